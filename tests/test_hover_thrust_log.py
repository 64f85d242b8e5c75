"""PX4's hover thrust read from the log's ``hover_thrust_estimate`` when ``--hover-thrust`` is not given
(tune and vehicle ``--export px4`` on altitude, x, y), stated first; refused before the work when absent."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mrftcli.errors import InputError
from mrftcli.io import TopicData, open_log, write_log
from mrftcli.io.hover import logged_hover_thrust

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"


def _log(tmp_path: Path, fields: dict[str, np.ndarray], name: str = "hover.ulg") -> Path:
    t = np.arange(fields["hover_thrust"].size) * 0.1
    pos = TopicData("vehicle_local_position", "px4", t, {"x": np.zeros(t.size), "z": np.zeros(t.size)})
    return write_log([pos, TopicData("hover_thrust_estimate", "px4", t, fields)], tmp_path / name)


def test_the_median_of_the_valid_samples_only(tmp_path):
    rng = np.random.default_rng(5)
    v = rng.uniform(0.40, 0.60, 101)
    valid = np.ones(v.size)
    valid[:30] = 0.0  # before take-off: not converged
    v[:30] = 0.9  # would move the median if kept
    v[40] = np.nan
    with open_log(_log(tmp_path, {"hover_thrust": v, "valid": valid}), echo_warnings=False) as src:
        got = logged_hover_thrust(src)
    kept = sorted(v[30:40].tolist() + v[41:].tolist())  # independent: the middle of the 70 kept, by hand
    assert got is not None and got.samples == 70
    assert got.value == pytest.approx((kept[34] + kept[35]) / 2, rel=1e-6)  # float32 in the ULog
    assert got.low == pytest.approx(kept[0], rel=1e-6) and got.high == pytest.approx(kept[-1], rel=1e-6)
    assert f"{got.value:.4g}" in got.statement() and "70 valid" in got.statement()


def test_absent_or_never_valid_gives_none(tmp_path):
    with open_log(SAMPLES / "design1_altitude.ulg", echo_warnings=False) as src:
        assert logged_hover_thrust(src) is None
    v = np.full(20, 0.5)
    with open_log(_log(tmp_path, {"hover_thrust": v, "valid": np.zeros(20)}), echo_warnings=False) as src:
        assert logged_hover_thrust(src) is None
    # a log without the valid flag: every sample inside (0, 1)
    v = np.r_[np.full(9, 0.45), 1.5]
    with open_log(_log(tmp_path, {"hover_thrust": v}, "novalid.ulg"), echo_warnings=False) as src:
        got = logged_hover_thrust(src)
    assert got is not None and got.samples == 9 and got.value == pytest.approx(0.45, rel=1e-6)


def test_vehicle_refuses_before_any_analysis_without_the_estimate(monkeypatch):
    """No --hover-thrust and a ULog without the estimate: one line naming the option, before any analysis
    (it used to fail after the analysis of every loop)."""
    import mrftcli.vehicle.driver as driver
    from mrftcli.mrft.model import soiptd_model
    from mrftcli.vehicle import StackOptions, TuneOptions, VehicleOptions, identify_vehicle

    def no_analysis(*args, **kwargs):
        raise AssertionError("analysed before the options were checked")

    monkeypatch.setattr(driver, "analyze_flight", no_analysis)
    opts = VehicleOptions(tune=TuneOptions(stack=StackOptions("px4")))
    # design1_altitude.ulg's /mocap/pose holds z alone: x and y are found but not recorded, and not named
    with pytest.raises(InputError, match=r"--hover-thrust X \(MPC_THR_HOVER.*export of the altitude loop needs it "
                                         r"and the log holds no valid hover_thrust_estimate"):
        identify_vehicle(SAMPLES / "design1_altitude.ulg", soiptd_model(0.0422), options=opts)
    # ArduPilot's altitude too: the same option, before the work
    opts = VehicleOptions(tune=TuneOptions(stack=StackOptions("ardupilot")))
    with pytest.raises(InputError, match="MOT_THST_HOVER"):
        identify_vehicle(SAMPLES / "sitl" / "altitude.BIN", soiptd_model(0.0422), options=opts)


def test_tune_refuses_at_once_without_the_estimate(capsys):
    from mrftcli.cli.main import main

    with pytest.raises(SystemExit) as ex:
        main(["tune", str(SAMPLES / "design1_altitude.ulg"), "--tp", "0.0422", "--loop", "altitude", "--export", "px4",
              "-q"])
    err = capsys.readouterr().err
    assert ex.value.code == 2 and len(err.strip().splitlines()) == 1
    # the same line vehicle gives: the option, and why it was not read from the log
    assert "--hover-thrust X (MPC_THR_HOVER" in err and "altitude loop needs it and the log holds no valid " \
        "hover_thrust_estimate" in err


def test_one_rule_for_given_read_or_refused():
    """tune and vehicle share :func:`read_hover_thrust`: the log is read only when the option is not given and a
    loop's export needs it (HOVER_LOOPS); a loop that may go without it (vehicle's cascade x, y) is not refused."""
    from mrftcli.io.hover import LoggedHoverThrust
    from mrftcli.tune.stacks import read_hover_thrust

    def never():
        raise AssertionError("read although not needed")

    est = LoggedHoverThrust(0.45, 9, 0.44, 0.46, "hover_thrust_estimate")
    assert read_hover_thrust("px4", ("altitude",), 0.5, never) is None  # given
    assert read_hover_thrust("px4", ("roll", "pitch"), None, never) is None  # not needed
    assert read_hover_thrust("hear", ("altitude",), None, never) is None
    assert read_hover_thrust("ardupilot", ("x",), None, never) is None
    assert read_hover_thrust("px4", ("roll", "x"), None, lambda: est) is est
    assert read_hover_thrust("px4", ("x", "y"), None, lambda: None, optional=("x", "y")) is None
    with pytest.raises(InputError, match=r"MPC_THR_HOVER, normalised 0-1\): the px4 export of the altitude, x loops "
                                         "needs it and the log holds no valid hover_thrust_estimate"):
        read_hover_thrust("px4", ("altitude", "roll", "x"), None, lambda: None)
    with pytest.raises(InputError, match=r"MOT_THST_HOVER, throttle 0-1\): the ardupilot export of the altitude loop "
                                         "needs it and it is not read from ArduPilot's log"):
        read_hover_thrust("ardupilot", ("altitude",), None, never)
