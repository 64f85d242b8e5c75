"""``mrft-ident topics LOG``: what a log holds (topics/messages/columns, types, counts, rates)."""

from __future__ import annotations

import click

from ..io import READ_FORMATS

from .options import dump_json, json_option, quiet_option, read_progress, text_table

__all__ = ["topics"]


def _rate(value: float | None) -> str:
    if value is None:
        return "-"
    return f"{value:.1f}" if value >= 1 else f"{value:.2g}"  # sparse topics (beta) keep a digit


@click.command("topics")
@click.argument("log", type=click.Path(exists=False, dir_okay=True))
@click.option("--format", "fmt", default=None, metavar="FMT",
              help=f"Log format (default: detected from the file): {', '.join(READ_FORMATS)}.")
@click.option("--fields", is_flag=True, help="Also list each topic's numeric fields.")
@json_option(what="topics, the format and the layout")
@quiet_option()
def topics(log: str, fmt: str | None, fields: bool, json_target: str | None, quiet: bool) -> None:
    """List the topics of LOG with message types, counts and mean rates.

    For ULog the topics are the logged messages (``name.N`` for instance N), for CSV the columns, for
    ArduPilot DataFlash the message types. Use the names (and the fields shown by ``--fields``) in
    ``--command-topic TOPIC[:FIELD]`` / ``--output-topic TOPIC[:FIELD]``.
    """
    from ..io import log_layout, open_log

    # a bar only for a read that takes seconds (a large CSV's passes)
    with read_progress(not quiet) as progress, open_log(log, fmt, progress=progress) as source:
        infos = source.topics()
        warnings = list(source.warnings)
        fmt_name = source.format
        layout = log_layout(source).describe()
        if not any(i.count for i in infos):
            from ..errors import LogReadError

            raise LogReadError(f"{log}: the log holds no messages (empty or cut off early)")
    if json_target:
        dump_json({
            "path": log,
            "format": fmt_name,
            "layout": layout,
            "topics": [{"name": i.name, "type": i.msgtype, "count": i.count, "rate_hz": i.rate_hz,
                        "fields": list(i.fields)} for i in infos],
            "warnings": warnings,
        }, json_target)
    if json_target == "-":
        return
    head, *lines = text_table([("topic", "type", "count", "rate_hz"),
                               *((i.name, i.msgtype, str(i.count), _rate(i.rate_hz)) for i in infos)], align="<<>>")
    click.echo(f"{log} ({fmt_name}, {len(infos)} topics)")
    click.echo(f"layout: {layout}")
    click.echo(head)
    for info, line in zip(infos, lines):
        click.echo(line)
        if fields and info.fields:
            click.echo("    fields: " + ", ".join(info.fields))
