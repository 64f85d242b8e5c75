"""Vectorised access to fields of serialised ROS messages (ROS 2 CDR and ROS 1), and the reverse.

Decoding one message at a time into Python objects costs tens of microseconds per message. Here a whole
topic is handled at once: the raw messages sit in one ``uint8`` buffer and an array holds where each
message starts. :func:`extract` walks the message definition (from a rosbags ``Typestore``) once, with
the current byte position of *every* message in one numpy array. Fixed-size fields just add a constant;
variable-size ones (strings such as ``header.frame_id``, sequences) add a per-message length read with one
numpy gather. Wanted leaves are gathered the same way. So a 120 000-message topic costs a few dozen
numpy operations, not 120 000 Python calls.

CDR (ROS 2): a 4-byte encapsulation header (byte 1 = 1 for little endian), then the body; primitives are
aligned to their size *relative to the body start*; strings are ``uint32`` length (including the NUL) +
bytes; sequences ``uint32`` count + elements (aligned to the element size only when not empty, as
rosbags and Fast-CDR do). ROS 1: no header, no alignment, little endian, strings without NUL.

The writer side (:func:`serialize_many`) uses the same walk on a template message: with a fixed
``frame_id`` and empty sequences every message of a topic has the same layout, so all messages are one
``(n, size)`` byte array filled column-wise.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from rosbags.interfaces import Nodetype

from ..errors import LogReadError

if TYPE_CHECKING:
    from rosbags.interfaces.typing import BaseDesc, FieldDesc, NameDesc
    from rosbags.typesys.store import Typestore

__all__ = ["extract", "packed", "naming", "leaf_paths", "serialize_many", "default_message", "CdrLayoutError", "struct_fields"]

_SIZE = {
    "bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1,
    "int16": 2, "uint16": 2, "int32": 4, "uint32": 4, "float32": 4,
    "int64": 8, "uint64": 8, "float64": 8,
}
_DTYPE = {
    "bool": "u1", "byte": "u1", "char": "u1", "int8": "i1", "uint8": "u1",
    "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4", "float32": "f4",
    "int64": "i8", "uint64": "u8", "float64": "f8",
}


class CdrLayoutError(LogReadError):
    """A requested field does not exist in the message type, or messages are shorter than their type."""


class _Unsupported(Exception):
    """The walker cannot skip this field kind (``wstring``): use the per-message decoder instead."""


class _Walk:
    """One pass over a message definition for many messages at once."""

    def __init__(self, typestore: Typestore, buf: np.ndarray, body: np.ndarray, end: np.ndarray,
                 ros1: bool, big: np.ndarray | None, targets: set[str]) -> None:
        self.ts = typestore
        self.buf = buf
        self.body = body
        self.end = end
        self.ros1 = ros1
        self.big = big if big is not None and big.any() else None
        self.targets = set(targets)
        self.found: dict[str, tuple[np.ndarray, str, np.ndarray | None]] = {}
        self.last = len(buf) - 1
        self.active: np.ndarray | None = None  # messages that have the element being walked

    # -- primitives -------------------------------------------------------------------------------
    def _align(self, rel: np.ndarray, size: int) -> np.ndarray:
        if self.ros1 or size == 1:
            return rel
        return (rel + (size - 1)) & -size

    def _gather(self, rel: np.ndarray, typ: str) -> np.ndarray:
        size = _SIZE[typ]
        idx = (self.body + rel)[:, None] + np.arange(size)
        np.clip(idx, 0, self.last, out=idx)  # masked-out rows may point past the end; checked later
        raw = self.buf[idx]
        if self.big is not None and size > 1:
            raw[self.big] = raw[self.big, ::-1]
        values: np.ndarray = raw.view("<" + _DTYPE[typ]).ravel()
        return values

    def _record(self, path: str, rel: np.ndarray, typ: str, valid: np.ndarray | None = None) -> None:
        if self.active is not None:  # inside a sequence element that some messages lack
            valid = self.active if valid is None else (valid & self.active)
        self.found[path] = (rel.copy(), typ, valid)
        self.targets.discard(path)

    # -- structure --------------------------------------------------------------------------------
    def struct(self, msgtype: str, prefix: str, rel: np.ndarray) -> np.ndarray:
        for name, desc in self.ts.fielddefs[msgtype][1]:
            if not self.targets:
                return rel
            rel = self.field(prefix + name, desc, rel)
        return rel

    def field(self, path: str, desc: FieldDesc, rel: np.ndarray) -> np.ndarray:
        if desc[0] == Nodetype.NAME:
            if self.ros1 and not any(t.startswith(path + ".") for t in self.targets):
                # ROS 1 has no alignment: a struct without strings/sequences is a constant skip
                size = self._fixed_size(desc)
                if size is not None:
                    return rel + size
            return self.struct(desc[1], path + ".", rel)
        if desc[0] == Nodetype.BASE:
            typ = desc[1][0]
            if typ == "string":
                return self._string(rel)
            if typ not in _SIZE:
                raise _Unsupported(typ)
            rel = self._align(rel, _SIZE[typ])
            if path in self.targets:
                self._record(path, rel, typ)
            return rel + _SIZE[typ]
        sub, length = desc[1]
        if desc[0] == Nodetype.ARRAY:
            return self._elements(path, sub, rel, np.full(len(rel), length, dtype=np.int64))
        rel = self._align(rel, 4)  # a sequence: uint32 count, then the elements
        count = self._gather(rel, "uint32").astype(np.int64)
        return self._elements(path, sub, rel + 4, count)

    def _string(self, rel: np.ndarray) -> np.ndarray:
        rel = self._align(rel, 4)
        length = self._gather(rel, "uint32").astype(np.int64)
        return rel + 4 + length

    def _elements(self, path: str, sub: BaseDesc | NameDesc, rel: np.ndarray, count: np.ndarray) -> np.ndarray:
        if sub[0] == Nodetype.BASE and sub[1][0] == "wstring":
            raise _Unsupported("wstring")
        if sub[0] == Nodetype.BASE and sub[1][0] != "string":
            typ = sub[1][0]
            size = _SIZE[typ]
            if not self.ros1 and size > 1:
                rel = np.where(count > 0, self._align(rel, size), rel)
            for target in [t for t in self.targets if t.startswith(path + "[")]:
                try:
                    k = int(target[len(path) + 1:-1])
                except ValueError:
                    continue
                self._record(target, rel + k * size, typ, valid=count > k)
            after: np.ndarray = rel + count * size
            return after
        # strings or nested types: one vectorised step per element index, masked by the count
        outer = self.active
        for k in range(int(count.max(initial=0))):
            active = count > k
            self.active = active if outer is None else (outer & active)
            elem_path = f"{path}[{k}]"
            if sub[0] == Nodetype.NAME:
                new = self.struct(sub[1], elem_path + ".", rel)
            else:
                new = self._string(rel)
            rel = np.where(active, new, rel)
        self.active = outer
        return rel

    def _fixed_size(self, desc: FieldDesc) -> int | None:
        """Byte size of a type in ROS 1 (no alignment) if it holds no strings/sequences, else None."""
        if desc[0] == Nodetype.BASE:
            return _SIZE.get(desc[1][0])
        if desc[0] == Nodetype.ARRAY:
            inner = self._fixed_size(desc[1][0])
            return None if inner is None else inner * desc[1][1]
        if desc[0] == Nodetype.NAME:
            total = 0
            for _, sub in self.ts.fielddefs[desc[1]][1]:
                size = self._fixed_size(sub)
                if size is None:
                    return None
                total += size
            return total
        return None


def packed(datas: Sequence[bytes | memoryview]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Messages' bytes end to end, as :func:`extract` takes them: (buffer, each one's start, its length)."""
    lengths = np.fromiter(map(len, datas), dtype=np.int64, count=len(datas))
    starts = (np.cumsum(lengths) - lengths).astype(np.int64)
    return np.frombuffer(b"".join(datas), dtype=np.uint8), starts, lengths


