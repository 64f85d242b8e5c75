"""A command with dropped messages: the tick numbering runs on through the gaps, and a switch that
may sit in a gap carries one tick of uncertainty into the output-error fit (issue 38, item 1).

Oracles: constructed commands whose missing ticks are known; scipy's own linear simulation
(``scipy.signal.lsim``, zero-order hold on a fine grid) of eq. (2)'s transfer function; and the
flight simulator (mrftcli.sim, which shares no code with the segmenter or the refinement), whose
switch ticks are known before any message is dropped.
"""

from dataclasses import replace

import numpy as np
import pytest
from scipy import signal

from mrftcli.io.logtypes import Signal
from mrftcli.mrft.identify import ParameterEstimate
from mrftcli.mrft.model import LoopModel
from mrftcli.mrft.refine import refine, refinement_windows
from mrftcli.mrft.waveform import CommandWindow, response_basis
from mrftcli.segment import segment
from mrftcli.segment.runs import rebuild_send_times
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight
from mrftcli.sim.stamps import recorded_flight

DT = 0.005


def _square(n: int = 200, switches: tuple[int, ...] = (50, 100, 150)) -> np.ndarray:
    """A relay command of +-1 whose message at each tick in ``switches`` is the first at the new level."""
    u = np.ones(n)
    for s in switches[0::2]:
        u[s:] = -1.0
    for s in switches[1::2]:
        u[s:] = 1.0
    return u


def test_a_dropped_switch_message_leaves_its_tick_unknown_and_a_dropped_flat_one_is_held():
    t, u = DT * np.arange(200), _square()
    kept = np.delete(np.arange(200), [50, 120, 99, 100])  # 50: a switch; 120: mid-run; 99-100: before and at one
    w = CommandWindow.from_arrays(t[kept], u[kept], t)
    assert w.free.tolist() == [50, 99, 100]  # the switch may sit at any missing tick of its gap
    assert w.u[50] == 0.0 and w.u[99] == 0.0  # the middle of the two levels stands for them
    assert w.u[120] == u[120]  # the same level either side: held, known
    assert np.array_equal(np.delete(w.u[:200], [50, 99, 100]), np.delete(u, [50, 99, 100]))


def test_a_receive_stamped_command_keeps_its_ticks_through_the_gaps():
    """Numbered through the gaps, the rebuilt times put every message on its own tick, so a gap at
    a switch is found where it is (numbered by position, every message after it would be a tick early)."""
    rng = np.random.default_rng(8)
    n = 2000
    sent, u = 10.0 + DT * np.arange(n), _square(n, tuple(range(40, n, 37)))
    lost = np.array([40, 77, 500, 1301, 1302])  # two switch messages, a flat one, two in a row
    kept = np.delete(np.arange(n), lost)
    r = rebuild_send_times(sent[kept] + rng.uniform(0.0, 0.003, kept.size))
    assert r.rebuilt and r.dropped == lost.size
    assert np.max(np.abs(r.t - sent[kept])) < 2e-5
    w = CommandWindow.from_arrays(r.t, u[kept], r.t)
    switch_gaps = [g for g in lost if u[g] != u[g - 1] or u[g + 1] != u[g]]
    assert w.free.tolist() == switch_gaps == [40, 77]
    assert np.array_equal(np.delete(w.u[:n], w.free), np.delete(u, w.free))


def test_the_pulse_response_of_an_unknown_tick_is_eq2s_response_to_one_tick_of_command():
    m = LoopModel(0.04, 1.5, 0.03, 12.0)
    t, u = DT * np.arange(400), _square(400, (100, 180, 260, 340))
    kept = np.delete(np.arange(400), [180])
    to = t[8:] + 0.002  # between the ticks
    w = CommandWindow.from_arrays(t[kept], u[kept], to)
    assert w.free.tolist() == [180]
    A, B, C = m.state_space()
    pulse = response_basis(A, B, C, m.tau, w).pulses[:, 0]
    # scipy's simulation of K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1)) driven by one tick of unit
    # command at t_180, on a fine grid (tau and the output times are whole multiples of its step)
    h = DT / 40
    tf = h * np.arange(int(round(to[-1] / h)) + 1)
    drive = ((tf >= t[180] + m.tau - 1e-12) & (tf < t[180] + DT + m.tau - 1e-12)).astype(float)
    den = np.polymul(np.polymul([m.Tp, 1.0], [m.Td, 1.0]), [1.0, 0.0])
    _, y, _ = signal.lsim((np.array([m.K * m.Td]), den), drive, tf, interp=False)
    ref = y[np.rint(to / h).astype(int)]
    assert np.max(np.abs(pulse - ref)) < 1e-6 * np.max(np.abs(ref))
    assert np.max(np.abs(ref)) > 0


