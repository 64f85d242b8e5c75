"""Low-rate logs: does the 95 % interval for tau cover the truth at PX4's default 10 Hz logging?

Fresh random altitude plants (Td 1-3 s, tau 30-70 ms, K 10-25, Tp 42.2 ms), a 50 Hz controller,
tests at beta -0.6 and -0.2 (14 cycles); each flight written as a PX4 ULog twice, at 10 Hz and at
every controller tick (io/stacks.py), and analysed. Prints each plant's tau [ms] and the estimate and
interval from both logs, then the coverage. Usage: python benchmarks/bench_low_rate.py [SEED] [N]
Figures: docs/log-layout.md ("Few samples per cycle and low-rate logs").
"""
import sys, math, tempfile, numpy as np
from pathlib import Path
from mrftcli.mrft.model import LoopModel
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight
from mrftcli.io.stacks import StackTest, write_stack_log
from mrftcli.io import read_flight
from mrftcli.analyze import analyze_flight
rng = np.random.default_rng(int(sys.argv[1]) if len(sys.argv) > 1 else 20261122)
out = Path(tempfile.mkdtemp())
hits = {10: 0, 50: 0}; n = 0
for k in range(int(sys.argv[2]) if len(sys.argv) > 2 else 8):
    m = LoopModel(0.0422, float(rng.uniform(1.0, 3.0)), float(rng.uniform(0.03, 0.07)), float(rng.uniform(10, 25)))
    betas = (-0.6, -0.2)
    tests = tuple(plan_test(m, b, 0.05, rate_hz=50.0, cycles=14.0) for b in betas)
    spec = FlightSpec(model=m, tests=tests, loop="altitude", rate_hz=50.0, noise_std=0.0005, bias=0.5, setpoint=1.0,
                      hover_s=3.0, hold_s=3.0, seed=int(rng.integers(1 << 30)))
    fl = simulate_flight(spec)
    st = [StackTest(e["t_start"], e["t_end"], e["beta"], e["h"]) for e in fl.truth["tests"]]
    row = []
    for lr in (10, 50):
        p = write_stack_log(out / f"f{lr}.ulg", "px4-mrft", "altitude", fl.t, fl.command, fl.output_measured,
                            fl.setpoint, fl.truth["bias"], st, log_rate_hz=lr if lr == 10 else None)
        try:
            r = analyze_flight(read_flight(p, loop="altitude", echo_warnings=False), Tp=0.0422, n_bootstrap=200, seed=1)
            ok = r.tau.ci95_low <= m.tau <= r.tau.ci95_high
            row.append((lr, round(r.tau.mean*1e3,1), round(r.tau.ci95_low*1e3,1), round(r.tau.ci95_high*1e3,1), ok))
            hits[lr] += ok
        except Exception as e:
            row.append((lr, type(e).__name__))
    n += 1
    print(round(m.tau*1e3,1), row, flush=True)
print("coverage", {k: f"{v}/{n}" for k, v in hits.items()})
