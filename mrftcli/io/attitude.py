"""Quaternion -> roll/pitch, ZYX (yaw-pitch-roll, aerospace) convention.

The attitude is R = Rz(yaw) Ry(pitch) Rx(roll) (intrinsic Z-Y'-X'', as ``scipy``'s
``Rotation.as_euler("ZYX")``), with a Hamilton unit quaternion q = w + x i + y j + z k that rotates body
vectors into the world (ROS and PX4 both use this). Then

    roll  = atan2(2 (w x + y z), 1 - 2 (x^2 + y^2))
    pitch = asin(2 (w y - z x))

Both are independent of yaw, and well defined away from pitch = +-90 deg (gimbal lock), which an
attitude-loop MRFT test never reaches.
"""

from __future__ import annotations

import numpy as np

from ..errors import LogReadError

__all__ = ["roll_pitch"]


def roll_pitch(x: np.ndarray, y: np.ndarray, z: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch [rad] of quaternions given by components (normalised here).

    Parameters
    ----------
    x, y, z, w : numpy.ndarray
        Quaternion components (vector part x, y, z; scalar part w), any common scale.

    Returns
    -------
    roll, pitch : numpy.ndarray
        ZYX Euler angles [rad]: roll in (-pi, pi], pitch in [-pi/2, pi/2].

    Raises
    ------
    LogReadError
        A quaternion has (near) zero norm, i.e. the field is not an orientation.
    """
    q = np.stack([np.asarray(c, dtype=np.float64) for c in (x, y, z, w)])
    norm = np.sqrt((q * q).sum(axis=0))
    if (norm < 1e-9).any() or not np.isfinite(norm).all():
        raise LogReadError(f"{int((~(norm >= 1e-9)).sum())} orientation quaternion(s) have zero or "
                           "non-finite norm; is this field really an orientation?")
    x, y, z, w = q / norm
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    return roll, pitch
