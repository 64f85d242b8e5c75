"""One validator per kind of argument, shared by the library and the CLI.

Each returns the value as a float and raises :class:`~mrftcli.errors.InputError` with a one-line
message naming the argument and what it must be.

Examples
--------
>>> check_beta(-0.4)
-0.4
>>> check_time("Tp", 0.0422)
0.0422
>>> check_tp(0.0422)
0.0422
>>> check_beta(1.2)
Traceback (most recent call last):
...
mrftcli.errors.InputError: beta must lie in the open interval (-1, 1), got 1.2
"""

from __future__ import annotations

import math

from .errors import InputError

__all__ = ["check_beta", "check_positive", "check_time", "check_tp", "TP_RANGE", "TP_MISSING"]

#: Physical range of the propulsion time constant Tp [s]: a multirotor's motor and propeller respond in
#: tens of milliseconds (the paper's 42.2 ms); 1 ms is below any rotor's inertia, 2 s is an airship.
TP_RANGE = (1e-3, 2.0)

#: What Tp is and how to give it, said when it is missing (the model rests on it: never assumed).
TP_MISSING = ("the propulsion time constant Tp [s] from a bench test of the motor and propeller is required, "
              "e.g. --tp 0.0422 (42.2 ms)")


def check_beta(beta: float) -> float:
    """The MRFT parameter beta [-], a number in the open interval (-1, 1) (paper eq. (1))."""
    try:
        value = float(beta)
    except (TypeError, ValueError) as err:
        raise InputError(f"beta must be a number in (-1, 1), got {beta!r}") from err
    if not -1.0 < value < 1.0:
        raise InputError(f"beta must lie in the open interval (-1, 1), got {value}")
    return value


def check_positive(name: str, value: float) -> float:
    """A positive, finite number called ``name`` in messages (a relay height, a rate in Hz, ...)."""
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} must be a positive number, got {value!r}") from err
    if not math.isfinite(v) or v <= 0:
        raise InputError(f"{name} must be a positive number, got {v}")
    return v


def check_time(name: str, value: float) -> float:
    """A positive, finite time in seconds called ``name`` in messages (Tp, Td, tau, a duration)."""
    if value is None:
        what = TP_MISSING if name == "Tp" else "give it as a positive time in seconds"
        raise InputError(f"{name} is missing: {what}")
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} must be a positive time in seconds, got {value!r}") from err
    if not math.isfinite(v) or v <= 0:
        raise InputError(f"{name} must be a positive time in seconds, got {value!r}")
    return v


def check_tp(value: float) -> float:
    """The propulsion time constant Tp [s] (bench test), within :data:`TP_RANGE`.

    A Tp outside the physical range is refused rather than identified with: a Tp of 1e-9 s, or one
    given in milliseconds (42.2 for 42.2 ms), would produce a plausible-looking but wrong model.

    Examples
    --------
    >>> check_tp(1e-9)
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: Tp = 1e-09 s is outside the physical range 0.001-2 s of a propulsion time constant (tens of ms for a multirotor); give it in seconds, e.g. 0.0422
    """
    v = check_time("Tp", value)
    low, high = TP_RANGE
    if not low <= v <= high:
        raise InputError(f"Tp = {v:g} s is outside the physical range {low:g}-{high:g} s of a propulsion time "
                         "constant (tens of ms for a multirotor); give it in seconds, e.g. 0.0422")
    return v
