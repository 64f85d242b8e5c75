"""batch --model NAME: each log analysed as a process plant (mrftcli/batch/run.py: the one analysis route, the model object chosen per task).

The logs are relay tests simulated by tests/process_sim.py (independent of mrftcli); the truth is
the simulated plant's parameters.
"""

from __future__ import annotations

import json
import os
import sys

import pytest
from cli_helpers import run_main

sys.path.insert(0, os.path.dirname(__file__))
from process_sim import Window, simulate, write_csv  # noqa: E402

from mrftcli.batch import BatchOptions, run_batch  # noqa: E402
from mrftcli.errors import InputError  # noqa: E402
from mrftcli.mrft.families import family_model  # noqa: E402

_TRUTH = {"a.csv": dict(K=2.0, T=1.0, tau=0.3), "b.csv": dict(K=1.5, T=0.8, tau=0.25)}
_READ = {"command_topic": "u_relay", "output_topic": "y_output"}


def _fleet(folder, names=("a.csv", "b.csv")):
    folder.mkdir(exist_ok=True)
    for i, name in enumerate(names):
        windows = [Window("hysteresis", 1.0, -1.0, eps=e, duration=20.0) for e in (0.05, 0.3)]
        t, u, y = simulate("fopdt", _TRUTH[name], windows, 20.0, 0.01, seed=i)
        write_csv(str(folder / name), t, u, y)
    return folder


def test_batch_fopdt_rows_hold_the_parameters_with_units(tmp_path):
    logs = _fleet(tmp_path / "logs")
    options = BatchOptions(jobs=1, report=False, model=family_model("fopdt"))
    res = run_batch([logs], tmp_path / "out", options=options, explicit=_READ)
    df = res.summary
    assert list(df["status"]) == ["ok", "ok"] and list(df["model"]) == ["fopdt", "fopdt"]
    assert list(df["loop"]) == ["process", "process"]  # a process plant's loop (was the vehicle default altitude)
    for _, row in df.iterrows():
        truth = _TRUTH[os.path.basename(str(row["path"]))]
        for name, value in truth.items():
            assert row[f"p_{name}"] == pytest.approx(value, rel=0.1)
        assert row["p_T_unit"] == "s" and row["p_tau_unit"] == "s" and row["p_K_unit"] == "output / command"
        assert " s" in row["parameters"] and "output / command" in row["parameters"]
        assert row["tau_mean"] == row["p_tau"]  # the fleet's tau flags see the delay
    record = json.loads((tmp_path / "out" / str(df["result_json"].iloc[0])).read_text())
    assert record["loops"][0]["result"]["model"] == "fopdt"  # the process analysis record
    again = run_batch([logs], tmp_path / "out", options=options, explicit=_READ)
    assert set(again.summary["status"]) == {"skipped-uptodate"}
    known = BatchOptions(jobs=1, report=False, model=family_model("fopdt", known={"tau": 0.3}))
    other = run_batch([logs], tmp_path / "out", options=known, explicit=_READ)
    # another model is another result: recomputed
    assert "skipped-uptodate" not in set(other.summary["status"])
    # no controller rate given: the 20 Hz log's switches are placed midway between samples, half a sample
    # (25 ms) before process_sim's relay (deciding at the log's rate) switched; said in the record's first notes
    notes = json.loads((tmp_path / "out" / str(other.summary["result_json"].iloc[0])).read_text())
    notes = json.dumps(notes["loops"][0]["result"])
    assert "assumed: the relay decided much faster than the 20 Hz log" in notes and "--controller-rate 20" in notes
    # the relay's true rate given: the known tau is the plant's delay and K, T hold (were K 4.19, T 2.12:
    # 'insufficient', the 25 ms lag pushed into them)
    at_rate = run_batch([logs], tmp_path / "out", options=known, explicit={**_READ, "controller_rate_hz": 20.0})
    # (b.csv's delay is 0.25 s: tau 0.3 is not its truth, only a.csv's row is checked)
    row = at_rate.summary.iloc[0]
    assert os.path.basename(str(row["path"])) == "a.csv" and row["status"] == "ok"
    assert row["p_K"] == pytest.approx(2.0, rel=0.1) and row["p_T"] == pytest.approx(1.0, rel=0.1)
    assert row["p_tau"] == 0.3


