#!/usr/bin/env python
"""Regenerate ``sample_logs/``: simulated MRFT flights of the paper's two platforms, with sidecars.

    python scripts/make_sample_logs.py            # writes sample_logs/ (about a minute)
    python scripts/make_sample_logs.py --check    # also read every log back and compare
    python scripts/make_sample_logs.py --stacks   # only the logs in the flight stacks' layouts

The truth of each scenario is the mean of Table III of the paper (checks.md section 4); the
"+20 ms" scenarios keep the nominal Td and add 0.020 s to tau. Every scenario is written as MCAP
(``<name>.mcap``); the first scenario, ``design1_altitude``, also in every other format that
:mod:`mrftcli.io` writes. Each log has its ground truth beside it as ``<log>.truth.json``.
Seeds are fixed, so the files are reproducible bit for bit with the same library versions.

Flight-stack layouts (:mod:`mrftcli.io.stacks`, docs/log-layout.md): the same simulator, written the
way the stacks log: ``px4_altitude_10hz.ulg`` (PX4 MRFT patch, 50 Hz position controller, the default
10 Hz logger: 6-13 samples per cycle), ``px4_altitude_50hz.ulg`` (high-rate logging), ``hear_x.bag``
(HEAR ROS 1, x loop, HEAR switching rule, receive-time stamps, OptiTrack at 90 Hz) and
``dnn_altitude.mat`` (a MATLAB export at 100 Hz).

Noise: 0.2 mm (altitude) and 0.05 deg (attitude) white noise at 200 Hz. The simulator's defaults
(0.5 mm / 0.2 deg) are too much for the plain MRFT rule at amplitudes of a few cm / degrees: a
noise-triggered switch near the error's zero crossing locks the relay (docs/simulator.md); the
script refuses to write a log with an aborted test or fewer than 10 regular cycles per test.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
from pathlib import Path

import numpy as np

from mrftcli.mrft.model import LoopModel
from mrftcli.io import FORMATS, ReadOptions, log_filename, read_flight
from mrftcli.io.stacks import StackLogSpec, StackTest, write_stack_log
from mrftcli.sim.flight import FlightSpec, plan_test, sidecar_path, simulate_flight, write_flight

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "sample_logs"

#: name -> (Tp, Td, tau, K, loop, betas); Td/tau: Table III means (checks.md section 4)
SCENARIOS = {
    "design1_altitude": (0.0422, 2.669, 0.0464, 19.62, "altitude", (-0.4, -0.7)),
    "design1_altitude_20ms": (0.0422, 2.669, 0.0464 + 0.020, 19.62, "altitude", (-0.4, -0.7)),
    "design1_roll": (0.0422, 1.301, 0.0297, 30.0, "roll", (-0.5, -0.8)),
    "design1_pitch": (0.0422, 1.6026, 0.0289, 25.0, "pitch", (-0.5, -0.8)),
    "design2_altitude": (0.0499, 1.8345, 0.0498, 19.62, "altitude", (-0.4, -0.7)),
    "design2_altitude_20ms": (0.0499, 1.8345, 0.0498 + 0.020, 19.62, "altitude", (-0.4, -0.7)),
    "design2_roll": (0.0499, 0.887, 0.0228, 20.0, "roll", (-0.5, -0.8)),
    "design2_pitch": (0.0499, 0.6312, 0.0308, 18.0, "pitch", (-0.5, -0.8)),
}
AMPLITUDE = {"altitude": 0.05, "roll": math.radians(5.0), "pitch": math.radians(5.0)}  # planned (DF)
NOISE = {"altitude": 0.0002, "roll": math.radians(0.05), "pitch": math.radians(0.05)}
ALL_FORMATS_SCENARIO = "design1_altitude"
START_TIME = 1_700_000_000.0  # a UNIX time, as in real recordings
MAX_TOTAL_BYTES = 15_000_000
MAX_FILE_BYTES = 1_000_000


def build(name: str, seed: int):
    tp, td, tau, k, loop, betas = SCENARIOS[name]
    model = LoopModel(tp, td, tau, k)
    tests = tuple(plan_test(model, beta, AMPLITUDE[loop], cycles=14.0) for beta in betas)
    spec = FlightSpec(
        model=model,
        tests=tests,
        loop=loop,
        noise_std=NOISE[loop],
        hover_s=3.0,
        hold_s=3.0,
        seed=seed,
        start_time=START_TIME,
    )
    return simulate_flight(spec)


#: name -> (layout, model, loop, betas, controller rate [Hz], logger rate [Hz] or None, switching, seed)
STACKS = {
    "px4_altitude_10hz.ulg": ("px4-mrft", (0.0422, 2.669, 0.0464, 19.62), "altitude", (-0.6, -0.2), 50.0,
                              10.0, "checks", 101),
    "px4_altitude_50hz.ulg": ("px4-mrft", (0.0422, 2.669, 0.0464, 19.62), "altitude", (-0.6, -0.2), 50.0,
                              None, "checks", 101),
    "hear_x.bag": ("hear-ros", (0.08, 2.0, 0.08, 1.0), "x", (-0.6, -0.3), 200.0, None, "hear", 102),
    "dnn_altitude.mat": ("mat", (0.0499, 1.8345, 0.0498, 19.62), "altitude", (-0.7, -0.4), 100.0, None,
                         "checks", 103),
}


def build_stack(name: str):
    """Simulate one flight-stack scenario; the PX4 pair shares its flight (same seed)."""
    layout, (tp, td, tau, k), loop, betas, rate, _, switching, seed = STACKS[name]
    model = LoopModel(tp, td, tau, k)
    amplitude = 0.05 if loop != "roll" else math.radians(5.0)
    tests = tuple(plan_test(model, beta, amplitude, rate_hz=rate, cycles=18.0) for beta in betas)
    spec = FlightSpec(model=model, tests=tests, loop=loop, rate_hz=rate, noise_std=0.0005,
                      bias=0.5 if loop == "altitude" else 0.0, setpoint=1.0 if loop == "altitude" else 0.0,
                      hover_s=3.0, hold_s=3.0, seed=seed, switching=switching, start_time=START_TIME)
    return simulate_flight(spec)


def write_stack(flight, name: str, out: Path) -> Path:
    layout, _, loop, _, _, log_rate, _, seed = STACKS[name]
    tests = [StackTest(e["t_start"], e["t_end"], e["beta"], e["h"]) for e in flight.truth["tests"]]
    spec = StackLogSpec(layout, loop, flight.truth["bias"], tests, log_rate_hz=log_rate, seed=seed)
    path = write_stack_log(out / name, spec, flight.t, flight.command, flight.output_measured, flight.setpoint)
    truth = dict(flight.truth)
    truth.update(log_format={"px4-mrft": "ulog", "hear-ros": "bag", "mat": "mat"}[layout], log_file=name,
                 layout=layout, log_rate_hz=log_rate or flight.spec.rate_hz)
    truth["units"] = dict(truth["units"], output="m")
    sidecar_path(path).write_text(json.dumps(truth, indent=2, allow_nan=False) + "\n")
    return path


def check_cycles(flight, skip: int = 4) -> list[int]:
    """Regular cycles per test (half-periods within 25 % of the median, after 2 start cycles)."""
    counts = []
    for entry in flight.truth["tests"]:
        if entry["aborted"]:
            raise SystemExit(f"a test of {entry} was aborted; change the seed or the amplitude")
        sel = (flight.t >= entry["t_start"]) & (flight.t < entry["t_end"])
        t, u = flight.t[sel], flight.command[sel]
        switches = t[1:][np.diff(u) != 0]
        half = np.diff(switches)[skip:]
        med = np.median(half)
        if np.any(np.abs(half - med) > 0.25 * med):
            raise SystemExit(f"irregular half-periods in test beta={entry['beta']}: {np.round(half, 3)}")
        counts.append(len(half) // 2)
    if min(counts) < 10:
        raise SystemExit(f"fewer than 10 regular cycles per test: {counts}")
    return counts


def size_of(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*")) if path.is_dir() else path.stat().st_size


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=OUT, help="target directory (default sample_logs/)")
    parser.add_argument("--check", action="store_true", help="read every log back and compare")
    parser.add_argument("--stacks", action="store_true", help="only the flight-stack layouts' logs")
    args = parser.parse_args(argv)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    flights: dict = {}
    for name in STACKS:
        key = STACKS[name][:5] + STACKS[name][6:]  # the PX4 pair flies once, logged at two rates
        if key not in flights:
            flights[key] = build_stack(name)
            check_cycles(flights[key], skip=8)
        path = write_stack(flights[key], name, out)
        written.append(path)
        print(f"{path.relative_to(out.parent)}  {size_of(path) / 1e3:7.1f} kB  ({STACKS[name][0]})")
    for seed, name in enumerate(() if args.stacks else SCENARIOS, start=1):
        flight = build(name, seed)
        cycles = check_cycles(flight)
        formats = FORMATS if name == ALL_FORMATS_SCENARIO else ("mcap",)
        for fmt in formats:
            path = out / f"{name}.mcap" if fmt == "mcap" else log_filename(out / name, fmt)
            if path.is_dir():
                shutil.rmtree(path)
            write_flight(flight, path, fmt)
            size = size_of(path)
            if size > MAX_FILE_BYTES:
                raise SystemExit(f"{path} is {size} bytes, over the {MAX_FILE_BYTES} byte limit")
            written.append(path)
            if args.check:
                log = read_flight(path, ReadOptions(loop=flight.spec.loop))
                n = len(log.command)
                got = log.output.values
                if n != flight.t.size or np.max(np.abs(got - flight.output_measured)) > 1e-6:
                    raise SystemExit(f"{path}: read back {n} samples, max output error "
                                     f"{np.max(np.abs(got - flight.output_measured[: got.size]))}")
            print(f"{path.relative_to(out.parent)}  {size / 1e3:7.1f} kB  cycles/test {cycles}")
    total = sum(size_of(p) + p.with_name(p.name + ".truth.json").stat().st_size for p in written)
    print(f"{len(written)} logs, {total / 1e6:.2f} MB in {out}")
    if total > MAX_TOTAL_BYTES:
        raise SystemExit(f"sample_logs/ is {total} bytes, over {MAX_TOTAL_BYTES}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
