"""Relay runs in the command and the controller's sample clock (steps 1 and 2 of :mod:`mrftcli.segment`).

* :func:`find_relay_runs` splits the command into chains of flat runs (:class:`RelayRun`) that
  alternate between two levels: the relay stretches.
* :func:`estimate_rate_hz` and :func:`regularise_times` recover the controller's rate and put jittery
  receive times back on its sample grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter1d

__all__ = ["RelayRun", "robust_sigma", "find_relay_runs", "estimate_rate_hz", "regularise_times"]

_MAD_TO_SIGMA = 1.4826
#: a command change smaller than this share of the largest one nearby is a moving bias, not a switch
_SMALL_STEP = 0.05


@dataclass(frozen=True)
class RelayRun:
    """One flat run of the command: a relay half-period (or the hold level before the relay starts).

    Attributes
    ----------
    start : int
        Index of its first command sample.
    stop : int
        One past the index of its last sample.
    level : float
        Mean command over the run [command units].
    glitch : bool
        A false switch (a short excursion to the other level and back) was absorbed into it.
    """

    start: int
    stop: int
    level: float
    glitch: bool = False


def robust_sigma(x: np.ndarray) -> float:
    """1.4826 x the median absolute deviation: a standard deviation that ignores outliers (0 when empty).

    Examples
    --------
    >>> robust_sigma(np.array([1.0, 2.0, 3.0, 100.0]))
    1.4826
    """
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return 0.0
    return float(_MAD_TO_SIGMA * np.median(np.abs(x - np.median(x))))


def find_relay_runs(
    command: np.ndarray,
    *,
    jump_sigmas: float = 8.0,
    min_run_samples: int = 3,
    max_glitch_samples: int = 3,
    min_runs: int = 6,
    breaks: np.ndarray | None = None,
) -> list[list[RelayRun]]:
    """Split the command into chains of flat runs alternating between two levels.

    Parameters
    ----------
    command : numpy.ndarray
        Command samples [command units].
    jump_sigmas : float
        A sample-to-sample change larger than this many robust standard deviations of the
        increments (and than 1e-9 of the command scale) is a candidate switch.
    min_run_samples : int
        Shortest flat run that can be a relay half-period.
    max_glitch_samples : int
        Longest stretch of short runs absorbed between two runs of the same level (a false switch).
    min_runs : int
        Shortest chain reported (runs, i.e. half-periods).
    breaks : numpy.ndarray, optional
        Sample indices where a chain must end (e.g. a new value on the beta topic).

    Returns
    -------
    list of list of RelayRun
        One list of runs per relay stretch, in time order; glitch-absorbing runs have ``glitch``.
    """
    c = np.asarray(command, dtype=float)
    n = c.size
    if n < 2 * min_run_samples:
        return []
    d = np.diff(c)
    scale = float(np.max(np.abs(c))) if n else 1.0
    thr = max(jump_sigmas * robust_sigma(d), 1e-9 * (scale + 1e-12))
    # A bias inside the command that moves (HEAR's 50-sample median of the PID output) steps by a
    # little at most samples: such steps, under 5 % of the largest change within +-1000 samples (a
    # relay switch nearby), are not switches, or they would split every half-period into short runs.
    local = maximum_filter1d(np.abs(d), size=2001, mode="nearest")
    small = (np.abs(d) > thr) & (np.abs(d) <= _SMALL_STEP * local)
    cut = np.flatnonzero((np.abs(d) > thr) & ~small) + 1
    starts = np.concatenate(([0], cut))
    stops = np.concatenate((cut, [n]))
    lengths = stops - starts
    sums = np.add.reduceat(c, starts)
    levels = sums / lengths
    rng = np.maximum.reduceat(c, starts) - np.minimum.reduceat(c, starts)
    # Jump magnitude on each side of each run; a flat run's spread is small beside them.
    jumps = np.abs(np.diff(levels))
    left = np.concatenate(([np.inf], jumps))
    right = np.concatenate((jumps, [np.inf]))
    # a run that absorbed small steps must be flat on the moving bias's scale (a continuous command
    # is not a relay level, however large the jumps beside it)
    n_small = np.add.reduceat(np.concatenate((small, [False])).astype(int), starts)
    flat_share = np.where(n_small > 0, _SMALL_STEP, 0.2)
    flat = (lengths >= min_run_samples) & (rng <= flat_share * np.minimum(left, right))
    cand = np.flatnonzero(flat)
    break_set = np.asarray(breaks if breaks is not None else [], dtype=int)

    chains: list[list[RelayRun]] = []
    chain: list[RelayRun] = []

    def close() -> None:
        if len(chain) >= min_runs:
            chains.append(list(chain))

    for i in cand:
        run = RelayRun(int(starts[i]), int(stops[i]), float(levels[i]))
        if not chain:
            chain = [run]
            continue
        last = chain[-1]
        gap = run.start - last.stop
        crosses_break = bool(np.any((break_set > last.start + min_run_samples) & (break_set <= run.start)))
        step = abs(run.level - last.level)
        ref_jump = abs(last.level - chain[-2].level) if len(chain) >= 2 else step
        tol = 0.1 * max(ref_jump, thr)
        if gap > max_glitch_samples and len(chain) >= 2 and gap <= max(r.stop - r.start for r in chain):
            # A relay switching on quantised noise chatters: a stretch of 1-2 sample runs at the
            # chain's own two levels, up to a half-period long, is still the same relay (the cycles
            # around it are dropped as glitches); anything at a third level ends the test.
            gs = c[last.stop:run.start]
            at_levels = np.minimum(np.abs(gs - last.level), np.abs(gs - chain[-2].level)) <= tol
            if at_levels.all():
                gap = max_glitch_samples
        if gap <= max_glitch_samples and not crosses_break and step <= tol and len(chain) >= 2:
            # Same level again after a short excursion: a false switch / glitch inside a half-period.
            chain[-1] = RelayRun(last.start, run.stop, (last.level + run.level) / 2, glitch=(gap > 0) or last.glitch)
            continue
        alternates = len(chain) < 2 or abs(run.level - chain[-2].level) <= tol
        if gap <= max_glitch_samples and not crosses_break and step > tol and alternates:
            chain.append(run)
            continue
        close()
        # The last run may still open a new chain with this one (e.g. hold level -> relay).
        if gap <= max_glitch_samples and not crosses_break and step > 0:
            chain = [last, run]
        else:
            chain = [run]
    close()
    # A chain may start with a run of the hold level before the relay began: drop leading runs that
    # do not belong to the two alternating levels.
    cleaned = []
    for ch in chains:
        lv = np.array([r.level for r in ch])
        even, odd = np.median(lv[0::2]), np.median(lv[1::2])
        tol = 0.1 * abs(even - odd)
        k = 0
        while k < len(ch) and abs(lv[k] - (even if k % 2 == 0 else odd)) > tol:
            k += 1
        ch = ch[k:]
        if len(ch) >= min_runs:
            cleaned.append(ch)
    return cleaned


def estimate_rate_hz(t: np.ndarray) -> float:
    """Controller rate from timestamps: 1 / median interval [Hz] (robust to drops and jitter)."""
    dt = np.diff(np.asarray(t, dtype=float))
    dt = dt[dt > 0]
    if dt.size == 0:
        return float("nan")
    return float(1.0 / np.median(dt))


def regularise_times(t: np.ndarray, *, max_residual: float = 0.45) -> tuple[np.ndarray, bool]:
    """Put jittery timestamps back on a uniform sample grid when they fit one.

    The sample period is found where the timestamps' phases line up best, sample numbers follow
    from the phase (dropped messages stay gaps), and the times are fitted by least squares as
    t0 + n * dt. If every residual is within ``max_residual`` periods the fitted grid replaces the
    times; otherwise (the clock is not a fixed-rate grid) the times are returned unchanged.

    Parameters
    ----------
    t : numpy.ndarray
        Increasing timestamps [s].
    max_residual : float
        Largest accepted residual, in nominal periods.

    Returns
    -------
    (numpy.ndarray, bool)
        The times and whether they were regularised.
    """
    t = np.asarray(t, dtype=float)
    if t.size < 8:
        return t, False
    dt0 = np.median(np.diff(t))
    if not dt0 > 0:
        return t, False
    steps = np.diff(t) / dt0
    if np.all(np.abs(steps - np.rint(steps)) < 0.05):
        # clean clock (no jitter to speak of): counting intervals cannot slip
        n = np.concatenate(([0.0], np.cumsum(np.maximum(np.rint(steps), 1.0))))
        return _grid_fit(t, n, max_residual)
    # Sample numbers from the clock's phase, not by counting intervals (a count slips by one where
    # jitter makes an interval look like 0.5 or 1.5 periods): the period is where the timestamps'
    # phases t / dt line up best (peak of |mean exp(2 pi i t / dt)|), first on a short stretch
    # with a coarse grid, then on all samples with a fine one.
    tr = t - t[0]
    dt = dt0
    sub = np.unique(np.linspace(0, t.size - 1, min(t.size, 400)).astype(int))  # the span matters, not n
    for ts, span in ((tr[: min(t.size, 200)], 0.02), (tr[sub], 0.0015)):
        cand = dt * (1.0 + np.linspace(-span, span, 81))
        ph = np.exp(2j * np.pi * ts[:, None] / cand[None, :])
        R = np.abs(ph.mean(axis=0))
        j = int(np.argmax(R))
        if 0 < j < cand.size - 1:  # parabolic refinement of the peak
            den = R[j - 1] - 2 * R[j] + R[j + 1]
            off = 0.5 * (R[j - 1] - R[j + 1]) / den if den != 0 else 0.0
            dt = cand[j] + off * (cand[1] - cand[0])
        else:
            dt = cand[j]
    phase = np.angle(np.mean(np.exp(2j * np.pi * tr / dt))) / (2 * np.pi) * dt
    n = np.rint((tr - phase) / dt)
    if np.any(np.diff(n) <= 0):
        return t, False
    return _grid_fit(t, n, max_residual)


def _grid_fit(t: np.ndarray, n: np.ndarray, max_residual: float) -> tuple[np.ndarray, bool]:
    """``t0 + dt n`` fitted to the times ``t`` [s] of sample numbers ``n`` by least squares, when every
    time lies within ``max_residual`` periods of it; else ``t`` unchanged (and False)."""
    A = np.vstack([np.ones_like(n), n]).T
    (t0, dt), *_ = np.linalg.lstsq(A, t, rcond=None)
    fit = t0 + dt * n
    if dt > 0 and np.max(np.abs(t - fit)) <= max_residual * dt:
        return fit, True
    return t, False
