#!/usr/bin/env python
"""diagnose's CPU against analyze's on the same logs, kept on disk so two code trees compare on the same
flights (issue 39: the median and the worst ratio, and whether the diagnosis changed).

Two steps:

``--fly DIR --sim S --seed N`` flies the simulator benchmark's draw (``diagnose_sims.cases``: one flight
per effect and ``--clean`` clean ones) once and writes each as MCAP with a JSON sidecar (its draw and Tp).

``--logs DIR`` runs, per log, analyze and then diagnose reusing its record (or its refusal) on one read
of the log, as ``mrft-ident diagnose`` does (``diagnose_sims.cases.analyze_then_diagnose``, the CLI's last
step included; BLAS single-threaded: ``mrftcli.cli`` is imported first), and
prints each log's CPU (``time.process_time``), the ratio, the names found and a hash of the diagnosis'
JSON; then the median and the worst ratio (all logs, and the logs analyze identified). ``--json OUT``
keeps the rows. Run it under two trees (``PYTHONPATH=TREE``) and compare the hashes and ratios.

Usage::

    nice -n 10 python benchmarks/bench_diagnose_cpu.py --fly /tmp/logs --sim jsbsim --seed 7391
    PYTHONPATH=/tmp/before python benchmarks/bench_diagnose_cpu.py --logs /tmp/logs --json before.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import mrftcli.cli  # noqa: F401 - BLAS single-threaded before numpy is loaded, as mrft-ident runs

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def fly(out: Path, sim: str, seed: int, per_effect: int, clean: int) -> None:
    """Fly the draw once: MCAP + JSON sidecar per flight."""
    from diagnose_sims.cases import EFFECTS, build, draw_case
    from diagnose_sims.loop import flight_topics
    from diagnose_sims.loop import fly as fly_loop
    from mrftcli.io import write_log

    rng = np.random.default_rng(seed)
    cases = [draw_case(rng, sim, e) for e in EFFECTS for _ in range(per_effect)]
    cases += [draw_case(rng, sim, None) for _ in range(clean)]
    out.mkdir(parents=True, exist_ok=True)
    for i, case in enumerate(cases):
        vehicle, spec, Tp, truth = build(case)
        rec = fly_loop(vehicle, spec)
        name = f"{sim}_{seed}_{i:02d}_{case['effect']}"
        write_log(flight_topics(rec, [b for b, _, _ in spec.tests]), out / f"{name}.mcap", "mcap")
        (out / f"{name}.json").write_text(json.dumps({**case, "Tp": Tp, "truth": truth}))
        print(name, flush=True)


def measure(log: Path) -> dict:
    """analyze, then diagnose reusing its record, on one read of ``log``: CPU [s], names, JSON hash."""
    from diagnose_sims.cases import analyze_then_diagnose

    run = analyze_then_diagnose(log, json.loads(log.with_suffix(".json").read_text())["Tp"])
    res, cpu_a, cpu_d = run.res, run.cpu_analyze, run.cpu
    row = {"log": log.stem, "analysed": run.analysis is not None, "cpu_analyze": cpu_a, "cpu_diagnose": cpu_d,
           "ratio": cpu_d / max(cpu_a, 1e-3), "error": run.error and run.error.split(":", 1)[0], "found": None, "json_sha": None}
    if res is not None:
        text = json.dumps(res.to_json(), sort_keys=True, default=str)
        row.update(found=[e.name for e in res.effects], json_sha=hashlib.sha1(text.encode()).hexdigest()[:12])
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fly", type=Path, default=None, help="fly the draw into this directory")
    ap.add_argument("--sim", choices=("rotorpy", "jsbsim"), default="jsbsim")
    ap.add_argument("--seed", type=int, default=7391, help="master seed of the draw (a dev seed)")
    ap.add_argument("--per-effect", type=int, default=1)
    ap.add_argument("--clean", type=int, default=1)
    ap.add_argument("--logs", type=Path, default=None, help="measure every MCAP of this directory")
    ap.add_argument("--json", type=Path, default=None, help="write the rows here")
    args = ap.parse_args()
    if args.fly is not None:
        fly(args.fly, args.sim, args.seed, args.per_effect, args.clean)
    if args.logs is None:
        return
    rows = []
    for log in sorted(args.logs.glob("*.mcap")):
        r = measure(log)
        rows.append(r)
        print(f"{r['log']}: analyze {r['cpu_analyze']:.2f} s ({'identified' if r['analysed'] else 'refused'}), "
              f"diagnose {r['cpu_diagnose']:.2f} s = {r['ratio']:.2f}x; found {r['found']} {r['error'] or ''} "
              f"json {r['json_sha']}", flush=True)
    for sim in sorted({r["log"].split("_")[0] for r in rows}):
        rs = [r for r in rows if r["log"].startswith(sim)]
        ratio = np.array([r["ratio"] for r in rs])
        ok = np.array([r["analysed"] for r in rs])
        line = f"{sim}: {len(rs)} logs, diagnose / analyze CPU per log median {np.median(ratio):.2f}x, worst {ratio.max():.2f}x"
        if ok.any():
            line += f"; on the {int(ok.sum())} analyze identified: median {np.median(ratio[ok]):.2f}x, worst {ratio[ok].max():.2f}x"
        print(line)
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
