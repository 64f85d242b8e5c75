"""mrft-ident plan: the planner's predictions against independent oracles, and its refusals."""

from __future__ import annotations

import json
import math
import subprocess

import numpy as np
import pytest
from click.testing import CliRunner
from cli_helpers import run_main

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalyzeOptions
from mrftcli.cli.main import cli
from mrftcli.errors import InputError, InsufficientDataError
from mrftcli.mrft.lprs import mrft_limit_cycle
from mrftcli.mrft.model import LoopModel
from mrftcli.plan import (PlanLimits, FlownTest, PlanOptions, PlanResult, Prior, cycle_noise, fisher_information,
                          plan_tests, simulated_flights)


def _narrow_prior(Td=0.8, tau=0.03, K=2.0) -> Prior:
    return Prior(Td=(Td * 0.999, Td * 1.001), tau=(tau * 0.999, tau * 1.001), K=(K * 0.999, K * 1.001))


def test_fisher_information_of_the_phase_constraint_is_its_closed_form():
    # phase alone: tau_phi(Td) = (-phi - pi/2 - atan(Tp W) - atan(Td W)) / W, so the residual
    # tau - tau_phi has gradient (W / (1 + (Td W)^2) / W, 1, 0); information = g g^T / var
    Tp, Td, W, sphi, n = 0.04, 0.7, 5.0, 0.01, 9
    I = fisher_information(Tp, Td, 1.0, -0.5, W, 0.05, n,
                           {"ufm": math.inf, "phase": sphi, "ln_amplitude": math.inf})
    g = np.array([1.0 / (1.0 + (Td * W) ** 2), 1.0, 0.0])
    var = (sphi**2 / n + 3e-4**2) / W**2
    np.testing.assert_allclose(I, np.outer(g, g) / var, rtol=1e-12)


def test_fisher_information_of_the_ufm_slice_matches_a_finite_difference_of_the_lprs():
    # the slice's d tau / d Td, checked against the exact limit cycle: moving Td by dTd and tau by
    # (d tau_i / d Td) dTd keeps the frequency (the plant stays on the slice)
    Tp, Td, tau, beta = 0.04, 0.8, 0.03, -0.6
    w = mrft_limit_cycle(LoopModel(Tp, Td, tau), beta).omega
    I = fisher_information(Tp, Td, 1.0, beta, w, 0.05, 1, {"ufm": 1e-3, "phase": math.inf, "ln_amplitude": math.inf})
    slope = -I[0, 1] / I[1, 1]  # row (-d tau_i/d Td, 1, 0): I01 / I11 = -d tau_i / d Td
    dTd = 1e-3 * Td
    w2 = mrft_limit_cycle(LoopModel(Tp, Td + dTd, tau + slope * dTd), beta).omega
    w_off = mrft_limit_cycle(LoopModel(Tp, Td + dTd, tau), beta).omega
    assert abs(w2 / w - 1) < 1e-2 * abs(w_off / w - 1)  # first order gone; second order stays


def test_predicted_cycle_is_the_exact_sampled_lprs():
    model = LoopModel(0.04, 0.8, 0.03, 2.0)
    limits = PlanLimits(max_amplitude=0.05, max_h=10.0, time_s=20.0, rate_hz=200.0, noise_std=0.0005)
    p = plan_tests(soiptd_model(model.Tp), limits, prior=_narrow_prior(), options=PlanOptions(n_tests=1, n_draws=2, betas=(-0.3, -0.6)))
    t = p.tests[0]
    lc = mrft_limit_cycle(model, t.beta, t.h, 200.0)
    assert t.frequency_hz == pytest.approx(lc.frequency_hz, rel=2e-3)
    assert t.amplitude == pytest.approx(lc.amplitude, rel=2e-3)
    assert t.amplitude <= 0.05 * 1.002  # the limit holds
    assert t.orbits_hz and min(t.orbits_hz) <= t.frequency_hz <= max(t.orbits_hz)
    assert t.n_cycles == math.floor(20.0 * t.frequency_hz) - 3


