"""Benchmark (issue 23): outer loops identified through the closed inner loop, against eq. (2) with a guessed Tp.

Each flight is drawn fresh and flown by the cascade simulator (:mod:`mrftcli.sim.cascade`, an
independent per-tick integration that shares no code with :mod:`mrftcli.mrft.cascade`):

* the inner attitude plant (eq. (2)): Tp 20-70 ms, Td 0.5-2.5 s (log-uniform), tau 10-35 ms, K 10-60
  (log-uniform); a controller rate of 100, 150 or 200 Hz;
* the inner PD as vehicles fly them: derivative time 0.15-0.35 s, filter Td_c/10, a 35-55 deg design
  phase margin at a crossover on the derivative's lead (:func:`mrftcli.sim.cascade.inner_pd`; where the
  plant needs more lead, the derivative time grows and the margin shrinks, as a tuner would do);
* the outer loop: Td 0.8-5 s (log-uniform), position delay 10-60 ms, commanded acceleration or
  attitude (one of two);
* noise: attitude 0.03-0.08 deg, position 0.1-0.3 mm (white, per tick);
* tests as people fly them: the inner loop at beta -0.4 and -0.7 (8 cycles, 5 deg), then the outer
  loop at -0.4 and -0.7 (8 cycles, 8-15 cm), in one flight, written in the HEAR layout (receive-time
  stamps) with its truth (``--layout reference``: the reference layout, stamped at the source).

Two routes on each flight:

1. **cascade** (issue 23): the inner loop analysed from the flight's own inner tests (eq. (2), Tp
   known from a bench test), the inner gains from the truth's PD, then
   :func:`mrftcli.analyze.cascade.analyze_cascade` on the outer tests (K known from the commanded
   quantity). Scored: outer Td within 10 %, tau within 3 ms, both 95 % intervals covering the truth.
2. **eq. (2)** (today's route): ``analyze --loop y --tp 0.08`` (a guessed Tp).

Each route's recommended robust PD (``tune``'s ``robust`` design) is then put on the TRUE cascade:
the exact discrete loop of the simulator's plant, inner PD and the designed outer controller
(:func:`mrftcli.sim.cascade_plant.outer_phase_margin`: the phase margin at every gain crossover,
-inf when the closed loop is unstable), and its crossover frequency (how fast the loop is). Target:
the cascade route keeps >= 35 deg on every flight.
A route that refuses (no usable test, a failed solve, no design) counts as a miss.

Run: ``nice -n 10 python benchmarks/bench_cascade.py [--n 20] [--seed 0] [--layout hear-ros|reference]``
(6-16 s of CPU per flight).
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

#: Tp [s] a user guesses for eq. (2) on x/y (what hear_x.bag was simulated with)
TP_GUESS = 0.08
PM_TARGET_DEG = 35.0


@dataclass
class Outcome:
    """One flight's figures (nan / None where a route refused)."""

    seed: int
    truth: dict
    cascade_Td: float = math.nan
    cascade_tau: float = math.nan
    cascade_td_covers: bool = False
    cascade_tau_covers: bool = False
    cascade_error: str = ""
    cascade_pm: float = math.nan
    cascade_wc: float = math.nan
    cascade_tune_error: str = ""
    eq2_Td: float = math.nan
    eq2_tau: float = math.nan
    eq2_error: str = ""
    eq2_pm: float = math.nan
    eq2_wc: float = math.nan
    eq2_tune_error: str = ""
    cpu_s: float = 0.0


