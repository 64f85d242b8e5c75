"""Analyse many flight logs in one go: local worker processes by default, a Dask cluster for fleets.

The unit of work is one log: :func:`analyze_one` reads it once per requested loop through
:func:`mrftcli.analyze.analyze_path` (and optionally :func:`mrftcli.diagnose.selection.diagnose`) and returns a
JSON-ready *record*. It never raises: a bad log becomes a record whose loops are ``failed`` with the
one-line message of the error, so one broken file never stops a batch of thousands.

:func:`run_batch` discovers the logs, resolves each log's settings (CLI defaults, a TOML/YAML config
matched by glob, explicit CLI options), skips logs whose stored result is up to date, runs the rest on
one of three executors (in-process, a :class:`concurrent.futures.ProcessPoolExecutor`, or an existing
Dask ``distributed`` scheduler) and writes, in the output folder::

    logs/<log name>.<8 hex of the log's absolute path>.json   one record per log (the analyze JSON)
    summary.csv, summary.parquet                               one row per log and loop
    report/index.html + PNGs                                   the fleet report (mrftcli.report.fleet)

The worker is injectable (``run_batch(..., worker=f)``) so the machinery is testable without the
analysis itself, and so other per-log jobs can reuse it. Workers on a Dask cluster must have mrftcli
installed and see the logs under the same absolute paths (a shared file system); the records travel
back to the client, which alone writes the output folder.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import re
import socket
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from .. import __version__
from .inputs import (
    SUPPORTED_SUFFIXES,
    BatchConfig,
    ConfigEntry,
    LogSettings,
    discover_logs,
    load_config,
    log_mtime,
    resolve_settings,
    result_path,
)
from ..errors import InputError, InsufficientDataError, MrftError
from ..io.logtypes import LOOPS
from ..jsonable import to_jsonable
from ..progress import Progress
from ..progress import report as report_progress

if TYPE_CHECKING:
    from ..analyze import AnalysisResult

__all__ = [
    "SUPPORTED_SUFFIXES",
    "BatchFailedError",
    "LogSettings",
    "LogTask",
    "BatchConfig",
    "ConfigEntry",
    "BatchResult",
    "resolve_settings",
    "log_mtime",
    "discover_logs",
    "load_config",
    "result_path",
    "settings_hash",
    "analyze_one",
    "run_batch",
    "summary_rows",
    "flag_outliers",
]

#: Statuses of a row in the summary.
STATUS_OK, STATUS_FAILED, STATUS_INSUFFICIENT, STATUS_SKIPPED = ("ok", "failed", "insufficient", "skipped-uptodate")

#: Record format version: bump when the record layout changes, so old results are recomputed.
_RECORD_VERSION = 1


class BatchFailedError(MrftError):
    """Some logs of a batch failed (the others were analysed and written); exit code 8."""

    exit_code = 8


def settings_hash(settings: LogSettings, diagnose: bool) -> str:
    """A short hash of everything that changes a log's result (settings, --diagnose, tool version).

    The vehicle name is left out: it only labels the summary row, so renaming does not recompute.
    """
    relevant = {k: v for k, v in settings.to_dict().items() if k != "vehicle"}
    blob = json.dumps(
        {"settings": relevant, "diagnose": bool(diagnose), "version": __version__, "record": _RECORD_VERSION},
        sort_keys=True,
    )
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


# --------------------------------------------------------------------------------------------------
# The per-log worker
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LogTask:
    """Everything a worker needs for one log (picklable, so it can travel to a process or Dask)."""

    path: str
    settings: LogSettings
    diagnose: bool = False
    settings_hash: str = ""
    log_mtime: float = 0.0


def _now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return text or type(err).__name__


def _failed_entry(loop: str, err: BaseException) -> dict[str, Any]:
    known = isinstance(err, MrftError)
    return {
        "loop": loop,
        "status": STATUS_FAILED,
        "error": _one_line(err) if known else f"{type(err).__name__}: {_one_line(err)}",
        "error_type": type(err).__name__ if known else "internal",
        "exit_code": getattr(err, "exit_code", 1),
        "result": None,
        "diagnosis": None,
    }


def _analyze_loop(task: LogTask, loop: str) -> dict[str, Any]:
    s = task.settings
    entry: dict[str, Any] = {"loop": loop, "status": STATUS_OK, "error": None, "error_type": None,
                             "exit_code": 0, "result": None, "diagnosis": None}
    try:
        if s.tp is None:
            raise InputError("no Tp for this log: pass --tp or set tp in a config entry matching it")
        from ..analyze import analyze_path

        # settings left unset keep analyze_path's defaults
        options = {k: v for k, v in (("command_topic", s.command_topic), ("output_topic", s.output_topic),
                                     ("beta_topic", s.beta_topic), ("setpoint_topic", s.setpoint_topic),
                                     ("output_scale", s.output_scale), ("min_stable_cycles", s.min_cycles))
                   if v is not None}
        result = analyze_path(task.path, s.tp, loop, **options)
        entry["result"] = result.to_dict()
    except InsufficientDataError as err:
        entry.update(status=STATUS_INSUFFICIENT, error=_one_line(err), error_type=type(err).__name__,
                     exit_code=err.exit_code, result={"partial": err.partial})
        return entry
    except Exception as err:  # noqa: BLE001 - one bad log must never stop the batch
        return _failed_entry(loop, err)
    if task.diagnose:
        entry["diagnosis"] = _diagnose_loop(task, result)
    return entry


def _diagnose_loop(task: LogTask, analysis: AnalysisResult) -> dict[str, Any]:
    """Run the diagnosis on an analysed loop (reusing its signals and segmentation); its failure is
    recorded but leaves the analysis ok."""
    try:
        from ..diagnose.selection import diagnose

        return {"status": STATUS_OK, "error": None,
                **diagnose(analysis.flight, task.settings.tp, analysis=analysis).to_dict()}
    except Exception as err:  # noqa: BLE001
        known = isinstance(err, MrftError)
        return {"status": STATUS_FAILED, "error": _one_line(err) if known else f"{type(err).__name__}: {_one_line(err)}",
                "effects": []}


def analyze_one(task: LogTask) -> dict[str, Any]:
    """Analyse one log for each of its loops; never raises.

    Returns
    -------
    dict
        The record stored as the log's JSON: ``path``, ``log_mtime`` [s since the epoch],
        ``settings``, ``settings_hash``, ``analysed_at`` (ISO 8601 UTC), ``host``, ``elapsed_s`` and
        ``loops``: one item per loop with ``status`` (ok / failed / insufficient), ``error`` (one line
        or None), ``error_type``, ``exit_code``, ``result`` (the analyze JSON, or ``{"partial": ...}``
        when insufficient), ``diagnosis`` (the diagnose JSON, or None) and ``python_warnings`` (the
        distinct warnings the numerics raised, which are kept here rather than printed).
    """
    t0 = time.perf_counter()
    loops = []
    for loop in task.settings.loops:
        # Python warnings raised by the numerics go into the record instead of interleaving on the
        # terminal from many processes.
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            entry = _analyze_loop(task, loop)
        entry["python_warnings"] = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
        loops.append(entry)
    # Plain JSON values (NaN -> None) made here, in the worker, so the parent only writes them.
    return to_jsonable(_record(task, loops, time.perf_counter() - t0))


def _record(task: LogTask, loops: list[dict[str, Any]], elapsed: float) -> dict[str, Any]:
    return {
        "record_version": _RECORD_VERSION,
        "tool_version": __version__,
        "path": task.path,
        "log_mtime": task.log_mtime,
        "settings": task.settings.to_dict(),
        "settings_hash": task.settings_hash,
        "diagnose": task.diagnose,
        "analysed_at": _now_iso(),
        "host": socket.gethostname(),
        "elapsed_s": elapsed,
        "loops": loops,
    }


def _crashed_record(task: LogTask, err: BaseException) -> dict[str, Any]:
    """A record for a log whose worker itself died (process killed, Dask worker lost...)."""
    return _record(task, [_failed_entry(loop, err) for loop in task.settings.loops], 0.0)


# --------------------------------------------------------------------------------------------------
# Executors
# --------------------------------------------------------------------------------------------------

Worker = Callable[[LogTask], dict[str, Any]]


def _run_inprocess(worker: Worker, tasks: Sequence[LogTask]) -> Iterator[tuple[LogTask, dict[str, Any]]]:
    for task in tasks:
        try:
            yield task, worker(task)
        except Exception as err:  # noqa: BLE001 - an injected worker may raise
            yield task, _crashed_record(task, err)


def _run_processes(worker: Worker, tasks: Sequence[LogTask], jobs: int) -> Iterator[tuple[LogTask, dict[str, Any]]]:
    """Run on a process pool; a log whose process dies fails alone.

    When a worker process dies (killed, out of memory, a crash in native code) the pool breaks and every
    log still queued gets ``BrokenProcessPool``. Those logs are run again on a fresh pool; logs that break
    a second pool are then run one per process, so only the log that kills its process fails.
    """
    pending = list(tasks)
    for attempt in range(3):
        if not pending:
            return
        broken: list[LogTask] = []
        isolate = attempt == 2
        groups = [[t] for t in pending] if isolate else [pending]
        for group in groups:
            pool = ProcessPoolExecutor(max_workers=max(1, min(jobs, len(group))))
            try:
                futures = {pool.submit(worker, task): task for task in group}
                for fut in as_completed(futures):
                    task = futures[fut]
                    try:
                        record = fut.result()
                    except BrokenProcessPool as err:
                        if isolate:
                            yield task, _crashed_record(task, RuntimeError(f"the worker process died ({err})"))
                        else:
                            broken.append(task)
                        continue
                    except Exception as err:  # noqa: BLE001 - e.g. an unpicklable result
                        record = _crashed_record(task, err)
                    yield task, record
            finally:
                # Do not wait for queued logs when the caller stops early (Ctrl-C, an error).
                pool.shutdown(wait=True, cancel_futures=True)
        pending = broken


def connect_scheduler(address: str, timeout_s: float) -> Any:
    """A ``distributed.Client`` for ``address``; one-line :class:`InputError` when it cannot be had."""
    m = re.fullmatch(r"(?:(tcp|tls|ws|wss|ucx)://)?(\[[0-9a-fA-F:]+\]|[^\s:/\[\]]+):(\d+)/?", address.strip())
    if m is None or not 0 < int(m.group(3)) < 65536:
        # checked here because distributed leaves a half-built Client behind that prints a traceback
        raise InputError(f"--scheduler must look like tcp://HOST:PORT (e.g. tcp://10.0.0.5:8786), got {address!r}")
    try:
        from distributed import Client
    except ImportError as err:
        raise InputError(
            "--scheduler needs Dask distributed, which is not installed: pip install 'mrft-ident[dask]'"
        ) from err
    try:
        return Client(address, timeout=f"{timeout_s}s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as err:
        raise InputError(
            f"cannot reach the Dask scheduler at {address} within {timeout_s:g} s ({_one_line(err)}); "
            "check the address or start it with `dask scheduler`"
        ) from err


def _run_dask(
    worker: Worker, tasks: Sequence[LogTask], address: str, timeout_s: float
) -> Iterator[tuple[LogTask, dict[str, Any]]]:
    from distributed import as_completed as dask_as_completed

    client = connect_scheduler(address, timeout_s)
    try:
        futures = client.map(worker, list(tasks), pure=False)
        by_key = {f.key: t for f, t in zip(futures, tasks)}
        for fut in dask_as_completed(futures, loop=client.loop):
            task = by_key[fut.key]
            try:
                yield task, fut.result()
            except Exception as err:  # noqa: BLE001 - KilledWorker, CommClosedError, ...
                yield task, _crashed_record(task, err)
            fut.release()
    finally:
        client.close()


# --------------------------------------------------------------------------------------------------
# Summary
# --------------------------------------------------------------------------------------------------

SUMMARY_COLUMNS = [
    "path", "loop", "vehicle", "status", "result_status", "error", "error_type",
    "Td_mean", "Td_std", "tau_mean", "tau_std", "K_mean", "K_std",
    "n_tests", "n_cycles", "betas", "findings", "Td_with_findings", "tau_with_findings", "K_with_findings",
    "diagnose_error",
    "tp", "log_time", "log_time_source", "log_mtime", "analysed_at", "elapsed_s", "result_json", "settings_hash",
    "tau_z", "Td_z", "tau_outlier", "Td_outlier", "tau_change", "Td_change", "tau_changed", "Td_changed",
    "outlier", "outlier_reason",
]


_OUTLIER_COLUMNS = ("tau_z", "Td_z", "tau_outlier", "Td_outlier", "tau_change", "Td_change", "tau_changed",
                    "Td_changed", "outlier", "outlier_reason")


def _param(result: Mapping[str, Any] | None, name: str, stat: str) -> float:
    try:
        value = result["parameters"][name][stat]  # type: ignore[index]
        return float(value) if value is not None else math.nan
    except (KeyError, TypeError, ValueError):
        return math.nan


def _tests_figures(result: Mapping[str, Any] | None) -> tuple[int | None, int | None, str]:
    tests = (result or {}).get("tests")
    if not isinstance(tests, list):
        return None, None, ""
    cycles = 0
    betas: list[str] = []
    for t in tests:
        c = t.get("cycles") if isinstance(t, Mapping) else None
        cycles += len(c) if isinstance(c, list) else int(c or 0)
        # the nominal (published) beta groups logs; the effective one differs by noise from log to log
        b = (t.get("beta_nominal") if t.get("beta_nominal") is not None else t.get("beta")) if isinstance(t, Mapping) else None
        if b is not None:
            betas.append(f"{float(b):g}")
    return len(tests), cycles, ";".join(betas)


#: Log time stamps accepted as absolute (UNIX) times: from 2001 on. Earlier ones (a simulator's 0 s, a
#: flight controller's time since boot) are relative and the file's modification time is used instead.
_EPOCH_MIN = 1.0e9


def _utc(t: Any) -> pd.Timestamp:
    """Seconds since the epoch -> UTC timestamp; NaT when missing or not finite."""
    if isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t):
        return pd.Timestamp(t, unit="s", tz="UTC")
    return pd.NaT


def _log_time(result: Mapping[str, Any] | None, mtime: Any) -> dict[str, Any]:
    """When the flight happened: the log's first time stamp if it is a UNIX time, else the file mtime."""
    t_first = ((result or {}).get("input") or {}).get("t_first")
    if isinstance(t_first, (int, float)) and math.isfinite(t_first) and _EPOCH_MIN <= t_first <= time.time() + 86400:
        return {"log_time": _utc(t_first), "log_time_source": "log"}
    return {"log_time": _utc(mtime), "log_time_source": "mtime"}


