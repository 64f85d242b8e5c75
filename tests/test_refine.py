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

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalyzeOptions, analyze_flight
from mrftcli.errors import IdentificationError, InputError
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
    r = analyze_flight(_flight(), soiptd_model(D1["Tp"]), options=AnalyzeOptions(n_bootstrap=100))
    ref = r.refinement
    assert r.method == "waveform" and ref.accepted and not ref.reasons
    assert ref.residual_ratio <= RESIDUAL_FACTOR
    mrft = r.parameters_mrft
    for name in ("tau", "K", "Td"):
        assert abs(getattr(r, name).value - D1[name]) < abs(mrft[name].value - D1[name]) + 0.5 * mrft[name].std, name
        assert getattr(r, name).std < mrft[name].std


@pytest.mark.parametrize("effects, why", [
    (Effects(delay_jitter=0.005), "residual"),
    (Effects(gain_drift=0.005), "residual"),
    (Effects(sensor_lag=0.03), "residual"),
])
def test_refused_with_the_reason_when_the_model_does_not_hold(effects, why):
    r = analyze_flight(_flight(effects), soiptd_model(D1["Tp"]), options=AnalyzeOptions(n_bootstrap=100))
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
        r = analyze_flight(_flight(seed=100 + k, Td=Td, rate_hz=float(rng.choice([100.0, 250.0]))), soiptd_model(D1["Tp"]), options=AnalyzeOptions(n_bootstrap=50))
        assert r.method == "waveform", r.refinement.reasons
        truth = {"Td": Td, "tau": D1["tau"], "K": D1["K"]}
        for name in ("Td", "tau", "K"):
            e = getattr(r, name)
            hits += e.ci95_low <= truth[name] <= e.ci95_high
            n += 1
    assert hits >= 0.9 * n, (hits, n)


def test_no_linear_damping_gives_a_one_sided_td_bound(tmp_path):
    """Issue 12 item 8: a double integrator with motor lag and delay (Td -> infinity)."""
    from mrftcli.cli.analyze import format_analysis
    from mrftcli.report.analysis import write_analysis_report

    from test_segment_support import simulate_paper_flight

    sf = simulate_paper_flight(D1["Tp"], 1e4, D1["tau"], D1["K"], (-0.4, -0.7), seed=7)
    r = analyze_flight(flight_from_simulated(sf), soiptd_model(D1["Tp"]), options=AnalyzeOptions(n_bootstrap=100))
    assert math.isfinite(r.Td.ci95_low) and not math.isfinite(r.Td.ci95_high)
    assert r.Td.ci95_low > 5.0  # the data do bound it from below
    assert any(w.startswith("Td > ") and "cannot bound it from above" in w for w in r.warnings)
    d = json.loads(json.dumps(to_jsonable(r.to_dict(cycles=False))))
    assert d["parameters"]["Td"]["ci95_high"] is None and d["parameters"]["Td"]["ci95_low"] > 5.0
    assert "not bounded from above" in format_analysis(r)
    write_analysis_report(r, tmp_path)
    assert "not bounded above" in (tmp_path / "index.html").read_text()
    # tau and K are still determined
    assert abs(r.tau.value - D1["tau"]) < 1e-3 and r.K.value == pytest.approx(D1["K"], rel=0.01)


def test_a_damped_plant_keeps_its_two_sided_interval():
    r = analyze_flight(_flight(Td=0.8, seed=9), soiptd_model(D1["Tp"]), options=AnalyzeOptions(n_bootstrap=100))
    assert math.isfinite(r.Td.ci95_high) and r.Td.ci95_low <= 0.8 <= r.Td.ci95_high


def test_windows_carry_the_commands_sent_before_the_test():
    """At the true plant, the independent exact simulation (test_segment_support) is reproduced to
    round-off only when each window carries the hold controller's last commands: the outputs at the
    start of a test are driven by commands sent up to tau before it (tau 90 ms here)."""
    from mrftcli.mrft.refine import COMMAND_HISTORY, loop_model_plant, refinement_windows
    from mrftcli.mrft.waveform import CommandWindow, response_basis
    from test_segment_support import simulate_relay_flight

    Tp, Td, tau, K = 0.05, 0.8, 0.09, 4.0
    log = simulate_relay_flight(Tp, Td, tau, K, [(-0.4, 0.1, 6.0), (-0.7, 0.1, 6.0)], rate_hz=100.0, noise_std=0.0)
    A, B, C, delay = loop_model_plant(Tp)(np.array([math.log(Td), tau, K]))

    def worst_residual(windows):
        out = []
        for w in windows:
            cols = response_basis(A, B, C, delay, w).columns
            coef, *_ = np.linalg.lstsq(cols[:, 1:], w.output - cols[:, 0], rcond=None)
            out.append(np.max(np.abs(w.output - cols[:, 0] - cols[:, 1:] @ coef)))
        return max(out)

    spans = [(t0, t1) for t0, t1, _, _ in log.test_windows]
    bias = 0.5  # the simulator's hover command, the relay's centre
    with_history = [CommandWindow.between(t0, t1, log.t, log.command, log.t, log.y_meas, bias, COMMAND_HISTORY)
                    for t0, t1 in spans]
    without = [CommandWindow.between(t0, t1, log.t, log.command, log.t, log.y_meas, bias) for t0, t1 in spans]
    amplitude = np.ptp(log.y_meas)
    assert worst_residual(with_history) < 1e-8 * amplitude
    assert worst_residual(without) > 1e-4 * amplitude

    class _Span:  # refinement_windows reads a test's span and bias
        def __init__(self, t0, t1):
            self.t_start, self.t_end, self.bias = t0, t1, bias

    built = refinement_windows([_Span(*s) for s in spans], log.t, log.command, log.t, log.y_meas)
    assert [w.u.size for w in built] == [w.u.size for w in with_history]


