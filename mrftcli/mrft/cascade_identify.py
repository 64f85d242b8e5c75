"""Identification of an outer loop through its closed inner loop (the cascade of :mod:`mrftcli.mrft.cascade`):
the ``"cascade-cycles"`` strategy of :func:`mrftcli.mrft.identify.identify`.

Td and tau (and K when it is not known) are found from the outer MRFT tests' mean frequencies and
amplitudes through the exact sampled limit cycle of the whole cascade
(:meth:`~mrftcli.mrft.cascade.CascadeModel.sampled_limit_cycle`), by weighted least squares in
logarithms. The inner model's uncertainty is propagated by solving again for draws of the inner loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from ..errors import IdentificationError, InputError
from ..validate import check_positive
from .cascade import CASCADE_PARAMETERS, STANDARD_GRAVITY, CascadeModel, InnerLoop
from .controller import json_number
from .identify import TestMeasurement
from .identification import IdentificationRecord
from .parameter import ParameterEstimate, fitted_estimate
from .lprs import LimitCycle

__all__ = ["CascadeIdentification", "CascadeTestFit", "fit_cascade_cycles", "TD_BOUNDS",
           "TAU_BOUNDS"]

FloatArray = NDArray[np.float64]
_INF = math.inf
#: the method of the parameters this fit identifies (ParameterEstimate.method)
_METHOD = "cascade-cycles"
#: floor of the standard errors of ln(frequency) and ln(amplitude) of a test (as identify_lti's)
_SE_FLOOR = 5e-3
#: floor of the standard error of a test's switch level over its amplitude [-] (about 0.7 ms of tau at 2 rad/s)
_SE_LEVEL_FLOOR = 1e-3
#: the outer Td [s] and tau [s] searched (the set I when the model's ``ranges`` do not narrow it)
TD_BOUNDS, TAU_BOUNDS = (0.05, 50.0), (0.0, 0.5)


@dataclass(frozen=True)
class CascadeTestFit:
    """One outer test as measured and as the identified cascade predicts it.

    Attributes
    ----------
    beta, h : float
        The relay's beta and height [command units].
    frequency_hz, amplitude : float
        Measured mean frequency [Hz] and amplitude [output units] (NaN: no amplitude).
    predicted_hz, predicted_amplitude : float
        The exact sampled cycle's centre for the estimate [Hz], [output units].
    band_hz : tuple of float
        (lowest, highest) frequency of the admissible sampled orbits [Hz].
    """

    beta: float
    h: float
    frequency_hz: float
    amplitude: float
    predicted_hz: float
    predicted_amplitude: float
    band_hz: tuple[float, float]

    def to_json(self) -> dict[str, Any]:
        return {"beta": self.beta, "h": self.h, "frequency_hz": self.frequency_hz,
                "amplitude": self.amplitude if math.isfinite(self.amplitude) else None,
                "predicted_hz": self.predicted_hz, "predicted_amplitude": self.predicted_amplitude,
                "band_hz": list(self.band_hz)}

    @classmethod
    def from_json(cls, data: Any) -> CascadeTestFit:
        if not isinstance(data, Mapping):
            raise InputError("cascade identification JSON: each test must be an object")
        amp = data.get("amplitude")
        band = data.get("band_hz") or [math.nan, math.nan]
        def num(key: str) -> float:
            return json_number(data, key, "cascade test", finite=True)

        return cls(num("beta"), num("h"), num("frequency_hz"), math.nan if amp is None else float(amp),
                   num("predicted_hz"), num("predicted_amplitude"), (float(band[0]), float(band[1])))


@dataclass(frozen=True)
class CascadeIdentification(IdentificationRecord):
    """The outer loop identified through its inner loop (:func:`fit_cascade_cycles`): the one
    :class:`~mrftcli.mrft.identification.IdentificationRecord` with the cascade's figures.

    Attributes
    ----------
    model : CascadeModel
        The point estimate (with the nominal inner loop).
    estimates : tuple of ParameterEstimate
        Td [s], tau [s], K with std and 95 % interval: the tests' scatter and the inner model's
        draws together (``std`` is their root sum of squares).
    tests : tuple of CascadeTestFit
        Each test measured and predicted.
    rate_hz : float
        The outer relay's rate [Hz].
    inner_draws : int
        How many draws of the inner loop were solved (0: the inner model taken as exact).
    inner_std : mapping of str to float
        The part of each std due to the inner model alone [unit].
    """

    tests: tuple[CascadeTestFit, ...]
    rate_hz: float
    inner_draws: int = 0
    inner_std: Mapping[str, float] = field(default_factory=dict)

    _method: ClassVar[str] = _METHOD

    def fit_json(self) -> dict[str, Any]:
        """``tests``, ``rate_hz``, ``inner_draws``, ``inner_std``."""
        return {"tests": [t.to_json() for t in self.tests], "rate_hz": self.rate_hz,
                "inner_draws": self.inner_draws, "inner_std": dict(self.inner_std)}

    @classmethod
    def fit_from_json(cls, data: Mapping[str, Any], model: Any,
                      estimates: tuple[ParameterEstimate, ...]) -> CascadeIdentification:
        """The record from :meth:`fit_json`'s keys of ``data``."""
        return cls(model, estimates, tuple(CascadeTestFit.from_json(t) for t in data.get("tests") or ()),
                   json_number(data, "rate_hz", "cascade identification JSON", finite=True),
                   int(data.get("inner_draws") or 0), {str(k): float(v) for k, v in (data.get("inner_std") or {}).items()})


