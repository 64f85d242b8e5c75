"""Closed-loop MRFT flight simulator on the loop model of the paper, eq. (2).

What is simulated
-----------------
The plant is G(s) = K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1)) in the realisation of
:meth:`mrftcli.mrft.model.LoopModel.state_space` (states: output y, rate y', propulsion state). A digital
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
followed by ``hold_s`` of hold. During holds a PID designed from the model (:func:`design_hold_pid`)
keeps the setpoint; during tests the MRFT switching rule (checks.md section 2, docs/architecture.md;
:class:`MrftRelay`) on the sampled noisy error produces command = bias +/- h. A test keeps the sign
of its first error until the error is ``start_threshold`` beyond zero on the other side, and is
aborted (hold again) if the error exceeds ``abort_error``, as a flight stack's safety limit would.
``switching="hear"`` uses the HEAR flight stack's block with its anti-false-switching instead
(:class:`HearMrftRelay`). docs/simulator.md has the details, the effects and the sidecar format.

Integration is exact for the linear plant: between events (command changes reaching the plant,
rate-limiter kinks) the input is a polynomial of degree <= 2 in time and the state is propagated with
the matrix exponential of an augmented system; fractional delays are handled exactly (no delay
quantisation). Only quadratic drag needs a numerical integrator (classical RK4, at most T/20 per step,
events still handled exactly).
"""

from __future__ import annotations

import json
import math
from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path
import numpy as np

from .control import (
    SWITCHING_RULES,
    HearMrftRelay,
    HoldPID,
    MrftRelay,
    design_hold_pid,
    df_prediction,
    make_relay,
    noise_margin,
    relay_sequence,
)
from .plant import (LinearPropagator, PeriodPropagator, actuator_pieces, command_shaper, fifo_delays, gauss_markov,
                    rk4_quadratic, rk4_rotor)
from ..errors import InputError
from ..io.logtypes import LOOPS, TopicData
from ..mrft.model import LoopModel
from ..progress import Progress, report
from ..validate import check_beta

__all__ = [
    "Effects",
    "TestSpec",
    "FlightSpec",
    "SimulatedFlight",
    "HoldPID",
    "MrftRelay",
    "HearMrftRelay",
    "make_relay",
    "relay_sequence",
    "simulate_flight",
    "design_hold_pid",
    "df_prediction",
    "plan_test",
    "noise_margin",
    "default_noise_std",
    "default_bias",
    "default_setpoint",
    "sidecar_path",
    "write_flight",
    "EFFECT_NAMES",
    "SWITCHING_RULES",
]

