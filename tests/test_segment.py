"""Segmenter: relay runs, timestamps, stable-cycle criterion, per-cycle measurements, robustness.

Oracles: synthetic signals built here with known switch instants/levels, and the independent exact
closed-loop simulation in ``test_segment_support.py`` (its relay decisions are the truth for the
switch instants; its exact noise-free output is the truth for the switching levels).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mrftcli.errors import SegmentationError
from mrftcli.io.logtypes import FlightLog, Signal
from mrftcli.segment import (
    StabilityCriterion,
    find_relay_runs,
    regularise_times,
    segment,
    segment_arrays,
    stable_cycles,
)
from test_segment_support import simulate_relay_flight, to_flight

# Altitude loop of the paper's Design II (checks.md section 4); K and h give ~4 cm oscillations.
TP, TD, TAU, K = 0.0499, 1.8345, 0.0498, 2.0


@pytest.fixture(scope="module")
def sim():
    return simulate_relay_flight(TP, TD, TAU, K, [(-0.4, 0.8, 20.0), (-0.7, 2.0, 12.0)], seed=3, takeoff_s=3.0)


def _switches(t, c, bias):
    """Independent switch list: first samples of each new relay level."""
    s = np.sign(c - bias)
    idx = np.flatnonzero(s[1:] != s[:-1]) + 1
    return t[idx], s[idx]


# ----------------------------------------------------------------------------------------------- runs


def test_relay_runs_in_noisy_command_between_pid_flight():
    rng = np.random.default_rng(0)
    n_pid = 400
    pid = 0.5 + 0.05 * np.cumsum(rng.normal(0, 0.02, n_pid))  # smooth wandering PID command
    half = 37
    relay = np.concatenate([np.full(half, 0.5 + s * 0.2) for s in ([1, -1] * 10)])
    relay2 = np.concatenate([np.full(23, 0.45 + s * 0.1) for s in ([-1, 1] * 8)])
    c = np.concatenate([pid, relay, pid[::-1], relay2, pid])
    c = c + rng.normal(0, 0.002, c.size)  # noise on the logged command
    chains = find_relay_runs(c)
    assert len(chains) == 2
    lv1 = np.array([r.level for r in chains[0]])
    assert len(chains[0]) == 20 and chains[0][0].start == n_pid
    assert np.allclose(np.sort(np.unique(np.round(lv1, 2))), [0.3, 0.7], atol=0.005)
    lv2 = np.array([r.level for r in chains[1]])
    assert len(chains[1]) == 16
    assert np.allclose(np.sort(np.unique(np.round(lv2, 2))), [0.35, 0.55], atol=0.005)


def test_single_sample_false_switch_is_absorbed_and_flagged():
    c = np.concatenate([np.full(30, 1.0 if k % 2 == 0 else -1.0) for k in range(10)])
    c[75] = -1.0  # a one-sample false switch inside the third half-period (+1 level)
    chains = find_relay_runs(c)
    assert len(chains) == 1
    runs = chains[0]
    assert len(runs) == 10
    assert runs[2].glitch and not runs[1].glitch
    assert [r.start for r in runs] == list(range(0, 300, 30))


def test_no_relay_in_a_pid_only_log_raises():
    rng = np.random.default_rng(1)
    t = np.arange(4000) / 200.0
    c = 0.5 + 0.01 * np.sin(2 * np.pi * 0.3 * t) + rng.normal(0, 0.003, t.size)
    y = 1.0 + rng.normal(0, 5e-4, t.size)
    flight = FlightLog(path="pid.csv", loop="altitude", command=Signal(t, c), output=Signal(t, y))
    with pytest.raises(SegmentationError, match="no MRFT relay test"):
        segment(flight)


# ----------------------------------------------------------------------------------------------- times


def test_regularise_times_removes_jitter_and_keeps_gaps():
    rng = np.random.default_rng(2)
    n = np.arange(2000)
    n = np.delete(n, [100, 101, 700])  # dropped messages
    true = 3.0 + n * 0.005
    t = true + rng.normal(0, 0.0004, n.size)
    t_reg, ok = regularise_times(t)
    assert ok
    assert np.max(np.abs(t_reg - true)) < 5e-5
    # a clock that is not a grid is left alone
    t_irr = np.cumsum(rng.uniform(0.001, 0.009, 500))
    t2, ok2 = regularise_times(t_irr)
    assert not ok2 and np.array_equal(t2, t_irr)


# ----------------------------------------------------------------------------------------------- criterion


def test_stable_cycles_drops_transient_and_outliers():
    rng = np.random.default_rng(3)
    P = 1.0 + rng.normal(0, 0.003, 20)
    a = 0.05 + rng.normal(0, 0.0003, 20)
    P[:3] = [0.6, 0.85, 0.92]  # start-up
    a[:3] = [0.01, 0.03, 0.04]
    P[12] = 1.3  # a disturbed cycle
    reg = np.ones(20, bool)
    reg[15] = False  # a gap
    stable, consistent, info = stable_cycles(P, a, reg, 0.005, StabilityCriterion())
    assert not stable[:4].any()  # transient, and the first consistent cycle (may still converge)
    assert stable[4:12].all() and not stable[12] and not stable[15] and stable[16:].all()
    assert info["period_median"] == pytest.approx(1.0, abs=0.01)


def _cycle_map(n, rng, multiplier=-0.8, rel=0.07):
    """Period and amplitude of a relay limit cycle kicked by noise every cycle: the deviation of each
    cycle is ``multiplier`` times the last one's plus a new kick (a jittery MRFT at beta -0.7
    alternates like this), about 1 s and 0.05."""
    e = np.zeros(n)
    for k in range(1, n):
        e[k] = multiplier * e[k - 1] + rng.normal(0.0, rel)
    return 1.0 + e, 0.05 * (1.0 + 2.0 * e)


def test_a_noisy_stationary_limit_cycle_is_kept_and_a_drift_is_not():
    rng = np.random.default_rng(11)
    kept = []
    for _ in range(20):
        P, a = _cycle_map(14, rng)
        stable, _, info = stable_cycles(P, a, np.ones(14, bool), 0.01, StabilityCriterion())
        kept.append(int(stable.sum()))
        assert info["stationary"]
    # every cycle after the first of the first run of three (the rule for the start-up transient)
    assert min(kept) >= 10
    # a level that grows by half over the test (a slow start-up or a drift) keeps the capped
    # tolerances: the same cycles as with the stationary test switched off
    for _ in range(20):
        P, a = _cycle_map(14, rng, rel=0.02)
        ramp = np.linspace(0.0, 0.5, 14)
        P, a = P * (1 + 0.3 * ramp), a * (1 + ramp)
        stable, _, info = stable_cycles(P, a, np.ones(14, bool), 0.01, StabilityCriterion())
        assert not info["stationary"]
        capped, _, _ = stable_cycles(P, a, np.ones(14, bool), 0.01, StabilityCriterion(stationary_z=0.0))
        assert (stable == capped).all()


# ----------------------------------------------------------------------------------------------- on a flight


def test_segment_finds_tests_levels_and_switches(sim):
    flight = to_flight(sim)
    tests = segment(flight)
    assert len(tests) == 2
    for test, (t0, t1, beta, h) in zip(tests, sim.test_windows):
        assert test.beta_nominal == beta
        assert test.h == pytest.approx(h, rel=1e-9)
        assert test.bias == pytest.approx(0.5, abs=1e-9)
        assert t0 - 1e-6 <= test.t_start < t0 + 0.01 and t1 - 0.01 < test.t_end <= t1 + 1e-6
        assert test.rate_hz == pytest.approx(200.0, rel=1e-6)
        assert test.n_stable >= 8
        # every stable cycle's boundaries are switch instants of the simulated relay
        m = (sim.t >= t0) & (sim.t <= t1)
        ts, sgn = _switches(sim.t[m], sim.command[m], 0.5)
        ups = ts[sgn > 0]
        for c in test.stable:
            assert np.min(np.abs(ups - c.t_start)) < 1e-9 and np.min(np.abs(ups - c.t_end)) < 1e-9
            assert c.half_period_high + c.half_period_low == pytest.approx(c.period)


def test_amplitude_and_effective_beta_against_the_noise_free_output(sim):
    """Fitted extrema and switch-instant outputs vs the simulation's exact output at its samples."""
    tests = segment(to_flight(sim))
    y_true = sim.y_true - sim.setpoint
    for test in tests:
        errs_a, errs_b = [], []
        for c in test.stable:
            seg = (sim.t >= c.t_start) & (sim.t <= c.t_end)
            a_true = (y_true[seg].max() - y_true[seg].min()) / 2  # 5 ms samples: within 0.1 % of the peak
            centre = (y_true[seg].max() + y_true[seg].min()) / 2
            i_dn = np.searchsorted(sim.t, c.t_switch - 1e-9)
            i_up = np.searchsorted(sim.t, c.t_end - 1e-9)
            b_true = 0.5 * ((y_true[i_dn] - centre) - (y_true[i_up] - centre)) / a_true
            errs_a.append(c.amplitude / a_true - 1)
            errs_b.append(c.beta_effective - b_true)
        # noise 0.5 mm on ~4 cm: per cycle the fits are within ~1 %; the test means much closer
        assert abs(np.mean(errs_a)) < 0.004
        assert abs(np.mean(errs_b)) < 0.004
        assert np.std(errs_b) < 0.02


