"""Flight-log readers and writers behind one API.

* :func:`open_log` -> a :class:`LogSource` (topics, one field as a time series), any supported format;
* :func:`read_flight` -> the :class:`~mrftcli.io.logtypes.FlightLog` one loop's analysis needs
  (:func:`flight_from_source` does the same on an already open :class:`LogSource`);
* :func:`write_log` -> write :class:`~mrftcli.io.logtypes.TopicData` in any of :data:`FORMATS`.

The layouts (reference topics, how topics map to ULog messages and CSV columns) are documented in
``docs/log-layout.md``.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..validate import check_positive
from ..errors import InputError, LogReadError
from .logtypes import LOOPS, FlightLog, Signal, TopicData, TopicInfo
from .source import LogSource, TopicSpec, parse_spec
from .attitude import roll_pitch
from .layouts import LAYOUT_NAMES, LAYOUTS, Layout, LayoutMatch, detect_layout, get_layout

__all__ = [
    "open_log", "read_flight", "flight_from_source", "write_log", "LogSource", "TopicSpec", "parse_spec",
    "FORMATS", "READ_FORMATS", "FORMAT_SUFFIX", "log_filename", "detect_format", "format_from_name",
    "DEFAULT_TOPICS", "roll_pitch", "list_topics", "FlightLog", "Signal",
    "LAYOUTS", "LAYOUT_NAMES", "Layout", "LayoutMatch", "detect_layout", "get_layout", "log_layout",
]

#: formats :func:`write_log` writes (and :func:`open_log` reads)
FORMATS = ("mcap", "mcap-json", "bag", "ros2-sqlite3", "ros2-mcap", "ulog", "csv")
#: formats :func:`open_log` reads
READ_FORMATS = FORMATS + ("dataflash", "mat")
#: fmt -> what :func:`log_filename` appends to a stem (a trailing ``/`` marks a directory)
FORMAT_SUFFIX = {
    "mcap": ".mcap",
    "mcap-json": ".json.mcap",
    "bag": ".bag",
    "ros2-sqlite3": "_ros2_sqlite3/",
    "ros2-mcap": "_ros2_mcap/",
    "ulog": ".ulg",
    "csv": ".csv",
}

#: the reference layout (ROS 2 names, :data:`LAYOUTS` ``["reference"]``) by role, see docs/log-layout.md
DEFAULT_TOPICS = {
    "command": LAYOUTS["reference"].loops["altitude"].command,
    "beta": LAYOUTS["reference"].loops["altitude"].beta,
    "setpoint": LAYOUTS["reference"].loops["altitude"].setpoint,
    **{f"output.{loop}": topics.output for loop, topics in LAYOUTS["reference"].loops.items()},
    "battery": "/battery:voltage",
}

_MAGIC = {
    b"\x89MCAP0\r\n": "mcap",
    b"#ROSBAG V2.0": "bag",
    b"ULog\x01\x12\x35": "ulog",
    b"SQLite format 3\x00": "ros2-sqlite3",
    b"\xa3\x95": "dataflash",
    b"MATLAB 5.0 MAT-file": "mat",
    b"MATLAB 7.3 MAT-file": "mat",
}


def log_filename(stem: str | Path, fmt: str) -> Path:
    """Where a log of format ``fmt`` for ``stem`` goes (``sample/alt`` + ``ulog`` -> ``sample/alt.ulg``)."""
    if fmt not in FORMAT_SUFFIX:
        raise InputError(f"unknown log format {fmt!r}; choose one of {', '.join(FORMATS)}")
    return Path(f"{stem}{FORMAT_SUFFIX[fmt].rstrip('/')}")


def format_from_name(path: str | Path) -> str | None:
    """The format :func:`write_log` writes for a file name (``.json.mcap`` -> ``mcap-json``), None
    when the name does not tell.

    Examples
    --------
    >>> format_from_name("fit.json.mcap"), format_from_name("flight.ULG"), format_from_name("flight.txt")
    ('mcap-json', 'ulog', None)
    """
    path = Path(path)
    if path.name.lower().endswith(".json.mcap"):
        return "mcap-json"
    return {".mcap": "mcap", ".bag": "bag", ".ulg": "ulog", ".csv": "csv"}.get(path.suffix.lower())


def detect_format(path: str | Path) -> str:
    """Format of an existing log from its magic bytes (then its extension). Raises LogReadError."""
    path = Path(path)
    if not path.exists():
        raise LogReadError(f"{path}: no such file or directory")
    if path.is_dir():
        meta = path / "metadata.yaml"
        if not meta.is_file():
            raise LogReadError(f"{path}: a directory but not a ROS 2 bag (no metadata.yaml)")
        text = meta.read_text(errors="replace")
        return "ros2-mcap" if "storage_identifier: mcap" in text else "ros2-sqlite3"
    try:
        with open(path, "rb") as handle:
            head = handle.read(24)
    except OSError as err:
        raise LogReadError(f"{path}: cannot read ({err.strerror})") from None
    if not head:
        raise LogReadError(f"{path}: the file is empty")
    for magic, fmt in _MAGIC.items():
        if head.startswith(magic):
            return fmt
    suffix = path.suffix.lower()
    if suffix == ".mat":
        return "mat"
    if suffix in (".csv", ".txt") or (b"," in head and head.isascii()):
        return "csv"
    raise LogReadError(f"{path}: unknown log format (not MCAP, ROS 1 bag, ROS 2 bag, ULog, "
                       "DataFlash, MATLAB or CSV); if it is one of these, pass --format "
                       f"({', '.join(READ_FORMATS)})")


def open_log(path: str | Path, fmt: str | None = None, *, echo_warnings: bool = True) -> LogSource:
    """Open a flight log; use as ``with open_log(path) as log: log.topics(); log.series(t, f)``.

    Parameters
    ----------
    path : str or Path
        A file (``.mcap``, ``.bag``, ``.ulg``, ``.BIN``, ``.csv``, a ROS 2 ``.db3``) or a ROS 2 bag
        directory (with ``metadata.yaml``).
    fmt : str, optional
        One of :data:`READ_FORMATS` to skip detection (``mcap-json`` reads like ``mcap``).
    echo_warnings : bool
        Print the reader's warnings (``warning: ...`` on stderr) when the ``with`` block ends; with
        False they are only kept in ``LogSource.warnings`` for the caller to show (``watch``).

    Raises
    ------
    LogReadError
        Unknown format, unreadable/corrupt/empty file.
    """
    path = Path(path)
    if fmt is None:
        fmt = detect_format(path)
    elif fmt not in READ_FORMATS:
        raise InputError(f"unknown log format {fmt!r}; choose one of {', '.join(READ_FORMATS)}")
    elif not path.exists():
        raise LogReadError(f"{path}: no such file or directory")
    source = _open(path, fmt)
    source.echo_warnings = echo_warnings
    return source


def _open(path: Path, fmt: str) -> LogSource:
    if fmt in ("mcap", "mcap-json"):
        from .format_mcap import McapSource

        return McapSource(path)
    if fmt == "ros2-mcap" and path.is_dir():
        # a ROS 2 bag with mcap storage is an MCAP file plus metadata.yaml: read the single-file,
        # not message-compressed case with the vectorised MCAP reader (same log times as rosbags)
        files = sorted(path.glob("*.mcap"))
        meta = (path / "metadata.yaml").read_text(errors="replace")
        if len(files) == 1 and "compression_mode: message" not in meta.lower():
            from .format_mcap import McapSource

            source = McapSource(files[0])
            source.format = "ros2-mcap"
            return source
    if fmt in ("bag", "ros2-sqlite3", "ros2-mcap"):
        from .format_rosbag import RosbagSource

        return RosbagSource(path, fmt)
    if fmt == "ulog":
        from .format_ulog import UlogSource

        return UlogSource(path)
    if fmt == "dataflash":
        from .format_dataflash import DataflashSource

        return DataflashSource(path)
    if fmt == "mat":
        from .format_mat import MatSource

        return MatSource(path)
    from .format_csv import CsvSource

    return CsvSource(path)


def write_log(topics: list[TopicData], path: str | Path, fmt: str | None = None,
              *, overwrite: bool = True) -> Path:
    """Write ``topics`` as a log of format ``fmt`` (default: from the path's extension).

    Parameters
    ----------
    topics : list of TopicData
        ROS 2 type names (``std_msgs/msg/Float64``, ``geometry_msgs/msg/PoseStamped``,
        ``sensor_msgs/msg/Imu``, ``sensor_msgs/msg/BatteryState``); ROS 1 bags get the ROS 1 names.
    path : str or Path
        Target file, or directory for ``ros2-sqlite3`` / ``ros2-mcap``.
    fmt : str, optional
        One of :data:`FORMATS`; ``.json.mcap`` means ``mcap-json``.
    overwrite : bool
        Replace an existing file (or ROS 2 bag directory, recognised by its ``metadata.yaml``).

    Returns
    -------
    Path
        The written path.
    """
    path = Path(path)
    if fmt is None:
        fmt = format_from_name(path)
        if fmt is None:
            raise InputError(f"cannot tell the log format from {path.name!r}; pass fmt= one of "
                             f"{', '.join(FORMATS)}")
    if fmt not in FORMATS:
        raise InputError(f"unknown log format {fmt!r}; choose one of {', '.join(FORMATS)}")
    for td in topics:
        t = np.asarray(td.t, dtype=np.float64)
        if len(t) > 1 and (np.diff(t) < 0).any():
            raise InputError(f"{td.name}: message times must be non-decreasing")
    if path.exists():
        if not overwrite:
            raise InputError(f"{path} exists already")
        if path.is_dir():
            if not (path / "metadata.yaml").is_file():
                raise InputError(f"{path} is a directory that is not a ROS 2 bag; not replacing it")
            shutil.rmtree(path)
        else:
            path.unlink()
    if fmt in ("mcap", "mcap-json"):
        from .format_mcap import write_mcap

        write_mcap(topics, path, encoding="cdr" if fmt == "mcap" else "json")
    elif fmt in ("bag", "ros2-sqlite3", "ros2-mcap"):
        from .format_rosbag import write_rosbag

        write_rosbag(topics, path, fmt)
    elif fmt == "ulog":
        from .format_ulog import write_ulog

        write_ulog(topics, path)
    else:
        from .format_csv import write_csv

        write_csv(topics, path)
    return path


# -- read_flight ---------------------------------------------------------------------------------
def _get(log: LogSource, spec: str, required: bool):
    """(t, leaves, values, TopicSpec) for one role, or None if an optional topic is absent."""
    ts = parse_spec(spec)
    topic = log.resolve_topic(ts.topic)
    if topic is None:
        if required:
            raise log.missing_topic(ts.topic)
        return None
    t, leaves, vals = log.values(topic, ts.field)
    return t, leaves, vals, TopicSpec(topic, ts.field)


def _where(topic: str, leaf: str) -> str:
    """``topic:leaf`` for FlightLog.source (CSV leaves are whole column names already)."""
    return leaf if leaf.startswith(topic) else f"{topic}:{leaf}"


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


#: PX4 MRFT axis of each loop (parameters MRFT_<AXIS>_BETA, _H, _ENABLE)
_PX4_AXIS = {"x": "X", "y": "Y", "altitude": "Z"}
#: below this command rate [Hz] an MRFT cycle of 1-2 Hz has fewer than ~10 samples
_LOW_RATE_HZ = 25.0


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


def _jitter(t: np.ndarray) -> float:
    """Timing jitter [s] of receive-time stamps: the robust spread of the sample spacing / sqrt 2.

    A stamp e_k late gives spacings dt + e_{k+1} - e_k, whose variance is 2 var(e) for independent
    delays; the median absolute deviation (x 1.4826) ignores dropped samples and bursts.
    """
    if t.size < 20:
        return float("nan")
    d = np.diff(t)
    mad = float(np.median(np.abs(d - np.median(d)))) * 1.4826
    return mad / np.sqrt(2.0)


def read_flight(path: str | Path, loop: str = "altitude", command_topic: str | None = None,
                output_topic: str | None = None, beta_topic: str | None = None,
                setpoint_topic: str | None = None, battery_topic: str | None = None,
                output_scale: float | None = None, fmt: str | None = None, *,
                layout: str | None = None, command_scale: float | None = None,
                controller_rate_hz: float | None = None, echo_warnings: bool = True) -> FlightLog:
    """Read the signals of one loop from a flight log.

    Parameters
    ----------
    path : str or Path
        The log (any format :func:`open_log` reads).
    loop : {"altitude", "roll", "pitch", "x", "y"}
        Which loop; picks the layout's topics and turns a quaternion output into roll or pitch
        (ZYX convention, :mod:`mrftcli.io.attitude`).
    command_topic, output_topic, beta_topic, setpoint_topic, battery_topic : str, optional
        ``TOPIC[:FIELD]`` overriding the layout (:data:`~mrftcli.io.layouts.LAYOUTS`); FIELD is a
        dotted path into the message (ULog: message field, ``name.N`` for instance N; CSV: column;
        DataFlash: ``TYPE:Column``; ``.mat``: the vector's name). An omitted FIELD means ``data`` for
        ROS topics.
    output_scale : float, optional
        Factor applied to the output and the setpoint (e.g. ``-1`` for a NED ``z`` as altitude,
        ``pi/180`` for degrees). Default: the layout's (1, or -1 for PX4's NED z).
    fmt : str, optional
        Log format; detected when omitted.
    layout : str, optional
        One of :data:`~mrftcli.io.layouts.LAYOUT_NAMES`; recognised from the topics when omitted
        (``FlightLog.source["layout"]`` says which and why).
    command_scale : float, optional
        Factor applied to the command (default: the layout's; -1 for PX4's upward-negative thrust).
    controller_rate_hz : float, optional
        Rate [Hz] at which the relay decided, when the command may be logged more slowly (default:
        the layout's, e.g. 50 Hz for PX4's position controller; recorded in
        ``source["controller_rate_hz"]`` for the segmenter).
    echo_warnings : bool
        Print the reader's warnings on stderr; False keeps them in ``FlightLog.warnings`` only, for a
        caller that shows them itself (``analyze``, ``watch``).

    Returns
    -------
    FlightLog
        ``command`` and ``output`` always; ``beta``, ``setpoint``, ``battery_voltage`` when logged.
        ``source`` records the layout, where each signal came from, the scales, the timing
        (``timestamps``: header or receive, ``timing_jitter_s``) and, for PX4, the test windows.

    Raises
    ------
    InputError
        Unknown loop or layout, or a loop the layout does not record.
    LogReadError
        Unreadable log, or a required topic/field missing (the message lists what exists).
    """
    _check_read_options(loop, output_scale, command_scale, controller_rate_hz)  # before opening the log
    with open_log(path, fmt, echo_warnings=echo_warnings) as log:
        flight = flight_from_source(log, loop, command_topic, output_topic, beta_topic, setpoint_topic,
                                    battery_topic, output_scale, layout=layout, command_scale=command_scale,
                                    controller_rate_hz=controller_rate_hz)
    # a ROS 2 bag folder is read through the MCAP file inside it: the flight is the folder's
    return replace(flight, path=str(path))


def _check_read_options(loop: str, output_scale: float | None, command_scale: float | None,
                        controller_rate_hz: float | None) -> float | None:
    """InputError for an unknown loop or a zero/non-finite scale; the checked controller rate [Hz]."""
    if loop not in LOOPS:
        raise InputError(f"unknown loop {loop!r}; choose one of {', '.join(LOOPS)}")
    if controller_rate_hz is not None:
        controller_rate_hz = check_positive("controller rate [Hz]", controller_rate_hz)
    for name, value in (("output", output_scale), ("command", command_scale)):
        if value is not None and not (np.isfinite(value) and value != 0.0):
            raise InputError(f"{name} scale must be a finite non-zero number, got {value}")
    return controller_rate_hz


def flight_from_source(log: LogSource, loop: str = "altitude", command_topic: str | None = None,
                       output_topic: str | None = None, beta_topic: str | None = None,
                       setpoint_topic: str | None = None, battery_topic: str | None = None,
                       output_scale: float | None = None, *, layout: str | None = None,
                       command_scale: float | None = None, controller_rate_hz: float | None = None) -> FlightLog:
    """The signals of one loop from an open :class:`LogSource` (what :func:`read_flight` does after opening).

    The topic logic (layout, ``TOPIC[:FIELD]`` specs, quaternion -> roll/pitch, scales, optional
    topics, PX4 test windows) lives here once, for readers of a whole file (:func:`read_flight`) and of
    a file that is still being written (:mod:`mrftcli.watch`). Parameters, return value and errors
    are :func:`read_flight`'s; the reader's warnings are added to ``log.warnings`` (and copied into
    ``FlightLog.warnings``); ``FlightLog.path`` is ``log.path``.
    """
    controller_rate_hz = _check_read_options(loop, output_scale, command_scale, controller_rate_hz)
    match = log_layout(log, layout)
    lay = match.layout
    lt = lay.loops.get(loop)
    if lt is None and (command_topic is None or output_topic is None):
        raise InputError(f"layout {lay.name} has no {loop} loop (its loops: {', '.join(lay.loops)}); "
                         "name the topics with --command-topic and --output-topic")
    ref = lay.name == "reference"
    spec_cmd = command_topic or lt.command
    spec_out = output_topic or lt.output
    spec_beta = beta_topic or (lt.beta if lt is not None else None)
    spec_sp = setpoint_topic or (lt.setpoint if lt is not None else None)
    spec_bat = battery_topic or (DEFAULT_TOPICS["battery"] if ref else None)
    if output_scale is None:
        output_scale = lt.output_scale if lt is not None and output_topic is None else 1.0
    if command_scale is None:
        command_scale = lt.command_scale if lt is not None and command_topic is None else 1.0
    source: dict = {"format": log.format, "layout": match.describe()}
    if (controller_rate_hz or lay.controller_rate_hz) is not None:
        source["controller_rate_hz"] = controller_rate_hz or lay.controller_rate_hz
    log.prefetch([parse_spec(s).topic for s in (spec_cmd, spec_out, spec_beta, spec_sp, spec_bat) if s])
    cmd = _get(log, spec_cmd, True)
    out = _get(log, spec_out, True)
    t, leaves, vals, spec = out
    if len(leaves) == 4:
        if loop not in ("roll", "pitch"):
            raise LogReadError(f"{log.path}: output {spec} is an orientation quaternion; "
                               f"for --loop {loop} name a position field")
        try:
            roll, pitch = roll_pitch(*(vals[k] for k in leaves))
        except LogReadError as err:
            raise LogReadError(f"{log.path}: {spec}: {err}") from None
        y = roll if loop == "roll" else pitch
        source["output_conversion"] = f"quaternion -> {loop} (ZYX), rad"
    else:
        y = vals[leaves[0]]
    output = Signal(t, y * output_scale)
    source["command"] = _where(cmd[3].topic, cmd[1][0])
    source["output"] = str(spec) if len(leaves) == 4 else _where(spec.topic, leaves[0])
    if len(cmd[1]) != 1:
        raise LogReadError(f"{log.path}: command {cmd[3]} is a quaternion; name one number")
    command = Signal(cmd[0], cmd[2][cmd[1][0]] * command_scale)
    optional: dict = {}
    for role, option, default, scale in (
            ("beta", beta_topic, spec_beta, 1.0),
            ("setpoint", setpoint_topic, spec_sp, output_scale),
            ("battery_voltage", battery_topic, spec_bat, 1.0)):
        # an optional topic the user named must exist and fit; a layout's may be absent
        # or be something else under the same name (then it is skipped with a warning)
        if default is None:
            optional[role] = None
            continue
        try:
            got = _get(log, default, option is not None)
        except LogReadError as err:
            if option is not None:
                raise
            log.warn(f"ignored {default} as {role}: {err}")
            got = None
        if got is None:
            optional[role] = None
            continue
        tt, lv, vv, sp = got
        if len(lv) != 1:
            raise LogReadError(f"{log.path}: {role} {sp} is a quaternion; name one number")
        optional[role] = Signal(tt, vv[lv[0]] * scale)
        source[role] = _where(sp.topic, lv[0])
    if optional["beta"] is None and beta_topic is None and lay.parameters:
        beta_sig, windows, where = _parameter_tests(log, lay.parameters, loop)
        if beta_sig is not None:
            optional["beta"] = beta_sig
            source["beta"] = where
            source["test_windows"] = [[a, b if np.isfinite(b) else None] for a, b in windows]
    if output_scale != 1.0:
        source["output_scale"] = output_scale
    if command_scale != 1.0:
        source["command_scale"] = command_scale
    if lay.timestamps == "receive" or log.format == "bag":
        # no header stamps: the bag's receive time carries the transport's jitter
        source["timestamps"] = "receive"
        source["timing_jitter_s"] = max(_jitter(command.t), _jitter(output.t))
    command = _finite(log, command, "command", source["command"])
    output = _finite(log, output, "output", source["output"])
    rate = _median_rate(command.t)
    if not ref and rate is not None and rate < _LOW_RATE_HZ:
        log.warn(f"the command is logged at {rate:.0f} Hz: an MRFT cycle of 1-2 Hz gets "
                 f"{rate / 2:.0f}-{rate:.0f} samples, so switch instants (and tau) are known only to "
                 f"+-{500 / rate:.0f} ms; {lay.low_rate_fix}")
    return FlightLog(path=str(log.path), loop=loop, command=command, output=output,
                     beta=optional["beta"], setpoint=optional["setpoint"],
                     battery_voltage=optional["battery_voltage"], source=source,
                     warnings=list(log.warnings))


def _finite(log: LogSource, sig: Signal, role: str, where: str) -> Signal:
    """``sig`` without its NaN / infinite values, said in a warning (all of them: an error).

    A NaN in a relay command is not a level: the samples are left out, so a switch next to them is
    bracketed by the samples around (1-2 missing: the instant is interpolated; more: the cycle is
    dropped as a gap) rather than read at a made-up level.
    """
    bad = ~np.isfinite(sig.values)
    if not bad.any():
        return sig
    if bad.all():
        raise LogReadError(f"{log.path}: {role} {where}: every value is NaN or infinite; check the "
                           f"--{role}-topic field")
    k = np.flatnonzero(bad)
    log.warn(f"{role} {where}: {k.size} value(s) are NaN or infinite (the first {sig.t[k[0]] - sig.t[0]:.3f} s "
             f"after its first sample, message {int(k[0]) + 1}); left out as missing samples: a relay switch next to them is "
             f"interpolated between the samples around it (1-2 missing) or its cycle is dropped (more)")
    return Signal(sig.t[~bad], sig.values[~bad])


def _median_rate(t: np.ndarray) -> float | None:
    """Median sample rate [Hz] of increasing times (None for fewer than three)."""
    if t.size < 3:
        return None
    d = float(np.median(np.diff(t)))
    return 1.0 / d if d > 0 else None


def list_topics(path: str | Path, fmt: str | None = None) -> tuple[str, list[TopicInfo]]:
    """Format name and topics of a log (what ``mrft-ident topics`` shows)."""
    with open_log(path, fmt) as log:
        return log.format, log.topics()
