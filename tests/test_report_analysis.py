"""The analysis report: figures are drawn from a finished AnalysisResult, files are written, nothing
is left open; computing draws nothing (python-control's compute-then-plot check)."""

from __future__ import annotations

import re
from dataclasses import replace

import matplotlib
import numpy as np
import pytest

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalyzeOptions, analyze_flight
from mrftcli.io.logtypes import Signal
from test_segment_support import flight_from_simulated, simulate_paper_flight

pytestmark = pytest.mark.usefixtures("mplcleanup")


@pytest.fixture(scope="module")
def result():
    sf = simulate_paper_flight(0.0499, 1.8345, 0.0498, 2.0, (-0.4, -0.7), seed=9)
    return analyze_flight(flight_from_simulated(sf), soiptd_model(0.0499))


def test_computing_draws_nothing(result):
    import matplotlib.pyplot as plt

    assert plt.get_fignums() == []


def test_figures(result):
    from mrftcli.report.analysis import plot_cycles, plot_manifolds, plot_spread, plot_timeseries

    fig = plot_timeseries(result)
    assert len(fig.axes) == 2 + len(result.tests)  # command, output, one zoom per test
    fig = plot_manifolds(result)
    ax = fig.axes[0]
    assert ax.get_xscale() == "log"
    lo, hi = ax.get_xlim()
    assert lo < result.model.Td < hi
    lo, hi = ax.get_ylim()
    assert lo < result.model.tau * 1e3 < hi
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert sum(lbl.startswith("test ") for lbl in labels) == len(result.tests)
    fig = plot_spread(result)
    assert [a.get_title() for a in fig.axes] == ["Td", "tau", "K"]
    fig = plot_cycles(result)
    assert len(fig.axes) == 2 * len(result.tests)


@pytest.fixture(scope="module")
def epoch_report(tmp_path_factory):
    """An epoch-stamped log's analysis and its report, written once (a report is ~10x its analysis' CPU): the
    written files are checked by test_write_report, the times on its page by test_time_axes_..."""
    from mrftcli.report.analysis import write_analysis_report

    sf = simulate_paper_flight(0.0499, 1.8345, 0.0498, 2.0, (-0.4, -0.7), seed=9)
    fl = flight_from_simulated(sf)
    fl = replace(fl, **{name: Signal(getattr(fl, name).t + 1_700_000_000.0, getattr(fl, name).values)
                        for name in ("command", "output", "setpoint", "beta")})
    res = analyze_flight(fl, soiptd_model(0.0499), options=AnalyzeOptions(n_bootstrap=100))
    out = tmp_path_factory.mktemp("report") / "out"
    return fl, res, write_analysis_report(res, out)


def test_write_report(epoch_report):
    import matplotlib.pyplot as plt

    _, result, index = epoch_report
    html = index.read_text()
    for png in re.findall(r"src='([^']+\.png)'", html):
        data = (index.parent / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    assert len(re.findall(r"src='([^']+\.png)'", html)) == 6
    assert f"{result.tau.value * 1e3:.4g}" in html and f"{result.Td.value:.4g}" in html
    # K has its unit; the amplitude the unit the CLI prints; one sentence says which uncertainty to use
    assert "<td>m/s² per command unit</td>" in html and "amplitude [m]" in html
    assert "Uncertainty: use the ± std and 95 % interval above" in html
    assert plt.get_fignums() == []  # every figure closed
    assert matplotlib.get_backend().lower() == "agg"


def test_time_axes_are_seconds_from_the_log_start(epoch_report):
    """Epoch-stamped log: no '+1.7e9' offset, no absolute times on the axes or in the page."""
    from mrftcli.report.analysis import plot_timeseries

    fl, res, index = epoch_report
    assert fl.command.t[0] > 1e9  # the log's own clock is epoch seconds
    duration = float(fl.command.t[-1] - fl.command.t[0])
    fig = plot_timeseries(res)
    fig.canvas.draw()
    for ax in fig.axes:
        lo, hi = ax.get_xlim()
        assert -0.1 * duration < lo < hi < 1.1 * duration
        assert ax.xaxis.get_offset_text().get_text() == ""
        assert "1700000" not in ax.get_xlabel()
    t1 = res.tests[0]
    html = index.read_text()
    assert "1700000" not in html
    assert f"{t1.t_start - res.t0:.1f} - {t1.t_end - res.t0:.1f}" in html


def test_model_output_leaves_the_simulated_sensor_noise_as_residual(result):
    """Oracle: the simulator's noise std (0.5 mm); the identified model's residual is that noise."""
    from mrftcli.report.analysis import plot_fit

    fig = plot_fit(result)
    n = len(result.tests)
    assert len(fig.axes) == 2 * n
    for ax in fig.axes[n:]:  # the residual row
        resid = np.asarray(ax.get_lines()[0].get_ydata(), float)
        assert np.sqrt(np.mean(resid ** 2)) == pytest.approx(0.0005, rel=0.2)


def test_bode_is_the_closed_form_and_the_ellipse_holds_95_percent(result):
    """Oracle: |G| and arg G of eq. (2) in closed form at the tests' frequencies; the drawn ellipse
    holds about 95 % of the posterior draws it summarises."""
    from matplotlib.path import Path as MplPath

    from mrftcli.report.analysis import plot_uncertainty, posterior_draws

    draws, _ = posterior_draws(result)
    assert draws.shape[0] >= 100
    assert np.std(draws[:, 0]) == pytest.approx(result.Td.std, rel=0.5)
    fig = plot_uncertainty(result)
    ax_m, ax_p, ax_e = fig.axes
    m = result.model
    w_line, mag = (np.asarray(a, float) for a in ax_m.get_lines()[0].get_data())
    _, ph = (np.asarray(a, float) for a in ax_p.get_lines()[0].get_data())
    for w in (2 * np.pi * t.frequency_hz_mean for t in result.tests):
        i = int(np.argmin(np.abs(w_line - w)))
        wi = w_line[i]
        closed = m.K * m.Td / (wi * np.hypot(1, m.Tp * wi) * np.hypot(1, m.Td * wi))
        assert mag[i] == pytest.approx(20 * np.log10(closed), abs=1e-6)
        arg = -90 - np.degrees(np.arctan(m.Tp * wi) + np.arctan(m.Td * wi) + m.tau * wi)
        assert ph[i] == pytest.approx(arg, abs=1e-6)
    ring = [ln for ln in ax_e.get_lines() if ln.get_label() == "95 % ellipse"][0]
    inside = MplPath(np.column_stack(ring.get_data())).contains_points(
        np.column_stack([draws[:, 0], draws[:, 1] * 1e3]))
    assert 0.9 < inside.mean() < 0.99
