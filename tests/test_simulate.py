"""The simulator against independent oracles.

* the plant: the logged commands are replayed through the closed-form step/ramp responses of G(s)
  (partial fractions, exact delay), and through a brute-force RK4 for quadratic drag;
* the MRFT rule: a scripted sinusoid with switching phases from geometry, and an independent
  implementation of checks.md section 2 replayed on the logged errors;
* the limit cycle: an independent closed loop (analytic step responses + the rule, written here), and
  the exact figures of checks.md section 1 at a fast controller rate;
* each effect changes what it should; the sidecar; the CLI's errors.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from mrftcli.errors import InputError
from mrftcli.mrft.model import LoopModel
from mrftcli.sim.flight import TestSpec as MrftTest
from mrftcli.sim.flight import (
    EFFECT_NAMES,
    Effects,
    FlightSpec,
    sidecar_path,
    simulate_flight,
)
from mrftcli.sim.control import relay_sequence
from cli_helpers import run_main
from relay_rule import relay_step

DESIGN1_ALT = LoopModel(0.0422, 2.669, 0.0464, 19.6)
DESIGN1_ROLL = LoopModel(0.0422, 1.301, 0.0297, 30.0)


# ------------------------------------------------------------------------------------------------
# closed-form responses of K Td / (s (T1 s + 1)(T2 s + 1)...) (partial fractions, distinct T_i)


def _coeffs(Ts):
    Ts = np.asarray(Ts, dtype=float)
    c = np.array([Ti ** len(Ts) / np.prod([Ti - Tj for Tj in Ts if Tj != Ti]) for Ti in Ts])
    return Ts, c


def step_response(t, gain, Ts):
    """Response to a unit step at t = 0 of gain / (s prod(T_i s + 1)) (zero for t < 0)."""
    Ts, c = _coeffs(Ts)
    t = np.asarray(t, dtype=float)
    tp = np.maximum(t, 0.0)
    f = tp - Ts.sum() + (c[:, None] * np.exp(-tp[None, :] / Ts[:, None])).sum(axis=0)
    return np.where(t > 0, gain * f, 0.0)


def ramp_response(t, gain, Ts):
    """Response to a unit ramp starting at t = 0 (the integral of the step response)."""
    Ts, c = _coeffs(Ts)
    t = np.asarray(t, dtype=float)
    tp = np.maximum(t, 0.0)
    f = 0.5 * tp**2 - Ts.sum() * tp + (c[:, None] * Ts[:, None] * (1 - np.exp(-tp[None, :] / Ts[:, None]))).sum(axis=0)
    return np.where(t > 0, gain * f, 0.0)


def parabola_response(t, gain, Ts):
    """Response to t^2 / 2 starting at t = 0 (the integral of the ramp response)."""
    Ts, c = _coeffs(Ts)
    t = np.asarray(t, dtype=float)
    tp = np.maximum(t, 0.0)
    f = tp**3 / 6 - Ts.sum() * tp**2 / 2 + (
        c[:, None] * Ts[:, None] * (tp[None, :] - Ts[:, None] * (1 - np.exp(-tp[None, :] / Ts[:, None])))
    ).sum(axis=0)
    return np.where(t > 0, gain * f, 0.0)


def replay_linear(flight, Ts=None, delays=None):
    """Output at the ticks of a linear flight, from the logged commands and closed forms only.

    Plant input w(t) = (1 + g t) u(t - d) - bias + input_bias (g = gain drift, t from the start), the
    command held between ticks, the log starting in trimmed hover (u = bias - input_bias before it).
    """
    spec = flight.spec
    m, eff = spec.model, spec.effects
    T = 1.0 / spec.rate_hz
    t_rel = np.arange(flight.t.size) * T
    bias = flight.truth["bias"]
    u_init = bias - eff.input_bias
    d = np.full(flight.t.size, m.tau) if delays is None else delays
    a = t_rel + d  # when each command reaches the plant
    du = np.diff(np.concatenate([[u_init], flight.command]))
    keep = du != 0
    a, du = a[keep], du[keep]
    gain = m.K * m.Td
    Ts = [m.Tp, m.Td] if Ts is None else Ts
    g = eff.gain_drift
    y = np.full(t_rel.size, flight.truth["setpoint"])
    if g:
        y += g * u_init * ramp_response(t_rel, gain, Ts)
    for start in range(0, a.size, 500):  # chunks keep the (ticks x changes) matrix small
        aa, dd = a[start : start + 500], du[start : start + 500]
        lag = t_rel[None, :] - aa[:, None]
        S = step_response(lag.ravel(), gain, Ts).reshape(lag.shape)
        y += ((dd * (1 + g * aa))[:, None] * S).sum(axis=0)
        if g:
            R = ramp_response(lag.ravel(), gain, Ts).reshape(lag.shape)
            y += ((dd * g)[:, None] * R).sum(axis=0)
    return y


def short_spec(model=DESIGN1_ALT, loop="altitude", **kw):
    base = dict(
        model=model,
        tests=(MrftTest(-0.5, 0.05 if loop == "altitude" else 0.15, 5.0),),
        loop=loop,
        hover_s=1.0,
        hold_s=2.0,
        noise_std=0.0002 if loop == "altitude" else math.radians(0.05),
        seed=3,
    )
    base.update(kw)
    return FlightSpec(**base)


def switch_times(flight, j, sign=+1):
    te = flight.truth["tests"][j]
    sel = (flight.t >= te["t_start"]) & (flight.t < te["t_end"])
    u, t = flight.command[sel], flight.t[sel]
    return t[1:][np.diff(u) * sign > 0]


def test_output_matches_closed_form_replay():
    flight = simulate_flight(short_spec())
    scale = np.ptp(flight.output_true)
    assert scale > 0.02  # the test really moved the vehicle
    np.testing.assert_allclose(flight.output_true, replay_linear(flight), rtol=0, atol=1e-9 * scale)


def test_fractional_delay_is_not_quantised():
    """tau 0.0464 s = 9.28 ticks: shifting it by 0.3 ms changes the output, and the replay follows."""
    a = simulate_flight(short_spec(noise_std=0.0))
    b = simulate_flight(short_spec(model=replace(DESIGN1_ALT, tau=0.0467), noise_std=0.0))
    assert np.max(np.abs(a.output_true - b.output_true)) > 1e-5
    np.testing.assert_allclose(b.output_true, replay_linear(b), atol=1e-9)


@pytest.mark.parametrize("tau", [0.0, 0.0033, 0.01])
@pytest.mark.parametrize("event_path", [False, True])
def test_short_and_whole_tick_delays_match_replay(tau, event_path):
    """tau = 0, below one tick, exactly two ticks; on the fixed-grid and the event-driven path."""
    eff = Effects(actuator_rate_limit=1e9) if event_path else Effects()
    flight = simulate_flight(short_spec(model=replace(DESIGN1_ALT, tau=tau), effects=eff, noise_std=0.0))
    np.testing.assert_allclose(flight.output_true, replay_linear(flight), atol=1e-9)


def test_input_bias_and_gain_drift_match_replay():
    eff = Effects(input_bias=0.01, gain_drift=-0.004)
    flight = simulate_flight(short_spec(effects=eff))
    np.testing.assert_allclose(flight.output_true, replay_linear(flight), atol=1e-9)


def test_sensor_lag_filters_the_measurement():
    eff = Effects(sensor_lag=0.02)
    flight = simulate_flight(short_spec(effects=eff, noise_std=0.0))
    np.testing.assert_allclose(flight.output_true, replay_linear(flight), atol=1e-9)
    m = flight.spec.model
    # measured = y through 1/(0.02 s + 1): same replay with one more time constant
    np.testing.assert_allclose(flight.output_measured, replay_linear(flight, Ts=[m.Tp, m.Td, 0.02]), atol=1e-9)


def test_delay_jitter_matches_replay_with_the_realised_delays():
    eff = Effects(delay_jitter=0.004, delay_jitter_correlation=0.03)
    flight = simulate_flight(short_spec(effects=eff))
    d = flight.delays
    assert d is not None and d.min() >= 0
    t_rel = np.arange(d.size) / flight.spec.rate_hz
    assert np.all(np.diff(t_rel + d) >= -1e-12)  # FIFO
    assert 0.002 < d.std() < 0.006 and abs(d.mean() - 0.0464) < 0.003
    np.testing.assert_allclose(flight.output_true, replay_linear(flight, delays=d), atol=1e-8)


def _actuator_kinks(flight, rate_limit):
    """Knots (time, slope change) of the rate-limited actuator, computed here from the commands."""
    spec = flight.spec
    T = 1.0 / spec.rate_hz
    bias = flight.truth["bias"]
    events = [(k * T + spec.model.tau, u) for k, u in enumerate(flight.command)]
    a, slope, s = bias, 0.0, 0.0
    target = bias
    knots = []
    for when, u in events:
        # move from s to `when` toward the old target
        if slope != 0.0:
            reach = s + abs(target - a) / rate_limit
            if reach <= when:
                knots.append((reach, -slope))
                a, slope = target, 0.0
            else:
                a += slope * (when - s)
        s = when
        target = u
        new_slope = 0.0 if target == a else math.copysign(rate_limit, target - a)
        if new_slope != slope:
            knots.append((when, new_slope - slope))
            slope = new_slope
    return knots


def test_actuator_rate_limit_matches_piecewise_linear_replay():
    R = 0.8  # command units / s: a 0.1 relay step takes 0.125 s
    flight = simulate_flight(short_spec(effects=Effects(actuator_rate_limit=R), noise_std=0.0))
    m = flight.spec.model
    t_rel = np.arange(flight.t.size) / flight.spec.rate_hz
    y = np.full(t_rel.size, flight.truth["setpoint"])
    for when, dslope in _actuator_kinks(flight, R):
        y += dslope * ramp_response(t_rel - when, m.K * m.Td, [m.Tp, m.Td])
    np.testing.assert_allclose(flight.output_true, y, atol=1e-8)
    # and it matters: the same commands without the limit give a different output
    assert np.max(np.abs(replay_linear(flight) - flight.output_true)) > 1e-3


def test_rate_limit_with_gain_drift_matches_replay():
    """w = (1 + g t) a(t) - bias + input_bias with a(t) piecewise linear: a quadratic input."""
    R, g = 0.8, -0.01
    flight = simulate_flight(short_spec(effects=Effects(actuator_rate_limit=R, gain_drift=g), noise_std=0.0))
    m = flight.spec.model
    gain, Ts = m.K * m.Td, [m.Tp, m.Td]
    t_rel = np.arange(flight.t.size) / flight.spec.rate_hz
    y = flight.truth["setpoint"] + g * flight.truth["bias"] * ramp_response(t_rel, gain, Ts)
    # (1 + g t)(t - s)_+ = (1 + g s)(t - s)_+ + 2 g (t - s)_+^2 / 2
    for when, dslope in _actuator_kinks(flight, R):
        y += dslope * ((1 + g * when) * ramp_response(t_rel - when, gain, Ts)
                       + 2 * g * parabola_response(t_rel - when, gain, Ts))
    np.testing.assert_allclose(flight.output_true, y, atol=1e-8)


def test_quadratic_drag_matches_brute_force_rk4():
    c = 2.0
    spec = short_spec(effects=Effects(quadratic_drag=c), noise_std=0.0, tests=(MrftTest(-0.5, 0.05, 3.0),), hold_s=0.5)
    flight = simulate_flight(spec)
    m = spec.model
    T = 1.0 / spec.rate_hz
    n_sub = 100  # dt = 50 us; tau = 928 dt exactly, so the delayed input switches on the grid
    dt = T / n_sub
    lag = int(round(m.tau / dt))
    bias = flight.truth["bias"]

    def f(x, w):
        y, v, p = x
        return np.array([v, -c * v * abs(v) + m.K * p, (w - p) / m.Tp])

    x = np.array([flight.truth["setpoint"], 0.0, 0.0])
    ys = []
    for i in range(flight.t.size * n_sub):
        if i % n_sub == 0:
            ys.append(x[0])
        j = (i - lag) // n_sub  # the tick whose command acts now
        w = (flight.command[j] if j >= 0 else bias) - bias
        k1 = f(x, w)
        k2 = f(x + 0.5 * dt * k1, w)
        k3 = f(x + 0.5 * dt * k2, w)
        k4 = f(x + dt * k3, w)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(flight.output_true, np.array(ys), atol=1e-7)
    entry = flight.truth["tests"][0]
    assert flight.truth["drag_model"] == "quadratic"
    assert entry["Td_equivalent"] == pytest.approx(3 * math.pi / (8 * c * entry["velocity_amplitude"]))


# ------------------------------------------------------------------------------------------------
# the MRFT rule


@pytest.mark.parametrize("beta", [-0.7, -0.5, -0.1, 0.3])
def test_relay_on_a_scripted_sinusoid(beta):
    """e = sin(theta): -h from theta = pi - asin(-beta) (falling), +h from 2 pi + asin(beta) (rising)."""
    n = 4000
    theta = 2 * math.pi * (np.arange(3 * n) / n) + 0.25  # 3 periods, start on a rising positive error
    e = np.sin(theta)
    relay = relay_sequence(e, beta)
    down = math.pi - math.asin(-beta)
    up = 2 * math.pi + math.asin(beta)
    phase = np.mod(theta, 2 * math.pi)
    expected = np.where(np.mod(phase - down, 2 * math.pi) < up - down, -1.0, 1.0)
    # skip the first half-cycle (start rule) and samples within two steps of a boundary
    step = 2 * math.pi / n
    dist = lambda x: np.abs(np.mod(phase - x + math.pi, 2 * math.pi) - math.pi)  # noqa: E731
    near = np.minimum(dist(down), dist(up)) < 2 * step
    ok = (theta > math.pi + 0.5) & ~near
    assert ok.sum() > 2 * n
    assert np.array_equal(relay[ok], expected[ok])


@pytest.mark.parametrize("kind, beta, eps", [("hysteresis", 0.0, 0.3), ("ideal", 0.0, 0.0), ("mrft", -0.4, 0.0)])
def test_relay_law_sampled_switches_at_its_closed_form_levels(kind, beta, eps):
    """RelayLaw's sampled rule on e = sin(theta): down where sin = -(beta + eps) after the peak (the
    amplitude is 1), up where sin = beta + eps after the trough; no code shared with the rule's module."""
    from mrftcli.mrft.relays import RelayLaw

    rule = RelayLaw(kind, 1.0, -1.0, beta=beta, eps=eps).sampled()
    n = 4000
    theta = 2 * math.pi * (np.arange(3 * n) / n) + 0.25
    e = np.sin(theta)
    relay = np.array([rule.start(v) if i == 0 else rule.step(v) for i, v in enumerate(e.tolist())])
    level = beta + eps  # the switching level over the amplitude
    down, up = math.pi + math.asin(level), 2 * math.pi + math.asin(level)
    phase = np.mod(theta, 2 * math.pi)
    expected = np.where(np.mod(phase - down, 2 * math.pi) < up - down, -1.0, 1.0)
    dist = lambda x: np.abs(np.mod(phase - x + math.pi, 2 * math.pi) - math.pi)  # noqa: E731
    near = np.minimum(dist(down), dist(up)) < 2 * (2 * math.pi / n)
    ok = (theta > math.pi + 1.0) & ~near
    assert ok.sum() > 2 * n and np.array_equal(relay[ok], expected[ok])


