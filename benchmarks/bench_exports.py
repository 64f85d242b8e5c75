"""Benchmark: ``tune --export`` on every sample log, as a user runs it, against the export it replaces.

For each sample log (analysed as ``tune LOG`` analyses it: the truth sidecar gives only the loop and
Tp, the figures a user knows; the posterior is the analysis's), the robust PD (model-based without a
posterior) is exported to each stack that has the loop, with the stack's defaults (PX4: the
IMU_GYRO_RATEMAX choice nearest the log's rate and IMU_GYRO_CUTOFF 40 Hz; ArduPilot: the log's rate,
INS_GYRO_FILTER 20 Hz; HEAR: 200 Hz and HEAR_FC's 50 Hz Butterworth; PX4 and ArduPilot altitude: hover
thrust 0.5, the samples' trim).

ArduPilot's altitude export is AC_PosControl's z cascade (:mod:`mrftcli.tune.ardupilot_z`): its Ms / GM are the
worst over the 37 splits of tau between the motors and the sensors (nominal model), with ArduPilot's own filters
(the motors' 2 Hz throttle filter, INS_ACCEL_FILTER, PSC_VELZ_FLTE, PSC_ACCZ_FLTE); the row adds PSC_ACCZ_P, the
fraction of the PD's loop gain kept, and the worst Ms over 20 draws of the analysis's 95 % set, each over the
splits of its own tau.

Per export: refused (the reason counts as a miss), exported in range, or exported with values set to
the stack's bounds (``--clamp``); and the nominal Ms / GM of the loop the exported values give with
the stack's filter (:func:`mrftcli.tune.stacks.export_design`).

The baseline is the export the issue found (``--format px4`` before): the design made with its own
first-order Tf at the log's rate, its PX4 values unchecked, flown with IMU_GYRO_CUTOFF = 1/(2 pi Tf)
as PX4 runs it (a 2nd-order Butterworth): the Ms the design table claimed, the Ms as flown, and how
many values fall outside PX4's ranges.

Run: ``nice -n 10 python benchmarks/bench_exports.py [--only REGEX]`` (about 10 minutes on 2 busy
cores for all logs).
"""

from __future__ import annotations

from mrftcli.mrft.model import soiptd_model
from mrftcli.io import ReadOptions
import argparse
import json
import math
import re
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_logs"
STACKS = ("px4", "ardupilot", "ardupilot-4.6", "hear")
HOVER = 0.5


def _logs(only: str | None) -> list[Path]:
    logs = sorted(p for p in SAMPLES.iterdir() if (SAMPLES / (p.name + ".truth.json")).exists())
    return [p for p in logs if not only or re.search(only, p.name)]


def _baseline(res, model, loop: str):
    """The export the issue found: the design's own Tf, flown with PX4's Butterworth at 1/(2 pi Tf)."""
    from mrftcli.tune.closed_loop import Controller, RateFilter
    from mrftcli.tune.margins import loop_margins
    from mrftcli.tune.stack_params import check_ranges

    d = res.get("robust" if any(x.name == "robust" for x in res.designs) else "model-based", "PD")
    c = d.controller
    cutoff = 1.0 / (2 * math.pi * c.Tf)
    flown = loop_margins(Controller(c.Kp, 0.0, c.Kd, 0.0, c.rate_hz, RateFilter(cutoff)), [model])[0]
    ax = loop.upper()
    out_of_range = (len(check_ranges("px4", {f"MC_{ax}_P": c.Kp / c.Kd, f"MC_{ax}RATE_P": c.Kd,
                                             "IMU_GYRO_CUTOFF": cutoff, "IMU_GYRO_RATEMAX": c.rate_hz}))
                    + (c.rate_hz not in (100, 250, 400, 800, 1000, 2000)))
    return d.margins.Ms, flown.Ms, flown.gain_margin, out_of_range


