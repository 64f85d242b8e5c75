"""Fly the MRFT tests and tuned steps in PX4 SITL (SIH quadrotor) over MAVLink (mrft-ident issue 42).

The PX4 twin of ``scripts/sitl/sitl.py``: it reuses that harness's message loop, waits and parameter
read-back (:class:`sitl.Sitl`), and changes what differs in PX4: the process (``bin/px4`` with airframe
10040 ``sihsim_quadx``, lockstep), MAVLink on UDP 14550, PX4's byte-wise integer parameters, its modes
(TAKEOFF, LOITER = Hold, OFFBOARD, LAND), its ULogs, and the MRFT, which is the fork's own C++ relay in
``mc_pos_control`` (``mrft_port.patch``), switched on and off by ``MRFT_<AXIS>_ENABLE`` as the fork does.
A command line::

    python scripts/sitl/px4/px4_sitl.py fly --px4 /work/sitl/px4 --axis altitude \\
        --tests "-0.2:0.05,-0.5:0.05" --delay-ms 0 --out alt.ulg        # also writes alt.ulg.json

Times are simulated seconds (``time_boot_ms``; lockstep makes them the log's clock).
"""

from __future__ import annotations

import math
import os
import shutil
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from pymavlink import mavutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from sitl import FlyCommand, Sitl, SitlError, fly_command  # noqa: E402

__all__ = ["Px4Sitl", "fly_mrft", "read_qgc_params", "load_params", "AXES", "PX4_VERSION", "SIH_MODEL"]

HERE = Path(__file__).resolve().parent
#: loop -> the fork's parameter letter
AXES = {"altitude": "Z", "x": "X", "y": "Y", "roll": "R", "pitch": "P"}
PX4_VERSION = "PX4 main of 2024-08-21 (abdullaayyad96/PX4-Autopilot ae16556) + mrft_port.patch"
#: SIH's quadrotor (src/modules/simulation/simulator_sih/sih_params.c defaults, airframe 10040)
SIH_MODEL = {"SIH_MASS": 1.0, "SIH_T_MAX": 5.0, "SIH_T_TAU": 0.05, "SIH_KDV": 1.0, "SIH_L_ROLL": 0.2,
             "SIH_IXX": 0.025, "SIH_KDW": 0.025}
#: the command (the setpoint's thrust: the relays' decision) at every publication, 125 Hz, mc_pos_control's
#: rate; what reached the attitude setpoint (the decision after MRFT_DELAY) too, so the log shows the delay
#: realised; the output every other one (62.5 Hz: 35-50 samples a cycle); PX4's default logs these at
#: 10 Hz. SIH's true position beside EKF2's (the steps' figures without the estimate's noise). The rest
#: slowly, to keep the ULogs small
LOGGER_TOPICS = ["vehicle_local_position 16", "vehicle_local_position_setpoint 0", "vehicle_attitude_setpoint 0",
                 "trajectory_setpoint 0", "vehicle_local_position_groundtruth 16", "hover_thrust_estimate 100",
                 "vehicle_attitude 50",
                 "vehicle_status 200", "vehicle_land_detected 200"]
#: a roll flight's command (the roll torque setpoint the relay replaces, mrft_roll.patch) and output (the
#: attitude), at every publication, and the relays' decision before MRFT_DELAY (debug_vect); beside them
#: each stage of the path between (what SIH reads, the motor commands; SIH's true rates and attitude; the
#: gyro's rates PX4 filters), to measure each stage's lag
ROLL_TOPICS = ["vehicle_torque_setpoint 0", "vehicle_attitude 0", "actuator_outputs_sim 0", "debug_vect 0",
               "vehicle_angular_velocity 0", "vehicle_angular_velocity_groundtruth 0",
               "vehicle_attitude_groundtruth 0"]
INT32 = mavutil.mavlink.MAV_PARAM_TYPE_INT32
REAL32 = mavutil.mavlink.MAV_PARAM_TYPE_REAL32


def _encode(value: float, ptype: int) -> float:
    """PX4 sends and takes integer parameters byte-wise inside MAVLink's float field."""
    if ptype == INT32:
        return float(struct.unpack("<f", struct.pack("<i", int(round(value))))[0])
    return float(value)


