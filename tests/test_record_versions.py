"""Issue 36: one parameter record, and the records written before it still read (one release).

Every file under ``tests/data/old_records/`` was written by mrft-ident before the one parameter record
(the code of commit a693ecc, and for the analysis' versions 1 and 2 the commits before 922843a and
9d04ad6), by the CLI on shipped or simulated logs:

- ``analysis_v{1,2,3}.json``: ``analyze sample_logs/design1_altitude.mcap --tp 0.0422 --loop altitude --json``
- ``general_v2.json``: ``analyze sopdt.csv --model sopdt --json`` (``simulate --model sopdt --param K=2
  --param T1=1.0 --param T2=0.2 --param tau=0.3 --test -0.3``: T1 not determined by one test)
- ``cascade_v1.json``: ``analyze sample_logs/hear_cascade_y.bag --loop y --inner-model roll.json
  --inner-gains sample_logs/hear_cascade_y.gains.json --json``
- ``vehicle_v1.json``: ``vehicle sample_logs/hear_cascade_y.bag --tp 0.0422 --inner-gains ... --json``
- ``watch_v1.jsonl``: ``watch fopdt.csv --model fopdt --jsonl`` (``simulate --model fopdt --param K=2 --param T=1.0
  --param tau=0.3 --test -0.3 --test -0.6``)
- ``identification_sopdt_v2.json``, ``identification_cascade_v2.json``: the families' and the cascade's own
  identification layouts (version 2) before the one identification record, written by the code of commit 4382fba
  from ``general_v2.json`` and ``cascade_v1.json`` (eq. (2)'s ``identification_v{1,2}.json``: tests/test_identify.py)

The oracle is the old file itself: every figure it holds comes back unchanged under the new keys.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Iterator

import pytest

from mrftcli.analyze import AnalysisResult
from mrftcli.jsonable import to_jsonable
from mrftcli.mrft.parameter import JSON_KEYS, ParameterEstimate
from mrftcli.vehicle.record import VehicleResult

OLD = Path(__file__).parent / "data" / "old_records"
_FIGURES = ("std", "ci95_low", "ci95_high")


def _old(name: str) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((OLD / name).read_text())
    return data


def _written(record: Any) -> dict[str, Any]:
    """The record as its writer gives it, through plain JSON text."""
    out: dict[str, Any] = json.loads(json.dumps(to_jsonable(record.to_json()), allow_nan=False))
    return out


def _parameter_objects(obj: Any, where: str = "") -> Iterator[tuple[str, dict[str, Any]]]:
    """Every object of a JSON tree that states a parameter (a value or mean with its interval)."""
    if isinstance(obj, dict):
        if ("value" in obj or "mean" in obj) and "ci95_low" in obj:
            yield where, obj
        for k, v in obj.items():
            yield from _parameter_objects(v, f"{where}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _parameter_objects(v, f"{where}[{i}]")


def _same_figures(new: dict[str, Any], old: dict[str, Any], where: str) -> None:
    assert new["value"] == old.get("value", old.get("mean")), where
    for k in _FIGURES:
        # a parameter the tests do not determine has no std worth the name: null, in both layouts
        if k == "std" and not new["determined"]:
            assert new["std"] is None, where
            continue
        assert new[k] == old.get(k), (where, k)


def _one_shape(data: dict[str, Any]) -> list[str]:
    """The places of ``data`` whose parameter object is not the one record (empty: all are)."""
    return [where for where, p in _parameter_objects(data) if tuple(p) != JSON_KEYS]


@pytest.mark.parametrize("version", [1, 2, 3])
def test_an_analysis_of_each_earlier_version_reads_with_its_figures_and_writes_as_4(version: int) -> None:
    old = _old(f"analysis_v{version}.json")
    assert old["schema_version"] == version and "mean" in old["parameters"]["Td"]
    back = AnalysisResult.from_json(old)
    for name in ("Td", "tau", "K"):
        was = old["parameters"][name]
        est = getattr(back, name)
        assert (est.value, est.std, est.ci95_low, est.ci95_high) == (was["mean"], was["std"], was["ci95_low"],
                                                                     was["ci95_high"]), name
    assert back.Tp == old["parameters"]["Tp"]["mean"] == 0.0422
    new = _written(back)
    assert new["schema_version"] == 4 and _one_shape(new) == []
    for group, method in (("parameters", old["parameters"]["Td"]["method"]), ("parameters_mrft", "mrft"),
                          ("parameters_waveform", "waveform")):
        for name, p in new[group].items():
            _same_figures(p, old[group][name], f"{group}.{name}")
            assert p["method"] == ("given" if name == "Tp" else method), (group, name)
    assert new["parameters"]["Tp"]["known"] is True and new["parameters"]["Td"]["known"] is False
    # the rest of the record is the old one's (the held-out prediction null before version 3)
    assert {k: v for k, v in new.items() if not k.startswith("parameters") and k not in ("schema_version", "tests")} \
        == {k: v for k, v in old.items() if not k.startswith("parameters") and k not in ("schema_version", "tests")}
    again = AnalysisResult.from_json(new)
    assert _written(again) == new and again.Td == back.Td and again.tau == back.tau


def test_a_version_2_process_analysis_reads_with_its_figures_and_verdicts_and_writes_as_3() -> None:
    old = _old("general_v2.json")
    assert old["schema_version"] == 2 and old["identification"]["schema_version"] == 1
    back = AnalysisResult.from_json(old)
    assert back.identification is not None
    new = _written(back)
    assert new["schema_version"] == 3 and new["identification"]["schema_version"] == 3 and _one_shape(new) == []
    for name, was in old["parameters"].items():
        p = new["parameters"][name]
        _same_figures(p, was, name)
        assert (p["unit"], p["determined"], p["known"]) == (was["unit"], was["determined"], was["known"])
        assert p["method"] == "response-points" and new["identification"]["parameters"][name] == p
        # the interval's open side comes back from the model's ranges
        assert back.identification.estimate(name).one_sided == was["one_sided"], name
    assert [n for n, p in new["parameters"].items() if not p["determined"]] == ["T1"]
    assert AnalysisResult.from_json(new).identification == back.identification


def test_a_version_1_cascade_analysis_reads_and_writes_back_as_2() -> None:
    old = _old("cascade_v1.json")
    assert old["schema_version"] == 1 and "one_sided" in old["parameters"]["tau"]
    back = AnalysisResult.from_json(old)
    new = _written(back)
    assert new["schema_version"] == 2 and new["identification"]["schema_version"] == 3 and _one_shape(new) == []
    for name, was in old["parameters"].items():
        est = back.identification.parameters[name]
        assert est.one_sided == was["one_sided"] and est.known == was["known"], name
        _same_figures(new["parameters"][name], was, name)
        assert new["parameters"][name]["method"] == ("given" if was["known"] else "cascade-cycles")
    assert {k: v for k, v in new.items() if k not in ("schema_version", "parameters", "identification")} \
        == {k: v for k, v in old.items() if k not in ("schema_version", "parameters", "identification")}
    assert _written(AnalysisResult.from_json(new)) == new


def test_a_version_1_vehicle_record_mixed_four_shapes_and_writes_back_with_one() -> None:
    old = _old("vehicle_v1.json")
    assert old["schema_version"] == 1
    shapes = {tuple(sorted(p)) for _, p in _parameter_objects(old)}
    # eq. (2)'s with method, without it (parameters_mrft/_waveform), Tp's with known; the cascade's one_sided
    assert len(shapes) == 4
    back = VehicleResult.from_json(old)
    new = _written(back)
    assert new["schema_version"] == 2 and _one_shape(new) == []
    assert new["loops"]["roll"]["schema_version"] == 4 and new["loops"]["y"]["schema_version"] == 2
    olds, news = dict(_parameter_objects(old)), dict(_parameter_objects(new))
    assert olds.keys() == news.keys()
    for where, p in news.items():
        _same_figures(p, olds[where], where)
    assert back.loops["roll"].estimates == {k: (v["mean"], v["std"])
                                           for k, v in old["loops"]["roll"]["parameters"].items() if k != "Tp"}
    assert _written(VehicleResult.from_json(new)) == new


@pytest.mark.parametrize("data", [
    {"value": 0.05, "std": 0.001, "ci95_low": 0.048, "ci95_high": 0.052, "unit": "s", "determined": True,
     "known": False, "method": "waveform"},
    {"value": 2.0, "std": None, "ci95_low": 0.5, "ci95_high": None, "unit": "s", "determined": False,
     "known": False, "method": "mrft"},
    {"value": 0.0422, "std": 0.0, "ci95_low": 0.0422, "ci95_high": 0.0422, "unit": "s", "determined": True,
     "known": True, "method": "given"},
])
def test_the_one_record_reads_back_what_it_wrote(data: dict[str, Any]) -> None:
    est = ParameterEstimate.from_json("x", data)
    assert json.loads(json.dumps(to_jsonable(est.to_json()))) == data
    assert est.name == "x"


def test_eq2_former_open_interval_reads_as_not_determined() -> None:
    """Analysis schema <= 3 said 'bounded from below only' with a null ci95_high: not determined now."""
    est = ParameterEstimate.from_json("Td", {"mean": 5.0, "std": 1.0, "ci95_low": 2.0, "ci95_high": None,
                                             "unit": "s", "method": "mrft"})
    assert not est.determined and math.isnan(est.ci95_high) and est.to_json()["std"] is None


@pytest.mark.parametrize("version", [1, 2, 3])
def test_compare_reads_each_earlier_analysis_version(version: int, tmp_path: Path) -> None:
    """``compare`` of an old RESULT.json against the same record written today: nothing moved."""
    from mrftcli.compare import compare

    old = OLD / f"analysis_v{version}.json"
    new = tmp_path / "new.json"
    new.write_text(json.dumps(_written(AnalysisResult.from_json(_old(old.name)))))
    cmp = compare(str(old), str(new))
    assert [(c.parameter, c.change, c.verdict) for c in cmp.changes] == [
        ("Td", 0.0, "unchanged"), ("tau", 0.0, "unchanged"), ("K", 0.0, "unchanged")]
    assert cmp.exit_code == 0 and not cmp.missing


def test_compare_of_the_version_3_record_and_todays_analysis_of_its_log(tmp_path: Path) -> None:
    """The baseline's RESULT.json (version 3) against today's analysis of the same log with the same
    settings: the issue's bound, every parameter within 0.1 of its std (the record changed, not the numbers)."""
    from mrftcli.analyze import analyze_path
    from mrftcli.compare import compare
    from mrftcli.io import ReadOptions
    from mrftcli.mrft.model import soiptd_model

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "design1_altitude.mcap"
    now = analyze_path(log, soiptd_model(0.0422), read=ReadOptions(loop="altitude"))
    # each estimate says how it was found, as its JSON does
    assert {now.Td.method, now.tau.method, now.K.method} == {now.method} == {"waveform"}
    assert {e.method for e in now.parameters_mrft.values()} == {"mrft"}
    new = tmp_path / "new.json"
    new.write_text(json.dumps(_written(now)))
    old = _old("analysis_v3.json")
    cmp = compare(str(OLD / "analysis_v3.json"), str(new))
    assert cmp.exit_code == 0
    for c in cmp.changes:
        assert c.change is not None and abs(c.change) <= 0.1 * old["parameters"][c.parameter]["std"], c


