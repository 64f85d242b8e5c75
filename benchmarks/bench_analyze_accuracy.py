"""Benchmark: accuracy of ``analyze`` with and without the constraints beyond the paper.

Two sets, each identified four ways with :func:`mrftcli.analyze.analyze_flight`:
``constraints=()`` (the paper's method: UFM slices at the known Tp, exact LPRS, effective beta),
``("amplitude",)`` (plus the UGM amplitude ratios), ``("phase",)`` (plus each test's fundamental
harmonic phase) and ``("phase", "amplitude")`` (the default).

1. The acceptance sweep of ``tests/test_analyze_sweep.py``: 30 random plants (Tp 0.02-0.1 s, Td
   0.2-3 s, tau 10-100 ms, K 0.5-20; seed 0), the project's simulator at 200 Hz, noise 0.5 mm /
   0.2 deg, tests planned for 12 cycles.
2. Every log in ``sample_logs/`` with a ``.truth.json`` sidecar (each distinct log once: the format
   copies of design1_altitude hold the same samples).

Prints tau RMS and max error, the count within 1 ms, Td and K errors, and the mean |z| = |error| /
reported std (an honest interval has z of order 1). Run: ``python benchmarks/bench_analyze_accuracy.py``
(about a minute).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = {"paper (UFM only)": (), "+ amplitude": ("amplitude",), "+ phase": ("phase",),
            "+ phase + amplitude": ("phase", "amplitude")}


def _summary(name: str, rows: list) -> str:
    e = np.array([r[0] for r in rows]) * 1e3
    z = np.array([r[0] / r[3] for r in rows])
    td = np.array([r[1] for r in rows]) * 100
    kk = np.array([r[2] for r in rows]) * 100
    return (f"{name:<22} tau RMS {np.sqrt(np.mean(e**2)):.3f} ms  max {np.max(np.abs(e)):.3f} ms  "
            f"within 1 ms {int(np.sum(np.abs(e) <= 1.0))}/{e.size}  mean |z| {np.mean(np.abs(z)):.2f}  "
            f"Td max {np.max(np.abs(td)):.1f} %  K max {np.max(np.abs(kk)):.2f} %")


def main() -> None:
    sys.path.insert(0, str(ROOT / "tests"))
    from test_analyze_sweep import sweep_plants  # the acceptance sweep's own plants
    from test_segment_support import flight_from_simulated, simulate_paper_flight

    from mrftcli.analyze import analyze_flight
    from mrftcli.io import read_flight

    sets = {"30-plant sweep": [], "sample logs": []}
    for k, loop, Tp, Td, tau, K in sweep_plants(30, seed=0):
        betas = (-0.4, -0.7) if loop == "altitude" else (-0.5, -0.8)
        sf = simulate_paper_flight(Tp, Td, tau, K, betas, loop=loop, cycles=12.0, seed=k)
        sets["30-plant sweep"].append((f"plant {k}", flight_from_simulated(sf), Tp, Td, tau, K))
    seen = set()
    for sc in sorted((ROOT / "sample_logs").glob("*.truth.json")):
        truth = json.loads(sc.read_text())
        key = (truth.get("seed"), truth["tau"], truth["Td"], truth["loop"])
        if key in seen:
            continue
        seen.add(key)
        fl = read_flight(sc.with_name(sc.name[: -len(".truth.json")]), loop=truth["loop"])
        sets["sample logs"].append((sc.name[: -len(".truth.json")], fl, truth["Tp"], truth["Td"], truth["tau"],
                                    truth["K"]))
    for set_name, items in sets.items():
        print(f"== {set_name} ({len(items)} logs)")
        for name, cons in VARIANTS.items():
            t0 = time.perf_counter()
            rows = []
            worst = None
            for label, fl, Tp, Td, tau, K in items:
                r = analyze_flight(fl, Tp, constraints=cons, n_bootstrap=200)
                rows.append((r.tau.mean - tau, r.Td.mean / Td - 1, r.K.mean / K - 1, r.tau.std))
                if worst is None or abs(rows[-1][0]) > abs(worst[1]):
                    worst = (label, rows[-1][0])
            print(_summary(name, rows) + f"  worst {worst[0]} ({worst[1] * 1e3:+.2f} ms)  "
                  f"[{time.perf_counter() - t0:.1f} s]")


if __name__ == "__main__":
    main()
