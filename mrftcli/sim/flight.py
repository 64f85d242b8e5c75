"""Closed-loop MRFT flight simulator on a model object: the paper's eq. (2), a process family, a declared plant.

What is simulated
-----------------
The plant is the model's delay-free realisation (:meth:`~mrftcli.mrft.model.PlantModel.realisation`,
y = C x) behind its transport delay; for eq. (2), G(s) = K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1)) with
the states output y, rate y', propulsion state. Eq. (2) flies about the loop's trim (hover command,
setpoint), the other families about their operating point, the origin (:mod:`mrftcli.sim.spec`). A digital
controller runs at ``rate_hz``: at every tick t_k = k / rate_hz it samples the measured output
(true output, optionally through an extra first-order sensor lag, plus Gaussian noise), computes a
command and holds it until the next tick (zero-order hold). The command reaches the plant ``tau``
seconds later (transport delay). The plant input is

    w(t) = g(t) * a(t) - bias + input_bias,         g(t) = 1 + gain_drift * (t - t_0),

where ``a(t)`` is the actuator: the delayed command u(t - tau), or its rate-limited follower when
``actuator_rate_limit`` is set, and ``bias`` the nominal hover command. At the nominal bias and without
effects the model is in equilibrium (w = 0); the battery gain g(t) multiplies the whole command, bias
included, so a sagging battery also shifts the hover trim of the altitude loop (the attitude loops have
bias 0, so there it is a pure gain change).

The flight: ``hover_s`` of hold, then for each :class:`TestSpec` an MRFT of ``duration`` seconds
followed by ``hold_s`` of hold. During holds a PID designed on the model's frequency response (:func:`design_hold_pid`)
keeps the setpoint; during tests the MRFT switching rule (checks.md section 2, docs/architecture.md;
:class:`MrftRelay`) on the sampled noisy error produces command = bias +/- h. A test keeps the sign
of its first error until the error is ``start_threshold`` beyond zero on the other side, and is
aborted (hold again) if the error exceeds ``abort_error``, as a flight stack's safety limit would.
``switching="hear"`` uses the HEAR flight stack's block with its anti-false-switching instead
(:class:`HearMrftRelay`). docs/simulator.md has the details, the effects and the sidecar format.

Integration is exact for the linear plant: between events (command changes reaching the plant,
rate-limiter kinks) the input is a polynomial of degree <= 2 in time and the state is propagated with
the matrix exponential of an augmented system; fractional delays are handled exactly (no delay
quantisation). Only eq. (2)'s own nonlinear effects (quadratic drag, thrust rectification) need a numerical
integrator (classical RK4, at most T/20 per step, events still handled exactly).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError
from ..io.logtypes import TopicData
from ..mrft.model import LoopModel, PlantModel
from ..progress import Progress, report
from .control import (
    HoldPID,
    RelayTests,
    design_hold_pid,
    df_prediction,
    make_relay,
    noise_margin,
)
from ..mrft.propagate import (LinearPropagator, RotorCoefficients, actuator_pieces, fifo_delays, gauss_markov,
                              rk4_quadratic, rk4_rotor)
from .plant import command_shaper
from .sidecar import flight_topics, sidecar_path, truth_record, write_flight
from .spec import EFFECT_NAMES, Effects, FlightSettings, FlightSpec, TestSpec, default_noise_std, flight_settings

__all__ = [
    "Effects",
    "TestSpec",
    "FlightSpec",
    "SimulatedFlight",
    "simulate_flight",
    "df_prediction",
    "plan_test",
    "noise_margin",
    "default_noise_std",
    "sidecar_path",
    "write_flight",
    "EFFECT_NAMES",
]


@dataclass
class SimulatedFlight:
    """A simulated flight: sampled signals at the controller rate and the ground truth."""

    spec: FlightSpec
    t: np.ndarray
    command: np.ndarray
    output_true: np.ndarray
    output_measured: np.ndarray
    setpoint: np.ndarray
    truth: dict[str, Any]
    topics: list[TopicData]
    #: transport delay [s] of each tick's command when ``delay_jitter`` is on (None: the fixed tau)
    delays: np.ndarray | None = None


# --------------------------------------------------------------------------------------------------
# test planning (describing function, approximate)


def plan_test(
    model: PlantModel,
    beta: float,
    amplitude: float,
    rate_hz: float = 200.0,
    cycles: float = 14.0,
    min_duration: float = 8.0,
) -> TestSpec:
    """A :class:`TestSpec` whose describing-function amplitude is ``amplitude`` [output units].

    The duration covers ``cycles`` predicted periods plus 2 s of transient, and at least
    ``min_duration`` seconds (:func:`df_prediction`, with half a tick of hold at ``rate_hz`` [Hz]).
    """
    if not amplitude > 0:
        raise InputError(f"the planned amplitude must be positive, got {amplitude!r}")
    omega, a1 = df_prediction(model, beta, 1.0, rate_hz)
    h = amplitude / a1
    duration = max(min_duration, cycles * 2.0 * math.pi / omega + 2.0)
    return TestSpec(beta=beta, h=float(h), duration=float(round(duration, 1)))


# --------------------------------------------------------------------------------------------------
# the simulation: stages


@dataclass(frozen=True)
class NoiseDraws:
    """The flight's randomness, drawn up front in a fixed order so a seed defines the whole flight.

    Attributes
    ----------
    sensor : ndarray
        White sensor noise of the output per tick [output units].
    other_axis : ndarray
        Noise of the other attitude axis per tick [rad] (the IMU topic of roll and pitch loops).
    jitter : ndarray
        Standard normal innovations of the delay jitter per tick.
    battery : ndarray
        Battery voltage noise per tick [V] (only the published samples are used).
    """

    sensor: np.ndarray
    other_axis: np.ndarray
    jitter: np.ndarray
    battery: np.ndarray


def _draw_noise(seed: int, settings: FlightSettings) -> NoiseDraws:
    rng = np.random.default_rng(seed)
    n, std = settings.n_ticks, settings.noise_std
    sensor = rng.normal(0.0, std, n) if std > 0 else np.zeros(n)
    other_axis = rng.normal(0.0, std, n) if std > 0 else np.zeros(n)
    jitter = rng.standard_normal(n)
    battery = rng.normal(0.0, 0.01, n)
    return NoiseDraws(sensor, other_axis, jitter, battery)


def _command_delays(spec: FlightSpec, settings: FlightSettings, jitter: np.ndarray) -> np.ndarray | None:
    """The transport delay of each tick's command [s] with delay jitter (None without): tau plus a
    Gauss-Markov process at the controller rate; a command never overtakes an older one."""
    eff = spec.effects
    if not eff.delay_jitter > 0:
        return None
    T = settings.T
    phi = math.exp(-T / eff.delay_jitter_correlation)
    innov = eff.delay_jitter * math.sqrt(1.0 - phi * phi) * jitter
    innov[0] = eff.delay_jitter * jitter[0]  # stationary start
    delays: np.ndarray = fifo_delays(gauss_markov(innov, phi), spec.model.delay, T)
    return delays


@dataclass(frozen=True)
class PlantSetup:
    """The linear part of the plant, in the model's realisation with the output as its first state.

    Attributes
    ----------
    A, B : ndarray
        State matrix and input vector (the sensor-lag and flex-mode states appended when on).
    meas_index : int
        The state the sensor measures (the output, or its lagged / flexed version).
    x0 : ndarray
        The trimmed hover at the setpoint (the origin for a family other than eq. (2)).
    """

    A: np.ndarray
    B: np.ndarray
    meas_index: int
    x0: np.ndarray

    @property
    def n(self) -> int:
        """Number of states."""
        return int(self.A.shape[0])


def output_first(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) in coordinates whose first state is the output y = C x (eq. (2)'s realisation already is).

    z = S x with S's first row C and the others unit rows (all but the largest entry of C's), so the
    tick loops read y as z[0] whatever the family's realisation.
    """
    if C[0] == 1.0 and not C[1:].any():
        return A, B
    j = int(np.argmax(np.abs(C)))
    S = np.eye(C.size)[[j] + [i for i in range(C.size) if i != j]]
    S[0] = C
    return S @ A @ np.linalg.inv(S), S @ B


