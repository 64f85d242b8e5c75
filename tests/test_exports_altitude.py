"""ArduPilot's altitude cascade (tracker issue 25): AC_PosControl's z loops exported with their margins held
for every split of tau; the refusals; an independent simulation of ArduPilot's code checks the margins."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import linalg, signal

from mrftcli.errors import InputError
from mrftcli.mrft.model import LoopModel
from mrftcli.tune.ardupilot_z import design_z_cascade, split_grid
from mrftcli.tune.closed_loop import Controller, RateFilter
from mrftcli.tune.stack_params import STACK_PARAMS, check_ranges, param
from mrftcli.tune.stacks import ExportEvidence, check_exportable, export_design, stack_setting

#: tau 40 ms at 200 Hz: every split of the grid is whole ticks, so the simulation below needs no sub-steps
MODEL = LoopModel(0.0422, 2.669, 0.040, 19.62)
RATE = 200.0


def _pd() -> Controller:
    """A PD of the altitude loop (the shape tune's model-based PD has on design1_altitude)."""
    return Controller(0.53, 0.0, 0.226, 0.0, RATE, RateFilter(0.0, "none"))


def test_refusals_name_the_option_and_the_units():
    with pytest.raises(InputError, match="MOT_THST_HOVER"):
        check_exportable("ardupilot", "altitude", "PD")  # the hover throttle is required
    with pytest.raises(InputError, match="outside MOT_THST_HOVER's range 0.2-0.8"):
        check_exportable("ardupilot", "altitude", "PD", 0.9)
    with pytest.raises(InputError, match="not ArduPilot's throttle") as err:
        export_design("ardupilot", _pd(), MODEL, "altitude", "x", hover_thrust=0.2)  # K 19.6 against g / 0.2 = 49
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="x loop"):
        check_exportable("ardupilot", "x", "PD", 0.5)
    with pytest.raises(InputError, match="outside SCHED_LOOP_RATE's range 50-400 Hz"):
        stack_setting("ardupilot", "altitude", 25.0, None, None)  # ArduPilot runs no loop below 50 Hz


@pytest.mark.parametrize("stack,hover_param,command", [("ardupilot", "MOT_THST_HOVER", "ArduPilot's throttle"),
                                                        ("px4", "MPC_THR_HOVER", "PX4's normalised thrust")])
def test_both_stacks_altitude_exports_refuse_a_command_that_is_not_their_thrust(stack, hover_param, command):
    # both write acceleration gains x hover / g (ArduPilot's z cascade, PX4's MPC_Z_VEL_P_ACC = Kd g / h): one
    # rule, K within 2x of g / h. K 19.62: g / h is 19.61 at h 0.5, 49 at h 0.2 (2.5x)
    from mrftcli.tune.stacks import UNIT_TOLERANCE, check_units

    c, version = _pd(), {"version": "4.6"} if stack == "ardupilot" else {}
    export_design(stack, c, MODEL, "altitude", "x", hover_thrust=0.5, **version)
    edge = 9.80665 / (UNIT_TOLERANCE * MODEL.K)  # h 0.2499: g / h twice K
    for hover in (0.2, 0.995 * edge):
        with pytest.raises(InputError, match=f"not near g / {hover_param} .*not {command}") as err:
            export_design(stack, c, MODEL, "altitude", "x", hover_thrust=hover, **version)
        assert "\n" not in str(err.value) and "--hover-thrust" in str(err.value)
    check_units(MODEL, 1.005 * edge, stack, "altitude", hover_param)  # just within 2x


def test_the_design_rate_is_the_stacks_never_the_logs():
    """A 50 Hz log is designed at SCHED_LOOP_RATE's default 400 Hz (or the vehicle's, given), never advice to
    change the vehicle-wide rate; what the log's rate costs is said."""
    st = stack_setting("ardupilot", "altitude", None, 50.0, None)
    text = " ".join(st.notes)
    assert st.rate_hz == 400.0 and "set SCHED_LOOP_RATE" not in text and "20.0 ms" in text
    assert stack_setting("ardupilot", "roll", 200.0, 50.0, None).rate_hz == 200.0
    px4 = stack_setting("px4", "roll", None, 50.0, None)  # PX4's attitude loop at IMU_INTEG_RATE's default
    assert px4.rate_hz == 200.0 and "neither is written" in " ".join(px4.notes)


