"""Every loop of a multirotor from one flight: find, identify (inner loops first), tune, say what is missing.

:func:`identify_vehicle` finds the loops whose topics the log holds (:mod:`~mrftcli.vehicle.loops`),
identifies the inner loops (altitude, roll, pitch) with eq. (2) at the known Tp and the outer loops
(x, y) through the closed inner loop (or with eq. (2), said in the result's first assumption), tunes
each loop as ``tune`` does, and names the tests the loops without a model need
(:mod:`~mrftcli.vehicle.next_tests`). The result is one versioned record, :class:`VehicleResult`
(``mrft-ident vehicle --json``; docs/vehicle.md).

=============  ==================================================================================
``loops``      which loops a log records (one implementation, shared with ``batch --loop auto``)
``record``     :class:`VehicleResult`, :class:`VehicleLoop`, :class:`LoopGains`, :class:`MissingLoop`
``gains``      each loop tuned as ``tune`` does, for a stack's rate and filter with ``--export``
``next_tests`` what to fly for a loop without a model (:mod:`mrftcli.plan`)
``driver``     :func:`identify_vehicle` and :class:`VehicleOptions`
=============  ==================================================================================
"""

from __future__ import annotations

from .driver import EQ2_OUTER_ASSUMPTION, VehicleOptions, identify_vehicle, models_per_loop
from .gains import STACKS, StackOptions, TuneOptions, tune_loop
from .loops import INNER_LOOPS, INNER_OF, OUTER_LOOPS, VEHICLE_ORDER, absent_topics, loops_in_log
from .record import (MISSING_REASONS, ROLES, ROUTES, VEHICLE_SCHEMA_VERSION, LoopGains, MissingLoop, VehicleLoop,
                     VehicleResult)

__all__ = ["identify_vehicle", "VehicleOptions", "models_per_loop", "EQ2_OUTER_ASSUMPTION", "VehicleResult", "TuneOptions", "StackOptions", "STACKS", "tune_loop",
           "VehicleLoop", "LoopGains", "MissingLoop", "VEHICLE_SCHEMA_VERSION", "ROLES", "ROUTES", "MISSING_REASONS",
           "INNER_LOOPS", "OUTER_LOOPS", "INNER_OF", "VEHICLE_ORDER", "loops_in_log", "absent_topics"]
