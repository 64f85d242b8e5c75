"""Follow a flight log while it is written: relay tests and the identification as cycles arrive.

:func:`watch` is a generator of typed update records (:class:`TestUpdate`, :class:`EstimateUpdate`,
:class:`Restart`, :class:`WatchEnd`), the same records for every model family; ``mrft-ident watch``
prints them. It does not print itself.

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
*closed* test (one followed by ``max(quiet, 3 periods)`` of command without relay switching), so the
cost of a poll does not grow with the flight. A test is reported (:class:`TestUpdate`) once the
model's strategy accepts it and again at every new stable cycle; every new cycle is followed by the
identification from the tests so far (:class:`EstimateUpdate`, each parameter one
:class:`~mrftcli.mrft.parameter.ParameterEstimate`). When the writer closes the file, the whole log
goes through :func:`mrftcli.analyze.analyze_flight` with the same model (exactly what ``mrft-ident
analyze`` prints, each test's held-out prediction included) and the last estimate has ``final=True``.

The strategy is the model's family:

* eq. (2) (:class:`~mrftcli.mrft.model.LoopModel`, ``soiptd_model(Tp)``): a test with ``min_cycles``
  stable cycles that follow the relay (analyze's screening, :func:`mrftcli.analyze.screen.screen_tests`);
  once two betas are in, the paper's point estimate from the tests' mean effective betas, frequencies and amplitudes
  (:func:`mrftcli.mrft.identify.identify` at the model's Tp, about a millisecond; no spread: its std
  is null until the final analysis). A second without switching closes a test.
* every other family (process plants, a declared transfer function): each test screened, its relay
  inferred or taken as stated in ``options.relay`` and its cycles' frequency-response points measured
  as ``analyze --model`` does (:func:`mrftcli.analyze.general.measure_test`: stable cycles, an output
  that follows its relay, a chattering relay's cycles found again) once per new stable cycle, then
  the model fitted to all tests' points (:func:`mrftcli.analyze.general.identify_points`): the
  estimate names the parameters the tests so far do not determine, and the test that would. Three
  periods without switching close a test, whatever the plant's time scale.

Every update carries ``t_cycle_end``, the log time of the newest cycle end it includes, and
``wall_time``, when it was produced (``time.time()``), so that a benchmark can measure the latency
from a cycle's end reaching the file to the updated estimate (benchmarks/bench_watch.py).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Generator, Iterator, Mapping
from dataclasses import asdict, dataclass, fields, replace
from numbers import Integral
from pathlib import Path
from typing import Any, ClassVar, Protocol

import numpy as np

from .analyze import AnalysisResult, AnalyzeOptions, RelayOptions, analyze_flight
from .analyze.general import MeasuredTest, identify_points, measure_test
from .analyze.screen import screen_tests
from .errors import InputError, LogReadError, MrftError
from .io import FlightLog, ReadOptions, Signal
from .io.follow import follow_log
from .jsonable import check_schema_version
from .mrft.consensus import SAME_BETA
from .mrft.identify import TestMeasurement, identify
from .mrft.model import LoopModel, PlantModel
from .mrft.parameter import ParameterEstimate
from .mrft.relays import RelayLaw
from .segment import MrftTest, segment_arrays
from .validate import check_positive

__all__ = ["WatchOptions", "TestUpdate", "EstimateUpdate", "WatchEnd", "Restart", "Update", "watch",
           "WATCH_SCHEMA_VERSION"]

#: version of every ``watch --jsonl`` line (:meth:`TestUpdate.to_json`, ...). 2: one record for every
#: family (each parameter :class:`~mrftcli.mrft.parameter.ParameterEstimate`'s JSON); 1 was ``watch
#: --model``'s lines (still read for one release: the process plant's test and estimate updates), eq.
#: (2)'s had none (not read back).
WATCH_SCHEMA_VERSION = 2


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
    relay : RelayOptions
        What is stated about a process plant's relay (the rest is inferred per test); eq. (2) reads
        its relay from the log and takes none.

    Raises
    ------
    InputError
        ``min_cycles`` below 1; ``idle``, ``poll`` or ``wait`` not a positive number; an unknown relay.

    Examples
    --------
    >>> WatchOptions(idle=5.0).poll
    0.02
    """

    min_cycles: int = 3
    idle: float = 10.0
    poll: float = 0.02
    wait: float | None = None
    relay: RelayOptions = RelayOptions()

    def __post_init__(self) -> None:
        if isinstance(self.min_cycles, bool) or not isinstance(self.min_cycles, Integral) or self.min_cycles < 1:
            raise InputError(f"min_cycles must be a whole number of at least 1, got {self.min_cycles!r}")
        object.__setattr__(self, "idle", check_positive("idle", self.idle))
        object.__setattr__(self, "poll", check_positive("poll", self.poll))
        if self.wait is not None:
            object.__setattr__(self, "wait", check_positive("wait", self.wait))
        self.analysis()  # the relay checked now, not when the recording ends

    def analysis(self) -> AnalyzeOptions:
        """The final analysis's options: ``analyze``'s defaults, these stable cycles and relay."""
        return AnalyzeOptions(min_stable_cycles=self.min_cycles, relay=self.relay)


