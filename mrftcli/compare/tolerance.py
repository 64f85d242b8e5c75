"""Tolerances as users write them: ``--fail-on tau:+5ms,K:10%,Td:25%`` and a reference file's ``tol``.

One item is ``[LOOP.]PARAM:[+|-]AMOUNT[UNIT]``:

* ``PARAM`` is ``Td``, ``tau`` or ``K``; a ``LOOP.`` prefix (``altitude.tau``) restricts it to one loop;
* a leading ``+`` fails only on increases beyond the amount, ``-`` only on decreases; without a sign
  (or with ``±``) both directions fail (two-sided);
* ``AMOUNT`` is absolute with a unit (``s``, ``ms``, ``us`` for Td and tau; none for K, in its own
  units) or relative to the baseline value with ``%``. A time without a unit is refused: ``tau:5``
  could mean 5 s or 5 ms.

Examples
--------
>>> parse_tolerance("tau:+5ms")
Tolerance(parameter='tau', amount=0.005, relative=False, direction=1, loop=None, text='tau:+5ms')
>>> [t.text for t in parse_fail_on("K:10%, altitude.Td:-25%")]
['K:10%', 'altitude.Td:-25%']
"""

from __future__ import annotations

import math
import re

from ..errors import InputError
from .records import PARAMETERS, Tolerance

__all__ = ["parse_tolerance", "parse_fail_on", "parse_amount", "TIME_UNITS"]

#: Unit suffix -> factor to seconds (for Td and tau).
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6}

_ITEM = re.compile(r"^\s*(?:(?P<loop>[A-Za-z_][\w-]*)\.)?(?P<param>\w+)\s*:\s*(?P<amount>.+?)\s*$")
_AMOUNT = re.compile(r"^(?P<sign>[+\-±]?)\s*(?P<number>\d+(?:\.\d*)?(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?)"
                     r"\s*(?P<unit>%|s|ms|us|µs)?$")


def parse_amount(parameter: str, text: str) -> tuple[float, bool, int]:
    """Parse ``[+|-]AMOUNT[UNIT]`` for one parameter.

    Returns
    -------
    amount : float
        SI units (seconds for Td, tau), or a fraction when relative.
    relative : bool
        True for ``%``.
    direction : int
        +1, -1 or 0 (two-sided).

    Raises
    ------
    InputError
        Malformed, negative after its sign, or a time without a unit.
    """
    m = _AMOUNT.match(text.strip())
    if m is None:
        raise InputError(f"{parameter}:{text}: give [+|-]NUMBER[UNIT], e.g. {parameter}:+5ms or {parameter}:10%")
    number = float(m["number"])
    unit = m["unit"]
    direction = {"+": 1, "-": -1}.get(m["sign"], 0)
    if not math.isfinite(number):
        raise InputError(f"{parameter}:{text}: the amount must be a finite number")
    if unit == "%":
        return number / 100.0, True, direction
    if parameter == "K":
        if unit is not None:
            raise InputError(f"{parameter}:{text}: K takes no time unit; give it in K's own units or as %")
        return number, False, direction
    if unit is None:
        raise InputError(f"{parameter}:{text}: give a unit (s, ms, us) or %, e.g. {parameter}:{text}ms")
    return number * TIME_UNITS[unit], False, direction


def parse_tolerance(item: str) -> Tolerance:
    """Parse one ``[LOOP.]PARAM:[+|-]AMOUNT[UNIT]`` item.

    Raises
    ------
    InputError
        Unknown parameter or malformed amount.
    """
    m = _ITEM.match(item)
    if m is None:
        raise InputError(f"--fail-on item {item.strip()!r}: give PARAM:AMOUNT, e.g. tau:+5ms, K:10%, Td:25%")
    param = m["param"]
    if param not in PARAMETERS:
        raise InputError(f"--fail-on item {item.strip()!r}: unknown parameter {param!r} "
                         f"(known: {', '.join(PARAMETERS)})")
    amount, relative, direction = parse_amount(param, m["amount"])
    return Tolerance(parameter=param, amount=amount, relative=relative, direction=direction, loop=m["loop"],
                     text=item.strip())


def parse_fail_on(spec: str) -> tuple[Tolerance, ...]:
    """Parse a comma-separated ``--fail-on`` spec; a later item for the same loop and parameter wins.

    Raises
    ------
    InputError
        An empty spec or a malformed item.
    """
    items = [s for s in spec.split(",") if s.strip()]
    if not items:
        raise InputError("--fail-on: empty; give e.g. tau:+5ms,K:10%,Td:25%")
    by_key = {}
    for item in items:
        tol = parse_tolerance(item)
        by_key[(tol.loop, tol.parameter)] = tol
    return tuple(by_key.values())
