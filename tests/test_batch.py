"""Batch machinery: discovery, per-log config, resumability, failure isolation, outputs, executors.

The analysis itself is replaced by a small injected worker (``fake_worker``) that reads a toy text log
(``tau=...``/``Td=...`` lines), so these tests check the machinery alone and run in well under a second
each; ``test_batch_sample_logs.py`` runs the real analysis over ``sample_logs/``.
"""

from __future__ import annotations

import json
import os
import sys
import time
import types
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mrftcli.batch import inputs as I
from mrftcli.batch import run as B
from mrftcli.batch import summary as S
from mrftcli.errors import InputError, InsufficientDataError, LogReadError
from mrftcli.jsonable import to_jsonable
from mrftcli.segment import MrftTest, StabilityCriterion
from mrftcli.segment.records import RelayCycle


def toy_analysis(Td: float, tau: float, K: float, Tp: float, tests=((-0.4, 9), (-0.7, 11)), *, std=(0.1, 0.001, 0.0),
                 **extra) -> dict:
    """An analyze RESULT.json (what ``AnalysisResult.to_json`` writes) with these estimates and tests of
    (beta, stable cycles): what the batch reads through ``AnalysisResult.from_json``."""
    def cycles(beta: float, n: int) -> tuple[RelayCycle, ...]:
        return tuple(RelayCycle(t_start=i, t_switch=i + 0.5, t_end=i + 1.0, period=1.0, half_period_high=0.5,
                                half_period_low=0.5, amplitude=0.01, centre=0.0, y_max=0.01, y_min=-0.01,
                                t_max=i + 0.25, t_min=i + 0.75, y_switch_down=0.0, y_switch_up=0.0, beta_down=beta,
                                beta_up=beta, beta_effective=beta, stable=True) for i in range(n))

    rows = [MrftTest(index=k, t_start=0.0, t_end=float(n), h=0.1, bias=0.5, beta_nominal=b, beta_effective=b,
                     beta_effective_std=0.0, rate_hz=200.0, cycles=cycles(b, n), criterion=StabilityCriterion(),
                     period_median=1.0, period_tolerance=0.1, amplitude_median=0.01,
                     amplitude_tolerance=0.001).to_dict() for k, (b, n) in enumerate(tests)]
    est = {name: {"mean": v, "std": s} for name, v, s in (("Td", Td, std[0]), ("tau", tau, std[1]), ("K", K, std[2]))}
    return to_jsonable({"schema_version": 1, "parameters": {**est, "Tp": {"mean": Tp}}, "tests": rows, **extra})

# --------------------------------------------------------------------------------------------------
# A toy log format and a worker for it (module level, so processes and Dask can pickle it)
# --------------------------------------------------------------------------------------------------


def write_toy(path: Path, tau: float = 0.05, Td: float = 1.2, broken: bool = False) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("garbage\x00" if broken else f"tau={tau}\nTd={Td}\n")
    return path


def fake_worker(task: B.LogTask) -> dict:
    """Parse the toy log; K = 1/Tp so the test can see which Tp reached the worker."""
    text = Path(task.path).read_text()
    if "crash" in Path(task.path).name:
        raise RuntimeError("worker blew up")
    loops = []
    for loop in task.settings.loops:
        if "\x00" in text:
            err = LogReadError(f"{Path(task.path).name}: not a toy log")
            loops.append(B.failed_entry(loop, err))
            continue
        values = dict(line.split("=") for line in text.split())
        tau, Td = float(values["tau"]), float(values["Td"])
        loops.append({"loop": loop, "status": "ok", "error": None, "error_type": None, "exit_code": 0,
                      "result": toy_analysis(Td, tau, 1.0 / task.settings.tp, task.settings.tp),
                      "diagnosis": None})
    return B.log_record(task, loops, 0.0)


def killing_worker(task: B.LogTask) -> dict:
    """Like fake_worker, but the process running a log named kill* dies outright."""
    if Path(task.path).name.startswith("kill"):
        os._exit(3)
    return fake_worker(task)


def crashing_worker(task: B.LogTask) -> dict:
    raise RuntimeError("boom")


@pytest.fixture
def fleet(tmp_path: Path) -> Path:
    root = tmp_path / "fleet"
    write_toy(root / "quad1" / "f1.csv", tau=0.050)
    write_toy(root / "quad1" / "f2.csv", tau=0.051)
    write_toy(root / "quad2" / "f1.csv", tau=0.049)  # same name as quad1/f1.csv
    write_toy(root / "quad2" / "bad.csv", broken=True)
    return root


