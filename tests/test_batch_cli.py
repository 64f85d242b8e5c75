"""``mrft-ident batch`` on the command line: exit codes, one-line errors, option plumbing, --json."""

from __future__ import annotations

import contextlib
import json
import socket
import subprocess
import sys
import types
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from click.testing import CliRunner
from cli_helpers import run_cli, run_main

from mrftcli.cli.main import cli
from test_batch import toy_analysis


def mrft(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mrftcli", *args], cwd=cwd, capture_output=True, text=True, timeout=120)


def test_bad_log_exits_8_with_one_line_and_rows_written(tmp_path: Path) -> None:
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "broken.mcap").write_bytes(b"\x00not an mcap file at all")
    with contextlib.chdir(tmp_path):  # main() in this process (one log, --jobs 1: batch runs it here too)
        p = run_main("batch", "logs", "--tp", "0.04", "--out", "out", "--jobs", "1", "--json")
    assert p.returncode == 8, p.stderr
    assert "Traceback" not in p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: 1 of 1 logs failed (first: broken.mcap [altitude]: ")
    doc = json.loads(p.stdout)
    assert doc["counts"]["failed"] == 1 and doc["rows"][0]["status"] == "failed" and doc["rows"][0]["error"]
    assert pd.read_csv(tmp_path / "out" / "summary.csv")["status"].tolist() == ["failed"]
    # the summary is a versioned record (schema 1); one written before it was (no schema_version) still reads
    from mrftcli.batch import SUMMARY_SCHEMA_VERSION, BatchSummary
    from mrftcli.errors import InputError

    assert list(doc)[0] == "schema_version" and doc["schema_version"] == SUMMARY_SCHEMA_VERSION == 1
    summary = BatchSummary.from_json(doc)
    assert summary.to_json() == doc and summary.rows[0]["status"] == "failed" and summary.logs == 1
    unversioned = {k: v for k, v in doc.items() if k != "schema_version"}
    assert BatchSummary.from_json(unversioned) == summary
    with pytest.raises(InputError, match="batch summary: schema_version 2 is not supported"):
        BatchSummary.from_json({**doc, "schema_version": 2})


@pytest.mark.parametrize("args, code, message", [
    (["--config", "cfg.toml"], 2, "cfg.toml: [defaults]: unknown key 'tpp'"),
    (["--tp", "0.04", "nothing*.mcap"], 2, "matches no files"),
    ([], 2, "no Tp given"),
    (["--tp", "0.04", "--jobs", "0"], 2, "--jobs"),
])
def test_input_errors_are_one_line(tmp_path: Path, capsys, monkeypatch, args: list[str], code: int,
                                   message: str) -> None:
    """Refused before any log is read: the CLI in this process (cli_helpers.run_cli, the same main())."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "a.mcap").write_bytes(b"x")
    (tmp_path / "cfg.toml").write_text("[defaults]\ntpp = 0.1\n")
    got, _, err = run_cli(capsys, "batch", "logs", "--out", "out", *args)
    assert got == code and "Traceback" not in err
    assert message in err


def test_unreachable_scheduler_exit_2(tmp_path: Path) -> None:
    (tmp_path / "a.mcap").write_bytes(b"x")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    p = mrft("batch", "a.mcap", "--tp", "0.04", "--scheduler", f"tcp://127.0.0.1:{port}",
             "--scheduler-timeout", "1", cwd=tmp_path)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert f"error: cannot reach the Dask scheduler at tcp://127.0.0.1:{port} within 1 s" in p.stderr


# --------------------------------------------------------------------------------------------------
# Option plumbing through the real analyze_one, with a stand-in analysis module
# --------------------------------------------------------------------------------------------------


class _R:
    kind = "soiptd"  # an eq. (2) analysis, as AnalysisResult.kind says

    def __init__(self, d):
        self._d = d

    def to_json(self):
        return self._d


def _stand_in(path, model, *, read, options, loop_hint=True):
    # Echo the settings back as "parameters" so the test sees what reached the analysis.
    Tp = model.Tp
    return _R(toy_analysis(Tp, 0.05, read.output_scale or 1.0, Tp, ((-0.4, 8),), std=(0.0, 0.001, 0.0),
                           command_topic=read.command_topic))


@pytest.fixture
def stand_in(monkeypatch):
    from mrftcli.analyze.options import AnalyzeOptions

    mod = types.ModuleType("mrftcli.analyze")
    mod.analyze_path = _stand_in
    mod.AnalyzeOptions = AnalyzeOptions
    mod.refuse_rejected_tp = lambda result, accept=False: result  # a stand-in analysis has no verdict on Tp
    monkeypatch.setitem(sys.modules, "mrftcli.analyze", mod)


def test_cli_options_override_config(tmp_path: Path, stand_in, monkeypatch) -> None:
    for v in ("q1", "q2"):
        (tmp_path / "logs" / v).mkdir(parents=True)
        (tmp_path / "logs" / v / "f.mcap").write_bytes(b"x")
    (tmp_path / "logs" / "batch.toml").write_text(
        "[defaults]\ntp = 0.04\n\n[[logs]]\nmatch = 'q2/*'\ntp = 0.05\nloop = ['roll', 'pitch']\noutput_scale = 2.0\n"
    )
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    args = ["batch", "logs", "--config", "logs/batch.toml", "--out", "out", "--jobs", "1", "--no-report", "--quiet"]
    r = runner.invoke(cli, args + ["--json"])
    assert r.exit_code == 0, r.output
    rows = json.loads(r.stdout)["rows"]
    got = [(Path(x["path"]).parent.name, x["loop"], x["Td_mean"], x["K_mean"]) for x in rows]
    assert got == [("q1", "altitude", 0.04, 1.0), ("q2", "roll", 0.05, 2.0), ("q2", "pitch", 0.05, 2.0)]
    # Explicit --tp/--loop beat the config; the settings change makes every log recompute.
    r = runner.invoke(cli, args + ["--json", "--tp", "0.07", "--loop", "altitude"])
    rows = json.loads(r.stdout)["rows"]
    assert [(x["loop"], x["Td_mean"], x["K_mean"], x["status"]) for x in rows] == [
        ("altitude", 0.07, 1.0, "ok"), ("altitude", 0.07, 2.0, "ok")]
    # Same again: nothing to do, exit 0, the table and one summary line.
    r = runner.invoke(cli, args + ["--tp", "0.07", "--loop", "altitude"])
    assert r.exit_code == 0
    assert r.stdout.count("skipped-uptodate") == 2
    assert "2 log(s), 2 row(s): 2 skipped-uptodate" in r.stderr


def test_cli_scheduler_runs_on_a_local_dask_cluster(tmp_path: Path, stand_in, monkeypatch) -> None:
    distributed = pytest.importorskip("distributed")
    for v in ("q1", "q2"):
        (tmp_path / "logs" / v).mkdir(parents=True)
        (tmp_path / "logs" / v / "f.mcap").write_bytes(b"x")
    (tmp_path / "logs" / "q2" / "f.mcap").with_name("e.mcap").write_bytes(b"x")
    monkeypatch.chdir(tmp_path)
    # In-process workers (processes=False) see the stand-in analysis module; the client still talks TCP.
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, host="127.0.0.1",
                                  protocol="tcp://", dashboard_address=None, silence_logs=40) as cluster:
        r = CliRunner().invoke(cli, ["batch", "logs", "--tp", "0.05", "--out", "out", "--no-report", "--json",
                                     "--scheduler", cluster.scheduler_address, "--scheduler-timeout", "10"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    assert doc["counts"]["ok"] == 3 and [Path(x["path"]).name for x in doc["rows"]] == ["f.mcap", "e.mcap", "f.mcap"]
    assert all(x["Td_mean"] == 0.05 for x in doc["rows"])  # Tp reached the analysis on the cluster


def test_mixed_fleet_skips_a_loop_whose_topics_are_absent(tmp_path: Path) -> None:
    """Issue 25: an altitude log and a roll log asked for both loops: each log's other loop is skipped
    ("skipped: no <loop> topics"), not failed, and the batch exits 0."""
    import shutil

    samples = Path(__file__).resolve().parents[1] / "sample_logs"
    (tmp_path / "fleet").mkdir()
    for name in ("design1_altitude.mcap", "design1_roll.mcap"):
        shutil.copy(samples / name, tmp_path / "fleet" / name)
    r = CliRunner().invoke(cli, ["batch", str(tmp_path / "fleet"), "--tp", "0.0422", "--loop", "altitude",
                                 "--loop", "roll", "--out", str(tmp_path / "out"), "--jobs", "1",
                                 "--no-report", "--json", "-", "-q"])
    assert r.exit_code == 0, r.output
    data = json.loads(r.stdout)
    status = {(Path(row["path"]).name, row["loop"]): (row["status"], row["error"]) for row in data["rows"]}
    assert status[("design1_altitude.mcap", "altitude")][0] == "ok"
    assert status[("design1_roll.mcap", "roll")][0] == "ok"
    # the roll log has no /mocap/pose, the altitude log no /imu/data
    assert status[("design1_roll.mcap", "altitude")] == ("skipped-no-topics",
                                                          "skipped: no altitude topics (/mocap/pose:pose.position.z)")
    assert status[("design1_altitude.mcap", "roll")] == ("skipped-no-topics",
                                                          "skipped: no roll topics (/imu/data:orientation)")
    assert data["counts"]["failed"] == 0 and data["counts"]["skipped-no-topics"] == 2



def _batch_loop_auto(tmp_path: Path, names: tuple[str, ...]) -> Any:
    """``batch --loop auto`` (one job, JSON summary on stdout) over copies of these sample logs."""
    import shutil

    samples = Path(__file__).resolve().parents[1] / "sample_logs"
    (tmp_path / "fleet").mkdir()
    for name in names:
        shutil.copy(samples / name, tmp_path / "fleet" / name)
    return CliRunner().invoke(cli, ["batch", str(tmp_path / "fleet"), "--tp", "0.0422", "--loop", "auto",
                                    "--out", str(tmp_path / "out"), "--jobs", "1", "--no-report", "--json", "-", "-q"])


def test_loop_auto_finds_the_loops_from_the_topics(tmp_path: Path) -> None:
    """--loop auto: each log's loops whose topics it holds; a loop whose output does not follow the relay
    is skipped (no MRFT test on it), the tested one identified near the simulation's truth."""
    samples = Path(__file__).resolve().parents[1] / "sample_logs"
    r = _batch_loop_auto(tmp_path, ("design1_altitude.mcap", "design1_roll.mcap"))
    assert r.exit_code == 0, r.output
    rows = json.loads(r.stdout)["rows"]
    status = {(Path(row["path"]).name, row["loop"]): row["status"] for row in rows}
    assert status == {("design1_altitude.mcap", "altitude"): "ok", ("design1_altitude.mcap", "x"): "skipped-no-tests",
                      ("design1_altitude.mcap", "y"): "skipped-no-tests", ("design1_roll.mcap", "roll"): "ok",
                      ("design1_roll.mcap", "pitch"): "skipped-no-tests"}
    for row in rows:
        if row["status"] == "ok":
            truth = json.loads((samples / (Path(row["path"]).name + ".truth.json")).read_text())
            td = truth["Td"]
            assert abs(row["Td_mean"] - td) < 0.1 * td, (row["loop"], row["Td_mean"], td)


def test_mat_logs_found_and_identified_rows_first(tmp_path: Path) -> None:
    """Issue 40 item 3: a folder's .mat log is discovered (analyze reads it); the table lists the
    identified loops first and each log's loops without tests on one line after it."""
    import shutil

    samples = Path(__file__).resolve().parents[1] / "sample_logs"
    (tmp_path / "fleet").mkdir()
    for name in ("dnn_altitude.mat", "design1_altitude.mcap"):
        shutil.copy(samples / name, tmp_path / "fleet" / name)
    config = tmp_path / "fleet.toml"  # each log's own Tp (a wrong one is refused: issue 40 item 6)
    config.write_text('[defaults]\ntp = 0.0422\n\n[[logs]]\nmatch = "dnn_altitude.mat"\ntp = 0.0499\n')
    r = CliRunner().invoke(cli, ["batch", str(tmp_path / "fleet"), "--config", str(config), "--out", str(tmp_path / "out"),
                                 "--jobs", "1", "--no-report", "-q"])
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    assert [line.split()[:3] for line in lines[2:4]] == [["design1_altitude.mcap", "altitude", "ok"],
                                                         ["dnn_altitude.mat", "altitude", "ok"]]
    # eq. (2)'s K in its records' unit (the column has no room for it), then the loops without tests
    assert lines[4:] == ["K in output / (command s^2) (eq. (2))", "skipped design1_altitude.mcap: x, y (no MRFT test on them)"]
    truth = json.loads((samples / "dnn_altitude.mat.truth.json").read_text())
    assert abs(float(lines[3].split()[5]) - truth["Td"]) < 0.1 * truth["Td"]


@pytest.mark.parametrize("case", ["bad config", "missing config", "no logs", "--vehicle with --loop", "bad --fail-on",
                                  "a file in the way"])
def test_a_refused_run_creates_no_output_folder(tmp_path: Path, capsys, monkeypatch, case: str) -> None:
    """Issue 35: every check comes before --out is created, so a refusal leaves nothing behind. The CLI runs
    in this process (cli_helpers.run_cli: the same main(), its exit code and stderr; no import CPU per case)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "a.csv").write_text("t,u,y\n0,0,0\n")
    (tmp_path / "bad.toml").write_text("[defaults]\ntp = 0.04\nnot_a_setting = 1\n")
    out = tmp_path / "new" / "out"
    args = {"bad config": ["logs", "--config", "bad.toml"], "missing config": ["logs", "--config", "none.toml"],
            "no logs": [str(tmp_path / "empty*"), "--tp", "0.04"],
            "--vehicle with --loop": ["logs", "--tp", "0.04", "--vehicle", "--loop", "x"],
            "bad --fail-on": ["logs", "--tp", "0.04", "--fail-on", "tau:lots"],
            "a file in the way": ["logs", "--tp", "0.04"]}[case]
    if case == "a file in the way":  # a file where a parent of --out would be
        (tmp_path / "new").write_text("notes")
        out = tmp_path / "new" / "sub" / "out"
    code, _, err = run_cli(capsys, "batch", *args, "--out", str(out), "--jobs", "1", "--no-report", "-q")
    assert code == 2, (case, err)
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not (tmp_path / "new").exists() or (tmp_path / "new").is_file(), case



def test_a_skipped_loop_says_nothing_of_giving_loop(tmp_path: Path) -> None:
    """batch tries every loop itself: a CSV holding z alone has its x and y loops skipped with the columns
    it lacks, and a roll log its untested pitch loop with why, without the one-loop commands' hints to give
    --loop (which analyze still prints)."""
    r = _batch_loop_auto(tmp_path, ("design1_altitude.csv", "design1_roll.mcap"))
    assert r.exit_code == 0, r.output
    rows = {row["loop"]: row for row in json.loads(r.stdout)["rows"]}
    assert rows["altitude"]["status"] == "ok" and rows["roll"]["status"] == "ok"
    assert rows["pitch"]["status"] == "skipped-no-tests" and "pitch does not follow them" in rows["pitch"]["error"]
    assert "--loop" not in rows["pitch"]["error"], rows["pitch"]["error"]
    for loop in ("x", "y"):
        assert rows[loop]["status"] == "skipped-no-topics"
        assert f"no column for /mocap/pose:pose.position.{loop}" in rows[loop]["error"]
        assert "--loop" not in rows[loop]["error"], rows[loop]["error"]
    single = CliRunner().invoke(cli, ["analyze", str(tmp_path / "fleet" / "design1_altitude.csv"), "--tp", "0.0422",
                                      "--loop", "x"])
    assert single.exit_code != 0 and "for another loop give --loop" in str(single.exception or single.output)
