"""The whole vehicle from one flight: :func:`identify_vehicle`, a short driver over named stages.

``find_loops`` (the loops whose topics the log holds) -> ``identify_inner`` (altitude, roll, pitch:
eq. (2) at the known Tp) -> ``identify_outer`` (x, y: through the closed inner loop when the gains
in use are known, else eq. (2), said in the assumptions) -> ``tune_loops`` (inner loops first, robust
as ``tune`` does) -> the missing loops with what to fly next (:mod:`mrftcli.vehicle.next_tests`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ..analyze import AnalysisResult, analyze_flight
from ..analyze.options import AnalyzeOptions
from ..errors import InputError, MrftError
from ..io import ReadOptions, read_flight
from ..progress import Progress, report
from ..tune.analysis import RATE_ASSUMED_NOTE, tune_analysis
from ..tune.design import KINDS, OBJECTIVES
from ..validate import check_tp
from .loops import INNER_OF, OUTER_LOOPS, VEHICLE_ORDER, layout_absent
from .next_tests import missing_from_error, missing_topics
from .record import LoopGains, MissingLoop, VehicleLoop, VehicleResult

__all__ = ["VehicleOptions", "identify_vehicle", "tp_per_loop", "EQ2_OUTER_ASSUMPTION"]

#: The assumption stated when an outer loop is identified with eq. (2) (its ``{loops}``, ``{inner}`` filled in).
EQ2_OUTER_ASSUMPTION = ("{loops} identified with eq. (2) at Tp = {tp} s, its Td and tau absorbing the closed "
                        "{inner} loop: the inner gains in use during the flight are not given (--inner-gains "
                        "GAINS.json identifies {loops} through the closed inner loop); the outer gains are tuned "
                        "for the inner loop as flown")


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
    kind : {"PD", "PID"}
        The controller recommended for every loop.
    objective : {"iae", "itae"}
        The designs' criterion (as ``tune``).
    ms_max : float
        Limit on the sensitivity peak Ms (> 1).
    plan : bool
        Plan the next test of a loop flown at one beta (about a second each).
    """

    layout: str | None = None
    fmt: str | None = None
    time_unit: str | None = None
    controller_rate_hz: float | None = None
    min_stable_cycles: int = 3
    n_bootstrap: int = 400
    kind: str = "PD"
    objective: str = "iae"
    ms_max: float = 1.6
    plan: bool = True

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise InputError(f"unknown controller kind {self.kind!r}; choose from {', '.join(KINDS)}")
        if self.objective not in OBJECTIVES:
            raise InputError(f"unknown objective {self.objective!r}; choose from {', '.join(OBJECTIVES)}")

    def read(self, loop: str) -> ReadOptions:
        """How ``loop`` is read from the log."""
        return ReadOptions(loop=loop, layout=self.layout, fmt=self.fmt, time_unit=self.time_unit,
                           controller_rate_hz=self.controller_rate_hz)

    def analyze(self) -> AnalyzeOptions:
        return AnalyzeOptions(min_stable_cycles=self.min_stable_cycles, n_bootstrap=self.n_bootstrap)


def tp_per_loop(Tp: float | Mapping[str, float]) -> dict[str, float]:
    """Tp [s] for every loop: one value for all, or a mapping (every loop of :data:`VEHICLE_ORDER`).

    Raises
    ------
    InputError
        A Tp outside its physical range, or a mapping that leaves a loop out or names an unknown one.
    """
    if isinstance(Tp, Mapping):
        unknown = sorted(set(Tp) - set(VEHICLE_ORDER))
        if unknown:
            raise InputError(f"Tp given for unknown loop(s) {', '.join(unknown)}; loops are {', '.join(VEHICLE_ORDER)}")
        missing = [loop for loop in VEHICLE_ORDER if loop not in Tp]
        if missing:
            raise InputError(f"no Tp for the {', '.join(missing)} loop(s): give one Tp for all, or one per loop")
        return {loop: check_tp(Tp[loop]) for loop in VEHICLE_ORDER}
    return dict.fromkeys(VEHICLE_ORDER, check_tp(Tp))


@dataclass(frozen=True)
class _Found:
    """What ``find_loops`` found: the layout, the loops to analyse, and those the log does not record."""

    layout: str | None
    loops: tuple[str, ...]
    missing: dict[str, MissingLoop]


