"""A comparison as people and CI systems read it: a terminal table, Markdown, JUnit XML.

JUnit: one ``<testsuite>`` (``mrft-ident compare``) with one ``<testcase>`` per loop and parameter
(``classname`` = ``[NAME.]LOOP``, ``name`` = the parameter): a ``changed`` parameter is a
``<failure>``, an ``undetermined`` one is ``<skipped>``, a missing or unusable loop is one test case
(``name`` = ``result``) with an ``<error>``. Every case carries the figures in its ``<system-out>``.
"""

from __future__ import annotations

import math
import textwrap
import xml.etree.ElementTree as ET

from ..mrft.parameter import display_scale
from .records import Comparison, MissingResult, ParameterChange

__all__ = ["format_table", "to_markdown", "to_junit_xml", "format_value", "format_change", "TIME_PARAMETERS",
           "TABLE_WIDTH"]

#: The time parameters [s in the records]: shown as analyze shows them (:func:`mrftcli.mrft.parameter.display_scale`:
#: a vehicle loop's tau in ms, a process plant's in s), their unit in the table's param cell. Any other parameter
#: (K) is shown in its records' own unit (:attr:`ParameterChange.unit`): K's depends on the model.
TIME_PARAMETERS = ("Td", "tau", "T", "T1", "T2")


def _scale(param: str, unit: str = "", process: bool = False) -> tuple[str, float]:
    """(display unit, factor from SI): a time parameter's (``process``: a process plant's), else the records'
    ``unit``."""
    if param not in TIME_PARAMETERS:
        return unit, 1.0
    f, shown = display_scale(param, "s", process)
    return shown, f


def format_value(param: str, value: float | None, unit: str = "", process: bool = False) -> str:
    """A parameter value in its display unit, or ``-``; ``unit``: the records' unit of a parameter that is not
    a time (K's); ``process``: a process plant's (tau in s).

    >>> format_value("tau", 0.0464), format_value("K", 19.62, "output / (command s^2)")
    ('46.4 ms', '19.62 output / (command s^2)')
    """
    unit, f = _scale(param, unit, process)
    text = _number(value, f)
    return text if text == "-" else f"{text} {unit}".rstrip()


def format_change(c: ParameterChange, confidence: float) -> str:
    """``+20.01 ms [+19.96, +20.06] (95 %)``, or the reason it is undetermined.

    >>> from mrftcli.compare.records import ParameterChange
    >>> c = ParameterChange(None, "altitude", "tau", 0.0464, 0.0664, 0.02, 0.0199, 0.0201, 400.0, True, None,
    ...                     False, "changed")
    >>> format_change(c, 0.95)
    '+20 ms [+19.9, +20.1] (95 %)'
    """
    if c.change is None or c.low is None or c.high is None:
        return f"undetermined ({c.note})" if c.note else "undetermined"
    unit, f = _scale(c.parameter, c.unit, c.process)
    pct = f"{100 * confidence:.3g}"
    return f"{c.change * f:+.4g} {unit} [{c.low * f:+.4g}, {c.high * f:+.4g}] ({pct} %)".replace("  ", " ")


def _relative(c: ParameterChange) -> str:
    r = c.relative
    return "-" if r is None else f"{100 * r:+.2g} %"


def _who(name: str | None, loop: str) -> str:
    return f"{name} {loop}" if name else loop


def _z(z: float | None) -> str:
    if z is None:
        return "-"
    return f"{z:+.1f}" if math.isfinite(z) else ("+inf" if z > 0 else "-inf")


def _rows(cmp: Comparison) -> list[list[str]]:
    rows = []
    for c in cmp.changes:
        rows.append([_who(c.name, c.loop), c.parameter, format_value(c.parameter, c.baseline, c.unit, c.process),
                     format_value(c.parameter, c.new, c.unit, c.process), format_change(c, cmp.confidence), _relative(c), _z(c.z),
                     c.tolerance or "-", c.verdict])
    for m in cmp.missing:
        rows.append([_who(m.name, m.loop), "-", "-", "-", f"missing on {m.side}", "-", "-", "-", "missing"])
    return rows


_HEADER = ["loop", "param", "baseline", "new", "change [interval]", "relative", "z", "tolerance", "verdict"]

