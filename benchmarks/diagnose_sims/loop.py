"""The flight loop around a simulator written elsewhere: hold, MRFT relay, sensor, latency (issue 39).

Nothing here comes from ``mrftcli``'s simulator or relay: the relay rule, the hold controller, the
sensor chain (flexible mount, first-order filter, noise) and the latency line are written out below,
and the vehicle (RotorPy's or JSBSim's) integrates its own physics. Only the log is written with
``mrftcli.io.write_log``, as any flight stack's recorder would.

A vehicle adapter provides ``altitude() -> float`` [m, up], ``advance(u, dt)`` (hold the plant
input ``u`` [command units] for ``dt`` [s]), ``hover`` (the trim command) and ``planning`` (a rough
:class:`PlanningModel` a pilot would know before the flight, only used to pick the relay heights).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

_DEBUG = False

__all__ = ["Vehicle", "PlanningModel", "LoopSpec", "FlightRecord", "fly", "flight_topics", "relay_height"]


class Vehicle(Protocol):
    hover: float

    def altitude(self) -> float: ...

    def advance(self, u: float, dt: float) -> None: ...


@dataclass(frozen=True)
class PlanningModel:
    """What the pilot knows before flying: K [m/s^2 per command unit], Td, tau, Tp [s]."""

    K: float
    Td: float
    tau: float
    Tp: float


def relay_height(model: PlanningModel, beta: float, amplitude: float) -> float:
    """The relay height [command units] whose describing-function amplitude is ``amplitude`` [m].

    The MRFT oscillates where arg G(jw) = -pi + arcsin(beta) (so the relay's switch leads the error's
    zero by arcsin(-beta)); its amplitude is 4 h |G(jw)| / pi. G = K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1)).
    """
    target = -math.pi + math.asin(beta)

    def phase(w: float) -> float:
        return -w * model.tau - math.pi / 2 - math.atan(w * model.Tp) - math.atan(w * model.Td)

    lo, hi = 1e-3, 1e3
    for _ in range(100):  # phase falls monotonically in w
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if phase(mid) > target else (lo, mid)
    w = math.sqrt(lo * hi)
    gain = model.K * model.Td / (w * math.hypot(1, w * model.Tp) * math.hypot(1, w * model.Td))
    return amplitude * math.pi / (4.0 * gain)


class Relay:
    """MRFT (Boiko 2013): leave +h once the error has fallen from its peak e_max > 0 to -beta e_max
    (beta < 0: before the zero crossing), leave -h likewise from the trough; the first switch waits for
    the error to cross ``start`` beyond zero so noise at rest does not start it. As flight stacks do
    against noise-triggered switches (which lock the relay up), a peak counts once ``confirm`` samples
    have passed without a new one."""

    def __init__(self, beta: float, start: float, confirm: int) -> None:
        self.beta, self.start, self.confirm = beta, start, confirm
        self.sign, self.peak, self.armed, self.age = 0.0, 0.0, False, 0

    def _switch(self, sign: float, e: float) -> None:
        self.sign, self.peak, self.age = sign, e, 0

    def __call__(self, e: float) -> float:
        if self.sign == 0.0:
            self._switch(1.0 if e >= 0 else -1.0, e)
            return self.sign
        if not self.armed:
            if self.sign * e < -self.start:
                self._switch(-self.sign, e)
                self.armed = True
            return self.sign
        self.age += 1
        if self.sign * e > self.sign * self.peak:  # a new extremum of this half
            self.peak, self.age = e, 0
        confirmed = self.age >= self.confirm
        if self.sign > 0 and confirmed and self.peak > 0 and e <= -self.beta * self.peak:
            self._switch(-1.0, e)
        elif self.sign < 0 and confirmed and self.peak < 0 and e >= -self.beta * self.peak:
            self._switch(1.0, e)
        return self.sign


@dataclass(frozen=True)
class LoopSpec:
    """One flight: rate [Hz], tests ((beta, h [command units], duration [s]), ...), latency [s],
    sensor noise [m]; the loop-side effects: a first-order filter on the logged altitude (``lag`` [s]),
    a flexible sensor mount (``mount_hz``, ``mount_zeta``), a loop that runs late by a random
    ``jitter`` [s std] each tick."""

    rate: float
    tests: tuple[tuple[float, float, float], ...]
    latency: float
    noise: float
    seed: int
    lag: float = 0.0
    mount_hz: float = 0.0
    mount_zeta: float = 0.05
    jitter: float = 0.0
    hover_s: float = 2.0
    hold_s: float = 2.5
    abort: float = 0.5  # [m] the safety abort's error
    start: float = 0.0  # [m] the error beyond which the relay makes its first switch (at least 10 noise std)
    planning: PlanningModel | None = None


@dataclass
class FlightRecord:
    t: np.ndarray
    command: np.ndarray
    y_meas: np.ndarray
    y_true: np.ndarray
    y_mount: np.ndarray  # the mount's output before filter and noise (= y_true without a mount)
    setpoint: float
    test_starts: list[float] = field(default_factory=list)
    test_ends: list[float] = field(default_factory=list)
    aborted: list[bool] = field(default_factory=list)


class Mount:
    """A sensor on a spring: y_s'' = wn^2 (y - y_s) - 2 zeta wn y_s', y linear between ticks (RK4 substeps)."""

    def __init__(self, hz: float, zeta: float, y0: float) -> None:
        self.wn, self.zeta, self.x = 2 * math.pi * hz, zeta, np.array([y0, 0.0])

    def advance(self, y0: float, y1: float, dt: float) -> float:
        n = max(4, int(math.ceil(dt * self.wn / 0.2)))
        h = dt / n

        def f(x: np.ndarray, y: float) -> np.ndarray:
            return np.array([x[1], self.wn**2 * (y - x[0]) - 2 * self.zeta * self.wn * x[1]])

        x = self.x
        for i in range(n):
            ya, ym, yb = (y0 + (y1 - y0) * s / n for s in (i, i + 0.5, i + 1))
            k1 = f(x, ya)
            k2 = f(x + 0.5 * h * k1, ym)
            k3 = f(x + 0.5 * h * k2, ym)
            k4 = f(x + h * k3, yb)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        self.x = x
        return float(x[0])


