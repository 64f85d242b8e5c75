"""tune/px4_xy: PX4's x/y export's written loop in a module of its own; the PD's wind offset from its closed form,
not from a second 40 s run of PX4's law (last stop's note: ``_written_step`` re-ran it with I = 0 to read it)."""

from __future__ import annotations

import pytest

from mrftcli.mrft.model import LoopModel
from mrftcli.tune import px4_xy
from mrftcli.tune.closed_loop import Controller
from mrftcli.tune.stacks import export_design

G = 9.80665
RATE = 125.0


def test_xy_export_runs_pxs_law_once_and_states_the_pds_offset_in_closed_form(monkeypatch):
    model, hover = LoopModel(0.05, 0.6, 0.136, 27.4), 0.49
    c = Controller(0.1542 * 1.3, 0.0, 0.0614, 0.0, RATE, None)
    runs: list[float] = []
    real = px4_xy.px4_xy_ticks

    def counted(params, m, rate_hz, h, seconds):
        if seconds == px4_xy.XY_HORIZON_S:
            runs.append(params["MPC_XY_VEL_I_ACC"])
        return real(params, m, rate_hz, h, seconds)

    monkeypatch.setattr(px4_xy, "px4_xy_ticks", counted)
    pi = export_design("px4", c, model, "x", "robust PD", hover_thrust=hover, xy_integral=0.4)
    assert runs == [0.4]  # the loop as written, once: the PD's offset needs no run of its own
    p = pi.params
    closed = G / (hover * p["MPC_XY_VEL_P_ACC"] * p["MPC_XY_P"] * model.K)  # (h/g) P_v P_xy e = w / K
    assert px4_xy.pd_wind_offset(p, model, hover) == pytest.approx(closed, rel=1e-12)
    assert any(f"0 in steady state (without it {100 * closed:.1f} cm for good)" in n for n in pi.notes)


def test_no_gain_holds_no_offset_bound():
    model = LoopModel(0.05, 0.6, 0.136, 27.4)
    assert px4_xy.pd_wind_offset({"MPC_XY_VEL_P_ACC": 0.0, "MPC_XY_P": 1.0}, model, 0.5) == float("inf")