def _decode(msg: Any) -> float:
    if msg.param_type == INT32:
        return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
    return float(msg.param_value)


@dataclass
class Px4Sitl(Sitl):
    """One headless PX4 SITL process (SIH quadrotor, lockstep) and its MAVLink connection.

    ``ap_dir`` is the PX4 tree built by ``build_px4.sh``; ``params`` are set over MAVLink after boot.
    """

    udp_port: int = 14550
    #: :meth:`Sitl.wait` with room for a lockstep simulation slowed by a busy machine (10x wall)
    wall_factor: ClassVar[float] = 10.0
    wall_slack_s: ClassVar[float] = 60.0

    def start(self) -> Px4Sitl:
        binary = self.ap_dir / "build/px4_sitl_default/bin/px4"
        if not binary.exists():
            raise SitlError(f"{binary} not found: build it with scripts/sitl/px4/build_px4.sh")
        shutil.rmtree(self.workdir, ignore_errors=True)
        self.workdir.mkdir(parents=True)
        # a private copy of the ROMFS (an `etc` folder in the working dir is used as is), with the topics
        shutil.copytree(self.ap_dir / "build/px4_sitl_default/etc", self.workdir / "etc", symlinks=True)
        (self.workdir / "etc/logging").mkdir(exist_ok=True)
        (self.workdir / "etc/logging/logger_topics.txt").write_text("\n".join(self.topics()) + "\n")
        # log while armed only (SITL's rcS defaults to from boot): the airframe script runs after the defaults
        with open(self.workdir / "etc/init.d-posix/airframes/10040_sihsim_quadx", "a") as airframe:
            airframe.write("\nparam set SDLOG_MODE 0\n")
        env = {**os.environ, "PX4_SYS_AUTOSTART": "10040", "PX4_SIM_MODEL": "sihsim_quadx",
               "PX4_SIM_SPEED_FACTOR": f"{self.speedup:g}"}
        out = open(self.workdir / "px4.out", "wb")  # noqa: SIM115 - lives as long as the process
        self.proc = subprocess.Popen([str(binary), "-d", "-s", "etc/init.d-posix/rcS"], cwd=self.workdir,
                                     env=env, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        self.mav = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.udp_port}", source_system=250)
        if self.mav.wait_heartbeat(timeout=90) is None:
            raise SitlError(f"no MAVLink heartbeat on udp {self.udp_port}; see {self.workdir / 'px4.out'}")
        self._last_hb = 0.0
        self.wait(2)
        for name, value in self.params.items():
            self.set_param(name, value)
        return self

    def topics(self) -> list[str]:
        """The logger's topics: :data:`LOGGER_TOPICS`, and :data:`ROLL_TOPICS` instead where they overlap
        when roll or pitch is among the parameters' axes (an MRFT_R_* or MRFT_P_* parameter set)."""
        extra = ROLL_TOPICS if any(k.startswith(("MRFT_R_", "MRFT_P_")) for k in self.params) else []
        names = {e.split()[0] for e in extra}
        return [e for e in LOGGER_TOPICS if e.split()[0] not in names] + extra

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.proc = None
        if self.mav is not None:
            self.mav.close()

    def recv(self, timeout: float = 1.0) -> Any:
        now = time.monotonic()
        if now - getattr(self, "_last_hb", 0.0) > 0.5:  # PX4 wants a ground station's heartbeat
            self.mav.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID,
                                        0, 0, 0)
            self._last_hb = now
        return super().recv(min(timeout, 0.5))

    # -- parameters (PX4: integers byte-wise) ------------------------------------------------------
    def _param_value(self, name: str, timeout: float) -> Any:
        self.mav.mav.param_request_read_send(self.mav.target_system, self.mav.target_component,
                                             name.encode(), -1)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            msg = self.recv(0.5)
            if msg is not None and msg.get_type() == "PARAM_VALUE" and msg.param_id == name:
                return msg
        return None

    def get_param(self, name: str, timeout: float = 5.0) -> float:
        for _ in range(3):
            msg = self._param_value(name, timeout)
            if msg is not None:
                return _decode(msg)
        raise SitlError(f"parameter {name} not read back (does this firmware have it?)")

    def param_type(self, name: str) -> int:
        for _ in range(3):
            msg = self._param_value(name, 5.0)
            if msg is not None:
                return int(msg.param_type)
        raise SitlError(f"parameter {name} not in this firmware (PARAM_REQUEST_READ unanswered)")

    def set_param(self, name: str, value: float, ptype: int | None = None) -> float:
        """Set (as the parameter's own type) and return the value the vehicle reports back."""
        ptype = self.param_type(name) if ptype is None else ptype
        for _ in range(3):
            self.mav.mav.param_set_send(self.mav.target_system, self.mav.target_component, name.encode(),
                                        _encode(value, ptype), ptype)
            end = time.monotonic() + 3
            while time.monotonic() < end:
                msg = self.recv(0.5)
                if msg is not None and msg.get_type() == "PARAM_VALUE" and msg.param_id == name:
                    return _decode(msg)
        raise SitlError(f"parameter {name} not acknowledged")

    # -- flight ---------------------------------------------------------------------------------------
    def set_mode(self, mode: str) -> None:
        self.mav.set_mode(mode)
        self.wait(5, lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1
                  and self.mav.flightmode == mode)
        if self.mav.flightmode != mode:
            raise SitlError(f"mode {mode} not accepted (in {self.mav.flightmode}); {self.last_texts()}")

    def arm(self, timeout_s: float = 90.0) -> list[str]:
        """Arm (retrying while the EKF settles); the pre-arm refusals seen on the way are returned."""
        refusals: list[str] = []
        end = self.boot_ms + timeout_s * 1000
        while self.boot_ms < end:
            self.texts.clear()
            self.mav.arducopter_arm()  # MAV_CMD_COMPONENT_ARM_DISARM, param1 = 1: not ArduPilot-specific
            self.wait(2, lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1
                      and self.mav.motors_armed())
            if self.mav.motors_armed():
                return refusals
            refusals += [t for t in self.texts if "arm" in t.lower() or "Preflight" in t]
            self.wait(2)
        raise SitlError(f"would not arm in {timeout_s} s: {sorted(set(refusals))[-4:]}")

    def altitude(self) -> float:
        msg = self.wait(5, lambda m: m.get_type() == "LOCAL_POSITION_NED")
        return -float(msg.z)

    def takeoff(self, alt_m: float) -> list[str]:
        """TAKEOFF mode to ``alt_m`` [m], which ends in Hold (LOITER); the arming refusals seen."""
        self.set_param("MIS_TAKEOFF_ALT", alt_m)
        self.set_mode("TAKEOFF")
        refusals = self.arm()
        # above home (the EKF's local origin can sit a metre off the ground)
        msg = self.wait(60, lambda m: m.get_type() == "GLOBAL_POSITION_INT" and m.relative_alt > (alt_m - 0.3) * 1000)
        if msg is None:
            raise SitlError(f"take-off to {alt_m} m did not get there; {self.last_texts()}")
        self.wait(10, lambda m: m.get_type() == "HEARTBEAT" and self.mav.flightmode == "LOITER")
        self.wait(8)  # settle (and let the hover-thrust estimator converge)
        return refusals

    def land(self) -> None:
        self.set_mode("LAND")
        self.wait(90, lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1
                  and not self.mav.motors_armed())

    def mrft(self, axis: str, beta: float, h: float, duration_s: float, n_conf: int = 5,
             no_switch_ms: int = 20) -> dict[str, Any]:
        """One relay test by the fork's MRFT (``MRFT_<AXIS>_*``); what was asked."""
        p = f"MRFT_{AXES[axis]}_"
        for name, value in (("BETA", beta), ("H", h), ("N_CONF", n_conf), ("NO_SWITCH", no_switch_ms)):
            self.set_param(p + name, value)
        t0 = self.boot_ms / 1000
        self.set_param(p + "ENABLE", 1)
        self.wait(duration_s)
        self.set_param(p + "ENABLE", 0)
        t1 = self.boot_ms / 1000
        self.wait(5)  # back in Hold between tests
        return {"beta": beta, "h": h, "duration_s": duration_s, "n_conf": n_conf, "no_switch_ms": no_switch_ms,
                "start_s": round(t0, 2), "end_s": round(t1, 2)}

    def newest_log(self) -> Path:
        logs = sorted((self.workdir / "log").glob("*/*.ulg"), key=os.path.getmtime)
        if not logs:
            raise SitlError(f"no ULog under {self.workdir / 'log'}")
        return logs[-1]


