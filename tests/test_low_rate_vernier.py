"""Tests logged at 10 Hz below a 50 Hz relay (PX4): switch instants and cycles from the vernier (issue 24 part 3).

Oracles: the flight simulator's full-rate command (where the relay really switched: the ticks at
which the 50 Hz command changes) and its noise-free output (each cycle's true extrema), neither
seen by the segmenter, which gets every 5th tick of the command and of the noisy output.
"""

from __future__ import annotations

import numpy as np
import pytest

from mrftcli.mrft.model import soiptd_model
from mrftcli.mrft.model import LoopModel
from mrftcli.io.logtypes import Signal
from mrftcli.segment import SegmentOptions, segment_arrays
from mrftcli.segment.vernier import fold_amplitudes, fold_harmonics, fold_waveform, switch_ticks
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight

RATE = 50.0
TS = 1.0 / RATE


@pytest.fixture(scope="module")
def flight():
    """A 50 Hz MRFT flight with a 2.5 Hz test (beta -0.8: 4 logged samples per cycle at 10 Hz, the
    logging locked to the cycle) and a 0.9 Hz one (beta -0.3, an orbit that wanders by a few ticks)."""
    m = LoopModel(0.0422, 1.6, 0.015, 15.0)
    tests = tuple(plan_test(m, b, 0.05, rate_hz=RATE, cycles=14.0) for b in (-0.8, -0.3))
    spec = FlightSpec(model=m, tests=tests, loop="altitude", rate_hz=RATE, noise_std=5e-4, bias=0.5, setpoint=1.0,
                      hover_s=3.0, hold_s=3.0, seed=3)
    return simulate_flight(spec)


@pytest.fixture(scope="module")
def ten_hz(flight):
    """The flight's tests as segmented from its 10 Hz log (every 5th tick)."""
    return _ten_hz(flight)


def _true_switches(fl, t_a, t_b):
    """The ticks at which the full-rate command changed level inside [t_a, t_b] [s]."""
    k = np.flatnonzero(np.abs(np.diff(fl.command)) > 1e-9) + 1
    t = fl.t[k]
    return t[(t >= t_a - 1e-9) & (t <= t_b + 1e-9)]


def _ten_hz(fl, beta_t=None):
    sub = slice(0, None, 5)  # PX4's logger: every 5th controller tick, stamped with its tick
    t, c, y, sp = fl.t[sub], fl.command[sub], fl.output_measured[sub], fl.setpoint[sub]
    bt = np.array([e["t_start"] for e in fl.truth["tests"]])
    bv = np.array([e["beta"] for e in fl.truth["tests"]])
    return segment_arrays(Signal(t, c), Signal(t, y), setpoint=Signal(t, sp), beta=Signal(bt, bv),
                          options=SegmentOptions(controller_rate_hz=RATE))


def test_both_tests_are_found_and_every_switch_is_on_its_true_tick(flight, ten_hz):
    tests = ten_hz
    assert [round(t.beta_nominal, 2) for t in tests] == [-0.8, -0.3]
    fast = tests[0]
    assert fast.rate_hz == pytest.approx(10.0) and fast.controller_rate_hz == pytest.approx(RATE)
    assert fast.rate_hz / fast.frequency_hz_mean < 5.5  # under 8 samples per cycle: dropped before
    # the record says how coarse the test is and how its switches were placed: the 2.5 Hz test is 20
    # ticks a cycle, 4 logging periods, so the logging is locked to it and the nominal beta decides
    d = fast.to_dict(cycles=False)
    assert d["samples_per_cycle"] == pytest.approx(4.0) and d["switch_timing"] == "vernier-locked-beta"
    assert any("locked to the cycle" in n for n in fast.notes)
    assert tests[1].switch_timing == "vernier" and not tests[1].notes
    for t, exact, worst in zip(tests, (1.0, 0.5), (0, 3)):
        true = _true_switches(flight, t.cycles[0].t_start - 0.5, t.cycles[-1].t_end + 0.5)
        got = np.array([x for c in t.stable for x in (c.t_start, c.t_switch)])
        err = np.array([np.min(np.abs(true - g)) for g in got])
        # a logging bracket holds 5 ticks (a guess is on its tick 1 time in 5); the fast test's
        # switches are on their tick; the slow test's orbit wanders by 1-3 ticks from cycle to cycle
        # (26-30 ticks a half-period), and half its switches or more are on their tick, none more
        # than 3 off
        assert np.mean(err < 1e-6) >= exact and err.max() <= worst * TS + 1e-6


