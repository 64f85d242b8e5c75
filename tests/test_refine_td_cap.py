"""The waveform refinement's Td never past a week (issue 39, found on a JSBSim benchmark flight).

The output-error cost is flat in ln Td where the windows do not show the damping, so a fit may walk
Td past a week; eq. (2)'s model refuses such a time as a unit mistake (a one-line "give it in
seconds"), and that refusal used to end the whole analysis. The week is the fits' own upper bound on
ln Td (mrft.refine.loop_model_bounds): no evaluation goes past it and no estimate is reported past it.

Oracle: an independent simulation (test_segment_support, sharing no code with the fit) of a loop
with no damping at all (Td = 1e12 s: a double integrator behind Tp and tau), whose Td no window bounds.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mrftcli.errors import InputError
from mrftcli.mrft.identify import ParameterEstimate
from mrftcli.mrft.model import LoopModel
from mrftcli.mrft.refine import COMMAND_HISTORY, loop_model_bounds, loop_model_plant, refine
from mrftcli.mrft.waveform import CommandWindow
from mrftcli.validate import MAX_TIME_S
from test_segment_support import simulate_relay_flight


def test_the_fits_bound_ln_td_at_a_week():
    lower, upper = loop_model_bounds(0.05)
    assert math.exp(upper[0]) == pytest.approx(MAX_TIME_S, rel=1e-6) and math.exp(upper[0]) <= MAX_TIME_S
    assert math.exp(lower[0]) == pytest.approx(0.05e-2)
    LoopModel(0.05, math.exp(upper[0]), 0.03, 2.0)  # the bound itself is a model eq. (2) takes
    # past the bound the plant is eq. (2)'s own model, which refuses it (no silent clamp)
    with pytest.raises(InputError, match="longer than a week"):
        loop_model_plant(0.05)(np.array([math.log(2.0 * MAX_TIME_S), 0.03, 2.0]))


def test_a_refinement_that_does_not_bound_td_stops_at_the_week():
    Tp, tau, K = 0.05, 0.03, 4.0
    log = simulate_relay_flight(Tp, 1e12, tau, K, [(-0.4, 0.1, 6.0), (-0.7, 0.1, 6.0)], rate_hz=100.0,
                                noise_std=0.0005)
    windows = [CommandWindow.between(t0, t1, log.t, log.command, log.t, log.y_meas, 0.5, COMMAND_HISTORY)
               for t0, t1, _, _ in log.test_windows]
    start = LoopModel(Tp, 1e5, tau, K)  # a start the cost falls away from towards larger Td

    def est(v, unit):
        return ParameterEstimate(v, 0.1 * v, 0.8 * v, 1.2 * v, unit)

    r = refine(windows, start, {"Td": est(start.Td, "s"), "tau": est(tau, "s"), "K": est(K, "")})
    # before: the fit's bound was Td = 1e6 s and the plant clamped at the week, so the fit walked the
    # flat cost past the week and reported Td = 7.9e5 s
    assert r.fit.p[0] <= loop_model_bounds(Tp)[1][0]
    assert r.Td.value <= MAX_TIME_S and r.model.Td <= MAX_TIME_S
    assert r.Td.value > 1e4  # it did walk towards no damping
    assert not r.accepted


def test_a_refinement_whose_interval_runs_past_the_week_is_refused():
    """The same undamped loop from another start: the fit stopped on the flat cost at Td = 5.6e5 s, short of the
    week, with a 95 % interval 1.5e5-2.1e6 s, and was accepted (the MRFT interval, open above, let it pass):
    a Td the waveform does not bound is now refused as the fit at the bound is; tau and K are not the reason."""
    Tp, tau, K = 0.05, 0.03, 4.0
    log = simulate_relay_flight(Tp, 1e12, tau, K, [(-0.4, 0.1, 6.0), (-0.7, 0.1, 6.0)], rate_hz=100.0,
                                noise_std=0.0005)
    windows = [CommandWindow.between(t0, t1, log.t, log.command, log.t, log.y_meas, 0.5, COMMAND_HISTORY)
               for t0, t1, _, _ in log.test_windows]
    start = LoopModel(Tp, 1e5, tau, K)
    mrft = {"Td": ParameterEstimate(1e5, math.nan, 5e4, math.nan, "s"),  # open above, as a td_open MRFT's
            "tau": ParameterEstimate(tau, 1e-3, tau - 0.005, tau + 0.005, "s"),
            "K": ParameterEstimate(K, 0.1, 0.8 * K, 1.2 * K, "")}
    r = refine(windows, start, mrft)
    assert r.fit.p[0] < loop_model_bounds(Tp)[1][0] - 1e-3  # stopped short of the week ...
    assert r.Td.ci95_high > MAX_TIME_S  # ... with an interval past it
    assert r.tau.value == pytest.approx(tau, abs=1e-3) and r.K.value == pytest.approx(K, rel=0.01)
    assert not r.accepted and len(r.reasons) == 1
    assert r.reasons[0].startswith("the waveform does not bound Td (its fit's 95 % interval reaches")
