"""The records of a comparison: one side's estimates, the tolerances, the per-parameter changes.

:class:`Comparison` crosses the process line (``compare --json``, a CI artefact read back later), so it
carries ``schema_version`` and round-trips through :meth:`Comparison.to_json` /
:meth:`Comparison.from_json`; a malformed or newer record raises :class:`mrftcli.errors.InputError`
with a one-line message.

All values are in SI units (seconds for Td and tau, the analysis' output-per-command units for K);
renderers convert (tau in ms) for display only.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ..jsonable import check_schema_version, finite_or_none, json_opt_float
from ..mrft.parameter import ParameterEstimate
from ..errors import InputError, MrftError

__all__ = ["SCHEMA_VERSION", "PARAMETERS", "LoopEstimates", "Tolerance", "ParameterChange",
           "MissingResult", "Comparison", "EXIT_CHANGED", "EXIT_INCOMPLETE", "VERDICTS", "LoopChangedError",
           "ResultMissingError"]

#: Version of the ``compare --json`` record; bump when its layout changes.
SCHEMA_VERSION = 1

#: The loop parameters compared, in display order (Tp is an input of the analysis, not an estimate).
PARAMETERS: tuple[str, ...] = ("Td", "tau", "K")

#: Exit code when some parameter changed significantly and beyond its tolerance.
EXIT_CHANGED = 9
#: Exit code when a result is missing on one side or unusable (and nothing changed).
EXIT_INCOMPLETE = 10



class LoopChangedError(MrftError):
    """Some loop changed: a parameter's change is significant and beyond its tolerance; exit code 9."""

    exit_code = EXIT_CHANGED


class ResultMissingError(MrftError):
    """A result is missing on one side or unusable (and nothing changed); exit code 10."""

    exit_code = EXIT_INCOMPLETE


#: Per-parameter verdicts: ``changed`` fails the comparison; the others do not.
VERDICTS: tuple[str, ...] = ("changed", "significant", "unchanged", "undetermined")


@dataclass(frozen=True)
class Tolerance:
    """How far a parameter may move before the comparison fails (``--fail-on tau:+5ms``).

    Parameters
    ----------
    parameter : str
        ``Td``, ``tau`` or ``K``.
    amount : float
        The allowed change: SI units, or a fraction of the baseline value when ``relative``.
    relative : bool
        True for a percentage of the baseline.
    direction : int
        +1: only increases beyond ``amount`` fail; -1: only decreases; 0: either.
    loop : str or None
        Restricts the tolerance to one loop; None for every loop.
    text : str
        The tolerance as written (for reports).
    """

    parameter: str
    amount: float
    relative: bool = False
    direction: int = 0
    loop: str | None = None
    text: str = ""

    def limit(self, baseline: float) -> float:
        """The allowed change in SI units for a baseline value [SI units]."""
        return self.amount * abs(baseline) if self.relative else self.amount

    def exceeded_by(self, change: float, baseline: float) -> bool:
        """True when ``change`` (new - baseline) [SI units] is beyond this tolerance in its direction."""
        limit = self.limit(baseline)
        if self.direction > 0:
            return change > limit
        if self.direction < 0:
            return change < -limit
        return abs(change) > limit