def test_a_batch_summary_row_reads_a_record_stored_by_the_previous_version(tmp_path: Path) -> None:
    """A batch folder written before the upgrade keeps its logs/*.json (an up-to-date log is not analysed
    again): the summary reads their version-3 analyses with the same figures."""
    from mrftcli.batch.summary import summary_rows

    old = _old("analysis_v3.json")
    record = {"path": "sample_logs/design1_altitude.mcap", "settings": {"tp": 0.0422}, "log_mtime": 0.0,
              "loops": [{"loop": "altitude", "status": "ok", "result": old}]}
    (row,) = summary_rows(record, tmp_path / "logs" / "design1_altitude.json", skipped=True)
    assert row["status"] == "skipped-uptodate" and row["n_tests"] == len(old["tests"])
    for name in ("Td", "tau", "K"):
        assert (row[f"{name}_mean"], row[f"{name}_std"]) == (old["parameters"][name]["mean"],
                                                              old["parameters"][name]["std"]), name


@pytest.mark.parametrize(("t_range", "side"), [((0.98, 3.0), "low"), ((0.2, 1.02), "high")])
def test_an_interval_cut_at_a_range_bound_is_one_sided_again_when_read(t_range: tuple[float, float],
                                                                       side: str) -> None:
    """The JSON has no ``one_sided``: reading finds it again from the model's range (set I). Exact FOPDT
    response points (K 2, T 1 s, tau 0.3 s; 5 % standard errors) with T's range cutting its interval."""
    import numpy as np

    from mrftcli.mrft.families import family_model
    from mrftcli.mrft.identify import identify
    from mrftcli.mrft.identify_lti import LtiIdentification, ResponsePoint

    true = family_model("fopdt").with_parameters(K=2.0, T=1.0, tau=0.3)
    points = []
    for i, w in enumerate((0.8, 1.5, 2.4, 4.0)):
        g = complex(true.frequency_response(np.array([w]))[0])
        points.append(ResponsePoint(w, abs(g), float(np.angle(g)), 0.05, 0.05, i, 1))
    ident = identify(points, family_model("fopdt", ranges={"T": t_range}))
    assert ident.estimate("T").one_sided == side and ident.estimate("K").one_sided == ""
    back = LtiIdentification.from_json(json.loads(json.dumps(to_jsonable(ident.to_json()))))
    assert back.estimates == ident.estimates
    assert [e.one_sided for e in back.estimates] == [e.one_sided for e in ident.estimates]


