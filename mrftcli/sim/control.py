"""The simulator's controllers and planning helpers: MRFT relays, the hold PID, describing function.

Used by :mod:`mrftcli.sim.flight`, which re-exports the public names; :class:`MrftRelay` is
:mod:`mrftcli.mrft.relays`'s, re-exported here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError
from ..mrft.describing import df_amplitude, df_frequency
from ..mrft.model import LoopModel, PlantModel
from ..mrft.relays import MrftRelay
from ..validate import check_beta

__all__ = [
    "SWITCHING_RULES",
    "MrftRelay",
    "HearMrftRelay",
    "make_relay",
    "RelayTests",
    "relay_sequence",
    "HoldPID",
    "design_hold_pid",
    "df_prediction",
    "noise_margin",
]

#: MRFT switching rules the simulator implements (see FlightSpec.switching).
SWITCHING_RULES = ("checks", "hear")

_DEG = math.pi / 180.0


# --------------------------------------------------------------------------------------------------
# describing-function planning (approximate; only used to choose h and durations)


def _phase_crossing(model: PlantModel, target: float, rate_hz: float, lead: float = 0.0) -> float:
    """The lowest frequency [rad/s] where arg G(j omega), half a tick of hold and ``lead`` [rad] reach ``target``.

    Eq. (2)'s phase is monotone: the MRFT phase condition of :func:`mrftcli.mrft.describing.df_frequency`
    with sin(pi + target - lead) as its beta; any other family's is read off a 6000-point logarithmic grid
    up to 0.99 of the Nyquist frequency (its first point at or below the target).
    """
    if isinstance(model, LoopModel):
        # df_frequency's condition is arg = -pi + asin(beta): sin(pi + target - lead) gives back the target
        # only while it lies within 90 deg of -180 deg (the integrator's -90 to the delay's -270)
        if not abs(math.pi + target - lead) < 0.5 * math.pi:
            raise InputError("no phase crossover found; check the model parameters (the phase asked for, "
                             f"{math.degrees(target - lead):.1f} deg with the controller's lead, is outside "
                             "-270 to -90 deg)")
        omega_c = df_frequency(model, math.sin(math.pi + target - lead), extra_delay=0.5 / rate_hz)
        if not math.isfinite(omega_c):
            raise InputError("no phase crossover found; check the model parameters")
        return omega_c
    omega = np.geomspace(1e-4, 0.99 * math.pi * rate_hz, 6000)
    phase = np.unwrap(np.angle(model.frequency_response(omega))) - 0.5 * omega / rate_hz + lead
    below = np.flatnonzero(phase <= target)
    if below.size == 0:
        raise InputError("the plant's phase never reaches the one asked for below the Nyquist frequency; "
                         "check the model parameters or use a smaller beta")
    return float(omega[below[0]])


def df_prediction(model: PlantModel, beta: float, h: float, rate_hz: float = 200.0) -> tuple[float, float]:
    """Describing-function estimate of the MRFT limit cycle, eq. (4)-(6) of the paper, for any family.

    Solves arg G(j Omega) - Omega / (2 rate_hz) = -pi + asin(beta) (the half-sample lag models the
    zero-order hold; eq. (2) with :func:`mrftcli.mrft.describing.df_frequency`, other families on a
    grid: :func:`_phase_crossing`) and a = 4 h |G(j Omega)| / pi. Approximate
    (first harmonic only); use :mod:`mrftcli.mrft.lprs` for exact figures. Used here only to plan h
    and test durations.

    Returns
    -------
    omega : float
        Oscillation frequency [rad/s].
    amplitude : float
        Output amplitude [output units].
    """
    omega = _phase_crossing(model, -math.pi + math.asin(check_beta(beta)), rate_hz)
    return omega, df_amplitude(model, omega, h)  # type: ignore[arg-type]  # |G| of any family


def noise_margin(model: PlantModel, beta: float, h: float, rate_hz: float, noise_std: float) -> float:
    """How far the output moves per tick near the error's zero crossing, in noise std.

    a Omega / (rate_hz noise_std) with the describing-function amplitude a and frequency Omega. The
    plain MRFT rule on white noise locks up when a noise dip right after the zero crossing switches
    the relay the wrong way, so this margin should be at least 4. Measured over 486 simulated tests
    (54 models of the DNN-MRFT range, betas -0.2/-0.5/-0.8): margin < 1: 95 % locked, 1.5-2: 48 %,
    2.5-3: 24 %, 3-4: 6 %, >= 4: none of 176. Returns inf without noise.
    """
    if noise_std <= 0:
        return math.inf
    omega, amplitude = df_prediction(model, beta, h, rate_hz)
    return amplitude * omega / (rate_hz * noise_std)


# --------------------------------------------------------------------------------------------------
# hold controller


@dataclass(frozen=True)
class HoldPID:
    """The PID that holds the setpoint between tests (parallel form, filtered derivative).

    C(s) = Kp + Ki / s + Kd s / (Tf s + 1), derivative on the measurement.

    Attributes
    ----------
    Kp, Ki, Kd : float
        Gains [command units per output unit, per output unit-second, per output unit/s].
    Tf : float
        Derivative filter time constant [s].
    omega_c : float
        Design crossover frequency [rad/s].
    phase_margin_deg : float
        Design phase margin [deg] (continuous design, hold modelled as half a sample of delay).
    """

    Kp: float
    Ki: float
    Kd: float
    Tf: float
    omega_c: float
    phase_margin_deg: float


def design_hold_pid(model: PlantModel, rate_hz: float = 200.0, phase_margin_deg: float = 45.0) -> HoldPID:
    """Loop-shaping PID for G(s) with a given phase margin at a computed crossover.

    The controller shape is fixed relative to the crossover omega_c: derivative time 1.5 / omega_c
    with a filter at N = 10, integral time 6 / omega_c. Its phase at omega_c is then a constant lead;
    omega_c is where arg G(j omega) (with half a sample of hold delay) plus that lead equals
    -180 deg + phase margin, and Kp puts |C G| = 1 there (:func:`_phase_crossing`: eq. (2)'s phase in
    closed form, another family's first crossing on a grid). The phase of eq. (2) is monotone, so omega_c
    is unique; the design holds over the whole DNN-MRFT range (T1 0.015-0.3 s, T2 0.2-2 s, tau up to
    0.1 s) and the paper's platforms (checked in the tests with the exact discrete closed loop).
    """
    a, n_filter, ti = 1.5, 10.0, 6.0

    def c_norm(omega: float) -> complex:
        s = 1j * omega
        td, tf, ti_ = a / omega, a / omega / n_filter, ti / omega
        return 1.0 + 1.0 / (ti_ * s) + td * s / (tf * s + 1.0)

    lead = math.atan2(c_norm(1.0).imag, c_norm(1.0).real)  # scale-free: same at every omega_c
    omega_c = _phase_crossing(model, -math.pi + phase_margin_deg * _DEG, rate_hz, lead)
    g = abs(complex(model.frequency_response(omega_c)))
    kp = 1.0 / (g * abs(c_norm(omega_c)))
    td = a / omega_c
    return HoldPID(
        Kp=kp,
        Ki=kp / (ti / omega_c),
        Kd=kp * td,
        Tf=td / n_filter,
        omega_c=omega_c,
        phase_margin_deg=phase_margin_deg,
    )


# --------------------------------------------------------------------------------------------------
# MRFT relays (the checks.md rule, MrftRelay, lives in mrftcli.mrft.relays: the diagnosis decides with it too)


class HearMrftRelay:
    """The HEAR flight stack's MRFT block (``mrft_anti_false_switching``, mode 1), relay sign.

    The switching levels are those of :class:`MrftRelay` (-beta e_max, -beta e_min), but a switch
    needs the extremum to be confirmed (``confirm_samples`` ticks without a new one) and at least
    ``no_switch_ticks`` ticks since the previous switch, and the extremum's sign is not checked, so a
    noise-triggered switch is undone instead of locking the relay. Start: the sign of the first
    error (- for e <= 0), first switch when the error changes sign.
    """

    def __init__(self, beta: float, confirm_samples: int = 5, no_switch_ticks: float = 4.0) -> None:
        check_beta(beta)
        self.beta = float(beta)
        self.confirm = int(confirm_samples)
        self.no_switch = float(no_switch_ticks) - 1e-9
        self.start(0.0)

    def start(self, e: float) -> float:
        self.relay = 1.0 if e > 0 else -1.0
        self.e_max = self.e_min = 0.0
        self.reached = True
        self.count = 0
        self.since = 0
        return self.relay

    def step(self, e: float) -> float:
        self.since += 1
        if self.since <= self.no_switch:
            return self.relay
        beta = self.beta
        if self.relay < 0:
            if e < self.e_min:
                self.e_min, self.count = e, 0
            else:
                self.count += 1
                if self.count >= self.confirm:
                    self.reached, self.count = True, 0
                self.e_max = e
            if self.reached and e > -beta * self.e_min:
                self.relay, self.reached, self.since = 1.0, False, 0
        else:
            if e > self.e_max:
                self.e_max, self.count = e, 0
            else:
                self.count += 1
                if self.count >= self.confirm:
                    self.reached, self.count = True, 0
                self.e_min = e
            if self.reached and e < -beta * self.e_max:
                self.relay, self.reached, self.since = -1.0, False, 0
        return self.relay


def make_relay(
    beta: float,
    switching: str = "checks",
    start_threshold: float = 0.0,
    confirm_samples: int = 5,
    no_switch_ticks: float = 4.0,
    eps: float = 0.0,
) -> MrftRelay | HearMrftRelay:
    """The relay object of a switching rule (``checks``: with the hysteresis ``eps`` [output units], or ``hear``)."""
    if switching == "checks":
        return MrftRelay(beta, start_threshold, eps)
    if switching == "hear":
        return HearMrftRelay(beta, confirm_samples, no_switch_ticks)
    raise InputError(f"unknown switching rule {switching!r}; use one of {', '.join(SWITCHING_RULES)}")


class RelayTests:
    """A flight's MRFT tests tick by tick, for the flight's and the cascade's controllers: which test runs
    at each tick (``mode``: its index, -1 for the hold), its relay, and a flight stack's safety net.

    A test whose error exceeds its limit is aborted (``aborted[j]``: the tick) and the hold takes over for
    the rest of it. With ``from_start`` the limit counts from the error at the test's first tick (a
    cascade's test may start away from the setpoint, the vehicle having drifted during the one before,
    and first travel back).
    """

    def __init__(self, tests: Sequence[Any], relays: Sequence[MrftRelay | HearMrftRelay],
                 ranges: Sequence[tuple[int, int]], limits: Sequence[float], n_ticks: int,
                 from_start: bool = False) -> None:
        self.tests, self.relays, self.ranges, self.limits = tests, relays, ranges, limits
        self.mode = np.full(n_ticks, -1, dtype=np.int64)
        for j, (k0, k1) in enumerate(ranges):
            self.mode[k0:k1] = j
        self.aborted: list[int | None] = [None] * len(tests)
        self.start_error = [0.0] * len(tests)
        self.from_start = from_start

    def command(self, j: int, k: int, e: float) -> float:
        """Test ``j``'s relay output +-h at tick ``k`` for the error ``e``, or NaN when the safety net aborts it."""
        k0, k1 = self.ranges[j]
        if self.from_start and k == k0:
            self.start_error[j] = abs(e)
        if abs(e) > self.limits[j] + self.start_error[j]:
            self.aborted[j] = k
            self.mode[k:k1] = -1
            return math.nan
        relay = self.relays[j]
        s = relay.start(e) if k == k0 else relay.step(e)
        return s * self.tests[j].h


def relay_sequence(e: np.ndarray, beta: float, switching: str = "checks", **options) -> np.ndarray:
    """Relay signs (+1/-1) the rule produces for the error samples ``e`` (first sample = start)."""
    relay = make_relay(beta, switching, **options)
    e = np.asarray(e, dtype=float)
    out = np.empty(e.size)
    for i, value in enumerate(e.tolist()):
        out[i] = relay.start(value) if i == 0 else relay.step(value)
    return out