@dataclass(frozen=True)
class LoopEstimates:
    """One loop of one side: its parameter estimates, or why it cannot be used.

    Parameters
    ----------
    loop : str
        The loop (``altitude``, ``roll``...).
    name : str or None
        The log name or vehicle it is matched by; None for a single analysis or a reference file,
        which match the other side by loop alone.
    source : str
        Where it was read (a file).
    parameters : Mapping[str, ParameterEstimate]
        ``Td``, ``tau``, ``K`` (those the side states); a process family's own names (``T``, ``T1``...): the
        analysis's records (a null end read as NaN or infinite: open), a reference's value and std (interval NaN).
    tp : float or None
        The propulsion time constant the analysis assumed [s].
    error : str or None
        Why this loop is unusable (a failed or insufficient analysis); None when usable.
    tolerances : tuple of Tolerance
        Tolerances that come with it (a reference file's ``tol``).
    model : str or None
        The model family the analysis identified (``soiptd``: eq. (2); ``fopdt``...); None for a
        reference file, which states values only.
    absent : bool
        The log does not hold this loop at all (a batch row skipped for want of its topics or of any
        test on it): not a result, and not a failure either.
    """

    loop: str
    name: str | None
    source: str
    parameters: Mapping[str, ParameterEstimate] = field(default_factory=dict)
    tp: float | None = None
    error: str | None = None
    tolerances: tuple[Tolerance, ...] = ()
    absent: bool = False
    model: str | None = None

    @property
    def usable(self) -> bool:
        """True when this loop has estimates to compare (neither absent nor failed)."""
        return self.error is None and not self.absent

    @property
    def key(self) -> tuple[str | None, str]:
        """(name, loop), the matching key."""
        return (self.name, self.loop)


@dataclass(frozen=True)
class ParameterChange:
    """One parameter of one matched loop: the change, its interval, the verdict.

    Parameters
    ----------
    name : str or None
        Log name or vehicle (None when matched by loop alone).
    loop, parameter : str
        Which loop and parameter.
    baseline, new : float or None
        The two point estimates [SI units].
    change : float or None
        new - baseline [SI units]; None when undetermined.
    low, high : float or None
        Interval of the change at the comparison's confidence [SI units].
    z : float or None
        change / its standard deviation on the side towards zero.
    significant : bool
        The interval excludes zero.
    tolerance : str or None
        The tolerance applied, as written; None when none applies.
    beyond_tolerance : bool
        The change is beyond that tolerance (always False without one).
    verdict : str
        ``changed`` (significant, and beyond the tolerance when one applies: fails), ``significant``
        (significant but within its tolerance, or without a tolerance while others have one),
        ``unchanged`` (not significant), or ``undetermined`` (a side cannot determine the parameter;
        never a change).
    note : str
        Why undetermined, or other context.
    unit : str
        The unit of the values above, the analyses' own (their parameter record's ``unit``: eq. (2)'s K
        ``output / (command s^2)``, a family's ``output / command``); empty when neither side states one.
    model : str or None
        The model the analyses identified (``soiptd``: eq. (2); a process family's name: ``fopdt``...); None when
        no side states one (a cascade's, a reference's). A process plant's tau is shown in s, a vehicle loop's in
        ms (:func:`mrftcli.mrft.parameter.display_scale`).
    """

    name: str | None
    loop: str
    parameter: str
    baseline: float | None
    new: float | None
    change: float | None
    low: float | None
    high: float | None
    z: float | None
    significant: bool
    tolerance: str | None
    beyond_tolerance: bool
    verdict: str
    note: str = ""
    unit: str = ""
    model: str | None = None

    @property
    def process(self) -> bool:
        """The parameter is a process plant's (a family's), not a vehicle loop's."""
        return self.model not in (None, "soiptd")

    @property
    def failed(self) -> bool:
        """True when this change fails the comparison."""
        return self.verdict == "changed"

    @property
    def relative(self) -> float | None:
        """The change as a fraction of the baseline, or None."""
        if self.change is None or not self.baseline:
            return None
        return self.change / abs(self.baseline)


@dataclass(frozen=True)
class MissingResult:
    """A loop that cannot be compared: absent on one side, or unusable there.

    ``side`` is ``baseline``, ``new`` or ``both``; ``reason`` one line.
    """

    name: str | None
    loop: str
    side: str
    reason: str


