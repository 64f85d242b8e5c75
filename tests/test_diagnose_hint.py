"""The warnings a diagnosis would explain end with the hint of the command that made them (AnalyzeOptions.diagnose_hint):
'(try --diagnose)' for analyze and batch without --diagnose, '(try mrft-ident diagnose)' for tune, vehicle, plan and
a library caller, which have no --diagnose (they said '(try --diagnose)'), nothing with the diagnosis run (analyze
appended the hint and then cut it off again)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mrftcli.analyze import AnalyzeOptions, analyze_path
from mrftcli.analyze.options import TRY_DIAGNOSE_COMMAND
from mrftcli.io import ReadOptions
from mrftcli.mrft.model import soiptd_model

LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "concealed" / "flight_05.mcap"  # constraints disagree


def test_each_caller_gets_its_own_hint_or_none():
    assert AnalyzeOptions().diagnose_hint == TRY_DIAGNOSE_COMMAND  # a library caller: the command to run
    warnings = analyze_path(LOG, soiptd_model(0.0422), read=ReadOptions(loop="altitude"),
                            options=AnalyzeOptions(n_bootstrap=20, max_combinations=10,
                                                   diagnose_hint=TRY_DIAGNOSE_COMMAND)).warnings
    hinted = [w for w in warnings if w.endswith(TRY_DIAGNOSE_COMMAND)]
    assert len(hinted) == 2  # the constraints disagree; the waveform refinement was not used
    assert sum("(try " in w for w in warnings) == 2  # nowhere else; analyze's TRY_DIAGNOSE: test_analyze_cli


def test_tune_and_vehicle_point_to_the_diagnose_command(monkeypatch):
    """tune and vehicle have no --diagnose: they build their analysis with TRY_DIAGNOSE_COMMAND."""
    import mrftcli.analyze
    from mrftcli.cli.main import main
    from mrftcli.vehicle.driver import VehicleOptions

    assert VehicleOptions().analyze().diagnose_hint == TRY_DIAGNOSE_COMMAND
    asked = []

    def stop(path, model, *, read=None, options=None, **kwargs):
        asked.append(options)
        raise SystemExit(0)  # the options are what is checked: no analysis needed

    monkeypatch.setattr(mrftcli.analyze, "analyze_path", stop)
    with pytest.raises(SystemExit):
        main(["tune", str(LOG), "--tp", "0.0422", "--loop", "altitude", "-q"])
    assert [o.diagnose_hint for o in asked] == [TRY_DIAGNOSE_COMMAND]
