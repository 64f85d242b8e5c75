"""The cascaded plant, exactly, at the controller rate: the per-tick maps, frequency responses, stability.

The continuous plant has five states, x = [alpha, alpha', p, y, y'] (alpha the attitude in the
output's direction, p the propulsion state of eq. (2), y the position):

    alpha'' = -alpha'/Td_i + K_i p,   p' = (w(t) - p) / Tp,   y'' = g alpha - y'/Td,

driven by the inner command w(t): the command u_k of tick k held (zero-order hold) and delayed by
the inner tau = m T + f. The position is measured tau_y late: y(t_k - tau_y). A control period
splits at f and at the position's sampling offset; each piece is propagated exactly with the
exponential of the augmented matrix [[A, B], [0, 0]] (:func:`mrftcli.mrft.propagate.phi_gamma`), so
:class:`CascadePlant` holds a few constant affine maps, shared by the flight and by the discrete
transfer functions below (the truth of ``bench_cascade``: what a designed outer controller actually
achieves on the cascade the simulator flies).

This module shares nothing with :mod:`mrftcli.mrft.cascade` (the identification's model): the
simulator is its oracle.
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import optimize
from numpy.typing import NDArray

from ..mrft.model import LoopModel
from .cascade_spec import InnerGains
from ..mrft.propagate import phi_gamma

__all__ = ["CascadePlant", "Segment", "cascade_plant", "controller_response", "outer_plant_response",
           "outer_phase_margin", "closed_loop_radius", "OuterMargin"]

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]


@dataclass(frozen=True)
class Segment:
    """One piece of a control period: x <- Phi x + Gamma u, u the older (0) or newer (1) command."""

    Phi: Array
    Gamma: Array
    newer: bool
    sample_y_before: bool


@dataclass(frozen=True)
class CascadePlant:
    """The continuous cascade and its exact per-period maps.

    Attributes
    ----------
    A, B : ndarray
        The five-state realisation above (B: the inner command).
    T : float
        Controller period [s].
    m_in : int
        Whole periods in the inner delay; the command of tick k acts from t_{k+m} + f.
    f_in : float
        The rest of the inner delay [s], in [0, T).
    n_y : int
        The position measured at tick k is sampled in period k - n_y (>= 0).
    s_y : float
        ... at offset s_y [s] into that period (tau_y = n_y T - s_y).
    segments : tuple of Segment
        The period's pieces in time order.
    """

    A: Array
    B: Array
    T: float
    m_in: int
    f_in: float
    n_y: int
    s_y: float
    segments: tuple[Segment, ...]

    def period_maps(self) -> tuple[Array, Array, Array, Array, Array, Array]:
        """(Phi, Ga, Gb, Ms, Sa, Sb): x_{k+1} = Phi x_k + Ga u_{k-m-1} + Gb u_{k-m}; the state at the
        position's sampling offset is Ms x_k + Sa u_{k-m-1} + Sb u_{k-m}."""
        n = self.A.shape[0]
        M, Ga, Gb = np.eye(n), np.zeros(n), np.zeros(n)
        Ms, Sa, Sb = M, Ga, Gb
        for seg in self.segments:
            if seg.sample_y_before:
                Ms, Sa, Sb = M.copy(), Ga.copy(), Gb.copy()
            M = seg.Phi @ M
            Ga = seg.Phi @ Ga + (0.0 if seg.newer else seg.Gamma)
            Gb = seg.Phi @ Gb + (seg.Gamma if seg.newer else 0.0)
        return M, Ga, Gb, Ms, Sa, Sb


def cascade_plant(inner: LoopModel, Td: float, tau: float, rate_hz: float, g: float) -> CascadePlant:
    """The cascade's five-state plant and its exact per-period pieces.

    Parameters
    ----------
    inner : LoopModel
        The attitude plant (eq. (2), output in rad).
    Td : float
        Outer drag time constant [s].
    tau : float
        Position measurement delay [s].
    rate_hz : float
        Controller rate [Hz].
    g : float
        Gravity [m/s^2].
    """
    A3, B3, _ = inner.state_space()
    A = np.zeros((5, 5))
    A[:3, :3] = A3
    A[3, 4] = 1.0
    A[4, 0] = g
    A[4, 4] = -1.0 / Td
    B = np.zeros(5)
    B[:3] = B3
    T = 1.0 / rate_hz
    m_in = int(math.floor(inner.tau / T + 1e-9))
    f_in = inner.tau - m_in * T
    if f_in < 1e-9 * T:
        f_in = 0.0
    n_y = int(math.ceil(tau / T - 1e-9))
    s_y = n_y * T - tau
    if s_y < 1e-9 * T:
        s_y = 0.0
    cuts = sorted({0.0, f_in, s_y, T})
    segments = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        Phi, Gamma = phi_gamma(A, B, b - a)
        segments.append(Segment(Phi, Gamma, newer=a >= f_in, sample_y_before=a == s_y))
    return CascadePlant(A, B, T, m_in, f_in, n_y, s_y, tuple(segments))


