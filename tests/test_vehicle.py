"""mrft-ident vehicle (issue 23): every loop of one flight found from its topics, identified, tuned; the
loops without tests named with what to fly; the vehicle record's round trip.

The flight is a HEAR-layout bag with roll tests, then y tests, each flown by the simulator on a known
plant of eq. (2): the simulator is the oracle, and the analysis shares no code with it.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_helpers import run_main

from mrftcli.mrft.model import soiptd_model
from mrftcli.errors import InputError, InsufficientDataError, SegmentationError
from mrftcli.io import write_log
from mrftcli.io.logtypes import TopicData
from mrftcli.mrft.model import LoopModel
from mrftcli.sim import FlightSpec, TestSpec, simulate_flight
from mrftcli.vehicle import (VEHICLE_ORDER, StackOptions, TuneOptions, VehicleOptions, VehicleResult, identify_vehicle,
                             loops_in_log, models_per_loop)
from mrftcli.vehicle.next_tests import NOT_FOLLOWING, missing_from_error

TP = 0.0422
ROLL = LoopModel(TP, 1.301, 0.0297, 30.0)


Y = LoopModel(TP, 2.0, 0.08, 1.0)


def _point(n: int, **columns: np.ndarray) -> dict[str, np.ndarray]:
    out = {c: np.zeros(n) for c in "xyz"}
    out.update(columns)
    return out


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A HEAR-layout bag (/angle_u, /opti/ori, /fh_des, /opti/pos): two roll tests, then two y tests.

    Each loop is flown by the simulator on its own plant of eq. (2) (the y plant standing for the closed
    roll loop and the translational dynamics), so both have a known truth.
    """
    roll = simulate_flight(FlightSpec(ROLL, (TestSpec(-0.5, 0.17, 10.0), TestSpec(-0.2, 0.17, 10.0)), loop="roll",
                                      hover_s=2.0, hold_s=2.0, seed=3))
    y = simulate_flight(FlightSpec(Y, (TestSpec(-0.6, 0.9, 14.0), TestSpec(-0.3, 0.35, 16.0)), loop="y",
                                   hover_s=2.0, hold_s=2.0, seed=4))
    t = np.concatenate([roll.t, y.t + roll.t[-1] + 0.005])
    quiet = np.random.default_rng(5)
    nr, ny = roll.t.size, y.t.size
    topics = [
        TopicData("/angle_u", "geometry_msgs/msg/Point", t, _point(t.size, x=np.r_[roll.command, np.zeros(ny)])),
        TopicData("/opti/ori", "geometry_msgs/msg/Point", t,
                  _point(t.size, x=np.r_[roll.output_measured, quiet.normal(0, 1e-3, ny)])),
        TopicData("/fh_des", "geometry_msgs/msg/Point", t,
                  _point(t.size, y=np.r_[np.zeros(nr), y.command], z=np.full(t.size, 9.81))),
        TopicData("/opti/pos", "geometry_msgs/msg/Point", t,
                  _point(t.size, y=np.r_[quiet.normal(0, 5e-4, nr), y.output_measured], z=np.ones(t.size))),
    ]
    return write_log(topics, tmp_path_factory.mktemp("vehicle") / "roll_y.bag", "bag")


@pytest.fixture(scope="module")
def result(flight):
    return identify_vehicle(flight, soiptd_model(TP), options=VehicleOptions(n_bootstrap=100))


def test_roll_and_y_identified_and_tuned_from_one_flight(result):
    assert list(result.loops) == ["roll", "y"]  # inner loop first
    roll = result.loops["roll"]
    assert (roll.role, roll.route) == ("inner", "eq2")
    y = result.loops["y"]
    assert (y.role, y.route) == ("outer", "eq2") and len(y.analysis.tests) == 2
    for entry, truth in ((roll, ROLL), (y, Y)):  # the flown plants (the simulator's truth) within 2 %
        a = entry.analysis
        assert a.Td.value == pytest.approx(truth.Td, rel=0.02)
        assert a.tau.value == pytest.approx(truth.tau, rel=0.02)
        assert a.K.value == pytest.approx(truth.K, rel=0.02)
    for entry in result.loops.values():
        assert entry.gains is not None and entry.gains.design == "robust"
        c = entry.gains.controller
        assert c.Kp > 0 and c.Kd > 0 and entry.gains.phase_margin_deg > 30


