#!/usr/bin/env python
"""Benchmark of ``diagnose --model NAME``: the library of physics on process plants (issue 36; fresh seeds).

Every recording is a process plant of one family (FOPDT, SOPDT, IPDT, FOIPDT; parameters drawn as
``bench_families.py`` draws them) under three relay tests with hysteresis (eps 10-30 % of the ideal
relay's amplitude, as the KSTAR recordings' relays), at relay heights 1, 1.6 and 2.4 (in that order or
shuffled), each about 14 cycles, with rests between them; the controller runs at 50-200 Hz and the
output carries white noise of 1-2 % of the amplitude. One effect of the library is switched on, with
a magnitude drawn in a range where it matters to a user, or none (clean controls):

=====================  ==========================================================================
sensor_lag             a lag on the measured output, 0.3-0.6 of the main time constant (IPDT: of tau)
actuator_rate_limit    the plant input slews between the levels in 0.3-0.6 tau at the largest height
dead_zone              0.3-0.5 of the smallest relay height
actuator_saturation    0.7-0.85 of the middle height (the two larger tests saturate)
asymmetric_gain        a = +-(0.2-0.4)
input_bias             +-(0.15-0.3) of the smallest height
gain_drift             K changes by +-(25-40) % over the recording
bias_drift             an input offset drifting by +-(0.3-0.5) of the smallest height over the recording
delay_jitter           each switch reaches the plant after tau + N(0, sigma), sigma 1-2 % of the period
=====================  ==========================================================================

Clean controls come two ways: ``clean``, drawn as above (three hysteresis relays, 14 cycles each, at
least 40 ticks a cycle), and ``clean_mrft``, drawn as users fly: two or three MRFT tests (beta -0.1 to
-0.5; -0.3 to -0.6 on an integrating plant) of 6-10 cycles each at relay height 1, 20-200 ticks a cycle,
noise 0.5-2 % of the amplitude, flown by tests/process_sim.py (an exact zero-order-hold loop, the MRFT
rule of checks.md section 2, no mrftcli code). A clean recording is kept clean only when the verdict is
"consistent" (no effect named and nothing located as unexplained).

The simulator is written here (``simulate``) and shares no code with mrftcli: the plant from its
transfer function's polynomials (``scipy.signal.tf2ss``), stepped exactly (zero-order hold) on a grid
ten times finer than the controller; the relay decides at the controller's ticks on the noisy output.
Each recording is diagnosed as ``diagnose --model FAMILY`` does (``mrftcli.diagnose.diagnose`` with
the family's model object); a refusal (an ``MrftError``) is a miss wherever it happens.

Printed, with the targets of eq. (2)'s benchmark (``bench_diagnose.py``): right effect named
(>= 90 %), clean kept clean (>= 90 %), no spurious second effect among the named (>= 90 %), held-out
error at least halved on the named (>= 80 %); and the parameter within 25 % of the truth.

Usage::

    nice -n 10 python benchmarks/bench_diagnose_families.py [--per-effect 2] [--clean 4] [--jobs 1] [--seed N]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import mrftcli.cli  # noqa: F401 - BLAS single-threaded as the command line runs it (set before numpy loads)
import numpy as np
from scipy import linalg, signal

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # process_sim (clean_mrft)

FAMILIES = ("fopdt", "sopdt", "ipdt", "foipdt")
EFFECTS = ("sensor_lag", "actuator_rate_limit", "dead_zone", "actuator_saturation", "asymmetric_gain", "input_bias",
           "gain_drift", "bias_drift", "delay_jitter")
HEIGHTS = (1.0, 1.6, 2.4)


def draw_plant(family: str, rng: np.random.Generator) -> dict[str, float]:
    """As bench_families: K in [0.5, 5], time constants in [0.3, 3] s, tau 0.1-1 of the main one."""
    from bench_families import draw_plant as families_draw

    return families_draw(family, rng)


def polynomials(family: str, p: dict[str, float]) -> tuple[list[float], list[float]]:
    K = p["K"]
    return {"fopdt": ([K], [p.get("T", 1.0), 1.0]),
            "sopdt": ([K], list(np.polymul([p.get("T1", 1.0), 1.0], [p.get("T2", 1.0), 1.0]))),
            "ipdt": ([K], [1.0, 0.0]),
            "foipdt": ([K], [p.get("T", 1.0), 1.0, 0.0])}[family]


def main_lag(family: str, p: dict[str, float]) -> float:
    return p["tau"] if family == "ipdt" else p.get("T", p.get("T1", 1.0))


def _zoh(A: np.ndarray, B: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = A * step, B * step
    E = linalg.expm(M)
    return E[:n, :n], E[:n, n]


def plant_input(effect: str, value: float, dev: float, t: float, t_mid: float) -> float:
    """The plant's input for a relay deviation ``dev`` from the relay's bias at time ``t`` (the static effects)."""
    if effect == "dead_zone":
        return math.copysign(max(abs(dev) - value, 0.0), dev)
    if effect == "actuator_saturation":
        return min(dev, value)
    if effect == "asymmetric_gain":
        return (1 + value * math.copysign(1.0, dev)) * dev
    if effect == "input_bias":
        return dev + value
    if effect == "gain_drift":
        return (1 + value * (t - t_mid)) * dev
    if effect == "bias_drift":
        return dev + value * (t - t_mid)
    return dev


def simulate(family: str, p: dict[str, float], effect: str, value: float, relays: list[tuple[float, float]],
             rate_hz: float, noise: float, period: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, command, output) of three hysteresis-relay windows (h, eps) with rests, one effect switched on."""
    rng = np.random.default_rng(seed)
    num, den = polynomials(family, p)
    A, B, C, _ = signal.tf2ss(num, den)
    A, B, C = np.asarray(A, float), np.asarray(B, float)[:, 0], np.asarray(C, float)[0]
    over = 10
    Ts = 1.0 / rate_hz
    dt = Ts / over
    Phi, Gam = _zoh(A, B, dt)
    lag = value if effect == "sensor_lag" else 0.0
    a_lag = math.exp(-dt / lag) if lag > 0 else 0.0
    x, y_lag, w = np.zeros(A.shape[0]), 0.0, 0.0
    dur, rest = 14 * period, 3 * period
    total = 2 * period + len(relays) * (dur + rest)
    t_mid = 0.5 * total
    events: list[tuple[float, float]] = [(0.0, 0.0)]  # (time the plant sees it, relay deviation)
    ts, us, ys = [], [], []
    t, k, s = 0.0, 0, 1.0
    schedule = [(2 * period + i * (dur + rest), h, eps) for i, (h, eps) in enumerate(relays)]
    while t < total:
        y = (y_lag if lag > 0 else float(C @ x)) + noise * rng.standard_normal()
        win = next(((h, eps) for t0, h, eps in schedule if t0 <= t < t0 + dur), None)
        if win is None:
            dev, s = 0.0, 1.0
        else:
            h, eps = win
            e = -y
            if s > 0 and e <= -eps:
                s = -1.0
            elif s < 0 and e >= eps:
                s = 1.0
            dev = s * h
        if dev != events[-1][1]:
            jit = value * rng.standard_normal() if effect == "delay_jitter" else 0.0
            events.append((max(t + p["tau"] + jit, events[-1][0]), dev))
        ts.append(t)
        us.append(dev)
        ys.append(y)
        for j in range(over):
            tf = t + j * dt
            while len(events) > 1 and events[1][0] <= tf:
                events.pop(0)
            target = plant_input(effect, value, events[0][1], tf, t_mid)
            if effect == "actuator_rate_limit":
                w += float(np.clip(target - w, -value * dt, value * dt))
            else:
                w = target
            x = Phi @ x + Gam * w
            if lag > 0:
                y_lag = a_lag * y_lag + (1 - a_lag) * float(C @ x)
        t += Ts
        k += 1
    return np.array(ts), np.array(us), np.array(ys)