@dataclass(frozen=True)
class _Problem:
    """What the solver holds fixed: the tests, their weights, the free parameters and their bounds."""

    tests: tuple[TestMeasurement, ...]
    rate_hz: float
    free: tuple[str, ...]  # "Td", "tau" and maybe "K"
    lower: FloatArray
    upper: FloatArray
    se_f: FloatArray  # standard errors of ln f per test
    se_a: FloatArray  # of ln a (inf: no amplitude)
    #: each test's measured level at the down switch over its amplitude (None: match the frequencies instead)
    levels: FloatArray | None = None
    se_l: FloatArray | None = None  # their standard errors
    #: each test's last half period [ticks]: the next evaluation's start (a cache, not part of the problem)
    hints: dict[int, float] = field(default_factory=dict, compare=False)

    def model(self, base: CascadeModel, theta: FloatArray) -> CascadeModel:
        values = {name: (float(v) if name == "tau" else math.exp(float(v))) for name, v in zip(self.free, theta)}
        return base.with_parameters(**values)

    def cycles(self, model: CascadeModel) -> list[LimitCycle]:
        out = []
        for i, t in enumerate(self.tests):
            h = float(t.h or 1.0)
            try:
                lc = model.sampled_limit_cycle(t.beta, h, self.rate_hz, self.hints.get(i))
            except InputError:
                if i not in self.hints:
                    raise
                lc = model.sampled_limit_cycle(t.beta, h, self.rate_hz)  # the last cycle was far from this one
            self.hints[i] = 0.5 * self.rate_hz / lc.frequency_hz
            out.append(lc)
        return out

    def residuals(self, base: CascadeModel, theta: FloatArray) -> FloatArray:
        if self.levels is not None:
            return self.orbit_residuals(self.model(base, theta))
        try:
            cycles = self.cycles(self.model(base, theta))
        except InputError:
            return np.full(2 * len(self.tests), 1e3)
        out = []
        for t, lc, sf, sa in zip(self.tests, cycles, self.se_f, self.se_a):
            out.append((math.log(lc.frequency_hz) - math.log(t.frequency_mean)) / sf)
            a = t.amplitude_mean
            out.append(0.0 if a is None or not math.isfinite(sa) else (math.log(lc.amplitude) - math.log(a)) / sa)
        return np.array(out)

    def orbit_residuals(self, model: CascadeModel) -> FloatArray:
        """Each test's amplitude and switch level against the orbit of its measured half period.

        The measured frequency names the orbit (a whole number of ticks per half period, or between
        two when the loop alternates); at that orbit the amplitude holds Td (K known) and the level
        at the switch holds tau continuously, where the centre of the band of orbits moves by whole
        ticks only and the beta to match it must be known to a few thousandths (issue 23).
        """
        assert self.levels is not None and self.se_l is not None
        out = []
        for t, level, sl, sa in zip(self.tests, self.levels, self.se_l, self.se_a):
            try:
                orbit = model.orbit_at(0.5 * self.rate_hz / t.frequency_mean, float(t.h or 1.0), self.rate_hz)
            except InputError:
                return np.full(2 * len(self.tests), 1e3)
            out += [(math.log(orbit.amplitude) - math.log(float(t.amplitude_mean or 1.0))) / sa,
                    (orbit.switch_level - level) / sl]
        r = np.array(out)
        return r if np.isfinite(r).all() else np.full(r.size, 1e3)


