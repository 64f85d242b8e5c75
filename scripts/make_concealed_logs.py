#!/usr/bin/env python
"""Generate ``sample_logs/concealed/``: simulated MRFT flights with one concealed effect each.

Every log is an altitude flight in the reference layout (MCAP, ROS 2 CDR) with three MRFT tests:
beta -0.4 and -0.7 at the same amplitude, and beta -0.4 again with 1.6 times the relay height (the
h-invariance check). One log per candidate effect at a realistic magnitude plus clean controls. The
file names say nothing about the effect; the ground truth is in ``<log>.truth.json`` (the tool never
reads it; the tests and the benchmark compare with it). The ``/battery`` topic is left out, so the
battery voltage does not give the gain drift away.

Usage::

    python scripts/make_concealed_logs.py [--out sample_logs/concealed]

The same case generator (:func:`make_case`) is used by ``benchmarks/bench_diagnose.py`` with random
magnitudes and fresh seeds.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from mrftcli.mrft.model import LoopModel
from mrftcli.plan import switch_gap
from mrftcli.sim.flight import (Effects, FlightSpec, TestSpec, df_prediction, noise_margin, plan_test, simulate_flight,
                                write_flight)

#: The paper's two platforms' altitude loops (checks.md section 4); K gives about 5-8 cm at h ~ 0.1.
PLANTS = {
    "design1": LoopModel(Tp=0.0422, Td=2.669, tau=0.0464, K=15.0),
    "design2": LoopModel(Tp=0.0499, Td=1.8345, tau=0.0498, K=12.0),
}
EFFECTS = ("input_bias", "gain_drift", "sensor_lag", "quadratic_drag", "actuator_rate_limit", "delay_jitter",
           "asymmetric_gain", "actuator_saturation", "dead_zone", "thrust_rectification")
#: physics outside the diagnosis' library (it should report them as ``unexplained``)
OUT_OF_LIBRARY = ("flex_mode_hz",)
AMPLITUDE = 0.06  # planned output amplitude of the first test [m]
#: Admissibility lines a pilot's test must clear (measured in mrftcli.plan, docs/benchmarks/plan.md):
#: noise margin a Omega / (rate noise) >= 4 (no simulated test locked up) and switch gap
#: (1 + beta) a / noise >= 16 (analyze used every such test).
MIN_NOISE_MARGIN = 4.0
MIN_SWITCH_GAP = 16.0
#: Largest relay height [throttle] a pilot would fly around the 0.5 hover trim, and largest amplitude [m].
MAX_H = 0.45
MAX_AMPLITUDE = 0.12


def flight_tests(model: LoopModel, cycles: float = 16.0, amplitude: float = AMPLITUDE) -> tuple[TestSpec, ...]:
    """beta -0.4 and -0.7 at one amplitude [m], then beta -0.4 at 1.6 times the relay height."""
    t1 = plan_test(model, -0.4, amplitude, cycles=cycles)
    t2 = plan_test(model, -0.7, amplitude, cycles=cycles)
    t3 = TestSpec(-0.4, 1.6 * t1.h, t1.duration)
    return (t1, t2, t3)


def admissible_setting(model: LoopModel, rate_hz: float, noise_std: float, cycles: float = 16.0) -> tuple[float, float]:
    """The amplitude [m] and noise std [m] a pilot would fly at ``rate_hz`` with ``noise_std`` of sensor noise.

    Every test of :func:`flight_tests` must clear the noise margin and the switch gap. The margins
    grow in proportion to the amplitude, so the amplitude is first raised from :data:`AMPLITUDE`
    (up to :data:`MAX_AMPLITUDE` and a largest relay height of :data:`MAX_H`); where that is not
    enough the noise is lowered (a pilot would filter the estimate or fly at a lower rate) until
    every test is admissible.
    """
    tests = flight_tests(model, cycles)  # as make_case plans them; h scales with the amplitude
    need = 0.0
    for t in tests:
        _, a = df_prediction(model, t.beta, t.h, rate_hz)
        need = max(need, MIN_NOISE_MARGIN / noise_margin(model, t.beta, t.h, rate_hz, noise_std),
                   MIN_SWITCH_GAP / switch_gap(a, t.beta, noise_std))
    need = max(1.0, 1.05 * need)  # the lines are measured edges: keep a little room
    room = min(MAX_AMPLITUDE / AMPLITUDE, MAX_H / max(t.h for t in tests))
    scale = min(need, room)
    return AMPLITUDE * scale, noise_std * min(1.0, scale / need)


def reflown_setting(model: LoopModel, amplitude: float, noise_std: float, cycles: float = 16.0) -> tuple[float, float]:
    """The amplitude [m] and noise std [m] a pilot flies again with after a test's relay locked up.

    The effect the flight carries (which :func:`admissible_setting` does not know) ate the margin:
    the margins are raised by 1.3, through the amplitude while the relay height and amplitude limits
    allow, else through the noise (as :func:`admissible_setting` does).
    """
    room = AMPLITUDE * min(MAX_AMPLITUDE / AMPLITUDE, MAX_H / max(t.h for t in flight_tests(model, cycles)))
    new_amp = min(1.3 * amplitude, room)
    return new_amp, noise_std * new_amp / (1.3 * amplitude)


def effect_value(effect: str, model: LoopModel, tests: tuple[TestSpec, ...], scale: float = 1.0) -> float:
    """A realistic magnitude of ``effect`` for this flight (``scale`` ~ 1 varies it)."""
    h = tests[0].h
    if effect == "input_bias":
        return 0.18 * h * scale  # a trim error of ~1-2 % throttle
    if effect == "gain_drift":
        return -0.001 * scale  # -6 %/min: a hard-working battery
    if effect == "sensor_lag":
        return 0.07 * scale  # a ~2.3 Hz estimator/filter
    if effect == "quadratic_drag":
        # the same damping as the linear model at the first test's speed (describing function)
        omega, a = df_prediction(model, tests[0].beta, h)
        return 3.0 * math.pi / (8.0 * model.Td * a * omega) * scale
    if effect == "actuator_rate_limit":
        return 2.0 * h / (0.045 * scale)  # the relay step takes ~45 ms
    if effect == "delay_jitter":
        return 0.012 * scale  # a non-real-time link (e.g. mocap over Wi-Fi)
    h_max = max(t.h for t in tests)
    if effect == "asymmetric_gain":
        return 0.15 * scale  # +-15 % gain above/below the trim
    if effect == "actuator_saturation":
        return 0.5 + 0.7 * scale * h_max  # trim 0.5 (the simulator's altitude default) + a limit inside the largest step
    if effect == "dead_zone":
        return 0.2 * h * scale  # a dead band of a fifth of the smallest relay height
    if effect == "thrust_rectification":
        return h_max / (0.4 * scale)  # the largest swing is ~0.4 of the hover thrust
    if effect == "flex_mode_hz":
        omega, _ = df_prediction(model, tests[0].beta, h)
        return 4.5 * scale * omega / (2.0 * math.pi)  # a frame mode at ~4.5 times the test frequency
    raise ValueError(effect)


def make_case(effect: str | None, plant: str, seed: int, scale: float | tuple = 1.0, *, cycles: float = 16.0,
              rate_hz: float = 200.0, noise_std: float | None = None, amplitude: float = AMPLITUDE):
    """Simulate one flight; ``effect`` None is a clean control, ``"a+b"`` combines two effects (``scale``
    then one factor per effect, or one for both). ``amplitude`` is the first test's planned amplitude
    [m] (see :func:`admissible_setting`). Returns the SimulatedFlight."""
    model = PLANTS[plant]
    tests = flight_tests(model, cycles, amplitude)
    effects = Effects()
    names = [] if effect is None else effect.split("+")
    scales = scale if isinstance(scale, tuple) else (scale,) * len(names)
    for name, sc in zip(names, scales):
        effects = replace(effects, **{name: effect_value(name, model, tests, sc)})
    spec = FlightSpec(model=model, tests=tests, loop="altitude", rate_hz=rate_hz, effects=effects, seed=seed,
                      hover_s=2.0, hold_s=2.0, noise_std=noise_std)
    flight = simulate_flight(spec)
    flight.topics = [t for t in flight.topics if t.name != "/battery"]  # conceal the battery voltage
    return flight


#: the committed set: (effect or None, plant, seed); file names are neutral
CASES = (
    ("input_bias", "design1", 101),
    ("gain_drift", "design2", 102),
    ("sensor_lag", "design1", 103),
    ("quadratic_drag", "design2", 104),
    ("actuator_rate_limit", "design1", 105),
    ("delay_jitter", "design2", 106),
    (None, "design1", 107),
    (None, "design2", 108),
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "sample_logs" / "concealed"))
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # neutral, shuffled names so the order does not give the effect away either
    order = np.random.default_rng(2024).permutation(len(CASES))
    for k, i in enumerate(order):
        effect, plant, seed = CASES[i]
        flight = make_case(effect, plant, seed)
        path = out / f"flight_{k + 1:02d}.mcap"
        side = write_flight(flight, path, "mcap")
        truth = json.loads(side.read_text())
        truth["concealed_effect"] = effect
        truth["plant"] = plant
        side.write_text(json.dumps(truth, indent=2) + "\n")
        print(f"{path.name}: {path.stat().st_size / 1e3:.0f} kB")


if __name__ == "__main__":
    main()
