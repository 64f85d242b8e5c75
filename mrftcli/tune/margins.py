"""Frequency-domain figures of the sampled loop: gain, phase and delay margins, sensitivity peak Ms.

The loop is L(z) = C_fb(z) Gd(z) (broken at the plant input), with Gd the exact zero-order-hold
equivalent of the plant and its delay (:func:`mrftcli.tune.closed_loop.discrete_plant`: the
fractional part of the delay is exact, no Pade approximant) and C_fb the controller from -y to u.
python-control does the frequency-domain work (:func:`control.stability_margins`, frequency
responses); the delay margin is found exactly in the time domain: the extra transport delay at which
the sampled closed loop (:func:`mrftcli.tune.closed_loop.closed_loop_matrices`) loses stability,
bracketed from the first-order estimate phase margin / crossover frequency and bisected.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

import numpy as np

from ..mrft.model import LoopModel
from .closed_loop import Controller, as_discrete, closed_loop_matrices, discrete_plant, spectral_radius

__all__ = ["Margins", "plant_system", "controller_system", "loop_system", "margins", "frequency_grid",
           "plant_response", "sensitivity_peak", "grid_margins"]


@dataclass(frozen=True)
class Margins:
    """Stability margins of one sampled loop.

    Attributes
    ----------
    gain_margin : float
        Factor by which the loop gain may grow before instability [-] (inf if the phase never crosses -180 deg).
    phase_margin_deg : float
        Phase margin [deg] at the gain crossover ``w_gc``.
    delay_margin_s : float
        Extra transport delay the loop survives [s] (exact, sampled loop).
    Ms : float
        Sensitivity peak max |1 / (1 + L)| [-].
    w_gc, w_pc : float
        Gain and phase crossover frequencies [rad/s].
    stable : bool
        Whether the nominal sampled closed loop is stable.
    """

    gain_margin: float
    phase_margin_deg: float
    delay_margin_s: float
    Ms: float
    w_gc: float
    w_pc: float
    stable: bool

    @property
    def gain_margin_db(self) -> float:
        return 20.0 * math.log10(self.gain_margin) if self.gain_margin > 0 else -math.inf

    def to_dict(self) -> dict:
        return {"gain_margin": self.gain_margin, "gain_margin_db": self.gain_margin_db,
                "phase_margin_deg": self.phase_margin_deg, "delay_margin_ms": self.delay_margin_s * 1e3,
                "Ms": self.Ms, "w_gc_rad_s": self.w_gc, "w_pc_rad_s": self.w_pc, "stable": self.stable}


def plant_system(model: LoopModel, rate_hz: float):
    """Gd as a discrete python-control state space (input u_k, output y_k, time step 1/rate_hz).

    States: the plant's three, then the commands still in flight u_{k-1} ... u_{k-d-1}.
    """
    import control

    Phi, Gam, C, d = discrete_plant(model, rate_hz)
    nb = d + 1
    n = 3 + nb
    A = np.zeros((n, n))
    B = np.zeros((n, 1))
    A[:3, :3] = Phi
    A[:3, 3 + d] += Gam[0]
    if d == 0:
        B[:3, 0] += Gam[1]
    else:
        A[:3, 3 + d - 1] += Gam[1]
    B[3, 0] = 1.0
    for j in range(1, nb):
        A[3 + j, 3 + j - 1] = 1.0
    Cm = np.zeros((1, n))
    Cm[0, :3] = C
    return control.ss(A, B, Cm, np.zeros((1, 1)), 1.0 / rate_hz)


def controller_system(controller: Controller):
    """C_fb(z) = Kp + Ki T z / (z - 1) + Kd (z - 1) / ((Tf + T) z - Tf) as a python-control transfer function."""
    import control

    T = controller.Ts
    c = control.tf([controller.Kp], [1.0], T)
    if controller.Ki > 0:
        c = c + control.tf([controller.Ki * T, 0.0], [1.0, -1.0], T)
    if controller.Kd > 0:
        c = c + control.tf([controller.Kd, -controller.Kd], [controller.Tf + T, -controller.Tf], T)
    return c


def loop_system(model: LoopModel, controller: Controller):
    """L = C_fb Gd (python-control state space, discrete)."""
    import control

    return control.series(control.ss(controller_system(controller)), plant_system(model, controller.rate_hz))


def frequency_grid(rate_hz: float, n: int = 600) -> np.ndarray:
    """Log-spaced frequencies [rad/s] from 1e-3 of Nyquist up to just below Nyquist."""
    w_nyq = math.pi * rate_hz
    return np.geomspace(w_nyq * 1e-4, w_nyq * 0.999, n)


def plant_response(models, rate_hz: float, omega: np.ndarray) -> np.ndarray:
    """Gd(e^{j omega T}) of each model (LoopModel or DiscretePlant), shape (M, len(omega)).

    Gd(z) = C (z I - Phi)^{-1} (Gamma_b + Gamma_a / z) z^{-d} from :func:`discrete_plant`, evaluated
    directly (vectorised; the same system as :func:`plant_system`, whose python-control frequency
    response the tests compare it with).
    """
    omega = np.asarray(omega, float)
    z = np.exp(1j * omega / rate_hz)
    out = np.empty((len(models), omega.size), complex)
    eye = np.eye(3)
    for i, p in enumerate(as_discrete(models, rate_hz)):
        Phi, Gam, C, d = p
        rhs = Gam[1][None, :] + Gam[0][None, :] / z[:, None]
        x = np.linalg.solve(z[:, None, None] * eye[None] - Phi[None], rhs[..., None])[..., 0]
        out[i] = (x @ C) * z ** (-d)
    return out


def sensitivity_peak(controller: Controller, Gd: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """max over the grid of |1 / (1 + C_fb Gd)| for each row of ``Gd`` (shape (M, W)) -> (M,)."""
    L = controller.feedback_response(omega)[None, :] * Gd
    return np.max(1.0 / np.abs(1.0 + L), axis=-1)


def _stable(model: LoopModel, controller: Controller, extra: float) -> bool:
    A, *_ = closed_loop_matrices([replace(model, tau=model.tau + extra)], controller)
    return bool(spectral_radius(A)[0] < 1.0 - 1e-12)


def margins(model: LoopModel, controller: Controller) -> Margins:
    """Gain, phase and delay margins and Ms of the sampled loop (see the module docstring)."""
    import control

    stable = _stable(model, controller, 0.0)
    L = loop_system(model, controller)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gm, pm, sm, wpc, wgc, _ = control.stability_margins(L)
    gm = float(gm) if gm is not None and np.isfinite(gm) else math.inf
    pm = float(pm) if pm is not None and np.isfinite(pm) else math.nan
    # Ms on a dense grid as well: the loop's peak can fall between the points stability_margins samples
    w = frequency_grid(controller.rate_hz, 2000)
    Ms_grid = float(sensitivity_peak(controller, plant_response([model], controller.rate_hz, w), w)[0])
    Ms = max(1.0 / float(sm) if sm and np.isfinite(sm) and sm > 0 else math.inf, Ms_grid) if stable else math.inf
    if not stable:
        return Margins(gm, pm, 0.0, math.inf, float(wgc), float(wpc), False)
    dm = _delay_margin(model, controller, pm, float(wgc))
    return Margins(gm, pm, dm, Ms, float(wgc), float(wpc), True)


#: Above this many samples of extra delay the delay margin is the first-order figure (the exact one
#: needs the eigenvalues of a closed-loop matrix this large).
_EXACT_DELAY_SAMPLES = 300


def _delay_margin(model: LoopModel, controller: Controller, pm_deg: float, wgc: float) -> float:
    guess = math.radians(pm_deg) / wgc if np.isfinite(pm_deg) and pm_deg > 0 and wgc > 0 else 10 * controller.Ts
    if guess * controller.rate_hz > _EXACT_DELAY_SAMPLES:
        return guess
    hi = None
    lo = 0.0
    for f in np.linspace(0.25, 3.0, 12):
        if not _stable(model, controller, f * guess):
            hi = f * guess
            break
        lo = f * guess
    if hi is None:
        return math.inf
    for _ in range(10):  # 1/1024 of the bracket: well below a sample period
        mid = 0.5 * (lo + hi)
        if _stable(model, controller, mid):
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def grid_margins(controller: Controller, Gd: np.ndarray, omega: np.ndarray) -> dict:
    """Margins of many loops at once from their responses on a frequency grid (posterior figures).

    ``Gd`` has shape (M, W) (:func:`plant_response`). The phase of L is unwrapped from the lowest
    frequency; crossovers are interpolated linearly in log frequency. The delay margin here is the
    first-order figure phase margin / gain crossover (the exact sampled one is :func:`margins`').

    Returns
    -------
    dict of arrays (M,)
        ``phase_margin_deg`` (smallest over the gain crossovers), ``gain_margin`` (smallest over the
        -180 deg crossings, inf if none), ``Ms``, ``w_gc`` and ``delay_margin_s``.
    """
    L = controller.feedback_response(omega)[None, :] * Gd
    mag = np.abs(L)
    ph = np.unwrap(np.angle(L), axis=-1)
    lw = np.log(omega)
    M = L.shape[0]
    pm = np.full(M, np.inf)
    wgc = np.full(M, np.nan)
    gm = np.full(M, np.inf)
    lm = np.log(mag)
    for i in range(M):
        s = np.nonzero((lm[i, :-1] > 0) & (lm[i, 1:] <= 0))[0]
        for k in s:
            f = lm[i, k] / (lm[i, k] - lm[i, k + 1])
            p = ph[i, k] + f * (ph[i, k + 1] - ph[i, k])
            margin = math.degrees(p) + 180.0
            # the phase is unwrapped from -90 or -180 deg; bring the margin into (-180, 180]
            margin = (margin + 180.0) % 360.0 - 180.0
            if margin < pm[i]:
                pm[i] = margin
                wgc[i] = math.exp(lw[k] + f * (lw[k + 1] - lw[k]))
        q = ph[i] + math.pi
        c = np.nonzero((q[:-1] > 0) & (q[1:] <= 0))[0]
        for k in c:
            f = q[k] / (q[k] - q[k + 1])
            g = math.exp(lm[i, k] + f * (lm[i, k + 1] - lm[i, k]))
            gm[i] = min(gm[i], 1.0 / g)
    Ms = np.max(1.0 / np.abs(1.0 + L), axis=-1)
    dm = np.where(np.isfinite(wgc) & (pm > 0), np.radians(pm) / np.where(np.isfinite(wgc), wgc, 1.0), 0.0)
    return {"phase_margin_deg": pm, "gain_margin": gm, "Ms": Ms, "w_gc": wgc, "delay_margin_s": dm}
