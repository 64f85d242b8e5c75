"""Cascaded flights (issue 23) against independent oracles.

* the closed inner loop at low frequency against its closed form (type-1 plant, PD with the
  derivative on the measurement): T(1) = 1 and (1 - T)/(j omega) -> (1 + K Td Kd) / (K Td Kp);
* the whole flight, tick for tick, against an independent closed loop written here (scipy's ZOH
  discretisation, the PD and the relay rule of ``relay_rule.py``): identical switching ticks;
* the outer limit cycle's period against the describing function of the discrete G_outer;
* the phase-margin machinery: the gain at which the exact closed loop turns unstable equals the
  frequency response's gain margin;
* the truth record's round trip and its errors; the HEAR and reference layouts read back.
"""

from __future__ import annotations

import contextlib
import json
import math

import numpy as np
import pytest
from cli_helpers import run_main
from scipy.signal import cont2discrete

from mrftcli.errors import InputError
from mrftcli.io import read_flight
from mrftcli.io.flight import ReadOptions
from mrftcli.mrft.model import LoopModel
from mrftcli.sim.cascade import command_gain, inner_pd, plan_outer_test, simulate_cascade
from mrftcli.sim.cascade_plant import (cascade_plant, closed_loop_radius, controller_response,
                                       outer_phase_margin, outer_plant_response)
from mrftcli.sim.cascade_spec import CascadeSpec, CascadeTruth, InnerGains
from mrftcli.sim.cascade_write import write_cascade
from mrftcli.sim.flight import TestSpec as MrftTest
from mrftcli.sim.flight import plan_test, sidecar_path
from relay_rule import relay_step

ROLL = LoopModel(0.0422, 1.301, 0.0297, 30.0)
RATE = 200.0


def _spec(**kw) -> CascadeSpec:
    gains = inner_pd(ROLL, RATE)
    plant = cascade_plant(ROLL, 2.0, 0.03, RATE, 9.81)
    base = dict(inner=ROLL, gains=gains, Td=2.0, tau=0.03, axis="y", commanded="acceleration",
                inner_tests=(plan_test(ROLL, -0.5, math.radians(5), RATE, cycles=6),),
                outer_tests=(plan_outer_test(plant, gains, 1.0, -0.6, 0.1, cycles=6),), hover_s=1.0, hold_s=2.0)
    base.update(kw)
    return CascadeSpec(**base)


def _independent_flight(spec: CascadeSpec, n_ticks: int, ranges, kinds, hold: InnerGains):
    """The cascade as a plain per-tick loop: scipy's ZOH of the five states, whole-tick delays."""
    T = 1.0 / spec.rate_hz
    m = int(round(spec.inner.tau / T))
    n_y = int(round(spec.tau / T))
    K, Tp, Td = spec.inner.K, spec.inner.Tp, spec.inner.Td
    A = np.array([[0, 1, 0, 0, 0], [0, -1 / Td, K, 0, 0], [0, 0, -1 / Tp, 0, 0], [0, 0, 0, 0, 1],
                  [spec.g, 0, 0, 0, -1 / spec.Td]], float)
    B = np.array([[0], [0], [1 / Tp], [0], [0]], float)
    Ad, Bd, *_ = cont2discrete((A, B, np.eye(5), np.zeros((5, 1))), T, method="zoh")
    x = np.zeros(5)
    u_line = [0.0] * m
    y_hist = [0.0] * n_y
    conv = command_gain(spec.commanded, spec.g)
    g_in = spec.gains
    d_in = d_out = i_out = a_prev = y_prev = 0.0
    tests = (*spec.inner_tests, *spec.outer_tests)
    relay = [None] * len(tests)
    u_out, c_out = np.empty(n_ticks), np.empty(n_ticks)
    for k in range(n_ticks):
        y_m = y_hist[0] if n_y else x[3]
        alpha = x[0]
        j = next((i for i, (k0, k1) in enumerate(ranges) if k0 <= k < k1), -1)
        e_o = -y_m
        d_out = (hold.Tf * d_out - hold.Kd * (y_m - y_prev)) / (hold.Tf + T)
        y_prev = y_m
        if j >= 0 and kinds[j] == "outer":
            e = e_o
            if k == ranges[j][0]:
                relay[j] = (1.0 if e >= 0 else -1.0, e, False)
            s, ext, started = relay[j]
            if not started:  # the start: keep the sign until the error crosses zero (no noise: threshold 0)
                if s * e < 0:
                    s, ext, started = -s, e, True
            else:
                s, ext = relay_step(s, ext, e, tests[j].beta)
            relay[j] = (s, ext, started)
            c = s * tests[j].h
        else:
            if j < 0:
                i_out += hold.Ki * T * e_o
            c = hold.Kp * e_o + i_out + d_out
        ref = conv * c
        d_in = (g_in.Tf * d_in - g_in.Kd * (alpha - a_prev)) / (g_in.Tf + T)
        a_prev = alpha
        if j >= 0 and kinds[j] == "inner":
            e = -alpha
            if k == ranges[j][0]:
                relay[j] = (1.0 if e >= 0 else -1.0, e, False)
            s, ext, started = relay[j]
            if not started:
                if s * e < 0:
                    s, ext, started = -s, e, True
            else:
                s, ext = relay_step(s, ext, e, tests[j].beta)
            relay[j] = (s, ext, started)
            u = s * tests[j].h
        else:
            u = g_in.Kp * (ref - alpha) + d_in
        u_out[k], c_out[k] = u, c
        u_line.append(u)
        applied = u_line.pop(0)
        y_hist.append(x[3])
        if n_y:
            y_hist.pop(0)
        x = Ad @ x + Bd[:, 0] * applied
    return u_out, c_out


