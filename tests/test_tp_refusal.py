"""Issue 40 item 6: a Tp the recording rejects is a refusal (exit 5, naming the better Tp) unless
``--accept-tp``; analyze, batch and vehicle alike, and the JSON says which.

Oracle: design1_altitude.mcap is simulated with Tp = 0.0422 s (its truth file); --tp 0.1 is wrong.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from cli_helpers import run_cli

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"
LOG = SAMPLES / "design1_altitude.mcap"
TRUE_TP = json.loads((SAMPLES / "design1_altitude.mcap.truth.json").read_text())["Tp"]


def _best_tp(message: str) -> float:
    """The Tp a refusal names in its ``rerun with --tp X``."""
    return float(message.split("rerun with --tp ")[1].split(",")[0].split()[0])


def test_analyze_refuses_a_wrong_tp_unless_accepted(tmp_path, capsys):
    out = tmp_path / "r.json"
    code, stdout, err = run_cli(capsys, "analyze", str(LOG), "--tp", "0.1", "--json", str(out))
    assert code == 5 and err.count("error:") == 1
    assert _best_tp(err) == pytest.approx(TRUE_TP, rel=0.02)
    assert "tau" not in stdout  # no tight, wrong table
    check = json.loads(out.read_text())["tp_check"]
    assert check["verdict"] == "rejected" and check["given"] == 0.1
    assert check["low"] <= TRUE_TP * 1.01 and check["high"] >= TRUE_TP * 0.99

    code, stdout, err = run_cli(capsys, "analyze", str(LOG), "--tp", "0.1", "--accept-tp", "--json", str(out))
    assert code == 0 and "better than the given 0.1 s" in err
    assert json.loads(out.read_text())["tp_check"]["verdict"] == "accepted"


def test_batch_and_vehicle_refuse_it_too(tmp_path, capsys):
    (tmp_path / "logs").mkdir()
    shutil.copy(LOG, tmp_path / "logs" / LOG.name)
    code, _, err = run_cli(capsys, "batch", str(tmp_path / "logs"), "--tp", "0.1", "--loop", "altitude", "--jobs", "1",
                           "--out", str(tmp_path / "out"), "--no-report", "-q")
    assert code == 8 and "rerun with --tp" in err
    record = json.loads(next((tmp_path / "out" / "logs").glob("*.json")).read_text())
    entry = record["loops"][0]
    assert (entry["status"], entry["exit_code"], entry["error_type"]) == ("failed", 5, "TpRejectedError")
    assert entry["result"]["tp_check"]["verdict"] == "rejected"
    assert _best_tp(entry["error"]) == pytest.approx(TRUE_TP, rel=0.02)

    code, stdout, err = run_cli(capsys, "vehicle", str(LOG), "--tp", "0.1", "-q", "--json", str(tmp_path / "v.json"))
    assert code == 5 and "rerun with --tp" in err
    missing = json.loads((tmp_path / "v.json").read_text())["missing"]["altitude"]
    assert missing["reason"] == "wrong-tp" and "rerun with --tp 0.042" in missing["next_tests"]
