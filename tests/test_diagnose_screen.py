"""The screen stage's warning when a left-out test takes away the one comparison a dead zone shows in."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from mrftcli.diagnose.screen import lost_height_pair
from mrftcli.sim.plant import command_shaper


def _test(index: int, beta: float, h: float) -> SimpleNamespace:
    """The fields of an MrftTest the check reads."""
    return SimpleNamespace(index=index, beta=beta, beta_nominal=beta, beta_effective=beta, h=h)


def test_a_dead_zone_is_a_gain_of_one_less_delta_over_h_on_a_relay():
    # the premise of the warning, from the simulator's own command nonlinearity: the relay's two levels
    # come out scaled by 1 - delta / h, so one test sees a gain and only two heights tell it from K
    bias, delta = 0.5, 0.012
    shape = command_shaper(bias, dead_zone=delta)
    for h in (0.06, 0.12):
        levels = np.array([shape(bias + h) - bias, shape(bias - h) - bias])
        np.testing.assert_allclose(levels, np.array([h, -h]) * (1.0 - delta / h), rtol=1e-12)


def test_warns_when_the_only_pair_of_relay_heights_is_broken():
    flown = [_test(0, -0.4, 0.08), _test(1, -0.7, 0.24), _test(2, -0.4, 0.16)]
    msg = lost_height_pair(flown, {1, 2})
    assert msg is not None and "test 1 (beta -0.40, h 0.08)" in msg and "dead zone" in msg
    assert "\n" not in msg


def test_silent_when_a_pair_is_kept_or_none_was_flown():
    flown = [_test(0, -0.4, 0.08), _test(1, -0.7, 0.24), _test(2, -0.4, 0.16)]
    assert lost_height_pair(flown, {0, 1, 2}) is None
    assert lost_height_pair(flown, {0, 2}) is None  # the -0.7 test lost: the pair at -0.4 is still there
    same_height = [_test(0, -0.4, 0.08), _test(1, -0.7, 0.24), _test(2, -0.4, 0.084)]
    assert lost_height_pair(same_height, {1, 2}) is None  # 5 % apart: not two heights