#: JSON/CLI names of the effects, in the order of :class:`Effects`.
EFFECT_NAMES = (
    "input_bias",
    "gain_drift",
    "sensor_lag",
    "quadratic_drag",
    "actuator_rate_limit",
    "delay_jitter",
    "asymmetric_gain",
    "actuator_saturation",
    "dead_zone",
    "thrust_rectification",
    "flex_mode_hz",
)

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class Effects:
    """Physics the linear model G(s) leaves out; all default to "absent".

    Attributes
    ----------
    input_bias : float
        Constant disturbance added to the command at the plant input [command units]
        (hover-thrust trim error, CG offset).
    gain_drift : float
        Relative change of the gain K per second [1/s] (battery sag): K(t) = K (1 + gain_drift * t),
        t from the start of the log. It multiplies the whole command (bias included), like a battery
        whose voltage scales the thrust, so the altitude hover trim drifts too. The ``/battery``
        voltage follows V(t) = battery_voltage * (1 + gain_drift * t).
    sensor_lag : float
        Time constant of an extra first-order lag on the measured output [s] (filter/estimator).
    quadratic_drag : float
        Coefficient c of drag proportional to v|v| that replaces the linear drag term
        [1/(output units)]: y'' = -c y'|y'| + K (propulsion state). The spec's Td is then not part
        of the dynamics; the sidecar gives per test the describing-function equivalent
        ``Td_equivalent`` = 3 pi / (8 c V), V the amplitude of y' in the test.
    actuator_rate_limit : float
        Maximum slew rate of the actuator input [command units/s]; 0 means no limit.
    delay_jitter : float
        Standard deviation of a random transport-delay variation [s]. The delay of the command sent
        at tick k is tau + d_k, d_k a first-order Gauss-Markov process sampled at the controller
        rate with correlation time ``delay_jitter_correlation`` (commands never overtake each other).
    delay_jitter_correlation : float
        Correlation time of the delay jitter [s] (default 0.05 s).
    battery_voltage : float
        Battery voltage at the start of the log [V], written to ``/battery`` (default 16.0 V).
    asymmetric_gain : float
        The plant responds with gain K (1 + a) to commands above the trim and K (1 - a) below it
        (thrust ~ rotor speed squared, ESC curves); |a| < 1.
    actuator_saturation : float
        Absolute command at which the actuator saturates [command units] (trim + u is clipped
        there); 0 means no limit.
    dead_zone : float
        Half-width of a band of command deviations around the trim that gives no response
        [command units] (ESC dead band, stiction); beyond it the response starts from zero.
    thrust_rectification : float
        Hover thrust above the zero-thrust command [command units]: the propulsion lag Tp then acts
        on the rotor speed and the thrust goes with its square (``mrftcli.sim.plant.rk4_rotor``);
        0 means the linear propulsion of eq. (2).
    flex_mode_hz : float
        Frequency [Hz] of a lightly damped structural mode between the vehicle and its sensor
        (frame flexibility: y_measured = w_n^2 / (s^2 + 2 zeta w_n s + w_n^2) y); 0 means none.
        Physics outside the diagnosis' library (its ``unexplained`` case).
    flex_mode_damping : float
        Damping ratio zeta of that mode (default 0.05).
    """

    input_bias: float = 0.0
    gain_drift: float = 0.0
    sensor_lag: float = 0.0
    quadratic_drag: float = 0.0
    actuator_rate_limit: float = 0.0
    delay_jitter: float = 0.0
    delay_jitter_correlation: float = 0.05
    battery_voltage: float = 16.0
    asymmetric_gain: float = 0.0
    actuator_saturation: float = 0.0
    dead_zone: float = 0.0
    thrust_rectification: float = 0.0
    flex_mode_hz: float = 0.0
    flex_mode_damping: float = 0.05

    def active(self) -> tuple[str, ...]:
        """Names of the effects that are switched on (non-zero)."""
        return tuple(name for name in EFFECT_NAMES if getattr(self, name) != 0.0)


@dataclass(frozen=True)
class TestSpec:
    """One MRFT test: beta in (-1, 1), relay height h [command units], duration of the relay [s]."""

    beta: float
    h: float
    duration: float = 12.0


@dataclass(frozen=True)
class FlightSpec:
    """Everything that defines one simulated flight."""

    model: LoopModel
    tests: tuple[TestSpec, ...]
    loop: str = "altitude"
    rate_hz: float = 200.0
    noise_std: float | None = None  # output units; None -> 0.5 mm (altitude) / 0.05 deg (roll, pitch)
    bias: float | None = None  # hover command; None -> loop default
    setpoint: float | None = None  # None -> loop default (1 m altitude, 0 rad attitude)
    hover_s: float = 5.0
    hold_s: float = 4.0
    effects: Effects = field(default_factory=Effects)
    seed: int = 0
    start_time: float = 0.0  # log time of the first sample [s] (e.g. a UNIX time)
    setpoint_rate_hz: float = 20.0  # publication rate of /mrft/setpoint [Hz]
    battery_rate_hz: float = 10.0  # publication rate of /battery [Hz]
    # Safety net of a real flight stack: a test whose |error| exceeds this [output units] is aborted
    # and the hold controller takes over. None -> 10 x the describing-function amplitude of the test.
    abort_error: float | None = None
    # MRFT switching rule: "checks" = exactly checks.md section 2 / docs/architecture.md; "hear" = the
    # HEAR flight stack's MRFT block with its anti-false-switching logic (no sign condition on the
    # extremum, a switch only after the extremum is confirmed by ``confirm_samples`` samples without
    # a new one, and no switch within ``no_switch_delay`` seconds of the previous one). "hear" does
    # not lock up when noise triggers a switch, but its confirmation delays switches that come soon
    # after the extremum, so near beta = -1 its limit cycle differs from the exact MRFT one.
    switching: str = "checks"
    # First half-cycle of each test: the relay keeps the sign of the initial error until the error
    # is beyond this level on the other side [output units]. None -> 10 x noise_std.
    start_threshold: float | None = None
    confirm_samples: int = 5
    no_switch_delay: float = 0.02


