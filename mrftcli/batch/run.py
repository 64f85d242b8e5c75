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

import dataclasses
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

import pandas as pd

from .. import __version__
from ..io.atomic import atomic_path, check_output_path, looks_like_json, write_text_atomic
from ..vehicle.loops import absent_topics, loops_in_log  # one implementation: batch --loop auto and vehicle
from .inputs import AUTO_LOOP, BatchConfig, LogSettings, discover_logs, log_mtime, resolve_settings, result_path
from .summary import (
    STATUS_FAILED,
    STATUS_INSUFFICIENT,
    STATUS_NO_TESTS,
    STATUS_NO_TOPICS,
    STATUS_OK,
    STATUS_SKIPPED,
    lead_note,
    summary_frame,
    summary_rows,
)
from ..errors import InputError, InsufficientDataError, MrftError, TpRejectedError
from ..io.logtypes import LOOPS, PROCESS_LOOP
from ..jsonable import load_json_text, to_jsonable
from ..mrft.identify_lti import refuse_nothing_determined
from ..progress import Progress
from ..progress import report as report_progress
from ..validate import check_positive

if TYPE_CHECKING:
    from ..analyze import AnalysisResult
    from ..mrft.model import PlantModel

__all__ = ["BatchFailedError", "absent_topics", "loops_in_log", "LogTask", "BatchResult", "settings_hash", "analyze_one", "connect_scheduler",
           "BatchOptions", "run_batch", "failed_entry", "log_record", "caught_warnings"]

#: Record format version: bump when the record layout changes, so old results are recomputed. 2: the
#: analyses in it write every parameter as the one record (issue 36), so a rerun leaves no folder of two shapes.
_RECORD_VERSION = 2


class BatchFailedError(MrftError):
    """Some logs of a batch failed (the others were analysed and written); exit code 8."""

    exit_code = 8


