"""``mrft-ident tune``: controller gains from the identified model, robust to its uncertainty.

One path for every family: the source (a LOG, an analyze RESULT.json, the parameters given) becomes a
model object with its uncertainty (:class:`_TuneSource`), the one driver
(:func:`mrftcli.tune.design.tune`) designs for it by its family's strategy, and the table, the JSON and
the export are written from the one :class:`~mrftcli.tune.design.TuneResult`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from ..errors import InputError
from ..jsonable import load_json_text
from ..validate import TP_MISSING, check_spread, check_time

if TYPE_CHECKING:
    from ..io.source import LogSource
    from ..mrft.model import LoopModel, PlantModel
    from ..tune.design import Posterior, TuneResult
    from ..tune.stacks import StackExport, StackSetting
from .model_options import process_model, structure_options
from .options import (check_export_paths, check_output_dir, dump_json, echo_warnings, json_option,
                      log_layout_options, min_cycles_option,
                      quiet_option, tp_option, tqdm_progress)

#: ``--format``'s values before it named the log format (an export then), refused with what each is now
_EXPORT_NOT_FORMAT = {"table": "the design table is the default output (no option)",
                      "json": "the generic JSON export is --export generic (the whole tune record: --json -)",
                      "hear": "the export is --export hear", "px4": "the export is --export px4"}
#: the flight stacks ``--export`` knows besides generic: UAV autopilots, not process controllers
_UAV_STACKS = ("hear", "px4", "ardupilot")


@dataclass(frozen=True)
class ExportOptions:
    """What ``--export`` asked for: the stack (None: the design table), the file, the stack's settings."""

    stack: str | None
    out: str | None
    gyro_cutoff_hz: float | None
    hover_thrust: float | None
    clamp: bool
    stack_version: str | None = None
    xy_integral: float | None = None
    #: where ``hover_thrust`` came from when not given (read from the log), stated first in the export; empty: given
    hover_source: str = ""


@dataclass(frozen=True)
class _TuneSource:
    """What the designs start from: the model, its posterior, the loop and the controller rate [Hz] the
    source records (None: unknown), the tests' relay heights and output amplitudes (for the PX4 mapping),
    notes."""

    model: PlantModel
    posterior: Posterior | tuple[PlantModel, ...] | None
    loop: str | None
    rate_hz: float | None = None
    heights: tuple[float, ...] = ()
    amplitudes: tuple[float, ...] = ()
    notes: tuple[str, ...] = ()


def _from_spread(known: LoopModel, td: float | None, tau: float | None, K: float | None,
                 stds: tuple[float, float, float]) -> _TuneSource:
    """The model given with --td/--tau/--k, with a posterior when a std is given.

    Every parameter is required: the gains scale as 1/K, so an assumed K = 1 would print gains off by
    the factor the true K differs from 1 (issue 26).
    """
    from ..tune.design import Posterior

    if td is None and tau is None and K is None:
        raise InputError("give a LOG or RESULT.json, or the model with --td S, --tau S and --k K")
    missing = [f"--{name}" for name, v in (("td", td), ("tau", tau), ("k", K)) if v is None]
    if missing:
        raise InputError(f"missing {', '.join(missing)}: the model needs Td [s], tau [s] and the gain K "
                         "[output unit / s^2 per command unit] (analyze reports all three; the gains scale as 1/K)")
    assert td is not None and tau is not None and K is not None  # narrowed by the check above
    check_time("--td", td)
    check_time("--tau", tau)
    if not math.isfinite(K) or K == 0:
        raise InputError(f"--k must be a finite, non-zero gain, got {K}")
    model = known.with_parameters(Td=td, tau=tau, K=K)
    for name, std, value in zip(("--td-std", "--tau-std", "--k-std"), stds, (td, tau, K)):
        check_spread(name, std, value)
    posterior = None
    if any(s and s > 0 for s in stds):
        posterior = Posterior.from_spread(model, *stds, n=200, seed=0,
                                          source="log-normal draws from --td-std/--tau-std/--k-std")
    return _TuneSource(model, posterior, None)


