"""Benchmark (issue 23): ``mrft-ident vehicle`` on one flight with inner and outer tests, as people fly them.

Each flight is drawn fresh by :func:`bench_cascade.draw_spec` (the same generator as the cascade benchmark:
random inner attitude plants and the PD flying them, 100-200 Hz, realistic noise, the inner loop's tests
at beta -0.4 and -0.7, then the outer loop's through the closed inner loop, written in the HEAR layout)
and flown by the cascade simulator (:mod:`mrftcli.sim.cascade`, which shares no code with what it checks).

One command per flight: :func:`mrftcli.vehicle.identify_vehicle` with the bench-test Tp of the inner
plant, the inner PD flown as ``--inner-gains`` and the commanded quantity as ``--outer-command``. Scored:

* **both loops**: the inner loop (roll or pitch) identified and tuned, and the outer loop (y or x)
  identified through the cascade and tuned, from the one call (a refusal, a fallback to eq. (2) or a
  missing design counts as a miss);
* the inner estimate: Td within 5 %, tau within 3 ms of the simulator's plant;
* the outer estimate: Td within 10 %, tau within 3 ms;
* **the gains as they would fly**: the vehicle's new inner PD and its new outer PD loaded together on the
  TRUE cascade (:func:`mrftcli.sim.cascade_plant.outer_phase_margin`, the simulator's exact discrete
  loop): the outer phase margin (-inf when the closed loop is unstable); target >= 35 deg.

Run: ``nice -n 10 python benchmarks/bench_vehicle.py [--n 10] [--seed 100]`` (about 10-20 s of CPU per flight).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench_cascade's flight generator: one implementation

PM_TARGET_DEG = 35.0


@dataclass
class Outcome:
    """One flight's figures (nan / "" where the vehicle refused)."""

    seed: int
    axis: str
    rate_hz: float
    inner_ok: bool = False
    outer_ok: bool = False
    inner_Td_err: float = math.nan
    inner_tau_err_ms: float = math.nan
    outer_Td_err: float = math.nan
    outer_tau_err_ms: float = math.nan
    pm_deg: float = math.nan
    miss: str = ""
    cpu_s: float = 0.0


def _score(spec, res, out: Outcome) -> None:
    """Fill ``out`` from the vehicle result ``res`` of a flight flown from ``spec``."""
    from mrftcli.sim.cascade import command_gain
    from mrftcli.sim.cascade_plant import cascade_plant, outer_phase_margin
    from mrftcli.sim.cascade_spec import InnerGains

    inner_name, outer_name = spec.inner_loop, spec.axis
    inner, outer = res.loops.get(inner_name), res.loops.get(outer_name)
    if inner is not None:
        est = inner.estimates
        out.inner_Td_err = est["Td"][0] / spec.inner.Td - 1.0
        out.inner_tau_err_ms = (est["tau"][0] - spec.inner.tau) * 1e3
        out.inner_ok = inner.gains is not None
    if outer is not None and outer.route == "cascade":
        est = outer.estimates
        out.outer_Td_err = est["Td"][0] / spec.Td - 1.0
        out.outer_tau_err_ms = (est["tau"][0] - spec.tau) * 1e3
        out.outer_ok = outer.gains is not None
    misses = [f"{name}: {m.reason}: {m.message[:120]}" for name, m in res.missing.items()
              if name in (inner_name, outer_name)]
    if outer is not None and outer.route != "cascade":
        misses.append(f"{outer_name}: fell back to eq. (2)")
    out.miss = "; ".join(misses)
    if out.inner_ok and out.outer_ok:
        ci, co = inner.gains.controller, outer.gains.controller
        plant = cascade_plant(spec.inner, spec.Td, spec.tau, spec.rate_hz, spec.g)
        m = outer_phase_margin(plant, InnerGains(ci.Kp, ci.Ki, ci.Kd, ci.Tf, spec.rate_hz),
                               InnerGains(co.Kp, co.Ki, co.Kd, co.Tf, co.rate_hz), command_gain(spec.commanded, spec.g))
        out.pm_deg = m.phase_margin_deg


