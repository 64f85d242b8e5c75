"""Batch throughput: logs per second with 1 and 2 local workers and through a Dask LocalCluster.

All three are measured in one run on the same freshly simulated set of logs (altitude loop, two betas,
200 Hz, MCAP), each from a cold output folder (``force``), the fleet report excluded, best of
``--repeat`` runs (the machine may be shared; the best run is the least disturbed one). The Dask cluster
(2 worker processes, 1 thread each, loopback) is started before its timing starts, as an existing
cluster would be; connecting the client is timed.

    python benchmarks/bench_batch.py [--logs 16] [--cycles 14] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from mrftcli.batch.run import BatchOptions, run_batch
from mrftcli.mrft.model import LoopModel
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight, write_flight


def make_logs(folder: Path, n: int, cycles: float, seed: int) -> list[float]:
    """Simulate ``n`` altitude flights with random plants; return the Tp of each (they share one here)."""
    rng = np.random.default_rng(seed)
    for i in range(n):
        model = LoopModel(Tp=0.0422, Td=float(rng.uniform(0.5, 3.0)), tau=float(rng.uniform(0.02, 0.08)), K=19.62)
        # h chosen for a 5 cm output amplitude, duration ~ ``cycles`` periods (as a pilot would plan it)
        tests = tuple(plan_test(model, beta, 0.05, cycles=cycles) for beta in (-0.4, -0.7))
        spec = FlightSpec(model=model, tests=tests, loop="altitude", seed=seed * 1000 + i, abort_error=5.0)
        path = folder / f"vehicle{i % 4}" / f"flight{i:03d}.mcap"
        path.parent.mkdir(parents=True, exist_ok=True)
        write_flight(simulate_flight(spec), path, "mcap")
    return [0.0422] * n


def _cpu() -> float:
    """User + system CPU seconds of this process and its waited-for children."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def timed(label: str, n: int, repeat: int, **kw) -> float:
    """Best of ``repeat`` cold-output runs (the machine is shared, so the best is the least disturbed)."""
    dt = cpu = float("inf")
    for _ in range(repeat):
        c0 = _cpu()
        t0 = time.perf_counter()
        opts = BatchOptions(force=True, report=False, **{k: kw.pop(k) for k in ("jobs", "scheduler") if k in kw})
        res = run_batch(options=opts, **kw)
        dt = min(dt, time.perf_counter() - t0)
        cpu = min(cpu, _cpu() - c0)
    counts = ", ".join(f"{v} {k}" for k, v in res.counts.items() if v)
    load = os.getloadavg()[0]
    # CPU of this process and of its reaped children (the local pool's workers; not Dask's, which live on)
    cpu_txt = f"{cpu / n:5.2f} CPU-s/log" if "scheduler" not in kw else "      (CPU n/a)"
    print(f"{label:<32} {dt:6.2f} s {n / dt:6.2f} logs/s {cpu_txt}  ({counts}; load average {load:.1f})")
    for _, row in res.failed.iterrows():
        print(f"    failed: {Path(row['path']).name}: {row['error']}")
    return n / dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=16)
    ap.add_argument("--cycles", type=float, default=14.0, help="relay periods per test")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=2, help="runs per configuration; the best is reported")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        logs = root / "logs"
        t0 = time.perf_counter()
        make_logs(logs, args.logs, args.cycles, args.seed)
        size = sum(p.stat().st_size for p in logs.rglob("*.mcap"))
        print(f"{args.logs} logs generated in {time.perf_counter() - t0:.1f} s "
              f"({size / args.logs / 1e6:.2f} MB each); {os.cpu_count()} cores")
        import mrftcli.analyze  # noqa: F401 - import once before timing, as a long-lived process would have

        common = {"paths": [logs], "defaults": {"tp": 0.0422, "loops": ("altitude",)}, "repeat": args.repeat}
        r1 = timed("local, --jobs 1 (in-process)", args.logs, out_dir=root / "o1", jobs=1, **common)
        r2 = timed("local, --jobs 2 (processes)", args.logs, out_dir=root / "o2", jobs=2, **common)
        try:
            import distributed
        except ImportError:
            print("dask distributed not installed: Dask row skipped")
            rd = float("nan")
        else:
            with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                          dashboard_address=None, silence_logs=40) as cluster:
                rd = timed("Dask LocalCluster, 2 workers", args.logs, out_dir=root / "od",
                           scheduler=cluster.scheduler_address, **common)
        print(f"speed-up over --jobs 1: --jobs 2 x{r2 / r1:.2f}, Dask x{rd / r1:.2f}")


if __name__ == "__main__":
    main()
