"""The process families' strategy of :func:`mrftcli.analyze.analyze_flight` (``analyze --model NAME``).

Any plant structure and any relay; eq. (2) (:class:`~mrftcli.mrft.model.LoopModel`) takes the
manifold strategy of :mod:`mrftcli.analyze.driver` instead. Stages, each returning a frozen record:

1. windows (:func:`flight_windows`): the parts of the log to use (``--window``), each segmented on
   its own (:func:`mrftcli.segment.segment`);
2. screen: a test needs ``min_stable_cycles`` stable cycles and an output that follows its relay in a
   steady phase; a noisy one (low signal-to-noise) is kept with a note, weighted by its scatter;
3. relay (:func:`mrftcli.segment.relay_type.infer_relay`): MRFT, ideal or hysteresis, levels and bias;
4. response points (:func:`response_points`): ``G(j k Omega) = Y_k / U_k`` on every stable cycle, for
   the harmonics k = 1, 3, 5: exact for a periodic cycle of a linear plant under any relay;
5. identification (:func:`identify_points`) from all tests' points;
6. held out (:func:`held_out`): each test's cycle predicted (exact LPRS under its relay, sampled at the
   controller's rate) by the model identified from the other tests.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import IdentificationError, InputError, SegmentationError
from ..io.logtypes import FlightLog, Signal
from ..mrft.identify import identify
from ..mrft.identify_lti import (STATIC_HARMONIC, LtiIdentification, ResponsePoint, fit_response_points,
                                 static_gain_point)
from ..mrft.model import LoopModel, PlantModel
from ..mrft.relays import RelayLaw
from ..segment import segment
from ..segment.records import MrftTest
from ..segment.relay_type import infer_relay
from ..segment.segmenter import LOW_RATE_HZ, inside_windows
from ..segment.stability import stable_cycles
from ..segment.validity import check_limit_cycle
from .held_out import HeldOut
from .options import AnalyzeOptions, RelayOptions
from .record import AnalysisResult, TestSummary
from .screen import log_start
from .static_gain import StaticGain, is_self_regulating, static_gain
from .smooth_cycle import CycleFit, cycle_fits, effective_relay, predicted_cycle, switching_level

__all__ = ["analyze_family", "response_points", "chattering_cycles", "find_tests", "screen_test", "MeasuredTest",
           "measure_test", "measure_tests", "general_analysis", "flight_windows", "mask_windows", "held_out",
           "identify_points"]

#: harmonics measured on each cycle (odd: a square wave's even harmonics vanish at 50 % duty)
HARMONICS = (1, 3, 5)
#: validity failures that only say the output is noisy (kept, weighted by their scatter) or that
#: compare with eq. (2) (irrelevant to another structure)
_NOISY = {"snr", "h1_fraction", "phase", "beta_mismatch"}
#: floor of a harmonic point's standard errors (relative gain, phase [rad]): see identify_points
_HARMONIC_SE = 0.03


# ----------------------------------------------------------------------------------------------
# stages
# ----------------------------------------------------------------------------------------------
def flight_windows(flight: FlightLog, windows: Sequence[tuple[float, float]]) -> list[FlightLog]:
    """The flight cut to each window [s, log clock] (the whole flight when there is none).

    Raises
    ------
    InputError
        A window with t1 <= t0, or one holding no command sample.
    """
    if not windows:
        return [flight]

    out = []
    for a, b in windows:
        if not b > a:
            raise InputError(f"--window {a:g}:{b:g}: the end must be after the start (seconds from the log start)")
        part = _keep(flight, ((a, b),))
        if len(part.command.t) < 2:
            raise InputError(f"--window {a:g}:{b:g} holds no command samples; the log spans "
                             f"{flight.command.t[0]:.3f}-{flight.command.t[-1]:.3f} s")
        out.append(part)
    return out


def mask_windows(flight: FlightLog, windows: Sequence[tuple[float, float]]) -> FlightLog:
    """The flight with only the samples inside the windows [s, log clock] (eq. (2)'s ``--window``)."""
    if not windows:
        return flight

    flight_windows(flight, windows)  # the same checks
    return _keep(flight, windows)


def _keep(flight: FlightLog, windows: Sequence[tuple[float, float]]) -> FlightLog:
    """Every signal of the flight cut to the samples inside the windows."""
    def keep_opt(s: Signal | None) -> Signal | None:
        return None if s is None else inside_windows(s, windows)

    return dataclasses.replace(flight, command=inside_windows(flight.command, windows),
                               output=inside_windows(flight.output, windows),
                               beta=keep_opt(flight.beta), setpoint=keep_opt(flight.setpoint),
                               battery_voltage=keep_opt(flight.battery_voltage))


def chattering_cycles(test: MrftTest, min_stable_cycles: int) -> MrftTest | None:
    """The test with its stable cycles found again when the relay chatters at its switches, else None.

    A relay without hysteresis switches on the noise near the crossing when the output changes by less
    than the noise per sample (an ideal relay or an MRFT on a slow integrating plant at 50-200 Hz):
    the segmenter absorbs the false switches and flags every cycle ``glitch``, so none is stable
    although the cycles repeat. For a process plant the cycles' response points do not need a clean
    square wave (:func:`response_points` then takes the logged command's own harmonics), so the
    stability criterion and the limit-cycle check are applied again with the glitches allowed.
    """
    if test.n_stable >= min_stable_cycles or not any("glitch" in c.flags for c in test.cycles):
        return None
    regular = np.array([not ({"gap", "irregular"} & set(c.flags)) for c in test.cycles])
    rate = test.decision_rate_hz
    stable, _, _ = stable_cycles(np.array([c.period for c in test.cycles]),
                                 np.array([c.amplitude for c in test.cycles]), regular, 1.0 / rate)
    if int(stable.sum()) < min_stable_cycles:
        return None
    cycles = tuple(dataclasses.replace(c, stable=bool(k)) for c, k in zip(test.cycles, stable))
    levels = np.array([c.beta_effective for c, k in zip(test.cycles, stable) if k], float)
    beta = float(np.nanmean(levels)) if np.isfinite(levels).any() else float("nan")
    return dataclasses.replace(test, cycles=cycles, beta_effective=beta,
                               validity=check_limit_cycle(cycles, beta, test.beta_nominal))


def screen_test(test: MrftTest, min_stable_cycles: int) -> tuple[str, tuple[str, ...]]:
    """(reason to reject or "", notes) for one test of a process plant (``watch --model`` screens the same).

    A noisy output is kept and weighted by its scatter; the phase and beta checks compare with eq. (2),
    not with this structure, so they do not reject.
    """
    if test.n_stable < min_stable_cycles:
        return f"{test.n_stable} stable cycles (fewer than {min_stable_cycles})", ()
    failed = set(test.validity.failed) if test.validity is not None else set()
    hard = failed - _NOISY
    if hard:
        reasons = test.validity.reasons if test.validity is not None else ()
        return "not a limit cycle of its relay: " + ("; ".join(reasons) or ", ".join(sorted(hard))), ()
    if failed & {"snr", "h1_fraction"}:
        v = test.validity
        assert v is not None
        return "", (f"noisy (fundamental {v.snr:.2g}x the noise std, {100 * v.h1_fraction:.0f} % of the "
                    "variance): used, weighted by its cycle-to-cycle scatter",)
    return "", ()


def response_points(flight: FlightLog, test: MrftTest, harmonics: Sequence[int] = HARMONICS,
                    fits: Sequence[CycleFit] | None = None) -> tuple[ResponsePoint, ...]:
    """G(j k Omega) = Y_k / U_k of the test's stable cycles, averaged over the cycles (module docstring).

    Per cycle, the output over the cycle is fitted with a line plus eight harmonics
    (:func:`~mrftcli.analyze.smooth_cycle.cycle_fits`; ``fits`` if already made) and divided by the
    closed-form harmonic of the logged relay square wave, ``U_k = 4 h (1 - e^{-j k Omega d}) / (j k Omega P)``
    (d the time at the high level). The mean over the cycles is the complex mean (a mean of
    magnitudes would be biased upwards by the noise); the standard errors of ln gain and phase are
    the complex scatter per component over sqrt(n - 1), relative to the mean's modulus. A harmonic
    the relay hardly excites (|U_k| below 5 % of |U_1| / k) is skipped.
    """
    rows: dict[int, list[tuple[float, complex]]] = {k: [] for k in harmonics}
    for f in (cycle_fits(flight, test) if fits is None else fits):
        P, d, Y = f.period, f.t_high, f.harmonics
        w = 2 * math.pi / P
        chatter = _command_harmonics(flight.command, f.t_start, P, harmonics) if f.chattered else None
        for k in harmonics:
            if k > Y.size:
                continue
            U = (chatter[k] if chatter is not None
                 else 4 * test.h * (1 - np.exp(-1j * k * w * d)) / (1j * k * w * P))
            if abs(U) < 0.05 * 4 * test.h / (math.pi * k):
                continue
            rows[k].append((k * w, complex(Y[k - 1] / U)))
    points = []
    for k, vals in rows.items():
        if len(vals) < 2:
            continue
        w_k = np.array([v[0] for v in vals])
        G = np.array([v[1] for v in vals])
        # the complex mean: the noise averages out (a mean of magnitudes would be biased upwards by it)
        mean = complex(np.mean(G))
        n = len(vals)
        se = float(np.sqrt(np.mean(np.abs(G - mean) ** 2) / (2 * (n - 1)))) / abs(mean)  # per component, relative
        points.append(ResponsePoint(float(np.mean(w_k)), abs(mean), float(np.angle(mean)), se, se, test.index, k))
    return tuple(points)


def _command_harmonics(command: Signal, t0: float, P: float, harmonics: Sequence[int]) -> dict[int, complex]:
    """The logged command's harmonics over [t0, t0 + P] (held between its samples), scaled as U_k.

    Exact for a zero-order-held command: each sample's level over its hold interval integrates in
    closed form. Used where the relay chattered, so the square wave's closed form does not hold.
    """
    t, u = command.t, command.values
    i0 = max(int(np.searchsorted(t, t0, side="right")) - 1, 0)
    i1 = int(np.searchsorted(t, t0 + P, side="left"))
    edges = np.clip(np.append(t[i0:i1], t0 + P), t0, t0 + P) - t0
    levels = u[i0:i1]
    out = {}
    for k in harmonics:
        jw = 1j * k * 2 * math.pi / P
        # 2/P * integral of u e^{-jw t}: the fit_harmonics convention (amplitude, not half of it)
        out[k] = complex(2.0 / P * np.sum(levels * (np.exp(-jw * edges[:-1]) - np.exp(-jw * edges[1:])) / jw))
    return out


def identify_points(model: PlantModel, points: Sequence[ResponsePoint]) -> LtiIdentification:
    """The fit to the fundamentals and harmonics, the harmonics' standard errors floored at 3 %.

    A sampled relay switches up to a sample late, so consecutive cycles differ slightly and each
    cycle's output carries a little of the previous one's transient; the fundamental hardly notices,
    but the weak third and fifth harmonics are biased by 1-3 % (seen on simulated
    recordings), more than their cycle-to-cycle scatter says.
    """
    floored = [p if p.harmonic == 1 else dataclasses.replace(p, se_log_gain=max(p.se_log_gain, _HARMONIC_SE),
                                                             se_phase=max(p.se_phase, _HARMONIC_SE))
               for p in points]
    if isinstance(model, LoopModel):  # eq. (2) names the UFM's strategy; on response points it is fitted as any structure
        return fit_response_points(floored, model)
    return identify(floored, model)


def held_out(model: PlantModel, test: TestSummary, points: Sequence[ResponsePoint],
             n_h: int | None = None) -> HeldOut:
    """The test's cycle from the model identified on ``points`` (the other tests'), under its relay.

    The relay is the effective one where there is one (:attr:`TestSummary.predicting_relay`): the
    level the smooth waveform had at the switches, which is what a noise-free model must reproduce;
    an MRFT's level is read over the model's own ``n_h``-harmonic amplitude as it was over the test's
    (:func:`~mrftcli.analyze.smooth_cycle.predicted_cycle`; ``n_h`` None: its true amplitude).
    """
    if not any(p.harmonic != STATIC_HARMONIC for p in points):  # the static gain alone is no test
        return HeldOut(None, None, "no other test")
    try:
        fit = identify_points(model, points)
    except IdentificationError as err:
        return HeldOut(None, None, str(err))
    if len(fit.points) * 2 < sum(not e.known for e in fit.estimates):
        return HeldOut(None, None, f"the other tests do not determine {', '.join(fit.undetermined)}")
    note = f"{', '.join(fit.undetermined)} poorly determined by the other tests" if fit.undetermined else ""
    relay = test.predicting_relay
    try:
        lc = predicted_cycle(relay, fit.model, test.rate_hz, n_h)
    except InputError:
        # the model's noise-free cycle never reaches the level (its gain is too low at the recorded
        # frequency): predict at the level relative to the amplitude measured instead (and say so)
        beta = test.switching.beta if test.switching is not None else test.beta_effective
        if not (relay.kind == "hysteresis" and -1 < beta < 1):
            return HeldOut(None, None, "the model has no limit cycle under this relay")
        mrft = RelayLaw("mrft", relay.high, relay.low, beta=beta)
        try:
            lc = predicted_cycle(mrft, fit.model, test.rate_hz, n_h)
        except InputError:
            return HeldOut(None, None, "the model has no limit cycle under this relay")
        note = "; ".join(filter(None, [note, f"the noise-free loop does not reach eps {relay.eps:.3g}: "
                                             f"predicted at the measured switching level (beta {beta:.2f})"]))
    return HeldOut(lc.frequency_hz, lc.amplitude, note)


@dataclass(frozen=True)
class MeasuredTest:
    """One test through screening, its relay and its response points (a stage of :func:`analyze_family`).

    A usable test has ``summary``, ``points``, the test as used (``test``, its chattering cycles
    re-marked) and its per-cycle fits (``fits``); a rejected one has ``rejected`` (index, span [s],
    reason) only. ``diagnose --model`` reuses ``test`` and ``fits`` instead of segmenting again.
    """

    summary: TestSummary | None
    points: tuple[ResponsePoint, ...] = ()
    rejected: tuple[int, float, float, str] | None = None
    test: MrftTest | None = None
    fits: tuple[CycleFit, ...] = ()


def find_tests(flight: FlightLog, windows: Sequence[tuple[float, float]]) -> list[MrftTest]:
    """The relay tests of each window, in the order :func:`analyze_family` numbers them (a window
    without one is skipped; no window: the log's, or the :class:`SegmentationError`)."""
    found: list[MrftTest] = []
    for part in flight_windows(flight, windows):
        try:
            found += segment(part)
        except SegmentationError:
            if not windows:
                raise
    return found


def measure_test(flight: FlightLog, test: MrftTest, relay: RelayOptions, min_stable_cycles: int) -> MeasuredTest:
    """Screen one test; a usable one gets its relay (as inferred and effective) and its response points
    (:func:`measure_tests` per test; ``watch`` per new stable cycle)."""
    chattered = chattering_cycles(test, min_stable_cycles)
    test = chattered or test
    reason, notes = screen_test(test, min_stable_cycles)
    if chattered is not None:
        notes += ("the relay chatters at its switches (it switches on the noise near the crossing): "
                  "the cycles are used with the logged command's own harmonics; a hysteresis of a few "
                  "noise standard deviations avoids it",)
    fits = cycle_fits(flight, test) if not reason else ()
    pts = response_points(flight, test, fits=fits) if not reason else ()
    if not reason and not any(p.harmonic == 1 for p in pts):
        reason = "no cycle long enough to measure its fundamental"
    if reason:
        return MeasuredTest(None, (), (test.index, test.t_start, test.t_end, reason))
    law = infer_relay(test, relay.kind, relay.beta, relay.eps)
    level = switching_level(fits)
    summary = TestSummary(test.index, test.t_start, test.t_end, law, float(test.frequency_hz_mean),
                          float(test.amplitude_mean), test.n_stable, len(test.cycles),
                          test.decision_rate_hz, float(test.beta_effective), notes,
                          switching=level, effective_relay=effective_relay(law, level, test))
    return MeasuredTest(summary, pts, test=test, fits=tuple(fits))


def _no_usable_test(rejected: Sequence[tuple[int, float, float, str]]) -> SegmentationError:
    """The error naming why each test was left out."""
    reasons: dict[str, list[str]] = {}
    for i, _, _, r in rejected:
        reasons.setdefault(r, []).append(str(i + 1))
    return SegmentationError("no usable relay test: " + ("; ".join(f"test(s) {', '.join(ix)}: {r}"
                                                                   for r, ix in reasons.items())
                                                         or "no relay switching found"))


def analyze_family(flight: FlightLog, model: PlantModel, options: AnalyzeOptions) -> AnalysisResult:
    """A process family's unknown parameters from the relay tests of a flight (module docstring).

    The strategy :func:`mrftcli.analyze.analyze_flight` runs for every model but eq. (2): it reads
    ``options.relay`` (what is stated about the relay; the rest is inferred per test),
    ``options.windows``, ``options.min_stable_cycles`` and ``options.baseline`` (the operating point:
    a biased relay's mean levels then measure the static gain, one more constraint of the fit).

    Raises
    ------
    SegmentationError
        No usable relay test.
    InputError
        ``baseline`` on an integrating plant, or under relays symmetric about the command's zero.
    """
    measured = measure_tests(flight, options.relay, options.windows, options.min_stable_cycles)
    return general_analysis(flight, model, measured, options.windows, options.baseline)


def measure_tests(flight: FlightLog, relay: RelayOptions = RelayOptions(),
                  windows: Sequence[tuple[float, float]] = (), min_stable_cycles: int = 3) -> list[MeasuredTest]:
    """Stage 1 of :func:`analyze_family`: every relay test found, numbered in order, screened and measured."""
    return [measure_test(flight, dataclasses.replace(test, index=i), relay, min_stable_cycles)
            for i, test in enumerate(find_tests(flight, windows))]


def _midway_switches(flight: FlightLog, measured: Sequence[MeasuredTest]) -> str:
    """The assumption behind the switch instants of a command logged below ``LOW_RATE_HZ`` with no controller
    rate given ("" when none is made).

    The segmenter then places each switch midway between the last sample at the old level and the first at
    the new one (a relay deciding much faster than the log). A relay that decided at the log's rate
    switched at that first sample, half a sample later: every response point's phase then carries that
    lag, which a free delay absorbs (tau half a sample long) and a known one cannot (K and T pushed apart).
    """
    if flight.timing.controller_rate_hz is not None:
        return ""
    rates = [m.test.rate_hz for m in measured if m.summary is not None and m.test is not None
             and m.test.rate_hz < LOW_RATE_HZ]
    if not rates:
        return ""
    rate = float(np.median(rates))
    return (f"assumed: the relay decided much faster than the {rate:.3g} Hz log, so each switch is placed midway "
            "between the samples around it; if it decided at the log's rate (it switched at the first sample at "
            f"the new level, {500 / rate:.3g} ms later), give --controller-rate {rate:.3g}: otherwise tau reads "
            "that much longer, or, with tau known, the other parameters absorb it")


def general_analysis(flight: FlightLog, model: PlantModel, measured: Sequence[MeasuredTest],
                     windows: Sequence[tuple[float, float]] = (),
                     baseline: tuple[float | Signal, float] | None = None) -> AnalysisResult:
    """Stage 2 of :func:`analyze_family`: ``model`` identified from the measured tests, each held out.

    Raises
    ------
    SegmentationError
        No usable relay test.
    """
    t0 = log_start(flight)
    tests = [m.summary for m in measured if m.summary is not None]
    rejected = [m.rejected for m in measured if m.rejected is not None]
    points = [p for m in measured for p in m.points]
    notes = [f"test {k}: {n}" for k, t in enumerate(tests, 1) for n in t.notes]
    if not tests:
        raise _no_usable_test(rejected)
    midway = _midway_switches(flight, measured)
    if midway:
        notes.insert(0, midway)
    if any(abs(t.relay.bias) > 1e-9 * t.relay.h for t in tests):
        notes.insert(0, "assumed: each relay's bias is balanced by the loop's operating point (the cycle is "
                        "taken about its centre); the response points do not depend on it")
    sg = None
    if baseline is not None:
        sg = _static_gain(flight, model, measured, points, baseline)
        points.append(static_gain_point(sg.value, sg.std / abs(sg.value), points))
        notes.insert(0, f"measured: {sg.describe()}")
    ident = identify_points(model, points)
    if sg is None and "K" in ident.undetermined and any(abs(t.relay.bias) > 1e-9 * t.relay.h for t in tests) \
            and is_self_regulating(model, min(p.omega for p in points)):
        notes.append("the biased relay's mean levels would determine K: give the operating point with --baseline Y0 "
                     "(the output with the command at 0, e.g. the ambient temperature) or --baseline-topic TOPIC: "
                     "K = (mean output - Y0) / mean command")
    # the smooth waveform's harmonics per test (as switching_level read the effective relay over)
    n_hs = {m.summary.index: min(f.harmonics.size for f in m.fits) for m in measured
            if m.summary is not None and m.fits}
    with_held = tuple(dataclasses.replace(t, held_out=held_out(model, t, [p for p in points if p.test != t.index],
                                                               n_hs.get(t.index)))
                      for t in tests)
    return AnalysisResult(flight.path, flight.loop, ident.model, with_held, ident, ident.parameters,
                          warnings=(*ident.warnings, *flight.warnings), notes=tuple(notes), t0=t0,
                          flight=flight,
                          segments=tuple(m.test for m in measured if m.summary is not None and m.test is not None),
                          windows=tuple(windows), static_gain=sg, rejected_spans=tuple(rejected))


def _static_gain(flight: FlightLog, model: PlantModel, measured: Sequence[MeasuredTest],
                 points: Sequence[ResponsePoint], baseline: tuple[float | Signal, float]) -> StaticGain:
    """K from the used tests' mean levels (``--baseline``); InputError on an integrating plant."""
    if not is_self_regulating(model, min(p.omega for p in points)):
        raise InputError(f"--baseline: {model.family} integrates (no static gain): the mean levels say nothing of K; "
                         "leave --baseline out")
    return static_gain(flight, [m.test for m in measured if m.summary is not None and m.test is not None], *baseline)