def test_amplitude_and_period_match_the_noise_free_output(flight, ten_hz):
    for t in ten_hz:
        st = t.stable
        assert len(st) >= 3
        for c in st:
            sel = (flight.t >= c.t_start) & (flight.t < c.t_end)
            y = flight.output_true[sel] - flight.setpoint[sel]
            true_amp = 0.5 * (y.max() - y.min())  # sampled at 50 Hz: within 0.5 % of the continuous peak
            assert c.amplitude == pytest.approx(true_amp, rel=0.03)
        true = _true_switches(flight, st[0].t_start - 0.5, st[-1].t_end + 0.5)
        nearest = [true[np.argmin(np.abs(true - x))] for c in st for x in (c.t_start, c.t_end)]
        true_period = np.diff(np.reshape(nearest, (-1, 2)), axis=1).ravel()
        assert np.abs(t.period - true_period).max() <= 2 * TS + 1e-6
        assert t.period.mean() == pytest.approx(true_period.mean(), abs=0.5 * TS)


def test_switch_ticks_pins_a_sliding_bracket_and_says_when_the_logging_is_locked():
    # half-periods of 13 ticks alternate with 12 (a sampled relay between two orbits), logged every 5th tick
    true = np.concatenate(([0], np.cumsum(np.tile([13, 12], 15)))) + 2
    after = 5 * np.ceil(true / 5)
    sw = switch_ticks((after - 5) * TS, after * TS, TS)
    # a period of 25 ticks is 5 logging periods: the up-switches keep their place in their brackets,
    # and so do the down-switches: each kind is known up to a common shift, which shifted() spans
    assert sw.locked and len(sw.shifts()) == 25
    assert sum(np.allclose(sw.shifted(*m), true * TS, atol=1e-9) for m in sw.shifts()) == 1
    # 13-tick half-periods slide along the 5-tick logging grid: every switch is pinned
    true = 2 + 13 * np.arange(30)
    after = 5 * np.ceil(true / 5)
    sw = switch_ticks((after - 5) * TS, after * TS, TS)
    assert not sw.locked and sw.shifts() == [(0, 0)]
    np.testing.assert_allclose(sw.t, true * TS, atol=1e-9)


def test_fold_waveform_recovers_a_known_waveform_from_five_samples_a_cycle():
    # y = cos + 0.1 cos 3: four-and-a-bit samples per cycle whose phases slide (period 0.47 s, 10 Hz)
    P = 0.47
    t = np.arange(0.0, 14 * P, 0.1)
    y = np.cos(2 * np.pi * t / P) + 0.1 * np.cos(6 * np.pi * t / P)
    t0 = np.arange(14) * P
    w = fold_waveform(t, y, t0, t0 + P)
    assert w is not None and w.distinct_phases > 20
    assert w.amplitude == pytest.approx(1.1, rel=1e-3)  # the peak, not the fundamental (1.0)
    assert abs(w.coef[0]) == pytest.approx(1.0, rel=1e-3)
    # too few distinct phases: two samples a cycle at the same places
    assert fold_waveform(np.arange(0.0, 14.0, 0.5), np.ones(28), np.arange(14.0), np.arange(1.0, 15.0)) is None


