"""The records the diagnosis returns: the result, each effect found, and what the report draws.

:class:`DiagnosisResult` crosses process lines (``diagnose --json``, ``batch`` records):
:meth:`~DiagnosisResult.to_dict` is the CLI's JSON (unchanged layout), :meth:`~DiagnosisResult.to_json`
the same with its ``schema_version``, read back by :meth:`~DiagnosisResult.from_json`. The report's
figures (:class:`DiagnosisFigures`) hold live models and fits and are never serialised.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from ..jsonable import check_schema_version
from ..errors import InputError

if TYPE_CHECKING:
    from ..io.logtypes import FlightLog
    from .fit import CandidateModel, DiagnosedTest, Fit

__all__ = ["SCHEMA_VERSION", "NRMSE_DEFINITION", "HeldOut", "CandidateFit", "PairFit", "Evidence", "Disagreement", "TestRow", "Unexplained", "EffectFinding",
           "FinalModel", "CycleErrors", "DiagnosisFigures", "DiagnosisResult"]

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
    evidence : Evidence
        Its delta BIC against the model it beats, and the models it ties with.
    fit_before, fit_after : HeldOut
        The held-out scores of the model it is compared with and of the model with it (the JSON keeps
        :meth:`HeldOut.summary`).
    identification : dict
        ``linear`` and ``with_effect`` plant parameters (and ``model`` for a pair).
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
    identification: dict[str, Any]
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
            "identification": self.identification,
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
                       augmentation=str(data["augmentation"]), parameters=_dict(data["parameters"], "parameters"),
                       evidence=Evidence.from_dict(data["evidence"]), fit_before=HeldOut.from_dict(data["fit_before"]),
                       fit_after=HeldOut.from_dict(data["fit_after"]),
                       identification=_dict(data["identification"], "identification"),
                       harmonics=_dict(data.get("harmonics", {}), "harmonics"))
        except KeyError as err:
            raise InputError(f"a diagnosis effect has no {err.args[0]!r}") from None
        except (TypeError, ValueError) as err:
            raise InputError(f"a diagnosis effect is malformed ({err})".replace("\n", " ")) from None


def _dict(value: Any, key: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise InputError(f"the diagnosis' {key!r} must be a JSON object, got {type(value).__name__}")
    return value


def _list(value: Any, key: str) -> list[Any]:
    if not isinstance(value, list):
        raise InputError(f"the diagnosis' {key!r} must be a JSON list, got {type(value).__name__}")
    return value


# --------------------------------------------------------------------------------------------------
# the evidence records (JSON items of ``candidates``, ``second_effect_candidates`` and the effects)

#: the keys of a held-out score's JSON, per kind of score (in this order)
_HELD_OUT_KEYS = {
    "waveform": ("nrmse", "nrmse_raw", "nrmse_timed", "scatter_nrmse", "nrmse_per_test", "nrmse_raw_per_test",
                 "feature_rms_z", "feature_chi2", "feature_max_abs_z", "cycles"),
    "failed": ("nrmse", "feature_rms_z"),
    "scatter": ("nrmse", "feature_rms_z", "metric", "cycles"),
}
#: the keys an effect's ``fit_before`` / ``fit_after`` keep (in this order)
_SUMMARY_KEYS = ("nrmse", "nrmse_raw", "nrmse_timed", "scatter_nrmse", "feature_rms_z", "feature_chi2", "cycles",
                 "nrmse_per_test", "metric")


@dataclass(frozen=True)
class HeldOut:
    """A fitted model scored on the held-out (odd) cycles (:func:`mrftcli.diagnose.heldout.held_out_score`).

    Attributes
    ----------
    kind : str
        ``"waveform"`` (a deterministic model), ``"failed"`` (its limit cycle was not found: every
        score None) or ``"scatter"`` (the delay jitter, judged on the period scatter alone).
    nrmse : float or None
        Waveform NRMSE beyond the recording's own cycle-to-cycle scatter (for the jitter: the relative
        error of the predicted period scatter).
    nrmse_raw, nrmse_timed, scatter_nrmse : float or None
        The NRMSE with that scatter kept; with the model's own period too; the scatter's share.
    nrmse_per_test, nrmse_raw_per_test : list of float or None
        ``nrmse`` and ``nrmse_raw`` per test.
    feature_rms_z, feature_chi2, feature_max_abs_z : float or None
        The held-out features' RMS z, chi^2 and largest |z| (z = difference / standard error).
    metric : str or None
        What ``nrmse`` measures, for the jitter.
    cycles : int or None
        Held-out cycles scored.
    """

    kind: str
    nrmse: float | None = None
    nrmse_raw: float | None = None
    nrmse_timed: float | None = None
    scatter_nrmse: float | None = None
    nrmse_per_test: list[Any] | None = None
    nrmse_raw_per_test: list[Any] | None = None
    feature_rms_z: float | None = None
    feature_chi2: float | None = None
    feature_max_abs_z: float | None = None
    metric: str | None = None
    cycles: int | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON item (the keys of its kind)."""
        return {k: getattr(self, k) for k in _HELD_OUT_KEYS[self.kind]}

    def summary(self) -> dict[str, Any]:
        """The figures an effect's ``fit_before`` / ``fit_after`` report."""
        keys = _HELD_OUT_KEYS[self.kind]
        return {k: getattr(self, k) for k in _SUMMARY_KEYS if k in keys}

    @classmethod
    def from_dict(cls, data: Any) -> HeldOut:
        """The score of a :meth:`to_dict` (or :meth:`summary`) item."""
        data = _dict(data, "held_out")
        kind = "scatter" if "metric" in data else "waveform" if "nrmse_raw" in data else "failed"
        return cls(kind=kind, **{k: data.get(k) for k in _HELD_OUT_KEYS[kind]})


