"""The cascade of an outer loop (issue 23 part A): exact sampled cycle, identification, analyze and tune.

Oracles: an independent per-tick simulation written here (scipy's expm on fine sub-steps, the
relay rule of checks.md section 2, the inner PD of tune's generic form), sharing no code with
:mod:`mrftcli.mrft.cascade`; and the existing sampled machinery of :mod:`mrftcli.mrft.lprs` for a
plain eq. (2) plant.
"""

from __future__ import annotations

import json
from typing import Any
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_main
from scipy.linalg import expm

from mrftcli.errors import IdentificationError, InputError
from mrftcli.mrft.cascade import STANDARD_GRAVITY, CascadeModel, DiscreteStateSpace, InnerLoop, discrete_limit_cycle
from mrftcli.mrft.controller import Controller
from mrftcli.mrft.cascade_identify import CascadeIdentification
from mrftcli.mrft.identify import TestMeasurement, identify
from mrftcli.mrft.lprs import mrft_limit_cycle
from mrftcli.mrft.model import MODEL_FAMILIES, LoopModel, model_from_json

RATE = 100.0
INNER = LoopModel(Tp=0.04, Td=0.5, tau=0.0125, K=40.0)
GAINS = Controller(Kp=0.6, Ki=0.0, Kd=0.12, Tf=0.02, rate_hz=RATE)


def _cascade(Td: float = 0.8, tau: float = 0.0335, K: float = 1.0) -> CascadeModel:
    return CascadeModel(InnerLoop(INNER, GAINS, "roll"), Td=Td, tau=tau, K=K)


