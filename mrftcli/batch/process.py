"""``batch --model NAME`` / ``--model-file FILE``: each log's loop analysed as a process plant.

The worker's loop entry holds the process analysis record
(:meth:`mrftcli.analyze.general.GeneralAnalysis.to_json`, as ``analyze --model NAME --json``) in place of
eq. (2)'s; :func:`process_columns` gives its summary row's columns: the model, the parameters with
their units as text, and per parameter its value, std and unit.
"""

from __future__ import annotations

import json
import math
from typing import Any, Mapping

from ..errors import InputError

__all__ = ["analyze_process_loop", "process_columns", "model_key", "PROCESS_COLUMNS"]

#: The columns a process row adds after SUMMARY_COLUMNS (then ``p_NAME``, ``p_NAME_std``, ``p_NAME_unit``
#: per parameter of the family, in its order).
PROCESS_COLUMNS = ["model", "parameters"]


def model_key(model: Any) -> str:
    """The model's JSON as a stable string (for the settings hash: another model is another result)."""
    return json.dumps(model.to_json(), sort_keys=True)


def analyze_process_loop(path: str, loop: str, settings: Any, model: Any) -> dict[str, Any]:
    """The process analysis of one loop of a log, as a JSON dict (raises on a bad log: the caller records it).

    Parameters
    ----------
    path : str
        The log.
    loop : str
        The loop's name (the reader's: it picks the topics when none are given).
    settings : LogSettings
        Topics, scales, layout, controller rate [Hz], fewest stable cycles.
    model : PlantModel
        The structure with its known parameters (set E) and ranges (set I).
    """
    from ..analyze import AnalyzeOptions, analyze_flight
    from ..io import ReadOptions, read_flight

    read = ReadOptions(loop=loop, command_topic=settings.command_topic, output_topic=settings.output_topic,
                       beta_topic=settings.beta_topic, setpoint_topic=settings.setpoint_topic,
                       output_scale=settings.output_scale, command_scale=settings.command_scale,
                       layout=settings.layout, controller_rate_hz=settings.controller_rate_hz,
                       any_time_scale=True)  # a process plant: any time scale
    flight = read_flight(path, read, echo_warnings=False)
    min_cycles = 3 if settings.min_cycles is None else settings.min_cycles
    result = analyze_flight(flight, model, options=AnalyzeOptions(min_stable_cycles=min_cycles))
    data: dict[str, Any] = result.to_json()
    return data


def _g(x: float, digits: int = 4) -> str:
    return f"{x:.{digits}g}" if math.isfinite(x) else "-"


def process_columns(result: Mapping[str, Any] | None) -> dict[str, Any]:
    """The summary columns of a process analysis JSON (None: a loop without a result).

    ``parameters`` reads e.g. ``"K 1.985 ± 0.084 output / command; T 0.9755 ± 0.043 s; tau 0.3265 ± 0.0015 s"``
    (``known`` for a given parameter, ``not determined`` for one the tests leave open); ``tau_mean`` and
    ``tau_std`` [s] fill eq. (2)'s columns too (the delay is ``tau`` in seconds in every family, so the
    fleet's tau outlier flags apply).
    """
    from ..analyze.general import GeneralAnalysis

    if result is None:
        return {}
    try:
        analysis = GeneralAnalysis.from_json(result)
    except InputError:
        return {}
    ident = analysis.identification
    out: dict[str, Any] = {"model": result.get("model"), "n_tests": len(analysis.tests),
                           "n_cycles": sum(t.n_stable for t in analysis.tests),
                           "betas": ";".join(t.relay.kind for t in analysis.tests)}
    if ident is None:
        return out
    text = []
    for e in ident.estimates:
        spread = "known" if e.known else (f"± {_g(e.std, 2)}" if e.determined else "not determined")
        text.append(f"{e.name} {_g(e.value)} {spread} {e.unit}")
        out[f"p_{e.name}"] = e.value
        out[f"p_{e.name}_std"] = e.std if e.determined and not e.known else math.nan
        out[f"p_{e.name}_unit"] = e.unit
    out["parameters"] = "; ".join(text)
    tau = next((e for e in ident.estimates if e.name == "tau"), None)
    if tau is not None:
        out["tau_mean"] = tau.value
        out["tau_std"] = tau.std if tau.determined and not tau.known else math.nan
    return out
