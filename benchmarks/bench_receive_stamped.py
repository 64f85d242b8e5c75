"""Receive-stamped topics: is the refined estimate as accurate as on the same flights stamped at the source?

Fresh random altitude plants (Td 1-3 s, tau 20-80 ms, K 10-25, Tp 42.2 ms), a 200 Hz controller,
tests at beta -0.6 and -0.3 (12 cycles), sensor noise 0.3-1 mm. Each flight is recorded four ways
(mrftcli/sim/stamps.py, no file written):

* ``source``: both topics stamped at the source, 1 % of the outputs lost (the baseline);
* ``cmd-recv``: the command stamped on arrival, late by 0-3 ms at random; the output as in ``source``;
* ``both-recv``: both topics stamped on arrival (0-3 ms), 1 % of the outputs lost;
* ``cmd-drop``: as ``cmd-recv`` with 1 % of the commands lost too (a message's position is then not
  its tick: the refinement runs on receive times and tau's interval is widened for the jitter).

Every variant is analysed (``analyze_flight``, 200 draws); a failure counts as a miss. Prints per
variant the RMS error of Td [%], tau [ms], K [%], the coverage of the 95 % intervals, how often the
waveform estimate was reported, and the RMS ratio of each receive-stamped variant to ``source``.
Usage: nice -n 10 python benchmarks/bench_receive_stamped.py [SEED] [N]
Figures: docs/benchmarks/receive_stamped.md.
"""
import sys

import numpy as np

from mrftcli.analyze import AnalyzeOptions, analyze_flight
from mrftcli.mrft.model import LoopModel
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight
from mrftcli.sim.stamps import ReceiveStamping, recorded_flight

SEED = int(sys.argv[1]) if len(sys.argv) > 1 else 20261125
N = int(sys.argv[2]) if len(sys.argv) > 2 else 20
LATE = ReceiveStamping(late_max=0.003)
DROPS = ReceiveStamping(late_max=0.0, drop=0.01)
LATE_DROPS = ReceiveStamping(late_max=0.003, drop=0.01)
VARIANTS = {"source": (None, DROPS), "cmd-recv": (LATE, DROPS), "both-recv": (LATE, LATE_DROPS),
            "cmd-drop": (LATE_DROPS, DROPS)}
PARS = ("Td", "tau", "K")
SCALE = {"Td": "%", "tau": "ms", "K": "%"}


def error(name: str, est: float, truth: float) -> float:
    """Td and K in % of the truth, tau in ms."""
    return (est - truth) * 1e3 if name == "tau" else (est / truth - 1.0) * 100.0


rng = np.random.default_rng(SEED)
err = {v: {p: [] for p in PARS} for v in VARIANTS}
hit = {v: {p: 0 for p in PARS} for v in VARIANTS}
refined = {v: 0 for v in VARIANTS}
fail = {v: [] for v in VARIANTS}
for k in range(N):
    m = LoopModel(0.0422, float(rng.uniform(1.0, 3.0)), float(rng.uniform(0.02, 0.08)), float(rng.uniform(10, 25)))
    tests = tuple(plan_test(m, b, 0.05, cycles=10, min_duration=4.0) for b in (-0.6, -0.3))
    spec = FlightSpec(model=m, tests=tests, loop="altitude", switching="hear", rate_hz=200.0,
                      noise_std=float(rng.uniform(3e-4, 1e-3)), seed=int(rng.integers(1 << 30)))
    fl = simulate_flight(spec)
    stamp_seed = int(rng.integers(1 << 30))
    row = [f"Td {m.Td:.3f} tau {m.tau * 1e3:.1f} K {m.K:.2f} |"]
    for name, (cmd, out) in VARIANTS.items():
        flight = recorded_flight(fl, command=cmd, output=out, seed=stamp_seed)
        try:
            r = analyze_flight(flight, Tp=0.0422, options=AnalyzeOptions(n_bootstrap=200, seed=1))
        except Exception as e:  # a refusal or failure counts as a miss
            fail[name].append(type(e).__name__)
            row.append(f"{name}: {type(e).__name__} |")
            continue
        refined[name] += r.method == "waveform"
        for p in PARS:
            est, truth = getattr(r, p), getattr(m, p)
            err[name][p].append(error(p, est.mean, truth))
            hit[name][p] += bool(est.ci95_low <= truth <= est.ci95_high)
        row.append(f"{name}: tau {error('tau', r.tau.mean, m.tau):+.3f} ms ({r.method}) |")
    print(k, *row, flush=True)


def rms(name: str, p: str) -> float:
    e = np.asarray(err[name][p])
    return float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")


print(f"\n{N} flights (seed {SEED}); RMS error, 95 % coverage, waveform estimate reported, failures")
for name in VARIANTS:
    figs = "  ".join(f"{p} {rms(name, p):.3f} {SCALE[p]}" for p in PARS)
    cov = "  ".join(f"{p} {hit[name][p]}/{N}" for p in PARS)
    print(f"{name:9s} RMS {figs} | coverage {cov} | waveform {refined[name]}/{N} | failures {len(fail[name])}")
for name in VARIANTS:
    if name != "source":
        ratio = "  ".join(f"{p} {rms(name, p) / rms('source', p):.2f}x" for p in PARS)
        print(f"RMS ratio {name} / source: {ratio}")