# --------------------------------------------------------------------------------------------------
# update records: one ``--jsonl`` line each, the same for every family
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TestUpdate:
    """A usable test, reported when it first qualifies and again at every new stable cycle.

    Attributes
    ----------
    number : int
        Test number in the log, 1-based.
    t_start, t_cycle_end, t_log_start : float
        The relay's first command sample, the end of the newest stable cycle and the log's first command
        sample [s, log time] (a terminal shows test times from the log's start, as analyze does).
    beta_effective : float
        The switching level the relay achieved, over the amplitude [-] (mean over the stable cycles).
    frequency_hz, amplitude : float
        Limit-cycle frequency [Hz] and output amplitude [output units] (means over the stable cycles).
    h : float
        Relay half-height [command units].
    stable_cycles, cycles : int
        Stable and all complete cycles so far.
    wall_time : float
        When the update was produced (``time.time()``) [s].
    beta_nominal : float or None
        Eq. (2)'s MRFT beta from the beta topic (None without one, and for a process plant).
    relay : RelayLaw or None
        A process plant's relay, inferred from the data or as stated (``relay.source``); None for
        eq. (2), whose relay is the MRFT at ``beta_nominal`` with ``h``.
    notes : tuple of str
        How the test is used when not plainly (a noisy output, a chattering relay, an assumed bias).
    """

    __test__: ClassVar[bool] = False
    kind: ClassVar[str] = "test"
    number: int
    t_start: float
    t_cycle_end: float
    t_log_start: float
    beta_effective: float
    frequency_hz: float
    amplitude: float
    h: float
    stable_cycles: int
    cycles: int
    wall_time: float
    beta_nominal: float | None = None
    relay: RelayLaw | None = None
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """One ``--jsonl`` line: ``kind``, ``schema_version``, the figures, ``relay`` (its JSON or null)."""
        figures = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("relay", "notes")}
        return {"kind": self.kind, "schema_version": WATCH_SCHEMA_VERSION, **figures,
                "relay": None if self.relay is None else self.relay.to_json(), "notes": list(self.notes)}

    @classmethod
    def from_json(cls, data: Any) -> TestUpdate:
        """The record of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input.

        A version-1 line (``watch --model``'s, without ``h``) reads with ``h`` its relay's half swing.
        """
        d = check_schema_version(data, "watch test update", range(1, WATCH_SCHEMA_VERSION + 1))
        try:
            t_start, t_end, t_log, beta, f, a, wall = (float(d[n]) for n in (
                "t_start", "t_cycle_end", "t_log_start", "beta_effective", "frequency_hz", "amplitude", "wall_time"))
            nominal, relay = d.get("beta_nominal"), d.get("relay")
            law = None if relay is None else RelayLaw.from_json(relay)
            h = float(d["h"]) if "h" in d or law is None else (law.high - law.low) / 2
            return cls(int(d["number"]), t_start, t_end, t_log, beta, f, a, h, int(d["stable_cycles"]), int(d["cycles"]),
                       wall, None if nominal is None else float(nominal), law, tuple(str(n) for n in d.get("notes", [])))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"watch test update: bad or missing field ({err})") from None


