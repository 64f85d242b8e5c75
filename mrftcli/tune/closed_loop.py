"""The sampled closed loop of a tuned controller on G(s) = K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1)).

A digital controller runs at ``rate_hz``: at tick t_k = k T it samples the output y_k, computes the
command u_k and holds it for one period (zero-order hold); the command reaches the plant ``tau``
later. The controller is a PID in parallel form with the derivative on the measurement through a
first-order filter, discretised by backward differences (stable for any Tf >= 0)::

    I_k = I_{k-1} + Ki T e_k,            e_k = r - y_k
    D_k = (Tf D_{k-1} - Kd (y_k - y_{k-1})) / (Tf + T)
    u_k = Kp e_k + I_k + D_k

Two independent routes give the same sampled loop:

* :func:`discrete_plants` and :func:`closed_loop_matrix`: the exact zero-order-hold equivalent of
  the plant with a fractional delay (tau = d T + eps: the command of tick k - d - 1 acts for the first
  eps of each period, that of tick k - d for the rest; :class:`DiscretePlant`, every family's held
  delay), its command buffer as states (:func:`augmented`), closed with the controller into one state
  matrix z_{k+1} = A z_k + B r (the families' criterion iterates it); :func:`responses` inverts the same
  loop's z-transform.
* :func:`simulate_step`: an event-driven time-domain simulation of the continuous plant (matrix
  exponentials between the instants at which a held command reaches the plant), with the controller
  of :class:`Controller` stepping at every tick. It is the check of the first route
  (``tests/test_tune.py``, ``benchmarks/bench_tune.py``).

Both are exact for the linear plant (no delay quantisation, no Pade approximant).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ..errors import InputError
from ..mrft.cascade import DiscreteStateSpace, split_interval, whole_and_fraction
from ..mrft.controller import Controller, RateFilter
from ..mrft.propagate import phi_gamma
from ..mrft.model import LoopModel, PlantModel
from ..validate import check_positive

__all__ = ["Controller", "RateFilter", "DiscretePlant", "PlantStack", "PlantSpectrum", "plant_spectrum", "plants_of_parameters", "StepMetrics", "discrete_plants", "as_discrete", "held_delay", "augmented", "closed_loop_matrix", "step_outputs", "step_response",
           "responses", "outputs", "step_metrics", "criterion", "simulate_step", "SETTLING_BAND"]

#: Settling band of :func:`step_metrics`: |y - 1| <= 2 % of the step from then on.
SETTLING_BAND = 0.02
#: |y| beyond this many step heights: the loop diverged (unstable).
_DIVERGED = 1e3


@dataclass(frozen=True)
class StepMetrics:
    """Figures of a unit setpoint step (output y relative to the step).

    Attributes
    ----------
    overshoot_pct : float
        max(y) - 1 in percent of the step (0 when y never exceeds 1).
    rise_s : float
        Time from 10 % to 90 % of the step [s].
    settling_s : float
        Last time |y - 1| > SETTLING_BAND, i.e. settled from then on [s]; NaN if not settled in the horizon.
    iae, itae : float
        Integral of |e| [output unit s] and of t |e| [output unit s^2] over the horizon.
    peak_u : float
        Largest |u| [command units per output unit of step].
    """

    overshoot_pct: float
    rise_s: float
    settling_s: float
    iae: float
    itae: float
    peak_u: float

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True, eq=False)
class DiscretePlant:
    """x_{k+1} = Phi x_k + Gamma[0] u_{k-d-1} + Gamma[1] u_{k-d},  y_k = C x_k: the held delay tau = d T + eps
    of any plant (eq. (2)'s: :func:`discrete_plants`; the other families': :func:`mrftcli.tune.grid.discretise`)."""

    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    d: int
    rate_hz: float

    def __iter__(self) -> Iterator[Any]:
        return iter((self.Phi, self.Gamma, self.C, self.d))


def discrete_plants(models, rate_hz: float) -> list[DiscretePlant]:
    """Exact zero-order-hold equivalents of eq. (2)'s plants with their delays (:class:`DiscretePlant`), vectorised
    over the models (one, or the posterior's draws): x_{k+1} = Phi x_k + Gamma_a u_{k-d-1} + Gamma_b u_{k-d},
    y_k = C x_k, with tau = d T + eps, 0 <= eps < T; Phi (3, 3), Gamma (2, 3), C (3,), d
    (:func:`plants_of_parameters`)."""
    models = list(models)
    if not models:
        return []
    def column(name: str) -> np.ndarray:
        return np.array([getattr(m, name) for m in models], float)

    return plants_of_parameters(column("Tp"), column("Td"), column("tau"), column("K"), rate_hz)


def plants_of_parameters(Tp: np.ndarray, Td: np.ndarray, tau: np.ndarray, K: np.ndarray,
                         rate_hz: float) -> list[DiscretePlant]:
    """:func:`discrete_plants` of parameter arrays [s, s, s, -] (no LoopModel per draw: the delay margin
    rediscretises the draws at many delays): :meth:`~mrftcli.mrft.model.LoopModel.state_space`'s realisation
    held as every family's (:func:`_held`), all draws at once."""
    check_positive("the controller rate [Hz]", rate_hz)
    Tp, Td, tau, K = np.broadcast_arrays(*(np.asarray(v, float).ravel() for v in (Tp, Td, tau, K)))
    A = np.zeros((Tp.size, 3, 3))
    A[:, 0, 1], A[:, 1, 1], A[:, 1, 2], A[:, 2, 2] = 1.0, -1.0 / Td, K, -1.0 / Tp
    B = np.zeros((Tp.size, 3))
    B[:, 2] = 1.0 / Tp
    return _held(A, B, np.array([1.0, 0.0, 0.0]), tau, rate_hz)


def _held(A: np.ndarray, B: np.ndarray, C: np.ndarray, delay: np.ndarray, rate_hz: float) -> list[DiscretePlant]:
    """The held delays of M plants x' = A x + B u, y = C x (A (M, n, n), B (M, n), C (n,)) with delays ``delay``
    [s] (M,) at ``rate_hz``: tau = d T + eps (:func:`~mrftcli.mrft.cascade.whole_and_fraction`), the command
    of tick k - d - 1 acts over the first eps of the tick, that of tick k - d over the rest (the modified
    z-transform: :func:`~mrftcli.mrft.cascade.split_interval`, over the stack at once)."""
    T = 1.0 / rate_hz
    d, eps = whole_and_fraction(np.asarray(delay, float), T)
    Phi, G_old, G_new = split_interval(A, B, T, eps)
    return [DiscretePlant(Phi[i], np.stack([G_old[i], G_new[i]]), C, int(d[i]), float(rate_hz)) for i in range(len(d))]


def held_delay(model: PlantModel, rate_hz: float) -> DiscretePlant:
    """The modified z-transform of any plant's realisation (:class:`DiscretePlant`, :func:`_held`)."""
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"the controller rate must be a positive frequency in Hz, got {rate_hz!r}")
    ss = model.realisation()
    if abs(ss.D) > 0:
        raise InputError("the plant has direct feedthrough (its transfer function is not strictly proper): "
                         "tune designs for strictly proper plants")
    A, B, C = (np.asarray(v, float) for v in (ss.A, ss.B, ss.C))
    return _held(A[None], B[None], C, np.array([float(model.delay)]), rate_hz)[0]


