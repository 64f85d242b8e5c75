"""Identify Td, tau (and K) of eq. (2) from measured MRFT limit cycles via the UFM / UGM.

Each test i (beta_i, measured Omega_i) constrains the plant to one curve: scaling the UFM slice at
the known ``tp = Tp Omega_i`` back to real units (Lemma 3),

    tau_i(Td) = theta_{beta_i}(Tp Omega_i, Td Omega_i) / Omega_i .

Two tests give (Td, tau) at the intersection of their curves (paper Section IV, Fig. 5); three or
more a weighted least-squares fit in log-frequency.  The shipped manifolds only *bracket* the
solution; it is then polished with the exact closed form of :mod:`mrftcli.mrft.lprs`, so grid
interpolation never limits the accuracy.  K follows from the amplitudes through the UGM (Lemmas 2
and 4): ``a_i = h_i K Td a_unit(Tp Omega_i, Td Omega_i) / Omega_i``.

Uncertainty: the per-cycle scatter of each test's frequency (and amplitude) gives the standard
error of its mean; it is propagated by a vectorised Monte Carlo (two tests) or the delta method
(three or more) to mean, standard deviation and a 95 % interval per parameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize

from ..errors import IdentificationError, InputError
from ..validate import check_beta, check_time
from .lprs import unit_cycle, unit_cycle_scalar
from .model import LoopModel
from .ufm import ManifoldSet, load_manifolds

__all__ = [
    "TestMeasurement",
    "ParameterEstimate",
    "IdentificationResult",
    "identify",
    "ufm_slice",
    "tau_curve",
    "intersection_draws",
]

_TWO_PI = 2.0 * math.pi
#: |d ln Omega / d ln Td| below which Td is reported as poorly identifiable
_SENSITIVITY_WARN = 0.05


def _as_positive_array(name: str, value) -> np.ndarray:
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
    def _stats(x: np.ndarray) -> tuple[float, float]:
        """Mean and standard error of the mean (0 for a single value)."""
        if x.size < 2:
            return float(x[0]), 0.0
        return float(x.mean()), float(x.std(ddof=1) / math.sqrt(x.size))

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


@dataclass(frozen=True)
class ParameterEstimate:
    """An identified parameter: point estimate and its spread.

    ``mean`` is the point estimate from the mean frequencies; ``std`` and the 95 % interval come
    from the propagated scatter (zero width when no scatter was given).
    """

    mean: float
    std: float
    ci95_low: float
    ci95_high: float
    unit: str

    def to_dict(self) -> dict:
        return {"mean": self.mean, "std": self.std, "ci95_low": self.ci95_low, "ci95_high": self.ci95_high,
                "unit": self.unit}


@dataclass(frozen=True, eq=False)
class IdentificationResult:
    """Outcome of :func:`identify`.

    Attributes
    ----------
    Td, tau : ParameterEstimate
        Drag time constant [s] and delay [s] (the plant's delay: the sampling lag is removed when a
        rate was given).
    K : ParameterEstimate or None
        Gain (None without amplitudes).
    model : LoopModel
        The point estimate (K = 1 when unknown).
    Tp : float
        The known propulsion time constant [s].
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

    Td: ParameterEstimate
    tau: ParameterEstimate
    K: ParameterEstimate | None
    model: LoopModel
    Tp: float
    residual: float | None
    tests: tuple
    warnings: tuple
    method: str
    uncertainty: str
    rate_hz: float | None = None
    n_draws: int = 0
    draws: dict = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict:
        """JSON-ready dict: ``parameters.{Td,tau,K}.{mean,std,ci95_low,ci95_high,unit}`` etc."""
        params = {"Td": self.Td.to_dict(), "tau": self.tau.to_dict(),
                  "K": None if self.K is None else self.K.to_dict(),
                  "Tp": {"mean": self.Tp, "std": 0.0, "ci95_low": self.Tp, "ci95_high": self.Tp, "unit": "s",
                         "known": True}}
        return {
            "parameters": params,
            "model": {"Tp": self.model.Tp, "Td": self.model.Td, "tau": self.model.tau,
                      "K": None if self.K is None else self.model.K},
            "method": self.method,
            "uncertainty": self.uncertainty,
            "n_draws": self.n_draws,
            "residual": self.residual,
            "rate_hz": self.rate_hz,
            "tests": [dict(t) for t in self.tests],
            "warnings": list(self.warnings),
        }