def _held_out_or_none(value: Any) -> HeldOut | None:
    return None if value is None else HeldOut.from_dict(value)


#: the keys of a candidate row's JSON, per layout (in this order)
_CANDIDATE_KEYS = {
    "fitted": ("name", "parameter", "value", "std", "unit", "chi2", "bic", "delta_bic", "held_out_before",
               "held_out_after", "fit_params", "probe_delta_chi2", "significant"),
    "not_rejected": ("name", "parameter", "unit", "delta_bic", "status", "significant"),
    "explained": ("name", "parameter", "unit", "delta_bic", "probe_delta_chi2", "status", "significant"),
    "failed": ("name", "delta_bic", "status", "compared_with", "significant"),
    "jitter_below": ("name", "delta_bic", "parameter", "unit", "status", "compared_with", "significant"),
    "jitter": ("min_value", "name", "parameter", "value", "value_fit_cycles", "std", "unit", "chi2", "bic",
               "delta_bic", "held_out_before", "held_out_after", "fit_params", "calibration_runs", "period_scatter",
               "compared_with", "significant"),
}


def _item(record: Any, keys: tuple[str, ...]) -> dict[str, Any]:
    """A record's JSON item: its ``keys`` in order, held-out scores as dicts, an absent ``compared_with`` left out
    (the jitter's row has one when it was judged against the effects found)."""
    out = {}
    for k in keys:
        v = getattr(record, k)
        if k == "compared_with" and v is None:
            continue
        out[k] = v.to_dict() if isinstance(v, HeldOut) else v
    return out


