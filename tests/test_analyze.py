"""analyze_flight: accuracy on simulated flights, the paper's delay-increment experiment, partial
results and errors.

The truth is the plant each flight was simulated with (the analysis never sees it). Flights come
from the project's simulator (:mod:`mrftcli.sim.flight`) and, for take-off/landing around the tests,
from the independent simulation in ``test_segment_support.py``.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalysisResult, AnalyzeOptions, analyze_flight
from mrftcli.jsonable import to_jsonable
from mrftcli.errors import InputError, InsufficientDataError, SegmentationError
from mrftcli.io.logtypes import Signal
from test_segment_support import flight_from_simulated, simulate_paper_flight, simulate_relay_flight, to_flight

# checks.md section 4: Design I altitude (Tp from the bench, Td and tau as identified in the paper)
D1 = dict(Tp=0.0422, Td=2.669, tau=0.0464, K=19.6)


def _check(result: AnalysisResult, Tp, Td, tau, K, td_tol=0.05):
    assert abs(result.tau.value - tau) <= 1e-3
    assert result.K.value == pytest.approx(K, rel=0.03)
    td_omega = max(result.model.Td * 2 * np.pi * t.frequency_hz_mean for t in result.tests)
    if td_omega <= 5:
        assert result.Td.value == pytest.approx(Td, rel=td_tol)
    else:
        assert result.Td.ci95_low <= Td <= result.Td.ci95_high
        # said once: a note where the interval is usable, else a warning (issue 12 item 16)
        assert sum("Td*Omega" in w for w in (*result.warnings, *result.notes)) == 1
    assert result.tau.ci95_low <= tau <= result.tau.ci95_high


@pytest.fixture(scope="module")
def design1():
    sf = simulate_paper_flight(D1["Tp"], D1["Td"], D1["tau"], D1["K"], (-0.4, -0.7), seed=11)
    return sf, analyze_flight(flight_from_simulated(sf), soiptd_model(D1["Tp"]))


def test_design1_altitude(design1):
    sf, result = design1
    _check(result, **D1)
    assert [t.beta_nominal for t in result.tests] == [-0.4, -0.7]
    for t, spec in zip(result.tests, sf.spec.tests):
        assert t.h == pytest.approx(spec.h, rel=1e-9)
        assert t.n_stable >= 8
        assert abs(t.beta_effective - t.beta_nominal) < 0.03
    c = result.combination_stats()
    assert c["n"] >= 64
    assert c["tau"]["std"] > result.tau.std  # one cycle per test scatters more than the mean


def test_attitude_loop_small_td():
    # roll of Design II (checks.md section 4) with IMU noise 0.2 deg; Td*Omega < 5 here
    p = dict(Tp=0.0499, Td=0.887, tau=0.0228, K=30.0)
    sf = simulate_paper_flight(p["Tp"], p["Td"], p["tau"], p["K"], (-0.5, -0.8), loop="roll", seed=5)
    result = analyze_flight(flight_from_simulated(sf), soiptd_model(p["Tp"]))
    _check(result, **p)


def test_delay_increment_of_20ms_is_found():
    """The paper's validation: 20 ms added to the altitude loop of Design I (found 19.6 ms)."""
    base = simulate_paper_flight(D1["Tp"], D1["Td"], D1["tau"], D1["K"], (-0.4, -0.7), seed=21)
    added = simulate_paper_flight(D1["Tp"], D1["Td"], D1["tau"] + 0.020, D1["K"], (-0.4, -0.7), seed=22)
    r0 = analyze_flight(flight_from_simulated(base), soiptd_model(D1["Tp"]))
    r1 = analyze_flight(flight_from_simulated(added), soiptd_model(D1["Tp"]))
    assert (r1.tau.value - r0.tau.value) * 1e3 == pytest.approx(20.0, abs=1.5)


def test_takeoff_landing_dropouts_and_glitches_around_tests():
    """Independent simulator: take-off and landing ramps, PD holds, then a damaged log."""
    Tp, Td, tau, K = 0.0499, 0.6, 0.035, 2.0
    sim = simulate_relay_flight(Tp, Td, tau, K, [(-0.4, 1.0, 16.0), (-0.7, 2.5, 10.0)], seed=7, takeoff_s=3.0)
    clean = analyze_flight(to_flight(sim), soiptd_model(Tp))
    _check(clean, Tp, Td, tau, K)
    rng = np.random.default_rng(8)
    keep = rng.random(sim.t.size) > 0.03
    t_jit = np.sort(sim.t + rng.normal(0, 0.0005, sim.t.size))
    flight = to_flight(sim, t_cmd=t_jit, keep=keep)
    c = flight.command.values.copy()
    for tg in (12.2, 30.4):
        i = int(np.searchsorted(flight.command.t, tg))
        c[i] = 1.0 - c[i]
    flight = replace(flight, command=Signal(flight.command.t, c))
    damaged = analyze_flight(flight, soiptd_model(Tp))
    _check(damaged, Tp, Td, tau, K)


