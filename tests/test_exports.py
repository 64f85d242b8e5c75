"""``tune --export``: the stacks' parameter table, every sample log's exports against it, the margins of
the loop the exported values give (recomputed here from the values alone, with scipy's Butterworth),
the stack's filter in the sampled loop, the files the stacks load, versioned records."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from mrftcli.errors import InputError
from mrftcli.mrft.cascade import STANDARD_GRAVITY
from mrftcli.mrft.model import LoopModel
from mrftcli.tune.closed_loop import Controller, RateFilter, responses, simulate_step
from mrftcli.tune.design import Design, DesignOptions, TuneResult, Posterior, tune
from mrftcli.tune.margins import plant_system
from mrftcli.tune.stack_params import STACK_PARAMS, check_ranges, param
from mrftcli.tune.stacks import StackExport, check_exportable, export_design, stack_setting

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"
HOVER = 0.5


def _sample_models() -> list[tuple[str, LoopModel, float]]:
    """(loop, truth model, controller rate) of every sample log, each distinct one once (analysing every
    log takes minutes; benchmarks/bench_exports.py exports the analysed logs)."""
    seen = {}
    for f in sorted(SAMPLES.glob("*.truth.json")):
        d = json.loads(f.read_text())
        key = (d["loop"], d["Tp"], d["Td"], d["tau"], d["K"], d.get("rate_hz", 200.0))
        seen.setdefault(key, f.name.split(".")[0])
    return [(k[0], LoopModel(*k[1:5]), float(k[5])) for k in seen]


MODELS = _sample_models()


#: AC_PosControl.cpp's constructor sets these to 0 (off / no integral) below their own @Range's minimum
DEFAULTS_OUTSIDE_RANGE = ("PSC_VELZ_I", "PSC_ACCZ_FLTT", "PSC_ACCZ_FLTD")


# --- the vendored table ---------------------------------------------------------------------------

def test_table_rows_are_sourced_and_ordered():
    for p in STACK_PARAMS:
        assert p.minimum <= p.maximum, p.name
        assert p.source and ("/" in p.source), p.name  # repository and file
        if math.isfinite(p.default) and p.name not in DEFAULTS_OUTSIDE_RANGE:
            assert p.contains(p.default), p.name  # the stack's default is within its own range
    for name in DEFAULTS_OUTSIDE_RANGE:
        assert param("ardupilot", name).default == 0.0 and not param("ardupilot", name).contains(0.0)
    # the figures, as the sources give them
    assert (param("px4", "MC_ROLLRATE_P").minimum, param("px4", "MC_ROLLRATE_P").maximum) == (0.01, 0.5)
    assert (param("px4", "MPC_Z_P").minimum, param("px4", "MPC_Z_P").maximum) == (0.1, 1.5)
    assert param("px4", "MPC_Z_VEL_I_ACC").minimum == 0.2
    assert [v.param.name for v in check_ranges("px4", {"MC_ROLLRATE_P": 0.628, "MC_ROLL_P": 3.0})] == ["MC_ROLLRATE_P"]
    assert [v.param.name for v in check_ranges("px4", {"MC_ROLLRATE_P": 0.0082})] == ["MC_ROLLRATE_P"]


def test_rate_filter_is_scipys_butterworth():
    for fc, fs in ((40.0, 250.0), (20.0, 400.0), (50.0, 200.0)):
        b, a = signal.butter(2, fc, fs=fs)
        mb, ma = RateFilter(fc).coefficients(fs)
        np.testing.assert_allclose(mb, b, rtol=1e-12)
        np.testing.assert_allclose(ma, a, rtol=1e-12, atol=1e-15)
    assert not RateFilter(0.0).active(250.0) and not RateFilter(130.0).active(250.0)


def test_filtered_loop_steps_match_the_event_driven_simulation():
    m = LoopModel(0.0422, 1.301, 0.0297, 30.0)
    c = Controller(0.3, 0.0, 0.11, 0.0, 250.0, RateFilter(20.0, "IMU_GYRO_CUTOFF"))
    _, y, _, _, _ = responses([m], c, 3.0)
    _, ys, _, _ = simulate_step(m, c, 3.0)
    n = min(y.shape[1], ys.size)
    assert np.max(np.abs(y[0, :n] - ys[:n])) < 1e-8


# --- independent margins from the exported values alone -------------------------------------------

def _loop_from_params(stack: str, loop: str, p: dict[str, float], model: LoopModel, rate: float,
                      cutoff: float | None, w: np.ndarray) -> np.ndarray:
    """L(e^{jwT}) from the stack's parameter values: the cascade written out here, scipy's Butterworth
    on the rate (backward difference), python-control's sampled plant."""
    T = 1.0 / rate
    z = np.exp(1j * w * T)
    if cutoff and 0 < cutoff < rate / 2:
        b, a = signal.butter(2, cutoff, fs=rate)
        B = np.polyval(b[::-1], 1 / z) / np.polyval(a[::-1], 1 / z)
    else:
        B = np.ones_like(z)
    rate_meas = (z - 1) / (T * z) * B  # the measured rate of y, per unit y
    integ = T * z / (z - 1)
    if stack == "px4" and loop == "altitude":
        s = HOVER / STANDARD_GRAVITY
        pz, pv, iv = p["MPC_Z_P"], p["MPC_Z_VEL_P_ACC"], p["MPC_Z_VEL_I_ACC"]
        vel_err = pz + rate_meas  # velocity setpoint from -y, minus the velocity
        C = s * (pv * vel_err + iv * integ * vel_err)
    elif stack in ("px4", "ardupilot"):
        ax = loop.upper() if stack == "px4" else {"roll": "RLL", "pitch": "PIT"}[loop]
        if stack == "px4":
            pa, pr, ir = p[f"MC_{ax}_P"], p[f"MC_{ax}RATE_P"] * p[f"MC_{ax}RATE_K"], p[f"MC_{ax}RATE_I"]
        else:
            pa, pr, ir = p[f"ATC_ANG_{ax}_P"], p[f"ATC_RAT_{ax}_P"], p[f"ATC_RAT_{ax}_I"]
        rate_err = pa + rate_meas
        C = pr * rate_err + ir * integ * rate_err
    else:  # HEAR: u = kp e + ki int e + kd PV_DOT with PV_DOT = -(filtered rate)
        C = p["kp"] + p["ki"] * integ + p["kd"] * rate_meas
    sys = plant_system(model, rate)
    A, Bm, Cm = (np.asarray(x) for x in (sys.A, sys.B, sys.C))
    G = np.array([(Cm @ np.linalg.solve(zk * np.eye(A.shape[0]) - A, Bm))[0, 0] for zk in z])
    return C * G


