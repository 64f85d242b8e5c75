"""Exact MRFT limit cycle (LPRS): reference figures, closed forms and internal consistency."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from mrftcli.errors import InputError
from mrftcli.mrft.describing import describing_function_limit_cycle, df_frequency, df_phase
from mrftcli.mrft.lprs import lti_limit_cycle, mrft_limit_cycle, unit_cycle, unit_cycle_scalar
from mrftcli.mrft.model import LoopModel

sys.path.insert(0, str(Path(__file__).parent))
from boiko_lprs import lprs_first_order, lprs_integrator, lprs_series, lprs_soiptd, lprs_state_space  # noqa: E402

# checks.md section 1: theta/u = 0.14 e^{-0.06 s}/(s (0.1 s+1)(0.7042 s+1)); unit-gain form K Td = 1
PAPER = LoopModel(Tp=0.1, Td=1 / 1.42, tau=0.06, K=1.42)


@pytest.mark.parametrize(
    "beta, f_exact, a_exact, f_paper",
    [(-0.4, 0.70564, 0.078530, 0.708), (-0.7, 1.01884, 0.035602, 1.022)],
)
def test_paper_example(beta, f_exact, a_exact, f_paper):
    lc = mrft_limit_cycle(PAPER, beta)
    assert lc.frequency_hz == pytest.approx(f_exact, rel=5e-4)
    assert lc.amplitude == pytest.approx(a_exact, rel=1e-3)
    assert lc.frequency_hz == pytest.approx(f_paper, rel=5e-3)
    assert lc.omega == pytest.approx(2 * math.pi * lc.frequency_hz)
    assert lc.period == pytest.approx(1 / lc.frequency_hz)


def test_paper_example_with_paper_gain_scales_amplitude():
    # Lemma 2: amplitude proportional to K and h, frequency unchanged
    lc1 = mrft_limit_cycle(PAPER, -0.7)
    lc2 = mrft_limit_cycle(LoopModel(0.1, 1 / 1.42, 0.06, 0.14 * 1.42), -0.7, h=10.0)
    assert lc2.frequency_hz == pytest.approx(lc1.frequency_hz, rel=1e-12)
    assert lc2.amplitude == pytest.approx(1.4 * lc1.amplitude, rel=1e-12)


def test_waveform_satisfies_the_mrft_switching_condition():
    # at the -h -> +h switch (t = 0) y = -beta a_y on the descending branch; antisymmetric
    for beta in (-0.8, -0.3, 0.2):
        lc = mrft_limit_cycle(PAPER, beta, n_points=4000)
        assert lc.y[0] == pytest.approx(-beta * lc.amplitude, rel=1e-6, abs=1e-12)
        assert lc.y[1] < lc.y[0]  # descending
        assert np.max(np.abs(lc.y)) == pytest.approx(lc.amplitude, rel=1e-5)
        half = lc.y.size // 2
        np.testing.assert_allclose(lc.y[half:], -lc.y[:half], atol=1e-12)


def test_time_scaling_lemma_3_and_4():
    # scaling every time parameter by gamma divides the frequency by gamma; the amplitude of the
    # integrating plant (K Td fixed) scales by gamma (Lemma 4, one integrator)
    gamma = 3.7
    lc = mrft_limit_cycle(PAPER, -0.5)
    scaled = LoopModel(PAPER.Tp * gamma, PAPER.Td * gamma, PAPER.tau * gamma, PAPER.K / gamma)
    lcs = mrft_limit_cycle(scaled, -0.5)
    assert lcs.omega == pytest.approx(lc.omega / gamma, rel=1e-10)
    assert lcs.amplitude == pytest.approx(lc.amplitude * gamma, rel=1e-9)


def test_state_space_route_agrees_with_closed_form():
    rng = np.random.default_rng(3)
    for _ in range(3):
        m = LoopModel(rng.uniform(0.02, 0.3), rng.uniform(0.2, 2), rng.uniform(0.001, 0.1), rng.uniform(0.5, 3))
        beta = rng.uniform(-0.9, -0.1)
        a, b, c = m.state_space()
        ss = lti_limit_cycle(a, b, c, m.tau, beta, h=2.0)
        cf = mrft_limit_cycle(m, beta, h=2.0)
        assert ss.omega == pytest.approx(cf.omega, rel=1e-9)
        assert ss.amplitude == pytest.approx(cf.amplitude, rel=1e-8)


def test_double_pole_tp_equals_td():
    m = LoopModel(0.3, 0.3, 0.05)
    a, b, c = m.state_space()
    ss = lti_limit_cycle(a, b, c, m.tau, -0.6)
    cf = mrft_limit_cycle(m, -0.6)
    assert cf.omega == pytest.approx(ss.omega, rel=1e-7)
    assert cf.amplitude == pytest.approx(ss.amplitude, rel=1e-7)


def test_general_lti_first_order_plus_delay():
    # a loop without integrator: K e^{-tau s}/(T s+1); the LPRS gives the exact relay frequency with
    # beta = 0 where Im J = 0:  1 - 2 e^{gamma}/(1+e^{alpha}) = 0
    T, tau = 0.4, 0.1
    lc = lti_limit_cycle([[-1 / T]], [1 / T], [1.0], tau, 0.0)
    alpha = math.pi / (T * lc.omega)
    assert 2 * math.exp(tau / T) / (1 + math.exp(alpha)) == pytest.approx(1.0, rel=1e-9)


def test_boiko_integrator_closed_form_and_series():
    j = lprs_integrator(1.0, 1.3, 0.1)
    assert j.real == pytest.approx(-0.06500, abs=5e-6)
    assert j.imag == pytest.approx(-1.50171, abs=5e-6)
    s = lprs_series(1.0, lambda s: 1.3 * np.exp(-0.1 * s) / s, n_terms=2_000_000)
    assert abs(s - j) < 1e-6


def test_boiko_first_order_closed_form_and_series():
    j = lprs_first_order(3.0, 1.3, 0.4, 0.1)
    assert j.real == pytest.approx(0.32950, abs=5e-6)
    assert j.imag == pytest.approx(-0.84275, abs=5e-6)
    s = lprs_series(3.0, lambda s: 1.3 * np.exp(-0.1 * s) / (0.4 * s + 1), n_terms=2_000_000)
    assert abs(s - j) < 1e-6


def test_lprs_additive_over_partial_fractions_and_state_space():
    w = 2 * math.pi * 0.9
    j = lprs_soiptd(w, PAPER)
    a, b, c = PAPER.state_space()
    assert abs(lprs_state_space(w, a, b, c, PAPER.tau) - j) < 1e-12
    W = lambda s: PAPER.K * PAPER.Td * np.exp(-PAPER.tau * s) / (s * (PAPER.Tp * s + 1) * (PAPER.Td * s + 1))  # noqa
    assert abs(lprs_series(w, W, n_terms=2_000_000) - j) < 1e-6


def test_lprs_imaginary_part_is_the_output_at_the_switch():
    # Boiko: Im J(w) = pi/(4h) y(0), y(0) the output when the relay switches -h -> +h.
    # Our unit waveform at frequency w: y(0) = y0(-tau) with the closed-form periodic solution.
    for beta in (-0.7, -0.4):
        lc = mrft_limit_cycle(PAPER, beta, n_points=2048)
        j = lprs_soiptd(lc.omega, PAPER)
        assert j.imag == pytest.approx(math.pi / 4 * lc.y[0], rel=1e-9)
        # and the MRFT condition in LPRS form: y(0) = -beta a_y
        assert j.imag == pytest.approx(-math.pi / 4 * beta * lc.amplitude, rel=1e-6)


def test_describing_function_is_only_approximate():
    f_df, a_df = describing_function_limit_cycle(PAPER, -0.4)
    lc = mrft_limit_cycle(PAPER, -0.4)
    assert abs(f_df / lc.frequency_hz - 1) > 0.01  # the DF misses by several percent here
    # DF phase condition holds at its own frequency
    w = 2 * math.pi * f_df
    assert np.angle(PAPER.frequency_response(w) * np.exp(1j * math.pi)) == pytest.approx(math.asin(-0.4), abs=1e-9)
    assert a_df == pytest.approx(4 / math.pi * abs(PAPER.frequency_response(w)))


def test_unit_cycle_vectorised_matches_limit_cycle():
    lc = mrft_limit_cycle(PAPER, -0.55)
    th, a = unit_cycle(np.array([PAPER.Tp * lc.omega]), np.array([PAPER.Td * lc.omega]), -0.55)
    assert th[0] == pytest.approx(PAPER.tau * lc.omega, rel=1e-9)
    assert a[0] * PAPER.K * PAPER.Td / lc.omega == pytest.approx(lc.amplitude, rel=1e-9)


def test_scalar_unit_cycle_equals_the_vectorised_one():
    """unit_cycle_scalar (plain Python, for root finders) is the same closed form as unit_cycle.

    To 1e-12 where the closed form is well conditioned (physical plants, poles apart); near a double
    pole the partial fractions cancel (coefficients ~ T^2 / (Tp - Td)) and both lose digits alike.
    """
    rng = np.random.default_rng(20240610)
    n = 400
    tp_n = np.exp(rng.uniform(np.log(1e-3), np.log(50.0), n))
    td_n = np.exp(rng.uniform(np.log(1e-2), np.log(500.0), n))
    td_n[:20] = tp_n[:20] * (1 + rng.uniform(-1e-3, 1e-3, 20))  # (nearly) double poles
    beta = rng.uniform(-0.95, 0.6, n)
    th_v, a_v = unit_cycle(tp_n, td_n, beta)
    th_s = np.empty(n)
    a_s = np.empty(n)
    th_w = np.empty(n)
    warm: list = []
    for i in range(n):
        th_s[i], a_s[i] = unit_cycle_scalar(float(tp_n[i]), float(td_n[i]), float(beta[i]))
        # a warm start from the previous point (as the root finders use it) lands on the same root
        th_w[i], _ = unit_cycle_scalar(float(tp_n[i]), float(td_n[i]), float(beta[i]), warm)
    apart = np.abs(np.log(tp_n / td_n)) > 0.05
    good = apart & (th_v >= 0)
    assert good.sum() > 100
    np.testing.assert_allclose(th_s[good], th_v[good], rtol=0, atol=1e-12)
    np.testing.assert_allclose(a_s[good], a_v[good], rtol=1e-12, atol=0)
    np.testing.assert_allclose(th_s[apart], th_v[apart], rtol=0, atol=1e-11)  # no plant: theta < 0
    np.testing.assert_allclose(th_s, th_v, rtol=0, atol=1e-9)  # near double poles
    np.testing.assert_allclose(a_s, a_v, rtol=1e-10, atol=1e-11)
    np.testing.assert_allclose(th_w, th_s, rtol=0, atol=1e-9)


def test_simulator_planning_uses_the_describing_function_with_half_a_sample():
    """The simulator's df_prediction is the describing function with the zero-order hold's lag."""
    from mrftcli.sim.control import df_prediction

    rate = 200.0
    omega, amp = df_prediction(PAPER, -0.4, 2.0, rate)
    # harmonic balance, paper eq. (6), with the half-sample lag: arg G - Omega/(2 rate) = -pi + asin(beta)
    phase = (-0.5 * math.pi - math.atan(PAPER.Tp * omega) - math.atan(PAPER.Td * omega)
             - (PAPER.tau + 0.5 / rate) * omega)
    assert phase == pytest.approx(float(df_phase(-0.4)), abs=1e-12)
    assert amp == pytest.approx(4 * 2.0 / math.pi * abs(PAPER.frequency_response(omega)), rel=1e-12)
    assert omega < df_frequency(PAPER, -0.4)  # the extra lag lowers the frequency


def test_sampled_relay_band_brackets_continuous_plus_half_sample():
    lc = mrft_limit_cycle(PAPER, -0.4, rate_hz=200.0)
    cont = mrft_limit_cycle(PAPER, -0.4)
    assert lc.orbits_hz and min(lc.orbits_hz) <= lc.frequency_hz <= max(lc.orbits_hz)
    assert lc.frequency_hz < cont.frequency_hz  # the sampling lag lowers the frequency
    # every admissible orbit has a whole number of samples per half period
    for f in lc.orbits_hz:
        n = 200.0 / (2 * f)
        assert n == pytest.approx(round(n), abs=1e-9)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"beta": 1.0}, "beta"),
        ({"beta": -1.2}, "beta"),
        ({"beta": -0.4, "h": 0.0}, "h must be"),
        ({"beta": -0.4, "h": -1.0}, "h must be"),
        ({"beta": -0.4, "rate_hz": -5.0}, "rate_hz"),
        ({"beta": "abc"}, "beta"),
    ],
)
def test_bad_inputs(kwargs, match):
    with pytest.raises(InputError, match=match):
        mrft_limit_cycle(PAPER, **kwargs)


def test_bad_model_and_state_space():
    with pytest.raises(InputError, match="tau"):  # a lead beyond Tp / 2
        LoopModel(0.1, 0.5, -0.06)
    with pytest.raises(InputError, match="tau"):  # within Tp / 2 but beyond an estimator's 6 ms (LEAD_CAP_S)
        LoopModel(0.1, 0.5, -0.007)
    assert LoopModel(0.1, 0.5, -0.005).lead  # a small lead is eq. (2)'s (mrft.model.lead_floor)
    with pytest.raises(InputError, match="Tp"):
        LoopModel(-0.1, 0.5, 0.01)
    with pytest.raises(InputError, match="shapes"):
        lti_limit_cycle(np.eye(2), [1.0], [1.0, 0.0], 0.0, -0.5)
    with pytest.raises(InputError, match="tau"):
        lti_limit_cycle([[-1.0]], [1.0], [1.0], -1.0, -0.5)