def _check_stack(ex: ExportOptions, loop: str, kind: str) -> None:
    """A stack that cannot take this loop or kind is refused before the work (the values are checked again)."""
    from ..tune.stacks import HOVER_LOOPS, check_exportable

    if ex.stack is not None and ex.stack not in ("generic", "hear"):
        check_exportable(ex.stack, loop, kind, ex.hover_thrust)
    # an option the chosen export does not use is an error, not silently ignored
    if ex.gyro_cutoff_hz is not None and not (ex.stack in ("px4", "ardupilot") and loop in ("roll", "pitch")):
        raise InputError("--gyro-cutoff is for --export px4|ardupilot on roll or pitch (the stack's gyro filter)")
    if ex.hover_thrust is not None and loop not in HOVER_LOOPS.get(ex.stack or "", ()):
        raise InputError("--hover-thrust is for --export px4|ardupilot on the altitude loop (and px4 on x, y)")
    if ex.xy_integral is not None:
        from ..tune.stacks import check_xy_integral

        check_xy_integral(ex.stack, loop, ex.xy_integral)


@contextlib.contextmanager
def _log_once(source: str | None, read_options: dict[str, Any]) -> Iterator[Callable[[], LogSource]]:
    """A getter of the LOG ``source``, opened at its first use (the hover thrust, then the analysis) and closed on
    leaving: a PX4 log is opened once (it was opened for each, as vehicle's is once)."""
    from ..io import open_log

    with contextlib.ExitStack() as stack:
        opened: list[LogSource] = []

        def get() -> LogSource:
            if not opened:
                assert source is not None
                opened.append(stack.enter_context(open_log(source, read_options.get("fmt"), echo_warnings=False,
                                                           time_unit=read_options.get("time_unit"))))
            return opened[0]
        yield get


def _hover_from_log(ex: ExportOptions, source: str | None, read_options: dict[str, Any],
                    log: Callable[[], LogSource]) -> ExportOptions:
    """PX4's hover thrust read from a LOG (``log()``, :func:`_log_once`) when ``--hover-thrust`` is not given and
    the loop's export needs it (:func:`mrftcli.tune.stacks.read_hover_thrust`, as vehicle does), before the
    analysis; ``ex`` unchanged otherwise, and for a JSON source (its export is checked when its loop is known)."""
    from ..io.hover import logged_hover_thrust
    from ..tune.stacks import read_hover_thrust

    loop = read_options["loop"]
    if source is None or str(source).lower().endswith(".json") or loop is None:
        return ex
    logged = read_hover_thrust(ex.stack, (loop,), ex.hover_thrust, lambda: logged_hover_thrust(log()))
    return ex if logged is None else dataclasses.replace(ex, hover_thrust=logged.value,
                                                         hover_source=logged.statement())


def _stack_setting(ex: ExportOptions, loop: str, rate_given: float | None,
                   rate_source: float | None) -> StackSetting | None:
    """The rate and rate filter the chosen stack runs (None: no stack; the generic export designs as the table)."""
    from ..tune.stacks import stack_setting

    if ex.stack is None or ex.stack == "generic":
        return None
    return stack_setting(ex.stack, loop, rate_given, rate_source, ex.gyro_cutoff_hz)


def from_result_json(path: Path, known: LoopModel, loop: str | None) -> _TuneSource:
    """An ``analyze --json`` file, read by :meth:`~mrftcli.analyze.AnalysisResult.from_json`; ``known``: eq. (2)
    with the bench test's Tp (``soiptd_model(--tp)``), which the file's must equal.

    Without ``loop`` (no --loop) the loop is the one the file was analysed for.
    """
    from ..analyze import AnalysisResult
    from ..tune.analysis import model_from_result_json

    try:
        result = AnalysisResult.from_json(load_json_text(path.read_text(), str(path)))
        model, post, note = model_from_result_json(result, known)
    except InputError as err:  # before ValueError, its base: the record's own one line, named once
        raise InputError(str(err) if str(err).startswith(str(path)) else f"{path}: {err}") from err
    except (ValueError, OSError) as err:
        raise InputError(f"{path}: not an analyze RESULT.json ({err})") from err
    if loop is not None and result.loop and result.loop != loop:
        raise InputError(f"--loop {loop} but {path} was analysed for the {result.loop} loop")
    if not (loop or result.loop):
        raise InputError(f"give --loop altitude|roll|pitch|x|y: {path} does not record its loop")
    # the rate the analysis recorded: the controller's, as when the LOG is given (not the logging rate)
    return _TuneSource(model, post, loop or result.loop, result.controller_rate_hz,
                       tuple(float(t.h) for t in result.tests),
                       tuple(float(t.amplitude_mean) for t in result.tests), (note,))