@dataclass
class SimulatedFlight:
    """A simulated flight: sampled signals at the controller rate and the ground truth."""

    spec: FlightSpec
    t: np.ndarray
    command: np.ndarray
    output_true: np.ndarray
    output_measured: np.ndarray
    setpoint: np.ndarray
    truth: dict
    topics: list[TopicData]
    #: transport delay [s] of each tick's command when ``delay_jitter`` is on (None: the fixed tau)
    delays: np.ndarray | None = None


# --------------------------------------------------------------------------------------------------
# loop defaults


def default_noise_std(loop: str) -> float:
    """Default measurement noise std: 0.5 mm for altitude, x, y [m], 0.05 deg for roll/pitch [rad].

    White noise at the controller rate. 0.05 deg, not the 0.2 deg often quoted for attitude
    estimates: that figure is an accuracy, not sample-to-sample noise, and with 0.2 deg of white
    noise the plain MRFT rule locks up at amplitudes of a few degrees (docs/simulator.md).
    """
    return 0.0005 if loop in ("altitude", "x", "y") else 0.05 * _DEG


def default_bias(loop: str) -> float:
    """Default hover command: 0.5 (normalised throttle) for altitude, 0 for x, y, roll, pitch."""
    return 0.5 if loop == "altitude" else 0.0


def default_setpoint(loop: str) -> float:
    """Default setpoint: 1 m for altitude, 0 for x, y [m] and roll/pitch [rad]."""
    return 1.0 if loop == "altitude" else 0.0


# --------------------------------------------------------------------------------------------------
# test planning (describing function, approximate)


def plan_test(
    model: LoopModel,
    beta: float,
    amplitude: float,
    rate_hz: float = 200.0,
    cycles: float = 14.0,
    min_duration: float = 8.0,
) -> TestSpec:
    """A :class:`TestSpec` whose describing-function amplitude is ``amplitude`` [output units].

    The duration covers ``cycles`` predicted periods plus 2 s of transient, and at least
    ``min_duration`` seconds.
    """
    if not amplitude > 0:
        raise InputError(f"the planned amplitude must be positive, got {amplitude!r}")
    omega, a1 = df_prediction(model, beta, 1.0, rate_hz)
    h = amplitude / a1
    duration = max(min_duration, cycles * 2.0 * math.pi / omega + 2.0)
    return TestSpec(beta=beta, h=float(h), duration=float(round(duration, 1)))


# --------------------------------------------------------------------------------------------------
# validation


