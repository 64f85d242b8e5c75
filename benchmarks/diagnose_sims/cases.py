"""Flights drawn as pilots fly them, flown in RotorPy or JSBSim, diagnosed and scored (issue 39).

Per flight: a platform of the simulator, an altitude loop at 50-500 Hz, 0.5-1 mm of sensor noise,
20-40 ms of latency, three MRFT tests of 10-14 s (beta -0.4 and -0.7 at one planned amplitude of
5-10 cm, then beta -0.4 at twice the first relay height), one effect produced physically (or none,
or a flexible sensor mount the library does not have) at a realistic magnitude times a factor in
[0.7, 1.3]. Nothing is flown again or dropped; a refusal counts as a miss.
"""

from __future__ import annotations

import importlib
import math
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from .loop import LoopSpec, fly, flight_topics, relay_height

if TYPE_CHECKING:
    from mrftcli.analyze import AnalysisResult
    from mrftcli.diagnose.records import DiagnosisResult

__all__ = ["EFFECTS", "MOUNT", "RATES", "draw_case", "run_case", "trim_offsets"]

#: the library's names of the effects each simulator produces physically
EFFECTS = ("quadratic_drag", "actuator_saturation", "sensor_lag", "gain_drift", "actuator_rate_limit", "delay_jitter")
MOUNT = "flex_mount"  # out of the library: a sensor on a spring, 10 Hz to 0.8 of the Nyquist frequency
RATES = (50.0, 100.0, 200.0, 250.0, 500.0)
BETAS = (-0.4, -0.7, -0.4)


def draw_case(rng: np.random.Generator, sim: str, effect: str | None) -> dict:
    """One flight's draw (the simulator's platform, rate, noise, amplitude, durations, magnitude)."""
    if sim == "rotorpy":
        from .rotorpy_flight import PLATFORMS
    else:
        from .jsbsim_flight import PLATFORMS
    rate = float(rng.choice(RATES))
    return {"sim": sim, "effect": effect, "platform": str(rng.choice(PLATFORMS)), "seed": int(rng.integers(1 << 30)),
            "scale": float(rng.uniform(0.7, 1.3)), "rate": rate, "noise": float(rng.uniform(0.0005, 0.001)),
            "amplitude": float(rng.uniform(0.05, 0.10)), "latency": float(rng.uniform(0.02, 0.04)),
            "durations": tuple(round(float(rng.uniform(10.0, 14.0)), 1) for _ in range(3)),
            "mount_hz": float(rng.uniform(10.0, 0.8 * rate / 2)), "mount_zeta": float(rng.uniform(0.02, 0.1))}


def _omega(model, beta: float) -> float:
    """The MRFT's describing-function frequency [rad/s] on the planning model."""
    target = -math.pi + math.asin(beta)
    lo, hi = 1e-3, 1e3
    for _ in range(100):
        w = math.sqrt(lo * hi)
        ph = -w * model.tau - math.pi / 2 - math.atan(w * model.Tp) - math.atan(w * model.Td)
        lo, hi = (w, hi) if ph > target else (lo, w)
    return math.sqrt(lo * hi)


