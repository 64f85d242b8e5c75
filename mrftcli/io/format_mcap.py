"""MCAP: ROS 2 (CDR) and JSON messages (also ROS 1-encoded channels), reader and writers.

Reading holds one chunk at a time and keeps only the wanted channels' messages, so memory follows
what is read, not the file (a 40 s flight beside a 30 Hz camera topic is a 1 GB MCAP):

* indexed files (the normal case: chunked, with a summary): only chunks holding a wanted channel are
  read (the Chunk Index records say which), with ``pread``, each decompressed once within the size it
  declares (:mod:`mrftcli.io.mcap_stream`); its Message Index records (``(log_time, offset)`` pairs for
  one channel) locate the wanted messages with numpy, without a Python object per message, and their
  bytes are copied out before the next chunk. CDR fields are gathered by :mod:`mrftcli.io.cdr`.
* anything else (no summary, unchunked, or a truncated file whose footer is gone): a linear pass over
  the records that keeps every complete message before the damage, skips a chunk it cannot trust (CRC,
  size over the limits, records that do not parse) and warns saying how much was salvaged; it keeps
  log times only, and a second pass keeps the wanted channels' bytes.

A chunk declaring more than :data:`~mrftcli.io.mcap_stream.MAX_CHUNK_BYTES` uncompressed, or
decompressing to more than it declares, is a decompression bomb or damage: the indexed read refuses
the file (LogReadError naming the chunk and the size), the salvage pass skips that chunk.

Message time is the MCAP ``log_time`` (when the recorder received the message), so every topic,
including header-less ``std_msgs/msg/Float64``, shares one clock.
"""

from __future__ import annotations

import io
import json
import mmap
import os
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from ..errors import InputError, LogReadError
from ..jsonable import load_json_text
from .atomic import atomic_path
from .logtypes import TopicData, TopicInfo
from . import cdr
from .mcap_stream import (MESSAGE_HEADER_BYTES, OP_CHANNEL, OP_CHUNK, OP_FOOTER, OP_MESSAGE, OP_SCHEMA,
                          OversizeChunkError, check_declared, chunk_header, decompress_chunk,
                          walk_records)
from .source import LogSource, one_line
from .timing import mean_rate_hz
from .msgtypes import json_messages, json_schema, numeric_leaves, time_ordered, typestore_for, typestore_from_text

if TYPE_CHECKING:
    from mcap.records import Channel, ChunkIndex, Schema
    from mcap.summary import Summary
    from rosbags.typesys.store import Typestore

__all__ = ["McapSource", "McapRecords", "McapChannel", "channel_typestore", "channel_leaves", "channel_values",
           "json_leaves", "write_mcap", "MCAP_MAGIC"]

#: one channel's messages: log times [ns], its messages' bytes end to end, each one's start and length
_RawMessages = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

MCAP_MAGIC = b"\x89MCAP0\r\n"
_MSG_HEADER = MESSAGE_HEADER_BYTES
#: how much of a memory-mapped file the salvage pass reads before handing its pages back [bytes]
_RELEASE_EVERY = 16 * 2**20


@dataclass
class McapChannel:
    """One MCAP channel: its topic, message encoding and schema, and (when gathered record by record)
    the log times [ns] and raw data of its messages."""

    id: int
    topic: str
    encoding: str  # cdr | json | ros1
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    # salvage mode: messages collected by the linear scan
    times: list[int] = field(default_factory=list)
    datas: list[bytes] = field(default_factory=list)


