"""diagnose's least-squares fits to the recorded cycles' features (used by :mod:`mrftcli.diagnose.selection`).

* :func:`fit_model` fits a :class:`~mrftcli.diagnose.candidate_model.CandidateModel`'s parameters to the
  features (:func:`residuals`: in units of the recording's standard errors, :func:`feature_sigma`, with K in
  closed form); :func:`fit_base` starts the linear model along the Td-tau valley
  (:mod:`mrftcli.diagnose.starts`); :func:`plant_params`, :func:`effect_value` read a :class:`Fit`.
* The tests (:mod:`mrftcli.diagnose.prepared`), the candidate models' limit cycles
  (:mod:`mrftcli.diagnose.candidate_model`) and the fits' starts and bounds
  (:mod:`mrftcli.diagnose.starts`) live beside it; import their names from those modules.

Units: times in seconds, the output in its own units (m or rad), the command in command units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .features import FEATURE_NAMES
from .physics import Effect
from .prepared import DiagnosedTest
from .candidate_model import CandidateModel
from .starts import initial_base, tau_on_valley

__all__ = ["FEATURE_FLOOR", "feature_mask", "feature_sigma", "Fit", "residuals", "fit_model", "fit_base", "plant_params",
           "param_std", "effect_value"]

#: the fits' relative finite-difference step (least_squares' diff_step)
_STEP = 1e-3
_EPS_STEP = float(np.sqrt(np.finfo(float).eps))  # its step where the relative one vanishes (theta = 0)


# Floors added (in quadrature) to each feature's standard error: the continuous-relay model of a
# sampled, noisy relay (``diagnose_sim``) is not exact to better than about this.
FEATURE_FLOOR = {
    "period": 1.5e-3,  # relative
    "balance": 1.5e-3,
    "log_amplitude": 4e-3,
    "centre": 8e-3,
    "h3_re": 1.5e-3,
    "h3_im": 1.5e-3,
    "h5_re": 1e-3,
    "h5_im": 1e-3,
    "h2_re": 1.5e-3,
    "h2_im": 1.5e-3,
    "amplitude_trend": 2e-4,  # 1/s
    "balance_trend": 1e-4,  # 1/s
}


def feature_mask(test: DiagnosedTest) -> np.ndarray:
    m = np.ones(len(FEATURE_NAMES), bool)
    if not test.has_setpoint:
        m[FEATURE_NAMES.index("centre")] = False
    return m


def feature_sigma(rec_sigma: np.ndarray, rec_values: np.ndarray) -> np.ndarray:
    floor = np.array([FEATURE_FLOOR[n] for n in FEATURE_NAMES])
    floor = floor.copy()
    floor[0] *= rec_values[0]  # period floor is relative
    rs = np.nan_to_num(np.asarray(rec_sigma, float), nan=0.0, posinf=np.inf)
    with np.errstate(over="ignore"):
        s = np.sqrt(np.where(np.isfinite(rs), rs, np.inf) ** 2 + floor**2)
    return s


@dataclass
class Fit:
    theta: np.ndarray
    K: float
    chi2: float
    n: int
    k: int
    resid: np.ndarray
    evals: list
    cov: np.ndarray | None
    ok: bool


def residuals(model: CandidateModel, theta: np.ndarray, recs: list, with_K: bool = False, newton: bool = False):
    """Stacked z residuals over tests; K eliminated in closed form (weighted mean of ln A); ``newton``:
    a Jacobian's column (:meth:`CandidateModel.evaluate`)."""
    evals = []
    ia = FEATURE_NAMES.index("log_amplitude")
    num = den = 0.0
    for i, (f_rec, s) in enumerate(recs):
        ev = model.evaluate(theta, i, f_rec.t_mean, newton=newton)
        if ev is None:
            return None
        evals.append(ev)
        w = 1.0 / s[ia] ** 2
        num += w * (f_rec.values[ia] - ev.features[ia])
        den += w
    lnK = num / den
    out = []
    for (f_rec, s), ev, test in zip(recs, evals, model.tests):
        fm = ev.features.copy()
        fm[ia] += lnK
        z = (f_rec.values - fm) / s
        out.append(z[feature_mask(test)])
    r = np.concatenate(out)
    if with_K:
        return r, math.exp(lnK), evals
    return r


