"""Boiko's locus of a perturbed relay system J(omega) in closed form: the tests' independent oracle.

The library computes limit cycles from the exact periodic solution (``mrftcli.mrft.lprs``); these
closed forms (``checks.md`` section 3) and the series definition are a second route the tests check
it against. Units: ``omega`` in rad/s, times in seconds.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mrftcli.mrft.model import LoopModel

#: the relative split at which Tp == Td is evaluated (a double pole, as the library's unit cycle does)
_SPLIT = 2e-4


def _as_state_space(A: ArrayLike, B: ArrayLike, C: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.atleast_2d(np.asarray(A, float)), np.asarray(B, float).ravel(), np.asarray(C, float).ravel()


def lprs_integrator(omega: ArrayLike, K: complex = 1.0, tau: float = 0.0) -> np.ndarray:
    """LPRS of W = K e^{-tau s}/s (Boiko), valid for 0 <= omega tau < pi:
    J = -K tau/2 - j (pi K / (8 omega)) (pi - 2 omega tau)."""
    omega = np.asarray(omega, dtype=float)
    return -K * tau / 2 - 1j * (np.pi * K / (8 * omega)) * (np.pi - 2 * omega * tau)


def lprs_first_order(omega: ArrayLike, K: complex, T: complex, tau: float = 0.0) -> np.ndarray:
    """LPRS of W = K e^{-tau s}/(T s + 1) (Boiko), valid for tau < pi/omega.

    J = 0.5 K (1 - alpha e^gamma csch alpha) - j (pi/4) K (1 - 2 e^gamma / (1 + e^alpha)),
    alpha = pi/(T omega), gamma = tau/T.  Analytic in (K, T): complex-conjugate pairs of a partial
    fraction expansion may be passed term by term and summed.
    """
    omega = np.asarray(omega, dtype=float)
    alpha = np.pi / (T * omega)
    gamma = tau / T
    # e^gamma / sinh(alpha) = 2 e^{gamma - alpha} / (1 - e^{-2 alpha}); stable for large alpha
    re = 0.5 * K * (1 - alpha * 2 * np.exp(gamma - alpha) / (-np.expm1(-2 * alpha)))
    im = -(np.pi / 4) * K * (1 - 2 * np.exp(gamma - alpha) / (1 + np.exp(-alpha)))
    J: NDArray[np.complex128] = re + 1j * im
    return J


def lprs_soiptd(omega: ArrayLike, model: LoopModel) -> np.ndarray:
    """LPRS of eq. (2) by additivity over partial fractions (checks.md section 3)."""
    Tp, Td = model.Tp, model.Td
    if abs(Tp - Td) < _SPLIT * 0.5 * (Tp + Td):
        m = 0.5 * (Tp + Td)
        Tp, Td = m * (1 + 0.5 * _SPLIT), m * (1 - 0.5 * _SPLIT)
    g = model.K * model.Td
    J: NDArray[np.complex128] = g * (
        lprs_integrator(omega, 1.0, model.tau)
        + lprs_first_order(omega, -Tp * Tp / (Tp - Td), Tp, model.tau)
        + lprs_first_order(omega, Td * Td / (Tp - Td), Td, model.tau)
    )
    return J


def lprs_state_space(omega: ArrayLike, A: ArrayLike, B: ArrayLike, C: ArrayLike, tau: float = 0.0) -> np.ndarray:
    """LPRS of C (sI - A)^{-1} B e^{-tau s} in closed form via the modal (partial-fraction) expansion.

    Each simple pole lambda != 0 with residue r is a first-order term K = -r/lambda, T = -1/lambda
    (complex allowed); a simple pole at 0 is an integrator with gain r.  Requires A diagonalisable
    with at most a simple pole at the origin.
    """
    A, B, C = _as_state_space(A, B, C)
    lam, V = np.linalg.eig(A)
    cv = C @ V
    wb = np.linalg.solve(V, B)
    res = cv * wb
    out = np.zeros(np.shape(omega), dtype=complex)
    for lam_i, r_i in zip(lam, res):
        if abs(lam_i) < 1e-12:
            out = out + lprs_integrator(omega, r_i, tau)
        else:
            out = out + lprs_first_order(omega, -r_i / lam_i, -1.0 / lam_i, tau)
    return out


def lprs_series(omega: float, W: Callable[[np.ndarray], np.ndarray], n_terms: int = 200_000) -> complex:
    """LPRS from its series definition (Boiko):
    J(w) = sum_k (-1)^(k+1) Re W(j k w) + j sum_k Im W(j (2k-1) w) / (2k-1).

    ``W`` is a callable of the complex argument s.  The alternating real series is summed with the
    mean of two consecutive partial sums (error O(1/N^2)); the imaginary series converges like 1/N.
    """
    k = np.arange(1, n_terms + 1, dtype=float)
    re_terms = ((-1.0) ** (k + 1)) * np.real(W(1j * k * omega))
    partial = np.cumsum(re_terms)
    re = 0.5 * (partial[-1] + partial[-2])
    odd = 2 * k - 1
    im = np.sum(np.imag(W(1j * odd * omega)) / odd)
    return complex(re, im)
