"""Plots and an HTML page for ``mrft-ident tune --report``: Bode with margins, step responses with a posterior band."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._common import ensure_dir, html_page, html_table, new_figure, save_figure

if TYPE_CHECKING:
    from ..tune.design import TuneResult

__all__ = ["write_tune_report", "plot_bode", "plot_steps"]

_COLOURS = {"mrft-rule": "#D55E00", "model-based": "#0072B2", "robust": "#009E73"}


def plot_bode(result: "TuneResult", path: str | Path, kind: str = "PD") -> Path:
    """Bode plot of the sampled loop L = C Gd of each ``kind`` design, crossovers and margins marked."""
    from ..tune.margins import margin_grid, plant_response

    # the margins' grid: fine enough at high frequency for the delay's phase to unwrap at any delay
    w = margin_grid(result.rate_hz, int(result.model.tau * result.rate_hz))
    Gd = plant_response([result.model], result.rate_hz, w)[0]
    fig, (a1, a2) = new_figure(2, 1, width=9.0, height=6.5, sharex=True)
    for d in result.designs:
        if d.kind != kind:
            continue
        L = d.controller.feedback_response(w) * Gd
        col = _COLOURS.get(d.name)
        a1.semilogx(w, 20 * np.log10(np.abs(L)), color=col, label=f"{d.name} (PM {d.margins.phase_margin_deg:.0f} deg, "
                    f"GM {20 * math.log10(d.margins.gain_margin):.1f} dB, DM {d.margins.delay_margin_s * 1e3:.0f} ms)")
        a2.semilogx(w, np.degrees(np.unwrap(np.angle(L))), color=col)
        if math.isfinite(d.margins.w_gc):
            a2.plot([d.margins.w_gc], [-180 + d.margins.phase_margin_deg], "o", color=col)
    a1.axhline(0, color="k", lw=0.8)
    a2.axhline(-180, color="k", lw=0.8)
    a1.set_ylabel("|L| [dB]")
    a2.set_ylabel("arg L [deg]")
    a2.set_xlabel("frequency [rad/s] (up to Nyquist)")
    a1.set_title(f"{kind} loops on the identified model, {result.rate_hz:g} Hz, exact delay {result.model.tau * 1e3:.1f} ms")
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


def write_tune_report(result: "TuneResult", out_dir: str | Path) -> Path:
    """Write bode_<kind>.png, steps_<kind>.png and index.html to ``out_dir``; returns the index path."""
    out = ensure_dir(out_dir)
    body = [f"<p>Model Tp {result.model.Tp:g} s, Td {result.model.Td:.4g} s, tau {result.model.tau * 1e3:.4g} ms, "
            f"K {result.model.K:.4g}; controller {result.rate_hz:g} Hz; {result.objective.upper()} with Ms &le; "
            f"{result.ms_max:g}.</p>"]
    if result.rate_filter is not None:  # an export's design: Tf is replaced by the stack's filter
        f = result.rate_filter
        body.append(f"<p>Derivative through the stack's rate filter ({f.parameter or 'rate filter'}: 2nd-order "
                    f"Butterworth at {f.cutoff_hz:g} Hz), not Tf; every figure and plot includes it.</p>")
    rows = []
    for d in result.designs:
        w = d.posterior.get("worst", {}) if d.posterior else {}
        rows.append([d.name, d.kind, f"{d.controller.Kp:.4g}", f"{d.controller.Ki:.4g}", f"{d.controller.Kd:.4g}",
                     f"{d.controller.Tf * 1e3:.2f}", f"{d.margins.phase_margin_deg:.1f}",
                     f"{d.margins.delay_margin_s * 1e3:.1f}", f"{d.margins.Ms:.2f}", f"{d.step.overshoot_pct:.1f}",
                     f"{d.step.settling_s:.2f}", f"{w.get('phase_margin_deg', float('nan')):.1f}",
                     f"{w.get('Ms', float('nan')):.2f}"])
    body.append(html_table(["design", "kind", "Kp", "Ki", "Kd", "Tf [ms]", "PM [deg]", "DM [ms]", "Ms", "OS [%]",
                            "settling [s]", "worst PM (95 %)", "worst Ms (95 %)"], rows))
    for kind in sorted({d.kind for d in result.designs}):
        b = plot_bode(result, out / f"bode_{kind}.png", kind)
        s = plot_steps(result, out / f"steps_{kind}.png", kind)
        body.append(f"<h2>{kind}</h2><img src='{b.name}'><img src='{s.name}'>")
    index = out / "index.html"
    index.write_text(html_page("mrft-ident tune", "\n".join(body)))
    return index