def _from_log(source: str, known: LoopModel, min_cycles: int, read_options: dict[str, Any],
              quiet: bool = False, log: Callable[[], LogSource] | None = None) -> _TuneSource:
    """A flight log, analysed as ``analyze`` would (its warnings printed when the command ends, after its output)."""
    from ..analyze import AnalyzeOptions, analyze_path
    from ..io import ReadOptions
    from ..tune.analysis import posterior_from_analysis

    with tqdm_progress("tune", unit="step", enabled=not quiet) as progress:
        progress(0, 1, "analysing the log")
        read = ReadOptions(**read_options)
        # tune has no --diagnose: AnalyzeOptions' default hint points to the command
        result = analyze_path(source, known, read=read, options=AnalyzeOptions(min_stable_cycles=min_cycles),
                              log=None if log is None else log())  # opened once: _log_once
    # after tune's own lines (as analyze prints them): a lead's 'assumed:' design note is then read first
    click.get_current_context().call_on_close(lambda: echo_warnings(result.warnings))
    return _TuneSource(result.model, posterior_from_analysis(result), result.loop, result.controller_rate_hz,
                       tuple(float(t.h) for t in result.tests), tuple(float(t.amplitude_mean) for t in result.tests))


def _source_json(source: str | None) -> Any:
    """SOURCE parsed once when it is a ``.json`` file (None: not one, or unreadable: its own reader then says why)."""
    if source is None or not str(source).lower().endswith(".json"):
        return None
    try:
        with open(source, encoding="utf-8") as fh:
            return load_json_text(fh.read(), source)
    except (OSError, ValueError):  # InputError too: the caller's own reader then says why
        return None


def _family_asked(given: PlantModel | None, data: Any) -> bool:
    """Is this ``tune`` for a family other than eq. (2): ``--model NAME``/``--model-file`` given (``given``), or SOURCE
    (``data``, parsed) an ``analyze --model NAME --json`` result (its ``model`` a family other than soiptd)?"""
    if given is not None:
        return True
    return isinstance(data, dict) and isinstance(data.get("model"), str) and data["model"] != "soiptd" \
        and "identification" in data


def _family_source(given: PlantModel | None, source: str | None, data: Any) -> _TuneSource:
    """A family's model with its draws (none without a spread), from ``--model``/``--param`` (``given``) or an analyze
    RESULT.json: ``analyze --model NAME``'s (``rate_hz`` the tests' controller rate when they share one) or
    an outer loop's cascade (``analyze --inner-model``'s: draws over the outer estimate and the inner loop,
    the rate its outer controller ran at)."""
    from ..mrft.cascade import CascadeModel
    from ..tune.grid import N_DRAWS, model_draws, outer_draws

    if source is None:
        model = given
        assert model is not None  # a family without a SOURCE: --model was given
        missing = [p.name for p in model.parameters.values() if not p.known]
        if missing:
            raise InputError(f"give every parameter of {model.family} with --param NAME=VALUE: missing "
                             f"{', '.join(missing)} (or tune an analyze --model {model.family} RESULT.json)")
        return _TuneSource(model, None, "")
    if given is not None:
        raise InputError("give a RESULT.json or --model with --param, not both (the file holds its model)")
    from ..analyze.record import AnalysisResult

    if data is None:
        raise InputError(f"{source}: tune on a process plant takes the RESULT.json of analyze LOG --model NAME "
                         "--json RESULT.json (or --model NAME with every --param)")
    analysis = AnalysisResult.from_json(data)
    ident = analysis.identification
    if ident is None:
        raise InputError(f"{source}: the analysis identified no model (no usable test): nothing to tune")
    if isinstance(analysis.model, CascadeModel):
        return _TuneSource(analysis.model, tuple(outer_draws(analysis.model, ident.estimates, N_DRAWS)),
                           analysis.loop, analysis.controller_rate_hz)
    rates = sorted({round(t.rate_hz, 6) for t in analysis.tests})
    draws, notes = model_draws(ident.model, list(ident.estimates), N_DRAWS)
    return _TuneSource(ident.model, tuple(draws), analysis.loop, rates[0] if len(rates) == 1 else None,
                       notes=notes)


def _refuse_unused(options: dict[str, Any], why: str, error: type[Exception] = click.UsageError) -> None:
    """The options given (true values) that this route does not take: one line naming them, then ``why``."""
    used = [name for name, value in options.items() if value]
    if used:
        raise error(f"{', '.join(used)}{why}")


