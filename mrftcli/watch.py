"""Follow a flight log while it is written: MRFT tests and the identification as cycles arrive.

:func:`watch` is a generator of typed update records (:class:`TestUpdate`, :class:`EstimateUpdate`,
:class:`WatchEnd`); ``mrft-ident watch`` prints them. It never prints itself.

How the log is followed
-----------------------
* **MCAP** (a file, or the ``.mcap`` inside a ROS 2 bag directory being recorded): read
  incrementally. The byte offset after the last complete top-level record is kept; each poll parses
  only the records that arrived since (a chunk only once it is complete, so a half-written chunk is
  simply waited for) with the ``mcap`` library's record classes, and decodes only the new messages
  (:func:`mrftcli.io.cdr.extract` for CDR, ``json`` for JSON channels). The Footer record (or Data
  End) means the writer closed the file.
* **Anything else** (CSV, ULog, ROS 1 bag, ...): the whole file is read again with
  :func:`mrftcli.io.read_flight` whenever its size changes (a read that fails on a half-written row
  or record is retried at the next poll). The writer has closed the file when it has not grown for
  ``idle`` seconds (this also ends an MCAP whose writer died without a footer).

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

import json
import math
import time
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable, ClassVar, Iterator

import numpy as np

from .errors import InsufficientDataError, LogReadError, MrftError
from .io import DEFAULT_TOPICS, FlightLog, LogSource, Signal, flight_from_source, read_flight
from .io.format_mcap import MCAP_MAGIC, McapChannel, McapRecords, channel_typestore
from .io.logtypes import LOOPS, TopicInfo
from .mrft.consensus import SAME_BETA
from .segment import MrftTest, segment_arrays
from .validate import check_positive

__all__ = ["TestUpdate", "EstimateUpdate", "WatchEnd", "Update", "watch", "McapFollower"]


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

    def to_dict(self) -> dict:
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
    std: dict = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict:
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

    def to_dict(self) -> dict:
        return {"kind": self.kind, **asdict(self)}


Update = TestUpdate | EstimateUpdate | WatchEnd


# --------------------------------------------------------------------------------------------------
# following an MCAP file incrementally
# --------------------------------------------------------------------------------------------------


class McapFollower:
    """The messages of a growing MCAP file, read record by record as they are completed.

    :meth:`poll` parses what arrived since the last call; :meth:`values` gives one topic field's times
    [s] and float64 values so far (the same field paths as :mod:`mrftcli.io`); ``closed`` turns True at
    the Footer (or Data End) record. The records are parsed by :class:`mrftcli.io.format_mcap.McapRecords`,
    as in the MCAP reader's salvage pass.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.offset = 0
        self.closed = False
        self._records = McapRecords()
        self._decoded: dict[int, dict] = {}  # channel id -> leaves tuple -> (t [s] arrays, values)
        self._typestores: dict[int, object] = {}

    def poll(self) -> bool:
        """Read the complete records added since the last poll; True if any message arrived."""
        from mcap.opcode import Opcode

        try:
            with open(self.path, "rb") as fh:
                fh.seek(self.offset)
                data = fh.read()
        except OSError as err:
            raise LogReadError(f"{self.path}: cannot read ({err.strerror})") from None
        pos = 0
        if self.offset == 0:
            if len(data) < len(MCAP_MAGIC):
                return False
            if data[:len(MCAP_MAGIC)] != MCAP_MAGIC:
                raise LogReadError(f"{self.path}: not an MCAP file (bad magic bytes)")
            pos = len(MCAP_MAGIC)
        got = False
        while pos + 9 <= len(data):
            op = data[pos]
            length = int.from_bytes(data[pos + 1:pos + 9], "little")
            end = pos + 9 + length
            if end > len(data):
                break  # a record still being written: wait for the rest
            if op in (Opcode.FOOTER, Opcode.DATA_END):
                self.closed = True
                pos = end
                break
            try:
                got |= self._records.record(op, data[pos + 9:end]) > 0
            except Exception:  # noqa: BLE001 - a damaged record: skip it, keep the framing
                pass
            pos = end
        self.offset += pos
        return got

    def topics(self) -> list[str]:
        """Topic names seen so far."""
        return sorted({c.topic for c in self._records.channels.values()})

    def _find(self, topic: str) -> McapChannel | None:
        for ch in self._records.channels.values():
            if ch.topic == topic:
                return ch
        return None

    def _typestore(self, ch: McapChannel):
        if ch.id not in self._typestores:
            self._typestores[ch.id] = channel_typestore(ch, self.path)
        return self._typestores[ch.id]

    def leaves(self, topic: str, field_path: str | None) -> list[str] | None:
        """The numeric leaves ``topic:field`` stands for (four for a quaternion); None if the topic has
        not appeared yet or (JSON) has no message yet."""
        from .io import cdr

        ch = self._find(topic)
        if ch is None:
            return None
        path = field_path or "data"
        if ch.encoding == "json":
            sample = ch.datas[0] if ch.datas else None
            decoded = self._decoded.get(ch.id)
            if sample is None:
                return list(next(iter(decoded))) if decoded else None
            node = json.loads(sample)
            for key in path.split("."):
                if not isinstance(node, dict) or key not in node:
                    raise LogReadError(f"{self.path}: {topic}: no field {path!r}")
                node = node[key]
            if isinstance(node, dict) and sorted(node) == ["w", "x", "y", "z"]:
                return [f"{path}.{c}" for c in "xyzw"]
            return [path]
        try:
            return cdr.leaf_paths(self._typestore(ch), ch.schema_name, path)
        except LogReadError as err:
            raise LogReadError(f"{self.path}: {topic}: {err}") from None

    def values(self, topic: str, leaves: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Times [s] and values of ``leaves`` of ``topic`` so far (new messages decoded once)."""
        from .io import cdr

        ch = self._find(topic)
        key = tuple(leaves)
        if ch is None:
            return np.zeros(0), {k: np.zeros(0) for k in leaves}
        decoded = self._decoded.setdefault(ch.id, {})
        t_parts, v_parts = decoded.setdefault(key, ([], {k: [] for k in leaves}))
        if ch.datas:
            if len(decoded) > 1:
                raise LogReadError(f"{self.path}: {topic}: read with two field sets")
            t_new = np.asarray(ch.times, dtype=np.int64) / 1e9
            if ch.encoding == "json":
                vals = {k: np.array([_json_leaf(json.loads(d), k) for d in ch.datas], float) for k in leaves}
            else:
                lengths = np.fromiter(map(len, ch.datas), dtype=np.int64, count=len(ch.datas))
                starts = (np.cumsum(lengths) - lengths).astype(np.int64)
                buf = np.frombuffer(b"".join(ch.datas), dtype=np.uint8)
                vals = cdr.extract(self._typestore(ch), ch.schema_name, buf, starts, lengths, list(leaves),
                                   ros1=ch.encoding == "ros1")
            t_parts.append(t_new)
            for k in leaves:
                v_parts[k].append(np.asarray(vals[k], float))
            ch.times, ch.datas = [], []
            if len(t_parts) > 1:  # keep one array per leaf
                t_parts[:] = [np.concatenate(t_parts)]
                for k in leaves:
                    v_parts[k][:] = [np.concatenate(v_parts[k])]
        if not t_parts:
            return np.zeros(0), {k: np.zeros(0) for k in leaves}
        return t_parts[0], {k: v_parts[k][0] for k in leaves}


def _json_leaf(node, path: str) -> float:
    for key in path.split("."):
        node = node.get(key) if isinstance(node, dict) else None
    return float(node) if isinstance(node, (int, float)) else float("nan")


# --------------------------------------------------------------------------------------------------
# snapshots of the flight so far
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Layout:
    """The topic options as given (None: the reference layout's)."""

    loop: str
    command: str | None
    output: str | None
    beta: str | None
    setpoint: str | None
    output_scale: float | None

    def filled(self) -> _Layout:
        """The same with the reference layout's topics and scale in place of None."""
        loop = self.loop
        return _Layout(loop=loop, command=self.command or DEFAULT_TOPICS["command"],
                       output=self.output or DEFAULT_TOPICS[f"output.{loop}"],
                       beta=self.beta or DEFAULT_TOPICS["beta"], setpoint=self.setpoint or DEFAULT_TOPICS["setpoint"],
                       output_scale=1.0 if self.output_scale is None else float(self.output_scale))


class _NotYet(LogReadError):
    """A topic of a file still being written has not appeared, or has no message yet: wait."""


class _FollowedSource(LogSource):
    """The messages a :class:`McapFollower` has read so far, as a :class:`~mrftcli.io.LogSource`, so that
    :func:`mrftcli.io.flight_from_source` applies the same topic logic as to a finished log."""

    format = "mcap"
    default_field = "data"

    def __init__(self, follower: McapFollower, path: Path) -> None:
        super().__init__(path)
        self.follower = follower

    def topics(self) -> list[TopicInfo]:
        return [TopicInfo(name, "", 0, None, ()) for name in self.follower.topics()]

    def missing_topic(self, topic: str) -> LogReadError:
        err = super().missing_topic(topic)
        return err if self.follower.closed else _NotYet(str(err))

    def leaves(self, topic: str, field: str | None) -> list[str]:
        leaves = self.follower.leaves(topic, field)
        if leaves is None:
            raise self.missing_topic(topic)
        return leaves

    def read(self, topic: str, fields: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        t, vals = self.follower.values(topic, fields)
        if t.size == 0 and not self.follower.closed:
            raise _NotYet(f"{self.path}: {topic} has no messages yet")
        return t, vals


class _McapSnapshot:
    """FlightLog so far from a growing MCAP (file, or the one inside a ROS 2 bag directory)."""

    def __init__(self, path: Path, layout: _Layout) -> None:
        self.dir = path if path.is_dir() else None
        self.follower = None if self.dir else McapFollower(path)
        self.layout = layout
        self.path = path

    def poll(self) -> tuple[FlightLog | None, bool, bool]:
        """(flight so far or None, grew, closed)."""
        if self.follower is None:
            files = sorted(self.dir.glob("*.mcap"))
            if not files:
                return None, False, False
            self.follower = McapFollower(files[0])
        f = self.follower
        grew = f.poll()
        return (self._flight() if grew or f.closed else None), grew, f.closed

    def _flight(self) -> FlightLog | None:
        L = self.layout
        try:
            flight = flight_from_source(_FollowedSource(self.follower, self.path), L.loop, L.command, L.output,
                                        L.beta, L.setpoint, output_scale=L.output_scale, layout="reference")
        except _NotYet:
            return None  # a topic the flight needs has not arrived yet: the next poll
        if flight.command.t.size < 10 or flight.output.t.size < 10:
            return None
        flight.source["format"] = "mcap (followed)"
        return flight


class _RereadSnapshot:
    """FlightLog so far by reading the whole file again whenever it grows (CSV, ULog, ...)."""

    def __init__(self, path: Path, layout: _Layout, fmt: str | None) -> None:
        self.path = path
        self.layout = layout
        self.fmt = fmt
        self.size = -1

    def poll(self) -> tuple[FlightLog | None, bool, bool]:
        try:
            size = self.path.stat().st_size
        except OSError:
            return None, False, False
        if size == self.size or size == 0:
            return None, False, False
        self.size = size
        L = self.layout
        # a salvaged (half-written) file is the normal state here: the reader keeps its warnings
        # in FlightLog.warnings instead of printing them (echo_warnings=False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                flight = read_flight(self.path, loop=L.loop, command_topic=L.command, output_topic=L.output,
                                     beta_topic=L.beta, setpoint_topic=L.setpoint, output_scale=L.output_scale,
                                     fmt=self.fmt, echo_warnings=False)
            except LogReadError:
                return None, True, False  # a half-written row/record or topics not there yet: next poll
        return flight, True, False


# --------------------------------------------------------------------------------------------------
# the watch loop
# --------------------------------------------------------------------------------------------------


def _window(sig: Signal | None, t_from: float) -> tuple[np.ndarray, np.ndarray] | tuple[None, None]:
    if sig is None or len(sig) == 0:
        return None, None
    i = int(np.searchsorted(sig.t, t_from, side="left"))
    return sig.t[i:], sig.values[i:]


class _Tracker:
    """Tests so far: closed ones frozen, the open window segmented again at each poll."""

    def __init__(self) -> None:
        self.closed: list[MrftTest] = []
        self.t_from = -math.inf
        self.beta_from = -math.inf

    def update(self, flight: FlightLog) -> list[MrftTest]:
        tc, c = _window(flight.command, self.t_from)
        ty, y = _window(flight.output, self.t_from)
        if tc is None or ty is None or tc.size < 10 or ty.size < 10:
            return list(self.closed)
        kw = {}
        bt, bv = _window(flight.beta, self.beta_from)
        if bt is not None and bt.size:
            kw["beta_t"], kw["beta_v"] = bt, bv
        st, sv = _window(flight.setpoint, self.t_from)
        if st is not None and st.size:
            kw["t_sp"], kw["setpoint"] = st, sv
        found = segment_arrays(tc, c, ty, y, **kw)
        t_last = float(tc[-1])
        open_tests = []
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
    from .analyze import analyze_flight

    if flight is None:
        yield WatchEnd(reason=reason, tests=0, wall_time=time.time(), error="no data in the log",
                       exit_code=LogReadError.exit_code)
        return
    try:
        res = analyze_flight(flight, Tp, min_stable_cycles=min_cycles)
    except (MrftError, InsufficientDataError) as err:
        yield WatchEnd(reason=reason, tests=n_tests, wall_time=time.time(), error=str(err), exit_code=err.exit_code)
        return
    yield EstimateUpdate(
        Td=res.Td.mean, tau=res.tau.mean, K=res.K.mean, tests=tuple(t.index + 1 for t in res.tests),
        betas=tuple(float(t.beta_effective) for t in res.tests),
        t_cycle_end=max(_newest_end(t) for t in res.tests), final=True, wall_time=time.time(),
        std={"Td": res.Td.std, "tau": res.tau.std, "K": res.K.std}, warnings=tuple(res.warnings))
    yield WatchEnd(reason=reason, tests=len(res.tests), wall_time=time.time())


def watch(path: str | Path, Tp: float, *, loop: str = "altitude", command_topic: str | None = None,
          output_topic: str | None = None, beta_topic: str | None = None, setpoint_topic: str | None = None,
          output_scale: float | None = 1.0, min_cycles: int = 3, idle: float = 10.0, poll: float = 0.02,
          fmt: str | None = None, sleep: Callable[[float], None] = time.sleep,
          clock: Callable[[], float] = time.monotonic) -> Iterator[Update]:
    """Follow ``path`` while it is written and yield updates (see the module docstring).

    Parameters
    ----------
    path : str or Path
        An MCAP file, a ROS 2 bag directory with mcap storage, or any log :func:`mrftcli.io.read_flight`
        reads (CSV, ULog, ...). It may not exist yet (it is waited for up to ``idle`` seconds).
    Tp : float
        Known propulsion time constant [s].
    loop, command_topic, output_topic, beta_topic, setpoint_topic, output_scale
        The log layout, as for :func:`mrftcli.io.read_flight`.
    min_cycles : int
        Stable cycles a test needs before it is reported and used.
    idle : float
        Seconds without growth after which the writer is taken to have closed the file [s].
    poll : float
        Seconds between polls of the file [s].
    fmt : str, optional
        Log format (detected when omitted; a missing file or a ``.mcap`` name is followed as MCAP).
    sleep, clock
        Injected for tests (default :func:`time.sleep`, :func:`time.monotonic`).

    Yields
    ------
    TestUpdate, EstimateUpdate or WatchEnd
        The last one is a :class:`WatchEnd`; stop early by closing the generator (Ctrl-C in the CLI).

    Raises
    ------
    LogReadError
        The file never appeared, is not a log, or lacks a required topic once closed.
    """
    Tp = check_positive("Tp", Tp)
    idle = check_positive("idle", idle)
    poll = check_positive("poll", poll)
    if loop not in LOOPS:
        from .errors import InputError

        raise InputError(f"unknown loop {loop!r}; choose one of {', '.join(LOOPS)}")
    path = Path(path)
    layout = _Layout(loop=loop, command=command_topic, output=output_topic, beta=beta_topic,
                     setpoint=setpoint_topic, output_scale=output_scale)
    start = clock()
    while not path.exists() or (path.is_file() and path.stat().st_size == 0):
        if clock() - start > idle:
            raise LogReadError(f"{path}: no such file after waiting {idle:g} s; start the recording first")
        sleep(poll)
    snap = _McapSnapshot(path, layout) if _is_mcap(path, fmt) else _RereadSnapshot(path, layout.filled(), fmt)
    tracker = _Tracker()
    reported: dict[int, int] = {}  # test index -> stable cycles last reported
    flight = None
    last_growth = clock()
    while True:
        new, grew, closed = snap.poll()
        now = clock()
        if grew:
            last_growth = now
        if new is not None:
            flight = new
            tests = tracker.update(flight)
            changed = False
            for test in tests:
                if _usable(test, min_cycles) and reported.get(test.index) != test.n_stable:
                    reported[test.index] = test.n_stable
                    changed = True
                    yield TestUpdate(number=test.index + 1, t_start=test.t_start, t_cycle_end=_newest_end(test),
                                     beta_nominal=test.beta_nominal, beta_effective=test.beta_effective,
                                     frequency_hz=test.frequency_hz_mean, amplitude=test.amplitude_mean, h=test.h,
                                     stable_cycles=test.n_stable, cycles=len(test.cycles), wall_time=time.time())
            if changed:
                est = _estimate(tests, Tp, min_cycles)
                if est is not None:
                    yield est
        if closed or now - last_growth > idle:
            yield from _final(flight, Tp, min_cycles, "closed" if closed else "idle", len(reported))
            return
        sleep(poll)


def _is_mcap(path: Path, fmt: str | None) -> bool:
    if fmt is not None:
        return fmt in ("mcap", "mcap-json", "ros2-mcap")
    if path.is_dir():
        meta = path / "metadata.yaml"
        if meta.is_file():
            return "storage_identifier: mcap" in meta.read_text(errors="replace")
        return any(path.glob("*.mcap"))  # ros2 bag record writes metadata.yaml only at the end
    try:
        with open(path, "rb") as fh:
            return fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC or path.suffix.lower() == ".mcap"
    except OSError:
        return path.suffix.lower() == ".mcap"