def test_measured_effective_beta_differs_from_nominal_like_the_relay_did(sim):
    """The noisy sampled relay switches away from the nominal level; the estimate follows the relay."""
    tests = segment(to_flight(sim))
    y_true = sim.y_true - sim.setpoint
    for test in tests:
        lv = []
        for c in test.stable:
            i_up = np.searchsorted(sim.t, c.t_end - 1e-9)
            lv.append(-(y_true[i_up] - c.centre) / c.amplitude)
        assert test.beta_effective == pytest.approx(np.mean(lv), abs=0.006)


def test_dropped_messages_jitter_and_glitches(sim):
    rng = np.random.default_rng(4)
    base = segment(to_flight(sim))
    keep = rng.random(sim.t.size) > 0.05
    t_jit = np.sort(sim.t + rng.normal(0, 0.0005, sim.t.size))
    flight = to_flight(sim, t_cmd=t_jit, keep=keep)
    c = flight.command.values.copy()
    for tg in (11.3, 17.1, 33.2):  # one-sample false switches
        i = int(np.searchsorted(flight.command.t, tg))
        c[i] = 1.0 - c[i]
    flight = replace(flight, command=Signal(flight.command.t, c))
    tests = segment(flight)
    assert len(tests) == 2
    for t, b in zip(tests, base):
        assert t.timestamps_regularised
        assert t.n_stable >= 6
        assert t.frequency_hz_mean == pytest.approx(b.frequency_hz_mean, rel=0.004)
        assert t.amplitude_mean == pytest.approx(b.amplitude_mean, rel=0.01)
        assert t.beta_effective == pytest.approx(b.beta_effective, abs=0.01)
    assert any("glitch" in c.flags for t in tests for c in t.cycles)