def _schedule(spec: LoopSpec) -> tuple[np.ndarray, list[tuple[int, int]]]:
    T = 1.0 / spec.rate
    k, ranges = int(round(spec.hover_s / T)), []
    for _, _, dur in spec.tests:
        n = int(round(dur / T))
        ranges.append((k, k + n))
        k += n + int(round(spec.hold_s / T))
    mode = np.full(k, -1)
    for j, (a, b) in enumerate(ranges):
        mode[a:b] = j
    return mode, ranges


def fly(vehicle: Vehicle, spec: LoopSpec) -> FlightRecord:
    """Fly the spec's tests on ``vehicle``: the log's command, measured and true altitude per tick."""
    rng = np.random.default_rng(spec.seed)
    T = 1.0 / spec.rate
    mode, ranges = _schedule(spec)
    n = mode.size
    model = spec.planning
    assert model is not None
    # the hold: a PID on the altitude error, crossover ~2.5 rad/s on the planning model
    wc = 2.5
    kp, kd, ki = wc**2 / model.K, 1.6 * wc / model.K, 0.4 * wc**3 / model.K / 4
    r = vehicle.altitude()
    t = np.arange(n) * T
    cmd, y_meas, y_true, y_mount = (np.empty(n) for _ in range(4))
    mount = Mount(spec.mount_hz, spec.mount_zeta, r) if spec.mount_hz > 0 else None
    a_lag = math.exp(-T / spec.lag) if spec.lag > 0 else 0.0
    filt, integ, yprev, dterm = r, 0.0, r, 0.0
    confirm = max(1, int(round(0.01 * spec.rate)))  # 10 ms of samples
    relays = [Relay(beta, max(10 * spec.noise, spec.start), confirm) for beta, _, _ in spec.tests]
    bias, aborted = vehicle.hover, [False] * len(spec.tests)
    pending: list[tuple[float, float]] = []  # (time the command reaches the motors, command)
    u_plant, last_apply = vehicle.hover, 0.0
    y_now = vehicle.altitude()
    for k in range(n):
        y_true[k] = y_now
        y_mount[k] = mount.x[0] if mount is not None else y_now
        filt = a_lag * filt + (1 - a_lag) * y_mount[k]
        y_meas[k] = filt + spec.noise * rng.standard_normal()
        e = r - y_meas[k]
        j = mode[k]
        if j >= 0 and abs(e) > spec.abort:
            aborted[j] = True  # the safety abort: the hold takes over for the rest of the test
            if _DEBUG:
                print(f"abort test {j} at {t[k]:.2f} s: e {e:+.4f} m, relay {relays[j].sign:+.0f}, peak {relays[j].peak:+.4f}")
            mode[k:ranges[j][1]] = -1
            j = -1
        dterm = 0.7 * dterm - 0.3 * kd * (y_meas[k] - yprev) / T
        if j < 0:
            integ += ki * e * T
            u = vehicle.hover + integ + kp * e + dterm
            bias = vehicle.hover + integ
        else:
            u = bias + spec.tests[j][1] * relays[j](e)
        yprev = y_meas[k]
        cmd[k] = u
        # a loop that runs late: half-normal lateness of scale ``jitter`` (std 0.60 jitter), independent per tick
        late = abs(rng.normal(0.0, spec.jitter)) if spec.jitter > 0 else 0.0
        last_apply = max(last_apply, t[k] + spec.latency + late)  # a command never overtakes an older one
        pending.append((last_apply, u))
        # advance the vehicle over [t_k, t_k + T], switching the plant input where commands arrive
        now, end = t[k], t[k] + T
        while pending and pending[0][0] < end:
            when, val = pending.pop(0)
            if when > now:
                vehicle.advance(u_plant, when - now)
                now = when
            u_plant = val
        vehicle.advance(u_plant, end - now)
        y_next = vehicle.altitude()
        if mount is not None:
            mount.advance(y_now, y_next, T)
        y_now = y_next
    return FlightRecord(t=t, command=cmd, y_meas=y_meas, y_true=y_true, y_mount=y_mount, setpoint=r,
                        test_starts=[t[a] for a, _ in ranges], test_ends=[t[b - 1] for _, b in ranges],
                        aborted=aborted)


def flight_topics(rec: FlightRecord, betas: list[float]) -> list:
    """The reference layout (``/mrft/command``, ``/mrft/beta``, ``/mrft/setpoint``, ``/mocap/pose``)."""
    from mrftcli.io.logtypes import TopicData

    f64 = "std_msgs/msg/Float64"
    t = rec.t
    sp = np.arange(0, t.size, 10)
    return [TopicData("/mrft/command", f64, t.copy(), {"data": rec.command.copy()}),
            TopicData("/mrft/beta", f64, np.array(rec.test_starts), {"data": np.array(betas, float)}),
            TopicData("/mrft/setpoint", f64, t[sp].copy(), {"data": np.full(sp.size, rec.setpoint)}),
            TopicData("/mocap/pose", "geometry_msgs/msg/PoseStamped", t.copy(),
                      {"pose.position.z": rec.y_meas.copy(), "pose.orientation.w": np.ones(t.size)})]
