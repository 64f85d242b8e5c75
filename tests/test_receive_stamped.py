"""Receive-stamped topics: send times rebuilt on the publisher's tick grid, and the refinement on them.

Oracles: the send times drawn here (a fixed-rate grid, lateness and drops of known law), and the
simulator's true plant (mrftcli.sim, which shares no code with the segmenter or the refinement).
"""

import numpy as np
import pytest

from mrftcli.mrft.model import soiptd_model
from mrftcli.io import ReadOptions
from mrftcli.analyze import AnalyzeOptions, analyze_flight
from mrftcli.errors import InputError
from mrftcli.mrft.model import LoopModel
from mrftcli.segment.runs import rebuild_send_times
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight
from mrftcli.sim.stamps import ReceiveStamping, receive_stamped, recorded_flight

DT = 0.005  # a 200 Hz publisher


def _sent(n: int = 4000, t0: float = 1.7e9) -> np.ndarray:
    return t0 + DT * np.arange(n)


def test_rebuilt_on_the_grid_through_the_earliest_arrivals():
    rng = np.random.default_rng(3)
    sent = _sent()
    r = rebuild_send_times(sent + rng.uniform(0.0, 0.003, sent.size))
    assert r.rebuilt and r.dropped == 0
    assert r.period == pytest.approx(DT, rel=1e-5)
    # the uniform 0-3 ms lateness: mean 1.5 ms above its floor, median absolute deviation 3 / 4 ms
    assert r.lateness == pytest.approx(0.0015, abs=1e-4)
    assert r.spread == pytest.approx(1.4826 * 0.003 / 4, rel=0.1)
    assert np.max(np.abs(r.t - sent)) < 2e-5  # against 3 ms of lateness
    assert "200 Hz" in r.describe("command")


def test_lateness_beyond_a_period_is_rebuilt_by_position():
    """Messages late by more than a period bunch; one per tick in order, the position is the tick."""
    rng = np.random.default_rng(4)
    sent = _sent()
    late = np.abs(rng.normal(0.0, 0.003, sent.size)) + 0.001
    ramp = 1e-6 * np.arange(sent.size)
    received = np.maximum.accumulate(sent + late - ramp) + ramp
    r = rebuild_send_times(received)
    assert r.rebuilt
    assert np.max(np.abs(r.t - (sent + 0.001))) < 1e-4  # the 1 ms floor is not observable


@pytest.mark.parametrize("drop", [0.005, 0.01, 0.05])
def test_dropped_messages_stay_gaps_in_the_tick_numbering(drop):
    """A dropped message is one missing tick: every message keeps its own tick through the gaps
    (the simulator's send times are the oracle), 5 % lost included (the median interval is then
    2 % long, outside the phase search's old +-2 %)."""
    rng = np.random.default_rng(5)
    sent = _sent()
    k, received = receive_stamped(sent, ReceiveStamping(0.003, drop), rng)
    r = rebuild_send_times(received)
    assert r.rebuilt and r.dropped == (k[-1] - k[0] + 1) - k.size
    assert np.max(np.abs(r.t - sent[k])) < 2e-5
    assert np.array_equal(np.rint((r.t - r.t[0]) / DT), k - k[0])
    assert f"{r.dropped} ticks without a message" in r.describe("command")


def test_an_irregular_publisher_is_not_rebuilt():
    rng = np.random.default_rng(6)
    t = np.cumsum(rng.uniform(0.002, 0.008, 3000))
    assert not rebuild_send_times(t).rebuilt


def test_receive_stamping_rejects_bad_settings():
    with pytest.raises(InputError, match="drop must be a probability"):
        ReceiveStamping(0.003, 1.5)
    with pytest.raises(InputError, match="late_max must be >= 0"):
        ReceiveStamping(-1.0)


@pytest.fixture(scope="module")
def flight():
    m = LoopModel(0.0422, 1.8, 0.05, 15.0)
    tests = tuple(plan_test(m, b, 0.05, cycles=8, min_duration=4.0) for b in (-0.6, -0.3))
    spec = FlightSpec(model=m, tests=tests, loop="altitude", switching="hear", rate_hz=200.0, noise_std=5e-4,
                      seed=11)
    return m, simulate_flight(spec)


