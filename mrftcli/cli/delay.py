"""``mrft-ident delay``: the delay a change added, from two recordings of one loop identified together."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import click

from ..errors import InputError
from ..io.logtypes import gain_unit
from .model_options import parameter_lines
from .options import (InputPath, check_output_file, dump_json, echo_warnings, json_option, log_layout_options, min_cycles_option, num,
                      quiet_option, text_table, tp_option, tqdm_progress)

if TYPE_CHECKING:
    from ..compare.delay import DelayIncrement

__all__ = ["delay", "format_delay"]


@click.command("delay")
@click.argument("before", type=InputPath())
@click.argument("after", type=InputPath())
@tp_option()
@min_cycles_option()
@log_layout_options()
@json_option(what="delay record (docs/records.md)")
@quiet_option()
def delay(before: str, after: str, Tp: float, min_cycles: int, json_target: str | None, quiet: bool,
          **read_options) -> None:
    """The delay a change added to a loop: BEFORE and AFTER, two recordings of the same vehicle's loop with
    MRFT tests, identified together as one plant (one Td and K) with a delay each; the delay added is AFTER's
    less BEFORE's, with its 95 % interval.

    Fly the same loop before and after the change (a filter, a firmware, a delay inserted on purpose), at
    two or more betas in one of the flights. Both recordings are read with the same options. Identified
    apart, each flight's Td trades against its tau and their difference carries both trades; together,
    Td is shared (docs/usage.md#how-much-delay-did-a-change-add-delay, docs/method.md). A recording whose
    loop leads eq. (2) (an estimator's lead) gets a negative delay, said in a note; a PX4 ULog's output
    published later after its sample in one flight than in the other (timestamp - timestamp_sample) is said
    too: that change is in the delay added.

    Exit code 0; 2 bad input; 3 a recording cannot be read; 4 no usable test in a recording; 5 the fit fails;
    6 neither recording has two betas.
    """
    from ..compare.delay import delay_increment
    from ..io import ReadOptions

    if os.path.samefile(before, after):  # a slip: the "delay added" would be a confident 0 ms
        raise InputError(f"BEFORE and AFTER are the same recording ({after}): give the flight before the change, "
                         "then the flight after it")
    check_output_file(json_target)
    read = ReadOptions(**read_options)  # checked before either log is opened
    with tqdm_progress("delay", unit="step", enabled=not quiet, after_s=1.0) as progress:
        # an error's warnings (an assumed rate, tests left out) are shown above it by main (MrftError.warnings)
        result = delay_increment(before, after, Tp, read=read, min_stable_cycles=min_cycles, progress=progress)
    if json_target:
        dump_json(result.to_json(), json_target)
    if json_target != "-":
        click.echo(format_delay(result))
    echo_warnings(result.warnings)


def _rate(rate_hz: float | None, assumed: bool) -> str:
    """A recording's controller rate for its header line; an assumed one said as such (it sets the half tick
    added to the delay of a command logged below it)."""
    if rate_hz is None:
        return ""
    return f"; controller rate {rate_hz:g} Hz" + (" assumed (see the warning; --controller-rate sets it)" if assumed else "")


def _count(n: int) -> str:
    return f"{n} test" + ("" if n == 1 else "s")


def format_delay(result: DelayIncrement) -> str:
    """The terminal summary: what the figures rest on, each test measured and fitted, the figures, the notes."""
    K_unit = gain_unit(result.loop)
    lines = [f"delay added between two recordings of loop {result.loop}, Tp {result.Tp:g} s (known)",
             f"method: {result.METHOD}",
             *(f"  {flight + ':':7} {path} ({_count(sum(t.flight == flight for t in result.tests))}{_rate(rate, assumed)}"
               + ("" if latency is None else f"; output published {latency * 1e3:.3g} ms after its sample") + ")"
               for flight, path, rate, assumed, latency in zip(
                   ("before", "after"), (result.before, result.after), result.controller_rate_hz,
                   result.controller_rate_assumed, result.output_latency_s))]
    rows = [["flight", "beta", "h", "rate", "cycles", "f measured", "± se", "f fitted", "error", "K"],
            ["", "", "[command]", "[Hz]", "", "[Hz]", "[Hz]", "[Hz]", "[%]", f"[{K_unit}]"]]
    rows += [[t.flight, f"{t.beta:+.3f}", num(t.h), num(t.rate_hz), str(t.n_cycles), f"{t.frequency_hz:.4f}",
              num(t.frequency_se_hz, 2), f"{t.fitted_hz:.4f}", f"{t.error * 100:+.2f}", num(t.K)]
             for t in result.tests]
    lines += text_table(rows, align="<>>>>>>>>>", indent="  ")

    def display(name: str, e) -> tuple[float, str]:
        if e.unit == "s" and name != "Td":
            return 1e3, "ms"
        if name == "K":
            return 1.0, K_unit
        return 1.0, e.unit

    lines += parameter_lines(list(result.parameters().items()), display)
    inc = result.increment
    lines.append(f"delay added: {inc.value * 1e3:.2f} ms ± {inc.std * 1e3:.2f} ms "
                 f"(95 %: {inc.ci95_low * 1e3:.2f} to {inc.ci95_high * 1e3:.2f} ms)")
    lines += [f"note: {n}" for n in result.notes]
    return "\n".join(line.rstrip() for line in lines)