def _one(path: Path) -> list[dict]:
    from mrftcli.analyze import analyze_path
    from mrftcli.errors import MrftError
    from mrftcli.tune.analysis import posterior_from_analysis
    from mrftcli.tune.design import DesignOptions, tune
    from mrftcli.tune.stacks import ExportEvidence, check_exportable, export_design, stack_setting

    truth = json.loads((SAMPLES / (path.name + ".truth.json")).read_text())
    loop, Tp = truth["loop"], truth["Tp"]
    try:
        a = analyze_path(path, soiptd_model(Tp), read=ReadOptions(loop=loop))
    except MrftError as err:
        return [{"log": path.name, "stack": s, "outcome": f"refused (analysis: {err})"} for s in STACKS]
    post = posterior_from_analysis(a)
    rows = []
    base = None
    if loop in ("roll", "pitch") and a.controller_rate_hz:
        res0 = tune(a.model, a.controller_rate_hz, posterior=post, options=DesignOptions(kinds=("PD",)), loop=loop)
        base = _baseline(res0, a.model, loop)
    import numpy as np

    draws = post.models(np.flatnonzero(post.in_set())) if post is not None else []
    for name_ in STACKS:
        stack, version = (name_.split("-") + [None])[:2] if name_.startswith("ardupilot") else (name_, None)
        if stack == "ardupilot" and version is None:
            version = "4.7"
        row: dict = {"log": path.name, "stack": name_, "loop": loop}
        if name_ == "ardupilot-4.6" and loop != "altitude":
            continue  # roll/pitch names are the same in both versions
        try:
            check_exportable(stack, loop, "PD", HOVER)
            st = stack_setting(stack, loop, None, a.controller_rate_hz, None)
            res = tune(a.model, st.rate_hz, posterior=post, loop=loop,
                       options=DesignOptions(kinds=("PD",), rate_filter=st.rate_filter))
            name = "robust" if any(x.name == "robust" for x in res.designs) else "model-based"
            heights = [float(t.h) for t in a.tests]
            amps = [float(t.amplitude_mean) for t in a.tests]
            c = res.get(name, "PD").controller
            evidence = ExportEvidence(tuple(heights), tuple(amps), posterior_models=tuple(draws))
            try:
                e = export_design(stack, c, a.model, loop, name, hover_thrust=HOVER, version=version, evidence=evidence)
                inside = any("designed inside" in n for n in e.notes)
                row["outcome"] = ("designed inside the ranges" if inside else "in range" if not e.clamped
                                  else "minimum I set")
            except MrftError:
                e = export_design(stack, c, a.model, loop, name, clamp=True, hover_thrust=HOVER, version=version,
                                  evidence=evidence)
                row["outcome"] = "clamped (refused without --clamp)"
            row.update(Ms=e.margins.Ms, GM=e.margins.gain_margin, rate=st.rate_hz,
                       clamped=[n for n, _, _ in e.clamped], prearm=list(e.prearm))
            cost = next((n for n in e.notes if "its cost: IAE" in n), "")
            if cost:
                row["cost"] = cost.split("its cost: ")[1]
            if stack == "ardupilot" and loop == "altitude":
                row.update(_z_cascade_row(e, post, st.rate_hz))
                if row.get("post_Ms", 0) > row["Ms"]:
                    row["Ms"] = row["post_Ms"]  # the worst of what is written, over every draw checked
        except MrftError as err:
            row["outcome"] = f"refused: {err}"
        if stack == "hear" and loop in ("x", "y", "altitude") and "Ms" in row:
            row["hear_before"] = _hear_before(a.model, post, loop)
        if stack == "px4" and base is not None:
            row.update(base_Ms_claimed=base[0], base_Ms_flown=base[1], base_GM_flown=base[2], base_out_of_range=base[3])
        rows.append(row)
    return rows


def _hear_before(model, post, loop: str) -> tuple[float, float]:
    """The HEAR export before issue 37: designed with the inner loops' 50 Hz filter, flown with the outer
    loops' own (HEAR_FC's rate/12, 16.7 Hz at 200 Hz): (Ms stated, Ms flown)."""
    from dataclasses import replace

    from mrftcli.tune.closed_loop import RateFilter
    from mrftcli.tune.design import DesignOptions, tune
    from mrftcli.tune.margins import loop_margins

    res = tune(model, 200.0, posterior=post, loop=loop,
               options=DesignOptions(kinds=("PD",), rate_filter=RateFilter(50.0, "HEAR_FC rate filter")))
    d = res.get("robust" if any(x.name == "robust" for x in res.designs) else "model-based", "PD")
    flown = loop_margins(replace(d.controller, rate_filter=RateFilter(200.0 / 12, "outer")), [model])[0]
    return d.margins.Ms, flown.Ms


def _z_cascade_row(e, post, rate: float) -> dict:
    """PSC_ACCZ_P, the PD's loop gain kept, and the worst Ms over 20 draws of the 95 % set x their own splits."""
    import numpy as np

    from mrftcli.tune.ardupilot_z import ZCascadeGains, cascade_figures, split_grid

    from mrftcli.tune.ardupilot_versions import to_46_units

    g = ZCascadeGains.from_params(to_46_units(e.params), rate)
    idx = np.flatnonzero(post.in_set())
    idx = idx[np.linspace(0, idx.size - 1, min(20, idx.size)).astype(int)] if idx.size else idx
    worst = max((cascade_figures(g, [m], split_grid(m.tau)).worst().Ms for m in post.models(idx)), default=math.nan)
    kept = next((n for n in e.notes if n.startswith("the cascade keeps")), "")
    return {"acc_p": g.acc_p, "acc_i": g.acc_i, "kept": kept.split(" ")[3] if kept else "-", "post_Ms": worst}


