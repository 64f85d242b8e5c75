"""PX4's x/y export flown in PX4 SITL (mrft-ident issue 42): ``tune --export px4 --loop x`` (or y) from the
fork's x (y) MRFT ULog, loaded over MAVLink and read back, then position steps in OFFBOARD against the
prediction of the loop the written values give (``tune.stacks.px4_xy_controller``: PX4's velocity PID with
``MPC_XY_VEL_D_ACC`` through ``MPC_VELD_LP``, on the identified eq. (2) model).

Each step is a true step of the OFFBOARD position setpoint (unshaped, as the altitude step:
``px4_campaign.refly``), ``step_m`` along the axis and back, ``repeats`` times, ``dwell_s`` each; each
up-step's response is normalised from the level before it to the level it held (the mean of its last 3 s),
on EKF2's position (what PX4 controls) and on SIH's (``vehicle_local_position_groundtruth``).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from px4_campaign import _figures, _hover, _normalised_steps, _offboard_hold, _settling, _velocity_bias  # noqa: E402
from px4_sitl import Px4Sitl, load_params, read_qgc_params  # noqa: E402

__all__ = ["export_xy", "predicted_xy_step", "fly_xy_steps", "evaluate_xy_steps", "run_xy_step"]


def export_xy(log: Path, loop: str, work: Path, tp: float = 0.05) -> tuple[Path | None, dict[str, Any]]:
    """``tune --export px4 --loop x|y --hover-thrust H`` (H: the log's hover thrust estimate, which PX4's
    position controller uses) at Tp ``tp`` [s]; the ``.params`` (None: refused) and the tune record."""
    work.mkdir(parents=True, exist_ok=True)
    params, js = work / f"{loop}.params", work / f"{loop}_tune.json"
    for p in (params, js):
        p.unlink(missing_ok=True)
    hover = _hover(log)
    cmd = [sys.executable, "-m", "mrftcli.cli", "tune", str(log), "--tp", f"{tp:.6f}", "--loop", loop, "--export",
           "px4", "--hover-thrust", f"{hover:.4f}", "--out", str(params), "--json", str(js)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    print(f"  mrft-ident {' '.join(cmd[3:])}: exit {proc.returncode}")
    print("    " + "\n    ".join(proc.stdout.strip().splitlines()))
    if not params.exists():
        print(proc.stderr[-800:])
        return None, {}
    return params, {**json.loads(js.read_text()), "hover": hover}


def predicted_xy_step(record: dict[str, Any], params_file: Path, t_end: float = 20.0) -> dict[str, Any]:
    """The unit step of the loop the written values give, on the identified model (tune's sampled loop)."""
    from mrftcli.mrft.model import LoopModel
    from mrftcli.tune.closed_loop import step_metrics, step_response
    from mrftcli.tune.stacks import px4_xy_controller

    m = record["model"]
    if "parameters" in m:  # the model record (schema 1): each parameter's value
        m = {k: v["value"] for k, v in m["parameters"].items()}
    values = {k: v for k, (v, _) in read_qgc_params(params_file).items()}
    ctrl = px4_xy_controller(values, record["export"]["generic"]["rate_hz"], record["hover"])
    t, y, u = step_response([LoopModel(m["Tp"], m["Td"], m["tau"], m["K"])], ctrl, t_end)
    f = step_metrics(t, y[0], u[0])
    return {"overshoot_pct": f.overshoot_pct, "rise_s": f.rise_s, "settling_s": f.settling_s, "t": t, "y": y[0],
            "model": m, "controller": ctrl}


def fly_xy_steps(px4: Path, params_file: Path, work: Path, loop: str, step_m: float = 1.0, repeats: int = 4,
                 dwell_s: float = 8.0, speedup: float = 1.0) -> dict[str, Any]:
    """Load the export, read it back, arm, take off, fly ``repeats`` x (+step along ``loop``, back) in OFFBOARD."""
    params = read_qgc_params(params_file)
    with Px4Sitl(px4, work / f"refly_{loop}", speedup) as sitl:
        rows = load_params(sitl, params)
        changed = [r for r in rows if not r["unchanged"]]
        print(f"  loaded {len(rows)} parameters, read back: {len(changed)} rejected or changed")
        for r in changed:
            print(f"    {r['name']}: wrote {r['written']:g}, read {r['read_back']:g}")
        refusals = sitl.takeoff(5.0)
        print(f"  pre-arm: passed (refusals while the EKF settled: {sorted(set(refusals)) or 'none'})")
        msg = sitl.wait(5, lambda m: m.get_type() == "LOCAL_POSITION_NED")
        x, y, z = float(msg.x), float(msg.y), float(msg.z)
        _offboard_hold(sitl, x, y, z, 1.0)
        sitl.mav.set_mode("OFFBOARD")  # the stream goes on while the mode changes (COM_OF_LOSS_T)
        _offboard_hold(sitl, x, y, z, 8.0)
        if sitl.mav.flightmode != "OFFBOARD":
            raise RuntimeError(f"OFFBOARD not entered (in {sitl.mav.flightmode}); {sitl.last_texts()}")
        dx, dy = (step_m, 0.0) if loop == "x" else (0.0, step_m)
        for _ in range(repeats):
            _offboard_hold(sitl, x + dx, y + dy, z, dwell_s)
            _offboard_hold(sitl, x, y, z, dwell_s)
        sitl.set_mode("LOITER")
        sitl.land()
        sitl.wait(2)
    log = sitl.newest_log()
    shutil.copy(log, work / f"{loop}_steps.ulg")
    return {"rows": rows, "log": work / f"{loop}_steps.ulg", "p0": x if loop == "x" else y, "step_m": step_m,
            "dwell_s": dwell_s}


def evaluate_xy_steps(flown: dict[str, Any], loop: str, pred: dict[str, Any]) -> dict[str, Any]:
    """The flown up-steps' figures on EKF2's and SIH's position (mean response and each step) against ``pred``,
    and into the band PX4 holds in hover (+-2 std of the 6 s before the first step)."""
    from mrftcli.io import open_log

    step, dwell = flown["step_m"], flown["dwell_s"]
    with open_log(flown["log"], echo_warnings=False) as src:
        ts, sp = src.read("trajectory_setpoint", [f"position[{'0' if loop == 'x' else '1'}]"])
        psp = next(iter(sp.values()))
        p0 = flown.get("p0", float(np.nanmin(psp[np.isfinite(psp)])))
        up = np.isfinite(psp) & (psp > p0 + 0.5 * step)
        starts = [float(ts[i]) for i in np.flatnonzero(np.diff(up.astype(int)) == 1) + 1]
        out: dict[str, Any] = {"steps": len(starts)}
        for name, topic in (("EKF2", "vehicle_local_position"), ("SIH", "vehicle_local_position_groundtruth")):
            try:
                t, pos = src.read(topic, [loop, f"v{loop}"])
            except Exception:  # noqa: BLE001 - a topic not logged: that row is left out
                continue
            p = pos[loop]
            out.setdefault("setpoint", {})[name] = _against_setpoint(t, p, pos[f"v{loop}"], starts, step, dwell, pred)
            grid, runs = _normalised_steps(t, p, starts, dwell)
            got = _figures(grid, np.mean(runs, axis=0))
            each = [_figures(grid, r) for r in runs]
            hover = (t > starts[0] - 6) & (t < starts[0])
            band = 2 * float(np.std(p[hover])) / step
            got["band"] = band
            got["settling_band_s"] = _settling(grid, np.mean(runs, axis=0), band)
            got["predicted_settling_band_s"] = _settling(pred["t"], pred["y"], band)
            out[name] = {"mean": got, "each": each}
            print(f"  {loop} step +{step:g} m x{len(starts)} ({name}'s position; to the level held): mean response "
                  f"overshoot {got['overshoot_pct']:.1f} %, rise (10-90 %) {got['rise_s']:.2f} s, 2 % settling "
                  f"{got['settling_s']:.2f} s; predicted {pred['overshoot_pct']:.1f} %, {pred['rise_s']:.2f} s, "
                  f"{pred['settling_s']:.2f} s (ratios: rise {got['rise_s'] / pred['rise_s']:.2f}, settling "
                  f"{got['settling_s'] / pred['settling_s']:.2f})")
            print("    single steps: " + "; ".join(f"{e['overshoot_pct']:.1f} %, {e['rise_s']:.2f} s, "
                                                 f"{e['settling_s']:.2f} s" for e in each))
            print(f"    into the band held in hover (+-2 std = +-{band * step * 100:.1f} cm): mean response "
                  f"{got['settling_band_s']:.2f} s, predicted {got['predicted_settling_band_s']:.2f} s")
            _print_against_setpoint(name, loop, out["setpoint"][name], pred)
    return out


def _against_setpoint(t: np.ndarray, p: np.ndarray, v: np.ndarray, starts: list[float], step: float, dwell: float,
                      pred: dict[str, Any], window: float = 2.0) -> dict[str, Any]:
    """Each up-step against the commanded step (from the level before it to the setpoint, not to the level it
    held): 10-90 % rise of the setpoint step (median of the steps), the mean response's largest difference from
    the prediction over the first ``window`` s [fraction of the step], where the predicted loop settles; and
    what moves the held level afterwards: the estimate's velocity against the slope of its own position (median
    |.| over 2 s windows, :func:`px4_campaign._velocity_bias`) and each step's level [m] off the setpoint at its end."""
    grid = np.arange(0.0, dwell - 0.05, 0.008)
    runs = []
    for t0 in starts:
        base = float(np.mean(p[(t > t0 - 2) & (t < t0)]))
        runs.append((np.interp(t0 + grid, t, p) - base) / step)
    rises = [float(grid[np.argmax(r >= 0.9)] - grid[np.argmax(r >= 0.1)]) for r in runs]
    first = grid <= window
    diff = float(np.max(np.abs(np.mean(runs, axis=0)[first] - np.interp(grid[first], pred["t"], pred["y"]))))
    ends = [float(np.mean(r[grid > dwell - 3]) - 1.0) * step for r in runs]
    bias = _velocity_bias(t, p, v, starts[0], starts[-1] + 2 * dwell)
    return {"rise_s": float(np.median(rises)), "rises_s": rises, "max_diff_first": diff, "window_s": window,
            "end_offsets_m": ends, "velocity_bias": bias}


def _print_against_setpoint(name: str, loop: str, a: dict[str, Any], pred: dict[str, Any]) -> None:
    print(f"  against the setpoint ({name}'s {loop}): rise 10-90 % of the commanded step, median "
          f"{a['rise_s']:.2f} s (steps {', '.join(f'{r:.2f}' for r in a['rises_s'])}), predicted {pred['rise_s']:.2f} s "
          f"(ratio {a['rise_s'] / pred['rise_s']:.2f}); mean response within {100 * a['max_diff_first']:.1f} % of the "
          f"step of the predicted curve over the first {a['window_s']:g} s; then the level held wanders: "
          f"{', '.join(f'{o * 100:+.0f}' for o in a['end_offsets_m'])} cm off the setpoint at the steps' ends, "
          f"the estimate's v{loop} against the slope of its {loop} {a['velocity_bias']:.3f} m/s (median |.|, 2 s windows)")


def integral_effect(record: dict[str, Any], params_file: Path, integrals: tuple[float, ...] = (0.0, 0.1, 0.2, 0.4),
                    wind: float = 1.0) -> list[dict[str, float]]:
    """What ``MPC_XY_VEL_I_ACC`` > 0 would change in the loop written (the other values kept), on tune's model of
    PX4's x/y loop: Ms (nominal; worst over up to 40 posterior draws), and by PX4's own law
    (``tune.px4_xy.px4_xy_prediction``, what ``tune --xy-integral`` states) the position step and a ``wind``
    [m/s^2] step of force (a load at the plant's input) held off after 5 and 20 s. PX4 integrates the velocity error,
    so the integral removes a force's offset, not that of a biased velocity estimate (vel_sp = v either way)."""
    from mrftcli.mrft.model import LoopModel
    from mrftcli.tune.margins import loop_margins
    from mrftcli.tune.px4_xy import px4_xy_controller, px4_xy_prediction

    m = record["model"]
    if "parameters" in m:
        m = {k: v["value"] for k, v in m["parameters"].items()}
    post = record.get("posterior") or {"Td": [], "tau": [], "K": []}
    every = max(1, len(post["Td"]) // 40)
    models = [LoopModel(m["Tp"], m["Td"], m["tau"], m["K"])] + [
        LoopModel(m["Tp"], td, tau, k) for td, tau, k in zip(post["Td"][::every], post["tau"][::every], post["K"][::every])]
    values = {k: v for k, (v, _) in read_qgc_params(params_file).items()}
    rows = []
    for iv in integrals:
        ctrl = px4_xy_controller({**values, "MPC_XY_VEL_I_ACC": iv}, record["export"]["generic"]["rate_hz"],
                                 record["hover"])
        ms = np.asarray(loop_margins(ctrl, models).Ms, float)
        # the step and the wind by PX4's own law (its integral on P_xy e - v: no setpoint kick, which the PID form
        # ctrl has; E12, f9a5f96), scaled to ``wind``
        p = px4_xy_prediction({**values, "MPC_XY_VEL_I_ACC": iv}, models[0], record["export"]["generic"]["rate_hz"],
                              record["hover"])
        at = {5.0: wind * p["wind_offset_5s_m"], 20.0: wind * p["wind_offset_20s_m"]}
        rows.append({"I": iv, "Ms": float(ms[0]), "Ms_worst": float(ms.max()), "overshoot_pct": p["step_overshoot_pct"],
                     "settling_s": p["step_settling_s"], "wind_peak_m": wind * p["wind_peak_offset_m"],
                     "wind_5s_m": at[5.0], "wind_20s_m": at[20.0]})
        print(f"    MPC_XY_VEL_I_ACC {iv:g} (the rest as written): Ms {ms[0]:.3f} (worst over {len(models) - 1} draws "
              f"{ms.max():.3f}); unit step overshoot {p['step_overshoot_pct']:.1f} %, 2 % settling {p['step_settling_s']:.2f} s; a "
              f"{wind:g} m/s^2 wind step: peak {rows[-1]['wind_peak_m'] * 100:.1f} cm, after 5 s {at[5.0] * 100:.1f} cm, "
              f"after 20 s {at[20.0] * 100:.1f} cm")
    return rows


def run_xy_step(px4: Path, logs: Path, fly: bool, loop: str = "x", flight: str = "px4_x_h16",
                speedup: float = 1.0) -> dict[str, Any] | None:
    """Export ``loop`` from ``logs/flight.ulg`` and fly its steps (``fly``), or evaluate those flown before."""
    log, work = logs / f"{flight}.ulg", logs / "export"
    steps = work / f"{loop}_steps.ulg"
    if not log.exists() or not (fly or steps.exists()):
        return None
    params, record = export_xy(log, loop, work)
    if params is None:
        return None
    pred = predicted_xy_step(record, params)
    print(f"    the loop as written, a unit step on the identified model (Td {pred['model']['Td']:.3f} s, tau "
          f"{pred['model']['tau'] * 1e3:.1f} ms, K {pred['model']['K']:.2f}): overshoot {pred['overshoot_pct']:.1f} %, "
          f"rise {pred['rise_s']:.3f} s, 2 % settling {pred['settling_s']:.3f} s")
    integral_effect(record, params)
    flown: dict[str, Any] = {"log": steps, "step_m": 1.0, "dwell_s": 8.0}
    if fly:
        flown = fly_xy_steps(px4, params, work, loop, speedup=speedup)
        bad = [r for r in flown["rows"] if not r["unchanged"]]
        print(f"    parameters rejected or changed on read-back: {len(bad)} of {len(flown['rows'])}")
    return evaluate_xy_steps(flown, loop, pred)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--px4", type=Path, default=Path("/work/sitl/px4"))
    ap.add_argument("--logs", type=Path, required=True, help="folder with px4_x_h16.ulg / px4_y_h16.ulg")
    ap.add_argument("--loop", choices=("x", "y"), default="x")
    ap.add_argument("--flight", default=None, help="the MRFT flight to export from (default px4_<loop>_h16)")
    ap.add_argument("--evaluate-only", action="store_true", help="evaluate the steps flown before")
    a = ap.parse_args()
    res = run_xy_step(a.px4, a.logs, not a.evaluate_only, a.loop, a.flight or f"px4_{a.loop}_h16")
    raise SystemExit(0 if res is not None else 1)
