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
from mrftcli.diagnose.fit import CandidateModel, _extent, initial_base, model_cycle
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