def test_watch_model_lines_of_version_1_read_into_todays_updates() -> None:
    """``watch plant.csv --model fopdt --jsonl`` before the one record (tests/data/old_records/watch_v1.jsonl:
    the simulated FOPDT K 2, T 1 s, tau 0.3 s, two relay tests): its test and estimate lines read with their
    figures (a test's h, not in version 1, is its relay's half swing) and write as version 2."""
    from mrftcli.watch import EstimateUpdate, TestUpdate

    lines = [json.loads(line) for line in (OLD / "watch_v1.jsonl").read_text().splitlines()]
    tests = [d for d in lines if d["kind"] == "test"]
    estimates = [d for d in lines if d["kind"] == "estimate"]
    assert len(tests) == 2 and len(estimates) == 2 and all(d["schema_version"] == 1 for d in tests + estimates)
    for d in tests:
        t = TestUpdate.from_json(d)
        assert (t.number, t.frequency_hz, t.amplitude, t.stable_cycles) == (d["number"], d["frequency_hz"],
                                                                            d["amplitude"], d["stable_cycles"])
        assert t.relay is not None and t.h == (d["relay"]["high"] - d["relay"]["low"]) / 2
        assert t.to_json()["schema_version"] == 2
    for d in estimates:
        e = EstimateUpdate.from_json(d)
        new = json.loads(json.dumps(to_jsonable(e.to_json())))
        assert new["schema_version"] == 2 and _one_shape(new) == []
        for name, was in d["parameters"].items():
            _same_figures(new["parameters"][name], was, name)
        # the final update carries the whole analysis, its record of version 2 read and written as 3
        assert (e.analysis is not None and new["analysis"]["schema_version"] == 3) == d["final"]
    assert [d["final"] for d in estimates] == [False, True]


