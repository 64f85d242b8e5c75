"""Stage 4 of the diagnosis: the effects chosen, a second one by forward selection.

The first effect is the significant single candidate with the largest delta BIC. A second effect is
fitted on top of it (the pair model with the second's parameter at its null value is the first's
model, so the pair can only do better) and kept on the same evidence and held-out rules against the
first alone. When the first does not explain the held-out cycles, the next effects by evidence are
paired too (the first may stand in for a pair whose members are not it), and a swap step lets the
balance-shifting effects replace one another. Models within :data:`TIE_BIC` are named as
indistinguishable (docs/benchmarks/diagnose.md, "pair stage").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ..mrft.model import LoopModel
from .candidates import PROFILE_NFEV, CandidateSearch, LinearFit, Starts, jacobian, probe_gain
from .fit import Fit, effect_value, fit_model, plant_params, residuals
from .prepared import DiagnosedTest
from .candidate_model import CandidateModel
from .starts import theta_bounds
from .heldout import BIC_THRESHOLD, HOLDOUT_THRESHOLD, explains_held_out, harmonic_errors, held_out_score, significant
from .physics import BY_NAME, Effect
from .records import CandidateFit, EffectFinding, EffectIdentification, Evidence, FinalModel, HeldOut, PairFit
from .screen import Screen
from .testout import left_out_chi2

__all__ = ["PAIR_PROBE_MIN", "RIVAL_ANCHORS", "TIE_BIC", "EffectSelection", "select_effects", "effect_finding",
           "harmonics_before_after", "pair_starts", "pair_probe"]

#: a second effect is fitted beside a first that already explains the held-out cycles only when its
#: probe (one Gauss-Newton step from its starts) lowers the fitting cycles' chi^2 by this much
PAIR_PROBE_MIN = 8.0
#: effects after the first (by evidence alone) that are paired too when the first does not explain
#: the held-out cycles
RIVAL_ANCHORS = 2
#: models whose BIC differ by less than this are reported as indistinguishable (Kass & Raftery: "not
#: worth more than a bare mention")
TIE_BIC = 2.0


# --------------------------------------------------------------------------------------------------
# one pair: starts, fit, probe


def effect_finding(row: CandidateFit | PairFit, ident: EffectIdentification, harm: dict, compared_with: str,
                   bic_base: float, n_all: int) -> EffectFinding:
    """The :class:`~mrftcli.diagnose.records.EffectFinding` of a fitted candidate's (or pair's) row.

    Parameters
    ----------
    row : CandidateFit or PairFit
        The effect's row (a pair's: the effect added, its value from the joint fit).
    ident : EffectIdentification
        The plant's ``linear`` and ``with_effect`` estimates (and the pair's ``model``).
    harm : dict
        Per test, the harmonics' relative errors before and after.
    compared_with : str
        The model it beats.
    bic_base : float
        That model's BIC.
    n_all : int
        Features in the BIC.
    """
    cand = BY_NAME[row.name]
    assert (row.delta_bic is not None and row.bic is not None and row.held_out_before is not None
            and row.held_out_after is not None)  # (a significant row is a fitted one)
    return EffectFinding(
        name=cand.name,
        explanation=cand.explanation,
        augmentation=cand.augmentation,
        parameters={cand.parameter: row.value, f"{cand.parameter}_std": row.std, "unit": cand.unit,
                    **(row.fit_params or {})},
        evidence=Evidence(delta_bic=row.delta_bic, bic=row.bic, n_features=n_all, threshold=BIC_THRESHOLD,
                          compared_with=compared_with, bic_base=bic_base),
        fit_before=row.held_out_before,
        fit_after=row.held_out_after,
        identification=ident,
        harmonics=harm,
    )


def harmonics_before_after(tests: list[DiagnosedTest], base_model: CandidateModel, base: Fit, model: CandidateModel,
                           fit: Fit) -> dict:
    """Per test (its index as a string), the held-out cycles' relative G(j k Omega) errors of the model
    compared with (``before``) and of the model with the effect (``after``)."""
    out = {}
    for i, t in enumerate(tests):
        ev_b = base_model.evaluate(base.theta, i, t.tab.t_mid[t.hold].mean(), key=3000 + i)
        ev_a = model.evaluate(fit.theta, i, t.tab.t_mid[t.hold].mean(), key=3000 + i)
        if ev_b is None or ev_a is None:
            continue
        out[str(t.index)] = {
            "before": harmonic_errors(t, t.hold, ev_b, base.K),
            "after": harmonic_errors(t, t.hold, ev_a, fit.K),
        }
    return out


#: the value of each candidate's scaled parameter at which its model is the linear one (the nested
#: start of a pair fit); saturation's is its upper bound, the others' their lower bound when not listed
_NULL = {"input_bias": 0.0, "gain_drift": 0.0, "asymmetric_gain": 0.0}
#: the profiled candidates, whose starts carry their own Td and tau (they trade off against the delay)
_PROFILED = ("sensor_lag", "actuator_rate_limit")


def pair_starts(model: CandidateModel, lo: np.ndarray, c1: Effect, c2: Effect, fits: dict, base: Fit,
                starts2: list[np.ndarray], hi: np.ndarray) -> list[np.ndarray]:
    """Starts of the pair (c1 fitted already, c2 added): c1's fit with c2 at its null value (the
    nested model: the pair can only do better than c1 alone), at each of c2's own starts ``starts2``
    on the linear fit ``base`` (their Td and tau moved from c1's fit by what c2's start moved them from
    the linear fit), and, when c2 was fitted alone, its single fit's value."""
    m1, f1 = fits[c1.name]
    j1, j2 = model.extra_index(c1.name), model.extra_index(c2.name)
    k1 = m1.extra_index(c1.name)

    def assemble(head: np.ndarray, x2: float | None) -> np.ndarray:
        th = np.empty(lo.size)
        th[:2] = head
        if j1 is not None:
            th[j1] = f1.theta[k1]
        if j2 is not None and x2 is not None:
            th[j2] = x2
        return th

    starts = []
    if j2 is not None:
        null = _NULL.get(c2.name, hi[j2] if c2.name == "actuator_saturation" else lo[j2])
        starts.append(assemble(f1.theta[:2], null))
    for s2 in starts2:
        head = f1.theta[:2].copy()
        if c2.replaces_drag:
            head = np.array([s2[0], f1.theta[1] + s2[1] - base.theta[1]])
        elif c2.name in _PROFILED:
            head = head + (s2[:2] - base.theta[:2]) if not c1.replaces_drag else np.array(
                [head[0], head[1] + s2[1] - base.theta[1]])
        starts.append(assemble(head, None if c2.replaces_drag else s2[2]))
    if c2.name in fits and j2 is not None:
        m2, f2 = fits[c2.name]
        starts.append(assemble(f1.theta[:2], f2.theta[m2.extra_index(c2.name)]))
    return starts