@dataclass(frozen=True)
class EstimateUpdate:
    """The model identified from the tests so far, or from the whole log (``final``).

    Attributes
    ----------
    family : str
        The model's family (``soiptd`` for eq. (2), ``fopdt``, ... or ``declared``).
    parameters : tuple of ParameterEstimate
        Every parameter of the family in its order, each with its name, unit, std and 95 % interval
        (known ones given; std null before the final update where the estimate has no spread, eq. (2)'s).
    tests : tuple of int
        Numbers of the tests used.
    t_cycle_end : float
        Newest cycle end included [s, log time].
    final : bool
        True for the last update: the whole log through :func:`mrftcli.analyze.analyze_flight`.
    wall_time : float
        When the update was produced (``time.time()``) [s].
    undetermined : tuple of str
        The parameters the tests so far do not pin down (their values are one of many that fit).
    advice : str
        What would determine them (empty when all are).
    warnings : tuple of str
        The identification's warnings.
    analysis : AnalysisResult or None
        The final update's analysis, exactly ``analyze --json``'s record for the family (held-out
        predictions, notes); None before.
    """

    kind: ClassVar[str] = "estimate"
    family: str
    parameters: tuple[ParameterEstimate, ...]
    tests: tuple[int, ...]
    t_cycle_end: float
    final: bool
    wall_time: float
    undetermined: tuple[str, ...] = ()
    advice: str = ""
    warnings: tuple[str, ...] = ()
    analysis: AnalysisResult | None = None

    def to_json(self) -> dict[str, Any]:
        """One ``--jsonl`` line: ``parameters`` keyed by name, each the one parameter record."""
        return {"kind": self.kind, "schema_version": WATCH_SCHEMA_VERSION, "model": self.family,
                "parameters": {e.name: e.to_json() for e in self.parameters}, "tests": list(self.tests),
                "t_cycle_end": self.t_cycle_end, "final": self.final, "wall_time": self.wall_time,
                "undetermined": list(self.undetermined), "advice": self.advice, "warnings": list(self.warnings),
                "analysis": None if self.analysis is None else self.analysis.to_json()}

    @classmethod
    def from_json(cls, data: Any) -> EstimateUpdate:
        """The record of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input."""
        d = check_schema_version(data, "watch estimate update", range(1, WATCH_SCHEMA_VERSION + 1))
        try:
            params, family, analysis = d["parameters"], str(d["model"]), d.get("analysis")
            if not isinstance(params, Mapping):
                raise TypeError("'parameters' is not an object")
            eq2 = family == LoopModel.family  # eq. (2)'s open interval end reads as NaN, a family's as infinite
            reader = AnalysisResult.from_json
            return cls(family, tuple(ParameterEstimate.from_json(n, v, open_value=math.nan if eq2 else math.inf)
                                     for n, v in params.items()),
                       tuple(int(i) for i in d["tests"]), float(d["t_cycle_end"]), bool(d["final"]),
                       float(d["wall_time"]), tuple(str(n) for n in d.get("undetermined", [])),
                       str(d.get("advice", "")), tuple(str(w) for w in d.get("warnings", [])),
                       None if analysis is None else reader(analysis))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"watch estimate update: bad or missing field ({err})") from None


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

    def to_json(self) -> dict[str, Any]:
        """One ``--jsonl`` line: ``kind``, ``schema_version``, then the fields in their order."""
        return {"kind": self.kind, "schema_version": WATCH_SCHEMA_VERSION, **asdict(self)}


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

    to_json = WatchEnd.to_json


Update = TestUpdate | EstimateUpdate | WatchEnd | Restart


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


def _newest_end(test: MrftTest) -> float:
    st = test.stable
    return float(st[-1].t_end) if st else float(test.t_start)


# --------------------------------------------------------------------------------------------------
# the family's strategy: which tests it uses, how it reports them, the estimate so far, the final one
# --------------------------------------------------------------------------------------------------


class _Strategy(Protocol):
    #: the shortest quiet spell after a test that closes it [s] (:class:`_Tracker`)
    quiet_s: float

    def usable(self, test: MrftTest, flight: FlightLog) -> MrftTest | None:
        """The test as the model uses it, or None (not usable yet)."""

    def test_update(self, test: MrftTest, flight: FlightLog) -> TestUpdate:
        """The update reporting a usable test."""

    def estimate(self, tests: list[MrftTest]) -> EstimateUpdate | None:
        """The estimate from the usable tests, or None when they give none yet."""

    def final(self, res: Any) -> EstimateUpdate:
        """The final update of the whole log's analysis (:func:`mrftcli.analyze.analyze_flight`'s record)."""


