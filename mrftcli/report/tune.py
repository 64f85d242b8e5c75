"""Plots and an HTML page for ``mrft-ident tune --report``: Bode with margins, step responses with a posterior band."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ._common import ensure_dir, esc, html_page, html_table, new_figure, save_figure, write_page
from .wording import gain_unit, output_unit

if TYPE_CHECKING:
    from ..tune.design import Design, TuneResult
    from ..tune.stacks import StackExport

__all__ = ["write_tune_report", "plot_bode", "plot_steps", "recommended_design", "export_section"]

_COLOURS = {"mrft-rule": "#D55E00", "model-based": "#0072B2", "robust": "#009E73"}


def _phase_on_margin_branch(w: np.ndarray, L: np.ndarray, w_gc: float, pm_deg: float) -> np.ndarray:
    """arg L [deg] unwrapped along ``w`` and shifted by whole turns so that it passes through -180 + PM at the
    gain crossover (``np.angle`` starts a loop with two integrators on the +180 branch)."""
    ph = np.degrees(np.unwrap(np.angle(L)))
    if math.isfinite(w_gc) and math.isfinite(pm_deg):
        i = int(np.argmin(np.abs(np.log(w / w_gc))))
        return ph - 360.0 * np.round((ph[i] - (-180.0 + pm_deg)) / 360.0)
    return ph - 360.0 * np.ceil(ph[0] / 360.0)  # no crossover: start in (-360, 0]


def plot_bode(result: "TuneResult", path: str | Path, kind: str = "PD") -> Path:
    """Bode plot of the sampled loop L = C Gd of each ``kind`` design, crossovers and margins marked."""
    from ..tune.margins import margin_grid, plant_response

    # the margins' grid: fine enough at high frequency for the delay's phase to unwrap at any delay
    w = margin_grid(result.rate_hz, int(result.loop_model.tau * result.rate_hz))
    Gd = plant_response([result.loop_model], result.rate_hz, w)[0]
    fig, (a1, a2) = new_figure(2, 1, width=9.0, height=6.5, sharex=True)
    for d in result.designs:
        if d.kind != kind:
            continue
        L = d.controller.feedback_response(w) * Gd
        col = _COLOURS.get(d.name)
        g = d.margins
        a1.semilogx(w, 20 * np.log10(np.abs(L)), color=col, label=f"{d.name} (PM {g.phase_margin_deg:.0f} deg, "
                    f"GM {20 * math.log10(g.gain_margin):.1f} dB, DM {g.delay_margin_s * 1e3:.0f} ms)")
        a2.semilogx(w, _phase_on_margin_branch(w, L, g.w_gc, g.phase_margin_deg), color=col)
        if math.isfinite(g.w_gc) and math.isfinite(g.phase_margin_deg):
            # the margin drawn where it is read: from -180 deg up to the phase at the gain crossover
            a1.plot([g.w_gc], [0.0], "o", color=col)
            a2.plot([g.w_gc, g.w_gc], [-180.0, -180.0 + g.phase_margin_deg], color=col, lw=2.5)
            a2.plot([g.w_gc], [-180 + g.phase_margin_deg], "o", color=col)
        if math.isfinite(g.w_pc) and math.isfinite(g.gain_margin) and g.gain_margin > 0:
            a1.plot([g.w_pc, g.w_pc], [0.0, -20 * math.log10(g.gain_margin)], color=col, lw=2.5)
            a2.plot([g.w_pc], [-180.0], "s", color=col, ms=4)
    a1.axhline(0, color="k", lw=0.8)
    a2.axhline(-180, color="k", lw=0.8)
    a1.set_ylabel("|L| [dB]")
    a2.set_ylabel("arg L [deg]")
    a2.set_xlabel("frequency [rad/s] (up to Nyquist)")
    a1.set_title(f"{kind} loops on the identified model, {result.rate_hz:g} Hz, exact delay {result.loop_model.tau * 1e3:.1f} ms"
                  + ("" if result.tau_identified is None else f" (identified {result.tau_identified * 1e3:.3g} ms, a lead)"))
    a1.legend(loc="lower left")
    a2.set_ylim(-360, 0)
    return save_figure(fig, path)


def plot_steps(result: "TuneResult", path: str | Path, kind: str = "PD") -> Path:
    """Unit setpoint steps of the sampled loop: nominal line and the 2.5-97.5 % band over the posterior."""
    from ..tune.closed_loop import step_response

    fig, ax = new_figure(1, 1, width=9.0, height=4.5)
    for d in result.designs:
        if d.kind != kind:
            continue
        col = _COLOURS.get(d.name)
        horizon = d.horizon_s if math.isfinite(d.horizon_s) else result.horizon_s
        t, y, _ = step_response([result.model], d.controller, horizon)
        ax.plot(t, y[0], color=col, label=f"{d.name} (OS {d.step.overshoot_pct:.1f} %, settle {d.step.settling_s:.2f} s)")
        if result.posterior is not None:
            idx = np.arange(result.posterior.n)[:100]
            _, yp, _ = step_response(result.posterior.models(idx), d.controller, horizon)
            ok = np.all(np.isfinite(yp), axis=1) & (np.max(np.abs(yp), axis=1) < 10)
            if ok.sum() >= 5:
                lo, hi = np.percentile(yp[ok], [2.5, 97.5], axis=0)
                ax.fill_between(t, lo, hi, color=col, alpha=0.15, lw=0)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_ylim(-0.1, 1.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{result.loop or 'output'} / step")
    ax.set_title(f"{kind} step responses (sampled loop; band: 95 % of the posterior draws)")
    ax.legend(loc="lower right")
    return save_figure(fig, path)


#: below this phase margin a loop rings and a small model error destabilises it (the usual 30-60 deg design range)
_PM_MIN_DEG = 30.0


def recommended_design(result: TuneResult) -> tuple[str, str]:
    """The design and kind ``tune`` exports when no ``--design``/``--kind`` is given: robust (else
    model-based), PD (else the first kind designed)."""
    from ..tune.analysis import recommended_design_name

    kinds = [d.kind for d in result.designs]
    return recommended_design_name(result), "PD" if "PD" in kinds else (kinds[0] if kinds else "PD")


def _flag(d: Design, ms_max: float) -> str:
    """Why a design should not be flown as it is (Ms over the bound, PM under 30 deg), else 'yes'."""
    why = []
    if not math.isfinite(d.margins.Ms) or d.margins.Ms > ms_max * 1.001:
        why.append(f"Ms {d.margins.Ms:.1f} > {ms_max:g}")
    if not math.isfinite(d.margins.phase_margin_deg) or d.margins.phase_margin_deg < _PM_MIN_DEG:
        why.append(f"PM {d.margins.phase_margin_deg:.1f} deg < {_PM_MIN_DEG:g} deg")
    return "NO: " + ", ".join(why) if why else "yes"


def _recommended_section(result: TuneResult, name: str, kind: str) -> str:
    """The design tune exports by default and its generic export (the controller as JSON)."""
    from ..tune.export import generic_export

    try:
        d = result.get(name, kind)
    except (KeyError, ValueError, InputError):
        return "<p>No robust or model-based design to recommend.</p>"
    c = d.controller
    y = output_unit(result.loop)
    export = generic_export(result, name, kind)  # the file tune --export generic writes, as written
    return (f"<h2>Recommended: {esc(name)} {esc(kind)}</h2>"
            f"<p>The design <code>tune</code> exports without <code>--design</code>/<code>--kind</code>: "
            f"Kp {c.Kp:.5g} cmd/{y}, Ki {c.Ki:.5g} cmd/({y} s), Kd {c.Kd:.5g} cmd s/{y}, Tf {c.Tf * 1e3:.4g} ms "
            f"at {c.rate_hz:g} Hz; PM {d.margins.phase_margin_deg:.1f} deg, Ms {d.margins.Ms:.2f}. "
            f"Its generic export (<code>tune --export generic</code>):</p><pre>{esc(export)}</pre>")


def export_section(e: "StackExport") -> str:
    """The stack export as written (``tune --export``): its assumptions first, each value with its documented
    range, the margins of the loop the values give with the stack's filter, the notes and the file."""
    from ..tune.ardupilot_z import margins_qualifier
    from ..tune.stack_params import STACK_PARAMS

    ranges = {p.name: p for p in STACK_PARAMS if p.stack == e.stack}
    rows = [[n, f"{v:.6g}", (f"{ranges[n].minimum:g} .. {ranges[n].maximum:g}" if n in ranges else "-"),
             ranges[n].unit if n in ranges else "-"] for n, v in e.params.items()]
    m = e.margins
    worst = margins_qualifier(e.stack, e.loop)
    parts = [f"<h2>Export: {esc(e.stack)} ({esc(e.design)}, {esc(e.loop)})</h2>"]
    parts += [f"<p><b>Assumption:</b> {esc(a)}</p>" for a in e.assumptions]
    parts.append(html_table(["parameter", "value", "documented range", "unit"], rows))
    parts.append(f"<p>Margins with the stack's filter and rate{worst}: GM {m.gain_margin:.3g}, PM "
                 f"{m.phase_margin_deg:.1f} deg, delay margin {m.delay_margin_s * 1e3:.1f} ms, Ms {m.Ms:.3g}.</p>")
    if e.notes:
        parts.append("<ul>" + "".join(f"<li>{esc(n)}</li>" for n in e.notes) + "</ul>")
    parts.append(f"<p>The file the stack loads:</p><pre>{esc(e.file_text())}</pre>")
    return "\n".join(parts)


