"""Small helpers shared by the click commands (output formatting, option types)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import click
import numpy as np

__all__ = ["to_jsonable", "dump_json", "BETA"]


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