class McapRecords:
    """Schemas, channels and undecoded messages gathered from MCAP records parsed one at a time.

    Whoever walks the records (the salvage pass of :class:`McapSource`, :class:`mrftcli.io.follow.McapFollower`
    on a file still being written) hands each top-level record to :meth:`record`; ``channels`` maps
    channel id -> :class:`McapChannel`, whose ``times`` collect every message's log time and ``datas``
    the bytes of the messages of the channels in ``keep`` (None: all), so that a camera topic beside
    the wanted ones costs 8 bytes a message, not its image. Chunks are decompressed within what they
    declare (:func:`mrftcli.io.mcap_stream.decompress_chunk`): a hostile chunk raises, it cannot
    exhaust memory.
    """

    def __init__(self, keep: frozenset[int] | None = None) -> None:
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, McapChannel] = {}
        self.keep = keep

    def add_channel(self, rec: Channel, schema: Schema | None) -> None:
        """Register an ``mcap`` Channel record (with its Schema record, or None) once."""
        if rec.id in self.channels:
            return
        self.channels[rec.id] = McapChannel(
            id=rec.id, topic=rec.topic, encoding=rec.message_encoding.lower(),
            schema_name=schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            schema_data=bytes(schema.data) if schema else b"")

    def record(self, op: int, body: bytes | memoryview) -> int:
        """Parse one top-level (or in-chunk) record's body; returns the number of messages kept."""
        from mcap.data_stream import ReadDataStream
        from mcap.records import Channel, Message, Schema

        if op == OP_CHUNK:
            return self.chunk(body, "chunk")
        stream = ReadDataStream(io.BytesIO(body))
        if op == OP_SCHEMA:
            rec = Schema.read(stream)
            self.schemas[rec.id] = rec
        elif op == OP_CHANNEL:
            rec = Channel.read(stream)
            self.add_channel(rec, self.schemas.get(rec.schema_id))
        elif op == OP_MESSAGE:
            msg = Message.read(stream, len(body))
            ch = self.channels.get(msg.channel_id)
            if ch is None:
                return 0
            ch.times.append(msg.log_time)
            if self.keep is None or ch.id in self.keep:
                ch.datas.append(bytes(msg.data))
            return 1
        return 0

    def chunk(self, body: bytes | memoryview, where: str, *, partial: bool = False) -> int:
        """Parse a Chunk record's body; returns the number of messages kept.

        With ``partial`` the body is cut off by the end of the file: the complete records at the start
        of what decompresses are kept. Otherwise a chunk whose CRC fails or whose records cannot all
        be trusted is skipped whole (ValueError), and one over the size limits raises
        :class:`~mrftcli.io.mcap_stream.OversizeChunkError`.
        """
        header = chunk_header(body)
        packed = body[header.records_offset:header.records_offset + header.records_length]
        data = decompress_chunk(header, packed, where, partial=partial)
        walk = walk_records(data)
        if not walk.complete and not partial:
            raise ValueError(f"unreadable record at byte {walk.stop} of the chunk")
        for op, off, length in zip(walk.opcodes.tolist(), walk.offsets.tolist(), walk.lengths.tolist()):
            if op != OP_MESSAGE:
                self.record(op, data[off + 9:off + 9 + length])
        off = walk.offsets[walk.opcodes == OP_MESSAGE]
        rec_len, channel, log_time = _message_fields(np.frombuffer(data, dtype=np.uint8), off)
        kept = 0
        for cid in np.unique(channel).tolist():
            ch = self.channels.get(cid)
            if ch is None:
                continue
            sel = channel == cid
            ch.times.extend(log_time[sel].tolist())
            kept += int(sel.sum())
            if self.keep is None or cid in self.keep:
                starts = (off[sel] + 9 + _MSG_HEADER).tolist()
                ch.datas.extend(data[s:s + n] for s, n in zip(starts, (rec_len[sel] - _MSG_HEADER).tolist()))
        return kept


@dataclass(frozen=True)
class _Salvage:
    """What a salvage pass read: messages kept, damaged records skipped, messages from a cut-off
    chunk, whether the footer was reached, and notes on chunks refused for their size."""

    count: int
    bad: int
    from_partial: int
    complete: bool
    notes: tuple[str, ...]


def channel_typestore(ch: McapChannel, path: str | Path, warn: Callable[[str], None] | None = None) -> Typestore:
    """The rosbags typestore that decodes ``ch``'s CDR/ROS 1 messages: from the schema text the file
    carries, else the standard definitions (LogReadError if they do not know the type).

    A schema the file carries but that cannot be used (a type that contains itself, a nested type it
    never defines) is not guessed past silently: the standard definition of the type it names is
    used and ``warn`` is told so in one line (``FlightLog.warnings``: the terminal and the JSON);
    without ``warn`` such a schema is refused.
    """
    ros1 = ch.encoding == "ros1"
    ts = None
    broken = None
    if ch.schema_data and ch.schema_encoding in ("ros2msg", "ros1msg"):
        try:
            ts = typestore_from_text(ch.schema_data.decode(), ch.schema_name, ros1=ros1)
        except Exception as err:  # noqa: BLE001 - any parse or type-graph failure: the standard definition, said
            broken = one_line(err, 120)
    if ts is None:
        ts = typestore_for(ros1=ros1)
        if not ch.schema_name:
            raise LogReadError(f"{path}: {ch.topic}: the channel has no schema (the file does not say "
                               "what its messages hold); it cannot be decoded")
        if ch.schema_name not in ts.fielddefs:
            raise LogReadError(f"{path}: {ch.topic}: cannot decode type {ch.schema_name!r} "
                               f"(schema encoding {ch.schema_encoding!r})")
        if broken is not None:
            what = f"the file's schema for {ch.schema_name} is unusable ({broken})"
            if warn is None:
                raise LogReadError(f"{path}: {ch.topic}: {what}; it cannot be decoded")
            # no topic in the text: the channels sharing the schema give one warning (warn drops repeats)
            warn(f"{what}; its channels are decoded with the standard {ch.schema_name} definition "
                 "(check the recorder)")
    return ts


