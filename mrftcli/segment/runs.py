"""Relay runs in the command and the controller's sample clock (steps 1 and 2 of :mod:`mrftcli.segment`).

* :func:`find_relay_runs` splits the command into chains of flat runs (:class:`RelayRun`) that
  alternate between two levels: the relay stretches.
* :func:`regularise_times` puts jittery receive times back on the controller's sample grid (its
  rate: :func:`mrftcli.io.timing.median_rate_hz`), centred on them (the segmenter's clock);
* :func:`rebuild_send_times` does the same for a receive-stamped topic with the grid moved to the
  earliest arrivals (:class:`SendTimes`: the send times the waveform refinement needs);
  :func:`tick_numbers` numbers the messages for both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import optimize
from scipy.ndimage import maximum_filter1d

__all__ = ["RelayRun", "robust_sigma", "find_relay_runs", "regularise_times", "tick_numbers", "SendTimes",
           "rebuild_send_times"]

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
    dev = x - np.median(x)
    np.abs(dev, out=dev)  # in place, and the median may reorder it: one temporary, not three
    return float(_MAD_TO_SIGMA * np.median(dev, overwrite_input=True))


def find_relay_runs(
    command: np.ndarray,
    *,
    jump_sigmas: float = 8.0,
    min_run_samples: int = 3,
    max_glitch_samples: int = 3,
    min_runs: int = 6,
    breaks: np.ndarray | None = None,
    gaps: np.ndarray | None = None,
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
    gaps : numpy.ndarray, optional
        Sample indices with data absent just before them (a masked or lost stretch of the log): no run
        spans one and no chain continues across one, whatever the levels on either side.

    Returns
    -------
    list of list of RelayRun
        One list of runs per relay stretch, in time order; glitch-absorbing runs have ``glitch``.
    """
    c = np.asarray(command, dtype=float)
    if c.size < 2 * min_run_samples:
        return []
    holes = np.asarray(gaps if gaps is not None else [], dtype=int)
    runs = _flat_runs(c, jump_sigmas, min_run_samples, holes)
    joiner = _Joiner(c, runs.threshold, np.asarray(breaks if breaks is not None else [], dtype=int),
                     min_run_samples, max_glitch_samples, holes)
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


def _flat_runs(c: NDArray[np.float64], jump_sigmas: float, min_run_samples: int,
               gaps: NDArray[np.intp]) -> _FlatRuns:
    """Cut the command at its jumps and at its ``gaps`` (sample indices after absent data) and keep the
    flat pieces (step 1 of :func:`find_relay_runs`)."""
    n = c.size
    d = np.diff(c)
    scale = float(max(np.max(c), -np.min(c))) if n else 1.0  # max |c| without a copy of |c|
    thr = max(jump_sigmas * robust_sigma(d), 1e-9 * (scale + 1e-12))
    np.abs(d, out=d)  # only the steps' sizes from here (in place: 8 bytes a sample on a 14-hour log)
    # A bias inside the command that moves (HEAR's 50-sample median of the PID output) steps by a
    # little at most samples: such steps, under 5 % of the largest change within +-1000 samples (a
    # relay switch nearby), are not switches, or they would split every half-period into short runs.
    local = maximum_filter1d(d, size=2001, mode="nearest")
    local *= _SMALL_STEP
    big = d > thr
    small = big & (d <= local)
    del local
    cut = np.flatnonzero(big & ~small) + 1
    holes = gaps[(gaps > 0) & (gaps < n)]
    if holes.size:
        # the levels on either side of absent data are not one run, even when equal (two tests masked
        # to their windows, each ending and starting at the same relay level)
        cut = np.union1d(cut, holes)
    starts = np.concatenate(([0], cut))
    stops = np.concatenate((cut, [n]))
    lengths = stops - starts
    sums = np.add.reduceat(c, starts)
    levels = sums / lengths
    rng = np.maximum.reduceat(c, starts) - np.minimum.reduceat(c, starts)
    # Jump magnitude on each side of each run; a flat run's spread is small beside them.
    jumps = np.abs(np.diff(levels))
    if holes.size:
        jumps[np.isin(starts[1:], holes)] = np.inf  # no jump measured across absent data: an edge of the data
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
    gaps: NDArray[np.intp]

    def action(self, chain: list[RelayRun], run: RelayRun) -> tuple[str, int]:
        """``"merge"`` (a false switch inside the last run), ``"append"`` (the next half-period),
        ``"restart-pair"`` (a new chain of the last run and this one) or ``"restart"``; and the gap
        [samples] before ``run`` (shortened to the glitch limit where the relay chatters)."""
        last = chain[-1]
        if np.any((self.gaps > last.start) & (self.gaps <= run.start)):
            return "restart", run.start - last.stop  # absent data ends the test: never joins two
        gap = run.start - last.stop
        # a marker up to min_run_samples samples into a run opens the test at that run (a stack logs it a
        # little after the switch that starts the test); into the chain's first relay run (after the hold
        # level) it is the chain's own, published as the relay started
        m = self.min_run_samples
        reach = run.start + (m if len(chain) >= 2 else 0)
        crosses_break = bool(np.any((self.breaks > last.start + m) & (self.breaks <= reach)))
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
    n = tick_numbers(t)
    if n is None:
        return t, False
    return _grid_fit(t, n, max_residual)


