"""The analysis record: ``AnalysisResult.to_json`` / ``from_json`` round trips, version checks, and the
controller rate that ``tune`` reads the same from a log and from its RESULT.json.

The oracle of the round trip is the analysis itself (the typed record before writing) and the JSON text
itself (written, read, written again: the same text); the tune check compares two CLI runs that share
nothing but the log.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_cli

from mrftcli.mrft.model import soiptd_model
from mrftcli.io import ReadOptions
from mrftcli.analyze import AnalysisResult, AnalyzeOptions, SCHEMA_VERSION, analysis_controller_rate, analyze_path
from mrftcli.errors import InputError
from mrftcli.jsonable import to_jsonable

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_logs"


def _json_text(obj: object) -> str:
    return json.dumps(to_jsonable(obj), allow_nan=False, sort_keys=False)


@pytest.fixture(scope="module")
def design1() -> AnalysisResult:
    return analyze_path(SAMPLES / "design1_altitude.mcap", soiptd_model(0.0422), read=ReadOptions(loop="altitude"), options=AnalyzeOptions(n_bootstrap=100))


@pytest.fixture(scope="module")
def px4_10hz() -> AnalysisResult:
    return analyze_path(SAMPLES / "px4_altitude_10hz.ulg", soiptd_model(0.0422), read=ReadOptions(loop="altitude"), options=AnalyzeOptions(n_bootstrap=100))


def test_to_json_is_the_cli_json_with_the_schema_version_first(design1: AnalysisResult) -> None:
    d = design1.to_json()
    assert list(d)[0] == "schema_version" and d["schema_version"] == SCHEMA_VERSION == 4
    assert {k: v for k, v in d.items() if k != "schema_version"}.keys() == design1.to_dict().keys()
    assert _json_text({k: v for k, v in d.items() if k != "schema_version"}) == _json_text(design1.to_dict())


@pytest.mark.parametrize("name", ["design1", "px4_10hz"])
def test_from_json_rebuilds_the_typed_record(name: str, request: pytest.FixtureRequest) -> None:
    result: AnalysisResult = request.getfixturevalue(name)
    data = json.loads(_json_text(result.to_json()))
    back = AnalysisResult.from_json(data)
    for field in ("path", "loop", "Tp", "t0", "Td", "tau", "model", "method", "warnings", "notes",
                  "controller_rate_hz", "rejection_reasons", "estimate_method", "tp_check"):
        assert getattr(back, field) == getattr(result, field), field
    assert back.K.value == result.K.value and back.K.std == result.K.std  # K's unit: "" in the record either way
    assert dict(back.parameters_mrft) == dict(result.parameters_mrft)
    assert back.flight is None and back.identification is None
    assert back.log_info == result.log_info
    for t_back, t in zip(back.tests, result.tests, strict=True):
        # every per-test figure comes back (the cycles too: means and spreads are recomputed from them)
        assert _json_text(t_back.to_dict()) == _json_text(t.to_dict())
        assert t_back.amplitude_mean == t.amplitude_mean and t_back.h == t.h
        assert np.array_equal(t_back.frequency_hz, t.frequency_hz)
    assert len(back.rejected) == len(result.rejected)


def test_json_read_and_written_again_is_the_same_text(design1: AnalysisResult) -> None:
    text = _json_text(design1.to_json())
    back = AnalysisResult.from_json(json.loads(text))
    assert _json_text(back.to_json()) == text
    without_cycles = back.to_json(cycles=False)
    assert all("per_cycle" not in t for t in without_cycles["tests"])


def test_a_result_written_before_schema_version_reads_as_version_1(design1: AnalysisResult) -> None:
    old = json.loads(_json_text(design1.to_dict()))
    assert AnalysisResult.from_json(old).Td == design1.Td


@pytest.mark.parametrize("data, what", [
    ({"schema_version": 3, "strategy": "unit-manifolds", "family": "soiptd", "model": {}, "parameters": {}},
     "an identification record ('mrft-ident identify --json')"),
    ({"schema_version": 3, "kind": "delay-increment", "parameters": {}}, "a delay record ('mrft-ident delay --json')"),
    ({"schema_version": 3, "designs": [], "ms_max": 1.6, "model": {}}, "a tune record ('mrft-ident tune --json')"),
    ({"export": {}, "tune_results": []}, "a tune record"),
    ({"logs": 2, "counts": {}, "rows": []}, "a batch summary"),
])
def test_another_commands_record_is_named(data: object, what: str) -> None:
    # was 'not an analyze RESULT.json (KeyError: 'Tp'); needs parameters.Td/tau/K, ...' for an identify --json file
    with pytest.raises(InputError, match="^not an analyze RESULT.json but ") as info:
        AnalysisResult.from_json(data)
    assert what in str(info.value) and "KeyError" not in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("data, match", [
    ([1, 2], "expected a JSON object"),
    ({"schema_version": 99, "parameters": {}}, "schema_version 99 is not supported"),
    ({"schema_version": "1", "parameters": {}}, "schema_version '1'"),
    ({"tests": []}, "not an analyze RESULT.json"),
    ({"parameters": {"Td": {"mean": "x"}, "tau": {"mean": 1}, "K": {"mean": 1}, "Tp": {"mean": 1}}},
     "not an analyze RESULT.json"),
])
def test_bad_json_is_a_one_line_input_error(data: object, match: str) -> None:
    with pytest.raises(InputError, match=match) as info:
        AnalysisResult.from_json(data)
    assert "\n" not in str(info.value)


def test_a_hand_written_result_needs_the_parameters_only() -> None:
    data = {"parameters": {"Td": {"mean": 1.3, "std": 0.1}, "tau": {"mean": 0.03, "std": None},
                           "K": {"mean": 30.0, "std": 1.0}, "Tp": {"mean": 0.0422}}}
    r = AnalysisResult.from_json(data)
    assert (r.model.Td, r.model.tau, r.model.K, r.Tp) == (1.3, 0.03, 30.0, 0.0422)
    assert np.isnan(r.tau.std) and r.tests == () and r.controller_rate_hz is None


def test_the_controller_rate_is_the_declared_one_else_the_tests_logging_rate() -> None:
    assert analysis_controller_rate(50.0, [10.0, 10.0]) == 50.0
    assert analysis_controller_rate(None, [199.96, 200.02, 200.01]) == 200.0
    assert analysis_controller_rate(None, []) is None


def test_the_10hz_px4_record_holds_the_50hz_controller(px4_10hz: AnalysisResult) -> None:
    assert px4_10hz.controller_rate_hz == 50.0
    assert all(t.rate_hz == pytest.approx(10.0, rel=1e-3) for t in px4_10hz.tests)
    back = AnalysisResult.from_json(json.loads(_json_text(px4_10hz.to_json())))
    assert back.controller_rate_hz == 50.0


def _cli(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    """The CLI in this process (tests/cli_helpers.py): a subprocess would only add its imports' CPU."""
    code, out, err = run_cli(capsys, *args)
    assert code == 0, err
    return out


