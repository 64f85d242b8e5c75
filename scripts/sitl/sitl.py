"""Fly MRFT tests and tuned steps in ArduCopter SITL over MAVLink (mrft-ident issue 41).

A small harness on pymavlink: start the SITL binary headless with the MRFT Lua script
(``mrft_relay.lua``), take off in GUIDED, run relay tests by setting the script's ``MRFT_*``
parameters, load a ``.param`` file and read every value back, fly steps, land, and keep the DataFlash
log. Used by ``benchmarks/bench_sitl.py``; also a command line::

    python scripts/sitl/sitl.py fly --ap ~/sitl/ardupilot --axis roll --tests "-0.2:0.04,-0.5:0.04" \\
        --delay-ms 0 --out roll.BIN --sidecar roll.BIN.json

Times are simulated seconds (the vehicle's ``time_boot_ms``) unless said otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from pymavlink import mavutil

__all__ = ["Sitl", "SitlError", "fly_mrft", "load_params", "read_param_file", "tp_of_filter", "AXES", "TP_FILTER"]

HERE = Path(__file__).resolve().parent
AXES = {"altitude": 1, "roll": 2, "pitch": 3}
#: ArduPilot's SITL home (the autotest's CMAC site)
HOME = "-35.363261,149.165230,584,353"
#: parameters every campaign flight sets: scripting on, a small log (the MRFT message; ATT, CTUN and
#: the streaming messages, such as SITL's own SIM2 at 400 Hz, at most 1 Hz: LOG_FILE_RATEMAX; no EKF3
#: streaming messages: EK3_LOG_LEVEL 3)
BASE_PARAMS = {"SCR_ENABLE": 1, "LOG_BITMASK": 18, "LOG_DISARMED": 0, "LOG_FILE_DSRMROT": 1,
               "LOG_FILE_RATEMAX": 1, "EK3_LOG_LEVEL": 3}


class SitlError(RuntimeError):
    """SITL did not do what the harness asked (the message says what and what it saw)."""


@dataclass
class Sitl:
    """One headless ArduCopter SITL process and its MAVLink connection.

    Parameters
    ----------
    ap_dir : Path
        The ArduPilot tree built by ``build_ardupilot.sh`` (``build/sitl/bin/arducopter``).
    workdir : Path
        Folder the process runs in (its ``eeprom.bin``, ``scripts/``, ``logs/``); emptied first.
    speedup : float
        SITL's ``--speedup`` (simulated seconds per wall second, at most).
    params : dict
        Parameters written into the defaults file on top of ``copter.parm`` and :data:`BASE_PARAMS`.
    """

    ap_dir: Path
    workdir: Path
    speedup: float = 1.0
    params: dict[str, float] = field(default_factory=dict)
    port: int = 5760
    proc: subprocess.Popen[bytes] | None = None
    mav: Any = None
    texts: list[str] = field(default_factory=list)
    boot_ms: int = 0
    #: how long :meth:`wait` allows in wall time for a simulated span: ``seconds / speedup * wall_factor +
    #: wall_slack_s`` [s]
    wall_factor: ClassVar[float] = 4.0
    wall_slack_s: ClassVar[float] = 30.0

    def start(self) -> Sitl:
        binary = self.ap_dir / "build/sitl/bin/arducopter"
        if not binary.exists():
            raise SitlError(f"{binary} not found: build it with scripts/sitl/build_ardupilot.sh")
        shutil.rmtree(self.workdir, ignore_errors=True)
        (self.workdir / "scripts").mkdir(parents=True)
        shutil.copy(HERE / "mrft_relay.lua", self.workdir / "scripts/mrft_relay.lua")
        extra = self.workdir / "campaign.parm"
        extra.write_text("".join(f"{k} {v}\n" for k, v in {**BASE_PARAMS, **self.params}.items()))
        defaults = f"{self.ap_dir / 'Tools/autotest/default_params/copter.parm'},{extra}"
        cmd = [str(binary), "--model", "quad", "--speedup", str(self.speedup), "--defaults", defaults,
               "-I0", "--home", HOME]
        out = open(self.workdir / "sitl.out", "wb")  # noqa: SIM115 - lives as long as the process
        self.proc = subprocess.Popen(cmd, cwd=self.workdir, stdout=out, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 60
        while True:
            try:
                self.mav = mavutil.mavlink_connection(f"tcp:127.0.0.1:{self.port}", source_system=250)
                break
            except OSError:
                if time.monotonic() > deadline or self.proc.poll() is not None:
                    raise SitlError(f"no MAVLink on tcp:{self.port}; see {self.workdir / 'sitl.out'}") from None
                time.sleep(0.5)
        self.mav.wait_heartbeat(timeout=60)
        self.mav.mav.request_data_stream_send(self.mav.target_system, self.mav.target_component,
                                              mavutil.mavlink.MAV_DATA_STREAM_ALL, 10, 1)
        return self

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        self.proc = None

    def __enter__(self) -> Sitl:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- messages -----------------------------------------------------------------------------------
    def recv(self, timeout: float = 1.0) -> Any:
        msg = self.mav.recv_match(blocking=True, timeout=timeout)
        if msg is None:
            if self.proc is not None and self.proc.poll() is not None:
                raise SitlError(f"SITL exited; see {self.workdir / 'sitl.out'}")
            return None
        typ = msg.get_type()
        if typ == "STATUSTEXT":
            self.texts.append(msg.text)
        if hasattr(msg, "time_boot_ms"):
            self.boot_ms = max(self.boot_ms, int(msg.time_boot_ms))
        return msg

    def wait(self, seconds: float, until: Any = None) -> Any:
        """Run for ``seconds`` of simulated time, or until ``until(msg)`` is true (returns that message)."""
        end = self.boot_ms + seconds * 1000
        wall = time.monotonic() + seconds / max(self.speedup, 1) * self.wall_factor + self.wall_slack_s
        while self.boot_ms < end:
            msg = self.recv()
            if msg is not None and until is not None and until(msg):
                return msg
            if time.monotonic() > wall:
                raise SitlError(f"SITL made no progress for {seconds} simulated s")
        return None

    # -- parameters ---------------------------------------------------------------------------------
    def get_param(self, name: str, timeout: float = 5.0) -> float:
        for _ in range(3):
            self.mav.mav.param_request_read_send(self.mav.target_system, self.mav.target_component,
                                                 name.encode(), -1)
            end = time.monotonic() + timeout
            while time.monotonic() < end:
                msg = self.recv(0.5)
                if msg is not None and msg.get_type() == "PARAM_VALUE" and msg.param_id == name:
                    return float(msg.param_value)
        raise SitlError(f"parameter {name} not read back (does this firmware have it?)")

    def set_param(self, name: str, value: float) -> float:
        """Set and return the value the vehicle reports back."""
        for _ in range(3):
            self.mav.mav.param_set_send(self.mav.target_system, self.mav.target_component, name.encode(),
                                        float(value), mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
            end = time.monotonic() + 3
            while time.monotonic() < end:
                msg = self.recv(0.5)
                if msg is not None and msg.get_type() == "PARAM_VALUE" and msg.param_id == name:
                    return float(msg.param_value)
        raise SitlError(f"parameter {name} not acknowledged")

    # -- flight ---------------------------------------------------------------------------------------
    def set_mode(self, mode: str) -> None:
        mapping = self.mav.mode_mapping()
        self.mav.set_mode(mapping[mode])
        self.wait(5, lambda m: m.get_type() == "HEARTBEAT" and self.mav.flightmode == mode)
        if self.mav.flightmode != mode:
            raise SitlError(f"mode {mode} not accepted (in {self.mav.flightmode}); {self.last_texts()}")

    def last_texts(self, n: int = 4) -> str:
        return " | ".join(self.texts[-n:]) or "no status text"

    def arm(self, timeout_s: float = 90.0) -> list[str]:
        """Arm (retrying while the EKF settles); the pre-arm refusals seen on the way are returned."""
        refusals: list[str] = []
        end = self.boot_ms + timeout_s * 1000
        while self.boot_ms < end:
            self.texts.clear()
            self.mav.arducopter_arm()
            self.wait(2, lambda m: m.get_type() == "HEARTBEAT" and self.mav.motors_armed())
            if self.mav.motors_armed():
                return refusals
            refusals += [t for t in self.texts if "Arm" in t or "PreArm" in t]
            self.wait(2)
        raise SitlError(f"would not arm in {timeout_s} s: {sorted(set(refusals))[-4:]}")

    def altitude(self) -> float:
        msg = self.wait(5, lambda m: m.get_type() == "GLOBAL_POSITION_INT")
        return msg.relative_alt / 1000.0

    def takeoff(self, alt_m: float) -> None:
        self.mav.mav.command_long_send(self.mav.target_system, self.mav.target_component,
                                       mavutil.mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, alt_m)
        msg = self.wait(40, lambda m: m.get_type() == "GLOBAL_POSITION_INT" and
                        m.relative_alt > (alt_m - 0.3) * 1000)
        if msg is None:
            raise SitlError(f"take-off to {alt_m} m did not get there; {self.last_texts()}")
        self.wait(8)  # settle (and let the hover throttle learn)

    def land(self) -> None:
        self.set_mode("LAND")
        self.wait(90, lambda m: m.get_type() == "HEARTBEAT" and not self.mav.motors_armed())

    def mrft(self, axis: str, beta: float, h: float, delay_ms: float, duration_s: float,
             eth: float = 0.0) -> dict[str, Any]:
        """One relay test by the Lua script; returns what was asked and the script's messages.

        ``eth``: the start threshold [output units]: the first half-cycle holds until the error passes
        it on the other side (a kick that starts the cycle near its amplitude instead of from noise).
        """
        for name, value in (("MRFT_BETA", beta), ("MRFT_H", h), ("MRFT_DLY", delay_ms),
                            ("MRFT_DUR", duration_s), ("MRFT_ETH", eth)):
            self.set_param(name, value)
        self.texts.clear()
        t0 = self.boot_ms / 1000
        self.set_param("MRFT_AXIS", AXES[axis])
        self.wait(duration_s + 5, lambda m: m.get_type() == "STATUSTEXT" and "MRFT: test ended" in m.text)
        ended = [t for t in self.texts if t.startswith("MRFT")]
        self.wait(6)  # back in GUIDED's hold between tests
        return {"beta": beta, "h": h, "delay_ms": delay_ms, "duration_s": duration_s, "start_threshold": eth,
                "start_s": round(t0, 2), "script": ended}

    def newest_log(self) -> Path:
        logs = sorted((self.workdir / "logs").glob("*.BIN"), key=os.path.getmtime)
        if not logs:
            raise SitlError(f"no DataFlash log in {self.workdir / 'logs'}")
        return logs[-1]


def read_param_file(path: Path) -> dict[str, float]:
    """``NAME,VALUE`` (or ``NAME VALUE``) lines of a .param file; ``#`` comments skipped."""
    out: dict[str, float] = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        name, value = line.replace(",", " ").split()[:2]
        out[name] = float(value)
    return out


