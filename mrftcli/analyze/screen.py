"""The screen stage of an analysis: which of the tests found can be used, and the messages when none can.

:func:`screen` takes the tests :func:`mrftcli.segment.segment` found and returns a :class:`Screening`
(the usable tests, the rejected ones with their reasons, the warnings so far); it raises when no test
or a single beta survives. Times a person reads are seconds from the log start (``t0``, :func:`log_start`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

import numpy as np

from ..errors import InsufficientDataError, SegmentationError
from ..io.logtypes import FlightLog, output_unit
from ..mrft.consensus import SAME_BETA
from ..mrft.identify import ufm_slice
from ..mrft.model import LoopModel
from ..segment import MrftTest

__all__ = ["Screening", "screen", "screen_usable", "screen_tests", "irregular_hint", "group_betas", "log_start", "describe_t0", "span", "describe_tests",
           "prefixed_notes", "no_usable_message", "WHICH_LOOP_HINT", "partial_single_beta", "low_rate_period", "ASSUMED_TD_RANGE"]

#: Td range [s] assumed for the partial result of a single-beta log (multirotor drag time constants).
ASSUMED_TD_RANGE = (0.1, 10.0)


@dataclass(frozen=True)
class Screening:
    """The tests of a log sorted into usable and rejected (:func:`screen`).

    Attributes
    ----------
    usable, rejected : tuple of MrftTest
        The tests identification uses, and those left out.
    reasons : Mapping
        ``MrftTest.index`` of each rejected test -> why (one sentence).
    t0 : float
        The log's first sample time [s] (:func:`log_start`).
    ts_ctrl : float
        The controller's period [s] when every test's command is logged below its rate
        (:func:`low_rate_period`), else 0.
    warnings : tuple of str
        The rejections, the tests' own notes, a relay that switched off its nominal beta, the reader's.
    """

    usable: tuple[MrftTest, ...]
    rejected: tuple[MrftTest, ...]
    reasons: Mapping[int, str]
    t0: float
    ts_ctrl: float
    warnings: tuple[str, ...]


def _row(t: MrftTest, t0: float, **extra: Any) -> dict[str, Any]:
    """A test's JSON row without its cycles, with its times from the log start and ``extra`` keys."""
    return {**t.to_dict(cycles=False), "t_start_rel": t.t_start - t0, "t_end_rel": t.t_end - t0, **extra}


def _rejected_rows(tests: Sequence[MrftTest], reasons: Mapping[int, str], t0: float) -> list[dict[str, Any]]:
    """The JSON rows of rejected tests, with the reason."""
    return [_row(t, t0, reason=reasons[t.index]) for t in tests]


def screen(flight: FlightLog, found: Sequence[MrftTest], model: LoopModel, min_stable_cycles: int) -> Screening:
    """The usable tests of a flight (:func:`screen_tests`), with the warnings they raise.

    Parameters
    ----------
    flight : FlightLog
        The log (its path, loop, source and reader warnings go into the messages).
    found : sequence of MrftTest
        The tests the segmenter found.
    model : LoopModel
        Eq. (2) with its known Tp [s] (for the partial result of a single beta).
    min_stable_cycles : int
        Fewest stable cycles for a test to be used.

    Raises
    ------
    SegmentationError
        No test survives (``rejected_tests`` holds every test found, with its reason, for ``--json``).
    InsufficientDataError
        The usable tests share one beta (``partial``: tau over :data:`ASSUMED_TD_RANGE`).
    """
    usable, rejected, reasons, t0, warnings = screen_usable(flight, found, min_stable_cycles)
    if len(group_betas(usable)) < 2:
        raise InsufficientDataError(
            f"{flight.path}: only one beta was tested ({describe_tests(usable, t0)}; times from the log start); "
            f"Td and tau need two tests with "
            f"different betas (e.g. -0.4 and -0.7). Partial result: tau for an assumed Td range "
            f"{ASSUMED_TD_RANGE[0]:g}-{ASSUMED_TD_RANGE[1]:g} s"
            + (f" ({len(rejected)} other test(s) rejected: {'; '.join(reasons[t.index] for t in rejected)})"
               if rejected else ""),
            partial={**partial_single_beta(model, usable, t0), "rejected_tests": _rejected_rows(rejected, reasons, t0)},
        )
    ts_ctrl = low_rate_period(usable)
    for t in usable:
        warnings.extend(prefixed_notes([t], t0))
        # a low-rate log is identified at the nominal beta: its coarse effective beta is expected to differ
        if t.beta_nominal is not None and abs(t.beta_effective - t.beta_nominal) > 0.02 and not ts_ctrl:
            warnings.append(
                f"test at {t.t_start - t0:.1f} s: the relay switched at beta {t.beta_effective:.3f}, not the nominal "
                f"{t.beta_nominal:g} (sampling and noise); identified with the effective value"
            )
    warnings.extend(flight.warnings)
    return Screening(tuple(usable), tuple(rejected), reasons, t0, ts_ctrl, tuple(warnings))


