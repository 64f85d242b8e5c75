"""Benchmark: process plants of every family under every relay, identified from simulated recordings.

Each recording is drawn fresh: a plant of the family (K log-uniform in [0.5, 5]; time constants
log-uniform in [0.3, 3] s, SOPDT's second lag 0.1-0.5 of the first; tau 0.1-1 of the main time
constant, or 0.1-0.8 s for IPDT), a controller rate uniform in 50-200 Hz, white output noise of 1-3 %
of the ideal relay's amplitude, and 3-4 relay windows of about 14 cycles each with rests between
them, of one relay type:

* ``mrft``: betas drawn in [-0.3, 0.3] (integrating families: [-0.6, 0]), stated as MRFT;
* ``ideal``: relay heights 1-2;
* ``hysteresis``: eps 5-40 % of the ideal relay's amplitude;
* ``biased``: asymmetric levels (bias 20-50 % of h) with a hysteresis of 5-30 %.

The simulator (tests/process_sim.py) shares no code with mrftcli. Each recording is written as a CSV
and analysed with ``analyze_flight`` with the family model (what ``analyze --model NAME`` runs). Scored per recording:
every parameter within 5 % of the truth; every 95 % interval covering the truth; held-out frequency
within 10 % on every test. A recording the tool refuses (no usable test, an undetermined parameter)
counts as a miss. Also timed: the response-point fit (:func:`~mrftcli.mrft.identify_lti.fit_response_points`, the
families' strategy of :func:`~mrftcli.mrft.identify.identify`) on the recordings' response points, by its route
for the built-in families (the closed-form residuals and Jacobian of ``mrft/lti_kernel.py``) and,
in the same process, alternating per recording, by the general route every other structure takes
(a model object per grid point, ``scipy.optimize.least_squares``).

With ``--baseline`` each recording is analysed a second time, in the same process, with the per-cycle
fit before issue 22's fix (each cycle's own free line plus harmonics, which hands the harmonics left
out back to those fitted: an IPDT's K ~1 % low under the ideal relay), and the same scores and K's
median error are printed for both.

Run: ``nice -n 10 python benchmarks/bench_families.py [--n 10] [--seed 0] [--baseline]`` (n recordings
per family and relay; about 1.5 s each, 2 s with the baseline).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
# one BLAS thread: the small least-squares fits are 50x slower when BLAS threads fight for shared cores
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

FAMILIES = ("fopdt", "sopdt", "ipdt", "foipdt")
RELAYS = ("mrft", "ideal", "hysteresis", "biased")


def draw_plant(family: str, rng: np.random.Generator) -> dict[str, float]:
    lu = lambda lo, hi: float(np.exp(rng.uniform(np.log(lo), np.log(hi))))  # noqa: E731
    K = lu(0.5, 5.0)
    if family == "ipdt":
        return {"K": K, "tau": rng.uniform(0.1, 0.8)}
    T = lu(0.3, 3.0)
    tau = T * rng.uniform(0.1, 1.0)
    if family == "sopdt":
        return {"K": K, "T1": T, "T2": T * rng.uniform(0.1, 0.5), "tau": tau}
    return {"K": K, "T": T, "tau": tau}


def draw_windows(family: str, relay: str, amp: float, period: float, rng: np.random.Generator):
    from process_sim import Window

    n = int(rng.integers(3, 5))
    dur = 14 * period
    integrating = family in ("ipdt", "foipdt")
    out = []
    for k in range(n):
        h = float(rng.uniform(1.0, 2.0))
        if relay == "mrft":
            beta = float(rng.uniform(-0.6, 0.0) if integrating else rng.uniform(-0.3, 0.3))
            out.append(Window("mrft", h, -h, beta=beta, duration=dur * 1.5, rest=period))
        elif relay == "ideal":
            out.append(Window("ideal", h, -h, duration=dur, rest=period))
        elif relay == "hysteresis":
            eps = float(rng.uniform(0.05, 0.4)) * amp * h
            out.append(Window("hysteresis", h, -h, eps=eps, duration=dur * 2, rest=period))
        else:
            bias = float(rng.uniform(0.2, 0.5)) * h * (1 if k % 2 == 0 else -1)
            eps = float(rng.uniform(0.05, 0.3)) * amp * h
            out.append(Window("hysteresis", bias + h, bias - h, eps=eps, duration=dur * 2, rest=period))
    return out


def one_recording(family: str, relay: str, rng: np.random.Generator, tmp: Path,
                  baseline: bool = False) -> dict[str, object]:
    from process_sim import simulate, write_csv

    from mrftcli.analyze import AnalyzeOptions, analyze_flight
    from mrftcli.analyze.options import RelayOptions
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.families import PROCESS_FAMILIES, family_model
    from mrftcli.mrft.relays import RelayLaw

    params = draw_plant(family, rng)
    true = PROCESS_FAMILIES[family](**params)
    ideal = RelayLaw("ideal", 1.0, -1.0).limit_cycle(true)  # the scale of the draws' relays
    windows = draw_windows(family, relay, ideal.amplitude, ideal.period, rng)
    rate = float(rng.uniform(50.0, 200.0))
    noise = float(rng.uniform(0.01, 0.03)) * ideal.amplitude
    t, u, y = simulate(family, params, windows, rate, noise, seed=int(rng.integers(1 << 31)))
    path = tmp / "rec.csv"
    write_csv(str(path), t, u, y)
    flight = read_flight(path, ReadOptions(command_topic="u_relay", output_topic="y_output"), echo_warnings=False)
    relay_options = RelayOptions("mrft") if relay == "mrft" else RelayOptions()
    model = family_model(family)
    row = _score(lambda: analyze_flight(flight, model, options=AnalyzeOptions(relay=relay_options)), model, params, len(windows))
    if baseline:
        with _free_line_fits():
            base = _score(lambda: analyze_flight(flight, model, options=AnalyzeOptions(relay=relay_options)), model, params, len(windows))
        row.update({f"base_{k}": base[k] for k in ("within5", "covered", "held10")})
        row["base_worst"] = base.get("worst", math.nan)
        row["base_K_err"] = base.get("K_err", math.nan)
    return row


def _score(analyse, model, params: dict[str, float], n_windows: int) -> dict[str, object]:
    """One recording's scores (module docstring) from ``analyse()``, an ``analyze_flight`` with the family model call of ``model``."""
    from mrftcli.errors import MrftError

    try:
        res = analyse()
    except MrftError as err:
        return {"within5": False, "covered": False, "held10": False, "refused": str(err)[:80], "points": []}
    ident = res.identification
    assert ident is not None
    within = all(abs(ident.estimate(n).value / v - 1) <= 0.05 for n, v in params.items()) and not ident.undetermined
    covered = all(ident.estimate(n).ci95_low <= v <= ident.estimate(n).ci95_high for n, v in params.items())
    held = [t.held_out.frequency_hz / t.frequency_hz - 1 for t in res.tests
            if t.held_out is not None and t.held_out.frequency_hz is not None]
    held10 = len(held) == len(res.tests) and all(abs(h) <= 0.10 for h in held)
    return {"within5": within, "covered": covered, "held10": held10, "refused": "",
            "n_tests": len(res.tests), "n_windows": n_windows, "points": ident.points,
            "model": model,
            "worst": max(abs(ident.estimate(n).value / v - 1) for n, v in params.items()),
            "K_err": ident.estimate("K").value / params["K"] - 1}


