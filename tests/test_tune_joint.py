"""One gyro cutoff for roll and pitch (tracker issue 25): the search against a brute-force check, the
margins of the joint export recomputed from its values alone, the records, the CLI's refusals."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mrftcli.errors import InputError
from mrftcli.mrft.model import LoopModel
from mrftcli.tune.closed_loop import RateFilter
from mrftcli.tune.design import DesignOptions, Posterior, tune
from mrftcli.tune.joint import (AxisModel, AxisSource, JointCutoff, JointExport, export_axes,
                                joint_gyro_cutoff)
from mrftcli.tune.margins import loop_margins
from mrftcli.tune.stack_params import STACK_PARAMS, check_ranges
from test_exports import _loop_from_params, _ms_gm

RATE = 100.0  # PX4's lowest IMU_GYRO_RATEMAX: the fewest ticks per design
CANDIDATES = (8.0, 40.0)
LOSS = 0.08


def _axes() -> list[AxisModel]:
    """Two small posteriors (8 draws) about design1's roll and pitch truths."""
    out = []
    for loop, m in (("roll", LoopModel(0.0422, 1.3, 0.0297, 30.0)), ("pitch", LoopModel(0.0422, 1.6, 0.0289, 25.0))):
        out.append(AxisModel(loop, m, Posterior.from_spread(m, 0.05 * m.Td, 0.1 * m.tau, 0.05 * m.K, n=8, seed=1)))
    return out


@pytest.fixture(scope="module")
def joint() -> JointCutoff:
    return joint_gyro_cutoff(_axes(), "px4", RATE, max_loss=LOSS, candidates=CANDIDATES)


def _passes(axes: list[AxisModel], cutoff: float, reference: list[float]) -> tuple[bool, list[float]]:
    """Brute force at one cutoff: tune's robust PD per axis, its Ms recomputed on every draw of the 95 % set."""
    ok, J = True, []
    for a, j0 in zip(axes, reference or [math.inf, math.inf]):
        options = DesignOptions(designs=("model-based", "robust"), kinds=("PD",),
                                rate_filter=RateFilter(cutoff, "IMU_GYRO_CUTOFF"))
        d = tune(a.model, RATE, posterior=a.posterior, options=options).get("robust", "PD")
        draws = [a.posterior.models()[i] for i in np.nonzero(a.posterior.in_set())[0]]
        worst = float(np.max(loop_margins(d.controller, draws).Ms))
        J.append(d.criterion_expected)
        ok = ok and worst <= 1.6 * (1 + 1e-3) and d.criterion_expected <= (1 + LOSS) * j0
    return ok, J


def test_joint_cutoff_is_the_brute_force_choice(joint):
    """Every candidate and the bypassed filter evaluated: the chosen cutoff is the lowest one at and above
    which both axes pass (the search stops at the first failure, so it must agree)."""
    axes = _axes()
    _, ref = _passes(axes, 0.0, [])
    passed = {f: _passes(axes, f, ref)[0] for f in CANDIDATES}
    band = [f for f in sorted(CANDIDATES) if all(passed[g] for g in CANDIDATES if g >= f)]
    assert band, passed
    assert joint.cutoff_hz == band[0]
    assert joint.reference.criterion == pytest.approx(ref, rel=1e-9)
    # the filter costs performance, so a band exists below the top only if the loss allows it
    assert all(t.passed == passed[t.cutoff_hz] for t in joint.trials)


def test_joint_export_is_one_file_with_margins_recomputed_from_its_values(joint):
    exp = export_axes("px4", joint.results, "robust", [AxisSource(), AxisSource()], cutoff=joint)
    params = exp.params()
    rows = {p.name: p for p in STACK_PARAMS if p.stack == "px4"}
    assert set(params) <= set(rows) and not check_ranges("px4", params)
    assert params["IMU_GYRO_CUTOFF"] == joint.cutoff_hz and "IMU_GYRO_RATEMAX" not in params
    lines = [ln.split("\t") for ln in exp.file_text().splitlines() if not ln.startswith("#")]
    assert [ln[2] for ln in lines].count("IMU_GYRO_CUTOFF") == 1 and {"MC_ROLL_P", "MC_PITCH_P"} <= {ln[2] for ln in lines}
    w = np.geomspace(1e-3, 0.999, 3000) * math.pi * RATE
    for e, a in zip(exp.exports, _axes()):
        ms, gm = _ms_gm(_loop_from_params("px4", a.loop, e.params, a.model, RATE, joint.cutoff_hz, w))
        assert e.margins.Ms == pytest.approx(ms, rel=5e-3) and e.margins.gain_margin == pytest.approx(gm, rel=1e-2)