def draw_case(kind: str, seed: int) -> dict[str, object]:
    """One recording's settings (family, plant, effect and its value, relays, rate, noise)."""
    rng = np.random.default_rng(seed)
    family = FAMILIES[int(rng.integers(len(FAMILIES)))]
    p = draw_plant(family, rng)
    if kind == "clean_mrft":
        return _draw_users_clean(family, p, rng)
    from mrftcli.mrft.families import family_model
    from mrftcli.mrft.lprs import mrft_limit_cycle

    model = family_model(family).with_parameters(**p)
    lc = mrft_limit_cycle(model, 0.0, 1.0)
    period, amp = lc.period, lc.amplitude
    heights = list(HEIGHTS) if rng.random() < 0.5 else list(rng.permutation(HEIGHTS))
    relays = [(h, float(rng.uniform(0.1, 0.3)) * amp * h) for h in heights]
    u = float(rng.uniform(0.0, 1.0))
    sign = 1.0 if rng.random() < 0.5 else -1.0
    lag0 = main_lag(family, p)
    value = {"clean": 0.0,
             "sensor_lag": (0.3 + 0.3 * u) * lag0,
             "actuator_rate_limit": 2 * max(HEIGHTS) / ((0.3 + 0.3 * u) * p["tau"]),
             "dead_zone": (0.3 + 0.2 * u) * min(HEIGHTS),
             "actuator_saturation": (0.7 + 0.15 * u) * HEIGHTS[1],
             "asymmetric_gain": sign * (0.2 + 0.2 * u),
             "input_bias": sign * (0.15 + 0.15 * u) * min(HEIGHTS),
             "gain_drift": sign * (0.25 + 0.15 * u),  # over the recording; per second below
             "bias_drift": sign * (0.3 + 0.2 * u) * min(HEIGHTS),
             "delay_jitter": (0.01 + 0.01 * u) * period}[kind]
    rate = float(rng.uniform(50.0, 200.0))
    rate = max(rate, 40.0 / period)  # at least 40 ticks a cycle
    noise = float(rng.uniform(0.01, 0.02)) * amp
    total = 2 * period + 3 * 17 * period
    if kind in ("gain_drift", "bias_drift"):
        value /= total
    return dict(kind=kind, family=family, params=p, value=value, relays=relays, rate=rate, noise=noise,
                period=period, sim_seed=int(rng.integers(1 << 31)))


