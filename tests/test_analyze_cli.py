"""``mrft-ident analyze`` end to end through the console script (exit codes, JSON, report, errors)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mrftcli.mrft.model import soiptd_model
from mrftcli.io.logtypes import TopicData
from mrftcli.io import write_log
from mrftcli.sim.flight import write_flight
from test_segment_support import simulate_paper_flight

TP = 0.0422


def _run(*args: str) -> subprocess.CompletedProcess:
    """The console entry point in this process (the interpreter start-up is 1-5 s a call on a loaded machine);
    :func:`_run_console` runs the real console script once."""
    code, out, err = _invoke(*args)
    return subprocess.CompletedProcess(list(args), code, out, err)


def _run_console(*args: str) -> subprocess.CompletedProcess:
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
    proc = _run_console("analyze", str(logs / "two.mcap"), "--tp", str(TP), "--json", "-", "--report",
                        str(tmp_path / "rep"))
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)  # stdout holds the JSON only
    for name in ("Td", "tau", "K"):
        assert {"value", "std"} <= set(data["parameters"][name])
    assert abs(data["parameters"]["tau"]["value"] - 0.0464) < 1e-3
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
    lines = proc.stdout.splitlines()
    assert any(line.split()[:2] == ["tau", "ms"] for line in lines) and "effective" in proc.stdout
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

    def fake(flight, model, analysis=None, progress=None):
        seen.update(Tp=model.Tp, n_tests=len(analysis.tests))  # eq. (2)'s model object
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



def test_diagnose_flag_drops_the_try_diagnose_hint(tmp_path, monkeypatch):
    """A warning that ends '(try --diagnose)' without --diagnose (concealed flight 05: the constraints disagree,
    the waveform refinement is refused) ends without it when --diagnose is given: terminal and JSON alike."""
    import mrftcli.diagnose.selection as diag

    class _Fake:
        summary = "fake diagnosis"

        def to_dict(self):
            return {"summary": self.summary}

    monkeypatch.setattr(diag, "diagnose", lambda *a, **k: _Fake())  # the hint is analyze's: no fit needed
    log = str(SAMPLES / "concealed" / "flight_05.mcap")
    runs = {}
    for flag in ((), ("--diagnose",)):
        out = tmp_path / f"r{len(flag)}.json"
        code, _, stderr = _invoke("analyze", log, "--tp", str(TP), "--loop", "altitude", "-q", *flag,
                                  "--json", str(out))
        assert code == 0, stderr
        runs[flag] = ([ln for ln in stderr.splitlines() if ln.startswith("warning: ")],
                      json.loads(out.read_text())["warnings"])
    (text, data), (text_d, data_d) = runs[()], runs[("--diagnose",)]
    hinted = [w for w in data if w.endswith(" (try --diagnose)")]
    assert len(hinted) == 2 and sum(ln.endswith("(try --diagnose)") for ln in text) == 2
    assert not any("try --diagnose" in w for w in data_d + text_d)
    assert data_d == [w.removesuffix(" (try --diagnose)") for w in data]  # the warnings themselves kept


# ---- issue 12: what a new user trips over -------------------------------------------------------

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"


def _invoke(*args: str):
    """In-process CLI run through the console entry point (no interpreter start-up): exit code, stdout, stderr."""
    import contextlib
    import io

    from mrftcli.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(list(args))
            code = 0
        except SystemExit as stop:
            code = stop.code
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def table(logs, tmp_path_factory):
    """One analyze run on the two-beta flight: its table, stderr and JSON (several tests read it)."""
    out = tmp_path_factory.mktemp("table") / "missing" / "folder" / "r.json"
    code, stdout, stderr = _invoke("analyze", str(logs / "two.mcap"), "--tp", str(TP), "--json", str(out))
    return code, stdout, stderr, out


def test_ros2_bag_folder_is_accepted_by_analyze():
    # item 1: a ROS 2 bag is a folder; the README promises it works
    code, stdout, stderr = _invoke("analyze", str(SAMPLES / "design1_altitude_ros2_mcap"), "--tp", "0.0422")
    assert code == 0, stderr
    tau = next(line for line in stdout.splitlines() if line.split()[:2] == ["tau", "ms"])
    truth = json.loads((SAMPLES / "design1_altitude_ros2_mcap.truth.json").read_text())["tau"]
    lo, hi = (float(x) for x in tau.split()[-3:None:2])  # "... 46.36 - 46.43"
    assert lo <= truth * 1e3 <= hi


@pytest.mark.parametrize("tp", ["1e-9", "42.2"])
def test_tp_outside_the_physical_range_is_refused_with_the_reason(logs, tp):
    # item 6: in the CLI and in the library
    code, stdout, stderr = _invoke("analyze", str(logs / "two.mcap"), "--tp", tp)
    assert code == 2 and stdout == ""
    assert "physical range" in stderr and "in seconds" in stderr and len(stderr.strip().splitlines()) == 1
    from mrftcli.analyze import analyze_flight
    from mrftcli.errors import InputError

    with pytest.raises(InputError, match="physical range"):
        analyze_flight(None, soiptd_model(float(tp)))  # refused before the flight is looked at


def test_tp_with_a_process_model_is_refused_not_ignored(logs):
    # review B5: --tp is eq. (2)'s; a process model's known parameters are --param (as diagnose and watch)
    code, stdout, stderr = _invoke("analyze", str(logs / "two.mcap"), "--model", "fopdt", "--tp", "0.04")
    assert code == 2 and stdout == "" and "--tp is eq. (2)'s" in stderr and "--param" in stderr
    assert len(stderr.strip().splitlines()) == 1


def test_format_option_is_honoured_by_every_log_reading_command(logs):
    # item 10: the "pass --format" advice works in analyze and diagnose
    for command in ("analyze", "diagnose", "plan", "watch", "tune"):
        code, stdout, _ = _invoke(command, "--help")
        assert code == 0 and "--format" in stdout and "--layout" in stdout, command
    code, _, stderr = _invoke("analyze", str(logs / "two.mcap"), "--tp", str(TP), "--format", "csv")
    assert code == 3 and stderr.startswith("error:")  # the MCAP was read as CSV: it was used


def test_exit_6_prints_the_partial_result_in_text_mode(logs):
    # item 11: what one beta can say is on the terminal, not only in the JSON
    code, stdout, stderr = _invoke("analyze", str(logs / "one.mcap"), "--tp", str(TP))
    assert code == 6 and "only one beta" in stderr
    assert "partial result" in stdout
    lines = stdout.strip().splitlines()
    assert lines[-1].startswith("held-out test 1: the only test: nothing is held out")
    row = lines[-2].split()
    lo, hi = float(row[-3]), float(row[-1])
    assert 0 < lo < 46.4 < hi  # tau over the assumed Td range brackets the truth


def test_outputs_are_checked_before_the_work_the_same_way(logs, table, tmp_path):
    # item 13: a missing folder is created for --json as for --report; an impossible one is refused
    # before any work (nothing on stdout), with exit 2
    code, _, stderr, out = table
    assert code == 0, stderr
    assert json.loads(out.read_text())["input"]["loop"] == "altitude"
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    for option in ("--json", "--report"):
        target = blocker / "sub" / ("r.json" if option == "--json" else "rep")
        code, stdout, stderr = _invoke("analyze", str(logs / "two.mcap"), "--tp", str(TP), option, str(target))
        assert code == 2 and stdout == "", option
        assert stderr.startswith(f"error: {option}") and "cannot create the folder" in stderr
    code, stdout, stderr = _invoke("diagnose", str(logs / "two.mcap"), "--tp", str(TP), "--json", str(blocker / "d.json"))
    assert code == 2 and stdout == "" and "is not a folder" in stderr


def test_progress_covers_identify_diagnose_and_report(logs, tmp_path, monkeypatch):
    # item 14: one bar through the Progress protocol over the whole run, ending full
    import contextlib

    import mrftcli.cli.analyze as cli_analyze
    import mrftcli.diagnose.selection as diag

    calls = []

    @contextlib.contextmanager
    def recorder(desc, *, unit="it", enabled=True):
        calls.append(("open", enabled))
        yield lambda done, total, stage="": calls.append((done, total, stage))

    class _Fake:
        summary = "fake"

        def to_dict(self):
            return {}

    def fake(flight, Tp, analysis=None, progress=None):
        for i in range(3):
            progress(i + 1, 3, f"candidate {i}")
        return _Fake()

    monkeypatch.setattr(cli_analyze, "tqdm_progress", recorder)
    monkeypatch.setattr(diag, "diagnose", fake)
    monkeypatch.setattr("mrftcli.report.diagnosis.write_diagnosis_report",
                        lambda result, out: Path(out) / "diagnosis.html")
    code, _, stderr = _invoke("analyze", str(logs / "two.mcap"), "--tp", str(TP), "--diagnose",
                              "--report", str(tmp_path / "rep"))
    assert code == 0, stderr
    assert calls[0] == ("open", True)
    done = [c[0] for c in calls[1:]]
    assert done == sorted(done) and calls[-1][0] == calls[-1][1]  # monotonic, ends full
    stages = {c[2].split(":")[0] for c in calls[1:]}
    assert stages == {"identify", "diagnose", "report"}


def test_terminal_table_labels_units_and_format(table):
    # item 15: units, stable/total, separate headers, no trailing spaces, no paper jargon
    code, stdout, _, _ = table
    assert code == 0
    lines = stdout.splitlines()
    assert all(line == line.rstrip() for line in lines)
    assert "Table III" not in stdout
    head = next(i for i, line in enumerate(lines) if line.split()[:1] == ["test"])
    # two tests: each is held out from the other's fundamental and 3rd harmonic (issue 41), two more columns
    assert lines[head].split() == ["test", "from", "to", "beta", "beta", "relay", "h", "frequency", "amplitude",
                                   "stable/total", "held-out", "f", "held-out", "amplitude"]
    assert lines[head + 1].split()[:8] == ["[s]", "[s]", "nominal", "effective", "[command]", "[Hz]", "[m]", "cycles"]
    rows = [line.split() for line in lines[head + 2: head + 4]]
    for col in (5, 6, 7):  # h, frequency, amplitude: 4 significant digits each
        for r in rows:
            digits = r[col].replace(".", "").lstrip("0")
            assert len(digits) == 4, r[col]
    k = next(line for line in lines if line.split()[:1] == ["K"])
    assert "m/s² per command unit" in k


def test_td_omega_is_information_not_a_warning(table):
    # item 16: expected on an altitude loop, it is said once as a note, not as a warning
    code, stdout, stderr, out = table
    assert "Td*Omega" not in stderr
    assert sum("note: Td*Omega" in line for line in stdout.splitlines()) == 1
    data = json.loads(out.read_text())
    assert any("Td*Omega" in n for n in data["notes"]) and not any("Td*Omega" in w for w in data["warnings"])


def test_the_held_out_route_is_named_in_the_json_and_its_note_by_the_parameters_source(table):
    # R2 finding 4 (issue 41): each prediction names its route (JSON ``route``); the note says where the reported
    # parameters come from (here the waveform refinement), not always the fundamentals
    from mrftcli.analyze.held_out import ROUTE_POINTS
    from mrftcli.analyze.held_out_harmonic import ROUTE_NOTE, route_note

    code, stdout, _, out = table
    data = json.loads(out.read_text())
    assert code == 0 and [t["held_out"]["route"] for t in data["tests"]] == [ROUTE_POINTS] * 2
    assert "parameters, from the waveform refinement" in stdout
    assert route_note(True) in data["notes"] and f"note: {route_note(True)}" in stdout and ROUTE_NOTE not in stdout
    assert "identified from the waveform refinement" in route_note(True)


def test_wrong_loop_and_bad_effect_messages():
    # item 17: no misleading suggestion; every simulate option checked before planning
    code, _, stderr = _invoke("analyze", str(SAMPLES / "design1_altitude.mcap"), "--tp", "0.0422", "--loop", "roll")
    assert code == 3 and "did you mean /mrft/beta" not in stderr and "/mocap/pose" in stderr
    code, _, stderr = _invoke("simulate", "--tp", "0.0422", "--td", "2.669", "--tau", "0.0464", "--test", "-0.4",
                              "--noise", "0.01", "--effect", "bogus=1", "--out", "x.mcap")
    assert code == 2 and stderr.startswith("error: --effect") and "warning" not in stderr
