"""Small helpers shared by the click commands: JSON output, option types, the progress bar."""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import click

from ..errors import InputError
from ..jsonable import to_jsonable
from ..progress import Progress
from ..validate import MAX_RATE_HZ, TP_MISSING, check_beta, check_tp

__all__ = ["dump_json", "BETA", "tp_option", "log_layout_options", "READ_OPTIONS", "tqdm_progress", "read_progress",
           "check_output_file", "check_output_dir", "check_export_paths", "json_option", "quiet_option", "controller_rate_option",
           "HZ", "SHARED_HELP", "min_cycles_option", "num", "text_table", "echo_warnings", "InputPath", "LogFormat",
           "deprecated_alias"]

#: Words each shared option's help contains: one wording wherever the option appears
#: (``tests/test_cli_grammar.py`` checks every command against this table; docs/usage.md lists the grammar).
SHARED_HELP: dict[str, str] = {
    "--json": "Write the result as JSON to FILE, or to stdout with '-'",
    "--controller-rate": "Controller rate [Hz]",
    "--quiet": "No progress bar",
    "--min-cycles": "stable cycles",
    "--loop": "Loop",
    "--format": "Log format",
    "--time-unit": "Unit of a CSV's time column",
    "--report": "to DIR",
    "--tp": "time constant Tp [s]",
    "--ms-max": "Limit on the sensitivity peak Ms [-]",
}

#: A rate in Hz: positive, at most the 100 kHz the readers accept (every ``--controller-rate``; 1e300 hung predict).
HZ = click.FloatRange(0, MAX_RATE_HZ, min_open=True)


def num(x: float | None, digits: int = 4) -> str:
    """``digits`` significant digits, trailing zeros kept, so a column reads alike (0.1800 beside 0.05839);
    ``-`` for None or a non-finite value.

    >>> num(0.18), num(0.058391), num(float("nan")), num(1234567.0, 3)
    ('0.1800', '0.05839', '-', '1.23e+06')
    """
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x:#.{digits}g}".rstrip(".")


def text_table(rows: Sequence[Sequence[str]], align: str = "", indent: str = "") -> list[str]:
    """The lines of a terminal table (the header rows first): each column as wide as its widest cell,
    right-aligned where ``align`` has ``>`` at its index (else left), two spaces between columns, no
    trailing spaces.

    >>> text_table([("name", "value"), ("tau", "46.4")], align="<>")
    ['name  value', 'tau    46.4']
    """
    widths = [max(len(r[k]) for r in rows if k < len(r)) for k in range(max(len(r) for r in rows))]
    return [(indent + "  ".join(c.rjust(w) if align[k:k + 1] == ">" else c.ljust(w)
                                for k, (c, w) in enumerate(zip(r, widths)))).rstrip() for r in rows]


def echo_warnings(warnings: Sequence[str]) -> None:
    """Each warning as one ``warning: ...`` line on stderr (stdout may carry the JSON)."""
    for w in warnings:
        click.echo(f"warning: {w}", err=True)


def dump_json(obj: Any, target: str | None) -> None:
    """Write ``obj`` as JSON to ``target`` (a path, or ``-`` / None for stdout).

    A file is written atomically (:func:`mrftcli.io.atomic.write_text_atomic`): a reader never sees
    half of it, and a failed write leaves the old file as it was (InputError naming the path).
    """
    from ..io.atomic import write_text_atomic

    text = json.dumps(to_jsonable(obj), indent=2, allow_nan=False)
    if target in (None, "-"):
        click.echo(text)
        return
    # again at the write, for a command that did not check first (predict, identify, topics): never through a
    # link, never over a non-JSON file, its folder created as every command's is
    check_output_file(target, "--json")
    try:
        write_text_atomic(target, text + "\n")
    except OSError as err:
        raise InputError(f"--json {target}: cannot write ({err.strerror or err}); choose a writable path") from None


