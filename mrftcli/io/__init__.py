"""Flight-log readers and writers behind one API.

* :func:`open_log` -> a :class:`LogSource` (topics, one field as a time series), any supported format;
* :func:`read_flight` -> the :class:`~mrftcli.io.logtypes.FlightLog` one loop's analysis needs;
* :func:`write_log` -> write :class:`~mrftcli.io.logtypes.TopicData` in any of :data:`FORMATS`.

The layouts (reference topics, how topics map to ULog messages and CSV columns) are documented in
``docs/log-layout.md``.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from ..errors import InputError, LogReadError
from .logtypes import LOOPS, FlightLog, Signal, TopicData, TopicInfo
from .source import LogSource, TopicSpec, parse_spec
from .attitude import roll_pitch

__all__ = [
    "open_log", "read_flight", "write_log", "LogSource", "TopicSpec", "parse_spec",
    "FORMATS", "READ_FORMATS", "FORMAT_SUFFIX", "log_filename", "detect_format",
    "DEFAULT_TOPICS", "roll_pitch", "list_topics", "FlightLog", "Signal",
]

#: formats :func:`write_log` writes (and :func:`open_log` reads)
FORMATS = ("mcap", "mcap-json", "bag", "ros2-sqlite3", "ros2-mcap", "ulog", "csv")
#: formats :func:`open_log` reads
READ_FORMATS = FORMATS + ("dataflash",)
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

#: the reference layout (ROS 2 names), see docs/log-layout.md
DEFAULT_TOPICS = {
    "command": "/mrft/command:data",
    "beta": "/mrft/beta:data",
    "setpoint": "/mrft/setpoint:data",
    "output.altitude": "/mocap/pose:pose.position.z",
    "output.roll": "/imu/data:orientation",
    "output.pitch": "/imu/data:orientation",
    "battery": "/battery:voltage",
}

_MAGIC = {
    b"\x89MCAP0\r\n": "mcap",
    b"#ROSBAG V2.0": "bag",
    b"ULog\x01\x12\x35": "ulog",
    b"SQLite format 3\x00": "ros2-sqlite3",
    b"\xa3\x95": "dataflash",
}


def log_filename(stem: str | Path, fmt: str) -> Path:
    """Where a log of format ``fmt`` for ``stem`` goes (``sample/alt`` + ``ulog`` -> ``sample/alt.ulg``)."""
    if fmt not in FORMAT_SUFFIX:
        raise InputError(f"unknown log format {fmt!r}; choose one of {', '.join(FORMATS)}")
    return Path(f"{stem}{FORMAT_SUFFIX[fmt].rstrip('/')}")


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
            head = handle.read(16)
    except OSError as err:
        raise LogReadError(f"{path}: cannot read ({err.strerror})") from None
    if not head:
        raise LogReadError(f"{path}: the file is empty")
    for magic, fmt in _MAGIC.items():
        if head.startswith(magic):
            return fmt
    suffix = path.suffix.lower()
    if suffix in (".csv", ".txt") or (b"," in head and head.isascii()):
        return "csv"
    raise LogReadError(f"{path}: unknown log format (not MCAP, ROS 1 bag, ROS 2 bag, ULog, "
                       "DataFlash or CSV); pass the format explicitly if it is one of these")


def open_log(path: str | Path, fmt: str | None = None) -> LogSource:
    """Open a flight log; use as ``with open_log(path) as log: log.topics(); log.series(t, f)``.

    Parameters
    ----------
    path : str or Path
        A file (``.mcap``, ``.bag``, ``.ulg``, ``.BIN``, ``.csv``, a ROS 2 ``.db3``) or a ROS 2 bag
        directory (with ``metadata.yaml``).
    fmt : str, optional
        One of :data:`READ_FORMATS` to skip detection (``mcap-json`` reads like ``mcap``).

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
        name = path.name.lower()
        if name.endswith(".json.mcap"):
            fmt = "mcap-json"
        else:
            fmt = {".mcap": "mcap", ".bag": "bag", ".ulg": "ulog", ".csv": "csv"}.get(path.suffix.lower())
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


