"""Per-cycle and per-test features of MRFT limit cycles, computed the same way on a recording and on
a model's simulated cycles (used by :mod:`mrftcli.diagnose.selection`).

Per cycle (from a -h -> +h switch at s_i to the next one):

* period P, time at +h (``high``), half-period balance D = T_high / P - 1/2;
* the output projected by least squares onto a constant, a linear trend and the harmonics
  k = 1..7 of the cycle's own period (:func:`mrftcli.mrft.harmonics.fit_harmonics`), which removes
  the sensor noise: Y_k (complex, so that y ~ sum_k Re(Y_k e^{j k w t'}), t' = t - s_i),
  amplitude a = (max - min)/2 and centre (max + min)/2 of the noise-free reconstruction;
* the relay's harmonics U_k = (2h / (j pi k)) (1 - e^{-j k w T_high}) (exact for the square wave) and
  the per-harmonic frequency response G_k = Y_k / U_k: the relay excites the odd harmonics, so each
  G_k measures G(j k Omega);
* the switching levels the relay achieved relative to the setpoint, beta = -e(switch) / e_ext,
  e = r - y (the MRFT rule, ``docs/architecture.md``).

Per test (over a chosen set of cycles): means, trends over time (amplitude, balance) and the
cycle-to-cycle period scatter, each with a standard error from the cycle-to-cycle spread.
"""

from __future__ import annotations

from collections.abc import Sequence

from dataclasses import dataclass

import numpy as np

from ..mrft.harmonics import fit_harmonics

__all__ = ["N_HARM", "CycleTable", "cycle_table", "FeatureSummary", "summarize_features", "cycle_features",
           "FEATURE_NAMES", "cycle_scatter"]

#: highest harmonic in the per-cycle projection
N_HARM = 7
_GRID = 400

#: feature order inside one test's vector (see :func:`summarize_features`)
FEATURE_NAMES = (
    "period",
    "balance",
    "log_amplitude",
    "centre",
    "h3_re",
    "h3_im",
    "h5_re",
    "h5_im",
    "h2_re",
    "h2_im",
    "amplitude_trend",
    "balance_trend",
)


