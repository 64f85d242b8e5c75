"""``mrft-ident watch``: follow a log while it is recorded and print tests and estimates as they come."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from ..jsonable import to_jsonable
from ..report.wording import output_unit
from .model_options import parameter_display, relay_options, soiptd_or_process, structure_options
from .options import log_layout_options, min_cycles_option, tp_option

if TYPE_CHECKING:
    from collections.abc import Callable

    from ..analyze import AnalysisResult
    from ..mrft.model import PlantModel
    from ..mrft.parameter import ParameterEstimate
    from ..watch import EstimateUpdate, TestUpdate, Update, WatchEnd

    #: how a parameter is shown: ``display(name, estimate) -> (scale from the record's unit, unit shown)``
    _Display = Callable[[str, ParameterEstimate], tuple[float, str]]

__all__ = ["watch"]

#: a process plant's output and command are in the user's units (the model's K is output / command)
_PROCESS_UNIT = "output units"


def _units(model: PlantModel, loop: str) -> tuple[str, _Display]:
    """The output's unit and how each parameter is shown, as analyze shows it (:func:`parameter_display`): eq. (2)'s
    loop is a vehicle's (m or rad; tau in ms, K per command unit), a process plant's output is in the user's units
    (its parameters in the record's, tau in s)."""
    from ..mrft.model import LoopModel

    if isinstance(model, LoopModel):
        return output_unit(loop), parameter_display("soiptd", loop)
    return _PROCESS_UNIT, parameter_display("family", loop)


def _test_line(update: TestUpdate, unit: str) -> str:
    """A test: its start in seconds from the log's first command sample (as analyze prints it), its relay (a
    process plant's, inferred or stated) or eq. (2)'s betas, the cycle's figures."""
    relay = update.relay
    if relay is None:
        nom = f"{update.beta_nominal:+.3f}" if update.beta_nominal is not None else "-"
        how = f"beta nom {nom}  eff {update.beta_effective:+.3f}"
    else:
        how = f"{relay.describe()} ({relay.source})"
    text = (f"test {update.number}  t {update.t_start - update.t_log_start:7.1f} s  {how}  "
            f"f {update.frequency_hz:.4f} Hz  amplitude {update.amplitude:.4g} {unit}  "
            f"cycles {update.stable_cycles}/{update.cycles}")
    return text + "".join(f"; {n}" for n in update.notes)


def _parameter(e: ParameterEstimate, final: bool, display: _Display) -> str:
    """One parameter with its unit, as analyze shows it (and its std on the final update)."""
    scale, unit = display(e.name, e)
    unit = f" {unit}" if unit else ""  # a declared model's parameter may have no unit
    if e.known:
        return f"{e.name} {e.value * scale:.4g}{unit} (known)"
    spread = f" ± {e.std * scale:.2g}" if final and math.isfinite(e.std) else ""
    return f"{e.name} {e.value * scale:.4g}{spread}{unit}"


def _estimate_line(update: EstimateUpdate, unit: str, units: _Display) -> str:
    """The parameters the tests determine, with units; the others named with analyze's advice, not a number;
    the final one with each test's held-out prediction, the analysis's notes and warnings."""
    head = "final    " if update.final else "estimate "
    shown = [_parameter(e, update.final, units) for e in update.parameters if e.name not in update.undetermined]
    text = f"{head} {'  '.join(shown) or 'no parameter determined yet'}  (tests {', '.join(map(str, update.tests))})"
    if update.undetermined:
        text += f"; {update.advice}" if update.final else f"; so far {update.advice}"
    from ..mrft.identify import LEAD_WORDS

    if not update.final and any(w.startswith(LEAD_WORDS) for w in update.warnings):
        # a running tau < 0 is a lead (or a Tp given too large), said on its line: the final states it in full
        text += "; tau < 0: the loop leads eq. (2) (an estimator's lead, or check --tp)"
    if update.analysis is not None:  # as analyze prints them
        text += _held_out_lines(update.analysis, unit)
        text += "".join(f"\nnote: {n}" for n in update.analysis.notes)
        text += "".join(f"\nwarning: {w}" for w in update.warnings)
    return text


def _held_out_lines(analysis: AnalysisResult, unit: str) -> str:
    """Each test's cycle as predicted from the other tests, beside the measured one."""
    eq2 = analysis.kind == "soiptd"
    rows = [(t.index + 1, analysis.held_out_of(k), t.frequency_hz_mean if eq2 else t.frequency_hz,
             t.amplitude_mean if eq2 else t.amplitude) for k, t in enumerate(analysis.tests)]
    return "".join(f"\nheld-out test {n}: " + ("none" if ho is None else ho.describe(f, a, unit))
                   for n, ho, f, a in rows)


def _end_line(update: WatchEnd) -> str:
    return (f"stopped: the writer {'closed the file' if update.reason == 'closed' else 'stopped writing'}; "
            f"{update.tests} test(s)")


def _line(update: Update, unit: str, units: _Display) -> str:
    """One terminal line per update (a final estimate adds its held-out lines and notes)."""
    from ..watch import EstimateUpdate, Restart, TestUpdate

    if isinstance(update, Restart):
        return f"restarted: {update.reason} (a new recording); following it from its start"
    if isinstance(update, TestUpdate):
        return _test_line(update, unit)
    if isinstance(update, EstimateUpdate):
        return _estimate_line(update, unit, units)
    return _end_line(update)


def _model_header(model: PlantModel, unit: str) -> str:
    """The first line: the structure watched for, and the units shown."""
    structure = getattr(model, "transfer_function", model.structure)
    return f"model {model.family}: G(s) = {structure}; times in seconds from the log start; amplitudes in {unit}"


@click.command("watch")
@click.argument("log", type=click.Path())
@tp_option(required=False, help="Known propulsion time constant Tp [s] (bench test); required by --model soiptd.")
@structure_options
@relay_options
@log_layout_options()
@min_cycles_option(detail=" (and shown)")
@click.option("--idle", type=click.FloatRange(0, None, min_open=True), default=10.0, show_default=True,
              help="Stop when the log has not grown for this many seconds (CSV, ULog; MCAP stops at its footer).")
@click.option("--poll", type=click.FloatRange(0.001, 5.0), default=0.02, show_default=True,
              help="Seconds between looks at the file.")
@click.option("--wait", type=click.FloatRange(0, None, min_open=True), default=None, metavar="SECONDS",
              help="Longest wait for LOG to appear (default: until Ctrl-C).")
@click.option("--jsonl", is_flag=True, help="Print one JSON object per update (for a ground-station script).")
def watch(log: str, Tp: float | None, model_name: str, params: tuple[str, ...], ranges: tuple[str, ...],
          relay_kind: str | None, eps: float | None, min_cycles: int, idle: float, poll: float, wait: float | None,
          jsonl: bool, **read_options: Any) -> None:
    """Follow LOG while it is being written and print each relay test and the identification as cycles arrive.

    LOG is an MCAP file, a ROS 2 bag directory with mcap storage, a CSV or a ULog that a recorder is
    still writing. It may not exist yet: it is waited for (start watch before the logger) until Ctrl-C,
    or for --wait seconds. A file truncated or replaced by a new recording is followed from its start
    again ("restarted"). The first line names the model and the units. Each test is printed once it
    has --min-cycles stable cycles (frequency, amplitude; eq. (2)'s effective beta, a process plant's
    relay as inferred or stated) and again at every new cycle, each followed by the model's parameters
    from the tests so far (eq. (2): Td, tau and K once two betas are in; a parameter the tests so far do
    not determine is named, with the test that would, not given a number). When the writer closes the
    file (MCAP footer, or no growth for --idle seconds) the whole log is analysed as by 'mrft-ident
    analyze' with the same model: the final estimate with each parameter's std, each test's held-out
    prediction, the analysis's notes. Ctrl-C stops watching (exit 130).

    The model is eq. (2) with --tp (--model soiptd, the default), or --model fopdt|sopdt|ipdt|foipdt or
    --model-file with --param, --range, --relay, --eps as for analyze (docs/process-plants.md).

    Exit codes: 0 ok, 2 bad option, 3 unreadable log, 4-6 as for analyze (final analysis), 130 Ctrl-C.

    Example: mrft-ident watch flight.mcap --tp 0.0422 --jsonl

    Example: mrft-ident watch plant.csv --model fopdt --command-topic u_relay --output-topic y_output
    """
    from ..analyze import RelayOptions
    from ..errors import InputError
    from ..io import ReadOptions
    from ..watch import WatchOptions, watch as follow

    model = soiptd_or_process(Tp, model_name, params, ranges, relay_kind, eps)
    layout = read_options["layout"]
    if layout not in (None, "reference") or read_options["command_scale"] is not None \
            or read_options["controller_rate_hz"] is not None:
        # the incremental readers follow the reference topics; the other layouts are read whole
        raise InputError(f"watch follows logs in the reference layout only (--layout {layout or 'reference'}, "
                               "--command-scale or --controller-rate given); run 'mrft-ident analyze' with the same "
                               "options on the finished log")
    read = ReadOptions(**{**read_options, "layout": None}, any_time_scale=model_name != "soiptd")  # found from the topics
    options = WatchOptions(min_cycles=min_cycles, idle=idle, poll=poll, wait=wait,
                           relay=RelayOptions(relay_kind, None, eps))
    if not Path(log).exists():
        limit = f"for up to {wait:g} s" if wait is not None else "until Ctrl-C"
        click.echo(f"waiting for {log} to appear ({limit})", err=True)
    unit, units = _units(model, read.loop)
    if not jsonl:
        click.echo(_model_header(model, unit))
    _print(follow(log, model, read=read, options=options), log, unit, units, jsonl)


def _print(updates: Any, log: str, unit: str, units: _Display, jsonl: bool) -> None:
    """Each update as a line (or a JSON object); the final analysis's error as the command's error."""
    from ..errors import MrftError
    from ..watch import Restart, TestUpdate, WatchEnd

    seen = 0
    try:
        for update in updates:
            if isinstance(update, TestUpdate):
                seen = max(seen, update.number)
            elif isinstance(update, Restart):
                seen = 0
            if jsonl:
                click.echo(json.dumps(to_jsonable(update.to_json()), allow_nan=False))
            else:
                click.echo(_line(update, unit, units))
            if isinstance(update, WatchEnd) and update.error:
                err = MrftError(update.error)
                err.exit_code = update.exit_code
                raise err
    except KeyboardInterrupt:
        updates.close()
        click.echo(f"interrupted: stopped watching {log} after {seen} test(s)", err=True)
        raise SystemExit(130) from None
