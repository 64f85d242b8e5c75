"""``mrft-ident simulate``: write a simulated MRFT flight log plus its ground-truth sidecar."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
from click.core import ParameterSource

from ..errors import InputError
from ..io import writable_format
from ..io.logtypes import LOOPS
from ..validate import check_beta, check_positive, check_time
from ..report.wording import output_unit
from .model_options import MODEL_NAMES, parse_number, parse_params
from .options import (check_output_dir, check_output_file, controller_rate_option, dump_json, json_option, quiet_option,
                      read_json_file, tp_option, tqdm_progress)

__all__ = ["simulate", "parse_test", "parse_effect"]

#: default planned amplitude for ``--test BETA`` without H (eq. (2)): 5 cm (altitude, x, y) / 5 deg (roll, pitch)
_DEFAULT_AMPLITUDE = {"altitude": 0.05, "x": 0.05, "y": 0.05, "roll": math.radians(5.0), "pitch": math.radians(5.0)}


def parse_test(text: str, option: str = "--test") -> tuple[float, float | None, float | None]:
    """``BETA[:H[:DURATION]]`` -> (beta, h or None, duration or None); raises InputError naming ``option``."""
    parts = text.split(":")
    if not 1 <= len(parts) <= 3 or any(p.strip() == "" for p in parts[:1]):
        raise InputError(f"{option} {text!r}: expected BETA[:H[:DURATION]], e.g. -0.4 or -0.4:0.05:15")
    values: list[float | None] = [None if part.strip() == "" else parse_number(part, f"{option} {text!r}: {name}")
                                  for name, part in zip(("BETA", "H", "DURATION"), parts)]
    values += [None] * (3 - len(values))
    first, h, duration = values
    assert first is not None  # BETA was checked non-empty above
    try:
        beta = check_beta(first)
        h = None if h is None else check_positive("the relay height H", h)
        duration = None if duration is None else check_time("DURATION", duration)
    except InputError as err:
        raise InputError(f"{option} {text!r}: {err}") from None
    return beta, h, duration


def parse_effect(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` -> (name, value) for a field of :class:`mrftcli.sim.flight.Effects`."""
    from ..sim.flight import Effects

    valid = [f for f in Effects.__dataclass_fields__]
    name, sep, value = text.partition("=")
    name = name.strip().replace("-", "_")
    if not sep:
        raise InputError(f"--effect {text!r}: expected NAME=VALUE, e.g. input_bias=0.02; names: {', '.join(valid)}")
    if name not in valid:
        raise InputError(f"--effect: unknown effect {name!r}; valid names: {', '.join(valid)}")
    return name, parse_number(value, f"--effect {text!r}")


def _check_log_target(out: Path, fmt: str) -> None:
    """The log is this tool's to replace (:func:`mrftcli.sim.sidecar.check_log_target`) and ``--out``'s folder is
    created if missing (refused if it cannot be), before the work."""
    from ..sim.sidecar import check_log_target

    check_log_target(out, fmt)
    if not out.parent.is_dir():  # created, as every other output's folder (--json, --report, tune --out)
        check_output_dir(str(out.parent), "--out")


def _given(ctx: click.Context, names: tuple[str, ...], why: str) -> None:
    """UsageError naming the first of ``names`` given on the command line (with ``why``)."""
    for param in ctx.command.params:
        if param.name in names and ctx.get_parameter_source(param.name) == ParameterSource.COMMANDLINE:
            raise click.UsageError(f"{param.opts[0]} {why}")


def _required(*pairs: tuple[str, object]) -> None:
    """click's own message for the first option that is missing."""
    for option, value in pairs:
        if value is None:
            raise click.UsageError(f"Missing option '{option}'.")


@dataclass(frozen=True)
class CascadeOptions:
    """What ``simulate --cascade`` was asked for (pairs are (inner, outer) or (hover, hold))."""

    axis: str
    inner: tuple[float, float, float, float]  # --inner-tp, --inner-td, --inner-tau, --inner-k
    gains_path: Path | None
    inner_tests: tuple[str, ...]
    outer_tests: tuple[str, ...]
    Td: float
    tau: float
    commanded: str
    rate_hz: float | None  # None: not given (the gains' rate, else 200 Hz)
    noise: tuple[float | None, float | None]
    amplitude: tuple[float | None, float | None]
    hover_hold: tuple[float, float]
    switching: str
    seed: int
    start_time: float
    layout: str | None
    fmt: str | None


