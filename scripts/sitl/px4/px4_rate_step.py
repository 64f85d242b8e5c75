"""The rate loops' export flown in PX4 SITL: ``tune --export px4`` for pitch, loaded, read back, and a
pitch step flown in OFFBOARD against tune's prediction (mrft-ident issue 42).

The model is the one identified on SIH's own attitude at the bench Tp (``px4_campaign.rate_loop_truth``:
on EKF2's attitude eq. (2) is refused, docs/sitl.md); the design at the rate PX4's attitude and rate
loops run in this SITL (``IMU_INTEG_RATE`` 250 Hz, SIH's step). The step is an attitude setpoint
(``SET_ATTITUDE_TARGET``, thrust at the hover estimate) from level to ``step_deg`` and back, both signs,
``repeats`` times; each step's response is normalised from the level before it to the level it held
(the mean of its last 0.5 s), on EKF2's attitude (what PX4 controls) and on SIH's.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from px4_sitl import Px4Sitl, load_params, read_qgc_params  # noqa: E402

__all__ = ["export_rate", "fly_attitude_steps", "evaluate_attitude_steps", "RATE_HZ"]

#: the attitude and rate loops' rate in this SITL: IMU_INTEG_RATE 250 Hz (SIH's airframe; SIH's step)
RATE_HZ = 250.0


def export_rate(log: Path, loop: str, tp: float, work: Path, output_topic: str) -> tuple[Path | None, dict[str, Any]]:
    """``tune --export px4`` for ``loop`` from ``log`` (its output ``output_topic``) at ``tp`` and
    :data:`RATE_HZ`: the ``.params`` file (None when refused) and the exported design's predicted step."""
    work.mkdir(parents=True, exist_ok=True)
    params, js = work / f"{loop}.params", work / f"{loop}_tune.json"
    for p in (params, js):
        p.unlink(missing_ok=True)
    proc = subprocess.run([sys.executable, "-m", "mrftcli.cli", "tune", str(log), "--tp", f"{tp:.6f}", "--loop", loop,
                           "--output-topic", output_topic, "--controller-rate", f"{RATE_HZ:g}", "--export", "px4",
                           "--out", str(params), "--json", str(js)], capture_output=True, text=True)
    print(f"  tune --export px4 ({loop}, Tp {tp * 1e3:.2f} ms, {RATE_HZ:g} Hz): exit {proc.returncode}")
    print("    " + "\n    ".join(line for line in proc.stdout.strip().splitlines()[:12]))
    if not params.exists():
        print(proc.stderr[-600:])
        return None, {}
    record = json.loads(js.read_text())
    kind = record["export"]["design"]
    design = next(d for d in record["designs"] if d["design"] == kind)  # the first: the setpoint step
    return params, {"design": kind, **design["step"], "Ms": design["margins"]["Ms"],
                    "response": _predicted_response(record)}


def _predicted_response(record: dict[str, Any], t_end: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """The exported design's unit setpoint step on the identified model (tune's sampled loop, the stack's
    rate filter): the curve behind tune's step figures, to measure it against any band."""
    from mrftcli.mrft.controller import Controller, RateFilter
    from mrftcli.mrft.model import LoopModel
    from mrftcli.tune.closed_loop import step_response

    g, m = record["export"]["generic"], record["model"]
    if "parameters" in m:  # the model record (schema 1): each parameter's value
        m = {k: v["value"] for k, v in m["parameters"].items()}
    filt = g.get("rate_filter")
    ctrl = Controller(Kp=g["Kp"], Ki=g["Ki"], Kd=g["Kd"], Tf=g["Tf"], rate_hz=g["rate_hz"],
                      rate_filter=RateFilter(filt["cutoff_hz"], filt.get("parameter", "")) if filt else None)
    t, y, _ = step_response([LoopModel(m["Tp"], m["Td"], m["tau"], m["K"])], ctrl, t_end)
    return t, y[0]


def _quat(roll: float, pitch: float, yaw: float) -> list[float]:
    cr, sr, cp, sp, cy, sy = (math.cos(roll / 2), math.sin(roll / 2), math.cos(pitch / 2), math.sin(pitch / 2),
                              math.cos(yaw / 2), math.sin(yaw / 2))
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy]