@dataclass(frozen=True)
class Comparison:
    """The comparison of two sides: every parameter change and every loop that could not be compared.

    Parameters
    ----------
    baseline, new : str
        What was compared (paths).
    confidence : float
        Confidence of the change intervals, per parameter (0.95).
    correction : str
        ``none`` (each parameter at ``confidence``) or ``bonferroni`` (per loop: each of its m
        parameters at 1 - (1 - confidence) / m).
    fail_on : tuple of str
        The ``--fail-on`` tolerances as written (empty: any significant change fails).
    changes : tuple of ParameterChange
        One per matched loop and parameter.
    missing : tuple of MissingResult
        Loops not compared.
    notes : tuple of str
        Context (a Tp that differs between the sides, a vehicle with several logs...).
    """

    baseline: str
    new: str
    confidence: float
    correction: str
    fail_on: tuple[str, ...]
    changes: tuple[ParameterChange, ...]
    missing: tuple[MissingResult, ...] = ()
    notes: tuple[str, ...] = ()
    schema_version: int = SCHEMA_VERSION

    @property
    def exit_code(self) -> int:
        """0, :data:`EXIT_CHANGED` (some change fails; takes precedence) or :data:`EXIT_INCOMPLETE`."""
        if any(c.failed for c in self.changes):
            return EXIT_CHANGED
        if self.missing:
            return EXIT_INCOMPLETE
        return 0

    def to_json(self) -> dict[str, Any]:
        """The record as plain JSON values (non-finite numbers become None)."""
        return {
            "schema_version": self.schema_version,
            "baseline": self.baseline,
            "new": self.new,
            "confidence": self.confidence,
            "correction": self.correction,
            "fail_on": list(self.fail_on),
            "exit_code": self.exit_code,
            "changes": [_change_to_json(c) for c in self.changes],
            "missing": [{"name": m.name, "loop": m.loop, "side": m.side, "reason": m.reason} for m in self.missing],
            "notes": list(self.notes),
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Comparison:
        """Read a record written by :meth:`to_json`.

        Raises
        ------
        InputError
            Not a comparison record, a schema version other than :data:`SCHEMA_VERSION`, or a
            missing or mistyped field.
        """
        data = check_schema_version(data, "compare record", SCHEMA_VERSION,
                                    fix="pass the output of 'mrft-ident compare --json' of this version")
        try:
            return cls(
                baseline=str(data["baseline"]),
                new=str(data["new"]),
                confidence=float(data["confidence"]),
                correction=str(data["correction"]),
                fail_on=tuple(str(s) for s in data["fail_on"]),
                changes=tuple(_change_from_json(c) for c in data["changes"]),
                missing=tuple(MissingResult(name=_opt_str(m["name"]), loop=str(m["loop"]), side=str(m["side"]),
                                            reason=str(m["reason"])) for m in data["missing"]),
                notes=tuple(str(n) for n in data["notes"]),
            )
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"malformed compare record: {type(err).__name__} {err}; "
                             "pass the output of 'mrft-ident compare --json'") from None


_CHANGE_FLOATS = ("baseline", "new", "change", "low", "high", "z")


def _opt_str(x: object) -> str | None:
    return None if x is None else str(x)


def _change_to_json(c: ParameterChange) -> dict[str, Any]:
    return {
        "name": c.name, "loop": c.loop, "parameter": c.parameter,
        **{k: finite_or_none(getattr(c, k)) for k in _CHANGE_FLOATS},
        "relative": finite_or_none(c.relative),
        "significant": c.significant, "tolerance": c.tolerance, "beyond_tolerance": c.beyond_tolerance,
        "verdict": c.verdict, "note": c.note, "unit": c.unit, "model": c.model,
    }


def _change_from_json(d: Mapping[str, Any]) -> ParameterChange:
    verdict = str(d["verdict"])
    if verdict not in VERDICTS:
        raise ValueError(f"unknown verdict {verdict!r}")
    floats = {k: json_opt_float(d[k]) for k in _CHANGE_FLOATS}
    return ParameterChange(name=_opt_str(d["name"]), loop=str(d["loop"]), parameter=str(d["parameter"]),
                           baseline=floats["baseline"], new=floats["new"], change=floats["change"],
                           low=floats["low"], high=floats["high"], z=floats["z"],
                           significant=bool(d["significant"]), tolerance=_opt_str(d["tolerance"]),
                           beyond_tolerance=bool(d["beyond_tolerance"]), verdict=verdict, note=str(d["note"]),
                           unit=str(d.get("unit", "")),  # absent before the unit was recorded
                           model=_opt_str(d.get("model")))  # absent before the model was recorded