def test_refined_on_rebuilt_send_times_reaches_the_noise_and_covers(flight):
    m, fl = flight
    log = recorded_flight(fl, command=ReceiveStamping(0.003), output=ReceiveStamping(0.0, 0.01), seed=2)
    assert log.timing.stamps == "receive"
    r = analyze_flight(log, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=50))
    assert r.method == "waveform", r.warnings
    assert r.refinement is not None and r.refinement.residual_ratio < 1.15
    assert any("receive-stamped command rebuilt" in n for n in r.notes)
    assert not any("folded into tau's interval" in n for n in r.notes)
    for name in ("Td", "tau", "K"):
        est = getattr(r, name)
        assert est.ci95_low <= getattr(m, name) <= est.ci95_high, name
    # on the receive times the switches are 1.5 ms late on average; rebuilt, tau is within its std
    assert abs(r.tau.value - m.tau) < 3 * r.tau.std < 1e-3


def test_dropped_commands_are_rebuilt_through_the_gaps_and_refined(flight):
    m, fl = flight
    log = recorded_flight(fl, command=ReceiveStamping(0.003, 0.02), output=ReceiveStamping(0.0, 0.01), seed=2)
    r = analyze_flight(log, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=50))
    assert r.method == "waveform", r.warnings
    assert any("receive-stamped command rebuilt" in n and "ticks without a message" in n for n in r.notes)
    assert not any("folded into tau's interval" in n for n in r.notes)
    for name in ("Td", "tau", "K"):
        est = getattr(r, name)
        assert est.ci95_low <= getattr(m, name) <= est.ci95_high, name
    assert abs(r.tau.value - m.tau) < 3 * r.tau.std < 1e-3


def test_an_output_on_another_clock_is_not_rebuilt_and_the_interval_stays_widened(shared_results):
    """HEAR's 90 Hz camera topic forwards the latest 200 Hz sample: its own grid would put the
    samples 0-5 ms late. The shipped log's truth sidecar is the oracle."""
    import json
    from pathlib import Path

    log = Path(__file__).parents[1] / "sample_logs" / "hear_x.bag"
    truth = json.loads(log.with_name(log.name + ".truth.json").read_text())
    # test_analyze_sample_logs' analysis of this log (conftest.SharedResults: the same options, 200 draws)
    r = shared_results.analysis(log, soiptd_model(truth["Tp"]), ReadOptions(loop="x"), AnalyzeOptions(n_bootstrap=200))
    assert any("receive-stamped command rebuilt" in n for n in r.notes)
    assert any("90 Hz publisher is not on the controller's 200 Hz ticks" in n for n in r.notes)
    assert any("folded into tau's interval" in n for n in r.notes)
    assert r.method == "mrft"
    for name in ("tau", "K"):  # (Td's is the MRFT bootstrap's, not this stage's)
        est = getattr(r, name)
        assert est.ci95_low <= truth[name] <= est.ci95_high, name


def test_times_already_on_the_grid_are_kept_and_reported_unchanged():
    sent = _sent()
    assert rebuild_send_times(sent).unchanged
    late = rebuild_send_times(sent + np.random.default_rng(4).uniform(0.0, 0.003, sent.size))
    assert late.rebuilt and not late.unchanged


def test_no_rebuild_note_when_the_receive_stamps_are_on_the_grid():
    """The shipped simulated log is receive-stamped on its 200 Hz grid: the rebuild changes nothing,
    so the output says nothing of it (README command 1); the tests above keep the note where it did."""
    from mrftcli import sample_log
    from mrftcli.io import read_flight

    log = read_flight(sample_log("design1_altitude.mcap"), ReadOptions(loop="altitude"), echo_warnings=False)
    assert log.timing.stamps == "receive"
    r = analyze_flight(log, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=50))
    assert r.method == "waveform"
    assert not any("receive-stamped" in n for n in r.notes), r.notes