@dataclass(frozen=True)
class CandidateFit:
    """One candidate effect fitted alone against the linear model, or why it was not.

    Attributes
    ----------
    name : str
        The candidate (:data:`mrftcli.diagnose.physics.BY_NAME`).
    layout : str
        Which JSON keys the row has (a key of ``_CANDIDATE_KEYS``): ``"fitted"``; not fitted because
        ``"not_rejected"`` (the linear model explains the cycles), ``"explained"`` (another candidate
        does) or ``"failed"``; the jitter's ``"jitter"`` or ``"jitter_below"`` (not fitted: the scatter
        is within what noise explains).
    parameter, unit : str or None
        The effect's parameter and its unit.
    value, std : float or None
        Its fitted value and standard error.
    chi2, bic, delta_bic : float or None
        The fit's chi^2 and BIC, and BIC(linear) - BIC(this); None when not fitted.
    held_out_before, held_out_after : HeldOut or None
        The held-out scores of the linear model and of the model with the effect.
    fit_params : dict or None
        The plant's parameters fitted with it.
    probe_delta_chi2 : float or None
        The chi^2 its probe gained (the fitting order).
    status : str or None
        Why it was not fitted.
    significant : bool
        It passes the evidence and held-out rules (:func:`mrftcli.diagnose.heldout.significant`).
    min_value, value_fit_cycles, calibration_runs, period_scatter, compared_with
        The jitter's: half a tick [s] (below it the jitter is not told from the tick quantisation), the
        value fitted on the fitting cycles alone, the calibration runs, the recorded / noise-only /
        predicted period scatter per test [s], the model it was judged against (None: the linear one).
    """

    name: str
    layout: str = "fitted"
    parameter: str | None = None
    unit: str | None = None
    value: float | None = None
    std: float | None = None
    chi2: float | None = None
    bic: float | None = None
    delta_bic: float | None = None
    held_out_before: HeldOut | None = None
    held_out_after: HeldOut | None = None
    fit_params: dict[str, Any] | None = None
    probe_delta_chi2: float | None = None
    status: str | None = None
    significant: bool = False
    min_value: float | None = None
    value_fit_cycles: float | None = None
    calibration_runs: int | None = None
    period_scatter: dict[str, Any] | None = None
    compared_with: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON item (``candidates`` of the result)."""
        return _item(self, _CANDIDATE_KEYS[self.layout])

    @classmethod
    def from_dict(cls, data: Any) -> CandidateFit:
        """The row of a :meth:`to_dict` item."""
        data = _dict(data, "candidates")
        matches = [lay for lay, keys in _CANDIDATE_KEYS.items()
                   if set(data) - {"compared_with"} == set(keys) - {"compared_with"}]
        # a row that is not fitted has the same keys whether it is the jitter's or another candidate's
        jitter = data.get("name") == "delay_jitter"
        layout = next((lay for lay in matches if lay.startswith("jitter") == jitter), matches[0] if matches else None)
        if layout is None:
            raise InputError(f"a diagnosis candidate has unknown keys {sorted(data)}")
        fields = {k: data.get(k) for k in _CANDIDATE_KEYS[layout]}
        for k in ("held_out_before", "held_out_after"):
            if k in fields:
                fields[k] = _held_out_or_none(fields[k])
        return cls(layout=layout, **fields)


#: the keys of a pair row's JSON, per layout (in this order)
_PAIR_KEYS = {
    "fitted": ("name", "with_", "parameter", "values", "stds", "unit", "chi2", "bic", "delta_bic", "held_out_before",
               "held_out_after", "fit_params", "significant"),
    "probed": ("name", "with_", "parameter", "unit", "values", "delta_bic", "probe_delta_chi2", "significant",
               "status"),
}


@dataclass(frozen=True)
class PairFit:
    """A second effect (``name``) fitted together with a first (``with_``: ``with`` in the JSON),
    scored against the first alone.

    Attributes
    ----------
    name, with_ : str
        The effect added and the effect it is paired with.
    layout : str
        ``"fitted"``, or ``"probed"`` (not fitted: its probe gained less than the minimum).
    parameter, unit : str
        The added effect's parameter and its unit.
    values, stds : dict
        Both effects' values and standard errors from the joint fit (empty when probed).
    chi2, bic, delta_bic : float or None
        The joint fit's chi^2 and BIC, and BIC(first alone) - BIC(pair).
    held_out_before, held_out_after : HeldOut or None
        The held-out scores of the first alone and of the pair.
    fit_params : dict or None
        The plant's parameters fitted with both.
    probe_delta_chi2 : float or None
        The probe's chi^2 gain (probed rows).
    significant : bool
        It passes the evidence and held-out rules against the first alone.
    status : str or None
        Why it was not fitted.
    """

    name: str
    with_: str
    layout: str = "fitted"
    parameter: str | None = None
    unit: str | None = None
    values: dict[str, Any] = field(default_factory=dict)
    stds: dict[str, Any] = field(default_factory=dict)
    chi2: float | None = None
    bic: float | None = None
    delta_bic: float | None = None
    held_out_before: HeldOut | None = None
    held_out_after: HeldOut | None = None
    fit_params: dict[str, Any] | None = None
    probe_delta_chi2: float | None = None
    significant: bool = False
    status: str | None = None

    @property
    def value(self) -> float | None:
        """The added effect's value from the joint fit."""
        return self.values.get(self.name)

    @property
    def std(self) -> float | None:
        """Its standard error."""
        return self.stds.get(self.name)

    def to_dict(self) -> dict[str, Any]:
        """The JSON item (``second_effect_candidates`` of the result)."""
        return {("with" if k == "with_" else k): v for k, v in _item(self, _PAIR_KEYS[self.layout]).items()}

    @classmethod
    def from_dict(cls, data: Any) -> PairFit:
        """The row of a :meth:`to_dict` item."""
        data = _dict(data, "second_effect_candidates")
        layout = "probed" if "status" in data else "fitted"
        keys = {"with" if k == "with_" else k for k in _PAIR_KEYS[layout]}
        if set(data) != keys:
            raise InputError(f"a diagnosis pair has unknown keys {sorted(data)}")
        fields = {k: data["with" if k == "with_" else k] for k in _PAIR_KEYS[layout]}
        for k in ("held_out_before", "held_out_after"):
            if k in fields:
                fields[k] = _held_out_or_none(fields[k])
        return cls(layout=layout, **fields)


