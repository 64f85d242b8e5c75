"""What a simulated flight leaves behind: the ground-truth sidecar (``<log>.truth.json``) and the
topics in the reference layout, written through :mod:`mrftcli.io`.

The sidecar names eq. (2)'s parameters at its top level (``Tp``, ``Td``, ``tau``, ``K``); a flight of
another family has its ``family``, its model JSON (``model``) and ``parameters`` there instead.

docs/simulator.md describes the sidecar's fields.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..io.atomic import atomic_directory, atomic_path, check_output_path, write_text_atomic
from ..io.logtypes import TopicData
from ..jsonable import to_jsonable
from ..mrft.model import LoopModel, PlantModel
from .control import HoldPID, noise_margin
from .spec import FlightSettings, FlightSpec

if TYPE_CHECKING:
    from .flight import SimulatedFlight

__all__ = ["truth_record", "flight_topics", "imu_topic", "sidecar_path", "write_flight", "write_log_atomic", "write_sidecar", "check_log_target",
           "quaternion_zyx"]


def truth_record(spec: FlightSpec, settings: FlightSettings, pid: HoldPID, rate_true: np.ndarray,
                 delays: np.ndarray | None, aborted: Sequence[int | None],
                 abort_limits: Sequence[float]) -> dict[str, Any]:
    """The sidecar's contents: the model, the flight's settings, per test its span and truth figures.

    Parameters
    ----------
    spec, settings : FlightSpec, FlightSettings
        What was flown, and its defaults and schedule.
    pid : HoldPID
        The hold controller.
    rate_true : ndarray
        The true output rate y' at each tick [output units / s] (the quadratic-drag equivalent Td).
    delays : ndarray or None
        The realised delay of each tick's command [s] with delay jitter; None without.
    aborted : sequence of int or None
        Per test, the tick its safety abort came at (None: flown to the end).
    abort_limits : sequence of float
        Per test, the |error| that aborts it [output units].
    """
    from .._version import __version__

    model = spec.model
    eff = spec.effects
    noise_std, bias, r = settings.noise_std, settings.bias, settings.setpoint
    truth: dict[str, Any] = {
        "format": "mrft-ident simulation truth",
        "version": 1,
        "mrftcli_version": __version__,
        **_model_truth(model),
        "loop": spec.loop,
        "rate_hz": spec.rate_hz,
        "noise_std": noise_std,
        "bias": bias,
        "setpoint": r,
        "start_time": spec.start_time,
        "duration": settings.n_ticks * settings.T,
        "hover_s": spec.hover_s,
        "hold_s": spec.hold_s,
        "tests": _test_truths(spec, settings, rate_true, aborted, abort_limits),
        "effects": asdict(eff),
        "effects_active": list(eff.active()),
        "drag_model": "quadratic" if eff.quadratic_drag > 0 else "linear",
        "seed": spec.seed,
        "switching_rule": (
            {"name": "checks", "start_threshold": 10.0 * noise_std if spec.start_threshold is None else spec.start_threshold}
            if spec.switching == "checks"
            else {"name": "hear", "confirm_samples": spec.confirm_samples, "no_switch_delay": spec.no_switch_delay}
        ),
        "hold_controller": asdict(pid),
        "units": {
            "output": "m" if spec.loop in ("altitude", "x", "y") else "rad",
            "time": "s",
            "command": "command units (bias + relay output)",
        },
        "conventions": (
            "command and output samples share the controller tick time stamps; the command of a tick "
            "reaches the plant tau seconds later (zero-order hold); plant input = g(t) * command - bias + input_bias"
        ),
    }
    if delays is not None:
        truth["delay_realised"] = {"mean": float(delays.mean()), "std": float(delays.std())}
    return truth


def _model_truth(model: PlantModel) -> dict[str, Any]:
    """The plant flown: eq. (2)'s four parameters, or another family's name, model JSON and parameters."""
    if isinstance(model, LoopModel):
        return {"Tp": model.Tp, "Td": model.Td, "tau": model.tau, "K": model.K}
    return {"family": model.family, "model": model.to_json(),
            "parameters": {name: p.value for name, p in model.parameters.items()}}


def _test_truths(spec: FlightSpec, settings: FlightSettings, rate_true: np.ndarray, aborted: Sequence[int | None],
                 abort_limits: Sequence[float]) -> list[dict[str, Any]]:
    """The sidecar's ``tests``: each test's span, settings and, with the effects that change them,
    its effective K and describing-function equivalent Td."""
    model, eff, T = spec.model, spec.effects, settings.T
    tests = []
    for test, (k0, k1), k_abort, limit in zip(spec.tests, settings.ranges, aborted, abort_limits):
        if k_abort is not None:
            k1 = k_abort
        entry: dict[str, Any] = {
            "beta": test.beta,
            "h": test.h,
            "duration": test.duration,
            "t_start": spec.start_time + k0 * T,
            "t_end": spec.start_time + k1 * T,
            "bias": settings.bias,
            "aborted": k_abort is not None,
            "abort_error": limit,
            "noise_margin": noise_margin(model, test.beta, test.h, spec.rate_hz, settings.noise_std),
        }
        if test.eps > 0:
            entry["eps"] = test.eps
        if eff.gain_drift != 0 and "K" in model.parameters:
            t_mid = 0.5 * (k0 + k1) * T
            entry["K_effective"] = model.parameters["K"].value * (1.0 + eff.gain_drift * t_mid)
        if eff.quadratic_drag > 0:
            half = rate_true[(k0 + k1) // 2 : k1]
            v_amp = 0.5 * (half.max() - half.min()) if half.size else float("nan")
            entry["velocity_amplitude"] = v_amp
            entry["Td_equivalent"] = 3.0 * math.pi / (8.0 * eff.quadratic_drag * v_amp) if v_amp > 0 else None
        tests.append(entry)
    return tests


def quaternion_zyx(roll: np.ndarray, pitch: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Quaternion (x, y, z, w) of the ZYX Euler angles (yaw 0, pitch, roll)."""
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    return sr * cp, cr * sp, -sr * sp, cr * cp


