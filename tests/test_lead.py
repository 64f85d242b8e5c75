"""Eq. (2) with a lead (tau < 0, down to -Tp / 2): the cycle against the Fourier series of the output, identify's
round trip and refusal, analyze's statement and tune's causal design (issue 42: PX4 SIH's EKF2 attitude leads)."""

from __future__ import annotations

import contextlib
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mrftcli.errors import IdentificationError, InputError
from mrftcli.mrft.identify import TestMeasurement, identify
from mrftcli.mrft.lprs import mrft_limit_cycle
from mrftcli.mrft.model import LEAD_CAP_S, LEAD_MAX, LoopModel, lead_floor, soiptd_model

ROOT = Path(__file__).resolve().parents[1]
LEAD = LoopModel(0.05, 1.0, -0.003, 113.0)  # PX4 SIH's roll constants with EKF2's ~3 ms lead


def _series_output(model: LoopModel, omega: float, beta_check: float, n_terms: int = 4001) -> tuple[float, float]:
    """The output at the -h -> +h switch and its peak [output units, h = 1], from the Fourier series of the
    relay's square wave through G(j k omega) (odd k), not from the library's periodic solution."""
    k = np.arange(1, n_terms + 1, 2, dtype=float)
    s = 1j * k * omega
    G = model.K * model.Td * np.exp(-model.tau * s) / (s * (model.Tp * s + 1) * (model.Td * s + 1))
    t = np.linspace(0.0, 2 * math.pi / omega, 4096, endpoint=False)
    y = (4 / math.pi) * (np.abs(G) / k) @ np.sin(np.outer(k * omega, t) + np.angle(G)[:, None])
    return float((4 / math.pi) * np.sum(G.imag / k)), float(y.max())


@pytest.mark.parametrize("beta", [-0.3, -0.5, -0.7])
def test_the_lead_cycle_meets_the_mrft_condition_on_the_output_series(beta: float) -> None:
    """The MRFT switches -h -> +h where the output is -beta times its peak: with the frequency mrft_limit_cycle
    gives a lead, the output summed from its harmonics does so (the oracle), and its peak is the amplitude."""
    lc = mrft_limit_cycle(LEAD, beta)
    y0, peak = _series_output(LEAD, lc.omega, beta)
    assert y0 == pytest.approx(-beta * peak, rel=1e-4)
    assert peak == pytest.approx(lc.amplitude, rel=1e-4)
    assert lc.omega > mrft_limit_cycle(LEAD.with_parameters(tau=0.0), beta).omega  # a lead: faster than tau 0


def test_identify_recovers_a_lead_and_states_it() -> None:
    betas = (-0.3, -0.5, -0.7)
    cycles = [mrft_limit_cycle(LEAD, b) for b in betas]
    tests = [TestMeasurement(b, c.frequency_hz, amplitude=c.amplitude, h=1.0) for b, c in zip(betas, cycles)]
    r = identify(tests, soiptd_model(LEAD.Tp))
    assert r.tau.value == pytest.approx(-0.003, abs=1e-7) and r.model.tau == pytest.approx(r.tau.value)
    assert r.Td.value == pytest.approx(1.0, rel=1e-5) and r.K.value == pytest.approx(113.0, rel=1e-5)
    assert any(w.startswith("the loop leads eq. (2): tau = -3 ms") for w in r.warnings)
    two = identify(tests[::2], soiptd_model(LEAD.Tp))  # the two-test intersection too
    assert two.tau.value == pytest.approx(-0.003, abs=1e-7)


def test_what_no_lead_explains_is_still_refused() -> None:
    """A lead is admitted down to -min(Tp / 2, 6 ms) (an estimator's few ms; a cycle of eq. (2) holds at most
    ~0.3 Tp of lead at these betas): two frequencies whose slices do not meet stay refused, and a model beyond
    the bound is refused by name."""
    tests = [TestMeasurement(-0.2, 2.0), TestMeasurement(-0.6, 2.4)]
    with pytest.raises(IdentificationError, match="do not intersect"):
        identify(tests, soiptd_model(0.05))
    with pytest.raises(InputError, match="tau must be a non-negative time in seconds \\(or a lead down to -0.006"):
        LoopModel(0.05, 1.0, -0.007)
    assert LoopModel(0.05, 1.0, -LEAD_CAP_S).tau == -0.006
    assert LoopModel(0.01, 1.0, -LEAD_MAX * 0.01).tau == -0.005  # a small Tp: its half
    assert lead_floor(0.05) == -0.006 and lead_floor(0.004) == -0.002


