"""The records the diagnosis returns: the result, each effect found, and what the report draws.

:class:`DiagnosisResult` crosses process lines (``diagnose --json``, ``batch`` records):
:meth:`~DiagnosisResult.to_dict` is the CLI's JSON (unchanged layout), :meth:`~DiagnosisResult.to_json`
the same with its ``schema_version``, read back by :meth:`~DiagnosisResult.from_json`. The report's
figures (:class:`DiagnosisFigures`) hold live models and fits and are never serialised.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InputError

if TYPE_CHECKING:
    from ..io.logtypes import FlightLog
    from .fit import CandidateModel, DiagnosedTest, Fit

__all__ = ["SCHEMA_VERSION", "NRMSE_DEFINITION", "EffectFinding", "FinalModel", "CycleErrors", "DiagnosisFigures",
           "DiagnosisResult"]

#: the layout of :meth:`DiagnosisResult.to_json` (raise it when a key changes meaning or goes away)
SCHEMA_VERSION = 1

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
    evidence : dict
        ``delta_bic``, ``bic``, ``n_features``, ``threshold``, ``compared_with`` (the model it beats),
        ``bic_base`` and, when other models tie with it, ``indistinguishable_from``.
    fit_before, fit_after : dict
        The held-out scores of the model it is compared with and of the model with it.
    identification : dict
        ``linear`` and ``with_effect`` plant parameters (and ``model`` for a pair).
    harmonics : dict
        Per test index, the relative errors of G(j k Omega) before and after.
    """

    name: str
    explanation: str
    augmentation: str
    parameters: dict
    evidence: dict
    fit_before: dict
    fit_after: dict
    identification: dict
    harmonics: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "explanation": self.explanation,
            "augmentation": self.augmentation,
            "parameters": self.parameters,
            "evidence": self.evidence,
            "fit_before": self.fit_before,
            "fit_after": self.fit_after,
            "identification": self.identification,
            "harmonics": self.harmonics,
        }

    @classmethod
    def from_dict(cls, data: dict) -> EffectFinding:
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
                       augmentation=str(data["augmentation"]), parameters=_dict(data["parameters"], "parameters"),
                       evidence=_dict(data["evidence"], "evidence"), fit_before=_dict(data["fit_before"], "fit_before"),
                       fit_after=_dict(data["fit_after"], "fit_after"),
                       identification=_dict(data["identification"], "identification"),
                       harmonics=_dict(data.get("harmonics", {}), "harmonics"))
        except KeyError as err:
            raise InputError(f"a diagnosis effect has no {err.args[0]!r}") from None


def _dict(value: Any, key: str) -> dict:
    if not isinstance(value, dict):
        raise InputError(f"the diagnosis' {key!r} must be a JSON object, got {type(value).__name__}")
    return value


def _list(value: Any, key: str) -> list:
    if not isinstance(value, list):
        raise InputError(f"the diagnosis' {key!r} must be a JSON list, got {type(value).__name__}")
    return value


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
    harmonics: list[dict]

    def augmented(self) -> FinalModel | None:
        """The reported effect's model to overlay: the final one, else the first effect fitted alone."""
        if self.final is not None:
            return self.final
        for name in self.effects:
            if name in self.fits:
                model, fit = self.fits[name]
                return FinalModel(name, model, fit)
        return None