def read_qgc_params(path: Path) -> dict[str, tuple[float, int]]:
    """A QGroundControl ``.params`` file: ``NAME -> (value, MAV_PARAM_TYPE)``; ``#`` lines skipped."""
    out: dict[str, tuple[float, int]] = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        cols = line.split()
        if len(cols) < 5:
            raise ValueError(f"{path}: not a QGroundControl .params line: {line!r}")
        out[cols[2]] = (float(cols[3]), int(cols[4]))
    return out


def load_params(sitl: Px4Sitl, params: dict[str, tuple[float, int]]) -> list[dict[str, Any]]:
    """Set each parameter as the file's type, then read every one back (``unchanged``: as written)."""
    for name, (value, ptype) in params.items():
        sitl.set_param(name, value, ptype)
    rows = []
    for name, (value, _) in params.items():
        back = sitl.get_param(name)
        same = math.isclose(back, value, rel_tol=1e-5, abs_tol=1e-6)
        rows.append({"name": name, "written": value, "read_back": back, "unchanged": same})
    return rows


def fly_mrft(px4_dir: Path, workdir: Path, axis: str, tests: list[tuple[float, float]], delay_ms: float,
             duration_s: float, speedup: float = 1.0, alt_m: float = 5.0,
             extra: dict[str, float] | None = None) -> dict[str, Any]:
    """Take off, run ``tests`` ((beta, h) pairs) on ``axis``, land; the ULog and how it was flown. ``extra``:
    more parameters set after boot (recorded in the sidecar's ``params_set``)."""
    rate_loop = axis in ("roll", "pitch")
    params = {f"MRFT_{AXES[axis]}_ENABLE": 0, "MRFT_DELAY": delay_ms} if rate_loop else {"MRFT_DELAY": delay_ms}
    params.update(extra or {})
    with Px4Sitl(px4_dir, workdir, speedup, params) as sitl:
        refusals = sitl.takeoff(alt_m)
        hover = sitl.get_param("MPC_THR_HOVER")
        runs = [sitl.mrft(axis, beta, h, duration_s) for beta, h in tests]
        sitl.land()
        sitl.wait(2)
        texts = list(sitl.texts)
    log = sitl.newest_log()
    return {"stack": "PX4 SITL (SIH)", "version": PX4_VERSION, "frame": "sihsim_quadx (airframe 10040)",
            "loop": axis, "relay": (f"the fork's MRFT_Block in mc_rate_control on the {axis} angle, as the {axis} "
                                    "torque setpoint (scripts/sitl/px4/mrft_roll.patch)" if rate_loop else
                                    "the fork's MRFT_Block in mc_pos_control (scripts/sitl/px4/mrft_port.patch)"),
            "speedup": speedup, "hover_thrust_param": hover, "added_delay_ms": delay_ms,
            "tp_s": SIH_MODEL["SIH_T_TAU"], "tp_source": "SIH_T_TAU: SIH's first-order rotor thrust lag",
            "sih_model": SIH_MODEL, "logger_topics": sitl.topics(), "tests": runs,
            # the rate relays' decision before MRFT_DELAY (debug_vect x: roll, y: pitch; mrft_roll.patch)
            **({"decision_topic": f"debug_vect:{'x' if axis == 'roll' else 'y'}"} if rate_loop else {}),
            "prearm_refusals_before_arming": sorted(set(refusals)), "status_texts_tail": texts[-6:],
            **({"params_set": extra} if extra else {}), "log": str(log)}


def main(argv: list[str] | None = None) -> int:
    return fly_command(argv, FlyCommand(
        __doc__.split("\n\n")[0], "--px4", "built PX4 tree (build_px4.sh)", tuple(AXES), "normalised thrust",
        "relay output delay (MRFT_DELAY) [ms]", "ULog", Path("/tmp/mrft_px4_sitl")), fly_mrft)


if __name__ == "__main__":
    raise SystemExit(main())
