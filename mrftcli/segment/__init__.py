"""Segment a flight log into MRFT tests and their stable relay limit cycles.

A test is a run of relay switching in the command; its cycles are measured one by one (period,
amplitude, balance, phase of the fundamental), the stable ones kept, and the effective beta measured.
"""

from .core import (LimitCycleCheck, MrftTest, RelayCycle, StabilityCriterion, ValidityCriterion, check_limit_cycle,
                   df_phase, estimate_rate_hz, find_relay_runs, regularise_times, segment, segment_arrays,
                   stable_cycles)

__all__ = ["RelayCycle", "MrftTest", "StabilityCriterion", "segment", "segment_arrays", "find_relay_runs",
           "regularise_times", "stable_cycles", "estimate_rate_hz", "ValidityCriterion", "LimitCycleCheck",
           "check_limit_cycle", "df_phase"]
