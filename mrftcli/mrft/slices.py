"""The tests' UFM slices in real units and where they meet: the point and Monte Carlo solvers of :func:`identify`.

Each MRFT test i (beta_i, measured Omega_i) constrains eq. (2) to one curve, its UFM slice at the
known ``tp_n = Tp Omega_i`` scaled back to real units (Lemma 3):

    tau_i(Td) = theta_{beta_i}(Tp Omega_i, Td Omega_i) / Omega_i .

:func:`intersection` finds where two curves meet (paper Section IV, Fig. 5), :func:`least_squares`
fits three or more in log-frequency, and :func:`intersection_draws` solves many Monte Carlo draws
of two tests at once. The shipped manifolds only bracket a solution; it is polished with the exact
closed form of :mod:`mrftcli.mrft.lprs`, so grid interpolation never limits the accuracy.

Units: times in seconds, ``omega`` in rad/s.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize

from ..errors import IdentificationError
from .lprs import unit_cycle, unit_cycle_scalar
from .ufm import ManifoldSet, load_manifolds

__all__ = ["tau_curve", "intersection", "least_squares", "frequency_sensitivity", "intersection_draws"]

_TWO_PI = 2.0 * math.pi
FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------------------------
# the curves tau_i(Td)
# ----------------------------------------------------------------------------------------------
def tau_curve(Tp: float, beta: float, omega: ArrayLike, Td: ArrayLike, exact: bool = True,
              manifolds: ManifoldSet | None = None) -> np.ndarray:
    """Signed delay tau [s] that makes (Tp, Td, tau) oscillate at omega [rad/s] under beta.

    Vectorised over ``omega`` and ``Td`` (broadcast).  ``exact=False`` interpolates the manifolds
    (NaN outside their grid).  Negative values: no physical plant (kept for root bracketing).
    """
    omega = np.asarray(omega, dtype=float)
    Td = np.asarray(Td, dtype=float)
    if exact:
        theta, _ = unit_cycle(Tp * omega, Td * omega, beta)
    else:
        ms = manifolds if manifolds is not None else load_manifolds()
        theta, _ = ms.evaluate(beta, Tp * omega, Td * omega)
    tau: FloatArray = theta / omega
    return tau


# ----------------------------------------------------------------------------------------------
# point solvers (scalar, exact)
# ----------------------------------------------------------------------------------------------
class _Curve:
    """Exact scalar tau_i(Td) for one test, with warm-started Newton iterations."""

    def __init__(self, Tp: float, beta: float, omega: float) -> None:
        self.Tp, self.beta, self.omega = Tp, beta, omega
        self.warm: list[float] = []

    def tau(self, Td: float) -> float:
        w = self.omega
        theta, _ = unit_cycle_scalar(self.Tp * w, Td * w, self.beta, self.warm)
        return theta / w


def _td_range(ms: ManifoldSet, omegas: Sequence[float]) -> tuple[float, float]:
    """Range of Td [s] covered by the manifold grid for every test."""
    lo = max(ms.td_n[0] / w for w in omegas)
    hi = min(ms.td_n[-1] / w for w in omegas)
    return lo, hi


def _bracket_grid(ms: ManifoldSet, Tp: float, betas: Sequence[float], omegas: Sequence[float],
                  n: int = 96) -> tuple[FloatArray, FloatArray]:
    """Td [s] on a log grid over the manifolds' range, and each test's curve tau_i [s] on it."""
    lo, hi = _td_range(ms, omegas)
    if not lo < hi:
        raise IdentificationError("the tests' frequencies are too far apart for the manifold range")
    Td = np.geomspace(lo, hi, n)
    taus = []
    for b, w in zip(betas, omegas):
        tp = Tp * w
        exact = not (ms.tp_n[0] <= tp <= ms.tp_n[-1])
        taus.append(tau_curve(Tp, b, w, Td, exact=exact or not ms.covers(b), manifolds=ms))
    return Td, np.array(taus)


def intersection(Tp: float, betas: Sequence[float], omegas: Sequence[float], ms: ManifoldSet) -> tuple[float, float, list[str]]:
    """Exact intersection of two curves tau_1(Td) = tau_2(Td); returns Td, tau, warnings."""
    warns: list[str] = []
    Td, taus = _bracket_grid(ms, Tp, betas, omegas)
    D = taus[0] - taus[1]
    ok = np.isfinite(D)
    s = np.sign(D)
    idx = np.nonzero(ok[:-1] & ok[1:] & (s[:-1] * s[1:] <= 0) & (s[:-1] != s[1:]))[0]
    if idx.size == 0:
        for b, w, row in zip(betas, omegas, taus):
            if np.all(~(row >= 0)):
                raise IdentificationError(
                    f"{w / _TWO_PI:.4g} Hz at beta {b:g} is too fast for Tp = {Tp:g} s: no plant of eq. (2) with "
                    "a non-negative delay oscillates there (check Tp and the frequency units, Hz)"
                )
        raise IdentificationError(
            f"the UFM slices of the tests (beta {betas[0]:g} at {omegas[0] / _TWO_PI:.4g} Hz, beta {betas[1]:g} at "
            f"{omegas[1] / _TWO_PI:.4g} Hz) do not intersect for Tp = {Tp:g} s: no plant of eq. (2) produces both "
            "frequencies (check Tp, the betas and the frequencies; a more negative beta must give a higher frequency)"
        )
    # prefer an intersection with a physical (non-negative) delay
    mids = 0.5 * (taus[0, idx] + taus[0, idx + 1])
    phys = idx[mids >= -1e-12]
    k = int(phys[0]) if phys.size else int(idx[0])
    if phys.size > 1:
        warns.append(f"the slices intersect {phys.size} times; the smallest Td was taken")
    c1, c2 = _Curve(Tp, betas[0], omegas[0]), _Curve(Tp, betas[1], omegas[1])
    x_lo, x_hi = math.log(Td[k]), math.log(Td[k + 1])

    def d(x: float) -> float:
        t = math.exp(x)
        return c1.tau(t) - c2.tau(t)

    f_lo, f_hi = d(x_lo), d(x_hi)
    if f_lo == 0:
        x = x_lo
    elif f_hi == 0:
        x = x_hi
    elif f_lo * f_hi > 0:
        # interpolation error moved the crossing (nearly parallel curves): scan the exact curves
        xs = np.linspace(math.log(Td[0]), math.log(Td[-1]), 4 * Td.size)
        ds = (tau_curve(Tp, betas[0], omegas[0], np.exp(xs)) - tau_curve(Tp, betas[1], omegas[1], np.exp(xs)))
        ch = np.nonzero((np.sign(ds[:-1]) * np.sign(ds[1:]) <= 0)
                        & (tau_curve(Tp, betas[0], omegas[0], np.exp(xs[:-1])) >= -1e-12))[0]
        if ch.size == 0:
            raise IdentificationError(
                "the UFM slices of the tests only touch (nearly parallel curves): Td and tau cannot be "
                "separated with these betas; use betas further apart"
            )
        x = optimize.brentq(d, xs[ch[0]], xs[ch[0] + 1], xtol=1e-11, rtol=1e-12)
    else:
        x = optimize.brentq(d, x_lo, x_hi, xtol=1e-11, rtol=1e-12)
    Td_hat = math.exp(x)
    return Td_hat, c1.tau(Td_hat), warns


def _frequency_gap(Tp: float, tau: float, beta: float, warm: list[float] | None = None) -> Callable[[float, float], float]:
    """F(ln Omega, Td) = theta(Tp Omega, Td Omega) - tau Omega of one test: zero at the model's frequency."""
    def F(lw: float, Td: float) -> float:
        ww = math.exp(lw)
        return unit_cycle_scalar(Tp * ww, Td * ww, beta, warm)[0] - tau * ww

    return F