def summary_rows(record: Mapping[str, Any], json_path: Path | None, *, skipped: bool = False) -> list[dict[str, Any]]:
    """One summary row per loop of a record (see ``docs/batch.md`` for the columns)."""
    rows = []
    settings = record.get("settings", {})
    path = Path(record["path"])
    vehicle = settings.get("vehicle") or path.parent.name
    mtime = record.get("log_mtime")
    for entry in record.get("loops", []):
        result = entry.get("result") if entry.get("status") == STATUS_OK else None
        n_tests, n_cycles, betas = _tests_figures(result)
        diag = entry.get("diagnosis") or {}
        effects = diag.get("effects") or []
        rows.append({
            "path": str(path),
            "loop": entry.get("loop"),
            "vehicle": vehicle,
            "status": STATUS_SKIPPED if skipped else entry.get("status"),
            "result_status": entry.get("status"),
            "error": entry.get("error"),
            "error_type": entry.get("error_type"),
            "Td_mean": _param(result, "Td", "mean"), "Td_std": _param(result, "Td", "std"),
            "tau_mean": _param(result, "tau", "mean"), "tau_std": _param(result, "tau", "std"),
            "K_mean": _param(result, "K", "mean"), "K_std": _param(result, "K", "std"),
            "n_tests": n_tests, "n_cycles": n_cycles, "betas": betas,
            # None: not diagnosed (or the diagnosis failed); "": diagnosed, the linear model explains the log
            "findings": (";".join(str(e.get("name")) for e in effects if isinstance(e, Mapping))
                         if diag.get("status") == STATUS_OK else None),
            **_with_findings(effects),
            "diagnose_error": diag.get("error"),
            "tp": settings.get("tp"),
            "log_mtime": _utc(mtime),
            **_log_time(result, mtime),
            "analysed_at": pd.Timestamp(record["analysed_at"]) if record.get("analysed_at") else pd.NaT,
            "elapsed_s": record.get("elapsed_s"),
            # Relative to the output folder, so the folder can be moved or shared as a whole.
            "result_json": json_path.relative_to(json_path.parent.parent).as_posix() if json_path is not None else None,
            "settings_hash": record.get("settings_hash"),
        })
    return rows