def _ms_gm(L: np.ndarray) -> tuple[float, float]:
    ms = float(np.max(1.0 / np.abs(1.0 + L)))
    k = np.nonzero((np.sign(L.imag[:-1]) != np.sign(L.imag[1:])) & (L.real[:-1] < 0))[0]
    if not k.size:
        return ms, math.inf
    f = L.imag[k] / (L.imag[k] - L.imag[k + 1])  # linear interpolation to Im L = 0
    gm = 1.0 / np.abs(L[k] + f * (L[k + 1] - L[k]))
    return ms, float(gm[np.argmin(np.abs(np.log(gm)))])


#: _zoh_output's discretisations and state responses, per (model, delay, rate) and frequency grid
_ZOH_CACHE: dict = {}


def _zoh_output(model: LoopModel, C: np.ndarray, delay: float, rate: float, z: np.ndarray) -> np.ndarray:
    """The sampled transfer from the held throttle to the output C x delayed by ``delay`` [s] (whole ticks in
    z^-d, the fraction in the hold), from scipy's expm of eq. (2)'s states [z, v, thrust] written out here."""
    T = 1.0 / rate
    _cache = _ZOH_CACHE
    key = (model, round(delay, 12), rate)
    if key not in _cache:
        from scipy.linalg import expm

        A = np.array([[0.0, 1.0, 0.0], [0.0, -1.0 / model.Td, model.K], [0.0, 0.0, -1.0 / model.Tp]])
        B = np.array([0.0, 0.0, 1.0 / model.Tp])

        def step(t: float) -> tuple[np.ndarray, np.ndarray]:
            E = expm(np.block([[A, B[:, None]], [np.zeros((1, 4))]]) * t)
            return E[:3, :3], E[:3, 3]

        d = int(math.floor(delay / T + 1e-12))
        eps = max(delay - d * T, 0.0)
        (Phi, _), (E_rest, G0), (_, G_eps) = step(T), step(T - eps), step(eps)
        _cache[key] = (Phi, G0, E_rest @ G_eps, d)
    Phi, G0, G1, d = _cache[key]
    zkey = (key, z.size, complex(z[0]), complex(z[-1]))
    if zkey not in _cache:  # the state's response, shared by the three outputs
        rhs = G0[None, :] + G1[None, :] / z[:, None]
        _cache[zkey] = np.linalg.solve(z[:, None, None] * np.eye(3) - Phi, rhs[..., None])[..., 0] * z[:, None] ** (-d)
    return _cache[zkey] @ C


