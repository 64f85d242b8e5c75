"""Follow a flight log while it is written: MRFT tests and the identification as cycles arrive.

:func:`watch` (eq. (2)) and :func:`watch_model` (a process plant, ``--model NAME``) are generators of
typed update records (:class:`TestUpdate`, :class:`EstimateUpdate`; :class:`ProcessTestUpdate`,
:class:`ProcessEstimateUpdate`; :class:`Restart`, :class:`WatchEnd`); ``mrft-ident watch`` prints
them. Neither prints itself.

How the log is followed
-----------------------
:func:`mrftcli.io.follow.follow_log` gives the flight so far at each poll: an MCAP file (or a ROS 2
bag directory with mcap storage) is parsed incrementally and says when its writer closed it; any
other log is read again whenever its size changes. The writer has closed the file when it has not
grown for ``idle`` seconds (this also ends an MCAP whose writer died without a footer). A file that
does not exist yet is waited for (a ground station starts ``watch`` before the logger); one that is
truncated or replaced by another recording is followed from its start again (:class:`Restart`).

Incremental segmentation and identification
-------------------------------------------
Tests are found with :func:`mrftcli.segment.segment_arrays` on a window that starts after the last
*closed* test (one followed by ``max(1 s, 3 periods)`` of command without relay switching; for a
process plant 3 periods, whatever its time scale), so the cost of a poll does not grow with the flight. A test is reported (:class:`TestUpdate`) once it
has ``min_cycles`` stable cycles that follow the relay (``MrftTest.valid``), and again at every new
stable cycle. As soon as two betas are in, every update of a test is followed by the identification
(:class:`EstimateUpdate`): the paper's point estimate from the tests' mean effective betas,
frequencies and amplitudes (:func:`mrftcli.mrft.identify.identify`, about a millisecond). When the
writer closes the file, the whole log goes through :func:`mrftcli.analyze.analyze_flight` (the
weighted estimate with bootstrap uncertainty, exactly what ``mrft-ident analyze`` prints) and the last
update has ``final=True``.

A process plant (:func:`watch_model`, ``watch --model NAME``)
--------------------------------------------------------------
The same tracker finds the tests; each is screened as ``analyze --model`` screens it (stable cycles,
an output that follows its relay, a chattering relay's cycles found again), its relay inferred or
taken as stated (:func:`mrftcli.segment.relay_type.infer_relay`) and its cycles' frequency-response
points measured (:func:`mrftcli.analyze.general.response_points`) once per new stable cycle. Every
new cycle is followed by the fit of the model to all tests' points
(:func:`mrftcli.analyze.general.identify_points`): a :class:`ProcessEstimateUpdate` that names the
parameters the tests so far do not determine, and the test that would, instead of a number. When the
writer closes the file the whole log goes through :func:`mrftcli.analyze.general.analyze_general`,
exactly what ``mrft-ident analyze --model NAME`` prints (with each test's held-out prediction).

Every update carries ``t_cycle_end``, the log time of the newest cycle end it includes, and
``wall_time``, when it was produced (``time.time()``), so that a benchmark can measure the latency
from a cycle's end reaching the file to the updated estimate (benchmarks/bench_watch.py).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Generator, Iterator, Mapping
from dataclasses import asdict, dataclass, field, replace
from numbers import Integral
from pathlib import Path
from typing import Any, ClassVar, Protocol

import numpy as np

from .analyze.general import (GeneralAnalysis, RelayOptions, analyze_general, chattering_cycles, identify_points,
                              response_points, screen_test)
from .errors import InputError, InsufficientDataError, LogReadError, MrftError
from .io import FlightLog, ReadOptions, Signal
from .io.follow import follow_log
from .jsonable import check_schema_version
from .mrft.consensus import SAME_BETA
from .mrft.identify_lti import LtiEstimate, ResponsePoint
from .mrft.model import PlantModel
from .mrft.relays import RelayLaw
from .segment import MrftTest, segment_arrays
from .segment.relay_type import infer_relay
from .validate import check_positive

__all__ = ["WatchOptions", "TestUpdate", "EstimateUpdate", "WatchEnd", "Restart", "ProcessTestUpdate",
           "ProcessEstimateUpdate", "Update", "watch", "watch_model", "WATCH_PROCESS_SCHEMA_VERSION"]

#: version of :meth:`ProcessTestUpdate.to_json` and :meth:`ProcessEstimateUpdate.to_json` (``watch --model --jsonl``)
WATCH_PROCESS_SCHEMA_VERSION = 1


@dataclass(frozen=True)
class WatchOptions:
    """How a log is followed (:func:`watch`), checked on creation.

    Attributes
    ----------
    min_cycles : int
        Stable cycles a test needs before it is reported and used (also the final analysis's
        ``min_stable_cycles``).
    idle : float
        Seconds without growth after which the writer is taken to have closed the file [s].
    poll : float
        Seconds between polls of the file [s].
    wait : float, optional
        Longest wait for the file to appear [s]; None waits until the generator is closed (Ctrl-C).

    Raises
    ------
    InputError
        ``min_cycles`` below 1; ``idle``, ``poll`` or ``wait`` not a positive number.

    Examples
    --------
    >>> WatchOptions(idle=5.0).poll
    0.02
    """

    min_cycles: int = 3
    idle: float = 10.0
    poll: float = 0.02
    wait: float | None = None

    def __post_init__(self) -> None:
        if isinstance(self.min_cycles, bool) or not isinstance(self.min_cycles, Integral) or self.min_cycles < 1:
            raise InputError(f"min_cycles must be a whole number of at least 1, got {self.min_cycles!r}")
        object.__setattr__(self, "idle", check_positive("idle", self.idle))
        object.__setattr__(self, "poll", check_positive("poll", self.poll))
        if self.wait is not None:
            object.__setattr__(self, "wait", check_positive("wait", self.wait))


# --------------------------------------------------------------------------------------------------
# update records
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TestUpdate:
    """A test with enough stable cycles, reported when it first qualifies and at every new cycle.

    Attributes
    ----------
    number : int
        Test number in the log, 1-based.
    t_start, t_cycle_end : float
        The relay's first command sample and the end of the newest stable cycle [s, log time].
    t_log_start : float
        The log's first command sample [s, log time]: a terminal shows test times from it, as analyze does.
    beta_nominal : float or None
        Beta from the beta topic.
    beta_effective : float
        Mean switching level the relay achieved over the stable cycles.
    frequency_hz, amplitude : float
        Limit-cycle frequency [Hz] and output amplitude [output units] (means over stable cycles).
    h : float
        Relay half-height [command units].
    stable_cycles, cycles : int
        Stable and all complete cycles so far.
    wall_time : float
        When the update was produced (``time.time()``) [s].
    """

    __test__: ClassVar[bool] = False
    kind: ClassVar[str] = "test"
    number: int
    t_start: float
    t_cycle_end: float
    beta_nominal: float | None
    beta_effective: float
    frequency_hz: float
    amplitude: float
    h: float
    stable_cycles: int
    cycles: int
    wall_time: float
    t_log_start: float

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **asdict(self)}


@dataclass(frozen=True)
class EstimateUpdate:
    """The identification from the tests so far (two betas or more).

    Attributes
    ----------
    Td, tau : float
        Drag time constant and delay [s].
    K : float
        Gain [output units / (command unit s^2)] (NaN without amplitudes).
    tests : tuple of int
        Numbers of the tests used.
    betas : tuple of float
        Their effective betas.
    t_cycle_end : float
        Newest cycle end included [s, log time].
    final : bool
        True for the last update: the whole log through :func:`mrftcli.analyze.analyze_flight`.
    std : dict
        ``{"Td", "tau", "K"}`` -> bootstrap standard deviation (final update only; else empty).
    warnings : tuple of str
        The identification's warnings.
    wall_time : float
        When the update was produced (``time.time()``) [s].
    """

    kind: ClassVar[str] = "estimate"
    Td: float
    tau: float
    K: float
    tests: tuple[int, ...]
    betas: tuple[float, ...]
    t_cycle_end: float
    final: bool
    wall_time: float
    std: dict[str, float] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **asdict(self)}


@dataclass(frozen=True)
class WatchEnd:
    """The watch stopped: ``reason`` is ``closed`` (MCAP footer), ``idle`` (no growth) or an error.

    ``error`` holds the final analysis's one-line message and ``exit_code`` its code (0 when fine).
    """

    kind: ClassVar[str] = "end"
    reason: str
    tests: int
    wall_time: float
    error: str | None = None
    exit_code: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **asdict(self)}


@dataclass(frozen=True)
class Restart:
    """The followed file was truncated or replaced (a new recording): everything reported before
    belongs to the old one, and the tests are numbered from 1 again.

    Attributes
    ----------
    reason : str
        What was seen (the file shrank, or another file took its name).
    wall_time : float
        When it was noticed (``time.time()``) [s].
    """

    kind: ClassVar[str] = "restart"
    reason: str
    wall_time: float

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **asdict(self)}


def _floats(data: Mapping[str, Any], *names: str) -> list[float]:
    return [float(data[n]) for n in names]


@dataclass(frozen=True)
class ProcessTestUpdate:
    """A relay test of a process plant (:func:`watch_model`), reported as :class:`TestUpdate` is.

    Attributes
    ----------
    number : int
        Test number in the log, 1-based.
    t_start, t_cycle_end, t_log_start : float
        The relay's first command sample, the end of the newest stable cycle and the log's first command
        sample [s, log time].
    relay : RelayLaw
        The relay, inferred from the data or as stated (``relay.source``): kind, levels, bias, beta or eps.
    beta_effective : float
        The switching level measured, over the amplitude [-].
    frequency_hz, amplitude : float
        Limit-cycle frequency [Hz] and output amplitude [output units] (means over the stable cycles).
    stable_cycles, cycles : int
        Stable and all complete cycles so far.
    wall_time : float
        When the update was produced (``time.time()``) [s].
    notes : tuple of str
        How the test is used when not plainly (a noisy output, a chattering relay).
    """

    __test__: ClassVar[bool] = False
    kind: ClassVar[str] = "test"
    number: int
    t_start: float
    t_cycle_end: float
    t_log_start: float
    relay: RelayLaw
    beta_effective: float
    frequency_hz: float
    amplitude: float
    stable_cycles: int
    cycles: int
    wall_time: float
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """One ``--jsonl`` line: ``kind``, ``schema_version``, the figures and ``relay`` (its JSON)."""
        return {"kind": self.kind, "schema_version": WATCH_PROCESS_SCHEMA_VERSION, "number": self.number,
                "t_start": self.t_start, "t_cycle_end": self.t_cycle_end, "t_log_start": self.t_log_start,
                "relay": self.relay.to_json(), "beta_effective": self.beta_effective,
                "frequency_hz": self.frequency_hz, "amplitude": self.amplitude, "stable_cycles": self.stable_cycles,
                "cycles": self.cycles, "wall_time": self.wall_time, "notes": list(self.notes)}

    to_dict = to_json

    @classmethod
    def from_json(cls, data: Any) -> ProcessTestUpdate:
        """The record of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input."""
        d = check_schema_version(data, "watch test update", WATCH_PROCESS_SCHEMA_VERSION)
        try:
            t_start, t_end, t_log, beta, f, a, wall = _floats(d, "t_start", "t_cycle_end", "t_log_start",
                                                              "beta_effective", "frequency_hz", "amplitude",
                                                              "wall_time")
            return cls(int(d["number"]), t_start, t_end, t_log, RelayLaw.from_json(d["relay"]), beta, f, a,
                       int(d["stable_cycles"]), int(d["cycles"]), wall, tuple(str(n) for n in d.get("notes", [])))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"watch test update: bad or missing field ({err})") from None


@dataclass(frozen=True)
class ProcessEstimateUpdate:
    """The process model identified from the tests so far (:func:`watch_model`).

    Attributes
    ----------
    family : str
        The model's family (``fopdt``, ... or ``declared``).
    estimates : tuple of LtiEstimate
        Every parameter of the family, with its unit, std and 95 % interval (known ones flagged).
    tests : tuple of int
        Numbers of the tests used.
    t_cycle_end : float
        Newest cycle end included [s, log time].
    final : bool
        True for the last update: the whole log through :func:`mrftcli.analyze.general.analyze_general`.
    wall_time : float
        When the update was produced (``time.time()``) [s].
    undetermined : tuple of str
        The parameters the tests so far do not pin down (their values are one of many that fit).
    advice : str
        What would determine them (empty when all are).
    analysis : GeneralAnalysis or None
        The final update's analysis, exactly ``analyze --model --json``'s record (held-out predictions,
        notes); None before.
    """

    kind: ClassVar[str] = "estimate"
    family: str
    estimates: tuple[LtiEstimate, ...]
    tests: tuple[int, ...]
    t_cycle_end: float
    final: bool
    wall_time: float
    undetermined: tuple[str, ...] = ()
    advice: str = ""
    analysis: GeneralAnalysis | None = None

    def to_json(self) -> dict[str, Any]:
        """One ``--jsonl`` line: ``parameters`` keyed by name as in ``analyze --model --json``."""
        return {"kind": self.kind, "schema_version": WATCH_PROCESS_SCHEMA_VERSION, "model": self.family,
                "parameters": {e.name: e.to_json() for e in self.estimates}, "tests": list(self.tests),
                "t_cycle_end": self.t_cycle_end, "final": self.final, "wall_time": self.wall_time,
                "undetermined": list(self.undetermined), "advice": self.advice,
                "analysis": None if self.analysis is None else self.analysis.to_json()}

    to_dict = to_json

    @classmethod
    def from_json(cls, data: Any) -> ProcessEstimateUpdate:
        """The record of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input."""
        d = check_schema_version(data, "watch estimate update", WATCH_PROCESS_SCHEMA_VERSION)
        try:
            params = d["parameters"]
            if not isinstance(params, Mapping):
                raise TypeError("'parameters' is not an object")
            analysis = d.get("analysis")
            return cls(str(d["model"]), tuple(LtiEstimate.from_json(n, v) for n, v in params.items()),
                       tuple(int(i) for i in d["tests"]), float(d["t_cycle_end"]), bool(d["final"]),
                       float(d["wall_time"]), tuple(str(n) for n in d.get("undetermined", [])),
                       str(d.get("advice", "")), None if analysis is None else GeneralAnalysis.from_json(analysis))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"watch estimate update: bad or missing field ({err})") from None


Update = TestUpdate | EstimateUpdate | WatchEnd | Restart | ProcessTestUpdate | ProcessEstimateUpdate


# --------------------------------------------------------------------------------------------------
# the watch loop
# --------------------------------------------------------------------------------------------------


def _window(sig: Signal | None, t_from: float) -> Signal | None:
    """The samples of ``sig`` from ``t_from`` [s] on; None when there are none."""
    if sig is None or len(sig) == 0:
        return None
    i = int(np.searchsorted(sig.t, t_from, side="left"))
    return Signal(sig.t[i:], sig.values[i:]) if i < len(sig) else None


class _Tracker:
    """Tests so far: closed ones frozen, the open window segmented again at each poll.

    A test closes once ``max(quiet_s, 3 periods)`` of command without relay switching follow it [s].
    """

    def __init__(self, quiet_s: float) -> None:
        self.quiet_s = quiet_s
        self.closed: list[MrftTest] = []
        self.t_from = -math.inf
        self.beta_from = -math.inf

    def update(self, flight: FlightLog) -> list[MrftTest]:
        cmd = _window(flight.command, self.t_from)
        out = _window(flight.output, self.t_from)
        if cmd is None or out is None or len(cmd) < 10 or len(out) < 10:
            return list(self.closed)
        beta = _window(flight.beta, self.beta_from)
        sp = _window(flight.setpoint, self.t_from)
        found = segment_arrays(cmd, out, beta=beta, setpoint=sp)
        t_last = float(cmd.t[-1])
        open_tests: list[MrftTest] = []
        for test in found:
            test = replace(test, index=len(self.closed) + len(open_tests))
            period = test.period_median if math.isfinite(test.period_median) else 1.0
            if not open_tests and t_last - test.t_end > max(self.quiet_s, 3.0 * period):
                self.closed.append(test)
                self.t_from = test.t_end + 1e-9
                self.beta_from = test.t_end + 1e-9
            else:
                open_tests.append(test)
        return self.closed + open_tests


def _usable(test: MrftTest, min_cycles: int) -> bool:
    return test.n_stable >= min_cycles and test.valid and math.isfinite(test.beta_effective)


def _newest_end(test: MrftTest) -> float:
    st = test.stable
    return float(st[-1].t_end) if st else float(test.t_start)


def _estimate(tests: list[MrftTest], Tp: float, min_cycles: int) -> EstimateUpdate | None:
    """The paper's point estimate from the usable tests, when they span two betas or more."""
    from .mrft.identify import TestMeasurement, identify

    use = [t for t in tests if _usable(t, min_cycles)]
    betas = sorted(t.beta_effective for t in use)
    if len(use) < 2 or betas[-1] - betas[0] < SAME_BETA:
        return None
    meas = [TestMeasurement(beta=t.beta_effective, frequency_hz=t.frequency_hz_mean, amplitude=t.amplitude_mean,
                            h=t.h) for t in use]
    try:
        res = identify(meas, Tp, rate_hz=None)
    except MrftError:
        return None
    K = res.K.mean if res.K is not None else float("nan")
    return EstimateUpdate(Td=float(res.model.Td), tau=float(res.model.tau), K=float(K),
                          tests=tuple(t.index + 1 for t in use), betas=tuple(float(t.beta_effective) for t in use),
                          t_cycle_end=max(_newest_end(t) for t in use), final=False, wall_time=time.time(),
                          warnings=tuple(res.warnings))


