"""Benchmark (issue 30): ``tune`` at long delays, 1 to 200 controller ticks.

The issue's lateral loop (Tp 0.08 s, Td 3.205 s, K 0.98, 200 Hz) with its delay set to a given number
of ticks plus 0.2 of a tick (the flight's 451 ms is 90.2 ticks), a posterior of 200 log-normal draws
(Td 10 %, tau 2 %, K 5 %), and every design as the CLI makes them (MRFT rule, model-based, robust;
PD and PID). Each delay runs in a fresh process, which reports:

* the CPU and wall time of :func:`mrftcli.tune.design.tune` and the process's peak resident memory
  (``ru_maxrss``; the same figure after the imports is given for reference);
* every design's nominal gain and phase margins and Ms against an independent computation that
  shares no code with ``mrftcli.tune``: the loop's frequency response written here from the
  controller's difference equations and the zero-order-hold plant as the Poisson sum of
  G(j w_k) (1 - e^{-j w_k T}) / (j w_k T) with the exact delay e^{-j w_k tau}, crossings found on a
  dense grid and refined with ``brentq`` (targets: 0.5 deg and 1 %).

Run: ``python benchmarks/bench_tune_delay.py`` (all delays; about 3 minutes of CPU) or ``--quick``
(1, 10, 90, 200 ticks). ``--ticks 90.2`` runs given delays.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RATE = 200.0
DELAYS = (1.2, 2.2, 5.2, 10.2, 20.2, 40.2, 90.2, 140.2, 200.2)
QUICK = (1.2, 10.2, 90.2, 200.2)


def oracle_loop(Tp: float, Td: float, tau: float, K: float, c, w, n_alias: int = 400) -> np.ndarray:
    """L(e^{jwT}) from scratch (module docstring): controller difference equations x Poisson-sum ZOH plant."""
    T = 1.0 / RATE
    w = np.atleast_1d(np.asarray(w, float))
    Gd = np.empty(w.size, complex)
    for i in range(0, w.size, 500):  # in chunks: 500 x 801 terms at a time
        s = 1j * (w[i:i + 500, None] + 2 * np.pi * np.arange(-n_alias, n_alias + 1)[None, :] / T)
        G = K * Td * np.exp(-tau * s) / (s * (Tp * s + 1) * (Td * s + 1))
        Gd[i:i + 500] = np.sum(G * (1 - np.exp(-s * T)) / (s * T), axis=1)
    z = np.exp(1j * w * T)
    C = c.Kp + c.Ki * T * z / (z - 1) + c.Kd * (z - 1) / ((c.Tf + T) * z - c.Tf)
    return C * Gd


def oracle_margins(params: tuple[float, float, float, float], c) -> tuple[float, float, float]:
    """(PM [deg] of smallest |PM|, GM closest to 1, Ms): python-control's choice, on the oracle loop."""
    from scipy.optimize import brentq, minimize_scalar

    w_nyq = math.pi * RATE
    # log-spaced, and linear fine enough for the delay's phase (at most 0.2 rad per step up to 1.2 s)
    w = np.union1d(np.geomspace(w_nyq * 1e-5, w_nyq * 0.999, 3000), np.linspace(w_nyq / 3200, w_nyq * 0.999, 3200))
    L = oracle_loop(*params, c, w)

    def at(x: float) -> complex:
        return complex(oracle_loop(*params, c, x)[0])

    lm = np.log(np.abs(L))
    pms = []
    for i in np.nonzero(np.sign(lm[:-1]) != np.sign(lm[1:]))[0]:
        x = brentq(lambda v: math.log(abs(at(v))), w[i], w[i + 1], xtol=1e-14)
        pms.append(float(np.remainder(np.degrees(np.angle(at(x))), 360) - 180))
    gms = []
    for i in np.nonzero(np.sign(L.imag[:-1]) != np.sign(L.imag[1:]))[0]:
        Lx = at(brentq(lambda v: at(v).imag, w[i], w[i + 1], xtol=1e-14))
        if Lx.real < 0:
            gms.append(1 / abs(Lx))
    k = int(np.argmin(np.abs(1 + L)))
    r = minimize_scalar(lambda v: abs(1 + at(v)), bracket=(w[k - 1], w[k], w[k + 1]))
    pm = min(pms, key=abs) if pms else math.inf
    gm = min(gms, key=lambda g: abs(math.log(g))) if gms else math.inf
    return pm, gm, 1 / min(float(r.fun), float(np.min(np.abs(1 + L))))