#: The terminal table's width limit [characters]: a terminal, and a PR comment's code block.
TABLE_WIDTH = 100


def _summary(cmp: Comparison) -> str:
    failed = [c for c in cmp.changes if c.failed]
    code = cmp.exit_code
    if failed:
        what = ", ".join(f"{_who(c.name, c.loop)} {c.parameter} {format_change(c, cmp.confidence).split(' [')[0]}"
                         for c in failed)
        return f"CHANGED ({len(failed)} of {len(cmp.changes)} parameters): {what}; exit code {code}"
    if cmp.missing:
        return f"INCOMPLETE: {len(cmp.missing)} loop(s) missing or unusable; exit code {code}"
    return f"no change beyond tolerance in {len(cmp.changes)} parameters; exit code 0"


def _short_change(c: ParameterChange) -> str:
    """The change and its interval in the parameter's display unit, without the unit (the header has it)."""
    if c.change is None or c.low is None or c.high is None:
        return "undetermined"
    _, f = _scale(c.parameter, c.unit, c.process)
    return f"{c.change * f:+.4g} [{c.low * f:+.4g}, {c.high * f:+.4g}]"


def _number(x: float | None, factor: float) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x * factor:.4g}"


def _terminal_rows(cmp: Comparison) -> list[tuple[str | None, list[str]]]:
    """(name, cells) per change and missing loop, for the terminal table (a time's unit in the param cell; K's,
    which is long and depends on the model, below the table: :func:`_unit_lines`)."""
    out: list[tuple[str | None, list[str]]] = []
    for c in cmp.changes:
        unit, f = _scale(c.parameter, "", c.process)
        tol = (c.tolerance or "-").split(":")[-1]
        out.append((c.name, [c.loop, f"{c.parameter} {unit}".rstrip(), _number(c.baseline, f), _number(c.new, f),
                             _short_change(c), _relative(c), _z(c.z), tol, c.verdict]))
    for m in cmp.missing:
        out.append((m.name, [m.loop, "-", "-", "-", f"missing on {m.side}", "-", "-", "-", "missing"]))
    return out


def _unit_lines(cmp: Comparison) -> list[str]:
    """``K in output / (command s^2)``: the records' unit of each parameter that is not a time (the loops named
    when the table holds several units for it: eq. (2)'s K and a process family's)."""
    units: dict[str, dict[str, list[str]]] = {}
    for c in cmp.changes:
        if c.parameter not in TIME_PARAMETERS and c.unit:
            units.setdefault(c.parameter, {}).setdefault(c.unit, []).append(_who(c.name, c.loop))
    lines = []
    for param, by_unit in units.items():
        text = (next(iter(by_unit)) if len(by_unit) == 1 else
                "; ".join(f"{u} ({', '.join(dict.fromkeys(who))})" for u, who in by_unit.items()))
        lines += _wrapped(f"{param} in ", text)
    return lines


def _wrapped(prefix: str, text: str) -> list[str]:
    return textwrap.wrap(f"{prefix}{text}", TABLE_WIDTH, subsequent_indent="  ", break_on_hyphens=False) or [prefix]


def format_table(cmp: Comparison) -> str:
    """The terminal report: header lines, one row per loop and parameter (under its log or vehicle name),
    the missing loops' reasons and the notes, a verdict line; at most :data:`TABLE_WIDTH` columns."""
    header = ["loop", "param", "baseline", "new", f"change [{100 * cmp.confidence:.3g} % interval]", "rel.", "z",
              "tol.", "verdict"]
    rows = _terminal_rows(cmp)
    widths = [max(len(r[i]) for r in [header, *(cells for _, cells in rows)]) for i in range(len(header))]
    sep = "  " if sum(widths) + 2 * (len(widths) - 1) <= TABLE_WIDTH else " "

    def line(cells: list[str]) -> str:
        return sep.join(cell.ljust(w) for cell, w in zip(cells, widths)).rstrip()

    lines = [f"baseline {cmp.baseline}", f"new      {cmp.new}",
             f"confidence {100 * cmp.confidence:.3g} % per parameter"
             + (" (Bonferroni over each loop's parameters)" if cmp.correction == "bonferroni" else "")
             + (f"; fail on {', '.join(cmp.fail_on)}" if cmp.fail_on else "; fail on any significant change"
                if not any(c.tolerance for c in cmp.changes) else ""), line(header)]
    shown: str | None = None
    for name, cells in sorted(rows, key=lambda r: r[0] or "") if any(n for n, _ in rows) else rows:
        if name is not None and name != shown:
            lines.append(name if len(name) <= TABLE_WIDTH else "..." + name[-(TABLE_WIDTH - 3):])
            shown = name
        lines.append(line(cells))
    lines += _unit_lines(cmp)
    for c in cmp.changes:
        if c.verdict == "undetermined" and c.note:
            lines += _wrapped("undetermined: ", f"{_who(c.name, c.loop)} {c.parameter}: {c.note}")
    for m in cmp.missing:
        lines += _wrapped("missing: ", f"{_who(m.name, m.loop)} on {m.side}: {m.reason}")
    for n in cmp.notes:
        lines += _wrapped("note: ", n)
    lines += _wrapped("", _summary(cmp))
    return "\n".join(lines)