def _final(flight: FlightLog | None, Tp: float, min_cycles: int, reason: str, n_tests: int
           ) -> Iterator[Update]:
    from .analyze import AnalyzeOptions, analyze_flight

    if flight is None:
        yield WatchEnd(reason=reason, tests=0, wall_time=time.time(), error="no data in the log",
                       exit_code=LogReadError.exit_code)
        return
    try:
        res = analyze_flight(flight, Tp, options=AnalyzeOptions(min_stable_cycles=min_cycles))
    except (MrftError, InsufficientDataError) as err:
        yield WatchEnd(reason=reason, tests=n_tests, wall_time=time.time(), error=str(err), exit_code=err.exit_code)
        return
    yield EstimateUpdate(
        Td=res.Td.mean, tau=res.tau.mean, K=res.K.mean, tests=tuple(t.index + 1 for t in res.tests),
        betas=tuple(float(t.beta_effective) for t in res.tests),
        t_cycle_end=max(_newest_end(t) for t in res.tests), final=True, wall_time=time.time(),
        std={"Td": res.Td.std, "tau": res.tau.std, "K": res.K.std}, warnings=tuple(res.warnings))
    yield WatchEnd(reason=reason, tests=len(res.tests), wall_time=time.time())


# --------------------------------------------------------------------------------------------------
# what the loop asks of a model: which tests it uses, how it reports them, the estimate
# --------------------------------------------------------------------------------------------------


