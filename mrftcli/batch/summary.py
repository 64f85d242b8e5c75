"""The fleet summary of a batch: one row per log and loop, and the outlier flags.

:func:`summary_rows` turns a per-log record (see :func:`mrftcli.batch.run.analyze_one`) into rows,
:func:`summary_frame` types them into a table (columns :data:`SUMMARY_COLUMNS`, documented in
``docs/batch.md``) and :func:`flag_outliers` marks logs that stand out in the fleet or against their own
vehicle's history.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..analyze import AnalysisResult
from ..errors import InputError
from ..jsonable import check_schema_version
from ..report.wording import sig

__all__ = ["STATUS_OK", "STATUS_FAILED", "STATUS_INSUFFICIENT", "STATUS_SKIPPED", "STATUS_NO_TOPICS", "STATUS_NO_TESTS",
           "SUMMARY_COLUMNS",
           "TUNE_COLUMNS", "summary_rows", "summary_frame", "flag_outliers", "BatchSummary", "SUMMARY_SCHEMA_VERSION",
           "lead_note", "lead_rows"]

#: Statuses of a row in the summary.
STATUS_OK, STATUS_FAILED, STATUS_INSUFFICIENT, STATUS_SKIPPED = ("ok", "failed", "insufficient", "skipped-uptodate")
#: A loop asked for whose topics the log does not hold (a fleet of mixed loops): not a failure.
STATUS_NO_TOPICS = "skipped-no-topics"
#: With ``--loop auto``: a loop whose topics are there but on which no relay test was found, in a log
#: where another loop's were (a loop that was not tested).
STATUS_NO_TESTS = "skipped-no-tests"


SUMMARY_COLUMNS = [
    "path", "loop", "vehicle", "status", "result_status", "error", "error_type",
    "Td_mean", "Td_std", "tau_mean", "tau_std", "lead", "K_mean", "K_std",
    "n_tests", "n_cycles", "betas", "findings", "Td_with_findings", "tau_with_findings", "K_with_findings",
    "diagnose_error",
    "tp", "log_time", "log_time_source", "log_mtime", "analysed_at", "elapsed_s", "result_json", "settings_hash",
    "tau_z", "Td_z", "tau_outlier", "Td_outlier", "tau_change", "Td_change", "tau_changed", "Td_changed",
    "outlier", "outlier_reason",
]


#: Added after SUMMARY_COLUMNS when the batch ran with --tune (mrftcli.tune.analysis.summary_figures).
TUNE_COLUMNS = ["tune_design", "tune_kind", "tune_Kp", "tune_Ki", "tune_Kd", "tune_Tf", "tune_rate_hz", "tune_pm_deg",
                "tune_pm_worst_deg", "tune_dm_ms", "tune_ms", "tune_ms_worst", "tune_overshoot_pct", "tune_settling_s",
                "tune_error"]

#: the columns summary_frame computes from the others (not in a row of summary_rows)
_OUTLIER_COLUMNS = ("lead", "tau_z", "Td_z", "tau_outlier", "Td_outlier", "tau_change", "Td_change", "tau_changed",
                    "Td_changed", "outlier", "outlier_reason")


def _analysis(entry: Mapping[str, Any]) -> AnalysisResult | None:
    """The typed analysis of an ok loop entry, read once for every family (None: not ok, or a result this
    version cannot read)."""
    if entry.get("status") != STATUS_OK or entry.get("result") is None:
        return None
    try:
        return AnalysisResult.from_json(entry["result"])
    except InputError:
        return None


def _param(result: AnalysisResult | None, name: str, stat: str) -> float:
    if result is None:
        return math.nan
    est = {"Td": result.Td, "tau": result.tau, "K": result.K}[name]
    return float(est.value if stat == "mean" else est.std)


def _tests_figures(result: AnalysisResult | None) -> tuple[int | None, int | None, str]:
    if result is None:
        return None, None, ""
    # the nominal (published) beta groups logs; the effective one differs by noise from log to log
    betas = [t.beta_nominal if t.beta_nominal is not None else t.beta for t in result.tests]
    return (len(result.tests), sum(t.n_stable for t in result.tests),
            ";".join(f"{b:g}" for b in betas if math.isfinite(b)))


#: Log time stamps accepted as absolute (UNIX) times: from 2001 on. Earlier ones (a simulator's 0 s, a
#: flight controller's time since boot) are relative and the file's modification time is used instead.
_EPOCH_MIN = 1.0e9


def _utc(t: Any) -> pd.Timestamp:
    """Seconds since the epoch -> UTC timestamp; NaT when missing or not finite."""
    if isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t):
        return pd.Timestamp(t, unit="s", tz="UTC")
    return pd.NaT


def _log_time(t_first: float | None, mtime: Any) -> dict[str, Any]:
    """When the flight happened: the log's first time stamp [s] if it is a UNIX time, else the file mtime."""
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
        analysis = _analysis(entry)
        result = analysis if analysis is not None and analysis.kind == "soiptd" else None  # eq. (2)'s columns
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
            **_log_time(result.log_info.t_first if result is not None and result.log_info is not None else None,
                        mtime),
            "analysed_at": pd.Timestamp(record["analysed_at"]) if record.get("analysed_at") else pd.NaT,
            "elapsed_s": record.get("elapsed_s"),
            # Relative to the output folder, so the folder can be moved or shared as a whole.
            "result_json": json_path.relative_to(json_path.parent.parent).as_posix() if json_path is not None else None,
            "settings_hash": record.get("settings_hash"),
            **({k: (entry.get("tune") or {}).get(k) for k in TUNE_COLUMNS} if "tune" in entry else {}),
            **process_columns(analysis),  # {} but for a process analysis (batch --model)
        })
    return rows