def _simulate(beta: float, h: float, Td: float, tau: float, K: float, t_end: float, every: int = 1,
              sub: int = 20, gains: Controller = GAINS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-tick loop: outer relay (every ``every`` ticks) -> inner PD -> eq. (2) with its delay -> p'' = K phi - p'/Td.

    Exact between sub-steps (delays are whole sub-steps here); returns tick times, measured y, relay u.
    """
    T = 1.0 / RATE
    dt = T / sub
    A = np.array([[0, 1, 0, 0, 0], [0, -1 / INNER.Td, INNER.K, 0, 0], [0, 0, -1 / INNER.Tp, 0, 0],
                  [0, 0, 0, 0, 1], [K, 0, 0, 0, -1 / Td]], float)
    B = np.array([0, 0, 1 / INNER.Tp, 0, 0.0])
    M = np.zeros((6, 6))
    M[:5, :5], M[:5, 5] = A * dt, B * dt
    E = expm(M)
    Ph, Gm = E[:5, :5], E[:5, 5]
    d_in, d_out = round(INNER.tau / dt), round(tau / dt)
    x = np.zeros(5)
    x[3] = -0.02  # an initial offset starts the relay
    cmd = [0.0] * (d_in + 1)  # the command per sub-step, delayed by d_in sub-steps
    hist = [x[3]] * (d_out + 1)
    I = D = phi_prev = 0.0
    u, e_max, e_min, c = h, 0.0, 0.0, 0.0
    ts, ys, us = [], [], []
    for k in range(int(t_end * RATE)):
        y = hist[-1 - d_out]
        if k % every == 0:
            e = -y
            if u > 0:
                e_max = max(e_max, e)
                if e_max > 0 and e <= -beta * e_max:
                    u, e_min = -h, e
            else:
                e_min = min(e_min, e)
                if e_min < 0 and e >= -beta * e_min:
                    u, e_max = h, e
        phi = x[0]
        ei = u - phi
        I += gains.Ki * T * ei
        D = (gains.Tf * D - gains.Kd * (phi - phi_prev)) / (gains.Tf + T)
        phi_prev = phi
        c = gains.Kp * ei + I + D
        ts.append(k * T), ys.append(y), us.append(u)
        for _ in range(sub):
            cmd.append(c)
            x = Ph @ x + Gm * cmd[-1 - d_in]
            hist.append(x[3])
        del cmd[:-(d_in + 2)], hist[:-(d_out + 2)]
    return np.array(ts), np.array(ys), np.array(us)


def _cycles(ts: np.ndarray, ys: np.ndarray, us: np.ndarray, last: int = 3) -> tuple[np.ndarray, np.ndarray]:
    up = np.nonzero((us[1:] > 0) & (us[:-1] < 0))[0] + 1
    f = 1.0 / np.diff(ts[up])[-last:]
    a = np.array([(ys[i:j].max() - ys[i:j].min()) / 2 for i, j in zip(up[-last - 1:-1], up[-last:])])
    return f, a


@pytest.fixture(scope="module")
def flown() -> dict[float, tuple[np.ndarray, np.ndarray]]:
    """The independent simulation's last cycles at two betas (Td 0.8 s, tau 33.5 ms, K 1)."""
    return {beta: _cycles(*_simulate(beta, 1.0, 0.8, 0.0335, 1.0, t_end), last=2)
            for beta, t_end in ((-0.3, 15.0), (0.3, 40.0))}


def test_cycle_matches_an_independent_simulation(flown) -> None:
    """The simulated loop locks onto one of the exact admissible orbits: its frequency and amplitude."""
    for beta, (f, a) in flown.items():
        lc = _cascade().sampled_limit_cycle(beta, 1.0, RATE)
        k = int(np.argmin(np.abs(np.array(lc.orbits_hz) - f[-1])))
        assert f[-1] == pytest.approx(lc.orbits_hz[k], rel=1e-9)
        assert a[-1] == pytest.approx(lc.orbits_amplitude[k], rel=2e-3)  # the sim's max is on its tick grid
        assert min(lc.orbits_hz) <= lc.frequency_hz <= max(lc.orbits_hz)


def test_cycle_with_an_inner_pid() -> None:
    """The inner controller's integral path: a PID flown by the independent simulation, the same orbits."""
    pid = Controller(Kp=0.6, Ki=0.3, Kd=0.12, Tf=0.02, rate_hz=RATE)
    f, a = _cycles(*_simulate(-0.3, 1.0, 0.8, 0.0335, 1.0, 15.0, gains=pid), last=1)
    lc = CascadeModel(InnerLoop(INNER, pid), Td=0.8, tau=0.0335, K=1.0).sampled_limit_cycle(-0.3, 1.0, RATE)
    k = int(np.argmin(np.abs(np.array(lc.orbits_hz) - f[-1])))
    assert f[-1] == pytest.approx(lc.orbits_hz[k], rel=1e-9)
    assert a[-1] == pytest.approx(lc.orbits_amplitude[k], rel=2e-3)


def test_outer_relay_at_half_the_rate() -> None:
    """An outer relay deciding every second tick: the lifted realisation's orbits hold the simulated one."""
    f, _ = _cycles(*_simulate(-0.3, 1.0, 0.8, 0.0335, 1.0, 20.0, every=2))
    lc = mrft_limit_cycle(_cascade(), -0.3, 1.0, rate_hz=RATE / 2)
    assert min(abs(o - f[-1]) for o in lc.orbits_hz) < 1e-9 * f[-1]
    with pytest.raises(InputError, match="whole divisor"):
        _cascade().discrete_realisation(RATE / 2.5)


def test_discrete_cycle_of_eq2_agrees_with_lprs() -> None:
    """For eq. (2) alone (its exact ZOH equivalent built here by scipy), the orbits equal lprs.sampled_limit_cycle's."""
    plant = LoopModel(Tp=0.1, Td=1 / 1.42, tau=0.06, K=1.42)
    T = 1.0 / 200.0
    A, B, C = plant.state_space()
    M = np.zeros((4, 4))
    M[:3, :3], M[:3, 3] = A * T, B * T
    E = expm(M)
    d = round(plant.tau / T)  # 12 whole ticks: a buffer of the held commands
    n = 3 + d
    Phi = np.zeros((n, n))
    Phi[:3, :3], Phi[:3, 3 + d - 1] = E[:3, :3], E[:3, 3]
    Gamma = np.zeros(n)
    Gamma[3] = 1.0
    for j in range(1, d):
        Phi[3 + j, 3 + j - 1] = 1.0
    Cd = np.concatenate([C, np.zeros(d)])
    lc = discrete_limit_cycle(DiscreteStateSpace(Phi, Gamma, Cd, 200.0), -0.4, 1.0, plant.frequency_response)
    ref = mrft_limit_cycle(plant, -0.4, 1.0, rate_hz=200.0)
    assert lc.orbits_hz == pytest.approx(ref.orbits_hz, rel=1e-12)
    assert lc.orbits_amplitude == pytest.approx(ref.orbits_amplitude, rel=1e-9)
    assert lc.frequency_hz == pytest.approx(ref.frequency_hz, rel=2e-3)  # both centres of the same band


def test_model_protocol_and_json_round_trip() -> None:
    m = _cascade(K=STANDARD_GRAVITY)
    assert MODEL_FAMILIES["cascade"] is CascadeModel
    assert model_from_json(json.loads(json.dumps(m.to_json()))) == m
    assert m.parameters["K"].known and not m.parameters["Td"].known
    with pytest.raises(InputError, match="no continuous realisation"):
        m.realisation()
    with pytest.raises(InputError, match="rate_hz"):
        mrft_limit_cycle(m, -0.3, 1.0)
    bad = m.to_json()
    bad["inner"]["schema_version"] = 99
    with pytest.raises(InputError) as err:
        model_from_json(bad)
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="Kp"):
        Controller.from_json({"Ki": 0, "Kd": 0, "Tf": 0, "rate_hz": 100})


