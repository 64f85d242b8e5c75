"""The ``diagnose --report DIR`` page (also written by ``analyze --diagnose --report DIR``), every family.

Eq. (2)'s page draws the figures below; a family's (:func:`_family_sections`) holds its checks per test, where
the residual sits and the library's rows, with :func:`plot_evidence`.

Figures (each returns a matplotlib Figure; :func:`write_diagnosis_report` saves them):

1. :func:`plot_located` - the output over the log, tests shaded, each cycle's waveform error of the
   linear model, and the located segments highlighted.
2. :func:`plot_overlay` - per test, held-out cycles: recording, linear model, augmented model.
3. :func:`plot_harmonics` - per test, the relative error of G(j k Omega) measured from the odd
   harmonics of output/command, linear model vs augmented model.
4. :func:`plot_evidence` - delta BIC of every candidate against the threshold, and the held-out
   NRMSE before/after.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..diagnose.physics import LIBRARY, unit_in_loop
from ..diagnose.records import DiagnosisFigures, DiagnosisResult
from ..errors import InputError
from ..io.logtypes import gain_unit
from ._common import TEST_COLOURS, ensure_dir, esc, html_page, html_table, new_figure, save_figure, write_page

__all__ = ["plot_located", "plot_overlay", "plot_harmonics", "plot_evidence", "write_diagnosis_report"]

_BASE_C = "#D55E00"
_AUG_C = "#009E73"
_REC_C = "#444444"


def _scale(result):
    if result.loop in ("roll", "pitch"):
        return 180.0 / math.pi, "deg"
    return 1.0, "m"


def _figures(result: DiagnosisResult) -> DiagnosisFigures:
    """The result's figures record (a result read back from JSON has none to draw)."""
    if result.figures is None:
        raise InputError("this diagnosis has no figures (it was read back from JSON); rerun mrft-ident diagnose "
                         "with --report")
    return result.figures