#: The columns a process row adds after SUMMARY_COLUMNS (then ``p_NAME``, ``p_NAME_std``, ``p_NAME_unit``
#: per parameter of the family, in its order).
PROCESS_COLUMNS = ["model", "parameters"]


def process_columns(analysis: AnalysisResult | None) -> dict[str, Any]:
    """The summary columns of a process analysis (``batch --model``; None: a loop without a result).

    ``parameters`` reads e.g. ``"K 1.985 ± 0.084 output / command; T 0.9755 ± 0.043 s; tau 0.3265 ± 0.0015 s"``
    (``known`` for a given parameter, ``not determined`` for one the tests leave open); ``tau_mean`` and
    ``tau_std`` [s] fill eq. (2)'s columns too (the delay is ``tau`` in seconds in every family, so the
    fleet's tau outlier flags apply).
    """
    if analysis is None or analysis.kind != "family":
        return {}
    ident = analysis.identification
    out: dict[str, Any] = {"model": analysis.model.family, "n_tests": len(analysis.tests),
                           "n_cycles": sum(t.n_stable for t in analysis.tests),
                           "betas": ";".join(t.relay.kind for t in analysis.tests)}
    if ident is None:
        return out
    text = []
    for e in ident.estimates:
        spread = "known" if e.known else (f"± {sig(e.std, 2)}" if e.determined else "not determined")
        text.append(f"{e.name} {sig(e.value)} {spread} {e.unit}")
        out[f"p_{e.name}"] = e.value
        out[f"p_{e.name}_std"] = e.std if e.determined and not e.known else math.nan
        out[f"p_{e.name}_unit"] = e.unit
    out["parameters"] = "; ".join(text)
    tau = next((e for e in ident.estimates if e.name == "tau"), None)
    if tau is not None:
        out["tau_mean"] = tau.value
        out["tau_std"] = tau.std if tau.determined and not tau.known else math.nan
    return out


def _process_frame(rows: list[dict[str, Any]], index: pd.Index) -> pd.DataFrame:
    """PROCESS_COLUMNS, then each parameter's ``p_NAME``, ``p_NAME_std`` (float) and ``p_NAME_unit``, in the
    order the rows name them."""
    names: list[str] = []
    for r in rows:
        names += [k for k in r if k.startswith("p_") and k not in names]
    columns = PROCESS_COLUMNS + names
    frame = pd.DataFrame([{k: r.get(k) for k in columns} for r in rows], index=index, columns=columns)
    for col in columns:
        text = col in PROCESS_COLUMNS or col.endswith("_unit")
        frame[col] = frame[col].astype("string" if text else float)
    return frame


def _with_findings(effects: list) -> dict[str, float | None]:
    """Td, tau, K refitted with the diagnosed effects modelled (the last deterministic finding's
    identification, which for two effects is the joint fit); None when nothing was found that changes them."""
    out: dict[str, float | None] = {"Td_with_findings": None, "tau_with_findings": None, "K_with_findings": None}
    for e in effects:
        ident = e.get("identification") if isinstance(e, Mapping) else None
        if not isinstance(ident, Mapping):
            continue
        w = ident.get("with_effect")
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


def lead_rows(df: pd.DataFrame) -> pd.Series:
    """Which rows eq. (2) identified with a lead (``tau_mean`` < 0 [s]): the one test, computed once into the
    summary's ``lead`` column (:func:`summary_frame`), which the notes, the printed table and the fleet report read;
    a process row (``batch --model``, ``model`` set: its families take tau >= 0) never is."""
    if "tau_mean" not in df:
        return pd.Series(False, index=df.index, dtype=bool)
    tau = pd.to_numeric(df["tau_mean"], errors="coerce")
    lead = tau.notna() & (tau < 0)
    if "model" in df:
        lead &= df["model"].isna()
    return lead.astype(bool)


