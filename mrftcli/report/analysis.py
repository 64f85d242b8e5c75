"""The ``analyze --report DIR`` page: index.html and PNG figures of an AnalysisResult, of every family.

Figures (each function takes a finished :class:`~mrftcli.analyze.AnalysisResult` and returns a
matplotlib Figure; :func:`write_analysis_report` saves them). Every analysis gets 1, 4, 5 and 6 (the
tests drawn are :attr:`~mrftcli.analyze.AnalysisResult.segmented`; a process family's Bode plot
carries its measured response points); 2 and 3 are eq. (2)'s (its manifolds and its Table III):

1. :func:`plot_timeseries` - command and output over the log, tests shaded, stable cycles marked,
   plus a zoom on a few stable cycles of each test (switch instants, fitted extrema, the switching
   levels actually achieved).
2. :func:`plot_manifolds` - the paper's Fig. 5: for each test the UFM slice at the known Tp scaled to
   real units (tau against Td), their intersection with its 95 % interval, and the per-combination
   estimates.
3. :func:`plot_spread` - Td, tau and K: the spread over cycle combinations (paper Table III) and
   the bootstrap distribution of the estimate, with the point estimate and 95 % interval.
4. :func:`plot_cycles` - per test, each cycle's period and amplitude against the stable-cycle
   tolerances (why a cycle was kept or left out).
5. :func:`plot_fit` - per test, the model's output (driven by the recorded relay command) over the
   measured output, and the residual below it with the sensor noise level.
6. :func:`plot_uncertainty` - the Bode plot of the identified plant with its 95 % band, the tests'
   frequencies marked, and eq. (2)'s Td-tau correlation: the posterior draws with their 95 % ellipse
   (a process family: its measured response points with their standard errors on the Bode plot).

The posterior is the one the analysis keeps: the waveform refinement's Gauss-Newton covariance when the
values are the refinement's (``AnalysisResult.refinement``), else the bootstrap draws
(``AnalysisResult.bootstrap``). Nothing here re-runs the analysis.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.ticker import LogLocator, MaxNLocator, ScalarFormatter

from ..errors import InputError
from ..analyze.held_out import held_out_cells, held_out_notes
from ..progress import Progress, report
from ._common import TEST_COLOURS, ensure_dir, esc, html_page, html_table, new_figure, plt, save_figure, write_page
from .wording import gain_unit, uncertainty_sentence

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from ..analyze import AnalysisResult
    from ..mrft.identify import ParameterEstimate
    from ..segment import MrftTest

_TWO_PI = 2.0 * math.pi

__all__ = ["plot_timeseries", "plot_manifolds", "plot_spread", "plot_cycles", "posterior_draws", "plot_fit",
           "plot_uncertainty", "write_analysis_report"]

#: the figures' output unit, scale from the output's unit and axis name, by loop (attitude drawn in deg;
#: the tables keep the output's own unit, as the CLI and the JSON)
_UNITS = {"altitude": ("m", 1.0, "altitude"), "x": ("m", 1.0, "x"), "y": ("m", 1.0, "y"),
          "roll": ("deg", 180.0 / math.pi, "roll"), "pitch": ("deg", 180.0 / math.pi, "pitch")}


def _units(result):
    """(unit, scale, axis name) of the output as drawn: a vehicle loop's, or a process plant's own units."""
    if result.kind == "family":
        return "output units", 1.0, "output"
    return _UNITS.get(result.loop, ("output units", 1.0, "output"))


def _colour(i: int) -> str:
    return TEST_COLOURS[i % len(TEST_COLOURS)]


def _group_colours(result) -> dict:
    """test index -> colour: one colour per beta (tests repeated at the same beta share it)."""
    from ..analyze.screen import group_betas

    tests = list(result.segmented) + list(result.rejected)
    out = {t.index: "0.6" for t in tests}
    finite = [t for t in tests if np.isfinite(t.beta_nominal if t.beta_nominal is not None else t.beta_effective)]
    for g, members in enumerate(group_betas(finite)):
        out.update({finite[i].index: _colour(g) for i in members})
    return out


def _label(t) -> str:
    nom = f"beta {t.beta_nominal:+.2f}, " if t.beta_nominal is not None else ""
    return f"test {t.index + 1}: {nom}eff {t.beta_effective:+.3f}"


def _output_relative(result):
    """Output relative to the setpoint when logged (else raw) as arrays (t, y), display units."""
    unit, scale, _ = _units(result)
    fl = result.flight
    t = fl.output.t
    y = fl.output.values
    rel = False
    if fl.setpoint is not None and len(fl.setpoint):
        y = y - np.interp(t, fl.setpoint.t, fl.setpoint.values)
        rel = True
    return t, y * scale, rel


def _mark_tests(ax_c: Axes, ax_y: Axes, result: AnalysisResult, colours: dict[int, Any], T0: float) -> None:
    """Each test shaded, its stable cycles as bars, its label; a beta legend when there are many."""
    used_tests = result.segmented
    tests = list(used_tests) + list(result.rejected)
    many = len(tests) > 4  # long labels would overlap: numbers on the plot, betas in a legend
    seen: set[Any] = set()
    for t in tests:
        used = t in used_tests
        col = colours[t.index] if used else "0.6"
        for ax in (ax_c, ax_y):
            ax.axvspan(t.t_start - T0, t.t_end - T0, color=col, alpha=0.10, lw=0)
            for cyc in t.stable:
                ax.axvspan(cyc.t_start - T0, cyc.t_end - T0, ymin=0.0, ymax=0.04, color=col, alpha=0.9, lw=0)
        text = str(t.index + 1) if many else (_label(t) if used else f"test {t.index + 1}: left out")
        ax_c.text(0.5 * (t.t_start + t.t_end) - T0, 1.0, text,
                  transform=ax_c.get_xaxis_transform(), ha="center", va="bottom", fontsize=8, color=col)
        if many and used and col not in seen:
            seen.add(col)
            nom = t.beta_nominal if t.beta_nominal is not None else t.beta_effective
            ax_y.plot([], [], lw=6, alpha=0.5, color=col, label=f"beta {nom:+.2f}")
    if many:
        ax_y.legend(loc="lower right", fontsize=8, ncol=len(seen) or 1, framealpha=0.9)


def _output_limits(ax_y: Axes, result: AnalysisResult, ty: np.ndarray, y: np.ndarray, scale: float, T0: float) -> None:
    """Output limits from the tests and the transient after each (the hold controller's return to the
    setpoint); take-off and landing would squash the oscillations otherwise."""
    tests = result.segmented
    amp = max(t.amplitude_mean for t in tests) * scale
    after = {t.index: max(3.0, 3.0 / t.frequency_hz_mean) if t.n_stable else 3.0 for t in tests}
    inside = [(ty >= t.t_start - T0) & (ty <= t.t_end - T0 + after[t.index]) for t in tests]
    lo = min(np.min(y[m]) for m in inside if m.any())
    hi = max(np.max(y[m]) for m in inside if m.any())
    pad = 0.6 * amp
    ax_y.set_ylim(lo - pad, hi + pad)


def _zoom(ax: Axes, t: MrftTest, ty: np.ndarray, y: np.ndarray, colour: Any, result: AnalysisResult, rel: bool,
          T0: float, first: bool) -> None:
    """Two stable cycles of a test from the middle: samples, fitted extrema, output at the switches."""
    unit, scale, name = _units(result)
    st = t.stable
    mid = len(st) // 2
    sel = st[max(mid - 1, 0): mid + 1]
    # zoom axis: seconds from the log start, like the overview (offsets the reader can match)
    t0, t1 = sel[0].t_start - 0.1 * sel[0].period - T0, sel[-1].t_end + 0.1 * sel[-1].period - T0
    m = (ty >= t0) & (ty <= t1)
    ax.plot(ty[m], y[m], ".", ms=2, color="0.45", label="measured")
    for cyc in sel:
        centre = cyc.centre * t.loop_sign * scale
        ax.plot(cyc.t_max - T0, cyc.y_max * t.loop_sign * scale, "v", color=colour, ms=6)
        ax.plot(cyc.t_min - T0, cyc.y_min * t.loop_sign * scale, "^", color=colour, ms=6)
        for ts, ys in ((cyc.t_switch, cyc.y_switch_down), (cyc.t_end, cyc.y_switch_up)):
            ax.axvline(ts - T0, color=colour, lw=0.8, ls="--")
            ax.plot(ts - T0, ys * t.loop_sign * scale, "o", color=colour, ms=5, mfc="white")
        ax.axhline(centre, color="0.6", lw=0.6)
    ax.set_title(f"test {t.index + 1}: {t.frequency_hz_mean:.3f} Hz, a = {t.amplitude_mean * scale:.3g} {unit}",
                 fontsize=9)
    ax.set_xlim(t0, t1)
    ticks = ax.xaxis.get_major_formatter()
    if isinstance(ticks, ScalarFormatter):  # the default; offsets like +1.7e9 are what the axis must not show
        ticks.set_useOffset(False)
    ax.set_xlabel("time from log start [s]")
    if first:
        ax.set_ylabel(f"{name} {'- setpoint ' if rel else ''}[{unit}]")
        ax.plot([], [], "v", color="0.3", label="fitted extrema")
        ax.plot([], [], "o", color="0.3", mfc="white", label="output at switch")
        ax.legend(loc="best", fontsize=7, framealpha=0.8)


def plot_timeseries(result: AnalysisResult) -> Figure:
    """Command and output over the whole log with the tests and their stable cycles marked."""
    unit, scale, name = _units(result)
    fl = result.flight
    if fl is None:
        raise InputError("the analysis carries no flight signals to plot")
    T0 = result.t0  # every time axis is seconds from the log start (logs carry epoch times)
    segmented = result.segmented
    n_zoom = min(len(segmented), 4)
    fig = plt.figure(figsize=(11, 6.2 + (2.6 if n_zoom else 0)), layout="constrained")
    # command and output share the time axis and sit close; the zooms get their own row below
    outer = fig.add_gridspec(2 if n_zoom else 1, 1, height_ratios=[2.3, 1.2][: 2 if n_zoom else 1])
    top = outer[0].subgridspec(2, 1, height_ratios=[1, 1.3], hspace=0.0)
    ax_c = fig.add_subplot(top[0])
    ax_y = fig.add_subplot(top[1], sharex=ax_c)
    ty, y, rel = _output_relative(result)
    ty = ty - T0
    ax_c.plot(fl.command.t - T0, fl.command.values, lw=0.6, color="0.25")
    ax_y.plot(ty, y, lw=0.6, color="0.25")
    colours = _group_colours(result)
    _mark_tests(ax_c, ax_y, result, colours, T0)
    ax_c.set_ylabel("command [cmd units]")
    ax_y.set_ylabel(f"{name} {'- setpoint ' if rel else ''}[{unit}]")
    ax_y.set_xlabel("time from log start [s]")
    ax_c.set_title(f"{Path(result.path).name}: {result.loop} loop - relay tests (shaded) and stable cycles (bars)",
                   pad=16)
    if segmented:
        _output_limits(ax_y, result, ty, y, scale, T0)
    plt.setp(ax_c.get_xticklabels(), visible=False)
    if n_zoom:
        zooms = outer[1].subgridspec(1, n_zoom)
        for k, t in enumerate(segmented[:n_zoom]):
            _zoom(fig.add_subplot(zooms[0, k]), t, ty, y, colours[t.index], result, rel, T0, k == 0)
    return fig


def plot_manifolds(result):
    """The paper's Fig. 5: UFM slices tau(Td) at the known Tp, their intersection and the spread."""
    from ..mrft.consensus import phase_tau
    from ..mrft.identify import ufm_slice

    fig, ax = new_figure(width=8.5, height=5.6)
    Td_hat, tau_hat = result.model.Td, result.model.tau
    cTd = np.asarray(result.combinations.get("Td", []), float)
    ctau = np.asarray(result.combinations.get("tau", []), float)
    ok = np.isfinite(cTd) & np.isfinite(ctau)
    # x range: the estimate's interval and most of the combinations, at least a factor 3 each side
    lo_x = Td_hat / 3.0
    hi_x = Td_hat * 3.0
    if ok.sum() > 4:
        p = np.percentile(cTd[ok], [5, 95])
        lo_x, hi_x = min(lo_x, p[0] / 1.3), max(hi_x, p[1] * 1.3)
    if math.isfinite(result.Td.ci95_low):
        lo_x, hi_x = min(lo_x, result.Td.ci95_low / 1.3), max(hi_x, result.Td.ci95_high * 1.3)
    Td = np.geomspace(lo_x, hi_x, 300)
    colours = _group_colours(result)
    many = len(result.tests) > 4
    seen: set = set()
    constraints = result.constraints
    show_phase = "phase" in constraints.get("used", []) and not many
    phase_labelled = False
    for t in result.tests:
        try:
            tau = ufm_slice(result.Tp, t.beta_effective, t.frequency_hz_mean, Td) * 1e3
        except Exception:  # noqa: BLE001 - a curve that cannot be drawn is left out of the figure
            continue
        col = colours[t.index]
        if many:
            n_g = sum(colours[u.index] == col for u in result.tests)
            nom = t.beta_nominal if t.beta_nominal is not None else t.beta_effective
            label = None if col in seen else f"beta {nom:+.2f}: {n_g} tests"
            seen.add(col)
            ax.plot(Td, tau, color=col, lw=1.0, alpha=0.7, label=label)
        else:
            ax.plot(Td, tau, color=col, lw=2,
                    label=f"test {t.index + 1}: beta {t.beta_effective:+.3f}, {t.frequency_hz_mean:.4f} Hz")
        if show_phase:
            # Beyond the paper: the test's phase curve (arg of its fundamental harmonic), dashed
            ph = np.array([c.phase_h1 for c in t.stable], float)
            if np.isfinite(ph).sum() >= 2:
                tph = phase_tau(result.Tp, _TWO_PI * t.frequency_hz_mean, float(np.nanmean(ph)), Td) * 1e3
                label = None
                if not phase_labelled:
                    label = "phase of each test's fundamental (dashed, same colour)"
                    phase_labelled = True
                ax.plot(Td, tph, color=col, lw=1.2, ls="--", alpha=0.9, label=label)
    if ok.any():
        ax.plot(cTd[ok], ctau[ok] * 1e3, ".", color="0.35", ms=3, alpha=0.5,
                label=f"per combination of cycles ({int(ok.sum())})")
    xerr = None
    yerr = None
    if math.isfinite(result.Td.ci95_low):
        # a one-sided Td bound (NaN upper end) draws the lower error bar only
        xerr = [[Td_hat - result.Td.ci95_low], [result.Td.ci95_high - Td_hat if math.isfinite(result.Td.ci95_high) else 0.0]]
        yerr = [[(tau_hat - result.tau.ci95_low) * 1e3], [(result.tau.ci95_high - tau_hat) * 1e3]]
    ax.errorbar([Td_hat], [tau_hat * 1e3], xerr=xerr, yerr=yerr, fmt="*", color="k", ms=14, mfc="gold",
                capsize=4, zorder=5, label=f"estimate: Td {Td_hat:.3g} s, tau {tau_hat * 1e3:.4g} ms (95 % interval)")
    paper = constraints.get("paper_estimate")
    if paper and paper.get("Td") is not None:
        ax.plot([paper["Td"]], [paper["tau"] * 1e3], "o", color="k", mfc="white", ms=8, zorder=4,
                label=f"UFM slices alone (paper): Td {paper['Td']:.3g} s, tau {paper['tau'] * 1e3:.4g} ms")
    ax.set_xscale("log")
    ax.set_xlim(lo_x, hi_x)
    fmt = ScalarFormatter()
    fmt.set_scientific(False)
    ax.xaxis.set_major_formatter(fmt)
    ax.xaxis.set_minor_locator(LogLocator(subs=(2, 3, 5)))
    ax.xaxis.set_minor_formatter(fmt)
    # y range: around the estimate, wide enough for the combinations and the curves' crossing
    span = 4 * max((result.tau.ci95_high - result.tau.ci95_low) * 1e3 if math.isfinite(result.tau.ci95_low) else 0,
                   0.15 * tau_hat * 1e3, 1.0)
    if ok.sum() > 4:
        p = np.percentile(ctau[ok] * 1e3, [2, 98])
        ylo, yhi = min(tau_hat * 1e3 - span, p[0] - 0.2 * span), max(tau_hat * 1e3 + span, p[1] + 0.2 * span)
    else:
        ylo, yhi = tau_hat * 1e3 - span, tau_hat * 1e3 + span
    ax.set_ylim(max(ylo, 0.0), yhi)
    ax.set_xlabel("drag time constant Td [s] (log scale)")
    ax.set_ylabel("delay tau [ms]")
    ax.set_title(f"UFM slices at Tp = {result.Tp:g} s, scaled to each test's frequency (paper Fig. 5)"
                 + ("\nwith the weighted phase constraints (dashed)" if show_phase else ""), fontsize=10)
    ax.legend(loc="best", fontsize=8, framealpha=0.9)
    return fig


