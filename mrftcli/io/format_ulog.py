"""PX4 ULog: reading with pyulog, writing with a small numpy writer.

Naming (both directions):

* a ROS-style topic ``/mrft/command`` is the ULog message ``mrft_command`` (leading ``/`` dropped,
  other ``/`` and any character outside ``[A-Za-z0-9_]`` become ``_``); a ULog message name is also
  accepted as is (``vehicle_attitude``); ``name.N`` selects multi-instance ``N`` (default 0);
* a dotted FIELD is the flattened ULog field pyulog reports: nested types give ``pose.position.z``,
  arrays give ``q[0]``;
* time is the message's ``timestamp`` field [us] -> s.

Quaternions: a field with ``.x .y .z .w`` sub-fields, or a 4-array ``q[0..3]`` in PX4's order
``(w, x, y, z)`` (``vehicle_attitude:q``).

Why a hand-written writer: pyulog's ``ULog.write_ulog`` only re-serialises a ``ULog`` object that was
parsed from a file (there is no public way to build one from data) and packs each sample with
``struct.pack`` in Python. The format is simple (PX4 "ULog file format" spec: 16-byte header, then
``(uint16 size, uint8 type)``-framed messages); here every topic's data messages are one packed numpy
record array, interleaved in time order with one vectorised scatter.
"""

from __future__ import annotations

import contextlib
import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeAlias

import numpy as np

from ..errors import InputError, LogReadError
from .atomic import atomic_path
from .logtypes import TopicData, TopicInfo
from .source import Field, LogSource, one_line
from .timing import mean_rate_hz

__all__ = ["UlogSource", "write_ulog", "check_format_sizes"]

ULOG_MAGIC = b"ULog\x01\x12\x35"

#: pyulog's objects (``ULog``, ``ULog.Data``): the package has no type information
_PyUlog: TypeAlias = Any
#: dotted field paths as a tree: a leaf is None
_Tree: TypeAlias = "dict[str, _Tree | None]"


#: bytes of each ULog base type (PX4 "ULog file format")
_BASE_SIZES = {"int8_t": 1, "uint8_t": 1, "bool": 1, "char": 1, "int16_t": 2, "uint16_t": 2, "int32_t": 4,
               "uint32_t": 4, "float": 4, "int64_t": 8, "uint64_t": 8, "double": 8}
#: a data message's frame holds a uint16 size: no message format can be larger
_MAX_MESSAGE = 0xFFFF
_FIELD = re.compile(r"^\s*([A-Za-z_][\w]*)(?:\[(\d+)\])?\s+\S+\s*$")


def _format_definitions(data: bytes) -> dict[str, list[tuple[str, int]]]:
    """The ``F`` messages of the definitions section (up to the first subscription or data message):
    for each format name its fields as (type, count)."""
    import struct

    unpack = struct.Struct("<HB").unpack_from
    formats: dict[str, list[tuple[str, int]]] = {}
    pos = 16
    while pos + 3 <= len(data):
        size, kind = unpack(data, pos)
        if kind in (ord("A"), ord("D")):
            break
        if kind == ord("F"):
            text = data[pos + 3:pos + 3 + size].decode("ascii", "replace")
            name, _, body = text.partition(":")
            fields = []
            for part in body.split(";"):
                match = _FIELD.match(part)
                if match:
                    fields.append((match.group(1), int(match.group(2) or 1)))
            formats[name.strip()] = fields
        pos += 3 + size
    return formats


