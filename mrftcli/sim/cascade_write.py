"""Write a cascaded flight (:class:`~mrftcli.sim.cascade.CascadeFlight`) as a log plus its truth sidecar.

Two layouts (docs/log-layout.md, docs/simulator.md):

* ``hear-ros`` (a ROS 1 bag, as HEAR records a cascade): ``/fh_des`` (the outer command, x or y;
  z the hover thrust g = 9.80665 m/s^2), ``/angle_u`` (the inner commands: x roll, y pitch), ``/opti/pos`` and
  ``/opti/ori`` (position and attitude as measured), ``/waypoint_reference/pos`` and ``/angle_ref``
  (the attitude setpoint) at a tenth of the rate; ``geometry_msgs/Point`` has no header, so every message is stamped at
  its receive time (1 ms plus a half-normal 2 ms late, increasing per topic). Both loops' tests are
  found from these topics (``--loop roll`` / ``--loop y``).
* ``reference``: the reference layout holds one MRFT block per log, so ``/mrft/command``,
  ``/mrft/beta`` and ``/mrft/setpoint`` are the OUTER loop's (``--loop x|y`` reads them) and the
  inner loop's are under ``/mrft/inner/command``, ``/mrft/inner/beta``, ``/mrft/inner/setpoint``
  (``--loop roll --command-topic /mrft/inner/command:data --beta-topic /mrft/inner/beta:data``);
  ``/mocap/pose`` and ``/imu/data`` carry both loops' outputs, stamped at the source.

All topics are written at the controller rate, so the logs carry the simulated delays and nothing
else (a 90 Hz camera would add its sample-and-hold latency to the outer tau).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..io.logtypes import TopicData
from ..io.stacks import hear_receive_times
from ..mrft.cascade import STANDARD_GRAVITY
from .cascade import CascadeFlight
from .sidecar import imu_topic, write_log_atomic, write_sidecar

__all__ = ["CASCADE_LAYOUTS", "cascade_topics", "write_cascade"]

#: layouts a cascaded flight is written in, with their log format
CASCADE_LAYOUTS = {"hear-ros": "bag", "reference": None}

Array = NDArray[np.float64]


def _signs(flight: CascadeFlight) -> tuple[float, str]:
    """The logged attitude's sign (-1 for pitch: alpha = -theta) and the position axis."""
    return (1.0 if flight.spec.axis == "y" else -1.0), flight.spec.axis


def _attitudes(flight: CascadeFlight) -> tuple[Array, Array]:
    """(roll, pitch) as measured [rad]: the loop's axis and the other axis' noise."""
    sign, axis = _signs(flight)
    tested = sign * flight.attitude_measured
    return (tested, flight.other_attitude) if axis == "y" else (flight.other_attitude, tested)


def _test_starts(flight: CascadeFlight, inner: bool) -> tuple[Array, Array]:
    loop = flight.truth.inner_loop if inner else flight.truth.axis
    tests = flight.truth.tests_of(loop)
    return (np.array([t.t_start for t in tests], float), np.array([t.beta for t in tests], float))


def _reference_topics(flight: CascadeFlight) -> list[TopicData]:
    sign, axis = _signs(flight)
    t, n = flight.t, flight.t.size
    f64 = "std_msgs/msg/Float64"
    setpoint_idx = np.arange(0, n, 10)
    topics = [TopicData("/mrft/command", f64, t.copy(), {"data": flight.outer_command.copy()})]
    for name, inner in (("/mrft/beta", False), ("/mrft/inner/beta", True)):
        starts, betas = _test_starts(flight, inner)
        if starts.size:
            topics.append(TopicData(name, f64, starts, {"data": betas}))
    topics += [
        TopicData("/mrft/setpoint", f64, t[setpoint_idx].copy(), {"data": np.zeros(setpoint_idx.size)}),
        TopicData("/mrft/inner/command", f64, t.copy(), {"data": sign * flight.inner_command}),
        TopicData("/mrft/inner/setpoint", f64, t.copy(), {"data": sign * flight.attitude_setpoint}),
    ]
    pose = {f"pose.position.{c}": np.zeros(n) for c in "xyz"}
    pose[f"pose.position.{axis}"] = flight.position_measured.copy()
    pose["pose.position.z"] = np.ones(n)
    pose["pose.orientation.w"] = np.ones(n)
    topics.append(TopicData("/mocap/pose", "geometry_msgs/msg/PoseStamped", t.copy(), pose))
    topics.append(imu_topic(t, *_attitudes(flight)))
    return topics


def _hear_topics(flight: CascadeFlight, rng: np.random.Generator) -> list[TopicData]:
    sign, axis = _signs(flight)
    t, n = flight.t, flight.t.size
    point = "geometry_msgs/msg/Point"

    def xyz(**values: Array) -> dict[str, Array]:
        fields = {c: np.zeros(n) for c in "xyz"}
        fields.update(values)
        return fields

    roll, pitch = _attitudes(flight)
    inner = sign * flight.inner_command
    inner_ref = sign * flight.attitude_setpoint
    angle_axis = "x" if axis == "y" else "y"
    pos = xyz(z=np.ones(n), **{axis: flight.position_measured})
    ref = np.arange(0, n, 10)
    return [
        TopicData("/fh_des", point, hear_receive_times(t, rng), xyz(z=np.full(n, STANDARD_GRAVITY), **{axis: flight.outer_command})),
        TopicData("/angle_u", point, hear_receive_times(t, rng), xyz(**{angle_axis: inner})),
        TopicData("/opti/pos", point, hear_receive_times(t, rng), pos),
        TopicData("/opti/ori", point, hear_receive_times(t, rng), xyz(x=roll, y=pitch)),
        TopicData("/waypoint_reference/pos", point, hear_receive_times(t[ref], rng), {c: np.zeros(ref.size) for c in "xyz"}),
        TopicData("/angle_ref", point, hear_receive_times(t[ref], rng), {c: (inner_ref[ref] if c == angle_axis else np.zeros(ref.size))
                                                          for c in "xyz"}),
    ]


def cascade_topics(flight: CascadeFlight, layout: str = "hear-ros", seed: int = 0) -> list[TopicData]:
    """The flight's topics in ``layout`` (``hear-ros`` or ``reference``); ``seed``: the receive stamps."""
    if layout == "hear-ros":
        return _hear_topics(flight, np.random.default_rng(seed))
    if layout == "reference":
        return _reference_topics(flight)
    raise InputError(f"a cascaded flight is written in the {' or '.join(CASCADE_LAYOUTS)} layout, not {layout!r}")


def write_cascade(flight: CascadeFlight, path: str | Path, layout: str = "hear-ros", fmt: str | None = None) -> Path:
    """Write the flight as a log in ``layout`` and its :class:`CascadeTruth` next to it; return the sidecar.

    Parameters
    ----------
    flight : CascadeFlight
    path : str or Path
        The log (``.bag`` for ``hear-ros``; any writable format for ``reference``).
    layout : {"hear-ros", "reference"}
    fmt : str, optional
        The log format (default: ``bag`` for hear-ros, else from the file name).
    """
    from ..io import writable_format

    path = Path(path)
    topics = cascade_topics(flight, layout, seed=flight.spec.seed + 1)  # an unknown layout refused first
    fmt = writable_format(path, fmt or CASCADE_LAYOUTS[layout])
    write_log_atomic(topics, path, fmt)
    truth = dataclasses.replace(flight.truth, layout=layout, log_format=fmt, log_file=path.name)
    return write_sidecar(path, truth.to_json())
