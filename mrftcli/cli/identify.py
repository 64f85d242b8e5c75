"""``mrft-ident identify``: Td, tau (and K) from measured limit-cycle figures, without a log."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import click

from ..errors import InputError, InsufficientDataError
from ..mrft.identify_lti import refuse_nothing_determined
from .model_options import build_model, format_estimates, parse_number, structure_options, structure_text
from .options import controller_rate_option, dump_json, echo_warnings, json_option, tp_option

if TYPE_CHECKING:
    from ..mrft.identify import ParameterEstimate, ResponsePoint, TestMeasurement


def _fields(option: str, text: str, counts: tuple[int, int], expected: str) -> list[float]:
    """The colon-separated numbers of one ``--test``/``--point`` (``counts``: the two lengths it may have)."""
    parts = text.split(":")
    if len(parts) not in counts:
        raise InputError(f"{option} {text!r}: expected {expected}")
    return [parse_number(p, f"{option} {text!r}") for p in parts]


def _parse_test(text: str) -> TestMeasurement:
    """BETA:FREQ_HZ[:AMPLITUDE:H] -> TestMeasurement."""
    from ..mrft.identify import TestMeasurement

    nums = _fields("--test", text, (2, 4), "BETA:FREQ_HZ or BETA:FREQ_HZ:AMPLITUDE:H")
    try:
        return TestMeasurement(*nums[:2], *([] if len(nums) == 2 else [nums[2], nums[3]]))
    except InputError as err:  # name the --test, as simulate's does
        raise InputError(f"--test {text!r}: {err}") from None


def _parse_point(text: str) -> ResponsePoint:
    """FREQ_HZ:GAIN:PHASE_DEG[:SE_REL:SE_DEG] -> ResponsePoint."""
    from ..mrft.identify import ResponsePoint

    nums = _fields("--point", text, (3, 5), "FREQ_HZ:GAIN:PHASE_DEG[:SE_REL:SE_DEG]")
    se_rel, se_deg = (nums[3], nums[4]) if len(nums) == 5 else (0.01, 0.6)
    return ResponsePoint(2 * math.pi * nums[0], nums[1], math.radians(nums[2]), se_rel, math.radians(se_deg))


def _fmt(est: ParameterEstimate | None, scale: float = 1.0, unit: str = "") -> str:
    if est is None:
        return "-"
    s = f"{est.value * scale:.5g}{unit}"
    if est.std > 0:
        s += f" ± {est.std * scale:.2g}  [{est.ci95_low * scale:.4g}, {est.ci95_high * scale:.4g}]"
    return s


@click.command("identify")
@tp_option(required=False, help="Known propulsion time constant Tp [s] (--model soiptd).")
@structure_options
@click.option("--point", "points", multiple=True, metavar="FREQ_HZ:GAIN:PHASE_DEG[:SE_REL:SE_DEG]",
              help="A measured point of G(j omega) (process models): frequency [Hz], gain [output per command], "
                   "phase [deg], optional standard errors (relative gain, deg; default 1 %, 0.6 deg). Repeat.")
@click.option("--test", "tests", multiple=True, metavar="BETA:FREQ_HZ[:AMPLITUDE:H]",
              help="One MRFT test: beta and frequency [Hz], optionally amplitude and relay height. Repeat (>= 2).")
@controller_rate_option("rate_hz", detail="at which the relay decided: removes the half-sample switching lag "
                                           "from tau (nominal betas; default: a continuous relay).")
@json_option()
def identify(Tp: float | None, model_name: str, params: tuple[str, ...], ranges: tuple[str, ...],
             points: tuple[str, ...], tests: tuple[str, ...], rate_hz: float | None, json_target: str | None) -> None:
    """Identify Td, tau (and K when amplitudes are given) from two or more MRFT tests.

    With --model fopdt|sopdt|ipdt|foipdt: the process model's unknown parameters from measured points
    of its frequency response (--point; analyze --model measures them on a log's relay cycles).

    Example: mrft-ident identify --tp 0.1 --test -0.4:0.70564 --test -0.7:1.01884
    """
    from ..mrft.identify import IdentificationResult, strategy_of
    from ..mrft.identify import identify as run

    model = _model(Tp, model_name, params, ranges, tests, points)
    # the family's strategy names what it identifies from: eq. (2) MRFT tests, the process families response points
    if strategy_of(model).data == "tests":
        data: list[Any] = [_parse_test(t) for t in tests]
        options = {"rate_hz": rate_hz}
    else:
        data, options = [_parse_point(p) for p in points], {}
    try:
        result = run(data, model, **options)
    except InputError as err:
        if tests and len({t.beta for t in data}) < 2:
            # tests given but too few to determine Td and tau: the documented exit code 6, not a bad option
            raise InsufficientDataError(str(err)) from None
        raise
    if json_target:
        dump_json(result.to_json(), json_target)
    if json_target != "-":
        _echo(result, len(data))
    if not isinstance(result, IdentificationResult):
        refuse_nothing_determined(result)  # exit 6 after the output, as analyze's partial result


def _model(Tp: float | None, model_name: str, params: tuple[str, ...], ranges: tuple[str, ...],
           tests: tuple[str, ...], points: tuple[str, ...]) -> Any:
    """The model to identify (eq. (2) at --tp, or a process family), its data options checked."""
    from ..mrft.model import soiptd_model

    if model_name == "soiptd":
        if Tp is None or not tests or points or params or ranges:
            raise click.UsageError("--model soiptd takes --tp and two or more --test BETA:FREQ_HZ[:AMPLITUDE:H] "
                                   "(--point, --param and --range are for process models)")
        return soiptd_model(Tp)
    if tests or not points:
        raise click.UsageError(f"--model {model_name} identifies from --point FREQ_HZ:GAIN:PHASE_DEG "
                               "(measured on a log by analyze --model); --test is for --model soiptd")
    return build_model(model_name, params, ranges)


def _echo(result: Any, n_data: int) -> None:
    """The identification as text: eq. (2)'s estimates and tests, or the family's parameter table."""
    from ..mrft.identify import IdentificationResult

    if not isinstance(result, IdentificationResult):
        click.echo(f"model {result.model.family}: G(s) = {structure_text(result.model)}  [direct fit to {n_data} point(s)]")
        click.echo("\n".join(format_estimates(result)))
        if result.advice and not result.nothing_determined:  # else the exit-6 line after it gives the advice
            click.echo(f"not determined: {result.advice}")
        echo_warnings(result.warnings)
        return
    click.echo(f"model  G(s) = K Td e^(-tau s) / (s (Tp s+1)(Td s+1)),  Tp = {result.Tp:g} s (known)  [{result.method}]")
    click.echo(f"{'Td':<4} {_fmt(result.Td, 1.0, ' s')}")
    click.echo(f"{'tau':<4} {_fmt(result.tau, 1e3, ' ms')}")
    click.echo(f"{'K':<4} {_fmt(result.K, 1.0, ' ' + result.model.parameters['K'].unit)}")  # eq. (2)'s K_UNIT
    if result.residual is not None:
        click.echo(f"residual (weighted RMS of relative frequency errors): {result.residual:.3g}")
    click.echo("tests:")
    for t in result.tests:
        line = f"  beta {t['beta']:+.3f}  f {t['frequency_hz']:.5g} Hz  Td*Omega {t['td_norm']:.3g}  tau*Omega {t['theta']:.3g}"
        if t.get("K") is not None:
            line += f"  K {t['K']:.4g}"
        click.echo(line)
    echo_warnings(result.warnings)
