"""``analyze`` over every log in sample_logs/, checked against the ground-truth sidecars.

The sidecars are read here only; mrft-ident never sees them. The "+20 ms" pairs also repeat the
paper's delay-increment experiment on the committed logs.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mrftcli.mrft.model import soiptd_model
from mrftcli.io import ReadOptions
from mrftcli.analyze import AnalyzeOptions

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"
SIDECARS = sorted(SAMPLES.glob("*.truth.json")) if SAMPLES.is_dir() else []


def _log_of(sidecar: Path) -> Path:
    return sidecar.with_name(sidecar.name[: -len(".truth.json")])


@pytest.mark.skipif(not SIDECARS, reason="no sample_logs/ with sidecars")
@pytest.mark.parametrize("sidecar", SIDECARS, ids=lambda p: p.name[: -len(".truth.json")])
def test_sample_log_against_sidecar(sidecar, shared_results):
    truth = json.loads(sidecar.read_text())
    # shared (conftest.SharedResults) with test_layouts' and test_receive_stamped's analyses of the same logs
    r = shared_results.analysis(_log_of(sidecar), soiptd_model(truth["Tp"]), ReadOptions(loop=truth["loop"]),
                                AnalyzeOptions(n_bootstrap=200))
    assert len(r.tests) == len(truth["tests"])
    well_sampled = truth.get("log_rate_hz", truth["rate_hz"]) >= 100
    for t, tt in zip(r.tests, truth["tests"]):
        # stacks that do not log beta (HEAR, MATLAB) give None; PX4 stores it as a float32 parameter
        assert t.beta_nominal is None or t.beta_nominal == pytest.approx(tt["beta"], abs=1e-6)
        if well_sampled:  # at 10 Hz the switch instants, and so the effective beta, are coarse
            assert t.beta_effective == pytest.approx(tt["beta"], abs=0.1)
    assert not r.rejected and all(t.validity.ok for t in r.tests)  # no false rejection
    for t, tt in zip(r.tests, truth["tests"]):
        assert t.h == pytest.approx(tt["h"], rel=1e-6)
        assert tt["t_start"] - 0.01 <= t.t_start and t.t_end <= tt["t_end"] + 0.01
    if well_sampled:  # low-rate logs: their interval is checked below
        assert abs(r.tau.value - truth["tau"]) <= 1e-3
    mrft = r.parameters_mrft  # the MRFT estimate's (bootstrap) interval holds the truth on every log
    assert mrft["tau"].ci95_low <= truth["tau"] <= mrft["tau"].ci95_high
    if r.method == "waveform":  # the refined one's Gauss-Newton std is honest (z within 3 on each log)
        for name in ("tau", "K", "Td"):
            assert abs(getattr(r, name).value - truth[name]) <= 3 * getattr(r, name).std, name
    assert r.K.value == pytest.approx(truth["K"], rel=0.03)
    td_omega = max(r.model.Td * 2 * np.pi * t.frequency_hz_mean for t in r.tests)
    if td_omega <= 5:
        assert r.Td.value == pytest.approx(truth["Td"], rel=0.05)
    assert mrft["Td"].ci95_low <= truth["Td"] <= mrft["Td"].ci95_high


@pytest.mark.parametrize("design", ["design1", "design2"])
def test_delay_increment_on_sample_logs(design, shared_results):
    base, added = SAMPLES / f"{design}_altitude.mcap", SAMPLES / f"{design}_altitude_20ms.mcap"
    if not (base.exists() and added.exists()):
        pytest.skip("sample logs missing")
    tp = json.loads(Path(str(base) + ".truth.json").read_text())["Tp"]
    # the sidecar test's analyses (shared): tau's point estimate does not depend on the bootstrap's draws
    tau = [shared_results.analysis(log, soiptd_model(tp), ReadOptions(loop="altitude"),
                                   AnalyzeOptions(n_bootstrap=200)).tau.value for log in (added, base)]
    d_tau = tau[0] - tau[1]
    assert d_tau * 1e3 == pytest.approx(20.0, abs=1.5)