@pytest.mark.parametrize("factor", [3.0, 10.0])
def test_a_tp_given_too_large_is_refused_not_read_as_a_lead(factor: float) -> None:
    """Cycles of eq. (2) without delay (Tp 50 ms, the oracle: the closed form) identified at a Tp 3x / 10x too
    large read as a lead of tens of ms, not an estimator's few: refused in one line naming --tp."""
    truth = LoopModel(0.05, 1.0, 0.0, 113.0)
    tests = [TestMeasurement(b, mrft_limit_cycle(truth, b).frequency_hz) for b in (-0.3, -0.5, -0.7)]
    with pytest.raises(IdentificationError, match="beyond the 6 ms eq. \\(2\\) admits.*check --tp"):
        identify(tests, soiptd_model(0.05 * factor))


@pytest.mark.parametrize("tp", ["0.15", "0.5"])
def test_analyze_refuses_a_wrong_tp_on_a_lead_log(tp: str) -> None:
    """PX4 SIH's pitch on EKF2's attitude (true lead -2.9 ms at Tp 0.05 s): --tp 0.15 / 0.5 read as leads of
    10-16 ms and were accepted (exit 0, held out missing by 10-17 std); refused again, exit 5, one line naming --tp."""
    from cli_helpers import run_main

    proc = run_main("analyze", "sample_logs/sitl/px4_pitch_h.ulg", "--loop", "pitch", "--tp", tp)
    assert proc.returncode == 5, proc.stdout + proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "--tp" in lines[0] and "lead" in lines[0] and "Traceback" not in proc.stderr


def test_a_lead_whose_tests_disagree_is_refused() -> None:
    """Within the cap, a Tp too large still makes the tests disagree: a lead with a test held out > 5 std off, or
    one the others' model gives no cycle, is refused naming --tp; an estimator's lead (within 2 std) is not."""
    from mrftcli.analyze.held_out import MISS_WORDS, HeldOut, lead_held_out_refusal

    good = (HeldOut(1.0, 0.2, "", 0.01, 0.01, 1.2, -1.9), HeldOut(2.0, 0.1, "", 0.01, 0.01, -1.0, 1.0))
    assert lead_held_out_refusal(good, -0.003) is None
    far = (*good[:1], HeldOut(2.0, 0.1, "", 0.01, 0.01, 12.6, 1.0))
    assert "12.6 std" in (lead_held_out_refusal(far, -0.0038) or "") and "--tp" in (lead_held_out_refusal(far, -0.0038) or "")
    assert lead_held_out_refusal(far, 0.002) is None  # a delay, not a lead: not this rule's
    none = (*good[:1], HeldOut(None, None, f"no cycle at beta -0.7: {MISS_WORDS}"))
    assert "no cycle" in (lead_held_out_refusal(none, -0.003) or "")


def test_the_sampled_relays_orbits_of_a_lead_bracket_its_centre_and_tend_to_the_continuous_cycle() -> None:
    """The sampled relay's band of a lead: its orbits bracket the band's centre (the continuous cycle with half a
    tick more delay) and shrink onto the continuous lead cycle as the rate rises."""
    for beta in (-0.3, -0.7):
        cont = mrft_limit_cycle(LEAD, beta).frequency_hz
        gaps = []
        for rate in (250.0, 10_000.0):
            lc = mrft_limit_cycle(LEAD, beta, rate_hz=rate)
            assert min(lc.orbits_hz) <= lc.frequency_hz <= max(lc.orbits_hz)
            gaps.append(abs(lc.frequency_hz / cont - 1.0))
        assert gaps[1] < 0.003 and gaps[1] < gaps[0] / 10