@dataclass(frozen=True)
class Evidence:
    """Why an effect is reported.

    Attributes
    ----------
    delta_bic, bic : float
        BIC(the model it is compared with) - BIC(with it), and its BIC.
    n_features : int
        Features in the BIC.
    threshold : float
        The delta BIC an effect needs (:data:`mrftcli.diagnose.heldout.BIC_THRESHOLD`).
    compared_with : str
        The model it beats (``"linear"`` or ``"linear + <first effect>"``).
    bic_base : float
        That model's BIC.
    indistinguishable_from : list of str or None
        Models within the tie margin that pass the same rules (None: none).
    """

    delta_bic: float
    bic: float
    n_features: int
    threshold: float
    compared_with: str
    bic_base: float
    indistinguishable_from: list[str] | None = None

    def to_dict(self) -> dict[str, Any]:
        out = {"delta_bic": self.delta_bic, "bic": self.bic, "n_features": self.n_features,
               "threshold": self.threshold, "compared_with": self.compared_with, "bic_base": self.bic_base}
        if self.indistinguishable_from is not None:
            out["indistinguishable_from"] = self.indistinguishable_from
        return out

    @classmethod
    def from_dict(cls, data: Any) -> Evidence:
        data = _dict(data, "evidence")
        ties = data.get("indistinguishable_from")
        return cls(delta_bic=float(data["delta_bic"]), bic=float(data["bic"]), n_features=int(data["n_features"]),
                   threshold=float(data["threshold"]), compared_with=str(data["compared_with"]),
                   bic_base=float(data["bic_base"]), indistinguishable_from=None if ties is None else list(ties))


