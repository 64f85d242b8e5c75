"""Diagnose where the identified linear model and a flight log disagree, and which physics explains it.

Pipeline (``docs/diagnose.md`` walks through a case):

1. **Measure.** The MRFT tests and their stable cycles come from :func:`mrftcli.segment.segment`
   (or from an :class:`~mrftcli.analyze.AnalysisResult` already computed). Every cycle is measured by
   :func:`mrftcli.diagnose.features.cycle_table`: period, half-period balance, the noise-free
   waveform (harmonics 1..7 of the cycle), amplitude, centre, per-harmonic response Y_k/U_k and the
   switching levels the relay actually achieved (effective beta, per switch direction).
2. **Split.** Even-numbered stable cycles of each test are the fitting set, odd ones are held out.
3. **Base model.** Td and tau (K in closed form, Lemma 2) are fitted to the fitting set's features:
   per test the mean period, balance, log amplitude, centre, shape (Y3/Y1, Y5/Y1; Y2/Y1: the two
   half-cycles differ), amplitude and balance trends. The model's features come from its exact limit
   cycle under the same MRFT settings (effective betas, h, rate) computed by
   :mod:`mrftcli.diagnose.limit_cycles`. Each residual is
   weighted by its standard error (cycle-to-cycle spread / sqrt(n), with a small floor for the
   modelling approximations), so chi^2 is in units of what the noise explains. The cycle-to-cycle
   period scatter is compared with what the base model plus sensor noise produces on a sampled relay.
4. **Candidates** (:mod:`mrftcli.diagnose.physics`): each augments the model with one parameter and is
   refitted together with Td and tau. Evidence: BIC = chi^2 + k ln n over the same features;
   ``delta_bic`` = BIC(base) - BIC(candidate). An effect is reported when delta_bic >= 10 ("very
   strong" on Kass-Raftery's scale) *and* it improves the held-out cycles (feature chi^2 and
   waveform NRMSE); otherwise nothing is reported.
5. **Locate.** The base model's residuals say which test, which feature (period, a half-period,
   amplitude, a harmonic, a trend, the scatter), which time segment and by how much.

Everything here is pure computation on a :class:`~mrftcli.io.logtypes.FlightLog`; I/O is limited to
reading the log when a path is given.
"""

from __future__ import annotations

import math
import warnings
import warnings as pywarnings  # (diagnose() has a local list named warnings)
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.stats import chi2 as chi2_dist

from .features import FEATURE_NAMES, cycle_scatter, summarize_features
from .fit import (MIN_CYCLES, CandidateModel, Fit, PredictedCycle, DiagnosedTest, candidate_starts, effect_value, residuals,
                           feature_mask, feature_sigma, fit_base, fit_model, plant_params, prepare_tests, segments_of,
                           theta_bounds)
from .physics import BY_NAME, CANDIDATES, Candidate
from .limit_cycles import periodic_cycle
from .scatter import ScatterSetting, expected_period_variance, fit_jitter, pooled_scatter_error, refit_sigma
from ..errors import DiagnoseError, IdentificationError, InputError, MrftError
from ..analyze import log_start
from ..io.logtypes import FlightLog
from ..progress import Progress, report
from ..validate import check_time

if TYPE_CHECKING:
    from ..analyze import AnalysisResult

__all__ = ["diagnose", "DiagnosisResult", "EffectFinding", "BIC_THRESHOLD"]

#: delta BIC above which an effect counts as found (Kass & Raftery: > 10 is very strong evidence)
BIC_THRESHOLD = 10.0
#: sampled-relay windows behind the noise-only period scatter of each test
REFERENCE_WINDOWS = 4
#: a mismatch counts as unexplained below this chi^2 p-value (fitting and held-out cycles of the linear
#: model, and the held-out cycles of the model finally chosen)
UNEXPLAINED_P = 1e-3
#: function evaluations per profile point of a candidate's grid (Td and tau only)
PROFILE_NFEV = 6
#: the linear model counts as rejected (and the candidates are fitted) when some feature is this many
#: standard errors off, or the chi^2 of its fit has a p-value below REJECT_P
REJECT_Z = 3.0
REJECT_P = 0.01
#: held-out confirmation: the candidate must lower the held-out features' chi^2 by at least this much
#: (2 ln of the likelihood ratio on cycles it was not fitted on; the same "very strong" level)
HOLDOUT_THRESHOLD = 10.0
#: a second effect is fitted beside a first that already explains the held-out cycles only when its
#: probe (one Gauss-Newton step from its starts) lowers the fitting cycles' chi^2 by this much
PAIR_PROBE_MIN = 8.0
#: effects after the first (by evidence alone) that are paired too when the first does not explain
#: the held-out cycles
RIVAL_ANCHORS = 2
#: models whose BIC differ by less than this are reported as indistinguishable (Kass & Raftery: "not
#: worth more than a bare mention")
TIE_BIC = 2.0

_FEATURE_TEXT = {
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


# --------------------------------------------------------------------------------------------------
# result types


@dataclass
class EffectFinding:
    """A candidate effect with its fit and evidence (``to_dict`` gives the JSON item)."""

    name: str
    explanation: str
    augmentation: str
    parameters: dict
    evidence: dict
    fit_before: dict
    fit_after: dict
    identification: dict
    harmonics: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "explanation": self.explanation,
            "augmentation": self.augmentation,
            "parameters": self.parameters,
            "evidence": self.evidence,
            "fit_before": self.fit_before,
            "fit_after": self.fit_after,
            "identification": self.identification,
            "harmonics": self.harmonics,
        }


@dataclass
class DiagnosisResult:
    """What :func:`diagnose` found.

    Attributes
    ----------
    path, loop : str
        The log and loop.
    Tp : float
        The propulsion time constant used [s].
    effects : list of EffectFinding
        Effects the evidence supports (empty when the linear model explains the log).
    candidates : list of dict
        Every candidate's evidence and held-out scores (including the rejected ones).
    second_effect_candidates : list of dict
        When an effect was found: every other candidate fitted together with it (``with``), with its
        evidence and held-out scores against that effect's model (a second effect is reported when it
        passes the same rules). When the first effect already explains the held-out cycles, a
        candidate whose probe (``probe_delta_chi2``) is too small is listed with ``delta_bic`` None
        and a ``status``.
    located : list of dict
        Where the base model disagrees with the recording, largest first.
    identification : dict
        The base (linear) fit and, per found effect, the refit that accounts for it; the analysis'
        own identification when one was given.
    tests : list of dict
        Per test: beta (nominal, effective up/down), h, bias, cycles used, times.
    noise_std : float
        Sensor noise estimated from the residual of the cycle projections [output units].
    summary : str
        One sentence.
    unexplained : dict or None
        The mismatch that no candidate (or pair) explains, when the linear model is rejected on the
        fitting and the held-out cycles and the model finally chosen still is on the held-out ones
        (chi^2 p-value below ``UNEXPLAINED_P``): ``what``, ``after`` (the model it remains after),
        ``held_out_feature_chi2`` / ``held_out_features`` / ``p_value``, ``held_out_nrmse_raw``,
        ``tests`` (numbered from 1), ``largest`` (test, feature, z), ``segments`` (times from the log
        start, cycles from 1, worse half-cycle), ``harmonics`` (relative G(jk Omega) errors),
        ``worse_half``, ``best_candidate``. None otherwise; ``effects`` keeps the named findings only.
    t0 : float
        Log start [s] (the first sample of any series); ``*_rel`` times in ``tests`` and ``located``
        are from it, as ``analyze`` shows them (absolute ``t_start``/``t_end`` are log times).
    plot : dict
        What :mod:`mrftcli.report.diagnosis` draws (the tests, models and fits; not JSON).
    """

    path: str
    loop: str
    Tp: float
    effects: list[EffectFinding]
    candidates: list[dict]
    located: list[dict]
    identification: dict
    tests: list[dict]
    noise_std: float
    summary: str
    warnings: list[str] = field(default_factory=list)
    second_effect_candidates: list[dict] = field(default_factory=list)
    unexplained: dict | None = None
    t0: float = 0.0
    plot: dict = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict:
        return {
            "path": self.path,
            "loop": self.loop,
            "Tp": self.Tp,
            "summary": self.summary,
            "effects": [e.to_dict() for e in self.effects],
            "located": self.located,
            "identification": self.identification,
            "candidates": self.candidates,
            "second_effect_candidates": self.second_effect_candidates,
            "unexplained": self.unexplained,
            "t0": self.t0,
            "tests": self.tests,
            "noise_std": self.noise_std,
            "nrmse_definition": (
                "held-out (odd) stable cycles; waveform NRMSE = RMS(recorded - model) / RMS(recorded - its "
                "cycle mean), recorded waveform projected on harmonics 1-7 of each cycle (sensor noise "
                "removed), recorded and model cycles both aligned at the -h -> +h switch and put on the mean "
                "held-out period of the test (phase-normalised: the period is judged by the feature z-scores, "
                "whose standard errors account for the few-cycle sampling error of the mean period); the "
                "cycle-to-cycle scatter of the recording that no deterministic model can predict (residual of a "
                "per-phase linear trend over the held-out cycles of each test, or all its stable cycles when fewer than 3 are held out, dof-corrected; reported as "
                "scatter_nrmse) is subtracted from the mean square error (nrmse_raw keeps it; nrmse_timed also "
                "keeps the model's own period, and is what confirms a candidate, with a held-out feature chi^2 "
                "gain of at least 10); for delay_jitter the nrmse is the relative error of the predicted "
                "cycle-to-cycle period scatter on the held-out cycles, pooled over the tests"
            ),
            "warnings": self.warnings,
        }


