"""mrft-ident watch: following a log while it grows (the writer is simulated by the injected sleep).

Oracles: the sample logs' truth sidecars and ``analyze`` on the finished file (the final update must
be the same analysis).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from cli_helpers import LiveWriter, run_cli as _cli

from mrftcli.jsonable import to_jsonable
from mrftcli.mrft.model import soiptd_model
from mrftcli.mrft.parameter import JSON_KEYS
from mrftcli.analyze import analyze_path
from mrftcli.errors import LogReadError
from mrftcli.io import ReadOptions, read_flight
from mrftcli.watch import EstimateUpdate, TestUpdate, WatchEnd, WatchOptions, watch

EQ2 = soiptd_model(0.0422)


def _follow(writer, **kw):
    out = []
    for u in watch(writer.dst, EQ2, options=WatchOptions(**kw), sleep=writer.sleep, clock=writer.clock):
        out.append((u, min(writer.pos, len(writer.data))))
    return out


def test_mcap_tests_and_estimate_arrive_before_the_file_is_complete(repo_root, tmp_path):
    src = repo_root / "sample_logs" / "design1_altitude.mcap"
    truth = json.loads(src.with_name(src.name + ".truth.json").read_text())
    # odd slices cut records and chunks anywhere: a half-written chunk must be waited for, not fatal
    w = LiveWriter(src.read_bytes(), tmp_path / "live.mcap", 7919)
    got = _follow(w, idle=5.0)
    tests = [(u, pos) for u, pos in got if isinstance(u, TestUpdate)]
    assert tests and tests[0][0].number == 1 and tests[0][1] < len(w.data)
    assert tests[0][0].beta_nominal == pytest.approx(-0.4)
    assert {u.number for u, _ in tests} == {1, 2}
    live = [u for u, _ in got if isinstance(u, EstimateUpdate) and not u.final]
    assert live and abs(_values(live[-1])["tau"] - truth["tau"]) < 2e-3
    final = [u for u, _ in got if isinstance(u, EstimateUpdate) and u.final]
    assert len(final) == 1
    ref = analyze_path(src, EQ2)
    assert final[0].analysis is not None and final[0].analysis.tests == ref.tests
    got_final = {e.name: e for e in final[0].parameters}
    for name in ("Td", "tau", "K"):  # the final update is analyze's estimate, its spread included
        ours, theirs = got_final[name], getattr(ref, name)
        assert (ours.value, ours.std, ours.ci95_low) == pytest.approx((theirs.value, theirs.std, theirs.ci95_low),
                                                                       rel=1e-9), name
    assert got_final["Tp"].known and got_final["Tp"].value == 0.0422
    end = got[-1][0]
    assert isinstance(end, WatchEnd) and end.reason == "closed" and end.exit_code == 0


def _values(update):
    return {e.name: e.value for e in update.parameters}


def test_csv_stops_after_idle_and_survives_half_written_rows(repo_root, tmp_path):
    src = repo_root / "sample_logs" / "design1_altitude.csv"
    w = LiveWriter(src.read_bytes(), tmp_path / "live.csv", 40011)  # slices end in the middle of rows
    got = _follow(w, idle=0.5, poll=0.05)
    end = got[-1][0]
    assert isinstance(end, WatchEnd) and end.reason == "idle" and end.exit_code == 0
    assert any(isinstance(u, EstimateUpdate) and u.final for u, _ in got)


def test_a_file_that_never_appears_is_a_one_line_error(tmp_path):
    clock = iter(range(1000))
    with pytest.raises(LogReadError, match="no such file"):
        list(watch(tmp_path / "none.mcap", soiptd_model(0.04), options=WatchOptions(wait=3.0), sleep=lambda dt: None, clock=lambda: float(next(clock))))


def test_cli_jsonl_prints_one_object_per_update(repo_root, capsys):
    code, out, err = _cli(capsys, "watch", str(repo_root / "sample_logs" / "design1_altitude.mcap"), "--tp", "0.0422",
                          "--jsonl")
    assert code == 0, err
    rows = [json.loads(line) for line in out.splitlines()]
    assert rows[-1] == {**rows[-1], "kind": "end", "reason": "closed"}
    assert [r["kind"] for r in rows[-2:]] == ["estimate", "end"] and rows[-2]["final"] is True
    assert err == ""
    # one line shape for every family: schema 2, each parameter the one record, analyze --json's record at the end
    assert {r["schema_version"] for r in rows} == {2}
    final = rows[-2]
    assert final["model"] == "soiptd" and list(final["parameters"]) == ["Tp", "Td", "tau", "K"]
    assert all(list(p) == list(JSON_KEYS) for p in final["parameters"].values())
    assert final["parameters"]["Tp"] == {**final["parameters"]["Tp"], "value": 0.0422, "known": True}
    assert len(final["analysis"]["tests"]) == 2 and all("held_out" in t for t in final["analysis"]["tests"])
    for row in rows[:-1]:  # each line reads back as its record
        record = {"test": TestUpdate, "estimate": EstimateUpdate}[row["kind"]].from_json(row)
        assert json.loads(json.dumps(to_jsonable(record.to_json()))) == row


def test_ctrl_c_stops_cleanly_with_one_line(repo_root, tmp_path):
    import select
    import signal
    import time

    log = tmp_path / "still.csv"
    log.write_bytes((repo_root / "sample_logs" / "design1_altitude.csv").read_bytes()[:200000])
    proc = subprocess.Popen([sys.executable, "-m", "mrftcli.cli", "watch", str(log), "--tp", "0.0422", "--idle", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # interrupt once it is watching (its first test printed), not while a loaded machine still imports
    ready, _, _ = select.select([proc.stdout], [], [], 120.0)
    assert ready, "watch printed nothing in 120 s"
    first = proc.stdout.readline()
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    out = first + out
    assert proc.returncode == 130
    assert err.count("\n") == 1 and "interrupted" in err and "Traceback" not in err


def test_cli_text_prints_each_test_at_its_own_start_from_the_log_start(repo_root, capsys):
    """The time on a test's line is where analyze (and the truth sidecar) puts it, not the previous boundary."""
    log = repo_root / "sample_logs" / "design1_altitude.mcap"
    truth = json.loads(log.with_name(log.name + ".truth.json").read_text())
    code, out, err = _cli(capsys, "watch", str(log), "--tp", "0.0422")
    assert code == 0, err
    starts = {}
    for line in out.splitlines():
        if line.startswith("test "):
            words = line.split()
            starts[int(words[1])] = float(words[3])
            assert " m  cycles" in line  # the amplitude's unit
    t0 = read_flight(log, ReadOptions(loop="altitude")).command.t[0]
    for i, x in enumerate(truth["tests"], start=1):
        assert starts[i] == pytest.approx(x["t_start"] - t0, abs=0.1)
    assert starts[1] > 1.0  # not 0.0: the first test does not start at the log's first sample
    # the lines every family prints: the model first, the final with its spread, each test held out
    lines = out.splitlines()
    assert lines[0].startswith("model soiptd: G(s) = K Td e^{-tau s}") and lines[0].endswith("amplitudes in m")
    final = next(line for line in lines if line.startswith("final"))
    assert "Tp 0.0422 s (known)" in final and "m/s² per command unit" in final and final.count("±") == 3
    # tau in ms, as analyze prints it (the --jsonl numbers stay in s): every estimate line, the final's equal to
    # analyze's table of the same log
    import re

    estimates = [line for line in lines if line.startswith(("estimate", "final"))]
    assert estimates and all(re.search(r" tau [-\d.e+]+( ± [\d.e+-]+)? ms ", line) for line in estimates)
    code, table, _ = _cli(capsys, "analyze", str(log), "--tp", "0.0422")
    row = next(line.split() for line in table.splitlines() if line.split()[:2] == ["tau", "ms"])
    assert re.search(r" tau (\S+) ± (\S+) ms ", final).groups() == (row[2], row[3])
    assert sum(line.startswith("held-out test") for line in lines) == 2
