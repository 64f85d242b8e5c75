"""mrft.propagate.rk4_rotor (scalar stages, issue 39's CPU) against a textbook vector RK4 of its documented ODE."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mrftcli.mrft.propagate import RotorCoefficients, rk4_rotor


def _vector_rk4(x, h, c0, c1, c2, K, inv_td, c, F, inv_tp, inv_ts, max_step):
    """RK4 on (y, v, q, f) with numpy arrays: y' = v, v' = -v/Td - c v|v| + K F((1+q)^2 - 1),
    q' = (sqrt(1 + w/F) - 1 - q)/Tp, f' = (y - f)/Ts, w(s) = c0 + c1 s + c2 s^2/2 (the docstring's ODE)."""
    n = max(1, math.ceil(h / max_step - 1e-9))
    dt = h / n
    z = np.array([*x, 0.0][:4], float)

    def rhs(z, s):
        w = c0 + c1 * s + 0.5 * c2 * s * s
        p = F * ((1.0 + z[2]) ** 2 - 1.0)
        return np.array([z[1], -z[1] * inv_td - c * z[1] * abs(z[1]) + K * p,
                         (math.sqrt(max(1.0 + w / F, 0.0)) - 1.0 - z[2]) * inv_tp, (z[0] - z[3]) * inv_ts])

    s = 0.0
    for _ in range(n):
        k1 = rhs(z, s)
        k2 = rhs(z + 0.5 * dt * k1, s + 0.5 * dt)
        k3 = rhs(z + 0.5 * dt * k2, s + 0.5 * dt)
        k4 = rhs(z + dt * k3, s + dt)
        z = z + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        s += dt
    return z[: len(x)]


@pytest.mark.parametrize("lag", [False, True])
def test_rk4_rotor_is_the_vector_rk4_of_its_ode(lag):
    rng = np.random.default_rng(7 + lag)
    for _ in range(300):
        kw = dict(K=float(rng.choice([-1.0, 1.0]) * rng.uniform(1, 30)), inv_td=float(rng.choice([0.0, rng.uniform(0, 5)])),
                  quadratic_drag=float(rng.choice([0.0, rng.uniform(0, 3)])), hover_thrust=float(rng.uniform(0.05, 3)),
                  inv_tp=float(rng.uniform(5, 80)), inv_ts=float(rng.uniform(0, 50)) if lag else 0.0,
                  max_step=float(rng.uniform(1e-4, 5e-3)))
        x = list(rng.normal(0, 0.3, 4 if lag else 3))
        h, c0, c1, c2 = float(rng.uniform(1e-4, 0.03)), *map(float, rng.normal(0, [0.3, 3, 30]))
        got = rk4_rotor(x, h, c0, c1, c2, RotorCoefficients(**kw))
        want = _vector_rk4(x, h, c0, c1, c2, kw["K"], kw["inv_td"], kw["quadratic_drag"], kw["hover_thrust"],
                           kw["inv_tp"], kw["inv_ts"], kw["max_step"])
        assert got.shape == (len(x),)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