def tick_numbers(t: np.ndarray) -> np.ndarray | None:
    """The publisher's tick number of each timestamp (dropped ticks are gaps; the first is 0, or +-1
    when numbered from the clock's phase).

    A clean clock (every interval within 5 % of a whole number of periods) is counted interval by
    interval. A jittery one is numbered from the clock's phase, not by counting intervals (a count
    slips by one where jitter makes an interval look like 0.5 or 1.5 periods): the period is where
    the timestamps' phases t / dt line up best (peak of |mean exp(2 pi i t / dt)|), first on a short
    stretch with a coarse grid, then on all samples with a fine one.

    Parameters
    ----------
    t : numpy.ndarray
        Increasing timestamps [s].

    Returns
    -------
    numpy.ndarray or None
        Increasing tick numbers (float, whole); None for fewer than 8 stamps, no positive median
        interval, or numbers that do not increase (reordered or bunched messages).

    Examples
    --------
    >>> tick_numbers(np.array([0.0, 0.01, 0.02, 0.04, 0.05, 0.06, 0.07, 0.08])).tolist()
    [0.0, 1.0, 2.0, 4.0, 5.0, 6.0, 7.0, 8.0]
    """
    t = np.asarray(t, dtype=float)
    if t.size < 8:
        return None
    steps = np.diff(t)
    dt0 = np.median(steps)
    if not dt0 > 0:
        return None
    # in place: a 14-hour log holds tens of millions of stamps, and each temporary is 8 bytes a stamp
    steps /= dt0
    whole = np.rint(steps)
    if _all_near(steps, whole, 0.05):
        # clean clock (no jitter to speak of): counting intervals cannot slip
        ticks = np.empty(t.size)
        ticks[0] = 0.0
        np.cumsum(np.maximum(whole, 1.0, out=whole), out=ticks[1:])
        return ticks
    del steps, whole
    tr = t - t[0]
    dt = dt0
    sub = np.unique(np.linspace(0, t.size - 1, min(t.size, 400)).astype(int))  # the span matters, not n
    # the coarse search spans +-6 %: the median interval of a jittery topic with a few % of its
    # messages missing is a couple of % long (0-3 ms of lateness, 5 % lost at 200 Hz: +2.2 %)
    for ts, span, m in ((tr[: min(t.size, 200)], 0.06, 241), (tr[sub], 0.0015, 81)):
        cand = dt * (1.0 + np.linspace(-span, span, m))
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
    n: np.ndarray = np.rint((tr - phase) / dt)
    if np.any(np.diff(n) <= 0):
        return None
    return n