def test_relay_start_threshold_keeps_the_first_sign():
    e = np.array([0.1, 0.05, -0.02, -0.04, -0.06, -0.2])
    assert relay_sequence(e, -0.5, start_threshold=0.05).tolist() == [1, 1, 1, 1, -1, -1]
    assert relay_sequence(e, -0.5).tolist() == [1, 1, -1, -1, -1, -1]


def _checks_rule(e, beta, start_threshold):
    """checks.md section 2, written independently of mrftcli.sim.flight."""
    out = [1.0 if e[0] >= 0 else -1.0]
    ext, started = e[0], False
    for x in e[1:]:
        s = out[-1]
        if not started:
            if s * x < -start_threshold:
                s, ext, started = -s, x, True
        else:
            s, ext = relay_step(s, ext, x, beta)
        out.append(s)
    return np.array(out)


def test_logged_commands_follow_the_rule_on_the_noisy_error():
    flight = simulate_flight(short_spec(noise_std=0.0003))
    truth = flight.truth
    for test, entry in zip(flight.spec.tests, truth["tests"]):
        sel = (flight.t >= entry["t_start"]) & (flight.t < entry["t_end"])
        e = truth["setpoint"] - flight.output_measured[sel]
        expected = truth["bias"] + test.h * _checks_rule(e, test.beta, 10 * truth["noise_std"])
        np.testing.assert_array_equal(flight.command[sel], expected)
    beta_topic = next(tp for tp in flight.topics if tp.name == "/mrft/beta")
    assert beta_topic.t.tolist() == [e["t_start"] for e in truth["tests"]]