def test_negative_loop_gain_is_handled(sim):
    flight = to_flight(sim)
    flight = replace(flight, output=Signal(flight.output.t, -flight.output.values),
                     setpoint=Signal(flight.setpoint.t, -flight.setpoint.values))
    neg = segment(flight)
    pos = segment(to_flight(sim))
    for a, b in zip(neg, pos):
        assert a.loop_sign == -1
        assert a.frequency_hz_mean == pytest.approx(b.frequency_hz_mean, rel=1e-9)
        assert a.beta_effective == pytest.approx(b.beta_effective, abs=1e-9)


def test_segment_arrays_without_beta_or_setpoint(sim):
    tests = segment_arrays(Signal(sim.t, sim.command), Signal(sim.t, sim.y_meas))
    assert len(tests) == 2
    assert all(t.beta_nominal is None and t.setpoint is None for t in tests)
    assert tests[0].beta_effective == pytest.approx(-0.4, abs=0.04)
    assert tests[1].beta_effective == pytest.approx(-0.7, abs=0.05)


# ----------------------------------------------------------------------------------------------- fundamental harmonic


def _plant_response(W):
    """G(j W) of the simulated plant, closed form (eq. 2)."""
    return K * TD * np.exp(-1j * W * TAU) / (1j * W * (1j * TP * W + 1) * (1j * TD * W + 1))


