"""What the SITL campaign checks on a DataFlash log: tests found, held-out frequencies, the delay step.

Pure use of mrft-ident's library (``read_flight``, ``analyze_flight``, ``mask_windows``,
``mrft_limit_cycle``) on the ``ardupilot-mrft`` layout; shared by ``benchmarks/bench_sitl.py`` and
``tests/test_sitl_logs.py``.

Held out: for each test, the model is identified from the *other* tests alone (the log masked to
their windows) and predicts the held-out test's limit-cycle frequency at its nominal beta and h,
under the sampled relay at the log's rate; the error is relative to the frequency measured.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalysisResult, AnalyzeOptions, analyze_flight
from mrftcli.analyze.general import mask_windows
from mrftcli.errors import MrftError
from mrftcli.io import FlightLog, ReadOptions, read_flight
from mrftcli.mrft.lprs import mrft_limit_cycle
from mrftcli.mrft.model import LoopModel

__all__ = ["HeldOut", "analyze_log", "held_out", "test_lines", "orbit_band", "held_out_frequencies",
           "tau_needed", "matched_betas", "band_centre_hz", "half_period_ticks", "extrapolation_range",
           "held_out_known_td"]


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
    masked flight would carry the previous kept test's beta, the marker in force there, into it.
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


def orbit_band(tp: float, ho: HeldOut, rate_hz: float) -> tuple[float, float, float]:
    """The held-out model's admissible sampled-relay orbits for the held-out test (``mrft_limit_cycle``'s
    ``orbits_hz``: every symmetric periodic orbit the MRFT at ``rate_hz`` can lock onto, of which the centre
    is the prediction): (lowest [Hz], highest [Hz], the error of the orbit nearest the measured frequency)."""
    cycle = mrft_limit_cycle(LoopModel(tp, *ho.model), ho.beta, ho.h, rate_hz)
    orbits = sorted(cycle.orbits_hz) or [cycle.frequency_hz]
    nearest = min(orbits, key=lambda f: abs(f - ho.measured_hz))
    return orbits[0], orbits[-1], nearest / ho.measured_hz - 1.0


def held_out_frequencies(tp: float, rate_hz: float, tests: list[tuple[float, float]],
                         freqs: list[float]) -> list[float]:
    """Each test's frequency predicted from the others' frequencies alone (eq. (2)'s Td and tau fitted to
    them by least squares at the sampled relay's centre; K does not move a relay's frequency): the relative
    errors, predicted / measured - 1. For frequencies that carry no amplitudes (a simulation's)."""
    from scipy.optimize import least_squares

    def centre(p: np.ndarray, beta: float, h: float) -> float:
        return mrft_limit_cycle(LoopModel(tp, float(p[0]), float(p[1]), 1.0), beta, h, rate_hz).frequency_hz

    errors = []
    for i, (beta, h) in enumerate(tests):
        others = [(b, hh, f) for j, ((b, hh), f) in enumerate(zip(tests, freqs)) if j != i]
        def residuals(p: np.ndarray, others: list[tuple[float, float, float]] = others) -> list[float]:
            return [math.log(centre(p, b, hh) / f) for b, hh, f in others]

        fit = least_squares(residuals, [0.5, 0.003], bounds=([0.02, 0.0], [100.0, 0.5]), x_scale=[0.1, 0.001])
        errors.append(centre(fit.x, beta, h) / freqs[i] - 1.0)
    return errors


def band_centre_hz(tp: float, Td: float, tau: float, beta: float, h: float, rate_hz: float) -> float:
    """The sampled relay's band centre [Hz]: eq. (2)'s continuous cycle with half a tick more delay, the value
    ``mrft_limit_cycle(..., rate_hz).frequency_hz`` returns, without solving the orbits (K moves no frequency)."""
    return mrft_limit_cycle(LoopModel(tp, Td, tau + 0.5 / rate_hz, 1.0), beta, h).frequency_hz


def _fit_delays(tp: float, rate_hz: float, groups: list[list[tuple[float, float, float]]]) -> np.ndarray:
    """Td and one delay per group of tests (beta, h, frequency [Hz]) fitted to their frequencies at the band
    centre (least squares on log frequency): [Td, tau_1, tau_2, ...] [s]."""
    from scipy.optimize import least_squares

    def residuals(p: np.ndarray) -> list[float]:
        return [math.log(band_centre_hz(tp, float(p[0]), float(p[1 + g]), b, h, rate_hz) / f)
                for g, tests in enumerate(groups) for b, h, f in tests]

    n = len(groups)
    return least_squares(residuals, [0.5] + [0.003] * n, bounds=([0.02] + [0.0] * n, [100.0] + [0.5] * n),
                         x_scale=[0.1] + [0.001] * n).x


def extrapolation_range(tp: float, rate_hz: float, tests: list[tuple[float, float]], freqs: list[float], i: int,
                        step: float = 0.02) -> tuple[float, float]:
    """How far test ``i``'s held-out prediction moves when the other tests' measured frequencies move by
    ``step`` (relative) each way, every sign combination: (lowest, highest) relative error against its own
    measured frequency. Td and tau fitted to the moved frequencies alone at the band centre (as
    :func:`held_out_frequencies`): the amplification of a frequency offset by the model's extrapolation."""
    others = [j for j in range(len(tests)) if j != i]
    errs = []
    for signs in np.array(np.meshgrid(*[[-1.0, 1.0]] * len(others))).T.reshape(-1, len(others)):
        moved = [(tests[j][0], tests[j][1], freqs[j] * (1.0 + s * step)) for j, s in zip(others, signs)]
        Td, tau = _fit_delays(tp, rate_hz, [moved])
        errs.append(band_centre_hz(tp, Td, tau, tests[i][0], tests[i][1], rate_hz) / freqs[i] - 1.0)
    return min(errs), max(errs)


def held_out_known_td(tp: float, rate_hz: float, tests: list[tuple[float, float]], freqs: list[float],
                      Td: float) -> list[float]:
    """Each test's frequency predicted from the others' with Td given (only tau fitted to them, at the band
    centre): the relative errors, predicted / measured - 1. Against :func:`held_out_frequencies`, what is
    left when Td need not be extrapolated from the other tests."""
    from scipy.optimize import least_squares

    errors = []
    for i, (beta, h) in enumerate(tests):
        others = [(b, hh, f) for j, ((b, hh), f) in enumerate(zip(tests, freqs)) if j != i]
        fit = least_squares(lambda p, o=others: [math.log(band_centre_hz(tp, Td, float(p[0]), b, hh, rate_hz) / f)
                                                 for b, hh, f in o], [0.003], bounds=([0.0], [0.5]))
        errors.append(band_centre_hz(tp, Td, float(fit.x[0]), beta, h, rate_hz) / freqs[i] - 1.0)
    return errors


def half_period_ticks(t: np.ndarray, relay: np.ndarray, t_start: float, t_end: float, rate_hz: float,
                      skip: int = 4) -> np.ndarray:
    """The relay's half periods [ticks] between ``t_start`` and ``t_end`` [s] (its output's sign changes, the
    first ``skip`` left out as the start kick's): a test locked onto one sampled-relay orbit repeats one
    value; one that hops among the admissible orbits spreads over several."""
    sel = (t >= t_start) & (t <= t_end)
    sw = np.flatnonzero(np.diff(np.sign(relay[sel]))) + 1
    return np.rint(np.diff(t[sel][sw[skip:]]) * rate_hz).astype(int)


def tau_needed(test, tp: float, Td: float, K: float) -> float:
    """The delay [s] with which eq. (2) (Td, K and the known Tp) limit-cycles at the test's measured frequency
    under its beta, h and sampling; below 0 (a loop with less lag than Tp and Td give) by linear extrapolation
    of the frequency from tau 0 and 1 ms (eq. (2) holds tau >= 0)."""
    from scipy.optimize import brentq

    from mrftcli.mrft.lprs import mrft_limit_cycle
    from mrftcli.mrft.model import LoopModel

    def miss(tau: float) -> float:
        model = LoopModel(tp, Td, tau, K)
        return mrft_limit_cycle(model, test.beta_nominal, test.h, test.rate_hz).frequency_hz - test.frequency_hz_mean

    m0 = miss(0.0)
    if m0 < 0:  # the loop is faster than eq. (2) with no delay allows
        return float(m0 / (m0 - miss(1e-3)) * 1e-3)
    return float(brentq(miss, 0.0, 0.2))


def matched_betas(reference: Path, plain: Path, delay_s: float) -> list[tuple[float, float]]:
    """Betas (with each test's h) for which the reference flight's identified model, with ``delay_s`` added,
    limit-cycles at the plain flight's measured frequencies: the delayed flight of a matched-frequency pair."""
    from scipy.optimize import brentq

    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.lprs import mrft_limit_cycle
    from mrftcli.mrft.model import LoopModel
    from mrftcli.segment import segment

    tp = json.loads(Path(f"{reference}.json").read_text())["tp_s"]
    ref = analyze_log(reference, tp, "altitude")
    model = LoopModel(tp, ref.Td.value, ref.tau.value + delay_s, ref.K.value)
    out = []
    for t in segment(read_flight(plain, ReadOptions(loop="altitude"))):
        beta = brentq(lambda b, t=t: mrft_limit_cycle(model, b, t.h, t.rate_hz).frequency_hz - t.frequency_hz_mean,
                      -0.95, -0.01)
        out.append((round(float(beta), 3), round(float(t.h), 3)))
    return out
