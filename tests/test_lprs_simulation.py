"""The exact limit cycle against an independent closed-loop time-domain simulation of the MRFT.

The simulator below is written from scratch for this test (it does not import mrftcli.mrft.lprs): a batch
of plants of eq. (2) is discretised exactly (zero-order hold, scipy's expm) with a fine step that
divides the delay, and the MRFT rule of checks.md section 2 runs on every plant at once.

* continuous relay: the rule is checked at every fine step and the switching instant is located
  inside the step by linear interpolation; the input of that step in the delay line is the
  time-weighted mix of the two relay levels, so the loop is accurate to O(dt^2) instead of O(dt);
* sampled relay: the rule is checked only every ``Ts`` (a whole number of fine steps), the relay
  output is held in between, exactly as a flight controller does.  Such loops lock on one of
  several admissible orbits with a whole number of samples per half period, or wander among them
  (periods like 154, 154, 154, 151, 151 samples); the prediction is the exact set of symmetric
  orbits, so the test checks that every long-run mean lies in that band and that a loop locked on
  a symmetric orbit is on a predicted one.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import linalg, optimize

from mrftcli.mrft.lprs import mrft_limit_cycle
from mrftcli.mrft.model import LoopModel


def _df_frequency(Tp, Td, tau, beta):
    """Describing-function estimate [rad/s], only used to choose the simulation step."""
    target = math.pi / 2 - math.asin(beta)
    f = lambda w: math.atan(Tp * w) + math.atan(Td * w) + tau * w - target  # noqa: E731
    return optimize.brentq(f, 1e-6, 1e6)


def _zoh(Tp, Td, dt):
    """Exact ZOH discretisation of x' = A x + B u for 1/(s (Tp s+1)(Td s+1)) (K Td = 1)."""
    A = np.array([[0.0, 1.0, 0.0], [0.0, -1.0 / Td, 1.0 / Td], [0.0, 0.0, -1.0 / Tp]])
    B = np.array([0.0, 0.0, 1.0 / Tp])
    M = np.zeros((4, 4))
    M[:3, :3] = A * dt
    M[:3, 3] = B * dt
    E = linalg.expm(M)
    return E[:3, :3], E[:3, 3]


def simulate_mrft(plants, beta, dts, n_delay, n_steps, relay_every=None, offsets=None):
    """Simulate MRFT loops for a batch of plants (Tp, Td) with delay n_delay * dt.

    Returns switch times (-h -> +h) per plant and the output y at every step.
    """
    m = len(plants)
    Phi = np.empty((m, 3, 3))
    Gam = np.empty((m, 3))
    for i, ((Tp, Td), dt) in enumerate(zip(plants, dts)):
        Phi[i], Gam[i] = _zoh(Tp, Td, dt)
    dts = np.asarray(dts)
    n_delay = np.asarray(n_delay, dtype=int)
    L = int(n_delay.max()) + 2
    buf = np.ones((m, L))  # relay output history (+h = 1 before the start), ring buffer by step index
    x = np.zeros((m, 3))
    x[:, 0] = -np.asarray(offsets)  # start away from the set point so that e_max > 0 at once
    u = np.ones(m)
    e_ext = np.zeros(m)
    g_prev = np.zeros(m)
    ys = np.empty((n_steps, m))
    ups: list[list[float]] = [[] for _ in range(m)]
    rows = np.arange(m)
    for k in range(n_steps):
        y = x[:, 0]
        ys[k] = y
        e = -y
        decide = relay_every is None or k % relay_every == 0
        if decide and k > 0:
            plus = u > 0
            e_ext = np.where(plus, np.maximum(e_ext, e), np.minimum(e_ext, e))
            # g <= 0 means "switch now" in both states (written so that it is continuous in e)
            g = np.where(plus, e + beta * e_ext, -(e + beta * e_ext))
            sw = (np.where(plus, e_ext > 0, e_ext < 0)) & (g <= 0)
            if np.any(sw):
                new_u = -u
                if relay_every is None:
                    # crossing inside the last step: fraction phi of the step before the switch
                    phi = np.clip(g_prev / np.where(g_prev - g != 0, g_prev - g, 1.0), 0.0, 1.0)
                else:
                    phi = np.ones(m)  # sampled relay: switch exactly at the sample
                idx_prev = (k - 1) % L
                mix = phi * u + (1 - phi) * new_u
                buf[rows[sw], idx_prev] = np.where(relay_every is None, mix, u)[sw]
                for i in np.nonzero(sw & (new_u > 0))[0]:
                    ups[i].append((k - 1 + phi[i]) * dts[i])
                u = np.where(sw, new_u, u)
                e_ext = np.where(sw, e, e_ext)
                g = np.where(sw, -g, g)
            g_prev = g
        elif k == 0:
            e_ext = e.copy()
            g_prev = e + beta * e_ext
        buf[:, k % L] = u
        u_in = buf[rows, (k - n_delay) % L]
        x = np.einsum("mij,mj->mi", Phi, x) + Gam * u_in[:, None]
    return ups, ys


