#!/usr/bin/env python
"""Simulator speed: a 60 s and a 10-minute flight, each effect, against a naive baseline; and the
hand-written matrix exponential against scipy.linalg.expm.

    python benchmarks/bench_simulate.py

Baseline (measured in the same run): the obvious implementation of the same closed loop, a
fixed-step Euler integration at T/20 with the delay rounded to that step, in plain Python. Prints
CPU times (process time, best of 3 where marked) and the ratio; figures are recorded in
docs/benchmarks/simulate.md.

The last rows time :func:`mrftcli.mrft.propagate.taylor_expm` and :func:`scipy.linalg.expm` on the
augmented matrices a flight exponentiates (one control period, its delay sub-intervals, multiples
of the T/64 grid), count how many a flight needs, and print how far apart the two results are.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.linalg

from mrftcli.mrft.model import LoopModel
from mrftcli.mrft import propagate
from mrftcli.sim.flight import Effects, FlightSpec, TestSpec, simulate_flight

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from relay_rule import relay_step  # noqa: E402 - the checks.md rule, independent of mrftcli.sim

MODEL = LoopModel(0.0422, 2.669, 0.0464, 19.62)


def flight_60s() -> FlightSpec:
    tests = (TestSpec(-0.4, 0.06, 24.0), TestSpec(-0.7, 0.18, 20.0))
    return FlightSpec(MODEL, tests, noise_std=0.0002, hover_s=5.0, hold_s=3.0, seed=1)


def flight_10min() -> FlightSpec:
    tests = tuple(TestSpec(b, 0.06 if b == -0.4 else 0.18, 55.0) for b in (-0.4, -0.7) * 5)
    return FlightSpec(MODEL, tests, noise_std=0.0002, hover_s=5.0, hold_s=4.5, seed=1)


def naive(spec: FlightSpec) -> np.ndarray:
    """Same loop (checks rule, no hold PID details beyond P-D), Euler at T/20, delay rounded."""
    m = spec.model
    T = 1.0 / spec.rate_hz
    sub = 20
    dt = T / sub
    lag = int(round(m.tau / dt))
    n = int(round((spec.hover_s + sum(t.duration + spec.hold_s for t in spec.tests)) * spec.rate_hz))
    rng = np.random.default_rng(0)
    noise = rng.normal(0, spec.noise_std, n)
    y, v, p = 1.0, 0.0, 0.0
    buf = [0.0] * (lag + 1)
    out = np.empty(n)
    relay, ext = 1.0, 0.0
    for k in range(n):
        e = 1.0 - (y + noise[k])
        relay, ext = relay_step(relay, ext, e, -0.5)
        u = 0.05 * relay
        for _ in range(sub):
            buf.append(u)
            w = buf.pop(0)
            y, v, p = y + dt * v, v + dt * (-v / m.Td + m.K * p), p + dt * (w - p) / m.Tp
        out[k] = y
    return out


def timed(fn, *args, repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()  # CPU time: less sensitive than wall time to a shared machine
        fn(*args)
        best = min(best, time.process_time() - t0)
    return best


def main() -> None:
    spec = flight_60s()
    duration = spec.hover_s + sum(t.duration + spec.hold_s for t in spec.tests)
    t_fast = timed(simulate_flight, spec)
    t_naive = timed(naive, spec, repeat=1)
    print(f"{duration:.0f} s flight at 200 Hz, linear, exact:   {t_fast:7.3f} s")
    print(f"same loop, naive Euler at T/20 (baseline):      {t_naive:7.3f} s  -> ratio {t_naive / t_fast:.1f}x")
    long = flight_10min()
    long_s = long.hover_s + sum(t.duration + long.hold_s for t in long.tests)
    print(f"{long_s / 60:.0f}-minute flight, linear:                  {timed(simulate_flight, long, repeat=1):7.3f} s")
    for eff in (
        Effects(input_bias=0.01),
        Effects(gain_drift=-0.002),
        Effects(sensor_lag=0.01),
        Effects(actuator_rate_limit=1.0),
        Effects(delay_jitter=0.003),
        Effects(quadratic_drag=1.0),
    ):
        name = ",".join(eff.active())
        print(f"{duration:.0f} s flight with {name:22s}          {timed(simulate_flight, replace(spec, effects=eff), repeat=2):7.3f} s")
    expm_rows(spec)


def expm_rows(spec: FlightSpec) -> None:
    """taylor_expm against scipy.linalg.expm on the very matrices ``spec``'s flights exponentiate."""
    original = propagate.taylor_expm
    seen: list[np.ndarray] = []

    def recording(M: np.ndarray) -> np.ndarray:
        seen.append(M.copy())
        return original(M)

    counts = []
    for eff in (Effects(), Effects(delay_jitter=0.003), Effects(actuator_rate_limit=1.0)):
        before = len(seen)
        propagate.taylor_expm = recording
        try:
            simulate_flight(replace(spec, effects=eff))
        finally:
            propagate.taylor_expm = original
        counts.append(len(seen) - before)
    diff = max(float(np.abs(original(M) - scipy.linalg.expm(M)).max()) for M in seen)
    same = all(np.array_equal(original(M), scipy.linalg.expm(M)) for M in seen)
    reps = max(1, 3000 // len(seen))

    def run(fn) -> None:
        for _ in range(reps):
            for M in seen:
                fn(M)

    t_taylor = timed(run, original) / (reps * len(seen))
    t_scipy = timed(run, scipy.linalg.expm) / (reps * len(seen))
    print(f"matrix exponential, hand-written Taylor:        {t_taylor * 1e6:7.1f} us per call")
    print(f"matrix exponential, scipy.linalg.expm:          {t_scipy * 1e6:7.1f} us per call  -> ratio "
          f"{t_scipy / t_taylor:.1f}x")
    print(f"calls per flight (linear / jitter / rate limit): {' / '.join(map(str, counts))}")
    print(f"max |taylor - scipy| on those matrices:          {diff:.1e} (bit-identical: {same})")


if __name__ == "__main__":
    main()
