"""Issue 41: the covariance the response-point held-out route propagates (``identify_lti.fit_covariance``).

The route itself is checked against the series oracle of tests/test_held_out_eq2.py (its two- and three-test
flights, simulated by tests/process_sim.py); here the covariance against a closed form: with only ln K unknown,
an integrator's weighted least squares on log-gains is a weighted mean, var(ln K) = 1 / sum(1 / se^2), inflated
by the reduced chi-square when the points scatter beyond their standard errors.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mrftcli.mrft.families import family_model
from mrftcli.mrft.identify import identify
from mrftcli.mrft.identify_lti import ResponsePoint, fit_covariance


@pytest.mark.parametrize("scatter", [0.0, 0.2])
def test_fit_covariance_of_a_weighted_mean_is_its_closed_form(scatter: float) -> None:
    K, tau = 2.5, 0.04
    omega = np.array([1.0, 2.0, 4.0, 8.0])
    se = np.array([0.05, 0.1, 0.05, 0.2])
    offsets = scatter * np.array([1.0, -1.0, 0.5, -0.5])  # log-gain errors (zero: the points agree exactly)
    points = [ResponsePoint(float(w), K / w * math.exp(float(d)), -math.pi / 2 - tau * w, float(s), 0.05, 0, 1)
              for w, s, d in zip(omega, se, offsets)]
    fit = identify(points, family_model("ipdt", known={"tau": tau}))
    names, z, cov = fit_covariance(fit)
    wts = 1 / se ** 2
    lnk = float(np.sum(wts * (np.log(K) + offsets)) / np.sum(wts))
    chi2_dof = float(np.sum(wts * (np.log(K) + offsets - lnk) ** 2)) / (2 * omega.size - 1)
    assert names == ("K",) and z[0] == pytest.approx(lnk, abs=1e-8)
    assert cov[0, 0] == pytest.approx(max(1.0, chi2_dof) / np.sum(wts), rel=1e-6)
    assert (chi2_dof > 1) == (scatter > 0)  # the scattered case exercises the inflation
