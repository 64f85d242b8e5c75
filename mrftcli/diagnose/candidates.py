"""Stages 2 and 3 of the diagnosis: the linear model's fit (is it rejected?) and each candidate
effect fitted alone against it.

Each candidate augments the model with one parameter and is refitted together with Td and tau on the
fitting cycles' features (:mod:`mrftcli.diagnose.fit`). Evidence: BIC = chi^2 + k ln n over the same
features, ``delta_bic`` = BIC(linear) - BIC(candidate); the held-out cycles confirm
(:func:`mrftcli.diagnose.heldout.significant`). The candidates are fitted in the order of a cheap
probe, and once one explains the fitting and the held-out cycles to the noise level the rest are not.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2 as chi2_dist

from ..errors import DiagnoseError
from ..mrft.model import LoopModel
from .fit import Fit, effect_value, fit_base, fit_model, plant_params, residuals
from .candidate_model import CandidateModel
from .starts import candidate_starts, theta_bounds
from .heldout import BIC_THRESHOLD, explains_held_out, held_out_score, significant
from .scatter import scatter_reference, scatter_z
from .physics import CANDIDATES, Effect
from .records import CandidateFit, HeldOut
from .screen import Screen, with_trim_nuisance

__all__ = ["PROFILE_NFEV", "REJECT_Z", "REJECT_P", "LinearFit", "fit_linear", "Starts", "CandidateSearch",
           "search_candidates", "jacobian", "probe_gain"]

#: function evaluations per profile point of a candidate's grid (Td and tau only)
PROFILE_NFEV = 6
#: the linear model counts as rejected (and the candidates are fitted) when some feature is this many
#: standard errors off, or the chi^2 of its fit has a p-value below REJECT_P
REJECT_Z = 3.0
REJECT_P = 0.01


@dataclass(frozen=True)
class LinearFit:
    """The linear model fitted to the fitting cycles, and whether the recording rejects it.

    Attributes
    ----------
    model, fit : CandidateModel, Fit
        The linear model and its fit.
    scatter : list of dict
        Per test, the period scatter noise alone explains on a sampled relay (its ``setting``,
        variance ``v0``, std ``s0`` [s] and degrees of freedom ``dof``).
    chi2_scatter : float
        The fitting cycles' period-scatter chi^2 against that reference (added to every model's).
    n_all : int
        Features in the BIC (the fitting cycles' features and one scatter per test).
    bic : float
        The linear model's BIC.
    held_out : HeldOut
        Its held-out score (:func:`mrftcli.diagnose.heldout.held_out_score`).
    p_value : float
        The chi^2 p-value of its fit.
    rejected : bool
        Some feature of the fitting or the held-out cycles is :data:`REJECT_Z` standard errors off, or
        ``p_value`` < :data:`REJECT_P`: the candidates are fitted.
    screen : Screen
        The screen the diagnosis goes on with: each test's relay centre a per-test nuisance
        (:func:`~mrftcli.diagnose.screen.with_trim_nuisance`).
    """

    model: CandidateModel
    fit: Fit
    scatter: list[dict]
    chi2_scatter: float
    n_all: int
    bic: float
    held_out: HeldOut
    p_value: float
    rejected: bool
    screen: Screen


def fit_linear(screen: Screen, loop_model: LoopModel, path: str, say: Callable[[str], None]) -> LinearFit:
    """Stage 2: the linear model's fit, its noise-only period scatter and whether it is rejected
    (``loop_model``: eq. (2) with its known Tp [s]).

    Raises
    ------
    DiagnoseError
        The linear model reproduces no limit cycle close to the recorded ones.
    """
    tests, Tp = screen.tests, loop_model.Tp
    say("fitting the linear model")
    model = CandidateModel(None, tests, Tp)
    lo, hi = theta_bounds(None, tests)
    base = fit_base(model, tests, Tp, lo, hi, screen.recs_fit)
    if not base.ok:
        raise DiagnoseError(f"{path}: the linear model reproduces no limit cycle close to the recorded ones")
    # each test's relay centre (the hold's trim when it began) is a per-test nuisance: the features it
    # moves are widened by it, and the linear model refitted from its fit on the narrower ones
    widened = with_trim_nuisance(screen, model, base)
    if widened is not screen:
        screen = widened
        refit = fit_model(model, base.theta, lo, hi, screen.recs_fit)
        base = refit if refit.ok else _rescored(model, base, screen.recs_fit)
    say("simulating the noise-driven scatter")
    scatter = scatter_reference(tests, model, base, screen.noise)
    z_sc = scatter_z(tests, scatter, "fit", [sc["v0"] for sc in scatter])
    chi2_scatter = float(z_sc @ z_sc)
    n_all = base.n + len(tests)
    before = held_out_score(model, base, tests, screen.recs_hold)
    # is the linear model rejected at all? A candidate needs a chi^2 gain of BIC_THRESHOLD + ln n on
    # the fitting cycles and HOLDOUT_THRESHOLD on the held-out ones; when every feature of both halves
    # is within REJECT_Z standard errors and the chi^2 is what the noise gives, none is fitted
    p_base = float(chi2_dist.sf(base.chi2, max(base.n - base.k, 1)))
    rejected = (p_base < REJECT_P or float(np.max(np.abs(base.resid))) >= REJECT_Z
                or (before.feature_max_abs_z or 0.0) >= REJECT_Z)
    return LinearFit(model=model, fit=base, scatter=scatter, chi2_scatter=chi2_scatter, n_all=n_all,
                     bic=base.chi2 + chi2_scatter + base.k * math.log(n_all), held_out=before, p_value=p_base,
                     rejected=rejected, screen=screen)


def _rescored(model: CandidateModel, fit: Fit, recs: list) -> Fit:
    """A fit at its own theta scored against other standard errors (itself when its cycles fail there)."""
    got = residuals(model, fit.theta, recs, with_K=True)
    if got is None:
        return fit
    r, K, evals = got
    return replace(fit, resid=r, K=K, evals=evals, chi2=float(r @ r), n=int(r.size))


class Starts:
    """Each candidate's starting points on the linear fit (:func:`~mrftcli.diagnose.starts.candidate_starts`),
    computed once per diagnosis: the probes, the single fits and every pair ask for them again with the
    same linear fit (the profiled candidates' describing-function solves were 10-40 % of diagnose's
    CPU on the RotorPy and JSBSim flights; issue 39)."""

    def __init__(self, screen: Screen, linear: LinearFit, Tp: float) -> None:
        self._args = (linear.fit, screen.tests, screen.recs_fit, Tp)
        self._done: dict[str, list[np.ndarray]] = {}

    def __call__(self, cand: Effect) -> list[np.ndarray]:
        """The starts of ``cand`` (fresh copies: a caller may change them)."""
        if cand.name not in self._done:
            self._done[cand.name] = candidate_starts(cand, *self._args)
        return [th.copy() for th in self._done[cand.name]]


@dataclass(frozen=True)
class CandidateSearch:
    """Every candidate fitted alone against the linear model (:func:`search_candidates`).

    Attributes
    ----------
    rows : list of CandidateFit
        Per deterministic candidate, in the library's order: its evidence and held-out scores, or
        ``delta_bic`` None and a ``status`` saying why it was not fitted; ``significant`` on each.
    fits : dict
        name -> (model, fit) of each candidate fitted.
    order : list of Effect
        The deterministic candidates in the order they were fitted (by their probe).
    starts : Starts
        Each candidate's starts on the linear fit (the pairs' too).
    """

    rows: list[CandidateFit]
    fits: dict[str, tuple[CandidateModel, Fit]]
    order: list[Effect]
    starts: Starts


def _profile_starts(model: CandidateModel, starts: list[np.ndarray], lo: np.ndarray, hi: np.ndarray,
                    recs_fit: list) -> list[np.ndarray]:
    """The starts worth a full fit from a candidate's grid of starts.

    At each grid value Td and tau are fitted with the effect held (the effect and the delay trade off
    along a curved valley; the starts are on it already, from the describing function, so a few steps
    suffice); the best is kept, and the second best too when it is close.
    """
    prof = []
    free = np.ones(len(starts[0]), bool)
    free[2:] = False
    for th in starts:
        pf = fit_model(model, th, lo, hi, recs_fit, max_nfev=PROFILE_NFEV, free=free)
        if pf.ok and np.isfinite(pf.chi2):
            prof.append(pf)
    prof.sort(key=lambda f: f.chi2)
    return [pf.theta for pf in prof[:2] if pf.chi2 <= 1.5 * prof[0].chi2 + BIC_THRESHOLD]


def _fit_candidate(cand: Effect, screen: Screen, linear: LinearFit, Tp: float, probe: float | None,
                   starts_of: Starts) -> tuple[CandidateFit, CandidateModel | None, Fit | None]:
    """One candidate fitted alone: its row, and its model and fit (None when the fit failed)."""
    tests, recs_fit = screen.tests, screen.recs_fit
    model = CandidateModel(cand, tests, Tp)
    lo, hi = theta_bounds(cand, tests)
    best = None
    starts = starts_of(cand)
    if len(starts) > 2:
        starts = _profile_starts(model, starts, lo, hi, recs_fit)
    for th in starts:
        f = fit_model(model, th, lo, hi, recs_fit)
        if f.ok and (best is None or f.chi2 < best.chi2):
            best = f
    if best is None:
        return CandidateFit(cand.name, "failed", status="fit failed"), None, None
    chi2 = best.chi2 + linear.chi2_scatter
    bic = chi2 + best.k * math.log(linear.n_all)
    after = held_out_score(model, best, tests, screen.recs_hold)
    value, std = effect_value(cand, model, best, model.unpack(best.theta))
    row = CandidateFit(cand.name, "fitted", parameter=cand.parameter, unit=cand.unit, value=value, std=std, chi2=chi2,
                       bic=bic, delta_bic=linear.bic - bic, held_out_before=linear.held_out, held_out_after=after,
                       fit_params=plant_params(model, best), probe_delta_chi2=probe)
    return row, model, best


def _probe_order(cands: list[Effect], screen: Screen, linear: LinearFit, Tp: float,
                 starts_of: Starts) -> dict[str, float]:
    """Each candidate's probe: at its starting values with Td and tau corrected by one Gauss-Newton
    step on the linear model's Jacobian (3 limit cycles per start instead of a fit)."""
    J_b = jacobian(linear.model, linear.fit.theta, screen.recs_fit)
    return {cand.name: probe_gain(CandidateModel(cand, screen.tests, Tp), starts_of(cand), linear.fit.chi2, J_b,
                                  screen.recs_fit)
            for cand in cands}


