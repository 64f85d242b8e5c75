"""PX4's ``MRFT_DELAY`` on the rate relays (scripts/sitl/px4/mrft_roll.patch, issue 42): the layout's roll and
pitch command (``vehicle_torque_setpoint``) is then the relay's output held that long, and read as the command
it hides the delay from tau (a silently wrong number). With the delay set in the ULog's parameters the
``px4-mrft`` layout reads the decision the patch logs in ``debug_vect`` (x roll, y pitch) and says so; without
the decision logged, one error naming ``--command-topic``; an explicit ``--command-topic`` wins.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from mrftcli.errors import LogReadError
from mrftcli.io import ReadOptions, read_flight
from mrftcli.io.format_ulog import write_ulog
from mrftcli.io.logtypes import TopicData

LOGS = Path(__file__).parents[1] / "sample_logs" / "sitl"
_DT = 0.004  # mc_rate_control's tick in SIH [s]
_HOLD = 5  # MRFT_DELAY 20 ms = 5 ticks


def _write(path: Path, *, delay_ms: float | None, decision: bool = True,
           changes: list[tuple[float, str, float]] | None = None) -> np.ndarray:
    """A PX4-like ULog of a pitch relay: the decision (+-0.2 at 1.5 Hz), the torque the decision ``_HOLD`` ticks
    later, the attitude's pitch a sine; returns the decision."""
    t = 10.0 + _DT * np.arange(2500)
    u = np.where(np.sin(2 * math.pi * 1.5 * t) >= 0, 0.2, -0.2)
    held = np.r_[np.zeros(_HOLD), u[:-_HOLD]]
    half = 0.5 * 0.1 * np.sin(2 * math.pi * 1.5 * t - 2.0)  # half the pitch angle [rad]
    zero = np.zeros_like(t)
    topics = [TopicData("vehicle_local_position_setpoint", "px4", t, {"thrust[0]": zero, "thrust[1]": zero,
                                                                    "thrust[2]": zero - 0.5}),
              TopicData("vehicle_torque_setpoint", "px4", t, {"xyz[0]": zero, "xyz[1]": held, "xyz[2]": zero}),
              TopicData("vehicle_attitude", "px4", t, {"q[0]": np.cos(half), "q[1]": zero, "q[2]": np.sin(half),
                                                       "q[3]": zero})]
    if decision:
        topics.append(TopicData("debug_vect", "px4", t, {"x": zero, "y": u, "z": zero + (delay_ms or 0.0)}))
    params = {"MRFT_P_ENABLE": 0.0, "MRFT_P_BETA": -0.5}
    if delay_ms is not None:
        params["MRFT_DELAY"] = delay_ms
    write_ulog(topics, path, parameters=params, parameter_changes=changes)
    return u


def test_a_delayed_relay_is_read_from_its_decision_and_said(tmp_path: Path) -> None:
    path = tmp_path / "pitch_delay.ulg"
    decision = _write(path, delay_ms=20.0)
    flight = read_flight(path, ReadOptions(loop="pitch"), echo_warnings=False)
    np.testing.assert_array_equal(flight.command.values, decision)
    assert flight.source["command"] == "debug_vect:y"
    said = flight.source["command_choice"]
    assert "MRFT_DELAY 20 ms" in said and "vehicle_torque_setpoint:xyz[1]" in said and "--command-topic" in said
    # the user's --command-topic is used as given: the held torque, no choice stated
    given = read_flight(path, ReadOptions(loop="pitch", command_topic="vehicle_torque_setpoint:xyz[1]"),
                        echo_warnings=False)
    np.testing.assert_array_equal(given.command.values[_HOLD:], decision[:-_HOLD])
    assert "command_choice" not in given.source
    # altitude's command (mc_pos_control logs its decision, before the delay) is unchanged
    alt = read_flight(path, ReadOptions(loop="altitude", output_topic="vehicle_attitude:q[0]"), echo_warnings=False)
    assert alt.source["command"] == "vehicle_local_position_setpoint:thrust[2]" and "command_choice" not in alt.source


def test_a_delay_set_during_the_log_counts(tmp_path: Path) -> None:
    path = tmp_path / "pitch_changed.ulg"
    decision = _write(path, delay_ms=0.0, changes=[(12.0, "MRFT_DELAY", 20.0)])
    flight = read_flight(path, ReadOptions(loop="pitch"), echo_warnings=False)
    np.testing.assert_array_equal(flight.command.values, decision)


@pytest.mark.parametrize("delay_ms", [0.0, None])
def test_without_a_delay_the_torque_is_the_command(tmp_path: Path, delay_ms: float | None) -> None:
    path = tmp_path / "pitch_nodelay.ulg"
    _write(path, delay_ms=delay_ms)
    flight = read_flight(path, ReadOptions(loop="pitch"), echo_warnings=False)
    assert flight.source["command"] == "vehicle_torque_setpoint:xyz[1]" and "command_choice" not in flight.source


def test_a_delay_without_the_decision_logged_is_one_error_naming_the_option(tmp_path: Path) -> None:
    path = tmp_path / "pitch_nodecision.ulg"
    _write(path, delay_ms=20.0, decision=False)
    with pytest.raises(LogReadError) as err:
        read_flight(path, ReadOptions(loop="pitch"), echo_warnings=False)
    msg = str(err.value)
    assert "\n" not in msg and "MRFT_DELAY is 20 ms" in msg and "--command-topic" in msg


@pytest.mark.skipif(not (LOGS / "px4_pitch_h_20ms.ulg").exists(), reason="no PX4 SITL sample logs")
def test_px4_sitl_pitch_with_20ms_gives_the_delay_back_by_default() -> None:
    """PX4 SITL's pitch flights with MRFT_DELAY 0 and 20 ms, read with the layout's defaults: on SIH's attitude
    at SIH's discrete motor lag (an exponential of -dt / ln(1 - dt / SIH_T_TAU), docs/sitl.md) tau rises by the
    20.0 ms the firmware realises (5 ticks of 4 ms), within 2 ms; the torque read as the command gave ~0."""
    from mrftcli.analyze import AnalyzeOptions, analyze_flight
    from mrftcli.mrft.model import soiptd_model

    side = json.loads((LOGS / "px4_pitch_h_20ms.ulg.json").read_text())
    tp = -_DT / math.log(1.0 - _DT / side["sih_model"]["SIH_T_TAU"])
    opts = AnalyzeOptions(n_bootstrap=20, seed=1, refine_waveform=False)
    taus = []
    for name in ("px4_pitch_h", "px4_pitch_h_20ms"):
        flight = read_flight(LOGS / f"{name}.ulg", ReadOptions(loop="pitch", output_topic="vehicle_attitude_groundtruth:q"),
                             echo_warnings=False)
        taus.append(analyze_flight(flight, soiptd_model(tp), options=opts).tau.value)
    assert flight.source["command"] == side["decision_topic"] == "debug_vect:y"
    assert taus[1] - taus[0] == pytest.approx(side["added_delay_ms"] * 1e-3, abs=0.002)