def test_tune_designs_a_lead_on_tau_zero_and_says_so() -> None:
    """No discrete delay line holds a lead: the designs take tau 0 (more lag than identified), the robust design
    keeps the posterior (the lead's draws are not dropped), and the first note says so."""
    from mrftcli.tune.design import Posterior, tune

    rng = np.random.default_rng(0)
    post = Posterior(LEAD, rng.normal(1.0, 0.02, 50), rng.normal(-0.003, 0.0003, 50), rng.normal(113.0, 1.0, 50))
    assert post.n == 50
    res = tune(LEAD, 250.0, posterior=post)
    assert res.notes[0].startswith("assumed: the identified loop leads eq. (2) (tau = -3 ms < 0); the designs take tau = 0")
    assert res.model.tau == 0.0 and any(d.name == "robust" for d in res.designs)
    same = tune(LEAD.with_parameters(tau=0.0), 250.0, posterior=Posterior(LEAD.with_parameters(tau=0.0), post.Td,
                                                                           np.maximum(post.tau, 0.0), post.K))
    assert [d.controller for d in res.designs] == [d.controller for d in same.designs]
    # the identified tau travels beside the designed one: the table's first line states the design's assumption,
    # the model line both taus; the JSON names it (and reads it back); the causal design has none
    from mrftcli.tune.design import TuneResult
    from mrftcli.tune.export import format_table

    table = format_table(res).splitlines()
    assert table[0].startswith("note: assumed: the identified loop leads eq. (2)")
    assert "tau 0 ms (designed at; identified -3 ms, a lead)" in table[1]
    assert sum(line.startswith("note: assumed:") for line in table) == 1
    data = res.to_json()
    assert data["tau_identified"] == {"value": pytest.approx(-0.003), "unit": "s", "designed_at": 0.0}
    assert TuneResult.from_json(data).tau_identified == pytest.approx(-0.003)
    assert same.tau_identified is None and "tau_identified" not in same.to_json()


def test_analyze_states_the_lead_first_and_in_the_json(tmp_path: Path) -> None:
    """PX4 SIH's pitch on EKF2's attitude (sample_logs/sitl): identified with its lead (refused before), the
    assumption on the lines after the signals read, tau negative in the parameters, the model and the notes."""
    out = tmp_path / "r.json"
    from cli_helpers import run_main

    with contextlib.chdir(ROOT):
        proc = run_main("analyze", "sample_logs/sitl/px4_pitch_h.ulg", "--loop", "pitch", "--tp", "0.05", "--json",
                        str(out))
    assert proc.returncode == 0, proc.stderr
    head = proc.stdout.splitlines()[:6]
    assert any(line.startswith("note: assumed: the loop leads eq. (2): tau = -2.9") for line in head)
    assert proc.stdout.count("the loop leads eq. (2)") == 1
    data = json.loads(out.read_text())
    assert -0.005 < data["parameters"]["tau"]["value"] < -0.001
    assert data["model"]["tau"] == pytest.approx(data["parameters"]["tau"]["value"])
    assert data["notes"][0].startswith("assumed: the loop leads eq. (2)")
    # held out with the lead the reported model has: each test from the others' response points (a fit held at
    # tau >= 0 ended on tau = 0, its points 'disagreed' (chi2 18-38 on 5 dof) and every test fell back)
    from mrftcli.analyze.held_out_harmonic import FALLBACK_WORDS

    for row in data["tests"]:
        ho = row["held_out"]
        assert not ho["note"].startswith(FALLBACK_WORDS) and ho["route"] == "response_points", ho
        assert abs(ho["frequency_z"]) < 2 and abs(ho["frequency_hz"] / row["frequency_hz"] - 1) < 0.04, ho