def _test_update(test: MrftTest, flight: FlightLog, **extra: Any) -> TestUpdate:
    return TestUpdate(number=test.index + 1, t_start=float(test.t_start), t_cycle_end=_newest_end(test),
                      t_log_start=float(flight.command.t[0]), beta_effective=float(test.beta_effective),
                      frequency_hz=float(test.frequency_hz_mean), amplitude=float(test.amplitude_mean),
                      h=float(test.h), stable_cycles=test.n_stable, cycles=len(test.cycles), wall_time=time.time(),
                      **extra)


def _eq2_parameters(model: LoopModel, found: Mapping[str, ParameterEstimate | None], method: str,
                    spread: bool) -> tuple[ParameterEstimate, ...]:
    """eq. (2)'s parameters in the family's order and units: Tp given, Td, tau and K as found by ``method``
    (NaN: K without amplitudes); without ``spread`` (the live point estimate) std and interval NaN."""
    out = []
    for name, p in model.parameters.items():
        e = found.get(name)
        if p.known:
            out.append(ParameterEstimate.given(p.value, p.unit, name))
        elif e is None:
            out.append(ParameterEstimate(math.nan, math.nan, math.nan, math.nan, p.unit, False, method=method, name=name))
        elif spread:
            out.append(replace(e, value=float(e.value), unit=p.unit, method=e.method or method, name=name))
        else:
            out.append(ParameterEstimate(float(e.value), math.nan, math.nan, math.nan, p.unit, method=method, name=name))
    return tuple(out)


class _Eq2:
    """eq. (2) with Tp known: the paper's point estimate per update (module docstring)."""

    quiet_s = 1.0  # a multirotor's loops cycle at about 0.3-3 Hz: a second without switching ends a test

    def __init__(self, model: LoopModel, min_cycles: int) -> None:
        self.model, self.min_cycles = model, min_cycles

    def usable(self, test: MrftTest, flight: FlightLog) -> MrftTest | None:
        return None if screen_tests([test], self.min_cycles) else test  # analyze's screening of one test

    def test_update(self, test: MrftTest, flight: FlightLog) -> TestUpdate:
        return _test_update(test, flight, beta_nominal=test.beta_nominal)

    def estimate(self, tests: list[MrftTest]) -> EstimateUpdate | None:
        betas = sorted(t.beta_effective for t in tests)
        if len(tests) < 2 or betas[-1] - betas[0] < SAME_BETA:
            return None
        meas = [TestMeasurement(beta=t.beta_effective, frequency_hz=t.frequency_hz_mean, amplitude=t.amplitude_mean,
                                h=t.h) for t in tests]
        try:
            res = identify(meas, self.model, rate_hz=None)
        except MrftError:
            return None
        params = _eq2_parameters(self.model, {"Td": res.Td, "tau": res.tau, "K": res.K}, "mrft", spread=False)
        return EstimateUpdate(self.model.family, params, tuple(t.index + 1 for t in tests),
                              max(_newest_end(t) for t in tests), False, time.time(), warnings=tuple(res.warnings))

    def final(self, res: AnalysisResult) -> EstimateUpdate:
        params = _eq2_parameters(self.model, {"Td": res.Td, "tau": res.tau, "K": res.K}, res.method, spread=True)
        return EstimateUpdate(self.model.family, params, tuple(t.index + 1 for t in res.tests),
                              max(_newest_end(t) for t in res.tests), True, time.time(),
                              warnings=tuple(res.warnings), analysis=res)


