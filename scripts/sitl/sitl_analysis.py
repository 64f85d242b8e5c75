"""What the SITL campaign checks on a DataFlash log: tests found, held-out frequencies, the delay step.

Pure use of mrft-ident's library (``read_flight``, ``analyze_flight``, ``mask_windows``,
``mrft_limit_cycle``) on the ``ardupilot-mrft`` layout; shared by ``benchmarks/bench_sitl.py`` and
``tests/test_sitl_logs.py``.

Held out: for each test, the model is identified from the *other* tests alone (the log masked to
their windows) and predicts the held-out test's limit-cycle frequency at its nominal beta and h,
under the sampled relay at the log's rate; the error is relative to the frequency measured.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalysisResult, AnalyzeOptions, analyze_flight
from mrftcli.analyze.general import mask_windows
from mrftcli.errors import MrftError
from mrftcli.io import FlightLog, ReadOptions, read_flight
from mrftcli.mrft.lprs import mrft_limit_cycle
from mrftcli.mrft.model import LoopModel

__all__ = ["HeldOut", "analyze_log", "held_out", "test_lines"]


@dataclass(frozen=True)
class HeldOut:
    """One test predicted from the others.

    Attributes
    ----------
    index : int
        The test's position in the full analysis.
    beta, h : float
        Nominal beta and relay height of the held-out test.
    measured_hz, predicted_hz : float
        Its measured frequency and the frequency the other tests' model predicts [Hz].
    model : tuple of float
        (Td [s], tau [s], K) identified without it.
    """

    index: int
    beta: float
    h: float
    measured_hz: float
    predicted_hz: float
    model: tuple[float, float, float]

    @property
    def error(self) -> float:
        """Relative frequency error (predicted / measured - 1)."""
        return self.predicted_hz / self.measured_hz - 1.0


def _options(seed: int, refine: bool = True) -> AnalyzeOptions:
    return AnalyzeOptions(n_bootstrap=50, seed=seed, refine_waveform=refine)


def analyze_log(path: str | Path, tp: float, loop: str, seed: int = 0) -> AnalysisResult:
    """``mrft-ident analyze LOG --tp TP --loop LOOP`` as a library call."""
    flight = read_flight(path, ReadOptions(loop=loop))
    return analyze_flight(flight, soiptd_model(tp), options=_options(seed))


def held_out(path: str | Path, tp: float, loop: str, full: AnalysisResult, seed: int = 0,
             refine: bool = True, misses: list[tuple[int, str]] | None = None) -> list[HeldOut]:
    """Each test of ``full`` predicted by the model of the other tests (needs three tests or more).

    ``refine=False``: the other tests' model from their frequencies and amplitudes alone (the paper's
    MRFT estimate, faster), not the waveform refinement. ``misses``: when given, a test whose other
    tests the analysis refuses is recorded there as ``(index, reason)`` (a miss) instead of raising.
    """
    flight = read_flight(path, ReadOptions(loop=loop))
    tests = list(full.tests)
    out = []
    for i, test in enumerate(tests):
        others = [(_marked_start(flight, t.t_start), t.t_end) for j, t in enumerate(tests) if j != i]
        try:
            res = analyze_flight(mask_windows(flight, others), soiptd_model(tp), options=_options(seed, refine))
        except MrftError as err:
            if misses is None:
                raise
            misses.append((i, str(err)))
            continue
        model = LoopModel(tp, res.Td.value, res.tau.value, res.K.value)
        cycle = mrft_limit_cycle(model, test.beta_nominal, test.h, test.rate_hz)
        out.append(HeldOut(i, test.beta_nominal, test.h, test.frequency_hz_mean, cycle.frequency_hz,
                           (res.Td.value, res.tau.value, res.K.value)))
    return out


def _marked_start(flight: FlightLog, t_start: float) -> float:
    """A test's window opens at its beta marker (the last beta sample at or before its first cycle [s]).

    The stacks log beta once at a test's start (``MRFB``, a parameter change), a little before the first
    switch the segmenter dates the test from; a window cut at that switch would drop the marker, and the
    masked flight would carry the previous test's beta into it (two kept tests read as one).
    """
    if flight.beta is None:
        return t_start
    before = flight.beta.t[flight.beta.t <= t_start]
    return float(before[-1]) if before.size else t_start


def test_lines(res: AnalysisResult, held: list[HeldOut]) -> list[str]:
    """The campaign's lines under a log: each test found (beta, h, frequency [Hz], amplitude, stable cycles) and
    each held-out test's measured and predicted frequency [Hz]."""
    lines = [f"      beta {t.beta_nominal:+.2f}  h {t.h:.4f}  f {t.frequency_hz_mean:.3f} Hz  "
             f"amplitude {t.amplitude_mean:.4g}  cycles {t.n_stable}" for t in res.tests]
    return lines + [f"      held out beta {ho.beta:+.2f}: measured {ho.measured_hz:.3f} Hz, predicted "
                    f"{ho.predicted_hz:.3f} Hz ({ho.error * 100:+.2f} %)" for ho in held]
