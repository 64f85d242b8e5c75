"""Plan the next test(s) for a model object: the relay test that pins its unknown parameters down best.

:func:`plan_tests` takes the model object and picks the strategy of its kind. Eq. (2)
(``soiptd_model(Tp)``): what is known enters as a :class:`Prior` (ranges for Td, tau and K) and,
optionally, as tests already flown (:class:`FlownTest`, from a log or an ``analyze --json`` result);
what the flight allows as :class:`PlanLimits` (largest output amplitude, largest relay height, time
available, controller rate, sensor noise); it recommends the beta, relay height and duration of the
next MRFT test(s) with their predicted limit cycle and the predicted standard deviations of Td, tau
and K after them. A process plant (any other family): its recorded tests analysed
(``analyze --model``) and :class:`PlanLimits` (amplitude, half-height); it ranks the next relay tests by the parameters' std
after each. Both return a :class:`PlanResult` (versioned JSON). docs/plan.md and
docs/process-plants.md have the method.

One module per stage:

=============  ==================================================================================
``records``    the records: :class:`Prior`, :class:`PlanLimits`, :class:`FlownTest`,
               :class:`TestPlan`, :class:`CandidateTest`, :class:`PlanResult`
``inputs``     flown tests from a log's segments or an ``analyze --json`` result; prior ranges
``noise``      the per-cycle noise model of a test's constraints; the admissibility lines
``fisher``     Fisher information of a test (eq. (2): on (Td, tau, ln K); any family: of response points)
``draws``      eq. (2)'s plant draws from the prior, conditioned on the flown tests' UFM slice
``search``     candidates (the beta grid, or a process plant's relays) and the choice of the next test(s)
``forecast``   the predicted stds over the draws, and by simulated flights
``driver``     :func:`plan_tests`, the driver over those stages (one strategy per model kind)
=============  ==================================================================================

Units: times in seconds, frequencies in Hz, amplitudes in output units, h in command units. The example
is :func:`plan_tests`'.
"""

from __future__ import annotations

from .driver import DEFAULT_BETAS, TD_OMEGA_LIMIT, PlanOptions, plan_tests
from .fisher import fisher_information, flown_information, planned_information, point_information
from .forecast import simulated_flights
from .inputs import flown_from_result, flown_from_segments, noise_from_result, prior_range
from .noise import NOISE_MODEL, cycle_noise, switch_gap
from .records import CandidateTest, Conventional, FlownTest, PlanLimits, PlanResult, Prior, TestPlan

__all__ = [
    "Prior",
    "PlanLimits",
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
    "point_information",
    "plan_tests",
    "simulated_flights",
    "DEFAULT_BETAS",
    "TD_OMEGA_LIMIT",
]
