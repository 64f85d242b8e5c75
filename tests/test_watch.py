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

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import analyze_path
from mrftcli.errors import LogReadError
from mrftcli.io import ReadOptions, read_flight
from mrftcli.watch import EstimateUpdate, TestUpdate, WatchEnd, WatchOptions, watch


def _follow(writer, **kw):
    out = []
    for u in watch(writer.dst, 0.0422, options=WatchOptions(**kw), sleep=writer.sleep, clock=writer.clock):
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
    assert live and abs(live[-1].tau - truth["tau"]) < 2e-3
    final = [u for u, _ in got if isinstance(u, EstimateUpdate) and u.final]
    assert len(final) == 1
    ref = analyze_path(src, soiptd_model(0.0422))
    assert final[0].tau == pytest.approx(ref.tau.mean, rel=1e-9)
    assert final[0].Td == pytest.approx(ref.Td.mean, rel=1e-9)
    end = got[-1][0]
    assert isinstance(end, WatchEnd) and end.reason == "closed" and end.exit_code == 0


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
        list(watch(tmp_path / "none.mcap", 0.04, options=WatchOptions(wait=3.0), sleep=lambda dt: None, clock=lambda: float(next(clock))))


def test_cli_jsonl_prints_one_object_per_update(repo_root, capsys):
    code, out, err = _cli(capsys, "watch", str(repo_root / "sample_logs" / "design1_altitude.mcap"), "--tp", "0.0422",
                          "--jsonl")
    assert code == 0, err
    rows = [json.loads(line) for line in out.splitlines()]
    assert rows[-1] == {**rows[-1], "kind": "end", "reason": "closed"}
    assert [r["kind"] for r in rows[-2:]] == ["estimate", "end"] and rows[-2]["final"] is True
    assert err == ""


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
