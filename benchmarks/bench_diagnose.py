#!/usr/bin/env python
"""Benchmark of ``mrft-ident diagnose`` on flights drawn as users fly them (issue 27; new seeds every run).

Every log is an altitude flight of one of the paper's two platforms with three MRFT tests: beta
-0.4 and -0.7 at one planned amplitude (5-10 cm), then beta -0.4 at **twice** the first test's relay
height. Each test lasts 10-14 s (about 5-8 stable cycles); the controller runs at 100, 150, 200 or
250 Hz and the sensor noise is 0.5-1 mm. Nothing is chosen to suit the tool: no flight is flown
again and none is dropped, a test whose relay locks up in the air stays in the log (counted), a
test whose larger relay height drives the actuator into its limit stays in the log, and a refusal
(an MrftError: the tool declined the log) counts as a miss wherever it happens.

Drawn per log: platform, simulator seed, the effect's realistic magnitude times a factor in
[0.7, 1.3] (``scripts/make_concealed_logs.effect_value``; a delay jitter of 6 ms std times that
factor, as the issue's flights had), test durations, rate, noise, amplitude.
The effects: the ten of the library (``--per-effect`` logs each), a flexible sensor mount outside
the library (``--outside`` logs: a mode of 2-15 Hz, damping 0.02-0.1, between the airframe and the
sensor, its frequency drawn as it is, with no magnitude factor; ``unexplained`` expected, or the
resonance named; each printed with its oracle SNR, :func:`mount_snr`), and ``--clean`` clean controls.
Library and clean flights called a resonance are counted.

Printed, with the issue's targets: right effect named (>= 90 %), clean kept clean (>= 90 %), no
spurious second effect among the named (>= 90 %), out-of-library flights answered ``unexplained``
(>= 80 %), held-out NRMSE halved on the named (>= 80 %), and the commands' CPU on the same flights
(both timed in the same process): ``mrft-ident diagnose`` (read + analyze + the diagnosis) over
``mrft-ident analyze`` (read + analyze) per log, against issue 39's <= 1.5x median and issue 27's
<= 2x, each with met / not met. The diagnosis stage's own ratio (beyond analyze's record, over
analyze) is printed beside it, unlabelled. ``--pairs N`` adds N logs with two effects.

Usage::

    nice -n 10 python benchmarks/bench_diagnose.py [--per-effect 3] [--outside 3] [--clean 5] [--jobs 1] [--seed N]
    nice -n 10 python benchmarks/bench_diagnose.py --lookalikes
    # a run's cases of some kinds again: the same --seed, --per-effect, --outside, --clean, --pairs
    nice -n 10 python benchmarks/bench_diagnose.py --per-effect 3 --outside 10 --clean 5 --seed N --only delay_jitter,dead_zone
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import mrftcli.cli  # noqa: F401 - BLAS single-threaded as the command line runs it (set before numpy loads)
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PARAM = {"input_bias": "d", "gain_drift": "g", "sensor_lag": "T_lag", "quadratic_drag": "c",
         "actuator_rate_limit": "R", "delay_jitter": "sigma", "asymmetric_gain": "a", "actuator_saturation": "U_max",
         "dead_zone": "delta", "thrust_rectification": "F"}
RATES = (100.0, 150.0, 200.0, 250.0)
OUTSIDE = "flex_mode_hz"


def _gen_module():
    spec = importlib.util.spec_from_file_location("make_concealed_logs", ROOT / "scripts" / "make_concealed_logs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


#: flights of make_concealed_logs' generator on which look-alike pairs were once confused (plant, seed,
#: scales, cycles, rate [Hz], noise [m], amplitude [m]); ``--lookalikes`` diagnoses them with the whole
#: library, tests/test_diagnose.py with the pair and its look-alikes only
LOOKALIKE_FLIGHTS = {
    "quadratic_drag+thrust_rectification": ("design1", 1009683405, (1.124, 1.236), 10.3, 100.0, 0.000543, 0.06),
    "asymmetric_gain+actuator_saturation": ("design1", 328522801, (1.072, 0.980), 10.1, 100.0, 0.000823, 0.0632),
    "quadratic_drag+actuator_rate_limit": ("design1", 780730297, (0.974, 0.812), 14.0, 500.0, 0.000239, 0.0956),
    # the asymmetric gain alone explains the held-out cycles: the rectification is found by its probe
    "asymmetric_gain+thrust_rectification": ("design2", 771996162, (1.1004, 0.8806), 14.697, 200.0, 0.00031061, 0.06),
    # the saturation's fit ends where a warm-started limit cycle is lost: the cold start finds it
    "actuator_saturation+thrust_rectification": ("design2", 278146007, (1.1337, 0.8596), 9.6206, 500.0, 0.00021352,
                                                 0.088797),
    # the pair's nested start, its limit cycle solved from a distant start's, scored chi^2 9e4 for 2e3
    "input_bias+asymmetric_gain": ("design1", 234561604, (1.16095004, 1.13798917), 10.17517291, 250.0, 0.000371202054,
                                   0.0955844208),
}


def fly_lookalike(pair: str):
    """The SimulatedFlight of :data:`LOOKALIKE_FLIGHTS`' ``pair``."""
    plant, seed, scale, cycles, rate, noise, amplitude = LOOKALIKE_FLIGHTS[pair]
    return _gen_module().make_case(pair, plant, seed, scale, cycles=cycles, rate_hz=rate, noise_std=noise,
                                   amplitude=amplitude)


