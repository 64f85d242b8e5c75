"""The MRFT switching rule of checks.md section 2, written here independently of :mod:`mrftcli.sim`.

Tests use it as the oracle a simulated relay must follow; benchmarks (bench_engine, bench_simulate)
use it in their plain reference loops (they put ``tests/`` on ``sys.path``).
"""

from __future__ import annotations

from typing import Sequence


def relay_step(s: float, ext: float, e: float, beta: float) -> tuple[float, float]:
    """One sample of the started relay: ``(s, ext)`` after the error ``e`` [output units].

    ``s`` is the relay's sign (+1 / -1) and ``ext`` the error's extreme since the last switch: the
    relay switches down once the error falls to ``-beta`` times its maximum (which must be positive),
    and up once it rises to ``-beta`` times its minimum (negative); ``ext`` restarts at the switch.

    Examples
    --------
    >>> relay_step(1.0, 0.0, 0.5, -0.4)
    (1.0, 0.5)
    >>> relay_step(1.0, 0.5, 0.2, -0.4)
    (-1.0, 0.2)
    """
    if s > 0:
        ext = max(ext, e)
        if ext > 0 and e <= -beta * ext:
            return -1.0, e
    else:
        ext = min(ext, e)
        if ext < 0 and e >= -beta * ext:
            return 1.0, e
    return s, ext


def relay_signs(errors: Sequence[float], beta: float, eth: float) -> list[float]:
    """The relay's sign at each error sample, as a flight stack starts a test: the first sign from the
    first error, held until the error crosses ``eth`` the other way (the test's start), then
    :func:`relay_step` (the SITL relays of ArduPilot and PX4 are checked against this)."""
    s = 1.0 if errors[0] >= 0 else -1.0
    signs, ext, started = [s], float(errors[0]), False
    for e in errors[1:]:
        if not started:
            if s * e < -eth:
                s, ext, started = -s, float(e), True
        else:
            s, ext = relay_step(s, ext, float(e), beta)
        signs.append(s)
    return signs