def test_limit_cycle_matches_an_independent_closed_loop():
    """Noise-free 200 Hz test from rest vs a closed loop built here from the analytic step response."""
    m, beta, h = DESIGN1_ALT, -0.7, 0.08
    spec = FlightSpec(m, (MrftTest(beta, h, 12.0),), hover_s=0.0, hold_s=0.5, noise_std=0.0)
    flight = simulate_flight(spec)
    T = 1.0 / spec.rate_hz
    n = int(round(12.0 / T))
    r, bias = flight.truth["setpoint"], flight.truth["bias"]
    u = np.empty(n)
    changes_t, changes_du = [], []
    ext, s, started = 0.0, 1.0, False
    for k in range(n):
        tk = k * T
        y = r + float(np.dot(changes_du, step_response(tk - np.array(changes_t), m.K * m.Td, [m.Tp, m.Td]))) if changes_t else r
        e = r - y
        if k == 0:
            s, ext = (1.0 if e >= 0 else -1.0), e
        elif not started:
            if s * e < 0:
                s, ext, started = -s, e, True
        else:
            s, ext = relay_step(s, ext, e, beta)
        u[k] = bias + s * h
        prev = u[k - 1] if k else bias
        if u[k] != prev:
            changes_t.append(tk + m.tau)
            changes_du.append(u[k] - prev)
    np.testing.assert_array_equal(flight.command[:n], u)
    ups = np.flatnonzero(np.diff(u) > 0)
    assert ups.size >= 10


