"""The segmenter on relay-feedback recordings from real hardware (KSTAR vertical control).

The oracle is ../shared/data/real_relay/README.md: its tables of windows, relay levels, biases and
periods were read from the data independently of this tool. The recordings are not of the UAV
model class; the tests check that every clean window is found and measured, that no window
without a two-level relay (or with a stuck relay) becomes a test, and that the CLI ends with a
clear message, no NaN and no library warning.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from mrftcli.io import ReadOptions, read_flight
from mrftcli.segment import segment

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real_relay"
FILE_5K = DATA / "kstar23070_relay.csv"
FILE_10K = DATA / "kstar_signals21801_biased_relay.csv"

pytestmark = pytest.mark.skipif(
    not (FILE_5K.is_file() and FILE_10K.is_file()),
    reason="needs ../shared/data/real_relay/ (KSTAR relay recordings, from the public repository "
           "josiahwai/parasitic_relay_feedback; read in place, never copied into the project)",
)


def _tests(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no library warning may escape the segmenter
        flight = read_flight(path, ReadOptions(command_topic="u_relay", output_topic="y_output"), echo_warnings=False)
        return segment(flight)


def _usable(t) -> bool:
    return t.validity.ok and sum(c.stable for c in t.cycles) >= 3


@pytest.fixture(scope="module")
def tests_10k():
    return _tests(FILE_10K)


@pytest.fixture(scope="module")
def tests_5k():
    return _tests(FILE_5K)


# README table of the 10 kHz file: window start [s], high, low, bias, period [s]
WINDOWS_10K = [(2.0, 700, -480, 110, 0.037), (3.0, 1200, -720, 240, 0.025), (4.0, 1500, -900, 300, 0.023),
               (6.0, 1200, -720, 240, 0.113), (7.0, 1500, -900, 300, 0.066)]


def test_biased_relay_every_clean_window_found_with_levels_bias_and_period(tests_10k):
    assert len(tests_10k) == len(WINDOWS_10K)
    for t, (t0, hi, lo, bias, period) in zip(tests_10k, WINDOWS_10K):
        assert abs(t.t_start - t0) < 0.05 and t.t_end < t0 + 1.0
        assert t.bias + t.h == pytest.approx(hi, rel=0.02)
        assert t.bias - t.h == pytest.approx(lo, rel=0.02)
        assert t.bias == pytest.approx(bias, rel=0.05)
        assert t.period_median == pytest.approx(period, rel=0.15)


def test_biased_relay_stuck_window_is_never_a_test(tests_10k):
    # 5.0-5.9 s: the relay sits at +800 with about one switch
    assert not any(t.t_end > 5.0 and t.t_start < 5.9 for t in tests_10k)


def test_hysteresis_relay_measured_as_positive_effective_beta(tests_10k):
    # u goes high when the error rises through +eps: a hysteresis relay switches after the
    # output's extremum on the way down, i.e. beta_eff in (0, 1), and the loop sign is the logged one
    measured = [t for t in tests_10k if np.isfinite(t.beta_effective)]
    assert len(measured) >= 3
    for t in measured:
        assert t.loop_sign == 1
        assert 0.0 < t.beta_effective < 1.0


# README table of the 5 kHz file: clean windows [s] and relay half-height
CLEAN_5K = [(1.0, 2.0, 1000), (3.0, 4.0, 1000), (4.0, 5.0, 800), (8.0, 8.5, 1000), (8.5, 9.0, 1500)]
NOT_RELAY_5K = [(2.0, 3.0), (5.0, 7.0), (7.12, 7.9)]


def test_ideal_relay_clean_windows_found_one_test_per_block(tests_5k):
    for a, b, h in CLEAN_5K:
        inside = [t for t in tests_5k if t.t_start >= a - 0.01 and t.t_end <= b + 0.01]
        covered = sum(t.t_end - t.t_start for t in inside)
        assert covered > 0.85 * (b - a), (a, b, covered)  # chattering switches do not cut a block up
        assert all(t.h == pytest.approx(h, rel=0.01) and abs(t.bias) < 0.01 * h for t in inside)
        usable = [t for t in inside if _usable(t)]
        assert usable, (a, b)
        for t in usable:
            assert 250.0 < 1.0 / t.period_median < 330.0  # README: 270-310 Hz, ~15 samples per cycle
            assert abs(t.beta_effective) < 0.35  # an ideal relay switching within a sample of the crossing


def test_ideal_relay_no_test_where_the_command_is_not_a_two_level_relay(tests_5k):
    for a, b in NOT_RELAY_5K:
        assert not any(t.t_end > a and t.t_start < b for t in tests_5k), (a, b)
    # 7.0-7.1 s holds a few clean switches before the command turns continuous: never a usable test
    assert not any(_usable(t) for t in tests_5k if 7.0 <= t.t_start < 7.9)


# the 5 kHz file through one clean block and the start of one that is not a relay (1-2.5 s): its ~1500
# cycles of ~300 Hz make the whole file 40 s of CPU, and the segmenter tests above read all of it
@pytest.mark.parametrize("path, tp, window", [(FILE_5K, "0.001", ["--window", "1:2.5"]), (FILE_10K, "0.01", [])])
def test_cli_ends_with_a_clear_message_without_nan_or_library_warnings(path, tp, window):
    proc = subprocess.run([sys.executable, "-m", "mrftcli.cli", "analyze", str(path), "--tp", tp,
                           "--command-topic", "u_relay", "--output-topic", "y_output", *window],
                          capture_output=True, text=True, timeout=300)
    text = proc.stdout + proc.stderr
    assert "Traceback" not in text and "Warning:" not in text and ".py:" not in text
    assert not re.search(r"\bnan", text.lower())  # no NaN figure anywhere ("nan s", "nanx the noise")
    if proc.returncode != 0:
        # the plant does not follow eq. (2) (or one beta only): said in one line, with the reason
        last = proc.stderr.strip().splitlines()[-1]
        assert last.startswith("error: ") and ("eq. (2)" in last or "one beta" in last or "follow" in last)


# --- issue 22: the process-plant path (analyze --model fopdt) on the real recordings ---------------
@pytest.fixture(scope="module")
def fopdt_10k():
    from mrftcli.analyze import analyze_flight
    from mrftcli.mrft.families import family_model

    flight = read_flight(FILE_10K, ReadOptions(command_topic="u_relay", output_topic="y_output"), echo_warnings=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return analyze_flight(flight, family_model("fopdt"))


def test_fopdt_10k_every_clean_window_a_test_with_its_relay(fopdt_10k):
    tests = fopdt_10k.tests
    assert [round(t.t_start) for t in tests] == [w[0] for w in WINDOWS_10K]
    assert not any(t.t_end > 5.0 and t.t_start < 5.9 for t in tests)  # the stuck window
    for t, (_, hi, lo, bias, period) in zip(tests, WINDOWS_10K):
        assert t.relay.kind == "hysteresis"
        assert (t.relay.high, t.relay.low) == pytest.approx((hi, lo), rel=0.02)
        assert t.relay.bias == pytest.approx(bias, rel=0.05)
    # README: eps ~1.2e-6 in 2-5 s, ~4e-6 in 6-8 s (read at the switch instants)
    assert all(0.6e-6 < t.relay.eps < 2e-6 for t in tests[:3])
    assert all(3e-6 < t.relay.eps < 5e-6 for t in tests[3:])


def test_fopdt_10k_model_and_held_out(fopdt_10k):
    ident = fopdt_10k.identification
    assert ident is not None
    # issue 38: FOPDT does not explain the shot within its scatter (chi2/dof ~11), so K and T, which trade
    # along the tests' slope, are known within a factor ~1.5-2 only: not determined (within 1.25x), with
    # K/T determined; the published describing-function fit's K sits inside K's interval
    assert set(ident.undetermined) <= {"K", "T"} and ident.estimate("tau").determined
    if ident.undetermined:
        assert ident.combination is not None and ident.combination.name == "K/T"
        k = ident.estimate("K")
        assert k.ci95_low < 6.7e-9 < k.ci95_high
    # the published describing-function fit: |K| 6.7e-9 / 8.1e-9, T 24 / 32 ms, delay 4.2 / 3.8 ms;
    # ours (exact harmonics, complex means) sits near it: same delay, shorter T, smaller K
    assert 2e-9 < ident.estimate("K").value < 1e-8
    assert 0.005 < ident.estimate("T").value < 0.04
    assert 0.003 < ident.estimate("tau").value < 0.006
    held = [t.held_out for t in fopdt_10k.tests]
    assert all(h is not None and h.frequency_hz is not None for h in held)
    # windows 3 and 5 are predicted by the others within 10 %; windows 1, 2 and 4 are not
    # (docs/process-plants.md: no FOPDT identified from four windows predicts the fifth within 10 %);
    # none is the spurious sub-hertz cycle the hysteresis root search gave windows 4-5
    for k in (2, 4):
        assert held[k].frequency_hz == pytest.approx(fopdt_10k.tests[k].frequency_hz, rel=0.10)
    assert all(0.5 < h.frequency_hz / t.frequency_hz < 2.0 for h, t in zip(held, fopdt_10k.tests))
    text = json.dumps(fopdt_10k.to_json())
    assert "NaN" not in text and "Infinity" not in text


def test_fopdt_5k_ideal_relay_says_what_it_determines():
    from mrftcli.analyze import analyze_flight
    from mrftcli.cli.analyze import format_analysis
    from mrftcli.mrft.families import family_model

    flight = read_flight(FILE_5K, ReadOptions(command_topic="u_relay", output_topic="y_output"), echo_warnings=False)
    result = analyze_flight(flight, family_model("fopdt"))
    assert len(result.tests) >= 15
    assert sum(t.relay.kind == "ideal" for t in result.tests) >= 0.8 * len(result.tests)
    text = format_analysis(result)
    assert "nan" not in text.lower()
    ident = result.identification
    assert ident is not None
    # one relay type at one phase: the table says which parameters the tests leave open, if any
    for e in ident.estimates:
        assert ("NOT DETERMINED" in text) == bool(ident.undetermined)
        assert np.isfinite(e.value)
    assert "NaN" not in json.dumps(result.to_json())