def _lead_points(betas: tuple[float, ...]) -> list:
    """LEAD's fundamental and 3rd-harmonic response points at its MRFT cycles (G from the closed form), se 1 %."""
    from mrftcli.mrft.identify_lti import ResponsePoint

    out = []
    for i, beta in enumerate(betas):
        w = mrft_limit_cycle(LEAD, beta).omega
        for k in (1, 3):
            s = 1j * k * w
            G = LEAD.K * LEAD.Td * np.exp(-LEAD.tau * s) / (s * (LEAD.Tp * s + 1) * (LEAD.Td * s + 1))
            out.append(ResponsePoint(k * w, abs(G), float(np.angle(G)), 0.01, 0.01, i, k))
    return out


def test_the_held_out_fit_admits_the_lead_the_reported_model_does() -> None:
    """The held-out route's fit of eq. (2) to two tests' response points of a lead (-3 ms) predicts the third
    test's cycle: its frequency meets the MRFT condition on the output series (the oracle above) within 0.1 %.
    With tau held >= 0 the fit ended on tau = 0 and its points 'disagreed' (chi2 24 on 5 dof): no prediction."""
    from types import SimpleNamespace

    from mrftcli.analyze.held_out_harmonic import _predict
    from mrftcli.mrft.relays import RelayLaw

    test = SimpleNamespace(predicting_relay=RelayLaw("mrft", 1.0, -1.0, beta=-0.7), rate_hz=None)
    got = _predict(soiptd_model(LEAD.Tp), test, _lead_points((-0.3, -0.5)), None)  # type: ignore[arg-type]
    assert isinstance(got, tuple), got
    (f, a), (sf, sa), note = got
    assert note == ""  # two tests: 8 figures for 3 parameters
    y0, peak = _series_output(LEAD, 2 * math.pi * f, -0.7)
    assert y0 == pytest.approx(0.7 * peak, rel=1e-3) and a == pytest.approx(peak, rel=1e-3)
    assert 0 < sf < 0.05 * f and 0 < sa < 0.1 * a


def test_a_held_out_fit_on_its_bound_states_it() -> None:
    """A parameter on a bound of its range (tau on the lead floor): the fit's covariance does not hold there, the
    route names it; inside the range nothing."""
    from mrftcli.analyze.held_out_harmonic import _on_bound, _with_lead

    fitted = _with_lead(LEAD)
    assert _on_bound(fitted.with_parameters(tau=lead_floor(LEAD.Tp)), ("Td", "tau", "K")) == "tau = -6 ms"
    assert _on_bound(fitted, ("Td", "tau", "K")) == ""


def test_the_cascade_takes_an_inner_lead_as_tau_zero_and_keeps_it_to_say_so() -> None:
    """The cascade samples its inner loop through a delay line: an inner analysis with a lead (PX4 SIH's pitch on its
    own attitude: -0.02 ms) is flown at tau 0, the lead kept for the assumptions (and through the draws); an
    InnerLoop given a lead directly is refused in one line."""
    from types import SimpleNamespace

    from mrftcli.analyze.cascade import inner_loop_of
    from mrftcli.mrft.cascade import InnerLoop
    from mrftcli.mrft.controller import Controller
    from mrftcli.mrft.parameter import ParameterEstimate

    est = {n: ParameterEstimate(v, s, v - 2 * s, v + 2 * s, u) for n, v, s, u in
           (("Td", 1.0, 0.02, "s"), ("tau", -0.003, 0.0003, "s"), ("K", 113.0, 1.0, ""))}
    result = SimpleNamespace(loop="pitch", model=LEAD, **est)
    c = Controller(Kp=0.17, Ki=0.0, Kd=0.045, Tf=0.026, rate_hz=250.0)
    inner = inner_loop_of(result, c, "pitch")  # type: ignore[arg-type]
    assert inner.plant.delay == 0.0 and inner.lead_s == pytest.approx(-0.003)
    assert inner.draw(np.random.default_rng(0)).lead_s == pytest.approx(-0.003)
    with pytest.raises(InputError, match="leads"):
        InnerLoop(LEAD, c, "pitch")