def test_flight_matches_an_independent_closed_loop_tick_for_tick():
    # whole-tick delays (30 ms inner, 20 ms position at 200 Hz) so scipy's plain ZOH is exact
    inner = LoopModel(0.0422, 1.301, 0.030, 30.0)
    gains = inner_pd(inner, RATE)
    spec = CascadeSpec(inner=inner, gains=gains, Td=2.0, tau=0.020, axis="y", commanded="attitude",
                       inner_tests=(MrftTest(-0.5, 0.15, 3.0),), outer_tests=(MrftTest(-0.6, 0.05, 8.0),),
                       attitude_noise_std=0.0, position_noise_std=0.0, hover_s=0.5, hold_s=1.5)
    flight = simulate_cascade(spec)
    n = flight.t.size
    k_in = int(round(0.5 * RATE))
    k_out = k_in + int(round(3.0 * RATE)) + int(round(1.5 * RATE))
    ranges = [(k_in, k_in + 600), (k_out, k_out + 1600)]
    u, c = _independent_flight(spec, n, ranges, ["inner", "outer"], flight.truth.outer_hold)
    np.testing.assert_allclose(flight.inner_command, u, atol=1e-8)
    np.testing.assert_allclose(flight.outer_command, c, atol=1e-8)
    sw = np.flatnonzero(np.diff(flight.outer_command[k_out:k_out + 1600]) != 0)
    assert sw.size >= 4  # the outer relay did oscillate


def _switch_period(t, c):
    sw = t[1:][np.diff(c) != 0]
    return float(np.median(np.diff(sw)[4:]) * 2.0)


def test_outer_limit_cycle_period_against_the_describing_function_of_g_outer():
    spec = _spec(attitude_noise_std=0.0, position_noise_std=0.0, inner_tests=(),
                 outer_tests=(MrftTest(-0.5, 0.5, 25.0),))
    flight = simulate_cascade(spec)
    test = flight.truth.tests_of("y")[0]
    sel = (flight.t >= test.t_start) & (flight.t < test.t_end)
    period = _switch_period(flight.t[sel], flight.outer_command[sel])
    # DF: arg G_outer(e^{j w T}) = -pi + asin(beta) on the exact discrete G_outer (half a tick of hold
    # is inside the discrete response already)
    plant = cascade_plant(spec.inner, spec.Td, spec.tau, spec.rate_hz, spec.g)
    w = np.geomspace(0.3, 30.0, 3000)
    phase = np.unwrap(np.angle(outer_plant_response(plant, spec.gains, command_gain(spec.commanded, spec.g), w)))
    target = -math.pi + math.asin(-0.5)
    i = int(np.flatnonzero(phase < target)[0])
    df_period = 2 * math.pi / w[i]
    assert period == pytest.approx(df_period, rel=0.04)


