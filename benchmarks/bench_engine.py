"""Benchmarks of the engine (issue 2): speed, the paper's sensitivity study, sampling, DF vs LPRS.

Run:  python benchmarks/bench_engine.py [--quick]
Prints every figure; docs/benchmarks/engine.md records a run.
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mrftcli.mrft.model import soiptd_model
from mrftcli.mrft.describing import describing_function_limit_cycle
from mrftcli.mrft.identify import TestMeasurement, identify, intersection_draws
from mrftcli.mrft.lprs import mrft_limit_cycle, unit_cycle, unit_cycle_scalar
from mrftcli.mrft.model import LoopModel
from mrftcli.mrft.ufm import SHIPPED_BETAS, build_manifold, build_manifolds, load_manifolds, save_manifold

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from relay_rule import relay_step  # noqa: E402 - the checks.md rule, independent of mrftcli.sim

PAPER = LoopModel(Tp=0.1, Td=1 / 1.42, tau=0.06, K=1.42)


def _median_time(fn, reps: int) -> float:
    """Median wall time [s]; also remembers the median CPU time (the machine may be shared)."""
    fn()
    ts, cs = [], []
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    _median_time.cpu = statistics.median(cs)
    return statistics.median(ts)


def bench_speed(reps: int) -> None:
    print("== speed ==")
    f = {b: mrft_limit_cycle(PAPER, b).frequency_hz for b in (-0.4, -0.7)}
    tests = [TestMeasurement(b, f[b]) for b in f]
    load_manifolds()
    t_id = _median_time(lambda: identify(tests, soiptd_model(PAPER.Tp)), reps)
    print(f"identify, two tests, point estimate: median {t_id * 1e3:.3f} ms wall, {_median_time.cpu * 1e3:.3f} ms CPU "
          f"(target <= 1 ms; paper 100 ms -> {0.1 / t_id:.0f}x faster)")
    rng = np.random.default_rng(0)
    noisy = [TestMeasurement(b, f[b] * (1 + 0.01 * rng.standard_normal(20))) for b in f]
    t_mc = _median_time(lambda: identify(noisy, soiptd_model(PAPER.Tp), n_draws=2000), max(3, reps // 100))
    print(f"identify, two tests + 2000-draw Monte Carlo uncertainty: median {t_mc * 1e3:.1f} ms")
    t_pred = _median_time(lambda: mrft_limit_cycle(PAPER, -0.4), max(5, reps // 20))
    print(f"mrft_limit_cycle (exact, closed form): median {t_pred * 1e3:.2f} ms")
    t_one = _median_time(lambda: build_manifold(-0.4), 3)
    print(f"one beta manifold, shipped resolution 201 x 201: median {t_one:.3f} s wall, {_median_time.cpu:.3f} s CPU "
          "(target <= 3 s)")
    t0, c0 = time.perf_counter(), time.process_time()
    ms = build_manifolds(SHIPPED_BETAS)
    with tempfile.TemporaryDirectory() as d:
        for m in ms:
            save_manifold(m, d)
    t_all, c_all = time.perf_counter() - t0, time.process_time() - c0
    print(f"full shipped set ({len(SHIPPED_BETAS)} betas, built + saved): {t_all:.2f} s wall, {c_all:.2f} s CPU "
          "(target <= 60 s)")
    print(f"machine load average at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


def bench_scalar(n: int) -> None:
    """Why unit_cycle_scalar exists: root finders evaluate one point per call."""
    print("== unit cycle, one point per call (as in the identifier's root finders) ==")
    rng = np.random.default_rng()  # fresh points each run
    tp_n = np.exp(rng.uniform(np.log(0.05), np.log(2.0), n))
    td_n = np.exp(rng.uniform(np.log(0.5), np.log(50.0), n))
    beta = rng.uniform(-0.9, -0.1, n)
    pts = list(zip(tp_n.tolist(), td_n.tolist(), beta.tolist()))

    def scalar() -> None:
        for p in pts:
            unit_cycle_scalar(*p)

    # a root finder's sequence: slowly changing arguments (Td along a bracket), cold and warm-started
    seq = [(0.4, float(t), -0.4) for t in np.geomspace(2.0, 2.2, n) * rng.uniform(0.9, 1.1)]

    def cold() -> None:
        for p in seq:
            unit_cycle_scalar(*p)

    def warm() -> None:
        w: list = []
        for p in seq:
            unit_cycle_scalar(*p, w)

    def vector_per_call() -> None:
        for p in pts:
            unit_cycle(*p)

    def vector_batch() -> None:
        unit_cycle(tp_n, td_n, beta)

    t_s = _median_time(scalar, 5) / n
    t_c = _median_time(cold, 5) / n
    t_w = _median_time(warm, 5) / n
    t_v = _median_time(vector_per_call, 5) / n
    t_b = _median_time(vector_batch, 5) / n
    print(f"unit_cycle_scalar, per call: {t_s * 1e6:.1f} us; along a slowly changing sequence "
          f"{t_c * 1e6:.1f} us cold, {t_w * 1e6:.1f} us warm-started ({t_c / t_w:.1f}x)")
    print(f"unit_cycle (numpy) on one point per call: {t_v * 1e6:.1f} us -> scalar is {t_v / t_s:.1f}x faster")
    print(f"unit_cycle (numpy) on all {n} points at once: {t_b * 1e6:.2f} us per point "
          f"(the vectorised form wins when the points are known in advance)")


def bench_sensitivity(n: int) -> None:
    print("== paper's sensitivity study (checks.md section 1): 3 % white noise on the frequencies ==")
    rng = np.random.default_rng(2024)
    betas = (-0.4, -0.7)
    lcs = {b: mrft_limit_cycle(PAPER, b) for b in betas}
    w = np.array([2 * math.pi * lcs[b].frequency_hz for b in betas])
    wd = w[None, :] * (1 + 0.03 * rng.standard_normal((n, 2)))
    ms = load_manifolds()
    t0 = time.perf_counter()
    Td = intersection_draws(PAPER.Tp, list(betas), wd, ms, PAPER.Td)
    el = time.perf_counter() - t0
    ok = np.isfinite(Td)
    th, _ = unit_cycle(PAPER.Tp * wd[ok, 0], Td[ok] * wd[ok, 0], betas[0])
    tau = th / wd[ok, 0]
    Td = Td[ok]
    phys = tau >= 0
    print(f"{n} draws in {el:.2f} s; {ok.mean() * 100:.1f} % admit an intersection, "
          f"{phys.mean() * 100:.1f} % of those with tau >= 0")
    print(f"{'':>10} {'ours mean':>10} {'ours std':>9} {'bias':>8} {'median':>8} {'paper mean':>10} {'paper std':>9}")
    for name, v, true, pm, ps in (("Td [s]", Td, PAPER.Td, 0.6404, 0.1956), ("tau [s]", tau, PAPER.tau, 0.0679, 0.0168)):
        print(f"{name:>10} {v.mean():10.4f} {v.std(ddof=1):9.4f} {v.mean() - true:+8.4f} {np.median(v):8.4f} "
              f"{pm:10.4f} {ps:9.4f}")
    print(f"(truth Td = {PAPER.Td:.4f} s, tau = {PAPER.tau:.4f} s)")
    # amplitude (UGM) route at beta -0.7 alone, K known: 3 % on frequency and amplitude
    lc = lcs[-0.7]
    m = max(200, n // 10)
    fd = lc.frequency_hz * (1 + 0.03 * rng.standard_normal(m))
    ad = lc.amplitude * (1 + 0.03 * rng.standard_normal(m))
    Tds, taus = [], []
    for f_, a_ in zip(fd, ad):
        try:
            r = identify([TestMeasurement(-0.7, f_, a_, 1.0)], soiptd_model(PAPER.Tp, K=PAPER.K))
        except Exception:  # noqa: BLE001 - draws without a solution are counted
            continue
        Tds.append(r.Td.value)
        taus.append(r.tau.value)
    Tds, taus = np.array(Tds), np.array(taus)
    print(f"amplitude route, beta -0.7 alone ({len(Tds)}/{m} draws solvable): Td mean {Tds.mean():.3f} s "
          f"(std {Tds.std(ddof=1):.3f}, median {np.median(Tds):.3f}), tau mean {taus.mean():.4f} s "
          f"(std {taus.std(ddof=1):.4f}); paper: Td 0.39 s (std 0.089), tau 0.12 s")


def bench_sampling() -> None:
    print("== sampled relay: what the controller rate does to tau ==")
    betas = (-0.4, -0.7)
    print(f"{'rate':>6} {'orbits/beta':>11} {'tau naive':>10} {'tau corrected':>13} {'tau range over orbits (corrected)':>34}")
    for rate in (100.0, 200.0, 500.0):
        lcs = {b: mrft_limit_cycle(PAPER, b, rate_hz=rate) for b in betas}
        tests = [TestMeasurement(b, lcs[b].frequency_hz) for b in betas]
        naive = identify(tests, soiptd_model(PAPER.Tp)).tau.value
        corr = identify(tests, soiptd_model(PAPER.Tp), rate_hz=rate).tau.value
        taus = []
        for f1, f2 in itertools.product(lcs[-0.4].orbits_hz, lcs[-0.7].orbits_hz):
            try:
                taus.append(identify([TestMeasurement(-0.4, f1), TestMeasurement(-0.7, f2)], soiptd_model(PAPER.Tp),
                                     rate_hz=rate).tau.value)
            except Exception:  # noqa: BLE001
                pass
        n_orb = "/".join(str(len(lcs[b].orbits_hz)) for b in betas)
        print(f"{rate:6.0f} {n_orb:>11} {naive * 1e3:8.2f}ms {corr * 1e3:11.2f}ms "
              f"{min(taus) * 1e3:14.1f} .. {max(taus) * 1e3:.1f} ms  (truth 60 ms)")


def _noisy_sampled_frequency(model: LoopModel, beta: float, rate: float, noise: float, cycles: int, seed: int) -> float:
    """Long-run mean frequency of a sampled MRFT with white measurement noise (plain fine-step loop)."""
    from scipy import linalg

    rng = np.random.default_rng(seed)
    sub = 10
    dt = 1.0 / rate / sub
    nd = round(model.tau / dt)
    A, B, _ = model.state_space()
    M = np.zeros((4, 4))
    M[:3, :3], M[:3, 3] = A * dt, B * dt
    E = linalg.expm(M)
    Phi, Gam = E[:3, :3], E[:3, 3]
    x = np.array([-0.05, 0.0, 0.0])
    u, e_ext, buf, ups = 1.0, 0.0, [1.0] * (nd + 1), []
    period_guess = 1.0 / mrft_limit_cycle(model, beta).frequency_hz
    for k in range(int(cycles * period_guess / dt)):
        if k % sub == 0:
            e = -(x[0] + noise * rng.standard_normal())
            if k == 0:
                e_ext = e
            else:
                was, (u, e_ext) = u, relay_step(u, e_ext, e, beta)
                if u > was:
                    ups.append(k * dt)
        buf.append(u)
        x = Phi @ x + Gam * buf.pop(0)
    ups = np.array(ups)
    ups = ups[ups > 10 * period_guess]
    return (ups.size - 1) / (ups[-1] - ups[0])


def bench_sampled_noise() -> None:
    print("== sampled relay with measurement noise (paper plant, K Td = 1, 200 Hz, 150 cycles) ==")
    for beta in (-0.4, -0.7):
        lc = mrft_limit_cycle(PAPER, beta, rate_hz=200.0)
        for noise in (0.0, 2e-4):
            f = _noisy_sampled_frequency(PAPER, beta, 200.0, noise, 150, 0)
            print(f"beta {beta:+.1f} noise {noise:.0e}: mean {f:.5f} Hz, band centre {lc.frequency_hz:.5f} Hz "
                  f"({100 * (f / lc.frequency_hz - 1):+.2f} %), orbits {', '.join(f'{o:.4f}' for o in lc.orbits_hz)}")


def bench_df() -> None:
    print("== describing function vs exact LPRS on the paper's example (K Td = 1, h = 1) ==")
    print(f"{'beta':>6} {'LPRS f [Hz]':>11} {'DF f [Hz]':>10} {'DF err':>7} {'LPRS a':>9} {'DF a':>9} {'DF err':>7}")
    for b in (-0.9, -0.7, -0.4, -0.1):
        lc = mrft_limit_cycle(PAPER, b)
        f, a = describing_function_limit_cycle(PAPER, b)
        print(f"{b:6.1f} {lc.frequency_hz:11.5f} {f:10.5f} {100 * (f / lc.frequency_hz - 1):+6.1f}% "
              f"{lc.amplitude:9.6f} {a:9.6f} {100 * (a / lc.amplitude - 1):+6.1f}%")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer repetitions and draws")
    args = ap.parse_args()
    bench_speed(200 if args.quick else 1000)
    bench_scalar(500 if args.quick else 2000)
    bench_sensitivity(2000 if args.quick else 20000)
    bench_sampling()
    bench_sampled_noise()
    bench_df()


if __name__ == "__main__":
    main()
