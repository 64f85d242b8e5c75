"""Does a process plant's tuned PI hold its margins on the TRUE plant? (tune RESULT.json of analyze --model).

Fresh recordings as bench_families draws them (every family, random parameters, 50-200 Hz, 1-3 %
noise, 3-4 windows of a relay with hysteresis, as an engineer runs a process relay test): each is
analysed (analyze_flight with the family model), tuned (the one tune driver: model-based, and robust over 30 draws from the
record's intervals) and the exported PI (the default) is checked on the plant that was simulated:
closed-loop stability (eigenvalues of the exact sampled loop) and the sensitivity peak Ms against the
design limit 1.6. The robust design is compared with the model-based one in the same run (the ratio
of misses). A recording the analysis or the design refuses counts as a miss for both.

    nice -n 10 python benchmarks/bench_tune_process.py --n 24        # the full run
    nice -n 10 python benchmarks/bench_tune_process.py --n 4         # while developing
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_families import FAMILIES, draw_plant, draw_windows  # noqa: E402  (also puts tests/ on the path)

MS_LIMIT = 1.6
MS_TOLERANCE = 1.05  # an Ms within 5 % of the limit on the true plant counts as held


def _on_truth(controller, true_model, rate_hz: float) -> tuple[bool, float, float]:
    """(stable, Ms, phase margin [deg]) of the PI on the true plant's exact sampled loop."""
    from mrftcli.tune.closed_loop import DiscretePlant, PlantStack, closed_loop_matrix, held_delay
    from mrftcli.tune.grid import discretise
    from mrftcli.tune.margins import stack_margins

    sign = 1.0 if true_model.parameters["K"].value > 0 else -1.0
    ss = discretise(true_model, rate_hz)
    from mrftcli.mrft.cascade import DiscreteStateSpace

    ss = DiscreteStateSpace(ss.Phi, ss.Gamma, sign * ss.C, rate_hz)
    A = closed_loop_matrix(ss, controller)[0]
    stable = bool(np.max(np.abs(np.linalg.eigvals(A))) < 1.0)
    h = held_delay(true_model, rate_hz)
    integrators = int(np.sum(np.abs(np.linalg.eigvals(h.Phi) - 1.0) < 1e-9))
    m = stack_margins(controller, PlantStack.of([DiscretePlant(h.Phi, h.Gamma, sign * h.C, h.d, rate_hz)]),
                      integrators=integrators)[0]
    ms, pm = m.Ms, m.phase_margin_deg
    return stable, ms, pm


def one(family: str, rng: np.random.Generator, tmp: Path) -> dict[str, object]:
    from process_sim import simulate, write_csv

    from mrftcli.analyze import analyze_flight
    from mrftcli.errors import MrftError
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.families import PROCESS_FAMILIES, family_model
    from mrftcli.mrft.relays import RelayLaw
    from mrftcli.tune.design import DesignOptions, tune
    from mrftcli.tune.grid import N_DRAWS, model_draws

    params = draw_plant(family, rng)
    true = PROCESS_FAMILIES[family](**params)
    ideal = RelayLaw("ideal", 1.0, -1.0).limit_cycle(true)
    windows = draw_windows(family, "hysteresis", ideal.amplitude, ideal.period, rng)
    rate = float(rng.uniform(50.0, 200.0))
    noise = float(rng.uniform(0.01, 0.03)) * ideal.amplitude
    t, u, y = simulate(family, params, windows, rate, noise, seed=int(rng.integers(1 << 31)))
    path = tmp / "rec.csv"
    write_csv(str(path), t, u, y)
    out: dict[str, object] = {"family": family, "rate": rate}
    try:
        flight = read_flight(path, ReadOptions(command_topic="u_relay", output_topic="y_output"), echo_warnings=False)
        res = analyze_flight(flight, family_model(family))
        assert res.identification is not None
        ident = res.identification
        draws, _ = model_draws(ident.model, ident.estimates, N_DRAWS)
        rate_rec = res.tests[0].rate_hz
        tuned = tune(ident.model, rate_rec, posterior=draws, options=DesignOptions(kinds=("PI",)))
    except MrftError as err:
        out["refused"] = str(err)[:90]
        return out
    for name in ("model-based", "robust"):
        try:
            design = tuned.get(name, "PI")
        except KeyError:  # no design of that name (no draws: no robust one)
            continue
        out[name] = _on_truth(design.controller, true, rate_rec)
    return out


def _held(fig: object) -> bool:
    return isinstance(fig, tuple) and fig[0] and fig[1] <= MS_LIMIT * MS_TOLERANCE


def _show(r: dict[str, object], key: str) -> str:
    f = r.get(key)
    if not isinstance(f, tuple):
        return "refused: " + str(r.get("refused", "no design"))
    return f"{'stable' if f[0] else 'UNSTABLE'} Ms {f[1]:.3f} PM {f[2]:.1f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=24, help="recordings (spread over the four families)")
    ap.add_argument("--seed", type=int, default=2026)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    rows = []
    t0 = time.process_time()
    with tempfile.TemporaryDirectory() as d:
        for i in range(args.n):
            rows.append(one(FAMILIES[i % len(FAMILIES)], rng, Path(d)))
    cpu = time.process_time() - t0
    print(f"{args.n} recordings, {cpu:.0f} s CPU ({cpu / args.n:.1f} s each)")
    print("family  rate [Hz]  model-based PI on the truth (stable, Ms, PM deg)   robust PI on the truth")
    for r in rows:
        print(f"{r['family']:<7} {r['rate']:9.1f}  {_show(r, 'model-based'):<48} {_show(r, 'robust')}")
    for key in ("model-based", "robust"):
        held = sum(_held(r.get(key)) for r in rows)
        stable = sum(isinstance(r.get(key), tuple) and r[key][0] for r in rows)
        ms = [r[key][1] for r in rows if isinstance(r.get(key), tuple)]
        strict = sum(isinstance(r.get(key), tuple) and r[key][0] and r[key][1] <= MS_LIMIT for r in rows)
        print(f"{key:<12} PI: stable on the truth {stable}/{args.n}; Ms <= {MS_LIMIT} x {MS_TOLERANCE} on the truth "
              f"{held}/{args.n} ({100 * held / args.n:.0f} %), Ms <= {MS_LIMIT} {strict}/{args.n}; "
              f"Ms median {np.median(ms):.3f}, worst {max(ms):.3f}")
    miss = {k: args.n - sum(_held(r.get(k)) for r in rows) for k in ("model-based", "robust")}
    print(f"misses robust / model-based: {miss['robust']} / {miss['model-based']} "
          f"(ratio {miss['robust'] / max(miss['model-based'], 1):.2f})")


if __name__ == "__main__":
    main()
