"""What ArduPilot SITL's quad model implies for eq. (2)'s K, Td (and Tp), from its source.

Read in ``libraries/SITL/SIM_Frame.{h,cpp}`` and ``SIM_Motor.cpp`` (ArduPilot master of 2025-07-21,
the tree ``build_ardupilot.sh`` pins); docs/sitl.md derives each line.

* Frame (``Frame::default_model``): mass 3 kg, ``diagonal_size`` 0.35 m (each motor is 0.35 m from the
  centre: ``Motor::setup_params`` puts it at ``cos/sin(angle) * diagonal_size``), inertia
  ``mass * 0.25 * (diagonal_size / 2)^2`` about x and y, rotor disc area 0.385 m^2 (``true_prop_area``
  = 0.385 / 4), momentum-drag coefficient 0.2, ``refRotRate`` 120.
* Motors: thrust follows the command at once (only a slew limit of 150 command units/s): no
  propulsion lag. ArduPilot's mixer linearises thrust with the same expo (0.65) and spin range, so the
  throttle is proportional to thrust and ``MOT_THST_HOVER`` (learned in flight) is the hover fraction:
  total thrust per unit throttle = m g / hover, with battery and air-density compensation inside.
* Vertical damping: momentum drag on each motor, ``f * v_z * sqrt(T_motor)``,
  ``f = mdrag_coef * sqrt(rho * true_prop_area)``; at hover ``T_motor = m g / 4``, so the drag is
  ``4 f sqrt(m g / 4) v_z`` and Td = m / that. (The quadratic body drag ``areaCd`` and the inflow term
  are second order at the cycle's few cm/s.)
* The frame is a **plus**: ``--model quad`` is ``Frame("quad", 4, quad_plus_motors)`` (motors at 90, -90, 0
  and 180 deg), and copter.parm flies it as one (``FRAME_CLASS 1``, ``FRAME_TYPE 0``). ArduPilot's
  mixer (``AP_MotorsMatrix``) gives motor i the roll factor ``cos(angle_i + 90 deg)`` and the pitch factor
  ``cos(angle_i)``, normalised to +-0.5: only the two motors on the axis's arm (0.35 m) act, each by
  0.5 u m g / (4 hover), so the torque is 2 * 0.5 * 0.35 u m g / (4 hover). (Read as an X, four motors at
  0.247 m, it would be sqrt(2) larger: the 25-28 % shortfall of the first campaign's roll K.)
  Damping: the momentum drag of each motor's vertical speed p y, ``f y^2 sqrt(T_motor)`` [N m s] summed
  over the motors, plus the frame's ``gyro * radians(400) / refRotRate`` term.
"""

from __future__ import annotations

import math

__all__ = ["air_density", "implied_model", "MASS_KG", "DIAGONAL_M"]

G = 9.80665
MASS_KG = 3.0
DIAGONAL_M = 0.35
DISC_AREA_M2 = 0.385
N_MOTORS = 4
MDRAG_COEF = 0.2
REF_ROT_RATE = 120.0
HOME_ALT_M = 584.0
#: SITL's ``quad`` model: the plus frame's motor angles (``quad_plus_motors`` in SIM_Frame.cpp) [deg]
MOTOR_ANGLES_DEG = (90.0, -90.0, 0.0, 180.0)


def air_density(alt_amsl_m: float) -> float:
    """International Standard Atmosphere density [kg/m^3] at an altitude [m]."""
    return 1.225 * (1.0 - 2.25577e-5 * alt_amsl_m) ** 4.2559


def implied_model(loop: str, hover: float, alt_amsl_m: float = HOME_ALT_M) -> dict[str, float]:
    """K [output/s^2 per command unit] and Td [s] that SITL's quad model gives at hover.

    Parameters
    ----------
    loop : {"altitude", "roll", "pitch"}
    hover : float
        ``MOT_THST_HOVER`` the vehicle learned (0-1).
    alt_amsl_m : float
        Altitude of the flight above sea level [m] (SITL's home: 584 m).

    Returns
    -------
    dict
        ``K``, ``Td`` and the damping rate ``damping_per_s`` [1/s].
    """
    rho = air_density(alt_amsl_m)
    f = MDRAG_COEF * math.sqrt(rho * DISC_AREA_M2 / N_MOTORS)
    t_motor = MASS_KG * G / N_MOTORS
    if loop == "altitude":
        damping = N_MOTORS * f * math.sqrt(t_motor) / MASS_KG
        return {"K": G / hover, "Td": 1.0 / damping, "damping_per_s": damping}
    if loop not in ("roll", "pitch"):
        raise ValueError(f"loop must be altitude, roll or pitch, not {loop!r}")
    torque_per_unit, damping_nms = 0.0, 0.0
    factors = _mixer_factors(loop)
    for angle, factor in zip(MOTOR_ANGLES_DEG, factors):
        arm = DIAGONAL_M * abs(math.sin(math.radians(angle)) if loop == "roll" else math.cos(math.radians(angle)))
        torque_per_unit += abs(factor) * arm * MASS_KG * G / (N_MOTORS * hover)
        damping_nms += f * arm**2 * math.sqrt(t_motor)
    inertia = MASS_KG * 0.25 * (DIAGONAL_M * 0.5) ** 2
    damping = damping_nms / inertia + math.radians(400.0) / REF_ROT_RATE
    return {"K": torque_per_unit / inertia, "Td": 1.0 / damping, "damping_per_s": damping}


def _mixer_factors(loop: str) -> list[float]:
    """ArduPilot's roll (``cos(angle + 90)``) or pitch (``cos(angle)``) factors, normalised to +-0.5."""
    raw = [math.cos(math.radians(a + (90.0 if loop == "roll" else 0.0))) for a in MOTOR_ANGLES_DEG]
    top = max(abs(r) for r in raw)
    return [0.5 * r / top for r in raw]

if __name__ == "__main__":
    for name in ("altitude", "roll", "pitch"):
        print(name, implied_model(name, 0.362))
