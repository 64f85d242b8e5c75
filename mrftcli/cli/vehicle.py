"""``mrft-ident vehicle``: every loop of one flight identified and tuned, and the tests the others need."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any

import click

from ..errors import InputError, SegmentationError, TpRejectedError
from ..io.logtypes import gain_unit, output_unit
from .analyze import accept_tp_option
from .model_options import outer_options
from .options import (check_export_paths, check_output_dir, dump_json, echo_warnings, json_option,
                      log_layout_options, min_cycles_option, num, quiet_option, read_json_file, text_table,
                      tp_option, tqdm_progress)

if TYPE_CHECKING:
    from ..vehicle import VehicleResult

__all__ = ["vehicle"]

def _loop_rows(result: VehicleResult) -> list[list[str]]:
    rows = []
    for name, entry in result.loops.items():
        g, est = entry.gains, entry.estimates
        c = g.controller if g is not None else None
        pm = g.phase_margin_deg if g is not None else math.nan
        k_unit = gain_unit(name) if entry.analysis.kind == "soiptd" else entry.analysis.parameters["K"].unit
        rows.append([name, entry.role, entry.route, str(len(entry.analysis.tests)), num(est["Td"][0]),
                     num(est["tau"][0] * 1e3), f"{num(est['K'][0])} {k_unit}",
                     g.design if g is not None else "not tuned",
                     "-" if c is None else f"{num(c.Kp)} cmd/{output_unit(name)}",
                     "-" if c is None else f"{num(c.Kd)} cmd s/{output_unit(name)}",
                     "-" if c is None else f"{c.rate_hz:g}", num(pm, 3)])
    return rows


def format_vehicle(result: VehicleResult) -> str:
    """The terminal summary: the assumptions first, one row per identified loop, then the missing loops."""
    lines = [f"assumption: {a}" for a in result.assumptions]
    lines.append(f"{result.path} (layout {result.layout or 'not recognised'}); inner loops first")
    header = ["loop", "role", "model", "tests", "Td [s]", "tau [ms]", "K", "design", "Kp", "Kd", "rate [Hz]",
              "PM [deg]"]
    rows = _loop_rows(result)
    lines += text_table([header, *rows])
    if not rows:
        lines.append("(no loop identified)")
    for name, entry in result.loops.items():
        g = entry.gains
        if g is not None and g.export_refused:
            lines.append(f"{name}: not exported: {g.export_refused}")
        if g is not None and g.export is not None:
            m = g.export.margins  # with the stack's filter and rate, and any value set to the stack's bound
            lines.append(f"{name}: export {g.export.stack}: PM {m.phase_margin_deg:.1f} deg, delay margin "
                         f"{m.delay_margin_s * 1e3:.1f} ms, Ms {m.Ms:.3g}")
            lines += [f"{name}: export note: {n}" for n in g.export.notes]
    for name, miss in result.missing.items():
        lines.append(f"{name}: {miss.reason}: {miss.next_tests}")
    return "\n".join(lines)


def _inner_gains(path: str | None) -> dict[str, Any] | None:
    """GAINS.json: a loop name -> the generic gains ``tune`` exports (read only when given)."""
    if path is None:
        return None
    data = read_json_file(path, "--inner-gains")
    if not isinstance(data, dict):
        raise InputError(f"--inner-gains {path}: expected an object mapping a loop to its gains, "
                         "e.g. {\"roll\": {\"Kp\": .., \"Ki\": .., \"Kd\": .., \"Tf\": .., \"rate_hz\": ..}}")
    return data


def _export_text(result: VehicleResult, stack: str) -> str:
    """The ``--export`` file: one JSON object by loop (generic, hear) or one parameter file (px4, ardupilot)
    holding every exported loop's parameters."""
    gains = {name: e.gains for name, e in result.loops.items() if e.gains is not None}
    if stack == "generic":
        return json.dumps({name: g.controller.to_dict() for name, g in gains.items()}, indent=2) + "\n"
    exports = {name: g.export for name, g in gains.items() if g.export is not None}
    if not exports:
        raise InputError(f"no loop of this flight can be exported to {stack} (the reasons are in the table)")
    if stack == "hear":
        return json.dumps({name: json.loads(e.file_text()) for name, e in exports.items()}, indent=2) + "\n"
    from ..tune.joint import merge_exports

    return merge_exports(list(exports.values()), ", ".join(exports)).file_text()


def _check_stack_options(export: str | None, kind: str, gyro_cutoff: float | None,
                         hover_thrust: float | None) -> None:
    """What the export cannot do is refused before the work, as ``tune`` does (an unused option is an error)."""
    from ..tune.stacks import check_exportable, check_hover_thrust

    if export in ("px4", "ardupilot") and kind != "PD":
        check_exportable(export, "roll", kind)  # its one-line reason: the stack's rate loop takes a PD
    if gyro_cutoff is not None and export not in ("px4", "ardupilot"):
        raise InputError("--gyro-cutoff is for --export px4|ardupilot (the stack's gyro filter on roll and pitch)")
    if hover_thrust is not None and export not in ("px4", "ardupilot"):
        raise InputError("--hover-thrust is for --export px4|ardupilot (the altitude loop; PX4's x and y)")
    if hover_thrust is not None and export is not None:  # its range (and MOT_THST_HOVER's) in tune's words, before
        check_hover_thrust(export, hover_thrust)


@click.command("vehicle")
@click.argument("log", type=click.Path(dir_okay=True))
@tp_option()
@click.option("--inner-gains", "inner_gains", metavar="GAINS.json", type=click.Path(dir_okay=False),
              help="The inner controllers flown during the outer tests, {\"roll\": {\"Kp\", \"Ki\", \"Kd\", "
                   "\"Tf\", \"rate_hz\"}} (roll for y, pitch for x; tune --export generic or a vehicle record "
                   "is read too): x and y are identified through the closed inner loop. Without them: eq. (2), "
                   "as the first line says.")
