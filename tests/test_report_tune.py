"""The tune report: the phase of the loop passes through -180 + PM at the gain crossover (closed form
of the margin's definition: |L(w_gc)| = 1), the MRFT rule's Ms far over the bound is flagged, the
recommended design and its export are on the page, the gains carry units."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mrftcli.mrft.model import LoopModel

pytestmark = pytest.mark.usefixtures("mplcleanup")


@pytest.fixture(scope="module")
def result():
    from mrftcli.tune.design import DesignOptions, tune

    # design1's altitude loop (sample_logs/design1_altitude.mcap.truth.json), no posterior: PD only
    return tune(LoopModel(0.0422, 2.669, 0.0464, 19.62), 200.0, options=DesignOptions(kinds=("PD", "PID")),
                loop="altitude")


def test_phase_is_on_the_margins_branch(result):
    from mrftcli.report.tune import _phase_on_margin_branch
    from mrftcli.tune.margins import margin_grid, plant_response

    w = margin_grid(result.rate_hz, int(result.model.tau * result.rate_hz))
    Gd = plant_response([result.model], result.rate_hz, w)[0]
    for d in result.designs:
        L = d.controller.feedback_response(w) * Gd
        g = d.margins
        i = int(np.argmin(np.abs(20 * np.log10(np.abs(L)))))  # |L| = 1: the gain crossover, found here
        assert w[i] == pytest.approx(g.w_gc, rel=0.05)
        ph = _phase_on_margin_branch(w, L, g.w_gc, g.phase_margin_deg)
        assert ph[i] == pytest.approx(-180.0 + g.phase_margin_deg, abs=2.0)
        # below the crossover the loop's phase is on the axis the plot shows, not a turn above it
        assert np.all(ph[w < g.w_gc] < 0.0) and np.all(ph[w < g.w_gc] > -360.0)


def test_page_flags_the_rule_names_the_recommendation_and_units(result, tmp_path):
    import matplotlib.pyplot as plt

    from mrftcli.report.tune import recommended_design, write_tune_report

    html = write_tune_report(result, tmp_path / "tune").read_text()
    rule = result.get("mrft-rule", "PD")
    assert rule.margins.Ms > 2 * result.ms_max  # the paper's rule rings on this loop
    assert f"NO: Ms {rule.margins.Ms:.1f} &gt; {result.ms_max:g}" in html or f"NO: Ms {rule.margins.Ms:.1f} > " in html
    name, kind = recommended_design(result)
    assert name == "model-based" and kind == "PD"  # no posterior: no robust design
    c = result.get(name, kind).controller
    assert f"Recommended: {name} {kind}" in html and f"{c.Kp:.5g}" in html and "&quot;Kd&quot;" in html
    assert "Kp [cmd/m]" in html and "Kd [cmd s/m]" in html
    assert plt.get_fignums() == []
    assert math.isfinite(c.Kp)
