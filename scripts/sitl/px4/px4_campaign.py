"""The PX4 SITL campaign (issue 42): fly the fork's MRFT, analyse the ULogs, export, load, re-fly.

Run through ``benchmarks/bench_sitl.py --stack px4`` (which prints the figures); the ArduPilot
campaign's helpers are reused: ``sitl_analysis`` (tests found, held out).

1. build PX4 SITL with the MRFT port if needed (``build_px4.sh``);
2. fly the altitude MRFT at three betas, and again with MRFT_DELAY = 20 ms (the relay's output held
   20 ms inside mc_pos_control); keep the ULogs;
3. analyse each ULog as PX4 wrote it (``px4-mrft`` layout): tests found, held-out frequency, the
   +20 ms increment, Td / K beside what SIH's parameters imply;
4. ``tune --export px4`` (altitude), load the ``.params`` over MAVLink, read back, arm, take off, fly an
   altitude step in OFFBOARD (a true step of the position setpoint), compare with the prediction; the same
   for roll and pitch (``px4_rate_step.py``) and for x and y (``px4_xy_step.py``: PX4's velocity loop with
   ``MPC_XY_VEL_D_ACC``).
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from px4_sitl import SIH_MODEL, Px4Sitl, fly_mrft, load_params, read_qgc_params  # noqa: E402
from sitl import SitlError  # noqa: E402

from mrftcli.errors import MrftError  # noqa: E402
from miss_classes import classify, report_classes, totals  # noqa: E402
from sitl_analysis import analyze_log, held_out, test_lines  # noqa: E402

__all__ = ["FLIGHTS", "sih_implied", "fly_campaign", "analyse", "report", "export", "refly", "predicted_step",
           "run", "counted_errors", "held_out_jitter", "analyse_cascades", "px4_inner_gains", "relay_law_orbits", "estimate_error",
           "delay_increments"]

G = 9.80665
#: (name, loop, added delay [ms], [(beta, h), ...], each test's length [s]); h in normalised thrust.
#: The first pair at h 0.05 (the relay's switching drowned in EKF2's noise at low |beta|); the second at
#: h 0.15 (where the fixes were developed); the third, fresh, at h 0.25 (the published figures); x at h 0.08
_BETAS = (-0.2, -0.4, -0.6, -0.75)
FLIGHTS = [
    ("px4_altitude", "altitude", 0.0, [(-0.2, 0.05), (-0.4, 0.05), (-0.55, 0.05), (-0.7, 0.06)], 10.0),
    ("px4_altitude_20ms", "altitude", 20.0, [(-0.2, 0.05), (-0.4, 0.05), (-0.55, 0.05), (-0.7, 0.06)], 10.0),
    ("px4_altitude_h15", "altitude", 0.0, [(b, 0.15) for b in (-0.3, -0.45, -0.6, -0.75)], 12.0),
    ("px4_altitude_h15_20ms", "altitude", 20.0, [(b, 0.15) for b in (-0.3, -0.45, -0.6, -0.75)], 12.0),
    ("px4_altitude_h25", "altitude", 0.0, [(b, 0.25) for b in _BETAS], 12.0),
    ("px4_altitude_h25_20ms", "altitude", 20.0, [(b, 0.25) for b in _BETAS], 12.0),
    ("px4_x", "x", 0.0, [(b, 0.08) for b in (-0.3, -0.45, -0.6, -0.75)], 12.0),
    ("px4_roll", "roll", 0.0, [(b, 0.05) for b in (-0.3, -0.5, -0.7)], 10.0),  # mrft_roll.patch
    # the rate loops again with each stage of the path logged, at relay heights that keep the cycles well
    # above EKF2's attitude noise at every beta (roll amplitudes 5.7-12 deg); and y as x
    ("px4_roll_h", "roll", 0.0, [(-0.3, 0.1), (-0.5, 0.2), (-0.7, 0.3)], 10.0),
    ("px4_pitch_h", "pitch", 0.0, [(-0.3, 0.1), (-0.5, 0.2), (-0.7, 0.3)], 10.0),
    ("px4_roll_h_20ms", "roll", 20.0, [(-0.3, 0.1), (-0.5, 0.2), (-0.7, 0.3)], 10.0),
    ("px4_pitch_h_20ms", "pitch", 20.0, [(-0.3, 0.1), (-0.5, 0.2), (-0.7, 0.3)], 10.0),
    ("px4_y", "y", 0.0, [(b, 0.08) for b in (-0.3, -0.45, -0.6, -0.75)], 12.0),
    # x and y again with the attitude loops' rate D and I at 0 (FLIGHT_PARAMS): PX4's attitude controller is then
    # tune's generic form on the angle exactly (but the gyro filter), the cascade model's inner controller
    ("px4_x_pd", "x", 0.0, [(b, 0.08) for b in (-0.3, -0.45, -0.6, -0.75)], 12.0),
    ("px4_y_pd", "y", 0.0, [(b, 0.08) for b in (-0.3, -0.45, -0.6, -0.75)], 12.0),
    # x and y at twice the relay height (PX4's default gains): if the misses are the small cycles' irregular
    # switching on EKF2's estimate (as the altitude's were at h 0.05-0.15), their cycles spread less here
    ("px4_x_h16", "x", 0.0, [(b, 0.16) for b in (-0.3, -0.45, -0.6, -0.75)], 12.0),
    ("px4_y_h16", "y", 0.0, [(b, 0.16) for b in (-0.3, -0.45, -0.6, -0.75)], 12.0),
]
#: parameters set after boot for a flight (the rest fly PX4's defaults for airframe 10040)
_PD_ATTITUDE = {"MC_ROLLRATE_D": 0.0, "MC_ROLLRATE_I": 0.0, "MC_PITCHRATE_D": 0.0, "MC_PITCHRATE_I": 0.0}
FLIGHT_PARAMS: dict[str, dict[str, float]] = {"px4_x_pd": _PD_ATTITUDE, "px4_y_pd": _PD_ATTITUDE}
#: SIH's step [s]: 1 / min(IMU_GYRO_RATEMAX 800, IMU_INTEG_RATE 250) (sih.cpp ``lockstep_loop``)
SIH_DT = 0.004
#: SIH's own attitude (ground truth), beside EKF2's, for the rate loops
TRUTH_ATTITUDE = "vehicle_attitude_groundtruth:q"
#: the allocator's torque normalisation: SIH's motor combination (-u0 + u1 + u2 - u3) per unit of roll
#: torque setpoint, 2 sqrt(2) for airframe 10040's rotors at (+-1, +-1) (measured: actuator_outputs_sim /
#: vehicle_torque_setpoint = 2.83 in px4_roll_h)
ALLOCATOR_TORQUE = 2 * math.sqrt(2)
#: (without, with MRFT_DELAY) flight pairs for the delay increment
PAIRS = [("px4_altitude", "px4_altitude_20ms"), ("px4_altitude_h15", "px4_altitude_h15_20ms"),
         ("px4_altitude_h25", "px4_altitude_h25_20ms")]
#: the same for the rate loops (MRFT_DELAY on mc_rate_control's relays: 20 ms = 5 ticks of 4 ms, exact), on
#: SIH's own attitude at the bench Tp
RATE_PAIRS = [("px4_roll_h", "px4_roll_h_20ms"), ("px4_pitch_h", "px4_pitch_h_20ms")]
#: the flight whose export is loaded and flown
EXPORT_FROM = "px4_altitude_h25"


def sih_implied(loop: str, model: dict[str, float] = SIH_MODEL) -> dict[str, float]:
    """K [m/s^2 per unit thrust], Td [s] and Tp [s] that SIH's quadrotor implies (eq. (2)'s form).

    ``sih.cpp``: thrust ``T_MAX * sum(u_i)`` along body z, each ``u_i`` a first-order lag ``SIH_T_TAU`` of the
    motor command, linear drag ``-SIH_KDV v``; PX4's allocator gives each motor the collective thrust
    setpoint (THR_MDL_FAC 0: linear), so a unit of thrust accelerates ``4 T_MAX / MASS`` and the drag's
    time constant is ``MASS / KDV``. x and y add the attitude loop's lag, which eq. (2) does not hold.
    """
    if loop in ("roll", "pitch"):  # damper -SIH_KDW w; torque L T_MAX (motors); pitch = roll in airframe 10040
        return {"K": model["SIH_L_ROLL"] * model["SIH_T_MAX"] * ALLOCATOR_TORQUE / model["SIH_IXX"],
                "Td": model["SIH_IXX"] / model.get("SIH_KDW", 0.025), "Tp": model["SIH_T_TAU"]}
    if loop not in ("altitude", "x", "y"):
        raise ValueError(f"loop must be altitude, x, y, roll or pitch, not {loop!r}")
    return {"K": 4 * model["SIH_T_MAX"] / model["SIH_MASS"], "Td": model["SIH_MASS"] / model["SIH_KDV"],
            "Tp": model["SIH_T_TAU"]}


def bench_tp(model: dict[str, float] = SIH_MODEL, dt: float = SIH_DT) -> float:
    """The motor lag [s] a bench test on SIH would measure.

    ``sih.cpp`` (``read_motors``) steps each motor ``u += dt / SIH_T_TAU (u_sp - u)`` once per step, from
    the step that first reads the command: a command step's response is ``1 - (1 - dt / T_TAU)^k`` at
    ``t = k dt``, an exponential of time constant ``-dt / ln(1 - dt / T_TAU)``, with no dead time.

    Examples
    --------
    >>> round(bench_tp() * 1e3, 2)
    47.97
    """
    return -dt / math.log(1.0 - dt / model["SIH_T_TAU"])


def _ulog_rate(log: Path, topic: str = "vehicle_local_position_setpoint") -> float:
    """Median publication rate [Hz] of a topic in a ULog (mc_pos_control's rate for the setpoint)."""
    from mrftcli.io import open_log

    with open_log(log, echo_warnings=False) as src:
        t, _ = src.read(topic, ["z"])
    return float(1.0 / np.median(np.diff(t)))


def _hover(log: Path) -> float:
    """Hover thrust PX4 estimated during the flight (median of the valid hover_thrust_estimate samples)."""
    from mrftcli.io import open_log

    with open_log(log, echo_warnings=False) as src:
        _, d = src.read("hover_thrust_estimate", ["hover_thrust", "valid"])
    ok = (d["valid"] > 0) & np.isfinite(d["hover_thrust"])
    return float(np.median(d["hover_thrust"][ok]))


def realised_delay(log: Path, h: float, decision: tuple[str, str] = ("vehicle_local_position_setpoint", "thrust[2]"),
                   applied: tuple[str, str] = ("vehicle_attitude_setpoint", "thrust_body[2]")) -> str:
    """The delay between the relays' decision (by default the logged setpoint's thrust) and what reached the
    controller below (the attitude setpoint's collective thrust), switch by switch [ms]; "" when not logged.
    The rate relays: ``("debug_vect", "x" | "y")`` and ``("vehicle_torque_setpoint", "xyz[0]" | "xyz[1]")``."""
    from mrftcli.io import open_log

    with open_log(log, echo_warnings=False) as src:
        if not any(t.name == applied[0] for t in src.topics()):
            return ""
        td, d = src.read(decision[0], [decision[1]])
        ta, a = src.read(applied[0], [applied[1]])
    jump_d = np.flatnonzero(np.abs(np.diff(d[decision[1]])) > h) + 1
    jump_a = np.flatnonzero(np.abs(np.diff(a[applied[1]])) > h) + 1
    t_a = ta[jump_a]
    lags = [float(t_a[t_a >= t][0] - t) for t in td[jump_d] if (t_a >= t).any() and t_a[t_a >= t][0] - t < 0.2]
    if not lags:
        return "no switch found in vehicle_attitude_setpoint"
    return (f"{np.median(lags) * 1e3:.1f} ms median ({np.min(lags) * 1e3:.1f}-{np.max(lags) * 1e3:.1f}) over "
            f"{len(lags)} switches")


def fly_campaign(px4: Path, logs: Path, speedup: float, only: list[str]) -> None:
    logs.mkdir(parents=True, exist_ok=True)
    for name, loop, delay, tests, duration in FLIGHTS:
        if only and name not in only:
            continue
        out = logs / f"{name}.ulg"
        if out.exists():
            print(f"  {name}: {out} exists, not re-flown")
            continue
        t0 = time.monotonic()
        info = fly_mrft(px4, Path(f"/tmp/mrft_px4_{name}"), loop, tests, delay, duration, speedup,
                        extra=FLIGHT_PARAMS.get(name))
        shutil.copy(info.pop("log"), out)
        # how this run's EKF2 fell in PX4's lockstep: its estimate published 0 or one SIH step after its sample, a
        # latency inside the loop that differs from run to run (docs/benchmarks/sitl.md, the +20 ms pairs)
        info["estimate_latency_ms"] = {topic: round(_publish_latency(out, topic) * 1e3, 3)
                                       for topic in ("vehicle_local_position", "vehicle_attitude")}
        Path(f"{out}.json").write_text(json.dumps(info, indent=2) + "\n")
        print(f"  {name}: flown in {time.monotonic() - t0:.0f} s wall, {out.stat().st_size / 1e6:.2f} MB; EKF2 published "
              f"{info['estimate_latency_ms']['vehicle_local_position']:g} ms after its sample")


def analyse(logs: Path) -> dict[str, dict[str, Any]]:
    results: dict[str, dict[str, Any]] = {}
    for name, loop, delay, tests, _ in FLIGHTS:
        log = logs / f"{name}.ulg"
        if not log.exists():
            continue
        side = json.loads(Path(f"{log}.json").read_text())
        tp = side["tp_s"]
        if loop in ("roll", "pitch"):
            results[name] = analyse_rate(name, log, side, delay)
            continue
        try:
            res = analyze_log(log, tp, loop)
        except MrftError as err:  # a refusal is a result: every flown test counts as a miss
            print(f"  {name:18s} REFUSED: {err}")
            results[name] = {"loop": loop, "delay": delay, "flown": len(side["tests"]), "found": 0, "held": [],
                             "held_misses": [(i, str(err)) for i in range(len(side["tests"]))], "refused": str(err)}
            continue
        # the MRFT estimate (refine=False): analyze refuses the waveform refinement on these logs (SIH noise)
        misses: list[tuple[int, str]] = []
        held = held_out(log, tp, loop, res, refine=False, misses=misses) if len(res.tests) >= 3 else []
        implied = sih_implied(loop)
        results[name] = {"loop": loop, "delay": delay, "flown": len(side["tests"]), "found": len(res.tests),
                         "Td": res.Td.value, "tau": res.tau.value, "K": res.K.value, "tp": tp, "implied": implied,
                         "held": held, "held_misses": misses, "tests": res.tests, "log": log, "hover": _hover(log),
                         "rate_hz": _ulog_rate(log)}
        print(f"  {name:18s} tests {len(res.tests)}/{len(side['tests'])}  Td {res.Td.value:.3f} s  "
              f"tau {res.tau.value * 1e3:.2f} ms  K {res.K.value:.2f}   (SIH: Td {implied['Td']:.3f} s, "
              f"K {implied['K']:.2f}, Tp {tp * 1e3:.1f} ms; mc_pos_control at {results[name]['rate_hz']:.1f} Hz)")
        delay = realised_delay(log, 0.5 * min(t["h"] for t in side["tests"]))
        if delay:
            print(f"      decision -> attitude setpoint (MRFT_DELAY {side['added_delay_ms']:g} ms): {delay}")
        for line in test_lines(res, held):
            print(line)
        for i, why in misses:
            print(f"      held out beta {res.tests[i].beta_nominal:+.2f}: MISS (the other tests refused: {why[:160]})")
        results[name]["jitter"] = held_out_jitter(res)
        for row, ekf in zip(results[name]["jitter"], estimate_error(log, loop, res.tests)):
            row["ekf"] = ekf
        for row in results[name]["jitter"]:
            print(f"      beta {row['beta']:+.2f}: cycle-to-cycle frequency spread {row['spread'] * 100:.1f} % over "
                  f"{row['n']} cycles (standard error of the mean {row['sem'] * 100:.1f} %); lag beyond eq. (2) at SIH's "
                  f"Tp and Td {row['lag_ms']:+.1f} ms; analyze's own held-out "
                  + (f"{row['error'] * 100:+.1f} %, {row['z']:+.1f} of its stated std" if row["z"] is not None
                     else "none")
                  + (f"; EKF2's {loop} against SIH's at this frequency: lag {row['ekf']['lag_ms']:+.1f} ms, gain "
                     f"{row['ekf']['gain']:.3f}, their difference in the cycle's band {row['ekf']['band'] * 100:.0f} % of "
                     "the amplitude" if "ekf" in row else ""))
    analyse_cascades(results)
    return results


#: the lateral loops and the attitude loop each goes through (x: pitch, y: roll), flown without a delay
CASCADES = (("px4_x", "px4_pitch_h"), ("px4_y", "px4_roll_h"), ("px4_x_pd", "px4_pitch_h"), ("px4_y_pd", "px4_roll_h"),
            ("px4_x_h16", "px4_pitch_h"), ("px4_y_h16", "px4_roll_h"))


def px4_inner_gains(log: Path, axis: str) -> tuple[Any, str]:
    """PX4's attitude loop as the ULog's parameters set it, in tune's generic form on the angle, and what that
    form leaves out.

    ``mc_att_control``: rate setpoint = ``MC_{AX}_P`` e; ``rate_control.cpp``: torque = K (P e_r + I int e_r -
    D d(rate)/dt), e_r = rate setpoint - rate, the rate through ``IMU_GYRO_CUTOFF``: on the angle that is
    Kp = K P P_att + K I, Ki = K I P_att, Kd = K P (``tune.stacks``' mapping, as tune exports it), at
    ``IMU_INTEG_RATE`` (the attitude loop's rate; SIH steps the rate loop at the same 250 Hz).
    """
    from pyulog import ULog

    from mrftcli.mrft.controller import Controller

    p = ULog(str(log), [], False).initial_parameters
    ax = axis.upper()
    k, pa = p[f"MC_{ax}RATE_K"], p[f"MC_{ax}_P"]
    pr, ir = k * p[f"MC_{ax}RATE_P"], k * p[f"MC_{ax}RATE_I"]
    c = Controller(Kp=pr * pa + ir, Ki=ir * pa, Kd=pr, Tf=1.0 / (2 * math.pi * p["IMU_GYRO_CUTOFF"]),
                   rate_hz=float(p["IMU_INTEG_RATE"]))
    rd = k * p[f"MC_{ax}RATE_D"]
    left = (f"left out: MC_{ax}RATE_D {rd:g} (a derivative of the rate through IMU_DGYRO_CUTOFF "
            f"{p['IMU_DGYRO_CUTOFF']:g} Hz), and the rate integral's share K I = {ir:g} of Kp acts on the measured angle "
            "only in PX4 (on the error here); " if rd or ir else "MC_*RATE_D and _I 0: PX4's form exactly, but ")
    left += f"the gyro filter (2nd order, {p['IMU_GYRO_CUTOFF']:g} Hz) as Tf"
    return c, left


def analyse_cascades(results: dict[str, dict[str, Any]]) -> None:
    """x and y through the closed attitude loop (``analyze --loop x --inner-model --inner-gains``, docs/cascade.md):
    the inner model the pitch / roll flight's on SIH's attitude at the bench Tp, the inner gains PX4's from the
    flight's own parameters, K identified (the relay commands a thrust, PX4 tilts by thrust / hover thrust); each
    test's frequency held out from the other tests' cascade, at its nominal beta under the 125 Hz relay."""
    from mrftcli.analyze import AnalyzeOptions, CascadeOptions, analyze_flight
    from mrftcli.analyze.cascade import cascade_model, inner_loop_of
    from mrftcli.analyze.general import mask_windows
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.lprs import mrft_limit_cycle
    from sitl_analysis import _marked_start

    opts = AnalyzeOptions(n_bootstrap=50, seed=0, refine_waveform=False, cascade=CascadeOptions())
    for name, inner_name in CASCADES:
        r, inner = results.get(name), results.get(inner_name, {}).get("truth", {}).get("result")
        if r is None or "log" not in r or inner is None:
            continue
        gains, left = px4_inner_gains(r["log"], inner.loop)
        model = cascade_model(inner_loop_of(inner, gains, inner.loop), "identify")
        flight = read_flight(r["log"], ReadOptions(loop=r["loop"]), echo_warnings=False)
        try:
            full = analyze_flight(flight, model, options=opts)
        except MrftError as err:
            print(f"  {name} through the closed {inner.loop} loop: REFUSED: {err}")
            r["cascade"] = {"held": [], "flown": r["flown"]}
            continue
        errs = []
        for i, t in enumerate(full.tests):
            others = [(_marked_start(flight, u.t_start), u.t_end) for j, u in enumerate(full.tests) if j != i]
            try:
                res = analyze_flight(mask_windows(flight, others), model, options=opts)
            except MrftError:
                continue
            f = mrft_limit_cycle(res.model, t.beta_nominal, t.h, full.controller_rate_hz).frequency_hz
            errs.append(f / t.frequency_hz_mean - 1.0)
        r["cascade"] = {"held": errs, "flown": r["flown"], "Td": full.Td.value, "tau": full.tau.value, "K": full.K.value}
        print(f"  {name} through the closed {inner.loop} loop (cascade; inner: {inner_name} on SIH's attitude, Td "
              f"{inner.Td.value:.3f} s, tau {inner.tau.value * 1e3:.2f} ms, K {inner.K.value:.1f}; PX4's gains Kp {gains.Kp:.4g}, "
              f"Ki {gains.Ki:.4g}, Kd {gains.Kd:.4g}, Tf {gains.Tf * 1e3:.1f} ms at {gains.rate_hz:g} Hz; {left}): tests "
              f"{len(full.tests)}/{r['flown']}  Td {full.Td.value:.3f} s  tau {full.tau.value * 1e3:.1f} ms  K {full.K.value:.2f} "
              f"(g / hover {G / r['hover']:.2f}); held out " + ", ".join(f"{e * 100:+.2f} %" for e in errs))


def estimate_error(log: Path, loop: str, tests: Any) -> list[dict[str, float]]:
    """EKF2's position (what the relay switches on) against SIH's own (``vehicle_local_position_groundtruth``) over
    each test: at the test's frequency, EKF2's lag [ms] (negative: a lead) and gain over SIH's (the fundamentals'
    ratio); and the difference's standard deviation once its slow part (a one-period moving average) is removed, over
    the test's amplitude [-]. Empty when SIH's is not logged."""
    from mrftcli.io import open_log

    ax = {"altitude": "z", "x": "x", "y": "y"}[loop]
    with open_log(log, echo_warnings=False) as src:
        if "vehicle_local_position_groundtruth" not in {t.name for t in src.topics()}:
            return []
        te, e = src.read("vehicle_local_position", [ax])
        tg, g = src.read("vehicle_local_position_groundtruth", [ax])
    truth = np.interp(te, tg, g[ax])
    out = []
    for t in tests:
        sel = (te > t.t_start) & (te < t.t_end)
        w = 2 * math.pi * t.frequency_hz_mean
        basis = np.c_[np.sin(w * te[sel]), np.cos(w * te[sel]), np.ones(sel.sum()), te[sel] - te[sel].mean()]
        ce, ct = (np.linalg.lstsq(basis, v[sel], rcond=None)[0] for v in (e[ax], truth))
        ratio = complex(ce[0], ce[1]) / complex(ct[0], ct[1])
        n = max(1, int(round(2 * math.pi / w / float(np.median(np.diff(te[sel]))))))
        d = e[ax][sel] - truth[sel]
        band = (d - np.convolve(d, np.ones(n) / n, mode="same"))[n:-n]
        out.append({"lag_ms": float(np.angle(ratio)) / w * 1e3 * -1.0, "gain": abs(ratio),
                    "band": float(np.std(band)) / t.amplitude_mean if band.size else math.nan})
    return out


def held_out_jitter(res: Any) -> list[dict[str, Any]]:
    """Each test's cycle-to-cycle frequency spread and the standard error of its mean frequency [-], beside
    analyze's own held-out error [-] and its z (error over the std analyze states: the other tests' standard
    errors propagated and this test's own). A held-out miss whose test's mean frequency is itself uncertain by
    several percent is a miss of the measurement, not of the model: the relay switches on EKF2's estimate."""
    rows = []
    for k, t in enumerate(res.tests):
        f = 1.0 / np.array([c.period for c in t.stable])
        spread = float(np.std(f, ddof=1) / np.mean(f)) if f.size > 1 else math.nan
        ho = res.held_out_of(k)
        ok = ho is not None and ho.frequency_hz
        rows.append({"beta": t.beta_nominal, "n": int(f.size), "spread": spread, "sem": spread / math.sqrt(f.size),
                     "error": ho.frequency_hz / t.frequency_hz_mean - 1.0 if ok else None,
                     "z": ho.frequency_z if ok else None, "lag_ms": _lag_beyond_sih(t, res.loop)})
    return rows


def _lag_beyond_sih(test: Any, loop: str) -> float:
    """The loop's lag [ms] beyond eq. (2) at SIH's own Tp (the bench Tp), Td and no delay, at the test's
    frequency: from the phase of its cycles' fundamental (``RelayCycle.phase_h1``, the tool's measurement)."""
    phases = np.array([c.phase_h1 for c in test.stable], float)
    if not np.isfinite(phases).any():
        return math.nan
    w = 2 * math.pi * test.frequency_hz_mean
    sih = sih_implied(loop)
    eq2 = -math.pi / 2 - math.atan(w * bench_tp()) - math.atan(w * sih["Td"])
    return float((eq2 - np.nanmean(phases)) / w * 1e3)


def _rate_fit(log: Path, loop: str, tp: float, output_topic: str | None, command_topic: str | None
              ) -> tuple[Any, list[float]]:
    """eq. (2) at ``tp`` on a roll / pitch flight (the MRFT estimate) and analyze's own held-out errors."""
    from mrftcli.analyze import AnalyzeOptions, analyze_flight
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.model import soiptd_model

    flight = read_flight(log, ReadOptions(loop=loop, output_topic=output_topic, command_topic=command_topic),
                         echo_warnings=False)
    res = analyze_flight(flight, soiptd_model(tp), options=AnalyzeOptions(n_bootstrap=50, seed=0,
                                                                          refine_waveform=False))
    held = [(t.frequency_hz_mean, h.frequency_hz) for k, t in enumerate(res.tests)
            if (h := res.held_out_of(k)) is not None and h.frequency_hz]
    return res, [p / m - 1.0 for m, p in held]


def _logged_topics(log: Path) -> set[str]:
    from mrftcli.io import open_log

    with open_log(log, echo_warnings=False) as src:
        return {t.name for t in src.topics()}


def analyse_rate(name: str, log: Path, side: dict[str, Any], delay: float) -> dict[str, Any]:
    """A roll / pitch flight: on EKF2's attitude (the relay's) at SIH_T_TAU, and on SIH's own attitude at
    the bench Tp (:func:`bench_tp`), the command the relays' decision before MRFT_DELAY where logged
    (``decision_topic``; without it, the torque: the same when no delay is added); where the lag of its
    path goes (``rate_path.py``) when the stages are logged. Printed, and returned."""
    from rate_path import stage_lags

    loop, command = side["loop"], side.get("decision_topic")
    implied = sih_implied(loop)
    if command:
        axis = "0" if loop == "roll" else "1"
        topic, field = command.split(":")
        realised = realised_delay(log, 0.5 * min(t["h"] for t in side["tests"]), (topic, field),
                                  ("vehicle_torque_setpoint", f"xyz[{axis}]"))
        print(f"      decision ({command}) -> torque setpoint (MRFT_DELAY {side['added_delay_ms']:g} ms): {realised}")
    out: dict[str, Any] = {"loop": loop, "delay": delay, "flown": len(side["tests"]), "found": 0, "held": [],
                           "held_misses": []}
    try:
        res, errs = _rate_fit(log, loop, side["tp_s"], None, command)
        out.update(found=len(res.tests), tau=res.tau.value, held_rate=errs, jitter=held_out_jitter(res))
        print(f"  {name:18s} tests {len(res.tests)}/{len(side['tests'])}  Td {res.Td.value:.3f} s  tau "
              f"{res.tau.value * 1e3:.2f} ms  K {res.K.value:.1f} on EKF2's attitude at Tp {side['tp_s'] * 1e3:g} ms; "
              "held out " + ", ".join(f"{e * 100:+.2f} %" for e in errs))
    except MrftError as err:  # every flown test a miss
        print(f"  {name:18s} REFUSED on EKF2's attitude at Tp {side['tp_s'] * 1e3:g} ms: {err}")
        out.update(refused=str(err), held_misses=[(i, str(err)) for i in range(len(side["tests"]))])
    tp = bench_tp()
    truth: dict[str, Any] = {"tp": tp}
    if TRUTH_ATTITUDE.split(":")[0] not in _logged_topics(log):
        print(f"      SIH's attitude not logged (a flight before {TRUTH_ATTITUDE.split(':')[0]} was)")
        return out
    out["truth"] = truth
    try:
        res, errs = _rate_fit(log, loop, tp, TRUTH_ATTITUDE, command)
    except MrftError as err:
        print(f"      on SIH's attitude at the bench Tp {tp * 1e3:.2f} ms: REFUSED: {err}")
        truth["refused"] = str(err)
        return out
    truth.update(Td=res.Td.value, tau=res.tau.value, K=res.K.value, held=errs, found=len(res.tests), result=res)
    print(f"      on SIH's attitude ({TRUTH_ATTITUDE}) at the bench Tp {tp * 1e3:.2f} ms (sih.cpp's motor step): "
          f"tests {len(res.tests)}/{len(side['tests'])}  Td {res.Td.value:.3f} s  tau {res.tau.value * 1e3:.2f} ms  "
          f"K {res.K.value:.1f}   (SIH: Td {implied['Td']:.3f} s, K {implied['K']:.1f}); analyze's held-out "
          "frequencies " + ", ".join(f"{e * 100:+.2f} %" for e in errs)
          + (f"; command {command}" if command else ""))
    if delay:  # the stages are of the relay's own loop; with a delay the torque is not the decision
        return out
    try:
        rows = stage_lags(log, loop, implied["Tp"], implied["Td"])
    except KeyError:  # a flight without the stages logged
        return out
    for row in rows:
        lag = row["lag_ms"]
        print(f"      beta {row['beta']:+.2f} at {row['f_hz']:.2f} Hz, lag beyond eq. (2) at Tp 50 ms, Td 1 s [ms]: "
              f"allocator {lag['c->m']:+.2f}, SIH's motors and body {lag['m->p_true']:+.2f}, SIH's attitude "
              f"{lag['p_true->phi_true']:+.2f} (the path to SIH's attitude {lag['c->m'] + lag['m->p_true'] + lag['p_true->phi_true']:+.2f}; "
              f"sih.cpp's update order: {row['sih_discrete_ms']:+.2f}), EKF2's against SIH's {lag['phi_true->phi_ekf']:+.2f}; "
              f"the relay's path {lag['c->phi_ekf']:+.2f}")
    truth["stages"] = rows
    return out


def counted_errors(r: dict[str, Any]) -> list[float]:
    """A flight's held-out errors [-], one per flown test: a refusal, a test not found and a test left without a
    prediction (fewer than three found) each count as a miss (inf)."""
    errs = [abs(h.error) for h in r["held"]] + [abs(e) for e in r.get("held_rate", [])]
    return errs + [math.inf] * max(0, r["flown"] - len(errs))


def report(results: dict[str, dict[str, Any]]) -> None:
    errs = [e for r in results.values() for e in counted_errors(r)]
    print(f"tests found: {sum(r['found'] for r in results.values())}/{sum(r['flown'] for r in results.values())}")
    if errs:
        print(f"held-out frequency error (every flown test; refused, not found or not predicted: inf): max "
              f"{max(errs) * 100:.2f} %, median {np.median(errs) * 100:.2f} %, "
              f"within 5 %: {sum(e <= 0.05 for e in errs)}/{len(errs)}")
        classes = classify(results, {name: max(h for _, h in tests) for name, _, _, tests, _ in FLIGHTS})
        _report_misses(results, totals(classes))
        report_classes(classes)
        lateral = [k for k, _ in CASCADES if "cascade" in results.get(k, {})]
        if lateral:
            alt = [e for k, r in results.items() if k not in lateral for e in counted_errors(r)]
            alt += [e for k in lateral for e in counted_errors({"flown": results[k]["flown"], "held": [],
                                                                   "held_rate": results[k]["cascade"]["held"]})]
            print(f"the same with {', '.join(lateral)} through the closed attitude loop (the cascade model, "
                  f"docs/cascade.md, instead of eq. (2)): within 5 %: {sum(e <= 0.05 for e in alt)}/{len(alt)}")
    truth = [e for r in results.values() for e in r.get("truth", {}).get("held", [])]
    refused = [k for k, r in results.items() if "refused" in r.get("truth", {})]
    if truth or refused:
        print(f"roll / pitch on SIH's attitude at the bench Tp {bench_tp() * 1e3:.2f} ms: held out within 5 %: "
              f"{sum(abs(e) <= 0.05 for e in truth)}/{len(truth)} (max {max(map(abs, truth), default=0) * 100:.2f} %)"
              + (f"; refused: {', '.join(refused)}" if refused else ""))
    if EXPORT_FROM in results and "tests" in results[EXPORT_FROM]:
        rows = relay_law_orbits(results[EXPORT_FROM])
        print(f"the fork's relay (N_CONF 5, 20 ms guard) and the plain sampled MRFT tick by tick on {EXPORT_FROM}'s "
              "eq. (2), no noise: " + "; ".join(
                  f"beta {r['beta']:+.2f}: {r['fork']:.4f} / {r['plain']:.4f} Hz (centre {r['centre']:.4f}, "
                  f"{(r['fork'] / r['centre'] - 1) * 100:+.2f} %; nearest orbit "
                  f"{_nearest(r['orbits'], r['fork']):.4f})" for r in rows))


def _report_misses(results: dict[str, dict[str, Any]], counts: dict[str, int]) -> None:
    """Why the held-out misses miss: refused, not found, or over 5 % (``counts``: every flown test's outcome,
    ``miss_classes.totals``; each over-5 % eq. (2) test with the spread of its own cycles' frequencies and
    analyze's z, the error over the std it states)."""
    over = [(k, h) for k, r in results.items() for h in r["held"] if abs(h.error) > 0.05]
    print(f"  the misses: {counts.get('refused', 0)} refused (eq. (2) at the known Tp), "
          f"{counts.get('not found', 0)} not found, {counts.get('not predicted', 0)} found but not predicted (the "
          f"other tests refused or too few), {counts.get('over', 0)} predicted more than 5 % off")
    rows = []
    for k, h in over:
        j = results[k]["jitter"][h.index]
        rows.append(j)
        print(f"    {k} beta {h.beta:+.2f}: {h.error * 100:+.1f} %; its cycles' frequencies spread {j['spread'] * 100:.1f} % "
              f"(mean's standard error {j['sem'] * 100:.1f} %); analyze's held-out "
              + (f"{j['error'] * 100:+.1f} %, z {j['z']:+.1f}" if j["z"] is not None else "none"))
    zs = [abs(j["z"]) for j in rows if j["z"] is not None]
    hits = [results[k]["jitter"][h.index] for k, r in results.items() for h in r["held"] if abs(h.error) <= 0.05]
    if rows:
        print(f"  those {len(rows)}: within 2.5 std of analyze's stated held-out uncertainty "
              f"{sum(z <= 2.5 for z in zs)}/{len(rows)} (max |z| {max(zs, default=math.nan):.2f}); median cycle-to-cycle "
              f"frequency spread {np.median([j['spread'] for j in rows]) * 100:.1f} % against "
              f"{np.median([j['spread'] for j in hits]) * 100:.1f} % for the {len(hits)} within 5 %")


def _nearest(values: list[float], x: float) -> float:
    """The value nearest ``x`` (NaN for none)."""
    return min(values, key=lambda v: abs(v - x)) if values else math.nan


def relay_law_orbits(result: dict[str, Any], seconds: float = 30.0, sub: int = 16) -> list[dict[str, Any]]:
    """The fork's relay (``MRFT_Block``: peak confirmation over ``MRFT_*_N_CONF`` 5 samples, a 20 ms no-switch
    guard; ``mrftcli.sim.control.HearMrftRelay``) and the plain sampled MRFT, each run tick by tick at the log's
    rate on the identified eq. (2) (exact zero-order-hold steps ``sub`` times a tick, the delay in whole steps,
    no noise), against the admissible sampled orbits ``mrft_limit_cycle`` predicts at each flown beta and h:
    the frequency each relay settles to [Hz] (the second half of ``seconds``), the predicted centre and orbits."""
    from scipy.signal import cont2discrete, tf2ss

    from mrftcli.mrft.lprs import mrft_limit_cycle
    from mrftcli.mrft.model import LoopModel
    from mrftcli.mrft.relays import MrftRelay
    from mrftcli.sim.control import HearMrftRelay

    tp, Td, tau, K, rate = result["tp"], result["Td"], result["tau"], result["K"], result["rate_hz"]
    A, B, C, _ = tf2ss([K], np.polymul([1.0, 0.0], np.polymul([tp, 1.0], [Td, 1.0])))
    dt = 1.0 / rate / sub
    Ad, Bd, Cd, _, _ = cont2discrete((A, B, C, np.zeros((1, 1))), dt)

    def settle(relay: Any, h: float) -> float:
        x, line = np.zeros((A.shape[0], 1)), [0.0] * (int(round(tau / dt)) + 1)
        u = last = relay.start(1e-3)
        ups = []
        for k in range(int(seconds * rate)):
            u = relay.step(-float((Cd @ x)[0, 0]))
            if u > last:
                ups.append(k / rate)
            last = u
            for _ in range(sub):
                line.append(h * u)
                x = Ad @ x + Bd * line.pop(0)
        t = np.array(ups)
        t = t[t > seconds / 2]
        return float(1.0 / np.mean(np.diff(t))) if t.size > 2 else math.nan

    rows = []
    for t in result["tests"]:
        cycle = mrft_limit_cycle(LoopModel(tp, Td, tau, K), t.beta_nominal, t.h, rate)
        rows.append({"beta": t.beta_nominal, "fork": settle(HearMrftRelay(t.beta_nominal, 5, 0.02 * rate), t.h),
                     "plain": settle(MrftRelay(t.beta_nominal), t.h), "centre": cycle.frequency_hz,
                     "orbits": sorted(cycle.orbits_hz)})
    return rows


#: the delay each pair's after-flight realised [s]: mc_pos_control's ring (125 Hz) hands on the first output at
#: least 20 ms old, 3 ticks of 8 ms (logged: 24.0 ms at every switch); mc_rate_control's 5 ticks of 4 ms (20.0 ms)
REALISED_S = {"altitude": 0.024, "roll": 0.020, "pitch": 0.020}


def _delay_cases(logs: Path) -> list[tuple[str, str, str, str, float, list[str], str]]:
    """(label, before, after, loop, Tp [s], extra read options, the separately-fitted increment's key) of every PX4 pair whose
    two ULogs are in ``logs``: altitude on EKF2's altitude at SIH_T_TAU, roll and pitch on SIH's attitude at the
    bench Tp and on EKF2's attitude at SIH_T_TAU (both flights read with the same options: the command is the
    torque setpoint, which the after-flight's relay decided 20 ms before)."""
    cases = []
    for before, after in PAIRS + RATE_PAIRS:
        if not all((logs / f"{n}.ulg").exists() for n in (before, after)):
            continue
        side = json.loads((logs / f"{after}.ulg.json").read_text())
        if side["loop"] in ("roll", "pitch"):
            cases.append((f"{before} on SIH's attitude", before, after, side["loop"], bench_tp(),
                          ["--output-topic", TRUTH_ATTITUDE], "truth"))
        cases.append((before + (" on EKF2's attitude" if side["loop"] in ("roll", "pitch") else ""), before, after,
                      side["loop"], side["tp_s"], [], "ekf"))
    return cases


def delay_increments(logs: Path, results: dict[str, dict[str, Any]] | None = None) -> None:
    """The +20 ms increment of every pair as a user measures it: ``mrft-ident delay BEFORE AFTER --tp --loop
    --json -`` (``mrftcli/compare/delay.py``: one plant, one Td and K, a delay each), against the delay PX4
    realised, beside the two flights fitted separately (``results``, when given: their taus' difference).

    Two references: the delay the firmware realised (its delay line: :data:`REALISED_S`), and the change of the
    loop the relay switches on: on EKF2's output, that plus the change of EKF2's publication latency
    (:func:`_publish_latency`: PX4 published the estimate one SIH step after its sample in some flights), checked on
    the rate pairs against SIH's truth (:func:`_estimator_shift`)."""
    from mrftcli.compare.delay import DelayIncrement

    errors, loop_errors, covered, loop_covered, n = [], [], 0, 0, 0
    for label, before, after, loop, tp, extra, key in _delay_cases(logs):
        realised = REALISED_S[loop]
        n += 1
        proc = _cli("delay", str(logs / f"{before}.ulg"), str(logs / f"{after}.ulg"), "--tp", f"{tp:.6f}",
                    "--loop", loop, *extra, "--json", "-", "-q")
        separate = _separate_increment(results or {}, before, after, key, realised)
        if proc.returncode != 0:
            print(f"  {label}: mrft-ident delay refused (exit {proc.returncode}): "
                  f"{(proc.stderr.strip().splitlines() or [''])[-1]}: a miss" + separate)
            continue
        r = DelayIncrement.from_json(json.loads(proc.stdout))
        inc = r.increment
        # the output the relay switches on: EKF2's (its publication latency is in the loop) or SIH's truth (where
        # the latency moves the switches against the output: the effective beta, not tau)
        latency = [_publish_latency(logs / f"{name}.ulg", _SWITCHED_ON[loop]) for name in (before, after)] if key == "ekf" \
            else None
        shift = latency[1] - latency[0] if latency else 0.0
        changed = realised + shift
        errors.append(inc.value - realised)
        loop_errors.append(inc.value - changed)
        covered += int(inc.ci95_low <= realised <= inc.ci95_high)
        loop_covered += int(inc.ci95_low <= changed <= inc.ci95_high)
        check = _estimator_shift(logs, before, after, loop) if latency else None
        loop_line = ("" if not latency else
                     f"\n      the loop's change: {realised * 1e3:.1f} ms in the firmware {shift * 1e3:+.1f} ms of EKF2's "
                     f"publication latency ({_SWITCHED_ON[loop]} timestamp - timestamp_sample: {latency[0] * 1e3:.1f} -> "
                     f"{latency[1] * 1e3:.1f} ms) = {changed * 1e3:.1f} ms: {(inc.value - changed) * 1e3:+.2f} ms"
                     + ("" if check is None else f" (EKF2's attitude against SIH's, rate_path.py: {check * 1e3:+.2f} ms)"))
        print(f"  {label} (Tp {tp * 1e3:.2f} ms): +20 ms by mrft-ident delay {inc.value * 1e3:.2f} ± "
              f"{inc.std * 1e3:.2f} ms (95 %: {inc.ci95_low * 1e3:.2f} to {inc.ci95_high * 1e3:.2f}; "
              f"{(inc.value - realised) * 1e3:+.2f} ms from the {realised * 1e3:.1f} ms realised); one Td "
              f"{r.Td.value:.3f} s, K {r.K.value:.4g}, tau {r.tau_before.value * 1e3:.2f} / "
              f"{r.tau_after.value * 1e3:.2f} ms; model scatter {r.model_scatter * 100:.2g} % (chi^2 {r.chi2:.3g} on "
              f"{r.dof})" + separate + loop_line + "".join(f"\n      note: {note}" for note in r.notes))
    if n:
        print(f"+20 ms by mrft-ident delay, every PX4 pair: {sum(abs(e) <= 0.002 for e in errors)}/{n} within 2 ms of "
              f"the delay realised (max error {max(map(abs, errors), default=math.nan) * 1e3:.2f} ms; a refusal is a "
              f"miss), the realised delay inside the stated 95 % interval in {covered}/{n}; against the loop's change "
              f"(EKF2's publication latency's change added on EKF2's output): {sum(abs(e) <= 0.002 for e in loop_errors)}/{n} "
              f"within 2 ms (max {max(map(abs, loop_errors), default=math.nan) * 1e3:.2f} ms), inside the interval "
              f"in {loop_covered}/{n}")


#: the estimate each loop's relay switches on (its latency is in the loop when the output read is EKF2's)
_SWITCHED_ON = {"altitude": "vehicle_local_position", "x": "vehicle_local_position", "y": "vehicle_local_position",
                "roll": "vehicle_attitude", "pitch": "vehicle_attitude"}


def _publish_latency(log: Path, topic: str = "vehicle_attitude") -> float:
    """The median of ``timestamp - timestamp_sample`` of ``topic`` [s]: how long after its IMU sample PX4 published
    the estimate (0 when EKF2 runs in the step of its sample; one SIH step when it runs in the next)."""
    from pyulog import ULog

    data = ULog(str(log), [topic]).data_list[0].data
    return float(np.median(data["timestamp"] - data["timestamp_sample"])) * 1e-6


def _estimator_shift(logs: Path, before: str, after: str, loop: str) -> float | None:
    """How much later EKF2's attitude follows SIH's own in the after-flight than in the before-flight [s]: each
    flight's mean over its tests of ``rate_path.stage_lags``'s ``phi_true -> phi_ekf`` lag at the test's frequency
    (SIH's truth, not the tool). A change of the loop the relay switches on that the firmware's delay line did not
    make. None for a loop without an attitude, or a flight that does not log the stages."""
    if loop not in ("roll", "pitch"):
        return None  # EKF2's altitude against SIH's moves -5.5 to +26 ms from test to test: not measurable to 1 ms
    from rate_path import stage_lags

    sih = sih_implied(loop)
    try:
        lags = [float(np.mean([row["lag_ms"]["phi_true->phi_ekf"]  # type: ignore[index]
                               for row in stage_lags(logs / f"{name}.ulg", loop, sih["Tp"], sih["Td"])]))
                for name in (before, after)]
    except KeyError:  # a stage's topic not logged
        return None
    return (lags[1] - lags[0]) * 1e-3


def _separate_increment(results: dict[str, dict[str, Any]], before: str, after: str, key: str,
                        realised: float) -> str:
    """The two flights' separately fitted taus' difference [ms] and its error, as text (empty without results)."""
    if not results:
        return ""
    got = [(results.get(k, {}).get("truth", {}) if key == "truth" else results.get(k, {})).get("tau")
           for k in (before, after)]
    if None in got:
        return "; fitted separately: none (a flight refused)"
    taus = [float(t) for t in got if t is not None]
    inc = taus[1] - taus[0]
    return (f"; fitted separately: {inc * 1e3:.2f} ms ({taus[0] * 1e3:.2f} -> {taus[1] * 1e3:.2f}; "
            f"{(inc - realised) * 1e3:+.2f} ms)")


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([sys.executable, "-m", "mrftcli.cli", *args], capture_output=True, text=True)
    if proc.returncode not in (0, 6):
        print(proc.stdout[-2000:], proc.stderr[-2000:])
    return proc


def export(results: dict[str, dict[str, Any]], work: Path) -> Path | None:
    """``tune --export px4`` for the altitude loop, as the current code writes it (no --clamp)."""
    work.mkdir(parents=True, exist_ok=True)
    r = results[EXPORT_FROM]
    params, js = work / "altitude.params", work / "altitude_tune.json"
    for p in (params, js):
        p.unlink(missing_ok=True)
    # no --controller-rate: the rate is read from the log (mc_pos_control's setpoint at every publication)
    proc = _cli("tune", str(r["log"]), "--tp", f"{r['tp']:.6f}", "--loop", "altitude", "--export", "px4",
                "--hover-thrust", f"{r['hover']:.4f}", "--out", str(params), "--json", str(js))
    print(f"  tune --export px4 (altitude, --hover-thrust {r['hover']:.4f}, no --clamp, the rate from the log): "
          f"exit {proc.returncode} {proc.stderr.strip()[:300]}")
    print("    " + "\n    ".join(proc.stdout.strip().splitlines()[:16]))
    return params if params.exists() else None


def predicted_step(result: dict[str, Any], params: dict[str, float], hover: float, t_end: float = 10.0
                   ) -> dict[str, float]:
    """Overshoot and settling of the flown PX4 gains on the identified model (tune's sampled loop).

    PX4: ``acc = VEL_P (Z_P e - v) + VEL_I int(Z_P e - v) + ...``, thrust = acc hover / g; in the parallel
    form on the position error: ``Kp = Z_P VEL_P h/g``, ``Kd = VEL_P h/g`` (on the measurement),
    ``Ki = Z_P VEL_I h/g``; the integral's ``-VEL_I h/g (y - y0)`` remnant is left out (0.2 of the 4-7
    that VEL_P is).
    """
    from mrftcli.mrft.model import LoopModel
    from mrftcli.tune.closed_loop import Controller, step_metrics, step_response

    s = hover / G
    ctrl = Controller(Kp=params["MPC_Z_P"] * params["MPC_Z_VEL_P_ACC"] * s,
                      Ki=params["MPC_Z_P"] * params.get("MPC_Z_VEL_I_ACC", 0.0) * s,
                      Kd=params["MPC_Z_VEL_P_ACC"] * s, Tf=0.0, rate_hz=result["rate_hz"])
    model = LoopModel(result["tp"], result["Td"], result["tau"], result["K"])
    t, y, u = step_response([model], ctrl, t_end)
    m = step_metrics(t, y[0], u[0])
    return {"overshoot_pct": m.overshoot_pct, "settling_s": m.settling_s, "rise_s": m.rise_s,
            "t": t, "y": y[0]}


def _offboard_hold(sitl: Px4Sitl, x: float, y: float, z: float, seconds: float) -> None:
    """Stream a position setpoint (NED) at 20 Hz for ``seconds`` of simulated time."""
    end = sitl.boot_ms + seconds * 1000
    while sitl.boot_ms < end:
        sitl.mav.mav.set_position_target_local_ned_send(0, sitl.mav.target_system, sitl.mav.target_component, 1,
                                                        0b110111111000, x, y, z, 0, 0, 0, 0, 0, 0, 0, 0)
        sitl.wait(0.05)


def refly(px4: Path, params_file: Path, work: Path, speedup: float, step_m: float = 1.0, repeats: int = 4,
          dwell_s: float = 10.0) -> dict[str, Any]:
    """Load the export, read it back, arm, take off, fly ``repeats`` altitude steps up by ``step_m`` and
    back in OFFBOARD (``dwell_s`` each); the ULog and the up-steps' times [s]."""
    params = read_qgc_params(params_file)
    with Px4Sitl(px4, work / "refly", speedup) as sitl:
        rows = load_params(sitl, params)
        changed = [r for r in rows if not r["unchanged"]]
        print(f"  loaded {len(rows)} parameters, read back: {len(changed)} rejected or changed")
        for r in changed:
            print(f"    {r['name']}: wrote {r['written']:g}, read {r['read_back']:g}")
        try:
            refusals = sitl.takeoff(5.0)
        except Exception as err:  # noqa: BLE001 - reported, the figure is the refusal
            print(f"  arming / take-off: REFUSED ({err})")
            return {"rows": rows, "armed": False}
        print(f"  pre-arm: passed (refusals while the EKF settled: {sorted(set(refusals)) or 'none'})")
        msg = sitl.wait(5, lambda m: m.get_type() == "LOCAL_POSITION_NED")
        x, y, z = float(msg.x), float(msg.y), float(msg.z)
        _offboard_hold(sitl, x, y, z, 1.0)
        sitl.mav.set_mode("OFFBOARD")  # the stream must go on while the mode changes (COM_OF_LOSS_T)
        _offboard_hold(sitl, x, y, z, 8.0)
        if sitl.mav.flightmode != "OFFBOARD":
            raise SitlError(f"OFFBOARD not entered (in {sitl.mav.flightmode}); {sitl.last_texts()}")
        for _ in range(repeats):  # up (the prediction's linear step) and back down (PX4's 1 m/s descent limit)
            _offboard_hold(sitl, x, y, z - step_m, dwell_s)
            _offboard_hold(sitl, x, y, z, dwell_s)
        sitl.set_mode("LOITER")
        sitl.land()
        sitl.wait(2)
    log = sitl.newest_log()
    shutil.copy(log, work / "refly.ulg")
    return {"rows": rows, "armed": True, "z0": z, "step_m": step_m, "dwell_s": dwell_s, "log": work / "refly.ulg"}


def _normalised_steps(t: np.ndarray, alt: np.ndarray, starts: list[float], dwell: float
                      ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Each up-step's response from 0 (the mean of the 2 s before) to 1 (the mean of its last 3 s: the
    level the loop settled to, as step figures are defined), on one time grid from the step [s]."""
    grid = np.arange(0.0, dwell - 0.05, 0.008)
    runs = []
    for t0 in starts:
        a = np.interp(t0 + grid, t, alt)
        base = float(np.mean(alt[(t > t0 - 2) & (t < t0)]))
        final = float(np.mean(a[grid > dwell - 3]))
        runs.append((a - base) / (final - base))
    return grid, runs


def _settling(grid: np.ndarray, y: np.ndarray, band: float) -> float:
    """The last time [s] a normalised response is outside ``1 +- band``."""
    outside = np.flatnonzero(np.abs(y - 1.0) > band)
    return float(grid[outside[-1]]) if outside.size else 0.0


def _figures(grid: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """Overshoot [%], 2 % settling [s] and 10-90 % rise [s] of a normalised response."""
    outside = np.flatnonzero(np.abs(y - 1.0) > 0.02)
    return {"overshoot_pct": max(0.0, float(np.max(y)) - 1.0) * 100,
            "settling_s": float(grid[outside[-1]]) if outside.size else 0.0,
            "rise_s": float(grid[np.argmax(y >= 0.9)] - grid[np.argmax(y >= 0.1)])}


def _velocity_bias(t: np.ndarray, z: np.ndarray, vz: np.ndarray, t0: float, t1: float) -> float:
    """EKF2's vertical velocity against the slope of its own altitude over 2 s windows [m/s] (median |.|)."""
    edges = np.arange(t0, t1 - 2, 2.0)
    bias = []
    for a in edges:
        sel = (t >= a) & (t < a + 2)
        if sel.sum() > 10:
            bias.append(float(np.mean(vz[sel]) - np.polyfit(t[sel], z[sel], 1)[0]))
    return float(np.median(np.abs(bias))) if bias else float("nan")


def evaluate_refly(flown: dict[str, Any], pred: dict[str, float]) -> dict[str, float]:
    """The flown up-steps' figures (EKF2's altitude, which PX4 controls), each step and their mean,
    against the prediction; the EKF2 velocity bias that moves the level PX4 holds."""
    from mrftcli.io import open_log

    with open_log(flown["log"], echo_warnings=False) as src:
        ts, sp = src.read("trajectory_setpoint", ["position[2]"])
        tz, pos = src.read("vehicle_local_position", ["z", "vz"])
    zsp = sp["position[2]"]
    step = flown["step_m"]
    if "z0" not in flown:  # a log flown before: the level is the setpoint just before the first step up
        first = int(np.flatnonzero(np.isfinite(zsp[1:]) & (np.diff(zsp) < -0.5 * step))[0])
        flown = {**flown, "z0": float(zsp[first])}
    z0 = flown["z0"]
    up = np.isfinite(zsp) & (zsp < z0 - 0.5 * step)
    starts = [float(ts[i]) for i in np.flatnonzero(np.diff(up.astype(int)) == 1) + 1]
    alt = -pos["z"]
    hover = (tz > starts[0] - 6) & (tz < starts[0])
    bias = _velocity_bias(tz, pos["z"], pos["vz"], starts[0], starts[-1] + 2 * flown["dwell_s"])
    offset = [float(np.mean(alt[(tz > s + flown["dwell_s"] - 3) & (tz < s + flown["dwell_s"])]) - (-z0 + step))
              for s in starts]
    print(f"  hover (6 s before the first step): altitude std {np.std(alt[hover]) * 100:.2f} cm; EKF2's vz against "
          f"the slope of its z: {bias:.3f} m/s (median over 2 s windows), so PX4 holds the level "
          f"{', '.join(f'{o * 100:+.1f}' for o in offset)} cm off the setpoint (bias / MPC_Z_P)")
    grid, runs = _normalised_steps(tz, alt, starts, flown["dwell_s"])
    got = _figures(grid, np.mean(runs, axis=0))
    each = [_figures(grid, r) for r in runs]
    print(f"  altitude step +{step:g} m x{len(starts)} (OFFBOARD position setpoint, unshaped; to the level held): "
          f"mean response overshoot {got['overshoot_pct']:.1f} %, rise (10-90 %) {got['rise_s']:.2f} s, settling "
          f"(2 %) {got['settling_s']:.2f} s; predicted {pred['overshoot_pct']:.1f} %, {pred['rise_s']:.2f} s, "
          f"{pred['settling_s']:.2f} s")
    print("    single steps: " + "; ".join(f"{e['overshoot_pct']:.1f} %, {e['rise_s']:.2f} s, {e['settling_s']:.2f} s"
                                         for e in each))
    # The band PX4 holds: EKF2's altitude in the hover before the steps, +-2 std; settling into it,
    # flown and predicted (tune's loop has no estimator, so its response is measured against the same band)
    band = 2 * float(np.std(alt[hover])) / step
    got["band"] = band
    got["settling_band_s"] = _settling(grid, np.mean(runs, axis=0), band)
    singles = [_settling(grid, r, band) for r in runs]
    got["settling_band_single_s"] = singles
    if "y" in pred:
        got["predicted_settling_band_s"] = _settling(pred["t"], pred["y"], band)
        print(f"  settling into the band PX4 holds in hover (EKF2's altitude +-2 std = +-{band * step * 100:.1f} cm, "
              f"{band * 100:.1f} % of the step): mean response {got['settling_band_s']:.2f} s, single steps "
              f"{', '.join(f'{v:.2f}' for v in singles)} s; predicted {got['predicted_settling_band_s']:.2f} s")
    return got


def run(px4: Path, logs: Path, speedup: float, only: list[str], analyze_only: bool, no_refly: bool,
        delay_only: bool = False) -> int:
    """The whole PX4 campaign (``bench_sitl.py --stack px4``); ``delay_only``: the +20 ms pairs through
    ``mrft-ident delay`` only (no SITL, no other analysis)."""
    if delay_only:
        delay_increments(logs)
        return 0
    if not analyze_only:
        if not (px4 / "build/px4_sitl_default/bin/px4").exists():
            subprocess.run([str(HERE / "build_px4.sh"), str(px4)], check=True)
        print("1. MRFT flights in PX4 SITL (SIH)")
        fly_campaign(px4, logs, speedup, only)
    print("2. analysis of the ULogs")
    results = analyse(logs)
    report(results)
    print("the +20 ms pairs through mrft-ident delay (one Td and K for both flights), beside the flights fitted "
          "separately")
    delay_increments(logs, results)
    done = sorted((logs / "export").glob("refly*.ulg"))  # each re-flight of the export kept
    for loop in ("pitch", "roll"):  # the rate loops' export and step (px4_rate_step.py)
        if f"px4_{loop}_h" not in results or no_refly or (analyze_only and not
                                                          (logs / "export" / f"{loop}_steps.ulg").exists()):
            continue
        from px4_rate_step import run_rate_step

        print(f"3b. tune --export px4 for {loop} (SIH's attitude, the bench Tp), and a {loop} step" +
              (" (flown before: evaluated again)" if analyze_only else ""))
        run_rate_step(px4, logs, bench_tp(), TRUTH_ATTITUDE, fly=not analyze_only, loop=loop, flight=f"px4_{loop}_h")
    for loop in ("x", "y"):  # the x/y export and its position steps (px4_xy_step.py)
        flight = f"px4_{loop}_h16"
        if flight not in results or no_refly or (analyze_only and not (logs / "export" / f"{loop}_steps.ulg").exists()):
            continue
        from px4_xy_step import run_xy_step

        print(f"3c. tune --export px4 for {loop} (from {flight}), and {loop} steps" +
              (" (flown before: evaluated again)" if analyze_only else ""))
        run_xy_step(px4, logs, fly=not analyze_only, loop=loop, flight=flight, speedup=speedup)
    for flown in done if (analyze_only or no_refly) and EXPORT_FROM in results else []:
        print(f"3. the re-flight already flown ({flown}), evaluated again")
        _compare_step(results, logs / "export" / "altitude.params", {"log": flown, "step_m": 1.0, "dwell_s": 10.0})
    if analyze_only or no_refly or EXPORT_FROM not in results:
        return 0
    print("3. tune --export px4, load, re-fly")
    params_file = export(results, logs / "export")
    if params_file is None:
        print("  no export written: nothing to fly")
        return 1
    flown = refly(px4, params_file, logs / "export", speedup)
    if flown.get("armed"):
        _compare_step(results, params_file, flown)
    return 0


def _compare_step(results: dict[str, dict[str, Any]], params_file: Path, flown: dict[str, Any]) -> None:
    """The flown altitude steps against the prediction of the exported gains on the identified model."""
    values = {k: v for k, (v, _) in read_qgc_params(params_file).items()}
    r = results[EXPORT_FROM]
    pred = predicted_step(r, values, r["hover"])
    got = evaluate_refly(flown, pred)
    pred["settling_band_s"] = got.get("predicted_settling_band_s", math.nan)
    for key in ("overshoot_pct", "rise_s", "settling_s", "settling_band_s"):
        if math.isfinite(pred[key]) and pred[key] > 0:
            print(f"    {key}: flown / predicted = {got[key] / pred[key]:.2f}")
