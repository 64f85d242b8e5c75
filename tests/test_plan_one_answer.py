"""Issue 40 item 5: one plan per flight, whichever way it is given; honest notes; the conventional guard.

Oracles: the sample log's simulated sensor noise (its truth file), the plan's own predicted stds (a
"poorly determined" note must not sit beside a std of a few per cent), and the conventional pair's
forecast the plan prints beside its own.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_helpers import run_cli

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"
LOG = SAMPLES / "design1_altitude.mcap"
LIMITS = ["--tp", "0.0422", "--max-amplitude", "0.05", "--max-h", "0.2", "--time", "15", "-q"]


def test_plan_from_a_log_equals_plan_from_its_analysis_json(tmp_path, capsys):
    analysis = tmp_path / "first.json"
    code, _, err = run_cli(capsys, "analyze", str(LOG), "--tp", "0.0422", "--json", str(analysis))
    assert code == 0, err
    noise = json.loads(analysis.read_text())["noise"]["std"]
    assert noise == pytest.approx(json.loads((SAMPLES / "design1_altitude.mcap.truth.json").read_text())["noise_std"],
                                  rel=0.1)
    plans = {}
    for name, source in (("log", LOG), ("json", analysis)):
        out = tmp_path / f"plan_{name}.json"
        code, stdout, err = run_cli(capsys, "plan", *LIMITS, "--from", str(source), "--simulate", "0", "--json", str(out))
        assert code == 0, err
        plans[name] = (json.loads(out.read_text()), stdout)
    assert plans["log"][0] == plans["json"][0]  # one flight, one answer
    assert plans["log"][1] == plans["json"][1]
    data = plans["json"][0]
    assert data["limits"]["noise_std"] == pytest.approx(noise)  # the measured noise, not the 0.5 mm default
    assert not any("sensor noise" in a for a in data["assumptions"])
    # one controller rate for a log: plan's is the one tune designs for (analyze's, its tests' 199.995 Hz
    # median to 0.1 Hz); plan took the tests' upper median unrounded before
    code, stdout, err = run_cli(capsys, "tune", str(analysis), "--tp", "0.0422", "--json", "-", "--quiet")
    assert code == 0, err
    assert data["limits"]["rate_hz"] == json.loads(stdout)["rate_hz"] == 200.0


def test_no_poorly_determined_note_beside_a_small_std(capsys):
    """A prior that already knows tau to 1 %: tau is not 'poorly determined' whatever the tests add."""
    code, stdout, err = run_cli(capsys, "plan", *LIMITS, "--controller-rate", "200", "--noise", "0.0002",
                                "--k-range", "2", "8", "--tau-range", "0.046", "0.047", "--simulate", "0", "--json", "-")
    assert code == 0, err
    data = json.loads(stdout)
    tau_std = data["predicted_std"]["tau"]
    assert tau_std < 0.1 * 0.0465
    assert not any("tau stays poorly determined" in n for n in data["notes"])


def test_simulated_plan_never_silently_worse_than_the_conventional_pair(tmp_path, capsys):
    """With --simulate, the tests kept are no worse than -0.4 / -0.7 for Td and tau, or a note says why."""
    code, stdout, err = run_cli(capsys, "plan", *LIMITS, "--controller-rate", "200", "--noise", "0.0002",
                                "--k-range", "2", "8", "--time", "30", "--simulate", "16", "--json", "-")
    assert code == 0, err
    data = json.loads(stdout)
    conv = data["conventional"]["predicted_std"]
    worse = [p for p in ("Td", "tau") if data["predicted_std"][p] > conv[p] * (1 + 1e-6)]
    if worse:
        assert any("predicted worse than the conventional beta" in n for n in data["notes"]), data["notes"]


def test_single_beta_log_and_its_exit_6_json_give_one_plan(tmp_path, capsys):
    """One flown beta: analyze exits 6 with its partial (now with the measured noise); the plan from that JSON
    equals the plan from the log (which goes through the same object)."""
    log = tmp_path / "one.mcap"
    code, _, err = run_cli(capsys, "simulate", "--tp", "0.0422", "--td", "2.669", "--tau", "0.0464", "--k", "19.6",
                           "--test", "-0.4", "--noise", "0.0003", "--out", str(log))
    assert code == 0, err
    partial = tmp_path / "one.json"
    code, _, _ = run_cli(capsys, "analyze", str(log), "--tp", "0.0422", "--json", str(partial))
    assert code == 6
    noise = json.loads(partial.read_text())["partial"]["noise"]["std"]
    assert noise == pytest.approx(0.0003, rel=0.15)  # the simulated sensor noise
    plans = []
    for source in (log, partial):
        code, stdout, err = run_cli(capsys, "plan", *LIMITS, "--from", str(source), "--simulate", "0", "--json", "-")
        assert code == 0, err
        plans.append(json.loads(stdout))
    assert plans[0] == plans[1] and plans[0]["limits"]["noise_std"] == pytest.approx(noise)
