"""PX4's x/y export as the vehicle will fly it: the controller its ``MPC_XY_*`` values give, PX4's own law run tick
by tick on the nominal model, and the step and wind that loop predicts (said in the export's notes).

``PositionControl::_velocityControl`` (PX4 ``src/modules/mc_pos_control/PositionControl``) integrates the velocity
error P_xy e - v after the output, so its integral carries no P_xy r kick on a setpoint step: tune's
:class:`~mrftcli.tune.closed_loop.Controller` of the same loop (:func:`px4_xy_controller`, the integral on the error)
has the same margins but not the same step once ``MPC_XY_VEL_I_ACC`` > 0; :func:`px4_xy_ticks` runs PX4's law.
"""

from __future__ import annotations

import math

import numpy as np

from ..mrft.cascade import STANDARD_GRAVITY
from ..mrft.controller import PX4VelocityPath
from ..mrft.model import LoopModel
from .closed_loop import Controller
from .margins import loop_margins
from .stack_params import param

__all__ = ["XY_HORIZON_S", "px4_xy_controller", "px4_xy_ticks", "px4_xy_prediction", "pd_wind_offset",
           "written_loop"]


def px4_xy_controller(p: dict[str, float], rate_hz: float, hover_thrust: float) -> Controller:
    """The controller from -x (or -y) to the normalised thrust that PX4's ``MPC_XY_*`` values ``p`` (and
    ``MPC_VELD_LP``) give at ``rate_hz`` [Hz] and ``hover_thrust``: as altitude's (Kp = (h/g) P_v P_xy + the
    integral's I_v, Ki = (h/g) I_v P_xy, Kd = (h/g) P_v) with :class:`PX4VelocityPath` on the rate."""
    s = hover_thrust / STANDARD_GRAVITY
    pz, pv, iv = p["MPC_XY_P"], p["MPC_XY_VEL_P_ACC"], p["MPC_XY_VEL_I_ACC"]
    path = PX4VelocityPath(p["MPC_VELD_LP"], "MPC_XY_VEL_D_ACC, MPC_VELD_LP", accel_s=p["MPC_XY_VEL_D_ACC"] / pv)
    return Controller(s * (pv * pz + iv), s * iv * pz, s * pv, 0.0, rate_hz, path)


#: Horizon [s] of the x/y export's predicted step and wind (an integral's slow tail inside it).
XY_HORIZON_S = 40.0


def px4_xy_ticks(params: dict[str, float], model: LoopModel, rate_hz: float, hover: float,
                  seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """PX4's x/y loop with the values ``params`` run tick by tick on the nominal ``model`` held as tune holds it
    (:func:`mrftcli.tune.closed_loop.discrete_plants`): times [s] and the positions [m] (2, N) after a unit
    position step and after a step of 1 m/s^2 of wind (a load of 1 / K at the plant's input). PX4's law (the module's
    docstring), linear: no tilt or velocity limit."""
    from .closed_loop import discrete_plants

    Phi, G, C, d = discrete_plants([model], rate_hz)[0]
    n, T = int(round(seconds * rate_hz)) + 1, 1.0 / rate_hz
    alpha = PX4VelocityPath(params["MPC_VELD_LP"], "MPC_VELD_LP").alpha(rate_hz)
    pz, pv, iv, dv = (params[k] for k in ("MPC_XY_P", "MPC_XY_VEL_P_ACC", "MPC_XY_VEL_I_ACC", "MPC_XY_VEL_D_ACC"))
    r, load = np.array([1.0, 0.0]), np.array([0.0, 1.0 / model.K])
    u = np.zeros((n + d + 1, 2))  # u[j + d + 1]: the command of tick j (0 before the first)
    x, y_prev, v_prev, acc_f, integral = np.zeros((2, 3)), np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2)
    y = np.empty((2, n))
    # the tick's products as np.outer forms them (u[k][:, None] * G[0]), the constant load's once, Phi.T once:
    # the same values. Why: a Python loop of 5000 ticks (40 s at 125 Hz) where numpy's per-call cost is the time
    # (benchmarks/bench_tune_ranges.py prints the ratio)
    Phi_T, G0, G1 = Phi.T, G[0][None, :], G[1][None, :]
    wind = np.outer(load, G[0] + G[1])
    for k in range(n):
        yk = x @ C
        y[:, k] = yk
        v = (yk - y_prev) / T
        acc_f += alpha * ((v - v_prev) / T - acc_f)  # MPC_VELD_LP's AlphaFilter on the velocity's difference
        err = pz * (r - yk) - v
        u[k + d + 1] = (pv * err + integral - dv * acc_f) * hover / STANDARD_GRAVITY
        integral += iv * err * T  # after the output, as PX4
        x = x @ Phi_T + u[k][:, None] * G0 + u[k + 1][:, None] * G1 + wind
        y_prev, v_prev = yk, v
    return np.arange(n) * T, y


