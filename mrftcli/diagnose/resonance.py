"""A mode ringing after every relay switch: the matched fit against the linear model, and the periodic
residual above the fitted harmonics as the fallback (issue 27).

Eq. (2)'s plant has relative degree three: at every relay switch its jerk steps by K du / Tp (tau
later), and a mode between the airframe and the sensor, H(s) = w_n^2 / (s^2 + 2 zeta w_n s + w_n^2)
(a flexible sensor mount, a frame mode of 2-15 Hz), rings freely after each step, with an amplitude of
about K du / (Tp w_n^3) that decays over 1 / (zeta w_n). Over a cycle the sensor shows the harmonics
H(j k Omega) G(j k Omega) U_k, where U_k are those of the relay's square wave with the cycle's recorded
switches: the ringing repeats with every switch, the noise does not.

**The matched fit** (tried first). Above the harmonics each cycle's waveform fit holds
(:data:`~mrftcli.diagnose.features.N_HARM`), the linear model's own harmonics G U_k are known, so what
the recording leaves there is the noise plus what the model misses (:func:`switch_harmonics`). The
matched fit (:func:`fit_ringing`) puts the mode's template a_k = (H(j k Omega) e^{j k Omega delta} - 1)
G U_k (delta = 2 zeta / w_n, the low-frequency lag of H that the fitted delay already holds) against
that residual for every frequency and damping of a grid, and scores the chi^2 drop of subtracting
alpha a (alpha in [0.5, 2]: the template's amplitude is the physics', not a free one) over the
dispersion of the rest. The drop of a mode a cycle's fit cannot hold grows with the switches' number
and height (the oracle SNR ``benchmarks/bench_diagnose.py`` prints); the library's effects attenuate
the high harmonics (a lag, a slew) or scale them (a dead zone, a saturation) and do not fit a
resonance's peak.

**The band statistic** (the fallback, without the linear model). The residual's harmonics above
N_HARM, locked to the cycle's phase over all the test's cycles, are compared with what the noise
leaves plus what a smooth cycle of the model can hold (:func:`periodic_residual`). A mode rings at
one frequency in Hz whatever the test, and only in the few harmonics about it: the excess is summed
over a band of :data:`BAND_HZ` about each frequency, over every test (:func:`band_excess`), rather
than over all harmonics of one test (a 10.6 Hz mount: p 0.4 over all 32 harmonics of its best test,
0.008 in the pooled band; an 8.4 Hz one: 0.19 and 1e-7).

A phase-locked excess is physics outside the candidate library; :func:`resonance_mismatch` turns it
into the ``unexplained`` answer, with the frequency (and damping) where the residual sits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2 as chi2_dist

from ..io.logtypes import FlightLog
from ..mrft.model import LoopModel
from .features import N_HARM
from .prepared import DiagnosedTest
from .records import Unexplained

__all__ = ["RESONANCE_P", "BAND_HZ", "RINGING_P", "DAMPINGS", "MIN_TEMPLATE_CHI2", "PeriodicResidual", "BandExcess",
           "SwitchHarmonics", "RingingFit", "periodic_residual", "band_excess", "switch_harmonics", "fit_ringing",
           "resonance_mismatch", "ringing_answer"]

#: p-value below which the folded residual is not noise (strict: a clean log must stay clean)
RESONANCE_P = 1e-6

#: half-width of the band [Hz] the excess is summed over: a mode of damping 0.02-0.1 at 2-15 Hz rings
#: within ~0.1-1.5 Hz of its frequency, and the tests' harmonics are 0.7-1.5 Hz apart (2-3 in a band)
BAND_HZ = 1.0


@dataclass(frozen=True)
class PeriodicResidual:
    """One test's residual above the fitted harmonics, folded on the cycle phase.

    Attributes
    ----------
    test : int
        The test (from 0).
    rms : float
        RMS of the folded cycle's harmonics above N_HARM beyond a smooth cycle's bound [output units].
    harmonics_hz : ndarray
        The frequencies of the harmonics above N_HARM [Hz] (of the test's mean period).
    z2 : ndarray
        Each one's squared excess in units of its noise variance (chi^2 with 2 degrees of freedom
        under noise alone).
    """

    test: int
    rms: float
    harmonics_hz: np.ndarray = field(repr=False, compare=False, default_factory=lambda: np.zeros(0))
    z2: np.ndarray = field(repr=False, compare=False, default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class BandExcess:
    """The largest excess over the tests in a band of :data:`BAND_HZ` (:func:`band_excess`).

    Attributes
    ----------
    frequency_hz : float
        The band's centre [Hz].
    p_value : float
        The chi^2 p-value of the squared excess summed over the harmonics of every test in the band
        (two degrees of freedom a harmonic), Bonferroni over the bands tried.
    tests : list of int
        The tests (from 0) whose band excess is above its degrees of freedom.
    """

    frequency_hz: float
    p_value: float
    tests: list[int]


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
        The residual's chi^2 drop when the ringing is subtracted, over the rest's chi^2 per degree of
        freedom (at least 1: a model that misses the high harmonics broadly, an actuator effect,
        weighs a narrow peak less).
    p_value : float
        The drop's chi^2 (one degree of freedom) p-value, Bonferroni over the templates tried.
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
    p_value: float
    tests: list[int]
    rms: float
    at_lowest: bool = False


def _above_fitted(flight: FlightLog, test: DiagnosedTest) -> tuple[list, np.ndarray, np.ndarray, np.ndarray,
                                                                  np.ndarray, np.ndarray] | None:
    """What both statistics read above the fitted harmonics: per stable cycle its samples' times,
    outputs and waveform fit (harmonics 1..N_HARM); the cycles' sample counts; the harmonics above
    N_HARM below Nyquist (at most 39); every cycle's outputs and fits, concatenated; and the affine
    map from the table's waveform back to the log's output (the table holds loop_sign (y - reference)).
    None with fewer than three cycles or four such harmonics."""
    tab, t_all, y_all = test.tab, flight.output.t, flight.output.values
    cycles = []
    for i in range(len(tab)):
        sel = (t_all >= tab.start[i]) & (t_all < tab.end[i]) & np.isfinite(y_all)
        cycles.append((t_all[sel], y_all[sel], tab.waveform(i, t_all[sel])))
    n = np.array([c[0].size for c in cycles], float)
    if len(cycles) < 3:
        return None
    k = np.arange(N_HARM + 1, min(int(n.min()) // 2, 40))
    if k.size < 4:
        return None  # too few samples a cycle to see anything above the fitted harmonics
    y, w = (np.concatenate([c[j] for c in cycles]) for j in (1, 2))
    coef = np.linalg.lstsq(np.column_stack([np.ones_like(w), w]), y, rcond=None)[0]
    return cycles, n, k, y, w, coef


def switch_harmonics(flight: FlightLog, test: DiagnosedTest, plant: LoopModel) -> SwitchHarmonics | None:
    """The residual of ``test``'s cycles above the fitted harmonics, less ``plant``'s harmonics there.

    Each cycle's relay wave is the square wave of its recorded switches (+h from its start, -h from
    its inner switch); ``plant`` (eq. (2) with the diagnosis' linear fit, its delay included) maps it
    to the harmonics a clean loop shows. One complex gain per test, fitted on the harmonics the
    cycles' waveform fits hold, carries the loop's sign and what the fit's K leaves. None with too
    few samples a cycle (fewer than four harmonics above N_HARM below Nyquist) or cycles.
    """
    tab, above = test.tab, _above_fitted(flight, test)
    if above is None:
        return None
    cycles, n, k, y, w, coef = above
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
                      chi2_drop=score, p_value=p, tests=tests, rms=rms, at_lowest=bool(i <= 1))


def periodic_residual(flight: FlightLog, test: DiagnosedTest) -> PeriodicResidual | None:
    """Fold ``test``'s cycles on their phase; the harmonics above N_HARM beyond a smooth cycle's.

    The relay's square wave has harmonics falling as 1/k and the plant's magnitude falls at least as
    1/k^2 above its corner, so a cycle of the model has |Y_k| <= |Y_j| (j/k)^3 for k > j (j = 5, 7,
    the highest fitted); a sensor lag or the delay only lowers it. The folded mean cycle's harmonics
    above N_HARM are compared with that bound; the excess over it, in units of the noise's standard
    error (the within-bin scatter of the cycles' residuals), squared, is ``z2`` (chi^2 with two degrees of
    freedom a harmonic under noise alone). None with too few samples a cycle.
    """
    tab, above = test.tab, _above_fitted(flight, test)
    if above is None:
        return None
    cycles, _, k, y, w, coef = above
    ph = np.concatenate([(c[0] - tab.start[i]) / tab.period[i] for i, c in enumerate(cycles)])
    # the residual is what the cycles' harmonics 1..N_HARM (and drift) leave
    r = y - coef[0] - coef[1] * w
    s2 = float(np.var(r))
    if not s2 > 0:
        return None
    # harmonics of the residual locked to the cycle, over all samples (a non-uniform DFT: binning the
    # samples would alias the fundamental's phase error into them)
    c = (2.0 / r.size) * (r @ np.exp(-2j * np.pi * np.outer(ph, k)))
    var_c = 4.0 * s2 / r.size  # of a complex coefficient (half real, half imaginary)
    Y = abs(coef[1]) * np.mean(np.abs(tab.Y), axis=0)
    bound = np.maximum(Y[5] * (5.0 / k) ** 3, Y[N_HARM] * (N_HARM / k) ** 3)
    excess = np.clip(np.abs(c) - bound, 0.0, None)
    z2 = excess**2 / (0.5 * var_c)
    return PeriodicResidual(test=test.index, rms=float(np.sqrt(np.sum(excess**2) / 2.0)),
                            harmonics_hz=k / float(np.mean(tab.period)), z2=z2)


def band_excess(rows: list[PeriodicResidual]) -> BandExcess | None:
    """The band of +-:data:`BAND_HZ` where the tests' excess above the fitted harmonics is least like noise.

    Bands are centred every BAND_HZ over the harmonics' span; in each, the squared excess of every
    test's harmonics inside it is summed (chi^2 with two degrees of freedom a harmonic under noise
    alone) and its p-value is multiplied by the number of bands (Bonferroni). None without harmonics.
    """
    rows = [r for r in rows if r.z2.size]
    if not rows:
        return None
    f = np.concatenate([r.harmonics_hz for r in rows])
    z2 = np.concatenate([r.z2 for r in rows])
    owner = np.concatenate([np.full(r.z2.size, r.test) for r in rows])
    centres = np.arange(float(f.min()), float(f.max()) + 1e-9, BAND_HZ)
    in_band = np.abs(f[None, :] - centres[:, None]) <= BAND_HZ  # (bands, harmonics)
    dof = 2 * in_band.sum(axis=1)
    chi2 = in_band @ z2
    p = np.minimum(1.0, chi2_dist.sf(chi2, np.maximum(dof, 1)) * centres.size)
    p[dof == 0] = 1.0
    j = int(np.argmin(p))
    m = in_band[j]
    # the tests whose share of the band exceeds its degrees of freedom (they ring there)
    tests = sorted(int(t) for t in np.unique(owner[m]) if z2[m & (owner == t)].sum() > 2 * np.sum(m & (owner == t)))
    return BandExcess(frequency_hz=float(np.average(f[m], weights=z2[m] + 1e-12)), p_value=float(p[j]), tests=tests)


def resonance_mismatch(flight: FlightLog, tests: list[DiagnosedTest], after: str,
                       plant: LoopModel | None = None) -> Unexplained | None:
    """The ``unexplained`` answer when a mode rings after the relay switches (the matched fit of
    :func:`fit_ringing` against ``plant``'s harmonics, p < :data:`RINGING_P`), or when the residual above the fitted harmonics is
    not noise in some band (p < :data:`RESONANCE_P`, Bonferroni over the bands: :func:`band_excess`).

    Parameters
    ----------
    flight : FlightLog
        The log (its output samples).
    tests : list of DiagnosedTest
        The diagnosed tests (their cycle tables hold the fitted harmonics).
    after : str
        The model finally chosen (``"linear"`` or ``"linear + <effects>"``).
    plant : LoopModel, optional
        Eq. (2) with the diagnosis' linear fit (its harmonics above the fitted ones are what a clean
        loop shows there); without it only the band statistic is judged.
    """
    if plant is not None:
        ringing = fit_ringing([r for r in (switch_harmonics(flight, t, plant) for t in tests) if r is not None])
        if ringing is not None and ringing.p_value < RINGING_P:
            return ringing_answer(ringing, after)
    rows = [r for r in (periodic_residual(flight, t) for t in tests) if r is not None]
    band = band_excess(rows)
    if band is None or band.p_value >= RESONANCE_P:
        return None
    # the test that rings hardest in the band (the largest relay steps, as a rule) is the largest
    in_band = {r.test: r.z2[np.abs(r.harmonics_hz - band.frequency_hz) <= BAND_HZ] for r in rows}
    worst = max(rows, key=lambda r: float(in_band[r.test].sum()) - in_band[r.test].size)
    zw, dofw = float(in_band[worst.test].sum()), 2 * int(in_band[worst.test].size)
    f = band.frequency_hz
    return _mode_answer(
        after, (f"a residual locked to the cycle above its {N_HARM}th harmonic, near {f:.1f} Hz (a lightly damped "
                "mode ringing after the relay switches: a flexible sensor mount or a frame mode, outside the "
                "candidate library)"), band.p_value, band.tests or [worst.test],
        {"test": worst.test + 1, "feature": "residual_above_harmonics", "what": f"residual above harmonic {N_HARM} near {f:.1f} Hz",
         "z": (zw - dofw) / math.sqrt(2 * max(dofw, 1)), "recorded": worst.rms, "model": 0.0})


def ringing_answer(fit: RingingFit, after: str) -> Unexplained:
    """The ``unexplained`` answer of a mode found ringing after the switches (its frequency and damping)."""
    f, zeta = fit.frequency_hz, fit.damping
    at = f"at or below {f:.1f} Hz" if fit.at_lowest else f"at {f:.1f} Hz, damping {zeta:.2f}"
    what = (f"a ringing after every relay switch {at} (a lightly damped mode between the airframe and the sensor: "
            "a flexible sensor mount or a frame mode, outside the candidate library)")
    return _mode_answer(after, what, fit.p_value, fit.tests,
                        {"test": (fit.tests or [0])[-1] + 1, "feature": "ringing_after_switches",
                         "what": f"ringing {at}, after the relay switches", "z": math.sqrt(fit.chi2_drop),
                         "recorded": fit.rms, "model": 0.0})


def _mode_answer(after: str, what: str, p_value: float, tests: list[int], largest: dict) -> Unexplained:
    """The ``unexplained`` answer of a mode outside the library (judged on the residual above the fitted
    harmonics, not on the held-out features): ``tests`` from 0."""
    return Unexplained(after=after, what=what, held_out_feature_chi2=None, held_out_features=0, p_value=p_value,
                       held_out_nrmse_raw=None, tests=[t + 1 for t in tests], largest=largest, segments=[],
                       harmonics=[], best_candidate=None, worse_half=None)
