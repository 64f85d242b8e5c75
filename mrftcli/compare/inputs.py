"""The two sides of a comparison, read from what users have at hand.

A side is one of:

* an **analysis result**: the JSON of ``mrft-ident analyze LOG --json FILE`` (one loop; matched to the
  other side by loop);
* a **batch output folder** (``mrft-ident batch --out DIR``) or one of its per-log records
  (``DIR/logs/<name>.<hash>.json``): every log and loop, matched by log name (``by="log"``) or by the
  vehicle the batch config named (``by="vehicle"``; the latest log of a vehicle when it has several);
* a **reference file** (TOML, ``.toml``) of expected parameters with optional tolerances, per loop and
  optionally per vehicle or log name (docs/compare.md):

  .. code-block:: toml

      [altitude]
      Td = { value = 2.669, tol = "25%" }       # seconds
      tau = { value = 0.0464, tol = "+5ms" }    # seconds
      K = 19.62                                  # a bare value: no tolerance of its own

      [vehicle7.altitude]                        # only for the log or vehicle named vehicle7
      tau = { value = 0.050, std = 0.0005 }      # a reference with its own uncertainty

The analysis JSON is read by :meth:`mrftcli.analyze.AnalysisResult.from_json` (in
:func:`estimates_from_analysis`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..analyze import AnalysisResult
from ..errors import InputError
from ..io import require_input
from ..jsonable import load_json_text, load_toml_text
from ..mrft.identification import spelt_unit
from ..mrft.parameter import ParameterEstimate
from .records import PARAMETERS, LoopEstimates, Tolerance
from .tolerance import parse_amount

__all__ = ["Side", "read_side", "estimates_from_analysis", "estimates_from_batch_record", "read_reference",
           "MATCH_BY"]

#: How batch logs are matched across the two sides.
MATCH_BY: tuple[str, ...] = ("log", "vehicle")

_REFERENCE_KEYS = frozenset({"value", "tol", "std"})

#: Batch statuses of a loop the log does not hold (no topics for it, no test on it): absent, not failed.
_ABSENT = frozenset({"skipped-no-topics", "skipped-no-tests"})


@dataclass(frozen=True)
class Side:
    """One side of a comparison: its loops, how it was read, and what the reader noticed.

    ``kind`` is ``analysis``, ``batch`` or ``reference``; ``loops`` the loops found (usable or not).
    """

    path: str
    kind: str
    loops: tuple[LoopEstimates, ...]
    notes: tuple[str, ...] = ()


def _number(x: object) -> float | None:
    """A JSON number as float (None, booleans and non-numbers -> None)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return None
    return float(x)


def estimates_from_analysis(result: Mapping[str, Any], *, source: str, name: str | None = None) -> LoopEstimates:
    """The loop estimates of one ``analyze --json`` object, read through :meth:`AnalysisResult.from_json`.

    Parameters
    ----------
    result : Mapping
        The analysis JSON (Td, tau, K: the parameter record, ``value``, ``std``, ``ci95_low``, ``ci95_high``
        [SI units]; ``mean`` before analysis schema 4); a process family's record gives its unknown
        parameters by name (``K``, ``T``, ``tau``...).
    source : str
        Where it was read (for messages).
    name : str or None
        The log name or vehicle it is matched by.

    Raises
    ------
    InputError
        Not an analysis result.
    """
    try:
        analysis = AnalysisResult.from_json(result)
    except InputError as err:
        raise InputError(f"{source}: {err}") from None
    if analysis.kind == "family":  # a process family: its parameters by name, the given (known) ones left out
        estimates = {n: p for n, p in analysis.parameters.items() if not p.known}
        return LoopEstimates(loop=analysis.loop, name=name, source=source, parameters=estimates,
                             model=analysis.model.family)
    estimates = _with_model_units({"Td": analysis.Td, "tau": analysis.tau, "K": analysis.K}, analysis.model)
    # a cascade's outer Td, tau, K are compared with eq. (2)'s of the same loop as before (model not checked)
    return LoopEstimates(loop=analysis.loop, name=name, source=source, parameters=estimates, tp=analysis.Tp,
                         model=None if analysis.kind == "cascade" else "soiptd")