def load_params(sitl: Sitl, params: dict[str, float]) -> list[dict[str, Any]]:
    """Set each parameter, then read every one back; rows say what came back and whether it changed."""
    rejected = set()
    for name, value in params.items():
        try:
            sitl.set_param(name, value)
        except SitlError:  # the firmware has no such parameter: it does not answer
            rejected.add(name)
    rows = []
    for name, value in params.items():
        back = math.nan if name in rejected else sitl.get_param(name)
        same = math.isclose(back, value, rel_tol=1e-5, abs_tol=1e-6)
        rows.append({"name": name, "written": value, "read_back": back, "unchanged": same})
    return rows


def firmware_version(sitl: Sitl) -> str:
    """The firmware's name and version (``THISFIRMWARE`` in ArduCopter/version.h of the build)."""
    import re

    text = (sitl.ap_dir / "ArduCopter" / "version.h").read_text()
    match = re.search(r'#define THISFIRMWARE "([^"]+)"', text)
    return match.group(1) if match else "ArduCopter (version.h not readable)"


#: the main loop's rate (SCHED_LOOP_RATE, ArduCopter's default) [Hz]
LOOP_HZ = 400.0
#: the first-order filter on the relay's path that plays eq. (2)'s Tp: SITL's motors have no lag, so
#: the altitude tests go through ArduPilot's throttle filter (PILOT_THR_FILT, applied by
#: set_throttle_out) and the roll/pitch tests through the rate PID's target filter (ATC_RAT_*_FLTT,
#: which filters the feed-forward the script drives), each at a known cutoff [Hz]
TP_FILTER = {"altitude": ("PILOT_THR_FILT", 5.0), "roll": ("ATC_RAT_RLL_FLTT", 20.0),
             "pitch": ("ATC_RAT_PIT_FLTT", 20.0)}


