"""The row records of a diagnosis: held-out scores, candidate and pair rows, evidence, disagreements, tests.

Each is a frozen dataclass whose ``to_dict`` is its JSON item inside
:meth:`mrftcli.diagnose.records.DiagnosisResult.to_json` (which carries the ``schema_version``) and whose
``from_dict`` reads it back, raising :class:`~mrftcli.errors.InputError` with a one-line message. Two
shapes are shared: a row whose item is the keys of its layout (:class:`_Row`; one layout: all its
fields in order) and the held-out scores inside them.
"""

from __future__ import annotations

import math

from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

from ..errors import InputError

__all__ = ["expect_object", "expect_list", "HeldOut", "CandidateFit", "PairFit", "Evidence", "Disagreement", "TestRow", "Unexplained"]


def expect_object(value: Any, key: str) -> dict[str, Any]:
    """``value`` when it is a JSON object, else an :class:`InputError` naming the diagnosis' ``key``."""
    if not isinstance(value, dict):
        raise InputError(f"the diagnosis' {key!r} must be a JSON object, got {type(value).__name__}")
    return value


def expect_list(value: Any, key: str) -> list[Any]:
    """``value`` when it is a JSON list, else an :class:`InputError` naming the diagnosis' ``key``."""
    if not isinstance(value, list):
        raise InputError(f"the diagnosis' {key!r} must be a JSON list, got {type(value).__name__}")
    return value


class _Row:
    """A row whose JSON item is the keys of its layout, in order: ``_LAYOUTS[<the _BY field>]`` (None:
    every field), the ``_OPTIONAL`` fields only when set, held-out scores as dicts, fields spelt
    otherwise in the JSON in ``_RENAME`` (``with_`` -> ``with``); ``_KEY`` names it in messages."""

    _KEY: ClassVar[str]
    _LAYOUTS: ClassVar[dict[str, tuple[str, ...]] | None] = None
    _BY: ClassVar[str] = "layout"
    _OPTIONAL: ClassVar[frozenset[str]] = frozenset()
    _RENAME: ClassVar[dict[str, str]] = {}

    @classmethod
    def _keys(cls, layout: str | None) -> tuple[str, ...] | None:
        if cls._LAYOUTS is None:
            return tuple(f.name for f in fields(cls))  # type: ignore[arg-type]  # a dataclass mixin
        return cls._LAYOUTS.get(str(layout))

    @classmethod
    def _layout_of(cls, data: dict[str, Any]) -> str | None:
        """The layout of a JSON item (None: the class has one)."""
        return None

    def to_dict(self) -> dict[str, Any]:
        """The JSON item."""
        layout = getattr(self, self._BY, None)
        keys = self._keys(layout)
        if keys is None:  # a row built with a kind no layout has: a defect, never an empty item
            raise ValueError(f"the diagnosis' {self._KEY} row has unknown {self._BY} {layout!r}")
        out = {}
        for k in keys:
            v = getattr(self, k)
            if not (v is None and k in self._OPTIONAL):
                out[self._RENAME.get(k, k)] = v.to_dict() if isinstance(v, HeldOut) else v
        return out

    @classmethod
    def from_dict(cls, data: Any) -> Any:
        """The row of a :meth:`to_dict` item (the keys of one layout; held-out scores read back)."""
        data = expect_object(data, cls._KEY)
        layout = cls._layout_of(data)
        spelt = {cls._RENAME.get(k, k): k for k in cls._keys(layout) or ()}
        required = {s for s, k in spelt.items() if k not in cls._OPTIONAL}
        if not spelt or not required <= set(data) <= set(spelt):
            raise InputError(f"the diagnosis' {cls._KEY} item has unknown kind or keys {sorted(data)}")
        values = {spelt[s]: v for s, v in data.items()}
        for k in ("held_out_before", "held_out_after"):
            if values.get(k) is not None:
                values[k] = HeldOut.from_dict(values[k])
        if cls._LAYOUTS is not None and cls._BY not in values:
            values[cls._BY] = layout
        return cls(**values)


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

    def worse_beyond_chance(self, before: HeldOut) -> bool:
        """True when this score's ``nrmse`` exceeds ``before``'s (the same cycles, another model) by more
        than the recording's cycle-to-cycle scatter moves it (issue 39).

        ``nrmse^2`` is the raw error's square less the scatter's share (both over the cycles' variance);
        the share is the same for both models, so the difference of two ``nrmse^2`` is that of their raw
        errors: the models' own errors plus twice the cross term of the recorded cycles' scatter with
        the difference of the two model cycles. That cross term's standard deviation is at most
        ``scatter_nrmse (a + b) / sqrt(cycles)`` (the two cycles differ by at most the sum of their
        errors ``a + b``), and a rise of ``nrmse^2`` within twice that is chance: a RotorPy sensor lag
        (delta BIC 224, held-out feature chi^2 338 -> 55) was dropped for 0.0302 -> 0.0322 against a
        scatter share of 0.082 on 15 cycles. Without the scatter's share or the cycle count any rise counts.
        """
        b, a = before.nrmse, self.nrmse
        if b is None or a is None or a <= b:
            return False
        if self.scatter_nrmse is None or not self.cycles:
            return True
        return a * a - b * b > 2.0 * self.scatter_nrmse * (a + b) / math.sqrt(self.cycles)

    def summary(self) -> dict[str, Any]:
        """The figures an effect's ``fit_before`` / ``fit_after`` report."""
        keys = _HELD_OUT_KEYS[self.kind]
        return {k: getattr(self, k) for k in _SUMMARY_KEYS if k in keys}

    @classmethod
    def from_dict(cls, data: Any) -> HeldOut:
        """The score of a :meth:`to_dict` (or :meth:`summary`) item."""
        data = expect_object(data, "held_out")
        kind = "scatter" if "metric" in data else "waveform" if "nrmse_raw" in data else "failed"
        return cls(kind=kind, **{k: data.get(k) for k in _HELD_OUT_KEYS[kind]})