def to_markdown(cmp: Comparison) -> str:
    """A Markdown table for a merge-request comment (GitHub/GitLab flavoured)."""
    icon = {"changed": ":x: changed", "significant": ":warning: significant", "unchanged": ":white_check_mark: unchanged",
            "undetermined": ":grey_question: undetermined", "missing": ":no_entry: missing"}
    lines = ["### mrft-ident compare", "",
             f"Baseline `{cmp.baseline}`, new `{cmp.new}`; intervals at {100 * cmp.confidence:.3g} % per parameter"
             + (" (Bonferroni per loop)" if cmp.correction == "bonferroni" else "") + ".", "",
             "| " + " | ".join(_HEADER) + " |", "|" + "---|" * len(_HEADER)]
    for r in _rows(cmp):
        r[-1] = icon.get(r[-1], r[-1])
        lines.append("| " + " | ".join(cell.replace("|", "\\|") for cell in r) + " |")
    lines += ["", *(f"- missing: {_who(m.name, m.loop)} on {m.side}: {m.reason}" for m in cmp.missing),
              *(f"> note: {n}" for n in cmp.notes), f"**{_summary(cmp)}**", ""]
    return "\n".join(lines)


def _case_text(c: ParameterChange, confidence: float) -> str:
    return (f"baseline {format_value(c.parameter, c.baseline, c.unit, c.process)}, "
            f"new {format_value(c.parameter, c.new, c.unit, c.process)}, "
            f"change {format_change(c, confidence)}, z {_z(c.z)}, "
            f"tolerance {c.tolerance or '-'}, verdict {c.verdict}")


def _missing_case(suite: ET.Element, m: MissingResult) -> None:
    case = ET.SubElement(suite, "testcase", classname=f"{m.name}.{m.loop}" if m.name else m.loop, name="result")
    ET.SubElement(case, "error", message=f"missing on {m.side}: {m.reason}", type="missing")


def to_junit_xml(cmp: Comparison) -> str:
    """JUnit XML (module docstring), as a string with an XML declaration."""
    failures = sum(c.failed for c in cmp.changes)
    skipped = sum(c.verdict == "undetermined" for c in cmp.changes)
    suites = ET.Element("testsuites", name="mrft-ident compare")
    suite = ET.SubElement(suites, "testsuite", name="mrft-ident compare", tests=str(len(cmp.changes) + len(cmp.missing)),
                          failures=str(failures), errors=str(len(cmp.missing)), skipped=str(skipped))
    for c in cmp.changes:
        case = ET.SubElement(suite, "testcase", classname=f"{c.name}.{c.loop}" if c.name else c.loop, name=c.parameter)
        text = _case_text(c, cmp.confidence)
        if c.failed:
            ET.SubElement(case, "failure", message=f"{c.parameter} changed: {format_change(c, cmp.confidence)}",
                          type="changed").text = text
        elif c.verdict == "undetermined":
            ET.SubElement(case, "skipped", message=f"undetermined: {c.note}")
        ET.SubElement(case, "system-out").text = text
    for m in cmp.missing:
        _missing_case(suite, m)
    for attr in ("tests", "failures", "errors", "skipped"):
        suites.set(attr, suite.get(attr, "0"))
    ET.indent(suites)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(suites, encoding="unicode") + "\n"
