"""The limit-cycle validity check: an output that is not a limit cycle of the relay is rejected.

"Never a silently wrong number": analysing a loop the log does not exercise, an output that is noise,
an unrelated sinusoid, a signal from another flight or a shifted one must not give a confident
result. The wrong cases are constructed here (no ground truth is read back); the valid ones (the
simulator's flights, a low-SNR flight at 10x the noise) must still be accepted and identified.
Oracles: closed forms (the triangle wave's harmonic content, the describing-function phase) and
the exact limit cycle of eq. (2) (LPRS, ``unit_cycle``).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalyzeOptions, analyze_flight
from mrftcli.errors import InsufficientDataError, SegmentationError
from mrftcli.io.logtypes import Signal
from mrftcli.mrft.describing import df_phase
from mrftcli.mrft.lprs import unit_cycle
from mrftcli.segment import ValidityCriterion, check_limit_cycle, cycle_fundamental, segment
from cli_helpers import run_main
from test_segment_support import flight_from_simulated, simulate_paper_flight

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"
ROLL = dict(Tp=0.0499, Td=0.887, tau=0.0228, K=30.0)  # checks.md section 4, Design II roll


@pytest.fixture(scope="module")
def roll():
    sf = simulate_paper_flight(ROLL["Tp"], ROLL["Td"], ROLL["tau"], ROLL["K"], (-0.5, -0.8), loop="roll", seed=5)
    return flight_from_simulated(sf)


def _with_output(flight, y, t=None):
    t = flight.output.t if t is None else t
    return replace(flight, output=Signal(t, y))


def _noise_std(flight) -> float:
    # the simulator's IMU noise (0.2 deg) is what a non-excited axis shows
    return float(np.deg2rad(0.2))


# ------------------------------------------------------------------------------ closed-form oracles


def test_triangle_wave_fundamental_share_and_noise_estimate():
    """A pure integrator under a square wave gives a triangle: 96/pi^4 of its mean square is the
    fundamental (closed form); added white noise is recovered by the fit's residual."""
    P, n, a = 0.8, 160, 2.0
    t = np.arange(n) * P / n
    # zero mean, amplitude a, even about the window's centre (so the fit's drift line, odd about it,
    # takes none of it)
    tri = a * (4 * np.abs(t / P - 0.5) - 1)
    g1, noise, frac, a1 = cycle_fundamental(t, tri, 0.0, P / 2, P, 1.0)
    assert frac == pytest.approx(96 / np.pi**4, rel=2e-3)
    assert a1 == pytest.approx(8 * a / np.pi**2, rel=1e-3)
    # the residual is the noise plus the triangle's harmonics above the 8th (they decay like k^-2)
    trunc = noise
    k = np.arange(9, 2001, 2)
    assert trunc == pytest.approx(8 * a / np.pi**2 * np.sqrt(np.sum(k**-4.0) / 2), rel=0.1)
    rng = np.random.default_rng(0)
    sig = 0.05
    est = np.array([cycle_fundamental(t, tri + rng.normal(0, sig, n), 0.0, P / 2, P, 1.0)[1] for _ in range(40)])
    assert np.sqrt(np.mean(est**2)) == pytest.approx(np.hypot(sig, trunc), rel=0.04)


def test_exact_limit_cycle_phase_lies_in_the_documented_band():
    """For every plant of eq. (2) the exact fundamental phase is within 0.33 rad of -pi + asin(beta)
    (the tolerance the check builds on) and in (-3pi/2, -pi/2) for |beta| <= 0.95."""
    tp = np.geomspace(1e-3, 10, 14)
    td = np.geomspace(1e-2, 300, 14)
    beta = np.linspace(-0.95, 0.95, 11)
    X, Y, B = np.meshgrid(tp, td, beta, indexing="ij")
    theta, _ = unit_cycle(X, Y, B)
    ok = np.isfinite(theta) & (theta >= 0)
    assert ok.sum() > 1000
    phase = -np.pi / 2 - np.arctan(X) - np.arctan(Y) - theta  # arg G(j Omega), Omega = 1
    dev = (phase - df_phase(B))[ok]
    assert np.max(np.abs(dev)) < 0.335
    assert np.max(np.abs(dev)) < ValidityCriterion().phase_tolerance
    assert np.all(phase[ok] < -np.pi / 2) and np.all(phase[ok] > -1.5 * np.pi)