class _Family:
    """Any other family: each test measured once per new stable cycle, the model fitted to all points."""

    # a process plant's time scale is its own (a tokamak cycles in 25 ms, a furnace in minutes): three
    # periods without switching end a test (at 10 kHz, a fixed second kept the previous test in every
    # poll's segmentation, twice the work)
    quiet_s = 0.0

    def __init__(self, model: PlantModel, relay: RelayOptions, min_cycles: int) -> None:
        self.model, self.relay, self.min_cycles = model, relay, min_cycles
        # per test (by its start): the stable cycles it was last measured with, and the measurement; one
        # entry per test, so a test of thousands of cycles holds one copy of them, not one per cycle
        self._seen: dict[float, tuple[tuple[int, float], MeasuredTest]] = {}
        self._by_index: dict[int, MeasuredTest] = {}

    def usable(self, test: MrftTest, flight: FlightLog) -> MrftTest | None:
        stable = (test.n_stable, _newest_end(test))
        seen = self._seen.get(test.t_start)
        if seen is None or seen[0] != stable:  # the open test is measured again only when a cycle is added
            # screened, its relay inferred (or as stated) and its points measured as analyze --model does
            seen = self._seen[test.t_start] = (stable, measure_test(flight, test, self.relay, self.min_cycles))
        measured = seen[1]
        if measured.test is None:
            return None
        used = replace(measured.test, index=test.index)
        self._by_index[test.index] = replace(measured, test=used)
        return used

    def test_update(self, test: MrftTest, flight: FlightLog) -> TestUpdate:
        summary = self._by_index[test.index].summary
        assert summary is not None  # usable
        relay, notes = summary.relay, summary.notes
        if abs(relay.bias) > 1e-9 * relay.h:  # analyze --model states the same assumption in its first lines
            notes += ("assumed: the relay's bias is balanced by the loop's operating point",)
        return _test_update(test, flight, relay=relay, notes=notes)

    def estimate(self, tests: list[MrftTest]) -> EstimateUpdate | None:
        points = [p for t in tests for p in self._by_index[t.index].points]
        try:
            fit = identify_points(self.model, points)
        except MrftError:
            return None
        return EstimateUpdate(fit.model.family, tuple(fit.estimates), tuple(t.index + 1 for t in tests),
                              max(_newest_end(t) for t in tests), False, time.time(), fit.undetermined, fit.advice)

    def final(self, res: AnalysisResult) -> EstimateUpdate:
        fit = res.identification
        assert fit is not None  # analyze_flight raises when no test is usable
        return EstimateUpdate(fit.model.family, tuple(fit.estimates), tuple(t.index + 1 for t in res.tests),
                              max(t.t_end for t in res.tests), True, time.time(), fit.undetermined, fit.advice,
                              analysis=res)


def _strategy(model: PlantModel, options: WatchOptions) -> _Strategy:
    """The family's strategy, built afresh at the start and at every restart."""
    if isinstance(model, LoopModel):
        return _Eq2(model, options.min_cycles)
    return _Family(model, options.relay, options.min_cycles)


# --------------------------------------------------------------------------------------------------
# the follow loop
# --------------------------------------------------------------------------------------------------


def _updates(tests: list[MrftTest], flight: FlightLog, strategy: _Strategy,
             reported: dict[int, int]) -> Iterator[Update]:
    """Each usable test with a new stable cycle, then the estimate when any was new."""
    used = [u for u in (strategy.usable(t, flight) for t in tests) if u is not None]
    changed = False
    for test in used:
        if reported.get(test.index) != test.n_stable:
            reported[test.index] = test.n_stable
            changed = True
            yield strategy.test_update(test, flight)
    if changed:
        est = strategy.estimate(used)
        if est is not None:
            yield est


def _final(flight: FlightLog | None, model: PlantModel, strategy: _Strategy, options: WatchOptions, reason: str,
           n_tests: int, path: str | Path) -> Iterator[Update]:
    """The whole log through :func:`mrftcli.analyze.analyze_flight` (as ``analyze`` runs it), then :class:`WatchEnd`."""
    if flight is None:
        yield WatchEnd(reason=reason, tests=0, wall_time=time.time(),
                       error=f"{path}: no data in the log: the loop's command and output never appeared before the "
                             f"recording stopped ('mrft-ident topics {path}' lists what it holds; --command-topic, "
                             "--output-topic name others)",
                       exit_code=LogReadError.exit_code)
        return
    try:
        res = analyze_flight(flight, model, options=options.analysis())
    except MrftError as err:
        yield WatchEnd(reason=reason, tests=n_tests, wall_time=time.time(), error=str(err), exit_code=err.exit_code)
        return
    yield strategy.final(res)
    yield WatchEnd(reason=reason, tests=len(res.tests), wall_time=time.time())


