"""The one-log use case: :func:`analyze_flight` identifies a model's unknown parameters from one log;
:func:`analyze_path` reads the log first.

One route for every model family, the strategy chosen by the model object:

* eq. (2) (:class:`~mrftcli.mrft.model.LoopModel`, Tp known; ``mrftcli.mrft.model.soiptd_model``):
  segment (:func:`mrftcli.segment.segment`) -> screen (:func:`~mrftcli.analyze.screen.screen`) ->
  point estimate through the unit manifolds (the family's cached accelerator) -> consensus and
  bootstrap -> Table III combinations -> held out -> identifiability -> waveform refinement -> timing
  jitter (:mod:`mrftcli.analyze.estimate`); the method is described in :mod:`mrftcli.analyze`;
* an outer loop through its closed inner loop (:class:`~mrftcli.mrft.cascade.CascadeModel`): the
  exact sampled cascade's orbits (:func:`mrftcli.analyze.cascade.analyze_cascade`);
* every other family (the process plants, a declared transfer function): response points of every
  stable cycle under any relay, a direct exact fit, each test held out
  (:func:`mrftcli.analyze.general.analyze_family`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..errors import IdentificationError, InputError, LogReadError, TpRejectedError
from ..io.clock import implausible_timing
from ..io.flight import ReadOptions
from ..io.logtypes import PROCESS_LOOP, FlightLog
from ..io.source import LogSource
from ..mrft.cascade import CascadeModel
from ..mrft.consensus import combinations
from ..mrft.identify import LEAD_WORDS, lead_note
from ..mrft.model import LoopModel, PlantModel
from ..mrft.profile import BELOW_CONTROLLER_RATE, profile_tp, td_below_tp, tp_not_checkable
from ..mrft.refine import RESIDUAL_FACTOR, refinement_windows
from ..segment import StabilityCriterion, ValidityCriterion, segment
from ..validate import check_tp
from .cascade import analyze_cascade
from .estimate import (WaveformStage, beta_used, consensus, identifiability, point_estimate, waveform_refinement,
                       widen_for_jitter)
from .general import analyze_family, mask_windows
from .held_out import ROUTE_POINTS, held_out_eq2, lead_held_out_refusal
from .held_out_harmonic import held_out_harmonic, route_note
from .options import AnalyzeOptions
from .record import AnalysisResult, LogInfo, TpCheck, analysis_controller_rate
from .residual import MISMATCH_WORDS, residual_verdict
from .screen import Screening, screen

__all__ = ["analyze_flight", "analyze_path", "refuse_rejected_tp"]


def _check_clock(flight: FlightLog, period_s: float | None, delay_s: float | None) -> None:
    """Refuse a limit-cycle period [s] or a delay [s] no vehicle loop has: the log's clock unit is
    wrong (:mod:`mrftcli.io.clock` gives the thresholds), and every number would scale with it."""
    why = implausible_timing(period_s, delay_s)
    if why is not None:
        raise LogReadError(f"{flight.path}: {why}: the log's times are not in the unit they were read in; "
                           "check the time column's unit (--time-unit for CSV and .mat logs)")


def analyze_flight(flight: FlightLog, model: PlantModel, *,
                   options: AnalyzeOptions | None = None) -> AnalysisResult:
    """Segment the relay tests of a flight and identify the model's unknown parameters (module docstring).

    Parameters
    ----------
    flight : FlightLog
        Command and output (and optional beta/setpoint) of one loop.
    model : PlantModel
        The structure with its known parameters (set E) and ranges (set I): eq. (2) with Tp known
        (``soiptd_model(Tp)``, Tp [s] from the bench test) identifies Td, tau and K through the
        manifolds; a cascade (:func:`mrftcli.analyze.cascade.cascade_model`) through its closed inner
        loop; any other family by its direct fit (:func:`mrftcli.analyze.general.analyze_family`).
    options : AnalyzeOptions, optional
        The analysis's knobs (stability and validity criteria, bootstrap draws, Table III cap, seed,
        constraints, waveform refinement, controller rate, the relay stated, the windows, a process
        plant's operating point); None: ``AnalyzeOptions()``. A log below the controller's rate is
        identified as a sampled relay at the nominal beta (:func:`mrftcli.analyze.screen.low_rate_period`).

    Returns
    -------
    AnalysisResult
        The one analysis record; its ``kind`` says which strategy made it (``"soiptd"``, ``"cascade"``,
        ``"family"``).

    Raises
    ------
    LogReadError
        A limit-cycle period over 60 s or a delay over 10 s: the log's times are in another unit
        than they were read in (:mod:`mrftcli.io.clock`).
    SegmentationError
        No relay test in the log, or no test with ``min_stable_cycles`` stable cycles whose output
        is a limit cycle of its relay (the message says what was found and why it is not usable).
    InsufficientDataError
        Usable tests at a single beta only (``.partial`` gives tau over an assumed Td range).
    IdentificationError
        The measured cycles admit no plant of eq. (2) with this Tp. (Slices that do not cross but
        fit a plant without linear damping are not an error: Td is then bounded from below only,
        ``identification.method == "unbounded-Td"``.)
    InputError
        A Tp outside its physical range; a relay or an operating point stated for eq. (2) (it reads
        its relay from the log and integrates); a bad window.

    Examples
    --------
    A shipped sample log (simulated Design I altitude loop: Td 2.669 s, tau 46.4 ms, K 19.62):

    >>> from pathlib import Path
    >>> from mrftcli.io import ReadOptions, read_flight
    >>> from mrftcli.mrft.model import soiptd_model
    >>> log = Path(__file__).parents[2] / "sample_logs" / "design1_altitude.mcap"
    >>> flight = read_flight(log, ReadOptions(loop="altitude"))
    >>> result = analyze_flight(flight, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=100))
    >>> print(f"Td {result.Td.value:.2f} s ({result.Td.ci95_low:.2f}-{result.Td.ci95_high:.2f}), "
    ...       f"tau {result.tau.value * 1e3:.1f} ms")
    Td 2.66 s (2.65-2.67), tau 46.4 ms
    """
    opts = AnalyzeOptions() if options is None else options
    # the family's strategy: eq. (2) through its manifolds, every other structure by its direct fit
    if isinstance(model, LoopModel):
        return _analyze_eq2(flight, model, opts)
    if isinstance(model, CascadeModel):
        return analyze_cascade(flight, model, opts)
    return analyze_family(flight, model, opts)


def _analyze_eq2(flight: FlightLog, model: LoopModel, opts: AnalyzeOptions) -> AnalysisResult:
    """Eq. (2)'s strategy: the stages of the module docstring at the model's known Tp."""
    Tp = check_tp(model.Tp)
    if opts.relay.stated or opts.baseline is not None:
        raise InputError("a relay (--relay, --eps) and an operating point (--baseline) take a process model "
                         "(--model fopdt, sopdt, ipdt or foipdt); eq. (2) reads beta from the log and integrates")
    if model.known != frozenset({"Tp"}) or model.ranges:
        raise InputError("eq. (2) is identified with Tp known and Td, tau, K free: give --tp only")
    flight = mask_windows(flight, opts.windows)
    constraints = opts.constraints
    found = segment(flight, criterion=opts.criterion or StabilityCriterion(),
                    validity=opts.validity or ValidityCriterion(), controller_rate_hz=opts.controller_rate_hz)
    screening = screen(flight, found, model, opts.min_stable_cycles)
    _check_clock(flight, max((1.0 / t.frequency_hz_mean for t in screening.usable), default=None), None)
    # one generator through the stages in this order: a seed gives the same draws
    rng = np.random.default_rng(opts.seed)
    point = point_estimate(model, screening, constraints, opts.n_bootstrap, rng)
    cons = consensus(model, point, constraints, screening.ts_ctrl, rng, opts.diagnose_hint)
    n = len(screening.usable)
    n_combinations = int(min(opts.max_combinations, max(50, 4000 // n)))
    combos = combinations(Tp, list(point.cycles), cons.Td_point, n_combinations, rng)
    # each test predicted from the others (point solves, no draws: rng untouched, the estimates unchanged)
    held = held_out_eq2(model, screening.usable, [beta_used(t, screening.ts_ctrl) for t in screening.usable],
                        cons.Td_point)
    bounds = identifiability(model, screening, point, cons, constraints, rng, flight)
    mrft_params = {"Td": bounds.Td, "tau": bounds.tau, "K": bounds.K}
    wave = waveform_refinement(flight, screening, cons, bounds, mrft_params, opts.refine_waveform, opts.diagnose_hint)
    tau_est, jitter_note = widen_for_jitter(wave.tau, flight, wave.send_times)
    _check_clock(flight, None, tau_est.value)
    tp_warning, tp_check = _tp_check(flight, screening, wave, model, opts.refine_waveform)
    swapped = td_below_tp(wave.Td.value, Tp)  # the fast pole came out as Td: a Tp given too large
    tp_warning = (*tp_warning, *([swapped] if swapped else []))
    warnings = [w for w in (*tp_warning, *screening.warnings, *cons.warnings, *bounds.warnings, *wave.warnings)
                if not w.startswith(LEAD_WORDS)]  # the lead is stated once, first, for the tau reported
    notes = [*bounds.notes, *wave.notes, *([jitter_note] if jitter_note else [])]
    lead_refused = lead_held_out_refusal(held, tau_est.value)  # on the UFM's own route, as measured (method.md 4)
    if lead_refused:  # a Tp given too large reads as a lead the tests disagree on (docs/method.md section 4)
        raise IdentificationError(lead_refused)
    if tau_est.value < 0:
        notes.insert(0, f"assumed: {lead_note(tau_est.value)}")
    held = held_out_harmonic(flight, model, screening.usable, held, opts.min_stable_cycles)
    if any(h.route == ROUTE_POINTS for h in held):
        notes.append(route_note(wave.method == "waveform"))
    usable, rejected = screening.usable, screening.rejected
    return _residual_worded(AnalysisResult(
        path=str(flight.path), loop=flight.loop, model=wave.model, tests=usable, rejected=rejected,
        parameters={"Td": wave.Td, "tau": tau_est, "K": wave.K}, identification=point.identification,
        combinations=combos, bootstrap=dict(cons.draws), warnings=tuple(dict.fromkeys(warnings)), flight=flight,
        t0=screening.t0, constraints=cons.constraints,
        rejection_reasons={t.index: screening.reasons[t.index] for t in rejected}, method=wave.method,
        parameters_mrft=mrft_params, refinement=wave.refinement, notes=tuple(notes),
        controller_rate_hz=analysis_controller_rate(flight.timing.controller_rate_hz, [t.rate_hz for t in usable]),
        log_info=LogInfo.from_flight(flight), tp_check=tp_check, held_out=held,
    ))


def _residual_worded(result: AnalysisResult) -> AnalysisResult:
    """The warnings worded by the one residual verdict (:func:`mrftcli.analyze.residual.residual_verdict`):
    with receive-time stamps the waveform residual cannot say the recording holds dynamics eq. (2)
    leaves out (diagnose, which reads the same verdict, decides on the cycles' features)."""
    verdict = residual_verdict(result)
    if verdict is None or verdict.verdict != "untestable":
        return result
    why = ("with receive-time stamps it holds the transport's timing jitter too, so it cannot tell timing from "
           "dynamics eq. (2) leaves out; diagnose decides on the cycles' features")
    return dataclasses.replace(result, warnings=tuple(w.replace(MISMATCH_WORDS, why) for w in result.warnings))


def _tp_check(flight: FlightLog, screening: Screening, wave: WaveformStage, model: LoopModel,
              refine: bool) -> tuple[tuple[str, ...], TpCheck | None]:
    """What the waveform says about ``model``'s given Tp [s] (issue 26): a wrong Tp otherwise yields a tight,
    wrong tau. The warning, first of all (the recording fits another Tp, or this log cannot check Tp:
    the command logged below the controller's rate; eq. (2) holding at no Tp), and the verdict
    (:class:`TpCheck`; None when the waveform refinement did not run).

    Profiles the output-error fit over Tp (:func:`mrftcli.mrft.profile.profile_tp`, about 1 s of CPU),
    only when the refinement ran and its residual exceeded the acceptance factor.
    """
    ref, Tp = wave.refinement, model.Tp
    if not screening.usable:
        return (), None
    if ref is None:
        if refine and screening.ts_ctrl:
            return (tp_not_checkable(Tp, BELOW_CONTROLLER_RATE),), TpCheck("not-checkable", Tp)
        return (), None
    if ref.residual_ratio <= RESIDUAL_FACTOR:
        return (), TpCheck("consistent", Tp, residual_ratio_given=float(ref.residual_ratio))
    usable = screening.usable
    windows = refinement_windows(usable, flight.command.t, flight.command.values, flight.output.t,
                                 flight.output.values)
    profile = profile_tp(windows, ref.model, loop_sign=usable[0].loop_sign, noise_std=ref.noise_std)
    verdict = "rejected" if profile.rejects_given else "not-checkable" if profile.holds_nowhere else "consistent"
    return profile.warnings(), TpCheck(verdict, Tp, profile.best, profile.low, profile.high,
                                       profile.residual_ratio_given, profile.residual_ratio_best)


def refuse_rejected_tp(result: AnalysisResult, accept: bool = False) -> AnalysisResult:
    """The analysis, unless the recording rejects its Tp (``result.tp_check.verdict == "rejected"``).

    A wrong Tp moves Td, tau and K within tight, wrong intervals, so a Tp the recording rejects is a
    refusal (exit 5, naming the better Tp) unless the user keeps it (``accept``, ``--accept-tp``): the
    result's verdict is then ``accepted``.

    Raises
    ------
    TpRejectedError
        The recording rejects the given Tp and ``accept`` is False (``best``: the Tp it fits [s];
        ``result``: the analysis at the given Tp, its verdict ``rejected``).
    """
    check = result.tp_check
    if check is None or check.verdict != "rejected":
        return result
    if accept:
        return dataclasses.replace(result, tp_check=dataclasses.replace(check, verdict="accepted"))
    assert check.best is not None
    raise TpRejectedError(
        f"the recording rejects Tp = {check.given:.4g} s: it fits Tp = {check.best:.4g} s "
        f"[{check.low:.4g}, {check.high:.4g}] (waveform residual {check.residual_ratio_best:.2f}x the sensor noise "
        f"against {check.residual_ratio_given:.2f}x); rerun with --tp {check.best:.4g}, or, if {check.given:.4g} s is "
        f"the bench test's, a lag eq. (2) leaves out (a sensor filter) reads the same way: mrft-ident diagnose names "
        f"it, and --accept-tp keeps {check.given:.4g} s", best=check.best, result=result)


def analyze_path(path: str | Path, model: PlantModel, *, read: ReadOptions | None = None,
                 options: AnalyzeOptions | None = None, loop_hint: bool = True,
                 log: LogSource | None = None) -> AnalysisResult:
    """Read one log with :func:`mrftcli.io.read_flight` and run :func:`analyze_flight`.

    Parameters
    ----------
    path : str or Path
        The flight log (any supported format).
    model : PlantModel
        As in :func:`analyze_flight` (eq. (2): ``soiptd_model(Tp)``).
    read : ReadOptions, optional
        How to read the loop (loop, topics, scales, layout, controller rate, format, time unit; see
        :func:`mrftcli.io.read_flight`); None: ``ReadOptions()``, the altitude loop, or for a process model
        ``ReadOptions(loop="process")`` (its record's loop, as ``analyze --model`` without ``--loop`` says). A
        process model is read on any time scale (``any_time_scale``: its clock is not checked against a vehicle's).
    options : AnalyzeOptions, optional
        As in :func:`analyze_flight`.
    loop_hint : bool
        As in :func:`mrftcli.io.read_flight` (False: the caller tries every loop, ``batch``).
    log : LogSource, optional
        As in :func:`mrftcli.io.read_flight`: the log at ``path``, open already (``tune``, which read its hover
        thrust from it); None: opened and closed here.

    Returns
    -------
    AnalysisResult

    Examples
    --------
    >>> from pathlib import Path
    >>> from mrftcli.mrft.model import soiptd_model
    >>> log = Path(__file__).parents[2] / "sample_logs" / "design1_altitude.csv"
    >>> result = analyze_path(log, soiptd_model(0.0422), read=ReadOptions(loop="altitude"),
    ...                       options=AnalyzeOptions(n_bootstrap=100))
    >>> [round(t.beta_nominal, 1) for t in result.tests], f"{result.K.value:.1f}"
    ([-0.4, -0.7], '19.6')
    """
    from ..io import read_flight

    if not isinstance(model, (LoopModel, CascadeModel)):  # a process plant: not a vehicle loop's clock
        read = dataclasses.replace(read or ReadOptions(loop=PROCESS_LOOP), any_time_scale=True)
    flight = read_flight(path, read, echo_warnings=False, loop_hint=loop_hint, log=log)  # the reader's warnings come once, in the result's
    return analyze_flight(flight, model, options=options)
