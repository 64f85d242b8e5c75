"""``mrft-ident vehicle --report DIR``: one report for the vehicle, a page per loop.

``DIR/index.html`` holds the assumptions, the vehicle's table (every identified loop with its model
and gains) and the missing loops with the tests to fly next; each identified loop gets the analysis
report (:func:`mrftcli.report.analysis.write_analysis_report`) in ``DIR/<loop>/`` and its gains' report
(:func:`mrftcli.report.tune.write_tune_report`) in ``DIR/<loop>/gains/``, linked from both.
"""

from __future__ import annotations

from pathlib import Path

from ..progress import Progress, report
from ..mrft.model import LoopModel
from ..vehicle import VehicleLoop, VehicleResult
from ._common import ensure_dir, esc, html_page, html_table, write_page
from .analysis import write_analysis_report
from .tune import write_tune_report
from .wording import gain_unit, output_unit, sig

__all__ = ["write_vehicle_report"]


def _loop_rows(result: VehicleResult) -> list[list[str]]:
    rows = []
    for name, entry in result.loops.items():
        g, est = entry.gains, entry.estimates
        y = output_unit(name)
        gains = ("not tuned" if g is None else
                 f"{g.design} {g.kind}: Kp {sig(g.controller.Kp)} cmd/{y}, Ki {sig(g.controller.Ki)} cmd/({y} s), "
                 f"Kd {sig(g.controller.Kd)} cmd s/{y}, Tf {sig(g.controller.Tf * 1e3)} ms at {g.controller.rate_hz:g} Hz")
        pm = "-" if g is None else f"{g.phase_margin_deg:.1f}"
        k_unit = gain_unit(name) if entry.analysis.kind == "soiptd" else entry.analysis.parameters["K"].unit
        rows.append([name, entry.role, entry.route, str(len(entry.analysis.tests)), sig(est["Td"][0]),
                     sig(est["tau"][0] * 1e3), f"{sig(est['K'][0])} {k_unit}", gains, pm])
    return rows


def _index_body(result: VehicleResult) -> str:
    body = [f"<p class='muted'>{esc(result.path)} - layout {esc(result.layout or 'not recognised')} - inner loops "
            "first; times are seconds from the log start on each loop's page</p>"]
    if result.assumptions:
        body.append("<h2>Assumptions</h2><ul>" + "".join(f"<li class='warn'>{esc(a)}</li>" for a in result.assumptions)
                    + "</ul>")
    body.append("<h2>Loops</h2>")
    body.append(html_table(["loop", "role", "model", "tests", "Td [s]", "tau [ms]", "K", "gains", "PM [deg]"],
                           _loop_rows(result)))
    links = [f"<a href='{esc(name)}/index.html'>{esc(name)}: analysis</a> - "
             f"<a href='{esc(name)}/gains/index.html'>gains</a>" if entry.gains is not None else
             f"<a href='{esc(name)}/index.html'>{esc(name)}: analysis</a>"
             for name, entry in result.loops.items()]
    body.append("<p>" + "<br>".join(links) + "</p>")
    for name, entry in result.loops.items():
        if entry.route_notes:
            body.append(f"<p class='warn'>{esc(name)}: " + " ".join(esc(n) for n in entry.route_notes) + "</p>")
    if result.missing:
        body.append("<h2>Loops still to fly</h2>")
        body.append(html_table(["loop", "why", "what was found", "next tests"],
                               [[name, m.reason, m.message, m.next_tests] for name, m in result.missing.items()]))
    if result.warnings:
        body.append("<h2>Warnings</h2><ul>" + "".join(f"<li class='warn'>{esc(w)}</li>" for w in result.warnings)
                    + "</ul>")
    return "\n".join(body)


def _gains_paragraph(entry: VehicleLoop) -> list[str]:
    """A cascade's outer gains (its page is the analysis page; eq. (2)'s gains have a page of their own)."""
    if entry.gains is None or entry.analysis.kind != "cascade":
        return []
    c = entry.gains.controller
    return [f"<h2>Gains</h2><p>{esc(entry.gains.design)} PD on the exact sampled cascade: Kp {c.Kp:.4g}, "
            f"Kd {c.Kd:.4g}, Tf {c.Tf * 1e3:.3g} ms at {c.rate_hz:g} Hz; phase margin "
            f"{entry.gains.phase_margin_deg:.1f} deg</p>"]


def write_vehicle_report(result: VehicleResult, out_dir: str | Path, progress: Progress | None = None) -> Path:
    """Write the vehicle's index.html and a page per loop (analysis and gains); returns the index path.

    ``result`` must come from :func:`mrftcli.vehicle.identify_vehicle` in this process (the loop pages
    plot the flight's signals, which the JSON does not hold). ``progress(done, total, stage)`` is
    called per loop.
    """
    out = ensure_dir(out_dir)
    names = list(result.loops)
    for i, name in enumerate(names):
        report(progress, i, len(names), f"report: {name}")
        entry = result.loops[name]
        links = [("../index.html", "The vehicle")]
        if entry.gains is not None and isinstance(entry.gains.tune.model, LoopModel):  # eq. (2)'s page; a cascade's below
            write_tune_report(entry.gains.tune, out / name / "gains")
            links.append(("gains/index.html", f"Gains of the {name} loop"))
        write_analysis_report(entry.analysis, out / name, links=links, extra=_gains_paragraph(entry))
    report(progress, len(names), len(names), "index.html")
    index = out / "index.html"
    write_page(index, html_page(f"MRFT vehicle: {Path(result.path).name}", _index_body(result)))
    return index
