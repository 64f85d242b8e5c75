"""Format-neutral records passed between the readers, the simulator and the writers.

Times are float seconds (converted once from the logs' nanoseconds/microseconds at the reader edge).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

__all__ = ["TopicData", "TopicInfo", "FlightLog", "LOOPS"]

#: The loops mrft-ident identifies.
LOOPS = ("altitude", "roll", "pitch")


@dataclass(frozen=True)
class TopicData:
    """One topic's messages as columns, used to *write* logs (simulator -> writers).

    Attributes
    ----------
    name : str
        Topic name, e.g. ``/mrft/command``.
    msgtype : str
        ROS 2 style type name, e.g. ``std_msgs/msg/Float64``, ``geometry_msgs/msg/PoseStamped``,
        ``sensor_msgs/msg/Imu``, ``sensor_msgs/msg/BatteryState``.
    t : numpy.ndarray
        Message (receive/log) times [s], non-decreasing.
    fields : dict[str, numpy.ndarray]
        Dotted field path -> values, one per message, e.g. ``{"data": ...}`` or
        ``{"pose.position.z": ..., "pose.orientation.w": ...}``. Fields not given are written as zero
        (quaternion ``w`` as one).
    """

    name: str
    msgtype: str
    t: np.ndarray
    fields: dict[str, np.ndarray]


@dataclass(frozen=True)
class TopicInfo:
    """What ``mrft-ident topics`` lists for one topic (or ULog message / CSV column group)."""

    name: str
    msgtype: str
    count: int
    rate_hz: float | None
    fields: tuple[str, ...] = ()


@dataclass
class FlightLog:
    """The signals mrft-ident needs from one log, for one loop.

    Every series is a float ``pandas.Series`` indexed by time [s] (float64, increasing).

    Attributes
    ----------
    path : str
        The file it came from.
    loop : str
        ``altitude``, ``roll`` or ``pitch``.
    command : pandas.Series
        The command the MRFT block sends to the loop (bias + relay output), command units.
    output : pandas.Series
        The loop output: altitude [m] or roll/pitch [rad].
    beta : pandas.Series or None
        Beta as published when each test starts, if logged.
    setpoint : pandas.Series or None
        The loop reference, if logged (output units).
    battery_voltage : pandas.Series or None
        Battery voltage [V], if logged.
    source : dict
        Where each series came from (topic/field), format name and reader notes.
    warnings : list[str]
        Non-fatal problems met while reading (e.g. salvaged truncated file).
    """

    path: str
    loop: str
    command: pd.Series
    output: pd.Series
    beta: pd.Series | None = None
    setpoint: pd.Series | None = None
    battery_voltage: pd.Series | None = None
    source: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
