"""Altitude MRFT flights in JSBSim's F450 (``pip install jsbsim``; issue 39).

JSBSim flies its own F450 quadrotor: four DJI E305 brushless motors (its ``brushless_dc_motor``
model: the rotor speed follows the voltage through the propeller's inertia and torque, which makes
the loop's Tp) turning DJI 9450 propellers (thrust and power tables against the advance ratio: the
thrust falls as the vehicle climbs, the climb's linear damping), its drag table (``CD__zero`` times
the dynamic pressure: quadratic in the speed) and its ESC actuators (``Effectors.xml``: clip 0..1).
The command is the collective thrust over the weight (hover 1.0), turned into the throttle
``fcs/throttle-cmd-norm`` through the motors' static thrust curve (a flight stack's thrust
linearisation, e.g. ArduPilot's MOT_THST_EXPO, measured on JSBSim's motors on a thrust stand:
the vehicle on its gear under ballast, J = 0); the
attitude rate loops of its flight control hold the vehicle level.

Effects produced in the simulator (the aircraft's XML edited in a copy, or its properties set):

* ``quadratic_drag``: ``CD__zero`` scaled so that the drag damps as much as the propellers' climb
  damping at the first test's speed (times the case's factor); truth c = rho S CD / (2 m) [1/m].
* ``actuator_saturation``: the ESC actuators clipped (``clipto``) at the throttle of u_max = 1 + 0.7 f h_max.
* ``actuator_rate_limit``: the ESC actuators' ``rate_limit`` [throttle/s] (truth in command units/s
  through the thrust curve's slope at hover).
* ``gain_drift``: a spray tank emptying (a point mass whose weight falls so that K(t) = K (1 + g t)).
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import shutil
import tempfile
from functools import lru_cache
from pathlib import Path

import numpy as np

from .loop import PlanningModel

__all__ = ["PLATFORMS", "JSBSimVehicle", "hover_command", "make_vehicle", "platform_model", "stand_rectification", "tool_tp"]

PLATFORMS = ("F450",)
FT = 0.3048
G = 9.81
DT = 1.0 / 2000.0  # JSBSim's integration step [s]
RHO = 1.2238  # air density where the flights fly (10 m above the sea-level terrain; JSBSim's standard atmosphere) [kg/m^3]
AREA = 0.173611 * FT * FT  # the F450's reference area (Metrics.xml) [m^2]
TANK = 0.3  # the tank's initial weight over the empty weight (gain drift)


@contextlib.contextmanager
def _quiet():
    """JSBSim's loader prints to the C++ stdout/stderr ("Failed to tie property ..."): keep it off the terminal."""
    saved = [os.dup(1), os.dup(2)]
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        os.dup2(null.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)


def _aircraft_root(cd: float | None, u_max: float | None, rate_limit: float | None, tank: bool) -> str:
    """A JSBSim root whose F450 carries the effect (the package's files otherwise, linked)."""
    import jsbsim

    src = Path(jsbsim.get_default_root_dir())
    root = Path(tempfile.mkdtemp(prefix="f450_"))
    for sub in ("engine", "systems"):
        if (src / sub).exists():
            os.symlink(src / sub, root / sub)
    dst = root / "aircraft" / "F450"
    shutil.copytree(src / "aircraft" / "F450", dst)
    if cd is not None:
        p = dst / "Aero.xml"
        text = p.read_text()
        text = re.sub(r'(<function name="aero/coefficient/CD__zero">.*?<value>)\s*[0-9.eE+-]+\s*(</value>)',
                      rf"\g<1> {cd:.6g} \g<2>", text, count=1, flags=re.S)
        p.write_text(text)
    if u_max is not None or rate_limit is not None:
        p = dst / "Effectors.xml"
        text = p.read_text()
        if u_max is not None:
            text = text.replace("<max>1.0</max>", f"<max>{u_max:.6g}</max>")
        if rate_limit is not None:
            text = text.replace("<clipto>", f"<rate_limit>{rate_limit:.6g}</rate_limit>\n      <clipto>")
        p.write_text(text)
    if tank:
        p = dst / "Mass.xml"
        text = p.read_text().replace(
            "</mass_balance>",
            '  <pointmass name="tank"><weight unit="KG">0.0</weight>'
            '<location unit="M"><x>0</x><y>0</y><z>0</z></location></pointmass>\n</mass_balance>')
        p.write_text(text)
    return str(root)