# --------------------------------------------------------------------------------------------------
# discrete transfer functions (z = e^{j omega T})


def controller_response(gains: InnerGains, omega: Array) -> tuple[CArray, CArray]:
    """(Ce, D) of a generic-form controller at z = e^{j omega T}: Ce = Kp + Ki T z/(z-1) on the error,
    D = Kd (z-1)/((Tf+T) z - Tf) on the measurement (its command is Ce e - D y)."""
    T = 1.0 / gains.rate_hz
    z = np.exp(1j * np.asarray(omega, float) * T)
    ce = gains.Kp + gains.Ki * T * z / (z - 1.0)
    d = gains.Kd * (z - 1.0) / ((gains.Tf + T) * z - gains.Tf)
    return np.asarray(ce, complex), np.asarray(d, complex)


def _plant_responses(plant: CascadePlant, omega: Array) -> tuple[CArray, CArray]:
    """(P_alpha, P_y): inner command -> sampled attitude, -> sampled measured position."""
    Phi, Ga, Gb, Ms, Sa, Sb = plant.period_maps()
    z = np.exp(1j * np.asarray(omega, float) * plant.T)
    n = Phi.shape[0]
    p_alpha = np.empty(z.size, complex)
    p_y = np.empty(z.size, complex)
    for i, zi in enumerate(z):
        drive = Ga * zi ** (-plant.m_in - 1) + Gb * zi ** (-plant.m_in)
        x = np.linalg.solve(zi * np.eye(n) - Phi, drive)
        p_alpha[i] = x[0]
        xs = Ms @ x + Sa * zi ** (-plant.m_in - 1) + Sb * zi ** (-plant.m_in)
        p_y[i] = xs[3] * zi ** (-plant.n_y)
    return p_alpha, p_y


def outer_plant_response(plant: CascadePlant, gains: InnerGains, command_gain: float, omega: Array) -> CArray:
    """G_outer(e^{j omega T}): outer command -> measured position [m per command unit].

    ``command_gain`` turns the outer command into the attitude setpoint: 1 (commanded attitude) or
    1/g (commanded acceleration).
    """
    ce, d = controller_response(gains, omega)
    p_alpha, p_y = _plant_responses(plant, omega)
    out: CArray = command_gain * p_y * ce / (1.0 + (ce + d) * p_alpha)
    return out


# --------------------------------------------------------------------------------------------------
# the closed loops' stability, exactly: the linear tick map's spectral radius


def _tick_map(plant: CascadePlant, inner: InnerGains, outer: InnerGains | None, command_gain: float,
              ) -> tuple[int, Callable[[Array], Array]]:
    """The noise-free closed loop (inner PD, and the outer controller when given) as a linear map of
    one flat state vector per tick: plant, inner command line, position samples, controller states."""
    m, n_y = plant.m_in, plant.n_y
    Tc = plant.T
    # layout: x(5) | u_{k-m-1} .. u_{k-1} (m+1) | y samples of periods k-n_y .. k-1 (n_y) |
    #         inner D, alpha_prev, inner I | outer D, y_prev, outer I
    iu, iy, ic = 5, 5 + m + 1, 5 + m + 1 + n_y
    size = ic + 6
    Phi, Ga, Gb, Ms, Sa, Sb = plant.period_maps()

    def step(s: Array) -> Array:
        x, line, ys = s[:5], s[iu:iy], s[iy:ic]
        d_in, a_prev, i_in, d_out, y_prev, i_out = s[ic:ic + 6]
        y_meas = float(ys[0]) if n_y > 0 else float(x[3])
        ref = 0.0
        new = np.zeros(size)
        if outer is not None:
            d_out = (outer.Tf * d_out - outer.Kd * (y_meas - y_prev)) / (outer.Tf + Tc)
            e_o = -y_meas
            i_out = i_out + outer.Ki * Tc * e_o
            ref = command_gain * (outer.Kp * e_o + i_out + d_out)
        alpha = float(x[0])
        d_in = (inner.Tf * d_in - inner.Kd * (alpha - a_prev)) / (inner.Tf + Tc)
        e_i = ref - alpha
        i_in = i_in + inner.Ki * Tc * e_i
        u = inner.Kp * e_i + i_in + d_in
        full = np.append(line, u)  # u_{k-m-1} .. u_k
        ua, ub = full[0], full[1]
        new[:5] = Phi @ x + Ga * ua + Gb * ub
        new[iu:iy] = full[1:]
        if n_y > 0:
            y_s = float((Ms @ x + Sa * ua + Sb * ub)[3])
            new[iy:ic] = np.append(ys[1:], y_s)
        new[ic:ic + 6] = (d_in, alpha, i_in, d_out, y_meas, i_out)
        return new

    return size, step