@dataclass(frozen=True, eq=False)
class SendTimes:
    """A receive-stamped topic's messages put back on its publisher's tick grid (:func:`rebuild_send_times`).

    Attributes
    ----------
    t : numpy.ndarray
        Send times [s]: ``origin + period * tick`` where rebuilt, else the receive times unchanged.
    rebuilt : bool
        The receive times fit a fixed-rate publisher and ``t`` is its grid.
    period : float
        The publisher's period [s] (NaN when no grid was found).
    lateness : float
        Mean lateness of the arrivals behind the earliest ones [s], removed from the times: the
        grid's origin is set by the earliest arrivals (a message cannot arrive before it was sent).
    spread : float
        Robust std (1.4826 MAD) of the arrivals' lateness about the grid [s] (the transport's
        jitter; 0.37 L for a lateness uniform over 0..L).
    dropped : int
        Ticks without a message.
    reason : str
        Why the times were not rebuilt (empty when they were).
    """

    t: np.ndarray
    rebuilt: bool
    period: float
    lateness: float
    spread: float
    dropped: int
    reason: str = ""

    @property
    def unchanged(self) -> bool:
        """Rebuilt with the logged times kept: they were on the grid already (stamped at the source),
        so the rebuild has nothing to report."""
        return self.rebuilt and self.lateness == 0.0 and not self.dropped

    def describe(self, topic: str) -> str:
        """One line for the output: what was rebuilt and how well the grid fits."""
        if not self.rebuilt:
            return f"receive-stamped {topic} not rebuilt: {self.reason}"
        drops = f", {self.dropped} ticks without a message" if self.dropped else ""
        return (f"receive-stamped {topic} rebuilt on its publisher's {1.0 / self.period:.4g} Hz tick grid "
                f"(arrivals {self.spread * 1e3:.2f} ms std about the grid; {self.lateness * 1e3:.2f} ms of mean "
                f"lateness behind the earliest arrivals removed, those taken as sent on time{drops})")


def rebuild_send_times(t: np.ndarray) -> SendTimes:
    """Rebuild a receive-stamped topic's send times on its publisher's tick grid.

    A fixed-rate publisher sends message j at t0 + n_j dt; the recorder stamps it on arrival, late
    by a random 0..L (L may exceed dt: messages then bunch). One message per tick, in order: the
    tick number is the message's position. Where messages are missing the numbers come from the
    clock's phase instead (:func:`tick_numbers`, for lateness under a period): a dropped message is
    one missing tick, and the numbering runs on through it (for a command as for an output; where a
    switch could sit in the gap, :class:`mrftcli.mrft.waveform.CommandWindow` leaves that tick's
    command unknown). dt and a centre are fitted by least squares, and the grid is moved down to the
    earliest arrivals (no message arrives before it is sent). The numbering is accepted when the
    earliest arrivals of every stretch of messages agree (within a quarter period): a miscounted
    message, or a publisher that is not at a fixed rate, moves them by a period. A constant
    transport delay below the floor is not observable and stays in the times.

    Parameters
    ----------
    t : numpy.ndarray
        Receive times [s], increasing.

    Returns
    -------
    SendTimes

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> sent = 10.0 + 0.005 * np.arange(2000)
    >>> r = rebuild_send_times(sent + rng.uniform(0.0, 0.003, sent.size))
    >>> r.rebuilt, bool(np.max(np.abs(r.t - sent)) < 1e-5)
    (True, True)
    >>> kept = np.delete(np.arange(2000), [700, 1300])
    >>> r = rebuild_send_times(sent[kept] + rng.uniform(0.0, 0.003, kept.size))
    >>> r.rebuilt, r.dropped, bool(np.max(np.abs(r.t - sent[kept])) < 1e-5)
    (True, 2, True)
    """
    t = np.asarray(t, dtype=float)
    if t.size < 8:
        return SendTimes(t, False, float("nan"), 0.0, float("nan"), 0, "fewer than 8 messages")
    fit = _floor_fit(t, np.arange(t.size, dtype=float))
    if fit is None:
        n = tick_numbers(t)
        fit = None if n is None else _floor_fit(t, n - n[0])
    if fit is None:
        return SendTimes(t, False, float("nan"), 0.0, float("nan"), 0,
                         "its stamps are not a fixed-rate publisher's")
    return fit


