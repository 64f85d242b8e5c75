"""What a cascaded flight is (:class:`CascadeSpec`) and what it leaves as truth (:class:`CascadeTruth`).

An outer loop (x or y position) runs through the inner attitude loop (pitch or roll), closed by a
sampled PD (:class:`InnerGains`: the one PID record, tune's generic form). The truth record is the sidecar of a cascaded
log (``<log>.truth.json``), versioned: tests and benchmarks read it through
:meth:`CascadeTruth.from_json`.

Sign conventions (FRD body, NED world): y'' = g phi - y'/Td (positive roll accelerates +y), x'' = -g
theta - x'/Td (positive pitch, nose up, accelerates -x). The simulator works with the attitude "in
the output's direction", alpha = phi for y and alpha = -theta for x, so both read y'' = g alpha -
y'/Td; the pitch loop's logged angle and command are -alpha and -u. The outer command c is in the
output's direction too: a commanded attitude alpha_ref = c [rad] (K = g) or a commanded acceleration
alpha_ref = c / g [m/s^2] (K = 1).

Units: times [s], rates [Hz], positions [m], angles [rad], inner commands [inner command units].
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import partial
from typing import Any

from ..errors import InputError
from ..jsonable import check_schema_version
from ..mrft.controller import Controller, json_number
from ..mrft.cascade import STANDARD_GRAVITY
from ..mrft.model import LoopModel
from .spec import TestSpec, check_flight_size, check_hover_hold, check_switching

__all__ = ["InnerGains", "CascadeSpec", "CascadeTestTruth", "CascadeTruth", "CASCADE_AXES", "COMMANDED",
           "CASCADE_TRUTH_SCHEMA"]

#: outer loop -> the inner attitude loop it runs through
CASCADE_AXES: Mapping[str, str] = {"y": "roll", "x": "pitch"}
#: what the outer MRFT drives: the attitude setpoint [rad] (K = g) or the acceleration [m/s^2] (K = 1)
COMMANDED = ("attitude", "acceleration")
#: schema version of :class:`CascadeTruth`
CASCADE_TRUTH_SCHEMA = 1

_DEG = math.pi / 180.0
#: a sidecar's number: finite, else InputError naming it (:func:`~mrftcli.mrft.controller.json_number`)
_number = partial(json_number, finite=True)


#: The inner loop's sampled PD/PID: the one PID record (:class:`~mrftcli.mrft.controller.Controller`, tune's
#: generic form; ``to_json``/``from_json`` are GAINS.json's inner-loop entry).
InnerGains = Controller


@dataclass(frozen=True)
class CascadeSpec:
    """One cascaded flight: the inner plant and its PD, the outer dynamics, the tests.

    Attributes
    ----------
    inner : LoopModel
        The attitude plant of eq. (2): inner command -> attitude [rad] (K, Tp, Td, tau of the attitude).
    gains : InnerGains
        The PD (or PID) that closes the inner loop; its rate is the flight's controller rate.
    Td : float
        Outer drag time constant [s]: y'' = g alpha - y' / Td.
    tau : float
        Delay of the position measurement [s] (motion capture latency), >= 0.
    axis : {"y", "x"}
        The outer loop (y through roll, x through pitch).
    commanded : {"acceleration", "attitude"}
        What the outer MRFT (and the outer hold) drives: alpha_ref = c / g or alpha_ref = c.
    inner_tests, outer_tests : tuple of TestSpec
        The inner loop's MRFT tests (h in inner command units), flown first, then the outer ones
        (h in m/s^2 or rad).
    attitude_noise_std, position_noise_std : float or None
        White measurement noise per tick [rad], [m]; None: 0.05 deg and 0.2 mm (motion capture).
    hover_s, hold_s : float
        Hold before the first test and after each test [s].
    seed : int
        Seed of the noise.
    start_time : float
        Log time of the first tick [s].
    switching : {"checks", "hear"}
        The MRFT switching rule of both loops' relays (see :class:`mrftcli.sim.FlightSpec`).
    g : float
        Gravity [m/s^2] in y'' = g alpha.
    """

    inner: LoopModel
    gains: InnerGains
    Td: float
    tau: float
    axis: str = "y"
    commanded: str = "acceleration"
    inner_tests: tuple[TestSpec, ...] = ()
    outer_tests: tuple[TestSpec, ...] = ()
    attitude_noise_std: float | None = None
    position_noise_std: float | None = None
    hover_s: float = 3.0
    hold_s: float = 3.0
    seed: int = 0
    start_time: float = 0.0
    switching: str = "checks"
    g: float = STANDARD_GRAVITY

    def __post_init__(self) -> None:
        if self.axis not in CASCADE_AXES:
            raise InputError(f"a cascade's outer loop is x or y, got {self.axis!r}")
        if self.commanded not in COMMANDED:
            raise InputError(f"the outer command is one of {', '.join(COMMANDED)}, got {self.commanded!r}")
        if not (math.isfinite(self.Td) and self.Td > 0):
            raise InputError(f"the outer Td must be a positive time in seconds, got {self.Td!r}")
        if not (math.isfinite(self.tau) and self.tau >= 0):
            raise InputError(f"the outer tau must be a non-negative time in seconds, got {self.tau!r}")
        check_switching(self.switching)
        check_hover_hold(self)
        if not (self.inner_tests or self.outer_tests):
            raise InputError("give at least one MRFT test (inner or outer)")
        tests = (*self.inner_tests, *self.outer_tests)
        if any(t.eps != 0 for t in tests):
            raise InputError("a cascaded flight flies MRFT tests: leave the hysteresis eps at 0")
        check_flight_size(self.hover_s + sum(t.duration + self.hold_s for t in tests), self.gains.rate_hz)

    @property
    def inner_loop(self) -> str:
        """``roll`` (y) or ``pitch`` (x)."""
        return CASCADE_AXES[self.axis]

    @property
    def K(self) -> float:
        """The outer gain of G_outer: g for a commanded attitude, 1 for a commanded acceleration."""
        return self.g if self.commanded == "attitude" else 1.0

    @property
    def rate_hz(self) -> float:
        """The controller rate [Hz]."""
        return self.gains.rate_hz

    def noise(self) -> tuple[float, float]:
        """(attitude [rad], position [m]) noise std with the defaults filled in."""
        att = 0.05 * _DEG if self.attitude_noise_std is None else float(self.attitude_noise_std)
        pos = 0.0002 if self.position_noise_std is None else float(self.position_noise_std)
        return att, pos


@dataclass(frozen=True)
class CascadeTestTruth:
    """One flown test: its loop (``roll``/``pitch`` or ``x``/``y``), beta, h, span [s] and abort."""

    loop: str
    beta: float
    h: float
    t_start: float
    t_end: float
    aborted: bool

    def to_json(self) -> dict[str, Any]:
        return {"loop": self.loop, "beta": self.beta, "h": self.h, "t_start": self.t_start, "t_end": self.t_end,
                "aborted": self.aborted}

    @classmethod
    def from_json(cls, data: Any) -> CascadeTestTruth:
        if not isinstance(data, Mapping) or not isinstance(data.get("loop"), str):
            raise InputError("cascade truth: each test needs a loop name")
        what = "cascade truth test"
        return cls(str(data["loop"]), _number(data, "beta", what), _number(data, "h", what),
                   _number(data, "t_start", what), _number(data, "t_end", what), bool(data.get("aborted", False)))


@dataclass(frozen=True)
class CascadeTruth:
    """The truth sidecar of a cascaded flight (``<log>.truth.json``), versioned.

    Attributes
    ----------
    axis, inner_loop : str
        ``y``/``roll`` or ``x``/``pitch``.
    commanded : str
        ``acceleration`` (K = 1, command in m/s^2) or ``attitude`` (K = g, command in rad).
    K, Td, tau : float
        The outer loop's truth: gain, drag time constant [s], position measurement delay [s].
    g : float
        Gravity [m/s^2].
    inner : LoopModel
        The inner attitude plant (eq. (2)).
    gains : InnerGains
        The inner PD in use during the outer tests (and throughout the flight).
    outer_hold : InnerGains
        The position hold between tests (position error -> outer command), for the record.
    attitude_noise_std, position_noise_std : float
        White noise per tick [rad], [m].
    switching : str
        The relays' switching rule.
    seed : int
    start_time, duration : float
        Log time of the first tick and the flight's length [s].
    tests : tuple of CascadeTestTruth
        The tests in flight order (inner first).
    layout, log_format, log_file : str
        How the log was written (``reference`` or ``hear-ros``; empty before writing).
    mrftcli_version : str
    """

    axis: str
    inner_loop: str
    commanded: str
    K: float
    Td: float
    tau: float
    g: float
    inner: LoopModel
    gains: InnerGains
    outer_hold: InnerGains
    attitude_noise_std: float
    position_noise_std: float
    switching: str
    seed: int
    start_time: float
    duration: float
    tests: tuple[CascadeTestTruth, ...]
    layout: str = ""
    log_format: str = ""
    log_file: str = ""
    mrftcli_version: str = ""

    def tests_of(self, loop: str) -> tuple[CascadeTestTruth, ...]:
        """The tests of one loop (``roll``, ``y``, ...)."""
        return tuple(t for t in self.tests if t.loop == loop)

    def to_json(self) -> dict[str, Any]:
        """Plain JSON values, with ``schema_version``.

        The top level describes the inner loop as every simulator sidecar describes its eq. (2) loop
        (``loop``, ``Tp``, ``Td``, ``tau``, ``K``, ``rate_hz``, ``noise_std``, ``tests``), so the tools
        that read a sample log's sidecar treat the flight as the inner loop's log; ``outer`` holds the
        outer loop (its truth and tests) and ``inner_gains`` the PD in tune's generic form, keyed by
        the inner loop as GAINS.json is.
        """
        unit = "rad" if self.commanded == "attitude" else "m/s^2"
        return {
            "format": "mrft-ident cascade simulation truth",
            "schema_version": CASCADE_TRUTH_SCHEMA,
            "loop": self.inner_loop,
            "Tp": self.inner.Tp, "Td": self.inner.Td, "tau": self.inner.tau, "K": self.inner.K,
            "rate_hz": self.gains.rate_hz,
            "noise_std": self.attitude_noise_std,
            "tests": [t.to_json() for t in self.tests_of(self.inner_loop)],
            "outer": {"loop": self.axis, "K": self.K, "Td": self.Td, "tau": self.tau, "g": self.g,
                      "commanded": self.commanded, "command_unit": unit, "noise_std": self.position_noise_std,
                      "tests": [t.to_json() for t in self.tests_of(self.axis)]},
            "inner_gains": {self.inner_loop: self.gains.to_json()},
            "outer_hold": self.outer_hold.to_json(),
            "switching": self.switching,
            "seed": self.seed,
            "start_time": self.start_time,
            "duration": self.duration,
            "layout": self.layout,
            "log_format": self.log_format,
            "log_file": self.log_file,
            "mrftcli_version": self.mrftcli_version,
            "units": {"time": "s", "position": "m", "attitude": "rad", "inner_command": "inner command units",
                      "outer_command": unit},
            "conventions": "FRD/NED: y'' = g roll - y'/Td, x'' = -g pitch - x'/Td; the outer command is in the "
                           "output's direction; the inner command reaches the plant tau (inner) later (zero-order "
                           "hold); the position is measured outer.tau late; tests in flight order, inner first",
        }

    @classmethod
    def from_json(cls, data: Any) -> CascadeTruth:
        """The record of a sidecar's JSON; InputError (one line) on a wrong version or a missing field."""
        d = check_schema_version(data, "cascade truth", CASCADE_TRUTH_SCHEMA,
                                 fix="simulate the flight again with this version of mrft-ident")
        what = "cascade truth"
        try:
            outer = d["outer"]
            inner_loop = str(d["loop"])
            tests = tuple(CascadeTestTruth.from_json(t) for t in [*d["tests"], *outer["tests"]])
            return cls(
                axis=str(outer["loop"]), inner_loop=inner_loop, commanded=str(outer["commanded"]),
                K=_number(outer, "K", what), Td=_number(outer, "Td", what), tau=_number(outer, "tau", what),
                g=_number(outer, "g", what),
                inner=LoopModel(_number(d, "Tp", what), _number(d, "Td", what), _number(d, "tau", what),
                                _number(d, "K", what)),
                gains=InnerGains.from_json(d["inner_gains"][inner_loop], f"{what} inner_gains"),
                outer_hold=InnerGains.from_json(d["outer_hold"], f"{what} outer_hold"),
                attitude_noise_std=_number(d, "noise_std", what), position_noise_std=_number(outer, "noise_std", what),
                switching=str(d["switching"]), seed=int(d["seed"]), start_time=_number(d, "start_time", what),
                duration=_number(d, "duration", what), tests=tests, layout=str(d.get("layout", "")),
                log_format=str(d.get("log_format", "")), log_file=str(d.get("log_file", "")),
                mrftcli_version=str(d.get("mrftcli_version", "")),
            )
        except (KeyError, TypeError) as err:
            raise InputError(f"cascade truth: missing or malformed field {err}; simulate the flight again") from None