def flight_log(flight):
    """A SimulatedFlight written as MCAP and read back as the tool reads a log (the altitude loop)."""
    from mrftcli.io import ReadOptions, read_flight, write_log

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "flight.mcap"
        write_log(flight.topics, path, "mcap")
        return read_flight(path, ReadOptions(loop="altitude"))


def run_lookalikes() -> None:
    """Each look-alike flight diagnosed with the whole library: both effects named and nothing else."""
    from mrftcli.diagnose.selection import diagnose
    from mrftcli.mrft.model import soiptd_model

    ok = 0
    for pair in LOOKALIKE_FLIGHTS:
        flight = fly_lookalike(pair)
        t0 = time.process_time()
        res = diagnose(flight_log(flight), soiptd_model(flight.truth["Tp"]))
        found = sorted(e.name for e in res.effects)
        ok += found == sorted(pair.split("+"))
        print(f"{pair:<42} found {found} ({time.process_time() - t0:.1f} s CPU)", flush=True)
    print(f"look-alike pairs named exactly: {_pct(ok, len(LOOKALIKE_FLIGHTS))}")


def draw_case(rng: np.random.Generator, effect: str | None, plants: list[str]) -> dict:
    """One flight as a user flies it: platform, rate, noise, amplitude, durations, magnitudes."""
    names = [] if effect is None else effect.split("+")
    return {"effect": effect, "plant": str(rng.choice(plants)), "seed": int(rng.integers(1 << 30)),
            "scales": tuple(float(rng.uniform(0.7, 1.3)) for _ in names),
            "rate": float(rng.choice(RATES)), "noise": float(rng.uniform(0.0005, 0.001)),
            "amplitude": float(rng.uniform(0.05, 0.10)), "durations": tuple(float(rng.uniform(10.0, 14.0)) for _ in range(3)),
            "flex_hz": float(rng.uniform(2.0, 15.0)), "flex_damping": float(rng.uniform(0.02, 0.1))}


def fly(case: dict):
    """Simulate the drawn flight (never re-flown) and return the SimulatedFlight."""
    from mrftcli.sim.flight import Effects, FlightSpec, TestSpec, plan_test, simulate_flight

    gen = _gen_module()
    model = gen.PLANTS[case["plant"]]
    d1, d2, d3 = case["durations"]
    t1 = replace(plan_test(model, -0.4, case["amplitude"], case["rate"]), duration=round(d1, 1))
    t2 = replace(plan_test(model, -0.7, case["amplitude"], case["rate"]), duration=round(d2, 1))
    tests = (t1, t2, TestSpec(-0.4, 2.0 * t1.h, round(d3, 1)))
    effects = Effects()
    names = [] if case["effect"] is None else case["effect"].split("+")
    for name, sc in zip(names, case["scales"]):
        if name == OUTSIDE:
            # the mount's frequency is drawn in the issue's 2-15 Hz as it is (no magnitude factor on it)
            effects = replace(effects, flex_mode_hz=case["flex_hz"], flex_mode_damping=case["flex_damping"])
        elif name == "delay_jitter":
            effects = replace(effects, delay_jitter=0.006 * sc)  # ~4-8 ms std, as the issue's flights had
        else:
            effects = replace(effects, **{name: gen.effect_value(name, model, tests, sc)})
    spec = FlightSpec(model=model, tests=tests, loop="altitude", rate_hz=case["rate"], effects=effects,
                      seed=case["seed"], hover_s=2.0, hold_s=2.0, noise_std=case["noise"])
    flight = simulate_flight(spec)
    flight.topics = [t for t in flight.topics if t.name != "/battery"]  # conceal the battery voltage
    return flight