@pytest.mark.slow
@pytest.mark.parametrize("beta,freq_hz", [(-0.4, 0.70564), (-0.7, 1.01884)])
def test_paper_example_frequency_and_amplitude(beta, freq_hz):
    """checks.md section 1: theta/u = 0.14 e^{-0.06 s}/(s (0.1 s + 1)(0.7042 s + 1)), continuous relay.

    At a 10 kHz controller the sampled relay adds ~T/2 = 50 us of delay, i.e. -0.024 % in frequency.
    """
    model = LoopModel(0.1, 1 / 1.42, 0.06, 0.14 * 1.42)
    spec = FlightSpec(model, (MrftTest(beta, 1.0, 16.0),), loop="roll", rate_hz=10_000.0, hover_s=0.0,
                      hold_s=0.0001, noise_std=0.0)
    flight = simulate_flight(spec)
    ups = switch_times(flight, 0)
    ups = ups[ups > 6.0]
    freq = (ups.size - 1) / (ups[-1] - ups[0])
    assert freq == pytest.approx(freq_hz, rel=5e-4)
    y = flight.output_true[flight.t > 8.0]
    y = y[: int(10_000 * 6)]
    amplitude = 0.5 * np.ptp(y)
    expected = {-0.4: 0.078530, -0.7: 0.035602}[beta] * 0.14
    assert amplitude == pytest.approx(expected, rel=2e-3)