def test_single_beta_gives_partial_tau_curve():
    sf = simulate_paper_flight(D1["Tp"], D1["Td"], D1["tau"], D1["K"], (-0.4,), seed=3)
    with pytest.raises(InsufficientDataError, match="only one beta") as err:
        analyze_flight(flight_from_simulated(sf), soiptd_model(D1["Tp"]))
    part = err.value.partial
    assert part["assumed_Td_range_s"] == [0.1, 10.0]
    curve = part["tau_for_assumed_Td"][0]
    tau_at_true_Td = np.interp(np.log(D1["Td"]), np.log(curve["Td_s"]), curve["tau_s"])
    assert tau_at_true_Td == pytest.approx(D1["tau"], abs=0.003)
    json.dumps(to_jsonable(part), allow_nan=False)


def test_too_few_stable_cycles_is_a_segmentation_error():
    sf = simulate_paper_flight(D1["Tp"], D1["Td"], D1["tau"], D1["K"], (-0.4, -0.7), cycles=2.0, seed=4)
    # two-cycle tests: the start-up transient leaves no stable limit cycle
    from mrftcli.sim.flight import FlightSpec, TestSpec, simulate_flight

    spec = sf.spec
    short = FlightSpec(model=spec.model, tests=tuple(TestSpec(t.beta, t.h, 2.5) for t in spec.tests),
                       loop=spec.loop, switching=spec.switching, seed=4, hover_s=2.0, hold_s=2.0)
    with pytest.raises(SegmentationError, match="stable"):
        analyze_flight(flight_from_simulated(simulate_flight(short)), soiptd_model(D1["Tp"]))


def test_to_dict_is_plain_json_with_the_documented_keys(design1):
    _, result = design1
    d = json.loads(json.dumps(to_jsonable(result.to_dict()), allow_nan=False))
    for name in ("Td", "tau", "K"):
        assert list(d["parameters"][name]) == ["value", "std", "ci95_low", "ci95_high", "unit", "determined",
                                               "known", "method"]
    assert d["parameters"]["tau"]["value"] == pytest.approx(result.tau.value)
    for t in d["tests"]:
        assert {"beta", "h", "frequency_hz", "amplitude", "cycles", "t_start", "t_end", "beta_nominal",
                "beta_effective"} <= set(t)
        assert t["beta"] == t["beta_effective"]
    assert d["combinations"]["Td"]["mean"] > 0
    assert isinstance(d["warnings"], list) and d["input"]["loop"] == "altitude"


def test_without_beta_topic_the_effective_beta_is_the_estimate(design1):
    sf, with_topic = design1
    result = analyze_flight(flight_from_simulated(sf, with_beta=False), soiptd_model(D1["Tp"]))
    assert all(t.beta_nominal is None for t in result.tests)
    assert [t.beta_effective for t in result.tests] == pytest.approx([t.beta_effective for t in with_topic.tests])
    assert result.tau.value == pytest.approx(with_topic.tau.value, abs=1e-9)


# ------------------------------------------------------------------------- constraints beyond the paper


def test_weighted_constraints_are_reported_with_residuals(design1):
    """Default estimate: UFM slices + phase + amplitude, each with its residual at the estimate."""
    _, result = design1
    c = result.constraints
    assert c["used"] == ["ufm", "phase", "amplitude"]
    assert len(c["tests"]) == len(result.tests) and c["dof"] == 3 * len(result.tests) - 3
    for row in c["tests"]:
        for key in ("ufm", "phase", "amplitude"):
            assert np.isfinite(row[key]["normalised"]) and abs(row[key]["normalised"]) < 4
        # the residual is the curve's tau at the estimate minus the estimate
        assert row["phase"]["residual_s"] == pytest.approx(row["phase"]["tau_s"] - result.parameters_mrft["tau"].value,
                                                           abs=1e-12)
    # phase curve of a test at the estimate, recomputed from arg G (eq. 2) independently
    t = result.tests[0]
    W = 2 * np.pi / t.period.mean()
    ph = np.nanmean([cy.phase_h1 for cy in t.stable])
    tau_curve = (-ph - np.pi / 2 - np.arctan(D1["Tp"] * W) - np.arctan(result.parameters_mrft["Td"].value * W)) / W
    assert c["tests"][0]["phase"]["tau_s"] == pytest.approx(tau_curve, abs=2e-6)
    d = result.to_dict(cycles=False)
    assert d["identification"]["constraints"]["used"] == c["used"]
    assert d["identification"]["constraints"]["paper_estimate"]["tau"] == pytest.approx(result.identification.model.tau)


