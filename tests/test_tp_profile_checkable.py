"""A wrong Tp is named, or the output says the log cannot check Tp (issue 26 item 2).

The two sample logs whose waveform cannot tell Tp (``benchmarks/bench_tp_profile.py``): the PX4 log
whose command is logged at 10 Hz below the 50 Hz controller (no waveform refinement), and the HEAR
log whose receive-stamped delay jitter leaves eq. (2)'s residual near 9x the noise at every Tp. With
a wrong Tp their tau is far from the simulation's truth (the sidecar), so the first warning must say
that Tp was not checked rather than leave a tight wrong tau unqualified.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_helpers import run_main

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalyzeOptions, analyze_flight
from mrftcli.io import read_flight
from mrftcli.io.flight import ReadOptions
from mrftcli.mrft.profile import TpProfile

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_logs"


def _truth(log: str) -> dict:
    return json.loads((SAMPLES / f"{log}.truth.json").read_text())


def test_a_log_below_the_controller_rate_says_tp_is_not_checkable_cli() -> None:
    truth = _truth("px4_altitude_10hz.ulg")
    Tp = truth["Tp"] / 10
    proc = run_main("analyze", str(SAMPLES / "px4_altitude_10hz.ulg"), "--tp", f"{Tp:.6g}", "--loop", truth["loop"],
                    "--json", "-")  # main() in this process (cli_helpers)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    tau = data["parameters"]["tau"]["value"]
    assert abs(tau - truth["tau"]) > 0.1 * truth["tau"]  # the wrong Tp did move tau: silence would be a lie
    first = data["warnings"][0]
    assert first.startswith("Tp is not checkable from this log (the command is logged below the controller's rate")
    assert f"given Tp = {Tp:.3g} s" in first and "check --tp" in first


def test_a_waveform_eq2_fits_at_no_tp_says_tp_is_not_checkable() -> None:
    truth = _truth("hear_x.bag")
    flight = read_flight(SAMPLES / "hear_x.bag", ReadOptions(loop=truth["loop"]), echo_warnings=False)
    result = analyze_flight(flight, soiptd_model(truth["Tp"] / 3), options=AnalyzeOptions(n_bootstrap=50))
    assert abs(result.tau.value - truth["tau"]) > 0.1 * truth["tau"]
    first = result.warnings[0]
    assert first.startswith("Tp is not checkable from this log (eq. (2) leaves the waveform residual at ")
    assert "the sensor noise or more at every Tp from" in first


def _profile(best: float, low: float, high: float, ratio_given: float, ratio_best: float) -> TpProfile:
    return TpProfile(given=0.01, best=best, low=low, high=high, residual_ratio_given=ratio_given,
                     residual_ratio_best=ratio_best, grid=((0.001, ratio_given), (best, ratio_best), (0.1, 20.0)))


@pytest.mark.parametrize("profile, starts", [
    (_profile(0.04, 0.038, 0.042, 6.0, 1.02), "the recording fits Tp = 0.04 s [0.038, 0.042]"),  # named
    (_profile(0.04, 0.03, 0.05, 9.3, 9.0), "Tp is not checkable"),  # eq. (2) holds nowhere: no Tp named
    (_profile(0.0101, 0.009, 0.011, 1.1, 1.09), None),  # the given Tp fits
])
def test_what_the_profile_says(profile: TpProfile, starts: str | None) -> None:
    said = profile.warnings()
    if starts is None:
        assert said == ()
    else:
        assert len(said) == 1 and said[0].startswith(starts)
        assert "given" in said[0] and "0.01 s" in said[0]


def test_a_td_below_the_given_tp_is_named_as_the_fast_pole(tmp_path: Path) -> None:
    """--tp 45x the truth (1.9 s against 0.0422 s): the fit puts the recording's fast pole in Td (eq. (2) is
    symmetric in Tp and Td), so Td lands near the sidecar's Tp, below the given one; one warning says so, in the
    text and the JSON, and the run still exits 0 (the swapped model is the same transfer function)."""
    truth = _truth("design1_altitude.mcap")
    out = tmp_path / "a.json"
    proc = run_main("analyze", str(SAMPLES / "design1_altitude.mcap"), "--tp", "1.9", "-q", "--json", str(out))
    assert proc.returncode == 0, proc.stderr
    data = json.loads(out.read_text())
    Td = data["parameters"]["Td"]["value"]
    assert 0.5 * truth["Tp"] < Td < 2 * truth["Tp"]  # the fast pole, from the sidecar
    said = [w for w in data["warnings"] if "came out shorter than the given Tp (1.9 s)" in w]
    assert len(said) == 1 and said[0].startswith(f"Td ({Td:.3g} s)") and "check --tp" in said[0]
    assert sum(line.startswith("warning: Td (") for line in (proc.stdout + proc.stderr).splitlines()) == 1
    right = run_main("analyze", str(SAMPLES / "design1_altitude.mcap"), "--tp", str(truth["Tp"]), "-q", "--json", "-")
    assert right.returncode == 0 and "came out shorter" not in right.stdout  # the true Tp: Td 2.7 s, no warning
