"""PX4 SITL ULogs (sample_logs/sitl/px4_*.ulg, flown by scripts/sitl/px4/, issue 42), analysed without SITL.

The logs are PX4's own ULogs (PX4 main of 2024-08 with the MRFT of abdullaayyad96/PX4-Autopilot
ported by ``scripts/sitl/px4/mrft_port.patch``; the newer ones shortened by ``trim_ulog.py``, PX4's
messages kept byte for byte): the relay is the fork's C++ block in ``mc_pos_control``, the physics
SIH's quadrotor, the estimate EKF2's. Each has a sidecar ``*.ulg.json`` saying how it was flown (loop,
SIH's parameters, beta and h of each test, the delay added inside the firmware). Asserted is what
the data show (docs/benchmarks/sitl.md#px4), against oracles the logs do not carry: SIH's source
constants (Td = m / SIH_KDV = 1 s, K = 4 SIH_T_MAX / m = 20 m/s^2), the delay PX4 realised (the
relays' decision against the attitude setpoint, logged), and each test's frequency predicted from
the other tests. The first pair (h 0.05: the switching drowned in EKF2's noise) misses the held-out
and delay figures; the fresh pair at h 0.25 meets them.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).parents[1]
LOGS = ROOT / "sample_logs" / "sitl"
sys.path.insert(0, str(ROOT / "scripts" / "sitl"))

sys.path.insert(0, str(ROOT / "scripts" / "sitl" / "px4"))

from px4_campaign import bench_tp, realised_delay, sih_implied  # noqa: E402
from sitl_analysis import analyze_log, held_out  # noqa: E402

from mrftcli.io import read_flight  # noqa: E402
from mrftcli.io.flight import ReadOptions  # noqa: E402
from mrftcli.segment.segmenter import segment  # noqa: E402

SIDECARS = sorted(LOGS.glob("px4_*.ulg.json"))
pytestmark = pytest.mark.skipif(not SIDECARS, reason="no PX4 SITL sample logs")


def _names() -> list[str]:
    """The MRFT flights (a sidecar listing its tests); not the export's step flights (px4_x_steps)."""
    return [p.name[: -len(".ulg.json")] for p in SIDECARS if "tests" in json.loads(p.read_text())]


@pytest.fixture
def px4_flight(shared_results):
    """``px4_flight(name)``: a flight's sidecar and its analysis (``analyze_log``), computed once per session and
    shared by the tests of every xdist worker (conftest.SharedResults: a fresh record each call)."""
    from mrftcli.analyze import AnalysisResult

    def get(name: str):
        side = json.loads((LOGS / f"{name}.ulg.json").read_text())
        log = LOGS / f"{name}.ulg"
        res = shared_results.get("px4_sitl_analyze_log", (shared_results.log_key(log), side["tp_s"], side["loop"]),
                                 lambda: analyze_log(log, side["tp_s"], side["loop"]), AnalysisResult.to_json,
                                 AnalysisResult.from_json)
        return side, res

    return get


@pytest.mark.parametrize("name", _names())
def test_layout_and_test_windows_from_the_parameter_changes(name: str) -> None:
    from mrftcli.io import read_flight
    from mrftcli.io.flight import ReadOptions

    side = json.loads((LOGS / f"{name}.ulg.json").read_text())
    flight = read_flight(LOGS / f"{name}.ulg", ReadOptions(loop=side["loop"]))
    assert flight.source["layout"].startswith("px4-mrft (auto-detected")
    # the windows come from MRFT_Z_ENABLE's logged changes, one per flown test
    assert len(flight.source["test_windows"]) == len(side["tests"])


@pytest.mark.parametrize("name", ["px4_altitude", "px4_altitude_h25", "px4_altitude_h25_20ms", "px4_x", "px4_y"])
def test_every_flown_test_is_found_with_its_beta_and_h(name: str, px4_flight) -> None:
    side, res = px4_flight(name)
    flown = [(t["beta"], t["h"]) for t in side["tests"]]
    found = [(t.beta_nominal, t.h) for t in res.tests]
    assert len(found) == len(flown)
    for (b0, h0), (b1, h1) in zip(flown, found):
        assert b1 == pytest.approx(b0, abs=1e-6)
        assert h1 == pytest.approx(h0, rel=0.05)  # h from the command's levels (hover estimate moves)
    if side["loop"] == "altitude" and not side["added_delay_ms"]:
        assert res.Td.value == pytest.approx(1.0, rel=0.2)  # SIH: m / SIH_KDV = 1 kg / (1 N s/m)
        assert res.K.value == pytest.approx(20.0, rel=0.2)  # SIH: 4 x SIH_T_MAX / SIH_MASS