# --------------------------------------------------------------------------------------------------
# cycle-to-cycle period scatter (sampled relay with noise, and delay jitter: mrftcli.diagnose.scatter)


def _scatter_reference(tests: list[DiagnosedTest], model: CandidateModel, fit: Fit, noise: float) -> list[dict]:
    """Per test: the sampled-relay setting of a fitted model (the linear one, or with a found effect)
    and the period variance that noise alone explains."""
    p = model.unpack(fit.theta)
    out = []
    for i, t in enumerate(tests):
        plant, gain = model.plant(p, t, float(np.mean(t.tab.t_mid)))
        K = fit.K * gain
        # the model plant is at K = 1: the output scales with K, so a drag per output unit divides by it
        plant = replace(plant, K=K, quadratic_drag=plant.quadratic_drag / K)
        setting = ScatterSetting(plant=plant, beta=t.beta_nominal if t.beta_nominal is not None else float(np.mean(t.beta)),
                                 h=t.h, rate_hz=t.rate_hz, noise_std=noise, n_window=max(t.n_window, len(t.tab)),
                                 period=float(np.mean(t.tab.period)), warm=_limit_cycle_state(plant, t))
        # the noise-only reference: 4 windows (its standard error then adds ~5 % to the comparison's;
        # the jitter's calibration reruns it with the full N_WINDOWS on the same random numbers)
        v0, dof = expected_period_variance(setting, 0.0, n_windows=REFERENCE_WINDOWS)
        if not (np.isfinite(v0) and math.sqrt(v0) < 0.2 * float(np.mean(t.tab.period))):
            v0, dof = float("nan"), 0  # the sampled relay broke down (false switches): no scatter reference
        out.append({"setting": setting, "v0": v0, "s0": math.sqrt(v0) if np.isfinite(v0) else float("nan"), "dof": dof})
    return out


def _limit_cycle_state(plant, test: DiagnosedTest) -> dict | None:
    """The loop state on its continuous-relay limit cycle (a warm start for the sampled relay)."""
    try:
        run = periodic_cycle(plant, test.beta, test.h, test.rate_hz, tol=1e-5)
    except (FloatingPointError, ValueError, OverflowError, ZeroDivisionError):
        return None
    return run.state_at_up[-1] if run is not None and run.state_at_up else None


def _scatter_z(tests: list[DiagnosedTest], scatter: list[dict], sel: str, v_pred) -> np.ndarray:
    """z of log(recorded / predicted period scatter) per test, for the 'fit', 'hold' or all cycles."""
    out = []
    for t, sc, vp in zip(tests, scatter, v_pred):
        v_rec, n = t.scatter_var(sel)
        if not (np.isfinite(vp) and np.isfinite(sc["v0"]) and np.isfinite(v_rec)) or sc["dof"] == 0:
            out.append(0.0)
            continue
        v_floor = (0.5 / t.rate_hz) ** 2 / 3.0  # never compare below the tick quantisation
        se = math.sqrt(1.0 / (2 * (n - 1)) + 1.0 / (2 * sc["dof"]))
        out.append(0.5 * math.log(max(v_rec, v_floor) / max(vp, v_floor)) / se)
    return np.array(out)


# --------------------------------------------------------------------------------------------------
# waveform NRMSE and harmonics


def _model_wave(ev: PredictedCycle, K: float, t_rel: np.ndarray, period: float | None = None) -> np.ndarray:
    """The model cycle at times ``t_rel`` after its -h -> +h switch; with ``period`` [s] it is put on
    that period (phase-normalised) instead of its own."""
    c = ev.cycle
    if period is not None:
        t_rel = t_rel * (c.period[0] / period)
    return K * c.waveform(0, c.start[0] + t_rel, trend=False)