class McapSource(LogSource):
    """An MCAP file with ``cdr`` (ROS 2), ``ros1`` or ``json`` message encodings."""

    default_field = "data"
    recorder_times = True

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        self.format = "mcap"
        self._summary: Summary | None = None
        self._records = McapRecords(keep=frozenset())  # times only: bytes come from a second pass
        self._channels: dict[int, McapChannel] = self._records.channels
        self._salvaged = False
        self._typestores: dict[int, Typestore] = {}
        self._topic_cache: list[TopicInfo] | None = None
        self._raw_cache: dict[int, _RawMessages] = {}
        self._file: IO[bytes] | None = None
        self._data: bytes | mmap.mmap = b""
        self._summary_failed = False
        try:
            self._require_file()
            # memory-mapped: a multi-GB log with camera topics costs only the pages actually read
            self._file = open(self.path, "rb")  # noqa: SIM115 - closed in close()
            self._data = mmap.mmap(self._file.fileno(), 0, access=mmap.ACCESS_READ)
        except OSError as err:
            self.close()
            raise LogReadError(f"{self.path}: cannot read ({err.strerror})") from None
        if self._data[:len(MCAP_MAGIC)] != MCAP_MAGIC:
            self.close()
            raise LogReadError(f"{self.path}: not an MCAP file (bad magic bytes)")
        try:
            self._open()
        except BaseException:
            self.close()
            raise
        encodings = {c.encoding for c in self._channels.values()}
        if encodings == {"json"}:
            self.format = "mcap-json"

    # -- opening ----------------------------------------------------------------------------------
    def _open(self) -> None:
        from mcap.reader import SeekingReader

        summary = None
        try:
            handle = self._handle
            handle.seek(0)
            summary = SeekingReader(handle).get_summary()
        except Exception:  # noqa: BLE001 - any damage in the footer/summary -> linear salvage below
            summary = None
            self._summary_failed = True
        if summary is not None and summary.chunk_indexes:
            self._summary = summary
            for ch in summary.channels.values():
                self._records.add_channel(ch, summary.schemas.get(ch.schema_id))
            return
        self._scan()

    @property
    def _handle(self) -> IO[bytes]:
        """The open file (LogReadError once closed)."""
        if self._file is None:
            raise LogReadError(f"{self.path}: the file is closed")
        return self._file

    @property
    def _index(self) -> Summary:
        """The summary with the chunk indexes (a file read without salvage has one)."""
        if self._summary is None:
            raise LogReadError(f"{self.path}: no MCAP summary (the file was salvaged record by record)")
        return self._summary

    def _scan(self) -> None:
        """The salvage pass when there is no usable summary: every readable record, in file order.

        It keeps every channel's log times (for :meth:`topics`) but no message bytes; :meth:`_salvaged_raw`
        walks the file again for the wanted channels' bytes, so memory does not grow with a camera
        topic. Warns once saying what was salvaged and what was lost.
        """
        got = self._walk(self._records)
        if got.count == 0 and (got.bad or not got.complete):
            detail = f" ({'; '.join(got.notes)})" if got.notes else ""
            raise LogReadError(f"{self.path}: corrupt or truncated MCAP, no message could be read{detail}")
        notes: list[str] = []
        if not got.complete:
            notes.append("the file ends before its footer")
        if got.bad:
            notes.append(f"{got.bad} damaged record(s) skipped")
        if got.from_partial:
            notes.append(f"{got.from_partial} from the cut-off chunk")
        notes.extend(got.notes)
        if notes or self._summary_failed:
            self.warn(f"truncated or corrupt MCAP: salvaged {got.count} messages "
                      f"({'; '.join(notes) or 'summary section unreadable'})")
        self._salvaged = True

    def _walk(self, records: McapRecords) -> _Salvage:
        """Hand every readable top-level record to ``records``, in file order.

        The framing (``opcode``, ``uint64 length``) is walked here so that one damaged record (a chunk
        whose CRC fails, one over the size limits) is skipped rather than ending the pass; a record cut
        off by the end of the file ends it (if a chunk, the complete messages at the start of what
        decompresses are kept), and so does opcode 0, which no writer uses (a zero-filled region:
        nothing after it can be framed). Only records that are parsed are copied out of the map, and
        the map's pages are handed back as the pass goes, so memory does not grow with the file.
        """
        data = self._data
        view = memoryview(data)
        size = len(data)
        pos = len(MCAP_MAGIC)
        complete = False
        bad = count = from_partial = 0
        notes: list[str] = []
        released = 0
        try:
            while pos + 9 <= size:
                op = data[pos]
                length = int.from_bytes(data[pos + 1:pos + 9], "little")
                start, end = pos + 9, pos + 9 + length
                where = f"{self.path}: chunk at byte {pos}"
                if op == 0:
                    notes.append(f"unreadable bytes from byte {pos} on")
                    break
                if end > size:
                    if op == OP_CHUNK:
                        from_partial = self._partial_chunk(records, view[start:size], where)
                        count += from_partial
                    break
                if op == OP_FOOTER:
                    complete = True
                    break
                try:
                    if op == OP_CHUNK:
                        count += records.chunk(view[start:end], where)
                    elif op in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE):
                        count += records.record(op, data[start:end])
                except OversizeChunkError as err:
                    notes.append(f"{str(err).removeprefix(f'{self.path}: ')}, skipped")
                except Exception:  # noqa: BLE001 - a damaged record: skip it, keep the framing
                    bad += 1
                pos = end
                released = self._release(released, pos)
        finally:
            view.release()
        return _Salvage(count, bad, from_partial, complete, tuple(notes))

    def _release(self, released: int, pos: int) -> int:
        """Hand back the map's pages before ``pos`` every :data:`_RELEASE_EVERY` bytes (they stay in
        the page cache; the process's resident set stops growing with the file)."""
        if not isinstance(self._data, mmap.mmap) or pos - released < _RELEASE_EVERY:
            return released
        upto = pos - pos % mmap.PAGESIZE
        self._data.madvise(mmap.MADV_DONTNEED, released, upto - released)
        return upto

    def _partial_chunk(self, records: McapRecords, body: memoryview, where: str) -> int:
        """Complete records at the start of a chunk the file ends inside (0 if none can be read)."""
        try:
            return records.chunk(body, where, partial=True)
        except Exception:  # noqa: BLE001 - too little of the chunk is left, or it cannot be trusted
            return 0

    # -- types --------------------------------------------------------------------------------------
    def _typestore(self, ch: McapChannel) -> Typestore:
        if ch.id not in self._typestores:
            self._typestores[ch.id] = channel_typestore(ch, self.path, self.warn)
        return self._typestores[ch.id]

    def _channel(self, topic: str) -> McapChannel:
        chans = [c for c in self._channels.values() if c.topic == topic]
        if not chans:
            raise self.missing_topic(topic)
        return chans[0]

    # -- interface ----------------------------------------------------------------------------------
    def topics(self) -> list[TopicInfo]:
        if self._topic_cache is not None:
            return self._topic_cache
        out: list[TopicInfo] = []
        times = self.channel_times()
        for ch in self._channels.values():
            t = np.sort(times[ch.id]) / 1e9
            out.append(TopicInfo(ch.topic, ch.schema_name or ch.encoding, len(t), mean_rate_hz(t),
                                 self._leaves_or_none(ch)))
        self._topic_cache = sorted(out, key=lambda i: i.name)
        return self._topic_cache

    def channel_times(self) -> dict[int, np.ndarray]:
        """Every channel's message log times [ns] (file order), by channel id: from the Message Index
        records, without reading a chunk when the file has them."""
        if self._salvaged:
            return {cid: np.asarray(ch.times, dtype=np.int64) for cid, ch in self._channels.items()}
        times = self._index_times(list(self._channels))
        return {cid: times.get(cid, np.zeros(0, np.int64)) for cid in self._channels}

    def topic_fields(self, topic: str) -> tuple[str, ...]:
        """The numeric leaves of ``topic``'s message type (none if its type cannot be decoded)."""
        return self._leaves_or_none(self._channel(topic))

    def _leaves_or_none(self, ch: McapChannel) -> tuple[str, ...]:
        try:
            return tuple(self._fields(ch))
        except LogReadError:
            return ()

    def channel_topics(self) -> dict[int, tuple[str, str]]:
        """Channel id -> (topic, type name) of every channel."""
        return {cid: (ch.topic, ch.schema_name or ch.encoding) for cid, ch in self._channels.items()}

    def _fields(self, ch: McapChannel) -> list[str]:
        if ch.encoding == "json":
            if ch.schema_data and ch.schema_encoding == "jsonschema":
                try:  # depth-checked: a schema nested 100,000 deep would exhaust the parser's recursion
                    schema = load_json_text(bytes(ch.schema_data).decode("utf-8", "replace"), ch.topic)
                except InputError as err:
                    raise LogReadError(f"{self.path}: JSON schema of {err}") from None
                return _json_schema_leaves(schema, "") if isinstance(schema, dict) else []
            return []
        return numeric_leaves(self._typestore(ch), ch.schema_name)

    def leaves(self, topic: str, field: str | None) -> list[str]:
        ch = self._channel(topic)
        path = field if field is not None else self.default_field
        if ch.encoding == "json":
            _, buf, starts, lengths = self._raw(ch)
            first = buf[int(starts[0]):int(starts[0]) + int(lengths[0])].tobytes() if len(starts) else None
            return json_leaves(self.path, ch.topic, first, path)
        return channel_leaves(self.path, ch, self._typestore, path)

    def read(self, topic: str, fields: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        ch = self._channel(topic)
        t_ns, buf, starts, lengths = self._raw(ch)
        return t_ns / 1e9, channel_values(self.path, ch, self._typestore, buf, starts, lengths, fields)

    # -- raw access ---------------------------------------------------------------------------------
    def _raw(self, ch: McapChannel) -> _RawMessages:
        """Log times [ns], one byte buffer, and each message's start and length, in file order."""
        if ch.id not in self._raw_cache:
            self._raw_cache[ch.id] = self._raw_uncached(ch)
        return self._raw_cache[ch.id]

    def prefetch(self, topics: list[str]) -> None:
        """Read the wanted channels in one pass over the chunks (each chunk decompressed once, one at a time)."""
        cids = [c.id for c in self._channels.values()
                if c.topic in topics and c.id not in self._raw_cache]
        if cids:
            self._raw_cache.update(self._salvaged_raw(cids) if self._salvaged else self._indexed(cids))

    def close(self) -> None:
        self._raw_cache.clear()
        if isinstance(self._data, mmap.mmap):
            try:
                self._data.close()
            except BufferError:  # a caller still holds an array view; the map goes with it
                pass
        self._data = b""
        if self._file is not None:
            self._file.close()
            self._file = None

    def _raw_uncached(self, ch: McapChannel) -> _RawMessages:
        if self._salvaged:
            return self._salvaged_raw([ch.id])[ch.id]
        return self._indexed([ch.id])[ch.id]

    def _salvaged_raw(self, cids: list[int]) -> dict[int, _RawMessages]:
        """The wanted channels' messages of a salvaged file: a second pass keeping their bytes only."""
        records = McapRecords(keep=frozenset(cids))
        self._walk(records)  # what it skips was said by the first pass's warning
        out: dict[int, _RawMessages] = {}
        for cid in cids:
            ch = records.channels.get(cid)
            times, datas = (ch.times, ch.datas) if ch is not None else ([], [])
            out[cid] = (np.asarray(times, dtype=np.int64), *cdr.packed(datas))
        return out

    def _chunks(self, cids: list[int]) -> list[ChunkIndex]:
        # a writer may leave the Message Index records out (valid MCAP): such a chunk may hold anything
        return sorted((c for c in self._index.chunk_indexes
                       if not c.message_index_offsets or any(cid in c.message_index_offsets for cid in cids)),
                      key=lambda c: c.chunk_start_offset)

    def _message_index(self, offset: int) -> np.ndarray:
        """(log_time, offset) pairs of one Message Index record at file ``offset``, shape (n, 2)."""
        # opcode(1) length(8) channel_id(2) records_length(4) records(16 each)
        head = os.pread(self._handle.fileno(), 15, offset)
        n_bytes = int.from_bytes(head[11:15], "little")
        raw = os.pread(self._handle.fileno(), n_bytes - n_bytes % 16, offset + 15)
        return np.frombuffer(raw, dtype="<u8").reshape(-1, 2).astype(np.int64)

    def _index_times(self, cids: list[int]) -> dict[int, np.ndarray]:
        out: dict[int, list[np.ndarray]] = {cid: [] for cid in cids}
        if any(not c.message_index_offsets for c in self._index.chunk_indexes):
            # no Message Index records: the times come from reading the chunks (not their bytes)
            return {cid: v[0] for cid, v in self._indexed(cids, payload=False).items()}
        try:
            for chunk in sorted(self._index.chunk_indexes, key=lambda c: c.chunk_start_offset):
                for cid, off in chunk.message_index_offsets.items():
                    if cid in out:
                        out[cid].append(self._message_index(off)[:, 0])
        except Exception:  # noqa: BLE001
            raise LogReadError(f"{self.path}: corrupt MCAP message index") from None
        return {cid: np.concatenate(v) if v else np.zeros(0, np.int64) for cid, v in out.items()}

    def _chunk_data(self, chunk_index: ChunkIndex) -> bytes:
        """One chunk's records, decompressed (read with ``pread``: nothing of the file stays mapped).

        Raises OversizeChunkError for a chunk over the size limits (before its data are read),
        ValueError (or the decompressor's error) for a damaged one.
        """
        fd = self._handle.fileno()
        at = chunk_index.chunk_start_offset
        where = f"{self.path}: chunk at byte {at}"
        head = os.pread(fd, 9 + 1024, at)
        if len(head) < 9 or head[0] != OP_CHUNK:
            raise ValueError("no chunk record at its index's offset")
        header = chunk_header(head[9:])
        check_declared(header, where)  # before reading what it would decompress
        return decompress_chunk(header, os.pread(fd, header.records_length, at + 9 + header.records_offset), where)

    def _indexed(self, cids: list[int], *, payload: bool = True) -> dict[int, _RawMessages]:
        """For each channel: log times [ns], a byte buffer, its messages' starts and sizes (file order).

        One chunk is held at a time. When the wanted messages make up at least half of it (a light
        log) the chunk is kept whole, as copying them out would only cost time; otherwise (a camera
        beside them) only their bytes are copied out, so memory follows what is wanted, not the file
        (at most twice it). Without ``payload``, times only.
        """
        pieces: list[np.ndarray] = []  # the one buffer all channels index into, in pieces
        base = 0
        parts: dict[int, tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]] = {
            cid: ([], [], []) for cid in cids}
        for chunk_index in self._chunks(cids):
            try:
                data = self._chunk_data(chunk_index)
            except OversizeChunkError:
                raise
            except Exception as err:  # noqa: BLE001 - one damaged chunk: keep the others, say so
                self.warn(f"chunk at byte {chunk_index.chunk_start_offset} is corrupt "
                          f"({type(err).__name__}: {err}); its messages are skipped")
                continue
            whole = np.frombuffer(data, dtype=np.uint8)
            found = self._chunk_messages(whole, chunk_index, cids)
            wanted = sum(int(length.sum()) for _, _, length in found.values())
            keep_whole = payload and 2 * wanted >= len(whole)
            if keep_whole:
                pieces.append(whole)
            for cid, (t_ns, start, length) in found.items():
                times, starts, lengths = parts[cid]
                times.append(t_ns)
                lengths.append(length)
                if keep_whole:
                    starts.append(start + base)
                elif payload:
                    pieces.append(_gather(whole, start, length))
                    starts.append(base + np.cumsum(length) - length)
                    base += int(length.sum())
            if keep_whole:
                base += len(whole)
        buf = np.concatenate(pieces) if pieces else np.zeros(0, np.uint8)
        out: dict[int, _RawMessages] = {}
        for cid, (times, starts, lengths) in parts.items():
            t_ns = np.concatenate(times) if times else np.zeros(0, np.int64)
            size = np.concatenate(lengths).astype(np.int64) if lengths else np.zeros(0, np.int64)
            first = np.concatenate(starts).astype(np.int64) if starts else np.zeros(0, np.int64)
            out[cid] = (t_ns, buf, first if payload else np.zeros_like(size), size)
        return out

    def _chunk_messages(self, whole: np.ndarray, chunk_index: ChunkIndex,
                        cids: list[int]) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Log times, payload starts and sizes of the wanted channels' messages in one decompressed
        chunk: from its Message Index records, else (none written, or damaged) from walking it."""
        out: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        offsets = chunk_index.message_index_offsets
        walked: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        for cid in cids:
            if offsets and cid not in offsets:
                continue
            if offsets:
                try:
                    out[cid] = self._locate(whole, cid, offsets[cid])
                    continue
                except (ValueError, IndexError):
                    # the index (outside the CRC-checked chunk) is damaged but the chunk is fine
                    self.warn(f"message index of chunk at byte {chunk_index.chunk_start_offset} is "
                              "corrupt; read the chunk record by record")
            if walked is None:
                try:
                    walked = _walk_messages(whole)
                except ValueError as err:  # no CRC caught it and the index cannot be trusted: refuse, naming it
                    raise LogReadError(f"{self.path}: the chunk at byte {chunk_index.chunk_start_offset} is damaged "
                                       f"({err}); recover the readable part with 'mcap recover'") from None
            off, channel, log_time, rec_len = walked
            sel = channel == cid
            out[cid] = (log_time[sel], off[sel] + 9 + _MSG_HEADER, rec_len[sel] - _MSG_HEADER)
        return out

    def _locate(self, arr: np.ndarray, cid: int, index_offset: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Log times, payload starts and sizes of channel ``cid``'s messages in a decompressed chunk.

        The Message Index gives each record's offset; every record is checked (opcode, channel id,
        size, and log time equal to the index's) so a damaged index cannot yield wrong data.
        """
        index = self._message_index(index_offset)
        index = index[np.argsort(index[:, 1], kind="stable")]  # file order
        off = index[:, 1]
        if len(off) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
        if off.min() < 0 or off.max() + 9 + _MSG_HEADER > len(arr) or (arr[off] != OP_MESSAGE).any():
            raise ValueError("message index points outside the chunk")

        rec_len, channel, log_time = _message_fields(arr, off)
        if ((off + 9 + rec_len > len(arr)).any() or (rec_len < _MSG_HEADER).any()
                or (channel != cid).any() or (log_time != index[:, 0]).any()):
            raise ValueError("message index disagrees with the chunk")
        return log_time, off + 9 + _MSG_HEADER, rec_len - _MSG_HEADER