class _Identifier(Protocol):
    #: the shortest quiet spell after a test that closes it [s] (:class:`_Tracker`)
    quiet_s: float

    def usable(self, test: MrftTest, flight: FlightLog) -> MrftTest | None:
        """The test as the model uses it, or None (not usable yet)."""

    def test_update(self, test: MrftTest, flight: FlightLog) -> Update:
        """The update reporting a usable test."""

    def estimate(self, tests: list[MrftTest]) -> Update | None:
        """The estimate from the usable tests, or None when they give none yet."""

    def final(self, flight: FlightLog | None, reason: str, n_tests: int) -> Iterator[Update]:
        """The whole log's analysis, then :class:`WatchEnd`."""


class _PaperIdentifier:
    """eq. (2) with Tp known: the paper's point estimate per update, :func:`analyze_flight` at the end."""

    quiet_s = 1.0  # a multirotor's loops cycle at about 0.3-3 Hz: a second without switching ends a test

    def __init__(self, Tp: float, min_cycles: int) -> None:
        self.Tp, self.min_cycles = Tp, min_cycles

    def usable(self, test: MrftTest, flight: FlightLog) -> MrftTest | None:
        return test if _usable(test, self.min_cycles) else None

    def test_update(self, test: MrftTest, flight: FlightLog) -> Update:
        return TestUpdate(number=test.index + 1, t_start=test.t_start, t_cycle_end=_newest_end(test),
                          beta_nominal=test.beta_nominal, beta_effective=test.beta_effective,
                          frequency_hz=test.frequency_hz_mean, amplitude=test.amplitude_mean, h=test.h,
                          stable_cycles=test.n_stable, cycles=len(test.cycles), wall_time=time.time(),
                          t_log_start=float(flight.command.t[0]))

    def estimate(self, tests: list[MrftTest]) -> Update | None:
        return _estimate(tests, self.Tp, self.min_cycles)

    def final(self, flight: FlightLog | None, reason: str, n_tests: int) -> Iterator[Update]:
        return _final(flight, self.Tp, self.min_cycles, reason, n_tests)