def plot_located(result):
    """Output over the log with tests shaded, per-cycle error of the linear model, located segments."""
    p = _figures(result)
    fl = p.flight
    s, unit = _scale(result)
    fig, (ax, ax2) = new_figure(2, 1, width=11, height=6, sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    t0 = result.t0  # times from the log start, as analyze shows them
    t = fl.output.t - t0
    ax.plot(t, fl.output.values * s, color=_REC_C, lw=0.6, label="recorded output")
    for i, test in enumerate(p.tests):
        c = TEST_COLOURS[i % len(TEST_COLOURS)]
        ax.axvspan(test.t_start - t0, test.t_end - t0, color=c, alpha=0.10)
        ax.text(test.t_start - t0, 1.0, f" test {test.index + 1}: beta {np.mean(test.beta):+.2f}, h {test.h:.3g}",
                transform=ax.get_xaxis_transform(), va="top", fontsize=8, color=c)
    segs = [loc for loc in result.located if loc.kind == "segment"]
    for k, loc in enumerate(segs):
        for a in (ax, ax2):
            a.axvspan(loc.t_start - t0, loc.t_end - t0, color="red", alpha=0.18, lw=0,
                      label="located segment" if (k == 0 and a is ax) else None)
    ax.set_ylabel(f"output [{unit}]")
    ax.set_title("Where the linear model disagrees with the recording")
    ax.legend(loc="lower right", fontsize=8)
    for i, ce in enumerate(p.cycle_errors):
        c = TEST_COLOURS[i % len(TEST_COLOURS)]
        ax2.plot(ce.t - t0, 100 * ce.nrmse, "o-", color=c, ms=3, lw=1)
    ax2.set_ylabel("cycle NRMSE [%]\n(linear model)")
    ax2.set_xlabel("time from the log start [s]")
    feats = [loc for loc in result.located if loc.kind == "feature"][:2]
    if feats:
        txt = "largest: " + "; ".join(f"test {f.test + 1} {f.what} (z = {f.z:+.1f})" for f in feats)
        ax2.set_title(txt, fontsize=9)
    return fig


def _model_cycle_wave(model, fit, i, test, t_ref, tt):
    ev = model.evaluate(fit.theta, i, t_ref, key=5000 + i)
    if ev is None:
        return None
    c = ev.cycle
    return fit.K * c.waveform(0, c.start[0] + tt, trend=False)


def plot_overlay(result, n_cycles: int = 3):
    """Per test: consecutive held-out cycles, recording vs linear model vs augmented model."""
    p = _figures(result)
    tests = p.tests
    aug = p.augmented()
    s, unit = _scale(result)
    fig, axes = new_figure(1, len(tests), width=4.2 * len(tests), height=3.8, squeeze=False)
    for i, (test, ax) in enumerate(zip(tests, axes[0])):
        tab = test.tab
        hold = np.flatnonzero(test.hold)
        if hold.size == 0:
            continue
        mid = hold[len(hold) // 2]
        sel = [j for j in range(mid, min(mid + 2 * n_cycles, len(tab))) if test.hold[j]][:n_cycles]
        t0 = tab.start[sel[0]]
        for j in sel:
            tt = np.linspace(0.0, tab.period[j], 200, endpoint=False)
            rec = tab.waveform(j, tab.start[j] + tt)
            ax.plot(tab.start[j] + tt - t0, rec * s, color=_REC_C, lw=2.2, alpha=0.45,
                    label="recording (noise removed)" if j == sel[0] else None)
            yb = _model_cycle_wave(p.base_model, p.base, i, test, tab.t_mid[j], tt)
            if yb is not None:
                ax.plot(tab.start[j] + tt - t0, yb * s, "--", color=_BASE_C, lw=1.4,
                        label="linear model" if j == sel[0] else None)
            if aug is not None:
                ya = _model_cycle_wave(aug.model, aug.fit, i, test, tab.t_mid[j], tt)
                if ya is not None:
                    ax.plot(tab.start[j] + tt - t0, ya * s, color=_AUG_C, lw=1.2,
                            label=f"with {aug.label}" if j == sel[0] else None)
            ax.axvline(tab.start[j] - t0, color="#999", lw=0.6)
            ax.axvline(tab.switch[j] - t0, color="#999", lw=0.6, ls=":")
        ax.set_title(f"test {test.index + 1}: beta {np.mean(test.beta):+.2f}, h {test.h:.3g}\n"
                     f"held-out cycles from t = {t0 - result.t0:.1f} s", fontsize=10)
        ax.set_xlabel("time from the first shown -h -> +h switch [s]")
        if i == 0:
            ax.set_ylabel(f"output - setpoint [{unit}]")
        # below the axes: inside, the legend covered the waveform's extremes
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=2, frameon=False)
    return fig


def plot_harmonics(result):
    """Relative error of G(j k Omega) per odd harmonic, linear vs augmented, per test."""
    effects = result.effects
    harm = effects[0].harmonics if effects else {}
    p = _figures(result)
    tests = p.tests
    fig, axes = new_figure(1, len(tests), width=3.6 * len(tests), height=3.4, squeeze=False, sharey=True)
    ks = ["1", "3", "5", "7"]
    for i, (test, ax) in enumerate(zip(tests, axes[0])):
        h = harm.get(str(test.index))
        if h is None:
            before = p.harmonics[i] if i < len(p.harmonics) else {}
            after = {}
        else:
            before, after = h["before"], h["after"]
        x = np.arange(len(ks))
        ax.bar(x - 0.2, [100 * before.get(k, np.nan) for k in ks], 0.4, color=_BASE_C, label="linear model")
        if after:
            ax.bar(x + 0.2, [100 * after.get(k, np.nan) for k in ks], 0.4, color=_AUG_C,
                   label=f"with {effects[0].name}")
        ax.set_xticks(x, [f"k={k}" for k in ks])
        ax.set_yscale("log")
        ax.set_title(f"test {test.index + 1}: beta {np.mean(test.beta):+.2f}, h {test.h:.3g}", fontsize=10)
        if i == 0:
            ax.set_ylabel("|G_rec - G_model| / |G_model| [%]\n(held-out cycles)")
        ax.legend(fontsize=7)
    fig.suptitle("Each odd harmonic of the relay measures G(j k Omega)", fontsize=11)
    return fig


def plot_evidence(result):
    """delta BIC per candidate (threshold line) and held-out error before/after (every family)."""
    rows = [c for c in result.candidates if c.delta_bic is not None and np.isfinite(c.delta_bic)]
    names = [c.name for c in rows]
    # the raw error (eq. (2): the recording's own cycle-to-cycle scatter kept; the scatter-subtracted figure is 0
    # whenever a model is within the scatter, which shows nothing on a bar chart)
    before, after = ([_nan(c.held_out_errors[j]) for c in rows] for j in (0, 1))
    fig, (ax, ax2) = new_figure(1, 2, width=11, height=4.2)
    y = np.arange(len(names))
    ax.barh(y, np.array([c.delta_bic for c in rows], float), color=[_AUG_C if result.named(c) else "#999999" for c in rows])
    # linear up to +-10 (the threshold), logarithmic beyond: one large bar no longer flattens the rest
    ax.set_xscale("symlog", linthresh=10.0)
    ax.axvline(10.0, color="red", lw=1, ls="--", label="strong evidence starts here (10)")
    ax.set_yticks(y, [n.replace("_", " ") for n in names])
    ax.set_xlabel("how much better the effect explains the fitted cycles\n(drop in BIC; negative: worse)")
    ax.set_title("Evidence for each candidate effect")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.3))
    ax2.barh(y + 0.2, 100 * np.array(before, float), 0.4, color=_BASE_C, label="linear model")
    ax2.barh(y - 0.2, 100 * np.array(after, float), 0.4, color=_AUG_C, label="with the candidate")
    ax2.set_yticks(y, [n.replace("_", " ") for n in names])
    ax2.set_xlabel("waveform error on held-out cycles [%]\n(delay jitter: error of the period scatter)" if result.soiptd
                   else "each test predicted from the others:\nrelative error [%] (cycle, balance, scatter)")
    ax2.set_title("Confirmation on held-out (odd) cycles" if result.soiptd else "Confirmation on the tests held out")
    ax2.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.3), ncol=2)
    return fig


