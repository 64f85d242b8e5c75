"""``mrft-ident simulate``: write a simulated MRFT flight log plus its ground-truth sidecar."""

from __future__ import annotations

import math
from pathlib import Path

import click

from ..errors import InputError
from ..io.logtypes import LOOPS
from ..validate import check_beta, check_positive, check_time
from ..report.wording import output_unit
from .options import controller_rate_option, dump_json, json_option, quiet_option, tp_option, tqdm_progress

__all__ = ["simulate", "parse_test", "parse_effect"]

#: default planned amplitude for ``--test BETA`` without H: 5 cm (altitude) / 5 deg (roll, pitch)
_DEFAULT_AMPLITUDE = {"altitude": 0.05, "roll": math.radians(5.0), "pitch": math.radians(5.0)}


def parse_test(text: str) -> tuple[float, float | None, float | None]:
    """``BETA[:H[:DURATION]]`` -> (beta, h or None, duration or None); raises InputError."""
    parts = text.split(":")
    if not 1 <= len(parts) <= 3 or any(p.strip() == "" for p in parts[:1]):
        raise InputError(f"--test {text!r}: expected BETA[:H[:DURATION]], e.g. -0.4 or -0.4:0.05:15")
    values: list[float | None] = []
    for name, part in zip(("BETA", "H", "DURATION"), parts):
        if part.strip() == "":
            values.append(None)
            continue
        try:
            values.append(float(part))
        except ValueError:
            raise InputError(f"--test {text!r}: {name} {part!r} is not a number") from None
    values += [None] * (3 - len(values))
    first, h, duration = values
    assert first is not None  # BETA was checked non-empty above
    try:
        beta = check_beta(first)
        h = None if h is None else check_positive("the relay height H", h)
        duration = None if duration is None else check_time("DURATION", duration)
    except InputError as err:
        raise InputError(f"--test {text!r}: {err}") from None
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
    try:
        number = float(value)
    except ValueError:
        raise InputError(f"--effect {text!r}: {value!r} is not a number") from None
    if not math.isfinite(number):
        raise InputError(f"--effect {text!r}: the value must be finite")
    return name, number


def _format_of(path: Path, fmt: str | None) -> str:
    from ..io import FORMATS, format_from_name

    if fmt is not None:
        return fmt
    guessed = format_from_name(path)
    if guessed is None:
        raise InputError(
            f"cannot tell the log format from {path.name!r}; pass --format (one of {', '.join(FORMATS)})"
        )
    return guessed


