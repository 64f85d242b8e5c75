"""``--model``, ``--param``, ``--range``, ``--window``, ``--relay``, ``--eps``: the plant structure and relay options.

Shared by the commands that take or produce a model (``analyze``, ``identify``, ``predict``), and the
one terminal table of parameters (:func:`parameter_lines`).

The cascade's (``analyze LOG --loop x|y --inner-model RESULT.json --inner-gains GAINS.json``: an outer
loop through its inner loop): ``cli/analyze.py`` pops them (:func:`pop_cascade_options`), builds the
cascade (:func:`cascade_setup`) and runs the one analyze route; the maths is :mod:`mrftcli.analyze.cascade`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import click

from ..errors import InputError
from ..validate import check_parameter_value
from .options import num, read_json_file, text_table

if TYPE_CHECKING:
    from ..mrft.identify_lti import LtiIdentification
    from ..mrft.parameter import ParameterEstimate

__all__ = ["MODEL_NAMES", "structure_text", "check_soiptd_options", "soiptd_or_process", "process_model", "structure_options", "window_option", "relay_options",
           "parse_params", "parse_number", "parse_windows", "build_model", "format_estimates", "parameter_lines",
           "format_combination", "cascade_options", "outer_options", "CascadeRequest", "pop_cascade_options", "cascade_setup",
           "parameter_display"]

#: the families ``--model`` takes (eq. (2) first: the default)
MODEL_NAMES = ("soiptd", "fopdt", "sopdt", "ipdt", "foipdt")


#: ``model_name`` when ``--model-file`` declared the structure (the file's path is in the context's meta)
DECLARED = "declared"
_META_KEY = "mrftcli.model_file"
_MODEL_HELP = ("Plant structure: soiptd (eq. (2), Tp known), fopdt K e^{-tau s}/(T s+1), sopdt "
               "K e^{-tau s}/((T1 s+1)(T2 s+1)), ipdt K e^{-tau s}/s, foipdt K e^{-tau s}/(s (T s+1)).")
_MODEL_FILE_HELP = ("A plant structure you declare: a TOML/JSON file with transfer_function = \"K*exp(-tau*s)/"
                    "(T*s+1)**2\" (or numerator/denominator/delay) and [parameters] NAME = {value = V} (known) "
                    "or {range = [LO, HI]} (to identify); see docs/process-plants.md.")


def _explicit(ctx: click.Context, name: str) -> bool:
    source = ctx.get_parameter_source(name)
    return source is not None and source.name == "COMMANDLINE"


def _model_file_seen(ctx: click.Context, param: click.Parameter, value: str | None) -> None:
    """Keep the file's path for :func:`build_model` (the commands see ``model_name == DECLARED``)."""
    if value is None:
        return
    if ctx.params.get("model_name") not in (None, "soiptd") or (
            "model_name" in ctx.params and _explicit(ctx, "model_name")):
        raise InputError("give --model NAME or --model-file FILE, not both")
    ctx.meta[_META_KEY] = value


def _model_seen(ctx: click.Context, param: click.Parameter, value: str) -> str:
    """``--model``, or :data:`DECLARED` after a ``--model-file`` (click processes the options given on the
    command line first, in their order, then the others: a --model-file given is always seen here)."""
    if _META_KEY in ctx.meta:
        if value != "soiptd" or _explicit(ctx, "model_name"):
            raise InputError("give --model NAME or --model-file FILE, not both")
        return DECLARED
    return value


def model_option(f: Callable[..., Any]) -> Callable[..., Any]:
    """``--model NAME`` (default soiptd, eq. (2) with Tp known) and ``--model-file FILE`` (a declared structure).

    ``--model-file`` does not reach the command as an argument: the command receives
    ``model_name == DECLARED`` and :func:`build_model` reads the file (the commands keep one switch on
    ``model_name``).
    """
    f = click.option("--model-file", "model_file", type=click.Path(dir_okay=False), default=None, metavar="FILE",
                     expose_value=False, callback=_model_file_seen, help=_MODEL_FILE_HELP)(f)
    return click.option("--model", "model_name", type=click.Choice(MODEL_NAMES), default="soiptd",
                        show_default=True, callback=_model_seen, help=_MODEL_HELP)(f)


def process_model(model_name: str, params: Sequence[str], ranges: Sequence[str]) -> Any:
    """The process model of ``--model NAME``/``--model-file`` with ``--param``/``--range`` (None: eq. (2), none was
    asked for), for the commands whose eq. (2) route takes no model options (``tune``, ``batch``).

    Raises
    ------
    InputError
        ``--param``/``--range`` without a process model.
    """
    if model_name == "soiptd":
        if params or ranges:
            raise InputError("--param/--range are for a process model: give --model NAME (fopdt, sopdt, ipdt, "
                             "foipdt) or --model-file FILE")
        return None
    return build_model(model_name, params, ranges)