class InputPath(click.Path):
    """``click.Path`` of an input that must exist: a missing one is :func:`mrftcli.io.require_input`'s error
    (exit 3, ``<path>: no such file or directory``), as analyze words it, not click's exit 2."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        from ..io import require_input

        require_input(value)
        return super().convert(value, param, ctx)


def read_json_file(path: str | Path, option: str) -> Any:
    """A JSON input file (an analysis, GAINS.json, ...) parsed with the depth limit of
    :func:`mrftcli.jsonable.load_json_text`; a one-line InputError naming ``option`` and the file when
    it cannot be read or is not JSON."""
    from ..jsonable import load_json_text

    try:
        with open(path, encoding="utf-8") as fh:
            return load_json_text(fh.read(), f"{option} {path}")
    except OSError as err:
        raise InputError(f"{option} {path}: cannot read it ({err.strerror or err})") from err
    except InputError:
        raise
    except ValueError as err:  # not JSON, or not UTF-8 text
        raise InputError(f"{option} {path}: not JSON ({err})") from err


def json_option(dest: str = "json_target", *, what: str = "result"):
    """``--json FILE|-``: the one JSON output option of every command.

    A bare ``--json`` (the old flag of identify, predict, simulate, topics and batch) means ``-``, stdout,
    so scripts written for the flag keep working. Give ``-`` explicitly before a positional argument
    (``--json - LOG``): click takes the next word as FILE.
    """
    return click.option("--json", dest, metavar="FILE|-", is_flag=False, flag_value="-", default=None,
                        help=f"{SHARED_HELP['--json']} (a bare --json is '-'); '-' prints no table. "
                             f"Holds the {what}.")


def quiet_option():
    """``-q/--quiet``: no progress bar, on every command that draws one (output otherwise the same)."""
    return click.option("-q", "--quiet", "quiet", is_flag=True,
                        help=f"{SHARED_HELP['--quiet']} (the output is otherwise the same).")


def min_cycles_option(default: int | None = 3, detail: str = ""):
    """``--min-cycles N``: the fewest stable relay cycles a test needs to be used (analyze's rule)."""
    return click.option("--min-cycles", type=click.IntRange(2, None), default=default,
                        show_default=default is not None,
                        help=f"Fewest {SHARED_HELP['--min-cycles']} for a test to be used{detail}.")


class LogFormat(click.Choice):
    """The log formats ``--format`` takes; a value in ``misnamed`` (a word a user may take for a log format, e.g. a
    stack's name) is refused with one line naming the fix it maps to, a usage error (exit 2) as click's own."""

    def __init__(self, choices: Sequence[str], misnamed: Mapping[str, str] | None = None) -> None:
        super().__init__(choices)
        self.misnamed = dict(misnamed or {})

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if value in self.misnamed:
            raise click.UsageError(f"--format {value} is not a log format (formats: {', '.join(self.choices)}); "
                                   f"{self.misnamed[value]}", ctx)
        return super().convert(value, param, ctx)


def deprecated_alias(old: str, new: str, dest: str, type: click.ParamType, *, metavar: str, default: Any = None):
    """A hidden, deprecated option ``old`` meaning what ``new`` (received as ``dest``) means.

    Returns ``(alias, merge)``: the decorator adding ``old`` and the callback to give ``new``. The alias says it
    is deprecated (one line on stderr) and hands its value on; ``merge`` refuses both names at once and applies
    ``default`` (not click, so that a given alias is told from the default).
    """
    # the alias's value in click's context meta, under this key (simulate and batch read --rate's there)
    key = f"mrftcli.{old.lstrip('-').replace('-', '_')}_alias.{dest}"

    def take(ctx: click.Context, param: click.Parameter, value: Any) -> Any:
        if value is not None:
            click.echo(f"note: {old} is deprecated; use {new} {metavar} (same meaning)", err=True)
            ctx.meta[key] = value
        return value

    def merge(ctx: click.Context, param: click.Parameter, value: Any) -> Any:
        alias = ctx.meta.get(key)
        if alias is not None and value is not None:
            raise click.BadParameter(f"give {new} only ({old} is its deprecated name)")
        return value if value is not None else alias if alias is not None else default

    # eager: the alias is processed before the new name whatever the order on the command line
    alias = click.option(old, type=type, default=None, hidden=True, expose_value=False, is_eager=True, callback=take)
    return alias, merge


def controller_rate_option(dest: str = "controller_rate_hz", *, default: float | None = None,
                           detail: str = "(default: the rate the log records)."):
    """``--controller-rate HZ`` (and the hidden, deprecated ``--rate``): the rate the controller runs at."""
    alias, merge = deprecated_alias("--rate", "--controller-rate", dest, HZ, metavar="HZ", default=default)
    main = click.option("--controller-rate", dest, type=HZ, default=None,
                        show_default=f"{default:g}" if default is not None else False,
                        metavar="HZ", callback=merge, help=f"{SHARED_HELP['--controller-rate']} {detail}")

    def decorate(func):
        return main(alias(func))

    return decorate


def _writable_dir(folder: Path, option: str, what: Path, *, create: bool = True) -> None:
    """Create ``folder`` (and its parents) if missing; InputError if that fails or it is not writable.

    ``create=False`` creates nothing: a missing folder's nearest existing parent must be a writable
    folder (the caller creates it once every other check has passed)."""
    if not create and not folder.exists():
        parent = next((p for p in folder.absolute().parents if p.exists()), Path("/"))
        if not parent.is_dir():
            raise InputError(f"{option} {what}: {parent} exists and is not a folder; choose another path")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise InputError(f"{option} {what}: cannot create the folder {folder} ({parent} is not writable); "
                             "choose a writable path")
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise InputError(f"{option} {what}: {folder} exists and is not a folder; choose another path") from None
    except OSError as err:
        raise InputError(f"{option} {what}: cannot create the folder {folder} ({err.strerror or err}); "
                         "choose a writable path") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"{option} {what}: the folder {folder} is not writable; choose a writable path")
    try:  # os.access reads the mode bits (root passes them all, /proc included): create a file to know
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        raise InputError(f"{option} {what}: cannot write in the folder {folder} ({err.strerror or err}); "
                         "choose a writable path") from None