def log_freq_residuals(Tp: float, Td: float, tau: float, betas: Sequence[float], omegas: Sequence[float],
                       eps: float = 1e-5) -> FloatArray:
    """First-order log-frequency residuals ln(Omega_model / Omega_measured) of each test.

    F_i(Omega) (:func:`_frequency_gap`) vanishes at the model's frequency, so
    ln Omega_model - ln Omega_i ~= -F_i(Omega_i) / (dF_i / d ln Omega).
    """
    r = np.empty(len(betas))
    for i, (b, w) in enumerate(zip(betas, omegas)):
        F, lw = _frequency_gap(Tp, tau, b), math.log(w)
        dF = (F(lw + eps, Td) - F(lw - eps, Td)) / (2 * eps)
        r[i] = -F(lw, Td) / dF if dF != 0 else np.inf
    return r


def frequency_sensitivity(Tp: float, Td: float, tau: float, beta: float, omega: float,
                          eps: float = 1e-6) -> tuple[float, float]:
    """d ln Omega / d ln Td and d ln Omega / d tau [1/s] at the model point (implicit function).

    F(ln Omega, ln Td) (:func:`_frequency_gap`); dlnOmega/dlnTd = -F_lnTd / F_lnOmega,
    dlnOmega/dtau = Omega / F_lnOmega.  Central differences; the shared warm start keeps each
    evaluation to two or three Newton steps.
    """
    F = _frequency_gap(Tp, tau, beta, [])
    lw, lTd = math.log(omega), math.log(Td)
    dF_dlw = (F(lw + eps, math.exp(lTd)) - F(lw - eps, math.exp(lTd))) / (2 * eps)
    dF_dlTd = (F(lw, math.exp(lTd + eps)) - F(lw, math.exp(lTd - eps))) / (2 * eps)
    return -dF_dlTd / dF_dlw, omega / dF_dlw