def run(paths, out, **kw):
    """run_batch with the test defaults (one job, no report, the fake worker); BatchOptions fields by keyword."""
    kw.setdefault("defaults", {"tp": 0.05})
    kw.setdefault("worker", fake_worker)
    fields = B.BatchOptions.__dataclass_fields__
    options = B.BatchOptions(**({"jobs": 1, "report": False} | {k: kw.pop(k) for k in list(kw) if k in fields}))
    return B.run_batch(paths if isinstance(paths, list) else [paths], out, options=options, **kw)


# --------------------------------------------------------------------------------------------------
# Discovery
# --------------------------------------------------------------------------------------------------


def test_discovery_folders_suffixes_hidden_and_ros2_bags(tmp_path: Path) -> None:
    root = tmp_path / "logs"
    for name in ("a.mcap", "sub/b.bag", "sub/deep/c.ulg", "d.csv", "e.BIN", "f.bin", "notes.txt",
                 "a.mcap.truth.json", ".hidden/x.mcap", ".y.mcap"):
        write_toy(root / name)
    bag = root / "ros2" / "flight_0"
    write_toy(bag / "metadata.yaml")
    write_toy(bag / "flight_0_0.mcap")  # inside the bag: must not be listed on its own
    found = I.discover_logs([root])
    rel = sorted(p.relative_to(root.resolve()).as_posix() for p in found)
    assert rel == ["a.mcap", "d.csv", "e.BIN", "f.bin", "ros2/flight_0", "sub/b.bag", "sub/deep/c.ulg"]
    # A bag folder given directly is one log too.
    assert I.discover_logs([bag]) == [bag.resolve()]


def test_discovery_globs_explicit_files_dedupe_and_exclude(tmp_path: Path) -> None:
    root = tmp_path / "logs"
    write_toy(root / "v1" / "a.mcap")
    write_toy(root / "v2" / "b.mcap")
    write_toy(root / "v2" / "b.json")
    write_toy(root / "odd.log")
    out = root / "results"
    write_toy(out / "summary.csv")  # the output folder's own CSV must never be taken for a log
    found = I.discover_logs([str(root / "**" / "*"), str(root / "v1"), str(root / "odd.log")], exclude=[out])
    rel = sorted(p.relative_to(root.resolve()).as_posix() for p in found)
    # the glob keeps supported suffixes only; an explicit file is taken whatever its suffix
    assert rel == ["odd.log", "v1/a.mcap", "v2/b.mcap"]


@pytest.mark.parametrize("arg, message", [("nothing*.mcap", "matches no files"),
                                          ("empty", "no logs found")])
def test_discovery_errors(tmp_path: Path, arg: str, message: str) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=message):
        I.discover_logs([str(tmp_path / arg)])


def test_discovery_of_a_missing_path_is_the_one_missing_input_error(tmp_path: Path) -> None:
    """A path that is no glob and does not exist: every command's missing-input error (exit 3, one wording)."""
    from mrftcli.errors import LogReadError

    with pytest.raises(LogReadError, match=r"missing_dir: no such file or directory$") as err:
        I.discover_logs([str(tmp_path / "missing_dir")])
    assert err.value.exit_code == 3


# --------------------------------------------------------------------------------------------------
# Config
# --------------------------------------------------------------------------------------------------

TOML = """
[defaults]
tp = 0.04
loop = "altitude"

[[logs]]
match = "quad2/*"
tp = 0.05
loop = ["roll", "pitch"]

[[logs]]
match = "bad.csv"          # no '/': matches the file name anywhere
output_scale = 0.001

[[logs]]
match = "**/quad2/bad.csv" # later entry overrides the earlier ones
tp = 0.06
vehicle = "spare"
"""


