"""Issue 38 items 2-4 from the CLI: slow, jittered process recordings; what one test determines; the
static gain from a biased relay's mean levels. The recordings come from tests/thermal_sim.py (shares
no code with mrftcli); short (8-10 cycles) so the file runs in seconds."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from mrftcli.analyze.static_gain import cycle_means, static_gain
from mrftcli.io.logtypes import FlightLog, Signal
from mrftcli.mrft.determined import determined_combination

sys.path.insert(0, str(Path(__file__).parent))
from cli_helpers import run_cli  # noqa: E402
from process_sim import write_csv  # noqa: E402
from thermal_sim import RelayWindow, simulate_relay  # noqa: E402

#: a heater in an insulated box: 32 degC per unit duty, lags of 10 min and 1 min, a 15 s delay
HEATER = {"K": 32.0, "T1": 600.0, "T2": 60.0, "tau": 15.0}
AMBIENT = 20.0
TOPICS = ("--command-topic", "u_relay", "--output-topic", "y_output")


@pytest.fixture(scope="module")
def heater_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 0/1 heater, 2 degC hysteresis band (+-1), logged every 1-7 s by a recorder, ~5 min cycles."""
    t, u, y = simulate_relay("sopdt", HEATER, [RelayWindow(1.0, 0.0, 1.0, 3000.0)], setpoint=AMBIENT + 18.0,
                             baseline=AMBIENT, sample_s=(1.0, 7.0), noise_std=0.03, seed=38, decide_s=0.5)
    path = tmp_path_factory.mktemp("heater") / "heater.csv"
    write_csv(str(path), t, u, y)
    return path


def _analyze(capsys: pytest.CaptureFixture[str], log: Path, *extra: str) -> tuple[int, str, str, dict]:
    code, out, err = run_cli(capsys, "analyze", str(log), *TOPICS, "--model", "sopdt", *extra, "--json", "-")
    return code, out, err, (json.loads(out) if code == 0 else {})


def test_slow_jittered_heater_is_analysed_not_refused(capsys, heater_log):
    # item 2: 0.25 Hz with jitter: a process model takes it; the eq. (2) route still refuses the clock
    code, out, err, data = _analyze(capsys, heater_log)
    assert code == 0, err
    assert data["tests"] and data["tests"][0]["relay"]["kind"] == "hysteresis"
    period = 1.0 / data["tests"][0]["frequency_hz"]
    assert 150 < period < 900  # minutes-long cycles, measured as such
    code, _, err = run_cli(capsys, "analyze", str(heater_log), *TOPICS, "--tp", "0.04")
    assert code != 0 and "flight stack" in err and "--time-unit" in err


def test_one_setting_names_undetermined_and_the_determined_combination(capsys, heater_log):
    # item 3: one relay setting: K and T1 trade off along the slope it sees; K/T1 and the phase are pinned
    code, out, err, data = _analyze(capsys, heater_log)
    assert code == 0, err
    params = data["parameters"]
    assert not params["K"]["determined"] and not params["T1"]["determined"]
    for name in ("K", "T1"):  # an undetermined parameter's interval still holds the truth
        assert params[name]["ci95_low"] <= HEATER[name] <= params[name]["ci95_high"]
    for name in ("T2", "tau"):
        p = params[name]
        assert not p["determined"] or p["ci95_low"] <= HEATER[name] <= p["ci95_high"]
    combo = data["identification"]["determined_combination"]
    assert combo["exponents"] == {"K": 1.0, "T1": -1.0}
    assert combo["ci95_low"] <= HEATER["K"] / HEATER["T1"] <= combo["ci95_high"]
    text = run_cli(capsys, "analyze", str(heater_log), *TOPICS, "--model", "sopdt")[1]
    assert "NOT DETERMINED" in text and "determined: K/T1 = " in text
    assert "mrft-ident plan" in text and "--baseline Y0" in text  # the next test, and what K needs


def test_baseline_measures_the_static_gain(capsys, heater_log):
    # item 4: mean output minus the ambient over the mean duty is K: with it, K and T1 are determined
    code, out, err, data = _analyze(capsys, heater_log, "--baseline", f"{AMBIENT}:0.1")
    assert code == 0, err
    sg = data["static_gain"]
    assert abs(sg["value"] / HEATER["K"] - 1) < 0.05 and sg["baseline_std"] == 0.1
    for name in ("K", "T1"):
        p = data["parameters"][name]
        assert p["determined"] and abs(p["value"] / HEATER[name] - 1) < 0.1
        assert p["ci95_low"] <= HEATER[name] <= p["ci95_high"]


def test_baseline_topic_measures_the_static_gain(capsys, heater_log, tmp_path):
    # the ambient logged beside the heater (noisy, and at its own times): each cycle's own mean of it
    data = np.loadtxt(heater_log, delimiter=",", skiprows=1)
    rng = np.random.default_rng(5)
    ambient = AMBIENT + 0.1 * rng.standard_normal(len(data))
    path = tmp_path / "heater_ambient.csv"
    np.savetxt(path, np.column_stack([data, ambient]), delimiter=",", header="time,u_relay,y_output,ambient",
               comments="", fmt="%.10g")
    code, out, err, result = _analyze(capsys, path, "--baseline-topic", "ambient")
    assert code == 0, err
    assert abs(result["static_gain"]["baseline"] - AMBIENT) < 0.05
    assert abs(result["parameters"]["K"]["value"] / HEATER["K"] - 1) < 0.05 and result["parameters"]["K"]["determined"]
    code, _, err = run_cli(capsys, "analyze", str(path), *TOPICS, "--model", "sopdt", "--baseline", "20",
                           "--baseline-topic", "ambient")
    assert code == 2 and "once" in err
    code, _, err = run_cli(capsys, "analyze", str(path), *TOPICS, "--model", "sopdt", "--baseline-topic", "nope")
    assert code != 0 and "nope" in err and "Traceback" not in err