def test_gain_margin_matches_the_exact_closed_loop():
    spec = _spec()
    plant = cascade_plant(spec.inner, spec.Td, spec.tau, spec.rate_hz, spec.g)
    conv = command_gain(spec.commanded, spec.g)
    outer = InnerGains(1.0, 0.0, 1.0, 0.05, RATE)
    w = np.geomspace(0.05, 0.99 * math.pi * RATE, 6000)
    ce, d = controller_response(outer, w)
    L = (ce + d) * outer_plant_response(plant, spec.gains, conv, w)
    phase = np.unwrap(np.angle(L))
    i = int(np.flatnonzero(phase < -math.pi)[0])
    gm = 1.0 / abs(L[i])

    def scaled(k):
        return InnerGains(outer.Kp * k, 0.0, outer.Kd * k, outer.Tf, RATE)

    assert closed_loop_radius(plant, spec.gains, scaled(0.97 * gm), conv) < 1.0
    assert closed_loop_radius(plant, spec.gains, scaled(1.03 * gm), conv) > 1.0
    margin = outer_phase_margin(plant, spec.gains, scaled(0.5 * gm), conv)
    assert margin.stable and 0.0 < margin.phase_margin_deg < 90.0
    assert outer_phase_margin(plant, spec.gains, scaled(1.5 * gm), conv).phase_margin_deg == -math.inf


def test_unstable_inner_gains_are_refused():
    with pytest.raises(InputError, match="do not stabilise"):
        simulate_cascade(_spec(gains=InnerGains(20.0, 0.0, 0.0, 0.01, RATE)))


def test_truth_round_trip_and_errors():
    flight = simulate_cascade(_spec())
    data = json.loads(json.dumps(flight.truth.to_json()))
    back = CascadeTruth.from_json(data)
    assert back == flight.truth
    assert data["inner_gains"]["roll"] == flight.spec.gains.to_json()
    assert [t.loop for t in back.tests] == ["roll", "y"]
    with pytest.raises(InputError, match="schema_version"):
        CascadeTruth.from_json({**data, "schema_version": 99})
    bad = dict(data)
    del bad["outer"]
    with pytest.raises(InputError, match="missing"):
        CascadeTruth.from_json(bad)
    with pytest.raises(InputError, match="Kd"):
        InnerGains.from_json({"Kp": 1.0, "Ki": 0.0, "Tf": 0.01, "rate_hz": 200.0})


@pytest.mark.parametrize("axis", ["y", "x"])
def test_layouts_read_back(tmp_path, axis):
    spec = _spec(axis=axis, inner=LoopModel(0.0422, 1.6026, 0.0289, 25.0) if axis == "x" else ROLL,
                 inner_tests=(MrftTest(-0.5, 0.15, 2.0),), outer_tests=(MrftTest(-0.6, 0.5, 3.0),), hold_s=0.5)
    flight = simulate_cascade(spec)
    sign = 1.0 if axis == "y" else -1.0
    inner = flight.truth.inner_loop
    bag = tmp_path / "c.bag"
    side = write_cascade(flight, bag, "hear-ros")
    assert CascadeTruth.from_json(json.loads(side.read_text())).layout == "hear-ros"
    log = read_flight(bag, ReadOptions(loop=inner))
    assert "hear-ros" in log.source["layout"]
    np.testing.assert_allclose(log.command.values, sign * flight.inner_command, atol=1e-9)
    np.testing.assert_allclose(log.output.values, sign * flight.attitude_measured, atol=1e-9)
    log = read_flight(bag, ReadOptions(loop=axis))
    np.testing.assert_allclose(log.command.values, flight.outer_command, atol=1e-9)
    np.testing.assert_allclose(log.output.values, flight.position_measured, atol=1e-9)
    assert np.all(np.abs(log.command.t - flight.t) < 0.02)  # receive stamps: a few ms late
    ref = tmp_path / "c.mcap"
    write_cascade(flight, ref, "reference")
    log = read_flight(ref, ReadOptions(loop=axis))
    np.testing.assert_allclose(log.command.values, flight.outer_command, atol=1e-9)
    np.testing.assert_allclose(log.command.t, flight.t)
    log = read_flight(ref, ReadOptions(loop=inner, command_topic="/mrft/inner/command:data",
                                       beta_topic="/mrft/inner/beta:data"))
    np.testing.assert_allclose(log.command.values, sign * flight.inner_command, atol=1e-9)
    np.testing.assert_allclose(log.output.values, sign * flight.attitude_measured, atol=1e-6)
    assert sidecar_path(ref).exists()


INNER_CLI = ("--cascade", "y", "--inner-tp", "0.0422", "--inner-td", "1.301", "--inner-tau", "0.0297",
             "--inner-k", "30", "--td", "2", "--tau", "0.03", "--hover", "0.5", "--hold", "0.5")