def test_the_fresh_pair_predicts_each_held_out_frequency_within_5_percent(px4_flight) -> None:
    """h 0.25 (limit cycles of 3-33 cm over EKF2's 2 cm noise): each test's frequency from the model of the
    other three, within 5 % in both flights (measured: within 1.7 %); the h 0.05 pair misses (benchmark)."""
    for name in ("px4_altitude_h25", "px4_altitude_h25_20ms"):
        side, res = px4_flight(name)
        misses: list[tuple[int, str]] = []
        held = held_out(LOGS / f"{name}.ulg", side["tp_s"], side["loop"], res, refine=False, misses=misses)
        assert not misses and len(held) == 4
        for ho in held:
            assert abs(ho.error) <= 0.05, (name, ho)


def test_the_delay_realised_in_the_log_comes_back_in_tau(px4_flight) -> None:
    """MRFT_DELAY 20 ms holds the decision until the first output at least 20 ms old: 3 ticks of
    mc_pos_control's 8 ms, 24 ms, which the log shows (decision -> vehicle_attitude_setpoint); tau of
    the fresh pair rises by that within 2 ms (22.2 ms measured; the development pair at h 0.15: 33.8)."""
    assert realised_delay(LOGS / "px4_altitude_h25.ulg", 0.1).startswith("0.0 ms median")
    assert realised_delay(LOGS / "px4_altitude_h25_20ms.ulg", 0.1).startswith("24.0 ms median")
    _, res0 = px4_flight("px4_altitude_h25")
    _, res1 = px4_flight("px4_altitude_h25_20ms")
    assert res1.tau.value - res0.tau.value == pytest.approx(0.024, abs=0.002)


def test_added_delay_shows_in_tau(px4_flight) -> None:
    side0, res0 = px4_flight("px4_altitude")
    side1, res1 = px4_flight("px4_altitude_20ms")
    added = (side1["added_delay_ms"] - side0["added_delay_ms"]) / 1e3
    assert added == pytest.approx(0.020)
    # beta -0.2 under MRFT_DELAY 20 ms keeps too few stable cycles; the other three are found
    assert [t.beta_nominal for t in res1.tests] == pytest.approx([-0.4, -0.55, -0.7], abs=1e-6)
    # the delay is inside the loop (the effective betas stay near the nominal ones) ...
    for t in res1.tests:
        assert t.beta_effective == pytest.approx(t.beta_nominal, abs=0.05)
    # ... and comes back in tau, but 27.7 ms, not 20 +- 2 ms, on these noisy logs (docs/benchmarks/sitl.md)
    assert 0.010 <= res1.tau.value - res0.tau.value <= 0.040


@pytest.mark.parametrize("before, loop, output, realised", [
    ("px4_altitude_h25", "altitude", None, 0.024),
    ("px4_pitch_h", "pitch", "vehicle_attitude_groundtruth:q", 0.020),
    ("px4_pitch_h", "pitch", None, 0.020)], ids=["altitude", "pitch-sih", "pitch-ekf2"])
