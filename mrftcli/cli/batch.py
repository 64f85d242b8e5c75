"""``mrft-ident batch``: analyse many logs on local processes or a Dask cluster."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import click
from click.core import ParameterSource

from ..errors import InputError
from .model_options import process_model, structure_options
from .analyze import accept_tp_option
from .options import InputPath, json_option, log_layout_options, min_cycles_option, quiet_option, tp_option

__all__ = ["batch"]

#: CLI option name -> LogSettings field (the options a config file can also set): the same names, but --loop's
#: field is ``loops``.
_SETTING_OPTIONS = {opt: "loops" if opt == "loop" else opt for opt in (
    "tp", "loop", "command_topic", "output_topic", "beta_topic", "setpoint_topic", "output_scale", "command_scale",
    "layout", "controller_rate_hz", "min_cycles", "accept_tp")}


def _resolve_against(against: str | None, alias: str | None) -> str | None:
    """``--against``, or the deprecated ``--baseline`` it replaces (a note on stderr).

    ``--baseline`` means a process's operating point Y0 in ``analyze --model``; one name, one meaning."""
    if alias is None:
        return against
    if against is not None:
        raise InputError("give --against only (batch's --baseline is its deprecated alias)")
    click.echo("note: batch --baseline is deprecated and will be removed in the next release; use --against "
               "(--baseline is the operating point Y0 in analyze --model)", err=True)
    return alias


def _fmt_ms(x: float) -> str:
    return "" if not math.isfinite(x) else f"{x * 1e3:.2f}"


def _fmt(x: float) -> str:
    return "" if not math.isfinite(x) else f"{x:.4g}"


def _process_model(ctx: click.Context, setting_opts: dict[str, Any]) -> Any:
    """``--model``/``--model-file`` with ``--param``/``--range``: the process model (None: eq. (2)); the options
    are taken out of ``setting_opts``."""
    name, params, ranges = (setting_opts.pop(k) for k in ("model_name", "params", "ranges"))
    if name != "soiptd" and setting_opts.get("tp") is not None \
            and ctx.get_parameter_source("tp") is ParameterSource.COMMANDLINE:
        raise click.UsageError("--tp is eq. (2)'s propulsion time constant: with --model give the known parameters "
                               "with --param NAME=VALUE")
    return process_model(name, params, ranges)


def _shown_rows(df, limit: int):
    """All rows up to ``limit``; beyond it only the failed and outlying ones (the count left out is said)."""
    shown = df if len(df) <= limit else df[(df["result_status"] != "ok") | df["outlier"]]
    if len(shown) < len(df):
        click.echo(f"({len(df) - len(shown)} ok rows not shown; see summary.csv)")
    return shown


def _short_name(path: Any) -> str:
    """A log's file name in the table's 36 columns (its end kept)."""
    name = Path(str(path)).name
    return name if len(name) <= 36 else "..." + name[-33:]


#: Statuses of a loop a log does not hold: listed after the table, one line per log.
_ABSENT = ("skipped-no-tests", "skipped-no-topics")


def _split_absent(df):
    """(rows of the table, one line per log naming its absent loops) for the terminal summary."""
    absent = df["result_status"].isin(_ABSENT)
    lines = []
    for path, rows in df[absent].groupby("path", sort=False):
        why = {"skipped-no-tests": "no MRFT test on them", "skipped-no-topics": "no topics for them"}
        parts = [f"{', '.join(map(str, g['loop']))} ({why.get(str(status), status)})"
                 for status, g in rows.groupby("result_status", sort=False)]
        lines.append(f"skipped {_short_name(path)}: {'; '.join(parts)}")
    return df[~absent], lines


def _print_table(df, limit: int = 50) -> None:
    """The identified (and failed) rows first; then each log's loops it does not hold, on one line."""
    df, absent = _split_absent(df)
    df = df.sort_values("result_status", key=lambda s: s != "ok", kind="stable")  # identified rows first
    _print_rows(df, limit)
    for line in absent:
        click.echo(line)