def _draw_users_clean(family: str, p: dict[str, float], rng: np.random.Generator) -> dict[str, object]:
    """A clean recording as users fly it (module docstring: ``clean_mrft``)."""
    from mrftcli.mrft.families import family_model
    from mrftcli.mrft.lprs import mrft_limit_cycle

    lc = mrft_limit_cycle(family_model(family).with_parameters(**p), 0.0, 1.0)
    integrating = family in ("ipdt", "foipdt")
    n = int(rng.integers(2, 4))
    betas = [float(b) for b in rng.choice([-0.6, -0.5, -0.4, -0.3] if integrating else [-0.5, -0.4, -0.3, -0.2, -0.1],
                                          n, replace=False)]
    cycles = [float(rng.uniform(6.0, 10.0)) for _ in betas]
    ticks = float(np.exp(rng.uniform(math.log(20.0), math.log(200.0))))
    return dict(kind="clean_mrft", family=family, params=p, value=0.0, betas=betas, cycles=cycles,
                rate=ticks / lc.period, noise=float(rng.uniform(0.005, 0.02)) * lc.amplitude, period=lc.period,
                amp=lc.amplitude, sim_seed=int(rng.integers(1 << 31)))


def _fly_users_clean(case: dict[str, object]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, command, output) of a ``clean_mrft`` case, flown by tests/process_sim.py."""
    from process_sim import Window
    from process_sim import simulate as process_simulate

    P = float(case["period"])
    windows = [Window("mrft", 1.0, -1.0, beta=b, duration=c * P, rest=3 * P)
               for b, c in zip(case["betas"], case["cycles"])]
    # an integrating plant under an MRFT needs a clear first excursion (process_sim's start)
    return process_simulate(str(case["family"]), case["params"], windows, float(case["rate"]), float(case["noise"]),
                            seed=int(case["sim_seed"]), lead=2 * P, start=0.1 * float(case["amp"]))


def run_case(case: dict[str, object]) -> dict[str, object]:
    """Simulate and diagnose one case; the diagnosis's answer and CPU."""
    from mrftcli.diagnose import diagnose
    from mrftcli.errors import MrftError
    from mrftcli.io.logtypes import FlightLog, Signal
    from mrftcli.mrft.families import family_model

    kind = str(case["kind"])
    effect = "none" if kind == "clean" else kind
    if kind == "clean_mrft":
        t, u, y = _fly_users_clean(case)
    else:
        t, u, y = simulate(str(case["family"]), case["params"], effect, float(case["value"]), case["relays"],
                           float(case["rate"]), float(case["noise"]), float(case["period"]), int(case["sim_seed"]))
    flight = FlightLog(path=f"{kind}.sim", loop="altitude", command=Signal(t, u), output=Signal(t, y))
    t0 = time.process_time()
    try:
        result = diagnose(flight, family_model(str(case["family"])))
    except MrftError as err:
        return {**case, "found": None, "error": str(err), "cpu": time.process_time() - t0}
    effects = result.effects
    return {**case, "found": [e.name for e in effects], "error": "", "cpu": time.process_time() - t0,
            "values": [e.value for e in effects], "before": [e.held_out_before for e in effects],
            "after": [e.held_out_after for e in effects], "verdict": result.summary}


def _truth(case: dict[str, object]) -> float:
    value = float(case["value"])
    return value