def _tests(texts: tuple[str, ...], plan, option: str = "--test"):
    """The ``--test`` (``--inner-test``) specs of one loop, H and DURATION planned by ``plan(beta)`` (the describing
    function) where not given."""
    from ..sim.flight import TestSpec

    specs = []
    for text in texts:
        beta, h, duration = parse_test(text, option)
        if h is None or duration is None:
            planned = plan(beta)
            h = planned.h if h is None else h
            duration = planned.duration if duration is None else duration
        specs.append(TestSpec(beta=beta, h=h, duration=duration))
    return tuple(specs)


def _cascade_layout(opts: CascadeOptions, out: Path) -> tuple[str, str]:
    """(layout, format) of the cascaded log: hear-ros is a ROS 1 bag."""
    layout = opts.layout or ("hear-ros" if out.suffix == ".bag" else "reference")
    if layout == "hear-ros":
        if (opts.fmt or "bag") != "bag" or out.suffix != ".bag":
            raise InputError(f"--out {out.name}: the HEAR layout is a ROS 1 bag; name the log *.bag "
                             "(or use --layout reference)")
        return layout, "bag"
    return layout, writable_format(out, opts.fmt, "--format")


def _simulate_cascade(opts: CascadeOptions, out: Path, json_target: str | None) -> None:
    """``simulate --cascade``: check, plan, fly, write, report."""
    from ..mrft.model import LoopModel
    from ..sim.cascade import command_gain, inner_pd, plan_outer_test, simulate_cascade
    from ..sim.cascade_plant import cascade_plant
    from ..analyze.cascade import inner_gains_of
    from ..mrft.cascade import STANDARD_GRAVITY
    from ..sim.cascade_spec import CASCADE_AXES, CascadeSpec
    from ..sim.flight import plan_test
    from ..sim.cascade_write import write_cascade

    if not (opts.inner_tests or opts.outer_tests):
        raise click.UsageError("--cascade needs at least one --inner-test or --test")
    layout, fmt = _cascade_layout(opts, out)
    _check_log_target(out, fmt)
    inner_loop = CASCADE_AXES[opts.axis]
    inner = LoopModel(*opts.inner)
    assumptions = []
    if opts.gains_path is not None:
        # GAINS.json as analyze and vehicle read it (a map of loops, tune --export generic or --json, a vehicle record)
        gains = inner_gains_of(read_json_file(opts.gains_path, "--inner-gains"), inner_loop)
        if opts.rate_hz is not None and abs(gains.rate_hz - opts.rate_hz) > 1e-9 * opts.rate_hz:
            raise InputError(f"--inner-gains rate_hz {gains.rate_hz:g} Hz differs from --controller-rate "
                             f"{opts.rate_hz:g} Hz; the inner and outer loops tick together")
    else:
        gains = inner_pd(inner, opts.rate_hz or 200.0)
        assumptions.append(f"assumption: the inner {inner_loop} PD is the simulator's design (40 deg phase margin, "
                           f"derivative time 0.3 s): Kp {gains.Kp:.4g}, Kd {gains.Kd:.4g}, Tf {gains.Tf:.4g} s at "
                           f"{gains.rate_hz:g} Hz; give --inner-gains GAINS.json to fly yours")
    check_positive("--controller-rate (a frequency in Hz)", gains.rate_hz)
    if not (math.isfinite(opts.tau) and opts.tau >= 0):
        raise InputError(f"--tau (the position measurement delay) must be a time >= 0 s, got {opts.tau!r}")
    plant = cascade_plant(inner, check_positive("--td (the outer Td, s)", opts.Td), opts.tau, gains.rate_hz,
                          STANDARD_GRAVITY)
    conv = command_gain(opts.commanded, STANDARD_GRAVITY)
    amp_in = math.radians(5.0) if opts.amplitude[0] is None else opts.amplitude[0]
    amp_out = 0.1 if opts.amplitude[1] is None else opts.amplitude[1]
    spec = CascadeSpec(inner=inner, gains=gains, Td=opts.Td, tau=opts.tau, axis=opts.axis, commanded=opts.commanded,
                       inner_tests=_tests(opts.inner_tests,
                                                  lambda b: plan_test(inner, b, amp_in, rate_hz=gains.rate_hz),
                                                  "--inner-test"),
                       outer_tests=_tests(opts.outer_tests,
                                                  lambda b: plan_outer_test(plant, gains, conv, b, amp_out)),
                       attitude_noise_std=opts.noise[0], position_noise_std=opts.noise[1],
                       hover_s=opts.hover_hold[0], hold_s=opts.hover_hold[1], seed=opts.seed,
                       start_time=opts.start_time, switching=opts.switching)
    if spec.switching == "checks":
        _warn_noise_margins(spec, plant, conv)
    flight = simulate_cascade(spec)
    sidecar = write_cascade(flight, out, layout, fmt)
    truth = json.loads(sidecar.read_text())
    for n, test in enumerate(flight.truth.tests, 1):
        if test.aborted:
            click.echo(f"warning: test {n} ({test.loop}, beta {test.beta}) was aborted at t = {test.t_end:.2f} s: "
                       "the error exceeded the safety limit; use a larger H, less noise or --switching hear", err=True)
    if json_target:
        dump_json({"log": str(out), "format": fmt, "layout": layout, "sidecar": str(sidecar),
                   "assumptions": assumptions, "truth": truth}, json_target)
    if json_target == "-":
        return
    _echo_cascade(flight, out, sidecar, layout, fmt, assumptions)