def test_the_amplitude_route_keeps_a_lead_and_states_it() -> None:
    """One test and K known (the paper's amplitude route): its model took max(tau, 0) silently while its tau stayed
    negative; now model and estimate agree on the lead (the oracle: the closed-form cycle of LEAD) and it is stated."""
    lc = mrft_limit_cycle(LEAD, -0.5)
    r = identify([TestMeasurement(-0.5, lc.frequency_hz, amplitude=lc.amplitude, h=1.0)],
                 soiptd_model(LEAD.Tp, K=LEAD.K))
    assert r.tau.value == pytest.approx(-0.003, abs=1e-6) and r.model.tau == pytest.approx(r.tau.value)
    assert any(w.startswith("the loop leads eq. (2)") for w in r.warnings)


def test_a_held_out_test_the_others_model_has_no_cycle_for_is_a_miss_with_its_reason() -> None:
    """The others' model with a lead out of a beta's reach (at beta -0.9 a cycle holds at most ~0.05 Tp of lead)
    predicts no cycle where one was flown: a held-out miss saying so (was 'their UFM slices do not meet')."""
    from mrftcli.analyze.held_out import MISS_WORDS, _prediction

    no_cycle = _prediction(LEAD, 1.0, -0.005, 113.0, -0.9, 1.0)
    assert isinstance(no_cycle, str) and "no cycle at beta -0.9" in no_cycle and MISS_WORDS in no_cycle
    beyond = _prediction(LEAD, 1.0, -0.02, 113.0, -0.3, 1.0)
    assert isinstance(beyond, str) and "beyond the 6 ms" in beyond and MISS_WORDS in beyond
    assert isinstance(_prediction(LEAD, 1.0, -0.003, 113.0, -0.3, 1.0), tuple)


def test_the_designs_hold_a_posteriors_lead_draws_at_zero_and_say_so() -> None:
    """A causal point with draws on both sides of 0 (tau 0.5 ± 1 ms): the draws below 0 were dropped (the posterior
    cut at 0, its tau shifted up); now held at 0, all kept, counted in a note; beyond the lead floor: no model."""
    from mrftcli.tune.design import Posterior

    rng = np.random.default_rng(3)
    n = 400
    tau = 0.0005 + 0.001 * rng.standard_normal(n)
    tau[0] = -0.02  # beyond -6 ms: not eq. (2)'s
    post = Posterior(LoopModel(0.05, 1.0, 0.0005, 113.0), np.full(n, 1.0), tau, np.full(n, 113.0))
    below = int(np.count_nonzero((tau < 0) & (tau >= -0.006)))
    assert post.n == n - 1 and post.n_lead == below and float(post.tau.min()) == 0.0
    assert post.in_set().mean() > 0.9  # the held draws are in the set (ln tau put them at ln 1e-9)


def test_a_lead_out_of_a_betas_reach_names_the_fix() -> None:
    with pytest.raises(IdentificationError, match="nearer 0.*--tp"):
        mrft_limit_cycle(LoopModel(0.05, 1.0, -0.0029, 113.0), -0.9)


def test_the_cascades_inner_draws_of_a_lead_centre_on_the_lead() -> None:
    """An inner lead of -3 ms (held at 0) with tau std 0.3 ms: draws about -3 ms, held at 0 (were about 0: half of
    them above it, a delay the loop does not have)."""
    from mrftcli.mrft.cascade import InnerLoop
    from mrftcli.mrft.controller import Controller

    c = Controller(Kp=0.17, Ki=0.0, Kd=0.045, Tf=0.026, rate_hz=250.0)
    inner = InnerLoop(LEAD.with_parameters(tau=0.0), c, "pitch", std=(("tau", 0.0003),), lead_s=-0.003)
    rng = np.random.default_rng(0)
    assert max(inner.draw(rng).plant.delay for _ in range(50)) == 0.0