def least_squares(Tp: float, betas: Sequence[float], omegas: Sequence[float], weights: FloatArray,
                  ms: ManifoldSet) -> tuple[float, float, float, list[str]]:
    """Weighted least squares over (ln Td, tau) for three or more tests."""
    warns: list[str] = []
    # start: intersection of the two tests with the most different betas
    i0, i1 = int(np.argmin(betas)), int(np.argmax(betas))
    try:
        Td0, tau0, _ = intersection(Tp, [betas[i0], betas[i1]], [omegas[i0], omegas[i1]], ms)
    except IdentificationError:
        Td0, tau0 = 1.0 / float(np.median(omegas)), 0.1 / float(np.median(omegas))
    sw = np.sqrt(weights)

    def res(p: FloatArray) -> FloatArray:
        r: FloatArray = sw * log_freq_residuals(Tp, math.exp(p[0]), p[1], betas, omegas)
        return r

    sol = optimize.least_squares(res, x0=[math.log(Td0), tau0], x_scale=[1.0, max(tau0, 1e-3)], method="lm",
                                 xtol=1e-12, ftol=1e-12)
    Td_hat, tau_hat = math.exp(sol.x[0]), float(sol.x[1])
    r = log_freq_residuals(Tp, Td_hat, tau_hat, betas, omegas)
    rms = float(math.sqrt(np.sum(weights * r * r) / np.sum(weights)))
    return Td_hat, tau_hat, rms, warns


