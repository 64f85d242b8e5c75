"""A simulated flight as a recorder that stamps messages on arrival would log it.

Real stacks publish the relay command without a header (HEAR's ``geometry_msgs/Point``, many MRFT
nodes' ``std_msgs/Float64``), so the bag holds the recorder's receive time: the controller's tick plus
a random transport and scheduling delay, and some messages never arrive. :func:`receive_stamped`
draws that for one topic; :func:`recorded_flight` turns a :class:`~mrftcli.sim.flight.SimulatedFlight`
into the :class:`~mrftcli.io.logtypes.FlightLog` a reader would return, with the command and/or
the output stamped on arrival (the benchmarks' and tests' receive-stamped logs, no file written).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..io.logtypes import FlightLog, Signal
from ..io.timing import Timing, receive_jitter_s
from .flight import SimulatedFlight

__all__ = ["ReceiveStamping", "receive_stamped", "recorded_flight"]


@dataclass(frozen=True)
class ReceiveStamping:
    """How a topic's messages reach the recorder.

    Attributes
    ----------
    late_max : float
        Each message arrives late by a uniform 0..``late_max`` [s] (0: stamped at the source).
    drop : float
        Probability that a message never arrives [-], in [0, 1).
    """

    late_max: float = 0.003
    drop: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.late_max) and self.late_max >= 0):
            raise InputError(f"late_max must be >= 0 s, got {self.late_max!r}")
        if not (0.0 <= self.drop < 1.0):
            raise InputError(f"drop must be a probability in [0, 1), got {self.drop!r}")


def receive_stamped(t: NDArray[np.float64], stamping: ReceiveStamping,
                    rng: np.random.Generator) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """The messages that arrive and their receive times.

    Parameters
    ----------
    t : numpy.ndarray
        Send times [s] (the controller's ticks), increasing.
    stamping : ReceiveStamping
        Lateness and drops.
    rng : numpy.random.Generator
        Source of the lateness and the drops.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Indices of the messages that arrive, and their receive times [s] (increasing: a recorder
        writes one topic's messages in arrival order, 1 us apart at least).

    Examples
    --------
    >>> t = 0.005 * np.arange(1000)
    >>> k, tr = receive_stamped(t, ReceiveStamping(0.003, 0.01), np.random.default_rng(0))
    >>> bool(k.size < 1000 and np.all(tr >= t[k]) and np.all(tr - t[k] <= 0.003))
    True
    """
    t = np.asarray(t, float)
    keep = np.flatnonzero(rng.random(t.size) >= stamping.drop) if stamping.drop > 0 else np.arange(t.size)
    late = rng.uniform(0.0, stamping.late_max, keep.size)
    ramp = 1e-6 * np.arange(keep.size)
    arrived: NDArray[np.float64] = np.maximum.accumulate(t[keep] + late - ramp) + ramp
    return keep, arrived


def recorded_flight(flight: SimulatedFlight, *, command: ReceiveStamping | None = None,
                    output: ReceiveStamping | None = None, seed: int = 0) -> FlightLog:
    """The flight's command and measured output as a reader returns them (no file written).

    Parameters
    ----------
    flight : SimulatedFlight
        The simulated flight (every controller tick).
    command, output : ReceiveStamping, optional
        How each topic reaches the recorder; None: stamped at the source, every tick logged
        (``late_max=0`` with ``drop`` > 0: stamped at the source, some messages lost).
    seed : int
        Seed of the lateness and the drops.

    Returns
    -------
    FlightLog
        ``timing.stamps`` is ``"receive"`` when either topic arrives late (with the jitter a
        reader measures, :func:`mrftcli.io.timing.receive_jitter_s`).
    """
    rng = np.random.default_rng(seed)
    t = np.asarray(flight.t, float)

    def topic(values: NDArray[np.float64], stamping: ReceiveStamping | None) -> Signal:
        if stamping is None:
            return Signal(t, np.asarray(values, float))
        k, tr = receive_stamped(t, stamping, rng)
        return Signal(tr, np.asarray(values, float)[k])

    cmd, out = topic(flight.command, command), topic(flight.output_measured, output)
    timing = Timing()
    if any(s is not None and s.late_max > 0 for s in (command, output)):
        timing = Timing(None, "receive", max(receive_jitter_s(cmd.t), receive_jitter_s(out.t)))
    return FlightLog(path="simulated", loop=flight.spec.loop, command=cmd, output=out, timing=timing,
                     source={"format": "simulated"})
