"""``batch --vehicle``: one log's worker as ``mrft-ident vehicle``, its vehicle record in the batch record.

:func:`vehicle_one` runs :func:`mrftcli.vehicle.identify_vehicle` on a :class:`~mrftcli.batch.run.LogTask`
and returns the batch record (:func:`mrftcli.batch.run.analyze_one`'s layout) with the log's
:class:`~mrftcli.vehicle.VehicleResult` JSON under ``vehicle``. The record's ``loops`` give the fleet
summary its rows: an identified loop is ``ok`` with its analysis and its gains' ``tune_*`` figures; a loop
the flight gives no model for is skipped (no topics, no tests) or insufficient (one beta) with what to fly
next in its ``error``, or failed. It never raises: a log that cannot be read fails alone.
"""

from __future__ import annotations

import time
from typing import Any

from ..errors import InputError
from ..jsonable import to_jsonable
from ..tune.analysis import summary_figures
from ..mrft.model import LoopModel, soiptd_model
from ..vehicle import MissingLoop, VehicleLoop, VehicleOptions, VehicleResult, identify_vehicle
from ..vehicle.gains import TuneOptions
from .inputs import AUTO_LOOP
from .run import LogTask, caught_warnings, failed_entry, log_record
from .summary import STATUS_FAILED, STATUS_INSUFFICIENT, STATUS_NO_TESTS, STATUS_NO_TOPICS, STATUS_OK, TUNE_COLUMNS

__all__ = ["vehicle_one"]

#: The summary status of a missing loop's reason (a loop without tests is skipped only when the log
#: holds another loop's model, as ``--loop auto`` does).
_STATUS = {"no-topics": STATUS_NO_TOPICS, "no-tests": STATUS_NO_TESTS, "unusable-tests": STATUS_NO_TESTS,
           "single-beta": STATUS_INSUFFICIENT, "failed": STATUS_FAILED,
           "wrong-tp": STATUS_FAILED}


def vehicle_options(task: LogTask) -> VehicleOptions:
    """The vehicle's options from the log's settings (layout, controller rate, --min-cycles, --tune-pid)."""
    s = task.settings
    return VehicleOptions(layout=s.layout, controller_rate_hz=s.controller_rate_hz,
                          min_stable_cycles=3 if s.min_cycles is None else s.min_cycles,
                          accept_tp=s.accept_tp, tune=TuneOptions(kind=task.tune or "PD"))


def _ok_entry(entry: VehicleLoop) -> dict[str, Any]:
    g = entry.gains
    if g is None:
        tune: dict[str, Any] = {"tune_error": "not tuned (see the vehicle record's warnings)"}
    elif isinstance(g.tune.model, LoopModel):  # eq. (2): its figures as batch --tune's
        tune = summary_figures(g.tune, g.kind)
    else:  # an outer loop tuned on the cascade: its gains and nominal margins (no step figures there)
        c = g.controller
        tune = {k: None for k in TUNE_COLUMNS} | {"tune_design": g.design, "tune_kind": g.kind, "tune_Kp": c.Kp,
                                                  "tune_Ki": c.Ki, "tune_Kd": c.Kd, "tune_Tf": c.Tf,
                                                  "tune_rate_hz": c.rate_hz, "tune_pm_deg": g.phase_margin_deg}
    return {"loop": entry.loop, "status": STATUS_OK, "error": None, "error_type": None, "exit_code": 0,
            "result": entry.analysis.to_json(), "diagnosis": None, "tune": tune, "role": entry.role,
            "route": entry.route}


def _missing_entry(miss: MissingLoop, any_ok: bool) -> dict[str, Any]:
    status = _STATUS[miss.reason]
    if status == STATUS_NO_TESTS and not any_ok:
        status = STATUS_FAILED  # a log where no loop has tests keeps its failure
    return {"loop": miss.loop, "status": status, "error": f"{miss.message}; next: {miss.next_tests}",
            "error_type": f"vehicle:{miss.reason}", "exit_code": 0 if status != STATUS_FAILED else 4,
            "result": None, "diagnosis": None}


def _entries(result: VehicleResult) -> list[dict[str, Any]]:
    loops = [_ok_entry(entry) for entry in result.loops.values()]
    loops += [_missing_entry(miss, bool(result.loops)) for miss in result.missing.values()]
    return loops


def _vehicle_loops(task: LogTask) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """The record's loops and the vehicle record (None when the log failed as a whole)."""
    try:
        if task.settings.tp is None:
            raise InputError("no Tp for this log: pass --tp or set tp in a config entry matching it")
        result = identify_vehicle(task.path, soiptd_model(task.settings.tp), options=vehicle_options(task))
        return _entries(result), result.to_json()
    except Exception as err:  # noqa: BLE001 - one bad log must never stop the batch
        return [failed_entry(AUTO_LOOP, err)], None  # the log's loops are unknown: its row says 'auto' as --loop


def vehicle_one(task: LogTask) -> dict[str, Any]:
    """The batch record of one log identified as a vehicle (module docstring); never raises."""
    t0 = time.perf_counter()
    (loops, vehicle), found = caught_warnings(_vehicle_loops, task)
    for entry in loops:
        entry["python_warnings"] = found
    record = log_record(task, loops, time.perf_counter() - t0)
    record["vehicle"] = vehicle
    return to_jsonable(record)