def test_baseline_refusals(capsys, heater_log, tmp_path):
    code, _, err = run_cli(capsys, "analyze", str(heater_log), *TOPICS, "--model", "foipdt", "--baseline", "20")
    assert code == 2 and "integrates" in err and "Traceback" not in err
    code, _, err = run_cli(capsys, "analyze", str(heater_log), *TOPICS, "--tp", "0.04", "--baseline", "20")
    assert code == 2 and "take a process model" in err
    code, _, err = run_cli(capsys, "analyze", str(heater_log), *TOPICS, "--model", "sopdt", "--baseline", "warm")
    assert code == 2 and "--baseline" in err
    # a relay symmetric about the command's zero: its mean levels say nothing of K
    t, u, y = simulate_relay("fopdt", {"K": 2.0, "T": 300.0, "tau": 40.0}, [RelayWindow(1.0, -1.0, 0.05, 2500.0)],
                             setpoint=0.0, sample_s=(2.0, 4.0), noise_std=0.01, seed=3, decide_s=0.5)
    sym = tmp_path / "sym.csv"
    write_csv(str(sym), t, u, y)
    code, _, err = run_cli(capsys, "analyze", str(sym), *TOPICS, "--model", "fopdt", "--baseline", "0")
    assert code == 2 and "symmetric" in err


def test_static_gain_closed_form():
    # a periodic cycle whose mean levels are known in closed form: duty 0.3 at level 2, output 5 + 3 u
    P, n = 100.0, 6
    t = np.arange(0.0, n * P + 0.5, 0.5)
    u = np.where((t % P) < 0.3 * P, 2.0, 0.0)
    y = 5.0 + 3.0 * u + np.sin(2 * math.pi * t / P)  # the sine averages out over whole cycles
    from mrftcli.segment.records import RelayCycle

    cycles = tuple(RelayCycle(t_start=k * P, t_switch=k * P + 30, t_end=(k + 1) * P, period=P,
                              half_period_high=30, half_period_low=70, amplitude=1, centre=0, y_max=1, y_min=-1,
                              t_max=0, t_min=0, y_switch_down=0, y_switch_up=0, beta_down=0, beta_up=0,
                              beta_effective=0, stable=True) for k in range(n))
    test = type("T", (), {"cycles": cycles})()
    flight = FlightLog(path="x", loop="altitude", command=Signal(t, u), output=Signal(t, y))
    mu, my = cycle_means(flight, test)  # type: ignore[arg-type]
    assert np.allclose(mu, 0.6, atol=2e-3) and np.allclose(my, 6.8, atol=1e-2)
    sg = static_gain(flight, [test], baseline=5.0, baseline_std=0.06)  # type: ignore[list-item]
    assert sg.value == pytest.approx(3.0, rel=5e-3)
    assert sg.std == pytest.approx(0.06 / 0.6, rel=0.05)  # the baseline's std over the mean command


def test_combination_from_information_closed_form():
    # G ~ K/(j w T) at w >> 1/T: the residuals see ln K - ln T only; the tau column is determined
    J = np.array([[1.0, -1.0, 0.0], [0.0, 0.0, 1.0], [1.0, -1.0, 0.1]]) * 100
    z = np.log([30.0, 1500.0, 10.0])
    c = determined_combination(["K", "T1", "tau"], z, J.T @ J, ["K", "T1"], {"K": "degC", "T1": "s"})
    assert c is not None and c.name == "K/T1" and c.value == pytest.approx(0.02)
    assert c.ci95_low < 0.02 < c.ci95_high and c.ci95_high / c.ci95_low < 1.1
    assert determined_combination(["K", "T1"], z[:2], np.eye(2) * 1e-4, ["K", "T1"], {}) is None  # nothing seen


def test_simulator_at_a_sample_every_5_s_and_the_controller_rate(capsys, tmp_path):
    # item 2 on mrft-ident's own simulator (the oracle of simulate --model): a 15-min lag logged at 0.2 Hz,
    # each logged sample a decision of the relay; --controller-rate at the log's rate puts each switch on
    # its sample (mid-way between samples would make tau half a sample long)
    out = tmp_path / "slow.mcap"
    code, _, err = run_cli(capsys, "simulate", "--model", "fopdt", "--param", "K=2", "--param", "T=900",
                           "--param", "tau=120", "--controller-rate", "0.2", "--test", "0:1", "--noise", "0.005",
                           "--out", str(out))
    assert code == 0, err
    code, text, err = run_cli(capsys, "analyze", str(out), "--model", "fopdt", "--controller-rate", "0.2", "--json", "-")
    assert code == 0, err
    params = json.loads(text)["parameters"]
    for name, true in (("K", 2.0), ("T", 900.0), ("tau", 120.0)):
        assert params[name]["ci95_low"] <= true <= params[name]["ci95_high"], (name, params[name])
    assert abs(params["tau"]["value"] - 120.0) < 2.5  # within half a sample