def test_config_matching_and_precedence(tmp_path: Path, fleet: Path) -> None:
    cfg_path = fleet / "batch.toml"
    cfg_path.write_text(TOML)
    cfg = I.load_config(cfg_path)
    base = {"tp": None, "loops": ("altitude",)}
    s1, m1 = I.resolve_settings(fleet / "quad1" / "f1.csv", base, cfg, {})
    assert (s1.tp, s1.loops, m1) == (0.04, ("altitude",), [])
    s2, m2 = I.resolve_settings(fleet / "quad2" / "f1.csv", base, cfg, {})
    assert (s2.tp, s2.loops, m2) == (0.05, ("roll", "pitch"), [0])
    s3, m3 = I.resolve_settings(fleet / "quad2" / "bad.csv", base, cfg, {})
    assert (s3.tp, s3.loops, s3.output_scale, s3.vehicle, m3) == (0.06, ("roll", "pitch"), 0.001, "spare", [0, 1, 2])
    # Options given on the command line override the config.
    s4, _ = I.resolve_settings(fleet / "quad2" / "bad.csv", base, cfg, {"tp": 0.07, "loops": ("altitude",)})
    assert (s4.tp, s4.loops, s4.output_scale) == (0.07, ("altitude",), 0.001)


def test_yaml_config_is_equivalent(tmp_path: Path, fleet: Path) -> None:
    (fleet / "batch.yaml").write_text(
        "defaults: {tp: 0.04}\nlogs:\n  - match: 'quad2/*'\n    tp: 0.05\n    loop: [roll]\n"
    )
    cfg = I.load_config(fleet / "batch.yaml")
    s, m = I.resolve_settings(fleet / "quad2" / "f1.csv", {"loops": ("altitude",)}, cfg, {})
    assert (s.tp, s.loops, m) == (0.05, ("roll",), [0])


@pytest.mark.parametrize("text, message", [
    ("[defaults]\ntpp = 1\n", r"batch.toml: \[defaults\]: unknown key 'tpp'"),
    ("[defaults]\ntp = -1\n", r"batch.toml: \[defaults\]: tp must be a positive"),
    ("[[logs]]\nmatch = 'x'\nloop = 'yaw'\n", r"batch.toml: logs\[0\]: loop must be one of"),
    ("[[logs]]\ntp = 0.1\n", r"batch.toml: logs\[0\]: missing key 'match'"),
    ("[[logs]]\nmatch = 'x'\noutput_scale = 0\n", r"logs\[0\]: output_scale must be"),
    ("[[logs]]\nmatch = 'x'\nmin_cycles = 1\n", r"logs\[0\]: min_cycles must be an integer of at least 2"),
    ("tp = 0.1\n", r"batch.toml: unknown top-level key 'tp'"),
    ("[defaults\n", r"batch.toml: not valid TOML"),
])
def test_config_errors_name_file_and_key(tmp_path: Path, text: str, message: str) -> None:
    p = tmp_path / "batch.toml"
    p.write_text(text)
    with pytest.raises(InputError, match=message):
        I.load_config(p)


def test_config_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="cannot read config file"):
        I.load_config(tmp_path / "nope.toml")


# --------------------------------------------------------------------------------------------------
# Running: outputs, failures, resumability
# --------------------------------------------------------------------------------------------------


def test_outputs_csv_parquet_json_and_bad_log(tmp_path: Path, fleet: Path) -> None:
    out = tmp_path / "out"
    res = run(fleet, out)
    df = res.summary
    assert res.n_logs == 4
    assert list(df["path"]) == sorted(str(p.resolve()) for p in fleet.rglob("*.csv"))
    assert res.counts == {"ok": 3, "insufficient": 0, "failed": 1, "skipped-uptodate": 0}
    bad = df[df["path"].str.endswith("bad.csv")].iloc[0]
    assert bad["status"] == "failed" and bad["error_type"] == "LogReadError"
    assert bad["error"] == "bad.csv: not a toy log"
    good = df[df["path"].str.endswith("quad1/f2.csv")].iloc[0]
    assert good["tau_mean"] == pytest.approx(0.051) and good["K_mean"] == pytest.approx(20.0)
    assert (good["n_tests"], good["n_cycles"], good["betas"], good["vehicle"]) == (2, 20, "-0.4;-0.7", "quad1")
    # Per-log JSON: one per log, names never collide (two f1.csv), content is the record.
    jsons = sorted((out / "logs").glob("*.json"))
    assert len(jsons) == 4 and len({p.name for p in jsons}) == 4
    rec = json.loads((out / good["result_json"]).read_text())
    assert rec["path"] == good["path"] and rec["loops"][0]["result"]["parameters"]["tau"]["mean"] == 0.051
    # CSV and Parquet hold the same table.
    csv = pd.read_csv(out / "summary.csv")
    pq = pd.read_parquet(out / "summary.parquet")
    assert list(csv.columns) == list(pq.columns) == S.SUMMARY_COLUMNS
    assert list(csv["status"]) == list(pq["status"]) == list(df["status"])
    np.testing.assert_allclose(csv["tau_mean"], pq["tau_mean"].astype(float))
    assert str(pq["log_mtime"].dtype).startswith("datetime64") and str(pq["log_mtime"].dt.tz) == "UTC"
    # integer counts stay integers with a missing value for the failed log (quad1/f1, quad1/f2, quad2/bad, ...)
    assert str(pq["n_cycles"].dtype) == "Int64" and pq["n_cycles"].isna().tolist() == [False, False, True, False]


