"""Issue 40 item 5: with --simulate N, is the plan ever predicted worse than the conventional -0.4 / -0.7?

Runs docs/plan.md's first example (a 2-test plan before any flight: Tp 0.0422 s, 5 cm, h <= 0.2, 30 s,
200 Hz, 0.2 mm of noise, K 2-8) with N simulated plants, and prints every round of the simulated choice
(the betas tried, the flights analyze lost of each), the betas kept, their predicted std of Td and tau
beside the conventional pair's, and the note that says why when they are worse.

    python benchmarks/bench_plan_guard.py [--simulate 8,64] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import mrftcli.plan.driver as driver
from mrftcli.mrft.model import soiptd_model
from mrftcli.plan import PlanLimits, PlanOptions, Prior, plan_tests


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--simulate", default="8,64", help="simulated plants, comma-separated")
    ap.add_argument("--seed", type=int, default=0, help="the plan's seed (draws and simulated flights)")
    args = ap.parse_args()
    limits = PlanLimits(max_amplitude=0.05, max_h=0.2, time_s=30.0, rate_hz=200.0, noise_std=0.0002)
    prior = Prior(Td=(0.2, 3.0), tau=(0.01, 0.1), K=(2.0, 8.0))
    original = driver._simulate
    for n in (int(x) for x in args.simulate.split(",")):
        rounds: list[str] = []

        def traced(space, prior_, flown, tests, options, rng, progress, rounds=rounds):
            out = original(space, prior_, flown, tests, options, rng, progress)
            rounds.append(f"[{', '.join(f'{t.beta:g}' for t in tests)}] lost {list(out.lost)} of {options.n_simulated}")
            return out

        driver._simulate = traced
        t0 = time.process_time()
        p = plan_tests(soiptd_model(0.0422), limits, prior=prior, options=PlanOptions(n_simulated=n, seed=args.seed))
        cpu = time.process_time() - t0
        driver._simulate = original
        conv = p.conventional
        print(f"--simulate {n} (seed {args.seed}, {cpu:.0f} s CPU): rounds {'; '.join(rounds)}")
        print(f"  kept {[t.beta for t in p.tests]}: Td {p.predicted_std['Td']:.4g} s, tau "
              f"{p.predicted_std['tau'] * 1e3:.3g} ms; " + (
                  "the conventional pair: refused by the limits on these draws" if conv is None else
                  f"conventional {list(conv.betas)}: Td {conv.predicted_std['Td']:.4g} s, tau "
                  f"{conv.predicted_std['tau'] * 1e3:.3g} ms"))
        worse = [n_ for n_ in p.notes if "predicted worse than the conventional" in n_]
        print(f"  worse than the conventional pair: {'yes; note: ' + worse[0] if worse else 'no'}")


if __name__ == "__main__":
    main()
