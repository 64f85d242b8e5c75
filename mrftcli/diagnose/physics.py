"""diagnose's one library of physics: what a model leaves out, for every family (issue 36).

Each effect has a JSON name, a plain-language explanation, the augmentation of the model it stands
for and its own parameter (name, unit). How an effect changes a model's limit cycle is the family's
strategy:

* eq. (2) (:mod:`mrftcli.diagnose.selection` with a ``soiptd`` model) simulates the cycle of the
  augmented plant (:class:`mrftcli.diagnose.limit_cycles.AugmentedPlant`, keyed by the effect's name)
  and fits the effect with Td and tau to the cycle features; its library is :data:`CANDIDATES`, which
  holds the physics of the propulsion it models (quadratic drag, thrust rectification);
* every other family (:mod:`mrftcli.diagnose.effects`) writes the effect as what it does to one test's
  response points, mean balance and period scatter (:class:`OnTests`: an :class:`Action` per test, a
  grid of values to profile over); its library is :data:`EFFECTS`.

Parameterisation used by eq. (2)'s fit (all O(1) so finite differences behave): the base vector is
``[ln Td, 10 tau]``; K is eliminated in closed form (Lemma 2 of the paper: frequency and waveform
shape are invariant to K, the amplitude scales with it). Quadratic drag replaces the linear drag, so
its vector is ``[ln q, 10 tau]`` with q = c K (the limit cycle depends on c and K only through c K up
to the amplitude scale), then c = q / K.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from ..io.logtypes import output_unit

if TYPE_CHECKING:
    from .effects import TestData

__all__ = ["Effect", "Action", "OnTests", "LIBRARY", "CANDIDATES", "EFFECTS", "BY_NAME", "BIC_THRESHOLD", "unit_in_loop"]

#: evidence needed to name an effect, every family: delta BIC above it ("very strong" on Kass-Raftery's scale)
BIC_THRESHOLD = 10.0


@dataclass(frozen=True)
class Action:
    """What an effect does to one test, the families' strategy (:mod:`mrftcli.diagnose.effects`'s
    docstring). The defaults are no effect.

    Attributes
    ----------
    gain : float
        The factor on the relay's square wave the plant receives [-].
    ramp : float
        The time a rate-limited actuator takes between the levels [s].
    lag : float
        A first-order lag on the output [s].
    dc : float
        What the effect adds to the plant input's mean over a cycle [command units].
    jitter : float
        A switch-instant jitter [s].
    """

    gain: float = 1.0
    ramp: float = 0.0
    lag: float = 0.0
    dc: float = 0.0
    jitter: float = 0.0


@dataclass(frozen=True)
class OnTests:
    """An effect as the families' strategy fits it (:mod:`mrftcli.diagnose.effects`).

    Attributes
    ----------
    views : tuple of str
        Which views it changes: ``"points"``, ``"balance"``, ``"scatter"``.
    action : callable
        ``action(test, value, t_ref) -> Action``.
    grid : callable
        ``grid(tests) -> array`` of values to profile over (its no-effect value first).
    """

    views: tuple[str, ...]
    action: Callable[[TestData, float, float], Action]
    grid: Callable[[Sequence[TestData]], np.ndarray]


@dataclass(frozen=True)
class Effect:
    """One physical effect of the library.

    Attributes
    ----------
    name : str
        JSON name.
    explanation : str
        What it is and how it shows in an MRFT test, in plain words.
    augmentation : str
        The model change it stands for.
    parameter : str
        Name of its parameter in the JSON ``parameters`` object.
    unit : str
        Unit of the parameter.
    replaces_drag : bool
        The candidate replaces Td by its own parameter (quadratic drag) instead of adding one.
    stochastic : bool
        Acts on the cycle-to-cycle scatter only (delay jitter).
    on_tests : OnTests or None
        The families' strategy; None: eq. (2)'s only (the physics of its propulsion).
    """

    name: str
    explanation: str
    augmentation: str
    parameter: str
    unit: str
    replaces_drag: bool = False
    stochastic: bool = False
    on_tests: OnTests | None = None


def _static(f: Callable[[float], float]) -> Callable[[TestData], Action]:
    """A static input nonlinearity on the relay's deviation from its bias: the square wave's factor
    and the added mean (:mod:`mrftcli.diagnose.effects`'s docstring)."""
    def act(t: TestData) -> Action:
        hi, lo = f(t.h), f(-t.h)
        return Action(gain=(hi - lo) / (2 * t.h), dc=t.duty * hi + (1 - t.duty) * lo - t.h * (2 * t.duty - 1))
    return act


def _span(tests: Sequence[TestData]) -> float:
    return max(max(t.t_mid for t in tests) - min(t.t_mid for t in tests), 1e-9)


def _w(tests: Sequence[TestData]) -> float:
    return 2 * math.pi * min(t.frequency_hz for t in tests)


def _h_max(tests: Sequence[TestData]) -> float:
    return max(t.h for t in tests)


LIBRARY: tuple[Effect, ...] = (
    Effect(
        "input_bias",
        "A constant disturbance adds to the command at the plant input (hover-thrust trim error, "
        "centre-of-gravity offset). The relay then pushes harder one way than the other: the high and "
        "low half-periods become unequal and the oscillation centre shifts.",
        "plant input = command - hover trim + d",
        "d",
        "command units",
        on_tests=OnTests(("balance",), lambda t, v, _: Action(dc=v), lambda ts: np.linspace(-0.5, 0.5, 21) * _h_max(ts)),
    ),
    Effect(
        "gain_drift",
        "The loop gain changes steadily over the flight (battery sag: the same command gives less "
        "thrust as the voltage drops). At a constant frequency the amplitude drifts with time, and "
        "since the battery scales the hover command too, the trim and the half-period balance drift.",
        "K(t) = K (1 + g t) multiplying the whole command, t from the start of the log",
        "g",
        "1/s",
        on_tests=OnTests(("points", "balance"), lambda t, v, tr: _static(lambda u: (1 + v * (t.t_mid - tr)) * u)(t),
                         lambda ts: np.linspace(-0.8, 0.8, 17) / _span(ts)),
    ),
    Effect(
        "sensor_lag",
        "The measurement passes through an extra first-order lag (a filter or state estimator). It "
        "adds phase that grows like arctan(w T) rather than linearly with frequency as a delay does, "
        "and attenuates the higher harmonics, so one delay cannot absorb it at every beta and harmonic.",
        "y_measured = y / (T_lag s + 1)",
        "T_lag",
        "s",
        on_tests=OnTests(("points",), lambda t, v, _: Action(lag=v),
                         lambda ts: np.concatenate([[0.0], np.geomspace(0.02, 3.0, 14) / _w(ts)])),
    ),
    Effect(
        "quadratic_drag",
        "Drag grows with the square of the speed instead of linearly. The damping then depends on the "
        "oscillation's speed, so the amplitude stops scaling with h, the frequency moves with h and "
        "the waveform is distorted.",
        "y'' = -c y'|y'| + K p in place of y'' = -y'/Td + K p",
        "c",
        "1/output unit",
        replaces_drag=True,
    ),
    Effect(
        "actuator_rate_limit",
        "The actuator slews at a finite rate instead of stepping: the plant sees ramps rather than "
        "relay steps. That is an extra lag of about h/R that grows with the relay height, so the "
        "frequency drops as h grows (a linear loop's frequency does not depend on h).",
        "plant input follows the delayed command at |da/dt| <= R",
        "R",
        "command units/s",
        on_tests=OnTests(("points",), lambda t, v, _: Action(ramp=2 * t.h / v if v > 0 else 0.0),
                         lambda ts: np.concatenate([[math.inf], 2 * _h_max(ts) * _w(ts) / np.geomspace(0.02, 2.0, 14)])),
    ),
    Effect(
        "asymmetric_gain",
        "The plant responds more strongly to the relay's +h than to its -h (or the reverse): thrust goes "
        "with rotor speed squared, ESC curves are not straight. The relay's two half-periods then differ "
        "by an amount that grows with h (a trim error shifts them by the same amount at every h), and "
        "the oscillation centre moves.",
        "plant input = (1 + a) u for u > 0, (1 - a) u for u < 0 (u = command - trim)",
        "a",
        "1",
        on_tests=OnTests(("balance",), lambda t, v, _: _static(lambda u: (1 + v * math.copysign(1.0, u)) * u)(t),
                         lambda ts: np.linspace(-0.5, 0.5, 21)),
    ),
    Effect(
        "actuator_saturation",
        "Trim + u is clipped at an upper limit (throttle or ESC limit), so a large relay step upwards "
        "is cut short. Only the tests whose trim + h reaches the limit change: their upper half-period "
        "lengthens and the centre drops, while the small-h tests follow the linear model.",
        "plant input = min(trim + u, U_max) - trim",
        "U_max",
        "command units",
        on_tests=OnTests(("points", "balance"), lambda t, v, _: _static(lambda u: min(u, v))(t),
                         lambda ts: np.concatenate([[_h_max(ts)], np.linspace(0.98, 0.2, 14) * _h_max(ts)])),
    ),
    Effect(
        "dead_zone",
        "A band of command around the trim gives no response (ESC dead band, stiction): the plant sees "
        "a relay of height h - delta instead of h. The amplitude then grows faster than h (it is "
        "proportional to h - delta), while the period and waveform keep the linear model's.",
        "plant input = sign(u) max(|u| - delta, 0)",
        "delta",
        "command units",
        on_tests=OnTests(("points", "balance"), lambda t, v, _: _static(lambda u: math.copysign(max(abs(u) - v, 0.0), u))(t),
                         lambda ts: np.linspace(0.0, 0.9, 15) * min(t.h for t in ts)),
    ),
    Effect(
        "thrust_rectification",
        "The propulsion lag acts on rotor speed while thrust goes with speed squared. Over a relay "
        "swing of +-h the mean thrust falls short of the mean command by an amount growing with h^2, "
        "and the thrust rises and falls along different curves. The relay makes up the deficit by "
        "staying longer at +h: the half-period balance grows in proportion to h (a trim error's "
        "falls like 1/h, an asymmetric gain's is the same at every h) and the waveform loses its symmetry.",
        "rotor speed q' = (sqrt(1 + w/F) - 1 - q)/Tp, thrust = F ((1 + q)^2 - 1) in place of p' = (w - p)/Tp",
        "F",
        "command units",
    ),
    Effect(
        "bias_drift",
        "The offset of the plant input drifts between the tests (a trim or a disturbance that changes over "
        "the recording). The relay's half-period balance and the output's mean then move from one test to "
        "the next in proportion to the time between them, while each test's cycle keeps its shape.",
        "plant input = command + b (t - t_mid), t_mid the middle of the tests",
        "b",
        "command units/s",
        on_tests=OnTests(("balance",), lambda t, v, tr: Action(dc=v * (t.t_mid - tr)),
                         lambda ts: np.linspace(-0.5, 0.5, 21) * _h_max(ts) / _span(ts)),
    ),
    Effect(
        "delay_jitter",
        "The transport delay varies randomly from one command to the next (scheduling, a "
        "non-real-time link). Each switch then lands early or late: the cycle-to-cycle period "
        "scatter exceeds what the sensor noise and the controller's sampling explain.",
        "tau_k = tau + d_k, d_k Gauss-Markov with std sigma (correlation 0.05 s)",
        "sigma",
        "s",
        stochastic=True,
        on_tests=OnTests(("points", "scatter"), lambda t, v, _: Action(jitter=v),
                         lambda ts: np.concatenate([[0.0], np.geomspace(1e-3, 0.1, 14)
                                                    / (2 * math.pi * max(t.frequency_hz for t in ts))])),
    ),
)

BY_NAME: dict[str, Effect] = {e.name: e for e in LIBRARY}
#: eq. (2)'s library, in its fitting order (the drift of a bias between tests is the families' only)
CANDIDATES: tuple[Effect, ...] = tuple(BY_NAME[n] for n in (
    "input_bias", "gain_drift", "sensor_lag", "quadratic_drag", "actuator_rate_limit", "asymmetric_gain",
    "actuator_saturation", "dead_zone", "thrust_rectification", "delay_jitter"))
#: the families' library, in its fitting order: every effect with a strategy on the tests
EFFECTS: tuple[Effect, ...] = tuple(BY_NAME[n] for n in (
    "sensor_lag", "actuator_rate_limit", "dead_zone", "actuator_saturation", "asymmetric_gain", "input_bias",
    "gain_drift", "bias_drift", "delay_jitter"))


def df_quadratic_drag(Td: float, velocity_amplitude: float) -> float:
    """Describing-function equivalent: c with the same first-harmonic damping as 1/Td at speed V.

    The first harmonic of c v|v| for v = V sin(wt) is (8 / (3 pi)) c V v, so 1/Td = 8 c V / (3 pi).
    """
    return 3.0 * math.pi / (8.0 * Td * velocity_amplitude)


def unit_in_loop(unit: str | None, loop: str) -> str | None:
    """A candidate parameter's unit with the loop's output unit spelt out, as the terminal shows it.

    Examples
    --------
    >>> unit_in_loop("1/output unit", "altitude"), unit_in_loop("command units/s", "roll")
    ('1/m', 'command units/s')
    """
    return None if unit is None else unit.replace("output unit", output_unit(loop))