def test_worker_exceptions_become_failed_rows(tmp_path: Path, fleet: Path) -> None:
    write_toy(fleet / "quad3" / "crash.csv")
    res = run(fleet, tmp_path / "out")
    row = res.summary[res.summary["path"].str.endswith("crash.csv")].iloc[0]
    assert (row["status"], row["error_type"], row["error"]) == ("failed", "internal", "RuntimeError: worker blew up")
    assert res.counts["ok"] == 3  # the rest of the batch went on


def test_resume_skips_uptodate_and_recomputes_on_change(tmp_path: Path, fleet: Path) -> None:
    out = tmp_path / "out"
    first = run(fleet, out)
    second = run(fleet, out)
    st = dict(zip(second.summary["path"].map(lambda p: Path(p).name + Path(p).parent.name), second.summary["status"]))
    # ok logs are skipped with their stored figures; the failed one is tried again
    assert st == {"f1.csvquad1": "skipped-uptodate", "f2.csvquad1": "skipped-uptodate",
                  "f1.csvquad2": "skipped-uptodate", "bad.csvquad2": "failed"}
    pd.testing.assert_series_equal(first.summary["tau_mean"], second.summary["tau_mean"])
    assert (second.summary["result_status"] == first.summary["status"]).all()

    # A log modified after its result -> recomputed (content changed too, and the new value shows).
    f2 = fleet / "quad1" / "f2.csv"
    write_toy(f2, tau=0.060)
    future = time.time() + 5
    os.utime(f2, (future, future))
    third = run(fleet, out)
    row = third.summary[third.summary["path"] == str(f2.resolve())].iloc[0]
    assert row["status"] == "ok" and row["tau_mean"] == pytest.approx(0.060)
    assert (third.summary["status"] == "skipped-uptodate").sum() == 2

    # Settings change -> recomputed; --force -> everything recomputed.
    fourth = run(fleet, out, defaults={"tp": 0.1})
    assert set(fourth.summary["status"]) == {"ok", "failed"}
    assert fourth.summary["K_mean"].dropna().tolist() == pytest.approx([10.0] * 3)
    fifth = run(fleet, out, defaults={"tp": 0.1}, force=True)
    assert "skipped-uptodate" not in set(fifth.summary["status"])


def test_progress_counts_the_logs_analysed_not_the_skipped(tmp_path: Path, fleet: Path) -> None:
    out = tmp_path / "out"
    calls: list[tuple[float, float, str]] = []
    run(fleet, out, progress=lambda done, total, stage="": calls.append((done, total, stage)))
    assert [c[:2] for c in calls] == [(0, 4), (1, 4), (2, 4), (3, 4), (4, 4)]
    assert sorted(c[2] for c in calls[1:]) == ["bad.csv", "f1.csv", "f1.csv", "f2.csv"]
    calls.clear()
    run(fleet, out, progress=lambda done, total, stage="": calls.append((done, total, stage)))
    assert calls == [(0, 1, ""), (1, 1, "bad.csv")]  # the three up-to-date logs are not work


def test_missing_tp_everywhere_is_an_input_error(tmp_path: Path, fleet: Path) -> None:
    with pytest.raises(InputError, match="no Tp given"):
        run(fleet, tmp_path / "out", defaults={})


# --------------------------------------------------------------------------------------------------
# analyze_one with a stand-in analysis module: statuses and messages
# --------------------------------------------------------------------------------------------------


class _FakeResult:
    kind = "soiptd"  # an eq. (2) analysis, as AnalysisResult.kind says

    def __init__(self, d, path=""):
        self._d = d
        self.flight = types.SimpleNamespace(path=path)  # what diagnose is given

    def to_json(self):
        return self._d


