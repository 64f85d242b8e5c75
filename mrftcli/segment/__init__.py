"""Find the MRFT tests in a flight log and measure their stable limit cycles.

The segmenter works on the command the MRFT block sent (``FlightLog.command``) and the loop output
(``FlightLog.output``). It is a chain of small pure functions on numpy arrays, one module per step,
chained by :func:`segment` / :func:`segment_arrays` (:mod:`.segmenter`; its settings: :class:`SegmentOptions`):

1. **Relay runs** (:func:`find_relay_runs`, :mod:`.runs`). The command is split at jumps larger than
   ``jump_sigmas`` times a robust (MAD) scale of its sample-to-sample increments. A *flat run* is a
   stretch of at least ``min_run_samples`` samples whose spread is small beside the jumps that bound
   it. A relay test is a maximal chain of flat runs whose levels alternate between two values
   (``bias + h`` and ``bias - h``). A short run between two runs of the same level (a false switch,
   a glitch) is absorbed and the cycle that holds it is marked ``glitch``; a change of level, a change
   of h, a stretch of normal flight (PID hold, take-off, landing), a new value on the beta topic or
   absent data (an interval of 10 median sample intervals or more: a log masked to some tests' windows,
   a recorder stopped) ends the chain; no run spans absent data, whatever the levels either side. A
   test's nominal beta is the beta marker in force over its cycles (the last published up to its end:
   its own, or an earlier test's when none came since). A last run of 3 median half-periods or more is
   a relay that locked up (the output drifting away under one level): the test ends at the switch before
   the one into it (that one came early, so the cycle it closes is short).
2. **Switch instants.** The first sample at the new level. Timestamps inside a test are first put
   back on the controller's sample grid when they fit one (receive-time jitter removed, dropped
   messages kept as gaps; :func:`regularise_times`, :mod:`.runs`). A switch after one or two missing command
   samples is placed in the middle of the possible instants (flag ``interp``; its output level is not
   used for beta); after a longer gap its cycles are marked ``gap`` and left out.
3. **Cycles** (-h -> +h switch to the next one; :mod:`.cycles`). Per cycle: the period, the two
   half-periods, and a smooth model of the output: least squares over one period centred on each
   half-cycle with a line plus harmonics 1..8 of the cycle frequency
   (:func:`mrftcli.mrft.harmonics.fit_harmonics`; every sample of the period
   takes part except the ones that decided a switch, whose noise is biased by first-passage
   selection). From it: the extrema (a noise-robust peak, not the raw noisy maximum), the amplitude
   (max - min) / 2 about the centre (max + min) / 2, and the *effective beta*: the modelled output at
   each switch instant, relative to the centre, divided by the amplitude. At the -h -> +h switch of
   the MRFT's periodic solution y - centre = -beta a, at the +h -> -h switch y - centre = +beta a
   (``docs/architecture.md``); the mean over the stable cycles is the level the relay actually
   achieved, which a noisy sampled relay moves away from its nominal beta.
4. **Stable limit cycle** (:func:`stable_cycles`, :mod:`.stability`). Reference values are the medians of period and
   amplitude over the second half of the test's regular cycles (the limit cycle is established by
   then). A cycle is *consistent* when its period is within ``max(k * sigma_P, 3 dt, 6 % P)`` (capped
   at 15 % of P) of the median and its amplitude within ``max(k * sigma_a, 12 % a)`` (capped at 25 %),
   where sigma is 1.4826 MAD and k = ``mad_k``. The stable cycles are the consistent, regular ones
   after the first cycle of the first run of ``min_consecutive`` consecutive consistent cycles; the
   cycles before (and that first one, which may still be converging) are the start-up transient.
5. **Is it a limit cycle of this output?** (:func:`check_limit_cycle`, :mod:`.validity`, stored in
   ``MrftTest.validity``). A relay in the command says nothing about the output: the wrong loop,
   topic or an output buried in noise still yields "cycles". The output must oscillate at the
   relay's frequency above the noise (fundamental amplitude >= 3x the residual noise of the cycle
   fit, >= 50 % of its variance in the fundamental), with a steady phase relative to the relay
   (mean resultant length >= 0.9) that matches what an MRFT at the measured switching level gives a
   plant of eq. (2) (within 0.6 rad of -pi + arcsin beta_eff), and the effective beta must lie in
   (-1, 1) and agree with the nominal one (within 0.25, same sign). Thresholds and their reasons:
   :class:`ValidityCriterion` and docs/usage-analyze.md; :func:`mrftcli.analyze.analyze_flight`
   rejects the failing tests and those whose loop-gain sign disagrees with the others'.

**Logged below the controller's rate** (PX4's 10 Hz logger over its 50 Hz controller; the
controller's rate from the layout or ``controller_rate_hz``), a fast test has 2-sample half-periods
and 4-6 samples a cycle: runs of 2 samples count, the switch instants are put on the controller's
ticks from the vernier of every switch's logging bracket (:func:`switch_ticks`), and each cycle is
measured against the output folded over the test's stable cycles (:func:`measure_folded`,
:mod:`.vernier`); ``MrftTest.switch_timing`` and ``samples_per_cycle`` say how.

Everything the identification needs comes out as frozen dataclasses (:mod:`.records`):
:class:`RelayCycle` and :class:`MrftTest`.
"""

from .cycles import CycleFundamental, cycle_extrema, cycle_fundamental, measure_cycles
from .records import MrftTest, RelayCycle
from .runs import RelayRun, find_relay_runs, regularise_times, robust_sigma
from .segmenter import SegmentOptions, segment, segment_arrays
from .stability import StabilityCriterion, stable_cycles
from .validity import LimitCycleCheck, ValidityCriterion, check_limit_cycle
from .vernier import FoldedWaveform, TickSwitches, fold_waveform, measure_folded, switch_ticks

__all__ = [
    "segment", "segment_arrays", "SegmentOptions",
    "RelayCycle", "MrftTest",
    "RelayRun", "find_relay_runs", "regularise_times", "robust_sigma",
    "CycleFundamental", "cycle_extrema", "cycle_fundamental", "measure_cycles",
    "StabilityCriterion", "stable_cycles",
    "ValidityCriterion", "LimitCycleCheck", "check_limit_cycle",
    "TickSwitches", "switch_ticks", "FoldedWaveform", "fold_waveform", "measure_folded",
]