def _floor_fit(t: np.ndarray, n: np.ndarray) -> SendTimes | None:
    """The grid t0 + dt n through the earliest arrivals, when they agree along the topic (else None).

    The grid is the highest line under every arrival (a linear programme: the support's lower edge,
    which a bounded lateness pins far better than least squares pins the mean's line: a few us
    against 35 us at the ends of 4000 messages with 0-3 ms of lateness).
    """
    # relative to the first stamp: epoch stamps (1.7e9 s) would cost the fit its precision
    tr = t - t[0]
    A = np.vstack([np.ones_like(n), n]).T
    (c0, dt), *_ = np.linalg.lstsq(A, tr, rcond=None)
    if not dt > 0:
        return None
    late = tr - (c0 + dt * n)
    # the earliest arrival of each of up to 20 equal stretches (50 messages at least: a few
    # messages need not hold one that came early)
    parts = max(1, min(20, t.size // 50))
    floors = np.minimum.reduceat(late, np.linspace(0, late.size, parts + 1).astype(int)[:-1])
    if np.ptp(floors) > 0.25 * dt:
        return None
    spread = robust_sigma(late)
    dropped = int(n[-1] - n[0] - (n.size - 1))
    if np.ptp(late) < 1e-5:
        # already on a grid to the stamps' rounding (stamped at the source): kept as logged
        return SendTimes(t, True, float(dt), 0.0, spread, dropped)
    lp = optimize.linprog([-float(n.size), -float(n.sum())], A_ub=A, b_ub=tr, bounds=[(None, None), (None, None)],
                          method="highs")
    t0, period = (float(lp.x[0]), float(lp.x[1])) if lp.success and lp.x[1] > 0 else (c0 + float(np.min(late)), dt)
    grid = t0 + period * n
    return SendTimes(t[0] + grid, True, period, float(np.mean(tr - grid)), spread, dropped)


def _grid_fit(t: np.ndarray, n: np.ndarray, max_residual: float) -> tuple[np.ndarray, bool]:
    """``t0 + dt n`` fitted to the times ``t`` [s] of sample numbers ``n`` by least squares, when every
    time lies within ``max_residual`` periods of it; else ``t`` unchanged (and False).

    The straight line's closed form about the means rather than :func:`numpy.linalg.lstsq` on the
    design matrix [1, n]: the same fit (to rounding) with two work arrays instead of the matrix, its
    copy and the solver's workspace (about 48 bytes a sample on a 14-hour log, benchmarks/bench_large.py).
    """
    n_mean, t_mean = float(n.mean()), float(t.mean())
    dn = n - n_mean
    e = t - t_mean
    dt = float(np.dot(dn, e) / np.dot(dn, dn))
    del e
    dn *= dt  # dn becomes the fit about the mean time
    dn += t_mean
    fit = dn
    if dt > 0 and _max_abs_diff(t, fit) <= max_residual * dt:
        return fit, True
    return t, False


def _all_near(a: np.ndarray, b: np.ndarray, tol: float, block: int = 1 << 20) -> bool:
    """``all(|a - b| < tol)`` in blocks (no full-length temporary)."""
    return all(bool((np.abs(a[i:i + block] - b[i:i + block]) < tol).all()) for i in range(0, a.size, block))


def _max_abs_diff(a: np.ndarray, b: np.ndarray, block: int = 1 << 20) -> float:
    """``max(|a - b|)`` in blocks (no full-length temporary); 0 for empty arrays."""
    return max((float(np.abs(a[i:i + block] - b[i:i + block]).max()) for i in range(0, a.size, block)), default=0.0)
