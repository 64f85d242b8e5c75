"""The simulator's plant: whole control periods by superposition and the static command shaper.

The exact propagators, the RK4 steps, the actuator between ticks and the jittered delay live in
:mod:`mrftcli.mrft.propagate` (the diagnosis integrates with them too, and must not import the
simulator, its tests' oracle). See docs/simulator.md, "Integration".
"""

from __future__ import annotations

import math

import numpy as np

from ..mrft.propagate import taylor_expm

__all__ = ["PeriodPropagator", "command_shaper"]


# --------------------------------------------------------------------------------------------------
# whole periods by superposition


class PeriodPropagator:
    """One control period of the linear plant with an input made of polynomial segments.

    x(T) = Phi(T) x(0) + sum over segments of the responses to the segment's input. A segment on
    [o, o + L) with w = c0 + c1 s + c2 s^2 / 2 (s from o) is a step c0, a ramp c1 and a parabola c2
    starting at o, minus the step/ramp/parabola that continue its end values from o + L, so only the
    responses at T to inputs starting at o are needed:

        Gamma_j(h) = int_0^h e^{A (h - s)} B s^j / j! ds = sum_k A^k B h^(k+j+1) / (k+j+1)!,

    evaluated for all segment ends of the period in one matrix product (h <= T and ||A|| T <= 2,
    checked by the caller, so the series converges to rounding in about 30 terms).
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, T: float) -> None:
        n = A.shape[0]
        self.n = n
        self.T = T
        rho = float(np.abs(A).sum(axis=0).max()) * T
        terms, err = 1, rho
        while err > 1e-18 and terms < 80:
            terms += 1
            err *= rho / terms
        m = terms + 3
        G = np.zeros((m, 3 * n))  # powers h^1 .. h^m  ->  [Gamma_0 | Gamma_1 | Gamma_2]
        v = B.astype(float).copy()
        for k in range(terms):
            for j in range(3):
                G[k + j, j * n : (j + 1) * n] = v / math.factorial(k + j + 1)
            v = A @ v
        self._G = G
        self._exponents = np.arange(1, m + 1)
        self.Phi = taylor_expm(A * T)

    def advance(self, x: np.ndarray, segments: list[tuple[float, float, float, float, float]]) -> np.ndarray:
        """x at the end of the period; ``segments`` = (start offset, length, c0, c1, c2)."""
        T = self.T
        starts = np.array([T - seg[0] for seg in segments])
        ends = np.array([T - seg[0] - seg[1] for seg in segments])
        h = np.concatenate([starts, np.maximum(ends, 0.0)])
        gam = (h[:, None] ** self._exponents) @ self._G  # (2 * segments, 3 n)
        coef = np.empty((h.size, 3))
        for i, (_, L, c0, c1, c2) in enumerate(segments):
            coef[i] = (c0, c1, c2)
            coef[len(segments) + i] = (-(c0 + c1 * L + 0.5 * c2 * L * L), -(c1 + c2 * L), -c2)
        n = self.n
        resp = (coef[:, 0:1] * gam[:, :n] + coef[:, 1:2] * gam[:, n : 2 * n] + coef[:, 2:3] * gam[:, 2 * n :]).sum(axis=0)
        return self.Phi @ x + resp


def command_shaper(bias: float, asymmetric_gain: float = 0.0, saturation: float = 0.0, dead_zone: float = 0.0):
    """The static command nonlinearity between the controller and the actuator, or None (identity).

    Deviations d = u - bias from the trim: a dead band |d| <= ``dead_zone`` gives nothing (ESC dead
    band, stiction), beyond it the command moves by |d| - dead_zone; the plant then responds with
    gain 1 + ``asymmetric_gain`` to positive and 1 - ``asymmetric_gain`` to negative deviations; the
    result is clipped at the absolute command ``saturation`` (0: no limit).

    >>> f = command_shaper(0.5, asymmetric_gain=0.1, dead_zone=0.01, saturation=0.58)
    >>> [round(f(u), 4) for u in (0.4, 0.5, 0.505, 0.56, 0.7)]
    [0.419, 0.5, 0.5, 0.555, 0.58]
    """
    if asymmetric_gain == 0.0 and saturation == 0.0 and dead_zone == 0.0:
        return None

    def shape(u: float) -> float:
        d = u - bias
        if dead_zone > 0.0:
            d = math.copysign(max(abs(d) - dead_zone, 0.0), d)
        d *= (1.0 + asymmetric_gain) if d > 0 else (1.0 - asymmetric_gain)
        v = bias + d
        return min(v, saturation) if saturation > 0.0 else v

    return shape
