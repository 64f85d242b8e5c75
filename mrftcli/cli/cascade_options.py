"""``analyze LOG --loop x|y --inner-model RESULT.json --inner-gains GAINS.json``: an outer loop through its inner loop.

The options and their handling; ``cli/analyze.py`` pops them (:func:`pop_cascade_options`), builds the
cascade (:func:`cascade_setup`) and runs the one analyze route. The maths is :mod:`mrftcli.analyze.cascade`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping

import click

from .options import read_json_file

__all__ = ["cascade_options", "outer_options", "CascadeRequest", "pop_cascade_options", "cascade_setup"]

_KEYS = ("inner_model", "inner_gains", "outer_command", "inner_draws")


def outer_options(needs: str, commands: str) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """``--outer-command`` and ``--inner-draws`` of an outer loop identified through its inner loop, as
    ``analyze`` (with ``--inner-model``) and ``vehicle`` (with ``--inner-gains``) spell them."""
    def decorate(f: Callable[..., Any]) -> Callable[..., Any]:
        f = click.option("--inner-draws", "inner_draws", type=click.IntRange(0, 1000), default=30, show_default=True,
                         metavar="N",
                         help=f"With {needs}: draws of the inner model solved to carry its uncertainty into "
                              "the outer estimate (0: take it as exact).")(f)
        return click.option("--outer-command", "outer_command",
                            type=click.Choice(["acceleration", "attitude", "identify"]), default="acceleration",
                            show_default=True,
                            help=f"With {needs}: what the outer {commands}, an acceleration [m/s^2] (K = 1) or an "
                                 "attitude [rad] (K = g = 9.81), or identify K (two betas needed). Stated in the "
                                 "output.")(f)
    return decorate


def cascade_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """The click options of the cascade route (``--inner-model``, ``--inner-gains``, ``--outer-command``, ``--inner-draws``)."""
    f = outer_options("--inner-model", "relay commands")(f)
    f = click.option("--inner-gains", "inner_gains", metavar="GAINS.json", type=click.Path(dir_okay=False),
                     help="With --inner-model: the inner controller flown during the outer tests, "
                          '{"roll": {"Kp", "Ki", "Kd", "Tf", "rate_hz"}} (roll for y, pitch for x); tune '
                          "--export generic or tune --json output is read too. See docs/cascade.md.")(f)
    f = click.option("--inner-model", "inner_model", metavar="RESULT.json", type=click.Path(dir_okay=False),
                     help="Analyse --loop x|y through the closed inner loop: the inner (roll for y, pitch for x) "
                          "loop's analyze --json result. See docs/cascade.md.")(f)
    return f


@dataclass(frozen=True)
class CascadeRequest:
    """The cascade options as given (None: not given).

    Attributes
    ----------
    inner_model, inner_gains : str or None
        The paths of the inner analysis and of the gains file.
    outer_command : str
        ``"acceleration"``, ``"attitude"`` or ``"identify"``.
    inner_draws : int
        Draws of the inner model.
    """

    inner_model: str | None
    inner_gains: str | None
    outer_command: str
    inner_draws: int

    @property
    def requested(self) -> bool:
        """Was the cascade route asked for (either file given)?"""
        return self.inner_model is not None or self.inner_gains is not None


def pop_cascade_options(options: dict[str, Any]) -> CascadeRequest:
    """Take the cascade options out of a command's keyword arguments (the rest are the reader's)."""
    values = {k: options.pop(k, None) for k in _KEYS}
    return CascadeRequest(values["inner_model"], values["inner_gains"], values["outer_command"] or "acceleration",
                          int(values["inner_draws"] if values["inner_draws"] is not None else 30))


def _check(request: CascadeRequest, loop: str, unsupported: Mapping[str, Any]) -> str:
    """The inner loop's name; one-line errors naming the option otherwise."""
    from ..mrft.cascade import INNER_LOOP_OF

    if loop not in INNER_LOOP_OF:
        raise click.UsageError(f"--inner-model and --inner-gains take an outer loop: --loop x or y (got --loop {loop})")
    inner = INNER_LOOP_OF[loop]
    if request.inner_model is None:
        raise click.UsageError(f"--inner-gains needs --inner-model RESULT.json: the {inner} loop's analyze --json result")
    if request.inner_gains is None:
        raise click.UsageError(f"--inner-model needs --inner-gains GAINS.json: the gains the {inner} loop flew during "
                               f"the {loop} tests")
    used = [name for name, value in unsupported.items() if value]
    if used:
        raise click.UsageError(f"{', '.join(used)}: not with --inner-model (the cascade) yet")
    return inner


def cascade_setup(request: CascadeRequest, loop: str, unsupported: Mapping[str, Any]) -> tuple[Any, Any]:
    """The cascade to identify and its analysis options, from the inner analysis and the gains flown.

    ``analyze`` then runs the one route (:func:`mrftcli.analyze.analyze_flight`) and writes its outputs
    as for every model. One-line errors naming the option on a missing or unreadable file.
    """
    from ..analyze import CascadeOptions
    from ..analyze.cascade import cascade_model, inner_draws, inner_gains_of, inner_loop_of
    from ..analyze.record import AnalysisResult

    inner_name = _check(request, loop, unsupported)
    result = AnalysisResult.from_json(read_json_file(request.inner_model or "", "--inner-model"))
    controller = inner_gains_of(read_json_file(request.inner_gains or "", "--inner-gains"), inner_name)
    inner = inner_loop_of(result, controller, inner_name)
    return cascade_model(inner, request.outer_command), CascadeOptions(
        draws=tuple(inner_draws(result, inner, request.inner_draws)),
        assumptions=(f"inner model from {request.inner_model}",))
