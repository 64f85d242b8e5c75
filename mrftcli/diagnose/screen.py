"""Stage 1 of the diagnosis: the tests to diagnose, their cycles measured and split, and their features.

The tests are the ones ``analyze`` would use (refused for the same reasons), or the analysis' own
when one is given; even stable cycles are the fitting set, odd ones are held out.
"""

from __future__ import annotations

import warnings as pywarnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ..analyze import log_start
from ..errors import DiagnoseError, IdentificationError, InsufficientDataError, MrftError
from ..io.logtypes import FlightLog
from ..segment.records import MrftTest
from ..mrft.model import LoopModel
from .features import summarize_features
from .fit import Fit, feature_sigma
from .prepared import MIN_CYCLES, DiagnosedTest, prepare_tests, segments_of
from .candidate_model import CandidateModel
from .physics import BY_NAME

if TYPE_CHECKING:
    from ..analyze import AnalysisResult

__all__ = ["Screen", "screen_log", "lost_height_pair", "trim_spread", "with_trim_nuisance"]

#: two tests at one beta are at two relay heights when the larger is this much above the smaller
HEIGHT_RATIO = 1.1


@dataclass(frozen=True)
class Screen:
    """The tests a diagnosis works on (:func:`screen_log`).

    Attributes
    ----------
    analysis : AnalysisResult or None
        The analysis the tests come from (None when analyze refused the log).
    segments : list of MrftTest
        The segmenter's tests.
    tests : list of DiagnosedTest
        The tests with enough stable cycles, measured and split into fitting / held-out cycles.
    noise : float
        Sensor noise std [output units].
    t0 : float
        Log start [s].
    recs_fit, recs_hold, recs_all : list of (FeatureSummary, ndarray)
        Per test, the features of its fitting, held-out and all stable cycles and their standard errors.
    warnings : list of str
        What the user should know about the tests.
    analyze_refusal : str or None
        analyze's refusal of the log, without the log's path, when the diagnosis goes on without it (no plant
        of eq. (2) fits; one beta left of tests that differ in beta or relay height); else None. Data, not a
        warning: the CLI's second line and the JSON's ``analyze_refusal`` give it.
    flown : tuple of MrftTest
        Every test found in the log, those analyze or the diagnosis left out included (their relay centres
        measure how far the hold's trim moved: :func:`trim_spread`).
    """

    analysis: AnalysisResult | None
    segments: list[MrftTest]
    tests: list[DiagnosedTest]
    noise: float
    t0: float
    recs_fit: list
    recs_hold: list
    recs_all: list
    warnings: list[str]
    analyze_refusal: str | None = None
    flown: tuple[MrftTest, ...] = ()


def _analysis_of(flight: FlightLog, model: LoopModel,
                 refusal: MrftError | None = None) -> tuple[AnalysisResult | None, MrftError | None]:
    """The tests analyze would use, refused for the same reasons (an output that does not follow
    the relay: the --loop / --output-topic hint), so the two commands agree on what a
    log supports; the identification's bootstrap and refinement are not needed here. ``refusal``:
    analyze's own refusal of this log when the caller ran it (analyze is not run again; issue 39).
    Returns the analysis, or None and analyze's refusal (:func:`_goes_on` decides what follows)."""
    from ..analyze import AnalyzeOptions, analyze_flight

    if refusal is None:
        with pywarnings.catch_warnings():
            # numpy's all-NaN medians inside analyze's refusal message must not reach the terminal
            pywarnings.simplefilter("ignore", RuntimeWarning)
            try:
                options = AnalyzeOptions(n_bootstrap=1, max_combinations=10, refine_waveform=False)
                return analyze_flight(flight, model, options=options), None
            except (IdentificationError, InsufficientDataError) as exc:
                refusal = exc
    return None, refusal


def _goes_on(refusal: MrftError, flight: FlightLog) -> bool:
    """Whether the diagnosis goes on without analyze, which refused the log (``analyze_refusal`` says why); else
    the refusal is the command's (the same message and exit code as analyze)."""
    if isinstance(refusal, IdentificationError):
        # analyze must refuse, but no plant of eq. (2) fitting is the strongest sign of missing physics
        # there is, so the diagnosis fits the cycles itself
        return True
    # one usable beta: refused as analyze refuses it, unless the log flew tests to compare (another
    # beta analyze left out, or another relay height: a test that saturates at the larger one is not an
    # MRFT limit cycle of eq. (2), yet its flattening is the evidence of the saturation)
    return isinstance(refusal, InsufficientDataError) and _comparable(segments_of(flight, None))


