"""Issue 39 (speed): the shortcuts of diagnose's fits against the computations they stand for.

A Jacobian column's cycle is the cycle at the period of the point it steps from, moved by one Newton
step times the features' derivative in the period (:meth:`CandidateModel._column`); the oracle is the
same column with each cycle solved to convergence by a fresh model. A model cycle's features
(:func:`~mrftcli.diagnose.features.cycle_features`) are those of the one-row table summarised.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mrftcli.diagnose.features import cycle_features, summarize_features
from mrftcli.diagnose.candidate_model import CandidateModel, _extent, model_cycle
from mrftcli.diagnose.starts import initial_base
from mrftcli.diagnose.periodic import CyclePlant, periodic_solution
from mrftcli.diagnose.screen import screen_log
from mrftcli.io import ReadOptions, read_flight
from mrftcli.mrft.model import soiptd_model

ROOT = Path(__file__).resolve().parents[1]


def test_a_model_cycles_features_are_its_one_row_tables_summary() -> None:
    rng = np.random.default_rng(39)
    n = 0
    for _ in range(200):
        pl = CyclePlant(Tp=rng.uniform(0.005, 0.1), Td=rng.uniform(0.3, 5.0), tau=rng.uniform(0.0, 0.1),
                        level_high=rng.uniform(0.05, 0.2), level_low=-rng.uniform(0.05, 0.2),
                        rate_limit=float(rng.choice([0.0, rng.uniform(2.0, 20.0)])),
                        sensor_lag=float(rng.choice([0.0, rng.uniform(0.01, 0.1)])))
        sol = periodic_solution(pl, -0.4, -0.3, 1.0)
        if sol is None:
            continue
        n += 1
        amplitude, centre = _extent(sol)
        fast = cycle_features(sol.period, sol.high / sol.period - 0.5, amplitude, centre, sol.Y)
        np.testing.assert_array_equal(fast, summarize_features(model_cycle(sol, 0.1)).values)
    assert n > 100


def test_a_jacobian_column_matches_the_column_of_converged_cycles() -> None:
    path = ROOT / "sample_logs" / "concealed" / "flight_05.mcap"  # an actuator rate limit: asymmetric levels
    Tp = json.loads(Path(str(path) + ".truth.json").read_text())["Tp"]
    screen = screen_log(read_flight(path, ReadOptions(loop="altitude")), soiptd_model(Tp), None,
                        lambda *a, **k: None)
    theta = initial_base(screen.tests, Tp)
    model = CandidateModel(None, screen.tests, Tp)
    for i, test in enumerate(screen.tests):
        t_ref = float(test.tab.t_mid.mean())
        base = model.evaluate(theta, i, t_ref)
        assert base is not None
        for j in range(theta.size):
            step = np.zeros(theta.size)
            step[j] = 1e-3 * max(abs(theta[j]), 1.0)
            column = model.evaluate(theta + step, i, t_ref, newton=True)
            solved = CandidateModel(None, screen.tests, Tp).evaluate(theta + step, i, t_ref)
            assert column is not None and solved is not None
            d_col = (column.features - base.features) / step[j]
            d_ref = (solved.features - base.features) / step[j]
            # the column's error is of the order of the step squared, so 1e-3 of the column's largest
            # entry (without the period's derivative term it would be of the order of the column)
            assert np.max(np.abs(d_col - d_ref)) < 1e-3 * np.max(np.abs(d_ref))
        # the column's cycle is a point's; the point it stepped from is still the next start
        assert model.warm[i][0].tobytes() == np.asarray(theta, float).tobytes()


def test_a_point_solved_twice_is_one_cycle() -> None:
    path = ROOT / "sample_logs" / "concealed" / "flight_01.mcap"
    Tp = json.loads(Path(str(path) + ".truth.json").read_text())["Tp"]
    screen = screen_log(read_flight(path, ReadOptions(loop="altitude")), soiptd_model(Tp), None,
                        lambda *a, **k: None)
    theta = initial_base(screen.tests, Tp)
    model = CandidateModel(None, screen.tests, Tp)
    first = model.evaluate(theta, 0, 1.0)
    # another reference time and key: the linear model's cycle does not depend on them
    again = model.evaluate(theta, 0, 7.0, key=1000)
    fresh = CandidateModel(None, screen.tests, Tp).evaluate(theta, 0, 7.0)
    assert first is again and first is not None and fresh is not None
    np.testing.assert_allclose(first.features, fresh.features, rtol=1e-7, atol=1e-10)


def test_the_swap_never_pairs_an_effect_with_itself() -> None:
    """The swap step pairs the second effect (alone) with each other significant effect; once a pair
    replaces the second, the loop must still skip the anchor itself (it once fitted, and printed,
    'actuator_rate_limit with actuator_rate_limit')."""
    from types import SimpleNamespace

    from mrftcli.diagnose.pairs import _Pairs
    from mrftcli.diagnose.rows import CandidateFit, PairFit

    rows = [CandidateFit(name=n, bic=b, significant=True) for n, b in
            (("input_bias", 100.0), ("gain_drift", 110.0), ("actuator_rate_limit", 120.0))]
    first = rows[0]
    second = PairFit(name="actuator_rate_limit", with_="input_bias", bic=90.0, delta_bic=10.0, significant=True)
    asked: list[tuple[str, str]] = []

    def pair(anchor: CandidateFit, other: str) -> PairFit:
        asked.append((anchor.name, other))
        return PairFit(name=other, with_=anchor.name, bic=80.0 - len(asked), delta_bic=30.0, significant=True)

    _Pairs.swap(SimpleNamespace(pair=pair), first, second, rows, rows)  # type: ignore[arg-type]
    assert asked and all(anchor != other for anchor, other in asked)


def _phase_test(W: float, beta: float, rate_hz: float = 200.0):
    """A stand-in for a diagnosed test: its cycles' period at W [rad/s], its beta and rate (what the
    phase condition reads)."""
    from types import SimpleNamespace

    period = np.full(6, 2.0 * np.pi / W)
    return SimpleNamespace(tab=SimpleNamespace(period=period), fit=np.ones(6, bool), beta=(beta, beta), rate_hz=rate_hz)


def _frequency(Tp: float, Td: float, tau: float, beta: float, rate_hz: float) -> float:
    """The describing-function frequency [rad/s] of eq. (2) under an MRFT of ``beta`` (bisection on the
    phase: -pi/2 - atan(W Tp) - atan(W Td) - W (tau + 1 / (2 f_s)) = -pi + asin(beta))."""
    lo, hi = 1e-3, 1e3
    for _ in range(200):
        w = 0.5 * (lo + hi)
        ph = -np.pi / 2 - np.arctan(w * Tp) - np.arctan(w * Td) - w * (tau + 0.5 / rate_hz)
        lo, hi = (w, hi) if ph > -np.pi + np.arcsin(beta) else (lo, w)
    return 0.5 * (lo + hi)


def test_the_phase_condition_start_recovers_the_plant_of_two_betas() -> None:
    """Issue 39: the phase-condition start (tau in closed form at each Td, Td on a refined grid) is the
    plant whose describing-function frequencies the tests have."""
    Tp = 0.04
    for Td, tau in ((0.5, 0.03), (3.0, 0.05), (12.0, 0.02)):
        tests = [_phase_test(_frequency(Tp, Td, tau, b, 200.0), b) for b in (-0.2, -0.7)]
        theta = initial_base(tests, Tp)  # type: ignore[arg-type]
        assert abs(np.exp(theta[0]) / Td - 1.0) < 1e-4 and abs(theta[1] / 10.0 - tau) < 1e-6


def test_one_frequency_leaves_the_valley_flat_and_the_start_meets_it() -> None:
    """Issue 39: tests at one frequency cannot separate Td from tau: the start meets the phase
    condition exactly at the valley's point nearest Td = 1 s (it once wandered the valley to a bound
    for 40-120 ms a start)."""
    Tp, W, beta = 0.04, 5.0, -0.4
    theta = initial_base([_phase_test(W, beta)], Tp)  # type: ignore[arg-type]
    Td, tau = float(np.exp(theta[0])), theta[1] / 10.0
    assert 0.8 < Td < 1.25
    ph = -np.pi / 2 - np.arctan(W * Tp) - np.arctan(W * Td) - W * (tau + 0.5 / 200.0)
    assert abs(ph - (-np.pi + np.arcsin(beta))) < 1e-9


def test_a_td_on_the_fits_bound_is_named_not_determined() -> None:
    from mrftcli.diagnose.starts import TD_RANGE_S, bound_reason

    assert bound_reason(TD_RANGE_S[1] * (1 - 1e-7)) is not None and "upper bound (100 s)" in str(bound_reason(99.99))
    assert bound_reason(TD_RANGE_S[0]) is not None
    assert bound_reason(5.0) is None and bound_reason(None) is None
