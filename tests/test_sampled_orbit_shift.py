"""The sampled relay's orbits with the delay's whole ticks as a shift of the orbit (``fraction_discrete`` +
``orbits(shift=d)``) equal those of the plant carrying a d-long command buffer in its state (``delayed_discrete``,
the exact discretisation they replace in ``sampled_limit_cycle``): 200x faster at 10 kHz, same orbits.

Oracle: the buffered realisation, solved as one big linear system per half period (no shift), on plants whose
delay spans 0 to 60 ticks (eq. (2)'s integrator keeps a relay's half period longer than the delay). tests/test_lprs_simulation.py checks both against an
independent simulation."""

from __future__ import annotations

import numpy as np
import pytest

from mrftcli.mrft.cascade import delayed_discrete, fraction_discrete, orbits
from mrftcli.mrft.lprs import mrft_limit_cycle
from mrftcli.mrft.model import LoopModel


@pytest.mark.parametrize(("model", "rate_hz", "beta"), [
    (LoopModel(0.1, 0.7042, 0.06, 1 / 0.7042), 1000.0, -0.7),  # checks.md's example, 60 ticks of delay
    (LoopModel(0.0422, 1.301, 0.0297, 30.0), 400.0, 0.2),
    (LoopModel(0.02, 0.05, 0.2, 3.0), 200.0, -0.3),  # delay-dominated: 40 ticks of an 87-tick half period
    (LoopModel(0.05, 0.6, 0.0013, 27.4), 500.0, -0.5),  # under one tick: no shift
])
def test_shifted_orbits_equal_the_buffered_ones(model, rate_hz, beta):
    ss = model.realisation()
    cyc = mrft_limit_cycle(model, beta, 1.0, rate_hz=rate_hz)
    n_mid = int(round(rate_hz / (2 * cyc.frequency_hz)))
    lo, hi = max(2, n_mid - 8), n_mid + 8
    buffered = orbits(delayed_discrete(ss, model.delay, rate_hz), beta, 1.0, lo, hi)
    small, d = fraction_discrete(ss, model.delay, rate_hz)
    assert d == int(np.floor(model.delay * rate_hz + 1e-12)) and small.order == ss.order + 1
    shifted = orbits(small, beta, 1.0, lo, hi, shift=d)
    np.testing.assert_array_equal(shifted.valid, buffered.valid)
    assert shifted.valid.any()
    np.testing.assert_allclose(shifted.amplitude, buffered.amplitude, rtol=1e-9)
    for i, N in enumerate(buffered.N):  # every sample the rule looks at, y_0 .. y_N
        np.testing.assert_allclose(shifted.samples[i, :N + 1], buffered.samples[i, :N + 1], rtol=1e-8,
                                   atol=1e-12 * buffered.amplitude[i])
    ok = np.isfinite(buffered.at_end)
    np.testing.assert_allclose(shifted.at_end[ok], buffered.at_end[ok], rtol=1e-7, atol=1e-12)
    if model.delay * rate_hz >= 1:
        assert d >= 1  # the shift path was taken
