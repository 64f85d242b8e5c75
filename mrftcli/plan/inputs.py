"""What the planner reads: flown tests from the segmenter's records or an ``analyze --json`` result,
and prior ranges from identified parameters."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InputError
from .noise import MIN_CYCLES
from .records import FlownTest

if TYPE_CHECKING:
    from ..mrft.identify import ParameterEstimate
    from ..segment.records import MrftTest

__all__ = ["flown_from_segments", "flown_from_result", "noise_from_result", "prior_range"]


def flown_from_segments(tests: Sequence[MrftTest]) -> tuple[tuple[FlownTest, ...], float | None]:
    """The flown tests of :func:`mrftcli.segment.segment` (``MrftTest`` records) and their sensor noise.

    Tests with fewer than 3 stable cycles are left out. Returns the tests and the median per-cycle
    residual noise of the segmenter's cycle fits [output units] (None when none was measured).
    """
    from ..analyze import measured_noise_std

    out: list[FlownTest] = []
    kept = []
    for t in tests:
        if t.n_stable < MIN_CYCLES or not np.isfinite(t.beta_effective):
            continue
        ph = np.array([c.phase_h1 for c in t.stable], float)
        ph = ph[np.isfinite(ph)]
        out.append(FlownTest(beta=float(t.beta_effective), h=float(t.h), frequency_hz=float(t.frequency_hz_mean),
                             amplitude=float(t.amplitude_mean), n_cycles=int(t.n_stable),
                             phase=float(ph.mean()) if ph.size >= 2 else None))
        kept.append(t)
    return tuple(out), measured_noise_std(kept)


def flown_from_result(data: object) -> tuple[list[FlownTest], dict[str, ParameterEstimate]]:
    """The flown tests and the identified Td, tau, K (``{}`` if none) of an ``analyze --json`` result.

    ``data`` is the parsed JSON: a result, read through
    :meth:`mrftcli.analyze.AnalysisResult.from_json`, or the exit-6 object of a single-beta log, whose
    ``partial`` tests count too.

    Raises
    ------
    InputError
        Not a JSON object, not an analyze result (its one-line reason), a partial test without beta,
        h, frequency_hz, amplitude or cycles, or no test.
    """
    if not isinstance(data, dict):
        raise InputError("not an analyze --json result (expected a JSON object)")
    if "parameters" not in data and isinstance(data.get("partial"), dict):
        flown, params = _partial_tests(data["partial"]), {}
    else:
        from ..analyze import AnalysisResult

        result = AnalysisResult.from_json(data)
        # the tests as the log gives them (effective beta, the fundamental's phase): one plan for a log and its JSON
        flown = list(flown_from_segments(result.tests)[0])
        params = {"Td": result.Td, "tau": result.tau, "K": result.K}
    if not flown:
        raise InputError("no MRFT test in this JSON (give the output of 'mrft-ident analyze --json')")
    return flown, params


def noise_from_result(data: object) -> float | None:
    """The sensor noise std [output units] an ``analyze --json`` result measured: its ``noise.std``
    (schema 2), else the median residual of its tests' stable cycle fits (schema 1), as
    :func:`flown_from_segments` measures it from the log; None when neither is there."""
    if not isinstance(data, dict):
        return None
    if "parameters" not in data:  # the exit-6 object of a single-beta log: its partial's noise, if recorded
        partial = data.get("partial")
        data = partial if isinstance(partial, dict) else {}
    noise = data.get("noise")
    if isinstance(noise, dict) and isinstance(noise.get("std"), (int, float)) and noise["std"] > 0:
        return float(noise["std"])
    if "parameters" not in data:
        return None
    from ..analyze import AnalysisResult, measured_noise_std

    return measured_noise_std(AnalysisResult.from_json(data).tests)


def _partial_tests(partial: Mapping[str, Any]) -> list[FlownTest]:
    """The tests of analyze's partial (single-beta) result: its ``tests`` rows, read by their keys
    (the exit-6 object is an error report, not an :class:`~mrftcli.analyze.AnalysisResult`)."""
    flown = []
    for t in partial.get("tests") or []:
        try:
            flown.append(FlownTest(beta=float(t["beta"]), h=float(t["h"]), frequency_hz=float(t["frequency_hz"]),
                                   amplitude=float(t["amplitude"]), n_cycles=int(t["cycles"])))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"a test lacks beta, h, frequency_hz, amplitude or cycles ({err})") from err
    return flown


def prior_range(estimate: ParameterEstimate | None, default: tuple[float, float]) -> tuple[float, float]:
    """A prior range from an identified parameter: value +/- 2 std, its low end kept above value / 10
    (a range must stay positive); ``default`` without a usable estimate (none, or a std that is not
    a positive number).

    Examples
    --------
    >>> from mrftcli.mrft.identify import ParameterEstimate
    >>> prior_range(ParameterEstimate(1.0, 0.1, 0.8, 1.2, "s"), (0.2, 3.0))
    (0.8, 1.2)
    >>> prior_range(None, (0.2, 3.0))
    (0.2, 3.0)
    """
    if estimate is not None and math.isfinite(estimate.std) and estimate.std > 0 and estimate.value > 0:
        m, s = float(estimate.value), float(estimate.std)
        return (max(m - 2 * s, m / 10), m + 2 * s)
    return default