def test_a_process_row_with_nothing_determined_is_insufficient(tmp_path):
    """One relay test logged at 8 Hz: one response point (too few samples a cycle for a harmonic), so none of
    K, T, tau is determined. The row is insufficient with the identification's advice, as analyze's exit 6
    (was 'ok', its estimates points of the range the data leave open); the analysis is kept as the partial."""
    logs = tmp_path / "logs"
    logs.mkdir()
    t, u, y = simulate("fopdt", _TRUTH["a.csv"], [Window("hysteresis", 1.0, -1.0, eps=0.05, duration=20.0)], 8.0,
                       0.001, seed=0)
    write_csv(str(logs / "a.csv"), t, u, y)
    res = run_batch([logs], tmp_path / "out", options=BatchOptions(jobs=1, report=False, model=family_model("fopdt")),
                    explicit=_READ)
    row = res.summary.iloc[0]
    assert row["status"] == "insufficient" and row["error_type"] == "InsufficientDataError"
    assert row["error"].startswith("K, T, tau not determined by 1 response point(s)") and "--param" in row["error"]
    loop = json.loads((tmp_path / "out" / str(row["result_json"])).read_text())["loops"][0]
    assert loop["exit_code"] == 6 and loop["result"]["partial"]["model"] == "fopdt"
    assert loop["result"]["partial"]["identification"]["advice"] == row["error"]


def test_batch_model_refuses_eq2_extras():
    with pytest.raises(InputError, match="--tune: not with --model"):
        BatchOptions(diagnose=True, tune="PD", model=family_model("ipdt"))
    assert BatchOptions(diagnose=True, model=family_model("ipdt")).diagnose  # --diagnose takes every family


def test_batch_model_diagnose_names_the_lag_a_fopdt_leaves_out(tmp_path):
    """``batch --model fopdt --diagnose`` on a FOPDT and a second-order plant (tests/process_sim.py, no mrftcli),
    each under two hysteresis relays: the FOPDT's diagnosis finds nothing, the second-order plant's names the
    lag FOPDT leaves out (the simulator's lags 0.7 s and 0.3 s: FOPDT's T takes one, the effect the other)."""
    folder = tmp_path / "logs"
    folder.mkdir()
    windows = [Window("hysteresis", 1.0, -1.0, eps=0.05, duration=25.0),
               Window("hysteresis", 1.5, -0.5, eps=0.3, duration=25.0)]
    for name, family, truth in (("clean.csv", "fopdt", dict(K=2.0, T=1.0, tau=0.3)),
                                ("lag.csv", "sopdt", dict(K=2.0, T1=0.7, T2=0.3, tau=0.15))):
        t, u, y = simulate(family, truth, windows, 100.0, 0.01, seed=1)
        write_csv(str(folder / name), t, u, y)
    summary = tmp_path / "summary.json"
    out = run_main("batch", str(folder), "--model", "fopdt", "--diagnose", "--command-topic", "u_relay",
                   "--output-topic", "y_output", "--out", str(tmp_path / "out"), "--jobs", "1", "--no-report", "-q",
                   "--json", str(summary))  # main() in this process
    assert out.returncode == 0, out.stderr
    table = {ln.split()[0]: ln for ln in out.stdout.splitlines() if ln.endswith(")") or ".csv" in ln}
    assert "findings: sensor_lag" in table["lag.csv"] and "findings" not in table["clean.csv"]
    rows = {os.path.basename(str(r["path"])): r for r in json.loads(summary.read_text())["rows"]}
    assert rows["clean.csv"]["status"] == "ok" and rows["clean.csv"]["findings"] == ""
    assert rows["lag.csv"]["status"] == "ok" and rows["lag.csv"]["findings"] == "sensor_lag"
    record = json.loads((tmp_path / "out" / str(rows["lag.csv"]["result_json"])).read_text())
    diagnosis = record["loops"][0]["diagnosis"]
    assert diagnosis["status"] == "ok" and diagnosis["family"] == "fopdt" and diagnosis["found"] == ["sensor_lag"]
    (lag,) = diagnosis["effects"]
    assert sorted([lag["value"], lag["refit"]["T"]]) == pytest.approx([0.3, 0.7], rel=0.15)
    # the record read back through the one diagnosis record, as diagnose --json's
    from mrftcli.diagnose import DiagnosisResult

    back = DiagnosisResult.from_json({"schema_version": 2, **{k: v for k, v in diagnosis.items()
                                                               if k not in ("status", "error")}})
    assert back.found == ("sensor_lag",) and not back.consistent


