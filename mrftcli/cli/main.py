"""The ``mrft-ident`` command: a thin click layer over the library.

Each subcommand lives in ``mrftcli/cli/<name>.py`` and is imported only when it runs, so
``mrft-ident --help`` stays fast and one command's heavy imports (matplotlib, dask) never slow another.
Errors from :mod:`mrftcli.errors` become one line on stderr and the exit code of their class; any other
exception is reported as an internal error in one line (``--debug`` shows the traceback).
"""

from __future__ import annotations

import difflib
import importlib
import os
import sys
from pathlib import Path

import click

from .._version import __version__
from ..errors import MrftError
from .options import echo_warnings

__all__ = ["main", "cli"]

#: name -> (module under mrftcli.cli, attribute, one-line help shown by ``mrft-ident --help``)
COMMANDS: dict[str, tuple[str, str, str]] = {
    "analyze": ("analyze", "analyze", "Segment MRFT tests in a flight log, identify Td, tau and K, report."),
    "diagnose": ("diagnose", "diagnose", "Find where the identified model and the log disagree, and why."),
    "batch": ("batch", "batch", "Analyse many logs, on local processes or a Dask cluster."),
    "identify": ("identify", "identify", "Identify Td, tau (and K) from measured limit-cycle figures."),
    "predict": ("predict", "predict", "Predict the exact MRFT limit cycle (frequency, amplitude) of a model."),
    "build-ufm": ("build_ufm", "build_ufm", "Build unit frequency / unit gain manifolds for given betas."),
    "simulate": ("simulate", "simulate", "Simulate an MRFT flight and write it as a log with a ground-truth sidecar."),
    "topics": ("topics", "topics", "List the topics (or messages/columns) of a log with counts and rates."),
    "watch": ("watch", "watch", "Follow a log while it is recorded: tests and estimates as cycles arrive."),
    "plan": ("plan", "plan", "Recommend the next MRFT test(s) (beta, h, duration) from a prior or a first test."),
    "tune": ("tune", "tune", "PD/PID gains from the identified model (MRFT rule, model-based, robust) and exports."),
    "compare": ("compare", "compare", "Compare identified loops against a baseline: changes, significance, CI exit code."),
    "delay": ("delay", "delay", "The delay a change added: two recordings of one loop identified together (one Td, K)."),
    "vehicle": ("vehicle", "vehicle", "Every loop of one flight: identify (inner loops first), tune, and the tests still to fly."),
}


class _LazyGroup(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in COMMANDS:
            return None
        module_name, attr, _ = COMMANDS[cmd_name]
        module = importlib.import_module(f"mrftcli.cli.{module_name}")
        command: click.Command = getattr(module, attr)
        return command

    def resolve_command(
        self, ctx: click.Context, args: list[str]
    ) -> tuple[str | None, click.Command | None, list[str]]:
        # A misspelt command ("analyse", the British spelling the docs' prose uses) gets a suggestion.
        name = args[0] if args else ""
        if name and not name.startswith("-") and name not in COMMANDS:
            close = difflib.get_close_matches(name, list(COMMANDS), n=1, cutoff=0.6)
            hint = f": did you mean '{close[0]}'?" if close else ""
            raise click.UsageError(f"no command '{name}'{hint}", ctx)
        return super().resolve_command(ctx, args)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        # Short help without importing every command module.
        rows = [(name, help_) for name, (_, _, help_) in COMMANDS.items()]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


@click.group(cls=_LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mrft-ident")
@click.option("--debug", is_flag=True, help="Show full tracebacks instead of one-line errors.")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """Identify multirotor loop models (Td, tau, K) from MRFT flight logs.

    Typical use: ``mrft-ident analyze LOG --tp 0.0422 --loop altitude``.
    """
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug


def _matplotlib_font_cache_missing() -> bool:
    """True when matplotlib has no font cache yet (its first import then takes 10-40 s to build one).

    Looked up without importing matplotlib: ``$MPLCONFIGDIR``, else ``$XDG_CACHE_HOME/matplotlib``, else
    ``~/.cache/matplotlib`` (matplotlib's own order on Linux and macOS).
    """
    configured = os.environ.get("MPLCONFIGDIR")
    if configured:
        cache = Path(configured)
    else:
        cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "matplotlib"
    return not any(cache.glob("fontlist-v*.json"))


#: Commands that import matplotlib (directly, or through python-control).
_PLOTTING = {"analyze", "diagnose", "tune", "batch", "plan", "watch", "compare", "simulate"}


def _command(args: list[str]) -> str:
    """``mrft-ident COMMAND`` for a message (the first argument that names a command)."""
    name = next((a for a in args if a in COMMANDS), None)
    return f"mrft-ident {name}" if name else "mrft-ident"


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the CLI and map errors to one line and an exit code."""
    args = sys.argv[1:] if argv is None else argv
    if not args:  # bare mrft-ident: its help, as --help gives it (not inside an error)
        args = ["--help"]
    debug = "--debug" in args
    if (any(a in _PLOTTING for a in args[:2]) and not {"-h", "--help"} & set(args)
            and _matplotlib_font_cache_missing()):
        click.echo("note: first run: matplotlib is building its font cache (once, 10-40 s)", err=True)
    try:
        cli.main(args=args, prog_name="mrft-ident", standalone_mode=False)
    except (click.exceptions.Abort, KeyboardInterrupt):  # Ctrl-C: worded as watch words it
        click.echo(f"interrupted: stopped {_command(args)} (Ctrl-C)", err=True)
        sys.exit(130)
    except click.ClickException as err:
        # One line, naming the problem and where help is, instead of click's three-line usage block.
        ctx = err.ctx if isinstance(err, click.UsageError) else None
        where = f" (see '{ctx.command_path} --help')" if ctx is not None else ""
        click.echo(f"error: {err.format_message()}{where}", err=True)
        sys.exit(err.exit_code)
    except MrftError as err:
        if debug:
            raise
        echo_warnings(err.warnings)  # what was warned of before the error (delay's assumed rate), then the error
        click.echo(f"error: {err}", err=True)
        sys.exit(err.exit_code)
    except OSError as err:
        # A path the user gave cannot be written or read (permissions, missing folder, full disk).
        if debug:
            raise
        where = f"{err.filename}: " if err.filename else ""
        click.echo(f"error: {where}{err.strerror or err}", err=True)
        sys.exit(2)
    except Exception as err:  # noqa: BLE001 - last line of defence: never a traceback for users
        if debug:
            raise
        click.echo(f"internal error: {type(err).__name__}: {err} (run with --debug for details)", err=True)
        sys.exit(1)
    sys.exit(0)
