"""Broken and hostile files through the CLI (tracker issue 29; the full corpus: benchmarks/bench_hostile.py).

The corpus is built by ``scripts/make_hostile_corpus.py`` from the shipped sample logs; each case
here runs the CLI in a capped subprocess (the benchmark's runner) and checks the issue's contract:
no internal error, no library warning on stderr, the input unchanged, and exit 0 only with the
truth's numbers. The oracle of "right numbers" is the simulation's truth sidecar, not the tool.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_main

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_hostile import run_one  # noqa: E402
from make_hostile_corpus import build_corpus  # noqa: E402

from mrftcli.mrft.model import soiptd_model  # noqa: E402
from mrftcli.analyze import AnalyzeOptions  # noqa: E402
from mrftcli.errors import InputError, LogReadError  # noqa: E402
from mrftcli.io import read_flight  # noqa: E402
from mrftcli.io.atomic import write_text_atomic  # noqa: E402
from mrftcli.io.clock import suggest_unit  # noqa: E402
from mrftcli.io.follow import follow_log  # noqa: E402
from mrftcli.io.flight import ReadOptions  # noqa: E402

#: fast cases, each a different failure of the issue (the benchmark runs every case and command)
FAST = {
    "csv_time_ms.csv": ("analyze", "pass --time-unit ms"),
    "mat_time_ms.mat": ("analyze", "pass --time-unit ms"),
    "mcap_mutual_schema.mcap": ("topics", None),
    "mcap_mutual_schema.mcap ": ("analyze", "cannot decode"),
    "mcap_zero_times.mcap": ("analyze", "same time"),
    "mcap_no_schema.mcap": ("analyze", "has no schema"),
    "mat_nx2.mat": ("analyze", "4930 x 2 matrix"),
    "mat_complex.mat": ("analyze", "complex"),
    "mat_length.mat": ("analyze", "4923 samples but its time vector z_t has 4930"),
    "folder_of_logs": ("analyze", "mrft-ident batch"),
    "design1_altitude_noise.csv": ("analyze", None),
    "px4_beta_nan.ulg": ("diagnose", None),
}


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    out = tmp_path_factory.mktemp("hostile") / "corpus"
    names = sorted({n.strip() for n in FAST} | {"csv_1e308.csv"})
    manifest = build_corpus(out, only="^(" + "|".join(map(lambda n: n.replace(".", r"\."), names)) + ")$")
    return out, {e["name"]: e for e in manifest}


@pytest.mark.parametrize("key", list(FAST))
def test_hostile_case_is_refused_or_right(corpus, key):
    out, manifest = corpus
    name = key.strip()
    command, message = FAST[key]
    run = run_one(manifest[name], out, command, timeout=100.0)
    assert not run.internal, run.stderr
    assert not run.hang and not run.big and not run.modified
    assert not run.warned, run.stderr
    assert not run.wrong, run.wrong
    if manifest[name]["expect"] == "refuse" and command != "topics":  # topics lists what it can
        assert run.code in (2, 3, 4, 5, 6, 7), run.stderr
        assert run.stderr.count("\n") == 1, run.stderr  # one line
    if message is not None:
        assert message in run.stderr


def test_a_corrupt_sample_of_1e308_is_left_out_and_the_numbers_stay_right(corpus):
    out, manifest = corpus
    run = run_one(manifest["csv_1e308.csv"], out, "analyze", timeout=100.0)
    assert run.code == 0 and not run.wrong and not run.warned and not run.internal, run.stderr
    assert "beyond +-1e+100" in run.stderr


def test_time_unit_ms_reads_the_times_the_seconds_file_has(corpus):
    out, _ = corpus
    seconds = read_flight(ROOT / "sample_logs" / "design1_altitude.csv", echo_warnings=False)
    ms = read_flight(out / "csv_time_ms.csv", ReadOptions(time_unit="ms"), echo_warnings=False)
    np.testing.assert_allclose(ms.command.t, seconds.command.t, rtol=0, atol=2e-6)
    with pytest.raises(LogReadError, match="--time-unit ms"):
        read_flight(out / "csv_time_ms.csv", echo_warnings=False)
    with pytest.raises(InputError, match="CSV and .mat"):
        read_flight(ROOT / "sample_logs" / "design1_altitude.mcap", ReadOptions(time_unit="ms"))


def test_suggested_unit_is_the_one_that_gives_a_controller_rate():
    # 200 Hz with times in ms, us, ns read as seconds: the inverse factor each time
    assert suggest_unit(200.0 / 1e3, "s") == ("ms", 200.0)
    assert suggest_unit(200.0 / 1e6, "s") == ("us", 200.0)
    assert suggest_unit(200.0 / 1e9, "s") == ("ns", 200.0)
    assert suggest_unit(200.0 * 1e3, "ms") == ("s", 200.0)  # seconds taken for milliseconds
    assert suggest_unit(1e-12, "s") is None


def test_analyze_cli_with_time_unit_gives_the_seconds_file_numbers(corpus):
    out, _ = corpus
    proc = run_main("analyze", str(out / "csv_time_ms.csv"), "--tp", "0.0422", "--time-unit", "ms", "--json", "-")
    assert proc.returncode == 0, proc.stderr
    truth = json.loads((ROOT / "sample_logs" / "design1_altitude.csv.truth.json").read_text())
    got = json.loads(proc.stdout)["parameters"]
    for name in ("Td", "tau", "K"):  # the clean file's own errors are below 15 %
        assert abs(got[name]["value"] / truth[name] - 1) < 0.2, (name, got[name]["value"], truth[name])


# -- watch: a file that does not exist yet, a file replaced by another recording ------------------
def test_watch_waits_for_a_missing_file_then_says_how_long_it_waited(tmp_path):
    env = dict(os.environ)
    proc = subprocess.run([sys.executable, "-m", "mrftcli", "watch", str(tmp_path / "later.csv"), "--tp", "0.0422",
                           "--wait", "0.3"], capture_output=True, text=True, timeout=100, env=env)
    assert proc.returncode == 3
    lines = proc.stderr.strip().splitlines()
    assert lines[0].startswith("waiting for") and "0.3 s" in lines[0]
    assert "no such file after waiting 0.3 s" in lines[1] and "Traceback" not in proc.stderr


def test_watch_without_wait_keeps_waiting_until_the_file_appears(tmp_path):
    from mrftcli.watch import WatchOptions, watch

    log = tmp_path / "late.csv"
    polls = []

    def sleep(dt):  # the logger starts after 1000 polls (20 s at the default poll), later than --idle
        polls.append(dt)
        if len(polls) == 1000:
            log.write_bytes((ROOT / "sample_logs" / "design1_altitude.csv").read_bytes())

    clock = iter(np.arange(1e6) * 0.02)
    updates = list(watch(log, soiptd_model(0.0422), options=WatchOptions(idle=1.0), sleep=sleep, clock=lambda: float(next(clock))))
    assert updates[-1].reason == "idle" and updates[-1].tests == 2 and updates[-1].exit_code == 0


@pytest.mark.parametrize("name", ["design1_altitude.csv", "design1_altitude.mcap"])
def test_follower_starts_over_when_the_file_is_truncated_and_rewritten(tmp_path, name):
    src = (ROOT / "sample_logs" / name).read_bytes()
    log = tmp_path / name
    log.write_bytes(src)
    follower = follow_log(log, ReadOptions())
    first = follower.poll()
    assert first.flight is not None and first.restarted is None
    # another recording under the same name: truncated, then a shorter one written in place
    other = src[:len(src) // 2] if name.endswith(".csv") else (ROOT / "sample_logs" / "design2_altitude.mcap").read_bytes()
    with open(log, "r+b") as fh:
        fh.truncate(0)
        fh.write(other)
    snap = follower.poll()
    assert snap.restarted is not None  # shrank (CSV), or rewritten from its start, already longer (MCAP)
    assert snap.flight is not None
    alone = tmp_path / f"alone_{name}"
    alone.write_bytes(other)
    expected = read_flight(alone, echo_warnings=False).command  # the new recording read on its own
    np.testing.assert_array_equal(snap.flight.command.t, expected.t)
    np.testing.assert_array_equal(snap.flight.command.values, expected.values)


def test_watch_reports_a_restart_and_forgets_the_old_tests(tmp_path):
    from mrftcli.watch import Restart, TestUpdate, WatchOptions, watch

    log = tmp_path / "run.csv"
    log.write_bytes((ROOT / "sample_logs" / "design1_altitude.csv").read_bytes())
    second = (ROOT / "sample_logs" / "design2_altitude.mcap")
    from mrftcli.io import open_log, write_log
    from mrftcli.io.logtypes import TopicData

    with open_log(second) as src:
        t, v = src.read("/mrft/command", ["data"])
        tz, vz = src.read("/mocap/pose", ["pose.position.z"])
    short = tmp_path / "short.csv"
    write_log([TopicData("/mrft/command", "std_msgs/msg/Float64", t[:2000], {"data": v["data"][:2000]}),
               TopicData("/mocap/pose", "geometry_msgs/msg/PoseStamped", tz[:2000],
                         {"pose.position.z": vz["pose.position.z"][:2000]})], short, "csv")
    state = {"n": 0}

    def sleep(dt):
        state["n"] += 1
        if state["n"] == 3:
            log.write_bytes(short.read_bytes())  # smaller: a new recording

    clock = iter(np.arange(1e6) * 0.02)
    updates = list(watch(log, soiptd_model(0.0422), options=WatchOptions(idle=0.5), sleep=sleep, clock=lambda: float(next(clock))))
    kinds = [type(u).__name__ for u in updates]
    assert "Restart" in kinds
    after = updates[kinds.index("Restart") + 1:]
    assert all(u.t_start < 10.0 + t[0] for u in after if isinstance(u, TestUpdate))
    assert isinstance(updates[kinds.index("Restart")], Restart)


# -- atomic writes --------------------------------------------------------------------------------
def test_atomic_write_leaves_the_old_file_whole_when_it_fails(tmp_path):
    target = tmp_path / "result.json"
    target.write_text("old\n")
    write_text_atomic(target, "new\n")
    assert target.read_text() == "new\n"
    folder = tmp_path / "a_folder"
    folder.mkdir()
    with pytest.raises(OSError):
        write_text_atomic(folder, "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_folder", "result.json"]  # no temporary left


@pytest.mark.parametrize("fmt", ["bag", "csv"])
def test_a_simulated_log_killed_while_written_leaves_the_old_log_whole(tmp_path, monkeypatch, fmt):
    """simulate writes a ROS 1 bag chunk by chunk: a run that dies mid-way must not leave a cut bag
    that reads as a shorter flight (issue 29, item 8), nor a temporary file."""
    import mrftcli.io as io
    from mrftcli.io.logtypes import TopicData
    from mrftcli.sim.sidecar import write_log_atomic

    def topics(n):
        t = np.arange(n) * 0.01
        return [TopicData("/mrft/command", "std_msgs/msg/Float64", t, {"data": np.sin(t)})]

    target = tmp_path / f"flight.{fmt}"
    write_log_atomic(topics(50), target, fmt)
    old = target.read_bytes()
    real = io.write_log

    def dies_midway(topics, path, fmt=None, **kw):
        real(topics, path, fmt, **kw)
        Path(path).write_bytes(Path(path).read_bytes()[:100])  # what a kill leaves: the first bytes
        raise KeyboardInterrupt

    monkeypatch.setattr(io, "write_log", dies_midway)
    with pytest.raises(KeyboardInterrupt):
        write_log_atomic(topics(500), target, fmt)
    assert target.read_bytes() == old and [p.name for p in tmp_path.iterdir()] == [target.name]
    monkeypatch.setattr(io, "write_log", real)
    write_log_atomic(topics(500), target, fmt)  # over an existing file (rosbags refuses to overwrite one)
    assert [t.count for t in io.list_topics(target)[1]] == [500]


# -- batch: write what can be written, report the rest --------------------------------------------
def test_batch_writes_every_result_it_can_and_reports_the_rest(tmp_path):
    from test_batch import fake_worker, write_toy

    from mrftcli.batch import run as B
    from mrftcli.batch.inputs import result_path

    fleet = tmp_path / "fleet"
    for name in ("a.csv", "b.csv", "c.csv"):
        write_toy(fleet / name)
    out = tmp_path / "out"
    (out / "logs").mkdir(parents=True)
    blocked = result_path(out, (fleet / "b.csv").resolve())
    blocked.mkdir()  # a folder where b's record goes: that one write fails, the others must not
    res = B.run_batch([fleet], out, options=B.BatchOptions(jobs=1, report=False), defaults={"tp": 0.05},
                        worker=fake_worker)
    assert len(res.unwritten) == 1 and str(blocked) in res.unwritten[0]
    assert res.counts["ok"] == 3  # b's row is kept in the summary
    written = sorted(p.name for p in (out / "logs").iterdir() if p.is_file())
    assert len(written) == 2 and (out / "summary.csv").is_file()
    assert "could not be written" in res.notes[0]


def test_batch_output_logs_being_a_file_is_a_one_line_input_error(tmp_path):
    from test_batch import fake_worker, write_toy

    from mrftcli.batch import run as B

    write_toy(tmp_path / "fleet" / "a.csv")
    out = tmp_path / "out"
    out.mkdir()
    (out / "logs").write_text("not a folder")
    with pytest.raises(InputError, match=r"logs is a file, not a folder"):
        B.run_batch([tmp_path / "fleet"], out, options=B.BatchOptions(jobs=1, report=False), defaults={"tp": 0.05},
                    worker=fake_worker)


def test_a_period_no_vehicle_has_is_refused_as_a_clock_unit():
    from dataclasses import replace

    from mrftcli.analyze import analyze_flight
    from mrftcli.io.logtypes import Signal

    f = read_flight(ROOT / "sample_logs" / "design1_altitude.csv", echo_warnings=False)

    def slow(s):  # a 200 Hz log stamped in units of 10 ms: 2 Hz passes the rate check, periods of 73-130 s
        return Signal(s.t * 100, s.values)

    g = replace(f, command=slow(f.command), output=slow(f.output), beta=slow(f.beta), setpoint=None)
    with pytest.raises(LogReadError, match="limit-cycle period of 129.5 s"):
        analyze_flight(g, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=20))


def test_a_large_csv_read_column_by_column_gives_the_same_flight(monkeypatch):
    from mrftcli.io import format_csv

    path = ROOT / "sample_logs" / "design1_altitude.csv"
    whole = read_flight(path, echo_warnings=False)
    with format_csv.CsvSource(path) as log:
        counts = [(i.name, i.count) for i in log.topics()]
    monkeypatch.setattr(format_csv, "LARGE_CSV_BYTES", 1000)  # every file is "large"
    lazy = read_flight(path, echo_warnings=False)
    for role in ("command", "output", "beta", "setpoint"):
        a, b = getattr(whole, role), getattr(lazy, role)
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_array_equal(a.values, b.values)
    with format_csv.CsvSource(path) as log:
        assert isinstance(log._cols, format_csv._LazyColumns) and not log._cols.loaded  # nothing parsed yet
        assert [(i.name, i.count) for i in log.topics()] == counts
