"""CI over ``sample_logs/``: ``mrft-ident batch`` on every shipped log, checked against the sidecars.

Each simulated log has a ground-truth sidecar ``<log>.truth.json`` (written by the simulator). The test
gives batch only what a user would know from a bench test, Tp and the loop, through a generated
per-log config file (which also exercises the config path); Td, tau and K from the sidecar are used
only to check the results. The tool never reads the sidecars.

* clean logs (no simulated effect, two or more betas): status ok, tau within 2 ms (or two of its reported std, where
  that is wider: a log at 10 Hz), K within 5 %, and
  the true Td inside the reported spread (mean +/- max(3 std, 5 % of the mean));
* logs with a concealed effect: the linear model is knowingly incomplete there, so only "no internal
  error" is required (a clean ``MrftError`` failure or a result);
* logs without a sidecar (deliberately broken files): a row with a clean one-line error, never an
  internal error, and the batch went on.
"""

from __future__ import annotations

import glob
import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

# MRFT_SAMPLE_LOGS points the test at another folder of simulated logs (for developers).
SAMPLE = Path(os.environ.get("MRFT_SAMPLE_LOGS", Path(__file__).resolve().parents[1] / "sample_logs")).resolve()

pytestmark = pytest.mark.slow


def _sidecar(log: Path) -> dict | None:
    side = log.with_name(log.name + ".truth.json")
    return json.loads(side.read_text()) if side.is_file() else None


def _ci_selection(logs: list[Path]) -> list[Path]:
    """A varied few: the first log of each (folder, flight stack, file or folder) and each kind of broken file.

    Every clean log is also analysed one by one in test_analyze_sample_logs.py (every format of design1's
    altitude flight, each against its sidecar; the SITL logs in test_sitl_logs.py and test_sitl_px4_logs.py);
    batch's own job here is the machinery (config matching, processes, rows, report) and "no internal
    error" on every kind. In the top folder a name's prefix is its writer, and one file of each writer (with
    a log that is a folder, a ROS 2 bag, beside it) is enough for that: the same flight in four more
    containers would redo the same analysis through readers tested on their own. In a subfolder
    (concealed/, sitl/) the prefix is a flight or a loop, so there the format alone tells the writers apart
    (one DataFlash and one ULog from SITL).
    """
    seen, chosen = set(), []
    for log in sorted(logs):
        # design1, design2, px4, hear, dnn: the writers differ
        top = log.parent == SAMPLE
        stack = log.name.split("_")[0].split(".")[0] if top else ""
        form = "folder" if not log.is_file() else "file" if top else "".join(log.suffixes[-2:])
        kind = (log.parent, stack if stack != "design2" else "design1", form, _sidecar(log) is None)
        if kind not in seen:
            seen.add(kind)
            chosen.append(log)
    return chosen


@pytest.fixture(scope="module")
def batch_run(tmp_path_factory, sweep_size):
    from mrftcli.batch.inputs import discover_logs

    try:
        logs = discover_logs([SAMPLE])
    except Exception as err:  # noqa: BLE001 - folder missing or empty
        pytest.skip(f"sample_logs/ holds no logs yet ({err})")
    if sweep_size(1, 0) == 0:  # the CI size (--full-sweeps: every log)
        logs = _ci_selection(list(logs))
    tmp = tmp_path_factory.mktemp("batch_sample")
    lines = ["[defaults]", "tp = 0.05  # only logs with a sidecar are checked; the rest just need a row", ""]
    truths = {}
    for log in logs:
        truth = _sidecar(log)
        truths[str(log)] = truth
        if truth is None:
            continue
        # a pattern with "/" matches the log's absolute path (glob characters escaped)
        lines += ["[[logs]]", f"match = {json.dumps(glob.escape(str(log)))}", f"tp = {float(truth['Tp'])!r}",
                  f"loop = {json.dumps(truth['loop'])}", ""]
    cfg = tmp / "sample_logs.toml"
    cfg.write_text("\n".join(lines))
    out = tmp / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "mrftcli", "batch", *map(str, logs), "--config", str(cfg), "--out", str(out), "--jobs", "2",
         "--json", "--quiet"],
        capture_output=True, text=True, timeout=900,
    )
    return proc, out, truths


def test_batch_runs_over_sample_logs_without_internal_errors(batch_run) -> None:
    proc, out, truths = batch_run
    assert proc.returncode in (0, 8), proc.stderr
    assert "Traceback" not in proc.stderr
    summary = pd.read_csv(out / "summary.csv")
    assert sorted(set(summary["path"])) == sorted(truths)
    internal = summary[summary["error_type"] == "internal"]
    assert internal.empty, internal[["path", "error"]].to_string()
    # exit code 8 exactly when some rows failed
    assert (proc.returncode == 8) == bool((summary["status"] == "failed").any())
    assert (out / "summary.parquet").is_file() and (out / "report" / "index.html").is_file()


def test_clean_sample_logs_match_their_sidecars(batch_run) -> None:
    proc, out, truths = batch_run
    summary = pd.read_csv(out / "summary.csv")
    checked = 0
    problems = []
    for _, row in summary.iterrows():
        truth = truths.get(row["path"])
        if truth is None or truth.get("effects_active") or row["loop"] != truth["loop"]:
            continue
        betas = {round(t["beta"], 6) for t in truth.get("tests", []) if not t.get("aborted")}
        if len(betas) < 2:
            if row["status"] not in ("insufficient", "failed"):
                problems.append(f"{row['path']}: one beta but status {row['status']}")
            continue
        checked += 1
        name = Path(row["path"]).name
        if row["status"] != "ok":
            problems.append(f"{name}: {row['status']}: {row['error']}")
            continue
        # 2 ms, or two of tau's own std where the log cannot do better (PX4's 10 Hz log: std 7-8 ms)
        if abs(row["tau_mean"] - truth["tau"]) > max(0.002, 2 * row["tau_std"]):
            problems.append(f"{name}: tau {row['tau_mean'] * 1e3:.2f} ± {row['tau_std'] * 1e3:.2f} ms vs true "
                            f"{truth['tau'] * 1e3:.2f} ms")
        if abs(row["K_mean"] / truth["K"] - 1) > 0.05:
            problems.append(f"{name}: K {row['K_mean']:.4g} vs true {truth['K']:.4g}")
        half = max(3 * row["Td_std"], 0.05 * row["Td_mean"])
        if not row["Td_mean"] - half <= truth["Td"] <= row["Td_mean"] + half:
            problems.append(f"{name}: Td {row['Td_mean']:.3f} +/- {half:.3f} s excludes true {truth['Td']:.3f} s")
    if checked == 0:
        pytest.skip("sample_logs/ has no clean simulated log with two betas and a sidecar")
    assert not problems, "\n".join(problems)