def _refuse_for_family(unsupported: dict[str, Any], ex: ExportOptions, design: str | None) -> None:
    """The options a process family's design does not take: a one-line error, never ignored."""
    _refuse_unused(unsupported, ": not for a process plant (tune designs PI/PID/PD on it with --controller-rate, "
                   "--ms-max, --design, --kind, --json, --export generic)")
    if ex.stack in _UAV_STACKS:
        raise InputError(f"--export {ex.stack}: {ex.stack} is a UAV flight stack, not a process controller; "
                         "a process plant's gains export as --export generic")
    if design == "mrft-rule":
        raise InputError("--design mrft-rule is the DNN-MRFT rule for eq. (2) loops; a process plant has "
                         "model-based and robust designs")


def _write_outputs(res: TuneResult, src: _TuneSource, rate: float, loop: str, design: str | None,
                   kind: str, json_target: str | None, ex: ExportOptions, quiet: bool = True) -> StackExport | None:
    """The table, or the chosen export (on stdout or --out), and every design as JSON with --json; returns the
    stack export (None: the table or the generic export). A stack's export designed inside its ranges takes
    seconds: a bar says so unless ``quiet``."""
    from ..tune.analysis import recommended_design_name
    from ..tune.export import format_table, hear_json, px4_params
    from ..tune.stacks import ExportEvidence, export_design

    from ..mrft.model import LoopModel

    name = design or recommended_design_name(res, kind)
    eq2 = isinstance(res.model, LoopModel)
    try:
        chosen = res.get(name, kind)
    except KeyError:
        have = ", ".join(f"{d.name} {d.kind}" for d in res.designs)
        raise InputError(f"no {name} {kind} design for this plant (have: {have})") from None
    c = chosen.controller
    # the one versioned record (TuneResult.from_json reads it back), with the chosen design's export beside it
    data = {**res.to_json(), "export": (
        {"design": name, "kind": kind, "generic": c.to_dict(), "hear": hear_json(c, loop)} if eq2 else
        {"design": name, "kind": kind, "generic": c.to_dict(), "reverse_acting": res.reverse_acting})}
    stack_export, refused = None, None
    if ex.stack in (None, "generic"):
        if eq2:
            try:
                data["export"]["px4"] = px4_params(c, loop, list(src.heights), list(src.amplitudes))
            except InputError as err:
                data["export"]["px4"] = {"refused": str(err)}
    else:
        try:
            evidence = ExportEvidence(tuple(src.heights), tuple(src.amplitudes), tuple(res.notes), tuple(_in_set(src)),
                                      ex.hover_source)
            with tqdm_progress("tune", unit="step", enabled=not quiet) as progress:
                progress(0, 1, f"the {ex.stack} export")
                stack_export = export_design(ex.stack, c, res.loop_model, loop, f"{name} {kind}", clamp=ex.clamp,
                                             hover_thrust=ex.hover_thrust, version=ex.stack_version, evidence=evidence,
                                             xy_integral=ex.xy_integral)
            data["export"]["stack"] = stack_export.to_json()
        except InputError as err:
            refused = err
            data["export"]["stack"] = {"stack": ex.stack, "refused": str(err)}
    if json_target:
        dump_json(data, json_target)
    if refused is not None:
        raise refused
    if ex.stack is None:
        if json_target != "-":
            click.echo(format_table(res))
            click.echo(f"export ({name} {kind}): Kp {c.Kp:.5g}  Ki {c.Ki:.5g}  "
                       f"Kd {c.Kd:.5g}  Tf {c.Tf:.5g} s  rate {rate:g} Hz")
        return None
    if stack_export is None:  # generic: the controller as JSON
        from ..tune.export import generic_export

        text = generic_export(res, name, kind)
        summary = [f"export generic ({name} {kind}, {loop})" if loop else f"export generic ({name} {kind})"]
    else:
        text, summary = stack_export.file_text(), stack_summary(stack_export)
    write_export(text, summary, ex.out, json_target)
    return stack_export


def write_export(text: str, summary: list[str], out: str | None, json_target: str | None) -> None:
    """The export to ``out`` (atomically; the summary on stdout, or on stderr when ``--json -`` has stdout) or to
    stdout (the summary on stderr)."""
    if out:
        from ..io.atomic import write_text_atomic

        write_text_atomic(out, text)  # the usual permissions, never a half-written file
        summary.append(f"written: {out}")
        click.echo("\n".join(summary), err=json_target == "-")
    else:
        click.echo(text, nl=False)
        click.echo("\n".join(summary), err=True)


