"""The sampled relay's written-out whole-tick step (mrftcli.diagnose.limit_cycles._run_sampled) is
``_Propagator.step`` to the bit: R3 finding 1 kept the copy for its CPU, this pins it to the original."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import mrftcli.diagnose.limit_cycles as lc
from mrftcli.diagnose.limit_cycles import AugmentedPlant, SampledRelay, periodic_cycle, run_relay

BASE = AugmentedPlant(0.05, 0.562, 0.0287, 9.763)


def _run(monkeypatch, inline: bool, plant: AugmentedPlant, rate: float, relay: SampledRelay):
    calls = []
    tick = lc._tick

    def counted(*args):
        calls.append(1)
        return tick(*args)

    monkeypatch.setattr(lc, "_INLINE_TICK", inline)
    monkeypatch.setattr(lc, "_tick", counted)
    warm = periodic_cycle(plant, -0.4, 0.3, rate, tol=1e-5).state_at_up[-1]
    run = run_relay(plant, -0.4, 0.3, rate, 8, warm=warm, sampled=relay, max_time=20.0)
    return run, len(calls)


@pytest.mark.parametrize("plant, rate, relay", [
    (BASE, 100.0, SampledRelay(noise_std=5e-4, jitter_std=2e-3, seed=3)),  # 3 states, jittered commands
    (replace(BASE, sensor_lag=0.02, input_bias=0.01), 250.0, SampledRelay(noise_std=5e-4, seed=4)),  # 4 states
    (replace(BASE, rate_limit=20.0), 200.0, SampledRelay(noise_std=2e-4, seed=5)),  # the actuator slews
], ids=["3-state", "lag-bias", "rate-limit"])
def test_written_out_tick_is_the_propagator_step_bit_for_bit(monkeypatch, plant, rate, relay):
    inline, n_inline = _run(monkeypatch, True, plant, rate, relay)
    every, n_every = _run(monkeypatch, False, plant, rate, relay)
    assert len(every.y) > 500 and len(every.up) >= 8  # a real run of the relay
    assert n_every - n_inline > 200  # ticks that took the written-out step
    for a, b in ((inline.t, every.t), (inline.y, every.y), (inline.up, every.up), (inline.down, every.down)):
        assert a.tobytes() == b.tobytes()
    assert all(np.array_equal(np.asarray(inline.state_at_up[i]), np.asarray(every.state_at_up[i]))
               for i in range(len(every.state_at_up)))