def test_frequency_response_low_frequency_limit() -> None:
    """At low frequency T_inner -> 1 (a PD closing a type-1 inner loop): G_outer -> K Td e^{-tau s} / (s (Td s + 1))."""
    m = _cascade(Td=0.8, tau=0.03, K=STANDARD_GRAVITY)
    assert complex(m.inner.closed_response(np.array([1e-5]))[0]) == pytest.approx(1.0, abs=1e-4)
    w = np.array([1e-4])
    ref = STANDARD_GRAVITY * 0.8 * np.exp(-0.03j * w) / (1j * w * (0.8j * w + 1))
    assert abs(complex(m.frequency_response(w)[0] / ref[0]) - 1.0) < 1e-3


def _tests(flown) -> list[TestMeasurement]:
    return [TestMeasurement(beta, f, a, 1.0) for beta, (f, a) in flown.items()]


def test_identification_recovers_the_outer_loop(flown) -> None:
    res = identify(_tests(flown), CascadeModel(InnerLoop(INNER, GAINS, "roll"), 1.0, 0.0, K=1.0), rate_hz=RATE)
    td, tau = res.parameters["Td"], res.parameters["tau"]
    assert td.value == pytest.approx(0.8, rel=0.03) and td.ci95_low <= 0.8 <= td.ci95_high
    # the loop locks onto one orbit of the sampled band: tau is known to about half a tick (5 ms at 100 Hz)
    assert tau.value == pytest.approx(0.0335, abs=5e-3) and tau.ci95_low <= 0.0335 <= tau.ci95_high
    back = CascadeIdentification.from_json(json.loads(json.dumps(res.to_json())))
    assert back.to_json() == json.loads(json.dumps(res.to_json()))


def test_identification_of_K_and_the_inner_draws(flown) -> None:
    inner = InnerLoop(INNER, GAINS, "roll")
    free = identify(_tests(flown), CascadeModel(inner, 1.0, 0.0, known=frozenset()), rate_hz=RATE)  # K unknown
    assert free.parameters["K"].value == pytest.approx(1.0, rel=0.05) and not free.parameters["K"].known
    draws = [InnerLoop(INNER.with_parameters(Td=INNER.Td * s, tau=INNER.tau + 0.002 * (s - 1) * 5), GAINS)
             for s in (0.9, 1.1, 0.95, 1.05)]
    wide = identify(_tests(flown), CascadeModel(inner, 1.0, 0.0), rate_hz=RATE, inner_draws=draws)
    exact = identify(_tests(flown), CascadeModel(inner, 1.0, 0.0), rate_hz=RATE)
    assert wide.inner_draws == 4 and wide.parameters["Td"].std > exact.parameters["Td"].std
    with pytest.raises(IdentificationError, match="two different beta"):
        identify(_tests(flown)[:1], CascadeModel(inner, 1.0, 0.0, known=frozenset()), rate_hz=RATE)