def _in_set(src: _TuneSource) -> list[Any]:
    """The posterior's 95 % set's models (empty without eq. (2)'s posterior)."""
    from ..tune.design import Posterior

    post = src.posterior
    return post.in_set_models() if isinstance(post, Posterior) else []


def _parse_cutoff(value: str | None) -> tuple[bool, float | None]:
    """``--gyro-cutoff``: (auto, the cutoff [Hz] or None)."""
    if value is None:
        return False, None
    if value.strip().lower() == "auto":
        return True, None
    try:
        hz = float(value)
    except ValueError:
        raise InputError(f"--gyro-cutoff {value}: give auto or a cutoff in Hz (0: the filter off)") from None
    if not (math.isfinite(hz) and hz >= 0):
        raise InputError(f"--gyro-cutoff {value}: the cutoff must be a finite frequency >= 0 Hz")
    return False, hz


def stack_summary(e: Any, console: bool = True) -> list[str]:
    """The lines that say what was exported: values with their ranges, the margins with the stack's filter,
    the notes, and PX4's ``param set`` lines."""
    from ..tune.ardupilot_z import margins_qualifier
    from ..tune.stack_params import STACK_PARAMS

    rows = {p.name: p for p in STACK_PARAMS if p.stack == e.stack}
    version = f", ArduPilot Copter {e.version} names" if e.version else ""
    out = [f"assumption: {a}" for a in e.assumptions] + [f"export {e.stack} ({e.design}, {e.loop}{version}):"]
    for n, v in e.params.items():
        p = rows.get(n)
        rng = f"  [{p.minimum:g} .. {p.maximum:g} {p.unit}]" if p else ""
        out.append(f"  {n} = {v:.6g}{rng}")
    m = e.margins
    out.append(f"margins with the stack's filter and rate{margins_qualifier(e.stack, e.loop)}: GM {m.gain_margin:.3g}  PM {m.phase_margin_deg:.1f} deg  "
               f"delay margin {m.delay_margin_s * 1e3:.1f} ms  Ms {m.Ms:.3g}")
    out += [f"pre-arm: {r['rule']} with {r['value']:.6g}: {'pass' if r['passed'] else 'FAIL'} ({r['source']})"
            for r in e.prearm]
    out += [f"note: {n}" for n in e.notes]
    if console:
        out += e.console_lines()
    return out


class _XYIntegralOption(click.Option):
    """``--xy-integral``, whose help names MPC_XY_VEL_I_ACC's range from tune's stack table when help is shown (the
    CLI does not import tune to start)."""

    def get_help_record(self, ctx: click.Context) -> tuple[str, str] | None:
        from ..tune.stack_params import param

        row = param("px4", "MPC_XY_VEL_I_ACC")
        self.help = (f"PX4 MPC_XY_VEL_I_ACC [{row.unit}, {row.minimum:g}-{row.maximum:g}; PX4's default {row.default:g}] "
                     "for --export px4 on x or y: designed with (Ms search, margins) and written, the wind offset and "
                     "step it gives stated. Default 0 (a PD: a steady wind is not corrected; the offset per m/s^2 is "
                     "stated).")
        return super().get_help_record(ctx)


@click.command("tune")
@structure_options
@click.argument("sources", nargs=-1, type=click.Path(dir_okay=True))
@tp_option(required=False, help="Known propulsion time constant Tp [s] (bench test); required, except for a cascade RESULT.json (analyze --inner-model), which carries its inner loop's.")  # required but for a cascade RESULT.json (its Tp is the inner analysis'): checked below
@log_layout_options(format_alias="--log-format", format_misnamed=_EXPORT_NOT_FORMAT)
@min_cycles_option(detail=" (as analyze)")
@click.option("--td", type=float, help="Td [s], instead of a LOG or RESULT.json.")
@click.option("--tau", type=float, help="tau [s], with --td.")
@click.option("--k", "K", type=float, help="Gain K [output unit / s^2 per command unit, e.g. m/s^2 for altitude], "
              "with --td (required: the gains scale as 1/K).")
@click.option("--td-std", type=float, default=0.0, help="Std of Td [s] for the robust design (with --td).")
@click.option("--tau-std", type=float, default=0.0, help="Std of tau [s] for the robust design (with --td).")
@click.option("--k-std", type=float, default=0.0, help="Std of K [--k's unit] for the robust design (with --td).")
@click.option("--objective", type=click.Choice(["iae", "itae"]), default="iae", show_default=True,
              help="Criterion of a unit setpoint step.")
