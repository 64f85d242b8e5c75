"""``analyze --report``, ``--mcap-out`` and ``--paper-only`` for every family and the cascade (issue 36):
one analysis record (kind ``soiptd``, ``family``, ``cascade``) and one output path in the CLI.

Oracles: a first-order plant flown by tests/process_sim.py (an exact ZOH loop sharing no code with
mrftcli): the model's prediction written to the results MCAP must leave the simulation's sensor noise
(2e-4) as its residual; the cascade: the shipped HEAR log and its truth sidecar.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_main

from mrftcli.analyze import AnalysisResult

sys.path.insert(0, str(Path(__file__).parent))
from process_sim import Window, simulate, write_csv  # noqa: E402

SAMPLES = Path(__file__).parents[1] / "sample_logs"
FOPDT = {"K": 2.0, "T": 1.5, "tau": 0.3}
NOISE = 2e-4
TOPICS = ("--command-topic", "u_relay", "--output-topic", "y_output")


@pytest.fixture(scope="module")
def fopdt_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two MRFT tests (beta -0.2, -0.5) of the FOPDT plant, 500 Hz, sensor noise std 2e-4."""
    parts, off = [], 0.0
    for k, beta in enumerate((-0.2, -0.5)):
        t, u, y = simulate("fopdt", FOPDT, [Window("mrft", 1.0, -1.0, beta=beta, duration=40.0)], 500.0, NOISE,
                           seed=k, start=0.01)
        parts.append((t + off, u, y))
        off += t[-1] + 0.002
    t, u, y = (np.concatenate(z) for z in zip(*parts))
    path = tmp_path_factory.mktemp("family") / "fopdt.csv"
    write_csv(str(path), t, u, y)
    return path


def _mcap(path: Path) -> tuple[dict[str, list], dict[str, dict], dict[str, bytes]]:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        reader = make_reader(fh)
        msgs: dict[str, list] = {}
        for _, channel, message in reader.iter_messages():
            if channel.message_encoding == "json":
                msgs.setdefault(channel.topic, []).append(json.loads(message.data))
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        attachments = {a.name: a.data for a in reader.iter_attachments()}
    return msgs, meta, attachments