def _pair_candidate(first: CandidateFit, other: str, fits: dict, base: Fit, tests: list[DiagnosedTest], Tp: float,
                    recs_fit: list, recs_hold: list, chi2_scatter: float, n_all: int, starts_of: Starts
                    ) -> tuple[PairFit | None, CandidateModel | None, Fit | None]:
    """Fit the first effect (its row ``first``, fitted alone already) and ``other`` together; evidence
    and held-out scores against the first alone: the pair's row, model and fit (None, None, None when
    the two cannot be paired or no fit succeeded).

    The starts (:func:`_pair_starts`) are scored first (one limit cycle each) and the fit runs from
    the best ones, so the pair never ends worse than the first alone (before, pair fits started only
    from the two single fits and some ended at delta BIC -1e4 to -1e6). ``delta_bic`` =
    BIC(first) - BIC(pair): the pair has one parameter more.
    """
    c1, c2 = BY_NAME[first.name], BY_NAME[other]
    if c1.replaces_drag and c2.replaces_drag:
        return None, None, None
    model = CandidateModel((c1, c2), tests, Tp)
    lo, hi = theta_bounds((c1, c2), tests)
    scored = []
    j2 = model.extra_index(c2.name)
    for i, th in enumerate(pair_starts(model, lo, c1, c2, fits, base, starts_of(c2), hi)):
        th = np.clip(th, lo + 1e-9, hi - 1e-9)
        if i > 0 and c2.name in _PROFILED and j2 is not None:
            # a lag or a slew trades off against the delay along a curved valley (as alone): each of
            # its starts is scored after a few steps with it held
            free = np.ones(th.size, bool)
            free[j2] = False
            pf = fit_model(model, th, lo, hi, recs_fit, max_nfev=PROFILE_NFEV, free=free)
            if pf.ok and np.isfinite(pf.chi2):
                scored.append((pf.chi2, pf.theta))
            continue
        r = residuals(model, th, recs_fit)
        if r is not None and np.all(np.isfinite(r)):
            scored.append((float(r @ r), th))
    if not scored:
        return None, None, None
    scored.sort(key=lambda x: x[0])
    best = None
    for chi2_start, th in scored[:2]:
        if best is not None and chi2_start > 1.5 * scored[0][0] + BIC_THRESHOLD:
            break
        f = fit_model(model, th, lo, hi, recs_fit)
        if f.ok and (best is None or f.chi2 < best.chi2):
            best = f
    if best is None:
        return None, None, None
    chi2 = best.chi2 + chi2_scatter
    bic = chi2 + best.k * math.log(n_all)
    p = model.unpack(best.theta)
    values, stds = {}, {}
    for c in (c1, c2):
        values[c.name], stds[c.name] = effect_value(c, model, best, p)
    assert first.bic is not None  # (a fitted first effect)
    row = PairFit(c2.name, c1.name, "fitted", parameter=c2.parameter, unit=c2.unit, values=values, stds=stds, chi2=chi2,
                  bic=bic, delta_bic=first.bic - bic, held_out_before=first.held_out_after,
                  held_out_after=held_out_score(model, best, tests, recs_hold), fit_params=plant_params(model, best))
    return row, model, best