def test_paper_only_estimate_is_the_ufm_intersection(design1):
    sf, weighted = design1
    paper = analyze_flight(flight_from_simulated(sf), soiptd_model(D1["Tp"]), options=AnalyzeOptions(constraints=(), n_bootstrap=100, refine_waveform=False))
    assert paper.constraints == {}
    assert paper.model.tau == pytest.approx(paper.identification.model.tau, abs=1e-12)
    assert paper.model.Td == pytest.approx(paper.identification.model.Td, rel=1e-12)
    assert paper.identification.model.tau == pytest.approx(weighted.identification.model.tau, abs=1e-12)
    assert paper.to_dict(cycles=False)["identification"]["constraints"] == {"used": ["ufm"]}
    with pytest.raises(InputError, match="constraint"):
        analyze_flight(flight_from_simulated(sf), soiptd_model(D1["Tp"]), options=AnalyzeOptions(constraints=("harmonics",)))


def test_times_for_people_are_relative_to_the_log_start(design1):
    """Epoch-stamped logs: table and warnings in seconds from the start, JSON keeps both."""
    from mrftcli.cli.analyze import format_analysis

    sf, ref = design1
    fl = flight_from_simulated(sf)
    T0 = 1_700_000_000.0
    fl = replace(fl, **{name: Signal(getattr(fl, name).t + T0, getattr(fl, name).values)
                       for name in ("command", "output", "setpoint", "beta")})
    result = analyze_flight(fl, soiptd_model(D1["Tp"]), options=AnalyzeOptions(n_bootstrap=100))
    first = min(float(getattr(fl, n).t[0]) for n in ("command", "output", "setpoint", "beta"))
    assert result.t0 == first
    d = result.to_dict(cycles=False)
    assert d["input"]["t0"] == first
    for t, tr in zip(d["tests"], ref.tests):
        assert t["t_start"] > T0  # absolute, as the issue asks
        assert t["t_start_rel"] == pytest.approx(t["t_start"] - first, abs=1e-6)
        assert t["t_start_rel"] == pytest.approx(tr.t_start - float(ref.flight.command.t[0]), abs=1e-6)
    table = format_analysis(result)
    assert "17000000" not in table and "2023-11-14 22:13:20" in table
    t1 = result.tests[0]
    row = next(line.split() for line in table.splitlines() if line.split()[:1] == [str(t1.index + 1)])
    assert row[1:3] == [f"{t1.t_start - first:.1f}", f"{t1.t_end - first:.1f}"]  # from, to [s]
    assert not any("17000000" in w for w in result.warnings)


# ------------------------------------------------------------------------- the waveform refinement


def test_refinement_is_reported_beside_the_mrft_estimate(design1):
    """Clean log: the refinement is accepted, reported with ``method``, and both estimates keep their std."""
    _, result = design1
    assert result.method == "waveform" and result.refinement is not None and result.refinement.accepted
    d = result.to_dict(cycles=False)
    assert d["parameters"]["tau"]["method"] == "waveform"
    assert d["parameters"]["tau"]["value"] == result.refinement.tau.value
    for key in ("parameters_mrft", "parameters_waveform"):
        assert all(d[key][n]["std"] > 0 for n in ("Td", "tau", "K"))
    assert d["refinement"]["accepted"] is True and d["refinement"]["reasons"] == []
    # the refined model has the smaller std; the truth (independent: the simulator's plant) within 3 std
    for name in ("Td", "tau", "K"):
        wf, mr = d["parameters_waveform"][name], d["parameters_mrft"][name]
        assert wf["std"] < mr["std"]
        assert abs(wf["value"] - D1[name]) < 3 * wf["std"] + 1e-12, name
