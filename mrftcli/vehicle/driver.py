"""The whole vehicle from one flight: :func:`identify_vehicle`, a short driver over named stages.

``find_loops`` (the loops whose topics the log holds) -> ``identify_inner`` (altitude, roll, pitch:
eq. (2) at the known Tp) -> ``identify_outer`` (x, y: through the closed inner loop when the gains
in use are known, else eq. (2), said in the assumptions) -> ``tune_loops`` (inner loops first, robust
as ``tune`` does) -> the missing loops with what to fly next (:mod:`mrftcli.vehicle.next_tests`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from ..analyze import AnalysisResult, analyze_flight, refuse_rejected_tp
from ..analyze.options import AnalyzeOptions, CascadeOptions
from ..errors import InputError, LogReadError, MrftError, OtherLoopError
from ..io import FlightLog, LogSource, ReadOptions, get_layout, log_layout, open_log, parse_spec, read_loop
from ..io.hover import logged_hover_thrust
from ..progress import Progress, report
from ..tune.analysis import RATE_ASSUMED_NOTE
from ..tune.design import LEAD_DESIGN_WORDS
from ..tune.design import KINDS, OBJECTIVES
from ..tune.stacks import read_hover_thrust
from ..validate import check_tp
from ..analyze.cascade import OUTER_COMMANDS, cascade_model, inner_draws, inner_gains_of, inner_loop_of
from ..mrft.controller import Controller
from ..mrft.model import LoopModel
from .gains import TuneOptions, joint_gyro_gains, tune_loop, tune_outer
from .loops import INNER_OF, OUTER_LOOPS, VEHICLE_ORDER, layout_absent
from .next_tests import missing_from_error, missing_topics
from .record import LoopGains, MissingLoop, VehicleLoop, VehicleResult

__all__ = ["VehicleOptions", "identify_vehicle", "models_per_loop", "find_loops", "identify_inner", "identify_outer",
           "cascade_outer", "EQ2_OUTER_ASSUMPTION", "hover_thrust_from_log"]

#: The assumption stated when an outer loop is identified with eq. (2) (``{loops}``, ``{tp}``, ``{inner}`` and
#: ``{why}`` the cascade could not be used filled in).
EQ2_OUTER_ASSUMPTION = ("{loops} identified with eq. (2) at Tp = {tp} s, its Td and tau absorbing the closed "
                        "{inner} loop: {why}; the outer gains are tuned for the inner loop as flown")


@dataclass(frozen=True)
class VehicleOptions:
    """How :func:`identify_vehicle` reads, identifies and tunes (one record instead of a keyword list).

    Attributes
    ----------
    layout, fmt, time_unit : str or None
        As :class:`mrftcli.io.ReadOptions` (None: recognised / detected).
    controller_rate_hz : float or None
        Rate [Hz] the relays and controllers run at; None: each loop's log records it.
    min_stable_cycles : int
        Fewest stable cycles for a test to be used (analyze's ``--min-cycles``).
    n_bootstrap : int
        Bootstrap draws of each loop's uncertainty (the robust designs' posterior).
    tune : TuneOptions
        Controller kind, criterion, Ms limit and the ``--export`` stack (as ``tune``); its ``rate_hz``
        is taken from ``controller_rate_hz``.
    plan : bool
        Plan the next test of a loop flown at one beta (about a second each).
    outer_command : {"acceleration", "attitude", "identify"}
        What the outer relays command (``--outer-command``), for the outer loops identified through the
        cascade; stated in the assumptions.
    inner_draws : int
        Draws of the inner model carried into an outer estimate through the cascade.
    accept_tp : bool
        Keep a Tp the recording rejects (``--accept-tp``); else that loop is missing, naming the Tp it
        fits (:func:`mrftcli.analyze.refuse_rejected_tp`).
    """

    layout: str | None = None
    fmt: str | None = None
    time_unit: str | None = None
    controller_rate_hz: float | None = None
    min_stable_cycles: int = 3
    n_bootstrap: int = 400
    tune: TuneOptions = TuneOptions()
    plan: bool = True
    outer_command: str = "acceleration"
    inner_draws: int = 30
    accept_tp: bool = False

    def __post_init__(self) -> None:
        if self.tune.kind not in KINDS:
            raise InputError(f"unknown controller kind {self.tune.kind!r}; choose from {', '.join(KINDS)}")
        if self.tune.objective not in OBJECTIVES:
            raise InputError(f"unknown objective {self.tune.objective!r}; choose from {', '.join(OBJECTIVES)}")
        if self.outer_command not in OUTER_COMMANDS:
            raise InputError(f"--outer-command must be one of {', '.join(OUTER_COMMANDS)}, got {self.outer_command!r}")
        object.__setattr__(self, "tune", dataclasses.replace(self.tune, rate_hz=self.controller_rate_hz))

    def read(self, loop: str) -> ReadOptions:
        """How ``loop`` is read from the log."""
        return ReadOptions(loop=loop, layout=self.layout, fmt=self.fmt, time_unit=self.time_unit,
                           controller_rate_hz=self.controller_rate_hz)

    def analyze(self) -> AnalyzeOptions:
        """How each loop's tests are screened and identified."""
        # vehicle has no --diagnose: the default hint points to the command
        return AnalyzeOptions(min_stable_cycles=self.min_stable_cycles, n_bootstrap=self.n_bootstrap)