def test_psc_ranges_are_vendored_with_their_source():
    rows = {p.name: p for p in STACK_PARAMS if p.name.startswith("PSC_")}
    assert {"PSC_POSZ_P", "PSC_VELZ_P", "PSC_ACCZ_P", "PSC_ACCZ_I", "PSC_ACCZ_D"} <= set(rows)
    assert all("AC_PosControl.cpp" in p.source and ("46d6887e" in p.source or p.name.startswith("PSC_D_"))
               and p.verified for p in rows.values())
    assert (param("ardupilot", "PSC_ACCZ_P").minimum, param("ardupilot", "PSC_ACCZ_P").maximum) == (0.2, 1.5)
    assert (param("ardupilot", "PSC_ACCZ_P").default, param("ardupilot", "PSC_VELZ_P").default) == (0.5, 5.0)
    assert [v.param.name for v in check_ranges("ardupilot", {"PSC_POSZ_P": 0.5, "PSC_VELZ_P": 5.0})] == ["PSC_POSZ_P"]


def test_split_grid_covers_tau():
    g = split_grid(0.04)
    assert len(g) == 37 and len(set(g)) == 37
    assert all(0 <= s.actuator_s <= 0.04 + 1e-15 and max(s.velocity_s, s.altitude_s) <= 0.04 - s.actuator_s + 1e-15
               for s in g)


def _simulate(p: dict[str, float], model: LoopModel, split_ticks: tuple[int, int, int], k: float,
              seconds: float) -> np.ndarray:
    """ArduPilot's z loops as its code runs them (AC_P_1D, AC_PID_Basic, AC_PID, the motors' 2 Hz throttle
    filter, INS_ACCEL_FILTER as scipy's Butterworth), the throttle scaled by ``k``, on the plant stepped
    exactly (scipy's expm); delays in whole ticks: the actuator's, and the velocity's and altitude's
    measurements' beyond it. Returns z [m] per tick."""
    T = 1.0 / RATE
    A = np.array([[0.0, 1.0, 0.0], [0.0, -1.0 / model.Td, model.K], [0.0, 0.0, -1.0 / model.Tp]])
    B = np.array([0.0, 0.0, 1.0 / model.Tp])
    E = linalg.expm(np.block([[A, B[:, None]], [np.zeros((1, 4))]]) * T)
    Phi, Gam = E[:3, :3], E[:3, 3]

    def alpha(hz: float) -> float:
        return 1.0 if hz <= 0 else T / (T + 1.0 / (2.0 * math.pi * hz))

    b, a = signal.butter(2, p["INS_ACCEL_FILTER"], fs=RATE)
    na, nv, nz = split_ticks
    n = int(seconds * RATE)
    xs = [np.array([0.01, 0.0, 0.0])]  # 1 cm off the target
    us = [0.0] * (na + 1)
    e_v = i_v = e_a = i_a = thr = 0.0
    acc_in, acc_out = [0.0, 0.0], [0.0, 0.0]
    out = np.empty(n)
    for i in range(n):
        x = xs[-1]
        z_m = 100 * xs[max(i - nz, 0)][0]  # cm
        v_m = 100 * xs[max(i - nv, 0)][1]
        a_raw = 100 * (-x[1] / model.Td + model.K * x[2])
        a_m = (b[0] * a_raw + b[1] * acc_in[0] + b[2] * acc_in[1] - a[1] * acc_out[0] - a[2] * acc_out[1]) / a[0]
        acc_in, acc_out = [a_raw, acc_in[0]], [a_m, acc_out[0]]
        v_t = p["PSC_POSZ_P"] * (0.0 - z_m)
        e_v += alpha(p["PSC_VELZ_FLTE"]) * ((v_t - v_m) - e_v)
        i_v += e_v * p["PSC_VELZ_I"] * T
        a_t = p["PSC_VELZ_P"] * e_v + i_v
        e_a += alpha(p["PSC_ACCZ_FLTE"]) * ((a_t - a_m) - e_a)
        i_a += e_a * p["PSC_ACCZ_I"] * T  # AC_PID::update_i, ahead of the output
        thr_in = k * 0.001 * (p["PSC_ACCZ_P"] * e_a + i_a)
        thr += alpha(2.0) * (thr_in - thr)
        us.append(thr)
        xs.append(Phi @ x + Gam * us[-1 - na])
        out[i] = x[0]
    return out