def _waveform_errors(test: DiagnosedTest, mask: np.ndarray, evs: list, K: float, t_refs: np.ndarray | None = None,
                     flight_t: np.ndarray | None = None, phase: bool = False
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per selected cycle: sum of squared error, sum of squares about the mean, and per half (high, low).

    ``phase=True`` puts the model cycle on the same reference period as the recorded ones (the
    held-out NRMSE: a 0.3 % period error, the sampling error of the mean of a few periods, would
    otherwise make 2-3 % of waveform error; the period is judged by the feature z-scores).
    """
    tab = test.tab
    idx = np.flatnonzero(mask)
    sse = np.zeros(idx.size)
    sst = np.zeros(idx.size)
    sse_hi = np.zeros(idx.size)
    sse_lo = np.zeros(idx.size)
    # Each recorded cycle is put on the mean period of the selected cycles (phase-normalised): the
    # cycle-to-cycle timing scatter of a sampled, noisy relay (a tick or two) is not a model error,
    # a systematic period error still is unless ``phase`` (the model cycle keeps its own period).
    P_ref = float(np.mean(tab.period[idx])) if idx.size else 1.0
    for j, i in enumerate(idx):
        P = P_ref
        tt = np.linspace(0.0, P, 200, endpoint=False)
        y_rec = tab.waveform(i, tab.start[i] + tt * tab.period[i] / P_ref)
        Pm = P_ref if phase else None
        if len(evs) == 1:
            y_mod = _model_wave(evs[0], K, tt, Pm)
        else:  # quasi-static models at several times: interpolate linearly in time
            tm = tab.start[i] + 0.5 * P
            w = np.interp(tm, t_refs, np.arange(len(evs)))
            a = int(min(math.floor(w), len(evs) - 2))
            lam = w - a
            y_mod = (1 - lam) * _model_wave(evs[a], K, tt, Pm) + lam * _model_wave(evs[a + 1], K, tt, Pm)
        err = y_rec - y_mod
        sse[j] = float(err @ err) / tt.size
        sst[j] = float(np.var(y_rec))
        hi = tt < tab.high[i] * P_ref / tab.period[i]
        sse_hi[j] = float(np.mean(err[hi] ** 2)) if hi.any() else 0.0
        sse_lo[j] = float(np.mean(err[~hi] ** 2)) if (~hi).any() else 0.0
    return sse, sst, sse_hi, sse_lo


def _harmonic_errors(test: DiagnosedTest, mask: np.ndarray, ev: PredictedCycle, K: float) -> dict:
    """Relative error of the measured G(j k Omega) = Y_k/U_k against the model's, odd k."""
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        G_rec = np.nanmean(test.tab.G[mask], axis=0)
    G_mod = K * ev.cycle.G[0]
    out = {}
    for k in (1, 3, 5, 7):
        if np.isfinite(G_rec[k]) and np.isfinite(G_mod[k]) and abs(G_mod[k]) > 0:
            out[str(k)] = float(abs(G_rec[k] - G_mod[k]) / abs(G_mod[k]))
    return out


# --------------------------------------------------------------------------------------------------
# the diagnosis


def _held_out(model: CandidateModel, fit: Fit, tests: list[DiagnosedTest], recs_hold: list) -> dict:
    """Score a fitted model on the held-out cycles: feature z RMS and waveform NRMSE."""
    zs = []
    sse = sst = floor = sse_timed = 0.0
    per_test = []
    per_test_raw = []
    ia = FEATURE_NAMES.index("log_amplitude")
    gain_times = "gain_drift" in model.names
    for i, (test, (f_rec, s)) in enumerate(zip(tests, recs_hold)):
        ev = model.evaluate(fit.theta, i, f_rec.t_mean, key=1000 + i)
        if ev is None:
            return {"nrmse": None, "feature_rms_z": None}
        fm = ev.features.copy()
        fm[ia] += math.log(fit.K)
        z = ((f_rec.values - fm) / s)[feature_mask(test)]
        zs.append(z)
        if gain_times:
            t_refs = np.array([test.t_start, 0.5 * (test.t_start + test.t_end), test.t_end])
            evs = [model.evaluate(fit.theta, i, tr, key=2000 + 10 * i + j) for j, tr in enumerate(t_refs)]
            if any(e is None for e in evs):
                return {"nrmse": None, "feature_rms_z": None}
        else:
            t_refs, evs = None, [ev]
        e, v, _, _ = _waveform_errors(test, test.hold, evs, fit.K, t_refs, phase=True)
        sse_timed += float(_waveform_errors(test, test.hold, evs, fit.K, t_refs)[0].sum())
        # the cycle-to-cycle scatter of the recording (relay ticks on noisy samples) is the same for
        # every model: it is taken out, so the NRMSE measures the systematic (model) error
        # (estimated over the held-out cycles; a short test's two held-out cycles say nothing about it,
        # so there all of the test's cycles estimate it)
        fl = cycle_scatter(test.tab, test.hold, reference=None if test.hold.sum() >= 3 else np.ones(len(test.tab), bool))
        sse += float(e.sum())
        sst += float(v.sum())
        floor += fl
        per_test.append(math.sqrt(max(e.sum() - fl, 0.0) / v.sum()) if v.sum() > 0 else None)
        per_test_raw.append(math.sqrt(e.sum() / v.sum()) if v.sum() > 0 else None)
    z = np.concatenate(zs)
    return {
        "nrmse": math.sqrt(max(sse - floor, 0.0) / sst) if sst > 0 else None,
        "nrmse_raw": math.sqrt(sse / sst) if sst > 0 else None,
        "nrmse_timed": math.sqrt(sse_timed / sst) if sst > 0 else None,
        "scatter_nrmse": math.sqrt(floor / sst) if sst > 0 else None,
        "nrmse_per_test": per_test,
        "nrmse_raw_per_test": per_test_raw,
        "feature_rms_z": float(np.sqrt(np.mean(z**2))),
        "feature_chi2": float(z @ z),
        "feature_max_abs_z": float(np.max(np.abs(z))) if z.size else 0.0,
        "cycles": int(sum(int(t.hold.sum()) for t in tests)),
    }


def diagnose(
    flight: FlightLog,
    Tp: float,
    analysis: AnalysisResult | None = None,
    progress: Progress | None = None,
    *,
    candidates: tuple[str, ...] | None = None,
) -> DiagnosisResult:
    """Locate model mismatch in an MRFT flight log, name the missing physics, fit it, compare.

    Parameters
    ----------
    flight : FlightLog
        The log's signals (:func:`mrftcli.io.read_flight` reads them).
    Tp : float
        Propulsion time constant [s] (known from a bench test, as for ``analyze``).
    analysis : AnalysisResult, optional
        An analysis of the same flight already computed (its segmentation is reused and its
        identification is reported beside the diagnosis' own fits).
    progress : Progress, optional
        Called as ``progress(done, total, stage)`` before each stage (segmenting, the linear fit,
        each candidate, locating; ``total`` grows when a second effect is tried).
    candidates : tuple of str, optional
        Restrict the candidate library (JSON names); default all.

    Returns
    -------
    DiagnosisResult

    Raises
    ------
    InputError
        Tp missing or not positive, unknown candidate name.
    SegmentationError, LogReadError
        From reading/segmenting the log.
    DiagnoseError
        No test with enough stable cycles, or the base model cannot reproduce any limit cycle.

    Examples
    --------
    A shipped log whose altitude sensor lags by 70 ms (a filter the linear model leaves out); the
    diagnosis takes about 20 s of CPU, so it is not run here, but the refusal of a bad Tp is:

    >>> from pathlib import Path
    >>> import mrftcli
    >>> log = Path(mrftcli.__file__).parents[1] / "sample_logs" / "concealed" / "flight_02.mcap"
    >>> flight = mrftcli.read_flight(log, loop="altitude")
    >>> diagnose(flight, Tp=-0.04)
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: Tp (the bench-measured propulsion time constant) must be a positive time in seconds, got -0.04
    >>> result = diagnose(flight, Tp=0.0422)  # doctest: +SKIP
    >>> [(e.name, round(e.parameters["T_lag"], 3)) for e in result.effects]  # doctest: +SKIP
    [('sensor_lag', 0.07)]
    """
    Tp = check_time("Tp (the bench-measured propulsion time constant)", Tp)
    names = [c.name for c in CANDIDATES] if candidates is None else list(candidates)
    for n in names:
        if n not in BY_NAME:
            raise InputError(f"unknown candidate effect {n!r}; choose from {', '.join(BY_NAME)}")
    stages = [0, 4 + len(names)]  # done, total: segmenting, linear fit, noise scatter, candidates, locating

    def say(stage: str, more: int = 0) -> None:
        stages[1] += more
        report(progress, stages[0], stages[1], stage)
        stages[0] += 1

    say("segmenting")
    screen = analysis
    refused_by_linear = None  # analyze's IdentificationError, when the diagnosis goes on without it
    if screen is None:
        # the tests analyze would use, refused for the same reasons (one beta: exit 6; an output that
        # does not follow the relay: the --loop / --output-topic hint), so the two commands agree on
        # what a log supports; the identification's bootstrap and refinement are not needed here
        from ..analyze import analyze_flight

        with pywarnings.catch_warnings():
            # numpy's all-NaN medians inside analyze's refusal message must not reach the terminal
            pywarnings.simplefilter("ignore", RuntimeWarning)
            try:
                screen = analyze_flight(flight, Tp, n_bootstrap=1, max_combinations=10, refine_waveform=False)
            except IdentificationError as exc:
                # no plant of eq. (2) produces these tests' frequencies: analyze must refuse, but that is
                # the strongest sign of missing physics there is, so the diagnosis fits the cycles itself
                screen, refused_by_linear = None, str(exc)
    segs = segments_of(flight, screen)
    t0_log = log_start(flight)
    tests, noise, warnings = prepare_tests(flight, segs)
    if refused_by_linear is not None:
        warnings.append(f"analyze refuses this log ({refused_by_linear.split(': ', 1)[-1]}); the diagnosis fits the "
                        "recorded cycles with the linear model and each candidate directly")
    if not tests:
        raise DiagnoseError(
            f"{flight.path}: no MRFT test with at least {MIN_CYCLES} stable cycles; the diagnosis compares "
            "cycles, so record longer tests"
        )
    if len({round(np.mean(t.beta), 2) for t in tests}) < 2:
        warnings.append("all tests share one beta: Td and tau are fitted from the waveform shape alone (weakly identified)")

    recs_fit = []
    recs_hold = []
    recs_all = []
    for t in tests:
        for mask, store in ((t.fit, recs_fit), (t.hold, recs_hold), (np.ones(len(t.tab), bool), recs_all)):
            f = summarize_features(t.tab.subset(mask))
            store.append((f, feature_sigma(f.sigma, f.values)))

    # ---- base model
    say("fitting the linear model")
    base_model = CandidateModel(None, tests, Tp)
    lo, hi = theta_bounds(None, tests)
    base = fit_base(base_model, tests, Tp, lo, hi, recs_fit)
    if not base.ok:
        raise DiagnoseError(f"{flight.path}: the linear model reproduces no limit cycle close to the recorded ones")
    n_data = base.n

    # ---- scatter predicted by noise on a sampled relay (base model)
    say("simulating the noise-driven scatter")
    scatter = _scatter_reference(tests, base_model, base, noise)

    def scatter_z(sel: str, v_pred: list[float]) -> np.ndarray:
        return _scatter_z(tests, scatter, sel, v_pred)

    z_sc_base = scatter_z("fit", [sc["v0"] for sc in scatter])
    chi2_base = base.chi2 + float(z_sc_base @ z_sc_base)
    n_all = n_data + len(tests)
    bic_base = chi2_base + base.k * math.log(n_all)

    before = _held_out(base_model, base, tests, recs_hold)
    # is the linear model rejected at all? A candidate needs a chi^2 gain of BIC_THRESHOLD + ln n on
    # the fitting cycles and HOLDOUT_THRESHOLD on the held-out ones; when every feature of both halves
    # is within REJECT_Z standard errors and the chi^2 is what the noise gives, none is fitted
    p_base = float(chi2_dist.sf(base.chi2, max(base.n - base.k, 1)))
    rejected = (p_base < REJECT_P or float(np.max(np.abs(base.resid))) >= REJECT_Z
                or (before.get("feature_max_abs_z") or 0.0) >= REJECT_Z)

    # ---- candidates
    cand_rows = []
    fits: dict[str, tuple[CandidateModel, Fit]] = {}
    deterministic_cands = [c for c in CANDIDATES if c.name in names and not c.stochastic]
    probes: dict[str, float] = {}
    if rejected and deterministic_cands:
        # cheap ordering: each candidate at its starting values with Td and tau corrected by one
        # Gauss-Newton step on the linear model's Jacobian (3 limit cycles per start instead of a fit)
        J_b = _jacobian(base_model, base.theta, recs_fit)
        for cand in deterministic_cands:
            probes[cand.name] = _probe_gain(CandidateModel(cand, tests, Tp),
                                            candidate_starts(cand, base, tests, recs_fit, Tp), base.chi2, J_b,
                                            recs_fit)
        deterministic_cands.sort(key=lambda c: -probes[c.name])
    explained_by = None
    for cand in deterministic_cands:
        say(f"fitting {cand.name}")
        if not rejected:
            cand_rows.append({"name": cand.name, "parameter": cand.parameter, "unit": cand.unit, "delta_bic": None,
                              "status": "not fitted: the linear model is not rejected (every feature within "
                                        f"{REJECT_Z:g} standard errors, chi^2 p = {p_base:.2g})"})
            continue
        if explained_by is not None:
            # a candidate already explains the fitting and the held-out cycles to the noise level: the
            # others (tried in the order of their probes) could only tie with it within the noise
            cand_rows.append({"name": cand.name, "parameter": cand.parameter, "unit": cand.unit, "delta_bic": None,
                              "probe_delta_chi2": probes.get(cand.name),
                              "status": f"not fitted: {explained_by} explains the cycles to the noise level"})
            continue
        model = CandidateModel(cand, tests, Tp)
        lo, hi = theta_bounds(cand, tests)
        best = None
        starts = candidate_starts(cand, base, tests, recs_fit, Tp)
        if len(starts) > 2:
            # profile over the grid: at each grid value fit Td and tau with the effect held (the effect
            # and the delay trade off along a curved valley; the starts are on it already, from the
            # describing function, so a few steps suffice), then refine the best freely, and the
            # second best too when it is close
            prof = []
            free = np.ones(len(starts[0]), bool)
            free[2:] = False
            for th in starts:
                pf = fit_model(model, th, lo, hi, recs_fit, max_nfev=PROFILE_NFEV, free=free)
                if pf.ok and np.isfinite(pf.chi2):
                    prof.append(pf)
            prof.sort(key=lambda f: f.chi2)
            starts = [pf.theta for pf in prof[:2] if pf.chi2 <= 1.5 * prof[0].chi2 + BIC_THRESHOLD]
        for th in starts:
            f = fit_model(model, th, lo, hi, recs_fit)
            if f.ok and (best is None or f.chi2 < best.chi2):
                best = f
        if best is None:
            cand_rows.append({"name": cand.name, "delta_bic": None, "status": "fit failed"})
            continue
        chi2 = best.chi2 + float(z_sc_base @ z_sc_base)
        bic = chi2 + best.k * math.log(n_all)
        after = _held_out(model, best, tests, recs_hold)
        p = model.unpack(best.theta)
        value, std = effect_value(cand, model, best, p)
        fits[cand.name] = (model, best)
        row = {
            "name": cand.name,
            "parameter": cand.parameter,
            "value": value,
            "std": std,
            "unit": cand.unit,
            "chi2": chi2,
            "bic": bic,
            "delta_bic": bic_base - bic,
            "held_out_before": before,
            "held_out_after": after,
            "fit_params": plant_params(model, best),
            "probe_delta_chi2": probes.get(cand.name),
        }
        cand_rows.append(row)
        if (_significant(row) and float(chi2_dist.sf(best.chi2, max(best.n - best.k, 1))) > REJECT_P
                and _explains_held_out(after, tests)):
            explained_by = cand.name
    for cand in CANDIDATES:
        if cand.name in names and cand.stochastic:
            say(f"fitting {cand.name}")  # judged after the deterministic selection, against the model chosen there
    order = {c.name: i for i, c in enumerate(CANDIDATES)}
    cand_rows.sort(key=lambda r: order[r["name"]])  # the library's order in the output, whatever the fitting order

    # ---- selection: strong evidence and confirmed on the held-out cycles
    for row in cand_rows:
        row["significant"] = _significant(row)
    base_params = plant_params(base_model, base)
    deterministic = sorted((r for r in cand_rows if r["significant"] and r["name"] in fits),
                           key=lambda r: -r["delta_bic"])
    effects = []
    pair_rows: list[dict] = []
    final = None  # (label, model, fit) of the deterministic model finally chosen (for the plots)
    if deterministic:
        # forward step: a second effect on top of the first (nested: the pair model with the second
        # effect's parameter at its null value is the first's model), kept on the same evidence and
        # held-out rules. Every other candidate fitted is paired, also one that fitted worse than the
        # linear model alone (quadratic drag beside a rate limit: alone it cannot take the linear drag
        # the slew imitates, with the slew modelled it is found); none once the first explains the
        # held-out cycles to the noise level (docs/benchmarks/diagnose.md, "pair stage").
        first = deterministic[0]
        say(f"testing a second effect on top of {first['name']}", more=1)
        chi2_sc = float(z_sc_base @ z_sc_base)

        def pair(anchor: dict, other: str) -> dict | None:
            pr = _pair_candidate(anchor, other, fits, base, tests, Tp, recs_fit, recs_hold, chi2_sc, n_all)
            if pr is not None:
                pr["significant"] = _significant(pr)
                pair_rows.append(pr)
            return pr

        searched = not _explains_held_out(first["held_out_after"], tests)
        if searched:
            for row in cand_rows:
                if row["name"] != first["name"] and row["name"] in fits:
                    pair(first, row["name"])
        else:
            # the first explains the held-out cycles to the noise level, yet a second effect can still
            # be plain on the fitting cycles (thrust rectification beside an asymmetric gain or a
            # saturation: delta BIC 40-65): every other candidate is probed, and only those whose
            # probe clears PAIR_PROBE_MIN are fitted
            m1, f1 = fits[first["name"]]
            J1 = _jacobian(m1, f1.theta, recs_fit)
            for cand in deterministic_cands:
                if cand.name == first["name"]:
                    continue
                gain = _pair_probe(first, cand, fits, J1, base, tests, recs_fit, Tp)
                if gain is not None and gain >= PAIR_PROBE_MIN:
                    pair(first, cand.name)
                else:
                    pair_rows.append({"name": cand.name, "with": first["name"], "parameter": cand.parameter,
                                      "unit": cand.unit, "values": {}, "delta_bic": None,
                                      "probe_delta_chi2": gain, "significant": False,
                                      "status": f"not fitted: its probe lowers chi^2 by less than {PAIR_PROBE_MIN:g}"})
        good = sorted((pr for pr in pair_rows if pr["significant"]), key=lambda r: -r["delta_bic"])
        second = good[0] if good else None
        rivals = sorted((r for r in cand_rows if r["name"] in fits and r["name"] != first["name"]
                         and (r.get("delta_bic") or -1.0) >= BIC_THRESHOLD), key=lambda r: -r["delta_bic"])
        if searched:
            # the first may be a stand-in for a pair whose members are not it (a sensor lag imitates a
            # slew with quadratic drag; an asymmetric gain stood in for a gain drift beside a
            # saturation), so the next RIVAL_ANCHORS effects by evidence alone are paired too; such a
            # pair replaces the first's only when it also passes the rules against the first alone
            # and has the lower BIC
            tried = {frozenset((pr["with"], pr["name"])) for pr in pair_rows}
            anchor_of_second = first
            for alt in rivals[:RIVAL_ANCHORS]:
                m_alt, f_alt = fits[alt["name"]]
                J_alt = None
                for row in cand_rows:
                    if (row["name"] == alt["name"] or row["name"] not in fits
                            or frozenset((alt["name"], row["name"])) in tried):
                        continue
                    tried.add(frozenset((alt["name"], row["name"])))
                    # only the partners whose probe beside this rival clears PAIR_PROBE_MIN are fitted
                    if J_alt is None:
                        J_alt = _jacobian(m_alt, f_alt.theta, recs_fit)
                    gain = _pair_probe(alt, BY_NAME[row["name"]], fits, J_alt, base, tests, recs_fit, Tp)
                    if gain is None or gain < PAIR_PROBE_MIN:
                        continue
                    pr = pair(alt, row["name"])
                    if pr is None or not pr["significant"]:
                        continue
                    against_first = dict(pr, delta_bic=first["bic"] - pr["bic"],
                                         held_out_before=first["held_out_after"])
                    if _significant(against_first) and (second is None or pr["bic"] < second["bic"]):
                        second, anchor_of_second = pr, alt
            first = anchor_of_second
        if second is not None:
            # swap step: the balance-shifting effects (a trim error, an asymmetric gain, a saturation)
            # stand in for one another, so the first effect found may be the stand-in for the true
            # partner of the second: with the second kept, each other effect significant alone takes
            # the first's place, and the pair with the lowest BIC is kept (it must pass the rules against
            # the second effect alone, as the first pair did against the first)
            anchor = next(r for r in cand_rows if r["name"] == second["name"])
            if anchor.get("significant"):
                for row in deterministic[1:]:
                    if row["name"] == second["name"]:
                        continue
                    pr = pair(anchor, row["name"])
                    if pr is not None and pr["significant"] and pr["bic"] < second["bic"]:
                        first, second = anchor, pr
        m1, f1 = fits[first["name"]]
        final = (first["name"], m1, f1)
        effects.append(_finding(first, {"linear": base_params, "with_effect": first["fit_params"]},
                                _harmonics_before_after(tests, base_model, base, m1, f1),
                                {"compared_with": "linear", "bic_base": bic_base}, n_all))
        if second is not None:
            mp, fp = second["_joint_fit"]
            final = (f"{first['name']} + {second['name']}", mp, fp)
            # with both effects modelled, both parameters come from the joint fit
            for e, name in ((effects[0], first["name"]), (None, second["name"])):
                value, std = effect_value(BY_NAME[name], mp, fp, mp.unpack(fp.theta))
                if e is not None:
                    par = BY_NAME[name].parameter
                    e.parameters[f"{par}_alone"] = e.parameters[par]
                    e.parameters[f"{par}_alone_std"] = e.parameters[f"{par}_std"]
                    e.parameters[par], e.parameters[f"{par}_std"] = value, std
            row2 = dict(second, name=second["name"], value=second["values"][second["name"]],
                        std=second["stds"][second["name"]])
            effects.append(_finding(row2, {"linear": base_params, "with_effect": second["fit_params"],
                                           "model": f"{first['name']}+{second['name']}"},
                                    _harmonics_before_after(tests, m1, f1, mp, fp),
                                    {"compared_with": f"linear + {first['name']}", "bic_base": first["bic"]}, n_all))
        # models the recording cannot rank (BIC within TIE_BIC of the one chosen, and passing the same
        # rules) are named: the choice among them is not the data's
        chosen = {first["name"]} | ({second["name"]} if second is not None else set())
        if second is None:
            rows, ref = [r for r in cand_rows if r.get("significant") and r["name"] in fits], first
            label = lambda r: r["name"]  # noqa: E731
        else:
            rows, ref = [pr for pr in pair_rows if pr.get("significant")], second
            label = lambda r: f"{r['with']}+{r['name']}"  # noqa: E731
        ties = sorted({label(r) for r in rows
                       if abs(r["bic"] - ref["bic"]) < TIE_BIC and set(label(r).split("+")) != chosen})
        if ties:
            for e in effects:
                e.evidence["indistinguishable_from"] = ties
            models = [first["name"] if second is None else f"{first['name']}+{second['name']}", *ties]
            warnings.append(f"{', '.join(models[:-1])} and {models[-1]} fit these tests equally well "
                            f"(BIC within {TIE_BIC:g}): the tests cannot tell them apart; a test at another relay "
                            "height or beta, or longer tests, would")
    stochastic = []
    if "delay_jitter" in names:
        # the scatter noise alone explains depends on the loop: the jitter is judged against the
        # deterministic model found (an actuator slew once made the linear model's noise scatter too
        # small), or the linear one when none was
        z0 = np.clip(scatter_z("all", [sc["v0"] for sc in scatter]), 0.0, None)
        if final is not None and float(z0 @ z0) >= BIC_THRESHOLD + math.log(n_all):
            # (the linear model's noise scatter already explains the recorded one, no need to recompute)
            say(f"testing delay jitter on top of {final[0]}", more=1)
            scatter_j = _scatter_reference(tests, final[1], final[2], noise)
            jrow = _jitter_candidate(BY_NAME["delay_jitter"], tests, scatter_j,
                                     lambda sel, v: _scatter_z(tests, scatter_j, sel, v), final[2], n_all)
            jrow["compared_with"] = f"linear + {final[0]}"
        else:
            jrow = _jitter_candidate(BY_NAME["delay_jitter"], tests, scatter, scatter_z, base, n_all)
        jrow["significant"] = _significant(jrow)
        cand_rows.append(jrow)
        stochastic = [jrow] if jrow["significant"] else []
    for row in stochastic:
        # the jitter acts on the cycle-to-cycle scatter only, which the deterministic effects leave alone
        effects.append(_finding(row, {"linear": base_params, "with_effect": base_params}, {},
                                {"compared_with": row.get("compared_with", "linear"),
                                 "bic_base": row["bic"] + row["delta_bic"]}, n_all))
    for pr in pair_rows:
        pr.pop("_joint_fit", None)  # the fitted model is not JSON

    # ---- locate (base model against all cycles)
    say("locating")
    located, plot = _locate(tests, base_model, base, recs_all, scatter)
    for d in located:
        d["t_start_rel"], d["t_end_rel"] = d["t_start"] - t0_log, d["t_end"] - t0_log
    unexplained = None
    if rejected:
        unexplained = _unexplained(tests, base, before, effects, final, cand_rows, recs_all, scatter, t0_log, located)
    identification = {"linear": {**base_params, "Tp": Tp}}
    for e in effects:
        key = f"with_{e.identification.get('model', e.name)}"
        identification[key] = {**e.identification["with_effect"], "Tp": Tp}
    identification.update(_waveform_refits(flight, screen, effects, warnings))
    if analysis is not None:
        identification["analyze"] = _analysis_params(analysis)
    if effects:
        parts = [
            f"{e.name} ({e.parameters.get(BY_NAME[e.name].parameter):.4g} {BY_NAME[e.name].unit}; delta BIC "
            f"{e.evidence['delta_bic']:.0f} against the {e.evidence['compared_with']} model; held-out NRMSE "
            f"{_fmt(e.fit_before.get('nrmse'))} -> {_fmt(e.fit_after.get('nrmse'))})"
            for e in effects
        ]
        summary = ("found " if len(parts) > 1 else "") + " and ".join(parts) + (
            " explains the mismatch" if len(parts) == 1 else "")
    else:
        summary = "the linear model explains the log: no candidate effect has strong evidence confirmed on held-out cycles"
    if unexplained is not None:
        lg = unexplained.get("largest")
        where = f" (largest: test {lg['test']}, {lg['what']}, z = {lg['z']:+.1f})" if lg else ""
        if effects:
            summary += "; unexplained: " + unexplained["what"] + where
        else:
            summary = "unexplained: " + unexplained["what"] + where
    test_rows = [
        {
            "index": t.index,
            "beta_nominal": t.beta_nominal,
            "beta_effective_up": t.beta[0],
            "beta_effective_down": t.beta[1],
            "h": t.h,
            "bias": t.bias,
            "rate_hz": t.rate_hz,
            "t_start": t.t_start,
            "t_end": t.t_end,
            "t_start_rel": t.t_start - t0_log,
            "t_end_rel": t.t_end - t0_log,
            "cycles": len(t.tab),
            "stable_cycles_found": next((int(sum(c.stable for c in g.cycles)) for g in segs if g.index == t.index), None),
            "cycles_fit": int(t.fit.sum()),
            "cycles_held_out": int(t.hold.sum()),
            "period_scatter": math.sqrt(t.scatter_var("all")[0]) if t.scatter_var("all")[1] >= 3 else None,
            "period_scatter_noise_model": sc["s0"],
        }
        for t, sc in zip(tests, scatter)
    ]
    plot.update({"tests": tests, "base_model": base_model, "base": base, "fits": fits, "flight": flight,
                 "effects": [e.name for e in effects], "final": final})
    report(progress, stages[1], stages[1], "done")
    return DiagnosisResult(
        path=str(flight.path),
        loop=flight.loop,
        Tp=float(Tp),
        effects=effects,
        candidates=cand_rows,
        located=located,
        identification=identification,
        tests=test_rows,
        noise_std=noise,
        summary=summary,
        warnings=warnings,
        second_effect_candidates=pair_rows,
        unexplained=unexplained,
        t0=t0_log,
        plot=plot,
    )


def _fmt(x) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def _fit_summary(h: dict) -> dict:
    return {k: h.get(k) for k in ("nrmse", "nrmse_raw", "nrmse_timed", "scatter_nrmse", "feature_rms_z", "feature_chi2",
                                  "cycles",
                                  "nrmse_per_test",
                                  "metric") if k in h}


def _held_out_p(held: dict, tests: list[DiagnosedTest]) -> float:
    """p-value of a model's held-out feature chi^2 (one degree of freedom per held-out feature)."""
    chi2 = held.get("feature_chi2")
    if chi2 is None:
        return float("nan")
    return float(chi2_dist.sf(chi2, sum(int(feature_mask(t).sum()) for t in tests)))


def _unexplained(tests, base, before, effects, final, cand_rows, recs_all, scatter, t0_log,
                 base_located: list) -> dict | None:
    """The mismatch no candidate (or pair) explains: where and how large, or None.

    Reported when the linear model is rejected on the fitting cycles *and* on the held-out ones
    (chi^2 p-value below :data:`UNEXPLAINED_P` on both), and the model finally chosen (the linear one
    when nothing was found) is still rejected on the held-out cycles at that level.
    """
    dof_fit = max(base.n - base.k, 1)
    p_fit = float(chi2_dist.sf(base.chi2, dof_fit))
    p_hold = _held_out_p(before, tests)
    if not (p_fit < UNEXPLAINED_P and p_hold < UNEXPLAINED_P):
        return None
    det = [e for e in effects if e.name != "delay_jitter"]
    held = det[-1].fit_after if det else before
    p_final = _held_out_p(held, tests)
    if not p_final < UNEXPLAINED_P:
        return None
    model_name = "linear" if final is None else f"linear + {final[0]}"
    # where: the base model's disagreements, or the chosen model's when an effect was modelled
    located = base_located if final is None else _locate(tests, final[1], final[2], recs_all, scatter)[0]
    feats = [d for d in located if d["kind"] == "feature"]
    segs = [d for d in located if d["kind"] == "segment"]
    harms = [d for d in located if d["kind"] == "harmonic"]
    worst = feats[0] if feats else None
    tested = sorted((r for r in cand_rows if r.get("delta_bic") is not None), key=lambda r: -r["delta_bic"])
    where_tests = sorted({d["test"] + 1 for d in feats})
    out = {
        "after": model_name,
        "what": ("the linear model is rejected, and no candidate effect (or pair) of the library explains the "
                 "mismatch" if final is None else
                 f"the model with {final[0]} still leaves a mismatch beyond the noise on the held-out cycles"),
        "held_out_feature_chi2": held.get("feature_chi2"),
        "held_out_features": sum(int(feature_mask(t).sum()) for t in tests),
        "p_value": p_final,
        "held_out_nrmse_raw": held.get("nrmse_raw"),
        "tests": where_tests,
        "largest": None if worst is None else {
            "test": worst["test"] + 1, "feature": worst["feature"], "what": worst["what"], "z": worst["z"],
            "recorded": worst["recorded"], "model": worst["model"]},
        "segments": [{"test": d["test"] + 1, "t_start_rel": d["t_start"] - t0_log, "t_end_rel": d["t_end"] - t0_log,
                      "cycles": [c + 1 for c in d["cycles"]], "nrmse": d["nrmse"], "worse_half": d["worse_half"]}
                     for d in segs[:5]],
        "harmonics": [{"test": d["test"] + 1, "harmonic": d["harmonic"], "relative_error": d["relative_error"]}
                      for d in harms[:5]],
        "best_candidate": None if not tested else {"name": tested[0]["name"], "delta_bic": tested[0]["delta_bic"],
                                                   "significant": bool(tested[0].get("significant"))},
    }
    half = None
    if segs:
        halves = [d["worse_half"] for d in segs]
        half = max(set(halves), key=halves.count)
    out["worse_half"] = half
    return out


def _jacobian(model: CandidateModel, theta: np.ndarray, recs: list, step: float = 1e-3) -> np.ndarray:
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


def _probe_gain(model: CandidateModel, starts: list[np.ndarray], chi2_ref: float, J: np.ndarray,
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


def _pair_probe(first: dict, cand: Candidate, fits: dict, J1: np.ndarray, base: Fit, tests: list[DiagnosedTest],
                recs_fit: list, Tp: float) -> float | None:
    """:func:`_probe_gain` of the pair (the first effect fitted, ``cand`` added) against the first
    alone (its Jacobian ``J1``), from the pair's starts other than the nested null one; None when the
    two cannot be paired."""
    c1 = BY_NAME[first["name"]]
    if c1.replaces_drag and cand.replaces_drag:
        return None
    model = CandidateModel((c1, cand), tests, Tp)
    lo, hi = theta_bounds((c1, cand), tests)
    starts = _pair_starts(model, lo, c1, cand, fits, base, tests, recs_fit, Tp, hi)
    if model.extra_index(cand.name) is not None:
        starts = starts[1:]  # the null start is the first alone: no gain
    return _probe_gain(model, [np.clip(th, lo + 1e-9, hi - 1e-9) for th in starts], fits[c1.name][1].chi2, J1,
                       recs_fit)


def _explains_held_out(held: dict, tests: list[DiagnosedTest]) -> bool:
    """True when a model's held-out feature chi^2 is what the noise explains (p > 0.01 against
    chi^2 with one degree of freedom per held-out feature): a second effect would then be fitting
    noise, so the pair stage stops there."""
    chi2 = held.get("feature_chi2")
    if chi2 is None:
        return False
    dof = sum(int(feature_mask(t).sum()) for t in tests)
    return float(chi2_dist.sf(chi2, dof)) > 0.01


def _significant(row: dict) -> bool:
    db = row.get("delta_bic")
    if db is None or not np.isfinite(db) or db < BIC_THRESHOLD:
        return False
    b, a = row.get("held_out_before") or {}, row.get("held_out_after") or {}
    if b.get("nrmse") is None or a.get("nrmse") is None:
        return False
    if row["name"] == "delay_jitter":
        # a jitter below half a controller tick cannot be told from the tick quantisation itself
        return a["nrmse"] < b["nrmse"] and row.get("value", 0.0) >= row.get("min_value", 0.0)
    # confirmation on the held-out cycles: the whole waveform error as timed (the model cycle on its own
    # period, so the period counts; the recording's scatter is common to both sides) must fall, and the
    # features must be explained better by a clear margin (a small gain on noisy cycles is not a
    # confirmation: a 13 ms delay jitter once made a trim error pass with a held-out chi^2 gain of 7)
    key = "nrmse_timed" if a.get("nrmse_timed") is not None and b.get("nrmse_timed") is not None else "nrmse"
    if b.get("feature_chi2") is not None and a.get("feature_chi2") is not None:
        features_ok = b["feature_chi2"] - a["feature_chi2"] >= HOLDOUT_THRESHOLD
    else:
        features_ok = (a.get("feature_rms_z") or 0) < (b.get("feature_rms_z") or 0)
    return a[key] < b[key] and features_ok


def _jitter_candidate(cand, tests, scatter, scatter_z, base, n_all) -> dict:
    """Fit the delay-jitter std to the recorded period scatter (:func:`mrftcli.diagnose.scatter.fit_jitter`)."""
    v0 = np.array([sc["v0"] for sc in scatter])
    if not np.isfinite(v0).any():
        return {"name": cand.name, "delta_bic": None, "status": "no scatter reference (the sampled relay broke down)"}

    z_all = np.clip(scatter_z("all", list(v0)), 0.0, None)
    if float(z_all @ z_all) < BIC_THRESHOLD + math.log(n_all):
        # a jitter only raises the predicted scatter, so its chi^2 gain is at most the sum of the
        # positive z^2: below the threshold its calibration runs (most of a diagnosis' cost) are skipped
        return {"name": cand.name, "delta_bic": None, "parameter": cand.parameter, "unit": cand.unit,
                "status": "period scatter within what sensor noise explains (no jitter could reach the evidence threshold)"}

    # the calibration runs below use N_WINDOWS windows: the noise-only variance is recomputed on the
    # same random numbers, so that the calibrated slope is not biased by the reference's sampling
    scatter = [dict(sc, v0=expected_period_variance(sc["setting"], 0.0)[0]) if np.isfinite(sc["v0"]) else sc
               for sc in scatter]
    v0 = np.array([sc["v0"] for sc in scatter])

    def calibrate(sigma: float) -> np.ndarray:
        return np.array([expected_period_variance(sc["setting"], sigma)[0] if np.isfinite(sc["v0"]) else np.nan
                         for sc in scatter])

    v_all, n_all_c = (np.array(x) for x in zip(*(t.scatter_var("all") for t in tests)))
    v_fit, n_fit = (np.array(x) for x in zip(*(t.scatter_var("fit") for t in tests)))
    v_hold, n_hold = (np.array(x) for x in zip(*(t.scatter_var("hold") for t in tests)))
    # the reported value uses every cycle of the scatter sample (calibrated at that value); the
    # evidence and the held-out scores use the fit from the even cycles only
    jf = fit_jitter(v_all, n_all_c, v0, calibrate)
    sigma_fit = refit_sigma(jf, v_fit, n_fit)
    v_pred = jf.predicted_var(sigma_fit)
    z = scatter_z("fit", list(v_pred))
    chi2 = base.chi2 + float(z @ z)
    bic = chi2 + (base.k + 1) * math.log(n_all)
    z_base = scatter_z("fit", list(v0))
    bic_b = base.chi2 + float(z_base @ z_base) + base.k * math.log(n_all)
    zh_b = scatter_z("hold", list(v0))
    zh_a = scatter_z("hold", list(v_pred))
    # standard error of sigma: var(log s^2) = 2/(n - 1) per test, pooled; d log v / d log sigma = 2 c^2 s^2 / v
    ok = np.isfinite(v0) & np.isfinite(v_all) & (n_all_c > 1)
    if jf.sigma > 0 and ok.any():
        vp = jf.predicted_var()[ok]
        g = 2.0 * jf.slope[ok] * jf.sigma**2 / vp
        info = float(np.sum((n_all_c[ok] - 1) / 2.0 * g * g))
        s_std = jf.sigma / math.sqrt(info) if info > 0 else float("nan")
    else:
        s_std = float("nan")
    metric = "pooled relative error of the held-out cycle-to-cycle period scatter, |s_rec - s_model| / s_rec"
    cycles = int(n_hold.sum())
    return {
        "min_value": 0.5 / min(t.rate_hz for t in tests),
        "name": cand.name,
        "parameter": cand.parameter,
        "value": jf.sigma,
        "value_fit_cycles": sigma_fit,
        "std": s_std,
        "unit": cand.unit,
        "chi2": chi2,
        "bic": bic,
        "delta_bic": bic_b - bic,
        "held_out_before": {"nrmse": pooled_scatter_error(v_hold, n_hold, v0),
                            "feature_rms_z": float(np.sqrt(np.mean(zh_b**2))), "metric": metric, "cycles": cycles},
        "held_out_after": {"nrmse": pooled_scatter_error(v_hold, n_hold, v_pred),
                           "feature_rms_z": float(np.sqrt(np.mean(zh_a**2))), "metric": metric, "cycles": cycles},
        "fit_params": None,
        "calibration_runs": jf.iterations,
        "period_scatter": {"recorded": [math.sqrt(v) if np.isfinite(v) else None for v in v_all],
                           "noise_only": [math.sqrt(v) if np.isfinite(v) else None for v in v0],
                           "with_jitter": [math.sqrt(v) if np.isfinite(v) else None for v in jf.predicted_var()]},
    }


def _finding(row: dict, ident: dict, harm: dict, evidence: dict, n_all: int) -> EffectFinding:
    cand = BY_NAME[row["name"]]
    return EffectFinding(
        name=cand.name,
        explanation=cand.explanation,
        augmentation=cand.augmentation,
        parameters={cand.parameter: row["value"], f"{cand.parameter}_std": row["std"], "unit": cand.unit,
                    **(row.get("fit_params") or {})},
        evidence={"delta_bic": row["delta_bic"], "bic": row["bic"], "n_features": n_all, "threshold": BIC_THRESHOLD,
                  **evidence},
        fit_before=_fit_summary(row["held_out_before"]),
        fit_after=_fit_summary(row["held_out_after"]),
        identification={k: v for k, v in ident.items() if v is not None},
        harmonics=harm,
    )


#: the value of each candidate's scaled parameter at which its model is the linear one (the nested
#: start of a pair fit); saturation's is its upper bound, the others' their lower bound when not listed
_NULL = {"input_bias": 0.0, "gain_drift": 0.0, "asymmetric_gain": 0.0}
#: the profiled candidates, whose starts carry their own Td and tau (they trade off against the delay)
_PROFILED = ("sensor_lag", "actuator_rate_limit")


def _pair_starts(model: CandidateModel, lo: np.ndarray, c1: Candidate, c2: Candidate, fits: dict, base: Fit,
                 tests: list[DiagnosedTest], recs_fit: list, Tp: float, hi: np.ndarray) -> list[np.ndarray]:
    """Starts of the pair (c1 fitted already, c2 added): c1's fit with c2 at its null value (the
    nested model: the pair can only do better than c1 alone), at each of c2's own starts (their Td and
    tau moved from c1's fit by what c2's start moved them from the linear fit), and, when c2 was
    fitted alone, its single fit's value."""
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
    for s2 in candidate_starts(c2, base, tests, recs_fit, Tp):
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


def _pair_candidate(first: dict, other: str, fits: dict, base: Fit, tests: list[DiagnosedTest], Tp: float,
                    recs_fit: list, recs_hold: list, chi2_scatter: float, n_all: int) -> dict | None:
    """Fit the first effect (its row ``first``, fitted alone already) and ``other`` together; evidence
    and held-out scores against the first alone.

    The starts (:func:`_pair_starts`) are scored first (one limit cycle each) and the fit runs from
    the best ones, so the pair never ends worse than the first alone (before, pair fits started only
    from the two single fits and some ended at delta BIC -1e4 to -1e6). ``delta_bic`` =
    BIC(first) - BIC(pair): the pair has one parameter more.
    """
    c1, c2 = BY_NAME[first["name"]], BY_NAME[other]
    if c1.replaces_drag and c2.replaces_drag:
        return None
    model = CandidateModel((c1, c2), tests, Tp)
    lo, hi = theta_bounds((c1, c2), tests)
    scored = []
    j2 = model.extra_index(c2.name)
    for i, th in enumerate(_pair_starts(model, lo, c1, c2, fits, base, tests, recs_fit, Tp, hi)):
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
        return None
    scored.sort(key=lambda x: x[0])
    best = None
    for chi2_start, th in scored[:2]:
        if best is not None and chi2_start > 1.5 * scored[0][0] + BIC_THRESHOLD:
            break
        f = fit_model(model, th, lo, hi, recs_fit)
        if f.ok and (best is None or f.chi2 < best.chi2):
            best = f
    if best is None:
        return None
    chi2 = best.chi2 + chi2_scatter
    bic = chi2 + best.k * math.log(n_all)
    p = model.unpack(best.theta)
    values, stds = {}, {}
    for c in (c1, c2):
        values[c.name], stds[c.name] = effect_value(c, model, best, p)
    return {
        "name": c2.name,
        "with": c1.name,
        "parameter": c2.parameter,
        "values": values,
        "stds": stds,
        "unit": c2.unit,
        "chi2": chi2,
        "bic": bic,
        "delta_bic": first["bic"] - bic,
        "held_out_before": first["held_out_after"],
        "held_out_after": _held_out(model, best, tests, recs_hold),
        "fit_params": plant_params(model, best),
        "_joint_fit": (model, best),
    }


def _harmonics_before_after(tests, base_model, base, model, fit) -> dict:
    out = {}
    for i, t in enumerate(tests):
        ev_b = base_model.evaluate(base.theta, i, t.tab.t_mid[t.hold].mean(), key=3000 + i)
        ev_a = model.evaluate(fit.theta, i, t.tab.t_mid[t.hold].mean(), key=3000 + i)
        if ev_b is None or ev_a is None:
            continue
        out[str(t.index)] = {
            "before": _harmonic_errors(t, t.hold, ev_b, base.K),
            "after": _harmonic_errors(t, t.hold, ev_a, fit.K),
        }
    return out


def _waveform_refits(flight: FlightLog, analysis: AnalysisResult, effects: list, warnings: list) -> dict:
    """The output-error refit of issue 16 with each found effect it can model (a sensor lag, an input bias).

    The same problem as :func:`mrftcli.mrft.refine.refine` with one more parameter, fitted on the
    recorded waveform of the analysis' test windows: the effect's parameter and Td, tau, K with it
    accounted for, beside the cycle-feature fit's (``identification["waveform_with_<effect>"]``).
    Skipped for a command logged below the controller's rate (the waveform is not known there).
    """
    from ..mrft.refine import EFFECTS, refinement_windows, refit_with_effect

    names = [e.name for e in effects if e.name in EFFECTS]
    tests = analysis.tests if analysis is not None else ()
    if not names or not tests or any(t.controller_rate_hz is not None for t in tests):
        return {}
    windows = refinement_windows(tests, flight.command.t, flight.command.values, flight.output.t,
                                 flight.output.values)
    out = {}
    for name in names:
        try:
            r = refit_with_effect(windows, analysis.model, name, loop_sign=tests[0].loop_sign)
        except MrftError as err:
            warnings.append(f"the waveform refit with {name} failed ({err}); the cycle-feature fit stands")
            continue
        out[f"waveform_with_{name}"] = {"Td": r.model.Td, "tau": r.model.tau, "K": r.model.K, "Tp": r.model.Tp,
                                        "value": r.value, "value_std": r.value_std,
                                        "residual_rms": r.fit.residual_rms}
    return out


def _analysis_params(analysis: AnalysisResult) -> dict:
    """Td, tau [s] and K (the point estimates) of an analysis, the finite ones."""
    means = {"Td": analysis.Td.mean, "tau": analysis.tau.mean, "K": analysis.K.mean}
    return {k: float(v) for k, v in means.items() if v is not None and math.isfinite(float(v))}


def _locate(tests, base_model, base, recs_all, scatter) -> tuple[list, dict]:
    """Where the base model and the recording disagree: features, cycles/halves, harmonics."""
    located = []
    ia = FEATURE_NAMES.index("log_amplitude")
    plot = {"cycle_errors": [], "harmonics": []}
    errs_all = []
    for i, (t, (f, s)) in enumerate(zip(tests, recs_all)):
        ev = base_model.evaluate(base.theta, i, f.t_mean, key=4000 + i)
        if ev is None:
            continue
        fm = ev.features.copy()
        fm[ia] += math.log(base.K)
        z = (f.values - fm) / s
        for j, name in enumerate(FEATURE_NAMES):
            if not feature_mask(t)[j] or abs(z[j]) < 3.0:
                continue
            rec, mod = float(f.values[j]), float(fm[j])
            item = {
                "kind": "feature",
                "test": t.index,
                "beta": float(np.mean(t.beta)),
                "h": t.h,
                "t_start": t.t_start,
                "t_end": t.t_end,
                "feature": name,
                "what": _FEATURE_TEXT[name],
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
                a_rec = math.exp(float(f.values[ia]))
                item.update(recorded=rec * a_rec, model=mod * math.exp(float(fm[ia])),
                            difference=rec * a_rec - mod * math.exp(float(fm[ia])), unit="output units")
            if name in ("amplitude_trend", "balance_trend"):
                item["unit"] = "relative change per second" if name == "amplitude_trend" else "per second"
            if name == "balance":
                P = float(f.values[0])
                item["half_periods_recorded"] = {"high": P * (0.5 + rec), "low": P * (0.5 - rec)}
                item["half_periods_model"] = {"high": P * (0.5 + mod), "low": P * (0.5 - mod)}
            located.append(item)
        # period scatter
        sc = scatter[i]
        zs = float(_scatter_z([t], [sc], "all", [sc["v0"]])[0])
        if abs(zs) >= 3.0:
            s_rec = math.sqrt(t.scatter_var("all")[0])
            located.append({"kind": "feature", "test": t.index, "beta": float(np.mean(t.beta)), "h": t.h,
                            "t_start": t.t_start, "t_end": t.t_end, "feature": "period_scatter",
                            "what": _FEATURE_TEXT["period_scatter"], "recorded": s_rec, "model": sc["s0"],
                            "difference": s_rec - sc["s0"], "z": zs})
        # per cycle and half-cycle waveform errors
        allm = np.ones(len(t.tab), bool)
        e, v, e_hi, e_lo = _waveform_errors(t, allm, [ev], base.K)
        cyc_nrmse = np.sqrt(e / np.where(v > 0, v, np.nan))
        errs_all.append(cyc_nrmse)
        plot["cycle_errors"].append({"t": t.tab.t_mid, "nrmse": cyc_nrmse, "hi": np.sqrt(e_hi / v), "lo": np.sqrt(e_lo / v),
                                     "start": t.tab.start, "end": t.tab.end})
        harm = _harmonic_errors(t, allm, ev, base.K)
        plot["harmonics"].append(harm)
        # only the fundamental and the 3rd harmonic are well above the noise at realistic amplitudes
        strong = {k: v for k, v in harm.items() if k in ("1", "3")}
        if strong:
            kmax = max(strong, key=lambda k: strong[k])
            if strong[kmax] > 0.05:
                located.append({"kind": "harmonic", "test": t.index, "beta": float(np.mean(t.beta)), "h": t.h,
                                "t_start": t.t_start, "t_end": t.t_end, "harmonic": int(kmax),
                                "what": f"G(j{kmax}Omega) measured from harmonic {kmax} of output/command",
                                "relative_error": harm[kmax], "all": harm})
    # time segments: runs of cycles whose waveform error stands out from the log's typical cycle
    # (only when some feature disagrees beyond the noise at all: otherwise they would flag noise)
    mismatch = any(d["kind"] == "feature" for d in located)
    if not mismatch:
        located = []
    if errs_all and mismatch:
        pooled = np.concatenate(errs_all)
        med = float(np.nanmedian(pooled))
        for t, ce in zip(tests, plot["cycle_errors"]):
            bad = ce["nrmse"] > max(1.5 * med, 0.02)
            if not bad.any():
                continue
            idx = np.flatnonzero(bad)
            runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
            for rr in runs:
                hi_err = float(np.nanmean(ce["hi"][rr]))
                lo_err = float(np.nanmean(ce["lo"][rr]))
                located.append({
                    "kind": "segment", "test": t.index, "beta": float(np.mean(t.beta)), "h": t.h,
                    "t_start": float(ce["start"][rr[0]]), "t_end": float(ce["end"][rr[-1]]),
                    "cycles": [int(x) for x in rr],
                    "nrmse": float(np.nanmean(ce["nrmse"][rr])),
                    "typical_nrmse": med,
                    "worse_half": "high (+h)" if hi_err > lo_err else "low (-h)",
                    "half_nrmse": {"high": hi_err, "low": lo_err},
                })
    located.sort(key=lambda d: -abs(d.get("z", 0.0)) if d["kind"] == "feature" else (0 if d["kind"] == "harmonic" else 1))
    return located, plot