def models_per_loop(model: LoopModel | Mapping[str, LoopModel]) -> dict[str, LoopModel]:
    """Eq. (2) with its known Tp for every loop: one model for all, or a mapping (every loop of
    :data:`VEHICLE_ORDER`), each Tp checked within its physical range.

    Raises
    ------
    InputError
        A Tp outside its physical range, or a mapping that leaves a loop out or names an unknown one.
    """
    if isinstance(model, Mapping):
        unknown = sorted(set(model) - set(VEHICLE_ORDER))
        if unknown:
            raise InputError(f"Tp given for unknown loop(s) {', '.join(unknown)}; loops are {', '.join(VEHICLE_ORDER)}")
        missing = [loop for loop in VEHICLE_ORDER if loop not in model]
        if missing:
            raise InputError(f"no Tp for the {', '.join(missing)} loop(s): give one Tp for all, or one per loop")
        models = {loop: model[loop] for loop in VEHICLE_ORDER}
    else:
        models = dict.fromkeys(VEHICLE_ORDER, model)
    for m in models.values():
        check_tp(m.Tp)
    return models


@dataclass(frozen=True)
class _Found:
    """What ``find_loops`` found: the layout, the loops to analyse, and those the log does not record."""

    layout: str | None
    loops: tuple[str, ...]
    missing: dict[str, MissingLoop]


def find_loops(source: LogSource, options: VehicleOptions, tps: Mapping[str, float]) -> _Found:
    """The loops whose command and output topics the open log holds (:func:`~mrftcli.vehicle.loops.loops_in_log`'s
    rule), in the vehicle's order; their topics are read in one pass (a bag is read once, not once per loop)."""
    layout = log_layout(source, options.layout).layout
    absent = {loop: layout_absent(source, layout, loop) for loop in VEHICLE_ORDER}
    missing = {loop: missing_topics(loop, gone, tps[loop]) for loop, gone in absent.items() if gone}
    present = tuple(loop for loop in VEHICLE_ORDER if not absent[loop])
    specs = [spec for loop in present for spec in (layout.loops[loop].command, layout.loops[loop].output,
                                                   layout.loops[loop].setpoint, layout.loops[loop].beta) if spec]
    source.prefetch(sorted({parse_spec(spec).topic for spec in specs}))
    return _Found(layout.name, present, missing)


def _read(source: LogSource, loop: str, Tp: float, options: VehicleOptions, acc: _Accumulated) -> FlightLog | None:
    """The loop's signals, or None with the loop recorded as missing: a field the log's topic does not
    hold (a CSV or ULog with z alone) means the loop is not recorded, as ``batch --loop auto`` says."""
    try:
        return read_loop(source, options.read(loop))
    except OtherLoopError as err:  # the log's tests are another loop's: this one has none (not "record it")
        acc.missing[loop] = missing_from_error(loop, err, Tp, str(source.path))
        return None
    except (InputError, LogReadError) as err:
        acc.missing[loop] = missing_topics(loop, (" ".join(str(err).split()),), Tp)
        return None


