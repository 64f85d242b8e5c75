"""Low-rate logs: do the 95 % intervals for Td, tau and K cover the truth at PX4's default 10 Hz logging?

Fresh random altitude plants (Td 1-3 s, tau 30-70 ms, K 10-25, Tp 42.2 ms), a 50 Hz controller,
tests at beta -0.6 and -0.2 (14 cycles), sensor noise 0.2-1 mm; each flight written as a PX4 ULog
twice, at 10 Hz and at every controller tick (io/stacks.py), and analysed (the 10 Hz log with the
controller's rate, 50 Hz, as the PX4 layout knows it). Prints each plant's truth and both logs'
estimates and intervals, then per log rate: the coverage of each parameter's 95 % interval, the
mean interval widths and the failures. Usage: python benchmarks/bench_low_rate.py [SEED] [N]
Figures: docs/benchmarks/low_rate.md.
"""
import sys
import tempfile
import numpy as np
from pathlib import Path
from mrftcli.mrft.model import LoopModel
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight
from mrftcli.io.stacks import StackTest, write_stack_log
from mrftcli.io import read_flight
from mrftcli.analyze import analyze_flight

rng = np.random.default_rng(int(sys.argv[1]) if len(sys.argv) > 1 else 20261122)
N = int(sys.argv[2]) if len(sys.argv) > 2 else 20
out = Path(tempfile.mkdtemp())
RATES = (10, 50)
PARS = ("Td", "tau", "K")
hit = {r: {p: 0 for p in PARS} for r in RATES}
width = {r: {p: [] for p in PARS} for r in RATES}
fail = {r: [] for r in RATES}
for k in range(N):
    m = LoopModel(0.0422, float(rng.uniform(1.0, 3.0)), float(rng.uniform(0.03, 0.07)), float(rng.uniform(10, 25)))
    tests = tuple(plan_test(m, b, 0.05, rate_hz=50.0, cycles=14.0) for b in (-0.6, -0.2))
    spec = FlightSpec(model=m, tests=tests, loop="altitude", rate_hz=50.0, noise_std=float(rng.uniform(2e-4, 1e-3)),
                      bias=0.5, setpoint=1.0, hover_s=3.0, hold_s=3.0, seed=int(rng.integers(1 << 30)))
    fl = simulate_flight(spec)
    st = [StackTest(e["t_start"], e["t_end"], e["beta"], e["h"]) for e in fl.truth["tests"]]
    row = [f"Td {m.Td:.3f} tau {m.tau * 1e3:.1f} K {m.K:.2f} |"]
    for lr in RATES:
        p = write_stack_log(out / f"f{lr}.ulg", "px4-mrft", "altitude", fl.t, fl.command, fl.output_measured,
                            fl.setpoint, fl.truth["bias"], st, log_rate_hz=lr if lr < 50 else None)
        try:
            r = analyze_flight(read_flight(p, loop="altitude", echo_warnings=False), Tp=0.0422, n_bootstrap=200,
                               seed=1, controller_rate_hz=50.0)
        except Exception as e:  # a failure counts as a miss
            fail[lr].append(type(e).__name__)
            row.append(f"{lr} Hz: {type(e).__name__} |")
            continue
        for name in PARS:
            est, truth = getattr(r, name), getattr(m, name)
            ok = bool(est.ci95_low <= truth <= est.ci95_high)
            hit[lr][name] += ok
            width[lr][name].append((est.ci95_high - est.ci95_low) / truth)
        row.append(f"{lr} Hz: tau {r.tau.mean * 1e3:.1f} [{r.tau.ci95_low * 1e3:.1f}, {r.tau.ci95_high * 1e3:.1f}] "
                   f"Td {r.Td.mean:.3f} [{r.Td.ci95_low:.3f}, {r.Td.ci95_high:.3f}] K {r.K.mean:.2f} "
                   f"[{r.K.ci95_low:.2f}, {r.K.ci95_high:.2f}] ({r.method}) |")
    print(k, *row, flush=True)
print(f"\n{N} plants; 95 % interval coverage and mean width (relative to the truth); failures")
for lr in RATES:
    cov = "  ".join(f"{p} {hit[lr][p]}/{N}" for p in PARS)
    wid = "  ".join(f"{p} {np.mean(width[lr][p]) * 100:.1f} %" if width[lr][p] else f"{p} -" for p in PARS)
    print(f"{lr:3d} Hz log: coverage {cov} | width {wid} | failures {len(fail[lr])} {fail[lr]}")
r10, r50 = (np.mean(width[10]["tau"]) if width[10]["tau"] else np.nan), np.mean(width[50]["tau"])
print(f"tau interval width ratio 10 Hz / 50 Hz: {r10 / r50:.1f}")
