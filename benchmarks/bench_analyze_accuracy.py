"""Benchmark: accuracy of ``analyze`` against an output-error baseline and the Cramer-Rao bound.

Fresh random plants every run (the seed is printed; ``--seed`` repeats one): Tp 0.02-0.1 s, Td
0.3-3 s, tau 10-100 ms, K 0.5-20, loop altitude/roll/pitch, controller 100-500 Hz, sensor noise
0.2-1 mm (altitude) / 0.05-0.2 deg (roll, pitch), 2 or 3 tests (betas from -0.3 .. -0.8), the project's
simulator (HEAR switching rule). On each plant, side by side:

* ``analyze``: :func:`mrftcli.analyze.analyze_flight` as the CLI runs it (the MRFT consensus, then the
  waveform refinement when the data accept it); its MRFT estimate (``parameters_mrft``) is printed too.
* the baseline a control engineer would use (MATLAB ``tfest``/``procest`` style): an output-error fit
  of eq. (2) by :func:`mrftcli.mrft.refine.fit_output_error` (exact ZOH discretisation, fractional
  delay, Tp known, a free initial state and trim per test) on the same test windows, from generic
  starts (Td 0.5 / 2 s x tau 20 / 60 ms, K 1), the best residual kept.
* the Cramer-Rao bound: sigma^2 (J^T J)^-1 at the truth with the true noise sigma, J the Jacobian of
  the output with the nuisance parameters projected out (the bound with them unknown).

Prints the RMS errors (tau [ms], K [%], Td [%]), the ratios analyze / baseline and analyze / bound, the
coverage of analyze's 95 % intervals, how often the refinement was accepted, and the cost the
refinement adds per 2-test log at 200 Hz (median of repeated runs, ``analyze_flight`` with and without
it, in the same process). Run: ``python benchmarks/bench_analyze_accuracy.py [--n 20] [--seed S]``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from test_segment_support import flight_from_simulated  # noqa: E402

from mrftcli.mrft.model import soiptd_model  # noqa: E402
from mrftcli.analyze import AnalyzeOptions, analyze_flight  # noqa: E402
from mrftcli.mrft.model import LoopModel  # noqa: E402
from mrftcli.mrft.refine import fit_output_error, loop_model_plant, refinement_windows  # noqa: E402
from mrftcli.mrft.waveform import response_basis  # noqa: E402
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight  # noqa: E402


def draw_plant(rng):
    loop = str(rng.choice(["altitude", "roll", "pitch"]))
    Tp = float(np.exp(rng.uniform(np.log(0.02), np.log(0.1))))
    Td = float(np.exp(rng.uniform(np.log(0.3), np.log(3.0))))
    tau = float(rng.uniform(0.01, 0.1))
    K = float(np.exp(rng.uniform(np.log(0.5), np.log(20.0))))
    rate = float(rng.choice([100.0, 200.0, 250.0, 400.0, 500.0]))
    noise = float(rng.uniform(0.2e-3, 1e-3)) if loop == "altitude" else float(np.deg2rad(rng.uniform(0.05, 0.2)))
    n_tests = int(rng.integers(2, 4))
    betas = tuple(float(b) for b in np.sort(rng.uniform(-0.8, -0.3, n_tests))[::-1])
    if n_tests == 2 and betas[0] - betas[1] < 0.15:
        betas = (-0.35, -0.7)
    return loop, LoopModel(Tp, Td, tau, K), rate, noise, betas


def simulate(loop, model, rate, noise, betas, seed):
    amp = 0.05 if loop == "altitude" else np.deg2rad(10.0)
    tests = tuple(plan_test(model, b, amp, cycles=10, min_duration=4.0) for b in betas)
    spec = FlightSpec(model=model, tests=tests, loop=loop, switching="hear", seed=seed, noise_std=noise,
                      rate_hz=rate)
    return flight_from_simulated(simulate_flight(spec))


def windows_of(result):
    """The windows analyze refines on (each test's outputs, its commands from 1 s before)."""
    fl = result.flight
    return refinement_windows(result.tests, fl.command.t, fl.command.values, fl.output.t, fl.output.values)


def baseline(windows, Tp, sign):
    plant = loop_model_plant(Tp)
    best = None
    for Td0 in (0.5, 2.0):
        for tau0 in (0.02, 0.06):
            try:
                f = fit_output_error(windows, plant, [math.log(Td0), tau0, sign * 1.0], lower=[math.log(Tp * 1e-2), 0.0, -np.inf],
                                     upper=[math.log(1e6), 1.0, np.inf], max_evaluations=200)
            except Exception:  # noqa: BLE001 - a failed start is just a worse start
                continue
            if best is None or f.residual_rms < best.residual_rms:
                best = f
    return math.exp(best.p[0]), float(best.p[1]), abs(float(best.p[2]))


def crb(windows, model, sign, sigma):
    """Cramer-Rao std of (ln Td, tau, K) at the truth (nuisance parameters projected out)."""
    plant = loop_model_plant(model.Tp)

    def proj(p):
        A, B, C, tau = plant(p)
        out = []
        for w in windows:
            cols = response_basis(A, B, C, tau, w).columns
            X = cols[:, 1:]
            q, _ = np.linalg.qr(X)
            y = cols[:, 0]
            out.append(y - q @ (q.T @ y))
        return np.concatenate(out)

    p0 = np.array([math.log(model.Td), model.tau, sign * model.K])
    steps = np.array([1e-5, 1e-7, 1e-5 * abs(model.K)])
    r0 = proj(p0)
    J = np.stack([(proj(p0 + np.eye(3)[i] * steps[i]) - r0) / steps[i] for i in range(3)], axis=1)
    return np.sqrt(np.diag(sigma ** 2 * np.linalg.inv(J.T @ J)))


def cost(n_repeats=5, seed=1):
    model = LoopModel(0.0422, 2.669, 0.0464, 19.6)
    fl = simulate("altitude", model, 200.0, 5e-4, (-0.4, -0.7), seed)
    t_with, t_without = [], []
    for _ in range(n_repeats):
        t0 = time.perf_counter()
        analyze_flight(fl, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=200, refine_waveform=False))
        t_without.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        r = analyze_flight(fl, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=200))
        t_with.append(time.perf_counter() - t0)
    return float(np.median(t_with)), float(np.median(t_without)), r.refinement.fit.n_evaluations


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=None)
    a = ap.parse_args()
    seed = a.seed if a.seed is not None else int(time.time()) % 100000
    print(f"seed {seed}, {a.n} plants")
    rng = np.random.default_rng(seed)
    rows = []
    while len(rows) < a.n:
        loop, model, rate, noise, betas = draw_plant(rng)
        try:
            fl = simulate(loop, model, rate, noise, betas, int(rng.integers(1 << 30)))
            r = analyze_flight(fl, soiptd_model(model.Tp), options=AnalyzeOptions(n_bootstrap=200))
        except Exception as exc:  # noqa: BLE001 - a refused flight is counted, not fatal
            print(f"  skipped ({type(exc).__name__}: {str(exc)[:90]})")
            continue
        ws = windows_of(r)
        sign = r.tests[0].loop_sign
        b = baseline(ws, model.Tp, sign)
        c = crb(ws, model, sign, noise)
        m = r.parameters_mrft
        err = lambda td, tau, k: (100 * (td / model.Td - 1), 1e3 * (tau - model.tau), 100 * (k / model.K - 1))  # noqa: E731, B023 (used in this iteration)
        cover = [r.Td.ci95_low <= model.Td <= (r.Td.ci95_high if math.isfinite(r.Td.ci95_high) else np.inf),
                 r.tau.ci95_low <= model.tau <= r.tau.ci95_high, r.K.ci95_low <= model.K <= r.K.ci95_high]
        td_omega = model.Td * 2 * math.pi * max(t.frequency_hz_mean for t in r.tests)
        rows.append(dict(analyze=err(r.Td.value, r.tau.value, r.K.value), mrft=err(m["Td"].value, m["tau"].value, m["K"].value),
                         base=err(*b), crb=(100 * c[0], 1e3 * c[1], 100 * c[2] / model.K), cover=cover,
                         method=r.method, ratio=r.refinement.residual_ratio if r.refinement else float("nan"),
                         # per-plant error in bound units (ln Td, so that the Td bound's coordinate is used)
                         z=(math.log(r.Td.value / model.Td) / c[0], (r.tau.value - model.tau) / c[1],
                            (r.K.value - model.K) / c[2]), td_omega=td_omega))
        e = rows[-1]
        print(f"  {loop:8s} {rate:5.0f} Hz {len(betas)} tests Td {model.Td:5.2f} (Td Omega {td_omega:5.1f}) tau "
              f"{model.tau * 1e3:5.1f} ms  {r.method:8s} ratio {e['ratio']:.3f}  error/bound Td {e['z'][0]:+.2f} "
              f"tau {e['z'][1]:+.2f} K {e['z'][2]:+.2f}")

    def rms(key, i):
        return float(np.sqrt(np.mean([row[key][i] ** 2 for row in rows])))

    print(f"\nRMS error over {len(rows)} plants       tau [ms]   K [%]    Td [%]")
    for key, label in (("analyze", "analyze (as reported)"), ("mrft", "analyze, MRFT estimate"),
                       ("base", "output-error baseline"), ("crb", "Cramer-Rao bound")):
        print(f"  {label:<28} {rms(key, 1):8.4f} {rms(key, 2):8.4f} {rms(key, 0):8.3f}")
    print(f"  {'ratio analyze / baseline':<28} {rms('analyze', 1) / rms('base', 1):8.2f} "
          f"{rms('analyze', 2) / rms('base', 2):8.2f} {rms('analyze', 0) / rms('base', 0):8.2f}")
    print(f"  {'ratio analyze / bound':<28} {rms('analyze', 1) / rms('crb', 1):8.2f} "
          f"{rms('analyze', 2) / rms('crb', 2):8.2f} {rms('analyze', 0) / rms('crb', 0):8.2f}")
    # how well this many plants pin that ratio down: resample the plants (90 % interval)
    ea = np.array([row["analyze"] for row in rows])
    eb = np.array([row["crb"] for row in rows])
    pick = np.random.default_rng(seed).integers(0, len(rows), size=(2000, len(rows)))
    boot = np.sqrt((ea[pick] ** 2).mean(axis=1) / (eb[pick] ** 2).mean(axis=1))
    lo, hi = np.percentile(boot, [5, 95], axis=0)
    print(f"  {'  90 % interval (plants resampled)':<28} {lo[1]:.2f}-{hi[1]:.2f} {lo[2]:.2f}-{hi[2]:.2f} {lo[0]:.2f}-{hi[0]:.2f}")
    # The ratio of RMS errors is dominated by the few plants with the widest bound (Td Omega large);
    # the error in units of each plant's own bound weighs every plant alike: its RMS is the
    # efficiency (1 at the bound), its mean a bias, its median |z| / 0.674 a tail-proof RMS.
    z = np.array([row["z"] for row in rows])
    n = len(rows)
    print(f"\nerror / bound per plant (z)          tau      K       Td      (1 at the bound; sampling error "
          f"+-{1 / math.sqrt(2 * n):.2f} on the RMS, +-{1 / math.sqrt(n):.2f} on the mean)")
    print(f"  {'RMS z':<32} {np.sqrt(np.mean(z[:, 1] ** 2)):6.2f} {np.sqrt(np.mean(z[:, 2] ** 2)):6.2f} "
          f"{np.sqrt(np.mean(z[:, 0] ** 2)):6.2f}")
    print(f"  {'median |z| / 0.674':<32} {np.median(np.abs(z[:, 1])) / 0.6745:6.2f} "
          f"{np.median(np.abs(z[:, 2])) / 0.6745:6.2f} {np.median(np.abs(z[:, 0])) / 0.6745:6.2f}")
    print(f"  {'mean z (bias)':<32} {z[:, 1].mean():+6.2f} {z[:, 2].mean():+6.2f} {z[:, 0].mean():+6.2f}")
    big = np.array([row["td_omega"] > 5 for row in rows])
    for label, sel in (("Td Omega <= 5", ~big), ("Td Omega > 5", big)):
        if sel.any():
            print(f"  {'RMS z, ' + label + f' ({int(sel.sum())})':<32} {np.sqrt(np.mean(z[sel, 1] ** 2)):6.2f} "
                  f"{np.sqrt(np.mean(z[sel, 2] ** 2)):6.2f} {np.sqrt(np.mean(z[sel, 0] ** 2)):6.2f}")
    cov = np.array([row["cover"] for row in rows], float).mean(axis=0)
    print(f"95 % interval coverage (Td, tau, K): {cov[0]:.2f} {cov[1]:.2f} {cov[2]:.2f}; refinement accepted on "
          f"{sum(row['method'] == 'waveform' for row in rows)}/{len(rows)} (residual/noise "
          f"{min(row['ratio'] for row in rows):.3f}-{max(row['ratio'] for row in rows):.3f})")
    w, wo, nfev = cost()
    print(f"cost per 2-test log at 200 Hz (median of 5): analyze {w:.3f} s with the refinement, {wo:.3f} s without: "
          f"+{w - wo:.3f} s ({nfev} evaluations)")


if __name__ == "__main__":
    main()
