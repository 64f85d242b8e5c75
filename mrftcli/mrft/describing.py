"""The describing-function (harmonic balance) approximation of the MRFT limit cycle, paper eqs. (4)-(7).

The MRFT's describing function is ``N(a) = 4 h / (pi a) (sqrt(1 - beta^2) + j beta)``; harmonic
balance ``G(j Omega) N(a) = -1`` gives

* the phase condition ``arg G(j Omega) = -pi + asin(beta)`` (:func:`df_phase`), whose root is the
  frequency (:func:`df_frequency`), and
* the amplitude ``a = 4 h |G(j Omega)| / pi`` (:func:`df_amplitude`).

It is an approximation (first harmonic only): :mod:`mrftcli.mrft.lprs` gives the exact cycle. The
package uses it to compare (``predict``), to start the exact solver's bracket, to plan the
simulator's relay heights and to judge whether a measured phase can belong to an MRFT limit cycle.

Examples
--------
The paper's example at beta = -0.4 (the exact cycle is 0.7057 Hz, amplitude 0.0553):

>>> from mrftcli.mrft.model import LoopModel
>>> f, a = describing_function_limit_cycle(LoopModel(0.1, 0.7042, 0.06), -0.4)
>>> round(f, 4), round(a, 4)
(0.7351, 0.0518)
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize

from ..validate import check_beta, check_positive
from .model import LoopModel

__all__ = ["df_phase", "df_frequency", "df_crossing", "df_amplitude", "describing_function_limit_cycle"]


def df_phase(beta: ArrayLike) -> np.ndarray:
    """-pi + arcsin(beta) [rad]: the describing-function phase of G(j Omega) in an MRFT limit cycle.

    Harmonic balance G(j Omega) N(a) = -1 with the MRFT's N(a) = 4h/(pi a) (sqrt(1 - beta^2) + j beta)
    (paper Section III). The exact limit cycle of any plant of eq. (2) lies within 0.33 rad of it.
    Vectorised; beta is clipped to [-1, 1] (a measured effective beta may stray outside).

    Examples
    --------
    >>> float(df_phase(0.0)) == -math.pi
    True
    """
    phase: np.ndarray = -np.pi + np.arcsin(np.clip(np.asarray(beta, float), -1.0, 1.0))
    return phase


def df_frequency(model: LoopModel, beta: float, extra_delay: float = 0.0) -> float:
    """Frequency Omega [rad/s] of the describing-function phase condition, paper eq. (6).

    Solves ``atan(Tp w) + atan(Td w) + (tau + extra_delay) w = pi/2 - asin(beta)`` (the lag beyond
    the integrator's -pi/2); the left side increases with w, so the root is unique.

    Parameters
    ----------
    model : LoopModel
        The plant of eq. (2).
    beta : float
        MRFT parameter in (-1, 1).
    extra_delay : float
        Delay [s] added to the model's tau (e.g. half a sample for a relay behind a zero-order hold).

    Returns
    -------
    float
        Omega [rad/s]; NaN when no root is found above 1e-12 rad/s.
    """
    beta = check_beta(beta)
    Tp, Td, tau = model.Tp, model.Td, model.tau + float(extra_delay)
    target = math.pi / 2 - math.asin(beta)  # phase lag beyond the integrator's -pi/2

    def lag(w: float) -> float:
        return math.atan(Tp * w) + math.atan(Td * w) + tau * w - target

    hi = 1.0 / max(Tp, Td, tau, 1e-9)
    while lag(hi) < 0:
        hi *= 2.0
    lo = hi
    while lag(lo) > 0:
        lo /= 2.0
        if lo < 1e-12:
            return float("nan")
    return float(optimize.brentq(lag, lo, hi, xtol=1e-14, rtol=1e-14))


def df_crossing(omega: np.ndarray, response: np.ndarray, beta: float) -> float | None:
    """The first of the increasing frequencies ``omega`` [rad/s] where the unwrapped arg G (``response``,
    G(j omega) there) falls through the phase condition -pi + asin(beta): any structure's describing-function
    frequency on a grid (a start for the exact cycle), or None where it does not cross."""
    phase = np.unwrap(np.angle(response)) - math.asin(beta) + math.pi
    k = np.nonzero((phase[:-1] > 0) & (phase[1:] <= 0))[0]
    return float(omega[k[0]]) if k.size else None


def df_amplitude(model: LoopModel, omega: float, h: float = 1.0) -> float:
    """Describing-function amplitude a = 4 h |G(j omega)| / pi [output units], paper eq. (7).

    ``omega`` in rad/s, ``h`` the relay height [command units].
    """
    return 4.0 * abs(h) / math.pi * float(abs(model.frequency_response(omega)))


def describing_function_limit_cycle(model: LoopModel, beta: float, h: float = 1.0) -> tuple[float, float]:
    """Describing-function prediction of the MRFT limit cycle, paper eqs. (4)-(7): NOT exact.

    Parameters
    ----------
    model : LoopModel
        The plant of eq. (2).
    beta : float
        MRFT parameter in (-1, 1).
    h : float
        Relay height [command units], > 0.

    Returns
    -------
    frequency_hz : float
        From arg W(j Omega) = -pi + asin(beta) [Hz].
    amplitude : float
        a = (4 h / pi) |W(j Omega)| [output units].
    """
    beta = check_beta(beta)
    h = check_positive("h", h)
    w = df_frequency(model, beta)
    return w / (2.0 * math.pi), df_amplitude(model, w, h)