@dataclass(frozen=True)
class _Measured:
    """One usable test of a process plant: as used, its relay and its frequency-response points."""

    test: MrftTest
    relay: RelayLaw
    points: tuple[ResponsePoint, ...]
    notes: tuple[str, ...]


def _measure(test: MrftTest, flight: FlightLog, relay: RelayOptions, min_cycles: int) -> _Measured | None:
    """The test screened, its relay and points as ``analyze --model`` takes them; None: not usable (yet)."""
    chattered = chattering_cycles(test, min_cycles)
    used = chattered or test
    reason, notes = screen_test(used, min_cycles)  # the rule analyze --model screens with
    if reason:
        return None
    points = response_points(flight, used)
    if not any(p.harmonic == 1 for p in points):  # no cycle long enough for its fundamental
        return None
    if chattered is not None:
        notes += ("the relay chatters at its switches: its cycles are used with the logged command's harmonics",)
    law = infer_relay(used, relay.kind, relay.beta, relay.eps)
    if abs(law.bias) > 1e-9 * law.h:  # analyze --model states the same assumption in its first lines
        notes += ("assumed: the relay's bias is balanced by the loop's operating point",)
    return _Measured(used, law, points, notes)


class _ProcessIdentifier:
    """A process plant: each test measured once per new stable cycle, the model fitted to all points."""

    # a process plant's time scale is its own (a tokamak cycles in 25 ms, a furnace in minutes): three
    # periods without switching end a test (at 10 kHz, a fixed second kept the previous test in every
    # poll's segmentation, twice the work)
    quiet_s = 0.0

    def __init__(self, model: PlantModel, relay: RelayOptions, min_cycles: int) -> None:
        self.model, self.relay, self.min_cycles = model, relay, min_cycles
        # per test (by its start): the stable cycles it was last measured with, and the measurement; one
        # entry per test, so a test of thousands of cycles holds one copy of them, not one per cycle
        self._seen: dict[float, tuple[tuple[int, float], _Measured | None]] = {}
        self._by_index: dict[int, _Measured] = {}

    def usable(self, test: MrftTest, flight: FlightLog) -> MrftTest | None:
        stable = (test.n_stable, _newest_end(test))
        seen = self._seen.get(test.t_start)
        if seen is None or seen[0] != stable:  # the open test is measured again only when a cycle is added
            seen = self._seen[test.t_start] = (stable, _measure(test, flight, self.relay, self.min_cycles))
        measured = seen[1]
        if measured is None:
            return None
        used = replace(measured.test, index=test.index)
        self._by_index[test.index] = replace(measured, test=used)
        return used

    def test_update(self, test: MrftTest, flight: FlightLog) -> Update:
        m = self._by_index[test.index]
        return ProcessTestUpdate(number=test.index + 1, t_start=test.t_start, t_cycle_end=_newest_end(test),
                                 t_log_start=float(flight.command.t[0]), relay=m.relay,
                                 beta_effective=float(test.beta_effective), frequency_hz=float(test.frequency_hz_mean),
                                 amplitude=float(test.amplitude_mean), stable_cycles=test.n_stable,
                                 cycles=len(test.cycles), wall_time=time.time(), notes=m.notes)

    def estimate(self, tests: list[MrftTest]) -> Update | None:
        points = [p for t in tests for p in self._by_index[t.index].points]
        try:
            fit = identify_points(self.model, points)
        except MrftError:
            return None
        return ProcessEstimateUpdate(fit.model.family, fit.estimates, tuple(t.index + 1 for t in tests),
                                     max(_newest_end(t) for t in tests), False, time.time(), fit.undetermined,
                                     fit.advice)

    def final(self, flight: FlightLog | None, reason: str, n_tests: int) -> Iterator[Update]:
        if flight is None:
            yield WatchEnd(reason=reason, tests=0, wall_time=time.time(), error="no data in the log",
                           exit_code=LogReadError.exit_code)
            return
        try:
            res = analyze_general(flight, self.model, relay=self.relay, min_stable_cycles=self.min_cycles)
        except MrftError as err:
            yield WatchEnd(reason=reason, tests=n_tests, wall_time=time.time(), error=str(err),
                           exit_code=err.exit_code)
            return
        fit = res.identification
        assert fit is not None  # analyze_general raises when no test is usable
        yield ProcessEstimateUpdate(fit.model.family, fit.estimates, tuple(t.index + 1 for t in res.tests),
                                    max(t.t_end for t in res.tests), True, time.time(), fit.undetermined,
                                    fit.advice, analysis=res)
        yield WatchEnd(reason=reason, tests=len(res.tests), wall_time=time.time())


