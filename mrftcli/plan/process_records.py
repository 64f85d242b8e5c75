"""The records of ``plan --model NAME``: a candidate next relay test and the ranked plan (versioned JSON).

Units: frequencies in Hz, amplitudes in output units, phases in degrees, each parameter's standard
deviation in its own unit (the model's ``unit``: s for times).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

from ..errors import InputError
from ..jsonable import check_schema_version
from ..mrft.identify_lti import LtiIdentification
from ..mrft.relays import RelayLaw

__all__ = ["ProcessCandidate", "ProcessPlan", "PROCESS_PLAN_SCHEMA_VERSION"]

#: version of :meth:`ProcessPlan.to_json`
PROCESS_PLAN_SCHEMA_VERSION = 1


def _finite(x: float) -> float | None:
    """JSON has no infinity: an undetermined parameter's std is null."""
    return x if math.isfinite(x) else None


def _stds(data: Any, what: str) -> dict[str, float]:
    """{name: std} from JSON (null: not determined, infinity)."""
    if not isinstance(data, Mapping):
        raise InputError(f"process plan JSON: {what} must be an object of parameter: std")
    return {str(k): math.inf if v is None else float(v) for k, v in data.items()}


@dataclass(frozen=True)
class ProcessCandidate:
    """One relay test the user could run next, predicted with the current model.

    Attributes
    ----------
    relay : RelayLaw
        The relay (kind, levels, beta or eps [output units]).
    frequency_hz : float
        Predicted limit-cycle frequency [Hz] (exact LPRS, sampled at the controller rate).
    amplitude : float
        Predicted output amplitude [output units].
    gain : float
        |G(j Omega)| at that frequency [output units per command unit]: the response point it yields.
    phase_deg : float
        arg G(j Omega) [deg].
    std_after : mapping of str to float
        Each unknown parameter's standard deviation [its unit] after this test is added to the
        recorded ones (Fisher / Gauss-Newton update); ``inf``: still not determined.
    undetermined_after : tuple of str
        The parameters still not determined after it.
    within_limit : bool
        False when its amplitude exceeds the user's ``--max-amplitude`` (never recommended then).
    """

    relay: RelayLaw
    frequency_hz: float
    amplitude: float
    gain: float
    phase_deg: float
    std_after: Mapping[str, float] = field(hash=False)
    undetermined_after: tuple[str, ...] = ()
    within_limit: bool = True

    def to_json(self) -> dict[str, Any]:
        return {"relay": self.relay.to_json(), "frequency_hz": self.frequency_hz, "amplitude": self.amplitude,
                "gain": self.gain, "phase_deg": self.phase_deg,
                "std_after": {k: _finite(v) for k, v in self.std_after.items()},
                "undetermined_after": list(self.undetermined_after), "within_limit": self.within_limit}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ProcessCandidate:
        try:
            return cls(RelayLaw.from_json(data["relay"]), float(data["frequency_hz"]), float(data["amplitude"]),
                       float(data["gain"]), float(data["phase_deg"]), _stds(data["std_after"], "std_after"),
                       tuple(str(n) for n in data.get("undetermined_after", [])), bool(data.get("within_limit", True)))
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise InputError(f"process plan JSON: bad candidate ({err})") from None


@dataclass(frozen=True)
class ProcessPlan:
    """The outcome of :func:`mrftcli.plan.process.plan_process` (``plan LOG --model NAME``).

    Attributes
    ----------
    identification : LtiIdentification
        The current model from the recorded tests (as ``analyze --model`` identifies it).
    rate_hz : float
        The controller rate the candidates are predicted at [Hz].
    std_now : mapping of str to float
        Each unknown parameter's standard deviation from the recorded tests [its unit] (``inf``: not
        determined), on the same information the candidates add to.
    undetermined : tuple of str
        The parameters the recorded tests do not pin down.
    candidates : tuple of ProcessCandidate
        Ranked, the recommended one first.
    why : str
        One sentence: why the first candidate is recommended.
    assumptions : tuple of str
        What the forecast assumes (cycles, levels, noise): stated in the output's first lines.
    notes : tuple of str
        E.g. candidate relays with no limit cycle on this model.
    """

    identification: LtiIdentification
    rate_hz: float
    std_now: Mapping[str, float] = field(hash=False)
    undetermined: tuple[str, ...]
    candidates: tuple[ProcessCandidate, ...]
    why: str
    assumptions: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def recommended(self) -> ProcessCandidate:
        """The candidate recommended (the first)."""
        return self.candidates[0]

    def to_json(self) -> dict[str, Any]:
        """``schema_version``, ``kind "process"``, the model, the ranked candidates (recommended first)."""
        ident = self.identification
        return {"schema_version": PROCESS_PLAN_SCHEMA_VERSION, "kind": "process", "model": ident.model.family,
                "parameters": {e.name: e.to_json() for e in ident.estimates}, "identification": ident.to_json(),
                "rate_hz": self.rate_hz, "std_now": {k: _finite(v) for k, v in self.std_now.items()},
                "undetermined": list(self.undetermined), "candidates": [c.to_json() for c in self.candidates],
                "recommended": 0, "why": self.why, "assumptions": list(self.assumptions), "notes": list(self.notes)}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ProcessPlan:
        """The record of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input."""
        data = check_schema_version(data, "process plan JSON", PROCESS_PLAN_SCHEMA_VERSION)
        try:
            candidates = tuple(ProcessCandidate.from_json(c) for c in data["candidates"])
            if not candidates:
                raise InputError("process plan JSON: no candidate")
            return cls(LtiIdentification.from_json(data["identification"]), float(data["rate_hz"]),
                       _stds(data["std_now"], "std_now"), tuple(str(n) for n in data.get("undetermined", [])),
                       candidates, str(data["why"]), tuple(str(a) for a in data.get("assumptions", [])),
                       tuple(str(n) for n in data.get("notes", [])))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"process plan JSON: bad or missing field ({err})") from None