# ----------------------------------------------------------------------------------------------
# the curves tau_i(Td)
# ----------------------------------------------------------------------------------------------
def tau_curve(Tp: float, beta: float, omega: ArrayLike, Td: ArrayLike, exact: bool = True,
              manifolds: ManifoldSet | None = None) -> np.ndarray:
    """Signed delay tau [s] that makes (Tp, Td, tau) oscillate at omega [rad/s] under beta.

    Vectorised over ``omega`` and ``Td`` (broadcast).  ``exact=False`` interpolates the manifolds
    (NaN outside their grid).  Negative values: no physical plant (kept for root bracketing).
    """
    omega = np.asarray(omega, dtype=float)
    Td = np.asarray(Td, dtype=float)
    if exact:
        theta, _ = unit_cycle(Tp * omega, Td * omega, beta)
    else:
        ms = manifolds if manifolds is not None else load_manifolds()
        theta, _ = ms.evaluate(beta, Tp * omega, Td * omega)
    return theta / omega


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
# point solvers (scalar, exact)
# ----------------------------------------------------------------------------------------------
class _Curve:
    """Exact scalar tau_i(Td) for one test, with warm-started Newton iterations."""

    def __init__(self, Tp: float, beta: float, omega: float) -> None:
        self.Tp, self.beta, self.omega = Tp, beta, omega
        self.warm: list = []

    def tau(self, Td: float) -> float:
        w = self.omega
        theta, _ = unit_cycle_scalar(self.Tp * w, Td * w, self.beta, self.warm)
        return theta / w

    def amp_unit(self, Td: float) -> float:
        w = self.omega
        return unit_cycle_scalar(self.Tp * w, Td * w, self.beta)[1]


def _td_range(ms: ManifoldSet, omegas: Sequence[float]) -> tuple[float, float]:
    """Range of Td [s] covered by the manifold grid for every test."""
    lo = max(ms.td_n[0] / w for w in omegas)
    hi = min(ms.td_n[-1] / w for w in omegas)
    return lo, hi


def _bracket_grid(ms: ManifoldSet, Tp: float, betas, omegas, n: int = 96):
    lo, hi = _td_range(ms, omegas)
    if not lo < hi:
        raise IdentificationError("the tests' frequencies are too far apart for the manifold range")
    Td = np.geomspace(lo, hi, n)
    taus = []
    for b, w in zip(betas, omegas):
        tp = Tp * w
        exact = not (ms.tp_n[0] <= tp <= ms.tp_n[-1])
        taus.append(tau_curve(Tp, b, w, Td, exact=exact or not ms.covers(b), manifolds=ms))
    return Td, np.array(taus)


