"""``mrft-ident analyze`` end to end through the console script (exit codes, JSON, report, errors)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from mrftcli.io.logtypes import TopicData
from mrftcli.io import write_log
from mrftcli.sim.flight import write_flight
from test_segment_support import simulate_paper_flight

TP = 0.0422


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mrftcli.cli", *args], capture_output=True, text=True, timeout=120)


def _no_traceback(proc: subprocess.CompletedProcess) -> None:
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("analyze_cli")
    two = simulate_paper_flight(TP, 2.669, 0.0464, 19.6, (-0.4, -0.7), seed=1)
    write_flight(two, d / "two.mcap", "mcap")
    one = simulate_paper_flight(TP, 2.669, 0.0464, 19.6, (-0.7,), seed=2)
    write_flight(one, d / "one.mcap", "mcap")
    # a hover log with no relay test: a PID-like command and a noisy altitude
    rng = np.random.default_rng(0)
    t = np.arange(3000) / 200.0
    cmd = 0.5 + 0.02 * np.sin(0.7 * t) + rng.normal(0, 0.002, t.size)
    z = 1.0 + rng.normal(0, 5e-4, t.size)
    write_log([TopicData("/mrft/command", "std_msgs/msg/Float64", t, {"data": cmd}),
               TopicData("/mocap/pose", "geometry_msgs/msg/PoseStamped", t, {"pose.position.z": z})],
              d / "hover.mcap", "mcap")
    # two relay tests far too short to settle into a limit cycle
    from mrftcli.sim.flight import FlightSpec, TestSpec, simulate_flight

    spec = two.spec
    short = FlightSpec(model=spec.model, tests=tuple(TestSpec(x.beta, x.h, 2.0) for x in spec.tests),
                       loop="altitude", switching="hear", seed=3, hover_s=2.0, hold_s=2.0)
    write_flight(simulate_flight(short), d / "short.mcap", "mcap")
    return d


def test_json_to_stdout_and_report(logs, tmp_path):
    proc = _run("analyze", str(logs / "two.mcap"), "--tp", str(TP), "--json", "-", "--report", str(tmp_path / "rep"))
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)  # stdout holds the JSON only
    for name in ("Td", "tau", "K"):
        assert {"mean", "std"} <= set(data["parameters"][name])
    assert abs(data["parameters"]["tau"]["mean"] - 0.0464) < 1e-3
    assert [round(t["beta_nominal"], 3) for t in data["tests"]] == [-0.4, -0.7]
    for t in data["tests"]:
        assert {"beta", "h", "frequency_hz", "amplitude", "cycles", "t_start", "t_end"} <= set(t)
        assert t["t_start_rel"] == pytest.approx(t["t_start"] - data["input"]["t0"], abs=1e-9)
    assert data["identification"]["constraints"]["used"] == ["ufm", "phase", "amplitude"]
    rep = tmp_path / "rep"
    assert (rep / "index.html").is_file()
    for png in ("timeseries.png", "manifolds.png", "spread.png", "cycles.png"):
        assert (rep / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_table_on_stdout_and_json_file(logs, tmp_path):
    out = tmp_path / "r.json"
    proc = _run("analyze", str(logs / "two.mcap"), "--tp", str(TP), "--json", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "tau  [ms]" in proc.stdout and "beta eff" in proc.stdout
    assert json.loads(out.read_text())["input"]["loop"] == "altitude"


def test_no_relay_test_exits_4(logs):
    proc = _run("analyze", str(logs / "hover.mcap"), "--tp", str(TP))
    assert proc.returncode == 4
    _no_traceback(proc)
    assert proc.stderr.startswith("error:") and "no MRFT relay test" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_single_beta_exits_6_with_partial_json(logs, tmp_path):
    out = tmp_path / "p.json"
    proc = _run("analyze", str(logs / "one.mcap"), "--tp", str(TP), "--json", str(out))
    assert proc.returncode == 6
    _no_traceback(proc)
    assert "only one beta" in proc.stderr and "assumed Td range" in proc.stderr
    data = json.loads(out.read_text())
    assert data["exit_code"] == 6 and "parameters" not in data
    assert data["partial"]["tau_for_assumed_Td"][0]["tau_range_s"][0] > 0


def test_too_few_stable_cycles_exits_4(logs):
    proc = _run("analyze", str(logs / "short.mcap"), "--tp", str(TP))
    assert proc.returncode == 4
    _no_traceback(proc)
    assert "stable" in proc.stderr and "found 2 relay test(s)" in proc.stderr


@pytest.mark.parametrize("args, code", [
    (["--tp", "-1"], 2),
    (["--tp", "0.04", "--loop", "yaw"], 2),
])
def test_bad_options(logs, args, code):
    proc = _run("analyze", str(logs / "two.mcap"), *args)
    assert proc.returncode == code
    _no_traceback(proc)


def test_missing_log_exits_3(tmp_path):
    proc = _run("analyze", str(tmp_path / "nope.mcap"), "--tp", str(TP))
    assert proc.returncode == 3
    _no_traceback(proc)


def test_diagnose_flag_is_wired(logs, tmp_path, monkeypatch):
    """--diagnose calls mrftcli.diagnose.selection.diagnose with the analysis and adds its dict to the JSON."""
    from click.testing import CliRunner

    import mrftcli.diagnose.selection as diag
    from mrftcli.cli.main import cli

    seen = {}

    class _Fake:
        summary = "fake diagnosis"

        def to_dict(self):
            return {"summary": self.summary}

    def fake(flight, Tp, analysis=None, progress=None):
        seen.update(Tp=Tp, n_tests=len(analysis.tests))
        if progress:
            progress(1, 2, "fitting")  # the library's one protocol: (done, total, stage)
        return _Fake()

    monkeypatch.setattr(diag, "diagnose", fake)
    out = tmp_path / "d.json"
    res = CliRunner().invoke(cli, ["analyze", str(logs / "two.mcap"), "--tp", str(TP), "--diagnose", "--json", str(out)])
    assert res.exit_code == 0, res.output
    assert seen == {"Tp": TP, "n_tests": 2}
    assert json.loads(out.read_text())["diagnosis"] == {"summary": "fake diagnosis"}
    assert "diagnosis: fake diagnosis" in res.output
