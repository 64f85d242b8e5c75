"""An MRFT test back from its JSON (:meth:`mrftcli.segment.MrftTest.to_dict`), for :meth:`AnalysisResult.from_json`.

JSON has no NaN: the writers turn it into null, and null comes back here as NaN in the fields
that are numbers (and stays None where the record allows None: ``beta_nominal``, ``setpoint``,
``controller_rate_hz``). The test's relay switch count is not in the JSON (0 here).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

from ..jsonable import json_float, json_opt_float
from ..segment import MrftTest, StabilityCriterion, ValidityCriterion
from ..segment.records import RelayCycle
from ..segment.validity import LimitCycleCheck

__all__ = ["mrft_test_from_json"]

#: Keys of a test's ``criterion`` object that are measured on the test, not settings of the criterion.
_MEASURED = ("period_median", "period_tolerance", "amplitude_median", "amplitude_tolerance")


def _cycle(d: Mapping[str, Any]) -> RelayCycle:
    kw: dict[str, Any] = {}
    for f in fields(RelayCycle):
        if f.name not in d:
            continue
        v = d[f.name]
        if f.name == "flags":
            kw[f.name] = tuple(str(x) for x in v)
        elif f.name == "stable":
            kw[f.name] = bool(v)
        else:
            kw[f.name] = json_float(v)
    return RelayCycle(**kw)


def _criterion(d: Mapping[str, Any]) -> StabilityCriterion:
    names = {f.name for f in fields(StabilityCriterion)}
    return StabilityCriterion(**{k: v for k, v in d.items() if k in names})


def _validity(d: Mapping[str, Any]) -> LimitCycleCheck:
    names = {f.name for f in fields(ValidityCriterion)}
    crit = ValidityCriterion(**{k: v for k, v in (d.get("thresholds") or {}).items() if k in names})
    return LimitCycleCheck(
        n_cycles=int(d["n_cycles"]), amplitude=json_float(d["amplitude"]), amplitude_h1=json_float(d["amplitude_h1"]),
        noise_std=json_float(d["noise_std"]), snr=json_float(d["snr"]), h1_fraction=json_float(d["h1_fraction"]),
        phase_coherence=json_float(d["phase_coherence"]), phase=json_float(d["phase"]),
        phase_expected=json_float(d["phase_expected"]), beta_effective=json_float(d["beta_effective"]),
        beta_nominal=json_opt_float(d.get("beta_nominal")), failed=tuple(str(x) for x in d.get("failed") or ()),
        reasons=tuple(str(x) for x in d.get("reasons") or ()), criterion=crit)


def mrft_test_from_json(d: Mapping[str, Any]) -> MrftTest:
    """The :class:`~mrftcli.segment.MrftTest` of one entry of ``tests`` or ``rejected_tests``.

    Raises KeyError, TypeError or ValueError on an entry that is not a test's JSON (the caller
    turns them into :class:`~mrftcli.errors.InputError`).
    """
    crit = d.get("criterion") or {}
    validity = d.get("validity")
    return MrftTest(
        index=int(d["index"]), t_start=json_float(d["t_start"]), t_end=json_float(d["t_end"]), h=json_float(d["h"]),
        bias=json_float(d["bias"]), beta_nominal=json_opt_float(d.get("beta_nominal")), beta_effective=json_float(d["beta_effective"]),
        beta_effective_std=json_float(d.get("beta_effective_std")), rate_hz=json_float(d.get("rate_hz")),
        cycles=tuple(_cycle(c) for c in d.get("per_cycle") or ()), criterion=_criterion(crit),
        period_median=json_float(crit.get(_MEASURED[0])), period_tolerance=json_float(crit.get(_MEASURED[1])),
        amplitude_median=json_float(crit.get(_MEASURED[2])), amplitude_tolerance=json_float(crit.get(_MEASURED[3])),
        loop_sign=int(d.get("loop_sign", 1)), setpoint=json_opt_float(d.get("setpoint")),
        timestamps_regularised=bool(d.get("timestamps_regularised", False)),
        notes=tuple(str(n) for n in d.get("notes") or ()),
        validity=_validity(validity) if isinstance(validity, Mapping) else None,
        controller_rate_hz=json_opt_float(d.get("controller_rate_hz")),
        switch_timing=str(d["switch_timing"]) if d.get("switch_timing") is not None else None,
    )
