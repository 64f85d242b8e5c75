"""The output-error refinement (mrftcli.mrft.refine): accepted on clean logs and closer to the truth,
refused with the reason on logs with physics eq. (2) leaves out, honest std, one-sided Td bound.

Oracles: the project's simulator (sim.flight, the plant it flew is the truth; its Effects add the
physics), and a white-noise series for the noise estimate.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mrftcli.analyze import analyze_flight
from mrftcli.jsonable import to_jsonable
from mrftcli.mrft.model import LoopModel
from mrftcli.mrft.refine import RESIDUAL_FACTOR, sensor_noise
from mrftcli.sim.flight import Effects, FlightSpec, plan_test, simulate_flight
from test_segment_support import flight_from_simulated

D1 = dict(Tp=0.0422, Td=2.669, tau=0.0464, K=19.6)


def _flight(effects=Effects(), seed=3, Td=D1["Td"], rate_hz=200.0, noise_std=None, betas=(-0.4, -0.7)):
    model = LoopModel(D1["Tp"], Td, D1["tau"], D1["K"])
    tests = tuple(plan_test(model, b, 0.05, cycles=12, min_duration=4.0) for b in betas)
    spec = FlightSpec(model=model, tests=tests, loop="altitude", switching="hear", seed=seed, effects=effects,
                      rate_hz=rate_hz, noise_std=noise_std)
    return flight_from_simulated(simulate_flight(spec))


def test_sensor_noise_of_white_noise_on_a_smooth_signal():
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 30.0, 0.005)
    y = 0.05 * np.sign(np.sin(2 * np.pi * 1.1 * t)).cumsum() * 0.005 + 0.0007 * rng.standard_normal(t.size)
    assert sensor_noise([y]) == pytest.approx(0.0007, rel=0.05)


def test_clean_log_accepted_and_closer_than_mrft():
    r = analyze_flight(_flight(), D1["Tp"], n_bootstrap=100)
    ref = r.refinement
    assert r.method == "waveform" and ref.accepted and not ref.reasons
    assert ref.residual_ratio <= RESIDUAL_FACTOR
    mrft = r.parameters_mrft
    for name in ("tau", "K", "Td"):
        assert abs(getattr(r, name).mean - D1[name]) < abs(mrft[name].mean - D1[name]) + 0.5 * mrft[name].std, name
        assert getattr(r, name).std < mrft[name].std


@pytest.mark.parametrize("effects, why", [
    (Effects(delay_jitter=0.005), "residual"),
    (Effects(gain_drift=0.005), "residual"),
    (Effects(sensor_lag=0.03), "residual"),
])
def test_refused_with_the_reason_when_the_model_does_not_hold(effects, why):
    r = analyze_flight(_flight(effects), D1["Tp"], n_bootstrap=100)
    ref = r.refinement
    assert r.method == "mrft" and not ref.accepted
    assert any(why in x for x in ref.reasons)
    # the reported estimate is the MRFT one, and the user is told why and what to run
    assert r.tau is r.parameters_mrft["tau"] and r.K is r.parameters_mrft["K"]
    assert any("waveform refinement was not used" in w and "diagnose" in w for w in r.warnings)
    d = r.to_dict(cycles=False)
    assert d["parameters"]["tau"]["method"] == "mrft" and d["refinement"]["accepted"] is False


def test_interval_coverage_on_seeded_plants():
    """The refined 95 % intervals hold the truth (the simulator's plant) in >= 90 % of the cases."""
    rng = np.random.default_rng(16)
    hits, n = 0, 0
    for k in range(4):
        Td = float(np.exp(rng.uniform(np.log(0.5), np.log(3.0))))
        r = analyze_flight(_flight(seed=100 + k, Td=Td, rate_hz=float(rng.choice([100.0, 250.0]))), D1["Tp"],
                           n_bootstrap=50)
        assert r.method == "waveform", r.refinement.reasons
        truth = {"Td": Td, "tau": D1["tau"], "K": D1["K"]}
        for name in ("Td", "tau", "K"):
            e = getattr(r, name)
            hits += e.ci95_low <= truth[name] <= e.ci95_high
            n += 1
    assert hits >= 0.9 * n, (hits, n)


def test_no_linear_damping_gives_a_one_sided_td_bound(tmp_path):
    """Issue 12 item 8: a double integrator with motor lag and delay (Td -> infinity)."""
    from mrftcli.cli.analyze import format_table
    from mrftcli.report.analysis import write_analysis_report

    from test_segment_support import simulate_paper_flight

    sf = simulate_paper_flight(D1["Tp"], 1e4, D1["tau"], D1["K"], (-0.4, -0.7), seed=7)
    r = analyze_flight(flight_from_simulated(sf), D1["Tp"], n_bootstrap=100)
    assert math.isfinite(r.Td.ci95_low) and not math.isfinite(r.Td.ci95_high)
    assert r.Td.ci95_low > 5.0  # the data do bound it from below
    assert any(w.startswith("Td > ") and "cannot bound it from above" in w for w in r.warnings)
    d = json.loads(json.dumps(to_jsonable(r.to_dict(cycles=False))))
    assert d["parameters"]["Td"]["ci95_high"] is None and d["parameters"]["Td"]["ci95_low"] > 5.0
    assert "not bounded from above" in format_table(r)
    write_analysis_report(r, tmp_path)
    assert "not bounded above" in (tmp_path / "index.html").read_text()
    # tau and K are still determined
    assert abs(r.tau.mean - D1["tau"]) < 1e-3 and r.K.mean == pytest.approx(D1["K"], rel=0.01)


def test_a_damped_plant_keeps_its_two_sided_interval():
    r = analyze_flight(_flight(Td=0.8, seed=9), D1["Tp"], n_bootstrap=100)
    assert math.isfinite(r.Td.ci95_high) and r.Td.ci95_low <= 0.8 <= r.Td.ci95_high