def _print_rows(df, limit: int) -> None:
    """log, loop, status, then eq. (2)'s tau, Td, K (with their std) or a process row's model and parameters
    with units (value ± std unit); the note: a failed row's error, an outlier's reason, a lead (the summary's
    ``lead`` column), the diagnosis' findings."""
    process = "parameters" in df
    shown = _shown_rows(df, limit)
    figures = (f"{'model':<8} parameters (value ± std unit) / note" if process else
               f"{'tau ms':>8} {'+/-':>6} {'Td s':>8} {'+/-':>7} {'K':>8}  note")
    header = f"{'log':<36} {'loop':<9} {'status':<16} {figures}"
    click.echo(header)
    click.echo("-" * len(header))
    for i, r in shown.iterrows():
        failed = r["result_status"] != "ok" and isinstance(r["error"], str)
        note = r["error"] if failed else (r["parameters"] if process and isinstance(r["parameters"], str) else "")
        if r["outlier"]:
            note = f"OUTLIER {r['outlier_reason']} {note}".strip()
        if r["lead"]:
            note = f"LEAD tau < 0 (tune designs at tau 0) {note}".strip()
        if isinstance(r["findings"], str) and r["findings"]:
            note = f"{note} findings: {r['findings']}".strip()
        if process:
            cells = f"{r['model'] if isinstance(r['model'], str) else '':<8} {note}"
        else:
            cells = (f"{_fmt_ms(r['tau_mean']):>8} {_fmt_ms(r['tau_std']):>6} {_fmt(r['Td_mean']):>8} "
                     f"{_fmt(r['Td_std']):>7} {_fmt(r['K_mean']):>8}  {note}")
        click.echo(f"{_short_name(r['path']):<36} {r['loop']:<9} {r['status']:<16} {cells}".rstrip())
    if not process and (shown["result_status"] == "ok").any():
        from ..mrft.model import K_UNIT

        # eq. (2)'s K, in its records' unit (the model's one spelling): too long for the column's 8 characters
        click.echo(f"K in {K_UNIT} (eq. (2))")


@click.command("batch")
@structure_options
@click.argument("paths", nargs=-1, required=True, metavar="PATH...")
@click.option("--jobs", "-j", type=click.IntRange(min=1), default=None,
              help="Local worker processes (default: the number of cores); 1 runs in this process.")
@click.option("--scheduler", metavar="tcp://HOST:PORT", default=None,
              help="Run on an existing Dask distributed scheduler instead of local processes.")
@click.option("--scheduler-timeout", type=click.FloatRange(min=0, min_open=True), default=10.0, show_default=True,
              help="Seconds to wait for the Dask scheduler.")
@click.option("--out", "-o", "out_dir", type=click.Path(file_okay=False), default="mrft-batch", show_default=True,
              help="Output folder: per-log JSON, summary.csv/.parquet, report/.")
@click.option("--config", "config_file", type=click.Path(dir_okay=False), default=None,
              help="Per-log settings (TOML, or YAML for .yaml/.yml) matched by glob; see docs/batch.md.")
@tp_option("tp", required=False, help="Propulsion time constant Tp [s] (overrides the config).")
@log_layout_options(config_defaults=True)
@min_cycles_option(default=None, detail=" (default: analyze's, 3)")
@accept_tp_option
@click.option("--diagnose", is_flag=True, help="Also run the model-mismatch diagnosis on each loop.")
@click.option("--tune", "tune_kind", flag_value="PD", default=None,
              help="Also tune a PD on each loop (robust design, as `tune`): tune_* columns in the summary.")
@click.option("--tune-pid", "tune_kind", flag_value="PID", help="As --tune, with a PID.")
@click.option("--vehicle", "vehicle", is_flag=True,
              help="Identify and tune every loop of each log as `mrft-ident vehicle` (loops from the topics, inner "
                   "loops first; a vehicle record per log, tune_* columns; --tune-pid for PIDs).")
@click.option("--force", is_flag=True, help="Recompute logs whose results are up to date.")
@click.option("--no-report", is_flag=True, help="Skip the fleet report (HTML + PNG).")
@json_option(what="fleet summary (counts, notes, outputs, one row per log and loop)")
@click.option("--against", "baseline", metavar="PATH", type=InputPath(), default=None,
              help="At the end, compare the results against this baseline (a batch folder or reference .toml; matched "
                   "by log name) as `mrft-ident compare`: compare.json/.xml/.md in --out; exit 9 when a loop changed.")
# the old name, kept for a release: --baseline elsewhere is a process's operating point Y0 (analyze --model)
@click.option("--baseline", "baseline_alias", type=InputPath(), default=None, hidden=True,
              help="Deprecated alias of --against.")
@click.option("--fail-on", "fail_on", metavar="SPEC", default=None,
              help="Tolerances for --against, as compare --fail-on (e.g. tau:+5ms,K:10%).")