def mount_snr(flight) -> float:
    """The oracle SNR of a sensor mount's ringing: its energy over the tests' samples / the noise variance.

    Independent of the tool: the plant of eq. (2) (states y, y', thrust; relative degree 3) has a step
    in its jerk, K du / Tp, at each relay switch (reaching it tau later); the mount (y_s'' =
    w_n^2 (y - y_s) - 2 zeta w_n y_s') then rings freely from the kick A_f^-4 b dj (the jump of the
    quasi-static solution's series -sum A_f^-(n+1) b y^(n)). The rings of all switches are superposed
    at the controller's samples inside the tests; sum(ring^2) / sigma^2 is what a detector knowing the
    ringing's shape could reach (its square root: the matched filter's z).
    """
    from scipy.linalg import expm

    truth, eff = flight.truth, flight.spec.effects
    wn, zeta = 2.0 * np.pi * eff.flex_mode_hz, eff.flex_mode_damping
    A_f = np.array([[0.0, 1.0], [-wn * wn, -2.0 * zeta * wn]])
    b_f = np.array([0.0, wn * wn])
    kick = np.linalg.matrix_power(np.linalg.inv(A_f), 4) @ b_f  # per unit jerk step
    t, u = flight.t, flight.command
    T = float(np.median(np.diff(t)))
    n_ring = int(min(5.0 / (zeta * wn), 3.0) / T) + 2
    step = expm(A_f * T)  # the free response a tick on
    resp, z = np.empty(n_ring), kick.copy()
    for i in range(n_ring):
        resp[i] = z[0]
        z = step @ z
    ring = np.zeros(t.size)
    inside = np.zeros(t.size, bool)
    for test in truth["tests"]:
        inside |= (t >= test["t_start"]) & (t < test["t_end"])
    jumps = np.flatnonzero(np.abs(np.diff(u)) > 0.5 * min(abs(x["h"]) for x in truth["tests"])) + 1
    for k in jumps:
        dj = truth["K"] * (u[k] - u[k - 1]) / truth["Tp"]
        t_on = t[k] + truth["tau"]  # when the switch reaches the plant
        j0 = int(np.searchsorted(t, t_on))
        lag = (t[j0:j0 + n_ring - 1] - t_on) / T  # in ticks, interpolated in the tick-spaced table
        ring[j0:j0 + lag.size] += dj * np.interp(lag, np.arange(n_ring), resp)
    return float(np.sum(ring[inside] ** 2) / truth["noise_std"] ** 2)


def run_case(case: dict) -> dict:
    from diagnose_sims.cases import analyze_then_diagnose
    from mrftcli.io import write_log

    flight = fly(case)
    truth = flight.truth
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "flight.mcap"
        write_log(flight.topics, path, "mcap")
        # read once, analyze, its record or refusal to diagnose: as `mrft-ident diagnose` runs it
        run = analyze_then_diagnose(path, truth["Tp"])
    res = run.res
    effect = case["effect"]
    out = {**case, "cpu": run.cpu, "cpu_analyze": run.cpu_analyze, "error": run.error, "refused": run.refused,
           "aborted": sum(bool(t["aborted"]) for t in truth["tests"]),
           "min_margin": min(t["noise_margin"] for t in truth["tests"]),
           "true_values": {n: truth["effects"][n] for n in (effect or "").split("+") if n},
           "snr": mount_snr(flight) if effect == OUTSIDE else None}
    if res is not None:
        out.update(diagnosis_row(res))
    return out


def diagnosis_row(res) -> dict:
    """What the benchmark scores of a diagnosis: effects found, unexplained and where, a resonance found,
    cycles used, each effect's value and NRMSE before/after, effects dropped (also diagnose_sims/cases.py)."""
    where = res.unexplained.largest if res.unexplained is not None else None
    return {"found": [e.name for e in res.effects], "unexplained": res.unexplained is not None, "where": where,
            # a mode found ringing (or ringing above the fitted harmonics): what a library flight must not show
            "resonance": (where or {}).get("feature") in ("ringing_after_switches", "residual_above_harmonics"),
            "cycles_used": [t.cycles for t in res.tests],
            "values": {e.name: e.parameters.get(PARAM.get(e.name, ""), float("nan")) for e in res.effects},
            "nrmse": {e.name: (e.fit_before.nrmse, e.fit_after.nrmse) for e in res.effects},
            "dropped": [w for w in res.warnings if "not reported" in w]}


def _halved(r: dict, name: str) -> bool:
    before, after = r["nrmse"][name]
    return after is not None and bool(before) and after <= 0.5 * before