def _intersection(Tp: float, betas, omegas, ms: ManifoldSet) -> tuple[float, float, list[str]]:
    """Exact intersection of two curves tau_1(Td) = tau_2(Td); returns Td, tau, warnings."""
    warns: list[str] = []
    Td, taus = _bracket_grid(ms, Tp, betas, omegas)
    D = taus[0] - taus[1]
    ok = np.isfinite(D)
    s = np.sign(D)
    idx = np.nonzero(ok[:-1] & ok[1:] & (s[:-1] * s[1:] <= 0) & (s[:-1] != s[1:]))[0]
    if idx.size == 0:
        for b, w, row in zip(betas, omegas, taus):
            if np.all(~(row >= 0)):
                raise IdentificationError(
                    f"{w / _TWO_PI:.4g} Hz at beta {b:g} is too fast for Tp = {Tp:g} s: no plant of eq. (2) with "
                    "a non-negative delay oscillates there (check Tp and the frequency units, Hz)"
                )
        raise IdentificationError(
            f"the UFM slices of the tests (beta {betas[0]:g} at {omegas[0] / _TWO_PI:.4g} Hz, beta {betas[1]:g} at "
            f"{omegas[1] / _TWO_PI:.4g} Hz) do not intersect for Tp = {Tp:g} s: no plant of eq. (2) produces both "
            "frequencies (check Tp, the betas and the frequencies; a more negative beta must give a higher frequency)"
        )
    # prefer an intersection with a physical (non-negative) delay
    mids = 0.5 * (taus[0, idx] + taus[0, idx + 1])
    phys = idx[mids >= -1e-12]
    k = int(phys[0]) if phys.size else int(idx[0])
    if phys.size > 1:
        warns.append(f"the slices intersect {phys.size} times; the smallest Td was taken")
    c1, c2 = _Curve(Tp, betas[0], omegas[0]), _Curve(Tp, betas[1], omegas[1])
    x_lo, x_hi = math.log(Td[k]), math.log(Td[k + 1])

    def d(x: float) -> float:
        t = math.exp(x)
        return c1.tau(t) - c2.tau(t)

    f_lo, f_hi = d(x_lo), d(x_hi)
    if f_lo == 0:
        x = x_lo
    elif f_hi == 0:
        x = x_hi
    elif f_lo * f_hi > 0:
        # interpolation error moved the crossing (nearly parallel curves): scan the exact curves
        xs = np.linspace(math.log(Td[0]), math.log(Td[-1]), 4 * Td.size)
        ds = (tau_curve(Tp, betas[0], omegas[0], np.exp(xs)) - tau_curve(Tp, betas[1], omegas[1], np.exp(xs)))
        ch = np.nonzero((np.sign(ds[:-1]) * np.sign(ds[1:]) <= 0)
                        & (tau_curve(Tp, betas[0], omegas[0], np.exp(xs[:-1])) >= -1e-12))[0]
        if ch.size == 0:
            raise IdentificationError(
                "the UFM slices of the tests only touch (nearly parallel curves): Td and tau cannot be "
                "separated with these betas; use betas further apart"
            )
        x = optimize.brentq(d, xs[ch[0]], xs[ch[0] + 1], xtol=1e-11, rtol=1e-12)
    else:
        x = optimize.brentq(d, x_lo, x_hi, xtol=1e-11, rtol=1e-12)
    Td_hat = math.exp(x)
    return Td_hat, c1.tau(Td_hat), warns


def _log_freq_residuals(Tp: float, Td: float, tau: float, betas, omegas, eps: float = 1e-5) -> np.ndarray:
    """First-order log-frequency residuals ln(Omega_model / Omega_measured) of each test.

    F_i(Omega) = theta(Tp Omega, Td Omega) - tau Omega vanishes at the model's frequency, so
    ln Omega_model - ln Omega_i ~= -F_i(Omega_i) / (dF_i / d ln Omega).
    """
    r = np.empty(len(betas))
    for i, (b, w) in enumerate(zip(betas, omegas)):
        def F(lw: float, b: float = b) -> float:
            ww = math.exp(lw)
            return unit_cycle_scalar(Tp * ww, Td * ww, b)[0] - tau * ww

        lw = math.log(w)
        f0 = F(lw)
        dF = (F(lw + eps) - F(lw - eps)) / (2 * eps)
        r[i] = -f0 / dF if dF != 0 else np.inf
    return r


def _model_frequency_sensitivity(Tp: float, Td: float, tau: float, beta: float, omega: float,
                                 eps: float = 1e-6) -> tuple[float, float]:
    """d ln Omega / d ln Td and d ln Omega / d tau [1/s] at the model point (implicit function).

    F(ln Omega, ln Td) = theta(Tp Omega, Td Omega) - tau Omega; dlnOmega/dlnTd = -F_lnTd / F_lnOmega,
    dlnOmega/dtau = Omega / F_lnOmega.  Central differences; the shared warm start keeps each
    evaluation to two or three Newton steps.
    """
    warm: list = []

    def F(lw: float, lTd: float) -> float:
        ww = math.exp(lw)
        return unit_cycle_scalar(Tp * ww, math.exp(lTd) * ww, beta, warm)[0] - tau * ww

    lw, lTd = math.log(omega), math.log(Td)
    dF_dlw = (F(lw + eps, lTd) - F(lw - eps, lTd)) / (2 * eps)
    dF_dlTd = (F(lw, lTd + eps) - F(lw, lTd - eps)) / (2 * eps)
    return -dF_dlTd / dF_dlw, omega / dF_dlw


