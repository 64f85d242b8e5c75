"""tune on process plants: the one driver (mrftcli/tune/design.py: tune) by the grid strategy (tune/grid.py).

The oracle of the margins is python-control on the plant's pulse transfer function written here from
its closed form (the modified z-transform of K e^{-tau s} / (T s + 1) and K e^{-tau s} / s under a
zero-order hold, the delay d T + eps), sharing no code with the library's discretisation.
"""

from __future__ import annotations

import json
import math

import control
import numpy as np
import pytest
from cli_helpers import run_main

from mrftcli.analyze.record import AnalysisResult, TestSummary
from mrftcli.errors import InputError
from mrftcli.mrft.families import FOPDT, IPDT
from mrftcli.mrft.identify_lti import LtiIdentification
from mrftcli.mrft.parameter import ParameterEstimate
from mrftcli.mrft.relays import RelayLaw
from mrftcli.tune.design import DesignOptions, TuneResult, tune
from mrftcli.tune.grid import model_draws
from mrftcli.tune.margins import plant_response


def _fopdt_z(K: float, Tc: float, tau: float, T: float) -> control.TransferFunction:
    """K [(1 - b) z + (b - a)] / (z^{d+1} (z - a)), a = e^{-T/Tc}, b = e^{-(T - eps)/Tc}."""
    d = int(math.floor(tau / T + 1e-12))
    eps = tau - d * T
    a, b = math.exp(-T / Tc), math.exp(-(T - eps) / Tc)
    den = np.polymul(np.r_[1.0, np.zeros(d + 1)], [1.0, -a])
    return control.tf([K * (1 - b), K * (b - a)], den, T)


def _ipdt_z(K: float, tau: float, T: float) -> control.TransferFunction:
    """K [(T - eps) z + eps] / (z^{d+1} (z - 1))."""
    d = int(math.floor(tau / T + 1e-12))
    eps = tau - d * T
    return control.tf([K * (T - eps), K * eps], np.polymul(np.r_[1.0, np.zeros(d + 1)], [1.0, -1.0]), T)


def _controller_z(c, T: float) -> control.TransferFunction:
    z = control.tf([1.0, 0.0], [1.0], T)
    C = c.Kp + c.Ki * T * z / (z - 1) if c.Ki > 0 else control.tf([c.Kp], [1.0], T)
    if c.Kd > 0:
        C = C + c.Kd * (z - 1) / ((c.Tf + T) * z - c.Tf)
    return C


def _check_against_control(design, G: control.TransferFunction, sign: float = 1.0) -> None:
    L = _controller_z(design.controller, G.dt) * G * sign
    gm, pm, sm, _, _, _ = control.stability_margins(L)
    # the margins refined on the exact response (eq. (2)'s one computation), not read off a grid: the grid's
    # figures were the lesser of the points either side of the crossing (a FOPDT PI's PM 52.36 for 52.42 deg)
    assert design.margins.phase_margin_deg == pytest.approx(pm, abs=1e-3)
    assert design.margins.gain_margin == pytest.approx(gm, rel=1e-3)
    assert design.margins.Ms == pytest.approx(1.0 / sm, rel=0.01)  # python-control's sm: the min over its grid
    poles = control.feedback(L, 1).poles()
    assert np.max(np.abs(poles)) < 1.0 and design.margins.stable


def test_fopdt_fractional_delay_margins_match_python_control():
    model = FOPDT(K=2.0, T=1.0, tau=0.33)  # 6.6 ticks at 20 Hz: the fraction matters
    w = np.geomspace(0.05, 60.0, 50)
    G = _fopdt_z(2.0, 1.0, 0.33, 0.05)
    assert np.allclose(plant_response([model], 20.0, w)[0], G(np.exp(1j * w * 0.05)), rtol=1e-9, atol=1e-12)
    res = tune(model, 20.0, options=DesignOptions(kinds=("PID",)))
    (design,) = res.designs
    assert design.kind == "PID" and design.controller.Ki > 0 and design.controller.Kd > 0
    _check_against_control(design, G)
    assert design.margins.Ms <= 1.6 + 1e-9 and design.margins.phase_margin_deg >= 45.0 - 1e-9