def _validate(spec: FlightSpec) -> None:
    if spec.loop not in LOOPS:
        raise InputError(f"unknown loop {spec.loop!r}; use one of {', '.join(LOOPS)}")
    if not (math.isfinite(spec.rate_hz) and spec.rate_hz > 0):
        raise InputError(f"the controller rate must be a positive frequency in Hz, got {spec.rate_hz!r}")
    if spec.noise_std is not None and not (math.isfinite(spec.noise_std) and spec.noise_std >= 0):
        raise InputError(f"the noise std must be >= 0, got {spec.noise_std!r}")
    for name in ("hover_s", "hold_s"):
        value = getattr(spec, name)
        if not (math.isfinite(value) and value >= 0):
            raise InputError(f"{name} must be a non-negative time in seconds, got {value!r}")
    if not spec.tests:
        raise InputError("give at least one MRFT test (beta and h)")
    for i, test in enumerate(spec.tests, 1):
        check_beta(test.beta)
        if not (math.isfinite(test.h) and test.h > 0):
            raise InputError(f"test {i}: the relay height h must be positive, got {test.h!r}")
        if not (math.isfinite(test.duration) and test.duration * spec.rate_hz >= 2):
            raise InputError(f"test {i}: the duration must cover at least two controller periods, got {test.duration!r} s")
    if spec.switching not in SWITCHING_RULES:
        raise InputError(f"unknown switching rule {spec.switching!r}; use one of {', '.join(SWITCHING_RULES)}")
    if spec.start_threshold is not None and not (math.isfinite(spec.start_threshold) and spec.start_threshold >= 0):
        raise InputError(f"start_threshold must be >= 0, got {spec.start_threshold!r}")
    if not (math.isfinite(spec.no_switch_delay) and spec.no_switch_delay >= 0):
        raise InputError(f"no_switch_delay must be >= 0 s, got {spec.no_switch_delay!r}")
    if not (isinstance(spec.confirm_samples, (int, np.integer)) and spec.confirm_samples >= 0):
        raise InputError(f"confirm_samples must be a non-negative integer, got {spec.confirm_samples!r}")
    e = spec.effects
    if not (math.isfinite(e.asymmetric_gain) and abs(e.asymmetric_gain) < 1):
        raise InputError(f"effect asymmetric_gain must be within (-1, 1), got {e.asymmetric_gain!r}")
    if not (math.isfinite(e.flex_mode_damping) and e.flex_mode_damping > 0):
        raise InputError(f"flex_mode_damping must be positive, got {e.flex_mode_damping!r}")
    for name in ("sensor_lag", "quadratic_drag", "actuator_rate_limit", "delay_jitter", "actuator_saturation",
                 "dead_zone", "thrust_rectification", "flex_mode_hz"):
        value = getattr(e, name)
        if not (math.isfinite(value) and value >= 0):
            raise InputError(f"effect {name} must be >= 0, got {value!r}")
    for name in ("input_bias", "gain_drift"):
        if not math.isfinite(getattr(e, name)):
            raise InputError(f"effect {name} must be finite, got {getattr(e, name)!r}")
    if not (e.delay_jitter_correlation > 0):
        raise InputError(f"delay_jitter_correlation must be positive, got {e.delay_jitter_correlation!r}")
    if not (e.battery_voltage > 0):
        raise InputError(f"battery_voltage must be positive, got {e.battery_voltage!r}")
    total = spec.hover_s + sum(t.duration + spec.hold_s for t in spec.tests)
    if 1.0 + e.gain_drift * total <= 0.05:
        raise InputError(
            f"gain_drift {e.gain_drift} makes the gain vanish within the {total:.0f} s flight; use a smaller drift"
        )


# --------------------------------------------------------------------------------------------------
# the simulation


