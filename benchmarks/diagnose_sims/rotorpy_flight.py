"""Altitude MRFT flights in RotorPy (``pip install rotorpy``; issue 39).

RotorPy's :class:`rotorpy.vehicles.multirotor.Multirotor` integrates the rigid body, its rotor drag
and induced inflow (the linear damping of the climb), its parasitic drag ``c_Dz`` |v| v, and its
first-order motor dynamics (``tau_m``, the loop's Tp) with the rotor speeds clipped at
``rotor_speed_max``. The command is the collective thrust over the weight (hover 1.0): every motor is
commanded omega_0 sqrt(u), so the thrust k_eta omega^2 is u times the weight once the motors settle.

Effects produced in the simulator (none by ``mrftcli``'s code):

* ``quadratic_drag``: RotorPy's parasitic drag ``c_Dz`` set so that it damps as much as the inflow
  damping at the first test's speed (times the case's factor); truth c = c_Dz / m [1/m].
* ``actuator_saturation``: ``rotor_speed_max`` lowered so the thrust caps at u_max = 1 + 0.7 f h_max.
* ``gain_drift``: a sagging battery, the motors reaching omega sqrt(1 + g t) of the commanded speed.
* ``actuator_rate_limit``: an ESC that slews the motor-speed command at R_omega [rad/s^2], updated
  at 400 Hz (truth in command units/s near hover: 2 R_omega / omega_0).
"""

from __future__ import annotations

import importlib
import math

import numpy as np

from .loop import PlanningModel

__all__ = ["PLATFORMS", "RotorPyVehicle", "hover_command", "make_vehicle", "platform_model", "tool_tp"]

#: RotorPy's own multirotors with a linear climb damping (px4_sihsim_quadx has k_z = 0: no eq. (2) loop)
PLATFORMS = ("hummingbird", "crazyflie", "crazyfliebrushless")
G = 9.81


def _params(platform: str) -> dict:
    return dict(importlib.import_module(f"rotorpy.vehicles.{platform}_params").quad_params)


def platform_model(platform: str) -> PlanningModel:
    """What the pilot knows: K = g per unit of thrust/weight, Td = m / (4 omega_0 k_z), Tp = tau_m, and
    tau 30 ms (latency); the tool is given Tp only."""
    p = _params(platform)
    w0 = math.sqrt(p["mass"] * G / (4 * p["k_eta"]))
    return PlanningModel(K=G, Td=p["mass"] / (4 * w0 * p["k_z"]), tau=0.03, Tp=p["tau_m"])


class RotorPyVehicle:
    """A RotorPy multirotor held level (equal motor speeds), RotorPy's dynamics integrated by RK4."""

    def __init__(self, platform: str, *, c_dz: float | None = None, u_max: float | None = None,
                 drift: float = 0.0, slew: float = 0.0, z0: float = 1.0) -> None:
        from rotorpy.vehicles.multirotor import Multirotor

        p = _params(platform)
        self.w0 = math.sqrt(p["mass"] * G / (4 * p["k_eta"]))
        if c_dz is not None:
            p["c_Dz"] = c_dz
        if u_max is not None:
            p["rotor_speed_max"] = self.w0 * math.sqrt(u_max)
        self.mass, self.hover, self.drift, self.slew = p["mass"], 1.0, drift, slew
        self.state = {"x": np.array([0.0, 0.0, z0]), "v": np.zeros(3), "q": np.array([0.0, 0.0, 0.0, 1.0]),
                      "w": np.zeros(3), "wind": np.zeros(3), "rotor_speeds": np.full(4, self.w0)}
        self.vehicle = Multirotor(p, initial_state=self.state, control_abstraction="cmd_motor_speeds", aero=True)
        self.t, self.esc = 0.0, self.w0

    def altitude(self) -> float:
        return float(self.state["x"][2])

    def _step(self, w_cmd: float, dt: float) -> None:
        """RotorPy's own state derivative (``Multirotor._s_dot_fn``: forces, drag, motor lag) integrated by
        fixed-step RK4 at <= 2 ms, then what ``Multirotor.step`` does after its integration (unit
        quaternion, rotor speeds clipped): ``step``'s adaptive solve_ivp per tick cost 5x more CPU."""
        from rotorpy.vehicles.multirotor import Multirotor

        v = self.vehicle
        cmd = np.clip(np.full(4, w_cmd), v.rotor_speed_min, v.rotor_speed_max)
        x = Multirotor._pack_state(self.state)
        n = max(1, int(math.ceil(dt / 0.002)))
        h = dt / n
        for _ in range(n):
            k1 = v._s_dot_fn(0.0, x, cmd)
            k2 = v._s_dot_fn(0.0, x + 0.5 * h * k1, cmd)
            k3 = v._s_dot_fn(0.0, x + 0.5 * h * k2, cmd)
            k4 = v._s_dot_fn(0.0, x + h * k3, cmd)
            x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        state = Multirotor._unpack_state(x)
        state["q"] = state["q"] / np.linalg.norm(state["q"])
        state["rotor_speeds"] = np.clip(state["rotor_speeds"], v.rotor_speed_min, v.rotor_speed_max)
        self.state = state
        self.t += dt

    def advance(self, u: float, dt: float) -> None:
        if dt <= 1e-9:
            return
        target = self.w0 * math.sqrt(max(u, 0.0))
        if self.slew <= 0:
            self._step(target * math.sqrt(max(1.0 + self.drift * (self.t + 0.5 * dt), 0.0)), dt)
            return
        n = max(1, int(math.ceil(dt / 0.0025)))
        for _ in range(n):
            step = dt / n
            self.esc += float(np.clip(target - self.esc, -self.slew * step, self.slew * step))
            self._step(self.esc * math.sqrt(max(1.0 + self.drift * (self.t + 0.5 * step), 0.0)), step)


def hover_command(platform: str) -> float:
    """The trim command [thrust / weight]."""
    return 1.0


def tool_tp(platform: str) -> float:
    """The Tp [s] the tool is given: RotorPy's motor time constant (a bench test would measure it)."""
    return float(_params(platform)["tau_m"])


def make_vehicle(platform: str, *, drag_c: float | None = None, u_max: float | None = None, drift: float = 0.0,
                 slew_u: float = 0.0) -> RotorPyVehicle:
    """The vehicle with the effect in RotorPy's terms: drag c [1/m] -> c_Dz = c m; the command's slew
    [1/s] -> the ESC's R_omega = slew omega_0 / 2 (du/domega = 2 / omega_0 at hover)."""
    p = _params(platform)
    w0 = math.sqrt(p["mass"] * G / (4 * p["k_eta"]))
    return RotorPyVehicle(platform, c_dz=None if drag_c is None else drag_c * p["mass"], u_max=u_max, drift=drift,
                          slew=slew_u * w0 / 2.0)
