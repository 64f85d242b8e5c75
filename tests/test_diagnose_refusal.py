"""diagnose on a log analyze refuses: analyze runs once, its refusal is handed to the diagnosis (issue 39).

The CLI runs analyze first (the diagnosis reuses its record); when analyze refuses, its refusal decides
whether the diagnosis goes on (no plant of eq. (2) fits, or one beta left of tests flown at two relay
heights: the evidence of missing physics) or the command refuses with analyze's message and exit code.
Before, the diagnosis ran analyze a second time to learn the same refusal.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest
from cli_helpers import run_main

import mrftcli.analyze
from mrftcli.diagnose.records import DiagnosisResult
from mrftcli.diagnose.screen import screen_log
from mrftcli.errors import IdentificationError, InsufficientDataError, SegmentationError
from mrftcli.io import ReadOptions, read_flight, write_log
from mrftcli.mrft.model import soiptd_model
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight
from mrftcli.sim.flight import TestSpec as FlownTest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import make_concealed_logs as gen  # noqa: E402 - the benchmark's case generator

M = gen.PLANTS["design1"]


def _one_beta(tmp: Path, heights: tuple[float, ...], name: str, lost: float | None = None, cut: float = 0.3) -> Path:
    """A clean flight of tests at beta -0.4 only, at the given multiples of the planned relay height (and,
    with ``lost``, a test at that beta cut to ``cut`` of its planned length: at 0.3 three switches, none of
    its cycles stable; at 0.5 three stable cycles, enough for analyze, one short of diagnose's four)."""
    t1 = plan_test(M, -0.4, gen.AMPLITUDE, cycles=8)
    tests = tuple(FlownTest(-0.4, k * t1.h, t1.duration) for k in heights)
    if lost is not None:
        t2 = plan_test(M, lost, gen.AMPLITUDE, cycles=8)
        tests += (FlownTest(lost, t2.h, cut * t2.duration),)
    fl = simulate_flight(FlightSpec(model=M, tests=tests, loop="altitude", rate_hz=200.0, seed=7, hover_s=2.0,
                                    hold_s=2.0))
    path = tmp / f"{name}.mcap"
    write_log([t for t in fl.topics if t.name != "/battery"], path, "mcap")
    return path


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("refusal")
    return {"one_height": _one_beta(tmp, (1.0, 1.0), "one_height"), "two_heights": _one_beta(tmp, (1.0, 2.0), "two"),
            "one_left": _one_beta(tmp, (1.0,), "one_left", lost=-0.7),
            "three_left": _one_beta(tmp, (1.0,), "three_left", lost=-0.7, cut=0.5)}


def _counting(monkeypatch) -> list[int]:
    """analyze_flight's calls from here on (the CLI and the diagnosis import it from mrftcli.analyze)."""
    calls: list[int] = []
    real = mrftcli.analyze.analyze_flight
    monkeypatch.setattr(mrftcli.analyze, "analyze_flight", lambda *a, **k: calls.append(1) or real(*a, **k))
    return calls


def test_the_cli_runs_analyze_once_on_a_log_it_refuses(logs, monkeypatch, tmp_path):
    calls = _counting(monkeypatch)
    r = run_main("diagnose", str(logs["one_height"]), "--tp", str(M.Tp), "-q", "--json", str(tmp_path / "d.json"))
    assert r.returncode == 6 and "only one beta" in r.stderr, r.stderr
    assert len(calls) == 1  # was 2: the diagnosis ran analyze again to learn the same refusal
    # the refusal says what analyze's says: the partial result on the terminal and in --json (was: no JSON)
    a = run_main("analyze", str(logs["one_height"]), "--tp", str(M.Tp), "-q", "--json", str(tmp_path / "a.json"))
    assert a.returncode == 6
    assert json.loads((tmp_path / "d.json").read_text()) == json.loads((tmp_path / "a.json").read_text())
    assert "partial result: tau for an assumed Td range" in r.stdout


def _refusal(path: Path) -> InsufficientDataError:
    with pytest.raises(InsufficientDataError, match="only one beta") as exc:
        mrftcli.analyze.analyze_flight(read_flight(path, ReadOptions(loop="altitude")), soiptd_model(M.Tp))
    return exc.value


def test_a_refusal_handed_over_gives_the_screen_analyze_again_gives(logs, monkeypatch):
    # two relay heights at one beta: the diagnosis goes on, with the same tests and warnings either way
    refusal = _refusal(logs["two_heights"])
    fl = read_flight(logs["two_heights"], ReadOptions(loop="altitude"))
    again = screen_log(fl, soiptd_model(M.Tp), None, lambda *a, **k: None)
    calls = _counting(monkeypatch)
    handed = screen_log(fl, soiptd_model(M.Tp), None, lambda *a, **k: None, refusal)
    assert calls == []
    assert handed.analysis is None and [t.index for t in handed.tests] == [t.index for t in again.tests]
    assert len(handed.tests) == 2 and handed.warnings == again.warnings
    assert handed.analyze_refusal == again.analyze_refusal == str(refusal).removeprefix(f"{fl.path}: ")
    assert handed.analyze_refusal.startswith("only one beta was tested (")


def test_a_refusal_that_is_not_evidence_is_the_commands(logs, monkeypatch):
    fl = read_flight(logs["one_height"], ReadOptions(loop="altitude"))
    calls = _counting(monkeypatch)
    one_beta = _refusal(logs["one_height"])  # one beta at one relay height: nothing to compare
    with pytest.raises(InsufficientDataError) as exc:
        screen_log(fl, soiptd_model(M.Tp), None, lambda *a, **k: None, one_beta)
    assert exc.value is one_beta and len(calls) == 1  # the call in _refusal only
    no_test = SegmentationError("no usable MRFT limit cycle")
    with pytest.raises(SegmentationError) as seg:
        screen_log(fl, soiptd_model(M.Tp), None, lambda *a, **k: None, no_test)
    assert seg.value is no_test
    # no plant of eq. (2) fits: the strongest sign of missing physics, diagnosed (its reason in a warning)
    screen = screen_log(fl, soiptd_model(M.Tp), None, lambda *a, **k: None,
                        IdentificationError(f"{fl.path}: no plant of eq. (2) produces these tests' frequencies"))
    assert screen.analyze_refusal == "no plant of eq. (2) produces these tests' frequencies"
    assert len(calls) == 1


def test_a_log_analyze_refuses_is_diagnosed_and_says_so_first(logs, monkeypatch, tmp_path):
    calls = _counting(monkeypatch)
    out = tmp_path / "d.json"
    r = run_main("diagnose", str(logs["two_heights"]), "--tp", str(M.Tp), "-q", "--json", str(out))
    assert r.returncode == 0, r.stderr
    assert len(calls) == 1
    # analyze's reason as data (the JSON's analyze_refusal, schema 3), the terminal's second line printed from it
    reason = str(_refusal(logs["two_heights"])).removeprefix(f"{logs['two_heights']}: ")
    data = json.loads(out.read_text())
    assert data["schema_version"] == 3 and data["analyze_refusal"] == reason
    assert DiagnosisResult.from_json(data).analyze_refusal == reason
    second = r.stdout.splitlines()[1]
    assert second == (f"analyze refuses this log: {reason}; the diagnosis below fits the recorded cycles itself "
                      "(no model of analyze's to compare with)"), second
    assert (r.stdout + r.stderr).count("only one beta was tested") == 1  # said once, not again in a warning


def test_the_first_line_gives_a_refusal_with_brackets_whole(logs, monkeypatch):
    # the line was read back out of a warning's text (split at " (" and ";"): "no plant of eq.; ..." came out
    reason = "no plant of eq. (2) produces these tests' frequencies (1.2 and 3.4 rad/s); check --tp (try 0.05 s)"

    def refuse(flight, *args, **kwargs):
        raise IdentificationError(f"{flight.path}: {reason}")

    monkeypatch.setattr(mrftcli.analyze, "analyze_flight", refuse)
    r = run_main("diagnose", str(logs["two_heights"]), "--tp", str(M.Tp), "-q")
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[1] == (f"analyze refuses this log: {reason}; the diagnosis below fits the recorded "
                                        "cycles itself (no model of analyze's to compare with)")


def test_one_test_left_of_a_flight_at_two_betas_is_refused_as_analyze_does(logs, monkeypatch):
    # the -0.7 test was flown but lost (two cycles): the flight is comparable, yet one test is left to
    # diagnose and nothing to compare it with; the benchmark's flights like it were named wrong 4 of 4
    refusal = _refusal(logs["one_left"])
    fl = read_flight(logs["one_left"], ReadOptions(loop="altitude"))
    with pytest.raises(InsufficientDataError) as exc:
        screen_log(fl, soiptd_model(M.Tp), None, lambda *a, **k: None, refusal)
    msg = str(exc.value)
    assert msg.startswith(str(refusal)) and "no second test is left to compare it with" in msg and "\n" not in msg
    # analyze's refusal, first, says why the -0.7 test was rejected; diagnose does not say it again (E6's note)
    assert "0 stable cycles (need 3)" in str(refusal) and msg.count("0 stable cycles") == 1, msg
    assert msg.endswith("so no second test is left to compare it with (fly the lost test again)"), msg
    assert exc.value.partial == refusal.partial
    # the test is named by its flown span, as analyze's message names it (was: its stable cycles' span beside it)
    flown = re.search(r"beta -0.4 at (\S+ s)", str(refusal))
    assert flown is not None and f"diagnose: only the test at {flown[1]} has 4 stable cycles" in msg, msg
    calls = _counting(monkeypatch)
    r = run_main("diagnose", str(logs["one_left"]), "--tp", str(M.Tp), "-q")
    assert r.returncode == 6 and "no second test is left" in r.stderr and "Traceback" not in r.stderr
    assert len(calls) == 1


def test_one_test_left_of_a_log_analyze_identifies_is_diagnosed_and_said(logs, monkeypatch):
    # the -0.7 test kept three stable cycles: analyze identifies the log from both tests, while the diagnosis
    # (four stable cycles a test) is left with the -0.4 one. It goes on from that test (naming the explanations
    # one test cannot tell apart: test_diagnose.test_models_the_tests_cannot_rank_are_named) and says first
    # which test it has and why the other was left out (the test named by its flown span, as analyze names it)
    path = logs["three_left"]
    fl = read_flight(path, ReadOptions(loop="altitude"))
    analysis = mrftcli.analyze.analyze_flight(fl, soiptd_model(M.Tp))
    assert sorted(round(float(t.beta_effective), 1) for t in analysis.tests) == [-0.7, -0.4]
    screen = screen_log(fl, soiptd_model(M.Tp), analysis, lambda *a, **k: None)
    said = [w for w in screen.warnings if "only one test has the 4 stable cycles" in w]
    assert len(said) == 1 and "diagnose needs and can measure (beta -0.4 at " in said[0], screen.warnings
    assert "has 3 stable cycles; the diagnosis needs 4, so it is left out" in said[0]
    assert said[0].endswith("the effects below are named from its waveform alone")
    calls = _counting(monkeypatch)
    r = run_main("diagnose", str(path), "--tp", str(M.Tp), "-q")
    assert r.returncode == 0 and "only one test has the 4 stable cycles" in r.stderr + r.stdout, r.stderr
    assert "Traceback" not in r.stderr and len(calls) == 1


def test_a_test_whose_cycles_are_too_sparsely_logged_to_measure_is_named_as_such():
    # PX4 at 10 Hz: the -0.6 test's 7 stable cycles have fewer output samples than the waveform fit's unknowns
    # (was: left out without a word, and the -0.2 test diagnosed alone); analyze identifies the log, so the
    # diagnosis goes on from the -0.2 test and says so
    log = ROOT / "sample_logs" / "px4_altitude_10hz.ulg"
    r = run_main("diagnose", str(log), "--tp", "0.0422", "--loop", "altitude", "-q")
    assert r.returncode == 0, r.stderr
    said = r.stderr + r.stdout
    assert "only one test has the 4 stable cycles diagnose needs and can measure (beta -0.2 at 23.8-60.3 s" in said, said
    assert "test 1 (beta -0.54): 0 of its 7 stable cycles can be measured" in said and "log the output faster" in said
