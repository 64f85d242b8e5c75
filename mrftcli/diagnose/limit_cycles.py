"""Fast MRFT limit cycles of the loop model with the candidate physics (used by :mod:`mrftcli.diagnose.selection`).

Diagnosis fits augmented models to features of the recorded limit cycles, which needs hundreds of
limit cycles per log, each a smooth function of the parameters. :func:`mrftcli.sim.flight.simulate_flight`
simulates whole flights (hover, PID holds, a sampled relay that quantises every switch to a controller
tick); here we only need one test's steady oscillation, so this module integrates the same plant

    y' = v,   v' = -v/Td (or -c v|v|) + K p,   p' = (w - p)/Tp,   [z' = (y - z)/T_lag],
    w(t) = g (a(t - tau)) + d,

with the relay in one of two modes:

* ``continuous``: the switch happens at the exact instant the (noise-free) error crosses
  ``-beta * e_ext`` (cubic Hermite interpolation between ticks, extremum refined the same way). The
  resulting features (period, amplitude, harmonics) are smooth in the parameters, so a least-squares
  fit converges. The log's relay decides at ticks on noisy samples; diagnosis measures the switching
  level that relay actually achieved (its *effective* beta) and uses it here.
* ``sampled``: the switch is decided at ticks on ``y + noise`` with a given beta and optional
  Gauss-Markov delay jitter, exactly like the project simulator. Used to predict the
  cycle-to-cycle scatter that sensor noise (and jitter) produce.

Coordinates are deviations: setpoint 0, relay output u = +/- h (the hover command is removed). The
plant's linear part is propagated exactly (matrix exponential of an augmented system, input a
polynomial of degree <= 1 between events); quadratic drag and thrust rectification use RK4 with
at most T/4 substeps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..sim.control import MrftRelay
from ..sim.plant import LinearPropagator, actuator_pieces, fifo_delays, gauss_markov, rk4_quadratic, rk4_rotor

__all__ = ["AugmentedPlant", "RelayRun", "run_relay", "periodic_cycle", "quasi_static_plant"]


@dataclass(frozen=True)
class AugmentedPlant:
    """The loop model (:class:`mrftcli.mrft.model.LoopModel`'s parameters) augmented with the candidate
    physics, in deviation coordinates.

    Attributes
    ----------
    Tp, Td, tau, K : float
        The linear model of eq. (2) [s, s, s, output units/(command unit s^2)].
    input_bias : float
        Constant disturbance at the plant input [command units] (includes the hover-trim shift a
        drifting gain causes, see :mod:`mrftcli.diagnose.selection`).
    sensor_lag : float
        Extra first-order measurement lag [s]; 0 = none.
    quadratic_drag : float
        c in v' = -c v|v| + K p [1/output unit]; replaces the linear drag when > 0.
    rate_limit : float
        Actuator slew rate [command units/s]; 0 = none.
    asymmetric_gain, headroom, dead_zone, hover_thrust : float
        The command nonlinearities of :mod:`mrftcli.diagnose.physics` (gain (1 +- a) above/below the
        trim; clipping at ``headroom`` above the trim [command units], 0 = none; a dead band
        [command units]; thrust rectification's hover thrust F [command units], 0 = none). Only the
        periodic solver (:func:`mrftcli.diagnose.fit.cycle_plant`) models them.
    """

    Tp: float
    Td: float
    tau: float
    K: float = 1.0
    input_bias: float = 0.0
    sensor_lag: float = 0.0
    quadratic_drag: float = 0.0
    rate_limit: float = 0.0
    asymmetric_gain: float = 0.0
    headroom: float = 0.0
    dead_zone: float = 0.0
    hover_thrust: float = 0.0


@dataclass
class RelayRun:
    """One simulated relay run sampled at the ticks.

    Attributes
    ----------
    t : ndarray
        Tick times [s] (from 0).
    y : ndarray
        Measured output (noise-free) at the ticks [output units], relative to the setpoint.
    up, down : ndarray
        Switch instants to +h and to -h [s].
    """

    t: np.ndarray
    y: np.ndarray
    up: np.ndarray
    down: np.ndarray
    state_at_up: list


class _Propagator:
    """Exact x' = A x + B w with w(s) = c0 + c1 s on an interval of length h.

    Wraps the project simulator's :class:`mrftcli.sim.plant.LinearPropagator` (exponential of the
    augmented matrix): the full tick, used over and over, gets its matrices once and is stepped with
    unrolled scalar arithmetic (far faster than numpy for 3 or 4 states); any other length (a
    switch or a command arrival inside a tick) goes through the simulator's vector Taylor series.
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, T: float) -> None:
        self.n = A.shape[0]
        self.T = T
        self.lin = LinearPropagator(A, B, grid=T)
        self.lin.fix(T)
        Phi, E0, E1, _ = self.lin.fixed(T)
        self.tick = (tuple(Phi.ravel().tolist()), tuple(E0.tolist()), tuple(E1.tolist()))

    def step(self, x: tuple, h: float, c0: float, c1: float) -> tuple:
        if h != self.T:
            return tuple(self.lin.step(np.asarray(x, float), h, c0, c1, 0.0).tolist())
        P, G0, G1 = self.tick
        if self.n == 3:
            x0, x1, x2 = x
            return (
                P[0] * x0 + P[1] * x1 + P[2] * x2 + G0[0] * c0 + G1[0] * c1,
                P[3] * x0 + P[4] * x1 + P[5] * x2 + G0[1] * c0 + G1[1] * c1,
                P[6] * x0 + P[7] * x1 + P[8] * x2 + G0[2] * c0 + G1[2] * c1,
            )
        x0, x1, x2, x3 = x
        return (
            P[0] * x0 + P[1] * x1 + P[2] * x2 + P[3] * x3 + G0[0] * c0 + G1[0] * c1,
            P[4] * x0 + P[5] * x1 + P[6] * x2 + P[7] * x3 + G0[1] * c0 + G1[1] * c1,
            P[8] * x0 + P[9] * x1 + P[10] * x2 + P[11] * x3 + G0[2] * c0 + G1[2] * c1,
            P[12] * x0 + P[13] * x1 + P[14] * x2 + P[15] * x3 + G0[3] * c0 + G1[3] * c1,
        )