def _pct(k: int, n: int) -> str:
    return f"{k}/{n} = {100 * k / max(n, 1):.0f} %"


def met(value: float, target: float, issue: str) -> str:
    """A CPU ratio against an issue's ceiling, in words: ``<= 1.5x median, issue 39: met``."""
    return f"<= {target:g}x median, {issue}: {'met' if value <= target else 'not met'}"


def single_rows(results: list[dict], effects: list[str]) -> dict:
    """Per effect: named right (alone or with a second), its parameter and held-out NRMSE; totals."""
    tot = {"n": 0, "right": 0, "alone": 0, "refused": 0, "halved": 0, "within": 0}
    print(f"{'effect':<20} {'n':>3} {'named':>6} {'alone':>6} {'25 %':>5} {'NRMSE/2':>8}  found instead / with")
    for effect in effects:
        rs = [r for r in results if r["effect"] == effect]
        if not rs:
            continue
        right = [r for r in rs if effect in (r.get("found") or [])]
        alone = [r for r in right if r["found"] == [effect]]
        within = [r for r in right if abs(r["values"][effect] / r["true_values"][effect] - 1) <= 0.25]
        halved = [r for r in right if _halved(r, effect)]
        for key, val in (("n", rs), ("right", right), ("alone", alone), ("halved", halved), ("within", within)):
            tot[key] += len(val)
        tot["refused"] += sum(r["refused"] for r in rs)
        other = [r.get("found") if r.get("error") is None else r["error"][:70] for r in rs if r.get("found") != [effect]]
        print(f"{effect:<20} {len(rs):>3} {len(right):>3}/{len(rs):<2} {len(alone):>3}/{len(right):<2} "
              f"{len(within):>2}/{len(right):<2} {len(halved):>4}/{len(right):<3} {other}")
        for r in rs:
            if r.get("found") != [effect] and r.get("dropped"):
                print(f"  {'':<18} {r['rate']:.0f} Hz: {' | '.join(r['dropped'])}")
        steps = [f"{r['nrmse'][effect][0]:.3f}->{r['nrmse'][effect][1]:.3f}" if r["nrmse"][effect][1] is not None
                 else "n/a" for r in right]
        vals = [f"{r['values'][effect]:.4g}/{r['true_values'][effect]:.4g}" for r in right]
        print(f"  {'':<18} held-out NRMSE {' '.join(steps)}; found/true {' '.join(vals)}")
    return tot


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-effect", type=int, default=3)
    ap.add_argument("--outside", type=int, default=3, help="flights with a sensor-mount resonance (out of library)")
    ap.add_argument("--clean", type=int, default=5)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=None, help="master seed (default: fresh every run)")
    ap.add_argument("--effects", default=None, help="comma-separated subset of the library's effects (default: all)")
    ap.add_argument("--pairs", type=int, default=0, help="also this many logs with two effects at once")
    ap.add_argument("--only", default=None,
                    help="run only the drawn cases of these kinds (comma-separated effects, 'clean', 'outside'): with "
                         "the run's --seed and counts the draws are unchanged, so its misses are reproduced")
    ap.add_argument("--lookalikes", action="store_true",
                    help="only the look-alike pairs' flights (LOOKALIKE_FLIGHTS), with the whole library")
    args = ap.parse_args()
    if args.lookalikes:
        run_lookalikes()
        return
    master = args.seed if args.seed is not None else int.from_bytes(os.urandom(4), "little")
    rng = np.random.default_rng(master)
    gen = _gen_module()
    plants = list(gen.PLANTS)
    chosen = list(gen.EFFECTS) if args.effects is None else args.effects.split(",")
    cases = [draw_case(rng, e, plants) for e in chosen for _ in range(args.per_effect)]
    cases += [draw_case(rng, OUTSIDE, plants) for _ in range(args.outside)]
    cases += [draw_case(rng, None, plants) for _ in range(args.clean)]
    for _ in range(args.pairs):
        a, b = sorted(rng.choice(len(gen.EFFECTS), 2, replace=False))
        cases.append(draw_case(rng, f"{gen.EFFECTS[a]}+{gen.EFFECTS[b]}", plants))
    if args.only is not None:
        kinds = {{"clean": None, "outside": OUTSIDE}.get(k, k) for k in args.only.split(",")}
        cases = [c for c in cases if c["effect"] in kinds]
    print(f"master seed {master}: {len(cases)} logs, {args.jobs} processes; rates {RATES} Hz, noise 0.5-1 mm, "
          "tests 10-14 s, third test at 2x the first's relay height, nothing re-flown or dropped")
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(run_case, cases))
    wall = time.perf_counter() - t0
    tot = single_rows(results, chosen)
    outside = [r for r in results if r["effect"] == OUTSIDE]
    if outside:
        ok = [r for r in outside if r.get("unexplained") or "sensor_resonance" in (r.get("found") or [])]
        only = [r for r in ok if not set(r.get("found") or []) - {"sensor_resonance"}]
        print(f"{'sensor mount (out)':<20} {len(outside):>3} unexplained or resonance {_pct(len(ok), len(outside))}: "
              + str([(f"{r['flex_hz']:.1f} Hz", f"zeta {r['flex_damping']:.3f}", f"{r['rate']:.0f} Hz",
                      f"oracle SNR {r['snr']:.0f}", r.get("found"), r.get("unexplained"),
                      (r.get("where") or {}).get("what"), r.get("error")) for r in outside]))
    clean = [r for r in results if r["effect"] is None]
    kept = [r for r in clean if r.get("found") == [] and not r.get("unexplained")]
    if clean:
        print(f"{'clean':<20} {len(clean):>3} kept clean {_pct(len(kept), len(clean))}: "
              + str([(r.get("found"), r.get("unexplained"), r.get("error")) for r in clean if r not in kept]))
    library = [r for r in results if r["effect"] not in (None, OUTSIDE)]
    called = [r for r in library + clean if r.get("resonance")]
    print(f"library and clean flights called a resonance: {len(called)}/{len(library) + len(clean)} "
          + str([(r["effect"], r["where"]["what"]) for r in called]))
    pair_rs = [r for r in results if r["effect"] and "+" in r["effect"]]
    if pair_rs:
        both = sum(set(r.get("found") or []) == set(r["true_values"]) for r in pair_rs)
        print(f"pairs: both named, nothing else {_pct(both, len(pair_rs))}: "
              + str([(r["effect"], r.get("found") or r.get("error")) for r in pair_rs]))
    print(f"tests whose relay locked up in the air (kept): {sum(r['aborted'] for r in results)} over "
          f"{sum(1 for r in results if r['aborted'])} logs; least noise margin {min(r['min_margin'] for r in results):.1f}")
    refused = [r for r in results if r["refused"]]
    print(f"refused (counted as misses): {len(refused)}/{len(results)} "
          f"{[(r['effect'], r['error'][:90]) for r in refused]}")
    crashed = [r for r in results if r["error"] and not r["refused"]]
    if crashed:
        print(f"crashed (not an MrftError): {[(r['effect'], r['error']) for r in crashed]}")
    used = [c for r in results for c in r.get("cycles_used") or []]
    if used:
        print(f"stable cycles used per test: min {min(used)}, median {np.median(used):.0f}, max {max(used)}")
    print("targets (issue 27):")
    print(f"  right effect named          {_pct(tot['right'], tot['n'])} (>= 90 %; {tot['refused']} refused)")
    print(f"  clean kept clean            {_pct(len(kept), len(clean))} (>= 90 %)")
    print(f"  no spurious second effect   {_pct(tot['alone'], tot['right'])} of the named (>= 90 %)")
    if outside:
        print(f"  out-of-library unexplained  {_pct(len(ok), len(outside))} (>= 80 %); with no library effect named "
              f"beside it {_pct(len(only), len(outside))}")
    print(f"  held-out NRMSE halved       {_pct(tot['halved'], tot['right'])} of the named (>= 80 %)")
    print(f"  parameter within 25 %       {_pct(tot['within'], tot['right'])} of the named")
    cpu, cpu_a = np.array([r["cpu"] for r in results]), np.array([r["cpu_analyze"] for r in results])
    command = (cpu_a + cpu) / np.maximum(cpu_a, 1e-3)  # `mrft-ident diagnose` reads once and runs analyze inside
    print(f"  the commands' CPU (diagnose = read + analyze + the diagnosis; analyze = read + analyze): per log "
          f"median {np.median(command):.2f}x ({met(np.median(command), 1.5, 'issue 39')}; "
          f"{met(np.median(command), 2.0, 'issue 27')}), worst {command.max():.2f}x")
    print(f"    the diagnosis stage (beyond analyze's record) / analyze: medians {np.median(cpu):.2f} s / "
          f"{np.median(cpu_a):.2f} s = {np.median(cpu) / np.median(cpu_a):.2f}x, per log median "
          f"{np.median(cpu / cpu_a):.2f}x; max {cpu.max():.1f} s; wall {wall:.0f} s")


if __name__ == "__main__":
    main()
