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
from dataclasses import dataclass, field

import numpy as np

from ..mrft.propagate import (LinearPropagator, RotorCoefficients, actuator_pieces, fifo_delays, gauss_markov,
                              rk4_quadratic, rk4_rotor)
from ..mrft.relays import MrftRelay

__all__ = ["AugmentedPlant", "RelayRun", "SampledRelay", "run_relay", "periodic_cycle", "quasi_static_plant"]


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
        periodic solver (:func:`mrftcli.diagnose.candidate_model.cycle_plant`) models them.
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

    Wraps the project simulator's :class:`mrftcli.mrft.propagate.LinearPropagator` (exponential of the
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


@dataclass(frozen=True)
class SampledRelay:
    """The log's relay, as :func:`run_relay` runs it in sampled mode (see the module docstring).

    The switch is decided at ticks on ``y + noise`` with one (nominal) beta by :class:`~mrftcli.mrft.relays.MrftRelay`,
    and the command sent reaches the plant after a Gauss-Markov, first-in-first-out delay (the same
    process as :func:`mrftcli.sim.flight.simulate_flight`'s, from :mod:`mrftcli.mrft.propagate`).

    Attributes
    ----------
    noise_std : float
        Sensor noise std [output units].
    jitter_std, jitter_corr : float
        Delay jitter std [s] and its correlation time [s].
    seed : int
        Seed of the noise and jitter draws.
    max_gap : float, optional
        Stop when the relay has not switched for this long [s] (a relay that false switches on
        noise can lock up).
    """

    noise_std: float = 0.0
    jitter_std: float = 0.0
    jitter_corr: float = 0.05
    seed: int = 0
    max_gap: float | None = None


def _loop_matrices(plant: AugmentedPlant) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of y' = v, v' = -v/Td + K p, p' = (w - p)/Tp [, z' = (y - z)/T_lag] (no linear drag
    when the quadratic one replaces it)."""
    A = np.array([[0.0, 1.0, 0.0], [0.0, -1.0 / plant.Td, plant.K], [0.0, 0.0, -1.0 / plant.Tp]])
    B = np.array([0.0, 0.0, 1.0 / plant.Tp])
    if plant.quadratic_drag > 0:
        A[1, 1] = 0.0
    if plant.sensor_lag > 0:
        A = np.pad(A, ((0, 1), (0, 1)))
        A[3, 0] = 1.0 / plant.sensor_lag
        A[3, 3] = -1.0 / plant.sensor_lag
        B = np.append(B, 0.0)
    return A, B


class _PlantStepper:
    """The plant between events: exact for the linear model, the propagators' RK4 for quadratic drag
    and thrust rectification (at most 2.5 ms substeps); the measured output and its rate."""

    def __init__(self, plant: AugmentedPlant, T: float) -> None:
        self.plant = plant
        self.lag = plant.sensor_lag > 0
        self.quad = plant.quadratic_drag > 0
        self.rotor = plant.hover_thrust > 0
        A, B = _loop_matrices(plant)
        self.n = A.shape[0]
        self.prop = _Propagator(A, B, T)
        self.inv_tp = 1.0 / plant.Tp
        self.inv_lag = 1.0 / plant.sensor_lag if self.lag else 0.0
        # the rotor's coefficients once per run (advance is called per event)
        self.rotor_plant = RotorCoefficients(plant.K, 0.0 if self.quad else 1.0 / plant.Td, plant.quadratic_drag,
                                             plant.hover_thrust, self.inv_tp, self.inv_lag, 0.0025) \
            if self.rotor else None

    def advance(self, x: tuple, hstep: float, a0: float, slope: float) -> tuple:
        """The state after ``hstep`` [s] with the actuator at ``a0`` moving at ``slope`` [units/s]."""
        p = self.plant
        c0, c1 = a0 + p.input_bias, slope
        if self.rotor_plant is not None:
            # the rotor-speed RK4 (state q: relative rotor speed in place of the force)
            return tuple(rk4_rotor(x, hstep, c0, c1, 0.0, self.rotor_plant).tolist())
        if self.quad:
            # RK4 (input polynomial of degree <= 1 here), at most 2.5 ms substeps
            return tuple(rk4_quadratic(x, hstep, c0, c1, 0.0, p.K, p.quadratic_drag, self.inv_tp, self.inv_lag,
                                       0.0025).tolist())
        return self.prop.step(x, hstep, c0, c1)

    def meas(self, x: tuple) -> float:
        """The measured output (through the sensor lag when there is one)."""
        return x[3] if self.lag else x[0]

    def meas_rate(self, x: tuple) -> float:
        """d/dt of the measured output."""
        return (x[0] - x[3]) * self.inv_lag if self.lag else x[1]


@dataclass
class _Loop:
    """The relay loop's working state between ticks (what a warm start restores)."""

    x: tuple
    relay: float
    act: float
    target: float
    pending: list
    e_prev: float
    de_prev: float
    e_ext: float
    t: float = 0.0
    up: list = field(default_factory=list)
    down: list = field(default_factory=list)
    states: list = field(default_factory=list)
    t_last_switch: float = 0.0

    @classmethod
    def cold(cls, stepper: _PlantStepper, h: float) -> _Loop:
        x = (0.0,) * stepper.n
        # start as if the error had just been positive: the first switch comes at once
        return cls(x=x, relay=1.0, act=h, target=h, pending=[], e_prev=-stepper.meas(x),
                   de_prev=-stepper.meas_rate(x), e_ext=1e-300)

    @classmethod
    def warm(cls, snap: dict) -> _Loop:
        loop = cls(x=tuple(float(v) for v in snap["x"]), relay=1.0, act=snap["act"], target=snap["target"],
                   pending=list(snap["pending"]), e_prev=snap["e_prev"], de_prev=snap["de_prev"], e_ext=snap["e_ext"])
        loop.up.append(snap["t_up"])
        return loop

    def snapshot(self, t_up: float) -> dict:
        """The whole loop state at this tick; times relative to it (``RelayRun.state_at_up``)."""
        return {"x": self.x, "act": self.act, "target": self.target,
                "pending": [(pt - self.t, pv) for pt, pv in self.pending],
                "e_prev": self.e_prev, "de_prev": self.de_prev, "e_ext": self.e_ext, "t_up": t_up - self.t}

    def send(self, t_arrive: float, u: float) -> None:
        """A relay output that reaches the actuator at ``t_arrive`` [s]."""
        self.pending.append((t_arrive, u))
        self.pending.sort()


