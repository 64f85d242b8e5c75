"""The ardupilot-mrft layout holds one axis per log and says which (MRFB:Ax): reading it as another
loop is refused, naming the loop the log holds, instead of identifying roll with altitude's units."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_main

from mrftcli.errors import InputError, OtherLoopError
from mrftcli.io import ReadOptions, read_flight

LOGS = Path(__file__).resolve().parents[1] / "sample_logs" / "sitl"


@pytest.mark.skipif(not (LOGS / "pitch.BIN").exists(), reason="ArduPilot SITL sample log not shipped")
def test_a_pitch_log_read_as_altitude_is_refused_naming_pitch() -> None:
    with pytest.raises(OtherLoopError, match=r"excite the pitch loop \(MRFB:Ax\), not altitude: give --loop pitch"):
        read_flight(LOGS / "pitch.BIN", ReadOptions(loop="altitude"), echo_warnings=False)
    flight = read_flight(LOGS / "pitch.BIN", ReadOptions(loop="pitch"), echo_warnings=False)
    assert flight.loop == "pitch"
    # the user's own output topic: the topics are theirs, the logged axis is not checked
    assert read_flight(LOGS / "pitch.BIN", ReadOptions(loop="altitude", output_topic="MRFT:Out"),
                       echo_warnings=False).loop == "altitude"


@pytest.mark.skipif(not (LOGS / "roll.BIN").exists(), reason="ArduPilot SITL sample log not shipped")
def test_cli_roll_log_without_loop_is_one_line_error() -> None:
    proc = run_main("analyze", str(LOGS / "roll.BIN"), "--tp", "0.00915")  # main() in this process, as the console
    assert proc.returncode == 4  # no usable test on the loop asked, as a log without any (docs/usage.md)
    assert proc.stderr.strip().splitlines() == [
        f"error: {LOGS / 'roll.BIN'}: the log's tests excite the roll loop (MRFB:Ax), not altitude: give --loop roll"]
    assert "Traceback" not in proc.stderr


@pytest.mark.skipif(not (LOGS / "pitch.BIN").exists(), reason="ArduPilot SITL sample log not shipped")
def test_vehicle_identifies_only_the_logged_axis() -> None:
    """``vehicle`` tries every loop: a pitch log used to be identified three times, as altitude (in m),
    roll and pitch; now only pitch, and the other loops are reported as without tests (the log's MRFB:Ax
    names pitch: fly the others' tests, not 'record their topics')."""
    proc = run_main("vehicle", str(LOGS / "pitch.BIN"), "--tp", "0.00915")
    assert proc.returncode == 0, proc.stderr
    rows = [line.split()[0] for line in proc.stdout.splitlines()[2:] if " inner " in line or " outer " in line]
    assert rows == ["pitch"]
    assert "altitude: no-tests" in proc.stdout and "roll: no-tests" in proc.stdout


class _TwoAxisLog:
    """A stand-in for an open log whose MRFB:Ax says roll, then pitch (the script flew both axes)."""

    path = Path("two_axes.BIN")

    def resolve_topic(self, name: str) -> str | None:
        return name if name == "MRFB" else None

    def values(self, topic: str, field: str | None = None) -> tuple[np.ndarray, list[str], dict[str, np.ndarray]]:
        return np.array([1.0, 20.0]), ["Ax"], {"Ax": np.array([2.0, 3.0])}


def test_a_log_of_two_axes_is_refused_naming_both() -> None:
    from mrftcli.io.flight import _check_logged_loop
    from mrftcli.io.layouts import LAYOUTS

    with pytest.raises(InputError, match=r"excite the pitch and roll loops \(MRFB:Ax\); the ardupilot-mrft layout "
                                         r"reads one loop per log"):
        _check_logged_loop(_TwoAxisLog(), LAYOUTS["ardupilot-mrft"], ReadOptions(loop="pitch"))  # type: ignore[arg-type]
