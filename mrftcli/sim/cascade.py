"""Cascaded flights: an outer MRFT (x or y) through the closed inner attitude loop, with known truth.

One flight holds the inner loop's own MRFT tests first (the attitude PD replaced by the relay on
the inner command), then the outer loop's (the relay on the outer command, the inner PD closing the
attitude loop), as a vehicle is identified from take-off. Between tests a position hold (a PID on
the position, :func:`outer_hold_gains`) and the inner PD keep the vehicle in place.

At each controller tick t_k (one rate for both loops, :attr:`InnerGains.rate_hz`):

1. measure the attitude alpha(t_k) and the position y(t_k - tau) (plus white noise);
2. the outer command c_k: the outer relay (outer tests) or the position hold;
   the attitude setpoint alpha_ref = c_k (commanded attitude) or c_k / g (commanded acceleration);
3. the inner command u_k: the inner relay (inner tests, on the error 0 - alpha) or the inner PD
   (derivative on the measured attitude, first-order filter Tf, backward differences);
4. u_k is held for one period and reaches the plant tau_inner later.

The plant between ticks is propagated exactly (:mod:`mrftcli.sim.cascade_plant`). Conventions and
the truth record: :mod:`mrftcli.sim.cascade_spec`; writing the logs: :mod:`mrftcli.sim.cascade_write`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..mrft.model import LoopModel
from .cascade_plant import CascadePlant, cascade_plant, closed_loop_radius, outer_plant_response
from .cascade_spec import CascadeSpec, CascadeTestTruth, CascadeTruth, InnerGains
from .control import HearMrftRelay, MrftRelay, RelayTests, df_prediction, make_relay
from .spec import TestSpec

__all__ = ["CascadeFlight", "simulate_cascade", "outer_hold_gains", "inner_pd",
           "command_gain", "outer_describing_function", "plan_outer_test"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class CascadeFlight:
    """A simulated cascaded flight at the controller rate, in the output's direction (see
    :mod:`mrftcli.sim.cascade_spec`; the pitch loop's logged angle and command are the negatives).

    Attributes
    ----------
    spec : CascadeSpec
    truth : CascadeTruth
    t : ndarray
        Tick times (log time) [s].
    inner_command : ndarray
        u_k [inner command units].
    outer_command : ndarray
        c_k [rad or m/s^2].
    attitude_setpoint : ndarray
        alpha_ref [rad] (0 during the inner tests).
    attitude_true, attitude_measured : ndarray
        alpha(t_k) and what the controller saw [rad].
    position_true, position_measured : ndarray
        y(t_k) and the delayed, noisy measurement [m].
    other_attitude : ndarray
        The other attitude axis (noise only) [rad].
    """

    spec: CascadeSpec
    truth: CascadeTruth
    t: Array
    inner_command: Array
    outer_command: Array
    attitude_setpoint: Array
    attitude_true: Array
    attitude_measured: Array
    position_true: Array
    position_measured: Array
    other_attitude: Array


def command_gain(commanded: str, g: float) -> float:
    """alpha_ref per unit outer command: 1 (attitude [rad]) or 1/g (acceleration [m/s^2])."""
    return 1.0 if commanded == "attitude" else 1.0 / g


def inner_pd(inner: LoopModel, rate_hz: float, phase_margin_deg: float = 40.0, derivative_time: float = 0.3,
             filter_ratio: float = 10.0) -> InnerGains:
    """A PD for the attitude plant with a given phase margin (continuous design, half a tick of hold).

    C(s) = Kp (1 + Td_c s / (Tf s + 1)), Tf = Td_c / ``filter_ratio``; the crossover is the highest
    frequency where arg C G = -180 deg + ``phase_margin_deg`` (at least 3 / Td of the plant: on the
    derivative's lead), and Kp puts |C G| = 1 there.

    Parameters
    ----------
    inner : LoopModel
        The attitude plant.
    rate_hz : float
        Controller rate [Hz].
    phase_margin_deg : float
        Design phase margin [deg].
    derivative_time : float
        Td_c = Kd / Kp [s].
    filter_ratio : float
        Td_c / Tf.

    Raises
    ------
    InputError
        No crossover reaches that margin with this derivative time.
    """
    td_c = float(derivative_time)
    tf = td_c / filter_ratio
    omega = np.geomspace(0.05, 0.95 * math.pi * rate_hz, 4000)
    g = inner.frequency_response(omega) * np.exp(-0.5j * omega / rate_hz)
    c = 1.0 + td_c * 1j * omega / (tf * 1j * omega + 1.0)
    phase = np.unwrap(np.angle(g * c))
    # the crossover sits on the derivative's lead, well beyond the drag corner 1/Td: below it the loop
    # would be a slow one that never uses the derivative, not a vehicle's attitude loop
    lead = omega >= 3.0 / inner.Td
    above = np.flatnonzero(lead & (phase >= -math.pi + math.radians(phase_margin_deg)))
    if above.size == 0:
        raise InputError(f"no PD with derivative time {td_c:g} s reaches a {phase_margin_deg:g} deg phase margin "
                         f"on this plant; use a longer derivative time or a smaller margin")
    i = int(above[-1])
    kp = 1.0 / float(np.abs(g[i] * c[i]))
    return InnerGains(kp, 0.0, kp * td_c, tf, rate_hz)


def outer_describing_function(plant: CascadePlant, gains: InnerGains, command_gain: float, beta: float,
                              ) -> tuple[float, float]:
    """The describing function's outer cycle on the exact discrete G_outer (planning only).

    Omega where arg G_outer(e^{j Omega T}) = -pi + asin(beta), and |G_outer| there.

    Returns
    -------
    omega : float
        Frequency [rad/s].
    gain : float
        |G_outer(e^{j Omega T})| [m per outer command unit]; the amplitude is 4 h gain / pi.
    """
    omega = np.geomspace(1e-2, 0.99 * math.pi / plant.T, 2000)
    response = outer_plant_response(plant, gains, command_gain, omega)
    phase = np.unwrap(np.angle(response))
    below = np.flatnonzero(phase <= -math.pi + math.asin(beta))
    if below.size == 0:
        raise InputError("the cascade's phase never reaches the MRFT's; check the outer Td and tau")
    i = int(below[0])
    return float(omega[i]), float(abs(response[i]))


def plan_outer_test(plant: CascadePlant, gains: InnerGains, command_gain: float, beta: float, amplitude: float,
                    cycles: float = 14.0, min_duration: float = 8.0) -> TestSpec:
    """An outer :class:`TestSpec` whose describing-function amplitude is ``amplitude`` [m].

    The duration covers ``cycles`` predicted periods plus 2 s, and at least ``min_duration`` [s].
    """
    if not amplitude > 0:
        raise InputError(f"the planned amplitude must be positive, got {amplitude!r}")
    omega, gain = outer_describing_function(plant, gains, command_gain, beta)
    duration = max(min_duration, cycles * 2.0 * math.pi / omega + 2.0)
    return TestSpec(beta=beta, h=float(amplitude * math.pi / (4.0 * gain)), duration=float(round(duration, 1)))


def outer_hold_gains(spec: CascadeSpec, phase_margin_deg: float = 60.0) -> InnerGains:
    """The position hold between tests (position error -> outer command), designed on the exact cascade.

    A PID in the hold's fixed shape (derivative time 2 / omega_c, filter N = 10, integral time
    10 / omega_c) whose crossover omega_c is the highest frequency where arg C G_outer reaches
    -180 deg + ``phase_margin_deg`` on the exact discrete G_outer; |C G_outer| = 1 there. Its gains
    are halved until the exact closed loop (:func:`closed_loop_radius`) is stable.
    """
    plant = cascade_plant(spec.inner, spec.Td, spec.tau, spec.rate_hz, spec.g)
    conv = command_gain(spec.commanded, spec.g)
    omega = np.geomspace(1e-2, 0.99 * math.pi / plant.T, 1500)
    g = outer_plant_response(plant, spec.gains, conv, omega)
    a, n_filter, ti = 2.0, 10.0, 10.0
    c_norm = 1.0 + 1.0 / (ti * 1j) + a * 1j / (a / n_filter * 1j + 1.0)  # C / Kp at omega = omega_c (scale-free)
    phase = np.unwrap(np.angle(g)) + math.atan2(c_norm.imag, c_norm.real)
    above = np.flatnonzero(phase >= -math.pi + math.radians(phase_margin_deg))
    if above.size == 0:
        raise InputError("no position hold reaches its phase margin on this cascade; check the outer Td, tau and "
                         "the inner gains")
    i = int(above[-1])
    w_c = float(omega[i])
    kp = 1.0 / float(abs(g[i]) * abs(c_norm))
    scale = 1.0
    for _ in range(8):
        hold = InnerGains(kp * scale, kp * scale * w_c / ti, kp * scale * a / w_c, a / w_c / n_filter, spec.rate_hz)
        if closed_loop_radius(plant, spec.gains, hold, conv) < 1.0:
            return hold
        scale *= 0.5
    raise InputError("no stable position hold found for this cascade; check the outer Td, tau and the inner gains")


@dataclass(frozen=True)
class _Schedule:
    """The tests in flight order: loop kind ("inner"/"outer"), tick ranges, relays, abort limits."""

    kinds: tuple[str, ...]
    ranges: tuple[tuple[int, int], ...]
    n_ticks: int
    limits: tuple[float, ...]


def _schedule(spec: CascadeSpec, plant: CascadePlant, noise: tuple[float, float]) -> _Schedule:
    """The tests in flight order; each aborts beyond 10 x its describing-function amplitude (>= 50 noise std)."""
    rate = spec.rate_hz
    k = int(round(spec.hover_s * rate))
    kinds, ranges, limits = [], [], []
    conv = command_gain(spec.commanded, spec.g)
    for kind, tests, std in (("inner", spec.inner_tests, noise[0]), ("outer", spec.outer_tests, noise[1])):
        for test in tests:
            n = int(round(test.duration * rate))
            if n < 2:
                raise InputError(f"a test must cover at least two controller periods, got {test.duration!r} s")
            kinds.append(kind)
            ranges.append((k, k + n))
            if kind == "inner":
                amplitude = df_prediction(spec.inner, test.beta, test.h, rate)[1]
            else:
                amplitude = 4.0 * test.h * outer_describing_function(plant, spec.gains, conv, test.beta)[1] / math.pi
            limits.append(max(10.0 * amplitude, 50.0 * std))
            k += n + int(round(spec.hold_s * rate))
    return _Schedule(tuple(kinds), tuple(ranges), k, tuple(limits))


class _CascadeController:
    """Both loops' controllers, tick by tick: relays during tests, the inner PD and the position hold."""

    def __init__(self, spec: CascadeSpec, schedule: _Schedule, hold: InnerGains, noise: tuple[float, float]):
        self.T = 1.0 / spec.rate_hz
        self.inner, self.hold = spec.gains, hold
        self.conv = command_gain(spec.commanded, spec.g)
        self.schedule = schedule
        self.tests = (*spec.inner_tests, *spec.outer_tests)
        thresholds = {"inner": 10.0 * noise[0], "outer": 10.0 * noise[1]}
        relays: list[MrftRelay | HearMrftRelay] = [
            make_relay(t.beta, spec.switching, thresholds[kind], 5, 0.02 * spec.rate_hz)
            for t, kind in zip(self.tests, schedule.kinds)]
        # a flight stack's safety net, counted from where each test started (the vehicle may have drifted
        # during the previous test and first travel back): the hold takes over for the rest of the test
        self.running = RelayTests(self.tests, relays, schedule.ranges, schedule.limits, schedule.n_ticks,
                                  from_start=True)
        self.aborted, self.mode = self.running.aborted, self.running.mode
        self.d_in = self.i_in = self.d_out = self.i_out = 0.0
        self.a_prev = self.y_prev = 0.0

    def step(self, k: int, alpha_m: float, y_m: float) -> tuple[float, float, float]:
        """(u, c, alpha_ref) of tick ``k`` for the measured attitude [rad] and position [m]."""
        T, hold, inner = self.T, self.hold, self.inner
        j = int(self.mode[k])
        kind = self.schedule.kinds[j] if j >= 0 else "hold"
        e_o = -y_m
        self.d_out = (hold.Tf * self.d_out - hold.Kd * (y_m - self.y_prev)) / (hold.Tf + T)
        self.y_prev = y_m
        c = self.running.command(j, k, e_o) if kind == "outer" else math.nan
        if math.isnan(c):
            if kind == "hold" or self.mode[k] < 0:
                self.i_out += hold.Ki * T * e_o  # the integrators are frozen during tests
            c = hold.Kp * e_o + self.i_out + self.d_out
        alpha_ref = self.conv * c
        self.d_in = (inner.Tf * self.d_in - inner.Kd * (alpha_m - self.a_prev)) / (inner.Tf + T)
        self.a_prev = alpha_m
        u = self.running.command(j, k, -alpha_m) if kind == "inner" else math.nan
        if kind == "inner" and not math.isnan(u):
            return u, c, 0.0
        e_i = alpha_ref - alpha_m
        if self.mode[k] < 0:
            self.i_in += inner.Ki * T * e_i
        return inner.Kp * e_i + self.i_in + self.d_in, c, alpha_ref


