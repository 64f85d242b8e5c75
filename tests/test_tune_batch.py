"""``mrft-ident batch --tune``: the gains per log in the summary, checked against the loop they make."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd
import pytest

pytest.importorskip("control")

from mrftcli.batch.run import settings_hash  # noqa: E402
from mrftcli.batch.inputs import LogSettings  # noqa: E402
from mrftcli.mrft.model import LoopModel  # noqa: E402
from mrftcli.tune.closed_loop import Controller  # noqa: E402
from mrftcli.tune.margins import margins  # noqa: E402

LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "design1_roll.mcap"


@pytest.mark.skipif(not LOG.exists(), reason="sample log missing")
def test_batch_tune_adds_gains_that_give_the_reported_loop(tmp_path):
    from click.testing import CliRunner

    from mrftcli.cli.main import cli

    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["batch", str(LOG), "--tp", "0.0422", "--loop", "roll", "--tune", "--no-report",
                                 "-j", "1", "-q", "--out", str(out), "--json"])
    assert r.exit_code == 0, r.output
    row = json.loads(r.stdout)["rows"][0]
    assert row["tune_design"] == "robust" and row["tune_kind"] == "PD" and row["tune_error"] is None
    assert row["tune_Ki"] == 0.0 and row["tune_Kp"] > 0 and row["tune_Kd"] > 0
    # independent check: the summary's gains on the summary's model give the margins it reports
    model = LoopModel(row["tp"], row["Td_mean"], row["tau_mean"], row["K_mean"])
    c = Controller(row["tune_Kp"], row["tune_Ki"], row["tune_Kd"], row["tune_Tf"], row["tune_rate_hz"])
    mg = margins(model, c)
    assert row["tune_rate_hz"] == pytest.approx(200.0, rel=1e-3)  # the log's command rate
    assert mg.Ms <= 1.6 * 1.002 and mg.Ms == pytest.approx(row["tune_ms"], rel=1e-6)
    assert mg.phase_margin_deg == pytest.approx(row["tune_pm_deg"], abs=1e-6)
    # worst case over the posterior: Ms <= 1.6 on the 95 % set bounds the phase margin below
    assert row["tune_pm_worst_deg"] >= 2 * math.degrees(math.asin(1 / (2 * 1.6))) - 0.5
    assert 0 < row["tune_dm_ms"] < 1e3
    # the same columns in the CSV; a batch without --tune has none
    csv = pd.read_csv(out / "summary.csv")
    assert csv.loc[0, "tune_Kp"] == pytest.approx(row["tune_Kp"], rel=1e-9)
    out2 = tmp_path / "plain"
    r = CliRunner().invoke(cli, ["batch", str(LOG), "--tp", "0.0422", "--loop", "roll", "--no-report", "-j", "1",
                                 "-q", "--out", str(out2)])
    assert r.exit_code == 0, r.output
    assert not any(c.startswith("tune_") for c in pd.read_csv(out2 / "summary.csv").columns)


def test_tune_changes_the_settings_hash_but_not_an_untuned_one():
    s = LogSettings(tp=0.0422, loops=("roll",))
    assert settings_hash(s, False) == settings_hash(s, False, None)
    assert len({settings_hash(s, False), settings_hash(s, False, "PD"), settings_hash(s, False, "PID")}) == 3
