"""PX4's x/y export (issue 42): tune's loop with MPC_XY_VEL_D_ACC against PX4's position controller
transcribed tick by tick (PositionControl::_positionControl/_velocityControl/_accelerationControl,
MulticopterPositionControl's AlphaFilter on the velocity difference), on a plant discretised by scipy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import cont2discrete

from mrftcli.errors import InputError
from mrftcli.mrft.model import LoopModel
from mrftcli.tune.closed_loop import Controller, simulate_step, step_metrics, step_response
from mrftcli.tune.stack_params import check_ranges
from mrftcli.tune.stacks import check_exportable, export_design, px4_xy_controller

G = 9.80665
RATE = 125.0


def _px4_step(model: LoopModel, p: dict[str, float], hover: float, seconds: float, setpoint: float = 1.0,
              load: float = 0.0) -> np.ndarray:
    """PX4's x loop after a position step (``setpoint`` [m]), written from PX4's C++ (I after the output, as PX4
    does); ``load`` [command units] added at the plant's input from t = 0 (a force: wind w is w / K)."""
    T = 1.0 / RATE
    a, b = 1.0 / model.Tp, 1.0 / model.Td  # eq. (2): x'' = -b x' + K Td b w, w' = a (u - w)
    A = np.array([[0, 1, 0], [0, -b, model.K * b * model.Td], [0, 0, -a]], float)
    Bc = np.array([[0.0], [0.0], [a]])
    Ad, Bd, *_ = cont2discrete((A, Bc, np.eye(3), np.zeros((3, 1))), T, method="zoh")
    d = int(round(model.tau / T))
    assert abs(d * T - model.tau) < 1e-12  # the oracle holds whole ticks of delay
    cut = p["MPC_VELD_LP"]
    alpha = 1.0 if cut == 0 else T / (T + 1.0 / (2 * math.pi * cut))  # AlphaFilter::setCutoffFreq
    s = np.zeros(3)
    queue = [0.0] * d
    x_prev = v_prev = acc_f = v_int = 0.0
    out = []
    for _ in range(int(seconds * RATE) + 1):
        x = float(s[0])
        out.append(x)
        v = (x - x_prev) / T  # the velocity tune models: the position's backward difference
        vel_sp = p["MPC_XY_P"] * (setpoint - x)
        acc_f += alpha * ((v - v_prev) / T - acc_f)
        err = vel_sp - v
        acc = p["MPC_XY_VEL_P_ACC"] * err + v_int - p["MPC_XY_VEL_D_ACC"] * acc_f
        thrust = acc * hover / G  # _accelerationControl: body_z x collective thrust, exact below the tilt limit
        v_int += p["MPC_XY_VEL_I_ACC"] * err * T
        queue.append(thrust)
        s = Ad @ s + Bd[:, 0] * (queue.pop(0) + load)
        x_prev, v_prev = x, v
    return np.array(out)


@pytest.mark.parametrize("cut, d_acc", [(5.0, 0.1), (5.0, 0.6), (0.0, 0.2)])
def test_px4_xy_loop_is_px4s_position_controller(cut, d_acc):
    model = LoopModel(0.05, 0.8, 0.12, 27.0)
    p = {"MPC_XY_P": 1.6, "MPC_XY_VEL_P_ACC": 2.2, "MPC_XY_VEL_I_ACC": 0.0, "MPC_XY_VEL_D_ACC": d_acc,
         "MPC_VELD_LP": cut}
    ctrl = px4_xy_controller(p, RATE, 0.49)
    t, y, _ = step_response([model], ctrl, 6.0)
    oracle = _px4_step(model, p, 0.49, 6.0)
    n = min(len(oracle), y.shape[1])
    assert np.max(np.abs(y[0, :n] - oracle[:n])) < 1e-9
    # the event simulation (tune's second route) runs the same section from its coefficients
    _, ys, _, _ = simulate_step(model, ctrl, 6.0)
    assert np.max(np.abs(ys[:n] - oracle[:n])) < 1e-9
    if d_acc >= 0.6:  # the term matters: without it the step differs
        plain = Controller(ctrl.Kp, 0.0, ctrl.Kd, 0.0, RATE, None)
        assert np.max(np.abs(step_response([model], plain, 6.0)[1][0, :n] - oracle[:n])) > 1e-3


