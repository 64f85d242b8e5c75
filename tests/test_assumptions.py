"""Issue 26: never a confident wrong answer. Each case is run from the CLI as the user meets it.

The oracles are independent of the code under test: the truth sidecars of the sample logs (the
simulator's plant), and the closed-form scaling of the gains with 1/K.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
from pathlib import Path

import pytest

from cli_helpers import run_main

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_logs"


def run(*args: str) -> subprocess.CompletedProcess[str]:
    """``mrft-ident ARGS`` from the checkout's root, through main() in this process with the warning filters of a
    plain ``python -m mrftcli`` (cli_helpers.run_main: a fresh interpreter costs ~1.4 s of imports a call; the
    entry point itself is run as a process in test_cli.py)."""
    with contextlib.chdir(ROOT):
        return run_main(*args)


def one_line_error(proc: subprocess.CompletedProcess[str], code: int = 2) -> str:
    """The process failed with ``code`` and one ``error:`` line on stderr (no traceback); that line."""
    assert proc.returncode == code, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[0]


# item 1: tune rests on no silent default

MODEL = ["--tp", "0.0422", "--td", "1.3", "--tau", "0.03"]


def test_tune_without_k_names_the_option():
    err = one_line_error(run("tune", *MODEL, "--loop", "roll", "--controller-rate", "200"))
    assert "--k" in err and "gain K" in err


def test_tune_without_loop_names_the_option():
    err = one_line_error(run("tune", *MODEL, "--k", "30", "--controller-rate", "200"))
    assert "--loop" in err


def test_tune_without_a_rate_names_the_option():
    err = one_line_error(run("tune", *MODEL, "--k", "30", "--loop", "roll"))
    assert "--controller-rate" in err


def test_tune_gains_scale_as_one_over_k():
    """The MRFT rule's Kp for K = 30 is the K = 1 one over 30 (G is linear in K): the K given is the K used."""
    def kp(k: str) -> float:
        proc = run("tune", *MODEL, "--k", k, "--loop", "roll", "--controller-rate", "200", "--design", "mrft-rule",
                   "--export", "generic")
        assert proc.returncode == 0, proc.stderr
        return float(json.loads(proc.stdout)["Kp"])

    assert kp("30") == pytest.approx(kp("1") / 30, rel=1e-6)
    assert kp("30") == pytest.approx(1.955, abs=1e-3)  # the figure


def test_tune_result_json_takes_its_loop_from_the_file(tmp_path):
    result = tmp_path / "r.json"
    log = str(SAMPLES / "design1_roll.mcap")
    assert run("analyze", log, "--tp", "0.0422", "--loop", "roll", "--json", str(result)).returncode == 0
    proc = run("tune", str(result), "--tp", "0.0422", "--export", "hear")
    assert proc.returncode == 0, proc.stderr
    explicit = run("tune", str(result), "--tp", "0.0422", "--export", "hear", "--loop", "roll")
    assert proc.stdout == explicit.stdout  # the file's loop, roll, was used
    err = one_line_error(run("tune", log, "--tp", "0.0422"))  # a LOG needs its loop
    assert "--loop" in err


# item 7: a missing --tp names the option and what it is

@pytest.mark.parametrize("command", [
    ["analyze", "sample_logs/design1_altitude.mcap"],
    ["diagnose", "sample_logs/design1_altitude.mcap"],
    ["tune", "--td", "1.3", "--tau", "0.03", "--k", "30", "--loop", "roll", "--controller-rate", "200"],
    ["plan", "--max-amplitude", "0.05", "--max-h", "0.2", "--time", "30", "--controller-rate", "200"],
])
def test_missing_tp_says_which_option_and_what_it_is(command):
    err = one_line_error(run(*command))
    assert "--tp" in err and "propulsion time constant" in err and "None" not in err


def test_library_missing_tp_is_an_input_error():
    from mrftcli.errors import InputError
    from mrftcli.validate import check_tp

    with pytest.raises(InputError, match="Tp is missing"):
        check_tp(None)  # type: ignore[arg-type]  # what an unset option passes