def _ardupilot_z_worst(p: dict[str, float], model: LoopModel, rate: float, w: np.ndarray) -> tuple[float, float]:
    """(largest Ms, smallest GM) over the splits of tau of ArduPilot's z loops written from the values alone
    (AC_PID's first-order filters, scipy's Butterworth for INS_ACCEL_FILTER, the motors' 2 Hz throttle filter)."""
    T = 1.0 / rate
    z = np.exp(1j * w * T)

    def lp(hz: float) -> np.ndarray:
        al = T / (T + 1.0 / (2 * math.pi * hz)) if hz > 0 else 1.0
        return al / (1 - (1 - al) / z)

    b, a = signal.butter(2, p["INS_ACCEL_FILTER"], fs=rate)
    F_acc = np.polyval(b[::-1], 1 / z) / np.polyval(a[::-1], 1 / z)
    integ = T * z / (z - 1)
    Cv = lp(p["PSC_VELZ_FLTE"]) * (p["PSC_VELZ_P"] + p["PSC_VELZ_I"] * integ)
    Ca = lp(p["PSC_ACCZ_FLTE"]) * (p["PSC_ACCZ_P"] + p["PSC_ACCZ_I"] * integ)
    ms, gm = 0.0, math.inf
    for i in range(5):  # the actuator's delay in quarters of tau; each measurement's at 0, half, all of the rest
        ta = model.tau * i / 4
        rest = model.tau - ta
        Ga = _zoh_output(model, np.array([0.0, -1.0 / model.Td, model.K]), ta, rate, z)
        for fv in ((0.0, 0.5, 1.0) if rest > 0 else (0.0,)):
            Gv = _zoh_output(model, np.array([0.0, 1.0, 0.0]), ta + fv * rest, rate, z)
            for fz in ((0.0, 0.5, 1.0) if rest > 0 else (0.0,)):
                Gz = _zoh_output(model, np.array([1.0, 0.0, 0.0]), ta + fz * rest, rate, z)
                L = 0.1 * lp(2.0) * Ca * (F_acc * Ga + Cv * (Gv + p["PSC_POSZ_P"] * Gz))
                m_i, g_i = _ms_gm(L)
                ms, gm = max(ms, m_i), min(gm, g_i)
    return ms, gm


def _stack_loops() -> list[tuple[str, str, LoopModel, float]]:
    """Every sample model to every stack that has its loop (ArduPilot altitude: AC_PosControl's z cascade),
    each design problem once: a stack whose loop runs at its own rate whatever the log's (ArduPilot's 400 Hz,
    PX4's attitude at IMU_INTEG_RATE, HEAR's) would design and export the same controller again."""
    out, seen = [], set()
    for loop, m, rate in MODELS:
        for stack in ("px4", "ardupilot", "hear"):
            if stack in ("ardupilot", "px4") and loop not in ("roll", "pitch", "altitude"):
                continue
            st = stack_setting(stack, loop, None, rate, None)
            if (key := (stack, loop, m, st.rate_hz, st.rate_filter)) not in seen:
                seen.add(key)
                out.append((stack, loop, m, rate))
    return out