# ----------------------------------------------------------------------------------------------
# vectorised solver for Monte Carlo draws (two tests)
# ----------------------------------------------------------------------------------------------
def intersection_draws(Tp: float, betas: Sequence[float], omega_draws: np.ndarray, ms: ManifoldSet, Td_ref: float,
                        iters: int = 40, lags: np.ndarray | None = None) -> np.ndarray:
    """Td for each row of omega_draws (M, 2); NaN where the draws' slices do not intersect.

    ``lags`` (M, 2) [s], optional: per-test extra delay of each draw (the sampled relay's switching
    lag); curve i becomes tau_i(Td) - lag_i.

    Bracket on a log grid around the point estimate (interpolated manifolds, exact outside their
    range), then the Illinois variant of regula falsi on the exact closed form, vectorised over the
    draws.
    """
    M = omega_draws.shape[0]
    if lags is None:
        lags = np.zeros((M, 2))
    grid = Td_ref * np.geomspace(1e-2, 1e2, 49)
    taus = [_draw_curves(Tp, betas[i], omega_draws[:, i : i + 1], grid, ms) - lags[:, i : i + 1] for i in range(2)]
    s = np.sign(taus[0] - taus[1])
    change = (s[:, :-1] * s[:, 1:] < 0) & (taus[0][:, :-1] >= -1e-12)
    k = np.argmax(change, axis=1)
    rows = np.nonzero(change.any(axis=1))[0]
    out = np.full(M, np.nan)
    if rows.size == 0:
        return out
    w1, w2 = omega_draws[rows, 0], omega_draws[rows, 1]
    l1, l2 = lags[rows, 0], lags[rows, 1]

    def d(x: FloatArray) -> FloatArray:
        t = np.exp(x)
        th1, _ = unit_cycle(Tp * w1, t * w1, betas[0])
        th2, _ = unit_cycle(Tp * w2, t * w2, betas[1])
        gap: FloatArray = (th1 / w1 - l1) - (th2 / w2 - l2)
        return gap

    x_lo, x_hi = np.log(grid[k]), np.log(grid[np.minimum(k + 1, grid.size - 1)])
    out[rows] = np.exp(_illinois(d, x_lo[rows], x_hi[rows], iters))
    return out


def _draw_curves(Tp: float, beta: float, w: FloatArray, grid: FloatArray, ms: ManifoldSet) -> FloatArray:
    """Each draw's curve tau(Td) [s] on the Td grid [s], (M, grid.size), for draws ``w`` (M, 1) [rad/s]:
    interpolated manifolds where they cover the draws, the exact closed form elsewhere."""
    tp = Tp * w
    td = grid[None, :] * w
    covered = ms.covers(beta) and np.all((tp >= ms.tp_n[0]) & (tp <= ms.tp_n[-1]))
    if covered:
        th, _ = ms.evaluate(beta, np.broadcast_to(tp, td.shape), td)
        bad = ~np.isfinite(th)
        if np.any(bad):
            th_ex, _ = unit_cycle(np.broadcast_to(tp, td.shape)[bad], td[bad], beta)
            th[bad] = th_ex
    else:
        th, _ = unit_cycle(np.broadcast_to(tp, td.shape), td, beta)
    tau: FloatArray = th / w
    return tau


def _illinois(d: Callable[[FloatArray], FloatArray], a: FloatArray, b: FloatArray, iters: int) -> FloatArray:
    """Roots of ``d`` bracketed by [a, b] elementwise: the Illinois variant of regula falsi."""
    fa, fb = d(a), d(b)
    side = np.zeros(a.size)
    c_prev = np.full(a.size, np.inf)
    c = c_prev
    for _ in range(iters):
        c = (a * fb - b * fa) / (fb - fa)
        c = np.where(np.isfinite(c), c, 0.5 * (a + b))
        if np.all(np.abs(c - c_prev) < 1e-11):
            break
        c_prev = c
        fc = d(c)
        left = fc * fa > 0  # root in [c, b]
        # Illinois: halve the retained end's value when the same side is kept twice
        a_new = np.where(left, c, a)
        fa_new = np.where(left, fc, np.where(side == -1, 0.5 * fa, fa))
        b_new = np.where(left, b, c)
        fb_new = np.where(left, np.where(side == 1, 0.5 * fb, fb), fc)
        side = np.where(left, 1, -1)
        a, b, fa, fb = a_new, b_new, fa_new, fb_new
    return c
