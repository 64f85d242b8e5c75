"""Eq. (2)'s plant draws the design is averaged over: from the prior, or from what the flown tests leave
(conditioned on their UFM slice: the eq. (2) strategy's own maths)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..errors import InputError
from ..mrft.lprs import unit_cycle
from ..mrft.model import LoopModel, lead_floor
from .noise import FLOOR_PHASE, cycle_noise
from .records import FlownTest, Prior

__all__ = ["conditioned_draws"]


def conditioned_draws(model: LoopModel, prior: Prior, flown: Sequence[FlownTest], n: int,
                      rng: np.random.Generator, rate_hz: float, noise_std: float,
                      notes: list[str] | None = None) -> np.ndarray:
    """``n`` plants (rows Td [s], tau [s], K) of eq. (2) at ``model``'s known Tp, consistent with the flown tests.

    Td from the prior, tau from the first test's UFM slice (Lemma 3), K from its amplitude (UGM);
    with two betas flown, Td from the least squares of them all. When the flown tests carry their
    phase, many candidates on the slice are weighted by the likelihood of the measured phases
    (Gaussian, the noise model's standard error) and ``n`` drawn from them by systematic
    resampling: the posterior of the flown tests, not the whole slice. Without flown tests: the
    prior's stratified draws. Candidates on the slice with a lead (tau < 0, within
    :func:`~mrftcli.mrft.model.lead_floor`) are left out when causal ones exist; ``notes``, when
    given, gets one line counting them.

    Raises
    ------
    InputError
        The flown test admits no plant with Td in the prior range and a non-negative delay.
    """
    if not flown:
        return prior.draws(n, rng)
    phased = [t for t in flown if t.phase is not None]
    out = _on_the_slice(model, prior, flown, n, rng, 64 * n if phased else n, notes)
    if not phased or out.shape[0] <= n:
        return out
    return _resample(model, out, phased, n, rng, rate_hz, noise_std)


def _on_the_slice(model: LoopModel, prior: Prior, flown: Sequence[FlownTest], n: int, rng: np.random.Generator,
                  m: int, notes: list[str] | None = None) -> np.ndarray:
    """``m`` prior draws moved onto the first flown test's UFM slice and UGM (rows Td, tau, K)."""
    draws = prior.draws(m, rng)
    f = flown[0]
    omega = math.tau * f.frequency_hz
    Td = draws[:, 0]
    if len({round(t.beta, 2) for t in flown}) >= 2:
        from ..mrft.identify import TestMeasurement, identify

        res = identify([TestMeasurement(beta=t.beta, frequency_hz=t.frequency_hz, amplitude=t.amplitude, h=t.h)
                        for t in flown], model)
        Td = np.full(n, res.model.Td)
    th, a_unit = unit_cycle(model.Tp * omega, Td * omega, f.beta)
    tau = th / omega
    K = f.amplitude * omega / (f.h * Td * a_unit)
    ok = np.isfinite(tau) & (tau >= 0) & (K > 0)
    inside = ok & (tau >= prior.tau[0]) & (tau <= prior.tau[1])
    keep = inside if inside.sum() >= max(2, n // 3) else ok
    lead = np.isfinite(tau) & (tau < 0) & (tau >= lead_floor(model.Tp)) & (K > 0)
    if keep.any() and lead.any() and notes is not None:  # tune holds such draws at 0; plan cannot simulate them
        notes.append(f"{int(lead.sum())} of {len(tau)} posterior draws have tau < 0 (a lead): plan leaves them out "
                     "(its simulator's delay line cannot advance the command); the forecasts rest on the causal draws")
    if not keep.any():
        if lead.any():  # eq. (2) with a lead (analyze admits it); the forecasts' simulator delays the command only
            raise InputError(f"the flown tests give a loop that leads eq. (2) (tau {np.median(tau[lead]) * 1e3:.3g} ms "
                             "< 0, an estimator's lead): plan forecasts each test by simulating the flight "
                             "(mrftcli.sim), whose delay line cannot advance the command; plan the next test from a "
                             "loop with tau >= 0 (or check --tp)")
        raise InputError("the flown test admits no plant with Td in the prior range and a non-negative delay; "
                         "check --tp and the Td range")
    out: np.ndarray = np.stack([Td, tau, K], axis=1)[keep]
    return out


def _resample(model: LoopModel, out: np.ndarray, phased: Sequence[FlownTest], n: int, rng: np.random.Generator,
              rate_hz: float, noise_std: float) -> np.ndarray:
    """``n`` of the plants ``out`` by systematic resampling, weighted by the measured phases' likelihood."""
    loglik = np.zeros(out.shape[0])
    for t in phased:
        assert t.phase is not None  # the caller passes the phased tests only
        w = math.tau * t.frequency_hz
        pred = -0.5 * math.pi - np.arctan(model.Tp * w) - np.arctan(out[:, 0] * w) - out[:, 1] * w
        # the noise model's per-cycle phase scatter at this test (slope of a triangle-like cycle)
        sd = cycle_noise(t.amplitude, w, 1.5 * t.amplitude * w, rate_hz, noise_std)["phase"]
        sd = math.sqrt(sd**2 / t.n_cycles + FLOOR_PHASE**2)
        r = np.angle(np.exp(1j * (t.phase - pred)))
        loglik += -0.5 * (r / sd) ** 2
    wts = np.exp(loglik - loglik.max())
    cdf = np.cumsum(wts) / wts.sum()
    idx = np.searchsorted(cdf, (np.arange(n) + rng.uniform()) / n)
    chosen: np.ndarray = out[np.minimum(idx, out.shape[0] - 1)]
    return chosen
