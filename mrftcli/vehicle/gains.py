"""Tune one identified loop of the vehicle as ``tune`` does, optionally for a flight stack's rate and filter.

Without a stack the designs run at the controller rate the analysis records (as ``tune LOG``); with
``--export px4|ardupilot|hear`` each loop the stack takes is designed with the stack's own rate and
rate filter (:func:`mrftcli.tune.stacks.stack_setting`) and exported as it loads it
(:func:`mrftcli.tune.stacks.export_design`); a loop the stack cannot take is tuned without it and
the refusal is recorded with the gains.

An outer loop (x, y) identified through its closed inner loop is tuned on the cascade (:func:`tune_outer`):
the outer PD is designed on the cascade closed by the inner loop's *new* gains, the ones tuned in the
same run (robust over the outer estimate's draws, :func:`mrftcli.tune.design.tune`): the vehicle is
flown with both sets loaded.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass


from ..analyze import AnalysisResult
from ..errors import InputError
from ..mrft.cascade import InnerLoop
from ..mrft.controller import Controller
from ..segment import MrftTest
from ..tune.analysis import posterior_from_analysis, recommended_design_name, tune_analysis
from ..tune.design import DesignOptions, TuneResult, tune
from ..tune.grid import outer_draws
from ..tune.stacks import (ExportEvidence, StackSetting, check_exportable, export_design,
                           stack_setting)
from .record import LoopGains, VehicleLoop

__all__ = ["StackOptions", "TuneOptions", "tune_loop", "tune_outer", "joint_gyro_gains", "STACKS", "OUTER_DRAWS"]

#: Draws of the outer estimate the robust outer design holds its margins on (as ``tune`` on a cascade).
OUTER_DRAWS = 30
#: What ``--export`` takes: ``generic`` (tune's generic JSON, the GAINS.json ``--inner-gains`` reads)
#: and the stacks with their own rate and filter.
STACKS = ("generic", "hear", "px4", "ardupilot")


@dataclass(frozen=True)
class StackOptions:
    """The flight stack the gains are for (``--export``) and its settings, as ``tune --export``.

    Attributes
    ----------
    stack : str
        One of :data:`STACKS`.
    gyro_cutoff_hz : float or None
        PX4 IMU_GYRO_CUTOFF / ArduPilot INS_GYRO_FILTER [Hz]; None: the stack's default (stated).
    hover_thrust : float or None
        PX4 MPC_THR_HOVER / ArduPilot MOT_THST_HOVER (normalised), for the loops of
        :data:`~mrftcli.tune.stacks.HOVER_LOOPS`.
    clamp : bool
        Export values outside the stack's ranges at the bound instead of refusing.
    hover_source : str
        Where ``hover_thrust`` came from when not given (read from the log): stated first among the
        assumptions of every export that uses it; empty: given.
    """

    stack: str
    gyro_cutoff_hz: float | None = None
    hover_thrust: float | None = None
    clamp: bool = False
    hover_source: str = ""

    def __post_init__(self) -> None:
        if self.stack not in STACKS:
            raise InputError(f"unknown export {self.stack!r}; choose from {', '.join(STACKS)}")


@dataclass(frozen=True)
class TuneOptions:
    """How every loop is tuned: the controller kind, the criterion, the Ms limit, the rate, the stack."""

    kind: str = "PD"
    objective: str = "iae"
    ms_max: float = 1.6
    rate_hz: float | None = None
    stack: StackOptions | None = None


def _evidence(result: AnalysisResult, notes: Sequence[str], hover_source: str = "") -> ExportEvidence:
    """The relay heights and amplitudes flown, the analysis's notes, its posterior's 95 % set and where the hover
    thrust came from, for an export's checks, range-constrained designs and first assumption: what
    ``tune LOG --export`` gives them, so both write the same values."""
    post = posterior_from_analysis(result)
    tests: Sequence[MrftTest] = result.tests
    return ExportEvidence(tuple(float(t.h) for t in tests), tuple(float(t.amplitude_mean) for t in tests), tuple(notes),
                          tuple(post.in_set_models()), hover_source)


def _setting(result: AnalysisResult, options: TuneOptions) -> tuple[StackSetting | None, str | None]:
    """The stack's setting for this loop, or (None, why the stack cannot take it)."""
    st = options.stack
    if st is None or st.stack == "generic":
        return None, None
    try:
        check_exportable(st.stack, result.loop, options.kind, st.hover_thrust)
        setting = stack_setting(st.stack, result.loop, options.rate_hz, result.controller_rate_hz, st.gyro_cutoff_hz)
    except InputError as err:
        return None, str(err)
    return setting, None


def tune_loop(result: AnalysisResult, options: TuneOptions) -> LoopGains:
    """Robust gains (model-based without a posterior) for one analysed loop, and its stack export.

    Parameters
    ----------
    result : AnalysisResult
        The loop's analysis (model, posterior, controller rate [Hz]).
    options : TuneOptions

    Returns
    -------
    LoopGains
        ``export`` holds the stack's parameters, or ``export_refused`` says why not.

    Raises
    ------
    MrftError
        No design could be made (the tune's own error).
    """
    setting, refused = _setting(result, options)
    # as tune LOG does (the analysis's rate, or the assumed one stated); a stack's own rate and filter where it takes
    # the loop
    res = tune_analysis(result, kinds=(options.kind,), designs=("model-based", "robust"),
                        rate_hz=setting.rate_hz if setting is not None else options.rate_hz,
                        objective=options.objective, ms_max=options.ms_max,
                        rate_filter=setting.rate_filter if setting is not None else None)
    if setting is not None and setting.notes:
        res = dataclasses.replace(res, notes=(*setting.notes, *res.notes))
    design = recommended_design_name(res)
    gains = LoopGains(design, options.kind, res, export_refused=refused)
    st = options.stack
    if st is None or refused is not None:
        return gains
    try:
        export = export_design(st.stack, gains.controller, res.loop_model, result.loop, f"{design} {options.kind}",
                               clamp=st.clamp, hover_thrust=st.hover_thrust,
                               evidence=_evidence(result, res.notes, st.hover_source))
    except InputError as err:
        return LoopGains(design, options.kind, res, export_refused=str(err))
    return LoopGains(design, options.kind, res, export=export)


