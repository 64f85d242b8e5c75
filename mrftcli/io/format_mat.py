"""MATLAB ``.mat`` files (v4/v5 through ``scipy.io.loadmat``, v7.3 = HDF5 through h5py), reader and writer.

DNN-MRFT-style pipelines save each signal as a vector with its sample times in a companion vector:
``controller_output_2`` and ``controller_output_2_t``, ``z`` and ``z_t``. A "topic" here is a numeric
vector variable; its times are ``<name>_t`` (or ``<name>_time``), else a shared ``t`` / ``time``
vector of the same length. Times are in seconds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import LogReadError
from .clock import TIME_UNITS
from .logtypes import TopicData, TopicInfo
from .source import LogSource, closest, one_line
from .timing import mean_rate_hz

__all__ = ["MatSource", "write_mat"]

MAT_MAGIC = b"MATLAB 5.0 MAT-file"
MAT73_MAGIC = b"MATLAB 7.3 MAT-file"
_SHARED_TIMES = ("t", "time", "timestamp")
#: largest variable read [bytes]: 256 MiB, 33.5 M doubles (a 9-hour flight at 1 kHz); a file's variables
#: can claim any size, and a few small files asking for GB each must not take the machine (issue 35)
_MAX_BYTES = 1 << 28
#: deflate (zlib, HDF5's gzip) expands at most 1032:1; a larger ratio is a declared size no data backs
_MAX_RATIO = 1100


def _too_large(name: str, declared: int, stored: int) -> str | None:
    """Why a variable declaring ``declared`` bytes from ``stored`` bytes of the file is not read, or None."""
    if declared > _MAX_BYTES:
        return (f"{name} declares {declared / 2**20:.0f} MiB, more than the {_MAX_BYTES >> 20} MiB a variable may "
                "hold; save the flight in shorter files")
    if declared > _MAX_RATIO * max(stored, 1):
        return (f"{name} declares {declared} bytes from {stored} stored (more than deflate's 1032:1): "
                "never written or damaged")
    return None


def _check_v5_sizes(path: Path) -> None:
    """Refuse a v5 file whose variable (compressed or not) declares more than it can hold, before scipy
    inflates it: the tag of each element and of each compressed one's inner matrix, read from its first
    bytes (a 1.5 MB file of one compressed vector of 200 M zeros asked scipy for 3.1 GB)."""
    import struct
    import zlib

    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(128)
        order = "<" if head[126:128] == b"IM" else ">"
        pos = 128
        while pos + 8 <= size:
            fh.seek(pos)
            kind, nbytes = struct.unpack(order + "II", fh.read(8))
            if kind & 0xFFFF0000:  # a small data element (no variable) ends the walk
                break
            if kind == 15:  # miCOMPRESSED: the inner miMATRIX tag gives the inflated size
                inner = zlib.decompressobj().decompress(fh.read(min(nbytes, 4096)), 16)
                if len(inner) >= 8:
                    declared = struct.unpack(order + "I", inner[4:8])[0]
                    why = _too_large(f"variable at byte {pos}", declared, nbytes)
                    if why:
                        raise LogReadError(f"{path}: {why}")
            elif nbytes > size - pos - 8:
                raise LogReadError(f"{path}: a variable at byte {pos} declares {nbytes} bytes, more than the file "
                                   f"holds after it ({size - pos - 8}); the file is cut or damaged")
            pos += 8 + nbytes + (-nbytes % 8 if kind != 15 else 0)


def _vector(name: str, arr: np.ndarray, out: dict[str, np.ndarray], skipped: dict[str, str]) -> None:
    """Put ``arr`` into ``out`` as a 1-D float64 vector, or say in ``skipped`` why it is not one."""
    shape = " x ".join(map(str, arr.shape)) or "scalar"
    if arr.dtype.kind == "c":
        skipped[name] = f"{name} holds complex numbers ({shape}); save the real signal"
    elif arr.dtype.kind not in "fiub":
        skipped[name] = f"{name} is not numeric ({arr.dtype.kind!r} data)"
    elif arr.ndim == 0:
        skipped[name] = f"{name} is a single number, not a vector"
    elif arr.ndim > 2 or (arr.size and min(arr.shape) != 1):
        skipped[name] = f"{name} is a {shape} matrix, not a vector; save one vector per signal"
    elif not arr.size:
        skipped[name] = f"{name} is empty"
    else:
        out[name] = arr.astype(np.float64).ravel()


def _load(path: Path) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Every numeric vector in the file, raveled to 1-D float64 (v7.3 through h5py), and why each
    other variable is not one (name -> reason: a matrix, complex, not numeric)."""
    with open(path, "rb") as handle:
        head = handle.read(128)
    out: dict[str, np.ndarray] = {}
    skipped: dict[str, str] = {}
    if head.startswith(MAT73_MAGIC) or head[:8] == b"\x89HDF\r\n\x1a\n":
        import h5py

        with h5py.File(path, "r") as f:
            for name, obj in f.items():
                if isinstance(obj, h5py.Dataset) and not name.startswith("#"):
                    # declared against stored: a never-written gzip dataset claims any size from no bytes
                    why = _too_large(name, int(obj.size) * obj.dtype.itemsize, int(obj.id.get_storage_size()))
                    if why:
                        skipped[name] = why
                        continue
                    _vector(name, np.asarray(obj[()]), out, skipped)
        return out, skipped
    from scipy.io import loadmat

    if head.startswith(MAT_MAGIC[:10]) and len(head) == 128:
        _check_v5_sizes(path)
    raw = loadmat(str(path), squeeze_me=False, mat_dtype=False)
    for name, arr in raw.items():
        if name.startswith("__") or not isinstance(arr, np.ndarray):
            continue
        _vector(name, arr, out, skipped)
    return out, skipped