def screen_usable(flight: FlightLog, found: Sequence[MrftTest], min_stable_cycles: int
                  ) -> tuple[list[MrftTest], list[MrftTest], dict[int, str], float, list[str]]:
    """The tests ``analyze`` uses (:func:`screen_tests`) and those it leaves out, the reasons by test index, the
    log's start [s] and one line per test left out ("test at ... left out: reason"); :func:`screen`'s first half,
    which ``delay`` shares.

    Raises
    ------
    SegmentationError
        No test survives (``rejected_tests`` holds every test found, with its reason, for ``--json``).
    """
    t0 = log_start(flight)
    reasons = screen_tests(found, min_stable_cycles)
    usable = [t for t in found if t.index not in reasons]
    rejected = [t for t in found if t.index in reasons]
    if not usable:
        err = SegmentationError(no_usable_message(flight, found, reasons, min_stable_cycles, t0))
        # for ``--json``: what was found and why each test was rejected (read by cli/analyze.py)
        err.rejected_tests = _rejected_rows(found, reasons, t0)
        raise err
    return usable, rejected, reasons, t0, [f"test at {span(t, t0)} left out: {reasons[t.index]}" for t in rejected]


def low_rate_period(tests: Sequence[MrftTest]) -> float:
    """The controller's period [s] when every test's command is logged below it with a nominal beta, else 0.

    Then the logged switch instants are known to a logging period only, and with them the output
    at the switch (the effective beta) and the phase of the fundamental: the tests are identified
    from the nominal beta as a relay sampled at the controller's rate (exact LPRS band centre: the
    continuous cycle with the delay tau + Ts / 2, :func:`mrftcli.mrft.lprs.sampled_limit_cycle`)
    and their frequencies (a mean over many switches, unbiased) and amplitudes.
    """
    if not tests or any(t.controller_rate_hz is None or t.beta_nominal is None for t in tests):
        return 0.0
    return 1.0 / max(t.controller_rate_hz for t in tests if t.controller_rate_hz is not None)


def group_betas(tests: Sequence[MrftTest]) -> list[list[int]]:
    """Indices of tests grouped by beta (nominal when logged, else effective)."""
    groups: list[list[int]] = []
    keys: list[float] = []
    for i, t in enumerate(tests):
        key = t.beta_nominal if t.beta_nominal is not None else t.beta_effective
        for g, k in zip(groups, keys):
            if abs(k - key) < SAME_BETA:
                g.append(i)
                break
        else:
            groups.append([i])
            keys.append(key)
    return groups


def log_start(flight: FlightLog) -> float:
    """The log's first sample time [s]: the earliest timestamp of any series of the flight.

    Real logs carry epoch timestamps (1.7e9 s); people read times relative to this.
    """
    firsts = []
    for s in (flight.command, flight.output, flight.beta, flight.setpoint, flight.battery_voltage):
        if s is not None and len(s):
            idx = s.t
            idx = idx[np.isfinite(idx)]
            if idx.size:
                firsts.append(float(idx.min()))
    return min(firsts) if firsts else 0.0