def test_delay_refuses_a_lead_beyond_the_floor_as_analyze_does() -> None:
    """delay's fit is bounded at analyze's lead floor (one rule): PX4 SIH's pitch pair at --tp 0.15 (3x) wants
    more lead than 6 ms, its delay on the bound: refused naming --tp (was exit 0, 32 ± 22 ms and a note)."""
    from mrftcli.compare.delay import delay_increment
    from mrftcli.io.flight import ReadOptions

    logs = ROOT / "sample_logs" / "sitl"
    with pytest.raises(IdentificationError, match="leads eq. \\(2\\) by more than the 6 ms.*check --tp"):
        delay_increment(logs / "px4_pitch_h.ulg", logs / "px4_pitch_h_20ms.ulg", 0.15, read=ReadOptions(loop="pitch"))


def test_diagnose_states_that_its_models_take_no_lead() -> None:
    """diagnose's linear fit and effects hold tau >= 0 (review finding 2): on a lead analysis it says so, first,
    with analyze's lead (checked by hand on px4_pitch_h: the line after the header, and notes[0] of --json);
    a causal analysis gets no such note."""
    from types import SimpleNamespace

    from mrftcli.diagnose.selection import DIAGNOSE_LEAD_WORDS, lead_assumption
    from mrftcli.mrft.parameter import ParameterEstimate

    def analysis(tau: float) -> SimpleNamespace:
        return SimpleNamespace(parameters={"tau": ParameterEstimate(tau, 0.0002, tau - 0.0004, tau + 0.0004, "s")})

    (note,) = lead_assumption(analysis(-0.00292))  # type: ignore[arg-type]
    assert note.startswith(DIAGNOSE_LEAD_WORDS) and "a lead of 2.92 ms" in note
    assert lead_assumption(analysis(0.03)) == [] and lead_assumption(None) == []  # type: ignore[arg-type]


def test_watchs_running_line_says_a_lead() -> None:
    """watch's running estimate line printed a negative tau with no word (its warnings show on the final only)."""
    import time

    from mrftcli.cli.watch import _estimate_line
    from mrftcli.cli.model_options import parameter_display
    from mrftcli.mrft.identify import lead_note
    from mrftcli.mrft.parameter import ParameterEstimate
    from mrftcli.watch import EstimateUpdate

    nan = math.nan
    params = (ParameterEstimate.given(0.05, "s", "Tp"), ParameterEstimate(1.0, nan, nan, nan, "s", name="Td"),
              ParameterEstimate(-0.003, nan, nan, nan, "s", name="tau"), ParameterEstimate(113.0, nan, nan, nan, "", name="K"))
    show = parameter_display("soiptd", "pitch")
    lead = EstimateUpdate("soiptd", params, (1, 2), 10.0, False, time.time(), warnings=(lead_note(-0.003),))
    assert "tau < 0: the loop leads eq. (2)" in _estimate_line(lead, "rad", show)
    causal = EstimateUpdate("soiptd", params, (1, 2), 10.0, False, time.time(), warnings=())
    assert "leads" not in _estimate_line(causal, "rad", show)


def test_plan_counts_the_lead_draws_it_leaves_out():
    """Plan's slice candidates with a lead are left out (its simulator cannot advance the command): counted, said."""
    from mrftcli.plan import FlownTest, PlanLimits, PlanOptions, Prior, plan_tests
    from mrftcli.plan.draws import conditioned_draws

    model = LoopModel(0.04, 0.8, 0.001, 2.0)  # 1 ms: a larger Td on this test's slice is a lead
    lc = mrft_limit_cycle(model, -0.4, 1.0, 200.0)
    flown = FlownTest(beta=-0.4, h=1.0, frequency_hz=lc.frequency_hz, amplitude=lc.amplitude, n_cycles=10)
    prior = Prior(Td=(0.3, 2.0), tau=(0.001, 0.06), K=(1.0, 4.0))
    notes: list[str] = []
    d = conditioned_draws(soiptd_model(0.04), prior, [flown], 200, np.random.default_rng(0), 200.0, 0.0005, notes)
    assert d[:, 1].min() >= 0 and len(notes) == 1
    n_lead = int(notes[0].split()[0])  # no phase: the draws kept are causal candidates, the rest dropped
    assert 0 < n_lead <= 200 - d.shape[0]
    assert notes == [f"{n_lead} of 200 posterior draws have tau < 0 (a lead): plan leaves them out (its simulator's "
                     "delay line cannot advance the command); the forecasts rest on the causal draws"]
    limits = PlanLimits(max_amplitude=0.05, max_h=10.0, time_s=15.0, rate_hz=200.0, noise_std=0.0005)
    p = plan_tests(soiptd_model(0.04), limits, prior=prior, flown=[flown],
                   options=PlanOptions(n_draws=8, betas=(-0.4, -0.6, -0.8)))
    assert "posterior draws have tau < 0 (a lead): plan leaves them out" in p.notes[0]
    assert p.to_json()["notes"][0] == p.notes[0]