def test_mrft_ident_delay_gives_back_the_delay_px4_realised(before: str, loop: str, output: str | None,
                                                             realised: float) -> None:
    """``mrft-ident delay`` (compare/delay.py: one Td and K for both flights, a delay each) on the committed
    PX4 pairs: the increment is the delay the log shows PX4 realised (altitude: 3 ticks of 8 ms, 24.0 ms;
    pitch: 5 ticks of 4 ms, 20.0 ms, measured on SIH's attitude at the bench Tp, and on EKF2's at SIH_T_TAU,
    whose plain flight leads eq. (2) by ~3 ms: a negative tau, which delay takes) within 2 ms, inside the stated
    95 % interval, with SIH's Td and K (m / SIH_KDV; pitch: SIH's torque constants) within 10 % / 5 % (on EKF2's
    with tau held at 0 the fit bent Td to 0.74 s)."""
    from mrftcli.compare.delay import delay_increment

    tp = bench_tp() if output else json.loads((LOGS / f"{before}.ulg.json").read_text())["tp_s"]
    result = delay_increment(LOGS / f"{before}.ulg", LOGS / f"{before}_20ms.ulg", tp,
                             read=ReadOptions(loop=loop, output_topic=output))
    inc = result.increment
    assert inc.value == pytest.approx(realised, abs=0.002) and inc.ci95_low < realised < inc.ci95_high
    sih = sih_implied(loop)
    assert result.Td.value == pytest.approx(sih["Td"], rel=0.10)
    assert result.K.value == pytest.approx(sih["K"], rel=0.12 if loop == "altitude" else 0.05)


def _px4_logger_interval(t: np.ndarray, interval_s: float) -> np.ndarray:
    """Indices PX4's logger keeps of a topic published at ``t`` with a logging interval
    (uORB ``SubscriptionInterval``: a message at least ``interval`` after the last update, which moves
    on by ``interval``, kept within one interval of now): the logger's rule, written from its source."""
    keep, last = [], -np.inf
    for i, now in enumerate(np.round(t * 1e6)):
        if now - last >= interval_s * 1e6:
            keep.append(i)
            last = min(max(last + interval_s * 1e6, now - interval_s * 1e6), now)
    return np.array(keep)


def _thrust(z_thrust: np.ndarray) -> dict[str, np.ndarray]:
    zero = np.zeros(z_thrust.size)
    return {"thrust[0]": zero, "thrust[1]": zero, "thrust[2]": z_thrust, "z": zero - 5.0}


def test_the_relay_rate_is_read_from_the_log(tmp_path: Path) -> None:
    """mc_pos_control publishes one setpoint a cycle: 125 Hz in this SITL (the fork's v1.11 ran it at
    50 Hz, the layout's fallback): read from the command logged at every publication, and from the
    same command sub-sampled to 10 Hz by PX4's logger rule (intervals of 96 and 104 ms, multiples of 8)."""
    from mrftcli.io import read_flight
    from mrftcli.io.flight import ReadOptions
    from mrftcli.io.format_ulog import write_ulog
    from mrftcli.io.logtypes import TopicData

    full = read_flight(LOGS / "px4_altitude.ulg", ReadOptions(loop="altitude"), echo_warnings=False)
    assert full.timing.controller_rate_hz == pytest.approx(125.0, rel=1e-6)
    assert full.source["controller_rate"].startswith("125 Hz from the log")
    c, y = full.command, full.output
    k = _px4_logger_interval(c.t, 0.1)
    j = _px4_logger_interval(y.t, 0.1)
    topics = [TopicData("vehicle_local_position_setpoint", "px4", c.t[k],
                        _thrust(-c.values[k])),
              TopicData("vehicle_local_position", "px4", y.t[j], {"z": -y.values[j]})]
    path = tmp_path / "px4_10hz.ulg"
    write_ulog(topics, path)
    low = read_flight(path, ReadOptions(loop="altitude"), echo_warnings=False)
    assert low.timing.controller_rate_hz == pytest.approx(125.0, rel=1e-3)
    assert "multiples of 8 ms" in low.source["controller_rate"]
    assert not any("assumed" in w for w in low.warnings)
    # every interval the same multiple of the tick (a 10 Hz log of 50 Hz): the fallback, said
    even = tmp_path / "px4_even.ulg"
    t = c.t[0] + 0.1 * np.arange(400)
    write_ulog([TopicData("vehicle_local_position_setpoint", "px4", t, _thrust(-np.interp(t, c.t, c.values))),
                TopicData("vehicle_local_position", "px4", t, {"z": -np.interp(t, y.t, y.values)})], even)
    assumed = read_flight(even, ReadOptions(loop="altitude"), echo_warnings=False)
    assert assumed.timing.controller_rate_hz == 50.0 and assumed.timing.controller_rate_assumed
    assert assumed.source["controller_rate"].startswith("50 Hz assumed")
    assert sum("controller rate 50 Hz assumed" in w and "--controller-rate" in w for w in assumed.warnings) == 1
    given = read_flight(even, ReadOptions(loop="altitude", controller_rate_hz=125.0), echo_warnings=False)
    assert given.timing.controller_rate_hz == 125.0 and "controller_rate" not in given.source
    assert not given.timing.controller_rate_assumed


