"""What every format reader shares: the :class:`LogSource` interface, topic-option parsing, checks.

A reader answers two questions: which topics are there (:meth:`LogSource.topics`), and what are the
values of some numeric fields of one topic over time (:meth:`LogSource.read`). Everything else
(default layout, quaternions, error wording) is built once on top, in :mod:`mrftcli.io`.
"""

from __future__ import annotations

import difflib
import sys
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import numpy as np

from ..errors import LogReadError
from ..progress import Progress
from .logtypes import Signal, TopicInfo

__all__ = ["one_line", "LogSource", "TopicSpec", "parse_spec", "closest", "check_times", "spread_batches", "Field"]


@dataclass(frozen=True)
class TopicSpec:
    """A ``TOPIC[:FIELD]`` option split into its parts (``field`` None = the format's default)."""

    topic: str
    field: str | None = None

    def __str__(self) -> str:
        return self.topic if self.field is None else f"{self.topic}:{self.field}"


def parse_spec(text: str | TopicSpec) -> TopicSpec:
    """Split ``TOPIC[:FIELD]`` at the *last* colon whose right side is a field path.

    ROS topic names never contain ``:``, ULog names neither; a CSV column might, so a column name that
    contains ``:`` is matched whole first by the CSV reader (see :meth:`LogSource.split_spec`).
    """
    if isinstance(text, TopicSpec):
        return text
    text = text.strip()
    if not text:
        raise LogReadError("empty topic option; expected TOPIC[:FIELD]")
    topic, sep, field = text.rpartition(":")
    if not sep:
        return TopicSpec(text, None)
    if not topic:
        raise LogReadError(f"topic option {text!r} has no topic before ':'")
    return TopicSpec(topic, field or None)


def one_line(err: BaseException, limit: int = 160) -> str:
    """A library exception as a short printable single line (for wrapping in LogReadError)."""
    text = " ".join(str(err).split()) or type(err).__name__
    text = "".join(c if c.isprintable() and c != "\ufffd" else "?" for c in text)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def closest(name: str, candidates: list[str]) -> str:
    """`` (did you mean X?)`` for the best fuzzy match among ``candidates``, or an empty string."""
    # 0.7: a typo (/mrft/comand) matches, an unrelated topic of another loop (/imu/data ~ /mrft/beta) does not
    match = difflib.get_close_matches(name, candidates, n=1, cutoff=0.7)
    return f" (did you mean {match[0]}?)" if match else ""


