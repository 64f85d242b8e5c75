"""Benchmark: ``analyze`` on a 10-minute, 200 Hz MCAP log, end to end, plots excluded.

The log (reference layout, altitude loop of the paper's Design I) holds 20 MRFT tests (beta -0.4
and -0.7 alternating, ~22 s each, with holds between them). Timed: reading the three topics,
segmentation, identification with the bootstrap and the per-combination estimates, i.e.
:func:`mrftcli.analyze.analyze_path`. Baseline measured in the same run: the per-combination
estimates done the straightforward way, one :func:`mrftcli.mrft.identify.identify` call per combination
of cycles (timed on a sample and scaled), against the vectorised solver used by ``analyze``.

Run: ``python benchmarks/bench_analyze.py`` (about 30 s including the simulation).
"""

from __future__ import annotations

from mrftcli.mrft.model import soiptd_model
from mrftcli.io import ReadOptions
import tempfile
import time
from pathlib import Path

import numpy as np


def ten_minute_spec():
    """The 10-minute, 200 Hz altitude flight of 20 tests (Design I, betas -0.4/-0.7 alternating, 22 s each)
    this benchmark analyses; ``bench_held_out`` times its held-out stage on the same flight."""
    from mrftcli.mrft.model import LoopModel
    from mrftcli.sim.flight import FlightSpec, plan_test

    model = LoopModel(0.0422, 2.669, 0.0464, 19.6)
    tests = []
    for i in range(20):
        spec = plan_test(model, (-0.4, -0.7)[i % 2], 0.05, cycles=14)
        tests.append(type(spec)(spec.beta, spec.h, 22.0))
    return FlightSpec(model=model, tests=tuple(tests), loop="altitude", switching="hear", seed=1, hover_s=10.0,
                      hold_s=7.5)


def main() -> None:
    from mrftcli.analyze import analyze_path
    from mrftcli.mrft.consensus import consensus_solve
    from mrftcli.mrft.identify import TestMeasurement, identify
    from mrftcli.sim.flight import simulate_flight, write_flight

    fspec = ten_minute_spec()
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "ten_minutes.mcap"
        t0 = time.perf_counter()
        flight = simulate_flight(fspec)
        write_flight(flight, path, "mcap")
        print(f"log: {flight.t[-1] - flight.t[0]:.0f} s at 200 Hz, {flight.t.size} samples per topic, "
              f"{path.stat().st_size / 1e6:.1f} MB (simulated and written in {time.perf_counter() - t0:.1f} s)")
        analyze_path(path, soiptd_model(0.0422), read=ReadOptions(loop="altitude"))  # warm-up: imports, manifold loading
        runs = []
        for _ in range(3):
            t0 = time.perf_counter()
            result = analyze_path(path, soiptd_model(0.0422), read=ReadOptions(loop="altitude"))
            runs.append(time.perf_counter() - t0)
        total = float(np.median(runs))
        from mrftcli.io import read_flight
        from mrftcli.segment import segment

        t0 = time.perf_counter()
        fl = read_flight(path, ReadOptions(loop="altitude"))
        t_read = time.perf_counter() - t0
        t0 = time.perf_counter()
        segment(fl)
        t_seg = time.perf_counter() - t0
    n_cyc = sum(t.n_stable for t in result.tests)
    print(f"tests found {len(result.tests)}, stable cycles {n_cyc}; tau {result.tau.value * 1e3:.2f} ms "
          f"(true 46.40), Td {result.Td.value:.3f} s (true 2.669), K {result.K.value:.3f} (true 19.6)")
    print(f"analyze end to end (median of 3): {total:.2f} s  [read {t_read:.2f} s, segment {t_seg:.2f} s, "
          f"identification + uncertainty {total - t_read - t_seg:.2f} s]   target <= 3 s")

    # baseline: one identify() call per combination of cycles (two tests), vs the vectorised solver
    a, b = result.tests[0], result.tests[1]
    ba = np.array([c.beta_effective for c in a.stable])
    bb = np.array([c.beta_effective for c in b.stable])
    pa, pb = a.period, b.period
    ii, jj = np.meshgrid(np.arange(pa.size), np.arange(pb.size), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    m = min(40, ii.size)
    t0 = time.perf_counter()
    for i, j in zip(ii[:m], jj[:m]):
        identify([TestMeasurement(ba[i], 1 / pa[i]), TestMeasurement(bb[j], 1 / pb[j])], soiptd_model(0.0422))
    t_loop = (time.perf_counter() - t0) / m * ii.size
    t0 = time.perf_counter()
    betas = np.stack([ba[ii], bb[jj]], axis=1)
    omegas = 2 * np.pi / np.stack([pa[ii], pb[jj]], axis=1)
    consensus_solve(0.0422, betas, omegas, np.ones_like(betas), result.model.Td)
    t_vec = time.perf_counter() - t0
    print(f"per-combination estimates for one pair of tests ({ii.size} combinations): identify() loop "
          f"{t_loop:.2f} s, vectorised {t_vec:.3f} s -> {t_loop / t_vec:.0f}x faster")


if __name__ == "__main__":
    main()
