"""MRFT flights of the process plants of issue 22 (FOPDT, SOPDT, IPDT, FOIPDT), with known truth.

``simulate --model NAME --param ...``: the same flight as the eq. (2) simulator (hover, each test then
a hold, the sampled MRFT rule of checks.md section 2 or HEAR's, the zero-order hold, the exact
delay) on a process family's realisation (:meth:`PlantModel.realisation`, y = C x, the command
reaching the plant ``delay`` late). The operating point is the origin: command 0 (``bias``) holds
output 0 (the setpoint), so the plant sees the command itself. Between tests a PID designed on the
family's frequency response (:func:`process_hold`) holds the setpoint.

Between the ticks the plant is propagated exactly: a period splits at the delay's fraction, each piece
one precomputed affine map (the exponential of the augmented matrix). The truth is a versioned
record (:class:`ProcessTruth`, ``<log>.truth.json``); the log is written in the reference layout.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..io.logtypes import LOOPS, TopicData
from ..jsonable import check_schema_version
from ..mrft.model import PlantModel, model_from_json
from ..validate import check_beta
from .cascade_spec import InnerGains
from .control import SWITCHING_RULES, HearMrftRelay, MrftRelay, make_relay
from .plant import taylor_expm
from .sidecar import sidecar_path, write_log_atomic
from .spec import TestSpec, check_flight_size

__all__ = ["ProcessSpec", "ProcessTruth", "ProcessFlight", "simulate_process", "write_process", "process_hold",
           "plan_process_test", "PROCESS_TRUTH_SCHEMA"]

#: schema version of :class:`ProcessTruth`
PROCESS_TRUTH_SCHEMA = 1

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ProcessSpec:
    """One flight of a process plant.

    Attributes
    ----------
    model : PlantModel
        A process family's model (``mrftcli.mrft.families``) with its true parameters.
    tests : tuple of TestSpec
        The MRFT tests (h in command units).
    loop : str
        Where the reference layout puts the output (``altitude``: ``/mocap/pose`` z).
    rate_hz : float
        Controller rate [Hz].
    noise_std : float
        White output noise per tick [output units].
    hover_s, hold_s : float
        Hold before the first test and after each test [s].
    seed : int
    start_time : float
        Log time of the first tick [s].
    switching : {"checks", "hear"}
        The MRFT switching rule.
    """

    model: PlantModel
    tests: tuple[TestSpec, ...]
    loop: str = "altitude"
    rate_hz: float = 200.0
    noise_std: float = 0.0
    hover_s: float = 5.0
    hold_s: float = 4.0
    seed: int = 0
    start_time: float = 0.0
    switching: str = "checks"

    def __post_init__(self) -> None:
        if self.loop not in LOOPS:
            raise InputError(f"unknown loop {self.loop!r}; use one of {', '.join(LOOPS)}")
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise InputError(f"the controller rate must be a positive frequency in Hz, got {self.rate_hz!r}")
        if not (math.isfinite(self.noise_std) and self.noise_std >= 0):
            raise InputError(f"the noise std must be >= 0, got {self.noise_std!r}")
        if self.switching not in SWITCHING_RULES:
            raise InputError(f"unknown switching rule {self.switching!r}; use one of {', '.join(SWITCHING_RULES)}")
        if not self.tests:
            raise InputError("give at least one MRFT test (beta and h)")
        for i, test in enumerate(self.tests, 1):
            check_beta(test.beta)
            if not (math.isfinite(test.h) and test.h > 0):
                raise InputError(f"test {i}: the relay height h must be positive, got {test.h!r}")
            if not (math.isfinite(test.duration) and test.duration * self.rate_hz >= 2):
                raise InputError(f"test {i}: the duration must cover at least two controller periods")
        check_flight_size(self.hover_s + sum(t.duration + self.hold_s for t in self.tests), self.rate_hz)


@dataclass(frozen=True)
class ProcessTruth:
    """The truth sidecar of a process-plant flight, versioned.

    Attributes
    ----------
    model : PlantModel
        The plant flown (its family and parameters).
    loop : str
    rate_hz, noise_std : float
        Controller rate [Hz], white output noise [output units].
    tests : tuple of dict
        Per test ``beta``, ``h``, ``t_start``, ``t_end`` [s, log time], ``aborted``.
    hold : InnerGains
        The hold PID between tests (generic form).
    switching : str
    seed : int
    start_time, duration : float
        [s].
    log_format, log_file, mrftcli_version : str
    """

    model: PlantModel
    loop: str
    rate_hz: float
    noise_std: float
    tests: tuple[Mapping[str, Any], ...]
    hold: InnerGains
    switching: str
    seed: int
    start_time: float
    duration: float
    log_format: str = ""
    log_file: str = ""
    mrftcli_version: str = ""

    def to_json(self) -> dict[str, Any]:
        """Plain JSON values with ``schema_version``; ``model`` is the family's model JSON."""
        return {"format": "mrft-ident process simulation truth", "schema_version": PROCESS_TRUTH_SCHEMA,
                "family": self.model.family, "model": self.model.to_json(),
                "parameters": {name: p.value for name, p in self.model.parameters.items()},
                "loop": self.loop, "rate_hz": self.rate_hz, "noise_std": self.noise_std,
                "tests": [dict(t) for t in self.tests], "hold_controller": self.hold.generic(),
                "switching": self.switching, "seed": self.seed, "start_time": self.start_time,
                "duration": self.duration, "log_format": self.log_format, "log_file": self.log_file,
                "mrftcli_version": self.mrftcli_version,
                "conventions": "operating point at the origin (command 0 holds output 0); the command of a tick "
                               "reaches the plant tau later (zero-order hold)"}

    @classmethod
    def from_json(cls, data: Any) -> ProcessTruth:
        """The record of a sidecar's JSON; InputError (one line) on a wrong version or a missing field."""
        d = check_schema_version(data, "process truth", PROCESS_TRUTH_SCHEMA,
                                 fix="simulate the flight again with this version of mrft-ident")
        try:
            tests = tuple({"beta": float(t["beta"]), "h": float(t["h"]), "t_start": float(t["t_start"]),
                           "t_end": float(t["t_end"]), "aborted": bool(t["aborted"])} for t in d["tests"])
            return cls(model_from_json(d["model"]), str(d["loop"]), float(d["rate_hz"]), float(d["noise_std"]), tests,
                       InnerGains.from_generic(d["hold_controller"], "process truth hold_controller"),
                       str(d["switching"]), int(d["seed"]), float(d["start_time"]), float(d["duration"]),
                       str(d.get("log_format", "")), str(d.get("log_file", "")), str(d.get("mrftcli_version", "")))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"process truth: missing or malformed field {err}; simulate the flight again") from None


