"""Identification: the one entry point :func:`identify`, and eq. (2)'s strategy (the unit manifolds).

Every model family is identified through :func:`identify` (``identify(data, model, **options)``);
the family names its strategy (its class's ``identification``, :data:`STRATEGIES`): eq. (2)'s
``"unit-manifolds"`` (below), the process families' ``"response-points"``
(:mod:`~mrftcli.mrft.identify_lti`), the cascade's ``"cascade-cycles"`` (:mod:`~mrftcli.mrft.cascade_identify`).

Eq. (2)'s strategy: each test i (beta_i, measured Omega_i) constrains the plant to one curve:
scaling the UFM slice at the known ``tp = Tp Omega_i`` back to real units (Lemma 3),

    tau_i(Td) = theta_{beta_i}(Tp Omega_i, Td Omega_i) / Omega_i .

Two tests give (Td, tau) at the intersection of their curves (paper Section IV, Fig. 5); three or
more a weighted least-squares fit in log-frequency.  The shipped manifolds only *bracket* the
solution; it is then polished with the exact closed form of :mod:`mrftcli.mrft.lprs`, so grid
interpolation never limits the accuracy.  K follows from the amplitudes through the UGM (Lemmas 2
and 4): ``a_i = h_i K Td a_unit(Tp Omega_i, Td Omega_i) / Omega_i``.  The same strategy over a log's
cycles (a consensus of all the tests' constraints, a bootstrap over cycles) is
:mod:`mrftcli.mrft.consensus`; its waveform refinement :mod:`mrftcli.mrft.refine`.

Uncertainty: the per-cycle scatter of each test's frequency (and amplitude) gives the standard
error of its mean; it is propagated by a vectorised Monte Carlo (two tests) or the delta method
(three or more) to mean, standard deviation and a 95 % interval per parameter.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Iterable, Mapping, Sequence, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize

from ..jsonable import json_opt_float
from ..errors import IdentificationError, InputError
from ..validate import check_beta, check_time
from .identification import IdentificationRecord
from .identify_lti import LtiIdentification, ResponsePoint
from .lprs import unit_cycle, unit_cycle_scalar
from .model import LEAD_CAP_S, LoopModel, PlantModel, lead_floor
from .sem import mean_sem
from .parameter import Z95, ParameterEstimate
from .slices import frequency_sensitivity, intersection, intersection_draws, least_squares, tau_curve
from .ufm import ManifoldSet, load_manifolds

if TYPE_CHECKING:
    from .cascade import CascadeModel
    from .cascade_identify import CascadeIdentification

__all__ = [
    "TestMeasurement",
    "ResponsePoint",
    "ParameterEstimate",
    "IdentificationResult",
    "identify",
    "Strategy",
    "STRATEGIES",
    "strategy_of",
    "unit_manifolds",
    "gain_disagreement",
    "lead_note",
    "lead_refusal",
    "LEAD_WORDS",
    "GAIN_FLOOR",
    "ufm_slice",
    "tau_curve",
    "intersection_draws",
]

_TWO_PI = 2.0 * math.pi
FloatArray = NDArray[np.float64]
#: |d ln Omega / d ln Td| below which Td is reported as poorly identifiable
_SENSITIVITY_WARN = 0.05


def _as_positive_array(name: str, value: object) -> FloatArray:
    try:
        arr = np.atleast_1d(np.asarray(value, dtype=float)).ravel()
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} must be a positive number or a sequence of them, got {value!r}") from err
    if arr.size == 0:
        raise InputError(f"{name} is empty")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise InputError(f"{name} must be positive and finite, got {value!r}")
    return arr


@dataclass(frozen=True, eq=False)
class TestMeasurement:
    """One MRFT test as measured.

    Parameters
    ----------
    beta : float
        MRFT parameter in (-1, 1) (nominal, or the effective beta measured at the switches).
    frequency_hz : float or sequence of float
        Limit-cycle frequency [Hz]: one value, or one value per cycle (its scatter is then
        propagated to the parameters).
    amplitude : float or sequence of float, optional
        Output amplitude [output units], scalar or per cycle; needed for K.
    h : float, optional
        Relay amplitude [command units]; required together with ``amplitude``.

    Examples
    --------
    >>> t = TestMeasurement(beta=-0.4, frequency_hz=[0.70, 0.71, 0.705], amplitude=0.0785, h=1.0)
    >>> t.n_cycles, round(t.frequency_mean, 3)
    (3, 0.705)
    """

    __test__ = False  # not a pytest test class

    beta: float
    frequency_hz: float | Sequence[float] | np.ndarray
    amplitude: float | Sequence[float] | np.ndarray | None = None
    h: float | None = None
    #: the per-cycle frequencies [Hz] and amplitudes, checked (set in __post_init__)
    _f: FloatArray = field(init=False, repr=False)
    _a: FloatArray | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        object.__setattr__(self, "beta", check_beta(self.beta))
        f = _as_positive_array("frequency_hz", self.frequency_hz)
        object.__setattr__(self, "_f", f)
        if self.amplitude is not None:
            a = _as_positive_array("amplitude", self.amplitude)
            if self.h is None:
                raise InputError("an amplitude needs the relay height h of its test")
            object.__setattr__(self, "_a", a)
        else:
            object.__setattr__(self, "_a", None)
        if self.h is not None:
            h = float(self.h)
            if not math.isfinite(h) or h <= 0:
                raise InputError(f"relay height h must be positive, got {self.h!r}")

    @staticmethod
    def _stats(x: FloatArray) -> tuple[float, float]:
        """Mean and standard error of the mean, cycles taken as an AR(1) sequence (:func:`~mrftcli.mrft.sem.mean_sem`;
        0 for a single value)."""
        if x.size < 2:
            return float(x[0]), 0.0
        return float(x.mean()), mean_sem(x)

    @property
    def n_cycles(self) -> int:
        return int(self._f.size)

    @property
    def frequency_mean(self) -> float:
        return self._stats(self._f)[0]

    @property
    def frequency_sem(self) -> float:
        return self._stats(self._f)[1]

    @property
    def frequency_cycle_std(self) -> float:
        return float(self._f.std(ddof=1)) if self._f.size > 1 else 0.0

    @property
    def amplitude_mean(self) -> float | None:
        return None if self._a is None else self._stats(self._a)[0]

    @property
    def amplitude_sem(self) -> float | None:
        return None if self._a is None else self._stats(self._a)[1]

    @property
    def amplitude_cycle_std(self) -> float | None:
        if self._a is None:
            return None
        return float(self._a.std(ddof=1)) if self._a.size > 1 else 0.0


@dataclass(frozen=True, eq=False)
class IdentificationResult(IdentificationRecord):
    """Outcome of :func:`identify` for eq. (2): the one :class:`~mrftcli.mrft.identification.IdentificationRecord`
    record with the unit manifolds' figures.

    Attributes
    ----------
    model : LoopModel
        The point estimate (K = 1 when unknown), with the known Tp [s] (:attr:`Tp`).
    estimates : tuple of ParameterEstimate
        Td [s] and tau [s] (the plant's delay: the sampling lag is removed when a rate was given), K (left
        out without amplitudes) and the given Tp [s]: :attr:`Td`, :attr:`tau`, :attr:`K`.
    residual : float or None
        Three or more tests: weighted RMS of the log-frequency residuals (relative frequency error).
    tests : tuple of dict
        Per test: beta, measured and model frequency, normalised coordinates, sensitivities, K_i.
    warnings : tuple of str
        Identifiability and consistency warnings.
    method : str
        "intersection", "least-squares" or "amplitude".
    uncertainty : str
        How std/intervals were obtained ("monte-carlo", "delta", "none").
    """

    residual: float | None
    tests: tuple[dict[str, Any], ...]
    warnings: tuple[str, ...]
    method: str
    uncertainty: str
    rate_hz: float | None = None
    n_draws: int = 0
    draws: dict[str, FloatArray] = field(default_factory=dict, repr=False)

    _open_value: ClassVar[float] = math.nan
    _sided: ClassVar[bool] = False
    _optional: ClassVar[frozenset[str]] = frozenset({"K"})

    @classmethod
    def of(cls, Td: ParameterEstimate, tau: ParameterEstimate, K: ParameterEstimate | None, model: LoopModel,
           **fit: Any) -> IdentificationResult:
        """The record of eq. (2)'s estimates (named here; Tp given from ``model``) and the fit's fields."""
        named = [dataclasses.replace(e, name=n) for n, e in (("Td", Td), ("tau", tau), ("K", K)) if e is not None]
        return cls(model, (*named, ParameterEstimate.given(model.Tp, "s", "Tp")), **fit)

    @property
    def Td(self) -> ParameterEstimate:
        """Drag time constant [s]."""
        return self.estimate("Td")

    @property
    def tau(self) -> ParameterEstimate:
        """Delay [s]."""
        return self.estimate("tau")

    @property
    def K(self) -> ParameterEstimate | None:
        """Gain (None without amplitudes)."""
        return self.parameters.get("K")

    @property
    def Tp(self) -> float:
        """The known propulsion time constant [s] (the model's)."""
        return float(self.model.Tp)

    def fit_json(self) -> dict[str, Any]:
        """``method``, ``uncertainty``, ``n_draws``, ``residual``, ``rate_hz``, ``tests``, ``warnings`` (the
        Monte Carlo draws are left out)."""
        return {"method": self.method, "uncertainty": self.uncertainty, "n_draws": self.n_draws,
                "residual": self.residual, "rate_hz": self.rate_hz, "tests": [dict(t) for t in self.tests],
                "warnings": list(self.warnings)}

    @classmethod
    def fit_from_json(cls, data: Mapping[str, Any], model: Any,
                      estimates: tuple[ParameterEstimate, ...]) -> IdentificationResult:
        """The record from :meth:`fit_json`'s keys of ``data`` (without draws)."""
        missing = [n for n in ("Td", "tau") if n not in {e.name for e in estimates}]
        if missing:
            raise InputError(f"identification JSON: 'parameters' needs {' and '.join(map(repr, missing))} "
                             "(eq. (2) identifies both)")
        tests, warnings = data.get("tests"), data.get("warnings")
        if not (isinstance(tests, list) and all(isinstance(t, Mapping) for t in tests)
                and isinstance(warnings, list) and all(isinstance(w, str) for w in warnings)):
            raise InputError("identification JSON needs 'tests' (objects) and 'warnings' (strings)")
        return cls(model, estimates, residual=json_opt_float(data.get("residual"), "identification JSON: residual"),
                   tests=tuple(dict(t) for t in tests), warnings=tuple(warnings),
                   method=str(data.get("method")), uncertainty=str(data.get("uncertainty")),
                   rate_hz=json_opt_float(data.get("rate_hz"), "identification JSON: rate_hz"),
                   n_draws=int(data.get("n_draws") or 0))


# ----------------------------------------------------------------------------------------------
# the curves tau_i(Td)
# ----------------------------------------------------------------------------------------------
def ufm_slice(Tp: float, beta: float, frequency_hz: float, Td_values: ArrayLike, exact: bool = True) -> np.ndarray:
    """The UFM slice of one test scaled to real units (paper Fig. 5): tau [s] for each Td [s].

    Parameters
    ----------
    Tp : float
        Known propulsion time constant [s].
    beta : float
        The test's beta.
    frequency_hz : float
        The test's measured frequency [Hz].
    Td_values : array_like
        Drag time constants [s] at which to evaluate the curve.
    exact : bool
        Evaluate the closed form (default) rather than interpolating the shipped manifolds.

    Returns
    -------
    ndarray
        tau [s]; NaN where no non-negative delay produces that frequency.
    """
    Tp = check_time("Tp", Tp)
    beta = check_beta(beta)
    f = _as_positive_array("frequency_hz", frequency_hz)
    if f.size != 1:
        raise InputError("ufm_slice takes one frequency")
    Td = _as_positive_array("Td_values", Td_values)
    tau = tau_curve(Tp, beta, _TWO_PI * f[0], Td, exact=exact)
    return np.where(tau >= 0, tau, np.nan)


# ----------------------------------------------------------------------------------------------
# the stages of identify(): checked inputs -> measured tests -> point estimate -> gains and
# identifiability -> uncertainty
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Inputs:
    """The arguments of :func:`identify`, checked."""

    tests: tuple[TestMeasurement, ...]
    Tp: float
    rate_hz: float | None
    K: float | None
    n_draws: int
    seed: int
    spread: str

    @property
    def sampling_lag(self) -> float:
        """The sampled relay's mean switching lag [s]: half a sample (0 for a continuous relay)."""
        return 0.0 if self.rate_hz is None else 0.5 / self.rate_hz


@dataclass(frozen=True, eq=False)
class _Measured:
    """The tests' betas, mean frequencies [Hz] and the spread to propagate [Hz]; omegas [rad/s]."""

    betas: list[float]
    f_mean: FloatArray
    f_unc: FloatArray
    omegas: FloatArray


@dataclass(frozen=True, eq=False)
class _Point:
    """The point estimate from the mean frequencies.

    ``tau_eff`` [s] is the delay the curves meet at (>= 0, sampling lag included), ``tau`` [s] the
    plant's delay; ``weights`` are the least-squares weights of the tests (ones for two tests).
    """

    Td: float
    tau_eff: float
    tau: float
    residual: float | None
    method: str
    weights: FloatArray
    warnings: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class _Spread:
    """The estimates with their spread, how it was obtained, and the draws behind it."""

    Td: ParameterEstimate
    tau: ParameterEstimate
    K: ParameterEstimate | None
    method: str
    n_draws: int
    draws: dict[str, FloatArray]
    warnings: tuple[str, ...]


def _estimate(values: FloatArray, point: float, unit: str) -> ParameterEstimate:
    v = values[np.isfinite(values)]
    if v.size < 2:
        return ParameterEstimate(point, 0.0, point, point, unit, method="mrft")
    lo, hi = np.percentile(v, [2.5, 97.5])
    return ParameterEstimate(point, float(v.std(ddof=1)), float(lo), float(hi), unit, method="mrft")


def _delta_estimate(point: float, std: float, unit: str) -> ParameterEstimate:
    return ParameterEstimate(point, std, point - Z95 * std, point + Z95 * std, unit, method="mrft")


def _check_inputs(tests: Iterable[TestMeasurement], model: LoopModel, rate_hz: float | None,
                  n_draws: int, seed: int, spread: str) -> _Inputs:
    checked = tuple(tests)
    for t in checked:
        if not isinstance(t, TestMeasurement):
            raise InputError("tests must be TestMeasurement objects")
    if not isinstance(model, LoopModel) or "Tp" not in model.known:
        raise InputError("identify takes eq. (2) with Tp known: soiptd_model(Tp) (Tp [s] from the bench test)")
    # the model checked Tp (a positive time up to a week) and K (finite, non-zero) when it was made
    Tp, K = float(model.Tp), (float(model.K) if "K" in model.known else None)
    if rate_hz is not None:
        rate_hz = float(rate_hz)
        if not math.isfinite(rate_hz) or rate_hz <= 0:
            raise InputError(f"rate must be a positive frequency in Hz, got {rate_hz}")
    if spread not in ("sem", "cycle"):
        raise InputError("spread must be 'sem' or 'cycle'")
    if int(n_draws) < 10:
        raise InputError(f"n_draws must be at least 10, got {n_draws}")
    return _Inputs(checked, Tp, rate_hz, K, int(n_draws), seed, spread)


def _measure(inputs: _Inputs) -> _Measured:
    """The betas (checked: two or more, different) and mean frequencies of the tests."""
    tests = inputs.tests
    if len(tests) < 2:
        raise InputError("identification needs at least two tests with different betas")
    betas = [t.beta for t in tests]
    if len(set(np.round(betas, 6))) < len(betas) and len(tests) == 2:
        raise InputError("the two tests have the same beta: they determine the same curve, use different betas")
    if len(set(np.round(betas, 6))) < 2:
        raise InputError("all tests have the same beta; at least two different betas are needed")
    f_mean = np.array([t.frequency_mean for t in tests])
    if inputs.spread == "sem":
        f_unc = np.array([t.frequency_sem for t in tests])
    else:
        f_unc = np.array([t.frequency_cycle_std for t in tests])
    return _Measured(betas, f_mean, f_unc, _TWO_PI * f_mean)


def _point_estimate(inputs: _Inputs, m: _Measured, ms: ManifoldSet) -> _Point:
    """Where the tests' curves meet: the intersection (two tests) or a weighted least-squares fit."""
    Tp, omegas = inputs.Tp, m.omegas
    residual: float | None
    if len(m.betas) == 2:
        Td_hat, tau_eff, warns = intersection(Tp, m.betas, list(omegas), ms)
        residual, method, weights = None, "intersection", np.ones(2)
    else:
        rel = m.f_unc / m.f_mean
        # each test weighs by its relative frequency precision, or all alike when one has none
        weights = np.where(rel > 0, 1.0 / np.maximum(rel, 1e-12) ** 2, 1.0) if np.all(rel > 0) else np.ones(len(rel))
        Td_hat, tau_eff, residual, warns = least_squares(Tp, m.betas, list(omegas), weights, ms)
        method = "least-squares"
    warns = list(warns)
    tau_hat = _checked_lead(tau_eff - inputs.sampling_lag, Tp, warns, lag=inputs.sampling_lag)
    return _Point(Td_hat, tau_eff, tau_hat, residual, method, weights, tuple(warns))


def _checked_lead(tau: float, Tp: float, warns: list[str], *, lag: float = 0.0) -> float:
    """``tau`` [s] under eq. (2)'s lead rule, every route's one copy of it.

    ``tau + lag`` (the route's delay before the sampling ``lag`` [s] is removed) beyond
    :func:`~mrftcli.mrft.model.lead_floor` of ``Tp`` [s] is refused (:func:`lead_refusal`); a ``tau`` pushed
    beyond it only by removing the lag is set to the floor, said in ``warns``; a ``tau`` < 0 appends
    :func:`lead_note` to ``warns``. Returns the tau the model takes [s].
    """
    floor = lead_floor(Tp)
    if tau + lag < floor:
        raise IdentificationError(lead_refusal(tau + lag, Tp))
    if tau < floor:
        warns.append(f"removing the sampling lag ({lag * 1e3:.3g} ms) leaves a lead beyond the "
                     f"{-floor * 1e3:.3g} ms eq. (2) admits; tau set to {floor * 1e3:.3g} ms")
        tau = floor
    if tau < 0:
        warns.append(lead_note(tau))
    return tau


#: how :func:`lead_note` begins (a record's lead statement is found by it)
LEAD_WORDS = "the loop leads eq. (2)"


def lead_refusal(tau: float, Tp: float) -> str:
    """The one-line refusal of a lead ``tau`` [s] beyond :func:`~mrftcli.mrft.model.lead_floor` at ``Tp`` [s]."""
    return (f"the measured frequencies imply a lead of {-tau * 1e3:.3g} ms (tau < 0), beyond the "
            f"{-lead_floor(Tp) * 1e3:.3g} ms eq. (2) admits (an estimator's lead is a few ms: at most "
            f"{LEAD_CAP_S * 1e3:g} ms or Tp/2): no plant of eq. (2) with Tp = {Tp:g} s fits; a Tp given too large "
            "reads as a lead: check --tp (and the betas)")


def lead_note(tau: float) -> str:
    """The statement a lead (``tau`` < 0 [s]) carries wherever eq. (2) is identified with one."""
    return (f"{LEAD_WORDS}: tau = {tau * 1e3:.3g} ms < 0, less lag than eq. (2) without delay (an "
            "estimator's lead, e.g. EKF2's attitude or EKF3's altitude, or a Tp given too large); identified "
            f"with the lead (down to -min(Tp/2, {LEAD_CAP_S * 1e3:g} ms) admitted); a design or simulation that needs a causal delay "
            "says what it does with it")


def _test_gains(inputs: _Inputs, m: _Measured, Td: float) -> list[float | None]:
    """K of each test with an amplitude, from the UGM (Lemmas 2 and 4); None without one."""
    gains: list[float | None] = []
    for t, w in zip(inputs.tests, m.omegas):
        if t.amplitude_mean is None or t.h is None:
            gains.append(None)
            continue
        a_unit = unit_cycle_scalar(inputs.Tp * w, Td * w, t.beta)[1]
        gains.append(t.amplitude_mean * w / (float(t.h) * Td * a_unit))
    return gains


def _per_test(inputs: _Inputs, m: _Measured, point: _Point,
              gains: list[float | None]) -> tuple[tuple[dict[str, Any], ...], list[str]]:
    """Each test's figures and sensitivities, and the identifiability warnings they raise."""
    Tp, Td = inputs.Tp, point.Td
    rows: list[dict[str, Any]] = []
    for i, (t, w) in enumerate(zip(inputs.tests, m.omegas)):
        s_td, s_tau = frequency_sensitivity(Tp, Td, point.tau_eff, t.beta, w)
        rows.append({
            "beta": t.beta,
            "frequency_hz": float(m.f_mean[i]),
            "frequency_sem_hz": float(t.frequency_sem),
            "n_cycles": t.n_cycles,
            "amplitude": t.amplitude_mean,
            "h": t.h,
            "tp_norm": Tp * w,
            "td_norm": Td * w,
            "theta": point.tau_eff * w,
            "dlnOmega_dlnTd": s_td,
            "dlnOmega_dtau": s_tau,
            "K": gains[i],
            # the curve of this test in real units is ufm_slice(Tp, beta, frequency_hz, Td) - sampling_lag
            "sampling_lag": inputs.sampling_lag,
        })
    warns: list[str] = []
    sens = [abs(r["dlnOmega_dlnTd"]) for r in rows]
    if max(sens) < _SENSITIVITY_WARN:
        warns.append(
            f"Td is poorly identifiable: Td*Omega = {max(r['td_norm'] for r in rows):.3g}, a 10 % change of Td "
            f"moves the test frequencies by at most {10 * max(sens):.2g} %"
        )
    spread_b = max(m.betas) - min(m.betas)
    if spread_b < 0.2:
        warns.append(f"the betas differ by only {spread_b:.2g}; Td and tau are better determined with betas "
                     "further apart (e.g. -0.4 and -0.7)")
    return tuple(rows), warns


#: relative error [-] every test's own gain carries beyond its amplitude's standard error (the cycle's
#: shape, the plant's unmodelled dynamics): tests agreeing to within a few of these are consistent
GAIN_FLOOR = 0.1


def gain_disagreement(tests: Sequence[TestMeasurement], gains: Sequence[float | None]) -> list[str]:
    """A warning naming two tests whose own K disagree beyond their intervals (a typed or logged amplitude
    or relay height off by a factor, a test on another vehicle), or nothing.

    Each test's K carries its amplitude's relative standard error and :data:`GAIN_FLOOR`; two tests
    disagree when ``|ln K_i - ln K_j|`` exceeds three times their combined error (10x: ln 10 = 2.3
    against 0.42 without standard errors).
    """
    rows = [(i, k, math.hypot(GAIN_FLOOR, (t.amplitude_sem or 0.0) / t.amplitude_mean))
            for i, (t, k) in enumerate(zip(tests, gains))
            if k is not None and k > 0 and t.amplitude_mean]
    worst = None
    for a in range(len(rows)):
        for b in range(a + 1, len(rows)):
            (i, ki, si), (j, kj, sj) = rows[a], rows[b]
            z = abs(math.log(ki / kj)) / math.hypot(si, sj)
            if z > 3 and (worst is None or z > worst[0]):
                worst = (z, i, ki, j, kj)
    if worst is None:
        return []
    _, i, ki, j, kj = worst
    return [f"the tests' own gains disagree: test {i + 1} gives K {ki:.4g}, test {j + 1} K {kj:.4g} "
            f"({max(ki, kj) / min(ki, kj):.2g}x, beyond their intervals): check each test's amplitude and relay "
            "height H (units, a typo); K is their mean and is not to be trusted"]


def _uncertainty(inputs: _Inputs, m: _Measured, point: _Point, gains: list[float | None],
                 ms: ManifoldSet) -> _Spread:
    """The spread of the estimates: none, Monte Carlo (two tests) or the delta method (three or more)."""
    have_K = [k for k in gains if k is not None]
    K_hat = float(np.mean(have_K)) if have_K else None
    a_unc_any = any(t.amplitude is not None and (t.amplitude_sem or 0) > 0 for t in inputs.tests)
    if np.all(m.f_unc == 0) and not a_unc_any and (inputs.rate_hz is None or len(inputs.tests) != 2):
        empty = np.array([])
        K_est = None if K_hat is None else _estimate(empty, K_hat, "")
        return _Spread(_estimate(empty, point.Td, "s"), _estimate(empty, point.tau, "s"), K_est, "none", 0, {}, ())
    if len(inputs.tests) == 2:
        return _monte_carlo(inputs, m, point, K_hat, ms)
    K_std = float(np.std(have_K, ddof=1)) if len(have_K) > 1 else 0.0
    return _delta_method(inputs, m, point, None if K_hat is None else _delta_estimate(K_hat, K_std, ""), ms)


def _monte_carlo(inputs: _Inputs, m: _Measured, point: _Point, K_hat: float | None, ms: ManifoldSet) -> _Spread:
    """Two tests: draw their mean frequencies (and a sampled relay's switching lags), solve each draw."""
    n_draws, Tp, betas = inputs.n_draws, inputs.Tp, m.betas
    rng = np.random.default_rng(inputs.seed)
    wd = _TWO_PI * (m.f_mean[None, :] + m.f_unc[None, :] * rng.standard_normal((n_draws, 2)))
    wd = np.where(wd > 0, wd, np.nan)
    # sampled relay: each test's switching lag is uniform in [0, Ts) (its orbit is unknown)
    lag_d = None if inputs.rate_hz is None else rng.uniform(0.0, 1.0 / inputs.rate_hz, (n_draws, 2))
    Td_d = intersection_draws(Tp, betas, np.nan_to_num(wd, nan=m.omegas.mean()), ms, point.Td, lags=lag_d)
    Td_d[~np.all(np.isfinite(wd), axis=1)] = np.nan
    ok = np.isfinite(Td_d)
    th1, _ = unit_cycle(Tp * wd[ok, 0], Td_d[ok] * wd[ok, 0], betas[0])
    tau_d = np.full(n_draws, np.nan)
    tau_d[ok] = th1 / wd[ok, 0] - (inputs.sampling_lag if lag_d is None else lag_d[ok, 0])
    n_used = int(ok.sum())
    warns = []
    if n_used < n_draws:
        warns.append(f"{n_draws - n_used} of {n_draws} Monte Carlo draws admitted no plant (large scatter)")
    draws = {"Td": Td_d, "tau": tau_d}
    K_est = None
    if K_hat is not None:
        draws["K"] = _gain_draws(inputs, m, wd, Td_d, ok, rng)
        K_est = _estimate(draws["K"], K_hat, "")
    return _Spread(_estimate(Td_d, point.Td, "s"), _estimate(tau_d, point.tau, "s"), K_est, "monte-carlo", n_used,
                   draws, tuple(warns))


def _gain_draws(inputs: _Inputs, m: _Measured, wd: FloatArray, Td_d: FloatArray, ok: NDArray[np.bool_],
                rng: np.random.Generator) -> FloatArray:
    """K of each Monte Carlo draw: the mean over the tests with an amplitude (itself drawn)."""
    n_draws = inputs.n_draws
    K_d_all = []
    for i, t in enumerate(inputs.tests):
        if t.amplitude_mean is None or t.h is None:
            continue
        a_unc = t.amplitude_sem if inputs.spread == "sem" else t.amplitude_cycle_std
        a_d = t.amplitude_mean + (a_unc or 0.0) * rng.standard_normal(n_draws)
        _, au = unit_cycle(inputs.Tp * wd[ok, i], Td_d[ok] * wd[ok, i], m.betas[i])
        kd = np.full(n_draws, np.nan)
        kd[ok] = a_d[ok] * wd[ok, i] / (float(t.h) * Td_d[ok] * au)
        K_d_all.append(kd)
    K_d: FloatArray = np.nanmean(np.array(K_d_all), axis=0) if K_d_all else np.full(n_draws, np.nan)
    return K_d


def _delta_method(inputs: _Inputs, m: _Measured, point: _Point, K_est: ParameterEstimate | None,
                  ms: ManifoldSet) -> _Spread:
    """Three or more tests: the least-squares fit's Jacobian carries the frequencies' spread."""
    J = np.zeros((2, len(m.betas)))
    for i in range(len(m.betas)):
        if m.f_unc[i] == 0:
            continue
        om = m.omegas.copy()
        dw = 1e-4 * om[i]
        om[i] += dw
        Tdp, taup, _, _ = least_squares(inputs.Tp, m.betas, list(om), point.weights, ms)
        J[:, i] = [(Tdp - point.Td) / dw, (taup - point.tau_eff) / dw]
    cov = (J * (_TWO_PI * m.f_unc) ** 2) @ J.T
    Td_est = _delta_estimate(point.Td, math.sqrt(max(cov[0, 0], 0.0)), "s")
    tau_est = _delta_estimate(point.tau, math.sqrt(max(cov[1, 1], 0.0)), "s")
    return _Spread(Td_est, tau_est, K_est, "delta", 0, {}, ())


# ----------------------------------------------------------------------------------------------
# the one entry point
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Strategy:
    """How a family is identified: from what (``data``: ``"tests"``, :class:`TestMeasurement`, or
    ``"points"``, :class:`ResponsePoint`), by which function (``module``, ``function``: called as
    ``function(data, model, **options)``) and into which :class:`~mrftcli.mrft.identification.IdentificationRecord`
    (``record``, in ``module``)."""

    name: str
    data: str
    module: str
    function: str
    record: str


#: the identification strategies by the name a model class declares in its ``identification``
STRATEGIES: dict[str, Strategy] = {s.name: s for s in (
    Strategy("unit-manifolds", "tests", __name__, "unit_manifolds", "IdentificationResult"),
    Strategy("response-points", "points", "mrftcli.mrft.identify_lti", "fit_response_points", "LtiIdentification"),
    Strategy("cascade-cycles", "tests", "mrftcli.mrft.cascade_identify", "fit_cascade_cycles", "CascadeIdentification"))}


@overload
def identify(data: Iterable[TestMeasurement], model: LoopModel, **options: Any) -> IdentificationResult: ...
@overload
def identify(data: Iterable[TestMeasurement], model: CascadeModel, **options: Any) -> CascadeIdentification: ...
@overload
def identify(data: Sequence[ResponsePoint], model: PlantModel, **options: Any) -> LtiIdentification: ...
def identify(data: Iterable[Any], model: PlantModel, **options: Any) -> Any:
    """Identify the unknown parameters of ``model`` (any family) from its relay tests' measurements.

    The model carries what is known (the set E, e.g. eq. (2)'s Tp from a bench test:
    ``soiptd_model(Tp)``) and the ranges of the rest (the set I); its family names the strategy
    (:data:`STRATEGIES`), and with it what ``data`` must be.

    Parameters
    ----------
    data : iterable of TestMeasurement or of ResponsePoint
        Eq. (2) and the cascade: the MRFT tests as measured (:class:`TestMeasurement`); the process
        families and a declared structure: the frequency-response points of the tests' cycles
        (:class:`~mrftcli.mrft.identify_lti.ResponsePoint`, measured by
        :func:`mrftcli.analyze.general.response_points`).
    model : PlantModel
        The structure to identify, with its known parameters and ranges.
    **options
        The strategy's own options: eq. (2)'s ``rate_hz``, ``n_draws``, ``seed``, ``spread``,
        ``manifolds`` (:func:`unit_manifolds`); the cascade's ``rate_hz``, ``inner_draws``,
        ``switch_levels``, ``tau_timing_std``
        (:func:`~mrftcli.mrft.cascade_identify.fit_cascade_cycles`); none for the response points.

    Returns
    -------
    IdentificationResult, LtiIdentification or CascadeIdentification
        The family's record (each with ``model``, the point estimate, and per-parameter
        :class:`~mrftcli.mrft.parameter.ParameterEstimate` records).

    Raises
    ------
    InputError
        ``data`` of the wrong kind for the family, an option the strategy does not take, bad input.
    IdentificationError
        No plant of the structure explains the measurements.

    Examples
    --------
    Eq. (2), the paper's example: two tests at beta -0.4 and -0.7 (frequencies in Hz, amplitudes for h = 1):

    >>> from mrftcli.mrft.model import soiptd_model
    >>> tests = [TestMeasurement(-0.4, 0.705643, amplitude=0.078530, h=1.0),
    ...          TestMeasurement(-0.7, 1.018843, amplitude=0.035602, h=1.0)]
    >>> r = identify(tests, soiptd_model(0.1))
    >>> print(f"Td {r.Td.value:.4f} s, tau {r.tau.value * 1e3:.2f} ms, K {r.K.value:.3f} ({r.method})")
    Td 0.7042 s, tau 60.00 ms, K 1.420 (intersection)

    Per-cycle frequencies give an uncertainty (Monte Carlo over their standard errors):

    >>> noisy = [TestMeasurement(-0.4, [0.7049, 0.7063, 0.7058, 0.7056]),
    ...          TestMeasurement(-0.7, [1.0180, 1.0195, 1.0189, 1.0190])]
    >>> r = identify(noisy, soiptd_model(0.1), n_draws=200)
    >>> r.uncertainty, bool(r.Td.ci95_low < r.Td.value < r.Td.ci95_high)
    ('monte-carlo', True)

    A process family from its response points (two exact points of 2 e^{-0.1 s}/(0.5 s + 1)):

    >>> from mrftcli.mrft.families import FOPDT, family_model
    >>> from mrftcli.mrft.identify_lti import ResponsePoint
    >>> G = FOPDT(K=2.0, T=0.5, tau=0.1).frequency_response(np.array([5.0, 15.0]))
    >>> pts = [ResponsePoint(w, abs(g), float(np.angle(g)), 0.01, 0.01) for w, g in zip([5.0, 15.0], G)]
    >>> fit = identify(pts, family_model("fopdt"))
    >>> [round(fit.estimate(n).value, 4) for n in ("K", "T", "tau")]
    [2.0, 0.5, 0.1]
    """
    strategy = strategy_of(model)
    data = tuple(data)
    expected = TestMeasurement if strategy.data == "tests" else ResponsePoint
    if not all(isinstance(d, expected) for d in data):
        given = sorted({type(d).__name__ for d in data if not isinstance(d, expected)})
        what = "MRFT tests as measured" if strategy.data == "tests" else "the tests' frequency-response points"
        raise InputError(f"a {model.family} model is identified from {expected.__name__} records ({what}), "
                         f"got {', '.join(given)}")
    solve, takes, needs = _strategy_function(strategy.module, strategy.function)
    other, missing = sorted(set(options) - set(takes)), [n for n in needs if n not in options]
    if other or missing:
        raise InputError(f"identify: the {model.family} model's strategy {strategy.function} "
                         + (f"needs {', '.join(missing)}" if missing else
                            f"takes {', '.join(takes) or 'no options'}, not {', '.join(other)}"))
    return solve(data, model, **options)


@functools.lru_cache(maxsize=None)
def _strategy_function(module: str, name: str) -> tuple[Any, tuple[str, ...], tuple[str, ...]]:
    """The strategy's function, the names of its options (its parameters after data and model) and of
    those it needs (no default)."""
    solve = getattr(importlib.import_module(module), name)
    options = list(inspect.signature(solve).parameters.values())[2:]
    return (solve, tuple(p.name for p in options),
            tuple(p.name for p in options if p.default is inspect.Parameter.empty))


def strategy_of(model: Any) -> Strategy:
    """The identification strategy of ``model``'s family (:data:`STRATEGIES`).

    Raises
    ------
    InputError
        Not a plant model.
    """
    name = getattr(model, "identification", None)  # the built-in families name theirs
    if name is None:  # any other structure: a response-point fit, if it is a plant model
        if not isinstance(model, PlantModel):
            raise InputError(f"identify takes a plant model (soiptd_model(Tp), family_model(...), ...), got "
                             f"{type(model).__name__}")
        name = "response-points"
    return STRATEGIES[name]


# ----------------------------------------------------------------------------------------------
# eq. (2)'s strategy, "unit-manifolds"
# ----------------------------------------------------------------------------------------------
def unit_manifolds(tests: Iterable[TestMeasurement], model: LoopModel, rate_hz: float | None = None,
                   n_draws: int = 2000, seed: int = 0, spread: str = "sem",
                   manifolds: ManifoldSet | None = None) -> IdentificationResult:
    """Eq. (2)'s strategy (:func:`identify` of a :class:`LoopModel`): Td and tau (and K) from MRFT tests at a known Tp.

    Parameters
    ----------
    tests : iterable of TestMeasurement
        Two or more tests with different betas (one test suffices only for the amplitude route,
        which needs K known and an amplitude).
    model : LoopModel
        Eq. (2) with its known set: Tp [s] from the bench test (``soiptd_model(Tp)``); with K known
        too (``soiptd_model(Tp, K=...)``) a single test's amplitude gives Td and tau (the UGM route,
        paper Section V-A), for comparison.
    rate_hz : float, optional
        Rate [Hz] of the relay that produced the tests when their betas are *nominal*.  A sampled
        relay switches on average half a sample after the continuous crossing, which looks like an
        extra delay of ``0.5 / rate_hz``; it is removed so that ``tau`` is the plant's delay
        (``docs/method.md`` measures the effect).  Which of the sampled loop's admissible orbits a
        test ran on is unknown, so each test's lag is uniform in [0, 1/rate_hz): the Monte Carlo
        includes that quantisation (two tests).  When beta is the *effective* beta measured from
        the recorded output at the actual switch instants (as ``analyze`` does), the loop is exactly
        a continuous relay switching at that level: pass ``rate_hz=None``.
    n_draws : int
        Monte Carlo draws for the uncertainty of two-test identifications.
    seed : int
        Seed of the Monte Carlo generator.
    spread : {"sem", "cycle"}
        Propagate the standard error of each test's mean frequency ("sem", the uncertainty of the
        estimate) or the per-cycle scatter itself ("cycle", the spread of per-cycle identifications
        as reported in the paper's Table III).
    manifolds : ManifoldSet, optional
        Manifolds used to bracket the solution (default: the shipped set).

    Returns
    -------
    IdentificationResult

    Raises
    ------
    InputError
        Fewer than two tests (without the amplitude route), duplicate betas, bad Tp/rate.
    IdentificationError
        The measured frequencies admit no plant of eq. (2) in the manifold range.

    """
    inputs = _check_inputs(tests, model, rate_hz, n_draws, seed, spread)
    ms = manifolds if manifolds is not None else load_manifolds()
    if len(inputs.tests) == 1:
        return _identify_amplitude(inputs)
    measured = _measure(inputs)
    point = _point_estimate(inputs, measured, ms)
    gains = _test_gains(inputs, measured, point.Td)
    per_test, identifiability = _per_test(inputs, measured, point, gains)
    est = _uncertainty(inputs, measured, point, gains, ms)
    warns = [*point.warnings, *identifiability, *est.warnings, *gain_disagreement(inputs.tests, gains)]
    if est.Td.std > 0.3 * point.Td:
        warns.append(f"Td is poorly determined by these tests: std {est.Td.std:.3g} s is "
                     f"{100 * est.Td.std / point.Td:.0f} % of the estimate")
    model = LoopModel(inputs.Tp, point.Td, point.tau, est.K.value if est.K is not None else 1.0)
    return IdentificationResult.of(est.Td, est.tau, est.K, model,
                                residual=point.residual, tests=per_test, warnings=tuple(warns), method=point.method,
                                uncertainty=est.method, rate_hz=inputs.rate_hz, n_draws=est.n_draws, draws=est.draws)


def _identify_amplitude(inputs: _Inputs) -> IdentificationResult:
    """Single-test amplitude (UGM) route with known K: the paper's comparison case (Section V-A)."""
    test, Tp, lag = inputs.tests[0], inputs.Tp, inputs.sampling_lag
    if inputs.K is None or test.amplitude_mean is None or test.h is None:
        raise InputError("identification needs two tests with different betas (one test only "
                         "determines a curve tau(Td)); or give K and the amplitude for the amplitude route")
    K, h, a_mean = inputs.K, float(test.h), test.amplitude_mean

    def solve(w: float, a: float) -> tuple[float, float]:
        target = a * w / (h * K)  # = Td * a_unit(Tp w, Td w)

        def g(lTd: float) -> float:
            Td = math.exp(lTd)
            return Td * unit_cycle_scalar(Tp * w, Td * w, test.beta)[1] - target

        lo, hi = math.log(1e-2 / w), math.log(1e3 / w)
        if not g(lo) < 0 < g(hi):
            raise IdentificationError("the amplitude cannot be produced by any plant with this Tp, K and h "
                                      "in the manifold range")
        Td = math.exp(optimize.brentq(g, lo, hi, xtol=1e-12))
        return Td, unit_cycle_scalar(Tp * w, Td * w, test.beta)[0] / w

    w0 = _TWO_PI * test.frequency_mean
    Td_hat, tau_eff = solve(w0, a_mean)
    f_unc = test.frequency_sem if inputs.spread == "sem" else test.frequency_cycle_std
    a_unc = (test.amplitude_sem if inputs.spread == "sem" else test.amplitude_cycle_std) or 0.0
    draws: dict[str, FloatArray] = {}
    if f_unc > 0 or a_unc > 0:
        n_draws = inputs.n_draws
        rng = np.random.default_rng(inputs.seed)
        fd = test.frequency_mean + f_unc * rng.standard_normal(n_draws)
        ad = a_mean + a_unc * rng.standard_normal(n_draws)
        Tds, taus = np.full(n_draws, np.nan), np.full(n_draws, np.nan)
        for j in range(n_draws):
            try:
                Tds[j], taus[j] = solve(_TWO_PI * fd[j], ad[j])
            except (IdentificationError, ValueError):
                pass
        taus = taus - lag
        draws = {"Td": Tds, "tau": taus}
        Td_est, tau_est, unc = _estimate(Tds, Td_hat, "s"), _estimate(taus, tau_eff - lag, "s"), "monte-carlo"
    else:
        Td_est = _estimate(np.array([]), Td_hat, "s")
        tau_est = _estimate(np.array([]), tau_eff - lag, "s")
        unc = "none"
    warns = ["amplitude route: sensitive to amplitude noise and to K (the paper prefers two frequencies)"]
    # the lag is the route's own here: a lead beyond the floor after removing it is refused, not floored
    tau_hat = _checked_lead(tau_eff - lag, Tp, warns)
    model = LoopModel(Tp, Td_hat, tau_hat, K)
    per = ({"beta": test.beta, "frequency_hz": test.frequency_mean, "amplitude": a_mean, "h": test.h,
            "tp_norm": Tp * w0, "td_norm": Td_hat * w0, "theta": tau_eff * w0},)
    return IdentificationResult.of(Td_est, tau_est, ParameterEstimate.given(K, ""), model,
                                residual=None, tests=per, warnings=tuple(warns), method="amplitude",
                                uncertainty=unc, rate_hz=inputs.rate_hz, n_draws=inputs.n_draws if draws else 0,
                                draws=draws)
