"""The measurement noise model of a test's three constraints, and the admissibility lines.

The per-cycle scatter of each constraint (UFM slice, fundamental's phase, ln amplitude) comes from
three sources: the sensor noise relative to the amplitude (``eps = noise / a``), the sampling of the
relay (a switch comes up to one controller period ``Ts`` after the crossing) and the switch-timing
jitter that the noise causes (``noise / |dy/dt|`` at the switch). The coefficients
(:data:`NOISE_MODEL`) were fitted on simulated flights (``benchmarks/bench_plan.py --calibrate``,
docs/benchmarks/plan.md).
"""

from __future__ import annotations

import math

from ..mrft.consensus import BETA_SYSTEMATIC, GAIN_SYSTEMATIC, PHASE_SYSTEMATIC

__all__ = [
    "NOISE_MODEL",
    "cycle_noise",
    "switch_gap",
    "FLOOR_BETA",
    "FLOOR_PHASE",
    "FLOOR_LN_A",
    "LOST_CYCLES",
    "MIN_CYCLES",
    "MAX_EPS",
    "MIN_NOISE_MARGIN",
    "MIN_SWITCH_GAP",
]

#: Per-cycle noise model (see :func:`cycle_noise`): coefficients of (eps, sampling, switch jitter)
#: for the UFM slice, the fundamental's phase and ln(amplitude). Fitted on simulated flights by
#: ``benchmarks/bench_plan.py --calibrate`` (docs/benchmarks/plan.md).
NOISE_MODEL = {
    "ufm": (0.0, 0.072, 0.596),
    "phase": (0.003, 0.0, 0.719),
    "ln_amplitude": (0.0, 0.0, 1.536),
}
#: Systematic floors analyze adds to every test (mrftcli.analyze: effective beta [-], phase [rad], ln a [-]).
FLOOR_BETA, FLOOR_PHASE, FLOOR_LN_A = BETA_SYSTEMATIC, PHASE_SYSTEMATIC, GAIN_SYSTEMATIC
#: Cycles the segmenter typically drops at the start of a test (the transient) and at its end.
LOST_CYCLES = 3
#: Fewest stable cycles analyze accepts in a test (its min_stable_cycles).
MIN_CYCLES = 3
#: Largest sensor noise relative to the amplitude for a usable test (the MRFT rule locks up on noise).
MAX_EPS = 0.1
#: Least a * Omega / (rate * noise) for the MRFT rule not to lock up on noise (measured over 486
#: simulated tests: none locked at >= 4; mrftcli.sim.noise_margin).
MIN_NOISE_MARGIN = 4.0
#: Least switch gap (1 + beta) a / noise for analyze to use the test (see :func:`switch_gap`).
MIN_SWITCH_GAP = 16.0


def cycle_noise(amplitude: float, omega: float, switch_slope: float, rate_hz: float,
                noise_std: float) -> dict[str, float]:
    """Per-cycle standard deviations of a test's three constraints (the measurement noise model).

    Parameters
    ----------
    amplitude : float
        Output amplitude a [output units].
    omega : float
        Limit-cycle frequency [rad/s].
    switch_slope : float
        |dy/dt| of the output at the relay switch [output units / s].
    rate_hz : float
        Controller rate [Hz].
    noise_std : float
        Sensor noise std [output units].

    Returns
    -------
    dict
        ``ufm`` [s] (scatter of a cycle's UFM value tau_c), ``phase`` [rad] (of the fundamental's
        phase), ``ln_amplitude`` [-]: each ``sqrt(sum (c_k x_k)^2)`` over the sources
        ``x = (eps, Ts, noise / slope)`` scaled to the quantity (:data:`NOISE_MODEL`), with
        ``eps = noise / a`` and ``Ts = 1 / rate``.

    Examples
    --------
    >>> s = cycle_noise(0.05, 6.0, 0.3, 200.0, 0.0)   # no sensor noise: sampling alone
    >>> round(s["ufm"] * 1e3, 3)   # 0.072 Ts [ms]
    0.36
    """
    eps = noise_std / amplitude
    Ts = 1.0 / rate_hz
    jit = noise_std / max(switch_slope, 1e-300)
    n_per_cycle = rate_hz * math.tau / omega

    def comb(c: tuple[float, float, float], x: tuple[float, float, float]) -> float:
        return math.sqrt(sum((ci * xi) ** 2 for ci, xi in zip(c, x)))

    return {
        "ufm": comb(NOISE_MODEL["ufm"], (eps / omega, Ts, jit)),
        "phase": comb(NOISE_MODEL["phase"], (eps / math.sqrt(n_per_cycle), omega * Ts, omega * jit)),
        "ln_amplitude": comb(NOISE_MODEL["ln_amplitude"], (eps, omega * Ts, omega * jit)),
    }


def switch_gap(amplitude: float, beta: float, noise_std: float) -> float:
    """How far below the extremum the MRFT rule switches, in sensor noise std: ``(1 + beta) a / noise``.

    The rule switches once the error has fallen back by the share ``1 + beta`` of its extremum. Near
    beta = -1 that is a small drop, which a noise dip right after the extremum triggers early (the
    switch level then wanders and the relay hops between orbits or locks up), although the output
    moves fast enough at the zero crossing (:func:`mrftcli.sim.noise_margin`). ``analyze`` could
    use every simulated test with a gap of 16 or more (``benchmarks/bench_plan.py --admissibility``,
    docs/benchmarks/plan.md). Returns inf without noise.

    Examples
    --------
    >>> round(switch_gap(0.05, -0.9, 0.0005), 3)   # a 5 cm cycle at beta -0.9 under 0.5 mm of noise
    10.0
    """
    if noise_std <= 0:
        return math.inf
    return (1.0 + beta) * amplitude / noise_std