@dataclass(frozen=True)
class ProcessFlight:
    """A simulated process-plant flight: tick times [s], command, true and measured output, truth."""

    spec: ProcessSpec
    truth: ProcessTruth
    t: Array
    command: Array
    output_true: Array
    output_measured: Array


def _phase_with_hold(model: PlantModel, omega: Array, rate_hz: float) -> Array:
    phase: Array = np.unwrap(np.angle(model.frequency_response(omega))) - 0.5 * omega / rate_hz
    return phase


def _describing_function(model: PlantModel, beta: float, rate_hz: float) -> tuple[float, float]:
    """(Omega [rad/s], |G(j Omega)|) of the describing function's MRFT cycle, half a tick of hold included."""
    omega = np.geomspace(1e-4, 0.99 * math.pi * rate_hz, 6000)
    below = np.flatnonzero(_phase_with_hold(model, omega, rate_hz) <= -math.pi + math.asin(beta))
    if below.size == 0:
        raise InputError(f"the plant's phase never reaches the MRFT's at beta {beta}; use a smaller beta")
    w = float(omega[below[0]])
    return w, float(abs(complex(model.frequency_response(w))))


def plan_process_test(model: PlantModel, beta: float, amplitude: float, rate_hz: float, cycles: float = 14.0,
                      min_duration: float = 8.0) -> TestSpec:
    """A test whose describing-function amplitude is ``amplitude`` [output units] (planning only).

    Omega where arg G(j Omega) minus half a tick = -pi + asin(beta); h = amplitude pi / (4 |G|); the
    duration covers ``cycles`` predicted periods plus 2 s, at least ``min_duration``.
    """
    if not amplitude > 0:
        raise InputError(f"the planned amplitude must be positive, got {amplitude!r}")
    w, gain = _describing_function(model, beta, rate_hz)
    return TestSpec(beta, float(amplitude * math.pi / (4.0 * gain)), float(round(max(min_duration,
                                                                                   cycles * 2 * math.pi / w + 2), 1)))