@dataclass(frozen=True)
class DiagnosisResult:
    """What :func:`diagnose` found.

    Attributes
    ----------
    path, loop : str
        The log and loop.
    Tp : float
        The propulsion time constant used [s].
    effects : list of EffectFinding
        Effects the evidence supports (empty when the linear model explains the log).
    candidates : list of dict
        Every candidate's evidence and held-out scores (including the rejected ones).
    second_effect_candidates : list of dict
        When an effect was found: every other candidate fitted together with it (``with``), with its
        evidence and held-out scores against that effect's model (a second effect is reported when it
        passes the same rules). When the first effect already explains the held-out cycles, a
        candidate whose probe (``probe_delta_chi2``) is too small is listed with ``delta_bic`` None
        and a ``status``.
    located : list of dict
        Where the base model disagrees with the recording, largest first.
    identification : dict
        The base (linear) fit and, per found effect, the refit that accounts for it; the analysis'
        own identification when one was given.
    tests : list of dict
        Per test: beta (nominal, effective up/down), h, bias, cycles used, times.
    noise_std : float
        Sensor noise estimated from the residual of the cycle projections [output units].
    summary : str
        One sentence.
    unexplained : dict or None
        The mismatch that no candidate (or pair) explains, when the linear model is rejected on the
        fitting and the held-out cycles and the model finally chosen still is on the held-out ones
        (chi^2 p-value below ``UNEXPLAINED_P``): ``what``, ``after`` (the model it remains after),
        ``held_out_feature_chi2`` / ``held_out_features`` / ``p_value``, ``held_out_nrmse_raw``,
        ``tests`` (numbered from 1), ``largest`` (test, feature, z), ``segments`` (times from the log
        start, cycles from 1, worse half-cycle), ``harmonics`` (relative G(jk Omega) errors),
        ``worse_half``, ``best_candidate``. None otherwise; ``effects`` keeps the named findings only.
    t0 : float
        Log start [s] (the first sample of any series); ``*_rel`` times in ``tests`` and ``located``
        are from it, as ``analyze`` shows them (absolute ``t_start``/``t_end`` are log times).
    figures : DiagnosisFigures or None
        What :mod:`mrftcli.report.diagnosis` draws (the tests, models and fits; not JSON): None on a
        result read back with :meth:`from_json`.
    schema_version : int
        The version of :meth:`to_json`'s layout (:data:`SCHEMA_VERSION`).
    """

    path: str
    loop: str
    Tp: float
    effects: list[EffectFinding]
    candidates: list[dict]
    located: list[dict]
    identification: dict
    tests: list[dict]
    noise_std: float
    summary: str
    warnings: list[str] = field(default_factory=list)
    second_effect_candidates: list[dict] = field(default_factory=list)
    unexplained: dict | None = None
    t0: float = 0.0
    figures: DiagnosisFigures | None = field(default=None, repr=False, compare=False)
    schema_version: int = SCHEMA_VERSION

    def to_dict(self) -> dict:
        """The ``--json`` output (and the batch record's ``diagnosis``)."""
        return {
            "path": self.path,
            "loop": self.loop,
            "Tp": self.Tp,
            "summary": self.summary,
            "effects": [e.to_dict() for e in self.effects],
            "located": self.located,
            "identification": self.identification,
            "candidates": self.candidates,
            "second_effect_candidates": self.second_effect_candidates,
            "unexplained": self.unexplained,
            "t0": self.t0,
            "tests": self.tests,
            "noise_std": self.noise_std,
            "nrmse_definition": NRMSE_DEFINITION,
            "warnings": self.warnings,
        }

    def to_json(self) -> dict:
        """:meth:`to_dict` with the ``schema_version`` (what :meth:`from_json` reads)."""
        return {"schema_version": self.schema_version, **self.to_dict()}

    @classmethod
    def from_json(cls, data: dict) -> DiagnosisResult:
        """The result of a :meth:`to_json` dict (without its figures).

        Raises
        ------
        InputError
            Not a diagnosis of this schema version, or a key missing or of the wrong kind.
        """
        if not isinstance(data, dict):
            raise InputError(f"a diagnosis must be a JSON object, got {type(data).__name__}")
        version = data.get("schema_version")
        if version != SCHEMA_VERSION:
            raise InputError(f"diagnosis schema_version {version!r} is not supported (this version reads "
                             f"{SCHEMA_VERSION}); rerun mrft-ident diagnose")
        try:
            unexplained = data["unexplained"]
            return cls(
                path=str(data["path"]), loop=str(data["loop"]), Tp=float(data["Tp"]),
                effects=[EffectFinding.from_dict(e) for e in _list(data["effects"], "effects")],
                candidates=_list(data["candidates"], "candidates"), located=_list(data["located"], "located"),
                identification=_dict(data["identification"], "identification"),
                tests=_list(data["tests"], "tests"), noise_std=float(data["noise_std"]),
                summary=str(data["summary"]), warnings=[str(w) for w in _list(data["warnings"], "warnings")],
                second_effect_candidates=_list(data["second_effect_candidates"], "second_effect_candidates"),
                unexplained=None if unexplained is None else _dict(unexplained, "unexplained"),
                t0=float(data["t0"]),
            )
        except KeyError as err:
            raise InputError(f"the diagnosis has no {err.args[0]!r}; rerun mrft-ident diagnose") from None
        except (TypeError, ValueError) as err:
            raise InputError(f"the diagnosis JSON is malformed ({err})") from None