def plot_spread(result):
    """Spread of Td, tau and K: per combination (Table III) and bootstrap of the estimate."""
    fig, axes = new_figure(1, 3, width=11, height=3.6)
    specs = (("Td", "Td [s]", 1.0, result.Td), ("tau", "tau [ms]", 1e3, result.tau), ("K", "K", 1.0, result.K))
    for ax, (key, label, scale, est) in zip(axes, specs):
        comb = np.asarray(result.combinations.get(key, []), float) * scale
        boot = np.asarray(result.bootstrap.get(key, []), float) * scale
        data, names = [], []
        for arr, nm in ((comb, "per\ncombination"), (boot, "bootstrap\n(estimate)")):
            arr = arr[np.isfinite(arr)]
            if arr.size:
                data.append(arr)
                names.append(nm)
        if data:
            ax.boxplot(data, widths=0.5, showfliers=True,
                       flierprops={"marker": ".", "markersize": 2, "alpha": 0.4})
            ax.set_xticks(range(1, len(names) + 1))
            ax.set_xticklabels(names, fontsize=8)
        if math.isfinite(est.value):
            ax.axhline(est.value * scale, color="k", lw=1.2, label=f"estimate {est.value * scale:.4g}")
        if math.isfinite(est.ci95_low) and not math.isfinite(est.ci95_high):  # one-sided bound
            ax.axhspan(est.ci95_low * scale, ax.get_ylim()[1], color="gold", alpha=0.3,
                       label=f"95 %: > {est.ci95_low * scale:.4g} (not bounded above)")
        elif math.isfinite(est.ci95_low):
            ax.axhspan(est.ci95_low * scale, est.ci95_high * scale, color="gold", alpha=0.3,
                       label=f"95 %: {est.ci95_low * scale:.4g}-{est.ci95_high * scale:.4g}")
        ax.set_ylabel(label)
        ax.set_title(label.split(" ")[0])
        ax.legend(loc="upper right", fontsize=7, framealpha=0.9)
    fig.suptitle("Parameter spread: one cycle per test per combination (paper Table III) vs. bootstrap of the "
                 "whole-log estimate", fontsize=10)
    return fig


