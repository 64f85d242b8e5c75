"""ROS 1 bags and ROS 2 bags (sqlite3 or mcap storage) through rosbags, reader and writers.

rosbags hands out each message's raw bytes; they are joined into one buffer per topic and decoded
field-wise with :mod:`mrftcli.io.cdr` (ROS 1 serialisation for ``.bag``, CDR for ROS 2), with the
message definitions the bag itself carries. Time is the bag's record time (receive time) [ns -> s].
A ROS 1 bag whose index is missing or cut off (a recording stopped short) is read from its complete
chunks, as ``rosbag reindex`` would (:func:`reindex_ros1`), with a warning.
"""

from __future__ import annotations

import io
import os
import struct
from collections import defaultdict
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rosbags.rosbag1 import Reader as Ros1Reader
from rosbags.rosbag2 import Reader as Ros2Reader

from ..errors import LogReadError
from .logtypes import TopicData, TopicInfo
from . import cdr
from .source import LogSource, one_line
from .timing import mean_rate_hz
from .msgtypes import numeric_leaves, time_ordered, typestore_for, typestore_from_text

if TYPE_CHECKING:
    from rosbags.interfaces import Connection
    from rosbags.rosbag1.reader import Header
    from rosbags.rosbag1.writer import Writer as Ros1Writer
    from rosbags.rosbag2.writer import Writer as Ros2Writer
    from rosbags.typesys.store import Typestore

__all__ = ["RosbagSource", "McapBagSource", "write_rosbag", "reindex_ros1"]

#: one topic's messages as the bag gives them: record times [ns] and raw bytes
_Raw = tuple[list[int], list[bytes]]