def test_cli_batch_model(tmp_path):
    logs = _fleet(tmp_path / "logs", names=("a.csv",))
    out = run_main("batch", str(logs), "--model", "fopdt", "--command-topic", "u_relay", "--output-topic", "y_output",
                   "--out", str(tmp_path / "out"), "--jobs", "1", "--no-report", "-q")  # main() in this process
    assert out.returncode == 0, out.stderr
    assert "parameters (value ± std unit)" in out.stdout
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith("a.csv"))
    assert "fopdt" in line and "tau 0.3" in line and " s" in line and "output / command" in line


def test_a_known_value_the_points_contradict_is_named_not_a_missing_test(tmp_path):
    """A given tau the response points contradict (a.csv's 20 Hz log read with no --controller-rate: each switch
    half a sample early, so the true 0.3 s misfits, chi2/dof ~100; b.csv's true delay is 0.25 s) inflates the
    covariance until K, T look undetermined: the advice names the given value and its chi2/dof, not another
    test or more --param values (the advice before)."""
    logs = _fleet(tmp_path / "logs", names=("a.csv",))
    out = run_main("analyze", str(logs / "a.csv"), "--model", "fopdt", "--param", "tau=0.3", "--command-topic",
                   "u_relay", "--output-topic", "y_output")
    assert out.returncode != 0
    err = out.stderr.strip()
    assert err.startswith("error: K, T not determined: the given value tau = 0.3 s disagrees with the 6 response")
    chi = float(err.split("chi2/dof ")[1].split()[0])
    assert chi > 10 and f"chi2/dof {chi:.3g}" in out.stdout  # the figure the parameter table states
    assert "either the given value is wrong or the log's timing is" in err and "--controller-rate" in err
    assert "add a relay test" not in err and "--param NAME=VALUE" not in err


def test_a_known_value_the_points_contradict_is_warned_even_when_the_rest_look_determined(tmp_path):
    """b.csv (truth K 1.5, T 0.8, tau 0.25) with a given tau 0.3: the fit misses the points (chi2/dof ~80) yet K
    and T look determined (K ~1.0, a third low); before, nothing said so (exit 0, no warning). Now a warning names
    the given value, the chi2/dof and the two likely causes, on the terminal and in the JSON; the numbers stay."""
    logs = _fleet(tmp_path / "logs")
    out = run_main("analyze", str(logs / "b.csv"), "--model", "fopdt", "--param", "tau=0.3", "--command-topic",
                   "u_relay", "--output-topic", "y_output", "--json", str(tmp_path / "b.json"))
    assert out.returncode == 0  # reported, flagged
    chi = float(out.stdout.split("chi2/dof ")[1].split(")")[0])
    assert chi > 10
    warning = next(ln for ln in (out.stdout + out.stderr).splitlines() if ln.startswith("warning: the estimates of K, T"))
    assert "the given value tau = 0.3 s disagrees" in warning and f"chi2/dof {chi:.3g}" in warning
    assert "either the given value is wrong or the log's timing is" in warning and "--controller-rate" in warning
    record = json.loads((tmp_path / "b.json").read_text())
    assert warning.removeprefix("warning: ") in record["warnings"]
    assert warning.removeprefix("warning: ") in record["identification"]["warnings"]