def plot_cycles(result):
    """Per test: each cycle's period and amplitude with the stable-cycle tolerance bands."""
    tests = (list(result.segmented) + list(result.rejected))[:6]  # the first six; the HTML table lists all
    unit, scale, _ = _units(result)
    colours = _group_colours(result)
    fig, axes = new_figure(2, max(len(tests), 1), width=min(3.6 * max(len(tests), 1), 14), height=5.0,
                           squeeze=False)
    for k, t in enumerate(tests):
        P = np.array([c.period for c in t.cycles])
        A = np.array([c.amplitude for c in t.cycles]) * scale
        st = np.array([c.stable for c in t.cycles], bool)
        i = np.arange(1, P.size + 1)
        for row, (vals, med, tol, lab) in enumerate(
                ((P, t.period_median, t.period_tolerance, "period [s]"),
                 (A, t.amplitude_median * scale, t.amplitude_tolerance * scale, f"amplitude [{unit}]"))):
            ax = axes[row, k]
            if math.isfinite(med):
                ax.axhspan(med - tol, med + tol, color=colours[t.index], alpha=0.15, label="tolerance")
                ax.axhline(med, color=colours[t.index], lw=0.8)
            if math.isfinite(med):
                # cycles far off (start-up chatter) are drawn at the edge so they stay visible
                lo, hi = med - 3 * tol, med + 3 * tol
                ax.set_ylim(lo, hi)
                vals = np.clip(np.nan_to_num(vals, nan=lo), lo + 0.03 * (hi - lo), hi - 0.03 * (hi - lo))
            ax.plot(i[st], vals[st], "o", color=colours[t.index], ms=4, label="stable")
            ax.plot(i[~st], vals[~st], "x", color="0.4", ms=4, label="left out")
            ax.set_ylabel(lab)
            if row == 0:
                ax.set_title(_label(t), fontsize=9)
                if k == 0:
                    ax.legend(fontsize=7, loc="lower right")
            else:
                ax.set_xlabel("cycle")
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    fig.suptitle("Stable-cycle criterion: median +/- tolerance (MAD-based) per test", fontsize=10)
    return fig