def _follow(path: Path, model: PlantModel, read: ReadOptions, options: WatchOptions,
            sleep: Callable[[float], None], clock: Callable[[], float]) -> Generator[Update, None, None]:
    """The loop of :func:`watch`."""
    _wait_for(path, options.wait, options.poll, sleep, clock)
    follower = follow_log(path, read)
    strategy = _strategy(model, options)
    tracker = _Tracker(strategy.quiet_s)
    reported: dict[int, int] = {}  # test index -> stable cycles last reported
    flight = None
    last_growth = clock()
    while True:
        snap = follower.poll()
        now = clock()
        if snap.restarted is not None:
            strategy, reported, flight = _strategy(model, options), {}, None
            tracker = _Tracker(strategy.quiet_s)
            yield Restart(reason=snap.restarted, wall_time=time.time())
        if snap.grew:
            last_growth = now
        if snap.flight is not None:
            flight = snap.flight
            yield from _updates(tracker.update(flight), flight, strategy, reported)
        if snap.closed or now - last_growth > options.idle:
            reason = "closed" if snap.closed else "idle"
            if flight is None and read.fmt is None:  # nothing read: say whether it is a log at all
                not_a_log = _not_a_log(path)
                if not_a_log is not None:
                    yield WatchEnd(reason=reason, tests=0, wall_time=time.time(), error=not_a_log,
                                   exit_code=LogReadError.exit_code)
                    return
            yield from _final(flight, model, strategy, options, reason, len(reported), path)
            return
        sleep(options.poll)


def watch(path: str | Path, model: PlantModel, *, read: ReadOptions | None = None,
          options: WatchOptions | None = None, sleep: Callable[[float], None] = time.sleep,
          clock: Callable[[], float] = time.monotonic) -> Generator[Update, None, None]:
    """Follow ``path`` while it is written and yield the updates of ``model``'s identification.

    The live counterpart of :func:`mrftcli.analyze.analyze_flight` (module docstring): each usable test
    as a :class:`TestUpdate`, after each new cycle an :class:`EstimateUpdate` (naming the parameters the
    tests so far do not determine), and when the writer closes the file the whole log's analysis
    (``final``).

    Parameters
    ----------
    path : str or Path
        An MCAP file, a ROS 2 bag directory with mcap storage, or any log :func:`mrftcli.io.read_flight`
        reads (CSV, ULog, ...). It may not exist yet: it is waited for (a ground station starts
        ``watch`` before the logger), until the generator is closed or for ``options.wait`` seconds.
    model : PlantModel
        The structure with its known parameters (set E) and ranges (set I): eq. (2) with Tp known
        (``mrftcli.mrft.model.soiptd_model(Tp)``, Tp [s] from the bench test), or e.g.
        ``mrftcli.mrft.families.family_model("fopdt")``.
    read : ReadOptions, optional
        The loop and the log layout, as for :func:`mrftcli.io.read_flight` (``fmt`` None: detected; a
        missing file or a ``.mcap`` name is followed as MCAP); None: ``ReadOptions()``.
    options : WatchOptions, optional
        Stable cycles per test, idle time, poll interval, the longest wait for the file and a process
        plant's relay; None: ``WatchOptions()``.
    sleep, clock
        Injected for tests (default :func:`time.sleep`, :func:`time.monotonic`).

    Yields
    ------
    TestUpdate, EstimateUpdate, Restart or WatchEnd
        The last one is a :class:`WatchEnd` (its ``error`` the final analysis's one-line message); stop
        early by closing the generator (Ctrl-C in the CLI). A :class:`Restart` when the file is
        truncated or replaced (a new recording): the tests so far are forgotten.

    Raises
    ------
    InputError
        A relay stated for eq. (2) (it reads its relay from the log).
    LogReadError
        The file did not appear within ``wait`` seconds, is not a log, or lacks a required topic once
        closed.

    Examples
    --------
    >>> from mrftcli.mrft.model import soiptd_model
    >>> updates = watch("flight.mcap", soiptd_model(0.0422), read=ReadOptions(loop="altitude"))
    """
    opts = WatchOptions() if options is None else options
    if isinstance(model, LoopModel) and opts.relay.stated:
        raise InputError("a relay (--relay, --eps) takes a process model (--model fopdt, sopdt, ipdt or foipdt); "
                         "eq. (2) reads beta from the log")
    return _follow(Path(path), model, ReadOptions() if read is None else read, opts, sleep, clock)


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
