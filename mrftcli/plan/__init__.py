"""Plan the next MRFT test(s): the beta, relay height and duration that pin (Td, tau, K) down best.

What is known enters as a :class:`Prior` (ranges for Td, tau and K) and, optionally, as tests
already flown (:class:`FlownTest`, from a log or an ``analyze --json`` result). What the flight
allows enters as :class:`FlightLimits` (largest output amplitude, largest relay height, time
available, controller rate, sensor noise). :func:`plan_tests` returns the recommended test(s) with
their predicted limit cycle and the predicted standard deviations of Td, tau and K after them
(:class:`PlanResult`, versioned JSON). docs/plan.md has the method.

One module per stage:

=============  ==================================================================================
``records``    the records: :class:`Prior`, :class:`FlightLimits`, :class:`FlownTest`,
               :class:`TestPlan`, :class:`CandidateTest`, :class:`PlanResult`
``inputs``     flown tests from a log's segments or an ``analyze --json`` result; prior ranges
``noise``      the per-cycle noise model of a test's constraints; the admissibility lines
``fisher``     Fisher information of a test on (Td, tau, ln K) and the posterior it leaves
``draws``      plant draws from the prior, conditioned on the flown tests
``search``     candidates on the beta grid and the greedy choice of the next test(s)
``forecast``   the predicted stds over the draws, and by simulated flights
``driver``     :func:`plan_tests`, the driver over those stages
=============  ==================================================================================

Units: times in seconds, frequencies in Hz, amplitudes in output units, h in command units.

Examples
--------
>>> from mrftcli.plan import FlightLimits, PlanOptions, Prior, plan_tests
>>> prior = Prior(Td=(0.3, 3.0), tau=(0.01, 0.08), K=(1.0, 10.0))
>>> limits = FlightLimits(max_amplitude=0.05, max_h=2.0, time_s=30.0, rate_hz=200.0, noise_std=0.0005)
>>> p = plan_tests(0.04, prior, limits, options=PlanOptions(n_tests=2, n_draws=3, betas=(-0.2, -0.5, -0.8)))
>>> len(p.tests), all(-0.9 <= t.beta <= -0.1 for t in p.tests)
(2, True)
"""

from __future__ import annotations

from .driver import DEFAULT_BETAS, TD_OMEGA_LIMIT, PlanOptions, plan_tests
from .fisher import fisher_information, flown_information, planned_information
from .forecast import simulated_std
from .inputs import flown_from_result, flown_from_segments, noise_from_result, prior_range
from .noise import NOISE_MODEL, cycle_noise, switch_gap
from .records import CandidateTest, Conventional, FlightLimits, FlownTest, PlanResult, Prior, TestPlan

__all__ = [
    "Prior",
    "FlightLimits",
    "FlownTest",
    "flown_from_segments",
    "flown_from_result",
    "noise_from_result",
    "prior_range",
    "TestPlan",
    "CandidateTest",
    "Conventional",
    "PlanResult",
    "PlanOptions",
    "NOISE_MODEL",
    "cycle_noise",
    "switch_gap",
    "fisher_information",
    "planned_information",
    "flown_information",
    "plan_tests",
    "simulated_std",
    "DEFAULT_BETAS",
    "TD_OMEGA_LIMIT",
]