def structure_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """``--model``, ``--param NAME=VALUE`` (known, the paper's set E), ``--range NAME=LO:HI`` (set I)."""
    f = click.option("--range", "ranges", multiple=True, metavar="NAME=LO:HI",
                     help="Admissible range of an unknown parameter (the paper's set I), in its unit "
                          "(s for times). Repeatable. Process models only.")(f)
    f = click.option("--param", "params", multiple=True, metavar="NAME=VALUE",
                     help="A known parameter (the paper's set E), in its unit (s for times). Repeatable. "
                          "Process models only.")(f)
    return model_option(f)


def window_option(f: Callable[..., Any]) -> Callable[..., Any]:
    """``--window T0:T1`` (repeatable): parts of the log to use, in seconds from the log start."""
    return click.option("--window", "windows", multiple=True, metavar="T0:T1",
                        help="Use only this part of the log [s from the log start, as the tables show]. "
                             "Repeatable.")(f)


def relay_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """``--relay KIND`` and ``--eps EPS``: state the relay instead of inferring it (process models)."""
    f = click.option("--eps", type=float, default=None,
                     help="Relay hysteresis [output units] (with --relay hysteresis); default: read from the "
                          "output at the switches.")(f)
    return click.option("--relay", "relay_kind", type=click.Choice(("mrft", "ideal", "hysteresis")), default=None,
                        help="Relay type; default: inferred per test (a logged beta: mrft; a switching level "
                             "beyond the sampling lag: hysteresis; else ideal).")(f)


def baseline_option(f: Callable[..., Any]) -> Callable[..., Any]:
    """``--baseline Y0[:STD]`` or ``--baseline-topic``: the operating point that lets a biased relay's mean
    levels measure K."""
    f = click.option("--baseline-topic", "baseline_topic", metavar="TOPIC[:FIELD]", default=None,
                     help="Process models: the logged operating point (e.g. the ambient temperature) instead of "
                          "--baseline: each stable cycle's own mean of it is that cycle's Y0.")(f)
    return click.option("--baseline", "baseline", metavar="Y0[:STD]", default=None,
                        help="Process models: the output with the command at 0 (a heater off: the ambient "
                             "temperature) [output units], with its standard deviation after ':' (default: "
                             "exact). A biased relay's mean levels then measure the static gain K = (mean "
                             "output - Y0) / mean command, one more constraint of the fit.")(f)


def parse_baseline(text: str | None) -> tuple[float, float] | None:
    """``Y0[:STD]`` of ``--baseline`` as (Y0, STD); None when not given."""
    if text is None:
        return None
    head, _, tail = text.partition(":")
    y0 = parse_number(head, "--baseline")
    std = parse_number(tail, "--baseline STD") if tail else 0.0
    if std < 0:
        raise InputError(f"--baseline: the standard deviation must be >= 0, got {std:g}")
    return y0, std


def parse_number(text: str, what: str) -> float:
    """An option's number as text -> float; a one-line InputError naming ``what`` if it is not a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{what}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise InputError(f"{what}: {text!r} must be finite")
    return value


def parse_params(items: Sequence[str]) -> dict[str, float]:
    """``NAME=VALUE`` items -> {name: value} (one-line InputError on a bad item)."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise InputError(f"--param {item!r}: expected NAME=VALUE, e.g. --param tau=0.05")
        out[name.strip()] = check_parameter_value(f"--param {name.strip()}", parse_number(value, f"--param {name.strip()}"))
    return out


def parse_ranges(items: Sequence[str]) -> dict[str, tuple[float, float]]:
    """``NAME=LO:HI`` items -> {name: (lo, hi)}."""
    out = {}
    for item in items:
        name, sep, span = item.partition("=")
        lo, sep2, hi = span.partition(":")
        if not (sep and sep2 and name.strip()):
            raise InputError(f"--range {item!r}: expected NAME=LO:HI, e.g. --range T=0.01:10")
        out[name.strip()] = (check_parameter_value(f"--range {name}", parse_number(lo, f"--range {name}")),
                             check_parameter_value(f"--range {name}", parse_number(hi, f"--range {name}")))
    return out


def parse_windows(items: Sequence[str], t0: float) -> list[tuple[float, float]]:
    """``T0:T1`` items [s from the log start] -> absolute (start, end) [s, log clock]."""
    out = []
    for item in items:
        a, sep, b = item.partition(":")
        if not sep:
            raise InputError(f"--window {item!r}: expected T0:T1 in seconds from the log start, e.g. --window 2:3")
        lo, hi = parse_number(a, "--window"), parse_number(b, "--window")
        if not hi > lo:
            raise InputError(f"--window {item!r}: the end must be after the start")
        out.append((t0 + lo, t0 + hi))
    return out