def _schedule(spec: FlightSpec) -> tuple[int, list[tuple[int, int]]]:
    """Total number of ticks and the [start, end) tick range of each test."""
    rate = spec.rate_hz
    k = int(round(spec.hover_s * rate))
    ranges = []
    for test in spec.tests:
        n = int(round(test.duration * rate))
        ranges.append((k, k + n))
        k += n + int(round(spec.hold_s * rate))
    return k, ranges


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
    _validate(spec)
    loop = spec.loop
    model = spec.model
    eff = spec.effects
    T = 1.0 / spec.rate_hz
    noise_std = default_noise_std(loop) if spec.noise_std is None else float(spec.noise_std)
    bias = default_bias(loop) if spec.bias is None else float(spec.bias)
    r = default_setpoint(loop) if spec.setpoint is None else float(spec.setpoint)
    n_ticks, ranges = _schedule(spec)
    pid = design_hold_pid(model, spec.rate_hz)

    # ---- randomness, drawn up front in a fixed order so a seed defines the whole flight
    rng = np.random.default_rng(spec.seed)
    noise = rng.normal(0.0, noise_std, n_ticks) if noise_std > 0 else np.zeros(n_ticks)
    other_axis_noise = rng.normal(0.0, noise_std, n_ticks) if noise_std > 0 else np.zeros(n_ticks)
    jitter_innov = rng.standard_normal(n_ticks)
    battery_noise = rng.normal(0.0, 0.01, n_ticks)  # [V], only the published samples are used

    # ---- delays: application time of the command of tick k is k T + d_k (relative to the start)
    if eff.delay_jitter > 0:
        phi = math.exp(-T / eff.delay_jitter_correlation)
        innov = eff.delay_jitter * math.sqrt(1.0 - phi * phi) * jitter_innov
        innov[0] = eff.delay_jitter * jitter_innov[0]  # stationary start
        delays = fifo_delays(gauss_markov(innov, phi), model.tau, T)  # a command never overtakes an older one
    else:
        delays = None

    # ---- plant (linear part), optionally with the sensor-lag state appended
    A, B, _ = model.state_space()
    n = 3
    if eff.sensor_lag > 0:
        A = np.pad(A, ((0, 1), (0, 1)))
        A[3, 0] = 1.0 / eff.sensor_lag
        A[3, 3] = -1.0 / eff.sensor_lag
        B = np.append(B, 0.0)
        n = 4
    meas_index = 3 if eff.sensor_lag > 0 else 0
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
    quadratic = eff.quadratic_drag > 0
    rotor = eff.thrust_rectification > 0
    if (quadratic or rotor) and eff.flex_mode_hz > 0:
        raise InputError("flex_mode_hz cannot be combined with quadratic_drag or thrust_rectification")
    prop = LinearPropagator(A, B, grid=T / 64.0)
    shaper = command_shaper(bias, eff.asymmetric_gain, eff.actuator_saturation, eff.dead_zone)

    x = np.zeros(n)
    x[0] = r
    if eff.sensor_lag > 0:
        x[3] = r
    if eff.flex_mode_hz > 0:
        x[meas_index] = r

    # ---- records
    command = np.empty(n_ticks)
    y_true = np.empty(n_ticks)
    y_meas = np.empty(n_ticks)
    rate_true = np.empty(n_ticks)
    mode = np.full(n_ticks, -1, dtype=np.int64)
    for j, (k0, k1) in enumerate(ranges):
        mode[k0:k1] = j

    aborted: list[int | None] = [None] * len(spec.tests)
    if spec.abort_error is not None:
        if not spec.abort_error > 0:
            raise InputError(f"abort_error must be positive, got {spec.abort_error!r}")
        abort_limits = [float(spec.abort_error)] * len(spec.tests)
    else:
        abort_limits = [
            max(10.0 * df_prediction(model, t.beta, t.h, spec.rate_hz)[1], 50.0 * noise_std) for t in spec.tests
        ]

    # ---- controller state
    integ = -eff.input_bias  # the log starts in trimmed hover: the integrator holds the trim error
    dterm = 0.0
    y_prev = r
    a_d = pid.Tf / (pid.Tf + T)
    b_d = pid.Kd / (pid.Tf + T)
    relay = 1.0
    start_threshold = 10.0 * noise_std if spec.start_threshold is None else float(spec.start_threshold)
    relays = [
        make_relay(t.beta, spec.switching, start_threshold, spec.confirm_samples, spec.no_switch_delay * spec.rate_hz)
        for t in spec.tests
    ]
    u_init = bias - eff.input_bias  # the command that keeps the trimmed hover at t = 0

    # ---- actuator and delay line
    u_plant = u_init if shaper is None else shaper(u_init)
    act = u_plant  # actuator value a(t) at the current time
    target = u_plant  # the delayed command currently reaching the actuator
    pending: deque[tuple[float, float]] = deque()  # (application time from start, command)
    m_delay = int(math.floor(model.tau / T + 1e-12))
    frac = model.tau - m_delay * T
    if frac < 1e-12 * T:
        frac = 0.0
    if frac > 0:
        prop.fix(frac)
        prop.fix(T - frac)
    else:
        prop.fix(T)
    rlim = eff.actuator_rate_limit
    gd = eff.gain_drift
    ib = eff.input_bias
    c_drag = eff.quadratic_drag
    K = model.K
    inv_tp = 1.0 / model.Tp
    inv_ts = 1.0 / eff.sensor_lag if eff.sensor_lag > 0 else 0.0

    # Fast path: linear plant, fixed delay, no rate limit -> each period has the same two
    # sub-intervals [0, frac) and [frac, T), so the propagators are precomputed.
    fast = not quadratic and not rotor and rlim == 0 and delays is None and n <= 4
    if fast:
        # Whole period in one affine map on plain floats (numpy's per-call overhead would dominate
        # for 3-4 states): x+ = P x + qa0 c0a + qa1 c1a + qb0 c0b + qb1 c1b, where (c0, c1) are the
        # input's value and slope on [0, frac) and [frac, T).
        if frac > 0:
            Pa, Ea0, Ea1, _ = prop.fixed(frac)
            Pb, Eb0, Eb1, _ = prop.fixed(T - frac)
            P, qa0, qa1 = Pb @ Pa, Pb @ Ea0, Pb @ Ea1
        else:
            Pb, Eb0, Eb1, _ = prop.fixed(T)
            P, qa0, qa1 = Pb, np.zeros(n), np.zeros(n)
        pad = 4 - n
        P4 = np.pad(P, ((0, pad), (0, pad)))
        (p00, p01, p02, p03), (p10, p11, p12, p13), (p20, p21, p22, p23), (p30, p31, p32, p33) = P4.tolist()
        a00, a01, a02, a03 = np.pad(qa0, (0, pad)).tolist()
        a10, a11, a12, a13 = np.pad(qa1, (0, pad)).tolist()
        b00, b01, b02, b03 = np.pad(Eb0, (0, pad)).tolist()
        b10, b11, b12, b13 = np.pad(Eb1, (0, pad)).tolist()
        x0, x1, x2, x3 = np.pad(x, (0, pad)).tolist()
        lagged = n == 4
        hist = deque([u_plant] * (m_delay + 2), maxlen=m_delay + 2)
    rk4_step = T / 20.0
    # Event path of a linear plant: whole periods by superposition (one matrix product per period)
    # when the series of PeriodPropagator converges quickly; otherwise sub-interval by sub-interval.
    period = None
    if not fast and not quadratic and not rotor and float(np.abs(A).sum(axis=0).max()) * T <= 2.0:
        period = PeriodPropagator(A, B, T)

    def propagate(x: np.ndarray, h: float, ts: float, a0: float, slope: float) -> np.ndarray:
        """Advance x over [ts, ts + h) with actuator a(ts + s) = a0 + slope * s."""
        g0 = 1.0 + gd * ts
        c0 = g0 * a0 - bias + ib
        c1 = g0 * slope + gd * a0
        c2 = 2.0 * gd * slope
        if rotor:
            return rk4_rotor(x, h, c0, c1, c2, K, 0.0 if quadratic else 1.0 / model.Td, c_drag,
                             eff.thrust_rectification, inv_tp, inv_ts, rk4_step)
        if not quadratic:
            return prop.step(x, h, c0, c1, c2)
        return rk4_quadratic(x, h, c0, c1, c2, K, c_drag, inv_tp, inv_ts, rk4_step)

    report_every = max(1, n_ticks // 100)
    for k in range(n_ticks):
        tk = k * T
        if fast:
            y_true[k] = x0
            rate_true[k] = x1
            ym = (x3 if lagged else x0) + noise[k]
        else:
            y_true[k] = x[0]
            rate_true[k] = x[1]
            ym = float(x[meas_index]) + noise[k]
        y_meas[k] = ym
        e = r - ym
        j = mode[k]
        if j >= 0 and abs(e) > abort_limits[j]:
            # safety abort of a real flight stack (e.g. the relay got stuck after a noise-triggered
            # switch and the output runs away): the hold controller takes over for the rest of the test
            aborted[j] = k
            mode[k : ranges[j][1]] = -1
            j = -1
        if j < 0:
            # PID hold (derivative on the measurement; the integrator is frozen during tests)
            dterm = a_d * dterm - b_d * (ym - y_prev)
            integ += pid.Ki * T * e
            u = bias + pid.Kp * e + integ + dterm
        else:
            # MRFT, checks.md section 2: extremum of the sampled error since the last switch
            if k == ranges[j][0]:
                relay = relays[j].start(e)
            else:
                relay = relays[j].step(e)
            u = bias + relay * spec.tests[j].h
            dterm = a_d * dterm - b_d * (ym - y_prev)  # keep the filter current: no kick on return
        y_prev = ym
        command[k] = u
        if shaper is not None:
            u = shaper(u)  # what the actuator makes of the command (the log records the command)

        if fast:
            # hist = [u_{k-m-1}, ..., u_k]: u_{k-m-1} acts on [t_k, t_k + frac), u_{k-m} on [t_k + frac, t_{k+1})
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
        else:
            if delays is None:
                pending.append(((k + m_delay) * T + frac, u))  # exact grid offsets, no drift
            else:
                pending.append((tk + delays[k], u))
            t_end = (k + 1) * T
            pieces, act, target = actuator_pieces(tk, t_end, pending, act, target, rlim)
            if period is None:
                for s, h, a, slope in pieces:
                    x = propagate(x, h, s, a, slope)
            else:
                segments = [
                    (s - tk, h, (1.0 + gd * s) * a - bias + ib, (1.0 + gd * s) * slope + gd * a, 2.0 * gd * slope)
                    for s, h, a, slope in pieces
                ]
            if period is not None:
                x = period.advance(x, segments)
        if progress is not None and (k % report_every == 0):
            progress(k, n_ticks, "simulating")
    report(progress, n_ticks, n_ticks, "simulating")

    t = spec.start_time + np.arange(n_ticks) * T
    setpoint = np.full(n_ticks, r)
    truth = _truth(spec, pid, ranges, noise_std, bias, r, rate_true, delays, n_ticks, aborted, abort_limits)
    topics = _topics(spec, t, command, y_meas, other_axis_noise, battery_noise, ranges, r, n_ticks)
    return SimulatedFlight(
        spec=spec,
        t=t,
        command=command,
        output_true=y_true,
        output_measured=y_meas,
        setpoint=setpoint,
        truth=truth,
        topics=topics,
        delays=delays,
    )


# --------------------------------------------------------------------------------------------------
# outputs


def _truth(spec, pid, ranges, noise_std, bias, r, rate_true, delays, n_ticks, aborted, abort_limits) -> dict:
    from .._version import __version__

    model = spec.model
    T = 1.0 / spec.rate_hz
    eff = spec.effects
    tests = []
    for test, (k0, k1), k_abort, limit in zip(spec.tests, ranges, aborted, abort_limits):
        if k_abort is not None:
            k1 = k_abort
        entry = {
            "beta": test.beta,
            "h": test.h,
            "duration": test.duration,
            "t_start": spec.start_time + k0 * T,
            "t_end": spec.start_time + k1 * T,
            "bias": bias,
            "aborted": k_abort is not None,
            "abort_error": limit,
            "noise_margin": noise_margin(model, test.beta, test.h, spec.rate_hz, noise_std),
        }
        if eff.gain_drift != 0:
            t_mid = 0.5 * (k0 + k1) * T
            entry["K_effective"] = model.K * (1.0 + eff.gain_drift * t_mid)
        if eff.quadratic_drag > 0:
            half = rate_true[(k0 + k1) // 2 : k1]
            v_amp = 0.5 * (half.max() - half.min()) if half.size else float("nan")
            entry["velocity_amplitude"] = v_amp
            entry["Td_equivalent"] = 3.0 * math.pi / (8.0 * eff.quadratic_drag * v_amp) if v_amp > 0 else None
        tests.append(entry)
    truth = {
        "format": "mrft-ident simulation truth",
        "version": 1,
        "mrftcli_version": __version__,
        "Tp": model.Tp,
        "Td": model.Td,
        "tau": model.tau,
        "K": model.K,
        "loop": spec.loop,
        "rate_hz": spec.rate_hz,
        "noise_std": noise_std,
        "bias": bias,
        "setpoint": r,
        "start_time": spec.start_time,
        "duration": n_ticks * T,
        "hover_s": spec.hover_s,
        "hold_s": spec.hold_s,
        "tests": tests,
        "effects": asdict(eff),
        "effects_active": list(eff.active()),
        "drag_model": "quadratic" if eff.quadratic_drag > 0 else "linear",
        "seed": spec.seed,
        "switching_rule": (
            {"name": "checks", "start_threshold": 10.0 * noise_std if spec.start_threshold is None else spec.start_threshold}
            if spec.switching == "checks"
            else {"name": "hear", "confirm_samples": spec.confirm_samples, "no_switch_delay": spec.no_switch_delay}
        ),
        "hold_controller": asdict(pid),
        "units": {
            "output": "m" if spec.loop in ("altitude", "x", "y") else "rad",
            "time": "s",
            "command": "command units (bias + relay output)",
        },
        "conventions": (
            "command and output samples share the controller tick time stamps; the command of a tick "
            "reaches the plant tau seconds later (zero-order hold); plant input = g(t) * command - bias + input_bias"
        ),
    }
    if delays is not None:
        truth["delay_realised"] = {"mean": float(delays.mean()), "std": float(delays.std())}
    return truth


def _quaternion_zyx(roll: np.ndarray, pitch: np.ndarray) -> tuple[np.ndarray, ...]:
    """Quaternion (x, y, z, w) of the ZYX Euler angles (yaw 0, pitch, roll)."""
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    return sr * cp, cr * sp, -sr * sp, cr * cp


def _topics(spec, t, command, y_meas, other_noise, battery_noise, ranges, r, n_ticks) -> list[TopicData]:
    T = 1.0 / spec.rate_hz
    topics = [TopicData("/mrft/command", "std_msgs/msg/Float64", t.copy(), {"data": command.copy()})]
    starts = np.array([k0 for k0, _ in ranges])
    topics.append(
        TopicData(
            "/mrft/beta",
            "std_msgs/msg/Float64",
            t[starts].copy(),
            {"data": np.array([test.beta for test in spec.tests], dtype=float)},
        )
    )
    step = max(1, int(round(spec.rate_hz / spec.setpoint_rate_hz)))
    idx = np.arange(0, n_ticks, step)
    topics.append(TopicData("/mrft/setpoint", "std_msgs/msg/Float64", t[idx].copy(), {"data": np.full(idx.size, r)}))
    if spec.loop in ("altitude", "x", "y"):
        # position loops: the motion-capture pose (x, y, z in m), as the reference layout reads it
        axis = {"altitude": "z", "x": "x", "y": "y"}[spec.loop]
        topics.append(
            TopicData(
                "/mocap/pose",
                "geometry_msgs/msg/PoseStamped",
                t.copy(),
                {f"pose.position.{axis}": y_meas.copy(), "pose.orientation.w": np.ones(n_ticks)},
            )
        )
    else:
        if spec.loop == "roll":
            roll, pitch = y_meas, other_noise
        else:
            roll, pitch = other_noise, y_meas
        qx, qy, qz, qw = _quaternion_zyx(roll, pitch)
        topics.append(
            TopicData(
                "/imu/data",
                "sensor_msgs/msg/Imu",
                t.copy(),
                {"orientation.x": qx, "orientation.y": qy, "orientation.z": qz, "orientation.w": qw},
            )
        )
    step = max(1, int(round(spec.rate_hz / spec.battery_rate_hz)))
    idx = np.arange(0, n_ticks, step)
    volts = spec.effects.battery_voltage * (1.0 + spec.effects.gain_drift * idx * T) + battery_noise[idx]
    topics.append(TopicData("/battery", "sensor_msgs/msg/BatteryState", t[idx].copy(), {"voltage": volts}))
    return topics


def sidecar_path(log_path: str | Path) -> Path:
    """The ground-truth sidecar of a log: ``<log path>.truth.json`` (a directory bag: ``<dir>.truth.json``)."""
    p = Path(log_path)
    return p.with_name(p.name.rstrip("/") + ".truth.json")


def write_flight(flight: SimulatedFlight, path: str | Path, fmt: str) -> Path:
    """Write ``flight`` as a log in format ``fmt`` plus its sidecar; return the sidecar path."""
    from ..io import write_log  # the writers live with the readers

    write_log(flight.topics, path, fmt)
    truth = dict(flight.truth)
    truth["log_format"] = fmt
    truth["log_file"] = Path(path).name
    side = sidecar_path(path)
    side.write_text(json.dumps(_jsonable(truth), indent=2, allow_nan=False) + "\n")
    return side


def _jsonable(obj):
    """numpy scalars/arrays -> plain JSON values; non-finite floats -> None."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj
