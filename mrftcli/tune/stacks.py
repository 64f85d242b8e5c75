"""Gains as the flight stacks load them: the cascade mappings, the stacks' ranges, their filters and files.

Each stack is a :class:`Stack`: the rate and the filter on the measured rate it really runs (so that
``tune --export`` designs the loop the vehicle will fly, :func:`stack_setting`), the mapping of a
PD on the loop's output onto its parameters and back (:func:`export_design`), and the file it loads
(:meth:`StackExport.file_text`).

* **PX4** roll/pitch: the angle P feeding the rate PID (``src/lib/rate_control/rate_control.cpp``:
  torque = K (P e_rate + I int e_rate + D d(e_rate)) with the rate loop's I, D and FF at 0) is
  u = P_rate (P_att (r - y) - y'), a PD with the derivative on the measurement: ``MC_ROLL_P`` =
  Kp / Kd, ``MC_ROLLRATE_P`` = Kd. The measured rate goes through ``IMU_GYRO_CUTOFF``, one
  2nd-order Butterworth for all three axes (yaw included), and the rate loop runs at
  ``IMU_GYRO_RATEMAX`` (100, 250, 400, 800, 1000 or 2000 Hz).
* **PX4** altitude: ``MPC_Z_P`` (m -> m/s) feeding the vertical velocity PID (m/s -> m/s^2), with
  thrust = acceleration x hover thrust / g: u = (h/g) P_vel (P_z e - v), so ``MPC_Z_P`` = Kp / Kd and
  ``MPC_Z_VEL_P_ACC`` = Kd g / h. PX4 requires ``MPC_Z_VEL_I_ACC`` >= 0.2: the export sets that
  minimum and recomputes the margins with it (its integral adds (h/g) I_acc to the loop's
  proportional gain and (h/g) I_acc P_z as integral gain).
* **PX4** x/y: ``MPC_XY_P`` feeding the horizontal velocity PID the same way, thrust_x = acceleration x hover
  thrust / g (``PositionControl::_accelerationControl``: exact below the tilt limit), so ``MPC_XY_P`` = Kp / Kd and
  ``MPC_XY_VEL_P_ACC`` = Kd g / h; but PX4 also feeds back the velocity's derivative, ``MPC_XY_VEL_D_ACC`` (>= 0.1)
  times (v_k - v_{k-1}) / T through an alpha filter at ``MPC_VELD_LP`` (:class:`PX4VelocityPath`): the export
  sets it at its minimum, designs the PD with it (:func:`_inside_ranges`) and reports the margins of that loop.
* **ArduPilot** roll/pitch: ``ATC_ANG_RLL_P`` feeding the ``ATC_RAT_RLL_*`` PID (rad/s error ->
  motor output), the same mapping as PX4's; the gyro goes through ``INS_GYRO_FILTER`` (2nd-order
  Butterworth, ``LowPassFilter2p``). ``ATC_RAT_RLL_I`` >= 0.01 is documented: set at that minimum,
  the margins recomputed with it.
* **ArduPilot** altitude: ``AC_PosControl``'s z cascade ``PSC_POSZ_P`` -> ``PSC_VELZ_*`` ->
  ``PSC_ACCZ_*`` (the innermost loop on the IMU's vertical acceleration, the throttle through a 2 Hz
  filter), designed by :mod:`mrftcli.tune.ardupilot_z` so that its margins hold for every split of the
  identified tau between the motors and the sensors (the split is not identifiable from one altitude test:
  stated first in the output, in :attr:`StackExport.assumptions`). Needs ``--hover-thrust``
  (``MOT_THST_HOVER``): the command must be ArduPilot's throttle, K about g / hover.
* **HEAR** (HEAR_FC): the PID of ``PID_param.msg`` computes u += kd PV_DOT and HEAR_FC feeds PV_DOT
  through a Gain(-1) block, i.e. PV_DOT = -(filtered rate); the rate is filtered by HEAR_FC's own
  2nd-order Butterworth (50 Hz at 200 Hz), which the design uses.

  HEAR_FC's outer loops (x, y, z) filter the velocity with their own Butterworth (rate/12, 16.7 Hz at 200 Hz,
  :data:`HEAR_OUTER_CUTOFF_RATIO`); the z command is HEAR's acceleration [m/s^2] (converted x K, stated).

The stacks' ranges are constraints of the design (:func:`_inside_ranges`, issue 37): values outside are
replaced by the design inside them that keeps the PD's worst Ms, its cost stated; a value still outside
is refused, or with ``clamp`` set to the bound, and the margins of the loop the written values give (with
the stack's filter) are reported. ArduPilot's files use the names of ``version``
(:mod:`mrftcli.tune.ardupilot_versions`) and every pre-arm rule on their values is checked. The design
rate is the stack's (PX4 ``IMU_INTEG_RATE``, ArduPilot ``SCHED_LOOP_RATE``, HEAR's nodelets), never the
log's; vehicle-wide rates are not written.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..jsonable import check_schema_version
from ..errors import InputError
from ..io.hover import HOVER_TOPIC, LoggedHoverThrust
from ..mrft.cascade import STANDARD_GRAVITY
from ..mrft.model import LoopModel
from ..mrft.controller import PX4VelocityPath
from .closed_loop import Controller, PlantStack, RateFilter, as_discrete
from .export import unit_reasons
from .margins import Margins, loop_margins, margin_response, stack_sensitivity
from .px4_xy import px4_xy_controller, px4_xy_ticks, written_loop
from .stack_params import check_ranges, param

__all__ = ["PX4_ATTITUDE_RATES_HZ", "EXPORTS", "PX4VelocityPath", "StackSetting", "StackExport", "ExportEvidence", "stack_setting",
           "check_exportable", "check_hover_thrust", "check_xy_integral", "export_design", "cascade_params", "px4_xy_controller",
           "HOVER_LOOPS", "hover_thrust_refusal", "read_hover_thrust",
           "UNIT_TOLERANCE", "check_units", "HEAR_FILTER_HZ", "HEAR_RATE_HZ", "EXPORT_SCHEMA_VERSION"]

#: ``tune --export`` choices.
EXPORTS = ("generic", "px4", "ardupilot", "hear")
#: K hover / g may differ from 1 by this factor before the command is refused as not the stack's thrust (throttle).
UNIT_TOLERANCE = 2.0
#: HEAR_FC's rate filter: 2nd-order Butterworth at 50 Hz, run at 200 Hz (tracker issue 25, InnerSysNodelet.cpp).
HEAR_FILTER_HZ, HEAR_RATE_HZ = 50.0, 200.0
#: HEAR_FC's outer loops (x, y, z; oussamaabdulhay/HEAR_FC Flight_controller/HEAR_nodelet/OuterSysNodelet.cpp
#: @11421487): the velocity through ``BWFilter2`` with ``coeff_120Hz_2nd_butter_5hz``, whose coefficients
#: (a1 -1.27963, a2 0.477592, b 0.04949, 0.09898, 0.04949) are a 2nd-order Butterworth at 1/12 of the sampling
#: rate (scipy.signal.butter(2, 1/6): 10 Hz at 120 Hz, despite the name), run at ``FREQUENCY`` 200 Hz
#: (OuterSysNodelet.h @3a375019): 16.7 Hz. The z command is an acceleration [m/s^2]: PID + ``BIAS_Z_VALUE`` 9.8,
#: saturated at ``SAT_Z_VALUE`` 22.
HEAR_OUTER_CUTOFF_RATIO, HEAR_OUTER_RATE_HZ, HEAR_Z_BIAS, HEAR_Z_SAT = 1.0 / 12.0, 200.0, 9.8, 22.0
_HEAR_OUTER = ("x", "y", "altitude")
#: Version of :meth:`StackExport.to_json`'s object.
EXPORT_SCHEMA_VERSION = 1
#: Integral gains a PD leaves at 0 but the stack requires above a minimum: set to it (not a refusal).
_STRUCTURAL = {"MC_ROLLRATE_I", "MC_PITCHRATE_I", "MPC_Z_VEL_I_ACC", "ATC_RAT_RLL_I", "ATC_RAT_PIT_I",
               "MPC_XY_VEL_D_ACC"}
#: PX4's horizontal loops (mc_pos_control: the velocity PID with the velocity's filtered derivative)
_PX4_XY = ("x", "y")
#: The loops whose export needs the hover thrust (``--hover-thrust``; PX4's is read from the log's estimate when
#: not given: :func:`mrftcli.io.hover.logged_hover_thrust`), by stack.
HOVER_LOOPS = {"px4": ("altitude", *_PX4_XY), "ardupilot": ("altitude",)}
_AXIS_AP = {"roll": "RLL", "pitch": "PIT"}
#: The stack's hover parameter (``--hover-thrust``) and its scale, and why its log does not give it
_HOVER_PARAM = {"px4": "MPC_THR_HOVER, normalised 0-1", "ardupilot": "MOT_THST_HOVER, throttle 0-1"}
_HOVER_NOT_LOGGED = {"px4": f"the log holds no valid {HOVER_TOPIC} to read it from",
                     "ardupilot": "it is not read from ArduPilot's log (CTUN.ThH holds the saved value until "
                                  "ArduPilot has learned it)"}


def hover_thrust_refusal(stack: str, loops: Sequence[str], *, from_log: bool = False) -> InputError:
    """The one-line error when the ``stack`` export of ``loops`` (of :data:`HOVER_LOOPS`) needs ``--hover-thrust``
    and it is not given: why the stack needs it, or (``from_log``: a log was there to read) why the log did not
    give it."""
    head = f"give --hover-thrust X ({_HOVER_PARAM[stack]}): "
    if from_log:
        return InputError(f"{head}the {stack} export of the {', '.join(loops)} loop{'s' if len(loops) > 1 else ''} "
                          f"needs it and {_HOVER_NOT_LOGGED[stack]}")
    if stack == "ardupilot":
        return InputError(f"{head}ArduPilot adds it to the acceleration loop's output, and the identified K must be "
                          "its throttle's (about g / X)")
    return InputError(f"{head}PX4's {'vertical' if 'altitude' in loops else 'horizontal'} velocity loop outputs "
                      "acceleration, converted to thrust by hover thrust / g")


def read_hover_thrust(stack: str | None, loops: Sequence[str], given: float | None,
                          read: Callable[[], LoggedHoverThrust | None], *,
                          optional: Sequence[str] = ()) -> LoggedHoverThrust | None:
    """The hover thrust the ``stack`` export of ``loops`` needs (:data:`HOVER_LOOPS`) when ``--hover-thrust`` is not
    ``given``: PX4's estimate, ``read()`` from the log (:func:`mrftcli.io.hover.logged_hover_thrust`; called only
    then); None when given or not needed, or when the log holds none and only ``optional`` loops need it.

    Raises
    ------
    InputError
        A loop outside ``optional`` needs it, it is not given and the log does not hold it
        (:func:`hover_thrust_refusal`).
    """
    if stack is None or given is not None:
        return None
    needs = [loop for loop in loops if loop in HOVER_LOOPS.get(stack, ())]
    logged = read() if needs and stack == "px4" else None
    required = [loop for loop in needs if loop not in optional]
    if logged is None and required:
        raise hover_thrust_refusal(stack, required, from_log=True)
    return logged


def check_exportable(stack: str, loop: str, kind: str, hover_thrust: float | None = None) -> None:
    """InputError (before any work) when ``stack`` cannot take a ``kind`` design of ``loop``."""
    if stack not in EXPORTS:
        raise InputError(f"unknown export {stack!r}; choose from {', '.join(EXPORTS)}")
    if stack in ("px4", "ardupilot") and kind != "PD":
        raise InputError(f"cannot export a PID to {stack}: its rate-loop (velocity-loop) I acts on the measured "
                         "rate, not on the error of a parallel PID; export the PD (--kind PD)")
    if stack == "ardupilot" and loop not in ("roll", "pitch", "altitude"):
        raise InputError(f"cannot export the {loop} loop to ArduPilot: only roll and pitch (the angle-P / rate-PID "
                         "cascade) and altitude (AC_PosControl's z cascade) map")
    if stack == "px4" and loop not in ("roll", "pitch", "altitude", *_PX4_XY):
        raise InputError(f"cannot export the {loop} loop to PX4: only roll, pitch, altitude, x and y map onto its "
                         "cascades")
    if loop in HOVER_LOOPS.get(stack, ()) and hover_thrust is None:
        raise hover_thrust_refusal(stack, (loop,))
    if hover_thrust is not None:
        check_hover_thrust(stack, hover_thrust, loop)


def check_hover_thrust(stack: str, hover_thrust: float, loop: str = "altitude") -> None:
    """InputError unless ``hover_thrust`` (``--hover-thrust``) is a normalised thrust in (0, 1) and, for
    ArduPilot's altitude loop (the one that takes it), inside ``MOT_THST_HOVER``'s range."""
    if not (0.0 < hover_thrust < 1.0):
        raise InputError(f"--hover-thrust must be a normalised thrust in (0, 1), got {hover_thrust}")
    row = param("ardupilot", "MOT_THST_HOVER")
    if stack == "ardupilot" and loop == "altitude" and not row.contains(hover_thrust):
        raise InputError(f"--hover-thrust {hover_thrust:g} is outside MOT_THST_HOVER's range {row.minimum:g}-"
                         f"{row.maximum:g} (AP_MotorsMulticopter.cpp): give the vehicle's learned hover throttle")


@dataclass(frozen=True)
class StackSetting:
    """The loop a stack really runs: its controller rate [Hz], its filter on the measured rate, notes."""

    stack: str
    rate_hz: float
    rate_filter: RateFilter | None
    notes: tuple[str, ...]


def _log_rate_cost(rate: float, rate_source: float | None) -> tuple[str, ...]:
    """What designing at the stack's ``rate`` [Hz] from a log at ``rate_source`` [Hz] means (never advice to change
    the vehicle's rate: those are vehicle-wide and need a reboot)."""
    if rate_source is None or abs(rate_source - rate) <= 1e-6 * rate:
        return ()
    return (f"the log records at {rate_source:g} Hz, the stack runs this loop at {rate:g} Hz: designed at {rate:g} Hz "
            "(the vehicle's rate is not changed: it is vehicle-wide and needs a reboot); the log's sampling adds up "
            f"to {1e3 / rate_source:.1f} ms of delay to the identified tau, which the design carries as plant delay "
            f"(conservative when the vehicle runs at {rate:g} Hz)",)