def _warn_lock_up(i: int, beta: float, margin: float, remedy: str) -> None:
    """The lock-up warning of test ``i`` when its noise margin (docs/simulator.md) is under 4."""
    if margin < 4.0:
        click.echo(f"warning: test {i} (beta {beta}): the output moves only {margin:.1f} noise std per tick near the "
                   f"zero crossing (< 4); the MRFT relay may lock up. Use {remedy}, or --switching hear", err=True)


def _warn_noise_margins(spec, plant, conv: float) -> None:
    """The one-loop path's lock-up warning for each test (docs/simulator.md: margin a Omega / (rate std) < 4)."""
    from ..sim.cascade import outer_describing_function
    from ..sim.flight import noise_margin

    att, pos = spec.noise()
    for i, test in enumerate((*spec.inner_tests, *spec.outer_tests), 1):
        if i <= len(spec.inner_tests):
            margin = noise_margin(spec.inner, test.beta, test.h, spec.rate_hz, att)
        else:
            omega, gain = outer_describing_function(plant, spec.gains, conv, test.beta)
            margin = 4.0 * test.h * gain / math.pi * omega / (spec.rate_hz * pos) if pos > 0 else math.inf
        _warn_lock_up(i, test.beta, margin, "a larger H or amplitude, less noise")


def _echo_cascade(flight, out: Path, sidecar: Path, layout: str, fmt: str, assumptions: list[str]) -> None:
    tr = flight.truth
    for line in assumptions:
        click.echo(line)
    click.echo(f"wrote {out} ({layout} layout, {fmt}, {tr.duration:.1f} s at {tr.gains.rate_hz:g} Hz) and {sidecar}")
    m, gn = tr.inner, tr.gains
    click.echo(f"  inner {tr.inner_loop}: Tp {m.Tp:g} s, Td {m.Td:g} s, tau {m.tau:g} s, K {m.K:g} rad/s² per "
               f"command unit; PD Kp {gn.Kp:.4g}, Ki {gn.Ki:.4g}, Kd {gn.Kd:.4g}, Tf {gn.Tf:.4g} s")
    unit = "rad" if tr.commanded == "attitude" else "m/s²"
    click.echo(f"  outer {tr.axis}: Td {tr.Td:g} s, tau {tr.tau:g} s, K {tr.K:g} (commanded {tr.commanded} [{unit}]); "
               f"noise {tr.position_noise_std:g} m, {tr.attitude_noise_std:g} rad")
    for n, test in enumerate(tr.tests, 1):
        what = "inner command" if test.loop == tr.inner_loop else unit
        click.echo(f"  test {n}: {test.loop} beta {test.beta:+.3f}, h {test.h:.4g} [{what}], "
                   f"{test.t_start:.2f}-{test.t_end:.2f} s")


@click.command("simulate")
@tp_option("tp", required=False, help="Propulsion time constant Tp [s] (eq. (2); not with --cascade or a process --model).")
@click.option("--td", type=float, default=None, help="Drag time constant Td [s] (eq. (2); with --cascade: the "
              "outer Td of y'' = g roll - y'/Td).")
