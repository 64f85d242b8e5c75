"""A test's smooth periodic waveform and the relay's effective switching level on it.

Each stable cycle's output, less the drift its level shows from one cycle to the next, is fitted
with a constant plus harmonics of its period (:func:`cycle_fits`, the fits
:func:`mrftcli.analyze.general.response_points` divides by the relay's harmonics). Their complex mean over the cycles, in the cycle's phase from its ``-h -> +h`` switch,
is the test's smooth waveform: the noise averages out, the plant's response to the relay stays.

A relay deciding on a noisy error switches when the *noisy* error crosses its level, so the smooth
output at the switching instants is what a noise-free model of the loop must reproduce for its
limit cycle (LPRS) to have the recorded phase. :func:`switching_level` reads that level, half the
difference between each cycle's smooth output at its ``+h -> -h`` and its ``-h -> +h`` switch (the
bias's offset cancels), and the mean smooth waveform's amplitude; :func:`effective_relay` turns it into the
relay the held-out prediction uses: a hysteresis ``eps`` [output units] or an MRFT ``beta`` (the
level over the amplitude), less the mean lag of a relay deciding on samples (the sampled prediction
adds that lag itself). :func:`predicted_cycle` is a model's cycle under that relay, its MRFT level
read over the model's smooth amplitude alike.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import InputError
from ..io.logtypes import FlightLog
from ..jsonable import check_schema_version
from ..mrft.harmonics import fit_harmonics, harmonic_basis
from ..mrft.lprs import LimitCycle
from ..mrft.model import PlantModel
from ..mrft.relays import RelayLaw
from ..segment.records import MrftTest
from ..segment.relay_type import sampling_level

__all__ = ["CycleFit", "SwitchingLevel", "cycle_fits", "switching_level", "effective_relay",
           "peak_amplitude", "cycle_harmonics", "predicted_cycle", "SWITCHING_SCHEMA_VERSION"]

#: version of :meth:`SwitchingLevel.to_json`
SWITCHING_SCHEMA_VERSION = 1
#: phase samples of the smooth waveform over one period (its extrema to ~1e-5 of the amplitude)
_PHASES = 4096


@dataclass(frozen=True, eq=False)
class CycleFit:
    """One stable cycle's output as harmonics of its period.

    Attributes
    ----------
    t_start : float
        The cycle's ``-h -> +h`` switch [s, log clock]; the harmonics' phase origin.
    period : float
        P [s].
    t_high : float
        Time at the high level, from ``t_start`` to the ``+h -> -h`` switch [s].
    harmonics : numpy.ndarray
        Y_k, k = 1..H [output units] (:attr:`mrftcli.mrft.harmonics.HarmonicFit.harmonics`).
    chattered : bool
        The relay chattered in this cycle (its square wave is not the closed form).
    """

    t_start: float
    period: float
    t_high: float
    harmonics: np.ndarray
    chattered: bool = False


@dataclass(frozen=True)
class SwitchingLevel:
    """The smooth output at a test's switching instants.

    Attributes
    ----------
    level : float
        Half the difference between the smooth output at the ``+h -> -h`` and at the ``-h -> +h``
        switches [output units]: a hysteresis relay's eps, an MRFT's ``beta * amplitude``.
    amplitude : float
        Half the smooth waveform's peak-to-peak [output units].
    n_cycles : int
        The cycles averaged.
    level_se : float
        The level's standard error [output units].
    """

    level: float
    amplitude: float
    n_cycles: int
    level_se: float = 0.0

    @property
    def beta(self) -> float:
        """The level over the amplitude [-]."""
        return self.level / self.amplitude

    def to_json(self) -> dict[str, Any]:
        return {"schema_version": SWITCHING_SCHEMA_VERSION, "level": self.level, "amplitude": self.amplitude,
                "n_cycles": self.n_cycles,
                "level_se": self.level_se}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> SwitchingLevel:
        """The record of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input."""
        data = check_schema_version(data, "switching level JSON", SWITCHING_SCHEMA_VERSION)
        try:
            return cls(float(data["level"]), float(data["amplitude"]), int(data["n_cycles"]),
                       float(data.get("level_se", 0.0)))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"switching level JSON: bad or missing field ({err})") from None


def cycle_fits(flight: FlightLog, test: MrftTest) -> tuple[CycleFit, ...]:
    """Each stable cycle of ``test`` as a level, its drift and up to eight harmonics of its period.

    A cycle's drift is not fitted from its own samples: over one period a free line is not orthogonal
    to the harmonics, so the harmonics the fit leaves out (a triangle has all odd ones) project onto
    the line and the line's sawtooth series hands them back to harmonics 1..H (-0.77 % at the
    fundamental of a triangle with H = 3, +2.3 % at the 3rd: an IPDT's K read 1 % low). The drift is
    what the cycle's level does from one cycle to the next (:func:`_drift_rates`); with it removed a
    constant plus the harmonics, orthogonal on a uniform grid, leave out nothing that leaks into them.
    Cycles with fewer than ten samples are skipped (the level and the fundamental need a few each).
    """
    t, y = flight.output.t, flight.output.values * test.loop_sign
    spans = []
    for c in test.stable:
        P = c.t_end - c.t_start
        # the cycle is [t_start, t_end): a sample within a millionth of a period of a bound counts as on
        # it, so rounding in the times (1e-14 s) cannot move a sample across (it moved K by 0.25 %)
        i0, i1 = np.searchsorted(t, [c.t_start - 1e-6 * P, c.t_end - 1e-6 * P])
        if i1 - i0 >= 10:
            spans.append((c, int(i0), int(i1)))
    projections = [_level_and_harmonics(t[i0:i1] - c.t_start, y[i0:i1], c.t_end - c.t_start)
                   for c, i0, i1 in spans]
    rates = _drift_rates([c.t_start + 0.5 * (c.t_end - c.t_start) for c, _, _ in spans],
                         [float(coef_y[0]) for coef_y, _ in projections])
    if len(spans) == 1:
        # a lone cycle has no neighbour: its drift is fitted with its harmonics as a free line, which
        # leaks the harmonics left out into the ones fitted (above)
        c, i0, i1 = spans[0]
        P = c.t_end - c.t_start
        rates = [float(fit_harmonics(t[i0:i1] - c.t_start, y[i0:i1], P, min(8, (i1 - i0 - 2) // 4)).coef[1]) / P]
    fits = []
    for (c, _, _), (coef_y, coef_ramp), rate in zip(spans, projections, rates):
        H = (coef_y.size - 1) // 2
        coef = coef_y - rate * coef_ramp  # by linearity: the fit of y minus the drift line
        fits.append(CycleFit(c.t_start, c.t_end - c.t_start, c.t_switch - c.t_start,
                             coef[1: 1 + H] - 1j * coef[1 + H:], "glitch" in c.flags))
    return tuple(fits)


def _level_and_harmonics(x: np.ndarray, y: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``[c, a_1..a_H, b_1..b_H]`` of one cycle's output and of the ramp ``x - P / 2``.

    The basis is a constant plus the cosines and sines of harmonics 1..H (H up to eight, two samples
    per fitted function: 16 samples a cycle give H = 3), the same as
    :func:`~mrftcli.mrft.harmonics.harmonic_basis` without its trend column; ``x`` is the time from
    the cycle's start [s]. The ramp's fit is what a drift of one output unit per second adds.
    """
    H = min(8, (x.size - 2) // 4)
    A = np.delete(harmonic_basis(x, period, H), 1, axis=1)
    coef, *_ = np.linalg.lstsq(A, np.column_stack([y, x - 0.5 * period]), rcond=None)
    return coef[:, 0], coef[:, 1]


def _drift_rates(mid_times: Sequence[float], levels: Sequence[float]) -> list[float]:
    """Each cycle's drift [output units / s]: the central difference of its neighbours' levels.

    A cycle's fitted constant is its level at mid-cycle (the mean over a period carries no harmonic),
    so the difference of the neighbours' levels over their mid-times is the drift at the cycle,
    exact for a linear drift; the first and the last cycle take the one-sided difference. Zero for a
    lone cycle (no neighbour to read it from).

    Examples
    --------
    >>> _drift_rates([0.5, 1.5, 2.5], [1.0, 2.0, 4.0])
    [1.0, 1.5, 2.0]
    """
    n = len(levels)
    if n < 2:
        return [0.0] * n
    rates = []
    for i in range(n):
        a, b = max(i - 1, 0), min(i + 1, n - 1)
        rates.append((levels[b] - levels[a]) / (mid_times[b] - mid_times[a]))
    return rates


def switching_level(fits: Sequence[CycleFit]) -> SwitchingLevel | None:
    """The smooth output's level at the switches and the smooth amplitude (module docstring); None under two cycles.

    The level is the mean over the cycles of each cycle's smooth output (its harmonics) at its own
    switches: a noisy relay's switches jitter from cycle to cycle, and one mean waveform evaluated
    at the mean switch would blur the level there (by 3-10 % where the switch is near the peak, on
    the KSTAR windows). Its standard error is the cycles' scatter over sqrt(n). The amplitude is
    that of the mean waveform (the complex mean of the harmonics every cycle carries, in the cycle's
    phase): the noise, which inflates each cycle's own extrema, averages out.

    Examples
    --------
    A cosine lagging the switches by a quarter period is at zero at both switches:

    >>> h = np.array([1j])  # Re(j e^{j phi}) = -sin(phi): 0 at phi = 0 and at phi = pi
    >>> s = switching_level([CycleFit(0.0, 1.0, 0.5, h), CycleFit(1.0, 1.0, 0.5, h)])
    >>> round(s.level, 9) + 0.0, round(s.amplitude, 6), s.n_cycles
    (0.0, 1.0, 2)
    """
    if len(fits) < 2:
        return None
    levels = []
    for f in fits:
        k = np.arange(1, f.harmonics.size + 1)
        up, down = np.real(np.exp(1j * np.outer([0.0, 2 * math.pi * f.t_high / f.period], k)) @ f.harmonics)
        levels.append(0.5 * (down - up))
    n = min(f.harmonics.size for f in fits)
    Y = np.mean([f.harmonics[:n] for f in fits], axis=0)
    return SwitchingLevel(float(np.mean(levels)), peak_amplitude(Y, _PHASES), len(fits),
                          float(np.std(levels, ddof=1) / math.sqrt(len(levels))))


def effective_relay(relay: RelayLaw, level: SwitchingLevel | None, test: MrftTest) -> RelayLaw | None:
    """The relay at the smooth waveform's switching level (``source="effective"``), or None.

    A hysteresis relay gets ``eps = level - L_s`` [output units], an MRFT ``beta = (level - L_s) /
    amplitude`` (clipped to [-0.99, 0.99]); ``L_s`` is the sampled relay's mean lag
    (:func:`mrftcli.segment.relay_type.sampling_level`). None for an ideal relay (it has no level to
    move) or without a measured level.
    """
    if level is None or relay.kind == "ideal" or not (math.isfinite(level.level) and level.amplitude > 0):
        return None
    excess = level.level - sampling_level(test, level.amplitude)
    if relay.kind == "hysteresis":
        return RelayLaw("hysteresis", relay.high, relay.low, eps=max(excess, 0.0), source="effective")
    return RelayLaw("mrft", relay.high, relay.low, beta=float(np.clip(excess / level.amplitude, -0.99, 0.99)),
                    source="effective")


def peak_amplitude(Y: np.ndarray, n: int = 2048) -> float:
    """Half the peak-to-peak of the waveform with harmonics ``Y`` (k = 1.., phase sampled at ``n``
    points of the cycle) [output units]."""
    phase = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    wave = np.real(np.exp(1j * np.outer(phase, np.arange(1, Y.size + 1))) @ Y)
    return float(0.5 * (wave.max() - wave.min()))


def cycle_harmonics(lc: LimitCycle, n_h: int) -> np.ndarray:
    """Y_k, k = 1..n_h, of a model's limit cycle (phase from its ``-h -> +h`` switch) [output units]."""
    t, y = np.asarray(lc.t, float), np.asarray(lc.y, float)
    n_h = max(1, min(n_h, (t.size - 2) // 4))
    harmonics: np.ndarray = fit_harmonics(t, y, lc.period, n_h).harmonics
    return harmonics


def predicted_cycle(relay: RelayLaw, model: PlantModel, rate_hz: float | None, n_h: int | None) -> LimitCycle:
    """The limit cycle a model should be predicted with under a test's (effective) relay.

    An effective MRFT's beta is the switching level over the *smooth* waveform's amplitude (its first
    ``n_h`` harmonics, :func:`switching_level`), while the model's relay switches at beta times its
    cycle's true extremum. Where the waveform has a kink at its peak (a first-order plant's output
    turns as the delayed input switches), eight harmonics round the peak off by several per cent, and
    the effective beta read that way is too large by as much (-0.216 for a relay of -0.2 on a clean
    simulated FOPDT at 500 Hz: its cycle predicted 1.1 % fast). So the model's beta is the relay's
    times the model's own smooth-to-true amplitude ratio (one fixed-point step: the ratio moves little
    with beta), the level measured alike on both sides. Other relays, or ``n_h`` None (no smooth
    waveform measured), are taken as they are.

    Raises
    ------
    InputError, IdentificationError, ValueError, ArithmeticError
        As :meth:`RelayLaw.limit_cycle` (the model has no cycle under the relay).
    """
    lc = relay.limit_cycle(model, rate_hz)
    if relay.kind != "mrft" or n_h is None or not lc.amplitude > 0:
        return lc
    ratio = peak_amplitude(cycle_harmonics(lc, n_h)) / lc.amplitude
    beta = float(np.clip(relay.beta * ratio, -0.99, 0.99))
    return dataclasses.replace(relay, beta=beta).limit_cycle(model, rate_hz)
