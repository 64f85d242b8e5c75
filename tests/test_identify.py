"""Identification of Td, tau and K from MRFT tests via the UFM/UGM."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from mrftcli.mrft.model import soiptd_model
from mrftcli.errors import IdentificationError, InputError
from mrftcli.mrft.identify import IdentificationResult, TestMeasurement, identify, ufm_slice
from mrftcli.mrft.lprs import mrft_limit_cycle
from mrftcli.mrft.model import LoopModel

PAPER = LoopModel(Tp=0.1, Td=1 / 1.42, tau=0.06, K=1.42)


def _tests(model, betas, h=1.0, amplitude=True):
    out = []
    for b in betas:
        lc = mrft_limit_cycle(model, b, h=h)
        out.append(TestMeasurement(b, lc.frequency_hz, lc.amplitude if amplitude else None, h if amplitude else None))
    return out


def test_paper_example_round_trip_with_gain():
    res = identify(_tests(PAPER, (-0.4, -0.7)), soiptd_model(PAPER.Tp))
    assert isinstance(res, IdentificationResult)
    assert res.Td.value == pytest.approx(PAPER.Td, rel=1e-6)
    assert res.tau.value == pytest.approx(PAPER.tau, rel=1e-6)
    assert res.K.value == pytest.approx(PAPER.K, rel=1e-6)
    assert res.method == "intersection"
    assert res.model.Td == pytest.approx(PAPER.Td, rel=1e-6)


def test_paper_figures_from_checks_md():
    # the rounded exact figures of checks.md section 1 identify the plant to the rounding's accuracy
    res = identify([TestMeasurement(-0.4, 0.70564), TestMeasurement(-0.7, 1.01884)], soiptd_model(0.1))
    assert res.Td.value == pytest.approx(1 / 1.42, rel=2e-3)
    assert res.tau.value == pytest.approx(0.06, rel=2e-3)
    assert res.K is None


@pytest.mark.slow
def test_round_trip_random_plants_dnn_mrft_range():
    rng = np.random.default_rng(11)
    worst = 0.0
    for _ in range(50):
        m = LoopModel(rng.uniform(0.015, 0.3), rng.uniform(0.2, 2.0), rng.uniform(0.0005, 0.1), rng.uniform(0.2, 5))
        b1 = rng.uniform(-0.9, -0.5)
        b2 = rng.uniform(-0.4, -0.1)
        res = identify(_tests(m, (b1, b2), h=rng.uniform(0.1, 2)), soiptd_model(m.Tp))
        for est, true in ((res.Td.value, m.Td), (res.tau.value, m.tau), (res.K.value, m.K)):
            worst = max(worst, abs(est / true - 1))
    assert worst < 5e-3
    assert worst < 1e-6  # in fact limited only by the root finder


def test_flight_like_large_td_over_tau():
    # Design II altitude + 20 ms of Table III scaled: Td/tau near 100
    m = LoopModel(0.0499, 4.1755, 0.042, 1.0)
    res = identify(_tests(m, (-0.4, -0.7)), soiptd_model(m.Tp))
    assert res.Td.value == pytest.approx(m.Td, rel=1e-5)
    assert res.tau.value == pytest.approx(m.tau, rel=1e-5)


def test_effective_beta_between_shipped_slices_and_beyond():
    m = LoopModel(0.05, 1.3, 0.03)
    for betas in ((-0.63, -0.27), (-0.95, -0.05)):
        res = identify(_tests(m, betas), soiptd_model(m.Tp))
        assert res.Td.value == pytest.approx(m.Td, rel=1e-6)
        assert res.tau.value == pytest.approx(m.tau, rel=1e-6)


def test_three_tests_least_squares_consistent_data_has_zero_residual():
    m = LoopModel(0.04, 0.9, 0.025)
    res = identify(_tests(m, (-0.8, -0.5, -0.2), amplitude=False), soiptd_model(m.Tp))
    assert res.method == "least-squares"
    assert res.Td.value == pytest.approx(m.Td, rel=1e-5)
    assert res.tau.value == pytest.approx(m.tau, rel=1e-5)
    assert res.residual < 1e-7


def test_three_tests_residual_measures_inconsistency():
    m = LoopModel(0.04, 0.9, 0.025)
    tests = _tests(m, (-0.8, -0.5, -0.2), amplitude=False)
    tests[1] = TestMeasurement(-0.5, tests[1].frequency_mean * 1.01)
    res = identify(tests, soiptd_model(m.Tp))
    assert 1e-3 < res.residual < 1e-2


def test_rate_correction_removes_half_sample_lag():
    # frequencies of the sampled relay's band centre: the plant with tau + Ts/2, continuous
    rate = 200.0
    lagged = LoopModel(PAPER.Tp, PAPER.Td, PAPER.tau + 0.5 / rate)
    tests = _tests(lagged, (-0.4, -0.7), amplitude=False)
    naive = identify(tests, soiptd_model(PAPER.Tp))
    corrected = identify(tests, soiptd_model(PAPER.Tp), rate_hz=rate)
    assert naive.tau.value == pytest.approx(PAPER.tau + 0.0025, rel=1e-6)
    assert corrected.tau.value == pytest.approx(PAPER.tau, rel=1e-6)
    assert corrected.Td.value == pytest.approx(PAPER.Td, rel=1e-6)


def test_k_carries_its_unit_in_every_route_and_on_the_cli():
    # eq. (2)'s K is an acceleration per command unit: identify --json wrote its unit "" (records.md: the model's
    # K_UNIT, as analyze's JSON spells it) and the text printed a bare number
    from cli_helpers import run_main
    from mrftcli.mrft.model import K_UNIT
    rng = np.random.default_rng(5)
    three = _tests(PAPER, (-0.4, -0.55, -0.7))
    noisy = [TestMeasurement(t.beta, t.frequency_mean * (1 + 0.01 * rng.standard_normal(20)),
                             t.amplitude_mean * (1 + 0.01 * rng.standard_normal(20)), 1.0) for t in three[::2]]
    for res in (identify(three[::2], soiptd_model(PAPER.Tp)), identify(three, soiptd_model(PAPER.Tp)),
                identify(noisy, soiptd_model(PAPER.Tp), n_draws=200, seed=1)):
        d = json.loads(json.dumps(res.to_json()))
        assert d["parameters"]["K"]["unit"] == K_UNIT and d["parameters"]["Td"]["unit"] == "s"
        assert IdentificationResult.from_json(d).to_json() == res.to_json()
    out = run_main("identify", "--tp", "0.1", "--test", "-0.4:0.7056:0.0785:1", "--test", "-0.7:1.0188:0.0356:1")
    assert out.returncode == 0 and f"K    1.4195 {K_UNIT}" in out.stdout.splitlines()
    js = run_main("identify", "--tp", "0.1", "--test", "-0.4:0.7056:0.0785:1", "--test", "-0.7:1.0188:0.0356:1",
                  "--json", "-")
    assert json.loads(js.stdout)["parameters"]["K"]["unit"] == K_UNIT


def test_uncertainty_from_per_cycle_scatter():
    rng = np.random.default_rng(5)
    base = _tests(PAPER, (-0.4, -0.7))
    tests = [
        TestMeasurement(t.beta, t.frequency_mean * (1 + 0.01 * rng.standard_normal(30)),
                        t.amplitude_mean * (1 + 0.01 * rng.standard_normal(30)), 1.0)
        for t in base
    ]
    res = identify(tests, soiptd_model(PAPER.Tp), n_draws=1500, seed=1)
    assert res.uncertainty == "monte-carlo"
    for est, true in ((res.Td, PAPER.Td), (res.tau, PAPER.tau), (res.K, PAPER.K)):
        assert est.std > 0
        assert est.ci95_low < est.value < est.ci95_high
        # the truth lies within 4 standard deviations of the estimate
        assert abs(est.value - true) < 4 * est.std
    # delta-method cross-check of the Monte Carlo spread of Td: finite differences of the solver
    f = np.array([t.frequency_mean for t in tests])
    se = np.array([t.frequency_sem for t in tests])
    J = []
    for i in range(2):
        fp = f.copy()
        fp[i] *= 1 + 1e-6
        r = identify([TestMeasurement(-0.4, fp[0]), TestMeasurement(-0.7, fp[1])], soiptd_model(PAPER.Tp))
        J.append((r.Td.value - res.Td.value) / (fp[i] - f[i]))
    std_delta = math.sqrt(sum((j * s) ** 2 for j, s in zip(J, se)))
    assert res.Td.std == pytest.approx(std_delta, rel=0.15)
    # "cycle" spread is larger than the standard error by about sqrt(n)
    res_c = identify(tests, soiptd_model(PAPER.Tp), n_draws=1500, seed=1, spread="cycle")
    assert res_c.Td.std > 3 * res.Td.std


def test_to_dict_is_json_ready():
    rng = np.random.default_rng(2)
    tests = [TestMeasurement(t.beta, t.frequency_mean * (1 + 0.002 * rng.standard_normal(10)), t.amplitude_mean, 1.0)
             for t in _tests(PAPER, (-0.4, -0.7))]
    d = identify(tests, soiptd_model(PAPER.Tp), n_draws=300).to_json()
    text = json.dumps(__import__("mrftcli.jsonable", fromlist=["to_jsonable"]).to_jsonable(d))
    back = json.loads(text)
    for name in ("Td", "tau", "K"):
        assert {"value", "std", "ci95_low", "ci95_high", "unit", "determined", "known", "method"} == set(
            back["parameters"][name])
    assert back["parameters"]["tau"]["unit"] == "s"
    assert len(back["tests"]) == 2


def test_td_poorly_identifiable_warning():
    # a very slow drag pole (Td * Omega in the hundreds): the frequencies barely depend on Td
    m = LoopModel(0.03, 60.0, 0.02)
    res = identify(_tests(m, (-0.4, -0.7), amplitude=False), soiptd_model(m.Tp))
    assert any("poorly identifiable" in w for w in res.warnings)
    ok = identify(_tests(PAPER, (-0.4, -0.7), amplitude=False), soiptd_model(PAPER.Tp))
    assert not any("poorly identifiable" in w for w in ok.warnings)


def test_amplitude_route_single_test():
    lc = mrft_limit_cycle(PAPER, -0.7)
    res = identify([TestMeasurement(-0.7, lc.frequency_hz, lc.amplitude, 1.0)], soiptd_model(PAPER.Tp, K=PAPER.K))
    assert res.method == "amplitude"
    assert res.Td.value == pytest.approx(PAPER.Td, rel=1e-6)
    assert res.tau.value == pytest.approx(PAPER.tau, rel=1e-6)


def test_ufm_slice_passes_through_the_plant_and_masks_negative_delays():
    lc = mrft_limit_cycle(PAPER, -0.4)
    Td = np.array([0.2, PAPER.Td, 3.0, 1e3])
    tau = ufm_slice(PAPER.Tp, -0.4, lc.frequency_hz, Td)
    assert tau[1] == pytest.approx(PAPER.tau, rel=1e-9)
    assert tau[0] > tau[1] > tau[2]  # more drag lag leaves less room for delay
    assert np.isnan(tau[3]) or tau[3] >= 0
    # interpolated manifolds agree with the exact slice to grid accuracy
    approx = ufm_slice(PAPER.Tp, -0.4, lc.frequency_hz, Td[:3], exact=False)
    np.testing.assert_allclose(approx, tau[:3], rtol=2e-3)


@pytest.mark.parametrize(
    "call, exc, match",
    [
        (lambda: identify([TestMeasurement(-0.4, 0.7)], soiptd_model(0.1)), InputError, "two tests"),
        (lambda: identify([TestMeasurement(-0.4, 0.7), TestMeasurement(-0.4, 0.8)], soiptd_model(0.1)), InputError, "same beta"),
        (lambda: identify([TestMeasurement(-0.4, 0.7), TestMeasurement(-0.7, 1.0)], soiptd_model(-0.1)), InputError, "Tp"),
        (lambda: TestMeasurement(-1.5, 0.7), InputError, "beta"),
        (lambda: TestMeasurement(-0.4, -0.7), InputError, "frequency"),
        (lambda: TestMeasurement(-0.4, 0.7, amplitude=0.1), InputError, "relay height"),
        (lambda: identify([TestMeasurement(-0.4, 0.7), TestMeasurement(-0.7, 0.5)], soiptd_model(0.1)), IdentificationError,
         "do not intersect"),
        # a frequency far too high for Tp = 0.3 s: no plant of eq. (2) can produce it
        (lambda: identify([TestMeasurement(-0.4, 40.0), TestMeasurement(-0.7, 50.0)], soiptd_model(0.3)), IdentificationError, "do not intersect|too fast"),
        (lambda: identify([TestMeasurement(-0.4, 0.7), TestMeasurement(-0.7, 1.0)], soiptd_model(0.1), rate_hz=0), InputError, "rate"),
    ],
)
def test_errors(call, exc, match):
    with pytest.raises(exc, match=match):
        call()


def test_inputs_are_not_modified():
    f = np.array([0.70, 0.71, 0.705])
    before = f.copy()
    identify([TestMeasurement(-0.4, f), TestMeasurement(-0.7, [1.01, 1.02, 1.03])], soiptd_model(0.1), n_draws=200)
    np.testing.assert_array_equal(f, before)


def test_three_tests_delta_method_uncertainty():
    m = LoopModel(0.04, 0.9, 0.025)
    rng = np.random.default_rng(8)
    tests = [TestMeasurement(t.beta, t.frequency_mean * (1 + 0.01 * rng.standard_normal(25)))
             for t in _tests(m, (-0.8, -0.5, -0.2), amplitude=False)]
    res = identify(tests, soiptd_model(m.Tp))
    assert res.uncertainty == "delta"
    for est, true in ((res.Td, m.Td), (res.tau, m.tau)):
        assert est.std > 0
        assert est.ci95_low < est.value < est.ci95_high
        assert abs(est.value - true) < 4 * est.std


def test_rate_quantisation_uncertainty_reported():
    # nominal betas at 200 Hz: which sampled orbit each test ran on is unknown -> tau has a spread
    tests = [TestMeasurement(b, mrft_limit_cycle(PAPER, b, rate_hz=200.0).frequency_hz) for b in (-0.4, -0.7)]
    res = identify(tests, soiptd_model(PAPER.Tp), rate_hz=200.0, n_draws=500)
    assert res.uncertainty == "monte-carlo"
    assert res.tau.value == pytest.approx(PAPER.tau, rel=1e-6)
    assert 0.5e-3 < res.tau.std < 0.01
    assert res.tau.ci95_low < PAPER.tau < res.tau.ci95_high


def test_bad_spread_and_test_objects():
    t = [TestMeasurement(-0.4, 0.7), TestMeasurement(-0.7, 1.0)]
    with pytest.raises(InputError, match="spread"):
        identify(t, soiptd_model(0.1), spread="bogus")
    with pytest.raises(InputError, match="TestMeasurement"):
        identify([(-0.4, 0.7), (-0.7, 1.0)], soiptd_model(0.1))


def test_identification_json_round_trip():
    """to_json -> plain JSON -> from_json gives the same record (draws excepted), with and without K."""
    noisy = [TestMeasurement(-0.4, [0.7049, 0.7063, 0.7058], amplitude=[0.078, 0.0785], h=1.0),
             TestMeasurement(-0.7, [1.0180, 1.0195, 1.0189])]
    for res in (identify(noisy, soiptd_model(0.1), n_draws=50), identify(_tests(PAPER, (-0.2, -0.4, -0.7), amplitude=False), soiptd_model(0.1))):
        d = json.loads(json.dumps(res.to_json()))
        assert d["schema_version"] == 3 and d["model"]["family"] == "soiptd" and d["strategy"] == "unit-manifolds"
        back = IdentificationResult.from_json(d)
        assert back.to_json() == res.to_json()
        assert back.model == res.model and back.n_draws == res.n_draws and back.draws == {}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.update(schema_version=0), r"schema_version 0 is not supported \(this version reads 1, 2, 3\)"),
        (lambda d: d.pop("parameters"), "needs 'model' and 'parameters' objects"),
        (lambda d: d["parameters"]["Td"].update(value="x"), "'Td' needs a numeric value"),
        (lambda d: d["parameters"].update(Td=None), "'Td' needs a numeric value"),  # only K may be null
        (lambda d: d["parameters"].pop("tau"), "'parameters' needs 'tau'"),
        (lambda d: d.update(warnings="none"), "needs 'tests' \\(objects\\) and 'warnings' \\(strings\\)"),
        (lambda d: d.update(residual="small"), "residual, got 'small'"),
        (lambda d: d["model"].update(schema_version=9), "model JSON: schema_version 9 is not supported"),
    ],
)
def test_identification_json_errors(change, message):
    d = json.loads(json.dumps(identify(_tests(PAPER, (-0.4, -0.7)), soiptd_model(PAPER.Tp)).to_json()))
    change(d)
    with pytest.raises(InputError, match=message) as err:
        IdentificationResult.from_json(d)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("version", [1, 2])
def test_identification_json_old_versions_still_read(version):
    """A version-1 record (``mean`` per parameter; before issue 36's one parameter record) and a version-2 one
    (eq. (2)'s own layout before the one identification record; tests/data/old_records/identification_v1.json,
    _v2.json, each written by the code of its time) read with the same figures and write back as version 3."""
    old = json.loads((Path(__file__).parent / "data" / "old_records" / f"identification_v{version}.json").read_text())
    assert old["schema_version"] == version and "strategy" not in old
    back = IdentificationResult.from_json(old)
    noisy = [TestMeasurement(-0.4, [0.7049, 0.7063, 0.7058], amplitude=[0.078, 0.0785], h=1.0),
             TestMeasurement(-0.7, [1.0180, 1.0195, 1.0189])]
    now = identify(noisy, soiptd_model(0.1), n_draws=50)  # the same tests today: the same numbers
    for name in ("Td", "tau", "K"):
        was = old["parameters"][name]
        est = getattr(back, name)
        assert (est.value, est.std, est.ci95_low, est.ci95_high) == (was.get("mean", was.get("value")), was["std"],
                                                                     was["ci95_low"], was["ci95_high"])
        assert est == getattr(now, name), name
    d = json.loads(json.dumps(back.to_json()))
    assert d["schema_version"] == 3 and d["strategy"] == "unit-manifolds" and back.Tp == 0.1
    assert {k: d[k] for k in ("tests", "warnings", "method", "residual")} == {k: old[k] for k in
                                                                            ("tests", "warnings", "method", "residual")}
    assert d["parameters"]["Tp"] == {"value": 0.1, "std": 0.0, "ci95_low": 0.1, "ci95_high": 0.1, "unit": "s",
                                     "determined": True, "known": True, "method": "given"}
    assert list(d["parameters"]["Td"]) == ["value", "std", "ci95_low", "ci95_high", "unit", "determined", "known",
                                           "method"]


def test_one_identification_record_reads_by_the_model_and_refuses_another_strategys():
    """IdentificationRecord.from_json gives eq. (2)'s record for a soiptd model; the families' reader refuses it in one line."""
    from mrftcli.mrft.identification import IdentificationRecord
    from mrftcli.mrft.identify_lti import LtiIdentification

    d = json.loads(json.dumps(identify(_tests(PAPER, (-0.4, -0.7)), soiptd_model(PAPER.Tp)).to_json()))
    back = IdentificationRecord.from_json(d)
    assert isinstance(back, IdentificationResult) and back.to_json() == d
    assert [e.name for e in back.estimates] == ["Td", "tau", "K", "Tp"] and back.estimate("Tp").known
    with pytest.raises(InputError, match="a soiptd model's record \\(unit-manifolds\\), not a LtiIdentification") as err:
        LtiIdentification.from_json(d)
    assert "\n" not in str(err.value)


def test_one_identify_for_every_family_each_by_its_strategy():
    """identify(data, model): the model's family picks the strategy and with it the data it takes; a process
    family's exact response points give its plant back (the closed form G(j w) as the oracle)."""
    from mrftcli.mrft.families import FOPDT, family_model
    from mrftcli.mrft.identify import ResponsePoint, strategy_of

    assert [strategy_of(m).name for m in (soiptd_model(0.1), family_model("sopdt"))] == \
        ["unit-manifolds", "response-points"]
    true = FOPDT(K=2.0, T=0.5, tau=0.1)
    w = np.array([2.0, 6.0, 15.0])
    points = [ResponsePoint(wi, abs(g), float(np.angle(g)), 0.01, 0.01, i) for i, (wi, g)
              in enumerate(zip(w, true.frequency_response(w)))]
    fit = identify(points, family_model("fopdt"))
    assert [fit.estimate(n).value for n in ("K", "T", "tau")] == pytest.approx([2.0, 0.5, 0.1], rel=1e-6)
    eq2 = identify(_tests(PAPER, (-0.4, -0.7)), soiptd_model(PAPER.Tp))
    assert (eq2.Td.value, eq2.tau.value, eq2.Tp) == (pytest.approx(PAPER.Td, rel=1e-4), pytest.approx(0.06, abs=1e-5),
                                                     PAPER.Tp)
    with pytest.raises(InputError, match="fopdt model is identified from ResponsePoint"):
        identify(_tests(PAPER, (-0.4, -0.7)), family_model("fopdt"))
    with pytest.raises(InputError, match="soiptd model is identified from TestMeasurement"):
        identify(points, soiptd_model(0.1))
    with pytest.raises(InputError, match="fit_response_points takes no options, not rate_hz"):
        identify(points, family_model("fopdt"), rate_hz=100.0)
    from mrftcli.mrft.cascade import CascadeModel, InnerLoop
    from mrftcli.mrft.controller import Controller

    cascade = CascadeModel(InnerLoop(PAPER, Controller(0.4, 0.0, 0.05, 0.005, 200.0)), 1.0, 0.0)
    with pytest.raises(InputError, match="fit_cascade_cycles needs rate_hz"):
        identify(_tests(PAPER, (-0.4, -0.7)), cascade)
    with pytest.raises(InputError, match="plant model"):
        identify(points, "fopdt")