@pytest.mark.filterwarnings("ignore:invalid value encountered in subtract:RuntimeWarning")  # python-control's search
def test_reverse_acting_integrating_plant_gets_pd_and_pi():
    model = IPDT(K=-0.5, tau=0.21)
    res = tune(model, 50.0, options=DesignOptions(kinds=("PD", "PI")))
    assert res.reverse_acting and any("reverse acting" in n for n in res.notes)
    G = _ipdt_z(-0.5, 0.21, 0.02)
    for kind in ("PD", "PI"):
        design = res.get("model-based", kind)
        _check_against_control(design, G, sign=-1.0)  # the gains act on -e


def test_robust_design_holds_on_every_draw_and_round_trips():
    model = FOPDT(K=2.0, T=1.0, tau=0.3)
    draws = [model.with_parameters(T=1.3, tau=0.36), model.with_parameters(K=2.4, T=0.8)]
    res = tune(model, 20.0, posterior=draws, options=DesignOptions(kinds=("PI",)))
    robust = res.get("robust", "PI")
    worst = robust.posterior["worst"]
    assert worst["Ms"] <= 1.6 + 1e-9 and worst["stable"]
    for m, G in zip(draws, (_fopdt_z(2.0, 1.3, 0.36, 0.05), _fopdt_z(2.4, 0.8, 0.3, 0.05))):
        L = _controller_z(robust.controller, 0.05) * G
        assert 1.0 / control.stability_margins(L)[2] <= 1.6 * 1.01
    back = TuneResult.from_json(json.loads(json.dumps(res.to_json())))
    assert back.to_json() == res.to_json() and back.model == model and back.get("robust", "PI").kind == "PI"
    with pytest.raises(InputError, match="schema_version"):
        TuneResult.from_json({**res.to_json(), "schema_version": 99})
    with pytest.raises(InputError):
        TuneResult.from_json({"schema_version": 2, "kind": "cascade"})
    with pytest.raises(InputError, match="ms-max"):
        DesignOptions(ms_max=0.9)
    for bad in ({"objective": "itae"}, {"designs": ("mrft-rule",)}, {"effort_max": 2.0}):
        with pytest.raises(InputError):  # eq. (2)'s options: refused on a process plant, never ignored
            tune(model, 20.0, options=DesignOptions(**bad))


def test_a_robust_design_no_gains_hold_is_said_not_dropped():
    # draws 1e5 x and 1e-3 x the nominal gain: no PI keeps Ms <= 1.6 on all three (the largest gain needs a Kp
    # below the grid's); the table lost its robust row without a word and the export fell back silently
    model = FOPDT(K=2.0, T=1.0, tau=0.3)
    draws = [model.with_parameters(K=2e5), model.with_parameters(K=2e-3)]
    res = tune(model, 20.0, posterior=draws, options=DesignOptions(kinds=("PI",)))
    assert [(d.name, d.kind) for d in res.designs] == [("model-based", "PI")]
    assert any(n.startswith("no robust PI: ") and "model-based design is the one exported" in n for n in res.notes)
    held = tune(model, 20.0, posterior=[model.with_parameters(T=1.3), model.with_parameters(K=2.4)],
                options=DesignOptions(kinds=("PI",)))
    assert held.get("robust", "PI") is not None and not any(n.startswith("no robust") for n in held.notes)


def test_cli_exports_the_model_based_design_of_a_kind_that_lost_its_robust_one(tmp_path):
    # an integrator whose delay is known to a factor e^2 either way: no PI holds on every draw, PID and PD do.
    # The note says the model-based PI is exported; the CLI picked "robust" because another kind kept one and
    # then refused: "no robust PI design for this plant"
    model = IPDT(K=2.0, tau=0.3)
    est = (ParameterEstimate(2.0, 0.1, 1.8, 2.2, "output / (command s)", name="K"),
           ParameterEstimate(0.3, 0.3, 0.3 * math.exp(-2.0), 0.3 * math.exp(2.0), "s", name="tau"))
    test = TestSummary(0, 2.0, 20.0, RelayLaw("ideal", 1.0, -1.0), 0.83, 0.55, 14, 15, 20.0, 0.0)
    src = tmp_path / "r.json"
    src.write_text(json.dumps(AnalysisResult("p.csv", "level", model, (test,), LtiIdentification(model, est, (), None),
                                             {e.name: e for e in est}).to_json()))
    out = run_main("tune", str(src), "--kind", "PI", "--json", "-")
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    res = TuneResult.from_json(data)
    assert {d.kind for d in res.designs if d.name == "robust"} == {"PID", "PD"}
    assert any(n.startswith("no robust PI: ") and "model-based design is the one exported" in n for n in res.notes)
    assert (data["export"]["design"], data["export"]["kind"]) == ("model-based", "PI")
    assert data["export"]["generic"] == res.get("model-based", "PI").controller.to_dict()