def _with_model_units(estimates: Mapping[str, ParameterEstimate], model: Any) -> dict[str, ParameterEstimate]:
    """Each estimate with its unit as the analysis JSON spells it (:func:`mrftcli.mrft.identification.spelt_unit`:
    eq. (2)'s K, empty in memory, ``output / (command s^2)``)."""
    return {n: dataclasses.replace(e, unit=spelt_unit(n, e.unit, model)) for n, e in estimates.items()}


def _batch_name(record: Mapping[str, Any], by: str) -> str:
    path = Path(str(record.get("path", "")))
    if by == "vehicle":
        settings = record.get("settings") or {}
        return str(settings.get("vehicle") or path.parent.name)
    return path.name


def estimates_from_batch_record(record: Mapping[str, Any], *, source: str, by: str = "log") -> list[LoopEstimates]:
    """Every loop of one batch record (``DIR/logs/<name>.<hash>.json``), usable or not.

    A loop whose analysis failed or was insufficient is returned with its ``error``.

    Raises
    ------
    InputError
        Not a batch record (no ``loops``).
    """
    loops = record.get("loops")
    if not isinstance(loops, list):
        raise InputError(f"{source}: not a batch record (no 'loops'); pass a batch output folder")
    name = _batch_name(record, by)
    out = []
    for entry in loops:
        loop = str(entry.get("loop"))
        result = entry.get("result")
        if entry.get("status") != "ok" or not isinstance(result, Mapping) or "parameters" not in result:
            status = str(entry.get("status"))
            reason = entry.get("error") or f"status {status}"
            out.append(LoopEstimates(loop=loop, name=name, source=source, error=f"{status}: {reason}",
                                     absent=status in _ABSENT))
            continue
        est = estimates_from_analysis(result, source=source, name=name)
        out.append(est)
    return out


def _read_json(path: Path) -> Any:
    try:
        return load_json_text(path.read_text(), str(path))  # depth-checked: the one reader of input JSON
    except InputError as err:
        raise InputError(f"{err}; pass an analysis JSON, a batch folder or a reference .toml") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: cannot read it as JSON ({err}); pass an analysis JSON, a batch folder "
                         "or a reference .toml") from None


def _read_batch_folder(folder: Path, by: str) -> Side:
    files = sorted((folder / "logs").glob("*.json"))
    if not files:
        raise InputError(f"{folder}: not a batch output folder (no logs/*.json); pass the --out folder of "
                         "'mrft-ident batch' or an analysis JSON")
    latest: dict[tuple[str | None, str], tuple[float, LoopEstimates]] = {}
    notes = []
    for f in files:
        record = _read_json(f)
        mtime = _number(record.get("log_mtime")) if isinstance(record, Mapping) else None
        for est in estimates_from_batch_record(record, source=str(f), by=by):
            previous = latest.get(est.key)
            if previous is not None and est.absent:
                continue  # a log without this loop says nothing about the vehicle's other logs
            if previous is not None and not previous[1].absent:
                notes.append(f"{folder}: several logs for {est.name} {est.loop}; the latest (by log time) is used")
                if previous[0] > (mtime or 0.0):
                    continue
            latest[est.key] = (mtime or 0.0, est)
    return Side(path=str(folder), kind="batch", loops=tuple(v[1] for v in latest.values()),
                notes=tuple(dict.fromkeys(notes)))


def _reference_estimate(value: object, where: str) -> tuple[ParameterEstimate, str | None]:
    """A reference entry -> (estimate, tolerance text or None)."""
    if isinstance(value, Mapping):
        unknown = set(value) - _REFERENCE_KEYS
        if unknown:
            raise InputError(f"{where}: unknown key {sorted(unknown)[0]!r} (known: {', '.join(sorted(_REFERENCE_KEYS))})")
        mean = _number(value.get("value"))
        std = _number(value.get("std")) if "std" in value else 0.0
        tol = value.get("tol")
        if tol is not None and not isinstance(tol, str):
            raise InputError(f"{where}: tol must be a string such as \"+5ms\" or \"25%\"")
    else:
        mean, std, tol = _number(value), 0.0, None
    if mean is None or not math.isfinite(mean) or std is None or not std >= 0.0 or not math.isfinite(std):
        raise InputError(f"{where}: give a finite value (and std >= 0), e.g. {{ value = 0.0464, tol = \"+5ms\" }}")
    return ParameterEstimate(mean, std, math.nan, math.nan, ""), tol  # no interval: the std is its spread


