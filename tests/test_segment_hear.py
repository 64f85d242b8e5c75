"""HEAR-style logs: a bias inside the command that moves during a test, receive-time stamps.

Oracles: the simulator's truth (h, the relay's switching instants) and the same flight segmented
without the moving bias / with its controller-tick stamps; scipy's median filter for HEAR's bias.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import median_filter

from mrftcli.mrft.model import LoopModel
from mrftcli.io.logtypes import Signal
from mrftcli.segment import segment_arrays
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight

MODEL = LoopModel(0.08, 2.0, 0.08, 1.0)  # the HEAR x sample log's plant (m/s^2 command)


@pytest.fixture(scope="module")
def flight():
    rate = 200.0
    tests = tuple(plan_test(MODEL, beta, 0.05, rate_hz=rate, cycles=12.0) for beta in (-0.6, -0.3))
    spec = FlightSpec(model=MODEL, tests=tests, loop="x", rate_hz=rate, noise_std=0.0005, bias=0.0,
                      setpoint=0.0, hover_s=2.0, hold_s=2.0, seed=7, switching="hear")
    return simulate_flight(spec)


def _stable(tests):
    return [t for t in tests if t.n_stable >= 3]


def hear_bias(t: np.ndarray, drift: float, rng: np.random.Generator) -> np.ndarray:
    """HEAR z's bias: 9.8 plus a 50-sample running median of the PID output, here a slow drift
    (a battery sagging: the trim the PID finds moves by ``drift`` over the flight) plus the PID's
    sample-to-sample noise."""
    pid = drift * (t - t[0]) / (t[-1] - t[0]) + 0.02 * rng.standard_normal(t.size)
    return 9.8 + median_filter(pid, size=50, mode="nearest")


@pytest.mark.parametrize("drift", [0.1, 0.3])
def test_beta_and_h_hold_when_the_bias_inside_the_command_moves(flight, drift):
    # the plant's trim moves with the bias (the PID's median follows it), so the relay part of the
    # command and the output are those of the flight without it: h and beta must come out the same
    t, y = flight.t, flight.output_measured
    plain = _stable(segment_arrays(Signal(t, flight.command), Signal(t, y), setpoint=Signal(t, flight.setpoint)))
    bias = hear_bias(t, drift * max(e["h"] for e in flight.truth["tests"]), np.random.default_rng(3))
    moved = _stable(segment_arrays(Signal(t, flight.command + bias), Signal(t, y), setpoint=Signal(t, flight.setpoint)))
    assert len(moved) == len(plain) == 2
    for a, b, tr in zip(plain, moved, flight.truth["tests"]):
        assert b.h == pytest.approx(tr["h"], rel=0.01)  # h from the two levels, the drift cancels
        assert b.beta_effective == pytest.approx(a.beta_effective, abs=0.01)
        assert b.beta_effective == pytest.approx(tr["beta"], abs=0.05)
        assert b.frequency_hz_mean == pytest.approx(a.frequency_hz_mean, rel=1e-3)
        inside = (t >= b.t_start) & (t <= b.t_end)  # the bias the test ran on, as HEAR computed it
        assert bias[inside].min() - 0.01 < b.bias < bias[inside].max() + 0.01


def test_receive_jitter_is_not_read_as_missing_samples_but_a_lost_one_still_is(flight):
    # stamps as a bag records header-less messages: transport and scheduling delays of 1 ms plus
    # |N(0, 2 ms)| (the HEAR sample log's), at a 200 Hz controller
    rng = np.random.default_rng(11)
    t, c, y = flight.t, flight.command, flight.output_measured

    def received(stamps):
        return np.maximum.accumulate(stamps + 0.001 + np.abs(rng.normal(0.0, 0.002, stamps.size)))

    tests = _stable(segment_arrays(Signal(received(t), c), Signal(received(t), y),
                                   setpoint=Signal(t, flight.setpoint)))
    assert len(tests) == 2
    assert not any("missing" in n for tt in tests for n in tt.notes)
    assert not any("interp" in cy.flags for tt in tests for cy in tt.cycles)
    # the command sample before three switches lost: those switches (and only those) are interpolated
    sw = np.flatnonzero(np.abs(np.diff(c)) > 0.5 * flight.truth["tests"][0]["h"]) + 1
    sw = sw[(t[sw] > 8.0) & (t[sw] < 16.0)][[2, 6, 10]]
    keep = np.ones(t.size, bool)
    keep[sw - 1] = False
    tests = _stable(segment_arrays(Signal(received(t)[keep], c[keep]), Signal(received(t), y),
                                  setpoint=Signal(t, flight.setpoint)))
    cycles = [cy for tt in tests for cy in tt.cycles if "interp" in cy.flags]
    flagged = {x for cy in cycles for x in (cy.t_start, cy.t_switch, cy.t_end)}
    assert len({k for k in sw if any(abs(t[k] - f) < 0.02 for f in flagged)}) == 3
    assert len(cycles) <= 6  # each lost sample touches the one or two cycles around its switch
    assert any("missing" in n for tt in tests for n in tt.notes)