@quiet_option()
@click.pass_context
def batch(ctx: click.Context, paths: tuple[str, ...], jobs: int | None, scheduler: str | None,
          scheduler_timeout: float, out_dir: str, config_file: str | None, diagnose: bool, force: bool,
          no_report: bool, json_target: str | None, quiet: bool, tune_kind: str | None, baseline: str | None,
          fail_on: str | None, vehicle: bool, baseline_alias: str | None, **setting_opts) -> None:
    """Analyse every flight log under PATH... (files, folders, globs) and summarise the fleet.

    Folders are searched recursively for .mcap, .bag, .ulg, .csv and .bin logs and ROS 2 bag folders.
    Writes per-log JSON, summary.csv, summary.parquet and a fleet report to --out. A second run skips
    logs whose results are newer than the log and were made with the same settings (--force recomputes).
    Exit code 8 when some logs failed (the others are still analysed and written).
    """
    from ..batch.inputs import load_config
    from ..batch.run import BatchFailedError, BatchOptions, run_batch
    from .options import check_output_dir, check_output_file, dump_json, echo_warnings, tqdm_progress

    # the shared rule (never a symbolic link, io.atomic.check_output_path), creating nothing: the config,
    # the options and the logs are checked first, and run_batch creates the folder after them
    check_output_dir(out_dir, "--out", create=False)
    check_output_file(json_target, "--json")
    baseline = _resolve_against(baseline, baseline_alias)
    model = _process_model(ctx, setting_opts)
    defaults: dict[str, Any] = {}
    explicit: dict[str, Any] = {}
    for opt, key in _SETTING_OPTIONS.items():
        value = setting_opts[opt]
        if opt == "loop":
            value = tuple(value) if value else None
        if value is None:
            continue
        source = ctx.get_parameter_source(opt)
        given = source in (ParameterSource.COMMANDLINE, ParameterSource.ENVIRONMENT)
        given = given or f"mrftcli.rate_alias.{opt}" in ctx.meta  # the deprecated --rate spelling
        (explicit if given else defaults)[key] = value
    config = load_config(config_file) if config_file else None
    if vehicle and (diagnose or explicit.get("loops") or any(
            setting_opts[k] is not None for k in ("command_topic", "output_topic", "beta_topic", "setpoint_topic",
                                                  "output_scale", "command_scale"))):
        raise click.UsageError("--vehicle finds each log's loops from its topics: give it without --diagnose, --loop "
                               "and the topic and scale options (run analyze or batch without --vehicle for those)")
    if fail_on:
        from ..compare import parse_fail_on

        parse_fail_on(fail_on)  # a malformed spec stops before the work, not after it

    with tqdm_progress("batch", unit="log", enabled=not quiet) as progress:
        options = BatchOptions(diagnose=diagnose, tune=tune_kind, jobs=jobs, scheduler=scheduler,
                               scheduler_timeout_s=scheduler_timeout, force=force, report=not no_report,
                               vehicle=vehicle, model=model)
        result = run_batch(paths, out_dir, options=options, defaults=defaults, config=config, explicit=explicit,
                           progress=progress)
    df = result.summary
    if json_target:
        from ..batch import BatchSummary

        dump_json(BatchSummary.of(result).to_json(), json_target)
    if json_target != "-":
        _print_table(df)
    echo_warnings(result.notes)
    comparison = None
    if baseline:
        from .compare import compare_batch, raise_for

        comparison = compare_batch(baseline, out_dir, fail_on, table_err=json_target == "-")
        if any(c.failed for c in comparison.changes):
            raise_for(comparison)  # exit 9: a loop changed, whatever else failed
    failed = result.failed
    if len(failed):
        first = failed.iloc[0]
        raise BatchFailedError(
            f"{failed['path'].nunique()} of {result.n_logs} logs failed "
            f"(first: {Path(str(first['path'])).name} [{first['loop']}]: {first['error']}); "
            f"{result.summary_line()}"
        )
    if result.unwritten:
        raise BatchFailedError(f"{len(result.unwritten)} output file(s) could not be written (first: "
                               f"{result.unwritten[0]}); {result.summary_line()}")
    click.echo(result.summary_line(), err=True)
    if comparison is not None:
        from .compare import raise_for as raise_for_missing

        raise_for_missing(comparison)  # exit 10: a loop of the baseline has no result here
