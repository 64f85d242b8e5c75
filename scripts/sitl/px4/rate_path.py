"""Where the lag of PX4-SIH's roll / pitch path goes, stage by stage (mrft-ident issue 42).

eq. (2) at SIH's Tp (``SIH_T_TAU`` 50 ms) and Td (``SIH_IXX / SIH_KDW`` = 1 s) refuses the roll tests
(negative delay). This measures, at each test's frequency, the phase of each stage of the path from the
relay's torque setpoint to the attitude it switches on, from a ULog flown with the stages logged
(``px4_sitl.py``'s ``ROLL_TOPICS``), and reports each stage's lag beyond the continuous model as a delay
[ms]:

* ``c -> m``: ``vehicle_torque_setpoint`` to ``actuator_outputs_sim`` (the control allocator; model 0);
* ``m -> p_true``: the motor commands' torque combination to SIH's true body rate (SIH reads the outputs
  at its next 4 ms step; its motor lag and rigid body; model ``1 / ((Tp s + 1)(Td s + 1))``);
* ``p_true -> phi_true``: SIH's rate to its attitude (model: an integrator, -90 deg);
* ``phi_true -> phi_ekf``: SIH's attitude to EKF2's (``vehicle_attitude``, what the relay switches on);
* ``c -> phi_ekf``: the whole path the relay sees (the sum).

:func:`sih_discrete_tau` is the same path computed from ``sih.cpp``'s update order at its step ``dt``
(the outputs read one step late; the motor state ``u += dt / T_TAU (u_sp - u)`` used in the step that
updates it; the rate from that torque; the attitude from the previous step's rate): the delay beyond the
continuous model that SIH's discretisation leaves, with no estimator. A command line::

    python scripts/sitl/px4/rate_path.py px4_roll.ulg --axis roll     # the sidecar px4_roll.ulg.json beside it
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from pyulog import ULog

__all__ = ["STAGES", "stage_lags", "sih_discrete_tau", "relay_beta_from_fundamental"]

#: (from, to, the continuous model's phase [rad] at w [rad/s] given Tp, Td)
STAGES: list[tuple[str, str, Callable[[float, float, float], float]]] = [
    ("c", "m", lambda w, tp, td: 0.0),
    ("m", "p_true", lambda w, tp, td: -float(np.arctan(tp * w) + np.arctan(td * w))),
    ("p_true", "phi_true", lambda w, tp, td: -np.pi / 2),
    ("phi_true", "phi_ekf", lambda w, tp, td: 0.0),
    ("c", "phi_ekf", lambda w, tp, td: -float(np.arctan(tp * w) + np.arctan(td * w)) - np.pi / 2),
]


def _angle(data: dict[str, np.ndarray], axis: str) -> np.ndarray:
    q0, q1, q2, q3 = (data[f"q[{i}]"] for i in range(4))
    if axis == "roll":
        return np.arctan2(2 * (q0 * q1 + q2 * q3), 1 - 2 * (q1**2 + q2**2))
    return np.arcsin(np.clip(2 * (q0 * q2 - q3 * q1), -1.0, 1.0))


def _signals(log: Path, axis: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    d = {x.name: x.data for x in ULog(str(log)).data_list}
    i = 0 if axis == "roll" else 1
    ao = d["actuator_outputs_sim"]
    # SIH's torque combination of the four motors (sih.cpp generate_force_and_torques, quadrotor X)
    m = (-ao["output[0]"] + ao["output[1]"] + ao["output[2]"] - ao["output[3]"] if axis == "roll"
         else ao["output[0]"] - ao["output[1]"] + ao["output[2]"] - ao["output[3]"])
    sec = 1e-6
    return {
        "c": (d["vehicle_torque_setpoint"]["timestamp"] * sec, d["vehicle_torque_setpoint"][f"xyz[{i}]"]),
        "m": (ao["timestamp"] * sec, m),
        "p_true": (d["vehicle_angular_velocity_groundtruth"]["timestamp"] * sec,
                   d["vehicle_angular_velocity_groundtruth"][f"xyz[{i}]"]),
        "phi_true": (d["vehicle_attitude_groundtruth"]["timestamp"] * sec,
                     _angle(d["vehicle_attitude_groundtruth"], axis)),
        "phi_ekf": (d["vehicle_attitude"]["timestamp"] * sec, _angle(d["vehicle_attitude"], axis)),
    }


def _fundamental(t: np.ndarray, x: np.ndarray, t0: float, t1: float, w: float) -> complex:
    sel = (t >= t0) & (t < t1)
    return complex(np.mean((x[sel] - np.mean(x[sel])) * np.exp(-1j * w * t[sel])))


def _cycles(sig: dict[str, tuple[np.ndarray, np.ndarray]], t0: float, t1: float) -> tuple[float, float, float]:
    """The relay's frequency [rad/s] and a whole number of its cycles (first to last rising switch) [s]."""
    t, c = sig["c"]
    sel = (t > t0) & (t < t1)
    rising = t[sel][1:][np.diff(np.sign(c[sel] - np.mean(c[sel]))) > 0]
    return 2 * np.pi / float(np.median(np.diff(rising))), float(rising[0]), float(rising[-1])