def draw_spec(rng: np.random.Generator, seed: int):
    from mrftcli.errors import InputError
    from mrftcli.mrft.model import LoopModel
    from mrftcli.sim.cascade import command_gain, inner_pd, plan_outer_test
    from mrftcli.sim.cascade_plant import cascade_plant
    from mrftcli.mrft.cascade import STANDARD_GRAVITY
    from mrftcli.sim.cascade_spec import CascadeSpec
    from mrftcli.sim.flight import plan_test

    lu = lambda lo, hi: float(np.exp(rng.uniform(np.log(lo), np.log(hi))))  # noqa: E731
    rate = float(rng.choice([100.0, 150.0, 200.0]))
    inner = LoopModel(rng.uniform(0.02, 0.07), lu(0.5, 2.5), rng.uniform(0.010, 0.035), lu(10.0, 60.0))
    pm = rng.uniform(35.0, 55.0)
    td_c = rng.uniform(0.15, 0.35)
    for _ in range(30):
        try:
            gains = inner_pd(inner, rate, pm, td_c)
            break
        except InputError:
            # a plant that needs more lead: a longer derivative time and a little less margin, as a tuner would
            td_c, pm = td_c * 1.15, max(pm - 2.0, 25.0)
    else:
        raise RuntimeError(f"no inner PD for {inner}")
    axis = str(rng.choice(["y", "x"]))
    commanded = str(rng.choice(["acceleration", "attitude"]))
    Td, tau = lu(0.8, 5.0), rng.uniform(0.010, 0.060)
    plant = cascade_plant(inner, Td, tau, rate, STANDARD_GRAVITY)
    conv = command_gain(commanded, STANDARD_GRAVITY)
    amp = rng.uniform(0.08, 0.15)
    inner_tests = tuple(plan_test(inner, b, math.radians(5.0), rate, cycles=8.0, min_duration=4.0) for b in (-0.4, -0.7))
    outer_tests = tuple(plan_outer_test(plant, gains, conv, b, amp, cycles=8.0, min_duration=6.0) for b in (-0.4, -0.7))
    return CascadeSpec(inner=inner, gains=gains, Td=Td, tau=tau, axis=axis, commanded=commanded,
                       inner_tests=inner_tests, outer_tests=outer_tests,
                       attitude_noise_std=math.radians(rng.uniform(0.03, 0.08)),
                       position_noise_std=rng.uniform(0.0001, 0.0003), hover_s=2.0, hold_s=6.0, seed=seed,
                       start_time=1.7e9)


def _gains_of(controller):
    from mrftcli.sim.cascade_spec import InnerGains

    return InnerGains(controller.Kp, controller.Ki, controller.Kd, controller.Tf, controller.rate_hz)


def _margin(spec, controller) -> tuple[float, float]:
    """(phase margin [deg], its crossover [rad/s]) of ``controller`` on the true cascade."""
    from mrftcli.sim.cascade import command_gain
    from mrftcli.sim.cascade_plant import cascade_plant, outer_phase_margin

    plant = cascade_plant(spec.inner, spec.Td, spec.tau, spec.rate_hz, spec.g)
    if getattr(controller, "rate_filter", None) is not None:
        raise RuntimeError("the design uses a stack's rate filter; the truth loop models Tf only")
    m = outer_phase_margin(plant, spec.gains, _gains_of(controller), command_gain(spec.commanded, spec.g))
    return m.phase_margin_deg, m.crossover_rad_s


def _inner_read(spec, layout: str):
    """How the inner loop is read: the HEAR layout by its topics, the reference layout's inner MRFT block by name."""
    from mrftcli.io.flight import ReadOptions

    if layout == "reference":
        return ReadOptions(loop=spec.inner_loop, command_topic="/mrft/inner/command:data",
                           beta_topic="/mrft/inner/beta:data")
    return ReadOptions(loop=spec.inner_loop)


def cascade_route(spec, bag: Path, out: Outcome, layout: str = "hear-ros") -> None:
    from mrftcli.analyze import AnalyzeOptions, CascadeOptions, analyze_flight, analyze_path
    from mrftcli.mrft.model import soiptd_model
    from mrftcli.analyze.cascade import cascade_model, inner_draws, inner_gains_of, inner_loop_of
    from mrftcli.io import read_flight
    from mrftcli.io.flight import ReadOptions

    inner_result = analyze_path(bag, soiptd_model(spec.inner.Tp), read=_inner_read(spec, layout))
    controller = inner_gains_of({spec.inner_loop: spec.gains.to_json()}, spec.inner_loop)
    inner = inner_loop_of(inner_result, controller, spec.inner_loop)
    flight = read_flight(bag, ReadOptions(loop=spec.axis), echo_warnings=False)
    analysis = analyze_flight(flight, cascade_model(inner, spec.commanded), options=AnalyzeOptions(
        cascade=CascadeOptions(draws=tuple(inner_draws(inner_result, inner, 30)))))
    est = analysis.identification.parameters
    out.cascade_Td, out.cascade_tau = est["Td"].value, est["tau"].value
    out.cascade_td_covers = est["Td"].ci95_low <= spec.Td <= est["Td"].ci95_high
    out.cascade_tau_covers = est["tau"].ci95_low <= spec.tau <= est["tau"].ci95_high
    try:
        out.cascade_pm, out.cascade_wc = _margin(spec, tune_cascade(analysis))
    except Exception as err:  # noqa: BLE001 - a refusal is a miss, recorded with its reason
        out.cascade_tune_error = f"{type(err).__name__}: {err}"