def tp_of_filter(cutoff_hz: float, rate_hz: float = LOOP_HZ) -> float:
    """Time constant [s] of ArduPilot's first-order low-pass at ``rate_hz``.

    ``y_k = y_(k-1) + a (x_k - y_(k-1))``, ``a = T / (T + 1/(2 pi f))``: the pole ``1 - a`` is that of a
    continuous lag ``-T / ln(1 - a)`` (33.1 ms at 5 Hz, 9.15 ms at 20 Hz, 400 Hz), advanced by one
    sample T (the filter takes the new input in the same tick), which the identified delay absorbs.
    """
    dt = 1.0 / rate_hz
    alpha = dt / (dt + 1.0 / (2.0 * math.pi * cutoff_hz))
    return -dt / math.log(1.0 - alpha)


def has_main_loop_relay(ap_dir: Path) -> bool:
    """Whether the tree carries the main-loop relay (``ardupilot_patch/apply_patch.py``, run by the build)."""
    return (ap_dir / "ArduCopter" / "MRFT_task.cpp").exists()


def fly_mrft(ap_dir: Path, workdir: Path, axis: str, tests: list[tuple[float, float]], delay_ms: float,
             duration_s: float, speedup: float, alt_m: float = 10.0, eth: float = 0.0,
             tick_ms: float = 1.0, main_loop: bool | None = None) -> dict[str, Any]:
    """Take off, run ``tests`` ((beta, h) pairs) on ``axis``, land; the log and how it was flown.

    ``main_loop``: the relay as the firmware's main-loop task (the patched build; ``None``: when the tree
    has it), else in the Lua script at most every ``tick_ms`` of simulated time.
    """
    filt_name, filt_hz = TP_FILTER[axis]
    main = has_main_loop_relay(ap_dir) if main_loop is None else main_loop
    if main and delay_ms * LOOP_HZ / 1000 != round(delay_ms * LOOP_HZ / 1000):
        raise SitlError(f"--delay-ms {delay_ms:g} is not a whole number of {1000 / LOOP_HZ:g} ms loop ticks")
    with Sitl(ap_dir, workdir, speedup, {filt_name: filt_hz}) as sitl:
        sitl.wait(3)
        version = firmware_version(sitl)
        sitl.set_mode("GUIDED")
        refusals = sitl.arm()
        sitl.takeoff(alt_m)
        hover = sitl.get_param("MOT_THST_HOVER")
        sitl.set_param("MRFT_TICK", tick_ms)
        sitl.set_param("MRFT_MAIN", int(main))
        runs = [sitl.mrft(axis, beta, h, delay_ms, duration_s, eth) for beta, h in tests]
        sitl.land()
        sitl.wait(2)
        log = sitl.newest_log()
    relay = ({"relay": "main-loop task (scripts/sitl/ardupilot_patch), started by scripts/sitl/mrft_relay.lua",
              "relay_rate_hz": LOOP_HZ, "added_delay_ticks": round(delay_ms * LOOP_HZ / 1000)} if main else
             {"relay": "scripts/sitl/mrft_relay.lua", "script_period_ms": 2, "script_min_tick_ms": tick_ms})
    return {"stack": "ArduPilot SITL", "version": version,
            "frame": "quad (SITL --model quad: the plus frame quad_plus_motors; copter.parm FRAME_TYPE 0, plus)",
            "loop": axis, **relay, "loop_rate_hz": LOOP_HZ, "speedup": speedup,
            "hover_throttle": logged_hover(log), "MOT_THST_HOVER_saved": hover, "added_delay_ms": delay_ms,
            "tp_s": tp_of_filter(filt_hz), "tp_source": f"{filt_name} = {filt_hz:g} Hz first-order filter at "
            f"{LOOP_HZ:g} Hz (SITL's motors have no lag)",
            "tests": runs, "prearm_refusals_before_arming": sorted(set(refusals)), "log": str(log)}