# --------------------------------------------------------------------------------------------------
# the follow loop
# --------------------------------------------------------------------------------------------------


def _updates(tests: list[MrftTest], flight: FlightLog, ident: _Identifier,
             reported: dict[int, int]) -> Iterator[Update]:
    """Each usable test with a new stable cycle, then the estimate when any was new."""
    used = [u for u in (ident.usable(t, flight) for t in tests) if u is not None]
    changed = False
    for test in used:
        if reported.get(test.index) != test.n_stable:
            reported[test.index] = test.n_stable
            changed = True
            yield ident.test_update(test, flight)
    if changed:
        est = ident.estimate(used)
        if est is not None:
            yield est


def _follow(path: Path, make: Callable[[], _Identifier], read: ReadOptions, options: WatchOptions,
            sleep: Callable[[float], None], clock: Callable[[], float]) -> Generator[Update, None, None]:
    """The loop of :func:`watch` and :func:`watch_model` (``make`` builds the model's identifier afresh
    at the start and at every restart)."""
    _wait_for(path, options.wait, options.poll, sleep, clock)
    follower = follow_log(path, read)
    ident = make()
    tracker = _Tracker(ident.quiet_s)
    reported: dict[int, int] = {}  # test index -> stable cycles last reported
    flight = None
    last_growth = clock()
    while True:
        snap = follower.poll()
        now = clock()
        if snap.restarted is not None:
            ident, reported, flight = make(), {}, None
            tracker = _Tracker(ident.quiet_s)
            yield Restart(reason=snap.restarted, wall_time=time.time())
        if snap.grew:
            last_growth = now
        if snap.flight is not None:
            flight = snap.flight
            yield from _updates(tracker.update(flight), flight, ident, reported)
        if snap.closed or now - last_growth > options.idle:
            reason = "closed" if snap.closed else "idle"
            if flight is None and read.fmt is None:  # nothing read: say whether it is a log at all
                not_a_log = _not_a_log(path)
                if not_a_log is not None:
                    yield WatchEnd(reason=reason, tests=0, wall_time=time.time(), error=not_a_log,
                                   exit_code=LogReadError.exit_code)
                    return
            yield from ident.final(flight, reason, len(reported))
            return
        sleep(options.poll)


