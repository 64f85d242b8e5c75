"""``mrft-ident analyze``: segment the MRFT tests of one log, identify Td, tau and K, report."""

from __future__ import annotations

import math

import click

from ..errors import InsufficientDataError, SegmentationError
from .options import dump_json, log_layout_options, tp_option, tqdm_progress


def _fmt_est(est, scale: float, digits: int = 4) -> str:
    if est is None or not math.isfinite(est.mean):
        return "-"
    s = f"{est.mean * scale:.{digits}g}"
    if math.isfinite(est.std) and not math.isfinite(est.ci95_high):  # one-sided: the data bound it from below only
        s += f"  (> {est.ci95_low * scale:.{digits}g}: not bounded from above)"
    elif math.isfinite(est.std):
        s += f"  ± {est.std * scale:.2g}  [{est.ci95_low * scale:.{digits}g}, {est.ci95_high * scale:.{digits}g}]"
    return s


def format_table(result) -> str:
    """The compact terminal summary of an :class:`~mrftcli.analyze.AnalysisResult`."""
    from ..analyze import describe_t0

    t0 = result.t0
    lines = [f"{result.path}  loop {result.loop}  Tp {result.Tp:g} s (known)  t: seconds from the log start"
             + (f" ({describe_t0(t0)})" if t0 else "")]
    lines.append(f"{'test':>4} {'t [s]':>13} {'beta nom':>8} {'beta eff':>8} {'h':>8} {'f [Hz]':>8} "
                 f"{'amplitude':>10} {'cycles':>7}")
    for t in result.tests:
        nom = f"{t.beta_nominal:+.3f}" if t.beta_nominal is not None else "-"
        lines.append(
            f"{t.index + 1:>4} {t.t_start - t0:>6.1f}-{t.t_end - t0:<6.1f} {nom:>8} {t.beta_effective:>+8.3f} {t.h:>8.4g} "
            f"{t.frequency_hz_mean:>8.4f} {t.amplitude_mean:>10.4g} {t.n_stable:>3d}/{len(t.cycles):<3d}"
        )
    for t in result.rejected:
        nom = f"{t.beta_nominal:+.3f}" if t.beta_nominal is not None else "-"
        why = result.rejection_reasons.get(t.index) or f"{t.n_stable} stable cycles"
        if len(why) > 80 and ":" in why:  # the figures are in the warning below the table
            why = why[: why.index(":")] + "; see the warning"
        lines.append(f"{t.index + 1:>4} {t.t_start - t0:>6.1f}-{t.t_end - t0:<6.1f} {nom:>8}  (left out: {why})")
    ref = result.refinement
    if ref is None or not ref.accepted:
        used = "MRFT estimate" + (" (waveform refinement refused: see the warning)" if ref is not None else "")
    else:
        used = f"waveform refinement (residual {ref.residual_ratio:.2f}x the sensor noise)"
    lines.append(f"parameters   estimate  ± std  [95 % interval]   from the {used}")
    lines.append(f"  Td   [s]   {_fmt_est(result.Td, 1.0)}")
    lines.append(f"  tau  [ms]  {_fmt_est(result.tau, 1e3)}")
    lines.append(f"  K          {_fmt_est(result.K, 1.0)}")
    c = result.combination_stats()
    if c["n"] and c["Td"]["mean"] is not None:
        lines.append(
            f"per combination of cycles ({c['n']}, paper Table III): Td {c['Td']['mean']:.4g} ± {c['Td']['std'] or 0:.2g} s, "
            f"tau {c['tau']['mean'] * 1e3:.4g} ± {(c['tau']['std'] or 0) * 1e3:.2g} ms"
        )
    return "\n".join(lines)


@click.command("analyze")
@click.argument("log", type=click.Path(dir_okay=False))
@tp_option()
@log_layout_options()
@click.option("--min-cycles", type=click.IntRange(2, None), default=3, show_default=True,
              help="Fewest stable cycles for a test to be used.")
@click.option("--json", "json_target", metavar="FILE|-", help="Write the result as JSON to FILE, or '-' for stdout.")
@click.option("--report", "report_dir", metavar="DIR", type=click.Path(file_okay=False),
              help="Write an HTML report with plots to DIR.")
