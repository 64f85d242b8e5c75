"""The records the diagnosis returns: the result, each effect found, and what the report draws.

:class:`DiagnosisResult` crosses process lines (``diagnose --json``, ``batch`` records):
:meth:`~DiagnosisResult.to_dict` is the CLI's JSON (unchanged layout), :meth:`~DiagnosisResult.to_json`
the same with its ``schema_version``, read back by :meth:`~DiagnosisResult.from_json`. The report's
figures (:class:`DiagnosisFigures`) hold live models and fits and are never serialised. The rows
inside it live in :mod:`mrftcli.diagnose.rows` (re-exported here), the plant's estimates in
:mod:`mrftcli.diagnose.identification`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from ..errors import InputError
from ..jsonable import check_schema_version
from .identification import EffectIdentification, Identification
from .rows import (CandidateFit, Disagreement, Evidence, HeldOut, PairFit, TestRow, Unexplained, expect_list,
                   expect_object)

if TYPE_CHECKING:
    from ..analyze.record import AnalysisResult
    from ..io.logtypes import FlightLog
    from .checks import TestCheck
    from .fit import CandidateModel, DiagnosedTest, Fit

__all__ = ["SCHEMA_VERSION", "NRMSE_DEFINITION", "HELD_OUT_DEFINITION_TESTS", "HeldOut", "CandidateFit", "PairFit", "Evidence", "Disagreement",
           "TestRow", "Unexplained", "Identification", "EffectIdentification", "EffectFinding", "FinalModel", "CycleErrors", "DiagnosisFigures",
           "DiagnosisResult"]

#: the layout of :meth:`DiagnosisResult.to_json` (raise it when a key changes meaning or goes away). 2: one
#: record for every family (issue 36): eq. (2)'s diagnosis (1) and the families' ``process_diagnosis`` (1, 2)
SCHEMA_VERSION = 2

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
        if not isinstance(data, dict):
            raise InputError(f"a diagnosis effect must be a JSON object, got {type(data).__name__}")
        try:
            return cls(name=str(data["name"]), explanation=str(data["explanation"]),
                       augmentation=str(data["augmentation"]), parameters=expect_object(data["parameters"], "parameters"),
                       evidence=Evidence.from_dict(data["evidence"]), fit_before=HeldOut.from_dict(data["fit_before"]),
                       fit_after=HeldOut.from_dict(data["fit_after"]),
                       identification=EffectIdentification.from_json(data["identification"]),
                       harmonics=expect_object(data.get("harmonics", {}), "harmonics"))
        except InputError:
            raise
        except KeyError as err:
            raise InputError(f"a diagnosis effect has no {err.args[0]!r}") from None
        except (TypeError, ValueError) as err:
            raise InputError(f"a diagnosis effect is malformed ({err})".replace("\n", " ")) from None


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
    :class:`~mrftcli.diagnose.effects.EffectFit`, ``located`` as sentences). The parts of the other
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

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` output without its version (the batch record's ``diagnosis``)."""
        from .checks import Z_LIMIT

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
        wrote it without ``schema_version``, as the batch records still hold it), and the families'
        ``process_diagnosis`` of versions 1 (no effects) and 2.

        Raises
        ------
        InputError
            Not a diagnosis of a version this one reads, or a key missing or of the wrong kind.
        """
        if isinstance(data, dict) and data.get("kind") == "process_diagnosis":
            return _from_process_json(data)
        data = check_schema_version(data, "diagnosis", (1, SCHEMA_VERSION), missing=1,
                                    fix="rerun mrft-ident diagnose")
        try:
            if data.get("family", "soiptd") != "soiptd":
                return _from_family_json(data)
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
            )
        except InputError:
            raise  # a row's own one-line message
        except KeyError as err:
            raise InputError(f"the diagnosis has no {err.args[0]!r}; rerun mrft-ident diagnose") from None
        except (TypeError, ValueError, AttributeError) as err:
            raise InputError(f"the diagnosis JSON is malformed ({err})".replace("\n", " ")) from None


def _family_result(data: Mapping[str, Any], summary: str, rows: list[Any]) -> DiagnosisResult:
    """The families' record from the JSON keys both their layouts share (``rows``: every EffectFit, in order)."""
    from ..analyze.record import AnalysisResult
    from .checks import TestCheck
    from .effects import EffectFit

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


def _from_family_json(data: Mapping[str, Any]) -> DiagnosisResult:
    """A family's diagnosis of this version (the caller maps its errors to one line)."""
    return _family_result(data, str(data["summary"]),
                          [*expect_list(data["candidates"], "candidates"),
                           *expect_list(data["second_effect_candidates"], "second_effect_candidates")])


def _from_process_json(data: Mapping[str, Any]) -> DiagnosisResult:
    """The families' ``process_diagnosis`` of versions 1 (no effects) and 2, before the one record (issue 36)."""
    data = check_schema_version(data, "process diagnosis JSON", (1, 2))
    try:
        return _family_result(data, str(data["verdict"]), list(data.get("candidates", [])))
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise InputError(f"process diagnosis JSON: bad or missing field ({err})") from None
