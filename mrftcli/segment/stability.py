"""The stable limit cycle of one test (step 4 of :mod:`mrftcli.segment`).

Reference values are the medians of period and amplitude over the second half of the test's regular
cycles (the limit cycle is established by then). A cycle is *consistent* when its period is within
``max(k * sigma_P, 3 dt, 6 % P)`` (capped at 15 % of P) of the median and its amplitude within
``max(k * sigma_a, 12 % a)`` (capped at 25 %), where sigma is 1.4826 MAD and k =
:attr:`StabilityCriterion.mad_k`. The caps keep a slow drift or a transient out. A test whose
cycles scatter beyond half the floors about a level that does not move (the slopes of period and
amplitude against the cycle index within :attr:`StabilityCriterion.stationary_z` standard errors of
zero; a delay jitter at beta -0.7 scatters the period by +-15 % and the amplitude by +-30 % from
cycle to cycle) takes every regular cycle within the wider stationary tolerances. The stable cycles
are the consistent, regular ones after the first cycle of the first run of ``min_consecutive``
consecutive consistent cycles; the cycles before (and that first one, which may still be
converging) are the start-up transient.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .runs import robust_sigma

__all__ = ["StabilityCriterion", "stable_cycles"]


@dataclass(frozen=True)
class StabilityCriterion:
    """Settings of the stable-limit-cycle criterion (:func:`stable_cycles`).

    Attributes
    ----------
    mad_k : float
        Tolerance in robust standard deviations (1.4826 MAD) about the median period/amplitude.
    period_floor_samples : float
        Lowest period tolerance in controller samples (a sampled relay's half-periods are quantised).
    period_floor_rel, period_cap_rel : float
        Lowest / highest period tolerance relative to the median period.
    amplitude_floor_rel, amplitude_cap_rel : float
        Lowest / highest amplitude tolerance relative to the median amplitude.
    min_consecutive : int
        Consecutive consistent cycles that mark the end of the start-up transient.
    stationary_z : float
        The regular cycles are stationary when the least-squares slopes of period and amplitude
        against the cycle index are within this many standard errors of zero.
    stationary_period_cap_rel, stationary_amplitude_cap_rel : float
        The tolerances of a noisy stationary test (at least 6 regular cycles, robust spread above
        half the floors), relative to the medians.
    """

    mad_k: float = 4.0
    period_floor_samples: float = 3.0
    period_floor_rel: float = 0.06
    period_cap_rel: float = 0.15
    amplitude_floor_rel: float = 0.12
    amplitude_cap_rel: float = 0.25
    min_consecutive: int = 3
    stationary_z: float = 3.0
    stationary_period_cap_rel: float = 0.35
    stationary_amplitude_cap_rel: float = 0.6

    def to_dict(self) -> dict:
        return asdict(self)


def stable_cycles(
    period: np.ndarray,
    amplitude: np.ndarray,
    regular: np.ndarray,
    dt: float,
    criterion: StabilityCriterion = StabilityCriterion(),
    period_error: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Apply the stable-limit-cycle criterion (module docstring).

    Parameters
    ----------
    period, amplitude : numpy.ndarray
        Per-cycle period [s] and amplitude [output units].
    regular : numpy.ndarray of bool
        Cycles without gaps/glitches/failed fits; only these can be stable.
    dt : float
        Controller sample period [s].
    criterion : StabilityCriterion
    period_error : float
        The measured periods' own error [s], added to the period floor: 0 where every switch is
        on a logged sample (the floor's ``period_floor_samples`` covers the quantisation); a test
        logged below its controller's rate has its switches placed from the vernier
        (:mod:`~mrftcli.segment.vernier`), and where its orbit wanders or the logging locks to it
        over a stretch a switch may sit a tick or more off: a cycle of the limit cycle then reads
        outside the floor and breaks the run of consistent cycles (the cap still applies).
    -------
    (stable, consistent, info)
        Boolean masks and the medians/tolerances used.
    """
    P = np.asarray(period, float)
    a = np.asarray(amplitude, float)
    reg = np.asarray(regular, bool) & np.isfinite(P) & np.isfinite(a)
    n = P.size
    info = {"period_median": float("nan"), "period_tolerance": float("nan"),
            "amplitude_median": float("nan"), "amplitude_tolerance": float("nan")}
    if reg.sum() == 0:
        return np.zeros(n, bool), np.zeros(n, bool), info
    idx = np.flatnonzero(reg)
    ref = idx[idx.size // 2:] if idx.size >= 4 else idx  # second half: past the transient
    Pm, am = float(np.median(P[ref])), float(np.median(a[ref]))
    sP, sa = robust_sigma(P[ref]), robust_sigma(a[ref])
    c = criterion
    tolP = min(max(c.mad_k * sP, c.period_floor_samples * dt + period_error, c.period_floor_rel * Pm),
               c.period_cap_rel * Pm)
    tola = min(max(c.mad_k * sa, c.amplitude_floor_rel * am), c.amplitude_cap_rel * am)
    # a noisy test (its cycles scatter beyond half the floors) about a level that does not move: every
    # regular cycle inside the stationary caps is consistent (the robust sigma of a jittery MRFT at
    # beta -0.7 is that of the cycles near the median, while the cycle map alternates the others far
    # out, so k sigma alone rejects half of a stationary test)
    noisy = (robust_sigma(P[idx] - Pm) > c.period_floor_rel * Pm / 2
             or robust_sigma(a[idx] - am) > c.amplitude_floor_rel * am / 2)
    stationary = bool(noisy and _stationary(P[idx], a[idx], c.stationary_z))
    if stationary:
        tolP = max(tolP, c.stationary_period_cap_rel * Pm)
        tola = max(tola, c.stationary_amplitude_cap_rel * am)
    consistent = reg & (np.abs(P - Pm) <= tolP) & (np.abs(a - am) <= tola)
    # The first run of min_consecutive consecutive consistent cycles ends the transient. Its first
    # cycle still carries some of the start-up (a converging cycle can sit inside the tolerances
    # while its switching level and period do not yet match), so it counts as transient too.
    stable = np.zeros(n, bool)
    m = c.min_consecutive
    run = 0
    start = None
    reg_idx = np.flatnonzero(reg)  # irregular cycles (gaps, glitches) neither count nor break a run
    for j, i in enumerate(reg_idx):
        run = run + 1 if consistent[i] else 0
        if run >= m:
            start = int(reg_idx[j - m + 2])
            break
    if start is not None:
        stable[start:] = consistent[start:]
    info.update(period_median=Pm, period_tolerance=tolP, amplitude_median=am, amplitude_tolerance=tola,
                stationary=stationary)
    return stable, consistent, info


def _stationary(P: np.ndarray, a: np.ndarray, z: float) -> bool:
    """True when at least 6 cycles' period and amplitude keep one level: the least-squares slope of
    each against the cycle index is within ``z`` of its standard error (the scatter about the line)."""
    n = P.size
    if n < 6:
        return False
    k = np.arange(n, dtype=float) - (n - 1) / 2.0
    skk = float(k @ k)
    for x in (P, a):
        slope = float(k @ (x - x.mean())) / skk
        resid = x - x.mean() - slope * k
        se = math.sqrt(float(resid @ resid) / (n - 2) / skk)
        if se <= 0 or abs(slope) > z * se:
            return False
    return True