@click.option("--ms-max", type=float, default=1.6, show_default=True, help="Limit on the sensitivity peak Ms [-].")
@click.option("--effort-max", type=float, default=None,
              help="Limit on the controller's noise gain |C| at Nyquist [command/output unit] (default: the MRFT rule's).")
@click.option("--export", "export", type=click.Choice(["generic", "px4", "ardupilot", "hear"]), default=None,
              help="Design for the stack's own rate and rate filter and write what it loads: PX4 QGroundControl "
                   ".params (and param set lines), ArduPilot .param, HEAR PID JSON, generic JSON; checked "
                   "against the stack's parameter ranges.")
@click.option("--out", "-o", "out", metavar="FILE", help="Write the export to FILE (atomically); default: stdout.")
@click.option("--gyro-cutoff", "gyro_cutoff", metavar="auto|HZ",
              help="PX4 IMU_GYRO_CUTOFF / ArduPilot INS_GYRO_FILTER [Hz] the design runs with (one SOURCE: default "
                   "the stack's default, stated; ROLL.json PITCH.json: default auto, the cutoff designed from both "
                   "axes, docs/tune.md).")
@click.option("--hover-thrust", "hover_thrust", type=float, metavar="X",
              help="Hover thrust, normalised 0-1 (PX4 MPC_THR_HOVER, ArduPilot MOT_THST_HOVER), required for "
                   "the altitude exports and PX4's x and y (PX4: default a LOG's hover_thrust_estimate, stated).")
@click.option("--xy-integral", "xy_integral", cls=_XYIntegralOption, type=float, metavar="I_ACC", default=None)
@click.option("--stack-version", "stack_version", type=click.Choice(["4.6", "4.7"]), default=None,
              help="ArduPilot release whose parameter names and scalings the file uses (4.7 renamed PSC_POSZ_/VELZ_/"
                   "ACCZ_ to PSC_D_POS_/D_VEL_/D_ACC_); default: the current stable release, 4.7, named in the file.")
@click.option("--clamp", is_flag=True, help="Export values outside the stack's ranges at the bound (the "
              "resulting margins are stated) instead of refusing.")
@click.option("--design", type=click.Choice(["robust", "model-based", "mrft-rule"]), default=None,
              help="Design exported (default: robust, else model-based).")
@click.option("--kind", type=click.Choice(["PD", "PI", "PID"]), default="PD", show_default=True,
              help="Controller exported (PI: process plants only, their default).")
@json_option(what="tune record (model, every design with its gains and figures) and the chosen export")
@click.option("--report", "report_dir", metavar="DIR", type=click.Path(file_okay=False),
              help="Write plots (Bode with margins, step responses with the posterior band) and index.html to DIR.")
