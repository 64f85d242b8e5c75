"""The records the diagnosis returns: the result, each effect found, and what the report draws.

:class:`DiagnosisResult` crosses process lines (``diagnose --json``, ``batch`` records):
:meth:`~DiagnosisResult.to_dict` is the CLI's JSON (unchanged layout), :meth:`~DiagnosisResult.to_json`
the same with its ``schema_version``, read back by :meth:`~DiagnosisResult.from_json`. The report's
figures (:class:`DiagnosisFigures`) hold live models and fits and are never serialised. The rows
inside it live in :mod:`mrftcli.diagnose.rows` (re-exported here).

The plant's parameters a diagnosis reports: its linear fit, the refits with the effects found,
analyze's model of the same log and the one estimate the user should take (issue 26, item 4).

:class:`Identification` is ``DiagnosisResult.identification``; its :meth:`~Identification.to_json`
is the JSON's ``identification`` object (the layout of the result's ``schema_version``):
``linear``, ``with_<effect>`` (``with_<a>+<b>`` for a pair), ``waveform_with_<effect>``, ``analyze``
(when an analysis of the log is known: :func:`with_analysis`), ``recommended`` and ``units``.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Iterator, Mapping

import numpy as np

from ..errors import InputError
from ..io.logtypes import gain_unit, output_unit
from ..jsonable import check_schema_version
from .physics import Z_LIMIT
from .rows import (CandidateFit, Disagreement, Evidence, HeldOut, PairFit, TestRow, Unexplained, expect_list,
                   expect_object)

if TYPE_CHECKING:
    from ..analyze.record import AnalysisResult
    from ..io.logtypes import FlightLog
    from .fit import Fit
    from .prepared import DiagnosedTest
    from .candidate_model import CandidateModel
    from .locate import TestCheck

__all__ = ["SCHEMA_VERSION", "NRMSE_DEFINITION", "HELD_OUT_DEFINITION_TESTS", "HeldOut", "CandidateFit", "PairFit", "Evidence", "Disagreement",
           "TestRow", "Unexplained", "Identification", "EffectIdentification", "ModelEstimate",
           "analyze_model", "with_analysis", "DIFFERS_BECAUSE", "EffectFinding", "FinalModel", "CycleErrors", "DiagnosisFigures",
           "DiagnosisResult"]

#: the layout of :meth:`DiagnosisResult.to_json` (raise it when a key changes meaning or goes away). 2: one
#: record for every family (issue 36): eq. (2)'s diagnosis (1) and the families' ``process_diagnosis`` (1, 2).
#: 3: ``analyze_refusal``, analyze's refusal of a log the diagnosis went on without (issue 39; 2 still read)
SCHEMA_VERSION = 3

#: how the held-out NRMSE figures are defined (the JSON's ``nrmse_definition``)
NRMSE_DEFINITION = (
                "held-out (odd) stable cycles; waveform NRMSE = RMS(recorded - model) / RMS(recorded - its "
                "cycle mean), recorded waveform projected on harmonics 1-7 of each cycle (sensor noise "
                "removed), recorded and model cycles both aligned at the -h -> +h switch and put on the mean "
                "held-out period of the test (phase-normalised: the period is judged by the feature z-scores, "
                "whose standard errors account for the few-cycle sampling error of the mean period); the "
                "cycle-to-cycle scatter of the recording that no deterministic model can predict (residual of a "
                "per-phase linear trend over the held-out cycles of each test, or all its stable cycles when fewer than 3 are held out, dof-corrected; reported as "
                "scatter_nrmse) is subtracted from the mean square error (nrmse_raw keeps it; nrmse_timed also "
                "keeps the model's own period, and is what confirms a candidate, with a held-out feature chi^2 "
                "gain of at least 10); for delay_jitter the nrmse is the relative error of the predicted "
                "cycle-to-cycle period scatter on the held-out cycles, pooled over the tests"
)


#: why the diagnosis' linear model is not analyze's (the terminal and the JSON say it)
DIFFERS_BECAUSE = ("diagnose refits the linear model to the cycles it compares the candidates on (the stable "
                   "cycles above, by their features), so the two differ by that choice of data")

#: the JSON keys of each kind of estimate, in order (the layout before the record existed)
_KEYS = {
    "cycles": ("tau", "K", "Td", "Tp"),
    "waveform": ("Td", "tau", "K", "Tp", "value", "value_std", "residual_rms"),
    "analyze": ("Td", "tau", "K", "method", "tests", "differs_because"),
    "recommended": ("source", "Td", "tau", "K", "why"),
}
#: the keys that hold words (the others numbers, but an analyze entry's ``tests``)
_WORDS = ("method", "differs_because", "source", "why")


@dataclass(frozen=True)
class ModelEstimate:
    """Eq. (2)'s parameters from one fit.

    Attributes
    ----------
    kind : str
        ``"cycles"`` (fitted to the stable cycles' features), ``"waveform"`` (the output-error refit
        on the recorded waveform, with the effect's parameter ``value``), ``"analyze"`` (analyze's
        model of the same log: its point estimates, the finite ones) or ``"recommended"`` (the one
        estimate the diagnosis recommends: :meth:`Identification.recommend`).
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
    method, tests, differs_because : str, list of list of float, str or None
        analyze's: ``"waveform"`` (the waveform refinement) or ``"mrft"`` (the MRFT estimate), its tests'
        spans [s] from the log start, and why the diagnosis' linear model is not this one.
    source, why : str or None
        The recommended's: the identification entry it is (``"linear"``, ``"with_<effect>"``,
        ``"waveform_with_<effect>"`` or ``"analyze"``), and why that one.
    """

    kind: str = "cycles"
    Td: float | None = None
    tau: float | None = None
    K: float | None = None
    Tp: float | None = None
    value: float | None = None
    value_std: float | None = None
    residual_rms: float | None = None
    method: str | None = None
    tests: list[list[float]] | None = None
    differs_because: str | None = None
    source: str | None = None
    why: str | None = None

    def to_json(self) -> dict[str, Any]:
        """The JSON object (the kind's keys that are set, in order)."""
        return {k: getattr(self, k) for k in _KEYS[self.kind] if getattr(self, k) is not None}

    @classmethod
    def from_json(cls, data: Any, kind: str = "cycles") -> ModelEstimate:
        """The estimate of a :meth:`to_json` object (its numbers checked)."""
        if not isinstance(data, dict) or not set(data) <= set(_KEYS[kind]):
            raise InputError(f"a diagnosis' identification entry must be an object of {', '.join(_KEYS[kind])}; "
                             f"got {data!r:.80}")
        if kind == "recommended" and not {"source", "why"} <= set(data):
            raise InputError(f"the diagnosis' recommended estimate needs 'source' and 'why', got {data!r:.80}")
        tests = data.get("tests")
        if tests is not None and not (isinstance(tests, list) and all(isinstance(t, list) and len(t) == 2 for t in tests)):
            raise InputError("the diagnosis' identification 'analyze' tests must be a list of [start, end] spans")
        values: dict[str, Any] = {k: (None if v is None else str(v)) if k in _WORDS else _number(v, k)
                                  for k, v in data.items() if k != "tests"}
        if tests is not None:
            values["tests"] = [[float(a), float(b)] for a, b in tests]
        return cls(kind=kind, **values)

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
    analyze : ModelEstimate or None
        analyze's model of the same log (kind ``"analyze"``), when known.
    recommended : ModelEstimate or None
        The estimate to take (kind ``"recommended"``: :meth:`recommend`).
    """

    loop: str
    linear: ModelEstimate
    refits: dict[str, ModelEstimate] = field(default_factory=dict)
    waveform: dict[str, ModelEstimate] = field(default_factory=dict)
    analyze: ModelEstimate | None = None
    recommended: ModelEstimate | None = None

    def entries(self) -> dict[str, ModelEstimate]:
        """Every estimate by its JSON key (``linear``, ``with_*``, ``waveform_with_*``, ``analyze``)."""
        out = {"linear": self.linear, **{f"with_{k}": v for k, v in self.refits.items()},
               **{f"waveform_with_{k}": v for k, v in self.waveform.items()}}
        if self.analyze is not None:
            out["analyze"] = self.analyze
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
                source, est, why = (f"waveform_with_{label}", self.waveform[label],
                                    f"refit with {label} on the recorded waveform (every sample, as analyze's "
                                    "refinement; the cycle refit is what the selection compared)")
            else:
                key = label if label in self.refits else effects[-1]
                source, est, why = (f"with_{key}", self.refits[key],
                                    f"refit to the cycles with {key}: the linear model leaves it out")
        elif self.analyze is not None:
            source, est, why = ("analyze", self.analyze, "the linear model explains the log: analyze's estimate of it")
        else:
            source, est, why = ("linear", self.linear, "the linear model explains the log (its fit to the cycles; "
                                "analyze's estimate of the same log is the one to take when it is at hand)")
        # the recommendation states the plant (Td, tau, K); the entry it names keeps the rest
        plant = ModelEstimate.of_plant(est.plant())
        return replace(self, recommended=replace(plant, kind="recommended", source=source, why=why))

    def to_json(self) -> dict[str, Any]:
        """The JSON's ``identification`` object."""
        out: dict[str, Any] = {k: v.to_json() for k, v in self.entries().items()}
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
                   analyze=None if analyze is None else ModelEstimate.from_json(analyze, "analyze"),
                   recommended=None if rec is None else ModelEstimate.from_json(rec, "recommended"))


