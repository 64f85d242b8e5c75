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
    assert any(w.startswith("the waveform does not bound Td (") for w in r.reasons)


def _undamped_windows():
    log = simulate_relay_flight(0.05, 1e12, 0.03, 4.0, [(-0.4, 0.1, 6.0), (-0.7, 0.1, 6.0)], rate_hz=100.0,
                                noise_std=0.0005)
    return [CommandWindow.between(t0, t1, log.t, log.command, log.t, log.y_meas, 0.5, COMMAND_HISTORY)
            for t0, t1, _, _ in log.test_windows]


def _open_above(Td0, tau, K):
    """An MRFT estimate whose Td interval is open above, as a td_open consensus gives it."""
    return {"Td": ParameterEstimate(Td0, math.nan, Td0 / 2, math.nan, "s"),
            "tau": ParameterEstimate(tau, 1e-3, tau - 0.005, tau + 0.005, "s"),
            "K": ParameterEstimate(K, 0.1, 0.8 * K, 1.2 * K, "")}


@pytest.mark.parametrize("Td0", [1e5, 30.0])
def test_a_refinement_whose_interval_runs_past_the_record_is_refused(Td0):
    """The undamped loop (true Td 1e12 s) from a start of 1e5 s: the fit stopped on the flat cost at 5.6e5 s
    [1.5e5, 2.1e6] s, short of the week; from 30 s (as from 3 s to 1e4 s): at 151 s [2.95, 7.7e3] s, an interval
    that leaves the truth out. Both were accepted (the MRFT interval, open above, let them pass). Over the 12 s
    the windows record a Td that long leaves eq. (2) an integrator of gain K, so neither is a value: refused,
    tau and K not the reason."""
    Tp, tau, K = 0.05, 0.03, 4.0
    windows = _undamped_windows()
    record = sum(w.t_output[-1] - w.t_output[0] for w in windows)
    r = refine(windows, LoopModel(Tp, Td0, tau, K), _open_above(Td0, tau, K))
    assert r.fit.p[0] < loop_model_bounds(Tp)[1][0] - 1e-3  # stopped short of the week ...
    assert r.Td.ci95_high > record  # ... with an interval past the record
    assert r.tau.value == pytest.approx(tau, abs=1e-3) and r.K.value == pytest.approx(K, rel=0.01)
    assert not r.accepted and len(r.reasons) == 1
    assert r.reasons[0].startswith("the waveform does not bound Td (its 95 % interval reaches")
    assert f"more than the {record:.3g} s these windows record" in r.reasons[0]


def test_a_bounded_td_is_accepted():
    """The criterion refuses only what the record cannot show: the same flight with drag (Td 2 s) is accepted."""
    Tp, Td, tau, K = 0.05, 2.0, 0.03, 4.0
    log = simulate_relay_flight(Tp, Td, tau, K, [(-0.4, 0.1, 6.0), (-0.7, 0.1, 6.0)], rate_hz=100.0,
                                noise_std=0.0005)
    windows = [CommandWindow.between(t0, t1, log.t, log.command, log.t, log.y_meas, 0.5, COMMAND_HISTORY)
               for t0, t1, _, _ in log.test_windows]

    def est(v, unit):
        return ParameterEstimate(v, 0.1 * v, 0.8 * v, 1.2 * v, unit)

    r = refine(windows, LoopModel(Tp, 1.8, tau, K), {"Td": est(1.8, "s"), "tau": est(tau, "s"), "K": est(K, "")})
    assert r.accepted, r.reasons
    assert r.Td.ci95_low <= Td <= r.Td.ci95_high
