"""Controller designs for the identified loop: the MRFT tuning rule, model-based and robust optimisation.

Three designs, each as a PD and a PID (parallel form, derivative on the measurement through a
first-order filter Tf = Td_c / N with Td_c = Kd / Kp and N = ``FILTER_N``; integral time Ti = Kp / Ki):

* ``mrft-rule``: the DNN-MRFT describing-function rule from the MRFT test itself
  (checks.md section 5): Kp = c1 4 h / (pi a0), Td_c = c3 T0 with the stored optimised c1 = 0.4249,
  c3 = 0.3391 at beta = -0.7 (phase margin 20 deg), where (T0, a0) is the limit cycle of the MRFT at
  beta = -0.7 on the identified model, at the controller rate (:func:`mrftcli.mrft.lprs.mrft_limit_cycle`).
  It is the published baseline; its PID takes Ti = ``TI_RATIO`` x Td_c (the ratio that gives the
  ideal PID a double zero).
* ``model-based``: the gains minimising the criterion on the sampled loop of the identified model
  (exact delay, zero-order hold, :mod:`mrftcli.tune.closed_loop`), with Ms <= ``ms_max`` and the
  controller's noise gain (|C| at Nyquist, :meth:`Controller.noise_gain`) <= ``effort_max``
  (default: the MRFT rule's). A PD's criterion is the IAE (or ITAE) of a unit setpoint step over
  6 T0 (Kp and Td_c free). A setpoint step does not reward integral action (on an integrating
  plant the PD already has no steady error), so a PID's criterion (Kp, Td_c and Ti free) adds the
  IAE (ITAE) of a load step: a step of size Kp_PD (the same design's PD gain, so that it would leave
  that PD a unit steady offset) added at the plant input, over 12 T0 (integral action is slow).
* ``robust``: the same criterion in expectation over the posterior draws, with Ms <= ``ms_max`` on
  every draw of the 95 % set (:meth:`Posterior.in_set`), which bounds the worst-case phase margin
  below by 2 asin(1 / (2 Ms)) (36.4 deg at Ms = 1.6).

Every design is reported with the exact nominal margins (:func:`mrftcli.tune.margins.margins`), the
nominal step figures and the same figures over the posterior (median over all draws, worst over the
95 % set).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.optimize import minimize

from ..jsonable import check_schema_version, to_jsonable
from ..errors import InputError
from ..mrft.controller import json_number
from ..mrft.model import LoopModel, PlantModel, lead_floor, model_from_json
from ..progress import Progress, report
from ..validate import check_positive
from .closed_loop import (SETTLING_BAND, Controller, DiscretePlant, PlantSpectrum, RateFilter, StepMetrics, as_discrete,
                          criterion, discrete_plants, outputs, plant_spectrum, responses, step_metrics)
from .margins import LoopMargins, Margins, frequency_grid, loop_margins, plant_response


def _encode(obj: Any) -> Any:
    """JSON-able copy (:func:`~mrftcli.jsonable.to_jsonable`), a non-finite float as the string "inf", "-inf" or "nan"."""
    return to_jsonable(obj, nonfinite=str)


def _decode(obj: Any) -> Any:
    """Inverse of :func:`_encode` on the figures' dicts (the strings "inf", "-inf", "nan" become floats)."""
    if isinstance(obj, dict):
        return {k: _decode(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_decode(v) for v in obj]
    if isinstance(obj, str) and obj in ("inf", "-inf", "nan"):
        return float(obj)
    return obj


def _check_version(data: Any, what: str) -> dict[str, Any]:
    return dict(check_schema_version(data, what, _READS))


__all__ = ["Posterior", "Design", "TuneResult", "DesignOptions", "mrft_rule", "tune", "OBJECTIVES", "DESIGNS", "KINDS", "ALL_KINDS",
           "FILTER_N", "TI_RATIO", "controller", "RULE_BETA", "RULE_C1", "RULE_C3", "TUNE_SCHEMA_VERSION",
           "lead_design_note", "LEAD_DESIGN_WORDS", "assumptions_first", "tau_line"]

#: Version of :meth:`TuneResult.to_json`'s object (and of each design's in it); 3: ``tune --json`` writes
#: this record itself (until then a report holding it as ``tune_result``), each design names its
#: ``design`` (was ``name``) and its ``kind``.
TUNE_SCHEMA_VERSION = 3
#: The versions :meth:`TuneResult.from_json` reads for one release: 1 (eq. (2) only, the model as
#: {Tp, Td, tau, K}) and 2 (also inside the ``tune --json`` report of that release, as ``tune_result``).
_READS = (1, 2, 3)

OBJECTIVES = ("iae", "itae")
DESIGNS = ("mrft-rule", "model-based", "robust")
KINDS = ("PD", "PID")
#: Every controller kind a family designs (eq. (2): :data:`KINDS`; a PI on the process families).
ALL_KINDS = ("PD", "PI", "PID")
#: Derivative filter: Tf = Td_c / FILTER_N.
FILTER_N = 10.0
#: The MRFT rule's PID integral time Ti = TI_RATIO * Td_c (the optimised PIDs choose their own).
TI_RATIO = 4.0
#: The DNN-MRFT rule's beta and its stored optimised coefficients (checks.md section 5).
RULE_BETA, RULE_C1, RULE_C3 = -0.7, 0.4249, 0.3391
#: Horizon of the step criterion, in MRFT periods T0 at RULE_BETA.
_HORIZON_PERIODS = 6.0
#: A PID's horizon (setpoint and load steps), in T0: the integral action settles more slowly.
_HORIZON_PERIODS_PID = 12.0
#: Largest number of draws the robust optimisation iterates on (all draws are used for the report).
_OPT_DRAWS = 30


@dataclass(frozen=True)
class Posterior:
    """Draws of eq. (2)'s identified parameters; Tp (known) travels inside ``model``.

    Attributes
    ----------
    model : LoopModel
        The eq. (2) model the draws are of (its Tp is every draw's; its Td, tau, K the point estimate).
    Td, tau, K : numpy.ndarray
        Joint draws [s, s, -] (the identification's bootstrap, or drawn from a stated spread).
    source : str
        Where the draws come from (for the report).
    """

    model: LoopModel
    Td: np.ndarray
    tau: np.ndarray
    K: np.ndarray
    source: str = ""
    #: how many draws had tau < 0 (a lead within :func:`~mrftcli.mrft.model.lead_floor`) and hold tau = 0
    n_lead: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        Td, tau, K = (np.asarray(v, float).ravel() for v in (self.Td, self.tau, self.K))
        # draws beyond the lead eq. (2) admits are no model; a lead within it is held at tau = 0 (the designs'
        # discrete delay line holds delays only), never dropped: dropping truncated the posterior towards larger tau
        ok = (np.isfinite(Td) & np.isfinite(tau) & np.isfinite(K) & (Td > 0) & (K != 0)
              & (tau >= lead_floor(float(self.model.Tp))))
        object.__setattr__(self, "n_lead", int(np.count_nonzero(tau[ok] < 0)))
        object.__setattr__(self, "Td", Td[ok])
        object.__setattr__(self, "tau", np.maximum(tau[ok], 0.0))
        object.__setattr__(self, "K", K[ok])

    @property
    def n(self) -> int:
        return int(self.Td.size)

    def models(self, index=None) -> list[LoopModel]:
        idx = range(self.n) if index is None else index
        Tp = self.model.Tp
        return [LoopModel(Tp, float(self.Td[i]), float(self.tau[i]), float(self.K[i])) for i in idx]

    def in_set(self) -> np.ndarray:
        """Mask of the draws in the 95 % set: Mahalanobis distance in (ln Td, ln tau, ln |K|) within chi2(3, 0.95).

        Parameters with no spread are left out of the distance. tau enters linearly when a draw holds 0 (a lead
        held at 0), where ln tau put it at ln 1e-9, far outside the set.
        """
        tau = np.log(self.tau) if np.all(self.tau > 0) else self.tau
        X = np.column_stack([np.log(self.Td), tau, np.log(np.abs(self.K))])
        keep = X.std(axis=0) > 1e-12
        if self.n < 5 or not keep.any():
            return np.ones(self.n, bool)
        X = X[:, keep]
        d = X - X.mean(axis=0)
        cov = np.atleast_2d(np.cov(d, rowvar=False))
        m2 = np.einsum("ij,jk,ik->i", d, np.linalg.pinv(cov), d)
        from scipy.special import chdtri  # chi2.ppf(0.95, k), the same value, without importing scipy.stats

        return m2 <= chdtri(X.shape[1], 1.0 - 0.95)

    def in_set_models(self) -> list[LoopModel]:
        """The draws of the 95 % set (:meth:`in_set`) as models: what range-constrained exports are held on."""
        return self.models(np.flatnonzero(self.in_set()))

    @classmethod
    def from_spread(cls, model: LoopModel, Td_std: float = 0.0, tau_std: float = 0.0, K_std: float = 0.0,
                    n: int = 200, seed: int = 0, source: str = "") -> "Posterior":
        """Independent log-normal draws with the given means (the model) and standard deviations.

        Used when only means and standard deviations are known (an analyze RESULT.json, or the
        paper's Table III): the correlation between Td and tau is then not known and is taken as zero.
        """
        rng = np.random.default_rng(seed)

        def draw(mean: float, std: float) -> np.ndarray:
            if not std or not math.isfinite(std) or std <= 0:
                return np.full(n, mean)
            s2 = math.log(1.0 + (std / abs(mean)) ** 2)
            return np.sign(mean) * abs(mean) * np.exp(rng.normal(-0.5 * s2, math.sqrt(s2), n))

        return cls(model, draw(model.Td, Td_std), draw(model.tau, tau_std), draw(model.K, K_std),
                   source or "log-normal draws from means and standard deviations (no correlation)")


@dataclass(frozen=True)
class Design:
    """One tuned controller with its figures.

    Attributes
    ----------
    name : str
        ``mrft-rule``, ``model-based`` or ``robust``.
    controller : Controller
    objective : str
        ``iae`` or ``itae``; ``criterion`` is its value on the nominal model, ``criterion_expected``
        its mean over the posterior draws.
    margins : Margins
        Exact nominal margins.
    step : StepMetrics
        Nominal step figures (sampled loop).
    posterior : dict
        Over the posterior: ``median`` (all draws) and ``worst`` (the 95 % set) of the margins and
        step figures, ``n_draws``, ``n_in_set``, ``unstable_in_set``.
    constraints : dict
        ``ms_max``, ``effort_max`` and whether they hold (``feasible``).
    load : dict
        The load step of a PID's criterion (empty for a PD): ``size`` [command units], ``iae`` (or
        ``itae``) [output unit s], ``peak`` (largest |y| [output units]), ``recovery_s`` (|y| within
        ``SETTLING_BAND`` from then on, NaN if not within the horizon).
    horizon_s : float
        Horizon of the criterion and of the step figures [s].
    criterion_definition : str
        What ``criterion`` is of: ``"setpoint step"``, ``"load step"`` (the process families' PI/PID) or
        ``"setpoint step + load step"`` (eq. (2)'s PID).
    """

    name: str
    controller: Controller
    objective: str
    criterion: float
    criterion_expected: float
    margins: Margins
    step: StepMetrics
    posterior: dict = field(default_factory=dict)
    constraints: dict = field(default_factory=dict)
    load: dict = field(default_factory=dict)
    horizon_s: float = math.nan
    criterion_definition: str = ""

    @property
    def kind(self) -> str:
        return self.controller.kind

    def to_json(self) -> dict[str, Any]:
        """The versioned JSON object (:data:`TUNE_SCHEMA_VERSION`); non-finite figures as "inf"/"nan"."""
        return {"schema_version": TUNE_SCHEMA_VERSION, "design": self.name, "kind": self.kind,
                "controller": self.controller.to_json(),
                "objective": self.objective, "criterion": _encode(self.criterion),
                "criterion_expected": _encode(self.criterion_expected), "margins": self.margins.to_json(),
                "step": _encode(self.step.to_dict()), "posterior": _encode(self.posterior),
                "constraints": _encode(self.constraints), "load": _encode(self.load),
                "horizon_s": _encode(self.horizon_s), "criterion_definition": self.criterion_definition}

    @classmethod
    def from_json(cls, data: Any) -> "Design":
        """The record of :meth:`to_json` (version 3; 1 and 2 named the design ``name`` and had no ``kind``);
        InputError (one line) on another version or a malformed field."""
        what = "tune design"
        data = _check_version(data, what)
        step = data.get("step")
        if not isinstance(step, dict):
            raise InputError(f"{what}: 'step' must be an object")
        name, objective = data.get("design" if data["schema_version"] >= 3 else "name"), data.get("objective")
        if name not in DESIGNS or objective not in OBJECTIVES:
            raise InputError(f"{what}: unknown design {name!r} or objective {objective!r}")
        extras = {k: _decode(data.get(k, {})) for k in ("posterior", "constraints", "load")}
        if not all(isinstance(v, dict) for v in extras.values()):
            raise InputError(f"{what}: 'posterior', 'constraints' and 'load' must be objects")
        controller = Controller.from_json(data.get("controller"), f"{what}'s controller")
        if data["schema_version"] >= 3 and data.get("kind") != controller.kind:
            raise InputError(f"{what}: 'kind' {data.get('kind')!r} is not its controller's ({controller.kind})")
        return cls(name, controller, objective,
                   json_number(data, "criterion", what), json_number(data, "criterion_expected", what),
                   Margins.from_json(data.get("margins")),
                   StepMetrics(*(json_number(step, f.name, what) for f in fields(StepMetrics))),
                   extras["posterior"], extras["constraints"], extras["load"], json_number(data, "horizon_s", what),
                   str(data.get("criterion_definition")  # versions 1-2 left eq. (2)'s empty
                       or ("setpoint step + load step" if extras["load"] else "setpoint step")))


@dataclass(frozen=True)
class TuneResult:
    """Everything ``mrft-ident tune`` found: the model, its posterior and every design.

    One record for every family. Eq. (2) (``model`` a :class:`~mrftcli.mrft.model.LoopModel`) has a
    ``posterior`` of (Td, tau, K) draws and the MRFT rule's ``rule_cycle``; another family's result
    has no posterior (its designs carry the worst figures over their draws), ``rule_cycle`` holds its
    ``ultimate_period_s`` [s], and ``reverse_acting`` says the gains act on -e (a negative plant gain).
    """

    model: PlantModel
    posterior: Posterior | None
    rate_hz: float
    loop: str
    objective: str
    ms_max: float
    effort_max: float
    horizon_s: float
    rule_cycle: dict
    designs: tuple[Design, ...]
    notes: tuple[str, ...] = ()
    rate_filter: RateFilter | None = None
    reverse_acting: bool = False
    #: the identified tau [s] when it was a lead the designs took as 0 (``model.tau`` is then 0); None otherwise
    tau_identified: float | None = None

    @property
    def loop_model(self) -> LoopModel:
        """The eq. (2) model the result was designed for (a stack's export, the report's figures need one).

        Raises
        ------
        InputError
            Another family's result (one line).
        """
        if not isinstance(self.model, LoopModel):
            raise InputError(f"a {self.model.family} model's gains export as --export generic only (the stack "
                             "exports and the report are for eq. (2) loops)")
        return self.model

    def get(self, name: str, kind: str) -> Design:
        for d in self.designs:
            if d.name == name and d.kind == kind:
                return d
        raise KeyError((name, kind))

    def to_json(self) -> dict[str, Any]:
        """The versioned JSON object (:data:`TUNE_SCHEMA_VERSION`): the model, the posterior's draws, the
        setting, every design (:meth:`Design.to_json`), the notes and the stack's rate filter.

        Examples
        --------
        >>> res = tune(LoopModel(0.0422, 1.301, 0.0297, 30.0), 200.0,
        ...            options=DesignOptions(designs=("mrft-rule",), kinds=("PD",)))
        >>> TuneResult.from_json(res.to_json()).designs[0].controller == res.designs[0].controller
        True
        """
        m, post = self.model, self.posterior
        return {"schema_version": TUNE_SCHEMA_VERSION, "model": m.to_json(), "reverse_acting": self.reverse_acting,
                "posterior": (None if post is None else
                              {"Td": _encode(post.Td), "tau": _encode(post.tau), "K": _encode(post.K),
                               "source": post.source}),
                "rate_hz": self.rate_hz, "loop": self.loop, "objective": self.objective, "ms_max": self.ms_max,
                "effort_max": _encode(self.effort_max), "horizon_s": _encode(self.horizon_s),
                "rule_cycle": _encode(self.rule_cycle), "designs": [d.to_json() for d in self.designs],
                "notes": list(self.notes),
                "rate_filter": None if self.rate_filter is None else self.rate_filter.to_json(),
                **({} if self.tau_identified is None else
                   {"tau_identified": {"value": self.tau_identified, "unit": "s",
                                       "designed_at": float(getattr(m, "tau", 0.0))}})}

    @classmethod
    def from_json(cls, data: Any) -> "TuneResult":
        """The record of :meth:`to_json`.

        Raises
        ------
        InputError
            Not a JSON object, another ``schema_version``, or a missing or malformed field.
        """
        what = "tune result"
        if isinstance(data, dict) and "schema_version" not in data and isinstance(data.get("tune_result"), dict):
            data = data["tune_result"]  # the tune --json report of version 2: the record is its tune_result
        data = _check_version(data, what)
        if data["schema_version"] == 1 and data.get("kind") == "cascade":  # the cascade's own record until now
            from .grid import cascade_result_v1

            return cascade_result_v1(data)
        md, pd = data.get("model"), data.get("posterior")
        if not isinstance(md, dict):
            raise InputError(f"{what}: 'model' must be an object")
        if data["schema_version"] == 1:  # eq. (2) only: the model as {Tp, Td, tau, K}
            Tp, Td, tau, K = (json_number(md, k, what) for k in ("Tp", "Td", "tau", "K"))
            model: PlantModel = LoopModel(Tp, Td, tau, K)
        else:
            model = model_from_json(md)
        post = None
        if pd is not None:
            if not isinstance(model, LoopModel):
                raise InputError(f"{what}: a posterior of (Td, tau, K) draws belongs to an eq. (2) model only")
            if not isinstance(pd, dict) or not all(isinstance(pd.get(k), list) for k in ("Td", "tau", "K")):
                raise InputError(f"{what}: 'posterior' must hold the lists Td, tau and K")
            try:
                draws = [np.asarray(_decode(pd[k]), float) for k in ("Td", "tau", "K")]
            except (TypeError, ValueError) as err:
                raise InputError(f"{what}: malformed posterior draws ({err})") from err
            post = Posterior(model, draws[0], draws[1], draws[2], str(pd.get("source", "")))
        designs, notes, cycle = data.get("designs"), data.get("notes", []), data.get("rule_cycle")
        if not isinstance(designs, list) or not isinstance(notes, list) or not isinstance(cycle, dict):
            raise InputError(f"{what}: 'designs' and 'notes' must be lists, 'rule_cycle' an object")
        return cls(model, post, json_number(data, "rate_hz", what), str(data.get("loop", "")),
                   str(data.get("objective", "")), json_number(data, "ms_max", what), json_number(data, "effort_max", what),
                   json_number(data, "horizon_s", what), _decode(cycle), tuple(Design.from_json(d) for d in designs),
                   tuple(str(n) for n in notes), RateFilter.from_json(data.get("rate_filter"), what),
                   data.get("reverse_acting") is True, _tau_identified(data.get("tau_identified"), what))


def _tau_identified(data: Any, what: str) -> float | None:
    """``tau_identified``'s value [s] (absent in records without a lead, and in older ones)."""
    if data is None:
        return None
    if not isinstance(data, dict):
        raise InputError(f"{what}: 'tau_identified' must be an object")
    return json_number(data, "value", what)


def controller(kind: str, Kp: float, Td_c: float, rate_hz: float, Ti: float | None = None,
                rate_filter: RateFilter | None = None) -> Controller:
    """Parallel gains from (Kp, Td_c, Ti) (a PI: ``"PID"`` with Td_c 0); a PID without Ti takes TI_RATIO x Td_c.

    The derivative filter is Tf = Td_c / FILTER_N, or the stack's ``rate_filter`` (then Tf = 0).
    """
    Ki = Kp / (Ti if Ti is not None else TI_RATIO * Td_c) if kind == "PID" else 0.0
    if rate_filter is not None:
        return Controller(Kp, Ki, Kp * Td_c, 0.0, rate_hz, rate_filter)
    return Controller(Kp, Ki, Kp * Td_c, Td_c / FILTER_N, rate_hz)


def mrft_rule(model: LoopModel, rate_hz: float, kind: str = "PD",
              rate_filter: RateFilter | None = None) -> tuple[Controller, dict]:
    """The DNN-MRFT rule (checks.md section 5) on the MRFT limit cycle at beta = -0.7 of ``model``.

    Returns the controller and the cycle used (``T0`` [s], ``a0`` for h = 1). ``rate_filter``: the
    stack's filter on the measured rate, in place of Tf.

    Examples
    --------
    >>> c, cyc = mrft_rule(LoopModel(0.0422, 1.301, 0.0297, 30.0), 200.0)
    >>> round(c.Kd / c.Kp / cyc["T0"], 4), c.kind
    (0.3391, 'PD')
    """
    from ..mrft.lprs import mrft_limit_cycle

    lc = mrft_limit_cycle(model, RULE_BETA, 1.0, rate_hz=rate_hz)
    T0, a0 = float(lc.period), float(lc.amplitude)
    Kp = RULE_C1 * 4.0 / (math.pi * a0)
    return controller(kind, Kp, RULE_C3 * T0, rate_hz, rate_filter=rate_filter), {"beta": RULE_BETA, "T0": T0, "a0": a0, "h": 1.0,
                                                           "c1": RULE_C1, "c3": RULE_C3}


class _Evaluator:
    """Criterion and constraints of a candidate controller over a fixed set of models.

    ``load`` > 0 (a PID): the criterion adds the load step of that size (module docstring).
    """

    def __init__(self, plants: Sequence[DiscretePlant], ms_plants: Sequence[DiscretePlant], rate_hz: float, kind: str,
                 objective: str, horizon: float, ms_max: float, effort_max: float, load: float = 0.0,
                 rate_filter: RateFilter | None = None) -> None:
        self.models = as_discrete(plants, rate_hz)
        self.rate_filter = rate_filter
        self.rate_hz, self.kind, self.objective = rate_hz, kind, objective
        self.horizon, self.ms_max, self.effort_max, self.load = horizon, ms_max, effort_max, load
        self.omega = frequency_grid(rate_hz, 400)
        self.Gd = plant_response(list(ms_plants), rate_hz, self.omega)
        self.spectra: dict[float, PlantSpectrum] = {}

    def _copy(self, **changes: Any) -> "_Evaluator":
        new = object.__new__(_Evaluator)
        new.__dict__.update(self.__dict__)
        new.__dict__.update(changes)
        return new

    def with_ms_models(self, Gd: np.ndarray, omega: np.ndarray) -> "_Evaluator":
        """A copy whose Ms constraint covers the loops of ``Gd`` (responses on ``omega``)."""
        return self._copy(omega=omega, Gd=Gd)

    def with_kind(self, kind: str, load: float = 0.0, horizon: float | None = None) -> "_Evaluator":
        return self._copy(kind=kind, load=load, horizon=self.horizon if horizon is None else horizon)

    def ms(self, c: Controller) -> float:
        L = c.feedback_response(self.omega)[None, :] * self.Gd
        return float(np.max(1.0 / np.abs(1.0 + L)))

    def criterion(self, c: Controller) -> float:
        if self.horizon not in self.spectra:  # the plants on the inversion circle, kept across controllers
            self.spectra[self.horizon] = plant_spectrum(self.models, self.horizon)
        t, y, yl = outputs(self.models, c, self.horizon, self.load, self.spectra[self.horizon])
        J = criterion(t, y, self.objective)
        if yl is not None:  # a load step was asked for (self.load != 0)
            J = J + criterion(t, 1.0 - yl, self.objective)  # |1 - (1 - y)| = |y|: the load's deviation
        return float(np.mean(J))

    def violation(self, c: Controller) -> float:
        return max(0.0, self.ms(c) / self.ms_max - 1.0) + max(0.0, c.noise_gain() / self.effort_max - 1.0)

    def controller(self, p: np.ndarray) -> Controller:
        Ti = math.exp(p[2]) if p.size > 2 else None
        return controller(self.kind, math.exp(p[0]), math.exp(p[1]), self.rate_hz, Ti, self.rate_filter)

    def cost(self, p: np.ndarray) -> float:
        c = self.controller(p)
        v = self.violation(c)
        if v > 0.5:
            return 1e6 * (1.0 + v)
        J = self.criterion(c)
        if not math.isfinite(J):
            return 1e6 * (1.0 + v)
        return J * (1.0 + 50.0 * v)


def _params(c: Controller) -> np.ndarray:
    """(ln Kp, ln Td_c) of a PD, (ln Kp, ln Td_c, ln Ti) of a PID."""
    p = [math.log(c.Kp), math.log(c.Kd / c.Kp)]
    if c.Ki > 0:
        p.append(math.log(c.Kp / c.Ki))
    return np.array(p)


def _feasible_start(ev: _Evaluator, start: Controller) -> Controller:
    """The best (by the criterion) of the most aggressive feasible gains per derivative time on a grid.

    Ms is not monotone in the gain on this plant (a PD's phase lead vanishes below its zero), so a
    simple scaling of the start need not reach the feasible set. A PID keeps the start's Ti / Td_c.
    """
    Td0 = start.Kd / start.Kp
    Ti_ratio = (start.Kp / start.Ki) / Td0 if start.Ki > 0 else None
    best, best_J = start, math.inf
    for f in np.geomspace(0.3, 4.0, 12):
        for g in np.geomspace(1.0, 0.01, 60):
            Td_c = Td0 * f
            Kp = start.Kp * g
            c = controller("PID" if Ti_ratio else "PD", Kp, Td_c, ev.rate_hz, Ti_ratio * Td_c if Ti_ratio else None,
                            ev.rate_filter)
            if ev.violation(c) == 0.0:
                J = ev.criterion(c)
                if J < best_J:
                    best, best_J = c, J
                break
    return best


def _pid_start(ev: _Evaluator, pd: Controller) -> Controller:
    """A PID start from a PD: the best (penalised cost) of a few integral times Ti = r Td_c at the PD's Kp, Td_c.

    Integral action costs phase at the crossover, so on a PD at its Ms limit every Ti breaks it a
    little; the penalty in the cost lets the optimiser move back (a feasible-only start would pick the
    slowest integral and start far from the optimum).
    """
    Td_c = pd.Kd / pd.Kp
    cands = [controller("PID", pd.Kp, Td_c, ev.rate_hz, r * Td_c, ev.rate_filter) for r in (2.0, 3.0, 4.0, 6.0, 8.0, 16.0)]
    return min(cands, key=lambda c: ev.cost(_params(c)))


def _optimise(ev: _Evaluator, start: Controller, step: float = 0.3, maxfev: int | None = None) -> Controller:
    """Nelder-Mead on (ln Kp, ln Td_c[, ln Ti]) with the constraints as a penalty, from ``start``.

    An infeasible start (and a result the penalty left slightly infeasible) is replaced by the best
    feasible point of a grid around it (:func:`_feasible_start`); a PID starts from the PD solution.
    ``step``: the initial simplex's size in log units (small for a warm start).
    """
    # a slight violation is left to the penalty; a large one needs a feasible start from the grid
    c0 = _feasible_start(ev, start) if ev.violation(start) > 0.1 else start
    p0 = _params(c0)
    k = p0.size
    simplex = np.vstack([p0] + [p0 + step * np.eye(k)[i] for i in range(k)])
    res = minimize(ev.cost, p0, method="Nelder-Mead",
                   options={"xatol": 2e-3, "fatol": 1e-6, "maxfev": maxfev or (70 if k == 2 else 200),
                            "initial_simplex": simplex})
    c = ev.controller(res.x)
    if ev.violation(c) > 0:  # the penalty leaves a slight violation: the best feasible point near it
        c = _feasible_start(ev, c)
    return c


def _load_figures(t: np.ndarray, y: np.ndarray, size: float, objective: str) -> dict:
    """Figures of one load-step response ``y`` (output deviation, setpoint 0)."""
    if not np.all(np.isfinite(y)) or np.max(np.abs(y)) > 1e3:
        return {"size": size, objective: math.inf, "peak": math.inf, "recovery_s": math.nan}
    out = np.nonzero(np.abs(y) > SETTLING_BAND)[0]
    rec = float(t[0]) if out.size == 0 else (math.nan if out[-1] == t.size - 1 else float(t[out[-1] + 1]))
    return {"size": size, objective: float(criterion(t, 1.0 - y, objective)), "peak": float(np.max(np.abs(y))),
            "recovery_s": rec}


def _summaries(c: Controller, post: Posterior, plants: list[DiscretePlant], objective: str, horizon: float,
               load: float = 0.0) -> tuple[dict[str, Any], float, LoopMargins]:
    """Figures over the posterior (``plants``: its draws discretised); the expected criterion; the draws' margins.

    The margins are :func:`loop_margins` of every draw, the same computation as the nominal figure's.
    """
    t, y, u, yl, _ = responses(plants, c, horizon, load)
    rows = [step_metrics(t, y[i], u[i]) for i in range(post.n)]
    mg = loop_margins(c, post.models(), plants)
    table = {
        "phase_margin_deg": mg.phase_margin_deg, "gain_margin": mg.gain_margin, "Ms": mg.Ms,
        "delay_margin_ms": mg.delay_margin_s * 1e3,
        "overshoot_pct": np.array([r.overshoot_pct for r in rows]),
        "rise_s": np.array([r.rise_s for r in rows]), "settling_s": np.array([r.settling_s for r in rows]),
        objective: np.array([getattr(r, objective) for r in rows]),
    }
    in_set = post.in_set()
    worse_low = {"phase_margin_deg", "gain_margin", "delay_margin_ms"}
    med, worst = {}, {}
    for k, v in table.items():
        v = np.asarray(v, float)
        med[k] = float(np.nanmedian(np.where(np.isfinite(v), v, np.nan))) if np.isfinite(v).any() else math.inf
        s = v[in_set]
        if k in worse_low:
            worst[k] = float(np.min(s))
        else:
            worst[k] = float(np.max(np.where(np.isnan(s), np.inf, s)))
    crit = table[objective]
    if yl is not None:  # load != 0
        crit = crit + criterion(t, 1.0 - yl, objective)
    expected = float(np.mean(crit)) if np.all(np.isfinite(crit)) else math.inf
    return {"median": med, "worst": worst, "n_draws": post.n, "n_in_set": int(in_set.sum()),
            "delay_margin": "exact for the sampled loop, per draw (as the nominal figure)",
            "unstable_in_set": int(np.sum(~mg.stable[in_set]))}, expected, mg


@dataclass(frozen=True)
class DesignOptions:
    """The design settings of :func:`tune`; checked on creation (a one-line ``InputError``).

    Attributes
    ----------
    objective : {"iae", "itae"}
        Criterion of the unit setpoint step over ``6 T0`` (T0: the MRFT period at beta = -0.7); the
        other families' designs take the IAE only.
    ms_max : float
        Limit on the sensitivity peak Ms [-] (> 1).
    effort_max : float, optional
        Limit on the controller's noise gain [command units / output unit] (> 0); None: the MRFT
        rule's (eq. (2) only).
    designs : tuple of str, optional
        Which of :data:`DESIGNS` to make (the robust one needs a posterior); None: the family's
        (eq. (2): all three; the other families: model-based and robust).
    kinds : tuple of str, optional
        Which of :data:`KINDS` to make; None: the family's (eq. (2): PD and PID; the other families:
        PI and PID, and PD on an integrating plant).
    rate_filter : RateFilter, optional
        The flight stack's filter on the measured rate (``tune --export``): every design, the MRFT
        rule's included, runs its derivative through it instead of Tf = Td_c / FILTER_N (eq. (2) only).
    pm_min_deg : float
        Least phase margin of the other families' designs [deg] (eq. (2)'s hold Ms only).
    """

    objective: str = "iae"
    ms_max: float = 1.6
    effort_max: float | None = None
    designs: Sequence[str] | None = None
    kinds: Sequence[str] | None = None
    rate_filter: RateFilter | None = None
    pm_min_deg: float = 45.0

    def __post_init__(self) -> None:
        if self.objective not in OBJECTIVES:
            raise InputError(f"unknown objective {self.objective!r}; choose from {', '.join(OBJECTIVES)}")
        if not (math.isfinite(self.ms_max) and self.ms_max > 1.0):
            raise InputError(f"--ms-max must be a number above 1, got {self.ms_max!r}")
        if self.effort_max is not None:
            check_positive("--effort-max", self.effort_max)
        if not (math.isfinite(self.pm_min_deg) and 0.0 <= self.pm_min_deg < 90.0):
            raise InputError(f"the least phase margin must be in [0, 90) deg, got {self.pm_min_deg!r}")
        bad = [d for d in self.designs or () if d not in DESIGNS]
        if bad:
            raise InputError(f"unknown design(s) {bad}; choose from {', '.join(DESIGNS)}")
        bad = [k for k in self.kinds or () if k not in ALL_KINDS]
        if bad:
            raise InputError(f"unknown controller kind(s) {bad}; choose from {', '.join(ALL_KINDS)}")
        for name in ("designs", "kinds"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, tuple(getattr(self, name)))


def tune(model: PlantModel, rate_hz: float, *, posterior: Posterior | Sequence[PlantModel] | None = None,
         options: DesignOptions = DesignOptions(), loop: str = "", progress: Progress | None = None) -> TuneResult:
    """The one tune driver: controllers for ``model`` at ``rate_hz``, by the strategy of its family.

    Eq. (2) (:class:`~mrftcli.mrft.model.LoopModel`): the MRFT rule, model-based and robust PD and PID
    (the module docstring). An outer loop through its closed inner loop
    (:class:`~mrftcli.mrft.cascade.CascadeModel`): a PD on the exact sampled cascade; any other family or
    a declared model: PI/PID (PD on integrating plants); both by the one grid search on the exact sampled
    loop, the model kind's strategy (:func:`mrftcli.tune.grid.tune_grid`).

    Parameters
    ----------
    model : PlantModel
        The identified model (point estimate).
    rate_hz : float
        Controller rate [Hz].
    posterior : Posterior or sequence of PlantModel, optional
        Eq. (2): the parameters' draws (:class:`Posterior`); another family: the drawn models
        (:func:`mrftcli.tune.grid.model_draws`, :func:`mrftcli.tune.grid.outer_draws`). Without it the
        robust design is left out.
    options : DesignOptions
        The objective, the Ms and noise-gain limits, the designs and kinds, the stack's rate filter.
    loop : str
        The loop's name, recorded in the result.
    progress : Progress, optional
        Called as ``progress(done, total, stage)`` per design (eq. (2)).

    Returns
    -------
    TuneResult
    """
    if not isinstance(model, LoopModel):
        if isinstance(posterior, Posterior):
            raise InputError(f"a {model.family} model's robust design takes drawn models, not eq. (2)'s posterior")
        from .grid import tune_grid  # the grid search of the families and the cascade (it builds this module's records)

        return tune_grid(model, rate_hz, tuple(posterior or ()), options, loop)
    if posterior is not None and not isinstance(posterior, Posterior):
        raise InputError("eq. (2)'s robust design takes a Posterior of (Td, tau, K) draws")
    rate_hz = check_positive("the controller rate [Hz]", rate_hz)
    objective, ms_max, rate_filter = options.objective, options.ms_max, options.rate_filter
    kinds, designs = options.kinds or KINDS, options.designs or DESIGNS
    if "PI" in kinds:
        raise InputError("--kind PI is for process plants (analyze --model NAME's result); eq. (2) loops take PD or PID")
    notes = []
    tau_identified = None
    if model.tau < 0:  # a lead: no discrete delay line holds it; design on the loop with tau 0 and say so
        notes.append(lead_design_note(model.tau))
        tau_identified = float(model.tau)
        model = model.with_parameters(tau=0.0)
        if posterior is not None:
            posterior = Posterior(model, posterior.Td, posterior.tau, posterior.K,
                                  source=posterior.source + "; a lead's tau taken as 0")
    elif posterior is not None and posterior.n_lead:
        notes.append(f"{posterior.n_lead} of {posterior.n} posterior draws have tau < 0 (a lead): the designs take "
                     "them at tau = 0 (no discrete delay line holds a lead)")
    if posterior is None or posterior.n < 2:
        designs = tuple(d for d in designs if d != "robust")
        notes.append("no posterior (no draws or spreads given): the robust design is left out")
        posterior = None
    st = _setting(model, rate_hz, posterior, objective, ms_max, options.effort_max, kinds, "robust" in designs,
                  rate_filter)
    jobs = [(d, k) for d in designs for k in kinds]
    # PD before PID: a PID design starts from the PD design of the same name
    jobs.sort(key=lambda j: (DESIGNS.index(j[0]), KINDS.index(j[1])))
    out = []
    found: dict[tuple[str, str], Controller] = {}
    for i, (name, kind) in enumerate(jobs):
        report(progress, i, len(jobs), f"{name} {kind}")
        c, load = _design(name, kind, st, found)
        found[(name, kind)] = c
        out.append(_figures(name, c, load, st.horizons[kind], st))
    report(progress, len(jobs), len(jobs), "done")
    return TuneResult(model, posterior, rate_hz, loop, objective, ms_max, st.effort_max, st.horizons["PD"],
                      st.cycle, tuple(out), tuple(notes), rate_filter, tau_identified=tau_identified)


#: how :func:`lead_design_note` begins (what a design rests on, shown first by tune's callers)
LEAD_DESIGN_WORDS = "assumed: the identified loop leads eq. (2)"


def assumptions_first(notes: tuple[str, ...]) -> tuple[str, ...]:
    """``notes`` with the ``assumed: ...`` ones first (what a design rests on is read before anything else)."""
    return tuple(sorted(notes, key=lambda n: not n.startswith("assumed:")))


def tau_line(result: "TuneResult") -> str:
    """``tau 0 ms (designed at; identified -2.92 ms, a lead)`` or ``tau 29.7 ms``: the model's tau as designed."""
    tau = float(getattr(result.model, "tau", 0.0))
    if result.tau_identified is None:
        return f"tau {tau * 1e3:.4g} ms"
    return f"tau {tau * 1e3:.4g} ms (designed at; identified {result.tau_identified * 1e3:.3g} ms, a lead)"


def lead_design_note(tau: float) -> str:
    """What a design does with an identified lead (``tau`` < 0 [s]): it takes tau = 0, the causal loop nearest."""
    return (f"{LEAD_DESIGN_WORDS} (tau = {tau * 1e3:.3g} ms < 0); the designs take tau = 0 "
            "(no discrete delay line holds a lead), a loop with more lag than identified: the identified loop's delay "
            f"margin is {-tau * 1e3:.3g} ms more than stated and its phase margin larger")


@dataclass(frozen=True, eq=False)
class _Setting:
    """What every design of one :func:`tune` call shares: the model, the rule, the posterior's plants."""

    model: LoopModel
    rate_hz: float
    posterior: Posterior | None
    objective: str
    ms_max: float
    effort_max: float
    rule_pd: Controller
    cycle: dict[str, float]
    horizons: dict[str, float]
    nominal: list[DiscretePlant]
    post_plants: list[DiscretePlant]
    omega: np.ndarray
    Gd_all: np.ndarray | None
    in_set_mask: np.ndarray | None
    nominal_ev: dict[str, _Evaluator]
    robust_ev: dict[str, _Evaluator]
    rate_filter: RateFilter | None = None


def _setting(model: LoopModel, rate_hz: float, posterior: Posterior | None, objective: str, ms_max: float,
             effort_max: float | None, kinds: Sequence[str], robust: bool,
             rate_filter: RateFilter | None = None) -> _Setting:
    """The MRFT rule and horizons, the noise-gain limit, the draws discretised once, the evaluators."""
    rule_pd, cycle = mrft_rule(model, rate_hz, "PD", rate_filter)
    horizons = {"PD": _HORIZON_PERIODS * cycle["T0"], "PID": _HORIZON_PERIODS_PID * cycle["T0"]}
    effort = rule_pd.noise_gain() if effort_max is None else check_positive("--effort-max", effort_max)
    omega = frequency_grid(rate_hz, 400)
    # the posterior's draws discretised once: every design's figures and the robust criterion reuse them
    post_plants = discrete_plants(posterior.models(), rate_hz) if posterior is not None else []
    Gd_all = plant_response(post_plants, rate_hz, omega) if posterior is not None else None
    in_set_mask = posterior.in_set() if posterior is not None else None
    nominal = as_discrete([model], rate_hz)
    nominal_ev = {k: _Evaluator(nominal, nominal, rate_hz, k, objective, horizons["PD"], ms_max, effort,
                                rate_filter=rate_filter) for k in kinds}
    robust_ev = {}
    if posterior is not None and in_set_mask is not None and robust:
        rng = np.random.default_rng(0)
        idx_all = np.arange(posterior.n)
        idx = np.sort(rng.choice(idx_all, _OPT_DRAWS, replace=False)) if posterior.n > _OPT_DRAWS else idx_all
        in_set = np.nonzero(in_set_mask)[0]
        ms_idx = np.sort(rng.choice(in_set, _OPT_DRAWS, replace=False)) if in_set.size > _OPT_DRAWS else in_set
        for k in kinds:
            robust_ev[k] = _Evaluator([post_plants[i] for i in idx], [post_plants[i] for i in ms_idx], rate_hz, k,
                                      objective, horizons["PD"], ms_max, effort, rate_filter=rate_filter)
    return _Setting(model, rate_hz, posterior, objective, ms_max, float(effort), rule_pd, cycle, horizons, nominal,
                    post_plants, omega, Gd_all, in_set_mask, nominal_ev, robust_ev, rate_filter)


def _design(name: str, kind: str, st: _Setting, found: dict[tuple[str, str], Controller]) -> tuple[Controller, float]:
    """One design's controller and the size of its load step (0 for a PD); ``found``: the designs so far."""
    rule_pd, rate_hz = st.rule_pd, st.rate_hz
    if name == "mrft-rule":
        if kind == "PD":
            return rule_pd, 0.0
        return controller("PID", rule_pd.Kp, rule_pd.Kd / rule_pd.Kp, rate_hz, rate_filter=st.rate_filter), rule_pd.Kp
    ev = st.nominal_ev[kind] if name == "model-based" else st.robust_ev[kind]
    load = 0.0
    if kind == "PD":
        # the robust design starts from the model-based one (warm start) when there is one
        c = _optimise(ev, found.get(("model-based", "PD"), rule_pd) if name == "robust" else rule_pd)
    else:
        pd = found.get((name, "PD"))
        if pd is None:
            pd = _optimise(ev.with_kind("PD"), found.get(("model-based", "PD"), rule_pd))
        load = pd.Kp
        ev = ev.with_kind("PID", load=load, horizon=st.horizons[kind])
        warm = found.get(("model-based", "PID")) if name == "robust" else None
        if warm is not None:  # the robust PID is near the model-based one: a short, local search
            c = _optimise(ev, warm, step=0.1, maxfev=60)
        else:
            c = _optimise(ev, _pid_start(ev, pd))
    if name == "robust" and st.Gd_all is not None and st.in_set_mask is not None:
        # the optimisation's draws stood for the 95 % set: hold Ms on all of its draws
        ev_all = ev.with_ms_models(st.Gd_all[st.in_set_mask], st.omega)
        if ev_all.violation(c) > 0:
            c = _optimise(ev_all, c)
    return c, load


def _figures(name: str, c: Controller, load: float, horizon: float, st: _Setting) -> Design:
    """A design's nominal margins and steps, its figures over the posterior, its constraints."""
    objective, ms_max, effort_max = st.objective, st.ms_max, st.effort_max
    mg = loop_margins(c, [st.model], st.nominal)[0]
    t, y, u, yl, _ = responses(st.nominal, c, horizon, load)
    step = step_metrics(t, y[0], u[0])
    J = getattr(step, objective)
    load_fig = {}
    if yl is not None:  # load != 0
        load_fig = _load_figures(t, yl[0], load, objective)
        J = J + load_fig[objective]
    post: dict[str, Any] = {}
    expected = math.nan
    if st.posterior is not None:
        post, expected, _ = _summaries(c, st.posterior, st.post_plants, objective, horizon, load)
    cons = {"ms_max": ms_max, "effort_max": effort_max, "noise_gain": c.noise_gain(),
            "feasible": bool(mg.Ms <= ms_max * (1 + 1e-3) and c.noise_gain() <= effort_max * (1 + 1e-9))}
    if name == "robust" and post:
        cons["feasible"] = bool(post["worst"]["Ms"] <= ms_max * (1 + 1e-3)
                                and cons["noise_gain"] <= effort_max * (1 + 1e-9))
    return Design(name, c, objective, J, expected, mg, step, post, cons, load_fig, horizon,
                  "setpoint step + load step" if load_fig else "setpoint step")
