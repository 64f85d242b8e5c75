"""Benchmark: analyze's held-out standard deviations with correlated cycles (issue 41, ``held_out.mean_sem``).

A test's mean frequency and amplitude are uncertain by their standard error; the held-out prediction's
std propagates the other tests' and adds the test's own. Taking a test's cycles as independent
(``std / sqrt(n)``, the baseline, run in this process) understates it where neighbouring cycles are
alike (a sampled relay hopping among its orbits: lag-1 autocorrelation 0.5-0.6 on ArduPilot SITL);
``mean_sem`` takes them as an AR(1) sequence. For every log given, as ``analyze`` identifies it (its Tp
and loop from the log's sidecar), this prints each test's lag-1 autocorrelation of the cycles'
frequencies, the ratio of the held-out frequency and amplitude std (effective sample size / baseline),
the held-out z before and after, and how many tests lie within 2.5 std. The held-out values do not
move (the point solve is the same); only their std and z.

    python benchmarks/bench_held_out_sem.py sample_logs/sitl /tmp/mrft41/fresh2

(A folder: its ``*.BIN`` and ``*.ulg`` logs with their ``.json`` sidecars, ``tp_s`` and ``loop``.)
Recorded in docs/benchmarks/held_out.md.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path


def _independent(x) -> float:
    """The baseline: cycles taken as independent."""
    return float(x.std(ddof=1) / math.sqrt(x.size)) if x.size > 1 else 0.0


def _lag1(x) -> float:
    d = x - x.mean()
    c0 = float(d @ d)
    return float(d[:-1] @ d[1:]) / c0 if x.size > 2 and c0 > 0 else math.nan


def _log(path: Path) -> tuple[int, int, int, list[float]] | None:
    from mrftcli.analyze import AnalyzeOptions, analyze_flight
    from mrftcli.analyze import held_out as H
    from mrftcli.analyze.estimate import beta_used
    from mrftcli.analyze.screen import low_rate_period
    from mrftcli.errors import MrftError
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.model import soiptd_model

    side = json.loads(Path(f"{path}.json").read_text())
    model = soiptd_model(side["tp_s"])
    try:
        res = analyze_flight(read_flight(path, ReadOptions(loop=side["loop"])), model,
                             options=AnalyzeOptions(n_bootstrap=20, seed=0, refine_waveform=False))
    except MrftError as err:
        print(f"{path.name}: refused ({str(err)[:90]}): nothing held out")
        return None
    betas = [beta_used(t, low_rate_period(res.tests)) for t in res.tests]
    ours = H.held_out_eq2(model, res.tests, betas, res.parameters_mrft["Td"].value)
    kept, H.mean_sem = H.mean_sem, _independent  # the baseline, in this process
    try:
        base = H.held_out_eq2(model, res.tests, betas, res.parameters_mrft["Td"].value)
    finally:
        H.mean_sem = kept
    pairs = [(a, b) for a, b in zip(ours, base) if a.frequency_z is not None and b.frequency_z is not None]
    ratios = [a.frequency_sigma_hz / b.frequency_sigma_hz for a, b in pairs]
    amp = [a.amplitude_sigma / b.amplitude_sigma for a, b in pairs if a.amplitude_sigma and b.amplitude_sigma]
    r1 = [_lag1(t.frequency_hz) for t in res.tests]
    print(f"{path.parent.name}/{path.name}: lag-1 r {' '.join(f'{r:+.2f}' for r in r1)}; held-out f std x "
          f"{' '.join(f'{x:.2f}' for x in ratios)}, amplitude std x {' '.join(f'{x:.2f}' for x in amp)}; z "
          + " ".join(f"{b.frequency_z:+.1f}->{a.frequency_z:+.1f}" for a, b in pairs))
    return (len(pairs), sum(abs(b.frequency_z) <= 2.5 for _, b in pairs),
            sum(abs(a.frequency_z) <= 2.5 for a, _ in pairs), ratios)


def main(folders: list[str]) -> int:
    n = within_base = within = 0
    ratios: list[float] = []
    for folder in folders:
        for path in sorted(p for p in Path(folder).iterdir() if p.suffix in (".BIN", ".ulg")):
            out = _log(path)
            if out:
                n, within_base, within = n + out[0], within_base + out[1], within + out[2]
                ratios += out[3]
    if ratios:
        ratios.sort()
        print(f"held-out tests with a std: {n}; frequency std x {ratios[0]:.2f}-{ratios[-1]:.2f} (median "
              f"{ratios[len(ratios) // 2]:.2f}); within 2.5 std: {within_base}/{n} with cycles independent, "
              f"{within}/{n} with the effective sample size")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:] or ["sample_logs/sitl"]))