def _prearm_table(rows: list[dict]) -> None:
    """Per pre-arm rule: its source line and how many written files pass it."""
    table: dict[tuple[str, str], list[bool]] = {}
    for r in rows:
        for c in r.get("prearm", []):
            table.setdefault((c["rule"], c["source"]), []).append(bool(c["passed"]))
    print(f"\n{'pre-arm rule':<22}{'pass':>8}  source")
    for (rule, src), ok in table.items():
        print(f"{rule:<22}{sum(ok):>4}/{len(ok):<3}  {src}")


def _cell(r: dict, key: str, fmt: str) -> str:
    return format(r[key], fmt) if key in r and math.isfinite(r[key]) else "-"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="regex on the sample log names")
    args = ap.parse_args()
    t0 = time.process_time()
    rows = [r for p in _logs(args.only) for r in _one(p)]
    print(f"{'log':<34}{'stack':<10}{'rate':>6}{'Ms':>6}{'GM':>6}  outcome   | before (PX4): Ms claimed / flown, "
          "GM flown, values out of range")
    for r in rows:
        line = (f"{r['log']:<34}{r['stack']:<10}{_cell(r, 'rate', '.0f'):>6}{_cell(r, 'Ms', '.2f'):>6}"
                f"{_cell(r, 'GM', '.2f'):>6}  {r['outcome'][:90]}")
        if "post_Ms" in r:
            line += (f" | ACCZ_P {r['acc_p']:g} I {r['acc_i']:.3g} (4.6 units), keeps {r['kept']} %, Ms over 20 draws "
                     f"x splits {r['post_Ms']:.2f}")
        if "cost" in r:
            line += f" | cost {r['cost']}"
        if "hear_before" in r:
            line += f" | before: designed with 50 Hz, Ms stated {r['hear_before'][0]:.2f}, flown {r['hear_before'][1]:.2f}"
        if "base_Ms_flown" in r:
            line += (f" | {r['base_Ms_claimed']:.2f} / {r['base_Ms_flown']:.2f}, {r['base_GM_flown']:.2f}, "
                     f"{r['base_out_of_range']}")
        print(line)
    done = [r for r in rows if "Ms" in r]
    refused = [r for r in rows if r["outcome"].startswith("refused")]
    over = [r for r in done if r["Ms"] > 1.6 * 1.001]
    base = [r for r in rows if "base_Ms_flown" in r]
    print(f"\nexports: {len(rows)}; written {len(done)} (clamped {sum('clamped' in r['outcome'] for r in done)}); "
          f"refused {len(refused)}; Ms above 1.6 with the stack's filter: {len(over)}")
    _prearm_table(rows)
    for name_ in STACKS:
        w = [r for r in done if r["stack"] == name_]
        if w:
            print(f"{name_}: {len(w)} written, worst Ms {max(r['Ms'] for r in w):.2f}, worst GM "
                  f"{min(r['GM'] for r in w):.2f}")
    z = [r for r in rows if "post_Ms" in r]
    if z:
        print(f"ArduPilot altitude ({len(z)} logs): written {len(z)}, Ms (worst split, nominal) "
              f"{min(r['Ms'] for r in z):.2f}-{max(r['Ms'] for r in z):.2f}, GM {min(r['GM'] for r in z):.2f}-"
              f"{max(r['GM'] for r in z):.2f}; over the 95 % set x splits Ms {min(r['post_Ms'] for r in z):.2f}-"
              f"{max(r['post_Ms'] for r in z):.2f}")
    if base:
        print(f"before (PX4 roll/pitch, {len(base)} logs): Ms as flown above 1.6: "
              f"{sum(r['base_Ms_flown'] > 1.6 * 1.001 for r in base)}; worst flown Ms "
              f"{max(r['base_Ms_flown'] for r in base):.2f} (claimed {max(r['base_Ms_claimed'] for r in base):.2f}); "
              f"logs with values PX4 cannot take: {sum(r['base_out_of_range'] > 0 for r in base)}")
    print(f"CPU {time.process_time() - t0:.0f} s")


if __name__ == "__main__":
    main()