def test_roll_relay_in_the_rate_controller_is_found_and_identified_with_a_lead_at_sihs_tp() -> None:
    """mrft_roll.patch: the fork's relay on the roll angle as mc_rate_control's roll torque. Every test is
    found from MRFT_R_ENABLE's windows, with its beta; identification at SIH's motor lag (Tp = SIH_T_TAU)
    gives a lead (tau < 0: EKF2's attitude leads SIH's by 2-4 ms, docs/benchmarks/sitl.md#px4), stated first
    as an assumption, with SIH's K (refused as 'a negative delay' before eq. (2) admitted a lead)."""
    side = json.loads((LOGS / "px4_roll.ulg.json").read_text())
    flight = read_flight(LOGS / "px4_roll.ulg", ReadOptions(loop="roll"), echo_warnings=False)
    assert flight.source["command"] == "vehicle_torque_setpoint:xyz[0]"
    assert flight.timing.controller_rate_hz == pytest.approx(250.0, rel=1e-3)  # the rate controller's
    tests = segment(flight)
    assert [t.beta_nominal for t in tests] == pytest.approx([t["beta"] for t in side["tests"]], abs=1e-6)
    assert all(t.h == pytest.approx(0.05, rel=0.02) and t.n_stable >= 10 for t in tests)
    assert [t.frequency_hz_mean for t in tests] == sorted(t.frequency_hz_mean for t in tests)
    res = analyze_log(LOGS / "px4_roll.ulg", side["tp_s"], "roll")
    assert -0.006 < res.tau.value < -0.001 and res.model.tau == pytest.approx(res.tau.value)
    assert res.notes[0].startswith("assumed: the loop leads eq. (2)")
    assert res.K.value == pytest.approx(sih_implied("roll")["K"], rel=0.05)


def test_a_relay_hidden_by_the_controllers_own_output_is_looked_for_in_the_logged_windows() -> None:
    """Between tests the command is the loop's own controller (a rate controller's torque on gyro noise, and
    the take-off's): noise larger than the relay's steps sets the whole log's jump threshold above them.
    The windows PX4 logs (MRFT_R_ENABLE) are searched then: the same three tests come back."""
    import dataclasses

    from mrftcli.io.logtypes import Signal

    flight = read_flight(LOGS / "px4_roll.ulg", ReadOptions(loop="roll"), echo_warnings=False)
    c, y = flight.command, flight.output
    rng = np.random.default_rng(3)
    t_pre = c.t[0] - 30.0 + np.arange(7500) / 250.0  # 30 s of a noisy controller before the tests
    noisy = Signal(np.r_[t_pre, c.t], np.r_[rng.normal(0.0, 0.3, t_pre.size), c.values])
    out = Signal(np.r_[t_pre, y.t], np.r_[np.zeros(t_pre.size), y.values])
    hidden = dataclasses.replace(flight, command=noisy, output=out)
    from mrftcli.segment.segmenter import SegmentOptions, segment_arrays

    assert not segment_arrays(noisy, out, beta=flight.beta, options=SegmentOptions(controller_rate_hz=250.0))
    found = segment(hidden)
    assert [t.beta_nominal for t in found] == pytest.approx([t.beta_nominal for t in segment(flight)])


def test_held_out_masks_keep_each_tests_parameter_marker(px4_flight) -> None:
    """A PX4 test's beta is the MRFT_Z_BETA in force when MRFT_Z_ENABLE went to 1, logged before its first
    switch: each other test's window opens at that marker, so the masked log keeps the tests apart (a window
    cut at the first switch merged neighbours of different beta: 3 of 7 refused on these logs)."""
    for name, n in (("px4_altitude", 4), ("px4_altitude_20ms", 3)):
        side, res = px4_flight(name)
        misses: list[tuple[int, str]] = []
        held = held_out(LOGS / f"{name}.ulg", side["tp_s"], side["loop"], res, refine=False, misses=misses)
        assert not misses and len(held) == n
        for ho in held:  # each from a model of the others, all of them distinct tests
            assert ho.beta == pytest.approx(res.tests[ho.index].beta_nominal)