#: PX4's ``IMU_INTEG_RATE`` choices [Hz] (imu_parameters.yaml): the EKF's, hence the attitude loop's, rate.
PX4_ATTITUDE_RATES_HZ = (100.0, 200.0, 250.0, 400.0)


def _px4_rate(rate_given: float | None, rate_source: float | None) -> tuple[float, tuple[str, ...]]:
    """PX4's attitude loop (mc_att_control) runs on each attitude estimate, at ``IMU_INTEG_RATE``: the vehicle's
    (--controller-rate) or its default 200 Hz. The rate loop runs faster, at ``IMU_GYRO_RATEMAX`` (default 400
    Hz); the design models both at the attitude rate (the rate path's extra delay at the slower rate is
    conservative)."""
    rows = param("px4", "IMU_INTEG_RATE"), param("px4", "IMU_GYRO_RATEMAX")
    both = (f"the rate loop runs at IMU_GYRO_RATEMAX (default {rows[1].default:g} Hz), modelled at the attitude rate "
            "(conservative); neither is written: both are vehicle-wide and reboot_required")
    if rate_given is not None:
        if rate_given not in PX4_ATTITUDE_RATES_HZ:
            raise InputError(f"--controller-rate {rate_given:g}: PX4's attitude loop runs at IMU_INTEG_RATE, one of "
                             f"{', '.join(f'{r:g}' for r in PX4_ATTITUDE_RATES_HZ)} Hz: give the vehicle's")
        return rate_given, (f"designed at IMU_INTEG_RATE = {rate_given:g} Hz (--controller-rate, the vehicle's "
                            f"attitude-loop rate); {both}", *_log_rate_cost(rate_given, rate_source))
    rate = rows[0].default
    return rate, (f"designed at IMU_INTEG_RATE = {rate:g} Hz, PX4's default (imu_parameters.yaml), the attitude loop's "
                  f"rate: give --controller-rate HZ if the vehicle's differs; {both}",
                  *_log_rate_cost(rate, rate_source))


