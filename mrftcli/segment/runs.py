"""Relay runs in the command and the controller's sample clock (steps 1 and 2 of :mod:`mrftcli.segment`).

* :func:`find_relay_runs` splits the command into chains of flat runs (:class:`RelayRun`) that
  alternate between two levels: the relay stretches.
* :func:`regularise_times` puts jittery receive times back on the controller's sample grid (its
  rate: :func:`mrftcli.io.timing.median_rate_hz`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import maximum_filter1d

__all__ = ["RelayRun", "robust_sigma", "find_relay_runs", "regularise_times"]

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
    if c.size < 2 * min_run_samples:
        return []
    runs = _flat_runs(c, jump_sigmas, min_run_samples)
    joiner = _Joiner(c, runs.threshold, np.asarray(breaks if breaks is not None else [], dtype=int),
                     min_run_samples, max_glitch_samples)
    chains: list[list[RelayRun]] = []
    chain: list[RelayRun] = []
    for i in runs.candidates:
        run = RelayRun(int(runs.starts[i]), int(runs.stops[i]), float(runs.levels[i]))
        action, gap = joiner.action(chain, run) if chain else ("restart", 0)
        if action == "merge":
            last = chain[-1]
            chain[-1] = RelayRun(last.start, run.stop, (last.level + run.level) / 2, glitch=(gap > 0) or last.glitch)
        elif action == "append":
            chain.append(run)
        else:
            if len(chain) >= min_runs:
                chains.append(chain)
            # the last run may still open a new chain with this one (e.g. hold level -> relay)
            chain = [chain[-1], run] if action == "restart-pair" else [run]
    if len(chain) >= min_runs:
        chains.append(chain)
    return _without_hold_level(chains, min_runs)


@dataclass(frozen=True, eq=False)
class _FlatRuns:
    """The command cut at its jumps: each piece's first index, one past its last, and mean level;
    which pieces are flat enough to be relay half-periods (``candidates``, indices into the pieces);
    and the smallest jump that counts as a switch (``threshold``, command units)."""

    starts: NDArray[np.intp]
    stops: NDArray[np.intp]
    levels: NDArray[np.float64]
    candidates: NDArray[np.intp]
    threshold: float


def _flat_runs(c: NDArray[np.float64], jump_sigmas: float, min_run_samples: int) -> _FlatRuns:
    """Cut the command at its jumps and keep the flat pieces (step 1 of :func:`find_relay_runs`)."""
    n = c.size
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
    return _FlatRuns(starts, stops, levels, np.flatnonzero(flat), thr)


@dataclass(frozen=True, eq=False)
class _Joiner:
    """How a flat run continues a chain of relay runs (step 2 of :func:`find_relay_runs`)."""

    command: NDArray[np.float64]
    threshold: float
    breaks: NDArray[np.intp]
    min_run_samples: int
    max_glitch_samples: int

    def action(self, chain: list[RelayRun], run: RelayRun) -> tuple[str, int]:
        """``"merge"`` (a false switch inside the last run), ``"append"`` (the next half-period),
        ``"restart-pair"`` (a new chain of the last run and this one) or ``"restart"``; and the gap
        [samples] before ``run`` (shortened to the glitch limit where the relay chatters)."""
        last = chain[-1]
        gap = run.start - last.stop
        crosses_break = bool(np.any((self.breaks > last.start + self.min_run_samples) & (self.breaks <= run.start)))
        step = abs(run.level - last.level)
        ref_jump = abs(last.level - chain[-2].level) if len(chain) >= 2 else step
        tol = 0.1 * max(ref_jump, self.threshold)
        if self._chatters(chain, run, gap, tol):
            gap = self.max_glitch_samples
        joined = gap <= self.max_glitch_samples and not crosses_break
        if joined and step <= tol and len(chain) >= 2:
            # Same level again after a short excursion: a false switch / glitch inside a half-period.
            return "merge", gap
        alternates = len(chain) < 2 or abs(run.level - chain[-2].level) <= tol
        if joined and step > tol and alternates:
            return "append", gap
        return ("restart-pair" if joined and step > 0 else "restart"), gap

    def _chatters(self, chain: list[RelayRun], run: RelayRun, gap: int, tol: float) -> bool:
        """A relay switching on quantised noise chatters: a stretch of 1-2 sample runs at the chain's
        own two levels, up to a half-period long, is still the same relay (the cycles around it are
        dropped as glitches); anything at a third level ends the test."""
        if not (gap > self.max_glitch_samples and len(chain) >= 2 and gap <= max(r.stop - r.start for r in chain)):
            return False
        last = chain[-1]
        gs = self.command[last.stop:run.start]
        return bool((np.minimum(np.abs(gs - last.level), np.abs(gs - chain[-2].level)) <= tol).all())


def _without_hold_level(chains: list[list[RelayRun]], min_runs: int) -> list[list[RelayRun]]:
    """A chain may start with a run of the hold level before the relay began: drop leading runs that
    do not belong to the two alternating levels (step 3 of :func:`find_relay_runs`)."""
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