@quiet_option()
def tune(sources, model_name, params, ranges, Tp, min_cycles, td, tau, K, td_std, tau_std, k_std, objective, ms_max, effort_max,
         export, out, gyro_cutoff, hover_thrust, xy_integral, stack_version, clamp, design, kind, json_target, report_dir, quiet,
         **read_options):
    """PD and PID gains for the identified loop: MRFT rule, model-based and robust designs.

    SOURCE is a flight log (analysed exactly as `analyze` would, same options), an analyze
    RESULT.json, or absent with --td/--tau/--k; or two RESULT.json files, a roll and a pitch one, with
    --export px4|ardupilot: both axes designed with one gyro cutoff (--gyro-cutoff auto|HZ) and one
    file written. Each design is reported with its gain, phase and
    delay margins, Ms and the step response of the sampled loop (overshoot, rise, settling), nominal
    and over the identification's posterior (median, worst of the 95 % set).

    The same command for every model: an `analyze --model NAME` RESULT.json (or --model NAME with every
    --param) gets PI/PID (PD on integrating plants) on its exact sampled loop, an `analyze --inner-model`
    RESULT.json an outer PD on the cascade; one TuneResult record in --json.

    Example: mrft-ident tune flight.mcap --tp 0.0422 --loop roll --export px4 --out roll.params
    """
    from ..mrft.model import soiptd_model
    from ..tune.design import DesignOptions
    from ..tune.design import tune as run_tune

    if len(sources) > 2:
        raise InputError(f"{len(sources)} sources: give one SOURCE, or a roll and a pitch RESULT.json with "
                         "--export px4|ardupilot")
    cutoff_auto, cutoff_hz = _parse_cutoff(gyro_cutoff)
    ex = ExportOptions(export, out, cutoff_hz, hover_thrust, clamp, stack_version, xy_integral)
    if stack_version is not None and ex.stack != "ardupilot":
        raise InputError("--stack-version is for --export ardupilot (PX4's and HEAR's names do not differ by version)")
    ctx = click.get_current_context()
    source = sources[0] if sources else None
    data = _source_json(source) if len(sources) == 1 else None  # SOURCE parsed once
    cascade = isinstance(data, dict) and data.get("kind") == "cascade"  # analyze --inner-model's result
    given = process_model(model_name, params, ranges)  # None: eq. (2)
    family = cascade or (len(sources) < 2 and _family_asked(given, data))
    if cascade:  # analyze --inner-model's result: outer gains on the cascade (its Tp is the inner analysis')
        _refuse_unused({"--report": report_dir, "--kind PID": kind != "PD", "--tp": Tp,
                        "--design mrft-rule": design == "mrft-rule",
                        "--controller-rate": read_options.get("controller_rate_hz"),
                        "--xy-integral": xy_integral is not None},
                       ": not for a cascade analysis (its Tp is the inner analysis'; tune designs a PD on the cascade "
                       "with --export generic, --json, --design, --ms-max)")
        if ex.stack not in (None, "generic"):
            raise click.UsageError(f"--export {ex.stack} does not work on a cascade analysis yet (use --export generic)")
    elif family:  # another family than eq. (2): its kinds and designs, its export
        if ctx.get_parameter_source("kind") is not click.core.ParameterSource.COMMANDLINE:
            kind = "PI"  # tune's default PD is eq. (2)'s: a process plant's is PI
        _refuse_for_family({"--tp": Tp, "--td/--tau/--k": any(v is not None for v in (td, tau, K)),
                            "--report": report_dir, "--effort-max": effort_max, "--hover-thrust": hover_thrust,
                            "--xy-integral": xy_integral is not None, "--gyro-cutoff": gyro_cutoff, "--clamp": clamp, "--objective itae": objective != "iae"},
                           ex, design)
    elif _other_routes(sources, Tp, ex, kind, design, cutoff_auto, objective, ms_max, effort_max,
                       (td, tau, K), json_target, report_dir, quiet, read_options):
        return
    check_export_paths(json_target, out, ex.stack is not None)  # before the work starts; never over a source
    check_output_dir(report_dir, "--report")
    if out and ex.stack is None:
        raise InputError("--out needs --export generic" + ("" if family else "|px4|ardupilot|hear"))
    rate_given: float | None = read_options.get("controller_rate_hz")
    setting = None
    if family:
        src = _family_source(given, source, data)
        loop = src.loop or ""
        options = DesignOptions(ms_max=ms_max)
    else:
        with _log_once(source, read_options) as log:
            ex = _hover_from_log(ex, source, read_options, log)
            src, loop = _eq2_source(source, soiptd_model(Tp), (td, tau, K, td_std, tau_std, k_std), ex, kind,
                                    min_cycles, read_options, quiet, log)
        setting = _stack_setting(ex, loop, rate_given, src.rate_hz)
        options = DesignOptions(objective=objective, ms_max=ms_max, effort_max=effort_max,
                                rate_filter=setting.rate_filter if setting is not None else None)
    rate, rate_notes = _design_rate(rate_given, setting, src, family and source is not None)
    if cascade:
        rate_notes = ()  # the outer controller's rate, as analysed
    with tqdm_progress("tune", unit="design", enabled=not quiet and not family) as progress:
        res = run_tune(src.model, rate, posterior=src.posterior, options=options, loop=loop, progress=progress)
    notes = rate_notes + src.notes + (setting.notes if setting is not None else ())
    if notes:
        from ..tune.design import assumptions_first

        res = dataclasses.replace(res, notes=assumptions_first(notes + res.notes))  # a lead's design first
        # the table shows its notes itself, a stack's export in its summary
        if not family and (ex.stack == "generic" or (json_target == "-" and ex.stack is None)):
            for n in notes:
                click.echo(f"note: {n}", err=True)
    stack_export = _write_outputs(res, src, rate, loop, design, kind, json_target, ex, quiet)
    if report_dir:
        from ..report.tune import write_tune_report

        click.echo(f"report: {write_tune_report(res, report_dir, stack_export)}",
                   err=ex.stack is not None or json_target == "-")