def test_inner_gains_forms_and_errors() -> None:
    from mrftcli.analyze.cascade import inner_gains_of

    g = GAINS.to_json()
    assert inner_gains_of({"roll": g}, "roll") == GAINS
    assert inner_gains_of({"design": "robust", "kind": "PD", **g, "form": "parallel"}, "roll") == GAINS
    assert inner_gains_of({"loop": "roll", "export": {"generic": g}}, "roll") == GAINS
    assert inner_gains_of({"loops": {"roll": {"gains": {"generic": g}}}}, "roll") == GAINS
    with pytest.raises(InputError, match="no gains for the roll loop"):
        inner_gains_of({"pitch": g}, "roll")
    with pytest.raises(InputError, match="holds gains of the pitch loop"):
        inner_gains_of({"loop": "pitch", "export": {"generic": g}}, "roll")
    # a stack's rate filter the cascade would ignore is refused; one the stack bypasses (0, or >= rate / 2) is not
    with pytest.raises(InputError, match=r"--inner-gains \(roll\): the cascade does not model a stack's rate filter"):
        inner_gains_of({"roll": {**g, "rate_filter": {"cutoff_hz": 20.0, "parameter": "IMU_GYRO_CUTOFF"}}}, "roll")
    for off in (0.0, 0.5 * GAINS.rate_hz):
        assert inner_gains_of({"roll": {**g, "rate_filter": {"cutoff_hz": off}}}, "roll").rate_hz == GAINS.rate_hz


def test_tune_on_the_cascade_keeps_its_margins() -> None:
    """The robust PD holds its phase margin on every draw; the closed loop of the independent form is stable."""
    from mrftcli.tune.design import TuneResult, tune
    from mrftcli.tune.closed_loop import closed_loop_matrix

    m = _cascade()
    draws = [m.with_parameters(Td=0.7, tau=0.04), m.with_parameters(Td=0.9, tau=0.028)]
    res = tune(m, RATE, posterior=draws, loop="y")
    robust = res.get("robust", "PD")
    worst = robust.posterior["worst"]
    assert worst["phase_margin_deg"] >= 45.0 - 1e-6 and worst["stable"]
    for model in [m, *draws]:
        A, _, _ = closed_loop_matrix(model.discrete_realisation(RATE), robust.controller)
        assert np.max(np.abs(np.linalg.eigvals(A))) < 1.0
    assert TuneResult.from_json(json.loads(json.dumps(res.to_json()))).to_json() == json.loads(
        json.dumps(res.to_json()))
    # the cascade is a strategy of the one grid search: the designs asked for, eq. (2)'s options refused
    from mrftcli.tune.design import DesignOptions

    only = tune(m, RATE, posterior=draws, loop="y", options=DesignOptions(designs=("model-based",)))
    assert [d.name for d in only.designs] == ["model-based"] and only.designs[0] == res.get("model-based", "PD")
    with pytest.raises(InputError, match="cascade's outer loop"):
        tune(m, RATE, options=DesignOptions(kinds=("PID",)))