def _nan(x: float | None) -> float:
    return np.nan if x is None else x


def _rows_table(result: DiagnosisResult) -> list[str]:
    """Every family's library: each candidate alone and on top of the first found, its parameter, drop in
    BIC, held-out error without and with it, and whether it is found (or why it was not fitted)."""
    rows = [*result.candidates, *result.second_effect_candidates]
    if not rows:
        return []
    return ["<div class='left2'>" + html_table(
        ["candidate", "with", "parameter", "drop in BIC", "held-out error before", "after", "found"],
        [(c.name.replace("_", " "), c.with_.replace("_", " ") or "-",
          f"{c.parameter} = {_f(c.value)} {c.unit}" if c.delta_bic is not None else c.status or "-",
          _f(c.delta_bic), *(_pct(x) for x in c.held_out_errors), "yes" if result.named(c) else "no")
         for c in rows]) + "</div>"]


_MODEL_NAMES = {"linear": "linear model", "analyze": "analyze (MRFT consensus)"}
_LEFT = "<style>.left3 td:nth-child(n+3), .left2 td:nth-child(n+2) { text-align: left; }</style>"


def _param_rows(e, loop: str) -> list[tuple]:
    """(parameter, value, +- std, unit) for people: the effect's name beside its parameter, times in ms."""
    by_parameter = {x.parameter: x for x in LIBRARY}
    plant = {"tau": ("delay tau", 1e3, "ms"), "Td": ("drag time constant Td", 1.0, "s"), "K": ("gain K", 1.0, gain_unit(loop))}
    out = []
    for key, v in e.parameters.items():
        if key == "unit" or key.endswith("_std") or not isinstance(v, (int, float)):
            continue
        base = key.removesuffix("_alone")
        effect = by_parameter.get(base)
        if base in plant:
            label, scale, unit = plant[base]
        else:
            unit = str(e.parameters.get("unit", "") if effect is None else unit_in_loop(effect.unit, loop))
            label = base if effect is None else f"{effect.name.replace('_', ' ')} {base}"
            scale, unit = (1e3, "ms") if unit == "s" else (1.0, "-" if unit == "1" else unit)
        std = e.parameters.get(f"{key}_std")
        out.append((label + (" (fitted alone)" if key != base else ""), _f(scale * v),
                    "-" if std is None else _f(scale * std), unit))
    return out


