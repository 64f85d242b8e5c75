"""The per-cycle harmonic fit: one relay cycle's output as a line plus harmonics of the cycle frequency.

An MRFT limit cycle is periodic, so over one period P the output is a constant, a slow drift (a cycle
that is not exactly periodic: start-up, a sampled relay's jitter) and harmonics k = 1..H of
Omega = 2 pi / P. A least-squares projection onto those 2 H + 2 functions removes the sensor noise
(the residual *is* the noise whenever the output is a limit cycle of the relay) and gives the
complex harmonics Y_k with y ~ c + d x / P + sum_k Re(Y_k exp(j k Omega x)). The output of an
MRFT loop has a discontinuous third derivative, so its harmonics decay like k^-4: H = 7 or 8 leaves
a truncation error near 5e-4 of the amplitude.

Used by the segmenter (:mod:`mrftcli.segment.cycles`: extrema, switching levels, the fundamental
relative to the relay's) and by the diagnosis (:func:`mrftcli.diagnose.features.cycle_table`: the
per-cycle feature table).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["harmonic_basis", "HarmonicFit", "fit_harmonics"]


def harmonic_basis(x: np.ndarray, period: float, n_harmonics: int) -> np.ndarray:
    """Design matrix ``[1, x / P, cos(k Omega x) (k = 1..H), sin(k Omega x) (k = 1..H)]``: the trend
    column's coefficient is the drift per period, the constant the level at x = 0.

    Parameters
    ----------
    x : numpy.ndarray
        Time from the fit's origin [s] (1-D).
    period : float
        The cycle period P [s]; Omega = 2 pi / P.
    n_harmonics : int
        H, the highest harmonic.

    Returns
    -------
    numpy.ndarray
        Shape (x.size, 2 H + 2).

    Examples
    --------
    >>> harmonic_basis(np.array([0.0, 0.25]), 1.0, 1).round(12).tolist()
    [[1.0, 0.0, 1.0, 0.0], [1.0, 0.25, 0.0, 1.0]]
    """
    x = np.asarray(x, dtype=float)
    w = 2.0 * np.pi / period
    k = np.arange(1, n_harmonics + 1)
    a = np.outer(x, k) * w
    return np.column_stack([np.ones(x.size), x / period, np.cos(a), np.sin(a)])


@dataclass(frozen=True, eq=False)
class HarmonicFit:
    """A least-squares fit of :func:`harmonic_basis` to one cycle's samples.

    Attributes
    ----------
    period : float
        P [s].
    n_harmonics : int
        H.
    coef : numpy.ndarray
        ``[c, d, a_1..a_H, b_1..b_H]``: the level at x = 0 and the drift per period [output units],
        cosine and sine coefficients [output units].
    residual : numpy.ndarray
        Samples minus the fit [output units], one per sample fitted.
    """

    period: float
    n_harmonics: int
    coef: np.ndarray
    residual: np.ndarray

    @property
    def harmonics(self) -> np.ndarray:
        """Y_k = a_k - j b_k, k = 1..H (so y ~ sum_k Re(Y_k exp(j k Omega x))) [output units]."""
        H = self.n_harmonics
        return self.coef[2: 2 + H] - 1j * self.coef[2 + H:]

    def __call__(self, x: np.ndarray | float) -> np.ndarray:
        """The fitted output at times ``x`` from the origin [s] (periodic part plus trend)."""
        xq = np.atleast_1d(np.asarray(x, float))
        y: np.ndarray = harmonic_basis(xq, self.period, self.n_harmonics) @ self.coef
        return y


def fit_harmonics(x: np.ndarray, y: np.ndarray, period: float, n_harmonics: int) -> HarmonicFit:
    """Project samples of one cycle onto a line plus harmonics 1..H of 1 / ``period``.

    The caller picks the samples (the cycle, or a period-long window centred where the fit is used)
    and the origin of ``x``; it should pass at least 2 (2 H + 2) samples.

    Parameters
    ----------
    x : numpy.ndarray
        Sample times from the origin [s].
    y : numpy.ndarray
        Output samples [output units].
    period : float
        P [s].
    n_harmonics : int
        H.

    Returns
    -------
    HarmonicFit

    Examples
    --------
    >>> P = 0.5
    >>> x = np.arange(100) * P / 100
    >>> fit = fit_harmonics(x, 1.0 + 2.0 * np.cos(2 * np.pi * x / P), P, 3)
    >>> bool(np.allclose(fit.harmonics, [2, 0, 0])), round(float(fit.coef[0]), 9)
    (True, 1.0)
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    A = harmonic_basis(x, period, n_harmonics)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    return HarmonicFit(period=float(period), n_harmonics=int(n_harmonics), coef=coef,
                       residual=y - A @ coef)
