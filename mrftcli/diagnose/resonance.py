"""A periodic residual above the fitted harmonics: the sign of a lightly damped mode (issue 27).

Every cycle's waveform is fitted with harmonics 1..N_HARM (:mod:`mrftcli.diagnose.features`); what
is left is sensor noise, unless a mode between the airframe and the sensor (a flexible sensor mount,
a frame mode of 2-15 Hz) rings after each relay switch. That ringing repeats with the cycle, the
noise does not: the residual's harmonics above N_HARM, locked to the cycle's phase over all the
test's cycles, are compared with what the noise leaves plus what a smooth cycle of the model can
hold (:func:`periodic_residual`). A phase-locked excess is physics outside the candidate library;
:func:`resonance_mismatch` turns it into the ``unexplained`` answer, with the frequency where the
residual sits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2 as chi2_dist

from ..io.logtypes import FlightLog
from .features import N_HARM
from .fit import DiagnosedTest
from .records import Unexplained

__all__ = ["RESONANCE_P", "PeriodicResidual", "periodic_residual", "resonance_mismatch"]

#: p-value below which the folded residual is not noise (strict: a clean log must stay clean)
RESONANCE_P = 1e-6


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
    """

    test: int
    chi2: float
    dof: int
    rms: float
    frequency_hz: float


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
    return PeriodicResidual(test=test.index, chi2=float(z2.sum()), dof=2 * int(k.size),
                            rms=float(np.sqrt(np.sum(excess**2) / 2.0)),
                            frequency_hz=float(k[int(np.argmax(z2))]) / float(np.mean(tab.period)))


def resonance_mismatch(flight: FlightLog, tests: list[DiagnosedTest], after: str) -> Unexplained | None:
    """The ``unexplained`` answer when a test's residual above the fitted harmonics is not noise
    (p < :data:`RESONANCE_P`, Bonferroni over the tests).

    Parameters
    ----------
    flight : FlightLog
        The log (its output samples).
    tests : list of DiagnosedTest
        The diagnosed tests (their cycle tables hold the fitted harmonics).
    after : str
        The model finally chosen (``"linear"`` or ``"linear + <effects>"``).
    """
    rows = [r for r in (periodic_residual(flight, t) for t in tests) if r is not None]
    pvals = [float(chi2_dist.sf(r.chi2, r.dof)) for r in rows]
    # per test (a mode rings hardest in the test with the largest relay steps), Bonferroni over tests
    hits = [r for r, p in zip(rows, pvals) if p * len(rows) < RESONANCE_P]
    if not hits:
        return None
    worst = max(hits, key=lambda r: (r.chi2 - r.dof) / math.sqrt(2 * r.dof))
    p = min(1.0, min(pvals) * len(rows))
    f = worst.frequency_hz
    return Unexplained(
        after=after,
        what=(f"a residual locked to the cycle above its {N_HARM}th harmonic, near {f:.1f} Hz (a lightly damped "
              "mode ringing after the relay switches: a flexible sensor mount or a frame mode, outside the "
              "candidate library)"),
        held_out_feature_chi2=None,
        held_out_features=0,
        p_value=p,
        held_out_nrmse_raw=None,
        tests=sorted(r.test + 1 for r in hits),
        largest={"test": worst.test + 1, "feature": "residual_above_harmonics",
                 "what": f"residual above harmonic {N_HARM} near {worst.frequency_hz:.1f} Hz",
                 "z": (worst.chi2 - worst.dof) / math.sqrt(2 * worst.dof), "recorded": worst.rms, "model": 0.0},
        segments=[],
        harmonics=[],
        best_candidate=None,
        worse_half=None,
    )
