"""Is the log's clock in the unit the reader took it to be? (tracker issue 29, item 1)

A CSV or ``.mat`` time column carries no unit; one in milliseconds read as seconds makes a 200 Hz
flight a 0.2 Hz one, and the analysis then reports a 0.06 Hz limit cycle and a delay of 90 s with
exit 0. Every number downstream scales with the clock, so no later check can tell a slow plant from
a wrong unit except by what no flying vehicle can do. The thresholds:

* :data:`MAX_RATE_HZ` = 100 kHz: no flight stack logs a loop signal faster (PX4's fastest gyro
  path runs at 8 kHz; ArduPilot's loop at 400 Hz-2 kHz; motion capture at 100-500 Hz);
* :data:`MIN_RATE_HZ` = 1 Hz: an MRFT cycle of a vehicle loop (0.3-20 Hz) would get less than one
  sample: the relay's switches cannot be placed;
* :data:`MAX_PERIOD_S` = 60 s (used by the analysis): a vehicle loop under an MRFT oscillates
  at 0.1-20 Hz; a minute-long limit cycle is a hovering vehicle drifting, or a clock unit;
* :data:`MAX_DELAY_S` = 10 s (used by the analysis): a vehicle whose loop delay is 10 s cannot
  hold a hover at all.

:func:`check_rate` refuses a command sampled outside these rates with the unit that would make it
plausible (``--time-unit``); :func:`suggest_unit` finds that unit.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from ..errors import InputError, LogReadError
from .timing import median_rate_hz

__all__ = ["TIME_UNITS", "MAX_RATE_HZ", "MIN_RATE_HZ", "MAX_PERIOD_S", "MAX_DELAY_S", "check_time_unit",
           "suggest_unit", "check_rate", "implausible_timing"]

#: ``--time-unit`` choices -> seconds per unit
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: fastest plausible rate [Hz] of a logged loop signal
MAX_RATE_HZ = 100e3
#: slowest plausible rate [Hz] of a relay command
MIN_RATE_HZ = 1.0
#: longest plausible MRFT limit-cycle period of a vehicle loop [s]
MAX_PERIOD_S = 60.0
#: longest plausible loop delay of a vehicle [s]
MAX_DELAY_S = 10.0
#: the rate [Hz] a suggested unit aims for (a typical controller rate)
_TYPICAL_RATE_HZ = 200.0


def check_time_unit(unit: str | None) -> str | None:
    """``unit`` if it is one of :data:`TIME_UNITS` (or None); InputError otherwise."""
    if unit is not None and unit not in TIME_UNITS:
        raise InputError(f"unknown time unit {unit!r}; choose one of {', '.join(TIME_UNITS)}")
    return unit


def suggest_unit(rate_hz: float, assumed: str) -> tuple[str, float] | None:
    """The unit (and the rate [Hz] it gives) that makes ``rate_hz``, measured with times taken in
    ``assumed``, closest to a typical controller rate; None when none is plausible.

    Examples
    --------
    >>> suggest_unit(0.2, "s")   # a 200 Hz log whose times are in ms
    ('ms', 200.0)
    >>> suggest_unit(2e5, "us")  # a 200 Hz log whose times, read as microseconds, are in ms
    ('ms', 200.0)
    """
    best: tuple[float, str, float] | None = None
    for unit, factor in TIME_UNITS.items():
        if unit == assumed:
            continue
        rate = rate_hz * TIME_UNITS[assumed] / factor
        if MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
            score = abs(math.log(rate / _TYPICAL_RATE_HZ))
            if best is None or score < best[0]:
                best = (score, unit, rate)
    return None if best is None else (best[1], float(f"{best[2]:.6g}"))


def _fix(rate_hz: float, assumed: str, settable: bool) -> str:
    found = suggest_unit(rate_hz, assumed)
    if found is None:
        return "no time unit makes it plausible: check the time column"
    unit, rate = found
    if settable:
        return f"with times in {unit} it is {rate:.4g} Hz: if so, pass --time-unit {unit}"
    return (f"with times in {unit} it would be {rate:.4g} Hz: the recorder wrote its clock in another unit "
            "than the format's; convert the log")


def check_rate(t: npt.ArrayLike, what: str, assumed: str, settable: bool) -> None:
    """Refuse a signal whose sample rate no flight stack has (a time unit mistaken).

    Parameters
    ----------
    t : array_like
        Sample times [s] as read.
    what : str
        ``PATH: command TOPIC`` for the message.
    assumed : str
        The unit the reader took the times to be in (one of :data:`TIME_UNITS`).
    settable : bool
        The format lets ``--time-unit`` say otherwise (CSV, ``.mat``).

    Raises
    ------
    LogReadError
        The median rate is above :data:`MAX_RATE_HZ` or below :data:`MIN_RATE_HZ`.
    """
    rate = median_rate_hz(np.asarray(t, dtype=np.float64))
    if rate is None or MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
        return
    side = "above" if rate > MAX_RATE_HZ else "below"
    raise LogReadError(
        f"{what} is sampled at {rate:.4g} Hz with its times read in {assumed}, {side} what any flight stack "
        f"logs ({MIN_RATE_HZ:g} Hz-{MAX_RATE_HZ / 1e3:g} kHz): the time unit is wrong; "
        f"{_fix(rate, assumed, settable)}")


def implausible_timing(period_s: float | None, delay_s: float | None) -> str | None:
    """Why a limit-cycle period [s] or a loop delay [s] means the clock's unit is wrong, or None."""
    if period_s is not None and period_s > MAX_PERIOD_S:
        return (f"a limit-cycle period of {period_s:.4g} s (a vehicle loop's MRFT cycle lasts less than "
                f"{MAX_PERIOD_S:g} s)")
    if delay_s is not None and delay_s > MAX_DELAY_S:
        return f"a loop delay of {delay_s:.4g} s (no vehicle with a delay over {MAX_DELAY_S:g} s can hover)"
    return None