def test_a_fold_over_a_locked_grid_of_12_phases_reads_the_peak_not_the_fundamental():
    # a 1.2 s cycle logged at 10 Hz: 12 samples a cycle at the same 12 phases (the logging locked to
    # it); the output of a relay through an integrating plant is near a parabola, whose fundamental
    # is 32 / pi^3 = 1.032 of its peak (closed form): one harmonic read K 3 % long (issue 24 part 3)
    P, n = 1.2, 10
    t = np.arange(0.0, n * P, 0.1)
    phi = (t / P) % 1.0
    y = np.where(phi < 0.5, 1.0 - (4 * phi - 1) ** 2, (4 * phi - 3) ** 2 - 1)  # peak 1, odd harmonics only
    y = y + np.random.default_rng(5).normal(0.0, 0.002, t.size)
    t0 = np.arange(n) * P
    assert fold_harmonics(t, y, t0, t0 + P) >= 3
    w = fold_waveform(t, y, t0, t0 + P, fold_harmonics(t, y, t0, t0 + P))
    assert w is not None and w.distinct_phases == 12
    assert abs(w.coef[0]) == pytest.approx(32 / np.pi ** 3, rel=5e-3)
    assert w.amplitude == pytest.approx(1.0, rel=1e-2)  # one harmonic: 1.032


def test_fold_amplitudes_carries_the_harmonic_counts_the_cycles_cannot_tell_apart():
    # the near-parabola (peak 1, third harmonic 0.038) over 3 cycles at a sliding 10 Hz grid, among
    # noise of 5 % of it: leaving one of 3 cycles out cannot tell the harmonic counts apart, and
    # the amplitudes they give bracket the peak where the one chosen is 2.5 % off; over 14 quiet
    # cycles the choice is clear and the peak alone is left
    def parabola(n, noise, seed):
        P = 1.27
        t = np.arange(0.0, n * P, 0.1)
        phi = (t / P) % 1.0
        y = np.where(phi < 0.5, 1.0 - (4 * phi - 1) ** 2, (4 * phi - 3) ** 2 - 1)
        return t, y + np.random.default_rng(seed).normal(0.0, noise, t.size), np.arange(n) * P, P

    t, y, t0, P = parabola(3, 0.05, 1)
    amps = fold_amplitudes(t, y, t0, t0 + P)
    assert abs(amps[0] - 1.0) > 0.02  # the choice alone: 2.5 % off
    assert amps.size >= 2 and amps.min() <= 1.0 <= amps.max() and np.ptp(amps) > 0.03
    t, y, t0, P = parabola(14, 0.001, 3)
    amps = fold_amplitudes(t, y, t0, t0 + P)
    assert np.all(np.abs(amps - 1.0) < 0.005)


def test_a_wandering_orbit_at_beta_minus_0_8_is_measured_at_its_level_and_amplitude():
    # a small relay height among noise (2.4 cm at 0.7 mm noise, as people fly it): the 1.7 Hz orbit
    # wanders by 1-3 ticks from cycle to cycle, 6 logged samples a cycle. Eight harmonics folded over
    # such cycles ring at the extrema (amplitude 31 mm against 25, beta -0.49: refused as "not the
    # nominal -0.8"); the harmonics the held-out cycles support measure it.
    m = LoopModel(0.0422, 1.48, 0.0493, 22.9)
    spec = FlightSpec(model=m, tests=(plan_test(m, -0.8, 0.0241, rate_hz=RATE, cycles=12.0),), loop="altitude",
                      rate_hz=RATE, noise_std=6.8e-4, bias=0.5, setpoint=1.0, hover_s=3.0, hold_s=3.0, seed=944675765)
    fl = simulate_flight(spec)
    (test,) = _ten_hz(fl)
    assert test.switch_timing == "vernier" and test.validity.ok, test.validity.reasons
    # the oracle: the noise-free 50 Hz output over each stable cycle, and its level at the true switches
    y = fl.output_true - fl.setpoint
    true = _true_switches(fl, test.stable[0].t_start - 0.5, test.stable[-1].t_end + 0.5)
    amps, levels = [], []
    for c in test.stable:
        sel = (fl.t >= c.t_start) & (fl.t < c.t_end)
        lo_, hi_ = y[sel].min(), y[sel].max()
        amps.append(0.5 * (hi_ - lo_))
        for x, sign in ((c.t_switch, 1.0), (c.t_end, -1.0)):
            k = np.searchsorted(fl.t, true[np.argmin(np.abs(true - x))])
            # the relay's level lies between the output at the tick before the switch and at the switch
            levels.append(sign * (0.5 * (y[k - 1] + y[k]) - 0.5 * (hi_ + lo_)) / (0.5 * (hi_ - lo_)))
    assert test.amplitude_mean == pytest.approx(np.mean(amps), rel=0.05)
    assert abs(test.beta_effective - np.mean(levels)) < 0.1