def test_a_bench_test_on_sih_measures_the_motor_lag_of_its_step() -> None:
    """sih.cpp steps each motor u += dt / SIH_T_TAU (u_sp - u) once per 4 ms step: a step response sampled
    at SIH's steps is an exponential of 47.97 ms (not 50), from the first step that reads the command."""
    dt, tau = 0.004, 0.05
    u, resp = 0.0, []
    for _ in range(200):  # the recursion itself, as sih.cpp runs it
        u += dt / tau * (1.0 - u)
        resp.append(u)
    k = np.arange(1, 201)
    slope = np.polyfit(k * dt, np.log(1.0 - np.array(resp)), 1)[0]
    assert -1.0 / slope == pytest.approx(bench_tp(), rel=1e-9)
    assert bench_tp() == pytest.approx(0.04797, abs=1e-5)


def test_pitch_has_a_lead_on_ekf2s_attitude_and_no_delay_on_sihs_at_the_bench_tp() -> None:
    """mrft_roll.patch's pitch relay (MRFT_P_*), h 0.1-0.3 of torque. On EKF2's attitude (the relay's) eq. (2)
    has a lead at SIH_T_TAU: EKF2 integrates the gyro by trapezoids and leads SIH's attitude (stepped with
    the previous step's rate) by half a 4 ms step, which leaves the loop 1-4 ms ahead of eq. (2): identified
    with tau < 0 and each test held out from the others within 5 % (refused before a lead was admitted). On SIH's
    own attitude (logged) at the bench Tp the tests give SIH's constants: Td = SIH_IYY / SIH_KDW = 1 s,
    K = SIH_L_PITCH SIH_T_MAX 2 sqrt(2) / SIH_IYY = 113.1 rad/s^2, and a delay within 1 ms of 0 (sih.cpp's
    update order: +0.2 to +0.9 ms at these frequencies); each test's frequency from the others within 5 %."""
    from mrftcli.analyze import AnalyzeOptions, analyze_flight
    from mrftcli.mrft.model import soiptd_model

    log = LOGS / "px4_pitch_h.ulg"
    side = json.loads((LOGS / "px4_pitch_h.ulg.json").read_text())
    lead = analyze_log(log, side["tp_s"], "pitch")
    assert -0.005 < lead.tau.value < -0.001 and lead.notes[0].startswith("assumed: the loop leads eq. (2)")
    for k, test in enumerate(lead.tests):
        ho = lead.held_out_of(k)
        assert ho is not None and abs(ho.frequency_hz / test.frequency_hz_mean - 1.0) <= 0.05
    flight = read_flight(log, ReadOptions(loop="pitch", output_topic="vehicle_attitude_groundtruth:q"),
                         echo_warnings=False)
    assert flight.source["command"] == "vehicle_torque_setpoint:xyz[1]"
    res = analyze_flight(flight, soiptd_model(bench_tp()), options=AnalyzeOptions(n_bootstrap=20, seed=1,
                                                                                  refine_waveform=False))
    assert [t.beta_nominal for t in res.tests] == pytest.approx([t["beta"] for t in side["tests"]], abs=1e-6)
    sih = sih_implied("pitch")
    assert res.Td.value == pytest.approx(sih["Td"], rel=0.05)
    assert res.K.value == pytest.approx(sih["K"], rel=0.02)
    assert abs(res.tau.value) <= 0.001
    for k, test in enumerate(res.tests):
        ho = res.held_out_of(k)
        assert ho is not None and ho.frequency_hz is not None
        assert abs(ho.frequency_hz / test.frequency_hz_mean - 1.0) <= 0.05