@contextmanager
def naming(path: object, topic: str) -> Iterator[None]:
    """A :class:`~mrftcli.errors.LogReadError` raised inside re-raised with the log and the topic in front."""
    try:
        yield
    except LogReadError as err:
        raise LogReadError(f"{path}: {topic}: {err}") from None


def _message_bounds(starts: np.ndarray, lengths: np.ndarray, ros1: bool,
                    buf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    starts = np.asarray(starts, dtype=np.int64)
    end = starts + np.asarray(lengths, dtype=np.int64)
    if ros1:
        return starts, end, None
    if len(starts) and (lengths < 4).any():
        raise CdrLayoutError("a message is shorter than the 4-byte CDR header")
    big = buf[starts + 1] == 0 if len(starts) else None  # CDR_BE = 0x0000, CDR_LE = 0x0001
    return starts + 4, end, big


def extract(typestore: Typestore, msgtype: str, buf: np.ndarray, starts: np.ndarray,
            lengths: np.ndarray, paths: list[str], ros1: bool = False) -> dict[str, np.ndarray]:
    """Read numeric leaf fields of many serialised messages of one type, as float64 arrays.

    Parameters
    ----------
    typestore : rosbags Typestore
        Knows ``msgtype`` (and the types it nests).
    msgtype : str
        Normalised type name, e.g. ``geometry_msgs/msg/PoseStamped``.
    buf : numpy.ndarray of uint8
        All messages' bytes.
    starts, lengths : numpy.ndarray of int
        Byte offset of each message in ``buf`` (at the CDR encapsulation header for ROS 2) and its size.
    paths : list of str
        Dotted leaf paths (``pose.position.z``; ``name[3]`` indexes arrays and sequences).
    ros1 : bool
        ROS 1 serialisation instead of CDR.

    Returns
    -------
    dict
        path -> float64 array, one value per message (NaN where a sequence is too short).

    Raises
    ------
    CdrLayoutError
        A path is not a numeric leaf of the type, or a message is too short for its type.
    """
    # corrupt or NaN/inf numbers become NaN/inf here, silently: the flight reader leaves them out
    # with its own warning (io/flight); numpy's cast warnings would only reach the terminal
    with np.errstate(invalid="ignore", over="ignore"):
        return _extract(typestore, msgtype, buf, starts, lengths, paths, ros1)


def _extract(typestore: Typestore, msgtype: str, buf: np.ndarray, starts: np.ndarray,
             lengths: np.ndarray, paths: list[str], ros1: bool) -> dict[str, np.ndarray]:
    """:func:`extract` without the floating-point error state."""
    for path in paths:
        leaf_paths(typestore, msgtype, path)  # raises a clear error for unknown/non-leaf paths
    body, end, big = _message_bounds(starts, lengths, ros1, buf)
    walk = _Walk(typestore, buf, body, end, ros1, big, set(paths))
    try:
        walk.struct(msgtype, "", np.zeros(len(body), dtype=np.int64))
    except _Unsupported:
        return _extract_generic(typestore, msgtype, buf, starts, lengths, paths, ros1)
    if walk.targets:
        raise CdrLayoutError(f"field(s) {sorted(walk.targets)} not found in {msgtype}")
    out = {}
    for path in paths:
        rel, typ, valid = walk.found[path]
        stop = body + rel + _SIZE[typ]
        bad = stop > end
        if valid is not None:
            bad &= valid
        if bad.any():
            raise CdrLayoutError(
                f"{int(bad.sum())} message(s) of {msgtype} are too short to hold {path} (corrupt data)")
        values = walk._gather(rel, typ).astype(np.float64)
        if valid is not None:
            values[~valid] = np.nan
        out[path] = values
    return out


def _extract_generic(typestore: Typestore, msgtype: str, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
                     paths: list[str], ros1: bool) -> dict[str, np.ndarray]:
    """Per-message fallback through rosbags' deserialiser (types the walker cannot skip)."""
    decode = typestore.deserialize_ros1 if ros1 else typestore.deserialize_cdr
    raw = buf.tobytes()
    out = {p: np.full(len(starts), np.nan) for p in paths}
    for i, (s, n) in enumerate(zip(starts.tolist(), lengths.tolist())):
        try:
            msg = decode(raw[s:s + n], msgtype)
        except Exception as err:  # noqa: BLE001 - rosbags SerdeError and friends
            raise CdrLayoutError(f"message {i} of {msgtype} cannot be decoded ({type(err).__name__})") from None
        for path in paths:
            node: object = msg
            for part in path.split("."):
                index = None
                if part.endswith("]"):
                    part, index = part[:-1].split("[")
                node = getattr(node, part)
                if index is not None:
                    seq = cast("Sequence[float]", node)
                    node = seq[int(index)] if int(index) < len(seq) else np.nan
            out[path][i] = float(cast("float", node))
    return out


def struct_fields(typestore: Typestore, msgtype: str, path: str) -> FieldDesc | None:
    """The field description at ``path`` inside ``msgtype`` (``(kind, detail)``), None if absent."""
    desc: FieldDesc = (Nodetype.NAME, msgtype)
    for part in path.split(".") if path else []:
        index = None
        if part.endswith("]") and "[" in part:
            part, index = part[:-1].split("[", 1)
        if desc[0] != Nodetype.NAME:
            return None
        fields = dict(typestore.fielddefs[desc[1]][1])
        if part not in fields:
            return None
        desc = fields[part]
        if index is not None:
            if desc[0] == Nodetype.BASE or desc[0] == Nodetype.NAME or not index.isdigit():
                return None
            desc = desc[1][0]
    return desc


def leaf_paths(typestore: Typestore, msgtype: str, path: str) -> list[str]:
    """Check ``path`` and return the numeric leaves it stands for.

    A numeric leaf returns ``[path]``; a struct whose fields are exactly ``x, y, z, w`` (a quaternion)
    returns its four leaves in that order. Anything else raises :class:`CdrLayoutError` listing the
    fields that do exist.
    """
    desc = struct_fields(typestore, msgtype, path)
    if desc is None:
        parent, _, _ = path.rpartition(".")
        pdesc = struct_fields(typestore, msgtype, parent)
        names: list[str] = []
        if pdesc is not None and pdesc[0] == Nodetype.NAME:
            names = [n for n, _ in typestore.fielddefs[pdesc[1]][1]]
        hint = f"; fields there: {', '.join(names)}" if names else ""
        raise CdrLayoutError(f"{msgtype} has no field {path!r}{hint}")
    if desc[0] == Nodetype.BASE and desc[1][0] in _SIZE:
        return [path]
    if desc[0] == Nodetype.NAME:
        names = [n for n, _ in typestore.fielddefs[desc[1]][1]]
        if sorted(names) == ["w", "x", "y", "z"]:
            return [f"{path}.{c}" for c in "xyzw"]
        raise CdrLayoutError(
            f"{path!r} of {msgtype} is a {desc[1]}, not a number; pick one of its fields: "
            + ", ".join(f"{path}.{n}" for n in names))
    raise CdrLayoutError(f"{path!r} of {msgtype} is not a numeric field (use name[i] for arrays)")


# -- writing ----------------------------------------------------------------------------------------
def default_message(typestore: Typestore, msgtype: str, frame_id: str) -> object:
    """A ``msgtype`` message (rosbags class) with every field zero or empty, quaternion ``w`` one and
    every ``frame_id`` set to ``frame_id``: the template the writers fill in."""
    cls = typestore.types[msgtype]
    kwargs: dict[str, Any] = {}
    names = [n for n, _ in typestore.fielddefs[msgtype][1]]
    quaternion = sorted(names) == ["w", "x", "y", "z"]
    for name, desc in typestore.fielddefs[msgtype][1]:
        if desc[0] == Nodetype.NAME:
            kwargs[name] = default_message(typestore, desc[1], frame_id)
        elif desc[0] == Nodetype.BASE:
            typ = desc[1][0]
            if typ in ("string", "wstring"):
                kwargs[name] = frame_id if name == "frame_id" else ""
            elif typ == "bool":
                kwargs[name] = False
            elif typ.startswith("float"):
                kwargs[name] = 1.0 if (quaternion and name == "w") else 0.0
            else:
                kwargs[name] = 0
        elif desc[0] == Nodetype.ARRAY:
            sub, length = desc[1]
            if sub[0] == Nodetype.BASE and sub[1][0] in _DTYPE:
                kwargs[name] = np.zeros(length, dtype=_DTYPE[sub[1][0]])
            elif sub[0] == Nodetype.BASE:
                kwargs[name] = [""] * length
            else:
                kwargs[name] = [default_message(typestore, sub[1], frame_id) for _ in range(length)]
        else:
            sub = desc[1][0]
            if sub[0] == Nodetype.BASE and sub[1][0] in _DTYPE:
                kwargs[name] = np.zeros(0, dtype=_DTYPE[sub[1][0]])
            else:
                kwargs[name] = []
    return cls(**kwargs)


def serialize_many(typestore: Typestore, msgtype: str, t: np.ndarray, fields: dict[str, np.ndarray],
                   ros1: bool = False, frame_id: str = "map") -> list[bytes]:
    """Serialise ``len(t)`` messages of ``msgtype`` with the given leaf values, vectorised.

    ``header.stamp`` (if the type has a header) is set from ``t`` [s]; unspecified fields are zero
    (quaternion ``w`` one). Returns one ``bytes`` per message, ready for a bag/MCAP writer.
    """
    template_msg = default_message(typestore, msgtype, frame_id)
    template = np.frombuffer(
        bytes(typestore.serialize_ros1(template_msg, msgtype) if ros1
              else typestore.serialize_cdr(template_msg, msgtype)), dtype=np.uint8)
    n = len(t)
    values: dict[str, np.ndarray] = {k: np.asarray(v, dtype=np.float64) for k, v in fields.items()}
    has_stamp = struct_fields(typestore, msgtype, "header.stamp.sec") is not None
    if has_stamp:
        ns = np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)
        values["header.stamp.sec"] = ns // 1_000_000_000
        values["header.stamp.nanosec"] = ns % 1_000_000_000
    paths = list(values)
    for path in paths:
        if leaf_paths(typestore, msgtype, path) != [path]:
            raise CdrLayoutError(f"cannot write {path!r} of {msgtype}: not a numeric leaf")
    one = np.zeros(1, dtype=np.int64)
    body, end, big = _message_bounds(one, np.array([len(template)]), ros1, template)
    walk = _Walk(typestore, template, body, end, ros1, big, set(paths))
    walk.struct(msgtype, "", np.zeros(1, dtype=np.int64))
    out = np.repeat(template[None, :], n, axis=0)
    offset = int(body[0])
    for path in paths:
        rel, typ, _ = walk.found[path]
        pos = offset + int(rel[0])
        val = values[path]
        if len(val) != n:
            raise ValueError(f"field {path!r} has {len(val)} values for {n} times")
        if typ.startswith("float"):
            col = val.astype("<" + _DTYPE[typ])
        else:
            col = np.round(val).astype("<" + _DTYPE[typ])
        out[:, pos:pos + _SIZE[typ]] = col.view(np.uint8).reshape(n, _SIZE[typ])
    return [row.tobytes() for row in out]
