"""Format-neutral records passed between the readers, the simulator and the writers.

Times are float seconds (converted once from the logs' nanoseconds/microseconds at the reader edge).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from .timing import Timing

__all__ = ["Signal", "TopicData", "TopicInfo", "FlightLog", "LOOPS", "PROCESS_LOOP", "output_unit", "gain_unit", "sig"]

#: The loops mrft-ident identifies.
LOOPS = ("altitude", "roll", "pitch", "x", "y")
#: The loop of a process plant's recording when the user names none (``--model``/``--model-file`` without
#: ``--loop``): not a vehicle's, so its records do not say ``altitude``. Read as the layouts' altitude loop.
PROCESS_LOOP = "process"


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


@dataclass(frozen=True, eq=False)
class Signal:
    """One logged signal: sample times and values, as float64 numpy arrays of equal length.

    Attributes
    ----------
    t : numpy.ndarray
        Sample times [s] (float64; increasing as the readers return them).
    values : numpy.ndarray
        The values, one per time, in the signal's units (float64).

    Examples
    --------
    >>> s = Signal([0.0, 0.01, 0.02], [1, 2, 3])
    >>> len(s), s.values.dtype.name, float(s.t[-1])
    (3, 'float64', 0.02)
    """

    t: np.ndarray
    values: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64)
        v = np.asarray(self.values, dtype=np.float64)
        if t.shape != v.shape or t.ndim != 1:
            raise InputError(f"a signal needs 1-D times and values of one length, got {t.shape} and {v.shape}")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "values", v)

    def __len__(self) -> int:
        return int(self.t.size)


@dataclass(frozen=True)
class FlightLog:
    """The signals mrft-ident needs from one log, for one loop.

    Every signal is a :class:`Signal` (numpy times [s] and float64 values).

    Attributes
    ----------
    path : str
        The file it came from.
    loop : str
        ``altitude``, ``roll``, ``pitch``, ``x`` or ``y`` (:data:`LOOPS`).
    command : Signal
        The command the MRFT block sends to the loop (bias + relay output), command units.
    output : Signal
        The loop output: altitude, x, y [m] or roll/pitch [rad].
    beta : Signal or None
        Beta as published when each test starts, if logged.
    setpoint : Signal or None
        The loop reference, if logged (output units).
    battery_voltage : Signal or None
        Battery voltage [V], if logged.
    source : dict
        Descriptive metadata: where each series came from (topic/field), the format and layout, the
        scales, the conversions and (PX4) the test windows.
    warnings : tuple[str, ...]
        Non-fatal problems met while reading (e.g. salvaged truncated file); a list is stored as a
        tuple.
    timing : Timing
        The controller's rate when the layout or the user gives it, and the stamps' kind and jitter
        (what the segmenter and the uncertainty of tau use).

    Notes
    -----
    The record is frozen: derive a changed flight with :func:`dataclasses.replace`.
    """

    path: str
    loop: str
    command: Signal
    output: Signal
    beta: Signal | None = None
    setpoint: Signal | None = None
    battery_voltage: Signal | None = None
    source: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    timing: Timing = Timing()

    def __post_init__(self) -> None:
        object.__setattr__(self, "warnings", tuple(self.warnings))

    def source_json(self) -> dict[str, Any]:
        """``source`` with the timing written back into its keys, in the order the ``--json`` output
        has always had them: ``controller_rate_hz`` after ``layout``; ``timestamps`` and
        ``timing_jitter_s`` last.

        Examples
        --------
        >>> flight = FlightLog("f.csv", "altitude", Signal([0.0], [0.0]), Signal([0.0], [0.0]),
        ...                    source={"format": "csv", "layout": "px4", "command": "c"}, timing=Timing(50.0))
        >>> list(flight.source_json())
        ['format', 'layout', 'controller_rate_hz', 'command']
        """
        timing = self.timing.source_items()
        out: dict[str, Any] = {}
        for key, value in self.source.items():
            out[key] = value
            if key == "layout" and "controller_rate_hz" in timing:
                out["controller_rate_hz"] = timing.pop("controller_rate_hz")
        out.update(timing)
        return out


#: the output's unit by loop (after --output-scale): roll and pitch come from a quaternion in rad
_OUTPUT_UNIT = {"altitude": "m", "x": "m", "y": "m", "roll": "rad", "pitch": "rad"}


def output_unit(loop: str) -> str:
    """The output's unit of a loop: ``m`` or ``rad`` (``output unit`` for a loop not listed).

    Examples
    --------
    >>> output_unit("roll"), output_unit("altitude"), output_unit("level")
    ('rad', 'm', 'output unit')
    """
    return _OUTPUT_UNIT.get(loop, "output unit")


def gain_unit(loop: str) -> str:
    """The unit of eq. (2)'s K for a loop: output unit/s² per command unit (K Td: command -> output rate).

    Examples
    --------
    >>> gain_unit("altitude")
    'm/s² per command unit'
    """
    return f"{output_unit(loop)}/s² per command unit"


def sig(x: float | None, spec: int | str = 4) -> str:
    """``x`` as the tables and summaries print a number: to ``spec`` significant digits (an int: ``.4g``) or by a
    format spec (a str, e.g. ``".2f"``); ``-`` when it is None or not finite.

    Examples
    --------
    >>> sig(0.0421999), sig(3.14159, 2), sig(12.345, ".1f"), sig(None), sig(float("nan"))
    ('0.0422', '3.1', '12.3', '-', '-')
    """
    if x is None or not math.isfinite(x):
        return "-"
    return format(x, f".{spec}g" if isinstance(spec, int) else spec)