def test_cli_cascade_writes_both_loops(tmp_path):
    gains = tmp_path / "gains.json"
    gains.write_text(json.dumps({"roll": {"Kp": 0.3, "Ki": 0.0, "Kd": 0.09, "Tf": 0.03, "rate_hz": 100.0}}))
    with contextlib.chdir(tmp_path):  # main() in this process (cli_helpers), relative paths as before
        res = run_main("simulate", *INNER_CLI, "--inner-test", "-0.5::2", "--test", "-0.5::4", "--inner-gains",
                       str(gains), "--out", "c.bag", "--json", "out.json")
    assert res.returncode == 0, res.stderr
    assert "assumption" not in res.stdout and "hear-ros layout" in res.stdout
    out = json.loads((tmp_path / "out.json").read_text())
    truth = CascadeTruth.from_json(out["truth"])
    assert truth.gains == InnerGains(0.3, 0.0, 0.09, 0.03, 100.0)  # the gains' rate: no --controller-rate given
    assert [t.loop for t in truth.tests] == ["roll", "y"] and truth.K == 1.0 and out["assumptions"] == []


def _main(capsys, *args):
    from mrftcli.cli.main import main

    try:
        main(["simulate", *args])
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    return code, capsys.readouterr()


def test_cli_cascade_states_its_assumption_and_refuses_bad_input(tmp_path, capsys):
    code, out = _main(capsys, *INNER_CLI, "--inner-test", "-0.5::1", "--out", str(tmp_path / "d.bag"))
    assert code == 0 and out.out.startswith("assumption: the inner roll PD")
    gains = tmp_path / "gains.json"
    gains.write_text(json.dumps({"pitch": {"Kp": 0.3, "Ki": 0.0, "Kd": 0.09, "Tf": 0.03, "rate_hz": 100.0}}))
    bag = str(tmp_path / "e.bag")
    for extra, message in ((("--inner-gains", str(gains), "--out", bag), "no gains for the roll loop"),
                           (("--k", "2", "--out", bag), "--k is not used with --cascade"),
                           (("--out", str(tmp_path / "e.mcap"), "--layout", "hear-ros"), "ROS 1 bag"),
                           (("--out", bag, "--inner-tp", "-1"), "Tp must be a positive")):
        code, out = _main(capsys, *INNER_CLI, "--test", "-0.5::4", *extra)
        assert code == 2 and message in out.err, out.err
    code, out = _main(capsys, "--inner-tp", "0.04", "--tp", "0.04", "--td", "1", "--tau", "0.03", "--test", "-0.5",
                      "--out", str(tmp_path / "f.mcap"))
    assert code == 2 and "--inner-tp needs --cascade" in out.err


# ------------------------------------------------------------------------------------------------
# simulate --model NAME: the process families of issue 22 through the one driver (mrftcli.sim.flight)


@pytest.mark.parametrize("family, params", [("sopdt", {"K": 1.5, "T1": 1.0, "T2": 0.3, "tau": 0.1234}),
                                            ("ipdt", {"K": 0.8, "tau": 0.3})])
def test_process_flight_matches_the_independent_process_sim(family, params):
    import process_sim

    from mrftcli.mrft.families import PROCESS_FAMILIES
    from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight

    model = PROCESS_FAMILIES[family](**params)
    test = plan_test(model, -0.3, 0.1, 100.0, cycles=5)
    flight = simulate_flight(FlightSpec(model, (test,), rate_hz=100.0, noise_std=0.0, hover_s=1.0, hold_s=5.0))
    n = int(round(test.duration * 100))
    window = process_sim.Window("mrft", test.h, -test.h, beta=-0.3, duration=test.duration)
    _, u, y = process_sim.simulate(family, params, [window], 100.0, 0.0, lead=1.0)
    np.testing.assert_allclose(flight.command[100:100 + n], u[100:100 + n], atol=1e-12)
    np.testing.assert_allclose(flight.output_true[:100 + n], y[:100 + n], atol=1e-9)
    assert np.count_nonzero(np.diff(flight.command[100:100 + n])) >= 6  # it oscillated
    assert abs(flight.output_true[-1]) < 0.02  # the hold brought it back