STACK_LOOPS = _stack_loops()


@pytest.mark.parametrize("stack,loop,model,rate", STACK_LOOPS,
                         ids=[f"{s}-{lp}-Td{m.Td}" for s, lp, m, _ in STACK_LOOPS])
def test_every_sample_export_is_in_range_with_its_margins(stack, loop, model, rate):
    """Every design of every sample model, exported (clamped where the stack's range says so): every name
    is a vendored parameter of the stack, every value in its range, and the margins the export states are
    those of the loop its values give, recomputed here from the values alone."""
    st = stack_setting(stack, loop, None, rate, None)
    res = tune(model, st.rate_hz, loop=loop, options=DesignOptions(kinds=("PD",), designs=("mrft-rule", "model-based"),
                                                                 rate_filter=st.rate_filter))
    cutoff = st.rate_filter.cutoff_hz if st.rate_filter is not None else None
    w = np.geomspace(1e-3, 0.999, 3000) * math.pi * st.rate_hz
    if stack == "ardupilot" and loop == "altitude":  # the cascade's design searches: its model-based PD only
        d = res.get("model-based", "PD")
        e = export_design(stack, d.controller, model, loop, d.name, clamp=True, hover_thrust=HOVER, version="4.6")
        rows = {p.name: p for p in STACK_PARAMS if p.stack == stack}
        assert set(e.params) <= set(rows) and not check_ranges(stack, e.params), e.params
        assert e.prearm and all(r["passed"] for r in e.prearm)
        assert e.assumptions and "every split" in e.assumptions[0]
        ms, gm = _ardupilot_z_worst(e.params, model, st.rate_hz, np.geomspace(1e-3, 0.999, 1200) * math.pi * st.rate_hz)
        assert e.margins.Ms == pytest.approx(ms, rel=5e-3) and e.margins.gain_margin == pytest.approx(gm, rel=1e-2)
        return
    for d in res.designs:
        try:
            export_design(stack, d.controller, model, loop, d.name, hover_thrust=HOVER)
        except InputError as err:  # refused: it names a parameter outside its range
            assert ("is above the maximum" in str(err) or "is below the minimum" in str(err)
                    or "keeps Ms" in str(err)), err
        e = export_design(stack, d.controller, model, loop, d.name, clamp=True, hover_thrust=HOVER)
        if stack != "hear":
            rows = {p.name: p for p in STACK_PARAMS if p.stack == stack}
            assert set(e.params) <= set(rows), set(e.params) - set(rows)
            assert not check_ranges(stack, e.params)
        # HEAR z: gains converted to HEAR's acceleration command (x K) fly a plant of K = 1 (issue 37)
        flown = LoopModel(model.Tp, model.Td, model.tau, 1.0) if e.assumptions and stack == "hear" else model
        ms, gm = _ms_gm(_loop_from_params(stack, loop, e.params, flown, st.rate_hz, cutoff, w))
        assert e.margins.Ms == pytest.approx(ms, rel=5e-3), (d.name, e.params)
        if math.isfinite(gm):
            assert e.margins.gain_margin == pytest.approx(gm, rel=1e-2), (d.name, e.params)


# --- the cases ----------------------------------------------------------------------------

