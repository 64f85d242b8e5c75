"""ArduCopter's roll / pitch MRFT path, transcribed from its sources: an independent check of eq. (2).

What lies between the main-loop relay (``ardupilot_patch/``) and the roll angle, read in ArduPilot's
sources at the pinned commit (docs/sitl.md derives each step):

* ``Copter.cpp``'s FAST_TASK table runs, each 2.5 ms tick k: ``ins.update`` -> ``run_rate_controller_main``
  (``AC_AttitudeControl_Multi::rate_controller_run_dt``: the rate target plus the System ID injection the
  relay set at tick k-1) -> ``motors_output`` -> ``read_AHRS`` -> ``update_flight_mode`` -> ``MrftTask::update``
  (y_k from the EKF, the decision u_k). The injection reaches the motors one tick after the decision.
* The rate PID with P = I = D = 0 and FF = 1 passes the injection through its target filter only
  (``AC_PID::update_all``: ``_target += a (target - _target)``, a = dt / (dt + 1 / (2 pi FLTT))); the
  attitude controller's own roll rate target is zero during the test (``RATE.RDes`` equals the injection
  at every sample of a fully logged flight, docs/benchmarks/sitl.md).
* The mixer's output is held until the next tick; SITL's motors follow the PWM at once (``SIM_Motor``:
  a slew limit of 150 /s that a relay of a few hundredths never reaches) and its roll dynamics are
  linear, I p' = torque - c p (``SIM_Frame``: the inflow term ``v_in^2`` is 0.4 % of the damping at the
  cycles flown). So y_(k+2) is the first sample that sees u_k, which the logs show.

:func:`chain_delay_s` is what this discrete chain adds to eq. (2) with Tp = ``tp_of_filter``: the
filter's output is held a tick before the motors act on it (a staircase), about half a tick, the same at
every frequency. :func:`simulate_mrft` flies the MRFT on the chain in closed loop, sample by sample, with
SITL's own K and Td: no term outside eq. (2), no code of mrft-ident. Used by ``benchmarks/bench_sitl.py``
and ``tests/test_sitl_chain.py``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["chain_delay_s", "chain_response", "simulate_mrft", "half_periods"]


def _alpha(cutoff_hz: float, dt: float) -> float:
    """ArduPilot's first-order filter coefficient (``calc_lowpass_alpha_dt``)."""
    return dt / (dt + 1.0 / (2.0 * math.pi * cutoff_hz))