def analyze_model(analysis: AnalysisResult) -> ModelEstimate:
    """analyze's model of a log: its point estimates (the finite ones), how it got them, its tests."""
    means = {"Td": analysis.Td.value, "tau": analysis.tau.value, "K": analysis.K.value}
    plant = {k: float(v) for k, v in means.items() if v is not None and math.isfinite(float(v))}
    if "K" in plant:
        plant["K"] = abs(plant["K"])  # the loop's sign is the layout's, not the plant's
    return replace(ModelEstimate.of_plant(plant), kind="analyze", method="waveform" if analysis.method == "waveform" else "mrft",
                   tests=[[t.t_start - analysis.t0, t.t_end - analysis.t0] for t in analysis.tests],
                   differs_because=DIFFERS_BECAUSE)


def with_analysis(identification: Identification, analysis: AnalysisResult, effects: list[str]) -> Identification:
    """``identification`` with analyze's model of the same log (computed after the diagnosis, as the CLI
    does), its recommendation made again for the deterministic ``effects`` found."""
    return replace(identification, analyze=analyze_model(analysis)).recommend(effects)


@dataclass(frozen=True)
class EffectFinding:
    """A candidate effect with its fit and evidence (``to_dict`` gives the JSON item).

    Attributes
    ----------
    name, explanation, augmentation : str
        The candidate (:mod:`mrftcli.diagnose.physics`), what it means, how it augments the model.
    parameters : dict
        Its parameter's value and standard error (the candidate's units), and the plant's fitted with
        it; with a second effect, the value fitted alone too (``<parameter>_alone``).
    evidence : Evidence
        Its delta BIC against the model it beats, and the models it ties with.
    fit_before, fit_after : HeldOut
        The held-out scores of the model it is compared with and of the model with it (the JSON keeps
        :meth:`HeldOut.summary`).
    identification : EffectIdentification
        The plant's ``linear`` and ``with_effect`` estimates (and the refit's ``model`` for a pair).
    harmonics : dict
        Per test index, the relative errors of G(j k Omega) before and after.
    """

    name: str
    explanation: str
    augmentation: str
    parameters: dict[str, Any]
    evidence: Evidence
    fit_before: HeldOut
    fit_after: HeldOut
    identification: EffectIdentification
    harmonics: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "explanation": self.explanation,
            "augmentation": self.augmentation,
            "parameters": self.parameters,
            "evidence": self.evidence.to_dict(),
            "fit_before": self.fit_before.summary(),
            "fit_after": self.fit_after.summary(),
            "identification": self.identification.to_json(),
            "harmonics": self.harmonics,
        }

    @classmethod
    def from_dict(cls, data: Any) -> EffectFinding:
        """The finding of a :meth:`to_dict` item.

        Raises
        ------
        InputError
            A key is missing or of the wrong kind.
        """
        data = expect_object(data, "effects")
        with _reading("a diagnosis effect"):
            return cls(name=str(data["name"]), explanation=str(data["explanation"]),
                       augmentation=str(data["augmentation"]), parameters=expect_object(data["parameters"], "parameters"),
                       evidence=Evidence.from_dict(data["evidence"]), fit_before=HeldOut.from_dict(data["fit_before"]),
                       fit_after=HeldOut.from_dict(data["fit_after"]),
                       identification=EffectIdentification.from_json(data["identification"]),
                       harmonics=expect_object(data.get("harmonics", {}), "harmonics"))


