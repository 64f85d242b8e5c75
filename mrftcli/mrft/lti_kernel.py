"""The built-in families' fit residuals and their Jacobian in closed form (the fast path of identify_lti).

Every built-in process family is a chain of first-order lags with a delay and 0-1 integrators,
``G(s) = K e^{-tau s} / (s^n prod_i (T_i s + 1))``, so its log-gain and phase at a frequency omega
[rad/s] are real closed forms,

    ln|G| = ln|K| - n ln omega - 1/2 sum_i ln(1 + (T_i omega)^2)
    arg G = arg K - n pi/2 - tau omega - sum_i atan(T_i omega),

and so are their derivatives in the solver's variables (ln|K|, ln T_i, tau): 1; -x^2/(1 + x^2) and
-x/(1 + x^2) with x = T_i omega; -omega. :func:`~mrftcli.mrft.identify_lti.identify_lti` evaluates
these instead of a complex response and a forward-difference Jacobian: the same residuals (to
rounding), the exact Jacobian, and a few microseconds per evaluation where the general route's
Python and numpy call overhead cost 50-100 us (bench_families prints both routes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Protocol, Sequence, cast

import numpy as np
from numpy.typing import NDArray

from .model import Parameter

__all__ = ["LagChain", "LagChainKernel", "WeightedPoints", "wrap"]

FloatArray = NDArray[np.float64]


class LagChain(Protocol):
    """A plant ``K e^{-tau s} / (s^n prod_i (T_i s + 1))`` (the built-in process families)."""

    @property
    def parameters(self) -> dict[str, Parameter]: ...

    @property
    def lags(self) -> tuple[str, ...]: ...

    @property
    def integrators(self) -> int: ...


class WeightedPoints(Protocol):
    """Measured frequency-response points as arrays: omega [rad/s], ln gain [-], phase [rad], and the
    weights 1 / standard error of each."""

    @property
    def omega(self) -> FloatArray: ...

    @property
    def log_gain(self) -> FloatArray: ...

    @property
    def phase(self) -> FloatArray: ...

    @property
    def w_gain(self) -> FloatArray: ...

    @property
    def w_phase(self) -> FloatArray: ...


def wrap(x: FloatArray, low: float = -math.pi) -> FloatArray:
    """x modulo 2 pi into [low, low + 2 pi) (the phase residuals of the kernel and of the response-point fit)."""
    wrapped: FloatArray = np.mod(x - low, 2 * math.pi) + low
    return wrapped


@dataclass(frozen=True, eq=False)  # arrays: no field-wise == or hash
class LagChainKernel:
    """The weighted residuals of a lag chain against measured points, and their Jacobian.

    The residual vector is ``[(ln|G| - ln gain) w_gain, wrap(arg G - phase) w_phase]`` over the
    points, as a function of the solver's variables ``z`` (in the order ``unknown``: ln|K| for K,
    ln T for a time constant, tau [s] for the delay).

    Attributes
    ----------
    omega : ndarray
        The points' frequencies [rad/s].
    gain0, phase0 : ndarray
        The known part of the model's log-gain and phase minus the measured ones (the integrators,
        the known parameters, the sign of K) [-], [rad].
    weights : ndarray
        1 / standard error of the log-gains [-], then of the phases [1/rad].
    constant : ndarray
        The Jacobian's columns that do not depend on z (ln|K|: w_gain; tau: -omega w_phase), the
        lags' columns zero.
    lag_index : tuple of int
        The positions in ``z`` of ln T of each unknown lag.
    k_index, tau_index : int
        The positions of ln|K| and tau in ``z`` (-1 when known).
    """

    omega: FloatArray
    gain0: FloatArray
    phase0: FloatArray
    weights: FloatArray
    constant: FloatArray
    lag_index: tuple[int, ...]
    k_index: int
    tau_index: int

    @classmethod
    def of(cls, model: object, values: Mapping[str, float], unknown: Sequence[str], log_scaled: set[str],
           points: WeightedPoints) -> LagChainKernel | None:
        """The kernel for ``model``'s unknown parameters (``values``: every parameter's value, the
        known ones used), or None where the closed form does not apply (not a lag chain, or a time
        constant whose range reaches below zero and so is not on a log scale)."""
        # a structural check by attribute: isinstance on a runtime protocol costs more than the fit
        if not (hasattr(model, "lags") and hasattr(model, "integrators")):
            return None
        chain = cast(LagChain, model)
        if any(n not in ("K", "tau") and n not in log_scaled for n in unknown):
            return None
        gain0, phase0 = cls.known_part(chain, values, unknown, points.omega)
        m = points.omega.size
        k_index = unknown.index("K") if "K" in unknown else -1
        tau_index = unknown.index("tau") if "tau" in unknown else -1
        constant = np.zeros((2 * m, len(unknown)))
        if k_index >= 0:
            constant[:m, k_index] = points.w_gain
        if tau_index >= 0:
            constant[m:, tau_index] = -points.omega * points.w_phase
        return cls(points.omega, gain0 - points.log_gain, phase0 - points.phase,
                   np.concatenate([points.w_gain, points.w_phase]), constant,
                   tuple(unknown.index(n) for n in chain.lags if n in unknown), k_index, tau_index)

    @staticmethod
    def known_part(model: LagChain, values: Mapping[str, float], unknown: Sequence[str],
                   omega: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Log-gain and phase of the known factors: s^-n, the known lags and delay, K (its sign if unknown)."""
        k = values["K"]
        gain = -model.integrators * np.log(omega) + (0.0 if "K" in unknown else math.log(abs(k)))
        phase = np.full(omega.shape, -model.integrators * 0.5 * math.pi + (0.0 if k > 0 else math.pi))
        if "tau" not in unknown:
            phase = phase - values["tau"] * omega
        for n in model.lags:
            if n not in unknown:
                x = values[n] * omega
                gain = gain - 0.5 * np.log1p(x * x)
                phase = phase - np.arctan(x)
        return gain, phase

    def residuals(self, z: FloatArray) -> FloatArray:
        """The weighted residuals at ``z``."""
        return self.evaluate(z)[0]

    def evaluate(self, z: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The weighted residuals at ``z`` and their Jacobian d residuals / d z (shape (2 points, unknowns)), in
        one pass (they share each lag's T omega)."""
        zs = z.tolist()
        m = self.omega.size
        gain, phase, J = self.gain0, self.phase0, self.constant.copy()
        if self.k_index >= 0:
            gain = gain + zs[self.k_index]
        if self.tau_index >= 0:
            phase = phase - zs[self.tau_index] * self.omega
        for i in self.lag_index:  # a loop: one or two lags, cheaper than their 2-D arrays
            x = math.exp(zs[i]) * self.omega
            x2 = x * x
            gain = gain - 0.5 * np.log1p(x2)
            phase = phase - np.arctan(x)
            q = 1.0 / (1.0 + x2)
            J[:m, i] = (q - 1.0) * self.weights[:m]  # d ln|G| / d ln T = -x^2 / (1 + x^2)
            J[m:, i] = -x * q * self.weights[m:]  # d arg G / d ln T = -x / (1 + x^2)
        r: FloatArray = np.concatenate([gain, wrap(phase)]) * self.weights
        return r, J

    def lag_grid(self, values: FloatArray, index: NDArray[np.intp]) -> tuple[FloatArray, FloatArray]:
        """The log-gain and phase misfits with ln|K| and tau at 0 over a grid of the unknown time
        constants: row j of ``index`` picks each unknown lag's value (in the family's order) from
        ``values`` [s]; returns two arrays of shape (rows, points) [-], [rad] (the phase not wrapped).
        Each lag's terms are evaluated once per grid value, not once per row (a product grid repeats them).
        """
        gain = np.broadcast_to(self.gain0, (len(index), self.omega.size))
        phase = np.broadcast_to(self.phase0, gain.shape)
        if index.shape[1]:
            x = values[:, None] * self.omega
            half_log, angle = 0.5 * np.log1p(x * x), np.arctan(x)
            for k in range(index.shape[1]):
                gain = gain - half_log[index[:, k]]
                phase = phase - angle[index[:, k]]
        return gain, phase