def identify_vehicle(path: str | Path, model: LoopModel | Mapping[str, LoopModel], *,
                     inner_gains: Mapping[str, object] | None = None, options: VehicleOptions | None = None,
                     progress: Progress | None = None) -> VehicleResult:
    """Identify and tune every loop one flight holds tests of; say which tests the others need.

    Parameters
    ----------
    path : str or Path
        The flight log (any format and layout ``analyze`` reads).
    model : LoopModel or Mapping[str, LoopModel]
        Eq. (2) with its known propulsion time constant Tp [s] (``soiptd_model(Tp)``), one for every
        loop or one per loop (:func:`models_per_loop`).
    inner_gains : Mapping[str, object], optional
        The inner loops' gains in use during the flight (``--inner-gains GAINS.json``); without them
        the outer loops are identified with eq. (2) and the result's first assumption says so.
    options : VehicleOptions, optional
        How to read, identify and tune (default ``VehicleOptions()``).
    progress : Progress, optional
        Called as ``progress(done, total, stage)`` per loop.

    Returns
    -------
    VehicleResult

    Raises
    ------
    InputError
        A bad Tp or option; a log that cannot be opened raises the reader's error.
    """
    opts = options or VehicleOptions()
    models = models_per_loop(model)
    tps = {loop: m.Tp for loop, m in models.items()}
    log = str(path)
    with open_log(log, opts.fmt, echo_warnings=False, time_unit=opts.time_unit) as source:
        found = find_loops(source, opts, tps)
        opts, hover_said = hover_thrust_from_log(source, _fields_held(source, found), opts,
                                                 cascade=inner_gains is not None)
        opts = dataclasses.replace(opts, layout=found.layout)
        acc = _Accumulated(missing=dict(found.missing), first=[hover_said] if hover_said else [])
        total = len(found.loops) + 1
        for i, loop in enumerate(found.loops):
            report(progress, i, total, f"{loop}: identifying and tuning")
            if loop in OUTER_LOOPS:
                identify_outer(source, loop, models[loop], opts, inner_gains, acc)
            else:
                identify_inner(source, loop, models[loop], opts, acc)
    acc.loops.update(joint_gyro_gains(acc.loops, opts.tune))  # one gyro cutoff for roll and pitch (issue 25)
    if inner_gains is not None and not any(loop in acc.loops for loop in OUTER_LOOPS):
        acc.warnings.append("--inner-gains not used: the flight gives no model of x or y")
    report(progress, total, total, "done")
    ordered = {loop: acc.missing[loop] for loop in VEHICLE_ORDER if loop in acc.missing}
    return VehicleResult(log, found.layout, acc.loops, ordered, (*acc.first, *acc.assumptions), tuple(acc.warnings))


def _fields_held(source: LogSource, found: _Found) -> tuple[str, ...]:
    """The found loops whose command and output fields the log holds (a topic may hold z alone: such a loop is
    found, then read as not recorded), without reading their data."""
    try:
        layout = get_layout(found.layout or "")
    except InputError:  # no layout by that name: every found loop counts
        return found.loops
    held = []
    for loop in found.loops:
        try:
            for spec in (layout.loops[loop].command, layout.loops[loop].output):
                ts = parse_spec(spec)
                source.leaves(source.resolve_topic(ts.topic) or ts.topic, ts.field)
        except (LogReadError, InputError):
            continue
        held.append(loop)
    return tuple(held)


def hover_thrust_from_log(source: LogSource, loops: tuple[str, ...], options: VehicleOptions, *,
                          cascade: bool = False) -> tuple[VehicleOptions, str]:
    """The hover thrust the export of ``loops`` needs (:data:`~mrftcli.tune.stacks.HOVER_LOOPS`) when
    ``--hover-thrust`` is not given: PX4's estimate read from the open log (:func:`mrftcli.io.hover.logged_hover_thrust`),
    with the sentence that states it; ``(options, "")`` when given or not needed. ``cascade``: x and y are
    identified through the closed inner loop (their export is refused there, so they do not need it).

    Raises
    ------
    InputError
        Before any analysis: a loop's export needs the hover thrust, and it is neither given nor in the log.
    """
    st = options.tune.stack
    if st is None:
        return options, ""
    logged = read_hover_thrust(st.stack, loops, st.hover_thrust, lambda: logged_hover_thrust(source),
                                      optional=OUTER_LOOPS if cascade else ())
    if logged is None:
        return options, ""
    stack = dataclasses.replace(st, hover_thrust=logged.value, hover_source=logged.statement())
    return dataclasses.replace(options, tune=dataclasses.replace(options.tune, stack=stack)), logged.statement()


@dataclass
class _Accumulated:
    """What the stages have found so far (private to :func:`identify_vehicle`; the result is frozen)."""

    loops: dict[str, VehicleLoop] = field(default_factory=dict)
    missing: dict[str, MissingLoop] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    #: assumptions shown first: what a whole route rests on
    first: list[str] = field(default_factory=list)
    assumptions: list[str] = field(default_factory=list)

    def add(self, entry: VehicleLoop, stated: tuple[str, ...], refused: tuple[str, ...]) -> None:
        self.loops[entry.loop] = entry
        self.warnings += [f"{entry.loop}: {w}" for w in (*entry.analysis.warnings, *refused)]
        self.assumptions += [f"{entry.loop}: {n}" for n in stated]


def identify_inner(source: LogSource, loop: str, model: LoopModel, options: VehicleOptions,
                   acc: _Accumulated, said: str = "") -> None:
    """An inner loop (altitude, roll, pitch): eq. (2) at the model's known Tp, tuned; or the tests it needs.

    ``said``: an outer loop identified with eq. (2) instead (:func:`identify_outer`), the assumption that
    says so and why, stated first."""
    flight = _read(source, loop, model.Tp, options, acc)
    if flight is None:
        return
    try:
        result = refuse_rejected_tp(analyze_flight(flight, model, options=options.analyze()), options.accept_tp)
    except MrftError as err:
        acc.missing[loop] = missing_from_error(loop, err, model.Tp, str(source.path), options.controller_rate_hz,
                                               options.plan)
        return
    if said:
        acc.first.append(said)
    gains, stated, refused = _tuned(result, options)
    acc.add(VehicleLoop(loop, "outer" if said else "inner", "eq2", result, gains, (said,) if said else ()), stated,
            refused)


