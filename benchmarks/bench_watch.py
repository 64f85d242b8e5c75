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

``--model fopdt``: a process plant instead (``watch --model fopdt``, :func:`mrftcli.watch.watch` with the family's model).
The writer draws a random FOPDT plant (K 0.5-5, T 0.2-1 s, tau 0.1-0.4 T) and records three relay
windows of about a dozen cycles each, as an engineer running relay autotuning would (an ideal relay, a
biased relay with a small hysteresis, a symmetric relay with a larger one), simulated by ``tests/process_sim.py`` (independent of mrftcli), at 50, 100 or 200 Hz by
run, noise 1 % of the amplitude; it writes them in real time as an MCAP (``--format mcap``: the command
on ``/mrft/command``, the output on ``/mocap/pose`` z) or as a CSV with a process recording's three
columns (``--format csv``: time, u_relay, y_output; a row per sample, flushed every few ms). The
baseline is the finished log read and analysed whole as ``analyze --model fopdt`` does
(``read_flight`` + ``analyze_flight`` with the family model).

``--replay CSV``: a real recording (the KSTAR files of ../shared/data/real_relay/) written again in
real time at its own rate (10 kHz), followed with ``watch --model fopdt``; no truth, so the final is
compared with ``analyze --model fopdt`` on the finished file.

Usage: python benchmarks/bench_watch.py [--runs 2] [--seed N] [--model fopdt [--format mcap|csv]] [--replay CSV]
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

# one BLAS thread, set before numpy is imported (OpenBLAS reads it when it loads; later it has no effect):
# the segmenter's small per-cycle least-squares fits cost several times the CPU when BLAS threads fight
# for the shared cores (the KSTAR replay in-process: 19 s of CPU with the default threads, 3 s with one)
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # process_sim: the independent simulator

#: the process plant's CSV columns (a KSTAR-style recording)
CSV_TOPICS = ("u_relay", "y_output")


def _model(rng):
    from mrftcli.mrft.model import LoopModel

    return LoopModel(Tp=float(rng.uniform(0.03, 0.06)), Td=float(rng.uniform(0.6, 3.0)),
                     tau=float(rng.uniform(0.02, 0.07)), K=float(rng.uniform(10, 30)))


def _eq2_rows(seed: int, rate_hz: float) -> tuple[list, dict]:
    """An MRFT flight of eq. (2) as (log time, topic, message type, CDR bytes) rows, and its truth."""
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
    return rows, {"Td": model.Td, "tau": model.tau, "K": model.K, "Tp": model.Tp}


def _ideal_period(T: float, tau: float) -> float:
    """The period of an FOPDT loop under an ideal relay [s]: the phase crossover, atan(w T) + w tau = pi."""
    lo, hi = 1e-6, math.pi / tau
    for _ in range(60):
        w = 0.5 * (lo + hi)
        lo, hi = (w, hi) if math.atan(w * T) + w * tau < math.pi else (lo, w)
    return 2 * math.pi / lo


def _fopdt_recording(seed: int, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """A random FOPDT plant under three relay windows (tests/process_sim.py): t [s], command, output, truth."""
    from process_sim import Window, simulate

    rng = np.random.default_rng(seed)
    T = float(rng.uniform(0.2, 1.0))
    truth = {"K": float(rng.uniform(0.5, 5.0)), "T": T, "tau": float(rng.uniform(0.1, 0.4) * T)}
    h = 1.0
    a = truth["K"] * h * (1 - math.exp(-truth["tau"] / T))  # the ideal relay's amplitude
    # as an engineer runs them: about a dozen cycles per window (the hysteresis lengthens the period)
    period = _ideal_period(T, truth["tau"])
    windows = [Window("ideal", h, -h, duration=max(6.0, 12 * period), rest=2.0),
               Window("hysteresis", 1.5 * h, -0.5 * h, eps=0.1 * a, duration=max(6.0, 14 * period), rest=2.0),
               Window("hysteresis", h, -h, eps=0.4 * a, duration=max(6.0, 18 * period), rest=2.0)]
    t, u, y = simulate("fopdt", truth, windows, rate_hz, 0.01 * a, seed=seed)
    return t, u, y, truth


def _fopdt_rows(seed: int, rate_hz: float) -> tuple[list, dict]:
    """The FOPDT recording as MCAP rows in the reference layout (/mrft/command, /mocap/pose z)."""
    from mrftcli.io.cdr import serialize_many
    from mrftcli.io.msgtypes import typestore_for

    t, u, y, truth = _fopdt_recording(seed, rate_hz)
    ts = typestore_for(ros1=False)
    rows = []
    for name, msgtype, fields in (("/mrft/command", "std_msgs/msg/Float64", {"data": u}),
                                  ("/mocap/pose", "geometry_msgs/msg/PoseStamped",
                                   {"pose.position.z": y, "pose.orientation.w": np.ones(t.size)})):
        datas = serialize_many(ts, msgtype, t, fields)
        rows.extend((float(ti), name, msgtype, d) for ti, d in zip(t, datas))
    return rows, truth


def _write_mcap(out: str, rows: list) -> list:
    """Write the rows as an MCAP in real time, 1 KiB chunks; (file offset, newest log time, wall) per flush."""
    from mcap.writer import CompressionType, Writer

    from mrftcli.io.msgtypes import typestore_for

    ts = typestore_for(ros1=False)
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
            due = t_first + (time.time() - wall0)
            j = i
            while j < len(rows) and rows[j][0] <= due:
                t, name, _, data = rows[j]
                ns = int(round(t * 1e9))
                writer.add_message(channel_id=channels[name], log_time=ns, publish_time=ns, data=data)
                j += 1
            if j > i:
                stream.flush()
                # what is in the file now: the messages of every closed chunk
                log.append((stream.tell(), rows[j - 1][0], time.time()))
                i = j
            time.sleep(0.002)
        writer.finish()
        stream.flush()
    return log


def _write_csv(out: str, t: np.ndarray, u: np.ndarray, y: np.ndarray) -> list:
    """Write the three columns in real time, whole rows flushed every few ms; (offset, newest time, wall)."""
    log = []
    with open(out, "w") as fh:
        fh.write("time," + ",".join(CSV_TOPICS) + "\n")
        fh.flush()
        wall0 = time.time() + 0.2
        i = 0
        while i < t.size:
            due = t[0] + (time.time() - wall0)
            j = int(np.searchsorted(t, due, side="right"))
            if j > i:
                fh.write("".join(f"{t[k]:.10g},{u[k]:.10g},{y[k]:.10g}\n" for k in range(i, j)))
                fh.flush()
                log.append((fh.tell(), float(t[j - 1]), time.time()))
                i = j
            time.sleep(0.002)
    return log


def _recorded(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A real recording's time [s], u_relay and y_output columns (the KSTAR files' header)."""
    with open(path) as fh:
        names = fh.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=[names.index(n) for n in ("time", *CSV_TOPICS)])
    return data[:, 0], data[:, 1], data[:, 2]


def _writer(out: str, flushes: str, seed: int, rate_hz: float, model: str, fmt: str, replay: str = "") -> None:
    """Simulate a flight (or replay a recording) and write it in real time (runs in its own process); the
    flushes and truth to ``flushes``."""
    if replay:
        t, u, y = _recorded(replay)
        log, truth = _write_csv(out, t, u, y), {}
    elif model == "fopdt" and fmt == "csv":
        t, u, y, truth = _fopdt_recording(seed, rate_hz)
        log = _write_csv(out, t, u, y)
    else:
        rows, truth = _fopdt_rows(seed, rate_hz) if model == "fopdt" else _eq2_rows(seed, rate_hz)
        rows.sort(key=lambda r: r[0])
        log = _write_mcap(out, rows)
    # the file offset after each flush tells which messages were complete on disk then; the
    # latency side only needs (newest log time on disk, wall time), reconstructed below
    Path(flushes).write_text(json.dumps({"flushes": log, "truth": truth, "rate_hz": rate_hz}))


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


def _latencies(updates: list, disk: list[tuple[float, float]]) -> list[float]:
    """Per non-final update with a cycle: its wall time - when its newest cycle's end was on disk [s]."""
    newest = np.array([d[0] for d in disk])
    walls = np.array([d[1] for d in disk])
    lat = []
    for u in updates:
        if u.kind == "end" or getattr(u, "final", False):
            continue
        k = int(np.searchsorted(newest, u.t_cycle_end - 1e-6))
        if k < walls.size:
            lat.append(u.wall_time - walls[k])
    return lat


def _follow(log: str, model: str, fmt: str, seed: int) -> list:
    """The updates of watch with eq. (2) (Tp known) or ``--model fopdt`` on the growing file."""
    from mrftcli.io import ReadOptions
    from mrftcli.mrft.families import family_model
    from mrftcli.mrft.model import soiptd_model
    from mrftcli.watch import WatchOptions, watch

    options = WatchOptions(idle=5.0, poll=0.01)
    if model == "fopdt":
        read = ReadOptions(command_topic=CSV_TOPICS[0], output_topic=CSV_TOPICS[1]) if fmt == "csv" else \
            ReadOptions(loop="altitude")
        return list(watch(log, family_model("fopdt"), read=read, options=options))
    Tp = _model(np.random.default_rng(seed)).Tp
    return list(watch(log, soiptd_model(Tp), read=ReadOptions(loop="altitude"), options=options))


def _baseline(log: str, model: str, fmt: str, truth: dict) -> tuple[float, float, object]:
    """(read [s], read + analyse [s]) of the finished log whole: what re-running analyze per update costs."""
    from mrftcli.analyze import analyze_flight
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.families import family_model
    from mrftcli.mrft.model import soiptd_model

    read = ReadOptions(command_topic=CSV_TOPICS[0], output_topic=CSV_TOPICS[1]) if fmt == "csv" else ReadOptions()
    t0 = time.perf_counter()
    flight = read_flight(log, read, echo_warnings=False)
    t1 = time.perf_counter()
    result = None
    try:
        if model == "fopdt":
            result = analyze_flight(flight, family_model("fopdt"))
        else:
            result = analyze_flight(flight, soiptd_model(truth["Tp"]))
    except Exception:  # noqa: BLE001 - the baseline's cost is what matters
        pass
    return t1 - t0, time.perf_counter() - t0, result


def _final_error(updates: list, truth: dict, model: str, analysis: object = None) -> str:
    """The final estimate against the truth: tau's error [ms] (eq. (2)); each parameter's [%] and coverage.
    A replayed recording has no truth: the final against ``analysis`` (analyze --model on the finished file)."""
    final = [u for u in updates if getattr(u, "final", False)]
    if not final:
        return "no final estimate (" + "; ".join(str(u.error) for u in updates if u.kind == "end") + ")"
    if not truth:
        ref = {e.name: e.value for e in analysis.identification.estimates} if analysis is not None else {}
        same = ref and all(_same(e.value, ref[e.name]) for e in final[0].parameters)
        return ("final " + ", ".join(f"{e.name} {e.value:.4g} {e.unit}" for e in final[0].parameters)
                + ("; the same as analyze --model on the finished file" if same else "; NOT analyze --model's"))
    if model != "fopdt":
        tau = next(e.value for e in final[0].parameters if e.name == "tau")
        return f"final tau error {(tau - truth['tau']) * 1e3:+.2f} ms"
    parts = []
    for e in final[0].parameters:
        inside = e.ci95_low <= truth[e.name] <= e.ci95_high
        parts.append(f"{e.name} {100 * (e.value / truth[e.name] - 1):+.1f} %{'' if inside else ' (outside its interval)'}")
    return "final " + ", ".join(parts)


def _same(a: float, b: float) -> bool:
    """Equal within a relative 1e-9 (the same numbers, whatever the last bits)."""
    return abs(a - b) <= 1e-9 * max(abs(a), abs(b))


def run(seed: int, rate_hz: float, model: str = "soiptd", fmt: str = "mcap", replay: str = "") -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        log = os.path.join(tmp, f"live.{fmt}")
        flushes = os.path.join(tmp, "flushes.json")
        proc = subprocess.Popen([sys.executable, __file__, "--writer", log, flushes, str(seed), str(rate_hz), model,
                                 fmt, replay])
        try:
            updates = _follow(log, model, fmt, seed)
        finally:
            proc.wait()
        info = json.loads(Path(flushes).read_text())
        disk = (_on_disk(log, info["flushes"]) if fmt == "mcap"
                else [(t_newest, wall) for _, t_newest, wall in info["flushes"]])  # whole rows: on disk when flushed
        reread, reread_analyze, analysis = _baseline(log, model, fmt, info["truth"])
        return {"seed": seed, "rate_hz": rate_hz, "latency": _latencies(updates, disk), "reread_s": reread,
                "reread_analyze_s": reread_analyze, "final": _final_error(updates, info["truth"], model, analysis)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=None, help="first seed (default: fresh)")
    ap.add_argument("--model", choices=("soiptd", "fopdt"), default="soiptd",
                    help="soiptd: eq. (2) (watch); fopdt: a process plant (watch --model fopdt)")
    ap.add_argument("--format", dest="fmt", choices=("mcap", "csv"), default="mcap",
                    help="how the recorder writes (csv: --model fopdt only)")
    ap.add_argument("--replay", metavar="CSV", default="",
                    help="replay a real recording (columns time, u_relay, y_output: the KSTAR files) in real time "
                         "instead of simulating (implies --model fopdt --format csv --runs 1)")
    args = ap.parse_args()
    if args.replay:
        args.model, args.fmt, args.runs = "fopdt", "csv", 1
    if args.fmt == "csv" and args.model != "fopdt":
        ap.error("--format csv is for --model fopdt (eq. (2)'s recorder writes MCAP)")
    seed0 = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % 100000)
    rates = [100.0, 50.0, 200.0] if args.model == "fopdt" else [200.0, 100.0, 250.0]
    all_lat = []
    for r in range(args.runs):
        res = run(seed0 + r, rates[r % len(rates)], args.model, args.fmt, args.replay)
        lat = np.array(res["latency"])
        all_lat.extend(lat.tolist())
        rate = "replayed at its own rate" if args.replay else f"{res['rate_hz']:.0f} Hz"
        print(f"seed {res['seed']}  {rate}  updates {lat.size}  latency median "
              f"{np.median(lat) * 1e3:.0f} ms  p90 {np.percentile(lat, 90) * 1e3:.0f} ms  max {lat.max() * 1e3:.0f} ms  "
              f"| whole-file re-read {res['reread_s'] * 1e3:.0f} ms, + analyze {res['reread_analyze_s'] * 1e3:.0f} ms "
              f"({res['reread_analyze_s'] / np.median(lat):.1f}x the median latency)  {res['final']}"
              if lat.size else f"seed {res['seed']}: no updates; {res['final']}")
    a = np.array(all_lat)
    if a.size:
        print(f"all ({args.model}, {args.fmt}): {a.size} updates, latency median {np.median(a) * 1e3:.0f} ms, "
              f"p90 {np.percentile(a, 90) * 1e3:.0f} ms, max {a.max() * 1e3:.0f} ms; "
              f"share <= 0.2 s: {np.mean(a <= 0.2) * 100:.0f} %")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--writer":
        _writer(sys.argv[2], sys.argv[3], int(sys.argv[4]), float(sys.argv[5]), sys.argv[6], sys.argv[7],
                sys.argv[8])
    else:
        main()