def process_hold(model: PlantModel, rate_hz: float, phase_margin_deg: float = 45.0) -> InnerGains:
    """The hold PID: the simulator's hold shape (derivative time 1.5 / omega_c, N = 10, integral time
    6 / omega_c) with omega_c where arg C G (half a tick of hold) = -180 deg + the margin, |C G| = 1."""
    a, n_filter, ti = 1.5, 10.0, 6.0
    c_norm = 1.0 + 1.0 / (ti * 1j) + a * 1j / (a / n_filter * 1j + 1.0)
    omega = np.geomspace(1e-4, 0.99 * math.pi * rate_hz, 6000)
    phase = _phase_with_hold(model, omega, rate_hz) + math.atan2(c_norm.imag, c_norm.real)
    below = np.flatnonzero(phase <= -math.pi + math.radians(phase_margin_deg))
    if below.size == 0:
        raise InputError("no hold controller found for this plant; check its parameters")
    w = float(omega[below[0]])
    kp = 1.0 / (float(abs(complex(model.frequency_response(w)))) * abs(c_norm))
    return InnerGains(kp, kp * w / ti, kp * a / w, a / w / n_filter, rate_hz)


def _pieces(model: PlantModel, T: float) -> tuple[int, list[tuple[Array, Array, bool]]]:
    """Whole periods in the delay, and the period's pieces (Phi, Gamma, newer command?)."""
    ss = model.realisation()
    n = ss.order
    m = int(math.floor(model.delay / T + 1e-9))
    frac = model.delay - m * T
    frac = 0.0 if frac < 1e-9 * T else frac
    pieces = []
    for start, length in ((0.0, frac), (frac, T - frac)):
        if length <= 0:
            continue
        M = np.zeros((n + 1, n + 1))
        M[:n, :n] = ss.A * length
        M[:n, n] = ss.B * length
        E = taylor_expm(M)
        pieces.append((E[:n, :n], E[:n, n], start >= frac))
    return m, pieces


class _Controller:
    """The hold PID between tests, the relay during them (abort beyond 10 x the planned amplitude)."""

    def __init__(self, spec: ProcessSpec, hold: InnerGains, ranges: list[tuple[int, int]]) -> None:
        self.spec, self.hold, self.ranges = spec, hold, ranges
        self.T = 1.0 / spec.rate_hz
        threshold = 10.0 * spec.noise_std
        self.relays: list[MrftRelay | HearMrftRelay] = [
            make_relay(t.beta, spec.switching, threshold, 5, 0.02 * spec.rate_hz) for t in spec.tests]
        self.aborted: list[int | None] = [None] * len(spec.tests)
        self.d = self.i = self.y_prev = 0.0
        self.j = 0

    def _test(self, k: int) -> int:
        while self.j < len(self.ranges) and k >= self.ranges[self.j][1]:
            self.j += 1
        if self.j < len(self.ranges) and self.ranges[self.j][0] <= k and self.aborted[self.j] is None:
            return self.j
        return -1

    def step(self, k: int, y: float, limit: float) -> float:
        hold, T = self.hold, self.T
        e = -y
        self.d = (hold.Tf * self.d - hold.Kd * (y - self.y_prev)) / (hold.Tf + T)
        self.y_prev = y
        j = self._test(k)
        if j >= 0 and abs(e) > limit:
            self.aborted[j] = k
            j = -1
        if j < 0:
            self.i += hold.Ki * T * e
            return hold.Kp * e + self.i + self.d
        relay = self.relays[j]
        s = relay.start(e) if k == self.ranges[j][0] else relay.step(e)
        return s * self.spec.tests[j].h