# item 2: a wrong Tp is named, not absorbed into a tight wrong tau (truth: the sample's sidecar)

def _truth(log: str) -> dict:
    return json.loads((SAMPLES / f"{log}.truth.json").read_text())


@pytest.mark.parametrize("log, factor", [("design1_altitude.mcap", 1 / 10), ("design1_altitude.mcap", 1 / 3),
                                         ("design2_roll.mcap", 3), ("design1_pitch.mcap", 10)])
def test_a_wrong_tp_is_named_with_the_tp_the_recording_fits(log, factor):
    truth = _truth(log)
    Tp = truth["Tp"] * factor
    proc = run("analyze", f"sample_logs/{log}", "--tp", f"{Tp:.6g}", "--loop", truth["loop"], "--json", "-")
    data = json.loads(proc.stdout)
    first = data["warnings"][0]
    assert first.startswith("the recording fits Tp = ") and "check --tp" in first
    best = float(first.split("Tp = ")[1].split(" s")[0])
    low, high = (float(v) for v in first.split("[")[1].split("]")[0].split(", "))
    assert best == pytest.approx(truth["Tp"], rel=0.02)
    assert low <= truth["Tp"] * 1.01 and high >= truth["Tp"] * 0.99 and not low <= Tp <= high


@pytest.mark.parametrize("factor", [3, 10])
def test_a_too_large_tp_the_frequencies_refuse_names_tp(factor):
    """A Tp 3x or 10x too large: refused (exit 5, one line) naming --tp. Eq. (2) admits a lead of an estimator's
    few ms (at most 6 ms, mrft.model.lead_floor): where the frequencies imply more (10x: 19 ms) they refuse it
    ('a lead ... beyond the 6 ms eq. (2) admits ... check --tp'); where a smaller lead fits them (3x) the
    waveform's Tp check does, and names the true Tp."""
    truth = _truth("design1_altitude.mcap")["Tp"]
    err = one_line_error(run("analyze", "sample_logs/design1_altitude.mcap", "--tp", f"{truth * factor:.6g}", "--loop",
                             "altitude"), code=5)
    if "it fits Tp = " not in err:
        assert "beyond the 6 ms eq. (2) admits" in err and "check --tp" in err
        return
    assert f"the recording rejects Tp = {truth * factor:.4g} s: it fits Tp = " in err and "--accept-tp" in err
    fitted = float(err.split("it fits Tp = ")[1].split(" s")[0])
    assert fitted == pytest.approx(truth, rel=0.02)


def test_the_right_tp_gets_no_tp_warning():
    truth = _truth("design1_altitude.mcap")
    proc = run("analyze", "sample_logs/design1_altitude.mcap", "--tp", repr(truth["Tp"]), "--loop", "altitude",
               "--json", "-")
    assert proc.returncode == 0 and not any("fits Tp" in w for w in json.loads(proc.stdout)["warnings"])


# item 4: diagnose says how its linear model relates to analyze's, which refit to take, and units

def test_diagnose_names_analyzes_model_one_estimate_and_units():
    proc = run("diagnose", "sample_logs/concealed/flight_02.mcap", "--tp", "0.0422", "--loop", "altitude")
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "analyze's model of this log" in out and "differ by that choice of data" in out
    assert out.count("<- the estimate to use") == 1  # one recommended estimate for the one effect found
    assert "T_lag = 0.0703 s" in out  # the candidate's parameter with its unit
    for line in out.splitlines():
        if line.lstrip().startswith(("linear model", "analyze's model", "refit")):
            assert "m/s² per command unit" in line, line
    truth = json.loads((SAMPLES / "concealed" / "flight_02.mcap.truth.json").read_text()) \
        if (SAMPLES / "concealed" / "flight_02.mcap.truth.json").exists() else None
    if truth is not None and "Td" in truth:  # the recommended estimate against the simulator's plant
        rec = next(line for line in out.splitlines() if "<- the estimate to use" in line)
        Td = float(rec.split("Td ")[1].split(" s")[0])
        assert Td == pytest.approx(truth["Td"], rel=0.05)