def test_the_rate_relays_delay_is_exact_and_comes_back_in_tau_on_sihs_attitude() -> None:
    """MRFT_DELAY on mc_rate_control's relays (mrft_roll.patch): 20 ms is 5 ticks of the 4 ms rate loop, so
    the torque follows the logged decision (debug_vect) by 20.0 ms at every switch. On SIH's attitude at the
    bench Tp, tau rises from the plain flight's by that within 2 ms (20.2 ms measured); on EKF2's attitude
    the delayed flight is identified (the added delay outweighs EKF2's lead) with SIH's Td and K."""
    from mrftcli.analyze import AnalyzeOptions, analyze_flight
    from mrftcli.mrft.model import soiptd_model

    log = LOGS / "px4_pitch_h_20ms.ulg"
    side = json.loads((LOGS / "px4_pitch_h_20ms.ulg.json").read_text())
    assert side["added_delay_ms"] == 20.0 and side["decision_topic"] == "debug_vect:y"
    delay = realised_delay(log, 0.05, ("debug_vect", "y"), ("vehicle_torque_setpoint", "xyz[1]"))
    assert delay.startswith("20.0 ms median")
    opts = AnalyzeOptions(n_bootstrap=20, seed=1, refine_waveform=False)
    taus = []
    for name, command in (("px4_pitch_h", None), ("px4_pitch_h_20ms", "debug_vect:y")):
        flight = read_flight(LOGS / f"{name}.ulg", ReadOptions(loop="pitch", command_topic=command,
                                                               output_topic="vehicle_attitude_groundtruth:q"),
                             echo_warnings=False)
        taus.append(analyze_flight(flight, soiptd_model(bench_tp()), options=opts).tau.value)
    assert taus[1] - taus[0] == pytest.approx(0.020, abs=0.002)
    ekf = analyze_flight(read_flight(log, ReadOptions(loop="pitch", command_topic="debug_vect:y"),
                                     echo_warnings=False), soiptd_model(side["tp_s"]), options=opts)
    sih = sih_implied("pitch")
    assert ekf.Td.value == pytest.approx(sih["Td"], rel=0.05)
    assert ekf.K.value == pytest.approx(sih["K"], rel=0.02)


def test_attitude_step_helpers_against_closed_forms() -> None:
    """px4_rate_step: the attitude setpoint's quaternion reads back as the angle sent (ZYX Euler), and a
    step's figures of a first-order response are tau ln 9 (10-90 % rise) and tau ln 50 (2 % settling)."""
    from px4_rate_step import _angle, _quat, _step_figures

    for roll, pitch in ((0.17, 0.0), (0.0, -0.17), (0.1, 0.2)):
        q = dict(zip([f"q[{i}]" for i in range(4)], (np.array([v]) for v in _quat(roll, pitch, 1.2))))
        assert _angle(q, "roll")[0] == pytest.approx(roll, abs=1e-9)
        assert _angle(q, "pitch")[0] == pytest.approx(pitch, abs=1e-9)
    tau, t0 = 0.1, 5.0
    t = np.arange(0.0, 10.0, 0.001)
    y = np.where(t < t0, 0.3, 0.3 + 2.0 * (1.0 - np.exp(-(t - t0) / tau)))
    fig = _step_figures(t, y, t0, dwell=2.0)
    assert fig["rise_s"] == pytest.approx(tau * np.log(9.0), abs=0.005)
    assert fig["settling_s"] == pytest.approx(tau * np.log(50.0), abs=0.005)
    assert fig["overshoot_pct"] == pytest.approx(0.0, abs=1e-3)  # the level: the mean of the last 0.5 s


def test_sihs_discrete_path_against_its_recursion_run_in_time() -> None:
    """rate_path.sih_discrete_tau (the z-domain form of sih.cpp's update order) against the recursion itself
    run on a sine command: read one step late, u += dt/T (c - u), w += dt (u - w/Td), phi += dt w_prev; the
    phase beyond eq. (2)'s continuous model agrees within 0.05 ms at 1.3 and 3 Hz."""
    from rate_path import sih_discrete_tau

    dt, tp, td = 0.004, 0.05, 1.0
    for f in (1.3, 3.0):
        w = 2 * np.pi * f
        n = int(40.0 / dt)
        t = np.arange(n) * dt
        c = np.sin(w * t)
        u = rate = phi = 0.0
        out = np.empty(n)
        for k in range(n):
            u += dt / tp * ((c[k - 1] if k else 0.0) - u)
            prev = rate
            rate += dt * (u - rate / td)
            phi += dt * prev
            out[k] = phi
        sel = t > 20.0  # the transient gone
        ratio = np.sum((out[sel] - out[sel].mean()) * np.exp(-1j * w * t[sel])) / np.sum(c[sel] * np.exp(-1j * w * t[sel]))
        cont = -np.pi / 2 - np.arctan(tp * w) - np.arctan(td * w)
        lag_ms = -float(np.angle(np.exp(1j * (np.angle(ratio) - cont)))) / w * 1e3
        assert lag_ms == pytest.approx(sih_discrete_tau(f, dt, tp, td), abs=0.05)