def flight_topics(spec: FlightSpec, settings: FlightSettings, t: np.ndarray, command: np.ndarray, y_meas: np.ndarray,
                  other_noise: np.ndarray, battery_noise: np.ndarray) -> list[TopicData]:
    """The flight's topics in the reference layout: command, beta, setpoint, the output's pose or
    attitude (the other attitude axis carries only its noise) and the battery voltage.

    ``t`` are the tick times [s]; ``other_noise`` and ``battery_noise`` per tick [rad], [V].
    """
    n_ticks, T, r = settings.n_ticks, settings.T, settings.setpoint
    topics = [TopicData("/mrft/command", "std_msgs/msg/Float64", t.copy(), {"data": command.copy()})]
    starts = np.array([k0 for k0, _ in settings.ranges])
    topics.append(
        TopicData(
            "/mrft/beta",
            "std_msgs/msg/Float64",
            t[starts].copy(),
            {"data": np.array([test.beta for test in spec.tests], dtype=float)},
        )
    )
    step = max(1, int(round(spec.rate_hz / spec.setpoint_rate_hz)))
    idx = np.arange(0, n_ticks, step)
    topics.append(TopicData("/mrft/setpoint", "std_msgs/msg/Float64", t[idx].copy(), {"data": np.full(idx.size, r)}))
    topics.append(_output_topic(spec, t, y_meas, other_noise))
    step = max(1, int(round(spec.rate_hz / spec.battery_rate_hz)))
    idx = np.arange(0, n_ticks, step)
    volts = spec.effects.battery_voltage * (1.0 + spec.effects.gain_drift * idx * T) + battery_noise[idx]
    topics.append(TopicData("/battery", "sensor_msgs/msg/BatteryState", t[idx].copy(), {"voltage": volts}))
    return topics


def _output_topic(spec: FlightSpec, t: np.ndarray, y_meas: np.ndarray, other_noise: np.ndarray) -> TopicData:
    """The measured output: the motion-capture pose (position loops, m) or the IMU attitude (rad)."""
    if spec.loop in ("altitude", "x", "y"):
        # position loops: the motion-capture pose (x, y, z in m), as the reference layout reads it
        axis = {"altitude": "z", "x": "x", "y": "y"}[spec.loop]
        return TopicData(
            "/mocap/pose",
            "geometry_msgs/msg/PoseStamped",
            t.copy(),
            {f"pose.position.{axis}": y_meas.copy(), "pose.orientation.w": np.ones(t.size)},
        )
    return imu_topic(t, *((y_meas, other_noise) if spec.loop == "roll" else (other_noise, y_meas)))