def test_px4_xy_export_inside_ranges_with_the_derivative_at_its_minimum():
    model = LoopModel(0.05, 0.6, 0.136, 27.4)
    hover = 0.49
    with pytest.raises(InputError, match="hover-thrust"):
        check_exportable("px4", "x", "PD")
    # a PD whose MPC_XY_P (2.5) is above PX4's 2, as tune's robust PD on px4_x_h16
    c = Controller(0.1542 * 1.3, 0.0, 0.0614 * 1.0, 0.0, RATE, None)
    e = export_design("px4", c, model, "y", "robust PD", hover_thrust=hover)
    assert set(e.params) == {"MPC_XY_P", "MPC_XY_VEL_P_ACC", "MPC_XY_VEL_I_ACC", "MPC_XY_VEL_D_ACC", "MPC_VELD_LP"}
    assert check_ranges("px4", e.params) == []
    assert e.params["MPC_XY_VEL_D_ACC"] == pytest.approx(0.1) and e.params["MPC_VELD_LP"] == 5.0
    assert e.params["MPC_XY_P"] == pytest.approx(2.0)
    assert math.isfinite(e.margins.Ms) and e.margins.Ms < 2.0
    # the step tune states for the written values is the one PX4's controller flies on the model (oracle)
    oracle = _px4_step(model, e.params, hover, 20.0)
    m = step_metrics(np.arange(oracle.size) / RATE, oracle)
    said = next(n for n in e.notes if n.startswith("the loop as written"))
    assert f"overshoot {m.overshoot_pct:.1f} %" in said
    assert any("MPC_XY_VEL_D_ACC" in n and "designed inside them" in n for n in e.notes)


def test_px4_xy_export_refuses_a_pid():
    with pytest.raises(InputError, match="PID"):
        check_exportable("px4", "x", "PID", 0.5)


def test_cli_exports_x_from_the_committed_px4_ulog(tmp_path, capsys):
    """``tune --export px4 --loop x`` on the fork's x MRFT as PX4 logged it (sample_logs/sitl/px4_x.ulg, 125 Hz
    from the log): written without --clamp, every value inside PX4's ranges, read back as the file says."""
    from pathlib import Path

    from mrftcli.cli.main import main

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "sitl" / "px4_x.ulg"
    out = tmp_path / "x.params"
    args = ["tune", str(log), "--tp", "0.05", "--loop", "x", "--export", "px4", "--out", str(out)]
    try:  # no --hover-thrust: PX4's estimate in the log (tests/test_hover_thrust_log.py), stated first
        main(args)
    except SystemExit as e:
        assert not e.code
    said = capsys.readouterr().out
    assert said.startswith("assumption: hover thrust 0.4911 (MPC_THR_HOVER, normalised) read from the log: the "
                           "median of the 710 valid hover_thrust_estimate.hover_thrust samples")
    assert "MPC_XY_VEL_D_ACC" in said and "125 Hz" in said
    assert "one MPC_XY_* set for x and y" in said  # PX4's x and y share the parameters: said, not left to find out
    # MPC_XY_VEL_I_ACC 0 by default: that wind is not corrected is said, with the offset and how to add it
    assert "MPC_XY_VEL_I_ACC 0 (a PD): nothing corrects a steady force" in said and "--xy-integral I_ACC" in said
    assert "# assumption: hover thrust 0.4911 (MPC_THR_HOVER, normalised) read from the log" in out.read_text()
    values = {ln.split("\t")[2]: float(ln.split("\t")[3]) for ln in out.read_text().splitlines()
              if ln and not ln.startswith("#")}
    assert set(values) == {"MPC_XY_P", "MPC_XY_VEL_P_ACC", "MPC_XY_VEL_I_ACC", "MPC_XY_VEL_D_ACC", "MPC_VELD_LP"}
    assert check_ranges("px4", values) == []
    # vehicle exports the same flight's x loop with the same values: its range-constrained design is held on the
    # same posterior draws as tune's (it was held on the nominal model alone and wrote MPC_XY_VEL_P_ACC 2.340)
    veh = tmp_path / "vehicle.params"
    try:
        main(["vehicle", str(log), "--tp", "0.05", "--export", "px4", "--out", str(veh)])
    except SystemExit as e:
        assert not e.code
    said = capsys.readouterr().out
    assert "over the nominal model and 43 posterior draws" in said
    assert said.startswith("assumption: hover thrust 0.4911 (MPC_THR_HOVER, normalised) read from the log")
    by_vehicle = {ln.split("\t")[2]: float(ln.split("\t")[3]) for ln in veh.read_text().splitlines()
                  if ln and not ln.startswith("#")}
    assert by_vehicle == values