#: the keys of a located disagreement's JSON, per kind (in this order; the optional ones only when set)
_DISAGREEMENT_KEYS = {
    "feature": ("kind", "test", "beta", "h", "t_start", "t_end", "feature", "what", "recorded", "model", "difference",
                "z", "relative", "unit", "half_periods_recorded", "half_periods_model", "t_start_rel", "t_end_rel"),
    "harmonic": ("kind", "test", "beta", "h", "t_start", "t_end", "harmonic", "what", "relative_error", "all",
                 "t_start_rel", "t_end_rel"),
    "segment": ("kind", "test", "beta", "h", "t_start", "t_end", "cycles", "nrmse", "typical_nrmse", "worse_half",
                "half_nrmse", "t_start_rel", "t_end_rel"),
}
_DISAGREEMENT_OPTIONAL = frozenset({"relative", "unit", "half_periods_recorded", "half_periods_model", "t_start_rel",
                                    "t_end_rel"})


@dataclass(frozen=True)
class Disagreement:
    """Where a model and the recording disagree (:func:`mrftcli.diagnose.locate.locate`).

    Attributes
    ----------
    kind : str
        ``"feature"`` (a feature beyond 3 standard errors), ``"harmonic"`` (G(j k Omega) off by more
        than 5 %) or ``"segment"`` (a run of cycles whose waveform error stands out).
    test : int
        The test's index (from 0).
    beta, h : float
        Its mean effective beta and relay height [command units].
    t_start, t_end : float
        Where [s] (log times); ``t_start_rel``, ``t_end_rel`` the same from the log start.
    feature, what : str or None
        The feature (:data:`mrftcli.diagnose.features.FEATURE_NAMES`, or ``period_scatter``) and what
        it is in words (a harmonic's: which G(j k Omega)).
    recorded, model, difference, z : float or None
        A feature's recorded and model values (amplitude and period in output units and s), their
        difference and z (difference / standard error).
    relative, unit : float or str or None
        The relative difference (amplitude, period) and the values' unit, where they have one.
    half_periods_recorded, half_periods_model : dict or None
        The balance's high and low half periods [s].
    harmonic, relative_error, all : int, float, dict or None
        A harmonic's order k, its relative error, and every odd harmonic's.
    cycles, nrmse, typical_nrmse, worse_half, half_nrmse
        A segment's cycles (from 0), waveform NRMSE, the log's typical cycle NRMSE, the worse half
        (``"high (+h)"`` or ``"low (-h)"``) and each half's NRMSE.
    """

    kind: str
    test: int
    beta: float
    h: float
    t_start: float
    t_end: float
    feature: str | None = None
    what: str | None = None
    recorded: float | None = None
    model: float | None = None
    difference: float | None = None
    z: float | None = None
    relative: float | None = None
    unit: str | None = None
    half_periods_recorded: dict[str, float] | None = None
    half_periods_model: dict[str, float] | None = None
    harmonic: int | None = None
    relative_error: float | None = None
    all: dict[str, float] | None = None
    cycles: list[int] | None = None
    nrmse: float | None = None
    typical_nrmse: float | None = None
    worse_half: str | None = None
    half_nrmse: dict[str, float] | None = None
    t_start_rel: float | None = None
    t_end_rel: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON item (``located`` of the result)."""
        out = {}
        for k in _DISAGREEMENT_KEYS[self.kind]:
            v = getattr(self, k)
            if v is None and k in _DISAGREEMENT_OPTIONAL:
                continue
            out[k] = v
        return out

    @classmethod
    def from_dict(cls, data: Any) -> Disagreement:
        """The disagreement of a :meth:`to_dict` item."""
        data = _dict(data, "located")
        keys = _DISAGREEMENT_KEYS.get(str(data.get("kind")))
        if keys is None or not set(data) <= set(keys):
            raise InputError(f"a located disagreement has unknown kind or keys {sorted(data)}")
        return cls(**{k: data[k] for k in keys if k in data})


@dataclass(frozen=True)
class TestRow:
    """One test as the diagnosis used it (``tests`` of the result; the JSON keys are the fields, in order).

    Attributes
    ----------
    index : int
        The test's index (from 0).
    beta_nominal : float or None
        The beta the log records (None when it does not).
    beta_effective_up, beta_effective_down : float
        The switching levels the relay achieved (-h -> +h, +h -> -h).
    h, bias : float
        Relay height and hover command [command units].
    rate_hz : float
        Controller rate [Hz].
    t_start, t_end, t_start_rel, t_end_rel : float
        The test's span [s]: log times, and from the log start.
    cycles, stable_cycles_found, cycles_fit, cycles_held_out : int
        Stable cycles used, found by the segmenter (None when unknown), fitted, held out.
    period_scatter, period_scatter_noise_model : float or None
        The recorded cycle-to-cycle period std [s] (None under 3 cycles), and what noise alone explains.
    """

    __test__ = False  # (not a pytest test class)

    index: int
    beta_nominal: float | None
    beta_effective_up: float
    beta_effective_down: float
    h: float
    bias: float
    rate_hz: float
    t_start: float
    t_end: float
    t_start_rel: float
    t_end_rel: float
    cycles: int
    stable_cycles_found: int | None
    cycles_fit: int
    cycles_held_out: int
    period_scatter: float | None
    period_scatter_noise_model: float | None

    def to_dict(self) -> dict[str, Any]:
        """The JSON item."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, data: Any) -> TestRow:
        """The row of a :meth:`to_dict` item."""
        data = _dict(data, "tests")
        names = [f.name for f in fields(cls)]
        if set(data) != set(names):
            raise InputError(f"a diagnosis test row has keys {sorted(data)}, not {names}")
        return cls(**data)