@contextmanager
def _reading(what: str, fix: str = "") -> Iterator[None]:
    """Read ``what`` of a JSON object: a missing key or a value of the wrong kind is an :class:`InputError`
    in one line (``fix``: what to do, after the message); a row's own message passes through."""
    try:
        yield
    except InputError:
        raise
    except KeyError as err:
        raise InputError(f"{what} has no {err.args[0]!r}{fix}") from None
    except (TypeError, ValueError, AttributeError) as err:
        raise InputError(f"{what} is malformed ({err})".replace("\n", " ")) from None


@dataclass(frozen=True)
class FinalModel:
    """The deterministic model finally chosen: ``label`` (e.g. ``"input_bias + sensor_lag"``), the
    model and its fit."""

    label: str
    model: CandidateModel
    fit: Fit


@dataclass(frozen=True)
class CycleErrors:
    """One test's waveform error per stable cycle of a model (the report's located plot).

    Attributes
    ----------
    t : ndarray
        Cycle mid times [s] (log time).
    nrmse : ndarray
        Waveform NRMSE of each cycle (RMS error over the RMS of the recorded cycle about its mean).
    hi, lo : ndarray
        The same over the +h and the -h half of each cycle.
    start, end : ndarray
        Cycle start and end times [s] (log time).
    """

    t: np.ndarray
    nrmse: np.ndarray
    hi: np.ndarray
    lo: np.ndarray
    start: np.ndarray
    end: np.ndarray