def build(case: dict):
    """The vehicle, the loop spec, Tp given to the tool, and the truth (library parameter, approximate)."""
    sim, effect, sc = case["sim"], case["effect"], case["scale"]
    mod = importlib.import_module(f".{sim}_flight", __package__)
    model = mod.platform_model(case["platform"])
    amp = case["amplitude"]
    # the planned amplitude's relay heights, as a pilot caps them: at most 15 % of the hover command
    # at beta -0.4 (a fast loop then oscillates by 1-3 cm), 25 % at -0.7 (its higher frequency shrinks
    # the amplitude), the third test at twice the first's height
    hover = mod.hover_command(case["platform"])
    h1, h2 = (min(relay_height(model, b, amp), cap * hover) for b, cap in ((-0.4, 0.15), (-0.7, 0.25)))
    heights = (h1, h2, 2.0 * h1)
    amp = amp * h1 / relay_height(model, -0.4, amp)  # the first test's planned amplitude [m]
    kw: dict = {}
    loop: dict = {}
    truth: float | None = None
    w = _omega(model, -0.4)
    if effect == "quadratic_drag":
        c = 3.0 * math.pi / (8.0 * model.Td * amp * w) * sc  # damps like the linear model at the test speed
        kw["drag_c"], truth = c, c
    elif effect == "actuator_saturation":
        truth = kw["u_max"] = mod.hover_command(case["platform"]) + 0.7 * sc * max(heights)
    elif effect == "gain_drift":
        truth = kw["drift"] = -0.001 * sc
    elif effect == "actuator_rate_limit":
        truth = kw["slew_u"] = 2.0 * h1 / (0.045 * sc)
    elif effect == "sensor_lag":
        truth = loop["lag"] = 0.07 * sc
    elif effect == "delay_jitter":
        loop["jitter"] = 0.012 * sc / math.sqrt(1 - 2 / math.pi)  # half-normal lateness, std 12 ms x factor
        truth = 0.012 * sc
    elif effect == MOUNT:
        loop.update(mount_hz=case["mount_hz"], mount_zeta=case["mount_zeta"])
    vehicle = mod.make_vehicle(case["platform"], **kw)
    tests = tuple((b, h, d) for b, h, d in zip(BETAS, heights, case["durations"]))
    spec = LoopSpec(rate=case["rate"], tests=tests, latency=case["latency"], noise=case["noise"], seed=case["seed"],
                    planning=model, abort=1.0, **loop)
    return vehicle, spec, mod.tool_tp(case["platform"]), truth


def mount_snr(rec, spec: LoopSpec) -> float:
    """The oracle SNR of the mount's ringing: what the mount adds to the true altitude beyond its
    quasi-static part (least squares on y, y', y''), summed squared inside the tests over the noise variance."""
    d = rec.y_mount - rec.y_true
    T = 1.0 / spec.rate
    v = np.gradient(rec.y_true, T)
    a = np.gradient(v, T)
    inside = np.zeros(d.size, bool)
    for t0, t1 in zip(rec.test_starts, rec.test_ends):
        inside |= (rec.t >= t0) & (rec.t <= t1)
    X = np.column_stack([np.ones(d.size), v, a])[inside]
    coef, *_ = np.linalg.lstsq(X, d[inside], rcond=None)
    ring = d[inside] - X @ coef
    return float(np.sum(ring**2) / spec.noise**2)


def switching(rec) -> list[tuple[float, float] | None]:
    """The oracle of how each test's relay switched, over the test's second half (after the start-up):
    switches per cycle of the error (2 for a relay that switches once per side; the cycles are the error's
    up-crossings of +-half its median peak) and the median switching phase [deg] after the half-cycle's
    peak, arccos(e at the switch / the peak) (arccos(-beta) as designed: 45.6 deg at beta -0.7, 66.4 at
    -0.4). The fork's 5-sample peak latch moves both at the lowest and highest rates. None for a test
    whose relay locked up or that switched too little to say."""
    out: list[tuple[float, float] | None] = []
    err = rec.setpoint - rec.y_meas
    for t0, t1, aborted in zip(rec.test_starts, rec.test_ends, rec.aborted):
        idx = np.flatnonzero((rec.t >= 0.5 * (t0 + t1)) & (rec.t <= t1))
        u, e = rec.command[idx], err[idx]
        sw = np.flatnonzero(np.diff(u) != 0) + 1  # the ticks the relay switched on (the bias is constant in a test)
        if aborted or sw.size < 3:
            out.append(None)
            continue
        ratios = [e[b] / (e[a:b + 1].max() if u[b] < u[b - 1] else e[a:b + 1].min()) for a, b in zip(sw[:-1], sw[1:])]
        level = 0.5 * np.median([np.abs(e[a:b + 1]).max() for a, b in zip(sw[:-1], sw[1:])])
        side, ups = 0, 0  # a Schmitt trigger on the error: noise does not count as a cycle
        for x in e:
            if x > level and side <= 0:
                ups, side = ups + (side < 0), 1
            elif x < -level:
                side = -1
        phase = float(np.degrees(np.median(np.arccos(np.clip(ratios, -1.0, 1.0)))))
        out.append((sw.size / ups, phase) if ups else None)
    return out


