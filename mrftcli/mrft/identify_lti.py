"""A plant of any structure from the frequency-response points of its relay tests (a direct exact solve):
the ``"response-points"`` strategy of :func:`mrftcli.mrft.identify.identify` (the process families, a
declared structure).

A relay test's stable limit cycle is periodic, so each harmonic k of the output is the plant's
response to the same harmonic of the relay's square wave: ``G(j k Omega) = Y_k / U_k`` exactly, for
any linear plant and any relay (MRFT, ideal, hysteresis, biased levels), with no describing-function
approximation (:func:`mrftcli.analyze.general.response_points` measures them). This module fits a
:class:`~mrftcli.mrft.model.PlantModel` to such points by weighted least squares over its unknown
parameters, with the paper's constraint sets: the known parameters (set E) are held at their
values, the unknown ones stay in their ranges (set I).

The solve is separable: for fixed time constants the delay ``tau`` enters the phase and ``ln K`` the
log-gain linearly, so both have closed-form weighted means; the time constants (0-2 of them in the
built-in families; a declared structure's over their ranges) are searched on a grid, and the best
grid point is refined together with ``tau`` and ``K``. Speed (the issue asks < 1 ms a call for the
built-in families; bench_families prints it): where hand-written code beat the library, it says so.
The built-in families' log-gain, phase and Jacobian are real closed forms
(:class:`~mrftcli.mrft.lti_kernel.LagChainKernel`), so the grid and every step need no complex
response and no forward differences (any other structure, e.g. a declared one, gets a model object
per grid point and ``scipy.optimize.least_squares``). The families' refinement is a short
Levenberg-Marquardt (:func:`_levenberg_marquardt`) instead of ``least_squares``, whose set-up cost
more than the few steps needed from the grid's start, and its 2-4 unknown systems go to LAPACK directly. No table is cached: the
direct solve is under a millisecond from the first call. The covariance is the Gauss-Newton one,
inflated by the reduced chi-square when the points disagree beyond their standard errors; 95 %
intervals are formed on the log scale for positive parameters and cut at a bound of the set I (then
one-sided).

What the tests do not pin down is said, not guessed: a parameter whose 95 % interval (the linear one,
or the profile likelihood's where that reaches further) is wider than a factor of 1.25 either way
(:data:`DETERMINED_LOG_WIDTH`; or, for the delay, than a radian of phase at the limit cycles' median
frequency) is reported as not determined, with the test that would determine it and the product of
powers of the undetermined parameters that the tests do determine (:mod:`~mrftcli.mrft.determined`).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import statistics
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy import optimize
from scipy.linalg import lapack

from ..errors import IdentificationError, InputError, InsufficientDataError
from .determined import DeterminedCombination, determined_combination
from .lti_kernel import LagChainKernel, wrap as _wrap
from .identification import IdentificationRecord
from .model import PlantModel
from .parameter import DETERMINED_LOG_WIDTH, Z95, ParameterEstimate, fitted_estimate

__all__ = ["ResponsePoint", "LtiIdentification", "refuse_nothing_determined", "fit_response_points", "fit_covariance", "STATIC_HARMONIC",
           "static_gain_point"]

#: the method every identified (not given) parameter of this fit records (ParameterEstimate.method)
_METHOD = "response-points"
#: floors of the standard errors (relative gain, phase [rad]): a point measured from few cycles
#: (or noise-free simulations) must not get an infinite weight, and the cycle-to-cycle scatter misses
#: the few tenths of a percent a sampled relay's jitter leaves in the mean (bench_families: 0.2 %
#: gave 72 % coverage overall, 0.5 % 88 % on the hysteresis and biased rows)
_SE_FLOOR = (5e-3, 5e-3)
#: floor of an identified parameter's standard deviation (relative; for tau, as phase [rad] at the
#: tests' frequency): the few tenths of a percent a sampled relay leaves in every test's mean alike
#: (bench_families: IPDT's K off by -0.7 % on every draw of an ideal relay, at 3x its std) do not
#: average down over the tests as the points' scatter does
_PARAM_FLOOR = 5e-3
_GRID = np.geomspace(1e-2, 1e2, 33)
#: 95 % point of the chi-square distribution with one degree of freedom (the profile's rise)
_CHI2_95 = 3.841458820694124
#: :attr:`ResponsePoint.harmonic` of a static-gain point
STATIC_HARMONIC = 0
#: a static-gain point's frequency, relative to the lowest test frequency
_STATIC_OMEGA = 1e-6  # time constants times the points' median frequency

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ResponsePoint:
    """One measured point of the plant's frequency response.

    Attributes
    ----------
    omega : float
        Frequency [rad/s].
    gain : float
        |G(j omega)| [output units per command unit].
    phase : float
        arg G(j omega) [rad], any branch (the fit compares phases modulo 2 pi near its model).
    se_log_gain, se_phase : float
        Standard errors of ln gain [-] and of the phase [rad] (the scatter over the test's cycles).
    test : int
        Index of the relay test it comes from.
    harmonic : int
        k: the point is at k times the test's limit-cycle frequency; 0: the static gain (measured from
        a biased relay's mean levels, :data:`STATIC_HARMONIC`), placed at a frequency far below the
        tests' where every self-regulating plant's response is its static gain, its phase carrying
        no figure.

    Examples
    --------
    The fundamental of a test at 1 Hz where the plant's gain is 0.5 and its phase -120 deg:

    >>> p = ResponsePoint(2 * math.pi, 0.5, math.radians(-120), se_log_gain=0.01, se_phase=0.01)
    >>> round(p.to_json()["frequency_hz"], 6), p.harmonic
    (1.0, 1)
    """

    omega: float
    gain: float
    phase: float
    se_log_gain: float
    se_phase: float
    test: int = 0
    harmonic: int = 1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.omega) and self.omega > 0 and math.isfinite(self.gain) and self.gain > 0
                and math.isfinite(self.phase)):
            raise InputError(f"a response point needs a positive frequency and gain and a finite phase, "
                             f"got omega={self.omega!r}, gain={self.gain!r}, phase={self.phase!r}")

    def to_json(self) -> dict[str, Any]:
        return {"frequency_hz": self.omega / (2 * math.pi), "gain": self.gain, "phase_rad": self.phase,
                "se_log_gain": self.se_log_gain, "se_phase_rad": self.se_phase, "test": self.test,
                "harmonic": self.harmonic}


@dataclass(frozen=True)
class LtiIdentification(IdentificationRecord):
    """Outcome of :func:`fit_response_points` (:func:`mrftcli.mrft.identify.identify` of a process family):
    the one :class:`~mrftcli.mrft.identification.IdentificationRecord` with the fit's figures.

    Attributes
    ----------
    model : PlantModel
        The plant at the point estimate (known parameters and ranges kept).
    estimates : tuple of ParameterEstimate
        Every parameter of the family, in its order (``name`` set; method ``"response-points"``, or
        ``"given"`` for a known one).
    points : tuple of ResponsePoint
        The points fitted.
    chi2_dof : float or None
        Weighted misfit per degree of freedom (None without spare points); > 1 widens the intervals.
    undetermined : tuple of str
        Names of the parameters the tests do not pin down.
    advice : str
        What would determine them (empty when all are determined).
    warnings : tuple of str
        Figures to distrust: given values the points contradict (the fit's ``chi2_dof`` above
        10), even when every free parameter looks determined.
    combination : DeterminedCombination or None
        The product of the undetermined parameters' powers that the tests do determine (e.g. K/T1),
        if any (:func:`~mrftcli.mrft.determined.determined_combination`).
    """

    points: tuple[ResponsePoint, ...]
    chi2_dof: float | None
    undetermined: tuple[str, ...] = ()
    advice: str = ""
    combination: DeterminedCombination | None = None
    warnings: tuple[str, ...] = ()

    _method: ClassVar[str] = _METHOD

    @property
    def nothing_determined(self) -> bool:
        """True when the data determine none of the unknown parameters: each estimate is then one point of the
        range they leave open, not a value to use (``identify`` and ``analyze`` exit 6 after their output with
        :attr:`advice`, ``batch``'s row is insufficient). False when every parameter is known."""
        unknown = {e.name for e in self.estimates if not e.known}
        return bool(unknown) and unknown <= set(self.undetermined)

    def fit_json(self) -> dict[str, Any]:
        """``points``, ``chi2_dof``, ``undetermined``, ``advice``, ``determined_combination``, ``warnings`` (only when set)."""
        out = {"points": [p.to_json() for p in self.points], "chi2_dof": self.chi2_dof,
               "undetermined": list(self.undetermined), "advice": self.advice,
               "determined_combination": None if self.combination is None else self.combination.to_json()}
        # additive key, written only when set: an older record reads and writes back unchanged
        return out | ({"warnings": list(self.warnings)} if self.warnings else {})

    @classmethod
    def fit_from_json(cls, data: Mapping[str, Any], model: Any,
                      estimates: tuple[ParameterEstimate, ...]) -> LtiIdentification:
        """The record from :meth:`fit_json`'s keys of ``data``."""
        points = tuple(ResponsePoint(2 * math.pi * float(p["frequency_hz"]), float(p["gain"]), float(p["phase_rad"]),
                                     float(p["se_log_gain"]), float(p["se_phase_rad"]), int(p["test"]),
                                     int(p["harmonic"])) for p in data.get("points", []))
        chi, combo = data.get("chi2_dof"), data.get("determined_combination")
        return cls(model, estimates, points, None if chi is None else float(chi),
                   tuple(str(n) for n in data.get("undetermined", [])), str(data.get("advice", "")),
                   None if combo is None else DeterminedCombination.from_json(combo),
                   tuple(str(w) for w in data.get("warnings") or ()))


# ----------------------------------------------------------------------------------------------
# the solve
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Data:
    """The points as arrays, with their weights."""

    omega: FloatArray
    log_gain: FloatArray
    phase: FloatArray
    w_gain: FloatArray  # 1 / se
    w_phase: FloatArray
    fundamental: NDArray[np.bool_]  # the points at a limit cycle's own frequency
    w_median: float  # median omega [rad/s]: the time constants' grid is about 1/w_median
    w_cycles: float  # median omega of the fundamentals (all points without one) [rad/s]
    base: NDArray[np.bool_]  # the points whose phase fixes the delay's branch (the fundamentals)

    @classmethod
    def of(cls, points: Sequence[ResponsePoint]) -> _Data:
        table = np.array([(p.omega, p.gain, p.phase, p.se_log_gain, p.se_phase, p.harmonic == 1,
                           p.harmonic != STATIC_HARMONIC) for p in points])
        omega, fundamental, dynamic = table[:, 0], table[:, 5] > 0, table[:, 6] > 0
        tests = omega[dynamic] if dynamic.any() else omega  # a static point is no test frequency
        cycles = omega[fundamental] if fundamental.any() else tests
        return cls(omega, np.log(table[:, 1]), table[:, 2], 1.0 / np.maximum(table[:, 3], _SE_FLOOR[0]),
                   1.0 / np.maximum(table[:, 4], _SE_FLOOR[1]), fundamental, _median(tests), _median(cycles),
                   fundamental if fundamental.any() else omega <= tests.min())


def refuse_nothing_determined(ident: LtiIdentification, partial: dict[str, Any] | None = None) -> None:
    """Exit 6 (a partial result, as eq. (2)'s single beta) when the data determine none of the model's unknown
    parameters (:attr:`LtiIdentification.nothing_determined`). identify and analyze call it after the estimates
    and their intervals are printed and written, so they stay readable; batch marks the row insufficient.

    Raises
    ------
    InsufficientDataError
        With the identification's own advice (what would determine them: --param, another relay test) and
        ``partial`` (the analysis record batch keeps).
    """
    if ident.nothing_determined:
        raise InsufficientDataError(ident.advice, partial=partial)


def _wrap_grid(x: FloatArray, low: float = -math.pi) -> FloatArray:
    """:func:`_wrap` for the search grid's large arrays: x - 2 pi floor((x - low) / 2 pi), a fifth of
    np.mod's cost (its remainder is exact, this one within an ulp: a start, not the fit)."""
    turns = np.floor((x - low) * (0.5 / math.pi))
    wrapped: FloatArray = x - 2 * math.pi * turns
    return wrapped


def _median(x: FloatArray) -> float:
    """``np.median`` of a short 1-D array (the same value; np.median's overhead was a tenth of a call)."""
    return float(statistics.median(x.tolist()))


def _clip(x: FloatArray, lo: Any, hi: Any) -> FloatArray:
    """``np.clip`` (the same values, NaN kept) without its per-call overhead."""
    out: FloatArray = np.minimum(np.maximum(x, lo), hi)
    return out




class _Problem:
    """The unknown parameters, their scaling (log for positive ones) and the weighted residuals."""

    def __init__(self, model: PlantModel, data: _Data) -> None:
        self.model, self.data = model, data
        params = model.parameters
        self.unknown = [n for n, p in params.items() if not p.known]
        self.shape = [n for n in self.unknown if n not in ("K", "tau")]
        self.bounds = {n: params[n].bounds for n in self.unknown}
        # K keeps the sign of the model's K (the loop's sign is the segmenter's business)
        self.k_sign = 1.0 if params["K"].value > 0 else -1.0
        # positive parameters on the log scale (a declared parameter whose range reaches below 0, e.g.
        # an unstable pole's coefficient, stays linear); K on the log of its modulus, its sign kept
        self.log_scaled = {n for n in self.unknown if n != "tau" and (n == "K" or self.bounds[n][0] >= 0)}
        self.given = {n: p.value for n, p in params.items()}  # the known values (and placeholders)
        # the built-in families' residuals and Jacobian in closed form (None: any other structure)
        self.kernel = LagChainKernel.of(model, self.given, self.unknown, self.log_scaled, data)

    def values(self, z: FloatArray) -> dict[str, float]:
        out = {}
        for n, zi in zip(self.unknown, z):
            out[n] = self.k_sign * math.exp(zi) if n == "K" else (math.exp(zi) if n in self.log_scaled else float(zi))
        return out

    def z_of(self, values: Mapping[str, float]) -> FloatArray:
        """The solver's variables of ``values``; a log-scaled value of 0 (a declared range's lower end,
        which the start's linear grid may pick) maps to its variable's lower bound."""
        lo = self.z_bounds()[0]
        return np.array([(math.log(abs(values[n])) if values[n] != 0 else lo[i]) if n in self.log_scaled
                         else values[n] for i, n in enumerate(self.unknown)])

    def z_bounds(self) -> tuple[FloatArray, FloatArray]:
        """Bounds of the solver's variables: the set I, and for time constants at most 1e6 times from 1/omega."""
        w_ref = self.data.w_median
        lo, hi = [], []
        for n in self.unknown:
            a, b = self.bounds[n]
            if n in self.log_scaled:
                if n == "K":
                    a, b = (a, b) if self.k_sign > 0 else (-b, -a)
                span = math.inf if n == "K" else 1e6
                lo.append(max(math.log(a) if a > 0 else -np.inf, -math.log(span * w_ref)))
                hi.append(min(math.log(b) if 0 < b < np.inf else np.inf, math.log(span / w_ref)))
            else:
                lo.append(a)
                hi.append(b)
        return np.array(lo), np.array(hi)

    def response(self, values: Mapping[str, float]) -> NDArray[np.complex128]:
        return self.model.with_parameters(**values).frequency_response(self.data.omega)

    def residuals(self, z: FloatArray) -> FloatArray:
        d = self.data
        try:
            G = self.response(self.values(z))
        except InputError:  # a step out of the structure's domain (e.g. a time constant underflowing to 0)
            return np.full(2 * d.omega.size, 1e6)
        r_gain = (np.log(np.abs(G)) - d.log_gain) * d.w_gain
        r_phase = _wrap(np.angle(G) - d.phase) * d.w_phase
        return np.concatenate([r_gain, r_phase])


def _start(problem: _Problem) -> dict[str, float]:
    """The best point of the log grid over the time constants (:func:`_axes`), K and tau profiled out in
    closed form at every grid point at once (for fixed time constants ``tau`` enters the phase and
    ``ln K`` the log-gain linearly). The built-in families' misfits come from the kernel
    (:meth:`~mrftcli.mrft.lti_kernel.LagChainKernel.lag_grid`), any other structure's from a model
    object per grid point (:func:`_grid_misfit`)."""
    d = problem.data
    n = len(problem.shape)
    sopdt = n > 1 and problem.model.family == "sopdt"  # two interchangeable lags: T1 >= T2 only
    if problem.kernel is not None:  # the built-in families: the unit grid of _axes about 1/omega
        unit, index = _unit_grid(n, sopdt)
        axis = unit / d.w_median
        combos = axis[index]
    else:
        combos = np.array(list(itertools.product(*_axes(problem))), dtype=float) if n else np.zeros((1, 0))
        combos = combos[combos[:, 0] >= combos[:, 1]] if sopdt else combos
        axis, index = np.zeros(0), np.zeros((len(combos), 0), np.intp)
    if any(problem.bounds[name] != (0.0, math.inf) for name in problem.shape):
        keep = np.ones(len(combos), bool)
        for k, name in enumerate(problem.shape):
            keep &= (combos[:, k] >= problem.bounds[name][0]) & (combos[:, k] <= problem.bounds[name][1])
        combos, index = combos[keep], index[keep]
    # the model's ln|G| and arg G (any branch) minus the points', K at its sign and tau at 0 (or known)
    gain, phase = problem.kernel.lag_grid(axis, index) if problem.kernel is not None else _grid_misfit(problem, combos)
    if "K" in problem.unknown:  # ln|K|: the weighted mean log-gain misfit
        wg = d.w_gain ** 2
        K = _clip(problem.k_sign * np.exp(-(gain @ wg) / wg.sum()), *problem.bounds["K"])
        gain = gain + np.log(np.abs(K))[:, None]
    if "tau" in problem.unknown:
        # the delay's phase: on its principal branch at the limit cycles' own frequencies (a relay
        # cycle is near -pi), then the harmonics' (several turns at k Omega) unwrapped near that delay
        lag = _wrap_grid(phase, -0.5 * math.pi)
        wp_omega = d.w_phase ** 2 * d.omega
        t1 = lag @ (wp_omega * d.base) / (wp_omega * d.omega)[d.base].sum()
        lag = d.omega * t1[:, None] + _wrap_grid(lag - d.omega * t1[:, None])
        lo, hi = problem.bounds["tau"]
        tau = _clip(lag @ wp_omega / (wp_omega @ d.omega), max(lo, 0.0), hi)
        phase = phase - d.omega * tau[:, None]
    cost = gain ** 2 @ d.w_gain ** 2 + _wrap_grid(phase) ** 2 @ d.w_phase ** 2
    cost = np.where(np.isfinite(cost), cost, np.inf)  # a grid point out of the structure's domain
    if not np.isfinite(cost).any() and problem.unknown:
        raise IdentificationError("no admissible parameter values on the search grid: widen the ranges (set I)")
    i = int(np.argmin(cost))
    out = {name: float(combos[i, k]) for k, name in enumerate(problem.shape)}
    if "K" in problem.unknown:
        out["K"] = float(K[i])
    if "tau" in problem.unknown:
        out["tau"] = float(tau[i])
    return out


def _grid_misfit(problem: _Problem, combos: FloatArray) -> tuple[FloatArray, FloatArray]:
    """ln|G| and arg G minus the points' for each grid row of time constants (``combos``), a model object
    each, with K at its sign (or its known value) and tau at 0 (or its known value): shape (rows, points)
    [-], [rad]; NaN for a row out of the structure's domain."""
    d = problem.data
    params = problem.model.parameters
    probe = {"K": problem.k_sign * abs(params["K"].value) if "K" not in problem.unknown else problem.k_sign,
             "tau": params["tau"].value if "tau" not in problem.unknown else 0.0}
    G = np.full((len(combos), d.omega.size), np.nan, dtype=complex)
    for row, combo in enumerate(combos):
        try:
            G[row] = problem.model.with_parameters(**dict(zip(problem.shape, combo)), **probe).frequency_response(d.omega)
        except InputError:
            continue
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(np.abs(G)) - d.log_gain, np.angle(G) - d.phase


@functools.lru_cache(maxsize=8)
def _unit_grid(n: int, symmetric: bool) -> tuple[FloatArray, NDArray[np.intp]]:
    """The families' search grid in units of 1/omega (:func:`_axes`): the axis' values and, per grid
    point, the index of each of the ``n`` time constants on it (cached: the same for every call);
    ``symmetric``: two interchangeable lags (SOPDT), T1 >= T2 only."""
    axis = np.array(_GRID if n < 2 else _GRID[::2])
    rows = [c for c in itertools.product(range(axis.size), repeat=n) if not symmetric or c[0] >= c[1]]
    index = np.array(rows, dtype=np.intp).reshape(len(rows), n)
    axis.flags.writeable = index.flags.writeable = False
    return axis, index


def _axes(problem: _Problem) -> list[FloatArray]:
    """The search grid's axes: time constants on a log grid about 1/omega (the built-in families), or
    each declared parameter across its range (set I; log-spaced when positive), about 2000 points in all."""
    w_ref = problem.data.w_median
    d = len(problem.shape)
    if not getattr(problem.model, "grid_from_ranges", False):
        grid = _GRID / w_ref if d < 2 else _GRID[::2] / w_ref
        return [grid] * d
    m = max(4, min(33, int(round(2000 ** (1 / max(d, 1))))))
    axes = []
    for n in problem.shape:
        lo, hi = problem.bounds[n]
        axes.append(np.geomspace(lo, hi, m) if lo > 0 else np.linspace(lo, hi, m))
    return axes


def fit_response_points(points: Sequence[ResponsePoint], model: PlantModel) -> LtiIdentification:
    """The response-point families' strategy (:func:`mrftcli.mrft.identify.identify` of a process family or
    a declared structure): the unknown parameters of ``model`` from measured frequency-response points.

    Parameters
    ----------
    points : sequence of ResponsePoint
        G(j omega) measured on the relay tests' limit cycles.
    model : PlantModel
        The structure, with its known parameters (set E, at their values) and ranges (set I). The
        values of the unknown parameters are ignored except for the sign of K.

    Returns
    -------
    LtiIdentification

    Raises
    ------
    IdentificationError
        No point, or no admissible parameters.
    """
    if not points:
        raise IdentificationError("no frequency-response points to identify from (no stable relay test)")
    data = _Data.of(points)
    problem = _Problem(model, data)
    if getattr(model, "grid_from_ranges", False) and len(problem.unknown) > 2 * len(points):
        raise IdentificationError(
            f"{len(problem.unknown)} unknowns ({', '.join(problem.unknown)}) but the tests give {2 * len(points)} "
            "figures (gain and phase of each response point): state more parameters' values in the model "
            "file, or add relay tests at other phases")
    if not problem.unknown:
        return _result(problem, {}, np.zeros((0, 0)), None, points)
    start = _start(problem)
    z0 = problem.z_of(start)
    lo, hi = problem.z_bounds()
    z0 = _interior(z0, lo, hi)
    if problem.kernel is not None:
        z, r, J = _off_ridge(problem, *_levenberg_marquardt(problem, z0, lo, hi), lo, hi)
    else:
        sol = optimize.least_squares(problem.residuals, z0, bounds=(lo, hi), x_scale="jac", method="trf")
        z, r, J = sol.x, sol.fun, sol.jac
    n_static = sum(p.harmonic == STATIC_HARMONIC for p in points)  # its phase residual carries no figure
    n_res, n_par = 2 * len(points) - n_static, len(problem.unknown)
    dof = n_res - n_par
    chi2_dof = float(r @ r) / dof if dof > 0 else None
    inflate = max(1.0, chi2_dof or 1.0)
    cov = _pinv_psd(J.T @ J) * inflate
    flat = _null_parameters(problem, J)
    profiled: dict[int, tuple[float, float]] | None = None
    region = [z]
    if problem.kernel is not None:
        profiled = _profile_ends(problem, z, lo, hi, float(r @ r), _CHI2_95 * inflate, cov, flat, region)
    profiled = _above_zero(problem, z, lo, hi, float(r @ r), _CHI2_95 * inflate, flat, profiled, cov)
    out = _result(problem, problem.values(z), cov, chi2_dof, points, z, lo, hi, flat, profiled)
    if len(out.undetermined) >= 2:
        log_names = [n for n in problem.unknown if n in problem.log_scaled]
        keep = [problem.unknown.index(n) for n in log_names]
        F = (J.T @ J)[np.ix_(keep, keep)] / inflate
        units = {n: p.unit for n, p in model.parameters.items()}
        combo = determined_combination(log_names, z[keep], F, out.undetermined, units, {"K": problem.k_sign},
                                       DETERMINED_LOG_WIDTH, [_same_order(problem, z, zr)[keep] for zr in region])
        out = dataclasses.replace(out, combination=combo)
    return out


def fit_covariance(fit: LtiIdentification) -> tuple[tuple[str, ...], FloatArray, FloatArray]:
    """The Gauss-Newton covariance of a fit, as :func:`fit_response_points` forms its intervals from it.

    Returns the unknown parameters' names, their solver variables at the fit (``z``: ln|K|, ln T of a positive
    parameter, tau [s] linear) and the covariance of ``z`` (``(J^T J)^+``, inflated by the reduced chi-square
    when it exceeds 1), so a prediction made from the fitted model can carry the fit's own uncertainty. The
    Jacobian is the kernel's closed form for the built-in families, central differences otherwise.
    """
    problem = _Problem(fit.model, _Data.of(fit.points))
    if not problem.unknown:
        return (), np.zeros(0), np.zeros((0, 0))
    z = problem.z_of({n: fit.model.parameters[n].value for n in problem.unknown})
    if problem.kernel is not None:
        r, J = problem.kernel.evaluate(z)
    else:
        r = problem.residuals(z)
        J = np.empty((r.size, z.size))
        for i in range(z.size):
            dz = 1e-6 * max(1.0, abs(float(z[i])))
            step = np.eye(z.size)[i] * dz
            J[:, i] = (problem.residuals(z + step) - problem.residuals(z - step)) / (2 * dz)
    n_static = sum(p.harmonic == STATIC_HARMONIC for p in fit.points)
    dof = 2 * len(fit.points) - n_static - z.size
    inflate = max(1.0, float(r @ r) / dof) if dof > 0 else 1.0
    return tuple(problem.unknown), z, _pinv_psd(J.T @ J) * inflate


def _off_ridge(problem: _Problem, z: FloatArray, r: FloatArray, J: FloatArray, lo: FloatArray,
               hi: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """SOPDT's fit moved off the equal-lag ridge when it stopped there.

    At T1 = T2 the response depends on the lags only through their sum and product, whose map from
    (ln T1, ln T2) is singular there: the gradient across the ridge vanishes and the fit can stop on
    it far from the minimum (bench_slow_process: T1 = T2 = 113 s at 2.4x the truth's cost, K 27 %
    low "determined"). Where the two lags end within 10 % of each other, the fit is restarted with
    them split by 1.5x and 3x about their geometric mean, and the lowest cost kept.
    """
    if problem.model.family != "sopdt" or not {"T1", "T2"} <= set(problem.unknown):
        return z, r, J
    i, j = problem.unknown.index("T1"), problem.unknown.index("T2")
    if abs(z[i] - z[j]) > 0.1:
        return z, r, J
    best = (float(r @ r), z, r, J)
    mid = 0.5 * (z[i] + z[j])
    for split in (math.log(1.5), math.log(3.0)):
        start = z.copy()
        start[i], start[j] = mid + split, mid - split
        zs, rs, Js = _levenberg_marquardt(problem, _interior(_clip(start, lo, hi), lo, hi), lo, hi)
        if float(rs @ rs) < best[0]:
            best = (float(rs @ rs), zs, rs, Js)
    return best[1], best[2], best[3]


def _same_order(problem: _Problem, z: FloatArray, zr: FloatArray) -> FloatArray:
    """``zr`` with SOPDT's two lags in the estimate's order: the plant is the same with T1 and T2 swapped,
    so a profile point past the swap is the same point of the confidence region."""
    if problem.model.family != "sopdt" or not {"T1", "T2"} <= set(problem.unknown):
        return zr
    i, j = problem.unknown.index("T1"), problem.unknown.index("T2")
    if (z[i] - z[j]) * (zr[i] - zr[j]) >= 0:
        return zr
    out = zr.copy()
    out[i], out[j] = zr[j], zr[i]
    return out


def static_gain_point(gain: float, se_log_gain: float, points: Sequence[ResponsePoint]) -> ResponsePoint:
    """The static gain ``gain`` [output / command] (relative standard error ``se_log_gain``) as a response
    point at :data:`_STATIC_OMEGA` times the lowest frequency of ``points``, phase 0: for a
    self-regulating plant G there is its static gain to 1e-6 (the delay's and lags' phase is
    ``omega (tau + T)``, a micro-radian)."""
    w = min(p.omega for p in points) * _STATIC_OMEGA
    return ResponsePoint(w, abs(gain), 0.0 if gain > 0 else math.pi, se_log_gain, 1.0, test=-1,
                         harmonic=STATIC_HARMONIC)


def _interior(z: FloatArray, lo: FloatArray, hi: FloatArray) -> FloatArray:
    """``z`` moved inside its bounds by 1e-9 (1 + |z|) (least_squares wants a strictly interior start);
    in Python floats: 2-4 of them, where a dozen numpy calls cost more than the fit's step."""
    out = []
    for zi, a, b in zip(z.tolist(), lo.tolist(), hi.tolist()):
        inside = 1e-9 * (1 + abs(zi))
        out.append(min(max(zi, a + inside if math.isfinite(a) else -math.inf), b - inside if math.isfinite(b) else math.inf))
    return np.array(out)


def _pinv_psd(A: FloatArray) -> FloatArray:
    """``np.linalg.pinv(A, rcond=1e-12)`` of a symmetric positive semi-definite A (J^T J) through its
    eigendecomposition: the same matrix (to rounding) at half pinv's cost; directions whose eigenvalue
    is below 1e-12 of the largest (the data's flat ones) get no variance, as in pinv."""
    w, V, info = lapack.dsyevd(A)  # np.linalg.eigh's LAPACK routine without numpy's 7 us of checks per call
    if info != 0:
        w, V = np.linalg.eigh(A)
    keep = w > 1e-12 * w[-1] if w.size else w > 0
    out: FloatArray = (V[:, keep] / w[keep]) @ V[:, keep].T
    return out


def _levenberg_marquardt(problem: _Problem, z: FloatArray, lo: FloatArray, hi: FloatArray,
                         fixed: int | None = None) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The weighted least-squares fit from the grid's start: (z, residuals, Jacobian) at the solution.

    Hand-written where ``scipy.optimize.least_squares`` (trf) was 90 % of a call: from the grid's start
    it needs 3-6 steps, but its set-up, bound handling and numerical Jacobian cost 1-2 ms; here a step
    is a 2-4 unknown linear solve (bounds by projection: the set I's edges). The residuals and the
    Jacobian are the built-in families' closed forms (:class:`~mrftcli.mrft.lti_kernel.LagChainKernel`).
    Same minimum as ``least_squares`` (the tests compare). ``fixed``: the index of an unknown held at
    its value in ``z`` (its Jacobian column zeroed: the profile of :func:`_profile_ends`).
    """
    kernel = problem.kernel
    assert kernel is not None
    evaluate = kernel.evaluate

    def jacobian(z: FloatArray, r: FloatArray, J: FloatArray) -> FloatArray:
        if fixed is not None:
            J = J.copy()
            J[:, fixed] = 0.0
        return J

    def largest(x: NDArray[np.floating[Any]]) -> float:  # max |x| of a 2-4 vector (np.max's overhead was a tenth of a step)
        return float(max(map(abs, x.tolist())))

    z = _clip(z, lo, hi)
    r, J_z = evaluate(z)
    cost, lam = float(r @ r), 1e-3
    for _ in range(100):
        J = J_z = jacobian(z, r, J_z)
        A, g = J.T @ J, J.T @ r
        scale = np.maximum(np.diag(A), 1e-12)
        tol = 1e-10 * (1 + largest(z))
        step = _solve(A + np.diag(lam * scale), g)
        if largest(step) <= tol or 2 * float(g @ step) - float(step @ A @ step) <= 1e-12 * cost:
            break  # converged: the next step would move z, or lower the cost, by less than the tolerance
        cost_new = cost
        while lam < 1e12:
            z_new = _clip(z - step, lo, hi)
            r_new, J_new = evaluate(z_new)
            cost_new = float(r_new @ r_new)
            if cost_new < cost:
                lam = max(lam / 10, 1e-12)
                break
            if cost_new - cost <= 1e-12 * cost:
                break  # the cost flat to rounding: shorter steps only trade rounding noise
            lam *= 10
            step = _solve(A + np.diag(lam * scale), g)
        if not cost_new < cost:
            break  # no step lowers the cost: a minimum (within the range)
        done = cost - cost_new <= 1e-12 * cost or largest(z_new - z) <= tol
        z, r, J_z, cost = z_new, r_new, J_new, cost_new
        if done:
            break
    return z, r, jacobian(z, r, J_z)


def _solve(M: FloatArray, b: FloatArray) -> FloatArray:
    """``np.linalg.solve(M, b)`` through its LAPACK routine (dgesv) called directly: a 2-4 unknown system
    costs 1 us there and 6-10 us through numpy's checks, and the fit solves 5-10 of them."""
    _, _, x, info = lapack.dgesv(M, b)
    if info != 0:
        return np.asarray(np.linalg.solve(M, b), dtype=np.float64)  # singular: numpy's LinAlgError, as before
    return np.asarray(x, dtype=np.float64)


def _null_parameters(problem: _Problem, J: FloatArray) -> set[str]:
    """The parameters along which the fit is flat (fewer independent figures than unknowns)."""
    norms = np.linalg.norm(J, axis=0)
    Js = J / np.where(norms > 0, norms, 1.0)  # column-scaled: the verdict must not depend on units
    # V's rows are all there without U's full square (the residuals outnumber the unknowns) at a fraction of its cost
    _, sv, Vt, info = lapack.dgesdd(Js, full_matrices=int(Js.shape[0] < Js.shape[1]))  # np.linalg.svd's routine
    if info != 0:
        _, sv, Vt = np.linalg.svd(Js, full_matrices=Js.shape[0] < Js.shape[1])
    sv_list = sv.tolist()
    rank = sum(v > 1e-6 * sv_list[0] for v in sv_list) if sv_list and sv_list[0] > 0 else 0
    null = Vt[rank:]
    flat = {n for k, n in enumerate(problem.unknown) if null.size and np.max(np.abs(null[:, k])) > 0.1}
    flat |= {n for n, norm in zip(problem.unknown, norms.tolist()) if norm == 0}
    n_freq = len({round(math.log(w), 2) for w in problem.data.omega.tolist()})
    if flat and 2 * n_freq < len(problem.unknown):
        # fewer figures than unknowns: a local null direction is one of many; none is pinned down
        flat = set(problem.unknown)
    return flat


def _profile_ends(problem: _Problem, z: FloatArray, lo: FloatArray, hi: FloatArray, cost0: float, delta: float,
                  cov: FloatArray, flat: set[str],
                  region: list[FloatArray] | None = None) -> dict[int, tuple[float, float]]:
    """Each unknown's 95 % profile-likelihood interval [in z], where it reaches past the linear one.

    The Gauss-Newton interval is exact for a fit that is linear in the parameters; one relay setting
    sees a slow plant's K and T1 only through the slope at its frequency, where the cost is a curved
    valley and the linear interval can sit on one side of the truth. So the cost is profiled (the
    other unknowns refitted with this one held) at the linear interval's ends and beyond, doubling
    the step until it rises by ``delta`` (chi-square 95 %, one degree of freedom, times the misfit's
    inflation) or reaches the range's bound; the end is interpolated on sqrt(rise). A lower cost
    found on the way (a second minimum) is walked past the same way. The refitted points inside the
    region (their rise below ``delta``) are appended to ``region``.

    Where the fit is linear enough this costs two residual evaluations a parameter, no refit: at the
    linear interval's end, with the others moved along their linear regression on it (the linear
    profile), the cost rises by ``delta`` exactly for a linear fit; a rise within 0.5-2 ``delta``
    keeps the linear end. Only a flatter or a steeper (curved) rise is profiled.
    """
    kernel = problem.kernel
    assert kernel is not None
    out = {}
    for i, name in enumerate(problem.unknown):
        if name in flat:
            continue
        half = Z95 * max(math.sqrt(max(cov[i, i], 0.0)), 1e-9 * (1 + abs(z[i])))
        slope = cov[:, i] / cov[i, i] if cov[i, i] > 0 else np.eye(z.size)[i]
        ends = []
        for sign in (-1.0, 1.0):
            bound = lo[i] if sign < 0 else hi[i]
            probe = z + sign * half * slope
            if np.all(probe >= lo) and np.all(probe <= hi):
                rise = float(np.sum(kernel.residuals(probe) ** 2)) - cost0
                if 0.5 * delta <= rise <= 2.0 * delta:  # linear enough: the linear end stands
                    ends.append(z[i] + sign * half)
                    continue
            start = z.copy()

            def rise_at(x: float, i: int = i) -> float:  # the others refitted from the previous step's
                nonlocal start
                start[i] = x
                zf, r, _ = _levenberg_marquardt(problem, start, lo, hi, fixed=i)
                rise = float(r @ r) - cost0
                if region is not None and rise < delta:
                    region.append(zf.copy())
                start = zf.copy()
                return rise

            steps = _up_to(bound, sign, [z[i] + sign * mult * half for mult in (1.0, 2.0, 4.0, 8.0)])
            end = _walk(float(z[i]), steps, rise_at, delta)
            ends.append((bound if steps[-1] == bound else z[i] + sign * 16 * half) if end is None else end)
        out[i] = (ends[0], ends[1])
    return out


def _up_to(bound: float, sign: float, xs: list[float]) -> list[float]:
    """``xs`` (walking away from the fit in the direction ``sign``) up to and including ``bound``, cut there."""
    out: list[float] = []
    for x in xs:
        if (x - bound) * sign >= 0:
            return [*out, bound]
        out.append(x)
    return out


def _walk(x0: float, xs: Sequence[float], rise_at: Callable[[float], float], delta: float) -> float | None:
    """Where the cost's rise over the fit's first reaches ``delta`` along ``xs`` (walking away from ``x0``, the
    fit's value, whose rise is 0): interpolated on sqrt(rise) between the steps either side; None when no step
    of ``xs`` reaches it. ``rise_at(x)``: the rise with the parameter held at ``x``, the others refitted."""
    prev_x, prev_rise = x0, 0.0
    for x in xs:
        rise = rise_at(x)
        if rise >= delta:
            root_prev = math.sqrt(max(prev_rise, 0.0))
            return prev_x + (math.sqrt(delta) - root_prev) / (math.sqrt(rise) - root_prev) * (x - prev_x)
        prev_x, prev_rise = x, rise
    return None


def _held_cost(problem: _Problem, z: FloatArray, lo: FloatArray, hi: FloatArray, i: int, zi: float) -> float:
    """The fit's cost with unknown ``i`` held at ``zi`` [its z] and the others refitted (inside their bounds):
    the built-in families' by :func:`_levenberg_marquardt` (``fixed=i``), any other structure's by least_squares."""
    free = [k for k in range(z.size) if k != i]
    held = z.copy()
    held[i] = zi
    if problem.kernel is not None:
        r = _levenberg_marquardt(problem, held, lo, hi, fixed=i)[1]
        return float(r @ r)
    if not free:
        r = problem.residuals(held)
        return float(r @ r)

    def residuals(x: FloatArray) -> FloatArray:
        held[free] = x
        return problem.residuals(held)

    sol = optimize.least_squares(residuals, _interior(z[free], lo[free], hi[free]), bounds=(lo[free], hi[free]),
                                 x_scale="jac", method="trf")
    return float(sol.fun @ sol.fun)


def _held_rise(problem: _Problem, z: FloatArray, lo: FloatArray, hi: FloatArray, i: int, cost0: float, x: float) -> float:
    """The cost's rise over ``cost0`` with positive unknown ``i`` held at the value ``x`` (its z is ln x)."""
    return _held_cost(problem, z, lo, hi, i, math.log(x)) - cost0


def _above_zero(problem: _Problem, z: FloatArray, lo: FloatArray, hi: FloatArray, cost0: float, delta: float,
                flat: set[str], profiled: dict[int, tuple[float, float]] | None,
                cov: FloatArray) -> dict[int, tuple[float, float]] | None:
    """``profiled`` with the 95 % upper end [in z] of each positive parameter the fit left at the solver's floor
    (1e-6 / omega on the log scale), which stands for its declared range's 0: profiled on the value itself.

    On the log scale the residuals do not move near 0 (their slope there is the value times their slope in
    it), so the log-scale interval at the floor is a few ulps wide ("< 9.7e-09 s", overconfident). The value is
    held at steps of the linear half-width sqrt(``delta``) / |dr/dx|, doubling, the others refitted
    (:func:`_held_cost`), until the cost rises by ``delta`` (interpolated on sqrt(rise)); a cost still within
    ``delta`` at the range's top: the data do not bound it there (the range's top is the end).

    So is a value further up whose log-scale interval (``cov``) reaches below half the value, when the cost with
    the value held at the floor (the others refitted) is within ``delta`` of the fit's and no profile of
    :func:`_profile_ends` already reaches the floor: the log-scale
    interval excluded the 0 the data admit ('0.00199 - 0.0119' where a = 0 raises the cost by 1.5 of 4.3;
    '> 2.2e-07' for a true 0)."""
    out = dict(profiled or {})
    for i, name in enumerate(problem.unknown):
        p = problem.model.parameters[name]
        if name == "K" or name not in problem.log_scaled or name in flat or p.bounds[0] > 0:
            continue
        x0, top, value = math.exp(lo[i]), math.exp(hi[i]), math.exp(z[i])
        h = 1e-6 * top
        probe = z.copy()
        probe[i] = math.log(value + h)
        slope = float(np.linalg.norm(problem.residuals(probe) - problem.residuals(z))) / h
        step = math.sqrt(delta) / slope if slope > 0 else top
        rise_at = functools.partial(_held_rise, problem, z, lo, hi, i, cost0)
        if value - x0 >= step:
            # off the floor by more than its linear half-width: the log-scale interval stands unless it is loose
            # and 0 fits (the cost held there within delta; a tight one that 0 fits is a swap of two exchangeable
            # lags, SOPDT's T1 held at 0 refitted as T2). Nearer, the solver may have stalled a few floors up (where
            # the residuals do not move either): profiled like the floor
            loose = Z95 * math.sqrt(max(cov[i, i], 0.0)) >= math.log(2.0)  # its log interval reaches below half of it
            if not loose or (profiled and i in profiled and profiled[i][0] <= lo[i]) or rise_at(x0) >= delta:
                continue
        steps = _up_to(top, 1.0, [x0 + step * 2.0 ** k for k in range(40)])
        end = _walk(x0, steps, rise_at, delta)
        out[i] = (float(lo[i]), math.log(top if end is None else end))
    return out or profiled


def _result(problem: _Problem, values: dict[str, float], cov: FloatArray, chi2_dof: float | None,
            points: Sequence[ResponsePoint], z: FloatArray | None = None, lo: FloatArray | None = None,
            hi: FloatArray | None = None, flat: set[str] | None = None,
            profiled: Mapping[int, tuple[float, float]] | None = None) -> LtiIdentification:
    """Estimates with their intervals and the determinability verdict."""
    model = problem.model.with_parameters(**values) if values else problem.model
    d = problem.data
    w_ref = d.w_cycles
    estimates, undetermined = [], []
    for name, p in model.parameters.items():
        if p.known:
            estimates.append(ParameterEstimate.given(p.value, p.unit, name))
            continue
        i = problem.unknown.index(name)
        assert z is not None and lo is not None and hi is not None
        s = float(math.sqrt(max(cov[i, i], 0.0)))
        s = max(s, _PARAM_FLOOR / w_ref if name == "tau" else (_PARAM_FLOOR if name in problem.log_scaled else 0.0))
        est = fitted_estimate(name, p.value, float(z[i]), s, (float(lo[i]), float(hi[i])), p.unit,
                              name in problem.log_scaled, w_ref, _METHOD, profiled.get(i) if profiled else None)
        if est.one_sided == "low" and name in problem.log_scaled and name != "K" and p.bounds[0] <= 0:
            # cut at the solver's floor (1e-6 / omega on the log scale), which stands for the declared range's 0
            est = dataclasses.replace(est, ci95_low=p.bounds[0])
        if flat and name in flat:  # no interval along a flat direction: the data say nothing there
            est = dataclasses.replace(est, ci95_low=p.bounds[0], ci95_high=p.bounds[1], determined=False,
                                      one_sided="low" if p.bounds[0] > -math.inf else "")
        estimates.append(est)
        determined = est.determined
        if not determined:
            undetermined.append(name)
    contradiction = _contradiction(model, points, chi2_dof)
    advice = _advice(undetermined, points, contradiction) if undetermined else ""
    # the determined estimates look confident: flag them (the undetermined ones the advice already explains)
    shown = [n for n in problem.unknown if n not in undetermined]
    warnings = (f"the estimates of {', '.join(shown)} are not to be trusted: {contradiction}",) \
        if contradiction and shown else ()
    return LtiIdentification(model, tuple(estimates), tuple(points), chi2_dof, tuple(undetermined), advice,
                             warnings=warnings)


#: a fit with given values whose reduced chi-square is above this misses the points by several times their stated
#: errors (a free fit of a matching structure sits near 1-3): the given values, not a missing test, are at fault
_DISAGREE_CHI2_DOF = 10.0


def _contradiction(model: PlantModel, points: Sequence[ResponsePoint], chi2_dof: float | None) -> str:
    """The given values ``points`` contradict (their fit's ``chi2_dof`` above 10) and the
    two likely causes, or "" (no given value, or a fit that agrees)."""
    given = [f"{name} = {p.value:.4g} {p.unit}" for name, p in model.parameters.items() if p.known]
    if not given or chi2_dof is None or chi2_dof <= _DISAGREE_CHI2_DOF:
        return ""
    values = f"value{'s' if len(given) > 1 else ''} {', '.join(given)} disagree{'' if len(given) > 1 else 's'}"
    return (f"the given {values} with the {len(points)} response point(s) "
            f"(chi2/dof {chi2_dof:.3g} of their fit with {'them' if len(given) > 1 else 'it'}): either the "
            "given value is wrong or the log's timing is (e.g. the switch instants of a log below 25 Hz read with "
            "no --controller-rate, which places each switch midway between samples)")


def _advice(undetermined: Sequence[str], points: Sequence[ResponsePoint], contradiction: str) -> str:
    """Why ``undetermined`` are not determined and what to do: given values the points contradict
    (``contradiction``, :func:`_contradiction`) are named; otherwise another test or known values would
    determine them."""
    n = len(points)
    if contradiction:
        # the covariance is inflated by the misfit, so the free parameters look undetermined; more tests or
        # more known values would not help: the given value (or the points' timing) is wrong
        return f"{', '.join(undetermined)} not determined: {contradiction}"
    n_freq = len({round(math.log(p.omega), 1) for p in points})
    return (f"{', '.join(undetermined)} not determined by {n} response point(s) at {n_freq} "
            "distinct frequencies: give known values with --param NAME=VALUE, or add a relay test at another "
            "phase (an MRFT with a different beta, or a relay with hysteresis or none if all tests had it)")
