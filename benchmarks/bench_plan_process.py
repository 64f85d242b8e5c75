"""Benchmark: ``plan LOG --model NAME`` — the forecast std after the recommended relay test against the std achieved.

Per family (fopdt, sopdt, ipdt, foipdt), fresh draws as ``bench_families.py`` makes them (K
log-uniform in [0.5, 5]; time constants in [0.3, 3] s, SOPDT's second lag 0.1-0.5 of the first; tau
0.1-1 of the main time constant, 0.1-0.8 s for IPDT; controller rate 50-200 Hz; white output noise of
1-3 % of the ideal relay's amplitude). The first recording is what an engineer runs first: one ideal
relay test of about 14 cycles, relay height 1. Then:

1. ``analyze_flight`` + ``plan_tests`` on it (what ``plan LOG --model NAME`` runs): the current stds,
   what is undetermined, the recommended relay and the stds it forecasts;
2. the recommended relay is flown after the first test in tests/process_sim.py (no code shared with
   mrftcli; the same seed, so the first test is the same recording) and both are analysed together:
   the std achieved, the error against the truth, and whether the 95 % interval covers it;
3. the baseline, in the same process: the ideal relay flown again instead (the obvious second test),
   analysed the same way: the ratio of the stds achieved (recommended / repeated) says what the plan
   is worth.

A draw the tool refuses (no usable test, no candidate) is printed and counted as a miss.

Run: ``nice -n 10 python benchmarks/bench_plan_process.py [--n 3] [--seed 0]`` (about 3 s a draw).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

FAMILIES = ("fopdt", "sopdt", "ipdt", "foipdt")


def _analyse(family, params, windows, rate, noise, seed, path):
    from process_sim import simulate, write_csv

    from mrftcli.analyze import analyze_flight
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.families import family_model

    t, u, y = simulate(family, params, windows, rate, noise, seed=seed)
    write_csv(str(path), t, u, y)
    flight = read_flight(path, ReadOptions(command_topic="u_relay", output_topic="y_output"), echo_warnings=False)
    return analyze_flight(flight, family_model(family))


def _std(e) -> float:
    return e.std if e.determined else math.inf


def one_draw(family: str, rng: np.random.Generator, tmp: Path) -> dict[str, object]:
    from bench_families import draw_plant
    from process_sim import Window

    from mrftcli.errors import MrftError
    from mrftcli.mrft.families import PROCESS_FAMILIES
    from mrftcli.mrft.relays import RelayLaw
    from mrftcli.mrft.families import family_model
    from mrftcli.plan import PlanLimits, plan_tests

    params = draw_plant(family, rng)
    ideal = RelayLaw("ideal", 1.0, -1.0).limit_cycle(PROCESS_FAMILIES[family](**params))
    rate = float(rng.uniform(50.0, 200.0))
    noise = float(rng.uniform(0.01, 0.03)) * ideal.amplitude
    seed = int(rng.integers(1 << 31))
    first = Window("ideal", 1.0, -1.0, duration=14 * ideal.period, rest=ideal.period)
    out: dict[str, object] = {"family": family, "params": params, "rate": rate, "noise_pct": 100 * noise / ideal.amplitude}
    try:
        plan = plan_tests(family_model(family), PlanLimits(),
                          recorded=_analyse(family, params, [first], rate, noise, seed, tmp / "first.csv"))
    except MrftError as err:
        return {**out, "refused": f"first/plan: {str(err)[:90]}"}
    best = plan.recommended
    r = best.relay
    dur = 14 * 2 * math.pi / max(2 * math.pi * best.frequency_hz[0], 1e-9)
    second = Window(r.kind, r.high, r.low, beta=r.beta, eps=r.eps, duration=dur, rest=ideal.period)
    again = Window("ideal", 1.0, -1.0, duration=first.duration, rest=ideal.period)
    try:
        both = _analyse(family, params, [first, second], rate, noise, seed, tmp / "both.csv").identification
        base = _analyse(family, params, [first, again], rate, noise, seed, tmp / "again.csv").identification
    except MrftError as err:
        return {**out, "refused": f"second: {str(err)[:90]}", "relay": r.describe()}
    rows = {}
    for name in plan.prior_std:
        e, b = both.estimate(name), base.estimate(name)
        rows[name] = {"now": plan.prior_std[name], "undetermined_now": name in plan.undetermined,
                      "predicted": best.predicted_std[name], "achieved": _std(e), "baseline": _std(b),
                      "err": e.value / params[name] - 1, "covered": e.ci95_low <= params[name] <= e.ci95_high}
    return {**out, "refused": "", "relay": r.describe()[len("relay: "):], "rows": rows}


def _print_draw(k: int, d: dict) -> None:
    p = ", ".join(f"{n} {v:.3g}" for n, v in d["params"].items())
    print(f"{d['family']:<6} #{k}  {p}; {d['rate']:.0f} Hz, noise {d['noise_pct']:.1f} %")
    if d["refused"]:
        print(f"    REFUSED ({d['refused']})")
        return
    print(f"    recommended: {d['relay']}")
    for name, r in d["rows"].items():
        und = " (undetermined now)" if r["undetermined_now"] else ""
        print(f"    {name:<4} std now {r['now']:.3g}{und}  predicted after {r['predicted']:.3g}  achieved {r['achieved']:.3g}"
              f"  (ratio {r['achieved'] / r['predicted']:.2f})  repeated ideal {r['baseline']:.3g}  "
              f"error {100 * r['err']:+.1f} %  95 % covers: {'yes' if r['covered'] else 'NO'}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=3, help="draws per family")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--families", default=",".join(FAMILIES))
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    draws = []
    t0 = time.process_time()
    print(f"{args.n} fresh draws per family (seed {args.seed}); first recording: one ideal relay test")
    with tempfile.TemporaryDirectory() as d:
        for family in args.families.split(","):
            for k in range(args.n):
                draws.append(one_draw(family, rng, Path(d)))
                _print_draw(k + 1, draws[-1])
    rows = [r for d in draws if not d["refused"] for r in d["rows"].values()]
    n_draws, refused = len(draws), sum(bool(d["refused"]) for d in draws)
    ratios = [r["achieved"] / r["predicted"] for r in rows if math.isfinite(r["achieved"] / r["predicted"])]
    within2 = sum(0.5 <= x <= 2.0 for x in ratios)
    gain = [r["baseline"] / r["achieved"] for r in rows if math.isfinite(r["baseline"] / r["achieved"])]
    covered = sum(r["covered"] for r in rows)
    und = [r for r in rows if r["undetermined_now"]]
    fixed = sum(math.isfinite(r["achieved"]) for r in und)
    print(f"summary: {n_draws} draws, {refused} refused (misses); {len(rows)} parameter rows")
    print(f"  achieved / predicted std: median {np.median(ratios):.2f} (10-90 %: {np.percentile(ratios, 10):.2f}-"
          f"{np.percentile(ratios, 90):.2f}); within 2x on {within2}/{len(rows)}")
    print(f"  repeated-ideal std / recommended std (same process, same first recording): median {np.median(gain):.2f} "
          f"(10-90 %: {np.percentile(gain, 10):.2f}-{np.percentile(gain, 90):.2f})")
    print(f"  undetermined after the first test: {len(und)} parameter rows; determined after the recommended "
          f"test: {fixed}/{len(und)}")
    print(f"  95 % intervals after both tests cover the truth: {covered}/{len(rows)}; "
          f"{time.process_time() - t0:.0f} s CPU")


if __name__ == "__main__":
    main()