class RosbagSource(LogSource):
    """A ROS 1 ``.bag`` (``fmt="bag"``) or a ROS 2 bag directory / ``.db3`` / ``.mcap`` file."""

    default_field = "data"
    recorder_times = True

    def __init__(self, path: str | Path, fmt: str) -> None:
        super().__init__(path)
        self.format = fmt
        self._ros1 = fmt == "bag"
        self._typestores: dict[int, Typestore] = {}
        self._reader: Ros1Reader | Ros2Reader | None = None
        self._raw: dict[str, _Raw] = {}
        try:
            reader = Ros1Reader(self.path) if self._ros1 else Ros2Reader(self.path)
            reader.open()
            self._reader = reader
        except LogReadError:
            raise
        except Exception as err:  # noqa: BLE001 - rosbags raises ReaderError, KeyError, sqlite errors...
            detail = one_line(err)
            salvaged = self._ros1 and self._salvage()
            if not salvaged:
                hint = " (and no complete chunk to salvage: cut off inside the first?)" if self._ros1 else ""
                raise LogReadError(f"{self.path}: cannot open the {'ROS 1' if self._ros1 else 'ROS 2'} "
                                   f"bag: {detail}{hint}") from None
        self._conns = {c.topic: c for c in self._bag.connections}

    @property
    def _bag(self) -> Ros1Reader | Ros2Reader:
        """The open reader (LogReadError once closed)."""
        if self._reader is None:
            raise LogReadError(f"{self.path}: the bag is closed")
        return self._reader

    def _salvage(self) -> bool:
        """Read a ROS 1 bag whose index is missing or cut off, as ``rosbag reindex`` would.

        A bag is written chunk by chunk and indexed at the end, so a recording cut short (a crash,
        a full disk, a copy stopped at 99 %) loses its index and rosbags refuses it. The chunks
        before the cut are complete: :func:`reindex_ros1` walks them and rebuilds the index in
        the reader, with one warning saying what was salvaged (the same wording as a truncated
        MCAP). Returns False when not a single message could be recovered.
        """
        reader = Ros1Reader(self.path)
        try:
            n_msgs, n_chunks, notes = reindex_ros1(reader)
        except Exception:  # noqa: BLE001 - not even the bag header is readable
            n_msgs, n_chunks, notes = 0, 0, []
        if n_msgs == 0:
            if reader.bio is not None:
                reader.close()
            return False
        self._reader = reader
        self.warn(f"truncated or corrupt ROS 1 bag: salvaged {n_msgs} messages from {n_chunks} complete "
                  f"chunk(s), as `rosbag reindex` would ({'; '.join(notes)})")
        return True

    def close(self) -> None:
        self._raw = {}
        reader = self._reader
        if reader is not None:
            try:
                reader.close()
            except Exception:  # noqa: BLE001 - closing a half-open reader
                pass
            self._reader = None

    def _typestore(self, conn: Connection) -> Typestore:
        if conn.id not in self._typestores:
            ts = None
            text = conn.msgdef.data or ""
            if text and conn.msgdef.format.name == "MSG":
                try:
                    ts = typestore_from_text(text, conn.msgtype, ros1=self._ros1)
                except Exception:  # noqa: BLE001 - use the standard definitions instead
                    ts = None
            if ts is None:
                ts = typestore_for(ros1=self._ros1)
                if conn.msgtype not in ts.fielddefs:
                    raise LogReadError(f"{self.path}: {conn.topic}: no definition for type {conn.msgtype!r}")
            self._typestores[conn.id] = ts
        return self._typestores[conn.id]

    def _conn(self, topic: str) -> Connection:
        conn = self._conns.get(topic)
        if conn is None:
            raise self.missing_topic(topic)
        return conn

    def _times(self) -> dict[str, np.ndarray]:
        out: dict[str, list[int]] = {topic: [] for topic in self._conns}
        reader = self._bag
        if isinstance(reader, Ros1Reader):
            for conn in reader.connections:
                out[conn.topic].extend(entry.time for entry in reader.indexes[conn.id])
        else:
            try:
                for conn, stamp, _ in reader.messages(reader.connections):
                    out[conn.topic].append(stamp)
            except Exception as err:  # noqa: BLE001
                raise LogReadError(f"{self.path}: corrupt bag data ({type(err).__name__})") from None
        return {k: np.asarray(v, dtype=np.int64) for k, v in out.items()}

    def topics(self) -> list[TopicInfo]:
        times = self._times()
        out: list[TopicInfo] = []
        for topic, conn in sorted(self._conns.items()):
            t = np.sort(times[topic]) / 1e9
            try:
                fields = tuple(numeric_leaves(self._typestore(conn), conn.msgtype))
            except Exception:  # noqa: BLE001 - listing must not fail on one odd type
                fields = ()
            out.append(TopicInfo(topic, conn.msgtype, len(t), mean_rate_hz(t), fields))
        return out

    def leaves(self, topic: str, field: str | None) -> list[str]:
        conn = self._conn(topic)
        with cdr.naming(self.path, topic):
            return cdr.leaf_paths(self._typestore(conn), conn.msgtype,
                                  field if field is not None else self.default_field)

    def prefetch(self, topics: list[str]) -> None:
        """Collect the raw messages of all wanted topics in one pass over the bag."""
        conns = [self._conns[t] for t in topics if t in self._conns and t not in self._raw]
        if conns:
            self._raw.update(self._collect(conns))

    def _collect(self, conns: list[Connection]) -> dict[str, _Raw]:
        out: dict[str, _Raw] = {c.topic: ([], []) for c in conns}
        try:
            for conn, stamp, data in self._bag.messages(conns):
                stamps, datas = out[conn.topic]
                stamps.append(stamp)
                datas.append(data)
        except Exception as err:  # noqa: BLE001 - rosbags raises several kinds on damaged data
            raise LogReadError(f"{self.path}: corrupt bag data ({type(err).__name__}: "
                               f"{one_line(err)})") from None
        return out

    def read(self, topic: str, fields: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        conn = self._conn(topic)
        if topic not in self._raw:
            self._raw.update(self._collect([conn]))
        stamps, datas = self._raw[topic]
        with cdr.naming(self.path, topic):
            vals = cdr.extract(self._typestore(conn), conn.msgtype, *cdr.packed(datas), fields, ros1=self._ros1)
        return np.asarray(stamps, dtype=np.int64) / 1e9, vals


class McapBagSource(LogSource):
    """A ROS 2 bag with mcap storage split over several files (``--max-bag-size``), read file by file
    with :class:`~mrftcli.io.format_mcap.McapSource` and merged in log-time order.

    rosbags reads these too, but decompresses each chunk whole with no limit and walks every
    message of every topic; the MCAP reader holds one chunk at a time, keeps only the wanted
    topics' bytes and refuses decompression bombs (:mod:`mrftcli.io.mcap_stream`). Bags whose
    messages are compressed one by one (``compression_mode: message``) stay with rosbags.
    """

    default_field = "data"
    recorder_times = True

    def __init__(self, path: str | Path, files: list[Path]) -> None:
        from .format_mcap import McapSource

        super().__init__(path)
        self.format = "ros2-mcap"
        self._parts: list[McapSource] = []
        try:
            for file in files:
                part = McapSource(file)
                part.echo_warnings = False
                self._parts.append(part)
        except BaseException:
            self.close()
            raise
        for part in self._parts:
            self.warnings.extend(w for w in part.warnings if w not in self.warnings)

    def close(self) -> None:
        for part in self._parts:
            part.close()

    def _holding(self, topic: str) -> list[LogSource]:
        parts: list[LogSource] = [p for p in self._parts if topic in p.topic_names()]
        if not parts:
            raise self.missing_topic(topic)
        return parts

    def topics(self) -> list[TopicInfo]:
        times: dict[str, list[np.ndarray]] = defaultdict(list)
        types: dict[str, str] = {}
        fields: dict[str, tuple[str, ...]] = {}
        for part in self._parts:
            names = part.channel_topics()
            for cid, t_ns in part.channel_times().items():
                topic, msgtype = names[cid]
                times[topic].append(t_ns)
                types.setdefault(topic, msgtype)
                fields.setdefault(topic, part.topic_fields(topic))
        out = []
        for topic in sorted(times):
            t = np.sort(np.concatenate(times[topic])) / 1e9
            out.append(TopicInfo(topic, types[topic], len(t), mean_rate_hz(t), fields[topic]))
        return out

    def leaves(self, topic: str, field: str | None) -> list[str]:
        return self._holding(topic)[0].leaves(topic, field)

    def prefetch(self, topics: list[str]) -> None:
        for part in self._parts:
            part.prefetch([t for t in topics if t in part.topic_names()])

    def read(self, topic: str, fields: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        reads = [part.read(topic, fields) for part in self._holding(topic)]
        t = np.concatenate([r[0] for r in reads])
        order = np.argsort(t, kind="stable")  # files in any order; ties keep file order
        return t[order], {f: np.concatenate([r[1][f] for r in reads])[order] for f in fields}


def _fields(data: bytes) -> Header:
    """A ROS 1 record's data section parsed as header fields (connection details)."""
    from rosbags.rosbag1.reader import Header

    return Header.read(io.BytesIO(struct.pack("<I", len(data)) + data))


def _connection(header: Header, data: bytes, owner: Ros1Reader) -> Connection:
    """A rosbags ``Connection`` from a connection record (its header and its data section)."""
    from rosbags.interfaces import Connection, ConnectionExtRosbag1, MessageDefinition, MessageDefinitionFormat
    from rosbags.rosbag1.reader import normalize
    from rosbags.typesys.msg import normalize_msgtype

    details = _fields(data)
    callerid = details.get_string("callerid") if "callerid" in details else None
    latching = details.get_string("latching") if "latching" in details else None
    return Connection(header.get_uint32("conn"), normalize(header.get_string("topic")),
                      normalize_msgtype(details.get_string("type")),
                      MessageDefinition(MessageDefinitionFormat.MSG, details.get_string("message_definition")),
                      details.get_string("md5sum"), 0,
                      ConnectionExtRosbag1(callerid, int(latching) if latching not in (None, "") else None), owner)


def reindex_ros1(reader: Ros1Reader) -> tuple[int, int, list[str]]:
    """Rebuild the index of a ROS 1 (v2.0) bag in an unopened rosbags ``Reader`` by walking its records.

    What ``rosbag reindex`` does, in memory and without writing: after the bag header, every record
    is read in file order; each *complete* chunk is decompressed and its connection and message
    records indexed (time, chunk position, offset in the chunk); connection records of the index
    section are kept; the walk stops at the first record that is cut off or unreadable. The reader
    is left open (``bio``) with ``connections``, ``chunks``, ``chunk_infos`` and ``indexes`` set, so
    its ``messages()`` reads the salvaged messages.

    Returns
    -------
    (messages, chunks, notes)
        Messages and chunks recovered, and what was lost (for the warning).
    """
    from rosbags.rosbag1 import reader as r1

    T = r1.RecordType
    bio = reader.path.open("rb")
    reader.bio = bio
    size = os.fstat(bio.fileno()).st_size
    if bio.readline() != b"#ROSBAG V2.0\n":
        raise r1.ReaderError("not a ROS 1 v2.0 bag")
    r1.Header.read(bio, T.BAGHEADER)
    bio.seek(r1.read_uint32(bio), os.SEEK_CUR)  # the header record's padding
    conns: dict[int, Connection] = {}
    indexes: dict[int, list[r1.IndexData]] = defaultdict(list)
    chunks: dict[int, r1.Chunk] = {}
    infos: list[r1.ChunkInfo] = []
    stop = None
    while bio.tell() < size:
        pos = bio.tell()
        try:
            header = r1.Header.read(bio)
            op = header.get_uint8("op")
            datasize = r1.read_uint32(bio)
            if bio.tell() + datasize > size:
                stop = ("the file ends inside a chunk (its messages are lost)" if op == T.CHUNK
                        else "the file ends inside an index record (no message lost)")
                break
            datapos = bio.tell()
            data = r1.read_bytes(bio, datasize)
            if op == T.CHUNK:
                decompress = r1.decompressors[header.get_string("compression")]
                raw = decompress(data)
                counts: dict[int, int] = defaultdict(int)
                times: list[int] = []
                chunk = io.BytesIO(raw)
                while chunk.tell() < len(raw):
                    offset = chunk.tell()
                    rec = r1.Header.read(chunk)
                    body = r1.read_bytes(chunk, r1.read_uint32(chunk))
                    rop = rec.get_uint8("op")
                    if rop == T.CONNECTION:
                        c = _connection(rec, body, reader)
                        conns.setdefault(c.id, c)
                    elif rop == T.MSGDATA:
                        conn, t = rec.get_uint32("conn"), rec.get_time("time")
                        indexes[conn].append(r1.IndexData(t, pos, offset))
                        counts[conn] += 1
                        times.append(t)
                chunks[pos] = r1.Chunk(datasize, datapos, decompress)
                infos.append(r1.ChunkInfo(pos, min(times, default=2**63 - 1), max(times, default=-1) + 1, dict(counts)))
            elif op == T.CONNECTION:
                c = _connection(header, data, reader)
                conns.setdefault(c.id, c)
        except Exception:  # noqa: BLE001 - a damaged record ends the walk (rosbag reindex stops there too)
            stop = f"an unreadable record at byte {pos} (what follows is lost)"
            break
    known = {k: v for k, v in indexes.items() if k in conns}
    reader.connections = [c._replace(msgcount=len(known.get(c.id, ()))) for c in conns.values()]
    reader.indexes = {c.id: sorted(known.get(c.id, [])) for c in reader.connections}
    reader.chunks, reader.chunk_infos = chunks, infos
    notes = ["its index is missing or cut off"] + ([stop] if stop else [])
    lost = sum(len(v) for k, v in indexes.items() if k not in conns)
    if lost:
        notes.append(f"{lost} message(s) of connections never described dropped")
    return sum(len(v) for v in known.values()), len(chunks), notes


def write_rosbag(topics: list[TopicData], path: str | Path, fmt: str) -> None:
    """Write a ROS 1 bag (``fmt="bag"``) or a ROS 2 bag directory (``ros2-sqlite3``/``ros2-mcap``)."""
    ros1 = fmt == "bag"
    ts = typestore_for(ros1=ros1)
    messages = time_ordered(topics, lambda td: cdr.serialize_many(ts, td.msgtype, np.asarray(td.t, np.float64),
                                                                   td.fields, ros1=ros1))
    # compressed as recorders commonly do (4-5x smaller for these small messages, reads as fast):
    # ROS 1 LZ4 chunks (`rosbag record --lz4`); ROS 2 mcap storage zstd chunks; ROS 2 sqlite3 a
    # zstd-compressed database file (per-message compression gains little on 100-byte messages)
    writer = _ros1_writer(Path(path)) if ros1 else _ros2_writer(Path(path), fmt)
    with writer:
        conns = [writer.add_connection(td.name, td.msgtype, typestore=ts) for td in topics]
        for w, ns, data in messages:
            writer.write(conns[w], ns, data)


def _ros1_writer(path: Path) -> Ros1Writer:
    """A ROS 1 bag writer with LZ4 chunks of 256 KiB.

    rosbags' default chunk is 1 MiB: a recording cut short loses at most the chunk being written
    (the others are salvaged, see :func:`reindex_ros1`), as with our MCAP chunks.
    """
    from rosbags.rosbag1 import Writer

    writer = Writer(path)
    writer.set_compression(Writer.CompressionFormat.LZ4)
    writer.chunk_threshold = 256 * 1024
    return writer


def _ros2_writer(path: Path, fmt: str) -> Ros2Writer:
    """A ROS 2 bag writer: mcap storage with zstd chunks, or a zstd-compressed sqlite3 file."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if fmt == "ros2-mcap" else StoragePlugin.SQLITE3
    writer = Writer(path, version=9, storage_plugin=plugin)
    writer.set_compression(CompressionMode.STORAGE if fmt == "ros2-mcap" else CompressionMode.FILE,
                           CompressionFormat.ZSTD)
    return writer
