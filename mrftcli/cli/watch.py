"""``mrft-ident watch``: follow a log while it is recorded and print tests and estimates as they come."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from ..jsonable import to_jsonable
from ..report.wording import output_unit
from .model_options import build_model, relay_options, structure_options
from .options import log_layout_options, min_cycles_option, tp_option

if TYPE_CHECKING:
    from ..analyze.general import TestSummary
    from ..mrft.identify_lti import LtiEstimate
    from ..mrft.model import PlantModel
    from ..watch import EstimateUpdate, ProcessEstimateUpdate, ProcessTestUpdate, TestUpdate, Update, WatchEnd

__all__ = ["watch"]

#: a process plant's output and command are in the user's units (the model's K is output / command)
_PROCESS_UNIT = "output units"


def _test_line(update: TestUpdate, unit: str) -> str:
    """A test of eq. (2): its start in seconds from the log's first command sample (as analyze prints it)."""
    nom = f"{update.beta_nominal:+.3f}" if update.beta_nominal is not None else "-"
    return (f"test {update.number}  t {update.t_start - update.t_log_start:7.1f} s  beta nom {nom}  "
            f"eff {update.beta_effective:+.3f}  f {update.frequency_hz:.4f} Hz  "
            f"amplitude {update.amplitude:.4g} {unit}  "
            f"cycles {update.stable_cycles}/{update.cycles}")


def _estimate_line(update: EstimateUpdate, unit: str) -> str:
    """eq. (2)'s estimate (amplitude in the output's ``unit``, K in ``unit``/s² per command unit)."""
    head = "final    " if update.final else "estimate "
    k_unit = f"{unit}/s² per command unit"
    text = (f"{head} Td {update.Td:.4g} s  tau {update.tau * 1e3:.4g} ms  K {update.K:.4g} {k_unit}  "
            f"(tests {', '.join(map(str, update.tests))})")
    if update.final and update.std:
        sd = update.std
        text += (f"  std: Td {sd['Td']:.2g} s, tau {sd['tau'] * 1e3:.2g} ms, K {sd['K']:.2g} {k_unit}"
                 if all(math.isfinite(sd[k]) for k in ("Td", "tau", "K")) else "")
    return text


def _process_test_line(update: ProcessTestUpdate) -> str:
    """A process plant's test: the same grammar as eq. (2)'s, with its relay (inferred or stated)."""
    relay = update.relay
    text = (f"test {update.number}  t {update.t_start - update.t_log_start:7.1f} s  {relay.describe()} "
            f"({relay.source})  f {update.frequency_hz:.4f} Hz  amplitude {update.amplitude:.4g} {_PROCESS_UNIT}  "
            f"cycles {update.stable_cycles}/{update.cycles}")
    return text + "".join(f"; {n}" for n in update.notes)


def _parameter(e: LtiEstimate, final: bool) -> str:
    """One parameter with its unit (and its std on the final update)."""
    unit = f" {e.unit}" if e.unit else ""  # a declared model's parameter may have no unit
    if e.known:
        return f"{e.name} {e.value:.4g}{unit} (known)"
    spread = f" ± {e.std:.2g}" if final and math.isfinite(e.std) else ""
    return f"{e.name} {e.value:.4g}{spread}{unit}"


def _process_estimate_line(update: ProcessEstimateUpdate) -> str:
    """The parameters the tests determine, with units; the others named with analyze's advice, not a number."""
    head = "final    " if update.final else "estimate "
    shown = [_parameter(e, update.final) for e in update.estimates if e.name not in update.undetermined]
    text = f"{head} {'  '.join(shown) or 'no parameter determined yet'}  (tests {', '.join(map(str, update.tests))})"
    if update.undetermined:
        text += f"; {update.advice}" if update.final else f"; so far {update.advice}"
    if update.analysis is not None:  # the held-out check and analyze's notes, as analyze --model prints them
        text += "".join(_held_out_line(t) for t in update.analysis.tests)
        text += "".join(f"\nnote: {n}" for n in update.analysis.notes)
    return text


def _held_out_line(test: TestSummary) -> str:
    """A test's cycle as predicted from the other tests, beside the measured one."""
    ho = test.held_out
    return (f"\nheld-out test {test.index + 1}: "
            + ("none" if ho is None else ho.describe(test.frequency_hz, test.amplitude, _PROCESS_UNIT)))


def _end_line(update: WatchEnd) -> str:
    return (f"stopped: the writer {'closed the file' if update.reason == 'closed' else 'stopped writing'}; "
            f"{update.tests} test(s)")


def _line(update: Update, unit: str) -> str:
    """One terminal line per update (a final process estimate adds its held-out lines and notes)."""
    from ..watch import EstimateUpdate, ProcessEstimateUpdate, ProcessTestUpdate, Restart, TestUpdate

    if isinstance(update, Restart):
        return f"restarted: {update.reason} (a new recording); following it from its start"
    if isinstance(update, TestUpdate):
        return _test_line(update, unit)
    if isinstance(update, EstimateUpdate):
        return _estimate_line(update, unit)
    if isinstance(update, ProcessTestUpdate):
        return _process_test_line(update)
    if isinstance(update, ProcessEstimateUpdate):
        return _process_estimate_line(update)
    return _end_line(update)


def _model_header(model: PlantModel) -> str:
    """The first line with a process model: the structure watched for, and the units shown."""
    structure = getattr(model, "transfer_function", model.structure)
    return (f"model {model.family}: G(s) = {structure}; times in seconds from the log start; amplitudes in "
            f"{_PROCESS_UNIT}")