def check_format_sizes(path: Path) -> None:
    """Refuse a ULog whose message formats declare more bytes than a ULog message can hold.

    pyulog builds each format's numpy type before reading a byte of data: a 168-byte file nesting
    ``inner[65535]`` of ``uint8_t[65535]`` asked for 3.9 GB (issue 35). A data message's frame has a
    uint16 size, so a format over 65535 bytes (or one that contains itself) is damage or hostility:
    one-line :class:`~mrftcli.errors.LogReadError` before pyulog parses.
    """
    with open(path, "rb") as fh:
        data = fh.read(1 << 22)  # the definitions come first; 4 MB is far more than any stack writes
    formats = _format_definitions(data)
    sizes: dict[str, int] = {}

    def size_of(name: str, depth: int) -> int:
        if name in _BASE_SIZES:
            return _BASE_SIZES[name]
        if name in sizes:
            return sizes[name]
        if name not in formats:
            return 0  # an unknown type is pyulog's to report
        if depth > 32:
            return _MAX_MESSAGE + 1
        sizes[name] = _MAX_MESSAGE + 1  # while it is measured: a format containing itself is too large
        total = 0
        for kind, count in formats[name]:
            total += size_of(kind, depth + 1) * count
            if total > _MAX_MESSAGE:
                break
        sizes[name] = total
        return total

    for name in formats:
        if size_of(name, 0) > _MAX_MESSAGE:
            raise LogReadError(f"{path}: ULog format {name!r} declares more than {_MAX_MESSAGE} bytes per message "
                               "(nested arrays), more than a ULog message can hold; the file is damaged")


def ulog_name(topic: str) -> str:
    """ULog message name for a ROS-style topic (``/mrft/command`` -> ``mrft_command``)."""
    return re.sub(r"[^A-Za-z0-9_]", "_", topic.lstrip("/"))