def test_cascade_gain_margin_against_an_independent_simulation():
    """The exported values, flown as ArduPilot's code runs them on the split of smallest gain margin: the
    loop with the throttle scaled by 0.95 GM settles, by 1.05 GM it grows (the GM the export states, from
    the frequency response, is where the simulated loop turns unstable)."""
    design, clamped = design_z_cascade(_pd(), MODEL)
    assert not clamped
    p = design.gains.params()
    assert p["PSC_ACCZ_I"] > 0  # AC_PosControl::pre_arm_checks: "PSC_ACCZ_I must be > 0"
    assert not check_ranges("ardupilot", p)
    rows = design.figures.per_row
    i = min(range(len(rows)), key=lambda j: rows[j].gain_margin)
    s = design.figures.splits[i]
    ticks = tuple(int(round(v * RATE)) for v in (s.actuator_s, s.velocity_s, s.altitude_s))
    gm = rows[i].gain_margin
    assert math.isfinite(gm) and gm > 1.5

    def envelope(k: float) -> tuple[float, float]:
        z = _simulate(p, MODEL, ticks, k, 12.0)
        third = z.size // 3
        return float(np.max(np.abs(z[third:2 * third]))), float(np.max(np.abs(z[2 * third:])))

    mid, late = envelope(0.95 * gm)
    assert late < 0.7 * mid  # decays
    mid, late = envelope(1.05 * gm)
    assert late > 1.3 * mid  # grows


def test_cli_writes_the_param_file_with_the_assumption_first(tmp_path, capsys):
    from mrftcli.cli.main import main
    from mrftcli.tune.stacks import StackExport

    args = ["tune", "--tp", "0.0422", "--td", "2.669", "--tau", "0.040", "--k", "19.62", "--loop", "altitude",
            "--controller-rate", "200", "--export", "ardupilot", "--stack-version", "4.6"]
    with pytest.raises(SystemExit) as ex:
        main(args)
    err = capsys.readouterr().err
    assert ex.value.code == 2 and len(err.strip().splitlines()) == 1 and "--hover-thrust" in err
    out, js = tmp_path / "alt.param", tmp_path / "alt.json"
    try:
        main([*args, "--hover-thrust", "0.5", "--out", str(out), "--json", str(js)])
    except SystemExit as e:
        assert not e.code
    stdout = capsys.readouterr().out
    assert stdout.startswith("assumption: the split of tau 40 ms between the motors and the sensors")
    lines = out.read_text().splitlines()
    assert lines[1].startswith("# assumption:")
    values = dict(ln.split(",") for ln in lines if not ln.startswith("#"))
    assert set(values) >= {"PSC_POSZ_P", "PSC_VELZ_P", "PSC_ACCZ_P", "PSC_ACCZ_I", "INS_ACCEL_FILTER"}
    import json

    e = StackExport.from_json(json.loads(js.read_text())["export"]["stack"])
    from mrftcli.report.tune import export_section

    page = export_section(e)  # tune --report's section on the export: its assumption first
    assert page.index("Assumption:") < page.index("PSC_ACCZ_P") and "worst over the splits" in page
    assert e.assumptions and e.margins.Ms <= 1.6 + 1e-3 and e.params["PSC_VELZ_P"] == pytest.approx(float(values["PSC_VELZ_P"]), rel=1e-5)


def test_out_of_range_position_gain_is_refused_then_clamped_with_its_margins():
    slow = Controller(0.1, 0.0, 0.226, 0.0, RATE, RateFilter(0.0, "none"))  # Kp / Kd = 0.44 < PSC_POSZ_P's 1
    with pytest.raises(InputError, match=r"PSC_POSZ_P = Kp / Kd = 0.4425 is outside its range 1-3.*--clamp"):
        export_design("ardupilot", slow, MODEL, "altitude", "x", hover_thrust=0.5, version="4.6")
    e = export_design("ardupilot", slow, MODEL, "altitude", "x", hover_thrust=0.5, clamp=True, version="4.6")
    assert e.params["PSC_POSZ_P"] == 1.0 and e.clamped[0][:2] == ("PSC_POSZ_P", pytest.approx(0.1 / 0.226))
    assert any(n.startswith("PSC_POSZ_P set to 1") for n in e.notes) and e.margins.stable