def _plant(spec: FlightSpec, r: float) -> PlantSetup:
    """The plant's state space with the sensor lag (one state) and the flex mode (two) appended.

    The trimmed state has the output at the setpoint ``r``, at rest (eq. (2)'s output is integrating;
    the other families fly at r = 0, checked by the spec).
    """
    eff = spec.effects
    ss = spec.model.realisation()
    A, B = output_first(ss.A, ss.B, np.asarray(ss.C, dtype=float))
    n = n0 = A.shape[0]
    if eff.sensor_lag > 0:
        A = np.pad(A, ((0, 1), (0, 1)))
        A[n, 0] = 1.0 / eff.sensor_lag
        A[n, n] = -1.0 / eff.sensor_lag
        B = np.append(B, 0.0)
        n += 1
    meas_index = n0 if eff.sensor_lag > 0 else 0
    if eff.flex_mode_hz > 0:
        # a structural mode between the (possibly lagged) output and the sensor: two more states
        wn = 2.0 * math.pi * eff.flex_mode_hz
        A = np.pad(A, ((0, 2), (0, 2)))
        A[n, n + 1] = 1.0
        A[n + 1, meas_index] = wn * wn
        A[n + 1, n] = -wn * wn
        A[n + 1, n + 1] = -2.0 * eff.flex_mode_damping * wn
        B = np.append(B, [0.0, 0.0])
        meas_index = n
        n += 2
    x = np.zeros(n)
    x[0] = r
    if eff.sensor_lag > 0:
        x[n0] = r
    if eff.flex_mode_hz > 0:
        x[meas_index] = r
    return PlantSetup(A, B, meas_index, x)


