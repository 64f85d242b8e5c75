"""Tests logged below the controller's rate: switch instants and cycles from the vernier of many cycles.

PX4 runs its MRFT at 50 Hz and logs the loop at 10 Hz: a 2 Hz limit cycle gets 5 logged samples, a
half-period 2-3. One cycle says little, but the test says much more (issue 24, part 3):

* **Switch instants on the controller's ticks** (:func:`switch_ticks`). The relay switches at a
  controller tick; the logged sample before a switch shows the old level and the one after it the
  new level, so the switch is one of the ticks in between (5 at 50 / 10 Hz). Every half-period is
  a whole number of ticks and nearly the same from cycle to cycle, while the logging instants
  slide along the cycle (unless a period is a multiple of the logging period): the brackets of
  many switches intersect, as on a vernier scale. The tick sequence through every bracket whose
  half-periods are closest to their means (least squares, a dynamic programme over the few
  candidates) is the switch sequence; where the logging locks to the cycle the ticks are
  ambiguous by a common shift and the bracket's middle is taken (unbiased, as before).
* **The output folded over the test** (:func:`measure_folded`). With the switch instants known,
  every output sample has a known phase in its cycle; folded over the test's cycles the samples
  fill the cycle at many phases, and one harmonic series (up to 8 harmonics, as many as the
  distinct phases carry and the cycles left out in turn confirm: :func:`fold_harmonics`) is the
  cycle's waveform: its extrema, its fundamental and its level at the
  switches. Each cycle is then measured against that waveform with three numbers from its own 4-6
  samples (level, scale, phase shift), so its amplitude and phase scatter as the cycle does: the
  analysis's bootstrap over cycles sees the data's own spread.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ..mrft.harmonics import harmonic_basis
from .records import RelayCycle

__all__ = ["TickSwitches", "switch_ticks", "refine_by_waveform", "FoldedWaveform", "fold_waveform", "fold_harmonics",
           "fold_amplitudes", "measure_folded"]

FloatArray = NDArray[np.float64]

#: fewest logged output samples per cycle a sub-sampled test is measured from (level, scale and
#: phase of the folded waveform, and one sample to spare)
MIN_LOGGED_PER_CYCLE = 4
#: most candidate ticks per switch (a bracket wider than this is a logging gap: its switch is left out)
_MAX_CANDIDATES = 16
#: weight of a candidate's distance from its bracket's middle [per tick^2]: decides only between
#: sequences the half-periods cannot tell apart (a logging rate locked to the cycle)
_TIE_BREAK = 1e-2
#: a half-period's squared deviation from its mean counts up to this [tick^2]: a start-up cycle
#: (half-periods several ticks longer) costs the same wherever its switches are, so it cannot pull
#: the steady cycles' switches off their places
_CAP = 2.25
#: switches on either side of a half-period that set its expected length (:func:`_half_periods`)
_WINDOW = 6
#: harmonics of the folded waveform (as the per-cycle fits of a well-sampled test)
_HARMONICS = 8


@dataclass(frozen=True, eq=False)
class TickSwitches:
    """The switch instants of one test on the controller's ticks (:func:`switch_ticks`).

    Attributes
    ----------
    t : numpy.ndarray
        Switch instants [s]: the controller tick at which the relay took its new level.
    ticks : numpy.ndarray
        Their tick numbers from the first switch's bracket (int).
    half_period_ticks : tuple of float
        The mean half-period after an even-numbered and after an odd-numbered switch [ticks] (NaN
        with fewer than 3 switches).
    scatter_ticks : float
        RMS deviation of the half-periods from those means [ticks] (0: a strictly periodic relay).
    locked : bool
        The logging instants do not slide along the cycle: the even-numbered switches (or the odd
        ones) can move together within their brackets without changing a half-period's fit (a
        period that is a whole number of logging periods).
    room : tuple of tuple of int
        How many ticks the even-numbered and the odd-numbered switches can move down and up
        together and stay in their brackets (the shifts :meth:`shifted` takes); ((0, 0), (0, 0))
        when the vernier pins them.
    ts : float
        The controller's period [s].
    """

    t: FloatArray
    ticks: NDArray[np.int64]
    half_period_ticks: tuple[float, float]
    scatter_ticks: float
    locked: bool
    room: tuple[tuple[int, int], tuple[int, int]] = ((0, 0), (0, 0))
    ts: float = 0.0
    lo: NDArray[np.int64] | None = None
    hi: NDArray[np.int64] | None = None

    def period_error(self) -> float:
        """A measured period's error [s] at about 95 %: the difference of two switches, each placed
        to within ``scatter_ticks`` (the half-periods' RMS deviation from their local means, which
        bounds how far the vernier can tell a switch from its neighbours'), at two standard
        deviations: 2 sqrt(2) scatter ticks; 0 for a strictly periodic relay (every switch pinned).
        """
        return float(2.0 * np.sqrt(2.0) * self.scatter_ticks * self.ts)

    def shifts(self) -> list[tuple[int, int]]:
        """Every (even, odd) shift [ticks] within ``room``."""
        (e0, e1), (o0, o1) = self.room
        return [(me, mo) for me in range(-e0, e1 + 1) for mo in range(-o0, o1 + 1)]

    def shifted(self, even: int, odd: int, *, inside: bool = True) -> FloatArray:
        """The instants [s] with the even-numbered switches moved by ``even`` ticks and the odd ones by
        ``odd`` (``inside``: only within ``room``; False: anywhere, for a level one tick beyond)."""
        if inside and (even, odd) not in self.shifts():
            raise ValueError(f"a shift of ({even}, {odd}) ticks leaves the brackets (room {self.room})")
        m = np.where(np.arange(self.t.size) % 2 == 0, even, odd)
        return np.asarray(self.t + m * self.ts, dtype=float)


def switch_ticks(t_before: FloatArray, t_after: FloatArray, ts: float) -> TickSwitches:
    """The relay's switch ticks inside the logging brackets, from the vernier of many switches.

    Parameters
    ----------
    t_before, t_after : numpy.ndarray
        Per switch, the time of the last logged sample at the old level and of the first at the new
        one [s] (both on the controller's ticks: the logger stamps a sample with its tick).
    ts : float
        The controller's period [s].

    Returns
    -------
    TickSwitches

    Examples
    --------
    A relay at 50 Hz with half-periods of 13 ticks, logged every 5th tick:

    >>> ts = 0.02
    >>> true = 3 + 13 * np.arange(20)
    >>> after = 5 * np.ceil(true / 5)
    >>> sw = switch_ticks((after - 5) * ts, after * ts, ts)
    >>> np.round(sw.half_period_ticks, 6).tolist(), sw.locked
    ([13.0, 13.0], False)
    >>> bool(np.allclose(sw.t, true * ts))  # every switch on its tick, though each bracket holds 5
    True
    """
    origin = float(t_after[0])
    lo = np.rint((np.asarray(t_before) - origin) / ts).astype(np.int64) + 1
    hi = np.rint((np.asarray(t_after) - origin) / ts).astype(np.int64)
    lo = np.maximum(np.minimum(lo, hi), hi - _MAX_CANDIDATES + 1)
    mid = np.asarray(0.5 * (lo + hi), dtype=np.float64)
    H = _half_periods(mid)
    ticks = mid.astype(np.int64)
    for _ in range(3):  # the half-periods from the sequence, the sequence from the half-periods
        ticks = _best_sequence(lo, hi, H)
        H = _half_periods(ticks.astype(float))
    d = np.diff(ticks) - H
    scatter = float(np.sqrt(np.mean(np.minimum(d ** 2, _CAP)))) if d.size else 0.0
    # locked: the whole sequence can move together inside the brackets of its steady switches
    # (beyond the first few, a start-up transient's)
    steady = np.arange(ticks.size) >= min(4, max(ticks.size - 6, 0))
    room = (_room(ticks, lo, hi, steady, 0), _room(ticks, lo, hi, steady, 1))
    locked = bool(sum(room[0]) + sum(room[1]) > 0 and ticks.size > 2)
    return TickSwitches(np.asarray(origin + ticks * ts, dtype=np.float64), ticks,
                        (float(np.mean(H[0::2])), float(np.mean(H[1::2]))) if H.size > 1 else (np.nan, np.nan),
                        scatter, locked, room, ts, lo, hi)


def refine_by_waveform(sw: TickSwitches, up: NDArray[np.bool_], t_y: FloatArray, y: FloatArray,
                       sweeps: int = 2) -> FloatArray:
    """The switch instants [s] moved, one at a time within its bracket, to where the output folded
    over the cycles fits one waveform best (least residual of :func:`fold_waveform`).

    A wrong tick puts its cycle's samples at wrong phases, off the waveform by the output's slope
    times a tick; the half-periods alone cannot see that where the orbit wanders by a tick or more
    from cycle to cycle. A common shift of a locked grid does not change the fit (decided elsewhere).
    """
    if sw.lo is None or sw.hi is None:
        return sw.t
    ticks = sw.ticks.copy()
    origin = float(sw.t[0] - sw.ticks[0] * sw.ts)

    ups = np.flatnonzero(up)
    tri = [(a, b) for a, b in zip(ups[:-1], ups[1:]) if b - a == 2]
    if len(tri) < 2:
        return sw.t

    def bounds(tk: NDArray[np.int64]) -> tuple[FloatArray, FloatArray]:
        t_sw = origin + tk * sw.ts
        return np.array([t_sw[a] for a, _ in tri]), np.array([t_sw[b] for _, b in tri])

    # the harmonics decided once, at the vernier's ticks: residuals of folds with different
    # harmonics would not compare
    H = fold_harmonics(t_y, y, *bounds(ticks))

    def residual(tk: NDArray[np.int64]) -> float:
        fit = _fold_fit(t_y, y, *bounds(tk), harmonics=H)  # the fit's residual only: no waveform's extrema
        return fit[3] if fit is not None else float("inf")

    best = residual(ticks)
    for _ in range(sweeps):
        moved = False
        for j in range(ticks.size):
            for c in range(int(sw.lo[j]), int(sw.hi[j]) + 1):
                if c == ticks[j]:
                    continue
                trial = ticks.copy()
                trial[j] = c
                r = residual(trial)
                if r < best:
                    best, ticks, moved = r, trial, True
        if not moved:
            break
    return np.asarray(origin + ticks * sw.ts, dtype=float)


def _room(ticks: NDArray[np.int64], lo: NDArray[np.int64], hi: NDArray[np.int64], steady: NDArray[np.bool_],
          parity: int) -> tuple[int, int]:
    """How far [ticks] the steady switches of one parity can move down and up together inside their brackets."""
    sel = steady & (np.arange(ticks.size) % 2 == parity)
    if not sel.any():
        return (0, 0)
    return int(np.min((ticks - lo)[sel])), int(np.min((hi - ticks)[sel]))


def _half_periods(s: FloatArray) -> FloatArray:
    """The half-period after each switch [ticks] (one fewer than ``s``), from a least-squares fit
    s_j = a + b j + c (-1)^j over the :data:`_WINDOW` switches on either side: the half-period after
    an even-numbered switch b - 2c, after an odd one b + 2c. Local, because a sampled relay can move
    to another orbit during a test (PX4's sample flight: 44-tick cycles, then 48)."""
    n = s.size
    if n < 3:
        d = float(np.mean(np.diff(s))) if n > 1 else 0.0
        return np.full(max(n - 1, 0), d)
    j = np.arange(n, dtype=float)
    A = np.column_stack([np.ones_like(j), j, (-1.0) ** j])
    out = np.empty(n - 1)
    for i in range(n - 1):
        lo, hi = max(0, min(i - _WINDOW, n - 2 * _WINDOW - 1)), min(n, max(i + _WINDOW + 2, 2 * _WINDOW + 1))
        (_, b, c), *_ = np.linalg.lstsq(A[lo:hi], s[lo:hi], rcond=None)
        out[i] = b - 2 * c * (-1.0) ** i
    return out


def _best_sequence(lo: NDArray[np.int64], hi: NDArray[np.int64], H: FloatArray) -> NDArray[np.int64]:
    """The ticks, one in each bracket [lo, hi], whose half-periods are closest to ``H`` (least
    squares; a Viterbi pass over the candidates)."""
    n = lo.size
    cands = [np.arange(lo[j], hi[j] + 1) for j in range(n)]
    centre = 0.5 * (lo + hi)
    cost = _TIE_BREAK * (cands[0] - centre[0]) ** 2
    back: list[NDArray[np.intp]] = []
    for j in range(1, n):
        step = cands[j][:, None] - cands[j - 1][None, :] - H[j - 1]
        total = cost[None, :] + np.minimum(step ** 2, _CAP)
        arg = np.argmin(total, axis=1)
        back.append(arg)
        cost = total[np.arange(cands[j].size), arg] + _TIE_BREAK * (cands[j] - centre[j]) ** 2
    k = int(np.argmin(cost))
    out = np.empty(n, dtype=np.int64)
    for j in range(n - 1, -1, -1):
        out[j] = cands[j][k]
        if j > 0:
            k = int(back[j - 1][k])
    return out


@dataclass(frozen=True, eq=False)
class FoldedWaveform:
    """A test's limit cycle from its output folded over the cycles (:func:`fold_waveform`).

    The waveform is w(phi) = sum_k Re(W_k exp(2 pi j k phi)), phi the phase in the cycle from its
    -h -> +h switch (0..1), zero mean; the output of cycle i is about c_i + s_i w(phi - d_i).

    Attributes
    ----------
    coef : numpy.ndarray
        Complex W_1..W_H [output units].
    amplitude : float
        (max - min) / 2 of w [output units].
    centre : float
        (max + min) / 2 of w (w has zero mean; its extrema need not be symmetric) [output units].
    phi_max, phi_min : float
        Phases of w's maximum and minimum [cycles].
    noise_std : float
        Residual standard deviation of the folded fit [output units].
    h1_fraction : float
        0.5 |W_1|^2 over the mean square of the de-trended samples [-].
    distinct_phases : int
        Distinct phases the samples fell on (the logging instants' vernier) [-].
    """

    coef: NDArray[np.complex128]
    amplitude: float
    centre: float
    phi_max: float
    phi_min: float
    noise_std: float
    h1_fraction: float
    distinct_phases: int

    def __call__(self, phi: FloatArray) -> FloatArray:
        """w at the phases ``phi`` [cycles] [output units]."""
        k = np.arange(1, self.coef.size + 1)
        e = np.exp(2j * np.pi * np.multiply.outer(np.asarray(phi, float), k))
        return np.asarray((e @ self.coef).real, dtype=float)

    def slope(self, phi: FloatArray) -> FloatArray:
        """dw / dphi at ``phi`` [output units per cycle]."""
        k = np.arange(1, self.coef.size + 1)
        e = np.exp(2j * np.pi * np.multiply.outer(np.asarray(phi, float), k))
        return np.asarray((e @ (2j * np.pi * k * self.coef)).real, dtype=float)


def _phases(t: FloatArray, t0: FloatArray, t2: FloatArray) -> tuple[FloatArray, NDArray[np.intp]]:
    """Each sample's phase in its cycle [0, 1) and its cycle's index (-1: in no cycle)."""
    k = np.searchsorted(t0, t, side="right") - 1
    inside = (k >= 0) & (t < t2[np.clip(k, 0, None)])
    k = np.where(inside, k, -1)
    kk = np.clip(k, 0, None)
    return np.where(inside, (t - t0[kk]) / (t2[kk] - t0[kk]), np.nan), k


def fold_waveform(t: FloatArray, y: FloatArray, t0: FloatArray, t2: FloatArray,
                  harmonics: int | None = None) -> FoldedWaveform | None:
    """The output's waveform over the cycles [t0_i, t2_i) folded at their phases.

    Least squares over every sample in a cycle: a line in time (the level's drift over the test)
    plus harmonics 1..H of the phase, H as many as the distinct phases carry (:func:`_fold_h_max`),
    at least 1 and at most 8, or fewer when
    ``harmonics`` says so (:func:`fold_harmonics`). None when the samples fall on fewer than 4
    distinct phases.
    """
    fit = _fold_fit(t, y, t0, t2, harmonics)
    if fit is None:
        return None
    A, yy, sol, noise_std, distinct = fit
    H = (sol.size - 2) // 2
    coef = sol[2:2 + H] - 1j * sol[2 + H:]
    w = FoldedWaveform(coef, 0.0, 0.0, 0.0, 0.0, noise_std, float("nan"), distinct)
    grid = np.linspace(0.0, 1.0, 2001)
    wg = w(grid)
    detrended = yy - A[:, :2] @ sol[:2]
    ms = float(detrended @ detrended / yy.size)
    return FoldedWaveform(coef, float(0.5 * (wg.max() - wg.min())), float(0.5 * (wg.max() + wg.min())),
                          float(grid[np.argmax(wg)]), float(grid[np.argmin(wg)]), w.noise_std,
                          float(0.5 * abs(coef[0]) ** 2 / ms) if ms > 0 else float("nan"), distinct)


def _fold_fit(t: FloatArray, y: FloatArray, t0: FloatArray, t2: FloatArray, harmonics: int | None
              ) -> tuple[FloatArray, FloatArray, FloatArray, float, int] | None:
    """The fold's least squares (:func:`fold_waveform`): design matrix, the samples in a cycle
    [output units], the solution, the residual standard deviation [output units] and the distinct
    phases; None under 4 distinct phases."""
    phi, k = _phases(t, t0, t2)
    sel = k >= 0
    tt, yy, ph = t[sel], y[sel], phi[sel]
    distinct = int(np.unique(np.round(ph, 3)).size)
    if distinct < MIN_LOGGED_PER_CYCLE:
        return None
    H = _fold_h_max(distinct)
    if harmonics is not None:
        H = int(min(H, max(1, harmonics)))
    A = _fold_design(tt, ph, H)
    sol, *_ = np.linalg.lstsq(A, yy, rcond=None)
    resid = yy - A @ sol
    dof = max(yy.size - A.shape[1], 1)
    return A, yy, np.asarray(sol, dtype=np.float64), float(np.sqrt(resid @ resid / dof)), distinct


def _fold_h_max(distinct: int) -> int:
    """Most harmonics [-] a fold over ``distinct`` phases carries: the line and 2 H coefficients with
    a phase to spare, at most :data:`_HARMONICS` (:func:`fold_harmonics` picks among them).

    The fold's limit is its distinct phases, not its samples per cycle: every cycle repeats them, so
    a grid locked to a 1.2 s cycle (12 phases, 10 Hz) carries 4 harmonics, where the per-cycle rule
    (:func:`~mrftcli.segment.cycles.harmonics_for`, twice over its 12 samples) allowed 2: with one
    harmonic the near-parabolic output of an integrating plant read its peak as its fundamental,
    32 / pi^3 = 1.032 of it, and K 2-3 % long, outside its interval (issue 24 part 3).
    """
    return int(min(_HARMONICS, max(1, (distinct - 3) // 2)))


def _fold_design(t: FloatArray, phi: FloatArray, H: int) -> FloatArray:
    """The fold's design matrix: [1, time scaled to the span (the level's drift), cos k phi (k = 1..H),
    sin k phi (k = 1..H)]."""
    x = (t - t.mean()) / max(float(np.ptp(t)), 1e-9)
    basis = harmonic_basis(phi, 1.0, H)  # [1, phi, cos k..., sin k...]
    return np.column_stack([np.ones_like(x), x, basis[:, 2:]])


def fold_harmonics(t: FloatArray, y: FloatArray, t0: FloatArray, t2: FloatArray) -> int:
    """The harmonics [-] a fold over the cycles [t0_i, t2_i) carries: the number that best predicts
    each cycle's samples from the fold of the others (leave one cycle out).

    The distinct phases of a sliding logging grid allow 8 (:func:`fold_waveform`); an orbit that
    wanders by a tick or more from cycle to cycle (a small relay height among noise) has each cycle
    off the common waveform in its own way, and 8 harmonics over 5 samples a cycle then fit those
    deviations: the fold rings at its extrema, the amplitude is read long and the level at the
    switches 0.1-0.4 short of the relay's beta (the test refused as not switching at its nominal
    beta). A cycle left out keeps its own deviation, so its prediction error grows once the
    harmonics start fitting the others'. A periodic orbit keeps its harmonics. Fewer than 3
    cycles: the distinct phases decide alone.
    """
    errors, h_max = _loo_errors(t, y, t0, t2)
    return h_max if errors is None else int(np.argmin(errors.sum(axis=0))) + 1


def fold_amplitudes(t: FloatArray, y: FloatArray, t0: FloatArray, t2: FloatArray) -> FloatArray:
    """The fold's amplitude [output units] at every harmonic count the leave-one-cycle-out
    criterion of :func:`fold_harmonics` cannot tell from its choice (the chosen one first).

    The choice is a statistic of the same cycles, not a known: with a few cycles, or an orbit that
    wanders, one harmonic and three predict the cycles left out about equally well while their
    amplitudes differ by the waveform's shape (the fundamental of a near-parabola is 1.032 of its
    peak). A count is indistinguishable when its excess prediction error over the chosen one,
    paired by cycle, is within two standard errors of zero (a t-test over the cycles at about 95
    %); the spread of these amplitudes is a systematic error of the test's amplitude, common to its
    cycles (:func:`mrftcli.analyze.estimate.widen_for_orbits` draws it per test). Empty when the
    samples do not fill the cycle; the choice alone with under 3 cycles.
    """
    errors, h_max = _loo_errors(t, y, t0, t2)
    best = h_max if errors is None else int(np.argmin(errors.sum(axis=0))) + 1
    counts = [best]
    if errors is not None:
        d = errors - errors[:, [best - 1]]  # (cycles, counts): excess error of each count, per cycle
        se = d.std(axis=0, ddof=1) / np.sqrt(d.shape[0])
        counts += [H + 1 for H in range(h_max) if H + 1 != best and d[:, H].mean() <= 2.0 * se[H]]
    amps = [w.amplitude for w in (fold_waveform(t, y, t0, t2, H) for H in counts) if w is not None]
    return np.asarray(amps, dtype=np.float64)


def _loo_errors(t: FloatArray, y: FloatArray, t0: FloatArray, t2: FloatArray) -> tuple[FloatArray | None, int]:
    """Per cycle (rows) and harmonic count 1..H (columns), the squared error [output units^2] of
    predicting the cycle's samples from the fold of the others, and the most harmonics H the
    distinct phases carry; None (no comparison) under 3 cycles or with H = 1."""
    phi, k = _phases(t, t0, t2)
    sel = k >= 0
    tt, yy, ph, kk = t[sel], y[sel], phi[sel], k[sel]
    h_max = _fold_h_max(int(np.unique(np.round(ph, 3)).size))
    cycles = np.unique(kk)
    if cycles.size < 3 or h_max <= 1:
        return None, h_max
    A = _fold_design(tt, ph, h_max)
    errors = np.zeros((cycles.size, h_max))
    for j, i in enumerate(cycles):
        out = kk == i
        for H in range(1, h_max + 1):
            cols = np.r_[0:2 + H, 2 + h_max:2 + h_max + H]  # the line and harmonics 1..H (cosines, sines)
            sol, *_ = np.linalg.lstsq(A[~out][:, cols], yy[~out], rcond=None)
            r = yy[out] - A[out][:, cols] @ sol
            errors[j, H - 1] = float(r @ r)
    return errors, h_max


def _cycle_fit(w: FoldedWaveform, ph: FloatArray, yy: FloatArray) -> tuple[float, float, float] | None:
    """Level c, scale s and phase shift d [cycles] of one cycle's samples against ``w``:
    y ~ c + s w(phi - d), linearised in d (y ~ c + s w - s d w'). None for under 4 samples or s <= 0."""
    if yy.size < MIN_LOGGED_PER_CYCLE:
        return None
    A = np.column_stack([np.ones_like(ph), w(ph), -w.slope(ph)])
    (c, s, sd), *_ = np.linalg.lstsq(A, yy, rcond=None)
    if not s > 0:
        return None
    return float(c), float(s), float(sd / s)


def measure_folded(t_sw: FloatArray, up: NDArray[np.bool_], flags_sw: list[set[str]], t_y: FloatArray,
                   y: FloatArray, h: float, fold: NDArray[np.bool_] | None = None) -> list[RelayCycle]:
    """The cycles of a sub-sampled test, each measured against the test's folded waveform.

    Parameters
    ----------
    t_sw : numpy.ndarray
        Switch instants [s] (on the controller's ticks: :func:`switch_ticks`).
    up : numpy.ndarray of bool
        True at the -h -> +h switches.
    flags_sw : list of set of str
        Per switch: ``interp``, ``gap``, ``glitch`` (see :class:`~mrftcli.segment.records.RelayCycle`).
    t_y, y : numpy.ndarray
        Output times [s] and values [output units], relative to the setpoint and signed so that +h
        raises them.
    h : float
        Relay half-height [command units].
    fold : numpy.ndarray of bool, optional
        Per cycle (up-down-up triple, in order): folded into the waveform (the stable limit cycle,
        once known: a start-up cycle's larger swing would distort it); None: the regular cycles.

    Returns
    -------
    list of RelayCycle
        One per up-down-up triple of switches, not yet marked stable; all ``irregular`` when the
        samples do not fill the cycle (:func:`fold_waveform` returns None).
    """
    ups = np.flatnonzero(up)
    triples = [(a, b) for a, b in zip(ups[:-1], ups[1:]) if b - a == 2]
    if not triples:
        return []
    flags = [set().union(flags_sw[a], flags_sw[a + 1], flags_sw[b]) for a, b in triples]
    t0 = np.array([t_sw[a] for a, _ in triples])
    t1 = np.array([t_sw[a + 1] for a, _ in triples])
    t2 = np.array([t_sw[b] for _, b in triples])
    use = np.array([not ({"gap", "glitch"} & f) for f in flags]) if fold is None else np.asarray(fold, bool)
    w = fold_waveform(t_y, y, t0[use], t2[use], fold_harmonics(t_y, y, t0[use], t2[use])) if use.sum() >= 2 else None
    phi, k = _phases(t_y, t0, t2)
    if w is not None:
        # the noise about each folded cycle's own fit, not about the fold: an orbit's cycle-to-cycle
        # deviation is the limit cycle's, and the validity check's SNR is against the sensor noise
        # (the well-sampled path's per-cycle fits have it too)
        w = replace(w, noise_std=_cycle_noise(w, phi, k, y, np.flatnonzero(use)))
    cycles = [_folded_cycle(w, phi[k == i], y[k == i], t0[i], t1[i], t2[i], h, flags[i]) for i in range(t0.size)]
    if w is not None and not _samples_reach(w, cycles, phi, k, y, np.flatnonzero(use)):
        # the fold claims extrema that none of the samples shows: the cycles are not measured
        return [replace(c, flags=tuple(sorted(set(c.flags) | {"irregular"}))) for c in cycles]
    return cycles


#: most the folded cycles' mean amplitude may exceed the largest half-swing of one cycle's
#: samples [-] where the logging instants slide over the cycle (the samples then come within a few
#: % of both extrema; well-measured tests were at 0.6-1.05 of it, mis-folded ones at 1.14-1.47)
_REACH = 1.1
#: distinct phases from which the samples are taken to fill the cycle (a sliding logging grid)
_FILLED = 12


def _samples_reach(w: FoldedWaveform, cycles: list[RelayCycle], phi: FloatArray, k: NDArray[np.intp],
                   y: FloatArray, folded: NDArray[np.intp]) -> bool:
    """Do the samples reach the amplitude measured from the fold (within :data:`_REACH`)?

    Where the switches are placed a few ticks off over an orbit that wanders (5-7 samples a cycle),
    or a test moves from one orbit to another, the fold is of mis-aligned cycles and rings: the
    amplitude read 20-45 % long while the level at the switches still passed the validity check.
    Over a sliding grid (:data:`_FILLED` distinct phases or more) some sample comes close to each
    extremum, so the largest half-swing of one cycle's samples bounds the amplitude.
    A locked grid (4 samples a cycle at the same phases) may miss the extrema by 30 %: not judged.
    """
    if w.distinct_phases < _FILLED:
        return True
    swings, amps = [], []
    for i in folded:
        yy = y[k == i]
        if yy.size and np.isfinite(cycles[i].amplitude):
            swings.append(0.5 * float(np.ptp(yy)))
            amps.append(cycles[i].amplitude)
    return not amps or bool(np.mean(amps) <= _REACH * max(swings))


def _cycle_noise(w: FoldedWaveform, phi: FloatArray, k: NDArray[np.intp], y: FloatArray,
                 cycles: NDArray[np.intp]) -> float:
    """The residual standard deviation [output units] of the cycles' own fits against ``w``
    (:func:`_cycle_fit`: level, scale, phase shift each), pooled; the fold's when none fits."""
    rss, dof = 0.0, 0
    for i in cycles:
        ph, yy = phi[k == i], y[k == i]
        if yy.size <= 3:
            continue
        A = np.column_stack([np.ones_like(ph), w(ph), -w.slope(ph)])
        sol, *_ = np.linalg.lstsq(A, yy, rcond=None)
        r = yy - A @ sol
        rss += float(r @ r)
        dof += yy.size - 3
    return float(np.sqrt(rss / dof)) if dof > 0 else w.noise_std


def _folded_cycle(w: FoldedWaveform | None, ph: FloatArray, yy: FloatArray, t0: float, t1: float, t2: float,
                  h: float, flags: set[str]) -> RelayCycle:
    """One cycle's record from its fit against the folded waveform ``w`` (NaNs and ``irregular`` without one)."""
    P = t2 - t0
    nan = float("nan")
    fit = _cycle_fit(w, ph, yy) if w is not None else None
    if w is None or fit is None:
        return RelayCycle(t_start=t0, t_switch=t1, t_end=t2, period=P, half_period_high=t1 - t0,
                          half_period_low=t2 - t1, amplitude=nan, centre=nan, y_max=nan, y_min=nan, t_max=nan,
                          t_min=nan, y_switch_down=nan, y_switch_up=nan, beta_down=nan, beta_up=nan,
                          beta_effective=nan, flags=tuple(sorted(flags | {"irregular"})))
    c, s, d = fit
    amp, centre = s * w.amplitude, c + s * w.centre
    phi1 = (t1 - t0) / P
    y_dn = c + s * float(w(np.array([phi1 - d]))[0])
    y_up = c + s * float(w(np.array([-d]))[0])
    b_dn = (y_dn - centre) / amp if "interp" not in flags else nan
    b_up = -(y_up - centre) / amp if "interp" not in flags else nan
    # the fundamental against the relay's square wave (+h on [0, phi1), -h after): Y1 / U1
    y1 = s * complex(w.coef[0]) * np.exp(-2j * np.pi * d)
    u1 = 2.0 * h * (2.0 - 2.0 * np.exp(-2j * np.pi * phi1)) / (2j * np.pi)
    g1 = y1 / u1
    ph1 = float(np.angle(g1))
    if ph1 > 0:
        ph1 -= 2.0 * np.pi  # the plant's phase lies in (-2 pi, 0]
    be = [b for b in (b_dn, b_up) if np.isfinite(b)]
    return RelayCycle(
        t_start=t0, t_switch=t1, t_end=t2, period=P, half_period_high=t1 - t0, half_period_low=t2 - t1,
        amplitude=amp, centre=centre, y_max=centre + amp, y_min=centre - amp,
        t_max=t0 + P * ((w.phi_max + d) % 1.0), t_min=t0 + P * ((w.phi_min + d) % 1.0),
        y_switch_down=y_dn, y_switch_up=y_up, beta_down=b_dn, beta_up=b_up,
        beta_effective=float(np.mean(be)) if be else nan, flags=tuple(sorted(flags)),
        phase_h1=ph1, gain_h1=float(abs(g1)), noise_std=w.noise_std, h1_fraction=w.h1_fraction,
        amplitude_h1=float(abs(y1)))