def _fake_analyze_path(path, model, *, read, options, loop_hint=True):
    """Takes the loop and three topics of ``read``; any other read setting fails as an unknown keyword did."""
    Tp = model.Tp  # eq. (2)'s model object (soiptd_model)
    unsupported = [f for f in ("setpoint_topic", "battery_topic", "output_scale", "layout", "command_scale",
                               "controller_rate_hz") if getattr(read, f) is not None]
    if unsupported:
        raise TypeError(f"_fake_analyze_path() got an unexpected setting {unsupported[0]!r}")
    loop, command_topic = read.loop, read.command_topic
    name = Path(path).name
    if name.startswith("single"):
        raise InsufficientDataError("only one beta found (-0.4); need two", partial={"tau": {"mean": 0.05}})
    if name.startswith("unreadable"):
        raise LogReadError(f"{name}: truncated\nmid-chunk")
    if name.startswith("bug"):
        raise ZeroDivisionError("division by zero")
    if name.startswith("warn"):
        for _ in range(3):
            warnings.warn("Mean of empty slice", RuntimeWarning, stacklevel=1)
    return _FakeResult(toy_analysis(Tp * 10, 0.04, 1.0, Tp, (), std=(0.0, 0.001, 0.0), loop=loop,
                                    command_topic=command_topic), path)


@pytest.fixture
def fake_analyze(monkeypatch):
    from mrftcli.analyze.options import AnalyzeOptions

    mod = types.ModuleType("mrftcli.analyze")
    mod.analyze_path = _fake_analyze_path
    mod.AnalyzeOptions = AnalyzeOptions
    mod.refuse_rejected_tp = lambda result, accept=False: result  # a stand-in analysis has no verdict on Tp
    monkeypatch.setitem(sys.modules, "mrftcli.analyze", mod)
    return mod


def test_analyze_one_statuses(tmp_path: Path, fake_analyze) -> None:
    def task(name, **kw):
        s = I.LogSettings(**({"tp": 0.1, "loops": ("altitude", "roll")} | kw))
        return B.LogTask(str(tmp_path / name), s)

    ok = B.analyze_one(task("good.mcap", command_topic="/cmd"))
    assert [e["status"] for e in ok["loops"]] == ["ok", "ok"]
    assert ok["loops"][1]["result"]["loop"] == "roll" and ok["loops"][0]["result"]["command_topic"] == "/cmd"
    assert ok["loops"][0]["result"]["parameters"]["Td"]["mean"] == pytest.approx(1.0)  # Tp reached analyze_path
    ins = B.analyze_one(task("single.mcap"))["loops"][0]
    assert (ins["status"], ins["exit_code"], ins["result"]) == ("insufficient", 6, {"partial": {"tau": {"mean": 0.05}}})
    bad = B.analyze_one(task("unreadable.mcap"))["loops"][0]
    assert (bad["status"], bad["error"], bad["error_type"]) == ("failed", "unreadable.mcap: truncated mid-chunk",
                                                                "LogReadError")
    bug = B.analyze_one(task("bug.mcap"))["loops"][0]
    assert (bug["error_type"], bug["error"]) == ("internal", "ZeroDivisionError: division by zero")
    # A setting the analysis does not take fails the loop with its name, not silently dropped.
    uns = B.analyze_one(task("good.mcap", output_scale=2.0))["loops"][0]
    assert uns["status"] == "failed" and "output_scale" in uns["error"]
    # numeric warnings are kept in the record (once each), not printed from the workers
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # would raise if one escaped analyze_one
        warned = B.analyze_one(task("warn.mcap"))["loops"][0]
    assert warned["status"] == "ok" and warned["python_warnings"] == ["RuntimeWarning: Mean of empty slice"]
    notp = B.analyze_one(B.LogTask(str(tmp_path / "good.mcap"), I.LogSettings()))["loops"][0]
    assert notp["status"] == "failed" and "no Tp" in notp["error"]


class _FakeDiagnosis:
    def __init__(self, effects):
        self.effects = effects

    def to_dict(self):
        linear = {"Td": 1.0, "tau": 0.05, "K": 10.0}
        joint = {"Td": 1.1, "tau": 0.04, "K": 11.0}
        return {"effects": [{"name": n, "identification": {"linear": linear, "with_effect": joint}}
                            for n in self.effects], "located": []}


