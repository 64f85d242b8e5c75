"""The tests as diagnose sees them: the segmenter's MRFT tests with their stable cycles measured
(:func:`mrftcli.diagnose.features.cycle_table`), split into a fitting (even) and a held-out (odd) half,
plus the sample behind the period-scatter statistic (:func:`prepare_tests`).

Units: times in seconds, the output in its own units (m or rad), the command in command units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .features import N_HARM, CycleTable, cycle_table
from .scatter import scatter_sample
from ..io.logtypes import FlightLog
from ..segment import MrftTest, segment

if TYPE_CHECKING:
    from ..analyze import AnalysisResult

__all__ = ["MIN_CYCLES", "DiagnosedTest", "segments_of", "prepare_tests"]

#: fewest stable cycles per test for a diagnosis
MIN_CYCLES = 4


@dataclass
class DiagnosedTest:
    """One MRFT test as the diagnosis sees it: its settings, its stable cycles and their split.

    Built by :func:`prepare_tests` from the segmenter's :class:`~mrftcli.segment.MrftTest` (the
    test as found in the log); not to be confused with the simulator's
    :class:`~mrftcli.sim.flight.TestSpec` (a test to fly) or identify's ``TestMeasurement``.

    ``beta`` is the effective switching level per direction (up, down); ``tab`` the measured stable
    cycles; ``fit`` / ``hold`` boolean masks over them (even / odd cycles); ``bias`` the hover
    command [command units]; times in log seconds.
    """

    index: int
    h: float
    bias: float
    rate_hz: float
    beta_nominal: float | None
    beta: tuple[float, float]  # effective (up, down)
    t_start: float
    t_end: float
    tab: CycleTable
    fit: np.ndarray
    hold: np.ndarray
    has_setpoint: bool
    t0_log: float
    #: periods [s] of the cycles behind the scatter statistic (``diagnose_scatter.scatter_sample``)
    scatter_periods: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: regular cycles the segmenter found in the test (the window the scatter model reproduces)
    n_window: int = 0
    #: the relay centre of the flight's earliest test flown, diagnosed or not [command units] (the hover
    #: command a gain drift's trim error is taken against; None: the earliest of the tests given)
    first_centre: float | None = None

    def scatter_var(self, sel: str) -> tuple[float, int]:
        """Sample variance [s^2] of the scatter periods ('fit': even, 'hold': odd, else all) and their count."""
        p = self.scatter_periods
        if sel in ("fit", "hold"):
            p = p[(np.arange(p.size) % 2 == 0) == (sel == "fit")]
        return (float(np.var(p, ddof=1)) if p.size >= 3 else float("nan")), int(p.size)


def segments_of(flight: FlightLog, analysis: AnalysisResult | None) -> list[MrftTest]:
    """The MRFT tests to diagnose: the analysis' tests when it used any (its segmentation is
    reused), else :func:`mrftcli.segment.segment` of ``flight``."""
    if analysis is not None and analysis.tests:
        return list(analysis.tests)
    return list(segment(flight))


def prepare_tests(flight: FlightLog, segs: list[MrftTest]) -> tuple[list[DiagnosedTest], float, list[str]]:
    """The tests with at least :data:`MIN_CYCLES` stable cycles as :class:`DiagnosedTest`, the sensor
    noise std estimated from the cycle projections' residual [output units], and warnings."""
    warnings: list[str] = []
    t_y, y = flight.output.t, flight.output.values
    ok = np.isfinite(t_y) & np.isfinite(y)
    t_y, y = t_y[ok], y[ok]
    t0_log = float(min(np.nanmin(flight.command.t), np.nanmin(flight.output.t)))
    tests: list[DiagnosedTest] = []
    rss = 0.0
    nsamp = 0
    for s in segs:
        st = [c for c in s.cycles if c.stable]
        if len(st) < MIN_CYCLES:
            warnings.append(
                f"test {s.index + 1} (beta {s.beta:.2f}) has {len(st)} stable cycles; the diagnosis needs "
                f"{MIN_CYCLES}, so it is left out"
            )
            continue
        r = s.setpoint if s.setpoint is not None else None
        has_sp = r is not None
        if r is None:
            # without a setpoint the relay's reference is unknown: take the oscillation centre
            r = float(np.median([c.centre for c in st]))
        yy = s.loop_sign * (y - r) if s.setpoint is not None else s.loop_sign * (y - r)
        tab = cycle_table(t_y, yy, s.h, [c.t_start for c in st], [c.t_switch for c in st], [c.t_end for c in st])
        good = np.isfinite(tab.amplitude) & (tab.amplitude > 0)
        tab, sparse = tab.subset(good), int(np.sum(tab.n_samples < 2 * N_HARM + 4))
        if len(tab) < MIN_CYCLES:  # a cycle with fewer output samples than the harmonic fit's unknowns is not measured
            warnings.append(
                f"test {s.index + 1} (beta {s.beta:.2f}): {len(tab)} of its {len(st)} stable cycles can be measured "
                f"({sparse} have fewer than the {2 * N_HARM + 4} output samples a cycle the waveform fit needs"
                + ("; log the output faster" if sparse else "") + f"); the diagnosis needs {MIN_CYCLES}, so it is left out"
            )
            continue
        idx = np.arange(len(tab))
        b_up = float(np.nanmedian(tab.beta_up))
        b_dn = float(np.nanmedian(tab.beta_dn))
        if not (-1 < b_up < 1 and -1 < b_dn < 1):
            b_up = b_dn = float(s.beta)
        rss += float(tab.resid_ss.sum())
        nsamp += int(tab.n_samples.sum()) - len(tab) * (2 * N_HARM + 2)
        P_all = np.array([c.period for c in s.cycles], float)
        A_all = np.array([c.amplitude for c in s.cycles], float)
        reg_all = np.array([c.regular for c in s.cycles], bool)
        keep = scatter_sample(P_all, A_all, reg_all, 1.0 / float(s.rate_hz))
        tests.append(
            DiagnosedTest(
                index=s.index,
                h=float(s.h),
                bias=float(s.bias),
                rate_hz=float(s.rate_hz),
                beta_nominal=None if s.beta_nominal is None else float(s.beta_nominal),
                beta=(b_up, b_dn),
                t_start=float(tab.start[0]),
                t_end=float(tab.end[-1]),
                tab=tab,
                fit=idx % 2 == 0,
                hold=idx % 2 == 1,
                has_setpoint=has_sp,
                t0_log=t0_log,
                scatter_periods=P_all[keep],
                n_window=int(reg_all.sum()),
            )
        )
    noise = math.sqrt(rss / nsamp) if nsamp > 0 else 0.0
    return tests, noise, warnings