def _ardupilot_rate(rate_given: float | None, rate_source: float | None) -> tuple[float, tuple[str, ...]]:
    """ArduPilot's main loop rate [Hz] (``SCHED_LOOP_RATE``), at which its attitude and z loops run: the vehicle's
    (--controller-rate) or Copter's default 400 Hz; never the log's."""
    row = param("ardupilot", "SCHED_LOOP_RATE")
    if rate_given is None:
        return row.default, (f"designed at SCHED_LOOP_RATE = {row.default:g} Hz, Copter's default (AP_Scheduler.cpp "
                             "SCHEDULER_DEFAULT_LOOP_RATE): give --controller-rate HZ if the vehicle's differs (it is "
                             "vehicle-wide, @RebootRequired: never changed for one loop)",
                             *_log_rate_cost(row.default, rate_source))
    if not row.contains(rate_given):
        raise InputError(f"--controller-rate {rate_given:g} Hz is outside SCHED_LOOP_RATE's range {row.minimum:g}-"
                         f"{row.maximum:g} Hz (AP_Scheduler.cpp): give the vehicle's main loop rate")
    return rate_given, (f"designed at SCHED_LOOP_RATE = {rate_given:g} Hz (--controller-rate, the vehicle's)",
                        *_log_rate_cost(rate_given, rate_source))


def stack_setting(stack: str, loop: str, rate_given: float | None, rate_source: float | None,
                  gyro_cutoff_hz: float | None) -> StackSetting:
    """The rate and rate filter ``stack`` runs for ``loop``, and the notes that state them.

    ``rate_given``: --controller-rate (the vehicle's rate); ``rate_source``: the rate the log records (never the
    design rate of a stack that has its own); ``gyro_cutoff_hz``: --gyro-cutoff (default: the stack's default
    cutoff, stated in the notes).
    """
    if stack == "generic":
        rate = rate_given or rate_source
        if rate is None:
            raise InputError("give --controller-rate HZ, the rate the controller runs at")
        return StackSetting(stack, rate, None, ())
    if stack == "hear" and loop in _HEAR_OUTER:
        rate = rate_given or HEAR_OUTER_RATE_HZ
        cut = HEAR_OUTER_CUTOFF_RATIO * rate
        notes = (f"HEAR_FC's outer loops (OuterSysNodelet) filter the velocity with BWFilter2 coeff_120Hz_2nd_butter_5hz, "
                 f"a 2nd-order Butterworth at 1/12 of the loop rate: {cut:.3g} Hz at {rate:g} Hz; designed with it"
                 + ("" if rate_given else " (HEAR_FC's outer-loop FREQUENCY; --controller-rate to change)"),)
        return StackSetting(stack, rate, RateFilter(cut, "HEAR_FC outer velocity filter"), notes)
    if stack == "hear":
        rate = rate_given or HEAR_RATE_HZ
        notes = (f"HEAR_FC filters the rate with a 2nd-order Butterworth at {HEAR_FILTER_HZ:g} Hz; designed with it "
                 f"at {rate:g} Hz" + ("" if rate_given else " (HEAR_FC's inner-loop rate; --controller-rate to change)"),)
        return StackSetting(stack, rate, RateFilter(HEAR_FILTER_HZ, "HEAR_FC rate filter"), notes)
    if stack == "ardupilot" and loop == "altitude":
        rate, ap_notes = _ardupilot_rate(rate_given, rate_source)
        return StackSetting(stack, rate, RateFilter(0.0, "none"), (
            *ap_notes, "AC_PosControl runs the z cascade every main-loop tick"))
    if stack == "px4" and (loop == "altitude" or loop in _PX4_XY):
        rate = rate_given or rate_source
        if rate is None:
            raise InputError("give --controller-rate HZ, the rate of PX4's position controller (the local position's rate)")
        if loop == "altitude":
            return StackSetting(stack, rate, RateFilter(0.0, "none"), (
                f"PX4 altitude: designed at {rate:g} Hz with the vertical velocity unfiltered (PX4 uses the EKF's "
                "estimate; its lag is not modelled)",))
        return StackSetting(stack, rate, RateFilter(0.0, "none"), (
            f"PX4 {loop}: designed at {rate:g} Hz with the horizontal velocity unfiltered (MPC_VEL_LP 0 and "
            "MPC_VEL_NF_FRQ 0, PX4's defaults, not written; PX4 uses the EKF's estimate, its lag is not modelled)",
            f"PX4 has one MPC_XY_* set for x and y (PositionControl applies it to both axes): these values, designed "
            f"on {loop}, set both loops; loading the other axis's export replaces them"))
    name, default = ("IMU_GYRO_CUTOFF", param("px4", "IMU_GYRO_CUTOFF").default) if stack == "px4" else \
        ("INS_GYRO_FILTER", param("ardupilot", "INS_GYRO_FILTER").default)
    cutoff = default if gyro_cutoff_hz is None else gyro_cutoff_hz
    said = (f"{name} = {cutoff:g} Hz" + (f" ({stack}'s default; --gyro-cutoff to change)" if gyro_cutoff_hz is None
                                         else " (--gyro-cutoff)")
            + ": one 2nd-order Butterworth on all three axes, so roll and pitch must be tuned with the same value "
              "(tune ROLL.json PITCH.json designs both with one cutoff)")
    rate, rate_notes = _px4_rate(rate_given, rate_source) if stack == "px4" else _ardupilot_rate(rate_given,
                                                                                                 rate_source)
    return StackSetting(stack, rate, RateFilter(cutoff, name), (*rate_notes, said))