def read_flight(path: str | Path, loop: str = "altitude", command_topic: str | None = None,
                output_topic: str | None = None, beta_topic: str | None = None,
                setpoint_topic: str | None = None, battery_topic: str | None = None,
                output_scale: float = 1.0, fmt: str | None = None) -> FlightLog:
    """Read the signals of one loop from a flight log.

    Parameters
    ----------
    path : str or Path
        The log (any format :func:`open_log` reads).
    loop : {"altitude", "roll", "pitch"}
        Which loop; picks the default output topic and turns a quaternion output into roll or pitch
        (ZYX convention, :mod:`mrftcli.io.attitude`).
    command_topic, output_topic, beta_topic, setpoint_topic, battery_topic : str, optional
        ``TOPIC[:FIELD]`` overriding the reference layout (:data:`DEFAULT_TOPICS`); FIELD is a dotted
        path into the message (ULog: message field, ``name.N`` for instance N; CSV: column; DataFlash:
        ``TYPE:Column``). An omitted FIELD means ``data`` for ROS topics.
    output_scale : float
        Factor applied to the output and the setpoint (e.g. ``-1`` for a NED ``z`` as altitude,
        ``pi/180`` for degrees).
    fmt : str, optional
        Log format; detected when omitted.

    Returns
    -------
    FlightLog
        ``command`` and ``output`` always; ``beta``, ``setpoint``, ``battery_voltage`` when logged.

    Raises
    ------
    InputError
        Unknown loop.
    LogReadError
        Unreadable log, or a required topic/field missing (the message lists what exists).
    """
    if loop not in LOOPS:
        raise InputError(f"unknown loop {loop!r}; choose one of {', '.join(LOOPS)}")
    if not (np.isfinite(output_scale) and output_scale != 0.0):
        raise InputError(f"output scale must be a finite non-zero number, got {output_scale}")
    with open_log(path, fmt) as log:
        source: dict = {"format": log.format}
        log.prefetch([parse_spec(s).topic for s in (
            command_topic or DEFAULT_TOPICS["command"], output_topic or DEFAULT_TOPICS[f"output.{loop}"],
            beta_topic or DEFAULT_TOPICS["beta"], setpoint_topic or DEFAULT_TOPICS["setpoint"],
            battery_topic or DEFAULT_TOPICS["battery"])])
        cmd = _get(log, command_topic or DEFAULT_TOPICS["command"], True)
        out = _get(log, output_topic or DEFAULT_TOPICS[f"output.{loop}"], True)
        t, leaves, vals, spec = out
        if len(leaves) == 4:
            if loop == "altitude":
                raise LogReadError(f"{log.path}: output {spec} is an orientation quaternion; "
                                   "for --loop altitude name a position field")
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
        command = Signal(cmd[0], cmd[2][cmd[1][0]])
        optional = {}
        for role, option, default, scale in (
                ("beta", beta_topic, DEFAULT_TOPICS["beta"], 1.0),
                ("setpoint", setpoint_topic, DEFAULT_TOPICS["setpoint"], output_scale),
                ("battery_voltage", battery_topic, DEFAULT_TOPICS["battery"], 1.0)):
            # an optional topic the user named must exist and fit; a default one may be absent
            # or be something else under the same name (then it is skipped with a warning)
            try:
                got = _get(log, option or default, option is not None)
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
        if output_scale != 1.0:
            source["output_scale"] = output_scale
        return FlightLog(path=str(path), loop=loop, command=command, output=output,
                         beta=optional["beta"], setpoint=optional["setpoint"],
                         battery_voltage=optional["battery_voltage"], source=source,
                         warnings=list(log.warnings))


def list_topics(path: str | Path, fmt: str | None = None) -> tuple[str, list[TopicInfo]]:
    """Format name and topics of a log (what ``mrft-ident topics`` shows)."""
    with open_log(path, fmt) as log:
        return log.format, log.topics()