@dataclass
class CycleTable:
    """Per-cycle measurements of one test (arrays of length n_cycles unless noted).

    Attributes
    ----------
    start, end, switch : ndarray
        Switch instants [s]: to +h (cycle start), the next to +h, and to -h inside the cycle.
    period, high, balance : ndarray
        P [s], T_high [s], D = T_high / P - 1/2.
    amplitude, centre : ndarray
        (max - min)/2 and (max + min)/2 of the reconstruction [output units] (centre relative to
        the setpoint).
    Y, U : ndarray (n_cycles, N_HARM + 1) complex
        Output and relay harmonics (index k; index 0 holds the mean output).
    trend : ndarray
        Fitted linear trend of the output within the cycle [output units/s].
    beta_up, beta_dn : ndarray
        Switching levels achieved at the cycle-closing -h -> +h and the inner +h -> -h switch.
    resid_ss, n_samples : ndarray
        Residual sum of squares of the projection and samples used (noise estimate).
    """

    start: np.ndarray
    end: np.ndarray
    switch: np.ndarray
    period: np.ndarray
    high: np.ndarray
    balance: np.ndarray
    amplitude: np.ndarray
    centre: np.ndarray
    Y: np.ndarray
    U: np.ndarray
    trend: np.ndarray
    beta_up: np.ndarray
    beta_dn: np.ndarray
    resid_ss: np.ndarray
    n_samples: np.ndarray

    @property
    def t_mid(self) -> np.ndarray:
        return 0.5 * (self.start + self.end)

    @property
    def G(self) -> np.ndarray:
        """Per-harmonic response estimate Y_k / U_k (k = 0..N_HARM; k = 0 and tiny U_k give NaN)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            g = self.Y / self.U
        g[:, 0] = np.nan
        g[np.abs(self.U) < 1e-9 * np.abs(self.U[:, 1:2])] = np.nan
        return g

    def subset(self, mask: np.ndarray) -> "CycleTable":
        return CycleTable(**{k: getattr(self, k)[mask] for k in self.__dataclass_fields__})

    def __len__(self) -> int:
        return int(self.period.size)

    def waveform(self, i: int, t: np.ndarray, *, trend: bool = True) -> np.ndarray:
        """Noise-free reconstruction of cycle ``i`` at absolute times ``t`` (periodic outside)."""
        tp = np.asarray(t, float) - self.start[i]
        w = 2.0 * np.pi / self.period[i]
        k = np.arange(1, N_HARM + 1)
        y = self.Y[i, 0].real + np.real(np.exp(1j * np.outer(tp, k * w)) @ self.Y[i, 1:])
        if trend:
            y = y + self.trend[i] * (tp - 0.5 * self.period[i])
        return y


def relay_harmonics(h: float, high: np.ndarray, period: np.ndarray) -> np.ndarray:
    """Fourier coefficients U_k (k = 0..N_HARM) of the relay square wave +h on [0, T_high), -h after."""
    k = np.arange(1, N_HARM + 1)
    w = 2.0 * np.pi / period
    U = np.zeros((period.size, N_HARM + 1), complex)
    U[:, 0] = h * (2.0 * high / period - 1.0)
    U[:, 1:] = (2.0 * h / (1j * np.pi * k)) * (1.0 - np.exp(-1j * np.outer(w * high, k)))
    return U


def cycle_table(
    t: np.ndarray,
    y: np.ndarray,
    h: float,
    start: np.ndarray | Sequence[float],
    switch: np.ndarray | Sequence[float],
    end: np.ndarray | Sequence[float],
) -> CycleTable:
    """Measure cycles [start_i, end_i) with inner switch switch_i on the sampled output ``y(t)``.

    ``y`` must already be relative to the setpoint and signed so that +h raises it.
    """
    start = np.asarray(start, float)
    switch = np.asarray(switch, float)
    end = np.asarray(end, float)
    n = start.size
    period = end - start
    high = switch - start
    Y = np.zeros((n, N_HARM + 1), complex)
    amp = np.full(n, np.nan)
    cen = np.full(n, np.nan)
    trend = np.zeros(n)
    b_up = np.full(n, np.nan)
    b_dn = np.full(n, np.nan)
    rss = np.zeros(n)
    ns = np.zeros(n, int)
    k = np.arange(1, N_HARM + 1)
    grid = np.linspace(0.0, 1.0, _GRID, endpoint=False)
    i0s = np.searchsorted(t, start - 1e-9)
    i1s = np.searchsorted(t, end - 1e-9)
    for i in range(n):
        tt = t[i0s[i] : i1s[i]] - start[i]
        yy = y[i0s[i] : i1s[i]]
        m = tt.size
        ns[i] = m
        if m < 2 * N_HARM + 4:
            continue
        w = 2.0 * np.pi / period[i]
        fit = fit_harmonics(tt, yy, period[i], N_HARM)
        coef, r = fit.coef, fit.residual
        rss[i] = float(r @ r)
        # the fit's constant is the level at the cycle's start and its trend the drift per period: the
        # table holds the level at mid-cycle and the drift per second
        trend[i] = coef[1] / period[i]
        c0 = coef[0] + 0.5 * coef[1]
        Y[i, 0] = c0
        Y[i, 1:] = fit.harmonics
        # noise-free periodic part on a fine grid
        tg = grid * period[i]
        yg = c0 + np.real(np.exp(1j * np.outer(tg, k * w)) @ Y[i, 1:])
        ymax, ymin = yg.max(), yg.min()
        amp[i] = 0.5 * (ymax - ymin)
        cen[i] = 0.5 * (ymax + ymin)
        # switching levels, MRFT rule with e = -y (setpoint 0): at the -h -> +h switch (cycle end,
        # periodically the start) e = -beta_up e_min, e_min = min e over the low half; at the inner
        # +h -> -h switch e = -beta_dn e_max, e_max = max e over the high half.
        e = -yg
        hi_mask = tg < high[i]
        if hi_mask.any() and (~hi_mask).any():
            e_max = e[hi_mask].max()
            e_min = e[~hi_mask].min()
            e_dn = -(c0 + np.real(np.exp(1j * k * w * high[i]) @ Y[i, 1:]))
            e_up = -(c0 + np.real(np.sum(Y[i, 1:])))
            if e_max > 0:
                b_dn[i] = -e_dn / e_max
            if e_min < 0:
                b_up[i] = -e_up / e_min
    U = relay_harmonics(h, high, period)
    return CycleTable(
        start=start, end=end, switch=switch, period=period, high=high, balance=high / period - 0.5,
        amplitude=amp, centre=cen, Y=Y, U=U, trend=trend, beta_up=b_up, beta_dn=b_dn,
        resid_ss=rss, n_samples=ns,
    )


@dataclass
class FeatureSummary:
    """Feature vector of one test over a set of cycles, with standard errors.

    ``values`` and ``sigma`` follow :data:`FEATURE_NAMES`; ``t_mean`` is the mean cycle time [s]
    (trend reference) and ``n`` the number of cycles.
    """

    values: np.ndarray
    sigma: np.ndarray
    t_mean: float
    n: int


def _slope(t: np.ndarray, v: np.ndarray) -> tuple[float, float]:
    """Least-squares slope of v(t) and its standard error."""
    if t.size < 4:
        return 0.0, np.inf
    tc = t - t.mean()
    sxx = float(tc @ tc)
    if sxx <= 0:
        return 0.0, np.inf
    b = float(tc @ (v - v.mean())) / sxx
    r = v - v.mean() - b * tc
    s2 = float(r @ r) / max(t.size - 2, 1)
    return b, float(np.sqrt(s2 / sxx))


def _feature_columns(period: np.ndarray, balance: np.ndarray, amplitude: np.ndarray, centre: np.ndarray,
                     Y: np.ndarray) -> np.ndarray:
    """Per cycle (rows), the features but the two trends (:data:`FEATURE_NAMES` order)."""
    Y1 = Y[:, 1]
    r3 = Y[:, 3] / Y1
    r5 = Y[:, 5] / Y1
    r2 = Y[:, 2] / Y1
    return np.column_stack([period, balance, np.log(amplitude), centre / amplitude, r3.real, r3.imag, r5.real, r5.imag,
                            r2.real, r2.imag])


def cycle_features(period: float, balance: float, amplitude: float, centre: float, Y: np.ndarray) -> np.ndarray:
    """The feature values of one cycle (a model's periodic solution; the trends 0): those of
    :func:`summarize_features` of a one-row table, bit for bit, without building it (half the CPU of
    a model cycle's features; issue 39). ``Y``: its harmonics 0..N_HARM."""
    one = _feature_columns(np.array([period]), np.array([balance]), np.array([amplitude]), np.array([centre]),
                           Y[None, : N_HARM + 1])[0]
    return np.concatenate([one, [0.0, 0.0]])


def summarize_features(tab: CycleTable) -> FeatureSummary:
    """Means, trends and scatter of a test's cycles (see :data:`FEATURE_NAMES`).

    Standard errors are the cycle-to-cycle standard deviation over sqrt(n) (trends: the regression
    standard error), i.e. what the sensor noise, the sampling of the switches and any jitter make
    of each feature. For a single cycle (a model's periodic solution) they are zero.
    """
    n = len(tab)
    cols = _feature_columns(tab.period, tab.balance, tab.amplitude, tab.centre, tab.Y)
    values = np.nanmean(cols, axis=0)
    if n > 1:
        sigma = np.nanstd(cols, axis=0, ddof=1) / np.sqrt(n)
    else:
        sigma = np.zeros(cols.shape[1])
    tm = tab.t_mid
    a_tr, a_se = _slope(tm, np.log(tab.amplitude)) if n > 1 else (0.0, 0.0)
    d_tr, d_se = _slope(tm, tab.balance) if n > 1 else (0.0, 0.0)
    values = np.concatenate([values, [a_tr, d_tr]])
    sigma = np.concatenate([sigma, [a_se, d_se]])
    return FeatureSummary(
        values=values,
        sigma=sigma,
        t_mean=float(tm.mean()) if n else float("nan"),
        n=n,
    )


def cycle_scatter(tab: CycleTable, mask: np.ndarray, reference: np.ndarray | None = None) -> float:
    """Sum over the selected recorded cycles of their cycle-to-cycle scatter [output units^2 x cycles].

    The sampled relay decides on noisy samples, so every cycle's switch instants and centre move
    by a tick or a fraction of a millimetre: the recorded cycles scatter about the waveform the
    plant would repeat, and no deterministic model can predict that part. For the n selected
    cycles y_i (on a grid of 200 phases of the mean period, as the held-out waveform errors of
    :mod:`mrftcli.diagnose.selection`) and any model m_i,
    E sum_i |y_i - m_i|^2 = sum_i |mu_i - m_i|^2 + n s^2, mu_i the scatter-free waveform. With
    mu_i = a + b t_i (a slow drift such as a battery sag is not scatter) the residual sum of squares
    of the per-phase least-squares line is (n - 2) s^2, so n s^2 = RSS n / (n - 2) (for n = 3 a
    constant a: RSS n / (n - 1)). Subtracting it leaves an unbiased estimate of the systematic error.
    ``mask`` selects the cycles of ``tab``. s^2 is estimated over the cycles ``reference`` selects
    (default ``mask``; a test's two held-out cycles say nothing about it, all of its cycles do) and
    counted for the ``mask`` cycles; fewer than 3 reference cycles give 0.

    Examples
    --------
    Eight cycles of one waveform, each shifted by its own offset: the two last ones' share of the
    scatter, estimated from all eight (2 RSS / 6 of the offsets about their least-squares line).

    >>> t = np.arange(0.0, 8.0, 0.005)
    >>> y = 0.05 * np.sin(2 * np.pi * t) + np.repeat([1, -1, 2, 0, -2, 1, -1, 0], 200) * 1e-3
    >>> starts = np.arange(8.0)
    >>> tab = cycle_table(t, y, 0.1, starts, starts + 0.5, starts + 1.0)
    >>> last2 = np.arange(8) >= 6
    >>> round(cycle_scatter(tab, last2, reference=np.ones(8, bool)) * 1e6, 2)  # 2 s^2 [mm^2]
    3.71
    >>> cycle_scatter(tab, last2)  # two cycles alone cannot tell scatter from the waveform
    0.0
    """
    ref = mask if reference is None else reference
    n_mask = int(np.count_nonzero(mask))
    idx = np.flatnonzero(ref)
    n = idx.size
    if n < 3 or n_mask == 0:
        return 0.0
    P_ref = float(np.mean(tab.period[idx]))
    tt = np.linspace(0.0, P_ref, 200, endpoint=False)
    Y = np.array([tab.waveform(int(i), tab.start[i] + tt * tab.period[i] / P_ref) for i in idx])
    tm = tab.start[idx] - tab.start[idx].mean()
    X = np.column_stack([np.ones(n), tm]) if n >= 4 else np.ones((n, 1))
    coef, *_ = np.linalg.lstsq(X, Y, rcond=None)
    rss = float(np.sum((Y - X @ coef) ** 2)) / tt.size
    return rss / (n - X.shape[1]) * n_mask