def _walk_messages(arr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Offsets, channel ids, log times [ns] and record lengths of the Message records in a chunk's
    records (for chunks written without Message Index records, or whose index is damaged).

    Raises ValueError if the walk stops before the end (a record that cannot be trusted).
    """
    walk = walk_records(arr.data)
    if not walk.complete:
        raise ValueError(f"unreadable record at byte {walk.stop} of the chunk")
    off = walk.offsets[walk.opcodes == OP_MESSAGE]
    rec_len, channel, log_time = _message_fields(arr, off)
    return off, channel, log_time, rec_len


def _gather(arr: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The bytes ``arr[starts[i]:starts[i] + lengths[i]]`` end to end, in one vectorised copy."""
    total = int(lengths.sum())
    if total == 0:
        return np.zeros(0, np.uint8)
    ends = np.cumsum(lengths)
    return arr[np.repeat(starts - (ends - lengths), lengths) + np.arange(total)]


def _message_fields(arr: np.ndarray, off: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Record length, channel id and log time [ns] of the Message records at byte offsets ``off``."""

    def field(offset: int, size: int, dtype: str) -> np.ndarray:
        return arr[(off + offset)[:, None] + np.arange(size)].view(dtype).ravel().astype(np.int64)

    return field(1, 8, "<u8"), field(9, 2, "<u2"), field(15, 8, "<u8")


# -- JSON messages -------------------------------------------------------------------------------
def _json_schema_leaves(schema: dict[str, Any], prefix: str) -> list[str]:
    out: list[str] = []
    properties = schema.get("properties")
    for name, sub in (properties.items() if isinstance(properties, dict) else ()):
        path = f"{prefix}{name}"
        if not isinstance(sub, dict):
            continue
        if sub.get("type") == "object":
            out.extend(_json_schema_leaves(sub, path + "."))
        elif sub.get("type") in ("number", "integer", "boolean"):
            out.append(path)
    return out


def json_leaves(path: str | Path, topic: str, first: bytes | None, field: str) -> list[str]:
    """The leaves ``topic:field`` stands for in a JSON channel, read from its first message (``first``; None:
    no message, the field taken as given): four for a quaternion (``x, y, z, w``), else the field itself."""
    if first is None:
        return [field]
    try:
        node = json.loads(first)
    except (ValueError, RecursionError):  # RecursionError: nested too deep for the parser
        raise LogReadError(f"{path}: {topic}: message 0 is not valid JSON") from None
    for key in field.split("."):
        if not isinstance(node, dict) or key not in node:
            have = ", ".join(node) if isinstance(node, dict) else "none"
            raise LogReadError(f"{path}: {topic}: no field {field!r} (fields there: {have})")
        node = node[key]
    if isinstance(node, dict) and sorted(node) == ["w", "x", "y", "z"]:
        return [f"{field}.{c}" for c in "xyzw"]
    if not isinstance(node, (int, float)):
        raise LogReadError(f"{path}: {topic}: {field!r} is not a number")
    return [field]


def channel_leaves(path: str | Path, ch: McapChannel, typestore: Callable[[McapChannel], Typestore],
                   field: str) -> list[str]:
    """The numeric leaves ``topic:field`` stands for in a CDR or ROS 1 channel (four for a quaternion)."""
    ts = typestore(ch)  # its errors name the path and topic already
    with cdr.naming(path, ch.topic):
        return cdr.leaf_paths(ts, ch.schema_name, field)


def channel_values(path: str | Path, ch: McapChannel, typestore: Callable[[McapChannel], Typestore],
                   buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray, fields: list[str]) -> dict[str, np.ndarray]:
    """The values of ``fields`` in a channel's messages (``buf``, each one's start and length): JSON one
    message at a time, CDR / ROS 1 in one vectorised pass (:func:`mrftcli.io.cdr.extract`). The MCAP reader
    and :class:`mrftcli.io.follow.McapFollower` (a file still being written) decode with it."""
    if ch.encoding == "json":
        return _json_values(Path(path), ch.topic, buf, starts, lengths, fields)
    if ch.encoding not in ("cdr", "ros1"):
        raise LogReadError(f"{path}: {ch.topic}: unsupported message encoding {ch.encoding!r}")
    ts = typestore(ch)  # its errors name the path and topic already
    with cdr.naming(path, ch.topic):
        return cdr.extract(ts, ch.schema_name, buf, starts, lengths, fields, ros1=ch.encoding == "ros1")


def _json_values(path: Path, topic: str, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
                 fields: list[str]) -> dict[str, np.ndarray]:
    """Leaf values of JSON messages (one ``json.loads`` per message: JSON has no fixed layout)."""
    raw = buf.tobytes()
    n = len(starts)
    parts = {f: f.split(".") for f in fields}
    out = {f: np.empty(n, dtype=np.float64) for f in fields}
    for i in range(n):
        s = int(starts[i])
        try:
            msg = json.loads(raw[s:s + int(lengths[i])])
        except (ValueError, RecursionError):  # RecursionError: nested too deep for the parser
            raise LogReadError(f"{path}: {topic}: message {i} is not valid JSON") from None
        for f, keys in parts.items():
            node = msg
            for k in keys:
                if not isinstance(node, dict) or k not in node:
                    have = ", ".join(node) if isinstance(node, dict) else "none"
                    raise LogReadError(f"{path}: {topic}: no field {f!r} (fields there: {have})")
                node = node[k]
            if not isinstance(node, (int, float)):
                raise LogReadError(f"{path}: {topic}: {f!r} of message {i} is not a number")
            out[f][i] = float(node)
    return out


# -- writing -----------------------------------------------------------------------------------------
def write_mcap(topics: list[TopicData], path: str | Path, encoding: str = "cdr") -> None:
    """Write topics as an MCAP file with ``cdr`` (ROS 2 profile) or ``json`` messages.

    Messages of all topics are interleaved in time order; chunks are zstd-compressed and indexed.
    """
    from mcap.writer import CompressionType, Writer

    ts = typestore_for(ros1=False)
    serialize = cdr.serialize_many if encoding == "cdr" else json_messages
    messages = time_ordered(topics, lambda td: serialize(ts, td.msgtype, np.asarray(td.t, np.float64), td.fields))
    # a temporary file renamed when whole (io/atomic): a killed run never leaves a log that looks complete
    with atomic_path(path) as tmp, open(tmp, "wb") as stream:
        # 256 KiB chunks: a truncated file loses at most the chunk being written (salvage, see _scan)
        writer = Writer(stream, compression=CompressionType.ZSTD, chunk_size=1 << 18)
        writer.start(profile="ros2" if encoding == "cdr" else "", library="mrft-ident")
        schema_ids: dict[str, int] = {}
        channel_ids = []
        for td in topics:
            if td.msgtype not in schema_ids:
                if encoding == "cdr":
                    text = ts.generate_msgdef(td.msgtype, ros_version=2)[0]
                    schema_ids[td.msgtype] = writer.register_schema(td.msgtype, "ros2msg", text.encode())
                else:
                    schema = json.dumps(json_schema(ts, td.msgtype)).encode()
                    schema_ids[td.msgtype] = writer.register_schema(td.msgtype, "jsonschema", schema)
            channel_ids.append(writer.register_channel(td.name, "cdr" if encoding == "cdr" else "json",
                                                       schema_ids[td.msgtype]))
        seq = [0] * len(topics)
        for w, ns, data in messages:
            writer.add_message(channel_id=channel_ids[w], log_time=ns, publish_time=ns, data=data, sequence=seq[w])
            seq[w] += 1
        writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer.finish has no annotations