def logged_hover(log: Path) -> float | None:
    """The hover throttle GUIDED used before the tests (the mean of the log's ``MRFB:Hov``), or None."""
    from mrftcli.io import open_log

    try:
        with open_log(log, echo_warnings=False) as src:
            _, m = src.read("MRFB", ["Hov"])
    except Exception:  # noqa: BLE001 - a log without the field: the sidecar says None
        return None
    return round(float(sum(m["Hov"]) / len(m["Hov"])), 5)


def _tests(text: str) -> list[tuple[float, float]]:
    return [(float(b), float(h)) for b, h in (item.split(":") for item in text.split(","))]


@dataclass(frozen=True)
class FlyCommand:
    """What differs between the stacks' ``fly`` commands (this script's and ``px4/px4_sitl.py``'s)."""

    description: str
    tree_option: str  #: the built tree's option, e.g. ``--ap``
    tree_help: str
    axes: tuple[str, ...]
    h_help: str  #: what h is in this stack
    delay_help: str
    log_name: str  #: "DataFlash log", "ULog"
    workdir: Path


def fly_command(argv: list[str] | None, cmd: FlyCommand, fly: Any) -> int:
    """The ``fly`` command of a stack's harness: take off, run MRFT tests on one loop, land, keep the log
    and its JSON sidecar (``fly(tree, workdir, axis, tests, delay_ms, duration, speedup)`` -> the sidecar's
    dict with the log's path under ``log``)."""
    ap = argparse.ArgumentParser(description=cmd.description)
    sub = ap.add_subparsers(dest="cmd", required=True)
    parser = sub.add_parser("fly", help=f"take off, run MRFT tests on one loop, land, keep the {cmd.log_name}")
    parser.add_argument(cmd.tree_option, dest="tree", type=Path, required=True, help=cmd.tree_help)
    parser.add_argument("--axis", choices=sorted(cmd.axes), required=True)
    parser.add_argument("--tests", required=True, help=f"beta:h,beta:h,... (h: {cmd.h_help})")
    parser.add_argument("--delay-ms", type=float, default=0.0, help=cmd.delay_help)
    parser.add_argument("--duration", type=float, default=12.0, help="each test's length [s]")
    parser.add_argument("--speedup", type=float, default=1.0)
    parser.add_argument("--workdir", type=Path, default=cmd.workdir)
    parser.add_argument("--out", type=Path, required=True, help=f"where to copy the {cmd.log_name}")
    args = ap.parse_args(argv)
    if args.out.exists():
        print(f"error: {args.out} exists; choose another --out", file=sys.stderr)
        return 2
    try:
        info = fly(args.tree, args.workdir, args.axis, _tests(args.tests), args.delay_ms, args.duration, args.speedup)
    except SitlError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    shutil.copy(info.pop("log"), args.out)
    Path(f"{args.out}.json").write_text(json.dumps(info, indent=2) + "\n")
    print(f"wrote {args.out} and {args.out}.json")
    return 0


def main(argv: list[str] | None = None) -> int:
    return fly_command(argv, FlyCommand(
        __doc__.split("\n\n")[0], "--ap", "built ArduPilot tree", tuple(AXES), "throttle or mixer units",
        "relay output delay inside the script [ms]", "DataFlash log", Path("/tmp/mrft_sitl")), fly_mrft)


if __name__ == "__main__":
    raise SystemExit(main())