def _random_plants(rng, n):
    Tp = rng.uniform(0.015, 0.3, n)
    Td = rng.uniform(0.2, 2.0, n)
    tau = np.exp(rng.uniform(math.log(0.002), math.log(0.1), n))
    return Tp, Td, tau


@pytest.mark.slow
def test_continuous_relay_matches_independent_simulation():
    rng = np.random.default_rng(20240611)
    n = 30
    Tp, Td, tau = _random_plants(rng, n)
    beta = -0.55  # one batch; betas vary in the sampled test and in test_lprs.py
    per_period = 1500
    dts, n_delay, offsets = [], [], []
    for i in range(n):
        w = _df_frequency(Tp[i], Td[i], tau[i], beta)
        dt0 = 2 * math.pi / w / per_period
        nd = max(2, round(tau[i] / dt0))
        dts.append(tau[i] / nd)
        n_delay.append(nd)
        offsets.append(0.3 / w)
    n_cycles = 22
    ups, ys = simulate_mrft(list(zip(Tp, Td)), beta, dts, n_delay, int(n_cycles * per_period * 1.1), offsets=offsets)
    for i in range(n):
        t_up = np.asarray(ups[i])
        assert t_up.size > 15, "the simulated loop did not oscillate"
        period = np.mean(np.diff(t_up[-8:]))
        k0 = int(t_up[-8] / dts[i])
        seg = ys[k0:, i]
        amp = 0.5 * (seg.max() - seg.min())
        lc = mrft_limit_cycle(LoopModel(Tp[i], Td[i], tau[i], 1.0 / Td[i]), beta)
        assert lc.period == pytest.approx(period, rel=1e-3), (Tp[i], Td[i], tau[i])
        assert lc.amplitude == pytest.approx(amp, rel=5e-3), (Tp[i], Td[i], tau[i])


@pytest.mark.slow
@pytest.mark.parametrize("rate_hz", [100.0, 400.0])
def test_sampled_relay_matches_independent_simulation(rate_hz):
    rng = np.random.default_rng(7 + int(rate_hz))
    n = 15
    Tp, Td, tau = _random_plants(rng, n)
    beta = float(rng.uniform(-0.8, -0.2))
    Ts = 1.0 / rate_hz
    sub = 10  # fine steps per controller sample
    dt = Ts / sub
    n_delay = np.maximum(1, np.round(tau / dt)).astype(int)
    tau = n_delay * dt  # the simulated plants have delays on the fine grid
    offsets = [0.3 / _df_frequency(Tp[i], Td[i], tau[i], beta) for i in range(n)]
    w_min = min(_df_frequency(Tp[i], Td[i], tau[i], beta) for i in range(n))
    n_steps = int(32 * 2 * math.pi / w_min / dt)
    ups, ys = simulate_mrft(list(zip(Tp, Td)), beta, [dt] * n, n_delay, n_steps, relay_every=sub, offsets=offsets)
    locked = 0
    for i in range(n):
        t_up = np.asarray(ups[i])
        assert t_up.size > 12
        steps = np.round(np.diff(t_up[-11:]) * rate_hz).astype(int)  # periods in controller samples
        f_sim = rate_hz * steps.size / steps.sum()
        lc = mrft_limit_cycle(LoopModel(Tp[i], Td[i], tau[i], 1.0 / Td[i]), beta, rate_hz=rate_hz)
        orbits = np.asarray(lc.orbits_hz)
        amps = np.asarray(lc.orbits_amplitude)
        assert orbits.size >= 1
        # every long-run frequency of the sampled loop lies in the predicted band of orbits
        assert orbits.min() * (1 - 1e-3) <= f_sim <= orbits.max() * (1 + 1e-3), (orbits, f_sim)
        cyc = [ys[int(a / dt):int(b / dt), i] for a, b in zip(t_up[-11:-1], t_up[-10:])]
        amp = float(np.mean([0.5 * (c.max() - c.min()) for c in cyc]))
        assert amps.min() * (1 - 1e-2) <= amp <= amps.max() * (1 + 1e-2)
        if np.all(steps == steps[0]) and steps[0] % 2 == 0:
            # locked on a symmetric orbit: it must be one of those predicted, with its amplitude
            j = int(np.argmin(np.abs(orbits / f_sim - 1)))
            assert orbits[j] == pytest.approx(f_sim, rel=1e-3), (orbits, f_sim)
            assert amps[j] == pytest.approx(amp, rel=5e-3)
            locked += 1
        # the band centre (half-sample mean lag) lies inside the band
        assert orbits.min() * (1 - 1e-3) <= lc.frequency_hz <= orbits.max() * (1 + 1e-3)
    assert locked >= 3  # several loops lock on a symmetric orbit (others wander among the orbits)