def _hermite_root(e0: float, d0: float, e1: float, d1: float, h: float, level: float) -> float:
    """Fraction in [0, 1] where the cubic Hermite interpolant of e crosses ``level`` (bisection)."""
    lo, hi = 0.0, 1.0
    f_lo = e0 - level
    for _ in range(40):
        m = 0.5 * (lo + hi)
        m2, m3 = m * m, m * m * m
        val = (2 * m3 - 3 * m2 + 1) * e0 + (m3 - 2 * m2 + m) * h * d0 + (-2 * m3 + 3 * m2) * e1 + (m3 - m2) * h * d1
        if (val - level) * f_lo > 0:
            lo = m
        else:
            hi = m
    return 0.5 * (lo + hi)


def _hermite_extremum(e0: float, d0: float, e1: float, d1: float, h: float) -> float:
    """Value of the cubic Hermite interpolant where its derivative vanishes (d0, d1 of opposite sign)."""
    # derivative of the interpolant in m is a quadratic; find its root in (0, 1) by bisection
    def deriv(m):
        return (6 * m * m - 6 * m) * e0 + (3 * m * m - 4 * m + 1) * h * d0 + (-6 * m * m + 6 * m) * e1 + (3 * m * m - 2 * m) * h * d1

    lo, hi = 0.0, 1.0
    f_lo = deriv(lo)
    for _ in range(30):
        m = 0.5 * (lo + hi)
        if deriv(m) * f_lo > 0:
            lo = m
        else:
            hi = m
    m = 0.5 * (lo + hi)
    m2, m3 = m * m, m * m * m
    return (2 * m3 - 3 * m2 + 1) * e0 + (m3 - 2 * m2 + m) * h * d0 + (-2 * m3 + 3 * m2) * e1 + (m3 - m2) * h * d1


