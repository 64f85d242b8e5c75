"""Flight-log readers and writers behind one API.

* :func:`open_log` -> a :class:`LogSource` (topics, one field as a time series), any supported format;
* :func:`read_flight` -> the :class:`~mrftcli.io.logtypes.FlightLog` one loop's analysis needs
  with its :class:`ReadOptions` (:func:`read_loop` does the same on an already open :class:`LogSource`,
  in the stages of :mod:`mrftcli.io.flight`);
* :func:`write_log` -> write :class:`~mrftcli.io.logtypes.TopicData` in any of :data:`FORMATS`;
* :mod:`mrftcli.io.timing` -> sample rates from timestamps and the flight's :class:`Timing`;
  :mod:`mrftcli.io.follow` -> the flight so far from a log still being written.

The layouts (reference topics, how topics map to ULog messages and CSV columns) are documented in
``docs/log-layout.md``.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import InputError, LogReadError
from ..progress import Progress
from .attitude import roll_pitch
from .clock import TIME_UNITS, check_time_unit
from .flight import DEFAULT_TOPICS, ReadOptions, log_layout, read_loop
from .layouts import LAYOUT_NAMES, LAYOUTS, Layout, LayoutMatch, detect_layout, get_layout
from .logtypes import FlightLog, Signal, TopicData, TopicInfo
from .source import LogSource, TopicSpec, parse_spec
from .timing import Timing, controller_rate_hz, median_rate_hz

__all__ = [
    "open_log", "read_flight", "write_log", "LogSource", "TopicSpec", "parse_spec",
    "FORMATS", "READ_FORMATS", "FORMAT_SUFFIX", "log_filename", "detect_format", "format_from_name",
    "require_input",
    "writable_format",
    "DEFAULT_TOPICS", "roll_pitch", "list_topics", "FlightLog", "Signal", "Timing", "ReadOptions", "read_loop",
    "median_rate_hz", "controller_rate_hz", "TIME_UNITS",
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


def writable_format(path: str | Path, fmt: str | None, option: str = "fmt=") -> str:
    """``fmt`` checked against :data:`FORMATS`, else the format of ``path``'s name (:func:`format_from_name`);
    a one-line InputError naming ``option`` when the name does not tell."""
    if fmt is None:
        fmt = format_from_name(path)
        if fmt is None:
            raise InputError(f"cannot tell the log format from {Path(path).name!r}; pass {option} (one of "
                             f"{', '.join(FORMATS)})")
    if fmt not in FORMATS:
        raise InputError(f"unknown log format {fmt!r}; choose one of {', '.join(FORMATS)}")
    return fmt


def require_input(path: str | Path) -> Path:
    """``path`` as a Path if it exists; else the one error of every command's missing input.

    Raises
    ------
    LogReadError
        ``"<path>: no such file or directory"`` (exit 3, docs/usage.md's exit codes): a log, a folder of
        logs, an analysis JSON or a reference, whichever command was given it.
    """
    path = Path(path)
    if not path.exists():
        raise LogReadError(f"{path}: no such file or directory")
    return path


def detect_format(path: str | Path) -> str:
    """Format of an existing log from its magic bytes (then its extension). Raises LogReadError."""
    path = require_input(path)
    if path.is_dir():
        meta = path / "metadata.yaml"
        if not meta.is_file():
            raise LogReadError(_not_a_bag(path))
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


def _not_a_bag(path: Path) -> str:
    """Why a folder is not one log: a folder of logs (then: batch), or a ROS 2 bag without its metadata."""
    logs = [p for p in path.iterdir() if p.suffix.lower() in _LOG_SUFFIXES or (p / "metadata.yaml").is_file()]
    if len(logs) > 1 or (logs and not any(path.glob("*.db3")) and not any(path.glob("*.mcap"))):
        return (f"{path}: a folder of {len(logs)} log(s), not one log; analyse each with "
                f"'mrft-ident batch {path}', or name one file")
    return (f"{path}: a directory but not a ROS 2 bag (no metadata.yaml; 'ros2 bag reindex' rebuilds it); "
            f"for a folder of logs use 'mrft-ident batch {path}'")


#: file suffixes of the logs a folder may hold (:func:`_not_a_bag`)
_LOG_SUFFIXES = {".mcap", ".bag", ".ulg", ".csv", ".mat", ".bin", ".db3"}


def open_log(path: str | Path, fmt: str | None = None, *, echo_warnings: bool = True,
             time_unit: str | None = None, progress: Progress | None = None) -> LogSource:
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
    time_unit : {"s", "ms", "us", "ns"}, optional
        The unit of a CSV's time column or a ``.mat`` file's time vectors (default: the column's name
        says, else seconds); other formats define their clock, and refuse it.
    progress : Progress, optional
        Told how far a read that takes seconds is (:mod:`mrftcli.progress`: bytes of the file read,
        and what): a large CSV's passes; other formats read fast enough not to call it.

    Raises
    ------
    InputError
        Unknown format or time unit; a time unit for a format whose clock has one.
    LogReadError
        Unknown format, unreadable/corrupt/empty file.
    """
    check_time_unit(time_unit)
    path = Path(path)
    if fmt is None:
        fmt = detect_format(path)
    elif fmt not in READ_FORMATS:
        raise InputError(f"unknown log format {fmt!r}; choose one of {', '.join(READ_FORMATS)}")
    else:
        require_input(path)
    if time_unit is not None and fmt not in ("csv", "mat"):
        raise InputError(f"--time-unit applies to CSV and .mat logs, whose times carry no unit; a {fmt} log's "
                         "clock has its own")
    source = _open(path, fmt, time_unit, progress)
    source.echo_warnings = echo_warnings
    return source


def _open(path: Path, fmt: str, time_unit: str | None = None, progress: Progress | None = None) -> LogSource:
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
        if files and "compression_mode: message" not in meta.lower():
            from .format_rosbag import McapBagSource

            return McapBagSource(path, files)
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

        return MatSource(path, time_unit)
    from .format_csv import CsvSource

    return CsvSource(path, time_unit, progress)


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
    fmt = writable_format(path, fmt)
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
def read_flight(path: str | Path, options: ReadOptions | None = None, *,
                echo_warnings: bool = True, progress: Progress | None = None, loop_hint: bool = True,
                log: LogSource | None = None) -> FlightLog:
    """Read the signals of one loop from a flight log.

    Parameters
    ----------
    path : str or Path
        The log (any format :func:`open_log` reads).
    options : ReadOptions, optional
        How to read the loop (default ``ReadOptions()``: the altitude loop, layout recognised from the
        topics, format detected):

        * ``loop`` picks the layout's topics and turns a quaternion output into roll or pitch (ZYX
          convention, :mod:`mrftcli.io.attitude`);
        * ``command_topic`` ... ``battery_topic`` are ``TOPIC[:FIELD]`` overriding the layout
          (:data:`~mrftcli.io.layouts.LAYOUTS`); FIELD is a dotted path into the message (ULog:
          message field, ``name.N`` for instance N; CSV: column; DataFlash: ``TYPE:Column``; ``.mat``:
          the vector's name). An omitted FIELD means ``data`` for ROS topics;
        * ``output_scale`` multiplies the output and the setpoint (e.g. ``-1`` for a NED ``z`` as
          altitude, ``pi/180`` for degrees), ``command_scale`` the command (-1 for PX4's
          upward-negative thrust); None: the layout's;
        * ``layout`` is one of :data:`~mrftcli.io.layouts.LAYOUT_NAMES`; None: recognised from the
          topics (``FlightLog.source["layout"]`` says which and why);
        * ``controller_rate_hz`` [Hz] is the rate at which the relay decided, when the command may be
          logged more slowly (None: the layout's, e.g. 50 Hz for PX4's position controller; recorded
          in ``FlightLog.timing.controller_rate_hz`` for the segmenter);
        * ``fmt`` names the log format (None: detected);
        * ``time_unit`` is the unit of a CSV's time column or a ``.mat`` file's time vectors
          (:func:`open_log`). Without it a command sampled faster than 100 kHz or slower than 1 Hz is
          refused, naming the unit that makes it plausible (:mod:`mrftcli.io.clock`).
    echo_warnings : bool
        Print the reader's warnings on stderr; False keeps them in ``FlightLog.warnings`` only, for a
        caller that shows them itself (``analyze``, ``watch``).
    loop_hint : bool
        A missing layout topic's error says which option to give (``--loop`` for another loop): a
        one-loop command's; False for a caller that tries every loop itself (``batch``).
    progress : Progress, optional
        Told how far a long read is (:func:`open_log`); the CLI draws it as a bar.
    log : LogSource, optional
        The log at ``path``, open already (:func:`open_log`), for a caller that reads another topic of it too
        (``tune``'s hover thrust): read, not closed; ``echo_warnings`` and ``progress`` were its opener's.
        None: opened and closed here.

    Returns
    -------
    FlightLog
        ``command`` and ``output`` always; ``beta``, ``setpoint``, ``battery_voltage`` when logged.
        ``source`` records the layout, where each signal came from, the scales and, for PX4, the
        test windows; ``timing`` the controller rate and the stamps (header or receive, with their
        jitter).

    Raises
    ------
    InputError
        Unknown layout or format, a loop the layout does not record, a time unit for a format whose
        clock has one.
    LogReadError
        Unreadable log, or a required topic/field missing (the message lists what exists); a
        command sampled at a rate no flight stack has (a time unit mistaken).

    Examples
    --------
    >>> from mrftcli.samples import sample_log
    >>> flight = read_flight(sample_log("design1_altitude.csv"), ReadOptions(loop="altitude"))
    >>> flight.loop, flight.source["layout"].split(" ")[0]
    ('altitude', 'reference')
    """
    opts = ReadOptions() if options is None else options  # checked on creation, before the log is opened
    if log is not None:
        return replace(read_loop(log, opts, loop_hint=loop_hint), path=str(path))
    with open_log(path, opts.fmt, echo_warnings=echo_warnings, time_unit=opts.time_unit, progress=progress) as opened:
        flight = read_loop(opened, opts, loop_hint=loop_hint)
    # a ROS 2 bag folder is read through the MCAP file inside it: the flight is the folder's
    return replace(flight, path=str(path))


def list_topics(path: str | Path, fmt: str | None = None, *,
                progress: Progress | None = None) -> tuple[str, list[TopicInfo]]:
    """Format name and topics of a log (what ``mrft-ident topics`` shows); ``progress`` as :func:`open_log`."""
    with open_log(path, fmt, progress=progress) as log:
        return log.format, log.topics()