def watch(path: str | Path, Tp: float, *, read: ReadOptions | None = None, options: WatchOptions | None = None,
          sleep: Callable[[float], None] = time.sleep,
          clock: Callable[[], float] = time.monotonic) -> Generator[Update, None, None]:
    """Follow ``path`` while it is written and yield updates of eq. (2) (see the module docstring).

    Parameters
    ----------
    path : str or Path
        An MCAP file, a ROS 2 bag directory with mcap storage, or any log :func:`mrftcli.io.read_flight`
        reads (CSV, ULog, ...). It may not exist yet: it is waited for (a ground station starts
        ``watch`` before the logger), until the generator is closed or for ``options.wait`` seconds.
    Tp : float
        Known propulsion time constant [s].
    read : ReadOptions, optional
        The loop and the log layout, as for :func:`mrftcli.io.read_flight` (``fmt`` None: detected; a
        missing file or a ``.mcap`` name is followed as MCAP); None: ``ReadOptions()``.
    options : WatchOptions, optional
        Stable cycles per test, idle time, poll interval and the longest wait for the file; None:
        ``WatchOptions()``.
    sleep, clock
        Injected for tests (default :func:`time.sleep`, :func:`time.monotonic`).

    Yields
    ------
    TestUpdate, EstimateUpdate, Restart or WatchEnd
        The last one is a :class:`WatchEnd`; stop early by closing the generator (Ctrl-C in the CLI).
        A :class:`Restart` when the file is truncated or replaced (a new recording): the tests so far
        are forgotten.

    Raises
    ------
    LogReadError
        The file did not appear within ``wait`` seconds, is not a log, or lacks a required topic once
        closed.
    """
    Tp = check_positive("Tp", Tp)
    wopts = WatchOptions() if options is None else options
    return _follow(Path(path), lambda: _PaperIdentifier(Tp, wopts.min_cycles), ReadOptions() if read is None else read,
                   wopts, sleep, clock)


