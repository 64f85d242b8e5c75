"""A periodic residual above the fitted harmonics: the sign of a lightly damped mode (issue 27).

Every cycle's waveform is fitted with harmonics 1..N_HARM (:mod:`mrftcli.diagnose.features`); what
is left is sensor noise, unless a mode between the airframe and the sensor (a flexible sensor mount,
a frame mode of 2-15 Hz) rings after each relay switch. That ringing repeats with the cycle, the
noise does not: the residual's harmonics above N_HARM, locked to the cycle's phase over all the
test's cycles, are compared with what the noise leaves plus what a smooth cycle of the model can
hold (:func:`periodic_residual`). A mode rings at one frequency in Hz whatever the test, and only
in the few harmonics about it: the excess is summed over a band of :data:`BAND_HZ` about each
frequency, over every test (:func:`band_excess`), rather than over all harmonics of one test (a
10.6 Hz mount: p 0.4 over all 32 harmonics of its best test, 0.008 in the pooled band; an 8.4 Hz
one: 0.19 and 1e-7). A phase-locked excess is physics outside the candidate library;
:func:`resonance_mismatch` turns it into the ``unexplained`` answer, with the frequency where the
residual sits.
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
from .records import Unexplained
from .ringing import RINGING_P, RingingFit, fit_ringing, switch_harmonics

__all__ = ["RESONANCE_P", "BAND_HZ", "PeriodicResidual", "BandExcess", "periodic_residual", "band_excess",
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
    chi2, dof : float, int
        The squared excess of the folded cycle's harmonics above N_HARM over a smooth cycle's bound,
        in units of their noise variance, and its degrees of freedom (two per harmonic).
    rms : float
        RMS of that excess [output units].
    frequency_hz : float
        Where the folded residual's power peaks [Hz] (the harmonic of the mean period above N_HARM).
    harmonics_hz : ndarray
        The frequencies of the harmonics above N_HARM [Hz] (of the test's mean period).
    z2 : ndarray
        Each one's squared excess in units of its noise variance (chi^2 with 2 degrees of freedom
        under noise alone).
    """

    test: int
    chi2: float
    dof: int
    rms: float
    frequency_hz: float
    harmonics_hz: np.ndarray = field(repr=False, compare=False, default_factory=lambda: np.zeros(0))
    z2: np.ndarray = field(repr=False, compare=False, default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class BandExcess:
    """The largest excess over the tests in a band of :data:`BAND_HZ` (:func:`band_excess`).

    Attributes
    ----------
    frequency_hz : float
        The band's centre [Hz].
    chi2, dof : float, int
        The squared excess summed over the harmonics of every test in the band, and its degrees of
        freedom.
    p_value : float
        Its chi^2 p-value, Bonferroni over the bands tried.
    tests : list of int
        The tests (from 0) whose band excess is above its degrees of freedom.
    """

    frequency_hz: float
    chi2: float
    dof: int
    p_value: float
    tests: list[int]


def periodic_residual(flight: FlightLog, test: DiagnosedTest) -> PeriodicResidual | None:
    """Fold ``test``'s cycles on their phase; the harmonics above N_HARM beyond a smooth cycle's.

    The relay's square wave has harmonics falling as 1/k and the plant's magnitude falls at least as
    1/k^2 above its corner, so a cycle of the model has |Y_k| <= |Y_j| (j/k)^3 for k > j (j = 5, 7,
    the highest fitted); a sensor lag or the delay only lowers it. The folded mean cycle's harmonics
    above N_HARM are compared with that bound; the excess over it, in units of the noise's standard
    error (the within-bin scatter of the cycles' residuals), is ``chi2`` over ``dof`` (two per
    harmonic: noise alone stays below chi^2 with ``dof`` degrees of freedom). None with too few
    samples a cycle.
    """
    tab = test.tab
    t_all, y_all = flight.output.t, flight.output.values
    phases, ys, fitted = [], [], []
    for i in range(len(tab)):
        sel = (t_all >= tab.start[i]) & (t_all < tab.end[i]) & np.isfinite(y_all)
        t = t_all[sel]
        phases.append((t - tab.start[i]) / tab.period[i])
        ys.append(y_all[sel])
        fitted.append(tab.waveform(i, t))
    per_cycle = min((p.size for p in phases), default=0)
    k = np.arange(N_HARM + 1, min(per_cycle // 2, 40))
    if k.size < 4 or len(phases) < 3:
        return None  # too few samples a cycle to see anything above the fitted harmonics
    ph, y, w = (np.concatenate(v) for v in (phases, ys, fitted))
    # the table holds loop_sign (y - reference): back to the log's output by one affine fit; the
    # residual is what the cycles' harmonics 1..N_HARM (and drift) leave
    coef = np.linalg.lstsq(np.column_stack([np.ones_like(w), w]), y, rcond=None)[0]
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
    f_k = k / float(np.mean(tab.period))
    return PeriodicResidual(test=test.index, chi2=float(z2.sum()), dof=2 * int(k.size),
                            rms=float(np.sqrt(np.sum(excess**2) / 2.0)), frequency_hz=float(f_k[int(np.argmax(z2))]),
                            harmonics_hz=f_k, z2=z2)


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
    return BandExcess(frequency_hz=float(np.average(f[m], weights=z2[m] + 1e-12)), chi2=float(chi2[j]),
                      dof=int(dof[j]), p_value=float(p[j]), tests=tests)


def resonance_mismatch(flight: FlightLog, tests: list[DiagnosedTest], after: str,
                       plant: LoopModel | None = None) -> Unexplained | None:
    """The ``unexplained`` answer when a mode rings after the relay switches (the matched fit of
    :func:`~mrftcli.diagnose.ringing.fit_ringing` against ``plant``'s harmonics, p <
    :data:`~mrftcli.diagnose.ringing.RINGING_P`), or when the residual above the fitted harmonics is
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
    f, p = band.frequency_hz, band.p_value
    return Unexplained(
        after=after,
        what=(f"a residual locked to the cycle above its {N_HARM}th harmonic, near {f:.1f} Hz (a lightly damped "
              "mode ringing after the relay switches: a flexible sensor mount or a frame mode, outside the "
              "candidate library)"),
        held_out_feature_chi2=None,
        held_out_features=0,
        p_value=p,
        held_out_nrmse_raw=None,
        tests=[t + 1 for t in (band.tests or [worst.test])],
        largest={"test": worst.test + 1, "feature": "residual_above_harmonics",
                 "what": f"residual above harmonic {N_HARM} near {f:.1f} Hz",
                 "z": (zw - dofw) / math.sqrt(2 * max(dofw, 1)), "recorded": worst.rms, "model": 0.0},
        segments=[],
        harmonics=[],
        best_candidate=None,
        worse_half=None,
    )


def ringing_answer(fit: RingingFit, after: str) -> Unexplained:
    """The ``unexplained`` answer of a mode found ringing after the switches (its frequency and damping)."""
    f, zeta = fit.frequency_hz, fit.damping
    at = f"at or below {f:.1f} Hz" if fit.at_lowest else f"at {f:.1f} Hz, damping {zeta:.2f}"
    what = (f"a ringing after every relay switch {at} (a lightly damped mode between the airframe and the sensor: "
            "a flexible sensor mount or a frame mode, outside the candidate library)")
    return Unexplained(
        after=after,
        what=what,
        held_out_feature_chi2=None,
        held_out_features=0,
        p_value=fit.p_value,
        held_out_nrmse_raw=None,
        tests=[t + 1 for t in fit.tests],
        largest={"test": (fit.tests or [0])[-1] + 1, "feature": "ringing_after_switches",
                 "what": f"ringing {at}, after the relay switches",
                 "z": math.sqrt(fit.chi2_drop), "recorded": fit.rms, "model": 0.0},
        segments=[],
        harmonics=[],
        best_candidate=None,
        worse_half=None,
    )