@dataclass(frozen=True)
class _Draws:
    attitude: Array
    position: Array
    other: Array


def _fly(plant: CascadePlant, controller: _CascadeController, draws: _Draws, n_ticks: int) -> dict[str, Array]:
    """The tick loop: measure, control, propagate the period piece by piece (exact)."""
    rec = {name: np.empty(n_ticks) for name in ("u", "c", "ref", "alpha", "alpha_m", "y", "y_m")}
    x = np.zeros(5)
    line: deque[float] = deque([0.0] * (plant.m_in + 2), maxlen=plant.m_in + 2)
    samples: deque[float] = deque([0.0] * max(plant.n_y, 1), maxlen=max(plant.n_y, 1))
    for k in range(n_ticks):
        y_meas = (samples[0] if plant.n_y > 0 else float(x[3])) + draws.position[k]
        alpha_m = float(x[0]) + draws.attitude[k]
        u, c, ref = controller.step(k, alpha_m, y_meas)
        for name, value in (("u", u), ("c", c), ("ref", ref), ("alpha", x[0]), ("alpha_m", alpha_m), ("y", x[3]),
                            ("y_m", y_meas)):
            rec[name][k] = value
        line.append(u)
        ua, ub = line[0], line[1]
        for seg in plant.segments:
            if seg.sample_y_before and plant.n_y > 0:
                samples.append(float(x[3]))
            x = seg.Phi @ x + seg.Gamma * (ub if seg.newer else ua)
    return rec


