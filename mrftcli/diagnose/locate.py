"""Where a model and the recording disagree: which test, which feature, which cycles, which harmonic.

:func:`locate` lists the features beyond 3 standard errors (and the period scatter beyond what noise
explains), the harmonics whose G(j k Omega) is off by more than 5 %, and the runs of cycles whose
waveform error stands out; :func:`unexplained_mismatch` describes what no candidate explains.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import chi2 as chi2_dist

from .features import FEATURE_NAMES
from .fit import CandidateModel, DiagnosedTest, Fit, feature_mask
from .heldout import harmonic_errors, held_out_p, waveform_errors
from .scatter import scatter_z
from .records import CandidateFit, CycleErrors, Disagreement, EffectFinding, FinalModel, HeldOut, Unexplained

__all__ = ["UNEXPLAINED_P", "FEATURE_TEXT", "Located", "locate", "unexplained_mismatch"]

#: a mismatch counts as unexplained below this chi^2 p-value (fitting and held-out cycles of the linear
#: model, and the held-out cycles of the model finally chosen)
UNEXPLAINED_P = 1e-3

#: each feature in words
FEATURE_TEXT = {
    "period": "oscillation period",
    "balance": "half-period balance (time at +h vs -h)",
    "log_amplitude": "amplitude",
    "centre": "oscillation centre relative to the setpoint",
    "h3_re": "3rd-harmonic content of the waveform",
    "h3_im": "3rd-harmonic content of the waveform",
    "h5_re": "5th-harmonic content of the waveform",
    "h5_im": "5th-harmonic content of the waveform",
    "h2_re": "2nd-harmonic content of the waveform (the two half-cycles differ)",
    "h2_im": "2nd-harmonic content of the waveform (the two half-cycles differ)",
    "amplitude_trend": "amplitude trend over time",
    "balance_trend": "half-period balance trend over time",
    "period_scatter": "cycle-to-cycle period scatter",
}


@dataclass(frozen=True)
class Located:
    """Where a model disagrees with the recording (:func:`locate`).

    Attributes
    ----------
    items : list of Disagreement
        The disagreements, largest first: ``kind`` "feature" (z beyond 3), "harmonic" (G(j k Omega)
        off by more than 5 %) or "segment" (a run of cycles whose waveform error stands out); empty
        when no feature disagrees beyond the noise.
    cycle_errors : list of CycleErrors
        Per test, every cycle's waveform NRMSE (the report's plot).
    harmonics : list of dict
        Per test, the relative error of G(j k Omega) per odd harmonic k.
    """

    items: list[Disagreement]
    cycle_errors: list[CycleErrors]
    harmonics: list[dict]


def _feature_items(t: DiagnosedTest, values: np.ndarray, fm: np.ndarray, z: np.ndarray) -> list[Disagreement]:
    """The features of test ``t`` beyond 3 standard errors, recorded (``values``) against model (``fm``)."""
    ia = FEATURE_NAMES.index("log_amplitude")
    out = []
    for j, name in enumerate(FEATURE_NAMES):
        if not feature_mask(t)[j] or abs(z[j]) < 3.0:
            continue
        rec, mod = float(values[j]), float(fm[j])
        item: dict[str, Any] = {
            "kind": "feature",
            "test": t.index,
            "beta": float(np.mean(t.beta)),
            "h": t.h,
            "t_start": t.t_start,
            "t_end": t.t_end,
            "feature": name,
            "what": FEATURE_TEXT[name],
            "recorded": rec,
            "model": mod,
            "difference": rec - mod,
            "z": float(z[j]),
        }
        if name == "log_amplitude":
            item.update(recorded=math.exp(rec), model=math.exp(mod), difference=math.exp(rec) - math.exp(mod),
                        relative=math.exp(rec - mod) - 1.0)
        if name == "period":
            item["relative"] = rec / mod - 1.0
            item["unit"] = "s"
        if name == "centre":
            a_rec = math.exp(float(values[ia]))
            item.update(recorded=rec * a_rec, model=mod * math.exp(float(fm[ia])),
                        difference=rec * a_rec - mod * math.exp(float(fm[ia])), unit="output units")
        if name in ("amplitude_trend", "balance_trend"):
            item["unit"] = "relative change per second" if name == "amplitude_trend" else "per second"
        if name == "balance":
            P = float(values[0])
            item["half_periods_recorded"] = {"high": P * (0.5 + rec), "low": P * (0.5 - rec)}
            item["half_periods_model"] = {"high": P * (0.5 + mod), "low": P * (0.5 - mod)}
        out.append(Disagreement(**item))
    return out


def _scatter_item(t: DiagnosedTest, sc: dict) -> Disagreement | None:
    """The period scatter of test ``t`` when it is beyond 3 standard errors of what noise explains."""
    zs = float(scatter_z([t], [sc], "all", [sc["v0"]])[0])
    if not abs(zs) >= 3.0:
        return None
    s_rec = math.sqrt(t.scatter_var("all")[0])
    return Disagreement("feature", t.index, float(np.mean(t.beta)), t.h, t.t_start, t.t_end, feature="period_scatter",
                        what=FEATURE_TEXT["period_scatter"], recorded=s_rec, model=sc["s0"],
                        difference=s_rec - sc["s0"], z=zs)


def _harmonic_item(t: DiagnosedTest, harm: dict) -> Disagreement | None:
    """The worse of the fundamental and the 3rd harmonic when its G(j k Omega) is off by more than 5 %
    (only these two are well above the noise at realistic amplitudes)."""
    strong = {k: v for k, v in harm.items() if k in ("1", "3")}
    if not strong:
        return None
    kmax = max(strong, key=lambda k: strong[k])
    if not strong[kmax] > 0.05:
        return None
    return Disagreement("harmonic", t.index, float(np.mean(t.beta)), t.h, t.t_start, t.t_end, harmonic=int(kmax),
                        what=f"G(j{kmax}Omega) measured from harmonic {kmax} of output/command",
                        relative_error=harm[kmax], all=harm)


def _segment_items(tests: list[DiagnosedTest], cycle_errors: list[CycleErrors]) -> list[Disagreement]:
    """Runs of cycles whose waveform error stands out from the log's typical cycle."""
    out: list[Disagreement] = []
    if not cycle_errors:
        return out
    med = float(np.nanmedian(np.concatenate([ce.nrmse for ce in cycle_errors])))
    for t, ce in zip(tests, cycle_errors):
        bad = ce.nrmse > max(1.5 * med, 0.02)
        if not bad.any():
            continue
        idx = np.flatnonzero(bad)
        for rr in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            hi_err = float(np.nanmean(ce.hi[rr]))
            lo_err = float(np.nanmean(ce.lo[rr]))
            out.append(Disagreement(
                "segment", t.index, float(np.mean(t.beta)), t.h, float(ce.start[rr[0]]), float(ce.end[rr[-1]]),
                cycles=[int(x) for x in rr],
                nrmse=float(np.nanmean(ce.nrmse[rr])),
                typical_nrmse=med,
                worse_half="high (+h)" if hi_err > lo_err else "low (-h)",
                half_nrmse={"high": hi_err, "low": lo_err},
            ))
    return out


