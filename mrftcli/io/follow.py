"""Follow a flight log while it is written: the :class:`~mrftcli.io.logtypes.FlightLog` so far, at each poll.

* **MCAP** (a file, or the ``.mcap`` inside a ROS 2 bag directory being recorded): read
  incrementally by :class:`McapFollower`. The byte offset after the last complete top-level record
  is kept; each poll parses only the records that arrived since (a chunk only once it is complete,
  so a half-written chunk is simply waited for) with the ``mcap`` library's record classes, and
  decodes only the new messages (:func:`mrftcli.io.cdr.extract` for CDR, ``json`` for JSON
  channels). The Footer record (or Data End) means the writer closed the file.
* **Anything else** (CSV, ULog, ROS 1 bag, ...): the whole file is read again with
  :func:`mrftcli.io.read_flight` whenever its size changes (a read that fails on a half-written row
  or record is retried at the next poll). Such a file never says it is closed: the caller decides
  from how long it has not grown.

A file that shrinks, or whose inode changes (another file renamed onto the name), is a new
recording: the follower starts over and says so in :attr:`Snapshot.restarted`.

:func:`follow_log` picks the follower; each :meth:`LogFollower.poll` returns a :class:`Snapshot`.
The same topic logic as for a finished log applies (:func:`mrftcli.io.flight.read_loop`).
"""

from __future__ import annotations

import warnings
from collections.abc import Collection
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from ..errors import InputError, LogReadError
from . import cdr
from .flight import DEFAULT_TOPICS, ReadOptions, layout_loop, read_loop, role_specs
from .format_mcap import (MCAP_MAGIC, McapChannel, McapRecords, channel_leaves, channel_typestore, channel_values,
                          json_leaves)
from .layouts import get_layout
from .logtypes import FlightLog, TopicInfo
from .source import LogSource, parse_spec

if TYPE_CHECKING:
    from mcap.records import Channel, Schema
    from rosbags.typesys.store import Typestore

__all__ = ["Snapshot", "LogFollower", "McapFollower", "follow_log", "is_mcap"]

#: per channel, per field set: the times [s] and values decoded so far (one array each)
_Decoded = dict[tuple[str, ...], tuple[list[np.ndarray], dict[str, list[np.ndarray]]]]


@dataclass(frozen=True)
class Snapshot:
    """One poll of a followed log.

    Attributes
    ----------
    flight : FlightLog or None
        The flight so far, when the poll brought something new and every required topic is in;
        None otherwise.
    grew : bool
        The file grew since the last poll.
    closed : bool
        The writer closed the file (MCAP Footer or Data End record).
    restarted : str or None
        Why the follower started over since the last poll (the file shrank, or another file took
        its name: a new recording); None when it did not. What was read before belongs to the old
        recording.
    """

    flight: FlightLog | None
    grew: bool
    closed: bool
    restarted: str | None = None


#: bytes at the start of a followed file compared at each poll: another recording differs there
_HEAD_BYTES = 4096

#: what identifies the file being followed: (inode, size [bytes], its first bytes)
_Identity = tuple[int, int, bytes]


def _identity(path: Path) -> _Identity | None:
    """(inode, size [bytes], first :data:`_HEAD_BYTES` bytes) of ``path``; None when it cannot be read."""
    try:
        st = path.stat()
        with open(path, "rb") as fh:
            head = fh.read(_HEAD_BYTES)
    except OSError:
        return None
    return st.st_ino, st.st_size, head


def _replaced(before: _Identity | None, now: _Identity | None) -> str | None:
    """Why the file at a path is not the one read before (a new recording), or None.

    It shrank; another file took the name (inode); or its first bytes changed (truncated and
    rewritten between two polls, already longer than before).
    """
    if before is None or now is None:
        return None
    if now[0] != before[0]:
        return "another file took its name"
    if now[1] < before[1]:
        return f"the file shrank from {before[1]} to {now[1]} bytes"
    k = min(len(before[2]), len(now[2]))
    if now[2][:k] != before[2][:k]:
        return "the file was rewritten from its start"
    return None


