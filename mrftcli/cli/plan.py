"""``mrft-ident plan``: recommend the next MRFT test(s) from a prior, a first test and the flight's limits."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import click

from ..errors import InputError
from ..report.wording import output_unit
from .model_options import (build_model, check_soiptd_options, format_estimates, parse_windows, relay_options,
                            structure_options, window_option)
from .options import (InputPath, check_output_file, dump_json, json_option, log_layout_options, min_cycles_option, quiet_option,
                      read_json_file, text_table, tp_option, tqdm_progress)

if TYPE_CHECKING:
    from ..analyze.record import AnalysisResult
    from ..mrft.identify import ParameterEstimate
    from ..mrft.model import LoopModel, PlantModel
    from ..plan import FlownTest, PlanLimits, PlanResult, Prior

__all__ = ["plan", "format_plan", "format_relay_plan"]


def _json_rate(data: object) -> float | None:
    """The controller rate [Hz] an ``analyze --json`` result records (declared, else its tests'), or None: analyze's
    one definition (:func:`~mrftcli.analyze.analysis_controller_rate`), so ``plan`` and ``tune`` agree on a log."""
    from ..analyze import analysis_controller_rate

    if not isinstance(data, dict):
        return None
    declared = ((data.get("input") or {}).get("source") or {}).get("controller_rate_hz")
    partial = data.get("partial")
    # a single-beta log's exit-6 object: its partial's tests
    tests = data.get("tests") or (partial.get("tests") if isinstance(partial, dict) else None) or ()
    rates = [float(t["rate_hz"]) for t in tests if isinstance(t, dict) and t.get("rate_hz")]
    return analysis_controller_rate(float(declared) if declared else None, rates)


def _from_analysis(data: object) -> tuple[list[FlownTest], dict[str, ParameterEstimate], float | None, float | None]:
    """Flown tests, identified parameters (if any), the controller rate [Hz] and the measured sensor noise
    [output units] (None: not recorded) of an ``analyze --json`` object: the one route from a log's
    analysis to a plan, whether the analysis was run here or read from its JSON."""
    from ..plan import flown_from_result, noise_from_result

    return (*flown_from_result(data), _json_rate(data), noise_from_result(data))


def _from_log(path: Path, model: LoopModel, min_cycles: int, read_options: Mapping[str, Any]
              ) -> tuple[Sequence[FlownTest], dict[str, ParameterEstimate], float | None, float | None]:
    """As :func:`_from_analysis` for a log: analysed with eq. (2)'s model (as ``analyze``), its JSON planned from, so
    ``plan --from LOG`` and ``plan --from`` its ``analyze --json`` give one plan. A log analyze cannot
    identify (a single beta, no plant) is planned from its segmented tests."""
    import json

    from ..analyze import AnalyzeOptions, analysis_controller_rate, analyze_flight
    from ..errors import IdentificationError, InsufficientDataError, SegmentationError
    from ..io import ReadOptions, read_flight
    from ..jsonable import to_jsonable
    from ..plan import flown_from_segments
    from ..segment import segment

    flight = read_flight(path, ReadOptions(**read_options))
    data: dict[str, Any] | None = None
    try:
        data = analyze_flight(flight, model, options=AnalyzeOptions(min_stable_cycles=min_cycles)).to_json()
    except InsufficientDataError as err:  # one beta: the object analyze --json writes for exit 6
        data = err.to_json()
    except (IdentificationError, SegmentationError):
        pass  # planned from what the segmenter measured, below
    if data is not None:
        return _from_analysis(json.loads(json.dumps(to_jsonable(data))))
    usable = [t for t in segment(flight) if t.n_stable >= min_cycles]
    flown, noise = flown_from_segments(usable)
    if not flown:
        raise SegmentationError(f"{path}: no MRFT test with {max(min_cycles, 3)} or more stable cycles to plan from")
    return flown, {}, analysis_controller_rate(flight.timing.controller_rate_hz, [t.rate_hz for t in usable]), noise


def _flown_from_json(path: Path) -> tuple[list[FlownTest], dict[str, ParameterEstimate], float | None, float | None]:
    """:func:`_from_analysis` of an ``analyze --json`` result file."""
    data = read_json_file(path, "--from")  # its errors name the file already
    try:
        return _from_analysis(data)
    except InputError as err:
        raise InputError(f"{path}: {err}") from err


def format_plan(result: PlanResult, unit: str = "output unit") -> str:
    """The readable table of a :class:`~mrftcli.plan.PlanResult` (its assumptions first); amplitudes in the
    output's ``unit`` (``m``, ``rad``), K in ``unit``/s² per command unit."""
    lines = [f"assumption: {a}" for a in result.assumptions]
    for f in result.flown:
        lines.append(f"flown     beta {f.beta:+.3f}  h {f.h:.4g}  {f.frequency_hz:.4g} Hz  amplitude {f.amplitude:.4g} {unit}  "
                     f"{f.n_cycles} cycles")
    head = f"{'test':<5} {'beta':>6} {'h':>8} {'duration':>9} {'frequency':>18} {f'amplitude [{unit}]':>13} {'cycles':>6}  Td*Omega"
    lines += ["", "recommended next test(s):", head]
    for i, t in enumerate(result.tests, 1):
        lines.append(f"{i:<5} {t.beta:>+6.2f} {t.h:>8.4g} {t.duration_s:>8.1f}s {t.frequency_hz:>8.4g} Hz "
                     f"({t.frequency_range_hz[0]:.3g}-{t.frequency_range_hz[1]:.3g}) {t.amplitude:>13.4g} {t.n_cycles:>6}  "
                     f"{t.td_omega[0]:.1f}-{t.td_omega[1]:.1f}")
    lines += ["", f"{'predicted std':<28} {'Td [s]':>10} {'tau [ms]':>10} {'K':>10}  (K in {unit}/s² per command unit)"]

    def row(name: str, s: dict[str, float]) -> str:
        return f"{name:<28} {s['Td']:>10.4g} {s['tau'] * 1e3:>10.4g} {s['K']:>10.4g}"

    def spread(name: str, r: dict[str, tuple[float, float]], why: str) -> str:
        return f"{name:<28} {r['Td'][0]:.3g}-{r['Td'][1]:.3g} s, {r['tau'][0] * 1e3:.3g}-{r['tau'][1] * 1e3:.3g} ms ({why})"

    lines.append(row("prior", result.prior_std))
    lines.append(row("after the recommended tests", result.predicted_std))
    lines.append(row("  the tests alone (analyze)", result.predicted_std_data))
    if result.predicted_std_data_range:
        lines.append(spread("  10-90 % over the plants", result.predicted_std_data_range,
                            "where the plant lies in what is still unknown"))
    if result.simulated_std:
        lines.append(row(f"  simulated ({result.n_simulated} plants)", result.simulated_std))
        lines.append(spread("  10-90 % simulated", result.simulated_std_range,
                            "flights of the same plant scatter too: read the range"))
    if result.conventional:
        betas = "/".join(f"{b:g}" for b in result.conventional.betas)
        lines.append(row(f"after beta {betas} instead", result.conventional.predicted_std))
    for n in result.notes:
        lines.append(f"note: {n}")
    return "\n".join(lines)


def _num(x: float, digits: int = 4) -> str:
    return f"{x:#.{digits}g}".rstrip(".") if math.isfinite(x) else "not determined"


def format_relay_plan(result: PlanResult, source: str) -> str:
    """The readable plan of a process plant: assumptions, the current model (what is undetermined), the
    candidates ranked (frequency [Hz], amplitude [output units], std after per parameter [its unit])."""
    ident = result.identification
    assert ident is not None  # a relay plan always carries its identification
    structure = getattr(ident.model, "transfer_function", ident.model.structure)
    lines = [f"assumption: {a}" for a in result.assumptions]
    chi = f", chi2/dof {ident.chi2_dof:.3g}" if ident.chi2_dof is not None else ""
    lines += [f"model {ident.model.family}: G(s) = {structure}; from the relay tests of {source} "
              f"({len(ident.points)} response points{chi})", *format_estimates(ident)]
    lines.append(f"not determined by the recorded tests: {', '.join(result.undetermined)}" if result.undetermined
                 else "every parameter is determined by the recorded tests; a next test narrows them")
    names = list(result.prior_std)
    units = {e.name: e.unit for e in ident.estimates}
    head = ["rank", "relay", "frequency [Hz]", "amplitude [output units]", "phase [deg]",
            *(f"std {n} [{units[n]}]" for n in names)]

    def stds(values: Mapping[str, float] | None, undetermined: Sequence[str]) -> list[str]:
        return ["not determined" if n in undetermined else _num((values or {})[n], 3) for n in names]

    rows = [head, ["now", "(the recorded tests)", "", "", "", *stds(result.prior_std, result.undetermined)]]
    for k, c in enumerate(result.candidates, 1):
        assert c.relay is not None and c.frequency_hz is not None and c.amplitude is not None
        rows.append([str(k), c.relay.describe()[len("relay: "):] + ("" if c.admissible else " (over --max-amplitude)"),
                     _num(c.frequency_hz[0]), _num(c.amplitude[0], 3), f"{c.phase_deg:.0f}",
                     *stds(c.predicted_std, c.undetermined)])
    lines += ["", f"candidate next tests (exact limit cycle of this model at {result.rate_hz:g} Hz; std after "
                  "adding each to the recorded tests):"]
    lines += text_table(rows, align="><" + ">" * (len(head) - 2))
    best = result.recommended
    assert best.relay is not None
    lines += ["", f"recommended: {best.relay.describe()[len('relay: '):]}: {result.why}"]
    lines += [f"note: {n}" for n in result.notes]
    return "\n".join(lines)


def _recorded_json(path: Path) -> AnalysisResult:
    """The process analysis of an ``analyze --model NAME --json`` file."""
    from ..analyze.record import AnalysisResult

    data = read_json_file(path, "--from")
    try:
        return AnalysisResult.from_json(data)
    except InputError as err:
        raise InputError(f"{path}: {err} (plan --model NAME reads an 'analyze --model NAME --json' result)") from None


@dataclasses.dataclass(frozen=True)
class _Given:
    """What the user gave ``plan`` (the command's options, passed on as one record)."""

    source: str | None
    model_name: str
    params: tuple[str, ...]
    ranges: tuple[str, ...]
    windows: tuple[str, ...]
    relay_kind: str | None
    eps: float | None
    Tp: float | None
    ranges_prior: dict[str, tuple[float, float] | None]
    max_amplitude: float | None
    max_h: float | None
    time_s: float | None
    noise_std: float | None
    min_cycles: int
    read_options: dict[str, Any]


#: eq. (2)'s options (its prior, time and forecast) and their parameter names
_EQ2_OPTIONS = {"tp": "Tp", "td_range": "td_range", "tau_range": "tau_range", "k_range": "k_range", "time": "time_s",
                "noise": "noise_std", "tests": "n_tests", "simulate": "n_simulated"}


def _check_given(given: _Given) -> None:
    """The options of the model's family: eq. (2) plans from --tp, the limits and the prior; a process model
    from the log of its recorded relay tests (click's usage errors name the option)."""
    ctx = click.get_current_context()
    if given.model_name == "soiptd":
        check_soiptd_options(given.Tp, {"--param": bool(given.params), "--range": bool(given.ranges),
                                        "--window": bool(given.windows), "--relay": bool(given.relay_kind),
                                        "--eps": given.eps is not None}, "plans from --tp and the ranges")
        for name, value in (("--max-amplitude", given.max_amplitude), ("--max-h", given.max_h),
                            ("--time", given.time_s)):
            if value is None:
                raise click.UsageError(f"Missing option '{name}'.")
        return
    eq2 = [f"--{n.replace('_', '-')}" for n, key in _EQ2_OPTIONS.items()
           if (src := ctx.get_parameter_source(key)) is not None and src.name == "COMMANDLINE"]
    if eq2:
        raise click.UsageError(f"{', '.join(eq2)} plan eq. (2) tests; with --model {given.model_name} give the log of "
                               "the recorded relay tests (and optionally --max-amplitude, --max-h)")
    if given.source is None:
        raise click.UsageError("plan --model NAME needs the log of the recorded relay tests: plan LOG --model NAME")
    if given.source.lower().endswith(".json") and (given.params or given.ranges or given.windows
                                                   or given.relay_kind or given.eps is not None):
        raise click.UsageError("--param, --range, --window, --relay and --eps apply to a log; an analyze --json "
                               "result was analysed with its own")


def _recorded(model: PlantModel, given: _Given) -> AnalysisResult:
    """A process plant's recorded relay tests, analysed as ``analyze --model`` does (or its JSON read back)."""
    from ..analyze import AnalyzeOptions, RelayOptions, analyze_flight
    from ..analyze.screen import log_start
    from ..io import ReadOptions, read_flight

    assert given.source is not None
    if given.source.lower().endswith(".json"):
        return _recorded_json(Path(given.source))
    flight = read_flight(given.source, ReadOptions(**given.read_options, any_time_scale=True), echo_warnings=False)
    analysis = analyze_flight(flight, model, options=AnalyzeOptions(
        min_stable_cycles=given.min_cycles, relay=RelayOptions(given.relay_kind, None, given.eps),
        windows=tuple(parse_windows(given.windows, log_start(flight)))))
    assert analysis.kind == "family"  # a process family's analysis
    return analysis


def _mrft_inputs(model: LoopModel, given: _Given) -> tuple[Prior, PlanLimits, Sequence[FlownTest], list[str]]:
    """Eq. (2)'s prior, limits and flown tests (from --from LOG|JSON), and what was assumed (stated first)."""
    from ..plan import PlanLimits, Prior, prior_range
    from ..sim import default_noise_std

    loop = given.read_options["loop"]
    # one idea, one option: the controller rate the log is read at is the rate the plan is made for
    rate_hz: float | None = given.read_options["controller_rate_hz"]
    flown: Sequence[FlownTest] = []
    estimates: dict[str, ParameterEstimate] = {}
    measured_noise: float | None = None
    log_rate: float | None = None
    if given.source is not None:
        path = Path(given.source)
        if path.suffix.lower() == ".json":
            flown, estimates, log_rate, measured_noise = _flown_from_json(path)
        else:
            flown, estimates, log_rate, measured_noise = _from_log(path, model, given.min_cycles, given.read_options)
    assumed: list[str] = []
    prior_ranges = {}
    for name, default, unit, option in (("Td", (0.2, 3.0), "s", "--td-range"), ("tau", (0.01, 0.1), "s", "--tau-range"),
                                        ("K", (0.5, 20.0), "output / (command s^2)", "--k-range")):
        given_range = given.ranges_prior[name]
        # the analysis' intervals come from the flown tests' cycles, which the plan counts already (their
        # information, and draws conditioned on them): narrowing the prior with them counts the tests twice
        known = {} if flown else estimates
        prior_ranges[name] = given_range if given_range is not None else prior_range(known.get(name), default)
        if given_range is None and name not in known:
            assumed.append(f"prior {name} {default[0]:g}-{default[1]:g} {unit} (the default; give {option})")
    prior = Prior(Td=prior_ranges["Td"], tau=prior_ranges["tau"], K=prior_ranges["K"])
    rate = rate_hz if rate_hz is not None else log_rate
    if rate is None:
        raise InputError("give --controller-rate HZ, the rate the controller runs at (the test's frequency and its samples "
                         "per period depend on it; --from a log measures it)")
    noise = given.noise_std if given.noise_std is not None else measured_noise
    if noise is None:
        noise = default_noise_std(loop)
        assumed.append(f"sensor noise std {noise:.3g} [output units] (the {loop} loop's default, not measured; "
                       "give --noise)")
    assert given.max_amplitude is not None and given.max_h is not None and given.time_s is not None
    limits = PlanLimits(max_amplitude=given.max_amplitude, max_h=given.max_h, time_s=given.time_s, rate_hz=rate,
                          noise_std=noise)
    return prior, limits, flown, assumed


@click.command("plan")
@click.argument("log", required=False, type=InputPath(dir_okay=False))
@structure_options
@relay_options
@window_option
@tp_option(required=False, help="Known propulsion time constant Tp [s] (bench test); required by --model soiptd.")
@click.option("--from", "source", metavar="LOG|JSON", type=InputPath(),
              help="A first test: a log with MRFT test(s), or the JSON of 'mrft-ident analyze --json'. "
                   "With --model NAME: the log of the recorded relay tests (or give it as LOG).")
@click.option("--td-range", nargs=2, type=float, default=None, metavar="LOW HIGH",
              help="Prior range of Td [s] (default 0.2 3, or the analysed value +/- 2 std).")
@click.option("--tau-range", nargs=2, type=float, default=None, metavar="LOW HIGH",
              help="Prior range of tau [s] (default 0.01 0.1, stated as an assumption).")
@click.option("--k-range", nargs=2, type=float, default=None, metavar="LOW HIGH",
              help="Prior range of K [output / (command s^2)] (default 0.5 20, stated as an assumption).")
@click.option("--max-amplitude", type=float, default=None,
              help="Largest output amplitude allowed [output units, e.g. 0.05 m or 0.087 rad]. Required for "
                   "eq. (2); with --model NAME optional (a candidate over it is never recommended).")
@click.option("--max-h", type=float, default=None,
              help="Largest relay height the motors give [command units]. Required for eq. (2); with --model "
                   "NAME the candidates' relay half-height (default: the recorded tests').")
@click.option("--time", "time_s", type=float, default=None,
              help="Relay time available for the next test(s) [s] (eq. (2), required there).")
@click.option("--noise", "noise_std", type=float, default=None,
              help="Sensor noise std [output units] (default: measured in the log, else the loop's default).")
@click.option("--tests", "n_tests", type=click.IntRange(1, 4), default=None,
              help="How many next tests (sharing --time); default 2 without a first test, else 1.")
@click.option("--simulate", "n_simulated", type=click.IntRange(0, 64), default=8, show_default=True,
              help="Also fly the recommended test(s) in simulation on this many plausible plants and analyse "
                   "them (about 0.1-0.2 s each; 0: the analytic forecast only).")
@log_layout_options()
@min_cycles_option(detail=" from a --from log (at least 3 are used)")
@json_option(what="plan")
@quiet_option()
def plan(log: str | None, model_name: str, params: tuple[str, ...], ranges: tuple[str, ...], relay_kind: str | None,
         eps: float | None, windows: tuple[str, ...], Tp: float | None, source: str | None, td_range: tuple[float, float] | None, tau_range: tuple[float, float] | None,
         k_range: tuple[float, float] | None, max_amplitude: float | None, max_h: float | None,
         time_s: float | None,
         noise_std: float | None, n_tests: int | None, n_simulated: int, min_cycles: int, json_target: str | None,
         quiet: bool, **read_options: Any) -> None:
    """Recommend the next test(s) for the model: eq. (2)'s MRFT beta, h and duration, or a process plant's relay.

    Eq. (2) (--tp): the prior (ranges, and a first test from --from) and the flight's limits give each candidate
    test (beta in -0.9..-0.1, the largest h within --max-amplitude and --max-h, the time available)
    its predicted limit cycle (exact LPRS at the controller rate) and the expected standard
    deviations of Td, tau and K after it (Fisher information of the frequency, phase and amplitude
    analyze measures; docs/plan.md). Says when a parameter cannot be pinned down and what would help.

    With --model NAME (or --model-file FILE), for a process plant: the log's relay tests are analysed
    as 'analyze --model' does, and the next relay tests (ideal, hysteresis, MRFT) are ranked by the
    parameters' std after each, predicted with the exact limit cycle of the current model
    (docs/process-plants.md, "Planning the next test").

    Exit codes: 0 ok, 2 bad option or limits that admit no test, 3 unreadable log, 4 no usable test
    in the --from log.

    Example: mrft-ident plan --tp 0.0422 --from first.mcap --max-amplitude 0.05 --max-h 0.2 --time 20

    Example: mrft-ident plan first.csv --model fopdt --command-topic u_relay --output-topic y_output
    """
    if log is not None and source is not None:
        raise click.UsageError("give the log as LOG or as --from LOG, not both")
    given = _Given(source if log is None else log, model_name, params, ranges, windows, relay_kind, eps, Tp,
                   {"Td": td_range, "tau": tau_range, "K": k_range}, max_amplitude, max_h, time_s, noise_std,
                   min_cycles, read_options)
    _check_given(given)
    from ..mrft.model import LoopModel, soiptd_model
    from ..plan import PlanLimits, PlanOptions, plan_tests

    # the one model object: eq. (2) with Tp known, or the process structure (its known values and ranges)
    model = soiptd_model(Tp) if Tp is not None and model_name == "soiptd" else build_model(model_name, params, ranges)
    relay_limits = None if isinstance(model, LoopModel) else PlanLimits(max_amplitude, max_h)
    check_output_file(json_target, "--json")  # before the work, as analyze
    prior: Prior | None = None
    flown: Sequence[FlownTest] = ()
    recorded: AnalysisResult | None = None
    assumed: list[str] = []
    limits: PlanLimits
    if isinstance(model, LoopModel):
        prior, limits, flown, assumed = _mrft_inputs(model, given)
    else:
        assert relay_limits is not None
        limits, recorded = relay_limits, _recorded(model, given)
    try:
        # a relay plan takes well under a second: no bar to flash
        with tqdm_progress("plan", unit="step", enabled=not quiet and recorded is None) as progress:
            result = plan_tests(model, limits, prior=prior, flown=flown, recorded=recorded, progress=progress,
                                options=PlanOptions(n_tests=n_tests, n_simulated=n_simulated))
    except InputError as err:
        if not assumed:
            raise
        raise InputError(f"{err} (assumed: {'; '.join(assumed)})") from None
    if assumed:
        result = dataclasses.replace(result, assumptions=tuple(assumed))
    if json_target:
        dump_json(result.to_json(), json_target)
    if json_target != "-":
        click.echo(format_plan(result, output_unit(given.read_options["loop"])) if recorded is None
                   else format_relay_plan(result, str(given.source)))