def _new_inner(analysis: AnalysisResult, inner: VehicleLoop) -> tuple[InnerLoop, str]:
    """The inner loop the outer gains are designed for: closed by its new gains when they run at the
    flight's inner rate without a stack's rate filter (which the cascade does not model), else as flown;
    and the sentence that says which."""
    flown = analysis.model.inner
    g = inner.gains
    # the cascade closes the inner loop through Tf only: new gains on a stack's rate filter are not modelled
    filtered = g is not None and g.controller.rate_filter is not None and g.controller.rate_filter.active(
        flown.controller.rate_hz)
    if g is not None and not filtered and math.isclose(g.controller.rate_hz, flown.controller.rate_hz, rel_tol=0.01):
        c = g.controller
        new = Controller(c.Kp, c.Ki, c.Kd, c.Tf, flown.controller.rate_hz)
        return (InnerLoop(flown.plant, new, flown.loop),
                f"outer gains designed for the {inner.loop} loop closed by its new gains tuned here (Kp {c.Kp:.4g}, "
                f"Kd {c.Kd:.4g}): load both")
    why = ("run through the stack's rate filter, which the cascade does not model" if filtered
           else "run at another rate or were not tuned")
    return flown, f"outer gains designed for the {inner.loop} loop as flown (its new gains {why}): keep its gains in use"


def tune_outer(analysis: AnalysisResult, inner: VehicleLoop, options: TuneOptions) -> LoopGains:
    """The outer PD on the cascade (module docstring): robust over the outer estimate's draws, within
    ``options.ms_max``; a stack export (``options.stack``) is refused: the generic gains only.

    Raises
    ------
    MrftError
        No PD meets the constraints (the cascade strategy's error: mrftcli.tune.grid.tune_grid).
    """
    closed, said = _new_inner(analysis, inner)
    model = dataclasses.replace(analysis.model, inner=closed)
    draws = outer_draws(model, analysis.identification.estimates, OUTER_DRAWS)
    assert analysis.controller_rate_hz is not None  # a cascade's analysis has its outer rate
    res: TuneResult = tune(model, analysis.controller_rate_hz, posterior=draws, loop=analysis.loop,
                           options=DesignOptions(ms_max=options.ms_max))
    res = dataclasses.replace(res, notes=(said, *res.notes))
    refused = None
    stack = None if options.stack is None else options.stack.stack
    if stack not in (None, "generic"):
        refused = (f"the {analysis.loop} loop is designed on the cascade at the flight's rate, without "
                   f"{stack}'s rate filter: export its generic gains (--export generic)")
    return LoopGains(recommended_design_name(res), "PD", res, export_refused=refused)


def joint_gyro_gains(loops: Mapping[str, VehicleLoop], options: TuneOptions) -> dict[str, VehicleLoop]:
    """Roll and pitch re-designed with ONE gyro cutoff chosen from both (PX4 ``IMU_GYRO_CUTOFF`` / ArduPilot
    ``INS_GYRO_FILTER`` filter all axes: :func:`mrftcli.tune.joint.joint_cutoff_of_analyses`).

    Only for ``--export px4|ardupilot`` without ``--gyro-cutoff`` when both loops were tuned and exported on
    the eq. (2) route at one rate; otherwise ``{}`` (the loops keep the stated default cutoff). The
    entries to replace, with the choice stated first in each loop's notes.
    """
    from ..tune.joint import GYRO_FILTER_PARAM, joint_cutoff_of_analyses

    st = options.stack
    pair = [loops.get(loop) for loop in ("roll", "pitch")]
    if st is None or st.stack not in GYRO_FILTER_PARAM or st.gyro_cutoff_hz is not None or options.kind != "PD":
        return {}
    entries = [v for v in pair if v is not None and v.route == "eq2" and v.analysis.kind == "soiptd"
               and v.gains is not None and v.gains.export is not None and isinstance(v.gains.tune, TuneResult)]
    rates = {v.gains.tune.rate_hz for v in entries if v.gains is not None}
    if len(entries) != 2 or len(rates) != 1:
        return {}
    name = GYRO_FILTER_PARAM[st.stack]
    try:
        joint = joint_cutoff_of_analyses([v.analysis for v in entries],
                                         st.stack, rates.pop(), objective=options.objective, ms_max=options.ms_max)
    except InputError:  # no cutoff suits both: the loops keep the stated default (their notes say so)
        return {}
    out = {}
    for v, res in zip(entries, joint.results):
        assert v.gains is not None
        kept = tuple(n for n in v.gains.tune.notes if not n.startswith(name))  # the default cutoff's note
        res = dataclasses.replace(res, notes=(joint.note(), *kept, *res.notes))
        try:
            export = export_design(st.stack, res.get(v.gains.design, "PD").controller, res.loop_model, v.loop,
                                   f"{v.gains.design} PD", clamp=st.clamp, evidence=_evidence(v.analysis, res.notes))
        except InputError as err:
            out[v.loop] = dataclasses.replace(v, gains=LoopGains(v.gains.design, "PD", res, export_refused=str(err)))
            continue
        out[v.loop] = dataclasses.replace(v, gains=LoopGains(v.gains.design, "PD", res, export=export))
    return out
