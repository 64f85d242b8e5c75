"""Leave one test out: how well a model fitted on the other tests predicts each test (issue 39).

The held-out cycles of :mod:`.heldout` are the odd cycles of the tests the model was fitted on, so a
second effect that only absorbs how the tests differ (physics that depends on the amplitude, read as
a gain drift; a drag and a rate limit both bending the waveform) is "confirmed" there as well. Here
each test in turn is left out: the model is refitted (warm, from its fit on all tests) on the others'
fitting cycles and predicts the left-out test's cycles (its features, all its stable cycles). Two
effects are named together only when the pair predicts the left-out tests better than each effect
alone, by :data:`~mrftcli.diagnose.heldout.HOLDOUT_THRESHOLD` in chi^2: what each predicts on the
other betas and amplitudes, not which fits one test best.
"""

from __future__ import annotations

import math

import numpy as np

from .features import FEATURE_NAMES
from .fit import Fit, feature_mask, fit_model, residuals
from .prepared import DiagnosedTest
from .candidate_model import CandidateModel
from .starts import theta_bounds

__all__ = ["MIN_REFIT_GAIN", "MIN_TESTS", "left_out_chi2"]

#: a refit on the other tests replaces the fit on all of them only when it lowers their chi^2 by more
#: than this (far below the evidence's thresholds of 10, far above the fits' rounding)
MIN_REFIT_GAIN = 0.1
#: fewest tests for a leave-one-test-out comparison (with two, each test's dozen features carry Td,
#: tau and the effects fitted on it alone: weaker, but the only test of what they predict elsewhere)
MIN_TESTS = 2


def left_out_chi2(model: CandidateModel, fit: Fit, tests: list[DiagnosedTest], recs_fit: list,
                  recs_all: list) -> float | None:
    """Sum over the tests of the feature chi^2 of each test predicted by the model refitted on the
    others (K in closed form on the others, as in the fit); None with fewer than :data:`MIN_TESTS`
    tests or when a refit or a prediction fails.

    Parameters
    ----------
    model, fit : CandidateModel, Fit
        The model and its fit on all the tests' fitting cycles (theta: the refits' start; the
        scaling of theta, by the mean relay height, is kept).
    tests : list of DiagnosedTest
        The tests, in the model's order.
    recs_fit, recs_all : list of (FeatureSummary, ndarray)
        Per test, the features [various units] and their standard errors of the fitting cycles and
        of all the stable cycles.
    """
    n = len(tests)
    if n < MIN_TESTS:
        return None
    ia = FEATURE_NAMES.index("log_amplitude")
    lo, hi = theta_bounds(model.cands, tests)
    total = 0.0
    for j in range(n):
        keep = [i for i in range(n) if i != j]
        sub = CandidateModel(model.cands, [tests[i] for i in keep], model.Tp)
        # the same theta, the same physics: the flight's hover command too (a gain drift's trim), which a
        # refit without the first test would otherwise take from the second
        sub.hs, sub.bias_mean, sub.bias_first = model.hs, model.bias_mean, model.bias_first
        kept = [recs_fit[i] for i in keep]
        f = fit_model(sub, fit.theta, lo, hi, kept)
        if not f.ok or not np.isfinite(f.chi2):
            return None
        theta, K = f.theta, f.K
        start = residuals(sub, fit.theta, kept, with_K=True)
        if start is not None and f.chi2 > float(start[0] @ start[0]) - MIN_REFIT_GAIN:
            # the other tests do not move the model: an effect they do not reach (a saturation only the
            # left-out test's amplitude hits) is a flat direction of their chi^2, along which the refit
            # ends wherever rounding takes it (a saturation 1.33 -> 0.91 at the same chi^2 once made a
            # pair's left-out chi^2 301 -> 8109); the fit on all the tests is the one kept there
            theta, K = fit.theta, start[1]
        rec, s = recs_all[j]
        ev = model.evaluate(theta, j, rec.t_mean, key=4000 + j)
        if ev is None:
            return None
        fm = ev.features.copy()
        fm[ia] += math.log(K)
        z = ((rec.values - fm) / s)[feature_mask(tests[j])]
        if not np.all(np.isfinite(z)):
            return None
        total += float(z @ z)
    return total
