"""Follow a flight log while it is written: MRFT tests and the identification as cycles arrive.

:func:`watch` is a generator of typed update records (:class:`TestUpdate`, :class:`EstimateUpdate`,
:class:`Restart`, :class:`WatchEnd`); ``mrft-ident watch`` prints them. It never prints itself.

How the log is followed
-----------------------
:func:`mrftcli.io.follow.follow_log` gives the flight so far at each poll: an MCAP file (or a ROS 2
bag directory with mcap storage) is parsed incrementally and says when its writer closed it; any
other log is read again whenever its size changes. The writer has closed the file when it has not
grown for ``idle`` seconds (this also ends an MCAP whose writer died without a footer). A file that
does not exist yet is waited for (a ground station starts ``watch`` before the logger); one that is
truncated or replaced by another recording is followed from its start again (:class:`Restart`).

Incremental segmentation and identification
-------------------------------------------
Tests are found with :func:`mrftcli.segment.segment_arrays` on a window that starts after the last
*closed* test (one followed by ``max(1 s, 3 periods)`` of command without relay switching), so
the cost of a poll does not grow with the flight. A test is reported (:class:`TestUpdate`) once it
has ``min_cycles`` stable cycles that follow the relay (``MrftTest.valid``), and again at every new
stable cycle. As soon as two betas are in, every update of a test is followed by the identification
(:class:`EstimateUpdate`): the paper's point estimate from the tests' mean effective betas,
frequencies and amplitudes (:func:`mrftcli.mrft.identify.identify`, about a millisecond). When the
writer closes the file, the whole log goes through :func:`mrftcli.analyze.analyze_flight` (the
weighted estimate with bootstrap uncertainty, exactly what ``mrft-ident analyze`` prints) and the last
update has ``final=True``.

Every update carries ``t_cycle_end``, the log time of the newest cycle end it includes, and
``wall_time``, when it was produced (``time.time()``), so that a benchmark can measure the latency
from a cycle's end reaching the file to the updated estimate (benchmarks/bench_watch.py).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Generator, Iterator
from dataclasses import asdict, dataclass, field, replace
from numbers import Integral
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .errors import InputError, InsufficientDataError, LogReadError, MrftError
from .io import FlightLog, ReadOptions, Signal
from .io.follow import follow_log
from .mrft.consensus import SAME_BETA
from .segment import MrftTest, segment_arrays
from .validate import check_positive

__all__ = ["WatchOptions", "TestUpdate", "EstimateUpdate", "WatchEnd", "Restart", "Update", "watch"]


@dataclass(frozen=True)
class WatchOptions:
    """How a log is followed (:func:`watch`), checked on creation.

    Attributes
    ----------
    min_cycles : int
        Stable cycles a test needs before it is reported and used (also the final analysis's
        ``min_stable_cycles``).
    idle : float
        Seconds without growth after which the writer is taken to have closed the file [s].
    poll : float
        Seconds between polls of the file [s].
    wait : float, optional
        Longest wait for the file to appear [s]; None waits until the generator is closed (Ctrl-C).

    Raises
    ------
    InputError
        ``min_cycles`` below 1; ``idle``, ``poll`` or ``wait`` not a positive number.

    Examples
    --------
    >>> WatchOptions(idle=5.0).poll
    0.02
    """

    min_cycles: int = 3
    idle: float = 10.0
    poll: float = 0.02
    wait: float | None = None

    def __post_init__(self) -> None:
        if isinstance(self.min_cycles, bool) or not isinstance(self.min_cycles, Integral) or self.min_cycles < 1:
            raise InputError(f"min_cycles must be a whole number of at least 1, got {self.min_cycles!r}")
        object.__setattr__(self, "idle", check_positive("idle", self.idle))
        object.__setattr__(self, "poll", check_positive("poll", self.poll))
        if self.wait is not None:
            object.__setattr__(self, "wait", check_positive("wait", self.wait))


# --------------------------------------------------------------------------------------------------
# update records
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TestUpdate:
    """A test with enough stable cycles, reported when it first qualifies and at every new cycle.

    Attributes
    ----------
    number : int
        Test number in the log, 1-based.
    t_start, t_cycle_end : float
        The relay's first command sample and the end of the newest stable cycle [s, log time].
    t_log_start : float
        The log's first command sample [s, log time]: a terminal shows test times from it, as analyze does.
    beta_nominal : float or None
        Beta from the beta topic.
    beta_effective : float
        Mean switching level the relay achieved over the stable cycles.
    frequency_hz, amplitude : float
        Limit-cycle frequency [Hz] and output amplitude [output units] (means over stable cycles).
    h : float
        Relay half-height [command units].
    stable_cycles, cycles : int
        Stable and all complete cycles so far.
    wall_time : float
        When the update was produced (``time.time()``) [s].
    """

    __test__: ClassVar[bool] = False
    kind: ClassVar[str] = "test"
    number: int
    t_start: float
    t_cycle_end: float
    beta_nominal: float | None
    beta_effective: float
    frequency_hz: float
    amplitude: float
    h: float
    stable_cycles: int
    cycles: int
    wall_time: float
    t_log_start: float

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **asdict(self)}


@dataclass(frozen=True)
class EstimateUpdate:
    """The identification from the tests so far (two betas or more).

    Attributes
    ----------
    Td, tau : float
        Drag time constant and delay [s].
    K : float
        Gain [output units / (command unit s^2)] (NaN without amplitudes).
    tests : tuple of int
        Numbers of the tests used.
    betas : tuple of float
        Their effective betas.
    t_cycle_end : float
        Newest cycle end included [s, log time].
    final : bool
        True for the last update: the whole log through :func:`mrftcli.analyze.analyze_flight`.
    std : dict
        ``{"Td", "tau", "K"}`` -> bootstrap standard deviation (final update only; else empty).
    warnings : tuple of str
        The identification's warnings.
    wall_time : float
        When the update was produced (``time.time()``) [s].
    """

    kind: ClassVar[str] = "estimate"
    Td: float
    tau: float
    K: float
    tests: tuple[int, ...]
    betas: tuple[float, ...]
    t_cycle_end: float
    final: bool
    wall_time: float
    std: dict[str, float] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **asdict(self)}


@dataclass(frozen=True)
class WatchEnd:
    """The watch stopped: ``reason`` is ``closed`` (MCAP footer), ``idle`` (no growth) or an error.

    ``error`` holds the final analysis's one-line message and ``exit_code`` its code (0 when fine).
    """

    kind: ClassVar[str] = "end"
    reason: str
    tests: int
    wall_time: float
    error: str | None = None
    exit_code: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **asdict(self)}


@dataclass(frozen=True)
class Restart:
    """The followed file was truncated or replaced (a new recording): everything reported before
    belongs to the old one, and the tests are numbered from 1 again.

    Attributes
    ----------
    reason : str
        What was seen (the file shrank, or another file took its name).
    wall_time : float
        When it was noticed (``time.time()``) [s].
    """

    kind: ClassVar[str] = "restart"
    reason: str
    wall_time: float

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **asdict(self)}


Update = TestUpdate | EstimateUpdate | WatchEnd | Restart


# --------------------------------------------------------------------------------------------------
# the watch loop
# --------------------------------------------------------------------------------------------------


def _window(sig: Signal | None, t_from: float) -> Signal | None:
    """The samples of ``sig`` from ``t_from`` [s] on; None when there are none."""
    if sig is None or len(sig) == 0:
        return None
    i = int(np.searchsorted(sig.t, t_from, side="left"))
    return Signal(sig.t[i:], sig.values[i:]) if i < len(sig) else None


class _Tracker:
    """Tests so far: closed ones frozen, the open window segmented again at each poll."""

    def __init__(self) -> None:
        self.closed: list[MrftTest] = []
        self.t_from = -math.inf
        self.beta_from = -math.inf

    def update(self, flight: FlightLog) -> list[MrftTest]:
        cmd = _window(flight.command, self.t_from)
        out = _window(flight.output, self.t_from)
        if cmd is None or out is None or len(cmd) < 10 or len(out) < 10:
            return list(self.closed)
        beta = _window(flight.beta, self.beta_from)
        sp = _window(flight.setpoint, self.t_from)
        found = segment_arrays(cmd, out, beta=beta, setpoint=sp)
        t_last = float(cmd.t[-1])
        open_tests: list[MrftTest] = []
        for test in found:
            test = replace(test, index=len(self.closed) + len(open_tests))
            period = test.period_median if math.isfinite(test.period_median) else 1.0
            if not open_tests and t_last - test.t_end > max(1.0, 3.0 * period):
                self.closed.append(test)
                self.t_from = test.t_end + 1e-9
                self.beta_from = test.t_end + 1e-9
            else:
                open_tests.append(test)
        return self.closed + open_tests


def _usable(test: MrftTest, min_cycles: int) -> bool:
    return test.n_stable >= min_cycles and test.valid and math.isfinite(test.beta_effective)


def _newest_end(test: MrftTest) -> float:
    st = test.stable
    return float(st[-1].t_end) if st else float(test.t_start)


def _estimate(tests: list[MrftTest], Tp: float, min_cycles: int) -> EstimateUpdate | None:
    """The paper's point estimate from the usable tests, when they span two betas or more."""
    from .mrft.identify import TestMeasurement, identify

    use = [t for t in tests if _usable(t, min_cycles)]
    betas = sorted(t.beta_effective for t in use)
    if len(use) < 2 or betas[-1] - betas[0] < SAME_BETA:
        return None
    meas = [TestMeasurement(beta=t.beta_effective, frequency_hz=t.frequency_hz_mean, amplitude=t.amplitude_mean,
                            h=t.h) for t in use]
    try:
        res = identify(meas, Tp, rate_hz=None)
    except MrftError:
        return None
    K = res.K.mean if res.K is not None else float("nan")
    return EstimateUpdate(Td=float(res.model.Td), tau=float(res.model.tau), K=float(K),
                          tests=tuple(t.index + 1 for t in use), betas=tuple(float(t.beta_effective) for t in use),
                          t_cycle_end=max(_newest_end(t) for t in use), final=False, wall_time=time.time(),
                          warnings=tuple(res.warnings))


