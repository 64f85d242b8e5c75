"""Profile the output-error fit over a "known" parameter: does the recording fit another Tp better?

Tp is given, not identified (the paper's bench test), so a slip of a decimal goes into Td, tau and K
and comes out as a tight, wrong model: Tp = 4.22 ms instead of 42.2 ms gives tau 82 ms instead of
46 ms, with a 95 % interval of +-1 ms (issue 26). The waveform carries information about Tp: the
fast pole shapes the output between the switches, and eq. (2) with the wrong Tp cannot follow it,
so the output-error residual rejects the model.

Method: for Tp on a grid, Td, tau and K are refitted by output error
(:func:`~mrftcli.mrft.refine.fit_output_error`, each started from the previous point), giving the
profile RSS(Tp), over the Tp that stay the fast pole (Tp < Td: eq. (2) is symmetric in Tp and Td up
to K's scale, so the swapped plant fits as well). Coarse: :data:`GRID_FACTORS` times the given Tp (log-spaced, 1/10 to 10), then a
bounded scalar refinement of ln Tp between the best point's neighbours. With white sensor noise
the profile deviance is ``n ln(RSS(Tp) / RSS_min)`` (n output samples); the interval is where it
stays below 3.84 (chi-square, 1 degree of freedom, 95 %), from the curvature at the minimum. It is
run only when the residual rejects the model (:func:`mrftcli.mrft.refine.refine`), about 30 fits.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from .model import LoopModel
from .refine import RESIDUAL_FACTOR, loop_model_bounds, loop_model_plant, fit_output_error, sensor_noise
from .waveform import CommandWindow

__all__ = ["TpProfile", "profile_tp", "tp_not_checkable", "td_below_tp", "BELOW_CONTROLLER_RATE", "GRID_FACTORS", "CHI2_95"]

#: Factors of the given Tp on the coarse grid (log-spaced, 1/10 to 10).
GRID_FACTORS = tuple(float(f) for f in np.logspace(-1.0, 1.0, 9))
#: 95 % point of the chi-square distribution with one degree of freedom.
CHI2_95 = 3.841458820694124


@dataclass(frozen=True)
class TpProfile:
    """Outcome of :func:`profile_tp`.

    Attributes
    ----------
    given : float
        The Tp the analysis was given [s].
    best : float
        The Tp the recording fits best [s].
    low, high : float
        Its 95 % profile interval [s].
    residual_ratio_given, residual_ratio_best : float
        Residual RMS over the sensor noise at the given and at the best Tp.
    grid : tuple of (float, float)
        (Tp [s], residual ratio) at every Tp fitted.
    """

    given: float
    best: float
    low: float
    high: float
    residual_ratio_given: float
    residual_ratio_best: float
    grid: tuple[tuple[float, float], ...]

    @property
    def rejects_given(self) -> bool:
        """The given Tp lies outside the interval and the best Tp makes the model hold (ratio within
        :data:`~mrftcli.mrft.refine.RESIDUAL_FACTOR`, or at least halves the residual)."""
        outside = not self.low <= self.given <= self.high
        holds = self.residual_ratio_best <= max(RESIDUAL_FACTOR, 0.5 * self.residual_ratio_given)
        return outside and holds

    @property
    def holds_nowhere(self) -> bool:
        """Eq. (2) leaves the residual above :data:`~mrftcli.mrft.refine.RESIDUAL_FACTOR` times the noise
        at every Tp fitted: the waveform cannot tell a right Tp from a wrong one."""
        return self.residual_ratio_best > RESIDUAL_FACTOR

    def message(self) -> str:
        """The one line the user reads (Tp in seconds, the residuals as multiples of the noise)."""
        return (f"the recording fits Tp = {self.best:.3g} s [{self.low:.3g}, {self.high:.3g}] better than the given "
                f"{self.given:.3g} s (waveform residual {self.residual_ratio_best:.2f}x the sensor noise against "
                f"{self.residual_ratio_given:.2f}x): check --tp; Td, tau and K rest on it")

    def warnings(self) -> tuple[str, ...]:
        """What the analysis says about the given Tp: :meth:`message` where the recording names another
        Tp, :func:`tp_not_checkable` where eq. (2) holds at no Tp, nothing where the given one fits."""
        if self.rejects_given:
            return (self.message(),)
        if self.holds_nowhere:
            low, high = self.grid[0][0], self.grid[-1][0]
            return (tp_not_checkable(self.given, (
                f"eq. (2) leaves the waveform residual at {self.residual_ratio_best:.2f}x the sensor noise or more "
                f"at every Tp from {low:.3g} to {high:.3g} s")),)
        return ()


#: Why a log sampled below the controller's rate cannot check Tp (:func:`tp_not_checkable`).
BELOW_CONTROLLER_RATE = "the command is logged below the controller's rate: the waveform the plant received is not known"


def tp_not_checkable(given: float, reason: str) -> str:
    """The warning for a log whose waveform cannot check the given Tp [s] (``reason``: why, in words).

    Examples
    --------
    >>> tp_not_checkable(0.0422, BELOW_CONTROLLER_RATE)[:60]
    'Tp is not checkable from this log (the command is logged bel'
    """
    return (f"Tp is not checkable from this log ({reason}): Td, tau and K rest on the given Tp = {given:.3g} s, "
            "and a wrong Tp would move them within a tight interval; check --tp against the bench test")


def td_below_tp(Td: float, Tp: float) -> str | None:
    """The warning for an identified Td [s] below the given Tp [s], else None.

    Eq. (2) is symmetric in Tp and Td (up to K's scale), so a Td below Tp means the recording's fast pole came
    out as Td: a warning, not a refusal (the model is the same transfer function as the swapped one).

    Examples
    --------
    >>> td_below_tp(0.0536, 1.9)[:57]
    'Td (0.0536 s) came out shorter than the given Tp (1.9 s):'
    >>> td_below_tp(0.7, 0.1) is None
    True
    """
    if not Td < Tp:
        return None
    return (f"Td ({Td:.3g} s) came out shorter than the given Tp ({Tp:.3g} s): eq. (2) is symmetric in Tp and Td, "
            "so the recording's fast pole is Td's here; check --tp (a bench test's Tp is the fast one)")


def profile_tp(windows: Sequence[CommandWindow], start: LoopModel, *, loop_sign: int = 1,
               noise_std: float | None = None, max_evaluations: int = 15) -> TpProfile:
    """The output-error fit of eq. (2) profiled over Tp (module docstring).

    Parameters
    ----------
    windows : sequence of CommandWindow
        The tests' windows (:func:`~mrftcli.mrft.refine.refinement_windows`).
    start : LoopModel
        The estimate at the given Tp (``start.Tp``) the fits start from.
    loop_sign : {1, -1}
        Sign of the loop gain (as :func:`~mrftcli.mrft.refine.refine`).
    noise_std : float, optional
        Sensor noise [output units]; estimated from the windows when omitted.
    max_evaluations : int
        Cap on residual evaluations of each fit.

    Returns
    -------
    TpProfile
    """
    outputs = [w.output for w in windows if w.output is not None]
    noise = sensor_noise(outputs) if noise_std is None else float(noise_std)
    n = sum(int(np.isfinite(y).sum()) for y in outputs)
    sign = -1.0 if loop_sign < 0 else 1.0
    p = np.array([math.log(start.Td), start.tau, sign * start.K])
    fits: dict[float, tuple[float, np.ndarray]] = {}

    def rss(Tp: float) -> float:
        near, p0 = _nearest_start(fits, Tp, (start.Tp, p))
        Td0 = math.exp(p0[0])
        # the neighbour's fast and slow poles (a fit on the swapped branch, Td < Tp, has them exchanged);
        # the start keeps the slow pole, K Td (the low-frequency gain) and fast pole + tau (the lag they add)
        fast, slow = min(near, Td0), max(near, Td0)
        q = np.array([math.log(slow), max(p0[1] + fast - Tp, 1e-4), p0[2] * Td0 / slow])
        lower, upper = loop_model_bounds(Tp)
        fit = fit_output_error(windows, loop_model_plant(Tp), q, lower=lower, upper=upper,
                               max_evaluations=max_evaluations)
        value = fit.residual_rms ** 2 * fit.n_samples
        fits[Tp] = (value, fit.p)
        return value

    grid = [start.Tp * f for f in GRID_FACTORS]
    middle = int(np.argmin(np.abs(np.log(GRID_FACTORS))))
    # continuation outward from the given Tp: each fit starts from its neighbour's
    for i in [*range(middle, -1, -1), *range(middle + 1, len(grid))]:
        rss(grid[i])
    coarse = min(_ordered(fits, grid), key=lambda t: fits[t][0])
    i = grid.index(coarse)
    lo, hi = math.log(grid[max(i - 1, 0)]), math.log(grid[min(i + 1, len(grid) - 1)])
    optimize.minimize_scalar(lambda x: rss(math.exp(x)), bounds=(lo, hi), method="bounded",
                             options={"xatol": 0.01, "maxiter": 12})
    best = min(_ordered(fits, list(fits)), key=lambda t: fits[t][0])
    half = _half_width({t: fits[t] for t in _ordered(fits, list(fits))}, best, n)
    # a noise-free output (a simulator's truth) has no floor: any residual is infinitely above it
    ratio = {t: (math.sqrt(v / n) / noise if noise > 0 else (math.inf if v > 0 else 0.0))
             for t, (v, _) in fits.items()}
    given = start.Tp
    return TpProfile(given=given, best=best, low=best * math.exp(-half), high=best * math.exp(half),
                     residual_ratio_given=ratio[min(fits, key=lambda t: abs(math.log(t / given)))],
                     residual_ratio_best=ratio[best], grid=tuple(sorted(ratio.items())))


def _ordered(fits: dict[float, tuple[float, np.ndarray]], tps: Sequence[float]) -> list[float]:
    """The Tp of ``tps`` whose fit keeps Tp < Td (all of them when none does).

    Eq. (2)'s response is symmetric in Tp and Td up to K's scale (G = K Td / (s (Tp s + 1)(Td s + 1))),
    so the profile has a second minimum at Tp = the true Td with Td = the true Tp; the paper's
    propulsion lag is the fast pole.
    """
    kept = [t for t in tps if math.exp(float(fits[t][1][0])) > t]
    return kept or list(tps)


def _nearest_start(fits: dict[float, tuple[float, np.ndarray]], Tp: float,
                   default: tuple[float, np.ndarray]) -> tuple[float, np.ndarray]:
    """(Tp, fitted parameters) of the fit nearest ``Tp`` in ln Tp (``default`` before any fit)."""
    if not fits:
        return default
    near = min(fits, key=lambda t: abs(math.log(t / Tp)))
    return near, fits[near][1]


def _half_width(fits: dict[float, tuple[float, np.ndarray]], best: float, n: int) -> float:
    """Half-width in ln Tp of the 95 % profile interval: deviance n ln(RSS / RSS_min) = 3.84, from the
    parabola through the fits nearest the minimum (a flat profile gives an infinite width)."""
    x = np.array([math.log(t) for t in fits])
    d = np.array([n * math.log(v / fits[best][0]) for v, _ in fits.values()])
    near = np.argsort(np.abs(x - math.log(best)))[:5]
    if near.size < 3:
        return math.inf
    a = np.polyfit(x[near] - math.log(best), d[near], 2)[0]
    return math.sqrt(CHI2_95 / a) if a > 0 else math.inf