def simulate_cascade(spec: CascadeSpec) -> CascadeFlight:
    """Fly a cascaded flight: hover, the inner tests, the outer tests, each followed by a hold.

    Raises
    ------
    InputError
        The inner gains do not stabilise the attitude plant, or no stable position hold exists.
    """
    from .._version import __version__

    plant = cascade_plant(spec.inner, spec.Td, spec.tau, spec.rate_hz, spec.g)
    radius = closed_loop_radius(plant, spec.gains)
    if radius >= 1.0:
        raise InputError(f"the inner gains do not stabilise the {spec.inner_loop} plant (closed-loop spectral "
                         f"radius {radius:.3f} >= 1); use smaller gains")
    noise = spec.noise()
    schedule = _schedule(spec, plant, noise)
    hold = outer_hold_gains(spec)
    controller = _CascadeController(spec, schedule, hold, noise)
    rng = np.random.default_rng(spec.seed)
    n = schedule.n_ticks
    draws = _Draws(rng.normal(0.0, noise[0], n) if noise[0] > 0 else np.zeros(n),
                   rng.normal(0.0, noise[1], n) if noise[1] > 0 else np.zeros(n),
                   rng.normal(0.0, noise[0], n) if noise[0] > 0 else np.zeros(n))
    rec = _fly(plant, controller, draws, n)
    T = plant.T
    loops = {"inner": spec.inner_loop, "outer": spec.axis}
    tests = tuple(
        CascadeTestTruth(loops[kind], test.beta, test.h, spec.start_time + k0 * T,
                         spec.start_time + (k1 if k_abort is None else k_abort) * T, k_abort is not None)
        for test, kind, (k0, k1), k_abort in zip(controller.tests, schedule.kinds, schedule.ranges,
                                                  controller.aborted))
    truth = CascadeTruth(
        axis=spec.axis, inner_loop=spec.inner_loop, commanded=spec.commanded, K=spec.K, Td=spec.Td, tau=spec.tau,
        g=spec.g, inner=spec.inner, gains=spec.gains, outer_hold=hold, attitude_noise_std=noise[0],
        position_noise_std=noise[1], switching=spec.switching, seed=spec.seed, start_time=spec.start_time,
        duration=n * T, tests=tests, mrftcli_version=__version__)
    t: Array = spec.start_time + np.arange(n, dtype=float) * T
    return CascadeFlight(spec, truth, t, rec["u"], rec["c"], rec["ref"],
                         rec["alpha"], rec["alpha_m"], rec["y"], rec["y_m"], draws.other)