def test_check_on_synthetic_cycles_fails_each_criterion_for_its_reason(roll):
    tests = segment(roll)
    good = tests[0]
    assert good.validity.ok and good.validity.snr > 50 and good.validity.h1_fraction > 0.98
    # the same cycles against a nominal beta far from the measured one
    v = check_limit_cycle(good.cycles, good.beta_effective, beta_nominal=+0.3)
    assert v.failed == ("beta_mismatch",)
    v = check_limit_cycle(good.cycles, good.beta_effective, beta_nominal=good.beta_effective + 0.03)
    assert v.ok  # a few hundredths is what sampling and noise do
    # phase not matching the measured switching level: the cycles' phases rotated by 90 deg
    turned = [replace(c, phase_h1=c.phase_h1 - np.pi / 2) for c in good.cycles]
    assert "phase" in check_limit_cycle(turned, good.beta_effective).failed
    # scattered phases
    rng = np.random.default_rng(1)
    scattered = [replace(c, phase_h1=rng.uniform(-2 * np.pi, 0)) for c in good.cycles]
    assert "phase_coherence" in check_limit_cycle(scattered, good.beta_effective).failed
    assert "beta_range" in check_limit_cycle(good.cycles, 1.2).failed


# ------------------------------------------------------------------------------------- wrong outputs


def test_pure_noise_output_is_rejected(roll):
    rng = np.random.default_rng(2)
    flight = _with_output(roll, rng.normal(0, _noise_std(roll), len(roll.output)))
    with pytest.raises(SegmentationError, match="does not follow them") as err:
        analyze_flight(flight, soiptd_model(ROLL["Tp"]), options=AnalyzeOptions(n_bootstrap=50))
    msg = str(err.value)
    assert "2 relay test(s)" in msg and "--loop/--output-topic" in msg and "\n" not in msg
    rej = err.value.rejected_tests
    assert len(rej) == 2
    for r in rej:
        assert r["validity"]["snr"] < 1 and r["validity"]["h1_fraction"] < 0.2
        assert "does not follow" in r["reason"]


def test_the_output_amplitude_of_a_refusal_is_in_the_loops_unit():
    # 'analyze ALTITUDE_LOG --loop x' said the x output's amplitude in mrad: every loop but altitude was
    # taken for an angle
    from mrftcli.analyze.screen import _amp_text

    said = {loop: _amp_text(0.0123, loop) for loop in ("altitude", "x", "y", "roll", "pitch", "process")}
    assert said == {"altitude": "12 mm", "x": "12 mm", "y": "12 mm", "roll": "12 mrad", "pitch": "12 mrad",
                    "process": "0.0123 output units"}


def test_unrelated_sinusoid_at_another_frequency_is_rejected(roll):
    tests = segment(roll)
    f_relay = [t.frequency_hz_mean for t in tests]
    t = roll.output.t
    rng = np.random.default_rng(3)
    f_other = 1.3 * f_relay[0]  # between the two tests' frequencies (f1 / f0 = 1.67), near neither
    y = np.deg2rad(5.0) * np.sin(2 * np.pi * f_other * t + 0.3) + rng.normal(0, _noise_std(roll), t.size)
    with pytest.raises(SegmentationError) as err:
        analyze_flight(_with_output(roll, y), soiptd_model(ROLL["Tp"]), options=AnalyzeOptions(n_bootstrap=50))
    for r in err.value.rejected_tests:
        # within one cycle a sinusoid at 1.3x leaks into the fundamental, but its phase drifts
        assert "phase_coherence" in r["validity"]["failed"]


def test_output_of_a_different_flight_is_rejected(roll):
    """Mixed-up topics: the command of one flight, the output of another plant's flight."""
    other = simulate_paper_flight(0.0422, 1.6026, 0.0289, 25.0, (-0.3, -0.6), loop="roll", seed=9)
    y_other = np.interp(roll.output.t, other.t, other.output_measured)
    with pytest.raises(SegmentationError) as err:
        analyze_flight(_with_output(roll, y_other), soiptd_model(ROLL["Tp"]), options=AnalyzeOptions(n_bootstrap=50))
    assert all(not r["validity"]["ok"] for r in err.value.rejected_tests)


def test_output_shifted_in_time_is_rejected(roll):
    """An output logged with a wrong time offset (a quarter of the first test's period): the phase
    relative to the relay no longer matches the level the relay switched at."""
    P0 = 1.0 / segment(roll)[0].frequency_hz_mean
    t = roll.output.t
    shifted = _with_output(roll, roll.output.values, t + 0.25 * P0)
    with pytest.raises((SegmentationError, InsufficientDataError)):
        analyze_flight(shifted, soiptd_model(ROLL["Tp"]), options=AnalyzeOptions(n_bootstrap=50))
    v = segment(shifted)[0].validity
    assert {"phase", "beta_mismatch"} & set(v.failed)


def test_opposite_loop_signs_between_tests_are_rejected(roll):
    """The output flipped during the second test only: one plant cannot have both signs."""
    tests = segment(roll)
    t = roll.output.t
    y = roll.output.values.copy()
    sp = np.interp(t, roll.setpoint.t, roll.setpoint.values)
    w = (t >= tests[1].t_start - 0.5) & (t <= tests[1].t_end + 0.5)
    y[w] = 2 * sp[w] - y[w]  # mirrored about the setpoint
    flight = _with_output(roll, y)
    seg = segment(flight)
    assert [s.loop_sign for s in seg] == [1, -1] and all(s.validity.ok for s in seg)
    with pytest.raises(SegmentationError, match="opposite signs"):
        analyze_flight(flight, soiptd_model(ROLL["Tp"]), options=AnalyzeOptions(n_bootstrap=50))


