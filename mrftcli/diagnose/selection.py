"""Diagnose where the identified linear model and a flight log disagree, and which physics explains it.

:func:`diagnose` is a short driver over the stages below, each a function returning a frozen record:
:func:`~mrftcli.diagnose.screen.screen_log` (:class:`~mrftcli.diagnose.screen.Screen`),
:func:`~mrftcli.diagnose.candidates.fit_linear` (:class:`~mrftcli.diagnose.candidates.LinearFit`),
:func:`~mrftcli.diagnose.candidates.search_candidates` (:class:`~mrftcli.diagnose.candidates.CandidateSearch`),
:func:`~mrftcli.diagnose.pairs.select_effects` (:class:`~mrftcli.diagnose.pairs.EffectSelection`),
:func:`judge_jitter`, :func:`~mrftcli.diagnose.locate.locate` (:class:`~mrftcli.diagnose.locate.Located`)
and the summary; the result is :class:`~mrftcli.diagnose.records.DiagnosisResult`.

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
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Sequence

import numpy as np

from ..analyze.general import general_analysis, measure_tests
from ..analyze.options import RelayOptions
from ..errors import InputError, MrftError
from ..io.logtypes import FlightLog, Signal
from ..mrft.model import LoopModel, PlantModel
from ..progress import Progress, report
from .candidates import LinearFit, fit_linear, search_candidates
from .fit import plant_params
from .starts import bound_reason
from .heldout import significant
from .scatter import jitter_candidate, scatter_reference, scatter_z
from .locate import (Z_LIMIT, check_test, locate, measured_waveform, misfit, test_disagreements,
                     unexplained_mismatch, verdict)
from .pairs import effect_finding, select_effects
from .physics import BIC_THRESHOLD, BY_NAME, CANDIDATES, as_test_data, select as select_effects_on, unit_in_loop
from .resonance import resonance_mismatch
from .records import (CandidateFit, DiagnosisFigures, DiagnosisResult, Disagreement, EffectFinding, EffectIdentification,
                      FinalModel, Identification, ModelEstimate, TestRow, Unexplained, analyze_model)
from .screen import Screen, screen_log, trim_spread

if TYPE_CHECKING:
    from ..analyze import AnalysisResult

__all__ = ["diagnose", "judge_jitter", "deterministic", "DiagnosisResult", "EffectFinding",
           "BIC_THRESHOLD"]


#: how :func:`lead_assumption` begins (shown in diagnose's first lines)
DIAGNOSE_LEAD_WORDS = "assumed: diagnose's models take tau >= 0"


def lead_assumption(analysis: AnalysisResult | None) -> list[str]:
    """The assumption a lead analysis (tau < 0, an estimator's lead analyze admits) puts on diagnose's figures:
    its linear fit and the effects' cycles hold delays only, so its tau sits at 0 and its Td moves to the nearest
    causal loop (review finding 2: said, not fitted)."""
    tau = analysis.parameters.get("tau") if analysis is not None else None
    if tau is None or not tau.value < 0:
        return []
    return [f"{DIAGNOSE_LEAD_WORDS}; analyze found a lead of {-tau.value * 1e3:.3g} ms (tau {tau.value * 1e3:.3g} ms), "
            "so diagnose's linear model is the nearest causal loop (its tau near 0, its Td off analyze's), and an "
            "effect named may stand for the lead: read analyze's model for the loop"]


def _trim_note(screen: Screen) -> list[str]:
    """The assumption the features' standard errors carry when the tests' relay centres differ (issue 39)."""
    spread = trim_spread(list(screen.flown))
    if spread <= 0.0:
        return []
    return [f"the tests' relay centres differ (std {spread:.3g} command units: the hold's trim moved between "
            "tests), so each test's centre is taken as off the vehicle's trim by about that much: offsets that "
            "differ between tests are not named as an effect, one shared by every test is (input_bias)"]


class _Stages:
    """The progress of a diagnosis: ``progress(done, total, stage)`` before each stage; ``total``
    grows when a stage adds one (a second effect, the jitter on top of an effect)."""

    def __init__(self, progress: Progress | None, total: int) -> None:
        self.progress, self.done, self.total = progress, 0, total

    def __call__(self, stage: str, more: int = 0) -> None:
        self.total += more
        report(self.progress, self.done, self.total, stage)
        self.done += 1

    def finish(self) -> None:
        report(self.progress, self.total, self.total, "done")


@dataclass(frozen=True)
class JitterJudgement:
    """The delay-jitter candidate (:func:`judge_jitter`): its row and, when significant, its finding."""

    row: CandidateFit
    finding: EffectFinding | None


def judge_jitter(screen: Screen, linear: LinearFit, final: FinalModel | None, say: _Stages) -> JitterJudgement:
    """Stage 5: the delay jitter, judged on the cycle-to-cycle period scatter alone.

    The scatter noise alone explains depends on the loop: the jitter is judged against the
    deterministic model found (an actuator slew once made the linear model's noise scatter too
    small), or the linear one when none was (or when the linear model's noise scatter already
    explains the recorded one: no need to recompute).
    """
    tests, n_all = screen.tests, linear.n_all
    cand = BY_NAME["delay_jitter"]
    z0 = np.clip(scatter_z(tests, linear.scatter, "all", [sc["v0"] for sc in linear.scatter]), 0.0, None)
    if final is not None and float(z0 @ z0) >= BIC_THRESHOLD + math.log(n_all):
        say(f"testing delay jitter on top of {final.label}", more=1)
        scatter_j = scatter_reference(tests, final.model, final.fit, screen.noise)
        row = jitter_candidate(cand, tests, scatter_j, lambda sel, v: scatter_z(tests, scatter_j, sel, v), final.fit,
                               n_all)
        row = replace(row, compared_with=f"linear + {final.label}")
    else:
        row = jitter_candidate(cand, tests, linear.scatter, lambda sel, v: scatter_z(tests, linear.scatter, sel, v),
                               linear.fit, n_all)
    row = replace(row, significant=significant(row))
    if not row.significant or row.bic is None or row.delta_bic is None:
        return JitterJudgement(row, None)
    # the jitter acts on the cycle-to-cycle scatter only, which the deterministic effects leave alone
    base_params = plant_params(linear.model, linear.fit)
    finding = effect_finding(row, EffectIdentification.of(base_params, base_params), {},
                             row.compared_with or "linear", row.bic + row.delta_bic, n_all)
    return JitterJudgement(row, finding)


def diagnose(
    flight: FlightLog,
    model: PlantModel,
    analysis: AnalysisResult | None = None,
    progress: Progress | None = None,
    *,
    candidates: tuple[str, ...] | None = None,
    relay: RelayOptions = RelayOptions(),
    windows: Sequence[tuple[float, float]] = (),
    min_stable_cycles: int = 3,
    baseline: tuple[float | Signal, float] | None = None,
    refusal: MrftError | None = None,
) -> DiagnosisResult:
    """Locate model mismatch in a relay-test log, name the missing physics, fit it, compare.

    One driver for every family; the family chooses the strategy. Eq. (2) (a
    :class:`~mrftcli.mrft.model.LoopModel`, ``soiptd_model(Tp)``: Tp read from the model) compares
    the cycles feature by feature with eq. (2)'s periodic solutions (the stages of the module
    docstring); every other family (``fopdt``, ``sopdt``, ``ipdt``, ``foipdt``, a declared model) is
    checked test by test (:mod:`.locate`) and runs the library of physics on the model object
    (:mod:`.physics`). Both return the one :class:`DiagnosisResult` (its ``family`` says which parts
    are filled).

    Parameters
    ----------
    flight : FlightLog
        The log's signals (:func:`mrftcli.io.read_flight` reads them).
    model : PlantModel
        The model to diagnose against, with its known parameters (set E) and ranges (set I).
    analysis : AnalysisResult, optional
        An analysis of the same flight already computed. Eq. (2): its segmentation is reused and its
        identification is reported beside the diagnosis' own fits; the other families: ``analyze
        --model``'s record made with the same ``relay``, ``windows``, ``min_stable_cycles`` and
        ``baseline``, used instead of identifying again.
    progress : Progress, optional
        Called as ``progress(done, total, stage)`` before each stage.
    candidates : tuple of str, optional
        Eq. (2): restrict the candidate library (JSON names); default all.
    relay, windows, min_stable_cycles, baseline
        The other families: what is stated about the relay, the parts of the log to use [s, log
        clock], the fewest stable cycles of a test, the operating point (``AnalyzeOptions.baseline``:
        the same analysis as ``analyze --model`` with those options).
    refusal : MrftError, optional
        Eq. (2): analyze's refusal of this log when the caller ran analyze and it refused (``analysis``
        None): analyze is not run again; the diagnosis goes on where analyze's refusal is the evidence
        of missing physics (no plant of eq. (2) fits, or one beta left of tests flown at two betas or two
        relay heights), else ``refusal`` is raised (analyze's message and exit code).

    Raises
    ------
    InputError
        An unknown candidate name.
    SegmentationError, LogReadError
        From reading/segmenting the log.
    DiagnoseError
        No test with enough stable cycles, or the base model cannot reproduce any limit cycle.

    Examples
    --------
    A shipped log whose altitude sensor lags by 70 ms (a filter the linear model leaves out); the
    diagnosis takes about 20 s of CPU, so it is not run here:

    >>> from pathlib import Path
    >>> import mrftcli
    >>> log = Path(mrftcli.__file__).parents[1] / "sample_logs" / "concealed" / "flight_02.mcap"
    >>> flight = mrftcli.read_flight(log, mrftcli.ReadOptions(loop="altitude"))
    >>> result = diagnose(flight, soiptd_model(0.0422))  # doctest: +SKIP
    >>> [(e.name, round(e.parameters["T_lag"], 3)) for e in result.effects]  # doctest: +SKIP
    [('sensor_lag', 0.07)]
    """
    if not isinstance(model, LoopModel):
        return _diagnose_family(flight, model, relay, windows, min_stable_cycles, progress, baseline, analysis)
    return _diagnose_soiptd(flight, model, analysis, progress, candidates, refusal)


def _diagnose_family(flight: FlightLog, model: PlantModel, relay: RelayOptions,
                     windows: Sequence[tuple[float, float]], min_stable_cycles: int,
                     progress: Progress | None, baseline: tuple[float | Signal, float] | None = None,
                     analysis: AnalysisResult | None = None) -> DiagnosisResult:
    """Every family but eq. (2): the analysis, the checks per test, the library of physics, the verdict."""
    say = _Stages(progress, 3)
    say("analysing the tests")
    stage = measure_tests(flight, relay, windows, min_stable_cycles)  # segmented once, for both uses
    if analysis is None:  # else analyze's, made from the same measured tests
        analysis = general_analysis(flight, model, stage, windows, baseline)
    by_index = {m.summary.index: m for m in stage if m.summary is not None}
    measured, skipped = {}, []
    for s in analysis.tests:
        try:
            measured[s.index] = measured_waveform(by_index[s.index])
        except InputError as err:  # a test the analysis used but whose cycles are too short to fit here
            skipped.append(f"not checked: {err}")
    all_model = analysis.identification.model if analysis.identification is not None else None
    checks = tuple(check_test(model, s, measured[s.index],
                              [p for i, m in measured.items() if i != s.index for p in m.points], all_model)
                   for s in analysis.tests if s.index in measured)
    say("fitting the library of physics")
    chosen = select_effects_on(model, [as_test_data(flight, by_index[i], w) for i, w in measured.items()])
    say("locating")
    gap = misfit(analysis.identification)
    # where the residual sits first (per test, largest first); the fit's overall misfit after it
    ranked = sorted((item for c in checks for item in test_disagreements(c)), key=lambda item: -item[0])
    located = tuple(text for _, text in ranked) + ((gap[1],) if gap else ())
    notes = (*skipped,) + (() if len(measured) > 1 else
                           ("one test: nothing to hold out, so no effect is fitted (a second relay test checks them)",))
    say.finish()
    first = verdict(model, checks, located, chosen.found)
    if chosen.found and located and chosen.cycle_error_left > Z_LIMIT * chosen.cycle_precision:
        # named, but not the whole story: each test's cycle from the others still misses beyond its scatter
        first += (f"; unexplained beyond it: each test's cycle predicted from the others misses by "
                  f"{100 * chosen.cycle_error_left:.0f} % (RMS; the cycles' own scatter: "
                  f"{100 * chosen.cycle_precision:.1f} %); the linear model's disagreements are below")
    return DiagnosisResult(
        path=str(flight.path), loop=flight.loop, summary=first, family=model.family, effects=list(chosen.found),
        candidates=[r for r in chosen.rows if not r.with_], second_effect_candidates=[r for r in chosen.rows if r.with_],
        located=list(located), warnings=list(analysis.warnings), notes=list(notes), t0=analysis.t0,
        checks=list(checks), analysis=analysis)


def _diagnose_soiptd(flight: FlightLog, model: LoopModel, analysis: AnalysisResult | None, progress: Progress | None,
                     candidates: tuple[str, ...] | None, refusal: MrftError | None = None) -> DiagnosisResult:
    """Eq. (2)'s strategy (module docstring), Tp [s] read from the model object."""
    Tp = model.Tp
    names = [c.name for c in CANDIDATES] if candidates is None else list(candidates)
    library = [c.name for c in CANDIDATES]  # eq. (2)'s part of the library
    for n in names:
        if n not in library:
            raise InputError(f"unknown candidate effect {n!r}; choose from {', '.join(library)}")
    # done, total: segmenting, linear fit, noise scatter, candidates, locating
    say = _Stages(progress, 4 + len(names))
    screen = screen_log(flight, model, analysis, say, refusal)
    linear = fit_linear(screen, model, str(flight.path), say)
    screen = linear.screen  # each test's relay centre a per-test nuisance
    search = search_candidates(linear, names, model, say)
    chosen = select_effects(linear, search, model, say)
    cand_rows, effects = list(search.rows), list(chosen.effects)
    if "delay_jitter" in names:
        jitter = judge_jitter(screen, linear, chosen.final, say)
        cand_rows.append(jitter.row)
        effects += [jitter.finding] if jitter.finding is not None else []
    say("locating")
    located = locate(screen.tests, linear.model, linear.fit, screen.recs_all, linear.scatter)
    items = [replace(d, t_start_rel=d.t_start - screen.t0, t_end_rel=d.t_end - screen.t0) for d in located.items]
    unexplained = _unexplained(flight, screen, linear, effects, chosen.final, cand_rows, items, Tp)
    warnings = screen.warnings + chosen.warnings
    effects = [replace(e, parameters={**e.parameters, "unit": unit_in_loop(e.parameters.get("unit"), flight.loop)})
               for e in effects]
    figures = DiagnosisFigures(flight=flight, tests=screen.tests, base_model=linear.model, base=linear.fit,
                               fits=search.fits, effects=[e.name for e in effects], final=chosen.final,
                               cycle_errors=located.cycle_errors, harmonics=located.harmonics)
    say.finish()
    return DiagnosisResult(
        path=str(flight.path), loop=flight.loop, Tp=float(Tp), effects=effects, family="soiptd",
        # the parameters' units spelt in the loop's unit, as the terminal prints them (issue 26)
        candidates=[replace(c, unit=unit_in_loop(c.unit, flight.loop)) for c in cand_rows],
        located=items, identification=_identification(flight, Tp, screen, linear, effects, analysis, warnings),
        tests=_test_rows(screen, linear), noise_std=screen.noise, summary=_summary_text(effects, unexplained),
        warnings=warnings, analyze_refusal=screen.analyze_refusal,
        second_effect_candidates=[replace(c, unit=unit_in_loop(c.unit, flight.loop)) for c in chosen.pair_rows],
        unexplained=unexplained, t0=screen.t0, figures=figures, notes=[*lead_assumption(analysis), *_trim_note(screen)],
    )


def _unexplained(flight: FlightLog, screen: Screen, linear: LinearFit, effects: list[EffectFinding],
                 final: FinalModel | None, cand_rows: list[CandidateFit], items: list[Disagreement],
                 Tp: float) -> Unexplained | None:
    """Stage 6b: what no candidate explains, on the features (when the linear model is rejected), else
    a mode ringing after the switches (against the linear fit's harmonics, Tp [s] known)."""
    unexplained = None
    if linear.rejected:
        unexplained = unexplained_mismatch(screen.tests, linear.fit, linear.held_out, effects, final, cand_rows,
                                           screen.recs_all, linear.scatter, screen.t0, items)
    if unexplained is None:
        # a lightly damped mode above the fitted harmonics leaves the features alone (issue 27)
        lin = plant_params(linear.model, linear.fit)
        try:
            plant: LoopModel | None = LoopModel(Tp=Tp, Td=lin["Td"], tau=lin["tau"], K=abs(lin["K"]))
        except (InputError, TypeError):
            plant = None  # a fit at a bound eq. (2) refuses: the band statistic alone
        unexplained = resonance_mismatch(flight, screen.tests, "linear" if final is None else f"linear + {final.label}",
                                         plant)
    return unexplained


# --------------------------------------------------------------------------------------------------
# the summary: identification, one sentence, the tests


def _identification(flight: FlightLog, Tp: float, screen: Screen, linear: LinearFit, effects: list[EffectFinding],
                    analysis: AnalysisResult | None, warnings: list[str]) -> Identification:
    """The linear fit, the refit with each found effect, the waveform refits, analyze's model (when
    given) and the one estimate to take."""
    lin = plant_params(linear.model, linear.fit)
    refits = {e.identification.model_of(e.name): replace(e.identification.with_effect, Tp=float(Tp)) for e in effects}
    ident = Identification(loop=flight.loop, linear=ModelEstimate(**{**lin, "Tp": Tp}), refits=refits,
                           waveform=_waveform_refits(flight, screen.analysis, effects, warnings),
                           analyze=None if analysis is None else analyze_model(analysis))
    ident = ident.recommend(deterministic(effects))
    rec = ident.recommended
    why = None if rec is None else bound_reason(rec.Td)
    if rec is not None and rec.source != "analyze" and why is not None:  # a fit ended on Td's bound: no estimate
        warnings.append(f"no estimate of the plant to use: the one it would be ({rec.source}) is not determined: {why}")
        ident = replace(ident, recommended=None)
    return ident


def deterministic(effects: list[EffectFinding]) -> list[str]:
    """The names of the effects a deterministic model refits (the delay jitter leaves Td, tau, K alone)."""
    return [e.name for e in effects if e.name != "delay_jitter"]


def _summary_text(effects: list[EffectFinding], unexplained: Unexplained | None) -> str:
    """One sentence: the effects found (or none) and what remains unexplained."""
    if effects:
        parts = [
            f"{e.name} ({e.parameters.get(BY_NAME[e.name].parameter):.4g} {e.parameters['unit']}; delta BIC "
            f"{e.evidence.delta_bic:.0f} against the {e.evidence.compared_with} model; held-out NRMSE "
            f"{_fmt(e.fit_before.nrmse)} -> {_fmt(e.fit_after.nrmse)})"
            for e in effects
        ]
        summary = ("found " if len(parts) > 1 else "") + " and ".join(parts) + (
            " explains the mismatch" if len(parts) == 1 else "")
    else:
        summary = "the linear model explains the log: no candidate effect has strong evidence confirmed on held-out cycles"
    if unexplained is not None:
        lg = unexplained.largest
        where = f" (largest: test {lg['test']}, {lg['what']}, z = {lg['z']:+.1f})" if lg else ""
        if effects:
            summary += "; unexplained: " + unexplained.what + where
        else:
            summary = "unexplained: " + unexplained.what + where
    return summary


def _test_rows(screen: Screen, linear: LinearFit) -> list[TestRow]:
    """Per test: beta (nominal, effective up/down), h, bias, cycles used, times, period scatter."""
    t0_log = screen.t0
    return [
        TestRow(
            index=t.index,
            beta_nominal=t.beta_nominal,
            beta_effective_up=t.beta[0],
            beta_effective_down=t.beta[1],
            h=t.h,
            bias=t.bias,
            rate_hz=t.rate_hz,
            t_start=t.t_start,
            t_end=t.t_end,
            t_start_rel=t.t_start - t0_log,
            t_end_rel=t.t_end - t0_log,
            cycles=len(t.tab),
            stable_cycles_found=next((int(sum(c.stable for c in g.cycles)) for g in screen.segments
                                      if g.index == t.index), None),
            cycles_fit=int(t.fit.sum()),
            cycles_held_out=int(t.hold.sum()),
            period_scatter=math.sqrt(t.scatter_var("all")[0]) if t.scatter_var("all")[1] >= 3 else None,
            period_scatter_noise_model=sc["s0"],
        )
        for t, sc in zip(screen.tests, linear.scatter)
    ]


def _fmt(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def _waveform_refits(flight: FlightLog, analysis: AnalysisResult | None, effects: list[EffectFinding],
                     warnings: list[str]) -> dict[str, ModelEstimate]:
    """The output-error refit of issue 16 with each found effect it can model (a sensor lag, an input bias).

    The same problem as :func:`mrftcli.mrft.refine.refine` with one more parameter, fitted on the
    recorded waveform of the analysis' test windows: the effect's parameter and Td, tau, K with it
    accounted for, beside the cycle-feature fit's (``identification.waveform[<effect>]``).
    Skipped for a command logged below the controller's rate (the waveform is not known there).
    """
    from ..mrft.refine import EFFECTS, refinement_windows, refit_with_effect

    names = [e.name for e in effects if e.name in EFFECTS]
    if analysis is None:
        return {}
    tests = analysis.tests
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
        out[name] = ModelEstimate(kind="waveform", Td=r.model.Td, tau=r.model.tau, K=r.model.K, Tp=r.model.Tp,
                                  value=r.value, value_std=r.value_std, residual_rms=r.fit.residual_rms)
    return out