def run_flight(seed: int, folder: Path) -> Outcome:
    from bench_cascade import draw_spec

    from mrftcli.sim.cascade import simulate_cascade
    from mrftcli.sim.cascade_write import write_cascade
    from mrftcli.mrft.model import soiptd_model
    from mrftcli.vehicle import VehicleOptions, identify_vehicle

    spec = draw_spec(np.random.default_rng(seed), seed)
    out = Outcome(seed, spec.axis, spec.rate_hz)
    bag = folder / f"vehicle_{seed}.bag"
    write_cascade(simulate_cascade(spec), bag, "hear-ros")
    t0 = time.process_time()
    try:
        res = identify_vehicle(bag, soiptd_model(spec.inner.Tp), inner_gains={spec.inner_loop: spec.gains.to_json()},
                               options=VehicleOptions(outer_command=spec.commanded))
        _score(spec, res, out)
    except Exception as err:  # noqa: BLE001 - a refusal is a miss
        out.miss = f"{type(err).__name__}: {err}".splitlines()[0][:200]
    out.cpu_s = time.process_time() - t0
    return out


def _pct(k: int, n: int) -> str:
    return f"{k}/{n} ({100.0 * k / n:.0f} %)" if n else "0/0"


def report(outcomes: list[Outcome]) -> None:
    n = len(outcomes)
    print(f"\n{'seed':>4} {'ax':>2} {'rate':>4} | {'inner Td %':>10} {'tau ms':>6} | {'outer Td %':>10} {'tau ms':>6} | "
          f"{'PM deg':>6} | cpu s")
    for o in outcomes:
        print(f"{o.seed:>4} {o.axis:>2} {o.rate_hz:>4.0f} | {o.inner_Td_err * 100:>10.1f} {o.inner_tau_err_ms:>6.1f} | "
              f"{o.outer_Td_err * 100:>10.1f} {o.outer_tau_err_ms:>6.1f} | {o.pm_deg:>6.1f} | {o.cpu_s:5.1f}")
        if o.miss:
            print(f"      miss: {o.miss}")
    both = sum(o.inner_ok and o.outer_ok for o in outcomes)
    inner_acc = sum(abs(o.inner_Td_err) <= 0.05 and abs(o.inner_tau_err_ms) <= 3.0 for o in outcomes)
    outer_acc = sum(abs(o.outer_Td_err) <= 0.10 and abs(o.outer_tau_err_ms) <= 3.0 for o in outcomes)
    pm = np.array([o.pm_deg for o in outcomes], float)
    print(f"\nflights: {n}; refusals and eq. (2) fallbacks count as misses")
    print(f"both loops identified and tuned from one command: {_pct(both, n)}")
    print(f"inner loop Td within 5 % and tau within 3 ms: {_pct(inner_acc, n)}")
    print(f"outer loop (cascade) Td within 10 % and tau within 3 ms: {_pct(outer_acc, n)}")
    finite = pm[np.isfinite(pm)]
    print(f"the vehicle's new inner and outer PDs together on the true cascade: outer PM >= {PM_TARGET_DEG:g} deg: "
          f"{_pct(int(np.sum(pm >= PM_TARGET_DEG)), n)}; unstable {int(np.sum(pm == -np.inf))}; min "
          f"{np.min(finite) if finite.size else math.nan:.1f} deg, median {np.median(finite) if finite.size else math.nan:.1f} deg")
    cpu = [o.cpu_s for o in outcomes]
    print(f"CPU per flight (identify_vehicle: both loops, both designs): median {np.median(cpu):.1f} s, "
          f"max {np.max(cpu):.1f} s")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=10, help="flights (default 10)")
    parser.add_argument("--seed", type=int, default=100, help="first seed (default 100: flights bench_cascade's "
                                                              "default run does not draw)")
    args = parser.parse_args(argv)
    outcomes = []
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for seed in range(args.seed, args.seed + args.n):
                outcomes.append(run_flight(seed, Path(tmp)))
                o = outcomes[-1]
                print(f"flight {seed}: both {o.inner_ok and o.outer_ok}, outer PM {o.pm_deg:.1f} deg "
                      f"({o.cpu_s:.1f} s){' miss: ' + o.miss if o.miss else ''}", flush=True)
    except KeyboardInterrupt:
        print(f"stopped after {len(outcomes)} of {args.n} flights", flush=True)
    if outcomes:
        report(outcomes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
