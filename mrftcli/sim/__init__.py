"""Closed-loop MRFT flights of the paper's model with known truth (the tests' and benchmarks' oracle).

``spec`` says what to fly (:class:`FlightSpec`, :class:`TestSpec`, :class:`Effects`, the loop
defaults, validation and schedule); ``flight`` flies it (:func:`simulate_flight`, in stages, and
:func:`plan_test`); ``sidecar`` writes what it leaves (the truth sidecar and the topics,
:func:`write_flight`); ``control`` and ``plant`` re-export the relay, hold PID and propagators.
"""

from .flight import (EFFECT_NAMES, Effects, FlightSpec, SimulatedFlight, TestSpec, default_noise_std, noise_margin,
                     plan_test, sidecar_path, simulate_flight, write_flight)

__all__ = ["Effects", "TestSpec", "FlightSpec", "SimulatedFlight", "simulate_flight", "write_flight", "plan_test",
           "noise_margin", "default_noise_std", "sidecar_path", "EFFECT_NAMES"]