def find_loops(path: str, options: VehicleOptions, tps: Mapping[str, float]) -> _Found:
    """The loops whose command and output topics the log holds (:func:`~mrftcli.vehicle.loops.loops_in_log`'s
    rule), in the vehicle's order."""
    from ..io import log_layout, open_log

    with open_log(path, options.fmt, echo_warnings=False, time_unit=options.time_unit) as source:
        layout = log_layout(source, options.layout).layout
        absent = {loop: layout_absent(source, layout, loop) for loop in VEHICLE_ORDER}
    missing = {loop: missing_topics(loop, gone, tps[loop]) for loop, gone in absent.items() if gone}
    return _Found(layout.name, tuple(loop for loop in VEHICLE_ORDER if not absent[loop]), missing)


def _identify_eq2(path: str, loop: str, Tp: float, options: VehicleOptions) -> AnalysisResult:
    """One loop with eq. (2) at the known Tp, as ``analyze`` (the reader's warnings kept in the result)."""
    flight = read_flight(path, options.read(loop), echo_warnings=False)
    return analyze_flight(flight, Tp, options=options.analyze())


def _tune(result: AnalysisResult, options: VehicleOptions) -> LoopGains:
    """Robust gains (model-based without a posterior) at the loop's controller rate, as ``tune``."""
    res = tune_analysis(result, kinds=(options.kind,), rate_hz=options.controller_rate_hz,
                        designs=("model-based", "robust"), objective=options.objective, ms_max=options.ms_max)
    design = "robust" if any(d.name == "robust" for d in res.designs) else "model-based"
    return LoopGains(design, options.kind, res)


def identify_vehicle(path: str | Path, Tp: float | Mapping[str, float], *, inner_gains: Mapping[str, object] | None = None,
                     options: VehicleOptions | None = None, progress: Progress | None = None) -> VehicleResult:
    """Identify and tune every loop one flight holds tests of; say which tests the others need.

    Parameters
    ----------
    path : str or Path
        The flight log (any format and layout ``analyze`` reads).
    Tp : float or Mapping[str, float]
        Known propulsion time constant [s], one for every loop or one per loop (:func:`tp_per_loop`).
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
    tps = tp_per_loop(Tp)
    log = str(path)
    found = find_loops(log, opts, tps)
    opts = dataclasses.replace(opts, layout=found.layout)
    loops: dict[str, VehicleLoop] = {}
    missing = dict(found.missing)
    warnings: list[str] = []
    assumptions: list[str] = []
    eq2_outer: list[str] = []
    total = len(found.loops) + 1
    for i, loop in enumerate(found.loops):
        report(progress, i, total, f"{loop}: identifying and tuning")
        try:
            result = _identify_eq2(log, loop, tps[loop], opts)
        except MrftError as err:
            missing[loop] = missing_from_error(loop, err, tps[loop], log, opts.controller_rate_hz, opts.plan)
            continue
        role = "outer" if loop in OUTER_LOOPS else "inner"
        notes: tuple[str, ...] = ()
        if role == "outer":
            eq2_outer.append(loop)
            notes = (EQ2_OUTER_ASSUMPTION.format(loops=loop, tp=f"{tps[loop]:g}", inner=INNER_OF[loop]),)
        gains, stated, refused = _tuned(result, opts)
        warnings += [f"{loop}: {w}" for w in (*result.warnings, *refused)]
        assumptions += [f"{loop}: {n}" for n in stated]
        loops[loop] = VehicleLoop(loop, role, "eq2", result, gains, notes)
    if eq2_outer:
        inner = "/".join(INNER_OF[loop] for loop in eq2_outer)
        tp = "/".join(f"{tps[loop]:g}" for loop in eq2_outer)
        assumptions.insert(0, EQ2_OUTER_ASSUMPTION.format(loops=", ".join(eq2_outer), tp=tp, inner=inner))
    report(progress, total, total, "done")
    ordered = {loop: missing[loop] for loop in VEHICLE_ORDER if loop in missing}
    return VehicleResult(log, found.layout, loops, ordered, tuple(assumptions), tuple(warnings))


def _tuned(result: AnalysisResult,
           options: VehicleOptions) -> tuple[LoopGains | None, tuple[str, ...], tuple[str, ...]]:
    """The loop's gains, the assumptions they rest on, and why it was not tuned (None, (), (why,))."""
    try:
        gains = _tune(result, options)
    except MrftError as err:
        return None, (), (f"not tuned: {' '.join(str(err).split())}",)
    return gains, tuple(n for n in gains.tune.notes if n == RATE_ASSUMED_NOTE), ()