# ------------------------------------------------------------------------------------------------
# effects


def _half_periods(flight, j):
    up, down = switch_times(flight, j, +1), switch_times(flight, j, -1)
    up, down = up[up > up[0] + 2.5], down[down > up[0]]
    plus = [d - u for u in up for d in down[down > u][:1]]
    minus = [u - d for d in down for u in up[up > d][:1]]
    return np.median(plus), np.median(minus)


def test_input_bias_unbalances_the_half_periods():
    spec = short_spec(noise_std=0.0, tests=(MrftTest(-0.4, 0.05, 10.0),))
    plus0, minus0 = _half_periods(simulate_flight(spec), 0)
    assert plus0 == pytest.approx(minus0, abs=0.006)
    # extra thrust: the +h half (pushing up) gets shorter, the -h half longer
    plus, minus = _half_periods(simulate_flight(replace(spec, effects=Effects(input_bias=0.01))), 0)
    assert plus < plus0 - 0.02 and minus > minus0 + 0.02


def test_gain_drift_scales_the_amplitude_and_sags_the_battery():
    g = -0.01
    spec = short_spec(model=DESIGN1_ROLL, loop="roll", noise_std=0.0, tests=(MrftTest(-0.5, 0.15, 30.0),),
                      effects=Effects(gain_drift=g))
    flight = simulate_flight(spec)
    entry = flight.truth["tests"][0]

    def amp(t0, t1):
        sel = (flight.t >= t0) & (flight.t < t1)
        return 0.5 * np.ptp(flight.output_true[sel])

    early, late = amp(5, 9), amp(25, 29)
    assert late / early == pytest.approx((1 + g * 27) / (1 + g * 7), rel=0.02)
    assert entry["K_effective"] == pytest.approx(spec.model.K * (1 + g * 16.0))
    battery = next(tp for tp in flight.topics if tp.name == "/battery")
    slope = np.polyfit(battery.t, battery.fields["voltage"], 1)[0]
    assert slope == pytest.approx(g * spec.effects.battery_voltage, rel=0.05)


def test_sensor_lag_and_rate_limit_lower_the_frequency():
    base = short_spec(noise_std=0.0, tests=(MrftTest(-0.7, 0.08, 10.0),))

    def freq(spec):
        ups = switch_times(simulate_flight(spec), 0)
        ups = ups[ups > ups[0] + 3]
        return (ups.size - 1) / (ups[-1] - ups[0])

    f0 = freq(base)
    assert freq(replace(base, effects=Effects(sensor_lag=0.03))) < 0.95 * f0
    assert freq(replace(base, effects=Effects(actuator_rate_limit=0.5))) < 0.97 * f0


# ------------------------------------------------------------------------------------------------
# hold controller, validation, sidecar, CLI


@pytest.mark.parametrize(
    "model",
    [LoopModel(t1, t2, tau) for t1 in (0.015, 0.3) for t2 in (0.2, 2.0) for tau in (0.0005, 0.1)]
    + [LoopModel(0.0499, 1.8345, 0.0498 + 0.02), LoopModel(0.0499, 0.6312, 0.0308)],
    ids=lambda m: f"Tp{m.Tp}-Td{m.Td}-tau{m.tau}",
)
def test_hold_controller_recovers_after_a_test(model):
    spec = FlightSpec(model, (MrftTest(-0.5, 0.2, 2.0),), loop="roll", hover_s=0.5, hold_s=25.0, noise_std=0.0)
    flight = simulate_flight(spec)
    y = flight.output_true
    excursion = np.max(np.abs(y))
    assert excursion > 1e-5  # the test moved the vehicle
    assert np.max(np.abs(y[-400:])) < 0.01 * excursion  # last 2 s: back at the setpoint