#: draws of the refinement's Gaussian posterior (and of a family's or the cascade's estimates)
_N_DRAWS = 400
#: chi-square quantile of 2 degrees of freedom at 95 %: the ellipse holding 95 % of a Gaussian pair
_CHI2_2_95 = 5.991


def posterior_draws(result: AnalysisResult) -> tuple[np.ndarray, str]:
    """Draws of (Td [s], tau [s], K), shape (n, 3), and their source: the posterior tune designs over
    (:func:`mrftcli.tune.analysis.posterior_from_analysis`: the waveform refinement's covariance when the
    values are the refinement's, else the bootstrap draws); empty (0, 3) when the result carries neither
    (a record read from JSON keeps no draws).
    """
    from ..tune.analysis import posterior_from_analysis

    post = posterior_from_analysis(result, n=_N_DRAWS)  # a fixed seed: the same report for the same result
    return np.column_stack([post.Td, post.tau, post.K]), post.source


def plot_fit(result: AnalysisResult) -> Figure:
    """Per test (up to four): measured and model output [output units] and their residual against time [s]."""
    from ..analyze.overlay import analysis_predictions

    tests = list(result.segmented)[:4]
    fig, axes = new_figure(2, max(len(tests), 1), width=min(4.2 * max(len(tests), 1), 14), height=5.2,
                           squeeze=False, sharex="col", gridspec_kw={"height_ratios": [2, 1]})
    if result.flight is None or not tests:
        axes[0, 0].text(0.5, 0.5, "no flight signals in this result", ha="center", transform=axes[0, 0].transAxes)
        return fig
    preds = analysis_predictions(result)
    unit = result.output_unit
    noise = result.refinement.noise_std if result.refinement is not None else float("nan")
    for k, t in enumerate(tests):
        p = preds.get(t.index)
        top, bottom = axes[0, k], axes[1, k]
        top.set_title(f"test {t.index + 1}: beta {t.beta_effective:+.3f}", fontsize=9)
        bottom.set_xlabel("time [s from the log start]")
        if p is None:
            continue
        tr = np.asarray(p.t, float) - result.t0
        top.plot(tr, p.y + p.residual, color="0.3", lw=0.9, label="measured")
        top.plot(tr, p.y, color=_colour(k), lw=1.0, ls="--", label="model")
        bottom.plot(tr, p.residual, color="0.3", lw=0.6)
        if math.isfinite(noise):
            for s in (-2 * noise, 2 * noise):
                bottom.axhline(s, color="C3", lw=0.8, ls=":")
        bottom.set_title(f"residual RMS {p.rms:.3g} {unit}", fontsize=8)
        if k == 0:
            top.set_ylabel(f"output [{unit}]")
            bottom.set_ylabel(f"residual [{unit}]")
            top.legend(fontsize=7, loc="upper right")
    fig.suptitle("Model output (driven by the recorded relay command) over the measured output"
                 + ("; dotted: +/- 2 sensor-noise std" if math.isfinite(noise) else ""), fontsize=10)
    return fig