def check_soiptd_options(Tp: float | None, process_options: Mapping[str, bool], eq2_takes: str) -> None:
    """Eq. (2) (``--model soiptd``) needs ``--tp``, and the options of a process model do not apply to it.

    ``process_options`` maps each such option's name to whether it was given; ``eq2_takes`` ends the
    refusal with what eq. (2) takes instead (e.g. ``"takes --tp and reads beta from the log"``).
    """
    if Tp is None:
        raise click.UsageError("Missing option '--tp' (the known propulsion time constant of --model soiptd).")
    used = [name for name, given in process_options.items() if given]
    if used:
        names = ", ".join(used[:-1]) + (" and " if len(used) > 1 else "") + used[-1]
        verb = "take" if len(used) > 1 else "takes"
        raise click.UsageError(f"{names} {verb} a process model (--model fopdt, sopdt, ipdt, foipdt or --model-file); "
                               f"eq. (2) {eq2_takes}")


def soiptd_or_process(Tp: float | None, model_name: str, params: Sequence[str], ranges: Sequence[str],
                      relay_kind: str | None, eps: float | None, refused: Mapping[str, bool] | None = None) -> Any:
    """The model of ``--model``: eq. (2) at ``--tp`` (``--param``, ``--range``, ``--relay``, ``--eps`` and the
    command's own ``refused`` options, e.g. diagnose's ``--window``, refused: :func:`check_soiptd_options`), or
    the process model (:func:`build_model`; ``--tp`` refused, never silently ignored)."""
    if model_name != "soiptd":
        if Tp is not None:
            raise click.UsageError("--tp is eq. (2)'s (--model soiptd); a process model's known parameters are "
                                   "--param NAME=VALUE")
        return build_model(model_name, params, ranges)
    check_soiptd_options(Tp, {"--param": bool(params), "--range": bool(ranges), **(refused or {}),
                              "--relay": bool(relay_kind), "--eps": eps is not None},
                         "takes --tp and reads beta from the log")
    from ..mrft.model import soiptd_model
    from ..validate import check_tp

    assert Tp is not None  # refused above
    return soiptd_model(check_tp(Tp))


def build_model(model_name: str, params: Sequence[str], ranges: Sequence[str]) -> Any:
    """The process model of ``--model``/``--param``/``--range``, or of ``--model-file`` (not for soiptd).

    With a model file, ``--param`` and ``--range`` override its parameters' values and ranges.
    """
    if model_name == DECLARED:
        return _declared(params, ranges)
    from ..mrft.families import family_model

    return family_model(model_name, parse_params(params), parse_ranges(ranges))


def _declared(params: Sequence[str], ranges: Sequence[str]) -> Any:
    from ..mrft.model_file import declared_model, load_model_file

    path = click.get_current_context().meta[_META_KEY]
    model = load_model_file(path)
    if not (params or ranges):
        return model
    extra_known, extra_ranges = parse_params(params), parse_ranges(ranges)
    names = {n for n, _ in model.values}
    bad = sorted((set(extra_known) | set(extra_ranges)) - names)
    if bad:
        raise InputError(f"--param/--range {', '.join(bad)}: not a parameter of {path} ({', '.join(sorted(names))})")
    known = {n: v for n, v in model.values if n in model.known and n not in extra_ranges}
    rng = {n: (lo, hi) for n, lo, hi in model.ranges if n not in extra_known}
    return declared_model(model.transfer_function, {**known, **extra_known}, {**rng, **extra_ranges},
                          dict(model.units))


def structure_text(model: Any) -> str:
    """A model's G(s) as people read it: a declared structure's own expression (a family's formula otherwise)."""
    return str(getattr(model, "transfer_function", model.structure))


def format_estimates(ident: LtiIdentification) -> list[str]:
    """The parameter table of a family's fit (:func:`parameter_lines`)."""
    return parameter_lines([(e.name, e) for e in ident.estimates])