def test_cli_option_errors(tmp_path) -> None:
    """Bad cascade options: a one-line error naming the option, exit 2 (no log is read)."""
    inner = tmp_path / "roll.json"
    inner.write_text(json.dumps({"schema_version": 1, "input": {"loop": "roll"},
                                 "parameters": {"Tp": {"mean": 0.04}, "Td": {"mean": 0.5, "std": 0.02},
                                                "tau": {"mean": 0.0125, "std": 0.001}, "K": {"mean": 40.0, "std": 1}}}))
    gains = tmp_path / "gains.json"
    gains.write_text(json.dumps({"pitch": GAINS.to_json()}))
    log = tmp_path / "missing.csv"

    r = run_main("analyze", str(log), "--loop", "y", "--inner-model", str(inner))  # main() in this process
    assert r.returncode == 2 and "--inner-gains" in r.stderr and "Traceback" not in r.stderr
    from click.testing import CliRunner

    from mrftcli.cli.main import cli

    def run(*args: str) -> Any:
        return CliRunner().invoke(cli, ["analyze", str(log), *args])

    res = run("--loop", "roll", "--inner-model", str(inner), "--inner-gains", str(gains))
    assert res.exit_code == 2 and "--loop x or y" in res.output
    res = run("--loop", "y", "--inner-model", str(inner), "--inner-gains", str(gains))
    assert isinstance(res.exception, InputError) and "no gains for the roll loop" in str(res.exception)
    filtered = tmp_path / "filtered.json"
    filtered.write_text(json.dumps({"roll": {**GAINS.to_json(), "rate_filter": {"cutoff_hz": 20.0}}}))
    r = run_main("analyze", str(log), "--loop", "y", "--inner-model", str(inner), "--inner-gains", str(filtered))
    assert r.returncode != 0 and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert "--inner-gains (roll)" in r.stderr and "rate filter" in r.stderr, r.stderr


