"""The static gain from a biased relay's mean levels (issue 38, item 4; Astrom and Hagglund's asymmetric relay).

Over a whole period of a linear, self-regulating plant's limit cycle the derivatives average to
zero, so the mean output is the static gain times the mean plant input: with the command's zero as
the plant's rest (a heater off) and ``Y0`` the output there (the ambient), ``mean y - Y0 = K mean u``
on every stable cycle, whatever the relay, the delay or the lags. A symmetric relay about the zero
(mean u = 0) says nothing of K this way; a biased one (a 0/1 heater) does, once ``Y0`` is known.

:func:`static_gain` fits ``K`` through the cycles' means (least squares through the origin, the
cycles' scatter giving the standard error, ``Y0``'s own standard deviation added) and returns it as a
record that :func:`~mrftcli.mrft.identify_lti.static_gain_point` turns into one more measured
constraint of the fit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError
from ..io.logtypes import FlightLog, Signal
from ..mrft.model import PlantModel
from ..segment.records import MrftTest

__all__ = ["StaticGain", "static_gain", "cycle_means", "is_self_regulating"]

#: the mean command must stand this many standard errors clear of the zero for K to be measured
_MIN_T = 5.0


@dataclass(frozen=True)
class StaticGain:
    """K measured from the mean levels.

    Attributes
    ----------
    value, std : float
        Static gain [output / command] and its standard deviation.
    baseline, baseline_std : float
        The operating point ``Y0`` [output units] used, and its standard deviation.
    mean_command, mean_output : float
        Means over the stable cycles [command units], [output units].
    n_cycles : int
        Stable cycles used.
    """

    value: float
    std: float
    baseline: float
    baseline_std: float
    mean_command: float
    mean_output: float
    n_cycles: int

    def describe(self) -> str:
        return (f"static gain from the relay's mean levels: K = (mean output {self.mean_output:.4g} - baseline "
                f"{self.baseline:.4g}) / mean command {self.mean_command:.4g} = {self.value:.4g} ± {self.std:.2g} "
                f"output / command ({self.n_cycles} stable cycles; the command's zero taken as the plant's rest)")

    def to_json(self) -> dict[str, Any]:
        return {"value": self.value, "std": self.std, "baseline": self.baseline, "baseline_std": self.baseline_std,
                "mean_command": self.mean_command, "mean_output": self.mean_output, "n_cycles": self.n_cycles}

    @classmethod
    def from_json(cls, data: Any) -> StaticGain:
        try:
            return cls(float(data["value"]), float(data["std"]), float(data["baseline"]), float(data["baseline_std"]),
                       float(data["mean_command"]), float(data["mean_output"]), int(data["n_cycles"]))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"analysis JSON: bad static_gain ({err})") from None


def _mean(sig: Signal, a: float, b: float, hold: bool) -> float:
    """Time average of ``sig`` over [a, b] [s]: held from each sample (``hold``) or linear between them."""
    t, v = sig.t, sig.values
    inside = (t > a) & (t < b)
    knots = np.concatenate([[a], t[inside], [b]])
    if hold:
        idx = np.clip(np.searchsorted(t, knots[:-1], side="right") - 1, 0, t.size - 1)
        return float(np.sum(v[idx] * np.diff(knots)) / (b - a))
    vals = np.interp(knots, t, v)
    return float(np.trapezoid(vals, knots) / (b - a))


def cycle_means(flight: FlightLog, test: MrftTest) -> tuple[np.ndarray, np.ndarray]:
    """(mean command, mean output) over each stable cycle of ``test`` [command units], [output units]."""
    rows = [(_mean(flight.command, c.t_start, c.t_end, True), _mean(flight.output, c.t_start, c.t_end, False))
            for c in test.cycles if c.stable and c.t_end > c.t_start]
    arr = np.array(rows, dtype=np.float64).reshape(-1, 2)
    return arr[:, 0], arr[:, 1]


def is_self_regulating(model: PlantModel, omega: float) -> bool:
    """The model has a finite static gain (no integrator): its gain levels off below ``omega`` [rad/s]."""
    g = np.abs(model.frequency_response(np.array([1e-6 * omega, 1e-4 * omega])))
    return bool(np.all(np.isfinite(g)) and g[0] < 2 * g[1])


def _check_cover(baseline: Signal, tests: Sequence[MrftTest]) -> None:
    """InputError unless the baseline's readings span the stable cycles (to within one cycle at each end)."""
    spans = [(c.t_start, c.t_end) for t in tests for c in t.cycles if c.stable and c.t_end > c.t_start]
    if not spans or baseline.t.size == 0:
        raise InputError("--baseline-topic: no readings of the operating point")
    first, last = min(a for a, _ in spans), max(b for _, b in spans)
    period = float(np.median([b - a for a, b in spans]))
    if baseline.t[0] > first + period or baseline.t[-1] < last - period:
        raise InputError(f"--baseline-topic: its readings ({baseline.t[0]:.6g}-{baseline.t[-1]:.6g} s) do not "
                         f"cover the relay test's stable cycles ({first:.6g}-{last:.6g} s)")


def static_gain(flight: FlightLog, tests: Sequence[MrftTest], baseline: float | Signal,
                baseline_std: float = 0.0) -> StaticGain:
    """K from the stable cycles' mean levels of ``tests`` and the operating point ``baseline``.

    ``baseline`` is a number [output units] or a logged signal (the ambient temperature's topic):
    then each cycle's own mean of it is that cycle's operating point (a drifting ambient is followed;
    its readings' noise is in the cycles' scatter), and :attr:`StaticGain.baseline` is its mean.

    Raises
    ------
    InputError
        Fewer than two stable cycles, or a mean command too close to the command's zero (a symmetric
        relay) for the mean levels to say anything of K.
    """
    us, ys, bs = [], [], []
    for test in tests:
        u, y = cycle_means(flight, test)
        us.append(u)
        ys.append(y)
        if isinstance(baseline, Signal):
            bs.append(np.array([_mean(baseline, c.t_start, c.t_end, False) for c in test.cycles
                                if c.stable and c.t_end > c.t_start]))
    u, y = np.concatenate(us), np.concatenate(ys)
    n = u.size
    if n < 2:
        raise InputError("--baseline: fewer than two stable cycles to take the mean levels over")
    if isinstance(baseline, Signal):
        _check_cover(baseline, tests)
    y0 = np.concatenate(bs) if isinstance(baseline, Signal) else np.full(n, float(baseline))
    if not np.all(np.isfinite(y0)):
        raise InputError("--baseline-topic: its readings do not cover the relay test's cycles")
    d = y - y0
    k = float(np.sum(u * d) / np.sum(u * u))
    resid = d - k * u
    se_scatter = math.sqrt(float(np.sum(resid ** 2)) / max(n - 1, 1) / float(np.sum(u * u)))
    se_base = baseline_std * abs(float(np.sum(u))) / float(np.sum(u * u))
    mean_u = float(np.mean(u))
    se_u = float(np.std(u, ddof=1)) / math.sqrt(n) if n > 1 else math.inf
    if abs(mean_u) < _MIN_T * max(se_u, 1e-12 * float(np.max(np.abs(u)) or 1.0)):
        raise InputError(f"--baseline: the relay's mean command {mean_u:.3g} is at the command's zero (a symmetric "
                         "relay): its mean levels do not determine the static gain; a biased relay (e.g. 0/1) does")
    return StaticGain(k, math.hypot(se_scatter, se_base), float(np.mean(y0)), baseline_std, mean_u, float(np.mean(y)), n)