def watch_model(path: str | Path, model: PlantModel, *, relay: RelayOptions | None = None,
                read: ReadOptions | None = None, options: WatchOptions | None = None,
                sleep: Callable[[float], None] = time.sleep,
                clock: Callable[[], float] = time.monotonic) -> Generator[Update, None, None]:
    """Follow ``path`` while it is written and yield updates of a process plant's identification.

    The live counterpart of :func:`mrftcli.analyze.general.analyze_general` (``watch --model NAME``;
    module docstring): each usable test as a :class:`ProcessTestUpdate` (its relay inferred or as
    stated), after each new cycle a :class:`ProcessEstimateUpdate` (naming the parameters the tests so
    far do not determine), and when the writer closes the file the whole log's analysis (``final``).

    Parameters
    ----------
    path : str or Path
        The log, as for :func:`watch`.
    model : PlantModel
        The structure with its known parameters (set E) and ranges (set I), e.g.
        ``mrftcli.mrft.families.family_model("fopdt")``.
    relay : RelayOptions, optional
        What is stated about the relay (the rest is inferred per test); None: all inferred.
    read, options, sleep, clock
        As for :func:`watch`.

    Yields
    ------
    ProcessTestUpdate, ProcessEstimateUpdate, Restart or WatchEnd
        The last one is a :class:`WatchEnd` (its ``error`` the final analysis's one-line message).

    Raises
    ------
    LogReadError
        As for :func:`watch`.

    Examples
    --------
    >>> from mrftcli.mrft.families import family_model
    >>> updates = watch_model("plant.csv", family_model("fopdt"),
    ...                       read=ReadOptions(command_topic="u_relay", output_topic="y_output"))
    """
    rel = RelayOptions() if relay is None else relay
    wopts = WatchOptions() if options is None else options
    return _follow(Path(path), lambda: _ProcessIdentifier(model, rel, wopts.min_cycles),
                   ReadOptions() if read is None else read, wopts, sleep, clock)


def _not_a_log(path: Path) -> str | None:
    """Why ``path`` is not a log of any format read (a PNG, a text file...), or None when it may be one."""
    from .io import detect_format

    try:
        detect_format(path)
    except LogReadError as err:
        return f"not a log: {err}"
    return None


def _wait_for(path: Path, wait: float | None, poll: float, sleep: Callable[[float], None],
              clock: Callable[[], float]) -> None:
    """Return once ``path`` exists and is not empty; LogReadError after ``wait`` seconds (None: never)."""
    start = clock()
    while not path.exists() or (path.is_file() and path.stat().st_size == 0):
        if wait is not None and clock() - start > wait:
            raise LogReadError(f"{path}: no such file after waiting {wait:g} s (--wait); start the recording, "
                               "or wait longer")
        sleep(poll)
