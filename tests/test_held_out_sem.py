"""The held-out standard error of a test's mean (``analyze/held_out.mean_sem``) against correlated cycles.

Oracle: an AR(1) sequence x_k = rho x_(k-1) + sqrt(1 - rho^2) e_k (unit variance), whose mean has the
closed-form variance (1 + 2 sum_(k<n) (1 - k/n) rho^k) / n. Over many sequences the root mean square of the
stated standard error must match that closed form; ``std / sqrt(n)`` (cycles taken as independent) is about
half of it at rho 0.55, the lag-1 autocorrelation of ArduPilot SITL's hopping cycles.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mrftcli.analyze.held_out import mean_sem


def _ar1(rho: float, n: int, runs: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    e = rng.standard_normal((runs, n))
    x = np.empty_like(e)
    x[:, 0] = e[:, 0]
    for k in range(1, n):
        x[:, k] = rho * x[:, k - 1] + math.sqrt(1.0 - rho ** 2) * e[:, k]
    return x


def _true_se(rho: float, n: int) -> float:
    k = np.arange(1, n)
    return math.sqrt((1.0 + 2.0 * float(np.sum((1.0 - k / n) * rho ** k))) / n)


@pytest.mark.parametrize("rho", [0.0, 0.3, 0.55])
@pytest.mark.parametrize("n", [12, 30])
def test_the_stated_standard_error_matches_an_ar1_means_scatter(rho: float, n: int) -> None:
    x = _ar1(rho, n, 3000, seed=int(100 * rho) + n)
    stated = np.array([mean_sem(row) for row in x])
    true = _true_se(rho, n)
    # the typical stated error is the true one (before the lag-1 bias correction: 0.70 at 12 cycles, rho 0.55;
    # its root mean square looked right only because a few sequences stated huge errors)
    assert float(np.median(stated)) / true == pytest.approx(1.0, abs=0.15)
    assert 0.9 < math.sqrt(float(np.mean(stated ** 2))) / true < 1.5  # those few: bounded
    # and the closed form is the scatter of the simulated means (the oracle checks itself)
    assert float(np.std(x.mean(axis=1))) / true == pytest.approx(1.0, abs=0.06)
    # mean +- 1.96 se covers the true mean (0) in most runs, never more than 95 % by much (no over-statement); short
    # of 95 % at 12 cycles: r estimated from 12 values is noisy, so the interval has heavier tails
    covered = float(np.mean(np.abs(x.mean(axis=1)) < 1.96 * stated))
    assert (0.83 if n == 12 else 0.88) < covered < 0.97


@pytest.mark.parametrize("rho", [0.0, 0.3, 0.55])
@pytest.mark.parametrize("n, median_min, covered_min", [(5, 0.55, 0.71), (8, 0.74, 0.78)])
def test_short_tests_are_not_made_much_more_certain_than_they_are(rho: float, n: int, median_min: float,
                                                                  covered_min: float) -> None:
    """5 and 8 cycles (--min-cycles is 3; SITL tests have 7-11): the lag-1 autocorrelation estimated from so few
    cycles is biased low by about (1 + 4 r) / n; uncorrected, the stated error at rho 0.55 was 0.51 and 0.60 of the
    true one (median) and covered 68 and 75 %. Against the AR(1) closed form, fresh seeds."""
    x = _ar1(rho, n, 3000, seed=5000 + int(100 * rho) + n)
    stated = np.array([mean_sem(row) for row in x])
    true = _true_se(rho, n)
    assert float(np.std(x.mean(axis=1))) / true == pytest.approx(1.0, abs=0.06)
    assert median_min < float(np.median(stated)) / true < 1.15
    assert covered_min < float(np.mean(np.abs(x.mean(axis=1)) < 1.96 * stated)) < 0.97


def test_independent_cycles_take_std_over_root_n_when_uncorrelated() -> None:
    """An alternating sequence (negative lag-1 autocorrelation) is not made more certain than independent
    cycles: its standard error is std / sqrt(n)."""
    x = np.array([1.0, -1.0] * 10)
    assert mean_sem(x) == pytest.approx(x.std(ddof=1) / math.sqrt(x.size))


def test_cycles_taken_as_independent_understate_a_correlated_mean() -> None:
    """The check can fail: std / sqrt(n), the former rule, is about half the scatter at rho 0.55."""
    x = _ar1(0.55, 30, 3000, seed=7)
    naive = np.array([row.std(ddof=1) / math.sqrt(row.size) for row in x])
    assert math.sqrt(float(np.mean(naive ** 2))) / _true_se(0.55, 30) < 0.6


def test_degenerate_inputs() -> None:
    assert mean_sem(np.array([])) == 0.0
    assert mean_sem(np.array([2.0])) == 0.0
    assert mean_sem(np.array([2.0, 2.0, 2.0])) == 0.0
    assert mean_sem(np.array([1.0, 3.0])) == pytest.approx(1.0)
    # a monotone drift (r near 1) is held at n_eff = 2: finite, and larger than std / sqrt(n)
    x = np.linspace(0.0, 1.0, 10)
    assert x.std(ddof=1) / math.sqrt(10) < mean_sem(x) < math.inf


def test_one_standard_error_of_a_mean_in_every_layer() -> None:
    """eq. (2)'s TestMeasurement and the analysis record's frequency_sem_hz take the same standard error as the
    held-out predictions (mrft/sem.mean_sem), not std / sqrt(n) beside it: on correlated cycles (AR(1), rho 0.55)
    it is larger than std / sqrt(n), and the identified Td, tau and K (from the tests' means) do not move."""
    from pathlib import Path

    from mrftcli.analyze import analyze_flight
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.identify import TestMeasurement
    from mrftcli.mrft.model import soiptd_model
    from mrftcli.mrft.sem import mean_sem as the_one

    assert the_one is mean_sem
    x = 1.0 + 0.01 * _ar1(0.55, 12, 1, seed=4242)[0]
    t = TestMeasurement(-0.4, x, amplitude=0.05 + 0.001 * x, h=1.0)
    assert t.frequency_sem == pytest.approx(mean_sem(x)) and t.amplitude_sem == pytest.approx(mean_sem(0.001 * x))
    assert t.frequency_sem > x.std(ddof=1) / math.sqrt(x.size)
    log = Path(__file__).resolve().parents[1] / "sample_logs" / "design1_altitude.mcap"
    result = analyze_flight(read_flight(log, ReadOptions(), echo_warnings=False), soiptd_model(0.0499))
    rows = result.to_json()["identification"]["tests"]
    assert [r["frequency_sem_hz"] for r in rows] == pytest.approx([mean_sem(s.frequency_hz) for s in result.tests])