def search_candidates(linear: LinearFit, names: list[str], loop_model: LoopModel,
                      say: Callable[[str], None]) -> CandidateSearch:
    """Stage 3: each deterministic candidate of ``names`` fitted alone (when the linear model is rejected), on
    the screen the linear model was fitted on (``linear.screen``: each test's relay centre a nuisance)."""
    screen, Tp = linear.screen, loop_model.Tp
    rows: list[CandidateFit] = []
    fits: dict[str, tuple[CandidateModel, Fit]] = {}
    order = [c for c in CANDIDATES if c.name in names and not c.stochastic]
    probes: dict[str, float] = {}
    starts_of = Starts(screen, linear, Tp)
    if linear.rejected and order:
        probes = _probe_order(order, screen, linear, Tp, starts_of)
        order.sort(key=lambda c: -probes[c.name])
    explained_by = None
    for cand in order:
        say(f"fitting {cand.name}")
        if not linear.rejected:
            rows.append(CandidateFit(cand.name, "not_rejected", parameter=cand.parameter, unit=cand.unit,
                                     status="not fitted: the linear model is not rejected (every feature within "
                                            f"{REJECT_Z:g} standard errors, chi^2 p = {linear.p_value:.2g})"))
            continue
        if explained_by is not None:
            # a candidate already explains the fitting and the held-out cycles to the noise level: the
            # others (tried in the order of their probes) could only tie with it within the noise
            rows.append(CandidateFit(cand.name, "explained", parameter=cand.parameter, unit=cand.unit,
                                     probe_delta_chi2=probes.get(cand.name),
                                     status=f"not fitted: {explained_by} explains the cycles to the noise level"))
            continue
        row, model, best = _fit_candidate(cand, screen, linear, Tp, probes.get(cand.name), starts_of)
        rows.append(row)
        if model is None or best is None:
            continue
        fits[cand.name] = (model, best)
        if (significant(row) and float(chi2_dist.sf(best.chi2, max(best.n - best.k, 1))) > REJECT_P
                and explains_held_out(row.held_out_after, screen.tests)):
            explained_by = cand.name
    for cand in CANDIDATES:
        if cand.name in names and cand.stochastic:
            say(f"fitting {cand.name}")  # judged after the deterministic selection, against the model chosen there
    library = {c.name: i for i, c in enumerate(CANDIDATES)}
    rows.sort(key=lambda r: library[r.name])  # the library's order in the output, whatever the fitting order
    return CandidateSearch(rows=[replace(r, significant=significant(r)) for r in rows], fits=fits, order=order,
                           starts=starts_of)


