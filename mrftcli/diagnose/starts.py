"""Where diagnose's fits start and their bounds: the describing-function phase condition's Td-tau
valley (:func:`initial_base`, :func:`tau_on_valley`), the parameters' bounds (:func:`theta_bounds`,
:data:`TD_RANGE_S`, :func:`bound_reason`) and each candidate's starting points
(:func:`candidate_starts`); theta's layout is :class:`~mrftcli.diagnose.candidate_model.CandidateModel`'s.

Units: times in seconds, phases in rad.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Callable

import numpy as np
from scipy.optimize import minimize_scalar

from .features import FEATURE_NAMES
from .physics import Effect, df_quadratic_drag
from .prepared import DiagnosedTest

if TYPE_CHECKING:
    from .fit import Fit

__all__ = ["TD_RANGE_S", "initial_base", "bound_reason", "tau_on_valley", "theta_bounds", "candidate_starts"]

#: Td's range in the fits [s] (:func:`theta_bounds`) and in the phase-condition start (:func:`initial_base`)
TD_RANGE_S = (0.02, 100.0)
#: tau's upper end in the phase-condition start [s]
_TAU_START_MAX_S = 0.5
#: log-Td grid of the phase-condition start (refined around its best point)
_LOG_TD_GRID = np.linspace(math.log(TD_RANGE_S[0]), math.log(TD_RANGE_S[1]), 49)
#: phase residuals [rad^2] this close to the best are rounding: the valley is flat there
_FLAT_COST = 1e-12


def _phase_terms(tests: list[DiagnosedTest], Tp: float, extra_phase: Callable | None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Each test's frequency W [rad/s] and the part of its describing-function phase condition that
    depends on neither Td nor tau [rad]: the condition is ``c - atan(W Td) - W tau = 0``."""
    W = np.array([2 * np.pi / np.mean(t.tab.period[t.fit]) for t in tests])
    # an effective beta measured beyond +-1 (a relay that switched late on a noisy or lagging output)
    # has no describing-function phase: the edge's (was a NaN and a RuntimeWarning on the terminal)
    B = np.clip([np.mean(t.beta) for t in tests], -1.0, 1.0)
    fs = np.array([t.rate_hz for t in tests])
    extra = np.zeros(len(tests)) if extra_phase is None else np.array([extra_phase(w, t) for w, t in zip(W, tests)])
    return W, np.pi / 2 - np.arctan(W * Tp) - W * 0.5 / fs + extra - np.arcsin(B)


def initial_base(tests: list[DiagnosedTest], Tp: float, extra_phase: Callable | None = None) -> np.ndarray:
    """Td, tau from the describing-function phase condition at each test's frequency (theta's layout).

    arg G(jW) - W/(2 f_s) + extra = -pi + asin(beta), with arg G = -pi/2 - atan(W Tp) - atan(W Td) - W tau;
    ``extra_phase(W, test)`` adds a candidate's own phase [rad] (e.g. -atan(W T_lag)). The condition
    is linear in tau, so tau is solved in closed form at each Td (in [0, 0.5] s) and the least-squares
    Td is found on a log grid over :data:`TD_RANGE_S` refined by a bounded scalar search. (A 2-D
    least-squares fit wandered the Td-tau valley for 40-120 ms a start when the tests share one
    frequency, where the condition cannot separate Td from tau: issue 39.) Tests at one frequency
    leave the valley (nearly) flat: its least-squares point is then as arbitrary as the noise, often a
    bound of the range, and the fits from it say so (:func:`bound_reason`); one test leaves it exactly
    flat, and the start is the valley's point nearest Td = 1 s.
    """
    W, c = _phase_terms(tests, Tp, extra_phase)
    ww = float(W @ W)

    def profile(u: float) -> tuple[float, float]:
        a = c - np.arctan(W * math.exp(u))
        tau = min(max(float(W @ a) / ww, 0.0), _TAU_START_MAX_S)
        r = a - W * tau
        return float(r @ r), tau

    costs = np.array([profile(u)[0] for u in _LOG_TD_GRID])
    flat = np.flatnonzero(costs <= costs.min() + _FLAT_COST)
    if flat.size > 1:  # one frequency: every Td of the valley meets the condition; the one nearest 1 s
        u = float(_LOG_TD_GRID[flat[np.argmin(np.abs(_LOG_TD_GRID[flat]))]])
        return np.array([u, 10 * profile(u)[1]])
    i = int(np.argmin(costs))
    lo, hi = _LOG_TD_GRID[max(i - 1, 0)], _LOG_TD_GRID[min(i + 1, _LOG_TD_GRID.size - 1)]
    ref = minimize_scalar(lambda u: profile(u)[0], bounds=(lo, hi), method="bounded", options={"xatol": 1e-9})
    u = float(ref.x) if ref.fun <= costs[i] else float(_LOG_TD_GRID[i])
    return np.array([u, 10 * profile(u)[1]])


def bound_reason(Td: float | None) -> str | None:
    """Why a fitted Td [s] is no estimate of the plant, or None: it ended on an end of :data:`TD_RANGE_S`.

    There the tests did not bound Td (nor so tau and K, which trade off against it along the valley of
    the phase condition): their frequencies fix the phase, not how Td and tau share it.
    """
    if Td is None or not math.isfinite(Td):
        return None
    lo, hi = TD_RANGE_S
    if Td >= hi * (1.0 - 1e-3):
        end = f"upper bound ({hi:g} s)"
    elif Td <= lo * (1.0 + 1e-3):
        end = f"lower bound ({lo:g} s)"
    else:
        return None
    return (f"its Td ended on the fit's {end}: these tests do not determine Td, nor so tau and K (their "
            "frequencies fix the phase, not how Td and tau share it; a test at another beta would)")


