"""One identified parameter and its JSON: :class:`ParameterEstimate`, the record every result writes.

Every record that states a parameter (eq. (2)'s analysis, the families', the cascade's, a vehicle's
loops, batch, watch lines, ``identify --json``) writes it as one JSON object (docs/records.md)::

    {"value": 0.0464, "std": 1.8e-05, "ci95_low": 0.04637, "ci95_high": 0.04644, "unit": "s",
     "determined": true, "known": false, "method": "waveform"}

``value`` is the point estimate (the given value of a known parameter), ``std`` its standard deviation
(null when not determined or not finite; read back as NaN), ``ci95_low``/``ci95_high`` its 95 % interval (null where
open), ``determined`` whether the tests pin it down, ``known`` whether it was given (the paper's set
E), ``method`` how the value was found (:data:`METHODS`). :meth:`ParameterEstimate.from_json` reads
that shape and, for one release, the two it replaces (eq. (2)'s ``mean`` shape of analysis schema
<= 3 and the families' ``one_sided`` shape).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ..errors import InputError

__all__ = ["ParameterEstimate", "METHODS", "JSON_KEYS", "Z95", "DETERMINED_LOG_WIDTH", "is_determined", "fitted_estimate",
           "display_scale"]

#: the 95 % point of the normal distribution (a normal interval is value +- Z95 std)
Z95 = 1.959964

#: a positive parameter is determined when its 95 % interval is within this log width: a factor
#: 1.25 either way. Issue 38: a factor e^2 called K 10.2 [7.2, 14.5] determined where one relay
#: setting saw only K/T1 (the truth 32); a user acts on a parameter pinned to +-25 %, not to 2x.
DETERMINED_LOG_WIDTH = 2 * math.log(1.25)


def display_scale(name: str, unit: str, process: bool) -> tuple[float, str]:
    """How a parameter is shown to people, one rule for every command (the records stay in SI): tau in ms on a
    vehicle's loop (eq. (2), a cascade: as its tests are read), a process plant's (``process``: a family's or a
    declared model's) in its record's ``unit``, as every other parameter.

    Returns
    -------
    tuple
        (scale from the record's unit, the unit shown).

    >>> display_scale("tau", "s", False), display_scale("tau", "s", True)
    ((1000.0, 'ms'), (1.0, 's'))
    """
    if name == "tau" and unit == "s" and not process:
        return 1e3, "ms"
    return 1.0, unit


def is_determined(low: float, high: float, log_scale: bool, omega: float) -> bool:
    """The one rule for "determined" (the families' fit and the cascade's): the 95 % interval as
    reported, [low, high] (in ln of the value for a log-scaled parameter), narrower than a factor 1.25
    either way (:data:`DETERMINED_LOG_WIDTH`), or for a delay [s] than a radian of phase at the tests'
    frequency ``omega`` [rad/s]."""
    return bool(high - low < DETERMINED_LOG_WIDTH) if log_scale else bool((high - low) * omega < 1.0)


def fitted_estimate(name: str, value: float, z: float, s: float, bounds: tuple[float, float], unit: str,
                    log_scale: bool, omega: float, method: str,
                    reach: tuple[float, float] | None = None) -> ParameterEstimate:
    """An identified parameter from a fit (the families' and the cascade's): the 95 % interval
    ``z -+ Z95 s`` in the fit's coordinate ``z`` (ln |value| for a log-scaled parameter, else the value
    [unit]), reaching at least to ``reach`` (a profile likelihood's ends), cut at ``bounds`` (the set I
    in ``z``; the end cut is ``one_sided``); std ``|value| s`` (log-scaled) or ``s``; :func:`is_determined`."""
    a, b = z - Z95 * s, z + Z95 * s
    if reach is not None:  # the profile's ends where they reach further (never narrower)
        a, b = min(a, reach[0]), max(b, reach[1])
    side = "low" if a <= bounds[0] else ("high" if b >= bounds[1] else "")
    a, b = max(a, bounds[0]), min(b, bounds[1])
    sign = math.copysign(1.0, value)
    ends = sorted([sign * math.exp(a), sign * math.exp(b)]) if log_scale else [a, b]
    return ParameterEstimate(value, float(abs(value) * s if log_scale else s), float(ends[0]), float(ends[1]), unit,
                             is_determined(a, b, log_scale, omega), False, method, name, side)


#: The keys of a parameter's JSON object, in their order.
JSON_KEYS = ("value", "std", "ci95_low", "ci95_high", "unit", "determined", "known", "method")

#: How a value was found: eq. (2)'s waveform refinement or MRFT consensus, a family's fit to the
#: tests' harmonic response points, the cascade's fit to its limit cycles, or given (known).
METHODS = ("waveform", "mrft", "response-points", "cascade-cycles", "given", "")


@dataclass(frozen=True)
class ParameterEstimate:
    """An identified (or given) parameter: its value, spread and 95 % interval.

    Attributes
    ----------
    value : float
        Point estimate [unit] (the given value for a known parameter).
    std : float
        Standard deviation [unit] (0 for a known parameter; NaN when not estimated).
    ci95_low, ci95_high : float
        95 % interval [unit]; NaN or infinite where the tests leave that side open (eq. (2)'s Td
        bounded from below only); an end cut at a bound of the set I is that bound (``one_sided``).
    unit : str
        The unit of the value.
    determined : bool
        Pinned down by the tests; False: the value is one of many that fit (docs/records.md).
    known : bool
        In the set E (given, not identified).
    method : str
        How the value was found (:data:`METHODS`); ``""`` where the record writing it says.
    name : str
        The family's parameter name (``""`` where the record's key names it).
    one_sided : str
        ``""``, ``"low"`` or ``"high"``: the interval's end that is a range's bound (open side).

    Examples
    --------
    >>> tau = ParameterEstimate(0.0464, 1.8e-05, 0.04637, 0.04644, "s", method="waveform")
    >>> tau.to_json()
    {'value': 0.0464, 'std': 1.8e-05, 'ci95_low': 0.04637, 'ci95_high': 0.04644, 'unit': 's', 'determined': True, 'known': False, 'method': 'waveform'}
    >>> old = {"mean": 2.0, "std": 0.4, "ci95_low": 1.4, "ci95_high": None, "unit": "s", "method": "mrft"}
    >>> Td = ParameterEstimate.from_json("Td", old)  # eq. (2)'s record before analysis schema 4
    >>> Td.value, Td.determined, Td.to_json()["std"]  # bounded from below only: not determined
    (2.0, False, None)
    """

    value: float
    std: float
    ci95_low: float
    ci95_high: float
    unit: str
    determined: bool = True
    known: bool = False
    # labels, not the estimate: two records of the same figures compare equal whoever names them
    method: str = field(default="", compare=False)
    name: str = field(default="", compare=False)
    one_sided: str = ""

    @classmethod
    def given(cls, value: float, unit: str, name: str = "") -> ParameterEstimate:
        """A known parameter (set E): its value, no spread, method ``"given"``."""
        return cls(float(value), 0.0, float(value), float(value), unit, True, True, "given", name)

    def to_json(self, *, unit: str | None = None, method: str | None = None) -> dict[str, Any]:
        """The one JSON object (:data:`JSON_KEYS`); ``unit``/``method`` override the record's for the JSON.

        Non-finite numbers are null; so is ``std`` of a parameter the tests do not determine (no
        standard deviation worth the name).
        """
        def finite(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {"value": finite(self.value), "std": finite(self.std) if self.determined or self.known else None,
                "ci95_low": finite(self.ci95_low), "ci95_high": finite(self.ci95_high),
                "unit": self.unit if unit is None else unit, "determined": self.determined, "known": self.known,
                "method": self.method if method is None else method}

    @classmethod
    def from_json(cls, name: str, data: Any, *, bounds: tuple[float, float] | None = None,
                  open_value: float = math.nan, method: str = "") -> ParameterEstimate:
        """The estimate of a :meth:`to_json` object (``name`` for messages and the record).

        Also reads, for one release, eq. (2)'s former ``{mean, std, ci95_low, ci95_high, unit[, method,
        known]}`` (``determined`` false where the interval is open above) and the families' former
        ``{value, ..., one_sided}``. ``bounds`` (the parameter's range, set I) recovers ``one_sided``
        where the JSON does not hold it; ``open_value`` is what a null interval end reads as (NaN in
        eq. (2)'s records, -inf/+inf as the families' ``(-inf, inf)``); ``method`` is the method of an
        identified parameter whose JSON does not say (the families' former layout; a known one's is ``"given"``).

        Raises
        ------
        InputError
            Not an object with a numeric value (or mean), or a unit that is not a string.
        """
        key = "value" if isinstance(data, Mapping) and "value" in data else "mean"
        if not (isinstance(data, Mapping) and _is_number(data.get(key)) and isinstance(data.get("unit", ""), str)):
            raise InputError(f"parameter JSON: {name!r} needs a numeric value (and a unit)")

        def num(k: str, default: float) -> float:
            v = data.get(k)
            if v is None:
                return default
            if not _is_number(v):
                raise InputError(f"parameter JSON: {name!r} {k} is not a number")
            return float(v)

        low, high = num("ci95_low", -open_value if open_value == math.inf else open_value), num("ci95_high", open_value)
        known = bool(data.get("known", False))
        if "determined" in data:
            determined = bool(data["determined"])
        else:  # eq. (2)'s former shape: not determined where the tests bound it from one side only
            determined = known or not (math.isfinite(low) and data.get("ci95_high", 0.0) is None)
        one_sided = str(data["one_sided"]) if "one_sided" in data else _one_sided(low, high, bounds, known)
        return cls(float(data[key]), num("std", math.nan), low, high, str(data.get("unit", "")), determined, known,
                   str(data["method"]) if "method" in data else ("given" if known else method), name, one_sided)


def _is_number(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _one_sided(low: float, high: float, bounds: tuple[float, float] | None, known: bool) -> str:
    """Which interval end sits on a range's bound (as the fit cut it there), from the range."""
    if bounds is None or known:
        return ""

    def at(x: float, bound: float) -> bool:
        # the fit wrote the bound itself (exp(ln bound) on the log scale: within rounding)
        return math.isfinite(bound) and math.isfinite(x) and abs(x - bound) <= 1e-9 * max(abs(bound), abs(x))

    if at(low, bounds[0]):
        return "low"
    return "high" if at(high, bounds[1]) else ""