def test_every_flown_test_counts_in_the_held_out_figure() -> None:
    """The benchmark's held-out figure counts every flown test: a refusal, a test not found and a test left
    without a prediction are misses (the first count left the unfound beta -0.2 of px4_altitude_20ms out)."""
    from px4_campaign import counted_errors
    from sitl_analysis import HeldOut

    ho = [HeldOut(i, -0.4, 0.05, 1.0, 1.0 + e, (1.0, 0.01, 20.0)) for i, e in enumerate((0.01, -0.08, 0.02))]
    found3_of4 = counted_errors({"flown": 4, "found": 3, "held": ho})
    assert found3_of4 == pytest.approx([0.01, 0.08, 0.02, np.inf])
    assert counted_errors({"flown": 3, "found": 0, "held": [], "refused": "negative delay"}) == [np.inf] * 3
    assert counted_errors({"flown": 3, "found": 3, "held": [], "held_rate": [0.036, -0.015]}) == pytest.approx(
        [0.036, 0.015, np.inf])


def test_the_misses_are_classed_by_how_the_flight_was_flown_and_every_flown_test_counted() -> None:
    """The benchmark's classes of the held-out misses (issue 42): set by the loop and relay height flown, every
    flown test counted once (refused, not found, over 5 %, within), the over-5 % tests' |z| and own standard
    errors collected per class: counts checked by hand."""
    from miss_classes import classify, miss_class, totals
    from sitl_analysis import HeldOut

    assert [miss_class("altitude", 0.05), miss_class("altitude", 0.25), miss_class("y", 0.16),
            miss_class("pitch", 0.3)] == ["altitude, h <= 0.15", "altitude, h > 0.15", "x / y", "roll / pitch"]

    def row(z: float, sem: float, error: float | None = None) -> dict[str, float | None]:
        return {"z": z, "sem": sem, "error": error}

    ho = [HeldOut(i, -0.4, 0.05, 1.0, 1.0 + e, (1.0, 0.01, 20.0)) for i, e in enumerate((0.01, -0.30, 0.06))]
    results = {"a": {"loop": "altitude", "flown": 4, "found": 3, "held": ho,
                     "jitter": [row(0.2, 0.01), row(1.9, 0.09), row(-2.6, 0.04)]},
               "r": {"loop": "roll", "flown": 3, "found": 3, "held": [], "held_rate": [0.056, 0.02],
                     "jitter": [row(-1.2, 0.02, 0.056), row(0.8, 0.01, None), row(0.1, 0.01, 0.02)]},
               "x": {"loop": "x", "flown": 4, "found": 0, "held": [], "refused": "no"}}
    c = classify(results, {"a": 0.06, "r": 0.05, "x": 0.08})
    assert c["altitude, h <= 0.15"]["counts"] == {"not found": 1, "within": 1, "over": 2}
    assert c["altitude, h <= 0.15"]["z"] == pytest.approx([1.9, 2.6])
    assert c["altitude, h <= 0.15"]["sem_miss"] == pytest.approx([0.09, 0.04])
    assert c["roll / pitch"]["counts"] == {"over": 1, "not predicted": 1, "within": 1}
    # the hits' standard errors are those of the tests held out within 5 % only: not the one not predicted
    assert c["altitude, h <= 0.15"]["sem_hit"] == pytest.approx([0.01])
    assert c["roll / pitch"]["sem_hit"] == pytest.approx([0.01]) and c["roll / pitch"]["sem_miss"] == [0.02]
    assert c["x / y"]["counts"] == {"refused": 4}
    assert totals(c) == {"not found": 1, "within": 2, "over": 3, "not predicted": 1, "refused": 4}  # 11 flown
    with pytest.raises(KeyError, match="'x'"):  # a flight without its relay height is not put in a class
        classify(results, {"a": 0.06, "r": 0.05})
    with pytest.raises(ValueError):
        miss_class("altitude", float("nan"))


