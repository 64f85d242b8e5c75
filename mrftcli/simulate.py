"""Closed-loop MRFT flight simulator (interface; implementation owned by the simulator work, issue 3).

The types below are the contract other modules (diagnose, tests, sample-log generation) code against.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .logtypes import TopicData
from .model import LoopModel

__all__ = ["Effects", "TestSpec", "FlightSpec", "SimulatedFlight", "simulate_flight"]


@dataclass(frozen=True)
class Effects:
    """Physics the linear model G(s) leaves out; all default to "absent".

    Attributes
    ----------
    input_bias : float
        Constant disturbance added to the command at the plant input [command units]
        (hover-thrust trim error, CG offset).
    gain_drift : float
        Relative change of the gain K per second [1/s] (battery sag): K(t) = K (1 + gain_drift * t),
        t from the start of the log.
    sensor_lag : float
        Time constant of an extra first-order lag on the measured output [s] (filter/estimator).
    quadratic_drag : float
        Coefficient c of drag proportional to v|v| that replaces the linear drag term
        [1/(output units)]: y'' = -c y'|y'| + K (propulsion state).
    actuator_rate_limit : float
        Maximum slew rate of the actuator input [command units/s]; 0 means no limit.
    delay_jitter : float
        Standard deviation of a random transport-delay variation [s], redrawn every cycle-ish
        (see the implementation for the correlation time).
    """

    input_bias: float = 0.0
    gain_drift: float = 0.0
    sensor_lag: float = 0.0
    quadratic_drag: float = 0.0
    actuator_rate_limit: float = 0.0
    delay_jitter: float = 0.0


@dataclass(frozen=True)
class TestSpec:
    """One MRFT test: beta in (-1, 1), relay height h [command units], duration of the relay [s]."""

    beta: float
    h: float
    duration: float = 12.0


@dataclass(frozen=True)
class FlightSpec:
    """Everything that defines one simulated flight."""

    model: LoopModel
    tests: tuple[TestSpec, ...]
    loop: str = "altitude"
    rate_hz: float = 200.0
    noise_std: float | None = None  # output units; None -> 0.5 mm (altitude) / 0.2 deg (roll, pitch)
    bias: float | None = None  # hover command; None -> loop default
    setpoint: float | None = None  # None -> loop default (1 m altitude, 0 rad attitude)
    hover_s: float = 5.0
    hold_s: float = 4.0
    effects: Effects = field(default_factory=Effects)
    seed: int = 0


@dataclass
class SimulatedFlight:
    """A simulated flight: sampled signals at the controller rate and the ground truth."""

    spec: FlightSpec
    t: np.ndarray
    command: np.ndarray
    output_true: np.ndarray
    output_measured: np.ndarray
    setpoint: np.ndarray
    truth: dict
    topics: list[TopicData]


def simulate_flight(spec: FlightSpec) -> SimulatedFlight:  # pragma: no cover - replaced by issue 3
    raise NotImplementedError("the simulator is being implemented (issue 3)")