def _abort_limits(spec: FlightSpec, noise_std: float) -> list[float]:
    """Per test, the |error| a flight stack's safety net aborts it at [output units]: ``abort_error``,
    else 10 x the describing-function amplitude (at least 50 noise std)."""
    if spec.abort_error is not None:
        return [float(spec.abort_error)] * len(spec.tests)
    return [max(10.0 * df_prediction(spec.model, t.beta, t.h, spec.rate_hz)[1], 50.0 * noise_std) for t in spec.tests]


class _Controller:
    """The flight's controller, tick by tick: the hold PID between tests (and after a safety abort),
    the MRFT relay during them (checks.md section 2, or HEAR's; :class:`~mrftcli.sim.control.RelayTests`)."""

    def __init__(self, spec: FlightSpec, settings: FlightSettings, pid: HoldPID, abort_limits: Sequence[float]):
        T = settings.T
        self.r, self.bias, self.T, self.pid = settings.setpoint, settings.bias, T, pid
        self.integ = -spec.effects.input_bias  # the log starts in trimmed hover: the integrator holds the trim error
        self.dterm = 0.0
        self.y_prev = settings.setpoint
        self.a_d = pid.Tf / (pid.Tf + T)
        self.b_d = pid.Kd / (pid.Tf + T)
        start_threshold = 10.0 * settings.noise_std if spec.start_threshold is None else float(spec.start_threshold)
        relays = [make_relay(t.beta, spec.switching, start_threshold, spec.confirm_samples,
                             spec.no_switch_delay * spec.rate_hz, t.eps) for t in spec.tests]
        # a real flight stack's safety abort (e.g. the relay got stuck after a noise-triggered switch and the
        # output runs away): the hold controller takes over for the rest of the test
        self.running = RelayTests(spec.tests, relays, settings.ranges, abort_limits, settings.n_ticks)
        self.aborted = self.running.aborted

    def step(self, k: int, ym: float) -> float:
        """The command of tick ``k`` for the measured output ``ym`` [command units]."""
        e = self.r - ym
        j = int(self.running.mode[k])
        relay = self.running.command(j, k, e) if j >= 0 else math.nan  # +-h; NaN: no test, or just aborted
        if math.isnan(relay):
            # PID hold (derivative on the measurement; the integrator is frozen during tests)
            self.dterm = self.a_d * self.dterm - self.b_d * (ym - self.y_prev)
            self.integ += self.pid.Ki * self.T * e
            u = self.bias + self.pid.Kp * e + self.integ + self.dterm
        else:
            # MRFT, checks.md section 2: extremum of the sampled error since the last switch
            u = self.bias + relay
            self.dterm = self.a_d * self.dterm - self.b_d * (ym - self.y_prev)  # keep the filter current: no kick on return
        self.y_prev = ym
        return u


