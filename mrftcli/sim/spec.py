"""What to fly: the simulator's specs (:class:`FlightSpec` of :class:`TestSpec` s and :class:`Effects`),
the loop defaults, their validation and the flight's schedule (:class:`FlightSettings`).

The plant is any model object (:class:`~mrftcli.mrft.model.PlantModel`): eq. (2) (``LoopModel``), a
process family or a declared structure. Eq. (2) flies about the loop's trim (the hover command, the
setpoint); the other families about their operating point, the origin (command ``bias`` holds output 0).

Times in seconds, rates in Hz, outputs in output units (m or rad), commands in command units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from ..io.logtypes import LOOPS
from ..mrft.model import LoopModel, PlantModel
from ..validate import check_beta, check_rate
from .control import SWITCHING_RULES

__all__ = [
    "check_flight_size",
    "check_hover_hold",
    "check_switching",
    "MAX_SIM_TICKS",
    "Effects",
    "TestSpec",
    "FlightSpec",
    "FlightSettings",
    "EFFECT_NAMES",
    "default_noise_std",
    "default_bias",
    "default_setpoint",
    "validate_spec",
    "flight_settings",
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
        on the rotor speed and the thrust goes with its square (``mrftcli.mrft.propagate.rk4_rotor``);
        0 means the linear propulsion of eq. (2). Like ``quadratic_drag``, eq. (2)'s own (its states).
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
    """One relay test: beta in (-1, 1), relay height h [command units], duration of the relay [s].

    ``eps`` [output units] adds a hysteresis to the switching level (``checks`` rule only): beta 0 and
    eps > 0 is the hysteresis relay (:class:`~mrftcli.mrft.relays.RelayLaw` ``hysteresis``), beta 0 and
    eps 0 the ideal relay, eps 0 the MRFT.
    """

    __test__ = False  # not a pytest test class, although its name starts with "Test"

    beta: float
    h: float
    duration: float = 12.0
    eps: float = 0.0


@dataclass(frozen=True)
class FlightSpec:
    """Everything that defines one simulated flight (``model``: the plant with its true parameters)."""

    model: PlantModel
    tests: tuple[TestSpec, ...]
    loop: str = "altitude"
    rate_hz: float = 200.0
    noise_std: float | None = None  # output units; None -> 0.5 mm (altitude) / 0.05 deg (roll, pitch)
    bias: float | None = None  # hover command; None -> loop default (eq. (2)), 0 (other families)
    setpoint: float | None = None  # None -> loop default (1 m altitude, 0 rad attitude); 0 for other families
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
# validation


#: most controller ticks one simulated flight may have: 10 M (14 h at 200 Hz, 100 s at 100 kHz), a few
#: hundred MB of arrays; a 1e6 s test or a 1e7 Hz rate asked for 3.2 GB (issue 35)
MAX_SIM_TICKS = 10_000_000


def check_flight_size(duration_s: float, rate_hz: float) -> None:
    """Refuse a simulated flight of more than :data:`MAX_SIM_TICKS` controller ticks (one-line InputError),
    and a rate above the 100 kHz the readers accept, before any array is allocated."""
    check_rate("the controller rate (--controller-rate)", rate_hz)
    ticks = duration_s * rate_hz
    if not math.isfinite(ticks) or ticks > MAX_SIM_TICKS:
        raise InputError(f"the flight would be {duration_s:.4g} s at {rate_hz:g} Hz, {ticks:.3g} controller ticks, "
                         f"more than the {MAX_SIM_TICKS:.0e} simulated at once; give shorter tests (DURATION), --hover and --hold, or a "
                         "lower --controller-rate")


def validate_spec(spec: FlightSpec) -> None:
    """Check everything :func:`~mrftcli.sim.flight.simulate_flight` needs of ``spec``.

    Raises
    ------
    InputError
        The first setting out of range, with a one-line message naming it.
    """
    _check_flight(spec)
    _check_tests(spec)
    _check_switching(spec)
    _check_effects(spec)


def _check_flight(spec: FlightSpec) -> None:
    if spec.loop not in LOOPS:
        raise InputError(f"unknown loop {spec.loop!r}; use one of {', '.join(LOOPS)}")
    if not (math.isfinite(spec.rate_hz) and spec.rate_hz > 0):
        raise InputError(f"the controller rate must be a positive frequency in Hz, got {spec.rate_hz!r}")
    if spec.model.delay < 0:  # eq. (2) admits a lead (an identified estimator's), which no delay line holds
        raise InputError(f"tau = {spec.model.delay * 1e3:.3g} ms < 0 (a lead) cannot be simulated: the simulator "
                         "delays the command, it cannot advance it; give tau >= 0")
    if spec.noise_std is not None and not (math.isfinite(spec.noise_std) and spec.noise_std >= 0):
        raise InputError(f"the noise std must be >= 0, got {spec.noise_std!r}")
    check_hover_hold(spec)
    if spec.abort_error is not None and not spec.abort_error > 0:
        raise InputError(f"abort_error must be positive, got {spec.abort_error!r}")
    if not isinstance(spec.model, LoopModel) and spec.setpoint not in (None, 0.0):
        raise InputError(f"a {spec.model.family} plant flies about its operating point, output 0: "
                         "leave the setpoint out")


def _check_tests(spec: FlightSpec) -> None:
    if not spec.tests:
        raise InputError("give at least one MRFT test (beta and h)")
    for i, test in enumerate(spec.tests, 1):
        check_beta(test.beta)
        if not (math.isfinite(test.h) and test.h > 0):
            raise InputError(f"test {i}: the relay height h must be positive, got {test.h!r}")
        if not (math.isfinite(test.duration) and test.duration * spec.rate_hz >= 2):
            raise InputError(f"test {i}: the duration must cover at least two controller periods, got {test.duration!r} s")
        if not (math.isfinite(test.eps) and test.eps >= 0) or (test.eps > 0 and spec.switching != "checks"):
            raise InputError(f"test {i}: the hysteresis eps must be >= 0 [output units] (and the checks switching "
                             f"rule), got {test.eps!r}")
    check_flight_size(spec.hover_s + sum(t.duration + spec.hold_s for t in spec.tests), spec.rate_hz)


def check_hover_hold(spec: Any) -> None:
    """``spec.hover_s`` and ``spec.hold_s`` (a flight's or a cascade's) are times >= 0 s; one-line InputError."""
    for name in ("hover_s", "hold_s"):
        value = getattr(spec, name)
        if not (math.isfinite(value) and value >= 0):
            raise InputError(f"{name} must be a non-negative time in seconds, got {value!r}")


def check_switching(switching: str) -> None:
    """An MRFT switching rule this simulator flies (:data:`~mrftcli.sim.control.SWITCHING_RULES`)."""
    if switching not in SWITCHING_RULES:
        raise InputError(f"unknown switching rule {switching!r}; use one of {', '.join(SWITCHING_RULES)}")


def _check_switching(spec: FlightSpec) -> None:
    check_switching(spec.switching)
    if spec.start_threshold is not None and not (math.isfinite(spec.start_threshold) and spec.start_threshold >= 0):
        raise InputError(f"start_threshold must be >= 0, got {spec.start_threshold!r}")
    if not (math.isfinite(spec.no_switch_delay) and spec.no_switch_delay >= 0):
        raise InputError(f"no_switch_delay must be >= 0 s, got {spec.no_switch_delay!r}")
    if not (isinstance(spec.confirm_samples, (int, np.integer)) and spec.confirm_samples >= 0):
        raise InputError(f"confirm_samples must be a non-negative integer, got {spec.confirm_samples!r}")


def _check_effects(spec: FlightSpec) -> None:
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
    if (e.quadratic_drag > 0 or e.thrust_rectification > 0) and e.flex_mode_hz > 0:
        raise InputError("flex_mode_hz cannot be combined with quadratic_drag or thrust_rectification")
    if (e.quadratic_drag > 0 or e.thrust_rectification > 0) and not isinstance(spec.model, LoopModel):
        raise InputError("quadratic_drag and thrust_rectification change eq. (2)'s states; a "
                         f"{spec.model.family} plant takes the other effects")


# --------------------------------------------------------------------------------------------------
# the schedule


@dataclass(frozen=True)
class FlightSettings:
    """A checked spec with its defaults filled in, and the flight's schedule.

    Attributes
    ----------
    T : float
        Controller period [s].
    noise_std : float
        White sensor noise std [output units].
    bias : float
        Hover (trim) command [command units].
    setpoint : float
        The loop's setpoint r [output units].
    n_ticks : int
        Controller ticks of the whole flight.
    ranges : tuple of (int, int)
        The [start, end) tick range of each test.
    """

    T: float
    noise_std: float
    bias: float
    setpoint: float
    n_ticks: int
    ranges: tuple[tuple[int, int], ...]


def flight_settings(spec: FlightSpec) -> FlightSettings:
    """:func:`validate_spec`, then the defaults of the loop and the schedule: ``hover_s`` of hold,
    then each test followed by ``hold_s`` of hold, in whole controller ticks."""
    validate_spec(spec)
    trimmed = isinstance(spec.model, LoopModel)  # eq. (2): the loop's trim; other families: the origin
    rate = spec.rate_hz
    k = int(round(spec.hover_s * rate))
    ranges = []
    for test in spec.tests:
        n = int(round(test.duration * rate))
        ranges.append((k, k + n))
        k += n + int(round(spec.hold_s * rate))
    return FlightSettings(
        T=1.0 / rate,
        noise_std=default_noise_std(spec.loop) if spec.noise_std is None else float(spec.noise_std),
        bias=float(spec.bias) if spec.bias is not None else default_bias(spec.loop) if trimmed else 0.0,
        setpoint=float(spec.setpoint) if spec.setpoint is not None else default_setpoint(spec.loop) if trimmed else 0.0,
        n_ticks=k,
        ranges=tuple(ranges),
    )