def _given_paths(option: str) -> tuple[str, ...]:
    """Every existing path the running command was given, but through ``option`` itself: its inputs (a
    JSON ``--from``, ``--model-file``, ``--inner-model`` as much as a LOG), which no output replaces.
    ``ctx.meta`` holds what an option keeps out of the command's arguments (``--model-file``'s path)."""
    ctx = click.get_current_context(silent=True)
    if ctx is None:
        return ()
    own = {p.name for p in ctx.command.params if option in getattr(p, "opts", ())}
    given = [value for name, value in ctx.params.items() if name not in own] + list(ctx.meta.values())
    values = [v for value in given for v in (value if isinstance(value, (tuple, list)) else (value,))]
    # a Path-typed option (simulate --inner-gains) as much as a str one
    paths = [os.fspath(v) for v in values if isinstance(v, (str, os.PathLike))]
    return tuple(v for v in paths if isinstance(v, str) and v != "-" and os.path.exists(v))


def check_output_file(target: str | None, option: str = "--json", *, inputs: tuple[str, ...] = ()) -> None:
    """Check an output file before the work starts: its folder is created if missing and must be writable.

    ``None`` and ``-`` (stdout) pass. The same rule as :func:`check_output_dir`, so ``--json`` and
    ``--report`` behave alike: missing parents are created, an unwritable place is refused (exit 2)
    before minutes of analysis, not after. Never through a symbolic link, onto one of ``inputs``, or
    (``--json``) over a file that is not a JSON document (:func:`mrftcli.io.atomic.check_output_path`).
    """
    from ..io.atomic import check_output_path, looks_like_json

    if target in (None, "-"):
        return
    path = Path(target)
    json_out = option == "--json"
    inputs = (*inputs, *_given_paths(option))
    check_output_path(path, option, inputs=inputs, ours=looks_like_json if json_out else None,
                      what="a JSON document" if json_out else "")
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError(f"{option} {target}: the file is not writable; choose another path")
    _writable_dir(path.parent if str(path.parent) else Path("."), option, path)


def check_export_paths(json_target: str | None, out: str | None, exporting: bool, *,
                       inputs: tuple[str, ...] = ()) -> None:
    """``--json`` and ``--out`` checked before the work (tune, vehicle), never onto one of ``inputs`` (the
    logs or results read), ``--out`` never over a file that is not an export this tool wrote (a log, a
    ground station's own parameter file); an export and ``--json -`` cannot share stdout."""
    from ..io.atomic import check_output_path, looks_like_json

    def ours(path: Path) -> bool:  # every export is JSON or names mrft-ident in its first comment lines
        with open(path, "rb") as fh:
            head = fh.read(1024)
        # a text file: a log simulate wrote names mrft-ident in its binary header too (MCAP, ULog)
        return looks_like_json(path) or (b"\0" not in head and any(
            line.lstrip().startswith(b"#") and b"mrft-ident" in line for line in head.splitlines()))

    check_output_file(json_target, "--json", inputs=inputs)
    check_output_file(out, "--out", inputs=inputs)
    if out not in (None, "-"):
        check_output_path(out, "--out", ours=ours, what="an export (a parameter file or JSON)")
    if exporting and not out and json_target == "-":
        raise InputError("--json - and the export would both go to stdout: give --out FILE (or --json FILE)")


def check_output_dir(target: str | None, option: str = "--report", *, create: bool = True) -> None:
    """Check an output folder before the work starts: created (with its parents) if missing, writable;
    never a symbolic link (:func:`mrftcli.io.atomic.check_output_path`). ``create=False`` checks the
    same and creates nothing (a command whose own checks come later creates it after them)."""
    from ..io.atomic import check_output_path, looks_like_figure, looks_like_page

    if target is None:
        return
    check_output_path(target, option, folder=True)
    if option == "--report" and Path(target).is_dir():
        # before the work, what the report's writers would refuse after it: someone's page or figure there
        kinds = {".html": (looks_like_page, "an HTML page"), ".png": (looks_like_figure, "a figure"),
                 ".svg": (looks_like_figure, "a figure"), ".pdf": (looks_like_figure, "a figure")}
        for path in sorted(Path(target).iterdir())[:1000]:
            ours, what = kinds.get(path.suffix.lower(), (None, ""))
            if ours is not None:
                check_output_path(path, option, ours=ours, what=what)
    _writable_dir(Path(target), option, Path(target), create=create)


class _BetaType(click.ParamType):
    """A beta in the open interval (-1, 1), checked by :func:`mrftcli.validate.check_beta`."""

    name = "beta"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> float:
        try:
            return check_beta(value)
        except InputError as err:
            self.fail(str(err), param, ctx)


BETA = _BetaType()


def _positive_time(ctx: click.Context | None, param: click.Parameter | None, value: float | None) -> float | None:
    """``--tp``'s callback: :func:`mrftcli.validate.check_tp`, its message as click's BadParameter."""
    if value is None:
        if param is not None and param.required:
            # click 8.3+ passes a required option's explicit default None through to the callback
            raise click.UsageError(f"missing --tp: {TP_MISSING}", ctx)
        return None
    try:
        return check_tp(value)
    except InputError as err:
        raise click.BadParameter(str(err)) from None


def tp_option(name: str = "Tp", *, required: bool = True, help: str | None = None):
    """``--tp``: the known propulsion time constant [s], validated within its physical range."""
    return click.option(
        "--tp", name, type=float, required=required, default=None, callback=_positive_time,
        help=help or "Known propulsion time constant Tp [s] (bench test).",
    )


def _scale(ctx: click.Context | None, param: click.Parameter | None, value: float | None) -> float | None:
    """A sign/scale option: finite and non-zero, or None (the layout's)."""
    if value is not None and (value == 0 or not math.isfinite(value)):
        raise click.BadParameter(f"must be a finite, non-zero factor, got {value}")
    return value


#: The names :func:`log_layout_options` gives the command: exactly :class:`mrftcli.io.ReadOptions`'
#: fields, so a command passes them on as ``read_flight(log, ReadOptions(**read_options))``.
READ_OPTIONS = ("loop", "command_topic", "output_topic", "beta_topic", "setpoint_topic", "output_scale",
                "command_scale", "layout", "controller_rate_hz", "fmt", "time_unit")


def log_layout_options(*, config_defaults: bool = False, only: tuple[str, ...] | None = None,
                       format_alias: str | None = None, format_misnamed: Mapping[str, str] | None = None):
    """The options that say how to read a loop from a log, shared by every command that reads one.

    ``--format``, ``--layout``, ``--loop``, ``--command-topic``, ``--output-topic``, ``--beta-topic``,
    ``--setpoint-topic``, ``--output-scale``, ``--command-scale``, ``--controller-rate`` and ``--time-unit``
    (not for batch); the command receives them under
    the names of :data:`READ_OPTIONS` (those of :func:`mrftcli.io.read_flight`). With
    ``config_defaults`` (batch) ``--loop`` defaults to None so that a per-log config file can fill it,
    and may be repeated; batch finds its logs by name and has no ``--format``. ``only``: those of these options
    (by the names they are received under) a command takes (vehicle: those that apply to a whole flight, ``fmt``,
    ``layout``, ``controller_rate_hz``, ``time_unit``). ``format_alias``: a hidden, deprecated old name of
    ``--format`` (:func:`deprecated_alias`); ``format_misnamed``: values refused with their fix (:class:`LogFormat`).
    """
    from ..io import LAYOUT_NAMES, READ_FORMATS, TIME_UNITS
    from ..io.logtypes import LOOPS

    if config_defaults:
        loop = click.option("--loop", multiple=True, type=click.Choice((*LOOPS, "auto")),
                            help="Loop to identify; repeat for several; auto: every loop whose topics the log "
                                 "holds, a loop without relay tests skipped (default: auto; overrides "
                                 "the config).")
    else:
        loop = click.option("--loop", type=click.Choice(LOOPS), default="altitude", show_default=True,
                            help="Loop the log's MRFT tests excite.")
    options = [
        ("loop", loop),
        ("layout", click.option("--layout", type=click.Choice(LAYOUT_NAMES), default=None,
                     help="Where the flight stack records the loop (default: recognised from the topics; "
                          "see docs/log-layout.md).")),
        ("command_topic", click.option("--command-topic", metavar="TOPIC[:FIELD]", default=None,
                                       help="Command the MRFT block sent (default: the layout's, /mrft/command).")),
        ("output_topic", click.option("--output-topic", metavar="TOPIC[:FIELD]", default=None,
                                      help="Loop output (default: the layout's, e.g. /mocap/pose or /imu/data).")),
        ("beta_topic", click.option("--beta-topic", metavar="TOPIC[:FIELD]", default=None,
                                    help="Beta published at each test start (default: the layout's, /mrft/beta).")),
        ("setpoint_topic", click.option("--setpoint-topic", metavar="TOPIC[:FIELD]", default=None,
                                        help="Loop setpoint (default: the layout's, /mrft/setpoint).")),
        ("output_scale", click.option(
            "--output-scale", type=float, default=None, callback=_scale,
            help="Factor applied to output and setpoint (default: the layout's, 1 or -1 for NED z; e.g. 0.0174533 "
                 "for degrees).")),
        ("command_scale", click.option(
            "--command-scale", type=float, default=None, callback=_scale,
            help="Factor applied to the command (default: the layout's, 1 or -1 for PX4's thrust).")),
        ("controller_rate_hz", controller_rate_option(detail="at which the relay decided, when the log records the "
                                                             "command more slowly (default: the layout's, 50 Hz for "
                                                             "px4-mrft).")),
    ]
    if not config_defaults:
        options.append(("time_unit", click.option(
            "--time-unit", type=click.Choice(list(TIME_UNITS)), default=None,
            help="Unit of a CSV's time column or a .mat file's time vectors (default: the column's name "
                 "says, else s); a log whose command rate is below 1 Hz or above 100 kHz is refused "
                 "with the unit that fits.")))
        options.insert(0, ("fmt", _format_option(READ_FORMATS, format_alias, format_misnamed)))
    chosen = [option for name, option in options if only is None or name in only]

    def decorate(func):
        if not config_defaults and (only is None or "loop" in only):
            func = _process_loop(func)
        for option in reversed(chosen):
            func = option(func)
        return func

    return decorate