@click.option("--tau", type=float, default=None, help="Transport delay tau [s] (eq. (2); with --cascade: the "
              "position measurement delay).")
@click.option("--k", "k", type=float, default=1.0, show_default=True, help="Gain K [output unit / s^2 per command unit, e.g. m/s^2 for altitude] (K*Td: command -> output rate).")
@click.option("--loop", type=click.Choice(LOOPS), default="altitude", show_default=True, help="Loop to simulate.")
@click.option(
    "--test",
    "tests",
    multiple=True,
    metavar="BETA[:H[:DURATION]]",
    help="One MRFT test (repeat for more; with --cascade: an outer-loop test). H [command units] defaults "
    "to the relay height for which the describing function predicts --amplitude; DURATION [s] to 14 "
    "predicted periods + 2 s.",
)
@controller_rate_option("controller_rate_hz", default=200.0, detail="at which the simulated relay decides and the log is stamped.")
@click.option("--noise", type=float, default=None, help="Output noise std [m or rad]; default 0.0005 m / 0.05 deg "
              "(with --cascade: the position's, 0.0002 m).")
@click.option("--amplitude", type=float, default=None, help="Planned amplitude for tests without H [m or rad]; "
              "default 0.05 m / 5 deg (with --cascade: the outer tests', 0.1 m).")
@click.option("--bias", type=float, default=None, help="Hover command [command units]; default 0.5 (altitude) / 0 (roll, pitch; "
              "a process --model: the command holding output 0).")
@click.option("--setpoint", type=float, default=None, help="Setpoint [m or rad]; default 1 m (altitude) / 0 rad (eq. (2) only).")
@click.option("--hover", "hover_s", type=float, default=5.0, show_default=True, help="Hover before the first test [s].")
@click.option("--hold", "hold_s", type=float, default=4.0, show_default=True, help="Hold after each test [s].")
@click.option(
    "--switching",
    type=click.Choice(["checks", "hear"]),
    default="checks",
    show_default=True,
    help="MRFT switching rule: plain rule of the docs, or the HEAR block with anti-false-switching.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (noise, jitter).")
@click.option("--start-time", type=float, default=0.0, show_default=True, help="Log time of the first sample [s].")
@click.option(
    "--effect",
    "effects",
    multiple=True,
    metavar="NAME=VALUE",
    help="Add an effect: input_bias, gain_drift, sensor_lag, quadratic_drag, actuator_rate_limit, "
    "delay_jitter (and delay_jitter_correlation, battery_voltage), asymmetric_gain, actuator_saturation, dead_zone, "
    "thrust_rectification, flex_mode_hz; every family but quadratic_drag and thrust_rectification (eq. (2)'s own). "
    "See docs/simulator.md.",
)
@click.option("--model", "model_name", type=click.Choice(MODEL_NAMES), default="soiptd", show_default=True,
              help="Plant structure: soiptd (eq. (2): --tp, --td, --tau, --k) or a process family (fopdt, sopdt, "
              "ipdt, foipdt) with its parameters as --param NAME=VALUE; see docs/simulator.md.")
@click.option("--model-file", "model_file", type=click.Path(exists=True, dir_okay=False), default=None,
              metavar="FILE", help="A plant structure you declare (the TOML/JSON file of analyze --model-file): "
              "its known parameters as in the file, every unknown one's true value as --param NAME=VALUE.")
@click.option("--param", "params", multiple=True, metavar="NAME=VALUE",
              help="--model fopdt|sopdt|ipdt|foipdt or --model-file: a parameter of the plant (K, T, T1, T2, tau; "
              "times in s). Repeat for each.")
@click.option("--cascade", type=click.Choice(["x", "y"]), default=None,
              help="Fly a cascaded flight: the outer loop X (through pitch) or Y (through roll), the inner "
              "attitude loop closed by a PD; --inner-test tests first, then the --test tests. Needs --inner-tp, "
              "--inner-td, --inner-tau, --inner-k. See docs/simulator.md.")
@click.option("--inner-tp", type=float, default=None, help="--cascade: the attitude plant's Tp [s].")
@click.option("--inner-td", type=float, default=None, help="--cascade: the attitude plant's Td [s].")
@click.option("--inner-tau", type=float, default=None, help="--cascade: the attitude plant's tau [s].")
@click.option("--inner-k", type=float, default=None,
              help="--cascade: the attitude plant's K [rad/s^2 per inner command unit].")