def test_predicted_cycle_matches_a_simulated_flight():
    from mrftcli.segment import segment
    from mrftcli.sim import FlightSpec, TestSpec, simulate_flight
    from test_segment_support import flight_from_simulated

    model = LoopModel(0.04, 0.8, 0.03, 2.0)
    limits = PlanLimits(max_amplitude=0.05, max_h=10.0, time_s=10.0, rate_hz=200.0, noise_std=0.0005)
    t = plan_tests(soiptd_model(model.Tp), limits, prior=_narrow_prior(), options=PlanOptions(n_tests=1, n_draws=2, betas=(-0.5,))).tests[0]
    sf = simulate_flight(FlightSpec(model=model, tests=(TestSpec(t.beta, t.h, t.duration_s),), rate_hz=200.0,
                                    noise_std=0.0005, seed=5, hover_s=2.0, hold_s=1.0))
    (found,) = segment(flight_from_simulated(sf))
    assert found.frequency_hz_mean == pytest.approx(t.frequency_hz, rel=0.03)
    assert found.amplitude_mean == pytest.approx(t.amplitude, rel=0.05)
    assert abs(found.n_stable - t.n_cycles) <= 2


def test_noise_model_grows_with_the_sensor_noise():
    quiet = cycle_noise(0.05, 6.0, 0.3, 200.0, 1e-4)
    loud = cycle_noise(0.05, 6.0, 0.3, 200.0, 1e-3)
    assert all(loud[k] > quiet[k] for k in quiet)


def test_refuses_when_the_limits_admit_no_test():
    limits = PlanLimits(max_amplitude=1e-5, max_h=1.0, time_s=20.0, rate_hz=200.0, noise_std=0.0005)
    with pytest.raises(InputError, match="admit no MRFT test.*--max-amplitude"):
        plan_tests(soiptd_model(0.04), limits, prior=_narrow_prior(), options=PlanOptions(n_tests=1, n_draws=2, betas=(-0.5,)))


def test_flags_td_when_no_test_can_pin_it_down():
    # a slow drag (Td 3 s) on a fast loop: Td * Omega >> 5 for every beta
    limits = PlanLimits(max_amplitude=0.05, max_h=10.0, time_s=20.0, rate_hz=200.0, noise_std=0.0005)
    prior = Prior(Td=(2.5, 3.0), tau=(0.01, 0.012), K=(2.0, 2.1))
    p = plan_tests(soiptd_model(0.02), limits, prior=prior, options=PlanOptions(n_tests=1, n_draws=2, betas=(-0.3, -0.6)))
    assert any("Td cannot be pinned down" in n for n in p.notes)


def test_a_flown_test_is_counted_and_not_repeated():
    model = LoopModel(0.04, 0.8, 0.03, 2.0)
    lc = mrft_limit_cycle(model, -0.4, 1.0, 200.0)
    flown = FlownTest(beta=-0.4, h=1.0, frequency_hz=lc.frequency_hz, amplitude=lc.amplitude, n_cycles=10)
    limits = PlanLimits(max_amplitude=0.05, max_h=10.0, time_s=15.0, rate_hz=200.0, noise_std=0.0005)
    p = plan_tests(soiptd_model(model.Tp), limits, prior=Prior(Td=(0.3, 2.0), tau=(0.01, 0.06), K=(1.0, 4.0)), flown=[flown], options=PlanOptions(n_draws=3, betas=(-0.4, -0.6, -0.8)))
    assert len(p.tests) == 1 and abs(p.tests[0].beta + 0.4) > 0.1  # one new slice, not the same again
    # the flown test plus the new one say more than the prior alone
    assert all(p.predicted_std[k] < p.prior_std[k] for k in ("Td", "tau", "K"))


@pytest.mark.parametrize("args, needle", [
    (["--tp", "0.04", "--max-amplitude", "0.05", "--max-h", "1", "--time", "-3"], "time available"),
    (["--tp", "0.04", "--max-amplitude", "0", "--max-h", "1", "--time", "20"], "largest amplitude"),
    (["--tp", "0.04", "--max-amplitude", "0.05", "--max-h", "1", "--time", "20", "--td-range", "2", "1"],
     "Td range"),
    (["--tp", "0", "--max-amplitude", "0.05", "--max-h", "1", "--time", "20"], "Tp"),
])
def test_cli_bad_input_is_one_line_and_non_zero(args, needle, capsys):
    from mrftcli.cli.main import main

    with pytest.raises(SystemExit) as exc:
        main(["plan", *args, "--controller-rate", "200"])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and needle in err and "\n" not in err and "Traceback" not in err