def run_relay(
    plant: AugmentedPlant,
    beta: float,
    h: float,
    rate_hz: float,
    n_cycles: int,
    *,
    warm: dict | None = None,
    gain_slope: float = 0.0,
    gain_t0: float = 0.0,
    bias_cmd: float = 0.0,
    sampled: bool = False,
    noise_std: float = 0.0,
    jitter_std: float = 0.0,
    jitter_corr: float = 0.05,
    seed: int = 0,
    max_time: float | None = None,
    max_gap: float | None = None,
) -> RelayRun:
    """Simulate the MRFT loop on ``plant`` for ``n_cycles`` switches to +h (or until ``max_time``).

    Parameters
    ----------
    plant : AugmentedPlant
        The (augmented) model.
    beta : float or (float, float)
        Switching level of the relay (effective beta in continuous mode, nominal beta in sampled
        mode); a pair gives (beta for the -h -> +h switch, beta for the +h -> -h switch),
        continuous mode only.
    h : float
        Relay half-height [command units].
    rate_hz : float
        Controller (log) rate [Hz]; the output is sampled at these ticks.
    n_cycles : int
        Stop at the tick after this many switches to +h.
    warm : dict, optional
        A snapshot from ``RelayRun.state_at_up`` (the whole loop state at the tick after a switch to
        +h); time restarts from 0 at that tick.
    gain_slope, gain_t0, bias_cmd : float
        Time-varying gain g(t) = 1 + gain_slope (gain_t0 + t) multiplying the whole command
        (bias_cmd + u), as a battery does; the plant input is g (bias_cmd + u) - bias_cmd + d.
    sampled : bool
        Decide switches at ticks on noisy samples (see the module docstring).
    noise_std, jitter_std, jitter_corr, seed : float, float, float, int
        Sensor noise std [output units], delay jitter std [s] and its correlation time [s]
        (sampled mode only; the same Gauss-Markov, first-in-first-out delay as
        :func:`mrftcli.sim.flight.simulate_flight`).
    max_time : float, optional
        Hard stop [s].
    max_gap : float, optional
        Sampled mode: stop when the relay has not switched for this long [s] (a relay that false
        switches on noise can lock up).
    """
    T = 1.0 / rate_hz
    if isinstance(beta, tuple):
        beta_up, beta_dn = beta
    else:
        beta_up = beta_dn = beta
    lag = plant.sensor_lag > 0
    quad = plant.quadratic_drag > 0
    rotor = plant.hover_thrust > 0
    A = np.array([[0.0, 1.0, 0.0], [0.0, -1.0 / plant.Td, plant.K], [0.0, 0.0, -1.0 / plant.Tp]])
    B = np.array([0.0, 0.0, 1.0 / plant.Tp])
    if quad:
        A[1, 1] = 0.0
    if lag:
        A = np.pad(A, ((0, 1), (0, 1)))
        A[3, 0] = 1.0 / plant.sensor_lag
        A[3, 3] = -1.0 / plant.sensor_lag
        B = np.append(B, 0.0)
    n = A.shape[0]
    prop = _Propagator(A, B, T)
    inv_tp = 1.0 / plant.Tp
    inv_lag = 1.0 / plant.sensor_lag if lag else 0.0
    rng = np.random.default_rng(seed) if sampled else None
    rlim = plant.rate_limit
    d_in = plant.input_bias
    gs = gain_slope

    def advance(x, s, hstep, a0, slope):
        g0 = 1.0 + gs * (gain_t0 + s)
        c0 = g0 * (bias_cmd + a0) - bias_cmd + d_in
        c1 = g0 * slope + gs * (bias_cmd + a0)
        if rotor:
            # the simulator's rotor-speed RK4 (state q: relative rotor speed in place of the force)
            return tuple(rk4_rotor(x, hstep, c0, c1, 0.0, plant.K, 0.0 if quad else 1.0 / plant.Td,
                                   plant.quadratic_drag, plant.hover_thrust, inv_tp, inv_lag, 0.0025).tolist())
        if quad:
            # the project simulator's RK4 (input polynomial of degree <= 1 here), at most 2.5 ms substeps
            return tuple(rk4_quadratic(x, hstep, c0, c1, 0.0, plant.K, plant.quadratic_drag, inv_tp, inv_lag,
                                        0.0025).tolist())
        return prop.step(x, hstep, c0, c1)

    def meas(x):
        return x[3] if lag else x[0]

    def meas_rate(x):
        if lag:
            return (x[0] - x[3]) * inv_lag
        return x[1] if not quad else x[1]

    up: list[float] = []
    down: list[float] = []
    states: list[dict] = []
    if warm is None:
        x = (0.0,) * n
        relay, act, target = 1.0, h, h
        pending: list[tuple[float, float]] = []
        e_prev = -meas(x)
        de_prev = -meas_rate(x)
        e_ext = 1e-300  # start as if the error had just been positive: the first switch comes at once
    else:
        x = tuple(float(v) for v in warm["x"])
        if len(x) != n:  # snapshot of a different structure: cold start
            return run_relay(plant, beta, h, rate_hz, n_cycles, gain_slope=gain_slope, gain_t0=gain_t0,
                             bias_cmd=bias_cmd, sampled=sampled, noise_std=noise_std,
                             jitter_std=jitter_std, jitter_corr=jitter_corr, seed=seed, max_time=max_time,
                             max_gap=max_gap)
        relay, act, target = 1.0, warm["act"], warm["target"]
        pending = list(warm["pending"])
        e_prev, de_prev, e_ext = warm["e_prev"], warm["de_prev"], warm["e_ext"]
        up.append(warm["t_up"])
    max_steps = int((max_time if max_time is not None else 1e6) * rate_hz) + 1
    rule = None
    if sampled:
        # the log's relay decides with one (nominal) level: the project simulator's own rule, in its state
        if beta_up != beta_dn:
            raise ValueError("the sampled relay takes one beta")
        rule = MrftRelay(beta_up)
        rule.relay, rule.e_ext, rule.first_half = relay, e_ext, False
    jit_eff = np.zeros(1)
    if sampled and jitter_std > 0:
        # the delay of the command sent at tick k is tau + d_k, d a Gauss-Markov process at the tick
        # rate (correlation ``jitter_corr``); commands never overtake each other, so the command of
        # tick k takes effect at max_{j<=k} (j T + d_j): its effective extra delay is that minus k T
        # (the simulator's process: mrftcli.sim.plant.gauss_markov and fifo_delays)
        n_j = min(max_steps + 1, 2_000_000)
        phi = math.exp(-T / jitter_corr)
        innov = rng.standard_normal(n_j) * jitter_std * math.sqrt(1.0 - phi * phi)
        innov[0] = rng.standard_normal() * jitter_std
        jit_eff = np.maximum(fifo_delays(gauss_markov(innov, phi), plant.tau, T) - plant.tau, -plant.tau)
    ys: list[float] = [meas(x)]
    t = 0.0
    k = 0

    def snapshot(t_up):
        return {"x": x, "act": act, "target": target,
                "pending": [(pt - t, pv) for pt, pv in pending],
                "e_prev": e_prev, "de_prev": de_prev, "e_ext": e_ext, "t_up": t_up - t}

    t_last_switch = 0.0
    while k < max_steps:
        t_end = (k + 1) * T
        pieces, act, target = actuator_pieces(t, t_end, pending, act, target, rlim, tol=1e-15)
        for s, hs, a, slope in pieces:
            if abs(hs - T) < 1e-12:
                hs = T  # the whole tick: its propagator is cached
            x = advance(x, s, hs, a, slope)
        t = t_end
        k += 1
        y_m = meas(x)
        ys.append(y_m)
        if not math.isfinite(y_m) or abs(y_m) > 1e9:
            break
        if sampled:
            e = -(y_m + rng.normal(0.0, noise_std)) if noise_std > 0 else -y_m
            new = rule.step(e)
            switched = new != relay
            relay = new
            if not switched and max_gap is not None and t - t_last_switch > max_gap:
                break
            if switched:
                t_last_switch = t
                delay = plant.tau + (float(jit_eff[min(k, jit_eff.size - 1)]) if jitter_std > 0 else 0.0)
                pending.append((t + max(delay, 0.0), relay * h))
                pending.sort()
                (up if relay > 0 else down).append(t)
                if relay > 0 and len(up) >= n_cycles:
                    break
            continue
        e = -y_m
        de = -meas_rate(x)
        if relay > 0:
            cand = e
            if de_prev > 0 >= de:
                cand = max(cand, _hermite_extremum(e_prev, de_prev, e, de, T))
            e_ext_new = max(e_ext, cand)
            thr = -beta_dn * e_ext_new
            if e_ext_new > 0 and e <= thr:
                frac = _hermite_root(e_prev, de_prev, e, de, T, thr) if e_prev > thr else 0.0
                tc = t - T + frac * T
                relay = -1.0
                e_ext = min(thr, e)
                down.append(tc)
                pending.append((tc + plant.tau, -h))
                pending.sort()
            else:
                e_ext = e_ext_new
        else:
            cand = e
            if de_prev < 0 <= de:
                cand = min(cand, _hermite_extremum(e_prev, de_prev, e, de, T))
            e_ext_new = min(e_ext, cand)
            thr = -beta_up * e_ext_new
            if e_ext_new < 0 and e >= thr:
                frac = _hermite_root(e_prev, de_prev, e, de, T, thr) if e_prev < thr else 0.0
                tc = t - T + frac * T
                relay = 1.0
                e_ext = max(thr, e)
                up.append(tc)
                pending.append((tc + plant.tau, h))
                pending.sort()
                e_prev, de_prev = e, de
                states.append(snapshot(tc))
                if len(up) >= n_cycles:
                    break
                continue
            else:
                e_ext = e_ext_new
        e_prev, de_prev = e, de
    tt = np.arange(len(ys)) * T
    return RelayRun(t=tt, y=np.asarray(ys), up=np.asarray(up), down=np.asarray(down), state_at_up=states)