def _fake_diagnose(flight, model, analysis=None, progress=None, **options):
    from mrftcli.errors import DiagnoseError

    # the analysis' signals and the log's Tp (in eq. (2)'s model object) are passed on, so the log is not read twice
    assert analysis is not None and flight is analysis.flight and model.Tp == 0.1
    name = Path(flight.path).name
    if name.startswith("nodiag"):
        raise DiagnoseError("no test with 6 stable cycles")
    return _FakeDiagnosis(["input_bias", "sensor_lag"] if name.startswith("good") else [])


def test_diagnose_findings_and_failures(tmp_path: Path, fake_analyze, monkeypatch) -> None:
    mod = types.ModuleType("mrftcli.diagnose.selection")
    mod.diagnose = _fake_diagnose
    monkeypatch.setitem(sys.modules, "mrftcli.diagnose.selection", mod)
    for name in ("good.mcap", "clean.mcap", "nodiag.mcap"):
        write_toy(tmp_path / "logs" / name)
    kw = {"defaults": {"tp": 0.1}}
    df = B.run_batch([tmp_path / "logs"], tmp_path / "out", options=B.BatchOptions(diagnose=True, jobs=1, report=False),
                     **kw).summary.set_index("path")
    row = {Path(p).name: r for p, r in df.iterrows()}
    assert row["good.mcap"]["findings"] == "input_bias;sensor_lag"
    assert (row["good.mcap"]["tau_with_findings"], row["good.mcap"]["K_with_findings"]) == (0.04, 11.0)
    assert row["clean.mcap"]["findings"] == ""  # diagnosed, nothing found
    assert pd.isna(row["clean.mcap"]["tau_with_findings"])
    # a failed diagnosis leaves the analysis ok and says why
    nd = row["nodiag.mcap"]
    assert (nd["status"], pd.isna(nd["findings"]), nd["diagnose_error"]) == ("ok", True, "no test with 6 stable cycles")
    # without --diagnose: not run, so no findings at all; and the settings hash differs, so it recomputes
    df2 = B.run_batch([tmp_path / "logs"], tmp_path / "out", options=B.BatchOptions(jobs=1, report=False), **kw).summary
    assert df2["findings"].isna().all() and (df2["status"] == "ok").all()


def test_insufficient_rows_and_cli_like_summary(tmp_path: Path, fake_analyze) -> None:
    for name in ("good.mcap", "single.mcap", "unreadable.mcap"):
        write_toy(tmp_path / "logs" / name)
    res = B.run_batch([tmp_path / "logs"], tmp_path / "out", options=B.BatchOptions(jobs=1, report=False),
                      defaults={"tp": 0.1})
    assert res.summary["status"].tolist() == ["ok", "insufficient", "failed"]
    assert "1 ok, 1 insufficient, 1 failed" in res.summary_line()
    assert res.summary.loc[1, "error"] == "only one beta found (-0.4); need two"


# --------------------------------------------------------------------------------------------------
# Executors: local processes and a real Dask LocalCluster on loopback
# --------------------------------------------------------------------------------------------------

_SAME = ["path", "loop", "status", "error", "tau_mean", "Td_mean", "K_mean", "n_cycles"]


def test_process_pool_matches_in_process(tmp_path: Path, fleet: Path) -> None:
    write_toy(fleet / "quad3" / "crash.csv")
    a = run(fleet, tmp_path / "a", jobs=1).summary
    b = run(fleet, tmp_path / "b", jobs=2).summary
    pd.testing.assert_frame_equal(a[_SAME], b[_SAME])


def test_a_dying_worker_process_fails_only_its_log(tmp_path: Path, fleet: Path) -> None:
    write_toy(fleet / "quad3" / "kill.csv")
    res = run(fleet, tmp_path / "out", jobs=2, worker=killing_worker).summary
    st = dict(zip(res["path"].map(lambda p: Path(p).name + Path(p).parent.name), res["status"]))
    assert st == {"f1.csvquad1": "ok", "f2.csvquad1": "ok", "f1.csvquad2": "ok", "bad.csvquad2": "failed",
                  "kill.csvquad3": "failed"}
    assert res.loc[res["path"].str.endswith("kill.csv"), "error"].iloc[0].startswith("RuntimeError: the worker process died")


@pytest.fixture
def dask_cluster():
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, host="127.0.0.1", protocol="tcp://",
                                       dashboard_address=None, silence_logs=40)
    try:
        yield cluster
    finally:
        cluster.close()


