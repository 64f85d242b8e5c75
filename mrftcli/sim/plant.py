"""The simulator's plant: the static command shaper.

The exact propagators, the RK4 steps, the actuator between ticks and the jittered delay live in
:mod:`mrftcli.mrft.propagate` (the diagnosis integrates with them too, and must not import the
simulator, its tests' oracle). See docs/simulator.md, "Integration".
"""

from __future__ import annotations

import math

__all__ = ["command_shaper"]


def command_shaper(bias: float, asymmetric_gain: float = 0.0, saturation: float = 0.0, dead_zone: float = 0.0):
    """The static command nonlinearity between the controller and the actuator, or None (identity).

    Deviations d = u - bias from the trim: a dead band |d| <= ``dead_zone`` gives nothing (ESC dead
    band, stiction), beyond it the command moves by |d| - dead_zone; the plant then responds with
    gain 1 + ``asymmetric_gain`` to positive and 1 - ``asymmetric_gain`` to negative deviations; the
    result is clipped at the absolute command ``saturation`` (0: no limit).

    >>> f = command_shaper(0.5, asymmetric_gain=0.1, dead_zone=0.01, saturation=0.58)
    >>> [round(f(u), 4) for u in (0.4, 0.5, 0.505, 0.56, 0.7)]
    [0.419, 0.5, 0.5, 0.555, 0.58]
    """
    if asymmetric_gain == 0.0 and saturation == 0.0 and dead_zone == 0.0:
        return None

    def shape(u: float) -> float:
        d = u - bias
        if dead_zone > 0.0:
            d = math.copysign(max(abs(d) - dead_zone, 0.0), d)
        d *= (1.0 + asymmetric_gain) if d > 0 else (1.0 - asymmetric_gain)
        v = bias + d
        return min(v, saturation) if saturation > 0.0 else v

    return shape