class JSBSimVehicle:
    """JSBSim's F450 in the air, stepped at :data:`DT`; the throttle is the plant input."""

    def __init__(self, *, drag_c: float | None = None, u_max: float | None = None, slew_u: float | None = None,
                 drift: float = 0.0, settle_s: float = 6.0) -> None:
        import jsbsim

        self.mass0 = 1.4 * (1.0 + TANK) if drift else 1.4
        cd = None if drag_c is None else drag_c * 2.0 * 1.4 / (RHO * AREA)
        thr_max = None if u_max is None else float(throttle_of(u_max))
        slew = None if slew_u is None else slew_u / _slope_at_hover()
        self.root = _aircraft_root(cd, thr_max, slew, bool(drift))
        with _quiet():
            fdm = jsbsim.FGFDMExec(self.root)
            fdm.set_debug_level(0)
            # the step before the model: its FCS components (the ESC actuators' rate limit, the attitude
            # loops' integrators) take their dt when they are built (after, they ran at JSBSim's 1/120 s
            # and a rate limit was 16.7x the one written)
            fdm.set_dt(DT)
            fdm.load_model("F450")
        self.fdm, self.drift, self.t = fdm, drift, 0.0
        fdm["ic/h-agl-ft"] = 10.0 / FT
        with _quiet():
            fdm.run_ic()
        fdm["propulsion/set-running"] = -1
        if drift:
            fdm["inertia/pointmass-weight-lbs"] = TANK * 1.4 / 0.45359237
        self.hover = self.mass0 / 1.4
        # spin the motors up and settle the hover (not logged): a PID on the altitude
        z0, integ = self.altitude(), 0.0
        for _ in range(int(settle_s / DT)):
            e = z0 - self.altitude()
            integ += 1.0 * e * DT
            self._step(self.hover + integ + 0.9 * e - 0.3 * self.fdm["velocities/h-dot-fps"] * FT)
        self.hover += integ
        self.t = 0.0

    def altitude(self) -> float:
        return float(self.fdm["position/h-sl-meters"])

    def _step(self, u: float) -> None:
        self.fdm["fcs/throttle-cmd-norm"] = float(throttle_of(u))
        self.fdm.run()

    def advance(self, u: float, dt: float) -> None:
        n = int(round(dt / DT))
        thr = float(throttle_of(u))
        if self.drift:
            # m(t) = m0 / (1 + g t): the thrust's acceleration per throttle K(t) = K (1 + g t)
            m = self.mass0 / (1.0 + self.drift * (self.t + 0.5 * dt))
            self.fdm["inertia/pointmass-weight-lbs"] = max(m - 1.4, 0.0) / 0.45359237
        for _ in range(n):
            self.fdm["fcs/throttle-cmd-norm"] = thr
            self.fdm.run()
        self.t += dt


#: ballast on the thrust stand [kg]: the F450's weight with it exceeds its thrust at full throttle (4.4 x 1.4 kg)
STAND_BALLAST = 10.0


@lru_cache(maxsize=None)
def _stand_root() -> str:
    """The F450 with a point mass for the stand's ballast (a copy of the package's aircraft)."""
    return _aircraft_root(None, None, None, True)


def _grounded_f450():
    """JSBSim's stock F450 on a thrust stand with its motors running (the bench tests below start from it):
    standing on its gear on the flights' terrain (sea level, the air of :data:`RHO`), held down by
    :data:`STAND_BALLAST`, so its propellers run at advance ratio J = 0 at every throttle, as a stand
    measures them. (It was the package's ``initGrnd``, 285 m above that terrain: above hover the vehicle
    climbed, and the thrust read 1.5 s after a step was the climbing propeller's, J 0.16-0.47, up to
    40 % short; a concave table whose error the flights carried as a thrust surplus ~0.5 h^2.)"""
    import jsbsim

    with _quiet():
        fdm = jsbsim.FGFDMExec(_stand_root())
        fdm.set_debug_level(0)
        fdm.set_dt(DT)  # before the model (its FCS components take their dt when built)
        fdm.load_model("F450")
        fdm["ic/h-agl-ft"] = 0.52  # on its gear (the contacts are 0.1524 m below the reference point)
        fdm.run_ic()
    fdm["propulsion/set-running"] = -1
    fdm["inertia/pointmass-weight-lbs"] = STAND_BALLAST / 0.45359237
    return fdm


def _static(u: float) -> tuple[float, float]:
    """Total thrust [N] at throttle ``u`` on the stand after the spin-up (and 0.0, unused)."""

    fdm = _grounded_f450()
    thrust = []
    for _ in range(int(1.5 / DT)):
        fdm["fcs/throttle-cmd-norm"] = u
        fdm.run()
        thrust.append(sum(fdm[f"propulsion/engine{'' if i == 0 else f'[{i}]'}/thrust-lbs"] for i in range(4)))
    return thrust[-1] * 4.4482216, 0.0