@click.option("--inner-gains", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="GAINS.json",
              help="--cascade: the inner PD in tune's generic form ({\"roll\": {\"Kp\", \"Ki\", \"Kd\", \"Tf\", "
              "\"rate_hz\"}}); its rate_hz must be --controller-rate. Default: a PD the simulator designs (40 deg "
              "phase margin, derivative time 0.3 s), stated in the output.")
@click.option("--inner-test", "inner_tests", multiple=True, metavar="BETA[:H[:DURATION]]",
              help="--cascade: an MRFT test of the inner attitude loop (repeat for more; H in inner command units).")
@click.option("--inner-noise", type=float, default=None, help="--cascade: attitude noise std [rad]; default 0.05 deg.")
@click.option("--inner-amplitude", type=float, default=None,
              help="--cascade: planned amplitude of inner tests without H [rad]; default 5 deg.")
@click.option("--commanded", type=click.Choice(["acceleration", "attitude"]), default="acceleration",
              show_default=True, help="--cascade: what the outer MRFT drives: an acceleration [m/s^2] (K = 1) "
              "or the attitude setpoint [rad] (K = g).")
@click.option("--layout", type=click.Choice(["hear-ros", "reference"]), default=None,
              help="--cascade: the log layout (default: hear-ros for a .bag, else reference).")
@click.option("--format", "fmt", default=None, metavar="FMT", help="Log format to write (default: from the file name): mcap, mcap-json, bag, ros2-sqlite3, ros2-mcap, ulog, csv.")
@click.option("--out", "-o", "out", required=True, type=click.Path(dir_okay=True, path_type=Path), help="Log to write; the sidecar goes to OUT.truth.json.")
@json_option(what="ground truth and the paths written")
@quiet_option()
@click.pass_context
def simulate(
    ctx, tp, td, tau, k, loop, tests, controller_rate_hz, noise, amplitude, bias, setpoint, hover_s, hold_s, switching,
    seed, start_time, effects, model_name, model_file, params, cascade, inner_tp, inner_td, inner_tau, inner_k, inner_gains, inner_tests,
    inner_noise, inner_amplitude, commanded, layout, fmt, out, json_target, quiet,
) -> None:
    """Simulate a closed-loop MRFT flight of a plant model: eq. (2) by default, G(s) = K Td e^(-tau s) /
    (s (Tp s+1)(Td s+1)) with --tp, --td, --tau, --k.

    Writes OUT in the reference layout (/mrft/command, /mrft/beta, /mrft/setpoint, /mocap/pose or
    /imu/data, /battery) and the ground truth next to it as OUT.truth.json.

    With --cascade x|y: a cascaded flight, the outer position loop through the inner attitude loop
    (closed by a sampled PD), the inner loop's tests first; written in the HEAR layout (.bag) or the
    reference layout. With --model fopdt|sopdt|ipdt|foipdt and --param NAME=VALUE (or --model-file): a
    process plant, the same flight about its operating point (output 0).

    Example: mrft-ident simulate --tp 0.0422 --td 2.669 --tau 0.0464 --k 19.6 --test -0.4 --test -0.7
    --switching hear --out alt.mcap

    Example: mrft-ident simulate --cascade y --inner-tp 0.0422 --inner-td 1.301 --inner-tau 0.0297
    --inner-k 30 --inner-test -0.4 --inner-test -0.7 --td 2 --tau 0.03 --test -0.4 --test -0.7
    --out cascade_y.bag
    """
    # the option's own name: "rate" would also be the hidden --rate alias' name, and click then hands
    # --controller-rate's value to the alias too (simulate --controller-rate was refused as given twice)
    rate = controller_rate_hz
    check_output_file(json_target)  # before the flight, never onto an input (--inner-gains, --model-file)
    if model_file is not None:
        _given(ctx, ("model_name",), "is not used with --model-file (the file declares the structure)")
    if model_name != "soiptd" or model_file is not None:
        what = "--model-file" if model_file is not None else f"--model {model_name}"
        _given(ctx, ("setpoint",), f"is not used with {what} (the plant flies about its operating point, output 0)")
        _given(ctx, ("tp", "td", "tau", "k", "cascade", "inner_tp", "inner_td", "inner_tau", "inner_k",
                     "inner_gains", "inner_tests", "inner_noise", "inner_amplitude", "commanded", "layout"),
               f"is not used with {what} (its parameters are --param)")
        _required(("--test", tests or None))
        model = (_declared_model(model_file, tuple(params)) if model_file is not None
                 else _process_model(model_name, tuple(params)))
    else:
        _given(ctx, ("params",), "needs --model fopdt|sopdt|ipdt|foipdt (eq. (2) takes --tp, --td, --tau, --k)")
        if cascade is not None:
            _given(ctx, ("tp", "k", "loop", "bias", "setpoint", "effects"), "is not used with --cascade")
            _required(("--td", td), ("--tau", tau))
            rate_given = (ctx.get_parameter_source("controller_rate_hz") == ParameterSource.COMMANDLINE
                          or ctx.meta.get("mrftcli.rate_alias.controller_rate_hz") is not None)
            _required(("--inner-tp", inner_tp), ("--inner-td", inner_td), ("--inner-tau", inner_tau),
                      ("--inner-k", inner_k))
            options = CascadeOptions(cascade, (inner_tp, inner_td, inner_tau, inner_k), inner_gains,
                                     tuple(inner_tests), tuple(tests), td, tau, commanded,
                                     rate if rate_given else None, (inner_noise, noise), (inner_amplitude, amplitude),
                                     (hover_s, hold_s), switching, seed, start_time, layout, fmt)
            _simulate_cascade(options, out, json_target)
            return
        _given(ctx, ("inner_tp", "inner_td", "inner_tau", "inner_k", "inner_gains", "inner_tests", "inner_noise",
                     "inner_amplitude", "commanded", "layout"), "needs --cascade x|y")
        _required(("--tp", tp), ("--td", td), ("--tau", tau), ("--test", tests or None))
        from ..mrft.model import LoopModel

        model = LoopModel(tp, td, tau, k)
    _simulate_loop(LoopOptions(model, loop, tuple(tests), rate, noise, amplitude, bias, setpoint, (hover_s, hold_s),
                               switching, seed, start_time, tuple(effects), fmt, quiet), out, json_target)