def describe_t0(t0: float) -> str:
    """The log start for people: a UTC date when it looks like an epoch time, else seconds."""
    if 1e9 <= t0 <= 4e9:  # 2001 .. 2096: an epoch timestamp
        return datetime.fromtimestamp(t0, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC"
    return f"{t0:.3f} s"


def span(t: MrftTest, t0: float) -> str:
    """A test's time span for people: seconds from the log start."""
    return f"{t.t_start - t0:.1f}-{t.t_end - t0:.1f} s"


def prefixed_notes(tests: Sequence[MrftTest], t0: float) -> list[str]:
    """The tests' own notes as warnings, each after the time its test starts [s from ``t0``, the log start]:
    ``"test at 12.3 s: <note>"`` (named so that pytest does not collect it where a test module imports it)."""
    return [f"test at {t.t_start - t0:.1f} s: {n}" for t in tests for n in t.notes]


def describe_tests(tests: Sequence[MrftTest], t0: float = 0.0) -> str:
    parts = []
    for t in tests:
        b = f"beta {t.beta_nominal:g}" if t.beta_nominal is not None else f"beta~{t.beta_effective:.2f}"
        parts.append(f"{b} at {span(t, t0)} ({t.n_stable} stable of {len(t.cycles)} cycles)")
    return "; ".join(parts)


#: how :func:`irregular_hint` ends: marks a reason that carries it
_IRREGULAR_TAIL = "a larger relay height h lifts the cycle above it"


def _off_tolerance(test: MrftTest) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Which regular cycles' periods and which amplitudes lie off the test's medians by more than the
    tolerances the stability criterion applied to it (``period_tolerance``, ``amplitude_tolerance``: the
    capped MAD tolerances, or the stationary caps of a noisy stationary test), and which cycles it could
    count (regular, measured): the criterion's own test (:func:`~mrftcli.segment.stability.stable_cycles`).
    None without medians."""
    med = (test.period_median, test.period_tolerance, test.amplitude_median, test.amplitude_tolerance)
    if not (all(np.isfinite(med)) and test.period_median > 0 and test.amplitude_median > 0):
        return None
    P = np.array([c.period for c in test.cycles], float)
    A = np.array([c.amplitude for c in test.cycles], float)
    reg = np.array([c.regular for c in test.cycles], bool) & np.isfinite(P) & np.isfinite(A)
    return (reg & (np.abs(P - test.period_median) > test.period_tolerance),
            reg & (np.abs(A - test.amplitude_median) > test.amplitude_tolerance), reg)


def irregular_hint(test: MrftTest, min_stable_cycles: int) -> str:
    """What to do about a test with cycles enough but too few of them stable because they scatter.

    Fires on a test of at least ``2 * min_stable_cycles`` cycles, fewer than ``min_stable_cycles`` of them
    stable, where past the start-up transient (the leading cycles off the medians) cycles still fall outside
    the tolerances the stability criterion applied to this test (``period_tolerance`` / ``period_median``,
    ``amplitude_tolerance`` / ``amplitude_median``). Such a test did not lack time: the relay switched
    irregularly, on noise or on an estimate's error that is a large part of the cycle (PX4 SITL's altitude at
    h 0.05: EKF2's error 16-38 % of the cycle in its band, periods 0.35-1.6 s and amplitudes 5-44 mm in one
    test; docs/sitl.md), and a larger relay height lifts the cycle above it. ``""`` otherwise (a short test,
    or one that only converged slowly: "record longer tests" stands).

    Examples
    --------
    A test of ten cycles, four of them off the median period 1.0 s by more than its 6 % tolerance, gets
    ``"; of its 10 cycles 4 periods are off their median (1 s) by over the 6 % the stability criterion
    allowed this test: ..."``.
    """
    found = _off_tolerance(test)
    if found is None or len(test.cycles) < 2 * min_stable_cycles or test.n_stable >= min_stable_cycles:
        return ""
    off_p, off_a, reg = found
    off = off_p | off_a
    first_in = np.flatnonzero(reg & ~off)
    if first_in.size == 0 or not off[first_in[0]:].any():  # none past the transient: a slow start
        return ""
    parts = []
    n_p, n_a = int(off_p.sum()), int(off_a.sum())
    if n_p:
        parts.append(f"{n_p} period{' is' if n_p == 1 else 's are'} off their median ({test.period_median:.3g} s) "
                     f"by over the {test.period_tolerance / test.period_median * 100:.0f} %")
    if n_a:
        parts.append(f"{n_a} amplitude{'' if n_a == 1 else 's'} off their median by over the "
                     f"{test.amplitude_tolerance / test.amplitude_median * 100:.0f} %")
    return (f"; of its {len(test.cycles)} cycles {' and '.join(parts)} the stability criterion allowed this test: "
            "the relay switched irregularly, on noise or an estimate's error that is a large part of the cycle; "
            + _IRREGULAR_TAIL)


def screen_tests(found: Sequence[MrftTest], min_stable_cycles: int, *, eq2: bool = True) -> dict[int, str]:
    """Which tests cannot be used, and why: {MrftTest.index: reason}.

    In order: an output with no oscillation at the relay frequency (SNR or variance share of
    ``MrftTest.validity``, robust even on start-up cycles); too few stable cycles; then, for eq. (2)
    (``eq2``), any other failed validity criterion (phase, beta) and the loop-gain sign, which must
    be the same in every test of one log (one plant, one sign): the tests of the minority sign are
    rejected, and all of them when the signs split evenly (nothing tells which is right). The
    cascade's outer tests (``eq2=False``) take the first two checks only: the phase and beta checks
    compare with eq. (2).
    """
    reasons: dict[int, str] = {}
    for t in found:
        v = t.validity
        if v is not None and not v.follows_relay:
            reasons[t.index] = "the output does not follow this relay: " + "; ".join(v.reasons)
        elif t.n_stable < min_stable_cycles or (eq2 and not np.isfinite(t.beta_effective)):
            reasons[t.index] = f"{t.n_stable} stable cycles (need {min_stable_cycles})" + irregular_hint(
                t, min_stable_cycles)
        elif eq2 and v is not None and not v.ok:
            reasons[t.index] = "not an MRFT limit cycle of this output: " + "; ".join(v.reasons)
    if not eq2:
        return reasons
    kept = [t for t in found if t.index not in reasons]
    signs = np.array([t.loop_sign for t in kept])
    if signs.size and np.unique(signs).size > 1:
        n_pos, n_neg = int((signs > 0).sum()), int((signs < 0).sum())
        keep = 1 if n_pos > n_neg else -1 if n_neg > n_pos else 0
        for t in kept:
            if t.loop_sign != keep:
                reasons[t.index] = (
                    f"the loop gain is {'positive' if t.loop_sign > 0 else 'negative'} here but "
                    f"{'negative' if t.loop_sign > 0 else 'positive'} in {n_neg if t.loop_sign > 0 else n_pos} "
                    "other test(s) of the log: one plant has one sign, so the output is not the relayed signal "
                    "in all of them")
    return reasons


def _topic(flight: FlightLog, key: str, default: str) -> str:
    src = flight.source.get(key) if isinstance(flight.source, dict) else None
    return str(src).split(":")[0] if src else default


def _amp_text(x: float, loop: str) -> str:
    """An output amplitude for people: mm for a position [m], mrad for an angle [rad], else the output's unit."""
    if not np.isfinite(x):
        return "-"
    unit = output_unit(loop)
    if unit in ("m", "rad"):
        return f"{x * 1e3:.2g} m{unit}"
    return f"{x:.3g} output units"