def _rank(d: Disagreement) -> float:
    """Features first, largest |z| first, then the harmonics, then the segments."""
    if d.kind == "feature":
        return -abs(d.z if d.z is not None else 0.0)
    return 0 if d.kind == "harmonic" else 1


def locate(tests: list[DiagnosedTest], model: CandidateModel, fit: Fit, recs_all: list, scatter: list[dict]) -> Located:
    """Where ``model`` (fitted: ``fit``) and the recording disagree: features, cycles/halves, harmonics.

    Parameters
    ----------
    tests : list of DiagnosedTest
        The tests diagnosed.
    model, fit : CandidateModel, Fit
        The model and its fit (the linear one, or with the effects chosen).
    recs_all : list of (FeatureSummary, ndarray)
        Per test, the features over all its stable cycles and their standard errors.
    scatter : list of dict
        Per test, the noise-only period scatter (:func:`mrftcli.diagnose.scatter.scatter_reference`).
    """
    items: list[Disagreement] = []
    ia = FEATURE_NAMES.index("log_amplitude")
    cycle_errors: list[CycleErrors] = []
    harmonics: list[dict] = []
    for i, (t, (feats, sigma)) in enumerate(zip(tests, recs_all)):
        ev = model.evaluate(fit.theta, i, feats.t_mean, key=4000 + i)
        if ev is None:
            continue
        fm = ev.features.copy()
        fm[ia] += math.log(fit.K)
        items += _feature_items(t, feats.values, fm, (feats.values - fm) / sigma)
        scatter_item = _scatter_item(t, scatter[i])
        if scatter_item is not None:
            items.append(scatter_item)
        # per cycle and half-cycle waveform errors
        allm = np.ones(len(t.tab), bool)
        e, v, e_hi, e_lo = waveform_errors(t, allm, [ev], fit.K)
        cycle_errors.append(CycleErrors(t=t.tab.t_mid, nrmse=np.sqrt(e / np.where(v > 0, v, np.nan)),
                                        hi=np.sqrt(e_hi / v), lo=np.sqrt(e_lo / v), start=t.tab.start, end=t.tab.end))
        harm = harmonic_errors(t, allm, ev, fit.K)
        harmonics.append(harm)
        harmonic_item = _harmonic_item(t, harm)
        if harmonic_item is not None:
            items.append(harmonic_item)
    # time segments only when some feature disagrees beyond the noise at all: otherwise they would flag noise
    if any(d.kind == "feature" for d in items):
        items += _segment_items(tests, cycle_errors)
    else:
        items = []
    items.sort(key=_rank)
    return Located(items=items, cycle_errors=cycle_errors, harmonics=harmonics)


