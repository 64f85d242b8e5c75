"""CSV logs: one time column plus one column per numeric field (PlotJuggler's export layout).

Layout written (and the default one read)::

    __time,/imu/data/orientation/w,/imu/data/orientation/x,...,/mocap/pose/pose/position/z,/mrft/command/data
    12.000000000,,,,,0.4
    12.005000000,1.0,0.0,...,1.02,

* time column: ``__time`` or ``time``/``t``/``time_s``/``seconds`` in seconds;
  ``timestamp``/``time_us``/``timestamp_us`` in microseconds (PX4 ``ulog2csv``);
  ``time_ns``/``timestamp_ns`` in nanoseconds. Any other first column is refused rather than guessed.
* every other column is a numeric series; an empty cell means "no sample of this column at this time",
  so topics at different rates share one file (rows are the union of all message times).
* a topic option ``TOPIC:FIELD`` names the column ``TOPIC/FIELD`` with dots as slashes
  (``/mocap/pose:pose.position.z`` -> ``/mocap/pose/pose/position/z``); ``TOPIC.FIELD`` and a column
  named exactly ``TOPIC:FIELD`` or ``TOPIC`` are accepted too. A field whose ``/x /y /z /w`` (or
  ``.x ...``) columns all exist is a quaternion.
"""

from __future__ import annotations

import io
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import LogReadError
from .clock import TIME_UNITS
from .logtypes import TopicData, TopicInfo
from ..progress import Progress, report
from .atomic import atomic_path
from .source import Field, LogSource, one_line
from .timing import mean_rate_hz

__all__ = ["CsvSource", "write_csv", "LARGE_CSV_BYTES"]

#: a CSV larger than this [bytes] is parsed column by column, only the columns a command uses
#: (:class:`_LazyColumns`); smaller ones are parsed whole, as one cut mid-row must be
LARGE_CSV_BYTES = 64 << 20
#: rows parsed at a time in a large CSV (about 12 MB of text at 10 columns)
_BLOCK_ROWS = 1 << 18

#: accepted time column names -> factor to seconds
TIME_COLUMNS = {
    "__time": 1.0, "time": 1.0, "t": 1.0, "time_s": 1.0, "seconds": 1.0,
    "timestamp": 1e-6, "time_us": 1e-6, "timestamp_us": 1e-6,
    "time_ns": 1e-9, "timestamp_ns": 1e-9,
}


def _undecodable(head: bytes) -> bool:
    """True when the first bytes are not UTF-8 text (a cut multi-byte character at the end is fine)."""
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as err:
        return err.start < len(head) - 3
    return False