def _one_test_left(flight: FlightLog, refusal: InsufficientDataError | None, kept: DiagnosedTest,
                   flown: list[MrftTest], t0: float, why: list[str]) -> str:
    """What is said when a single test of a flight that flew tests to compare has the cycles to diagnose: the
    other beta or relay height was flown but lost (a relay that locked up, too few stable cycles, cycles too
    sparsely logged to measure; ``why`` says which, per test left out). The test is named by its flown span,
    as analyze names it. When analyze refused the log (one beta), this is the command's refusal (exit 6,
    analyze's message first): the effects named from one test's waveform and trends there were wrong on every
    such benchmark flight (issue 39: 0 of 4 on RotorPy and JSBSim dev flights). When analyze identified the
    log, the diagnosis goes on from the one test with this as its warning, and names the explanations that
    test cannot tell apart (``test_models_the_tests_cannot_rank_are_named``)."""
    from ..analyze.screen import describe_tests, span

    test = next(t for t in flown if t.index == kept.index)
    if refusal is not None:  # analyze's refusal, said first, names the tests it rejected and why: said once
        named = tuple(f"test {row['index'] + 1} (" for row in refusal.partial.get("rejected_tests", []))
        why = [w for w in why if not w.startswith(named)]
    tail = f"so no second test is left to compare it with ({'; '.join([*why, 'fly the lost test again'])})"
    if refusal is not None:
        return f"{refusal}; diagnose: only the test at {span(test, t0)} has {MIN_CYCLES} stable cycles it can measure, {tail}"
    return (f"only one test has the {MIN_CYCLES} stable cycles diagnose needs and can measure "
            f"({describe_tests([test], t0)}; times from the log start), {tail}: the effects below are named from its "
            "waveform alone")


def _reason(flight: FlightLog, refusal: MrftError) -> str:
    """analyze's refusal without the log's path (the lines that carry it name the log already)."""
    return str(refusal).removeprefix(f"{flight.path}: ")


def _comparable(tests: list[MrftTest]) -> bool:
    """Whether the flown tests differ in beta or in relay height (by more than 10 %)."""
    from ..analyze.screen import group_betas

    return len(group_betas(tests)) > 1 or bool(_height_pairs(tests))  # one beta: its heights differ


def _height_pairs(tests: list[MrftTest]) -> list[list[MrftTest]]:
    """The groups of tests at one beta flown at two relay heights (or more)."""
    from ..analyze.screen import group_betas

    groups = [[tests[i] for i in g] for g in group_betas(tests)]
    return [g for g in groups if max(abs(t.h) for t in g) > HEIGHT_RATIO * min(abs(t.h) for t in g)]


def lost_height_pair(flown: list[MrftTest], kept: set[int]) -> str | None:
    """A warning when the tests left out break the only comparison of one beta at two relay heights.

    On a relay test a dead zone delta [command units] is exactly a gain of 1 - delta / h: the relay
    steps through the band at once, so each test's square wave is only smaller, never reshaped. The
    linear model's K absorbs it on one test, and on tests at different betas Td, tau and K absorb it
    (two tests leave one feature of freedom beyond the three parameters). Only two tests at one beta
    and two heights show it, as an amplitude ratio other than the heights'. When the flight had such a
    pair and a test of it was left out (a relay that locked up in the air, too few stable cycles), the
    diagnosis cannot see a dead zone, and its "nothing found" must say so.

    Parameters
    ----------
    flown : list of MrftTest
        Every test the segmenter found in the log, used or not.
    kept : set of int
        ``MrftTest.index`` of the tests the diagnosis works on.

    Returns
    -------
    str or None
        The warning, or None when no such pair was flown or one is kept.
    """
    pairs = _height_pairs(flown)
    if not pairs or _height_pairs([t for t in flown if t.index in kept]):
        return None
    lost = [t for g in pairs for t in g if t.index not in kept]
    what = ", ".join(f"test {t.index + 1} (beta {t.beta:.2f}, h {abs(t.h):.3g})" for t in lost)
    return (f"{what} left out: no two tests left share a beta at two relay heights, so a gain that changes with "
            "the relay height (a dead zone) cannot be told from the linear model's gain; fly it again to test for one")