def parameter_display(kind: str, loop: str) -> Callable[[str, ParameterEstimate], tuple[float, str]]:
    """How a record's parameter is shown on the terminal, one rule for ``analyze`` and ``watch``: tau in ms on a
    vehicle's loop (``kind`` ``soiptd``, eq. (2), or ``cascade``), as its tests are read; eq. (2)'s K per command
    unit of ``loop`` (``m/s² per command unit``); a process plant's (``family``) in its record's units (tau in s):
    :func:`mrftcli.mrft.parameter.display_scale`, which ``compare`` follows too.
    The records (JSON, ``watch --jsonl``) stay in SI.

    Returns
    -------
    callable
        ``display(name, estimate) -> (scale from the record's unit, unit shown)``.
    """
    from ..io.logtypes import gain_unit
    from ..mrft.parameter import display_scale

    def display(name: str, e: ParameterEstimate) -> tuple[float, str]:
        if name == "K" and kind == "soiptd":
            return 1.0, gain_unit(loop)
        return display_scale(name, e.unit, kind == "family")
    return display


def parameter_lines(estimates: Sequence[tuple[str, ParameterEstimate]],
                    display: Callable[[str, ParameterEstimate], tuple[float, str]] | None = None) -> list[str]:
    """The one parameter table of every record: unit, estimate, std, 95 % interval (one-sided where the data or a
    range bound it) and the verdict (known, NOT DETERMINED).

    ``display(name, estimate)`` gives the scale and unit a parameter is shown in (e.g. tau in ms); by
    default the record's own.
    """
    rows = [("parameter", "unit", "estimate", "± std", "95 % interval", "")]
    for name, e in estimates:
        scale, unit = display(name, e) if display is not None else (1.0, e.unit)
        if not math.isfinite(e.value):
            rows.append((name, unit, "-", "", "", ""))
            continue
        std = "" if e.known else (num(e.std * scale, 2) if e.determined and math.isfinite(e.std) else "-")
        rows.append((name, unit, num(e.value * scale), std, _interval(e, scale),
                     "known" if e.known else ("" if e.determined else "NOT DETERMINED")))
    return text_table(rows, align="<<>>", indent="  ")


def _interval(e: ParameterEstimate, scale: float = 1.0) -> str:
    """The 95 % interval, saying which end is open (the data's, or a range's bound)."""
    lo, hi = e.ci95_low * scale, e.ci95_high * scale
    if e.known:
        return ""
    if not math.isfinite(hi):  # open above; below, the data's bound or only the range's
        if e.one_sided == "low" or not math.isfinite(lo):
            return f"anywhere above {num(lo)}" if math.isfinite(lo) else "anywhere"
        return f"> {num(lo)} (not bounded from above)"
    if e.one_sided == "low":
        return f"< {num(hi)} (open below: the range's bound {num(lo)})"
    if e.one_sided == "high":
        return f"> {num(lo)} (open above)"
    return f"{num(lo)} - {num(hi)}"


def format_combination(ident: LtiIdentification) -> list[str]:
    """The line naming what the tests determine of the parameters they leave undetermined (K/T1)."""
    c = ident.combination
    if c is None:
        return []
    return [f"determined: {c.name} = {num(c.value)} {c.unit} (95 % {num(c.ci95_low)} - {num(c.ci95_high)}); "
            f"{', '.join(n for n, _ in c.exponents)} trade off along it"]


@dataclass(frozen=True)
class CascadeRequest:
    """The cascade options as given (:func:`pop_cascade_options`).

    Attributes
    ----------
    inner_model, inner_gains : str or None
        The paths of the inner analysis and of the gains file (None: not given).
    outer_command : str
        ``"acceleration"``, ``"attitude"`` or ``"identify"``.
    inner_draws : int
        Draws of the inner model.
    """

    inner_model: str | None
    inner_gains: str | None
    outer_command: str
    inner_draws: int


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
                                 "attitude [rad] (K = g = 9.80665 m/s^2), or identify K (two betas needed). Stated in the "
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


def pop_cascade_options(options: dict[str, Any]) -> CascadeRequest | None:
    """Take the cascade options out of a command's keyword arguments (the rest are the reader's): ``inner_model``
    and ``inner_gains`` (paths), ``outer_command`` and ``inner_draws``; None when neither file was given
    (the cascade route not asked for)."""
    request = CascadeRequest(**{f.name: options.pop(f.name, None) for f in fields(CascadeRequest)})
    return request if request.inner_model is not None or request.inner_gains is not None else None


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
    assert request.inner_model is not None and request.inner_gains is not None  # refused by _check
    data = read_json_file(request.inner_model, "--inner-model")
    try:
        result = AnalysisResult.from_json(data)
    except InputError as err:  # the record's one line, with the option and file it came from
        raise InputError(f"--inner-model {request.inner_model}: {err}") from None
    controller = inner_gains_of(read_json_file(request.inner_gains, "--inner-gains"), inner_name)
    inner = inner_loop_of(result, controller, inner_name)
    return cascade_model(inner, request.outer_command), CascadeOptions(
        draws=tuple(inner_draws(result, inner, request.inner_draws)),
        assumptions=(f"inner model from {request.inner_model}",))
