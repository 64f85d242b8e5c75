"""The flight loop around a simulator written elsewhere: hold, MRFT relay, sensor, latency (issue 39).

Nothing here comes from ``mrftcli``'s simulator or relay: the relay (the PX4 fork's and HEAR's
``mrft_anti_false_switching``, ported line by line), the hold controller, the sensor chain (flexible
mount, first-order filter, noise) and the latency line are written out below,
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
    """The MRFT relay as the stacks fly it: the PX4 fork's ``MRFT_Block::mrft_anti_false_switching``,
    ``mode_of_operation`` 1, ported line by line; HEAR's ``MRFTController::mrft_anti_false_switching``
    (oussamaabdulhay/HEAR_Architecture @04c69c3, ``src/MRFTController.cpp``) is the same code.

    Sources, abdullaayyad96/PX4-Autopilot @a08b08d:

    * ``src/lib/MRFT/src/MRFT.cpp:76-186``, the function. First call 95-112; the no-switch window
      116-120; the -h branch 122-151; the +h branch 152-181.
    * ``src/lib/MRFT/include/DataTypes.hpp:101``: the defaults ``no_switch_delay_in_ms`` 20 and
      ``num_of_peak_conf_samples`` 5. HEAR's ``include/HEAR_control/MRFT_values.hpp`` has the same.
    * ``src/lib/MRFT/include/Timer.hpp:21``: ``tockMilliSeconds()`` returns whole milliseconds (an int).
    * ``src/modules/mc_pos_control/mc_pos_control_params.c:917,927``: the PX4 parameters
      ``MRFT_Z_NO_SWITCH`` 20 and ``MRFT_Z_N_CONF`` 5.

    Per call, with the error e:

    * first call: the output is +h if e > 0 else -h, that side's peak counted as reached, both peaks 0;
    * for ``no_switch_ms`` after each switch (the timer's whole milliseconds <= the delay) nothing moves;
    * on +h: a new maximum sets e_max and resets the confirmation counter. Any other sample counts one
      and sets e_min to itself, so e_min ends as the last sample that was not a new maximum. Mode 1's
      threshold on +h does not read e_min; it is only the -h side's starting minimum after the switch.
      ``n_conf`` counts latch "maximum reached" (a later new maximum moves the threshold, not the
      latch); once latched, e < -beta e_max switches to -h. On -h the mirror image.

    The switch threshold -beta e_peak is the fork's ``sw_max`` / ``sw_min`` of mode 1
    (e_max - (e_max - e_min*) / 2 - beta (e_max - e_min*) / 2 with e_min* = -e_max). The confirmation
    counter is not reset by a switch, as in the fork.

    One simplification: ``period`` [s] is the loop's nominal tick, and the no-switch window counts
    ticks. The fork's timer reads real time (``CLOCK_REALTIME``). Only the delay-jitter flights
    (``LoopSpec.jitter``) are touched. There the real time between a switch and a later call would differ
    from the counted ticks by the two calls' difference in lateness. At the draws' 12 ms std of lateness
    that difference has about 17 ms std: about one tick at 50 Hz, several at 500 Hz. The port's 20 ms
    window ignores it.

    The relay's output is +-1 here; :func:`fly` sends ``bias + h * relay``. That trim is HEAR's: its
    ``MRFTController::runTask`` sends ``mrft_anti_false_switching(...) + parameters.bias``
    (``src/MRFTController.cpp:51``). The fork's z has no trim: ``PositionMRFT.cpp:117-121`` sets
    ``_thr_sp(2)`` to the relay's +-h, and ``mc_pos_control_main.cpp:726-727`` puts it in place of the
    thrust setpoint with weight 1."""

    def __init__(self, beta: float, period: float, n_conf: int = 5, no_switch_ms: int = 20) -> None:
        self.beta, self.period, self.n_conf, self.no_switch_ms = beta, period, n_conf, no_switch_ms
        self.first, self.out, self.e_max, self.e_min = True, 0.0, 0.0, 0.0
        self.reached_max = self.reached_min = False
        self.count, self.ticks = 0, 0  # confirmation counter; ticks since the last switch (the fork's timer)

    @property
    def sign(self) -> float:
        """The relay's side (+1, -1; 0 before the first call)."""
        return 1.0 if self.out > 0 else -1.0 if self.out < 0 else 0.0

    @property
    def peak(self) -> float:
        """The running peak of the side the relay is on [error units]."""
        return self.e_max if self.out > 0 else self.e_min

    def __call__(self, e: float) -> float:
        if self.first:
            self.first, self.ticks, self.count, self.e_max, self.e_min = False, 0, 0, 0.0, 0.0
            self.reached_max, self.reached_min = e > 0, not e > 0
            self.out = 1.0 if e > 0 else -1.0
            return self.out
        self.ticks += 1
        if math.floor(self.ticks * self.period * 1e3 + 1e-6) <= self.no_switch_ms:  # tockMilliSeconds() is an int
            return self.out
        if self.out < 0:
            if e < self.e_min:
                self.e_min, self.count = e, 0
            else:
                self.count += 1
                if self.count >= self.n_conf:
                    self.reached_min, self.count = True, 0
                self.e_max = e
            if self.reached_min and e > -self.beta * self.e_min:
                self.out, self.ticks, self.reached_min = 1.0, 0, False
        else:
            if e > self.e_max:
                self.e_max, self.count = e, 0
            else:
                self.count += 1
                if self.count >= self.n_conf:
                    self.reached_max, self.count = True, 0
                self.e_min = e
            if self.reached_max and e < -self.beta * self.e_max:
                self.out, self.ticks, self.reached_max = -1.0, 0, False
        return self.out


@dataclass(frozen=True)
class LoopSpec:
    """One flight: rate [Hz], tests ((beta, h [command units], duration [s]), ...), latency [s],
    sensor noise [m]; the relay's ``n_conf`` and ``no_switch_ms`` (the fork's defaults); the loop-side effects: a first-order filter on the logged altitude (``lag`` [s]),
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
    n_conf: int = 5  # the relay's peak confirmation samples (the fork's MRFT_Z_N_CONF)
    no_switch_ms: int = 20  # [ms] the relay's no-switch window after a switch (the fork's MRFT_Z_NO_SWITCH)
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
    relays = [Relay(beta, T, spec.n_conf, spec.no_switch_ms) for beta, _, _ in spec.tests]
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
            u = bias + spec.tests[j][1] * relays[j](e)  # HEAR's runTask: relay + bias (the fork's z has none)
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
