"""Closed-loop MRFT flights of a model object with known truth (the tests' and benchmarks' oracle).

One driver flies every family (eq. (2), the process families, a declared plant): ``spec`` says what
to fly (:class:`FlightSpec`, :class:`TestSpec`, :class:`Effects`, the loop defaults, validation and
schedule); ``flight`` flies it (:func:`simulate_flight`, in stages, and :func:`plan_test`);
``sidecar`` writes what it leaves (the truth sidecar and the topics, :func:`write_flight`);
``control`` and ``plant`` hold the relays, the hold PID and the whole-period propagator. Cascaded
flights (an outer position loop through the closed inner attitude loop): ``cascade_spec``
(:class:`CascadeSpec`, :class:`InnerGains`, the :class:`CascadeTruth` sidecar), ``cascade``
(:func:`simulate_cascade`), ``cascade_plant`` (the exact discrete cascade, its responses and
margins), ``cascade_write`` (:func:`write_cascade`: HEAR and reference layouts).
"""

from .flight import (EFFECT_NAMES, Effects, FlightSpec, SimulatedFlight, TestSpec, default_noise_std, noise_margin,
                     plan_test, sidecar_path, simulate_flight, write_flight)
from .cascade import CascadeFlight, simulate_cascade
from .cascade_spec import CascadeSpec, CascadeTruth, InnerGains
from .cascade_write import write_cascade

__all__ = ["Effects", "TestSpec", "FlightSpec", "SimulatedFlight", "simulate_flight", "write_flight", "plan_test",
           "noise_margin", "default_noise_std", "sidecar_path", "EFFECT_NAMES", "CascadeSpec", "InnerGains",
           "CascadeTruth", "CascadeFlight", "simulate_cascade", "write_cascade"]
