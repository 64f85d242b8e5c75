"""Benchmark: false alarms and detections of ``mrft-ident compare`` on simulated re-flights.

Fresh random plants every run (the seed is printed; ``--seed`` repeats one), flown as people fly them:
loop altitude/roll/pitch, Tp 0.02-0.1 s, Td 0.3-3 s, tau 10-90 ms, K 0.5-20, controller 100-500 Hz,
sensor noise 0.2-1 mm / 0.05-0.2 deg, two tests (betas drawn in -0.3 .. -0.8), 8-14 planned cycles,
and every flight at its own relay height (planned amplitude 3-8 cm / 3-8 deg, raised where the relay would
not clear the noise: noise margin >= 4) and noise seed. Per plant:

* a **baseline** flight and a **re-flight** of the unchanged plant: any significant change is a false
  alarm;
* a **changed** flight, tau + 10 ms (``--delta-ms``): the tau change must be flagged (significant and
  positive); a refused analysis of either flight counts as a miss.

Each flight is analysed as ``mrft-ident analyze`` does (:func:`mrftcli.analyze.analyze_flight`), its
JSON read back as ``compare`` reads it, and compared at 95 % (no tolerance: every significant change
fails). Prints the false-alarm rate per parameter (the figure the issue asks for, with its binomial
standard error), per loop (any of Td, tau, K; and with ``--bonferroni``'s correction), the detection rate,
and the calibration of the change intervals: the RMS of the z scores of the unchanged pairs (1 when the
analyses' intervals are calibrated) and each analysis' coverage of the true parameter.

Run: ``python benchmarks/bench_compare.py [--n 100] [--seed S] [--delta-ms 10]``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from test_segment_support import flight_from_simulated  # noqa: E402

from mrftcli.mrft.model import soiptd_model  # noqa: E402
from mrftcli.analyze import analyze_flight  # noqa: E402
from mrftcli.compare import CompareOptions, Side, compare_sides  # noqa: E402
from mrftcli.compare.inputs import estimates_from_analysis  # noqa: E402
from mrftcli.jsonable import to_jsonable  # noqa: E402
from mrftcli.mrft.model import LoopModel  # noqa: E402
from mrftcli.sim import noise_margin  # noqa: E402
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight  # noqa: E402

PARAMS = ("Td", "tau", "K")
MIN_MARGIN = 4.0


def draw_plant(rng: np.random.Generator) -> dict:
    loop = str(rng.choice(["altitude", "roll", "pitch"]))
    model = LoopModel(float(np.exp(rng.uniform(np.log(0.02), np.log(0.1)))),
                      float(np.exp(rng.uniform(np.log(0.3), np.log(3.0)))),
                      float(rng.uniform(0.01, 0.09)),
                      float(np.exp(rng.uniform(np.log(0.5), np.log(20.0)))))
    noise = float(rng.uniform(0.2e-3, 1e-3)) if loop == "altitude" else float(np.deg2rad(rng.uniform(0.05, 0.2)))
    betas = (float(rng.uniform(-0.5, -0.3)), float(rng.uniform(-0.8, -0.6)))
    return dict(loop=loop, model=model, rate=float(rng.choice([100.0, 200.0, 250.0, 500.0])), noise=noise,
                betas=betas)


def fly(plant: dict, model: LoopModel, rng: np.random.Generator):
    """One flight: its own relay height (amplitude), cycles and noise seed."""
    unit = 0.01 if plant["loop"] == "altitude" else math.radians(1.0)
    amplitude = float(rng.uniform(3.0, 8.0)) * unit
    cycles = float(rng.uniform(8.0, 14.0))
    tests = tuple(plan_test(model, b, amplitude, rate_hz=plant["rate"], cycles=cycles, min_duration=4.0)
                  for b in plant["betas"])
    # A pilot raises the amplitude until the relay clears the noise (margin 4: no lock-up over 176
    # simulated tests, mrftcli.sim.control.noise_margin); the margin is linear in the amplitude.
    margin = min(noise_margin(model, t.beta, t.h, plant["rate"], plant["noise"]) for t in tests)
    if margin < MIN_MARGIN:
        amplitude *= MIN_MARGIN / margin
        tests = tuple(plan_test(model, b, amplitude, rate_hz=plant["rate"], cycles=cycles, min_duration=4.0)
                      for b in plant["betas"])
    spec = FlightSpec(model=model, tests=tests, loop=plant["loop"], rate_hz=plant["rate"], noise_std=plant["noise"],
                      hover_s=2.0, hold_s=2.0, seed=int(rng.integers(1 << 30)))
    return flight_from_simulated(simulate_flight(spec))


def analyse(plant: dict, model: LoopModel, rng: np.random.Generator) -> dict | None:
    """The analysis JSON of one flight, or None when analyze refuses it."""
    try:
        return to_jsonable(analyze_flight(fly(plant, model, rng), soiptd_model(model.Tp)).to_dict())
    except Exception as exc:  # noqa: BLE001 - a refused flight is counted, not fatal
        print(f"    refused ({type(exc).__name__}: {str(exc)[:80]})")
        return None


def side(result: dict, name: str) -> Side:
    return Side(path=name, kind="analysis", loops=(estimates_from_analysis(result, source=name),))


def covers(result: dict, model: LoopModel) -> dict:
    out = {}
    for p in PARAMS:
        d = result["parameters"][p]
        hi = d["ci95_high"] if d["ci95_high"] is not None else math.inf
        if d["ci95_low"] is not None:
            out[p] = d["ci95_low"] <= getattr(model, p) <= hi
    return out


def rate(k: int, n: int) -> str:
    if n == 0:
        return "-"
    p = k / n
    return f"{k}/{n} = {100 * p:.1f} % (+/- {100 * math.sqrt(p * (1 - p) / n):.1f})"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--delta-ms", type=float, default=10.0)
    a = ap.parse_args()
    seed = a.seed if a.seed is not None else int(time.time()) % 1_000_000
    print(f"seed {seed}, {a.n} plants, changed flights tau + {a.delta_ms:g} ms")
    rng = np.random.default_rng(seed)
    plain, bonf = CompareOptions(), CompareOptions(correction="bonferroni")
    fa = {p: [0, 0] for p in PARAMS}  # [false alarms, determined pairs]
    undetermined = {p: 0 for p in PARAMS}
    loop_fa, loop_fa_bonf, loop_n, refused_pairs = 0, 0, 0, 0
    detected, det_refused = 0, 0
    zs: dict[str, list[float]] = {p: [] for p in PARAMS}
    largest = {p: 0.0 for p in PARAMS}  # largest |change| of an unchanged pair: relative (Td, K), seconds (tau)
    cover = {p: [0, 0] for p in PARAMS}
    t0 = time.process_time()
    for i in range(a.n):
        plant = draw_plant(rng)
        m = plant["model"]
        print(f"  {i + 1:3d} {plant['loop']:8s} {plant['rate']:4.0f} Hz Tp {m.Tp:.3f} Td {m.Td:.2f} "
              f"tau {1e3 * m.tau:.1f} ms K {m.K:.2f}", flush=True)
        base = analyse(plant, m, rng)
        again = analyse(plant, m, rng)
        changed = analyse(plant, LoopModel(m.Tp, m.Td, m.tau + a.delta_ms * 1e-3, m.K), rng)
        for r in (base, again):
            if r is not None:
                for p, ok in covers(r, m).items():
                    cover[p][0] += ok
                    cover[p][1] += 1
        if base is None or again is None:
            refused_pairs += 1
        else:
            cmp = compare_sides(side(base, "base"), side(again, "again"), plain)
            loop_n += 1
            loop_fa += any(c.significant for c in cmp.changes)
            loop_fa_bonf += any(c.significant for c in compare_sides(side(base, "b"), side(again, "a"), bonf).changes)
            for c in cmp.changes:
                if c.verdict == "undetermined":
                    undetermined[c.parameter] += 1
                    continue
                fa[c.parameter][0] += c.significant
                fa[c.parameter][1] += 1
                if c.z is not None and math.isfinite(c.z):
                    zs[c.parameter].append(c.z)
                size = abs(c.change or 0.0) if c.parameter == "tau" else abs(c.relative or 0.0)
                largest[c.parameter] = max(largest[c.parameter], size)
            flags = [f"{c.parameter} z {c.z:+.1f}" for c in cmp.changes if c.significant and c.z is not None]
            print(f"      re-flight: {'; '.join(flags) or 'nothing flagged'}")
        if base is None or changed is None:
            det_refused += 1
            print("      changed: MISS (refused)")
        else:
            cmp = compare_sides(side(base, "base"), side(changed, "changed"), plain)
            tau = next(c for c in cmp.changes if c.parameter == "tau")
            hit = tau.significant and (tau.change or 0.0) > 0
            detected += hit
            print(f"      changed: tau {1e3 * (tau.change or math.nan):+.2f} ms z {tau.z or math.nan:+.1f} "
                  f"{'flagged' if hit else 'MISS'}")
    cpu = time.process_time() - t0
    total_fa = sum(v[0] for v in fa.values())
    total_n = sum(v[1] for v in fa.values())
    print(f"\nseed {seed}: {a.n} plants, CPU {cpu:.0f} s")
    print(f"false alarms at 95 % per parameter (pooled Td, tau, K): {rate(total_fa, total_n)}")
    for p in PARAMS:
        zz = np.asarray(zs[p])
        rms = math.sqrt(float(np.mean(zz ** 2))) if zz.size else math.nan
        print(f"  {p:4s} {rate(*fa[p])}; undetermined {undetermined[p]}; RMS z {rms:.2f}; "
              f"coverage of the truth by the 95 % intervals {rate(*cover[p])}")
    print(f"largest change of an unchanged pair: Td {100 * largest['Td']:.2f} %, tau {1e3 * largest['tau']:.3f} ms, "
          f"K {100 * largest['K']:.3f} %")
    print(f"per loop (any parameter): {rate(loop_fa, loop_n)}; with --bonferroni {rate(loop_fa_bonf, loop_n)}; "
          f"refused pairs {refused_pairs}")
    print(f"tau + {a.delta_ms:g} ms flagged: {rate(detected, a.n)} (refusals counted as misses: {det_refused})")


if __name__ == "__main__":
    main()