def lead_note(df: pd.DataFrame) -> str | None:
    """The note on the rows of a :func:`summary_frame` identified with a lead (its ``lead`` column): how many,
    which (None: none)."""
    lead = df[df["lead"].astype(bool)]
    if lead.empty:
        return None
    which = ", ".join(f"{Path(str(r['path'])).name} {r['loop']} ({r['tau_mean'] * 1e3:.3g} ms)"
                      for _, r in lead.iterrows())
    return (f"{len(lead)} loop(s) identified with tau < 0 (a lead: eq. (2) admits an estimator's few ms; tune "
            f"designs them at tau = 0): {which}")


def summary_frame(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """The summary table of :func:`summary_rows` rows: typed columns, outliers flagged, columns :data:`SUMMARY_COLUMNS`."""
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
    # batch --model: the process model and its parameters with units
    process = _process_frame(rows, df.index) if any("model" in r for r in rows) else None
    df["lead"] = lead_rows(df if process is None else df.join(process["model"]))
    if process is not None:
        return pd.concat([df[SUMMARY_COLUMNS], process], axis=1)
    if any("tune_Kp" in r for r in rows):
        tuned = pd.DataFrame([{k: r.get(k) for k in TUNE_COLUMNS} for r in rows], index=df.index, columns=TUNE_COLUMNS)
        for col in TUNE_COLUMNS:
            tuned[col] = tuned[col].astype("string" if col in ("tune_design", "tune_kind", "tune_error") else float)
        return pd.concat([df[SUMMARY_COLUMNS], tuned], axis=1)
    return df[SUMMARY_COLUMNS]


#: Version of the ``batch --json`` summary (:class:`BatchSummary`). A summary written before it carried one
#: has the same layout and reads as version 1 (for one release).
SUMMARY_SCHEMA_VERSION = 1
#: the summary's columns of times, written as ISO 8601 text (UTC)
_TIME_COLUMNS = ("log_time", "log_mtime", "analysed_at")


@dataclass(frozen=True)
class BatchSummary:
    """The ``batch --json`` record: what one batch run did, and its summary table's rows.

    Attributes
    ----------
    logs : int
        Logs discovered.
    counts : Mapping[str, int]
        Rows per status (``ok``, ``failed``, ...).
    out_dir : str
        The output folder.
    notes : tuple of str
        Problems that did not stop the batch.
    outputs : Mapping[str, str]
        ``csv``, ``parquet`` and (when made) ``report``: their paths.
    rows : tuple of Mapping
        One per log and loop: the columns of ``summary.csv`` (docs/batch.md; Td, tau [s]; times ISO 8601
        UTC text; null where a cell is empty).
    """

    logs: int
    counts: Mapping[str, int]
    out_dir: str
    notes: tuple[str, ...]
    outputs: Mapping[str, str]
    rows: tuple[Mapping[str, Any], ...]

    @classmethod
    def of(cls, result: Any) -> BatchSummary:
        """The record of a :class:`~mrftcli.batch.run.BatchResult` (its summary table as JSON-ready rows)."""
        df = result.summary
        rows = df.astype(object).where(df.notna(), None)
        for col in _TIME_COLUMNS:
            rows[col] = [t.isoformat() if t is not None else None for t in rows[col]]
        return cls(int(result.n_logs), dict(result.counts), str(result.out_dir), tuple(result.notes),
                   {k: str(v) for k, v in result.outputs.items()}, tuple(rows.to_dict(orient="records")))

    def to_json(self) -> dict[str, Any]:
        """``{"schema_version", "logs", "counts", "out_dir", "notes", "outputs", "rows"}``."""
        return {"schema_version": SUMMARY_SCHEMA_VERSION, "logs": self.logs, "counts": dict(self.counts),
                "out_dir": self.out_dir, "notes": list(self.notes), "outputs": dict(self.outputs),
                "rows": [dict(r) for r in self.rows]}

    @classmethod
    def from_json(cls, data: Any) -> BatchSummary:
        """The record of a :meth:`to_json` dict (one without ``schema_version``, written before it, too).

        Raises
        ------
        InputError
            Not a batch summary, or a version this one does not read (one line).
        """
        d = check_schema_version(data, "batch summary", SUMMARY_SCHEMA_VERSION, missing=SUMMARY_SCHEMA_VERSION,
                                 fix="pass the output of 'mrft-ident batch --json'")
        try:
            return cls(int(d["logs"]), {str(k): int(v) for k, v in d["counts"].items()}, str(d["out_dir"]),
                       tuple(str(n) for n in d["notes"]), {str(k): str(v) for k, v in d["outputs"].items()},
                       tuple(dict(r) for r in d["rows"]))
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise InputError(f"malformed batch summary: {type(err).__name__} {err}; "
                             "pass the output of 'mrft-ident batch --json'") from None
