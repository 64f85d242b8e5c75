"""Benchmark (issue 38): slow process plants under relays, logged every 1-10 s with jitter.

Each recording is drawn fresh: a plant (FOPDT, SOPDT or FOIPDT; the main time constant
log-uniform in 1-60 min, SOPDT's second lag 0.1-0.5 of the first, the delay 0.1-0.5 of the main
time constant; K log-uniform in 0.5-50), one or two relay settings (hysteresis eps 5-30 % of the
ideal relay's amplitude; a second setting 2.5-4 times the first), about 8 cycles each, white output
noise of 1-3 % of the amplitude. The relay (a thermostat) decides five times a mean log interval on its
own noisy reading; a recorder logs the command and the output at jittered intervals (uniform in
0.5-1.5 times a mean drawn in 1-10 s, kept to 30-400 samples a cycle), so each switch falls between
two logged samples. The relay is

* ``symmetric``: levels +1 / -1 about the command's zero, the setpoint at the output's rest;
* ``biased``: a 0/1 heater (the setpoint at a duty of 0.3-0.7 of the static gain above the rest;
  FOIPDT: an operating point of 0.3-0.7 on its 0/1 command), analysed without and with
  ``--baseline Y0:STD`` (the rest known to 2 % of the amplitude; self-regulating plants).

The simulator (tests/thermal_sim.py: tf2ss, exact event-to-event propagation, the delay exact)
shares no code with mrftcli. Each recording is written as a CSV, read as ``analyze --model`` reads it
(any time scale) and analysed with :func:`~mrftcli.analyze.analyze_flight` (a family model). Scored per
parameter: a determined one (95 % interval within a factor 1.25 either way) within 5 % of the truth,
and the same among those whose interval is within +-10 %; an undetermined one named (``determined``
False), with the determined combination the tool names; 95 % coverage of every parameter's interval; **false determined**: a parameter called
determined whose 95 % interval excludes the truth (and **gross**: by more than the interval's
half-width). A refusal counts as a miss on every figure.

Run: ``nice -n 10 python benchmarks/bench_slow_process.py [--n 6] [--seed 3800]`` (n recordings per
family, relay and number of settings; about 1 s each).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from process_sim import polynomials, write_csv  # noqa: E402
from thermal_sim import INTEGRATING, RelayWindow, simulate_relay  # noqa: E402

FAMILIES = ("fopdt", "sopdt", "foipdt")
#: a determined parameter whose 95 % interval is within a factor 1.1 either way (log half-width)
_TIGHT = math.log(1.1)
RELAYS = ("symmetric", "biased")


def lu(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def draw_plant(family: str, rng: np.random.Generator) -> dict[str, float]:
    T = lu(rng, 60.0, 3600.0)
    p = {"K": lu(rng, 0.5, 50.0), "tau": float(rng.uniform(0.1, 0.5)) * T}
    if family == "sopdt":
        p.update(T1=T, T2=float(rng.uniform(0.1, 0.5)) * T)
    else:
        p["T"] = T
    if family == "foipdt":
        p["K"] /= T  # output per command per second: a comparable amplitude
    return p


def describing_cycle(family: str, p: dict[str, float], h: float, eps: float) -> tuple[float, float]:
    """(period [s], amplitude) of the hysteresis relay's cycle by the describing function (for planning)."""
    num, den = polynomials(family, p)
    ws = np.geomspace(1e-7, 10.0, 4000)
    G = np.polyval(num, 1j * ws) / np.polyval(den, 1j * ws)
    phase = np.unwrap(np.angle(G)) - ws * p["tau"]
    amp = 4 * h * np.abs(G) / math.pi
    lag = np.arcsin(np.clip(eps / amp, 0.0, 1.0))
    f = phase + math.pi - lag
    k = int(np.flatnonzero((f[:-1] > 0) & (f[1:] <= 0))[0])
    w = ws[k] - f[k] * (ws[k + 1] - ws[k]) / (f[k + 1] - f[k])
    return 2 * math.pi / w, float(np.interp(w, ws, amp))


