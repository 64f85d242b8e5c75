"""Issue 37: exports the stacks accept and fly as stated. HEAR's outer loops with their own filter (from
HEAR_FC's coefficients), HEAR's z command units, PX4 altitude designed inside its ranges (no --clamp), the
reboot-required parameters from the stacks' metadata."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from mrftcli.errors import InputError
from mrftcli.mrft.model import LoopModel
from mrftcli.tune.closed_loop import Controller, RateFilter
from mrftcli.tune.design import DesignOptions, Posterior, tune
from mrftcli.tune.stack_params import STACK_PARAMS, check_ranges, param
from mrftcli.tune.stacks import ExportEvidence, StackExport, export_design, stack_setting
from test_exports import HOVER, _loop_from_params, _ms_gm

#: HEAR_FC BWFilt2_coeff::coeff_120Hz_2nd_butter_5hz as HEAR writes it: {a1, a2, b0, b1, b2}
HEAR_OUTER = (-1.279632424997809, 0.477592250072517, 0.049489956268677, 0.098979912537354, 0.049489956268677)
ALT = LoopModel(0.0422, 2.669, 0.0464, 19.62)  # design1_altitude's truth


@pytest.mark.parametrize("loop", ["x", "y", "altitude"])
def test_hear_outer_loops_run_hear_fcs_outer_filter(loop):
    """The outer loops' filter is HEAR's own coefficients at the outer rate (200 Hz): its frequency response
    (HEAR's difference equation through scipy.freqz) is the design's filter's; the inner loops keep 50 Hz."""
    st = stack_setting("hear", loop, None, None, None)
    assert st.rate_hz == 200.0 and st.rate_filter is not None
    a1, a2, b0, b1, b2 = HEAR_OUTER
    w = np.linspace(0.01, 0.99, 200) * math.pi * st.rate_hz
    _, h = signal.freqz([b0, b1, b2], [1.0, a1, a2], worN=w, fs=2 * math.pi * st.rate_hz)
    ours = st.rate_filter.response(np.exp(1j * w / st.rate_hz), st.rate_hz)
    assert np.max(np.abs(ours - h)) < 1e-6
    assert stack_setting("hear", "roll", None, None, None).rate_filter.cutoff_hz == 50.0


def test_hear_z_command_in_hears_units_or_converted_with_the_assumption():
    st = stack_setting("hear", "altitude", None, None, None)
    c = Controller(0.53, 0.0, 0.226, 0.0, st.rate_hz, st.rate_filter)
    e = export_design("hear", c, ALT, "altitude", "x")  # K 19.6 per unit: a normalised thrust
    assert e.params["kp"] == pytest.approx(0.53 * ALT.K) and "HEAR's acceleration command" in e.assumptions[0]
    # flown on HEAR's plant (K = 1 per m/s^2 commanded), the converted gains give the margins stated
    w = np.geomspace(1e-3, 0.999, 3000) * math.pi * st.rate_hz
    ms, _ = _ms_gm(_loop_from_params("hear", "altitude", e.params, LoopModel(ALT.Tp, ALT.Td, ALT.tau, 1.0),
                                     st.rate_hz, st.rate_filter.cutoff_hz, w))
    assert e.margins.Ms == pytest.approx(ms, rel=5e-3)
    one = LoopModel(ALT.Tp, ALT.Td, ALT.tau, 1.0)
    e1 = export_design("hear", Controller(10.4, 0.0, 4.43, 0.0, st.rate_hz, st.rate_filter), one, "altitude", "x")
    assert e1.params["kp"] == 10.4 and not e1.assumptions and any("saturates at 22" in n for n in e1.notes)
    with pytest.raises(InputError, match="neither HEAR's acceleration command"):
        export_design("hear", c, LoopModel(ALT.Tp, ALT.Td, ALT.tau, 0.1), "altitude", "x")


def test_px4_altitude_designed_inside_the_ranges_without_clamp():
    """A robust PD wanting MPC_Z_P > 1.5 is exported inside PX4's ranges (no --clamp), with its cost stated,
    and the loop the written values give (recomputed from them alone) has the Ms the export states, within
    the PD's own worst."""
    post = Posterior.from_spread(ALT, 0.1, 0.004, 0.5, n=80, seed=5, source="test")
    rf = RateFilter(0.0, "none")
    res = tune(ALT, 100.0, posterior=post, loop="altitude", options=DesignOptions(kinds=("PD",), rate_filter=rf))
    c = res.get("robust", "PD").controller
    assert c.Kp / c.Kd > param("px4", "MPC_Z_P").maximum
    draws = post.models(np.flatnonzero(post.in_set()))
    e = export_design("px4", c, ALT, "altitude", "robust PD", hover_thrust=HOVER,
                      evidence=ExportEvidence(posterior_models=tuple(draws)))
    assert e.params["MPC_Z_P"] == pytest.approx(1.5) and not check_ranges("px4", e.params)
    assert any("its cost: IAE" in n for n in e.notes)
    w = np.geomspace(1e-3, 0.999, 3000) * math.pi * 100.0
    ms, _ = _ms_gm(_loop_from_params("px4", "altitude", e.params, ALT, 100.0, None, w))
    assert e.margins.Ms == pytest.approx(ms, rel=5e-3) and ms <= res.get("robust", "PD").margins.Ms * 1.05 + 0.1


def test_reboot_required_from_the_stacks_metadata():
    """IMU_GYRO_RATEMAX and IMU_INTEG_RATE (PX4 yaml reboot_required: true) and SCHED_LOOP_RATE (ArduPilot
    @RebootRequired: True) carry the flag; a written value with it is named in the notes."""
    flagged = {p.name for p in STACK_PARAMS if p.reboot_required}
    assert flagged == {"IMU_GYRO_RATEMAX", "IMU_INTEG_RATE", "SCHED_LOOP_RATE"}
    assert param("px4", "IMU_INTEG_RATE").default == 200.0  # imu_parameters.yaml
    from mrftcli.tune.margins import Margins
    from mrftcli.tune.stacks import _with_reboot_note

    e = StackExport("px4", "roll", "x", {"MC_ROLL_P": 4.0, "IMU_GYRO_RATEMAX": 400.0}, (),
                    Margins(2.0, 45.0, 0.01, 1.5, 1.0, 2.0, True), ())
    assert any(n.startswith("IMU_GYRO_RATEMAX take effect only after a reboot") for n in _with_reboot_note(e).notes)


def test_only_ardupilot_altitude_margins_are_labelled_the_worst_over_the_splits_of_tau():
    """The export's margins line said "(the worst over the splits of tau)" for any stated assumption: PX4's x export
    with the hover thrust read from the log, HEAR's command scale. Only ArduPilot's altitude cascade is held over
    the splits (tune.ardupilot_z)."""
    from mrftcli.report.tune import export_section
    from mrftcli.tune.margins import Margins

    m = Margins(2.0, 45.0, 0.01, 1.5, 1.0, 2.0, True)
    hover = StackExport("px4", "x", "robust PD", {"MPC_XY_P": 2.0}, (), m, (),
                        ("hover thrust 0.4911 (MPC_THR_HOVER, normalised) read from the log",))
    z = StackExport("ardupilot", "altitude", "robust PD", {"PSC_POSZ_P": 1.0}, (), m, (),
                    ("the split of tau 46 ms between the motors and the sensors is not identifiable",))
    assert "splits of tau" not in export_section(hover) and "Assumption:</b> hover thrust 0.4911" in export_section(hover)
    assert "Margins with the stack's filter and rate (the worst over the splits of tau)" in export_section(z)
    from mrftcli.cli.tune import stack_summary  # the terminal's lines alike

    assert not any("splits of tau" in line for line in stack_summary(hover, console=False))
    assert any(line.startswith("margins with the stack's filter and rate (the worst over the splits of tau)")
               for line in stack_summary(z, console=False))


def test_generic_export_carries_its_units_in_the_file(tmp_path):
    """tune --export generic: the file says the unit of every number (the output's from the loop)."""
    import json

    from mrftcli.cli.main import main

    out = tmp_path / "g.json"
    try:
        main(["tune", "--tp", "0.0499", "--td", "0.887", "--tau", "0.0228", "--k", "20", "--loop", "roll",
              "--controller-rate", "200", "--export", "generic", "--out", str(out), "-q"])
    except SystemExit as e:
        assert not e.code
    data = json.loads(out.read_text())
    assert data["units"]["Kp"] == "command unit per rad" and data["units"]["Tf"] == "s"
    assert data["units"]["rate_hz"] == "Hz" and data["loop"] == "roll" and data["Kp"] > 0


def test_tune_report_shows_the_generic_file_tune_writes(tmp_path):
    """tune --report's recommended design shows its generic export as tune --export generic writes it (the loop and
    the units included: the page showed the controller without them)."""
    from mrftcli.cli.main import main
    from mrftcli.report._common import esc

    out, report = tmp_path / "g.json", tmp_path / "report"
    try:
        main(["tune", "--tp", "0.0499", "--td", "0.887", "--tau", "0.0228", "--k", "20", "--loop", "roll",
              "--controller-rate", "200", "--export", "generic", "--out", str(out), "--report", str(report), "-q"])
    except SystemExit as e:
        assert not e.code
    text = out.read_text()
    assert '"units"' in text and '"loop": "roll"' in text
    assert f"<pre>{esc(text)}</pre>" in (report / "index.html").read_text()


def test_ardupilot_roll_export_passes_every_prearm_rule_on_its_values():
    """AC_AttitudeControl::pre_arm_checks (ANG P > 0; rate P, I > 0 with FF 0; D >= 0) and the ACRO_BAL check
    (angle P at least ACRO_BAL_*, whose documented maximum is 3), each with its source line."""
    m = LoopModel(0.0499, 0.887, 0.0228, 20.0)
    st = stack_setting("ardupilot", "roll", None, None, None)
    res = tune(m, st.rate_hz, loop="roll", options=DesignOptions(kinds=("PD",), designs=("model-based",),
                                                                rate_filter=st.rate_filter))
    e = export_design("ardupilot", res.designs[0].controller, m, "roll", "x", clamp=True)
    rules = {r["rule"]: r for r in e.prearm}
    assert set(rules) == {"ATC_ANG_RLL_P > 0", "ATC_ANG_RLL_P >= ACRO_BAL_ROLL (<= 3)", "ATC_RAT_RLL_P > 0",
                          "ATC_RAT_RLL_I > 0", "ATC_RAT_RLL_D >= 0"}
    assert all(r["passed"] for r in e.prearm) and e.version == "4.7"
    assert rules["ATC_RAT_RLL_I > 0"]["source"].startswith("libraries/AC_AttitudeControl/AC_AttitudeControl.cpp:1454")


def test_ardupilot_roll_designed_inside_the_ranges_without_clamp():
    """A PD whose ATC_ANG_RLL_P = Kp / Kd falls below ArduPilot's 3 is exported at 3 with the ATC_RAT_RLL_P of least
    IAE holding its Ms (no --clamp); the values, recomputed alone (ATC_RAT_RLL_I at its minimum 0.01), give the
    Ms stated, within the PD's own."""
    m = LoopModel(0.0422, 1.301, 0.0297, 30.0)  # design1_roll's truth
    st = stack_setting("ardupilot", "roll", None, None, None)
    c = Controller(0.25, 0.0, 0.1, 0.0, st.rate_hz, st.rate_filter)  # Kp / Kd = 2.5 < 3

    e = export_design("ardupilot", c, m, "roll", "x")
    assert e.params["ATC_ANG_RLL_P"] == pytest.approx(3.0) and not check_ranges("ardupilot", e.params)
    assert any("designed inside" in n and "its cost: IAE" in n for n in e.notes)
    w = np.geomspace(1e-3, 0.999, 3000) * math.pi * st.rate_hz
    ms, _ = _ms_gm(_loop_from_params("ardupilot", "roll", e.params, m, st.rate_hz, st.rate_filter.cutoff_hz, w))
    assert e.margins.Ms == pytest.approx(ms, rel=5e-3)
    assert ms < 1.46  # better than the clamped design (Ms 1.46 at ATC_ANG_RLL_P 3, ATC_RAT_RLL_P 0.1)
