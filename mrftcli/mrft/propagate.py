"""Exact propagation of the loop's plant between events, RK4 for its nonlinear forms, the actuator
between controller ticks and the jittered transport delay.

The one home of the propagators that both the diagnosis (:mod:`mrftcli.diagnose.limit_cycles`, one
test's limit cycle) and the simulator (:mod:`mrftcli.sim.flight`, whole flights) integrate with;
the simulator imports them from here. See docs/simulator.md, "Integration".
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["taylor_expm", "phi_gamma", "LinearPropagator", "rk4_quadratic", "RotorCoefficients", "rk4_rotor",
           "actuator_pieces", "gauss_markov",
           "fifo_delays"]


# --------------------------------------------------------------------------------------------------
# exact propagation of the linear part


def taylor_expm(M: np.ndarray) -> np.ndarray:
    """e^M by a Taylor series with scaling and squaring (||M||_1 scaled to <= 1/2; error ~1e-16).

    ``M`` is one matrix (n, n) or a stack (..., n, n), exponentiated together with one scaling (the
    largest norm's); a single matrix gives the same bits as before stacks were taken.

    Kept instead of :func:`scipy.linalg.expm` (Pade with scaling and squaring) for bit-identity,
    and for stacks: ``benchmarks/bench_simulate.py`` measures both on the very matrices a flight
    exponentiates (docs/benchmarks/simulate.md): 39 us against 44-135 us per call; a flight needs
    only 2-3 calls (the diagnosis one per limit-cycle run), so there either costs well under 1 % of
    the run. The two agree to 1.4e-17 yet not bit for bit, and every simulated sample log and every
    diagnosis would change in its last digits with scipy's. ``tune`` discretises its hundreds of
    posterior draws as one stack per piece of the held tick (:func:`phi_gamma`): 400 draws in about
    3 ms of CPU, against 0.9 s for scipy's expm draw by draw (docs/tune.md, "Speed").

    Examples
    --------
    >>> import numpy as np
    >>> bool(np.allclose(taylor_expm(np.array([[0.0, 1.0], [0.0, 0.0]])), [[1.0, 1.0], [0.0, 1.0]]))
    True
    """
    norm = float(np.abs(M).sum(axis=-2).max())  # a stack of matrices (..., n, n): one scaling for all
    squarings = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    A = M / (2.0**squarings)
    eye = np.eye(M.shape[-1])
    E = eye.copy()
    for k in range(18, 0, -1):  # 0.5^19 / 19! < 1e-22
        E = eye + (A @ E) / k
    for _ in range(squarings):
        E = E @ E
    return E


def phi_gamma(A: np.ndarray, B: np.ndarray, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e^{A t}, int_0^t e^{A s} ds B) of x' = A x + B u with u held over [0, t) [s]: one
    :func:`taylor_expm` of the augmented matrix [[A t, B t], [0, 0]] (the zero-order hold's pieces; the
    limit-cycle searches call it hundreds of times, where scipy's expm cost ~10 ms in its dispatch).

    A stack of plants at once: ``A`` (..., n, n), ``B`` (..., n) and ``t`` a scalar or (...,) [s] give
    (..., n, n) and (..., n), the whole stack in one :func:`taylor_expm` (one scaling for all).
    """
    n = A.shape[-1]
    t = np.asarray(t, float)
    M = np.zeros((*np.broadcast_shapes(A.shape[:-2], B.shape[:-1], t.shape), n + 1, n + 1))
    M[..., :n, :n] = A * t[..., None, None]
    M[..., :n, n] = B * t[..., None]
    E = taylor_expm(M)
    return E[..., :n, :n], E[..., :n, n]


class LinearPropagator:
    """Exact propagation of x' = A x + B w(t) for w(s0 + s) = c0 + c1 s + c2 s^2 / 2.

    Uses the exponential of the augmented matrix M = [[A, B, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], 0]:
    its top-right blocks are int_0^h e^{A(h-s)} B s^j / j! ds for j = 0, 1, 2, i.e. the state
    z = [x, w, w', w''] evolves as z(h) = e^{M h} z(0). Lengths that recur (the fixed delay's two
    sub-intervals) get their exponential once; any other length h = n g + d (g = ``grid``) is
    e^{M n g} (cached, at most T/g of them) times a short Taylor series for the remainder d < g
    applied to the vector - exact to rounding, and about 30x cheaper than an expm per call.
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, grid: float) -> None:
        n = A.shape[0]
        self.n = n
        M = np.zeros((n + 3, n + 3))
        M[:n, :n] = A
        M[:n, n] = B
        M[n, n + 1] = 1.0
        M[n + 1, n + 2] = 1.0
        self._M = M
        self._grid = float(grid)
        self._fixed: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        self._grid_exp: dict[int, np.ndarray] = {}
        # Taylor terms for a remainder < grid: rho^N / N! < 1e-17 with rho = ||M||_1 * grid
        rho = float(np.abs(M).sum(axis=0).max()) * self._grid
        terms, err = 1, rho
        while err > 1e-17 and terms < 60:
            terms += 1
            err *= rho / terms
        self._terms = terms

    def fix(self, h: float) -> None:
        """Precompute the matrices of a recurring length ``h``."""
        E = taylor_expm(self._M * h)
        n = self.n
        self._fixed[h] = (E[:n, :n].copy(), E[:n, n].copy(), E[:n, n + 1].copy(), E[:n, n + 2].copy())

    def fixed(self, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(Phi, E0, E1, E2) of a length registered with :meth:`fix`: x(h) = Phi x + E0 c0 + E1 c1 + E2 c2."""
        return self._fixed[h]

    def step(self, x: np.ndarray, h: float, c0: float, c1: float, c2: float) -> np.ndarray:
        got = self._fixed.get(h)
        if got is not None:
            Phi, E0, E1, E2 = got
            out: np.ndarray = Phi @ x + E0 * c0
            if c1 != 0.0:
                out += E1 * c1
            if c2 != 0.0:
                out += E2 * c2
            return out
        z = np.concatenate([x, (c0, c1, c2)])
        k = int(h / self._grid)
        rest = h - k * self._grid
        if rest > 0.0:
            # Taylor series on the vector: ||M rest|| < ||M|| grid, so few terms reach rounding level
            M = self._M
            term = z
            total = z.copy()
            for i in range(1, self._terms + 1):
                term = (M @ term) * (rest / i)
                total += term
            z = total
        if k:
            E = self._grid_exp.get(k)
            if E is None:
                E = self._grid_exp[k] = taylor_expm(self._M * (k * self._grid))
            z = E @ z
        return z[: self.n]


# --------------------------------------------------------------------------------------------------
# RK4 for quadratic drag and thrust rectification


def rk4_quadratic(
    x: np.ndarray | Sequence[float], h: float, c0: float, c1: float, c2: float,
    K: float, c: float, inv_tp: float, inv_ts: float, max_step: float,
) -> np.ndarray:
    """RK4 for y' = v, v' = -c v|v| + K p, p' = (w - p)/Tp [, f' = (y - f)/Ts] over a length ``h`` [s].

    The input is w(s) = c0 + c1 s + c2 s^2 / 2; ``x`` holds (y, v, p[, f]); ``inv_tp`` = 1/Tp and
    ``inv_ts`` = 1/Ts [1/s]; the step is at most ``max_step`` [s].
    """
    n_sub = max(1, math.ceil(h / max_step - 1e-9))
    dt = h / n_sub
    lag = len(x) == 4
    y, v, p = float(x[0]), float(x[1]), float(x[2])
    f = float(x[3]) if lag else 0.0
    s = 0.0
    for _ in range(n_sub):
        w1 = c0 + c1 * s + 0.5 * c2 * s * s
        sm = s + 0.5 * dt
        w2 = c0 + c1 * sm + 0.5 * c2 * sm * sm
        se = s + dt
        w3 = c0 + c1 * se + 0.5 * c2 * se * se
        ky1, kv1, kp1 = v, -c * v * abs(v) + K * p, (w1 - p) * inv_tp
        kf1 = (y - f) * inv_ts
        v2, p2, y2, f2 = v + 0.5 * dt * kv1, p + 0.5 * dt * kp1, y + 0.5 * dt * ky1, f + 0.5 * dt * kf1
        ky2, kv2, kp2 = v2, -c * v2 * abs(v2) + K * p2, (w2 - p2) * inv_tp
        kf2 = (y2 - f2) * inv_ts
        v3, p3, y3, f3 = v + 0.5 * dt * kv2, p + 0.5 * dt * kp2, y + 0.5 * dt * ky2, f + 0.5 * dt * kf2
        ky3, kv3, kp3 = v3, -c * v3 * abs(v3) + K * p3, (w2 - p3) * inv_tp
        kf3 = (y3 - f3) * inv_ts
        v4, p4, y4, f4 = v + dt * kv3, p + dt * kp3, y + dt * ky3, f + dt * kf3
        ky4, kv4, kp4 = v4, -c * v4 * abs(v4) + K * p4, (w3 - p4) * inv_tp
        kf4 = (y4 - f4) * inv_ts
        y += dt / 6.0 * (ky1 + 2 * ky2 + 2 * ky3 + ky4)
        v += dt / 6.0 * (kv1 + 2 * kv2 + 2 * kv3 + kv4)
        p += dt / 6.0 * (kp1 + 2 * kp2 + 2 * kp3 + kp4)
        f += dt / 6.0 * (kf1 + 2 * kf2 + 2 * kf3 + kf4)
        s = se
    return np.array([y, v, p, f]) if lag else np.array([y, v, p])


@dataclass(frozen=True)
class RotorCoefficients:
    """The coefficients of the rotor-speed plant :func:`rk4_rotor` integrates; checked on creation.

    Built once per run (a flight, a diagnosed test): :func:`rk4_rotor` is called per tick.

    Attributes
    ----------
    K : float
        Plant gain [output units / s^2 per command unit].
    inv_td : float
        1/Td [1/s], the linear drag (>= 0; 0 when quadratic drag replaces it).
    quadratic_drag : float
        c in v' = ... - c v|v| [1/output unit] (>= 0).
    hover_thrust : float
        F [command units] (> 0): the hover thrust above the zero-thrust command.
    inv_tp : float
        1/Tp [1/s] (> 0), the propulsion lag on the rotor speed.
    inv_ts : float
        1/Ts [1/s] (>= 0) of the sensor lag f' = (y - f)/Ts (0: no lag state).
    max_step : float
        Longest RK4 step [s] (> 0).

    Raises
    ------
    InputError
        A coefficient that is not finite or is out of its range.
    """

    K: float
    inv_td: float
    quadratic_drag: float
    hover_thrust: float
    inv_tp: float
    inv_ts: float
    max_step: float

    def __post_init__(self) -> None:
        for name in ("K", "inv_td", "quadratic_drag", "hover_thrust", "inv_tp", "inv_ts", "max_step"):
            value = float(getattr(self, name))
            need = "> 0" if name in ("hover_thrust", "inv_tp", "max_step") else ">= 0"
            in_range = value > 0 if need == "> 0" else (value >= 0 or name == "K")  # K carries the loop's sign
            if not (math.isfinite(value) and in_range):
                raise InputError(f"the rotor plant's {name} must be finite and {need}, got {value!r}")
            object.__setattr__(self, name, value)


def rk4_rotor(
    x: np.ndarray | Sequence[float], h: float, c0: float, c1: float, c2: float, plant: RotorCoefficients,
) -> np.ndarray:
    """RK4 with the propulsion lag on rotor speed (thrust rectification) over a length ``h`` [s].

    ``x`` holds (y, v, q[, f]): q = omega / omega_hover - 1 the relative rotor speed. The rotor
    speed follows the speed the command asks for, q' = (sqrt(1 + w/F) - 1 - q)/Tp, and the thrust
    [command units] is p = F ((1 + q)^2 - 1), F = ``plant.hover_thrust`` (the hover thrust above the
    zero-thrust command); v' = -v/Td - c v|v| + K p (``plant.inv_td`` = 1/Td, ``plant.quadratic_drag``
    = c, either may be 0). For small swings p ~ w lagged by Tp, the linear model.
    w(s) = c0 + c1 s + c2 s^2 / 2 [command units], s [s] from the start of the step.
    """
    # plain float locals and scalar stages, as rk4_quadratic: per tick this was 4 x n_sub small numpy arrays (the
    # sampled relay on a rotor plant took ~75 % of a diagnosis' CPU); the same operations in the same order
    K, inv_td, c, F = plant.K, plant.inv_td, plant.quadratic_drag, plant.hover_thrust
    inv_tp, inv_ts, max_step = plant.inv_tp, plant.inv_ts, plant.max_step
    n_sub = max(1, math.ceil(h / max_step - 1e-9))
    dt = h / n_sub
    lag = len(x) == 4
    y, v, q = float(x[0]), float(x[1]), float(x[2])
    f = float(x[3]) if lag else 0.0

    def w_c(s: float) -> float:
        """The rotor speed the command asks for at s, relative to hover's."""
        w = c0 + c1 * s + 0.5 * c2 * s * s
        return math.sqrt(max(1.0 + w / F, 0.0)) - 1.0

    s = 0.0
    half = 0.5 * dt
    q_start = w_c(s)
    for _ in range(n_sub):
        # the four stages inline (a call each cost as much as its arithmetic); q_mid: the stages at s + dt/2
        q_mid, q_end = w_c(s + half), w_c(s + dt)
        kv1 = -v * inv_td - c * v * abs(v) + K * (F * ((1.0 + q) ** 2 - 1.0))
        kq1, kf1 = (q_start - q) * inv_tp, (y - f) * inv_ts
        y2, v2, q2, f2 = y + half * v, v + half * kv1, q + half * kq1, f + half * kf1
        kv2 = -v2 * inv_td - c * v2 * abs(v2) + K * (F * ((1.0 + q2) ** 2 - 1.0))
        kq2, kf2 = (q_mid - q2) * inv_tp, (y2 - f2) * inv_ts
        y3, v3, q3, f3 = y + half * v2, v + half * kv2, q + half * kq2, f + half * kf2
        kv3 = -v3 * inv_td - c * v3 * abs(v3) + K * (F * ((1.0 + q3) ** 2 - 1.0))
        kq3, kf3 = (q_mid - q3) * inv_tp, (y3 - f3) * inv_ts
        y4, v4, q4, f4 = y + dt * v3, v + dt * kv3, q + dt * kq3, f + dt * kf3
        kv4 = -v4 * inv_td - c * v4 * abs(v4) + K * (F * ((1.0 + q4) ** 2 - 1.0))
        kq4, kf4 = (q_end - q4) * inv_tp, (y4 - f4) * inv_ts
        sixth = dt / 6.0
        y += sixth * (v + 2 * v2 + 2 * v3 + v4)
        v += sixth * (kv1 + 2 * kv2 + 2 * kv3 + kv4)
        q += sixth * (kq1 + 2 * kq2 + 2 * kq3 + kq4)
        f += sixth * (kf1 + 2 * kf2 + 2 * kf3 + kf4)
        s += dt
        q_start = q_end  # (s + dt above is this s, bit for bit)
    return np.array([y, v, q, f]) if lag else np.array([y, v, q])


# --------------------------------------------------------------------------------------------------
# actuator between ticks: commands arriving after their delay, optional slew-rate limit


def actuator_pieces(s: float, t_end: float, pending: deque[tuple[float, float]] | list[tuple[float, float]], act: float, target: float, rate_limit: float,
                    tol: float = 0.0) -> tuple[list[tuple[float, float, float, float]], float, float]:
    """Split [s, t_end) into pieces over which the actuator input is affine in time.

    ``pending`` holds (arrival time [s], command) in time order (a deque or a list); the commands that
    arrive before ``t_end`` are taken from it. Without a rate limit the actuator steps to each
    command on arrival; with ``rate_limit`` > 0 [command units/s] it slews towards the latest one.
    ``tol`` [s] absorbs rounding in arrival times. Returns ``(pieces, act, target)``: pieces are
    (start [s], length [s], actuator value at start, slope [units/s]), and the actuator's value and
    target at t_end.
    """
    pop_first = pending.popleft if isinstance(pending, deque) else (lambda: pending.pop(0))
    pieces = []
    while True:
        while pending and pending[0][0] <= s + tol:  # commands reaching the actuator now
            target = pop_first()[1]
            if rate_limit == 0:
                act = target
        if s >= t_end - tol:
            break
        nxt = t_end
        if pending and pending[0][0] < nxt:
            nxt = pending[0][0]
        slope = 0.0
        arrived = False
        if rate_limit > 0 and act != target:
            slope = math.copysign(rate_limit, target - act)
            reach = s + abs(target - act) / rate_limit
            if reach <= nxt:
                nxt, arrived = reach, True
        h = nxt - s
        if h > 0:
            pieces.append((s, h, act, slope))
        if arrived:
            act = target
        elif slope != 0.0:
            act += slope * h
        s = nxt
    return pieces, act, target


# --------------------------------------------------------------------------------------------------
# delay jitter: a first-order Gauss-Markov (AR(1)) process at the tick rate, first in first out


def gauss_markov(innovations: np.ndarray, phi: float) -> np.ndarray:
    """The AR(1) process d_0 = i_0, d_k = phi d_(k-1) + i_k of the transport-delay jitter [s].

    ``innovations`` [s] are already scaled by the caller: for a stationary process of std sigma and
    correlation time tau_c sampled every T, phi = exp(-T / tau_c), i_0 = sigma z_0 and
    i_k = sigma sqrt(1 - phi^2) z_k with standard normal z. One :func:`scipy.signal.lfilter`, used by
    the simulator and by the diagnosis' sampled relay alike.

    Examples
    --------
    >>> gauss_markov(np.array([1.0, 0.0, 2.0]), 0.5).tolist()
    [1.0, 0.5, 2.25]
    """
    from scipy.signal import lfilter  # here, not at the top: importing mrftcli.mrft must not load scipy.signal

    out: np.ndarray = lfilter([1.0], [1.0, -phi], np.asarray(innovations, dtype=float))
    return out


def fifo_delays(d: np.ndarray, tau: float, T: float) -> np.ndarray:
    """Transport delay [s] of the command sent at each tick k T: tau + d_k, never negative, and
    commands never overtake each other (a command takes effect at max over j <= k of j T + delay_j).

    Examples
    --------
    >>> fifo_delays(np.array([0.5, -0.5, 0.0, -1.0]), 0.5, 0.25).tolist()  # 2nd-4th wait for the 1st
    [1.0, 0.75, 0.5, 0.25]
    """
    kT = np.arange(len(d)) * T
    apply_at: np.ndarray = np.maximum.accumulate(kT + np.maximum(tau + d, 0.0))
    delays: np.ndarray = apply_at - kT
    return delays
