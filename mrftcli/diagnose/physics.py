"""The library of candidate physics that the linear model G(s) of eq. (2) leaves out.

Each candidate has a JSON name, a plain-language explanation, the augmentation of the model it
stands for, its own parameter (name, unit, bounds, a data-driven starting value) and the way it
changes the model's limit cycle (:func:`plant_for`). :mod:`mrftcli.diagnose.selection` fits every candidate
together with the base parameters (Td, tau, K) and selects by evidence.

Parameterisation used by the fit (all O(1) so finite differences behave): the base vector is
``[ln Td, 10 tau]``; K is eliminated in closed form (Lemma 2 of the paper: frequency and waveform
shape are invariant to K, the amplitude scales with it). Quadratic drag replaces the linear drag, so
its vector is ``[ln q, 10 tau]`` with q = c K (the limit cycle depends on c and K only through c K up
to the amplitude scale), then c = q / K.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..io.logtypes import output_unit

__all__ = ["Candidate", "CANDIDATES", "BY_NAME", "unit_in_loop"]


@dataclass(frozen=True)
class Candidate:
    """One candidate physical effect.

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
    """

    name: str
    explanation: str
    augmentation: str
    parameter: str
    unit: str
    replaces_drag: bool = False
    stochastic: bool = False


CANDIDATES: tuple[Candidate, ...] = (
    Candidate(
        "input_bias",
        "A constant disturbance adds to the command at the plant input (hover-thrust trim error, "
        "centre-of-gravity offset). The relay then pushes harder one way than the other: the high and "
        "low half-periods become unequal and the oscillation centre shifts.",
        "plant input = command - hover trim + d",
        "d",
        "command units",
    ),
    Candidate(
        "gain_drift",
        "The loop gain changes steadily over the flight (battery sag: the same command gives less "
        "thrust as the voltage drops). At a constant frequency the amplitude drifts with time, and "
        "since the battery scales the hover command too, the trim and the half-period balance drift.",
        "K(t) = K (1 + g t) multiplying the whole command, t from the start of the log",
        "g",
        "1/s",
    ),
    Candidate(
        "sensor_lag",
        "The measurement passes through an extra first-order lag (a filter or state estimator). It "
        "adds phase that grows like arctan(w T) rather than linearly with frequency as a delay does, "
        "and attenuates the higher harmonics, so one delay cannot absorb it at every beta and harmonic.",
        "y_measured = y / (T_lag s + 1)",
        "T_lag",
        "s",
    ),
    Candidate(
        "quadratic_drag",
        "Drag grows with the square of the speed instead of linearly. The damping then depends on the "
        "oscillation's speed, so the amplitude stops scaling with h, the frequency moves with h and "
        "the waveform is distorted.",
        "y'' = -c y'|y'| + K p in place of y'' = -y'/Td + K p",
        "c",
        "1/output unit",
        replaces_drag=True,
    ),
    Candidate(
        "actuator_rate_limit",
        "The actuator slews at a finite rate instead of stepping: the plant sees ramps rather than "
        "relay steps. That is an extra lag of about h/R that grows with the relay height, so the "
        "frequency drops as h grows (a linear loop's frequency does not depend on h).",
        "plant input follows the delayed command at |da/dt| <= R",
        "R",
        "command units/s",
    ),
    Candidate(
        "asymmetric_gain",
        "The plant responds more strongly to the relay's +h than to its -h (or the reverse): thrust goes "
        "with rotor speed squared, ESC curves are not straight. The relay's two half-periods then differ "
        "by an amount that grows with h (a trim error shifts them by the same amount at every h), and "
        "the oscillation centre moves.",
        "plant input = (1 + a) u for u > 0, (1 - a) u for u < 0 (u = command - trim)",
        "a",
        "1",
    ),
    Candidate(
        "actuator_saturation",
        "Trim + u is clipped at an upper limit (throttle or ESC limit), so a large relay step upwards "
        "is cut short. Only the tests whose trim + h reaches the limit change: their upper half-period "
        "lengthens and the centre drops, while the small-h tests follow the linear model.",
        "plant input = min(trim + u, U_max) - trim",
        "U_max",
        "command units",
    ),
    Candidate(
        "dead_zone",
        "A band of command around the trim gives no response (ESC dead band, stiction): the plant sees "
        "a relay of height h - delta instead of h. The amplitude then grows faster than h (it is "
        "proportional to h - delta), while the period and waveform keep the linear model's.",
        "plant input = sign(u) max(|u| - delta, 0)",
        "delta",
        "command units",
    ),
    Candidate(
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
    Candidate(
        "delay_jitter",
        "The transport delay varies randomly from one command to the next (scheduling, a "
        "non-real-time link). Each switch then lands early or late: the cycle-to-cycle period "
        "scatter exceeds what the sensor noise and the controller's sampling explain.",
        "tau_k = tau + d_k, d_k Gauss-Markov with std sigma (correlation 0.05 s)",
        "sigma",
        "s",
        stochastic=True,
    ),
)

BY_NAME = {c.name: c for c in CANDIDATES}


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