def test_a_family_analysis_writes_its_report_and_overlay(fopdt_log: Path, tmp_path: Path) -> None:
    report, mcap, out = tmp_path / "report", tmp_path / "fit.mcap", tmp_path / "r.json"
    proc = run_main("analyze", str(fopdt_log), *TOPICS, "--model", "fopdt", "--report", str(report),
                    "--mcap-out", str(mcap), "--json", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    written = json.loads(out.read_text())
    assert written["model"] == "fopdt" and len(written["tests"]) == 2
    # the figures a person looks at first; eq. (2)'s manifolds and Table III are not drawn for a FOPDT
    figures = {p.name for p in report.glob("*.png")}
    assert figures == {"timeseries.png", "cycles.png", "fit.png", "uncertainty.png"}
    page = (report / "index.html").read_text()
    assert "model fopdt" in page and "K e^{-tau s} / (T s + 1)" in page
    for name in ("K", "T", "tau"):  # every identified parameter in the table
        assert f"<td>{name}</td>" in page
    # the overlay: the identified model's prediction leaves the sensor noise, on the log's clock
    msgs, meta, attachments = _mcap(mcap)
    fit = msgs["/mrft_ident/fit"]
    resid = np.array([m["residual"] for m in fit])
    assert np.sqrt(np.mean(resid ** 2)) == pytest.approx(NOISE, rel=0.25)
    assert any(m.get("model") == "fopdt" for m in meta.values())
    back = AnalysisResult.from_json(json.loads(attachments["analysis.json"]))
    assert back.kind == "family" and back.to_json() == written
    # the parameters at the log's first and last output sample, by name, each finding the flown plant
    first = msgs["/mrft_ident/parameters"][0]
    for name, value in FOPDT.items():
        assert first[f"{name}_ci95_low"] <= value <= first[f"{name}_ci95_high"], name


def test_paper_only_is_refused_in_one_line_where_the_paper_has_no_method(fopdt_log: Path) -> None:
    proc = run_main("analyze", str(fopdt_log), *TOPICS, "--model", "fopdt", "--paper-only")
    assert proc.returncode == 2
    line = proc.stderr.strip().splitlines()[-1]
    assert "--paper-only" in line and "response points" in line and "Traceback" not in proc.stderr


@pytest.fixture(scope="module")
def roll_json(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cascade") / "roll.json"
    proc = run_main("analyze", str(SAMPLES / "hear_cascade_y.bag"), "--tp", "0.0422", "--loop", "roll",
                    "--json", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    return out


def test_the_cascade_writes_its_report_and_overlay_and_refuses_paper_only(roll_json: Path, tmp_path: Path) -> None:
    truth = json.loads((SAMPLES / "hear_cascade_y.bag.truth.json").read_text())
    args = ["analyze", str(SAMPLES / "hear_cascade_y.bag"), "--loop", "y", "--inner-model", str(roll_json),
            "--inner-gains", str(SAMPLES / "hear_cascade_y.gains.json")]
    report, mcap, out = tmp_path / "report", tmp_path / "y.mcap", tmp_path / "y.json"
    proc = run_main(*args, "--report", str(report), "--mcap-out", str(mcap), "--json", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    written = json.loads(out.read_text())
    assert written["kind"] == "cascade"
    assert {p.name for p in report.glob("*.png")} >= {"timeseries.png", "cycles.png", "uncertainty.png"}
    page = (report / "index.html").read_text()
    assert "through the closed inner loop" in page and "Assumption: the outer relay commands an acceleration" in page
    msgs, meta, attachments = _mcap(mcap)
    back = AnalysisResult.from_json(json.loads(attachments["analysis.json"]))
    assert back.kind == "cascade" and back.to_json() == written
    # the exact discrete cascade driven by the recorded outer command: its residual (0.78 mm) is within 1 % of
    # the cycles' amplitude (0.1 m); the same model with tau one tick (10 ms) longer leaves 1.5 mm
    resid = np.array([m["residual"] for m in msgs["/mrft_ident/fit"]])
    rms = float(np.sqrt(np.mean(resid ** 2)))
    assert truth["outer"]["noise_std"] <= rms < 0.01 * min(t["amplitude"] for t in written["tests"])
    first = msgs["/mrft_ident/parameters"][0]  # the parameters as the analysis found the flown outer plant
    assert first["Td_ci95_low"] <= truth["outer"]["Td"] <= first["Td_ci95_high"]
    assert first["K"] == truth["outer"]["K"] and first["K_std"] == 0.0  # known: --outer-command
    refused = run_main(*args, "--paper-only")
    assert refused.returncode == 2 and "--paper-only" in refused.stderr and "sampled orbits" in refused.stderr


def test_one_record_reads_every_layout_and_says_its_kind(fopdt_log: Path) -> None:
    from mrftcli.analyze import AnalyzeOptions, RelayOptions, analyze_path
    from mrftcli.io import ReadOptions
    from mrftcli.mrft.families import family_model

    result = analyze_path(fopdt_log, family_model("fopdt"), read=ReadOptions(command_topic="u_relay",
                                                                             output_topic="y_output"),
                          options=AnalyzeOptions(relay=RelayOptions("mrft")))
    assert result.kind == "family" and len(result.segmented) == len(result.tests) == 2
    assert [t.index for t in result.segmented] == [t.index for t in result.tests]
    back = AnalysisResult.from_json(json.loads(json.dumps(result.to_json())))
    assert type(back) is type(result) and back.kind == "family" and back.segmented == ()
    assert back.to_json() == result.to_json()
    assert set(back.parameters) == {"K", "T", "tau"}
    # a process family has no eq. (2) parameter: a one-line error, not an AttributeError
    from mrftcli.errors import InputError

    with pytest.raises(InputError, match="no Td"):
        _ = back.Td


def test_a_family_analysis_takes_diagnose_too(fopdt_log: Path, tmp_path: Path) -> None:
    out = tmp_path / "d.json"
    proc = run_main("analyze", str(fopdt_log), *TOPICS, "--model", "fopdt", "--diagnose", "--report",
                    str(tmp_path / "report"), "--json", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(out.read_text())
    assert data["model"] == "fopdt" and data["diagnosis"]["family"] == "fopdt"
    assert f"diagnosis: {data['diagnosis']['summary']}" in proc.stdout
    assert "Model-mismatch diagnosis" in (tmp_path / "report" / "index.html").read_text()


def test_a_familys_bode_band_holds_the_flown_plant(fopdt_log: Path) -> None:
    """The report's 95 % band (tune's draws over the estimates) holds the plant that flew the log at the tests'
    frequencies, in magnitude and in phase."""
    from mrftcli.analyze import AnalyzeOptions, RelayOptions, analyze_path
    from mrftcli.io import ReadOptions
    from mrftcli.mrft.families import family_model
    from mrftcli.report.analysis import _bode_band, _drawn_models

    result = analyze_path(fopdt_log, family_model("fopdt"), read=ReadOptions(command_topic="u_relay",
                                                                             output_topic="y_output"),
                          options=AnalyzeOptions(relay=RelayOptions("mrft")))
    omega = np.array(sorted(2 * np.pi * t.frequency_hz for t in result.tests))
    models, _ = _drawn_models(result, np.empty((0, 3)))
    assert len(models) >= 100
    _, ph0, m_lo, m_hi, p_lo, p_hi = _bode_band(result, models, omega)
    g = family_model("fopdt").with_parameters(**FOPDT).frequency_response(omega)
    mag, ph = 20 * np.log10(np.abs(g)), np.degrees(np.unwrap(np.angle(g)))
    ph -= 360.0 * np.round((ph[0] - ph0[0]) / 360.0)
    assert np.all((m_lo <= mag) & (mag <= m_hi)) and np.all((p_lo <= ph) & (ph <= p_hi))
