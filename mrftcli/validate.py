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

__all__ = ["check_beta", "check_positive", "check_time", "check_tp", "check_parameter_value", "TP_RANGE", "TP_MISSING",
           "PARAMETER_MAGNITUDE", "check_rate", "check_spread", "MAX_TIME_S",
           "MAX_RATE_HZ"]

#: Physical range of the propulsion time constant Tp [s]: a multirotor's motor and propeller respond in
#: tens of milliseconds (the paper's 42.2 ms); 1 ms is below any rotor's inertia, 2 s is an airship.
TP_RANGE = (1e-3, 2.0)

#: The magnitudes a model parameter's value or range end may have (0 allowed): a physical quantity in SI
#: units (s for times), far beyond any plant's and far from the floats' underflow and overflow.
PARAMETER_MAGNITUDE = (1e-9, 1e9)

#: Longest time any option or model parameter may be [s]: a week. A relay test, a delay, a time constant
#: or a flight's time budget beyond it is a typo or hostile (1e300 s made root finders fail, 1e9 s plans
#: asked for GB); a process plant's hours are well inside.
MAX_TIME_S = 7 * 86400.0

#: Fastest rate [Hz] any option may give: the 100 kHz the log readers accept (:mod:`mrftcli.io.clock`).
MAX_RATE_HZ = 100e3

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
    if v > MAX_TIME_S:
        raise InputError(f"{name} = {v:g} s is longer than a week ({MAX_TIME_S:g} s); give it in seconds")
    return v


def check_rate(name: str, value: float) -> float:
    """A rate [Hz] called ``name`` in messages: positive, finite and at most :data:`MAX_RATE_HZ`.

    Examples
    --------
    >>> check_rate("--controller-rate", 1e300)
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: --controller-rate = 1e+300 Hz is above 100000 Hz, the fastest rate a log is read at
    """
    v = check_positive(f"{name} (a rate in Hz)", value)
    if v > MAX_RATE_HZ:
        raise InputError(f"{name} = {v:g} Hz is above {MAX_RATE_HZ:g} Hz, the fastest rate a log is read at")
    return v


def check_spread(name: str, std: float, value: float) -> float:
    """A standard deviation ``std`` of a parameter whose value is ``value``: finite, >= 0 and at most ten
    times the value (a wider spread is no prior: 1e300 overflowed the log-normal draws).

    Examples
    --------
    >>> check_spread("--td-std", 1e300, 0.5)
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: --td-std = 1e+300 is not a spread of the value 0.5: give a number from 0 to 5 (ten times the value)
    """
    limit = 10.0 * abs(value)
    if not (math.isfinite(std) and 0 <= std <= limit):
        raise InputError(f"{name} = {std:g} is not a spread of the value {value:g}: give a number from 0 to "
                         f"{limit:g} (ten times the value)")
    return std


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


def check_parameter_value(what: str, value: float) -> float:
    """A model parameter's value or range end: finite, and 0 or of a magnitude within :data:`PARAMETER_MAGNITUDE`.

    Examples
    --------
    >>> check_parameter_value("--param T", 1e-300)
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: --param T = 1e-300 is outside the physical range: give 0 or a magnitude from 1e-09 to 1e+09 (SI units, s for times)
    """
    low, high = PARAMETER_MAGNITUDE
    if not (math.isfinite(value) and (value == 0 or low <= abs(value) <= high)):
        raise InputError(f"{what} = {value:g} is outside the physical range: give 0 or a magnitude from {low:g} "
                         f"to {high:g} (SI units, s for times)")
    return value
