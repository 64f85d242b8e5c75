"""Write a flight's signals the way a real flight stack records them (:mod:`mrftcli.io.layouts`).

The simulator (:mod:`mrftcli.sim`) flies at the controller's rate and writes the reference layout; this
module turns the same arrays into what PX4 with the MRFT patch, the HEAR ROS 1 stack or a MATLAB
export would have logged: their topic names, frames and signs, their logging rates (PX4's default
10 Hz logger), their receive-time stamps (HEAR's header-less ``geometry_msgs/Point``) and, for PX4,
beta, h and the test windows as parameter changes. The sample logs and the layout tests use it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .layouts import LAYOUTS
from .logtypes import TopicData

__all__ = ["StackTest", "StackLogSpec", "write_stack_log", "hear_receive_times"]

#: layout -> the format its logs are written in
STACK_FORMATS = {"px4-mrft": "ulog", "hear-ros": "bag", "mat": "mat", "mat-v73": "mat"}
_AXIS = {"x": 0, "y": 1, "altitude": 2}


@dataclass(frozen=True)
class StackTest:
    """One MRFT test as the stack switched it on: window [s], beta and h [command units]."""

    t_start: float
    t_end: float
    beta: float
    h: float


@dataclass(frozen=True)
class StackLogSpec:
    """How a flight stack logs one loop's flight (:func:`write_stack_log`); checked on creation.

    Attributes
    ----------
    layout : {"px4-mrft", "hear-ros", "mat", "mat-v73"}
        The flight stack's layout (:data:`STACK_FORMATS`).
    loop : str
        The loop the tests excite (in the loop's frame: altitude up, command = bias + relay).
    bias : float
        The command's trim [command units] (hover thrust for altitude).
    tests : tuple of StackTest
        The tests' windows [s], beta [-] and h [command units] (PX4 logs them as parameter changes);
        any sequence is kept as a tuple.
    log_rate_hz : float, optional
        The logger's rate [Hz] (> 0; PX4's default profile: 10 Hz); None logs every controller tick.
    seed : int
        Seed of the receive-time jitter (hear-ros).

    Raises
    ------
    InputError
        An unknown layout, a bias that is not finite, a logging rate that is not positive.
    """

    layout: str
    loop: str
    bias: float
    tests: Sequence[StackTest] = ()
    log_rate_hz: float | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if self.layout not in STACK_FORMATS:
            raise InputError(f"cannot write layout {self.layout!r}; choose one of {', '.join(STACK_FORMATS)}")
        if not math.isfinite(self.bias):
            raise InputError(f"the command's trim (bias) must be a finite number, got {self.bias!r}")
        if self.log_rate_hz is not None and not (math.isfinite(self.log_rate_hz) and self.log_rate_hz > 0):
            raise InputError(f"the logging rate must be a positive number [Hz] or None, got {self.log_rate_hz!r}")
        object.__setattr__(self, "tests", tuple(self.tests))


def _decimate(t: np.ndarray, rate_hz: float | None) -> np.ndarray:
    """Indices of the samples a logger at ``rate_hz`` keeps (every k-th controller tick)."""
    if rate_hz is None:
        return np.arange(t.size)
    dt = float(np.median(np.diff(t)))
    step = max(1, int(round(1.0 / (rate_hz * dt))))
    return np.arange(0, t.size, step)


@dataclass(frozen=True)
class _Px4Log:
    """What the PX4 logger writes of a flight: the topics, the parameters and their changes, the messages."""

    topics: list[TopicData]
    parameters: dict[str, float]
    parameter_changes: list[tuple[float, str, float]]
    messages: list[tuple[float, str]]


def _px4(loop: str, t: np.ndarray, command: np.ndarray, output: np.ndarray, setpoint: np.ndarray, bias: float,
         tests: Sequence[StackTest], log_rate_hz: float | None) -> _Px4Log:
    if loop not in _AXIS:
        raise InputError(f"the PX4 MRFT patch runs on x, y and altitude, not {loop}")
    k = _decimate(t, log_rate_hz)
    axis = _AXIS[loop]
    n = k.size
    pos = {c: np.zeros(n) for c in "xyz"}
    sp = {c: np.zeros(n) for c in "xyz"}
    thrust = {f"thrust[{i}]": np.zeros(n) for i in range(3)}
    hover = bias if loop == "altitude" else 0.5
    thrust["thrust[2]"][:] = -hover
    c = "xyz"[axis]
    if loop == "altitude":  # NED: z down, thrust[2] = -(u) - hover (upwards is negative)
        pos[c] = -output[k]
        sp[c] = -setpoint[k]
        thrust["thrust[2]"] = -command[k]
    else:
        pos[c] = output[k]
        sp[c] = setpoint[k]
        thrust[f"thrust[{axis}]"] = command[k] - bias
    tk = t[k]
    topics = [
        TopicData("vehicle_local_position", "px4", tk, {**pos, "vx": np.gradient(pos["x"], tk),
                                                        "vy": np.gradient(pos["y"], tk),
                                                        "vz": np.gradient(pos["z"], tk)}),
        TopicData("vehicle_local_position_setpoint", "px4", tk, {**sp, **thrust}),
        TopicData("hover_thrust_estimate", "px4", tk[::10], {"hover_thrust": np.full(tk[::10].size, hover)}),
    ]
    A = "XYZ"[axis]
    params = {f"MRFT_{a}_{p}": v for a in "XYZ" for p, v in
              (("BETA", -0.73), ("H", 0.05), ("ENABLE", 0.0), ("NO_SWITCH", 0.02), ("N_CONF", 5.0))}
    params["MPC_THR_HOVER"] = hover
    changes: list[tuple[float, str, float]] = []
    messages: list[tuple[float, str]] = []
    for test in tests:
        changes += [(test.t_start, f"MRFT_{A}_BETA", test.beta), (test.t_start, f"MRFT_{A}_H", test.h),
                    (test.t_start, f"MRFT_{A}_ENABLE", 1.0), (test.t_end, f"MRFT_{A}_ENABLE", 0.0)]
        on = [int(a == A) for a in "XYZ"]
        messages.append((test.t_start, "MRFT parameters updated, x: %i, y: %i, z: %i" % tuple(on)))
    return _Px4Log(topics, params, changes, messages)


def hear_receive_times(stamps: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """When HEAR's ROS 1 bag receives messages sent at ``stamps`` [s]: 1 ms plus a half-normal 2 ms late
    (transport and scheduling), increasing per topic (1 us apart at least), as a header-less Point is stamped."""
    late = np.abs(rng.normal(0.0, 0.002, stamps.size)) + 0.001
    ramp = np.arange(stamps.size) * 1e-6
    stamped: np.ndarray = np.maximum.accumulate(stamps + late - ramp) + ramp
    return stamped


def _hear(loop: str, t: np.ndarray, command: np.ndarray, output: np.ndarray, setpoint: np.ndarray,
          log_rate_hz: float | None, rng: np.random.Generator) -> list[TopicData]:
    """HEAR ROS 1: Points without header, stamped at receive time (a few ms of jitter)."""
    if loop not in LAYOUTS["hear-ros"].loops:
        raise InputError(f"the HEAR layout has no loop {loop}")
    roles = LAYOUTS["hear-ros"].loops[loop]  # the topics the reader's layout looks for: TOPIC:AXIS
    (cmd_topic, comp), (out_topic, _), (ref_topic, _) = (
        str(spec).split(":") for spec in (roles.command, roles.output, roles.setpoint))
    k = _decimate(t, log_rate_hz)
    # OptiTrack at ~90 Hz: the latest controller-tick sample at each camera frame
    t_cam = np.arange(t[0], t[-1], 1.0 / 90.0)
    kc = np.clip(np.searchsorted(t, t_cam, side="right") - 1, 0, t.size - 1)

    def point(values: np.ndarray, n: int) -> dict[str, np.ndarray]:
        out = {c: np.zeros(n) for c in "xyz"}
        out[comp] = values
        return out

    return [
        TopicData(cmd_topic, "geometry_msgs/msg/Point", hear_receive_times(t[k], rng), point(command[k], k.size)),
        TopicData(out_topic, "geometry_msgs/msg/Point", hear_receive_times(t[kc], rng), point(output[kc], kc.size)),
        TopicData(ref_topic, "geometry_msgs/msg/Point", hear_receive_times(t[k][::10], rng), point(setpoint[k][::10], k[::10].size)),
    ]


def _mat(loop: str, t: np.ndarray, command: np.ndarray, output: np.ndarray,
         log_rate_hz: float | None) -> list[TopicData]:
    topics = LAYOUTS["mat"].loops[loop]  # the names the reader's layout looks for
    k = _decimate(t, log_rate_hz)
    return [TopicData(topics.command, "vector", t[k], {"data": command[k]}),
            TopicData(topics.output, "vector", t[k], {"data": output[k]})]


def write_stack_log(path: str | Path, spec: StackLogSpec, t: np.ndarray, command: np.ndarray,
                    output: np.ndarray, setpoint: np.ndarray | float) -> Path:
    """Write one loop's flight as ``spec.layout`` logs it.

    Parameters
    ----------
    path : str or Path
        Target file (``.ulg`` for ``px4-mrft``, ``.bag`` for ``hear-ros``, ``.mat`` for ``mat`` and
        ``mat-v73``).
    spec : StackLogSpec
        The layout, the loop, the command's trim, the tests, the logger's rate and the jitter's seed.
    t, command, output : numpy.ndarray
        Controller ticks [s], the command sent (bias + relay output) [command units] and the measured
        output [output units].
    setpoint : numpy.ndarray or float
        The loop reference [output units].

    Returns
    -------
    Path
        The written file.
    """
    layout, loop, log_rate_hz = spec.layout, spec.loop, spec.log_rate_hz
    t = np.asarray(t, float)
    command = np.asarray(command, float)
    output = np.asarray(output, float)
    setpoint = np.broadcast_to(np.asarray(setpoint, float), t.shape).copy()
    path = Path(path)
    if path.exists():
        path.unlink()
    if layout == "px4-mrft":
        from .format_ulog import write_ulog

        px4 = _px4(loop, t, command, output, setpoint, spec.bias, spec.tests, log_rate_hz)
        write_ulog(px4.topics, path, parameters=px4.parameters, parameter_changes=px4.parameter_changes,
                   messages=px4.messages)
    elif layout == "hear-ros":
        from .format_rosbag import write_rosbag

        write_rosbag(_hear(loop, t, command, output, setpoint, log_rate_hz, np.random.default_rng(spec.seed)),
                     path, "bag")
    elif layout in ("mat", "mat-v73"):
        from .format_mat import write_mat

        write_mat(_mat(loop, t, command, output, log_rate_hz), path, v73=layout == "mat-v73")
    else:
        raise InputError(f"cannot write layout {layout!r}; choose one of {', '.join(STACK_FORMATS)}")
    return path