def test_outer_loop_on_eq2_is_said_first_naming_the_option(result):
    assert result.assumptions[0].startswith("y identified with eq. (2)")
    assert "--inner-gains" in result.assumptions[0]
    assert result.loops["y"].route_notes == (result.assumptions[0],)


def test_loops_without_tests_get_the_tests_to_fly(result, flight):
    assert loops_in_log(flight) == ("altitude", "x", "y", "roll", "pitch")  # the HEAR layout's topics are all there
    assert list(result.missing) == ["altitude", "pitch", "x"]
    for name, miss in result.missing.items():
        assert miss.reason == "no-tests"
        assert f"mrft-ident plan --tp {TP:g} --loop {name}" in miss.next_tests
    assert "pitch loop's new gains" in result.missing["x"].next_tests  # x rides on pitch


def test_record_round_trip(result):
    data = json.loads(json.dumps(result.to_json(), allow_nan=True))
    back = VehicleResult.from_json(data)
    assert json.loads(json.dumps(back.to_json(), allow_nan=True)) == data
    roll = data["loops"]["roll"]
    assert {"parameters", "tests", "model", "gains", "role", "route"} <= set(roll)
    assert set(roll["gains"]["generic"]) >= {"Kp", "Ki", "Kd", "Tf", "rate_hz"}
    assert back.loops["roll"].gains.controller == result.loops["roll"].gains.controller


@pytest.mark.parametrize("change, message", [
    ({"schema_version": 99}, "schema_version 99 is not supported"),
    ({"loops": {"yaw": {}}}, "unknown loop(s) yaw"),
    ({"missing": {"x": {"reason": "lost", "message": "", "next_tests": ""}}}, "'reason' must be one of"),
])
def test_record_refuses_bad_input_in_one_line(result, change, message):
    data = {**result.to_json(), **change}
    with pytest.raises(InputError, match="vehicle") as err:
        VehicleResult.from_json(data)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_models_per_loop():
    assert models_per_loop(soiptd_model(0.05)) == dict.fromkeys(VEHICLE_ORDER, soiptd_model(0.05))
    with pytest.raises(InputError, match="no Tp for the x, y loop"):
        models_per_loop({loop: soiptd_model(0.04) for loop in ("altitude", "roll", "pitch")})
    with pytest.raises(InputError, match="physical range"):
        models_per_loop(soiptd_model(42.2))  # 42.2 ms given in seconds


def test_shared_command_tests_of_another_loop_mean_no_tests():
    """The reference layout's /mrft/command serves every loop: tests the loop's output does not follow are
    another loop's, so the loop has none (not 'fly them again')."""
    err = SegmentationError("2 relay test(s) found on /mrft/command, but /imu/data pitch does not follow them")
    err.rejected_tests = [{"index": 0, "reason": f"{NOT_FOLLOWING}: output amplitude 0.2x the noise"}]
    miss = missing_from_error("pitch", err, TP, "f.mcap")
    assert miss.reason == "no-tests" and "another loop's tests" in miss.message


def test_single_beta_loop_gets_a_planned_second_test(tmp_path):
    flown = simulate_flight(FlightSpec(ROLL, (TestSpec(-0.5, 0.17, 10.0),), loop="roll", hover_s=2.0, hold_s=2.0))
    from mrftcli.analyze import analyze_flight
    from mrftcli.io import ReadOptions, read_flight

    path = write_log(flown.topics, tmp_path / "one_beta.mcap")
    with pytest.raises(InsufficientDataError) as err:
        analyze_flight(read_flight(path, ReadOptions(loop="roll")), soiptd_model(TP))
    miss = missing_from_error("roll", err.value, TP, str(path))
    assert miss.reason == "single-beta" and miss.plan is not None
    t = miss.plan.tests[0]  # the planner's recommendation, passed on as the hint
    assert -0.95 < t.beta < 0 and t.beta != -0.5 and f"beta {t.beta:+.2f}, h {t.h:.3g}" in miss.next_tests
    assert miss.plan.flown and miss.plan.flown[0].beta == pytest.approx(-0.5, abs=0.05)  # it counted the flown test
    assert any("--max-amplitude" in a for a in miss.plan.assumptions)  # the limits it took are stated