def _with_findings(effects: list) -> dict[str, float | None]:
    """Td, tau, K refitted with the diagnosed effects modelled (the last deterministic finding's
    identification, which for two effects is the joint fit); None when nothing was found that changes them."""
    out: dict[str, float | None] = {"Td_with_findings": None, "tau_with_findings": None, "K_with_findings": None}
    for e in effects:
        ident = e.get("identification") if isinstance(e, Mapping) else None
        w = ident.get("with_effect") if isinstance(ident, Mapping) else None
        if isinstance(w, Mapping) and w != ident.get("linear"):
            out = {f"{k}_with_findings": w.get(k) for k in ("Td", "tau", "K")}
    return out


def flag_outliers(df: pd.DataFrame, threshold: float = 3.5) -> pd.DataFrame:
    """Add robust z-scores of tau and Td per loop and flag outliers.

    z = 0.6745 (x - median) / MAD over the logs of the same loop with a result (Iglewicz & Hoaglin's
    modified z-score; 0.6745 makes it comparable to a normal z). A log is a tau (Td) outlier when
    |z| > ``threshold`` (3.5, their recommendation) *and* its distance from the median exceeds twice its
    own standard deviation, so that a log whose estimate is merely uncertain is not flagged. When the
    MAD is 0 (over half the values equal), z = (x - median) / (1.253314 MeanAD) instead. Needs at
    least 3 results per loop and some spread; otherwise z is NaN and nothing is flagged.

    Also flags changes against each vehicle's own earlier logs (:func:`_flag_vehicle_changes`).
    Adds the columns ``tau_z``, ``Td_z``, ``tau_outlier``, ``Td_outlier``, ``tau_change``,
    ``Td_change``, ``tau_changed``, ``Td_changed``, ``outlier`` (any of the flags) and
    ``outlier_reason`` (text, empty when not flagged).
    """
    df = df.copy()
    for name in ("tau", "Td"):
        df[f"{name}_z"] = np.nan
        df[f"{name}_outlier"] = False
    has = df["tau_mean"].notna() | df["Td_mean"].notna()
    for _, idx in df[has].groupby("loop").groups.items():
        for name in ("tau", "Td"):
            x = df.loc[idx, f"{name}_mean"].astype(float)
            x = x[np.isfinite(x)]
            if len(x) < 3:
                continue
            med = float(np.median(x))
            mad = float(np.median(np.abs(x - med)))
            if mad > 0:
                z = 0.6745 * (x - med) / mad
            else:
                # More than half the logs share one value (copies of a flight, a very consistent
                # fleet): the MAD is 0, so use the mean absolute deviation, scaled to match a normal
                # z-score (1.253314 = sqrt(pi/2)), as IBM SPSS and others do.
                mean_ad = float(np.mean(np.abs(x - med)))
                if mean_ad <= 0:
                    continue
                z = (x - med) / (1.253314 * mean_ad)
            std = df.loc[x.index, f"{name}_std"].astype(float).fillna(0.0)
            df.loc[x.index, f"{name}_z"] = z
            df.loc[x.index, f"{name}_outlier"] = (np.abs(z) > threshold) & (np.abs(x - med) > 2.0 * std)
    _flag_vehicle_changes(df)
    reasons = []
    for _, row in df.iterrows():
        r = []
        for name, unit, scale in (("tau", "ms", 1e3), ("Td", "s", 1.0)):
            if row[f"{name}_outlier"]:
                z = row[f"{name}_z"]
                r.append(f"{name} {'high' if z > 0 else 'low'} in the fleet (z={z:+.1f})")
            if row[f"{name}_changed"]:
                c = row[f"{name}_change"] * scale
                r.append(f"{name} {'grew' if c > 0 else 'fell'} by {abs(c):.3g} {unit} vs this vehicle's earlier logs")
        reasons.append("; ".join(r))
    df["outlier"] = df["tau_outlier"] | df["Td_outlier"] | df["tau_changed"] | df["Td_changed"]
    df["outlier_reason"] = reasons
    return df