def fit_model(model: CandidateModel, theta0: np.ndarray, lo: np.ndarray, hi: np.ndarray, recs: list, max_nfev: int = 60,
         free: np.ndarray | None = None) -> Fit:
    """Least-squares fit of the candidate's parameters (``free`` selects the ones that move)."""
    big = 1e3
    theta0 = np.clip(np.asarray(theta0, float), lo + 1e-9, hi - 1e-9)
    free = np.ones(theta0.size, bool) if free is None else np.asarray(free, bool)
    full0 = theta0.copy()

    def expand(x):
        th = full0.copy()
        th[free] = x
        return th

    # the best point evaluated is kept: a limit cycle solved from a warm start (the last one found)
    # can land on another periodic solution when evaluated again, so the final x of least_squares,
    # evaluated once more, is not always the point it scored (a pair fit once "ended" at delta BIC -1e5)
    best: list = [np.inf, None, None]  # chi^2, theta, (r, K, evals)
    last: list = [None, None]  # the last point evaluated and its residuals
    calls = [0]  # least_squares' own evaluations

    def fun(x):
        th = expand(x)
        got = residuals(model, th, recs, with_K=True)
        if got is None or not np.all(np.isfinite(got[0])):
            n = sum(int(feature_mask(t).sum()) for t in model.tests)
            last[:] = [np.array(x), np.full(n, big)]
            return last[1]
        r = got[0]
        chi2 = float(r @ r)
        if chi2 < best[0]:
            best[:] = [chi2, th, got]
        last[:] = [np.array(x), r]
        return r

    def counted(x):
        calls[0] += 1
        return fun(x)

    def jac(x):
        """Forward differences as least_squares' '2-point' with ``diff_step`` (its steps, their sign
        at the bounds), each column's cycles one Newton step on the period from the point's own."""
        r0 = last[1] if last[0] is not None and np.array_equal(last[0], x) else fun(x)
        if calls[0] >= max_nfev and not free.all():
            # least_squares asks for the Jacobian of its last point before it stops at max_nfev: with
            # parameters held, no covariance is taken from it, so it is never read (a profile's fit)
            return np.zeros((r0.size, x.size))
        sign = np.where(x >= 0, 1.0, -1.0)
        h = _STEP * sign * np.abs(x)
        h = np.where((x + h) - x == 0, _EPS_STEP * sign * np.maximum(1.0, np.abs(x)), h)
        lb, ub = lo[free], hi[free]
        flip = ((x + h < lb) | (x + h > ub)) & (np.abs(h) <= np.maximum(x - lb, ub - x))
        h[flip] = -h[flip]
        cols = []
        for j in range(x.size):
            xj = x.copy()
            xj[j] += h[j]
            r = residuals(model, expand(xj), recs, newton=True)
            if r is None or not np.all(np.isfinite(r)):
                r = np.full(r0.size, big)
            cols.append((r - r0) / (xj[j] - x[j]))
        return np.column_stack(cols)

    try:
        # chi^2 to 1e-5 relative is far finer than the evidence needs (thresholds of 10 in chi^2)
        sol = least_squares(counted, theta0[free], jac=jac, bounds=(lo[free], hi[free]), max_nfev=max_nfev,
                            x_scale=1.0, ftol=1e-5, xtol=1e-6)
        theta = expand(sol.x)
        J = sol.jac if free.all() else None
    except (ValueError, np.linalg.LinAlgError):
        theta, J = theta0, None
    got = residuals(model, theta, recs, with_K=True)
    if best[1] is not None and (got is None or float(got[0] @ got[0]) > best[0]):
        theta, got = best[1], best[2]
    if got is None:
        return Fit(theta, float("nan"), float("inf"), 0, len(theta) + 1, np.array([]), [], None, False)
    r, K, evals = got
    cov = None
    if J is not None:
        try:
            cov = np.linalg.pinv(J.T @ J)
        except np.linalg.LinAlgError:
            cov = None
    return Fit(theta, K, float(r @ r), int(r.size), len(theta) + 1, r, evals, cov, bool(np.all(np.abs(r) < big)))