def as_discrete(models, rate_hz: float) -> list[DiscretePlant]:
    """PlantModel or DiscretePlant items -> DiscretePlants (eq. (2)'s LoopModels discretised together, another
    family's model by :func:`held_delay`)."""
    models = [m if isinstance(m, (LoopModel, DiscretePlant)) else held_delay(m, rate_hz) for m in models]
    todo = [i for i, m in enumerate(models) if isinstance(m, LoopModel)]
    done = discrete_plants([models[i] for i in todo], rate_hz) if todo else []
    out = list(models)
    for i, p in zip(todo, done):
        out[i] = p
    for m in out:
        if abs(m.rate_hz - rate_hz) > 1e-9 * rate_hz:
            raise InputError("a discretised plant was made for another controller rate")
    return out


def augmented(p: DiscretePlant) -> DiscreteStateSpace:
    """The held-delay plant ``p`` with its command buffer as states: X_k = [x_k, u_{k-1}, ..., u_{k-d-1}]
    (the delay part of the state, so the closed loop's eigenvalues decide stability); the command u_k
    enters the buffer's first slot (state n)."""
    n, d = p.Phi.shape[0], p.d
    N = n + d + 1
    Ad = np.zeros((N, N))
    Bd = np.zeros(N)
    Ad[:n, :n] = p.Phi
    Ad[:n, n + d] = p.Gamma[0]  # u_{k-d-1}
    if d == 0:
        Bd[:n] = p.Gamma[1]  # u_k itself
    else:
        Ad[:n, n + d - 1] = p.Gamma[1]  # u_{k-d}
    Bd[n] = 1.0  # the buffer: u_k becomes u_{(k+1)-1}
    for j in range(1, d + 1):
        Ad[n + j, n + j - 1] = 1.0
    Cd = np.zeros(N)
    Cd[:n] = p.C
    return DiscreteStateSpace(Ad, Bd, Cd, p.rate_hz)


