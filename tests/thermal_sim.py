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
import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

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


class _Zoh:
    """Exact zero-order-hold maps of x' = A x + B v over any step, from A's eigen-decomposition (the
    families' poles are real and distinct; a zero pole's integral is the step itself): the per-event
    matrix exponential, of a 3 x 3 matrix, costs a millisecond on a loaded machine; this a few us."""

    def __init__(self, A: np.ndarray, B: np.ndarray) -> None:
        lam, V = np.linalg.eig(A)
        self.lam, self.V = lam, V
        self.Vinv_B = np.linalg.solve(V, B[:, 0])
        self.Vinv = np.linalg.inv(V)

    def __call__(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        lam = self.lam
        e = np.exp(lam * dt)
        small = np.abs(lam * dt) < 1e-12
        integral = np.where(small, dt, (e - 1.0) / np.where(small, 1.0, lam))
        Phi = (self.V * e) @ self.Vinv
        Gam = self.V @ (integral * self.Vinv_B)
        return np.real(Phi), np.real(Gam)


def simulate_relay(family: str, params: dict[str, float], windows: list[RelayWindow], *, setpoint: float,
                   baseline: float = 0.0, sample_s: tuple[float, float] = (1.0, 7.0), noise_std: float = 0.0,
                   seed: int = 0, lead: float = 0.0,
                   u_op: float | None = None,
                   decide_s: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t [s], command, output) at jittered sample times (intervals uniform in ``sample_s`` [s]).

    The plant starts at rest at the steady state of the first window's mean level (self-regulating)
    or at the setpoint (integrating); ``lead`` [s] of that mean level precedes the first window.
    ``u_op``: the command the plant is at rest with (default: 0, or an integrating plant's window mid).
    ``decide_s``: the relay (a thermostat) decides every ``decide_s`` [s] on its own noisy reading and a
    recorder logs the command and the output at the jittered times (a switch falls between two logged
    samples); None: the controller decides at the logged samples, on the logged output.
    """
    rng = np.random.default_rng(seed)
    num, den = polynomials(family, params)
    A, B, C, _ = signal.tf2ss(num, den)
    tau = float(params["tau"])
    zoh = _Zoh(A, B)
    integrating = family in INTEGRATING
    w0 = windows[0]
    mid0 = 0.5 * (w0.high + w0.low)
    x = np.zeros(A.shape[0])
    if not integrating:  # steady state at the first window's mean level: A x + B u = 0
        x = -np.linalg.solve(A, B[:, 0] * (mid0 - (u_op or 0.0)))
    offset = setpoint if integrating else baseline

    def plant_input(u: float, w: RelayWindow) -> float:
        if u_op is not None:
            return u - u_op
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
    mean_dt = 0.5 * (sample_s[0] + sample_s[1])
    tick = decide_s if decide_s is not None else None
    Phi_tick, Gam_tick = zoh(tick) if tick else (None, None)
    t, k, s = 0.0, 0, 1.0
    u = mid0
    ts, us, ys = [], [], []
    cur: RelayWindow | None = None
    next_log, next_tick = 0.0, 0.0 if tick else math.inf

    def decide(t: float, y_seen: float) -> None:
        nonlocal k, s, u, cur
        while k < len(plan) and plan[k][1] <= t:
            k += 1
        win = plan[k][2] if k < len(plan) else None
        if win is not None:
            e = setpoint - y_seen
            if win is not cur:
                s = 1.0 if e > 0 else -1.0
            if s > 0 and e < -win.eps:
                s = -1.0
            elif s < 0 and e > win.eps:
                s = 1.0
            u_new, ref = (win.high if s > 0 else win.low), win
        else:
            ref = cur or w0
            u_new = 0.5 * (ref.high + ref.low)
        cur = win
        if u_new != u or not pending:
            heapq.heappush(pending, (t + tau, plant_input(u_new, ref)))
        u = u_new

    while next_log < t_end:
        t_ev = min(next_log, next_tick, pending[0][0] if pending else math.inf)
        if t_ev > t:  # propagate with the input the plant sees
            if tick and abs(t_ev - t - tick) < 1e-9 * tick:
                x = Phi_tick @ x + Gam_tick * v
            else:
                Phi, Gam = zoh(t_ev - t)
                x = Phi @ x + Gam * v
            t = t_ev
        while pending and pending[0][0] <= t:
            v = heapq.heappop(pending)[1]
        y_true = float(C[0] @ x) + offset
        if t >= next_tick:
            decide(t, y_true + noise_std * rng.standard_normal())
            next_tick += tick  # type: ignore[operator]
        if t >= next_log:
            y_log = y_true + noise_std * rng.standard_normal()
            if not tick:
                decide(t, y_log)  # the controller decides at the logged samples, on the logged output
            ts.append(t)
            us.append(u)
            ys.append(y_log)
            next_log = t + float(rng.uniform(*sample_s))
    del mean_dt
    return np.array(ts), np.array(us), np.array(ys)