def periodic_cycle(
    plant: AugmentedPlant,
    beta: float,
    h: float,
    rate_hz: float,
    *,
    warm: dict | None = None,
    max_cycles: int = 40,
    tol: float = 1e-7,
) -> RelayRun | None:
    """Run the continuous relay until successive periods agree to ``tol``; the run's last cycle is
    the periodic solution. Returns ``None`` when no limit cycle forms (divergence, no switching).
    """
    chunk = 4 if warm is not None else 10
    total = 0
    run = None
    while total < max_cycles:
        run = run_relay(plant, beta, h, rate_hz, chunk + 1, warm=warm, max_time=(chunk + 2) * 30.0)
        if run.up.size < 3 or not np.all(np.isfinite(run.y)) or np.abs(run.y).max() > 1e6:
            return None
        per = np.diff(run.up)
        total += per.size
        if per.size >= 3 and abs(per[-1] - per[-2]) < tol * per[-1] and abs(per[-2] - per[-3]) < tol * per[-1]:
            return run
        warm = run.state_at_up[-1]
        chunk = 4
    return run


def quasi_static_plant(plant: AugmentedPlant, gain: float, bias_cmd: float) -> AugmentedPlant:
    """The plant seen at a constant battery gain g: g (b + u) - b + d = g (u + ((g - 1) b + d) / g)."""
    if gain == 1.0:
        return plant
    from dataclasses import replace

    return replace(plant, K=plant.K * gain, input_bias=(plant.input_bias + (gain - 1.0) * bias_cmd) / gain)