def test_stack_export_designs_with_the_stack_filter(result):
    """--export ardupilot: roll designed with the stack's gyro filter at its rate; a value below the stack's
    range is set to the bound with --clamp and the export says so."""
    from mrftcli.vehicle import tune_loop

    roll = tune_loop(result.loops["roll"].analysis, TuneOptions(stack=StackOptions("ardupilot", clamp=True)))
    assert roll.export is not None and roll.export.stack == "ardupilot" and roll.export_refused is None
    assert roll.tune.rate_filter is not None and roll.tune.rate_filter.parameter == "INS_GYRO_FILTER"
    assert roll.export.params["ATC_ANG_RLL_P"] >= 3.0  # ArduPilot's minimum
    assert all(n in " ".join(roll.export.notes) for n, _, _ in roll.export.clamped)


def test_cli_vehicle(flight, tmp_path):
    out_json, gains = tmp_path / "vehicle.json", tmp_path / "gains.json"
    proc = run_main("vehicle", str(flight), "--tp", str(TP), "-q", "--json", str(out_json), "--export", "generic",
                    "--out", str(gains))  # main() in this process (cli_helpers)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("assumption: y identified with eq. (2)")
    assert any(line.startswith("roll  inner  eq2") for line in lines)
    assert any("tau [ms]" in line for line in lines) and "rad/s² per command unit" in proc.stdout
    assert "Traceback" not in proc.stderr
    record = VehicleResult.from_json(json.loads(out_json.read_text()))
    assert list(record.loops) == ["roll", "y"]
    exported = json.loads(gains.read_text())  # the GAINS.json --inner-gains reads
    assert exported["roll"]["Kp"] == pytest.approx(record.loops["roll"].gains.controller.Kp)


def test_cli_vehicle_refuses_a_bad_ms_max_before_the_work(tmp_path, monkeypatch):
    """--ms-max 0.9 was taken: every loop analysed, then each 'not tuned' in a warning, exit 0, and --export generic
    --out wrote '{}'. Now the one-line refusal tune gives, exit 2, before any analysis, nothing written."""
    from pathlib import Path

    import mrftcli.vehicle

    def no_work(*args, **kwargs):
        raise AssertionError("vehicle analysed the log before checking --ms-max")

    monkeypatch.setattr(mrftcli.vehicle, "identify_vehicle", no_work)
    log = Path(__file__).resolve().parents[1] / "sample_logs" / "design1_roll.mcap"
    out = tmp_path / "g.json"
    proc = run_main("vehicle", str(log), "--tp", str(TP), "-q", "--ms-max", "0.9", "--export", "generic",
                    "--out", str(out))
    assert proc.returncode == 2 and proc.stderr == "error: --ms-max must be a number above 1, got 0.9\n"
    assert not out.exists()
    # --hover-thrust outside (0, 1): was ~10 s of analysis, the table on stderr and 'x: not exported: ...', exit 2
    proc = run_main("vehicle", str(log), "--tp", str(TP), "-q", "--export", "px4", "--hover-thrust", "1.5")
    assert proc.returncode == 2 and proc.stderr == "error: --hover-thrust must be a normalised thrust in (0, 1), got 1.5\n"


def test_batch_vehicle_writes_a_vehicle_record_per_log(tmp_path):
    """batch --vehicle: each log's record holds its vehicle record; the summary has a row per loop with the
    gains' tune_* figures, and the loops without tests skipped with the tests to fly."""
    from pathlib import Path

    from mrftcli.batch import BatchOptions, run_batch

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "design1_roll.mcap"
    res = run_batch([log], tmp_path / "out", defaults={"tp": TP},
                    options=BatchOptions(vehicle=True, jobs=1, report=False))
    record = json.loads(next((tmp_path / "out" / "logs").glob("*.json")).read_text())
    vehicle = VehicleResult.from_json(record["vehicle"])
    rows = res.summary.set_index("loop")
    assert rows.loc["roll", "status"] == "ok"
    assert rows.loc["roll", "tune_Kp"] == pytest.approx(vehicle.loops["roll"].gains.controller.Kp)
    assert rows.loc["roll", "Td_mean"] == pytest.approx(ROLL.Td, rel=0.02)
    assert rows.loc["pitch", "status"] == "skipped-no-tests" and "next: fly MRFT tests" in rows.loc["pitch", "error"]


