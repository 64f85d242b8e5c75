"""Benchmark: should eq. (2)'s own held-out prediction fit the other tests' harmonics? (issue 41)

Each test's frequency predicted from the other tests of its flight, every test flown counted (no prediction,
or a refused log, is a miss), by routes computed in this process on the same logs:

* ``eq2``: what ``analyze LOG --tp TP`` prints today (``analyze.held_out.held_out_eq2``: eq. (2)'s UFM point
  solve of the other tests' mean frequencies; the analysis with 20 bootstrap draws and no waveform
  refinement, which the held-out stage does not use), with its stated std: a miss is "inside the stated
  uncertainty" when |z| <= 2.5;
* ``points_h1``, ``points_h13``, ``points_h135``, ``points_raw`` (scripts/sitl/held_out_routes.py): eq. (2)
  declared, fitted to the other tests' response points as ``analyze --model-file`` does, with the
  fundamentals alone, with the 3rd harmonic, the 3rd and 5th (standard errors floored at 3 %: analyze's
  rule), the 3rd and 5th over their measured scatter alone.

On three sets: ArduPilot SITL campaigns (folders of ``*.BIN`` with their sidecars, ``--sitl``); our simulator
(``mrftcli.sim``: eq. (2) exactly, three betas -0.2/-0.4/-0.6, random plants, 100-400 Hz; ``--sims N`` flights
from ``--seed``); RotorPy (benchmarks/diagnose_sims, clean flights as bench_diagnose_sims draws them: betas
-0.4/-0.7/-0.4, 50-500 Hz, a relay that may lock up; ``--rotorpy N``). Simulated flights are written to
``--work`` with sidecars and reused if there.

    python benchmarks/bench_held_out_harmonics.py --sitl /tmp/mrft41/fresh2 /tmp/mrft41/final /tmp/mrft41/c1 \\
        /tmp/mrft41/c2 --sims 8 --rotorpy 8 --seed 41043 --work /tmp/held_out_harmonics

``--residuals LOG...``: only each test's harmonics against eq. (2) fitted to the fundamentals (gain and phase
beyond it, beside their scatter): why a harmonic helps (roll, pitch) or hurts (EKF3's altitude).

Recorded in docs/benchmarks/sitl.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts" / "sitl"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from held_out_routes import POINT_ROUTES, RouteResult, harmonic_residuals, points_route  # noqa: E402



def eq2_routes(log: Path) -> tuple[RouteResult, list[float | None], RouteResult, list[float | None]]:
    """``analyze --tp``'s held-out errors and their z (the response-point route, ``analyze.held_out_harmonic``),
    then the fundamentals' UFM point solve's (``analyze.held_out.held_out_eq2``, analyze's route before issue
    41's) on the same analysis' tests."""
    from mrftcli.analyze import AnalyzeOptions, analyze_flight
    from mrftcli.analyze.estimate import beta_used
    from mrftcli.analyze.held_out import held_out_eq2
    from mrftcli.analyze.screen import low_rate_period
    from mrftcli.errors import MrftError
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.model import soiptd_model

    side = json.loads(Path(f"{log}.json").read_text())
    flown = len(side["tests"])
    try:
        res = analyze_flight(read_flight(log, ReadOptions(loop=side["loop"]), echo_warnings=False),
                             soiptd_model(side["tp_s"]), options=AnalyzeOptions(n_bootstrap=20, seed=0,
                                                                                 refine_waveform=False))
    except MrftError:
        res = None
    tests = [] if res is None else list(res.tests)
    ufm = [] if res is None else held_out_eq2(soiptd_model(side["tp_s"]), tests, [
        beta_used(t, low_rate_period(tests)) for t in tests], res.parameters_mrft["Td"].value)
    out: list = []
    for held in ([] if res is None else [res.held_out_of(k) for k in range(len(tests))], ufm):
        errors: list[float | None] = []
        zs: list[float | None] = []
        for ho, t in zip(held, tests):
            ok = ho is not None and ho.frequency_hz is not None
            errors.append(ho.frequency_hz / t.frequency_hz_mean - 1.0 if ok else None)
            zs.append(ho.frequency_z if ok else None)
        pad = [None] * (flown - len(errors))
        out += [RouteResult(flown, tuple(errors + pad)), zs + pad]
    return out[0], out[1], out[2], out[3]


def simulate_ours(work: Path, n: int, seed: int) -> list[Path]:
    """``n`` three-beta flights of our simulator (eq. (2) exactly), altitude and roll alternately."""
    from mrftcli.mrft.model import LoopModel
    from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight, write_flight

    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        loop = ("altitude", "roll")[k % 2]
        Tp = float(rng.uniform(0.02, 0.06))
        Td = float(rng.uniform(1.0, 4.0) if loop == "altitude" else rng.uniform(0.4, 1.5))
        tau, K, rate = float(rng.uniform(0.005, 0.05)), float(rng.uniform(10, 30)), float(rng.choice([100.0, 200, 400]))
        path = work / f"ours{k:02d}_{loop}.mcap"
        flight_seed = int(rng.integers(1 << 30))
        if not path.exists():
            model = LoopModel(Tp, Td, tau, K)
            tests = tuple(plan_test(model, b, 0.03, rate, cycles=10) for b in (-0.2, -0.4, -0.6))
            write_flight(simulate_flight(FlightSpec(model=model, tests=tests, loop=loop, rate_hz=rate,
                                                    seed=flight_seed)), path, "mcap")
            Path(f"{path}.json").write_text(json.dumps({"tp_s": Tp, "loop": loop, "tests": [
                {"beta": t.beta, "h": t.h} for t in tests], "truth": {"Td": Td, "tau": tau, "K": K, "rate_hz": rate}}))
        out.append(path)
    return out


def simulate_rotorpy(work: Path, n: int, seed: int) -> list[Path]:
    """``n`` clean RotorPy flights as bench_diagnose_sims draws them (its platforms, rates, noise, relay)."""
    from diagnose_sims.cases import build, draw_case
    from diagnose_sims.loop import flight_topics, fly

    from mrftcli.io import write_log

    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        case = draw_case(rng, "rotorpy", None)
        path = work / f"rotorpy{k:02d}_{case['platform']}.mcap"
        if not path.exists():
            vehicle, spec, Tp, _ = build(case)
            rec = fly(vehicle, spec)
            write_log(flight_topics(rec, [b for b, _, _ in spec.tests]), path, "mcap")
            Path(f"{path}.json").write_text(json.dumps({"tp_s": Tp, "loop": "altitude", "tests": [
                {"beta": b, "h": h} for b, h, _ in spec.tests], "locked_up": [bool(a) for a in rec.aborted],
                "rate_hz": case["rate"], "seed": case["seed"]}))
        out.append(path)
    return out


def _kind(log: Path) -> str:
    name = log.stem
    if log.suffix == ".ulg":
        loop = json.loads(Path(f"{log}.json").read_text())["loop"]
        return f"PX4 {loop}" + (" +20 ms" if "20ms" in name else "")
    if name.startswith(("ours", "rotorpy")):
        return name.split("0")[0].rstrip("0123456789")
    if name.startswith("altitude"):
        return "SITL altitude +20 ms" if "20ms" in name else "SITL altitude"
    tests = json.loads(Path(f"{log}.json").read_text())["tests"]
    longest = max(t.get("duration_s", 0.0) for t in tests)
    return "SITL roll, pitch" + (f" ({longest:g} s tests)" if longest > 6.0 else "")


def _summary(name: str, results: list[RouteResult], zs: list[float | None] | None) -> str:
    errs = [e for r in results for e in r.errors]
    n, hits = len(errs), sum(e is not None and abs(e) <= 0.05 for e in errs)
    got = [abs(e) for e in errs if e is not None]
    med = f"median |error| {np.median(got) * 100:.1f} %, max {max(got) * 100:.1f} %" if got else "no prediction"
    text = f"{name:12s} {hits:3d}/{n:<3d} within 5 %; {med}"
    if zs is not None:
        stated = [abs(z) for z in zs if z is not None]
        misses = [z for e, z in zip(errs, zs) if not (e is not None and abs(e) <= 0.05)]
        inside = sum(z is not None and abs(z) <= 2.5 for z in misses)
        text += (f"; misses inside 2.5 stated std {inside}/{len(misses)}; calibration: |z| <= 2 in "
                 f"{sum(z <= 2 for z in stated)}/{len(stated)} predictions, <= 1 in {sum(z <= 1 for z in stated)}")
    return text


def _zs(route: str, kinds: list[str], zs_kind: dict[str, list[float | None]]) -> list[float | None] | None:
    if route not in ("eq2", "eq2_ufm"):
        return None
    return [z for k in kinds for z in zs_kind[k + (" ufm" if route == "eq2_ufm" else "")]]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sitl", type=Path, nargs="*", default=[],
                    help="folders of SITL logs with their sidecars (ArduPilot *.BIN, PX4 *.ulg)")
    ap.add_argument("--sims", type=int, default=8, help="flights of our simulator")
    ap.add_argument("--rotorpy", type=int, default=8, help="clean RotorPy flights")
    ap.add_argument("--seed", type=int, default=41043, help="seed of the simulated flights' draws")
    ap.add_argument("--work", type=Path, default=Path("/tmp/held_out_harmonics"), help="folder of the simulated flights")
    ap.add_argument("--residuals", type=Path, nargs="*", default=[],
                    help="only: these logs' harmonics against eq. (2) fitted to the fundamentals (why a harmonic "
                         "helps or hurts)")
    ap.add_argument("--points", nargs="*", choices=tuple(POINT_ROUTES), default=list(POINT_ROUTES),
                    help="the declared-model response-point routes to run beside analyze's (default all; none: "
                         "analyze's route and the fundamentals' alone)")
    args = ap.parse_args()
    routes = tuple(args.points)
    if args.residuals:
        for log in args.residuals:
            print(f"{log}: eq. (2) fitted to every test's fundamental; what each point adds beyond it")
            print("\n".join(f"  {line}" for line in harmonic_residuals(log)))
        return 0
    args.work.mkdir(parents=True, exist_ok=True)
    logs = [log for d in args.sitl for log in sorted([*d.glob("*.BIN"), *d.glob("*.ulg")])
            if Path(f"{log}.json").exists()]
    logs += simulate_ours(args.work, args.sims, args.seed) + simulate_rotorpy(args.work, args.rotorpy, args.seed + 1)
    by_kind: dict[str, dict[str, list[RouteResult]]] = {}
    zs_kind: dict[str, list[float | None]] = {}
    for log in logs:
        kind = _kind(log)
        res, zs, ufm, zs_ufm = eq2_routes(log)
        rows = {"eq2": res, "eq2_ufm": ufm, **{r: points_route(log, r) for r in routes}}
        zs_kind.setdefault(kind, []).extend(zs)
        zs_kind.setdefault(kind + " ufm", []).extend(zs_ufm)
        for route, r in rows.items():
            by_kind.setdefault(kind, {}).setdefault(route, []).append(r)
            cells = " ".join("  none" if e is None else f"{e * 100:+6.1f}" for e in r.errors)
            print(f"  {log.parent.name:>8s}/{log.stem:20s} {route:12s} {cells}", flush=True)
    print("\nheld out within 5 % of the measured frequency, every test flown (no prediction is a miss)")
    for kind, by_route in by_kind.items():
        print(f"{kind}:")
        for route in ("eq2", "eq2_ufm", *routes):
            print("  " + _summary(route, by_route[route], _zs(route, [kind], zs_kind)))
    sitl = [k for k in by_kind if k.startswith("SITL") and "s tests)" not in k]
    if sitl:
        print("SITL, all (the 6 s roll and pitch tests, altitude 12 s):")
        for route in ("eq2", "eq2_ufm", *routes):
            print("  " + _summary(route, [r for k in sitl for r in by_kind[k][route]], _zs(route, sitl, zs_kind)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