def test_px4_xy_export_refuses_a_command_that_is_not_pxs_thrust():
    """K far from g / hover (e.g. HEAR's x command, an acceleration: K ~ 1) is not PX4's thrust setpoint."""
    c = Controller(0.2, 0.0, 0.08, 0.0, RATE, None)
    with pytest.raises(InputError, match="not near g / MPC_THR_HOVER"):
        export_design("px4", c, LoopModel(0.05, 2.0, 0.1, 0.98), "x", "robust PD", hover_thrust=0.5)


def test_the_flown_x_steps_follow_the_written_loops_prediction():
    """The x export flown in PX4 SITL (sample_logs/sitl/px4_x_steps.ulg, trimmed; its sidecar: the values written,
    the model they were designed on): PX4 ran the values written (its own parameter record), and against the
    commanded step the flown rise is within 30 % of the prediction and the mean response within 10 % of the
    step of the predicted curve over the first 2 s (the level held after that is EKF2's, docs/benchmarks/sitl.md)."""
    import json
    import sys
    from pathlib import Path

    from pyulog import ULog

    from mrftcli.io import open_log

    root = Path(__file__).resolve().parents[1]
    sys.path[:0] = [str(root / "scripts" / "sitl"), str(root / "scripts" / "sitl" / "px4")]
    from px4_xy_step import _against_setpoint

    log = root / "sample_logs" / "sitl" / "px4_x_steps.ulg"
    side = json.loads(Path(f"{log}.json").read_text())
    ran = ULog(str(log), ["trajectory_setpoint"]).initial_parameters
    for name, value in side["params_written"].items():
        assert ran[name] == pytest.approx(value, rel=1e-6)
    m = side["model"]
    ctrl = px4_xy_controller(side["params_written"], side["rate_hz"], side["hover_thrust"])
    t_p, y_p, u_p = step_response([LoopModel(m["Tp"], m["Td"], m["tau"], m["K"])], ctrl, 20.0)
    pred = {"t": t_p, "y": y_p[0], **step_metrics(t_p, y_p[0], u_p[0]).to_dict()}
    with open_log(log, echo_warnings=False) as src:
        ts, sp = src.read("trajectory_setpoint", ["position[0]"])
        t, pos = src.read("vehicle_local_position", ["x", "vx"])
    psp = sp["position[0]"]
    up = np.isfinite(psp) & (psp > np.nanmin(psp) + 0.5)
    starts = [float(ts[i]) for i in np.flatnonzero(np.diff(up.astype(int)) == 1) + 1]
    assert len(starts) == 4
    got = _against_setpoint(t, pos["x"], pos["vx"], starts, side["step_m"], side["dwell_s"], pred)
    assert abs(got["rise_s"] / pred["rise_s"] - 1.0) <= 0.3
    assert got["max_diff_first"] <= 0.10