def _other_routes(sources: tuple[str, ...], Tp: float | None, ex: ExportOptions, kind: str, design: str | None,
                  cutoff_auto: bool, objective: str, ms_max: float,
                  effort_max: float | None, given: tuple[float | None, ...], json_target: str | None,
                  report_dir: str | None, quiet: bool, read_options: dict[str, Any]) -> bool:
    """Eq. (2)'s joint roll and pitch export (True: done); the checks before one loop's."""
    if kind == "PI":
        raise InputError("--kind PI is for process plants (analyze --model NAME's result); eq. (2) loops take PD or PID")
    if len(sources) == 2:
        unsupported = {"--td/--tau/--k": any(v is not None for v in given), "--report": report_dir,
                       "--effort-max": effort_max, "--hover-thrust": ex.hover_thrust, "--loop": read_options["loop"],
                       "--xy-integral": ex.xy_integral is not None,
                       "--design mrft-rule": design == "mrft-rule"}
        _refuse_unused(unsupported, " cannot be used with two results (the joint roll and pitch export)", InputError)
        from ..mrft.model import soiptd_model
        from .tune_axes import AxesRequest, tune_axes

        tune_axes(AxesRequest(sources, None if Tp is None else soiptd_model(Tp), ex, cutoff_auto or ex.gyro_cutoff_hz is None,
                              read_options.get("controller_rate_hz"), objective, ms_max, design or "robust", kind,
                              json_target, quiet))
        return True
    if cutoff_auto:
        raise InputError("--gyro-cutoff auto designs one cutoff from the roll and the pitch loop: give ROLL.json "
                         "PITCH.json (or --gyro-cutoff HZ)")
    if Tp is None:
        raise click.UsageError(f"missing --tp: {TP_MISSING}")
    return False


def _eq2_source(source: str | None, known: LoopModel, given: tuple[Any, ...], ex: ExportOptions, kind: str,
                min_cycles: int, read_options: dict[str, Any], quiet: bool,
                log: Callable[[], LogSource] | None = None) -> tuple[_TuneSource, str]:
    """Eq. (2)'s model and posterior from a LOG, a RESULT.json or --td/--tau/--k (with their stds), and the loop."""
    td, tau, K, *stds = given
    if source is not None and any(v is not None for v in (td, tau, K)):
        raise InputError("give either SOURCE (a log or RESULT.json) or --td/--tau/--k, not both")
    is_result = source is not None and str(source).lower().endswith(".json") and Path(source).is_file()
    loop: str | None = read_options["loop"]
    if loop is None and not is_result:
        # the gains, their HEAR/PX4 export and the log's signals all depend on the loop: never assumed
        raise InputError("give --loop altitude|roll|pitch|x|y: the loop the gains are for")
    if loop is not None:
        _check_stack(ex, loop, kind)  # before the work starts
    if source is None:
        src = _from_spread(known, td, tau, K, (stds[0], stds[1], stds[2]))
    elif is_result:
        src = from_result_json(Path(source), known, loop)
    else:
        src = _from_log(source, known, min_cycles, read_options, quiet, log)
    loop = loop or src.loop
    assert loop is not None  # from_result_json refuses a file without its loop
    _check_stack(ex, loop, kind)
    return src, loop


def _design_rate(rate_given: float | None, setting: StackSetting | None, src: _TuneSource,
                 from_result: bool) -> tuple[float, tuple[str, ...]]:
    """The controller rate [Hz] the gains are designed for (--controller-rate, the stack's, the source's) and,
    for a process family, the note saying which."""
    if setting is not None:
        return setting.rate_hz, ()
    rate = rate_given or src.rate_hz
    if rate is None:
        raise InputError("give --controller-rate HZ, the rate the controller runs at: the gains are designed for "
                         "the sampled loop and " + ("the tests' rates differ" if from_result else
                                                     "the source records no rate"))
    from ..mrft.model import LoopModel

    if isinstance(src.model, LoopModel):
        return rate, ()
    if rate_given is not None:
        return rate, (f"controller rate {rate_given:g} Hz: --controller-rate",)
    return rate, (f"controller rate {rate:g} Hz: the analysis' tests' rate",)


def _loop_required(command: click.Command) -> None:
    """tune's --loop has no default (the shared option's is altitude): the gains are for one loop."""
    for param in command.params:
        if param.name == "loop" and isinstance(param, click.Option):
            param.default = None
            param.show_default = False
            param.help = ("Loop the gains are for (required with a LOG or --td; default for a RESULT.json: the "
                          "loop it was analysed for).")


_loop_required(tune)
