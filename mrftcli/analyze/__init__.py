"""One flight log in, the loop's model out: read -> segment -> identify, with uncertainty.

:func:`analyze_flight` takes a :class:`~mrftcli.io.logtypes.FlightLog`, the model object (eq. (2):
``mrftcli.mrft.model.soiptd_model(Tp)``; a process family: ``mrftcli.mrft.families.family_model``) and an
:class:`AnalyzeOptions`; :func:`analyze_path` reads the log first (with a :class:`mrftcli.io.ReadOptions`).
Both are pure (no printing, no files written) and return the one :class:`AnalysisResult` of every
family (its ``kind``: ``"soiptd"`` for eq. (2), the figures below; ``"family"``; ``"cascade"``).

How the figures are obtained
----------------------------
* Every MRFT test comes from :func:`mrftcli.segment.segment` with its stable cycles, the measured
  frequency and amplitude per cycle and the *effective* beta (the switching level the relay actually
  achieved, measured from the output at the switch instants). Identification uses the effective
  beta with ``rate_hz=None``: at the actual switch instants the sampled, noisy relay *is* a
  continuous relay switching at that level, so no sampling correction applies.
* **Point estimate** (``parameters.*.value``): the paper's method at its core - each test's UFM
  slice at the known Tp scaled to real units (Lemma 3, exact LPRS, the test's mean effective beta
  and mean frequency) - with two more measured constraints per test in one weighted least squares
  (*Beyond the paper*, :mod:`mrftcli.mrft.consensus`; ``constraints=()`` leaves them out): the
  **phase** of each test's fundamental harmonic (``RelayCycle.phase_h1``; on the 30-plant sweep its
  standard error in tau is 1.2-4.9 times (median 2.2) smaller than the UFM slice's, and the tau RMS
  error drops from 0.59 to 0.16 ms, docs/benchmarks/analyze.md) and the **amplitude** ratios between
  tests through the UGM. ``identification`` keeps the UFM-only result of
  :func:`mrftcli.mrft.identify.identify` (the paper's estimate) and ``constraints`` the constraints
  used with their residuals at the estimate and the chi-square; a chi-square with p < 1e-3 raises a
  warning (the constraints disagree: the plant may not follow eq. (2)).
* **Uncertainty** (``std``, ``ci95_low/high``): a bootstrap over cycles
  (:func:`mrftcli.mrft.consensus.bootstrap`): ``n_bootstrap`` draws (400), fewer for logs with many
  tests (draws x tests <= 4000, >= 100).
* **Per-combination spread** (``combinations``, the paper's Table III): one stable cycle from each
  test, identified with that cycle's own beta and frequency, over all combinations (a seeded random
  subset when there are more than ``max_combinations``; :func:`mrftcli.mrft.consensus.combinations`).

Times: people read times relative to the log's first sample (``AnalysisResult.t0``, epoch seconds
in real logs); the JSON keeps the absolute ``t_start``/``t_end`` and adds ``t_start_rel``/``t_end_rel``.
"""

from __future__ import annotations

from ..mrft.consensus import CONSTRAINTS
from .driver import analyze_flight, analyze_path, refuse_rejected_tp
from .options import AnalyzeOptions, CascadeOptions, RelayOptions
from .overlay import analysis_overlay
from .record import (SCHEMA_VERSION, AnalysisResult, LogInfo, TestSummary,
                     TpCheck, analysis_controller_rate, command_rate_of_result, measured_noise_std)
from .screen import ASSUMED_TD_RANGE, describe_t0, log_start

__all__ = ["AnalyzeOptions", "CascadeOptions", "RelayOptions", "AnalysisResult",
           "TestSummary", "LogInfo", "SCHEMA_VERSION", "analyze_flight", "analyze_path", "analysis_overlay",
           "refuse_rejected_tp", "TpCheck", "measured_noise_std",
           "analysis_controller_rate", "command_rate_of_result", "log_start", "describe_t0", "CONSTRAINTS",
           "ASSUMED_TD_RANGE"]
