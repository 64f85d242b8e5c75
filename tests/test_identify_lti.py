"""The built-in families' closed-form fit (mrft/lti_kernel.py) against independent computations.

Oracles: the families' complex frequency response (``frequency_response``: K e^{-tau s} / den,
evaluated in complex arithmetic, no shared formula with the kernel's real log-gain and arctan sums);
central differences of the residuals for the Jacobian; the general route of identify's response-point fit (a
model object per grid point and scipy's least_squares, the kernel switched off) for the minimum and its
uncertainty; exact points of a known plant for the answer itself.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mrftcli.mrft.families import FOIPDT, FOPDT, IPDT, SOPDT, family_model
from mrftcli.mrft.identify import identify
from mrftcli.mrft.identify_lti import ResponsePoint
from mrftcli.mrft.lti_kernel import LagChainKernel

#: plants and the structures they are fitted with: every family, a negative gain, known parameters
CASES = [
    (FOPDT(K=2.0, T=0.5, tau=0.1), family_model("fopdt")),
    (FOPDT(K=-2.0, T=0.5, tau=0.1), FOPDT(K=-1.0, T=1.0, tau=0.0)),  # K's sign comes from the model
    (SOPDT(K=1.5, T1=1.0, T2=0.25, tau=0.1), family_model("sopdt")),
    (SOPDT(K=1.5, T1=1.0, T2=0.25, tau=0.1), family_model("sopdt", known={"T2": 0.25})),
    (IPDT(K=3.0, tau=0.2), family_model("ipdt")),
    (FOIPDT(K=1.0, T=1.0, tau=0.05), family_model("foipdt", known={"K": 1.0})),
    (FOIPDT(K=1.0, T=1.0, tau=0.05), family_model("foipdt", known={"tau": 0.05})),
]
IDS = ["fopdt", "fopdt-negative-K", "sopdt", "sopdt-T2-known", "ipdt", "foipdt-K-known", "foipdt-tau-known"]
OMEGAS = [1.0, 2.5, 6.0, 14.0]  # limit cycles: every phase within a turn of -pi (the delay's branch)


def _points(true, noise, seed):
    rng = np.random.default_rng(seed)
    G = true.frequency_response(np.array(OMEGAS))
    return [ResponsePoint(w, abs(g) * math.exp(noise * rng.standard_normal()),
                          float(np.angle(g)) + noise * rng.standard_normal(), max(noise, 1e-3),
                          max(noise, 1.5e-3), test=i) for i, (w, g) in enumerate(zip(OMEGAS, G))]


class _Arrays:
    """The points as the kernel takes them (what the response-point fit's private _Data holds)."""

    def __init__(self, points):
        self.omega = np.array([p.omega for p in points])
        self.log_gain = np.log([p.gain for p in points])
        self.phase = np.array([p.phase for p in points])
        self.w_gain = 1 / np.array([p.se_log_gain for p in points])
        self.w_phase = 1 / np.array([p.se_phase for p in points])


def _kernel_and_z(structure, at, points):
    """The kernel for ``structure`` and the solver's variables of the plant ``at``."""
    unknown = [n for n, p in structure.parameters.items() if not p.known]
    log_scaled = {n for n in unknown if n != "tau"}
    given = {n: p.value for n, p in structure.parameters.items()}
    kernel = LagChainKernel.of(structure, given, unknown, log_scaled, _Arrays(points))
    values = {n: p.value for n, p in at.parameters.items()}
    z = np.array([values[n] if n == "tau" else math.log(abs(values[n])) for n in unknown])
    return kernel, z


@pytest.mark.parametrize(("true", "structure"), CASES, ids=IDS)
def test_kernel_residuals_are_the_complex_response(true, structure):
    points = _points(true, 0.02, seed=1)
    trial = true.with_parameters(**{n: p.value * 1.3 for n, p in true.parameters.items() if n != "tau"
                                    and not structure.parameters[n].known})
    kernel, z = _kernel_and_z(structure, trial, points)
    data = _Arrays(points)
    G = trial.frequency_response(data.omega)
    phase = np.mod(np.angle(G) - data.phase + math.pi, 2 * math.pi) - math.pi
    expected = np.concatenate([(np.log(np.abs(G)) - data.log_gain) * data.w_gain, phase * data.w_phase])
    np.testing.assert_allclose(kernel.residuals(z), expected, rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize(("true", "structure"), CASES, ids=IDS)
def test_kernel_jacobian_is_the_residuals_derivative(true, structure):
    points = _points(true, 0.02, seed=2)
    kernel, z = _kernel_and_z(structure, true, points)
    J = kernel.evaluate(z)[1]
    h = 1e-6
    for i in range(z.size):
        dz = np.zeros(z.size)
        dz[i] = h
        central = (kernel.residuals(z + dz) - kernel.residuals(z - dz)) / (2 * h)
        np.testing.assert_allclose(J[:, i], central, rtol=1e-6, atol=1e-4 * np.max(np.abs(central)))


def test_kernel_only_for_lag_chains_on_a_log_scale():
    points = _points(FOPDT(K=2.0, T=0.5, tau=0.1), 0.0, seed=0)
    model = family_model("fopdt")
    given = {n: p.value for n, p in model.parameters.items()}
    assert LagChainKernel.of(object(), given, ["K", "T", "tau"], {"K", "T"}, _Arrays(points)) is None
    # a time constant whose range reaches below zero stays linear: the closed form's ln T does not apply
    assert LagChainKernel.of(model, given, ["K", "T", "tau"], {"K"}, _Arrays(points)) is None


@pytest.mark.parametrize(("true", "structure"), CASES, ids=IDS)
def test_response_fit_same_minimum_and_uncertainty_as_the_general_route(true, structure, monkeypatch):
    points = _points(true, 0.01, seed=3)
    fast = identify(points, structure)
    monkeypatch.setattr(LagChainKernel, "of", classmethod(lambda cls, *args: None))
    general = identify(points, structure)
    for a, b in zip(fast.estimates, general.estimates):
        assert a.value == pytest.approx(b.value, rel=1e-6, abs=1e-9), a.name
        assert a.std == pytest.approx(b.std, rel=1e-4, abs=1e-12), a.name
        assert (a.determined, a.one_sided, a.known) == (b.determined, b.one_sided, b.known)
    assert fast.chi2_dof == pytest.approx(general.chi2_dof, rel=1e-6)


@pytest.mark.parametrize(("true", "structure"), CASES, ids=IDS)
def test_response_fit_exact_points_give_the_plant_back(true, structure):
    # with a time constant known the grid has one axis fewer (SOPDT's known T2 was an IndexError)
    fit = identify(_points(true, 0.0, seed=0), structure)
    for e in fit.estimates:
        assert e.value == pytest.approx(true.parameters[e.name].value, rel=1e-6), e
        assert e.determined