class _Scored:
    """A row scored held out (``held_out_before``, ``held_out_after``: :class:`HeldOut` or None)."""

    @property
    def held_out_errors(self) -> tuple[float | None, float | None]:
        """The held-out error without and with the effect, as recorded (the jitter's: its period-scatter
        error), what the terminal and the report show."""
        held = (getattr(self, "held_out_before"), getattr(self, "held_out_after"))
        return tuple(None if h is None else h.nrmse_raw if h.kind == "waveform" else h.nrmse for h in held)  # type: ignore[return-value]


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


@dataclass(frozen=True)
class CandidateFit(_Row, _Scored):
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

    @property
    def with_(self) -> str:
        """The first effect it is fitted on top of: none (``""``), a candidate alone."""
        return ""

    _KEY: ClassVar[str] = "candidates"
    _LAYOUTS: ClassVar[dict[str, tuple[str, ...]] | None] = _CANDIDATE_KEYS
    _OPTIONAL: ClassVar[frozenset[str]] = frozenset({"compared_with"})

    @classmethod
    def _layout_of(cls, data: dict[str, Any]) -> str | None:
        matches = [lay for lay, keys in _CANDIDATE_KEYS.items()
                   if set(data) - {"compared_with"} == set(keys) - {"compared_with"}]
        # a row that is not fitted has the same keys whether it is the jitter's or another candidate's
        jitter = data.get("name") == "delay_jitter"
        return next((lay for lay in matches if lay.startswith("jitter") == jitter), matches[0] if matches else None)


#: the keys of a pair row's JSON, per layout (in this order)
_PAIR_KEYS = {
    "fitted": ("name", "with_", "parameter", "values", "stds", "unit", "chi2", "bic", "delta_bic", "held_out_before",
               "held_out_after", "fit_params", "significant"),
    "probed": ("name", "with_", "parameter", "unit", "values", "delta_bic", "probe_delta_chi2", "significant",
               "status"),
}


@dataclass(frozen=True)
class PairFit(_Row, _Scored):
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

    _KEY: ClassVar[str] = "second_effect_candidates"
    _LAYOUTS: ClassVar[dict[str, tuple[str, ...]] | None] = _PAIR_KEYS
    _RENAME: ClassVar[dict[str, str]] = {"with_": "with"}  # ``with`` is a Python keyword

    @classmethod
    def _layout_of(cls, data: dict[str, Any]) -> str | None:
        return "probed" if "status" in data else "fitted"


@dataclass(frozen=True)
class Evidence(_Row):
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

    _KEY: ClassVar[str] = "evidence"
    _OPTIONAL: ClassVar[frozenset[str]] = frozenset({"indistinguishable_from"})


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
class Disagreement(_Row):
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

    _KEY: ClassVar[str] = "located"
    _LAYOUTS: ClassVar[dict[str, tuple[str, ...]] | None] = _DISAGREEMENT_KEYS
    _BY: ClassVar[str] = "kind"
    _OPTIONAL: ClassVar[frozenset[str]] = _DISAGREEMENT_OPTIONAL

    @classmethod
    def _layout_of(cls, data: dict[str, Any]) -> str | None:
        return str(data.get("kind"))


@dataclass(frozen=True)
class TestRow(_Row):
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
    _KEY: ClassVar[str] = "tests"

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


@dataclass(frozen=True)
class Unexplained(_Row):
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

    _KEY: ClassVar[str] = "unexplained"