def pair_probe(first: CandidateFit, cand: Effect, fits: dict, J1: np.ndarray, base: Fit, tests: list[DiagnosedTest],
               recs_fit: list, Tp: float, starts_of: Starts) -> float | None:
    """:func:`_probe_gain` of the pair (the first effect fitted, ``cand`` added) against the first
    alone (its Jacobian ``J1``), from the pair's starts other than the nested null one; None when the
    two cannot be paired."""
    c1 = BY_NAME[first.name]
    if c1.replaces_drag and cand.replaces_drag:
        return None
    model = CandidateModel((c1, cand), tests, Tp)
    lo, hi = theta_bounds((c1, cand), tests)
    starts = pair_starts(model, lo, c1, cand, fits, base, starts_of(cand), hi)
    if model.extra_index(cand.name) is not None:
        starts = starts[1:]  # the null start is the first alone: no gain
    return probe_gain(model, [np.clip(th, lo + 1e-9, hi - 1e-9) for th in starts], fits[c1.name][1].chi2, J1,
                       recs_fit)


# --------------------------------------------------------------------------------------------------
# the selection


@dataclass(frozen=True)
class EffectSelection:
    """The deterministic effects chosen (:func:`select_effects`).

    Attributes
    ----------
    effects : list of EffectFinding
        The first effect and, when one passed the rules, the second (empty when no candidate did).
    pair_rows : list of PairFit
        Every pair fitted or probed: ``with`` (the anchor), the candidate added, its evidence and
        held-out scores against the anchor alone, ``significant``.
    final : FinalModel or None
        The model finally chosen (for the jitter's reference, the unexplained check and the plots).
    warnings : list of str
        Ties among models the recording cannot rank.
    """

    effects: list[EffectFinding]
    pair_rows: list[PairFit]
    final: FinalModel | None
    warnings: list[str]


