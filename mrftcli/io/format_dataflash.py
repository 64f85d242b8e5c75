"""ArduPilot DataFlash ``.BIN`` logs: pymavlink's DFReader for the index, numpy for the values.

``DFReader_binary`` scans the file once when it opens and records, for every message type, the byte
offset of each message (``offsets``) and the parsed ``FMT`` definitions (``formats``: struct format,
columns, multipliers, instance field). Reading a series through ``recv_match`` would then build one
Python object per message of *every* type; instead the messages of the one wanted type are gathered
from the memory map at those offsets and decoded as a numpy record array, with DFReader's multipliers
(``c``/``C``/``e``/``E`` x 0.01, ``L`` x 1e-7) applied. Same numbers, no per-message objects.

Naming: a topic is a message type (``ATT``, ``BAT``); FIELD a column (``ATT:Roll``). Types with an
instance column (``BAT`` on newer firmware) are listed as ``BAT[0]``, ``BAT[1]``. Time is ``TimeUS``
[us] (``TimeMS`` [ms] on old logs) -> s. ArduPilot logs angles in degrees: use ``output_scale`` to get
radians.
"""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np

from ..errors import LogReadError
from .logtypes import TopicInfo
from .source import LogSource, closest, one_line
from .timing import mean_rate_hz

__all__ = ["DataflashSource"]

_NP = {"b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "q": "<i8", "Q": "<u8",
       "f": "<f4", "d": "<f8", "e": "<f2"}


def _dtype(msg_struct: str) -> np.dtype:
    """numpy dtype of a DFReader struct string such as ``<QhhH64s``."""
    fields: list[str | tuple[str, tuple[int]]] = []
    for count, char in re.findall(r"(\d*)([a-zA-Z?])", msg_struct.lstrip("<")):
        if char == "s":
            fields.append(f"S{count or 1}")
        elif count:
            fields.append((_NP[char], (int(count),)))
        else:
            fields.append(_NP[char])
    return np.dtype([(f"f{i}", f) for i, f in enumerate(fields)])


_FMT_HEAD = b"\xa3\x95\x80"  # a FMT message: the two header bytes and FMT's own type, 128
_FMT_NAME = re.compile(rb"[A-Z0-9]{1,4}\x00*")
_FMT_FORMAT = re.compile(rb"[a-zA-Z]{1,16}\x00*")


def check_formats(path: Path) -> None:
    """Refuse a log whose ``FMT`` defines a message shorter than its 3-byte header plus one byte.

    pymavlink's scan steps from message to message by each type's declared length: a length of 0 never
    advances (a hang, issue 35), 1-2 step backwards, 3 holds no field. Each FMT (found by its header and
    a well-formed name and format, so that stray bytes are not taken for one) is checked before
    pymavlink reads the file: one-line :class:`~mrftcli.errors.LogReadError`.
    """
    import mmap

    with open(path, "rb") as fh:
        if path.stat().st_size == 0:
            return
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
            pos = data.find(_FMT_HEAD)
            while pos >= 0:
                body = data[pos + 3:pos + 3 + 22]
                if (len(body) == 22 and _FMT_NAME.fullmatch(body[2:6]) and _FMT_FORMAT.fullmatch(body[6:22])
                        and body[1] < 4):
                    name = body[2:6].rstrip(b"\x00").decode()
                    raise LogReadError(f"{path}: FMT defines message {name} (type {body[0]}) as {body[1]} bytes "
                                       "long, less than its 3-byte header and one value; the log is damaged")
                pos = data.find(_FMT_HEAD, pos + 1)


