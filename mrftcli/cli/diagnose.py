"""``mrft-ident diagnose``: locate model mismatch in a log, name the missing physics, fit it, compare."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

import click

from ..diagnose.starts import bound_reason
from ..diagnose.physics import BY_NAME, unit_in_loop
from ..report.wording import gain_unit, sig
from .model_options import (parse_windows, relay_options, soiptd_or_process, structure_options, window_option)
from .options import (check_output_dir, check_output_file, dump_json, echo_warnings, json_option, log_layout_options,
                      min_cycles_option, quiet_option, read_progress, text_table, tp_option, tqdm_progress)

from ..diagnose.records import DiagnosisResult, ModelEstimate

if TYPE_CHECKING:
    from ..analyze import AnalysisResult
    from ..errors import MrftError
    from ..analyze.residual import ResidualVerdict
    from ..io.logtypes import FlightLog
    from ..mrft.model import LoopModel


def _shown(unit: str | None) -> str:
    """A unit as the tables print it: "-" for a ratio (no unit, "" or "1")."""
    return "-" if unit in (None, "", "1", "-") else str(unit)


def _unit(name: str, loop: str) -> str:
    """A candidate parameter's unit in the loop's output unit ("-" for a ratio)."""
    return _shown(unit_in_loop(BY_NAME[name].unit, loop))


def _plant(est: ModelEstimate, k_unit: str) -> str:
    """An estimate's Td [s], tau [ms] and K with its unit, for the terminal (a Td on the fit's bound marked:
    the tests did not determine it)."""
    on_bound = "" if bound_reason(est.Td) is None else " (Td on the fit's bound: not determined by these tests)"
    return (f"Td {sig(est.Td)} s  tau {sig(None if est.tau is None else 1e3 * est.tau)} ms  K {sig(est.K)} {k_unit}"
            + on_bound)


def _model_lines(result: DiagnosisResult) -> list[str]:
    """The linear model with units, and analyze's model of the same log with the reason they differ
    (issue 26: one model per log across commands, or the reason in the output)."""
    k_unit = gain_unit(result.loop)
    ident = result.identification
    assert ident is not None  # eq. (2)'s strategy fills it
    lin = ident.linear
    spans = ", ".join(f"{t.t_start_rel:.1f}-{t.t_end_rel:.1f}" for t in result.tests)
    lines = [f"linear model fitted to the stable cycles diagnose uses ({spans} s): {_plant(lin, k_unit)}"]
    a = ident.analyze
    if a is None or a.method is None:
        return lines
    how = "waveform refinement" if a.method == "waveform" else "MRFT estimate"
    a_spans = ", ".join(f"{t0:.1f}-{t1:.1f}" for t0, t1 in a.tests or [])
    rec = ident.recommended
    lines.append(f"analyze's model of this log ({how}, tests {a_spans} s): {_plant(a, k_unit)}: "
                 + ("the model to use" if rec is not None and rec.source == "analyze" else
                    "it leaves out the effect found below: take the estimate marked there")
                 + f"; {a.differs_because}")
    return lines


def _effect_lines(result: DiagnosisResult) -> list[str]:
    """Each effect found with its refits, the recommended one marked as the estimate to take, with units."""
    k_unit = gain_unit(result.loop)
    ident = result.identification
    assert ident is not None  # eq. (2)'s strategy fills it
    chosen = ident.recommended.source if ident.recommended is not None else None
    lines = []
    for e in result.effects:
        cand = BY_NAME[e.name]  # its parameter's name
        lines.append(f"found: {e.name}: {e.explanation}")
        model = e.identification.model_of(e.name)
        w = ident.refits.get(model)
        if w is None:
            continue
        lines.append(f"  refit to the cycles with {model}: {_plant(w, k_unit)}"
                     + ("  <- the estimate to use" if chosen == f"with_{model}" else ""))
        wf = ident.waveform.get(e.name)
        if wf is not None:
            lines.append(f"  refit to the recorded waveform: {cand.parameter} = {sig(wf.value)} {_unit(e.name, result.loop)}  "
                         f"{_plant(wf, k_unit)}"
                         + ("  <- the estimate to use (every sample, as analyze's refinement; the cycle refit is what "
                            "the selection compared)" if chosen == f"waveform_with_{e.name}" else ""))
    return lines


def format_summary(result: DiagnosisResult, residual: ResidualVerdict | None = None) -> str:
    """The terminal summary of a :class:`~mrftcli.diagnose.records.DiagnosisResult` (analyze's model of
    the same log beside the diagnosis' linear model when its identification holds it), with the
    waveform residual's verdict analyze gives (``residual``: one verdict for both commands)."""
    unit = "rad" if result.loop in ("roll", "pitch") else "m"
    lines = [f"{result.path}  loop {result.loop}  Tp {result.Tp:g} s  sensor noise {result.noise_std:.3g} {unit} (std)"]
    first = [n for n in result.notes if n.startswith("assumed:")]  # what the figures rest on, before them
    lines += [f"note: {n}" for n in first]
    lines += _refusal_line(result)
    lines.append(f"{'test':>4} {'from-to':>11} {'beta':>8} {'beta':>9} {'relay h':>9} {'cycles':>6}")
    lines.append(f"{'':>4} {'[s]':>11} {'nominal':>8} {'effective':>9} {'[command]':>9} {'used':>6}")
    for t in result.tests:
        nom = f"{t.beta_nominal:+.3f}" if t.beta_nominal is not None else "-"
        beff = 0.5 * (t.beta_effective_up + t.beta_effective_down)
        span = f"{t.t_start_rel:.1f}-{t.t_end_rel:.1f}"
        lines.append(f"{t.index + 1:>4} {span:>11} {nom:>8} {beff:>+9.3f} "
                     f"{t.h:>9.4g} {t.cycles:>6d}")
    lines += _model_lines(result)
    lines += _candidate_lines(result)
    if result.effects:
        lines += _effect_lines(result)
    elif result.unexplained is None:
        mismatch = residual is not None and residual.verdict == "mismatch"
        lines.append("found: nothing among the candidates" if mismatch else
                     "found: nothing: the linear model explains the log")
    if residual is not None and not result.effects:
        lines.append(f"waveform residual (analyze's test): {residual.sentence}")
    if result.unexplained is not None:
        u = result.unexplained
        # a mode ringing above the fitted harmonics is judged on the residual, not the held-out features
        held = ("" if u.held_out_feature_chi2 is None else
                f"held-out chi^2 {u.held_out_feature_chi2:.0f} over {u.held_out_features} features, ")
        lines.append(f"unexplained: {u.what} ({held}p = {u.p_value:.2g})")
    feats = [loc for loc in result.located if loc.kind == "feature"][:4]
    if feats:
        lines.append("largest disagreements of the linear model (z = difference / noise-explained spread):")
        for loc in feats:
            lines.append(f"  test {loc.test + 1} ({loc.t_start_rel:.1f}-{loc.t_end_rel:.1f} s): {loc.what}, z = {loc.z:+.1f}")
    lines += [f"note: {n}" for n in result.notes if n not in first]
    return "\n".join(line.rstrip() for line in lines)


def _refusal_line(result: DiagnosisResult) -> list[str]:
    """When analyze refused the log, a line at the top says so with analyze's reason (issue 39: a log analyze
    refuses is diagnosed from the recorded cycles alone), from the record's ``analyze_refusal``."""
    if result.analyze_refusal is None:
        return []
    return [f"analyze refuses this log: {result.analyze_refusal}; the diagnosis below fits the recorded cycles itself "
            "(no model of analyze's to compare with)"]


@click.command("diagnose")
@click.argument("log", type=click.Path(dir_okay=True))
@tp_option(required=False, help="Known propulsion time constant Tp [s] (bench test); required by --model soiptd.")
@structure_options
@window_option
@relay_options
@log_layout_options()
@min_cycles_option()
@json_option(what="diagnosis")
@click.option("--report", "report_dir", metavar="DIR", type=click.Path(file_okay=False),
              help="Write an HTML report with plots to DIR (created if missing).")
@quiet_option()
def diagnose(log, Tp, model_name, params, ranges, windows, relay_kind, eps, min_cycles, json_target, report_dir,
             quiet, **read_options):
    """Find where the linear model and LOG disagree, name the missing physics, fit it and compare.

    The linear model G(s) = K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1)) is fitted to the recorded
    limit cycles and re-simulated with the same MRFT settings; period, half-period balance, amplitude,
    waveform harmonics, trends and cycle-to-cycle scatter are compared per test. Candidate physics
    (input_bias, gain_drift, sensor_lag, quadratic_drag, actuator_rate_limit, delay_jitter,
    asymmetric_gain, actuator_saturation, dead_zone, thrust_rectification) are fitted
    on even cycles, chosen by BIC and confirmed on the odd (held-out) cycles; a second effect is then
    looked for on top of the first one by the same rules. A mismatch that none explains is reported
    as "unexplained" with where it is and how large. Times are from the log start.

    With --model fopdt|sopdt|ipdt|foipdt or --model-file FILE (a process plant), each test's mean
    cycle is checked against the exact limit cycle of the model identified from the other tests and
    from all tests, and the same library of physics (sensor_lag, actuator_rate_limit, dead_zone,
    actuator_saturation, asymmetric_gain, input_bias, gain_drift, bias_drift, delay_jitter) is fitted
    on the model object; an effect is named only when it improves each test's prediction from the
    other tests. The first line is the verdict (docs/process-plants.md).

    Exit codes: 0 ok (with or without a finding), 2 bad option, 3 unreadable log, 4 no relay test,
    6 only one beta tested (as analyze; with the other beta or height flown, when a single test has the
    cycles to diagnose), 7 the diagnosis could not be carried out.

    Example: mrft-ident diagnose flight.mcap --tp 0.0422 --json - --report out/
    """
    from ..analyze.options import RelayOptions
    from ..analyze.screen import log_start
    from ..diagnose.selection import diagnose as run
    from ..io import ReadOptions, read_flight

    check_output_file(json_target, "--json")  # before the work, as analyze
    check_output_dir(report_dir, "--report")
    analysis = None
    model = soiptd_or_process(Tp, model_name, params, ranges, relay_kind, eps, {"--window": bool(windows)})
    with _partial_on_refusal(json_target):
        if model_name == "soiptd":
            with read_progress(not quiet) as progress:  # a bar only for a read that takes seconds (a large CSV)
                flight = read_flight(log, ReadOptions(**read_options), progress=progress)
            analysis, refusal = _analysis(flight, model, min_cycles)
            options: dict[str, Any] = {"analysis": analysis, "refusal": refusal}
        else:  # a process family's model object, through the same driver
            flight = read_flight(log, ReadOptions(**read_options, any_time_scale=True), echo_warnings=False)
            options = {"relay": RelayOptions(relay_kind, None, eps),
                       "windows": parse_windows(windows, log_start(flight)), "min_stable_cycles": min_cycles}
        with tqdm_progress("diagnose", unit="stage", enabled=not quiet) as progress:
            result = _with_analysis(run(flight, model, progress=progress, **options), analysis)
    to_stdout = json_target == "-"
    if json_target:
        dump_json(result.to_json(), json_target)
    if not to_stdout and result.soiptd:
        from ..analyze.residual import residual_verdict

        click.echo(format_summary(result, residual_verdict(analysis) if analysis is not None else None))
    elif not to_stdout:
        click.echo(format_process(result))
    echo_warnings(result.warnings)
    if report_dir:
        from ..report.diagnosis import write_diagnosis_report

        click.echo(f"report: {write_diagnosis_report(result, report_dir)}", err=to_stdout)


@contextmanager
def _partial_on_refusal(json_target: str | None) -> Iterator[None]:
    """A one-beta refusal (exit 6) says what analyze's says: ``--json`` gets ``{"error", "exit_code", "partial"}``
    and the terminal the partial result (tau over an assumed Td range) before the one-line error."""
    from ..errors import InsufficientDataError

    try:
        yield
    except InsufficientDataError as err:
        from .analyze import report_partial

        report_partial(err, json_target)
        raise


def _analysis(flight: FlightLog, model: LoopModel, min_cycles: int) -> tuple[AnalysisResult | None, MrftError | None]:
    """analyze's record of the log, made once: the diagnosis reuses its segmentation (issue 39) and reports
    its model beside its own fits. With ``--min-cycles`` analyze's refusal is the command's (the user's
    cycle count); with the default, analyze's refusal is handed to the diagnosis (None, the refusal), which
    goes on where the refusal is the evidence of missing physics and raises it otherwise, without running
    analyze a second time."""
    from ..analyze import AnalyzeOptions, analyze_flight
    from ..errors import MrftError

    if min_cycles != 3:
        return analyze_flight(flight, model, options=AnalyzeOptions(min_stable_cycles=min_cycles)), None
    try:
        return analyze_flight(flight, model), None
    except MrftError as exc:
        return None, exc  # the diagnosis decides (its analyze_refusal says so when it goes on)


def _with_analysis(result: DiagnosisResult, analysis: AnalysisResult | None) -> DiagnosisResult:
    """The diagnosis with analyze's model of the same log and the recommendation made again with it, for
    the terminal and the JSON alike (as it was without ``analysis``: analyze refused the log)."""
    from dataclasses import replace

    from ..diagnose.records import with_analysis
    from ..diagnose.selection import deterministic

    if analysis is None:
        return result
    assert result.identification is not None  # eq. (2)'s strategy fills it
    return replace(result, identification=with_analysis(result.identification, analysis, deterministic(result.effects)))


#: what "found" and the held-out error mean, per strategy (eq. (2): cycles held out; the families: tests)
_FOUND_RULE = {
    True: "candidates (found = delta BIC > 10 and better on the held-out cycles; held-out error = RMS of\nthe held-out "
          "cycles' misfit over their amplitude, without and with the effect; delay jitter: its period-scatter error):",
    False: "effects (found = delta BIC > 10 and each test predicted from the others better with it; held-out "
           "error: RMS over the tests of each test's relative error from the others (cycle: frequency and "
           "amplitude; balance: the mean input's residual over h; scatter: ln of the period variance's ratio)):",
}


def _candidate_lines(result: DiagnosisResult) -> list[str]:
    """Every family's library: each candidate alone, then on top of the first found (``+``), with its
    parameter, delta BIC and held-out error without and with it, the found ones marked; those not
    fitted grouped by why; then the families' plant refitted with each effect named."""
    fits = [*result.candidates, *result.second_effect_candidates]
    if not fits:
        return []
    rows, skipped = [], {}  # type: tuple[list[tuple[str, ...]], dict[str, list[str]]]
    for c in fits:
        label = c.name if not c.with_ else f"+ {c.name} (with {c.with_})"
        if c.delta_bic is None:  # eq. (2): not fitted, and why
            why = str(c.status).replace("its probe", "each one's probe")  # said of the names listed after it
            skipped.setdefault(f"{why}{' beside ' + c.with_ if c.with_ else ''}", []).append(c.name)
            continue
        b, a = c.held_out_errors
        rows.append((label, f"{c.parameter} = {sig(c.value)} {_shown(c.unit)}", sig(c.delta_bic, ".1f"),
                     f"{sig(b, '.3f')} -> {sig(a, '.3f')}",
                     ("" if result.soiptd else "+".join(c.views)) + ("  <- found" if result.named(c) else "")))
    head = ("effect", "parameter [unit]", "delta BIC", "held-out error", "" if result.soiptd else "views")
    lines = [_FOUND_RULE[result.soiptd], *text_table([head, *rows], align="<>>><", indent="  ")]
    lines += [f"  {why}: {', '.join(names)}" for why, names in skipped.items()]
    for e in result.effects if not result.soiptd else []:
        if e.refit:
            ident = result.analysis.identification if result.analysis is not None else None
            unit = {est.name: est.unit for est in ident.estimates} if ident is not None else {}
            lines.append(f"refit with {e.name}{' and ' + e.with_ if e.with_ else ''} (all tests): " + "  ".join(
                f"{k} {sig(v)} {unit.get(k, '')}".rstrip() for k, v in e.refit.items()))
    return lines


def _pct_z(err: float | None, z: float | None) -> str:
    return "-" if err is None else f"{100 * err:+.1f} %" + ("" if z is None else f" ({z:+.1f} sd)")


def format_process(result: DiagnosisResult) -> str:
    """The terminal summary of a process-plant diagnosis: the verdict first, the checks, then the analysis."""
    t0 = result.t0
    lines = [result.summary]
    head = ("test", "from-to [s]", "frequency [Hz]", "held-out f [Hz]", "error (z)", "amplitude", "held-out amplitude",
            "error (z)", "residual/noise: fund.", "2-3", "higher")
    rows = [head]
    for c in result.checks:
        bands = {b.band: f"{b.ratio:.1f}" for b in c.all_bands}
        rows.append((str(c.index + 1), f"{c.t_start - t0:.2f}-{c.t_end - t0:.2f}",
                     f"{c.frequency_hz:.4g} ± {c.frequency_se_hz:.2g}", sig(c.held_out_frequency_hz),
                     _pct_z(c.frequency_error, c.frequency_z), f"{c.amplitude:.3g} ± {c.amplitude_se:.2g}",
                     sig(c.held_out_amplitude, ".3g"), _pct_z(c.amplitude_error, c.amplitude_z),
                     bands.get("fundamental", "-"), bands.get("2-3", "-"), bands.get("higher", "-")))
    lines += text_table(rows, align=">" * len(head))
    lines.append("(amplitudes in output units; held out: the model of the other tests; z = difference / its sd "
                 "(the measurement's and the held-out model's); residual/noise: the mean cycle against the model "
                 "of all tests, per harmonic band)")
    shown = 8  # the largest; the JSON's "located" holds them all
    lines += [f"disagreement: {text}" for text in result.located[:shown]]
    if len(result.located) > shown:
        lines.append(f"... and {len(result.located) - shown} more disagreements (all in --json's \"located\")")
    by_note: dict[str, list[str]] = {}
    for c in result.checks:
        if c.note:
            by_note.setdefault(c.note, []).append(str(c.index + 1))
    lines += [f"test{'s' if len(ix) > 1 else ''} {', '.join(ix)}: {note}" for note, ix in by_note.items()]
    lines += _candidate_lines(result)
    lines += [f"note: {n}" for n in result.notes]
    if result.analysis is not None:
        from .analyze import format_analysis

        lines += ["", format_analysis(result.analysis)]
    return "\n".join(lines)