def check_times(t: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    """Validate message times of one topic in recording order.

    Returns ``(t, keep, notes)``. Messages sharing a stamp (a logger stamping batches on arrival)
    keep their values; their times are rebuilt from the rate (:func:`spread_batches`) with a note.
    ``keep`` (an index array of the messages kept) is None: no message is dropped.

    Raises
    ------
    LogReadError
        Times are not finite or go backwards (a clock reset would interleave two recordings).
    """
    t = np.asarray(t, dtype=np.float64)
    notes: list[str] = []
    if not np.isfinite(t).all():
        raise LogReadError(f"{what}: {int((~np.isfinite(t)).sum())} timestamps are not finite")
    if len(t) < 2:
        return t, None, notes
    dt = np.diff(t)
    back = np.flatnonzero(dt < 0)
    if len(back):
        i = int(back[0])
        raise LogReadError(
            f"{what}: timestamps go backwards ({len(back)} times, first at message {i + 1}: "
            f"{t[i]:.6f} s -> {t[i + 1]:.6f} s)")
    dup = dt == 0
    if dup.all():
        raise LogReadError(f"{what}: all {len(t)} messages carry the same time ({t[0]:.6f} s): the recorder "
                           "did not stamp them, so no rate or delay can be measured")
    if dup.any():
        t_new, period = spread_batches(t)
        notes.append(
            f"{what}: {int(dup.sum())} messages repeat the timestamp before them (a logger that stamps "
            f"batches on arrival): their times are rebuilt at the logged rate ({1.0 / period:.4g} Hz), "
            f"spaced back from each stamp (exact for a steady latency; a latency that varies from batch "
            f"to batch moves switch instants by up to a batch interval, {1e3 * batch_interval(t):.3g} ms: "
            f"stamp samples where they are made to be sure of tau)")
        return t_new, None, notes
    return t, None, notes


def batch_interval(t: np.ndarray) -> float:
    """Median interval between distinct stamps [s] (the batch interval of a logger stamping on arrival)."""
    u = np.unique(np.asarray(t, float))
    return float(np.median(np.diff(u))) if u.size > 1 else 0.0


def spread_batches(t: np.ndarray) -> tuple[np.ndarray, float]:
    """Times of messages that share stamps, rebuilt from the rate: ``(times [s], period [s])``.

    A logger that stamps on batch arrival gives a batch of k samples one stamp, the arrival of the
    last. Dropping all but one sample per stamp (or keeping them at the stamp) puts the samples,
    and the relay's switch instants with them, up to a batch late by an amount that depends on
    where the switch fell in the batch: tau came out 4 ms short for a 46 ms truth. The samples are
    produced at a steady rate, so the period is the median over batches of (stamp gap / batch
    size), and sample i of a batch of k lies (k - 1 - i) periods before its stamp. Where a batch
    would reach back before the previous stamp (a burst after a stall), its samples are spread
    evenly over the gap instead, so the times always increase. A latency common to every sample
    cancels between command and output.

    Examples
    --------
    >>> t, period = spread_batches(np.array([0.0, 0.3, 0.3, 0.3, 0.6, 0.6, 0.6]))
    >>> round(period, 3), np.round(t, 3).tolist()
    (0.1, [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    """
    t = np.asarray(t, dtype=float)
    stamps, first, counts = np.unique(t, return_index=True, return_counts=True)
    if stamps.size < 2:
        return t, 0.0
    period = float(np.median(np.diff(stamps) / counts[1:]))
    room = np.r_[np.inf, np.diff(stamps)]  # time back to the previous stamp
    step = np.where((counts - 1) * period < room, period, room / counts)
    pos = np.arange(t.size) - np.repeat(first, counts)  # index inside the batch
    back = np.repeat(counts, counts) - 1 - pos
    return t - back * np.repeat(step, counts), period


class LogSource(ABC):
    """An open flight log: list its topics and read numeric fields of one topic.

    Use it as a context manager (``with open_log(path) as log: ...``). ``format`` names the format
    (one of :data:`mrftcli.io.FORMATS` or ``"dataflash"``).
    """

    format: str = ""
    #: print the warnings on stderr when the ``with`` block ends (False: the caller shows them)
    echo_warnings: bool = True
    #: what a missing FIELD means for this format (ROS: ``data``)
    default_field: str | None = None
    #: the times are the recorder's (a bag's record time, MCAP ``log_time``: when each message
    #: arrived), not stamps set where the sample was made. The readers never read ``header.stamp``,
    #: so this holds for header-less and header-carrying messages alike: such a log is
    #: receive-stamped in every format (:func:`mrftcli.io.flight.read_flight`'s ``Timing``)
    recorder_times: bool = False
    #: the unit the reader took the log's times to be in (:data:`mrftcli.io.clock.TIME_UNITS`)
    time_unit: str = "s"
    #: the format's times carry no unit, so ``--time-unit`` may say which (CSV, ``.mat``)
    time_unit_settable: bool = False
    #: told how far a long read is (:mod:`mrftcli.progress`: bytes read of the file's size, and what
    #: is being read); readers of files that take seconds to parse call it (a large CSV)
    progress: Progress | None = None

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.warnings: list[str] = []
        self._shown = 0

    # context manager --------------------------------------------------------------------------
    def __enter__(self) -> LogSource:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
        if exc_type is None and self.echo_warnings:
            # warnings go to stderr only when reading succeeded: a fatal error stays one line
            for text in self.warnings[self._shown:]:
                print(f"warning: {text}", file=sys.stderr)
            self._shown = len(self.warnings)

    def _require_file(self) -> int:
        """The file's size in bytes; a one-line LogReadError if it cannot be read or is empty."""
        try:
            size = self.path.stat().st_size
        except OSError as err:
            raise LogReadError(f"{self.path}: cannot read ({err.strerror})") from None
        if size == 0:
            raise LogReadError(f"{self.path}: the file is empty")
        return size

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release file handles (most readers hold none after opening)."""

    def warn(self, message: str) -> None:
        """Record a non-fatal problem; shown as a ``warning: ...`` line on stderr when the
        ``with`` block ends without an error (also kept in ``warnings`` / ``FlightLog.warnings``)."""
        text = f"{self.path}: {message}"
        if text not in self.warnings:
            self.warnings.append(text)

    # interface --------------------------------------------------------------------------------
    @abstractmethod
    def topics(self) -> list[TopicInfo]:
        """Every topic (ULog message, CSV column, DataFlash message type) with count, rate, fields."""

    @abstractmethod
    def leaves(self, topic: str, field: str | None) -> list[str]:
        """The numeric leaf field(s) ``field`` of ``topic`` stands for: ``[field]``, or four leaves
        ``x, y, z, w`` for a quaternion. Raises LogReadError for unknown topics/fields."""

    @abstractmethod
    def read(self, topic: str, fields: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Times [s] (recording order) and float64 values of numeric leaf ``fields`` of ``topic``."""

    # shared -----------------------------------------------------------------------------------
    def prefetch(self, topics: list[str]) -> None:  # noqa: B027 - optional hook
        """Hint which topics will be read (formats that parse per topic read them in one pass)."""

    def topic_names(self) -> list[str]:
        return [info.name for info in self.topics()]

    def parameters(self) -> tuple[dict[str, float], list[tuple[float, str, float]]]:
        """Logged parameters ``(initial, [(t [s], name, value)])``; formats without any: empty."""
        return {}, []

    def resolve_topic(self, topic: str) -> str | None:
        """The log's name for ``topic`` (formats with other naming rules override), None if absent."""
        return topic if topic in self.topic_names() else None

    def missing_topic(self, topic: str) -> LogReadError:
        names = self.topic_names()
        shown = ", ".join(names[:25]) + (f", ... ({len(names)} in all)" if len(names) > 25 else "")
        return LogReadError(
            f"{self.path}: no topic {topic!r}{closest(topic, names)}; topics in the log: {shown or 'none'}")

    def values(self, topic: str, field: str | None = None) -> tuple[np.ndarray, list[str], dict[str, np.ndarray]]:
        """Checked times [s] and the leaf values for ``topic:field`` (see :meth:`leaves`)."""
        leaves = self.leaves(topic, field)
        t, vals = self.read(topic, leaves)
        where = f"{self.path}: {topic}"
        if len(t) == 0:
            raise LogReadError(f"{where} has no messages")
        t, keep, notes = check_times(t, where)
        for note in notes:
            self.warn(note.split(": ", 1)[1] if note.startswith(str(self.path)) else note)
        if keep is not None:
            vals = {k: v[keep] for k, v in vals.items()}
        return t, leaves, vals

    def series(self, topic: str, field: str | None = None) -> Signal:
        """One numeric field of ``topic`` as a :class:`~mrftcli.io.logtypes.Signal` (times [s], increasing).

        A quaternion field is refused here (it is four numbers): name one component or use
        :func:`mrftcli.io.read_flight`, which turns it into roll/pitch.
        """
        t, leaves, vals = self.values(topic, field)
        if len(leaves) != 1:
            raise LogReadError(
                f"{self.path}: {topic}:{field} is a quaternion; name one component "
                f"({', '.join(leaves)}) or read it with --loop roll/pitch")
        return Signal(t, vals[leaves[0]])


class Field:
    """Helpers for dotted field paths in formats that flatten them (CSV, ULog)."""

    @staticmethod
    def quaternion(prefix: str, available: set[str], seps: tuple[str, ...] = (".", "/")) -> list[str] | None:
        """Leaves ``prefix.x, .y, .z, .w`` (or with ``/``) if all exist in ``available``."""
        for sep in seps:
            names = [f"{prefix}{sep}{c}" for c in "xyzw"]
            if all(n in available for n in names):
                return names
        return None