def test_the_switching_lag_drawn_into_the_bootstrap_keeps_td_where_the_tests_put_it(flight, tmp_path):
    # each test's place in the sampled relay's 0..Ts band is unseen at 10 Hz; drawn per test into the
    # bootstrap (not a linearised spread added in quadrature: Td [-1.2, 5.5] s, tau [-1.7, 23] ms on
    # this flight), the intervals stay positive and still hold the simulator's truth
    from mrftcli.analyze import AnalyzeOptions, analyze_flight
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.io.stacks import StackLogSpec, StackTest, write_stack_log

    tests = [StackTest(e["t_start"], e["t_end"], e["beta"], e["h"]) for e in flight.truth["tests"]]
    spec = StackLogSpec("px4-mrft", "altitude", flight.truth["bias"], tests, log_rate_hz=10)
    path = write_stack_log(tmp_path / "px4_10hz.ulg", spec, flight.t, flight.command, flight.output_measured,
                           flight.setpoint)
    r = analyze_flight(read_flight(path, ReadOptions(loop="altitude"), echo_warnings=False), soiptd_model(0.0422),
                       options=AnalyzeOptions(n_bootstrap=100, seed=1))
    assert len(r.tests) == 2 and all(t.controller_rate_hz == pytest.approx(RATE) for t in r.tests)
    truth = {"Td": 1.6, "tau": 0.015, "K": 15.0}
    for name, value in truth.items():
        est = getattr(r, name)
        assert est.ci95_low <= value <= est.ci95_high, (name, est)
    assert r.Td.ci95_low > 0.25 * truth["Td"] and r.tau.ci95_low > 0.0


def test_the_noise_of_a_folded_test_is_the_sensors_and_an_output_that_is_not_the_loops_stays_refused(flight, ten_hz):
    # the validity check's SNR divides by the scatter about each cycle's own fit (as at the
    # controller's rate), not about the fold: a wandering orbit's cycle-to-cycle change is the limit
    # cycle's, and counted as noise it refused a clean test ("3x the noise, need 3x")
    fast = ten_hz[0]
    assert fast.validity.ok and fast.validity.noise_std == pytest.approx(5e-4, rel=0.25)  # the simulator's noise
    sub = slice(0, None, 5)
    t, c, sp = flight.t[sub], flight.command[sub], flight.setpoint[sub]
    y = sp + 0.01 * np.random.default_rng(0).standard_normal(t.size)  # an output that does not follow the relay
    bt = np.array([e["t_start"] for e in flight.truth["tests"]])
    bv = np.array([e["beta"] for e in flight.truth["tests"]])
    tests = segment_arrays(Signal(t, c), Signal(t, y), setpoint=Signal(t, sp), beta=Signal(bt, bv),
                           options=SegmentOptions(controller_rate_hz=RATE))
    assert tests and all(not x.validity.ok and "snr" in x.validity.failed for x in tests)


def test_a_fold_whose_extrema_no_sample_reaches_is_not_measured():
    # the 2.3 Hz test settles in 20-tick cycles (4 logging periods: 4 samples a cycle at the same
    # phases) and moves to 23-25-tick ones; folded together the two orbits made a waveform whose
    # amplitude (41 % long) no cycle's samples come near, and K came out +22 % outside its interval.
    # Over a sliding grid the samples reach the extrema: such a fold is not measured (a refusal,
    # not a wrong number)
    m = LoopModel(0.0422, 2.942015362110934, 0.017509361416051937, 15.878255202321345)
    spec = FlightSpec(model=m, tests=(plan_test(m, -0.8, 0.05, rate_hz=RATE, cycles=14.0),), loop="altitude",
                      rate_hz=RATE, noise_std=0.000651768104031005, bias=0.5, setpoint=1.0, hover_s=3.0, hold_s=3.0,
                      seed=409493471)
    fl = simulate_flight(spec)
    (test,) = _ten_hz(fl)
    periods = np.rint(np.array([c.period for c in test.cycles]) / TS)
    assert periods.min() <= 20 and periods.max() >= 24  # both orbits in the test
    y = fl.output_true - fl.setpoint  # the oracle: the noise-free 50 Hz output over each stable cycle
    true = [0.5 * np.ptp(y[(fl.t >= c.t_start) & (fl.t < c.t_end)]) for c in test.stable]
    assert not test.stable or test.amplitude_mean == pytest.approx(np.mean(true), rel=0.05)