def _theta0(problem: _Problem, base: CascadeModel) -> FloatArray:
    """A start for the exact solve: the best point of a (Td, tau, K) grid by the describing function.

    T_inner does not depend on the outer parameters, so it is computed once; the relay's sampling
    lag is half a tick of delay. The describing function is only the start (a few % off the
    exact cycle, which the least squares then matches).
    """
    T = 1.0 / problem.rate_hz
    w = np.geomspace(1e-2, 0.99 * math.pi * problem.rate_hz, 700)
    s = 1j * w
    t_inner = base.inner.closed_response(w) * np.exp(-0.5 * T * s)
    i_td, i_tau = problem.free.index("Td"), problem.free.index("tau")
    tds = np.exp(np.linspace(problem.lower[i_td], problem.upper[i_td], 25))
    taus = np.linspace(problem.lower[i_tau], min(problem.upper[i_tau], 0.3), 21)
    TD, TAU = np.meshgrid(tds, taus, indexing="ij")
    shape = (TD.size, 1)
    G = (TD.reshape(shape) * np.exp(-TAU.reshape(shape) * s) * t_inner / (s * (TD.reshape(shape) * s + 1)))
    phase = np.unwrap(np.angle(G), axis=1)
    mag = np.abs(G)
    cost = np.zeros(TD.size)
    log_k = np.zeros(TD.size)  # ln K per grid point: known, or the tests' mean amplitude ratio
    preds = []
    for t in problem.tests:
        f = phase - (math.asin(t.beta) - math.pi)
        cross = np.argmax((f[:, :-1] > 0) & (f[:, 1:] <= 0), axis=1)
        ok = (f[np.arange(f.shape[0]), cross] > 0) & (f[np.arange(f.shape[0]), cross + 1] <= 0)
        w0 = np.where(ok, w[cross], np.nan)
        a0 = 4.0 * float(t.h or 1.0) / math.pi * mag[np.arange(f.shape[0]), cross]
        preds.append((w0, a0))
        log_k += (math.log(float(t.amplitude_mean or 1.0)) - np.log(a0)) / len(problem.tests)
    if "K" not in problem.free:
        log_k[:] = math.log(base.K)
    for t, (w0, a0) in zip(problem.tests, preds):
        cost += (np.log(w0 / (2 * math.pi)) - math.log(t.frequency_mean)) ** 2
        cost += (np.log(a0) + log_k - math.log(float(t.amplitude_mean or 1.0))) ** 2
    cost = np.where(np.isfinite(cost), cost, np.inf)
    if not np.isfinite(cost).any():
        raise IdentificationError("no outer model in the ranges Td, tau oscillates like the tests (check the inner "
                                  "gains and model, and the outer command's K)")
    k = int(np.argmin(cost))
    theta = [math.log(TD.flat[k]), TAU.flat[k]] + ([float(log_k[k])] if "K" in problem.free else [])
    return np.array(theta)


