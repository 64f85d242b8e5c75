"""The segmenter's entry points: :func:`segment` (a :class:`~mrftcli.io.logtypes.FlightLog`) and
:func:`segment_arrays` (numpy arrays), which chain the steps of :mod:`mrftcli.segment`: relay runs and
switch instants (:mod:`.runs`), cycles (:mod:`.cycles`), the stable limit cycle (:mod:`.stability`)
and the validity check (:mod:`.validity`), into :class:`~mrftcli.segment.records.MrftTest` records.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import SegmentationError
from ..io.logtypes import FlightLog
from .cycles import measure_cycles
from .records import MrftTest
from .runs import estimate_rate_hz, find_relay_runs, regularise_times
from .stability import StabilityCriterion, stable_cycles
from .validity import ValidityCriterion, check_limit_cycle

__all__ = ["segment", "segment_arrays"]

#: a switch after at most this many missing command samples is interpolated, after more it is a gap
_MAX_INTERP_SAMPLES = 2
#: a command logged below this rate [Hz] is a logger's sub-sampling of a faster controller (PX4's
#: default 10 Hz logger over its 50 Hz position controller): its switch instants are only bracketed
LOW_RATE_HZ = 25.0


def _missing_before(t: np.ndarray, k: int, dt: float, on_grid: bool, m: int = 8) -> int:
    """Command samples missing just before sample ``k`` (a switch), from times ``t`` [s], period ``dt``.

    On a regular grid (``on_grid``) the gap says it. Receive-time stamps (a bag of header-less
    messages) jitter by a few ms, so one gap of 1.5-2 periods is as often jitter as a lost sample:
    there the offset between the ``m`` stamps after and the ``m`` before, each set averaged about
    its own sample grid, decides (its jitter is that of one stamp divided by sqrt(m / 2)).
    """
    if on_grid:
        return int(round((t[k] - t[k - 1]) / dt)) - 1
    m = int(min(m, k, t.size - k))
    j = np.arange(m)
    offset = np.mean(t[k:k + m] - j * dt) - np.mean(t[k - m:k] - (j - m) * dt)
    return int(round(offset / dt))


def _loop_sign(ty: np.ndarray, yy: np.ndarray, tc: np.ndarray, command: np.ndarray, bias: float,
               t_sw: np.ndarray, up: np.ndarray) -> int:
    """+1 when the output is the relay's feedback as logged, -1 when it is its negative.

    Two pieces of evidence, each scaled by the output's spread: (1) the relay rule itself: an MRFT
    (any beta in (-1, 1), hysteresis included) switches to +h while the error rises, i.e. while the
    output falls, and to -h while it rises, so the mean slope over the eighth of a period before the
    up-switches minus that before the down-switches is negative; (2) a plant of eq. (2) lags the
    relay by more than 90 degrees, so the output is lower on average while the relay is +h. (2) alone
    is weak where the switch is near an extremum (beta near +-1: a hysteresis relay) and (1) where
    the output is flat at the switch (beta near -1); their sum decides. (1) follows the relay, so a
    plant that lags by less than 90 degrees keeps its sign and fails the phase check downstream
    rather than being flipped into a look-alike.
    """
    cmd_at_y = np.interp(ty, tc, command)
    hi_mask = cmd_at_y > bias
    spread = float(np.std(yy)) if yy.size > 1 else 0.0
    if not spread > 0 or not (hi_mask.any() and (~hi_mask).any()):
        return 1
    mean_evidence = (yy[~hi_mask].mean() - yy[hi_mask].mean()) / spread
    slope_evidence = 0.0
    if t_sw.size >= 3:
        win = 0.125 * float(np.median(np.diff(t_sw))) * 2.0
        i_sw = np.searchsorted(ty, t_sw)
        i_pre = np.searchsorted(ty, t_sw - win)
        rise = np.array([yy[b - 1] - yy[a] if b - 1 > a else np.nan for a, b in zip(i_pre, i_sw)])
        ok = np.isfinite(rise)
        if ok[up].any() and ok[~up].any():
            slope_evidence = (np.mean(rise[~up & ok]) - np.mean(rise[up & ok])) / spread
    return -1 if mean_evidence + slope_evidence < 0 else 1


def segment_arrays(
    t_cmd: np.ndarray,
    command: np.ndarray,
    t_y: np.ndarray,
    y: np.ndarray,
    *,
    beta_t: np.ndarray | None = None,
    beta_v: np.ndarray | None = None,
    t_sp: np.ndarray | None = None,
    setpoint: np.ndarray | None = None,
    criterion: StabilityCriterion = StabilityCriterion(),
    min_runs: int = 6,
    validity: ValidityCriterion = ValidityCriterion(),
    controller_rate_hz: float | None = None,
) -> list[MrftTest]:
    """Find the MRFT tests in command/output arrays (steps 1-5 of :mod:`mrftcli.segment`).

    Parameters
    ----------
    t_cmd, command : numpy.ndarray
        Command timestamps [s] (increasing) and values [command units].
    t_y, y : numpy.ndarray
        Output timestamps [s] (increasing) and values [output units].
    beta_t, beta_v : numpy.ndarray, optional
        Beta topic messages (time [s], value).
    t_sp, setpoint : numpy.ndarray, optional
        Setpoint series; when given, outputs are measured relative to it.
    criterion : StabilityCriterion
    min_runs : int
        Fewest relay half-periods for a stretch to count as a test.
    validity : ValidityCriterion
        Thresholds of the limit-cycle validity check stored in ``MrftTest.validity``.
    controller_rate_hz : float, optional
        Rate the relay decides at [Hz], when the command may be logged below it (a logger that
        sub-samples the controller); None: unknown (a switch is then placed mid-way between the two
        command samples around it, as for a continuous relay).

    Returns
    -------
    list of MrftTest
        Possibly with tests that have no stable cycle; empty when no relay stretch exists.
    """
    t_cmd = np.asarray(t_cmd, float)
    command = np.asarray(command, float)
    t_y = np.asarray(t_y, float)
    y = np.asarray(y, float)
    ok = np.isfinite(t_cmd) & np.isfinite(command)
    t_cmd, command = t_cmd[ok], command[ok]
    ok = np.isfinite(t_y) & np.isfinite(y)
    t_y, y = t_y[ok], y[ok]
    breaks = None
    if beta_t is not None and len(beta_t):
        breaks = np.searchsorted(t_cmd, np.asarray(beta_t, float))
    chains = find_relay_runs(command, breaks=breaks, min_runs=min_runs)
    rate_all = estimate_rate_hz(t_cmd)

    tests: list[MrftTest] = []
    prev_end = -np.inf
    for chain in chains:
        i0, i1 = chain[0].start, chain[-1].stop
        # Regularise the command times locally (a margin of a few samples around the test).
        j0, j1 = max(i0 - 4, 0), min(i1 + 4, t_cmd.size)
        t_loc, regularised = regularise_times(t_cmd[j0:j1])
        tc = np.array(t_cmd, copy=True)
        tc[j0:j1] = t_loc
        dt_nom = float(np.median(np.diff(t_cmd[j0:j1])))
        rate = 1.0 / dt_nom if dt_nom > 0 else rate_all
        # the controller's period when the logger sub-samples it (0: not known, or not sub-sampled)
        ctrl = controller_rate_hz if controller_rate_hz and controller_rate_hz > 1.5 * rate else None
        ts_ctrl = 1.0 / ctrl if ctrl else 0.0

        levels = np.array([r.level for r in chain])
        lv_a, lv_b = float(np.median(levels[0::2])), float(np.median(levels[1::2]))
        hi_is_even = lv_a > lv_b
        hi, lo = max(lv_a, lv_b), min(lv_a, lv_b)
        h, bias = (hi - lo) / 2.0, (hi + lo) / 2.0

        # Switches: the first sample of every run after the first one.
        t_sw = np.array([tc[r.start] for r in chain[1:]])
        up = np.array([((k + 1) % 2 == 0) == hi_is_even for k in range(len(chain) - 1)])
        flags_sw: list[set] = []
        for k, r in enumerate(chain[1:]):
            f = set()
            prev = chain[k]
            if r.start - prev.stop > 1:
                f.add("glitch")  # several samples between the levels: the switch instant is not clean
            missing = _missing_before(tc, r.start, dt_nom, regularised) if r.start > 0 else 0
            if 1 <= missing <= _MAX_INTERP_SAMPLES:
                # The switch happened at one of the missing sample instants or at the first sample
                # seen at the new level: take the middle of those (error within +/- (missing+1)/2
                # samples, unbiased). The output at this switch is not used for beta.
                t_sw[k] = 0.5 * (tc[r.start - 1] + dt_nom + tc[r.start])
                f.add("interp")
            elif missing > _MAX_INTERP_SAMPLES:
                f.add("gap")
            if prev.glitch:
                f.add("glitch")
            if rate < LOW_RATE_HZ and not f and r.start > 0:
                # the relay switched at one of the controller's ticks after the last sample at the
                # old level, up to the first at the new one (its timestamp is the controller tick
                # that published it): the mean of those ticks is unbiased. Mid-way between the two
                # samples is early by half a controller period (10 ms for PX4's 50 Hz controller
                # under its 10 Hz logger), which read as a longer tau.
                gap = tc[r.start] - tc[r.start - 1]
                t_sw[k] = 0.5 * (tc[r.start - 1] + tc[r.start]) + (0.5 * ts_ctrl if ts_ctrl < gap else 0.0)
            flags_sw.append(f)

        # Output in the test window (the first to the last switch, with a margin)
        t_a, t_b = t_sw[0], t_sw[-1]
        t_first, t_last = float(tc[chain[0].start]), float(tc[chain[-1].stop - 1])
        m0, m1 = np.searchsorted(t_y, [t_a - 1.0, t_b + 1.0])
        ty, yy = t_y[m0:m1], y[m0:m1]
        if ty.size > 8:
            ty, _ = regularise_times(ty)
        sp_val = None
        if t_sp is not None and setpoint is not None and len(t_sp):
            sp_in = np.asarray(setpoint, float)[(np.asarray(t_sp) >= t_a) & (np.asarray(t_sp) <= t_b)]
            if sp_in.size:
                sp_val = float(np.median(sp_in))
                yy = yy - np.interp(ty, np.asarray(t_sp, float), np.asarray(setpoint, float))
        sign = _loop_sign(ty, yy, tc, command, bias, t_sw, up)
        # a sparsely logged test (even its longest cycle has fewer than 72 output samples) is measured
        # with fewer harmonics where a cycle has fewer than 36; a well-sampled test keeps the full fit,
        # and its short start-up cycles (a noise-triggered switch) stay unmeasured
        t_up = t_sw[up]
        few = False
        if t_up.size > 1 and ty.size > 2:
            few = bool(np.max(np.diff(t_up)) / np.median(np.diff(ty)) < 72)
        cycles = measure_cycles(t_sw, up, flags_sw, ty, sign * yy, 1.0 / rate, h, few_samples=few)
        notes: list[str] = []
        if sign < 0:
            notes.append("the output falls under +h (negative loop gain); amplitudes are magnitudes")
        P = np.array([c.period for c in cycles])
        A = np.array([c.amplitude for c in cycles])
        reg = np.array([c.regular for c in cycles], bool)
        stable, consistent, info = stable_cycles(P, A, reg, 1.0 / rate, criterion)
        final = []
        for k, c in enumerate(cycles):
            fl = set(c.flags)
            if not consistent[k] and c.regular:
                fl.add("outlier")
            if consistent[k] and not stable[k]:
                fl.add("transient")
            final.append(replace(c, flags=tuple(sorted(fl)), stable=bool(stable[k])))
        be = np.array([c.beta_effective for c in final if c.stable])
        be = be[np.isfinite(be)]
        beta_nom = None
        if beta_t is not None and len(beta_t):
            bt = np.asarray(beta_t, float)
            sel = np.flatnonzero((bt > prev_end) & (bt <= t_b))
            if sel.size:
                beta_nom = float(np.asarray(beta_v, float)[sel[-1]])
        n_interp = sum("interp" in c.flags for c in final)
        if n_interp:
            notes.append(f"{n_interp} cycle(s) with a switch after 1-2 missing command samples (instant interpolated)")
        n_gap = sum("gap" in c.flags for c in final)
        n_glitch = sum("glitch" in c.flags for c in final)
        if n_gap:
            notes.append(f"{n_gap} cycle(s) dropped: command messages missing at a switch")
        if n_glitch:
            notes.append(f"{n_glitch} cycle(s) dropped: false switch / glitch in the command")
        tests.append(
            MrftTest(
                index=len(tests), t_start=t_first, t_end=t_last, h=float(h), bias=float(bias),
                beta_nominal=beta_nom,
                beta_effective=float(be.mean()) if be.size else float("nan"),
                beta_effective_std=float(be.std(ddof=1)) if be.size > 1 else float("nan"),
                rate_hz=float(rate), cycles=tuple(final), criterion=criterion,
                period_median=info["period_median"], period_tolerance=info["period_tolerance"],
                amplitude_median=info["amplitude_median"], amplitude_tolerance=info["amplitude_tolerance"],
                loop_sign=sign, setpoint=sp_val, timestamps_regularised=regularised,
                n_switches=len(t_sw), notes=tuple(notes), controller_rate_hz=ctrl,
                validity=check_limit_cycle(final, float(be.mean()) if be.size else float("nan"), beta_nom,
                                           validity),
            )
        )
        prev_end = t_b
    return tests


def segment(
    flight: FlightLog,
    *,
    criterion: StabilityCriterion = StabilityCriterion(),
    min_runs: int = 6,
    validity: ValidityCriterion = ValidityCriterion(),
    controller_rate_hz: float | None = None,
) -> list[MrftTest]:
    """Find the MRFT tests in a flight log and measure their cycles.

    Parameters
    ----------
    flight : FlightLog
        Command, output and optional beta/setpoint signals (times in seconds).
    criterion : StabilityCriterion
        Stable-limit-cycle settings.
    min_runs : int
        Fewest relay half-periods for a stretch of switching to count as a test.
    validity : ValidityCriterion
        Thresholds of the limit-cycle validity check (``MrftTest.validity``).
    controller_rate_hz : float, optional
        Rate the relay decides at [Hz] (see :func:`segment_arrays`); None: the flight's
        ``source["controller_rate_hz"]`` (set by the log layout) when it has one.

    Returns
    -------
    list of MrftTest
        All tests found, in time order (some may have no stable cycle).

    Raises
    ------
    SegmentationError
        When the command never switches between two levels (no relay test at all).
    """
    t_c, c = flight.command.t, flight.command.values
    t_y, y = flight.output.t, flight.output.values
    if t_c.size < 10 or t_y.size < 10:
        raise SegmentationError(
            f"{flight.path}: too few samples (command {t_c.size}, output {t_y.size}) to look for MRFT tests"
        )
    kw = {}
    if flight.beta is not None and len(flight.beta):
        kw["beta_t"], kw["beta_v"] = flight.beta.t, flight.beta.values
    if flight.setpoint is not None and len(flight.setpoint):
        kw["t_sp"], kw["setpoint"] = flight.setpoint.t, flight.setpoint.values
    if controller_rate_hz is None:
        controller_rate_hz = flight.source.get("controller_rate_hz")
    tests = segment_arrays(t_c, c, t_y, y, criterion=criterion, min_runs=min_runs, validity=validity,
                           controller_rate_hz=controller_rate_hz, **kw)
    if not tests:
        span = f"{t_c[-1] - t_c[0]:.1f} s long"
        raise SegmentationError(
            f"{flight.path}: no MRFT relay test in the command ({t_c.size} samples, {span}): it never "
            f"switches back and forth between two levels for {min_runs} or more half-periods; check "
            "--command-topic"
        )
    return tests