@click.option("--mcap-out", "mcap_out", metavar="FILE", type=click.Path(dir_okay=False),
              help="Write an MCAP with the tests, the model's predicted output and residual and the parameters, "
                   "on the log's clock, to open beside the log in Foxglove Studio or PlotJuggler.")
@click.option("--paper-only", is_flag=True,
              help="Identify from the UFM slices alone (the paper's method), without the weighted phase and "
                   "amplitude constraints.")
@click.option("--diagnose", "run_diagnose", is_flag=True,
              help="Also locate model mismatch and name the missing physics (mrftcli.diagnose.selection).")
def analyze(log, Tp, loop, command_topic, output_topic, beta_topic, setpoint_topic, output_scale, min_cycles,
            json_target, report_dir, mcap_out, paper_only, run_diagnose):
    """Find the MRFT tests in LOG, identify Td, tau and K of the loop, and report.

    Each test's stable limit cycles are measured (frequency, amplitude, and the beta the relay
    actually achieved); two or more betas give Td and tau from the intersection of the unit frequency
    manifolds at the known Tp (paper Fig. 5), K from the amplitudes. Each test's fundamental-harmonic
    phase and the amplitude ratios join the UFM slices as weighted constraints (--paper-only: not).
    Times shown are seconds from the log start; the JSON also keeps the absolute ones.

    Each test's output must be a limit cycle of its relay (oscillating at the relay's frequency
    above the noise, in a steady phase that matches the measured beta, with the nominal beta and the
    same loop-gain sign as the other tests); tests that are not are rejected with the reason.

    Exit codes: 0 ok, 2 bad option, 3 unreadable log, 4 no usable relay test (none, too short, or
    the output does not follow the relay), 5 no plant fits, 6 a single usable beta or not enough
    data (a partial result is given).

    Example: mrft-ident analyze flight.mcap --tp 0.0422 --loop altitude --report out/
    """
    from ..analyze import analyze_path

    to_stdout = json_target == "-"
    if mcap_out:
        from ..io.overlay import check_overlay_path

        check_overlay_path(mcap_out)  # before the work starts
    try:
        result = analyze_path(log, Tp, loop, command_topic=command_topic, output_topic=output_topic,
                              beta_topic=beta_topic, setpoint_topic=setpoint_topic, output_scale=output_scale,
                              min_stable_cycles=min_cycles, **({"constraints": ()} if paper_only else {}))
    except InsufficientDataError as err:
        if json_target:
            dump_json({"error": str(err), "exit_code": err.exit_code, "partial": err.partial}, json_target)
        raise
    except SegmentationError as err:
        # tests found but none usable: the JSON still says what was found and why each was rejected
        rejected = getattr(err, "rejected_tests", None)
        if json_target and rejected is not None:
            dump_json({"error": str(err), "exit_code": err.exit_code, "tests": [], "rejected_tests": rejected},
                      json_target)
        raise
    diagnosis = None
    if run_diagnose:
        from ..diagnose.selection import diagnose as run_diagnosis

        # a live bar on a terminal: the diagnosis re-simulates and takes tens of seconds
        with tqdm_progress("diagnose", unit="stage") as progress:
            diagnosis = run_diagnosis(result.flight, Tp, analysis=result, progress=progress)
    if json_target:
        data = result.to_dict()
        if diagnosis is not None:
            data["diagnosis"] = diagnosis.to_dict()
        dump_json(data, json_target)
    if not to_stdout:
        click.echo(format_table(result))
        if diagnosis is not None:
            click.echo(f"diagnosis: {diagnosis.summary}")
    if mcap_out:
        from ..io.overlay import write_analysis_overlay

        click.echo(f"mcap: {write_analysis_overlay(mcap_out, result)}", err=to_stdout)
    for w in result.warnings:
        click.echo(f"warning: {w}", err=True)
    if report_dir:
        from ..report.analysis import write_analysis_report

        links = []
        if diagnosis is not None:
            from ..report.diagnosis import write_diagnosis_report

            page = write_diagnosis_report(diagnosis, report_dir)
            links.append((page.name, "Model-mismatch diagnosis"))
        index = write_analysis_report(result, report_dir, links=links)
        click.echo(f"report: {index}", err=to_stdout)