# ----------------------------------------------------------------------------------------------
# the one diagnosis record (issue 36): eq. (2)'s diagnosis (version 1) and the families' process_diagnosis
# (versions 1 and 2), written by commit 8c336ae:
# - ``diagnosis_v1.json``: ``diagnose sample_logs/concealed/flight_02.mcap --loop altitude --tp 0.0422 --json``
#   (no schema_version: the CLI wrote the layout of version 1 without it)
# - ``process_diagnosis_v2.json``: ``diagnose kstar_signals21801_biased_relay.csv --command-topic u_relay
#   --output-topic y_output --model fopdt --json`` (../shared/data/real_relay)


def _diagnosis_written(record: Any) -> dict[str, Any]:
    out: dict[str, Any] = json.loads(json.dumps(to_jsonable(record.to_json())))
    return out


@pytest.mark.parametrize("versioned", [False, True])
def test_an_eq2_diagnosis_of_version_1_reads_with_its_figures_and_writes_as_2(versioned: bool) -> None:
    """The CLI's file (no schema_version) and the record's ``to_json`` of then (``schema_version`` 1)."""
    from mrftcli.diagnose.records import DiagnosisResult

    old = _old("diagnosis_v1.json")
    assert "schema_version" not in old
    result = DiagnosisResult.from_json({"schema_version": 1, **old} if versioned else old)
    new = _diagnosis_written(result)
    assert new["schema_version"] == 3 and new["kind"] == "diagnosis" and new["family"] == "soiptd"
    assert result.found == ("sensor_lag",) and new["found"] == ["sensor_lag"]
    # every key of version 1 comes back with the same content; the new keys are the families' (empty here)
    assert {k: new[k] for k in old} == old
    assert (new["checks"], new["notes"], new["analysis"], new["consistent"]) == ([], [], None, None)
    assert new["analyze_refusal"] is None
    assert DiagnosisResult.from_json(new) == result


def test_an_eq2_diagnosis_of_version_2_reads_and_writes_as_3() -> None:
    """``diagnosis_v2.json``: ``diagnose sample_logs/concealed/flight_02.mcap --loop altitude --tp 0.0422 --json -``
    at commit 980ecd6 (version 2: no ``analyze_refusal``; version 3 adds it, None where analyze identified the log)."""
    from mrftcli.diagnose.records import DiagnosisResult

    old = _old("diagnosis_v2.json")
    assert old["schema_version"] == 2 and "analyze_refusal" not in old
    result = DiagnosisResult.from_json(old)
    new = _diagnosis_written(result)
    assert new["schema_version"] == 3 and result.found == ("sensor_lag",) and result.analyze_refusal is None
    assert {k: v for k, v in new.items() if k not in ("schema_version", "analyze_refusal")} == \
        {k: v for k, v in old.items() if k != "schema_version"}
    assert new["analyze_refusal"] is None and DiagnosisResult.from_json(new) == result