def closed_loop_radius(plant: CascadePlant, inner: InnerGains, outer: InnerGains | None = None,
                       command_gain: float = 1.0) -> float:
    """Spectral radius of the noise-free closed loop's tick map (< 1: stable).

    Without ``outer`` the inner loop alone (attitude setpoint 0; the position, which then only
    integrates, is left out); with it, the outer controller (generic form, position error -> outer
    command, derivative on the measured position) closes the cascade.
    """
    size, step = _tick_map(plant, inner, outer, command_gain)
    M = np.column_stack([step(col) for col in np.eye(size)])
    iy, ic = 5 + plant.m_in + 1, size - 6
    # an integrator with Ki = 0 is a constant (eigenvalue 1 that does not act): drop it
    keep = [i for i in range(size) if not (i == ic + 2 and inner.Ki == 0)
            and not (i == ic + 5 and (outer is None or outer.Ki == 0))]
    if outer is None:
        # the position, its samples and the unused outer controller do not feed back into the attitude
        keep = [i for i in keep if i < 3 or 5 <= i < iy or ic <= i < ic + 3]
    M = M[np.ix_(keep, keep)]
    return float(np.max(np.abs(np.linalg.eigvals(M))))


@dataclass(frozen=True)
class OuterMargin:
    """What an outer controller actually has on the true cascade.

    Attributes
    ----------
    phase_margin_deg : float
        The smallest phase margin over the gain crossovers [deg] (-inf when the closed loop is unstable).
    crossover_rad_s : float
        The crossover frequency of that margin [rad/s] (nan without one).
    stable : bool
        The closed loop's spectral radius is below 1.
    radius : float
        That spectral radius.
    """

    phase_margin_deg: float
    crossover_rad_s: float
    stable: bool
    radius: float


def outer_phase_margin(plant: CascadePlant, inner: InnerGains, outer: InnerGains, command_gain: float,
                       n_grid: int = 3000) -> OuterMargin:
    """The phase margin an outer controller has on the cascade: L = (Ce + D) G_outer on the unit circle.

    The loop is broken at the outer command (the controller's P, I and D paths all feed it), the
    crossovers located on a log grid up to the Nyquist frequency and refined on |L| = 1 (Brent's method).
    An unstable closed loop (spectral radius >= 1) has margin -inf.
    """
    radius = closed_loop_radius(plant, inner, outer, command_gain)
    omega_n = math.pi / plant.T

    def loop(omega: Array) -> CArray:
        ce, d = controller_response(outer, omega)
        out: CArray = (ce + d) * outer_plant_response(plant, inner, command_gain, omega)
        return out

    grid = np.geomspace(1e-3, omega_n * 0.999, n_grid)
    mag = np.abs(loop(grid)) - 1.0
    margins: list[tuple[float, float]] = []
    for i in np.flatnonzero(np.sign(mag[:-1]) != np.sign(mag[1:])):
        w = float(optimize.brentq(lambda x: abs(complex(loop(np.array([x]))[0])) - 1.0, grid[i], grid[i + 1],
                                  xtol=1e-14, rtol=1e-14))
        pm = 180.0 + math.degrees(cmath.phase(complex(loop(np.array([w]))[0])))
        margins.append(((pm + 180.0) % 360.0 - 180.0, w))
    if radius >= 1.0:
        return OuterMargin(-math.inf, margins[0][1] if margins else math.nan, False, radius)
    if not margins:
        return OuterMargin(math.inf, math.nan, True, radius)
    pm, w = min(margins)
    return OuterMargin(pm, w, True, radius)