def _jitter_delays(rng: np.random.Generator, relay: SampledRelay, tau: float, T: float, n_ticks: int) -> np.ndarray:
    """Effective extra delay [s] of the command sent at each tick.

    The delay of the command sent at tick k is tau + d_k, d a Gauss-Markov process at the tick rate
    (correlation ``jitter_corr``); commands never overtake each other, so the command of tick k takes
    effect at max_{j<=k} (j T + d_j): its effective extra delay is that minus k T.
    """
    n_j = min(n_ticks + 1, 2_000_000)
    phi = math.exp(-T / relay.jitter_corr)
    innov = rng.standard_normal(n_j) * relay.jitter_std * math.sqrt(1.0 - phi * phi)
    innov[0] = rng.standard_normal() * relay.jitter_std
    return np.maximum(fifo_delays(gauss_markov(innov, phi), tau, T) - tau, -tau)


#: the arrival-time tolerance [s] of the actuator's pieces within a tick (:func:`_tick`)
_ARRIVAL_TOL = 1e-15


def _tick(loop: _Loop, stepper: _PlantStepper, k: int, T: float) -> float:
    """Propagate the loop over tick ``k`` (the actuator's pieces within it); the measured output at its end."""
    t_end = (k + 1) * T
    pend = loop.pending
    if ((not pend or pend[0][0] > t_end + _ARRIVAL_TOL) and (loop.act == loop.target or stepper.plant.rate_limit == 0)
            and loop.t < t_end - _ARRIVAL_TOL):
        # nothing arrives and the actuator rests: the one piece actuator_pieces would return, without
        # building it (most ticks of the sampled relay's runs; issue 39: the same arithmetic, so every bit)
        hs = t_end - loop.t
        x = stepper.advance(loop.x, T if abs(hs - T) < 1e-12 else hs, loop.act, 0.0)
        loop.x, loop.t = x, t_end
        return stepper.meas(x)
    pieces, loop.act, loop.target = actuator_pieces(loop.t, t_end, loop.pending, loop.act, loop.target,
                                                    stepper.plant.rate_limit, tol=_ARRIVAL_TOL)
    x = loop.x
    for _, hs, a, slope in pieces:
        if abs(hs - T) < 1e-12:
            hs = T  # the whole tick: its propagator is cached
        x = stepper.advance(x, hs, a, slope)
    loop.x, loop.t = x, t_end
    return stepper.meas(x)


def _sampled_switch(loop: _Loop, new: float, delay: float, h: float) -> None:
    """The log's relay switched to ``new`` (its sign) at this tick: the command sent, reaching the
    actuator ``delay`` [s] later."""
    loop.relay = new
    loop.t_last_switch = loop.t
    loop.send(loop.t + max(delay, 0.0), new * h)
    (loop.up if new > 0 else loop.down).append(loop.t)