def settings_hash(settings: LogSettings, diagnose: bool, tune: str | None = None, vehicle: bool = False,
                  model: str = "") -> str:
    """A short hash of everything that changes a log's result (settings, --diagnose, --tune, --vehicle, the
    process model's JSON ``model``, tool version).

    The vehicle name is left out: it only labels the summary row, so renaming does not recompute.
    """
    relevant = {k: v for k, v in settings.to_dict().items() if k != "vehicle"}
    # untuned batches keep their earlier hashes; a vehicle record is another result than the loops' analyses
    extra = {**({"tune": tune} if tune else {}), **({"vehicle_record": True} if vehicle else {}),
             **({"model": model} if model else {})}
    blob = json.dumps(
        {"settings": relevant, "diagnose": bool(diagnose), "version": __version__, "record": _RECORD_VERSION,
         **extra},
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
    #: Controller kind to tune ("PD" or "PID") on each identified loop, or None.
    tune: str | None = None
    #: Identify and tune the whole vehicle (mrftcli.vehicle): the record holds its vehicle record.
    vehicle: bool = False
    #: A process model (PlantModel, ``--model NAME``/``--model-file``): each loop analysed with it;
    #: None: eq. (2).
    model: Any = None


def _now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return text or type(err).__name__


def _error_text(err: BaseException) -> str:
    """The error in one line; an unexpected one (not an :class:`MrftError`) with its class name first."""
    return _one_line(err) if isinstance(err, MrftError) else f"{type(err).__name__}: {_one_line(err)}"


def failed_entry(loop: str, err: BaseException) -> dict[str, Any]:
    """A loop's row in a log's record when its analysis raised ``err`` (the message and the exit code's status)."""
    return {
        "loop": loop,
        "status": STATUS_FAILED,
        "error": _error_text(err),
        "error_type": type(err).__name__ if isinstance(err, MrftError) else "internal",
        "exit_code": getattr(err, "exit_code", 1),
        "result": None,
        "diagnosis": None,
    }


def _auto_loops(task: LogTask) -> tuple[str, ...]:
    """``--loop auto``: the loops the log records; altitude (the old default) when it cannot be opened,
    so that the analysis reports why; a process plant's (``--model``) one loop, ``process`` (as analyze
    records it without ``--loop``)."""
    if task.model is not None:
        return (PROCESS_LOOP,)
    try:
        return loops_in_log(task.path, task.settings.layout) or ("altitude",)
    except Exception:  # noqa: BLE001 - the analysis says why the log cannot be read
        return ("altitude",)


def _untested_skipped(loops: list[dict[str, Any]]) -> None:
    """``--loop auto``: a loop without relay tests (or whose field the log's topic lacks: a CSV or ULog
    holding z alone) is skipped when another loop of the log was not (a log where every loop failed
    keeps its failures). batch chose the loop, so the one-loop question whether --loop is right goes."""
    from ..analyze.screen import WHICH_LOOP_HINT

    why = {"SegmentationError": (STATUS_NO_TESTS, "no MRFT test on the {} loop"),
           "OtherLoopError": (STATUS_NO_TESTS, "no MRFT test on the {} loop"),
           "InputError": (STATUS_NO_TOPICS, "no {} topics"), "LogReadError": (STATUS_NO_TOPICS, "no {} topics")}
    untested = [e for e in loops if e["status"] == STATUS_FAILED and e.get("error_type") in why]
    if len(untested) < len(loops):
        for e in untested:
            status, text = why[e["error_type"]]
            e.update(status=status, error=f"skipped: {text.format(e['loop'])} ({e['error'].removesuffix(WHICH_LOOP_HINT)})")


def _skipped_entry(entry: dict[str, Any], loop: str, absent: tuple[str, ...]) -> dict[str, Any]:
    entry.update(status=STATUS_NO_TOPICS, error=f"skipped: no {loop} topics ({', '.join(absent)})",
                 error_type="NoTopics")
    return entry


def _analyze_loop(task: LogTask, loop: str) -> dict[str, Any]:
    s = task.settings
    entry: dict[str, Any] = {"loop": loop, "status": STATUS_OK, "error": None, "error_type": None,
                             "exit_code": 0, "result": None, "diagnosis": None}
    try:
        from ..analyze import AnalyzeOptions, analyze_path, refuse_rejected_tp
        from ..analyze.options import TRY_DIAGNOSE
        from ..io import ReadOptions
        from ..mrft.model import soiptd_model

        model = task.model if task.model is not None or s.tp is None else soiptd_model(s.tp)
        if model is None:
            raise InputError("no Tp for this log: pass --tp or set tp in a config entry matching it")
        if task.model is None and s.command_topic is None and s.output_topic is None:
            # a fleet of mixed loops: a log that does not record this loop is skipped, not failed
            try:
                absent = absent_topics(task.path, loop, s.layout)
            except Exception:  # noqa: BLE001 - an unreadable log: the analysis says why, in its own words
                absent = ()
            if absent:
                return _skipped_entry(entry, loop, absent)
        # settings left unset (None) keep the options' defaults
        read = ReadOptions(loop=loop, command_topic=s.command_topic, output_topic=s.output_topic,
                           beta_topic=s.beta_topic, setpoint_topic=s.setpoint_topic, output_scale=s.output_scale,
                           command_scale=s.command_scale, layout=s.layout, controller_rate_hz=s.controller_rate_hz)
        # the hint batch's --diagnose answers, unless it is given
        hint = "" if task.diagnose else TRY_DIAGNOSE
        options = AnalyzeOptions(diagnose_hint=hint)
        if s.min_cycles is not None:
            options = dataclasses.replace(options, min_stable_cycles=s.min_cycles)
        # batch tries every loop itself: a missing topic's error does not tell the user to give --loop
        result = analyze_path(task.path, model, read=read, options=options, loop_hint=False)  # the one route
        if task.model is None:  # eq. (2): a Tp the recording rejects fails the loop unless --accept-tp
            result = refuse_rejected_tp(result, s.accept_tp)
        if result.kind == "family":  # nothing determined: insufficient, as analyze's exit 6
            refuse_nothing_determined(result.identification, partial=result.to_json())
        entry["result"] = result.to_json()
    except InsufficientDataError as err:
        entry.update(status=STATUS_INSUFFICIENT, error=_one_line(err), error_type=type(err).__name__,
                     exit_code=err.exit_code, result={"partial": err.partial})
        return entry
    except TpRejectedError as err:  # failed (exit code 5), the analysis at the given Tp kept: tp_check says so
        rejected = failed_entry(loop, err)
        rejected["result"] = err.result.to_json() if hasattr(err.result, "to_json") else None
        return rejected
    except Exception as err:  # noqa: BLE001 - one bad log must never stop the batch
        return failed_entry(loop, err)
    if task.diagnose:
        entry["diagnosis"] = _diagnose_loop(task, result, model, options.min_stable_cycles)
    if task.tune:
        entry["tune"] = _tune_loop(result, task.tune)
    return entry


def _tune_loop(analysis: AnalysisResult, kind: str) -> dict[str, Any]:
    """The gains of an analysed loop (mrftcli.tune.analysis.summary_figures); a failure is recorded
    but leaves the analysis ok."""
    try:
        from ..tune.analysis import summary_figures, tune_analysis

        res = tune_analysis(analysis, kinds=(kind,), designs=("model-based", "robust"))
        return summary_figures(res, kind)
    except Exception as err:  # noqa: BLE001
        return {"tune_error": _error_text(err)}


def _diagnose_loop(task: LogTask, analysis: AnalysisResult, model: PlantModel,
                   min_stable_cycles: int = 3) -> dict[str, Any]:
    """Run the diagnosis (:func:`mrftcli.diagnose.selection.diagnose`, which takes every family) on an
    analysed loop with the model it was analysed with, reusing its signals (and eq. (2)'s segmentation);
    its failure is recorded but leaves the analysis ok. The record is ``diagnose --json``'s without its
    version (DiagnosisResult.to_dict)."""
    try:
        from ..diagnose.selection import diagnose

        if analysis.flight is None:  # a fresh analysis has it
            raise InputError("the diagnosis needs the analysis's flight signals")
        result = diagnose(analysis.flight, model, analysis=analysis if task.model is None else None,
                          min_stable_cycles=min_stable_cycles)
        return {"status": STATUS_OK, "error": None, **result.to_dict()}
    except Exception as err:  # noqa: BLE001
        return {"status": STATUS_FAILED, "error": _error_text(err), "effects": []}


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
    if task.vehicle:
        from .vehicle import vehicle_one

        return vehicle_one(task)
    t0 = time.perf_counter()
    loops = []
    auto = AUTO_LOOP in task.settings.loops
    chosen = _auto_loops(task) if auto else task.settings.loops
    for loop in chosen:
        entry, caught = caught_warnings(_analyze_loop, task, loop)
        entry["python_warnings"] = caught
        loops.append(entry)
    if auto:
        _untested_skipped(loops)
    # Plain JSON values (NaN -> None) made here, in the worker, so the parent only writes them.
    return to_jsonable(log_record(task, loops, time.perf_counter() - t0))


def caught_warnings(work: Callable[..., Any], *args: Any) -> tuple[Any, list[str]]:
    """``work(*args)`` and the distinct Python warnings the numerics raised in it: kept in the record
    instead of interleaving on the terminal from many processes."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = work(*args)
    return out, sorted({f"{w.category.__name__}: {w.message}" for w in caught})


def log_record(task: LogTask, loops: list[dict[str, Any]], elapsed: float) -> dict[str, Any]:
    """One log's batch record: its loops' rows, the settings, the tool version and the elapsed time [s]."""
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
    return log_record(task, [failed_entry(loop, err) for loop in task.settings.loops], 0.0)


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
# Orchestration
# --------------------------------------------------------------------------------------------------


@dataclass
class BatchResult:
    """What :func:`run_batch` did.

    Attributes
    ----------
    summary : pandas.DataFrame
        One row per log and loop, columns :data:`mrftcli.batch.summary.SUMMARY_COLUMNS`, sorted by path then loop.
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
    unwritten : list of str
        ``path: reason`` of each output file that could not be written (the others were).
    """

    summary: pd.DataFrame
    out_dir: Path
    outputs: dict[str, Path]
    counts: dict[str, int]
    n_logs: int
    notes: list[str] = field(default_factory=list)
    unwritten: list[str] = field(default_factory=list)

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
        record = load_json_text(json_path.read_text(), str(json_path))
    except (OSError, ValueError):  # unreadable, not JSON or nested too deep: analysed again
        return None
    if record.get("settings_hash") != task.settings_hash or record.get("path") != task.path:
        return None
    if any(e.get("status") == STATUS_FAILED for e in record.get("loops", [])):
        return None
    if not _declared_models_parse(record):
        return None  # a declared model's text no longer parses (edited, or written by hand): analysed again
    return record


def _declared_models_parse(record: Any) -> bool:
    """Does every declared model (``family: declared``) in a stored record parse through the one
    transfer-function parser (mrft/tf_parse.py)? A record is read back as it would be by tune or plan."""
    from ..mrft.model import model_from_json

    stack = [record]
    while stack:
        node = stack.pop()
        if isinstance(node, dict):
            if node.get("family") == "declared" and "transfer_function" in node:
                try:
                    model_from_json(node)
                except MrftError:
                    return False
            stack.extend(v for v in node.values() if isinstance(v, (dict, list)))
        elif isinstance(node, list):
            stack.extend(v for v in node if isinstance(v, (dict, list)))
    return True


def _to_json_text(obj: Any) -> str:
    """Compact JSON: without ``indent`` the json module uses its C encoder, ~10x faster on the
    per-cycle data of a record, and the parent process writes every record of the batch."""
    try:
        return json.dumps(obj, allow_nan=False, separators=(",", ":"))
    except (TypeError, ValueError):  # numpy values or NaN from a worker that did not clean its record
        return json.dumps(to_jsonable(obj), allow_nan=False, separators=(",", ":"))


def _write_json_atomic(path: Path, obj: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    refused = _unreplaceable(path, looks_like_json, "a JSON record")  # never someone's file (issue 35)
    if refused is not None:
        raise refused
    write_text_atomic(path, _to_json_text(obj) + "\n")


def _is_summary(path: Path) -> bool:
    """A summary batch wrote: a parquet file, or a CSV whose header starts with the summary's columns."""
    with open(path, "rb") as fh:
        head = fh.read(64)
    return head.startswith(b"PAR1") or head.startswith(b"path,loop,")


def _unreplaceable(path: Path, ours: Callable[[Path], bool], what: str) -> OSError | None:
    """Why an output may not be replaced (someone's file, a link), as the OSError batch reports, or None."""
    try:
        check_output_path(path, "--out", ours=ours, what=what)
    except InputError as err:
        return OSError(17, str(err).split(": ", 1)[-1])
    return None


def _check_out_dir(out: Path) -> None:
    """Create ``out`` and its ``logs`` folder before any work; InputError naming what is in the way."""
    for folder in (out, out / "logs"):
        if folder.exists() and not folder.is_dir():
            raise InputError(f"{folder} is a file, not a folder: batch stores {'its results' if folder == out else 'one record per log'} "
                             "there; move the file away or choose another output folder")
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise InputError(f"cannot create the output folder {folder}: {err.strerror or err}") from err


def _unwritten(path: Path, err: OSError) -> str:
    """One line for a result that could not be written."""
    return f"{path}: {err.strerror or err}"


@dataclass(frozen=True)
class BatchOptions:
    """What a batch does besides analysing each log, and where it runs (:func:`run_batch`), checked on creation.

    Attributes
    ----------
    diagnose : bool
        Also run the diagnosis on each identified loop.
    tune : {"PD", "PID"}, optional
        Also design that controller on each identified loop (:mod:`mrftcli.tune`); its gains and
        figures become the summary's ``tune_*`` columns.
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
    vehicle : bool
        Identify and tune every loop of each log as ``mrft-ident vehicle`` (:mod:`mrftcli.batch.vehicle`):
        each log's record holds its vehicle record, the summary one row per loop (``tune`` sets the
        controller kind).
    model : PlantModel, optional
        A process model (``--model NAME``, ``--model-file``): each loop is analysed with it
        (no Tp needed); its record is the process analysis and the
        summary adds the model and its parameters with units; ``diagnose`` runs the family's diagnosis. Not with
        ``tune``, ``vehicle``.

    Raises
    ------
    InputError
        ``jobs`` below 1, a non-positive scheduler timeout, a model with tune or vehicle.

    Examples
    --------
    >>> BatchOptions(jobs=1, report=False).scheduler is None
    True
    """

    diagnose: bool = False
    tune: str | None = None
    jobs: int | None = None
    scheduler: str | None = None
    scheduler_timeout_s: float = 10.0
    force: bool = False
    report: bool = True
    vehicle: bool = False
    model: Any = None

    def __post_init__(self) -> None:
        if self.model is not None:
            used = [n for n, v in (("--tune", self.tune), ("--vehicle", self.vehicle)) if v]
            if used:
                raise InputError(f"{', '.join(used)}: not with --model (batch --model analyses and diagnoses each "
                                 "log's process model; tune and vehicle work on eq. (2) loops)")
        if self.jobs is not None and self.jobs < 1:
            raise InputError(f"--jobs must be at least 1, got {self.jobs}")
        object.__setattr__(self, "scheduler_timeout_s",
                           check_positive("scheduler timeout [s]", self.scheduler_timeout_s))


def run_batch(
    paths: Iterable[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    options: BatchOptions | None = None,
    defaults: Mapping[str, Any] | None = None,
    config: BatchConfig | None = None,
    explicit: Mapping[str, Any] | None = None,
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
    options : BatchOptions, optional
        Diagnosis, controller design, executor (jobs, Dask scheduler), cache and report; None:
        ``BatchOptions()``.
    defaults, config, explicit : mappings of :class:`LogSettings` fields
        Settings precedence, lowest first: ``defaults`` (the CLI's defaults), ``config`` (its
        ``[defaults]`` then every matching ``[[logs]]`` entry in file order), ``explicit`` (options the
        user gave on the command line).
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
    opts = BatchOptions() if options is None else options
    out = Path(out_dir)
    logs = discover_logs(paths, exclude=[out])
    base = {"tp": None, "loops": (AUTO_LOOP,)} | dict(defaults or {})
    tasks = [_task(log, base, config, explicit or {}, opts.diagnose, opts.tune, opts.vehicle, opts.model)
             for log in logs]
    if opts.model is None and all(t.settings.tp is None for t in tasks):
        raise InputError("no Tp given: pass --tp SECONDS or a config file that sets tp for the logs")
    _check_out_dir(out)
    rows, todo = _cached_rows(tasks, out, opts.force)
    unwritten: list[str] = []
    if todo:
        stream = _stream(worker, todo, opts.jobs, opts.scheduler, opts.scheduler_timeout_s)
        report_progress(progress, 0, len(todo), "")
        for done, (task, record) in enumerate(stream, 1):
            jp = result_path(out, Path(task.path))
            try:
                _write_json_atomic(jp, record)
            except OSError as err:  # a full disk or a folder gone: keep the row, write the others
                unwritten.append(_unwritten(jp, err))
            rows.extend(summary_rows(record, jp))
            report_progress(progress, done, len(todo), Path(task.path).name)
    df, outputs, notes = _write_summary(rows, out, opts.report, unwritten)
    if unwritten:
        notes.insert(0, f"{len(unwritten)} output file(s) could not be written (first: {unwritten[0]}); "
                        "the results that were are complete")
    counts = {s: int((df["status"] == s).sum()) for s in (STATUS_OK, STATUS_INSUFFICIENT, STATUS_FAILED, STATUS_SKIPPED)}
    for status in (STATUS_NO_TOPICS, STATUS_NO_TESTS):  # named only when they happen (a fleet of mixed loops)
        if (df["status"] == status).any():
            counts[status] = int((df["status"] == status).sum())
    return BatchResult(df, out, outputs, counts, len(logs), notes, unwritten)


def _task(log: Path, base: Mapping[str, Any], config: BatchConfig | None, explicit: Mapping[str, Any],
          diagnose: bool, tune: str | None, vehicle: bool = False, model: Any = None) -> LogTask:
    """One log's unit of work with its resolved settings."""
    settings, _ = resolve_settings(log, base, config, explicit)
    try:
        mtime = log_mtime(log)
    except OSError:  # vanished or unreadable since discovery: the worker reports it as that log's failure
        mtime = math.inf
    key = "" if model is None else json.dumps(model.to_json(), sort_keys=True)  # another model, another result
    return LogTask(str(log), settings, diagnose, settings_hash(settings, diagnose, tune, vehicle, key), mtime, tune,
                   vehicle, model)


def _cached_rows(tasks: Sequence[LogTask], out: Path, force: bool) -> tuple[list[dict[str, Any]], list[LogTask]]:
    """The summary rows of the logs whose stored result is up to date, and the tasks still to run."""
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
    return rows, todo


def _stream(worker: Worker, todo: Sequence[LogTask], jobs: int | None, scheduler: str | None,
            scheduler_timeout_s: float) -> Iterator[tuple[LogTask, dict[str, Any]]]:
    """(task, record) as the executor finishes them: Dask, this process, or local processes."""
    if worker is analyze_one and not scheduler:
        # Import the analysis once here, so forked worker processes inherit it instead of each
        # paying the import (about a second of SciPy and readers) on its first log.
        try:
            import mrftcli.analyze  # noqa: F401
        except Exception:  # noqa: BLE001 - the worker reports it per log
            pass
    if scheduler:
        return _run_dask(worker, list(todo), scheduler, scheduler_timeout_s)
    if (jobs or os.cpu_count() or 1) == 1 or len(todo) == 1:
        return _run_inprocess(worker, list(todo))
    return _run_processes(worker, list(todo), jobs or os.cpu_count() or 1)


def _write_summary(rows: list[dict[str, Any]], out: Path, report: bool,
                   unwritten: list[str]) -> tuple[pd.DataFrame, dict[str, Path], list[str]]:
    """summary.csv, summary.parquet and the fleet report; the table, the files written and notes.

    Each file is written atomically; one that cannot be written is added to ``unwritten`` and
    left out of the outputs, and the others are still written.
    """
    loop_order = {name: i for i, name in enumerate(LOOPS)}
    rows.sort(key=lambda r: (r["path"], loop_order.get(r["loop"], 99), str(r["loop"])))
    df = summary_frame(rows)
    outputs = {"csv": out / "summary.csv", "parquet": out / "summary.parquet"}
    csv_df = df.copy()
    for col in ("log_time", "log_mtime", "analysed_at"):
        csv_df[col] = csv_df[col].map(lambda t: t.isoformat() if pd.notna(t) else "")
    for key, write in (("csv", lambda p: csv_df.to_csv(p, index=False)),
                       ("parquet", lambda p: df.to_parquet(p, index=False, engine="pyarrow"))):
        refused = _unreplaceable(outputs[key], _is_summary, "a batch summary")
        if refused is not None:
            unwritten.append(_unwritten(outputs.pop(key), refused))
            continue
        try:
            with atomic_path(outputs[key]) as tmp:
                write(tmp)
        except OSError as err:
            unwritten.append(_unwritten(outputs.pop(key), err))
    lead = lead_note(df)  # a negative tau_mean is eq. (2) with a lead: said, not left for a reader to spot
    notes: list[str] = [] if lead is None else [lead]
    if report and len(df):
        try:
            from ..report.fleet import write_fleet_report

            outputs["report"] = write_fleet_report(df, out / "report", notes)
        except Exception as err:  # noqa: BLE001 - the results are written; a plotting problem must not lose them
            notes.append(f"the fleet report could not be drawn ({type(err).__name__}: {_one_line(err)})")
    return df, outputs, notes