def write_diagnosis_report(result: DiagnosisResult, out_dir: str | Path) -> Path:
    """Write ``diagnosis.html`` and its PNGs into ``out_dir`` (``index.html`` too if there is none): the
    verdict, where the model disagrees (eq. (2): its figures; a family: each test against the model of
    the other tests), the library's evidence and rows, the notes."""
    out = ensure_dir(out_dir)
    body = [_LEFT, f"<p><b>{esc(result.summary)}</b></p>", *(_soiptd_sections(result, out) if result.soiptd else
                                                              _family_sections(result))]
    # candidates are fitted only when the model is rejected: no empty chart otherwise
    if any(c.delta_bic is not None and np.isfinite(c.delta_bic) for c in result.candidates):
        save_figure(plot_evidence(result), out / "diagnosis_evidence.png")
        body.append("<h2>Evidence for each candidate</h2><img src='diagnosis_evidence.png'>")
    elif result.soiptd:
        body.append("<h2>Evidence for each candidate</h2><p>No candidate was fitted: the cycles do not reject the "
                    "linear model, so there is nothing for a candidate effect to explain.</p>")
    body += _rows_table(result)
    body += [f"<p class='muted'>{esc(n)}</p>" for n in [*result.notes, result.to_dict()["nrmse_definition"]]]
    page = out / "diagnosis.html"
    write_page(page, html_page(f"Diagnosis: {Path(result.path).name} ({result.loop if result.soiptd else result.family.upper()})",
                               "\n".join(body)))
    if not (out / "index.html").exists():
        write_page(out / "index.html", page.read_text())
    return page


def _soiptd_sections(result: DiagnosisResult, out: Path) -> list[str]:
    """Eq. (2)'s page: the effects found, the identification, the located disagreements and the figures."""
    figs = {"diagnosis_located.png": plot_located(result), "diagnosis_overlay.png": plot_overlay(result),
            "diagnosis_harmonics.png": plot_harmonics(result)}
    for name, fig in figs.items():
        save_figure(fig, out / name)
    return [*_effect_sections(result), *_identification_section(result),
            "<h2>Where the linear model disagrees</h2><img src='diagnosis_located.png'>", _located_table(result),
            "<h2>Recording vs models (held-out cycles)</h2><img src='diagnosis_overlay.png'>",
            "<h2>Per-harmonic errors</h2><img src='diagnosis_harmonics.png'>"]


def _family_sections(result: DiagnosisResult) -> list[str]:
    """A family's page: each test against the model of the other tests, and where the residual sits."""
    return ["<h2>Each test against the model of the other tests</h2>",
            html_table(["test", "from-to [s]", "frequency [Hz]", "held out [Hz]", "amplitude", "held out",
                        "residual / noise: fundamental, 2-3, higher"],
                       [(c.index + 1, f"{c.t_start - result.t0:.2f}-{c.t_end - result.t0:.2f}", _f(c.frequency_hz),
                         _f(c.held_out_frequency_hz), _f(c.amplitude), _f(c.held_out_amplitude),
                         ", ".join(f"{b.ratio:.1f}" for b in c.all_bands)) for c in result.checks]),
            "<h2>Where the model disagrees</h2>",
            "".join(f"<p>{esc(text)}</p>" for text in result.located) or "<p>Nowhere beyond 3 sigma.</p>"]