def test_tune_designs_for_the_same_rate_from_the_log_and_from_its_result_json(tmp_path: Path, capsys) -> None:
    """The issue's case: the 10 Hz PX4 log of a 50 Hz controller; RESULT.json used to give 10 Hz gains."""
    log = str(SAMPLES / "px4_altitude_10hz.ulg")
    result_json = tmp_path / "result.json"
    _cli(capsys, "analyze", log, "--tp", "0.0422", "--json", str(result_json))
    common = ["--tp", "0.0422", "--loop", "altitude", "--design", "model-based", "--export", "generic"]
    from_log = json.loads(_cli(capsys, "tune", log, *common))
    from_json = json.loads(_cli(capsys, "tune", str(result_json), *common))
    assert from_log["rate_hz"] == from_json["rate_hz"] == 50.0
    for gain in ("Kp", "Ki", "Kd", "Tf"):
        assert from_json[gain] == pytest.approx(from_log[gain], rel=1e-9), gain


def test_version_2_adds_noise_and_tp_check_and_version_1_still_reads(design1: AnalysisResult) -> None:
    """Issue 40: the measured sensor noise and the verdict on Tp in the JSON; a version-1 JSON (without
    them) reads as before."""
    d = json.loads(_json_text(design1.to_json()))
    truth = json.loads((SAMPLES / "design1_altitude.mcap.truth.json").read_text())
    assert d["noise"]["std"] == pytest.approx(truth["noise_std"], rel=0.1)  # the simulation's sensor noise
    assert d["tp_check"]["verdict"] == "consistent" and d["tp_check"]["given"] == 0.0422
    old = {k: v for k, v in d.items() if k not in ("noise", "tp_check")} | {"schema_version": 1}
    back = AnalysisResult.from_json(old)
    assert back.tp_check is None and back.tau == design1.tau