def closed_loop_matrix(ss: DiscreteStateSpace, c: Controller) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, Cy): z_{k+1} = A z_k + B r, y_k = Cy z_k, for the PD/PID ``c`` on the plant ``ss``.

    State z = [x (plant), I_{k-1}, D_{k-1}, y_{k-1}], the controller of :class:`Controller` (derivative on
    the measurement, backward differences; a PD has no integrator state: no spurious eigenvalue at 1).
    On a delay-augmented plant (:func:`augmented`) the command u_k = (row, entry) of the buffer's first
    slot in (A, B).
    """
    n = ss.order
    N = n + 3
    iI, iD, iy = n, n + 1, n + 2
    T = c.Ts
    cy = np.zeros(N)
    cy[:n] = ss.C
    cI = -c.Ki * T * cy
    if c.Ki > 0:
        cI[iI] += 1.0
    cD = -c.Kd / (c.Tf + T) * cy
    cD[iD] += c.Tf / (c.Tf + T)
    cD[iy] += c.Kd / (c.Tf + T)
    cu = -c.Kp * cy + cI + cD
    A = np.zeros((N, N))
    B = np.zeros(N)
    A[:n, :n] = ss.Phi
    A[:n] += np.outer(ss.Gamma, cu)
    B[:n] = ss.Gamma * (c.Kp + c.Ki * T)
    A[iI], B[iI] = cI, c.Ki * T
    A[iD] = cD
    A[iy] = cy
    return A, B, cy


def step_outputs(A: np.ndarray, B: np.ndarray, Cy: np.ndarray, count: int) -> np.ndarray:
    """The outputs Cy z_k of z_{k+1} = A z_k + B, z_0 = 0, over ``count`` ticks (exact: z_k = sum_{j<k} A^j B,
    by doubling)."""
    S = np.zeros((count, A.shape[0]))
    step, have = A.copy(), 1  # step = A^have
    with np.errstate(all="ignore"):
        while have < count:
            take = min(have, count - have)
            S[have:have + take] = np.einsum("ij,nj->ni", step, S[:take]) + (A @ S[have - 1] + B)
            have += take
            step = step @ step
        out: np.ndarray = S @ Cy
    return out


@dataclass(frozen=True, eq=False)
class PlantStack:
    """Discretised plants stacked as arrays (for evaluating many loops' transfer functions at once).

    Attributes
    ----------
    Phi : (M, n, n); Gamma : (M, 2, n) (rows Gamma_a, Gamma_b); C : (M, n); d : (M,) delay [ticks]
        As in :class:`DiscretePlant` (eq. (2)'s n = 3, another family's its realisation's order).
    """

    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    d: np.ndarray
    triangular: bool = True

    @classmethod
    def of(cls, plants: Sequence[DiscretePlant]) -> "PlantStack":
        """Stack ``plants`` (a non-empty sequence)."""
        Phi = np.stack([p.Phi for p in plants])
        return cls(Phi, np.stack([p.Gamma for p in plants]), np.stack([p.C for p in plants]),
                   np.array([p.d for p in plants], int), Phi.shape[-1] == 3 and not np.any(np.tril(Phi, -1) != 0.0))

    def take(self, index: np.ndarray) -> "PlantStack":
        """The plants at ``index`` (repeats allowed)."""
        return PlantStack(self.Phi[index], self.Gamma[index], self.C[index], self.d[index], self.triangular)

    def transfer(self, z: np.ndarray, delayed: bool = True) -> np.ndarray:
        """The plant's z-transfer function at the points ``z`` (W,) or (M, W), for each plant: shape (M, W).

        Gd(z) = C (z I - Phi)^{-1} (Gamma_b + Gamma_a z^{-1}) z^{-d} (``delayed``: from the command u_k),
        or C (z I - Phi)^{-1} (Gamma_a + Gamma_b) (not ``delayed``: a constant input over each whole
        period, the load disturbance of :func:`responses`). The delay is the phase term z^{-d} and the
        fractional part of the delay is in Gamma_a, Gamma_b (:func:`discrete_plants`), so the cost does not
        depend on d. Eq. (2)'s Phi is upper triangular, so (z I - Phi)^{-1} is a back substitution (another
        plant's: a solve). ``z``: points of the z-plane (e^{j omega T} for a frequency response, omega in rad/s).
        """
        if not delayed:
            return self.transfers(z)[1]
        z, xa, xb = self._solved(z)
        return self._delayed(z, xa, xb)

    def transfers(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Gd, Gl) at ``z``: the delayed transfer from the command and the undelayed one of a constant
        input over each period (:meth:`transfer`), sharing the solves; each (M, W)."""
        z, xa, xb = self._solved(z)
        return self._delayed(z, xa, xb), xa + xb

    def _delayed(self, z: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
        # z^-d as exp(-d log z): one logarithm per point, not one per point and plant
        return (xb + xa / z) * np.exp(-self.d[:, None] * np.log(z))

    def _solved(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(z as (1 or M, W), C (z I - Phi)^{-1} Gamma_a, the same of Gamma_b), each resolvent (M, W).

        At a few points per plant (the margins' refinements, thousands of calls, where numpy's per-call cost
        dominates) eq. (2)'s triangular form solves both inputs in one pass, arrays (M, 2, W): each element as
        the two passes compute it. Why: 1.3x per call there; on a long grid the doubled arrays cost more than
        they save, so it keeps two passes (``benchmarks/bench_tune_ranges.py`` prints the ratio)."""
        z = np.atleast_2d(np.asarray(z, complex))  # (1, W) or (M, W)
        b = self.Gamma
        if not self.triangular or z.shape[-1] > _ONE_PASS_POINTS:
            return z, self._resolvent(z[:, None, :], b[:, :1])[:, 0], self._resolvent(z[:, None, :], b[:, 1:])[:, 0]
        x = self._resolvent(z[:, None, :], b)
        return z, x[:, 0], x[:, 1]

    def _resolvent(self, z: np.ndarray, b: np.ndarray) -> np.ndarray:
        """C (z I - Phi)^{-1} b_k for each plant and input k (b: (M, K, n)) at the points z (1 or M, 1, W):
        (M, K, W)."""
        Phi, C = self.Phi, self.C
        if not self.triangular:  # not the triangular form of eq. (2): a general solve
            n = Phi.shape[-1]
            zz = np.broadcast_to(z, (Phi.shape[0], b.shape[1], z.shape[-1]))
            rhs = np.broadcast_to(b[:, :, None, :, None], zz.shape + (n, 1))
            x = np.linalg.solve(zz[..., None, None] * np.eye(n) - Phi[:, None, None], rhs)[..., 0]
            return np.einsum("mkwi,mi->mkw", x, C)
        P = Phi[:, None, :, :, None]  # (M, 1, n, n, 1): P[:, :, i, j] broadcasts against (M, K, W)
        x2 = b[:, :, 2, None] / (z - P[:, :, 2, 2])
        x1 = (b[:, :, 1, None] + P[:, :, 1, 2] * x2) / (z - P[:, :, 1, 1])
        x0 = (b[:, :, 0, None] + P[:, :, 0, 1] * x1 + P[:, :, 0, 2] * x2) / (z - P[:, :, 0, 0])
        Cx = C[:, None, :, None]
        return Cx[:, :, 0] * x0 + Cx[:, :, 1] * x1 + Cx[:, :, 2] * x2


#: :meth:`PlantStack._solved` solves both inputs in one pass up to this many points per plant
_ONE_PASS_POINTS = 8


#: z-transform inversion: the responses are sampled on the circle |z| = rho with rho^N = this (a loop
#: growing faster than this over the horizon has diverged, as :func:`criterion` counts it from 1e3) ...
_SPECTRAL_GROWTH = 1e4
#: ... at this many points per tick of the horizon (time aliasing: the transient left after N ticks
#: times rho^-(2 N) = 1e-8).
_SPECTRAL_OVERSAMPLE = 2
#: Loops transformed at once (bounds the working memory to ~30 MB at a 60 s, 200 Hz horizon).
_SPECTRAL_CHUNK = 8


@dataclass(frozen=True, eq=False)
class PlantSpectrum:
    """The plants' transfer functions on the inversion circle of an N-tick horizon (:func:`plant_spectrum`).

    Computed once per set of plants and horizon, it serves every controller tried on them.
    """

    z: np.ndarray  # (W,) the circle's points from theta = 0 to pi
    rho: float
    n_fft: int
    n_ticks: int
    Gd: np.ndarray  # (M, W)
    Gl: np.ndarray  # (M, W)


def plant_spectrum(plants: Sequence[DiscretePlant], t_end: float) -> PlantSpectrum:
    """What :func:`responses` of these plants over [0, ``t_end``] [s] needs from them, kept for reuse
    across controllers (``plants``: non-empty, one rate)."""
    return _spectrum(plants, _ticks(t_end, plants[0].rate_hz))


def _ticks(t_end: float, rate_hz: float) -> int:
    return int(math.ceil(t_end * rate_hz)) + 1


def _spectrum(plants: Sequence[DiscretePlant], n_ticks: int) -> PlantSpectrum:
    from scipy.fft import next_fast_len

    n_fft = next_fast_len(_SPECTRAL_OVERSAMPLE * n_ticks, real=True)
    rho = _SPECTRAL_GROWTH ** (1.0 / max(n_ticks, 1))
    z = rho * np.exp(2j * np.pi * np.arange(n_fft // 2 + 1) / n_fft)
    return PlantSpectrum(z, rho, n_fft, n_ticks, *PlantStack.of(plants).transfers(z))


def _invert(X: np.ndarray, sp: PlantSpectrum) -> np.ndarray:
    """x_k, k < N, of the z-transforms X (M, W) sampled on the circle |z| = rho (half spectrum)."""
    from scipy.fft import irfft

    x = irfft(X, n=sp.n_fft, axis=-1)[:, :sp.n_ticks]
    return x * sp.rho ** np.arange(sp.n_ticks)


def _half_turns(F: np.ndarray) -> np.ndarray:
    """Half turns of each row of F (M, W) about 0, F real at both ends (the closed contour's half).

    Counted as crossings of the negative real axis (+1 from Im > 0 to Im < 0, i.e. counter-clockwise)
    plus the ends' arguments (0 or pi): cheaper than the arguments of every point.
    """
    up = F.imag > 0
    m, k = np.nonzero(up[:, 1:] != up[:, :-1])
    a, b = F[m, k], F[m, k + 1]
    re_x = a.real + (b.real - a.real) * a.imag / (a.imag - b.imag)  # where the segment meets the real axis
    ccw = np.zeros(F.shape[0], int)
    np.add.at(ccw, m[re_x < 0], np.where(up[m, k], 1, -1)[re_x < 0])
    return 2 * ccw + (F.real[:, -1] < 0).astype(int) - (F.real[:, 0] < 0).astype(int)


#: A loop's responses: setpoint step y, u and load step y, u (None without a load step), each (M, N).
Steps = tuple[np.ndarray, np.ndarray, "np.ndarray | None", "np.ndarray | None"]


def _spectral_responses(sp: PlantSpectrum, controller: Controller, load: float, command: bool = True) -> Steps:
    """Setpoint and load steps from the closed loop's z-transforms (exact to ~1e-12, see the constants).

    Y = Gd C_r S R, U = C_r S R with S = 1 / (1 + C_fb Gd) and R = z / (z - 1) (the unit step); the
    load step: Y_l = Gl S load R, U_l = -C_fb Y_l. The plant's integrator fixes the final values (its
    input u + load settles at 0: y -> 1, u -> 0 after a setpoint step; u -> -load and y -> load / Kp
    for a PD, 0 for a PID after a load step); each signal is inverted less its final value times the
    step, which decays, so that few points on the circle suffice. A loop with closed-loop poles outside
    the circle (1 + C_fb Gd winds around 0 on it) grows faster than the horizon allows: its rows are
    NaN (diverged). Without ``command`` the commands are not inverted (empty (M, 0) arrays).
    """
    z = sp.z
    T = controller.Ts
    Cr = controller.Kp + controller.Ki * T * z / (z - 1.0)
    Cfb = controller.feedback_at(z)  # Cr + Kd D(z), C_fb's one expression
    R = z / (z - 1.0)
    F = 1.0 + Cfb * sp.Gd
    S = 1.0 / F
    U = Cr * S * R
    y = _invert(sp.Gd * U - R, sp) + 1.0
    u = _invert(U, sp) if command else np.empty((y.shape[0], 0))
    yl = ul = None
    if load:
        Yl = sp.Gl * S * (load * R)
        y_end = load / controller.Kp if controller.Ki == 0 else 0.0
        yl = _invert(Yl - y_end * R, sp) + y_end
        ul = _invert(-Cfb * Yl + load * R, sp) - load if command else np.empty((y.shape[0], 0))
    bad = _half_turns(F) != 0
    for arr in (y, u, yl, ul):
        if arr is not None:
            arr[bad] = np.nan
    return y, u, yl, ul


def responses(models: Sequence[LoopModel | DiscretePlant], controller: Controller, t_end: float, load: float = 0.0,
              spectrum: PlantSpectrum | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The sampled loop's unit setpoint step and, when ``load`` != 0, its load-disturbance step, from rest.

    The load disturbance is a step of ``load`` [command units] added to the plant input at t = 0
    (after the delay: a disturbance torque or thrust, not a command), with the setpoint at 0.

    The closed loop's z-transform is inverted on a circle (exact to ~1e-9; the cost does not depend on the
    delay; in chunks of loops; a loop that diverges faster than 1e4 over the horizon is NaN; checked against
    :func:`simulate_step`). ``spectrum``: :func:`plant_spectrum` of the same ``models`` and ``t_end`` (saves
    recomputing it when many controllers are tried on one set of plants).

    Returns
    -------
    t : (N,) tick times [s]; y, u : (M, N) output and command of the setpoint step;
    y_load, u_load : (M, N) output and command of the load step (None when ``load`` is 0).
    """
    plants = as_discrete(models, controller.rate_hz)
    N = _ticks(t_end, controller.rate_hz)
    t = np.arange(N) / controller.rate_hz
    if spectrum is not None and spectrum.n_ticks == N and spectrum.Gd.shape[0] == len(plants):
        return (t, *_spectral_responses(spectrum, controller, load))
    parts = [_spectral_responses(_spectrum(plants[i:i + _SPECTRAL_CHUNK], N), controller, load)
             for i in range(0, len(plants), _SPECTRAL_CHUNK)]
    y, u = (np.concatenate([p[j] for p in parts]) for j in (0, 1))
    if not load:
        return t, y, u, None, None
    return t, y, u, np.concatenate([p[2] for p in parts]), np.concatenate([p[3] for p in parts])


def outputs(models: Sequence[LoopModel | DiscretePlant], controller: Controller, t_end: float, load: float = 0.0,
            spectrum: PlantSpectrum | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The outputs of :func:`responses` only: (t, y, y_load), the commands left out (a criterion needs no
    more, and at long delays this saves half the inversions)."""
    plants = as_discrete(models, controller.rate_hz)
    N = _ticks(t_end, controller.rate_hz)
    t = np.arange(N) / controller.rate_hz
    if spectrum is None or spectrum.n_ticks != N or spectrum.Gd.shape[0] != len(plants):
        spectrum = _spectrum(plants, N)
    y, _, yl, _ = _spectral_responses(spectrum, controller, load, command=False)
    return t, y, yl


def step_response(models, controller: Controller, t_end: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit setpoint step of the sampled loop for each model, from rest.

    ``models``: LoopModel or DiscretePlant items.

    Returns
    -------
    t : (N,) tick times [s]; y : (M, N) output at the ticks; u : (M, N) command at the ticks.
    """
    t, y, u, _, _ = responses(models, controller, t_end)
    return t, y, u


def criterion(t: np.ndarray, y: np.ndarray, objective: str = "iae") -> np.ndarray:
    """IAE or ITAE of unit step responses ``y`` (shape (..., N)) sampled at ``t`` (trapezoidal rule).

    Responses that are not finite or diverge (an unstable loop) get inf.
    """
    e = np.abs(1.0 - np.asarray(y, float))
    if objective == "itae":
        e = e * t
    with np.errstate(invalid="ignore", over="ignore"):
        val = np.sum(0.5 * (e[..., 1:] + e[..., :-1]) * np.diff(t), axis=-1)
        bad = ~np.all(np.isfinite(y), axis=-1) | (np.max(np.abs(y), axis=-1, initial=0.0) > _DIVERGED)
    return np.where(bad, np.inf, val)


def step_metrics(t: np.ndarray, y: np.ndarray, u: np.ndarray | None = None) -> StepMetrics:
    """Overshoot, 10-90 % rise, 2 % settling, IAE and ITAE of a unit step response sampled at ``t``.

    Examples
    --------
    >>> t = np.linspace(0.0, 10.0, 10001)
    >>> m = step_metrics(t, 1.0 - np.exp(-t))
    >>> round(m.rise_s, 3), round(m.settling_s, 3), round(m.iae, 3)
    (2.197, 3.912, 1.0)
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    if not np.all(np.isfinite(y)) or np.max(np.abs(y)) > _DIVERGED:
        return StepMetrics(math.inf, math.nan, math.nan, math.inf, math.inf, math.inf)
    ae = np.abs(1.0 - y)
    iae, itae = float(criterion(t, y, "iae")), float(criterion(t, y, "itae"))
    over = max(0.0, float(np.max(y) - 1.0)) * 100.0

    def crossing(level: float) -> float:
        k = int(np.argmax(y >= level))
        if y[k] < level:
            return math.nan
        if k == 0:
            return float(t[0])
        return float(t[k - 1] + (level - y[k - 1]) / (y[k] - y[k - 1]) * (t[k] - t[k - 1]))

    rise = crossing(0.9) - crossing(0.1)
    out = np.nonzero(ae > SETTLING_BAND)[0]
    if out.size == 0:
        settle = float(t[0])
    elif out[-1] == t.size - 1:
        settle = math.nan
    else:
        k = out[-1]
        # interpolate where |e| re-enters the band
        a0, a1 = ae[k], ae[k + 1]
        settle = float(t[k] + (a0 - SETTLING_BAND) / (a0 - a1) * (t[k + 1] - t[k]))
    peak_u = float(np.max(np.abs(u))) if u is not None else math.nan
    return StepMetrics(over, rise, settle, iae, itae, peak_u)


def simulate_step(model: LoopModel, controller: Controller, t_end: float, substeps: int = 4,
                  extra_delay: float = 0.0, setpoint: float = 1.0,
                  load: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Time-domain simulation of a unit setpoint step, event by event (the independent route).

    The continuous plant (:meth:`LoopModel.state_space`) is propagated with matrix exponentials
    between events: the controller ticks t_k and the instants t_k + tau (+ ``extra_delay``) at which
    each held command reaches the plant. ``substeps`` extra points per period give the continuous
    output between ticks. ``setpoint`` is the step's height; ``load`` [command units] is added to
    the plant input from t = 0 (a load disturbance: :func:`responses` with ``setpoint=0``).

    Returns
    -------
    t_ticks, y_ticks, u_ticks : arrays (N,) at the controller ticks; y_fine : (N - 1) * substeps + 1
    values of the continuous output on the grid t = linspace(0, t_ticks[-1], ...).
    """
    A, Bv, C = model.state_space()
    T = controller.Ts
    delay = model.tau + extra_delay
    N = int(math.ceil(t_end * controller.rate_hz)) + 1
    Kp, Ki, Kd, Tf = controller.Kp, controller.Ki, controller.Kd, controller.Tf
    x = np.zeros(3)
    cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def propagate(x: np.ndarray, w: float, h: float) -> np.ndarray:
        if h <= 0:
            return x
        key = round(h, 15)
        if key not in cache:
            cache[key] = phi_gamma(A, Bv, h)
        E, G = cache[key]
        return E @ x + G * (w + load)

    # arrivals: command j reaches the plant at j T + delay; before the first arrival the input is 0
    y_t = np.empty(N)
    u_t = np.empty(N)
    fine = [0.0]
    I = D = 0.0
    y_prev = 0.0
    t_now = 0.0
    w = 0.0  # plant input now
    cmds: list[float] = []
    next_arrival = 0  # index of the next command to arrive
    filt = controller.rate_filter
    bq, aq = filt.coefficients(controller.rate_hz) if filt is not None else (None, None)
    v1 = v2 = 0.0  # the biquad's delay line (direct form II)
    for k in range(N):
        yk = float(C @ x)
        e = setpoint - yk
        I += Ki * T * e
        if bq is not None and aq is not None:  # the stack's filter on the rate (y_k - y_{k-1}) / T
            v0 = (yk - y_prev) / T - aq[1] * v1 - aq[2] * v2
            D = -Kd * (bq[0] * v0 + bq[1] * v1 + bq[2] * v2)
            v1, v2 = v0, v1
        else:
            D = (Tf * D - Kd * (yk - y_prev)) / (Tf + T)
        y_prev = yk
        uk = Kp * e + I + D
        y_t[k], u_t[k] = yk, uk
        cmds.append(uk)
        if k == N - 1:
            break
        t_next = (k + 1) * T
        grid = [t_now + (i + 1) * T / substeps for i in range(substeps)]
        while True:
            t_arr = next_arrival * T + delay
            t_stop = min(t_arr, t_next) if next_arrival < len(cmds) else t_next
            while grid and grid[0] <= t_stop + 1e-15:
                g = grid.pop(0)
                fine.append(float(C @ propagate(x, w, g - t_now)))
            x = propagate(x, w, t_stop - t_now)
            t_now = t_stop
            if next_arrival < len(cmds) and t_arr <= t_next + 1e-15 and t_now >= t_arr - 1e-15:
                w = cmds[next_arrival]
                next_arrival += 1
                continue
            if t_now >= t_next - 1e-15:
                break
        t_now = t_next
    return np.arange(N) * T, y_t, u_t, np.asarray(fine[: (N - 1) * substeps + 1])
