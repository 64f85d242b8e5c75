"""A gain drift's hover command is the relay centre of the earliest test FLOWN (R2's finding 6), as
trim_spread takes every test flown: a first test lost to the diagnosis (too few stable cycles) still
says what the hold trimmed to first. Oracle: the centre put into the simulated command (test_segment_support,
an exact simulation sharing no code with diagnose)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mrftcli.diagnose.candidate_model import CandidateModel
from mrftcli.diagnose.screen import screen_log
from mrftcli.mrft.model import soiptd_model
from test_segment_support import simulate_relay_flight, to_flight

TP, TD, TAU, K = 0.0499, 1.8345, 0.0498, 2.0


def test_the_hover_command_is_the_first_test_flown_even_when_it_is_lost():
    sim = simulate_relay_flight(TP, TD, TAU, K, [(-0.4, 0.8, 2.5), (-0.4, 0.8, 14.0), (-0.7, 2.0, 10.0)], seed=4)
    t0, t1, _, _ = sim.test_windows[0]
    first = (sim.t >= t0 - 0.5) & (sim.t <= t1 + 0.5)
    command = sim.command.copy()
    command[first] += 0.02  # the hold had trimmed to 0.52 when the first test began (0.5 later)
    flight = to_flight(replace(sim, command=command))
    screen = screen_log(flight, soiptd_model(TP), None, lambda *a, **k: None)
    assert [t.index for t in screen.flown] == [0, 1, 2] and 0 not in [t.index for t in screen.tests]
    model = CandidateModel(None, screen.tests, TP)
    assert model.bias_first == pytest.approx(0.52, abs=1e-9)  # before: 0.5, the first test diagnosed
    # without the screen's word, the earliest of the tests given
    bare = [replace(t, first_centre=None) for t in screen.tests]
    assert CandidateModel(None, bare, TP).bias_first == pytest.approx(0.5, abs=1e-9)
    assert np.isclose(min(screen.flown, key=lambda s: s.t_start).bias, 0.52)