def _format_option(formats: Sequence[str], alias_name: str | None, misnamed: Mapping[str, str] | None):
    """``--format FMT`` (received as ``fmt``), with its hidden old name ``alias_name`` when one is given."""
    if alias_name is None:
        return click.option("--format", "fmt", type=LogFormat(formats, misnamed), default=None,
                            help="Log format (default: detected from the file).")
    alias, merge = deprecated_alias(alias_name, "--format", "fmt", click.Choice(formats), metavar="FMT")
    main = click.option("--format", "fmt", type=LogFormat(formats, misnamed), default=None, callback=merge,
                        help=f"Log format (default: detected from the file; {alias_name}, its old name, still works).")
    return lambda func: main(alias(func))


def _process_loop(func):
    """``func`` that reads a process plant's log (``--model NAME`` or ``--model-file``) as the loop ``process``
    when ``--loop`` is not given (:data:`~mrftcli.io.logtypes.PROCESS_LOOP`): its records say the loop the user
    named, or ``process``, never the vehicle default ``altitude`` (compare printed KSTAR's rows as altitude)."""
    import functools

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        from ..io.logtypes import PROCESS_LOOP

        ctx = click.get_current_context()
        if (kwargs.get("model_name", "soiptd") != "soiptd" and kwargs.get("loop") == "altitude"
                and ctx.get_parameter_source("loop") is click.core.ParameterSource.DEFAULT):
            kwargs["loop"] = PROCESS_LOOP
        return func(*args, **kwargs)
    return wrapper


@contextlib.contextmanager
def tqdm_progress(desc: str, *, unit: str = "it", enabled: bool = True, after_s: float = 0.0,
                  unit_scale: bool = False) -> Iterator[Progress]:
    """A :class:`~mrftcli.progress.Progress` callback that draws a tqdm bar on stderr.

    The bar is drawn only on a terminal (and when ``enabled``), so piped and captured output is the
    same with or without it; it is removed when the block ends. ``total`` may change between calls
    (a library function that learns its amount of work as it goes); ``stage`` is shown after the bar.
    ``after_s`` [s]: nothing is drawn until the work has taken that long (a bar that would flash
    for a fast file is noise); ``unit_scale``: counts shown with k/M/G prefixes (bytes).

    Examples
    --------
    >>> with tqdm_progress("demo", unit="log") as progress:   # not a terminal here: draws nothing
    ...     progress(1, 2, "first.mcap")
    """
    from tqdm import tqdm

    bar = tqdm(total=None, desc=desc, unit=unit, file=sys.stderr, disable=None if enabled else True,
               leave=False, dynamic_ncols=True, unit_scale=unit_scale, delay=after_s)
    start = time.monotonic()

    def progress(done: float, total: float, stage: str = "") -> None:
        if bar.disable or time.monotonic() - start < after_s:
            return
        bar.total = total
        bar.n = done
        if stage:
            bar.set_postfix_str(stage, refresh=False)
        bar.refresh()

    try:
        yield progress
    finally:
        bar.close()


#: A read shorter than this [s] draws no bar (:func:`read_progress`).
READ_BAR_AFTER_S = 2.0


@contextlib.contextmanager
def read_progress(enabled: bool = True) -> Iterator[Progress]:
    """The bar of a long log read (bytes of the file; a large CSV's passes), drawn once the read has
    taken :data:`READ_BAR_AFTER_S` seconds: a file that reads in a blink shows nothing.

    Examples
    --------
    >>> with read_progress() as progress:   # not a terminal here: draws nothing
    ...     progress(1 << 20, 1 << 30, "reading 2 column(s)")
    """
    with tqdm_progress("reading", unit="B", enabled=enabled, after_s=READ_BAR_AFTER_S, unit_scale=True) as progress:
        yield progress
