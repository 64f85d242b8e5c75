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
* Roll/pitch: the mixer's quad-X factors are +-0.5, so a roll input u changes each motor's thrust by
  0.5 u m g / (4 hover) at arm y = 0.35 sin 45 deg: torque 0.5 u y m g / hover. Damping: the momentum
  drag of each motor's vertical speed p y, ``4 f y^2 sqrt(T_motor)`` [N m s], plus the frame's
  ``gyro * radians(400) / refRotRate`` term.
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
    arm = DIAGONAL_M * math.sin(math.radians(45.0))
    inertia = MASS_KG * 0.25 * (DIAGONAL_M * 0.5) ** 2
    torque_per_unit = 0.5 * arm * MASS_KG * G / hover
    damping = (N_MOTORS * f * arm**2 * math.sqrt(t_motor)) / inertia + math.radians(400.0) / REF_ROT_RATE
    return {"K": torque_per_unit / inertia, "Td": 1.0 / damping, "damping_per_s": damping}


if __name__ == "__main__":
    for name in ("altitude", "roll"):
        print(name, implied_model(name, 0.39))