@pytest.mark.parametrize(
    "change,match",
    [
        (dict(tests=(MrftTest(1.0, 0.1),)), "beta"),
        (dict(tests=(MrftTest(-0.5, -0.1),)), "relay height"),
        (dict(tests=()), "at least one"),
        (dict(loop="yaw"), "unknown loop"),
        (dict(effects=Effects(sensor_lag=-1.0)), "sensor_lag"),
        (dict(effects=Effects(gain_drift=-1.0)), "gain_drift"),
        (dict(switching="pid"), "switching"),
        (dict(abort_error=0.0), "abort_error must be positive"),
        (dict(effects=Effects(flex_mode_hz=20.0, quadratic_drag=1.0)), "flex_mode_hz cannot be combined"),
        (dict(effects=Effects(asymmetric_gain=1.0)), "asymmetric_gain"),
        (dict(confirm_samples=-1), "confirm_samples"),
    ],
)
def test_bad_specs_raise_input_error(change, match):
    with pytest.raises(InputError, match=match):
        simulate_flight(replace(short_spec(), **change))


def test_flight_settings_schedule_whole_ticks_and_loop_defaults():
    # the schedule: hover, then each test and its hold, rounded to whole controller ticks
    from mrftcli.sim.spec import default_bias, default_noise_std, default_setpoint, flight_settings

    spec = replace(short_spec(), rate_hz=100.0, hover_s=1.004, hold_s=0.5,
                   tests=(MrftTest(-0.4, 0.1, 2.0), MrftTest(-0.7, 0.1, 1.236)))
    s = flight_settings(spec)
    assert s.ranges == ((100, 300), (350, 474)) and s.n_ticks == 524 and s.T == 0.01
    assert (s.noise_std, s.bias, s.setpoint) == (default_noise_std(spec.loop) if spec.noise_std is None
                                                 else spec.noise_std, default_bias(spec.loop)
                                                 if spec.bias is None else spec.bias,
                                                 default_setpoint(spec.loop) if spec.setpoint is None
                                                 else spec.setpoint)
    sf = simulate_flight(spec)
    assert sf.t.size == s.n_ticks
    assert [round((t["t_start"] - spec.start_time) * 100) for t in sf.truth["tests"]] == [100, 350]


def test_reproducible_and_spec_untouched():
    spec = short_spec(effects=Effects(delay_jitter=0.002))
    a, b = simulate_flight(spec), simulate_flight(spec)
    np.testing.assert_array_equal(a.output_measured, b.output_measured)
    np.testing.assert_array_equal(a.command, b.command)
    assert spec == short_spec(effects=Effects(delay_jitter=0.002))
    c = simulate_flight(replace(spec, seed=4))
    assert not np.array_equal(a.output_measured, c.output_measured)


def test_attitude_topic_is_a_zyx_quaternion():
    flight = simulate_flight(short_spec(model=DESIGN1_ROLL, loop="pitch"))
    imu = next(tp for tp in flight.topics if tp.name == "/imu/data")
    x, y, z, w = (imu.fields[f"orientation.{c}"] for c in "xyzw")
    np.testing.assert_allclose(x**2 + y**2 + z**2 + w**2, 1.0, atol=1e-12)
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1, 1))
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x**2 + y**2))
    np.testing.assert_allclose(pitch, flight.output_measured, atol=1e-12)
    assert np.std(roll) < 3 * flight.truth["noise_std"]


def test_sidecar_contents(tmp_path):
    from mrftcli import __version__
    from mrftcli.sim.flight import write_flight

    eff = Effects(input_bias=0.01, delay_jitter=0.001)
    flight = simulate_flight(short_spec(effects=eff))
    log = tmp_path / "flight.csv"
    side = write_flight(flight, log, "csv")
    assert side == sidecar_path(log) == tmp_path / "flight.csv.truth.json"
    assert log.exists()
    truth = json.loads(side.read_text())
    for key in ("Tp", "Td", "tau", "K", "loop", "rate_hz", "noise_std", "bias", "setpoint", "tests", "effects", "seed"):
        assert key in truth
    assert truth["mrftcli_version"] == __version__
    assert (truth["Tp"], truth["Td"], truth["tau"], truth["K"]) == (0.0422, 2.669, 0.0464, 19.6)
    assert set(EFFECT_NAMES) <= set(truth["effects"])
    assert truth["effects"]["input_bias"] == 0.01 and truth["effects_active"] == ["input_bias", "delay_jitter"]
    (test,) = truth["tests"]
    assert (test["beta"], test["h"]) == (-0.5, 0.05)
    assert test["t_start"] == pytest.approx(1.0) and test["t_end"] == pytest.approx(6.0)
    assert truth["log_format"] == "csv"