def _effect_sections(result: DiagnosisResult) -> list[str]:
    """Each effect found (parameters with units, held-out scores), or what the log shows instead."""
    body = []
    for e in result.effects:
        body.append(f"<h2>Found: {esc(e.name.replace('_', ' '))}</h2><p>{esc(e.explanation)}</p>"
                    f"<p class='muted'>Model: {esc(e.augmentation)}</p>")
        body.append(html_table(["parameter", "value", "+- std", "unit"], _param_rows(e, result.loop)))
        before = e.evidence.compared_with
        fb, fa = e.fit_before, e.fit_after
        body.append("<div class='left2'>" + html_table(
            ["held-out cycles", f"{before} model", f"with {e.identification.model_of(e.name)}".replace("_", " ")],
            [("waveform error (NRMSE), as recorded", _pct(fb.nrmse_raw), _pct(fa.nrmse_raw)),
             ("the same beyond the recording's own cycle-to-cycle scatter", _pct(fb.nrmse), _pct(fa.nrmse)),
             ("features off by (RMS, in standard errors)", _f(fb.feature_rms_z), _f(fa.feature_rms_z))])
            + "</div>")
    if not result.effects and result.unexplained is None:
        body.append("<p>The linear model explains the log: no candidate has strong evidence confirmed on held-out "
                    "cycles.</p>")
    u = result.unexplained
    if u is not None:
        body.append("<h2>Unexplained mismatch</h2>")
        body.append(f"<p>{esc(u.what)}: on the held-out cycles the features are off by chi^2 "
                    f"{_f(u.held_out_feature_chi2)} over {u.held_out_features} features (p = {u.p_value:.2g}), "
                    f"waveform error {_pct(u.held_out_nrmse_raw)}.</p>")
        if u.largest:
            lg = u.largest
            body.append(f"<p>Largest: test {lg['test']}, {esc(lg['what'])} (z = {lg['z']:+.1f}).</p>")
    return body


def _identification_section(result: DiagnosisResult) -> list[str]:
    """Every estimate of the plant, the one to take marked, and why analyze's differs."""
    body: list[str] = []
    ident = result.identification
    if ident is None:  # a family's diagnosis: its analysis holds the identification (refused by write_diagnosis_report)
        return body
    body.append("<h2>Identification</h2>")
    rec = ident.recommended
    body.append(html_table(["model", "Td [s]", "tau [ms]", f"K [{esc(gain_unit(result.loop))}]", ""],
                           [(_MODEL_NAMES.get(k, k.replace("with_", "with ").replace("_", " ")), _f(v.Td),
                             _f(1e3 * v.tau) if v.tau is not None else "-", _f(v.K),
                             "the estimate to use" if rec is not None and rec.source == k else "")
                            for k, v in ident.entries().items()]))
    if rec is not None:
        body.append(f"<p>Recommended: {esc(rec.why)}.</p>")
    if ident.analyze is not None and ident.analyze.differs_because:
        body.append(f"<p class='muted'>analyze's model and the linear fit differ: {esc(ident.analyze.differs_because)}."
                    "</p>")
    return body


def _located_table(result: DiagnosisResult) -> str:
    """Where the linear model disagrees: features, harmonics, segments (times from the log start)."""
    t0 = result.t0
    loc_rows = []
    for loc in result.located[:12]:
        span = f"{loc.t_start - t0:.1f}-{loc.t_end - t0:.1f}"
        if loc.kind == "feature":
            loc_rows.append((loc.test + 1, span, loc.what, f"z = {loc.z:+.1f} standard errors"))
        elif loc.kind == "harmonic":
            loc_rows.append((loc.test + 1, span, loc.what, f"{100 * (loc.relative_error or 0.0):.1f} %"))
        else:
            cyc = ", ".join(str(c + 1) for c in loc.cycles or [])
            loc_rows.append((loc.test + 1, span, f"cycles {cyc}, worse half: {loc.worse_half}",
                             f"NRMSE {100 * (loc.nrmse or 0.0):.1f} %"))
    if not loc_rows:
        return "<p>Every feature is within 3 standard errors of the linear model's.</p>"
    return "<div class='left3'>" + html_table(["test", "time from the log start [s]", "what", "by how much"],
                                              loc_rows) + "</div>"


def _pct(x) -> str:
    return "-" if x is None else f"{100 * float(x):.2f} %"


def _f(x) -> str:
    if x is None:
        return "-"
    try:
        return f"{float(x):.4g}"
    except (TypeError, ValueError):
        return str(x)