@pytest.mark.parametrize("noise, tol_phase, tol_gain", [(0.0, 1.5e-3, 1.5e-3), (5e-4, 4e-3, 4e-3)])
def test_fundamental_harmonic_is_the_plant_frequency_response(noise, tol_phase, tol_gain):
    """arg/|Y1/U1| per cycle against the closed-form G(j Omega) of the simulated plant.

    The relay switched wherever its noisy samples made it; the harmonic ratio does not depend on
    that level, so it must equal G(j Omega) at each cycle's own frequency.
    """
    sim = simulate_relay_flight(TP, TD, TAU, K, [(-0.4, 0.8, 14.0), (-0.7, 2.0, 9.0)], seed=4, takeoff_s=2.0,
                                noise_std=noise)
    for test in segment(to_flight(sim)):
        W = 2 * np.pi / test.period
        g = _plant_response(W)
        ph_true = np.angle(g) - 2 * np.pi * (np.angle(g) > 0)
        ph = np.array([c.phase_h1 for c in test.stable])
        gain = np.array([c.gain_h1 for c in test.stable])
        assert np.all((ph <= 0) & (ph > -2 * np.pi))
        assert abs(np.mean(ph - ph_true)) < tol_phase
        assert abs(np.mean(gain / np.abs(g) - 1)) < tol_gain


# ----------------------------------------------------------------------------------------------- the shared harmonic fit


def test_harmonic_fit_recovers_a_known_cycle():
    """A line plus harmonics 1, 3 and 5 is recovered exactly: the level at x = 0, the drift per period (and
    from them the level at mid-cycle and the drift per second, diagnose's features)."""
    from mrftcli.mrft.harmonics import fit_harmonics

    rng = np.random.default_rng(11)
    P = rng.uniform(0.2, 2.0)
    x = np.sort(rng.uniform(0.0, P, 300))
    Y = {1: 0.8 - 0.3j, 3: 0.05 + 0.02j, 5: -0.01j}
    c0, slope = 1.7, 0.4  # level at x = 0 [units], drift [units/s]
    y = c0 + slope * x + sum(np.real(v * np.exp(1j * k * 2 * np.pi * x / P)) for k, v in Y.items())
    expect = np.array([Y.get(k, 0.0) for k in range(1, 8)])
    per = fit_harmonics(x, y, P, 7)
    np.testing.assert_allclose(per.harmonics, expect, atol=1e-10)
    assert np.max(np.abs(per.residual)) < 1e-10
    np.testing.assert_allclose(per(np.array([0.1, 0.2]) * P), np.interp([0.1 * P, 0.2 * P], x, y), atol=1e-3)
    assert per.coef[0] == pytest.approx(c0) and per.coef[1] == pytest.approx(slope * P)
    assert per.coef[0] + 0.5 * per.coef[1] == pytest.approx(c0 + slope * P / 2)
    assert per.coef[1] / P == pytest.approx(slope)


