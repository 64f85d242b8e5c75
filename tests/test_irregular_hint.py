"""analyze's reason for a test left out with cycles enough but their periods scattered (issue 42): the relay
switched irregularly, and the user is told to raise h rather than to record longer tests."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from mrftcli.analyze.screen import irregular_hint


def _test(periods: list[float], cap: float = 0.15) -> SimpleNamespace:
    return SimpleNamespace(cycles=[SimpleNamespace(period=p) for p in periods],
                           criterion=SimpleNamespace(period_cap_rel=cap))


def test_scattered_periods_name_the_spread_and_the_relay_height() -> None:
    periods = [0.688, 1.064, 0.968, 1.040, 0.832, 0.464, 0.896, 0.944, 1.056, 0.672]  # PX4 SITL altitude, h 0.05
    spread = np.std(periods, ddof=1) / np.mean(periods)  # 0.2268
    hint = irregular_hint(_test(periods), 3)  # type: ignore[arg-type]
    assert f"its 10 cycles' periods spread {spread * 100:.0f} %" in hint and "over the 15 %" in hint
    assert "larger relay height h" in hint


def test_short_or_steady_tests_get_no_hint() -> None:
    assert irregular_hint(_test([0.7, 1.1, 0.5, 1.0, 0.6]), 3) == ""  # type: ignore[arg-type]  # 5 < 2 x 3: a short test
    steady = list(1.0 + 0.05 * np.sin(np.arange(10)))
    spread = np.std(steady, ddof=1) / np.mean(steady)  # 0.035: inside the criterion's 15 %
    assert irregular_hint(_test(steady), 3) == ""  # type: ignore[arg-type]
    hint = irregular_hint(_test(steady, cap=0.02), 3)  # type: ignore[arg-type]
    assert hint.startswith(f"; its 10 cycles' periods spread {spread * 100:.0f} % (over the 2 %")