class _Pairs:
    """The pair fits of one diagnosis: their rows, in the order fitted, and each row's joint fit."""

    def __init__(self, screen: Screen, linear: LinearFit, search: CandidateSearch, Tp: float) -> None:
        self.screen, self.linear, self.fits, self.starts, self.Tp = screen, linear, search.fits, search.starts, Tp
        self.rows: list[PairFit] = []
        self._joint: list[tuple[PairFit, CandidateModel, Fit]] = []

    def pair(self, anchor: CandidateFit, other: str) -> PairFit | None:
        """Fit ``anchor``'s effect and ``other`` together; the row (also kept), or None."""
        sc, lin = self.screen, self.linear
        pr, model, fit = _pair_candidate(anchor, other, self.fits, lin.fit, sc.tests, self.Tp, sc.recs_fit,
                                        sc.recs_hold, lin.chi2_scatter, lin.n_all, self.starts)
        if pr is not None and model is not None and fit is not None:
            pr = replace(pr, significant=significant(pr))
            self.rows.append(pr)
            self._joint.append((pr, model, fit))
        return pr

    def joint(self, row: PairFit) -> tuple[CandidateModel, Fit]:
        """The joint model and fit of a pair row."""
        return next((m, f) for r, m, f in self._joint if r is row)

    def probe(self, anchor: CandidateFit, cand: Effect, J: np.ndarray) -> float | None:
        """:func:`pair_probe` of ``cand`` beside ``anchor`` (its fit's Jacobian ``J``)."""
        sc = self.screen
        return pair_probe(anchor, cand, self.fits, J, self.linear.fit, sc.tests, sc.recs_fit, self.Tp, self.starts)

    def probed(self, first: CandidateFit, order: list[Effect]) -> None:
        """The first explains the held-out cycles to the noise level, yet a second effect can still be
        plain on the fitting cycles (thrust rectification beside an asymmetric gain or a saturation:
        delta BIC 40-65): every other candidate is probed, and only those whose probe clears
        :data:`PAIR_PROBE_MIN` are fitted."""
        m1, f1 = self.fits[first.name]
        J1 = jacobian(m1, f1.theta, self.screen.recs_fit)
        for cand in order:
            if cand.name == first.name:
                continue
            gain = self.probe(first, cand, J1)
            if gain is not None and gain >= PAIR_PROBE_MIN:
                self.pair(first, cand.name)
            else:
                self.rows.append(PairFit(cand.name, first.name, "probed", parameter=cand.parameter, unit=cand.unit,
                                         probe_delta_chi2=gain, status="not fitted: its probe lowers chi^2 by less "
                                                                       f"than {PAIR_PROBE_MIN:g}"))

    def rivals(self, first: CandidateFit, second: PairFit | None, rivals: list[CandidateFit],
               cand_rows: list[CandidateFit]) -> tuple[CandidateFit, PairFit | None]:
        """The first may be a stand-in for a pair whose members are not it (a sensor lag imitates a
        slew with quadratic drag; an asymmetric gain stood in for a gain drift beside a saturation),
        so the next :data:`RIVAL_ANCHORS` effects by evidence alone are paired too (partners pruned by
        their probe); such a pair replaces the first's only when it also passes the rules against the
        first alone and has the lower BIC. Returns (anchor of the second, second)."""
        tried = {frozenset((pr.with_, pr.name)) for pr in self.rows}
        anchor_of_second = first
        for alt in rivals[:RIVAL_ANCHORS]:
            m_alt, f_alt = self.fits[alt.name]
            J_alt = None
            for row in cand_rows:
                if row.name == alt.name or row.name not in self.fits or frozenset((alt.name, row.name)) in tried:
                    continue
                tried.add(frozenset((alt.name, row.name)))
                if J_alt is None:
                    J_alt = jacobian(m_alt, f_alt.theta, self.screen.recs_fit)
                gain = self.probe(alt, BY_NAME[row.name], J_alt)
                if gain is None or gain < PAIR_PROBE_MIN:
                    continue
                pr = self.pair(alt, row.name)
                if pr is None or not pr.significant or pr.bic is None or first.bic is None:
                    continue
                against_first = replace(pr, delta_bic=first.bic - pr.bic, held_out_before=first.held_out_after)
                if significant(against_first) and (second is None or pr.bic < _bic(second)):
                    second, anchor_of_second = pr, alt
        return anchor_of_second, second

    def swap(self, first: CandidateFit, second: PairFit, deterministic: list[CandidateFit],
             cand_rows: list[CandidateFit]) -> tuple[CandidateFit, PairFit]:
        """The balance-shifting effects (a trim error, an asymmetric gain, a saturation) stand in for
        one another, so the first effect found may be the stand-in for the true partner of the second:
        with the second kept, each other effect significant alone takes the first's place, and the pair
        with the lowest BIC is kept (it must pass the rules against the second effect alone, as the
        first pair did against the first)."""
        anchor = next(r for r in cand_rows if r.name == second.name)
        if anchor.significant:
            for row in deterministic[1:]:
                if row.name == anchor.name:  # (not second.name: second changes inside the loop)
                    continue
                pr = self.pair(anchor, row.name)
                if pr is not None and pr.significant and _bic(pr) < _bic(second):
                    first, second = anchor, pr
        return first, second