def test_the_grid_bounds_splits_off_it():
    """The worst over the 37 grid splits is the worst over 200 random splits of tau too (to 0.5 %)."""
    from mrftcli.tune.ardupilot_z import DelaySplit, cascade_figures

    design, _ = design_z_cascade(_pd(), MODEL)
    rng = np.random.default_rng(7)
    splits = []
    for _ in range(200):
        ta = rng.uniform(0.0, MODEL.tau)
        splits.append(DelaySplit(ta, rng.uniform(0.0, MODEL.tau - ta), rng.uniform(0.0, MODEL.tau - ta)))
    grid, off = design.figures.worst(), cascade_figures(design.gains, [MODEL], splits).worst()
    assert off.stable and off.Ms <= grid.Ms * 1.005 and off.gain_margin >= grid.gain_margin / 1.005


def test_every_prearm_rule_of_the_written_values_passes_in_both_versions():
    """AC_PosControl::pre_arm_checks (POSZ_P, VELZ_P, ACCZ_P, ACCZ_I > 0; 4.7: D_POS_P, D_VEL_P, D_ACC_P, D_ACC_I)
    on the file's values; 4.7's names and scalings are 4.6's renamed, the _D_ACC_ gains x 0.1."""
    from mrftcli.tune.ardupilot_versions import to_46_units

    e46 = export_design("ardupilot", _pd(), MODEL, "altitude", "x", hover_thrust=0.5, version="4.6")
    e47 = export_design("ardupilot", _pd(), MODEL, "altitude", "x", hover_thrust=0.5, version="4.7")
    assert [r["rule"] for r in e46.prearm] == ["PSC_POSZ_P > 0", "PSC_VELZ_P > 0", "PSC_ACCZ_P > 0", "PSC_ACCZ_I > 0"]
    assert [r["rule"] for r in e47.prearm] == ["PSC_D_POS_P > 0", "PSC_D_VEL_P > 0", "PSC_D_ACC_P > 0",
                                               "PSC_D_ACC_I > 0"]
    assert all(r["passed"] for r in e46.prearm + e47.prearm)
    assert all(":18" in r["source"] for r in e46.prearm)  # the source line
    assert not any(n.startswith(("PSC_POSZ", "PSC_VELZ", "PSC_ACCZ")) for n in e47.params)
    assert e47.params["PSC_D_ACC_P"] == pytest.approx(0.1 * e46.params["PSC_ACCZ_P"])
    assert to_46_units(e47.params) == pytest.approx(e46.params, rel=1e-3)
    assert "Copter 4.7 parameter names" in e47.file_text().splitlines()[0]
    assert not check_ranges("ardupilot", e47.params) and not check_ranges("ardupilot", e46.params)


def test_a_failing_prearm_rule_is_a_refusal():
    from mrftcli.tune.ardupilot_versions import prearm_checks

    bad = prearm_checks({"PSC_ACCZ_I": 0.0, "PSC_ACCZ_P": 0.5, "ATC_RAT_RLL_I": 0.0}, "4.6")
    assert [(r.rule.rule, r.passed) for r in bad] == [("PSC_ACCZ_P > 0", True), ("PSC_ACCZ_I > 0", False),
                                                     ("ATC_RAT_RLL_I > 0", False)]
    assert "AC_PosControl.cpp:1860" in bad[1].rule.source


def test_the_cascade_holds_over_the_posterior_draws():
    """Held on the posterior's extreme draws: every draw of the 95 % set (not only those the design used), each
    over its own splits, has Ms within 2 % of the PD's own worst (the search's grid is coarser)."""
    from mrftcli.tune.ardupilot_z import cascade_figures
    from mrftcli.tune.design import Posterior
    from mrftcli.tune.margins import margins

    post = Posterior.from_spread(MODEL, 0.1, 0.004, 0.5, n=60, seed=3, source="test")
    draws = post.models(np.flatnonzero(post.in_set()))
    e = export_design("ardupilot", _pd(), MODEL, "altitude", "x", hover_thrust=0.5, version="4.6",
                      evidence=ExportEvidence(posterior_models=tuple(draws)))
    from mrftcli.tune.ardupilot_z import ZCascadeGains

    g = ZCascadeGains.from_params(e.params, RATE)
    target = max(margins(m, _pd()).Ms for m in [MODEL, *draws])
    worst = max(cascade_figures(g, [m], split_grid(m.tau)).worst().Ms for m in draws[::4])
    assert worst <= 1.02 * target and e.margins.Ms <= 1.02 * target