def test_tunes_first_line_is_the_lead_design_note_before_the_analysis_warnings():
    """tune on a lead log: the 'assumed:' design note is the first line a user reads (stdout and stderr as one
    terminal), the analysis' warnings after the output, as analyze prints them."""
    # a real process: the claim is the order of stdout and stderr merged into one stream (stderr=STDOUT), which
    # run_main's two separate buffers cannot show
    proc = subprocess.run([sys.executable, "-m", "mrftcli", "tune", "sample_logs/sitl/px4_pitch_h.ulg", "--loop",
                           "pitch", "--tp", "0.05", "--controller-rate", "250", "--quiet"], cwd=ROOT,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout
    lines = [ln for ln in proc.stdout.splitlines() if ln.strip()]
    assert lines[0].startswith("note: assumed: the identified loop leads eq. (2) (tau = -")
    warned = [i for i, ln in enumerate(lines) if ln.startswith("warning: ")]
    assert warned and min(warned) > next(i for i, ln in enumerate(lines) if ln.startswith("export (robust PD)"))


def test_batch_flags_a_lead_row_and_says_so_in_its_notes(tmp_path: Path) -> None:
    """batch on PX4 SIH's pitch (analyze's lead, -2.9 ms): the printed row is flagged and the summary's notes
    (printed and in --json) name the loop, instead of a bare negative tau_mean."""
    from cli_helpers import run_main

    out = tmp_path / "out"
    summary = tmp_path / "s.json"
    proc = run_main("batch", str(ROOT / "sample_logs/sitl/px4_pitch_h.ulg"), "--loop", "pitch", "--tp", "0.05",
                    "--out", str(out), "--jobs", "1", "--no-report", "--quiet", "--json", str(summary))
    assert proc.returncode == 0, proc.stderr
    row = next(ln for ln in proc.stdout.splitlines() if ln.startswith("px4_pitch_h.ulg"))
    assert "-2.9" in row and "LEAD tau < 0" in row
    data = json.loads(summary.read_text())
    assert data["rows"][0]["tau_mean"] < 0
    assert data["notes"][0].startswith("1 loop(s) identified with tau < 0 (a lead")
    assert "px4_pitch_h.ulg pitch (-2.9" in data["notes"][0] and data["notes"][0] in proc.stderr


def test_one_lead_rule_serves_both_routes() -> None:
    """identify's frequencies and amplitude routes check a lead with one ``_checked_lead`` (they wrote the rule
    twice): beyond ``lead_floor`` = -min(Tp/2, 6 ms) (closed form) refused; pushed beyond it only by the sampling
    lag, set to the floor and said; below 0 noted; at or above 0 untouched."""
    from mrftcli.mrft.identify import _checked_lead, lead_note

    Tp = 0.05
    floor = -min(Tp / 2, 0.006)
    with pytest.raises(IdentificationError, match="beyond the 6 ms"):
        _checked_lead(floor - 1e-4, Tp, [])
    warns: list[str] = []
    assert _checked_lead(floor - 1e-4, Tp, warns, lag=2e-4) == floor
    assert "tau set to -6 ms" in warns[0] and warns[1] == lead_note(floor)
    warns = []
    assert _checked_lead(-0.003, Tp, warns) == -0.003 and warns == [lead_note(-0.003)]
    warns = []
    assert _checked_lead(0.0, Tp, warns) == 0.0 and warns == []