@dataclass(frozen=True)
class StackExport:
    """A design as one stack loads it, checked against the stack's ranges.

    Attributes
    ----------
    stack, loop : str
    design : str
        ``"<name> <kind>"`` of the exported design.
    params : dict
        Parameter name -> value, in the order written (HEAR: its message's fields).
    clamped : tuple of (name, value designed, value exported)
        Values set to the stack's bound.
    margins : Margins
        Of the loop the exported values give, with the stack's rate filter and rate (ArduPilot altitude: the
        worst over the splits of tau).
    notes : tuple of str
    assumptions : tuple of str
        What the values rest on that the log cannot show (said first in the output).
    version : str
        The stack version whose names the file uses (ArduPilot: ``4.6`` or ``4.7``; empty: one naming).
    prearm : tuple of dict
        The stack's pre-arm rules on the values written (:func:`mrftcli.tune.ardupilot_versions.prearm_checks`):
        ``rule``, ``value``, ``passed``, ``source``.
    predicted : dict
        PX4 x/y: the loop as written on the nominal model (:func:`mrftcli.tune.px4_xy.px4_xy_prediction`): ``MPC_XY_VEL_I_ACC``, the unit
        position step's ``step_overshoot_pct``, ``step_rise_s``, ``step_settling_s`` and, per 1 m/s^2 of steady
        wind, ``wind_steady_offset_m``, ``wind_peak_offset_m``, ``wind_offset_5s_m``, ``wind_offset_20s_m``
        (empty for the other exports).
    """

    stack: str
    loop: str
    design: str
    params: dict[str, float]
    clamped: tuple[tuple[str, float, float], ...]
    margins: Margins
    notes: tuple[str, ...]
    assumptions: tuple[str, ...] = ()
    version: str = ""
    prearm: tuple[dict[str, Any], ...] = ()
    predicted: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The versioned JSON object (:data:`EXPORT_SCHEMA_VERSION`)."""
        return {"schema_version": EXPORT_SCHEMA_VERSION, "stack": self.stack, "loop": self.loop,
                "design": self.design, "params": dict(self.params),
                "clamped": [{"name": n, "designed": a, "exported": b} for n, a, b in self.clamped],
                "margins": self.margins.to_json(), "notes": list(self.notes), "assumptions": list(self.assumptions),
                "version": self.version, "prearm": [dict(r) for r in self.prearm],
                "predicted": dict(self.predicted)}

    @classmethod
    def from_json(cls, data: Any) -> "StackExport":
        """The record of :meth:`to_json`; InputError (one line) on another version or a malformed field."""
        check_schema_version(data, "stack export", EXPORT_SCHEMA_VERSION)
        try:
            params = {str(k): float(v) for k, v in data["params"].items()}
            clamped = tuple((str(c["name"]), float(c["designed"]), float(c["exported"])) for c in data["clamped"])
            fields = (str(data["stack"]), str(data["loop"]), str(data["design"]))
            notes = tuple(str(n) for n in data["notes"])
            assumptions = tuple(str(n) for n in data.get("assumptions", []))
            version = str(data.get("version", ""))
            prearm = tuple(dict(r) for r in data.get("prearm", []))
            predicted = {str(k): math.nan if v is None else float(v) for k, v in data.get("predicted", {}).items()}
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise InputError(f"stack export: missing or malformed field ({err})") from err
        return cls(*fields, params, clamped, Margins.from_json(data.get("margins")), notes, assumptions, version,
                   prearm, predicted)

    def file_text(self) -> str:
        """What the stack loads: QGroundControl ``.params`` (PX4), ``.param`` (ArduPilot), JSON (HEAR)."""
        if self.stack == "px4":
            return _qgc_params(self)
        if self.stack == "ardupilot":
            head = [f"# mrft-ident tune: {self.design} for {self.loop}, ArduPilot Copter {self.version} parameter names "
                    "(load in Mission Planner / MAVProxy; a ground station skips names the firmware does not have)"]
            head += [f"# assumption: {a}" for a in self.assumptions]
            return "\n".join(head + [f"{n},{_fmt(v)}" for n, v in self.params.items()]) + "\n"
        import json

        return json.dumps(_hear_object(self), indent=2) + "\n"

    def console_lines(self) -> list[str]:
        """PX4 shell / MAVLink console ``param set NAME VALUE`` lines (PX4 only)."""
        return [f"param set {n} {_fmt(v)}" for n, v in self.params.items()] if self.stack == "px4" else []


def _fmt(v: float) -> str:
    return str(int(v)) if float(v).is_integer() and abs(v) >= 1 else f"{v:.6g}"


def _qgc_params(e: StackExport) -> str:
    """QGroundControl's parameter file: tab-separated vehicle id, component id, name, value, MAVLink type
    (9 = REAL32, 6 = INT32); comment lines start with '#'."""
    lines = ["# Onboard parameters for Vehicle 1", "#", "# Stack: PX4 Pro", "# Vehicle: Multi-Rotor",
             f"# mrft-ident tune: {e.design} for {e.loop}", *(f"# assumption: {a}" for a in e.assumptions), "#",
             "# Vehicle-Id Component-Id Name Value Type"]
    ints = {"IMU_GYRO_RATEMAX"}
    for n, v in e.params.items():
        lines.append(f"1\t1\t{n}\t{int(v) if n in ints else format(v, '.18f')}\t{6 if n in ints else 9}")
    return "\n".join(lines) + "\n"


def _hear_object(e: StackExport) -> dict[str, Any]:
    p = e.params
    return {"PID_parameters": {k: (int(v) if k in ("id", "en_pv_derivation") else v) for k, v in p.items()},
            "sign": "HEAR computes u += kd * PV_DOT: feed PV_DOT with the NEGATED filtered rate, -dy/dt (HEAR_FC's "
                    "Gain(-1) block); kd is positive",
            "ros_msg_PID_param": {("id" if k == "id" else f"pid_{k}"): (int(v) if k in ("id", "en_pv_derivation")
                                                                      else v) for k, v in p.items()},
            "rate_filter": (f"HEAR_FC's outer-loop velocity filter, a 2nd-order Butterworth at {1.0 / (12 * p['dt']):.3g} Hz "
                            "(BWFilter2 coeff_120Hz_2nd_butter_5hz at the loop rate; designed with it)"
                            if e.loop in _HEAR_OUTER else
                            f"HEAR_FC's 2nd-order Butterworth at {HEAR_FILTER_HZ:g} Hz (designed with it)")}


def cascade_params(c: Controller, loop: str, stack: str, hover_thrust: float | None,
                   xy_integral: float = 0.0) -> dict[str, float]:
    """The stack's (``px4`` or ``ardupilot``) parameters for the PD ``c`` on ``loop`` (unclamped; the gyro
    cutoff [Hz] the design's rate filter's, 0 without one); PX4 x/y's ``MPC_XY_VEL_I_ACC`` is ``xy_integral``
    [(m/s^2)/m] (``--xy-integral``)."""
    rate_filter = c.rate_filter
    if stack == "px4" and loop == "altitude":
        assert hover_thrust is not None  # check_exportable asked for it
        return {"MPC_Z_P": c.Kp / c.Kd, "MPC_Z_VEL_P_ACC": c.Kd * STANDARD_GRAVITY / hover_thrust,
                "MPC_Z_VEL_I_ACC": 0.0, "MPC_Z_VEL_D_ACC": 0.0}
    if stack == "px4" and loop in _PX4_XY:
        assert hover_thrust is not None  # check_exportable asked for it
        return {"MPC_XY_P": c.Kp / c.Kd, "MPC_XY_VEL_P_ACC": c.Kd * STANDARD_GRAVITY / hover_thrust,
                "MPC_XY_VEL_I_ACC": xy_integral, "MPC_XY_VEL_D_ACC": 0.0,
                "MPC_VELD_LP": param("px4", "MPC_VELD_LP").default}
    cutoff = rate_filter.cutoff_hz if rate_filter is not None else 0.0
    if stack == "px4":
        ax = loop.upper()
        return {f"MC_{ax}_P": c.Kp / c.Kd, f"MC_{ax}RATE_P": c.Kd, f"MC_{ax}RATE_I": 0.0, f"MC_{ax}RATE_D": 0.0,
                f"MC_{ax}RATE_K": 1.0, f"MC_{ax}RATE_FF": 0.0, "IMU_GYRO_CUTOFF": cutoff}
    ax = _AXIS_AP[loop]
    return {f"ATC_ANG_{ax}_P": c.Kp / c.Kd, f"ATC_RAT_{ax}_P": c.Kd, f"ATC_RAT_{ax}_I": 0.0,
            f"ATC_RAT_{ax}_D": 0.0, f"ATC_RAT_{ax}_FF": 0.0, f"ATC_RAT_{ax}_FLTE": 0.0,
            f"ATC_RAT_{ax}_FLTT": 100.0, "INS_GYRO_FILTER": cutoff}


def _loop_controller(p: dict[str, float], c: Controller, loop: str, stack: str,
                     hover_thrust: float | None) -> Controller:
    """The controller from -y to u that the stack's values ``p`` give (the loop's C_fb: the margins depend on
    nothing else). A rate-loop integral I_r on (P_a e - y') adds I_r to the proportional gain on y and
    I_r P_a as integral gain (so is it for PX4's velocity loop, scaled by h / g)."""
    ratio, gain, integral = _names(stack, loop)
    if stack == "px4" and loop == "altitude":
        assert hover_thrust is not None
        s = hover_thrust / STANDARD_GRAVITY
        pz, pv, iv = p[ratio], p[gain], p[integral]
        return Controller(s * (pv * pz + iv), s * iv * pz, s * pv, c.Tf, c.rate_hz, c.rate_filter)
    if stack == "px4" and loop in _PX4_XY:
        assert hover_thrust is not None
        return px4_xy_controller(p, c.rate_hz, hover_thrust)
    # PX4's rate P acts times its MC_*RATE_K (ArduPilot has none)
    pa, pr, ir = p[ratio], p[gain] * (p[f"MC_{loop.upper()}RATE_K"] if stack == "px4" else 1.0), p[integral]
    return Controller(pr * pa + ir, ir * pa, pr, c.Tf, c.rate_hz, c.rate_filter)


@dataclass(frozen=True)
class ExportEvidence:
    """What the analysis a design came from says, for its export (in-process, not written as JSON).

    Attributes
    ----------
    heights : tuple of float
        The relay heights flown [command units]: over 1, the command was not the stack's normalised one.
    amplitudes : tuple of float
        The tests' amplitudes [output units]: over 1 on roll or pitch, not radians.
    notes : tuple of str
        The analysis's notes, carried into the export's.
    posterior_models : tuple of LoopModel
        The posterior's 95 % set, which the range-constrained designs and ArduPilot's altitude cascade are
        held on.
    hover_source : str
        Where the hover thrust came from when it was read from the log, not given
        (:meth:`mrftcli.io.hover.LoggedHoverThrust.statement`): the export's first assumption where its loop
        needs the hover thrust (:data:`HOVER_LOOPS`); empty when given.
    """

    heights: tuple[float, ...] = ()
    amplitudes: tuple[float, ...] = ()
    notes: tuple[str, ...] = ()
    posterior_models: tuple[LoopModel, ...] = ()
    hover_source: str = ""


def export_design(stack: str, c: Controller, model: LoopModel, loop: str, design: str, *, clamp: bool = False,
                  hover_thrust: float | None = None, version: str | None = None,
                  evidence: ExportEvidence = ExportEvidence(), xy_integral: float | None = None) -> StackExport:
    """``c`` (designed with the stack's rate and filter, :func:`stack_setting`) as ``stack`` loads it.

    ``version``: ArduPilot's (``--stack-version``; default the current stable release, named in the file);
    ``evidence``: the relay heights and amplitudes flown, the analysis's notes, the posterior's 95 % set and where
    ``hover_thrust`` came from when not given, said first (:class:`ExportEvidence`); ``xy_integral``: PX4 x/y's
    ``MPC_XY_VEL_I_ACC`` [(m/s^2)/m] (None: 0, a PD, whose steady wind offset is stated), designed with and
    written.

    Raises
    ------
    InputError
        The loop, kind or units do not map (the reasons), a value is outside the stack's documented
        range and ``clamp`` is off (each value, its bound and the source, and the margins clamping
        would give), or a value written fails one of the stack's pre-arm rules (never written).
    """
    e = _export(stack, c, model, loop, design, clamp, hover_thrust, version, evidence, xy_integral)
    if evidence.hover_source and loop in HOVER_LOOPS.get(stack, ()):  # the value read from the log, said first
        e = replace(e, assumptions=(evidence.hover_source, *e.assumptions))
    return e


def _export(stack: str, c: Controller, model: LoopModel, loop: str, design: str, clamp: bool,
            hover_thrust: float | None, version: str | None, evidence: ExportEvidence,
            xy_integral: float | None) -> StackExport:
    """:func:`export_design` but the hover thrust's statement."""
    from .ardupilot_versions import check_version

    check_exportable(stack, loop, c.kind, hover_thrust)
    check_xy_integral(stack, loop, xy_integral)
    iv = xy_integral or 0.0
    if stack != "ardupilot" and version is not None:
        raise InputError("--stack-version is for --export ardupilot (PX4's and HEAR's names do not differ by version)")
    if stack in ("px4", "ardupilot"):
        why = unit_reasons(loop, evidence.heights, evidence.amplitudes)
        if c.Kd <= 0:
            why.append("the design has no derivative gain (the rate P would be 0)")
        if why:
            raise InputError(f"cannot export to {stack}: " + "; ".join(why))
    out_notes = list(evidence.notes)
    if stack == "hear":
        return _hear_export(c, model, loop, design, out_notes)
    if stack == "generic":
        params = {"Kp": c.Kp, "Ki": c.Ki, "Kd": c.Kd, "Tf": c.Tf, "rate_hz": c.rate_hz}
        return StackExport(stack, loop, design, params, (), loop_margins(c, [model])[0], tuple(out_notes))
    if stack == "ardupilot" and loop == "altitude":
        assert hover_thrust is not None  # check_exportable asked for it
        e = _ardupilot_altitude(c, model, design, clamp, hover_thrust, out_notes, check_version(version),
                                evidence.posterior_models)
        return _with_prearm(e)
    if stack == "px4" and loop in (*_PX4_XY, "altitude"):  # the gains are accelerations x hover / g
        assert hover_thrust is not None  # check_exportable asked for it
        check_units(model, hover_thrust, stack, loop, "MPC_THR_HOVER")
    if not clamp:  # the stack's ranges are constraints of the design (issue 37)
        c = _inside_ranges(c, model, stack, loop, hover_thrust, evidence.posterior_models, out_notes, iv)
    e = _cascade_export(stack, c, model, loop, design, clamp, hover_thrust, out_notes, iv)
    if stack == "px4" and loop in _PX4_XY:
        assert hover_thrust is not None  # check_exportable asked for it
        said, predicted = written_loop(e.params, model, c.rate_hz, hover_thrust)
        e = replace(e, notes=(*e.notes, *said), predicted=predicted)
    if stack == "ardupilot":
        e = replace(e, version=check_version(version))
        return _with_prearm(e)
    return _with_reboot_note(e)


def check_units(model: LoopModel, hover: float, stack: str, loop: str, hover_param: str) -> None:
    """InputError unless K [m/s^2 per command unit] is within :data:`UNIT_TOLERANCE` of g / ``hover``: the
    exports that turn the PD into a stack's acceleration gains (thrust = acceleration x hover / g: ArduPilot's
    z cascade, PX4's z and x/y velocity loops) hold only for a command that is the stack's normalised thrust
    (ArduPilot's throttle 0-1; PX4's thrust setpoint, along x or y for those loops) and an output in metres.
    ``hover_param`` names the stack's hover parameter (``--hover-thrust``)."""
    expected = STANDARD_GRAVITY / hover
    if 1.0 / UNIT_TOLERANCE <= model.K / expected <= UNIT_TOLERANCE:
        return
    command = "ArduPilot's throttle (0-1)" if stack == "ardupilot" else (
        "PX4's normalised thrust setpoint" + (f" along {loop}" if loop in _PX4_XY else " (0-1)"))
    output = "altitude" if loop == "altitude" else "position"
    raise InputError(f"cannot export the {loop} loop to {stack}: K {model.K:.4g} m/s^2 per command unit is not near "
                     f"g / {hover_param} = {expected:.4g} (--hover-thrust {hover:g}): the log's command is not "
                     f"{command} or its {output} not in metres")


def check_xy_integral(stack: str | None, loop: str, value: float | None) -> None:
    """InputError unless ``value`` (``--xy-integral``, PX4's ``MPC_XY_VEL_I_ACC`` [(m/s^2)/m]) is None, or inside
    its range for an ``--export px4`` of x or y."""
    if value is None:
        return
    if stack != "px4" or loop not in _PX4_XY:
        raise InputError("--xy-integral is PX4's MPC_XY_VEL_I_ACC: for --export px4 on the x or y loop")
    row = param("px4", "MPC_XY_VEL_I_ACC")
    if not (math.isfinite(value) and row.contains(value)):
        raise InputError(f"--xy-integral {value:g} is outside MPC_XY_VEL_I_ACC's range {row.minimum:g}-{row.maximum:g} "
                         f"{row.unit} ({row.source}): give a value inside it (PX4's default {row.default:g})")


def _names(stack: str, loop: str) -> tuple[str, str, str]:
    """The stack's cascade parameters for ``loop``: (the ratio Kp / Kd, the rate (velocity) loop's P, its I)."""
    if stack == "px4" and loop == "altitude":
        return "MPC_Z_P", "MPC_Z_VEL_P_ACC", "MPC_Z_VEL_I_ACC"
    if stack == "px4" and loop in _PX4_XY:
        return "MPC_XY_P", "MPC_XY_VEL_P_ACC", "MPC_XY_VEL_I_ACC"
    if stack == "px4":
        return f"MC_{loop.upper()}_P", f"MC_{loop.upper()}RATE_P", f"MC_{loop.upper()}RATE_I"
    ax = _AXIS_AP[loop]
    return f"ATC_ANG_{ax}_P", f"ATC_RAT_{ax}_P", f"ATC_RAT_{ax}_I"


def _gain_pair(stack: str, loop: str, hover: float | None) -> tuple[str, str, float]:
    """(the ratio parameter Kp / Kd, the gain parameter, gain per unit Kd) of a stack's cascade mapping."""
    ratio, gain, _ = _names(stack, loop)
    if stack == "px4" and loop in ("altitude", *_PX4_XY):
        assert hover is not None
        return ratio, gain, STANDARD_GRAVITY / hover
    return ratio, gain, 1.0


def _inside_ranges(c: Controller, model: LoopModel, stack: str, loop: str, hover: float | None,
                   posterior: Sequence[LoopModel], notes: list[str], xy_integral: float = 0.0) -> Controller:
    """The stack's ranges as constraints of the design (PX4 ``MPC_Z_P``/``MPC_Z_VEL_P_ACC``, ``MC_*_P``/
    ``MC_*RATE_P``; ArduPilot ``ATC_ANG_*_P``/``ATC_RAT_*_P``): ``c`` when its values are in range; else the PD
    with the ratio Kp / Kd at its nearest bound and the gain (in its range) of least IAE whose loop, with the
    stack's minimum integrals, keeps Ms at most ``c``'s own worst over the nominal model and the posterior's
    95 % set (up to 40 draws); the cost in IAE is said in ``notes``. None found: ``c`` (the refusal follows).
    PX4 x/y: the loop searched and held has ``MPC_XY_VEL_I_ACC`` = ``xy_integral`` (as altitude's its minimum
    integral)."""
    from .closed_loop import criterion, step_response

    ratio_name, gain_name, per_kd = _gain_pair(stack, loop, hover)
    rz, rv = param(stack, ratio_name), param(stack, gain_name)
    ratio = c.Kp / c.Kd
    # PX4 x/y: MPC_XY_VEL_D_ACC >= 0.1 is a term the PD lacks; the gain is designed with it even when in range
    lacks = stack == "px4" and loop in _PX4_XY
    if rz.contains(ratio) and rv.contains(c.Kd * per_kd) and not lacks:
        return c
    base = cascade_params(c, loop, stack, hover, xy_integral)
    base.update({n: param(stack, n).minimum for n in base if n in _STRUCTURAL})
    models = [model, *posterior[:: max(1, len(posterior) // 40)]]

    def loop_of(r: float, v: float) -> Controller:
        return _loop_controller({**base, ratio_name: r, gain_name: v}, c, loop, stack, hover)

    def iae(ctrl: Controller) -> float:
        t, y, _ = step_response([model], ctrl, 20.0)
        return float(criterion(t, y)[0])

    def iae_at(r: float, v: float) -> float:
        if lacks and xy_integral > 0:  # PX4's integral has no P_xy r kick: its own law (the PID form is exact at 0)
            assert hover is not None
            t, y = px4_xy_ticks({**base, ratio_name: r, gain_name: v}, model, c.rate_hz, hover, 20.0)
            return float(criterion(t, y[:1])[0])
        return iae(loop_of(r, v))

    # the scan reads Ms alone: the plants' response once, Ms without the other margins (the same figures)
    plants = PlantStack.of(as_discrete(models, c.rate_hz))
    response = margin_response(plants, c.rate_hz)

    def worst_ms(ctrl: Controller) -> float:
        ms, stable = stack_sensitivity(ctrl, plants, response)
        return float(np.max(ms)) if bool(np.all(stable)) else math.inf

    limit = max(worst_ms(c), worst_ms(loop_of(ratio, c.Kd * per_kd)))
    if not math.isfinite(limit):
        return c  # c itself is unstable on some model: no Ms to hold (the refusal follows)
    r_in = rz.clamp(ratio)
    best: tuple[float, float] | None = None
    least: tuple[float, float] | None = None  # (gain, worst Ms): when none holds the limit
    for v in np.geomspace(rv.minimum, rv.maximum, 48):
        worst = worst_ms(loop_of(r_in, float(v)))
        if least is None or worst < least[1]:
            least = (float(v), worst)
        if worst <= limit:
            j = iae_at(r_in, float(v))
            if best is None or j < best[1]:
                best = (float(v), j)
    held = f"the least IAE with Ms <= {limit:.3g}"
    if best is None:
        if least is None or not math.isfinite(least[1]):
            return c
        best = (least[0], iae_at(r_in, least[0]))
        held = f"none holds Ms <= {limit:.3g}: the least worst Ms, {least[1]:.3g}"
    v, j = best
    j0 = iae_at(ratio, c.Kd * per_kd)
    why = "outside the stack's ranges" if not (rz.contains(ratio) and rv.contains(c.Kd * per_kd)) else "in range"
    if lacks:
        d_min = param("px4", "MPC_XY_VEL_D_ACC").minimum
        why += (f"; PX4 adds MPC_XY_VEL_D_ACC x the velocity's derivative through MPC_VELD_LP "
                f"{base['MPC_VELD_LP']:g} Hz, at least {d_min:g}, which the PD lacks: set at {d_min:g}"
                + (f", and MPC_XY_VEL_I_ACC {xy_integral:g} (--xy-integral)" if xy_integral else "") + ", the ranges")
    if lacks:
        j_pd = iae(c)
        j0_said = (f"{j_pd:.4g} s for the PD as designed ({100 * (j / j_pd - 1):+.0f} %) and {j0:.4g} s for its "
                   f"values with the minimum ({100 * (j / j0 - 1):+.0f} %)")
    else:
        j0_said = f"{j0:.4g} s unconstrained ({100 * (j / j0 - 1):+.0f} %)"
    notes.append(f"{ratio_name} {ratio:.4g} / {gain_name} {c.Kd * per_kd:.4g} {why}: designed "
                 f"inside them ({ratio_name} {r_in:g}, {gain_name} {v:.4g} of {rv.minimum:g}-{rv.maximum:g}, {held} "
                 f"over the nominal model and {len(models) - 1} posterior draws); its cost: IAE {j:.4g} s against "
                 f"{j0_said}")
    return replace(c, Kp=r_in * v / per_kd, Ki=0.0, Kd=v / per_kd)


def _hear_export(c: Controller, model: LoopModel, loop: str, design: str, notes: list[str]) -> StackExport:
    """HEAR's PID message; the z command in HEAR's units (an acceleration, m/s^2) or converted, stated."""
    from .export import hear_params

    scale, assumptions = 1.0, ()  # type: tuple[float, tuple[str, ...]]
    if loop == "altitude":
        K = model.K
        if 0.5 <= K <= 2.0:
            notes.append(f"the log's z command is taken as HEAR's (an acceleration in m/s^2: K {K:.3g} ~ 1); HEAR adds "
                         f"{HEAR_Z_BIAS:g} and saturates at {HEAR_Z_SAT:g} (OuterSysNodelet.h), so the PID's output "
                         f"swings at most {HEAR_Z_SAT - HEAR_Z_BIAS:.3g} m/s^2 above hover")
        elif K > 2.0:
            scale = K
            assumptions = (f"the log's z command is not HEAR's acceleration command (K {K:.4g} m/s^2 per command unit, "
                           "e.g. a normalised thrust): kp, ki, kd converted to HEAR's m/s^2 by x K, assuming HEAR_FC's "
                           "Force2Rot makes the commanded acceleration (K = 1 in HEAR's units)",)
        else:
            raise InputError(f"cannot export the altitude loop to hear: K {K:.4g} per command unit is neither HEAR's "
                             "acceleration command (K ~ 1 m/s^2 per m/s^2) nor a thrust it can convert (K > 2): check "
                             "the log's command and altitude units")
    return StackExport("hear", loop, design, hear_params(c, loop, scale), (), loop_margins(c, [model])[0], tuple(notes), assumptions)


def _with_reboot_note(e: StackExport) -> StackExport:
    """The export with a note naming the written values that need a reboot (the stacks' metadata)."""
    from .stack_params import STACK_PARAMS

    rows = {p.name: p for p in STACK_PARAMS if p.stack == e.stack}
    need = [n for n in e.params if n in rows and rows[n].reboot_required]
    if not need:
        return e
    note = (f"{', '.join(need)} take effect only after a reboot (reboot_required / @RebootRequired in the stack's "
            "parameter metadata)")
    return replace(e, notes=(*e.notes, note))


def _with_prearm(e: StackExport) -> StackExport:
    """ArduPilot: every pre-arm rule on the values written, checked (a failure is a refusal, never a file)."""
    from .ardupilot_versions import prearm_checks

    checks = prearm_checks(e.params, e.version)
    failed = [r for r in checks if not r.passed]
    if failed:
        raise InputError("cannot export to ardupilot: the vehicle would refuse to arm: " + "; ".join(
            f"{r.rule.rule} fails with {r.value:g} ({r.rule.source})" for r in failed))
    return _with_reboot_note(replace(e, prearm=tuple(r.to_json() for r in checks)))


def _cascade_export(stack: str, c: Controller, model: LoopModel, loop: str, design: str, clamp: bool,
                    hover_thrust: float | None, out_notes: list[str], xy_integral: float = 0.0) -> StackExport:
    """PX4 (attitude, altitude, x/y) and ArduPilot attitude: the cascade mapping, its ranges, its margins."""
    params = cascade_params(c, loop, stack, hover_thrust, xy_integral)
    bad = check_ranges(stack, params)
    gains = [v for v in bad if v.param.name not in _STRUCTURAL]
    clamped_params = {**params, **{v.param.name: v.clamped for v in bad}}
    margins = loop_margins(_loop_controller(clamped_params, c, loop, stack, hover_thrust), [model])[0]
    if gains and not clamp:
        raise InputError(f"cannot export to {stack}: " + "; ".join(v.message() for v in gains)
                         + f". Clamped to the bounds the loop would have Ms {margins.Ms:.3g}, GM {margins.gain_margin:.3g}"
                         + f", PM {margins.phase_margin_deg:.1f} deg (--clamp to export that)")
    for v in bad:
        reason = ("the stack's minimum (the PD has none)" if v.param.name in _STRUCTURAL
                  else "the stack's bound (--clamp)")
        out_notes.append(f"{v.param.name} set to {v.clamped:g} instead of {v.value:.4g}: {reason}")
    if bad:
        out_notes.append(f"with these values the loop has Ms {margins.Ms:.3g}, GM {margins.gain_margin:.3g}, "
                         f"PM {margins.phase_margin_deg:.1f} deg, delay margin {margins.delay_margin_s * 1e3:.1f} ms "
                         "(nominal model, the stack's filter)")
    if stack == "ardupilot":
        w = margins.w_gc
        lag = math.degrees(math.atan(w / (2 * math.pi * 100.0))) if math.isfinite(w) else 0.0
        out_notes.append(f"ATC_RAT_*_FLTT = 100 Hz (its maximum) filters the rate target: {lag:.1f} deg of phase at "
                         "the crossover on the P path, not in the margins above; ArduPilot's angle P is linear only "
                         "for small errors (sqrt controller) and ATC_INPUT_TC shapes the setpoint")
    clamped = tuple((v.param.name, v.value, v.clamped) for v in bad)
    return StackExport(stack, loop, design, clamped_params, clamped, margins, tuple(out_notes))


def _ardupilot_altitude(c: Controller, model: LoopModel, design: str, clamp: bool, hover_thrust: float,
                        notes: list[str], version: str, posterior: Sequence[LoopModel]) -> StackExport:
    """ArduPilot's z cascade for the PD ``c`` (:func:`mrftcli.tune.ardupilot_z.design_z_cascade`) in ``version``'s
    names, its values checked against that version's ranges, its margins the worst over the splits of tau of the
    nominal model and the posterior's extreme draws."""
    from .ardupilot_versions import ardupilot_names, z_bounds
    from .ardupilot_z import THROTTLE_CUTOFF_HZ, design_z_cascade, robust_models, split_assumption

    check_units(model, hover_thrust, "ardupilot", "altitude", "MOT_THST_HOVER")
    draws = robust_models(posterior)
    z, clamped = design_z_cascade(c, model, clamp=clamp, models=draws, bounds=z_bounds(version))
    clamp_notes = [f"{n} set to {v:g} instead of {d:.4g}: the stack's bound (--clamp)" for n, d, v in clamped]
    params = ardupilot_names(z.gains.params(), version)
    bad = check_ranges("ardupilot", params)
    if bad:  # the design keeps every value in range: a violation here is a defect, never exported
        raise InputError("cannot export to ardupilot: " + "; ".join(v.message() for v in bad))
    w, split, r = z.figures.worst(), z.figures.worst_split(), z.robust
    tried = ", ".join(f"{p:g}/{ratio:g}: {g:.2f}" for ratio, p, g in z.tried)
    i_name = "PSC_ACCZ_I" if version == "4.6" else "PSC_D_ACC_I"
    held = (f"the nominal model and {len(draws)} extreme draws of the posterior's 95 % set (smallest and largest "
            "tau, K, Td, Tp)" if draws else "the nominal model (no posterior given)")
    notes = [*notes, *clamp_notes,
             f"ArduPilot Copter {version} names and units (--stack-version; 4.7 renamed PSC_POSZ_/VELZ_/ACCZ_ to "
             "PSC_D_POS_/D_VEL_/D_ACC_, the _D_ACC_ gains x 0.1)",
             f"the cascade keeps {100 * z.kept:.0f} % of the {design}'s loop gain (PSC_ACCZ_P {z.gains.acc_p:g}, "
             f"PSC_ACCZ_I {z.gains.acc_i:.4g} = {z.gains.acc_i / z.gains.acc_p:g} x P, in 4.6 units; kept per P/ratio "
             f"tried: {tried}) with Ms <= {z.ms_target:.3g}, the PD's own worst, on every split of tau of {held}",
             f"margins written (the worst over those models and splits): Ms {r.Ms:.3g}, GM {r.gain_margin:.3g}, PM "
             f"{r.phase_margin_deg:.1f} deg, delay margin {r.delay_margin_s * 1e3:.1f} ms; nominal model's worst split "
             f"({split.describe()}): Ms {w.Ms:.3g}, GM {w.gain_margin:.3g}",
             f"in the loop: the motors' {THROTTLE_CUTOFF_HZ:g} Hz throttle filter (AC_PosControl "
             "POSCONTROL_THROTTLE_CUTOFF_FREQ_HZ), INS_ACCEL_FILTER, the velocity and acceleration error filters at "
             "the values written, and the acceleration loop's integral (AC_PID: integrator += Ki e dt, ahead of "
             f"the output); {i_name} > 0 is a pre-arm rule (AC_PosControl::pre_arm_checks); the target filter "
             "(_ACCZ_FLTT / _D_ACC_FLTT) is not written and runs off in the design",
             f"PSC_VELZ_I = {z.gains.vel_i:g} (4.6's documented minimum), in the margins",
             f"MOT_THST_HOVER = {hover_thrust:g} (--hover-thrust; not written, ArduPilot learns it): K "
             f"{model.K:.4g} m/s^2 per throttle unit against g / MOT_THST_HOVER = {STANDARD_GRAVITY / hover_thrust:.4g}; "
             "the log's command is taken as the throttle after the 2 Hz filter (an MRFT at the mixer); for a test "
             "flown through set_throttle_out the filter is in the identified Tp and tau already, and this loop "
             "counts it twice",
             "AC_P_1D's square-root controller and the PSC_ACCZ_IMAX / speed limits make the cascade nonlinear for "
             "large errors: the margins are those of the linear region"]
    assumption = split_assumption(z.tau, len(z.figures.splits))
    return StackExport("ardupilot", "altitude", design, params, clamped, r, tuple(notes), (assumption,), version)
