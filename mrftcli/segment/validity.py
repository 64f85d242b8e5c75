"""Is a test's output an MRFT limit cycle of its relay? (Step 5 of :mod:`mrftcli.segment`; beyond the paper.)

A relay in the command says nothing about the output: the wrong loop, topic or an output buried in
noise still yields "cycles". The output must oscillate at the relay's frequency above the noise
(fundamental amplitude >= 3x the residual noise of the cycle fit, >= 50 % of its variance in the
fundamental), with a steady phase relative to the relay (mean resultant length >= 0.9) that matches
what an MRFT at the measured switching level gives a plant of eq. (2) (within 0.6 rad of
-pi + arcsin beta_eff), and the effective beta must lie in (-1, 1) and agree with the nominal one
(within 0.25, same sign). Thresholds and their reasons: :class:`ValidityCriterion` and
docs/usage-analyze.md; :func:`mrftcli.analyze.analyze_flight` rejects the failing tests and those
whose loop-gain sign disagrees with the others'.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..mrft.describing import df_phase

if TYPE_CHECKING:
    from .records import RelayCycle

__all__ = ["ValidityCriterion", "LimitCycleCheck", "check_limit_cycle"]


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