class DataflashSource(LogSource):
    """An ArduPilot DataFlash binary log."""

    format = "dataflash"
    default_field = None

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        from pymavlink.DFReader import DFReader_binary

        try:
            self._require_file()
            check_formats(self.path)
            noise = io.StringIO()
            with contextlib.redirect_stderr(noise), contextlib.redirect_stdout(noise):
                self._reader = DFReader_binary(str(self.path), zero_time_base=False)
        except LogReadError:
            raise
        except Exception as err:  # noqa: BLE001 - DFReader raises many kinds on damaged files
            detail = one_line(err)
            raise LogReadError(f"{self.path}: not a readable DataFlash log ({detail})") from None
        if any(s in noise.getvalue() for s in ("bad header", "Skipped", "Failed to parse")):
            self.warn("DataFlash log has damaged bytes; the readable messages were kept")
        self._data = np.frombuffer(self._reader.data_map, dtype=np.uint8)
        self._types = {}
        for mtype, fmt in self._reader.formats.items():
            if fmt.name in ("FMT", "FMTU", "UNIT", "MULT") or not self._reader.offsets[mtype]:
                continue
            self._types[fmt.name] = mtype
        self._decoded: dict[str, dict[str, np.ndarray]] = {}

    def close(self) -> None:
        reader = getattr(self, "_reader", None)
        if reader is not None:
            # the array over DFReader's memory map is an exported pointer: while it lives, the map (and the
            # file under it) cannot close, and the file was left to the garbage collector (a ResourceWarning)
            self._data = np.empty(0, dtype=np.uint8)
            with contextlib.suppress(Exception):
                reader.close()
            self._reader = None

    def _decode(self, name: str) -> dict[str, np.ndarray]:
        if name in self._decoded:
            return self._decoded[name]
        mtype = self._types[name]
        fmt = self._reader.formats[mtype]
        offsets = np.asarray(self._reader.offsets[mtype], dtype=np.int64)
        dtype = _dtype(fmt.msg_struct)
        size = fmt.len - 3
        if dtype.itemsize != size:
            raise LogReadError(f"{self.path}: {name}: FMT length {fmt.len} does not match its format "
                               f"{fmt.format!r}")
        whole = offsets + 3 + size <= len(self._data)
        if not whole.all():
            self.warn(f"{name}: {int((~whole).sum())} message(s) cut off at the end of the file dropped")
            offsets = offsets[whole]
        raw = self._data[(offsets + 3)[:, None] + np.arange(size)]
        if "TimeUS" in fmt.columns and len(raw) > 1:
            # a message repeated byte for byte, time stamp included, is one message written twice (seen
            # from Lua's logger:write in SITL): keep the first
            again = np.r_[False, np.all(raw[1:] == raw[:-1], axis=1)]
            if again.any():
                self.warn(f"{name}: {int(again.sum())} message(s) repeated byte for byte (time stamp "
                          "included) dropped")
                raw = raw[~again]
        rec = np.ascontiguousarray(raw).view(dtype).ravel()
        cols: dict[str, np.ndarray] = {}
        for i, col in enumerate(fmt.columns):
            values = rec[f"f{i}"]
            if values.dtype.kind in "SU" or values.ndim > 1:
                continue  # text and array columns are not time series
            values = values.astype(np.float64)
            mult = fmt.msg_mults[i] if i < len(fmt.msg_mults) else None
            if mult is not None:
                values = values * mult
            cols[col] = values
        self._decoded[name] = cols
        return cols

    def _time(self, cols: dict[str, np.ndarray], name: str) -> np.ndarray:
        if "TimeUS" in cols:
            return cols["TimeUS"] / 1e6
        if "TimeMS" in cols:
            return cols["TimeMS"] / 1e3
        raise LogReadError(f"{self.path}: {name} has no TimeUS/TimeMS column")

    def _instances(self, name: str) -> list[float] | None:
        fmt = self._reader.formats[self._types[name]]
        if fmt.instance_field is None:
            return None
        return sorted(np.unique(self._decode(name)[fmt.instance_field]).tolist())

    def _split(self, topic: str) -> tuple[str, int | None]:
        match = re.fullmatch(r"(.+)\[(\d+)\]", topic)
        return (match.group(1), int(match.group(2))) if match else (topic, None)

    def topics(self) -> list[TopicInfo]:
        out = []
        for name in sorted(self._types):
            cols = self._decode(name)
            if "TimeUS" not in cols and "TimeMS" not in cols:
                continue
            t = self._time(cols, name)
            fields = tuple(c for c in cols if c not in ("TimeUS", "TimeMS"))
            insts = self._instances(name)
            if insts is None or len(insts) < 2:
                out.append(TopicInfo(name, name, len(t), mean_rate_hz(np.sort(t)), fields))
                continue
            field = self._reader.formats[self._types[name]].instance_field
            for inst in insts:
                sel = cols[field] == inst
                out.append(TopicInfo(f"{name}[{int(inst)}]", name, int(sel.sum()),
                                     mean_rate_hz(np.sort(t[sel])), fields))
        return out

    def topic_names(self) -> list[str]:
        return list(self._types)

    def resolve_topic(self, topic: str) -> str | None:
        name, _ = self._split(topic)
        return topic if name in self._types else None

    def leaves(self, topic: str, field: str | None) -> list[str]:
        name, _ = self._split(topic)
        if name not in self._types:
            raise self.missing_topic(topic)
        cols = [c for c in self._decode(name) if c not in ("TimeUS", "TimeMS")]
        if field is None:
            raise LogReadError(f"{self.path}: name a column of {name} with {name}:COLUMN "
                               f"({', '.join(cols)})")
        if field not in cols:
            raise LogReadError(f"{self.path}: {name} has no column {field!r}{closest(field, cols)}; "
                               f"columns: {', '.join(cols)}")
        return [field]

    def read(self, topic: str, fields: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        name, inst = self._split(topic)
        cols = self._decode(name)
        t = self._time(cols, name)
        insts = self._instances(name)
        sel = slice(None)
        if insts is not None and (inst is not None or len(insts) > 1):
            if inst is None:
                raise LogReadError(f"{self.path}: {name} is logged for several instances; name one "
                                   f"({', '.join(f'{name}[{int(i)}]' for i in insts)})")
            sel = cols[self._reader.formats[self._types[name]].instance_field] == inst
            if not sel.any():
                raise LogReadError(f"{self.path}: no {name} messages of instance {inst}")
        elif inst is not None and inst != 0:
            raise LogReadError(f"{self.path}: {name} has no instances; use {name}")
        return t[sel], {f: cols[f][sel] for f in fields}
