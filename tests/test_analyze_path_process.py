"""analyze_path's default read for a process model: its record's loop is 'process' (as analyze --model without --loop
says), not the vehicle default 'altitude' that ReadOptions() names (last stop's noticed-left-alone)."""

from __future__ import annotations

from mrftcli.analyze import analyze_path
from mrftcli.mrft.families import family_model
from mrftcli.mrft.model import soiptd_model
from mrftcli.samples import sample_log


def test_a_process_models_default_loop_is_process_and_eq2s_altitude():
    log = sample_log("design1_altitude.csv")
    assert analyze_path(log, family_model("fopdt")).loop == "process"
    assert analyze_path(log, soiptd_model(0.0422)).loop == "altitude"  # eq. (2): the vehicle default, unchanged