def write_tune_report(result: "TuneResult", out_dir: str | Path, export: "StackExport | None" = None) -> Path:
    """Write bode_<kind>.png, steps_<kind>.png and index.html to ``out_dir``; returns the index path.

    ``export``: the stack export written with ``--export`` (shown after the recommended design)."""
    out = ensure_dir(out_dir)
    m = result.loop_model
    from ..tune.design import assumptions_first, tau_line

    # what the designs rest on (a lead taken as tau 0) first, then the model as designed
    body = [f"<p><b>note: {esc(n)}</b></p>" for n in assumptions_first(result.notes) if n.startswith("assumed:")]
    body += [f"<p>Model Tp {m.Tp:g} s, Td {m.Td:.4g} s, {esc(tau_line(result))}, "
            f"K {m.K:.4g} {gain_unit(result.loop)}; controller {result.rate_hz:g} Hz; {result.objective.upper()} with Ms &le; "
            f"{result.ms_max:g}.</p>"]
    if result.rate_filter is not None:  # an export's design: Tf is replaced by the stack's filter
        f = result.rate_filter
        body.append(f"<p>Derivative through the stack's rate filter ({f.parameter or 'rate filter'}: 2nd-order "
                    f"Butterworth at {f.cutoff_hz:g} Hz), not Tf; every figure and plot includes it.</p>")
    name, kind = recommended_design(result)
    rows = []
    for d in result.designs:
        w = d.posterior.get("worst", {}) if d.posterior else {}
        label = f"{d.name} (recommended)" if (d.name, d.kind) == (name, kind) else d.name
        rows.append([label, d.kind, f"{d.controller.Kp:.4g}", f"{d.controller.Ki:.4g}", f"{d.controller.Kd:.4g}",
                     f"{d.controller.Tf * 1e3:.2f}", f"{d.margins.phase_margin_deg:.1f}",
                     f"{d.margins.delay_margin_s * 1e3:.1f}", f"{d.margins.Ms:.2f}", f"{d.step.overshoot_pct:.1f}",
                     f"{d.step.settling_s:.2f}", f"{w.get('phase_margin_deg', float('nan')):.1f}",
                     f"{w.get('Ms', float('nan')):.2f}", _flag(d, result.ms_max)])
    y = output_unit(result.loop)
    body.append(html_table(["design", "kind", f"Kp [cmd/{y}]", f"Ki [cmd/({y} s)]", f"Kd [cmd s/{y}]", "Tf [ms]",
                            "PM [deg]", "DM [ms]", "Ms", "OS [%]", "settling [s]", "worst PM [deg] (95 %)",
                            "worst Ms (95 %)", "fit to fly?"], rows))
    body.append(_recommended_section(result, name, kind))
    if export is not None:
        body.append(export_section(export))
    for kind in sorted({d.kind for d in result.designs}):
        b = plot_bode(result, out / f"bode_{kind}.png", kind)
        s = plot_steps(result, out / f"steps_{kind}.png", kind)
        body.append(f"<h2>{kind}</h2><img src='{b.name}'><img src='{s.name}'>")
    index = out / "index.html"
    write_page(index, html_page("mrft-ident tune", "\n".join(body)))
    return index
