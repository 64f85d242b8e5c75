"""The hover thrust PX4 estimated during a flight, read from the log's ``hover_thrust_estimate`` topic.

PX4's velocity loops output an acceleration that ``PositionControl`` turns into thrust with the hover
thrust its estimator learns in flight (``MPC_USE_HTE``, on by default), so the value flown is the
estimate's, not ``MPC_THR_HOVER``'s. ``tune`` and ``vehicle`` use it for ``--export px4`` when
``--hover-thrust`` is not given, and say so first. ArduPilot's ``CTUN.ThH`` is not read: logged at
about 1 Hz it holds the saved ``MOT_THST_HOVER`` for most of a short flight before the learned value.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import LogReadError
from .source import LogSource

__all__ = ["HOVER_TOPIC", "LoggedHoverThrust", "logged_hover_thrust"]

#: PX4's uORB topic of the hover thrust estimator (``mc_hover_thrust_estimator``); a ROS 2 bridge's
#: ``/fmu/out/hover_thrust_estimate`` is the same message
HOVER_TOPIC = "hover_thrust_estimate"


@dataclass(frozen=True)
class LoggedHoverThrust:
    """The hover thrust a log holds: the median of its valid samples.

    Attributes
    ----------
    value : float
        Median of the valid samples [normalised thrust, 0-1].
    samples : int
        Valid samples the median is taken over.
    low, high : float
        Their smallest and largest value [normalised thrust].
    topic : str
        The log's topic they were read from.
    """

    value: float
    samples: int
    low: float
    high: float
    topic: str

    def statement(self) -> str:
        """The assumption the output states first (and its JSON carries)."""
        return (f"hover thrust {self.value:.4g} (MPC_THR_HOVER, normalised) read from the log: the median of the "
                f"{self.samples} valid {self.topic}.hover_thrust samples ({self.low:.4g}-{self.high:.4g}); "
                "--hover-thrust X overrides it")


def _topic(source: LogSource) -> str | None:
    for name in source.topic_names():
        if name.rsplit("/", 1)[-1] == HOVER_TOPIC:
            return name
    return None


def logged_hover_thrust(source: LogSource) -> LoggedHoverThrust | None:
    """The hover thrust PX4 estimated in the open log, or None when the log holds no valid estimate.

    Samples flagged not ``valid`` (before take-off the estimator has not converged), non-finite or outside
    (0, 1) are left out; a log without the ``valid`` field uses every sample in (0, 1).
    """
    topic = _topic(source)
    if topic is None:
        return None
    try:
        _, d = source.read(topic, ["hover_thrust", "valid"])
        ok = d["valid"] > 0
    except (LogReadError, KeyError):
        try:
            _, d = source.read(topic, ["hover_thrust"])
        except (LogReadError, KeyError):
            return None
        ok = np.ones(d["hover_thrust"].shape, dtype=bool)
    v = np.asarray(d["hover_thrust"], dtype=float)
    v = v[ok & np.isfinite(v) & (v > 0.0) & (v < 1.0)]
    if v.size == 0:
        return None
    return LoggedHoverThrust(float(np.median(v)), int(v.size), float(v.min()), float(v.max()), topic)