@dataclass(frozen=True)
class Unexplained:
    """The mismatch no candidate (or pair) explains (``unexplained`` of the result; JSON keys = fields).

    Attributes
    ----------
    after : str
        The model it remains after (``"linear"`` or ``"linear + <effects>"``).
    what : str
        In words.
    held_out_feature_chi2 : float or None
        That model's held-out feature chi^2, over ``held_out_features`` features: ``p_value``.
    held_out_features : int
        Held-out features.
    p_value : float
        The chi^2 p-value.
    held_out_nrmse_raw : float or None
        Its held-out waveform NRMSE (the recording's scatter kept).
    tests : list of int
        The tests that disagree (from 1).
    largest : dict or None
        The largest disagreement: test (from 1), feature, what, z, recorded, model.
    segments : list of dict
        Runs of cycles that stand out: test, times from the log start, cycles (from 1), nrmse, worse half.
    harmonics : list of dict
        Harmonics off by more than 5 %: test, harmonic, relative_error.
    best_candidate : dict or None
        The candidate with the largest delta BIC (name, delta_bic, significant).
    worse_half : str or None
        The half-cycle most segments are worse in.
    """

    after: str
    what: str
    held_out_feature_chi2: float | None
    held_out_features: int
    p_value: float
    held_out_nrmse_raw: float | None
    tests: list[int]
    largest: dict[str, Any] | None
    segments: list[dict[str, Any]]
    harmonics: list[dict[str, Any]]
    best_candidate: dict[str, Any] | None
    worse_half: str | None

    def to_dict(self) -> dict[str, Any]:
        """The JSON item."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, data: Any) -> Unexplained:
        """The record of a :meth:`to_dict` item."""
        data = _dict(data, "unexplained")
        names = [f.name for f in fields(cls)]
        if set(data) != set(names):
            raise InputError(f"the diagnosis' unexplained has keys {sorted(data)}, not {names}")
        return cls(**data)


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
    candidates : list of CandidateFit
        Every candidate's evidence and held-out scores (including the rejected ones).
    second_effect_candidates : list of PairFit
        When an effect was found: every other candidate fitted together with it (``with``), with its
        evidence and held-out scores against that effect's model (a second effect is reported when it
        passes the same rules). When the first effect already explains the held-out cycles, a
        candidate whose probe (``probe_delta_chi2``) is too small is listed with ``delta_bic`` None
        and a ``status``.
    located : list of Disagreement
        Where the base model disagrees with the recording, largest first.
    identification : dict
        The base (linear) fit and, per found effect, the refit that accounts for it; the analysis'
        own identification when one was given.
    tests : list of TestRow
        Per test: beta (nominal, effective up/down), h, bias, cycles used, times.
    noise_std : float
        Sensor noise estimated from the residual of the cycle projections [output units].
    summary : str
        One sentence.
    unexplained : Unexplained or None
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
    candidates: list[CandidateFit]
    located: list[Disagreement]
    identification: dict[str, Any]
    tests: list[TestRow]
    noise_std: float
    summary: str
    warnings: list[str] = field(default_factory=list)
    second_effect_candidates: list[PairFit] = field(default_factory=list)
    unexplained: Unexplained | None = None
    t0: float = 0.0
    figures: DiagnosisFigures | None = field(default=None, repr=False, compare=False)
    schema_version: int = SCHEMA_VERSION

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` output (and the batch record's ``diagnosis``)."""
        return {
            "path": self.path,
            "loop": self.loop,
            "Tp": self.Tp,
            "summary": self.summary,
            "effects": [e.to_dict() for e in self.effects],
            "located": [d.to_dict() for d in self.located],
            "identification": self.identification,
            "candidates": [c.to_dict() for c in self.candidates],
            "second_effect_candidates": [c.to_dict() for c in self.second_effect_candidates],
            "unexplained": None if self.unexplained is None else self.unexplained.to_dict(),
            "t0": self.t0,
            "tests": [t.to_dict() for t in self.tests],
            "noise_std": self.noise_std,
            "nrmse_definition": NRMSE_DEFINITION,
            "warnings": self.warnings,
        }

    def to_json(self) -> dict[str, Any]:
        """:meth:`to_dict` with the ``schema_version`` (what :meth:`from_json` reads)."""
        return {"schema_version": self.schema_version, **self.to_dict()}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> DiagnosisResult:
        """The result of a :meth:`to_json` dict (without its figures).

        Raises
        ------
        InputError
            Not a diagnosis of this schema version, or a key missing or of the wrong kind.
        """
        check_schema_version(data, "diagnosis", SCHEMA_VERSION, fix="rerun mrft-ident diagnose")
        try:
            unexplained = data["unexplained"]
            return cls(
                path=str(data["path"]), loop=str(data["loop"]), Tp=float(data["Tp"]),
                effects=[EffectFinding.from_dict(e) for e in _list(data["effects"], "effects")],
                candidates=[CandidateFit.from_dict(c) for c in _list(data["candidates"], "candidates")],
                located=[Disagreement.from_dict(d) for d in _list(data["located"], "located")],
                identification=_dict(data["identification"], "identification"),
                tests=[TestRow.from_dict(t) for t in _list(data["tests"], "tests")], noise_std=float(data["noise_std"]),
                summary=str(data["summary"]), warnings=[str(w) for w in _list(data["warnings"], "warnings")],
                second_effect_candidates=[PairFit.from_dict(c) for c in _list(data["second_effect_candidates"],
                                                                               "second_effect_candidates")],
                unexplained=None if unexplained is None else Unexplained.from_dict(unexplained),
                t0=float(data["t0"]),
            )
        except KeyError as err:
            raise InputError(f"the diagnosis has no {err.args[0]!r}; rerun mrft-ident diagnose") from None
        except (TypeError, ValueError) as err:
            raise InputError(f"the diagnosis JSON is malformed ({err})".replace("\n", " ")) from None