def unexplained_mismatch(tests: list[DiagnosedTest], base: Fit, before: HeldOut, effects: list[EffectFinding],
                         final: FinalModel | None, cand_rows: list[CandidateFit], recs_all: list, scatter: list[dict],
                         t0_log: float, base_located: list[Disagreement]) -> Unexplained | None:
    """The mismatch no candidate (or pair) explains: where and how large, or None.

    Reported when the linear model is rejected on the fitting cycles *and* on the held-out ones
    (chi^2 p-value below :data:`UNEXPLAINED_P` on both), and the model finally chosen (the linear one
    when nothing was found) is still rejected on the held-out cycles at that level.
    """
    dof_fit = max(base.n - base.k, 1)
    p_fit = float(chi2_dist.sf(base.chi2, dof_fit))
    p_hold = held_out_p(before, tests)
    if not (p_fit < UNEXPLAINED_P and p_hold < UNEXPLAINED_P):
        return None
    det = [e for e in effects if e.name != "delay_jitter"]
    held = det[-1].fit_after if det else before
    p_final = held_out_p(held, tests)
    if not p_final < UNEXPLAINED_P:
        return None
    model_name = "linear" if final is None else f"linear + {final.label}"
    # where: the base model's disagreements, or the chosen model's when an effect was modelled
    located = base_located if final is None else locate(tests, final.model, final.fit, recs_all, scatter).items
    feats = [d for d in located if d.kind == "feature"]
    segs = [d for d in located if d.kind == "segment"]
    harms = [d for d in located if d.kind == "harmonic"]
    worst = feats[0] if feats else None
    gains = [(r, r.delta_bic) for r in cand_rows if r.delta_bic is not None]
    tested = [(r, gain) for r, gain in sorted(gains, key=lambda rg: -rg[1])]
    where_tests = sorted({d.test + 1 for d in feats})
    half = None
    if segs:
        halves = [d.worse_half for d in segs]
        half = max(set(halves), key=halves.count)
    return Unexplained(
        after=model_name,
        what=("the linear model is rejected, and no candidate effect (or pair) of the library explains the "
              "mismatch" if final is None else
              f"the model with {final.label} still leaves a mismatch beyond the noise on the held-out cycles"),
        held_out_feature_chi2=held.feature_chi2,
        held_out_features=sum(int(feature_mask(t).sum()) for t in tests),
        p_value=p_final,
        held_out_nrmse_raw=held.nrmse_raw,
        tests=where_tests,
        largest=None if worst is None else {
            "test": worst.test + 1, "feature": worst.feature, "what": worst.what, "z": worst.z,
            "recorded": worst.recorded, "model": worst.model},
        segments=[{"test": d.test + 1, "t_start_rel": d.t_start - t0_log, "t_end_rel": d.t_end - t0_log,
                   "cycles": [c + 1 for c in d.cycles or []], "nrmse": d.nrmse, "worse_half": d.worse_half}
                  for d in segs[:5]],
        harmonics=[{"test": d.test + 1, "harmonic": d.harmonic, "relative_error": d.relative_error}
                   for d in harms[:5]],
        best_candidate=None if not tested else {"name": tested[0][0].name, "delta_bic": tested[0][1],
                                                "significant": bool(tested[0][0].significant)},
        worse_half=half,
    )