def test_one_wrong_test_leaves_a_partial_result(roll):
    """Noise instead of the output during the second test: the first stays, exit 6 with the reason."""
    tests = segment(roll)
    t = roll.output.t
    y = roll.output.values.copy()
    w = (t >= tests[1].t_start - 0.5) & (t <= tests[1].t_end + 0.5)
    y[w] = np.random.default_rng(4).normal(0, _noise_std(roll), w.sum()) + np.median(y[w])
    with pytest.raises(InsufficientDataError, match="rejected") as err:
        analyze_flight(_with_output(roll, y), soiptd_model(ROLL["Tp"]), options=AnalyzeOptions(n_bootstrap=50))
    part = err.value.partial
    assert len(part["tests"]) == 1 and len(part["rejected_tests"]) == 1
    assert "does not follow" in part["rejected_tests"][0]["reason"]


# ------------------------------------------------------------------------------ no false rejection


def test_low_snr_valid_flight_is_accepted_and_identified(roll):
    """Logged output 10x noisier than the flight's (amplitude 10 deg, noise 1 deg: a noisy logging
    path the controller did not switch on): accepted, and the truth inside the reported interval."""
    t = roll.output.t
    y = roll.output.values + np.random.default_rng(6).normal(0, np.deg2rad(1.0), t.size)
    r = analyze_flight(_with_output(roll, y), soiptd_model(ROLL["Tp"]), options=AnalyzeOptions(n_bootstrap=200))
    assert len(r.tests) == 2 and not r.rejected
    for t in r.tests:
        assert t.validity.ok and 6 < t.validity.snr < 15 and t.n_stable >= 8
    assert r.tau.ci95_low <= ROLL["tau"] <= r.tau.ci95_high
    assert abs(r.tau.value - ROLL["tau"]) < 3e-3


@pytest.mark.skipif(not SAMPLES.is_dir(), reason="no sample_logs/")
def test_wrong_loop_on_a_roll_log_exits_4_with_one_line():
    log = SAMPLES / "design2_roll.mcap"
    if not log.exists():
        pytest.skip("sample log missing")
    proc = run_main("analyze", str(log), "--tp", "0.0499", "--loop", "pitch", "--json", "-")  # main() in this process
    assert proc.returncode == 4, proc.stderr
    assert "Traceback" not in proc.stderr
    err = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    assert len(err) == 1
    assert "/mrft/command" in err[0] and "/imu/data pitch does not follow them" in err[0]
    assert "--loop/--output-topic" in err[0]
    d = json.loads(proc.stdout)
    assert d["exit_code"] == 4 and d["tests"] == [] and len(d["rejected_tests"]) == 2
    for r in d["rejected_tests"]:
        assert r["reason"] and {"snr", "h1_fraction", "phase_coherence"} <= set(r["validity"])
    ok = run_main("analyze", str(log), "--tp", "0.0499", "--loop", "roll", "--json", "-")
    assert ok.returncode == 0, ok.stderr
    d = json.loads(ok.stdout)
    assert d["rejected_tests"] == [] and all(t["validity"]["ok"] for t in d["tests"])


def test_rejected_test_is_listed_with_its_reason_and_the_rest_identified():
    """Three tests, the output of the middle one replaced by noise: two remain and identify the plant."""
    from mrftcli.jsonable import to_jsonable
    from mrftcli.cli.analyze import format_analysis

    sf = simulate_paper_flight(ROLL["Tp"], ROLL["Td"], ROLL["tau"], ROLL["K"], (-0.3, -0.5, -0.8), loop="roll",
                               seed=5)
    fl = flight_from_simulated(sf)
    tests = segment(fl)
    t = fl.output.t
    y = fl.output.values.copy()
    w = (t >= tests[1].t_start - 0.5) & (t <= tests[1].t_end + 0.5)
    y[w] = np.random.default_rng(4).normal(0, np.deg2rad(0.2), w.sum()) + np.median(y[w])
    r = analyze_flight(_with_output(fl, y), soiptd_model(ROLL["Tp"]), options=AnalyzeOptions(n_bootstrap=100))
    assert [x.index for x in r.tests] == [0, 2] and [x.index for x in r.rejected] == [1]
    assert abs(r.tau.value - ROLL["tau"]) < 1e-3
    d = json.loads(json.dumps(to_jsonable(r.to_dict(cycles=False)), allow_nan=False))
    rej = d["rejected_tests"][0]
    assert rej["reason"].startswith("the output does not follow this relay")
    assert {"snr", "h1_fraction"} <= set(rej["validity"]["failed"])
    assert all(x["validity"]["ok"] for x in d["tests"])
    table = format_analysis(r)
    assert "left out: the output does not follow this relay" in table
    assert any("left out" in w_ and "0.5" in w_ for w_ in r.warnings)
