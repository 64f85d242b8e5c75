"""An outer loop (x, y) of the vehicle through its closed inner loop, and its gains on the cascade.

The inner loop is the one identified in the same flight (roll for y, pitch for x) closed by the
controller that flew it during the outer tests (``--inner-gains``); the outer loop is identified
through the exact sampled cascade (:func:`mrftcli.analyze.cascade.analyze_cascade`, the inner model's
uncertainty carried by draws). The outer PD is then designed on the cascade closed by the inner
loop's *new* gains, the ones tuned in the same run (robust over the outer estimate's draws,
:func:`mrftcli.tune.design.tune`): the vehicle is flown with both sets loaded.
"""

from __future__ import annotations

import dataclasses
import math

from ..analyze import AnalyzeOptions, CascadeOptions, analyze_flight
from ..analyze.cascade import cascade_model, inner_draws, inner_loop_of
from ..analyze.record import AnalysisResult
from ..io import FlightLog
from ..mrft.cascade import InnerLoop
from ..mrft.controller import Controller
from ..tune.grid import outer_draws
from ..tune.design import DesignOptions, TuneResult, tune
from .record import LoopGains, VehicleLoop

__all__ = ["OuterOptions", "cascade_outer", "tune_outer", "OUTER_DRAWS"]

#: Draws of the outer estimate the robust outer design holds its margins on (as ``tune`` on a cascade).
OUTER_DRAWS = 30


@dataclasses.dataclass(frozen=True)
class OuterOptions:
    """How an outer loop is identified through the cascade and tuned on it.

    Attributes
    ----------
    commanded : {"acceleration", "attitude", "identify"}
        What the outer relay commands (``--outer-command``; stated in the assumptions).
    inner_draws : int
        Draws of the inner model solved to carry its uncertainty into the outer estimate.
    min_stable_cycles : int
        Fewest stable cycles for an outer test to be used.
    ms_max : float
        Limit on the outer loop's sensitivity peak.
    stack : str or None
        The ``--export`` asked for (the cascade route exports the generic form only).
    """

    commanded: str = "acceleration"
    inner_draws: int = 30
    min_stable_cycles: int = 3
    ms_max: float = 1.6
    stack: str | None = None


def cascade_outer(flight: FlightLog, inner: VehicleLoop, controller: Controller,
                  options: OuterOptions) -> AnalysisResult:
    """The outer loop of ``flight`` through ``inner`` closed by ``controller`` (the gains flown).

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
    return analyze_flight(flight, cascade_model(loop, options.commanded),
                          options=AnalyzeOptions(min_stable_cycles=options.min_stable_cycles, cascade=copts))


def _new_inner(analysis: AnalysisResult, inner: VehicleLoop) -> tuple[InnerLoop, str]:
    """The inner loop the outer gains are designed for: closed by its new gains when they run at the
    flight's inner rate, else as flown; and the sentence that says which."""
    flown = analysis.model.inner
    g = inner.gains
    if g is not None and math.isclose(g.controller.rate_hz, flown.controller.rate_hz, rel_tol=0.01):
        c = g.controller
        new = Controller(c.Kp, c.Ki, c.Kd, c.Tf, flown.controller.rate_hz)
        return (InnerLoop(flown.plant, new, flown.loop),
                f"outer gains designed for the {inner.loop} loop closed by its new gains tuned here (Kp {c.Kp:.4g}, "
                f"Kd {c.Kd:.4g}): load both")
    return flown, (f"outer gains designed for the {inner.loop} loop as flown (its new gains run at another rate or "
                   "were not tuned): keep its gains in use")


def tune_outer(analysis: AnalysisResult, inner: VehicleLoop, options: OuterOptions) -> LoopGains:
    """The outer PD on the cascade (module docstring): robust over the outer estimate's draws.

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
    design = "robust" if any(d.name == "robust" for d in res.designs) else "model-based"
    refused = None
    if options.stack not in (None, "generic"):
        refused = (f"the {analysis.loop} loop is designed on the cascade at the flight's rate, without "
                   f"{options.stack}'s rate filter: export its generic gains (--export generic)")
    return LoopGains(design, "PD", res, export_refused=refused)