@pytest.fixture(scope="module")
def flight():
    m = LoopModel(0.0422, 1.6, 0.045, 14.0)
    tests = tuple(plan_test(m, b, 0.05, cycles=6, min_duration=3.0) for b in (-0.6, -0.3))
    spec = FlightSpec(model=m, tests=tests, loop="altitude", switching="hear", rate_hz=200.0, noise_std=5e-4,
                      seed=21)
    return m, simulate_flight(spec)


def _refit(log, tests, free: bool):
    windows = refinement_windows(tests, log.command.t, log.command.values, log.output.t, log.output.values)
    if not free:  # the zero-order hold's reading: the old level held through the gap
        held = []
        for w in windows:
            u = w.u.copy()
            for j in w.free:
                u[j] = u[j - 1]
            held.append(replace(w, u=u, free=np.zeros(0, dtype=np.intp)))
        windows = held
    wide = {n: ParameterEstimate(v, 0.0, 0.0, 10.0 * v + 1.0, "") for n, v in (("Td", 1.6), ("tau", 0.045),
                                                                               ("K", 14.0))}
    start = LoopModel(0.0422, 1.9, 0.052, 13.0)
    return windows, refine(windows, start, wide, loop_sign=tests[0].loop_sign)


@pytest.mark.parametrize("at", ["switch", "before"])
def test_a_switch_in_a_gap_carries_one_tick_of_uncertainty_into_the_intervals(flight, at):
    """Every switch's message (or the one before each switch) lost: the truth is at the missing tick
    (or at the next message). The fit leaves those ticks free, the truth is inside the intervals,
    and they widen against the log with every message; holding the old level through the gap (the
    switch a tick late every time) misses the truth."""
    m, fl = flight
    full = recorded_flight(fl)
    tests = segment(full)
    c = fl.command
    switches = np.flatnonzero(np.abs(np.diff(c)) > 0.5 * np.ptp(c)) + 1
    lost = switches if at == "switch" else switches - 1
    kept = np.delete(np.arange(c.size), lost)
    log = replace(full, command=Signal(fl.t[kept], c[kept]))
    windows, r = _refit(log, tests, free=True)
    assert sum(w.free.size for w in windows) >= 20
    for name in ("Td", "tau", "K"):
        est = getattr(r, name)
        assert est.ci95_low <= getattr(m, name) <= est.ci95_high, name
    assert abs(r.tau.value - m.tau) < 3 * r.tau.std
    _, every = _refit(full, tests, free=True)
    assert r.tau.std > 1.1 * every.tau.std  # the switches' tick of uncertainty is in the interval
    if at == "switch":
        _, held = _refit(log, tests, free=False)
        assert not held.tau.ci95_low <= m.tau <= held.tau.ci95_high


def test_a_gap_after_the_test_adds_no_unknown_ticks_and_leaves_the_fit_as_it_is(flight):
    """A log masked to its tests' windows (the held-out benchmark's): the first test's window takes its
    command up to the first message after the test, seconds later across the gap. The ticks after the
    last output move no output, so none is left free (each was a zero column of every least squares:
    > 400 s on a masked SITL log), and the fit is the unmasked log's."""
    from mrftcli.analyze.general import mask_windows

    m, fl = flight
    full = recorded_flight(fl)
    tests = segment(full)
    masked = mask_windows(full, [(t.t_start - 1.5, t.t_end) for t in tests])
    fits = []
    for log in (full, masked):
        windows, r = _refit(log, tests[:1], free=True)
        w = windows[0]
        assert w.free.size == 0 and w.k[-1] < w.u.size
        fits.append(r)
    gap_ticks = CommandWindow.between(tests[0].t_start, tests[0].t_end, masked.command.t, masked.command.values,
                                      masked.output.t, masked.output.values, history=0.1).u.size
    assert gap_ticks > 300  # the masked window's grid does run across the gap
    for name in ("Td", "tau", "K"):
        assert getattr(fits[1], name).value == pytest.approx(getattr(fits[0], name).value, rel=1e-6), name