def _declared_model(path: str, items: tuple[str, ...]) -> Any:
    """The declared structure of ``--model-file`` with every parameter's true value: the file's known ones,
    ``--param`` for the rest (an unknown one's start inside its range is not a truth to fly)."""
    from ..mrft.model_file import load_model_file

    model = load_model_file(path)
    values = parse_params(items)
    names = [n for n, _ in model.values]
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise InputError(f"--param {unknown[0]}: {path} has the parameters {', '.join(names)}")
    missing = [n for n in names if n not in model.known and n not in values]
    if missing:
        raise InputError(f"{path}: {', '.join(missing)} unknown in the file (a range): give the plant's true "
                         f"value{'s' if len(missing) > 1 else ''} to fly with "
                         + " ".join(f"--param {n}=VALUE" for n in missing))
    return model.with_parameters(**values) if values else model


def _process_model(family: str, items: tuple[str, ...]):
    """The family's model of ``--param`` values; one-line errors naming a missing or unknown parameter."""
    from ..mrft.families import PROCESS_FAMILIES

    cls = PROCESS_FAMILIES[family]
    names = list(cls._spec)
    values = parse_params(items)
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise InputError(f"--param {unknown[0]}: --model {family} has the parameters {', '.join(names)}")
    missing = [n for n in names if n not in values]
    if missing:
        raise InputError(f"--model {family} needs --param {' --param '.join(f'{n}=VALUE' for n in missing)} "
                         f"({cls.structure})")
    return cls(**values)


@dataclass(frozen=True)
class LoopOptions:
    """What ``simulate`` of one loop was asked for (``model``: eq. (2), a process family or a declared plant)."""

    model: Any
    loop: str
    tests: tuple[str, ...]
    rate_hz: float
    noise: float | None
    amplitude: float | None
    bias: float | None
    setpoint: float | None
    hover_hold: tuple[float, float]
    switching: str
    seed: int
    start_time: float
    effects: tuple[str, ...]
    fmt: str | None
    quiet: bool


