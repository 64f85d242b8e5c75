"""The estimation stages of an analysis, each returning a frozen record.

:func:`point_estimate` (the paper's UFM slices, or the Td -> infinity limit) -> :func:`consensus`
(the weighted estimate and its bootstrap over cycles) -> :func:`mrftcli.mrft.consensus.combinations`
(Table III) -> :func:`identifiability` (what the data bound, the sampled relay's switching lag)
-> :func:`waveform_refinement` (output error on the tests' windows) -> :func:`widen_for_jitter`.
:func:`mrftcli.analyze.analyze_flight` chains them (see :mod:`mrftcli.analyze` for the method).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..errors import IdentificationError
from ..io.logtypes import FlightLog
from ..mrft.consensus import (Bootstrap, StableCycles, UnboundedTd, bootstrap, bootstrap_estimate, constraint_report,
                              unbounded_td, upper_bound_open)
from ..mrft.identify import IdentificationResult, ParameterEstimate, TestMeasurement, identify, lead_refusal
from ..mrft.model import LoopModel, lead_floor
from ..mrft.refine import COMMAND_HISTORY, Refinement, refine, refinement_windows
from ..mrft.waveform import CommandWindow
from ..segment import MrftTest
from ..segment.runs import SendTimes, rebuild_send_times
from ..segment.vernier import fold_amplitudes
from .screen import Screening

__all__ = ["PointEstimate", "Consensus", "Identifiability", "WaveformStage", "SendTimeWindows", "point_estimate",
           "consensus", "identifiability", "send_time_windows", "waveform_refinement", "widen_for_jitter",
           "TD_OMEGA_LIMIT"]

_TWO_PI = 2.0 * math.pi
#: Td * Omega above which Td is called poorly identifiable (the issue's accuracy boundary).
TD_OMEGA_LIMIT = 5.0


@dataclass(frozen=True, eq=False)
class PointEstimate:
    """The paper's point identification of a log's usable tests (:func:`point_estimate`).

    Attributes
    ----------
    cycles : tuple of StableCycles
        Each test's stable cycles as the consensus reads them.
    n_draws : int
        Bootstrap draws for this log (fewer for many tests: draws x tests <= 4000, >= 100).
    identification : IdentificationResult
        :func:`mrftcli.mrft.identify.identify` on the tests' means, or the Td -> infinity limit.
    limit : tuple of (Bootstrap, UnboundedTd) or None
        The bootstrap and the limit when the UFM slices do not intersect but a plant without linear
        damping fits the tests; None otherwise.
    """

    cycles: tuple[StableCycles, ...]
    n_draws: int
    identification: IdentificationResult
    limit: tuple[Bootstrap, UnboundedTd] | None


@dataclass(frozen=True, eq=False)
class Consensus:
    """The weighted estimate of the tests together and its bootstrap (:func:`consensus`).

    Attributes
    ----------
    Td, tau, K : ParameterEstimate
        The estimate with the bootstrap's std and 95 % interval [s], [s], [-].
    model : LoopModel
        The point estimate as a model.
    Td_point : float
        The point Td [s] the later stages start from.
    boot : Bootstrap
        The bootstrap (row 0: the data themselves).
    draws : Mapping
        ``"Td"``, ``"tau"``, ``"K"`` -> the draws (rows 1..; tau without the sampled relay's lag).
    constraints : Mapping
        The constraints used, their residuals and chi-square (empty without constraints).
    warnings : tuple of str
        The identification's warnings, disagreeing constraints, failed draws.
    """

    Td: ParameterEstimate
    tau: ParameterEstimate
    K: ParameterEstimate
    model: LoopModel
    Td_point: float
    boot: Bootstrap
    draws: Mapping[str, np.ndarray]
    constraints: Mapping[str, Any]
    warnings: tuple[str, ...]


@dataclass(frozen=True)
class Identifiability:
    """What the data bound (:func:`identifiability`).

    Attributes
    ----------
    Td, tau, K : ParameterEstimate
        The estimates with Td's open upper end and the sampled relay's switching lag in the intervals.
    td_open : bool
        The tests bound Td from below only.
    warnings, notes : tuple of str
        What to act on, and information.
    """

    Td: ParameterEstimate
    tau: ParameterEstimate
    K: ParameterEstimate
    td_open: bool
    warnings: tuple[str, ...]
    notes: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class WaveformStage:
    """The output-error refinement's outcome (:func:`waveform_refinement`).

    Attributes
    ----------
    refinement : Refinement or None
        The fit (None when not run).
    method : {"waveform", "mrft"}
        Which estimate the analysis reports.
    model : LoopModel
        The model reported.
    Td, tau, K : ParameterEstimate
        The estimates reported.
    warnings, notes : tuple of str
        Why the refinement was not used, or not run; what a receive-stamped log's rebuild did.
    send_times : SendTimeWindows or None
        The rebuilt send times the refinement ran on (every test's; None: on the logged times). The
        command's jitter is then removed, and tau's interval is widened for the output's only
        (:func:`widen_for_jitter`).
    """

    refinement: Refinement | None
    method: str
    model: LoopModel
    Td: ParameterEstimate
    tau: ParameterEstimate
    K: ParameterEstimate
    warnings: tuple[str, ...]
    notes: tuple[str, ...]
    send_times: SendTimeWindows | None = None


@dataclass(frozen=True, eq=False)
class SendTimeWindows:
    """The refinement's windows of a receive-stamped log on its topics' rebuilt send times (:func:`send_time_windows`).

    Attributes
    ----------
    windows : tuple of CommandWindow
        One per test (a test with fewer than 2 commands or 8 outputs is left out).
    command, output : tuple of SendTimes
        Each test's rebuild of the command and of the output (missing messages are ticks without
        one; a window's :attr:`~mrftcli.mrft.waveform.CommandWindow.free` ticks are where a switch
        may sit in a gap).
    """

    windows: tuple[CommandWindow, ...]
    command: tuple[SendTimes, ...]
    output: tuple[SendTimes, ...]

    @property
    def output_spread(self) -> float:
        """The largest robust std of the output's arrivals about its grid over the tests [s]
        (about 0 for an output stamped at the source)."""
        return max((r.spread for r in self.output), default=0.0)

    @property
    def all_rebuilt(self) -> bool:
        """Every test's command and output were put back on their publishers' grids."""
        return all(r.rebuilt for r in (*self.command, *self.output))

    def notes(self) -> tuple[str, ...]:
        """What was rebuilt and how well the grid fits, one line per topic (the first test's figures
        when every test was rebuilt, else the first reason it was not; none for a topic whose logged
        times were on the grid in every test: nothing changed)."""
        out = []
        for topic, rec in (("command", self.command), ("output", self.output)):
            failed = [i for i, r in enumerate(rec) if not r.rebuilt]
            if not rec or all(r.unchanged for r in rec):
                continue
            if failed:
                out.append(rec[failed[0]].describe(topic) + f" (in {len(failed)} of {len(rec)} tests)")
            else:
                out.append(rec[0].describe(topic) + f" in {len(rec)} of {len(rec)} tests")
        unknown = sum(w.free.size for w in self.windows)
        if unknown:
            out.append(f"{unknown} command tick(s) without a message where a switch may sit (the messages either side "
                       "differ): each such switch's time carries one tick of uncertainty, its command fitted from "
                       "the output and its uncertainty in the intervals")
        return tuple(out)


def point_estimate(model: LoopModel, screening: Screening, constraints: Sequence[str], n_bootstrap: int,
                   rng: np.random.Generator) -> PointEstimate:
    """The paper's identification of the usable tests (UFM slices at the tests' means, ``rate_hz=None``)
    at ``model``'s known Tp.

    The slices may not cross because the plant has no linear damping (Td -> infinity: they run
    side by side and noise decides); the consensus then says whether the tests agree in that limit.

    Raises
    ------
    IdentificationError
        The tests admit no plant of eq. (2), not even in the limit.
    """
    usable, ts_ctrl = screening.usable, screening.ts_ctrl
    meas = [TestMeasurement(beta=beta_used(t, ts_ctrl), frequency_hz=t.frequency_hz_mean, amplitude=t.amplitude_mean,
                            h=t.h) for t in usable]
    cycles = [stable_cycles(t, ts_ctrl) for t in usable]
    # Many tests: fewer draws keep the cost (draws x tests) bounded; a few hundred draws suffice
    # for a std and percentile interval.
    B = int(min(n_bootstrap, max(100, 4000 // len(usable))))
    limit = None
    try:
        ident = identify(meas, model, rate_hz=None)
    except IdentificationError as exc:
        # a Td far beyond every test's time scale stands for the limit
        Td_ref = 1e4 / (_TWO_PI * min(t.frequency_hz_mean for t in usable))
        ident, limit = unbounded_td_or_raise(exc, model, Td_ref, cycles, constraints, B, rng)
    return PointEstimate(tuple(cycles), B, ident, limit)


def _within_lead(tau: float, Tp: float) -> float:
    """``tau`` [s], or the one-line refusal (:func:`mrftcli.mrft.identify.lead_refusal`) of a lead beyond
    :func:`mrftcli.mrft.model.lead_floor`: never clamped to it (the reported tau would then differ from the model's)."""
    if tau < lead_floor(Tp):
        raise IdentificationError(lead_refusal(tau, Tp))
    return tau


def consensus(model: LoopModel, point: PointEstimate, constraints: Sequence[str], ts_ctrl: float,
              rng: np.random.Generator, hint: str) -> Consensus:
    """The weighted estimate of the tests together (UFM slices + ``constraints``) at ``model``'s known Tp,
    and its bootstrap over cycles.

    The weighted estimate on the data themselves (bootstrap row 0) is the point estimate; the
    paper's UFM-only estimate stays in ``identification`` for comparison. A low-rate log
    (``ts_ctrl`` > 0) has the sampled relay's lag Ts / 2 removed from every tau. ``hint`` ends the warning
    that the tests' constraints disagree (:attr:`~mrftcli.analyze.options.AnalyzeOptions.diagnose_hint`).
    """
    known, Tp = model, model.Tp  # the known set E; below, ``model`` is the fit
    ident, limit, B = point.identification, point.limit, point.n_draws
    cycles = list(point.cycles)
    warnings = list(ident.warnings)
    model = ident.model
    Td_hat, tau_hat = model.Td, model.tau
    K_hat = ident.K.value if ident.K is not None else float("nan")
    if limit is None:
        boot = bootstrap(Tp, cycles, Td_hat, constraints, B, rng)
        Td_d, tau_d, K_d = boot.Td, boot.tau, boot.K
    else:
        boot, lim = limit
        Td_d, tau_d, K_d = np.full(B + 1, Td_hat), lim.tau, lim.K
    constraint_info: dict[str, Any] = {}
    if constraints and np.isfinite(Td_d[0]):
        Td_hat, tau_hat, K_hat = float(Td_d[0]), float(tau_d[0]), float(K_d[0])
        model = LoopModel(Tp, Td_hat, _within_lead(tau_hat, Tp), K_hat if np.isfinite(K_hat) else model.K)
        constraint_info = _constraint_info(known, cycles, boot, ident, Td_hat, tau_hat, constraints)
        pv = constraint_info["p_value"]
        if pv is not None and pv < 1e-3:
            warnings.append(
                f"the tests' constraints disagree (chi2 {constraint_info['chi2']:.1f} for {constraint_info['dof']} "
                f"degrees of freedom): the plant may not follow eq. (2); the UFM-only estimate is Td "
                f"{ident.model.Td:.4g} s, tau {ident.model.tau * 1e3:.4g} ms{hint}")
    elif constraints:
        warnings.append("the weighted estimate found no minimum in the search range; the UFM-only estimate is used")
    if ts_ctrl:
        # the sampled relay's continuous equivalent has the delay tau + Ts / 2 (it switches 0..Ts
        # after the crossing of its level); remove that lag from every tau
        lag = 0.5 * ts_ctrl
        tau_hat, tau_d = tau_hat - lag, tau_d - lag
        model = LoopModel(Tp, model.Td, _within_lead(model.tau - lag, Tp), model.K)
    Td_est = bootstrap_estimate(Td_hat, Td_d[1:], Td_d[0], "s")
    tau_est = bootstrap_estimate(tau_hat, tau_d[1:], tau_d[0], "s")
    K_est = bootstrap_estimate(K_hat, K_d[1:], K_d[0], "")
    if limit is not None:
        Td_est = ParameterEstimate(Td_hat, float("nan"), limit[1].Td_low, float("nan"), "s", determined=False,
                                   method="mrft")
    n_fail = int((~np.isfinite(Td_d[1:])).sum())
    if n_fail > 0.05 * B:
        warnings.append(f"{n_fail} of {B} bootstrap draws found no intersection of the UFM slices within "
                        f"{Td_hat / 10:.3g}-{Td_hat * 10:.3g} s: Td is poorly determined")
    return Consensus(Td_est, tau_est, K_est, model, Td_hat, boot, {"Td": Td_d[1:], "tau": tau_d[1:], "K": K_d[1:]},
                     constraint_info, tuple(warnings))


def _constraint_info(model: LoopModel, cycles: Sequence[StableCycles], boot: Bootstrap, ident: IdentificationResult,
                     Td: float, tau: float, constraints: Sequence[str]) -> dict[str, Any]:
    """The constraints' residuals at the estimate (``model``: eq. (2) with its known Tp), with the paper's
    UFM-only estimate beside them."""
    info = constraint_report(model.Tp, cycles, Td, tau, boot.betas[0], boot.omegas[0], boot.phases[0], boot.ln_amp[0],
                             boot.weights or {}, constraints)
    info["paper_estimate"] = {"Td": ident.model.Td, "tau": ident.model.tau,
                              "K": ident.K.value if ident.K is not None else None,
                              "method": "UFM slices only (identify)"}
    return info


def identifiability(model: LoopModel, screening: Screening, point: PointEstimate, cons: Consensus,
                    constraints: Sequence[str], rng: np.random.Generator,
                    flight: FlightLog | None = None) -> Identifiability:
    """Td's upper end when the data do not close it, Td * Omega, and a low-rate log's switching lag.

    The likelihood may not close as Td -> infinity: then Td has a lower bound only (the upper end
    of the bootstrap interval would come from the search range, not from the data). Td * Omega >
    :data:`TD_OMEGA_LIMIT` is usual for an altitude loop (slow drag, fast loop): information, not a
    warning, unless the interval is too wide to use (then the user should act: another test,
    'mrft-ident plan').

    A low-rate log's switching lag and its folds' harmonic counts (from ``flight``'s output) are
    drawn into the intervals (:func:`widen_for_orbits`). ``model``: eq. (2) with its known Tp.
    """
    Tp = model.Tp
    usable, ts_ctrl = screening.usable, screening.ts_ctrl
    Td_est, tau_est, K_est = cons.Td, cons.tau, cons.K
    Td_hat = cons.Td_point
    warnings: list[str] = []
    notes: list[str] = []  # what is expected and needs no action (shown as information)
    td_omega = max(Td_hat * _TWO_PI * t.frequency_hz_mean for t in usable)
    td_open = point.limit is not None or (bool(constraints) and upper_bound_open(Tp, cons.boot, Td_hat))
    if td_open:
        Td_est = replace(Td_est, ci95_high=float("nan"), determined=False)
        low = f"Td > {Td_est.ci95_low:.3g} s" if np.isfinite(Td_est.ci95_low) else "Td"
        warnings.append(f"{low}: these tests cannot bound it from above (a plant without "
                        "linear damping fits them as well); tau and K are determined")
    elif td_omega > TD_OMEGA_LIMIT:
        text = (f"Td*Omega = {td_omega:.1f} > {TD_OMEGA_LIMIT:g}: the test frequencies depend weakly on Td, so Td "
                f"is less closely determined than tau and K (MRFT interval {Td_est.ci95_low:.3g}-{Td_est.ci95_high:.3g} s)")
        if Td_est.ci95_high > 2.0 * Td_est.ci95_low:
            warnings.append(text + "; a test at another beta narrows it (see 'mrft-ident plan')")
        else:
            notes.append(text)
    if ts_ctrl and point.limit is None:
        shapes = [fold_amplitude_ratios(flight, t) for t in usable] if flight is not None else None
        Td_est, tau_est, K_est = widen_for_orbits(model, list(point.cycles), Td_hat, constraints, ts_ctrl,
                                                  (Td_est, tau_est, K_est), rng, point.n_draws, shapes)
        rate = min(t.rate_hz for t in usable)
        notes.append(f"command logged at {rate:.0f} Hz below the {1 / ts_ctrl:.0f} Hz controller: identified as "
                     "a sampled relay at the nominal beta (the logged switch instants and output levels are too "
                     f"coarse), with +-{0.5e3 * ts_ctrl:.0f} ms of switching lag per test in the intervals")
    return Identifiability(Td_est, tau_est, K_est, td_open, tuple(warnings), tuple(notes))


def send_time_windows(flight: FlightLog, tests: Sequence[MrftTest],
                      history: float = COMMAND_HISTORY) -> SendTimeWindows:
    """The refinement's windows with each test's command and output on their publishers' tick grids.

    Receive stamps are late by a random transport delay: the waveform fit would read that jitter as
    model error (a residual of 6-9x the sensor noise on logs with 0-3 ms of it). Over each test's
    window each topic is checked against a fixed-rate publisher and its send times rebuilt
    (:func:`mrftcli.segment.runs.rebuild_send_times`), the tick numbering running on through
    missing messages (a dropped command message is one missing tick, not a missing switch; where a
    switch may sit in the gap the window leaves that tick's command free,
    :attr:`mrftcli.mrft.waveform.CommandWindow.free`).

    Parameters
    ----------
    flight : FlightLog
        The log (receive-stamped).
    tests : sequence of MrftTest
        The tests refined.
    history : float
        Command before each test its window carries [s].

    Returns
    -------
    SendTimeWindows
    """
    tc, c = flight.command.t, flight.command.values
    ty, y = flight.output.t, flight.output.values
    windows, cmd, out = [], [], []
    for test in tests:
        # a margin of a few periods either side keeps the window's edges inside the rebuilt stretch
        a, b = np.searchsorted(tc, [test.t_start - history - 0.05, test.t_end + 0.05])
        ya, yb = np.searchsorted(ty, [test.t_start - 0.05, test.t_end + 0.05])
        sc = rebuild_send_times(tc[a:b])
        so = _on_controller_ticks(rebuild_send_times(ty[ya:yb]), sc, ty[ya:yb])
        w = CommandWindow.between(test.t_start, test.t_end, sc.t, c[a:b], so.t, y[ya:yb], test.bias, history)
        if w is not None:
            windows.append(w)
            cmd.append(sc)
            out.append(so)
    return SendTimeWindows(tuple(windows), tuple(cmd), tuple(out))


def _on_controller_ticks(output: SendTimes, command: SendTimes, t_output: np.ndarray) -> SendTimes:
    """A receive-stamped output's rebuild, kept only when its publisher ticks on the controller's
    clock (its period a whole number of command periods).

    A publisher on another clock (HEAR's 90 Hz camera topic under a 200 Hz controller) sends the
    latest sample it holds: which instant each message samples is not known, up to a controller
    period, and its own grid would put the samples 0-5 ms late. An output stamped at the source
    (no spread about its grid) keeps its times whatever its rate.
    """
    if not (output.rebuilt and command.rebuilt) or output.spread < 1e-4:
        return output
    ratio = output.period / command.period
    if abs(ratio - round(ratio)) <= 1e-3 * ratio:
        return output
    return replace(output, t=t_output, rebuilt=False,
                   reason=f"its {1 / output.period:.4g} Hz publisher is not on the controller's {1 / command.period:.4g} "
                          "Hz ticks, so the instant each message samples is not known")


def _refinement_windows(flight: FlightLog, usable: Sequence[MrftTest]
                        ) -> tuple[list[CommandWindow], tuple[str, ...], SendTimeWindows | None]:
    """The refinement's windows, the notes on a receive-stamped log's rebuild, and the rebuild when
    every window is on rebuilt send times.

    All or nothing: a window left on receive times carries its topic's mean lateness into tau
    (+1.5 ms for 0-3 ms) while the rebuilt ones pull the fit to the noise, so the guard would pass
    a biased estimate; on receive times throughout, the jitter fails the guard.
    """
    if flight.timing.stamps == "receive":
        rebuilt = send_time_windows(flight, usable)
        if rebuilt.all_rebuilt:
            return list(rebuilt.windows), rebuilt.notes(), rebuilt
        notes = rebuilt.notes()
    else:
        notes = ()
    windows = refinement_windows(usable, flight.command.t, flight.command.values, flight.output.t,
                                 flight.output.values)
    return windows, notes, None


def waveform_refinement(flight: FlightLog, screening: Screening, cons: Consensus, bounds: Identifiability,
                        mrft_params: Mapping[str, ParameterEstimate], refine_waveform: bool,
                        hint: str) -> WaveformStage:
    """Refine the MRFT estimate by output error on the tests' windows; report it when the data accept it.

    The waveform needs the command as the plant received it: logged below the controller's rate,
    its switch instants are off by up to a logging period, and the refinement is not run. ``hint`` ends the
    warning that the refinement was not used (:attr:`~mrftcli.analyze.options.AnalyzeOptions.diagnose_hint`).
    """
    model, (Td_est, tau_est, K_est) = cons.model, (bounds.Td, bounds.tau, bounds.K)
    usable = screening.usable
    if refine_waveform and screening.ts_ctrl:
        return WaveformStage(None, "mrft", model, Td_est, tau_est, K_est, (),
                             ("the waveform refinement was not run: the command is logged below the controller's rate",))
    if not (refine_waveform and np.isfinite(cons.K.value)):
        return WaveformStage(None, "mrft", model, Td_est, tau_est, K_est, (), ())
    windows, send_notes, send_times = _refinement_windows(flight, usable)
    if not windows:
        return WaveformStage(None, "mrft", model, Td_est, tau_est, K_est, (), ())
    guard = mrft_params
    if send_times is not None:
        # the MRFT estimate read the switches at their receive times: its tau is off by about the
        # mean lateness, which its interval holds only with the jitter folded in
        guard = {**mrft_params, "tau": widen_for_jitter(mrft_params["tau"], flight)[0]}
    # Td bounded from below only: the cost is flat along ln Td, and the fit takes longer
    refinement = refine(windows, model, guard, loop_sign=usable[0].loop_sign,
                        max_evaluations=80 if bounds.td_open else 30)
    if not refinement.accepted:
        return WaveformStage(refinement, "mrft", model, Td_est, tau_est, K_est,
                             ("the waveform refinement was not used (" + "; ".join(refinement.reasons)
                              + "): the MRFT estimate is reported" + hint,), send_notes)
    Td_est, tau_est, K_est = refinement.Td, refinement.tau, refinement.K
    if bounds.td_open:
        # the waveform does not close it either: keep the one-sided statement, with the
        # consensus's profile lower bound (the Gauss-Newton interval of ln Td is a local
        # linearisation, meaningless where the cost is flat in Td: it gave 1e-5 s)
        Td_est = replace(Td_est, ci95_low=mrft_params["Td"].ci95_low, ci95_high=float("nan"), determined=False)
    return WaveformStage(refinement, "waveform", refinement.model, Td_est, tau_est, K_est, (), send_notes,
                         send_times)


def widen_for_jitter(tau_est: ParameterEstimate, flight: FlightLog,
                     send_times: SendTimeWindows | None = None) -> tuple[ParameterEstimate, str | None]:
    """tau with receive-time stamps' jitter in its spread, and the note saying so (None: no jitter).

    Receive-time stamps: the command's and the output's transport delays differ by an unknown
    offset of the order of their jitter, which moves every switch against the output alike (no
    averaging over cycles): added to tau's spread in quadrature. Below 0.1 ms it is stamp rounding,
    not transport. A waveform estimate on the rebuilt send times (``send_times``,
    :func:`send_time_windows`) has the command's lateness removed, its earliest arrivals taken as
    sent on time; a receive-stamped output's earliest arrivals need not be on time against the
    command's (and a publisher that samples between its own ticks, as HEAR's camera topic does,
    spreads them further), so the output's spread about its grid is what is added then.
    """
    if send_times is not None:
        jitter = send_times.output_spread
        text = (f"receive-stamped output: its arrivals' {jitter * 1e3:.1f} ms spread about its grid is folded into "
                "tau's interval (its earliest arrivals need not be on time against the command's)")
    else:
        jitter = float(flight.timing.timing_jitter_s or 0.0)
        text = f"receive-time stamps: {jitter * 1e3:.1f} ms of timing jitter between topics is folded into tau's interval"
    if not (jitter >= 1e-4 and np.isfinite(tau_est.std)):
        return tau_est, None
    std = float(np.hypot(tau_est.std, jitter))
    widen = 1.96 * std - 1.96 * tau_est.std
    return replace(tau_est, std=std, ci95_low=tau_est.ci95_low - widen, ci95_high=tau_est.ci95_high + widen), text


def unbounded_td_or_raise(exc: IdentificationError, model: LoopModel, Td_ref: float,
                          cycles: list[StableCycles], constraints: Sequence[str], B: int,
                           rng: np.random.Generator) -> tuple[IdentificationResult, tuple[Bootstrap, UnboundedTd]]:
    """The Td -> infinity result when the tests fit a plant without linear damping, else ``exc``.

    Returns the identification record of the limit (method ``"unbounded-Td"``) and the bootstrap
    with :func:`mrftcli.mrft.consensus.unbounded_td`'s result. ``model``: eq. (2) with its known Tp.
    """
    if not constraints:
        raise exc
    Tp = model.Tp
    boot = bootstrap(Tp, cycles, Td_ref, constraints, B, rng)
    limit = unbounded_td(Tp, boot)
    if limit is None or not limit.tau[0] >= 0:  # a finite Td fits better, or no plant of eq. (2) does
        raise exc
    tau = bootstrap_estimate(float(limit.tau[0]), limit.tau[1:], float(limit.tau[0]), "s")
    K = bootstrap_estimate(float(limit.K[0]), limit.K[1:], float(limit.K[0]), "")
    Td = ParameterEstimate(limit.Td_limit, float("nan"), limit.Td_low, float("nan"), "s", determined=False, method="mrft")
    ident = IdentificationResult.of(
        Td, tau, K, LoopModel(Tp, limit.Td_limit, tau.value, K.value),
        residual=None, tests=(), method="unbounded-Td", uncertainty="bootstrap", n_draws=B,
        warnings=(f"the UFM slices do not intersect: identified in the limit Td -> infinity, which the tests "
                  f"fit (chi2 {limit.chi2:.1f} for {limit.dof} degrees of freedom)",))
    return ident, (boot, limit)


def beta_used(test: MrftTest, ts_ctrl: float) -> float:
    """The beta a test is identified with: nominal for a low-rate log (:func:`mrftcli.analyze.screen.low_rate_period`), else effective."""
    return float(test.beta_nominal) if ts_ctrl and test.beta_nominal is not None else test.beta_effective


def stable_cycles(test: MrftTest, ts_ctrl: float = 0.0) -> StableCycles:
    """The per-cycle arrays of a test's stable cycles that the consensus reads.

    For a low-rate log (``ts_ctrl`` > 0): the nominal beta and no phase (the switch instants are
    too coarse for it, and the error they share over a test's cycles does not average out).
    """
    st = test.stable
    if ts_ctrl:
        return StableCycles(beta=np.full(len(st), beta_used(test, ts_ctrl)), period=test.period,
                            amplitude=test.amplitude, phase=np.full(len(st), np.nan), h=test.h, index=test.index)
    return StableCycles(beta=np.array([c.beta_effective for c in st]), period=test.period,
                        amplitude=test.amplitude, phase=np.array([c.phase_h1 for c in st]), h=test.h,
                        index=test.index)


def fold_amplitude_ratios(flight: FlightLog, test: MrftTest) -> np.ndarray:
    """A sub-sampled test's amplitude at each harmonic count its fold cannot tell apart, over the
    one it was measured with [-] (:func:`mrftcli.segment.vernier.fold_amplitudes` over its stable
    cycles; [1.0] for a test measured cycle by cycle or when the fold does not compare).

    The ratio is the same for the output as logged (sign, setpoint offset and units cancel).
    """
    st = test.stable
    if test.switch_timing is None or len(st) < 3:
        return np.ones(1)
    t0 = np.array([c.t_start for c in st])
    t2 = np.array([c.t_end for c in st])
    t, y = np.asarray(flight.output.t, float), np.asarray(flight.output.values, float)
    inside = (t >= t0[0]) & (t < t2[-1])
    amps = fold_amplitudes(t[inside], y[inside], t0, t2)
    return amps / amps[0] if amps.size and amps[0] > 0 else np.ones(1)


def widen_for_orbits(model: LoopModel, cycles: list[StableCycles], Td: float, constraints: Sequence[str],
                     ts_ctrl: float, estimates: tuple[ParameterEstimate, ...], rng: np.random.Generator,
                     n_draws: int = 200, shapes: Sequence[np.ndarray] | None = None
                     ) -> tuple[ParameterEstimate, ...]:
    """Td, tau, K with the sampled relay's switching lag and the fold's harmonic count per test
    drawn into the bootstrap.

    A relay sampled at period Ts switches 0..Ts after the crossing of its level; the band centre
    takes Ts / 2, and where in that band a test's cycles settled (its orbits) is common to all its
    cycles and cannot be seen at a lower logging rate: a lag uniform over the band, independent
    between tests. A lag d moves the continuous equivalent's switching level by Omega sqrt(1 -
    beta^2) d (the output's slope at the switch over the amplitude). The draws are made in groups,
    each with one lag per test (stratified over the band, so a few groups span it), and the
    cycles resampled within the group; the 95 % interval is the pooled draws' percentiles about the
    point. Solving each draw, rather than adding a linearised spread in quadrature, keeps the
    interval where the tests put the plant (Td's was [-1.8, 8.0] s: the slices bend as a lag moves
    them, and a symmetric spread crossed zero) and uses the band's uniform spread (95 % within
    +-0.475 Ts, not +-1.96 Ts / sqrt(12)).

    ``shapes``: per test, its amplitude at each harmonic count its fold cannot tell apart over the
    one measured (:func:`fold_amplitude_ratios`); each group draws one per test (stratified as the
    lags), so the amplitude's dependence on that choice, common to the test's cycles, is in the
    interval (K read 1-3 % long from a 3-cycle fold with one harmonic, outside its interval).
    ``model``: eq. (2) with its known Tp.
    """
    Tp, n = model.Tp, len(cycles)
    groups = int(min(max(n_draws // 8, 1), 25))
    per = max(n_draws // groups, 1)
    base = bootstrap(Tp, cycles, Td, constraints, 0, rng)
    strata = np.argsort(rng.random((n, groups)), axis=1)  # each test's lags: one per stratum of the band
    lags = ((strata + rng.random((n, groups))) / groups - 0.5) * ts_ctrl
    # the harmonic count's draws, stratified and independent of the lags' (drawn only where a fold
    # leaves a choice: the other tests' draws stay as they were)
    spread = shapes is not None and any(r.size > 1 for r in shapes)
    picks = np.argsort(rng.random((n, groups)), axis=1) if spread else strata
    draws = []
    for g in range(groups):
        moved = [replace(c, beta=c.beta + _TWO_PI / c.period * np.sqrt(1.0 - c.beta ** 2) * lags[i, g],
                         amplitude=c.amplitude * _shape(shapes, i, picks[i, g], groups))
                 for i, c in enumerate(cycles)]
        b = bootstrap(Tp, moved, Td, constraints, per, rng)
        draws.append(np.column_stack([b.Td[1:], b.tau[1:], b.K[1:]]))
    pooled = np.vstack(draws)
    centre = (base.Td[0], base.tau[0], base.K[0])
    out = []
    for j, est in enumerate(estimates):
        if not np.isfinite(est.std):
            out.append(est)
            continue
        out.append(bootstrap_estimate(est.value, pooled[:, j], float(centre[j]), est.unit))
    return tuple(out)


def _shape(shapes: Sequence[np.ndarray] | None, test: int, stratum: int, groups: int) -> float:
    """The amplitude ratio [-] a group's stratum draws for a test (1 without ``shapes``)."""
    if shapes is None or shapes[test].size <= 1:
        return 1.0
    r = shapes[test]
    return float(r[stratum * r.size // groups])