def _drawn_models(result: AnalysisResult, draws: np.ndarray) -> tuple[list[Any], str]:
    """The plants the band is drawn over and their source: eq. (2)'s posterior draws (Td, tau, K); a
    family's or the cascade's draws over its estimates' intervals (tune's, :mod:`mrftcli.tune.grid`)."""
    if result.kind == "soiptd":
        out = []
        for td, tau, k in draws:
            try:
                out.append(result.model.with_parameters(Td=float(td), tau=float(tau), K=float(k)))
            except InputError:  # a draw outside the model's valid set
                continue
        return out, ""
    from ..tune.grid import model_draws, outer_draws

    try:
        if result.kind == "cascade":
            return outer_draws(result.model, list(result.parameters.values()), _N_DRAWS), "the estimates' std and the inner model's"
        return model_draws(result.model, list(result.parameters.values()), _N_DRAWS)[0], "the estimates' intervals"
    except InputError:  # an undetermined parameter with an open interval: no band
        return [], ""


def _bode_band(result: AnalysisResult, models: list[Any], omega: np.ndarray) -> tuple[np.ndarray, ...]:
    """Nominal magnitude [dB] and phase [deg] of the identified plant and the drawn plants' 2.5-97.5 % band."""
    g0 = result.model.frequency_response(omega)
    mag0, ph0 = 20 * np.log10(np.abs(g0)), np.degrees(np.unwrap(np.angle(g0)))
    mags: list[np.ndarray]
    phs: list[np.ndarray]
    mags, phs = [], []
    for model in models:
        g = model.frequency_response(omega)
        mags.append(20 * np.log10(np.abs(g)))
        ph = np.degrees(np.unwrap(np.angle(g)))
        phs.append(ph - 360.0 * np.round((ph[0] - ph0[0]) / 360.0))  # the same branch as the nominal
    if len(mags) < 10:
        return mag0, ph0, mag0, mag0, ph0, ph0
    m_lo, m_hi = np.percentile(mags, [2.5, 97.5], axis=0)
    p_lo, p_hi = np.percentile(phs, [2.5, 97.5], axis=0)
    return mag0, ph0, m_lo, m_hi, p_lo, p_hi


