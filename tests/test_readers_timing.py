"""The log's clock (io/timing), the frozen FlightLog and its timing, the read options and the follower's choice."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from mrftcli.errors import InputError
from mrftcli.io import ReadOptions, read_flight
from mrftcli.io.follow import follow_log, is_mcap
from mrftcli.io.logtypes import FlightLog, Signal
from mrftcli.io.timing import (TIMING_SCHEMA_VERSION, Timing, controller_rate_hz, mean_rate_hz, median_rate_hz,
                               receive_jitter_s)


def _flight(**kw) -> FlightLog:
    t = np.arange(5) * 0.01
    return FlightLog("f.csv", "altitude", Signal(t, np.zeros(5)), Signal(t, np.ones(5)), **kw)


# -- rates --------------------------------------------------------------------------------------------
def test_median_rate_ignores_repeated_stamps_and_drops():
    t = np.array([0.0, 0.01, 0.02, 0.02, 0.02, 0.03, 0.05, 0.06])  # a batch stamped twice, a drop
    assert median_rate_hz(t) == pytest.approx(100.0)


@pytest.mark.parametrize("t", [[], [0.0], [0.0, 0.01], [1.0, 1.0, 1.0]], ids=["empty", "one", "two", "one-stamp"])
def test_median_rate_is_unknown_without_a_clock(t):
    assert median_rate_hz(t) is None


def test_mean_rate_is_messages_over_span():
    assert mean_rate_hz([0.0, 0.5, 2.0]) == pytest.approx(1.0)
    assert mean_rate_hz([3.0]) is None and mean_rate_hz([2.0, 2.0]) is None


def test_receive_jitter_of_alternating_delays():
    # every third stamp late by e: spacings dt + e, dt - e, dt; median dt, deviations e, e, 0: MAD e
    e = 0.001
    t = np.arange(40) * 0.01 + e * (np.arange(40) % 3 == 1)
    assert receive_jitter_s(t) == pytest.approx(e * 1.4826 / math.sqrt(2.0))
    assert math.isnan(receive_jitter_s(t[:19]))


def test_controller_rate_prefers_the_declared_one():
    t = np.arange(10) * 0.1
    assert controller_rate_hz(Timing(50.0), t) == 50.0
    assert controller_rate_hz(Timing(), t) == pytest.approx(10.0)
    assert controller_rate_hz(Timing(), t[:2]) is None


# -- the Timing record --------------------------------------------------------------------------------
@pytest.mark.parametrize("timing", [Timing(), Timing(50.0), Timing(None, "receive", 0.0016),
                                    Timing(200.0, "receive", None), Timing(50.0, controller_rate_assumed=True)],
                         ids=["header", "rate", "receive", "no-jitter", "assumed"])
def test_timing_round_trips_through_json(timing):
    data = json.loads(json.dumps(timing.to_json()))
    assert data["schema_version"] == TIMING_SCHEMA_VERSION == 2
    assert Timing.from_json(data) == timing


def test_a_version_1_timing_record_reads_as_a_rate_not_assumed():
    assert Timing.from_json({"schema_version": 1, "controller_rate_hz": 50.0, "stamps": "header",
                             "timing_jitter_s": None}) == Timing(50.0)
    # a JSON integer is a number (jsonable.json_opt_float, the one reader): read as a float
    rate = Timing.from_json({"schema_version": 1, "controller_rate_hz": 50, "stamps": "header"}).controller_rate_hz
    assert rate == 50.0 and type(rate) is float


def test_timing_nan_jitter_is_written_as_null():
    data = Timing(None, "receive", float("nan")).to_json()
    assert data["timing_jitter_s"] is None
    json.dumps(data, allow_nan=False)


@pytest.mark.parametrize(("data", "match"), [
    ([], "expected a JSON object"),
    ({"schema_version": 99, "stamps": "header"}, "schema_version 99"),
    ({"schema_version": TIMING_SCHEMA_VERSION, "stamps": "arrival"}, "stamps must be"),
    ({"schema_version": TIMING_SCHEMA_VERSION, "stamps": "header", "controller_rate_hz": "50"},
     r"^timing: expected controller_rate_hz to be a number or null, got '50'$"),
    ({"schema_version": TIMING_SCHEMA_VERSION, "stamps": "header", "timing_jitter_s": True},
     r"^timing: expected timing_jitter_s to be a number or null, got True$"),
], ids=["not-a-dict", "version", "stamps", "rate-string", "jitter-bool"])
def test_timing_from_json_refuses_bad_input(data, match):
    with pytest.raises(InputError, match=match):
        Timing.from_json(data)


# -- FlightLog ----------------------------------------------------------------------------------------
def test_flight_log_is_frozen_and_replaced():
    flight = _flight(warnings=["a"])
    assert flight.warnings == ("a",)
    with pytest.raises(dataclasses.FrozenInstanceError):
        flight.command = flight.output  # type: ignore[misc]
    flipped = dataclasses.replace(flight, output=Signal(flight.output.t, -flight.output.values))
    assert flipped.output.values[0] == -1.0 and flight.output.values[0] == 1.0


def test_source_json_puts_the_timing_back_where_it_was():
    source = {"format": "bag", "layout": "hear-ros (auto-detected: /fh_des)", "command": "/fh_des:x",
              "output": "/opti/pos:x"}
    flight = _flight(source=source, timing=Timing(50.0, "receive", 0.002))
    assert list(flight.source_json()) == ["format", "layout", "controller_rate_hz", "command", "output",
                                          "timestamps", "timing_jitter_s"]
    assert flight.source_json()["timing_jitter_s"] == 0.002
    assert "timing_jitter_s" not in flight.source  # the descriptive metadata only
    assert _flight(source=source).source_json() == source  # header stamps, no declared rate: nothing added


def test_px4_log_declares_its_controller_rate():
    from pathlib import Path

    logs = Path(__file__).parents[1] / "sample_logs"
    flight = read_flight(logs / "px4_altitude_10hz.ulg", echo_warnings=False)
    # the 10 Hz command shows no tick: the layout's 50 Hz, flagged as assumed (and warned of); 50 Hz is measured
    assert flight.timing == Timing(50.0, controller_rate_assumed=True)
    assert any("controller rate 50 Hz assumed" in w for w in flight.warnings)
    assert "controller_rate_hz" not in flight.source
    measured = read_flight(logs / "px4_altitude_50hz.ulg", echo_warnings=False).timing
    assert measured.controller_rate_hz == pytest.approx(50.0) and not measured.controller_rate_assumed
    given = read_flight(logs / "px4_altitude_10hz.ulg", ReadOptions(controller_rate_hz=50.0), echo_warnings=False)
    assert not given.timing.controller_rate_assumed


# -- ReadOptions ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(("kw", "match"), [
    ({"loop": "yaw"}, "unknown loop 'yaw'"),
    ({"output_scale": 0.0}, "output scale must be a finite non-zero number"),
    ({"command_scale": float("inf")}, "command scale must be a finite non-zero number"),
    ({"controller_rate_hz": -5.0}, "controller rate"),
], ids=["loop", "output-scale", "command-scale", "rate"])
def test_read_options_are_checked_on_creation(kw, match):
    with pytest.raises(InputError, match=match):
        ReadOptions(**kw)


# -- which follower --------------------------------------------------------------------------------------
def test_follower_is_chosen_by_format_magic_and_name(tmp_path):
    assert is_mcap(tmp_path / "later.mcap")  # not written yet: the name says it
    csv = tmp_path / "flight.csv"
    csv.write_text("t,/mrft/command\n")
    assert not is_mcap(csv) and is_mcap(csv, "mcap") and not is_mcap(tmp_path / "x.mcap", "csv")
    follower = follow_log(csv, ReadOptions())
    snap = follower.poll()
    assert snap.flight is None and snap.grew and not snap.closed  # the topics are not there yet: next poll
    assert follower.poll().grew is False  # no growth since
