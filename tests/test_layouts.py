"""Flight-stack layouts: auto-detection, the sample logs each stack writes, few samples per cycle.

Oracles: the simulator's truth sidecars (sample_logs/*.truth.json, written by
scripts/make_sample_logs.py through mrftcli.io.stacks), closed forms for the per-cycle fit.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalyzeOptions, analyze_flight
from mrftcli.io import LAYOUTS, ReadOptions, detect_layout, log_layout, open_log, read_flight
from mrftcli.io.logtypes import TopicData
from mrftcli.segment.cycles import cycle_fundamental, harmonics_for

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"
STACK_LOGS = {"px4_altitude_10hz.ulg": "px4-mrft", "px4_altitude_50hz.ulg": "px4-mrft",
              "hear_x.bag": "hear-ros", "dnn_altitude.mat": "mat"}


def truth(name: str) -> dict:
    return json.loads((SAMPLES / f"{name}.truth.json").read_text())


@pytest.fixture(scope="module")
def analyses(shared_results) -> dict:
    """Each stack log read (the layout auto-detected, nothing named) and analysed: the analysis is
    test_analyze_sample_logs' (the same options; conftest.SharedResults)."""
    out = {}
    for name in STACK_LOGS:
        tr = truth(name)
        flight = read_flight(SAMPLES / name, ReadOptions(loop=tr["loop"]), echo_warnings=False)
        out[name] = (flight, shared_results.analysis(SAMPLES / name, soiptd_model(tr["Tp"]), ReadOptions(loop=tr["loop"]),
                                                     AnalyzeOptions(n_bootstrap=200)), tr)
    return out


@pytest.mark.parametrize("name", sorted(STACK_LOGS))
def test_stack_log_identifies_within_interval(analyses, name):
    flight, result, tr = analyses[name]
    assert flight.source["layout"].startswith(STACK_LOGS[name] + " (auto-detected")
    params = result.to_dict()["parameters"]
    for key in ("Td", "tau", "K"):
        p = params[key]
        assert p["ci95_low"] <= tr[key] <= p["ci95_high"], (name, key, p, tr[key])


def test_low_rate_log_interval_contains_truth_and_is_wider(analyses):
    low = analyses["px4_altitude_10hz.ulg"][1].to_dict()["parameters"]["tau"]
    high = analyses["px4_altitude_50hz.ulg"][1].to_dict()["parameters"]["tau"]
    assert low["ci95_high"] - low["ci95_low"] > 1.5 * (high["ci95_high"] - high["ci95_low"])
    flight = analyses["px4_altitude_10hz.ulg"][0]
    assert sum("SDLOG_PROFILE" in w for w in flight.warnings) == 1  # warned once, naming the fix


def test_px4_beta_and_windows_from_parameter_changes(analyses):
    flight, result, tr = analyses["px4_altitude_50hz.ulg"]
    assert flight.beta is not None
    np.testing.assert_allclose(flight.beta.values, [e["beta"] for e in tr["tests"]])
    np.testing.assert_allclose(flight.beta.t, [e["t_start"] for e in tr["tests"]], atol=0.03)
    windows = flight.source["test_windows"]
    np.testing.assert_allclose(np.array(windows, float), [[e["t_start"], e["t_end"]] for e in tr["tests"]],
                               atol=0.03)
    # NED z and upward-negative thrust turned into altitude up and thrust up: +h raises the output
    assert all(t.loop_sign == 1 for t in result.tests)
    assert abs(np.median(flight.output.values) - tr["setpoint"]) < 0.1


def test_receive_time_jitter_is_estimated(analyses):
    flight = analyses["hear_x.bag"][0]
    assert flight.timing.stamps == "receive"
    jitter = flight.timing.timing_jitter_s
    assert jitter is not None and 0.0003 < jitter < 0.005  # written with |N(0, 2 ms)| + 1 ms delays
    assert flight.source_json()["timing_jitter_s"] == jitter  # the --json output keeps its keys
    # folded into tau's interval (an offset between the topics' delays does not average out)
    result = analyses["hear_x.bag"][1]
    assert result.tau.std >= jitter
    assert result.tau.ci95_high - result.tau.ci95_low >= 2 * 1.96 * jitter
    assert any("timing jitter" in n for n in result.notes)
    assert not any("missing" in w for w in result.warnings)  # receive jitter is not a lost sample


@pytest.mark.parametrize("path", sorted(p.name for p in SAMPLES.iterdir()
                                        if not p.name.endswith((".json", ".md", ".py")) and p.name not in ("concealed", "sitl")
                                        and not p.name.startswith("__")))
def test_autodetection_picks_the_layout_of_every_sample_log(path):
    with open_log(SAMPLES / path, echo_warnings=False) as log:
        match = log_layout(log)
    assert match.detected
    assert match.layout.name == {**STACK_LOGS, "hear_cascade_y.bag": "hear-ros"}.get(path, "reference")