def identify_outer(source: LogSource, loop: str, model: LoopModel, options: VehicleOptions,
                   inner_gains: Mapping[str, object] | None, acc: _Accumulated) -> None:
    """An outer loop (x, y): through the closed inner loop when the inner loop has a model from this flight
    and its gains in use are given, else eq. (2) (the first assumption says so and why, naming the
    option); tuned; or the tests it needs. ``model``: eq. (2) with the loop's Tp known."""
    Tp = model.Tp
    inner = INNER_OF[loop]
    controller, why_not = _inner_controller(inner, inner_gains, acc)
    if controller is None:
        said = EQ2_OUTER_ASSUMPTION.format(loops=loop, tp=f"{Tp:g}", inner=inner, why=why_not)
        identify_inner(source, loop, model, options, acc, said)
        return
    flight = _read(source, loop, Tp, options, acc)
    if flight is None:
        return
    try:
        analysis = cascade_outer(flight, acc.loops[inner], controller, options)
    except MrftError as err:
        acc.missing[loop] = missing_from_error(loop, err, Tp, str(source.path), options.controller_rate_hz,
                                               options.plan)
        return
    acc.first += [f"{loop}: {a}" for a in analysis.assumptions]
    try:
        gains: LoopGains | None = tune_outer(analysis, acc.loops[inner], options.tune)
        refused: tuple[str, ...] = ()
    except MrftError as err:
        gains, refused = None, (f"not tuned: {' '.join(str(err).split())}",)
    notes = (f"identified through the closed {inner} loop",) + (() if gains is None else gains.tune.notes[:1])
    acc.add(VehicleLoop(loop, "outer", "cascade", analysis, gains, notes), (), refused)


def cascade_outer(flight: FlightLog, inner: VehicleLoop, controller: Controller,
                  options: VehicleOptions) -> AnalysisResult:
    """The outer loop of ``flight`` through ``inner`` closed by ``controller`` (the gains flown): the inner
    loop identified in the same flight, its uncertainty carried by ``options.inner_draws`` draws, K as
    ``options.outer_command`` says (:func:`mrftcli.analyze.cascade.analyze_cascade`).

    Raises
    ------
    MrftError
        No usable outer test, or the tests do not determine the unknowns (analyze_cascade's errors).
    """
    assert inner.analysis.kind == "soiptd"  # an inner loop is identified with eq. (2)
    loop = inner_loop_of(inner.analysis, controller, inner.loop)
    copts = CascadeOptions(draws=tuple(inner_draws(inner.analysis, loop, options.inner_draws)),
                           assumptions=(f"inner model: the {inner.loop} loop identified in this flight",),
                           inner_source=f"identified from the {inner.loop} tests of this flight",
                           gains_source="--inner-gains")
    return analyze_flight(flight, cascade_model(loop, options.outer_command),
                          options=AnalyzeOptions(min_stable_cycles=options.min_stable_cycles, cascade=copts))


def _inner_controller(inner: str, inner_gains: Mapping[str, object] | None,
                      acc: _Accumulated) -> tuple[Controller | None, str]:
    """The controller that flew ``inner`` (from ``--inner-gains``), or (None, why the cascade cannot be used)."""
    if inner_gains is None:
        return None, ("the inner gains in use during the flight are not given (--inner-gains GAINS.json identifies "
                      "it through the closed inner loop)")
    if inner not in acc.loops:
        return None, (f"the {inner} loop has no model from this flight (fly its tests in the same flight to "
                      "identify the outer loop through it)")
    try:
        return inner_gains_of(inner_gains, inner), ""
    except InputError as err:
        return None, f"{err}"


def _tuned(result: AnalysisResult,
           options: VehicleOptions) -> tuple[LoopGains | None, tuple[str, ...], tuple[str, ...]]:
    """The loop's gains, the assumptions they rest on, and why it was not tuned (None, (), (why,))."""
    try:
        gains = tune_loop(result, options.tune)
    except MrftError as err:
        return None, (), (f"not tuned: {' '.join(str(err).split())}",)
    # what the gains rest on that the log cannot show: an assumed rate, an export's (ArduPilot altitude's split of tau)
    hover = options.tune.stack.hover_source if options.tune.stack is not None else ""  # already stated first
    stated = (*(n for n in gains.tune.notes if n == RATE_ASSUMED_NOTE or n.startswith(LEAD_DESIGN_WORDS)),
              *(a for a in (gains.export.assumptions if gains.export is not None else ()) if a != hover))
    return gains, stated, ()