def _reference_loop(table: Mapping[str, Any], loop: str, name: str | None, source: str) -> LoopEstimates:
    where = f"{source}: [{name + '.' if name else ''}{loop}]"
    estimates, tolerances = {}, []
    for key, value in table.items():
        if key not in PARAMETERS:
            raise InputError(f"{where}: unknown parameter {key!r} (known: {', '.join(PARAMETERS)})")
        est, tol = _reference_estimate(value, f"{where} {key}")
        estimates[key] = est
        if tol is not None:
            amount, relative, direction = parse_amount(key, tol)
            tolerances.append(Tolerance(parameter=key, amount=amount, relative=relative, direction=direction,
                                        loop=loop, text=f"{key}:{tol}"))
    return LoopEstimates(loop=loop, name=name, source=source, parameters=estimates, tolerances=tuple(tolerances))


def read_reference(path: Path) -> Side:
    """Read a reference TOML file (module docstring; docs/compare.md).

    Values are in SI units (seconds for Td and tau). A top-level table whose keys are parameters is a
    loop; otherwise it names a log or vehicle and holds loop tables.

    Raises
    ------
    InputError
        Unreadable TOML, an unknown key or parameter, a non-finite value, a malformed tolerance.
    """
    try:
        data = load_toml_text(path.read_text(), "TOML")
    except InputError as err:
        raise InputError(f"{path}: cannot read it as TOML ({str(err).removeprefix('TOML: ')})") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: cannot read it as TOML ({err})") from None
    loops = []
    for key, table in data.items():
        if not isinstance(table, Mapping):
            raise InputError(f"{path}: {key!r} must be a table such as [altitude] or [vehicle7.altitude]")
        if any(k in PARAMETERS for k in table):
            loops.append(_reference_loop(table, key, None, str(path)))
            continue
        for loop, sub in table.items():
            if not isinstance(sub, Mapping):
                raise InputError(f"{path}: [{key}] {loop!r} must be a loop table such as [{key}.altitude]")
            loops.append(_reference_loop(sub, loop, key, str(path)))
    if not loops:
        raise InputError(f"{path}: no loop in the reference file; add e.g. [altitude] tau = {{ value = 0.0464 }}")
    return Side(path=str(path), kind="reference", loops=tuple(loops))


def read_side(path: str | Path, by: str = "log") -> Side:
    """Read one side: an analysis JSON, a batch folder or record, or a reference ``.toml``.

    Parameters
    ----------
    path : str or Path
        What to read.
    by : {"log", "vehicle"}
        How a batch folder's logs are named for matching.

    Raises
    ------
    InputError
        A path that is none of the above.
    LogReadError
        A path that does not exist (:func:`mrftcli.io.require_input`).
    """
    p = Path(path)
    if by not in MATCH_BY:
        raise InputError(f"match by {by!r}: use one of {', '.join(MATCH_BY)}")
    if p.is_dir():
        return _read_batch_folder(p, by)
    require_input(p)  # the one missing-input error (exit 3), as every command words it
    if p.suffix.lower() == ".toml":
        return read_reference(p)
    data = _read_json(p)
    if isinstance(data, Mapping) and "loops" in data:
        return Side(path=str(p), kind="batch", loops=tuple(estimates_from_batch_record(data, source=str(p), by=by)))
    if not isinstance(data, Mapping):
        raise InputError(f"{p}: not an analysis result (a JSON object); pass the JSON of 'mrft-ident analyze'")
    return Side(path=str(p), kind="analysis", loops=(estimates_from_analysis(data, source=str(p)),))
