"""Per-cycle measurement (step 3 of :mod:`mrftcli.segment`).

A cycle runs from a -h -> +h switch to the next one. Per cycle: the period, the two half-periods,
and a smooth model of the output: least squares over one period centred on each half-cycle with a
line plus harmonics 1..8 of the cycle frequency (:func:`mrftcli.mrft.harmonics.fit_harmonics`;
every sample of the period takes part except the ones that decided a switch, whose noise is biased
by first-passage selection). From it (:func:`cycle_extrema`): the extrema (a noise-robust peak, not
the raw noisy maximum), the amplitude (max - min) / 2 about the centre (max + min) / 2, and the
*effective beta*: the modelled output at each switch instant, relative to the centre, divided by
the amplitude. From a fit over the whole cycle (:func:`cycle_fundamental`): the output's
fundamental relative to the relay's, the noise, and the share of the output at the relay frequency.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..mrft.harmonics import HarmonicFit, fit_harmonics
from .records import RelayCycle

__all__ = ["CycleFundamental", "cycle_extrema", "cycle_fundamental", "measure_cycles", "harmonics_for",
           "samples_between", "ON_BOUND"]

#: harmonics of the per-cycle fits (truncation error near 5e-4 of the amplitude)
_HARMONICS = 8
#: largest output magnitude a cycle is fitted at: above ~1e150 the sums of squares overflow float64
_LARGEST = 1e150
#: fewest samples per period a cycle is measured from (a line and one harmonic, twice over)
MIN_SAMPLES_PER_CYCLE = 8
#: a sample within this share of a sample period of a cycle's bound lies on it [-]: the switch
#: instants and the output's times come from two separate grid fits (or one grid's rounding), so a
#: sample on a bound is 1e-14 s either side of it by chance, and counting it or not moved Td by 0.4 %
ON_BOUND = 1e-2


def samples_between(t: np.ndarray, lo: float, hi: float, dt: float) -> tuple[int, int]:
    """Indices ``i0, i1`` of the samples in the half-open span [``lo``, ``hi``) of times ``t`` [s].

    A sample within :data:`ON_BOUND` sample periods ``dt`` [s] of a bound lies on it: it belongs to
    the span it opens and not to the one it closes, whatever the rounding of the times.

    Examples
    --------
    >>> t = np.arange(10) * 0.1
    >>> samples_between(t, 0.3 + 1e-14, 0.6 - 1e-14, 0.1), samples_between(t, 0.3 - 1e-14, 0.6 + 1e-14, 0.1)
    ((3, 6), (3, 6))
    """
    tol = ON_BOUND * dt if dt > 0 else 0.0
    i0, i1 = np.searchsorted(t, [lo - tol, hi - tol])
    return int(i0), int(i1)


def harmonics_for(n_samples: int) -> int:
    """Harmonics a period-long fit of ``n_samples`` samples can carry (0: too few to measure).

    Eight when there are at least 2 (2 * 8 + 2) = 36 samples (the fit's parameters twice over), else
    as many as keep that ratio: a 10 Hz log of a 1 Hz cycle (10 samples) gets a line and harmonics
    1..1, enough for the fundamental (what identification uses) and for the extrema of the smooth,
    low-pass filtered output, at a truncation error that grows to a few % of the amplitude (the
    interval widens through the cycle-to-cycle scatter it adds).

    Examples
    --------
    >>> [harmonics_for(n) for n in (7, 8, 12, 20, 35, 36, 200)]
    [0, 1, 2, 4, 7, 8, 8]
    """
    return int(min(_HARMONICS, max(0, (n_samples // 2 - 2) // 2)))


class CycleFundamental(NamedTuple):
    """The output's fundamental over one cycle (:func:`cycle_fundamental`).

    Attributes
    ----------
    response : complex
        Y1 / U1, the output's fundamental over the relay square wave's [output units per command
        unit]: G(j Omega) for a periodic cycle of a linear plant.
    noise_std : float
        Residual standard deviation of the fit [output units].
    h1_fraction : float
        |Y1|^2 / 2 over the mean square of the de-trended output [-].
    amplitude_h1 : float
        |Y1| [output units].
    """

    response: complex
    noise_std: float
    h1_fraction: float
    amplitude_h1: float


def _periodic_fit(t: np.ndarray, y: np.ndarray, tc: float, P: float, dt: float,
                  t_switch: np.ndarray, few_samples: bool = False) -> HarmonicFit | None:
    """Least-squares model of the output over one period centred at ``tc`` (x = t - tc).

    Model: a line plus harmonics 1..H of 1/P (:func:`mrftcli.mrft.harmonics.fit_harmonics`). The output of an MRFT loop has a discontinuous third
    derivative, so its harmonics decay like k^-4 and H = 8 leaves a truncation error near 5e-4 of
    the amplitude. Centring the window on the point of interest keeps it away from the window
    edges, where a cycle that is not exactly periodic (start-up, drift, a sampled relay's jitter)
    would bias the fit. Every sample of the period takes part (a local polynomial around a switch
    uses a tenth of them and is several times noisier at high frequencies) except the samples that
    decided a switch and the one before each: their noise is biased by first-passage selection.
    Returns None when there are too few samples.
    """
    i0, i1 = samples_between(t, tc - 0.5 * P, tc + 0.5 * P, dt)
    tt = t[i0:i1]
    yy = y[i0:i1]
    j0, j1 = np.searchsorted(t_switch, [tc - 0.5 * P - 2 * dt, tc + 0.5 * P + 2 * dt])
    keep = np.ones(tt.size, bool)
    for ts in t_switch[j0:j1]:
        keep &= ~((tt > ts - 1.5 * dt) & (tt < ts + 0.5 * dt))
    H = _HARMONICS
    if keep.sum() >= 2 * (2 * H + 2):
        return fit_harmonics(tt[keep] - tc, yy[keep], P, H)
    if not few_samples:
        return None
    # few samples per cycle: every sample counts (at a low logging rate the logged samples are not
    # the ones that decided a switch anyway), with fewer harmonics
    H = harmonics_for(tt.size)
    if H < 1:
        return None
    return fit_harmonics(tt - tc, yy, P, H)


def cycle_extrema(t: np.ndarray, y: np.ndarray, t_switch: np.ndarray, t0: float, t1: float, t2: float,
                  dt: float, few_samples: bool = False) -> tuple[float, float, float, float, float, float]:
    """Extrema and switch-instant outputs of one cycle from period-long harmonic fits.

    ``few_samples``: the test is logged with fewer than 36 samples per cycle, so a fit with fewer
    harmonics (:func:`harmonics_for`) is used where the full one has too few samples; otherwise such
    a cycle (a start-up transient of a well-sampled test) is not measured.

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
        f = _periodic_fit(t, y, tc, P, dt, t_switch, few_samples)
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


def cycle_fundamental(t: np.ndarray, y: np.ndarray, t0: float, t1: float, t2: float,
                      h: float, few_samples: bool = True, dt: float | None = None) -> CycleFundamental:
    """Fundamental of one cycle and how much of the output it explains (Beyond the paper).

    The relay output is u = +h on [t0, t1) and -h on [t1, t2) (the plant's input between the logged
    switch instants, which lie on the controller's sample grid, so this square wave *is* the
    zero-order-hold command); its complex Fourier coefficient at Omega = 2 pi / P is closed form,
    U1 = (2/P) int u exp(-j Omega t) dt = 2 h (2 - 2 exp(-j Omega (t1 - t0))) / (j Omega P). The
    output's Y1 comes from a least-squares fit over the cycle of a line (the drift of a cycle that
    is not exactly periodic) plus harmonics 1..8 (:func:`mrftcli.mrft.harmonics.fit_harmonics`). For a periodic response of a linear plant
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

    Parameters
    ----------
    t, y : numpy.ndarray
        Output sample times [s] (increasing) and values [output units].
    t0, t1, t2 : float
        The cycle's -h -> +h switch, its +h -> -h switch and the closing -h -> +h switch [s].
    h : float
        Relay half-height [command units].
    few_samples : bool
        Fewer harmonics below 36 samples (:func:`harmonics_for`); False keeps eight and returns NaNs.
    dt : float, optional
        Sample period [s]: a sample within :data:`ON_BOUND` periods of ``t0`` or ``t2`` lies on that
        bound (:func:`samples_between`); None: within a millionth of the cycle's period ``t2 - t0``.

    Returns
    -------
    CycleFundamental
        NaNs when there are fewer than :data:`MIN_SAMPLES_PER_CYCLE` samples in the cycle (fewer
        harmonics below 36: :func:`harmonics_for`).

    Examples
    --------
    A pure integrator's triangle wave, y = int u: G(j Omega) = 1 / (j Omega), phase -pi/2.

    >>> P = 1.0
    >>> t = np.arange(400) * P / 400
    >>> y = np.where(t < P / 2, t, P - t)  # integral of the +1 / -1 square wave
    >>> g = cycle_fundamental(t, y, 0.0, P / 2, P, 1.0)
    >>> round(float(np.angle(g.response)), 2), round(abs(g.response) * 2 * np.pi / P, 3), g.h1_fraction > 0.98
    (-1.57, 1.0, True)
    """
    nan = float("nan")
    P = t2 - t0
    i0, i1 = samples_between(t, t0, t2, dt if dt else 1e-6 * P / ON_BOUND)
    tt, yy = t[i0:i1] - t0, y[i0:i1]
    H = harmonics_for(tt.size) if few_samples else _HARMONICS
    npar = 2 * H + 2
    if H < 1 or tt.size < 2 * npar:
        return CycleFundamental(complex(nan, nan), nan, nan, nan)
    if not np.isfinite(yy).all() or np.abs(yy).max() > _LARGEST:
        return CycleFundamental(complex(nan, nan), nan, nan, nan)  # squares would overflow float64
    fit = fit_harmonics(tt, yy, P, H)
    coef, resid = fit.coef, fit.residual
    noise = float(np.sqrt(resid @ resid / (tt.size - npar)))
    detrended = yy - coef[0] - coef[1] * tt / P
    ms = float(detrended @ detrended / tt.size)
    Y1 = complex(fit.harmonics[0])  # y ~ Re(Y1 exp(j w (t - t0)))
    w = 2.0 * np.pi / P
    U1 = 2.0 * h * (2.0 - 2.0 * np.exp(-1j * w * (t1 - t0))) / (1j * w * P)  # (2/P) int u e^{-jwt} dt
    frac = 0.5 * abs(Y1) ** 2 / ms if ms > 0 else nan
    return CycleFundamental(complex(Y1 / U1), noise, float(frac), float(abs(Y1)))


def measure_cycles(
    t_sw: np.ndarray,
    up: np.ndarray,
    flags_sw: list[set[str]],
    t_y: np.ndarray,
    y: np.ndarray,
    dt: float,
    h: float = 1.0,
    few_samples: bool = False,
) -> list[RelayCycle]:
    """Measure the cycles between consecutive -h -> +h switches (step 3 of :mod:`mrftcli.segment`).

    Parameters
    ----------
    t_sw : numpy.ndarray
        Switch instants [s], in time order.
    up : numpy.ndarray of bool
        True where the switch is -h -> +h.
    flags_sw : list of set of str
        Per switch: ``interp``, ``gap``, ``glitch`` (see :class:`~mrftcli.segment.records.RelayCycle`).
    t_y, y : numpy.ndarray
        Output times [s] and values, relative to the setpoint and signed so that +h raises them.
    dt : float
        Controller sample period [s].
    h : float
        Relay half-height [command units].
    few_samples : bool
        The test has fewer than 36 output samples per cycle: measure cycles from 8 samples up with
        fewer harmonics (:func:`harmonics_for`).

    Returns
    -------
    list of RelayCycle
        One per up-down-up triple of switches, not yet marked stable.
    """
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
        t_min, y_min, t_max, y_max, y_dn, y_up = cycle_extrema(t_y, y, t_sw, t0, t1, t2, dt, few_samples)
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
        g1, noise, frac, a1 = cycle_fundamental(t_y, y, t0, t1, t2, h, few_samples, dt)
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