def test_a_process_diagnosis_of_version_2_reads_with_its_figures_and_writes_as_2() -> None:
    """KSTAR 21801 as FOPDT: its input bias found, the rows of every candidate (alone, then on top of it)."""
    from mrftcli.diagnose.records import DiagnosisResult

    old = _old("process_diagnosis_v2.json")
    assert old["schema_version"] == 2 and old["kind"] == "process_diagnosis"
    result = DiagnosisResult.from_json(old)
    new = _diagnosis_written(result)
    assert new["schema_version"] == 3 and new["family"] == "fopdt" and new["summary"] == old["verdict"]
    assert new["found"] == old["found"] == ["input_bias"]
    # the rows: the alone ones in candidates, those on top of the first in second_effect_candidates, unchanged
    assert new["candidates"] + new["second_effect_candidates"] == old["candidates"]
    assert all(not c["with"] for c in new["candidates"]) and all(c["with"] for c in new["second_effect_candidates"])
    assert [e["name"] for e in new["effects"]] == ["input_bias"] and new["effects"][0] == old["candidates"][5]
    for key in ("checks", "located", "notes", "consistent", "z_limit"):
        assert new[key] == old[key], key
    # the analysis unchanged but for its identification, now the one record (version 3, its strategy named)
    new_id, old_id = new["analysis"]["identification"], old["analysis"]["identification"]
    assert {**new["analysis"], "identification": None} == {**old["analysis"], "identification": None}
    assert (new_id["schema_version"], old_id["schema_version"]) == (3, 2)
    assert {k: v for k, v in new_id.items() if k not in ("schema_version", "strategy")} == \
        {k: v for k, v in old_id.items() if k != "schema_version"}
    assert DiagnosisResult.from_json(new).to_json() == result.to_json()


def test_a_process_diagnosis_of_version_1_reads() -> None:
    """Version 1 (before the library of physics: no candidates, no found) is version 2 without those keys;
    no file of it was kept, so it is the version 2 file with them removed."""
    from mrftcli.diagnose.records import DiagnosisResult
    from mrftcli.errors import InputError

    old = {k: v for k, v in _old("process_diagnosis_v2.json").items() if k not in ("candidates", "found")}
    result = DiagnosisResult.from_json({**old, "schema_version": 1})
    assert result.summary == old["verdict"] and result.candidates == [] and result.found == ()
    assert len(result.checks) == len(old["checks"])
    with pytest.raises(InputError, match="process diagnosis JSON"):
        DiagnosisResult.from_json({"schema_version": 1, "kind": "process_diagnosis", "verdict": "x"})
    with pytest.raises(InputError, match="schema_version 3"):
        DiagnosisResult.from_json({**old, "schema_version": 3})


@pytest.mark.parametrize(("name", "cls", "fit_keys"), [
    ("identification_sopdt_v2.json", "LtiIdentification",
     ("points", "chi2_dof", "undetermined", "advice", "determined_combination")),
    ("identification_cascade_v2.json", "CascadeIdentification", ("tests", "rate_hz", "inner_draws", "inner_std"))])
def test_a_version_2_identification_of_each_fit_reads_into_the_one_record_and_writes_as_3(
        name: str, cls: str, fit_keys: tuple[str, ...]) -> None:
    """The families' and the cascade's own identification layouts (version 2) read, through the one
    ``IdentificationRecord.from_json``, into their strategy's record with every figure, and write back as version 3."""
    from mrftcli.mrft import cascade_identify, identify_lti
    from mrftcli.mrft.identification import IdentificationRecord

    old = _old(name)
    assert old["schema_version"] == 2 and "strategy" not in old
    back = IdentificationRecord.from_json(old)
    assert type(back).__name__ == cls and type(back) in (identify_lti.LtiIdentification,
                                                        cascade_identify.CascadeIdentification)
    new = _written(back)
    assert new["schema_version"] == 3 and new["strategy"] == back.model.identification
    assert new["family"] == old["model"]["family"] and new["model"] == old["model"]
    assert new["parameters"] == old["parameters"]
    assert {k: new[k] for k in fit_keys} == {k: old[k] for k in fit_keys}
    assert _written(IdentificationRecord.from_json(new)) == new
    assert type(back).from_json(new) == back
