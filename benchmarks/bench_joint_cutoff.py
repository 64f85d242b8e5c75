"""One gyro cutoff for roll and pitch (tracker issue 25): the cutoff chosen from both loops against PX4's
default 40 Hz, on the sample logs' roll and pitch, both routes a user takes.

For each route (the logs' own posterior, as ``vehicle`` tunes them; the analyze RESULT.json, as
``tune ROLL.json PITCH.json``) it prints the chosen cutoff, each axis's loss of expected IAE against the
filter off, its noise gain, and the Ms / GM / PM of the exported values with PX4's Butterworth at that
cutoff; the baseline is the same designs at PX4's default 40 Hz, measured in the same run.

Run: ``nice -n 10 python benchmarks/bench_joint_cutoff.py`` (about 40 s of CPU).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalysisResult, AnalyzeOptions, analyze_path
from mrftcli.io import ReadOptions
from mrftcli.tune.analysis import model_from_result_json, posterior_from_analysis
from mrftcli.tune.closed_loop import RateFilter
from mrftcli.tune.joint import AxisModel, AxisSource, design_axes, export_axes, joint_gyro_cutoff

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"
TP, RATE = 0.0422, 250.0


def _line(label: str, results, cutoff: float) -> None:
    exp = export_axes("px4", results, "robust", [AxisSource(), AxisSource()])
    for res, e in zip(results, exp.exports):
        d = res.get("robust", "PD")
        m = e.margins
        print(f"  {label:>14} {res.loop:>5} {cutoff:5g} Hz  J {d.criterion_expected:.4f}  noise gain "
              f"{d.controller.noise_gain():7.2f}  worst Ms {d.posterior['worst']['Ms']:.3f}  export: Ms {m.Ms:.3f} "
              f"GM {m.gain_margin:.2f} PM {m.phase_margin_deg:.1f} deg DM {m.delay_margin_s * 1e3:.1f} ms")


def main() -> None:
    analyses = [analyze_path(SAMPLES / f"design1_{ax}.mcap", soiptd_model(TP), read=ReadOptions(loop=ax), options=AnalyzeOptions())
                for ax in ("roll", "pitch")]
    routes = {
        "log posterior": [AxisModel(a.loop, a.model, posterior_from_analysis(a)) for a in analyses],
        "RESULT.json": [AxisModel(a.loop, *model_from_result_json(AnalysisResult.from_json(
            json.loads(json.dumps(a.to_json()))), soiptd_model(TP))[:2]) for a in analyses],
    }
    for name, axes in routes.items():
        t = time.process_time()
        joint = joint_gyro_cutoff(axes, "px4", RATE)
        cpu = time.process_time() - t
        print(f"{name}: joint IMU_GYRO_CUTOFF {joint.cutoff_hz:g} Hz ({len(joint.trials)} cutoffs tried, "
              f"{cpu:.1f} s CPU)")
        print(f"  {joint.note()}")
        for tr in joint.trials:
            loss = ", ".join(f"{100 * (j / j0 - 1):+.1f} %" for j, j0 in zip(tr.criterion, joint.reference.criterion))
            print(f"    {tr.cutoff_hz:5g} Hz: loss {loss}  worst Ms {', '.join(f'{m:.3f}' for m in tr.worst_ms)}  "
                  f"{'pass' if tr.passed else 'FAIL'}")
        _line("joint", joint.results, joint.cutoff_hz)
        _line("PX4 default", design_axes(axes, RATE, RateFilter(40.0, "IMU_GYRO_CUTOFF")), 40.0)
        ref = joint.reference.noise_gain
        print("  noise gain joint / filter off: " + ", ".join(
            f"{lp} {g / g0:.2f}" for lp, g, g0 in zip(joint.loops, joint.chosen().noise_gain, ref)))


if __name__ == "__main__":
    main()