def _run(*args):
    """The CLI's main() in this process (cli_helpers.run_main): a subprocess only adds its imports' CPU."""
    return run_main(*args)


def test_cli_writes_log_and_sidecar(tmp_path):
    out = tmp_path / "roll.csv"
    proc = _run("simulate", "--tp", "0.0422", "--td", "1.301", "--tau", "0.0297", "--k", "30", "--loop", "roll",
                "--test", "-0.5:0.15:4", "--test", "-0.8", "--noise", "0.0009", "--hover", "1", "--hold", "1",
                "--effect", "input_bias=0.01", "--out", str(out), "--json")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    side = json.loads((tmp_path / "roll.csv.truth.json").read_text())
    assert report["truth"]["tests"] == side["tests"]
    assert [t["beta"] for t in side["tests"]] == [-0.5, -0.8]
    assert side["tests"][0]["h"] == 0.15 and side["tests"][0]["duration"] == 4.0
    assert side["tests"][1]["h"] > 0 and side["effects"]["input_bias"] == 0.01
    assert out.exists()


@pytest.mark.parametrize(
    "args,message",
    [
        (["--test", "1.5"], "beta must lie in the open interval"),
        (["--test", "-0.5", "--effect", "wind=3"], "valid names: input_bias, gain_drift"),
        (["--test", "-0.5:abc"], "is not a number"),
        (["--test", "-0.5", "--out", "x.unknown"], "cannot tell the log format"),
    ],
)
def test_cli_errors_are_one_line(tmp_path, args, message):
    if "--out" not in args:
        args = args + ["--out", str(tmp_path / "x.mcap")]
    proc = _run("simulate", "--tp", "0.05", "--td", "1", "--tau", "0.03", *args)
    assert proc.returncode == 2
    assert message in proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_hear_relay_undoes_a_noise_triggered_switch():
    """A dip right after the zero crossing locks the plain rule; the HEAR block switches back."""
    e = np.concatenate([np.linspace(-1, 0.004, 60), [0.001], np.linspace(0.02, 1.0, 40)])
    plain = relay_sequence(e, -0.5)
    assert plain[-1] == -1 and np.all(plain[62:] == -1)  # locked: e_min never goes below zero
    hear = relay_sequence(e, -0.5, "hear", confirm_samples=3, no_switch_ticks=0)
    assert hear[-1] == 1


def test_hear_relay_on_a_sinusoid_switches_at_the_same_levels():
    n = 2000
    theta = 2 * np.pi * np.arange(4 * n) / n + 0.25
    relay = relay_sequence(np.sin(theta), -0.5, "hear", confirm_samples=5, no_switch_ticks=4)
    downs = np.mod(theta[1:][np.diff(relay) < 0], 2 * np.pi)[1:]
    ups = np.mod(theta[1:][np.diff(relay) > 0], 2 * np.pi)[1:]
    step = 2 * np.pi / n
    np.testing.assert_allclose(downs, 5 * np.pi / 6, atol=1.5 * step)
    np.testing.assert_allclose(ups, 11 * np.pi / 6, atol=1.5 * step)


def test_locked_relay_is_aborted_and_the_hold_takes_over():
    """0.2 deg of white noise at a 4 deg amplitude locks the plain rule (docs/simulator.md)."""
    spec = FlightSpec(DESIGN1_ROLL, (MrftTest(-0.5, 0.14, 10.0),), loop="roll", noise_std=math.radians(0.2),
                      hover_s=1.0, hold_s=6.0, seed=0)
    flight = simulate_flight(spec)
    (entry,) = flight.truth["tests"]
    assert entry["aborted"] and entry["t_end"] < entry["t_start"] + 10.0
    tail = flight.output_true[-200:]
    assert np.max(np.abs(tail)) < entry["abort_error"]  # recovered, not diverging


def test_defaults_and_planning():
    from mrftcli.sim.flight import default_noise_std, df_prediction, plan_test

    assert default_noise_std("altitude") == 0.0005
    assert default_noise_std("roll") == pytest.approx(math.radians(0.05))
    planned = plan_test(DESIGN1_ALT, -0.4, 0.05)
    omega, amp = df_prediction(DESIGN1_ALT, -0.4, planned.h)
    assert amp == pytest.approx(0.05)
    assert planned.duration >= 14 * 2 * math.pi / omega
    flight = simulate_flight(FlightSpec(DESIGN1_ALT, (planned,), noise_std=0.0, hover_s=0.5, hold_s=0.5))
    ups = switch_times(flight, 0)
    ups = ups[ups > 8.0]
    freq = (ups.size - 1) / (ups[-1] - ups[0])
    assert freq == pytest.approx(omega / (2 * math.pi), rel=0.1)  # the DF is an approximation (-8 % here)


