"""The relay of a test: MRFT, ideal, with hysteresis; its levels and bias; its exact limit cycle.

A relay test's command is ``u = bias + h sign(.)`` between the two levels ``high = bias + h`` and
``low = bias - h``. What differs between relays is where they switch (e = r - y):

* ``mrft`` (paper eq. 3): at ``-beta`` times the error's extremum since the last switch, so the
  switching level scales with the amplitude (``beta a_y``);
* ``ideal``: where the error changes sign;
* ``hysteresis``: where the error passes ``-eps`` / ``+eps`` [output units] (a level independent of
  the amplitude; the classic relay autotuner of Astrom and Hagglund).

The exact limit cycle under any of them is the LPRS one of :func:`~mrftcli.mrft.lprs.mrft_limit_cycle`
with the switching level ``beta a_y + eps``. The bias moves the loop's operating point; the cycle
is taken about it (a bias that is not balanced by the plant's operating point shows as unequal
half periods, which the output states as an assumption).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from ..jsonable import check_schema_version
from ..errors import InputError
from .lprs import LimitCycle, mrft_limit_cycle
from .model import PlantModel

__all__ = ["RelayLaw", "RELAY_KINDS", "RELAY_SCHEMA_VERSION"]

#: the relay types
RELAY_KINDS = ("mrft", "ideal", "hysteresis")
#: version of :meth:`RelayLaw.to_json`
RELAY_SCHEMA_VERSION = 1


@dataclass(frozen=True)
class RelayLaw:
    """One test's relay.

    Attributes
    ----------
    kind : str
        ``"mrft"``, ``"ideal"`` or ``"hysteresis"``.
    high, low : float
        The two command levels [command units], high > low.
    beta : float
        MRFT parameter in (-1, 1) (0 for the other kinds).
    eps : float
        Hysteresis [output units], >= 0 (0 for the other kinds).
    source : str
        ``"stated"`` (given by the user or logged) or ``"inferred"`` (read from the data).

    Examples
    --------
    >>> r = RelayLaw("hysteresis", high=1200.0, low=-720.0, eps=1.2e-6)
    >>> r.h, r.bias
    (960.0, 240.0)
    >>> r.describe()
    'relay: hysteresis eps 1.2e-06, levels +1200 / -720, bias +240'
    """

    kind: str
    high: float
    low: float
    beta: float = 0.0
    eps: float = 0.0
    source: str = "inferred"

    def __post_init__(self) -> None:
        if self.kind not in RELAY_KINDS:
            raise InputError(f"unknown relay {self.kind!r}; known: {', '.join(RELAY_KINDS)}")
        if not (math.isfinite(self.high) and math.isfinite(self.low) and self.high > self.low):
            raise InputError(f"relay levels must be finite with high > low, got {self.high!r} / {self.low!r}")
        if not (math.isfinite(self.beta) and -1 < self.beta < 1):
            raise InputError(f"relay beta must be in (-1, 1), got {self.beta!r}")
        if not (math.isfinite(self.eps) and self.eps >= 0):
            raise InputError(f"relay hysteresis eps must be >= 0 [output units], got {self.eps!r}")
        if self.kind != "mrft" and self.beta != 0:
            raise InputError(f"a {self.kind} relay has no beta (use --relay mrft)")
        if self.kind != "hysteresis" and self.eps != 0:
            raise InputError(f"a {self.kind} relay has no hysteresis eps (use --relay hysteresis)")

    @property
    def h(self) -> float:
        """Half the level difference [command units]."""
        return 0.5 * (self.high - self.low)

    @property
    def bias(self) -> float:
        """The levels' midpoint [command units]."""
        return 0.5 * (self.high + self.low)

    def describe(self) -> str:
        """One line: kind, its parameter, levels and bias."""
        what = {"mrft": f"MRFT beta {self.beta:+.3g}", "ideal": "ideal",
                "hysteresis": f"hysteresis eps {self.eps:.3g}"}[self.kind]
        return f"relay: {what}, levels {self.high:+.5g} / {self.low:+.5g}, bias {self.bias:+.4g}"

    def limit_cycle(self, model: PlantModel, rate_hz: float | None = None) -> LimitCycle:
        """The exact limit cycle of ``model`` under this relay (continuous, or sampled at ``rate_hz``).

        Raises
        ------
        InputError
            No limit cycle (e.g. a hysteresis larger than any oscillation the plant sustains).
        """
        return mrft_limit_cycle(model, self.beta, self.h, rate_hz, eps=self.eps)

    def to_json(self) -> dict[str, Any]:
        return {"schema_version": RELAY_SCHEMA_VERSION, "kind": self.kind, "high": self.high, "low": self.low,
                "h": self.h, "bias": self.bias, "beta": self.beta, "eps": self.eps, "source": self.source}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> RelayLaw:
        """The relay of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input."""
        data = check_schema_version(data, "relay JSON", RELAY_SCHEMA_VERSION)
        try:
            return cls(str(data["kind"]), float(data["high"]), float(data["low"]), float(data.get("beta", 0.0)),
                       float(data.get("eps", 0.0)), str(data.get("source", "inferred")))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"relay JSON: bad or missing field ({err})") from None