def score(rows: list[dict[str, object]]) -> None:
    """The table and the targets."""
    lib = [r for r in rows if not str(r["kind"]).startswith("clean")]
    clean = [r for r in rows if str(r["kind"]).startswith("clean")]
    print(f"{'effect':<22} {'n':>3} {'named':>6} {'param 25%':>10} {'halved':>7}  found instead / refused")
    named_right = param_ok = halved = spurious = named_any = 0
    for kind in EFFECTS:
        rs = [r for r in lib if r["kind"] == kind]
        if not rs:
            continue
        ok = [r for r in rs if r["found"] and r["found"][0] == kind]
        par = [r for r in ok if abs(r["values"][0] / _truth(r) - 1) <= 0.25]
        half = [r for r in ok if r["after"][0] <= 0.5 * r["before"][0]]
        wrong = [("refused" if r["found"] is None else ",".join(r["found"]) or "nothing") + f" ({r['family']})"
                 for r in rs if r not in ok]
        print(f"{kind:<22} {len(rs):>3} {len(ok):>3}/{len(rs):<2} {len(par):>6}/{len(ok):<3} {len(half):>3}/{len(ok):<3}  "
              + "; ".join(wrong))
        for r in ok:
            extra = f"  + {r['found'][1]} (second)" if len(r["found"]) > 1 else ""
            print(f"    {r['family']:<7} found/true {r['values'][0]:.4g}/{_truth(r):.4g}  held-out "
                  f"{r['before'][0]:.3f} -> {r['after'][0]:.3f}{extra}")
        named_right += len(ok)
        param_ok += len(par)
        halved += len(half)
        named_any += sum(bool(r["found"]) for r in rs)
        spurious += sum(bool(r["found"]) and len(r["found"]) > 1 for r in rs)
    # kept clean: nothing named and nothing located (the verdict "consistent"), as a user reads it
    kept = [r for r in clean if r["found"] == [] and str(r.get("verdict", "")).startswith("consistent")]
    for kind in ("clean", "clean_mrft"):
        rs = [r for r in clean if r["kind"] == kind]
        if rs:
            ok = [r for r in rs if r in kept]
            print(f"{kind:<22} {len(rs):>3} {len(ok):>3}/{len(rs):<2} (kept clean)  false: "
                  + "; ".join(_false_clean(r) for r in rs if r not in ok))
    n = len(lib)
    pct = lambda a, b: f"{100 * a / b:.0f} %" if b else "-"  # noqa: E731
    print(f"right effect named: {named_right}/{n} = {pct(named_right, n)} (target >= 90 %)")
    print(f"clean kept clean: {len(kept)}/{len(clean)} = {pct(len(kept), len(clean))} (target >= 90 %)")
    print(f"no spurious second effect: {named_any - spurious}/{named_any} = {pct(named_any - spurious, named_any)} "
          "(target >= 90 %)")
    print(f"held-out error halved (of named right): {halved}/{named_right} = {pct(halved, named_right)} (target >= 80 %)")
    print(f"parameter within 25 % (of named right): {param_ok}/{named_right}")
    cpu = sorted(float(r["cpu"]) for r in rows)
    print(f"CPU per recording (diagnose): median {cpu[len(cpu) // 2]:.1f} s, max {cpu[-1]:.1f} s")


def _false_clean(r: dict[str, object]) -> str:
    """Why a clean recording was not kept clean: refused, the effects named, or the verdict's start."""
    if r["found"] is None:
        why = "refused"
    elif r["found"]:
        why = ",".join(r["found"])
    else:  # the first place located: "unexplained by X (...): <where>"
        why = str(r.get("verdict", "")).partition("): ")[2][:90]
    return f"{why} ({r['family']}, {float(r['rate']) * float(r['period']):.0f} ticks/cycle)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-effect", type=int, default=2)
    ap.add_argument("--clean", type=int, default=4)
    ap.add_argument("--clean-mrft", type=int, default=None,
                    help="clean recordings flown as users fly them (MRFT, few cycles; default: --clean)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=None, help="master seed (default: fresh)")
    ap.add_argument("--only", default="", help="comma-separated kinds (effects or clean)")
    args = ap.parse_args()
    master = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % (1 << 32))
    rng = np.random.default_rng(master)
    n_users = args.clean if args.clean_mrft is None else args.clean_mrft
    kinds = [k for k in EFFECTS for _ in range(args.per_effect)] + ["clean"] * args.clean + ["clean_mrft"] * n_users
    seeds = [int(rng.integers(1 << 31)) for _ in kinds]
    only = set(filter(None, args.only.split(",")))
    cases = [draw_case(k, s) for k, s in zip(kinds, seeds) if not only or k in only]
    print(f"master seed {master}: {len(cases)} recordings, {args.jobs} process(es)")
    t0 = time.time()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as ex:
            rows = list(ex.map(run_case, cases))
    else:
        rows = [run_case(c) for c in cases]
    score(rows)
    print(f"wall {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
