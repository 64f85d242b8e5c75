"""The fleet report's tables stay inside the page: every table is in a horizontally scrolling wrapper,
long paths may wrap, and the columns name their units."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

pytestmark = pytest.mark.usefixtures("mplcleanup")


def _summary(n: int) -> pd.DataFrame:
    deep = "/data/flights/" + "/".join(f"campaign_{i:02d}_with_a_long_folder_name" for i in range(6))
    taus = np.linspace(0.045, 0.050, n)
    return pd.DataFrame({
        "path": [f"{deep}/log{i}.mcap" for i in range(n)], "loop": ["altitude"] * n,
        "vehicle": [f"v{i % 2}" for i in range(n)], "status": ["ok"] * n, "result_status": ["ok"] * n,
        "tau_mean": taus, "tau_std": [0.001] * n, "Td_mean": [1.0] * n, "Td_std": [0.2] * n,
        "K_mean": [20.0] * n, "K_std": [0.01] * n, "n_tests": [2] * n, "n_cycles": [20] * n, "findings": [""] * n,
        "error": [None] * n, "error_type": [None] * n, "outlier": [False] * n, "outlier_reason": [""] * n, "lead": [False] * n,
        "log_time": pd.date_range("2026-01-01", periods=n, freq="D", tz="UTC"), "log_time_source": ["log"] * n,
    })


def test_tables_scroll_inside_the_page_and_name_their_units(tmp_path):
    from mrftcli.report.fleet import write_fleet_report

    try:
        html = write_fleet_report(_summary(4), tmp_path).read_text()
    except KeyError as err:  # a column the batch summary has and this toy lacks
        pytest.fail(f"toy summary lacks {err}")
    tables = html.count("<table>")
    assert tables >= 1 and html.count("<div class='table-wrap'><table>") == tables
    assert re.search(r"\.table-wrap \{[^}]*overflow-x: auto", html)
    assert "max-width: 1100px" in html  # the page itself keeps its width; the wrapper scrolls
    assert "<th>Td [s]</th>" in html and "<th>K [m or rad /s² per command unit]</th>" in html
    assert "ms</td>" in html  # tau cells carry their unit


@pytest.mark.parametrize("n", [6, 12, 40])
def test_fleet_plot_labels_do_not_overlap_and_k_has_its_unit(tmp_path, monkeypatch, n):
    """Issue 40: on the log-order axis (logs without distinct times) no two x labels overlap (their
    rendered boxes, measured by matplotlib's renderer), and the K axis names its unit."""
    import mrftcli.report.fleet as fleet

    figs = []
    monkeypatch.setattr(fleet, "savefig_atomic", lambda fig, path, **kw: figs.append(fig))
    monkeypatch.setattr(fleet.plt, "close", lambda fig: None)
    df = _summary(n)
    df["log_time"] = pd.Timestamp("2026-01-01", tz="UTC")  # one time stamp: the logs in order, named
    fleet.plot_loop(df, "altitude", tmp_path / "fleet.png")
    fig = figs[0]
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    axes = fig.get_axes()
    boxes = [t.get_window_extent(renderer) for t in axes[2].get_xticklabels() if t.get_text()]
    assert boxes and all(a.x1 <= b.x0 + 0.5 for a, b in zip(boxes, boxes[1:])), "x labels overlap"
    assert axes[2].get_ylabel() == "K [m/s² per command unit]"