def tau_on_valley(tests: list[DiagnosedTest], Tp: float, Td: float) -> float:
    """tau [s] that satisfies the describing-function phase condition best for a given Td (closed form)."""
    W = np.array([2 * np.pi / np.mean(t.tab.period[t.fit]) for t in tests])
    B = np.clip([np.mean(t.beta) for t in tests], -1.0, 1.0)  # as _phase_terms
    fs = np.array([t.rate_hz for t in tests])
    # -pi/2 - atan(W Tp) - atan(W Td) - W (tau + 1/(2 fs)) = -pi + asin(B), linear in tau
    rhs = np.pi / 2 - np.arctan(W * Tp) - np.arctan(W * Td) - W * 0.5 / fs - np.arcsin(B)
    return max(float(W @ rhs / (W @ W)), 0.0)



def theta_bounds(cand: Effect | tuple | None, tests: list[DiagnosedTest]) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of theta (layout of :class:`CandidateModel`) for the base model, one candidate or a combination."""
    cands = () if cand is None else (tuple(cand) if isinstance(cand, (tuple, list)) else (cand,))
    lo = [math.log(TD_RANGE_S[0]), 0.0]
    hi = [math.log(TD_RANGE_S[1]), 5.0]
    hmin = min(t.h for t in tests)
    hmax = max(t.h for t in tests)
    hs = float(np.mean([t.h for t in tests]))
    extra: dict[str, tuple[float, float]] = {
        "input_bias": (-0.9 * hmin / hs, 0.9 * hmin / hs),
        "gain_drift": (-5.0, 5.0),
        "sensor_lag": (0.002, 3.0),
        "actuator_rate_limit": (0.0, 10.0),
        "asymmetric_gain": (-5.0, 5.0),
        "actuator_saturation": (0.2 * hmin / hs, 3.0 * hmax / hs),
        "dead_zone": (0.0, 9.0 * hmin / hs),
        "thrust_rectification": (0.0, 9.5 * hs / hmax),
    }
    for c in cands:
        if c.stochastic:
            continue
        if c.replaces_drag:
            lo[0], hi[0] = math.log(1e-4), math.log(1e6)
            continue
        lo.append(extra[c.name][0])
        hi.append(extra[c.name][1])
    return np.array(lo), np.array(hi)


def candidate_starts(cand: Effect, base: Fit, tests: list[DiagnosedTest], recs: list, Tp: float) -> list[np.ndarray]:
    th = base.theta
    hs = np.mean([t.h for t in tests])
    if cand.name == "input_bias":
        d = np.mean([-2.0 * t.h * f.values[FEATURE_NAMES.index("balance")] for t, (f, _) in zip(tests, recs)])
        return [np.array([th[0], th[1], d / hs])]
    if cand.name == "gain_drift":
        # amplitude trend ~ g; where the hover command b is non-zero the battery also shifts the trim:
        # balance trend dD/dt ~ -b g / (2 h)
        ga = float(np.mean([f.values[FEATURE_NAMES.index("amplitude_trend")] for f, _ in recs]))
        starts = [np.array([th[0], th[1], 100 * ga])]
        gb = [-2.0 * t.h * f.values[FEATURE_NAMES.index("balance_trend")] / t.bias for t, (f, _) in zip(tests, recs)
              if abs(t.bias) > 0.2 * t.h]
        if gb:
            starts.insert(0, np.array([th[0], th[1], 100 * float(np.median(gb))]))
        return starts
    if cand.name == "sensor_lag":
        # profile over a grid of lags: Td and tau from the describing function with the lag's phase
        out = []
        for tl in (0.01, 0.03, 0.06, 0.1, 0.16):
            b = initial_base(tests, Tp, lambda w, t, tl=tl: -math.atan(w * tl))
            out.append(np.array([b[0], b[1], 10 * tl]))
        return out
    if cand.name == "actuator_rate_limit":
        # a ramp of 2h/R delays the relay's first harmonic by h/R: profile over that extra delay
        out = []
        for ex in (0.005, 0.012, 0.025, 0.045, 0.07):
            rho = ex / hs
            b = initial_base(tests, Tp, lambda w, t, rho=rho: -w * t.h * rho)
            out.append(np.array([b[0], b[1], 10 * hs * rho]))
        return out
    if cand.name == "asymmetric_gain":
        # the balance of a test ~ -(a h) / (2 h) beyond the trim error's: start from both signs
        return [np.array([th[0], th[1], x]) for x in (-1.0, -0.3, 0.3, 1.0)]
    if cand.name == "actuator_saturation":
        # the limit just inside the largest test's trim + h, or a little further in
        hmax = max(t.h for t in tests)
        return [np.array([th[0], th[1], f * hmax / hs]) for f in (0.5, 0.7, 0.9, 1.2)]
    if cand.name == "dead_zone":
        hmin = min(t.h for t in tests)
        return [np.array([th[0], th[1], 10.0 * f * hmin / hs]) for f in (0.05, 0.2, 0.4)]
    if cand.name == "thrust_rectification":
        hmax = max(t.h for t in tests)
        return [np.array([th[0], th[1], 10.0 * f * hs / hmax]) for f in (0.15, 0.4, 0.7)]
    if cand.name == "quadratic_drag":
        # describing-function equivalent at the middle test's velocity amplitude (K = 1 units)
        Td = math.exp(th[0])
        f, _ = recs[len(recs) // 2]
        a1 = math.exp(f.values[FEATURE_NAMES.index("log_amplitude")]) / base.K
        V = a1 * 2 * np.pi / f.values[0]
        q = df_quadratic_drag(Td, V)
        return [np.array([math.log(q), th[1]])]
    raise ValueError(cand.name)