def _flag_vehicle_changes(df: pd.DataFrame, k: float = 3.0, min_history: int = 2) -> None:
    """Flag logs that moved away from their own vehicle's history (in place).

    For each vehicle and loop, in ``log_time`` order, a log with at least ``min_history`` earlier
    results is compared with their median: ``{name}_change`` = x - median(earlier) and
    ``{name}_changed`` when |change| > k * sqrt(std_x^2 + s^2), s = max(1.4826 MAD(earlier),
    median(std of earlier)) -- the spread the history shows or its own reported uncertainty, whichever
    is larger. This catches "a vehicle whose tau grew" even when the new value is still inside the
    fleet's range.
    """
    for name in ("tau", "Td"):
        df[f"{name}_change"] = np.nan
        df[f"{name}_changed"] = False
    if "log_time" not in df or "vehicle" not in df:
        return
    for _, grp in df[df["tau_mean"].notna()].groupby(["vehicle", "loop"]):
        grp = grp.sort_values(["log_time", "path"])
        for name in ("tau", "Td"):
            x = grp[f"{name}_mean"].to_numpy(float)
            sd = np.nan_to_num(grp[f"{name}_std"].to_numpy(float))
            for i in range(min_history, len(grp)):
                prev, prev_sd = x[:i][np.isfinite(x[:i])], sd[:i][np.isfinite(x[:i])]
                if len(prev) < min_history or not np.isfinite(x[i]):
                    continue
                med = float(np.median(prev))
                spread = max(1.4826 * float(np.median(np.abs(prev - med))), float(np.median(prev_sd)))
                change = x[i] - med
                idx = grp.index[i]
                df.loc[idx, f"{name}_change"] = change
                df.loc[idx, f"{name}_changed"] = bool(abs(change) > k * math.hypot(sd[i], spread))


