"""ArduPilot's altitude cascade flown on an identified model, following a logged target (issue 41).

What ``tune --export ardupilot`` predicts for the step ArduPilot actually flies: ArduPilot shapes a
position step into a target with its speed, acceleration and jerk limits and feeds the shaped velocity and
acceleration forward, so the prediction runs ``AC_PosControl::update_U_controller`` (the pinned tree,
``libraries/AC_AttitudeControl/AC_PosControl.cpp``) on the identified eq. (2) model with the target the
log holds (``PSCD``: DPD, DVD, DAD, down-positive):

* velocity target [m/s] = ``PSC_POSZ_P`` (target - z) + the desired velocity (``AC_P_1D``, linear region);
* acceleration target [cm/s^2] = ``AC_PID_Basic`` ``PSC_VELZ_P``/``_I`` of the velocity error through
  ``PSC_VELZ_FLTE`` + the desired acceleration;
* throttle = hover + 0.001 ``AC_PID`` ``PSC_ACCZ_P``/``_I`` of (target - the IMU's acceleration through
  ``INS_ACCEL_FILTER``, a 2nd-order Butterworth) through ``PSC_ACCZ_FLTE`` (integrator ahead of the output);
* the throttle through the motors' 2 Hz filter (``POSCONTROL_THROTTLE_CUTOFF_FREQ_HZ``).

The plant is eq. (2) without its Tp: the identified Tp of a relay flown through ``set_throttle_out`` is
the pilot throttle filter, which the cascade replaces with its own 2 Hz one (SITL's motors have no lag);
tau is taken on the throttle (z, v and the acceleration measured without delay), in whole ticks.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

__all__ = ["cascade_follow"]

#: AC_PosControl's throttle filter (POSCONTROL_THROTTLE_CUTOFF_FREQ_HZ) [Hz]
THROTTLE_CUTOFF_HZ = 2.0


def _alpha(hz: float, dt: float) -> float:
    return 1.0 if hz <= 0 else dt / (dt + 1.0 / (2.0 * math.pi * hz))


def cascade_follow(params: dict[str, float], Td: float, tau: float, K: float, rate_hz: float,
                   t: np.ndarray, pos: np.ndarray, vel: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """The altitude [m] the cascade predicts at the times ``t`` [s] (a uniform grid at ``rate_hz``).

    ``pos``, ``vel``, ``acc``: the desired altitude [m, up], climb rate [m/s] and acceleration [m/s^2] on
    ``t``. Starts at rest on the target with the integrators at their hover values (zero deviation).
    """
    dt = 1.0 / rate_hz
    a_mat = np.array([[0.0, 1.0, 0.0], [0.0, -1.0 / Td, K], [0.0, 0.0, 0.0]])
    # exact zero-order hold of [z, v] with the throttle deviation u held over a tick
    from scipy.linalg import expm

    e = expm(np.block([[a_mat[:2, :2], a_mat[:2, 2:3]], [np.zeros((1, 3))]]) * dt)
    phi, gam = e[:2, :2], e[:2, 2]
    b, a = signal.butter(2, params.get("INS_ACCEL_FILTER", 20.0), fs=rate_hz)
    n_delay = int(round(tau * rate_hz))
    x = np.array([pos[0], 0.0])
    u_hist = [0.0] * (n_delay + 1)
    e_v = i_v = e_a = i_a = thr = 0.0
    acc_in, acc_out = [0.0, 0.0], [0.0, 0.0]
    out = np.empty(t.size)
    for k in range(t.size):
        out[k] = x[0]
        u = u_hist[-1 - n_delay]
        a_raw = 100.0 * (-x[1] / Td + K * u)  # the accelerometer's climb acceleration [cm/s^2]
        a_m = (b[0] * a_raw + b[1] * acc_in[0] + b[2] * acc_in[1] - a[1] * acc_out[0] - a[2] * acc_out[1]) / a[0]
        acc_in, acc_out = [a_raw, acc_in[0]], [a_m, acc_out[0]]
        v_t = 100.0 * (params["PSC_POSZ_P"] * (pos[k] - x[0]) + vel[k])  # [cm/s]
        e_v += _alpha(params.get("PSC_VELZ_FLTE", 5.0), dt) * ((v_t - 100.0 * x[1]) - e_v)
        i_v += e_v * params["PSC_VELZ_I"] * dt
        a_t = params["PSC_VELZ_P"] * e_v + i_v + 100.0 * acc[k]
        e_a += _alpha(params.get("PSC_ACCZ_FLTE", 20.0), dt) * ((a_t - a_m) - e_a)
        i_a += e_a * params["PSC_ACCZ_I"] * dt  # AC_PID::update_i, ahead of the output
        thr += _alpha(THROTTLE_CUTOFF_HZ, dt) * (0.001 * (params["PSC_ACCZ_P"] * e_a + i_a) - thr)
        u_hist.append(thr)
        x = phi @ x + gam * u
    return out