def _estimates(std_T: float, determined: bool = True, hi: float = 1.2) -> list[ParameterEstimate]:
    return [ParameterEstimate(2.0, 0.1, 1.8, 2.2, "output / command", name="K"),
            ParameterEstimate(1.0, std_T, 0.8, hi, "s", determined, name="T"),
            ParameterEstimate(0.3, 0.01, 0.28, 0.32, "s", name="tau")]


def test_draws_follow_the_intervals_and_refuse_an_open_one():
    model = FOPDT(K=2.0, T=1.0, tau=0.3)
    draws, notes = model_draws(model, _estimates(0.1), 400, seed=1)
    T = np.array([m.parameters["T"].value for m in draws])
    assert np.std(np.log(T)) == pytest.approx(0.1, rel=0.15) and not notes
    draws, notes = model_draws(model, _estimates(math.nan, determined=False), 50)
    assert notes and all(0.8 <= m.parameters["T"].value <= 1.2 for m in draws)
    with pytest.raises(InputError, match="analyze --param T=VALUE"):
        model_draws(model, _estimates(math.nan, determined=False, hi=math.inf), 5)


def _result_json(path, rate_hz: float = 20.0, std_T: float = 0.05) -> None:
    model = FOPDT(K=2.0, T=1.0, tau=0.3)
    relay = RelayLaw("ideal", 1.0, -1.0)
    test = TestSummary(0, 2.0, 20.0, relay, 0.83, 0.55, 14, 15, rate_hz, 0.0)
    estimates = _estimates(std_T) if std_T else [ParameterEstimate(e.value, 0.0, e.value, e.value, e.unit, name=e.name)
                                                 for e in _estimates(0.0)]
    ident = LtiIdentification(model, tuple(estimates), (), None)
    path.write_text(json.dumps(AnalysisResult("p.csv", "level", model, (test,), ident,
                                               {e.name: e for e in estimates}).to_json()))


def test_cli_tune_process_result(tmp_path):
    src = tmp_path / "r.json"
    _result_json(src, std_T=0.0)  # no spread: the model-based design only (the robust one is tested above)
    out = run_main("tune", str(src), "--kind", "PI", "--json", "-")
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    res = TuneResult.from_json(data)
    assert res.rate_hz == 20.0 and any("analysis' tests' rate" in n for n in res.notes)
    assert data["export"]["design"] == "model-based" and data["export"]["kind"] == "PI"
    assert any("no robust design" in n for n in res.notes)
    _check_against_control(res.get("model-based", "PI"), _fopdt_z(2.0, 1.0, 0.3, 0.05))


@pytest.mark.parametrize("extra, message", [
    (["--export", "px4"], "UAV flight stack"),
    (["--design", "mrft-rule"], "mrft-rule"),
    (["--tp", "0.05"], "--tp: not for a process plant"),
    (["--export", "generic", "--json", "-"], "both go to stdout"),
])
def test_cli_tune_process_refusals_are_one_line(tmp_path, capsys, extra, message):
    from mrftcli.cli.main import main

    src = tmp_path / "r.json"
    _result_json(src)
    with pytest.raises(SystemExit) as exit_:
        main(["tune", str(src), *extra])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.strip().count("\n") == 0 and message in err


def test_cli_tune_from_parameters_needs_every_one_and_a_rate(capsys):
    from mrftcli.cli.main import main

    for argv, message in ((["--param", "K=2", "--param", "T=1"], "missing tau"),
                          (["--param", "K=2", "--param", "T=1", "--param", "tau=0.3"], "--controller-rate"),
                          (["--kind", "PI", "--td", "1", "--tau", "0.03", "--k", "3", "--tp", "0.04", "--loop", "roll"],
                           "--kind PI is for process plants")):
        with pytest.raises(SystemExit) as exit_:
            main(["tune", *(["--model", "fopdt"] if "--td" not in argv else []), *argv])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and message in err, err