@outer_options("--inner-gains", "relays command")
@log_layout_options(only=("fmt", "layout", "controller_rate_hz", "time_unit"))  # a whole flight's
@min_cycles_option()
@accept_tp_option
@click.option("--kind", type=click.Choice(["PD", "PID"]), default="PD", show_default=True,
              help="Controller tuned for every loop.")
@click.option("--objective", type=click.Choice(["iae", "itae"]), default="iae", show_default=True,
              help="Criterion of a unit setpoint step.")
@click.option("--ms-max", type=float, default=1.6, show_default=True, help="Limit on the sensitivity peak Ms [-].")
@click.option("--export", "export", type=click.Choice(["generic", "px4", "ardupilot", "hear"]), default=None,
              help="Write every loop's gains as the stack loads them (px4, ardupilot, hear: designed for the "
                   "stack's rate and rate filter) or generic JSON (the GAINS.json --inner-gains reads).")
@click.option("--out", "-o", "out", metavar="FILE", help="Write the export to FILE (atomically); default: stdout.")
@click.option("--gyro-cutoff", "gyro_cutoff", type=click.FloatRange(0, None), metavar="HZ",
              help="PX4 IMU_GYRO_CUTOFF / ArduPilot INS_GYRO_FILTER [Hz] (default: the stack's, stated).")
@click.option("--hover-thrust", "hover_thrust", type=float, metavar="X",
              help="Hover thrust, normalised 0-1 (PX4 MPC_THR_HOVER, ArduPilot MOT_THST_HOVER), for the "
                   "altitude exports and PX4's x and y (PX4: default the log's hover_thrust_estimate, stated).")
@click.option("--clamp", is_flag=True, help="Export values outside the stack's ranges at the bound instead of "
              "refusing (the margins are stated).")
@json_option(what="vehicle record: loops.<name> (the analysis, gains.generic) and the missing loops")
@click.option("--report", "report_dir", metavar="DIR", type=click.Path(file_okay=False),
              help="Write an HTML report with a page per loop to DIR (created if missing).")
@quiet_option()
def vehicle(log: str, Tp: float, inner_gains: str | None, outer_command: str, inner_draws: int, min_cycles: int,
            accept_tp: bool, kind: str, objective: str, ms_max: float,
            export: str | None, out: str | None, gyro_cutoff: float | None, hover_thrust: float | None, clamp: bool,
            json_target: str | None, report_dir: str | None, quiet: bool, **read_options: Any) -> None:
    """Identify and tune every loop one flight holds MRFT tests of; say which tests the others need.

    The loops are found from the log's topics (any layout analyze reads); inner loops (altitude,
    roll, pitch) are identified first with eq. (2) at the known Tp, outer loops (x, y) through the
    closed inner loop (--inner-gains) or with eq. (2), which the first line then says. Each loop is
    tuned as `tune` does (robust over the identification's posterior). docs/vehicle.md.

    Example: mrft-ident vehicle flight.bag --tp 0.0422 --json vehicle.json --report out/
    """
    from ..mrft.model import soiptd_model
    from ..vehicle import StackOptions, TuneOptions, VehicleOptions, identify_vehicle

    check_export_paths(json_target, out, export is not None)
    check_output_dir(report_dir, "--report")
    if out and export is None:
        raise InputError("--out needs --export generic|px4|ardupilot|hear")
    _check_stack_options(export, kind, gyro_cutoff, hover_thrust)
    from ..tune.design import DesignOptions

    DesignOptions(objective=objective, ms_max=ms_max)  # refused before the work, as tune does (not per loop after it)
    stack = None if export is None else StackOptions(export, gyro_cutoff, hover_thrust, clamp)
    gains = _inner_gains(inner_gains)
    options = VehicleOptions(layout=read_options["layout"], fmt=read_options["fmt"],
                             time_unit=read_options["time_unit"], controller_rate_hz=read_options["controller_rate_hz"],
                             min_stable_cycles=min_cycles, outer_command=outer_command, inner_draws=inner_draws,
                             accept_tp=accept_tp, tune=TuneOptions(kind=kind, objective=objective, ms_max=ms_max, stack=stack))
    with tqdm_progress("vehicle", unit="loop", enabled=not quiet) as progress:
        result = identify_vehicle(log, soiptd_model(Tp), inner_gains=gains, options=options, progress=progress)
        index = None
        if report_dir:
            from ..report.vehicle import write_vehicle_report

            index = write_vehicle_report(result, report_dir, progress=progress)
    if json_target:
        dump_json(result.to_json(), json_target)
    to_stdout = json_target == "-"
    if not to_stdout:
        click.echo(format_vehicle(result), err=export is not None and not out)
    echo_warnings(result.warnings)
    wrong_tp = [m.message for m in result.missing.values() if m.reason == "wrong-tp"]
    if wrong_tp:  # as analyze: the given Tp is wrong for this flight (the table and the JSON are written)
        raise TpRejectedError(f"{log}: {wrong_tp[0]}", best=math.nan)
    if not result.loops:
        # nothing to tune: the exit code says so (the table and the JSON say what each loop needs)
        raise SegmentationError(f"{log}: no loop has usable MRFT tests; the table above names the tests to fly")
    if export is not None:
        from ..io.atomic import write_text_atomic

        text = _export_text(result, export)
        if out:
            write_text_atomic(out, text)
            click.echo(f"export {export}: {out}", err=to_stdout)
        else:
            click.echo(text, nl=False)
    if index is not None:
        click.echo(f"report: {index}", err=to_stdout or (export is not None and not out))
