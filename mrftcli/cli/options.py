"""Small helpers shared by the click commands: JSON output, option types, the progress bar."""

from __future__ import annotations

import contextlib
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import click

from ..errors import InputError
from ..jsonable import to_jsonable
from ..progress import Progress
from ..validate import check_beta, check_tp

__all__ = ["dump_json", "BETA", "tp_option", "log_layout_options", "tqdm_progress"]


def dump_json(obj: Any, target: str | None) -> None:
    """Write ``obj`` as JSON to ``target`` (a path, or ``-`` / None for stdout)."""
    text = json.dumps(to_jsonable(obj), indent=2, allow_nan=False)
    if target in (None, "-"):
        click.echo(text)
    else:
        Path(target).write_text(text + "\n")


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


def log_layout_options(*, config_defaults: bool = False):
    """The options that say where a loop's signals are in a log, shared by analyze, diagnose and batch.

    ``--loop``, ``--command-topic``, ``--output-topic``, ``--beta-topic``, ``--setpoint-topic`` and
    ``--output-scale``. With ``config_defaults`` (batch) every option defaults to None so that a
    per-log config file can fill it, and ``--loop`` may be repeated.
    """
    from ..io.logtypes import LOOPS

    if config_defaults:
        loop = click.option("--loop", multiple=True, type=click.Choice(LOOPS),
                            help="Loop to identify; repeat for several (default: altitude; overrides the config).")
        scale = click.option("--output-scale", type=float, default=None,
                             help="Factor applied to output and setpoint (default 1; e.g. -1 for NED z).")
    else:
        loop = click.option("--loop", type=click.Choice(LOOPS), default="altitude", show_default=True,
                            help="Which loop the log's MRFT tests excite.")
        scale = click.option("--output-scale", type=float, default=1.0, show_default=True,
                             help="Factor applied to output and setpoint (e.g. -1 for NED z, 0.0174533 for degrees).")
    options = [
        loop,
        click.option("--command-topic", metavar="TOPIC[:FIELD]", default=None,
                     help="Command the MRFT block sent (default /mrft/command)."),
        click.option("--output-topic", metavar="TOPIC[:FIELD]", default=None,
                     help="Loop output (default by loop: /mocap/pose or /imu/data)."),
        click.option("--beta-topic", metavar="TOPIC[:FIELD]", default=None,
                     help="Beta published at each test start (default /mrft/beta)."),
        click.option("--setpoint-topic", metavar="TOPIC[:FIELD]", default=None,
                     help="Loop setpoint (default /mrft/setpoint)."),
        scale,
    ]

    def decorate(func):
        for option in reversed(options):
            func = option(func)
        return func

    return decorate


@contextlib.contextmanager
def tqdm_progress(desc: str, *, unit: str = "it", enabled: bool = True) -> Iterator[Progress]:
    """A :class:`~mrftcli.progress.Progress` callback that draws a tqdm bar on stderr.

    The bar is drawn only on a terminal (and when ``enabled``), so piped and captured output is the
    same with or without it; it is removed when the block ends. ``total`` may change between calls
    (a library function that learns its amount of work as it goes); ``stage`` is shown after the bar.

    Examples
    --------
    >>> with tqdm_progress("demo", unit="log") as progress:   # not a terminal here: draws nothing
    ...     progress(1, 2, "first.mcap")
    """
    from tqdm import tqdm

    bar = tqdm(total=None, desc=desc, unit=unit, file=sys.stderr, disable=None if enabled else True,
               leave=False, dynamic_ncols=True)

    def progress(done: float, total: float, stage: str = "") -> None:
        if bar.disable:
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