def _ellipse(ax: Axes, result: AnalysisResult, draws: np.ndarray) -> None:
    """The Td-tau draws and their 95 % ellipse, with the correlation coefficient in the title."""
    ax.set_xlabel("Td [s]")
    ax.set_ylabel("tau [ms]")
    if draws.shape[0] < 10:
        ax.set_title("Td-tau: no posterior draws in this result", fontsize=9)
        return
    xy = np.column_stack([draws[:, 0], draws[:, 1] * 1e3])
    ax.plot(xy[:, 0], xy[:, 1], ".", color="0.6", ms=2, label="posterior draws")
    mean, cov = xy.mean(axis=0), np.cov(xy.T)
    vals, vecs = np.linalg.eigh(cov)
    a = np.linspace(0.0, 2.0 * math.pi, 200)
    circle = np.column_stack([np.cos(a), np.sin(a)]) * np.sqrt(np.maximum(vals, 0.0) * _CHI2_2_95)
    ring = mean + circle @ vecs.T
    ax.plot(ring[:, 0], ring[:, 1], color="C0", lw=1.2, label="95 % ellipse")
    ax.plot([result.Td.value], [result.tau.value * 1e3], "k+", ms=10, label="estimate")
    rho = cov[0, 1] / math.sqrt(cov[0, 0] * cov[1, 1]) if cov[0, 0] > 0 and cov[1, 1] > 0 else float("nan")
    ax.set_title(f"Td-tau correlation rho = {rho:+.2f}", fontsize=9)
    ax.legend(fontsize=7, loc="best")


def _points(ax_m: Axes, ax_p: Axes, result: AnalysisResult, omega: np.ndarray, ph0: np.ndarray) -> None:
    """A process family's measured response points (each harmonic of each test, 95 % error bars) on the Bode axes."""
    points = [p for p in getattr(result.identification, "points", ()) if p.harmonic > 0]
    if not points:
        return
    w = np.array([p.omega for p in points])
    mag = 20 * np.log10([p.gain for p in points])
    se_db = 20 / math.log(10) * np.array([p.se_log_gain for p in points])
    ph = np.degrees([p.phase for p in points])
    # the measured phase on the drawn curve's branch (the model's phase at the same frequency)
    ph = ph - 360.0 * np.round((ph - np.interp(w, omega, ph0)) / 360.0)
    se_ph = np.degrees([p.se_phase for p in points])
    ax_m.errorbar(w, mag, yerr=1.96 * se_db, fmt="o", color="k", ms=3, capsize=2, label="measured points (95 %)")
    ax_p.errorbar(w, ph, yerr=1.96 * se_ph, fmt="o", color="k", ms=3, capsize=2)


def plot_uncertainty(result: AnalysisResult) -> Figure:
    """Bode plot of the identified plant with its 95 % band (tests' frequencies marked) and the Td-tau ellipse."""
    eq2 = result.kind == "soiptd"
    draws, source = posterior_draws(result) if eq2 else (np.empty((0, 3)), "none kept")
    freqs = [2 * math.pi * t.frequency_hz_mean for t in result.segmented if math.isfinite(t.frequency_hz_mean)]
    centre = float(np.median(freqs)) if freqs else 10.0
    omega = np.logspace(math.log10(centre / 30), math.log10(centre * 10), 300)
    models, drawn = _drawn_models(result, draws)
    mag0, ph0, m_lo, m_hi, p_lo, p_hi = _bode_band(result, models, omega)
    at = [int(np.argmin(np.abs(omega - w))) for w in freqs]  # the band where the tests measured the plant
    width = (f"; 95 % band at the tests' frequencies: {max(m_hi[at] - m_lo[at]):.2g} dB, "
             f"{max(p_hi[at] - p_lo[at]):.2g} deg wide" if at else "")
    fig, axes = new_figure(1, 3 if eq2 else 2, width=14 if eq2 else 10, height=4.4)
    ax_m, ax_p = axes[:2]
    for ax, nom, lo, hi, lab in ((ax_m, mag0, m_lo, m_hi, f"|G| [dB re 1 {result.output_unit} per command unit]"),
                                 (ax_p, ph0, p_lo, p_hi, "phase [deg]")):
        ax.fill_between(omega, lo, hi, color="C0", alpha=0.25, lw=0, label="95 % band")
        ax.plot(omega, nom, color="C0", lw=1.2, label="identified")
        for k, w in enumerate(freqs):
            ax.axvline(w, color=_colour(k), lw=0.8, ls="--",
                       label="test frequencies" if k == 0 else None)
        ax.set_xscale("log")
        ax.set_xlabel("omega [rad/s]")
        ax.set_ylabel(lab)
    _points(ax_m, ax_p, result, omega, ph0)
    ax_m.legend(fontsize=7, loc="lower left")
    if eq2:
        _ellipse(axes[2], result, draws)
    if eq2:
        title = f"Identified plant G(s) with its uncertainty (posterior: {source}, {draws.shape[0]} draws{width})"
    else:
        band = (f"95 % band over {len(models)} draws of {drawn}\n{width.lstrip('; ')}" if models
                else "no band (an undetermined parameter's interval is open)\n")
        title = (f"Identified plant G(s) ({result.model.family}): {band}"
                 + ("; dots: the response points it was fitted to" if result.kind == "family" else ""))
    fig.suptitle(title, fontsize=10)
    return fig


