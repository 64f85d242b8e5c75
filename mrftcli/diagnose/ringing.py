"""The ringing of a lightly damped mode after every relay switch, fitted against the linear model (issue 27).

Eq. (2)'s plant has relative degree three: at every relay switch its jerk steps by K du / Tp (tau
later), and a mode between the airframe and the sensor, H(s) = w_n^2 / (s^2 + 2 zeta w_n s + w_n^2)
(a flexible sensor mount, a frame mode), rings freely after each step, with an amplitude of about
K du / (Tp w_n^3) that decays over 1 / (zeta w_n). Over a cycle the sensor shows the harmonics
H(j k Omega) G(j k Omega) U_k, where U_k are those of the relay's square wave with the cycle's recorded
switches: the ringing repeats with every switch, the noise does not.

Above the harmonics each cycle's waveform fit holds (:data:`~mrftcli.diagnose.features.N_HARM`),
the linear model's own harmonics G U_k are known, so what the recording leaves there is the noise
plus what the model misses (:func:`switch_harmonics`). The matched fit (:func:`fit_ringing`) puts
the mode's template a_k = (H(j k Omega) e^{j k Omega delta} - 1) G U_k (delta = 2 zeta / w_n, the
low-frequency lag of H that the fitted delay already holds) against that residual for every
frequency and damping of a grid, and scores the chi^2 drop of subtracting alpha a (alpha in [0.5, 2]:
the template's amplitude is the physics', not a free one) over the dispersion of the rest. The
drop of a mode a cycle's fit cannot hold grows with the switches' number and height (the oracle SNR
``benchmarks/bench_diagnose.py`` prints); the library's effects attenuate the high harmonics (a lag,
a slew) or scale them (a dead zone, a saturation) and do not fit a resonance's peak.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2 as chi2_dist

from ..io.logtypes import FlightLog
from ..mrft.model import LoopModel
from .features import N_HARM
from .fit import DiagnosedTest

__all__ = ["RINGING_P", "DAMPINGS", "MIN_TEMPLATE_CHI2", "SwitchHarmonics", "RingingFit", "switch_harmonics",
           "fit_ringing"]

#: p-value (Bonferroni over the grid's templates) below which the residual's ringing is not noise
RINGING_P = 1e-3

#: the dampings of the grid (a lightly damped mode: issue 27's mounts have 0.02-0.1)
DAMPINGS = (0.01, 0.02, 0.035, 0.05, 0.07, 0.1, 0.15)

#: a template whose full subtraction would lower chi^2 by less than this cannot be told from noise
#: whatever the data: it is not tried (its p-value would only dilute the grid's)
MIN_TEMPLATE_CHI2 = 16.0

#: the frequency grid's step (relative): a fifth of the narrowest resonance's half-power width
_F_STEP = 0.01

#: the template's amplitude against the physics' (a mode is not 5 % of a resonance)
_ALPHA = (0.5, 2.0)
#: how many standard errors the fitted amplitude may lie outside :data:`_ALPHA`
_ALPHA_Z = 3.0


@dataclass(frozen=True)
class SwitchHarmonics:
    """One test's residual harmonics above the fitted ones, less the linear model's own.

    Attributes
    ----------
    test : int
        The test (from 0).
    k : ndarray of int
        The harmonics (above :data:`~mrftcli.diagnose.features.N_HARM`).
    omega : ndarray
        Each stable cycle's fundamental [rad/s].
    residual : ndarray, complex (cycles, harmonics)
        The recording's harmonics after the cycle's waveform fit, less the model's ``predicted`` ones
        [output units, the cycle table's sign].
    predicted : ndarray, complex (cycles, harmonics)
        The linear model's harmonics G(j k Omega) U_k of each cycle's relay wave (its gain and phase
        matched to the fitted harmonics of the test).
    weight : ndarray
        Per cycle, 1 / the noise variance of one real component of a harmonic [1 / output units^2].
    """

    test: int
    k: np.ndarray = field(repr=False)
    omega: np.ndarray = field(repr=False)
    residual: np.ndarray = field(repr=False)
    predicted: np.ndarray = field(repr=False)
    weight: np.ndarray = field(repr=False)

    @property
    def band_hz(self) -> tuple[float, float]:
        """The harmonics' span at the test's mean period [Hz]."""
        f = float(np.mean(self.omega)) / (2.0 * math.pi)
        return float(self.k[0]) * f, float(self.k[-1]) * f


@dataclass(frozen=True)
class RingingFit:
    """The best mode of the grid (:func:`fit_ringing`).

    Attributes
    ----------
    frequency_hz : float
        Its natural frequency [Hz].
    damping : float
        Its damping ratio.
    amplitude : float
        The template's amplitude fitted (1: the ringing the mode predicts; clipped to [0.5, 2]).
    chi2_drop : float
        The residual's chi^2 drop when the ringing is subtracted, over the ``dispersion``.
    template_chi2 : float
        What the template alone weighs in chi^2 (the mode's SNR at this log's noise).
    dispersion : float
        The rest's chi^2 per degree of freedom (at least 1): a model that misses the high harmonics
        broadly (an actuator effect) weighs a narrow peak less.
    trials : int
        The templates tried.
    p_value : float
        The drop's chi^2 (one degree of freedom) p-value, Bonferroni over the trials.
    tests : list of int
        The tests (from 0) whose residual the template lowers.
    rms : float
        The fitted ringing's RMS over the cycles [output units].
    at_lowest : bool
        The frequency is the grid's lowest (a mode at or below it: its peak is where the cycles'
        waveform fits hold it).
    """

    frequency_hz: float
    damping: float
    amplitude: float
    chi2_drop: float
    template_chi2: float
    dispersion: float
    trials: int
    p_value: float
    tests: list[int]
    rms: float
    at_lowest: bool = False


def _cycles(flight: FlightLog, test: DiagnosedTest) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per stable cycle: its samples' times, outputs and waveform fit (harmonics 1..N_HARM)."""
    tab, t_all, y_all = test.tab, flight.output.t, flight.output.values
    out = []
    for i in range(len(tab)):
        sel = (t_all >= tab.start[i]) & (t_all < tab.end[i]) & np.isfinite(y_all)
        out.append((t_all[sel], y_all[sel], tab.waveform(i, t_all[sel])))
    return out


