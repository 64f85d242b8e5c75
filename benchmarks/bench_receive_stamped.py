"""Receive-stamped topics with dropped messages: as accurate as the same flights stamped at the source?

Fresh random altitude plants (Td 1-3 s, tau 20-80 ms, K 10-25, Tp 42.2 ms) flown as people fly them:
a 100 or 200 Hz controller (HEAR switching), two tests per flight at two betas (-0.6 and -0.3) and
two relay heights (describing-function amplitudes 3-8 cm, drawn per test), 6-10 cycles each (drawn),
sensor noise 0.3-1 mm. Each flight is recorded (mrftcli/sim/stamps.py, no file written):

* ``source``: both topics stamped at the source, every message (the baseline);
* ``recv``: both topics stamped on arrival, each message 0-3 ms late (uniform), none lost;
* ``cmd P``, ``out P``, ``both P``: both topics stamped on arrival (0-3 ms late) with P = 0.5, 1, 2, 5 %
  of the command's, the output's, or both topics' messages lost.

Every recording of a flight is analysed (``analyze_flight``, 200 draws) in the same process; a
refusal or failure counts as a miss (no error, not covered). Prints per setting the RMS error of
Td [%], tau [ms], K [%], the coverage of the 95 % intervals, how often the waveform estimate was
reported, refusals, and the RMS ratio to ``source`` on the same flights.
Usage: OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/bench_receive_stamped.py [SEED] [N] [SETTINGS]
(SETTINGS: comma-separated names, default all; one BLAS thread: on a busy shared machine a threaded
lstsq of a few thousand rows took 50x its single-thread time). Figures: docs/benchmarks/receive_stamped.md.
"""
import sys
import time

import numpy as np

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalyzeOptions, analyze_flight
from mrftcli.mrft.model import LoopModel
from mrftcli.sim.flight import FlightSpec, plan_test, simulate_flight
from mrftcli.sim.stamps import ReceiveStamping, recorded_flight

SEED = int(sys.argv[1]) if len(sys.argv) > 1 else 20261128
N = int(sys.argv[2]) if len(sys.argv) > 2 else 24
LATE = 0.003
DROPS = (0.005, 0.01, 0.02, 0.05)


def _settings() -> dict[str, tuple[ReceiveStamping | None, ReceiveStamping | None]]:
    out: dict[str, tuple[ReceiveStamping | None, ReceiveStamping | None]] = {
        "source": (None, None), "recv": (ReceiveStamping(LATE), ReceiveStamping(LATE))}
    for p in DROPS:
        lost, kept = ReceiveStamping(LATE, p), ReceiveStamping(LATE)
        out[f"cmd {p * 100:g}%"] = (lost, kept)
        out[f"out {p * 100:g}%"] = (kept, lost)
        out[f"both {p * 100:g}%"] = (lost, lost)
    return out


SETTINGS = _settings()
if len(sys.argv) > 3:
    SETTINGS = {k: v for k, v in SETTINGS.items() if k in sys.argv[3].split(",") or k == "source"}
PARS = ("Td", "tau", "K")
SCALE = {"Td": "%", "tau": "ms", "K": "%"}


def error(name: str, est: float, truth: float) -> float:
    """Td and K in % of the truth, tau in ms."""
    return (est - truth) * 1e3 if name == "tau" else (est / truth - 1.0) * 100.0


def flight(rng: np.random.Generator) -> tuple[LoopModel, object]:
    """One flight as people fly it (module docstring)."""
    m = LoopModel(0.0422, float(rng.uniform(1.0, 3.0)), float(rng.uniform(0.02, 0.08)), float(rng.uniform(10, 25)))
    rate = float(rng.choice([100.0, 200.0]))
    tests = tuple(plan_test(m, b, float(rng.uniform(0.03, 0.08)), rate_hz=rate, cycles=int(rng.integers(6, 11)),
                            min_duration=3.0) for b in (-0.6, -0.3))
    spec = FlightSpec(model=m, tests=tests, loop="altitude", switching="hear", rate_hz=rate,
                      noise_std=float(rng.uniform(3e-4, 1e-3)), seed=int(rng.integers(1 << 30)))
    return m, simulate_flight(spec)


rng = np.random.default_rng(SEED)
err = {v: {p: [] for p in PARS} for v in SETTINGS}
hit = {v: {p: 0 for p in PARS} for v in SETTINGS}
refined = {v: 0 for v in SETTINGS}
width = {v: [] for v in SETTINGS}  # tau's 95 % half-width [ms]
fail = {v: [] for v in SETTINGS}
start = time.perf_counter()
for k in range(N):
    m, fl = flight(rng)
    stamp_seed = int(rng.integers(1 << 30))
    row = [f"{fl.spec.rate_hz:.0f} Hz Td {m.Td:.2f} tau {m.tau * 1e3:.1f} K {m.K:.1f} |"]
    for name, (cmd, out) in SETTINGS.items():
        log = recorded_flight(fl, command=cmd, output=out, seed=stamp_seed)
        try:
            r = analyze_flight(log, soiptd_model(0.0422), options=AnalyzeOptions(n_bootstrap=200, seed=1))
        except Exception as e:  # a refusal or failure counts as a miss
            fail[name].append(type(e).__name__)
            row.append(f"{name}: {type(e).__name__}")
            continue
        refined[name] += r.method == "waveform"
        width[name].append(0.5e3 * (r.tau.ci95_high - r.tau.ci95_low))
        inside = []
        for p in PARS:
            est, truth = getattr(r, p), getattr(m, p)
            err[name][p].append(error(p, est.value, truth))
            ok = bool(est.ci95_low <= truth <= est.ci95_high)
            hit[name][p] += ok
            inside.append("" if ok else f"!{p}")
        row.append(f"{name}: {error('tau', r.tau.value, m.tau):+.2f}{'w' if r.method == 'waveform' else 'm'}"
                   f"{''.join(inside)}")
    print(k, " ".join(row), f"({time.perf_counter() - start:.0f} s)", flush=True)


def rms(name: str, p: str) -> float:
    e = np.asarray(err[name][p])
    return float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")


print(f"\n{N} flights (seed {SEED}), {time.perf_counter() - start:.0f} s; RMS error Td [%] / tau [ms] / K [%], "
      "95 % coverage (refusals count as misses), tau's median 95 % half-width [ms], waveform estimate reported, "
      "refusals, RMS ratio to source")
print("| setting | RMS Td / tau / K | coverage Td / tau / K | tau half-width | waveform | refused | ratio Td / tau / K |")
print("|---|---|---|---|---|---|---|")
for name in SETTINGS:
    figs = " / ".join(f"{rms(name, p):.3f}" for p in PARS)
    cov = " / ".join(f"{hit[name][p]}" for p in PARS)
    ratio = " / ".join(f"{rms(name, p) / rms('source', p):.2f}" for p in PARS)
    half = float(np.median(width[name])) if width[name] else float("nan")
    print(f"| `{name}` | {figs} | {cov} of {N} | {half:.2f} | {refined[name]} | {len(fail[name])} | {ratio} |")
worst = max(rms(n, p) / rms("source", p) for n in SETTINGS for p in PARS)
low = min(hit[n][p] for n in SETTINGS for p in PARS)
print(f"largest RMS ratio {worst:.2f}x (target 1.2x); lowest coverage {low}/{N} ({100 * low / N:.0f} %)")