@dataclass(frozen=True)
class DiagnosisFigures:
    """What :mod:`mrftcli.report.diagnosis` draws (live objects; never serialised).

    Attributes
    ----------
    flight : FlightLog
        The log's signals.
    tests : list of DiagnosedTest
        The tests diagnosed, with their cycles and the fitting/held-out split.
    base_model, base : CandidateModel, Fit
        The linear model and its fit.
    fits : dict
        Each candidate fitted alone: name -> (model, fit).
    effects : list of str
        The effects found (names).
    final : FinalModel or None
        The deterministic model finally chosen (None when nothing was found).
    cycle_errors : list of CycleErrors
        Per test, the linear model's waveform error per cycle.
    harmonics : list of dict
        Per test, the linear model's relative error of G(j k Omega) per odd harmonic ("1", "3", ...).
    """

    flight: FlightLog
    tests: list[DiagnosedTest]
    base_model: CandidateModel
    base: Fit
    fits: dict[str, tuple[CandidateModel, Fit]]
    effects: list[str]
    final: FinalModel | None
    cycle_errors: list[CycleErrors]
    harmonics: list[dict[str, Any]]

    def augmented(self) -> FinalModel | None:
        """The reported effect's model to overlay: the final one, else the first effect fitted alone."""
        if self.final is not None:
            return self.final
        for name in self.effects:
            if name in self.fits:
                model, fit = self.fits[name]
                return FinalModel(name, model, fit)
        return None