def tune_cascade(analysis):
    """The cascade route's recommended robust PD: what ``tune RESULT.json`` designs on a cascade analysis
    (30 draws of the outer Td, tau over their intervals)."""
    from mrftcli.tune.grid import N_DRAWS, outer_draws
    from mrftcli.tune.design import tune

    draws = outer_draws(analysis.model, analysis.identification.estimates, N_DRAWS)
    res = tune(analysis.model, analysis.controller_rate_hz, posterior=draws, loop=analysis.loop)
    return res.get("robust", "PD").controller


def eq2_route(spec, bag: Path, out: Outcome, layout: str = "hear-ros") -> None:
    from mrftcli.analyze import analyze_path
    from mrftcli.mrft.model import soiptd_model
    from mrftcli.io.flight import ReadOptions
    from mrftcli.tune.analysis import tune_analysis

    result = analyze_path(bag, soiptd_model(TP_GUESS), read=ReadOptions(loop=spec.axis))
    out.eq2_Td, out.eq2_tau = result.Td.value, result.tau.value
    try:
        res = tune_analysis(result, kinds=("PD",), designs=("robust",))
        out.eq2_pm, out.eq2_wc = _margin(spec, res.get("robust", "PD").controller)
    except Exception as err:  # noqa: BLE001 - a refusal is a miss
        out.eq2_tune_error = f"{type(err).__name__}: {err}"


def run_flight(seed: int, folder: Path, layout: str = "hear-ros") -> Outcome:
    from mrftcli.sim.cascade import simulate_cascade
    from mrftcli.sim.cascade_write import write_cascade

    rng = np.random.default_rng(seed)
    spec = draw_spec(rng, seed)
    t0 = time.process_time()
    flight = simulate_cascade(spec)
    bag = folder / (f"cascade_{seed}.bag" if layout == "hear-ros" else f"cascade_{seed}.mcap")
    write_cascade(flight, bag, layout)
    out = Outcome(seed, {"axis": spec.axis, "commanded": spec.commanded, "Td": spec.Td, "tau": spec.tau,
                         "rate": spec.rate_hz, "inner": spec.inner, "aborted": sum(t.aborted for t in flight.truth.tests)})
    for route, err_field in ((cascade_route, "cascade_error"), (eq2_route, "eq2_error")):
        try:
            route(spec, bag, out, layout)
        except Exception as err:  # noqa: BLE001 - a refusal is a miss
            setattr(out, err_field, f"{type(err).__name__}: {err}".splitlines()[0][:200])
            if os.environ.get("BENCH_TRACE"):
                traceback.print_exc()
    out.cpu_s = time.process_time() - t0
    return out


def _pct(k: int, n: int) -> str:
    return f"{k}/{n} ({100.0 * k / n:.0f} %)" if n else "0/0"