def test_detection_of_the_stacks_without_sample_logs():
    assert detect_layout(["/control_system_output", "/providers/z"], "bag").layout.name == "hear-2020"
    assert detect_layout(["/mavros/local_position/pose", "/mavros/imu/data"], "bag").layout.name == "mavros"
    assert detect_layout(["vehicle_local_position_setpoint"], "bag") is None  # PX4 writes ULog only
    # roll, pitch: scripts/sitl/px4/mrft_roll.patch
    assert set(LAYOUTS["px4-mrft"].loops) == {"altitude", "x", "y", "roll", "pitch"}


def test_named_layout_and_explicit_topics_override(tmp_path):
    name = "hear_x.bag"
    flight = read_flight(SAMPLES / name, ReadOptions(loop="x", layout="hear-ros"), echo_warnings=False)
    assert flight.source["layout"] == "hear-ros (--layout)"
    own = read_flight(SAMPLES / name, ReadOptions(loop="x", command_topic="/fh_des:x", output_topic="/opti/pos:x", layout="reference"), echo_warnings=False)
    np.testing.assert_array_equal(own.output.values, flight.output.values)
    from mrftcli.errors import LogReadError, OtherLoopError

    # an altitude log read as roll: its MRFT_Z_ENABLE changes say which loop was tested (before: "no topic
    # vehicle_torque_setpoint", which named no --loop); with the user's own command topic, the topic's error
    with pytest.raises(OtherLoopError, match=r"excite the altitude loop \(MRFT_Z_ENABLE\), not roll: give --loop altitude"):
        read_flight(SAMPLES / "px4_altitude_50hz.ulg", ReadOptions(loop="roll"), echo_warnings=False)
    with pytest.raises(LogReadError, match="no_such_topic"):
        read_flight(SAMPLES / "px4_altitude_50hz.ulg", ReadOptions(loop="roll", command_topic="no_such_topic:x"),
                    echo_warnings=False)


def test_mat_v73_reads_like_v5(tmp_path):
    from mrftcli.io.format_mat import write_mat

    t = np.arange(50) * 0.01
    topics = [TopicData("controller_output_2", "vector", t, {"data": np.sin(t)}),
              TopicData("z", "vector", t, {"data": np.cos(t)})]
    for v73 in (False, True):
        path = tmp_path / f"f{int(v73)}.mat"
        write_mat(topics, path, v73=v73)
        flight = read_flight(path, echo_warnings=False)
        assert flight.source["layout"].startswith("mat (auto-detected")
        np.testing.assert_allclose(flight.command.values, np.sin(t))
        np.testing.assert_allclose(flight.output.t, t)


@pytest.mark.parametrize("n", [8, 10, 16, 34])
def test_few_samples_per_cycle_still_measure_the_fundamental(n):
    # a pure integrator's triangle wave: G(j Omega) = 1 / (j Omega), phase -pi/2, |G| Omega = 1
    assert harmonics_for(n) >= 1
    P = 1.0
    t = (np.arange(n) + 0.3) * P / n
    y = np.where(t < P / 2, t, P - t)
    g = cycle_fundamental(t, y, 0.0, P / 2, P, 1.0)
    # fewer harmonics: the error grows from 0.017 rad / 0.1 % (34 samples) to 0.04-0.065 rad / 2 %
    # (8-20 samples) on this cycle (docs/log-layout.md, "few samples per cycle")
    assert abs(np.angle(g.response) + np.pi / 2) < (0.07 if n < 30 else 0.02)
    assert abs(abs(g.response) * 2 * np.pi / P - 1.0) < (0.025 if n < 30 else 0.002)
    assert harmonics_for(n - 1) < harmonics_for(40) and np.isnan(cycle_fundamental(t[:7], y[:7], 0, .5, 1, 1).response)


@pytest.mark.parametrize("loop", ["x", "y"])
def test_simulator_writes_x_and_y_as_positions(tmp_path, loop):
    # sim/flight writes a position loop as the motion-capture pose, the place the reference layout
    # reads x and y from (an attitude quaternion would be refused for a position loop)
    from mrftcli.io import write_log
    from mrftcli.mrft.model import LoopModel
    from mrftcli.sim.flight import FlightSpec, TestSpec, simulate_flight

    spec = FlightSpec(LoopModel(0.04, 1.5, 0.05, 5.0), (TestSpec(beta=-0.5, h=0.1, duration=3.0),),
                      loop=loop, hover_s=0.5, hold_s=0.5)
    flight = simulate_flight(spec)
    names = {tp.name for tp in flight.topics}
    assert "/mocap/pose" in names and "/imu/data" not in names
    assert flight.truth["units"]["output"] == "m" and flight.truth["noise_std"] == 0.0005
    path = tmp_path / "f.mcap"
    write_log(flight.topics, path, "mcap")
    log = read_flight(path, ReadOptions(loop=loop), echo_warnings=False)
    np.testing.assert_allclose(log.output.values, flight.output_measured)
    np.testing.assert_allclose(log.command.values, flight.command)


