"""One residual test of eq. (2) on a log, and its one verdict, for ``analyze`` and ``diagnose`` alike.

``analyze`` fits eq. (2) to the waveform (:func:`mrftcli.mrft.refine.refine`): a residual RMS above
:data:`~mrftcli.mrft.refine.RESIDUAL_FACTOR` times the sensor noise says the recording holds what eq.
(2) leaves out, *when the sample instants are known*. With receive-time stamps the residual also holds
the transport's jitter (a 90 Hz output off the controller's ticks is sampled at unknown instants), so
it cannot tell timing from dynamics: the verdict is then ``untestable`` and ``diagnose``'s test on the
cycles' features decides. Both commands word the outcome with :func:`residual_verdict`, so they
cannot contradict each other (issue 40: on ``hear_x.bag`` analyze said "dynamics eq. (2) leaves out"
while diagnose found the linear model explains the log; the log is simulated linear, receive-stamped).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..mrft.refine import RESIDUAL_FACTOR

if TYPE_CHECKING:
    from .record import AnalysisResult

__all__ = ["ResidualVerdict", "residual_verdict", "RESIDUAL_VERDICTS", "MISMATCH_WORDS"]

#: ``explained`` (residual noise-like), ``mismatch`` (the recording holds what eq. (2) leaves out),
#: ``untestable`` (receive-time stamps: the residual cannot tell timing from dynamics).
RESIDUAL_VERDICTS = ("explained", "mismatch", "untestable")
#: The words :func:`mrftcli.mrft.refine.refine` gives a residual above the factor (replaced where untestable).
MISMATCH_WORDS = "the recording holds dynamics eq. (2) leaves out"


@dataclass(frozen=True)
class ResidualVerdict:
    """The verdict of the waveform residual on eq. (2).

    ``verdict`` is one of :data:`RESIDUAL_VERDICTS`; ``ratio`` the residual RMS over the sensor noise;
    ``sentence`` the words both commands print.
    """

    verdict: str
    ratio: float
    sentence: str


#: receive stamps whose jitter is below this [s] carry no transport jitter: a recorder's clock on the
#: publisher's ticks (a converter that wrote the source's times; float64 epoch seconds resolve 0.24 us),
#: so the residual can tell dynamics there (real transports jitter by tens of us to ms)
NO_JITTER_S = 1e-6


def _receive_stamped(result: AnalysisResult) -> bool:
    """Whether the residual may hold the transport's timing jitter: receive stamps that jitter."""
    stamps: object
    jitter: object
    if result.flight is not None:
        timing = result.flight.timing
        stamps, jitter = timing.stamps, timing.timing_jitter_s
    else:
        source = result.log_info.source if result.log_info is not None else {}
        stamps, jitter = source.get("timestamps"), source.get("timing_jitter_s")
    if stamps != "receive":
        return False
    return not (isinstance(jitter, (int, float)) and math.isfinite(jitter) and jitter < NO_JITTER_S)


def _ratio(result: AnalysisResult) -> float | None:
    if result.refinement is not None:
        return float(result.refinement.residual_ratio)
    recorded = (result.recorded or {}).get("refinement") or {}
    ratio = recorded.get("residual_ratio") if isinstance(recorded, dict) else None
    return float(ratio) if isinstance(ratio, (int, float)) and math.isfinite(ratio) else None


def residual_verdict(result: AnalysisResult) -> ResidualVerdict | None:
    """The waveform residual's verdict on eq. (2) for an analysis (None when the refinement did not run).

    Examples
    --------
    >>> from pathlib import Path
    >>> from mrftcli.analyze import AnalyzeOptions, analyze_path
    >>> from mrftcli.mrft.model import soiptd_model
    >>> log = Path(__file__).parents[2] / "sample_logs" / "design1_altitude.mcap"
    >>> residual_verdict(analyze_path(log, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=50))).verdict
    'explained'
    """
    ratio = _ratio(result)
    if ratio is None:
        return None
    if ratio <= RESIDUAL_FACTOR:
        return ResidualVerdict("explained", ratio, f"the waveform residual is {ratio:.2f}x the sensor noise: eq. (2) "
                                                   "explains the recording")
    if _receive_stamped(result):
        return ResidualVerdict("untestable", ratio, (
            f"the waveform residual is {ratio:.2f}x the sensor noise, but with receive-time stamps it holds the "
            "transport's timing jitter too, so it cannot tell timing from dynamics eq. (2) leaves out: the "
            "cycles' features decide (diagnose)"))
    return ResidualVerdict("mismatch", ratio, f"the waveform residual is {ratio:.2f}x the sensor noise (accepted up "
                                              f"to {RESIDUAL_FACTOR:g}x): {MISMATCH_WORDS}")