class UlogSource(LogSource):
    """A ``.ulg`` file parsed by pyulog (only the messages asked for, when reading series)."""

    format = "ulog"
    default_field = None

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        self._require_file()
        check_format_sizes(self.path)
        self._end_checked = False
        self._header = self._parse(None, header_only=True)
        self._full: _PyUlog | None = None
        self._cache: dict[tuple[str, int], _PyUlog] = {}

    def _parse(self, names: list[str] | None, header_only: bool = False) -> _PyUlog:
        from pyulog import ULog

        noise = io.StringIO()  # pyulog prints its corruption notices; turn them into one warning
        try:
            with contextlib.redirect_stdout(noise), contextlib.redirect_stderr(noise):
                ulog = ULog(str(self.path), message_name_filter_list=names,
                            parse_header_only=header_only)
        except Exception as err:  # noqa: BLE001 - pyulog raises several kinds on bad bytes
            detail = one_line(err)
            raise LogReadError(f"{self.path}: not a readable ULog file ({detail})") from None
        if not header_only and (ulog.file_corruption or "corrupt" in noise.getvalue().lower()):
            self.warn("ULog file is corrupt or truncated; pyulog skipped the damaged part")
        if not header_only and not self._end_checked:
            self._end_checked = True
            if self._ends_inside_a_message():
                self.warn("ULog file ends inside a message (cut off?); read up to the last whole one")
        return ulog

    def _ends_inside_a_message(self) -> bool:
        """Walk the message frames (uint16 size, uint8 type): does the last one run past the end?

        pyulog stops silently at a cut message; this pass (about 1.5 us per message) says so.
        Files with appended data (an incompat flag) are not checked.
        """
        import struct

        data = self.path.read_bytes()
        if len(data) > 16 + 3 + 40 and data[16 + 2:16 + 3] == b"B" and data[16 + 3 + 8] & 1:
            return False  # appended-data offsets: frames do not simply chain to the end
        unpack = struct.Struct("<H").unpack_from
        pos, end = 16, len(data)
        while pos + 3 <= end:
            pos += 3 + unpack(data, pos)[0]
        return pos != end

    def _all(self) -> _PyUlog:
        if self._full is None:
            self._full = self._parse(None)
        return self._full

    @staticmethod
    def _key(name: str, multi_id: int) -> str:
        return name if multi_id == 0 else f"{name}.{multi_id}"

    @staticmethod
    def _split(topic: str) -> tuple[str, int]:
        name, dot, inst = topic.rpartition(".")
        if dot and inst.isdigit():
            return name, int(inst)
        return topic, 0

    def topics(self) -> list[TopicInfo]:
        out: list[TopicInfo] = []
        for d in self._all().data_list:
            t = d.data["timestamp"].astype(np.float64) / 1e6
            fields = tuple(k for k in d.data if k != "timestamp")
            out.append(TopicInfo(self._key(d.name, d.multi_id), d.name, len(t), mean_rate_hz(np.sort(t)),
                                 fields))
        return sorted(out, key=lambda i: i.name)

    def topic_names(self) -> list[str]:
        if self._full is not None:
            return [i.name for i in self.topics()]
        formats = self._header.message_formats
        nested = {typ for fmt in formats.values() for typ, _, _ in fmt.fields}
        return sorted(set(formats) - nested)  # formats of logged messages, not their nested types

    def resolve_topic(self, topic: str) -> str | None:
        name, inst = self._split(topic)
        formats = self._header.message_formats
        for cand in (name, ulog_name(name)):
            if cand in formats:
                return self._key(cand, inst)
        return None

    def _dataset(self, topic: str) -> _PyUlog:
        name, inst = self._split(topic)
        key = (name, inst)
        if key not in self._cache:
            ulog = self._full if self._full is not None else self._parse([name])
            found = [d for d in ulog.data_list if d.name == name and d.multi_id == inst]
            if not found:
                others = sorted({self._key(d.name, d.multi_id) for d in ulog.data_list if d.name == name})
                extra = f"; instances logged: {', '.join(others)}" if others else ""
                raise LogReadError(f"{self.path}: ULog message {topic!r} has no data{extra}")
            self._cache[key] = found[0]
        return self._cache[key]

    def prefetch(self, topics: list[str]) -> None:
        """Parse the file once for all these messages (pyulog reads the whole file per call)."""
        if self._full is not None:
            return
        wanted = {self._split(self.resolve_topic(t) or t)[0] for t in topics}
        wanted = {w for w in wanted if (w, 0) not in self._cache}
        if not wanted:
            return
        ulog = self._parse(sorted(wanted))
        for d in ulog.data_list:
            self._cache.setdefault((d.name, d.multi_id), d)

    def logged_messages(self) -> list[tuple[float, str, str]]:
        """Text messages the autopilot logged: (time [s], level, text)."""
        return [(m.timestamp / 1e6, m.log_level_str(), m.message) for m in self._all().logged_messages]

    def parameters(self) -> tuple[dict[str, float], list[tuple[float, str, float]]]:
        """The parameters at the start and every logged change: ``(initial, [(t [s], name, value)])``.

        A change is stamped with the time of the last data message before it (how PX4 and pyulog
        place ``P`` messages in the data section).
        """
        ulog = self._all()
        initial = {k: float(v) for k, v in ulog.initial_parameters.items() if isinstance(v, (int, float))}
        changes = [(t / 1e6, k, float(v)) for t, k, v in ulog.changed_parameters if isinstance(v, (int, float))]
        return initial, changes

    def leaves(self, topic: str, field: str | None) -> list[str]:
        resolved = self.resolve_topic(topic)
        if resolved is None:
            raise self.missing_topic(topic)
        data = self._dataset(resolved).data
        names = [k for k in data if k != "timestamp"]
        available = set(names)
        if field is None:
            if "data" in available:
                return ["data"]
            if len(names) == 1:
                return names
            raise LogReadError(f"{self.path}: {topic} has several fields; name one with "
                               f"{topic}:FIELD ({', '.join(names[:12])})")
        if field in available:
            return [field]
        quat = Field.quaternion(field, available, seps=(".",))
        if quat:
            return quat
        if all(f"{field}[{i}]" in available for i in range(4)) and f"{field}[4]" not in available:
            return [f"{field}[1]", f"{field}[2]", f"{field}[3]", f"{field}[0]"]  # PX4: (w, x, y, z)
        from .source import closest

        raise LogReadError(f"{self.path}: {topic} has no field {field!r}{closest(field, names)}; "
                           f"fields: {', '.join(names[:20])}")

    def read(self, topic: str, fields: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        resolved = self.resolve_topic(topic) or topic
        data = self._dataset(resolved).data
        t = data["timestamp"].astype(np.float64) / 1e6
        return t, {f: data[f].astype(np.float64) for f in fields}


# -- writing ------------------------------------------------------------------------------------------
def _message(kind: bytes, payload: bytes) -> bytes:
    return len(payload).to_bytes(2, "little") + kind + payload


def _tree(paths: list[str]) -> _Tree:
    root: _Tree = {}
    for path in paths:
        node = root
        parts = path.split(".")
        for part in parts[:-1]:
            child = node.setdefault(part, {})
            if child is None:
                raise InputError(f"cannot write {path!r}: {part!r} is a number and a message")
            node = child
        node[parts[-1]] = None
    return root


def _formats(name: str, tree: _Tree, prefix: str, out: list[str]) -> list[str]:
    """Format strings for ``name`` and its nested types; returns the flattened leaf order."""
    fields: list[str] = []
    leaves: list[str] = []
    if not prefix:
        fields.append("uint64_t timestamp")
    arrays: dict[str, int] = {}  # name[i] leaves become one ``double[N] name`` field (PX4's arrays)
    for key in tree:
        m = re.fullmatch(r"(\w+)\[(\d+)\]", key)
        if m and tree[key] is None:
            arrays[m.group(1)] = max(arrays.get(m.group(1), 0), int(m.group(2)) + 1)
    for key, sub in tree.items():
        m = re.fullmatch(r"(\w+)\[(\d+)\]", key)
        if m and sub is None:
            base = m.group(1)
            if base in arrays:
                n = arrays.pop(base)
                fields.append(f"double[{n}] {base}")
                leaves.extend(f"{prefix}{base}[{i}]" for i in range(n))
            continue
        if sub is None:
            fields.append(f"double {key}")
            leaves.append(prefix + key)
        else:
            type_name = f"{name}__{key}"
            leaves.extend(_formats(type_name, sub, prefix + key + ".", out))
            fields.append(f"{type_name} {key}")
    out.append(f"{name}:" + "".join(f + ";" for f in fields))
    return leaves


def _parameter(name: str, value: float) -> bytes:
    """A ``P`` message: ``int32_t`` for whole numbers (PX4's enable switches), else ``float``."""
    import struct

    if float(value).is_integer() and not name.endswith(("_BETA", "_H")):
        key, packed = f"int32_t {name}".encode(), struct.pack("<i", int(value))
    else:
        key, packed = f"float {name}".encode(), struct.pack("<f", float(value))
    return _message(b"P", bytes([len(key)]) + key + packed)


@dataclass(frozen=True)
class _UlogTopic:
    """One topic as ULog: its message name, format definitions, stamps [us] and data-message rows."""

    name: str
    formats: list[str]
    stamps: np.ndarray
    rows: np.ndarray  # (messages, bytes per message) uint8


def write_ulog(topics: list[TopicData], path: str | Path, *, parameters: dict[str, float] | None = None,
               parameter_changes: list[tuple[float, str, float]] | None = None,
               messages: list[tuple[float, str]] | None = None) -> None:
    """Write topics as ULog (version 1): one message per topic, ``double`` fields (``name[i]`` leaves
    as one array field), nested types for dotted field paths, ``timestamp`` [us] from the topic times.

    ``parameters`` are written as the initial parameters; ``parameter_changes`` ``(t [s], name,
    value)`` and text ``messages`` ``(t [s], text)`` go into the data section after the last data
    message at or before ``t`` (pyulog stamps a change with that message's time)."""
    t_all = np.concatenate([np.asarray(td.t, dtype=np.float64) for td in topics] or [np.zeros(1)])
    start_us = int(np.floor(t_all.min() * 1e6)) if len(t_all) else 0
    head = ULOG_MAGIC + b"\x01" + start_us.to_bytes(8, "little")
    definitions = [_message(b"B", bytes(16) + bytes(24))]  # flag bits: no (in)compat flags, no appended data
    info_key = b"char[10] sys_name"
    definitions.append(_message(b"I", bytes([len(info_key)]) + info_key + b"mrft-ident"))
    encoded: list[_UlogTopic] = []
    for msg_id, td in enumerate(topics):
        topic = _ulog_topic(msg_id, td)
        if any(other.name == topic.name for other in encoded):
            raise ValueError(f"two topics map to the ULog message {topic.name!r}")
        encoded.append(topic)
        definitions.extend(_message(b"F", f.encode()) for f in topic.formats)
    subscriptions = [_message(b"A", bytes([0]) + k.to_bytes(2, "little") + topic.name.encode())
                     for k, topic in enumerate(encoded)]
    data, sorted_stamps, ends = _interleave(encoded)
    definitions.extend(_parameter(k, v) for k, v in (parameters or {}).items())
    extra = [(t, _parameter(k, v)) for t, k, v in (parameter_changes or [])]
    for t, text in messages or []:
        body = bytes([ord("6")]) + int(round(t * 1e6)).to_bytes(8, "little") + text.encode()
        extra.append((t, _message(b"L", body)))
    if extra:
        data = _insert_after(data, sorted_stamps, ends, extra)
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:  # a killed run leaves no cut log
        handle.write(head)
        handle.write(b"".join(definitions))
        handle.write(b"".join(subscriptions))
        handle.write(data.tobytes())


def _ulog_topic(msg_id: int, td: TopicData) -> _UlogTopic:
    """One topic's format definitions and data messages (a quaternion's missing parts: x, y, z 0, w 1)."""
    name = ulog_name(td.name)
    fields = dict(td.fields)
    for key in list(fields):
        prefix, _, comp = key.rpartition(".")
        if comp in "xyzw" and prefix.endswith("orientation"):
            n = len(td.t)
            for c in "xyzw":
                fields.setdefault(f"{prefix}.{c}", np.full(n, 1.0 if c == "w" else 0.0))
    formats: list[str] = []
    leaves = _formats(name, _tree(list(fields)), "", formats)
    stamps = np.round(np.asarray(td.t, dtype=np.float64) * 1e6).astype(np.int64)
    if len(stamps) and stamps.min() < 0:
        raise ValueError("ULog timestamps must be >= 0 s")
    dtype = np.dtype([("size", "<u2"), ("type", "u1"), ("msg_id", "<u2"), ("timestamp", "<u8")]
                     + [(f"f{i}", "<f8") for i in range(len(leaves))])
    rec = np.zeros(len(stamps), dtype=dtype)
    rec["size"] = dtype.itemsize - 3
    rec["type"] = ord("D")
    rec["msg_id"] = msg_id
    rec["timestamp"] = stamps
    for i, leaf in enumerate(leaves):
        rec[f"f{i}"] = np.asarray(fields[leaf], dtype=np.float64)
    return _UlogTopic(name, formats, stamps, rec.view(np.uint8).reshape(len(stamps), dtype.itemsize))


def _interleave(topics: list[_UlogTopic]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The data messages of all topics in time order (one scatter per topic), their stamps [us] in
    that order and the byte offset where each ends."""
    stamps = np.concatenate([tp.stamps for tp in topics] or [np.zeros(0, np.int64)])
    which = np.concatenate([np.full(len(tp.stamps), k) for k, tp in enumerate(topics)] or [np.zeros(0, int)])
    sizes = np.concatenate([np.full(len(tp.stamps), tp.rows.shape[1]) for tp in topics] or [np.zeros(0, int)])
    order = np.lexsort((which, stamps))
    position = np.empty(len(order), dtype=np.int64)
    position[order] = np.concatenate([[0], np.cumsum(sizes[order])[:-1]]) if len(order) else []
    data = np.zeros(int(sizes.sum()), dtype=np.uint8)
    first = 0
    for tp in topics:
        pos = position[first:first + len(tp.rows)]
        data[pos[:, None] + np.arange(tp.rows.shape[1])] = tp.rows
        first += len(tp.rows)
    return data, stamps[order], np.cumsum(sizes[order])


def _insert_after(data: np.ndarray, sorted_stamps: np.ndarray, ends: np.ndarray,
                  extra: list[tuple[float, bytes]]) -> np.ndarray:
    """``data`` with each extra message ``(t [s], bytes)`` after the last data message stamped at or
    before its time."""
    raw = data.tobytes()
    pieces: list[bytes] = []
    last = 0
    for t, blob in sorted(extra, key=lambda e: e[0]):
        k = int(np.searchsorted(sorted_stamps, int(round(t * 1e6)), side="right"))
        cut = int(ends[k - 1]) if k else 0
        pieces.extend([raw[last:cut], blob])
        last = cut
    pieces.append(raw[last:])
    return np.frombuffer(b"".join(pieces), dtype=np.uint8)