def fit_base(model: CandidateModel, tests: list[DiagnosedTest], Tp: float, lo: np.ndarray, hi: np.ndarray, recs: list) -> Fit:
    """The linear model's fit, started along the Td-tau valley.

    The features pin the phase at each test's frequency well but Td and tau trade off along a curved
    valley, and a noisy log (large cycle-to-cycle scatter) can leave the describing-function start on
    the wrong side of a shallow local minimum. Td is therefore profiled over a decade-wide grid (tau
    fitted alone at each point, from the phase condition), and the two best points are refined freely.
    """
    th0 = initial_base(tests, Tp)
    starts = [th0] + [np.array([math.log(td), 10 * tau_on_valley(tests, Tp, td)])
                      for td in math.exp(th0[0]) * np.array([0.25, 0.5, 2.0, 4.0])]
    free = np.array([False, True])
    prof = []
    for th in starts:
        pf = fit_model(model, th, lo, hi, recs, max_nfev=6, free=free)
        if np.isfinite(pf.chi2):
            prof.append(pf)
    prof.sort(key=lambda f: f.chi2)
    best: Fit | None = None
    tries: list[Fit | None] = list(prof[:2]) or [None]
    for trial in tries:
        f = fit_model(model, trial.theta if trial is not None else th0, lo, hi, recs)
        if best is None or (f.ok and (not best.ok or f.chi2 < best.chi2)):
            best = f
    assert best is not None  # (one try at least)
    return best



def plant_params(model: CandidateModel, fit: Fit) -> dict:
    p = model.unpack(fit.theta)
    out = {"tau": p["tau"], "K": fit.K}
    if p.get("Td") is not None:
        out["Td"] = p["Td"]
    return out


def param_std(fit: Fit, j: int | None) -> float:
    """Standard error of theta[j] from the fit's covariance (NaN without one, or no such parameter)."""
    if fit.cov is None or j is None or j >= fit.cov.shape[0]:
        return float("nan")
    v = fit.cov[j, j]
    return float(math.sqrt(v)) if v >= 0 else float("nan")


def effect_value(cand: Effect, model: CandidateModel, fit: Fit, p: dict) -> tuple[float, float]:
    """The effect's parameter in its own units and its standard error, from a fit of ``model``."""
    hs = model.hs
    j = model.extra_index(cand.name)
    if cand.name == "quadratic_drag":
        c = p["q"] / fit.K
        return c, c * param_std(fit, 0)
    x = p["extras"][cand.name]
    if cand.name == "input_bias":
        return x, param_std(fit, j) * hs
    if cand.name == "gain_drift":
        return x, param_std(fit, j) / 100.0
    if cand.name == "sensor_lag":
        return x, param_std(fit, j) / 10.0
    if cand.name == "asymmetric_gain":
        return x, param_std(fit, j) / 10.0
    if cand.name == "actuator_saturation":
        return model.bias_mean + x, param_std(fit, j) * hs
    if cand.name == "dead_zone":
        return x, param_std(fit, j) * hs / 10.0
    if cand.name == "thrust_rectification":
        F = 1.0 / x if x > 1e-9 else float("inf")
        s_inv = param_std(fit, j) / (10.0 * hs)
        return F, (s_inv / x**2 if x > 1e-9 else float("nan"))
    if cand.name == "actuator_rate_limit":
        rho = x
        R = 1.0 / rho if rho > 1e-9 else float("inf")
        s_rho = param_std(fit, j) / (10.0 * hs)
        return R, (s_rho / rho**2 if rho > 1e-9 else float("nan"))
    raise ValueError(cand.name)