def screen_log(flight: FlightLog, model: LoopModel, analysis: AnalysisResult | None,
               say: Callable[[str], None], refusal: MrftError | None = None) -> Screen:
    """Stage 1: the tests, their cycles and features (``analysis`` reused when given; ``model``: eq. (2)
    with Tp known, as analyze takes it; ``refusal``: analyze's refusal of the log when the caller ran
    analyze and it refused, so that it is not run again).

    Raises
    ------
    DiagnoseError
        No test has :data:`~mrftcli.diagnose.prepared.MIN_CYCLES` stable cycles.
    InsufficientDataError
        One test has them, of tests flown at two betas or relay heights (exit 6, as analyze's one beta); or
        analyze refused the log with one beta at one relay height (its refusal).
    """
    say("segmenting")
    refused_by_linear = None  # analyze's refusal, when the diagnosis goes on without it
    if analysis is None:
        analysis, refused_by_linear = _analysis_of(flight, model, refusal)
    if refused_by_linear is not None and not _goes_on(refused_by_linear, flight):
        raise refused_by_linear
    segs = segments_of(flight, analysis)
    flown = segs if analysis is None else sorted([*analysis.tests, *analysis.rejected], key=lambda s: s.index)
    t0_log = log_start(flight)
    tests, noise, warnings = prepare_tests(flight, segs)
    if flown:  # a gain drift's hover command: the earliest test flown, as trim_spread takes every test flown
        first = float(min(flown, key=lambda s: s.t_start).bias)
        tests = [replace(t, first_centre=first) for t in tests]
    if len(tests) == 1 and _comparable(flown):  # tests to compare were flown, one is left: nothing to compare
        by_analyze = [] if analysis is None else [f"test {t.index + 1} (beta {t.beta:.2f}) left out by analyze: "
                                                  f"{analysis.rejection_reasons.get(t.index, '')}" for t in analysis.rejected]
        one_beta = refused_by_linear if isinstance(refused_by_linear, InsufficientDataError) else None
        said = _one_test_left(flight, one_beta, tests[0], flown, t0_log, by_analyze + warnings)
        if one_beta is not None:
            raise InsufficientDataError(said, partial=one_beta.partial)
        warnings.append(said)
    lost = lost_height_pair(flown, {t.index for t in tests})
    warnings += [lost] if lost is not None else []
    if not tests:
        raise DiagnoseError(
            f"{flight.path}: no MRFT test with at least {MIN_CYCLES} stable cycles; the diagnosis compares "
            "cycles, so record longer tests"
        )
    if len({round(np.mean(t.beta), 2) for t in tests}) < 2:
        warnings.append("all tests share one beta: Td and tau are fitted from the waveform shape alone (weakly identified)")
    recs: tuple[list, list, list] = ([], [], [])
    for t in tests:
        for mask, store in zip((t.fit, t.hold, np.ones(len(t.tab), bool)), recs):
            feats = summarize_features(t.tab.subset(mask))
            store.append((feats, feature_sigma(feats.sigma, feats.values)))
    return Screen(analysis=analysis, segments=segs, tests=tests, noise=noise, t0=t0_log, recs_fit=recs[0],
                  recs_hold=recs[1], recs_all=recs[2], warnings=warnings,
                  analyze_refusal=None if refused_by_linear is None else _reason(flight, refused_by_linear),
                  flown=tuple(flown))


def trim_spread(tests: list[DiagnosedTest] | list[MrftTest]) -> float:
    """How far the tests' relay centres scatter [command units]: their sample standard deviation (0 with one test).

    Each test is centred on the hold's trim when it began. A hold whose trim moved between the tests (an
    integrator not settled since the previous test) leaves each test's centre off the vehicle's trim by
    about as much as the centres differ (issue 39: 0-3.7 % of h on RotorPy's and JSBSim's flights); a
    relay centred on one trim throughout gives 0 (centres that agree to a millionth of the mean relay height:
    the levels' rounding).
    """
    if len(tests) < 2:
        return 0.0
    spread = float(np.std([t.bias for t in tests], ddof=1))
    return spread if spread > 1e-6 * float(np.mean([abs(t.h) for t in tests])) else 0.0


def with_trim_nuisance(screen: Screen, model: CandidateModel, fit: Fit) -> Screen:
    """The screen with each test's relay centre treated as a per-test nuisance (issue 39).

    A relay test is centred on the hold's trim when it began, not on the vehicle's trim: an offset d
    [command units] of the relay's two levels shifts the half-period balance (-d / (2 h) on eq. (2)),
    the oscillation's centre and the second harmonic, differently in each test. Each feature's standard
    error gains, in quadrature, what an offset of :func:`trim_spread` (how far the centres of the tests
    flown scatter, those analyze or the diagnosis left out included) moves it on ``model``'s limit cycle at ``fit`` (the linear model fitted; the cycles at +-d,
    a central difference), so that the tests' own offsets are not evidence of an effect that acts on
    the whole flight. One offset shared by every test still is (an input bias), once beyond that
    spread: the evidence rules judge the sum over the tests. The screen itself when the centres agree.
    """
    if model.cands:  # (the linear model's cycle is the reference)
        raise ValueError("with_trim_nuisance needs the linear model")
    spread_d = trim_spread(list(screen.flown))  # a lost test's relay was centred by the same hold
    if spread_d <= 0.0:
        return screen
    shifted = CandidateModel(BY_NAME["input_bias"], screen.tests, model.Tp)
    dx = spread_d / shifted.hs  # input_bias' theta entry: d / (mean h)
    spread = []
    for i, (feats, _) in enumerate(screen.recs_fit):
        ends = [shifted.evaluate(np.append(fit.theta, s * dx), i, feats.t_mean, key=5000 + 2 * i + (s > 0))
                for s in (-1.0, 1.0)]
        if ends[0] is None or ends[1] is None:
            spread.append(np.zeros(len(feats.values)))
            continue
        spread.append(np.abs(ends[1].features - ends[0].features) / 2.0)

    def widened(recs: list) -> list:
        return [(f, np.sqrt(s**2 + d**2)) for (f, s), d in zip(recs, spread)]

    return replace(screen, recs_fit=widened(screen.recs_fit), recs_hold=widened(screen.recs_hold),
                   recs_all=widened(screen.recs_all))