def child(ticks: float) -> dict:
    """One delay, in this process: tune's cost and its margins against the oracle."""
    from mrftcli.mrft.model import LoopModel
    from mrftcli.tune.design import Posterior, tune

    rss_imports = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    model = LoopModel(0.08, 3.205, ticks / RATE, 0.98)
    post = Posterior.from_spread(model, 0.1 * model.Td, 0.02 * model.tau, 0.05 * model.K, n=200, seed=0)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    res = tune(model, RATE, posterior=post, loop="y")
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    params = (model.Tp, model.Td, model.tau, model.K)
    rows = []
    for d in res.designs:
        pm, gm, Ms = oracle_margins(params, d.controller)
        g = d.margins
        rows.append({"design": d.name, "kind": d.kind, "pm": g.phase_margin_deg, "pm_oracle": pm,
                     "gm": g.gain_margin, "gm_oracle": gm, "Ms": g.Ms, "Ms_oracle": Ms, "dm_ms": g.delay_margin_s * 1e3,
                     "stable": g.stable, "pm_worst": d.posterior.get("worst", {}).get("phase_margin_deg")})
    return {"ticks": ticks, "cpu_s": cpu, "wall_s": wall, "rss_mb": rss, "rss_imports_mb": rss_imports, "designs": rows}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="1, 10, 90 and 200 ticks only")
    ap.add_argument("--ticks", type=float, nargs="*", help="delays [ticks] to run")
    ap.add_argument("--child", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        print(json.dumps(child(args.child)))
        return 0
    delays = args.ticks or (QUICK if args.quick else DELAYS)
    print(f"load average at start: {os.getloadavg()[0]:.1f} (2 cores)")
    print(f"{'ticks':>6} {'tau[ms]':>8} {'CPU[s]':>7} {'wall[s]':>8} {'peak MB':>8} {'(imports)':>9}  "
          f"{'max |dPM| deg':>13} {'max dGM %':>10} {'max dMs %':>10}  model-based PD: PM  GM   DM[ms]")
    worst = [0.0, 0.0, 0.0]
    for ticks in delays:
        out = subprocess.run([sys.executable, __file__, "--child", str(ticks)], capture_output=True, text=True,
                             cwd=ROOT, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        dpm = max(abs(x["pm"] - x["pm_oracle"]) for x in r["designs"])
        dgm = max(abs(x["gm"] / x["gm_oracle"] - 1) for x in r["designs"]) * 100
        dms = max(abs(x["Ms"] / x["Ms_oracle"] - 1) for x in r["designs"]) * 100
        worst = [max(worst[0], dpm), max(worst[1], dgm), max(worst[2], dms)]
        mb = next(x for x in r["designs"] if x["design"] == "model-based" and x["kind"] == "PD")
        print(f"{ticks:>6g} {ticks / RATE * 1e3:>8.1f} {r['cpu_s']:>7.2f} {r['wall_s']:>8.2f} {r['rss_mb']:>8.0f} "
              f"{r['rss_imports_mb']:>9.0f}  {dpm:>13.2e} {dgm:>10.2e} {dms:>10.2e}  "
              f"{mb['pm']:>18.2f} {mb['gm']:>4.2f} {mb['dm_ms']:>7.1f}", flush=True)
    print(f"largest differences from the independent response: PM {worst[0]:.2e} deg, GM {worst[1]:.2e} %, "
          f"Ms {worst[2]:.2e} % (targets 0.5 deg, 1 %, 1 %)")
    print(f"load average at end: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