def test_px4_mrft_rule_out_of_range_is_refused_then_clamped_with_margins():
    m = LoopModel(0.0499, 0.887, 0.0228, 20.0)  # design2_roll's truth
    st = stack_setting("px4", "roll", 250.0, 200.0, None)  # the vehicle's IMU_GYRO_RATEMAX given
    assert st.rate_hz == 250.0 and st.rate_filter is not None and st.rate_filter.cutoff_hz == 40.0
    # without it, PX4's attitude loop's default IMU_INTEG_RATE 200 Hz, never the log's rate (issue 37)
    assert stack_setting("px4", "roll", None, 250.0, None).rate_hz == 200.0
    res = tune(m, st.rate_hz, loop="roll",
               options=DesignOptions(kinds=("PD",), designs=("mrft-rule",), rate_filter=st.rate_filter))
    c = res.designs[0].controller
    big = Controller(c.Kp * 3, 0.0, c.Kd * 3, 0.0, c.rate_hz, c.rate_filter)  # MC_ROLLRATE_P far above 0.5
    # no design inside the ranges holds big's Ms (issue 37's constrained search finds none): refused
    with pytest.raises(InputError, match=r"MC_ROLLRATE_P = .* above the maximum 0.5.*--clamp"):
        export_design("px4", big, m, "roll", "x")
    e = export_design("px4", big, m, "roll", "x", clamp=True)
    assert e.params["MC_ROLLRATE_P"] == 0.5 and e.clamped[0][0] == "MC_ROLLRATE_P"
    assert any("Ms" in n for n in e.notes)
    with pytest.raises(InputError, match="IMU_INTEG_RATE"):
        stack_setting("px4", "roll", 300.0, None, None)


def test_refusals_before_the_work():
    with pytest.raises(InputError, match="hover-thrust"):
        check_exportable("px4", "altitude", "PD")
    with pytest.raises(InputError, match="MOT_THST_HOVER"):
        check_exportable("ardupilot", "altitude", "PD")
    with pytest.raises(InputError, match="PID"):
        check_exportable("px4", "roll", "PID")


def test_hear_sign_and_ros_form():
    c = Controller(0.4, 0.0, 0.15, 0.0, 200.0, RateFilter(50.0))
    e = export_design("hear", c, LoopModel(0.0422, 1.3, 0.03, 30.0), "roll", "robust PD")
    obj = json.loads(e.file_text())
    assert obj["PID_parameters"]["kd"] == pytest.approx(0.15) and obj["PID_parameters"]["id"] == 3
    assert "NEGATED" in obj["sign"]
    assert set(obj["ros_msg_PID_param"]) == {"id", "pid_kp", "pid_ki", "pid_kd", "pid_kdd", "pid_anti_windup",
                                             "pid_en_pv_derivation", "pid_dt"}  # PID_param.msg's fields


def test_px4_params_file_is_qgroundcontrols_format():
    m = LoopModel(0.0499, 0.887, 0.0228, 20.0)
    e = export_design("px4", Controller(0.9, 0.0, 0.25, 0.0, 250.0, RateFilter(40.0)), m, "roll", "x")
    rows = [ln.split("\t") for ln in e.file_text().splitlines() if not ln.startswith("#")]
    assert all(len(r) == 5 and r[:2] == ["1", "1"] for r in rows)
    values = {r[2]: float(r[3]) for r in rows}
    assert values["MC_ROLL_P"] == pytest.approx(0.9 / 0.25)
    assert "IMU_GYRO_RATEMAX" not in values  # vehicle-wide and reboot_required: never written (issue 37)
    assert "param set MC_ROLLRATE_P 0.25" in e.console_lines()


# --- versioned records ----------------------------------------------------------------------------

def test_records_round_trip_and_refuse_other_versions():
    m = LoopModel(0.0422, 1.301, 0.0297, 30.0)
    post = Posterior.from_spread(m, 0.1, 0.002, 2.0, n=12)
    res = tune(m, 250.0, posterior=post,
               options=DesignOptions(kinds=("PD",), designs=("mrft-rule",), rate_filter=RateFilter(40.0)))
    data = json.loads(json.dumps(res.to_json()))
    back = TuneResult.from_json(data)
    assert back.to_json() == res.to_json() and back.rate_filter == res.rate_filter
    assert Design.from_json(data["designs"][0]).controller == res.designs[0].controller
    e = export_design("px4", res.designs[0].controller.scaled(0.5), m, "roll", "x", clamp=True)
    assert StackExport.from_json(json.loads(json.dumps(e.to_json()))) == e
    older = {k: v for k, v in e.to_json().items() if k != "assumptions"}  # written before the key existed
    assert StackExport.from_json(older).assumptions == ()
    for bad in ({**data, "schema_version": 99}, [], {**data, "model": None}):
        with pytest.raises(InputError):
            TuneResult.from_json(bad)
    with pytest.raises(InputError, match="schema_version"):
        StackExport.from_json({**e.to_json(), "schema_version": 0})


