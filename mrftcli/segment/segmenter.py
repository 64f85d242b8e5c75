"""The segmenter's entry points: :func:`segment` (a :class:`~mrftcli.io.logtypes.FlightLog`) and
:func:`segment_arrays` (numpy arrays), which chain the steps of :mod:`mrftcli.segment`: relay runs and
switch instants (:mod:`.runs`), cycles (:mod:`.cycles`), the stable limit cycle (:mod:`.stability`)
and the validity check (:mod:`.validity`), into :class:`~mrftcli.segment.records.MrftTest` records.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError, SegmentationError
from ..io.logtypes import FlightLog, Signal
from ..io.timing import median_rate_hz
from ..validate import check_positive
from .cycles import ON_BOUND, measure_cycles, samples_between
from .records import MrftTest, RelayCycle
from .runs import RelayRun, find_relay_runs, regularise_times
from .stability import StabilityCriterion, stable_cycles
from .validity import ValidityCriterion, check_limit_cycle
from .vernier import TickSwitches, measure_folded, refine_by_waveform, switch_ticks

__all__ = ["segment", "segment_arrays", "SegmentOptions", "MAX_CYCLES", "inside_windows"]

#: relay cycles measured per test at most: a relay test's limit cycle repeats itself, and measuring a
#: cycle costs about a millisecond of CPU (a 14-hour single test holds 50 000 cycles: a minute, per pass)
MAX_CYCLES = 5000
#: a switch after at most this many missing command samples is interpolated, after more it is a gap
_MAX_INTERP_SAMPLES = 2
#: an interval between command samples this many times the median one or longer is absent data (a log
#: masked to some tests' windows, a recorder stopped): it ends a test. A relay's cycle holds 6 samples at
#: least (two runs of 3), so such a gap can hide a whole cycle of the fastest test; shorter losses are
#: a switch's missing samples (``interp`` or ``gap`` at that switch, the test goes on)
_GAP_INTERVALS = 10.0
#: a test's last relay run this many times its median half-period or longer is a relay that stopped
#: switching (locked up: a noise-triggered switch left it waiting for an extremum that never comes, until
#: the safety abort or the test's end): the test ends at the switch into it (:func:`_locked_tail`)
_LOCKED_RUNS = 3.0
#: a command logged below this rate [Hz] is a logger's sub-sampling of a faster controller (PX4's
#: default 10 Hz logger over its 50 Hz position controller): its switch instants are only bracketed
LOW_RATE_HZ = 25.0

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SegmentOptions:
    """How the segmenter finds and judges tests (:func:`segment_arrays`); checked on creation.

    Attributes
    ----------
    criterion : StabilityCriterion
        Stable-limit-cycle settings (step 4).
    min_runs : int
        Fewest relay half-periods for a stretch of switching to count as a test (>= 2).
    validity : ValidityCriterion
        Thresholds of the limit-cycle validity check stored in ``MrftTest.validity`` (step 5).
    controller_rate_hz : float, optional
        Rate the relay decides at [Hz] (> 0), when the command may be logged below it (a logger that
        sub-samples the controller); at the command's own rate (within 1.5x: every decision logged) a
        switch is at the first sample at the new level, however slow the log; None: unknown (a switch is
        then placed mid-way between the two command samples around it, as for a continuous relay).

    Raises
    ------
    InputError
        ``min_runs`` below 2 or not an integer, ``controller_rate_hz`` not a positive number.
    """

    criterion: StabilityCriterion = StabilityCriterion()
    min_runs: int = 6
    validity: ValidityCriterion = ValidityCriterion()
    controller_rate_hz: float | None = None

    def __post_init__(self) -> None:
        # a relay test alternates between two levels: one half-period is no test
        if isinstance(self.min_runs, bool) or not isinstance(self.min_runs, (int, np.integer)) or self.min_runs < 2:
            raise InputError(f"the segmenter's min_runs must be an integer >= 2 (relay half-periods), got "
                             f"{self.min_runs!r}")
        object.__setattr__(self, "min_runs", int(self.min_runs))
        if self.controller_rate_hz is not None:
            object.__setattr__(self, "controller_rate_hz",
                               check_positive("controller rate [Hz]", self.controller_rate_hz))


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
               t_sw: np.ndarray, up: np.ndarray, dt: float) -> int:
    """+1 when the output is the relay's feedback as logged, -1 when it is its negative.

    Two pieces of evidence, each scaled by the output's spread: (1) the relay rule itself: an MRFT
    (any beta in (-1, 1), hysteresis included) switches to +h while the error rises, i.e. while the
    output falls, and to -h while it rises, so the mean slope over the eighth of a period before the
    up-switches minus that before the down-switches is negative; (2) a plant of eq. (2) lags the
    relay by more than 90 degrees, so the output is lower on average while the relay is +h. (2) alone
    is weak where the switch is near an extremum (beta near +-1: a hysteresis relay) and (1) where
    the output is flat at the switch (beta near -1); their sum decides. (1) follows the relay, so a
    plant that lags by less than 90 degrees keeps its sign and fails the phase check downstream
    rather than being flipped into a look-alike. ``dt``: the sample period [s] (a sample on a switch
    instant, within a hundredth of it, is the switch's: :func:`~mrftcli.segment.cycles.samples_between`).
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
        tol = ON_BOUND * dt if dt > 0 else 0.0  # as samples_between: a sample on a switch instant is the new level's
        i_sw = np.searchsorted(ty, t_sw - tol)
        i_pre = np.searchsorted(ty, t_sw - win - tol)
        rise = np.array([yy[b - 1] - yy[a] if b - 1 > a else np.nan for a, b in zip(i_pre, i_sw)])
        ok = np.isfinite(rise)
        if ok[up].any() and ok[~up].any():
            slope_evidence = (np.mean(rise[~up & ok]) - np.mean(rise[up & ok])) / spread
    return -1 if mean_evidence + slope_evidence < 0 else 1


@dataclass(frozen=True, eq=False)
class _Clock:
    """The command's clock around one test.

    Attributes: ``t`` the command times [s] (regularised near the test when they fit a grid),
    ``regularised`` whether they were, ``dt`` the median sample period [s], ``rate_hz`` its inverse
    [Hz], ``controller_rate_hz`` the controller's rate when the logger sub-samples it (else None)
    and ``ts_controller`` its period [s] (0 when unknown); ``every_decision`` the controller's rate is
    known to be the log's (each logged sample a decision: a switch is at its first sample);
    ``irregular`` a slow log sampled at jittered intervals (a recorder every 3 s +-2 s): no grid, so
    no sample is "missing" before a switch.
    """

    t: FloatArray
    regularised: bool
    dt: float
    rate_hz: float
    controller_rate_hz: float | None
    ts_controller: float
    every_decision: bool = False
    irregular: bool = False

    @property
    def sub_sampled(self) -> bool:
        """Logged below :data:`LOW_RATE_HZ` with the controller's rate known: the vernier path."""
        return self.controller_rate_hz is not None and self.rate_hz < LOW_RATE_HZ


@dataclass(frozen=True, eq=False)
class _Switches:
    """The relay's levels and switches in one test.

    Attributes: ``h`` half the distance between the levels and ``bias`` their centre [command
    units]; ``t`` the switch instants [s], ``up`` True at the -h -> +h switches, ``flags`` each
    switch's problems (``"glitch"``, ``"interp"``, ``"gap"``); ``vernier`` the instants on the
    controller's ticks of a test logged below its rate (:func:`~mrftcli.segment.vernier.switch_ticks`).
    """

    h: float
    bias: float
    t: FloatArray
    up: NDArray[np.bool_]
    flags: list[set[str]]
    vernier: TickSwitches | None = None


@dataclass(frozen=True, eq=False)
class _Window:
    """The output around one test: times [s], values relative to the setpoint when it was logged
    [output units], and the setpoint's median over the test (None without one)."""

    t: FloatArray
    y: FloatArray
    setpoint: float | None


def _finite(t: ArrayLike, v: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The samples of a signal whose time [s] and value are both finite."""
    t, v = np.asarray(t, float), np.asarray(v, float)
    ok = np.isfinite(t) & np.isfinite(v)
    if ok.all():  # the usual case: no copy (a 10-million-row log's four signals are 320 MB)
        return t, v
    return t[ok], v[ok]


def _first_cycles(chain: list[RelayRun], t_cmd: FloatArray) -> tuple[list[RelayRun], tuple[str, ...]]:
    """Step 1b: the relay runs of a test's first :data:`MAX_CYCLES` cycles, and the note saying what
    was left out (none when nothing was): the clock, the output window and the cycles measured stay
    bounded however long the relay ran."""
    keep = 2 * MAX_CYCLES + 2  # half-periods (and the run the first switch closes)
    if len(chain) <= keep:
        return chain, ()
    rest = chain[keep:]
    span = float(t_cmd[rest[-1].stop - 1] - t_cmd[rest[0].start])
    return chain[:keep], (f"the relay runs on for {len(rest) // 2} more cycles ({span:.0f} s) after the first "
                          f"{MAX_CYCLES}: only those are measured (the limit cycle repeats itself; each cycle "
                          "measured costs about a millisecond)",)


def _locked_tail(chain: list[RelayRun], t_cmd: FloatArray) -> tuple[list[RelayRun], tuple[str, ...]]:
    """Step 1c: a relay that locked up at the end of a test. Its last run lasts :data:`_LOCKED_RUNS` median
    half-periods or more: the output drifts away under one level (often metres, until a safety abort) and
    no cycle closes there. The switch into that level is the one that went wrong (a noise-triggered switch,
    early: the run before it is cut short, so the cycle that switch closes is short and may still pass as
    stable), so the test ends at the switch before it: the run there is kept as a one-sample run, so its
    switch still closes the last whole cycle, and the drift stays out of the loop sign and of the output
    window; the note says when, in the test's own time."""
    if len(chain) < 5:
        return chain, ()
    lengths = np.array([t_cmd[r.stop - 1] - t_cmd[r.start] for r in chain[1:-1]])
    half = float(np.median(lengths))
    last = chain[-1]
    span = float(t_cmd[last.stop - 1] - t_cmd[last.start])
    if not half > 0 or span < _LOCKED_RUNS * half:
        return chain, ()
    t0 = t_cmd[chain[0].start]
    end = chain[-2]
    return chain[:-2] + [replace(end, stop=end.start + 1)], (
        f"the relay stopped switching {t_cmd[last.start] - t0:.1f} s into the test (one level held {span:.1f} s, "
        f"{span / half:.0f} half-periods: locked up); the test ends at the switch before, "
        f"{t_cmd[end.start] - t0:.1f} s into it",)


def _test_clock(chain: list[RelayRun], t_cmd: FloatArray, rate_all: float | None,
                controller_rate_hz: float | None) -> _Clock:
    """Step 2: the controller's clock over one test (its command times regularised locally)."""
    i0, i1 = chain[0].start, chain[-1].stop
    # Regularise the command times locally (a margin of a few samples around the test).
    j0, j1 = max(i0 - 4, 0), min(i1 + 4, t_cmd.size)
    t_loc, regularised = regularise_times(t_cmd[j0:j1])
    if j0 == 0 and j1 == t_cmd.size:
        tc = t_loc  # the test spans the log (a 14-hour test): no second full-length copy
    else:
        tc = np.array(t_cmd, copy=True)
        tc[j0:j1] = t_loc
    del t_loc
    # the median of a temporary may reorder it in place (no copy of 8 bytes a sample)
    dt_nom = float(np.median(np.diff(t_cmd[j0:j1]), overwrite_input=True))
    rate = 1.0 / dt_nom if dt_nom > 0 else (float("nan") if rate_all is None else rate_all)
    # the controller's period when the logger sub-samples it (0: not known, or not sub-sampled)
    ctrl = controller_rate_hz if controller_rate_hz and controller_rate_hz > 1.5 * rate else None
    return _Clock(tc, regularised, dt_nom, rate, ctrl, 1.0 / ctrl if ctrl else 0.0,
                  every_decision=bool(controller_rate_hz) and ctrl is None,
                  irregular=_irregular(t_cmd[j0:j1], rate))


def _irregular(t: FloatArray, rate: float) -> bool:
    """A slow log (below :data:`LOW_RATE_HZ`) whose intervals spread by over 20 % (interquartile range
    over the median): a recorder with jittered sampling, not a grid with lost samples. Receive stamps
    of a vehicle's 10-50 Hz log jitter by a few ms, a few percent of the period."""
    if not rate < LOW_RATE_HZ or t.size < 8:
        return False
    q25, q50, q75 = np.percentile(np.diff(t), [25, 50, 75])
    return bool(q50 > 0 and (q75 - q25) > 0.2 * q50)


def _switches(chain: list[RelayRun], clock: _Clock) -> _Switches:
    """The relay's two levels and its switch instants: the first sample of every run after the first."""
    levels = np.array([r.level for r in chain])
    lv_a, lv_b = float(np.median(levels[0::2])), float(np.median(levels[1::2]))
    hi_is_even = lv_a > lv_b
    hi, lo = max(lv_a, lv_b), min(lv_a, lv_b)
    tc = clock.t
    t_sw = np.array([tc[r.start] for r in chain[1:]])
    up = np.array([((k + 1) % 2 == 0) == hi_is_even for k in range(len(chain) - 1)])
    flags = []
    for k, r in enumerate(chain[1:]):
        t_k, f = _switch_instant(chain[k], r, clock)
        if t_k is not None:
            t_sw[k] = t_k
        flags.append(f)
    vernier = None
    if clock.sub_sampled and t_sw.size >= 2:
        # the switch ticks from the vernier of every switch's logging bracket (:mod:`.vernier`)
        before = np.array([tc[r.start - 1] for r in chain[1:]])
        after = np.array([tc[r.start] for r in chain[1:]])
        vernier = switch_ticks(before, after, clock.ts_controller)
        t_sw = vernier.t
    return _Switches((hi - lo) / 2.0, (hi + lo) / 2.0, t_sw, up, flags, vernier)


def _switch_instant(prev: RelayRun, run: RelayRun, clock: _Clock) -> tuple[float | None, set[str]]:
    """The instant [s] of the switch into ``run`` when it is not its first sample's time, and its flags."""
    tc, dt_nom = clock.t, clock.dt
    f = set()
    t_k = None
    if run.start - prev.stop > 1:
        f.add("glitch")  # several samples between the levels: the switch instant is not clean
    missing = _missing_before(tc, run.start, dt_nom, clock.regularised) if run.start > 0 and not clock.irregular else 0
    if 1 <= missing <= _MAX_INTERP_SAMPLES:
        # The switch happened at one of the missing sample instants or at the first sample
        # seen at the new level: take the middle of those (error within +/- (missing+1)/2
        # samples, unbiased). The output at this switch is not used for beta.
        t_k = 0.5 * (tc[run.start - 1] + dt_nom + tc[run.start])
        f.add("interp")
    elif missing > _MAX_INTERP_SAMPLES:
        f.add("gap")
    if prev.glitch:
        f.add("glitch")
    if clock.rate_hz < LOW_RATE_HZ and not f and run.start > 0 and not clock.every_decision:
        # the relay switched at one of the controller's ticks after the last sample at the
        # old level, up to the first at the new one (its timestamp is the controller tick
        # that published it): the mean of those ticks is unbiased. Mid-way between the two
        # samples is early by half a controller period (10 ms for PX4's 50 Hz controller
        # under its 10 Hz logger), which read as a longer tau.
        gap = tc[run.start] - tc[run.start - 1]
        ts_ctrl = clock.ts_controller
        t_k = 0.5 * (tc[run.start - 1] + tc[run.start]) + (0.5 * ts_ctrl if ts_ctrl < gap else 0.0)
    return t_k, f


def _output_window(t_y: FloatArray, y: FloatArray, t_sp: ArrayLike | None, setpoint: ArrayLike | None,
                   t_a: float, t_b: float, dt: float, after: float = 1.0) -> _Window:
    """The output from 1 s before the first switch ``t_a`` to ``after`` [s] after the last ``t_b`` [s] (``dt``:
    the sample period [s], for a sample on those bounds: :func:`~mrftcli.segment.cycles.samples_between`)."""
    m0, m1 = samples_between(t_y, t_a - 1.0, t_b + after, dt)
    ty, yy = t_y[m0:m1], y[m0:m1]
    if ty.size > 8:
        ty, _ = regularise_times(ty)
    sp_val = None
    if t_sp is not None and setpoint is not None and len(np.asarray(t_sp)):
        sp_in = np.asarray(setpoint, float)[(np.asarray(t_sp) >= t_a) & (np.asarray(t_sp) <= t_b)]
        if sp_in.size:
            sp_val = float(np.median(sp_in))
            yy = yy - np.interp(ty, np.asarray(t_sp, float), np.asarray(setpoint, float))
    return _Window(ty, yy, sp_val)


def _measured_cycles(sw: _Switches, win: _Window, sign: int, clock: _Clock, criterion: StabilityCriterion,
                     beta_nominal: float | None) -> tuple[list[RelayCycle], dict[str, float]]:
    """Steps 3-4: measure the cycles, flag outliers and transients, mark the stable limit cycle."""
    if clock.sub_sampled:
        return _folded_cycles(sw, win, sign, clock, criterion, beta_nominal)
    # a sparsely logged test (even its longest cycle has fewer than 72 output samples) is measured
    # with fewer harmonics where a cycle has fewer than 36; a well-sampled test keeps the full fit,
    # and its short start-up cycles (a noise-triggered switch) stay unmeasured
    t_up = sw.t[sw.up]
    few = False
    if t_up.size > 1 and win.t.size > 2:
        few = bool(np.max(np.diff(t_up)) / np.median(np.diff(win.t), overwrite_input=True) < 72)
    y = win.y if sign > 0 else -win.y  # not sign * y: no full-length copy when the sign is +1
    cycles = measure_cycles(sw.t, sw.up, sw.flags, win.t, y, 1.0 / clock.rate_hz, sw.h, few_samples=few)
    return _mark_stable(cycles, 1.0 / clock.rate_hz, criterion)


def _folded_cycles(sw: _Switches, win: _Window, sign: int, clock: _Clock, criterion: StabilityCriterion,
                   beta_nominal: float | None) -> tuple[list[RelayCycle], dict[str, float]]:
    """Steps 3-4 below the controller's rate: each cycle against the waveform folded over the test
    (:mod:`.vernier`); a period is a whole number of controller ticks.

    Where the logging locks to the cycle the vernier leaves the up-switches and the down-switches
    each a common shift within their brackets: the relay's own rule decides them. The sampled relay
    switches at the first tick after the output crosses its level (+-beta times the amplitude about
    the centre), so the level is crossed between the tick before the switch and the switch: the
    shifts are those where the mean of the stable cycles' effective beta at the switches and at the
    ticks before them is closest to the nominal beta, at each kind of switch.
    """
    y = sign * win.y
    v = sw.vernier
    if v is None or not v.locked or beta_nominal is None:
        t_sw = refine_by_waveform(v, sw.up, win.t, y) if v is not None and not v.locked else sw.t
        return _folded_pass(sw, t_sw, win.t, y, clock, criterion)
    up_even = bool(sw.up[0])  # the even-numbered switches are the -h -> +h ones
    done: dict[tuple[int, int], tuple[list[RelayCycle], dict[str, float], float, float]] = {}

    def measured(m: tuple[int, int]) -> tuple[list[RelayCycle], dict[str, float], float, float]:
        if m not in done:
            cycles, info = _folded_pass(sw, v.shifted(*m, inside=False), win.t, y, clock, criterion)
            dn, up = _switch_levels(cycles)
            done[m] = (cycles, info, dn, up)
        return done[m]

    def miss(m: tuple[int, int]) -> float:
        me, mo = m
        _, _, dn, up = measured(m)
        _, _, dn_b, _ = measured((me, mo - 1) if up_even else (me - 1, mo))  # down-switches a tick earlier
        _, _, _, up_b = measured((me - 1, mo) if up_even else (me, mo - 1))  # up-switches a tick earlier
        d = float(np.hypot(0.5 * (dn + dn_b) - beta_nominal, 0.5 * (up + up_b) - beta_nominal))
        return d if np.isfinite(d) else float("inf")

    best = min(v.shifts(), key=miss)
    cycles, info, _, _ = measured(best)
    return cycles, info


def _folded_pass(sw: _Switches, t_sw: FloatArray, t_y: FloatArray, y: FloatArray, clock: _Clock,
                 criterion: StabilityCriterion) -> tuple[list[RelayCycle], dict[str, float]]:
    """The cycles at switch instants ``t_sw`` [s], the waveform folded over the regular cycles, then
    again over the stable ones (a start-up cycle's larger swing would distort it)."""
    err = sw.vernier.period_error() if sw.vernier is not None else 0.0
    cycles, info = _mark_stable(measure_folded(t_sw, sw.up, sw.flags, t_y, y, sw.h), clock.ts_controller, criterion,
                                err)
    stable = np.array([c.stable for c in cycles], bool)
    if stable.sum() >= 2:
        cycles, info = _mark_stable(measure_folded(t_sw, sw.up, sw.flags, t_y, y, sw.h, fold=stable),
                                    clock.ts_controller, criterion, err)
    return cycles, info


def _switch_levels(cycles: list[RelayCycle]) -> tuple[float, float]:
    """The stable cycles' mean effective beta at the down- and at the up-switches (NaN without one)."""
    st = [c for c in cycles if c.stable]
    dn = np.array([c.beta_down for c in st], float)
    up = np.array([c.beta_up for c in st], float)
    return _nanmean(dn), _nanmean(up)


def _nanmean(x: FloatArray) -> float:
    """The mean of the finite values (NaN when there is none)."""
    return float(np.nanmean(x)) if np.isfinite(x).any() else float("nan")


def _mark_stable(cycles: list[RelayCycle], dt: float, criterion: StabilityCriterion,
                 period_error: float = 0.0) -> tuple[list[RelayCycle], dict[str, float]]:
    """Step 4: flag outliers and transients and mark the stable limit cycle (``dt``: the period's
    quantum [s], the controller's sample period)."""
    P = np.array([c.period for c in cycles])
    A = np.array([c.amplitude for c in cycles])
    reg = np.array([c.regular for c in cycles], bool)
    stable, consistent, info = stable_cycles(P, A, reg, dt, criterion, period_error)
    final = []
    for k, c in enumerate(cycles):
        fl = set(c.flags)
        if not consistent[k] and c.regular:
            fl.add("outlier")
        if consistent[k] and not stable[k]:
            fl.add("transient")
        final.append(replace(c, flags=tuple(sorted(fl)), stable=bool(stable[k])))
    return final, info


def _nominal_beta(beta_t: ArrayLike | None, beta_v: ArrayLike | None, until: float) -> float | None:
    """The beta marker in force over a test: the last published at or before ``until`` [s], its last switch
    (None without a beta topic or message). A new marker ends a test (:func:`find_relay_runs`' breaks),
    so this is the test's own, published as it starts, or the one in force since an earlier test (a test
    cut in two by absent data keeps it)."""
    if beta_t is None or beta_v is None or not len(np.asarray(beta_t)):
        return None
    bt = np.asarray(beta_t, float)
    sel = np.flatnonzero(bt <= until)
    return float(np.asarray(beta_v, float)[sel[-1]]) if sel.size else None


def _switch_timing(sw: _Switches, beta_nominal: float | None) -> str | None:
    """How a sub-sampled test's switches were placed (``MrftTest.switch_timing``); None at the controller's rate."""
    if sw.vernier is None:
        return None
    if not sw.vernier.locked:
        return "vernier"
    return "vernier-locked-beta" if beta_nominal is not None else "vernier-locked"


def _timing_notes(sw: _Switches, clock: _Clock, beta_nominal: float | None) -> tuple[str, ...]:
    """The assumption a locked logging grid needs (the switches placed by the relay's nominal beta)."""
    if sw.vernier is None or not sw.vernier.locked or not sw.up.size:
        return ()
    spc = clock.rate_hz * float(np.median(np.diff(sw.t[sw.up]))) if sw.up.sum() > 1 else float("nan")
    how = (f"placed where the output crosses the nominal beta {beta_nominal:g}" if beta_nominal is not None
           else "at the middles of their logging brackets (no beta logged)")
    return (f"logged at {clock.rate_hz:.0f} Hz ({spc:.1f} samples a cycle), locked to the cycle: the logging "
            f"instants do not slide along it, so the switches are {how}, not pinned by the vernier",)


def _notes(cycles: list[RelayCycle], sign: int) -> tuple[str, ...]:
    """What the user should know about a test: a negative loop gain, interpolated or dropped switches."""
    notes: list[str] = []
    if sign < 0:
        notes.append("the output falls under +h (negative loop gain); amplitudes are magnitudes")
    n_interp = sum("interp" in c.flags for c in cycles)
    if n_interp:
        notes.append(f"{n_interp} cycle(s) with a switch after 1-2 missing command samples (instant interpolated)")
    n_gap = sum("gap" in c.flags for c in cycles)
    n_glitch = sum("glitch" in c.flags for c in cycles)
    if n_gap:
        notes.append(f"{n_gap} cycle(s) dropped: command messages missing at a switch")
    if n_glitch:
        notes.append(f"{n_glitch} cycle(s) dropped: false switch / glitch in the command")
    return tuple(notes)


def segment_arrays(
    command: Signal,
    output: Signal,
    *,
    beta: Signal | None = None,
    setpoint: Signal | None = None,
    options: SegmentOptions = SegmentOptions(),
) -> list[MrftTest]:
    """Find the MRFT tests in command/output arrays (steps 1-5 of :mod:`mrftcli.segment`).

    Parameters
    ----------
    command : Signal
        Command timestamps [s] (increasing) and values [command units].
    output : Signal
        Output timestamps [s] (increasing) and values [output units].
    beta : Signal, optional
        Beta topic messages (time [s], value [-]).
    setpoint : Signal, optional
        Setpoint series [s, output units]; when given, outputs are measured relative to it.
    options : SegmentOptions
        The stability and validity criteria, the fewest half-periods of a test, the controller's rate.

    Returns
    -------
    list of MrftTest
        Possibly with tests that have no stable cycle; empty when no relay stretch exists.
    """
    t_cmd, cmd = _finite(command.t, command.values)
    t_y, y = _finite(output.t, output.values)
    beta_t = beta_v = t_sp = sp = None
    if beta is not None:
        beta_t, beta_v = beta.t, beta.values
    if setpoint is not None:
        t_sp, sp = setpoint.t, setpoint.values
    criterion, min_runs, controller_rate_hz = options.criterion, options.min_runs, options.controller_rate_hz
    breaks = None
    if beta_t is not None and len(beta_t):
        breaks = np.searchsorted(t_cmd, np.asarray(beta_t, float))
    rate_all = median_rate_hz(t_cmd)
    # below the controller's rate a fast test's half-period is 2 logged samples (a 2.5 Hz cycle at 10 Hz)
    sub = bool(controller_rate_hz and rate_all and rate_all < LOW_RATE_HZ and controller_rate_hz > 1.5 * rate_all)
    chains = find_relay_runs(cmd, breaks=breaks, gaps=_data_gaps(t_cmd, rate_all), min_runs=min_runs,
                             min_run_samples=2 if sub else 3)
    tests: list[MrftTest] = []
    for found in chains:
        chain, cut = _first_cycles(found, t_cmd)
        chain, locked = _locked_tail(chain, t_cmd)
        cut += locked
        clock = _test_clock(chain, t_cmd, rate_all, controller_rate_hz)
        sw = _switches(chain, clock)
        t_b = float(sw.t[-1])
        # after a locked-up relay the output drifts away: the window stops a median half-period after its switch
        after = min(1.0, float(np.median(np.diff(sw.t)))) if locked else 1.0
        win = _output_window(t_y, y, t_sp, sp, float(sw.t[0]), t_b, clock.dt, after)
        sign = _loop_sign(win.t, win.y, clock.t, cmd, sw.bias, sw.t, sw.up, clock.dt)
        beta_nom = _nominal_beta(beta_t, beta_v, t_b)
        final, info = _measured_cycles(sw, win, sign, clock, criterion, beta_nom)
        be = np.array([c.beta_effective for c in final if c.stable])
        be = be[np.isfinite(be)]
        beta_eff = float(be.mean()) if be.size else float("nan")
        tests.append(
            MrftTest(
                index=len(tests), t_start=float(clock.t[chain[0].start]), t_end=float(clock.t[chain[-1].stop - 1]),
                h=float(sw.h), bias=float(sw.bias), beta_nominal=beta_nom, beta_effective=beta_eff,
                beta_effective_std=float(be.std(ddof=1)) if be.size > 1 else float("nan"),
                rate_hz=float(clock.rate_hz), cycles=tuple(final), criterion=criterion,
                period_median=info["period_median"], period_tolerance=info["period_tolerance"],
                amplitude_median=info["amplitude_median"], amplitude_tolerance=info["amplitude_tolerance"],
                loop_sign=sign, setpoint=win.setpoint, timestamps_regularised=clock.regularised,
                n_switches=len(sw.t), notes=_notes(final, sign) + _timing_notes(sw, clock, beta_nom) + cut,
                controller_rate_hz=clock.controller_rate_hz, switch_timing=_switch_timing(sw, beta_nom),
                validity=check_limit_cycle(final, beta_eff, beta_nom, options.validity),
            )
        )
    return tests


def _data_gaps(t: FloatArray, rate_hz: float | None) -> NDArray[np.intp]:
    """Indices of the command samples after absent data: an interval of :data:`_GAP_INTERVALS` median
    intervals or more before them (``rate_hz``: the command's median rate [Hz]; None: no gaps)."""
    if not rate_hz or t.size < 2:
        return np.zeros(0, dtype=np.intp)
    return np.flatnonzero(np.diff(t) >= _GAP_INTERVALS / rate_hz) + 1


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
        ``timing.controller_rate_hz`` (set by the log layout) when it has one.

    Returns
    -------
    list of MrftTest
        All tests found, in time order (some may have no stable cycle).

    Raises
    ------
    SegmentationError
        When the command never switches between two levels (no relay test at all).
    """
    t_c, t_y = flight.command.t, flight.output.t
    if t_c.size < 10 or t_y.size < 10:
        raise SegmentationError(
            f"{flight.path}: too few samples (command {t_c.size}, output {t_y.size}) to look for MRFT tests"
        )
    if controller_rate_hz is None:
        controller_rate_hz = flight.timing.controller_rate_hz
    options = SegmentOptions(criterion=criterion, min_runs=min_runs, validity=validity,
                             controller_rate_hz=controller_rate_hz)
    tests = _LAST.get(flight, options)
    if tests is None:
        beta = flight.beta if flight.beta is not None and len(flight.beta) else None
        setpoint = flight.setpoint if flight.setpoint is not None and len(flight.setpoint) else None
        tests = segment_arrays(flight.command, flight.output, beta=beta, setpoint=setpoint, options=options)
        windows = _logged_windows(flight)
        if not tests and windows:
            # between a stack's logged tests (PX4: MRFT_<AXIS>_ENABLE) the command is the loop's own controller,
            # whose output (a rate controller's torque on gyro noise) can change as much per sample as the
            # relay's switches: a threshold set on the whole log hides them, so look inside the windows
            tests = segment_arrays(inside_windows(flight.command, windows), inside_windows(flight.output, windows),
                                   beta=None if beta is None else inside_windows(beta, windows),
                                   setpoint=None if setpoint is None else inside_windows(setpoint, windows),
                                   options=options)
        _LAST.keep(flight, options, tests)
    if not tests:
        span = f"{t_c[-1] - t_c[0]:.1f} s long"
        raise SegmentationError(
            f"{flight.path}: no MRFT relay test in the command ({t_c.size} samples, {span}): it never "
            f"switches back and forth between two levels for {min_runs} or more half-periods; check "
            "--command-topic"
        )
    return list(tests)


def _logged_windows(flight: FlightLog) -> list[tuple[float, float]]:
    """The tests' windows [s] the log states (``source["test_windows"]``: a stack's enable parameter), each
    widened by 0.25 s; empty when it states none."""
    out = []
    for w in flight.source.get("test_windows") or ():
        a, b = float(w[0]), (float(w[1]) if w[1] is not None else np.inf)
        out.append((a - 0.25, b + 0.25))
    return out


def inside_windows(sig: Signal, windows: Sequence[tuple[float, float]]) -> Signal:
    """The samples of ``sig`` inside any of ``windows`` [s] (ends included)."""
    keep = np.zeros(sig.t.size, dtype=bool)
    for a, b in windows:
        keep |= (sig.t >= a) & (sig.t <= b)
    return Signal(sig.t[keep], sig.values[keep])


class _LastSegmentation:
    """The last flight segmented, by identity, with its options and tests.

    A use case may segment one flight twice: ``diagnose`` lets ``analyze`` segment it, and segments
    it again when analyze refuses the log (one beta); on a 14-hour log each pass measures 50 000
    cycles (about a minute of CPU), so the second is taken from here. A :class:`FlightLog` is frozen
    and its arrays are not written after reading; only a weak reference to it is kept, and the
    tests are let go with it. One entry, replaced whole (a thread never sees half of one).
    """

    def __init__(self) -> None:
        self._entry: tuple[weakref.ref[FlightLog], SegmentOptions, tuple[MrftTest, ...]] | None = None

    def get(self, flight: FlightLog, options: SegmentOptions) -> list[MrftTest] | None:
        """The tests of ``flight`` segmented with ``options`` when they are the last ones, else None."""
        entry = self._entry
        if entry is not None and entry[0]() is flight and entry[1] == options:
            return list(entry[2])
        return None

    def keep(self, flight: FlightLog, options: SegmentOptions, tests: list[MrftTest]) -> None:
        """Remember ``tests`` as the segmentation of ``flight`` with ``options``."""
        self._entry = (weakref.ref(flight, self._forget), options, tuple(tests))

    def _forget(self, ref: weakref.ref[FlightLog]) -> None:
        """The flight is gone: let its tests go (unless a newer flight took the entry)."""
        entry = self._entry
        if entry is not None and entry[0] is ref:
            self._entry = None


_LAST = _LastSegmentation()