def test_batch_vehicle_refuses_per_loop_options():
    from click.testing import CliRunner

    from mrftcli.cli.main import cli

    out = CliRunner().invoke(cli, ["batch", "x.mcap", "--tp", "0.04", "--vehicle", "--loop", "roll"])
    assert out.exit_code == 2 and "--vehicle finds each log's loops from its topics" in out.output


@pytest.fixture(scope="module")
def cascaded(tmp_path_factory):
    """A HEAR-layout flight from the cascade simulator: roll tests, then y tests through the roll loop closed
    by a PD at 100 Hz (the outer relay commands an acceleration, K = 1); the PD as GAINS.json."""
    from mrftcli.sim.cascade import inner_pd, simulate_cascade
    from mrftcli.sim.cascade_spec import CascadeSpec
    from mrftcli.sim.cascade_write import write_cascade

    gains = inner_pd(ROLL, 100.0)
    spec = CascadeSpec(ROLL, gains, Td=2.0, tau=0.03, axis="y", commanded="acceleration",
                       inner_tests=(TestSpec(-0.4, 0.12, 8.0), TestSpec(-0.7, 0.33, 6.0)),
                       outer_tests=(TestSpec(-0.4, 0.3, 24.0), TestSpec(-0.7, 0.9, 18.0)), seed=2, hover_s=2.0,
                       hold_s=2.0)
    path = tmp_path_factory.mktemp("cascade") / "cascade_y.bag"
    write_cascade(simulate_cascade(spec), path, "hear-ros")
    return path, {"roll": gains.to_json()}


def test_outer_loop_through_the_closed_inner_loop(cascaded):
    """With the inner gains flown, y is identified on the cascade (Td within 10 % of the simulator's, its
    interval covering tau) and tuned on the cascade closed by the roll loop's new gains."""
    path, gains = cascaded
    res = identify_vehicle(path, soiptd_model(TP), inner_gains=gains,
                           options=VehicleOptions(n_bootstrap=100, inner_draws=5))
    y = res.loops["y"]
    assert (y.role, y.route) == ("outer", "cascade")
    est = y.analysis.identification.parameters
    assert est["Td"].value == pytest.approx(2.0, rel=0.10)
    assert est["tau"].ci95_low <= 0.03 <= est["tau"].ci95_high
    assert any(a.startswith("y: the outer relay commands an acceleration") for a in res.assumptions[:6])
    assert not any("eq. (2)" in a for a in res.assumptions)  # nothing fell back
    roll_new = res.loops["roll"].gains.controller
    assert y.gains is not None and y.gains.tune.model.inner.controller.Kp == pytest.approx(roll_new.Kp)
    assert y.gains.phase_margin_deg >= 35
    back = VehicleResult.from_json(json.loads(json.dumps(res.to_json(), allow_nan=True)))
    assert back.loops["y"].route == "cascade" and back.loops["y"].gains.controller == y.gains.controller


def test_outer_design_keeps_the_flown_inner_loop_when_the_new_gains_run_through_a_rate_filter() -> None:
    """The cascade closes the inner loop through Tf only: new inner gains designed on a stack's rate filter
    (HEAR_FC's Butterworth) are not the loop it would model, so the outer gains are designed for the inner loop
    as flown and the sentence says why; without the filter the new gains close it."""
    from types import SimpleNamespace

    from mrftcli.mrft.cascade import InnerLoop
    from mrftcli.mrft.controller import Controller, RateFilter
    from mrftcli.mrft.model import LoopModel
    from mrftcli.vehicle.gains import _new_inner

    flown = InnerLoop(LoopModel(0.0422, 1.3, 0.03, 30.0), Controller(0.29, 0.0, 0.087, 0.03, 100.0), "roll")
    analysis = SimpleNamespace(model=SimpleNamespace(inner=flown))

    def inner(rate_filter: RateFilter | None) -> SimpleNamespace:
        c = Controller(0.54, 0.0, 0.18, 0.0 if rate_filter else 0.01, 100.0, rate_filter)
        return SimpleNamespace(loop="roll", gains=SimpleNamespace(controller=c))

    closed, said = _new_inner(analysis, inner(RateFilter(30.0, "HEAR_FC rate filter")))
    assert closed is flown and "rate filter, which the cascade does not model" in said
    closed, said = _new_inner(analysis, inner(None))
    assert closed.controller.Kp == 0.54 and "closed by its new gains" in said