def _loop_spec(opts: LoopOptions, out: Path):
    """The checked :class:`FlightSpec` and the log format (every option checked before planning)."""
    from ..mrft.model import LoopModel
    from ..sim.flight import Effects, FlightSpec, default_noise_std, noise_margin, plan_test

    model, rate = opts.model, opts.rate_hz
    trimmed = isinstance(model, LoopModel)  # eq. (2): the loop's defaults; another family: 1 % of the amplitude
    fmt = writable_format(out, opts.fmt, "--format")
    check_positive("--controller-rate (a frequency in Hz)", rate)
    _check_log_target(out, fmt)
    effect_values = dict(parse_effect(text) for text in opts.effects)  # every option checked before planning
    amplitude = ((_DEFAULT_AMPLITUDE[opts.loop] if trimmed else 0.05) if opts.amplitude is None
                 else check_positive("--amplitude", opts.amplitude))
    specs = _tests(opts.tests, lambda beta: plan_test(model, beta, amplitude, rate_hz=rate))
    noise = opts.noise if opts.noise is not None or trimmed else 0.01 * amplitude
    noise_std = default_noise_std(opts.loop) if noise is None else noise
    for i, test in enumerate(specs, 1):
        margin = noise_margin(model, test.beta, test.h, rate, noise_std)
        if opts.switching == "checks":
            _warn_lock_up(i, test.beta, margin, "a larger H or --amplitude, less --noise")
    spec = FlightSpec(model=model, tests=tuple(specs), loop=opts.loop, rate_hz=rate, noise_std=noise,
                      bias=opts.bias, setpoint=opts.setpoint, hover_s=opts.hover_hold[0], hold_s=opts.hover_hold[1],
                      effects=Effects(**effect_values), seed=opts.seed, start_time=opts.start_time,
                      switching=opts.switching)
    return spec, fmt


def _simulate_loop(opts: LoopOptions, out: Path, json_target: str | None) -> None:
    """``simulate`` of one loop: check and plan, fly (a bar for long flights), write, report."""
    from ..sim.flight import simulate_flight, write_flight

    spec, fmt = _loop_spec(opts, out)
    hover_s, hold_s = opts.hover_hold
    total_s = hover_s + sum(t.duration + hold_s for t in spec.tests)
    # a bar only for flights long enough to wait for (and only on a terminal)
    with tqdm_progress("simulating", unit="tick", enabled=total_s > 120 and not opts.quiet) as progress:
        flight = simulate_flight(spec, progress=progress)
    sidecar = write_flight(flight, out, fmt)
    for i, test in enumerate(flight.truth["tests"], 1):
        if test["aborted"]:
            click.echo(
                f"warning: test {i} (beta {test['beta']}) was aborted at t = {test['t_end']:.2f} s: the error "
                f"exceeded the safety limit {test['abort_error']:.3g} (usually the relay locked up after a "
                "noise-triggered switch); use a larger H, less --noise or --switching hear",
                err=True,
            )
    if json_target:
        dump_json({"log": str(out), "format": fmt, "sidecar": str(sidecar), "truth": flight.truth}, json_target)
    if json_target == "-":
        return
    truth = flight.truth
    click.echo(f"wrote {out} ({fmt}, {truth['duration']:.1f} s at {opts.rate_hz:g} Hz) and {sidecar}")
    click.echo(_model_line(opts, truth["noise_std"]))
    for i, test in enumerate(truth["tests"], 1):
        click.echo(
            f"  test {i}: beta {test['beta']:+.3f}, h {test['h']:.4g} [command], "
            f"{test['t_start']:.2f}-{test['t_end']:.2f} s"
        )
    if truth["effects_active"]:
        click.echo("  effects: " + ", ".join(f"{n}={truth['effects'][n]:g}" for n in truth["effects_active"]))


def _model_line(opts: LoopOptions, noise: float) -> str:
    """The plant flown: eq. (2)'s parameters with units, or a family's structure and values."""
    from ..mrft.model import LoopModel

    m, loop = opts.model, opts.loop
    unit = output_unit(loop)
    if isinstance(m, LoopModel):
        return (f"  model: Tp {m.Tp:g} s, Td {m.Td:g} s, tau {m.tau:g} s, K {m.K:g} {unit}/s² per command unit; "
                f"loop {loop}, noise {noise:g} {unit}")
    values = ", ".join(f"{n} {p.value:g}{' ' + p.unit if p.unit == 's' else ''}" for n, p in m.parameters.items())
    structure = m.transfer_function if m.family == "declared" else m.structure
    return (f"  model {m.family}: {structure}; {values}; noise {noise:g} [output units]"
            f"{' (1 % of --amplitude)' if opts.noise is None else ''}")
