"""Log layouts: where the flight stacks that run MRFT put a loop's command, output, setpoint and beta.

A :class:`Layout` maps each loop (``altitude``, ``x``, ``y``, ``roll``, ``pitch``) to ``TOPIC[:FIELD]``
specs in one stack's naming, with the signs and scales the stack uses. :func:`detect_layout` recognises
a layout from a log's topic names (the evidence is returned with it); :func:`mrftcli.io.read_flight`
uses the detected (or named) layout unless ``--command-topic`` / ``--output-topic`` name the topics.
The stacks and what each records are described in ``docs/log-layout.md``.

Signs: a layout states the conventional scales (``output_scale``, ``command_scale``) that turn the
stack's frame into the loop's (PX4's NED z into altitude up, its ``thrust[2]`` into upward thrust).
The sign that matters for identification (does +h raise the output?) is measured from the data by
the segmenter whatever the layout says (``MrftTest.loop_sign``), so a wrong scale changes the
reported signs, never the identified Td and tau.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field

__all__ = ["LoopTopics", "Layout", "LAYOUTS", "LAYOUT_NAMES", "detect_layout", "get_layout", "LayoutMatch"]


@dataclass(frozen=True)
class LoopTopics:
    """Where one loop's signals are in a layout (``TOPIC[:FIELD]`` specs; None: not recorded).

    Attributes
    ----------
    command : str
        The MRFT block's output as sent to the loop (bias + relay output) [command units].
    output : str
        The loop output (a quaternion field is turned into roll/pitch).
    setpoint, beta : str or None
        The loop reference and the beta topic, when the stack records them.
    output_scale : float
        Factor from the logged output (and setpoint) to the loop's output (``-1``: NED z -> altitude).
    command_scale : float
        Factor from the logged command to the loop's command (``-1``: PX4's upward-negative thrust).
    decision : str or None
        Where the relay's decision is logged when the stack can delay ``command`` after it
        (:attr:`Layout.delay_parameter` > 0): then the decision is the command (the delay belongs inside
        the identified loop); None: ``command`` is the decision.
    """

    command: str
    output: str
    setpoint: str | None = None
    beta: str | None = None
    output_scale: float = 1.0
    command_scale: float = 1.0
    decision: str | None = None


@dataclass(frozen=True)
class Layout:
    """One flight stack's log layout.

    Attributes
    ----------
    name : str
        What ``--layout`` takes.
    title : str
        One line naming the stack.
    loops : Mapping[str, LoopTopics]
        The loops the stack runs MRFT on.
    signature : tuple of str
        Topic names (any one suffices, in the log's naming) that identify the layout.
    formats : tuple of str
        Log formats the stack writes (empty: any).
    parameters : str or None
        ``MRFT_{AXIS}_``-style prefix of the parameters holding beta, h and the enable switch
        (PX4: tests and their beta come from the logged parameter changes), None when not logged.
    timestamps : str
        ``header`` (stamped at the source) or ``receive`` (the stack's messages carry the recorder's
        arrival time in every format it writes). Bags and MCAP are read as receive-stamped whatever
        this says (their times are the recorder's: :attr:`mrftcli.io.source.LogSource.recorder_times`).
    low_rate_fix : str
        What to change in the stack's logger for high-rate logging (named in the low-rate warning).
    controller_rate_hz : float or None
        The rate [Hz] at which the stack's MRFT relay decides, when the logger may record the command
        more slowly (the segmenter then places each switch among the controller ticks between two logged
        samples); None: the command is logged at the controller's rate. With ``rate_from_log`` it is
        only the fallback for a log that does not show the rate, and is then stated as an assumption.
    rate_from_log : bool
        The relay decides once per published command (PX4: ``mc_pos_control`` publishes one
        ``vehicle_local_position_setpoint`` a cycle), so the log shows the controller's rate: the
        command's own rate when it is logged at every publication, else the tick its sub-sampled stamps
        are multiples of (:func:`mrftcli.io.timing.logged_tick_s`).
    rate_assumption : str
        Why ``controller_rate_hz`` is the fallback (said in the warning and in ``input.source``).
    delay_parameter : str or None
        The logged parameter [ms] by which the stack holds the relay's output before it acts (PX4's
        ``MRFT_DELAY``); above 0, a loop with a :attr:`LoopTopics.decision` reads the decision.
    loop_field : str or None
        ``TOPIC:FIELD`` where a one-axis log records which loop its tests excite (ArduPilot's
        ``MRFB:Ax``), decoded by :attr:`loop_codes`; None when the log does not say.
    loop_codes : Mapping[int, str]
        The loop each value of :attr:`loop_field` stands for.
    """

    name: str
    title: str
    loops: Mapping[str, LoopTopics]
    signature: tuple[str, ...]
    formats: tuple[str, ...] = ()
    parameters: str | None = None
    timestamps: str = "header"
    low_rate_fix: str = "record the command and the output at the controller's rate"
    controller_rate_hz: float | None = None
    rate_from_log: bool = False
    rate_assumption: str = ""
    delay_parameter: str | None = None
    loop_field: str | None = None
    loop_codes: Mapping[int, str] = field(default_factory=dict)


def _reference(output: str) -> LoopTopics:
    """A loop of the reference layout: the MRFT block's own topics, and the loop's output."""
    return LoopTopics("/mrft/command:data", output, "/mrft/setpoint:data", "/mrft/beta:data")


_REFERENCE = Layout(
    name="reference",
    title="mrft-ident's reference layout (/mrft/command, /mrft/beta, /mocap/pose, /imu/data)",
    loops={
        "altitude": _reference("/mocap/pose:pose.position.z"),
        "x": _reference("/mocap/pose:pose.position.x"),
        "y": _reference("/mocap/pose:pose.position.y"),
        "roll": _reference("/imu/data:orientation"),
        "pitch": _reference("/imu/data:orientation"),
    },
    signature=("/mrft/command",),
)

# PX4 with the MRFT position-controller patch (PositionMRFT in mc_pos_control): NED, normalised thrust.
_PX4 = Layout(
    name="px4-mrft",
    title="PX4 with the MRFT position-controller patch (ULog: vehicle_local_position[_setpoint])",
    loops={
        "altitude": LoopTopics("vehicle_local_position_setpoint:thrust[2]", "vehicle_local_position:z",
                               "vehicle_local_position_setpoint:z", None, output_scale=-1.0,
                               command_scale=-1.0),
        "x": LoopTopics("vehicle_local_position_setpoint:thrust[0]", "vehicle_local_position:x",
                        "vehicle_local_position_setpoint:x"),
        "y": LoopTopics("vehicle_local_position_setpoint:thrust[1]", "vehicle_local_position:y",
                        "vehicle_local_position_setpoint:y"),
        # mrft-ident's roll relay in mc_rate_control (scripts/sitl/px4/mrft_roll.patch; the fork has none):
        # the relay is the roll (pitch) torque setpoint, the output the attitude's roll (pitch) (setpoint: level);
        # with MRFT_DELAY > 0 the torque is the decision held that long, and the decision is in debug_vect
        "roll": LoopTopics("vehicle_torque_setpoint:xyz[0]", "vehicle_attitude:q", decision="debug_vect:x"),
        "pitch": LoopTopics("vehicle_torque_setpoint:xyz[1]", "vehicle_attitude:q", decision="debug_vect:y"),
    },
    signature=("vehicle_local_position_setpoint",),
    formats=("ulog",),
    parameters="MRFT_{axis}_",
    low_rate_fix="set SDLOG_PROFILE to high rate (or list vehicle_local_position and "
                 "vehicle_local_position_setpoint at 0 ms in etc/logging/logger_topics.txt)",
    # mc_pos_control decides once per vehicle_local_position it gets and publishes one setpoint a cycle:
    # 50 Hz in the fork's PX4 v1.11 (set_interval_us(20_ms)), EKF2's output rate from PX4 1.12 on
    # (125 Hz in SIH). Read from the log; 50 Hz only when the log cannot show it (a 10 Hz log whose
    # intervals are all one multiple of the tick), stated as an assumption (--controller-rate overrides)
    controller_rate_hz=50.0,
    rate_from_log=True,
    rate_assumption="the fork's PX4 v1.11 runs mc_pos_control at 50 Hz (set_interval_us(20_ms)); PX4 1.12 "
                    "and later run it at EKF2's output rate (vehicle_local_position's, e.g. 100-250 Hz)",
    # the port's MRFT_DELAY [ms]: the position relays log their decision (thrust, before the delay), the
    # rate relays of mrft_roll.patch their delayed torque (the decision in debug_vect)
    delay_parameter="MRFT_DELAY",
)

# HEAR flight controller, ROS 1 (geometry_msgs/Point has no header: receive time).
_HEAR = Layout(
    name="hear-ros",
    title="HEAR flight controller, ROS 1 (/fh_des, /angle_u, /opti/pos, /opti/ori)",
    loops={
        "altitude": LoopTopics("/fh_des:z", "/opti/pos:z", "/waypoint_reference/pos:z"),
        "x": LoopTopics("/fh_des:x", "/opti/pos:x", "/waypoint_reference/pos:x"),
        "y": LoopTopics("/fh_des:y", "/opti/pos:y", "/waypoint_reference/pos:y"),
        "roll": LoopTopics("/angle_u:x", "/opti/ori:x", "/angle_ref:x"),
        "pitch": LoopTopics("/angle_u:y", "/opti/ori:y", "/angle_ref:y"),
    },
    signature=("/fh_des", "/angle_u"),
    formats=("bag", "ros2-sqlite3", "ros2-mcap", "mcap"),
    timestamps="receive",
    low_rate_fix="record /fh_des, /angle_u and /opti/* unthrottled (rosbag record -a)",
)

#: the loops in the order of the 2020 HEAR controller's and the MATLAB export's controller outputs
#: (index i), with the name of each loop's output there
OUTPUT_ORDER = (("x", "x"), ("y", "y"), ("altitude", "z"), ("roll", "roll"), ("pitch", "pitch"))

# The older (2020) HEAR controller: every axis in one Float64MultiArray, outputs in /providers/*.
_HEAR_2020 = Layout(
    name="hear-2020",
    title="HEAR controller of 2020, ROS 1 (/control_system_output multi-array, /providers/*)",
    loops={loop: LoopTopics(f"/control_system_output:data[{i}]", f"/providers/{name}:x")
           for i, (loop, name) in enumerate(OUTPUT_ORDER)},
    signature=("/control_system_output",),
    formats=("bag", "ros2-sqlite3", "ros2-mcap", "mcap"),
    timestamps="receive",
    low_rate_fix="record /control_system_output and /providers/* unthrottled",
)

# What a MAVROS user records: ENU local pose, the attitude target's thrust as the altitude command.
_MAVROS = Layout(
    name="mavros",
    title="MAVROS (ROS): /mavros/local_position/pose, /mavros/setpoint_raw/attitude",
    loops={
        "altitude": LoopTopics("/mavros/setpoint_raw/attitude:thrust", "/mavros/local_position/pose:pose.position.z"),
        "roll": LoopTopics("/mavros/setpoint_raw/attitude:body_rate.x", "/mavros/imu/data:orientation"),
        "pitch": LoopTopics("/mavros/setpoint_raw/attitude:body_rate.y", "/mavros/imu/data:orientation"),
    },
    signature=("/mavros/setpoint_raw/attitude", "/mavros/setpoint_raw/target_attitude",
               "/mavros/local_position/pose"),
    formats=("bag", "ros2-sqlite3", "ros2-mcap", "mcap"),
    timestamps="header",
    low_rate_fix="raise the MAVLink stream rates (mavros set_stream_rate, or SR*/MAV_*_RATE) for "
                 "LOCAL_POSITION_NED and ATTITUDE_TARGET",
)

# DNN-MRFT-style MATLAB exports: one vector per signal, its times in <name>_t.
_MAT = Layout(
    name="mat",
    title="MATLAB .mat export (controller_output_<i> and <name>_t time vectors)",
    loops={loop: LoopTopics(f"controller_output_{i}", name) for i, (loop, name) in enumerate(OUTPUT_ORDER)},
    signature=tuple(f"controller_output_{i}" for i in range(len(OUTPUT_ORDER))),
    formats=("mat",),
    low_rate_fix="log the controller output and the output at the controller's rate",
)

# ArduCopter with mrft-ident's relay (a main-loop task, scripts/sitl/ardupilot_patch, started by
# scripts/sitl/mrft_relay.lua): one DataFlash message MRFT per main-loop tick (or per script tick without
# the patch) holding the relay's decision (bias + relay, before the delay line) and the EKF's output
# (altitude [m] or roll/pitch [rad]); one MRFB message at each test's start holds its beta (a beta
# logged every tick would cut the relay's runs at every sample). One axis per log.
def _ardupilot_mrft() -> LoopTopics:
    return LoopTopics("MRFT:Cmd", "MRFT:Out", "MRFT:SP", "MRFB:B")


_ARDUPILOT_MRFT = Layout(
    name="ardupilot-mrft",
    title="ArduCopter with mrft-ident's MRFT relay (DataFlash message MRFT)",
    loops={loop: _ardupilot_mrft() for loop in ("altitude", "roll", "pitch")},
    signature=("MRFT",),
    formats=("dataflash",),
    loop_field="MRFB:Ax",  # scripts/sitl/mrft_relay.lua: 1 altitude, 2 roll, 3 pitch
    loop_codes={1: "altitude", 2: "roll", 3: "pitch"},
    low_rate_fix="the relay logs every tick: build with scripts/sitl/build_ardupilot.sh (the main-loop relay, "
                 "400 Hz) instead of the script-run relay",
)

#: every layout by name (``--layout NAME``)
LAYOUTS: dict[str, Layout] = {lay.name: lay for lay in (_REFERENCE, _PX4, _HEAR, _HEAR_2020, _MAVROS, _MAT,
                                                        _ARDUPILOT_MRFT)}
#: what ``--layout`` accepts
LAYOUT_NAMES = tuple(LAYOUTS)


@dataclass(frozen=True)
class LayoutMatch:
    """The layout a log was read with and why.

    Attributes
    ----------
    layout : Layout
    detected : bool
        True when recognised from the topics, False when named by the user.
    evidence : str
        What decided it (the topics found, or ``--layout``).
    """

    layout: Layout
    detected: bool
    evidence: str

    def describe(self) -> str:
        """``px4-mrft (auto-detected: vehicle_local_position_setpoint)`` or ``hear-ros (--layout)``."""
        how = f"auto-detected: {self.evidence}" if self.detected else self.evidence
        return f"{self.layout.name} ({how})"


def get_layout(name: str) -> Layout:
    """The layout called ``name``; InputError naming the choices otherwise."""
    from ..errors import InputError

    if name not in LAYOUTS:
        raise InputError(f"unknown layout {name!r}; choose one of {', '.join(LAYOUT_NAMES)}")
    return LAYOUTS[name]


def detect_layout(topics: Collection[str] | Callable[[str], bool], fmt: str | None = None) -> LayoutMatch | None:
    """Recognise a layout from a log's topic names (and format).

    ``topics`` is the log's topic names, or a predicate saying whether the log has a topic (a reader's
    ``resolve_topic``, which knows its format's naming: ULog ``mrft_command``, CSV column prefixes).

    The most specific layouts are tried first (a PX4 ULog also holds ``vehicle_attitude``; a HEAR bag
    may carry reference-named topics from a bridge): the first layout with a signature topic in the
    log and a compatible format wins. None when no layout's signature is present.

    Examples
    --------
    >>> detect_layout(["/fh_des", "/opti/pos", "/angle_u"], "bag").describe()
    'hear-ros (auto-detected: /fh_des, /angle_u)'
    >>> detect_layout(["/mrft/command", "/mocap/pose"], "mcap").layout.name
    'reference'
    >>> detect_layout(["/tf"], "bag") is None
    True
    """
    has = topics if callable(topics) else set(topics).__contains__
    for name in ("px4-mrft", "ardupilot-mrft", "hear-2020", "hear-ros", "mavros", "mat", "reference"):
        lay = LAYOUTS[name]
        if lay.formats and fmt is not None and fmt not in lay.formats and not (
                fmt == "mcap-json" and "mcap" in lay.formats):
            continue
        found = [s for s in lay.signature if has(s)]
        if found:
            return LayoutMatch(lay, True, ", ".join(found[:3]))
    return None