def _frame(rows: list[dict[str, Any]]) -> pd.DataFrame:
    df = pd.DataFrame(rows, columns=[c for c in SUMMARY_COLUMNS if c not in _OUTLIER_COLUMNS])
    for col in ("n_tests", "n_cycles"):
        df[col] = df[col].astype("Int64")
    for col in ("Td_mean", "Td_std", "tau_mean", "tau_std", "K_mean", "K_std", "tp", "elapsed_s"):
        df[col] = df[col].astype(float)
    for col in ("path", "loop", "vehicle", "status", "result_status", "error", "error_type", "betas", "findings",
                "diagnose_error", "log_time_source", "result_json", "settings_hash"):
        df[col] = df[col].astype("string")
    for col in ("log_time", "log_mtime", "analysed_at"):
        df[col] = pd.to_datetime(df[col], utc=True)
    df = flag_outliers(df)
    return df[SUMMARY_COLUMNS]


# --------------------------------------------------------------------------------------------------
# Orchestration
# --------------------------------------------------------------------------------------------------


@dataclass
class BatchResult:
    """What :func:`run_batch` did.

    Attributes
    ----------
    summary : pandas.DataFrame
        One row per log and loop, columns :data:`SUMMARY_COLUMNS`, sorted by path then loop.
    out_dir : pathlib.Path
        The output folder.
    outputs : dict[str, pathlib.Path]
        ``csv``, ``parquet`` and (when made) ``report``.
    counts : dict[str, int]
        Rows per status.
    n_logs : int
        Logs discovered.
    notes : list of str
        Problems that did not stop the batch (e.g. the fleet report could not be drawn).
    """

    summary: pd.DataFrame
    out_dir: Path
    outputs: dict[str, Path]
    counts: dict[str, int]
    n_logs: int
    notes: list[str] = field(default_factory=list)

    @property
    def failed(self) -> pd.DataFrame:
        return self.summary[self.summary["status"] == STATUS_FAILED]

    def summary_line(self) -> str:
        parts = ", ".join(f"{n} {s}" for s, n in self.counts.items() if n)
        return f"{self.n_logs} log(s), {len(self.summary)} row(s): {parts}; results in {self.out_dir}"