def test_progress_is_reported_to_the_end():
    calls = []
    simulate_flight(short_spec(), progress=lambda done, total, stage="": calls.append((done, total, stage)))
    assert calls[-1][0] == calls[-1][1] == 1600 and len(calls) > 10
    assert all(stage == "simulating" for *_, stage in calls)


def test_sidecar_path_of_a_bag_directory(tmp_path):
    assert sidecar_path(tmp_path / "a_ros2_sqlite3") == tmp_path / "a_ros2_sqlite3.truth.json"
    assert sidecar_path(str(tmp_path / "a_ros2_mcap") + "/") == tmp_path / "a_ros2_mcap.truth.json"


@pytest.mark.parametrize("lag", [0.015, 0.001])  # 1 ms: ||A|| T > 2, sub-interval propagation
@pytest.mark.parametrize("trigger", [dict(actuator_rate_limit=1e9), dict(delay_jitter=1e-14)])
def test_event_path_agrees_with_the_fixed_grid_path(trigger, lag):
    """A huge rate limit / a negligible jitter sends the flight through the event-driven path."""
    eff = dict(input_bias=0.005, gain_drift=-0.003, sensor_lag=lag)
    a = simulate_flight(short_spec(effects=Effects(**eff)))
    b = simulate_flight(short_spec(effects=Effects(**eff, **trigger)))
    np.testing.assert_allclose(b.output_true, a.output_true, atol=1e-9)
    np.testing.assert_allclose(b.output_measured, a.output_measured, atol=1e-9)


def test_cli_warns_when_the_noise_margin_is_small(tmp_path):
    proc = _run("simulate", "--tp", "0.0422", "--td", "1.301", "--tau", "0.0297", "--k", "30", "--loop", "roll",
                "--test", "-0.5:0.1:3", "--noise", "0.0035", "--hover", "1", "--hold", "1",
                "--out", str(tmp_path / "r.csv"))
    assert proc.returncode == 0
    assert "may lock up" in proc.stderr and "Traceback" not in proc.stderr


def test_rotor_coefficients_are_checked_and_the_rotor_speed_lags_in_closed_form():
    from mrftcli.mrft.propagate import RotorCoefficients, rk4_rotor

    for bad in ({"hover_thrust": 0.0}, {"inv_tp": -1.0}, {"max_step": 0.0}, {"inv_td": -0.1},
                {"quadratic_drag": float("nan")}, {"K": float("inf")}):
        with pytest.raises(InputError):
            RotorCoefficients(**{"K": 1.0, "inv_td": 0.5, "quadratic_drag": 0.0, "hover_thrust": 0.4,
                                 "inv_tp": 1 / 0.0422, "inv_ts": 0.0, "max_step": 1e-3, **bad})
    # K = 0: the rotor speed alone, q' = (sqrt(1 + w/F) - 1 - q)/Tp, an exponential towards q_c
    F, Tp, w, q0, v0, h = 0.4, 0.0422, 0.1, 0.0, 0.3, 0.05
    plant = RotorCoefficients(0.0, 0.0, 0.0, F, 1.0 / Tp, 0.0, 1e-3)
    y, v, q = rk4_rotor([0.0, v0, q0], h, w, 0.0, 0.0, plant)
    q_c = math.sqrt(1.0 + w / F) - 1.0
    assert q == pytest.approx(q_c + (q0 - q_c) * math.exp(-h / Tp), rel=1e-7)  # RK4 at 1 ms: ~1e-9
    assert (y, v) == pytest.approx((v0 * h, v0), rel=1e-12)


def test_hold_pid_crossover_is_eq2s_phase_or_refused():
    # the hold PID's omega_c solves arg G(j w) - w T / 2 + lead = -180 deg + PM (eq. (2)'s phase in closed form
    # here, independent of df_frequency); a phase margin more than 90 deg from the lead has no such
    # solution through asin(beta): refused, where it used to return the crossover of another margin
    from mrftcli.sim.control import design_hold_pid

    m, rate = LoopModel(0.0422, 1.301, 0.0297, 30.0), 200.0
    s = 1j
    c1 = 1.0 + 1.0 / (6.0 * s) + 1.5 * s / (0.15 * s + 1.0)  # the PID's shape at omega_c = 1
    lead = math.degrees(math.atan2(c1.imag, c1.real))
    for pm in (30.0, 45.0, lead + 89.0):
        w = design_hold_pid(m, rate, pm).omega_c
        phase = -90.0 - math.degrees(math.atan(m.Tp * w) + math.atan(m.Td * w) + (m.tau + 0.5 / rate) * w)
        assert phase + lead == pytest.approx(-180.0 + pm, abs=1e-7)
    for pm in (lead + 91.0, lead - 91.0):
        with pytest.raises(InputError, match="no phase crossover found"):
            design_hold_pid(m, rate, pm)