def _continuous_switch(loop: _Loop, e: float, de: float, T: float, beta_up: float, beta_dn: float,
                       tau: float, h: float) -> bool:
    """The continuous relay: the switch at the exact instant the interpolated error crosses -beta e_ext
    (extremum refined by cubic Hermite interpolation between ticks). True at a switch to +h."""
    t = loop.t
    if loop.relay > 0:
        cand = e
        if loop.de_prev > 0 >= de:
            cand = max(cand, _hermite_extremum(loop.e_prev, loop.de_prev, e, de, T))
        e_ext_new = max(loop.e_ext, cand)
        thr = -beta_dn * e_ext_new
        if e_ext_new > 0 and e <= thr:
            frac = _hermite_root(loop.e_prev, loop.de_prev, e, de, T, thr) if loop.e_prev > thr else 0.0
            tc = t - T + frac * T
            loop.relay = -1.0
            loop.e_ext = min(thr, e)
            loop.down.append(tc)
            loop.send(tc + tau, -h)
        else:
            loop.e_ext = e_ext_new
        loop.e_prev, loop.de_prev = e, de
        return False
    cand = e
    if loop.de_prev < 0 <= de:
        cand = min(cand, _hermite_extremum(loop.e_prev, loop.de_prev, e, de, T))
    e_ext_new = min(loop.e_ext, cand)
    thr = -beta_up * e_ext_new
    if e_ext_new < 0 and e >= thr:
        frac = _hermite_root(loop.e_prev, loop.de_prev, e, de, T, thr) if loop.e_prev < thr else 0.0
        tc = t - T + frac * T
        loop.relay = 1.0
        loop.e_ext = max(thr, e)
        loop.up.append(tc)
        loop.send(tc + tau, h)
        loop.e_prev, loop.de_prev = e, de
        loop.states.append(loop.snapshot(tc))
        return True
    loop.e_ext = e_ext_new
    loop.e_prev, loop.de_prev = e, de
    return False


