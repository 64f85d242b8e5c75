"""``mrft-ident compare``: did a loop change against a baseline? Tables for people and CI, an exit code."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from ..io.atomic import write_text_atomic
from ..io.logtypes import LOOPS
from .options import InputPath, check_output_file, dump_json, json_option

if TYPE_CHECKING:
    from ..compare import Comparison

__all__ = ["compare", "raise_for", "compare_batch"]


def _write(target: str, text: str) -> None:
    if target == "-":
        click.echo(text, nl=False)
    else:
        write_text_atomic(target, text)


@click.command("compare")
@click.argument("baseline", type=InputPath())
@click.argument("new", type=InputPath())
@click.option("--fail-on", "fail_on", metavar="SPEC",
              help="Tolerances, e.g. 'tau:+5ms,K:10%,Td:25%' ([LOOP.]PARAM:[+|-]AMOUNT[s|ms|us|%]; + / - one-sided). "
                   "Fail on a change that is significant and beyond its tolerance; without any tolerance, on any "
                   "significant change.")
@click.option("--confidence", type=click.FloatRange(0.5, 1.0, max_open=True), default=0.95, show_default=True,
              help="Confidence of the change intervals, per parameter.")
@click.option("--bonferroni", is_flag=True,
              help="Test each of a loop's m parameters at 1-(1-confidence)/m: at most 1-confidence false alarms per loop.")
@click.option("--match", "by", type=click.Choice(["log", "vehicle"]), default="log", show_default=True,
              help="How batch folders are matched: by log file name, or by the vehicle of the batch config.")
@click.option("--loop", "loops", multiple=True, type=click.Choice(LOOPS),
              help="Loop to compare; repeat for several (default: every loop in both).")
@click.option("--junit", "junit_target", metavar="FILE|-", help="Write a JUnit XML report (one case per loop and parameter).")
@click.option("--markdown", "markdown_target", metavar="FILE|-", help="Write a Markdown table (merge-request comment).")
@json_option(what="comparison record")
def compare(baseline: str, new: str, fail_on: str | None, confidence: float, bonferroni: bool, by: str,
            loops: tuple[str, ...], junit_target: str | None, markdown_target: str | None,
            json_target: str | None) -> None:
    """Compare the loops identified in NEW against BASELINE: per parameter the change, its interval,
    whether it is significant and beyond tolerance.

    BASELINE and NEW are each an 'analyze --json' result, a 'batch --out' folder (or one of its
    logs/*.json records), or a reference .toml of expected values with tolerances (docs/compare.md).
    Exit code 0: nothing changed beyond tolerance; 9: some loop changed; 10: a result is missing or
    unusable.
    """
    from ..compare import CompareOptions, compare as run_compare, parse_fail_on

    for target, option in ((json_target, "--json"), (junit_target, "--junit"), (markdown_target, "--markdown")):
        check_output_file(target, option)  # never over a compared result (an argument: an input)
    options = CompareOptions(confidence=confidence, correction="bonferroni" if bonferroni else "none",
                             fail_on=parse_fail_on(fail_on) if fail_on else (), loops=loops)
    result = run_compare(baseline, new, options, by=by)
    write_reports(result, junit_target=junit_target, markdown_target=markdown_target, json_target=json_target)
    raise_for(result)


def write_reports(result: Comparison, *, junit_target: str | None = None, markdown_target: str | None = None,
                  json_target: str | None = None, table_err: bool = False) -> None:
    """Write the requested reports, and the terminal table (to stdout unless a report uses it, or stderr)."""
    from ..compare import format_table, to_junit_xml, to_markdown

    if junit_target:
        _write(junit_target, to_junit_xml(result))
    if markdown_target:
        _write(markdown_target, to_markdown(result))
    if json_target:
        dump_json(result.to_json(), json_target)
    if table_err:
        click.echo(format_table(result), err=True)
    elif "-" not in (json_target, junit_target, markdown_target):
        click.echo(format_table(result))


def raise_for(result: Comparison) -> None:
    """Raise the comparison's error (exit 9 changed, 10 missing) with a one-line message; return if neither."""
    from ..compare.records import LoopChangedError, ResultMissingError

    failed = [c for c in result.changes if c.failed]
    if failed:
        raise LoopChangedError(
            f"{len(failed)} parameter(s) changed beyond tolerance: "
            + ", ".join(f"{c.name + ' ' if c.name else ''}{c.loop} {c.parameter}" for c in failed))
    if result.missing:
        raise ResultMissingError(
            f"{len(result.missing)} loop(s) missing or unusable: "
            + ", ".join(f"{m.name + ' ' if m.name else ''}{m.loop} ({m.side})" for m in result.missing))


def compare_batch(baseline: str, out_dir: str, fail_on: str | None, *, table_err: bool = False) -> Comparison:
    """``batch --against``: compare a finished batch's ``out_dir`` against ``baseline`` (matched by log).

    Writes ``compare.json``, ``compare.xml`` (JUnit) and ``compare.md`` into ``out_dir`` and prints the
    table (to stderr with ``table_err``, when stdout carries JSON). The caller decides the exit code
    (:func:`raise_for`).
    """
    from ..compare import CompareOptions, compare as run_compare, parse_fail_on

    options = CompareOptions(fail_on=parse_fail_on(fail_on) if fail_on else ())
    result = run_compare(baseline, out_dir, options, by="log")
    out = Path(out_dir)
    write_reports(result, junit_target=str(out / "compare.xml"), markdown_target=str(out / "compare.md"),
                  json_target=str(out / "compare.json"), table_err=table_err)
    return result