def test_refit_with_a_sensor_lag_recovers_it():
    """Issue 16: the refinement's plant API reused with one more parameter (what diagnose calls)."""
    from mrftcli.mrft.refine import refinement_windows, refit_with_effect

    lag = 0.03
    r = analyze_flight(_flight(Effects(sensor_lag=lag)), soiptd_model(D1["Tp"]), options=AnalyzeOptions(n_bootstrap=50))
    assert not r.refinement.accepted  # eq. (2) alone does not hold (checked above)
    fl = r.flight
    ws = refinement_windows(r.tests, fl.command.t, fl.command.values, fl.output.t, fl.output.values)
    fit = refit_with_effect(ws, r.model, "sensor_lag", 0.01, loop_sign=r.tests[0].loop_sign)
    assert fit.value == pytest.approx(lag, rel=0.25)
    assert abs(fit.value - lag) < 4 * fit.value_std
    # with the lag modelled the residual is the sensor noise again, and tau is the plant's own delay
    assert fit.fit.residual_rms / r.refinement.noise_std <= RESIDUAL_FACTOR
    assert abs(fit.model.tau - D1["tau"]) < 3e-3 < abs(r.tau.value - D1["tau"])


def test_refit_with_an_input_bias_reads_it_from_the_offsets():
    from mrftcli.mrft.refine import refinement_windows, refit_with_effect

    d = 0.02  # command units, at the plant input
    r = analyze_flight(_flight(Effects(input_bias=d)), soiptd_model(D1["Tp"]), options=AnalyzeOptions(n_bootstrap=50))
    fl = r.flight
    ws = refinement_windows(r.tests, fl.command.t, fl.command.values, fl.output.t, fl.output.values)
    fit = refit_with_effect(ws, r.model, "input_bias", loop_sign=r.tests[0].loop_sign)
    assert fit.value == pytest.approx(d, rel=0.1)
    assert fit.value_std < 0.05 * d
    with pytest.raises(InputError, match="unknown effect"):
        refit_with_effect(ws, r.model, "gain_drift")


def test_slices_that_do_not_intersect_give_the_one_sided_result():
    """Issue 12 item 8 / issue 16: with no linear damping the two slices run side by side and at this
    seed do not cross; identify() has no intersection, analyze reports Td > bound, tau and K."""
    from mrftcli.mrft.identify import TestMeasurement, identify
    from test_segment_support import simulate_paper_flight

    sf = simulate_paper_flight(D1["Tp"], 1e4, D1["tau"], D1["K"], (-0.4, -0.7), seed=0)
    r = analyze_flight(flight_from_simulated(sf), soiptd_model(D1["Tp"]), options=AnalyzeOptions(n_bootstrap=100))
    meas = [TestMeasurement(beta=t.beta_effective, frequency_hz=t.frequency_hz_mean, amplitude=t.amplitude_mean,
                            h=t.h) for t in r.tests]
    with pytest.raises(IdentificationError, match="do not intersect"):
        identify(meas, soiptd_model(D1["Tp"]), rate_hz=None)
    assert r.identification.method == "unbounded-Td"
    m = r.parameters_mrft
    assert 5.0 < m["Td"].ci95_low and not math.isfinite(m["Td"].ci95_high)
    assert 5.0 < r.Td.ci95_low and not math.isfinite(r.Td.ci95_high)
    assert m["tau"].ci95_low <= D1["tau"] <= m["tau"].ci95_high and abs(m["tau"].value - D1["tau"]) < 1e-3
    assert m["K"].ci95_low <= D1["K"] <= m["K"].ci95_high
    assert abs(r.tau.value - D1["tau"]) < 1e-3 and r.K.value == pytest.approx(D1["K"], rel=0.01)
    assert any(w.startswith("Td > ") for w in r.warnings)
    # a wrong Tp is still refused (exit 5): the limit does not fit those tests either
    with pytest.raises(IdentificationError):
        analyze_flight(flight_from_simulated(sf), soiptd_model(0.01), options=AnalyzeOptions(n_bootstrap=50))
