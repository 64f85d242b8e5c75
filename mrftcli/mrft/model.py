"""The loop model of the paper, eq. (2):

    G(s) = K Td e^{-tau s} / (s (Tp s + 1) (Td s + 1))

Tp is the propulsion time constant [s] (known from a bench test), Td the drag time constant [s],
tau the loop's transport delay [s] and K the gain [output units / (command unit * s^2)], so that
K Td is the static gain from command to output rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["LoopModel"]


@dataclass(frozen=True)
class LoopModel:
    """Parameters of G(s) = K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1)).

    Attributes
    ----------
    Tp : float
        Propulsion time constant [s], > 0.
    Td : float
        Drag (aerodynamic) time constant [s], > 0.
    tau : float
        Transport delay [s], >= 0.
    K : float
        Gain; K * Td is the static gain from command to output rate. Default 1.

    Examples
    --------
    >>> G = LoopModel(Tp=0.1, Td=0.7042, tau=0.06, K=1.42)
    >>> round(abs(complex(G.frequency_response(4.4337))), 4)
    0.0629
    >>> LoopModel(Tp=0.1, Td=-1.0, tau=0.06)
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: Td must be a positive time in seconds, got -1.0
    """

    Tp: float
    Td: float
    tau: float
    K: float = 1.0

    def __post_init__(self) -> None:
        for name in ("Tp", "Td"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"{name} must be a positive time in seconds, got {value!r}")
        if not np.isfinite(self.tau) or self.tau < 0:
            raise InputError(f"tau must be a non-negative time in seconds, got {self.tau!r}")
        if not np.isfinite(self.K) or self.K == 0:
            raise InputError(f"K must be finite and non-zero, got {self.K!r}")

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Delay-free realisation (A, B, C) with states [y, y', thrust/moment state].

        x1 = y, x2 = y' (rate), x3 = propulsion output; u enters x3 (delayed by tau, handled by the
        caller):  x1' = x2;  x2' = (-x2 + K Td x3) / Td;  x3' = (-x3 + u) / Tp.
        """
        A = np.array(
            [
                [0.0, 1.0, 0.0],
                [0.0, -1.0 / self.Td, self.K],
                [0.0, 0.0, -1.0 / self.Tp],
            ]
        )
        B = np.array([0.0, 0.0, 1.0 / self.Tp])
        C = np.array([1.0, 0.0, 0.0])
        return A, B, C

    def frequency_response(self, omega: np.ndarray | float) -> np.ndarray:
        """G(j omega) including the delay; omega in rad/s."""
        s = 1j * np.asarray(omega, dtype=float)
        return self.K * self.Td * np.exp(-self.tau * s) / (s * (self.Tp * s + 1) * (self.Td * s + 1))