def imu_topic(t: np.ndarray, roll: np.ndarray, pitch: np.ndarray) -> TopicData:
    """``/imu/data`` of the reference layout: the attitude [rad] as a quaternion (yaw 0), stamped at ``t`` [s]."""
    qx, qy, qz, qw = quaternion_zyx(roll, pitch)
    return TopicData("/imu/data", "sensor_msgs/msg/Imu", t.copy(),
                     {"orientation.x": qx, "orientation.y": qy, "orientation.z": qz, "orientation.w": qw})


def sidecar_path(log_path: str | Path) -> Path:
    """The ground-truth sidecar of a log: ``<log path>.truth.json`` (a directory bag: ``<dir>.truth.json``)."""
    p = Path(log_path)
    return p.with_name(p.name.rstrip("/") + ".truth.json")


#: formats written as a directory (a ROS 2 bag): no one-step swap of a directory for another exists
_DIRECTORY_FORMATS = ("ros2-sqlite3", "ros2-mcap")


def _is_bag(path: Path) -> bool:
    """A ROS 2 bag folder (its metadata.yaml), or a file (a file log is replaced as before)."""
    return not path.is_dir() or (path / "metadata.yaml").is_file()


def _simulated(path: Path) -> bool:
    """A log this tool simulated: its truth sidecar lies beside it (a ROS 2 bag: also its metadata.yaml)."""
    return _is_bag(path) and sidecar_path(path).is_file()


def check_log_target(path: str | Path, fmt: str, option: str = "--out") -> Path:
    """Refuse a simulated log's target that is not this tool's to replace (one-line InputError).

    An existing file or folder is replaced only if it is empty or a log ``simulate`` wrote (its
    ``.truth.json`` sidecar beside it): a user's folder, a recorded flight or a symbolic link is never
    removed or written through (:func:`mrftcli.io.atomic.check_output_path`, issue 35).
    """
    folder = fmt in _DIRECTORY_FORMATS
    return check_output_path(path, option, folder=folder, ours=_simulated,
                             what="a ROS 2 bag folder" if folder else "a log")


def write_log_atomic(topics: list[TopicData], path: str | Path, fmt: str) -> Path:
    """Write ``topics`` as a log of format ``fmt`` into a temporary file renamed onto ``path``.

    A simulation killed while it writes (a ROS 1 bag is written chunk by chunk) leaves the old file
    or none, never a cut log that reads as a shorter flight (:mod:`mrftcli.io.atomic`); a ROS 2 bag
    folder is written beside it under a hidden name and moved into place the same way.

    Returns
    -------
    Path
        ``path``.
    """
    from ..io import write_log  # the writers live with the readers

    # again at the write (a library caller): a folder that is not a ROS 2 bag is not replaced via the staging
    check_output_path(path, "log", folder=fmt in _DIRECTORY_FORMATS, ours=_is_bag, what="a ROS 2 bag folder")
    if fmt in _DIRECTORY_FORMATS:
        with atomic_directory(path) as folder:
            write_log(topics, folder, fmt)
        return Path(path)
    with atomic_path(path, create=False) as tmp:  # create=False: rosbags refuses a file that exists
        write_log(topics, tmp, fmt)
    return Path(path)


def write_sidecar(log_path: str | Path, truth: dict[str, Any]) -> Path:
    """Write ``truth`` (plain JSON values) as the log's sidecar (:func:`sidecar_path`), atomically; return its path."""
    side = sidecar_path(log_path)
    write_text_atomic(side, json.dumps(truth, indent=2, allow_nan=False) + "\n")
    return side


def write_flight(flight: SimulatedFlight, path: str | Path, fmt: str) -> Path:
    """Write ``flight`` as a log in format ``fmt`` (atomically: :func:`write_log_atomic`) plus its
    sidecar; return the sidecar path."""
    write_log_atomic(flight.topics, path, fmt)
    return write_sidecar(path, to_jsonable({**flight.truth, "log_format": fmt, "log_file": Path(path).name}))
