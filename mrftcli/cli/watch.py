"""``mrft-ident watch``: follow a log while it is recorded and print tests and estimates as they come."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

import click

from ..jsonable import to_jsonable
from ..report.wording import output_unit
from .model_options import unsupported_model_option
from .options import log_layout_options, min_cycles_option, tp_option

if TYPE_CHECKING:
    from ..watch import Update

__all__ = ["watch"]


def _line(update: Update, unit: str) -> str:
    """One terminal line per update (a test's start in seconds from the log's first command sample, as analyze
    prints it; amplitude in the output's ``unit``, K in ``unit``/s² per command unit)."""
    from ..watch import EstimateUpdate, Restart, TestUpdate

    if isinstance(update, Restart):
        return f"restarted: {update.reason} (a new recording); following it from its start"

    if isinstance(update, TestUpdate):
        nom = f"{update.beta_nominal:+.3f}" if update.beta_nominal is not None else "-"
        return (f"test {update.number}  t {update.t_start - update.t_log_start:7.1f} s  beta nom {nom}  "
                f"eff {update.beta_effective:+.3f}  f {update.frequency_hz:.4f} Hz  "
                f"amplitude {update.amplitude:.4g} {unit}  "
                f"cycles {update.stable_cycles}/{update.cycles}")
    if isinstance(update, EstimateUpdate):
        head = "final    " if update.final else "estimate "
        k_unit = f"{unit}/s² per command unit"
        text = (f"{head} Td {update.Td:.4g} s  tau {update.tau * 1e3:.4g} ms  K {update.K:.4g} {k_unit}  "
                f"(tests {', '.join(map(str, update.tests))})")
        if update.final and update.std:
            sd = update.std
            text += (f"  std: Td {sd['Td']:.2g} s, tau {sd['tau'] * 1e3:.2g} ms, K {sd['K']:.2g} {k_unit}"
                     if all(math.isfinite(sd[k]) for k in ("Td", "tau", "K")) else "")
        return text
    return f"stopped: the writer {'closed the file' if update.reason == 'closed' else 'stopped writing'}; " \
           f"{update.tests} test(s)"


@click.command("watch")
@unsupported_model_option("watch", "record the log and run analyze --model NAME on it")
@click.argument("log", type=click.Path())
@tp_option()
@log_layout_options()
@min_cycles_option(detail=" (and shown)")
@click.option("--idle", type=click.FloatRange(0, None, min_open=True), default=10.0, show_default=True,
              help="Stop when the log has not grown for this many seconds (CSV, ULog; MCAP stops at its footer).")
@click.option("--poll", type=click.FloatRange(0.001, 5.0), default=0.02, show_default=True,
              help="Seconds between looks at the file.")
@click.option("--wait", type=click.FloatRange(0, None, min_open=True), default=None, metavar="SECONDS",
              help="Longest wait for LOG to appear (default: until Ctrl-C).")
@click.option("--jsonl", is_flag=True, help="Print one JSON object per update (for a ground-station script).")
def watch(log: str, Tp: float, loop: str, command_topic: str | None, output_topic: str | None,
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

    Exit codes: 0 ok, 2 bad option, 3 unreadable log, 4-6 as for analyze (final analysis), 130 Ctrl-C.

    Example: mrft-ident watch flight.mcap --tp 0.0422 --jsonl
    """
    from ..errors import InputError, MrftError
    from ..io import ReadOptions
    from ..watch import Restart, TestUpdate, WatchEnd, WatchOptions
    from ..watch import watch as follow

    if layout not in (None, "reference") or command_scale is not None or controller_rate_hz is not None:
        # the incremental readers follow the reference topics; the other layouts are read whole
        raise InputError(f"watch follows logs in the reference layout only (--layout {layout or 'reference'}, "
                         "--command-scale or --controller-rate given); run 'mrft-ident analyze' with the same "
                         "options on the finished log")
    seen = 0
    if not Path(log).exists():
        limit = f"for up to {wait:g} s" if wait is not None else "until Ctrl-C"
        click.echo(f"waiting for {log} to appear ({limit})", err=True)
    read = ReadOptions(loop=loop, command_topic=command_topic, output_topic=output_topic, beta_topic=beta_topic,
                       setpoint_topic=setpoint_topic, output_scale=output_scale, fmt=fmt, time_unit=time_unit)
    updates = follow(log, Tp, read=read, options=WatchOptions(min_cycles=min_cycles, idle=idle, poll=poll, wait=wait))
    try:
        for update in updates:
            if isinstance(update, TestUpdate):
                seen = max(seen, update.number)
            elif isinstance(update, Restart):
                seen = 0
            if jsonl:
                click.echo(json.dumps(to_jsonable(update.to_dict()), allow_nan=False))
            else:
                click.echo(_line(update, output_unit(loop)))
            if isinstance(update, WatchEnd) and update.error:
                err = MrftError(update.error)
                err.exit_code = update.exit_code
                raise err
    except KeyboardInterrupt:
        updates.close()
        click.echo(f"interrupted: stopped watching {log} after {seen} test(s)", err=True)
        raise SystemExit(130) from None