def _check_model_options(model_name: str, Tp: float | None, params: tuple[str, ...], ranges: tuple[str, ...],
                         relay_kind: str | None, eps: float | None) -> None:
    """eq. (2) needs --tp; a process model's options do not apply to it (and --tp not to a process model)."""
    if model_name == "soiptd":
        if Tp is None:
            raise click.UsageError("Missing option '--tp' (the known propulsion time constant of --model soiptd).")
        if params or ranges or relay_kind or eps is not None:
            raise click.UsageError("--param, --range, --relay and --eps take a process model (--model fopdt, sopdt, "
                                   "ipdt or foipdt); eq. (2) takes --tp and reads beta from the log.")
    elif Tp is not None:
        raise click.UsageError("--tp is eq. (2)'s (--model soiptd); a process model's known parameters are "
                               "--param NAME=VALUE")


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
          relay_kind: str | None, eps: float | None, loop: str, command_topic: str | None, output_topic: str | None,
          beta_topic: str | None, setpoint_topic: str | None, output_scale: float | None, command_scale: float | None,
          layout: str | None, controller_rate_hz: float | None, fmt: str | None, time_unit: str | None,
          min_cycles: int, idle: float, poll: float, wait: float | None, jsonl: bool) -> None:
    """Follow LOG while it is being written and print each MRFT test and the identification as cycles arrive.

    LOG is an MCAP file, a ROS 2 bag directory with mcap storage, a CSV or a ULog that a recorder is
    still writing. It may not exist yet: it is waited for (start watch before the logger) until Ctrl-C,
    or for --wait seconds. A file truncated or replaced by a new recording is followed from its start
    again ("restarted"). Each test is printed once it has --min-cycles stable cycles
    (frequency, amplitude, effective beta) and again at every new cycle; as soon as two betas are in,
    the estimate of Td, tau and K follows each update. When the writer closes the file (MCAP footer,
    or no growth for --idle seconds) the whole log is analysed as by 'mrft-ident analyze' and the final
    estimate with its uncertainty is printed. Ctrl-C stops watching (exit 130).

    With --model fopdt|sopdt|ipdt|foipdt (or --model-file; --param, --range, --relay, --eps as for
    analyze): each test is printed with its relay (inferred or stated), the process model's parameters
    after every new cycle (those the tests so far do not determine are named, with the test that would,
    not given a number), and at the end the analysis of 'mrft-ident analyze --model' with each test's
    held-out prediction. See docs/process-plants.md.

    Exit codes: 0 ok, 2 bad option, 3 unreadable log, 4-6 as for analyze (final analysis), 130 Ctrl-C.

    Example: mrft-ident watch flight.mcap --tp 0.0422 --jsonl

    Example: mrft-ident watch plant.csv --model fopdt --command-topic u_relay --output-topic y_output
    """
    from ..errors import InputError
    from ..io import ReadOptions

    _check_model_options(model_name, Tp, params, ranges, relay_kind, eps)
    if layout not in (None, "reference") or command_scale is not None or controller_rate_hz is not None:
        # the incremental readers follow the reference topics; the other layouts are read whole
        raise InputError(f"watch follows logs in the reference layout only (--layout {layout or 'reference'}, "
                               "--command-scale or --controller-rate given); run 'mrft-ident analyze' with the same "
                               "options on the finished log")
    read = ReadOptions(loop=loop, command_topic=command_topic, output_topic=output_topic, beta_topic=beta_topic,
                       setpoint_topic=setpoint_topic, output_scale=output_scale, fmt=fmt, time_unit=time_unit,
                       any_time_scale=model_name != "soiptd")
    model = None if model_name == "soiptd" else build_model(model_name, params, ranges)
    updates = _start(log, Tp, model, read, relay_kind, eps, min_cycles, (idle, poll, wait))
    if model is not None and not jsonl:
        click.echo(_model_header(model))
    _print(updates, log, output_unit(loop), jsonl)


def _start(log: str, Tp: float | None, model: PlantModel | None, read: Any, relay_kind: str | None,
           eps: float | None, min_cycles: int, timing: tuple[float, float, float | None]) -> Any:
    """The updates of eq. (2) (``model`` None) or of the process model; says so when LOG is waited for."""
    from ..analyze.general import RelayOptions
    from ..watch import WatchOptions, watch_model
    from ..watch import watch as follow

    idle, poll, wait = timing
    if not Path(log).exists():
        limit = f"for up to {wait:g} s" if wait is not None else "until Ctrl-C"
        click.echo(f"waiting for {log} to appear ({limit})", err=True)
    options = WatchOptions(min_cycles=min_cycles, idle=idle, poll=poll, wait=wait)
    if model is None:
        assert Tp is not None  # _check_model_options
        return follow(log, Tp, read=read, options=options)
    return watch_model(log, model, relay=RelayOptions(relay_kind, None, eps), read=read, options=options)


def _print(updates: Any, log: str, unit: str, jsonl: bool) -> None:
    """Each update as a line (or a JSON object); the final analysis's error as the command's error."""
    from ..errors import MrftError
    from ..watch import ProcessTestUpdate, Restart, TestUpdate, WatchEnd

    seen = 0
    try:
        for update in updates:
            if isinstance(update, (TestUpdate, ProcessTestUpdate)):
                seen = max(seen, update.number)
            elif isinstance(update, Restart):
                seen = 0
            if jsonl:
                click.echo(json.dumps(to_jsonable(update.to_dict()), allow_nan=False))
            else:
                click.echo(_line(update, unit))
            if isinstance(update, WatchEnd) and update.error:
                err = MrftError(update.error)
                err.exit_code = update.exit_code
                raise err
    except KeyboardInterrupt:
        updates.close()
        click.echo(f"interrupted: stopped watching {log} after {seen} test(s)", err=True)
        raise SystemExit(130) from None