@lru_cache(maxsize=None)
def _thrust_curve() -> tuple:
    """The static thrust (J = 0, on the stand) over the 1.4 kg weight at throttles 0.1..1 (the stack's
    linearisation table)."""
    import numpy as np

    thr = np.linspace(0.1, 1.0, 19)
    return thr, np.array([_static(float(x))[0] / (1.4 * G) for x in thr])


def throttle_of(u: float) -> float:
    """The throttle whose static thrust is ``u`` times the weight (linear between the table's points)."""
    import numpy as np

    thr, ratio = _thrust_curve()
    return float(np.clip(np.interp(u, ratio, thr, left=0.0), 0.0, 1.0))


def _slope_at_hover() -> float:
    """d(thrust / weight) / d(throttle) at hover [1 / throttle]."""
    x = throttle_of(1.0)
    thr, ratio = _thrust_curve()
    return float((np.interp(x + 0.02, thr, ratio) - np.interp(x - 0.02, thr, ratio)) / 0.04)


def hover_command(platform: str) -> float:
    """The trim command [thrust / weight]."""
    return 1.0


@lru_cache(maxsize=None)
def _motor(platform: str) -> tuple[float, float]:
    """(K [m/s^2 per unit of thrust / weight], Tp [s]): g, and the thrust's 63 % rise time after a 0.04
    throttle step about hover, on the stand (the motor test a pilot runs before flying)."""
    import numpy as np

    u0 = throttle_of(1.0)
    fdm = _grounded_f450()
    thrust = []
    for k in range(int(2.5 / DT)):
        fdm["fcs/throttle-cmd-norm"] = u0 - 0.02 if k < int(1.5 / DT) else u0 + 0.02
        fdm.run()
        thrust.append(sum(fdm[f"propulsion/engine{'' if i == 0 else f'[{i}]'}/thrust-lbs"] for i in range(4)))
    th = np.array(thrust[int(1.5 / DT) - 1:])
    rise = (th - th[0]) / (th[-1] - th[0])
    return G, float(np.argmax(rise >= 1 - math.exp(-1)) * DT)


def platform_model(platform: str) -> PlanningModel:
    """What the pilot knows: K and Tp from the motor test, Td ~1 s, tau ~30 ms (latency)."""
    K, Tp = _motor(platform)
    return PlanningModel(K=K, Td=1.0, tau=0.03, Tp=Tp)


def tool_tp(platform: str) -> float:
    """The Tp [s] the tool is given: the motor test's rise time."""
    return _motor(platform)[1]


def make_vehicle(platform: str, *, drag_c: float | None = None, u_max: float | None = None, drift: float = 0.0,
                 slew_u: float | None = None) -> JSBSimVehicle:
    return JSBSimVehicle(drag_c=drag_c, u_max=u_max, slew_u=slew_u, drift=drift)


def _square_mean(step, h: float, f: float, T: float = 5.0) -> float:
    """The mean of ``step(u) -> thrust / weight`` under the command 1 +- h at f [Hz] (a square wave from
    1 s on), over the whole periods after 2 s."""
    out = np.array([step(1.0 + (h if (k * DT * f) % 1.0 < 0.5 else -h) if k * DT > 1.0 else 1.0)
                    for k in range(int(T / DT))])
    per, k0 = int(round(1.0 / f / DT)), int(2.0 / DT)
    return float(out[k0:k0 + (out.size - k0) // per * per].mean())


def stand_rectification(h: float = 0.3, f: float = 2.0) -> float:
    """The hover thrust F [command units] of the library's thrust rectification (a first-order lag Tp on
    the rotor speed, thrust F ((1 + q)^2 - 1): ``diagnose_sims/inherent.py``) whose mean thrust deficit
    under a square wave 1 +- h at f [Hz] equals the one JSBSim's E305 motors and 9450 propellers make on
    the stand: its own rotor-speed dynamics, not the library's code (the deficit goes as 1 / F)."""
    fdm = _grounded_f450()

    def jsb(u: float) -> float:
        fdm["fcs/throttle-cmd-norm"] = float(throttle_of(u))
        fdm.run()
        return sum(fdm[f"propulsion/engine{'' if i == 0 else f'[{i}]'}/thrust-lbs"] for i in range(4)) * 4.4482216 / (1.4 * G)

    jsb_shift = _square_mean(jsb, h, f) - _square_mean(jsb, 0.0, f)
    tp, state = tool_tp("F450"), [1.0]

    def lib(u: float) -> float:  # F = 1: the rotor speed relative to hover lags sqrt(u)
        state[0] += DT * (math.sqrt(u) - state[0]) / tp
        return state[0] ** 2

    return (_square_mean(lib, h, f) - 1.0) / jsb_shift