def switch_harmonics(flight: FlightLog, test: DiagnosedTest, plant: LoopModel) -> SwitchHarmonics | None:
    """The residual of ``test``'s cycles above the fitted harmonics, less ``plant``'s harmonics there.

    Each cycle's relay wave is the square wave of its recorded switches (+h from its start, -h from
    its inner switch); ``plant`` (eq. (2) with the diagnosis' linear fit, its delay included) maps it
    to the harmonics a clean loop shows. One complex gain per test, fitted on the harmonics the
    cycles' waveform fits hold, carries the loop's sign and what the fit's K leaves. None with too
    few samples a cycle (fewer than four harmonics above N_HARM below Nyquist) or cycles.
    """
    tab = test.tab
    cycles = _cycles(flight, test)
    n = np.array([c[0].size for c in cycles], float)
    if len(cycles) < 3:
        return None
    k = np.arange(N_HARM + 1, min(int(n.min()) // 2, 40))
    if k.size < 4:
        return None
    y, w = (np.concatenate([c[j] for c in cycles]) for j in (1, 2))
    # the table holds loop_sign (y - reference): back to its units by one affine fit
    coef = np.linalg.lstsq(np.column_stack([np.ones_like(w), w]), y, rcond=None)[0]
    if not abs(coef[1]) > 0:
        return None
    s2 = float(np.var((y - coef[0] - coef[1] * w) / coef[1]))
    if not s2 > 0:
        return None
    omega = 2.0 * np.pi / tab.period
    low = np.arange(1, N_HARM + 1)
    model_low = plant.frequency_response(np.outer(omega, low)) * tab.U[:, 1:]
    gain = np.sum(np.conj(model_low) * tab.Y[:, 1:]) / np.sum(np.abs(model_low) ** 2)
    # each cycle's harmonics k of the residual, from its own start and period (one exponential table
    # for every sample, summed per cycle)
    r = (y - coef[0]) / coef[1] - w
    phase = np.concatenate([(c[0] - t_i) * om_i for c, t_i, om_i in zip(cycles, tab.start, omega)])
    first = np.concatenate([[0], np.cumsum(n[:-1])]).astype(int)
    resid = (2.0 / n[:, None]) * np.add.reduceat(r[:, None] * np.exp(-1j * np.outer(phase, k)), first, axis=0)
    om = np.outer(omega, k)
    relay = (2.0 * test.h / (1j * np.pi * k)) * (1.0 - np.exp(-1j * om * tab.high[:, None]))
    pred = gain * plant.frequency_response(om) * relay
    # one real component of (2 / n) sum r e^{-j theta} has the variance 2 s2 / n
    return SwitchHarmonics(test=test.index, k=k, omega=omega, residual=resid - pred, predicted=pred,
                           weight=n / (2.0 * s2))


def _grid(rows: list[SwitchHarmonics]) -> np.ndarray:
    """The frequencies tried [Hz]: from half a harmonic above the fitted ones (of the test with the
    shortest period: the peak must lie in every test's band) to the lowest test's top harmonic."""
    lo = max((N_HARM + 0.5) * float(np.mean(r.omega)) for r in rows) / (2.0 * math.pi)
    hi = min(r.band_hz[1] for r in rows)
    if not hi > lo:
        return np.zeros(0)
    grid: np.ndarray = np.exp(np.arange(math.log(lo), math.log(hi), _F_STEP))
    return grid


def _template(r: SwitchHarmonics, wn: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """The mode's ringing in ``r``'s harmonics, (H(j k Omega) e^{j k Omega delta} - 1) G U_k, for the
    natural frequencies ``wn`` [rad/s] and dampings ``zeta`` (broadcast against (cycles, harmonics))."""
    om = r.omega[:, None] * r.k[None, :]
    s = 1j * om
    H = wn * wn / (s * s + 2.0 * zeta * wn * s + wn * wn)
    out: np.ndarray = (H * np.exp(1j * om * 2.0 * zeta / wn) - 1.0) * r.predicted
    return out


def _scores(rows: list[SwitchHarmonics], f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per (frequency, damping): sum Re(conj(a) d) w and sum |a|^2 w over every test, and per test the
    former (the ``(tests, f, dampings)`` array)."""
    wn = 2.0 * np.pi * f[:, None, None, None]
    zeta = np.asarray(DAMPINGS)[None, :, None, None]
    num = np.zeros((f.size, len(DAMPINGS)))
    den = np.zeros_like(num)
    per_test = []
    for r in rows:
        a = _template(r, wn, zeta)  # (frequencies, dampings, cycles, harmonics)
        wt = r.weight[None, None, :, None]
        nt = np.sum(np.real(np.conj(a) * r.residual[None, None]) * wt, axis=(2, 3))
        num += nt
        den += np.sum(np.abs(a) ** 2 * wt, axis=(2, 3))
        per_test.append(nt)
    return num, den, np.array(per_test)


def fit_ringing(rows: list[SwitchHarmonics]) -> RingingFit | None:
    """The mode whose ringing after the switches best explains the tests' residual (None: no template).

    For each frequency of the grid and damping of :data:`DAMPINGS` whose template weighs at least
    :data:`MIN_TEMPLATE_CHI2`: the amplitude alpha (least squares, clipped to [0.5, 2]; a template whose
    fitted amplitude lies more than three standard errors outside that range is not a mode) and the
    chi^2 drop den (2 alpha_hat alpha - alpha^2) of subtracting it. The best drop is divided by the rest's
    chi^2 per degree of freedom (at least 1) and given its chi^2(1) p-value times the templates tried.
    """
    rows = [r for r in rows if r.k.size]
    f = _grid(rows) if rows else np.zeros(0)
    if not f.size:
        return None
    num, den, per_test = _scores(rows, f)
    ok = den >= MIN_TEMPLATE_CHI2
    if not ok.any():
        return None
    trials = int(ok.sum())
    alpha_hat = np.where(ok, num / np.where(ok, den, 1.0), 0.0)
    alpha = np.clip(alpha_hat, *_ALPHA)
    # a template is the physics only where the data allow its amplitude: alpha_hat within
    # _ALPHA_Z standard errors (1 / sqrt(den)) of the physical range (a lag's or a slew's broad
    # attenuation fits a strong template at a third of its amplitude: not a mode)
    ok &= (alpha - alpha_hat) ** 2 * den <= _ALPHA_Z**2
    drop = np.where(ok & (alpha_hat > 0), den * (2.0 * alpha_hat * alpha - alpha * alpha), 0.0)
    i, j = np.unravel_index(int(np.argmax(drop)), drop.shape)
    total = sum(float(np.sum(np.abs(r.residual) ** 2 * r.weight[:, None])) for r in rows)
    dof = sum(2 * r.residual.size for r in rows)
    dispersion = max(1.0, (total - float(drop[i, j])) / max(dof - 3, 1))
    score = float(drop[i, j]) / dispersion
    p = min(1.0, float(chi2_dist.sf(score, 1)) * trials)
    tests = [r.test for r, nt in zip(rows, per_test[:, i, j]) if nt > 0]
    # the ringing's RMS over a cycle (a harmonic c contributes |c|^2 / 2), averaged over the cycles
    power = [np.sum(np.abs(_template(r, np.asarray(2.0 * np.pi * f[i]), np.asarray(DAMPINGS[j]))) ** 2, axis=1) / 2.0
             for r in rows]
    rms = float(alpha[i, j]) * math.sqrt(float(np.mean(np.concatenate(power))))
    return RingingFit(frequency_hz=float(f[i]), damping=float(DAMPINGS[j]), amplitude=float(alpha_hat[i, j]),
                      chi2_drop=score, template_chi2=float(den[i, j]), dispersion=dispersion, trials=trials,
                      p_value=p, tests=tests, rms=rms, at_lowest=bool(i <= 1))