def test_an_xy_integral_removes_a_forces_offset_which_the_pd_holds_at_its_closed_form(tmp_path):
    """px4_xy_step.integral_effect (the benchmark's figures for MPC_XY_VEL_I_ACC > 0) on the committed x export's
    values and model: a constant force w [m/s^2] at the plant's input leaves the PD (I 0) off by w / ((h/g)
    P_v P_xy K) in steady state (the command -w / K balances it: the closed form); with PX4's
    default I (0.4) the offset decays towards 0, and the setpoint step overshoots (the integral acts on P_xy e)."""
    import json
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    sys.path[:0] = [str(root / "scripts" / "sitl"), str(root / "scripts" / "sitl" / "px4")]
    from px4_xy_step import integral_effect

    side = json.loads((root / "sample_logs" / "sitl" / "px4_x_steps.ulg.json").read_text())
    p = side["params_written"]
    params = tmp_path / "x.params"
    params.write_text("".join(f"1\t1\t{k}\t{v!r}\t9\n" for k, v in p.items()))
    record = {"model": side["model"], "export": {"generic": {"rate_hz": side["rate_hz"]}},
              "hover": side["hover_thrust"]}
    rows = integral_effect(record, params, integrals=(0.0, 0.4), wind=1.0)
    pd, pid = rows
    closed = 9.80665 / (side["hover_thrust"] * p["MPC_XY_VEL_P_ACC"] * p["MPC_XY_P"] * side["model"]["K"])
    assert pd["wind_20s_m"] == pytest.approx(closed, rel=1e-3)
    assert abs(pid["wind_20s_m"]) < 0.05 * closed < abs(pid["wind_5s_m"])
    assert pid["overshoot_pct"] > pd["overshoot_pct"] + 2  # PX4's law: 3.9 % (the PID form's 11.2 % overstates it)


def test_xy_integral_is_designed_with_written_and_its_wind_offset_and_step_stated():
    """``xy_integral`` (tune --xy-integral): MPC_XY_VEL_I_ACC written and inside the loop searched and whose margins
    are stated; ``predicted`` (and the notes) against PX4's controller transcribed tick by tick (the oracle above,
    a force at the plant's input) and the PD's closed-form steady offset g w / (h P_v P_xy K)."""
    from mrftcli.tune.margins import loop_margins
    from mrftcli.tune.stacks import StackExport

    model, hover = LoopModel(0.05, 0.6, 0.136, 27.4), 0.49  # tau 17 whole ticks at 125 Hz
    c = Controller(0.1542 * 1.3, 0.0, 0.0614, 0.0, RATE, None)
    pd = export_design("px4", c, model, "x", "robust PD", hover_thrust=hover)
    pi = export_design("px4", c, model, "x", "robust PD", hover_thrust=hover, xy_integral=0.4)
    assert pd.params["MPC_XY_VEL_I_ACC"] == 0.0 and pi.params["MPC_XY_VEL_I_ACC"] == 0.4
    assert check_ranges("px4", pi.params) == []
    # the stated margins are those of the loop with the integral written
    ms = loop_margins(px4_xy_controller(pi.params, RATE, hover), [model]).Ms[0]
    ms_without = loop_margins(px4_xy_controller({**pi.params, "MPC_XY_VEL_I_ACC": 0.0}, RATE, hover), [model]).Ms[0]
    assert pi.margins.Ms == pytest.approx(ms, rel=1e-9) and abs(ms - ms_without) > 1e-3
    assert any("MPC_XY_VEL_I_ACC 0.4 (--xy-integral), the ranges: designed inside them" in n for n in pi.notes)
    # the range search's IAE (the cost stated) is that of PX4's law, the oracle's 20 s step of the values written
    oracle = _px4_step(model, pi.params, hover, 20.0)
    j = float(np.trapezoid(np.abs(1.0 - oracle), dx=1.0 / RATE))
    assert any(f"its cost: IAE {j:.4g} s against" in n for n in pi.notes)

    w = 1.0  # m/s^2 of wind
    for e in (pd, pi):
        p = e.params
        wind = np.abs(_px4_step(model, p, hover, 60.0, setpoint=0.0, load=w / model.K))
        at = {s: wind[int(round(s * RATE))] for s in (5.0, 20.0)}
        assert e.predicted["wind_offset_5s_m"] == pytest.approx(at[5.0], abs=1e-9)
        assert e.predicted["wind_offset_20s_m"] == pytest.approx(at[20.0], abs=1e-9)
        assert e.predicted["wind_peak_offset_m"] == pytest.approx(wind[: 40 * int(RATE) + 1].max(), abs=1e-9)
        step = _px4_step(model, p, hover, 40.0)
        m = step_metrics(np.arange(step.size) / RATE, step)
        assert e.predicted["step_overshoot_pct"] == pytest.approx(m.overshoot_pct, abs=1e-6)
        assert e.predicted["step_settling_s"] == pytest.approx(m.settling_s, abs=1e-6)
        said = next(n for n in e.notes if n.startswith("the loop as written"))
        assert f"overshoot {m.overshoot_pct:.1f} %" in said and f"2 % settling {m.settling_s:.3f} s" in said
        closed = G * w / (hover * p["MPC_XY_VEL_P_ACC"] * p["MPC_XY_P"] * model.K)
        if e is pd:  # held off for good, at the closed form
            assert wind[-1] == pytest.approx(closed, rel=1e-4)
            assert e.predicted["wind_steady_offset_m"] == pytest.approx(closed, rel=1e-12)
            assert any(f"holds the vehicle {100 * closed:.1f} cm off for good" in n for n in e.notes)
        else:  # corrected: the integral of the velocity error removes it
            assert wind[-1] < 1e-3 * closed and e.predicted["wind_steady_offset_m"] == 0.0
            assert any(f"{100 * at[20.0]:.1f} cm after 20 s, 0 in steady state (without it {100 * closed:.1f} cm"
                       in n for n in e.notes)
    assert pi.predicted["step_overshoot_pct"] > pd.predicted["step_overshoot_pct"] + 1  # the integral's price
    # without integral tune's PID form (px4_xy_controller) is PX4's loop: the same step figures
    t, y, _ = step_response([model], px4_xy_controller(pd.params, RATE, hover), 40.0)
    f = step_metrics(t, y[0])
    assert (pd.predicted["step_overshoot_pct"], pd.predicted["step_settling_s"]) == pytest.approx(
        (f.overshoot_pct, f.settling_s), abs=1e-6)
    # PX4 integrates P_xy e - v (no P_xy r kick): tune's PID Controller of the same loop overshoots much more
    t, y, _ = step_response([model], px4_xy_controller(pi.params, RATE, hover), 40.0)
    assert step_metrics(t, y[0]).overshoot_pct > pi.predicted["step_overshoot_pct"] + 3
    back = StackExport.from_json(pi.to_json())
    assert back.predicted == pytest.approx(pi.predicted) and back.params == pi.params