def test_dask_scheduler_runs_the_batch(tmp_path: Path, fleet: Path, dask_cluster) -> None:
    a = run(fleet, tmp_path / "a", jobs=1).summary
    b = run(fleet, tmp_path / "b", scheduler=dask_cluster.scheduler_address, scheduler_timeout_s=10).summary
    pd.testing.assert_frame_equal(a[_SAME], b[_SAME])
    # A worker that raises on the cluster still yields failed rows, not a stopped batch.
    c = run(fleet, tmp_path / "c", scheduler=dask_cluster.scheduler_address, worker=crashing_worker).summary
    assert set(c["status"]) == {"failed"} and c["error"].str.contains("boom").all()


def test_unreachable_scheduler_is_one_line_input_error(tmp_path: Path, fleet: Path) -> None:
    pytest.importorskip("distributed")
    import socket

    with socket.socket() as s:  # a free port on loopback that nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(InputError, match=r"cannot reach the Dask scheduler at tcp://127.0.0.1:\d+ within 1 s"):
        run(fleet, tmp_path / "out", scheduler=f"tcp://127.0.0.1:{port}", scheduler_timeout_s=1)


def test_missing_dask_is_a_one_line_input_error(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)  # makes `import distributed` fail
    with pytest.raises(InputError, match=r"--scheduler needs Dask distributed.*pip install 'mrft-ident\[dask\]'"):
        B.connect_scheduler("tcp://127.0.0.1:8786", 1.0)


@pytest.mark.parametrize("address", ["not-an-address", "tcp://localhost", "tcp://127.0.0.1:99999", "http://h:1"])
def test_malformed_scheduler_address_is_refused_before_connecting(address: str) -> None:
    with pytest.raises(InputError, match="--scheduler must look like tcp://HOST:PORT"):
        B.connect_scheduler(address, 1.0)


# --------------------------------------------------------------------------------------------------
# Outliers and the fleet report
# --------------------------------------------------------------------------------------------------


def _toy_summary(taus_ms, Td=1.0):
    n = len(taus_ms)
    return pd.DataFrame({
        "path": [f"/f/v{i % 2}/log{i}.mcap" for i in range(n)], "loop": ["altitude"] * n,
        "vehicle": [f"v{i % 2}" for i in range(n)], "status": ["ok"] * n, "result_status": ["ok"] * n,
        "tau_mean": np.asarray(taus_ms) / 1e3, "tau_std": [0.001] * n, "Td_mean": [Td] * n, "Td_std": [0.2] * n,
        "K_mean": [1.0] * n, "K_std": [0.01] * n, "n_tests": [2] * n, "n_cycles": [20] * n, "findings": [""] * n,
        "error": [None] * n, "error_type": [None] * n,
        "log_time": pd.date_range("2026-01-01", periods=n, freq="D", tz="UTC"),
    })


def test_robust_outlier_flag() -> None:
    # tau = 46..50 ms and one 70 ms: median 48.5, |dev| = 2.5 1.5 .5 .5 1.5 21.5 -> MAD = 1.5
    df = S.flag_outliers(_toy_summary([46, 47, 48, 49, 50, 70]))
    assert df["outlier"].tolist() == [False] * 5 + [True]
    assert df["tau_z"].iloc[-1] == pytest.approx(0.6745 * 21.5 / 1.5)
    assert "tau high" in df["outlier_reason"].iloc[-1]
    assert df["Td_z"].isna().all()  # all Td equal: MAD 0, no z, nothing flagged
    # over half the logs equal (MAD 0): the mean absolute deviation scales z instead
    # tau = 50 x5, 51, 80: median 50, MeanAD = (1 + 30) / 7
    df0 = S.flag_outliers(_toy_summary([50, 50, 50, 50, 50, 51, 80]))
    assert df0["outlier"].tolist() == [False] * 6 + [True]
    assert df0["tau_z"].iloc[-1] == pytest.approx(30 / (1.253314 * 31 / 7))
    # fewer than three results: no flags at all
    assert not S.flag_outliers(_toy_summary([40, 90]))["outlier"].any()


