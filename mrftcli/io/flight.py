"""One loop's :class:`~mrftcli.io.logtypes.FlightLog` from an open log, in stages.

:func:`read_loop` resolves where each role (command, output, beta, setpoint, battery) is
read from (:func:`role_specs`: the layout, then the ``TOPIC[:FIELD]`` options), reads the command and
the output (a quaternion output becomes roll or pitch), the optional roles, the PX4 test windows from
the logged parameters, records the timing (:class:`~mrftcli.io.timing.Timing`), leaves out
non-finite samples and warns about a command logged too slowly for the MRFT. The same function
serves a finished file (:func:`mrftcli.io.read_flight`) and one still being written
(:mod:`mrftcli.io.follow`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError, LogReadError, OtherLoopError
from ..validate import check_positive
from .attitude import roll_pitch
from .clock import check_rate, check_time_unit
from .layouts import LAYOUTS, Layout, LayoutMatch, LoopTopics, detect_layout, get_layout
from .logtypes import LOOPS, PROCESS_LOOP, FlightLog, Signal
from .source import LogSource, TopicSpec, parse_spec
from .timing import Timing, logged_tick_s, median_rate_hz, receive_jitter_s

__all__ = ["ReadOptions", "RoleSpecs", "DEFAULT_TOPICS", "ABSURD_MAGNITUDE", "read_loop", "log_layout", "role_specs",
           "layout_loop"]

#: the reference layout (ROS 2 names, :data:`LAYOUTS` ``["reference"]``) by role, see docs/log-layout.md
DEFAULT_TOPICS = {
    "command": LAYOUTS["reference"].loops["altitude"].command,
    "beta": LAYOUTS["reference"].loops["altitude"].beta,
    "setpoint": LAYOUTS["reference"].loops["altitude"].setpoint,
    **{f"output.{loop}": topics.output for loop, topics in LAYOUTS["reference"].loops.items()},
    "battery": "/battery:voltage",
}

#: PX4 MRFT axis of each loop (parameters MRFT_<AXIS>_BETA, _H, _ENABLE)
_PX4_AXIS = {"x": "X", "y": "Y", "altitude": "Z", "roll": "R", "pitch": "P"}
#: a command or output sample beyond this magnitude is corrupt (its square overflows float64 in fits)
ABSURD_MAGNITUDE = 1e100
#: below this command rate [Hz] an MRFT cycle of 1-2 Hz has fewer than ~10 samples
_LOW_RATE_HZ = 25.0


@dataclass(frozen=True)
class ReadOptions:
    """How to read one loop: the options of :func:`mrftcli.io.read_flight`, checked on creation.

    Attributes
    ----------
    loop : str
        One of :data:`~mrftcli.io.logtypes.LOOPS`, or a process plant's
        :data:`~mrftcli.io.logtypes.PROCESS_LOOP` (read as the layouts' altitude loop: :func:`layout_loop`).
    command_topic, output_topic, beta_topic, setpoint_topic, battery_topic : str or None
        ``TOPIC[:FIELD]`` overriding the layout.
    output_scale, command_scale : float or None
        Factors on the output (and setpoint) and on the command; None: the layout's.
    layout : str or None
        A layout name; None: recognised from the topics.
    controller_rate_hz : float or None
        Rate [Hz] at which the relay decided; None: the layout's.
    fmt : str or None
        Log format (one of :data:`mrftcli.io.READ_FORMATS`); None: detected when the file is opened.
        Used where a file is opened (:func:`mrftcli.io.read_flight`, :func:`mrftcli.watch.watch`);
        :func:`read_loop` reads a log that is open already.
    time_unit : {"s", "ms", "us", "ns"} or None
        Unit of a CSV's time column or a ``.mat`` file's time vectors; None: the column's name says,
        else seconds (:func:`mrftcli.io.open_log`). Used where a file is opened, as ``fmt``.
    any_time_scale : bool
        A process plant's loop (``--model NAME``, ``--model-file``): any sample rate is plausible (a
        10 kHz plasma loop, a furnace logged once a minute), so the command's rate is not checked
        against what flight stacks log (:func:`~mrftcli.io.clock.check_rate`: eq. (2)'s vehicle loops
        only). ``time_unit`` still converts a log written in other units.

    Raises
    ------
    InputError
        Unknown loop or time unit, a zero or non-finite scale, a non-positive controller rate.

    Examples
    --------
    >>> ReadOptions(loop="roll", output_scale=0.0174533).layout is None
    True
    >>> ReadOptions(loop="yaw")
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: unknown loop 'yaw'; choose one of altitude, roll, pitch, x, y
    """

    loop: str = "altitude"
    command_topic: str | None = None
    output_topic: str | None = None
    beta_topic: str | None = None
    setpoint_topic: str | None = None
    battery_topic: str | None = None
    output_scale: float | None = None
    layout: str | None = None
    command_scale: float | None = None
    controller_rate_hz: float | None = None
    fmt: str | None = None
    time_unit: str | None = None
    any_time_scale: bool = False

    def __post_init__(self) -> None:
        if self.loop not in LOOPS and self.loop != PROCESS_LOOP:
            raise InputError(f"unknown loop {self.loop!r}; choose one of {', '.join(LOOPS)}")
        if self.controller_rate_hz is not None:
            object.__setattr__(self, "controller_rate_hz",
                               check_positive("controller rate [Hz]", self.controller_rate_hz))
        for name, value in (("output", self.output_scale), ("command", self.command_scale)):
            if value is not None and not (np.isfinite(value) and value != 0.0):
                raise InputError(f"{name} scale must be a finite non-zero number, got {value}")
        check_time_unit(self.time_unit)


@dataclass(frozen=True)
class RoleSpecs:
    """Where each role is read from and with which factor, the layout and the options combined.

    Attributes
    ----------
    command, output : str
        ``TOPIC[:FIELD]`` of the command and the output.
    beta, setpoint, battery : str or None
        ``TOPIC[:FIELD]`` of the optional roles (None: not read).
    output_scale, command_scale : float
        Factors on the output (and setpoint) and on the command.
    """

    command: str
    output: str
    beta: str | None
    setpoint: str | None
    battery: str | None
    output_scale: float
    command_scale: float


@dataclass(frozen=True)
class _Read:
    """One role as read: times [s], the leaf names and their values, and the resolved spec."""

    t: np.ndarray
    leaves: list[str]
    values: dict[str, np.ndarray]
    spec: TopicSpec


def log_layout(log: LogSource, layout: str | None = None) -> LayoutMatch:
    """The layout to read ``log`` with: ``layout`` when named, else the one its topics show.

    A log that matches no known layout is read with the reference layout (its topic options then
    name what is missing); the match says so in its evidence.
    """
    if layout is not None:
        return LayoutMatch(get_layout(layout), False, "--layout")
    found = detect_layout(lambda name: log.resolve_topic(name) is not None, log.format)
    if found is not None:
        return found
    return LayoutMatch(LAYOUTS["reference"], False, "default: no known layout's topics in the log")


def layout_loop(loop: str) -> str:
    """The layouts' loop a loop is read as: a process plant's (:data:`~mrftcli.io.logtypes.PROCESS_LOOP`) as
    altitude (the reference layout's one output when its topics are not named), a vehicle's as itself."""
    return "altitude" if loop == PROCESS_LOOP else loop


def role_specs(lay: Layout, opts: ReadOptions) -> RoleSpecs:
    """The specs and factors of each role: the options where given, else the layout's.

    Raises
    ------
    InputError
        The layout has no such loop and the options do not name both the command and the output.
    """
    lt: LoopTopics | None = lay.loops.get(layout_loop(opts.loop))
    command, output = opts.command_topic, opts.output_topic
    if lt is None:
        if command is None or output is None:
            raise InputError(f"layout {lay.name} has no {opts.loop} loop (its loops: {', '.join(lay.loops)}); "
                             "name the topics with --command-topic and --output-topic")
    else:
        command, output = command or lt.command, output or lt.output
    output_scale = opts.output_scale
    if output_scale is None:
        output_scale = lt.output_scale if lt is not None and opts.output_topic is None else 1.0
    command_scale = opts.command_scale
    if command_scale is None:
        command_scale = lt.command_scale if lt is not None and opts.command_topic is None else 1.0
    return RoleSpecs(
        command=command, output=output,
        beta=opts.beta_topic or (lt.beta if lt is not None else None),
        setpoint=opts.setpoint_topic or (lt.setpoint if lt is not None else None),
        battery=opts.battery_topic or (DEFAULT_TOPICS["battery"] if lay.name == "reference" else None),
        output_scale=output_scale, command_scale=command_scale)


def read_loop(log: LogSource, opts: ReadOptions, *, loop_hint: bool = False) -> FlightLog:
    """The signals of one loop from an open :class:`LogSource` (what :func:`mrftcli.io.read_flight` does
    after opening), the stages in order.

    The topic logic (layout, ``TOPIC[:FIELD]`` specs, quaternion -> roll/pitch, scales, optional
    topics, PX4 test windows) lives here once, for readers of a whole file (:func:`mrftcli.io.read_flight`)
    and of a file that is still being written (:mod:`mrftcli.io.follow`). Errors are
    :func:`mrftcli.io.read_flight`'s; ``opts.fmt`` and ``opts.time_unit`` are not used (the log is open);
    the reader's warnings are added to ``log.warnings`` (and copied into ``FlightLog.warnings``);
    ``FlightLog.path`` is ``log.path``. ``loop_hint``: the layout's output missing (no ``--output-topic``)
    says to give ``--loop`` or ``--output-topic`` (a one-loop command; ``vehicle`` reads every loop).
    """
    label = opts.loop  # the record's loop; a process plant's is read as the layouts' altitude loop
    opts = dataclasses.replace(opts, loop=layout_loop(opts.loop))
    match = log_layout(log, opts.layout)
    _check_logged_loop(log, match.layout, opts)
    roles, decision = _decision_command(log, match.layout, opts, role_specs(match.layout, opts))
    log.prefetch([parse_spec(s).topic for s in (roles.command, roles.output, roles.beta, roles.setpoint,
                                                roles.battery) if s])
    hint = loop_hint and opts.command_topic is None  # the user's own topic: the reader's message names it
    cmd = _get_layout_role(log, roles.command, hint, f"the {match.layout.name} layout's command for the {opts.loop} "
                           "loop: name the log's own with --command-topic, and its output with --output-topic")
    if not opts.any_time_scale:  # eq. (2)'s vehicle loops: a rate no flight stack logs is a wrong unit
        check_rate(cmd.t, f"{log.path}: the command {cmd.spec}", log.time_unit, log.time_unit_settable)
    # the layout's output for this loop: the usual slip is a log of another loop (--loop defaults to altitude)
    out = _get_layout_role(log, roles.output, loop_hint and opts.output_topic is None,
                           f"the {opts.loop} loop's output in the {match.layout.name} layout: for another loop give "
                           "--loop, for another topic --output-topic")
    source: dict[str, Any] = {"format": log.format, "layout": match.describe()}
    output, conversion = _output_signal(log, out, opts.loop, roles.output_scale)
    if conversion is not None:
        source["output_conversion"] = conversion
    source["command"] = _where(cmd.spec.topic, cmd.leaves[0])
    if decision is not None:
        source["command_choice"] = decision
    source["output"] = str(out.spec) if conversion is not None else _where(out.spec.topic, out.leaves[0])
    command = _command_signal(log, cmd, roles.command_scale)
    optional = _optional_signals(log, opts, roles, source)
    if optional["beta"] is None and opts.beta_topic is None and match.layout.parameters:
        optional["beta"] = _parameter_beta(log, match.layout.parameters, opts.loop, source)
    if roles.output_scale != 1.0:
        source["output_scale"] = roles.output_scale
    if roles.command_scale != 1.0:
        source["command_scale"] = roles.command_scale
    optional["beta"] = _finite_beta(log, optional["beta"], source.get("beta", ""))
    timing = _timing(log, match.layout, opts, command, output)  # the stamps as logged, before _finite
    if opts.controller_rate_hz is None and match.layout.rate_from_log:
        rate, source["controller_rate"], assumed = _rate_from_log(log, match.layout, command)
        timing = dataclasses.replace(timing, controller_rate_hz=rate, controller_rate_assumed=assumed)
    command = _finite(log, _bounded(log, command, "command", source["command"]), "command", source["command"])
    output = _finite(log, _bounded(log, output, "output", source["output"]), "output", source["output"])
    output = _fresh(log, output, source["output"])
    if match.layout.name != "reference" and not opts.any_time_scale:
        _warn_low_rate(log, command, match.layout)
    return FlightLog(path=str(log.path), loop=label, command=command, output=output,
                     beta=optional["beta"], setpoint=optional["setpoint"],
                     battery_voltage=optional["battery_voltage"], source=source,
                     warnings=tuple(log.warnings), timing=timing)


# -- the stages ---------------------------------------------------------------------------------
def _get_required(log: LogSource, spec: str) -> _Read:
    """One role the flight cannot do without; LogReadError (listing the topics) when absent."""
    ts = parse_spec(spec)
    topic = log.resolve_topic(ts.topic)
    if topic is None:
        raise log.missing_topic(ts.topic)
    return _read(log, topic, ts.field)


def _get_layout_role(log: LogSource, spec: str, hint: bool, fix: str) -> _Read:
    """:func:`_get_required` for a role the layout named: when ``hint``, its error ends with ``fix``
    (which option to give), in brackets."""
    try:
        return _get_required(log, spec)
    except LogReadError as err:
        if not hint:
            raise
        raise LogReadError(f"{err} ({fix})") from None


def _check_logged_loop(log: LogSource, lay: Layout, opts: ReadOptions) -> None:
    """OtherLoopError (exit 4: no test on the loop asked) when the log says its tests excite another loop than
    ``opts.loop``; InputError when it says they excite two (a one-axis layout cannot tell them apart).

    A one-axis layout (:attr:`Layout.loop_field`) maps every loop to the same topics, so without this a
    roll log read as the default altitude loop would be identified with altitude's units. Skipped when
    the user names the output topic (the topics are then theirs). A layout whose tests are started by a
    parameter per loop (:attr:`Layout.parameters`: PX4's ``MRFT_<AXIS>_ENABLE``) says so too: a y log read
    as the default altitude loop found no relay in altitude's command and named --command-topic.
    """
    if opts.output_topic is not None:
        return
    if lay.parameters is not None and opts.command_topic is None:
        switched_on = {n for _, n, v in log.parameters()[1] if v >= 0.5}
        names = {loop: f"{lay.parameters.format(axis=axis)}ENABLE" for loop, axis in _PX4_AXIS.items()}
        enabled = sorted(loop for loop, name in names.items() if name in switched_on)
        if enabled and opts.loop not in enabled:
            raise OtherLoopError(f"{log.path}: the log's tests excite the {' and '.join(enabled)} loop "
                                 f"({', '.join(names[k] for k in enabled)}), not {opts.loop}: give --loop {enabled[0]}")
    if lay.loop_field is None:
        return
    read = _get_optional(log, lay.loop_field)
    if read is None:
        return
    codes = {int(v) for v in np.concatenate([np.ravel(x) for x in read.values.values()]) if np.isfinite(v)}
    logged = sorted({lay.loop_codes.get(c, f"code {c}") for c in codes})
    if len(logged) > 1:  # every loop reads the same topics: the other axis's tests would pass as this one's
        raise InputError(f"{log.path}: the log's tests excite the {' and '.join(logged)} loops ({lay.loop_field}); "
                         f"the {lay.name} layout reads one loop per log: fly each axis into its own log")
    if logged and opts.loop not in logged:
        raise OtherLoopError(f"{log.path}: the log's tests excite the {logged[0]} loop ({lay.loop_field}), "
                             f"not {opts.loop}: give --loop {logged[0]}")


def _get_optional(log: LogSource, spec: str) -> _Read | None:
    """One optional role, None when its topic is absent."""
    ts = parse_spec(spec)
    topic = log.resolve_topic(ts.topic)
    return None if topic is None else _read(log, topic, ts.field)


def _read(log: LogSource, topic: str, field: str | None) -> _Read:
    t, leaves, vals = log.values(topic, field)
    return _Read(t, leaves, vals, TopicSpec(topic, field))


def _where(topic: str, leaf: str) -> str:
    """``topic:leaf`` for FlightLog.source (CSV leaves are whole column names already)."""
    return leaf if leaf.startswith(topic) else f"{topic}:{leaf}"


def _decision_command(log: LogSource, lay: Layout, opts: ReadOptions, roles: RoleSpecs) -> tuple[RoleSpecs, str | None]:
    """``roles`` with the relay's decision as the command when the log says the stack holds the layout's
    command after it (:attr:`Layout.delay_parameter` > 0 at the start or in a change, and the loop has a
    :attr:`LoopTopics.decision`), and why (``source["command_choice"]``, analyze's first lines).

    The held command hides the delay from tau (PX4's rate relays with ``MRFT_DELAY`` 20 ms: the torque read
    tau 0.1 ms and |beta| 0.14-0.46 for 0.3-0.7; the decision 20.2 ms). ``--command-topic`` is used as given.

    Raises
    ------
    LogReadError
        The delay is set and the decision is not logged (one line naming ``--command-topic``).
    """
    lt = lay.loops.get(opts.loop)
    name = lay.delay_parameter
    if opts.command_topic is not None or lt is None or lt.decision is None or name is None:
        return roles, None
    initial, changes = log.parameters()
    values = ([initial[name]] if name in initial else []) + [v for _, k, v in changes if k == name]
    delay = max(values, default=0.0)
    if not delay > 0:
        return roles, None
    spec = parse_spec(lt.decision)
    topic = log.resolve_topic(spec.topic)
    try:
        if topic is None:
            raise log.missing_topic(spec.topic)
        log.leaves(topic, spec.field)
    except LogReadError:
        raise LogReadError(f"{log.path}: {name} is {delay:g} ms in the log's parameters, so {lt.command} is the relay's "
                           f"output held {delay:g} ms after its decision, and the decision ({lt.decision}) is not in the "
                           "log: name the relay's decision with --command-topic TOPIC:FIELD") from None
    why = (f"{lt.decision}, the relay's decision: the log's {name} {delay:g} ms holds {lt.command} that long after "
           "it, so the delay is inside the identified loop (--command-topic overrides)")
    return dataclasses.replace(roles, command=lt.decision), why


def _output_signal(log: LogSource, out: _Read, loop: str, scale: float) -> tuple[Signal, str | None]:
    """The loop output times ``scale``, and the conversion made (roll or pitch from a quaternion)."""
    if len(out.leaves) == 4:
        if loop not in ("roll", "pitch"):
            raise LogReadError(f"{log.path}: output {out.spec} is an orientation quaternion; "
                               f"for --loop {loop} name a position field")
        try:
            roll, pitch = roll_pitch(*(out.values[k] for k in out.leaves))
        except LogReadError as err:
            raise LogReadError(f"{log.path}: {out.spec}: {err}") from None
        y = roll if loop == "roll" else pitch
        return Signal(out.t, y * scale), f"quaternion -> {loop} (ZYX), rad"
    return Signal(out.t, out.values[out.leaves[0]] * scale), None


def _command_signal(log: LogSource, cmd: _Read, scale: float) -> Signal:
    """The relay command times ``scale`` (one number, never a quaternion)."""
    if len(cmd.leaves) != 1:
        raise LogReadError(f"{log.path}: command {cmd.spec} is a quaternion; name one number")
    return Signal(cmd.t, cmd.values[cmd.leaves[0]] * scale)


def _optional_signals(log: LogSource, opts: ReadOptions, roles: RoleSpecs,
                      source: dict[str, Any]) -> dict[str, Signal | None]:
    """beta, setpoint and battery voltage where the options or the layout name them.

    An optional topic the user named must exist and fit; a layout's may be absent or be something
    else under the same name (then it is skipped with a warning).
    """
    optional: dict[str, Signal | None] = {}
    for role, option, spec, scale in (
            ("beta", opts.beta_topic, roles.beta, 1.0),
            ("setpoint", opts.setpoint_topic, roles.setpoint, roles.output_scale),
            ("battery_voltage", opts.battery_topic, roles.battery, 1.0)):
        optional[role] = None
        if spec is None:
            continue
        try:
            got = _get_required(log, spec) if option is not None else _get_optional(log, spec)
        except LogReadError as err:
            if option is not None:
                raise
            log.warn(f"ignored {spec} as {role}: {err}")
            got = None
        if got is None:
            continue
        if len(got.leaves) != 1:
            raise LogReadError(f"{log.path}: {role} {got.spec} is a quaternion; name one number")
        optional[role] = Signal(got.t, got.values[got.leaves[0]] * scale)
        source[role] = _where(got.spec.topic, got.leaves[0])
    return optional


def _parameter_beta(log: LogSource, prefix: str, loop: str, source: dict[str, Any]) -> Signal | None:
    """beta from the logged parameter changes (PX4 MRFT patch), the test windows into ``source``."""
    beta_sig, windows, where = _parameter_tests(log, prefix, loop)
    if beta_sig is not None:
        source["beta"] = where
        source["test_windows"] = [[a, b if np.isfinite(b) else None] for a, b in windows]
    return beta_sig


def _parameter_tests(log: LogSource, prefix: str, loop: str) -> tuple[Signal | None, list[tuple[float, float]], str]:
    """beta at each test start and the test windows from the parameter changes (PX4 MRFT patch).

    A test starts when ``<prefix>ENABLE`` is set to 1 and stops when it is set to 0; its beta is the
    ``<prefix>BETA`` in force at the start (changes stamped at the same instant count as before).
    """
    axis = _PX4_AXIS.get(loop)
    if axis is None:
        return None, [], ""
    pre = prefix.format(axis=axis)
    initial, changes = log.parameters()
    enable, beta = f"{pre}ENABLE", f"{pre}BETA"
    beta_now = initial.get(beta, -0.73)  # the patch's default
    state = initial.get(enable, 0.0)
    starts: list[tuple[float, float]] = []
    windows: list[tuple[float, float]] = []
    for t, name, value in sorted(changes, key=lambda c: c[0]):
        if name == beta:
            beta_now = value
            if starts and starts[-1][0] == t:  # set together with ENABLE: this is the test's beta
                starts[-1] = (t, value)
        elif name == enable:
            if value >= 0.5 and state < 0.5:
                starts.append((t, beta_now))
            elif value < 0.5 and state >= 0.5 and starts:
                windows.append((starts[-1][0], t))
            state = value
    if not starts:
        return None, [], ""
    if state >= 0.5:
        windows.append((starts[-1][0], float("inf")))
    sig = Signal(np.array([s[0] for s in starts]), np.array([s[1] for s in starts]))
    return sig, windows, f"parameter {beta} when {enable} is set to 1"


def _timing(log: LogSource, lay: Layout, opts: ReadOptions, command: Signal, output: Signal) -> Timing:
    """The controller's rate (option, else layout) and the stamps: receive stamps carry jitter.

    One rule for every format: times the reader takes from the recorder (bags, MCAP: see
    :attr:`~mrftcli.io.source.LogSource.recorder_times`) are receive times, whatever the layout
    says of the stack's messages (a header-less ``std_msgs/Float64`` command holds nothing else).
    """
    rate = opts.controller_rate_hz or lay.controller_rate_hz
    if lay.timestamps == "receive" or log.recorder_times:
        # the recorder's arrival times carry the transport's jitter (and its dropped messages)
        jitter = max(receive_jitter_s(command.t), receive_jitter_s(output.t))
        return Timing(controller_rate_hz=rate, stamps="receive", timing_jitter_s=jitter)
    return Timing(controller_rate_hz=rate)


def _rate_from_log(log: LogSource, lay: Layout, command: Signal) -> tuple[float, str, bool]:
    """The relay's rate [Hz] as the log shows it (``Layout.rate_from_log``), how it was found
    (``"125 Hz from the log: ..."``, ``input.source.controller_rate``) and whether it is the layout's assumption.

    The command's own rate when it is logged at every publication (the relay publishes it once a
    decision), else the tick its sub-sampled stamps are multiples of; when neither shows, the layout's
    rate, said as an assumption in a warning (and in ``input.source``).
    """
    rate = median_rate_hz(command.t)
    if rate is not None and rate >= _LOW_RATE_HZ:
        rate = float(f"{rate:.6g}")  # 125 Hz, not 125.00000000007 (the float stamps' rounding)
        return rate, f"{rate:.6g} Hz from the log: the command's rate (one message per controller cycle)", False
    tick = logged_tick_s(command.t)
    if tick is not None:
        return 1.0 / tick, (f"{1.0 / tick:.6g} Hz from the log: the sub-sampled command's intervals are "
                            f"multiples of {tick * 1e3:.4g} ms"), False
    if lay.controller_rate_hz is None:  # before the warning: no "0 Hz assumed" line above the error
        raise InputError("the controller's rate is not in the log: give --controller-rate (Hz)")
    assumed = f"{lay.controller_rate_hz:g} Hz assumed"
    log.warn(f"controller rate {assumed}: the command is logged at {rate or 0:.3g} Hz and its intervals do not "
             f"show the controller's tick; {lay.rate_assumption}. Give --controller-rate (Hz) if yours differs "
             "(a command logged at every publication shows it)")
    return lay.controller_rate_hz, f"{assumed}: {lay.rate_assumption}", True


def _finite_beta(log: LogSource, beta: Signal | None, where: str) -> Signal | None:
    """``beta`` without NaN / infinite values (a parameter set to NaN) or values outside (-1, 1), said in a
    warning.

    A beta that is not a number, or not a relay's (a scaled or another topic), says nothing about the test
    it was published for: that test is read as one with no beta logged (its effective beta from the
    switching levels, as the segmenter does for any test without a beta message), never with that rule.
    """
    if beta is None:
        return None
    nan = ~np.isfinite(beta.values)
    outside = ~nan & (np.abs(np.where(nan, 0.0, beta.values)) >= 1.0)
    left_out = "left out: the tests they were published for are read as tests without a logged beta"
    if nan.any():
        log.warn(f"beta {where}: {int(nan.sum())} value(s) are NaN or infinite (the first at "
                 f"{beta.t[nan][0]:.3f} s); {left_out}")
    if outside.any():
        log.warn(f"beta {where}: {int(outside.sum())} value(s) outside (-1, 1) (the first {beta.values[outside][0]:+g} "
                 f"at {beta.t[outside][0]:.3f} s), not a relay's beta (check --beta-topic); {left_out}")
    bad = nan | outside
    if not bad.any():
        return beta
    return Signal(beta.t[~bad], beta.values[~bad]) if not bad.all() else None


def _bounded(log: LogSource, sig: Signal, role: str, where: str) -> Signal:
    """``sig`` without values beyond :data:`ABSURD_MAGNITUDE`, said in a warning.

    No sensor or command reads 1e100 in any unit; such a value is a corrupt sample, and its square
    overflows float64 in every fit downstream. It is left out like a NaN (:func:`_finite`).
    """
    with np.errstate(invalid="ignore"):
        bad = np.isfinite(sig.values) & (np.abs(sig.values) > ABSURD_MAGNITUDE)  # NaN, inf: _finite

    def warning(k: np.ndarray) -> str:
        return (f"{role} {where}: {k.size} value(s) beyond +-{ABSURD_MAGNITUDE:.0e} (the first {sig.values[k[0]]:.3g} "
                f"at message {int(k[0]) + 1}): corrupt samples, left out as missing samples")

    return _left_out(log, sig, bad, f"{role} {where}: every value is beyond +-{ABSURD_MAGNITUDE:.0e}", role, warning)


def _finite(log: LogSource, sig: Signal, role: str, where: str) -> Signal:
    """``sig`` without its NaN / infinite values, said in a warning (all of them: an error).

    A NaN in a relay command is not a level: the samples are left out, so a switch next to them is
    bracketed by the samples around (1-2 missing: the instant is interpolated; more: the cycle is
    dropped as a gap) rather than read at a made-up level.
    """
    bad = ~np.isfinite(sig.values)

    def warning(k: np.ndarray) -> str:
        return (f"{role} {where}: {k.size} value(s) are NaN or infinite (the first {sig.t[k[0]] - sig.t[0]:.3f} s "
                f"after its first sample, message {int(k[0]) + 1}); left out as missing samples: a relay switch next "
                f"to them is interpolated between the samples around it (1-2 missing) or its cycle is dropped (more)")

    return _left_out(log, sig, bad, f"{role} {where}: every value is NaN or infinite", role, warning)


#: a held sample repeats its predecessor in runs of at most this many (a sensor at a third of the log's
#: rate or faster), and at least this share of all samples must be such repeats for the output to be
#: called stale: a flat stretch (saturation, a pause) repeats in long runs, a quantised signal now and then
#: (real KSTAR recordings: 8 % of the samples in short runs; a sensor at half the log's rate: 50 %)
_STALE_RUN, _STALE_SHARE = 3, 0.25
#: samples a stale output is judged on (the first 2^20: 87 min at 200 Hz); the rest only masked
_STALE_WINDOW = 1 << 20


def stale_samples(values: np.ndarray) -> np.ndarray | None:
    """The samples that exactly repeat their predecessor in short runs (:data:`_STALE_RUN`), when at least
    :data:`_STALE_SHARE` of the samples do (a sample-and-hold sensor slower than the log, a logger
    re-writing its last value); else None.

    Only a finely resolved output is judged (its typical step at least 3 times its smallest): exact repeats
    of a coarsely quantised signal are its resolution, not staleness.
    """
    y = np.asarray(values, dtype=np.float64)
    if len(y) < 100:
        return None
    head = y[:_STALE_WINDOW]  # judged on the first stretch: a 10 M-sample log's output stays within its memory
    steps = np.abs(np.diff(head))
    steps = steps[steps > 0]
    if len(steps) < 50 or np.median(steps) < 3 * steps.min() or _held(head).mean() < _STALE_SHARE:
        return None
    held = _held(y)
    return held if held.mean() >= _STALE_SHARE else None


def _held(y: np.ndarray) -> np.ndarray:
    """The samples repeating their predecessor in runs of at most :data:`_STALE_RUN`."""
    same = np.r_[False, y[1:] == y[:-1]]
    edges = np.diff(np.r_[np.int8(0), same.astype(np.int8), np.int8(0)])
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    keep = ends - starts <= _STALE_RUN
    short = np.bincount(starts[keep], minlength=len(y) + 1) - np.bincount(ends[keep], minlength=len(y) + 1)
    return np.cumsum(short[:-1]) > 0


#: contiguous blocks the interleaved delay is estimated in (their median is the estimate)
_STALE_BLOCKS = 16


def interleaved_delay(t: np.ndarray, values: np.ndarray) -> tuple[float, float]:
    """(delay [s], its standard error [s]) of the odd samples behind the even ones.

    The even samples interpolated at the odd samples' times leave a residual of ``-delay`` times the slope
    (linear interpolation's own error follows the curvature, which the slope does not predict, and the
    noise of the interpolation and of the slope are uncorrelated): a least-squares fit of the residual on
    the slope. A sensor whose every second sample is an older measurement (sample-and-hold) shows as a
    delay of a sample or more; a fresh one as 0.

    The fit is made in :data:`_STALE_BLOCKS` contiguous blocks and the estimate is their median, its
    standard error from their spread: a stale sensor lags in every block, while one jump of the output
    (recordings joined end to end, a setpoint step) has a slope that outweighs every other sample's and
    reads as a delay of a sample in the one block it falls in (a clean 500 Hz log of three joined
    recordings read "every second sample 1.99 ms older" from the whole-log fit).
    """
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    n_blocks = min(_STALE_BLOCKS, len(t) // 64)
    if n_blocks < 4:
        return _interleaved_fit(t, y)
    bounds = np.linspace(0, len(t), n_blocks + 1).astype(int) // 2 * 2  # even starts keep the phases
    fits = [_interleaved_fit(t[a:b], y[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
    delays = np.array([d for d, se in fits if math.isfinite(se)])
    if len(delays) < 4:
        return 0.0, float("inf")
    spread = float(np.std(delays, ddof=1))
    return float(np.median(delays)), 1.2533 * spread / math.sqrt(len(delays))  # the median's standard error


def _interleaved_fit(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(delay [s], its standard error [s]) from one least-squares fit over ``t`` (:func:`interleaved_delay`)."""
    te, ye, to, yo = t[0::2], y[0::2], t[1::2], y[1::2]
    inside = (to > te[0]) & (to < te[-1])
    to, yo = to[inside], yo[inside]
    dte = np.diff(te)
    if len(to) < 8 or (dte <= 0).any():
        return 0.0, float("inf")
    slope = np.interp(to, 0.5 * (te[1:] + te[:-1]), np.diff(ye) / dte)
    resid = yo - np.interp(to, te, ye)
    ss = float(np.dot(slope, slope))
    if ss <= 0:
        return 0.0, float("inf")
    delay = -float(np.dot(resid, slope)) / ss
    rest = resid + delay * slope
    return delay, math.sqrt(float(np.dot(rest, rest)) / (len(to) - 1) / ss)


def _stale_mask(sig: Signal) -> tuple[np.ndarray, str] | None:
    """The stale samples of ``sig`` and what they are, or None (:func:`stale_samples`, :func:`interleaved_delay`)."""
    held = stale_samples(sig.values)
    if held is not None:
        return held, f"{100 * held.mean():.0f} % of the samples repeat the one before exactly"
    dt = float(np.median(np.diff(sig.t))) if len(sig.t) > 1 else float("nan")
    if len(sig.t) < 100 or not dt > 0:
        return None
    delay, se = interleaved_delay(sig.t[:_STALE_WINDOW], sig.values[:_STALE_WINDOW])
    if abs(delay) < 0.5 * dt or abs(delay) < 5 * se:
        return None
    bad = np.zeros(len(sig.t), dtype=bool)
    bad[(1 if delay > 0 else 0)::2] = True  # the phase that lags
    return bad, f"every second sample is {1e3 * abs(delay):.3g} ms older than its neighbours"


def _fresh(log: LogSource, sig: Signal, where: str) -> Signal:
    """``sig`` without stale samples (:func:`stale_samples`), said in a warning naming the fix: a stale sample
    is an old measurement at a new time, and half the tests' samples held 20 ms biased tau by 10 ms."""
    found = _stale_mask(sig)
    if found is None:
        return sig
    bad, what = found
    log.warn(f"output {where}: {what}: a stale, sample-and-hold sensor slower than the log; those samples are "
             "left out (they would add their age to the loop's delay); log only the sensor's fresh samples")
    return Signal(sig.t[~bad], sig.values[~bad])


def _left_out(log: LogSource, sig: Signal, bad: np.ndarray, all_bad: str, role: str,
              warning: Callable[[np.ndarray], str]) -> Signal:
    """``sig`` without the samples ``bad`` marks; the warning names them (``warning(indices)``), and a
    signal with none left is a LogReadError (``all_bad``, then the option that names another field)."""
    if not bad.any():
        return sig
    if bad.all():
        raise LogReadError(f"{log.path}: {all_bad}; check the --{role}-topic field")
    log.warn(warning(np.flatnonzero(bad)))
    return Signal(sig.t[~bad], sig.values[~bad])


def _warn_low_rate(log: LogSource, command: Signal, lay: Layout) -> None:
    """Warn when the command is logged too slowly to place the relay's switches (tau)."""
    rate = median_rate_hz(command.t)
    if rate is not None and rate < _LOW_RATE_HZ:
        log.warn(f"the command is logged at {rate:.0f} Hz: an MRFT cycle of 1-2 Hz gets "
                 f"{rate / 2:.0f}-{rate:.0f} samples and each logged switch is known only to +-{500 / rate:.0f} ms "
                 "(the segmenter places the switches on the controller's ticks from many of them: tau's interval "
                 f"stays wide); {lay.low_rate_fix}")
