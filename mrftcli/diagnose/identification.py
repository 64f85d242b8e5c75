"""The plant's parameters a diagnosis reports: its linear fit, the refits with the effects found,
analyze's model of the same log and the one estimate the user should take (issue 26, item 4).

:class:`Identification` is ``DiagnosisResult.identification``; its :meth:`~Identification.to_json`
is the JSON's ``identification`` object (the layout of the result's ``schema_version``):
``linear``, ``with_<effect>`` (``with_<a>+<b>`` for a pair), ``waveform_with_<effect>``, ``analyze``
(when an analysis of the log is known: :func:`with_analysis`), ``recommended`` and ``units``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

from ..errors import InputError
from ..io.logtypes import gain_unit, output_unit

if TYPE_CHECKING:
    from ..analyze import AnalysisResult

__all__ = ["ModelEstimate", "EffectIdentification", "AnalyzeModel", "Recommendation", "Identification",
           "analyze_model", "with_analysis", "DIFFERS_BECAUSE"]

#: why the diagnosis' linear model is not analyze's (the terminal and the JSON say it)
DIFFERS_BECAUSE = ("diagnose refits the linear model to the cycles it compares the candidates on (the stable "
                   "cycles above, by their features), so the two differ by that choice of data")

#: the JSON keys of each kind of estimate, in order (the layout before the record existed)
_KEYS = {
    "cycles": ("tau", "K", "Td", "Tp"),
    "waveform": ("Td", "tau", "K", "Tp", "value", "value_std", "residual_rms"),
}


@dataclass(frozen=True)
class ModelEstimate:
    """Eq. (2)'s parameters from one fit.

    Attributes
    ----------
    kind : str
        ``"cycles"`` (fitted to the stable cycles' features) or ``"waveform"`` (the output-error refit
        on the recorded waveform, with the effect's parameter ``value``).
    Td, tau : float or None
        [s] (None: not fitted).
    K : float or None
        Eq. (2)'s gain [output unit/s² per command unit].
    Tp : float or None
        The propulsion time constant used [s].
    value, value_std : float or None
        The effect's parameter and its standard error (a waveform refit; the effect's unit).
    residual_rms : float or None
        The waveform refit's residual RMS [output units].
    """

    kind: str = "cycles"
    Td: float | None = None
    tau: float | None = None
    K: float | None = None
    Tp: float | None = None
    value: float | None = None
    value_std: float | None = None
    residual_rms: float | None = None

    def to_json(self) -> dict[str, Any]:
        """The JSON object (the kind's keys that are set, in order)."""
        return {k: getattr(self, k) for k in _KEYS[self.kind] if getattr(self, k) is not None}

    @classmethod
    def from_json(cls, data: Any, kind: str = "cycles") -> ModelEstimate:
        """The estimate of a :meth:`to_json` object (its numbers checked)."""
        if not isinstance(data, dict) or not set(data) <= set(_KEYS[kind]):
            raise InputError(f"a diagnosis' identification entry must be an object of {', '.join(_KEYS[kind])}; "
                             f"got {data!r:.80}")
        return cls(kind=kind, **{k: _number(v, k) for k, v in data.items()})

    def plant(self) -> dict[str, float]:
        """Td, tau [s] and K, those fitted."""
        return {k: v for k, v in (("Td", self.Td), ("tau", self.tau), ("K", self.K)) if v is not None}

    @classmethod
    def of_plant(cls, plant: dict[str, Any]) -> ModelEstimate:
        """The cycles estimate of a plant's ``{"Td", "tau", "K"}`` [s, s, gain] (those given and not None)."""
        unknown = set(plant) - {"Td", "tau", "K"}
        if unknown:
            raise InputError(f"a plant estimate holds Td, tau and K only, got {sorted(unknown)}")
        Td, tau, K = (None if plant.get(k) is None else float(plant[k]) for k in ("Td", "tau", "K"))
        return cls(Td=Td, tau=tau, K=K)


def _number(value: Any, key: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"the diagnosis' identification {key!r} must be a number, got {value!r:.40}")
    return float(value)


@dataclass(frozen=True)
class EffectIdentification:
    """The plant's parameters beside one effect found (``EffectFinding.identification``).

    Attributes
    ----------
    linear : ModelEstimate
        Eq. (2) fitted to the stable cycles' features without the effect (Td, tau [s], K).
    with_effect : ModelEstimate
        The same refitted with the effect (for a second effect: with both, the joint fit).
    model : str or None
        The model refitted, when it is not the effect alone (``"<first>+<second>"`` for a pair).
    """

    linear: ModelEstimate
    with_effect: ModelEstimate
    model: str | None = None

    def model_of(self, effect: str) -> str:
        """The refit's model name: :attr:`model`, else the ``effect``'s own."""
        return self.model if self.model is not None else effect

    def to_json(self) -> dict[str, Any]:
        """The JSON object: ``linear``, ``with_effect`` (their fitted Td, tau, K) and ``model`` when set."""
        out: dict[str, Any] = {"linear": self.linear.to_json(), "with_effect": self.with_effect.to_json()}
        if self.model is not None:
            out["model"] = self.model
        return out

    @classmethod
    def from_json(cls, data: Any) -> EffectIdentification:
        """The record of a :meth:`to_json` object.

        Raises
        ------
        InputError
            Not an object with ``linear`` and ``with_effect`` estimates (one line).
        """
        if not isinstance(data, dict) or not {"linear", "with_effect"} <= set(data):
            raise InputError("a diagnosis effect's identification must be an object with 'linear' and 'with_effect' "
                             f"estimates, got {data!r:.80}; rerun mrft-ident diagnose")
        model = data.get("model")
        if model is not None and not isinstance(model, str):
            raise InputError(f"a diagnosis effect's identification 'model' must be a name, got {model!r:.40}")
        return cls(linear=ModelEstimate.from_json(data["linear"]), with_effect=ModelEstimate.from_json(data["with_effect"]),
                   model=model)

    @classmethod
    def of(cls, linear: dict[str, float], with_effect: dict[str, float], model: str | None = None) -> EffectIdentification:
        """The record of two fits' plant parameters (``{"tau", "K", "Td"}`` [s, s, gain], those fitted)."""
        return cls(linear=ModelEstimate.of_plant(linear), with_effect=ModelEstimate.of_plant(with_effect), model=model)


@dataclass(frozen=True)
class AnalyzeModel:
    """``analyze``'s model of the same log, and why the diagnosis' linear fit differs from it.

    Attributes
    ----------
    estimate : ModelEstimate
        Its Td, tau [s] and K (the point estimates, the finite ones).
    method : str or None
        ``"waveform"`` (the waveform refinement) or ``"mrft"`` (the MRFT estimate); None when unknown.
    tests : list of list of float
        Its tests' spans [s] from the log start.
    differs_because : str or None
        Why the diagnosis' linear model is not this one (None: not said).
    """

    estimate: ModelEstimate
    method: str | None = None
    tests: list[list[float]] = field(default_factory=list)
    differs_because: str | None = None

    def to_json(self) -> dict[str, Any]:
        """The JSON object: Td, tau, K, then how analyze got them and why they differ."""
        out: dict[str, Any] = self.estimate.plant()
        if self.method is not None:
            out.update(method=self.method, tests=self.tests, differs_because=self.differs_because)
        return out

    @classmethod
    def from_json(cls, data: Any) -> AnalyzeModel:
        """The model of a :meth:`to_json` object."""
        if not isinstance(data, dict):
            raise InputError(f"the diagnosis' identification 'analyze' must be an object, got {data!r:.60}")
        plant = {k: data[k] for k in ("Td", "tau", "K") if k in data}
        tests = data.get("tests", [])
        if not isinstance(tests, list) or not all(isinstance(t, list) and len(t) == 2 for t in tests):
            raise InputError("the diagnosis' identification 'analyze' tests must be a list of [start, end] spans")
        return cls(estimate=ModelEstimate.from_json(plant), method=data.get("method"),
                   tests=[[float(a), float(b)] for a, b in tests], differs_because=data.get("differs_because"))


@dataclass(frozen=True)
class Recommendation:
    """The one estimate of Td, tau and K the diagnosis recommends.

    Attributes
    ----------
    source : str
        The identification entry it is (``"linear"``, ``"with_<effect>"``, ``"waveform_with_<effect>"``
        or ``"analyze"``).
    estimate : ModelEstimate
        Its Td, tau [s] and K.
    why : str
        Why that one.
    """

    source: str
    estimate: ModelEstimate
    why: str

    def to_json(self) -> dict[str, Any]:
        """The JSON object: source, Td, tau, K, why."""
        return {"source": self.source, **self.estimate.plant(), "why": self.why}

    @classmethod
    def from_json(cls, data: Any) -> Recommendation:
        """The recommendation of a :meth:`to_json` object."""
        if not isinstance(data, dict) or not {"source", "why"} <= set(data):
            raise InputError(f"the diagnosis' recommended estimate needs 'source' and 'why', got {data!r:.80}")
        return cls(source=str(data["source"]), why=str(data["why"]),
                   estimate=ModelEstimate.from_json({k: data[k] for k in ("Td", "tau", "K") if k in data}))


@dataclass(frozen=True)
class Identification:
    """The plant's parameters from every fit a diagnosis made, and which to take.

    Attributes
    ----------
    loop : str
        The loop (the units of K).
    linear : ModelEstimate
        Eq. (2) fitted to the stable cycles' features.
    refits : dict of str to ModelEstimate
        Per model found (``"input_bias"``, ``"input_bias+sensor_lag"``), eq. (2) refitted with it.
    waveform : dict of str to ModelEstimate
        Per effect the output-error refinement models, the refit on the recorded waveform.
    analyze : AnalyzeModel or None
        analyze's model of the same log, when known.
    recommended : Recommendation
        The estimate to take (:meth:`recommend`).
    """

    loop: str
    linear: ModelEstimate
    refits: dict[str, ModelEstimate] = field(default_factory=dict)
    waveform: dict[str, ModelEstimate] = field(default_factory=dict)
    analyze: AnalyzeModel | None = None
    recommended: Recommendation | None = None

    def entries(self) -> dict[str, ModelEstimate]:
        """Every estimate by its JSON key (``linear``, ``with_*``, ``waveform_with_*``, ``analyze``)."""
        out = {"linear": self.linear, **{f"with_{k}": v for k, v in self.refits.items()},
               **{f"waveform_with_{k}": v for k, v in self.waveform.items()}}
        if self.analyze is not None:
            out["analyze"] = self.analyze.estimate
        return out

    def recommend(self, effects: list[str]) -> Identification:
        """This identification with its :attr:`recommended` estimate for the deterministic ``effects`` found.

        One effect the waveform refinement models: its waveform refit (every sample, as analyze's
        refinement; the cycle refit is what the selection compared). Otherwise the cycle refit with
        every effect found (a pair's joint fit). Nothing found: analyze's model when known (the
        linear model explains the log), else the linear fit.
        """
        if effects:
            label = "+".join(effects)
            if len(effects) == 1 and effects[0] in self.waveform:
                rec = Recommendation(f"waveform_with_{label}", self.waveform[label],
                                     f"refit with {label} on the recorded waveform (every sample, as analyze's "
                                     "refinement; the cycle refit is what the selection compared)")
            else:
                key = label if label in self.refits else effects[-1]
                rec = Recommendation(f"with_{key}", self.refits[key],
                                     f"refit to the cycles with {key}: the linear model leaves it out")
        elif self.analyze is not None:
            rec = Recommendation("analyze", self.analyze.estimate,
                                 "the linear model explains the log: analyze's estimate of it")
        else:
            rec = Recommendation("linear", self.linear, "the linear model explains the log (its fit to the cycles; "
                                 "analyze's estimate of the same log is the one to take when it is at hand)")
        # the recommendation states the plant (Td, tau, K); the entry it names keeps the rest
        return replace(self, recommended=replace(rec, estimate=ModelEstimate.of_plant(rec.estimate.plant())))

    def to_json(self) -> dict[str, Any]:
        """The JSON's ``identification`` object."""
        out: dict[str, Any] = {"linear": self.linear.to_json()}
        out.update({f"with_{k}": v.to_json() for k, v in self.refits.items()})
        out.update({f"waveform_with_{k}": v.to_json() for k, v in self.waveform.items()})
        if self.analyze is not None:
            out["analyze"] = self.analyze.to_json()
        if self.recommended is not None:
            out["recommended"] = self.recommended.to_json()
        out["units"] = {"Td": "s", "tau": "s", "K": gain_unit(self.loop), "Tp": "s",
                        "residual_rms": output_unit(self.loop)}
        return out

    @classmethod
    def from_json(cls, data: Any, loop: str) -> Identification:
        """The identification of a :meth:`to_json` object (inside a diagnosis of ``loop``).

        Raises
        ------
        InputError
            Not an object, no ``linear`` entry, or an entry that is not a set of numbers (one line).
        """
        if not isinstance(data, dict) or "linear" not in data:
            raise InputError(f"the diagnosis' identification must be an object with a 'linear' entry, got {data!r:.80}")
        refits, waveform = {}, {}
        for key, value in data.items():
            if key.startswith("waveform_with_"):
                waveform[key.removeprefix("waveform_with_")] = ModelEstimate.from_json(value, "waveform")
            elif key.startswith("with_"):
                refits[key.removeprefix("with_")] = ModelEstimate.from_json(value)
        analyze = data.get("analyze")
        rec = data.get("recommended")
        return cls(loop=loop, linear=ModelEstimate.from_json(data["linear"]), refits=refits, waveform=waveform,
                   analyze=None if analyze is None else AnalyzeModel.from_json(analyze),
                   recommended=None if rec is None else Recommendation.from_json(rec))


def analyze_model(analysis: AnalysisResult) -> AnalyzeModel:
    """analyze's model of a log: its point estimates (the finite ones), how it got them, its tests."""
    means = {"Td": analysis.Td.value, "tau": analysis.tau.value, "K": analysis.K.value}
    plant = {k: float(v) for k, v in means.items() if v is not None and math.isfinite(float(v))}
    if "K" in plant:
        plant["K"] = abs(plant["K"])  # the loop's sign is the layout's, not the plant's
    return AnalyzeModel(estimate=ModelEstimate.of_plant(plant), method="waveform" if analysis.method == "waveform" else "mrft",
                        tests=[[t.t_start - analysis.t0, t.t_end - analysis.t0] for t in analysis.tests],
                        differs_because=DIFFERS_BECAUSE)


def with_analysis(identification: Identification, analysis: AnalysisResult, effects: list[str]) -> Identification:
    """``identification`` with analyze's model of the same log (computed after the diagnosis, as the CLI
    does), its recommendation made again for the deterministic ``effects`` found."""
    return replace(identification, analyze=analyze_model(analysis)).recommend(effects)
