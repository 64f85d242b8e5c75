"""The flight stacks' own definitions of the parameters ``tune --export`` writes: name, range, unit, default.

A small table vendored from the stacks' sources, each row with the file (and commit) it was read from,
so that every exported value is checked against what the stack documents (:func:`check_ranges`). A
row whose source could not be read says so (``verified=False``); no range is invented.

Sources (read for tracker issue 25):

* PX4 (github.com/PX4/PX4-Autopilot): ``src/modules/mc_rate_control/mc_rate_control_params.yaml``
  (commit 0227117f), ``src/modules/mc_att_control/mc_att_control_params.yaml`` (014866564),
  ``src/modules/sensors/vehicle_angular_velocity/imu_gyro_parameters.yaml`` (921345ae),
  ``src/modules/mc_pos_control/multicopter_position_control_gain_params.yaml`` (c426883b).
* ArduPilot (github.com/ArduPilot/ardupilot, Copter 4.x parameter names):
  ``libraries/AC_AttitudeControl/AC_AttitudeControl_Multi.cpp`` (read at commit 29643d00 of the
  IamPete1/ardupilot fork: the @Range lines of ``RAT_RLL_*``/``RAT_PIT_*``),
  ``libraries/AC_AttitudeControl/AC_AttitudeControl.cpp`` (``ANG_RLL_P``/``ANG_PIT_P`` @Range),
  ``libraries/AP_InertialSensor/AP_InertialSensor.cpp`` (``GYRO_FILTER`` @Range 0 127 in the version
  read; the commit was not pinned; ``ACCEL_FILTER`` 0 127 likewise), ``libraries/AC_AttitudeControl/AC_PosControl.cpp``
  at 46d6887e (Copter 4.x: the altitude cascade's ``PSC_POSZ_P``, ``PSC_VELZ_*`` (an ``AC_PID_Basic``) and
  ``PSC_ACCZ_*`` @Range lines and the constructor's defaults), ``libraries/AP_Motors/AP_MotorsMulticopter.cpp``
  (``THST_HOVER`` @Range 0.2 0.8; commit not pinned). ``update_z_controller`` gives the structure: velocity
  target = POSZ_P x altitude error [cm/s]; acceleration target = VELZ PID of the velocity error (the EKF's
  vertical velocity) [cm/s^2]; throttle = hover throttle + 0.001 x ACCZ PID of (acceleration target -
  ``get_z_accel_cmss()``, the IMU's earth-frame vertical acceleration) [cm/s^2], through the motors' 2 Hz
  throttle filter (:mod:`mrftcli.tune.ardupilot_z`).
* HEAR (github.com/oussamaabdulhay/HEAR_Architecture ``msg/PID_param.msg``, commit 832c597e): the
  message's fields; HEAR documents no ranges (its rows have none).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["StackParam", "STACK_PARAMS", "param", "check_ranges", "RangeViolation", "STACKS"]

STACKS = ("px4", "ardupilot", "hear")

_PX4 = "PX4/PX4-Autopilot"
_RATE = f"{_PX4} src/modules/mc_rate_control/mc_rate_control_params.yaml @0227117f"
_ATT = f"{_PX4} src/modules/mc_att_control/mc_att_control_params.yaml @01486656"
_GYRO = f"{_PX4} src/modules/sensors/vehicle_angular_velocity/imu_gyro_parameters.yaml @921345ae"
_POS = f"{_PX4} src/modules/mc_pos_control/multicopter_position_control_gain_params.yaml @c426883b"
#: x/y rows read in PX4 main of 2024-08-21 (abdullaayyad96/PX4-Autopilot ae16556, the PX4 SITL build of issue 42)
_POS_XY = f"{_PX4} src/modules/mc_pos_control/multicopter_position_control_gain_params.c @ae16556"
_POS_LP = f"{_PX4} src/modules/mc_pos_control/multicopter_position_control_params.c @ae16556"
_AP_MULTI = "ArduPilot/ardupilot libraries/AC_AttitudeControl/AC_AttitudeControl_Multi.cpp (@Range; read @29643d00 of a fork)"
_AP_ATC = "ArduPilot/ardupilot libraries/AC_AttitudeControl/AC_AttitudeControl.cpp (@Range; commit not pinned)"
_AP_INS = "ArduPilot/ardupilot libraries/AP_InertialSensor/AP_InertialSensor.cpp (@Range; commit not pinned)"
_AP_PSC = ("ArduPilot/ardupilot libraries/AC_AttitudeControl/AC_PosControl.cpp (@Range and the constructor's defaults; "
           "Copter 4.x, _VELZ_ an AC_PID_Basic; @46d6887e)")
_AP_MOT = "ArduPilot/ardupilot libraries/AP_Motors/AP_MotorsMulticopter.cpp (@Range; commit not pinned)"
_AP_SCHED = ("ArduPilot/ardupilot libraries/AP_Scheduler/AP_Scheduler.cpp (@Range 50 400, @RebootRequired: True, "
             "lines 64-65 @2598e9d4 of blitzy-public-samples/ardupilot-blitzy, upstream master 2025-07-21)")
_IMU = f"{_PX4} src/modules/sensors/vehicle_imu/imu_parameters.yaml @d709b046 (enum 100/200/250/400, reboot_required)"
#: AC_PosControl.cpp after the 4.7 rename (_POSZ_ -> _D_POS_, _VELZ_ -> _D_VEL_, _ACCZ_ -> _D_ACC_ in m, s).
_AP_PSC47 = ("ArduPilot/ardupilot libraries/AC_AttitudeControl/AC_PosControl.cpp (@Range of _D_POS_/_D_VEL_/_D_ACC_ "
             "and convert_parameters 'Added: Nov-2024 for 4.7'; a stored upstream copy after the rename)")


@dataclass(frozen=True)
class StackParam:
    """One parameter as its stack defines it.

    Attributes
    ----------
    stack : str
        ``px4``, ``ardupilot`` or ``hear``.
    name : str
        The parameter's name.
    minimum, maximum : float
        The documented range (-inf / inf: no bound documented).
    unit : str
        Its unit as we map it (the stack's when it gives one).
    default : float
        The stack's default (NaN: not recorded).
    source : str
        Repository, file and commit it was read from.
    verified : bool
        False when the source could not be read at a pinned version (the row then says what is known).
    reboot_required : bool
        The stack's metadata says a change takes effect only after a reboot (PX4 ``reboot_required: true``,
        ArduPilot ``@RebootRequired: True``).
    """

    stack: str
    name: str
    minimum: float
    maximum: float
    unit: str
    default: float
    source: str
    verified: bool = True
    reboot_required: bool = False

    def contains(self, value: float) -> bool:
        """Whether ``value`` is within the documented range (a tiny relative slack for float rounding)."""
        slack = 1e-9 * max(1.0, abs(value))
        return self.minimum - slack <= value <= self.maximum + slack

    def clamp(self, value: float) -> float:
        return min(max(value, self.minimum), self.maximum)


_INF = math.inf


def _rows() -> tuple[StackParam, ...]:
    px4 = [
        ("MC_ROLL_P", 0.0, 12.0, "(rad/s)/rad", 4.0, _ATT),
        ("MC_PITCH_P", 0.0, 12.0, "(rad/s)/rad", 4.0, _ATT),
        ("MC_ROLLRATE_P", 0.01, 0.5, "torque/(rad/s)", 0.15, _RATE),
        ("MC_ROLLRATE_I", 0.0, _INF, "torque/rad", 0.2, _RATE),
        ("MC_ROLLRATE_D", 0.0, 0.01, "torque/(rad/s^2)", 0.003, _RATE),
        ("MC_ROLLRATE_FF", 0.0, _INF, "torque/(rad/s)", 0.0, _RATE),
        ("MC_ROLLRATE_K", 0.01, 5.0, "-", 1.0, _RATE),
        ("MC_PITCHRATE_P", 0.01, 0.6, "torque/(rad/s)", 0.15, _RATE),
        ("MC_PITCHRATE_I", 0.0, _INF, "torque/rad", 0.2, _RATE),
        ("MC_PITCHRATE_D", 0.0, _INF, "torque/(rad/s^2)", 0.003, _RATE),
        ("MC_PITCHRATE_FF", 0.0, _INF, "torque/(rad/s)", 0.0, _RATE),
        ("MC_PITCHRATE_K", 0.01, 5.0, "-", 1.0, _RATE),
        ("IMU_GYRO_CUTOFF", 0.0, 1000.0, "Hz", 40.0, _GYRO),
        ("IMU_GYRO_RATEMAX", 100.0, 2000.0, "Hz", 400.0, _GYRO),
        ("IMU_INTEG_RATE", 100.0, 1000.0, "Hz", 200.0, _IMU),
        ("MPC_Z_P", 0.1, 1.5, "(m/s)/m", 1.0, _POS),
        ("MPC_Z_VEL_P_ACC", 2.0, 15.0, "(m/s^2)/(m/s)", 4.0, _POS),
        ("MPC_Z_VEL_I_ACC", 0.2, 3.0, "(m/s^2)/m", 2.0, _POS),
        ("MPC_Z_VEL_D_ACC", 0.0, 2.0, "(m/s^2)/(m/s^2)", 0.0, _POS),
        ("MPC_XY_P", 0.0, 2.0, "(m/s)/m", 0.95, _POS_XY),
        ("MPC_XY_VEL_P_ACC", 1.2, 5.0, "(m/s^2)/(m/s)", 1.8, _POS_XY),
        ("MPC_XY_VEL_I_ACC", 0.0, 60.0, "(m/s^2)/m", 0.4, _POS_XY),
        ("MPC_XY_VEL_D_ACC", 0.1, 2.0, "(m/s^2)/(m/s^2)", 0.2, _POS_XY),
        ("MPC_VELD_LP", 0.0, 50.0, "Hz", 5.0, _POS_LP),
    ]
    ap = [
        ("ATC_ANG_RLL_P", 3.0, 12.0, "(rad/s)/rad", math.nan, _AP_ATC, False),
        ("ATC_ANG_PIT_P", 3.0, 12.0, "(rad/s)/rad", math.nan, _AP_ATC, False),
        ("ATC_RAT_RLL_P", 0.01, 0.5, "output/(rad/s)", math.nan, _AP_MULTI, True),
        ("ATC_RAT_RLL_I", 0.01, 2.0, "output/rad", math.nan, _AP_MULTI, True),
        ("ATC_RAT_RLL_D", 0.0, 0.05, "output/(rad/s^2)", math.nan, _AP_MULTI, True),
        ("ATC_RAT_RLL_FF", 0.0, 0.5, "output/(rad/s)", math.nan, _AP_MULTI, True),
        ("ATC_RAT_RLL_FLTE", 0.0, 100.0, "Hz", math.nan, _AP_MULTI, True),
        ("ATC_RAT_RLL_FLTT", 5.0, 100.0, "Hz", math.nan, _AP_MULTI, True),
        ("ATC_RAT_RLL_FLTD", 5.0, 100.0, "Hz", math.nan, _AP_MULTI, True),
        ("ATC_RAT_PIT_P", 0.01, 0.5, "output/(rad/s)", math.nan, _AP_MULTI, True),
        ("ATC_RAT_PIT_I", 0.01, 2.0, "output/rad", math.nan, _AP_MULTI, True),
        ("ATC_RAT_PIT_D", 0.0, 0.05, "output/(rad/s^2)", math.nan, _AP_MULTI, True),
        ("ATC_RAT_PIT_FF", 0.0, 0.5, "output/(rad/s)", math.nan, _AP_MULTI, True),
        ("ATC_RAT_PIT_FLTE", 0.0, 100.0, "Hz", math.nan, _AP_MULTI, True),
        ("ATC_RAT_PIT_FLTT", 5.0, 100.0, "Hz", math.nan, _AP_MULTI, True),
        ("ATC_RAT_PIT_FLTD", 5.0, 100.0, "Hz", math.nan, _AP_MULTI, True),
        ("INS_GYRO_FILTER", 0.0, 127.0, "Hz", 20.0, _AP_INS, False),
        ("INS_ACCEL_FILTER", 0.0, 127.0, "Hz", 20.0, _AP_INS, False),
        # the altitude cascade (AC_PosControl z, exported by tune/ardupilot_z.py); defaults from its constructor
        ("PSC_POSZ_P", 1.0, 3.0, "(cm/s)/cm", 1.0, _AP_PSC, True),
        ("PSC_VELZ_P", 1.0, 8.0, "(cm/s^2)/(cm/s)", 5.0, _AP_PSC, True),
        ("PSC_VELZ_I", 0.02, 1.0, "(cm/s^2)/cm", 0.0, _AP_PSC, True),
        ("PSC_VELZ_D", 0.0, 1.0, "(cm/s^2)/(cm/s^2)", 0.0, _AP_PSC, True),
        ("PSC_VELZ_FF", 0.0, 1.0, "-", 0.0, _AP_PSC, True),
        ("PSC_VELZ_FLTE", 0.0, 100.0, "Hz", 5.0, _AP_PSC, True),
        ("PSC_VELZ_FLTD", 0.0, 100.0, "Hz", 5.0, _AP_PSC, True),
        ("PSC_ACCZ_P", 0.2, 1.5, "(throttle/1000)/(cm/s^2)", 0.5, _AP_PSC, True),
        ("PSC_ACCZ_I", 0.0, 3.0, "(throttle/1000)/(cm/s)", 1.0, _AP_PSC, True),
        ("PSC_ACCZ_D", 0.0, 0.4, "(throttle/1000)/(cm/s^3)", 0.0, _AP_PSC, True),
        ("PSC_ACCZ_FF", 0.0, 0.5, "(throttle/1000)/(cm/s^2)", 0.0, _AP_PSC, True),
        ("PSC_ACCZ_IMAX", 0.0, 1000.0, "throttle/1000", 800.0, _AP_PSC, True),
        ("PSC_ACCZ_FLTT", 1.0, 50.0, "Hz", 0.0, _AP_PSC, True),
        ("PSC_ACCZ_FLTE", 1.0, 100.0, "Hz", 20.0, _AP_PSC, True),
        ("PSC_ACCZ_FLTD", 1.0, 100.0, "Hz", 0.0, _AP_PSC, True),
        ("MOT_THST_HOVER", 0.2, 0.8, "throttle 0-1", math.nan, _AP_MOT, False),
        ("SCHED_LOOP_RATE", 50.0, 400.0, "Hz", 400.0, _AP_SCHED, True),
        # 4.7's names of the altitude cascade (SI units: _D_ACC_ gains are 4.6's _ACCZ_ x 0.1)
        ("PSC_D_POS_P", 0.5, 4.0, "(m/s)/m", 1.0, _AP_PSC47, True),
        ("PSC_D_VEL_P", 1.0, 10.0, "(m/s^2)/(m/s)", 5.0, _AP_PSC47, True),
        ("PSC_D_VEL_I", 0.0, 10.0, "(m/s^2)/m", math.nan, _AP_PSC47, True),
        ("PSC_D_VEL_D", 0.0, 2.0, "(m/s^2)/(m/s^2)", math.nan, _AP_PSC47, True),
        ("PSC_D_VEL_FF", 0.0, 2.0, "-", math.nan, _AP_PSC47, True),
        ("PSC_D_VEL_FLTE", 0.0, 100.0, "Hz", 5.0, _AP_PSC47, True),
        ("PSC_D_ACC_P", 0.01, 0.25, "throttle/(m/s^2)", 0.05, _AP_PSC47, True),
        ("PSC_D_ACC_I", 0.0, 0.5, "throttle/(m/s)", 0.1, _AP_PSC47, True),
        ("PSC_D_ACC_D", 0.0, 0.1, "throttle/(m/s^3)", 0.0, _AP_PSC47, True),
        ("PSC_D_ACC_FF", 0.0, 0.1, "throttle/(m/s^2)", math.nan, _AP_PSC47, True),
        ("PSC_D_ACC_FLTE", 1.0, 100.0, "Hz", 20.0, _AP_PSC47, True),
    ]
    reboot = {"IMU_GYRO_RATEMAX", "IMU_INTEG_RATE", "SCHED_LOOP_RATE"}  # the stacks' reboot flags (sources above)
    rows = [StackParam("px4", n, lo, hi, u, d, src, True, n in reboot) for n, lo, hi, u, d, src in px4]
    rows += [StackParam("ardupilot", n, lo, hi, u, d, src, v, n in reboot) for n, lo, hi, u, d, src, v in ap]
    return tuple(rows)


#: Every vendored row.
STACK_PARAMS: tuple[StackParam, ...] = _rows()
_BY_NAME = {(p.stack, p.name): p for p in STACK_PARAMS}


def param(stack: str, name: str) -> StackParam:
    """The row of ``name`` in ``stack`` (KeyError: not vendored)."""
    return _BY_NAME[(stack, name)]


@dataclass(frozen=True)
class RangeViolation:
    """An exported value outside its stack's documented range."""

    param: StackParam
    value: float

    @property
    def clamped(self) -> float:
        return self.param.clamp(self.value)

    def message(self) -> str:
        p = self.param
        side = f"above the maximum {p.maximum:g}" if self.value > p.maximum else f"below the minimum {p.minimum:g}"
        return f"{p.name} = {self.value:.4g} is {side} [{p.unit}] ({p.source.split(' ', 1)[1]})"


def check_ranges(stack: str, values: dict[str, float]) -> list[RangeViolation]:
    """The values of ``values`` (parameter name -> value) outside ``stack``'s documented ranges.

    Names without a vendored row are not checked (the caller exports only vendored names; the tests
    check that).

    Examples
    --------
    >>> [v.message() for v in check_ranges("px4", {"MC_ROLLRATE_P": 0.628, "MC_ROLL_P": 6.0})]
    ['MC_ROLLRATE_P = 0.628 is above the maximum 0.5 [torque/(rad/s)] (src/modules/mc_rate_control/mc_rate_control_params.yaml @0227117f)']
    """
    out = []
    for name, value in values.items():
        row = _BY_NAME.get((stack, name))
        if row is not None and not row.contains(value):
            out.append(RangeViolation(row, value))
    return out
