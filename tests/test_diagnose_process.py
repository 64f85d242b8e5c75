"""``diagnose --model NAME`` (mrftcli.diagnose.diagnose with a process family) on recordings of tests/process_sim.py.

The oracle is the independent simulator: a FOPDT recorded under two hysteresis relays (one biased) is a
FOPDT, so the check must call it consistent; a second-order plant recorded the same way and analysed
as FOPDT is not, and its mean cycle differs from any FOPDT cycle in its higher harmonics (a
second-order plant rounds the corners a first-order one has after each switch).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from cli_helpers import run_main

sys.path.insert(0, str(Path(__file__).parent))
from process_sim import Window, simulate, write_csv  # noqa: E402

from mrftcli.diagnose import DiagnosisResult, diagnose  # noqa: E402
from mrftcli.errors import InputError  # noqa: E402
from mrftcli.io import ReadOptions, read_flight  # noqa: E402
from mrftcli.mrft.families import family_model  # noqa: E402

WINDOWS = [Window("hysteresis", 1.0, -1.0, eps=0.05, duration=25.0),
           Window("hysteresis", 1.5, -0.5, eps=0.3, duration=25.0)]
READ = ReadOptions(command_topic="u_relay", output_topic="y_output")


def _recording(tmp_path: Path, family: str, params: dict[str, float]) -> Path:
    t, u, y = simulate(family, params, WINDOWS, 100.0, 0.01, seed=1)
    path = tmp_path / f"{family}.csv"
    write_csv(str(path), t, u, y)
    return path


@pytest.fixture(scope="module")
def fopdt_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _recording(tmp_path_factory.mktemp("fopdt"), "fopdt", dict(K=2.0, T=1.0, tau=0.3))


@pytest.fixture(scope="module")
def sopdt_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _recording(tmp_path_factory.mktemp("sopdt"), "sopdt", dict(K=2.0, T1=0.7, T2=0.3, tau=0.15))


@pytest.fixture(scope="module")
def fopdt_diagnosis(fopdt_csv: Path) -> DiagnosisResult:
    return diagnose(read_flight(fopdt_csv, READ, echo_warnings=False), family_model("fopdt"))


def test_clean_fopdt_under_two_relays_is_consistent(fopdt_diagnosis):
    result = fopdt_diagnosis
    assert result.consistent and result.summary == "consistent with FOPDT within the tests' scatter"
    assert not result.located and len(result.checks) == 2
    assert not result.found and result.candidates  # the library was fitted and named nothing
    for check in result.checks:
        # each test's cycle predicted from the OTHER test's model: within 1 % and 3 sd
        assert check.frequency_error is not None and abs(check.frequency_error) < 0.01
        assert check.frequency_z is not None and abs(check.frequency_z) < 3
        assert check.amplitude_error is not None and abs(check.amplitude_error) < 0.03
        assert [b.band for b in check.all_bands] == ["fundamental", "2-3", "higher"]
        assert all(b.ratio < 3 for b in check.all_bands + check.held_out_bands)


@pytest.fixture(scope="module")
def sopdt_as_fopdt_cli(sopdt_csv: Path, tmp_path_factory: pytest.TempPathFactory):
    """``diagnose --model fopdt --json --report`` on the second-order recording, once for the module (main() in
    this process): the CLI test reads its output, the located-and-named test its record (the same diagnosis;
    the record's round trip is test_process_diagnosis_json_round_trip_and_refusals')."""
    tmp = tmp_path_factory.mktemp("sopdt_cli")
    run = run_main("diagnose", str(sopdt_csv), "--command-topic", "u_relay", "--output-topic", "y_output",
                   "--model", "fopdt", "--json", str(tmp / "d.json"), "--report", str(tmp / "rep"))
    return run, tmp


def test_second_order_plant_analysed_as_fopdt_is_located_and_its_second_lag_named(sopdt_as_fopdt_cli):
    run, tmp = sopdt_as_fopdt_cli
    assert run.returncode == 0, run.stderr
    result = DiagnosisResult.from_json(json.loads((tmp / "d.json").read_text()))
    assert not result.consistent
    # the library names the lag FOPDT leaves out: the simulator's lags are 0.7 s and 0.3 s, FOPDT's T
    # takes one, the effect the other; each test predicted from the other at least halves its error
    assert result.summary.startswith("found: sensor_lag")
    (lag,) = result.effects
    fopdt_T = lag.refit["T"]  # FOPDT refitted with the lag taken out
    assert sorted([lag.value, fopdt_T]) == pytest.approx([0.3, 0.7], rel=0.15)
    assert lag.held_out_after < 0.5 * lag.held_out_before
    assert "harmonics 2-3 (most at 3)" in result.located[0]  # the FOPDT cycle's corners: the 3rd harmonic
    for check in result.checks:
        bands = {b.band: b for b in check.all_bands}
        assert bands["2-3"].ratio > 3 and bands["2-3"].peak == 3
        assert bands["fundamental"].ratio < bands["2-3"].ratio
    assert any("chi2/dof" in text for text in result.located)  # the response points disagree too


def test_process_diagnosis_json_round_trip_and_refusals(fopdt_diagnosis):
    result = fopdt_diagnosis
    data = json.loads(json.dumps(result.to_json()))
    assert data["schema_version"] == 3 and data["consistent"] is True  # the one diagnosis record (issue 36)
    assert data["checks"][0]["held_out"]["frequency_hz"] == pytest.approx(result.checks[0].held_out_frequency_hz)
    assert {c["name"] for c in data["candidates"]} >= {"sensor_lag", "dead_zone", "delay_jitter"}
    assert data["kind"] == "diagnosis" and data["family"] == "fopdt" and data["summary"] == result.summary
    back = DiagnosisResult.from_json(data)
    assert back.to_json() == result.to_json()
    with pytest.raises(InputError, match="schema_version"):
        DiagnosisResult.from_json({**data, "schema_version": 99})
    with pytest.raises(InputError, match="'checks'"):
        DiagnosisResult.from_json({"schema_version": 2, "family": "fopdt", "summary": "x", "candidates": [],
                                   "second_effect_candidates": [], "analysis": data["analysis"]})


def test_cli_diagnose_model_verdict_first_and_json(sopdt_as_fopdt_cli):
    run, tmp_path = sopdt_as_fopdt_cli
    out = tmp_path / "d.json"
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    assert lines[0].startswith("found: sensor_lag (T_lag ")
    assert "frequency [Hz]" in lines[1] and "Traceback" not in run.stderr
    assert DiagnosisResult.from_json(json.loads(out.read_text())).summary == lines[0]
    # the one record's page, every family: the verdict, each test held out, the library's evidence
    page = (tmp_path / "rep" / "diagnosis.html").read_text()
    assert lines[0].split(" (")[0] in page and "Each test against the model of the other tests" in page
    assert (tmp_path / "rep" / "diagnosis_evidence.png").stat().st_size > 0


def test_cli_diagnose_process_options_need_a_process_model(fopdt_csv):
    from click.testing import CliRunner

    from mrftcli.cli import cli

    runner = CliRunner()
    res = runner.invoke(cli, ["diagnose", str(fopdt_csv), "--tp", "0.05", "--relay", "ideal"])
    assert res.exit_code == 2 and "process model" in res.output
    res = runner.invoke(cli, ["diagnose", str(fopdt_csv), "--command-topic", "u_relay", "--output-topic",
                              "y_output"])
    assert res.exit_code == 2 and "--tp" in res.output
    # --tp with a process model is refused (as in analyze and watch), never silently ignored
    res = runner.invoke(cli, ["diagnose", str(fopdt_csv), "--model", "fopdt", "--tp", "0.04", "--command-topic",
                              "u_relay", "--output-topic", "y_output"])
    assert res.exit_code == 2 and "--tp is eq. (2)'s" in res.output and "--param" in res.output
    res = runner.invoke(cli, ["diagnose", str(fopdt_csv), "--tp", "0.05", "--window", "0:10"])  # eq. (2): no --window
    assert res.exit_code == 2 and "--window takes a process model" in res.output


def test_one_test_is_not_held_out_and_says_so(fopdt_csv):
    flight = read_flight(fopdt_csv, READ, echo_warnings=False)
    result = diagnose(flight, family_model("fopdt"), windows=[(0.0, 28.0)])
    (check,) = result.checks
    assert check.held_out_frequency_hz is None and check.frequency_z is None
    assert check.note == "no other test to hold it out against"
    assert result.summary.startswith("consistent with FOPDT within the noise, on one test only")


@pytest.mark.parametrize("effect, value", [("dead_zone", 0.4), ("input_bias", -0.25)])
def test_an_effect_on_an_integrating_plant_is_named_and_held_out_better(effect, value):
    """An IPDT under three hysteresis relays of heights 1, 1.6, 2.4 with an effect at the plant input,
    simulated by benchmarks/bench_diagnose_families.py's own code (scipy's tf2ss, no mrftcli): the
    library names it, its value within 10 %, and each test predicted from the others halves its error."""
    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from bench_diagnose_families import simulate

    from mrftcli.io.logtypes import FlightLog, Signal

    params = {"K": 1.5, "tau": 0.3}  # the cycle: period about 1.6 s at eps 0.1 h
    t, u, y = simulate("ipdt", params, effect, value, [(1.0, 0.05), (1.6, 0.08), (2.4, 0.12)], 100.0, 0.003,
                       1.6, seed=5)
    result = diagnose(FlightLog(path="ipdt.sim", loop="altitude", command=Signal(t, u), output=Signal(t, y)),
                      family_model("ipdt"))
    assert result.found[:1] == (effect,), result.summary
    (first, *_) = result.effects
    assert first.value == pytest.approx(value, rel=0.1)
    assert first.held_out_after < 0.5 * first.held_out_before


def test_the_diagnosis_checks_the_analysis_analyze_prints_with_its_baseline():
    """``analyze --model --baseline Y0 --diagnose``: the diagnosis' analysis is the one analyze prints (the
    operating point's static-gain constraint included), not a second one without it. Oracle: the analysis
    itself, run with and without the baseline on a biased-relay FOPDT flown by tests/process_sim.py."""
    from mrftcli.analyze.general import general_analysis, measure_tests
    from mrftcli.io.logtypes import FlightLog, Signal

    windows = [Window("hysteresis", 1.5, -0.5, eps=0.05, duration=15, rest=3),
               Window("hysteresis", 2.0, -1.0, eps=0.1, duration=15, rest=3)]
    t, u, y = simulate("fopdt", dict(K=2.0, T=1.0, tau=0.3), windows, 100.0, 0.003, seed=3)
    flight = FlightLog(path="biased.sim", loop="altitude", command=Signal(t, u), output=Signal(t, y))
    model = family_model("fopdt")
    with_y0 = general_analysis(flight, model, measure_tests(flight), (), (0.0, 0.01))
    without = general_analysis(flight, model, measure_tests(flight))
    result = diagnose(flight, model, baseline=(0.0, 0.01))
    assert result.analysis is not None and result.analysis.identification is not None

    def k(a):
        return next(e for e in a.identification.estimates if e.name == "K")

    assert (k(result.analysis).value, k(result.analysis).std) == (k(with_y0).value, k(with_y0).std)
    assert (k(with_y0).value, k(with_y0).std) != (k(without).value, k(without).std)  # the baseline is seen
