"""A family's held-out cycle on a clean FOPDT under MRFT matches the recorded one (issue 36/39).

The oracle is tests/process_sim.py (an exact zero-order-hold loop sharing no code with mrftcli). An
effective MRFT's beta is read over the smooth (eight-harmonic) amplitude, which rounds a FOPDT's
kinked peak off; predicted under that beta against the model's true extremum, the held-out cycle was
1.2 % fast on both tests (beta -0.2 read as -0.220 at 500 Hz). Read alike on the model's smooth
amplitude (:func:`mrftcli.analyze.smooth_cycle.predicted_cycle`) it is within 0.5 % (asserted: 0.8 %, half way
between, so the check fails on the bias and not on the last digits of one model fitted from one other test).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from process_sim import Window, simulate  # noqa: E402

from mrftcli.analyze.general import general_analysis, measure_tests  # noqa: E402
from mrftcli.io.logtypes import FlightLog, Signal  # noqa: E402
from mrftcli.mrft.families import family_model  # noqa: E402


def test_clean_fopdt_held_out_frequency_free_of_the_smooth_peak_bias():
    windows = [Window("mrft", 1.0, -1.0, beta=b, duration=12.0, rest=3.0) for b in (-0.2, -0.45)]
    t, u, y = simulate("fopdt", dict(K=2.0, T=1.0, tau=0.3), windows, 500.0, 0.0, seed=2, start=0.02)
    flight = FlightLog(path="fopdt.sim", loop="altitude", command=Signal(t, u), output=Signal(t, y))
    result = general_analysis(flight, family_model("fopdt"), measure_tests(flight))
    assert len(result.tests) == 2
    for test in result.tests:
        assert test.effective_relay is not None and test.held_out.frequency_hz is not None
        # before: +1.15 % and +1.23 %; now +0.47 % and -0.18 %
        assert abs(test.held_out.frequency_hz / test.frequency_hz - 1) < 0.008, test.held_out