def _bic_gain(row: CandidateFit | PairFit) -> float:
    """The delta BIC of a fitted row."""
    assert row.delta_bic is not None  # (only fitted rows are ranked)
    return row.delta_bic


def _bic(row: CandidateFit | PairFit) -> float:
    """The BIC of a fitted row."""
    assert row.bic is not None  # (only fitted rows are compared)
    return row.bic


def _findings(first: CandidateFit, second: PairFit | None, pairs: _Pairs) -> tuple[list[EffectFinding], FinalModel]:
    """The findings of the effects chosen and the model they make."""
    lin, tests = pairs.linear, pairs.screen.tests
    base_params = plant_params(lin.model, lin.fit)
    m1, f1 = pairs.fits[first.name]
    final = FinalModel(first.name, m1, f1)
    effects = [effect_finding(first, EffectIdentification.of(base_params, first.fit_params or {}),
                              harmonics_before_after(tests, lin.model, lin.fit, m1, f1), "linear", lin.bic, lin.n_all)]
    if second is None:
        return effects, final
    mp, fp = pairs.joint(second)
    final = FinalModel(f"{first.name} + {second.name}", mp, fp)
    # with both effects modelled, both parameters come from the joint fit
    par = BY_NAME[first.name].parameter
    value, std = effect_value(BY_NAME[first.name], mp, fp, mp.unpack(fp.theta))
    params = effects[0].parameters
    params[f"{par}_alone"] = params[par]
    params[f"{par}_alone_std"] = params[f"{par}_std"]
    params[par], params[f"{par}_std"] = value, std
    effects.append(effect_finding(second, EffectIdentification.of(base_params, second.fit_params or {},
                                                                  f"{first.name}+{second.name}"),
                                  harmonics_before_after(tests, m1, f1, mp, fp), f"linear + {first.name}", _bic(first),
                                  lin.n_all))
    return effects, final


def _ties(effects: list[EffectFinding], first: CandidateFit, second: PairFit | None, cand_rows: list[CandidateFit],
          pair_rows: list[PairFit], fits: dict) -> tuple[list[EffectFinding], list[str]]:
    """Models the recording cannot rank (BIC within :data:`TIE_BIC` of the one chosen, and passing the
    same rules) are named (``evidence.indistinguishable_from``): the choice among them is not the
    data's. Returns the effects (with the ties named) and the warning, if any."""
    chosen = {first.name} | ({second.name} if second is not None else set())
    rows: list[CandidateFit] | list[PairFit]
    if second is None:
        rows, ref = [r for r in cand_rows if r.significant and r.name in fits], _bic(first)
        labels = [(r.name, _bic(r)) for r in rows]
    else:
        rows, ref = [pr for pr in pair_rows if pr.significant], _bic(second)
        labels = [(f"{r.with_}+{r.name}", _bic(r)) for r in rows]
    ties = sorted({label for label, bic in labels if abs(bic - ref) < TIE_BIC and set(label.split("+")) != chosen})
    if not ties:
        return effects, []
    effects = [replace(e, evidence=replace(e.evidence, indistinguishable_from=ties)) for e in effects]
    models = [first.name if second is None else f"{first.name}+{second.name}", *ties]
    return effects, [f"{', '.join(models[:-1])} and {models[-1]} fit these tests equally well "
                     f"(BIC within {TIE_BIC:g}): the tests cannot tell them apart; a test at another relay "
                     "height or beta, or longer tests, would"]