def _hold_attitude(sitl: Px4Sitl, roll: float, pitch: float, yaw: float, thrust: float, seconds: float) -> None:
    """Stream an attitude setpoint [rad] with a collective thrust at 50 Hz for ``seconds`` of simulated time."""
    end = sitl.boot_ms + seconds * 1000
    while sitl.boot_ms < end:
        sitl.mav.mav.set_attitude_target_send(0, sitl.mav.target_system, sitl.mav.target_component, 0b00000111,
                                              _quat(roll, pitch, yaw), 0, 0, 0, thrust)
        sitl.wait(0.02)


def fly_attitude_steps(px4: Path, params_file: Path, work: Path, loop: str, step_deg: float = 10.0,
                       repeats: int = 2, dwell_s: float = 2.0) -> dict[str, Any]:
    """Load the export, read it back, take off, fly ``repeats`` x (+step, back, -step, back) in OFFBOARD."""
    params = read_qgc_params(params_file)
    # the stages' topics (SIH's attitude beside EKF2's) come with any MRFT_R_ / MRFT_P_ parameter
    with Px4Sitl(px4, work / "refly", 1.0, {f"MRFT_{'R' if loop == 'roll' else 'P'}_ENABLE": 0}) as sitl:
        rows = load_params(sitl, params)
        changed = [r for r in rows if not r["unchanged"]]
        print(f"  loaded {len(rows)} parameters, read back: {len(changed)} rejected or changed")
        refusals = sitl.takeoff(5.0)
        print(f"  pre-arm: passed (refusals while the EKF settled: {sorted(set(refusals)) or 'none'})")
        hover = sitl.get_param("MPC_THR_HOVER")
        att = sitl.wait(5, lambda m: m.get_type() == "ATTITUDE")
        yaw = float(att.yaw)
        _hold_attitude(sitl, 0, 0, yaw, hover, 1.0)
        sitl.mav.set_mode("OFFBOARD")  # the stream goes on while the mode changes
        _hold_attitude(sitl, 0, 0, yaw, hover, 3.0)
        if sitl.mav.flightmode != "OFFBOARD":
            raise RuntimeError(f"OFFBOARD not entered (in {sitl.mav.flightmode}); {sitl.last_texts()}")
        step = math.radians(step_deg)
        for _ in range(repeats):
            for sign in (1.0, -1.0):
                angles = (sign * step, 0.0) if loop == "roll" else (0.0, sign * step)
                _hold_attitude(sitl, *angles, yaw, hover / math.cos(step), dwell_s)
                _hold_attitude(sitl, 0, 0, yaw, hover, dwell_s)
        sitl.set_mode("LOITER")
        sitl.land()
        sitl.wait(2)
    log = sitl.newest_log()
    shutil.copy(log, work / f"{loop}_steps.ulg")
    return {"rows": rows, "log": work / f"{loop}_steps.ulg", "dwell_s": dwell_s, "step_deg": step_deg}


def _angle(q: dict[str, np.ndarray], loop: str) -> np.ndarray:
    q0, q1, q2, q3 = (q[f"q[{i}]"] for i in range(4))
    if loop == "roll":
        return np.arctan2(2 * (q0 * q1 + q2 * q3), 1 - 2 * (q1**2 + q2**2))
    return np.arcsin(np.clip(2 * (q0 * q2 - q3 * q1), -1, 1))


def _step_figures(t: np.ndarray, y: np.ndarray, t0: float, dwell: float, band: float = 0.02) -> dict[str, float]:
    """Overshoot [%], 10-90 % rise [s] and settling [s] into ``1 +- band`` (2 %) of one step at ``t0``,
    normalised from the mean of the 0.3 s before it to the mean of its last 0.5 s."""
    grid = np.arange(0.0, dwell - 0.02, 0.004)
    a = np.interp(t0 + grid, t, y)
    base = float(np.mean(y[(t > t0 - 0.3) & (t < t0)]))
    r = (a - base) / (float(np.mean(a[grid > dwell - 0.5])) - base)
    outside = np.flatnonzero(np.abs(r - 1.0) > band)
    return {"overshoot_pct": max(0.0, float(np.max(r)) - 1.0) * 100,
            "rise_s": float(grid[np.argmax(r >= 0.9)] - grid[np.argmax(r >= 0.1)]),
            "settling_s": float(grid[outside[-1]]) if outside.size else 0.0}


