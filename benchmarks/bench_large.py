"""A long log: time and memory against its length (tracker issue 29, item 4 and "what is left" 1).

The issue's case is a 10-million-row CSV (470 MB: one 14-hour 200 Hz flight, 50 000 relay cycles,
``csv_big`` of ``scripts/make_hostile_corpus.py``). This benchmark writes that file at ``--rows`` rows
and at a fifth of it (both above the 64 MB from which a CSV is read in blocks), runs ``topics`` and ``analyze`` on each as a user would (one process each), and
prints for every run: exit code, wall time, CPU time (user + system: the machine is shared, CPU is
the figure that does not depend on the load), the process's peak resident memory (``ru_maxrss`` from
``wait4``), and CPU per million rows. The scaling figures: the ratio of the long file's CPU to the short
one's (5 when the time is linear in the rows), and the memory each extra million rows costs.

Run: ``nice -n 10 python benchmarks/bench_large.py [--rows 10000000] [--keep DIR]`` (the issue's size:
about 5 minutes of CPU and 0.6 GB of disk; the default, 2 000 000 rows, about a minute).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from make_hostile_corpus import _big_csv  # noqa: E402

#: what each command is asked (the corpus's file is one single-beta flight: analyze refuses it, exit 6,
#: after reading it, finding its relay runs and measuring the test's first 5000 cycles,
#: mrftcli.segment.segmenter.MAX_CYCLES: the reading and the relay runs are the work that grows with the log)
COMMANDS = {
    "topics": ["topics"],
    "analyze": ["analyze", "--tp", "0.1", "--loop", "altitude", "--json", "{out}"],
}


@dataclass(frozen=True)
class Run:
    rows: int
    command: str
    code: int
    wall_s: float
    cpu_s: float
    peak_mb: float


def run(path: Path, rows: int, command: str, out: Path) -> Run:
    """One command on one file in its own process: exit code, wall and CPU time [s], peak RSS [MiB]."""
    argv = [sys.executable, "-m", "mrftcli", *[a.format(out=out) for a in COMMANDS[command][:1]], str(path),
            *[a.format(out=out) for a in COMMANDS[command][1:]]]
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
    start = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    return Run(rows, command, proc.returncode, wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=2_000_000, help="rows of the long file (the issue: 10000000)")
    parser.add_argument("--keep", type=Path, help="folder to write (and reuse) the CSVs in; default: a temporary one")
    args = parser.parse_args(argv)
    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench_large_"))
    folder.mkdir(parents=True, exist_ok=True)
    print("| rows | command | exit | wall [s] | CPU [s] | peak RSS [MiB] | CPU per M rows [s] |")
    print("|---|---|---|---|---|---|---|")
    runs: list[Run] = []
    for rows in (args.rows // 5, args.rows):
        path = folder / f"big_{rows}.csv"
        if not path.exists():
            _big_csv(rows)(path)
        for command in COMMANDS:
            r = run(path, rows, command, folder / "result.json")
            runs.append(r)
            m = rows / 1e6
            print(f"| {rows} | {command} | {r.code} | {r.wall_s:.1f} | {r.cpu_s:.1f} | {r.peak_mb:.0f} | "
                  f"{r.cpu_s / m:.1f} |", flush=True)
    for command in COMMANDS:
        short, long = (r for r in runs if r.command == command)
        print(f"{command}: {long.rows // short.rows}x the rows take {long.cpu_s / short.cpu_s:.1f}x the CPU "
              f"({'linear' if long.cpu_s / short.cpu_s < 1.3 * long.rows / short.rows else 'super-linear'}); "
              f"{(long.peak_mb - short.peak_mb) / ((long.rows - short.rows) / 1e6):.0f} MB per extra million rows; "
              f"peak {long.peak_mb:.0f} MB ({'under' if long.peak_mb < 1024 else 'OVER'} 1 GB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