@dataclass(frozen=True)
class Drive:
    """What reaches the plant: the actuator and the delay line, and the input's affine form.

    The plant input is ``w(t) = (1 + gain_drift t) a(t) - bias + input_bias``, ``a(t)`` the
    actuator (the delayed, shaped command, rate-limited when ``rate_limit`` > 0).

    Attributes
    ----------
    T : float
        Controller period [s].
    bias, input_bias, gain_drift, rate_limit : float
        The trim [command units], the input bias [command units], the gain drift [1/s] and the
        actuator's slew limit [command units / s] (0: none).
    shaper : callable or None
        What the actuator makes of a command (asymmetric gain, saturation, dead zone); None: itself.
    u_plant : float
        The actuator value of the trimmed hover at t = 0 [command units].
    m_delay : int
        Whole controller periods in the delay tau.
    frac : float
        The rest of tau [s] (0 when tau is a whole number of periods).
    """

    T: float
    bias: float
    input_bias: float
    gain_drift: float
    rate_limit: float
    shaper: Callable[[float], float] | None
    u_plant: float
    m_delay: int
    frac: float


def _drive(spec: FlightSpec, settings: FlightSettings) -> Drive:
    eff, T, bias = spec.effects, settings.T, settings.bias
    shaper = command_shaper(bias, eff.asymmetric_gain, eff.actuator_saturation, eff.dead_zone)
    u_init = bias - eff.input_bias  # the command that keeps the trimmed hover at t = 0
    m_delay = int(math.floor(spec.model.delay / T + 1e-12))
    frac = spec.model.delay - m_delay * T
    if frac < 1e-12 * T:
        frac = 0.0
    return Drive(T, bias, eff.input_bias, eff.gain_drift, eff.actuator_rate_limit, shaper,
                 u_init if shaper is None else shaper(u_init), m_delay, frac)


@dataclass(frozen=True)
class TickRecords:
    """Per controller tick: the command [command units], the true and measured output [output units]
    and eq. (2)'s true output rate [output units / s] (its second state; the quadratic drag's truth)."""

    command: np.ndarray
    y_true: np.ndarray
    y_meas: np.ndarray
    rate_true: np.ndarray

    @classmethod
    def empty(cls, n_ticks: int) -> TickRecords:
        return cls(np.empty(n_ticks), np.empty(n_ticks), np.empty(n_ticks), np.empty(n_ticks))