def test_xy_integral_is_refused_outside_its_range_and_for_other_exports():
    from mrftcli.tune.stacks import check_xy_integral

    check_xy_integral("px4", "y", 0.0)
    check_xy_integral("ardupilot", "altitude", None)
    for stack, loop, value, why in (("px4", "x", 61.0, "outside MPC_XY_VEL_I_ACC's range 0-60"),
                                    ("px4", "x", -0.1, "outside"), ("px4", "x", math.nan, "outside"),
                                    ("px4", "altitude", 0.4, "x or y loop"), ("hear", "x", 0.4, "x or y loop"),
                                    (None, "x", 0.0, "--export px4")):
        with pytest.raises(InputError, match=why):
            check_xy_integral(stack, loop, value)


def test_cli_xy_integral_before_the_work(capsys):
    """An --xy-integral the export does not take is one line, exit 2, before any analysis."""
    from mrftcli.cli.main import main

    base = ["tune", "--td", "0.6", "--tau", "0.136", "--k", "27.4", "--tp", "0.05", "--loop"]
    for extra, why in ((["x", "--xy-integral", "0"], "--export px4"),
                       (["roll", "--export", "px4", "--xy-integral", "0.4"], "x or y loop"),
                       (["x", "--export", "px4", "--hover-thrust", "0.49", "--xy-integral", "75"], "range 0-60")):
        with pytest.raises(SystemExit) as ex:
            main([*base, *extra])
        assert ex.value.code == 2 and why in capsys.readouterr().err
    with pytest.raises(SystemExit):  # the help names the parameter and its range, from the vendored table
        main(["tune", "--help"])
    said = " ".join(capsys.readouterr().out.split())
    assert "--xy-integral I_ACC PX4 MPC_XY_VEL_I_ACC [(m/s^2)/m, 0-60; PX4's default 0.4]" in said