def px4_xy_prediction(params: dict[str, float], model: LoopModel, rate_hz: float, hover: float) -> dict[str, float]:
    """The loop PX4 runs with the x/y values ``params`` on the nominal ``model`` (:func:`px4_xy_ticks`): its unit
    position step, and a step of 1 m/s^2 of wind, its offset [m]. The steady offset in closed form: 0 with
    ``MPC_XY_VEL_I_ACC`` > 0 (it integrates the velocity error P_xy e - v, so it holds until e = 0), g / (h P_v
    P_xy K) without (the PD holds (h/g) P_v P_xy e = w / K). ``rate_hz`` [Hz], ``hover`` normalised 0-1.

    Returns
    -------
    dict
        The keys of :attr:`mrftcli.tune.stacks.StackExport.predicted` (offsets in metres per 1 m/s^2 of wind, times in s).
    """
    from .closed_loop import step_metrics

    t, y = px4_xy_ticks(params, model, rate_hz, hover, XY_HORIZON_S)
    m, wind = step_metrics(t, y[0]), np.abs(y[1])
    steady = 0.0 if params["MPC_XY_VEL_I_ACC"] > 0 else pd_wind_offset(params, model, hover)
    at = {s: float(wind[min(int(round(s * rate_hz)), t.size - 1)]) for s in (5.0, 20.0)}
    return {"MPC_XY_VEL_I_ACC": params["MPC_XY_VEL_I_ACC"], "step_overshoot_pct": m.overshoot_pct,
            "step_rise_s": m.rise_s, "step_settling_s": m.settling_s, "wind_steady_offset_m": steady,
            "wind_peak_offset_m": float(np.max(wind)), "wind_offset_5s_m": at[5.0], "wind_offset_20s_m": at[20.0]}


def pd_wind_offset(params: dict[str, float], model: LoopModel, hover: float) -> float:
    """The steady offset [m] per 1 m/s^2 of wind that PX4's x/y loop with ``params`` holds without integral (the
    PD of ``MPC_XY_VEL_I_ACC`` 0): (h/g) P_v P_xy e = w / K gives g / (h P_v P_xy K) (inf for no gain).
    ``hover`` normalised 0-1."""
    pd_gain = hover / STANDARD_GRAVITY * params["MPC_XY_VEL_P_ACC"] * params["MPC_XY_P"] * model.K
    return 1.0 / pd_gain if pd_gain > 0 else math.inf


def _settling(s: float) -> str:
    return f"{s:.3f} s" if math.isfinite(s) else f"not within {XY_HORIZON_S:g} s"


def written_loop(params: dict[str, float], model: LoopModel, rate_hz: float,
                 hover: float) -> tuple[tuple[str, str], dict[str, float]]:
    """What the loop PX4 runs with the x/y values written (``params``, tune's sampled loop on the nominal ``model``
    at ``rate_hz`` [Hz], ``hover`` normalised 0-1) does: its unit step (what a flown step is compared with) and
    what a steady wind does, as two notes, with :func:`px4_xy_prediction`'s figures; without integral, what
    PX4's default one would do instead (the user's choice, ``--xy-integral``)."""
    p = px4_xy_prediction(params, model, rate_hz, hover)
    iv = p["MPC_XY_VEL_I_ACC"]
    step = (f"the loop as written (MPC_XY_VEL_D_ACC through MPC_VELD_LP{f', MPC_XY_VEL_I_ACC {iv:g}' if iv else ''} "
            f"included), a 1 m step on the nominal model: overshoot {p['step_overshoot_pct']:.1f} %, rise "
            f"(10-90 %) {p['step_rise_s']:.3f} s, 2 % settling {_settling(p['step_settling_s'])}")
    if iv > 0:
        wind = (f"MPC_XY_VEL_I_ACC {iv:g} (--xy-integral) corrects a steady force: a step of 1 m/s^2 of wind moves the "
                f"vehicle at most {100 * p['wind_peak_offset_m']:.1f} cm, {100 * p['wind_offset_5s_m']:.1f} cm off after "
                f"5 s, {100 * p['wind_offset_20s_m']:.1f} cm after 20 s, 0 in steady state (without it "
                f"{100 * pd_wind_offset(params, model, hover):.1f} cm for good); in the margins and the step above. It "
                "does not correct a biased velocity estimate (PX4 integrates vel_sp - v)")
        return (step, wind), p
    row = param("px4", "MPC_XY_VEL_I_ACC")
    alt = {**params, "MPC_XY_VEL_I_ACC": row.default}
    q = px4_xy_prediction(alt, model, rate_hz, hover)
    ms = float(loop_margins(px4_xy_controller(alt, rate_hz, hover), [model]).Ms[0])
    wind = (f"MPC_XY_VEL_I_ACC 0 (a PD): nothing corrects a steady force such as wind: each 1 m/s^2 of it holds the "
            f"vehicle {100 * p['wind_steady_offset_m']:.1f} cm off for good (g / (h MPC_XY_VEL_P_ACC MPC_XY_P K)); to "
            f"correct it give tune --xy-integral I_ACC (MPC_XY_VEL_I_ACC, {row.minimum:g}-{row.maximum:g} {row.unit}; "
            f"designed with it, its margins stated): PX4's default {row.default:g} with the values above gives "
            f"overshoot {q['step_overshoot_pct']:.1f} %, 2 % settling {_settling(q['step_settling_s'])}, "
            f"{100 * q['wind_offset_20s_m']:.1f} cm off 20 s after a wind step, Ms {ms:.3g} (nominal)")
    return (step, wind), p
