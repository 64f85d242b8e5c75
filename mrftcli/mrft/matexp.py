"""Matrix exponentials of the small matrices of the limit-cycle search (the LPRS of a state space).

scipy's ``expm`` spends ~10 ms on a 3x3 matrix in its dispatch; the continuous limit-cycle search of
:func:`mrftcli.mrft.lprs.lti_limit_cycle` needs hundreds of them.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["phi_gamma_small"]

FloatArray = NDArray[np.float64]


def expm_small(M: FloatArray) -> FloatArray:
    """e^M of a small matrix: scaling and squaring with a degree-14 Taylor polynomial.

    scipy's expm costs ~10 ms on a 3x3 matrix (its dispatch, not the arithmetic); the limit-cycle
    search needs hundreds. With ||M / 2^s|| <= 1/2 the truncation error is below 1e-16 relative.
    """
    norm = float(np.max(np.sum(np.abs(M), axis=1)))
    s = max(0, int(math.ceil(math.log2(norm))) + 1) if norm > 0 else 0
    X = M / 2.0 ** s
    E = np.eye(M.shape[0])
    term = np.eye(M.shape[0])
    for k in range(1, 15):
        term = term @ X / k
        E = E + term
    for _ in range(s):
        E = E @ E
    return E


def phi_gamma_small(A: FloatArray, B: FloatArray, t: float) -> tuple[FloatArray, FloatArray]:
    """:func:`mrftcli.mrft.lprs` ``_phi_gamma`` with :func:`expm_small` (the continuous limit-cycle search)."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A * t
    M[:n, n] = B * t
    E = expm_small(M)
    return E[:n, :n], E[:n, n]
