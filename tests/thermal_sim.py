"""Slow relay loops (a heater under a 0/1 relay) sampled with jitter, simulated independently of mrftcli.

The oracle of issue 38's tests and ``benchmarks/bench_slow_process.py``. The plant is built from its
transfer function's polynomials (``tests/process_sim.polynomials``, ``scipy.signal.tf2ss``) and stepped
exactly from event to event: the events are the sample times (drawn with jitter) and the times a
relay switch reaches the plant (the switch time plus the delay ``tau``), so the delay is exact
whatever the sampling. The relay decides at each sample on the noisy output: ``e = setpoint - y``;
the command goes ``high`` when e rises through ``+eps`` and ``low`` when it falls through ``-eps``
(``eps = 0``: an ideal relay). The plant sees the command itself (``u0 = 0``: heater off) and the
output sits at ``baseline`` (the ambient) when the plant input is 0; an integrating plant sees
``u - (high + low) / 2`` instead (it has no operating point of its own).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np
from scipy import linalg, signal

from process_sim import polynomials

__all__ = ["RelayWindow", "simulate_relay", "INTEGRATING"]

INTEGRATING = ("ipdt", "foipdt")


@dataclass(frozen=True)
class RelayWindow:
    """One relay test: the levels, the hysteresis [output units], its length [s], then a rest."""

    high: float
    low: float
    eps: float
    duration: float
    rest: float = 0.0


def _zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = A * dt, B[:, 0] * dt
    E = linalg.expm(M)
    return E[:n, :n], E[:n, n]


def simulate_relay(family: str, params: dict[str, float], windows: list[RelayWindow], *, setpoint: float,
                   baseline: float = 0.0, sample_s: tuple[float, float] = (1.0, 7.0), noise_std: float = 0.0,
                   seed: int = 0, lead: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t [s], command, output) at jittered sample times (intervals uniform in ``sample_s`` [s]).

    The plant starts at rest at the steady state of the first window's mean level (self-regulating)
    or at the setpoint (integrating); ``lead`` [s] of that mean level precedes the first window.
    """
    rng = np.random.default_rng(seed)
    num, den = polynomials(family, params)
    A, B, C, _ = signal.tf2ss(num, den)
    tau = float(params["tau"])
    integrating = family in INTEGRATING
    w0 = windows[0]
    mid0 = 0.5 * (w0.high + w0.low)
    x = np.zeros(A.shape[0])
    if not integrating:  # steady state at the first window's mean level: A x + B u = 0
        x = -np.linalg.solve(A, B[:, 0] * mid0)
    offset = setpoint if integrating else baseline

    def plant_input(u: float, w: RelayWindow) -> float:
        return u - 0.5 * (w.high + w.low) if integrating else u

    plan: list[tuple[float, float, RelayWindow | None]] = []  # (start, end, window or rest)
    t0 = 0.0
    if lead > 0:
        plan.append((0.0, lead, None))
        t0 = lead
    for w in windows:
        plan.append((t0, t0 + w.duration, w))
        t0 += w.duration
        if w.rest > 0:
            plan.append((t0, t0 + w.rest, None))
            t0 += w.rest
    t_end = t0
    pending: list[tuple[float, float]] = []  # (time the plant sees it, plant input)
    v = plant_input(mid0, w0)  # what the plant sees now
    t, k = 0.0, 0
    s = 1.0
    ts, us, ys = [], [], []
    cur: RelayWindow | None = None
    while t < t_end:
        while k < len(plan) and plan[k][1] <= t:
            k += 1
        win = plan[k][2] if k < len(plan) else None
        y = float(C[0] @ x) + offset + noise_std * rng.standard_normal()
        if win is not None:
            if win is not cur:
                s = 1.0 if setpoint - y > 0 else -1.0
            e = setpoint - y
            if s > 0 and e < -win.eps:
                s = -1.0
            elif s < 0 and e > win.eps:
                s = 1.0
            u = win.high if s > 0 else win.low
            ref = win
        else:
            ref = cur or w0
            u = 0.5 * (ref.high + ref.low)
        cur = win
        ts.append(t)
        us.append(u)
        ys.append(y)
        heapq.heappush(pending, (t + tau, plant_input(u, ref)))
        t_next = t + float(rng.uniform(*sample_s))
        while pending and pending[0][0] <= t_next:  # the inputs that reach the plant before the next sample
            te, ve = heapq.heappop(pending)
            if te > t:
                Phi, Gam = _zoh(A, B, te - t)
                x = Phi @ x + Gam * v
                t = te
            v = ve
        if t_next > t:
            Phi, Gam = _zoh(A, B, t_next - t)
            x = Phi @ x + Gam * v
        t = t_next
    return np.array(ts), np.array(us), np.array(ys)