def evaluate_attitude_steps(flown: dict[str, Any], loop: str, pred: dict[str, Any]) -> dict[str, Any]:
    """Each step's figures from level (the setpoint leaving 0) on EKF2's and SIH's attitude; their medians
    against ``pred``; printed."""
    from pyulog import ULog

    d = {x.name: x.data for x in ULog(str(flown["log"])).data_list}
    sp = d["vehicle_attitude_setpoint"]
    ts, target = sp["timestamp"] * 1e-6, _angle({f"q[{i}]": sp[f"q_d[{i}]"] for i in range(4)}, loop)
    # the steps flown: the setpoint at +-step (not the take-off's, Hold's or landing's attitude setpoints)
    away = np.abs(np.abs(target) - math.radians(flown["step_deg"])) < math.radians(0.2)
    starts = ts[1:][np.diff(away.astype(int)) == 1]
    out: dict[str, Any] = {"steps": len(starts)}
    for name, topic in (("EKF2", "vehicle_attitude"), ("SIH", "vehicle_attitude_groundtruth")):
        if topic not in d:
            continue
        t, y = d[topic]["timestamp"] * 1e-6, _angle(d[topic], loop)
        each = [_step_figures(t, y, t0, flown["dwell_s"]) for t0 in starts]
        med = {k: float(np.median([e[k] for e in each])) for k in ("overshoot_pct", "rise_s", "settling_s")}
        out[name] = {"median": med, "each": each}
        print(f"  {loop} step {flown['step_deg']:g} deg x{len(starts)} ({name}'s attitude): median overshoot "
              f"{med['overshoot_pct']:.1f} %, rise {med['rise_s']:.3f} s, 2 % settling {med['settling_s']:.3f} s; "
              f"predicted {pred['overshoot_pct']:.1f} %, {pred['rise_s']:.3f} s, {pred['settling_s']:.3f} s "
              f"(ratios {med['rise_s'] / pred['rise_s']:.2f}, {med['settling_s'] / pred['settling_s']:.2f})")
        print("    single steps: " + "; ".join(f"{e['overshoot_pct']:.1f} %, {e['rise_s']:.3f} s, "
                                             f"{e['settling_s']:.3f} s" for e in each))
        # the band the attitude holds at level before the steps (+-2 std), as the altitude's (px4_campaign)
        hold = (t > starts[0] - 2.5) & (t < starts[0] - 0.1)
        band = 2 * float(np.std(y[hold])) / math.radians(flown["step_deg"])
        singles = [_step_figures(t, y, t0, flown["dwell_s"], band)["settling_s"] for t0 in starts]
        if "response" in pred:
            tp_, yp = pred["response"]
            outside = np.flatnonzero(np.abs(yp - 1.0) > band)
            predicted = float(tp_[outside[-1]]) if outside.size else 0.0
            out[name]["band"] = {"band": band, "settling_s": float(np.median(singles)), "predicted_s": predicted}
            print(f"    into the band the attitude holds at level (+-2 std = +-{math.degrees(band * math.radians(flown['step_deg'])):.2f} "
                  f"deg, {band * 100:.1f} % of the step): median {np.median(singles):.3f} s (single steps "
                  f"{', '.join(f'{v:.3f}' for v in singles)}); predicted {predicted:.3f} s")
    return out


def run_rate_step(px4: Path, logs: Path, tp: float, output_topic: str, fly: bool, loop: str = "pitch",
                  flight: str = "px4_pitch_h") -> dict[str, Any] | None:
    """Export ``loop`` from ``logs/flight.ulg``, and fly its steps (``fly``) or evaluate those flown before."""
    log, work = logs / f"{flight}.ulg", logs / "export"
    steps = work / f"{loop}_steps.ulg"
    if not log.exists() or not (fly or steps.exists()):  # nothing to fly or evaluate: write nothing
        return None
    params, pred = export_rate(log, loop, tp, work, output_topic)
    if params is None:
        return None
    print(f"    exported design ({pred['design']}): step overshoot {pred['overshoot_pct']:.2f} %, rise "
          f"{pred['rise_s']:.3f} s, 2 % settling {pred['settling_s']:.3f} s, Ms {pred['Ms']:.2f}")
    flown: dict[str, Any] = {"log": steps, "dwell_s": 2.0, "step_deg": 10.0}
    if fly:
        flown = fly_attitude_steps(px4, params, work, loop)
        bad = [r for r in flown["rows"] if not r["unchanged"]]
        print(f"    parameters rejected or changed on read-back: {len(bad)} of {len(flown['rows'])}")
    return evaluate_attitude_steps(flown, loop, pred)
