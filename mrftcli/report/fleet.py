"""Fleet report of a batch: parameters per log over time, with outliers flagged (HTML + PNG).

Input is the summary table of :func:`mrftcli.batch.run.run_batch` (one row per log and loop). The time axis
is ``log_time`` (UTC): the log's first time stamp when it is an absolute UNIX time (ROS bags and MCAP
files record wall-clock time), otherwise the file's modification time (a simulator's or a flight
controller's time since boot says nothing about the date); ``log_time_source`` says which. Each vehicle (config ``vehicle``, else the log's
parent folder name) is one colour, its logs joined in time order, so a vehicle whose tau grew shows as a
rising line. Error bars are +/- one standard deviation of the per-combination estimates. Outliers
(``tau_outlier``/``Td_outlier``: robust z-score beyond 3.5 within the loop and more than two of the
log's own standard deviations from the median, see :func:`mrftcli.batch.summary.flag_outliers`) are ringed in
red on the panel of the parameter that is off, and labelled with the log's folder and name.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib.dates as mdates
import numpy as np
import pandas as pd

from ..io.logtypes import gain_unit
from ._common import esc, html_page, html_table, plt, savefig_atomic, write_page

__all__ = ["write_fleet_report", "plot_loop"]

#: (column prefix, axis label, scale to display units)
_PARAMS = (("tau", "tau [ms]", 1e3), ("Td", "Td [s]", 1.0), ("K", "K", 1.0))


def _draw_parameter(ax: Any, d: pd.DataFrame, xs: np.ndarray, by_time: bool, vehicles: list[str], names: list[str],
                    param: tuple[str, str, float]) -> None:
    """One parameter's panel: each vehicle's estimates with their std, changes and fleet outliers marked."""
    name, label, scale = param
    colours = plt.get_cmap("tab10" if len(vehicles) <= 10 else "tab20")
    for i, v in enumerate(vehicles):
        sel = (d["vehicle"].astype(str) == v).to_numpy()
        y = d.loc[sel, f"{name}_mean"].to_numpy(float) * scale
        e = d.loc[sel, f"{name}_std"].to_numpy(float) * scale
        ax.errorbar(xs[sel], y, yerr=np.where(np.isfinite(e), e, 0.0), fmt="o-" if by_time else "o", ms=5,
                    lw=1.2, capsize=3, color=colours(i % colours.N), label=v)
    changed = d[f"{name}_changed"].astype(bool).to_numpy() if f"{name}_changed" in d else np.zeros(len(d), bool)
    if changed.any():
        y = d.loc[changed, f"{name}_mean"].to_numpy(float) * scale
        ax.scatter(xs[changed], y, s=260, marker="s", facecolors="none", edgecolors="black", linewidths=1.5,
                   label="changed vs own history", zorder=4)
    flag = f"{name}_outlier"
    out = d[flag].astype(bool).to_numpy() if flag in d else np.zeros(len(d), bool)
    if out.any():
        y = d.loc[out, f"{name}_mean"].to_numpy(float) * scale
        ax.scatter(xs[out], y, s=180, facecolors="none", edgecolors="red", linewidths=2, label="fleet outlier",
                   zorder=5)
    for k in np.flatnonzero(out | changed):
        yk = float(d.loc[k, f"{name}_mean"]) * scale
        if np.isfinite(yk) and by_time:  # on the log-order axis the tick label names the log
            right = k >= len(d) / 2  # label towards the middle so it stays inside
            ax.annotate(names[k], (xs[k], yk), xytext=(-9 if right else 9, 6), textcoords="offset points",
                        ha="right" if right else "left", fontsize=8, color="red" if out[k] else "black")
    ax.margins(x=0.04, y=0.15)
    ax.set_ylabel(label, fontsize=11)
    ax.grid(True, alpha=0.3)


def _log_order_axis(ax: Any, d: pd.DataFrame, xs: np.ndarray, names: list[str]) -> None:
    """The x axis as the logs in time order, named; outliers in red."""
    # folder and file on two lines; few logs stand upright, many are turned about their tick (so
    # the layout measures them and the first one is not cut at the figure's left edge)
    two_line = [n.replace("/", "/\n", 1) for n in names]
    widest = max((len(line) for n in two_line for line in n.splitlines()), default=0)
    if len(names) * widest <= 90:  # about the characters the axis holds side by side at this font size
        ax.set_xticks(xs, two_line, fontsize=8)
    else:
        # upright text is two lines (about 22 px at 8 pt) wide per log: on the ~700 px axis, name every
        # step-th log (and every outlier) so that no two labels overlap
        step = max(1, math.ceil(len(names) * 24 / 700))
        out = d["outlier"].astype(bool).to_numpy()
        shown = [n if k % step == 0 or out[k] else "" for k, n in enumerate(two_line)]
        ax.set_xticks(xs, shown, rotation=90, ha="center", fontsize=8)
    for tick, is_out in zip(ax.get_xticklabels(), d["outlier"].astype(bool)):
        if is_out:
            tick.set_color("red")
    ax.set_xlabel(f"logs in time order\n({_time_label(d)}; too few distinct times for a time axis)", fontsize=10)


def plot_loop(df: pd.DataFrame, loop: str, path: Path) -> Path:
    """Draw tau, Td and K of one loop against log time, one colour per vehicle; save a PNG.

    When the times do not spread the logs out (all equal, or most logs sharing a time stamp, as with
    copies of one flight or logs without dates) or a log has no time, the x axis is the logs in time
    order, labelled with their names, instead of a time axis on which they would pile up.
    """
    d = df[(df["loop"] == loop) & df["tau_mean"].notna()].sort_values(["log_time", "path"]).reset_index(drop=True)
    times = d["log_time"].dt.tz_convert(None)
    by_time = len(d) > 0 and bool(times.notna().all()) and times.nunique() > max(1, len(d) // 2)
    xs = times.to_numpy() if by_time else np.arange(len(d), dtype=float)
    vehicles = sorted(d["vehicle"].astype(str).unique())
    names = [f"{Path(p).parent.name}/{Path(p).name}" for p in d["path"].astype(str)]
    fig, axes = plt.subplots(3, 1, figsize=(10, 8.5 if by_time else 10), sharex=True, constrained_layout=True)
    params = [p if p[0] != "K" else ("K", f"K [{gain_unit(loop)}]", 1.0) for p in _PARAMS]
    for ax, param in zip(axes, params):
        _draw_parameter(ax, d, xs, by_time, vehicles, names, param)
    axes[0].set_title(f"{loop} loop: identified parameters per log (mean +/- std)", fontsize=12)
    if by_time:
        axes[-1].set_xlabel(_time_label(d), fontsize=11)
        locator = mdates.AutoDateLocator()
        axes[-1].xaxis.set_major_locator(locator)
        axes[-1].xaxis.set_major_formatter(mdates.ConciseDateFormatter(locator))
    else:
        _log_order_axis(axes[-1], d, xs, names)
    legend: dict[str, object] = {}
    for ax in axes:  # vehicles, and "outlier" from whichever panel has one
        for handle, label in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(label, handle)
    if legend:
        axes[0].legend(list(legend.values()), list(legend.keys()), title="vehicle", fontsize=9,
                       loc="upper left", bbox_to_anchor=(1.01, 1.0))
    savefig_atomic(fig, path, dpi=110)
    plt.close(fig)
    return path


def _time_label(d: pd.DataFrame) -> str:
    sources = set(d["log_time_source"].astype(str)) if "log_time_source" in d else {"mtime"}
    if sources == {"log"}:
        return "log start time (UTC)"
    if sources == {"mtime"}:
        return "log time (file modification time, UTC)"
    return "log start time, or file modification time for logs without an absolute time (UTC)"


def _cell(column: str, v: object) -> str:
    """A summary value as table text: tau in ms, numbers to 4 digits, times to the minute, NA blank, a lead
    ``tau < 0`` (else blank)."""
    if column == "lead":
        return "tau < 0" if isinstance(v, (bool, np.bool_)) and v else ""
    if isinstance(v, float):
        return "" if not np.isfinite(v) else (f"{v * 1e3:.2f} ms" if column.startswith("tau") else f"{v:.4g}")
    if v is None or v is pd.NA or (isinstance(v, pd.Timestamp) and pd.isna(v)):
        return ""
    if isinstance(v, pd.Timestamp):
        return v.strftime("%Y-%m-%d %H:%M")
    return str(v)


#: column headers with their units (tau cells carry "ms" themselves)
_HEADERS = {"Td_mean": "Td [s]", "Td_std": "Td std [s]", "tau_mean": "tau", "tau_std": "tau std",
            "K_mean": "K [m or rad /s² per command unit]", "K_std": "K std", "log_time": "log time (UTC)",
            "n_tests": "tests", "n_cycles": "cycles", "lead": "lead (tune designs at tau 0)"}


def _table(df: pd.DataFrame, columns: list[str]) -> str:
    return html_table([_HEADERS.get(c, c) for c in columns],
                      ([_cell(c, row[c]) for c in columns] for _, row in df.iterrows()))


def write_fleet_report(df: pd.DataFrame, out_dir: Path, notes: Sequence[str] = ()) -> Path:
    """Write ``index.html`` and one ``fleet_<loop>.png`` per loop into ``out_dir``; return the HTML path.

    ``notes``: the batch's notes (e.g. the loops identified with a lead), listed first.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    parts: list[str] = []
    counts = df["status"].value_counts()
    parts.append("<p>" + esc(f"{df['path'].nunique()} logs, {len(df)} rows: "
                                      + ", ".join(f"{n} {s}" for s, n in counts.items())) + "</p>")
    if notes:
        parts.append("<ul>" + "".join(f"<li>{esc(n)}</li>" for n in notes) + "</ul>")
    parts.append("<p>Time axis: the log's first time stamp when it is an absolute (UNIX) time, else the file's "
                 "modification time (column log_time_source); UTC. Error bars: +/- one standard deviation. "
                 "Fleet outliers (red rings): modified z-score 0.6745 (x - median) / MAD of tau or Td within the loop beyond "
                 "3.5 and more than two of the log's own standard deviations from the median. Changed against the "
                 "vehicle's own history (black boxes): more than 3 combined standard deviations from the median of "
                 "the vehicle's earlier logs (at least two).</p>")
    outliers = df[df["outlier"].astype(bool)]
    parts.append("<h2>Flagged logs</h2>")
    parts.append(_table(outliers, ["path", "loop", "vehicle", "log_time", "tau_mean", "Td_mean", "outlier_reason"])
                 if len(outliers) else "<p>None.</p>")
    failed = df[df["result_status"] == "failed"]
    if len(failed):
        parts.append("<h2 class='warn'>Failed logs</h2>" + _table(failed, ["path", "loop", "error_type", "error"]))
    for loop in [str(x) for x in df["loop"].dropna().unique()]:
        if not df[(df["loop"] == loop) & df["tau_mean"].notna()].empty:
            png = plot_loop(df, loop, out_dir / f"fleet_{loop}.png")
            parts.append(f"<h2>{esc(loop)}</h2><img src='{png.name}' alt='{esc(loop)} parameters'>")
    parts.append("<h2>All rows</h2>")
    parts.append(_table(df, ["path", "loop", "vehicle", "status", "tau_mean", "tau_std", "lead",
                             "Td_mean", "Td_std", "K_mean", "K_std", "n_tests", "n_cycles", "findings", "log_time", "error"]))
    index = out_dir / "index.html"
    write_page(index, html_page("mrft-ident fleet report", "\n".join(parts)))
    return index