#: how the families' held-out error is defined (the JSON's ``held_out_definition`` for a family other than eq. (2))
HELD_OUT_DEFINITION_TESTS = (
                "RMS over the tests of each test's relative error predicted from the model of the other tests, "
                "over the views the effect changes (cycle: frequency and amplitude; balance: the mean input's "
                "residual over h; scatter: ln of the period variance's ratio)"
)

Row = Any  # a candidate row: eq. (2)'s CandidateFit / PairFit, or the families' EffectFit


@dataclass(frozen=True)
class DiagnosisResult:
    """What :func:`diagnose` found, for every family (one record; issue 36).

    The family's strategy fills its own parts: eq. (2) (``family`` ``"soiptd"``) compares the cycles
    feature by feature (``identification``, ``tests``, ``unexplained``, ``noise_std``, ``t0``, rows
    :class:`CandidateFit` / :class:`PairFit` / :class:`EffectFinding` / :class:`Disagreement`); every
    other family checks each test held out (``checks``, ``analysis``, ``notes``, rows
    :class:`~mrftcli.diagnose.physics.EffectFit`, ``located`` as sentences). The parts of the other
    strategy are empty (None in the JSON).

    Attributes
    ----------
    path, loop : str
        The log and loop.
    family : str
        The model's family (``"soiptd"``: eq. (2)).
    summary : str
        The first line: the effects found (with the held-out error before and after), consistent,
        or unexplained with where the residual sits.
    Tp : float or None
        Eq. (2): the propulsion time constant used [s].
    effects : list
        The effects the evidence supports, in order (empty when the linear model explains the log):
        eq. (2)'s :class:`EffectFinding`, the families' ``EffectFit`` rows.
    candidates : list
        Every candidate alone with its evidence and held-out scores (including the rejected ones).
    second_effect_candidates : list
        When an effect was found: every other candidate fitted together with it (``with``), against
        that effect's model (a second effect is reported when it passes the same rules). Eq. (2): when
        the first effect already explains the held-out cycles, a candidate whose probe
        (``probe_delta_chi2``) is too small is listed with ``delta_bic`` None and a ``status``.
    located : list
        Where the base model disagrees with the recording, largest first (eq. (2):
        :class:`Disagreement`; the families: sentences with units and sigma).
    identification : Identification or None
        Eq. (2): the linear fit, per found effect the refit that accounts for it (and on the recorded
        waveform where the refinement models it), analyze's model of the log when known, and the one
        estimate to take (``recommended``). The families: their ``analysis`` holds the identification.
    tests : list of TestRow
        Eq. (2): per test beta (nominal, effective up/down), h, bias, cycles used, times.
    noise_std : float or None
        Eq. (2): sensor noise estimated from the residual of the cycle projections [output units].
    warnings, notes : list of str
        What the reader needs to weigh the result (the families' notes: what is not checked).
    analyze_refusal : str or None
        Eq. (2): analyze's refusal of the log (its message without the log's path) when the diagnosis went
        on without analyze's model (no plant of eq. (2) fits; one beta left of tests that differ in beta or
        relay height); None when analyze identified the log (and for the families). Schema 3.
    unexplained : Unexplained or None
        Eq. (2): the mismatch that no candidate (or pair) explains, when the linear model is rejected on
        the fitting and the held-out cycles and the model finally chosen still is on the held-out ones
        (chi^2 p-value below ``UNEXPLAINED_P``): ``what``, ``after``, ``held_out_feature_chi2`` /
        ``held_out_features`` / ``p_value``, ``held_out_nrmse_raw``, ``tests`` (numbered from 1),
        ``largest``, ``segments``, ``harmonics``, ``worse_half``, ``best_candidate``. (The families say
        it in ``summary``: "unexplained ... beyond it".)
    t0 : float
        Log start [s]; ``*_rel`` times in ``tests`` and ``located`` are from it.
    checks : list of TestCheck
        The families: each test against the model of the other tests and of all tests.
    analysis : AnalysisResult or None
        The families: ``analyze --model``'s record of the same log.
    figures : DiagnosisFigures or None
        Eq. (2): what :mod:`mrftcli.report.diagnosis` draws (not JSON): None on a result read back.
    schema_version : int
        The version of :meth:`to_json`'s layout (:data:`SCHEMA_VERSION`).
    """

    path: str
    loop: str
    summary: str
    family: str = "soiptd"
    Tp: float | None = None
    effects: list[Row] = field(default_factory=list)
    candidates: list[Row] = field(default_factory=list)
    located: list[Any] = field(default_factory=list)
    identification: Identification | None = None
    tests: list[TestRow] = field(default_factory=list)
    noise_std: float | None = None
    warnings: list[str] = field(default_factory=list)
    second_effect_candidates: list[Row] = field(default_factory=list)
    unexplained: Unexplained | None = None
    t0: float = 0.0
    notes: list[str] = field(default_factory=list)
    checks: list[TestCheck] = field(default_factory=list)
    analysis: AnalysisResult | None = field(default=None, compare=False)
    figures: DiagnosisFigures | None = field(default=None, repr=False, compare=False)
    analyze_refusal: str | None = None
    schema_version: int = SCHEMA_VERSION

    @property
    def soiptd(self) -> bool:
        """Eq. (2)'s strategy (cycle features) rather than the families' (tests held out)."""
        return self.family == "soiptd"

    @property
    def found(self) -> tuple[str, ...]:
        """The names of the effects found, in order."""
        return tuple(e.name for e in self.effects)

    @property
    def consistent(self) -> bool | None:
        """The families: no test disagrees with the model beyond ``Z_LIMIT`` (None for eq. (2))."""
        return None if self.soiptd else not any(c.disagrees for c in self.checks)

    def named(self, row: Row) -> bool:
        """Whether the candidate ``row`` (alone, or on top of its ``with_``) is an effect found."""
        if not self.soiptd:
            return any((e.name, e.with_) == (row.name, row.with_) for e in self.effects)
        # the delay jitter is a candidate row judged on top of the first effect found: its own
        # ``compared_with`` names that model (``"linear + <effect>"``), its ``with_`` is empty
        base = getattr(row, "compared_with", None) or (f"linear + {row.with_}" if row.with_ else "linear")
        return any(e.name == row.name and e.evidence.compared_with == base for e in self.effects)

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` output without its version (the batch record's ``diagnosis``)."""
        feature = self.soiptd
        return {
            "kind": "diagnosis",
            "family": self.family,
            "path": self.path,
            "loop": self.loop,
            "Tp": self.Tp,
            "summary": self.summary,
            "found": list(self.found),
            "effects": [e.to_dict() if feature else e.to_json() for e in self.effects],
            "located": [d.to_dict() if feature else d for d in self.located],
            "identification": None if self.identification is None else self.identification.to_json(),
            "candidates": [c.to_dict() if feature else c.to_json() for c in self.candidates],
            "second_effect_candidates": [c.to_dict() if feature else c.to_json() for c in self.second_effect_candidates],
            "unexplained": None if self.unexplained is None else self.unexplained.to_dict(),
            "t0": self.t0,
            "tests": [t.to_dict() for t in self.tests],
            "noise_std": self.noise_std,
            "nrmse_definition": NRMSE_DEFINITION if feature else HELD_OUT_DEFINITION_TESTS,
            "warnings": self.warnings,
            "analyze_refusal": self.analyze_refusal,
            "notes": self.notes,
            "consistent": self.consistent,
            "z_limit": None if feature else Z_LIMIT,
            "checks": [c.to_json() for c in self.checks],
            "analysis": None if self.analysis is None else self.analysis.to_json(),
        }

    def to_json(self) -> dict[str, Any]:
        """:meth:`to_dict` with the ``schema_version`` (what ``diagnose --json`` writes and :meth:`from_json` reads)."""
        return {"schema_version": self.schema_version, **self.to_dict()}

    @classmethod
    def from_json(cls, data: Any) -> DiagnosisResult:
        """The result of a :meth:`to_json` dict (without its figures), of this version or an earlier one.

        Read for one release: version 1 of eq. (2)'s diagnosis (``diagnose --json`` before issue 36
        wrote it without ``schema_version``, as the batch records still hold it), version 2 (no
        ``analyze_refusal``: read as None), and the families' ``process_diagnosis`` of versions 1 (no
        effects) and 2.

        Raises
        ------
        InputError
            Not a diagnosis of a version this one reads, or a key missing or of the wrong kind.
        """
        if isinstance(data, dict) and data.get("kind") == "process_diagnosis":
            return _from_process_json(data)
        data = check_schema_version(data, "diagnosis", (1, 2, SCHEMA_VERSION), missing=1,
                                    fix="rerun mrft-ident diagnose")
        with _reading("the diagnosis", "; rerun mrft-ident diagnose"):
            if data.get("family", "soiptd") != "soiptd":  # a family's diagnosis of this version
                return _family_result(data, str(data["summary"]),
                                      [*expect_list(data["candidates"], "candidates"),
                                       *expect_list(data["second_effect_candidates"], "second_effect_candidates")])
            unexplained, ident = data["unexplained"], data["identification"]
            return cls(
                path=str(data["path"]), loop=str(data["loop"]), Tp=float(data["Tp"]),
                effects=[EffectFinding.from_dict(e) for e in expect_list(data["effects"], "effects")],
                candidates=[CandidateFit.from_dict(c) for c in expect_list(data["candidates"], "candidates")],
                located=[Disagreement.from_dict(d) for d in expect_list(data["located"], "located")],
                identification=Identification.from_json(ident, str(data["loop"])),
                tests=[TestRow.from_dict(t) for t in expect_list(data["tests"], "tests")], noise_std=float(data["noise_std"]),
                summary=str(data["summary"]), warnings=[str(w) for w in expect_list(data["warnings"], "warnings")],
                second_effect_candidates=[PairFit.from_dict(c) for c in expect_list(data["second_effect_candidates"],
                                                                               "second_effect_candidates")],
                unexplained=None if unexplained is None else Unexplained.from_dict(unexplained),
                t0=float(data["t0"]), notes=[str(n) for n in expect_list(data.get("notes", []), "notes")],
                # schema 3; versions 1 and 2 did not say (None)
                analyze_refusal=None if data.get("analyze_refusal") is None else str(data["analyze_refusal"]),
            )


def _family_result(data: Mapping[str, Any], summary: str, rows: list[Any]) -> DiagnosisResult:
    """The families' record from the JSON keys both their layouts share (``rows``: every EffectFit, in order)."""
    from ..analyze.record import AnalysisResult
    from .physics import EffectFit
    from .locate import TestCheck

    fits = [EffectFit.from_json(c) for c in rows]
    analysis = AnalysisResult.from_json(data["analysis"])
    found = [str(s) for s in data.get("found", [])]
    effects: list[EffectFit] = []
    for name in found:  # each named effect's row: alone, then on top of those before it
        prior = "+".join(f.name for f in effects)
        effects += [c for c in fits if c.name == name and c.with_ == prior][:1]
    return DiagnosisResult(
        path=str(data.get("path", analysis.path)), loop=str(data.get("loop", analysis.loop)), summary=summary,
        family=str(data.get("family", data["analysis"].get("model", "declared"))), effects=effects,
        candidates=[c for c in fits if not c.with_], second_effect_candidates=[c for c in fits if c.with_],
        located=[str(s) for s in data.get("located", [])], warnings=[str(w) for w in data.get("warnings", [])],
        notes=[str(s) for s in data.get("notes", [])], t0=float(data.get("t0", analysis.t0)),
        checks=[TestCheck.from_json(c) for c in data["checks"]], analysis=analysis)


def _from_process_json(data: Mapping[str, Any]) -> DiagnosisResult:
    """The families' ``process_diagnosis`` of versions 1 (no effects) and 2, before the one record (issue 36)."""
    data = check_schema_version(data, "process diagnosis JSON", (1, 2))
    with _reading("the process diagnosis JSON"):
        return _family_result(data, str(data["verdict"]), list(data.get("candidates", [])))
