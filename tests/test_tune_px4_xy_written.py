"""tune/px4_xy: PX4's x/y export's written loop in a module of its own; the PD's wind offset from its closed form,
not from a second 40 s run of PX4's law (last stop's note: ``_written_step`` re-ran it with I = 0 to read it)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mrftcli.mrft.model import LoopModel
from mrftcli.tune import px4_xy

G = 9.80665
RATE = 125.0


def test_the_written_loop_runs_pxs_law_once_and_states_the_pds_offset_in_closed_form(monkeypatch):
    model, hover = LoopModel(0.05, 0.6, 0.136, 27.4), 0.49
    p = {"MPC_XY_P": 1.2, "MPC_XY_VEL_P_ACC": 2.3, "MPC_XY_VEL_I_ACC": 0.4, "MPC_XY_VEL_D_ACC": 0.1, "MPC_VELD_LP": 5.0}
    runs: list[float] = []
    real = px4_xy.px4_xy_ticks

    def counted(params, m, rate_hz, h, seconds):
        if seconds == px4_xy.XY_HORIZON_S:
            runs.append(params["MPC_XY_VEL_I_ACC"])
        return real(params, m, rate_hz, h, seconds)

    monkeypatch.setattr(px4_xy, "px4_xy_ticks", counted)
    notes, predicted = px4_xy.written_loop(p, model, RATE, hover)
    assert runs == [0.4]  # the loop as written, once: the PD's offset needs no run of its own
    closed = G / (hover * p["MPC_XY_VEL_P_ACC"] * p["MPC_XY_P"] * model.K)  # (h/g) P_v P_xy e = w / K
    assert px4_xy.pd_wind_offset(p, model, hover) == pytest.approx(closed, rel=1e-12)
    assert f"0 in steady state (without it {100 * closed:.1f} cm for good)" in notes[1]
    assert predicted["wind_steady_offset_m"] == 0.0
    runs.clear()
    notes, predicted = px4_xy.written_loop({**p, "MPC_XY_VEL_I_ACC": 0.0}, model, RATE, hover)
    assert runs == [0.0, 0.4]  # the PD as written and PX4's default integral offered instead (its figures said)
    assert predicted["wind_steady_offset_m"] == pytest.approx(closed, rel=1e-12)
    # the export carries them: test_tune_px4_xy checks its figures against PX4's law transcribed tick by tick


def test_no_gain_holds_no_offset_bound():
    model = LoopModel(0.05, 0.6, 0.136, 27.4)
    assert px4_xy.pd_wind_offset({"MPC_XY_VEL_P_ACC": 0.0, "MPC_XY_P": 1.0}, model, 0.5) == float("inf")


def test_one_hover_thrust_check_for_tune_and_vehicle(monkeypatch):
    """vehicle checked --hover-thrust by asking check_exportable about an "altitude" loop it might not export;
    check_hover_thrust is the one rule both use: (0, 1), and MOT_THST_HOVER's range for ArduPilot's altitude."""
    from pathlib import Path

    import mrftcli.vehicle
    from mrftcli.cli.main import main
    from mrftcli.errors import InputError
    from mrftcli.tune.stacks import check_exportable, check_hover_thrust

    check_hover_thrust("px4", 0.9)
    check_hover_thrust("ardupilot", 0.9, "roll")  # its roll export does not take it (refused elsewhere)
    for stack, h, said in (("px4", 1.5, "normalised thrust in (0, 1)"), ("ardupilot", 0.9, "MOT_THST_HOVER's range")):
        with pytest.raises(InputError, match=said.replace("(", r"\(").replace(")", r"\)")) as direct:
            check_hover_thrust(stack, h)
        with pytest.raises(InputError) as via_tune:
            check_exportable(stack, "altitude", "PD", h)
        assert str(via_tune.value) == str(direct.value)

    def no_work(*args, **kwargs):
        raise AssertionError("vehicle analysed the log before checking --hover-thrust")

    monkeypatch.setattr(mrftcli.vehicle, "identify_vehicle", no_work)
    log = Path(__file__).resolve().parents[1] / "sample_logs" / "design1_roll.mcap"
    with pytest.raises(SystemExit) as code:
        main(["vehicle", str(log), "--tp", "0.05", "-q", "--export", "ardupilot", "--hover-thrust", "0.9"])
    assert code.value.code == 2


def test_tune_opens_a_px4_log_once(monkeypatch):
    """tune opened a PX4 log for its hover thrust, then again for the analysis: now once, the analysis reading the
    log the hover thrust was read from (as vehicle does)."""
    import mrftcli.analyze
    import mrftcli.io
    from mrftcli.cli.main import main

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "sitl" / "px4_x.ulg"
    opened, given = [], []
    real_open = mrftcli.io.open_log

    def counting_open(*args, **kwargs):
        opened.append(args[0])
        return real_open(*args, **kwargs)

    def stop(path, model, *, read=None, options=None, log=None, **kwargs):
        given.append(log)
        raise SystemExit(0)  # what the analysis is given is checked: no analysis needed

    monkeypatch.setattr(mrftcli.io, "open_log", counting_open)
    monkeypatch.setattr(mrftcli.analyze, "analyze_path", stop)
    with pytest.raises(SystemExit):
        main(["tune", str(log), "--tp", "0.05", "--loop", "x", "--export", "px4", "-q"])
    assert len(opened) == 1 and len(given) == 1 and given[0] is not None  # the hover thrust's open log