def test_an_effect_on_a_process_family_matches_the_independent_process_sim():
    # the one driver's effects serve every family: FOPDT seen through a first-order sensor lag is, to the
    # relay, the SOPDT of both lags; tests/process_sim.py flies that SOPDT (no code shared)
    import process_sim

    from mrftcli.mrft.families import PROCESS_FAMILIES
    from mrftcli.sim.flight import Effects, FlightSpec, TestSpec, simulate_flight

    test = TestSpec(-0.3, 0.5, 6.0)
    flight = simulate_flight(FlightSpec(PROCESS_FAMILIES["fopdt"](K=1.5, T=1.0, tau=0.1234), (test,), rate_hz=100.0,
                                        noise_std=0.0, hover_s=1.0, hold_s=2.0, effects=Effects(sensor_lag=0.3)))
    window = process_sim.Window("mrft", 0.5, -0.5, beta=-0.3, duration=6.0)
    _, u, y = process_sim.simulate("sopdt", {"K": 1.5, "T1": 1.0, "T2": 0.3, "tau": 0.1234}, [window], 100.0, 0.0,
                                   lead=1.0)
    np.testing.assert_allclose(flight.command[100:700], u[100:700], atol=1e-12)
    np.testing.assert_allclose(flight.output_measured[:700], y[:700], atol=1e-9)
    assert np.count_nonzero(np.diff(flight.command[100:700])) >= 6
    assert flight.truth["effects_active"] == ["sensor_lag"] and flight.truth["family"] == "fopdt"


def test_a_hysteresis_relay_on_a_process_family_matches_the_independent_process_sim():
    # TestSpec.eps: the simulator flies RelayLaw's hysteresis relay (as the KSTAR recordings' relay)
    import process_sim

    from mrftcli.mrft.families import PROCESS_FAMILIES
    from mrftcli.sim.flight import FlightSpec, TestSpec, simulate_flight

    params = {"K": 1.5, "T1": 1.0, "T2": 0.3, "tau": 0.1234}
    flight = simulate_flight(FlightSpec(PROCESS_FAMILIES["sopdt"](**params), (TestSpec(0.0, 0.5, 8.0, eps=0.05),),
                                        rate_hz=100.0, noise_std=0.0, hover_s=1.0, hold_s=2.0))
    window = process_sim.Window("hysteresis", 0.5, -0.5, eps=0.05, duration=8.0)
    _, u, y = process_sim.simulate("sopdt", params, [window], 100.0, 0.0, lead=1.0)
    np.testing.assert_allclose(flight.command[100:900], u[100:900], atol=1e-12)
    np.testing.assert_allclose(flight.output_true[:900], y[:900], atol=1e-9)
    assert np.count_nonzero(np.diff(flight.command[100:900])) >= 6 and flight.truth["tests"][0]["eps"] == 0.05
    with pytest.raises(InputError, match="hysteresis eps"):
        simulate_flight(FlightSpec(PROCESS_FAMILIES["sopdt"](**params), (TestSpec(0.0, 0.5, 8.0, eps=0.05),),
                                   switching="hear"))


def test_process_truth_and_cli_errors(tmp_path, capsys):
    from mrftcli.mrft.model import model_from_json

    code, out = _main(capsys, "--model", "foipdt", "--param", "K=0.8", "--param", "T=0.5", "--param", "tau=0.15",
                      "--test", "-0.3::6", "--hover", "1", "--hold", "1", "--out", str(tmp_path / "p.mcap"))
    assert code == 0 and "model foipdt" in out.out and "1 % of --amplitude" in out.out
    data = json.loads((tmp_path / "p.mcap.truth.json").read_text())
    model = model_from_json(data["model"])
    assert data["family"] == model.family == "foipdt" and model.tau == 0.15 and data["log_file"] == "p.mcap"
    assert data["parameters"] == {"K": 0.8, "T": 0.5, "tau": 0.15} and "Tp" not in data
    assert data["bias"] == 0.0 and data["setpoint"] == 0.0  # about its operating point
    for args, message in ((("--model", "ipdt", "--param", "K=1"), "needs --param tau=VALUE"),
                          (("--model", "ipdt", "--param", "K=1", "--param", "tau=0.1", "--param", "T=1"),
                           "--param T: --model ipdt has the parameters K, tau"),
                          (("--model", "fopdt", "--param", "K=1", "--param", "T=1", "--param", "tau=0.1", "--k", "2"),
                           "--k is not used with --model fopdt"),
                          (("--model", "fopdt", "--param", "K=1", "--param", "T=1", "--param", "tau=0.1",
                            "--effect", "quadratic_drag=1"), "quadratic_drag and thrust_rectification change eq. (2)"),
                          (("--param", "K=1", "--tp", "0.1", "--td", "1", "--tau", "0.1"), "--param needs --model")):
        code, out = _main(capsys, *args, "--test", "-0.3", "--out", str(tmp_path / "q.mcap"))
        assert code == 2 and message in out.err, out.err
