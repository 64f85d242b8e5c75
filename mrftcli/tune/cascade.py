"""Outer-loop gains designed on the closed inner loop: ``tune RESULT.json`` of a cascade analysis.

The plant is the exact discrete realisation of the cascade at the controller rate
(:meth:`mrftcli.mrft.cascade.CascadeModel.discrete_realisation`: the sampled inner loop with its
controller, the translational dynamics, both delays), so the margins are those of the sampled outer
loop with no approximation: the loop transfer is L(z) = C_fb(z) G_d(z), z = e^{j omega T}, with
G_d the discrete transfer from the held outer command to the sampled output and C_fb the PD
(derivative on the measurement, first-order filter Tf = Td_c / ``FILTER_N``, backward differences;
:class:`mrftcli.tune.closed_loop.Controller`). Stability is the closed loop's spectral radius.

The design is a PD (the outer plant has an integrator): for each derivative time Td_c on a grid,
the largest Kp that keeps, on every model (the nominal one for ``model-based``, the draws for
``robust``), a stable loop, Ms <= ``ms_max`` and a phase margin >= ``pm_min_deg``; of those, the
one with the least IAE of a unit setpoint step on the nominal model.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import InputError
from ..mrft.cascade import CascadeModel, DiscreteStateSpace
from .closed_loop import Controller, StepMetrics
from .design import FILTER_N, Design, DesignOptions, TuneResult
from .margins import Margins

__all__ = ["tune_cascade", "cascade_margins", "closed_loop_matrix", "step_outputs", "design_record", "worst_of",
           "outer_draws", "cascade_result_v1", "N_DRAWS"]

#: draws of the robust design over the outer estimate and the inner loop (:func:`outer_draws`)
N_DRAWS = 30
_TDC_GRID = np.geomspace(0.02, 5.0, 18)  # derivative times Td_c [s] searched


def cascade_result_v1(data: Mapping[str, Any]) -> TuneResult:
    """A cascade's tune JSON of the previous release (``kind "cascade"``, schema 1: its own design records),
    read into the one :class:`~mrftcli.tune.design.TuneResult` (read for one release: vehicle records hold it).

    Raises
    ------
    InputError
        A missing or malformed field (one line).
    """
    if not isinstance(data.get("designs"), list):
        raise InputError("not a cascade tune JSON (needs kind 'cascade' and 'designs')")

    def num(v: Any) -> float:
        return math.inf if v is None else float(v)

    def figures(m: Any) -> tuple[float, float, float, float, bool]:
        if not isinstance(m, Mapping):
            raise InputError("cascade tune JSON: margins must be an object")
        return (num(m.get("phase_margin_deg")), num(m.get("gain_margin")), num(m.get("Ms")),
                num(m.get("crossover_hz")), bool(m.get("stable")))

    try:
        ms_max, pm_min = float(data["ms_max"]), float(data["pm_min_deg"])
        designs = []
        for d in data["designs"]:
            g = d["generic"]
            c = Controller(float(g["Kp"]), float(g["Ki"]), float(g["Kd"]), float(g["Tf"]), float(g["rate_hz"]))
            worst = None if d.get("worst") is None else figures(d["worst"])
            designs.append(design_record(str(d.get("name", "")), c, figures(d.get("nominal")), worst,
                                   num(d.get("iae")), math.nan, ms_max, pm_min, int(data.get("n_draws") or 0)))
        return TuneResult(CascadeModel.from_json(data["model"]), None, float(data["rate_hz"]), str(data.get("loop", "")),
                          "iae", ms_max, math.inf, math.nan, {}, tuple(designs), tuple(str(n) for n in data.get("notes") or ()))
    except (KeyError, TypeError, ValueError) as err:
        raise InputError(f"cascade tune JSON: {type(err).__name__}: {err}") from None


def design_record(name: str, c: Controller, nominal: tuple[float, float, float, float, bool],
                  worst: tuple[float, float, float, float, bool] | None, iae: float, horizon_s: float, ms_max: float,
                  pm_min: float, n_draws: int, definition: str = "setpoint step") -> Design:
    """A grid design (the cascade's, the process families') as the one :class:`~mrftcli.tune.design.Design`.

    ``nominal`` and ``worst`` are (phase margin [deg], gain margin, Ms, first crossover [Hz], stable): the
    nominal figures become the margins (no delay margin or phase crossover here: NaN), the worst over the
    nominal model and the draws ``posterior["worst"]``; no step figures (NaN); ``iae`` [output unit s] of
    the ``definition`` step."""
    pm, gm, ms, fc, stable = nominal
    post: dict[str, Any] = {}
    if worst is not None:
        post = {"worst": dict(zip(("phase_margin_deg", "gain_margin", "Ms", "crossover_hz", "stable"), worst)),
                "n_draws": n_draws, "worst_of": "the nominal model and every draw"}
    return Design(name, c, "iae", iae, math.nan, Margins(gm, pm, math.nan, ms, 2 * math.pi * fc, math.nan, stable),
                  StepMetrics(*[math.nan] * 6), post, {"ms_max": ms_max, "pm_min_deg": pm_min, "feasible": True}, {},
                  horizon_s, definition)


# ----------------------------------------------------------------------------------------------
# the sampled loop on a discrete plant
# ----------------------------------------------------------------------------------------------
def closed_loop_matrix(ss: DiscreteStateSpace, c: Controller) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, Cy): z_{k+1} = A z_k + B r, y_k = Cy z_k, for the PD/PID ``c`` on the plant ``ss``.

    State z = [x (plant), I_{k-1}, D_{k-1}, y_{k-1}], the controller of
    :class:`~mrftcli.tune.closed_loop.Controller` (derivative on the measurement, backward differences).
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
    du = c.Kp + c.Ki * T
    A = np.zeros((N, N))
    B = np.zeros(N)
    A[:n, :n] = ss.Phi
    A[:n] += np.outer(ss.Gamma, cu)
    B[:n] = ss.Gamma * du
    A[iI], B[iI] = cI, c.Ki * T
    A[iD] = cD
    A[iy] = cy
    return A, B, cy


def _grid(rate_hz: float) -> np.ndarray:
    return np.geomspace(1e-2, 0.999 * math.pi * rate_hz, 600)


def cascade_margins(c: Controller, Gd: np.ndarray, omega: np.ndarray) -> list[tuple[float, float, float, float]]:
    """(phase margin [deg], gain margin, Ms, crossover [Hz]) per row of ``Gd`` (G_d(e^{j omega T}) on ``omega``).

    On the grid: the gain crossovers are where |L| falls through 1 (the least phase margin of them),
    the phase crossovers where the unwrapped phase passes an odd multiple of -180 deg.
    """
    L = c.feedback_response(omega)[None, :] * Gd
    mag = np.abs(L)
    ms = np.max(1.0 / np.abs(1.0 + L), axis=1)
    cross = (mag[:, :-1] >= 1.0) & (mag[:, 1:] < 1.0)
    pm_at = 180.0 + np.degrees(np.angle(L))  # arg L in (-180, 180]: the margin in (0, 360]
    pm_at = np.where(pm_at > 180.0, pm_at - 360.0, pm_at)  # a lead past 180 deg is a lag: (-180, 180]
    pm_at = np.minimum(pm_at[:, :-1], pm_at[:, 1:])  # the grid points either side of the crossover: the lesser
    pm = np.min(np.where(cross, pm_at, np.inf), axis=1)
    turns = np.floor((np.unwrap(np.angle(L), axis=1) + math.pi) / (2 * math.pi))
    phase_cross = np.diff(turns, axis=1) != 0
    gm = np.min(np.where(phase_cross, 1.0 / np.maximum(mag[:, :-1], 1e-300), np.inf), axis=1)
    first = np.argmax(cross, axis=1)
    wc = np.where(cross.any(axis=1), omega[first] / (2 * math.pi), np.nan)
    return [(float(a), float(b), float(m), float(w)) for a, b, m, w in zip(pm, gm, ms, wc)]


def _stable(ss: DiscreteStateSpace, c: Controller) -> bool:
    A, _, _ = closed_loop_matrix(ss, c)
    return bool(np.max(np.abs(np.linalg.eigvals(A))) < 1.0 - 1e-9)


def _margins(c: Controller, plants: Sequence[DiscreteStateSpace], Gd: np.ndarray,
             omega: np.ndarray) -> list[tuple[float, float, float, float, bool]]:
    """(phase margin [deg], gain margin, Ms, first crossover [Hz], stable) per plant."""
    figures = cascade_margins(c, Gd, omega)
    return [(pm, gm, ms, wc, _stable(ss, c)) for ss, (pm, gm, ms, wc) in zip(plants, figures)]


def _ok(c: Controller, plants: Sequence[DiscreteStateSpace], Gd: np.ndarray, omega: np.ndarray, ms_max: float,
        pm_min: float) -> bool:
    """The constraints on every plant: the frequency figures first, stability (eigenvalues) only if they hold."""
    figures = cascade_margins(c, Gd, omega)
    if not all(ms <= ms_max and pm >= pm_min for pm, _, ms, _ in figures):
        return False
    return all(_stable(ss, c) for ss in plants)


def worst_of(m: Sequence[tuple[float, float, float, float, bool]]) -> tuple[float, float, float, float, bool]:
    """The worst of each figure (phase margin, gain margin, Ms, first crossover [Hz], stable) over models."""
    return (min(x[0] for x in m), min(x[1] for x in m), max(x[2] for x in m), min(x[3] for x in m),
            all(x[4] for x in m))


def _iae(ss: DiscreteStateSpace, c: Controller, horizon_s: float) -> float:
    """IAE of a unit setpoint step of the sampled loop [output unit s] (exact: z_k = sum_{j<k} A^j B, by doubling)."""
    A, B, Cy = closed_loop_matrix(ss, c)
    with np.errstate(all="ignore"):
        total = float(np.sum(np.abs(1.0 - step_outputs(A, B, Cy, max(2, int(horizon_s * c.rate_hz)))))) * c.Ts
    return total if math.isfinite(total) else math.inf


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


def _largest_gain(tdc: float, rate_hz: float, plants: Sequence[DiscreteStateSpace], Gd: np.ndarray,
                  omega: np.ndarray, ms_max: float, pm_min: float) -> Controller | None:
    """The largest Kp at derivative time ``tdc`` [s] meeting the constraints on every plant (bisection in log Kp)."""
    def make(kp: float) -> Controller:
        return Controller(kp, 0.0, kp * tdc, tdc / FILTER_N, rate_hz)

    lo, hi = 1e-4, 1e3
    if not _ok(make(lo), plants, Gd, omega, ms_max, pm_min):
        return None
    while hi / lo > 1.02:
        mid = math.sqrt(lo * hi)
        if _ok(make(mid), plants, Gd, omega, ms_max, pm_min):
            lo = mid
        else:
            hi = mid
    return make(lo)


def _design(name: str, nominal: DiscreteStateSpace, plants: Sequence[DiscreteStateSpace], rate_hz: float,
            ms_max: float, pm_min: float, horizon_s: float) -> Design:
    omega = _grid(rate_hz)
    Gd = np.array([p.frequency_response(omega) for p in plants])
    best: tuple[float, Controller] | None = None
    for tdc in _TDC_GRID:
        c = _largest_gain(float(tdc), rate_hz, plants, Gd, omega, ms_max, pm_min)
        if c is None:
            continue
        J = _iae(nominal, c, horizon_s)
        if best is None or J < best[0]:
            best = (J, c)
    if best is None:
        raise InputError(f"no PD keeps Ms <= {ms_max:g} and a phase margin >= {pm_min:g} deg on the cascade "
                         "(relax --ms-max, or check the identified model)")
    J, c = best
    Gn = nominal.frequency_response(omega)[None, :]
    nominal_m = _margins(c, [nominal], Gn, omega)[0]
    worst = worst_of(_margins(c, plants, Gd, omega)) if len(plants) > 1 else None
    return design_record(name, c, nominal_m, worst, J, horizon_s, ms_max, pm_min, len(plants) - 1)


def outer_draws(model: CascadeModel, estimates: Mapping[str, Any], n: int, seed: int = 0) -> list[CascadeModel]:
    """``n`` cascades over the identification's std (Td, K log-normal, tau normal >= 0) and the inner loop's.

    The inner loop is drawn over its own std (:meth:`~mrftcli.mrft.cascade.InnerLoop.draw`: the inner
    analysis' uncertainty) when it carries one.
    """
    rng = np.random.default_rng(seed)
    out = []

    def std(name: str) -> float:
        e = estimates.get(name)
        s = float(getattr(e, "std", 0.0)) if e is not None and not getattr(e, "known", False) else 0.0
        return s if math.isfinite(s) else 0.0

    for _ in range(n):
        inner = model.inner.draw(rng) if model.inner.std else model.inner
        out.append(model.with_inner(inner).with_parameters(
            Td=model.Td * math.exp(rng.normal(0.0, std("Td") / model.Td)),
            tau=max(0.0, model.tau + rng.normal(0.0, std("tau"))),
            K=model.K * math.exp(rng.normal(0.0, std("K") / model.K))))
    return out


def tune_cascade(model: CascadeModel, rate_hz: float, draws: Sequence[CascadeModel] = (), *,
                 options: DesignOptions = DesignOptions(), loop: str = "", horizon_s: float | None = None) -> TuneResult:
    """Outer-loop PD gains on the cascade (the module docstring): model-based, and robust over ``draws``.

    The cascade's strategy of the one tune driver (:func:`mrftcli.tune.design.tune` calls it for a
    :class:`~mrftcli.mrft.cascade.CascadeModel`).

    Parameters
    ----------
    model : CascadeModel
        The identified cascade (nominal).
    rate_hz : float
        The outer controller's rate [Hz] (the inner controller's or a whole divisor of it).
    draws : sequence of CascadeModel
        Models the robust design must hold its margins on (:func:`outer_draws`); fewer than 2: no robust design.
    options : DesignOptions
        ``ms_max`` [-] and ``pm_min_deg`` [deg]; a PD, its IAE (the other settings are eq. (2)'s: refused).
    loop : str
        The outer loop's name.
    horizon_s : float, optional
        The step's horizon [s] for the IAE (default: 6 periods of the loop's MRFT cycle at beta -0.7).

    Raises
    ------
    InputError
        No PD meets the constraints, or an option of eq. (2)'s designs.
    """
    if (options.objective != "iae" or options.effort_max is not None or options.rate_filter is not None
            or "mrft-rule" in (options.designs or ()) or any(k != "PD" for k in options.kinds or ())):
        raise InputError("a cascade's outer loop is designed as a PD of least IAE (model-based, robust): "
                         "--objective, --effort-max, the mrft-rule design and --kind PID are for eq. (2) loops")
    ms_max, pm_min_deg = options.ms_max, options.pm_min_deg
    nominal = model.discrete_realisation(rate_hz)
    if horizon_s is None:
        horizon_s = 6.0 / model.sampled_limit_cycle(-0.7, 1.0, rate_hz).frequency_hz
    designs = [_design("model-based", nominal, [nominal], rate_hz, ms_max, pm_min_deg, horizon_s)]
    notes = [f"PD (derivative on the measurement, Tf = Kd / (Kp {FILTER_N:g})) on the exact sampled cascade at "
             f"{rate_hz:g} Hz: Ms <= {ms_max:g}, phase margin >= {pm_min_deg:g} deg; least IAE of a unit step"]
    if len(draws) >= 2:
        plants = [nominal] + [d.discrete_realisation(rate_hz) for d in draws]
        designs.append(_design("robust", nominal, plants, rate_hz, ms_max, pm_min_deg, horizon_s))
        inner = "and of the inner plant over its std" if model.inner.std else "the inner model at its estimate"
        notes.append(f"robust: the constraints held on the nominal model and {len(draws)} draws of the outer Td, tau "
                     f"(and K) over their intervals, {inner}")
    return TuneResult(model, None, rate_hz, loop, "iae", ms_max, math.inf, horizon_s, {}, tuple(designs), tuple(notes))