def draw_recording(family: str, relay: str, n_settings: int, rng: np.random.Generator):
    p = draw_plant(family, rng)
    h = 1.0 if relay == "symmetric" else 0.5
    _, amp0 = describing_cycle(family, p, h, 0.0)
    eps1 = float(rng.uniform(0.05, 0.3)) * amp0
    eps = [eps1] if n_settings == 1 else [eps1, eps1 * float(rng.uniform(2.5, 4.0))]
    cycles = [describing_cycle(family, p, h, e) for e in eps]
    period = min(c[0] for c in cycles)
    amp = max(c[1] for c in cycles)
    dt = float(np.clip(rng.uniform(1.0, 10.0), max(1.0, period / 400), max(min(10.0, period / 30), 0.05)))
    high, low = (1.0, -1.0) if relay == "symmetric" else (1.0, 0.0)
    windows = [RelayWindow(high, low, e, 8.5 * c[0]) for e, c in zip(eps, cycles)]
    baseline = float(rng.uniform(10.0, 30.0))
    integrating = family in INTEGRATING
    if relay == "biased" and integrating:
        u_op = float(rng.uniform(0.3, 0.7))
        setpoint = baseline
    elif relay == "biased":
        u_op = None
        setpoint = baseline + p["K"] * float(rng.uniform(0.3, 0.7))
    else:
        u_op, setpoint = None, baseline
    noise = float(rng.uniform(0.01, 0.03)) * amp
    t, u, y = simulate_relay(family, p, windows, setpoint=setpoint, baseline=baseline,
                             sample_s=(0.5 * dt, 1.5 * dt), noise_std=noise, seed=int(rng.integers(2**31)),
                             u_op=u_op, decide_s=dt / 5)
    return p, (t, u, y), baseline, amp, dt, period


def score(ident, truth: dict[str, float]) -> dict[str, object]:
    rows = {}
    for e in ident.estimates:
        if e.known:
            continue
        v = truth[e.name]
        lo, hi = e.ci95_low, e.ci95_high
        covered = lo <= v <= hi
        half = 0.5 * (hi - lo) if math.isfinite(hi - lo) else math.inf
        miss = 0.0 if covered else min(abs(v - lo), abs(v - hi))
        rows[e.name] = {"determined": e.determined, "within5": e.determined and abs(e.value / v - 1) <= 0.05,
                        "covered": covered, "false": e.determined and not covered,
                        "gross": e.determined and not covered and miss > half,
                        "err": e.value / v - 1, "half": 0.5 * math.log(hi / lo) if lo > 0 and math.isfinite(hi) else math.inf}
    return rows


def analyse(path: Path, family: str, baseline: tuple[float, float] | None):
    from mrftcli.analyze import AnalyzeOptions, analyze_flight
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.families import family_model

    flight = read_flight(path, ReadOptions(command_topic="u_relay", output_topic="y_output", any_time_scale=True),
                         echo_warnings=False)
    return analyze_flight(flight, family_model(family), options=AnalyzeOptions(baseline=baseline)).identification


def one(family: str, relay: str, n_settings: int, rng: np.random.Generator, tmp: Path) -> list[dict[str, object]]:
    from mrftcli.errors import MrftError

    truth, (t, u, y), baseline, amp, dt, period = draw_recording(family, relay, n_settings, rng)
    path = tmp / "rec.csv"
    write_csv(str(path), t, u, y)
    variants = [("", None)]
    if relay == "biased" and family not in INTEGRATING:
        variants.append(("+baseline", (baseline + float(rng.normal(0, 0.02 * amp)), 0.02 * amp)))
    out = []
    for tag, base in variants:
        row: dict[str, object] = {"family": family, "relay": relay + tag, "settings": n_settings, "dt": dt,
                                  "period": period, "n": t.size}
        try:
            ident = analyse(path, family, base)
            row["params"] = score(ident, truth)
            row["combination"] = ident.combination.name if ident.combination else ""
            if ident.combination is not None:
                c = ident.combination
                val = math.prod(truth[n] ** e for n, e in c.exponents)
                row["combination_covered"] = c.ci95_low <= val <= c.ci95_high
        except MrftError as err:
            row["refused"] = str(err)[:100]
            row["params"] = {}
        out.append(row)
    return out


