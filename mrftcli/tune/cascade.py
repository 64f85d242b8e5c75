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
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import InputError
from ..jsonable import check_schema_version
from ..mrft.cascade import CascadeModel, DiscreteStateSpace
from .closed_loop import Controller
from .design import FILTER_N

__all__ = ["CascadeMargins", "CascadeDesign", "CascadeTuneResult", "tune_cascade", "cascade_margins",
           "closed_loop_matrix", "outer_draws", "CASCADE_TUNE_SCHEMA_VERSION"]

#: version of :meth:`CascadeTuneResult.to_json`
CASCADE_TUNE_SCHEMA_VERSION = 1
_TDC_GRID = np.geomspace(0.02, 5.0, 18)  # derivative times Td_c [s] searched


@dataclass(frozen=True)
class CascadeMargins:
    """Margins of the sampled outer loop on one model.

    Attributes
    ----------
    phase_margin_deg : float
        The least phase margin over the gain crossovers [deg] (inf: no crossover).
    gain_margin : float
        The least gain margin over the phase crossovers [-] (inf: none).
    Ms : float
        Sensitivity peak max |1 / (1 + L)| [-].
    crossover_hz : float
        The first gain crossover [Hz].
    stable : bool
        The closed loop's spectral radius is below 1.
    """

    phase_margin_deg: float
    gain_margin: float
    Ms: float
    crossover_hz: float
    stable: bool

    def to_json(self) -> dict[str, Any]:
        def finite(x: float) -> float | None:
            return x if math.isfinite(x) else None

        return {"phase_margin_deg": finite(self.phase_margin_deg), "gain_margin": finite(self.gain_margin),
                "Ms": finite(self.Ms), "crossover_hz": finite(self.crossover_hz), "stable": self.stable}

    @classmethod
    def from_json(cls, d: Any) -> CascadeMargins:
        if not isinstance(d, Mapping):
            raise InputError("cascade tune JSON: margins must be an object")

        def num(k: str) -> float:
            v = d.get(k)
            return math.inf if v is None else float(v)

        return cls(num("phase_margin_deg"), num("gain_margin"), num("Ms"), num("crossover_hz"), bool(d.get("stable")))


@dataclass(frozen=True)
class CascadeDesign:
    """One outer-loop design: the controller, its nominal margins and the worst over the draws.

    Attributes
    ----------
    name : str
        ``"model-based"`` (the nominal model) or ``"robust"`` (every draw).
    controller : Controller
        The PD (generic form: Kp [command / output unit], Kd [command s / output unit], Tf [s], rate).
    nominal : CascadeMargins
        On the nominal model.
    worst : CascadeMargins or None
        The worst of each figure over the draws (None without draws).
    iae : float
        IAE of a unit setpoint step on the nominal model [output unit s].
    """

    name: str
    controller: Controller
    nominal: CascadeMargins
    worst: CascadeMargins | None
    iae: float

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "kind": "PD", "generic": self.controller.to_dict(),
                "nominal": self.nominal.to_json(), "worst": None if self.worst is None else self.worst.to_json(),
                "iae": self.iae if math.isfinite(self.iae) else None}

    @classmethod
    def from_json(cls, d: Any) -> CascadeDesign:
        if not isinstance(d, Mapping) or not isinstance(d.get("generic"), Mapping):
            raise InputError("cascade tune JSON: each design needs 'generic' gains")
        g = d["generic"]
        try:
            c = Controller(float(g["Kp"]), float(g["Ki"]), float(g["Kd"]), float(g["Tf"]), float(g["rate_hz"]))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"cascade tune JSON: bad generic gains ({err})") from err
        worst = d.get("worst")
        iae = d.get("iae")
        return cls(str(d.get("name", "")), c, CascadeMargins.from_json(d.get("nominal")),
                   None if worst is None else CascadeMargins.from_json(worst), math.inf if iae is None else float(iae))


