"""The segmenter's records: one relay cycle (:class:`RelayCycle`) and one MRFT test (:class:`MrftTest`).

Times in seconds; output values in output units, relative to the loop setpoint when it was logged;
command values in command units. Both are frozen and carry a JSON-ready ``to_dict``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .stability import StabilityCriterion
from .validity import LimitCycleCheck

__all__ = ["RelayCycle", "MrftTest"]


@dataclass(frozen=True)
class RelayCycle:
    """One relay cycle: from a -h -> +h switch to the next one.

    Times in seconds; output values in output units, relative to the loop setpoint when it was
    logged (else absolute); the amplitude is in output units.

    Attributes
    ----------
    t_start, t_switch, t_end : float
        The -h -> +h switch that opens the cycle, the +h -> -h switch inside it, the next -h -> +h.
    period, half_period_high, half_period_low : float
        t_end - t_start, time at +h, time at -h [s].
    amplitude : float
        (y_max - y_min) / 2 of the period-long harmonic fits around the extrema [output units].
    centre : float
        (y_max + y_min) / 2 [output units].
    y_max, y_min, t_max, t_min : float
        The fitted extrema and their times.
    y_switch_down, y_switch_up : float
        The smoothed output at the +h -> -h (t_switch) and -h -> +h (t_end) switch instants.
    beta_down, beta_up, beta_effective : float
        (y_switch_down - centre)/a, -(y_switch_up - centre)/a, and their mean: the switching level the
        relay actually achieved in this cycle.
    phase_h1, gain_h1 : float
        Fundamental harmonic of the output relative to that of the relay's square wave over the cycle
        (:func:`~mrftcli.segment.cycles.cycle_fundamental`): arg [rad, in (-2 pi, 0]] and modulus
        [output units per command unit]. For a periodic cycle they are arg G(j Omega) and
        |G(j Omega)| of the loop's plant, whatever level the relay switched at; NaN when an instant
        was interpolated or the fit failed.
    noise_std, h1_fraction, amplitude_h1 : float
        From the same whole-cycle fit (:func:`~mrftcli.segment.cycles.cycle_fundamental`): the
        residual standard deviation (the sensor noise) [output units], the share of the de-trended
        output's mean square at the relay's fundamental frequency [-], and the amplitude of that
        fundamental [output units]. They feed the limit-cycle validity check
        (:func:`~mrftcli.segment.validity.check_limit_cycle`).
    flags : tuple of str
        ``gap`` (a switch follows more than two dropped command samples), ``interp`` (a switch follows one
        or two dropped samples: its instant is interpolated and its level not used for beta),
        ``glitch`` (a false switch was absorbed),
        ``irregular`` (bad fits), ``transient``, ``outlier`` (fails the criterion).
    stable : bool
        Part of the stable limit cycle.
    """

    t_start: float
    t_switch: float
    t_end: float
    period: float
    half_period_high: float
    half_period_low: float
    amplitude: float
    centre: float
    y_max: float
    y_min: float
    t_max: float
    t_min: float
    y_switch_down: float
    y_switch_up: float
    beta_down: float
    beta_up: float
    beta_effective: float
    flags: tuple[str, ...] = ()
    stable: bool = False
    phase_h1: float = float("nan")
    gain_h1: float = float("nan")
    noise_std: float = float("nan")
    h1_fraction: float = float("nan")
    amplitude_h1: float = float("nan")

    @property
    def frequency_hz(self) -> float:
        """1 / period [Hz]."""
        return 1.0 / self.period

    @property
    def regular(self) -> bool:
        """No gap, glitch or failed fit inside the cycle."""
        return not ({"gap", "glitch", "irregular"} & set(self.flags))

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d["flags"] = list(self.flags)
        d["frequency_hz"] = self.frequency_hz
        return d


@dataclass(frozen=True)
class MrftTest:
    """One MRFT test as the segmenter found it in a log: the relay's settings and every cycle measured.

    Not to be confused with the simulator's :class:`~mrftcli.sim.flight.TestSpec` (a test to fly).

    Attributes
    ----------
    index : int
        Position in the log (0-based).
    t_start, t_end : float
        First and last command sample of the relay test [s] (the relay's start and stop).
    h, bias : float
        Relay half-height and centre level of the command [command units].
    beta_nominal : float or None
        Beta from the beta topic (last value published before or during the test), else None.
    beta_effective : float
        Mean effective beta over the stable cycles (NaN if there are none).
    beta_effective_std : float
        Standard deviation of the per-cycle effective beta.
    rate_hz : float
        Rate of the command samples in the test, from their timestamps [Hz] (the logger's rate, which
        is the controller's unless the logger sub-samples it).
    controller_rate_hz : float or None
        Rate the relay decides at [Hz] when the command is logged below it (PX4's 10 Hz logger over
        its 50 Hz position controller), from the layout or the caller; None when the command is
        logged at the controller's rate or the controller's rate is unknown.
    cycles : tuple of RelayCycle
        Every complete cycle, stable or not.
    criterion : StabilityCriterion
        The criterion used.
    period_median, period_tolerance, amplitude_median, amplitude_tolerance : float
        The reference values and tolerances the criterion applied [s], [output units].
    loop_sign : int
        +1 when the output rises under +h (positive loop gain), -1 otherwise (the output was flipped
        for the cycle analysis; amplitudes are magnitudes).
    setpoint : float or None
        Median setpoint over the test, if logged (output units).
    timestamps_regularised : bool
        Whether the command timestamps were put back on a sample grid.
    n_switches : int
        Relay switches seen in the test.
    notes : tuple of str
        Anything worth telling the user about this test.
    validity : LimitCycleCheck or None
        Whether the output follows this relay as an MRFT limit cycle, with the measured figures
        (:func:`~mrftcli.segment.validity.check_limit_cycle`).
    switch_timing : str or None
        How the switch instants of a test logged below the controller's rate were placed
        (:mod:`~mrftcli.segment.vernier`): ``"vernier"`` (on their controller ticks: the logging
        instants slide along the cycle), ``"vernier-locked-beta"`` (the logging locked to the cycle:
        up- and down-switches each placed within their logging brackets by the nominal beta),
        ``"vernier-locked"`` (locked and no nominal beta: the brackets' middles); None when the
        command is logged at the controller's rate.
    """

    index: int
    t_start: float
    t_end: float
    h: float
    bias: float
    beta_nominal: float | None
    beta_effective: float
    beta_effective_std: float
    rate_hz: float
    cycles: tuple[RelayCycle, ...]
    criterion: StabilityCriterion
    period_median: float
    period_tolerance: float
    amplitude_median: float
    amplitude_tolerance: float
    loop_sign: int = 1
    setpoint: float | None = None
    timestamps_regularised: bool = False
    n_switches: int = 0
    notes: tuple[str, ...] = ()
    validity: LimitCycleCheck | None = None
    controller_rate_hz: float | None = None
    switch_timing: str | None = None

    @property
    def decision_rate_hz(self) -> float:
        """The rate the relay decides at [Hz]: ``controller_rate_hz`` when known, else the logged ``rate_hz``."""
        return float(self.controller_rate_hz or self.rate_hz)

    @property
    def samples_per_cycle(self) -> float:
        """Logged command samples per stable cycle: ``rate_hz`` / the limit cycle's frequency [-] (NaN
        without a stable cycle)."""
        return float(self.rate_hz / self.frequency_hz_mean)

    @property
    def valid(self) -> bool:
        """The output follows this test's relay as an MRFT limit cycle (``validity.ok``)."""
        return self.validity is None or self.validity.ok

    @property
    def stable(self) -> tuple[RelayCycle, ...]:
        """The cycles of the stable limit cycle."""
        return tuple(c for c in self.cycles if c.stable)

    @property
    def n_stable(self) -> int:
        return sum(1 for c in self.cycles if c.stable)

    @property
    def beta(self) -> float:
        """The beta used for identification: the effective one when measured, else the nominal."""
        if np.isfinite(self.beta_effective):
            return float(self.beta_effective)
        return float(self.beta_nominal) if self.beta_nominal is not None else float("nan")

    @property
    def period(self) -> np.ndarray:
        """Per stable cycle period [s]."""
        return np.array([c.period for c in self.stable])

    @property
    def frequency_hz(self) -> np.ndarray:
        """Per stable cycle frequency [Hz]."""
        return 1.0 / self.period

    @property
    def amplitude(self) -> np.ndarray:
        """Per stable cycle output amplitude [output units]."""
        return np.array([c.amplitude for c in self.stable])

    @property
    def frequency_hz_mean(self) -> float:
        """1 / mean period of the stable cycles [Hz] (the test's limit-cycle frequency)."""
        p = self.period
        return float(1.0 / p.mean()) if p.size else float("nan")

    @property
    def amplitude_mean(self) -> float:
        a = self.amplitude
        return float(a.mean()) if a.size else float("nan")

    def to_dict(self, cycles: bool = True) -> dict[str, Any]:
        """JSON-ready summary; ``beta`` is the beta used for identification."""
        p = self.period
        a = self.amplitude
        d: dict[str, Any] = {
            "index": self.index,
            "beta": self.beta,
            "beta_nominal": self.beta_nominal,
            "beta_effective": self.beta_effective,
            "beta_effective_std": self.beta_effective_std,
            "h": self.h,
            "bias": self.bias,
            "rate_hz": self.rate_hz,
            "controller_rate_hz": self.controller_rate_hz,
            "t_start": self.t_start,
            "t_end": self.t_end,
            "cycles": self.n_stable,
            "cycles_total": len(self.cycles),
            "frequency_hz": self.frequency_hz_mean,
            "frequency_hz_std": float(np.std(1.0 / p, ddof=1)) if p.size > 1 else None,
            "amplitude": self.amplitude_mean,
            "amplitude_std": float(np.std(a, ddof=1)) if a.size > 1 else None,
            "half_period_high": float(np.mean([c.half_period_high for c in self.stable])) if p.size else None,
            "half_period_low": float(np.mean([c.half_period_low for c in self.stable])) if p.size else None,
            "loop_sign": self.loop_sign,
            "setpoint": self.setpoint,
            "timestamps_regularised": self.timestamps_regularised,
            "criterion": {
                **self.criterion.to_dict(),
                "period_median": self.period_median,
                "period_tolerance": self.period_tolerance,
                "amplitude_median": self.amplitude_median,
                "amplitude_tolerance": self.amplitude_tolerance,
            },
            "notes": list(self.notes),
        }
        if self.controller_rate_hz is not None:
            # logged below the controller's rate: how coarse, and how the switches were placed
            d["samples_per_cycle"] = self.samples_per_cycle
            d["switch_timing"] = self.switch_timing
        if self.validity is not None:
            d["validity"] = self.validity.to_dict()
        if cycles:
            d["per_cycle"] = [c.to_dict() for c in self.cycles]
        return d