def test_controller_rate_from_the_layout_and_the_option():
    # PX4's position controller decides at 50 Hz while its logger keeps the command at 10 Hz: the
    # layout says so, an explicit rate overrides it, and a wrong rate moves tau by half its period
    log = SAMPLES / "px4_altitude_10hz.ulg"
    assert read_flight(log, echo_warnings=False).timing.controller_rate_hz == 50.0
    fast = read_flight(log, ReadOptions(controller_rate_hz=100.0), echo_warnings=False)
    assert fast.timing.controller_rate_hz == 100.0
    assert fast.source_json()["controller_rate_hz"] == 100.0
    plain = read_flight(SAMPLES / "design1_altitude.mcap", echo_warnings=False)
    assert plain.timing.controller_rate_hz is None and "controller_rate_hz" not in plain.source_json()
    tau50 = analyze_flight(read_flight(log, echo_warnings=False), soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=50)).tau.value
    tau100 = analyze_flight(fast, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=50)).tau.value
    assert tau100 - tau50 == pytest.approx(0.5 / 50.0 - 0.5 / 100.0, abs=2e-3)


def test_controller_rate_option_is_validated():
    from click.testing import CliRunner

    from mrftcli.cli.main import cli

    res = CliRunner().invoke(cli, ["analyze", str(SAMPLES / "px4_altitude_10hz.ulg"), "--tp", "0.0422",
                                   "--controller-rate", "0"])
    assert res.exit_code == 2 and "controller-rate" in res.output


def test_analyze_prints_the_layout_and_the_feedback_sign_with_its_evidence():
    from click.testing import CliRunner

    from mrftcli.cli.main import cli

    log = str(SAMPLES / "px4_altitude_50hz.ulg")
    res = CliRunner().invoke(cli, ["analyze", log, "--tp", "0.0422"])
    assert res.exit_code == 0, res.output
    assert "read as: layout px4-mrft (auto-detected" in res.output
    assert "feedback sign + (the output rises while the relay is high in 2/2 tests" in res.output
    # NED z kept as it is (down positive): the data show the sign flipped, and the model is the same
    flipped = CliRunner().invoke(cli, ["analyze", log, "--tp", "0.0422", "--output-scale", "1"])
    assert flipped.exit_code == 0, flipped.output
    assert "feedback sign - (the output falls while the relay is high in 2/2 tests" in flipped.output


def test_stack_log_spec_is_checked_and_a_mat_log_reads_back_its_arrays(tmp_path):
    from mrftcli.errors import InputError
    from mrftcli.io.stacks import StackLogSpec, StackTest, write_stack_log

    for bad in ({"layout": "ardupilot"}, {"bias": float("nan")}, {"log_rate_hz": 0.0}):
        with pytest.raises(InputError):
            StackLogSpec(**{"layout": "mat", "loop": "altitude", "bias": 0.5, **bad})
    spec = StackLogSpec("mat", "altitude", 0.5, [StackTest(1.0, 2.0, -0.5, 0.05)])
    assert spec.tests == (StackTest(1.0, 2.0, -0.5, 0.05),)
    t = np.arange(200) / 100.0
    command, output = 0.5 + 0.05 * np.sign(np.sin(2 * np.pi * t)), 1.0 + 0.01 * np.sin(2 * np.pi * t)
    path = write_stack_log(tmp_path / "f.mat", spec, t, command, output, 1.0)
    flight = read_flight(path, ReadOptions(loop="altitude"), echo_warnings=False)
    assert np.allclose(flight.command.values, command) and np.allclose(flight.output.values, output)


def test_the_exports_benchmark_quotes_hear_xs_px4_refusal_as_tune_gives_it(analyses):
    """docs/benchmarks/exports.md's hear_x px4 row is the refusal tune gives on this analysis at the sidecar's Tp
    (the row had been edited by hand to K 0.9768); the K it names is the simulation's, 1.0 (truth sidecar)."""
    from mrftcli.errors import InputError
    from mrftcli.tune.stacks import export_design

    result = analyses["hear_x.bag"][1]
    doc = (SAMPLES.parent / "docs" / "benchmarks" / "exports.md").read_text()
    row = next(ln for ln in doc.splitlines() if ln.startswith("hear_x.bag") and ln.split()[1] == "px4")
    from mrftcli.mrft.controller import Controller

    c = Controller(0.2, 0.0, 0.1, 0.0, 200.0)  # K is checked before the gains are looked at
    with pytest.raises(InputError) as err:
        export_design("px4", c, result.model, "x", "robust PD", hover_thrust=0.5)  # the benchmark's HOVER
    said = row.split("refused: ", 1)[1]
    assert str(err.value).startswith(said) and f"K {truth('hear_x.bag')['K']:.4g} m/s^2" in said
