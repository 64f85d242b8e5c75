"""``mrft-ident vehicle --report DIR``: one report for the vehicle, a page per loop.

``DIR/index.html`` holds the assumptions, the vehicle's table (every identified loop with its model
and gains) and the missing loops with the tests to fly next; each identified loop gets the analysis
report (:func:`mrftcli.report.analysis.write_analysis_report`) in ``DIR/<loop>/`` and its gains' report
(:func:`mrftcli.report.tune.write_tune_report`) in ``DIR/<loop>/gains/``, linked from both.
"""

from __future__ import annotations

import math
from pathlib import Path

from ..progress import Progress, report
from ..mrft.model import LoopModel
from ..vehicle import VehicleLoop, VehicleResult
from ._common import ensure_dir, esc, html_page, html_table, write_page
from .analysis import write_analysis_report
from .tune import write_tune_report
from .wording import gain_unit, output_unit

__all__ = ["write_vehicle_report"]


def _num(x: float, digits: int = 4) -> str:
    return "-" if not math.isfinite(x) else f"{x:.{digits}g}"


def _loop_rows(result: VehicleResult) -> list[list[str]]:
    rows = []
    for name, entry in result.loops.items():
        g, est = entry.gains, entry.estimates
        y = output_unit(name)
        gains = ("not tuned" if g is None else
                 f"{g.design} {g.kind}: Kp {_num(g.controller.Kp)} cmd/{y}, Ki {_num(g.controller.Ki)} cmd/({y} s), "
                 f"Kd {_num(g.controller.Kd)} cmd s/{y}, Tf {_num(g.controller.Tf * 1e3)} ms at {g.controller.rate_hz:g} Hz")
        pm = "-" if g is None else f"{g.phase_margin_deg:.1f}"
        k_unit = gain_unit(name) if entry.analysis.kind == "soiptd" else entry.analysis.parameters["K"].unit
        rows.append([name, entry.role, entry.route, str(len(entry.analysis.tests)), _num(est["Td"][0]),
                     _num(est["tau"][0] * 1e3), f"{_num(est['K'][0])} {k_unit}", gains, pm])
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


def _cascade_page(entry: VehicleLoop, folder: Path) -> Path:
    """An outer loop identified through its closed inner loop: its assumptions, parameters, tests, gains."""
    a = entry.analysis
    assert a.kind == "cascade"  # only called for the cascade route
    est = a.parameters
    body = [f"<p><a href='../index.html'>The vehicle</a> - the {esc(entry.loop)} loop through the closed "
            f"{esc(a.model.inner.loop or 'inner')} loop: G(s) = K T<sub>inner</sub>(s) Td e<sup>-tau s</sup> / "
            "(s (Td s + 1))</p>",
            "<h2>Assumptions</h2><ul>" + "".join(f"<li>{esc(x)}</li>" for x in a.assumptions) + "</ul>",
            "<h2>Parameters</h2>",
            html_table(["parameter", "estimate", "std", "95 % interval", "unit"],
                       [[k, f"{e.value:.4g}", "known" if e.known else f"{e.std:.2g}",
                         "" if e.known else f"{e.ci95_low:.4g} - {e.ci95_high:.4g}", e.unit] for k, e in est.items()]),
            "<h2>Tests</h2>",
            html_table(["test", "beta nominal", "h", "frequency [Hz]", "amplitude [m]", "stable / cycles"],
                       [[t.index + 1, "-" if t.beta_nominal is None else f"{t.beta_nominal:+.3f}", f"{t.h:.4g}",
                         f"{t.frequency_hz_mean:.4f}", f"{t.amplitude_mean:.4g}", f"{t.n_stable} / {len(t.cycles)}"]
                        for t in a.tests])]
    if entry.gains is not None:
        c = entry.gains.controller
        body.append(f"<h2>Gains</h2><p>{esc(entry.gains.design)} PD on the exact sampled cascade: Kp {c.Kp:.4g}, "
                    f"Kd {c.Kd:.4g}, Tf {c.Tf * 1e3:.3g} ms at {c.rate_hz:g} Hz; phase margin "
                    f"{entry.gains.phase_margin_deg:.1f} deg</p>")
    if a.warnings:
        body.append("<h2>Warnings</h2><ul>" + "".join(f"<li class='warn'>{esc(w)}</li>" for w in a.warnings) + "</ul>")
    index = ensure_dir(folder) / "index.html"
    write_page(index, html_page(f"MRFT cascade: {Path(a.path).name} ({entry.loop})", "\n".join(body)))
    return index


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
        if entry.analysis.kind == "soiptd":
            write_analysis_report(entry.analysis, out / name, links=links)
        else:
            _cascade_page(entry, out / name)
    report(progress, len(names), len(names), "index.html")
    index = out / "index.html"
    write_page(index, html_page(f"MRFT vehicle: {Path(result.path).name}", _index_body(result)))
    return index
