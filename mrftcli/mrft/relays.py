"""The relay of a test: MRFT, ideal, with hysteresis; its levels and bias; its exact limit cycle; its
switching rule on sampled errors.

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

On sampled errors the relay decides with :class:`MrftRelay` (:meth:`RelayLaw.sampled`), the rule of
checks.md section 2 (the HEAR flight stack's), with the hysteresis added to its switching level. The
diagnosis' sampled relay (:func:`mrftcli.diagnose.limit_cycles.run_relay`) and the simulator both decide
with it; the tests check it against an independent transcription of the rule (``tests/relay_rule.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from ..jsonable import check_schema_version
from ..errors import InputError
from ..validate import check_beta
from .lprs import LimitCycle, mrft_limit_cycle
from .model import PlantModel, model_from_json

__all__ = ["RelayLaw", "MrftRelay", "Prediction", "RELAY_KINDS", "RELAY_SCHEMA_VERSION", "PREDICTION_SCHEMA_VERSION"]

#: the relay types
RELAY_KINDS = ("mrft", "ideal", "hysteresis")
#: version of :meth:`RelayLaw.to_json`
RELAY_SCHEMA_VERSION = 1
#: version of :meth:`Prediction.to_json`
PREDICTION_SCHEMA_VERSION = 1


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

    def sampled(self, start_threshold: float = 0.0) -> MrftRelay:
        """This relay's switching rule on sampled errors (a new :class:`MrftRelay`; it returns the sign)."""
        return MrftRelay(self.beta, start_threshold, self.eps)

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


@dataclass(frozen=True)
class Prediction:
    """A model's limit cycle under a relay (``predict``'s record).

    Attributes
    ----------
    cycle : LimitCycle
        The exact (or sampled-relay) limit cycle; read back from JSON without its waveform.
    model : PlantModel
        The model, every parameter given.
    relay : RelayLaw
        The relay.
    describing_function : tuple of float or None
        Eq. (2)'s describing-function estimate (frequency [Hz], amplitude [output units]), for
        comparison; None when not computed (a process family, or a relay with hysteresis).
    """

    cycle: LimitCycle
    model: PlantModel
    relay: RelayLaw
    describing_function: tuple[float, float] | None = None

    def to_json(self) -> dict[str, Any]:
        """``schema_version``, the cycle's summary (:meth:`LimitCycle.to_dict`), ``model``, ``relay`` and,
        when computed, ``describing_function`` (``frequency_hz``, ``amplitude``)."""
        out = {"schema_version": PREDICTION_SCHEMA_VERSION, **self.cycle.to_dict(),
               "model": self.model.to_json(), "relay": self.relay.to_json()}
        if self.describing_function is not None:
            out["describing_function"] = dict(zip(("frequency_hz", "amplitude"), self.describing_function))
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Prediction:
        """The prediction of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input."""
        data = check_schema_version(data, "predict JSON", PREDICTION_SCHEMA_VERSION)
        try:
            df = data.get("describing_function")
            return cls(LimitCycle.from_dict(data), model_from_json(data["model"]), RelayLaw.from_json(data["relay"]),
                       None if df is None else (float(df["frequency_hz"]), float(df["amplitude"])))
        except InputError as err:  # already names the field: one prefix, not "bad or missing field (...)"
            raise InputError(f"predict JSON: {err}") from None
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"predict JSON: bad or missing field ({err})") from None


class MrftRelay:
    """The switching rule of checks.md section 2 on sampled errors (returns the relay sign).

    e = r - y. While +h, track e_max since the last switch and switch to -h when e_max > 0 and
    e <= -beta e_max - eps; while -h, track e_min and switch to +h when e_min < 0 and
    e >= -beta e_min + eps. The tracked extremum restarts at the error of the switching sample. With
    eps = 0 this is the MRFT (beta = 0: the ideal relay); with beta = 0 the hysteresis relay.

    Start (:meth:`start`): the relay takes the sign of the first error (+ for e >= 0) and keeps it
    until the error is beyond ``start_threshold`` on the other side; that sample is the first switch
    and the rule above applies from there. With the vehicle at rest at the start, this keeps
    switching from beginning at noise level (the plain rule can then lock up); 0 means the first
    switch is at the first sample with the opposite sign.
    """

    def __init__(self, beta: float, start_threshold: float = 0.0, eps: float = 0.0) -> None:
        check_beta(beta)
        self.beta = float(beta)
        self.start_threshold = float(start_threshold)
        self.eps = float(eps)
        self.relay = 1.0
        self.e_ext = 0.0
        self.first_half = True

    def start(self, e: float) -> float:
        self.relay = 1.0 if e >= 0 else -1.0
        self.e_ext = e
        self.first_half = True
        return self.relay

    def step(self, e: float) -> float:
        if self.first_half:
            if self.relay * e < -self.start_threshold:
                self.relay = -self.relay
                self.e_ext = e
                self.first_half = False
        elif self.relay > 0:
            if e > self.e_ext:
                self.e_ext = e
            if self.e_ext > 0 and e <= -self.beta * self.e_ext - self.eps:
                self.relay = -1.0
                self.e_ext = e
        else:
            if e < self.e_ext:
                self.e_ext = e
            if self.e_ext < 0 and e >= -self.beta * self.e_ext + self.eps:
                self.relay = 1.0
                self.e_ext = e
        return self.relay