def _median(values: Sequence[float]) -> float | None:
    """Median of the finite values, None when there is none (no All-NaN warning, no 'nan' in a message)."""
    finite = [x for x in values if np.isfinite(x)]
    return float(np.median(finite)) if finite else None


#: how :func:`no_usable_message` ends when the output does not follow the relay: a one-loop command's
#: question (``batch --loop auto``, which tried every loop, drops it)
WHICH_LOOP_HINT = ": is --loop/--output-topic right?"


def no_usable_message(flight: FlightLog, found: Sequence[MrftTest], reasons: Mapping[int, str], min_stable_cycles: int,
                       t0: float) -> str:
    """The one-line SegmentationError when no test survives :func:`screen_tests`."""
    n = len(found)
    cmd = _topic(flight, "command", "the command")
    out = f"{_topic(flight, 'output', 'the output')} {flight.loop}"
    head = f"{flight.path}: {n} relay test(s) found on {cmd}, but "
    lost = [t for t in found if t.validity is not None and not t.validity.follows_relay]
    if lost and len(lost) * 2 >= n:
        v = [t.validity for t in lost if t.validity is not None]
        amp, snr, frac = (_median([getattr(x, k) for x in v]) for k in ("amplitude", "snr", "h1_fraction"))
        if amp is None or snr is None or frac is None:  # no cycle could be measured: no figures to quote
            return head + f"{out} does not follow them (no cycle of it could be measured)" + WHICH_LOOP_HINT
        return (head + f"{out} does not follow them (output amplitude {_amp_text(amp, flight.loop)}, "
                f"{snr:.2g}x the noise at the relay frequency; fraction of variance at the relay frequency "
                f"{frac:.2f})" + WHICH_LOOP_HINT)
    bad = [t for t in found if t.validity is not None and not t.validity.ok and t.index in reasons
           and "stable cycles" not in reasons[t.index]]
    if bad:
        why = "; ".join(f"test at {span(t, t0)}: {reasons[t.index]}" for t in bad)
        return (head + f"{out} is not a limit cycle of them ({why}): is --loop/--output-topic/--command-topic "
                "right?")
    signs = [t for t in found if "loop gain" in reasons.get(t.index, "")]
    if signs:
        return (head + f"the loop gain of {out} has opposite signs in them "
                f"({', '.join(f'{span(t, t0)}: {t.loop_sign:+d}' for t in found)}): the output is not the "
                "signal the relay controls in all of them; is --output-topic right?")
    irregular = [t for t in found if _IRREGULAR_TAIL in reasons.get(t.index, "")]
    advice = ("record longer tests or check for noise/dropouts" if not irregular else
              f"{len(irregular)} of them had cycles enough whose periods or amplitudes scatter beyond the "
              "tolerances the stability criterion allowed (the relay switched irregularly, on noise or an "
              "estimate's error that is a large part of the cycle): fly a larger relay height h")
    return (f"{flight.path}: found {n} relay test(s) but none with {min_stable_cycles} or more stable "
            f"cycles ({describe_tests(found, t0)}; times from the log start); {advice}"
            + (f" (or lower --min-cycles from {min_stable_cycles})" if min_stable_cycles > 3 else ""))