def run_relay(
    plant: AugmentedPlant,
    beta: float | tuple[float, float],
    h: float,
    rate_hz: float,
    n_cycles: int,
    *,
    warm: dict | None = None,
    sampled: SampledRelay | None = None,
    max_time: float | None = None,
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
    sampled : SampledRelay, optional
        Decide switches at ticks on noisy samples, with its noise and delay jitter (see the module
        docstring); None: the continuous relay.
    max_time : float, optional
        Hard stop [s].

    Raises
    ------
    ValueError
        A pair of betas with the sampled relay.
    """
    T = 1.0 / rate_hz
    beta_up, beta_dn = beta if isinstance(beta, tuple) else (beta, beta)
    stepper = _PlantStepper(plant, T)
    if warm is not None and len(warm["x"]) != stepper.n:  # snapshot of a different structure: cold start
        warm = None
    loop = _Loop.cold(stepper, h) if warm is None else _Loop.warm(warm)
    max_steps = int((max_time if max_time is not None else 1e6) * rate_hz) + 1
    ys: list[float] = [stepper.meas(loop.x)]
    if sampled is None:
        for k in range(max_steps):
            y_m = _tick(loop, stepper, k, T)
            ys.append(y_m)
            if not math.isfinite(y_m) or abs(y_m) > 1e9:
                break
            if (_continuous_switch(loop, -y_m, -stepper.meas_rate(loop.x), T, beta_up, beta_dn, plant.tau, h)
                    and len(loop.up) >= n_cycles):
                break
    else:
        _run_sampled(loop, stepper, sampled, beta_up, beta_dn, h, n_cycles, max_steps, ys)
    tt = np.arange(len(ys)) * T
    return RelayRun(t=tt, y=np.asarray(ys), up=np.asarray(loop.up), down=np.asarray(loop.down),
                    state_at_up=loop.states)


#: sensor-noise draws taken from the generator at once by the sampled relay (:func:`_run_sampled`)
_NOISE_BLOCK = 1024
#: :func:`_run_sampled` steps its resting whole ticks itself (False: every tick through :func:`_tick`;
#: the tests compare the two bit for bit)
_INLINE_TICK = True


def _run_sampled(loop: _Loop, stepper: _PlantStepper, relay: SampledRelay, beta_up: float, beta_dn: float, h: float,
                 n_cycles: int, max_steps: int, ys: list[float]) -> None:
    """The tick loop of the sampled relay (the log's relay: one nominal beta, noisy samples, jitter).

    A tick in which no command arrives and the actuator rests is the linear plant's whole-tick step,
    written out here (the arithmetic of ``_Propagator.step``, so every bit of :func:`_tick`'s), and the
    sensor noise is drawn in blocks after the jitter's draws (a Generator's stream does not depend on
    how its draws are grouped): these runs were half a diagnosis' CPU on some logs (issue 39).

    The written-out step (and its test, the one :func:`_tick` makes) is a deliberate second copy:
    calling ``_Propagator.step`` and ``_PlantStepper.meas`` instead costs 11-14 % of the relay's CPU
    at 1 kHz (0.82 -> 0.93 us a tick; 3-5 % at 100-250 Hz; R3's review, measured on a sampled relay
    with noise, 60 cycles, best of 5), and routing every tick through :func:`_tick` 23 %. Any change
    to ``_Propagator.step`` must be made here too: ``tests/test_diagnose_sampled_twin.py`` runs the
    relay with :data:`_INLINE_TICK` off and requires the same bits."""
    if beta_up != beta_dn:
        raise ValueError("the sampled relay takes one beta")
    T, tau = stepper.prop.T, stepper.plant.tau
    rng = np.random.default_rng(relay.seed)
    # the log's relay decides with one (nominal) level: the MRFT rule, in the loop's state
    rule = MrftRelay(beta_up)
    rule.relay, rule.e_ext, rule.first_half = loop.relay, loop.e_ext, False
    jitter = relay.jitter_std > 0
    jit_eff = _jitter_delays(rng, relay, tau, T, max_steps).tolist() if jitter else [0.0]
    n_jit = len(jit_eff)
    noisy, std, i_noise = relay.noise_std > 0, relay.noise_std, 0
    noise: list[float] = []
    # the whole tick's propagator, inline: linear plants only (quadratic drag and the rotor integrate)
    inline = _INLINE_TICK and not (stepper.quad or stepper.rotor_plant is not None)
    P, G0, G1 = stepper.prop.tick
    n3, lag, bias = stepper.n == 3, stepper.lag, stepper.plant.input_bias
    resting = stepper.plant.rate_limit == 0
    max_gap = relay.max_gap
    for k in range(max_steps):
        t_end = (k + 1) * T
        pend = loop.pending
        if (inline and (not pend or pend[0][0] > t_end + _ARRIVAL_TOL) and (resting or loop.act == loop.target)
                and loop.t < t_end - _ARRIVAL_TOL and abs((t_end - loop.t) - T) < 1e-12):
            c0, c1 = loop.act + bias, 0.0
            x: tuple
            if n3:
                x0, x1, x2 = loop.x
                x = (P[0] * x0 + P[1] * x1 + P[2] * x2 + G0[0] * c0 + G1[0] * c1,
                     P[3] * x0 + P[4] * x1 + P[5] * x2 + G0[1] * c0 + G1[1] * c1,
                     P[6] * x0 + P[7] * x1 + P[8] * x2 + G0[2] * c0 + G1[2] * c1)
            else:
                x0, x1, x2, x3 = loop.x
                x = (P[0] * x0 + P[1] * x1 + P[2] * x2 + P[3] * x3 + G0[0] * c0 + G1[0] * c1,
                     P[4] * x0 + P[5] * x1 + P[6] * x2 + P[7] * x3 + G0[1] * c0 + G1[1] * c1,
                     P[8] * x0 + P[9] * x1 + P[10] * x2 + P[11] * x3 + G0[2] * c0 + G1[2] * c1,
                     P[12] * x0 + P[13] * x1 + P[14] * x2 + P[15] * x3 + G0[3] * c0 + G1[3] * c1)
            loop.x, loop.t = x, t_end
            y_m = x[-1] if lag else x[0]  # (the lag state is the last of four)
        else:
            y_m = _tick(loop, stepper, k, T)
        ys.append(y_m)
        if not math.isfinite(y_m) or abs(y_m) > 1e9:
            break
        if noisy:
            if i_noise == len(noise):
                noise, i_noise = rng.normal(0.0, std, _NOISE_BLOCK).tolist(), 0
            e = -(y_m + noise[i_noise])
            i_noise += 1
        else:
            e = -y_m
        new = rule.step(e)
        if new != loop.relay:
            _sampled_switch(loop, new, tau + (jit_eff[min(k + 1, n_jit - 1)] if jitter else 0.0), h)
            if new > 0 and len(loop.up) >= n_cycles:
                break
        elif max_gap is not None and loop.t - loop.t_last_switch > max_gap:
            break


def periodic_cycle(
    plant: AugmentedPlant,
    beta: float | tuple[float, float],
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
