"""``mrft-ident diagnose``: locate model mismatch in a log, name the missing physics, fit it, compare."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import click

from ..diagnose.physics import BY_NAME
from .options import check_output_dir, check_output_file, dump_json, log_layout_options, tp_option, tqdm_progress

if TYPE_CHECKING:
    from ..diagnose.records import DiagnosisResult


def _g(x: float | None, fmt: str = ".4g") -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def format_summary(result: DiagnosisResult) -> str:
    """The terminal summary of a :class:`~mrftcli.diagnose.records.DiagnosisResult`."""
    unit = "rad" if result.loop in ("roll", "pitch") else "m"
    lines = [f"{result.path}  loop {result.loop}  Tp {result.Tp:g} s  sensor noise {result.noise_std:.3g} {unit} (std)"]
    lines.append(f"{'test':>4} {'from-to':>11} {'beta':>8} {'beta':>9} {'relay h':>9} {'cycles':>6}")
    lines.append(f"{'':>4} {'[s]':>11} {'nominal':>8} {'effective':>9} {'[command]':>9} {'used':>6}")
    for t in result.tests:
        nom = f"{t.beta_nominal:+.3f}" if t.beta_nominal is not None else "-"
        beff = 0.5 * (t.beta_effective_up + t.beta_effective_down)
        span = f"{t.t_start_rel:.1f}-{t.t_end_rel:.1f}"
        lines.append(f"{t.index + 1:>4} {span:>11} {nom:>8} {beff:>+9.3f} "
                     f"{t.h:>9.4g} {t.cycles:>6d}")
    lin = result.identification.get("linear", {})
    lines.append(f"linear model fitted to the cycles: Td {_g(lin.get('Td'))} s  tau {_g(1e3 * lin['tau'] if 'tau' in lin else None)} ms"
                 f"  K {_g(lin.get('K'))}")
    lines.append("candidates (found = delta BIC > 10 and better on the held-out cycles; held-out error = RMS of\n"
                 "the held-out cycles' misfit over their amplitude, without and with the effect):")
    lines.append(f"  {'effect':<20} {'parameter':>22} {'delta BIC':>10} {'held-out error':>22}")
    for c in result.candidates:
        if c.delta_bic is None:
            lines.append(f"  {c.name:<20} {'(' + str(c.status) + ')':>22}")
            continue
        par = f"{c.parameter} = {_g(c.value)}"
        b = c.held_out_before.nrmse_raw if c.held_out_before is not None else None
        a = c.held_out_after.nrmse_raw if c.held_out_after is not None else None
        mark = "  <- found" if any(e.name == c.name and e.evidence.compared_with == "linear"
                                   for e in result.effects) else ""
        lines.append(f"  {c.name:<20} {par:>22} {c.delta_bic:>10.1f} {_g(b, '.3f'):>10} -> {_g(a, '.3f'):<8}{mark}")
    pairs = result.second_effect_candidates
    if pairs:
        anchors = list(dict.fromkeys(c.with_ for c in pairs))
        lines.append(f"a second effect on top of {' or '.join(anchors)} (delta BIC against that model alone):")
        probed = [c for c in pairs if c.delta_bic is None]
        for pc in pairs:
            if pc.delta_bic is None:
                continue
            label = pc.name if len(anchors) == 1 else f"{pc.name} (with {pc.with_})"
            par = f"{pc.parameter} = {_g(pc.values.get(pc.name))}"
            b = pc.held_out_before.nrmse_raw if pc.held_out_before is not None else None
            a = pc.held_out_after.nrmse_raw if pc.held_out_after is not None else None
            mark = "  <- found" if any(e.name == pc.name for e in result.effects) else ""
            lines.append(f"  + {label:<18} {par:>22} {pc.delta_bic:>10.1f} {_g(b, '.3f'):>10} -> {_g(a, '.3f'):<8}{mark}")
        if probed:
            # the rows' status carries the threshold ("not fitted: its probe lowers chi^2 by less than N")
            why = str(probed[0].status).replace("its probe", "each one's probe")
            lines.append(f"  {why} beside {probed[0].with_}: " + ", ".join(c.name for c in probed))
    if result.effects:
        for e in result.effects:
            lines.append(f"found: {e.name}: {e.explanation}")
            w = e.identification.get("with_effect", {})
            lines.append(f"  refit with {e.identification.get('model', e.name)}: Td {_g(w.get('Td'))} s  tau {_g(1e3 * w['tau'] if 'tau' in w else None)} ms"
                         f"  K {_g(w.get('K'))}")
            wf = result.identification.get(f"waveform_with_{e.name}")
            if wf:
                lines.append(f"  on the recorded waveform: {BY_NAME[e.name].parameter} = {_g(wf['value'])} "
                             f"{BY_NAME[e.name].unit}  Td {_g(wf['Td'])} s  tau {_g(1e3 * wf['tau'])} ms  K {_g(wf['K'])}")
    elif result.unexplained is None:
        lines.append("found: nothing: the linear model explains the log")
    if result.unexplained is not None:
        u = result.unexplained
        lines.append(f"unexplained: {u.what} (held-out chi^2 {u.held_out_feature_chi2:.0f} over "
                     f"{u.held_out_features} features, p = {u.p_value:.2g})")
    feats = [loc for loc in result.located if loc.kind == "feature"][:4]
    if feats:
        lines.append("largest disagreements of the linear model (z = difference / noise-explained spread):")
        for loc in feats:
            lines.append(f"  test {loc.test + 1} ({loc.t_start_rel:.1f}-{loc.t_end_rel:.1f} s): {loc.what}, z = {loc.z:+.1f}")
    return "\n".join(line.rstrip() for line in lines)


@click.command("diagnose")
@click.argument("log", type=click.Path(dir_okay=True))
@tp_option()
@log_layout_options()
@click.option("--json", "json_target", metavar="FILE|-", help="Write the diagnosis as JSON to FILE, or '-' for stdout.")
@click.option("--report", "report_dir", metavar="DIR", type=click.Path(file_okay=False),
              help="Write an HTML report with plots to DIR (created if missing).")
def diagnose(log, Tp, json_target, report_dir, **read_options):
    """Find where the linear model and LOG disagree, name the missing physics, fit it and compare.

    The linear model G(s) = K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1)) is fitted to the recorded
    limit cycles and re-simulated with the same MRFT settings; period, half-period balance, amplitude,
    waveform harmonics, trends and cycle-to-cycle scatter are compared per test. Candidate physics
    (input_bias, gain_drift, sensor_lag, quadratic_drag, actuator_rate_limit, delay_jitter,
    asymmetric_gain, actuator_saturation, dead_zone, thrust_rectification) are fitted
    on even cycles, chosen by BIC and confirmed on the odd (held-out) cycles; a second effect is then
    looked for on top of the first one by the same rules. A mismatch that none explains is reported
    as "unexplained" with where it is and how large. Times are from the log start.

    Exit codes: 0 ok (with or without a finding), 2 bad option, 3 unreadable log, 4 no relay test,
    6 only one beta tested (as analyze), 7 the diagnosis could not be carried out.

    Example: mrft-ident diagnose flight.mcap --tp 0.0422 --json - --report out/
    """
    from ..diagnose.selection import diagnose as run
    from ..io import read_flight

    check_output_file(json_target, "--json")  # before the work, as analyze
    check_output_dir(report_dir, "--report")
    flight = read_flight(log, **read_options)
    with tqdm_progress("diagnose", unit="stage") as progress:
        result = run(flight, Tp, progress=progress)
    to_stdout = json_target == "-"
    if json_target:
        dump_json(result.to_dict(), json_target)
    if not to_stdout:
        click.echo(format_summary(result))
    for w in result.warnings:
        click.echo(f"warning: {w}", err=True)
    if report_dir:
        from ..report.diagnosis import write_diagnosis_report

        index = write_diagnosis_report(result, report_dir)
        click.echo(f"report: {index}", err=to_stdout)
