"""The vehicle record: every loop of one flight, identified and tuned, and the loops still to fly.

``mrft-ident vehicle --json`` writes :meth:`VehicleResult.to_json`; ``batch --vehicle`` stores it per
log; :meth:`VehicleResult.from_json` reads it back (docs/vehicle.md gives the layout)::

    {"schema_version": 1, "path": ..., "layout": ..., "assumptions": [...], "warnings": [...],
     "loops": {"roll": {<the loop's analyze JSON: parameters, tests, model, input, ...>,
                        "role": "inner", "route": "eq2", "route_notes": [...],
                        "gains": {"design": "robust", "kind": "PD", "generic": {Kp, Ki, Kd, Tf, rate_hz, form},
                                  "units": {...}, "tune_result": <TuneResult JSON>}},
               ...},
     "missing": {"pitch": {"reason": "no-tests", "message": ..., "next_tests": ..., "plan": <plan JSON>|null}}}

Each loop's entry *is* its analysis record (read back by :meth:`mrftcli.analyze.AnalysisResult.from_json`,
which ignores the keys the vehicle adds), so a tool that reads ``analyze --json`` reads
``loops.<name>`` as it is.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ..analyze import AnalysisResult
from ..errors import InputError
from ..io.logtypes import LOOPS, output_unit
from ..jsonable import check_schema_version
from ..plan import PlanResult
from ..tune.closed_loop import Controller
from ..tune.design import TuneResult
from ..tune.stacks import StackExport

__all__ = ["VEHICLE_SCHEMA_VERSION", "ROLES", "ROUTES", "MISSING_REASONS", "LoopGains", "VehicleLoop",
           "MissingLoop", "VehicleResult"]

#: Version of :meth:`VehicleResult.to_json`'s object; 2: its loops' records write every parameter as the one
#: record (:class:`~mrftcli.mrft.parameter.ParameterEstimate`; analysis schema 4, cascade 2); version 1 still reads
#: (its loops' older records through their own readers) and is written back as version 2
VEHICLE_SCHEMA_VERSION = 2
#: ``inner``: identified with eq. (2) at the known Tp; ``outer``: its plant holds a closed inner loop.
ROLES = ("inner", "outer")
#: The model a loop was identified with: ``eq2`` (eq. (2) at the known Tp) or ``cascade`` (the closed
#: inner loop followed by the translational dynamics, :mod:`mrftcli.mrft.cascade`).
ROUTES = ("eq2", "cascade")
#: Why a loop has no result: its topics are not in the log, it has no relay test, its tests are not
#: usable, it was flown at one beta only (Td and tau are not separable), or the analysis failed.
#: ``wrong-tp``: the recording rejects the given Tp (it fits another; ``--accept-tp`` keeps it).
MISSING_REASONS = ("no-topics", "no-tests", "unusable-tests", "single-beta", "failed", "wrong-tp")


def _str_list(data: Mapping[str, Any], key: str, what: str) -> tuple[str, ...]:
    value = data.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise InputError(f"{what}: '{key}' must be a list of strings")
    return tuple(value)


def _choice(data: Mapping[str, Any], key: str, choices: tuple[str, ...], what: str) -> str:
    value = data.get(key)
    if value not in choices:
        raise InputError(f"{what}: '{key}' must be one of {', '.join(choices)}, got {value!r}")
    return str(value)


@dataclass(frozen=True)
class LoopGains:
    """The gains recommended for one loop: one design of its tune result.

    Attributes
    ----------
    design : str
        ``robust`` (when the identification gave a posterior) or ``model-based``.
    kind : str
        ``PD`` or ``PID``.
    tune : TuneResult
        Every design with its margins (:func:`mrftcli.tune.design.tune`): eq. (2)'s, or an outer loop's
        on the exact sampled cascade.
    export : StackExport or None
        The design as the ``--export`` stack loads it (checked against its ranges).
    export_refused : str or None
        Why the stack could not take this loop (one line), when an export was asked for.
    """

    design: str
    kind: str
    tune: TuneResult
    export: StackExport | None = None
    export_refused: str | None = None

    @property
    def controller(self) -> Controller:
        """The recommended controller (gains per the loop's output unit, Tf [s], rate [Hz])."""
        return self.tune.get(self.design, self.kind).controller

    @property
    def phase_margin_deg(self) -> float:
        """The recommended design's nominal phase margin [deg]."""
        return self.tune.get(self.design, self.kind).margins.phase_margin_deg

    @property
    def delay_margin_ms(self) -> float | None:
        """The recommended design's nominal delay margin [ms] (None on a cascade: not computed there)."""
        dm = self.tune.get(self.design, self.kind).margins.delay_margin_s
        return dm * 1e3 if math.isfinite(dm) else None

    def to_json(self) -> dict[str, Any]:
        """``design``, ``kind``, ``generic`` (tune's generic export), ``units``, the margins, ``export``
        (or ``export_refused``) and ``tune_result``."""
        y = output_unit(self.tune.loop) if self.tune.loop in LOOPS else "output unit"
        return {"design": self.design, "kind": self.kind, "generic": self.controller.to_dict(),
                "units": {"Kp": f"command/{y}", "Ki": f"command/({y} s)", "Kd": f"command s/{y}", "Tf": "s",
                          "rate_hz": "Hz"},
                "phase_margin_deg": self.phase_margin_deg, "delay_margin_ms": self.delay_margin_ms,
                "export": None if self.export is None else self.export.to_json(),
                "export_refused": self.export_refused, "tune_result": self.tune.to_json()}

    @classmethod
    def from_json(cls, data: object) -> LoopGains:
        """The gains of :meth:`to_json`; InputError (one line) on a malformed object."""
        what = "vehicle gains"
        if not isinstance(data, Mapping):
            raise InputError(f"{what}: expected a JSON object")
        tune = TuneResult.from_json(data.get("tune_result"))
        design, kind = str(data.get("design")), str(data.get("kind"))
        export, refused = data.get("export"), data.get("export_refused")
        if not (refused is None or isinstance(refused, str)):
            raise InputError(f"{what}: 'export_refused' must be a string or null")
        gains = cls(design, kind, tune, None if export is None else StackExport.from_json(export), refused)
        try:
            gains.controller
        except (KeyError, InputError):
            raise InputError(f"{what}: the tune result has no {design} {kind} design") from None
        return gains


@dataclass(frozen=True)
class VehicleLoop:
    """One identified loop of the vehicle.

    Attributes
    ----------
    loop : str
        One of :data:`mrftcli.io.logtypes.LOOPS`.
    role : str
        ``inner`` or ``outer`` (:data:`ROLES`).
    route : str
        The model identified (:data:`ROUTES`).
    analysis : AnalysisResult
        Tests, parameters with their uncertainty, the model (eq. (2), or the cascade for an outer loop).
    gains : LoopGains or None
        The tuned gains; None when tuning failed (the vehicle's warnings say why).
    route_notes : tuple of str
        What the route assumed (e.g. eq. (2) for an outer loop without the inner gains in use).
    """

    loop: str
    role: str
    route: str
    analysis: AnalysisResult
    gains: LoopGains | None
    route_notes: tuple[str, ...] = ()

    @property
    def estimates(self) -> dict[str, tuple[float, float]]:
        """Td [s], tau [s] and K: (estimate, std) whatever the route."""
        est = self.analysis.parameters
        return {k: (float(est[k].value), float(est[k].std)) for k in ("Td", "tau", "K") if k in est}

    def to_json(self) -> dict[str, Any]:
        """The analysis JSON with ``role``, ``route``, ``route_notes`` and ``gains`` added."""
        return {**self.analysis.to_json(), "role": self.role, "route": self.route,
                "route_notes": list(self.route_notes),
                "gains": None if self.gains is None else self.gains.to_json()}

    @classmethod
    def from_json(cls, loop: str, data: object) -> VehicleLoop:
        """One ``loops.<name>`` entry; InputError (one line) on a malformed entry."""
        what = f"vehicle loop {loop}"
        if not isinstance(data, Mapping):
            raise InputError(f"{what}: expected a JSON object")
        gains = data.get("gains")
        try:
            analysis = AnalysisResult.from_json(data)
        except InputError as err:
            raise InputError(f"{what}: {err}") from None
        return cls(loop, _choice(data, "role", ROLES, what), _choice(data, "route", ROUTES, what), analysis,
                   None if gains is None else LoopGains.from_json(gains), _str_list(data, "route_notes", what))


@dataclass(frozen=True)
class MissingLoop:
    """A loop the flight gives no model for, and what to fly next.

    Attributes
    ----------
    loop : str
    reason : str
        One of :data:`MISSING_REASONS`.
    message : str
        One line: what was found (the analysis's own message).
    next_tests : str
        One line: which tests to fly next (with the ``mrft-ident plan`` command that designs them).
    plan : PlanResult or None
        The planned next test when the flight holds a test to plan from (a single beta).
    """

    loop: str
    reason: str
    message: str
    next_tests: str
    plan: PlanResult | None = None

    def to_json(self) -> dict[str, Any]:
        return {"reason": self.reason, "message": self.message, "next_tests": self.next_tests,
                "plan": None if self.plan is None else self.plan.to_json()}

    @classmethod
    def from_json(cls, loop: str, data: object) -> MissingLoop:
        """One ``missing.<name>`` entry; InputError (one line) on a malformed entry."""
        what = f"vehicle missing loop {loop}"
        if not isinstance(data, Mapping):
            raise InputError(f"{what}: expected a JSON object")
        plan = data.get("plan")
        message, hint = data.get("message"), data.get("next_tests")
        if not isinstance(message, str) or not isinstance(hint, str):
            raise InputError(f"{what}: 'message' and 'next_tests' must be strings")
        return cls(loop, _choice(data, "reason", MISSING_REASONS, what), message, hint,
                   None if plan is None else PlanResult.from_json(plan))


@dataclass(frozen=True)
class VehicleResult:
    """Every loop of one flight (:func:`mrftcli.vehicle.identify_vehicle`).

    Attributes
    ----------
    path : str
        The log.
    layout : str or None
        The layout the log was read with (None: not recognised).
    loops : Mapping[str, VehicleLoop]
        The identified loops, inner loops first.
    missing : Mapping[str, MissingLoop]
        The loops without a model, each with the tests to fly next.
    assumptions : tuple of str
        What a number rests on that the user did not give (each naming the option that gives it);
        shown first.
    warnings : tuple of str
        The analyses' and tunings' warnings, each prefixed with its loop.
    """

    path: str
    layout: str | None
    loops: Mapping[str, VehicleLoop]
    missing: Mapping[str, MissingLoop] = field(default_factory=dict)
    assumptions: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """The versioned JSON object (module docstring; :data:`VEHICLE_SCHEMA_VERSION`)."""
        return {"schema_version": VEHICLE_SCHEMA_VERSION, "path": self.path, "layout": self.layout,
                "assumptions": list(self.assumptions), "warnings": list(self.warnings),
                "loops": {name: entry.to_json() for name, entry in self.loops.items()},
                "missing": {name: entry.to_json() for name, entry in self.missing.items()}}

    @classmethod
    def from_json(cls, data: object) -> VehicleResult:
        """The record of :meth:`to_json`.

        Raises
        ------
        InputError
            Not a JSON object, another ``schema_version``, an unknown loop name, or a malformed entry.
        """
        what = "vehicle record"
        obj = check_schema_version(data, what, range(1, VEHICLE_SCHEMA_VERSION + 1), fix="run 'mrft-ident vehicle' again")
        loops, missing = obj.get("loops"), obj.get("missing", {})
        if not isinstance(loops, Mapping) or not isinstance(missing, Mapping):
            raise InputError(f"{what}: 'loops' and 'missing' must be objects")
        unknown = [name for name in (*loops, *missing) if name not in LOOPS]
        if unknown:
            raise InputError(f"{what}: unknown loop(s) {', '.join(map(str, unknown))} (loops are {', '.join(LOOPS)})")
        layout, path = obj.get("layout"), obj.get("path", "")
        if not (layout is None or isinstance(layout, str)) or not isinstance(path, str):
            raise InputError(f"{what}: 'path' and 'layout' must be strings")
        return cls(path, layout, {str(k): VehicleLoop.from_json(str(k), v) for k, v in loops.items()},
                   {str(k): MissingLoop.from_json(str(k), v) for k, v in missing.items()},
                   _str_list(obj, "assumptions", what), _str_list(obj, "warnings", what))