def _zoh_plant(K: float, Td: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of p' = K u - p / Td, y' = p (A [2x2], B [2])."""
    e = math.exp(-dt / Td)
    A = np.array([[1.0, Td * (1.0 - e)], [0.0, e]])
    B = np.array([K * Td * (dt - Td * (1.0 - e)), K * Td * (1.0 - e)])
    return A, B


def chain_response(freq_hz: np.ndarray, K: float, Td: float, cutoff_hz: float, rate_hz: float) -> np.ndarray:
    """Frequency response of the discrete chain from the decision u_k to y_k (complex, per frequency).

    One tick to the rate controller, ArduPilot's filter, the held output through the plant
    K Td / (s (Td s + 1)) sampled at the ticks.
    """
    dt = 1.0 / rate_hz
    a = _alpha(cutoff_hz, dt)
    A, B = _zoh_plant(K, Td, dt)
    z = np.exp(1j * 2.0 * np.pi * np.asarray(freq_hz, dtype=float) * dt)
    out = np.empty(z.shape, dtype=complex)
    for i, zi in enumerate(z.ravel()):
        plant = np.array([1.0, 0.0]) @ np.linalg.solve(zi * np.eye(2) - A, B)
        out.ravel()[i] = plant * a / (1.0 - (1.0 - a) / zi) / zi
    return out


def chain_delay_s(cutoff_hz: float, rate_hz: float, freq_hz: float = 5.0) -> float:
    """Delay [s] the chain adds to eq. (2) (Tp the filter's continuous lag, tau 0) with the relay's decision
    sampled and held as ``mrft_limit_cycle(rate_hz=...)`` models it (the plant's K and Td cancel).

    Both the chain and eq. (2) are discretised exactly (zero-order hold on the decision); the phase
    difference at ``freq_hz`` over the angular frequency. It is the same at every frequency to 0.01 ms
    (tests/test_sitl_chain.py): a pure delay, about half a tick.
    """
    from scipy.signal import cont2discrete

    dt = 1.0 / rate_hz
    a = _alpha(cutoff_hz, dt)
    tp = -dt / math.log(1.0 - a)
    K, Td = 1.0, 1.0
    num, den, _ = cont2discrete(([K * Td], np.polymul([Td, 1.0, 0.0], [tp, 1.0])), dt, method="zoh")
    z = np.exp(1j * 2.0 * np.pi * freq_hz * dt)
    eq2 = np.polyval(np.ravel(num), z) / np.polyval(den, z)
    chain = chain_response(np.array([freq_hz]), K, Td, cutoff_hz, rate_hz)[0]
    return float(-np.angle(chain / eq2) / (2.0 * np.pi * freq_hz))


class _Relay:
    """The MRFT switching rule of ``ardupilot_patch/MRFT_relay.h`` (start threshold included)."""

    def __init__(self, beta: float, eth: float) -> None:
        self.beta, self.eth = beta, eth
        self.sign, self.e_ext, self.started, self.first_half = 1, 0.0, False, True

    def step(self, e: float) -> int:
        if not self.started:
            self.sign, self.e_ext, self.started = (1 if e >= 0 else -1), e, True
        elif self.first_half:
            if self.sign * e < -self.eth:
                self.sign, self.e_ext, self.first_half = -self.sign, e, False
        elif self.sign > 0:
            self.e_ext = max(self.e_ext, e)
            if self.e_ext > 0 and e <= -self.beta * self.e_ext:
                self.sign, self.e_ext = -1, e
        else:
            self.e_ext = min(self.e_ext, e)
            if self.e_ext < 0 and e >= -self.beta * self.e_ext:
                self.sign, self.e_ext = 1, e
        return self.sign


def _fly(K: float, Td: float, beta: float, h: float, cutoff_hz: float, rate_hz: float, delay_ticks: int, eth: float,
         noise: float, seed: int, duration_s: float, pwm_us: float, pwm_base_us: float) -> np.ndarray:
    """The relay's output at every tick of the chain flown in closed loop (see :func:`simulate_mrft`)."""
    dt = 1.0 / rate_hz
    a = _alpha(cutoff_hz, dt)
    A, B = _zoh_plant(K, Td, dt)
    rng = np.random.default_rng(seed)
    relay = _Relay(beta, eth)
    x, filtered = np.zeros(2), 0.0
    pending = [0.0] * (delay_ticks + 1)  # the delay line, then the tick to the rate controller
    n = int(round(duration_s / dt))
    sent = np.empty(n)
    for k in range(n):
        y = x[0] + (noise * rng.standard_normal() if noise else 0.0)
        sent[k] = h * relay.step(-y)
        pending.append(sent[k])
        filtered += a * (pending.pop(0) - filtered)
        u = filtered
        if pwm_us:  # AP_MotorsMulticopter::output_to_pwm: int16_t of the float, the axis's two motors
            u = (int(pwm_base_us + pwm_us * filtered) - int(pwm_base_us - pwm_us * filtered)) / (2.0 * pwm_us)
        x = A @ x + B * u
    return sent


def simulate_mrft(K: float, Td: float, beta: float, h: float, cutoff_hz: float = 20.0, rate_hz: float = 400.0,
                  delay_ticks: int = 0, eth: float = 0.005, noise: float = 0.0, seed: int = 0,
                  duration_s: float = 6.0, settle_s: float = 2.0, pwm_us: float = 0.0,
                  pwm_base_us: float = 1460.3) -> float:
    """The MRFT flown on the chain in closed loop; its frequency [Hz] after ``settle_s``.

    Parameters
    ----------
    K, Td : float
        The plant K Td / (s (Td s + 1)) [rad/s^2 per unit, s] (SITL's: ``sitl_physics.implied_model``).
    beta, h : float
        The relay's beta and height [mixer units].
    cutoff_hz, rate_hz : float
        ``ATC_RAT_RLL_FLTT`` [Hz] and the main loop's rate [Hz].
    delay_ticks : int
        The relay's added delay in whole ticks (``MRFT_DLY``).
    eth : float
        The start threshold [rad]: the first half-cycle holds until the error passes it.
    noise : float
        Standard deviation of white noise on the measured angle [rad] (0: SITL's ideal sensors).
    seed : int
        Seed of the noise.
    duration_s, settle_s : float
        The test's length and the start of the part measured [s].
    pwm_us : float
        0: the mixer's output reaches the plant as a real number. Else the PWM [us] one unit of the axis's
        command moves each of its two motors by: ArduPilot sends integer microseconds
        (``AP_MotorsMulticopter::output_to_pwm`` returns an ``int16_t``, SITL reads ``uint16_t`` servos), so the
        torque is the difference of the two truncated PWMs (about 390 us per unit at SITL's hover).
    pwm_base_us : float
        The two motors' PWM without the axis's command [us] (hover throttle through the mixer).

    Returns
    -------
    float
        Up-switches counted over the measured part, per second [Hz].
    """
    sent = _fly(K, Td, beta, h, cutoff_hz, rate_hz, delay_ticks, eth, noise, seed, duration_s, pwm_us, pwm_base_us)
    t = np.arange(sent.size) / rate_hz
    up = t[1:][np.diff(sent) > 0]
    up = up[up > settle_s]
    if up.size < 3:
        return float("nan")
    return float((up.size - 1) / (up[-1] - up[0]))


def half_periods(K: float, Td: float, beta: float, h: float, settle_s: float = 1.0, **kw: float) -> np.ndarray:
    """The relay's half periods [ticks] after ``settle_s`` of the chain flown as :func:`simulate_mrft` (same
    keywords): one value when the loop locks onto one sampled-relay orbit, several when it hops."""
    rate_hz = float(kw.get("rate_hz", 400.0))
    args = {"cutoff_hz": 20.0, "rate_hz": 400.0, "delay_ticks": 0, "eth": 0.005, "noise": 0.0, "seed": 0,
            "duration_s": 6.0, "pwm_us": 0.0, "pwm_base_us": 1460.3}
    args.update(kw)
    sent = _fly(K, Td, beta, h, args["cutoff_hz"], args["rate_hz"], int(args["delay_ticks"]), args["eth"],
                args["noise"], int(args["seed"]), args["duration_s"], args["pwm_us"], args["pwm_base_us"])
    sw = np.flatnonzero(np.diff(np.sign(sent))) + 1
    sw = sw[sw >= settle_s * rate_hz]
    return np.diff(sw)