def _unconfirmed(cand_rows: list[CandidateFit], found: set[str]) -> list[str]:
    """One warning naming the candidates with strong evidence on the fitting cycles whose refit does
    not improve the held-out cycles (not reported as effects, issue 27)."""
    rows = [r for r in cand_rows if r.name not in found and r.name != "delay_jitter" and not r.significant
            and r.delta_bic is not None and r.delta_bic >= BIC_THRESHOLD]
    if not rows:
        return []
    parts = [f"{r.name} (delta BIC {r.delta_bic:.0f}; held-out NRMSE {_nrmse(r.held_out_before)} -> "
             f"{_nrmse(r.held_out_after)})" for r in rows]
    return ["not reported, their refit does not improve the held-out cycles: " + ", ".join(parts)]


def _improving(effects: list[EffectFinding]) -> tuple[list[EffectFinding], list[str]]:
    """The findings whose refit does not raise the held-out NRMSE they report beyond chance
    (:meth:`~mrftcli.diagnose.rows.HeldOut.worse_beyond_chance`; a sensor lag once went 0.011 -> 0.013 and
    was reported, issue 27), and a warning for the others. A pair is judged as a whole
    against the linear model (a rate limit alone may not help where the rate limit with the drag
    does), after its second effect against the first alone."""
    said: list[str] = []

    def rises(before: HeldOut, after: HeldOut, what: str) -> bool:
        b, a = before.nrmse, after.nrmse
        if b is None or a is None or not after.worse_beyond_chance(before):
            return False
        said.append(f"{what} not reported: the refit does not improve the held-out cycles (NRMSE {b:.3g} -> {a:.3g})")
        return True

    if len(effects) == 2 and rises(effects[1].fit_before, effects[1].fit_after, effects[1].name):
        effects = effects[:1]
    if effects and rises(effects[0].fit_before, effects[-1].fit_after, " with ".join(e.name for e in effects)):
        effects = []
    return effects, said


def _first_earns_place(first: CandidateFit, second: PairFit, cand_rows: list[CandidateFit],
                       fits: dict) -> tuple[CandidateFit, PairFit | None, list[str]]:
    """Leave-one-out on a pair (issue 39): the second effect earned its place against the first alone
    (its row is significant); the first must earn its place against the second alone, by the same
    rules (delta BIC >= 10 and confirmed on the held-out cycles). When it does not, the second alone
    is reported (a drag and a rate limit both bend the waveform: the pair was once named on every
    drag flight of a simulator written elsewhere)."""
    alone = next((r for r in cand_rows if r.name == second.name and r.significant and r.name in fits), None)
    if alone is None or alone.bic is None:
        return first, second, []
    loo = replace(second, held_out_before=alone.held_out_after, delta_bic=_bic(alone) - _bic(second))
    if significant(loo):
        return first, second, []
    return alone, None, [f"{first.name} not reported beside {second.name}: {second.name} alone explains the "
                         f"cycles as well (delta BIC {loo.delta_bic:.1f} for adding {first.name}; held-out NRMSE "
                         f"{_nrmse(alone.held_out_after)} -> {_nrmse(second.held_out_after)})"]