def test_records_round_trip_and_refuse_other_versions(joint):
    exp = export_axes("px4", joint.results, "robust", [AxisSource(), AxisSource()], cutoff=joint)
    back = JointExport.from_json(json.loads(json.dumps(exp.to_json())))
    assert back.params() == exp.params() and back.cutoff == JointCutoff.from_json(joint.to_json())
    assert back.cutoff is not None and back.cutoff.cutoff_hz == joint.cutoff_hz
    for cls, data in ((JointCutoff, joint.to_json()), (JointExport, exp.to_json())):
        with pytest.raises(InputError, match="schema_version"):
            cls.from_json({**data, "schema_version": 99})
        with pytest.raises(InputError):
            cls.from_json({"schema_version": 1})


def test_refusals():
    axes = _axes()
    with pytest.raises(InputError, match="one roll and one pitch"):
        joint_gyro_cutoff([axes[0], axes[0]], "px4", RATE)
    with pytest.raises(InputError, match="px4|ardupilot"):
        joint_gyro_cutoff(axes, "hear", RATE)
    with pytest.raises(InputError, match="below half the rate"):
        joint_gyro_cutoff(axes, "px4", RATE, candidates=(200.0,))


def _result(loop: str, rate: float, Td: float, K: float) -> dict:
    """The smallest analyze RESULT.json tune reads (means, stds, loop, the recorded controller rate)."""
    par = {"Td": (Td, 0.02 * Td, "s"), "tau": (0.0297, 0.0005, "s"), "K": (K, 0.01 * K, "-"), "Tp": (0.0422, 0.0, "s")}
    return {"schema_version": 1, "tests": [],
            "parameters": {k: {"mean": m, "std": sd, "unit": u} for k, (m, sd, u) in par.items()},
            "model": {"Tp": 0.0422, "Td": Td, "tau": 0.0297, "K": K},
            "input": {"path": f"{loop}.mcap", "loop": loop, "Tp": 0.0422, "t0": 0.0,
                      "source": {"controller_rate_hz": rate}, "command_samples": 100, "output_samples": 100,
                      "t_first": 0.0, "t_last": 1.0, "beta_topic": True, "setpoint_topic": False,
                      "reader_warnings": []}}


def test_cli_two_results(tmp_path, capsys):
    """tune ROLL.json PITCH.json --export px4 --gyro-cutoff HZ writes one file with one cutoff; the one-line
    refusals: two results of one loop, mismatched rates, another export, auto with one source."""
    from mrftcli.cli.main import main

    files = {}
    for name, args in (("roll", ("roll", 250.0, 1.3, 30.0)), ("pitch", ("pitch", 250.0, 1.6, 25.0)),
                       ("pitch400", ("pitch", 400.0, 1.6, 25.0))):
        files[name] = tmp_path / f"{name}.json"
        files[name].write_text(json.dumps(_result(*args)))

    def run(*args: object) -> tuple[int, str]:
        try:
            main(["tune", "--tp", "0.0422", *(str(a) for a in args)])
            code = 0
        except SystemExit as e:
            code = int(e.code or 0)
        cap = capsys.readouterr()
        return code, cap.err + cap.out

    out = tmp_path / "rp.params"  # the summary goes to stdout when the file is written
    code, err = run(files["pitch"], files["roll"], "--export", "px4", "--gyro-cutoff", "30", "--out", out)
    assert code == 0, err
    names = [ln.split("\t")[2] for ln in out.read_text().splitlines() if not ln.startswith("#")]
    assert names.count("IMU_GYRO_CUTOFF") == 1 and names.index("MC_ROLL_P") < names.index("MC_PITCH_P")
    assert "IMU_GYRO_CUTOFF = 30 Hz for both axes" in err and err.count("margins with the stack's filter") == 2
    for args, what in (((files["roll"], files["roll"]), "both for the roll loop"),
                       ((files["roll"], files["pitch400"]), "--controller-rate"),
                       ((files["roll"], files["pitch"], "--export", "hear"), "px4|ardupilot"),
                       (("--td", 1.3, "--tau", 0.03, "--k", 30, "--loop", "roll", "--export", "px4",
                         "--gyro-cutoff", "auto"), "ROLL.json PITCH.json"),
                       (("--gyro-cutoff", "fast", "--td", 1.3, "--tau", 0.03, "--k", 30, "--loop", "roll"),
                        "auto or a cutoff")):
        code, err = run(*args, *(() if "--export" in args else ("--export", "px4")))
        assert code == 2 and what in err and len(err.strip().splitlines()) == 1, err