def _least_squares(Tp: float, betas, omegas, weights, ms: ManifoldSet) -> tuple[float, float, float, list[str]]:
    """Weighted least squares over (ln Td, tau) for three or more tests."""
    warns: list[str] = []
    # start: intersection of the two tests with the most different betas
    i0, i1 = int(np.argmin(betas)), int(np.argmax(betas))
    try:
        Td0, tau0, _ = _intersection(Tp, [betas[i0], betas[i1]], [omegas[i0], omegas[i1]], ms)
    except IdentificationError:
        Td0, tau0 = 1.0 / float(np.median(omegas)), 0.1 / float(np.median(omegas))
    sw = np.sqrt(weights)

    def res(p: np.ndarray) -> np.ndarray:
        return sw * _log_freq_residuals(Tp, math.exp(p[0]), p[1], betas, omegas)

    sol = optimize.least_squares(res, x0=[math.log(Td0), tau0], x_scale=[1.0, max(tau0, 1e-3)], method="lm",
                                 xtol=1e-12, ftol=1e-12)
    Td_hat, tau_hat = math.exp(sol.x[0]), float(sol.x[1])
    r = _log_freq_residuals(Tp, Td_hat, tau_hat, betas, omegas)
    rms = float(math.sqrt(np.sum(weights * r * r) / np.sum(weights)))
    return Td_hat, tau_hat, rms, warns


# ----------------------------------------------------------------------------------------------
# vectorised solver for Monte Carlo draws (two tests)
# ----------------------------------------------------------------------------------------------
def intersection_draws(Tp: float, betas: Sequence[float], omega_draws: np.ndarray, ms: ManifoldSet, Td_ref: float,
                        iters: int = 40, lags: np.ndarray | None = None) -> np.ndarray:
    """Td for each row of omega_draws (M, 2); NaN where the draws' slices do not intersect.

    ``lags`` (M, 2) [s], optional: per-test extra delay of each draw (the sampled relay's switching
    lag); curve i becomes tau_i(Td) - lag_i.

    Bracket on a log grid around the point estimate (interpolated manifolds, exact outside their
    range), then the Illinois variant of regula falsi on the exact closed form, vectorised over the
    draws.
    """
    M = omega_draws.shape[0]
    if lags is None:
        lags = np.zeros((M, 2))
    grid = Td_ref * np.geomspace(1e-2, 1e2, 49)
    D = np.empty((M, grid.size))
    taus = []
    for i in range(2):
        w = omega_draws[:, i : i + 1]
        tp = Tp * w
        td = grid[None, :] * w
        covered = ms.covers(betas[i]) and np.all((tp >= ms.tp_n[0]) & (tp <= ms.tp_n[-1]))
        if covered:
            th, _ = ms.evaluate(betas[i], np.broadcast_to(tp, td.shape), td)
            bad = ~np.isfinite(th)
            if np.any(bad):
                th_ex, _ = unit_cycle(np.broadcast_to(tp, td.shape)[bad], td[bad], betas[i])
                th[bad] = th_ex
        else:
            th, _ = unit_cycle(np.broadcast_to(tp, td.shape), td, betas[i])
        taus.append(th / w - lags[:, i : i + 1])
    D = taus[0] - taus[1]
    s = np.sign(D)
    change = (s[:, :-1] * s[:, 1:] < 0) & (taus[0][:, :-1] >= -1e-12)
    has = change.any(axis=1)
    k = np.argmax(change, axis=1)
    x_lo = np.log(grid[k])
    x_hi = np.log(grid[np.minimum(k + 1, grid.size - 1)])
    rows = np.nonzero(has)[0]
    out = np.full(M, np.nan)
    if rows.size == 0:
        return out
    w1, w2 = omega_draws[rows, 0], omega_draws[rows, 1]
    l1, l2 = lags[rows, 0], lags[rows, 1]

    def d(x: np.ndarray) -> np.ndarray:
        t = np.exp(x)
        th1, _ = unit_cycle(Tp * w1, t * w1, betas[0])
        th2, _ = unit_cycle(Tp * w2, t * w2, betas[1])
        return (th1 / w1 - l1) - (th2 / w2 - l2)

    a, b = x_lo[rows], x_hi[rows]
    fa, fb = d(a), d(b)
    side = np.zeros(rows.size)
    c_prev = np.full(rows.size, np.inf)
    for _ in range(iters):
        c = (a * fb - b * fa) / (fb - fa)
        c = np.where(np.isfinite(c), c, 0.5 * (a + b))
        if np.all(np.abs(c - c_prev) < 1e-11):
            break
        c_prev = c
        fc = d(c)
        left = fc * fa > 0  # root in [c, b]
        # Illinois: halve the retained end's value when the same side is kept twice
        a_new = np.where(left, c, a)
        fa_new = np.where(left, fc, np.where(side == -1, 0.5 * fa, fa))
        b_new = np.where(left, b, c)
        fb_new = np.where(left, np.where(side == 1, 0.5 * fb, fb), fc)
        side = np.where(left, 1, -1)
        a, b, fa, fb = a_new, b_new, fa_new, fb_new
    out[rows] = np.exp(c)
    return out