def _load_cached(json_path: Path, task: LogTask) -> dict[str, Any] | None:
    """The stored record if it is up to date for ``task``, else None.

    Up to date: the file is newer than the log, it was made with the same settings hash, and it holds
    a result for every loop (a log that failed, or whose worker died, is tried again).
    """
    try:
        if json_path.stat().st_mtime <= task.log_mtime:
            return None
        record = json.loads(json_path.read_text())
    except (OSError, ValueError):
        return None
    if record.get("settings_hash") != task.settings_hash or record.get("path") != task.path:
        return None
    if any(e.get("status") == STATUS_FAILED for e in record.get("loops", [])):
        return None
    return record


def _to_json_text(obj: Any) -> str:
    """Compact JSON: without ``indent`` the json module uses its C encoder, ~10x faster on the
    per-cycle data of a record, and the parent process writes every record of the batch."""
    try:
        return json.dumps(obj, allow_nan=False, separators=(",", ":"))
    except (TypeError, ValueError):  # numpy values or NaN from a worker that did not clean its record
        return json.dumps(to_jsonable(obj), allow_nan=False, separators=(",", ":"))


def _write_json_atomic(path: Path, obj: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    tmp.write_text(_to_json_text(obj) + "\n")
    os.replace(tmp, path)


def run_batch(
    paths: Iterable[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    defaults: Mapping[str, Any] | None = None,
    config: BatchConfig | None = None,
    explicit: Mapping[str, Any] | None = None,
    diagnose: bool = False,
    jobs: int | None = None,
    scheduler: str | None = None,
    scheduler_timeout_s: float = 10.0,
    force: bool = False,
    report: bool = True,
    progress: Progress | None = None,
    worker: Worker = analyze_one,
) -> BatchResult:
    """Analyse every log under ``paths`` and write the outputs to ``out_dir``.

    Parameters
    ----------
    paths : iterable of path-like
        Files, folders and globs (see :func:`discover_logs`).
    out_dir : path-like
        Output folder (created); it is excluded from discovery.
    defaults, config, explicit : mappings of :class:`LogSettings` fields
        Settings precedence, lowest first: ``defaults`` (the CLI's defaults), ``config`` (its
        ``[defaults]`` then every matching ``[[logs]]`` entry in file order), ``explicit`` (options the
        user gave on the command line).
    diagnose : bool
        Also run the diagnosis on each identified loop.
    jobs : int, optional
        Local worker processes (default ``os.cpu_count()``); 1 runs in this process.
    scheduler : str, optional
        A Dask scheduler address (``tcp://host:port``); when given, ``jobs`` is ignored.
    scheduler_timeout_s : float
        How long to wait for the scheduler [s].
    force : bool
        Recompute logs whose stored result is up to date.
    report : bool
        Write the fleet report (HTML + PNG).
    progress : Progress, optional
        Called as ``progress(done, total, name)`` with the logs analysed so far out of those to
        analyse (up-to-date logs are not counted) and the name of the last one.
    worker : callable
        ``LogTask -> record``; :func:`analyze_one` unless testing or reusing the machinery. Must be
        picklable (a module-level function) for processes and Dask.

    Raises
    ------
    InputError
        Bad paths, no Tp anywhere, bad jobs, or an unreachable scheduler.
    """
    out = Path(out_dir)
    if jobs is not None and jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {jobs}")
    logs = discover_logs(paths, exclude=[out])
    base = {"tp": None, "loops": ("altitude",)} | dict(defaults or {})
    tasks: list[LogTask] = []
    for log in logs:
        settings, _ = resolve_settings(log, base, config, explicit or {})
        try:
            mtime = log_mtime(log)
        except OSError:  # vanished or unreadable since discovery: the worker reports it as that log's failure
            mtime = math.inf
        tasks.append(LogTask(str(log), settings, diagnose, settings_hash(settings, diagnose), mtime))
    if all(t.settings.tp is None for t in tasks):
        raise InputError("no Tp given: pass --tp SECONDS or a config file that sets tp for the logs")

    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot create the output folder {out}: {err.strerror or err}") from err
    rows: list[dict[str, Any]] = []
    todo: list[LogTask] = []
    for task in tasks:
        jp = result_path(out, Path(task.path))
        cached = None if force else _load_cached(jp, task)
        if cached is not None:
            cached["settings"] = {**cached.get("settings", {}), "vehicle": task.settings.vehicle}
            rows.extend(summary_rows(cached, jp, skipped=True))
        else:
            todo.append(task)

    if todo:
        if worker is analyze_one and not scheduler:
            # Import the analysis once here, so forked worker processes inherit it instead of each
            # paying the import (about a second of SciPy and readers) on its first log.
            try:
                import mrftcli.analyze  # noqa: F401
            except Exception:  # noqa: BLE001 - the worker reports it per log
                pass
        if scheduler:
            stream = _run_dask(worker, todo, scheduler, scheduler_timeout_s)
        elif (jobs or os.cpu_count() or 1) == 1 or len(todo) == 1:
            stream = _run_inprocess(worker, todo)
        else:
            stream = _run_processes(worker, todo, jobs or os.cpu_count() or 1)
        report_progress(progress, 0, len(todo), "")
        for done, (task, record) in enumerate(stream, 1):
            jp = result_path(out, Path(task.path))
            _write_json_atomic(jp, record)
            rows.extend(summary_rows(record, jp))
            report_progress(progress, done, len(todo), Path(task.path).name)

    loop_order = {name: i for i, name in enumerate(LOOPS)}
    rows.sort(key=lambda r: (r["path"], loop_order.get(r["loop"], 99), str(r["loop"])))
    df = _frame(rows)
    outputs = {"csv": out / "summary.csv", "parquet": out / "summary.parquet"}
    csv_df = df.copy()
    for col in ("log_time", "log_mtime", "analysed_at"):
        csv_df[col] = csv_df[col].map(lambda t: t.isoformat() if pd.notna(t) else "")
    csv_df.to_csv(outputs["csv"], index=False)
    df.to_parquet(outputs["parquet"], index=False, engine="pyarrow")
    notes: list[str] = []
    if report and len(df):
        try:
            from ..report.fleet import write_fleet_report

            outputs["report"] = write_fleet_report(df, out / "report")
        except Exception as err:  # noqa: BLE001 - the results are written; a plotting problem must not lose them
            notes.append(f"the fleet report could not be drawn ({type(err).__name__}: {_one_line(err)})")
    counts = {s: int((df["status"] == s).sum()) for s in (STATUS_OK, STATUS_INSUFFICIENT, STATUS_FAILED, STATUS_SKIPPED)}
    return BatchResult(df, out, outputs, counts, len(logs), notes)
