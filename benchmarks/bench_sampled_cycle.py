"""Benchmark: the sampled relay's exact orbits at fast controller rates (1-20 kHz), and tune's MRFT rule on them.

The sampled limit cycle (:func:`mrftcli.mrft.lprs.sampled_limit_cycle`) solves, for each half period N [ticks]
near the cycle, the periodic orbit of the loop discretised exactly. Its plant used to carry the delay's whole
ticks as a command buffer in its state (:func:`mrftcli.mrft.cascade.delayed_discrete`: 604 states for 60 ms at
10 kHz), so each orbit cost O(states^3) and the MRFT rule on checks.md's example took 3.8 s at 10 kHz and 22 s at
20 kHz. It now shifts the orbit of the plant with the delay's fraction only by those ticks
(:func:`mrftcli.mrft.cascade.fraction_discrete`, ``orbits(..., shift=d)``).

Printed per rate: CPU [s] of the orbit search over sampled_limit_cycle's window by the old (buffered) and the new
(shifted) realisation, in this process, their ratio and the largest relative difference of the orbits' switch
margins and amplitudes; then ``mrft_rule``'s CPU and its T0 / a0 against the continuous relay's (checks.md
section 1: 1.01884 Hz, a0 0.035602).

Run: ``python benchmarks/bench_sampled_cycle.py [--rates 1000,2500,5000,10000,20000] [--old-max-hz 10000]``
(the old path above --old-max-hz is skipped: 26 s at 20 kHz).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from mrftcli.mrft.cascade import delayed_discrete, fraction_discrete, orbits
from mrftcli.mrft.lprs import mrft_limit_cycle
from mrftcli.mrft.model import LoopModel
from mrftcli.tune.design import mrft_rule

#: checks.md section 1: 1/(s(0.1 s + 1)(0.7042 s + 1)) with 60 ms delay, beta -0.7
MODEL = LoopModel(0.1, 0.7042, 0.06, 1 / 0.7042)
BETA = -0.7
F_CONT, A_CONT = 1.01884, 0.035602


def _cpu(fn, *args, **kwargs):  # type: ignore[no-untyped-def]
    t = time.process_time()
    out = fn(*args, **kwargs)
    return out, time.process_time() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rates", default="1000,2500,5000,10000,20000", help="controller rates [Hz], comma-separated")
    ap.add_argument("--old-max-hz", type=float, default=10000.0, help="skip the old path above this rate [Hz]")
    args = ap.parse_args()
    ss = MODEL.realisation()
    print(f"{'rate [Hz]':>9} {'states old/new':>14} {'old [s]':>8} {'new [s]':>8} {'ratio':>7} {'max rel diff':>12} "
          f"{'mrft_rule [s]':>13} {'T0 vs cont.':>11} {'a0 vs cont.':>11}")
    for rate in (float(r) for r in args.rates.split(",")):
        lc = mrft_limit_cycle(MODEL, BETA, 1.0, rate_hz=rate)
        n_mid = rate / (2 * lc.frequency_hz)
        lo, hi = max(2, math.floor(n_mid) - 6), math.ceil(n_mid) + 6  # sampled_limit_cycle's first window
        small, d = fraction_discrete(ss, MODEL.delay, rate)
        new, t_new = _cpu(orbits, small, BETA, 1.0, lo, hi, shift=d)
        old_txt, ratio_txt, diff_txt = "-", "-", "-"
        states_old = ss.order + 1 + d
        if rate <= args.old_max_hz:
            old, t_old = _cpu(orbits, delayed_discrete(ss, MODEL.delay, rate), BETA, 1.0, lo, hi)
            ok = np.isfinite(old.at_end)
            diff = max(float(np.max(np.abs(new.at_end[ok] / old.at_end[ok] - 1))),
                       float(np.max(np.abs(new.amplitude / old.amplitude - 1))))
            assert np.array_equal(new.valid, old.valid)
            old_txt, ratio_txt, diff_txt = f"{t_old:.3f}", f"{t_old / max(t_new, 1e-6):.0f}x", f"{diff:.1e}"
        (c, cyc), t_rule = _cpu(mrft_rule, MODEL, rate)
        print(f"{rate:>9g} {f'{states_old}/{small.order}':>14} {old_txt:>8} {t_new:>8.3f} {ratio_txt:>7} {diff_txt:>12} "
              f"{t_rule:>13.3f} {cyc['T0'] * F_CONT - 1:>+11.1e} {cyc['a0'] / A_CONT - 1:>+11.1e}")


if __name__ == "__main__":
    main()