# ----------------------------------------------------------------------------------------------
# the public entry point
# ----------------------------------------------------------------------------------------------
def _estimate(values: np.ndarray, point: float, unit: str) -> ParameterEstimate:
    v = values[np.isfinite(values)]
    if v.size < 2:
        return ParameterEstimate(point, 0.0, point, point, unit)
    lo, hi = np.percentile(v, [2.5, 97.5])
    return ParameterEstimate(point, float(v.std(ddof=1)), float(lo), float(hi), unit)


def _delta_estimate(point: float, std: float, unit: str) -> ParameterEstimate:
    return ParameterEstimate(point, std, point - 1.959964 * std, point + 1.959964 * std, unit)


def identify(tests: Iterable[TestMeasurement], Tp: float, rate_hz: float | None = None, K: float | None = None,
             n_draws: int = 2000, seed: int = 0, spread: str = "sem",
             manifolds: ManifoldSet | None = None) -> IdentificationResult:
    """Identify Td and tau (and K) of eq. (2) from MRFT tests at a known Tp.

    Parameters
    ----------
    tests : iterable of TestMeasurement
        Two or more tests with different betas (one test suffices only for the amplitude route,
        which needs ``K`` and an amplitude).
    Tp : float
        Propulsion time constant [s] from the bench test.
    rate_hz : float, optional
        Rate [Hz] of the relay that produced the tests when their betas are *nominal*.  A sampled
        relay switches on average half a sample after the continuous crossing, which looks like an
        extra delay of ``0.5 / rate_hz``; it is removed so that ``tau`` is the plant's delay
        (``docs/method.md`` measures the effect).  Which of the sampled loop's admissible orbits a
        test ran on is unknown, so each test's lag is uniform in [0, 1/rate_hz): the Monte Carlo
        includes that quantisation (two tests).  When beta is the *effective* beta measured from
        the recorded output at the actual switch instants (as ``analyze`` does), the loop is exactly
        a continuous relay switching at that level: pass ``rate_hz=None``.
    K : float, optional
        Known gain: enables the single-test amplitude route (UGM, paper Section V-A) for comparison.
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

    Examples
    --------
    The paper's example: two tests at beta -0.4 and -0.7 (frequencies in Hz, amplitudes for h = 1):

    >>> tests = [TestMeasurement(-0.4, 0.705643, amplitude=0.078530, h=1.0),
    ...          TestMeasurement(-0.7, 1.018843, amplitude=0.035602, h=1.0)]
    >>> r = identify(tests, Tp=0.1)
    >>> print(f"Td {r.Td.mean:.4f} s, tau {r.tau.mean * 1e3:.2f} ms, K {r.K.mean:.3f} ({r.method})")
    Td 0.7042 s, tau 60.00 ms, K 1.420 (intersection)

    Per-cycle frequencies give an uncertainty (Monte Carlo over their standard errors):

    >>> noisy = [TestMeasurement(-0.4, [0.7049, 0.7063, 0.7058, 0.7056]),
    ...          TestMeasurement(-0.7, [1.0180, 1.0195, 1.0189, 1.0190])]
    >>> r = identify(noisy, Tp=0.1, n_draws=200)
    >>> r.uncertainty, bool(r.Td.ci95_low < r.Td.mean < r.Td.ci95_high)
    ('monte-carlo', True)
    """
    tests = list(tests)
    for t in tests:
        if not isinstance(t, TestMeasurement):
            raise InputError("tests must be TestMeasurement objects")
    Tp = check_time("Tp", Tp)
    if rate_hz is not None:
        rate_hz = float(rate_hz)
        if not math.isfinite(rate_hz) or rate_hz <= 0:
            raise InputError(f"rate must be a positive frequency in Hz, got {rate_hz}")
    if spread not in ("sem", "cycle"):
        raise InputError("spread must be 'sem' or 'cycle'")
    if int(n_draws) < 10:
        raise InputError(f"n_draws must be at least 10, got {n_draws}")
    n_draws = int(n_draws)
    if K is not None and (not math.isfinite(float(K)) or float(K) == 0):
        raise InputError(f"K must be finite and non-zero, got {K}")
    sampling_lag = 0.0 if rate_hz is None else 0.5 / rate_hz
    ms = manifolds if manifolds is not None else load_manifolds()
    if len(tests) == 1:
        if K is None or tests[0].amplitude is None:
            raise InputError("identification needs two tests with different betas (one test only "
                             "determines a curve tau(Td)); or give K and the amplitude for the amplitude route")
        return _identify_amplitude(tests[0], Tp, float(K), sampling_lag, rate_hz, n_draws, seed, spread)
    if len(tests) < 2:
        raise InputError("identification needs at least two tests with different betas")
    betas = [t.beta for t in tests]
    if len(set(np.round(betas, 6))) < len(betas) and len(tests) == 2:
        raise InputError("the two tests have the same beta: they determine the same curve, use different betas")
    if len(set(np.round(betas, 6))) < 2:
        raise InputError("all tests have the same beta; at least two different betas are needed")
    f_mean = np.array([t.frequency_mean for t in tests])
    if spread == "sem":
        f_unc = np.array([t.frequency_sem for t in tests])
    else:
        f_unc = np.array([t.frequency_cycle_std for t in tests])
    omegas = _TWO_PI * f_mean
    warns: list[str] = []
    if len(tests) == 2:
        Td_hat, tau_eff, w2 = _intersection(Tp, betas, list(omegas), ms)
        warns += w2
        residual = None
        method = "intersection"
    else:
        rel = f_unc / f_mean
        weights = np.where(rel > 0, 1.0 / np.maximum(rel, 1e-12) ** 2, 1.0) if np.all(rel > 0) else np.ones(len(tests))
        Td_hat, tau_eff, residual, w2 = _least_squares(Tp, betas, list(omegas), weights, ms)
        warns += w2
        method = "least-squares"
    tau_hat = tau_eff - sampling_lag
    if tau_eff < -1e-9 * max(1.0, 1.0 / omegas.min()):
        raise IdentificationError(
            f"the measured frequencies imply a negative delay (tau = {tau_eff * 1e3:.3g} ms): no plant of eq. (2) "
            f"with Tp = {Tp:g} s fits; check Tp and the betas"
        )
    if tau_hat < 0:
        warns.append(f"removing the sampling lag ({sampling_lag * 1e3:.3g} ms) leaves a negative delay; tau set to 0")
        tau_hat = 0.0
    tau_eff = max(tau_eff, 0.0)

    # --- K from the amplitudes (UGM) -----------------------------------------------------------
    K_i = []
    for t, w in zip(tests, omegas):
        if t.amplitude is None:
            K_i.append(None)
            continue
        a_unit = unit_cycle_scalar(Tp * w, Td_hat * w, t.beta)[1]
        K_i.append(t.amplitude_mean * w / (float(t.h) * Td_hat * a_unit))
    have_K = [k for k in K_i if k is not None]
    K_hat = float(np.mean(have_K)) if have_K else None

    # --- per-test information and identifiability ------------------------------------------------
    per_test = []
    sens = []
    for i, (t, w) in enumerate(zip(tests, omegas)):
        s_td, s_tau = _model_frequency_sensitivity(Tp, Td_hat, tau_eff, t.beta, w)
        sens.append(s_td)
        per_test.append({
            "beta": t.beta,
            "frequency_hz": float(f_mean[i]),
            "frequency_sem_hz": float(t.frequency_sem),
            "n_cycles": t.n_cycles,
            "amplitude": t.amplitude_mean,
            "h": t.h,
            "tp_norm": Tp * w,
            "td_norm": Td_hat * w,
            "theta": tau_eff * w,
            "dlnOmega_dlnTd": s_td,
            "dlnOmega_dtau": s_tau,
            "K": K_i[i],
            # the curve of this test in real units is ufm_slice(Tp, beta, frequency_hz, Td) - sampling_lag
            "sampling_lag": sampling_lag,
        })
    if max(abs(s) for s in sens) < _SENSITIVITY_WARN:
        warns.append(
            f"Td is poorly identifiable: Td*Omega = {max(p['td_norm'] for p in per_test):.3g}, a 10 % change of Td "
            f"moves the test frequencies by at most {10 * max(abs(s) for s in sens):.2g} %"
        )
    spread_b = max(betas) - min(betas)
    if spread_b < 0.2:
        warns.append(f"the betas differ by only {spread_b:.2g}; Td and tau are better determined with betas "
                     "further apart (e.g. -0.4 and -0.7)")

    # --- uncertainty -------------------------------------------------------------------------
    draws: dict = {}
    a_unc_any = any(t.amplitude is not None and (t.amplitude_sem or 0) > 0 for t in tests)
    if np.all(f_unc == 0) and not a_unc_any and (rate_hz is None or len(tests) != 2):
        uncertainty = "none"
        Td_est = _estimate(np.array([]), Td_hat, "s")
        tau_est = _estimate(np.array([]), tau_hat, "s")
        K_est = None if K_hat is None else _estimate(np.array([]), K_hat, "")
        n_used = 0
    elif len(tests) == 2:
        uncertainty = "monte-carlo"
        rng = np.random.default_rng(seed)
        wd = _TWO_PI * (f_mean[None, :] + f_unc[None, :] * rng.standard_normal((n_draws, 2)))
        wd = np.where(wd > 0, wd, np.nan)
        # sampled relay: each test's switching lag is uniform in [0, Ts) (its orbit is unknown)
        lag_d = None if rate_hz is None else rng.uniform(0.0, 1.0 / rate_hz, (n_draws, 2))
        Td_d = intersection_draws(Tp, betas, np.nan_to_num(wd, nan=omegas.mean()), ms, Td_hat, lags=lag_d)
        Td_d[~np.all(np.isfinite(wd), axis=1)] = np.nan
        ok = np.isfinite(Td_d)
        th1, a1 = unit_cycle(Tp * wd[ok, 0], Td_d[ok] * wd[ok, 0], betas[0])
        tau_d = np.full(n_draws, np.nan)
        tau_d[ok] = th1 / wd[ok, 0] - (sampling_lag if lag_d is None else lag_d[ok, 0])
        n_used = int(ok.sum())
        if n_used < n_draws:
            warns.append(f"{n_draws - n_used} of {n_draws} Monte Carlo draws admitted no plant (large scatter)")
        Td_est = _estimate(Td_d, Td_hat, "s")
        tau_est = _estimate(tau_d, tau_hat, "s")
        draws = {"Td": Td_d, "tau": tau_d}
        K_est = None
        if K_hat is not None:
            K_d_all = []
            for i, t in enumerate(tests):
                if t.amplitude is None:
                    continue
                a_unc = t.amplitude_sem if spread == "sem" else t.amplitude_cycle_std
                a_d = t.amplitude_mean + a_unc * rng.standard_normal(n_draws)
                _, au = unit_cycle(Tp * wd[ok, i], Td_d[ok] * wd[ok, i], betas[i])
                kd = np.full(n_draws, np.nan)
                kd[ok] = a_d[ok] * wd[ok, i] / (float(t.h) * Td_d[ok] * au)
                K_d_all.append(kd)
            K_d = np.nanmean(np.array(K_d_all), axis=0) if K_d_all else np.full(n_draws, np.nan)
            draws["K"] = K_d
            K_est = _estimate(K_d, K_hat, "")
    else:
        uncertainty = "delta"
        n_used = 0
        J = np.zeros((2, len(tests)))
        for i in range(len(tests)):
            if f_unc[i] == 0:
                continue
            om = omegas.copy()
            dw = 1e-4 * om[i]
            om[i] += dw
            Tdp, taup, _, _ = _least_squares(Tp, betas, list(om), weights, ms)
            J[:, i] = [(Tdp - Td_hat) / dw, (taup - tau_eff) / dw]
        cov = (J * (_TWO_PI * f_unc) ** 2) @ J.T
        Td_est = _delta_estimate(Td_hat, math.sqrt(max(cov[0, 0], 0.0)), "s")
        tau_est = _delta_estimate(tau_hat, math.sqrt(max(cov[1, 1], 0.0)), "s")
        K_est = None if K_hat is None else _delta_estimate(K_hat, float(np.std(have_K, ddof=1)) if len(have_K) > 1 else 0.0, "")
    if Td_est.std > 0.3 * Td_hat:
        warns.append(f"Td is poorly determined by these tests: std {Td_est.std:.3g} s is "
                     f"{100 * Td_est.std / Td_hat:.0f} % of the estimate")
    model = LoopModel(Tp, Td_hat, tau_hat, K_hat if K_hat is not None else 1.0)
    return IdentificationResult(Td=Td_est, tau=tau_est, K=K_est, model=model, Tp=Tp, residual=residual,
                                tests=tuple(per_test), warnings=tuple(warns), method=method,
                                uncertainty=uncertainty, rate_hz=rate_hz, n_draws=n_used, draws=draws)


