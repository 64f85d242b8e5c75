"""Benchmark: the CPU the eq. (2) held-out predictions add to ``analyze`` (issues 36 and 41).

For every shipped sample log (its Tp and loop from its ``.truth.json``) and for a simulated
10-minute, 200 Hz log of 20 tests (bench_analyze's: the held-out cost grows with the number of
tests), in this process: ``analyze_flight`` as the CLI runs it (400 bootstrap draws, waveform
refinement), which includes the held-out stages, and each stage alone on the same tests: the fundamentals'
UFM point solve (:func:`mrftcli.analyze.held_out.held_out_eq2`, issue 36; kept for the lead's check and as the
fallback) and the response-point route of issue 41 (:func:`mrftcli.analyze.held_out_harmonic.held_out_harmonic`,
the tests' fundamentals and 3rd harmonics measured and fitted once per test). "Before" is the analysis
without the response-point stage (the difference), "after" the analysis as it runs. CPU time (``process_time``),
so the figures do not depend on what else runs on the machine.

Run: ``python benchmarks/bench_held_out.py`` (about 2 minutes of CPU).

``--masked`` (only this part; about 10 s of CPU): the leave-one-test-out held-out analysis the SITL benchmark runs
(scripts/sitl/sitl_analysis.held_out: the log masked to the other tests' windows, waveform refinement on) on
``sample_logs/sitl/altitude_mf_20ms.BIN``: CPU per masked analysis, whether the refinement ran, and the grid ticks
each kept test's refinement window holds after its last output (across the masked gap). Those ticks were left
free before 8dd7acd, each a zero column of every least squares: over 400 s per analysis then (E9's cProfile);
that path is gone, so the figure is absolute.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _cpu(fn):
    t0 = time.process_time()
    out = fn()
    return out, time.process_time() - t0


def _measure(name: str, flight, Tp: float) -> tuple[float, float]:
    """(analyze's CPU without the held-out route of issue 41, with it) [s] on one log."""
    from mrftcli.analyze import analyze_flight
    from mrftcli.mrft.model import soiptd_model
    from mrftcli.analyze.estimate import beta_used
    from mrftcli.analyze.held_out import held_out_eq2
    from mrftcli.analyze.held_out_harmonic import held_out_harmonic
    from mrftcli.analyze.screen import low_rate_period

    result, total = _cpu(lambda: analyze_flight(flight, soiptd_model(Tp)))
    ts = low_rate_period(result.tests)
    # the driver centres the solves on the MRFT consensus's Td: the record's MRFT estimate stands for it
    Td_ref = result.parameters_mrft["Td"].value if "Td" in result.parameters_mrft else result.Td.value
    held, stage = _cpu(lambda: held_out_eq2(soiptd_model(Tp), result.tests, [beta_used(t, ts) for t in result.tests], Td_ref))
    _, points = _cpu(lambda: held_out_harmonic(flight, soiptd_model(Tp), result.tests, held))
    n_pred = sum(h.frequency_hz is not None for h in result.held_out)
    print(f"{name:40s} {len(result.tests):3d} {n_pred:5d}  {total - points:8.2f}  {total:8.2f}  {stage:8.3f}  "
          f"{points:8.3f}  {100 * points / (total - points):6.2f} %")
    return total - points, total


def _twenty_tests(d: str):
    from bench_analyze import ten_minute_spec  # the same flight bench_analyze times
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.sim.flight import simulate_flight, write_flight

    fspec = ten_minute_spec()
    path = Path(d) / "twenty_tests.mcap"
    write_flight(simulate_flight(fspec), path, "mcap")
    return read_flight(path, ReadOptions(loop="altitude"), echo_warnings=False)


def main() -> None:
    import numpy as np

    from mrftcli.errors import MrftError
    from mrftcli.io import ReadOptions, read_flight

    print(f"{'log':40s} {'tests':>3s} {'pred.':>5s}  {'before s':>8s}  {'after s':>8s}  {'UFM s':>8s}  {'points s':>8s}  "
          f"{'added':>8s}")
    rows = []
    for truth in sorted((ROOT / "sample_logs").rglob("*.truth.json")):
        log = truth.parent / truth.name[: -len(".truth.json")]
        if not log.exists():
            continue
        spec = json.loads(truth.read_text())
        try:
            flight = read_flight(log, ReadOptions(loop=spec["loop"]), echo_warnings=False)
            rows.append(_measure(str(log.relative_to(ROOT / "sample_logs")), flight, float(spec["Tp"])))
        except MrftError as err:  # counted, not dropped silently
            print(f"{log.name:40s} refused: {err}")
    before, after = sum(r[0] for r in rows), sum(r[1] for r in rows)
    print(f"sample logs ({len(rows)}): analyze CPU {before:.1f} s before, {after:.1f} s after: "
          f"+{100 * (after - before) / before:.2f} %; median per log {np.median([r[0] for r in rows]):.3f} s before, "
          f"{np.median([r[1] for r in rows]):.3f} s after")
    with tempfile.TemporaryDirectory() as d:
        b20, a20 = _measure("simulated 10 min, 20 tests", _twenty_tests(d), 0.0422)
    print(f"20-test log: analyze CPU {b20:.2f} s before, {a20:.2f} s after: +{100 * (a20 - b20) / b20:.1f} %")


def masked(log: Path = ROOT / "sample_logs" / "sitl" / "altitude_mf_20ms.BIN") -> None:
    """The ``--masked`` figures (module docstring)."""
    from mrftcli.analyze import AnalyzeOptions, analyze_flight
    from mrftcli.analyze.general import mask_windows
    from mrftcli.io import ReadOptions, read_flight
    from mrftcli.mrft.model import soiptd_model
    from mrftcli.mrft.waveform import CommandWindow
    import numpy as np

    side = json.loads(log.with_name(log.name + ".json").read_text())
    flight = read_flight(log, ReadOptions(loop=side["loop"]), echo_warnings=False)
    model = soiptd_model(float(side["tp_s"]))
    opts = AnalyzeOptions(n_bootstrap=50, seed=0)  # sitl_analysis's held-out options (refinement on)
    tests = analyze_flight(flight, model, options=opts).tests

    def opened(t_start: float) -> float:  # sitl_analysis._marked_start: the window opens at the beta marker
        b = flight.beta
        before = b.t[b.t <= t_start] if b is not None else np.zeros(0)
        return float(before[-1]) if before.size else t_start

    print(f"\n{log.relative_to(ROOT)}: each test held out, the log masked to the others' windows")
    print(f"{'held out':>8s}  {'CPU s':>6s}  {'refinement':>10s}  {'Td s':>7s}  {'tau ms':>6s}  {'K':>7s}  "
          "grid ticks after each window's last output (the masked gap's; left free before 8dd7acd)")
    for i in range(len(tests)):
        masked_flight = mask_windows(flight, [(opened(t.t_start), t.t_end) for j, t in enumerate(tests) if j != i])
        res, cpu = _cpu(lambda f=masked_flight: analyze_flight(f, model, options=opts))
        c, o = masked_flight.command, masked_flight.output
        after = []
        for t in res.tests:
            w = CommandWindow.between(t.t_start, t.t_end, c.t, c.values, o.t, o.values, history=0.1)
            after.append(0 if w is None else int(w.u.size - 1 - w.k[-1]))
        print(f"{i:>8d}  {cpu:6.2f}  {'ran' if res.refinement is not None else 'not run':>10s}  {res.Td.value:7.4f}  "
              f"{res.tau.value * 1e3:6.1f}  {res.K.value:7.3f}  {after}")


if __name__ == "__main__":
    import sys

    if "--masked" in sys.argv[1:]:
        masked()
    else:
        main()
        masked()
