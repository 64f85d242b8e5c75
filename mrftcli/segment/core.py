"""Find the MRFT tests in a flight log and measure their stable limit cycles.

The segmenter works on the command the MRFT block sent (``FlightLog.command``) and the loop output
(``FlightLog.output``). It is a chain of small pure functions on numpy arrays:

1. **Relay runs** (:func:`find_relay_runs`). The command is split at jumps larger than
   ``jump_sigmas`` times a robust (MAD) scale of its sample-to-sample increments. A *flat run* is a
   stretch of at least ``min_run_samples`` samples whose spread is small beside the jumps that bound
   it. A relay test is a maximal chain of flat runs whose levels alternate between two values
   (``bias + h`` and ``bias - h``). A short run between two runs of the same level (a false switch,
   a glitch) is absorbed and the cycle that holds it is marked ``glitch``; a change of level, a change
   of h, a stretch of normal flight (PID hold, take-off, landing) or a new value on the beta topic ends
   the chain.
2. **Switch instants.** The first sample at the new level. Timestamps inside a test are first put
   back on the controller's sample grid when they fit one (receive-time jitter removed, dropped
   messages kept as gaps; :func:`regularise_times`). A switch after one or two missing command
   samples is placed in the middle of the possible instants (flag ``interp``; its output level is not
   used for beta); after a longer gap its cycles are marked ``gap`` and left out.
3. **Cycles** (-h -> +h switch to the next one). Per cycle: the period, the two half-periods, and a
   smooth model of the output: least squares over one period centred on each half-cycle with a line
   plus harmonics 1..8 of the cycle frequency (:func:`_periodic_fit`; every sample of the period
   takes part except the ones that decided a switch, whose noise is biased by first-passage
   selection). From it: the extrema (a noise-robust peak, not the raw noisy maximum), the amplitude
   (max - min) / 2 about the centre (max + min) / 2, and the *effective beta*: the modelled output at
   each switch instant, relative to the centre, divided by the amplitude. At the -h -> +h switch of
   the MRFT's periodic solution y - centre = -beta a, at the +h -> -h switch y - centre = +beta a
   (``docs/architecture.md``); the mean over the stable cycles is the level the relay actually
   achieved, which a noisy sampled relay moves away from its nominal beta.
4. **Stable limit cycle** (:func:`stable_cycles`). Reference values are the medians of period and
   amplitude over the second half of the test's regular cycles (the limit cycle is established by
   then). A cycle is *consistent* when its period is within ``max(k * sigma_P, 3 dt, 6 % P)`` (capped
   at 15 % of P) of the median and its amplitude within ``max(k * sigma_a, 12 % a)`` (capped at 25 %),
   where sigma is 1.4826 MAD and k = ``mad_k``. The stable cycles are the consistent, regular ones
   after the first cycle of the first run of ``min_consecutive`` consecutive consistent cycles; the
   cycles before (and that first one, which may still be converging) are the start-up transient.
5. **Is it a limit cycle of this output?** (:func:`check_limit_cycle`, stored in
   ``MrftTest.validity``). A relay in the command says nothing about the output: the wrong loop,
   topic or an output buried in noise still yields "cycles". The output must oscillate at the
   relay's frequency above the noise (fundamental amplitude >= 3x the residual noise of the cycle
   fit, >= 50 % of its variance in the fundamental), with a steady phase relative to the relay
   (mean resultant length >= 0.9) that matches what an MRFT at the measured switching level gives a
   plant of eq. (2) (within 0.6 rad of -pi + arcsin beta_eff), and the effective beta must lie in
   (-1, 1) and agree with the nominal one (within 0.25, same sign). Thresholds and their reasons:
   :class:`ValidityCriterion` and docs/usage-analyze.md; :func:`mrftcli.analyze.analyze_flight`
   rejects the failing tests and those whose loop-gain sign disagrees with the others'.

Everything the identification needs comes out as frozen dataclasses: :class:`RelayCycle` and
:class:`MrftTest`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..errors import SegmentationError
from ..io.logtypes import FlightLog
from ..mrft.describing import df_phase

__all__ = [
    "RelayCycle",
    "MrftTest",
    "StabilityCriterion",
    "segment",
    "segment_arrays",
    "find_relay_runs",
    "regularise_times",
    "stable_cycles",
    "estimate_rate_hz",
    "ValidityCriterion",
    "LimitCycleCheck",
    "check_limit_cycle",
    "df_phase",
]

_MAD_TO_SIGMA = 1.4826
_SWITCH_WINDOW = 0.10
_SWITCH_DEG = 4
#: per-cycle waveform model: "fourier" (whole-cycle harmonic fit) or "local" (polynomials)
_CYCLE_MODEL = "fourier"
#: a switch after at most this many missing command samples is interpolated, after more it is a gap
_MAX_INTERP_SAMPLES = 2
_HARMONICS = 8


@dataclass(frozen=True)
class StabilityCriterion:
    """Settings of the stable-limit-cycle criterion (see the module docstring).

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
    """

    mad_k: float = 4.0
    period_floor_samples: float = 3.0
    period_floor_rel: float = 0.06
    period_cap_rel: float = 0.15
    amplitude_floor_rel: float = 0.12
    amplitude_cap_rel: float = 0.25
    min_consecutive: int = 3

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class RelayCycle:
    """One relay cycle: from a -h -> +h switch to the next one.

    Times in seconds; output values in output units, relative to the loop setpoint when it was
    logged (else absolute); the amplitude is in output units.

    Attributes
    ----------
    t_start, t_switch, t_end : float
        The -h -> +h switch that opens the cycle, the +h -> -h switch inside it, the next -h -> +h.
    period, half_period_high, half_period_low : float
        t_end - t_start, time at +h, time at -h [s].
    amplitude : float
        (y_max - y_min) / 2 from local polynomial fits around the extrema [output units].
    centre : float
        (y_max + y_min) / 2 [output units].
    y_max, y_min, t_max, t_min : float
        The fitted extrema and their times.
    y_switch_down, y_switch_up : float
        The smoothed output at the +h -> -h (t_switch) and -h -> +h (t_end) switch instants.
    beta_down, beta_up, beta_effective : float
        (y_switch_down - centre)/a, -(y_switch_up - centre)/a, and their mean: the switching level the
        relay actually achieved in this cycle.
    phase_h1, gain_h1 : float
        Fundamental harmonic of the output relative to that of the relay's square wave over the cycle
        (:func:`_cycle_fundamental`): arg [rad, in (-2 pi, 0]] and modulus [output units per command
        unit]. For a periodic cycle they are arg G(j Omega) and |G(j Omega)| of the loop's plant,
        whatever level the relay switched at; NaN when an instant was interpolated or the fit failed.
    noise_std, h1_fraction, amplitude_h1 : float
        From the same whole-cycle fit (:func:`_cycle_harmonics`): the residual standard deviation
        (the sensor noise) [output units], the share of the de-trended output's mean square at the
        relay's fundamental frequency [-], and the amplitude of that fundamental [output units].
        They feed the limit-cycle validity check (:func:`check_limit_cycle`).
    flags : tuple of str
        ``gap`` (a switch follows more than two dropped command samples), ``interp`` (a switch follows one
        or two dropped samples: its instant is interpolated and its level not used for beta),
        ``glitch`` (a false switch was absorbed),
        ``irregular`` (bad fits), ``transient``, ``outlier`` (fails the criterion).
    stable : bool
        Part of the stable limit cycle.
    """

    t_start: float
    t_switch: float
    t_end: float
    period: float
    half_period_high: float
    half_period_low: float
    amplitude: float
    centre: float
    y_max: float
    y_min: float
    t_max: float
    t_min: float
    y_switch_down: float
    y_switch_up: float
    beta_down: float
    beta_up: float
    beta_effective: float
    flags: tuple[str, ...] = ()
    stable: bool = False
    phase_h1: float = float("nan")
    gain_h1: float = float("nan")
    noise_std: float = float("nan")
    h1_fraction: float = float("nan")
    amplitude_h1: float = float("nan")

    @property
    def frequency_hz(self) -> float:
        """1 / period [Hz]."""
        return 1.0 / self.period

    @property
    def regular(self) -> bool:
        """No gap, glitch or failed fit inside the cycle."""
        return not ({"gap", "glitch", "irregular"} & set(self.flags))

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d["flags"] = list(self.flags)
        d["frequency_hz"] = self.frequency_hz
        return d


@dataclass(frozen=True)
class MrftTest:
    """One MRFT test found in a log.

    Attributes
    ----------
    index : int
        Position in the log (0-based).
    t_start, t_end : float
        First and last command sample of the relay test [s] (the relay's start and stop).
    h, bias : float
        Relay half-height and centre level of the command [command units].
    beta_nominal : float or None
        Beta from the beta topic (last value published before or during the test), else None.
    beta_effective : float
        Mean effective beta over the stable cycles (NaN if there are none).
    beta_effective_std : float
        Standard deviation of the per-cycle effective beta.
    rate_hz : float
        Controller rate estimated from the command timestamps in the test [Hz].
    cycles : tuple of RelayCycle
        Every complete cycle, stable or not.
    criterion : StabilityCriterion
        The criterion used.
    period_median, period_tolerance, amplitude_median, amplitude_tolerance : float
        The reference values and tolerances the criterion applied [s], [output units].
    loop_sign : int
        +1 when the output rises under +h (positive loop gain), -1 otherwise (the output was flipped
        for the cycle analysis; amplitudes are magnitudes).
    setpoint : float or None
        Median setpoint over the test, if logged (output units).
    timestamps_regularised : bool
        Whether the command timestamps were put back on a sample grid.
    n_switches : int
        Relay switches seen in the test.
    notes : tuple of str
        Anything worth telling the user about this test.
    validity : LimitCycleCheck or None
        Whether the output follows this relay as an MRFT limit cycle, with the measured figures
        (:func:`check_limit_cycle`).
    """

    index: int
    t_start: float
    t_end: float
    h: float
    bias: float
    beta_nominal: float | None
    beta_effective: float
    beta_effective_std: float
    rate_hz: float
    cycles: tuple[RelayCycle, ...]
    criterion: StabilityCriterion
    period_median: float
    period_tolerance: float
    amplitude_median: float
    amplitude_tolerance: float
    loop_sign: int = 1
    setpoint: float | None = None
    timestamps_regularised: bool = False
    n_switches: int = 0
    notes: tuple[str, ...] = ()
    validity: "LimitCycleCheck | None" = None

    @property
    def valid(self) -> bool:
        """The output follows this test's relay as an MRFT limit cycle (:func:`check_limit_cycle`)."""
        return self.validity is None or self.validity.ok

    @property
    def stable(self) -> tuple[RelayCycle, ...]:
        """The cycles of the stable limit cycle."""
        return tuple(c for c in self.cycles if c.stable)

    @property
    def n_stable(self) -> int:
        return sum(1 for c in self.cycles if c.stable)

    @property
    def beta(self) -> float:
        """The beta used for identification: the effective one when measured, else the nominal."""
        if np.isfinite(self.beta_effective):
            return float(self.beta_effective)
        return float(self.beta_nominal) if self.beta_nominal is not None else float("nan")

    @property
    def period(self) -> np.ndarray:
        """Per stable cycle period [s]."""
        return np.array([c.period for c in self.stable])

    @property
    def frequency_hz(self) -> np.ndarray:
        """Per stable cycle frequency [Hz]."""
        return 1.0 / self.period

    @property
    def amplitude(self) -> np.ndarray:
        """Per stable cycle output amplitude [output units]."""
        return np.array([c.amplitude for c in self.stable])

    @property
    def frequency_hz_mean(self) -> float:
        """1 / mean period of the stable cycles [Hz] (the test's limit-cycle frequency)."""
        p = self.period
        return float(1.0 / p.mean()) if p.size else float("nan")

    @property
    def amplitude_mean(self) -> float:
        a = self.amplitude
        return float(a.mean()) if a.size else float("nan")

    def to_dict(self, cycles: bool = True) -> dict:
        """JSON-ready summary; ``beta`` is the beta used for identification."""
        p = self.period
        a = self.amplitude
        d = {
            "index": self.index,
            "beta": self.beta,
            "beta_nominal": self.beta_nominal,
            "beta_effective": self.beta_effective,
            "beta_effective_std": self.beta_effective_std,
            "h": self.h,
            "bias": self.bias,
            "rate_hz": self.rate_hz,
            "t_start": self.t_start,
            "t_end": self.t_end,
            "cycles": self.n_stable,
            "cycles_total": len(self.cycles),
            "frequency_hz": self.frequency_hz_mean,
            "frequency_hz_std": float(np.std(1.0 / p, ddof=1)) if p.size > 1 else None,
            "amplitude": self.amplitude_mean,
            "amplitude_std": float(np.std(a, ddof=1)) if a.size > 1 else None,
            "half_period_high": float(np.mean([c.half_period_high for c in self.stable])) if p.size else None,
            "half_period_low": float(np.mean([c.half_period_low for c in self.stable])) if p.size else None,
            "loop_sign": self.loop_sign,
            "setpoint": self.setpoint,
            "timestamps_regularised": self.timestamps_regularised,
            "criterion": {
                **self.criterion.to_dict(),
                "period_median": self.period_median,
                "period_tolerance": self.period_tolerance,
                "amplitude_median": self.amplitude_median,
                "amplitude_tolerance": self.amplitude_tolerance,
            },
            "notes": list(self.notes),
        }
        if self.validity is not None:
            d["validity"] = self.validity.to_dict()
        if cycles:
            d["per_cycle"] = [c.to_dict() for c in self.cycles]
        return d


# --------------------------------------------------------------------------------------------------
# Step 1: relay runs in the command
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Run:
    start: int  # first sample index
    stop: int  # one past the last sample
    level: float
    glitch: bool = False


def _robust_sigma(x: np.ndarray) -> float:
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
) -> list[list[_Run]]:
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
    list of list of _Run
        One list of runs per relay stretch, in time order; glitch-absorbing runs have ``glitch``.
    """
    c = np.asarray(command, dtype=float)
    n = c.size
    if n < 2 * min_run_samples:
        return []
    d = np.diff(c)
    scale = float(np.max(np.abs(c))) if n else 1.0
    thr = max(jump_sigmas * _robust_sigma(d), 1e-9 * (scale + 1e-12))
    cut = np.flatnonzero(np.abs(d) > thr) + 1
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
    flat = (lengths >= min_run_samples) & (rng <= 0.2 * np.minimum(left, right))
    cand = np.flatnonzero(flat)
    break_set = np.asarray(breaks if breaks is not None else [], dtype=int)

    chains: list[list[_Run]] = []
    chain: list[_Run] = []

    def close() -> None:
        if len(chain) >= min_runs:
            chains.append(list(chain))

    for i in cand:
        run = _Run(int(starts[i]), int(stops[i]), float(levels[i]))
        if not chain:
            chain = [run]
            continue
        last = chain[-1]
        gap = run.start - last.stop
        crosses_break = bool(np.any((break_set > last.start + min_run_samples) & (break_set <= run.start)))
        step = abs(run.level - last.level)
        ref_jump = abs(last.level - chain[-2].level) if len(chain) >= 2 else step
        tol = 0.1 * max(ref_jump, thr)
        if gap <= max_glitch_samples and not crosses_break and step <= tol and len(chain) >= 2:
            # Same level again after a short excursion: a false switch / glitch inside a half-period.
            chain[-1] = _Run(last.start, run.stop, (last.level + run.level) / 2, glitch=(gap > 0) or last.glitch)
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


# --------------------------------------------------------------------------------------------------
# Step 2: times
# --------------------------------------------------------------------------------------------------


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
        A = np.vstack([np.ones_like(n), n]).T
        (t0, dt), *_ = np.linalg.lstsq(A, t, rcond=None)
        fit = t0 + dt * n
        if dt > 0 and np.max(np.abs(t - fit)) <= max_residual * dt:
            return fit, True
        return t, False
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
    A = np.vstack([np.ones_like(n), n]).T
    (t0, dt), *_ = np.linalg.lstsq(A, t, rcond=None)
    fit = t0 + dt * n
    if dt > 0 and np.max(np.abs(t - fit)) <= max_residual * dt:
        return fit, True
    return t, False


# --------------------------------------------------------------------------------------------------
# Step 3: per-cycle measurements
# --------------------------------------------------------------------------------------------------


def _local_poly_value(t: np.ndarray, y: np.ndarray, t0: float, half_window: float, deg: int,
                      exclude: float = 0.0) -> float:
    """Value at t0 of a degree-``deg`` least-squares polynomial over |t - t0| <= half_window.

    Samples with |t - t0| < ``exclude`` are left out (first-passage-biased switch samples).
    """
    i0, i1 = np.searchsorted(t, [t0 - half_window, t0 + half_window + 1e-12])
    tt, yy = t[i0:i1] - t0, y[i0:i1]
    if exclude > 0:
        keep = np.abs(tt) >= exclude
        tt, yy = tt[keep], yy[keep]
    if tt.size < deg + 3:
        return float("nan")
    s = half_window
    coef = np.polynomial.polynomial.polyfit(tt / s, yy, deg)
    return float(coef[0])


def _local_extremum(t: np.ndarray, y: np.ndarray, lo: float, hi: float, half_window: float,
                    sign: int) -> tuple[float, float]:
    """Fitted extremum of y in [lo, hi] (sign +1: maximum, -1: minimum) -> (t_ext, y_ext).

    The raw extreme sample only locates the peak; a quartic least-squares fit over +/- half_window
    around it gives the value (the raw maximum of noisy samples is biased by the noise).
    """
    i0, i1 = np.searchsorted(t, [lo, hi])
    if i1 - i0 < 3:
        return float("nan"), float("nan")
    seg = sign * y[i0:i1]
    # locate on a lightly smoothed copy so a single noisy sample cannot move the window much
    k = 5 if seg.size >= 15 else 1
    sm = np.convolve(seg, np.ones(k) / k, mode="same") if k > 1 else seg
    tc = t[i0 + int(np.argmax(sm[k // 2: seg.size - k // 2]) + k // 2)] if k > 1 else t[i0 + int(np.argmax(seg))]
    j0, j1 = np.searchsorted(t, [tc - half_window, tc + half_window + 1e-12])
    tt, yy = t[j0:j1] - tc, sign * y[j0:j1]
    if tt.size < 8:
        return float("nan"), float("nan")
    s = half_window
    coef = np.polynomial.polynomial.polyfit(tt / s, yy, 4)
    grid = np.linspace(-0.7, 0.7, 141)
    vals = np.polynomial.polynomial.polyval(grid, coef)
    j = int(np.argmax(vals))
    return float(tc + grid[j] * s), float(sign * vals[j])


def _periodic_fit(t: np.ndarray, y: np.ndarray, tc: float, P: float, dt: float, t_switch: np.ndarray):
    """Least-squares model of the output over one period centred at ``tc``; returns a callable.

    Model: a line plus harmonics 1..H of 1/P. The output of an MRFT loop has a discontinuous third
    derivative, so its harmonics decay like k^-4 and H = 8 leaves a truncation error near 5e-4 of
    the amplitude. Centring the window on the point of interest keeps it away from the window
    edges, where a cycle that is not exactly periodic (start-up, drift, a sampled relay's jitter)
    would bias the fit. Every sample of the period takes part (a local polynomial around a switch
    uses a tenth of them and is several times noisier at high frequencies) except the samples that
    decided a switch and the one before each: their noise is biased by first-passage selection.
    Returns None when there are too few samples.
    """
    i0, i1 = np.searchsorted(t, [tc - 0.5 * P, tc + 0.5 * P])
    tt = t[i0:i1]
    yy = y[i0:i1]
    j0, j1 = np.searchsorted(t_switch, [tc - 0.5 * P - 2 * dt, tc + 0.5 * P + 2 * dt])
    keep = np.ones(tt.size, bool)
    for ts in t_switch[j0:j1]:
        keep &= ~((tt > ts - 1.5 * dt) & (tt < ts + 0.5 * dt))
    tt, yy = tt[keep], yy[keep]
    H = _HARMONICS
    if tt.size < 2 * (2 * H + 2):
        return None
    w = 2.0 * np.pi / P
    k = np.arange(1, H + 1)

    def basis(xq: np.ndarray) -> np.ndarray:
        a = np.outer(xq, k) * w
        return np.hstack([np.ones((xq.size, 1)), (xq / P)[:, None], np.cos(a), np.sin(a)])

    coef, *_ = np.linalg.lstsq(basis(tt - tc), yy, rcond=None)
    return lambda xq: basis(np.atleast_1d(np.asarray(xq, float))) @ coef


def _fourier_cycle(t: np.ndarray, y: np.ndarray, t_switch: np.ndarray, t0: float, t1: float, t2: float,
                   dt: float):
    """Extrema and switch-instant outputs of one cycle from period-long harmonic fits.

    Returns
    -------
    (t_min, y_min, t_max, y_max, y_down, y_up)
        The fitted minimum (in the +h half) and maximum (in the -h half) and the fitted output at
        the +h -> -h switch t1 and at the closing -h -> +h switch t2; NaNs when a fit fails.
    """
    nan = (float("nan"),) * 6
    P = t2 - t0
    # One period-long fit centred on each half-cycle: the +h half holds the minimum and ends at the
    # +h -> -h switch, the -h half holds the maximum and ends at the closing switch; all four points
    # lie within a quarter period of their window's centre, away from its edges.
    out = []
    vals = []
    for lo, hi, sgn in ((t0, t1, -1.0), (t1, t2, 1.0)):
        tc = 0.5 * (lo + hi)
        f = _periodic_fit(t, y, tc, P, dt, t_switch)
        if f is None:
            return nan
        xs = np.linspace(lo - tc, hi - tc, 201)
        j = int(np.argmax(sgn * f(xs)))
        # refine the extremum on a fine grid around the coarse one
        xf = np.linspace(xs[max(j - 1, 0)], xs[min(j + 1, xs.size - 1)], 41)
        yf = f(xf)
        jj = int(np.argmax(sgn * yf))
        out.append((tc + xf[jj], float(yf[jj])))
        vals.append(float(f(hi - tc)[0]))
    (t_min, y_min), (t_max, y_max) = out
    return float(t_min), y_min, float(t_max), y_max, vals[0], vals[1]


def _cycle_harmonics(t: np.ndarray, y: np.ndarray, t0: float, t1: float, t2: float,
                     h: float) -> tuple[complex, float, float, float]:
    """Fundamental of one cycle and how much of the output it explains (Beyond the paper).

    The relay output is u = +h on [t0, t1) and -h on [t1, t2) (the plant's input between the logged
    switch instants, which lie on the controller's sample grid, so this square wave *is* the
    zero-order-hold command); its complex Fourier coefficient at Omega = 2 pi / P is closed form,
    U1 = (2/P) int u exp(-j Omega t) dt = 2 h (2 - 2 exp(-j Omega (t1 - t0))) / (j Omega P). The
    output's Y1 comes from a least-squares fit over the cycle of a line (the drift of a cycle that
    is not exactly periodic) plus harmonics 1..8. For a periodic response of a linear plant
    Y1 = G(j Omega) U1 exactly, whatever level the relay switched at, so arg(Y1 / U1) measures the
    plant's phase at Omega with the noise of a whole-cycle projection rather than that of a
    switching level. Every sample of the cycle takes part: leaving out the few that decided a switch
    (first-passage-biased noise) made the estimates noisier on the 30-plant sweep, not better.

    The same fit tells whether the output follows the relay at all (:func:`check_limit_cycle`): its
    residual is the sensor noise (the harmonics 1..8 hold the limit cycle to ~5e-4 of its
    amplitude, so the residual is noise whenever the output is a limit cycle of this relay), and
    the fundamental's share of the de-trended variance is close to 1 for an MRFT limit cycle (the
    plant's low-pass filtering of the square wave: 0.985 for a pure integrator, more with the lags)
    and about 2/n for an output that does not oscillate at the relay's frequency.

    Returns
    -------
    (g1, noise_std, h1_fraction, amplitude_h1)
        g1 = Y1 / U1 [output units per command unit]; the residual standard deviation of the fit
        [output units]; |Y1|^2 / 2 over the mean square of the de-trended output [-]; |Y1|
        [output units]. NaNs when there are too few samples.
    """
    nan = float("nan")
    P = t2 - t0
    i0, i1 = np.searchsorted(t, [t0, t2])
    tt, yy = t[i0:i1] - t0, y[i0:i1]
    H = _HARMONICS
    npar = 2 * H + 2
    if tt.size < 2 * npar:
        return complex(nan, nan), nan, nan, nan
    w = 2.0 * np.pi / P
    k = np.arange(1, H + 1)
    arg = np.outer(tt, k) * w
    A = np.hstack([np.ones((tt.size, 1)), (tt / P)[:, None], np.cos(arg), np.sin(arg)])
    coef, *_ = np.linalg.lstsq(A, yy, rcond=None)
    resid = yy - A @ coef
    noise = float(np.sqrt(resid @ resid / (tt.size - npar)))
    detrended = yy - coef[0] - coef[1] * tt / P
    ms = float(detrended @ detrended / tt.size)
    Y1 = complex(coef[2], -coef[2 + H])  # y ~ Re(Y1 exp(j w (t - t0)))
    U1 = 2.0 * h * (2.0 - 2.0 * np.exp(-1j * w * (t1 - t0))) / (1j * w * P)  # (2/P) int u e^{-jwt} dt
    frac = 0.5 * abs(Y1) ** 2 / ms if ms > 0 else nan
    return complex(Y1 / U1), noise, float(frac), float(abs(Y1))


def _cycle_fundamental(t: np.ndarray, y: np.ndarray, t0: float, t1: float, t2: float, h: float) -> complex:
    """Y1 / U1: fundamental of the output over one cycle relative to the relay's (see
    :func:`_cycle_harmonics`) [output units per command unit]; NaN when there are too few samples."""
    return _cycle_harmonics(t, y, t0, t1, t2, h)[0]


def _measure_cycles(
    t_sw: np.ndarray,
    up: np.ndarray,
    flags_sw: list[set],
    t_y: np.ndarray,
    y: np.ndarray,
    dt: float,
    h: float = 1.0,
) -> list[RelayCycle]:
    """Cycles between consecutive -h -> +h switches (``up[k]`` True for a -h -> +h switch)."""
    cycles = []
    ups = np.flatnonzero(up)
    for a, b in zip(ups[:-1], ups[1:]):
        if b - a != 2:  # must be up, down, up
            continue
        t0, t1, t2 = t_sw[a], t_sw[a + 1], t_sw[b]
        P = t2 - t0
        flags = set()
        for k in (a, a + 1, b):
            flags |= flags_sw[k]
        interp_dn = "interp" in flags_sw[a + 1]
        interp_up = "interp" in flags_sw[b]
        if _CYCLE_MODEL == "fourier":
            t_min, y_min, t_max, y_max, y_dn, y_up = _fourier_cycle(t_y, y, t_sw, t0, t1, t2, dt)
        else:
            w_ext = 0.15 * P
            t_min, y_min = _local_extremum(t_y, y, t0, t1, w_ext, -1)
            t_max, y_max = _local_extremum(t_y, y, t1, t2, w_ext, +1)
            w_sw = max(6 * dt, _SWITCH_WINDOW * P)
            y_dn = _local_poly_value(t_y, y, t1, w_sw, _SWITCH_DEG, exclude=1.5 * dt)
            y_up = _local_poly_value(t_y, y, t2, w_sw, _SWITCH_DEG, exclude=1.5 * dt)
        amp = (y_max - y_min) / 2
        centre = (y_max + y_min) / 2
        if not (np.isfinite(amp) and amp > 0 and np.isfinite(y_dn) and np.isfinite(y_up)):
            flags.add("irregular")
            b_dn = b_up = float("nan")
        else:
            # a switch instant interpolated inside a gap is too uncertain for the level
            b_dn = (y_dn - centre) / amp if not interp_dn else float("nan")
            b_up = -(y_up - centre) / amp if not interp_up else float("nan")
            if interp_dn and interp_up:
                flags.add("irregular")
        g1, noise, frac, a1 = _cycle_harmonics(t_y, y, t0, t1, t2, h)
        if interp_dn or interp_up or "gap" in flags:
            g1 = complex(float("nan"), float("nan"))  # the square wave's timing is not known
        ph1 = float(np.angle(g1)) if np.isfinite(g1) else float("nan")
        if ph1 > 0:
            ph1 -= 2.0 * np.pi  # the plant's phase lies in (-2 pi, 0]
        cycles.append(
            RelayCycle(
                t_start=float(t0), t_switch=float(t1), t_end=float(t2), period=float(P),
                half_period_high=float(t1 - t0), half_period_low=float(t2 - t1),
                amplitude=float(amp), centre=float(centre), y_max=float(y_max), y_min=float(y_min),
                t_max=float(t_max), t_min=float(t_min), y_switch_down=float(y_dn), y_switch_up=float(y_up),
                beta_down=float(b_dn), beta_up=float(b_up), beta_effective=float(np.nanmean([b_dn, b_up])) if np.isfinite([b_dn, b_up]).any() else float('nan'),
                flags=tuple(sorted(flags)), phase_h1=ph1, gain_h1=float(abs(g1)) if np.isfinite(g1) else float("nan"),
                noise_std=noise, h1_fraction=frac, amplitude_h1=a1,
            )
        )
    return cycles


# --------------------------------------------------------------------------------------------------
# Step 4: the stable limit cycle
# --------------------------------------------------------------------------------------------------


def stable_cycles(
    period: np.ndarray,
    amplitude: np.ndarray,
    regular: np.ndarray,
    dt: float,
    criterion: StabilityCriterion = StabilityCriterion(),
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Apply the stable-limit-cycle criterion (module docstring, step 4).

    Parameters
    ----------
    period, amplitude : numpy.ndarray
        Per-cycle period [s] and amplitude [output units].
    regular : numpy.ndarray of bool
        Cycles without gaps/glitches/failed fits; only these can be stable.
    dt : float
        Controller sample period [s].
    criterion : StabilityCriterion

    Returns
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
    sP, sa = _robust_sigma(P[ref]), _robust_sigma(a[ref])
    c = criterion
    tolP = min(max(c.mad_k * sP, c.period_floor_samples * dt, c.period_floor_rel * Pm), c.period_cap_rel * Pm)
    tola = min(max(c.mad_k * sa, c.amplitude_floor_rel * am), c.amplitude_cap_rel * am)
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
    info.update(period_median=Pm, period_tolerance=tolP, amplitude_median=am, amplitude_tolerance=tola)
    return stable, consistent, info


# --------------------------------------------------------------------------------------------------
# Step 5: is it a limit cycle of this output at all?
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ValidityCriterion:
    """Thresholds of the limit-cycle validity check (:func:`check_limit_cycle`; docs/usage-analyze.md).

    Attributes
    ----------
    min_snr : float
        Lowest ratio of the output's amplitude at the relay frequency to the noise standard deviation
        (medians over the cycles). An output that does not follow the relay gives about sqrt(2/n),
        0.1-0.3 for n = 40-200 samples per cycle; an MRFT whose amplitude is below ~3 noise standard
        deviations switches on the noise and has no limit cycle of its own. 3 keeps a valid test at
        10x the noise with a wide margin.
    min_h1_fraction : float
        Lowest share of the de-trended output's mean square at the relay's fundamental. A limit cycle
        of eq. (2) holds 0.985 or more without noise (the triangle wave of a pure integrator) and
        still 0.8 at 3x the noise; an output that does not oscillate at the relay's frequency holds
        about 2/n (0.01-0.05).
    min_phase_coherence : float
        Lowest mean resultant length R = |mean exp(j phi_k)| of the per-cycle fundamental phases
        relative to the relay (1: the same phase in every cycle; random phases give ~1/sqrt(N)).
        0.9 is a circular standard deviation of 26 deg; a valid test at 10x the noise scatters by
        about 1 deg.
    phase_tolerance : float
        Largest |arg G(j Omega) - (-pi + arcsin beta_eff)| [rad]. For every plant of eq. (2) the
        exact (LPRS) limit cycle's fundamental phase lies within 0.33 rad of this describing-function
        value (checked over Tp Omega in [1e-4, 20], Td Omega in [1e-3, 1e3], |beta| <= 0.999), i.e.
        in (-3 pi/2, -pi/2) for |beta| <= 0.95; 0.6 rad adds a margin for the measurement of beta_eff.
    max_beta_mismatch : float
        Largest |beta_eff - beta_nominal| when a nominal beta is logged. Sampling and noise move the
        switching level by a few hundredths (0.01-0.03 on the sample logs); 0.25 is a gross mismatch.
    beta_sign_floor : float
        Opposite signs of beta_eff and beta_nominal are a mismatch when both exceed this in magnitude.
    """

    min_snr: float = 3.0
    min_h1_fraction: float = 0.5
    min_phase_coherence: float = 0.9
    phase_tolerance: float = 0.6
    max_beta_mismatch: float = 0.25
    beta_sign_floor: float = 0.1

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class LimitCycleCheck:
    """The figures of the validity check of one test and what failed (:func:`check_limit_cycle`).

    Attributes
    ----------
    n_cycles : int
        Cycles the figures come from (the stable ones, else the regular ones).
    amplitude, amplitude_h1, noise_std : float
        Median cycle amplitude, median amplitude of the fundamental, median residual noise standard
        deviation of the cycle fits [output units].
    snr : float
        amplitude_h1 / noise_std [-].
    h1_fraction : float
        Median share of the de-trended output's mean square at the relay's fundamental [-].
    phase_coherence : float
        Mean resultant length of the per-cycle fundamental phases [-].
    phase : float
        Circular mean of the per-cycle phases arg(Y1/U1) [rad, in (-2 pi, 0]].
    phase_expected : float
        -pi + arcsin(beta_effective) [rad] (:func:`df_phase`).
    beta_effective, beta_nominal : float or None
        The switching level measured, and the one logged.
    failed : tuple of str
        Short codes of the failed criteria: ``snr``, ``h1_fraction``, ``phase_coherence``, ``phase``,
        ``beta_range``, ``beta_mismatch``, ``no_cycles``.
    reasons : tuple of str
        One sentence per failed criterion, with the figure and the threshold.
    criterion : ValidityCriterion
    """

    n_cycles: int
    amplitude: float
    amplitude_h1: float
    noise_std: float
    snr: float
    h1_fraction: float
    phase_coherence: float
    phase: float
    phase_expected: float
    beta_effective: float
    beta_nominal: float | None
    failed: tuple[str, ...]
    reasons: tuple[str, ...]
    criterion: ValidityCriterion = ValidityCriterion()

    @property
    def ok(self) -> bool:
        return not self.failed

    @property
    def follows_relay(self) -> bool:
        """False when the output shows no oscillation at the relay frequency at all (SNR or share)."""
        return not ({"snr", "h1_fraction", "no_cycles"} & set(self.failed))

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "criterion"}
        d["failed"] = list(self.failed)
        d["reasons"] = list(self.reasons)
        d["ok"] = self.ok
        d["thresholds"] = self.criterion.to_dict()
        return d


def _wrap(x: float) -> float:
    return float((x + np.pi) % (2.0 * np.pi) - np.pi)


def check_limit_cycle(
    cycles: tuple[RelayCycle, ...] | list[RelayCycle],
    beta_effective: float,
    beta_nominal: float | None = None,
    criterion: ValidityCriterion = ValidityCriterion(),
) -> LimitCycleCheck:
    """Is the output an MRFT limit cycle of this relay? (Beyond the paper; docs/usage-analyze.md.)

    Before a test's cycles are used, the output must (1) oscillate at the relay's frequency:
    the amplitude of its fundamental over the residual noise of the per-cycle harmonic fit
    (``min_snr``) and the share of its variance at the fundamental (``min_h1_fraction``); (2) be
    switched by the relay: the fundamental's phase relative to the relay's square wave is the same
    in every cycle (``min_phase_coherence``) and is the one an MRFT at the measured switching level
    gives a plant of eq. (2), arg G(j Omega) ~ -pi + arcsin(beta_eff) (``phase_tolerance``); the
    effective beta lies in (-1, 1) and agrees with the logged nominal beta (``max_beta_mismatch``,
    ``beta_sign_floor``). Each test's figures are medians over its stable cycles (the regular ones
    when none is stable).

    Parameters
    ----------
    cycles : sequence of RelayCycle
        All cycles of the test.
    beta_effective : float
        The test's mean effective beta (NaN if not measured).
    beta_nominal : float or None
        The logged beta, if any.
    criterion : ValidityCriterion

    Returns
    -------
    LimitCycleCheck
    """
    c = criterion
    use = [cy for cy in cycles if cy.stable]
    if len(use) < 2:
        use = [cy for cy in cycles if cy.regular]
    nan = float("nan")

    def med(name: str) -> float:
        v = np.array([getattr(cy, name) for cy in use], float)
        v = v[np.isfinite(v)]
        return float(np.median(v)) if v.size else nan

    amp, a1, noise, frac = med("amplitude"), med("amplitude_h1"), med("noise_std"), med("h1_fraction")
    snr = a1 / noise if noise > 0 else (float("inf") if a1 > 0 else nan)
    ph = np.array([cy.phase_h1 for cy in use], float)
    ph = ph[np.isfinite(ph)]
    if ph.size:
        z = np.exp(1j * ph).mean()
        R, phase = float(abs(z)), float(np.angle(z))
        phase = phase - 2.0 * np.pi if phase > 0 else phase
    else:
        R = phase = nan
    be = float(beta_effective)
    expected = float(df_phase(be)) if np.isfinite(be) and abs(be) < 1 else nan
    failed, reasons = [], []

    def fail(code: str, text: str) -> None:
        failed.append(code)
        reasons.append(text)

    if not use:
        fail("no_cycles", "no regular relay cycle to measure")
    else:
        if not snr >= c.min_snr:
            fail("snr", f"output amplitude at the relay frequency is {snr:.2g}x the noise (need {c.min_snr:g}x)")
        if not frac >= c.min_h1_fraction:
            fail("h1_fraction", f"fraction of the output's variance at the relay frequency {frac:.2f} "
                                f"(need {c.min_h1_fraction:g})")
        if ph.size >= 2 and not R >= c.min_phase_coherence:
            fail("phase_coherence", f"the output's phase relative to the relay wanders from cycle to cycle "
                                    f"(coherence {R:.2f}, need {c.min_phase_coherence:g})")
        if np.isfinite(be) and abs(be) >= 1:  # NaN (no stable cycle) is the stability criterion's business
            fail("beta_range", f"effective beta {be:.3g} outside (-1, 1)")
        elif np.isfinite(phase) and abs(_wrap(phase - expected)) > c.phase_tolerance:
            fail("phase", f"the output lags the relay by {-np.degrees(phase):.0f} deg, where an MRFT at beta "
                          f"{be:.2f} gives {-np.degrees(expected):.0f} +/- {np.degrees(c.phase_tolerance):.0f} deg")
        if beta_nominal is not None and np.isfinite(be):
            bn = float(beta_nominal)
            opposite = bn * be < 0 and min(abs(bn), abs(be)) >= c.beta_sign_floor
            if abs(be - bn) > c.max_beta_mismatch or opposite:
                fail("beta_mismatch", f"the relay switched at beta {be:+.2f} on this output, not the nominal "
                                      f"{bn:+g}")
    return LimitCycleCheck(
        n_cycles=len(use), amplitude=amp, amplitude_h1=a1, noise_std=noise, snr=float(snr), h1_fraction=frac,
        phase_coherence=R, phase=phase, phase_expected=expected, beta_effective=be, beta_nominal=beta_nominal,
        failed=tuple(failed), reasons=tuple(reasons), criterion=c,
    )


# --------------------------------------------------------------------------------------------------
# The whole chain
# --------------------------------------------------------------------------------------------------


def segment_arrays(
    t_cmd: np.ndarray,
    command: np.ndarray,
    t_y: np.ndarray,
    y: np.ndarray,
    *,
    beta_t: np.ndarray | None = None,
    beta_v: np.ndarray | None = None,
    t_sp: np.ndarray | None = None,
    setpoint: np.ndarray | None = None,
    criterion: StabilityCriterion = StabilityCriterion(),
    min_runs: int = 6,
    validity: ValidityCriterion = ValidityCriterion(),
) -> list[MrftTest]:
    """Find the MRFT tests in command/output arrays (see the module docstring).

    Parameters
    ----------
    t_cmd, command : numpy.ndarray
        Command timestamps [s] (increasing) and values [command units].
    t_y, y : numpy.ndarray
        Output timestamps [s] (increasing) and values [output units].
    beta_t, beta_v : numpy.ndarray, optional
        Beta topic messages (time [s], value).
    t_sp, setpoint : numpy.ndarray, optional
        Setpoint series; when given, outputs are measured relative to it.
    criterion : StabilityCriterion
    min_runs : int
        Fewest relay half-periods for a stretch to count as a test.
    validity : ValidityCriterion
        Thresholds of the limit-cycle validity check stored in ``MrftTest.validity``.

    Returns
    -------
    list of MrftTest
        Possibly with tests that have no stable cycle; empty when no relay stretch exists.
    """
    t_cmd = np.asarray(t_cmd, float)
    command = np.asarray(command, float)
    t_y = np.asarray(t_y, float)
    y = np.asarray(y, float)
    ok = np.isfinite(t_cmd) & np.isfinite(command)
    t_cmd, command = t_cmd[ok], command[ok]
    ok = np.isfinite(t_y) & np.isfinite(y)
    t_y, y = t_y[ok], y[ok]
    breaks = None
    if beta_t is not None and len(beta_t):
        breaks = np.searchsorted(t_cmd, np.asarray(beta_t, float))
    chains = find_relay_runs(command, breaks=breaks, min_runs=min_runs)
    rate_all = estimate_rate_hz(t_cmd)

    tests: list[MrftTest] = []
    prev_end = -np.inf
    for chain in chains:
        i0, i1 = chain[0].start, chain[-1].stop
        # Regularise the command times locally (a margin of a few samples around the test).
        j0, j1 = max(i0 - 4, 0), min(i1 + 4, t_cmd.size)
        t_loc, regularised = regularise_times(t_cmd[j0:j1])
        tc = np.array(t_cmd, copy=True)
        tc[j0:j1] = t_loc
        dt_nom = float(np.median(np.diff(t_cmd[j0:j1])))
        rate = 1.0 / dt_nom if dt_nom > 0 else rate_all

        levels = np.array([r.level for r in chain])
        lv_a, lv_b = float(np.median(levels[0::2])), float(np.median(levels[1::2]))
        hi_is_even = lv_a > lv_b
        hi, lo = max(lv_a, lv_b), min(lv_a, lv_b)
        h, bias = (hi - lo) / 2.0, (hi + lo) / 2.0

        # Switches: the first sample of every run after the first one.
        t_sw = np.array([tc[r.start] for r in chain[1:]])
        up = np.array([((k + 1) % 2 == 0) == hi_is_even for k in range(len(chain) - 1)])
        flags_sw: list[set] = []
        for k, r in enumerate(chain[1:]):
            f = set()
            prev = chain[k]
            if r.start - prev.stop > 1:
                f.add("glitch")  # several samples between the levels: the switch instant is not clean
            missing = int(round((tc[r.start] - tc[r.start - 1]) / dt_nom)) - 1 if r.start > 0 else 0
            if 1 <= missing <= _MAX_INTERP_SAMPLES:
                # The switch happened at one of the missing sample instants or at the first sample
                # seen at the new level: take the middle of those (error within +/- (missing+1)/2
                # samples, unbiased). The output at this switch is not used for beta.
                t_sw[k] = 0.5 * (tc[r.start - 1] + dt_nom + tc[r.start])
                f.add("interp")
            elif missing > _MAX_INTERP_SAMPLES:
                f.add("gap")
            if prev.glitch:
                f.add("glitch")
            flags_sw.append(f)

        # Output in the test window (the first to the last switch, with a margin)
        t_a, t_b = t_sw[0], t_sw[-1]
        t_first, t_last = float(tc[chain[0].start]), float(tc[chain[-1].stop - 1])
        m0, m1 = np.searchsorted(t_y, [t_a - 1.0, t_b + 1.0])
        ty, yy = t_y[m0:m1], y[m0:m1]
        if ty.size > 8:
            ty, _ = regularise_times(ty)
        sp_val = None
        if t_sp is not None and setpoint is not None and len(t_sp):
            sp_in = np.asarray(setpoint, float)[(np.asarray(t_sp) >= t_a) & (np.asarray(t_sp) <= t_b)]
            if sp_in.size:
                sp_val = float(np.median(sp_in))
                yy = yy - np.interp(ty, np.asarray(t_sp, float), np.asarray(setpoint, float))
        # Loop sign: with a positive loop gain the output is lower on average while the relay is +h
        # (the output lags the relay by more than 90 degrees for every beta in (-1, 1)).
        cmd_at_y = np.interp(ty, tc, command)
        hi_mask = cmd_at_y > bias
        sign = 1
        if hi_mask.any() and (~hi_mask).any() and yy[hi_mask].mean() > yy[~hi_mask].mean():
            sign = -1
        cycles = _measure_cycles(t_sw, up, flags_sw, ty, sign * yy, 1.0 / rate, h)
        notes: list[str] = []
        if sign < 0:
            notes.append("the output falls under +h (negative loop gain); amplitudes are magnitudes")
        P = np.array([c.period for c in cycles])
        A = np.array([c.amplitude for c in cycles])
        reg = np.array([c.regular for c in cycles], bool)
        stable, consistent, info = stable_cycles(P, A, reg, 1.0 / rate, criterion)
        final = []
        for k, c in enumerate(cycles):
            fl = set(c.flags)
            if not consistent[k] and c.regular:
                fl.add("outlier")
            if consistent[k] and not stable[k]:
                fl.add("transient")
            final.append(_replace(c, flags=tuple(sorted(fl)), stable=bool(stable[k])))
        be = np.array([c.beta_effective for c in final if c.stable])
        be = be[np.isfinite(be)]
        beta_nom = None
        if beta_t is not None and len(beta_t):
            bt = np.asarray(beta_t, float)
            sel = np.flatnonzero((bt > prev_end) & (bt <= t_b))
            if sel.size:
                beta_nom = float(np.asarray(beta_v, float)[sel[-1]])
        n_interp = sum("interp" in c.flags for c in final)
        if n_interp:
            notes.append(f"{n_interp} cycle(s) with a switch after 1-2 missing command samples (instant interpolated)")
        n_gap = sum("gap" in c.flags for c in final)
        n_glitch = sum("glitch" in c.flags for c in final)
        if n_gap:
            notes.append(f"{n_gap} cycle(s) dropped: command messages missing at a switch")
        if n_glitch:
            notes.append(f"{n_glitch} cycle(s) dropped: false switch / glitch in the command")
        tests.append(
            MrftTest(
                index=len(tests), t_start=t_first, t_end=t_last, h=float(h), bias=float(bias),
                beta_nominal=beta_nom,
                beta_effective=float(be.mean()) if be.size else float("nan"),
                beta_effective_std=float(be.std(ddof=1)) if be.size > 1 else float("nan"),
                rate_hz=float(rate), cycles=tuple(final), criterion=criterion,
                period_median=info["period_median"], period_tolerance=info["period_tolerance"],
                amplitude_median=info["amplitude_median"], amplitude_tolerance=info["amplitude_tolerance"],
                loop_sign=sign, setpoint=sp_val, timestamps_regularised=regularised,
                n_switches=len(t_sw), notes=tuple(notes),
                validity=check_limit_cycle(final, float(be.mean()) if be.size else float("nan"), beta_nom,
                                           validity),
            )
        )
        prev_end = t_b
    return tests


def _replace(c: RelayCycle, **kw) -> RelayCycle:
    from dataclasses import replace

    return replace(c, **kw)


def segment(
    flight: FlightLog,
    *,
    criterion: StabilityCriterion = StabilityCriterion(),
    min_runs: int = 6,
    validity: ValidityCriterion = ValidityCriterion(),
) -> list[MrftTest]:
    """Find the MRFT tests in a flight log and measure their cycles.

    Parameters
    ----------
    flight : FlightLog
        Command, output and optional beta/setpoint series (time index in seconds).
    criterion : StabilityCriterion
        Stable-limit-cycle settings.
    min_runs : int
        Fewest relay half-periods for a stretch of switching to count as a test.
    validity : ValidityCriterion
        Thresholds of the limit-cycle validity check (``MrftTest.validity``).

    Returns
    -------
    list of MrftTest
        All tests found, in time order (some may have no stable cycle).

    Raises
    ------
    SegmentationError
        When the command never switches between two levels (no relay test at all).
    """
    t_c, c = flight.command.t, flight.command.values
    t_y, y = flight.output.t, flight.output.values
    if t_c.size < 10 or t_y.size < 10:
        raise SegmentationError(
            f"{flight.path}: too few samples (command {t_c.size}, output {t_y.size}) to look for MRFT tests"
        )
    kw = {}
    if flight.beta is not None and len(flight.beta):
        kw["beta_t"], kw["beta_v"] = flight.beta.t, flight.beta.values
    if flight.setpoint is not None and len(flight.setpoint):
        kw["t_sp"], kw["setpoint"] = flight.setpoint.t, flight.setpoint.values
    tests = segment_arrays(t_c, c, t_y, y, criterion=criterion, min_runs=min_runs, validity=validity, **kw)
    if not tests:
        span = f"{t_c[-1] - t_c[0]:.1f} s long"
        raise SegmentationError(
            f"{flight.path}: no MRFT relay test in the command ({t_c.size} samples, {span}): it never "
            f"switches back and forth between two levels for {min_runs} or more half-periods; check "
            "--command-topic"
        )
    return tests
