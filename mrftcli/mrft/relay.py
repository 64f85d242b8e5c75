"""The MRFT switching rule on sampled errors (checks.md section 2, the HEAR flight stack's rule).

One home for the rule the diagnosis' sampled relay (:func:`mrftcli.diagnose.limit_cycles.run_relay`)
and the simulator (:mod:`mrftcli.sim.control`, which re-exports it) both decide with; the tests check
it against an independent transcription of the rule (``tests/relay_rule.py``).
"""

from __future__ import annotations

from ..validate import check_beta

__all__ = ["MrftRelay"]


class MrftRelay:
    """The MRFT switching rule of checks.md section 2 on sampled errors (returns the relay sign).

    e = r - y. While +h, track e_max since the last switch and switch to -h when e_max > 0 and
    e <= -beta e_max; while -h, track e_min and switch to +h when e_min < 0 and e >= -beta e_min.
    The tracked extremum restarts at the error of the switching sample.

    Start (:meth:`start`): the relay takes the sign of the first error (+ for e >= 0) and keeps it
    until the error is beyond ``start_threshold`` on the other side; that sample is the first switch
    and the rule above applies from there. With the vehicle at rest at the start, this keeps
    switching from beginning at noise level (the plain rule can then lock up); 0 means the first
    switch is at the first sample with the opposite sign.
    """

    def __init__(self, beta: float, start_threshold: float = 0.0) -> None:
        check_beta(beta)
        self.beta = float(beta)
        self.start_threshold = float(start_threshold)
        self.relay = 1.0
        self.e_ext = 0.0
        self.first_half = True

    def start(self, e: float) -> float:
        self.relay = 1.0 if e >= 0 else -1.0
        self.e_ext = e
        self.first_half = True
        return self.relay

    def step(self, e: float) -> float:
        if self.first_half:
            if self.relay * e < -self.start_threshold:
                self.relay = -self.relay
                self.e_ext = e
                self.first_half = False
        elif self.relay > 0:
            if e > self.e_ext:
                self.e_ext = e
            if self.e_ext > 0 and e <= -self.beta * self.e_ext:
                self.relay = -1.0
                self.e_ext = e
        else:
            if e < self.e_ext:
                self.e_ext = e
            if self.e_ext < 0 and e >= -self.beta * self.e_ext:
                self.relay = 1.0
                self.e_ext = e
        return self.relay