def test_the_h005_misses_are_the_measurements_own_spread_and_inside_the_stated_uncertainty(px4_flight) -> None:
    """Why the first pair's held-out frequencies miss by 6-30 %: the relay switches on EKF2's altitude, whose
    error (several cm, slow) moves the switches of 1-4 cm cycles, so one test's cycles spread 10-22 % in
    frequency (its mean uncertain by 4-9 %), against 2-9 % at h 0.25. analyze says so: each miss lies within 2.5
    of the std it states for its held-out prediction. (Issue 41: analyze's held-out fits the other tests'
    fundamentals and 3rd harmonics; on the h 0.25 flight that moves its end tests to -7.2 and +6.1 %, within 1.3
    of their stated std (the fundamentals alone: every test within 5 %), and on the h 0.05 flight the -0.7 test,
    17 cycles spread 18 %, to +20 % at 1 std.)"""
    from px4_campaign import held_out_jitter

    _, low = px4_flight("px4_altitude")
    _, fresh = px4_flight("px4_altitude_h25")
    rows_low, rows_fresh = held_out_jitter(low), held_out_jitter(fresh)
    assert [r["error"] is not None for r in rows_low] == [True] * 4
    missed = [r for r in rows_low if abs(r["error"]) > 0.05]
    assert [r["beta"] for r in missed] == pytest.approx([-0.2, -0.4, -0.7])  # -31.6, +15.6, +20.4 %
    for r in missed:
        assert r["spread"] > 0.10 and r["sem"] > 0.04
        assert abs(r["z"]) <= 2.5
    assert max(r["spread"] for r in rows_fresh) < 0.10
    assert all(abs(r["error"]) <= 0.08 and abs(r["z"]) <= 1.5 for r in rows_fresh)


def test_px4s_attitude_gains_in_the_generic_form_from_the_ulogs_parameters() -> None:
    """The inner controller of x's cascade: PX4's defaults for airframe 10040 (MC_PITCH_P 6.5, MC_PITCHRATE_P
    0.15, _I 0.2, _K 1, IMU_GYRO_CUTOFF 40 Hz, IMU_INTEG_RATE 250 Hz; mc_pos_control_params, rate_control)
    give Kp = 0.15 x 6.5 + 0.2, Ki = 0.2 x 6.5, Kd = 0.15; the rate loop's D (0.003) is named as left out."""
    from px4_campaign import px4_inner_gains

    c, left = px4_inner_gains(LOGS / "px4_x.ulg", "pitch")
    assert (c.Kp, c.Ki, c.Kd) == pytest.approx((1.175, 1.3, 0.15), rel=1e-6)
    assert c.Tf == pytest.approx(1 / (2 * np.pi * 40.0)) and c.rate_hz == 250.0
    assert "MC_PITCHRATE_D 0.003" in left


def test_the_forks_relay_lands_on_an_orbit_the_sampled_predictor_admits(px4_flight) -> None:
    """The fork's MRFT_Block (peak confirmation 5 samples, 20 ms guard) run tick by tick at 125 Hz on the fresh
    flight's eq. (2) (exact zero-order-hold steps, no noise) settles on the same orbit as the plain sampled MRFT,
    one of the admissible orbits ``mrft_limit_cycle`` lists (an independent simulation against the predictor), within
    3 % of their centre: the relay law is not what the held-out misses miss by."""
    from px4_campaign import relay_law_orbits

    side, res = px4_flight("px4_altitude_h25")
    rows = relay_law_orbits({"tp": side["tp_s"], "Td": res.Td.value, "tau": res.tau.value, "K": res.K.value,
                             "rate_hz": 125.0, "tests": res.tests})
    assert len(rows) == 4
    for r in rows:
        assert r["fork"] == pytest.approx(r["plain"], rel=1e-9)
        assert min(abs(f / r["fork"] - 1) for f in r["orbits"]) < 1e-6
        assert abs(r["fork"] / r["centre"] - 1) < 0.03