class CsvSource(LogSource):
    """A CSV file read whole with pandas (pyarrow engine when available)."""

    format = "csv"
    default_field = None

    time_unit_settable = True

    def __init__(self, path: str | Path, time_unit: str | None = None, progress: Progress | None = None) -> None:
        """Read ``path``; ``time_unit`` (one of :data:`~mrftcli.io.clock.TIME_UNITS`) overrides the unit
        the time column's name implies (``__time``: s, ``timestamp``: us, ...); ``progress`` is told
        how far the passes over a large file are (bytes of the file's size)."""
        super().__init__(path)
        self.progress = progress
        try:
            size = self._require_file()
            if size > LARGE_CSV_BYTES and _ends_with_newline(self.path):
                frame = self._open_large()
            else:
                frame = self._read_whole()
        except LogReadError:
            raise
        except OSError as err:
            raise LogReadError(f"{self.path}: cannot read ({err.strerror})") from None
        except Exception as err:  # noqa: BLE001 - pandas/pyarrow parse errors of many kinds
            msg = "".join(ch if ch.isprintable() else "?" for ch in one_line(err))[:200]
            raise LogReadError(f"{self.path}: not a readable CSV ({msg})") from None
        self._set_columns(frame, time_unit)

    def _read_whole(self) -> pd.DataFrame:
        """Every column of a file of up to :data:`LARGE_CSV_BYTES` (or one cut mid-row), parsed at once."""
        raw = self.path.read_bytes()
        if not raw.endswith(b"\n") and b"\n" in raw.rstrip(b"\n"):
            # a file cut off mid-row: the last row may hold a cut number, drop it rather than
            # read a wrong value
            raw = raw[:raw.rindex(b"\n") + 1]
            self.warn("CSV does not end with a line break (truncated?): its last, partial row "
                      "was dropped")
        head = raw[:4096]
        if b"\x00" in head or _undecodable(head):
            # never echo a binary file's bytes in the message
            raise LogReadError(f"{self.path}: a binary file, not a CSV (text with a time column); "
                               "pass its own --format, or leave --format out to detect it")
        return _read_frame(raw)

    def _open_large(self) -> pd.DataFrame:
        """A large file's header and time column only; the data columns are parsed when asked for."""
        with open(self.path, "rb") as handle:
            head = handle.read(4096)
        if b"\x00" in head or _undecodable(head):
            raise LogReadError(f"{self.path}: a binary file, not a CSV (text with a time column); "
                               "pass its own --format, or leave --format out to detect it")
        names = [str(c) for c in pd.read_csv(self.path, nrows=0).columns]
        time_raw = next((c for c in names if c.strip().lower() in TIME_COLUMNS), None)
        if time_raw is None or len(names) < 2:
            return pd.DataFrame(columns=names)  # the checks below say what is wrong
        self._lazy = _LazyColumns(self.path, self.progress, names, time_raw)
        return self._lazy.read([time_raw])

    def _set_columns(self, frame: pd.DataFrame, time_unit: str | None) -> None:
        """The time column [s] and the data columns (or their lazy loader) from ``frame``."""
        lazy = getattr(self, "_lazy", None)
        names = lazy.names if lazy is not None else [str(c) for c in frame.columns]
        if len(names) < 2:
            raise LogReadError(f"{self.path}: a CSV log needs a time column and at least one data column")
        cols = [c.strip() for c in names]
        frame.columns = [str(c).strip() for c in frame.columns]
        time_col = next((c for c in cols if c.lower() in TIME_COLUMNS), None)
        if time_col is None:
            raise LogReadError(
                f"{self.path}: no time column; name one of {', '.join(TIME_COLUMNS)} "
                f"(columns found: {', '.join(cols[:8])})")
        t = pd.to_numeric(frame[time_col], errors="coerce").to_numpy(dtype=np.float64)
        if np.isnan(t).any():
            bad = int(np.flatnonzero(np.isnan(t))[0])
            raise LogReadError(f"{self.path}: time column {time_col!r} is not numeric (row {bad + 2})")
        if len(t) == 0:
            raise LogReadError(f"{self.path}: the CSV has a header but no rows")
        factor = TIME_COLUMNS[time_col.lower()]
        if time_unit is not None:
            factor = TIME_UNITS[time_unit]
        self.time_unit = next(u for u, f in TIME_UNITS.items() if f == factor)
        self._t = t * factor
        self._cols: Mapping[str, pd.Series] = (
            {c: frame[c] for c in cols if c != time_col} if lazy is None else lazy)

    def prefetch(self, topics: list[str]) -> None:
        """Parse the columns of ``topics`` in one pass over a large file (see :data:`LARGE_CSV_BYTES`)."""
        if isinstance(self._cols, _LazyColumns):
            prefixes = tuple(f"{t}{sep}" for t in topics for sep in ("/", ".", ":"))
            self._cols.load([c for c in self._cols if c in topics or c.startswith(prefixes)])

    def _numeric(self, col: str) -> tuple[np.ndarray, np.ndarray]:
        raw = self._cols[col]
        if raw.dtype == np.float64:  # a large file's column (parsed as float64): no copy to convert
            values = raw.to_numpy()
            present = ~np.isnan(values)
        else:
            values = pd.to_numeric(raw, errors="coerce").to_numpy(dtype=np.float64)
            present = raw.notna().to_numpy()
        if (present & np.isnan(values)).any():
            bad = int(np.flatnonzero(present & np.isnan(values))[0])
            raise LogReadError(f"{self.path}: column {col!r} holds a non-number at row {bad + 2}")
        idx = np.flatnonzero(present)
        if idx.size and idx.size >= 0.9 * (idx[-1] - idx[0] + 1) and idx.size < idx[-1] - idx[0] + 1:
            # a column filled on (nearly) every row: its blank or NaN cells are samples that are
            # missing, not a topic's silence between messages (pandas reads "nan" as a blank)
            holes = int(idx[-1] - idx[0] + 1 - idx.size)
            first = int(idx[np.flatnonzero(np.diff(idx) > 1)[0]] + 1)
            self.warn(f"column {col!r}: {holes} blank or NaN cell(s) among its rows (the first at row "
                      f"{first + 2}): read as missing samples")
        if idx.size == values.size:  # every row holds a sample: the column itself (callers copy what they scale)
            if isinstance(self._cols, _LazyColumns):
                # a large file's signals share its one time array (read-only, so no one can change
                # another signal's times): 8 bytes a row per signal less
                self._t.flags.writeable = False
                return self._t, values
            return self._t.copy(), values
        return self._t[present], values[present]

    def topics(self) -> list[TopicInfo]:
        out = []
        if isinstance(self._cols, _LazyColumns):
            return self._cols.listing(self._t)
        for col, raw in self._cols.items():
            present = raw.notna().to_numpy()
            t = np.sort(self._t[present])
            out.append(TopicInfo(col, str(raw.dtype), int(present.sum()), mean_rate_hz(t), ()))
        return out

    def resolve_topic(self, topic: str) -> str | None:
        """A CSV "topic" is a column, or the prefix ``TOPIC/`` (``TOPIC.``) of some columns."""
        if topic in self._cols or any(c.startswith((topic + "/", topic + ".", topic + ":"))
                                      for c in self._cols):
            return topic
        return None

    def missing_topic(self, topic: str) -> LogReadError:
        names = list(self._cols)
        from .source import closest

        shown = ", ".join(names[:25]) + (f", ... ({len(names)} in all)" if len(names) > 25 else "")
        return LogReadError(f"{self.path}: no column {topic!r}{closest(topic, names)}; columns: {shown}")

    def leaves(self, topic: str, field: str | None) -> list[str]:
        names = set(self._cols)
        if field is None:
            candidates = [topic, f"{topic}/data", f"{topic}.data"]
        else:
            candidates = [f"{topic}/{field.replace('.', '/')}", f"{topic}.{field}", f"{topic}:{field}",
                          f"{topic}/{field}"]
        for cand in candidates:
            if cand in names:
                return [cand]
        for cand in candidates:
            quat = Field.quaternion(cand, names)
            if quat:
                return quat
        if field is None or not any(c.startswith(topic) for c in names):
            raise self.missing_topic(topic if field is None else f"{topic}/{field.replace('.', '/')}")
        inside = sorted(c for c in names if c.startswith(topic))
        raise LogReadError(f"{self.path}: no column for {topic}:{field}; columns of {topic}: "
                           f"{', '.join(inside[:12])}")

    def read(self, topic: str, fields: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        t0, first = self._numeric(fields[0])
        out = {fields[0]: first}
        for col in fields[1:]:
            t, v = self._numeric(col)
            if len(t) != len(t0) or not np.array_equal(t, t0):
                raise LogReadError(f"{self.path}: columns {fields[0]!r} and {col!r} are not sampled at "
                                   "the same times; a quaternion needs all four in every row")
            out[col] = v
        return t0, out


class _LazyColumns(Mapping[str, pd.Series]):
    """The data columns of a large CSV, parsed on first use, only those asked for (float64 each).

    A 10-million-row log of ten columns is 470 MB of text; parsed whole it took 2.3 GB, and pyarrow's
    block reader still held 1.2 GB (its pool keeps what it parsed). Each pass here reads the file
    :data:`_BLOCK_ROWS` rows at a time (pandas' C parser, ``usecols``) and keeps one float64 copy of
    the columns asked for: memory is the file's rows times the columns used, 8 bytes each, plus one
    block. Listing the topics keeps no column at all (counts and time spans per block).
    """

    def __init__(self, path: Path, progress: Progress | None, names: list[str], time_raw: str) -> None:
        # the file and the progress callback, not the source: a reference back to it would make a
        # cycle that keeps the parsed columns alive after the read, until the garbage collector runs
        self.path = path
        self.progress = progress
        self.names = names
        self.time_raw = time_raw
        self.raw = {n.strip(): n for n in names if n != time_raw}
        self.loaded: dict[str, pd.Series] = {}

    def _blocks(self, raw_names: list[str], stage: str) -> Iterator[pd.DataFrame]:
        """The columns ``raw_names`` (as in the file) as float64, :data:`_BLOCK_ROWS` rows at a time;
        progress (bytes read of the file's size) goes to ``progress``."""
        path = self.path
        total = float(path.stat().st_size)
        try:
            with open(path, "rb") as handle:
                chunks = pd.read_csv(handle, usecols=raw_names, dtype={n: np.float64 for n in raw_names},
                                     chunksize=_BLOCK_ROWS, engine="c")
                for block in chunks:
                    report(self.progress, float(handle.tell()), total, stage)
                    yield block
        except (ValueError, pd.errors.ParserError) as err:  # the parser's message names the value or row
            msg = "".join(ch if ch.isprintable() else "?" for ch in one_line(err))[:200]
            raise LogReadError(f"{path}: column(s) {', '.join(raw_names)} not numbers ({msg})") from None

    def read(self, raw_names: list[str]) -> pd.DataFrame:
        """Columns ``raw_names`` (as in the file) parsed from the whole file, one float64 array each.

        The arrays are allocated once at the file's line count and filled block by block: no list of
        pieces to concatenate (twice the column at the end, and a heap the pieces leave fragmented).
        """
        rows = self._line_count()
        columns = {n: np.empty(rows, dtype=np.float64) for n in raw_names}
        at = 0
        for block in self._blocks(raw_names, f"reading {len(raw_names)} column(s)"):
            k = min(len(block), rows - at)
            for n in raw_names:
                columns[n][at: at + k] = block[n].to_numpy(dtype=np.float64)[:k]
            at += k
        # blank lines are not rows: the arrays' tails are unused then
        return pd.DataFrame({n: v[:at] for n, v in columns.items()}, copy=False)

    def _line_count(self) -> int:
        """Lines after the header (an upper bound on the rows), counted once in 16 MB reads."""
        if not hasattr(self, "_lines"):
            lines = 0
            with open(self.path, "rb") as handle:
                while block := handle.read(16 << 20):
                    lines += block.count(b"\n")
            self._lines = max(lines - 1, 0)
        return self._lines

    def listing(self, t: np.ndarray) -> list[TopicInfo]:
        """Every column's count and mean rate [Hz] at times ``t`` [s] (row k at ``t[k]``), in one pass
        that keeps per column only its count and first and last time (memory: one block)."""
        raws = list(self.raw.values())
        count = dict.fromkeys(raws, 0)
        first: dict[str, float] = {}
        last: dict[str, float] = {}
        row = 0
        for block in self._blocks(raws, "listing the columns"):
            tb = t[row: row + len(block)]
            row += len(block)
            for n in raws:
                ts = tb[block[n].notna().to_numpy()]
                if ts.size:
                    count[n] += int(ts.size)
                    first[n] = min(first.get(n, np.inf), float(ts.min()))
                    last[n] = max(last.get(n, -np.inf), float(ts.max()))
        out = []
        for name, n in self.raw.items():
            span = last[n] - first[n] if count[n] > 1 else 0.0
            rate = (count[n] - 1) / span if span > 0 else None  # mean_rate_hz without sorting the times
            out.append(TopicInfo(name, "float64", count[n], rate, ()))
        return out

    def load(self, names: list[str]) -> None:
        """Parse the columns ``names`` (stripped names) not parsed yet, in one pass."""
        todo = [n for n in names if n not in self.loaded and n in self.raw]
        if todo:
            frame = self.read([self.raw[n] for n in todo])
            for n in todo:
                self.loaded[n] = frame[self.raw[n]]

    def __getitem__(self, name: str) -> pd.Series:
        self.load([name])
        return self.loaded[name]

    def __contains__(self, name: object) -> bool:
        return name in self.raw

    def __iter__(self) -> Iterator[str]:
        return iter(self.raw)

    def __len__(self) -> int:
        return len(self.raw)


def _ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as handle:
        handle.seek(-1, 2)
        return handle.read(1) == b"\n"


def _read_frame(raw: bytes) -> pd.DataFrame:
    try:
        return pd.read_csv(io.BytesIO(raw), engine="pyarrow")
    except ImportError:  # pragma: no cover - pyarrow is a dependency
        return pd.read_csv(io.BytesIO(raw))


def csv_column(topic: str, field: str) -> str:
    """Column name of ``topic`` / dotted ``field`` in the written layout."""
    return f"{topic}/{field.replace('.', '/')}"


def write_csv(topics: list[TopicData], path: str | Path) -> None:
    """Write topics as one CSV: ``__time`` [s] and one column per given field (rows = union of times).

    Quaternion fields are completed (a missing component is written as 0, ``w`` as 1) so readers always
    find all four.
    """
    all_t = np.unique(np.concatenate([np.asarray(td.t, dtype=np.float64) for td in topics]
                                     or [np.zeros(0)]))
    columns: dict[str, np.ndarray] = {"__time": all_t}
    for td in topics:
        t = np.asarray(td.t, dtype=np.float64)
        if len(np.unique(t)) != len(t):
            raise ValueError(f"{td.name}: CSV rows need distinct times per topic")
        rows = np.searchsorted(all_t, t)
        fields = dict(td.fields)
        for name in list(fields):
            prefix, _, comp = name.rpartition(".")
            if comp in ("x", "y", "z", "w") and prefix.endswith("orientation"):
                for c in "xyzw":
                    fields.setdefault(f"{prefix}.{c}", np.full(len(t), 1.0 if c == "w" else 0.0))
        for name, values in fields.items():
            col = np.full(len(all_t), np.nan)
            col[rows] = np.asarray(values, dtype=np.float64)
            columns[csv_column(td.name, name)] = col
    # time gets more digits than the values (absolute times at ns resolution)
    columns["__time"] = np.array([f"{v:.9f}" for v in all_t], dtype=object)
    with atomic_path(path) as tmp:  # a killed run never leaves a cut CSV that reads as a shorter log
        pd.DataFrame(columns).to_csv(tmp, index=False, float_format="%.10g", na_rep="")