def test_harmonic_fit_is_bit_identical_to_the_projections_it_replaced():
    """The segmenter's former inline fit (copied here) gives the very same bits; the diagnosis's (its trend
    x - P/2 in seconds, its angle x (k w)) the same model to rounding, its level and drift read from the
    one fit's (issue 36)."""
    from mrftcli.mrft.harmonics import fit_harmonics

    rng = np.random.default_rng(12)
    P = 0.73
    tt = np.sort(rng.uniform(0.0, P, 150))
    yy = np.sin(2 * np.pi * tt / P) + 0.1 * tt + rng.normal(0, 0.01, tt.size)
    # segment (8 harmonics, trend x / P, angle (x k) w)
    H, w, k = 8, 2.0 * np.pi / P, np.arange(1, 9)
    arg = np.outer(tt, k) * w
    A = np.hstack([np.ones((tt.size, 1)), (tt / P)[:, None], np.cos(arg), np.sin(arg)])
    coef, *_ = np.linalg.lstsq(A, yy, rcond=None)
    fit = fit_harmonics(tt, yy, P, H)
    assert np.array_equal(fit.coef, coef) and np.array_equal(fit.residual, yy - A @ coef)
    assert complex(fit.harmonics[0]) == complex(coef[2], -coef[2 + H])
    # diagnose features (7 harmonics, trend x - P/2, angle x (k w))
    H, k = 7, np.arange(1, 8)
    ph = np.outer(tt, k * w)
    X = np.column_stack([np.ones(tt.size), tt - 0.5 * P, np.cos(ph), np.sin(ph)])
    coef, *_ = np.linalg.lstsq(X, yy, rcond=None)
    fit = fit_harmonics(tt, yy, P, H)
    level, drift = fit.coef[0] + 0.5 * fit.coef[1], fit.coef[1] / P
    np.testing.assert_allclose([level, drift, *fit.coef[2:]], coef, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(fit.residual, yy - X @ coef, rtol=0, atol=1e-12)


def test_segment_options_are_checked_on_creation():
    from mrftcli.errors import InputError
    from mrftcli.segment import SegmentOptions

    assert SegmentOptions(min_runs=np.int64(4)).min_runs == 4
    for bad in ({"min_runs": 1}, {"min_runs": 2.5}, {"min_runs": True}, {"controller_rate_hz": 0.0},
                {"controller_rate_hz": float("nan")}):
        with pytest.raises(InputError):
            SegmentOptions(**bad)


# ----------------------------------------------------------------------------------------------- cycle bounds


@pytest.mark.parametrize("shift", [-1e-13, 1e-13])
def test_a_sample_on_a_cycle_bound_counts_the_same_whatever_the_rounding(sim, shift):
    """Output samples lying on the switch instants (one clock for both signals) are moved 1e-13 s
    either side, as two grid fits' rounding moves them: every cycle holds the same samples, so every
    measurement agrees to rounding (counting one sample more or less moved Td by 0.4 %)."""
    flight = to_flight(sim)
    moved = replace(flight, output=Signal(flight.output.t + shift, flight.output.values))
    for a, b in zip(segment(flight), segment(moved), strict=True):
        assert [c.stable for c in a.cycles] == [c.stable for c in b.cycles]
        for name in ("noise_std", "phase_h1", "gain_h1", "amplitude", "beta_effective"):
            x = np.array([getattr(c, name) for c in a.stable])
            y = np.array([getattr(c, name) for c in b.stable])
            np.testing.assert_allclose(y, x, rtol=1e-7, atol=1e-10, err_msg=name)


def test_a_flight_segmented_twice_is_measured_once(sim, monkeypatch):
    """diagnose segments a log analyze refused (one beta) again: the second pass over the same
    flight with the same options is the first one's tests; other options or another flight are measured."""
    import mrftcli.segment.segmenter as segmenter

    calls = []
    measure = segmenter.segment_arrays
    monkeypatch.setattr(segmenter, "segment_arrays", lambda *a, **k: calls.append(1) or measure(*a, **k))
    flight = to_flight(sim)
    first = segment(flight)
    again = segment(flight)
    assert len(calls) == 1 and again == first and again is not first
    assert len(segment(flight, min_runs=8)) == len(first) and len(calls) == 2  # other options: measured
    other = segment(to_flight(sim))  # an equal flight, but another object: measured
    assert len(calls) == 3 and [t.frequency_hz_mean for t in other] == [t.frequency_hz_mean for t in first]
    assert segmenter._LAST._entry is None  # that flight is gone: its tests are not kept


def test_a_test_longer_than_max_cycles_is_measured_on_its_first_cycles_and_says_so(sim, monkeypatch):
    """A 14-hour relay test (50 000 cycles, a minute of CPU a pass) is measured on its first
    MAX_CYCLES cycles: the same cycles as when measured whole, a note naming what was left out."""
    import mrftcli.segment.segmenter as segmenter

    whole = segment(to_flight(sim))
    monkeypatch.setattr(segmenter, "MAX_CYCLES", 6)
    cut = segment(to_flight(sim))
    assert len(cut) == len(whole)
    for a, b in zip(whole, cut, strict=True):
        assert len(a.cycles) > 6 >= len(b.cycles) >= 5 and b.t_end < a.t_end and b.t_start == pytest.approx(a.t_start)
        assert [c.period for c in b.cycles] == pytest.approx([c.period for c in a.cycles[:len(b.cycles)]], rel=1e-9)
        assert [c.amplitude for c in b.cycles] == pytest.approx([c.amplitude for c in a.cycles[:len(b.cycles)]],
                                                                 rel=1e-9)
        assert any("after the first 6: only those are measured" in n for n in b.notes)
        assert not any("only those are measured" in n for n in a.notes)


def _locked_up(sim, k_down: int):
    """The simulated flight with its first test's relay locked at -h from its ``k_down``-th down-switch to
    the test's end (a noise-triggered switch, then no extremum to switch on), the output falling away under
    -h as the double integrator K h t^2 / 2 does (the drift a safety abort stops), and that switch's time."""
    t0, t1, _, h = sim.test_windows[0]
    m = (sim.t >= t0) & (sim.t <= t1)
    ts, sgn = _switches(sim.t[m], sim.command[m], 0.5)
    t_k = ts[sgn < 0][k_down]
    lock = (sim.t >= t_k) & (sim.t <= t1)
    command, y = sim.command.copy(), sim.y_meas.copy()
    command[lock] = 0.5 - h
    k0 = int(np.flatnonzero(lock)[0])
    y[lock] = y[k0] - 0.5 * K * h * (sim.t[lock] - t_k) ** 2 + (sim.y_meas[lock] - sim.y_true[lock])
    return replace(sim, command=command, y_meas=y), t_k


@pytest.mark.parametrize("k_down", [2, 6])
def test_a_relay_that_locks_up_ends_its_test_at_the_lock_and_keeps_the_cycles_before(sim, k_down):
    """A test whose relay stops switching (held at -h to the test's end while the vehicle falls away) ends
    at the switch before the one into that level: the loop sign and the cycles before it are those of the
    same flight unlocked, and a note says when the relay locked up, in the test's own time (the warnings'
    "test at X s" prefix counts from the log's start; the log's own clock would be a second clock on the
    line). Before, the test ran on to the abort, and where few cycles preceded the lock (k_down 2) the fall
    (metres against a 4 cm limit cycle) in the output window turned the loop sign, so every amplitude was
    measured on the inverted output."""
    locked, t_k = _locked_up(sim, k_down)
    whole = segment(to_flight(sim))[0]
    test = segment(to_flight(locked))[0]
    t0, t1, _, _ = sim.test_windows[0]
    m = (sim.t >= t0) & (sim.t <= t1)
    ts, _ = _switches(sim.t[m], sim.command[m], 0.5)
    t_before = ts[ts < t_k][-1]  # the switch before the one into the held level
    assert test.t_end == pytest.approx(t_before, abs=1e-9) and test.loop_sign == whole.loop_sign == 1
    before = [c for c in whole.cycles if c.t_end < t_k]
    assert len(before) >= k_down - 1 and len(test.cycles) == len(before)
    for a, b in zip(before[:-1], test.cycles[:-1], strict=True):  # the last one's fit window meets the end
        assert (b.period, b.amplitude) == pytest.approx((a.period, a.amplitude), rel=1e-6)
    assert test.n_stable >= (3 if k_down == 6 else 0)
    note = next(n for n in test.notes if "stopped switching" in n and "locked up" in n)
    assert f"stopped switching {t_k - test.t_start:.1f} s into the test" in note
    assert f"ends at the switch before, {t_before - test.t_start:.1f} s into it" in note
    assert not any("locked up" in n for n in whole.notes)


@pytest.mark.parametrize("frac", [0.6, 0.8])
def test_a_relay_locked_by_an_early_switch_keeps_no_short_cycle(sim, frac):
    """The switch into a held level is the one that went wrong: noise triggers it early, and the relay then
    waits for an extremum that never comes. Held at +h, that up-switch closes a cycle whose -h half is cut
    short (here to ``frac`` of it: 8-15 % short of the period), which the stability rule kept as stable
    (the spread it adds widens the tolerance) before: the test now ends at the switch before it, and every
    cycle it keeps is one of the unlocked flight's."""
    t0, t1, _, h = sim.test_windows[0]
    m = (sim.t >= t0) & (sim.t <= t1)
    ts, sgn = _switches(sim.t[m], sim.command[m], 0.5)
    t_u = ts[sgn > 0][6]
    t_d = ts[(sgn < 0) & (ts < t_u)][-1]
    t_p = t_d + frac * (t_u - t_d)  # the early switch to +h, held to the test's end as the vehicle climbs away
    lock = (sim.t >= t_p) & (sim.t <= t1)
    command, y = sim.command.copy(), sim.y_meas.copy()
    command[lock] = 0.5 + h
    k0 = int(np.flatnonzero(lock)[0])
    y[lock] = y[k0] + 0.5 * K * h * (sim.t[lock] - sim.t[k0]) ** 2 + (sim.y_meas[lock] - sim.y_true[lock])
    whole = segment(to_flight(sim))[0]
    test = segment(to_flight(replace(sim, command=command, y_meas=y)))[0]
    assert test.t_end == pytest.approx(t_d, abs=1e-9)  # before: t_p
    assert test.cycles and all(c.t_end < t_d for c in test.cycles)
    for c in test.cycles:
        same = min(whole.cycles, key=lambda w: abs(w.t_end - c.t_end))  # the unlocked flight's cycle there
        assert abs(same.t_end - c.t_end) < 0.05 and c.period == pytest.approx(same.period, abs=0.02), c.t_end


def test_analyze_says_a_tests_notes_after_the_time_it_starts_from_the_log_start(sim):
    """analyze's screening (and delay's, through the same analyze.screen.prefixed_notes) gives each test's
    own notes after 'test at X s' (X from the log's start), the lock-up note then in the test's own time."""
    from mrftcli.analyze.screen import log_start, prefixed_notes, screen
    from mrftcli.mrft.model import soiptd_model

    locked, t_k = _locked_up(sim, 6)
    flight = to_flight(locked)
    found = segment(flight)
    t0 = log_start(flight)
    warnings = screen(flight, found, soiptd_model(TP), 3).warnings
    test = found[0]
    line = next(w for w in warnings if "stopped switching" in w)
    assert line.startswith(f"test at {test.t_start - t0:.1f} s: the relay stopped switching "
                           f"{t_k - test.t_start:.1f} s into the test")
    assert prefixed_notes(found, t0) == [f"test at {t.t_start - t0:.1f} s: {n}" for t in found for n in t.notes]
    assert all(w in warnings for w in prefixed_notes(found, t0))