class LogFollower(Protocol):
    """A log being followed: :meth:`poll` gives the flight so far."""

    def poll(self) -> Snapshot:
        """Read what the writer added since the last poll."""


class _WantedRecords(McapRecords):
    """:class:`~mrftcli.io.format_mcap.McapRecords` keeping the bytes of the channels of ``topics`` only.

    A followed file's channels appear as it is written, so the channel ids to keep are not known at
    the start: each Channel record of a wanted topic adds its id to ``keep`` as it is registered
    (before the messages of the chunk that declares it are gathered). Other channels (a camera)
    cost their log times only.
    """

    def __init__(self, topics: frozenset[str]) -> None:
        super().__init__(keep=frozenset())
        self.topics = topics

    def add_channel(self, rec: Channel, schema: Schema | None) -> None:
        super().add_channel(rec, schema)
        if rec.topic in self.topics and self.keep is not None:
            self.keep = self.keep | {rec.id}


class McapFollower:
    """The messages of a growing MCAP file, read record by record as they are completed.

    :meth:`poll` parses what arrived since the last call; :meth:`values` gives one topic field's times
    [s] and float64 values so far (the same field paths as :mod:`mrftcli.io`); ``closed`` turns True at
    the Footer (or Data End) record. The records are parsed by :class:`mrftcli.io.format_mcap.McapRecords`,
    as in the MCAP reader's salvage pass.

    Parameters
    ----------
    path : str or Path
        The MCAP file being written.
    topics : collection of str, optional
        The topics whose messages are kept (the others' bytes are dropped as they are parsed: a
        follower of a camera bag holds the loop's topics only); None keeps every topic.
    """

    def __init__(self, path: str | Path, topics: Collection[str] | None = None) -> None:
        self.path = Path(path)
        self.offset = 0
        self.closed = False
        self.wanted = None if topics is None else frozenset(topics)
        self._records = McapRecords() if self.wanted is None else _WantedRecords(self.wanted)
        self._decoded: dict[int, _Decoded] = {}  # channel id -> leaves -> (t [s] arrays, values)
        self._typestores: dict[int, Typestore] = {}

    def poll(self) -> bool:
        """Read the complete records added since the last poll; True if any message arrived."""
        data = self._new_bytes()
        pos = 0
        if self.offset == 0:
            if len(data) < len(MCAP_MAGIC):
                return False
            if data[:len(MCAP_MAGIC)] != MCAP_MAGIC:
                raise LogReadError(f"{self.path}: not an MCAP file (bad magic bytes)")
            pos = len(MCAP_MAGIC)
        pos, got = self._parse(data, pos)
        self.offset += pos
        return got

    def _new_bytes(self) -> bytes:
        try:
            with open(self.path, "rb") as fh:
                fh.seek(self.offset)
                return fh.read()
        except OSError as err:
            raise LogReadError(f"{self.path}: cannot read ({err.strerror})") from None

    def _parse(self, data: bytes, pos: int) -> tuple[int, bool]:
        """Parse the complete records of ``data`` from ``pos``: (where parsing stopped, any message)."""
        from mcap.opcode import Opcode

        got = False
        while pos + 9 <= len(data):
            op = data[pos]
            length = int.from_bytes(data[pos + 1:pos + 9], "little")
            end = pos + 9 + length
            if end > len(data):
                break  # a record still being written: wait for the rest
            if op in (Opcode.FOOTER, Opcode.DATA_END):
                self.closed = True
                return end, got
            try:
                got |= self._records.record(op, data[pos + 9:end]) > 0
            except Exception:  # noqa: BLE001 - a damaged record: skip it, keep the framing
                pass
            pos = end
        return pos, got

    def topics(self) -> list[str]:
        """Topic names seen so far."""
        return sorted({c.topic for c in self._records.channels.values()})

    def kept_bytes(self) -> int:
        """Bytes of message data held and not yet decoded, over every channel (what ``topics`` bounds)."""
        return sum(len(d) for ch in self._records.channels.values() for d in ch.datas)

    def _find(self, topic: str) -> McapChannel | None:
        if self.wanted is not None and topic not in self.wanted:
            # its bytes were dropped as parsed: asking for it is a caller's mistake, not an absent topic
            raise LogReadError(f"{self.path}: topic {topic!r} is not one this follower keeps "
                               f"({', '.join(sorted(self.wanted))})")
        for ch in self._records.channels.values():
            if ch.topic == topic:
                return ch
        return None

    def _typestore(self, ch: McapChannel) -> Typestore:
        if ch.id not in self._typestores:
            self._typestores[ch.id] = channel_typestore(ch, self.path)
        return self._typestores[ch.id]

    def leaves(self, topic: str, field_path: str | None) -> list[str] | None:
        """The numeric leaves ``topic:field`` stands for (four for a quaternion); None if the topic has
        not appeared yet or (JSON) has no message yet."""
        ch = self._find(topic)
        if ch is None:
            return None
        path = field_path or "data"
        if ch.encoding != "json":
            return channel_leaves(self.path, ch, self._typestore, path)
        if not ch.datas:  # its messages decoded already (their leaves), or none yet
            decoded = self._decoded.get(ch.id)
            return list(next(iter(decoded))) if decoded else None
        return json_leaves(self.path, topic, ch.datas[0], path)

    def values(self, topic: str, leaves: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Times [s] and values of ``leaves`` of ``topic`` so far (new messages decoded once)."""
        ch = self._find(topic)
        key = tuple(leaves)
        if ch is None:
            return np.zeros(0), {k: np.zeros(0) for k in leaves}
        decoded = self._decoded.setdefault(ch.id, {})
        t_parts, v_parts = decoded.setdefault(key, ([], {k: [] for k in leaves}))
        if ch.datas:
            if len(decoded) > 1:
                raise LogReadError(f"{self.path}: {topic}: read with two field sets")
            t_parts.append(np.asarray(ch.times, dtype=np.int64) / 1e9)
            vals = self._decode(ch, leaves)
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

    def _decode(self, ch: McapChannel, leaves: list[str]) -> dict[str, np.ndarray]:
        """The new messages' values of ``leaves``, decoded as the MCAP reader decodes them."""
        return channel_values(self.path, ch, self._typestore, *cdr.packed(ch.datas), list(leaves))


class _NotYet(LogReadError):
    """A topic of a file still being written has not appeared, or has no message yet: wait."""


class _FollowedSource(LogSource):
    """The messages a :class:`McapFollower` has read so far, as a :class:`~mrftcli.io.LogSource`, so that
    :func:`mrftcli.io.flight.read_loop` applies the same topic logic as to a finished log."""

    format = "mcap"
    default_field = "data"
    recorder_times = True

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


class _McapLog:
    """The flight so far from a growing MCAP (a file, or the one inside a ROS 2 bag directory)."""

    def __init__(self, path: Path, opts: ReadOptions) -> None:
        self.dir = path if path.is_dir() else None
        self.opts = replace(opts, layout="reference")
        self.topics = _wanted_topics(self.opts)
        self.follower = None if self.dir else McapFollower(path, self.topics)
        self.path = path
        #: (inode, size) when last read: a smaller size or another inode is a new recording
        self.seen = None if self.dir else _identity(path)

    def poll(self) -> Snapshot:
        if self.follower is None:
            assert self.dir is not None  # one of the two is set in __init__
            files = sorted(self.dir.glob("*.mcap"))
            if not files:
                return Snapshot(None, False, False)
            self.follower = McapFollower(files[0], self.topics)
            self.seen = _identity(files[0])
        f = self.follower
        now = _identity(f.path)
        restarted = _replaced(self.seen, now)
        if restarted is not None:
            # a new recording under the same name: what was parsed belongs to the old one
            f = self.follower = McapFollower(f.path, self.topics)
        grew = f.poll()
        self.seen = _identity(f.path) if grew or restarted else now
        return Snapshot(self._flight(f) if grew or f.closed else None, grew, f.closed, restarted)

    def _flight(self, follower: McapFollower) -> FlightLog | None:
        try:
            flight = read_loop(_FollowedSource(follower, self.path), self.opts)
        except _NotYet:
            return None  # a topic the flight needs has not arrived yet: the next poll
        if flight.command.t.size < 10 or flight.output.t.size < 10:
            return None
        return replace(flight, source={**flight.source, "format": "mcap (followed)"})


def _wanted_topics(opts: ReadOptions) -> frozenset[str]:
    """The topics :func:`~mrftcli.io.flight.read_loop` reads for ``opts`` (layout named): the command,
    output, beta, setpoint and battery roles' topics."""
    specs = role_specs(get_layout(opts.layout or "reference"), opts)
    roles = (specs.command, specs.output, specs.beta, specs.setpoint, specs.battery)
    return frozenset(parse_spec(s).topic for s in roles if s is not None)


class _RereadLog:
    """The flight so far by reading the whole file again whenever it grows (CSV, ULog, ...)."""

    def __init__(self, path: Path, opts: ReadOptions) -> None:
        self.path = path
        # the reference layout's topics in place of those not named (not the layout's detection); a
        # log whose command and output are named (a process recording: time, u_relay, y_output) is not
        # in the reference layout, so its optional beta and setpoint are not looked for there either
        loop = layout_loop(opts.loop)
        named = opts.command_topic is not None and opts.output_topic is not None
        self.opts = replace(
            opts, command_topic=opts.command_topic or DEFAULT_TOPICS["command"],
            output_topic=opts.output_topic or DEFAULT_TOPICS[f"output.{loop}"],
            beta_topic=opts.beta_topic or (None if named else DEFAULT_TOPICS["beta"]),
            setpoint_topic=opts.setpoint_topic or (None if named else DEFAULT_TOPICS["setpoint"]),
            output_scale=1.0 if opts.output_scale is None else float(opts.output_scale))
        self.size = -1
        self.seen: _Identity | None = None  # the file when last read

    def poll(self) -> Snapshot:
        from . import read_flight

        now = _identity(self.path)
        if now is None:
            return Snapshot(None, False, False)
        restarted = _replaced(self.seen, now)
        size = now[1]
        if restarted is None and (size == self.size or size == 0):
            return Snapshot(None, False, False)
        self.size, self.seen = size, now
        o = self.opts
        # a salvaged (half-written) file is the normal state here: the reader keeps its warnings
        # in FlightLog.warnings instead of printing them (echo_warnings=False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                flight = read_flight(self.path, o, echo_warnings=False)
            except LogReadError:
                # a half-written row/record or topics not there yet
                return Snapshot(None, size > 0, False, restarted)
        return Snapshot(flight, True, False, restarted)


def follow_log(path: str | Path, opts: ReadOptions) -> LogFollower:
    """The follower of ``path``: incremental for MCAP (:func:`is_mcap`), else reading it again as it grows.

    Parameters
    ----------
    path : str or Path
        An existing log file, or a ROS 2 bag directory being recorded.
    opts : ReadOptions
        The loop and its topic options (a topic not named: the reference layout's); ``opts.fmt`` the
        log format (None: detected), ``opts.time_unit`` the unit of a CSV's time column
        (:func:`mrftcli.io.read_flight`; an MCAP's clock has its own).

    Raises
    ------
    InputError
        ``opts.time_unit`` for an MCAP log.
    """
    path = Path(path)
    if is_mcap(path, opts.fmt):
        if opts.time_unit is not None:
            raise InputError("--time-unit applies to CSV and .mat logs, whose times carry no unit; an MCAP "
                             "log's clock has its own")
        return _McapLog(path, opts)
    return _RereadLog(path, opts)


def is_mcap(path: Path, fmt: str | None = None) -> bool:
    """Whether ``path`` is followed as MCAP: ``fmt`` says so, a ROS 2 bag directory with mcap
    storage (``metadata.yaml`` is written only at the end: then any ``.mcap`` in it), the MCAP
    magic bytes, or the ``.mcap`` suffix."""
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
