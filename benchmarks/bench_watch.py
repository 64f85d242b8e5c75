"""Latency of ``mrft-ident watch``: from a cycle's end reaching the file to the updated estimate.

A writer process simulates an MRFT flight (:mod:`mrftcli.sim`, a random plant drawn with a fresh seed,
two tests at betas -0.4 and -0.7, about 30 s) and writes it as an MCAP *in real time*: every message
is written when its log time comes, in small chunks (1 KiB, a new chunk every few tens of ms, as a
recorder flushing often would). After each flush it notes the newest log time in the file and the wall
time. This process follows the file with :func:`mrftcli.watch.watch` (incremental MCAP reading,
windowed segmentation). For every update with a new cycle, the latency is the update's wall time
minus the wall time at which the command sample that ends its newest cycle (``t_cycle_end``) was in
the file. Only non-final updates count (the final one waits for the footer by design).

Baseline in the same process: the cost of what the incremental path avoids, one whole-file re-read
and analysis (:func:`mrftcli.io.read_flight` + :func:`mrftcli.analyze.analyze_flight`) of the
finished log, as a ratio to the median per-update latency.

Usage: python benchmarks/bench_watch.py [--runs 2] [--seed N]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _model(rng):
    from mrftcli.mrft.model import LoopModel

    return LoopModel(Tp=float(rng.uniform(0.03, 0.06)), Td=float(rng.uniform(0.6, 3.0)),
                     tau=float(rng.uniform(0.02, 0.07)), K=float(rng.uniform(10, 30)))


def _writer(out: str, flushes: str, seed: int, rate_hz: float) -> None:
    """Simulate a flight and write it in real time as an MCAP (runs in its own process)."""
    from mcap.writer import CompressionType, Writer

    from mrftcli.io.cdr import serialize_many
    from mrftcli.io.msgtypes import typestore_for
    from mrftcli.sim import FlightSpec, plan_test, simulate_flight

    rng = np.random.default_rng(seed)
    model = _model(rng)
    tests = tuple(plan_test(model, b, 0.05, rate_hz=rate_hz, cycles=12, min_duration=8.0) for b in (-0.4, -0.7))
    spec = FlightSpec(model=model, tests=tests, rate_hz=rate_hz, hover_s=2.0, hold_s=2.0, seed=seed,
                      noise_std=float(rng.choice([0.0002, 0.0005])))
    sim = simulate_flight(spec)
    ts = typestore_for(ros1=False)
    rows = []
    for td in sim.topics:
        t = np.asarray(td.t, float)
        datas = serialize_many(ts, td.msgtype, t, td.fields)
        rows.extend((float(ti), td.name, td.msgtype, d) for ti, d in zip(t, datas))
    rows.sort(key=lambda r: r[0])
    t_first = rows[0][0]
    log = []
    with open(out, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.NONE, chunk_size=1024)
        writer.start(profile="ros2", library="bench_watch")
        schemas, channels = {}, {}
        for _, name, msgtype, _ in rows:
            if name not in channels:
                if msgtype not in schemas:
                    text = ts.generate_msgdef(msgtype, ros_version=2)[0]
                    schemas[msgtype] = writer.register_schema(msgtype, "ros2msg", text.encode())
                channels[name] = writer.register_channel(name, "cdr", schemas[msgtype])
        stream.flush()
        wall0 = time.time() + 0.2
        i = 0
        while i < len(rows):
            now = time.time()
            due = t_first + (now - wall0)
            j = i
            while j < len(rows) and rows[j][0] <= due:
                t, name, _, data = rows[j]
                ns = int(round(t * 1e9))
                writer.add_message(channel_id=channels[name], log_time=ns, publish_time=ns, data=data)
                j += 1
            if j > i:
                stream.flush()
                # what is in the file now: the messages of every closed chunk
                pos = stream.tell()
                log.append((pos, rows[j - 1][0], time.time()))
                i = j
            time.sleep(0.002)
        writer.finish()
        stream.flush()
    # the file offset after each flush tells which messages were complete on disk then; the
    # latency side only needs (newest log time on disk, wall time), reconstructed below
    Path(flushes).write_text(json.dumps({"flushes": log, "truth": {"Td": model.Td, "tau": model.tau, "K": model.K,
                                                                  "Tp": model.Tp}, "rate_hz": rate_hz}))


def _on_disk(path: str, flushes: list) -> list[tuple[float, float]]:
    """(newest log time whose message was in a complete chunk, wall time) after each flush."""
    from mrftcli.io.follow import McapFollower

    # replay: read the finished file up to each flushed size and see the newest complete message
    data = Path(path).read_bytes()
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        part = Path(tmp) / "part.mcap"
        follower = McapFollower(part)
        newest = -math.inf
        with open(part, "wb") as fh:
            written = 0
            for pos, _, wall in flushes:
                fh.write(data[written:pos])
                fh.flush()
                written = pos
                follower.poll()
                t, _ = follower.values("/mrft/command", ["data"])
                if t.size:
                    newest = float(t[-1])
                out.append((newest, wall))
    return out


def run(seed: int, rate_hz: float) -> dict:
    from mrftcli.analyze import analyze_flight
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.watch import WatchOptions, watch

    with tempfile.TemporaryDirectory() as tmp:
        log = os.path.join(tmp, "live.mcap")
        flushes = os.path.join(tmp, "flushes.json")
        proc = subprocess.Popen([sys.executable, __file__, "--writer", log, flushes, str(seed), str(rate_hz)])
        try:
            Tp = _model(np.random.default_rng(seed)).Tp
            updates = list(watch(log, Tp, read=ReadOptions(loop="altitude"), options=WatchOptions(idle=5.0, poll=0.01)))
        finally:
            proc.wait()
        info = json.loads(Path(flushes).read_text())
        disk = _on_disk(log, info["flushes"])
        newest = np.array([d[0] for d in disk])
        walls = np.array([d[1] for d in disk])
        lat = []
        for u in updates:
            if u.kind == "end" or getattr(u, "final", False):
                continue
            k = int(np.searchsorted(newest, u.t_cycle_end - 1e-6))
            if k < walls.size:
                lat.append(u.wall_time - walls[k])
        # baseline: one whole-file re-read + analysis of the finished log
        t0 = time.perf_counter()
        flight = read_flight(log)
        t1 = time.perf_counter()
        try:
            analyze_flight(flight, info["truth"]["Tp"])
        except Exception:  # noqa: BLE001 - the baseline's cost is what matters
            pass
        t2 = time.perf_counter()
        final = [u for u in updates if getattr(u, "final", False)]
        return {"seed": seed, "rate_hz": rate_hz, "updates": len(lat), "latency": lat,
                "reread_s": t1 - t0, "reread_analyze_s": t2 - t0,
                "final_tau_err_ms": (final[0].tau - info["truth"]["tau"]) * 1e3 if final else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=None, help="first seed (default: fresh)")
    args = ap.parse_args()
    seed0 = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % 100000)
    rates = [200.0, 100.0, 250.0]
    all_lat = []
    for r in range(args.runs):
        res = run(seed0 + r, rates[r % len(rates)])
        lat = np.array(res["latency"])
        all_lat.extend(lat.tolist())
        print(f"seed {res['seed']}  {res['rate_hz']:.0f} Hz  updates {res['updates']}  latency median "
              f"{np.median(lat) * 1e3:.0f} ms  p90 {np.percentile(lat, 90) * 1e3:.0f} ms  max {lat.max() * 1e3:.0f} ms  "
              f"| whole-file re-read {res['reread_s'] * 1e3:.0f} ms, + analyze {res['reread_analyze_s'] * 1e3:.0f} ms "
              f"({res['reread_analyze_s'] / np.median(lat):.1f}x the median latency)  final tau error "
              f"{res['final_tau_err_ms']:.2f} ms" if lat.size else f"seed {res['seed']}: no updates")
    a = np.array(all_lat)
    if a.size:
        print(f"all: {a.size} updates, latency median {np.median(a) * 1e3:.0f} ms, p90 {np.percentile(a, 90) * 1e3:.0f} ms, "
              f"max {a.max() * 1e3:.0f} ms; share <= 0.2 s: {np.mean(a <= 0.2) * 100:.0f} %")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--writer":
        _writer(sys.argv[2], sys.argv[3], int(sys.argv[4]), float(sys.argv[5]))
    else:
        main()
