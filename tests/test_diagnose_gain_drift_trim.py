"""Gain drift under a relay re-centred by a hold (issue 39): the trim error each test sees.

Oracle: the closed form of the plant input. With the battery (or a tank) scaling the whole command,
the plant sees g(t) (b + u) - b0, b0 the hover command at the log's start (g = 1) and b the test's
relay centre. A hold that hands over to the relay re-centres it on the trim of that moment,
b = b0 / g(t_start), so the test starts on trim and drifts off within it; a relay on one fixed centre
(b = b0 for every test, our simulator's) keeps the old reading, (g - 1) b / g.
"""

from __future__ import annotations

import numpy as np
import pytest

from mrftcli.diagnose.prepared import DiagnosedTest
from mrftcli.diagnose.candidate_model import CandidateModel
from mrftcli.diagnose.physics import BY_NAME

G = -0.002  # 1/s
B0 = 0.5


def _test(index: int, t_start: float, bias: float) -> DiagnosedTest:
    return DiagnosedTest(index=index, h=0.1, bias=bias, rate_hz=200.0, beta_nominal=-0.4, beta=(-0.4, -0.4),
                         t_start=t_start, t_end=t_start + 12.0, tab=None, fit=np.zeros(0, bool),  # type: ignore[arg-type]
                         hold=np.zeros(0, bool), has_setpoint=True, t0_log=0.0)


def _seen(model: CandidateModel, test: DiagnosedTest, t: float) -> tuple[float, float]:
    """The plant's gain and input offset [command units] at log time t."""
    plant, g = model.plant({"extras": {"gain_drift": G}, "Td": 2.0, "tau": 0.03}, test, t)
    return g, plant.input_bias


@pytest.mark.parametrize("t", [30.0, 36.0, 42.0])
def test_a_test_a_hold_recentred_starts_on_trim_and_drifts_off_within_it(t):
    first = _test(0, 2.0, B0 / (1.0 + G * 2.0))
    later = _test(1, 30.0, B0 / (1.0 + G * 30.0))  # the hold's trim when it handed over at 30 s
    model = CandidateModel((BY_NAME["gain_drift"],), [first, later], 0.05)
    g, d = _seen(model, later, t)
    assert g == pytest.approx(1.0 + G * t)
    # g (b + u) - b0' = g (u + d): b0' the first test's centre taken as the flight's hover command
    assert d == pytest.approx((g * later.bias - first.bias) / g, rel=1e-12)
    assert d == pytest.approx(B0 / (1 + G * 30.0) - B0 / ((1 + G * 2.0) * (1 + G * t)), abs=1e-12)
    if t == 30.0:
        # on trim at its start, but for the drift before the first test (its 2 s: 0.4 % of b0); the old
        # reading, (g - 1) b / g, put it 12 % of b0 off
        assert abs(d) < 0.03 * later.h < 0.1 * abs((g - 1.0) * later.bias / g)


def test_a_relay_on_one_fixed_centre_keeps_the_trim_of_the_log_start():
    tests = [_test(0, 2.0, B0), _test(1, 30.0, B0)]
    model = CandidateModel((BY_NAME["gain_drift"],), tests, 0.05)
    for test in tests:
        for t in (test.t_start, test.t_end):
            g, d = _seen(model, test, t)
            assert d == pytest.approx((g - 1.0) * B0 / g, rel=1e-12)