def test_tune_result_version_1_still_reads():
    """A tune result written by the previous release (schema 1: eq. (2) only, the model as {Tp, Td, tau, K};
    tests/data/old_records/tune_result_v1.json) reads with its figures, writes back as version 3, and holds
    the gains this release designs for the same inputs."""
    from pathlib import Path

    old = json.loads((Path(__file__).parent / "data" / "old_records" / "tune_result_v1.json").read_text())
    assert old["schema_version"] == 1
    res = TuneResult.from_json(old)
    assert res.model == LoopModel(0.0422, 1.301, 0.0297, 30.0) and res.posterior is not None
    assert res.get("model-based", "PD").controller.Kp == old["designs"][1]["controller"]["Kp"]
    new = res.to_json()
    assert new["schema_version"] == 3 and new["model"]["family"] == "soiptd"
    assert TuneResult.from_json(json.loads(json.dumps(new))).to_json() == new
    m = LoopModel(0.0422, 1.301, 0.0297, 30.0)
    again = tune(m, 250.0, posterior=Posterior.from_spread(m, 0.1, 0.002, 2.0, n=12), loop="roll",
                 options=DesignOptions(kinds=("PD",), designs=("mrft-rule", "model-based")))
    assert [d.controller for d in again.designs] == [d.controller for d in res.designs]


@pytest.mark.parametrize("name, family", [("tune_cli_v2", "soiptd"), ("tune_cli_v2_fopdt", "fopdt"),
                                           ("tune_cli_v2_cascade", "cascade")])
def test_tune_json_of_version_2_reads_with_its_figures(name, family):
    """``tune --json`` files written by commit 8c336ae (a report whose ``tune_result`` held the version 2
    record; tests/data/old_records/): ``tune --td 1.3 --tau 0.03 --k 30 --tp 0.0422 --loop roll
    --controller-rate 200 --design model-based --kind PD``, ``tune --model fopdt --param K=2 --param T=1
    --param tau=0.3 --controller-rate 20`` and ``tune y.json --export generic`` (a cascade analysis of
    sample_logs/hear_cascade_y.bag). The oracle is the file's report keys, written by the old code beside
    the record: every design's gains, margins and step figures come back, and the result writes as version 3."""
    from pathlib import Path

    old = json.loads((Path(__file__).parent / "data" / "old_records" / f"{name}.json").read_text())
    assert old["tune_result"]["schema_version"] == 2 and "schema_version" not in old
    res = TuneResult.from_json(old)
    assert res.model.family == family and res.loop == old["loop"] and res.rate_hz == old["rate_hz"]
    assert len(res.designs) == len(old["designs"])
    for d, o in zip(res.designs, old["designs"]):
        assert (d.name, d.kind) == (o["design"], o["kind"])
        assert [d.controller.Kp, d.controller.Ki, d.controller.Kd, d.controller.Tf] == [o[k] for k in ("Kp", "Ki", "Kd", "Tf")]
        for new_value, old_value in ((d.margins.Ms, o["margins"]["Ms"]), (d.criterion, o["criterion"]),
                                     (d.margins.delay_margin_s * 1e3, o["margins"]["delay_margin_ms"]),
                                     *((v, o["step"][k]) for k, v in d.step.to_dict().items())):
            # the old report wrote a figure that does not exist (NaN) as null
            assert math.isnan(new_value) if old_value is None else new_value == pytest.approx(old_value, rel=1e-12)
    chosen = res.get(old["export"]["design"], old["export"]["kind"]).controller
    assert chosen.Kp == old["export"]["generic"]["Kp"]
    new = json.loads(json.dumps(res.to_json()))
    assert new["schema_version"] == 3 and TuneResult.from_json(new).to_json() == new


# --- the CLI, as a user runs it -------------------------------------------------------------------