def _estimate_row(e: ParameterEstimate, label: str, s: float, u: str) -> list[str]:
    """One parameter's row: estimate, std and 95 % interval, scaled by ``s`` into the unit ``u``."""

    def f(v: float | None) -> str:
        return "-" if v is None or not math.isfinite(v) else f"{v * s:.4g}"

    hi = e.ci95_high
    ci = (f"> {f(e.ci95_low)} (not bounded above)" if hi is None or not math.isfinite(hi)
          else f"{f(e.ci95_low)} - {f(hi)}")
    return [label, f(e.value), f(e.std), ci, u]


def _estimate_notes(result: AnalysisResult) -> list[str]:
    """The Table III spread and the weighted estimate against the paper's, as paragraphs."""
    body = []
    comb = result.combination_stats()
    if comb["n"] and comb["Td"]["mean"] is not None:
        body.append(
            f"<p>Per combination of cycles ({comb['n']} combinations, as the paper's Table III): "
            f"Td {comb['Td']['mean']:.4g} &plusmn; {comb['Td']['std'] or 0:.3g} s, "
            f"tau {comb['tau']['mean'] * 1e3:.4g} &plusmn; {(comb['tau']['std'] or 0) * 1e3:.3g} ms, "
            f"K {comb['K']['mean']:.4g} &plusmn; {comb['K']['std'] or 0:.3g} {esc(gain_unit(result.loop))}.</p>")
    ref = result.refinement
    refined = ref is not None and ref.accepted
    if ref is not None and refined:
        body.append(f"<p>The values above are the waveform refinement's (output error over every stable cycle, "
                    f"residual {ref.residual_ratio:.2f}x the sensor noise), started from the MRFT estimate below.</p>")
    mrft_interval = any("MRFT interval" in note for note in result.notes)
    sentence = uncertainty_sentence(refined, mrft_interval)
    body.append(f"<p><b>{esc(sentence[0].upper() + sentence[1:])}.</b></p>")
    body += [f"<p class='muted'>Note: {esc(note)}</p>" for note in result.notes]
    cons = result.constraints
    paper = cons.get("paper_estimate")
    if paper and paper.get("tau") is not None:
        pv = cons.get("p_value")
        head = "MRFT estimate (the refinement's start)" if refined else "Estimate"
        body.append(
            f"<p>{head}: {esc(result.estimate_method)} (chi-square {cons['chi2']:.2f} for {cons['dof']} "
            f"degrees of freedom{'' if pv is None else f', p = {pv:.2g}'}). The UFM slices alone (the paper's "
            f"method) give Td {paper['Td']:.4g} s, tau {paper['tau'] * 1e3:.4g} ms.</p>")
    return body


#: the figures of every analysis, and eq. (2)'s own (file, function, title)
_FIGURES = (("timeseries.png", plot_timeseries, "Flight and detected relay tests"),
            ("manifolds.png", plot_manifolds, "Manifold intersection (paper Fig. 5)"),
            ("spread.png", plot_spread, "Parameter spread"),
            ("cycles.png", plot_cycles, "Cycles and the stable-cycle criterion"),
            ("fit.png", plot_fit, "Model output over the measured output, and the residual"),
            ("uncertainty.png", plot_uncertainty, "Bode plot of the identified plant with its 95 % band"))
_EQ2_ONLY = ("manifolds.png", "spread.png")


def _header(result: AnalysisResult, T0: float) -> str:
    """The page's first line: the log, the loop, the model and the time base."""
    from ..analyze import describe_t0

    when = f"times are seconds from the log start ({esc(describe_t0(T0))})"
    if result.kind == "soiptd":
        model = (f"Tp = {result.Tp:g} s (known) - model G(s) = K Td e<sup>-tau s</sup> / (s (Tp s+1)(Td s+1))")
    elif result.kind == "cascade":
        model = f"through the closed inner loop: G(s) = {esc(result.model.structure)}"
    else:
        m = result.model
        model = f"model {esc(m.family)}: G(s) = {esc(getattr(m, 'transfer_function', m.structure))}"
    return f"<p class='muted'>{esc(result.path)} - loop <b>{esc(result.loop)}</b> - {model} - {when}</p>"


def _parameter_rows(result: AnalysisResult) -> list[list[str]]:
    """Every family's parameters by name in their units (tau in ms; eq. (2)'s K in the loop's gain unit), known
    ones said so."""
    rows = []
    for name, e in result.parameters.items():
        s, u = (1e3, "ms") if e.unit == "s" and name == "tau" else (1.0, e.unit)
        if name == "K" and result.kind == "soiptd":
            u = gain_unit(result.loop)
        row = _estimate_row(e, name, s, u)
        if e.known:
            row[2:4] = ["", "known"]
        elif not e.determined:
            row[3] += " (not determined)"
        rows.append(row)
    return rows


