"""Low-rate logs: do the 95 % intervals for Td, tau and K cover the truth at PX4's default 10 Hz logging?

Fresh random altitude plants, a 50 Hz controller, two tests (14 cycles), sensor noise 0.2-1 mm; each
flight written as a PX4 ULog twice, at 10 Hz and at every controller tick (io/stacks.py), and
analysed (the 10 Hz log with the controller's rate, 50 Hz, as the PX4 layout knows it). Two draws:

* ``slow`` (issue 11): Td 1-3 s, tau 30-70 ms, K 10-25, Tp 42.2 ms, beta -0.6 and -0.2 (tests at
  0.4-1.3 Hz: 8-25 samples per cycle at 10 Hz);
* ``fast`` (issue 24 part 3): tau 15-50 ms, beta -0.8 and -0.3 (the faster test at 1.6-2.4 Hz:
  4-6 samples per cycle at 10 Hz);
* ``users``: as ``fast``, flown as people fly them: 8-14 cycles per test and a relay height for an
  amplitude of 2-8 cm, drawn per test (a refusal counts as a miss).

Prints each plant's truth, its tests' frequencies and both logs' estimates and intervals (K's error
over its std: a sign common to the misses would be a bias, not scatter), then per
log rate: the coverage of each parameter's 95 % interval, the mean interval widths, how many flights
had both tests used, and the failures (a failure, e.g. "only one beta was tested", counts as a miss);
and the 10 Hz / 50 Hz width ratios.
Usage: nice -n 10 python benchmarks/bench_low_rate.py [SEED] [N] [slow|fast|users] [--only I[,J...]]
(``--only``: fly and analyse only those plants of the draw, numbered from 0; the others are drawn
and skipped, so plant I is the same flight as in the full run.)
Figures: docs/benchmarks/low_rate.md.
"""
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalyzeOptions, analyze_flight
from mrftcli.io import ReadOptions, read_flight
from mrftcli.io.stacks import StackLogSpec, StackTest, write_stack_log
from mrftcli.mrft.model import LoopModel
from mrftcli.sim.control import df_prediction
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight

ARGS = sys.argv[1:]
ONLY: set[int] | None = None
if "--only" in ARGS:
    i = ARGS.index("--only")
    ONLY = {int(v) for v in ARGS[i + 1].split(",")}
    del ARGS[i:i + 2]
SEED = int(ARGS[0]) if len(ARGS) > 0 else 20261122
N = int(ARGS[1]) if len(ARGS) > 1 else 20
MODE = ARGS[2] if len(ARGS) > 2 else "slow"
DRAWS = {"slow": ((0.03, 0.07), (-0.6, -0.2)), "fast": ((0.015, 0.05), (-0.8, -0.3)),
         "users": ((0.015, 0.05), (-0.8, -0.3))}
TAU_RANGE, BETAS = DRAWS[MODE]
RATES = (10, 50)
PARS = ("Td", "tau", "K")

rng = np.random.default_rng(SEED)
out = Path(tempfile.mkdtemp())
hit = {r: {p: 0 for p in PARS} for r in RATES}
width = {r: {p: [] for p in PARS} for r in RATES}
both = {r: 0 for r in RATES}
fail = {r: [] for r in RATES}
for k in range(N):
    m = LoopModel(0.0422, float(rng.uniform(1.0, 3.0)), float(rng.uniform(*TAU_RANGE)), float(rng.uniform(10, 25)))
    if MODE == "users":
        tests = tuple(plan_test(m, b, float(rng.uniform(0.02, 0.08)), rate_hz=50.0,
                                cycles=float(rng.integers(8, 15))) for b in BETAS)
    else:
        tests = tuple(plan_test(m, b, 0.05, rate_hz=50.0, cycles=14.0) for b in BETAS)
    spec = FlightSpec(model=m, tests=tests, loop="altitude", rate_hz=50.0, noise_std=float(rng.uniform(2e-4, 1e-3)),
                      bias=0.5, setpoint=1.0, hover_s=3.0, hold_s=3.0, seed=int(rng.integers(1 << 30)))
    if ONLY is not None and k not in ONLY:
        continue  # drawn (the draws after it stay the same), not flown
    fl = simulate_flight(spec)
    st = [StackTest(e["t_start"], e["t_end"], e["beta"], e["h"]) for e in fl.truth["tests"]]
    freqs = [df_prediction(m, b, 1.0, 50.0)[0] / (2 * math.pi) for b in BETAS]
    row = [f"Td {m.Td:.3f} tau {m.tau * 1e3:.1f} K {m.K:.2f} tests {freqs[0]:.2f}/{freqs[1]:.2f} Hz |"]
    for lr in RATES:
        log = StackLogSpec("px4-mrft", "altitude", fl.truth["bias"], st, log_rate_hz=lr if lr < 50 else None)
        p = write_stack_log(out / f"f{lr}.ulg", log, fl.t, fl.command, fl.output_measured, fl.setpoint)
        try:
            r = analyze_flight(read_flight(p, ReadOptions(loop="altitude"), echo_warnings=False), soiptd_model(0.0422),
                               options=AnalyzeOptions(n_bootstrap=200, seed=1, controller_rate_hz=50.0))
        except Exception as e:  # a failure counts as a miss
            fail[lr].append(type(e).__name__)
            # what the user is told, after the path: the refusal's reason
            row.append(f"{lr} Hz: {type(e).__name__}: {str(e).split(': ', 1)[-1][:160]} |")
            continue
        both[lr] += len(r.tests) == len(BETAS)
        spc = [f"{t.rate_hz / t.frequency_hz_mean:.1f}" for t in r.tests]
        for name in PARS:
            est, truth = getattr(r, name), getattr(m, name)
            ok = bool(est.ci95_low <= truth <= est.ci95_high)
            hit[lr][name] += ok
            width[lr][name].append((est.ci95_high - est.ci95_low) / truth)
        row.append(f"{lr} Hz: tau {r.tau.value * 1e3:.1f} [{r.tau.ci95_low * 1e3:.1f}, {r.tau.ci95_high * 1e3:.1f}] "
                   f"Td {r.Td.value:.3f} [{r.Td.ci95_low:.3f}, {r.Td.ci95_high:.3f}] K {r.K.value:.2f} "
                   f"[{r.K.ci95_low:.2f}, {r.K.ci95_high:.2f}] (error/std {(r.K.value - m.K) / r.K.std:+.1f}) ({r.method}, {len(r.tests)} tests, {'/'.join(spc)} "
                   "samples per cycle) |")
    print(k, *row, flush=True)


def mean_width(lr: int, p: str) -> float:
    return float(np.mean(width[lr][p])) if width[lr][p] else float("nan")


print(f"\n{N} plants ({MODE}, seed {SEED}); 95 % interval coverage and mean width (relative to the truth); "
      "both tests used; failures")
for lr in RATES:
    cov = "  ".join(f"{p} {hit[lr][p]}/{N}" for p in PARS)
    wid = "  ".join(f"{p} {mean_width(lr, p) * 100:.1f} %" for p in PARS)
    print(f"{lr:3d} Hz log: coverage {cov} | width {wid} | both tests {both[lr]}/{N} | failures {len(fail[lr])} "
          f"{fail[lr]}")
ratios = "  ".join(f"{p} {mean_width(10, p) / mean_width(50, p):.1f}" for p in PARS)
print(f"interval width ratio 10 Hz / 50 Hz: {ratios}")