def trim_offsets(rec, spec: LoopSpec, hover: float, drift: float) -> list[float]:
    """The oracle of each test's relay centre: how far the hold centred it off the vehicle's trim, as a
    fraction of the test's relay height (tests whose relay locked up left out). The trim is the
    simulator's settled hover command, moved by a gain drift g as hover / (1 + g t); the relay's centre
    is the mid-point of the command's two levels during the test. The hold's integrator, unsettled
    2.5 s after the previous test, leaves it there: real, different per test (``with_trim_nuisance``)."""
    out = []
    for (_, h, _), t0, t1, aborted in zip(spec.tests, rec.test_starts, rec.test_ends, rec.aborted):
        inside = (rec.t >= t0) & (rec.t <= t1)
        if aborted or not inside.any():
            continue
        centre = 0.5 * (rec.command[inside].max() + rec.command[inside].min())
        trim = hover / (1.0 + drift * 0.5 * (t0 + t1))
        out.append(float((centre - trim) / h))
    return out


class DiagnoseRun(NamedTuple):
    """One log analyzed, then diagnosed reusing the analysis (:func:`analyze_then_diagnose`)."""

    analysis: AnalysisResult | None  #: analyze's record, or None when analyze refused the log
    res: DiagnosisResult | None  #: the diagnosis (after the CLI's last step), or None
    error: str | None  #: ``"ErrorType: message"`` when diagnose raised
    refused: bool  #: the tool declined the log (an MrftError: one line and an exit code on the CLI)
    cpu_analyze: float  #: CPU [s] of the read and analyze: ``mrft-ident analyze``'s work
    cpu: float  #: CPU [s] of diagnose beyond analyze's


def analyze_then_diagnose(path: Path, Tp: float) -> DiagnoseRun:
    """Read ``path`` once (the altitude loop), analyze it and hand its record or its refusal to diagnose,
    as ``mrft-ident diagnose`` runs it (analyze is not run twice; issue 39), timing each part in this
    process (``time.process_time``). The one copy of this block for bench_diagnose, bench_diagnose_cpu
    and :func:`run_case`."""
    from mrftcli.analyze import analyze_flight
    from mrftcli.cli.diagnose import _with_analysis
    from mrftcli.diagnose.selection import diagnose
    from mrftcli.errors import MrftError
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.model import soiptd_model

    t0 = time.process_time()
    analysis, refusal = None, None
    flight = read_flight(path, ReadOptions(loop="altitude"))
    try:
        analysis = analyze_flight(flight, soiptd_model(Tp))
    except MrftError as exc:
        refusal = exc  # handed to diagnose, as the CLI does
    cpu_analyze = time.process_time() - t0
    t0 = time.process_time()
    try:
        res = diagnose(flight, soiptd_model(Tp), analysis=analysis, refusal=refusal)
        res = _with_analysis(res, analysis)  # the CLI's last step: analyze's model beside, recommend again
        err, refused = None, False
    except Exception as exc:  # noqa: BLE001 - a benchmark records failures
        res, err, refused = None, f"{type(exc).__name__}: {exc}", isinstance(exc, MrftError)
    return DiagnoseRun(analysis, res, err, refused, cpu_analyze, time.process_time() - t0)


def run_case(case: dict) -> dict:
    """Fly, write MCAP, analyze and diagnose reusing the analysis as the CLI does (CPU of each timed in this
    process), and what was found."""
    from mrftcli.io import write_log

    t0 = time.process_time()
    vehicle, spec, Tp, truth = build(case)
    rec = fly(vehicle, spec)
    cpu_sim = time.process_time() - t0
    out = {**case, "cpu_sim": cpu_sim, "Tp": Tp, "aborted": sum(rec.aborted), "min_margin": float("nan"),
           "true_values": {case["effect"]: truth} if truth is not None else {},
           "snr": mount_snr(rec, spec) if case["effect"] == MOUNT else None,
           "trim_off": trim_offsets(rec, spec, vehicle.hover, truth if case["effect"] == "gain_drift" else 0.0),
           "switching": switching(rec)}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "flight.mcap"
        write_log(flight_topics(rec, [b for b, _, _ in spec.tests]), path, "mcap")
        run = analyze_then_diagnose(path, Tp)
    res = run.res
    # analysed False: analyze refused (one beta usable), its CPU is a refusal's
    out.update(cpu_analyze=run.cpu_analyze, analysed=run.analysis is not None, error=run.error, refused=run.refused,
               cpu=run.cpu)
    if res is not None:
        from bench_diagnose import diagnosis_row  # noqa: PLC0415 - the scoring, one home

        out.update(diagnosis_row(res))
    return out
