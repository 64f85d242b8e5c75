"""Small helpers shared by the click commands (output formatting, option types)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import click
import numpy as np

__all__ = ["to_jsonable", "dump_json", "BETA", "tp_option", "log_layout_options"]


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays, dataclasses' dicts and NaN into plain JSON values (NaN -> None)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [to_jsonable(v) for v in obj.tolist()]
    if isinstance(obj, (np.floating, float)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def dump_json(obj: Any, target: str | None) -> None:
    """Write ``obj`` as JSON to ``target`` (a path, or ``-`` / None for stdout)."""
    text = json.dumps(to_jsonable(obj), indent=2, allow_nan=False)
    if target in (None, "-"):
        click.echo(text)
    else:
        Path(target).write_text(text + "\n")


class _BetaType(click.ParamType):
    """A beta in the open interval (-1, 1)."""

    name = "beta"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> float:
        try:
            beta = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not -1.0 < beta < 1.0:
            self.fail(f"beta must lie in the open interval (-1, 1), got {beta}", param, ctx)
        return beta


BETA = _BetaType()


def _positive_time(ctx: click.Context | None, param: click.Parameter | None, value: float | None) -> float | None:
    if value is None:
        return None
    if not math.isfinite(value) or value <= 0:
        raise click.BadParameter(f"Tp must be a positive time in seconds, got {value}")
    return value


def tp_option(name: str = "Tp", *, required: bool = True, help: str | None = None):
    """``--tp``: the known propulsion time constant [s], validated positive."""
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