def _run(args: list[str], capsys) -> tuple[int, str, str]:
    """``mrft-ident tune`` on design2_roll's model through the console entry point: (exit code, stdout, stderr)."""
    from mrftcli.cli.main import main

    code = 0
    try:
        main(["tune", "--tp", "0.0499", "--td", "0.887", "--tau", "0.0228", "--k", "20", "--loop", "roll", *args])
    except SystemExit as e:
        code = int(e.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_export_out_file_and_generic(tmp_path, capsys):
    out = tmp_path / "roll.params"
    code, stdout, err = _run(["--controller-rate", "250", "--export", "px4", "--out", str(out), "--design", "model-based"], capsys)
    assert code == 0, err
    assert out.read_text().startswith("# Onboard parameters") and "param set MC_ROLL_P" in stdout
    assert not list(tmp_path.glob(".roll.params.*"))  # the temporary file was renamed
    code, stdout, err = _run(["--controller-rate", "250", "--export", "ardupilot", "--design", "model-based", "--clamp"], capsys)
    assert code == 0, err
    assert stdout.startswith("# mrft-ident") and "ATC_RAT_RLL_P," in stdout  # the .param file on stdout
    code, _, err = _run(["--controller-rate", "300", "--export", "px4"], capsys)
    assert code == 2 and err.startswith("error:") and "IMU_INTEG_RATE" in err and len(err.splitlines()) == 1
    # one output rule for every command (issue 35, io/atomic.check_output_path): a missing folder is created,
    # as analyze --json always did
    code, _, err = _run(["--controller-rate", "250", "--export", "px4", "--out", str(tmp_path / "no" / "x.params")], capsys)
    assert code == 0 and (tmp_path / "no" / "x.params").read_text().startswith("# Onboard parameters"), err
    (tmp_path / "link.params").symlink_to(out)
    code, _, err = _run(["--controller-rate", "250", "--export", "px4", "--out", str(tmp_path / "link.params")], capsys)
    assert code == 2 and "--out" in err and "symbolic link" in err and len(err.splitlines()) == 1
    code, _, err = _run(["--controller-rate", "200", "--export", "hear", "--gyro-cutoff", "30"], capsys)
    assert code == 2 and "--gyro-cutoff" in err
    code, stdout, err = _run(["--controller-rate", "200", "--export", "generic", "--design", "mrft-rule"], capsys)
    assert code == 0 and json.loads(stdout)["Kp"] > 0


def test_cli_json_holds_the_versioned_record(tmp_path, capsys):
    code, _, err = _run(["--controller-rate", "250", "--export", "px4", "--out", str(tmp_path / "r.params"),
                         "--json", str(tmp_path / "t.json")], capsys)
    assert code == 0, err
    data = json.loads((tmp_path / "t.json").read_text())
    assert data["schema_version"] == 3 and "tune_result" not in data  # the record itself, the export beside it
    res = TuneResult.from_json(data)
    assert res.rate_filter == RateFilter(40.0, "IMU_GYRO_CUTOFF") and res.rate_hz == 250.0
    e = StackExport.from_json(data["export"]["stack"])
    assert e.params["MC_ROLLRATE_P"] == pytest.approx(res.get("model-based", "PD").controller.Kd)


def test_tune_export_never_written_over_its_sources(tmp_path: Path) -> None:
    """tune SOURCE --export px4 --out SOURCE (one source, or ROLL.json PITCH.json) is refused before the work
    (exit 2, one line naming --out and the input), the source unchanged."""
    import shutil

    from cli_helpers import run_main

    log = tmp_path / "roll.BIN"
    shutil.copy(Path(__file__).resolve().parents[1] / "sample_logs" / "sitl" / "roll.BIN", log)
    roll, pitch = tmp_path / "roll.json", tmp_path / "pitch.json"
    roll.write_text("{}")
    pitch.write_text("{}")
    before = log.read_bytes()
    for argv in ([str(log), "--loop", "roll"], [str(roll), str(pitch)]):
        target = argv[0]
        done = run_main("tune", *argv, "--tp", "0.05", "--export", "px4", "--out", target, "-q")
        lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
        assert done.returncode == 2 and len(lines) == 1, done.stderr
        assert lines[0].startswith(f"error: --out {target}") and "input" in lines[0]
    assert log.read_bytes() == before and roll.read_text() == "{}"