def test_a_settling_slow_test_is_stable_at_10_hz_where_it_is_at_50_hz():
    # people fly 8 cycles: this 0.8 Hz test (beta -0.3) settles from 42-tick half-periods to 33-35,
    # and its steady 70-tick cycles are 14 logging periods (the logging locked to it over that
    # stretch): the vernier places those switches 1-3 ticks off, a 66-tick cycle read 65 fell out
    # of the 6 % period floor, broke the run of consistent cycles, and the test was refused ("only
    # one beta was tested"; `users` 24618/5). The floor now carries the vernier's own period error
    # (TickSwitches.period_error); the oracle is the 50 Hz command and the noise-free output.
    from mrftcli.sim.spec import TestSpec

    m = LoopModel(0.0422, 2.863869290781451, 0.02259795150753204, 16.936644775988842)
    spec = FlightSpec(model=m, tests=(TestSpec(-0.8, 0.6271713742349762, 8.6), TestSpec(-0.3, 0.04538497666129388, 13.2)),
                      loop="altitude", rate_hz=RATE, noise_std=0.00020852931245329628, bias=0.5, setpoint=1.0,
                      hover_s=3.0, hold_s=3.0, seed=133972793)
    fl = simulate_flight(spec)
    slow = _ten_hz(fl)[1]
    assert slow.switch_timing == "vernier" and len(slow.stable) >= 3 and slow.validity.ok, slow.validity.reasons
    st = slow.stable
    true = _true_switches(fl, st[0].t_start - 0.5, st[-1].t_end + 0.5)
    # the true cycles over the same span: consistent (within 6 % of their median period), as the
    # 50 Hz log marks them
    t0 = true[np.argmin(np.abs(true - st[0].t_start))]
    t2 = true[np.argmin(np.abs(true - st[-1].t_end))]
    n = len(st)
    assert t2 - t0 == pytest.approx(sum(c.period for c in st), abs=3 * TS)  # the span within 3 ticks
    true_period = (t2 - t0) / n
    assert slow.period.mean() == pytest.approx(true_period, abs=3 * TS / n + 1e-9)
    y = fl.output_true - fl.setpoint
    amps = [0.5 * np.ptp(y[(fl.t >= c.t_start) & (fl.t < c.t_end)]) for c in st]
    assert slow.amplitude_mean == pytest.approx(np.mean(amps), rel=0.03)


def test_the_period_floor_takes_the_measured_periods_own_error():
    from mrftcli.segment.stability import stable_cycles

    # a steady 69-70-tick orbit whose one cycle is read 65 (a switch a tick off, 66 in truth): out of
    # the 6 % floor (4.2 ticks) without the error, inside with it; a start-up cycle 12 ticks long
    # stays out (the 15 % cap), and 0 is the controller-rate path's floor unchanged
    P = np.array([83.0, 74.0, 69.0, 70.0, 65.0, 69.0, 70.0]) * TS
    a = np.array([63.0, 52.0, 46.0, 46.0, 41.0, 45.5, 45.5])
    reg = np.ones(P.size, bool)
    stable, _, _ = stable_cycles(P, a, reg, TS)
    assert not stable.any()
    stable, consistent, _ = stable_cycles(P, a, reg, TS, period_error=1.75 * TS)
    assert stable.tolist() == [False, False, False, True, True, True, True] and not consistent[:2].any()
    # where the vernier pins every switch (a strictly periodic relay) the floor is not widened
    true = 3 + 13 * np.arange(20)
    after = 5 * np.ceil(true / 5)
    assert switch_ticks((after - 5) * TS, after * TS, TS).period_error() == pytest.approx(0.0, abs=1e-12)