@contextlib.contextmanager
def _free_line_fits():
    """``analyze_flight`` with the family model with the per-cycle fit before issue 22's fix: each cycle's own free line plus
    harmonics (the baseline; it hands the harmonics left out back to those fitted through the line)."""
    from mrftcli.analyze import general
    from mrftcli.analyze.smooth_cycle import CycleFit
    from mrftcli.mrft.harmonics import fit_harmonics

    def free_line(flight, test):
        t, y = flight.output.t, flight.output.values * test.loop_sign
        fits = []
        for c in test.stable:
            P = c.t_end - c.t_start
            i0, i1 = np.searchsorted(t, [c.t_start - 1e-6 * P, c.t_end - 1e-6 * P])
            if i1 - i0 < 10:
                continue
            fit = fit_harmonics(t[i0:i1] - c.t_start, y[i0:i1], P, min(8, (i1 - i0 - 2) // 4))
            fits.append(CycleFit(c.t_start, P, c.t_switch - c.t_start, fit.harmonics, "glitch" in c.flags))
        return tuple(fits)

    fixed = general.cycle_fits
    general.cycle_fits = free_line
    try:
        yield
    finally:
        general.cycle_fits = fixed


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=10, help="recordings per family and relay")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--families", default=",".join(FAMILIES), help="comma-separated subset")
    ap.add_argument("--relays", default=",".join(RELAYS), help="comma-separated subset")
    ap.add_argument("--baseline", action="store_true",
                    help="also analyse each recording with the per-cycle free line (before issue 22's fix)")
    args = ap.parse_args()
    from mrftcli.mrft.identify_lti import fit_response_points

    rng = np.random.default_rng(args.seed)
    print(f"{args.n} fresh recordings per family and relay (seed {args.seed})")
    print(f"{'family':<7} {'relay':<11} {'within 5 %':>10} {'95 % covers':>11} {'held-out 10 %':>13} "
          f"{'refused':>7} {'tests/windows':>13} {'median worst err':>16}")
    totals = {"within5": 0, "covered": 0, "held10": 0, "n": 0, "base_within5": 0, "base_covered": 0, "base_held10": 0}
    timing_cases = []
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        for family in args.families.split(","):
            for relay in args.relays.split(","):
                rows = [one_recording(family, relay, rng, Path(d), args.baseline) for _ in range(args.n)]
                ok = {k: sum(bool(r[k]) for r in rows) for k in ("within5", "covered", "held10")}
                refused = sum(bool(r["refused"]) for r in rows)
                tw = f"{sum(r.get('n_tests', 0) for r in rows)}/{sum(r.get('n_windows', 0) for r in rows)}"
                worst = np.median([r["worst"] for r in rows if "worst" in r]) if refused < len(rows) else float("nan")
                print(f"{family:<7} {relay:<11} {ok['within5']:>7}/{args.n:<2} {ok['covered']:>8}/{args.n:<2} "
                      f"{ok['held10']:>10}/{args.n:<2} {refused:>7} {tw:>13} {100 * worst:>15.1f}%")
                for r in rows:
                    if r["refused"]:
                        print(f"    refused: {r['refused']}")
                if args.baseline:
                    _print_baseline(rows, args.n, totals)
                for k in ("within5", "covered", "held10"):
                    totals[k] += ok[k]
                totals["n"] += args.n
                timing_cases += [(r["model"], r["points"]) for r in rows if r["points"]]
    n = totals["n"]
    print(f"all: within 5 % {totals['within5']}/{n} ({100 * totals['within5'] / n:.0f} %), "
          f"95 % intervals cover {totals['covered']}/{n} ({100 * totals['covered'] / n:.0f} %), "
          f"held-out frequency within 10 % {totals['held10']}/{n} ({100 * totals['held10'] / n:.0f} %); "
          f"{time.perf_counter() - t_start:.0f} s")
    if args.baseline:
        print(f"  free line (baseline, same recordings): within 5 % {totals['base_within5']}/{n}, "
              f"95 % intervals cover {totals['base_covered']}/{n}, held-out within 10 % {totals['base_held10']}/{n}")
    times = _time_calls(fit_response_points, timing_cases)
    _print_timing(times)


def _print_baseline(rows: list[dict[str, object]], n: int, totals: dict[str, int]) -> None:
    """The same recordings' scores with the per-cycle free line, and K's median error under both fits."""
    base = {k: sum(bool(r.get(f"base_{k}")) for r in rows) for k in ("within5", "covered", "held10")}
    for k, v in base.items():
        totals[f"base_{k}"] += v
    k_now = np.median([r["K_err"] for r in rows if "K_err" in r]) if any("K_err" in r for r in rows) else math.nan
    k_base = (np.nanmedian([r["base_K_err"] for r in rows if "base_K_err" in r])
              if any("base_K_err" in r for r in rows) else math.nan)
    print(f"{'':<7} {'free line':<11} {base['within5']:>7}/{n:<2} {base['covered']:>8}/{n:<2} "
          f"{base['held10']:>10}/{n:<2}   median K error {100 * k_now:+.2f} % (free line {100 * k_base:+.2f} %)")


#: the routes timed, each as the response-point fit with a set of its fast paths switched off (same process)
ROUTES = ("closed form", "library")


def _print_timing(times: dict[str, dict[str, list[float]]]) -> None:
    now = times["closed form"]
    print("response-point fit per call (median over the recordings' response points; best of 5 calls each, the routes "
          "interleaved): " + ", ".join(f"{f} {1e3 * np.median(v):.2f} ms" for f, v in now.items()))
    labels = {"library": "the library route (a model object per grid point, scipy least_squares)"}
    for route, label in labels.items():
        print(f"  {label}: " + ", ".join(f"{f} {1e3 * np.median(v):.2f} ms ({np.median(v) / np.median(now[f]):.1f}x)"
                                         for f, v in times[route].items()))


def _time_calls(fit, cases) -> dict[str, dict[str, list[float]]]:
    """Per route and family, each recording's best of 5 calls [s]; the routes alternate per recording,
    so a shared machine's load falls on all of them alike."""
    per_route: dict[str, dict[str, list[float]]] = {r: {} for r in ROUTES}
    for model, points in cases:
        for route in ROUTES:
            with _route(route):
                best = math.inf
                for _ in range(5):
                    t0 = time.perf_counter()
                    fit(points, model)
                    best = min(best, time.perf_counter() - t0)
            per_route[route].setdefault(model.family, []).append(best)
    return per_route


@contextlib.contextmanager
def _route(route: str):
    """The response-point fit with its fast path switched off for ``route`` "library": without the families'
    closed-form kernel (mrft/lti_kernel.py) and the hand-written Levenberg-Marquardt (a model object per grid
    point, scipy's least_squares: the first implementation, and what a declared structure takes)."""
    from mrftcli.mrft.lti_kernel import LagChainKernel

    of = LagChainKernel.__dict__["of"]
    try:
        if route != "closed form":
            LagChainKernel.of = classmethod(lambda cls, *a, **k: None)  # type: ignore[method-assign]
        yield
    finally:
        LagChainKernel.of = of  # type: ignore[method-assign]


if __name__ == "__main__":
    main()