def test_vehicle_whose_tau_grew_is_flagged_against_its_own_history() -> None:
    # Vehicle A: 40 ms four times, then 46 ms; vehicle B flies at 44-52 ms, so 46 ms is no fleet outlier.
    taus = [40.0, 40.2, 39.9, 40.1, 46.0, 44.0, 48.0, 52.0, 50.0, 47.0]
    n = len(taus)
    df = _toy_summary(taus)
    df["vehicle"] = ["A"] * 5 + ["B"] * 5
    df["path"] = [f"/f/{v}/log{i}.mcap" for i, v in enumerate(df["vehicle"])]
    df["tau_std"] = [0.0005] * n
    df["log_time"] = pd.to_datetime([f"2026-01-{d:02d}" for d in (1, 2, 3, 4, 5, 1, 2, 3, 4, 5)], utc=True)
    out = S.flag_outliers(df)
    assert not out["tau_outlier"].any()
    # change = 46 - median(40, 40.2, 39.9, 40.1) = 5.95 ms > 3 hypot(0.5, 0.5) ms
    assert out.loc[4, "tau_change"] == pytest.approx(0.00595)
    assert out["tau_changed"].tolist() == [False] * 4 + [True] + [False] * 5
    assert out.loc[4, "outlier_reason"] == "tau grew by 5.95 ms vs this vehicle's earlier logs"
    assert out.loc[:3, "tau_change"].iloc[:2].isna().all()  # fewer than two earlier logs: no comparison


def test_fleet_report_writes_html_and_png(tmp_path: Path, mplcleanup) -> None:
    from mrftcli.report.fleet import write_fleet_report

    df = S.flag_outliers(_toy_summary([46, 47, 48, 49, 50, 70])).assign(lead=False)  # summary_frame's column
    index = write_fleet_report(df, tmp_path / "report")
    text = index.read_text()
    assert "fleet_altitude.png" in text and "log5.mcap" in text and "tau high" in text
    # table cells: tau in ms, no lead blank, other numbers to 4 digits, times to the minute, a missing error blank
    assert ("<td>/f/v1/log5.mcap</td><td>altitude</td><td>v1</td><td>ok</td><td>70.00 ms</td><td>1.00 ms</td><td></td>"
            "<td>1</td>") in text
    assert "<td>2026-01-06 00:00</td><td></td></tr>" in text
    png = tmp_path / "report" / "fleet_altitude.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_log_time_prefers_an_absolute_log_time_stamp() -> None:
    mtime = 1_790_000_000.0
    from_log = S._log_time(1_700_000_000.5, mtime)
    assert from_log == {"log_time": pd.Timestamp("2023-11-14 22:13:20.5", tz="UTC"), "log_time_source": "log"}
    # time since boot / a simulator's 0 s say nothing about the date: the file's mtime is used
    for t_first in (12.5, None):
        assert S._log_time(t_first, mtime) == {"log_time": pd.Timestamp(mtime, unit="s", tz="UTC"),
                                              "log_time_source": "mtime"}


def test_the_config_example_in_the_docs_works(tmp_path: Path, repo_root: Path) -> None:
    import re

    doc = (repo_root / "docs" / "batch.md").read_text()
    (tmp_path / "fleet.toml").write_text(re.search(r"```toml\n(.*?)```", doc, re.S).group(1))
    cfg = I.load_config(tmp_path / "fleet.toml")
    base = {"loops": ("altitude",)}
    spare, matched = I.resolve_settings(tmp_path / "design2" / "old" / "a.mcap", base, cfg, {})
    assert (spare.tp, spare.output_scale, spare.vehicle, matched) == (0.0499, 0.001, "E600-spare", [0, 2])
    att, _ = I.resolve_settings(tmp_path / "x" / "quad_attitude.mcap", base, cfg, {})
    assert (att.tp, att.loops) == (0.0422, ("roll", "pitch"))


def test_a_log_whose_mtime_cannot_be_read_does_not_stop_the_batch(tmp_path: Path, fleet: Path, monkeypatch) -> None:
    real = I.log_mtime

    def flaky(path: Path) -> float:
        if path.name == "f2.csv":
            raise PermissionError(13, "Permission denied")
        return real(path)

    monkeypatch.setattr(B, "log_mtime", flaky)
    for _ in range(2):  # never skipped as up to date: its age is unknown
        df = run(fleet, tmp_path / "out").summary
        row = df[df["path"].str.endswith("quad1/f2.csv")].iloc[0]
        assert row["status"] == "ok" and pd.isna(row["log_mtime"]) and pd.isna(row["log_time"])
    assert (df["status"] == "skipped-uptodate").sum() == 2
