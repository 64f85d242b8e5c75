"""A wrong Tp: named, refused, or a silent wrong answer? (issue 26 item 2)

Every shipped sample log (one per flight: the same flight in other formats is left out) is analysed
with its true Tp times 1/10, 1/3, 1, 3 and 10, as ``analyze`` runs. Each run is one of:

* named: exit 0 and the first warning says the recording fits another Tp whose interval holds the
  truth within 2 % (``mrftcli.mrft.profile``);
* refused: an error naming Tp (exit non-zero, e.g. "no plant of eq. (2) with Tp = ... fits");
* silent: exit 0 without a Tp warning, with tau more than 10 % from the truth: a confident wrong answer;
* unchecked: exit 0, tau more than 10 % off, and the first warning says "Tp is not checkable from this
  log" with the reason (the command logged below the controller's rate; eq. (2) fitting at no Tp);
* fine: the true Tp (factor 1) with no Tp warning, or a wrong Tp whose tau is still within 10 %.

Also the CPU the profile adds: analyze at the wrong Tp against the same log at the true Tp, in the
same process. Run: ``nice -n 10 python benchmarks/bench_tp_profile.py`` (about 2 minutes of CPU).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from mrftcli.mrft.model import soiptd_model
from mrftcli.io import ReadOptions
from mrftcli.analyze import analyze_path
from mrftcli.errors import MrftError

ROOT = Path(__file__).resolve().parents[1]
FACTORS = (0.1, 1 / 3, 1.0, 3.0, 10.0)
#: The same flight in another container adds nothing here.
DUPLICATES = ("design1_altitude.bag", "design1_altitude.csv", "design1_altitude.json.mcap",
              "design1_altitude.ulg", "design1_altitude_ros2_mcap", "design1_altitude_ros2_sqlite3")


def logs() -> list[tuple[Path, dict]]:
    out = []
    for truth in sorted((ROOT / "sample_logs").glob("*.truth.json")):
        log = Path(str(truth)[: -len(".truth.json")])
        if log.exists() and log.name not in DUPLICATES:
            out.append((log, json.loads(truth.read_text())))
    return out


def outcome(log: Path, truth: dict, factor: float) -> tuple[str, float, str]:
    """(category, CPU [s], detail) of one analysis."""
    Tp = truth["Tp"] * factor
    t0 = time.process_time()
    try:
        r = analyze_path(log, soiptd_model(Tp), read=ReadOptions(loop=truth["loop"]))
    except MrftError as err:
        cpu = time.process_time() - t0
        return ("refused" if "Tp" in str(err) else "refused (not naming Tp)"), cpu, str(err)[:70]
    cpu = time.process_time() - t0
    named = [w for w in r.warnings if w.startswith("the recording fits Tp")]
    if named:
        low, high = (float(v) for v in named[0].split("[")[1].split("]")[0].split(", "))
        ok = low <= truth["Tp"] * 1.02 and high >= truth["Tp"] * 0.98
        return ("named" if ok else "named wrongly"), cpu, named[0][:70]
    off = abs(r.tau.value - truth["tau"]) / truth["tau"]
    unchecked = [w for w in r.warnings if w.startswith("Tp is not checkable")]
    if factor != 1.0 and off > 0.10:
        # the log cannot tell Tp, and the first warning says so: not a silent answer, not a named Tp
        return ("unchecked" if unchecked and r.warnings[0] == unchecked[0] else "silent"), cpu, \
            f"tau {r.tau.value * 1e3:.1f} ms, truth {truth['tau'] * 1e3:.1f} ms"
    return ("fine" if factor == 1.0 or off <= 0.10 else "silent"), cpu, f"tau {r.tau.value * 1e3:.1f} ms"


def main() -> None:
    counts: dict[tuple[float, str], int] = {}
    cpu_ratio = []
    for log, truth in logs():
        base = None
        for f in sorted(FACTORS, key=lambda x: x != 1.0):  # the true Tp first: the baseline
            cat, cpu, detail = outcome(log, truth, f)
            base = cpu if f == 1.0 else base
            if f != 1.0 and cat == "named" and base:
                cpu_ratio.append(cpu / base)
            counts[(f, cat)] = counts.get((f, cat), 0) + 1
            print(f"{log.name:30s} x{f:<6.3g} {cat:10s} {cpu:5.2f} s  {detail}", flush=True)
    print()
    cats = sorted({c for _, c in counts})
    print(f"{'factor':>8} " + " ".join(f"{c:>12}" for c in cats))
    for f in FACTORS:
        print(f"{f:>8.3g} " + " ".join(f"{counts.get((f, c), 0):>12}" for c in cats))
    if cpu_ratio:
        cpu_ratio.sort()
        print(f"CPU of analyze with the profile / at the true Tp: median {cpu_ratio[len(cpu_ratio) // 2]:.1f}x, "
              f"max {cpu_ratio[-1]:.1f}x over {len(cpu_ratio)} named runs")


if __name__ == "__main__":
    main()
