"""analyze's reason for a test left out with cycles enough but their periods scattered (issue 42): the relay
switched irregularly, and the user is told to raise h rather than to record longer tests.

Oracle: relay logs built here with known switch instants (each cycle's period is chosen), segmented by the
real segmenter; the hint must name the tolerance the stability criterion applied to that test (exact periods:
no MAD, so the 6 % floor, not the 15 % cap; a stationary amplitude scatter: the 60 % stationary cap) and stay
silent on a slow start-up followed by too short a limit cycle, whose all-cycle period spread is as large as the
scattered test's."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from mrftcli.analyze.screen import irregular_hint, no_usable_message, screen_tests
from mrftcli.io.logtypes import Signal
from mrftcli.segment import MrftTest, segment_arrays

RATE_HZ = 200.0


def _segmented(periods: list[float], amps: list[float] | None = None) -> MrftTest:
    """The one test the segmenter finds in a relay log whose cycles have the given periods [s] (and output
    amplitudes, 0.05 each by default): +1 then -1 for half a period each, the output -amp cos over the cycle
    (rising under +1), after a 1 s hold."""
    amp = np.asarray(amps if amps is not None else [0.05] * len(periods))
    edges = 1.0 + np.concatenate([[0.0], np.cumsum(periods)])
    t = np.arange(0.0, edges[-1] + 1.0, 1.0 / RATE_HZ)
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(periods) - 1)
    inside = (t >= edges[0]) & (t < edges[-1])
    phase = (t - edges[k]) / np.asarray(periods)[k]
    command = np.where(inside, np.where(phase < 0.5, 1.0, -1.0), 0.0)
    output = np.where(inside, -amp[k] * np.cos(2 * np.pi * phase), -amp[k])
    output = output + np.random.default_rng(0).normal(0.0, 0.0005, t.size)
    (test,) = segment_arrays(Signal(t, command), Signal(t, output))
    return test


def _all_cycle_spread(test: MrftTest) -> float:
    p = np.array([c.period for c in test.cycles])
    return float(np.std(p, ddof=1) / np.mean(p))


def test_scattered_periods_name_the_tolerance_the_test_got_and_the_relay_height() -> None:
    # 1.0 s cycles, every third or so 40 % off, never three in tolerance in a row: no stable cycle
    test = _segmented([1.0, 1.0, 1.0, 1.4, 1.0, 0.6, 1.0, 1.0, 1.4, 1.0, 0.6, 1.0, 1.0])
    periods = [c.period for c in test.cycles]
    assert test.n_stable == 0 and len(periods) >= 6
    off = sum(abs(p - 1.0) > 0.3 for p in periods)  # the 0.6 s and 1.4 s cycles, by construction
    assert off == 4
    hint = irregular_hint(test, 3)
    # exact periods have no MAD spread: the tolerance is the 6 % floor, not the 15 % cap the old hint quoted
    assert f"; of its {len(periods)} cycles {off} periods are off their median (1 s) by over the 6 % the " in hint
    assert "larger relay height h" in hint
    reasons = screen_tests([test], 3)
    assert reasons[test.index].startswith("0 stable cycles (need 3); of its")
    flight = SimpleNamespace(path="f.ulg", source={}, loop="z")
    msg = no_usable_message(flight, [test], reasons, 3, 0.0)  # type: ignore[arg-type]
    assert "scatter beyond the tolerances the stability criterion allowed" in msg and "larger relay height" in msg


def test_scattered_amplitudes_at_one_period_name_the_amplitude_tolerance() -> None:
    # every period 1.0 s (the old all-period spread is 0); the amplitudes 5 cm, every third or so 1 or 10 cm,
    # never three in a row at 5 cm: a scatter with no trend, so the criterion's stationary caps apply (60 %)
    a = [0.05, 0.05, 0.05, 0.1, 0.05, 0.01, 0.05, 0.05, 0.1, 0.05, 0.01, 0.05, 0.05]
    test = _segmented([1.0] * len(a), a)
    assert test.n_stable == 0 and len(test.cycles) >= 6
    hint = irregular_hint(test, 3)
    cap = test.criterion.stationary_amplitude_cap_rel
    assert f"4 amplitudes off their median by over the {cap * 100:.0f} % the stability criterion allowed this test" in hint
    assert "periods are off" not in hint and "larger relay height h" in hint


def test_a_slow_start_before_too_short_a_limit_cycle_is_not_called_irregular() -> None:
    # the period converges 1.9 -> 1.0 s, then three 1.0 s cycles: too few stable, but nothing irregular
    test = _segmented([2.2, 1.9, 1.6, 1.3, 1.0, 1.0, 1.0, 1.0])
    assert len(test.cycles) >= 6 and 0 < test.n_stable < 3
    assert _all_cycle_spread(test) > test.criterion.period_cap_rel  # the old all-cycle formula fired here
    assert irregular_hint(test, 3) == ""
    reasons = screen_tests([test], 3)
    flight = SimpleNamespace(path="f.ulg", source={}, loop="z")
    assert "record longer tests" in no_usable_message(flight, [test], reasons, 3, 0.0)  # type: ignore[arg-type]


def test_a_short_test_gets_no_hint() -> None:
    test = _segmented([1.0, 1.0, 1.4, 1.0, 0.6, 1.0])  # 4 cycles measured: under 2 x 3
    assert len(test.cycles) < 6 and irregular_hint(test, 3) == ""
