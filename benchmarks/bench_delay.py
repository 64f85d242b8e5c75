"""Benchmark: ``mrft-ident delay`` against the difference of two separate analyses (issue 41).

A user flies the same MRFT tests (same betas, same relay heights) before and after a change that adds a
known delay, and asks how much it added. Our simulator (mrftcli/sim: no code shared with the
identification) flies each pair: three plants a multirotor has (altitude at 100 Hz and 50 Hz, roll at
400 Hz), a few cycles per test, sensor noise, delays added of 10-30 ms. For every pair, in this process:

* ``delay``: :func:`mrftcli.compare.delay.delay_increment` (both flights as one plant, a delay each);
* the baseline: ``analyze`` on each flight as the CLI runs it (``analyze_flight`` with its defaults) and
  the difference of the two taus, its std the two stds in quadrature.

Printed: for each, how many pairs come within 2 ms of the delay added (the issue's figure; a refusal is a
miss), the median and largest error, and how many pairs have the delay added inside the stated 95 %
interval. Seeds: ``--seeds`` (the published run's are not those the command was developed on).

    python benchmarks/bench_delay.py --seeds 101 102 103 104   # about 10 min of CPU

Recorded in docs/benchmarks/sitl.md (the simulator's part of the +20 ms figures).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Case:
    name: str
    loop: str
    Tp: float
    Td: float
    tau: float
    K: float
    rate_hz: float
    amplitude: float  # planned cycle amplitude [output units]
    added: float  # [s]
    cycles: float


CASES = (
    Case("altitude 100 Hz +20 ms", "altitude", 0.04, 2.5, 0.025, 20.0, 100.0, 0.03, 0.020, 8.0),
    Case("altitude 50 Hz +30 ms", "altitude", 0.05, 1.5, 0.04, 18.0, 50.0, 0.05, 0.030, 8.0),
    Case("roll 400 Hz +20 ms", "roll", 0.01, 0.5, 0.003, 300.0, 400.0, 0.04, 0.020, 10.0),
    Case("roll 400 Hz +10 ms", "roll", 0.02, 0.8, 0.004, 150.0, 400.0, 0.04, 0.010, 10.0),
)
BETAS = (-0.2, -0.45, -0.7)


def _fly(case: Case, tau: float, tests, seed: int, path: Path) -> Path:
    from mrftcli.mrft.model import LoopModel
    from mrftcli.sim import FlightSpec, simulate_flight, write_flight

    spec = FlightSpec(model=LoopModel(case.Tp, case.Td, tau, case.K), tests=tests, loop=case.loop,
                      rate_hz=case.rate_hz, hover_s=2.0, hold_s=2.0, seed=seed)
    write_flight(simulate_flight(spec), path, "mcap")
    return path


def _separate(case: Case, paths: list[Path]) -> tuple[float, float]:
    """The baseline: tau of each flight analysed apart, the difference and its std [s]."""
    from mrftcli.analyze import analyze_path
    from mrftcli.io import ReadOptions
    from mrftcli.mrft.model import soiptd_model

    taus = [analyze_path(p, soiptd_model(case.Tp), read=ReadOptions(loop=case.loop)).parameters["tau"] for p in paths]
    return taus[1].value - taus[0].value, math.hypot(taus[0].std, taus[1].std)


def _pair(case: Case, seed: int, folder: Path) -> tuple[tuple[float, float] | None, tuple[float, float] | None]:
    from mrftcli.compare.delay import delay_increment
    from mrftcli.errors import MrftError
    from mrftcli.io import ReadOptions
    from mrftcli.mrft.model import LoopModel
    from mrftcli.sim import plan_test

    before = LoopModel(case.Tp, case.Td, case.tau, case.K)
    # the same tests in both flights (betas and h planned on the plant before the change), long enough for the
    # slower cycles after it
    tests = tuple(plan_test(before, b, case.amplitude, case.rate_hz, cycles=case.cycles * 1.6) for b in BETAS)
    paths = [_fly(case, case.tau + add, tests, seed + 1000 * k, folder / f"{seed}_{k}.mcap")
             for k, add in enumerate((0.0, case.added))]
    out: list[tuple[float, float] | None] = []
    def joint() -> tuple[float, float]:
        result = delay_increment(paths[0], paths[1], case.Tp, read=ReadOptions(loop=case.loop))
        return result.increment.value, result.increment.std

    for run in (joint, lambda: _separate(case, paths)):
        try:
            out.append(run())
        except MrftError as err:
            print(f"    refused: {str(err)[:100]}")
            out.append(None)
    return out[0], out[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103, 104])
    args = ap.parse_args()
    tallies: dict[str, list[tuple[float | None, bool]]] = {"delay": [], "separate": []}  # error [s] or None, covered
    t0 = time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            for seed in args.seeds:
                joint, apart = _pair(case, seed, Path(tmp))
                cells = []
                for name, got in (("delay", joint), ("separate", apart)):
                    if got is None:
                        tallies[name].append((None, False))
                        cells.append(f"{name} refused")
                        continue
                    err = got[0] - case.added
                    tallies[name].append((err, abs(err) <= 1.96 * got[1]))
                    cells.append(f"{name} {got[0] * 1e3:6.2f} ± {got[1] * 1e3:.2f} ms ({err * 1e3:+.2f})")
                print(f"  {case.name}, seed {seed}: " + "; ".join(cells), flush=True)
    for name, rows in tallies.items():
        errs = sorted(abs(e) for e, _ in rows if e is not None)
        n = len(rows)
        print(f"{name}: within 2 ms {sum(e <= 0.002 for e in errs)}/{n} (refusals count as misses), median error "
              f"{errs[len(errs) // 2] * 1e3 if errs else math.nan:.2f} ms, max {max(errs, default=math.nan) * 1e3:.2f} ms; "
              f"the delay added inside the stated 95 % interval {sum(c for _, c in rows)}/{n}")
    print(f"CPU {time.process_time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