def _progress_every(progress: Progress | None, n_ticks: int) -> Callable[[int], None] | None:
    """A per-tick callback that reports about 100 times (None without progress)."""
    if progress is None:
        return None
    every = max(1, n_ticks // 100)

    def tick(k: int) -> None:
        if k % every == 0:
            progress(k, n_ticks, "simulating")

    return tick


def simulate_flight(
    spec: FlightSpec,
    progress: Progress | None = None,
) -> SimulatedFlight:
    """Simulate one closed-loop MRFT flight (see the module docstring for the model).

    Parameters
    ----------
    spec : FlightSpec
        The model, the tests and the flight settings. Not modified.
    progress : Progress, optional
        Called as ``progress(done, total, "simulating")`` (controller ticks) about 100 times
        (:mod:`mrftcli.progress`).

    Returns
    -------
    SimulatedFlight
        Signals sampled at the controller ticks, the ground truth (the sidecar contents) and the
        topics in the reference layout.

    Raises
    ------
    InputError
        A parameter is out of range (beta outside (-1, 1), h <= 0, negative effect, ...).
    """
    settings = flight_settings(spec)
    n_ticks, T = settings.n_ticks, settings.T
    pid = design_hold_pid(spec.model, spec.rate_hz)
    draws = _draw_noise(spec.seed, settings)
    delays = _command_delays(spec, settings, draws.jitter)
    plant = _plant(spec, settings.setpoint)
    drive = _drive(spec, settings)
    abort_limits = _abort_limits(spec, settings.noise_std)
    controller = _Controller(spec, settings, pid, abort_limits)
    ticks = TickRecords.empty(n_ticks)
    prop = LinearPropagator(plant.A, plant.B, grid=T / 64.0)
    if drive.frac > 0:
        prop.fix(drive.frac)
        prop.fix(T - drive.frac)
    else:
        prop.fix(T)
    on_tick = _progress_every(progress, n_ticks)
    eff = spec.effects
    # Fast path: linear plant, fixed delay, no rate limit -> each period has the same two
    # sub-intervals [0, frac) and [frac, T), so the propagators are precomputed.
    if eff.quadratic_drag == 0 and eff.thrust_rectification == 0 and drive.rate_limit == 0 and delays is None \
            and plant.n <= 4:
        _fly_fixed_delay(_period_map(prop, drive, plant), plant, drive, controller, draws.sensor, ticks, on_tick)
    else:
        _fly_events(spec, plant, prop, drive, controller, draws.sensor, delays, ticks, on_tick)
    report(progress, n_ticks, n_ticks, "simulating")

    t = spec.start_time + np.arange(n_ticks) * T
    return SimulatedFlight(
        spec=spec,
        t=t,
        command=ticks.command,
        output_true=ticks.y_true,
        output_measured=ticks.y_meas,
        setpoint=np.full(n_ticks, settings.setpoint),
        truth=truth_record(spec, settings, pid, ticks.rate_true, delays, controller.aborted, abort_limits),
        topics=flight_topics(spec, settings, t, ticks.command, ticks.y_meas, draws.other_axis, draws.battery),
        delays=delays,
    )


# --------------------------------------------------------------------------------------------------
# the tick loops


@dataclass(frozen=True)
class PeriodMap:
    """One whole period of the linear plant as an affine map on 4 states (padded with zeros):
    ``x+ = P x + qa0 c0a + qa1 c1a + qb0 c0b + qb1 c1b``, ``(c0, c1)`` the input's value and slope on
    [0, frac) and [frac, T). Plain floats: numpy's per-call overhead would dominate for 3-4 states.
    The output is the first of the 4, the measured state (when not the output) the last (:func:`_slots`).
    """

    P: list[list[float]]
    qa0: list[float]
    qa1: list[float]
    qb0: list[float]
    qb1: list[float]


def _period_map(prop: LinearPropagator, drive: Drive, plant: PlantSetup) -> PeriodMap:
    """The :class:`PeriodMap` of the fixed delay's two sub-intervals, from the exact propagators."""
    n, T, frac = plant.n, drive.T, drive.frac
    if frac > 0:
        Pa, Ea0, Ea1, _ = prop.fixed(frac)
        Pb, Eb0, Eb1, _ = prop.fixed(T - frac)
        P, qa0, qa1 = Pb @ Pa, Pb @ Ea0, Pb @ Ea1
    else:
        Pb, Eb0, Eb1, _ = prop.fixed(T)
        P, qa0, qa1 = Pb, np.zeros(n), np.zeros(n)
    slots = _slots(plant)

    def vec(v: np.ndarray) -> list[float]:
        out = np.zeros(4)
        out[slots] = v
        return [float(value) for value in out]

    P4 = np.zeros((4, 4))
    P4[np.ix_(slots, slots)] = P
    return PeriodMap(P4.tolist(), vec(qa0), vec(qa1), vec(Eb0), vec(Eb1))


def _slots(plant: PlantSetup) -> list[int]:
    """Where the fast path keeps each of the plant's (at most 4) states: the output first, a measured
    state that is not the output last, the others in order between (eq. (2): 0, 1, 2 and its lag 3)."""
    free = iter(i for i in range(4) if i != 0 and not (plant.meas_index and i == 3))
    return [0 if i == 0 else 3 if plant.meas_index and i == plant.meas_index else next(free) for i in range(plant.n)]


def _fly_fixed_delay(period_map: PeriodMap, plant: PlantSetup, drive: Drive,
                     controller: _Controller, noise: np.ndarray, ticks: TickRecords,
                     on_tick: Callable[[int], None] | None) -> None:
    """The tick loop of the fast path (the hot loop: one affine map per period on plain floats)."""
    (p00, p01, p02, p03), (p10, p11, p12, p13), (p20, p21, p22, p23), (p30, p31, p32, p33) = period_map.P
    a00, a01, a02, a03 = period_map.qa0
    a10, a11, a12, a13 = period_map.qa1
    b00, b01, b02, b03 = period_map.qb0
    b10, b11, b12, b13 = period_map.qb1
    x4 = np.zeros(4)
    x4[_slots(plant)] = plant.x0
    x0, x1, x2, x3 = x4.tolist()
    lagged = plant.meas_index > 0  # the measured state is the 4th (:func:`_slots`)
    T, frac, gd, bias, ib, shaper = drive.T, drive.frac, drive.gain_drift, drive.bias, drive.input_bias, drive.shaper
    # hist = [u_{k-m-1}, ..., u_k]: u_{k-m-1} acts on [t_k, t_k + frac), u_{k-m} on [t_k + frac, t_{k+1})
    hist = deque([drive.u_plant] * (drive.m_delay + 2), maxlen=drive.m_delay + 2)
    command, y_true, y_meas, rate_true = ticks.command, ticks.y_true, ticks.y_meas, ticks.rate_true
    for k in range(command.size):
        tk = k * T
        y_true[k] = x0
        rate_true[k] = x1
        ym = (x3 if lagged else x0) + noise[k]
        y_meas[k] = ym
        u = controller.step(k, ym)
        command[k] = u
        if shaper is not None:
            u = shaper(u)  # what the actuator makes of the command (the log records the command)
        hist.append(u)
        ua, ub = hist[0], hist[1]
        c0a = (1.0 + gd * tk) * ua - bias + ib
        c0b = (1.0 + gd * (tk + frac)) * ub - bias + ib
        c1a, c1b = gd * ua, gd * ub
        x0, x1, x2, x3 = (
            p00 * x0 + p01 * x1 + p02 * x2 + p03 * x3 + a00 * c0a + a10 * c1a + b00 * c0b + b10 * c1b,
            p10 * x0 + p11 * x1 + p12 * x2 + p13 * x3 + a01 * c0a + a11 * c1a + b01 * c0b + b11 * c1b,
            p20 * x0 + p21 * x1 + p22 * x2 + p23 * x3 + a02 * c0a + a12 * c1a + b02 * c0b + b12 * c1b,
            p30 * x0 + p31 * x1 + p32 * x2 + p33 * x3 + a03 * c0a + a13 * c1a + b03 * c0b + b13 * c1b,
        )
        if on_tick is not None:
            on_tick(k)


def _piece_propagator(spec: FlightSpec, prop: LinearPropagator, drive: Drive,
                      ) -> Callable[[np.ndarray, float, float, float, float], np.ndarray]:
    """``propagate(x, h, ts, a0, slope)``: x over [ts, ts + h) with the actuator a0 + slope * s
    (exact for the linear plant; RK4 at most T/20 per step for quadratic drag and the rotor)."""
    eff, model = spec.effects, spec.model
    gd, bias, ib = drive.gain_drift, drive.bias, drive.input_bias
    quadratic, rotor = eff.quadratic_drag > 0, eff.thrust_rectification > 0
    if not (quadratic or rotor):
        return lambda x, h, ts, a0, slope: prop.step(x, h, (1.0 + gd * ts) * a0 - bias + ib,
                                                     (1.0 + gd * ts) * slope + gd * a0, 2.0 * gd * slope)
    assert isinstance(model, LoopModel)  # eq. (2)'s own effects (checked by the spec)
    K, c_drag = model.K, eff.quadratic_drag
    inv_tp = 1.0 / model.Tp
    inv_ts = 1.0 / eff.sensor_lag if eff.sensor_lag > 0 else 0.0
    rk4_step = drive.T / 20.0
    # the rotor's coefficients once per flight (propagate runs per actuator piece)
    rotor_plant = RotorCoefficients(K, 0.0 if quadratic else 1.0 / model.Td, c_drag, eff.thrust_rectification,
                                    inv_tp, inv_ts, rk4_step) if rotor else None

    def propagate(x: np.ndarray, h: float, ts: float, a0: float, slope: float) -> np.ndarray:
        g0 = 1.0 + gd * ts
        c0 = g0 * a0 - bias + ib
        c1 = g0 * slope + gd * a0
        c2 = 2.0 * gd * slope
        if rotor_plant is not None:
            out: np.ndarray = rk4_rotor(x, h, c0, c1, c2, rotor_plant)
            return out
        out = rk4_quadratic(x, h, c0, c1, c2, K, c_drag, inv_tp, inv_ts, rk4_step)
        return out

    return propagate


def _fly_events(spec: FlightSpec, plant: PlantSetup, prop: LinearPropagator, drive: Drive, controller: _Controller,
                noise: np.ndarray, delays: np.ndarray | None, ticks: TickRecords,
                on_tick: Callable[[int], None] | None) -> None:
    """The tick loop of the event path: the actuator's pieces between events (delayed commands
    arriving, rate-limiter kinks), each propagated exactly (or by RK4 for the nonlinear plants).
    """
    T, frac, m_delay = drive.T, drive.frac, drive.m_delay
    propagate = _piece_propagator(spec, prop, drive)
    x = plant.x0.copy()
    rate_index = min(1, plant.n - 1)  # eq. (2)'s y' (a first-order family has no second state)
    act = target = drive.u_plant  # the actuator value a(t) now, and the delayed command reaching it
    pending: deque[tuple[float, float]] = deque()  # (application time from start, command)
    for k in range(ticks.command.size):
        tk = k * T
        ticks.y_true[k] = x[0]
        ticks.rate_true[k] = x[rate_index]
        ym = float(x[plant.meas_index]) + noise[k]
        ticks.y_meas[k] = ym
        u = controller.step(k, ym)
        ticks.command[k] = u
        if drive.shaper is not None:
            u = drive.shaper(u)  # what the actuator makes of the command (the log records the command)
        if delays is None:
            pending.append(((k + m_delay) * T + frac, u))  # exact grid offsets, no drift
        else:
            pending.append((tk + delays[k], u))
        pieces, act, target = actuator_pieces(tk, (k + 1) * T, pending, act, target, drive.rate_limit)
        for s, h, a, slope in pieces:
            x = propagate(x, h, s, a, slope)
        if on_tick is not None:
            on_tick(k)