def stage_lags(log: Path, axis: str, tp: float, td: float, settle_s: float = 3.0) -> list[dict[str, object]]:
    """Each test's frequency and each stage's lag beyond the continuous model [ms] (negative: a lead)."""
    sig = _signals(log, axis)
    tests = json.loads(Path(f"{log}.json").read_text())["tests"]
    rows = []
    for test in tests:
        w, a, b = _cycles(sig, test["start_s"] + settle_s, test["end_s"] - 0.3)
        lags = {}
        for src, dst, model in STAGES:
            gain = _fundamental(*sig[dst], a, b, w) / _fundamental(*sig[src], a, b, w)
            extra = np.angle(np.exp(1j * (np.angle(gain) - model(w, tp, td))))
            lags[f"{src}->{dst}"] = -float(extra) / w * 1e3
        rows.append({"beta": test["beta"], "h": test["h"], "f_hz": w / (2 * np.pi), "lag_ms": lags,
                     "sih_discrete_ms": sih_discrete_tau(w / (2 * np.pi), tp=tp, td=td),
                     "beta_fundamental": {out: relay_beta_from_fundamental(sig, out, a, b, w)
                                          for out in ("phi_ekf", "phi_true")}})
    return rows


def relay_beta_from_fundamental(sig: dict[str, tuple[np.ndarray, np.ndarray]], out: str, t0: float, t1: float,
                                w: float) -> float:
    """The relay's beta as its fundamental's phase shows it: sin of the command's lead over the error
    (= -output), negative for a lead (the MRFT's describing-function phase)."""
    gain = _fundamental(*sig["c"], t0, t1, w) / _fundamental(*sig[out], t0, t1, w)
    return -float(np.sin(np.angle(-gain)))


def sih_discrete_tau(f_hz: float, dt: float = 0.004, tp: float = 0.05, td: float = 1.0) -> float:
    """The delay [ms] beyond ``1 / (s (Tp s + 1)(Td s + 1))`` of SIH's discrete path at ``f_hz``.

    ``sih.cpp`` at each step ``k`` (``dt`` = 1 / min(IMU_GYRO_RATEMAX, IMU_INTEG_RATE)): reads the outputs
    PX4 computed at step ``k - 1``; ``u_k = u_{k-1} + dt / T_TAU (c_{k-1} - u_{k-1})``; the rate
    ``w_k = w_{k-1} + dt (b u_k - w_{k-1} / Td)``; the attitude ``phi_k = phi_{k-1} + dt w_{k-1}``.

    Examples
    --------
    >>> round(sih_discrete_tau(1.3), 2), round(sih_discrete_tau(3.0), 2)
    (0.25, 0.93)
    """
    w = 2 * np.pi * f_hz
    zi = np.exp(-1j * w * dt)
    a = dt / tp
    path = zi * (a / (1 - (1 - a) * zi)) * (dt / (1 - (1 - dt / td) * zi)) * (dt * zi / (1 - zi))
    cont = -np.pi / 2 - np.arctan(tp * w) - np.arctan(td * w)
    return float(np.angle(np.exp(1j * (np.angle(path) - cont)))) / -w * 1e3


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", type=Path, help="ULog flown with the stages logged (its .json sidecar beside it)")
    ap.add_argument("--axis", choices=("roll", "pitch"), default="roll")
    ap.add_argument("--tp", type=float, default=0.05, help="SIH_T_TAU [s]")
    ap.add_argument("--td", type=float, default=1.0, help="SIH_IXX / SIH_KDW [s]")
    args = ap.parse_args(argv)
    for row in stage_lags(args.log, args.axis, args.tp, args.td):
        lags = ", ".join(f"{k} {v:+.2f}" for k, v in row["lag_ms"].items())  # type: ignore[attr-defined]
        betas = row["beta_fundamental"]
        print(f"beta {row['beta']:+.2f} h {row['h']:.3f}: {row['f_hz']:.3f} Hz; lag beyond eq. (2) at Tp {args.tp:g} s, "
              f"Td {args.td:g} s [ms]: {lags}; sih.cpp's discrete path {row['sih_discrete_ms']:+.2f}; "
              f"relay beta from the fundamental: EKF2 {betas['phi_ekf']:+.3f}, SIH {betas['phi_true']:+.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