def _identify_amplitude(test: TestMeasurement, Tp: float, K: float, sampling_lag: float, rate_hz, n_draws: int,
                        seed: int, spread: str) -> IdentificationResult:
    """Single-test amplitude (UGM) route with known K: the paper's comparison case (Section V-A)."""

    def solve(w: float, a: float) -> tuple[float, float]:
        target = a * w / (float(test.h) * K)  # = Td * a_unit(Tp w, Td w)

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
    Td_hat, tau_eff = solve(w0, test.amplitude_mean)
    f_unc = test.frequency_sem if spread == "sem" else test.frequency_cycle_std
    a_unc = test.amplitude_sem if spread == "sem" else test.amplitude_cycle_std
    draws: dict = {}
    if f_unc > 0 or (a_unc or 0) > 0:
        rng = np.random.default_rng(seed)
        fd = test.frequency_mean + f_unc * rng.standard_normal(n_draws)
        ad = test.amplitude_mean + (a_unc or 0) * rng.standard_normal(n_draws)
        Tds, taus = np.full(n_draws, np.nan), np.full(n_draws, np.nan)
        for j in range(n_draws):
            try:
                Tds[j], taus[j] = solve(_TWO_PI * fd[j], ad[j])
            except (IdentificationError, ValueError):
                pass
        taus = taus - sampling_lag
        draws = {"Td": Tds, "tau": taus}
        Td_est, tau_est, unc = _estimate(Tds, Td_hat, "s"), _estimate(taus, tau_eff - sampling_lag, "s"), "monte-carlo"
    else:
        Td_est = _estimate(np.array([]), Td_hat, "s")
        tau_est = _estimate(np.array([]), tau_eff - sampling_lag, "s")
        unc = "none"
    warns = ["amplitude route: sensitive to amplitude noise and to K (the paper prefers two frequencies)"]
    tau_hat = max(tau_eff - sampling_lag, 0.0)
    model = LoopModel(Tp, Td_hat, tau_hat, K)
    per = ({"beta": test.beta, "frequency_hz": test.frequency_mean, "amplitude": test.amplitude_mean, "h": test.h,
            "tp_norm": Tp * w0, "td_norm": Td_hat * w0, "theta": tau_eff * w0},)
    return IdentificationResult(Td=Td_est, tau=tau_est, K=ParameterEstimate(K, 0.0, K, K, ""), model=model, Tp=Tp,
                                residual=None, tests=per, warnings=tuple(warns), method="amplitude",
                                uncertainty=unc, rate_hz=rate_hz, n_draws=n_draws if draws else 0, draws=draws)