def _solve(problem: _Problem, base: CascadeModel, theta0: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Least squares from ``theta0``: the estimate and the Jacobian of the weighted residuals."""
    x0 = np.clip(theta0, problem.lower + 1e-9, problem.upper - 1e-9)
    sol = optimize.least_squares(lambda th: problem.residuals(base, th), x0, bounds=(problem.lower, problem.upper),
                                 diff_step=1e-4, x_scale=np.ones_like(x0), xtol=1e-8, max_nfev=60)
    return np.asarray(sol.x, dtype=float), np.asarray(sol.jac, dtype=float)


def _weights(tests: Sequence[TestMeasurement], cycles: Sequence[LimitCycle]) -> tuple[FloatArray, FloatArray]:
    """Standard errors of ln f and ln a: the cycles' scatter, a floor, and the sampled band's spread.

    The loop may lock onto any admissible orbit of the band (and wander between them): the band's
    width over sqrt(12) (uniform over the band) is part of what the centre cannot predict.
    """
    se_f, se_a = [], []
    for t, lc in zip(tests, cycles):
        f_band = (max(lc.orbits_hz) - min(lc.orbits_hz)) / lc.frequency_hz if lc.orbits_hz else 0.0
        a_band = ((max(lc.orbits_amplitude) - min(lc.orbits_amplitude)) / lc.amplitude
                  if lc.orbits_amplitude else 0.0)
        se_f.append(math.hypot(math.hypot(t.frequency_sem / t.frequency_mean, _SE_FLOOR), f_band / math.sqrt(12)))
        a = t.amplitude_mean
        if a is None:
            se_a.append(_INF)
        else:
            se_a.append(math.hypot(math.hypot(float(t.amplitude_sem or 0.0) / a, _SE_FLOOR), a_band / math.sqrt(12)))
    return np.array(se_f), np.array(se_a)


def fit_cascade_cycles(tests: Sequence[TestMeasurement], model: CascadeModel, rate_hz: float, *,
                       inner_draws: Sequence[InnerLoop] = (),
                       switch_levels: Sequence[tuple[float, float]] | None = None,
                       tau_timing_std: float = 0.0) -> CascadeIdentification:
    """The cascade's strategy (:func:`mrftcli.mrft.identify.identify` of a :class:`CascadeModel`): Td and
    tau (and K when not known) of the outer loop from its MRFT tests, through the exact cycle.

    Each test's mean frequency and amplitude are matched, in logarithms and weighted by their
    standard errors, to the centre of the exact sampled cycle of the cascade
    (:meth:`CascadeModel.sampled_limit_cycle`). The standard errors hold the cycles' scatter, a
    floor of 0.5 % and the spread of the sampled band. The inner model's uncertainty is propagated
    by solving again for every draw of ``inner_draws`` (started at the estimate): their spread adds
    (in quadrature) to the Gauss-Newton spread of the tests.

    Parameters
    ----------
    tests : sequence of TestMeasurement
        The outer tests: nominal beta, per-cycle frequencies [Hz], amplitudes [output units], h.
    model : CascadeModel
        The cascade: its inner loop (the identified plant, nominal, and its controller during the
        outer tests); K known (the set E: 1 for a commanded acceleration, :data:`STANDARD_GRAVITY` for a commanded
        attitude [rad]) or not (two tests at different beta, with amplitudes, are then needed); the
        ranges of Td [s] and tau [s] (the set I; default :data:`TD_BOUNDS`, :data:`TAU_BOUNDS`).
        The values of Td, tau (and of an unknown K) are ignored.
    rate_hz : float
        The outer relay's rate [Hz] (the inner controller's or a whole divisor of it).
    inner_draws : sequence of InnerLoop
        Draws of the inner loop (its model's uncertainty); empty: the inner model taken as exact.
    switch_levels : sequence of (float, float), optional
        Each test's measured output at the relay's down switch over its amplitude [-] and its
        standard error (``MrftTest`` ``beta_down``). Given, the tests are matched at the orbit of
        their measured half period (:meth:`CascadeModel.orbit_at`: amplitude and switch level)
        rather than by the band's centre at beta: beta then serves the start only, and the
        fractional delay between ticks is read from the level.
    tau_timing_std : float
        Timing uncertainty between command and output stamps [s] (receive-time stamps' jitter),
        added to tau's spread in quadrature.

    Returns
    -------
    CascadeIdentification

    Raises
    ------
    IdentificationError
        Too few tests or amplitudes for the unknowns.
    InputError
        Bad bounds or rates.
    """
    inner = model.inner
    K = model.K if "K" in model.known else None
    ranges = {name: (lo, hi) for name, lo, hi in model.ranges}
    Td_bounds, tau_bounds = ranges.get("Td", TD_BOUNDS), ranges.get("tau", TAU_BOUNDS)
    tests = tuple(tests)
    check_positive("rate_hz", rate_hz)
    if not tests:
        raise IdentificationError("no outer-loop MRFT test to identify the cascade from")
    if any(t.h is None or t.amplitude_mean is None for t in tests):
        raise IdentificationError("the cascade identification needs every test's amplitude and relay height h")
    if K is None and len({round(t.beta, 3) for t in tests}) < 2:
        raise IdentificationError("identifying K needs tests at two different beta; or state K (1 for a commanded "
                                  f"acceleration, {STANDARD_GRAVITY:g} for a commanded attitude in rad)")
    lo_td, hi_td = Td_bounds
    if not (0 < lo_td < hi_td) or not (0 <= tau_bounds[0] < tau_bounds[1]):
        raise InputError(f"bad bounds: Td {Td_bounds}, tau {tau_bounds} (need 0 < low < high)")
    free = ("Td", "tau") if K is not None else ("Td", "tau", "K")
    lower = [math.log(lo_td), tau_bounds[0]] + ([math.log(1e-3)] if K is None else [])
    upper = [math.log(hi_td), tau_bounds[1]] + ([math.log(1e3)] if K is None else [])
    k0 = STANDARD_GRAVITY if K is None else K
    base = CascadeModel(inner, Td=math.sqrt(lo_td * hi_td), tau=0.5 * sum(tau_bounds), K=k0,
                        known=frozenset() if K is None else frozenset({"K"}),
                        ranges=(("Td", lo_td, hi_td), ("tau", *tau_bounds)))
    problem = _Problem(tests, rate_hz, free, np.array(lower), np.array(upper),
                       np.full(len(tests), _SE_FLOOR), np.full(len(tests), _SE_FLOOR))
    if switch_levels is not None:
        problem = _orbit_problem(problem, switch_levels)
        theta, jac = _solve(problem, base, _theta0(problem, base))
        return _result(problem, base, theta, jac, inner_draws, tau_timing_std)
    theta, _ = _solve(problem, base, _theta0(problem, base))
    # second pass with the sampled band's spread in the weights (it depends on the estimate)
    se_f, se_a = _weights(tests, problem.cycles(problem.model(base, theta)))
    problem = _Problem(tests, rate_hz, free, problem.lower, problem.upper, se_f, se_a, hints=problem.hints)
    theta, jac = _solve(problem, base, theta)
    return _result(problem, base, theta, jac, inner_draws, tau_timing_std)


def _orbit_problem(problem: _Problem, switch_levels: Sequence[tuple[float, float]]) -> _Problem:
    """The problem matched at the measured orbits: amplitudes and switch levels with their standard errors."""
    levels = np.array([float(level) for level, _ in switch_levels])
    if levels.size != len(problem.tests) or not np.isfinite(levels).all():
        raise InputError(f"switch_levels: need one finite level per test ({len(problem.tests)}), got {levels.size}")
    se_l = np.array([math.hypot(float(se) if math.isfinite(se) else 0.0, _SE_LEVEL_FLOOR) for _, se in switch_levels])
    se_a = np.array([math.hypot(float(t.amplitude_sem or 0.0) / float(t.amplitude_mean or 1.0), _SE_FLOOR)
                     for t in problem.tests])
    return _Problem(problem.tests, problem.rate_hz, problem.free, problem.lower, problem.upper, problem.se_f, se_a,
                    levels, se_l)


def _result(problem: _Problem, base: CascadeModel, theta: FloatArray, jac: FloatArray,
            inner_draws: Sequence[InnerLoop], tau_timing_std: float = 0.0) -> CascadeIdentification:
    """Estimates with the tests' spread (Gauss-Newton) and the inner draws' spread; the tests' fits."""
    model = problem.model(base, theta)
    r = problem.residuals(base, theta)
    dof = r.size - theta.size
    scale = max(1.0, float(r @ r) / dof) if dof > 0 else 1.0
    cov = np.linalg.pinv(jac.T @ jac) * scale
    var_inner = np.zeros(theta.size)
    draws = []
    for draw in inner_draws:
        try:
            draws.append(_solve(problem, model.with_inner(draw), theta)[0])
        except (InputError, IdentificationError, np.linalg.LinAlgError):
            continue  # a draw whose inner loop does not oscillate with this outer loop: not counted
    if len(draws) >= 2:
        var_inner = np.var(np.array(draws), axis=0, ddof=1)
    timing = np.array([tau_timing_std ** 2 if name == "tau" else 0.0 for name in problem.free])
    std = np.sqrt(np.diag(cov) + var_inner + timing)
    omega = 2 * math.pi * float(np.median([t.frequency_mean for t in problem.tests]))
    # Td and K on the log scale (theta holds ln), tau linear; cut at the set I (as the families' fit)
    estimates = {name: fitted_estimate(name, math.exp(float(theta[i])) if name != "tau" else float(theta[i]),
                                       float(theta[i]), float(std[i]), (problem.lower[i], problem.upper[i]),
                                       CASCADE_PARAMETERS[name][0], name != "tau", omega, _METHOD)
                 for i, name in enumerate(problem.free)}
    if "K" not in problem.free:
        estimates["K"] = ParameterEstimate.given(model.K, CASCADE_PARAMETERS["K"][0], "K")
    inner_std = {name: (math.sqrt(var_inner[i]) * (1.0 if name == "tau" else float(getattr(model, name))))
                 for i, name in enumerate(problem.free)}
    fits = tuple(CascadeTestFit(t.beta, float(t.h or 1.0), t.frequency_mean, float(t.amplitude_mean or math.nan),
                                lc.frequency_hz, lc.amplitude,
                                (min(lc.orbits_hz, default=math.nan), max(lc.orbits_hz, default=math.nan)))
                 for t, lc in zip(problem.tests, problem.cycles(model)))
    return CascadeIdentification(model, tuple(estimates.values()), fits, problem.rate_hz, len(draws), inner_std)