def partial_single_beta(model: LoopModel, tests: Sequence[MrftTest], t0: float = 0.0) -> dict[str, Any]:
    """What one beta can say: tau(Td) over the assumed Td range, per test; with the measured sensor noise
    (``noise``), which ``plan`` uses from the log and from this object alike; ``held_out`` says why nothing is predicted (one test, or one beta)."""
    from .held_out import held_out_eq2
    from .record import measured_noise_std

    Td = np.geomspace(ASSUMED_TD_RANGE[0], ASSUMED_TD_RANGE[1], 9)
    rows = [_row(t, t0, held_out=held.to_json())  # no solve: one beta
            for t, held in zip(tests, held_out_eq2(model, tests, [t.beta for t in tests]))]
    slices: list[dict[str, Any]] = []
    out = {"assumed_Td_range_s": list(ASSUMED_TD_RANGE), "t0": t0, "tests": rows, "tau_for_assumed_Td": slices,
           "noise": {"std": measured_noise_std(tests), "unit": "output units",
                     "source": "median residual of the tests' stable cycle fits"}}
    for t in tests:
        try:
            tau = ufm_slice(model.Tp, t.beta, t.frequency_hz_mean, Td)
        except Exception:  # noqa: BLE001 - a partial result is best effort; never invent a number
            tau = np.full(Td.size, np.nan)
        fin = tau[np.isfinite(tau)]
        slices.append({
            "beta": t.beta, "frequency_hz": t.frequency_hz_mean, "Td_s": Td.tolist(),
            "tau_s": [float(x) if np.isfinite(x) else None for x in tau],
            "tau_range_s": [float(fin.min()), float(fin.max())] if fin.size else None,
        })
    return out


