"""The forecast: the predicted stds over the draws (analytic), and by simulated flights (Monte Carlo)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..mrft.model import LoopModel
from ..progress import Progress, report
from .fisher import posterior_covariance, posterior_stds
from .noise import LOST_CYCLES
from .records import PARAMS, FlownTest, PlanLimits, TestPlan

__all__ = ["std_median", "std_range", "simulated_flights", "SimulatedForecast",
           "simulated_forecast"]


def _stds_over_draws(infos: Sequence[np.ndarray], plants: np.ndarray) -> list[np.ndarray]:
    return [posterior_stds(posterior_covariance(A), p) for A, p in zip(infos, plants)]


def std_median(infos: Sequence[np.ndarray], plants: np.ndarray) -> dict[str, float]:
    """Td, tau [s], K: the median over the draws of the std the information ``infos[k]`` leaves on
    plant ``plants[k]``.

    The median is the typical plant's std. The mean (or RMS) is pulled up by the draws with the
    slowest drag, whose Td std grows about as Td^2, so it over-forecasts most plants.
    """
    s = np.percentile(_stds_over_draws(infos, plants), 50.0, axis=0)
    return dict(zip(PARAMS, map(float, s)))


def std_range(infos: Sequence[np.ndarray], plants: np.ndarray) -> dict[str, tuple[float, float]]:
    """Td, tau [s], K -> the 10-90 % range over the draws of the std (see :func:`std_median`)."""
    s = np.percentile(_stds_over_draws(infos, plants), (10.0, 90.0), axis=0)
    return {k: (float(lo), float(hi)) for k, lo, hi in zip(PARAMS, s[0], s[1])}


def simulated_flights(model: LoopModel, plants: np.ndarray, flown: Sequence[FlownTest], tests: Sequence[TestPlan],
                      limits: PlanLimits, *, n_bootstrap: int = 100, seed: int = 0,
                      progress: Progress | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Forecast by simulation: fly the flown and planned tests on each plant and measure analyze's std.

    For each plant (rows Td [s], tau [s], K) the project's simulator (:func:`mrftcli.sim.simulate_flight`,
    exact sampled MRFT rule at ``limits.rate_hz``, white sensor noise ``limits.noise_std``) flies the
    flown tests (their beta and h, their stable cycles plus the transient) and then ``tests``; the
    flight is analysed as ``analyze`` does without the waveform refinement, and the bootstrap std
    of its MRFT estimate is kept. Everything the analytic noise model approximates (the sampled
    relay hopping between orbits, switch jitter, the segmenter's choices) is then in the forecast.

    Parameters
    ----------
    model : LoopModel
        Eq. (2) with its known propulsion time constant Tp [s] (``soiptd_model(Tp)``); analysed as given.
    plants : ndarray, shape (n, 3)
        The plants to fly (Td, tau, K), e.g. draws from what the flown tests leave.
    flown, tests : sequences of FlownTest and TestPlan
        The tests flown so far and the planned ones, in flying order.
    limits : PlanLimits
        Controller rate and sensor noise of the flight.
    n_bootstrap : int
        Bootstrap draws per analysis.
    seed : int
        Seed of the noise and of the bootstrap.
    progress : Progress, optional
        Called as ``progress(done, n, "simulating")`` per plant.

    Returns
    -------
    std : ndarray, shape (n, 3)
        std of Td [s], tau [s], K per plant; NaN where ``analyze`` could not use the simulated flight
        (it locked up on noise, or a test was lost).
    lost : ndarray of bool, shape (n, len(tests))
        True where the planned test was not among the tests analyze used (every test of a flight
        analyze refused as a whole).
    """
    from ..analyze import AnalyzeOptions, analyze_flight
    from ..errors import MrftError
    from ..io.logtypes import FlightLog, Signal
    from ..sim import FlightSpec, TestSpec, simulate_flight

    specs = [TestSpec(f.beta, f.h, (f.n_cycles + LOST_CYCLES) / f.frequency_hz) for f in flown]
    specs += [TestSpec(t.beta, t.h, t.duration_s) for t in tests]
    rng = np.random.default_rng(seed)
    out = np.full((len(plants), 3), np.nan)
    lost = np.ones((len(plants), len(tests)), bool)
    for k, p in enumerate(plants):
        plant = LoopModel(model.Tp, float(p[0]), float(p[1]), float(p[2]))
        try:
            sf = simulate_flight(FlightSpec(model=plant, tests=tuple(specs), rate_hz=limits.rate_hz,
                                            noise_std=limits.noise_std, seed=int(rng.integers(1 << 30)),
                                            hover_s=2.0, hold_s=2.0))
            flight = FlightLog(path="<simulated>", loop=sf.spec.loop, command=Signal(sf.t, sf.command),
                               output=Signal(sf.t, sf.output_measured), setpoint=Signal(sf.t, sf.setpoint))
            with np.errstate(all="ignore"):
                res = analyze_flight(flight, model, options=AnalyzeOptions(
                    n_bootstrap=n_bootstrap, refine_waveform=False, seed=int(rng.integers(1 << 30))))
            lost[k] = [not any(abs(m.beta_effective - t.beta) < 0.1 for m in res.tests) for t in tests]
            # a planned test analyze lost counts as no forecast (its std would be the flown tests')
            if not lost[k].any():
                out[k] = (res.Td.std, res.tau.std, res.K.std)
        except MrftError:
            pass
        report(progress, k + 1, len(plants), "simulating")
    return out, lost


@dataclass(frozen=True)
class SimulatedForecast:
    """The simulated forecast of a plan (empty when no flight was usable or none was asked for).

    Attributes
    ----------
    std, std_range : dict
        Td, tau [s], K: median and 10-90 % range of analyze's bootstrap std over the usable flights.
    n_used : int
        Simulated flights analyze could use.
    note : str or None
        What to tell the user when some flights were lost.
    lost : tuple of int
        Per planned test, the simulated flights on which analyze lost it.
    """

    std: dict[str, float]
    std_range: dict[str, tuple[float, float]]
    n_used: int
    note: str | None = None
    lost: tuple[int, ...] = ()


def simulated_forecast(model: LoopModel, plants: np.ndarray, flown: Sequence[FlownTest], tests: Sequence[TestPlan],
                       limits: PlanLimits, n_simulated: int, *, seed: int,
                       progress: Progress | None = None) -> SimulatedForecast:
    """:func:`simulated_flights` on the first ``n_simulated`` of ``plants``, summarised over the usable flights."""
    s, lost = simulated_flights(model, plants[:n_simulated], flown, tests, limits, seed=seed, progress=progress)
    s = s[np.all(np.isfinite(s), axis=1)]
    n_sim = int(s.shape[0])
    std: dict[str, float] = {}
    rng: dict[str, tuple[float, float]] = {}
    if n_sim:
        std = dict(zip(PARAMS, map(float, np.median(s, axis=0))))
        lo, hi = np.percentile(s, [10.0, 90.0], axis=0)
        rng = {k: (float(a), float(b)) for k, a, b in zip(PARAMS, lo, hi)}
    note = None
    if n_sim < n_simulated:
        note = (f"analyze could not use the simulated flight of {n_simulated - n_sim} of "
                f"{n_simulated} plants (lost or locked-up tests): the test may fail on noise")
    return SimulatedForecast(std, rng, n_sim, note, tuple(int(n) for n in lost.sum(axis=0)))