def test_cli_json_from_an_analyze_result(tmp_path):
    model = LoopModel(0.04, 0.8, 0.03, 2.0)
    lc = mrft_limit_cycle(model, -0.4, 1.0, 200.0)
    src = tmp_path / "first.json"
    src.write_text(json.dumps({"partial": {"tests": [{"beta": -0.4, "h": 1.0, "frequency_hz": lc.frequency_hz,
                                                      "amplitude": lc.amplitude, "cycles": 10}]}}))
    res = CliRunner().invoke(cli, ["plan", "--tp", "0.04", "--from", str(src), "--td-range", "0.3", "2",
                                   "--max-amplitude", "0.05", "--max-h", "5", "--time", "15", "--controller-rate", "200", "--json", "-"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    assert len(data["tests"]) == 1 and data["flown_tests"][0]["beta"] == -0.4
    t = data["tests"][0]
    assert -0.9 <= t["beta"] <= -0.1 and t["amplitude"] <= 0.05 * 1.01 and t["h"] <= 5
    assert set(data["predicted_std"]) == {"Td", "tau", "K"}


def test_a_beta_whose_switch_noise_would_trigger_is_not_recommended():
    # beta -0.9 switches once the error is 10 % below its extremum: with the exact amplitude a of the
    # capped test, (1 + beta) a / noise is computed here from the LPRS, independently of the planner
    model = LoopModel(0.04, 0.8, 0.03, 2.0)
    limits = PlanLimits(max_amplitude=0.02, max_h=10.0, time_s=20.0, rate_hz=200.0, noise_std=0.0002)
    betas = (-0.5, -0.9)
    gap = {b: (1 + b) * 0.02 / 0.0002 for b in betas}  # h is set so the amplitude is the limit
    assert gap[-0.9] < 16 < gap[-0.5]
    quiet = PlanLimits(max_amplitude=0.02, max_h=10.0, time_s=20.0, rate_hz=200.0, noise_std=0.00002)
    # without the noise the planner prefers -0.9 here (its slice crosses -0.4's more steeply) ...
    assert plan_tests(soiptd_model(model.Tp), quiet, prior=_narrow_prior(), options=PlanOptions(n_tests=1, n_draws=2, betas=betas)).tests[0].beta == -0.9
    # ... with it, -0.9 is set aside, and the plan says why
    p = plan_tests(soiptd_model(model.Tp), limits, prior=_narrow_prior(), options=PlanOptions(n_tests=1, n_draws=2, betas=betas))
    assert p.tests[0].beta == -0.5
    row = {c.beta: c for c in p.candidates}[-0.9]
    assert row.early_switch and "noise stds below the extremum" in row.reason
    assert row.h is not None and row.switch_gap is not None
    lc = mrft_limit_cycle(model, -0.9, row.h, 200.0)
    assert row.switch_gap == pytest.approx(0.1 * lc.amplitude / 0.0002, rel=0.05)


def test_forecast_is_the_typical_draw_inside_its_range():
    limits = PlanLimits(max_amplitude=0.05, max_h=10.0, time_s=20.0, rate_hz=200.0, noise_std=0.0005)
    p = plan_tests(soiptd_model(0.04), limits, prior=Prior(Td=(0.3, 2.0), tau=(0.01, 0.06), K=(1.0, 4.0)), options=PlanOptions(n_tests=2, n_draws=6, betas=(-0.3, -0.6)))
    for k in ("Td", "tau", "K"):
        lo, hi = p.predicted_std_data_range[k]
        assert 0 < lo <= p.predicted_std_data[k] <= hi
    assert p.to_json()["predicted_std_tests_only_range"]["Td"] == list(p.predicted_std_data_range["Td"])


def test_simulated_forecast_matches_the_scatter_of_repeat_flights():
    # oracle: the spread of the MRFT estimate over independent flights of the known plant (fresh
    # noise seeds, built here) - the sampling std the bootstrap forecast stands for
    from mrftcli.analyze import analyze_flight
    from mrftcli.sim import FlightSpec, TestSpec, simulate_flight
    from test_segment_support import flight_from_simulated

    model = LoopModel(0.04, 0.8, 0.03, 2.0)
    lc = mrft_limit_cycle(model, -0.4, 1.0, 200.0)
    h1 = 0.03 / lc.amplitude
    flown = FlownTest(beta=-0.4, h=h1, frequency_hz=lc.frequency_hz, amplitude=0.03, n_cycles=11)
    limits = PlanLimits(max_amplitude=0.04, max_h=10.0, time_s=10.0, rate_hz=200.0, noise_std=0.0005)
    p = plan_tests(soiptd_model(model.Tp), limits, prior=_narrow_prior(), flown=[flown], options=PlanOptions(n_draws=2, n_simulated=3, betas=(-0.6, -0.8)))
    assert p.n_simulated >= 2 and p.to_json()["simulated_std"] == p.simulated_std
    t = p.tests[0]
    est = []
    for seed in range(12):
        sf = simulate_flight(FlightSpec(model=model, tests=(TestSpec(-0.4, h1, 14 / lc.frequency_hz),
                                                            TestSpec(t.beta, t.h, t.duration_s)),
                                        rate_hz=200.0, noise_std=0.0005, seed=1000 + seed, hover_s=2.0, hold_s=2.0))
        try:
            r = analyze_flight(flight_from_simulated(sf), soiptd_model(model.Tp), options=AnalyzeOptions(n_bootstrap=10, refine_waveform=False))
        except InsufficientDataError:  # a test lost to noise now and then
            continue
        est.append((r.Td.value, r.tau.value))
    assert len(est) >= 9
    spread = np.std(est, axis=0, ddof=1)
    assert 1 / 2.5 < p.simulated_std["Td"] / spread[0] < 2.5
    assert 1 / 2.5 < p.simulated_std["tau"] / spread[1] < 2.5


def test_simulated_forecast_says_when_the_flights_fail():
    # a noise far above the amplitude: analyze cannot use the simulated flights, and the plan says so
    flown = FlownTest(beta=-0.4, h=1.0, frequency_hz=2.0, amplitude=0.03, n_cycles=8)
    limits = PlanLimits(max_amplitude=0.04, max_h=10.0, time_s=10.0, rate_hz=200.0, noise_std=0.0005)
    p = plan_tests(soiptd_model(0.04), limits, prior=_narrow_prior(), flown=[flown], options=PlanOptions(n_draws=2, betas=(-0.6,)))
    s, _ = simulated_flights(
        soiptd_model(0.04), np.array([[0.8, 0.03, 2.0]]), [flown], p.tests,
        PlanLimits(max_amplitude=0.04, max_h=10.0, time_s=10.0, rate_hz=200.0, noise_std=0.5))
    assert np.isnan(s).all()


def _plan_for_json() -> PlanResult:
    flown = FlownTest(beta=-0.4, h=1.0, frequency_hz=2.0, amplitude=0.03, n_cycles=8)
    limits = PlanLimits(max_amplitude=0.04, max_h=10.0, time_s=10.0, rate_hz=200.0, noise_std=0.0005)
    return plan_tests(soiptd_model(0.04), limits, prior=_narrow_prior(), flown=[flown], options=PlanOptions(n_draws=2, betas=(-0.6, -0.9)))


def test_plan_result_round_trips_through_json():
    p = _plan_for_json()
    data = json.loads(json.dumps(p.to_json()))  # through text, as a plan --json file
    assert data["schema_version"] == 2
    back = PlanResult.from_json(data)
    assert back == p  # the flown test has no phase, the one field the JSON leaves out
    assert back.to_json() == p.to_json()


def test_plan_json_of_version_1_reads_and_today_plans_the_same():
    """tests/data/old_records/plan_v1.json, written by mrft-ident before issue 36 (schema 1, Tp where the model
    object is now): ``plan --tp 0.0422 --max-amplitude 0.05 --max-h 0.2 --time 30 --controller-rate 200
    --noise 0.0002 --k-range 2 8 --simulate 0 --json``. It reads with its figures, and the same plan made
    today recommends the same tests with the same forecast (the old code is the oracle)."""
    from pathlib import Path

    data = json.loads((Path(__file__).parent / "data" / "old_records" / "plan_v1.json").read_text())
    old = PlanResult.from_json(data)
    assert data["schema_version"] == 1 and old.Tp == 0.0422 and old.rate_hz == 200.0
    assert [(t.beta, t.h, t.frequency_hz) for t in old.tests] == [(t["beta"], t["h"], t["frequency_hz"])
                                                                 for t in data["tests"]]
    assert old.to_json()["schema_version"] == 2  # written back in the new layout
    limits = PlanLimits(max_amplitude=0.05, max_h=0.2, time_s=30.0, rate_hz=200.0, noise_std=0.0002)
    new = plan_tests(soiptd_model(0.0422), limits, prior=Prior(K=(2.0, 8.0)), options=PlanOptions(n_simulated=0))
    assert (new.tests, new.candidates, new.conventional, new.notes) == (old.tests, old.candidates, old.conventional,
                                                                        old.notes)
    assert (new.predicted_std, new.predicted_std_data, new.prior_std) == (old.predicted_std, old.predicted_std_data,
                                                                          old.prior_std)


def test_plan_result_json_keeps_the_cli_fields():
    # the JSON of plan --json before the record was versioned, plus schema_version, (issue 26) assumptions and
    # (issue 36) the model object and the rate instead of Tp
    keys = ["schema_version", "assumptions", "model", "rate_hz", "tests", "predicted_std", "predicted_std_tests_only",
            "predicted_std_tests_only_range", "simulated_std", "simulated_std_range", "n_simulated", "prior_std",
            "conventional", "candidates", "notes", "flown_tests", "limits"]
    data = _plan_for_json().to_json()
    assert list(data) == keys
    assert {c["beta"] for c in data["candidates"]} == {-0.6, -0.9}
    searched = [c for c in data["candidates"] if "predicted_std" in c]
    assert searched and all(c["admissible"] for c in searched)


@pytest.mark.parametrize("data, needle", [
    ([1, 2], "expected a JSON object"),
    ({"Tp": 0.04}, "no schema_version"),
    ({"schema_version": 3}, "schema_version 3 is not supported"),
    ({"schema_version": 1, "Tp": 0.04}, "not a valid plan --json result"),
    ({"schema_version": 2, "model": {}}, "not a valid plan --json result"),
])
def test_plan_result_from_json_refuses_bad_input_in_one_line(data, needle):
    with pytest.raises(InputError, match=needle) as exc:
        PlanResult.from_json(data)
    assert "\n" not in str(exc.value)


def test_flown_tests_and_prior_of_an_analyze_result_json():
    # an analyze --json result read back through AnalysisResult.from_json: the tests as analyze
    # wrote them, and the prior ranges from its estimates (mean +/- 2 std)
    from pathlib import Path

    from mrftcli.analyze import analyze_path
    from mrftcli.jsonable import to_jsonable
    from mrftcli.plan import flown_from_result, prior_range

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "design1_altitude.mcap"
    data = json.loads(json.dumps(to_jsonable(analyze_path(log, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=20)).to_json())))
    flown, params = flown_from_result(data)
    assert [(f.beta, f.h, f.frequency_hz, f.amplitude, f.n_cycles) for f in flown] == [
        (t["beta"], t["h"], t["frequency_hz"], t["amplitude"], t["cycles"]) for t in data["tests"]]
    td = data["parameters"]["Td"]
    assert prior_range(params["Td"], (0.2, 3.0)) == pytest.approx(
        (max(td["value"] - 2 * td["std"], td["value"] / 10), td["value"] + 2 * td["std"]))
    with pytest.raises(InputError, match="schema_version"):
        flown_from_result({**data, "schema_version": 99})


# issue 26 item 3: from the CLI as the user meets it

def _plan_cli(*args: str) -> subprocess.CompletedProcess[str]:
    """``mrft-ident plan ARGS`` through main() in this process (a subprocess only adds its imports' CPU)."""
    return run_main("plan", *args)


LIMITS = ["--tp", "0.0422", "--max-amplitude", "0.05", "--max-h", "0.2", "--time", "30", "--controller-rate", "200"]


def test_cli_refusal_names_the_options_that_help():
    # 0.5 mm of assumed noise at 200 Hz: even the largest 5 cm cycle moves < 4 noise stds per tick
    proc = _plan_cli(*LIMITS, "--simulate", "0")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1
    err = proc.stderr
    assert "--noise" in err and "--k-range" in err and "assumed" in err and "altitude loop's default" in err


def test_cli_states_its_assumptions_first_and_in_the_json():
    proc = _plan_cli(*LIMITS, "--noise", "0.0002", "--k-range", "2", "8", "--simulate", "0", "--json", "-")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert [a.split()[1] for a in data["assumptions"]] == ["Td", "tau"]  # K and the noise were given
    again = PlanResult.from_json(data)
    assert again.assumptions == tuple(data["assumptions"])
    text = _plan_cli(*LIMITS, "--noise", "0.0002", "--k-range", "2", "8", "--simulate", "0").stdout
    assert text.splitlines()[0].startswith("assumption: prior Td 0.2-3 s")
    # K's prior in K's unit (an acceleration per command unit, as the table's "m/s² per command unit")
    k_line = _plan_cli(*LIMITS, "--noise", "0.0002", "--simulate", "0").stdout.splitlines()[2]
    assert k_line == "assumption: prior K 0.5-20 output / (command s^2) (the default; give --k-range)"


def test_cli_without_a_rate_names_the_option():
    proc = _plan_cli(*LIMITS[:-2], "--noise", "0.0002", "--simulate", "0")
    assert proc.returncode == 2 and "--controller-rate" in proc.stderr


def test_a_recommendation_its_simulation_loses_is_not_made():
    """The wide default K prior (40x) under 0.2 mm noise: the low-gain plants cycle too small and analyze
    loses the planned tests in simulation, so no test is recommended; with the prior narrowed, it is."""
    proc = _plan_cli(*LIMITS, "--noise", "0.0002", "--simulate", "8")
    assert proc.returncode == 2 and "flies reliably" in proc.stderr and "--k-range" in proc.stderr
    ok = _plan_cli(*LIMITS, "--noise", "0.0002", "--k-range", "2", "8", "--simulate", "8", "--json", "-")
    assert ok.returncode == 0, ok.stderr
    data = json.loads(ok.stdout)
    assert data["n_simulated"] >= 7  # at most one of the 8 simulated flights lost


def test_eq2_is_planned_with_tp_known_and_the_rest_free():
    # K known too would leave analyze (the simulated forecast) and the draws at odds with the plan: refused
    limits = PlanLimits(max_amplitude=0.05, max_h=2.0, time_s=30.0, rate_hz=200.0, noise_std=0.0005)
    with pytest.raises(InputError, match="soiptd_model"):
        plan_tests(soiptd_model(0.04, K=2.0), limits, prior=_narrow_prior())
    with pytest.raises(InputError, match="Prior"):
        plan_tests(soiptd_model(0.04), limits)


def test_plan_limits_one_record_for_a_flight_and_a_relay_test():
    # eq. (2)'s flight needs all five (amplitude and height included); a relay test's two are optional
    flight = PlanLimits(max_amplitude=0.05, max_h=0.2, time_s=30.0, rate_hz=200.0, noise_std=0.0002)
    assert flight.flight and flight.bounds() == (0.05, 0.2)
    assert list(flight.to_json()) == ["max_amplitude", "max_h", "time_s", "rate_hz", "noise_std"]
    assert PlanLimits.from_json(json.loads(json.dumps(flight.to_json()))) == flight
    relay = PlanLimits(max_amplitude=None, max_h=2.0)
    assert not relay.flight and relay.to_json() == {"max_amplitude": None, "max_h": 2.0}
    assert PlanLimits.from_json(relay.to_json()) == relay
    with pytest.raises(InputError, match="--max-amplitude"):
        PlanLimits(max_h=0.2, time_s=30.0, rate_hz=200.0, noise_std=0.0002)
    with pytest.raises(InputError, match="--noise"):
        PlanLimits(max_amplitude=0.05, max_h=0.2, time_s=30.0, rate_hz=200.0, noise_std=-1.0)
    with pytest.raises(InputError, match="Prior and a flight"):
        plan_tests(soiptd_model(0.04), relay, prior=Prior(Td=(0.3, 2.0), tau=(0.01, 0.06), K=(1.0, 4.0)))