@click.command("simulate")
@tp_option("tp", help="Propulsion time constant Tp [s].")
@click.option("--td", type=float, required=True, help="Drag time constant Td [s].")
@click.option("--tau", type=float, required=True, help="Transport delay tau [s].")
@click.option("--k", "k", type=float, default=1.0, show_default=True, help="Gain K (K*Td: command -> output rate).")
@click.option("--loop", type=click.Choice(LOOPS), default="altitude", show_default=True, help="Loop to simulate.")
@click.option(
    "--test",
    "tests",
    multiple=True,
    required=True,
    metavar="BETA[:H[:DURATION]]",
    help="One MRFT test (repeat for more). H [command units] defaults to the relay height for which "
    "the describing function predicts --amplitude; DURATION [s] to 14 predicted periods + 2 s.",
)
@controller_rate_option("rate", default=200.0, detail="at which the simulated relay decides and the log is stamped.")
@click.option("--noise", type=float, default=None, help="Output noise std [m or rad]; default 0.0005 m / 0.05 deg.")
@click.option("--amplitude", type=float, default=None, help="Planned amplitude for tests without H [m or rad]; default 0.05 m / 5 deg.")
@click.option("--bias", type=float, default=None, help="Hover command; default 0.5 (altitude) / 0 (roll, pitch).")
@click.option("--setpoint", type=float, default=None, help="Setpoint; default 1 m (altitude) / 0 rad.")
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
    "delay_jitter (and delay_jitter_correlation, battery_voltage). See docs/simulator.md.",
)
@click.option("--format", "fmt", default=None, metavar="FMT", help="Log format to write (default: from the file name): mcap, mcap-json, bag, ros2-sqlite3, ros2-mcap, ulog, csv.")
@click.option("--out", "-o", "out", required=True, type=click.Path(dir_okay=True, path_type=Path), help="Log to write; the sidecar goes to OUT.truth.json.")
@json_option(what="ground truth and the paths written")
@quiet_option()
def simulate(
    tp, td, tau, k, loop, tests, rate, noise, amplitude, bias, setpoint, hover_s, hold_s, switching,
    seed, start_time, effects, fmt, out, json_target, quiet,
) -> None:
    """Simulate a closed-loop MRFT flight on G(s) = K Td e^(-tau s) / (s (Tp s+1)(Td s+1)).

    Writes OUT in the reference layout (/mrft/command, /mrft/beta, /mrft/setpoint, /mocap/pose or
    /imu/data, /battery) and the ground truth next to it as OUT.truth.json.

    Example: mrft-ident simulate --tp 0.0422 --td 2.669 --tau 0.0464 --k 19.6 --test -0.4 --test -0.7
    --out alt.mcap
    """
    from ..mrft.model import LoopModel
    from ..io import FORMATS
    from ..sim.flight import Effects, FlightSpec, TestSpec, plan_test, simulate_flight, write_flight

    model = LoopModel(tp, td, tau, k)
    if fmt is not None and fmt not in FORMATS:
        raise InputError(f"unknown --format {fmt!r}; choose one of {', '.join(FORMATS)}")
    fmt = _format_of(out, fmt)
    check_positive("--controller-rate (a frequency in Hz)", rate)
    if out.parent and not out.parent.exists():
        raise InputError(f"--out {out}: the directory {out.parent} does not exist")
    effect_values = dict(parse_effect(text) for text in effects)  # every option checked before planning
    if amplitude is None:
        amplitude = _DEFAULT_AMPLITUDE[loop]
    specs = []
    for text in tests:
        beta, h, duration = parse_test(text)
        if h is None or duration is None:
            planned = plan_test(model, beta, amplitude, rate_hz=rate)
            h = planned.h if h is None else h
            duration = planned.duration if duration is None else duration
        specs.append(TestSpec(beta=beta, h=h, duration=duration))
    from ..sim.flight import default_noise_std, noise_margin

    noise_std = default_noise_std(loop) if noise is None else noise
    for i, test in enumerate(specs, 1):
        margin = noise_margin(model, test.beta, test.h, rate, noise_std)
        if margin < 4.0 and switching == "checks":
            click.echo(
                f"warning: test {i} (beta {test.beta}): the output moves only {margin:.1f} noise std per tick "
                "near the zero crossing (< 4); the MRFT relay may lock up. Use a larger H or --amplitude, "
                "less --noise, or --switching hear",
                err=True,
            )
    spec = FlightSpec(
        model=model,
        tests=tuple(specs),
        loop=loop,
        rate_hz=rate,
        noise_std=noise,
        bias=bias,
        setpoint=setpoint,
        hover_s=hover_s,
        hold_s=hold_s,
        effects=Effects(**effect_values),
        seed=seed,
        start_time=start_time,
        switching=switching,
    )

    total_s = hover_s + sum(t.duration + hold_s for t in specs)
    # a bar only for flights long enough to wait for (and only on a terminal)
    with tqdm_progress("simulating", unit="tick", enabled=total_s > 120 and not quiet) as progress:
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
    click.echo(f"wrote {out} ({fmt}, {truth['duration']:.1f} s at {rate:g} Hz) and {sidecar}")
    unit = output_unit(loop)
    click.echo(f"  model: Tp {tp:g} s, Td {td:g} s, tau {tau:g} s, K {k:g} {unit}/s² per command unit; loop {loop}, "
               f"noise {truth['noise_std']:g} {unit}")
    for i, test in enumerate(truth["tests"], 1):
        click.echo(
            f"  test {i}: beta {test['beta']:+.3f}, h {test['h']:.4g} [command], "
            f"{test['t_start']:.2f}-{test['t_end']:.2f} s"
        )
    if truth["effects_active"]:
        click.echo("  effects: " + ", ".join(f"{n}={truth['effects'][n]:g}" for n in truth["effects_active"]))
