"""Benchmark: :func:`mrftcli.mrft.waveform.response_basis` (the output-error refinement's inner call) against the
version it replaces, on the windows ``analyze`` really evaluates.

``analyze`` runs on sample logs (default: the PX4 SITL roll and x logs, whose refinements and Tp check evaluate
this thousands of times); every ``--every``-th call's arguments are kept. Both versions then run on the same
arguments in this process: the columns, modes and pulses must be equal element for element (printed: ``same``),
and the CPU per call of each is printed with their ratio. The old version is kept below verbatim (complex
accumulators, the window's indexing inside the modes' loop, lam^j at every grid tick).

Run: ``python benchmarks/bench_response_basis.py [--logs LOG:TP:LOOP ...] [--every 5]`` (about a minute).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import time
from pathlib import Path

import mrftcli.cli  # noqa: F401  (first: BLAS single-threaded, as the command line runs it)
import numpy as np
from scipy import signal

from mrftcli.errors import InputError
from mrftcli.mrft import refine, waveform
from mrftcli.mrft.waveform import ResponseBasis, _phi

ROOT = Path(__file__).resolve().parents[1]
LOGS = ("sample_logs/sitl/px4_roll.ulg:0.05:roll", "sample_logs/sitl/px4_x.ulg:0.05:x",
        "sample_logs/design1_altitude.mcap:0.0422:altitude")


def old_response_basis(A, B, C, tau: float, window) -> ResponseBasis:
    """The previous :func:`~mrftcli.mrft.waveform.response_basis`, verbatim."""
    A_ = np.asarray(A, float)
    mu, V = np.linalg.eig(A_)
    if np.linalg.cond(V) > 1e8:
        scale = max(float(np.max(np.abs(mu))), 1e-12)
        mu, V = np.linalg.eig(A_ + np.diag(1e-7 * scale * np.arange(A_.shape[0])))
    Vinv = np.linalg.inv(V)
    beta = Vinv @ np.asarray(B, float)
    c = np.asarray(C, float) @ V
    dt = window.dt
    d = int(math.floor(tau / dt + 1e-12))
    f = min(max(tau / dt - d, 0.0), 1.0)
    n = window.u.size
    U = np.zeros((n, 1 + window.free.size))
    U[:, 0] = window.u
    U[window.free, 1 + np.arange(window.free.size)] = 1.0
    pad = np.zeros((d + 1, U.shape[1]))
    pad[:, 0] = window.u[0]
    ua = np.concatenate([pad, U])[:n]
    ub = np.concatenate([pad[1:], U])[:n]
    lam = np.exp(mu * dt)
    gb = beta * _phi(mu, (1.0 - f) * dt)
    ga = beta * np.exp(mu * (1.0 - f) * dt) * _phi(mu, f * dt)
    k, s = window.k, window.s
    m = k.size
    first = s <= f * dt
    s2 = np.where(first, 0.0, s - f * dt)
    es = np.exp(np.outer(s, mu))
    pa = np.where(first[:, None], _phi(mu[None, :], s[:, None]),
                  np.exp(np.outer(s2, mu)) * _phi(mu, f * dt)[None, :])
    pb = np.where(first[:, None], 0.0, _phi(mu[None, :], s2[:, None]))
    cols = np.zeros((m, 2 + mu.size), dtype=complex)
    forced = np.zeros((m, U.shape[1]), dtype=complex)
    jj = np.arange(n)
    for i in range(mu.size):
        zf = signal.lfilter([0.0, 1.0], [1.0, -lam[i]], ga[i] * ua + gb[i] * ub, axis=0)
        if abs(lam[i] - 1.0) < 1e-12:
            zs = (ga[i] + gb[i]) * jj
        else:
            zs = (ga[i] + gb[i]) * (1.0 - lam[i] ** jj) / (1.0 - lam[i])
        forced += c[i] * (es[:, i, None] * zf[k] + beta[i] * (pa[:, i, None] * ua[k] + pb[:, i, None] * ub[k]))
        cols[:, 1] += c[i] * (es[:, i] * zs[k] + beta[i] * (pa[:, i] + pb[:, i]))
        cols[:, 2 + i] = c[i] * es[:, i] * lam[i] ** k
    if np.iscomplexobj(mu) and np.any(np.abs(mu.imag) > 0):
        raise InputError("the plant has oscillatory modes; response_basis handles real eigenvalues only")
    cols[:, 0] = forced[:, 0]
    return ResponseBasis(columns=cols.real, modes=V.real, pulses=forced[:, 1:].real)


def captured(spec: str, every: int) -> list[tuple]:
    """Every ``every``-th call's arguments of ``analyze LOG --tp TP --loop LOOP``."""
    from mrftcli.cli.main import main

    log, tp, loop = spec.split(":")
    kept: list[tuple] = []
    count = [0]
    real = refine.response_basis

    def keep(*args):
        count[0] += 1
        if count[0] % every == 0:
            kept.append(args)
        return real(*args)

    refine.response_basis = keep
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            main(["analyze", str(ROOT / log), "--tp", tp, "--loop", loop, "-q"])
    except SystemExit:
        pass
    finally:
        refine.response_basis = real
    return kept


def _cpu(fn, calls: list[tuple], reps: int) -> float:
    t = time.process_time()
    for _ in range(reps):
        for a in calls:
            fn(*a)
    return (time.process_time() - t) / (reps * len(calls))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--logs", nargs="*", default=list(LOGS), help="LOG:TP:LOOP (paths from the repository root)")
    ap.add_argument("--every", type=int, default=5)
    ap.add_argument("--reps", type=int, default=3)
    a = ap.parse_args()
    total_new = total_old = 0.0
    for spec in a.logs:
        calls = captured(spec, a.every)
        same = all(np.array_equal(getattr(x, f), getattr(y, f))
                   for args in calls for x, y in [(waveform.response_basis(*args), old_response_basis(*args))]
                   for f in ("columns", "modes", "pulses"))
        new, old = _cpu(waveform.response_basis, calls, a.reps), _cpu(old_response_basis, calls, a.reps)
        total_new, total_old = total_new + new * len(calls), total_old + old * len(calls)
        shape = calls[0][4].u.size if calls else 0
        print(f"{spec:48s} {len(calls):4d} calls (~{shape} ticks): new {new * 1e3:.3f} ms, old {old * 1e3:.3f} ms "
              f"a call (ratio {old / new:.2f}x); outputs {'same' if same else 'DIFFER'}")
    print(f"all calls: ratio {total_old / total_new:.2f}x")


if __name__ == "__main__":
    main()