def _final(flight: FlightLog | None, Tp: float, min_cycles: int, reason: str, n_tests: int
           ) -> Iterator[Update]:
    from .analyze import AnalyzeOptions, analyze_flight

    if flight is None:
        yield WatchEnd(reason=reason, tests=0, wall_time=time.time(), error="no data in the log",
                       exit_code=LogReadError.exit_code)
        return
    try:
        res = analyze_flight(flight, Tp, options=AnalyzeOptions(min_stable_cycles=min_cycles))
    except (MrftError, InsufficientDataError) as err:
        yield WatchEnd(reason=reason, tests=n_tests, wall_time=time.time(), error=str(err), exit_code=err.exit_code)
        return
    yield EstimateUpdate(
        Td=res.Td.mean, tau=res.tau.mean, K=res.K.mean, tests=tuple(t.index + 1 for t in res.tests),
        betas=tuple(float(t.beta_effective) for t in res.tests),
        t_cycle_end=max(_newest_end(t) for t in res.tests), final=True, wall_time=time.time(),
        std={"Td": res.Td.std, "tau": res.tau.std, "K": res.K.std}, warnings=tuple(res.warnings))
    yield WatchEnd(reason=reason, tests=len(res.tests), wall_time=time.time())


def watch(path: str | Path, Tp: float, *, read: ReadOptions | None = None, options: WatchOptions | None = None,
          sleep: Callable[[float], None] = time.sleep,
          clock: Callable[[], float] = time.monotonic) -> Generator[Update, None, None]:
    """Follow ``path`` while it is written and yield updates (see the module docstring).

    Parameters
    ----------
    path : str or Path
        An MCAP file, a ROS 2 bag directory with mcap storage, or any log :func:`mrftcli.io.read_flight`
        reads (CSV, ULog, ...). It may not exist yet: it is waited for (a ground station starts
        ``watch`` before the logger), until the generator is closed or for ``options.wait`` seconds.
    Tp : float
        Known propulsion time constant [s].
    read : ReadOptions, optional
        The loop and the log layout, as for :func:`mrftcli.io.read_flight` (``fmt`` None: detected; a
        missing file or a ``.mcap`` name is followed as MCAP); None: ``ReadOptions()``.
    options : WatchOptions, optional
        Stable cycles per test, idle time, poll interval and the longest wait for the file; None:
        ``WatchOptions()``.
    sleep, clock
        Injected for tests (default :func:`time.sleep`, :func:`time.monotonic`).

    Yields
    ------
    TestUpdate, EstimateUpdate, Restart or WatchEnd
        The last one is a :class:`WatchEnd`; stop early by closing the generator (Ctrl-C in the CLI).
        A :class:`Restart` when the file is truncated or replaced (a new recording): the tests so far
        are forgotten.

    Raises
    ------
    LogReadError
        The file did not appear within ``wait`` seconds, is not a log, or lacks a required topic once
        closed.
    """
    Tp = check_positive("Tp", Tp)
    opts = ReadOptions() if read is None else read
    wopts = WatchOptions() if options is None else options
    min_cycles, idle, poll = wopts.min_cycles, wopts.idle, wopts.poll
    path = Path(path)
    _wait_for(path, wopts.wait, poll, sleep, clock)
    follower = follow_log(path, opts)
    tracker = _Tracker()
    reported: dict[int, int] = {}  # test index -> stable cycles last reported
    flight = None
    last_growth = clock()
    while True:
        snap = follower.poll()
        now = clock()
        if snap.restarted is not None:
            tracker, reported, flight = _Tracker(), {}, None
            yield Restart(reason=snap.restarted, wall_time=time.time())
        if snap.grew:
            last_growth = now
        if snap.flight is not None:
            flight = snap.flight
            tests = tracker.update(flight)
            changed = False
            for test in tests:
                if _usable(test, min_cycles) and reported.get(test.index) != test.n_stable:
                    reported[test.index] = test.n_stable
                    changed = True
                    yield TestUpdate(number=test.index + 1, t_start=test.t_start, t_cycle_end=_newest_end(test),
                                     beta_nominal=test.beta_nominal, beta_effective=test.beta_effective,
                                     frequency_hz=test.frequency_hz_mean, amplitude=test.amplitude_mean, h=test.h,
                                     stable_cycles=test.n_stable, cycles=len(test.cycles), wall_time=time.time(),
                                     t_log_start=float(flight.command.t[0]))
            if changed:
                est = _estimate(tests, Tp, min_cycles)
                if est is not None:
                    yield est
        if snap.closed or now - last_growth > idle:
            yield from _final(flight, Tp, min_cycles, "closed" if snap.closed else "idle", len(reported))
            return
        sleep(poll)


def _wait_for(path: Path, wait: float | None, poll: float, sleep: Callable[[float], None],
              clock: Callable[[], float]) -> None:
    """Return once ``path`` exists and is not empty; LogReadError after ``wait`` seconds (None: never)."""
    start = clock()
    while not path.exists() or (path.is_file() and path.stat().st_size == 0):
        if wait is not None and clock() - start > wait:
            raise LogReadError(f"{path}: no such file after waiting {wait:g} s (--wait); start the recording, "
                               "or wait longer")
        sleep(poll)