class MatSource(LogSource):
    """A ``.mat`` file read whole (vectors only; structs and matrices are not listed)."""

    format = "mat"
    default_field = None

    time_unit_settable = True

    def __init__(self, path: str | Path, time_unit: str | None = None) -> None:
        """Read ``path``; its time vectors are in seconds unless ``time_unit`` (one of
        :data:`~mrftcli.io.clock.TIME_UNITS`) says otherwise."""
        super().__init__(path)
        self.time_unit = time_unit or "s"
        self._factor = TIME_UNITS[self.time_unit]
        self._require_file()
        try:
            self._vars, self._skipped = _load(self.path)
        except LogReadError:
            raise
        except Exception as err:  # noqa: BLE001 - scipy/h5py raise many kinds on bad bytes
            raise LogReadError(f"{self.path}: not a readable MATLAB file ({one_line(err)})") from None
        self._signals: dict[str, str] = {}  # signal -> its time vector
        shared = next((n for n in _SHARED_TIMES if n in self._vars), None)
        for name, arr in self._vars.items():
            if name in _SHARED_TIMES or name.endswith(("_t", "_time")):
                continue
            for cand in (f"{name}_t", f"{name}_time", shared):
                if cand is not None and cand in self._vars and self._vars[cand].size == arr.size:
                    self._signals[name] = cand
                    break
            else:
                own = next((c for c in (f"{name}_t", f"{name}_time", shared) if c and c in self._vars), None)
                self._skipped[name] = (
                    f"{name} has {arr.size} samples but its time vector {own} has {self._vars[own].size}"
                    if own is not None else f"{name} has no time vector ({name}_t or a shared t)")
        if not self._signals and not self._vars and self._skipped:
            raise LogReadError(f"{self.path}: no signal read: {next(iter(self._skipped.values()))}")
        if not self._signals:
            raise LogReadError(f"{self.path}: no signal with a time vector (<name>_t or a shared t) among "
                               f"{', '.join(sorted(self._vars)[:12]) or 'no numeric vectors'}")

    def missing_topic(self, topic: str) -> LogReadError:
        """The usual message, with why a variable of that name was not read as a signal."""
        err = super().missing_topic(topic)
        why = self._skipped.get(topic)
        return err if why is None else LogReadError(f"{self.path}: no signal {topic!r}: {why}")

    def topics(self) -> list[TopicInfo]:
        return [TopicInfo(name, "vector", int(self._vars[name].size),
                          mean_rate_hz(np.sort(self._vars[tn] * self._factor)), ())
                for name, tn in sorted(self._signals.items())]

    def topic_names(self) -> list[str]:
        return sorted(self._signals)

    def leaves(self, topic: str, field: str | None) -> list[str]:
        if topic not in self._signals:
            raise self.missing_topic(topic)
        if field not in (None, "data", "value"):
            raise LogReadError(f"{self.path}: {topic} is a vector; it has no field {field!r}"
                               f"{closest(field, ['data'])}")
        return [topic]

    def read(self, topic: str, fields: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        return self._vars[self._signals[topic]] * self._factor, {f: self._vars[f].copy() for f in fields}


def write_mat(topics: list[TopicData], path: str | Path, *, v73: bool = False) -> None:
    """Write each topic's fields as vectors ``<name>`` with times ``<name>_t`` [s].

    A topic with one field is written under the topic's name (leading ``/`` dropped, other characters
    outside ``[A-Za-z0-9_]`` as ``_``); with several, as ``<topic>_<field>``. ``v73`` writes an HDF5
    based v7.3 file (h5py) with MATLAB's 512-byte header, else a v5 file (scipy).
    """
    import re

    data: dict[str, np.ndarray] = {}
    for td in topics:
        base = re.sub(r"[^A-Za-z0-9_]", "_", td.name.lstrip("/"))
        for fname, values in td.fields.items():
            name = base if len(td.fields) == 1 else f"{base}_{re.sub(r'[^A-Za-z0-9_]', '_', fname)}"
            data[name] = np.asarray(values, dtype=np.float64)
            data[f"{name}_t"] = np.asarray(td.t, dtype=np.float64)
    if not v73:
        from scipy.io import savemat

        savemat(str(path), {k: v.reshape(-1, 1) for k, v in data.items()}, do_compression=True)
        return
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        for name, values in data.items():
            f.create_dataset(name, data=values.reshape(1, -1), compression="gzip")
    header = (MAT73_MAGIC + b" Platform: posix, Created by: mrft-ident").ljust(116, b" ")
    header += bytes(8) + b"\x00\x02" + b"IM"  # subsystem offset, version 0x0200, endian "IM"
    with open(path, "r+b") as handle:
        handle.write(header.ljust(512, b"\x00"))
