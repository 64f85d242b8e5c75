"""The sampled PID of every loop (tune's designs, a cascade's inner loop, GAINS.json) and a flight stack's
filter on the measured rate.

The controller (:class:`Controller`) is a PID in parallel form with the derivative on the measurement
through a first-order filter, discretised by backward differences (stable for any Tf >= 0)::

    I_k = I_{k-1} + Ki T e_k,            e_k = r - y_k
    D_k = (Tf D_{k-1} - Kd (y_k - y_{k-1})) / (Tf + T)
    u_k = Kp e_k + I_k + D_k

or with the stack's 2nd-order Butterworth on the rate (:class:`RateFilter`) in place of Tf. One record:
:mod:`mrftcli.tune` designs it, :mod:`mrftcli.mrft.cascade` closes a cascade's inner loop with it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError
from ..validate import check_positive

__all__ = ["Controller", "RateFilter", "PX4VelocityPath", "json_number"]


def json_number(data: Mapping[str, Any], key: str, what: str, finite: bool = False) -> float:
    """``data[key]`` as a float (a JSON number, or the strings "inf"/"nan" of a tune record; ``finite``: a
    finite number only); InputError naming it."""
    value = data.get(key)
    if isinstance(value, str) and value in ("inf", "-inf", "nan") and not finite:
        return float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (finite and not math.isfinite(value)):
        raise InputError(f"{what}: {key!r} must be a {'finite ' if finite else ''}number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class RateFilter:
    """A flight stack's second-order Butterworth low-pass on the measured rate (PX4's ``IMU_GYRO_CUTOFF``,
    ArduPilot's ``INS_GYRO_FILTER``, HEAR_FC's rate filter), in place of the design's first-order Tf.

    The stacks run it as a biquad from the bilinear transform with prewarping (PX4 and ArduPilot
    ``LowPassFilter2p``): with omega_c = tan(pi f_c / f_s) and c = 1 + sqrt(2) omega_c + omega_c^2,
    b = omega_c^2 (1, 2, 1) / c and a = (1, 2 (omega_c^2 - 1) / c, (1 - sqrt(2) omega_c + omega_c^2) / c).
    It is modelled at the controller rate f_s (PX4 filters at the raw gyro rate and publishes at
    ``IMU_GYRO_RATEMAX``: for cutoffs well below the control rate the two responses agree; the
    tuning notes say so).

    Attributes
    ----------
    cutoff_hz : float
        Cutoff [Hz]; 0 disables the filter (the stacks' convention), as does a cutoff at or above
        half the controller rate (PX4 and ArduPilot then bypass it).
    parameter : str
        The stack's parameter that sets it (for messages), e.g. ``"IMU_GYRO_CUTOFF"``.

    Examples
    --------
    >>> f = RateFilter(40.0)
    >>> round(float(abs(f.response(np.array([1.0 + 0j]), 400.0)[0])), 12)  # unit gain at DC
    1.0
    """

    cutoff_hz: float
    parameter: str = ""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cutoff_hz) and self.cutoff_hz >= 0):
            raise InputError(f"the rate filter's cutoff must be a number >= 0 Hz, got {self.cutoff_hz!r}")

    def active(self, rate_hz: float) -> bool:
        """Whether the stack runs the filter at ``rate_hz`` (0 < cutoff < rate / 2)."""
        return 0.0 < self.cutoff_hz < 0.5 * rate_hz

    def coefficients(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """(b, a) of the biquad at ``rate_hz`` (b = (1, 0, 0), a = (1, 0, 0) when bypassed)."""
        if not self.active(rate_hz):
            return np.array([1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
        w = math.tan(math.pi * self.cutoff_hz / rate_hz)
        c = 1.0 + math.sqrt(2.0) * w + w * w
        b0 = w * w / c
        return (np.array([b0, 2.0 * b0, b0]),
                np.array([1.0, 2.0 * (w * w - 1.0) / c, (1.0 - math.sqrt(2.0) * w + w * w) / c]))

    def response(self, z: np.ndarray, rate_hz: float) -> np.ndarray:
        """B(z) = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2) at complex ``z``."""
        b, a = self.coefficients(rate_hz)
        zi = 1.0 / np.asarray(z, complex)
        out: np.ndarray = (b[0] + b[1] * zi + b[2] * zi * zi) / (a[0] + a[1] * zi + a[2] * zi * zi)
        return out

    def to_json(self) -> dict[str, Any]:
        """``{"cutoff_hz", "parameter"}``: what a controller's and a tune result's ``rate_filter`` hold."""
        return {"cutoff_hz": self.cutoff_hz, "parameter": self.parameter}

    @classmethod
    def from_json(cls, data: Any, what: str = "rate filter") -> RateFilter | None:
        """The filter of :meth:`to_json` (a :class:`PX4VelocityPath` when it has ``accel_s``), None for null;
        InputError (one line naming ``what``) otherwise."""
        if data is None:
            return None
        if not isinstance(data, Mapping):
            raise InputError(f"{what}: 'rate_filter' must be an object or null")
        cutoff, parameter = json_number(data, "cutoff_hz", what), str(data.get("parameter", ""))
        if "accel_s" in data:  # PX4's velocity path (:meth:`PX4VelocityPath.to_json`), not a Butterworth
            return PX4VelocityPath(cutoff, parameter, accel_s=json_number(data, "accel_s", what, finite=True))
        return cls(cutoff, parameter)

    def to_dict(self) -> dict[str, Any]:
        return {"type": "2nd-order Butterworth (bilinear, prewarped) on the measured rate",
                "cutoff_hz": self.cutoff_hz, "parameter": self.parameter}


@dataclass(frozen=True)
class PX4VelocityPath(RateFilter):
    """PX4's horizontal velocity loop on the rate: the velocity plus ``accel_s`` times its filtered derivative.

    ``PositionControl::_velocityControl`` computes acc = P_v (v_sp - v) + I - D_v a with a the
    ``MPC_VELD_LP`` alpha filter (``AlphaFilter``: a_k = a_(k-1) + alpha (x_k - a_(k-1)), alpha = T / (T +
    1 / (2 pi f_c))) of (v_k - v_(k-1)) / T (``MulticopterPositionControl.cpp``, ``MPC_VEL_LP`` 0: v unfiltered).
    On the rate v the derivative path is then P_v B(z) v with B(z) = 1 + (D_v / P_v) alpha (z - 1) /
    (T (z - (1 - alpha))): a first-order section in the controller's rate-filter place, so that tune's margins,
    step responses and its event simulation run PX4's loop. ``cutoff_hz`` is ``MPC_VELD_LP`` (0: alpha 1,
    PX4's "disabled"); ``accel_s`` = D_v / P_v [s].

    Examples
    --------
    >>> f = PX4VelocityPath(5.0, "MPC_VELD_LP", accel_s=0.1 / 1.5)
    >>> round(float(abs(f.response(np.array([1.0 + 0j]), 125.0)[0])), 12)  # the velocity itself at DC
    1.0
    """

    accel_s: float = 0.0

    def active(self, rate_hz: float) -> bool:
        return True

    def alpha(self, rate_hz: float) -> float:
        """The filter's coefficient at ``rate_hz`` [Hz], as PX4's AlphaFilter sets it (1: no cutoff)."""
        if self.cutoff_hz == 0.0:
            return 1.0
        if self.cutoff_hz >= 0.5 * rate_hz:  # AlphaFilter::setCutoffFreq refuses it: PX4 keeps the old alpha
            raise InputError(f"MPC_VELD_LP {self.cutoff_hz:g} Hz (written at PX4's default) is at or above half the "
                             f"position controller's rate {rate_hz:g} Hz, where PX4 ignores it: give --controller-rate "
                             "HZ, the rate PX4's position controller ran at (without it the log's rate is taken)")
        T = 1.0 / rate_hz
        return T / (T + 1.0 / (2.0 * math.pi * self.cutoff_hz))

    def coefficients(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """(b, a) of B(z) in powers of z^-1 (b2 = a2 = 0: the biquad form of :class:`RateFilter`)."""
        al, g = self.alpha(rate_hz), self.accel_s * rate_hz
        return np.array([1.0 + g * al, -(1.0 - al) - g * al, 0.0]), np.array([1.0, -(1.0 - al), 0.0])

    def response(self, z: np.ndarray, rate_hz: float) -> np.ndarray:
        b, a = self.coefficients(rate_hz)
        zi = 1.0 / np.asarray(z, complex)
        out: np.ndarray = (b[0] + b[1] * zi) / (a[0] + a[1] * zi)
        return out

    def to_json(self) -> dict[str, Any]:
        """:meth:`RateFilter.to_json` with ``accel_s``, by which :meth:`RateFilter.from_json` tells the two apart."""
        return {**super().to_json(), "accel_s": self.accel_s}

    def to_dict(self) -> dict[str, Any]:
        return {"type": "PX4's velocity plus accel_s x its derivative through MPC_VELD_LP's alpha filter",
                "cutoff_hz": self.cutoff_hz, "parameter": self.parameter, "accel_s": self.accel_s}


@dataclass(frozen=True)
class Controller:
    """A sampled PID (parallel form, derivative on the measurement, first-order derivative filter).

    C(s) = Kp + Ki / s + Kd s / (Tf s + 1) on the error for P and I, on -y for D, at ``rate_hz``.

    Attributes
    ----------
    Kp : float
        Proportional gain [command units / output unit].
    Ki : float
        Integral gain [command units / (output unit s)]; 0 for a PD.
    Kd : float
        Derivative gain [command units / (output unit / s)].
    Tf : float
        Derivative filter time constant [s] (>= 0).
    rate_hz : float
        Controller rate [Hz].
    rate_filter : RateFilter, optional
        The flight stack's filter on the measured rate: the derivative is then the backward
        difference of y through it, D(z) = (z - 1) / (T z) B(z), and Tf is not used (set it to 0).

    Examples
    --------
    >>> c = Controller(Kp=2.0, Ki=0.0, Kd=0.5, Tf=0.01, rate_hz=200.0)
    >>> c.kind, c.Ts
    ('PD', 0.005)
    """

    Kp: float
    Ki: float
    Kd: float
    Tf: float
    rate_hz: float
    rate_filter: RateFilter | None = None

    def __post_init__(self) -> None:
        for name in ("Kp", "Ki", "Kd", "Tf"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"controller {name} must be a finite number >= 0, got {v!r}")
        check_positive("the controller rate [Hz]", self.rate_hz)

    @property
    def Ts(self) -> float:
        """Sample period [s]."""
        return 1.0 / self.rate_hz

    @property
    def kind(self) -> str:
        """``"PD"``, ``"PI"`` (integral action, no derivative: the process families') or ``"PID"``."""
        return ("PI" if self.Kd == 0 else "PID") if self.Ki > 0 else "PD"

    def scaled(self, g: float) -> "Controller":
        """The same controller with Kp, Ki, Kd multiplied by ``g`` (Tf kept)."""
        return Controller(self.Kp * g, self.Ki * g, self.Kd * g, self.Tf, self.rate_hz, self.rate_filter)

    def derivative_response(self, z: np.ndarray) -> np.ndarray:
        """D(z), the derivative path from y [per second]: (z - 1) / ((Tf + T) z - Tf), or with the stack's
        filter (z - 1) / (T z) B(z)."""
        T = self.Ts
        z = np.asarray(z, complex)
        out: np.ndarray = ((z - 1.0) / ((self.Tf + T) * z - self.Tf) if self.rate_filter is None
                           else (z - 1.0) / (T * z) * self.rate_filter.response(z, self.rate_hz))
        return out

    def feedback_response(self, omega: np.ndarray) -> np.ndarray:
        """C_fb(e^{j omega T}): the controller from -y to u (the loop is L = C_fb Gd), omega in rad/s."""
        return self.feedback_at(np.exp(1j * np.asarray(omega, float) * self.Ts))

    def feedback_at(self, z: np.ndarray) -> np.ndarray:
        """C_fb(z) at points ``z`` of the z-plane (the unit circle, or tune's contours and inversion circle)."""
        T = self.Ts
        if self.rate_filter is not None:
            return self.Kp + self.Ki * T * z / (z - 1.0) + self.Kd * self.derivative_response(z)
        return (self.Kp + self.Ki * T * z / (z - 1.0) + self.Kd * (z - 1.0) / ((self.Tf + T) * z - self.Tf))

    def noise_gain(self) -> float:
        """The largest |C_fb| over frequency [command units / output unit]: how much sensor noise reaches u.

        With backward differences and a first-order filter the derivative's gain is largest at
        z = -1 (Nyquist); a stack's Butterworth has its zeros there, so its peak is searched on a
        grid up to Nyquist.
        """
        T = self.Ts
        if self.rate_filter is None:
            return abs(self.Kp - self.Ki * T / 2.0 + self.Kd * 2.0 / (2.0 * self.Tf + T))
        w = np.linspace(0.05, 1.0, 400) * math.pi * self.rate_hz
        return float(np.max(np.abs(self.feedback_response(w))))

    def to_json(self) -> dict[str, Any]:
        """``{"Kp", "Ki", "Kd", "Tf", "rate_hz"}`` (tune's generic form; and the stack's ``rate_filter`` when
        there is one): what a tune record, a cascade's inner loop and GAINS.json hold."""
        out: dict[str, Any] = {"Kp": self.Kp, "Ki": self.Ki, "Kd": self.Kd, "Tf": self.Tf, "rate_hz": self.rate_hz}
        if self.rate_filter is not None:
            out["rate_filter"] = self.rate_filter.to_json()
        return out

    @classmethod
    def from_json(cls, data: Any, what: str = "controller") -> Controller:
        """The controller of :meth:`to_json` (extra keys such as ``form`` are ignored).

        Raises
        ------
        InputError
            Not an object, a gain missing or not a number (one line naming ``what``).

        Examples
        --------
        >>> Controller.from_json({"Kp": 2.0, "Ki": 0, "Kd": 0.3, "Tf": 0.01, "rate_hz": 200, "form": "parallel"})
        Controller(Kp=2.0, Ki=0.0, Kd=0.3, Tf=0.01, rate_hz=200.0, rate_filter=None)
        """
        if not isinstance(data, Mapping):
            raise InputError(f"{what} must be an object with Kp, Ki, Kd, Tf, rate_hz, got {type(data).__name__}")
        rf = RateFilter.from_json(data.get("rate_filter"), what)
        Kp, Ki, Kd, Tf, rate = (json_number(data, k, what) for k in ("Kp", "Ki", "Kd", "Tf", "rate_hz"))
        return cls(Kp, Ki, Kd, Tf, rate, rf)

    def to_dict(self) -> dict[str, Any]:
        """Kp, Ki, Kd, Tf [s], rate_hz and the form (and the stack's rate filter when there is one)."""
        if self.rate_filter is not None:
            return {**self.to_json(), "rate_filter": self.rate_filter.to_dict(),
                    "form": "parallel; derivative on measurement through the stack's rate filter; backward "
                            "differences"}
        return {**self.to_json(), "form": "parallel; derivative on measurement, first-order filter Tf; backward differences"}
