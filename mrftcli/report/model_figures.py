"""The identified model against the data and with its uncertainty, for the analysis report.

* :func:`plot_fit` - per test, the model's output (driven by the recorded relay command) over the
  measured output, and the residual below it with the sensor noise level.
* :func:`plot_uncertainty` - the Bode plot of the identified plant with its 95 % band, the tests'
  frequencies marked, and eq. (2)'s Td-tau correlation: the posterior draws with their 95 % ellipse
  (a process family: its measured response points with their standard errors on the Bode plot).

The posterior is the one the analysis keeps: the waveform refinement's Gauss-Newton covariance when the
values are the refinement's (``AnalysisResult.refinement``), else the bootstrap draws
(``AnalysisResult.bootstrap``). Nothing here re-runs the analysis.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InputError
from ._common import TEST_COLOURS, new_figure

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from ..analyze import AnalysisResult

__all__ = ["posterior_draws", "plot_fit", "plot_uncertainty"]

#: draws of the refinement's Gaussian posterior (a fixed seed: the same report for the same result)
_N_DRAWS = 400
#: chi-square quantile of 2 degrees of freedom at 95 %: the ellipse holding 95 % of a Gaussian pair
_CHI2_2_95 = 5.991


def posterior_draws(result: AnalysisResult) -> tuple[np.ndarray, str]:
    """Draws of (Td [s], tau [s], K) from the posterior the analysis keeps, shape (n, 3), and its name.

    The waveform refinement's covariance (in its (ln Td, tau, K) parametrisation) when the values are
    the refinement's; else the bootstrap draws. Empty (0, 3) when the result carries neither (a record
    read from JSON keeps no draws).
    """
    ref = result.refinement
    if ref is not None and ref.accepted:
        cov = np.asarray(ref.fit.covariance, float)[:3, :3]
        p = np.asarray(ref.fit.p, float)[:3]
        if cov.shape == (3, 3) and np.all(np.isfinite(cov)):
            rng = np.random.default_rng(0)
            z = rng.multivariate_normal(p, cov, size=_N_DRAWS, check_valid="ignore")
            # the fit's K may be of the opposite sign (a reversed loop): its model holds the signed K
            k_sign = math.copysign(1.0, ref.model.K) * math.copysign(1.0, p[2])
            draws = np.column_stack([np.exp(z[:, 0]), np.maximum(z[:, 1], 0.0), k_sign * z[:, 2]])
            return draws, "waveform refinement covariance"
    boot = [np.asarray(result.bootstrap.get(k, []), float) for k in ("Td", "tau", "K")]
    n = min(b.size for b in boot)
    draws = np.column_stack([b[:n] for b in boot]) if n else np.empty((0, 3))
    return draws[np.all(np.isfinite(draws), axis=1)], "bootstrap"


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
        top.plot(tr, p.y, color=TEST_COLOURS[k % len(TEST_COLOURS)], lw=1.0, ls="--", label="model")
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
            return outer_draws(result.model, result.parameters, _N_DRAWS), "the estimates' std and the inner model's"
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
            ax.axvline(w, color=TEST_COLOURS[k % len(TEST_COLOURS)], lw=0.8, ls="--",
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
