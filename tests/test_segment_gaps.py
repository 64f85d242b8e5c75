"""Absent data ends a test, and a test's beta is the marker in force over its cycles (issue 41).

A log masked to some tests' windows (the held-out check: each window opening at its test's beta
marker) has no samples between the windows. Two tests at the same h whose kept windows end and start at
the same relay level must stay two tests, each with its own beta; the flight is the independent
closed-loop simulation of ``test_segment_support`` (no code shared with the segmenter).
"""

from __future__ import annotations

import numpy as np
import pytest

from mrftcli.segment import find_relay_runs, segment

from test_segment_support import simulate_relay_flight, to_flight

# the paper's Design II altitude loop (checks.md section 4), as test_segment.py
TP, TD, TAU, K = 0.0499, 1.8345, 0.0498, 2.0
H, BIAS = 0.8, 0.5


@pytest.fixture(scope="module")
def sim():
    return simulate_relay_flight(TP, TD, TAU, K, [(-0.2, H, 30.0), (-0.5, H, 20.0)], seed=41, takeoff_s=3.0)


def _level_at(sim, t: float) -> float:
    return float(sim.command[np.searchsorted(sim.t, t)])


def _end_inside_a_run_at(sim, window: tuple, level: float) -> float:
    """A time [s] inside the last relay run of ``window`` at ``level`` (a few samples into it)."""
    t0, t1 = window[0], window[1]
    m = np.flatnonzero((sim.t >= t0) & (sim.t <= t1 - 0.5))
    at = m[np.abs(sim.command[m] - level) < 1e-9]
    starts = at[np.flatnonzero(np.diff(at, prepend=-2) > 1)]  # first samples of the runs at that level
    return float(sim.t[starts[-1] + 4])


def test_two_masked_tests_at_the_same_level_across_the_gap_stay_two(sim):
    (a0, a1, beta_a, _), (b0, b1, beta_b, _) = sim.test_windows
    first_level = _level_at(sim, b0)  # the level test b opens at
    assert abs(abs(first_level - BIAS) - H) < 1e-9
    cut = _end_inside_a_run_at(sim, sim.test_windows[0], first_level)
    keep = ((sim.t >= a0) & (sim.t <= cut)) | ((sim.t >= b0) & (sim.t <= b1))
    masked = to_flight(sim, keep=keep)
    # the two kept stretches are one flat piece across the gap in sample order: what joined the tests
    i_gap = int(np.flatnonzero(np.diff(masked.command.t) > 1.0)[0])
    assert masked.command.values[i_gap] == masked.command.values[i_gap + 1]

    tests = segment(masked)
    full = segment(to_flight(sim))
    assert [t.beta_nominal for t in tests] == [beta_a, beta_b]
    for test, ref, (t0, t1) in zip(tests, full, [(a0, cut), (b0, b1)]):
        assert t0 - 1e-9 <= test.t_start and test.t_end <= t1 + 1e-9
        assert all(t0 <= c.t_start and c.t_end <= t1 for c in test.cycles)
        assert test.n_stable >= 6
        assert test.frequency_hz_mean == pytest.approx(ref.frequency_hz_mean, rel=0.01)


def test_a_stretch_of_lost_data_ends_a_test_and_the_marker_stays_in_force(sim):
    (a0, a1, beta_a, _), _ = sim.test_windows
    lost = (sim.t > a0 + 15.0) & (sim.t < a0 + 16.0)  # one second of the first test never logged
    tests = segment(to_flight(sim, keep=~lost))
    first = [t for t in tests if t.t_start < a1]
    assert len(first) == 2
    assert first[0].t_end <= a0 + 15.0 and first[1].t_start >= a0 + 16.0
    # both pieces ran under the first test's marker (published once, at its start)
    assert [t.beta_nominal for t in first] == [beta_a, beta_a]


def test_a_gap_splits_runs_of_equal_level_and_ends_the_chain():
    relay = np.tile(np.r_[np.ones(5), -np.ones(5)], 6)  # +1 first, -1 last
    c = np.r_[relay, relay[5:]]  # the second stretch opens at -1, the level the first ends at
    joined = find_relay_runs(c)
    split = find_relay_runs(c, gaps=np.array([relay.size]))
    assert len(joined) == 1 and max(r.stop - r.start for r in joined[0]) == 10  # one run across the gap
    assert [(ch[0].start, ch[-1].stop) for ch in split] == [(0, relay.size), (relay.size, c.size)]


def test_a_marker_just_after_a_switch_mid_relay_opens_a_new_test():
    relay = np.tile(np.r_[np.ones(5), -np.ones(5)], 8)  # 16 runs of 5 samples, no pause between two tests
    for late in (0, 1, 3):  # the marker logged 0-3 samples after the switch that starts the second test
        chains = find_relay_runs(relay, breaks=np.array([40 + late]))
        assert [(ch[0].start, ch[-1].stop) for ch in chains] == [(0, 40), (40, 80)]
