"""Which relay ran a test: MRFT, ideal or with hysteresis, read from its levels and switching errors.

The levels and the bias are the test's own (:class:`~mrftcli.segment.records.MrftTest` ``h`` and
``bias``). The switching rule is read from the output at the switch instants relative to the cycle's
centre (``beta_effective * amplitude`` of the stable cycles, the level ``L``):

* a logged MRFT beta makes it an MRFT with that beta;
* a relay deciding on samples at ``rate_hz`` switches on average half a sample after the crossing,
  which raises the level by ``L_s = a sin(Omega Ts / 2)``; a level within three standard errors (or
  5 % of the amplitude) of ``L_s`` is an ideal relay;
* a larger level is a hysteresis ``eps = L - L_s`` [output units];
* a negative level beyond that floor (phase lead) is an MRFT with beta < 0 at the level less ``L_s``
  (also when ``kind="mrft"`` is stated without a beta and none is logged).

MRFT and hysteresis give the same level within one test (``beta a = eps``); they differ across
tests of different amplitude, so an MRFT without a logged beta must be stated (``kind="mrft"``).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..mrft.relays import RelayLaw
from .records import MrftTest

__all__ = ["infer_relay", "switching_level", "sampling_level"]


def switching_level(test: MrftTest) -> tuple[float, float, float]:
    """The level at the switches relative to the centre [output units], its standard error, and the amplitude.

    Medians over the test's stable cycles (all regular cycles when none is stable).
    """
    cycles = test.stable or tuple(c for c in test.cycles if c.regular)
    levels = np.array([c.beta_effective * c.amplitude for c in cycles], dtype=float)
    levels = levels[np.isfinite(levels)]
    amps = np.array([c.amplitude for c in cycles], dtype=float)
    if levels.size == 0 or amps.size == 0:
        return math.nan, math.nan, math.nan
    se = float(np.std(levels) / math.sqrt(levels.size)) if levels.size > 1 else math.inf
    return float(np.median(levels)), se, float(np.median(amps))


def infer_relay(test: MrftTest, kind: str | None = None, beta: float | None = None,
                eps: float | None = None) -> RelayLaw:
    """The relay of ``test``; what is given (``kind``, ``beta``, ``eps``) is taken as stated.

    Parameters
    ----------
    test : MrftTest
        The test.
    kind : {"mrft", "ideal", "hysteresis"}, optional
        The relay type if known; None: inferred (module docstring).
    beta : float, optional
        MRFT beta (default: the logged one, else the measured effective one).
    eps : float, optional
        Hysteresis [output units] (default: measured).

    Returns
    -------
    RelayLaw
    """
    high, low = test.bias + test.h, test.bias - test.h
    stated = "stated" if kind is not None else "inferred"
    if kind is None and test.beta_nominal is not None:
        kind = "mrft"
    if kind == "mrft":
        if beta is None and test.beta_nominal is None:
            # the measured level less the sampling lag's: the sampled prediction adds that lag itself
            level, _, amp = switching_level(test)
            beta = float(np.clip((level - sampling_level(test, amp)) / amp, -0.99, 0.99))
            return RelayLaw("mrft", high, low, beta=beta, source=stated)
        b = beta if beta is not None else test.beta_nominal
        assert b is not None
        return RelayLaw("mrft", high, low, beta=float(b), source="stated" if beta is not None else stated)
    if kind == "hysteresis" and eps is not None:
        amp = float(test.amplitude_mean)
        if not (math.isfinite(eps) and 0 <= eps < amp):  # the recording's own level: switches at +-eps < swing
            raise InputError(f"--eps {eps:g} is not below test {test.index + 1}'s own output amplitude {amp:.3g} "
                             "[output units]: a hysteresis relay switches where the error crosses +-eps, inside "
                             "the swing; give eps in output units, or leave it out to measure it")
        return RelayLaw("hysteresis", high, low, eps=float(eps), source="stated")
    level, se, amp = switching_level(test)
    lag_level = sampling_level(test, amp)
    excess = level - lag_level if math.isfinite(level) else 0.0
    if kind is None:
        floor = max(3.0 * se if math.isfinite(se) else 0.0, 0.05 * amp)
        if level < -floor:  # switching before the crossing: phase lead, which only an MRFT (beta < 0) gives
            return RelayLaw("mrft", high, low, beta=float(np.clip(excess / amp, -0.99, 0.99)), source=stated)
        kind = "ideal" if excess <= floor else "hysteresis"
    if kind == "ideal":
        return RelayLaw("ideal", high, low, source=stated)
    return RelayLaw("hysteresis", high, low, eps=max(float(excess), 0.0), source=stated)


def sampling_level(test: MrftTest, amplitude: float) -> float:
    """The mean level a relay deciding on samples adds: the cycle's rise over half a sample [output units].

    ``amplitude`` is the cycle's [output units]; the rate is the test's controller rate (else its
    logged rate) and the frequency its stable cycles' mean. 0 without stable cycles.
    """
    rate = test.decision_rate_hz
    if not (rate and math.isfinite(amplitude) and test.n_stable):
        return 0.0
    omega = 2 * math.pi * test.frequency_hz_mean
    return amplitude * math.sin(min(0.5 * omega / rate, 0.5 * math.pi))