def simulate_process(spec: ProcessSpec) -> ProcessFlight:
    """Fly ``spec``: hover, each test followed by a hold; exact between the ticks."""
    from .._version import __version__

    rate, T = spec.rate_hz, 1.0 / spec.rate_hz
    hold = process_hold(spec.model, rate)
    k, ranges = int(round(spec.hover_s * rate)), []
    for test in spec.tests:
        n = int(round(test.duration * rate))
        ranges.append((k, k + n))
        k += n + int(round(spec.hold_s * rate))
    n_ticks = k
    m, pieces = _pieces(spec.model, T)
    C = spec.model.realisation().C
    # a flight stack's safety net: 10 x the describing-function amplitude (at least 50 noise std)
    limits = [max(40.0 * t.h / math.pi * _describing_function(spec.model, t.beta, rate)[1], 50.0 * spec.noise_std)
              for t in spec.tests]
    noise = np.random.default_rng(spec.seed).normal(0.0, spec.noise_std, n_ticks) if spec.noise_std > 0 \
        else np.zeros(n_ticks)
    ctl = _Controller(spec, hold, ranges)
    x = np.zeros(C.size)
    line: deque[float] = deque([0.0] * (m + 2), maxlen=m + 2)
    y_true, y_meas, command = np.empty(n_ticks), np.empty(n_ticks), np.empty(n_ticks)
    for k in range(n_ticks):
        y_true[k] = float(C @ x)
        y_meas[k] = y_true[k] + noise[k]
        j = ctl._test(k)
        command[k] = u = ctl.step(k, y_meas[k], limits[j] if j >= 0 else math.inf)
        line.append(u)
        for Phi, Gamma, newer in pieces:
            x = Phi @ x + Gamma * (line[1] if newer else line[0])
    tests = tuple({"beta": t.beta, "h": t.h, "t_start": spec.start_time + k0 * T,
                   "t_end": spec.start_time + (k1 if a is None else a) * T, "aborted": a is not None}
                  for t, (k0, k1), a in zip(spec.tests, ranges, ctl.aborted))
    truth = ProcessTruth(spec.model, spec.loop, rate, spec.noise_std, tests, hold, spec.switching, spec.seed,
                         spec.start_time, n_ticks * T, mrftcli_version=__version__)
    t: Array = spec.start_time + np.arange(n_ticks, dtype=float) * T
    return ProcessFlight(spec, truth, t, command, y_true, y_meas)


def _topics(flight: ProcessFlight) -> list[TopicData]:
    """The reference layout: command, beta, setpoint and the output where ``loop`` puts it."""
    spec, t = flight.spec, flight.t
    f64 = "std_msgs/msg/Float64"
    starts = np.array([e["t_start"] for e in flight.truth.tests], float)
    idx = np.arange(0, t.size, max(1, int(round(spec.rate_hz / 20.0))))
    topics = [TopicData("/mrft/command", f64, t.copy(), {"data": flight.command.copy()}),
              TopicData("/mrft/beta", f64, starts, {"data": np.array([x.beta for x in spec.tests], float)}),
              TopicData("/mrft/setpoint", f64, t[idx].copy(), {"data": np.zeros(idx.size)})]
    y = flight.output_measured
    if spec.loop in ("altitude", "x", "y"):
        axis = {"altitude": "z", "x": "x", "y": "y"}[spec.loop]
        topics.append(TopicData("/mocap/pose", "geometry_msgs/msg/PoseStamped", t.copy(),
                                {f"pose.position.{axis}": y.copy(), "pose.orientation.w": np.ones(t.size)}))
    else:
        roll, pitch = (y, np.zeros(t.size)) if spec.loop == "roll" else (np.zeros(t.size), y)
        cr, sr, cp, sp = np.cos(roll / 2), np.sin(roll / 2), np.cos(pitch / 2), np.sin(pitch / 2)
        topics.append(TopicData("/imu/data", "sensor_msgs/msg/Imu", t.copy(),
                                {"orientation.x": sr * cp, "orientation.y": cr * sp, "orientation.z": -sr * sp,
                                 "orientation.w": cr * cp}))
    return topics


def write_process(flight: ProcessFlight, path: str | Path, fmt: str) -> Path:
    """Write the flight in the reference layout (format ``fmt``) and its :class:`ProcessTruth`; the sidecar."""
    from ..io.atomic import write_text_atomic

    write_log_atomic(_topics(flight), path, fmt)
    truth = dataclasses.replace(flight.truth, log_format=fmt, log_file=Path(path).name)
    side = sidecar_path(path)
    write_text_atomic(side, json.dumps(truth.to_json(), indent=2, allow_nan=False) + "\n")
    return side