def report(outcomes: list[Outcome]) -> None:
    n = len(outcomes)
    print(f"\n{'seed':>4} {'ax':>2} {'cmd':>5} {'rate':>4} {'Td':>6} {'tau ms':>6} | {'casc Td':>7} {'tau ms':>6} "
          f"{'cov':>3} {'PM':>6} {'wc':>5} | {'eq2 Td':>6} {'tau ms':>6} {'PM':>6} {'wc':>5} | cpu s")
    for o in outcomes:
        t = o.truth
        cov = ("T" if o.cascade_td_covers else "-") + ("t" if o.cascade_tau_covers else "-")
        print(f"{o.seed:>4} {t['axis']:>2} {t['commanded'][:5]:>5} {t['rate']:>4.0f} {t['Td']:>6.3f} "
              f"{t['tau'] * 1e3:>6.1f} | {o.cascade_Td:>7.3f} {o.cascade_tau * 1e3:>6.1f} {cov:>3} {o.cascade_pm:>6.1f} "
              f"{o.cascade_wc:>5.2f} | {o.eq2_Td:>6.3f} {o.eq2_tau * 1e3:>6.1f} {o.eq2_pm:>6.1f} {o.eq2_wc:>5.2f} | "
              f"{o.cpu_s:5.1f}")
        for what in ("cascade_error", "cascade_tune_error", "eq2_error", "eq2_tune_error"):
            if getattr(o, what):
                print(f"      {what}: {getattr(o, what)}")
    td_ok = [abs(o.cascade_Td / o.truth["Td"] - 1.0) <= 0.10 for o in outcomes]
    tau_ok = [abs(o.cascade_tau - o.truth["tau"]) <= 0.003 for o in outcomes]
    both = [a and b for a, b in zip(td_ok, tau_ok)]
    cover_td = sum(o.cascade_td_covers for o in outcomes)
    cover_tau = sum(o.cascade_tau_covers for o in outcomes)
    pm_c = np.array([o.cascade_pm for o in outcomes], float)
    pm_e = np.array([o.eq2_pm for o in outcomes], float)
    print(f"\nflights: {n} (aborted tests in the flights: {sum(o.truth['aborted'] for o in outcomes)}); "
          "refusals count as misses")
    print(f"cascade route: Td within 10 %: {_pct(sum(td_ok), n)}; tau within 3 ms: {_pct(sum(tau_ok), n)}; "
          f"both: {_pct(sum(both), n)}")
    print(f"cascade route: 95 % interval covers Td: {_pct(cover_td, n)}; covers tau: {_pct(cover_tau, n)}")
    eq2_td = [abs(o.eq2_Td / o.truth["Td"] - 1.0) <= 0.10 for o in outcomes]
    eq2_tau = [abs(o.eq2_tau - o.truth["tau"]) <= 0.003 for o in outcomes]
    print(f"eq. (2), Tp {TP_GUESS} s guessed: Td within 10 %: {_pct(sum(eq2_td), n)}; tau within 3 ms: "
          f"{_pct(sum(eq2_tau), n)}; median |tau error| "
          f"{np.nanmedian([abs(o.eq2_tau - o.truth['tau']) for o in outcomes]) * 1e3:.0f} ms")
    for name, pm in (("cascade route", pm_c), ("eq. (2) route", pm_e)):
        finite = pm[np.isfinite(pm)]
        print(f"{name}: robust PD's phase margin on the true cascade >= {PM_TARGET_DEG:g} deg: "
              f"{_pct(int(np.sum(pm >= PM_TARGET_DEG)), n)}; unstable {int(np.sum(pm == -np.inf))}; refused "
              f"{int(np.sum(np.isnan(pm)))}; min {np.min(finite) if finite.size else math.nan:.1f} deg, median "
              f"{np.median(finite) if finite.size else math.nan:.1f} deg")
    ratio = np.array([o.cascade_wc / o.eq2_wc for o in outcomes], float)
    ratio = ratio[np.isfinite(ratio)]
    if ratio.size:
        print(f"crossover of the cascade route's robust PD over the eq. (2) route's, on the true cascade: median "
              f"{np.median(ratio):.2f}x (range {ratio.min():.2f}-{ratio.max():.2f}x, {ratio.size} flights with both)")
    cpu = [o.cpu_s for o in outcomes]
    print(f"CPU per flight (simulate, write, both routes, both designs): median {np.median(cpu):.1f} s, "
          f"max {np.max(cpu):.1f} s")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=20, help="flights (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="first seed")
    parser.add_argument("--layout", choices=("hear-ros", "reference"), default="hear-ros",
                        help="the log layout: HEAR (receive-time stamps, no beta logged; default) or the reference "
                             "layout (stamped at the source, beta logged)")
    args = parser.parse_args(argv)
    outcomes = []

    def stop(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)  # a stopped run still reports the flights it finished
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for seed in range(args.seed, args.seed + args.n):
                outcomes.append(run_flight(seed, Path(tmp), args.layout))
                o = outcomes[-1]
                print(f"flight {seed}: cascade Td {o.cascade_Td:.3f} / {o.truth['Td']:.3f} s, tau "
                      f"{o.cascade_tau * 1e3:.1f} / {o.truth['tau'] * 1e3:.1f} ms, PM {o.cascade_pm:.1f} vs eq. (2) "
                      f"{o.eq2_pm:.1f} deg ({o.cpu_s:.1f} s)", flush=True)
    except KeyboardInterrupt:
        print(f"stopped after {len(outcomes)} of {args.n} flights", flush=True)
    if outcomes:
        report(outcomes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