def jacobian(model: CandidateModel, theta: np.ndarray, recs: list, step: float = 1e-3) -> np.ndarray:
    """Forward-difference Jacobian of the stacked z residuals at ``theta`` (the fit's diff_step)."""
    r0 = residuals(model, theta, recs)
    cols = []
    for j in range(theta.size):
        th = theta.copy()
        th[j] += step * max(abs(th[j]), 1.0)
        r = residuals(model, th, recs)
        if r is None or r0 is None:
            return np.zeros((0 if r0 is None else r0.size, theta.size))
        cols.append((r - r0) / (th[j] - theta[j]))
    return np.column_stack(cols)


def probe_gain(model: CandidateModel, starts: list[np.ndarray], chi2_ref: float, J: np.ndarray,
                recs_fit: list) -> float:
    """How much ``model`` lowers chi^2 below the reference fit's ``chi2_ref`` at its best start, the
    residual's part along the reference's parameter directions (its Jacobian ``J``) taken out by one
    Gauss-Newton step: one limit cycle per start instead of a fit."""
    best = -np.inf
    for th in starts:
        r = residuals(model, th, recs_fit)
        if r is None or not np.all(np.isfinite(r)):
            continue
        if J.shape[0] == r.size:
            d, *_ = np.linalg.lstsq(J, r, rcond=None)
            r = r - J @ d
        best = max(best, chi2_ref - float(r @ r))
    return float(best)
