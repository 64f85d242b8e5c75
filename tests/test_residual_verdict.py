"""Issue 40 item 4: analyze and diagnose give one verdict on the waveform residual.

Oracle: hear_x.bag is simulated with the linear model and no effect (its truth file: ``effects_active``
empty), with receive-time stamps and a 90 Hz output off the controller's ticks; so "the recording holds
dynamics eq. (2) leaves out" is wrong there, and diagnose's "the linear model explains the log" right.
"""

from __future__ import annotations

import json
from pathlib import Path

from cli_helpers import run_cli

from mrftcli.analyze import AnalysisResult
from mrftcli.analyze.residual import MISMATCH_WORDS, residual_verdict

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"
HEAR_X = SAMPLES / "hear_x.bag"


def test_analyze_and_diagnose_agree_on_hear_x(tmp_path, capsys):
    truth = json.loads((SAMPLES / "hear_x.bag.truth.json").read_text())
    assert truth["effects_active"] == []
    tp = str(truth["Tp"])
    out = tmp_path / "a.json"
    code, _, err = run_cli(capsys, "analyze", str(HEAR_X), "--tp", tp, "--loop", "x", "--json", str(out))
    assert code == 0, err
    assert MISMATCH_WORDS not in err and "cannot tell timing from dynamics" in err
    verdict = residual_verdict(AnalysisResult.from_json(json.loads(out.read_text())))
    assert verdict is not None and verdict.verdict == "untestable" and verdict.ratio > 1.15

    code, stdout, err = run_cli(capsys, "diagnose", str(HEAR_X), "--tp", tp, "--loop", "x", "-q")
    assert code == 0, err
    assert "found: nothing: the linear model explains the log" in stdout
    assert f"waveform residual (analyze's test): {verdict.sentence}" in stdout


def test_a_header_stamped_mismatch_is_a_mismatch_for_both(tmp_path, capsys):
    """A header-stamped log (the CSV of design1_altitude: a bag or MCAP holds the recorder's receive times) and
    a residual above the factor: 'mismatch', worded as analyze's."""
    out = tmp_path / "a.json"
    code, _, err = run_cli(capsys, "analyze", str(SAMPLES / "design1_altitude.csv"), "--tp", "0.1", "--accept-tp",
                           "--json", str(out))
    assert code == 0, err
    data = json.loads(out.read_text())
    verdict = residual_verdict(AnalysisResult.from_json(data))
    assert verdict is not None and verdict.verdict == "mismatch" and MISMATCH_WORDS in verdict.sentence
    assert MISMATCH_WORDS in err  # analyze says so too
    data["refinement"]["residual_ratio"] = 1.0
    assert residual_verdict(AnalysisResult.from_json(data)).verdict == "explained"


def test_receive_stamps_without_jitter_leave_the_residual_testable(tmp_path, capsys):
    """Receive stamps on the publisher's ticks (jitter under 1 us) hold no timing jitter: the residual's
    'mismatch' stands; with 1 ms of jitter it is 'untestable' (the record's own stamps and jitter decide)."""
    out = tmp_path / "a.json"
    code, _, err = run_cli(capsys, "analyze", str(SAMPLES / "design1_altitude.mcap"), "--tp", "0.1", "--accept-tp",
                           "--json", str(out))
    assert code == 0, err
    data = json.loads(out.read_text())
    source = data["input"]["source"] if "input" in data and "source" in data["input"] else None
    assert source is not None and source["timestamps"] == "receive" and source["timing_jitter_s"] < 1e-6, source
    assert residual_verdict(AnalysisResult.from_json(data)).verdict == "mismatch"
    assert MISMATCH_WORDS in err
    source["timing_jitter_s"] = 1e-3
    assert residual_verdict(AnalysisResult.from_json(data)).verdict == "untestable"