@dataclass(frozen=True)
class CascadeTuneResult:
    """Outer-loop designs on the cascade (``tune RESULT.json`` of a cascade analysis).

    Attributes
    ----------
    loop : str
        The outer loop.
    rate_hz : float
        The controller rate [Hz].
    model : CascadeModel
        The nominal cascade.
    designs : tuple of CascadeDesign
        ``model-based`` and (with draws) ``robust``.
    ms_max, pm_min_deg : float
        The constraints [-], [deg].
    n_draws : int
        Draws of the robust design.
    notes : tuple of str
        What the designs rest on.
    """

    loop: str
    rate_hz: float
    model: CascadeModel
    designs: tuple[CascadeDesign, ...]
    ms_max: float
    pm_min_deg: float
    n_draws: int = 0
    notes: tuple[str, ...] = field(default=())

    def get(self, name: str) -> CascadeDesign:
        """The design called ``name``."""
        for d in self.designs:
            if d.name == name:
                return d
        raise InputError(f"no {name!r} design (have: {', '.join(d.name for d in self.designs)})")

    def to_json(self) -> dict[str, Any]:
        """``{"schema_version", "kind": "cascade", "loop", "rate_hz", "model", "designs", "ms_max", "pm_min_deg", ...}``."""
        return {"schema_version": CASCADE_TUNE_SCHEMA_VERSION, "kind": "cascade", "loop": self.loop,
                "rate_hz": self.rate_hz, "model": self.model.to_json(), "designs": [d.to_json() for d in self.designs],
                "ms_max": self.ms_max, "pm_min_deg": self.pm_min_deg, "n_draws": self.n_draws,
                "notes": list(self.notes)}

    @classmethod
    def from_json(cls, data: Any) -> CascadeTuneResult:
        """The record of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input."""
        d = check_schema_version(data, "cascade tune JSON", CASCADE_TUNE_SCHEMA_VERSION)
        if d.get("kind") != "cascade" or not isinstance(d.get("designs"), list):
            raise InputError("not a cascade tune JSON (needs kind 'cascade' and 'designs')")
        try:
            return cls(str(d.get("loop", "")), float(d["rate_hz"]), CascadeModel.from_json(d["model"]),
                       tuple(CascadeDesign.from_json(x) for x in d["designs"]), float(d["ms_max"]),
                       float(d["pm_min_deg"]), int(d.get("n_draws") or 0), tuple(str(n) for n in d.get("notes") or ()))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"cascade tune JSON: {type(err).__name__}: {err}") from err


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


def _margins(c: Controller, plants: Sequence[DiscreteStateSpace], Gd: np.ndarray, omega: np.ndarray) -> list[CascadeMargins]:
    figures = cascade_margins(c, Gd, omega)
    return [CascadeMargins(pm, gm, ms, wc, _stable(ss, c)) for ss, (pm, gm, ms, wc) in zip(plants, figures)]


def _ok(c: Controller, plants: Sequence[DiscreteStateSpace], Gd: np.ndarray, omega: np.ndarray, ms_max: float,
        pm_min: float) -> bool:
    """The constraints on every plant: the frequency figures first, stability (eigenvalues) only if they hold."""
    figures = cascade_margins(c, Gd, omega)
    if not all(ms <= ms_max and pm >= pm_min for pm, _, ms, _ in figures):
        return False
    return all(_stable(ss, c) for ss in plants)


def _worst(m: Sequence[CascadeMargins]) -> CascadeMargins:
    return CascadeMargins(min(x.phase_margin_deg for x in m), min(x.gain_margin for x in m), max(x.Ms for x in m),
                          min(x.crossover_hz for x in m), all(x.stable for x in m))


def _iae(ss: DiscreteStateSpace, c: Controller, horizon_s: float) -> float:
    """IAE of a unit setpoint step of the sampled loop [output unit s] (exact: z_k = sum_{j<k} A^j B, by doubling)."""
    A, B, Cy = closed_loop_matrix(ss, c)
    count = max(2, int(horizon_s * c.rate_hz))
    S = np.empty((count, A.shape[0]))
    S[0] = 0.0
    step, have = A.copy(), 1  # step = A^have
    with np.errstate(all="ignore"):
        while have < count:
            take = min(have, count - have)
            s_have = A @ S[have - 1] + B
            S[have:have + take] = np.einsum("ij,nj->ni", step, S[:take]) + s_have
            have += take
            step = step @ step
        total = float(np.sum(np.abs(1.0 - S @ Cy))) * c.Ts
    return total if math.isfinite(total) else math.inf


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
            ms_max: float, pm_min: float, horizon_s: float) -> CascadeDesign:
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
    worst = _worst(_margins(c, plants, Gd, omega)) if len(plants) > 1 else None
    return CascadeDesign(name, c, nominal_m, worst, J)


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


def tune_cascade(model: CascadeModel, rate_hz: float, *, draws: Sequence[CascadeModel] = (), loop: str = "",
                 ms_max: float = 1.6, pm_min_deg: float = 45.0, horizon_s: float | None = None) -> CascadeTuneResult:
    """Outer-loop PD gains on the cascade (the module docstring): model-based, and robust over ``draws``.

    Parameters
    ----------
    model : CascadeModel
        The identified cascade (nominal).
    rate_hz : float
        The outer controller's rate [Hz] (the inner controller's or a whole divisor of it).
    draws : sequence of CascadeModel
        Models the robust design must hold its margins on (:func:`outer_draws`); empty: no robust design.
    ms_max : float
        Limit on the sensitivity peak [-].
    pm_min_deg : float
        Least phase margin [deg].
    horizon_s : float, optional
        The step's horizon [s] for the IAE (default: 6 periods of the loop's MRFT cycle at beta -0.7).

    Raises
    ------
    InputError
        No PD meets the constraints, or bad limits.
    """
    if not (math.isfinite(ms_max) and ms_max > 1.0):
        raise InputError(f"--ms-max must be a number above 1, got {ms_max!r}")
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
    return CascadeTuneResult(loop, rate_hz, model, tuple(designs), ms_max, pm_min_deg, len(draws), tuple(notes))
