"""Benchmark: ``mrft-ident tune``'s designs on the paper's platforms and on random identified plants.

1. The paper's two platforms (checks.md Table III: Design I and II, roll and altitude; Td and tau
   with the reported standard deviations as the posterior, K = 1: the gains scale as 1 / K and the
   margins do not depend on it), controller at 200 Hz.
2. ``--plants`` random plants of the identification sweep (``tests/test_analyze_sweep.py``'s
   generator with a fresh ``--seed``): each flown with the project's simulator (two MRFT tests,
   200 Hz, sensor noise) and identified by ``analyze_flight``; the posterior is its bootstrap.

For every plant (PD and PID designed, as the CLI does; CPU time of that call): the robust PD's worst-case phase margin over the 95 % set (target >= 35 deg) and
its delay margin; the predicted step response (the design's z-domain loop) against the
event-driven time-domain simulation of the sampled loop (overshoot within 2 points, settling within
10 %); and the model-based PD against the MRFT-rule baseline at equal or better Ms (the model-based
design re-run with Ms <= the rule's Ms and the rule's noise gain; target: better criterion on >= 18/20).
The robust PID (setpoint + load-step criterion, Ti free): worst PM, overshoot, settling and load recovery.

Run: ``python benchmarks/bench_tune.py [--plants 20] [--seed 14]`` (about 15 minutes on 2 busy cores;
``--quick``: 4 plants).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

TABLE_III = [  # platform, loop, Tp, Td mean, Td std, tau mean, tau std (checks.md section 4)
    ("Design I", "roll", 0.0422, 1.301, 0.8395, 0.0297, 0.0042),
    ("Design I", "altitude", 0.0422, 2.669, 0.6612, 0.0464, 0.0012),
    ("Design II", "roll", 0.0499, 0.887, 0.4574, 0.0228, 0.0053),
    ("Design II", "altitude", 0.0499, 1.8345, 0.1754, 0.0498, 0.0017),
]


def _check(name, model, post, rate, out):
    from mrftcli.tune import DesignOptions, simulate_step, step_metrics, tune

    t0 = time.perf_counter()
    c0 = time.process_time()
    res = tune(model, rate, posterior=post, options=DesignOptions(kinds=("PD", "PID")))
    cpu = time.process_time() - c0
    rule, mb, rob = (res.get(n, "PD") for n in ("mrft-rule", "model-based", "robust"))
    pid = res.get("robust", "PID")
    # predicted (z-domain matrices) vs simulated (event-driven continuous plant) step
    tt, y, u, _ = simulate_step(model, rob.controller, res.horizon_s, substeps=1)
    sim = step_metrics(tt, y, u)
    d_os = sim.overshoot_pct - rob.step.overshoot_pct
    d_st = (sim.settling_s / rob.step.settling_s - 1) * 100 if math.isfinite(rob.step.settling_s) else math.nan
    # model-based vs the rule at the rule's Ms (equal or better Ms) and noise gain
    eq = tune(model, rate, options=DesignOptions(objective=res.objective, ms_max=max(rule.margins.Ms, 1.01),
                                                 designs=("model-based",), kinds=("PD",))).get("model-based", "PD")
    w = rob.posterior["worst"]
    row = dict(name=name, pm_worst=w["phase_margin_deg"], ms_worst=w["Ms"], dm=rob.margins.delay_margin_s * 1e3,
               dm_worst=w["delay_margin_ms"], os_pred=rob.step.overshoot_pct, os_sim=sim.overshoot_pct, d_os=d_os,
               st_pred=rob.step.settling_s, d_st=d_st, rule_J=rule.criterion, rule_Ms=rule.margins.Ms,
               eq_J=eq.criterion, eq_Ms=eq.margins.Ms, mb_J=mb.criterion, mb_Ms=mb.margins.Ms,
               beats=bool(eq.criterion < rule.criterion and eq.margins.Ms <= rule.margins.Ms * 1.001),
               secs=time.perf_counter() - t0, cpu=cpu, pid_pm=pid.posterior["worst"]["phase_margin_deg"],
               pid_os=pid.step.overshoot_pct, pid_ts=pid.step.settling_s, pid_rec=pid.load["recovery_s"])
    out.append(row)
    print(f"{name:<26} {row['pm_worst']:>6.1f} {row['ms_worst']:>5.2f} {row['dm']:>7.1f} {row['dm_worst']:>7.1f} "
          f"{row['os_pred']:>6.2f} {row['os_sim']:>6.2f} {row['st_pred']:>6.3f} {row['d_st']:>+7.3f} "
          f"{row['rule_J']:>8.4g} {row['rule_Ms']:>6.2f} {row['eq_J']:>8.4g} {row['eq_Ms']:>6.2f} "
          f"{'yes' if row['beats'] else 'NO':>5} {row['secs']:>5.0f} {row['cpu']:>5.1f} | {row['pid_pm']:>5.1f} "
          f"{row['pid_os']:>5.1f} {row['pid_ts']:>6.2f} {row['pid_rec']:>6.2f}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", type=int, default=20)
    ap.add_argument("--seed", type=int, default=14, help="seed of the random plants (fresh: not the sweep's 0)")
    ap.add_argument("--quick", action="store_true", help="4 random plants")
    args = ap.parse_args()
    n_plants = 4 if args.quick else args.plants
    sys.path.insert(0, str(ROOT / "tests"))
    from test_analyze_sweep import sweep_plants
    from test_segment_support import flight_from_simulated, simulate_paper_flight

    from mrftcli.analyze import analyze_flight
    from mrftcli.mrft.model import LoopModel, soiptd_model
    from mrftcli.tune import Posterior

    print(f"{'plant':<26} {'PMwst':>6} {'Mswst':>5} {'DM[ms]':>7} {'DMwst':>7} {'OSpred':>6} {'OSsim':>6} "
          f"{'ts[s]':>6} {'dts[%]':>7} {'rule J':>8} {'ruleMs':>6} {'mb J':>8} {'mb Ms':>6} {'beat':>5} {'[s]':>5} "
          f"{'cpu':>5} | {'PIDPM':>5} {'PIDOS':>5} {'PIDts':>6} {'PIDrec':>6}")
    rows_t3, rows_rand = [], []
    for plat, loop, Tp, Td, Td_s, tau, tau_s in TABLE_III:
        model = LoopModel(Tp, Td, tau, 1.0)
        post = Posterior.from_spread(model, Td_s, tau_s, 0.0, n=200, seed=1,
                                     source="Table III mean and std (log-normal)")
        _check(f"{plat} {loop}", model, post, 200.0, rows_t3)
    for k, loop, Tp, Td, tau, K in sweep_plants(n_plants, seed=args.seed):
        betas = (-0.4, -0.7) if loop == "altitude" else (-0.5, -0.8)
        sf = simulate_paper_flight(Tp, Td, tau, K, betas, loop=loop, cycles=12.0, seed=1000 + k)
        try:
            r = analyze_flight(flight_from_simulated(sf), soiptd_model(Tp))
        except Exception as err:  # noqa: BLE001 - a benchmark reports and goes on
            print(f"plant {k}: analysis failed: {err}")
            continue
        post = Posterior(r.model, r.bootstrap["Td"], r.bootstrap["tau"], r.bootstrap["K"], source="bootstrap")
        _check(f"plant {k} {loop} Td {Td:.2f} tau {tau * 1e3:.0f}ms", r.model, post, 200.0, rows_rand)
    for label, rows in (("Table III platforms", rows_t3), (f"random plants (seed {args.seed})", rows_rand)):
        if not rows:
            continue
        pm = np.array([r["pm_worst"] for r in rows])
        d_os = np.array([r["d_os"] for r in rows])
        d_st = np.array([r["d_st"] for r in rows])
        beats = sum(r["beats"] for r in rows)
        print(f"{label}: robust worst-case PM >= 35 deg on {int(np.sum(pm >= 35))}/{len(rows)} (min {pm.min():.1f}); "
              f"delay margin {min(r['dm'] for r in rows):.0f}-{max(r['dm'] for r in rows):.0f} ms; "
              f"|overshoot sim - pred| max {np.nanmax(np.abs(d_os)):.2e} pp; |settling| max {np.nanmax(np.abs(d_st)):.2e} %; "
              f"model-based beats the MRFT rule at equal or better Ms on {beats}/{len(rows)} "
              f"(median criterion ratio {np.median([r['eq_J'] / r['rule_J'] for r in rows]):.3f}); "
              f"tune (PD + PID, all designs) CPU median {np.median([r['cpu'] for r in rows]):.1f} s; robust PID: worst "
              f"PM >= 35 deg on {sum(r['pid_pm'] >= 35 for r in rows)}/{len(rows)}, settled within 12 T0 on "
              f"{sum(np.isfinite(r['pid_ts']) for r in rows)}/{len(rows)}, load recovered on "
              f"{sum(np.isfinite(r['pid_rec']) for r in rows)}/{len(rows)}, overshoot median "
              f"{np.median([r['pid_os'] for r in rows]):.0f} %")


if __name__ == "__main__":
    main()
