"""Closed-loop MRFT flights of the paper's model with known truth (the tests' and benchmarks' oracle)."""

from .flight import (EFFECT_NAMES, Effects, FlightSpec, SimulatedFlight, TestSpec, default_noise_std, noise_margin,
                     plan_test, sidecar_path, simulate_flight, write_flight)

__all__ = ["Effects", "TestSpec", "FlightSpec", "SimulatedFlight", "simulate_flight", "write_flight", "plan_test",
           "noise_margin", "default_noise_std", "sidecar_path", "EFFECT_NAMES"]
