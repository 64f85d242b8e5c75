"""Fisher information of a test, and what its inverse says: eq. (2)'s on ``theta = (Td, tau, ln K)``
through its UFM slice, and any family's from response points (:func:`point_information`).

``mrft-ident analyze`` identifies from three constraints per test (:mod:`mrftcli.analyze`): the
test's UFM slice ``tau_i(Td) = theta_beta(Tp Omega, Td Omega) / Omega`` (paper Lemma 3, at the
effective beta and measured Omega), the phase of its fundamental harmonic ``arg G(j Omega)`` and its
amplitude through the UGM ``ln a = ln(h K Td a_unit / Omega)`` (Lemmas 2, 4). Each constraint is a
row of the Jacobian J at the test's frequency, evaluated with the exact closed form
(:func:`mrftcli.mrft.lprs.unit_cycle`); the expected posterior covariance is the inverse of
``sum_tests J^T W J`` (plus the prior's).

Any other family (a process plant's ``plan --model NAME``) is planned on its response points
``G(j k Omega)``: the information of (ln |G|, arg G) on the unknown parameters (ln p for a gain or a
time constant, tau in seconds), each point weighted by its standard error.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..mrft.lprs import mrft_limit_cycle, unit_cycle
from ..mrft.identify_lti import ResponsePoint
from ..mrft.model import LoopModel, PlantModel
from ..mrft.parameter import Z95, is_determined
from .noise import FLOOR_BETA, FLOOR_LN_A, FLOOR_PHASE, LOST_CYCLES, cycle_noise
from .records import FlownTest

__all__ = [
    "fisher_information",
    "PredictedCycle",
    "predict_cycle",
    "planned_information",
    "flown_information",
    "posterior_covariance",
    "posterior_stds",
    "design_cost",
    "unknown_parameters",
    "point_jacobian",
    "point_information",
    "point_stds",
    "undetermined_parameters",
    "is_log_parameter",
]


def _slice_derivatives(Tp: float, Td: float, omega: float, beta: float) -> tuple[float, float]:
    """d tau_i / d Td [-] of the UFM slice at Omega, and d tau / d beta [s] (central differences)."""
    d = 1e-4
    th, _ = unit_cycle(Tp * omega, np.array([Td * (1 - d), Td * (1 + d)]) * omega, beta)
    dtau_dTd = float(th[1] - th[0]) / (2 * d * Td) / omega
    tb, _ = unit_cycle(Tp * omega, Td * omega, np.array([beta - d, beta + d]))
    dtau_dbeta = float(tb[1] - tb[0]) / (2 * d) / omega
    return dtau_dTd, dtau_dbeta


def fisher_information(Tp: float, Td: float, K: float, beta: float, omega: float, amplitude: float,
                       n_cycles: float, noise: dict[str, float]) -> np.ndarray:
    """Fisher information of one test on ``(Td, tau, ln K)`` (3 x 3), as ``analyze`` measures it.

    Rows of J (residuals of :mod:`mrftcli.analyze`'s weighted least squares, at the measured Omega):
    UFM slice ``tau - tau_i(Td)``: ``(-d tau_i/d Td, 1, 0)``; phase ``tau - tau_phi(Td)`` with
    ``tau_phi = (-phi - pi/2 - atan(Tp W) - atan(Td W)) / W``: ``(1 / (1 + (Td W)^2), 1, 0)``; UGM
    ``ln K - ln K_i(Td)``, ``ln K_i = ln(a W / (h Td a_unit))``: ``(1/Td + W d ln a_unit / d td, 0,
    1)``. Their variances are the per-cycle ``noise`` over ``n_cycles`` plus analyze's floors.

    Examples
    --------
    The phase constraint alone for a plant with Td W = 1 (closed form: J = (1/2, 1, 0)):

    >>> import numpy as np
    >>> I = fisher_information(0.04, 1.0, 1.0, -0.5, 1.0, 1.0, 1, {"ufm": np.inf, "phase": 1.0,
    ...                      "ln_amplitude": np.inf})
    >>> np.round(I / I[1, 1] * 1.0, 3).tolist()[0]
    [0.25, 0.5, 0.0]
    """
    n = max(float(n_cycles), 1.0)
    dtau_dTd, dtau_dbeta = _slice_derivatives(Tp, Td, omega, beta)
    d = 1e-4
    _, au = unit_cycle(Tp * omega, np.array([Td * (1 - d), Td * (1 + d)]) * omega, 0.0)
    dln_au_dTd = float(np.log(au[1] / au[0])) / (2 * d * Td)
    var_u = noise["ufm"] ** 2 / n + (dtau_dbeta * FLOOR_BETA) ** 2
    var_p = (noise["phase"] ** 2 / n + FLOOR_PHASE ** 2) / omega**2
    var_k = noise["ln_amplitude"] ** 2 / n + FLOOR_LN_A**2
    rows = np.array([[-dtau_dTd, 1.0, 0.0], [1.0 / (1.0 + (Td * omega) ** 2), 1.0, 0.0],
                     [1.0 / Td + dln_au_dTd, 0.0, 1.0]])
    w = np.array([1.0 / var_u, 1.0 / var_p, 1.0 / var_k])
    w = np.where(np.isfinite(w), w, 0.0)
    info: np.ndarray = rows.T @ (w[:, None] * rows)
    return info


@dataclass(frozen=True)
class PredictedCycle:
    """The predicted limit cycle of one plant at one beta, for h = 1.

    Attributes
    ----------
    omega : float
        Frequency [rad/s].
    amp1 : float
        Output amplitude for h = 1 [output units per command unit].
    slope1 : float
        |dy/dt| at the relay switch for h = 1 [output units / (s command unit)].
    """

    omega: float
    amp1: float
    slope1: float


def predict_cycle(Tp: float, plant: Sequence[float], beta: float, rate_hz: float) -> PredictedCycle | None:
    """Exact LPRS with the sampled relay's mean lag (half a period) added to the delay, h = 1.

    ``plant`` is (Td [s], tau [s], K); None when the plant has no limit cycle at this beta.
    """
    Td, tau, K = plant
    try:
        lc = mrft_limit_cycle(LoopModel(Tp, Td, tau + 0.5 / rate_hz, K), beta, 1.0, None, n_points=256)
    except (InputError, ValueError, RuntimeError):
        return None
    if not (np.isfinite(lc.omega) and lc.omega > 0):
        return None
    # the +h -> -h switch is at t = T/2 in the LimitCycle frame
    dy = np.gradient(lc.y, lc.t)
    i = int(np.argmin(np.abs(lc.t - 0.5 * lc.period)))
    return PredictedCycle(lc.omega, lc.amplitude, float(abs(dy[i])))


def planned_information(Tp: float, plant: Sequence[float], beta: float, h: float, duration_s: float,
                        rate_hz: float, noise_std: float, *, cycle: PredictedCycle | None = None) -> np.ndarray:
    """Fisher information on ``(Td, tau, ln K)`` of a test not yet flown, for one plant (3 x 3).

    Parameters
    ----------
    Tp : float
        Propulsion time constant [s].
    plant : (float, float, float)
        Td [s], tau [s], K of the plant.
    beta, h, duration_s : float
        The test: MRFT beta, relay height [command units], relay duration [s].
    rate_hz, noise_std : float
        Controller rate [Hz] and sensor noise std [output units].
    cycle : PredictedCycle, optional
        The plant's cycle at ``beta`` when already predicted (:func:`predict_cycle`).

    Its cycle is the exact LPRS with half a controller period added to the delay; the stable cycles
    are those of ``duration_s`` less the transient; the noise is :func:`~mrftcli.plan.noise.cycle_noise`.
    Returns zeros when the plant has no limit cycle at this beta.
    """
    Td, tau, K = (float(v) for v in plant)
    c = cycle if cycle is not None else predict_cycle(Tp, (Td, tau, K), beta, rate_hz)
    if c is None:
        return np.zeros((3, 3))
    a = h * c.amp1
    n_c = max(math.floor(duration_s * c.omega / math.tau) - LOST_CYCLES, 1)
    noise = cycle_noise(a, c.omega, h * c.slope1, rate_hz, noise_std)
    return fisher_information(Tp, Td, K, beta, c.omega, a, n_c, noise)


def flown_information(Tp: float, plant: Sequence[float], f: FlownTest, rate_hz: float, noise_std: float) -> np.ndarray:
    """Fisher information on ``(Td, tau, ln K)`` of a flown test (as measured) for one plant (3 x 3)."""
    omega = math.tau * f.frequency_hz
    slope = f.amplitude * omega * 1.5  # a triangle-like cycle; used only for the jitter term
    noise = cycle_noise(f.amplitude, omega, slope, rate_hz, noise_std)
    return fisher_information(Tp, plant[0], plant[2], f.beta, omega, f.amplitude, f.n_cycles, noise)


def posterior_covariance(info: np.ndarray) -> np.ndarray:
    """The expected posterior covariance on (Td, tau, ln K): the inverse of the information
    (its pseudo-inverse when singular)."""
    try:
        cov: np.ndarray = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(info)
    return cov


def posterior_stds(cov: np.ndarray, plant: np.ndarray) -> np.ndarray:
    """(std Td [s], std tau [s], std K) from the covariance on (Td, tau, ln K)."""
    d = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return np.array([d[0], d[1], d[2] * plant[2]])


def design_cost(cov: np.ndarray, plant: np.ndarray) -> float:
    """The design criterion: var(ln Td) + var(ln tau) + var(ln K) (tau floored at 0.1 ms)."""
    return float(cov[0, 0] / plant[0] ** 2 + cov[1, 1] / max(plant[1], 1e-4) ** 2 + cov[2, 2])


# -- any family: the information of response points ------------------------------------------------

#: the identification's floor on a parameter's relative std (mrft/identify_lti.py, analyze/general.py)
PARAM_FLOOR = 5e-3
_STEP = 1e-5  # finite-difference step of the Jacobian (relative, or times tau's scale)

FloatArray = NDArray[np.float64]


def unknown_parameters(model: PlantModel) -> list[str]:
    """The names of ``model``'s parameters a test can determine (not known)."""
    return [n for n, p in model.parameters.items() if not p.known]


def is_log_parameter(name: str, value: float) -> bool:
    """A gain or time constant is varied as ln|p| (its std relative); the delay and a zero value in seconds."""
    return name != "tau" and value != 0


def point_jacobian(model: PlantModel, omega: float, names: Sequence[str]) -> FloatArray:
    """(2, n) derivatives of (ln |G|, arg G) at ``omega`` [rad/s] w.r.t. the coordinates of ``names``."""
    G0 = complex(model.frequency_response(np.array([omega]))[0])
    J = np.zeros((2, len(names)))
    for i, name in enumerate(names):
        v = model.parameters[name].value
        log = is_log_parameter(name, v)
        step = _STEP * (abs(v) if log else max(abs(v), 1.0 / omega))
        G1 = complex(model.with_parameters(**{name: v + step}).frequency_response(np.array([omega]))[0])
        ratio = G1 / G0
        scale = step / abs(v) if log else step
        J[:, i] = [math.log(abs(ratio)) / scale, math.atan2(ratio.imag, ratio.real) / scale]
    return J


def point_information(model: PlantModel, points: Sequence[ResponsePoint], names: Sequence[str]) -> FloatArray:
    """Fisher information of ``points`` on the coordinates of ``names`` (ln p, or tau [s])."""
    F = np.zeros((len(names), len(names)))
    for p in points:
        J = point_jacobian(model, p.omega, names)
        W = np.diag([1.0 / p.se_log_gain ** 2, 1.0 / p.se_phase ** 2])
        F += J.T @ W @ J
    return F


def point_stds(model: PlantModel, names: Sequence[str], F: FloatArray, w_ref: float) -> dict[str, float]:
    """Each parameter's std [its unit] from the information ``F`` (inf along a direction it does not see);
    ``w_ref`` [rad/s] scales tau's floor."""
    scale = np.sqrt(np.diag(F))
    scale = np.where(scale > 0, scale, 1.0)
    Fs = F / np.outer(scale, scale)  # scaled: the verdict must not depend on units
    vals, vecs = np.linalg.eigh(Fs)
    out = {}
    for i, name in enumerate(names):
        v = model.parameters[name].value
        # a direction the points hardly see (eigenvalue below 1e-8 of the largest) has no std worth the name
        flat = any(abs(vecs[i, k]) > 0.1 for k in range(len(vals)) if vals[k] < 1e-8 * vals[-1])
        if flat or np.diag(F)[i] <= 0:
            out[name] = math.inf
            continue
        cov = vecs @ np.diag(1.0 / np.maximum(vals, 1e-300)) @ vecs.T
        s = math.sqrt(max(float(cov[i, i]), 0.0)) / scale[i]
        if is_log_parameter(name, v):
            out[name] = float(abs(v) * max(s, PARAM_FLOOR))
        else:
            out[name] = float(max(s, PARAM_FLOOR / w_ref if name == "tau" else 0.0))
    return out


def undetermined_parameters(model: PlantModel, stds: Mapping[str, float], w_ref: float) -> tuple[str, ...]:
    """The fit's verdict (:func:`~mrftcli.mrft.parameter.is_determined`) on the 95 % interval of each std: wider
    than a factor 1.25 either way, or (tau) than a radian at ``w_ref`` [rad/s]."""
    out = []
    for name, s in stds.items():
        v = model.parameters[name].value
        log = is_log_parameter(name, v)
        wide = not is_determined(0.0, 2 * Z95 * (s / abs(v) if log else s), log, w_ref)
        if not math.isfinite(s) or wide:
            out.append(name)
    return tuple(out)
