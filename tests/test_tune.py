"""``mrft-ident tune``: the sampled closed loop, margins, the MRFT rule, exports, against independent oracles."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

control = pytest.importorskip("control")

from mrftcli.mrft.model import LoopModel  # noqa: E402
from mrftcli.tune.closed_loop import Controller, simulate_step, step_metrics, step_response  # noqa: E402
from mrftcli.tune.design import RULE_C1, RULE_C3, Posterior, mrft_rule  # noqa: E402
from mrftcli.tune.export import hear_json, px4_params  # noqa: E402
from mrftcli.tune.margins import margins, plant_response, plant_system  # noqa: E402
from mrftcli.errors import InputError  # noqa: E402

ROLL = LoopModel(0.0422, 1.301, 0.0297, 30.0)  # checks.md Table III, Design I roll (K arbitrary)
PD = Controller(0.29, 0.0, 0.11, 0.037, 200.0)
PID = Controller(0.28, 0.18, 0.106, 0.038, 200.0)


@pytest.mark.parametrize("ctrl", [PD, PID])
def test_state_matrices_match_event_simulation(ctrl):
    # fractional delay (29.7 ms = 5.94 samples): the z-domain matrices against the event-driven
    # continuous-time simulation, two independent constructions of the same sampled loop
    t, y, u = step_response([ROLL], ctrl, 2.0)
    t2, y2, u2, _ = simulate_step(ROLL, ctrl, 2.0)
    assert np.max(np.abs(y[0] - y2)) < 1e-9
    assert np.max(np.abs(u[0] - u2)) < 1e-9


def test_closed_loop_matches_python_control():
    # delay a whole number of samples: python-control's zoh c2d, a z^-d delay and the controller's
    # transfer functions give the step response independently of the tool's state matrices
    model = LoopModel(0.05, 0.9, 0.03, 12.0)
    c = PID
    T = c.Ts
    A, B, C = model.state_space()
    Gc = control.ss(A, B.reshape(3, 1), C.reshape(1, 3), 0)
    Gd = control.c2d(Gc, T, "zoh") * control.tf([1], [1] + [0] * 6, T)  # 6 samples = 30 ms
    z = control.tf([1, 0], [1], T)
    Cr = c.Kp + c.Ki * T * z / (z - 1)
    Cfb = Cr + c.Kd * (z - 1) / ((c.Tf + T) * z - c.Tf)
    Tyr = control.feedback(Gd, Cfb) * Cr
    n = 400
    resp = control.forced_response(Tyr, T=np.arange(n) * T, U=np.ones(n))
    _, y, _ = step_response([model], c, (n - 1) * T)
    assert np.max(np.abs(y[0] - np.asarray(resp.outputs).ravel())) < 1e-6


def _aliased_loop(model: LoopModel, c: Controller, w: np.ndarray, n_alias: int = 3000) -> np.ndarray:
    """L(e^{jwT}) by the Poisson sum of the continuous plant and the zero-order hold (exact e^{-jw tau})."""
    T = c.Ts
    k = np.arange(-n_alias, n_alias + 1)
    wk = w[:, None] + 2 * np.pi * k[None, :] / T
    s = 1j * wk
    G = model.K * model.Td * np.exp(-model.tau * s) / (s * (model.Tp * s + 1) * (model.Td * s + 1))
    zoh = (1 - np.exp(-s * T)) / s
    Gd = np.sum(G * zoh, axis=1) / T
    return c.feedback_response(w) * Gd


@pytest.mark.parametrize("ctrl", [PD, PID])
def test_margins_against_brute_force_sweep(ctrl):
    mg = margins(ROLL, ctrl)
    w = np.geomspace(0.05, np.pi * 200 * 0.999, 5000)
    L = _aliased_loop(ROLL, ctrl, w, n_alias=400)
    Ms = np.max(1 / np.abs(1 + L))
    lm = np.log(np.abs(L))
    ph = np.unwrap(np.angle(L))
    i = np.nonzero((lm[:-1] > 0) & (lm[1:] <= 0))[0][0]
    f = lm[i] / (lm[i] - lm[i + 1])  # linear interpolation between the two grid points
    pm = 180 + np.degrees(ph[i] + f * (ph[i + 1] - ph[i]))
    j = np.nonzero((ph[:-1] > -np.pi) & (ph[1:] <= -np.pi))[0][0]
    f = (ph[j] + np.pi) / (ph[j] - ph[j + 1])
    gm = 1 / np.exp(lm[j] + f * (lm[j + 1] - lm[j]))
    assert mg.Ms == pytest.approx(Ms, rel=2e-3)
    assert mg.phase_margin_deg == pytest.approx(pm, abs=0.05)
    assert mg.gain_margin == pytest.approx(gm, rel=2e-3)
    # the plant response used by the optimiser equals python-control's of the same state space
    fr = np.asarray(plant_system(ROLL, 200.0).frequency_response(w[:50]).complex).ravel()
    assert np.allclose(plant_response([ROLL], 200.0, w[:50])[0], fr, rtol=1e-8)


def test_delay_margin_is_where_the_sampled_loop_loses_stability():
    mg = margins(ROLL, PD)
    assert 0 < mg.delay_margin_s < 1
    horizon = 12.0
    _, y_in, _, _ = simulate_step(ROLL, PD, horizon, substeps=1, extra_delay=0.95 * mg.delay_margin_s)
    _, y_out, _, _ = simulate_step(ROLL, PD, horizon, substeps=1, extra_delay=1.05 * mg.delay_margin_s)
    tail = int(2.0 * PD.rate_hz)
    swing = lambda y, a, b: np.ptp(y[a:b])  # noqa: E731
    # inside the margin the oscillation decays, beyond it it grows
    assert swing(y_in, -tail, None) < swing(y_in, -3 * tail, -2 * tail)
    assert swing(y_out, -tail, None) > swing(y_out, -3 * tail, -2 * tail)


def test_mrft_rule_on_the_papers_example():
    # checks.md section 1: exact MRFT cycle at beta = -0.7 of 1/(s(0.1 s + 1)(0.7042 s + 1)) with 60 ms
    # delay: 1.01884 Hz, amplitude 0.035602 for h = 1; section 5: Kp = c1 4 h / (pi a0), Td_c = c3 T0
    model = LoopModel(0.1, 0.7042, 0.06, 1 / 0.7042)
    c, cyc = mrft_rule(model, 10000.0)  # a fast controller (10 kHz): the continuous relay's figures within 7e-4
    T0, a0 = 1 / 1.01884, 0.035602
    assert cyc["T0"] == pytest.approx(T0, rel=2e-3)
    assert c.Kp == pytest.approx(RULE_C1 * 4 / (np.pi * a0), rel=3e-3)
    assert c.Kd / c.Kp == pytest.approx(RULE_C3 * T0, rel=2e-3)


def test_step_metrics_of_a_second_order_system():
    # closed forms: overshoot exp(-pi zeta / sqrt(1 - zeta^2)) of a standard second-order step
    zeta, wn = 0.3, 4.0
    t = np.linspace(0, 20, 200001)
    wd = wn * math.sqrt(1 - zeta**2)
    y = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * t))
    m = step_metrics(t, y)
    assert m.overshoot_pct == pytest.approx(100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2)), rel=1e-4)
    assert m.iae > 0 and m.settling_s > m.rise_s > 0


def test_px4_cascade_reproduces_the_pd_loop():
    # PX4: rate_sp = MC_ROLL_P (r - y); u = MC_ROLLRATE_P (rate_sp - rate), rate = the filtered
    # derivative of the angle. Simulated as a cascade (own loop), it is the PD's step response.
    p = px4_params(PD, "roll", relay_heights=[0.17], amplitudes=[0.17])
    P_att, P_rate = p["MC_ROLL_P"], p["MC_ROLLRATE_P"]
    A, B, C = ROLL.state_space()
    T = PD.Ts
    from scipy.linalg import expm

    n = 600
    d = 6
    model = LoopModel(ROLL.Tp, ROLL.Td, d * T, ROLL.K)  # whole samples, so a plain command queue
    M = np.zeros((4, 4))
    M[:3, :3], M[:3, 3] = A, B
    E = expm(M * T)
    Phi, Gam = E[:3, :3], E[:3, 3]
    x = np.zeros(3)
    queue = [0.0] * d
    rate = y_prev = 0.0
    ys = []
    for _ in range(n):
        y = C @ x
        rate = (PD.Tf * rate + (y - y_prev)) / (PD.Tf + T)
        y_prev = y
        u = P_rate * (P_att * (1.0 - y) - rate)
        queue.append(u)
        x = Phi @ x + Gam * queue.pop(0)
        ys.append(y)
    _, y_pd, _ = step_response([model], PD, (n - 1) * T)
    assert np.max(np.abs(np.array(ys) - y_pd[0])) < 1e-10


def test_px4_refuses_with_reasons():
    with pytest.raises(InputError, match="integral"):
        px4_params(PID, "roll")
    with pytest.raises(InputError, match="altitude"):
        px4_params(PD, "altitude")
    with pytest.raises(InputError, match="relay height"):
        px4_params(PD, "roll", relay_heights=[3.0])
    with pytest.raises(InputError, match="radians"):
        px4_params(PD, "pitch", amplitudes=[5.0])


def test_hear_export_fields():
    h = hear_json(PID, "pitch")
    assert {k: h[k] for k in ("id", "kp", "ki", "kd", "kdd", "en_pv_derivation")} == \
        {"id": 4, "kp": PID.Kp, "ki": PID.Ki, "kd": PID.Kd, "kdd": 0.0, "en_pv_derivation": 1}
    assert h["dt"] == pytest.approx(0.005)


def test_posterior_95_set_holds_95_percent_of_gaussian_draws():
    rng = np.random.default_rng(5)
    n = 4000
    p = Posterior(LoopModel(0.04, 1.0, 0.03, 2.0), np.exp(rng.normal(0, 0.3, n)), np.exp(rng.normal(-3.5, 0.1, n)),
                  np.full(n, 2.0))
    assert p.in_set().mean() == pytest.approx(0.95, abs=0.015)


def test_cli_manual_model_px4_and_errors(tmp_path):
    from click.testing import CliRunner

    from mrftcli.cli.main import cli

    r = CliRunner().invoke(cli, ["tune", "--tp", "0.0422", "--td", "1.3", "--tau", "0.03", "--k", "30",
                                 "--loop", "roll", "--controller-rate", "250", "--export", "px4", "--design", "model-based",
                                 "--json", str(tmp_path / "t.json")])
    assert r.exit_code == 0, r.output
    rows = [ln.split("\t") for ln in r.stdout.splitlines() if ln.startswith("1\t1\t")]  # the QGC .params lines
    px4 = {row[2]: float(row[3]) for row in rows}
    data = json.loads((tmp_path / "t.json").read_text())
    mb = [d for d in data["designs"] if d["design"] == "model-based" and d["kind"] == "PD"][0]
    assert px4["MC_ROLL_P"] == pytest.approx(mb["controller"]["Kp"] / mb["controller"]["Kd"])
    assert data["export"]["stack"]["params"]["MC_ROLLRATE_P"] == pytest.approx(mb["controller"]["Kd"])
    assert mb["margins"]["Ms"] <= 1.6 * 1.001
    from mrftcli.cli.main import main

    with pytest.raises(SystemExit) as e:
        main(["tune", "--tp", "0.0422", "--loop", "roll"])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        main(["tune", "--tp", "0.0422", "--td", "1", "--tau", "0.03", "--json", str(tmp_path / "no" / "x.json")])
    assert e.value.code == 2


def test_modal_discretisation_matches_matrix_exponentials():
    # the closed-form modal discretisation against scipy's expm of the augmented system (any Tp, Td),
    # including a plant near Tp = Td, where the modal form hands over to expm
    from scipy.linalg import expm

    from mrftcli.tune.closed_loop import discrete_plants

    rng = np.random.default_rng(3)
    models = [LoopModel(0.0422, float(np.exp(rng.normal(0, 1))), float(rng.uniform(0, 0.1)), float(rng.uniform(-30, 30)))
              for _ in range(20)] + [LoopModel(0.05, 0.0501, 0.012, 4.0), LoopModel(0.05, 0.9, 0.0, 1.0)]
    T = 1 / 250.0
    for m, p in zip(models, discrete_plants(models, 250.0)):
        A, B, _ = m.state_space()
        Mx = np.zeros((4, 4))
        Mx[:3, :3], Mx[:3, 3] = A, B
        d = int(np.floor(m.tau / T + 1e-12))
        eps = m.tau - d * T
        Eeps, Erest = expm(Mx * eps), expm(Mx * (T - eps))
        assert p.d == d
        assert np.allclose(p.Phi, expm(Mx * T)[:3, :3], rtol=1e-12, atol=1e-14)
        assert np.allclose(p.Gamma[1], Erest[:3, 3], rtol=1e-10, atol=1e-16)
        assert np.allclose(p.Gamma[0], Erest[:3, :3] @ Eeps[:3, 3], rtol=1e-10, atol=1e-16)


def test_load_step_matches_event_simulation_and_pd_offset():
    # load step (input disturbance) of the z-domain loop against the event-driven simulation; and the
    # closed form: a PD on an integrating plant settles at y = d / Kp (u + d = 0), a PID returns to 0
    from mrftcli.tune.closed_loop import responses

    d = 0.2
    for ctrl in (PD, PID):
        t, _, _, yl, _ = responses([ROLL], ctrl, 40.0, load=d)
        _, y2, _, _ = simulate_step(ROLL, ctrl, 40.0, substeps=1, setpoint=0.0, load=d)
        assert np.max(np.abs(yl[0] - y2)) < 1e-9
    t, _, _, yl, _ = responses([ROLL], PD, 40.0, load=d)
    assert yl[0, -1] == pytest.approx(d / PD.Kp, rel=1e-4)  # u = -Kp y = -d
    _, _, _, yl, _ = responses([ROLL], PID, 40.0, load=d)
    assert abs(yl[0, -1]) < 1e-3 * d / PID.Kp


def test_pid_design_optimises_integral_action_within_the_limits():
    # the model-based PID chooses its own Ti: it must satisfy Ms <= 1.6, reject the load step (recover
    # within the horizon) and beat the fixed-ratio PID (Ti = 4 Td_c at the same Kp, Td_c) on its criterion
    from mrftcli.tune.design import TI_RATIO, DesignOptions, tune
    from mrftcli.tune.closed_loop import criterion, responses

    res = tune(ROLL, 200.0, options=DesignOptions(designs=("model-based",), kinds=("PD", "PID")))
    pd, pid = res.get("model-based", "PD"), res.get("model-based", "PID")
    c = pid.controller
    assert c.Ki > 0 and pid.margins.Ms <= 1.6 * 1.002
    assert pid.load["size"] == pytest.approx(pd.controller.Kp)
    assert np.isfinite(pid.load["recovery_s"]) and np.isfinite(pid.step.settling_s)
    fixed = Controller(c.Kp, c.Kp / (TI_RATIO * c.Kd / c.Kp), c.Kd, c.Tf, 200.0)
    t, y, _, yl, _ = responses([ROLL], fixed, pid.horizon_s, load=pid.load["size"])
    J_fixed = float(criterion(t, y[0]) + criterion(t, 1.0 - yl[0]))
    assert pid.criterion < J_fixed


def test_result_json_posterior_says_the_correlation_is_lost():
    from mrftcli.mrft.model import soiptd_model
    from mrftcli.tune.analysis import NO_CORRELATION_NOTE, model_from_result_json

    data = {"parameters": {"Td": {"mean": 1.3, "std": 0.1}, "tau": {"mean": 0.03, "std": 0.002},
                           "K": {"mean": 30.0, "std": 1.0}, "Tp": {"mean": 0.0422}}}
    model, post, note = model_from_result_json(data, soiptd_model(0.0422))
    assert note == NO_CORRELATION_NOTE and "correlation" in note
    assert model.Td == 1.3 and post.n == 200
    assert abs(np.corrcoef(post.Td, post.tau)[0, 1]) < 0.2
    with pytest.raises(InputError, match="Tp"):
        model_from_result_json(data, soiptd_model(0.05))


# --- long delays (issue 30): margins against an independent frequency response, stability, responses ---

FLIGHT = LoopModel(0.08, 3.205, 0.451, 0.98)  # the issue's lateral loop: 90.2 ticks of delay at 200 Hz


def _oracle_loop(model: LoopModel, c: Controller, w: float | np.ndarray, n_alias: int = 400) -> np.ndarray:
    """L(e^{jwT}) written from scratch: the controller's difference equations in z, and the plant sampled
    through the zero-order hold as the Poisson sum of G(j w_k) (1 - e^{-j w_k T}) / (j w_k T) with the
    exact delay e^{-j w_k tau} (shares no code with mrftcli.tune)."""
    T = 1.0 / c.rate_hz
    w = np.atleast_1d(np.asarray(w, float))
    Gd = np.empty(w.size, complex)
    for i in range(0, w.size, 500):  # in chunks: 500 x 801 terms at a time
        s = 1j * (w[i:i + 500, None] + 2 * np.pi * np.arange(-n_alias, n_alias + 1)[None, :] / T)
        G = model.K * model.Td * np.exp(-model.tau * s) / (s * (model.Tp * s + 1) * (model.Td * s + 1))
        Gd[i:i + 500] = np.sum(G * (1 - np.exp(-s * T)) / (s * T), axis=1)
    z = np.exp(1j * w * T)
    C = c.Kp + c.Ki * T * z / (z - 1) + c.Kd * (z - 1) / ((c.Tf + T) * z - c.Tf)
    return C * Gd


def _oracle_margins(model: LoopModel, c: Controller) -> tuple[float, float, float]:
    """(PM [deg] of smallest |PM|, GM closest to 1, Ms) of the oracle loop: dense grid + brentq."""
    from scipy.optimize import brentq, minimize_scalar

    w_nyq = np.pi * c.rate_hz
    # log-spaced, and linear fine enough for the delay's phase (at most 0.2 rad per step up to 1.2 s)
    w = np.union1d(np.geomspace(w_nyq * 1e-5, w_nyq * 0.999, 3000), np.linspace(w_nyq / 3200, w_nyq * 0.999, 3200))
    L = _oracle_loop(model, c, w)
    mag = lambda x: np.log(np.abs(_oracle_loop(model, c, x)[0]))  # noqa: E731
    im = lambda x: _oracle_loop(model, c, x)[0].imag  # noqa: E731
    lm = np.log(np.abs(L))
    pms = [np.remainder(np.degrees(np.angle(_oracle_loop(model, c, brentq(mag, w[i], w[i + 1], xtol=1e-14))[0])),
                        360) - 180 for i in np.nonzero(np.sign(lm[:-1]) != np.sign(lm[1:]))[0]]
    gms = []
    for i in np.nonzero(np.sign(L.imag[:-1]) != np.sign(L.imag[1:]))[0]:
        Lx = _oracle_loop(model, c, brentq(im, w[i], w[i + 1], xtol=1e-14))[0]
        if Lx.real < 0:
            gms.append(1 / abs(Lx))
    k = int(np.argmin(np.abs(1 + L)))
    r = minimize_scalar(lambda x: abs(1 + _oracle_loop(model, c, x)[0]), bracket=(w[k - 1], w[k], w[k + 1]))
    pm = min(pms, key=abs)
    gm = min(gms, key=lambda g: abs(np.log(g)))
    return pm, gm, 1 / min(r.fun, np.min(np.abs(1 + L)))


def _gains_for(model: LoopModel, rate_hz: float) -> Controller:
    """A PD with some 40-50 deg of phase margin whatever the delay (independent of the designs)."""
    wc = 0.5 / (model.tau + model.Tp + 1 / rate_hz)
    Td_c = 1.5 / wc
    g = abs(model.K * model.Td / (1j * wc * (model.Tp * 1j * wc + 1) * (model.Td * 1j * wc + 1)))
    Kp = 1 / (g * abs(1 + 1j * wc * Td_c))
    return Controller(Kp, 0.0, Kp * Td_c, Td_c / 10, rate_hz)


@pytest.mark.parametrize("ticks", [1.0, 7.3, 45.5, 90.2, 200.0])
def test_margins_against_an_independent_frequency_response_over_delays(ticks):
    from mrftcli.tune.margins import loop_margins

    model = LoopModel(0.08, 3.205, ticks / 200.0, 0.98)
    for c in (_gains_for(model, 200.0), Controller(_gains_for(model, 200.0).Kp, 0.02, _gains_for(model, 200.0).Kd,
                                                   _gains_for(model, 200.0).Tf, 200.0)):
        mg = loop_margins(c, [model])[0]
        pm, gm, Ms = _oracle_margins(model, c)
        assert mg.stable
        assert mg.phase_margin_deg == pytest.approx(pm, abs=0.05)
        assert mg.gain_margin == pytest.approx(gm, rel=1e-3)
        assert mg.Ms == pytest.approx(Ms, rel=1e-3)


def test_the_issues_flight_gains_have_their_true_margins():
    # issue 30: these gains were reported with GM 0.38 and PM -4.3 deg on the very model they were
    # designed for; the loop's exact response gives one crossover near 0.68 rad/s with PM ~48 deg
    c = Controller(0.3305, 0.0, 0.5441, 0.1646, 200.0)
    mg = margins(FLIGHT, c)
    assert mg.stable and mg.phase_margin_deg == pytest.approx(48.0, abs=1.0)
    assert mg.w_gc == pytest.approx(0.68, abs=0.02) and mg.gain_margin > 3
    pm, gm, _ = _oracle_margins(FLIGHT, c)
    assert mg.phase_margin_deg == pytest.approx(pm, abs=0.05) and mg.gain_margin == pytest.approx(gm, rel=1e-3)


def test_stability_and_delay_margin_agree_with_the_closed_loop_eigenvalues():
    # the Nyquist flag against the spectral radius of the closed-loop state matrix, stable and unstable
    # loops, short and long delays; the delay margin against the eigenvalues at +-0.1 % of it
    from dataclasses import replace

    from mrftcli.tune.closed_loop import augmented, closed_loop_matrix, discrete_plants
    from mrftcli.tune.margins import loop_margins

    def rho(m, c, extra=0.0):
        A, *_ = closed_loop_matrix(augmented(discrete_plants([replace(m, tau=m.tau + extra)], c.rate_hz)[0]), c)
        return np.max(np.abs(np.linalg.eigvals(A)))

    rng = np.random.default_rng(11)
    for i in range(8):
        m = LoopModel(float(rng.uniform(0.03, 0.1)), float(np.exp(rng.normal(0, 0.7))),
                      float(rng.uniform(0.0, 0.25)), float(rng.uniform(0.5, 30)))
        base = _gains_for(m, 200.0)
        c = Controller(base.Kp, base.Kp * 0.05 * (i % 2), base.Kd, base.Tf, 200.0)
        for g in (1.0, 3.0):
            cg = c.scaled(g)
            mg = loop_margins(cg, [m])[0]
            assert mg.stable == (rho(m, cg) < 1.0)
            if mg.stable and np.isfinite(mg.delay_margin_s):
                assert rho(m, cg, 0.999 * mg.delay_margin_s) < 1.0 < rho(m, cg, 1.001 * mg.delay_margin_s)


@pytest.mark.parametrize("ctrl", [PD, PID])
def test_long_delay_responses_match_event_simulation(ctrl):
    # 90.2 ticks of delay: the responses come from the z-transform inversion; the event-driven
    # continuous-time simulation is the independent check (setpoint and load steps)
    from mrftcli.tune.closed_loop import responses

    model = LoopModel(0.0422, 1.301, 0.451, 30.0)
    c = _gains_for(model, 200.0)
    c = Controller(c.Kp, c.Kp * 0.05 if ctrl.Ki else 0.0, c.Kd, c.Tf, 200.0)
    t, y, u, yl, _ = responses([model], c, 30.0, load=0.2)
    _, y2, u2, _ = simulate_step(model, c, 30.0, substeps=1)
    _, yl2, _, _ = simulate_step(model, c, 30.0, substeps=1, setpoint=0.0, load=0.2)
    assert np.max(np.abs(y[0] - y2)) < 1e-8 and np.max(np.abs(u[0] - u2)) < 1e-8
    assert np.max(np.abs(yl[0] - yl2)) < 1e-8


def test_nominal_margins_are_one_of_the_posteriors_figures():
    # one computation for the nominal model and the draws: the nominal figure is the draws' method's
    # figure on the nominal model, and lies within the range over a posterior centred on it
    from mrftcli.tune.design import DesignOptions, tune
    from mrftcli.tune.margins import loop_margins

    model = LoopModel(0.08, 3.205, 0.2, 0.98)  # 40 ticks: long enough for the spectral responses
    post = Posterior.from_spread(model, 0.2, 0.01, 0.05, n=40, seed=2)
    res = tune(model, 200.0, posterior=post, options=DesignOptions(designs=("model-based",), kinds=("PD",)))
    d = res.get("model-based", "PD")
    allm = loop_margins(d.controller, [model] + post.models())
    assert d.margins == allm[0]
    for name in ("phase_margin_deg", "gain_margin", "Ms", "delay_margin_s"):
        draws = getattr(allm, name)[1:]
        assert draws.min() <= getattr(d.margins, name) <= draws.max(), name
    assert d.posterior["worst"]["phase_margin_deg"] == pytest.approx(np.min(allm.phase_margin_deg[1:][post.in_set()]))


@pytest.mark.parametrize("ctrl", [PD, PID])
def test_z_transform_route_matches_the_event_driven_simulation(ctrl):
    # responses() on the posterior-like set of short delays (0 to 10 ticks), setpoint and load steps, outputs
    # and commands, against simulate_step (the continuous plant event by event, sharing no discretisation);
    # and outputs() is responses() without the commands
    from mrftcli.tune.closed_loop import outputs, responses

    rng = np.random.default_rng(4)
    models = [LoopModel(0.0422, float(np.exp(rng.normal(0.2, 0.3))), float(rng.uniform(0.0, 0.05)), 30.0)
              for _ in range(5)]
    b = responses(models, ctrl, 4.0, load=0.2)
    for i, m in enumerate(models):
        _, ys, us, _ = simulate_step(m, ctrl, 4.0, substeps=1)
        _, yls, uls, _ = simulate_step(m, ctrl, 4.0, substeps=1, setpoint=0.0, load=0.2)
        for x, y in zip((ys, us, yls, uls), (b[1][i], b[2][i], b[3][i], b[4][i])):
            assert np.max(np.abs(x - y)) < 1e-9
    t, y, yl = outputs(models, ctrl, 4.0, load=0.2)
    assert np.array_equal(y, b[1]) and np.array_equal(yl, b[3])


def test_margins_json_round_trip_and_errors():
    from mrftcli.tune.margins import MARGINS_SCHEMA_VERSION, Margins

    for m in (margins(ROLL, PD), Margins(float("inf"), 40.0, 0.0, float("inf"), 3.0, float("nan"), False)):
        data = json.loads(json.dumps(m.to_json()))
        assert data["schema_version"] == MARGINS_SCHEMA_VERSION
        back = Margins.from_json(data)
        assert back.to_json() == m.to_json()
    with pytest.raises(InputError, match="schema_version"):
        Margins.from_json({**margins(ROLL, PD).to_json(), "schema_version": 99})
    with pytest.raises(InputError, match="malformed"):
        Margins.from_json({k: v for k, v in margins(ROLL, PD).to_json().items() if k != "Ms"})
    with pytest.raises(InputError, match="JSON object"):
        Margins.from_json([1, 2])
    with pytest.raises(InputError, match="stable"):
        Margins.from_json({**margins(ROLL, PD).to_json(), "stable": "yes"})


def test_design_options_are_checked_on_creation():
    from mrftcli.tune import DesignOptions

    assert DesignOptions(designs=["robust"], kinds=["PD"]).designs == ("robust",)
    for bad in ({"objective": "ise"}, {"ms_max": 1.0}, {"ms_max": float("nan")}, {"effort_max": 0.0},
                {"designs": ("lqr",)}, {"kinds": ("P",)}, {"pm_min_deg": 95.0}):
        with pytest.raises(InputError):
            DesignOptions(**bad)


def test_controller_json_is_the_generic_form_and_reads_back():
    # the one PID record: tune's designs, a cascade's inner loop and GAINS.json share its JSON
    from mrftcli.mrft.controller import Controller as C, RateFilter

    c = C(2.0, 0.5, 0.3, 0.01, 200.0)
    assert c.to_json() == {"Kp": 2.0, "Ki": 0.5, "Kd": 0.3, "Tf": 0.01, "rate_hz": 200.0}
    assert C.from_json({**c.to_json(), "form": "parallel"}) == c
    f = C(2.0, 0.0, 0.3, 0.0, 250.0, RateFilter(40.0, "IMU_GYRO_CUTOFF"))
    assert C.from_json(json.loads(json.dumps(f.to_json()))) == f
    with pytest.raises(InputError, match="'Kd'"):
        C.from_json({"Kp": 1.0, "Ki": 0.0, "Tf": 0.01, "rate_hz": 200.0}, "inner gains")
    with pytest.raises(InputError, match="must be an object"):
        C.from_json([1, 2], "inner gains")


def test_largest_holding_stops_after_a_number_of_halvings_or_at_a_ratio():
    # a threshold at 3.7 behind a descending scan: the bracket [2, 4] halved on its log; a stop at
    # ratio r = 2^(1.5 / 2^8) is exactly 8 halvings (what ArduPilot z passed before it gave halvings)
    from mrftcli.tune.margins import largest_holding

    calls: list[float] = []

    def ok(v: float) -> bool:
        calls.append(v)
        return v <= 3.7

    scan = [8.0, 4.0, 2.0, 1.0]
    g = largest_holding(ok, scan, halvings=8)
    assert len(calls) == 3 + 8 and 3.7 / 2 ** (1 / 2**8) <= g <= 3.7
    assert largest_holding(lambda v: v <= 3.7, scan, 2.0 ** (1.5 / 2**8)) == g
    assert largest_holding(ok, scan, halvings=0) == 2.0 and largest_holding(ok, [9.0, 5.0], halvings=3) is None
    with pytest.raises(ValueError, match="one of the two"):
        largest_holding(ok, scan)


def test_px4_velocity_path_survives_the_controller_json():
    # tune --json writes PX4 x/y's rate path with accel_s; read back it is that path (the velocity plus
    # its filtered derivative), not a 5 Hz Butterworth without the D term
    from mrftcli.mrft.controller import PX4VelocityPath, RateFilter
    from mrftcli.tune.stacks import px4_xy_controller

    c = px4_xy_controller({"MPC_XY_P": 0.95, "MPC_XY_VEL_P_ACC": 1.8, "MPC_XY_VEL_I_ACC": 0.0, "MPC_XY_VEL_D_ACC": 0.1,
                           "MPC_VELD_LP": 5.0}, 50.0, 0.49)
    back = Controller.from_json(json.loads(json.dumps(c.to_json())))
    assert isinstance(back.rate_filter, PX4VelocityPath) and back == c
    z = np.exp(1j * np.geomspace(0.1, 150.0, 50) / 50.0)
    assert np.array_equal(back.rate_filter.response(z, 50.0), c.rate_filter.response(z, 50.0))
    # B(z) = 1 + (D/P) alpha (z - 1) / (T (z - (1 - alpha))): at Nyquist (z = -1) above 1 by the D term
    al = (1 / 50) / (1 / 50 + 1 / (2 * np.pi * 5.0))
    nyq = 1 + (0.1 / 1.8) * al * (-2) / ((1 / 50) * (-1 - (1 - al)))
    assert back.rate_filter.response(np.array([-1.0 + 0j]), 50.0)[0] == pytest.approx(nyq, rel=1e-12)
    assert type(RateFilter.from_json({"cutoff_hz": 5.0, "parameter": "IMU_GYRO_CUTOFF"})) is RateFilter
    with pytest.raises(InputError, match="'accel_s' must be a finite number"):
        RateFilter.from_json({"cutoff_hz": 5.0, "accel_s": None})
    with pytest.raises(InputError, match="give --controller-rate HZ"):
        PX4VelocityPath(5.0, "MPC_VELD_LP", accel_s=0.05).response(np.array([1j]), 8.0)


def test_the_posterior_of_an_analysis_keeps_every_bootstrap_draw():
    """The analysis keeps the bootstrap's draws (rows 1..; row 0, the estimate on the data, is the point
    estimate), so tune's posterior takes them all: it dropped the first real draw as if it were row 0."""
    from pathlib import Path

    from mrftcli.analyze import AnalyzeOptions, analyze_path
    from mrftcli.mrft.model import soiptd_model
    from mrftcli.tune.analysis import posterior_from_analysis

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "design1_altitude.mcap"
    result = analyze_path(log, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=100, refine_waveform=False))
    post = posterior_from_analysis(result)
    Td = np.asarray(result.bootstrap["Td"], float)
    assert Td.size >= 100 and post.Td.size == Td.size
    assert np.array_equal(post.Td, Td) and np.array_equal(post.K, np.asarray(result.bootstrap["K"], float))