def test_cli_analyze_and_tune_a_cascaded_flight(tmp_path) -> None:
    """A simulated HEAR flight's y tests through the roll loop: analyze --inner-model, then tune its result."""
    from click.testing import CliRunner

    from mrftcli.cli.main import cli
    from mrftcli.sim.cascade import simulate_cascade
    from mrftcli.sim.cascade_spec import CascadeSpec, InnerGains
    from mrftcli.sim.cascade_write import write_cascade
    from mrftcli.sim.spec import TestSpec

    gains = InnerGains(GAINS.Kp, GAINS.Ki, GAINS.Kd, GAINS.Tf, RATE)
    spec = CascadeSpec(inner=INNER, gains=gains, Td=0.8, tau=0.0335, axis="y",
                       outer_tests=(TestSpec(-0.3, 1.0, 20.0),), hover_s=1.0, hold_s=1.0, seed=3)
    log = tmp_path / "flight"
    write_cascade(simulate_cascade(spec), log, layout="hear-ros")
    inner = tmp_path / "roll.json"
    inner.write_text(json.dumps({"schema_version": 1, "input": {"loop": "roll"},
                                 "parameters": {"Tp": {"mean": INNER.Tp}, "Td": {"mean": INNER.Td, "std": 0.01},
                                                "tau": {"mean": INNER.tau, "std": 5e-4}, "K": {"mean": INNER.K, "std": 0.5}}}))
    gfile = tmp_path / "gains.json"
    gfile.write_text(json.dumps({"roll": GAINS.to_json()}))
    out = tmp_path / "y.json"
    res = CliRunner().invoke(cli, ["analyze", str(log), "--loop", "y", "--inner-model", str(inner), "--inner-gains",
                                   str(gfile), "--inner-draws", "0", "--json", str(out)])
    assert res.exit_code == 0, res.output
    assert res.output.splitlines()[2].startswith("assumption:") and "K = 1" in res.output
    tau_row = next(line.split() for line in res.output.splitlines() if line.strip().startswith("tau "))
    assert tau_row[1] == "ms" and 0.5 * 33.5 < float(tau_row[2]) < 1.5 * 33.5  # in ms as analyze shows it (issue 40)
    data = json.loads(out.read_text())
    assert data["kind"] == "cascade" and model_from_json(data["model"]).family == "cascade"
    assert data["parameters"]["Td"]["ci95_low"] <= 0.8 <= data["parameters"]["Td"]["ci95_high"]
    from mrftcli.analyze.record import AnalysisResult

    back = AnalysisResult.from_json(data)
    assert back.to_json() == data and back.model == model_from_json(data["model"])
    assert dict(back.model.inner.std)["Td"] == pytest.approx(0.01)
    res = CliRunner().invoke(cli, ["tune", str(out), "--export", "generic"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["Kp"] > 0 and "export generic (robust PD, y)" in res.stderr


def test_cascade_tune_version_1_still_reads() -> None:
    """A cascade's tune JSON of the previous release (its own record, kind "cascade", schema 1: vehicle records
    hold it; tests/data/old_records/cascade_tune_v1.json, tune y.json of the shipped HEAR cascade) reads into
    the one TuneResult with its gains and figures, and writes back as the current version."""
    from mrftcli.tune.design import TUNE_SCHEMA_VERSION, TuneResult

    old = json.loads((Path(__file__).parent / "data" / "old_records" / "cascade_tune_v1.json").read_text())
    res = TuneResult.from_json(old)
    for d, o in zip(res.designs, old["designs"]):
        assert d.kind == "PD" and d.controller.to_dict() == {**o["generic"], "form": d.controller.to_dict()["form"]}
        assert (d.margins.phase_margin_deg, d.margins.Ms, d.criterion) == (
            o["nominal"]["phase_margin_deg"], o["nominal"]["Ms"], o["iae"])
    assert res.get("robust", "PD").posterior["worst"]["Ms"] == old["designs"][1]["worst"]["Ms"]
    new = json.loads(json.dumps(res.to_json()))
    assert new["schema_version"] == TUNE_SCHEMA_VERSION and new["model"]["family"] == "cascade"
    assert TuneResult.from_json(new).to_json() == new


def test_records_refuse_other_versions() -> None:
    """Every record's from_json: a one-line InputError on another schema_version or a wrong shape."""
    from mrftcli.analyze.record import AnalysisResult
    from mrftcli.tune.design import TuneResult

    for cls in (InnerLoop, CascadeIdentification, AnalysisResult, TuneResult):
        for bad in ({"schema_version": 99}, [], {"schema_version": 1}):
            with pytest.raises(InputError) as err:
                cls.from_json(bad)
            assert "\n" not in str(err.value)


def test_inner_loop_draws_over_its_std() -> None:
    inner = InnerLoop(INNER, GAINS, "roll", (("Td", 0.05), ("tau", 0.002)))
    assert InnerLoop.from_json(json.loads(json.dumps(inner.to_json()))).std == inner.std
    rng = np.random.default_rng(1)
    draws = [inner.draw(rng).plant.parameters for _ in range(200)]
    td = np.array([d["Td"].value for d in draws])
    assert np.std(np.log(td)) == pytest.approx(0.05 / INNER.Td, rel=0.2)
    assert all(d["K"].value == INNER.K and d["Tp"].value == INNER.Tp for d in draws)
    with pytest.raises(InputError, match="not parameters of the plant"):
        InnerLoop.from_json({**inner.to_json(), "std": {"T9": 1.0}})


def test_outer_tau_on_a_receive_stamped_flight(tmp_path) -> None:
    """Issue 23: on a HEAR-layout (receive-stamped, beta not logged) flight at 100 Hz, the outer tau
    read through the orbits' switch levels is within 3 ms and its interval; the band's centre at the
    beta inferred from the level less half a tick (the route before) is off by 6.5 ms.

    Oracle: the cascade simulator (:mod:`mrftcli.sim.cascade`, a per-tick integration sharing no
    code with :mod:`mrftcli.mrft.cascade`) and its true tau.
    """
    from mrftcli.analyze import analyze_flight
    from mrftcli.analyze.cascade import _measurement, cascade_model
    from mrftcli.io import read_flight
    from mrftcli.io.flight import ReadOptions
    from mrftcli.sim.cascade import simulate_cascade
    from mrftcli.sim.cascade_spec import CascadeSpec, InnerGains
    from mrftcli.sim.cascade_write import write_cascade
    from mrftcli.sim.spec import TestSpec

    inner = LoopModel(Tp=0.064, Td=2.33, tau=0.0338, K=24.8)
    gains = Controller(0.2558, 0.0, 0.1081, 0.04225, RATE)
    tau = 0.0351
    spec = CascadeSpec(inner=inner, gains=InnerGains(gains.Kp, gains.Ki, gains.Kd, gains.Tf, RATE), Td=1.42, tau=tau,
                       axis="y", commanded="attitude",
                       outer_tests=(TestSpec(-0.4, 0.02, 25.0), TestSpec(-0.7, 0.031, 20.0)),
                       attitude_noise_std=6.8e-4, position_noise_std=2.9e-4, hover_s=1.0, hold_s=2.0, seed=2)
    log = tmp_path / "flight.bag"
    write_cascade(simulate_cascade(spec), log, layout="hear-ros")
    flight = read_flight(log, ReadOptions(loop="y"), echo_warnings=False)
    assert flight.timing.stamps == "receive"
    loop = InnerLoop(inner, gains, "roll")
    analysis = analyze_flight(flight, cascade_model(loop, "attitude"))
    est = analysis.identification.parameters["tau"]
    before = identify([_measurement(t) for t in analysis.tests], CascadeModel(loop, 1.0, 0.0, K=STANDARD_GRAVITY), rate_hz=RATE).parameters["tau"]
    assert abs(est.value - tau) < 3e-3 and est.ci95_low <= tau <= est.ci95_high
    assert abs(est.value - tau) < abs(before.value - tau) - 2e-3
    assert any("receive-time stamps" in a for a in analysis.assumptions)


def test_orbit_at_matches_the_exact_cycle() -> None:
    """The orbit of a whole half period is one of the exact cycle's admissible orbits; its switch
    level is past beta by at most one tick's rise (the relay decides on samples)."""
    model = _cascade()
    lc = model.sampled_limit_cycle(-0.3, 1.0, RATE)
    n = RATE / (2 * lc.orbits_hz[0])
    orbit = model.orbit_at(n, 1.0, RATE)
    assert orbit.amplitude == pytest.approx(lc.orbits_amplitude[0], rel=1e-9)
    rise = np.sin(2 * np.pi * lc.orbits_hz[0] / RATE)  # the cycle's largest rise over a tick, over its amplitude
    assert -0.3 - 1e-9 <= orbit.switch_level <= -0.3 + rise
    with pytest.raises(InputError, match="half period"):
        model.orbit_at(1.0, 1.0, RATE)


def test_split_interval_and_whole_and_fraction_take_stacks():
    # tune's held delays (tune.closed_loop._held) split every draw's tick at once: each plant of the
    # stack as the scalar call makes it, and both against scipy's expm of the augmented matrix
    from mrftcli.mrft.cascade import split_interval, whole_and_fraction

    rng = np.random.default_rng(7)
    A = rng.normal(size=(5, 3, 3))
    B = rng.normal(size=(5, 3))
    T = 0.01
    delay = np.array([0.0, 0.004, 0.01, 0.0237, 0.05 - 1e-15])
    d, eps = whole_and_fraction(delay, T)
    assert d.tolist() == [whole_and_fraction(float(x), T)[0] for x in delay] == [0, 0, 1, 2, 5]
    assert np.allclose(eps, [whole_and_fraction(float(x), T)[1] for x in delay], rtol=0, atol=1e-18)
    Phi, G_old, G_new = split_interval(A, B, T, eps)
    for i in range(5):
        one = split_interval(A[i], B[i], T, float(eps[i]))
        for got, want in zip((Phi[i], G_old[i], G_new[i]), one):
            assert np.allclose(got, want, rtol=1e-13, atol=1e-16)
        X = np.zeros((4, 4))
        X[:3, :3], X[:3, 3] = A[i], B[i]
        old = expm(X * (T - eps[i]))[:3, :3] @ expm(X * eps[i])[:3, 3]
        assert np.allclose(Phi[i], expm(A[i] * T), rtol=1e-12)
        assert np.allclose(G_old[i] + G_new[i], expm(X * T)[:3, 3], rtol=1e-12, atol=1e-16)
        assert np.allclose(G_old[i], old, rtol=1e-12, atol=1e-16)
    # an input changing at or after t: the old one over the whole tick, the new one never
    _, late_old, late_new = split_interval(A, B, T, np.full(5, 2 * T))
    assert np.allclose(late_old, G_old + G_new, rtol=1e-12, atol=1e-16) and not late_new.any()