def _pair_predicts_tests(first: CandidateFit, second: PairFit, cand_rows: list[CandidateFit], pairs: _Pairs,
                         said: list[str]) -> tuple[CandidateFit, PairFit | None, list[str]]:
    """Leave one test out on a pair (issue 39, :mod:`.testout`): the pair must predict each test from
    the others better than each of its effects alone (fitted alone and significant) by
    :data:`HOLDOUT_THRESHOLD` in chi^2; otherwise the single effect that predicts them best is
    reported alone, with a warning. The held-out cycles are the odd cycles of the tests fitted, so a
    second effect that only absorbs how the tests differ passes them; a left-out test does not."""
    sc = pairs.screen
    mp, fp = pairs.joint(second)
    chi2_pair = left_out_chi2(mp, fp, sc.tests, sc.recs_fit, sc.recs_all)
    if chi2_pair is None:
        return first, second, said
    singles = []
    for row in (first, next((r for r in cand_rows if r.name == second.name), None)):
        if row is None or not row.significant or row.name not in pairs.fits:
            continue
        m, f = pairs.fits[row.name]
        chi2 = left_out_chi2(m, f, sc.tests, sc.recs_fit, sc.recs_all)
        if chi2 is not None:
            singles.append((chi2, row))
    worse = [(c, r) for c, r in singles if chi2_pair > c - HOLDOUT_THRESHOLD]
    if not worse:
        return first, second, said
    chi2_best, best = min(singles, key=lambda x: x[0])
    other = second.name if best.name == first.name else first.name
    return best, None, said + [
        f"{other} not reported beside {best.name}: the pair does not predict each test from the others better "
        f"than {best.name} alone (left-out tests' feature chi^2 {chi2_pair:.0f} with both, {chi2_best:.0f} with "
        f"{best.name} alone)"]


def _nrmse(held: HeldOut | None) -> str:
    return "n/a" if held is None or held.nrmse is None else f"{held.nrmse:.3g}"


def select_effects(linear: LinearFit, search: CandidateSearch, loop_model: LoopModel,
                   say: Callable[..., None]) -> EffectSelection:
    """Stage 4: the first effect (the significant candidate with the largest delta BIC) and a second one
    on top of it by forward selection, kept on the same evidence and held-out rules.

    Every other candidate fitted is paired with the first, also one that fitted worse than the linear
    model alone (quadratic drag beside a rate limit: alone it cannot take the linear drag the slew
    imitates, with the slew modelled it is found); once the first explains the held-out cycles to the
    noise level, only those whose probe clears :data:`PAIR_PROBE_MIN`. On the screen the linear model was
    fitted on (``linear.screen``: each test's relay centre a nuisance).
    """
    screen, cand_rows, fits = linear.screen, search.rows, search.fits
    deterministic = sorted((r for r in cand_rows if r.significant and r.name in fits), key=lambda r: -_bic_gain(r))
    if not deterministic:
        return EffectSelection(effects=[], pair_rows=[], final=None, warnings=_unconfirmed(cand_rows, set()))
    first = deterministic[0]
    say(f"testing a second effect on top of {first.name}", more=1)
    pairs = _Pairs(screen, linear, search, loop_model.Tp)
    searched = not explains_held_out(first.held_out_after, screen.tests)
    if searched:
        for row in cand_rows:
            if row.name != first.name and row.name in fits:
                pairs.pair(first, row.name)
    else:
        pairs.probed(first, search.order)
    good = sorted((pr for pr in pairs.rows if pr.significant), key=lambda r: -_bic_gain(r))
    second = good[0] if good else None
    if searched:
        rivals = sorted((r for r in cand_rows if r.name in fits and r.name != first.name
                         and (r.delta_bic or -1.0) >= BIC_THRESHOLD), key=lambda r: -_bic_gain(r))
        first, second = pairs.rivals(first, second, rivals, cand_rows)
    loo: list[str] = []
    if second is not None:
        first, second = pairs.swap(first, second, deterministic, cand_rows)
        first, second, loo = _first_earns_place(first, second, cand_rows, fits)
    if second is not None:
        first, second, loo = _pair_predicts_tests(first, second, cand_rows, pairs, loo)
    effects, final = _findings(first, second, pairs)
    effects, warnings = _ties(effects, first, second, cand_rows, pairs.rows, fits)
    warnings = loo + warnings
    effects, dropped = _improving(effects)
    warnings += dropped + _unconfirmed(cand_rows, {e.name for e in effects} | {d.name for d in deterministic})
    return EffectSelection(effects=effects, pair_rows=pairs.rows, final=final, warnings=warnings)
