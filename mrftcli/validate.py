"""One validator per kind of argument, shared by the library and the CLI.

Each returns the value as a float and raises :class:`~mrftcli.errors.InputError` with a one-line
message naming the argument and what it must be.

Examples
--------
>>> check_beta(-0.4)
-0.4
>>> check_time("Tp", 0.0422)
0.0422
>>> check_beta(1.2)
Traceback (most recent call last):
...
mrftcli.errors.InputError: beta must lie in the open interval (-1, 1), got 1.2
"""

from __future__ import annotations

import math

from .errors import InputError

__all__ = ["check_beta", "check_positive", "check_time"]


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
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} must be a positive time in seconds, got {value!r}") from err
    if not math.isfinite(v) or v <= 0:
        raise InputError(f"{name} must be a positive time in seconds, got {value!r}")
    return v
