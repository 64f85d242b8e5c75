"""A log's clock: sample rates from timestamps and the timing a reader records for one flight.

* :func:`median_rate_hz` -> the rate [Hz] of a sampled signal, 1 / its median positive interval
  (the one rate-from-timestamps rule of the package: readers, segmenter, tuner);
* :func:`mean_rate_hz` -> the mean message rate [Hz] a topic listing shows;
* :func:`receive_jitter_s` -> the timing jitter [s] of receive-time stamps;
* :class:`Timing` -> what a :class:`~mrftcli.io.logtypes.FlightLog` knows about the controller's
  clock and its stamps; :func:`controller_rate_hz` -> the rate [Hz] at which the relay decided.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from ..jsonable import check_schema_version, json_opt_float
from ..errors import InputError

__all__ = ["Timing", "TIMING_SCHEMA_VERSION", "median_rate_hz", "mean_rate_hz", "receive_jitter_s",
           "controller_rate_hz", "logged_tick_s"]

#: version of :meth:`Timing.to_json`
TIMING_SCHEMA_VERSION = 2  # 2: controller_rate_assumed (1 is still read)

#: where a log's stamps come from: ``header`` (set where the sample was made) or ``receive``
#: (set by the recorder on arrival, so they carry the transport's jitter)
Stamps = Literal["header", "receive"]


def median_rate_hz(t: npt.ArrayLike) -> float | None:
    """Sample rate [Hz] of increasing times: 1 / the median positive interval.

    The median ignores dropped samples and bursts; intervals of zero (stamps repeated by a logger
    that stamps batches on arrival) are not intervals of the clock and are left out.

    Parameters
    ----------
    t : array_like
        Sample times [s], non-decreasing.

    Returns
    -------
    float or None
        The rate [Hz]; None for fewer than three samples or no positive interval.

    Examples
    --------
    >>> median_rate_hz([0.0, 0.01, 0.02, 0.02, 0.03, 0.05])
    100.0
    >>> median_rate_hz([0.0, 0.01]) is None
    True
    """
    times = np.asarray(t, dtype=np.float64)
    if times.size < 3:
        return None
    dt = np.diff(times)
    dt = dt[dt > 0]
    if dt.size == 0:
        return None
    return float(1.0 / np.median(dt))


def logged_tick_s(t: npt.ArrayLike, min_share: float = 0.05) -> float | None:
    """The controller's period [s] that a sub-sampled signal's stamps are whole multiples of.

    A logger that keeps one message every ``T`` from a topic published every controller tick ``Ts``
    (PX4's logger: the first message at least ``T`` after the last one kept, the lag carried over)
    logs intervals of ``n Ts`` and ``(n + 1) Ts`` when ``Ts`` does not divide ``T`` (10 Hz from a
    125 Hz controller: 96 and 104 ms): the step between the distinct intervals is the tick. When every
    interval is the same multiple, the tick is not in the stamps (None).

    Parameters
    ----------
    t : array_like
        Sample times [s], increasing, stamped where the message was published.
    min_share : float
        The least share of the intervals a distinct interval needs (rarer ones: dropped messages).

    Returns
    -------
    float or None
        The tick [s] (rounded to 1 us); None when the intervals do not show one.

    Examples
    --------
    >>> round(1 / logged_tick_s(np.cumsum([0.096, 0.104] * 20)), 6)
    125.0
    >>> logged_tick_s(np.arange(40) * 0.1) is None
    True
    """
    times = np.asarray(t, dtype=np.float64)
    if times.size < 20:
        return None
    d = np.sort(np.diff(times))
    d = d[d > 0]
    if d.size < 19:
        return None
    med = float(np.median(d))
    tol = max(20e-6, 0.005 * med)  # the publisher's scheduling jitter
    cuts = np.flatnonzero(np.diff(d) > tol) + 1
    groups = [g for g in np.split(d, cuts) if g.size >= min_share * d.size]
    if len(groups) < 2:
        return None
    centres = np.array([float(np.median(g)) for g in groups])
    tick = float(np.min(np.diff(centres)))
    multiples = centres / tick
    if tick < 10 * tol or tick > med / 1.5 or np.max(np.abs(multiples - np.round(multiples))) > 0.1:
        return None
    return round(tick, 6)


def mean_rate_hz(t: npt.ArrayLike) -> float | None:
    """Mean message rate [Hz] over a topic's span (what a topic listing shows).

    Parameters
    ----------
    t : array_like
        Message times [s].

    Returns
    -------
    float or None
        (messages - 1) / (last - first time) [Hz]; None for fewer than two messages or no span.

    Examples
    --------
    >>> mean_rate_hz([0.0, 0.5, 2.0])
    1.0
    """
    times = np.asarray(t, dtype=np.float64)
    if times.size < 2 or times[-1] <= times[0]:
        return None
    return float((times.size - 1) / (times[-1] - times[0]))


def receive_jitter_s(t: npt.ArrayLike) -> float:
    """Timing jitter [s] of receive-time stamps: the robust spread of the sample spacing / sqrt 2.

    A stamp e_k late gives spacings dt + e_{k+1} - e_k, whose variance is 2 var(e) for independent
    delays; the median absolute deviation (x 1.4826) ignores dropped samples and bursts.

    Parameters
    ----------
    t : array_like
        Receive times [s] of one topic.

    Returns
    -------
    float
        The jitter [s]; NaN for fewer than 20 samples.
    """
    times = np.asarray(t, dtype=np.float64)
    if times.size < 20:
        return float("nan")
    d = np.diff(times)
    mad = float(np.median(np.abs(d - np.median(d)))) * 1.4826
    return mad / math.sqrt(2.0)


@dataclass(frozen=True)
class Timing:
    """What a flight log says about the controller's clock and its own stamps.

    Attributes
    ----------
    controller_rate_hz : float or None
        Rate [Hz] at which the relay decided, when the log layout or the user gives it (the command
        may be logged more slowly, e.g. PX4's position controller at 50 Hz); None: the command's own.
    stamps : {"header", "receive"}
        ``receive`` when the samples carry the recorder's arrival times (no header stamps).
    timing_jitter_s : float or None
        Jitter [s] of receive-time stamps (:func:`receive_jitter_s`; the larger of command and
        output); None with header stamps. Widens tau's uncertainty.
    controller_rate_assumed : bool
        The rate is the layout's assumption: the log did not show it (the reader warns) and the user gave none.

    Examples
    --------
    >>> Timing(50.0).source_items()
    {'controller_rate_hz': 50.0}
    >>> Timing.from_json(Timing(None, "receive", 0.002).to_json()) == Timing(None, "receive", 0.002)
    True
    """

    controller_rate_hz: float | None = None
    stamps: Stamps = "header"
    timing_jitter_s: float | None = None
    controller_rate_assumed: bool = False

    def source_items(self) -> dict[str, Any]:
        """The keys ``FlightLog.source`` carried before :class:`Timing` existed (the ``--json``
        ``input.source`` keeps them): ``controller_rate_hz`` when known, and ``timestamps``,
        ``timing_jitter_s`` for receive stamps."""
        items: dict[str, Any] = {}
        if self.controller_rate_hz is not None:
            items["controller_rate_hz"] = self.controller_rate_hz
        if self.stamps == "receive":
            items["timestamps"] = "receive"
            items["timing_jitter_s"] = self.timing_jitter_s
        return items

    def to_json(self) -> dict[str, Any]:
        """A JSON-able dict with ``schema_version`` (NaN jitter becomes None)."""
        jitter = self.timing_jitter_s
        return {"schema_version": TIMING_SCHEMA_VERSION, "controller_rate_hz": self.controller_rate_hz,
                "stamps": self.stamps,
                "timing_jitter_s": None if jitter is None or not math.isfinite(jitter) else jitter,
                "controller_rate_assumed": self.controller_rate_assumed}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Timing:
        """The record :meth:`to_json` wrote.

        Raises
        ------
        InputError
            Not a dict, another schema version, or a field of the wrong kind.
        """
        check_schema_version(data, "timing", (1, TIMING_SCHEMA_VERSION))
        stamps = data.get("stamps")
        if stamps not in ("header", "receive"):
            raise InputError(f"timing: stamps must be 'header' or 'receive', got {stamps!r}")
        try:
            rate, jitter = (json_opt_float(data.get(key), f"{key} to be a number or null")
                            for key in ("controller_rate_hz", "timing_jitter_s"))
        except TypeError as err:  # the one JSON number reader's message, as a timing record's one line
            raise InputError(f"timing: {err}") from None
        return cls(controller_rate_hz=rate, stamps=stamps, timing_jitter_s=jitter,
                   controller_rate_assumed=data.get("controller_rate_assumed") is True)


def controller_rate_hz(timing: Timing, t_command: npt.ArrayLike) -> float | None:
    """The rate [Hz] at which the relay decided: the layout's or the user's, else the command's.

    Parameters
    ----------
    timing : Timing
        The flight's timing (``FlightLog.timing``).
    t_command : array_like
        The command's sample times [s].

    Returns
    -------
    float or None
        ``timing.controller_rate_hz`` when known, else :func:`median_rate_hz` of the command.

    Examples
    --------
    >>> controller_rate_hz(Timing(50.0), [0.0, 0.01, 0.02])
    50.0
    >>> controller_rate_hz(Timing(), [0.0, 0.01, 0.02])
    100.0
    """
    if timing.controller_rate_hz:
        return float(timing.controller_rate_hz)
    return median_rate_hz(t_command)
