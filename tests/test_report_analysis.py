"""The analysis report: figures are drawn from a finished AnalysisResult, files are written, nothing
is left open; computing draws nothing (python-control's compute-then-plot check)."""

from __future__ import annotations

import re
from dataclasses import replace

import matplotlib
import pytest

from mrftcli.analyze import analyze_flight
from mrftcli.io.logtypes import Signal
from test_segment_support import flight_from_simulated, simulate_paper_flight

pytestmark = pytest.mark.usefixtures("mplcleanup")


@pytest.fixture(scope="module")
def result():
    sf = simulate_paper_flight(0.0499, 1.8345, 0.0498, 2.0, (-0.4, -0.7), seed=9)
    return analyze_flight(flight_from_simulated(sf), 0.0499)


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


def test_write_report(result, tmp_path):
    import matplotlib.pyplot as plt

    from mrftcli.report.analysis import write_analysis_report

    index = write_analysis_report(result, tmp_path / "out")
    html = index.read_text()
    for png in re.findall(r"src='([^']+\.png)'", html):
        data = (tmp_path / "out" / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    assert len(re.findall(r"src='([^']+\.png)'", html)) == 4
    assert f"{result.tau.mean * 1e3:.4g}" in html and f"{result.Td.mean:.4g}" in html
    assert plt.get_fignums() == []  # every figure closed
    assert matplotlib.get_backend().lower() == "agg"


def test_time_axes_are_seconds_from_the_log_start(tmp_path):
    """Epoch-stamped log: no '+1.7e9' offset, no absolute times on the axes or in the page."""
    from mrftcli.report.analysis import plot_timeseries, write_analysis_report

    sf = simulate_paper_flight(0.0499, 1.8345, 0.0498, 2.0, (-0.4, -0.7), seed=9)
    fl = flight_from_simulated(sf)
    fl = replace(fl, **{name: Signal(getattr(fl, name).t + 1_700_000_000.0, getattr(fl, name).values)
                        for name in ("command", "output", "setpoint", "beta")})
    res = analyze_flight(fl, 0.0499, n_bootstrap=100)
    duration = float(fl.command.t[-1] - fl.command.t[0])
    fig = plot_timeseries(res)
    fig.canvas.draw()
    for ax in fig.axes:
        lo, hi = ax.get_xlim()
        assert -0.1 * duration < lo < hi < 1.1 * duration
        assert ax.xaxis.get_offset_text().get_text() == ""
        assert "1700000" not in ax.get_xlabel()
    t1 = res.tests[0]
    html = write_analysis_report(res, tmp_path / "out").read_text()
    assert "1700000" not in html
    assert f"{t1.t_start - res.t0:.1f} - {t1.t_end - res.t0:.1f}" in html
