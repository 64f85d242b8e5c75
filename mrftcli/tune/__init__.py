"""Controller gains from the identified model (``mrft-ident tune``): designs, margins, sampled closed loop, export."""

from .closed_loop import Controller, StepMetrics, simulate_step, step_metrics, step_response
from .design import DESIGNS, KINDS, OBJECTIVES, Design, DesignOptions, Posterior, TuneResult, mrft_rule, tune
from .margins import LoopMargins, Margins, loop_margins, margins

__all__ = ["Controller", "StepMetrics", "simulate_step", "step_metrics", "step_response", "DESIGNS", "KINDS",
           "OBJECTIVES", "Design", "DesignOptions", "Posterior", "TuneResult", "mrft_rule", "tune", "LoopMargins", "Margins",
           "loop_margins", "margins"]