def _test_rows(result: AnalysisResult, T0: float) -> tuple[list[str], list[list[Any]]]:
    """The tests table (header, rows): a process family's relays and held-out predictions; eq. (2)'s and the
    cascade's betas and cycles."""
    unit = result.output_unit
    held_head = ["held-out frequency [Hz] ± std (error/std)", f"held-out amplitude [{unit}] ± std (error/std)"]
    if result.kind == "family":
        rows: list[list[Any]] = [[t.index + 1, f"{t.t_start - T0:.1f} - {t.t_end - T0:.1f}", t.describe_relay(),
                                  f"{t.frequency_hz:.4f}", f"{t.amplitude:.4g}", f"{t.n_stable} / {t.n_cycles}",
                                  f"{t.rate_hz:.1f}", *held_out_cells(t.held_out), "used"] for t in result.tests]
        rows += [[i + 1, f"{a - T0:.1f} - {b - T0:.1f}", "", "-", "-", "", "", "-", "-", f"left out: {why}"]
                 for i, a, b, why in result.rejected_spans]
        return (["test", "t [s from log start]", "relay", "frequency [Hz]", f"amplitude [{unit}]", "stable / cycles",
                 "rate [Hz]", *held_head, ""], rows)
    held = {t.index: result.held_out_of(k) for k, t in enumerate(result.tests)}
    rows = []
    for t in list(result.tests) + list(result.rejected):
        rows.append([t.index + 1, f"{t.t_start - T0:.1f} - {t.t_end - T0:.1f}",
                     "-" if t.beta_nominal is None else f"{t.beta_nominal:+.3f}",
                     f"{t.beta_effective:+.4f}" if math.isfinite(t.beta_effective) else "-",
                     f"{t.h:.4g}", f"{t.bias:.4g}",
                     f"{t.frequency_hz_mean:.4f}" if t.n_stable else "-",
                     f"{t.amplitude_mean:.4g}" if t.n_stable else "-",
                     f"{t.n_stable} / {len(t.cycles)}", f"{t.rate_hz:.1f}",
                     *held_out_cells(held.get(t.index)), "used" if t in result.tests else "left out"])
    return (["test", "t [s from log start]", "beta nominal", "beta effective", "h", "bias", "frequency [Hz]",
             f"amplitude [{unit}]", "stable / cycles", "rate [Hz]", *held_head, ""], rows)


def _notes(result: AnalysisResult) -> list[str]:
    """Eq. (2)'s estimate notes; the cascade's assumptions and any other family's notes and advice."""
    if result.kind == "soiptd":
        return _estimate_notes(result)
    body = [f"<p class='muted'>Assumption: {esc(a)}</p>" for a in result.assumptions]
    body += [f"<p class='muted'>Note: {esc(n)}</p>" for n in result.notes]
    advice = getattr(result.identification, "advice", "")
    if advice:
        body.append(f"<p class='warn'>Not determined: {esc(advice)}</p>")
    return body


def write_analysis_report(result, out_dir: str | Path, links: Sequence[tuple[str, str]] = (),
                          progress: Progress | None = None, extra: Sequence[str] = ()) -> Path:
    """Write index.html and the PNG figures for one analysis of any family; returns the index path.

    ``links`` are (relative href, title) pairs of pages written beside it (e.g. the diagnosis);
    ``extra`` HTML blocks placed after the notes (e.g. the vehicle's gains of a cascade).
    ``progress(done, total, stage)`` is called before each figure (units: figures).
    """
    out = ensure_dir(out_dir)
    figures = [f for f in _FIGURES if result.kind == "soiptd" or f[0] not in _EQ2_ONLY]
    written = []
    for i, (name, fn, title) in enumerate(figures):
        report(progress, i, len(figures), name)
        save_figure(fn(result), out / name)
        written.append((name, title))
    T0 = result.t0
    body = [_header(result, T0), "<h2>Parameters</h2>",
            html_table(["parameter", "estimate", "std", "95 % interval", "unit"], _parameter_rows(result))]
    if links:
        body.insert(1, "<p>" + " - ".join(f"<a href='{esc(href)}'>{esc(title)}</a>" for href, title in links) + "</p>")
    body += [*_notes(result), *extra]
    header, rows = _test_rows(result, T0)
    body += ["<h2>Tests</h2>", html_table(header, rows)]
    held = [result.held_out_of(k) for k in range(len(result.tests))]
    model = "eq. (2)" if result.kind == "soiptd" else f"the {result.model.family} model"
    body += [f"<p class='muted'>{esc(n)} (held out: each test predicted by {esc(model)} from the other tests)</p>"
             for n in held_out_notes(held, [t.index + 1 for t in result.tests])]
    if result.warnings:
        body.append("<h2>Warnings</h2><ul>" + "".join(f"<li class='warn'>{esc(w)}</li>" for w in result.warnings)
                    + "</ul>")
    for name, title in written:
        body.append(f"<h2>{esc(title)}</h2><img src='{esc(name)}' alt='{esc(title)}'>")
    if result.kind == "soiptd":
        body.append("<p class='muted'>The effective beta is the switching level the relay actually achieved, "
                    "measured from the output at the switch instants; identification uses it (see "
                    "docs/usage-analyze.md).</p>")
    index = out / "index.html"
    write_page(index, html_page(f"MRFT analysis: {Path(result.path).name} ({result.loop})", "\n".join(body)))
    report(progress, len(figures), len(figures), "index.html")
    return index
