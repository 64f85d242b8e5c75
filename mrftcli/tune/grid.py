"""The one gain search of every model but eq. (2): the process families and the cascade's outer loop.

:func:`mrftcli.tune.design.tune` (the one tune driver) designs here for any
:class:`~mrftcli.mrft.model.PlantModel` that is not eq. (2)'s :class:`~mrftcli.mrft.model.LoopModel`
and returns the one :class:`~mrftcli.tune.design.TuneResult` record. What a model kind brings is a
:class:`_Strategy` (its plants, candidate controllers and gain scan); the search is the same:

* the plant is the exact zero-order-hold equivalent at the controller rate, so the margins are those
  of the sampled loop with no approximation. A family (FOPDT/SOPDT/IPDT/FOIPDT, a declared structure):
  its delay-free realisation ``realisation()`` and its delay ``tau`` (:func:`discretise`: tau = d T + eps,
  the input held over a tick reaches the plant eps late, the modified z-transform). The cascade
  (:class:`~mrftcli.mrft.cascade.CascadeModel`): its exact discrete realisation at the controller rate
  (:meth:`~mrftcli.mrft.cascade.CascadeModel.discrete_realisation`: the sampled inner loop with its
  controller, the translational dynamics, both delays);
* the controller is :class:`~mrftcli.mrft.controller.Controller` (parallel PID, derivative on the
  measurement through Tf = Td_c / ``FILTER_N``, backward differences); the loop's figures are
  :func:`~mrftcli.tune.closed_loop.closed_loop_matrix` and eq. (2)'s margins
  (:func:`~mrftcli.tune.margins.stack_margins`: the crossings refined on the exact response, stability the
  Nyquist criterion with the plant's integrators and unstable poles counted), one implementation of each;
* for each kind, on a grid of integral times Ti (PI, PID) and derivative times Td_c (PD, PID), the
  largest Kp that keeps every model (the nominal one for ``model-based``; the nominal and the draws for
  ``robust``) stable with Ms <= ``ms_max`` and a phase margin >= ``pm_min_deg``; of those, the least IAE
  on the nominal model: of a unit load step at the plant input for a PI/PID (the disturbance a process
  loop rejects; Astrom-Hagglund's criterion), of a unit setpoint step for a PD.

The families' grid is scaled by the nominal plant's ultimate period Tu (PD offered on integrating plants
only: on a self-regulating plant a PD leaves a steady error). The cascade's outer loop (the outer plant
has an integrator) is a PD with Td_c on a grid in seconds, its IAE that of a unit setpoint step.

What the record holds for these designs: the nominal margins (gain and phase margin, Ms, the crossover of
the phase margin as ``w_gc``, stability; the delay margin and the phase crossover are not recorded: NaN),
the worst of each figure over the nominal model and the draws in ``posterior["worst"]``, no step
figures (NaN), the criterion and its definition; a family's ultimate period in ``rule_cycle``.

A plant whose gain is negative (reverse acting) is designed on -G: the controller's gains are
positive and act on -e (``reverse_acting`` in the record).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..mrft.cascade import CascadeModel, DiscreteStateSpace
from ..mrft.model import PlantModel
from .closed_loop import (Controller, DiscretePlant, PlantStack, StepMetrics, augmented, closed_loop_matrix, held_delay,
                          step_outputs)
from .design import FILTER_N, Design, DesignOptions, TuneResult, controller
from .margins import LoopMargins, Margins, largest_holding, margin_grid, plant_response, stack_margins

__all__ = ["discretise", "model_draws", "outer_draws", "tune_grid", "cascade_result_v1", "GRID_KINDS", "GRID_DESIGNS", "N_DRAWS"]

#: the controllers designed (PD on integrating plants only)
GRID_KINDS = ("PI", "PID", "PD")
#: the designs made (robust with draws only)
GRID_DESIGNS = ("model-based", "robust")
#: draws of the robust design from an identification's intervals (:func:`model_draws`, :func:`outer_draws`)
N_DRAWS = 30
_CASCADE_TDC_GRID = np.geomspace(0.02, 5.0, 18)  # the cascade's derivative times Td_c [s]
_CASCADE_GAINS = (1e3, 1e-4)  # the cascade's scan of Kp: the bisection between them when the lower one holds
_TI_GRID = np.geomspace(0.1, 10.0, 14)  # integral times Ti, in ultimate periods Tu
_TDC_GRID = np.geomspace(0.02, 0.5, 8)  # derivative times Td_c, in Tu
_PID_TDC_GRID = np.geomspace(0.03, 0.3, 5)
_LOAD_PERIODS = 20.0  # horizon of the load step, in Tu (integral action is slow)
_STEP_PERIODS = 8.0  # horizon of a PD's setpoint step, in Tu
#: a pole of the discrete plant within this of z = 1 is an integrator's, beyond 1 + this outside the unit circle
_POLE_TOL = 1e-9
#: delay-augmented loops above this order are stepped as sparse matrices (the doubling's products cost N^3)
_DENSE_ORDER = 64
FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------------------------
# the exact discrete plant
# ----------------------------------------------------------------------------------------------
def discretise(model: PlantModel, rate_hz: float) -> DiscreteStateSpace:
    """The exact ZOH equivalent of ``model`` with its delay at ``rate_hz`` [Hz].

    tau = d T + eps (0 <= eps < T): over a tick the plant sees u_{k-d-1} for eps seconds, then u_{k-d}.
    State X_k = [x_k, u_{k-1}, ..., u_{k-d-1}] so the delay is part of the state (the closed loop's
    eigenvalues then decide stability).

    Raises
    ------
    InputError
        A plant with direct feedthrough (D != 0: not a relay-test plant), or a bad rate.
    """
    return augmented(held_delay(model, rate_hz))


# ----------------------------------------------------------------------------------------------
# the draws
# ----------------------------------------------------------------------------------------------
def model_draws(model: PlantModel, estimates: Sequence[Any], n: int, seed: int = 0) -> tuple[list[PlantModel], tuple[str, ...]]:
    """``n`` plants over the identification's uncertainty, and notes on how they were drawn.

    A positive parameter is drawn log-normal with its std (relative spread std / value), one that may
    be zero or negative normal, each kept within its bounds; an undetermined one uniformly over its
    95 % interval. ``estimates`` are :class:`~mrftcli.mrft.parameter.ParameterEstimate` records.

    Raises
    ------
    InputError
        An undetermined parameter whose interval is open (nothing bounds the draws).
    """
    rng = np.random.default_rng(seed)
    bounds = {p.name: p.bounds for p in model.parameters.values()}
    notes: list[str] = []
    free = [e for e in estimates if not e.known and e.name in bounds]
    for e in free:
        if not e.determined:
            if not (math.isfinite(e.ci95_low) and math.isfinite(e.ci95_high)):
                raise InputError(f"{e.name} is not determined by the tests and its interval is open: give it with "
                                 f"analyze --param {e.name}=VALUE (or a --range) before tuning")
            notes.append(f"{e.name} is not determined by the tests: drawn uniformly over its 95 % interval "
                         f"[{e.ci95_low:.4g}, {e.ci95_high:.4g}] {e.unit}")
    out: list[PlantModel] = []
    for _ in range(n):
        values: dict[str, float] = {}
        for e in free:
            lo, hi = bounds[e.name]
            if not e.determined:
                v = float(rng.uniform(e.ci95_low, e.ci95_high))
            elif not (e.std and math.isfinite(e.std) and e.std > 0):
                continue
            elif e.value > 0 and lo >= 0:
                v = e.value * math.exp(rng.normal(0.0, e.std / e.value))
            else:
                v = e.value + rng.normal(0.0, e.std)
            values[e.name] = float(min(max(v, lo), hi))
        if values:
            out.append(model.with_parameters(**values))
    return out, tuple(notes)


def outer_draws(model: CascadeModel, estimates: Sequence[Any], n: int, seed: int = 0) -> list[CascadeModel]:
    """``n`` cascades over the identification's std (Td, K log-normal, tau normal >= 0) and the inner loop's.

    ``estimates`` are :class:`~mrftcli.mrft.parameter.ParameterEstimate` records (as :func:`model_draws`'). The
    inner loop is drawn over its own std (:meth:`~mrftcli.mrft.cascade.InnerLoop.draw`: the inner analysis'
    uncertainty) when it carries one.
    """
    rng = np.random.default_rng(seed)
    out = []
    by_name = {e.name: e for e in estimates}

    def std(name: str) -> float:
        e = by_name.get(name)
        s = float(getattr(e, "std", 0.0)) if e is not None and not getattr(e, "known", False) else 0.0
        return s if math.isfinite(s) else 0.0

    for _ in range(n):
        inner = model.inner.draw(rng) if model.inner.std else model.inner
        out.append(model.with_inner(inner).with_parameters(
            Td=model.Td * math.exp(rng.normal(0.0, std("Td") / model.Td)),
            tau=max(0.0, model.tau + rng.normal(0.0, std("tau"))),
            K=model.K * math.exp(rng.normal(0.0, std("K") / model.K))))
    return out


# ----------------------------------------------------------------------------------------------
# the sampled loop and its figures
# ----------------------------------------------------------------------------------------------
def _stepped(A: FloatArray, B: FloatArray, Cy: FloatArray, count: int) -> FloatArray:
    """As :func:`step_outputs`, tick by tick with A sparse (a long delay's shift chain is mostly zeros)."""
    from scipy.sparse import csr_matrix

    As = csr_matrix(A)
    z = np.zeros(A.shape[0])
    y = np.empty(count)
    with np.errstate(all="ignore"):
        for k in range(count):
            y[k] = Cy @ z
            z = As @ z + B
    return y


def _iae(ss: DiscreteStateSpace, c: Controller, horizon_s: float, load: bool) -> float:
    """IAE [output unit s] of a unit load step at the plant input (``load``) or of a unit setpoint step."""
    A, B, Cy = closed_loop_matrix(ss, c)
    if load:
        B = np.zeros(A.shape[0])
        B[:ss.order] = ss.Gamma
    count = max(2, int(horizon_s * c.rate_hz))
    y = step_outputs(A, B, Cy, count) if A.shape[0] <= _DENSE_ORDER else _stepped(A, B, Cy, count)
    with np.errstate(all="ignore"):
        total = float(np.sum(np.abs(y if load else 1.0 - y))) * c.Ts
    return total if math.isfinite(total) else math.inf


@dataclass(frozen=True)
class _Plants:
    """The nominal plant's state space (the IAE's) and every model the constraints hold on (the nominal one and
    the draws, the gain's sign applied) for :func:`~mrftcli.tune.margins.stack_margins`: ``stack``, each
    plant's poles at z = 1 (``integrators``) and outside the unit circle (``unstable``), and their transfer on
    :func:`~mrftcli.tune.margins.margin_grid` (``response``: the same for every controller tried)."""

    nominal: DiscreteStateSpace
    stack: PlantStack
    integrators: NDArray[np.int64]
    unstable: NDArray[np.int64]
    response: NDArray[np.complex128]

    @classmethod
    def of(cls, plants: Sequence[DiscretePlant], sign: float = 1.0) -> "_Plants":
        """The plants ``plants`` (held delays at one rate, the nominal one first; the gain's ``sign`` applied)."""
        held = [DiscretePlant(h.Phi, h.Gamma, sign * h.C, h.d, h.rate_hz) for h in plants]
        stack = PlantStack.of(held)
        poles = [np.linalg.eigvals(h.Phi) for h in held]
        at_one = np.array([int(np.sum(np.abs(p - 1.0) < _POLE_TOL)) for p in poles])
        outside = np.array([int(np.sum((np.abs(p) > 1.0 + _POLE_TOL) & (np.abs(p - 1.0) >= _POLE_TOL))) for p in poles])
        rate = held[0].rate_hz
        w = margin_grid(rate, int(stack.d.max()))
        return cls(augmented(held[0]), stack, at_one, outside, stack.transfer(np.exp(1j * w / rate)))

    def margins(self, c: Controller, search: bool = False) -> LoopMargins:
        """:func:`~mrftcli.tune.margins.stack_margins` of ``c`` on every model (``search``: the constraints only)."""
        return stack_margins(c, self.stack, (), self.integrators, self.unstable, self.response, search)

    def ok(self, c: Controller, o: DesignOptions) -> bool:
        """The constraints on every model: stable, Ms <= ``ms_max``, phase margin >= ``pm_min_deg``."""
        w = margin_grid(c.rate_hz, int(self.stack.d.max()))
        # the cheap figure first (most gains tried fail it): Ms on the grid, which the refined Ms is at least
        if float(np.max(1.0 / np.abs(1.0 + c.feedback_response(w)[None, :] * self.response))) > o.ms_max:
            return False
        m = self.margins(c, search=True)
        return bool(np.all(m.stable) and np.all(m.Ms <= o.ms_max) and np.all(m.phase_margin_deg >= o.pm_min_deg))


# ----------------------------------------------------------------------------------------------
# the records
# ----------------------------------------------------------------------------------------------
def design_record(name: str, c: Controller, nominal: tuple[float, float, float, float, bool],
                  worst: tuple[float, float, float, float, bool] | None, iae: float, horizon_s: float, ms_max: float,
                  pm_min: float, n_draws: int, definition: str = "setpoint step") -> Design:
    """A grid design as the one :class:`~mrftcli.tune.design.Design`.

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


def _worst(m: Sequence[tuple[float, float, float, float, bool]]) -> tuple[float, float, float, float, bool]:
    """The worst of each figure (phase margin, gain margin, Ms, first crossover [Hz], stable) over models."""
    return (min(x[0] for x in m), min(x[1] for x in m), max(x[2] for x in m), min(x[3] for x in m),
            all(x[4] for x in m))


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


# ----------------------------------------------------------------------------------------------
# the one search
# ----------------------------------------------------------------------------------------------
Maker = Callable[[float], Controller]


def _maker(ti: float | None, tdc: float, rate_hz: float) -> Maker:
    """Kp -> the controller with integral time ``ti`` (None: no integral) and derivative time ``tdc`` [s]
    (:func:`~mrftcli.tune.design.controller`)."""
    return lambda kp: controller("PD" if ti is None else "PID", kp, tdc, rate_hz, ti)


def _largest_gain(make: Maker, gains: FloatArray, p: _Plants, o: DesignOptions) -> Controller | None:
    """The largest Kp meeting the constraints (:func:`~mrftcli.tune.margins.largest_holding`: a scan down ``gains``,
    then a bisection in log Kp to 2 %; on an integrating plant a PI is infeasible at low gains too: the feasible
    gains are an interval)."""
    kp = largest_holding(lambda kp: p.ok(make(kp), o), gains, 1.02)
    return None if kp is None else make(kp)


@dataclass(frozen=True)
class _Strategy:
    """What a model kind brings to the one search: its plants (``plants(models)``), its controllers per kind
    (``candidates(kind)``), the Kp scanned (``gains``), each kind's horizon [s] and what it refuses."""

    plants: Callable[[Sequence[PlantModel]], _Plants]
    candidates: Callable[[str], list[Maker]]
    gains: FloatArray
    horizons: Mapping[str, float]


def _design(name: str, kind: str, p: _Plants, st: _Strategy, o: DesignOptions) -> Design | None:
    """The least-IAE controller of ``kind`` over the strategy's candidates, each at its largest feasible gain."""
    load = kind != "PD"
    horizon = st.horizons[kind]
    best: tuple[float, Controller] | None = None
    for make in st.candidates(kind):
        c = _largest_gain(make, st.gains, p, o)
        if c is None:
            continue
        J = _iae(p.nominal, c, horizon, load)
        if best is None or J < best[0]:
            best = (J, c)
    if best is None:
        return None
    J, c = best
    m = p.margins(c)  # row 0 the nominal: each row's figures are its own
    rows = [(float(m.phase_margin_deg[i]), float(m.gain_margin[i]), float(m.Ms[i]), float(m.w_gc[i]) / (2 * math.pi),
             bool(m.stable[i])) for i in range(len(m))]
    worst = _worst(rows) if len(rows) > 1 else None
    return design_record(name, c, rows[0], worst, J, horizon, o.ms_max, o.pm_min_deg, len(p.stack.d) - 1,
                         "load step" if load else "setpoint step")


def _search(model: PlantModel, draws: Sequence[PlantModel], kinds: Sequence[str], st: _Strategy,
            o: DesignOptions) -> list[Design | None]:
    """The model-based designs (and the robust ones, with two draws or more) of every kind (None: no
    controller of that kind meets the constraints)."""
    names = o.designs or GRID_DESIGNS
    sets = [("model-based", st.plants([model]))] if "model-based" in names else []
    if len(draws) >= 2 and "robust" in names:
        sets.append(("robust", st.plants([model, *draws])))
    return [_design(name, kind, p, st, o) for kind in kinds for name, p in sets]


def _family_plants(rate_hz: float, sign: float) -> Callable[[Sequence[PlantModel]], _Plants]:
    def plants(models: Sequence[PlantModel]) -> _Plants:
        return _Plants.of([held_delay(m, rate_hz) for m in models], sign)  # each model's held delay once
    return plants


def _cascade_plants(rate_hz: float) -> Callable[[Sequence[PlantModel]], _Plants]:
    def plants(models: Sequence[PlantModel]) -> _Plants:
        # the exact sampled cascade (its delays are states): a held delay of no whole tick, all of the input new,
        # padded with states at rest to the largest order of the draws (one stack; the transfer is the same)
        ss = [m.discrete_realisation(rate_hz) for m in models if isinstance(m, CascadeModel)]
        n = max(s.Phi.shape[0] for s in ss)

        def held(s: DiscreteStateSpace) -> DiscretePlant:
            Phi, Gamma, C = np.zeros((n, n)), np.zeros((2, n)), np.zeros(n)
            k = s.Phi.shape[0]
            Phi[:k, :k], Gamma[1, :k], C[:k] = s.Phi, s.Gamma, s.C
            return DiscretePlant(Phi, Gamma, C, 0, rate_hz)
        return _Plants.of([held(s) for s in ss])
    return plants


def _family_candidates(tu: float, rate_hz: float) -> Callable[[str], list[Maker]]:
    """Controller makers over the kind's grid of (Ti, Td_c), in ultimate periods ``tu`` [s]."""
    def candidates(kind: str) -> list[Maker]:
        if kind == "PI":
            return [_maker(float(ti) * tu, 0.0, rate_hz) for ti in _TI_GRID]
        if kind == "PD":
            return [_maker(None, float(td) * tu, rate_hz) for td in _TDC_GRID]
        return [_maker(float(ti) * tu, float(td) * tu, rate_hz) for ti in _TI_GRID for td in _PID_TDC_GRID
                if ti >= 2.0 * td]
    return candidates


# ----------------------------------------------------------------------------------------------
# the strategies
# ----------------------------------------------------------------------------------------------
def _sign(model: PlantModel) -> float:
    """+1 or -1: the sign of the plant's gain (K when the structure has one, else its low-frequency response)."""
    params = model.parameters
    if "K" in params:
        return 1.0 if params["K"].value > 0 else -1.0
    w = 1e-6
    g = complex(np.asarray(model.frequency_response(np.array([w])))[0]) * (1j * w) ** _integrators(model)
    return 1.0 if g.real > 0 else -1.0


def _ultimate(model: PlantModel, rate_hz: float, sign: float) -> float:
    """The ultimate angular frequency [rad/s] of the sampled loop: the first -180 deg crossing of G_d."""
    omega = np.geomspace(1e-6, 0.999 * math.pi, 4000) * rate_hz
    phase = np.unwrap(np.angle(sign * plant_response([model], rate_hz, omega)[0]))
    phase -= 2 * math.pi * round(float(phase[0]) / (2 * math.pi))  # start in (-pi, pi]
    below = np.nonzero(phase <= -math.pi)[0]
    return float(omega[below[0]]) if below.size else float(omega[-1])


def _integrators(model: PlantModel) -> int:
    """The plant's poles at s = 0."""
    return int(np.sum(np.abs(np.linalg.eigvals(np.asarray(model.realisation().A, float))) < 1e-12))


def _check(options: DesignOptions, cascade: bool) -> None:
    """Options of eq. (2)'s designs that the grid search does not take: refused, never ignored."""
    if cascade:
        if (options.objective != "iae" or options.effort_max is not None or options.rate_filter is not None
                or "mrft-rule" in (options.designs or ()) or any(k != "PD" for k in options.kinds or ())):
            raise InputError("a cascade's outer loop is designed as a PD of least IAE (model-based, robust): "
                             "--objective, --effort-max, the mrft-rule design and --kind PID are for eq. (2) loops")
        return
    if options.objective != "iae":
        raise InputError(f"--objective {options.objective}: the process families' designs minimise the IAE "
                         "(of a load step for a PI/PID)")
    if options.effort_max is not None or options.rate_filter is not None:
        raise InputError("a noise-gain limit (--effort-max) and a stack's rate filter are for eq. (2) loops")
    if "mrft-rule" in (options.designs or ()):
        raise InputError("the mrft-rule design is the DNN-MRFT rule for eq. (2) loops; a process plant has "
                         "model-based and robust designs")
    bad = [k for k in options.kinds or () if k not in GRID_KINDS]
    if bad:
        raise InputError(f"unknown controller kind(s) {bad}; choose from {', '.join(GRID_KINDS)}")


def _tune_cascade(model: CascadeModel, rate_hz: float, draws: Sequence[PlantModel], o: DesignOptions,
                  loop: str) -> TuneResult:
    """The cascade's outer PD (module docstring); every design must exist (the vehicle exports both)."""
    horizon = 6.0 / model.sampled_limit_cycle(-0.7, 1.0, rate_hz).frequency_hz
    st = _Strategy(_cascade_plants(rate_hz), lambda kind: [_maker(None, float(t), rate_hz) for t in _CASCADE_TDC_GRID],
                   np.array(_CASCADE_GAINS), {"PD": horizon})
    draws = [d for d in draws if isinstance(d, CascadeModel)]
    designs = _search(model, draws, ("PD",), st, o)
    if not all(designs):
        raise InputError(f"no PD keeps Ms <= {o.ms_max:g} and a phase margin >= {o.pm_min_deg:g} deg on the cascade "
                         "(relax --ms-max, or check the identified model)")
    notes = [f"PD (derivative on the measurement, Tf = Kd / (Kp {FILTER_N:g})) on the exact sampled cascade at "
             f"{rate_hz:g} Hz: Ms <= {o.ms_max:g}, phase margin >= {o.pm_min_deg:g} deg; least IAE of a unit step"]
    if len(draws) >= 2:
        inner = "and of the inner plant over its std" if model.inner.std else "the inner model at its estimate"
        notes.append(f"robust: the constraints held on the nominal model and {len(draws)} draws of the outer Td, tau "
                     f"(and K) over their intervals, {inner}")
    return TuneResult(model, None, rate_hz, loop, "iae", o.ms_max, math.inf, horizon, {},
                      tuple(d for d in designs if d is not None), tuple(notes))


def tune_grid(model: PlantModel, rate_hz: float, draws: Sequence[PlantModel], options: DesignOptions,
              loop: str = "") -> TuneResult:
    """Model-based (and, with ``draws``, robust) gains by the one grid search (module docstring): PI/PID (and PD
    on integrating plants) for a family, an outer PD for a :class:`~mrftcli.mrft.cascade.CascadeModel`.

    Called by :func:`mrftcli.tune.design.tune` for a model that is not eq. (2)'s.

    Parameters
    ----------
    model : PlantModel
        The nominal plant.
    rate_hz : float
        The controller rate [Hz] (the cascade's outer one: the inner controller's or a whole divisor of it).
    draws : sequence of PlantModel
        Models the robust design holds its constraints on (:func:`model_draws`, :func:`outer_draws`);
        fewer than 2: none.
    options : DesignOptions
        ``ms_max``, ``pm_min_deg``, the ``designs`` and the ``kinds`` (None: PI and PID, and PD on an
        integrating plant; the cascade: PD); the objective is the IAE.
    loop : str
        The loop's name (for the record).

    Raises
    ------
    InputError
        A bad rate, a plant with feedthrough, an option of eq. (2)'s designs, or no controller of any
        kind meets the constraints (the cascade: no PD for one of its designs).
    """
    _check(options, isinstance(model, CascadeModel))
    if isinstance(model, CascadeModel):
        return _tune_cascade(model, rate_hz, draws, options, loop)
    discretise(model, rate_hz)  # checks the rate and the plant before the work
    integrating = _integrators(model) > 0
    kinds = tuple(options.kinds) if options.kinds is not None else (GRID_KINDS if integrating else ("PI", "PID"))
    sign = _sign(model)
    wu = _ultimate(model, rate_hz, sign)
    tu = 2 * math.pi / wu
    ku = 1.0 / max(float(np.abs(plant_response([model], rate_hz, np.array([wu])))[0, 0]), 1e-300)
    st = _Strategy(_family_plants(rate_hz, sign), _family_candidates(tu, rate_hz),
                   np.geomspace(1e-4 * ku, 10.0 * ku, 21)[::-1],
                   {"PI": _LOAD_PERIODS * tu, "PID": _LOAD_PERIODS * tu, "PD": _STEP_PERIODS * tu})
    designs = [d for d in _search(model, draws, kinds, st, options) if d is not None]
    if not designs:
        raise InputError(f"no {'/'.join(kinds)} keeps Ms <= {options.ms_max:g} and a phase margin >= "
                         f"{options.pm_min_deg:g} deg on this plant at {rate_hz:g} Hz (relax --ms-max, or check "
                         "the identified model and the controller rate)")
    notes = [f"the exact sampled loop at {rate_hz:g} Hz (zero-order hold, the delay exact): Ms <= {options.ms_max:g}, "
             f"phase margin >= {options.pm_min_deg:g} deg; least IAE of a unit load step at the plant input (PI, "
             "PID) or of a unit setpoint step (PD)"]
    if len(draws) >= 2:
        notes.append(f"robust: the constraints held on the nominal model and {len(draws)} draws over the "
                     "identification's intervals")
        lost = [k for k in kinds if not any(d.name == "robust" and d.kind == k for d in designs)]
        if lost and "robust" in (options.designs or GRID_DESIGNS):
            # said, not left for the user to notice: the export then falls back to the model-based design
            notes.append(f"no robust {'/'.join(lost)}: no gains keep these constraints on the nominal model and every "
                         "draw (the intervals are too wide to hold together: more tests, or --param for a known "
                         "value, narrow them); the model-based design is the one exported")
    else:
        notes.append("no robust design: the source gives the parameters without a spread to draw from")
    if sign < 0:
        notes.append("the plant's gain is negative: reverse acting, the controller acts on -e (gains shown positive)")
    if not integrating and "PD" not in kinds:
        notes.append("no PD: the plant is self-regulating, a PD would leave a steady error")
    return TuneResult(model, None, rate_hz, loop, "iae", options.ms_max, math.inf, _LOAD_PERIODS * tu,
                      {"ultimate_period_s": tu}, tuple(designs), tuple(notes), reverse_acting=sign < 0)