def summarise(rows: list[dict[str, object]], names: dict[str, tuple[str, ...]]) -> None:
    groups: dict[tuple[str, str, int], list[dict[str, object]]] = {}
    for r in rows:
        groups.setdefault((str(r["family"]), str(r["relay"]), int(r["settings"])), []).append(r)  # type: ignore[arg-type]
    print(f"{'family':<7} {'relay':<19} {'set':>3} {'n':>3} {'refused':>7} {'determined':>10} {'within 5 %':>10} "
          f"{'95 % covers':>11} {'false det.':>10} {'gross':>5}  undetermined (named), determined combination")
    tot = {"param": 0, "det": 0, "w5": 0, "cov": 0, "false": 0, "gross": 0, "refused": 0, "rec": 0, "tight": 0,
           "tight5": 0}
    for (fam, relay, k), rs in sorted(groups.items()):
        n = len(rs)
        refused = sum("refused" in r for r in rs)
        n_param = n * len(names[fam])
        det = sum(v["determined"] for r in rs for v in r["params"].values())  # type: ignore[union-attr]
        w5 = sum(v["within5"] for r in rs for v in r["params"].values())  # type: ignore[union-attr]
        cov = sum(v["covered"] for r in rs for v in r["params"].values())  # type: ignore[union-attr]
        fal = sum(v["false"] for r in rs for v in r["params"].values())  # type: ignore[union-attr]
        gro = sum(v["gross"] for r in rs for v in r["params"].values())  # type: ignore[union-attr]
        tight = [v for r in rs for v in r["params"].values() if v["determined"] and v["half"] <= _TIGHT]  # type: ignore[union-attr]
        tot["tight"] += len(tight)
        tot["tight5"] += sum(abs(v["err"]) <= 0.05 for v in tight)
        und: dict[str, int] = {}
        for r in rs:
            for name, v in r["params"].items():  # type: ignore[union-attr]
                if not v["determined"]:
                    und[name] = und.get(name, 0) + 1
        combos: dict[str, int] = {}
        for r in rs:
            if r.get("combination"):
                combos[str(r["combination"])] = combos.get(str(r["combination"]), 0) + 1
        text = ", ".join(f"{k_} {v}/{n}" for k_, v in sorted(und.items())) or "-"
        if combos:
            text += "; " + ", ".join(f"{k_} {v}" for k_, v in combos.items())
        print(f"{fam:<7} {relay:<19} {k:>3} {n:>3} {refused:>7} {det:>5}/{n_param:<4} {w5:>5}/{det:<4} "
              f"{cov:>6}/{n_param:<4} {fal:>10} {gro:>5}  {text}")
        for key, val in (("param", n_param), ("det", det), ("w5", w5), ("cov", cov), ("false", fal), ("gross", gro),
                         ("refused", refused), ("rec", n)):
            tot[key] += val
    print(f"all: {tot['rec']} analyses, {tot['refused']} refused; {tot['det']}/{tot['param']} parameters determined, "
          f"{tot['w5']}/{tot['det']} of them within 5 % ({100 * tot['w5'] / max(tot['det'], 1):.0f} %); 95 % intervals "
          f"cover {tot['cov']}/{tot['param']} ({100 * tot['cov'] / max(tot['param'], 1):.0f} %); determined but the "
          f"interval excludes the truth: {tot['false']} ({tot['gross']} by more than its half-width); of the "
          f"determined ones with a 95 % interval within +-10 %: {tot['tight5']}/{tot['tight']} within 5 %")
    combos = [r for r in rows if "combination_covered" in r]
    if combos:
        print(f"determined combinations: {len(combos)}, their 95 % intervals cover the truth on "
              f"{sum(bool(r['combination_covered']) for r in combos)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=6, help="recordings per family, relay and number of settings")
    ap.add_argument("--seed", type=int, default=3800)
    ap.add_argument("--families", default=",".join(FAMILIES))
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    names = {"fopdt": ("K", "T", "tau"), "sopdt": ("K", "T1", "T2", "tau"), "foipdt": ("K", "T", "tau")}
    rows: list[dict[str, object]] = []
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        for family in args.families.split(","):
            for relay in RELAYS:
                for k in (1, 2):
                    for _ in range(args.n):
                        rows += one(family, relay, k, rng, Path(d))
    elapsed = time.perf_counter() - start
    dts = [float(r["dt"]) for r in rows]  # type: ignore[arg-type]
    periods = [float(r["period"]) / 60 for r in rows]  # type: ignore[arg-type]
    print(f"seed {args.seed}: {len(rows)} analyses; mean sample interval {min(dts):.2f}-{max(dts):.2f} s (jitter "
          f"0.5-1.5x), cycle periods {min(periods):.1f}-{max(periods):.1f} min; {elapsed:.0f} s")
    summarise(rows, names)
    if os.environ.get("BENCH_DUMP"):
        import json
        Path(os.environ["BENCH_DUMP"]).write_text(json.dumps(rows, default=str))
    for r in rows:
        if "refused" in r:
            print(f"  refused: {r['family']} {r['relay']} {r['settings']}: {r['refused']}")


if __name__ == "__main__":
    main()
