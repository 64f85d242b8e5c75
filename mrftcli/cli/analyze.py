"""``mrft-ident analyze``: segment the MRFT tests of one log, identify Td, tau and K, report."""

from __future__ import annotations

from typing import Any, cast

import click

from ..analyze.held_out import HeldOut, held_out_cells, held_out_notes
from ..errors import InsufficientDataError, MrftError, SegmentationError, TpRejectedError
from .model_options import (baseline_option, cascade_options, cascade_setup, format_combination, parameter_display,
                            parameter_lines, parse_baseline, parse_windows, pop_cascade_options,
                            relay_options, soiptd_or_process, structure_options,
                            structure_text, window_option)
from ..mrft.identify_lti import refuse_nothing_determined
from ..report.wording import uncertainty_sentence
from .options import (check_output_dir, check_output_file, dump_json, echo_warnings, json_option,
                      log_layout_options, min_cycles_option, num, quiet_option, read_progress, text_table,
                      tp_option, tqdm_progress)


def accept_tp_option(f):
    """``--accept-tp``: keep a Tp the recording rejects (analyze, batch, vehicle)."""
    return click.option("--accept-tp", "accept_tp", is_flag=True, default=False,
                        help="Keep the given --tp even when the recording fits another Tp clearly better (by default "
                             "that is exit 5, naming the better Tp); the JSON's tp_check says 'accepted'.")(f)


def _table(header: list[tuple[str, str]], rows: list[list[str]], align: str) -> list[str]:
    """Columns as wide as their widest cell; two header lines (name, unit); no trailing spaces."""
    return text_table([[h[0] for h in header], [h[1] for h in header], *rows], align)


def format_analysis(result, *, advice: bool = True) -> str:
    """The terminal summary of any :class:`~mrftcli.analyze.AnalysisResult` (eq. (2), a family, the cascade).

    One layout for every kind: the log, the model and what the numbers rest on (first lines), the tests
    (the kind's own columns, then each test's held-out prediction where there is one), the tests left
    out, the parameters with their units, std and 95 % interval, and the kind's closing lines. ``advice``
    False leaves out a family's 'not determined' line (the exit-6 line that follows says it).
    """
    lines = [result.path, *_head(result)]
    header, align, rows = _test_columns(result)
    held = [result.held_out_of(k) for k in range(len(result.tests))]
    if any(ho is not None and (ho.frequency_hz is not None or ho.amplitude is not None) for ho in held):
        unit = result.output_unit  # else the notes below say why nothing is predicted
        header += [("held-out f", "[Hz] ± std (error/std)"), ("held-out amplitude", f"[{unit}] ± std (error/std)")]
        align += ">>"
        rows = [r + list(held_out_cells(ho)) for r, ho in zip(rows, held)]
    lines += _table(header, rows, align)
    lines += _left_out(result)
    lines += held_out_notes(held, _numbers(result))
    lines.append(_parameters_line(result))
    lines += parameter_lines(list(result.parameters.items()), parameter_display(result.kind, result.loop))
    lines += _tail(result, advice)
    return "\n".join(line.rstrip() for line in lines)


def _numbers(result) -> list[int]:
    """The test numbers the table shows (a family's count its used tests, the others' every test found)."""
    return [k + 1 if result.kind == "family" else t.index + 1 for k, t in enumerate(result.tests)]


def _head(result) -> list[str]:
    """The model line and what the numbers rest on: the signals read (eq. (2)), the assumptions."""
    from ..analyze import describe_t0

    since = "times in seconds from the log start" + (f" ({describe_t0(result.t0)})" if result.t0 else "")
    if result.kind == "soiptd":
        read_as = _read_as(result)
        return [f"loop {result.loop}, Tp {result.Tp:g} s (known); {since}", *([read_as] if read_as else []),
                *(f"note: {n}" for n in result.notes if n.startswith("assumed"))]
    if result.kind == "cascade":
        return [f"loop {result.loop} through the closed inner loop (cascade model "
                f"{result.identification.model.structure}); {since}",
                *(f"assumption: {a}" for a in result.assumptions)]
    model = result.model
    return [f"model {model.family}: G(s) = {structure_text(model)}; {since}",
            *(f"note: {n}" for n in result.notes if n.startswith("assumed"))]


def _test_columns(result) -> tuple[list[tuple[str, str]], str, list[list[str]]]:
    """The kind's columns of the test table: header (name, unit), alignment and one row per test."""
    t0, unit, numbers = result.t0, result.output_unit, _numbers(result)
    span = [("test", ""), ("from", "[s]"), ("to", "[s]")]
    if result.kind == "family":
        rows = [[str(n), f"{t.t_start - t0:.2f}", f"{t.t_end - t0:.2f}", t.describe_relay(), num(t.frequency_hz),
                 num(t.amplitude, 3), f"{t.n_stable}/{t.n_cycles}"] for n, t in zip(numbers, result.tests)]
        return (span + [("relay", ""), ("frequency", "[Hz]"), ("amplitude", f"[{unit}]"), ("stable/total", "cycles")],
                ">>><>>>", rows)
    if result.kind == "cascade":
        rows = []
        for n, t, fit in zip(numbers, result.tests, result.identification.tests):
            rows.append([str(n), f"{t.t_start - t0:.1f}", f"{t.t_end - t0:.1f}", f"{fit.beta:+.3f}", num(fit.h, 3),
                         num(fit.frequency_hz), num(fit.predicted_hz), f"{num(fit.band_hz[0])}-{num(fit.band_hz[1])}",
                         num(fit.amplitude), num(fit.predicted_amplitude)])
        return (span + [("beta", ""), ("relay h", "[command]"), ("frequency", "[Hz]"), ("predicted", "[Hz]"),
                        ("sampled band", "[Hz]"), ("amplitude", f"[{unit}]"), ("predicted", f"[{unit}]")],
                ">" * 10, rows)
    rows = [[str(n), f"{t.t_start - t0:.1f}", f"{t.t_end - t0:.1f}",
             f"{t.beta_nominal:+.3f}" if t.beta_nominal is not None else "-", f"{t.beta_effective:+.3f}", num(t.h),
             num(t.frequency_hz_mean), num(t.amplitude_mean), f"{t.n_stable}/{len(t.cycles)}"]
            for n, t in zip(numbers, result.tests)]
    return (span + [("beta", "nominal"), ("beta", "effective"), ("relay h", "[command]"), ("frequency", "[Hz]"),
                    ("amplitude", f"[{unit}]"), ("stable/total", "cycles")], ">" * 9, rows)


def _left_out(result) -> list[str]:
    """One line per test found and left out: its span, its beta where it has one, and why."""
    t0 = result.t0
    rows = [(f"({a - t0:.2f}-{b - t0:.2f} s)", why) for _, a, b, why in result.rejected_spans]
    for t in result.rejected:
        nom = "-" if t.beta_nominal is None else f"{t.beta_nominal:+.3f}"
        why = result.rejection_reasons.get(t.index) or f"{t.n_stable} stable cycles"
        if len(why) > 80 and ":" in why:  # the figures are in the warning below the table
            why = why[: why.index(":")] + "; see the warning"
        rows.append((f"test {t.index + 1} ({t.t_start - t0:.1f}-{t.t_end - t0:.1f} s, beta {nom})", why))
    return [f"{label} left out: {why}" for label, why in rows]


def _parameters_line(result) -> str:
    """Where the parameters come from."""
    if result.kind == "family":
        ident = result.identification
        chi = f", chi2/dof {ident.chi2_dof:.3g}" if ident.chi2_dof is not None else ""
        return f"parameters (direct fit to {len(ident.points)} frequency-response points of the cycles{chi}):"
    if result.kind == "cascade":
        return "parameters (the outer loop through the closed inner loop, its draws in the intervals):"
    ref = result.refinement
    if ref is None or not ref.accepted:
        used = "the MRFT estimate" + (" (waveform refinement refused: see the warning)" if ref is not None else "")
    else:
        used = f"the waveform refinement, residual {ref.residual_ratio:.2f}x the sensor noise"
    return f"parameters, from {used}:"


def _tail(result, advice: bool = True) -> list[str]:
    """The kind's closing lines: eq. (2)'s spread over combinations and which uncertainty to use, a family's
    undetermined parameters and the next test; then the notes."""
    if result.kind == "cascade":
        return [f"note: {n}" for n in result.notes]
    if result.kind == "family":
        ident, lines = result.identification, []
        if ident.advice and advice:
            lines.append(f"not determined: {ident.advice}")
        lines += format_combination(ident)
        if ident.undetermined:
            model = "--model-file FILE" if hasattr(ident.model, "transfer_function") else f"--model {ident.model.family}"
            lines.append(f"next test: 'mrft-ident plan {result.path} {model}' (with this command's topic options) "
                         f"ranks the relay tests that would determine {', '.join(ident.undetermined)}")
        return lines + [f"note: {n}" for n in result.notes if not n.startswith("assumed")]
    lines = []
    c = result.combination_stats()
    if c["n"] and c["Td"]["mean"] is not None:
        lines.append(
            f"spread over {c['n']} combinations of stable cycles: Td {num(c['Td']['mean'])} ± {num(c['Td']['std'] or 0, 2)} s, "
            f"tau {num(c['tau']['mean'] * 1e3)} ± {num((c['tau']['std'] or 0) * 1e3, 2)} ms"
        )
    mrft_interval = any("MRFT interval" in note for note in result.notes)
    if (c["n"] and c["Td"]["mean"] is not None) or mrft_interval:
        ref = result.refinement
        lines.append(uncertainty_sentence(ref is not None and ref.accepted, mrft_interval))
    return lines + [f"note: {note}" for note in result.notes if not note.startswith("assumed")]


def _read_as(result) -> str:
    """Where the signals came from, their scales and the feedback sign found in the data, with its evidence."""
    src = result.flight.source if result.flight is not None else {}
    if not src:
        return ""
    parts = [f"read as: layout {src.get('layout', '?')}; command {src.get('command', '?')}"
             + (f" x{src['command_scale']:g}" if src.get("command_scale", 1.0) != 1.0 else "")
             + f", output {src.get('output', '?')}"
             + (f" x{src['output_scale']:g}" if src.get("output_scale", 1.0) != 1.0 else "")]
    if src.get("command_choice"):  # the layout's command chosen from the log (PX4's MRFT_DELAY: the decision)
        parts.append(f"command {src['command_choice']}")
    if src.get("controller_rate"):  # the relay's rate, read from the log or assumed (and why)
        parts.append(f"controller rate {src['controller_rate']}")
    signs = [t.loop_sign for t in result.tests]
    if signs:
        up = sum(s > 0 for s in signs)
        sign, n = ("+", up) if up >= len(signs) - up else ("-", len(signs) - up)
        moves = "rises" if sign == "+" else "falls"
        parts.append(f"feedback sign {sign} (the output {moves} while the relay is high in {n}/{len(signs)} tests; "
                     "--command-scale/--output-scale -1 flip it)")
    return "\n".join(parts)


def format_partial(err) -> str:
    """The text of exit 6: what one beta can say (tau for an assumed Td range), from ``err.partial``."""
    part = err.partial or {}
    lo, hi = part.get("assumed_Td_range_s", (None, None))
    lines = [f"partial result: tau for an assumed Td range {lo:g}-{hi:g} s (one beta cannot separate Td and tau)"]
    header = [("test", ""), ("from", "[s]"), ("to", "[s]"), ("beta", "effective"), ("frequency", "[Hz]"),
              ("tau if Td in range", "[ms]")]
    rows = []
    for t, tau in zip(part.get("tests", []), part.get("tau_for_assumed_Td", [])):
        span = tau.get("tau_range_s")
        rows.append([str(t["index"] + 1), f"{t['t_start_rel']:.1f}", f"{t['t_end_rel']:.1f}",
                     f"{t['beta_effective']:+.3f}", num(tau["frequency_hz"]),
                     "-" if not span else f"{num(span[0] * 1e3)} - {num(span[1] * 1e3)}"])
    lines += _table(header, rows, ">>>>>>")
    lines += held_out_notes([HeldOut.from_json(t["held_out"]) if t.get("held_out") else None
                             for t in part.get("tests", [])], [t["index"] + 1 for t in part.get("tests", [])])
    return "\n".join(lines)


def report_partial(err, json_target: str | None) -> None:
    """Exit 6 as analyze says it (``diagnose`` too): ``--json`` gets ``err.to_json()`` and the terminal, unless
    the JSON goes to stdout, the partial result before the one-line error."""
    if json_target:
        dump_json(err.to_json(), json_target)
    if json_target != "-" and err.partial:
        click.echo(format_partial(err))


def _stages(progress, weights: dict[str, float]):
    """Split one bar among the stages of a run, in proportion to their usual duration (weights [s])."""
    total = sum(weights.values())
    start = {}
    acc = 0.0
    for name, w in weights.items():
        start[name] = acc
        acc += w

    def stage(name: str):
        def sub(done: float, sub_total: float, text: str = "") -> None:
            frac = min(max(done / sub_total, 0.0), 1.0) if sub_total else 0.0
            progress(round(start[name] + frac * weights[name], 1), total, f"{name}: {text}" if text else name)
        return sub

    return stage


@click.command("analyze")
@click.argument("log", type=click.Path(dir_okay=True))
@tp_option(required=False, help="Known propulsion time constant Tp [s] (bench test); required by --model soiptd.")
@structure_options
@window_option
@relay_options
@baseline_option
@log_layout_options()
@min_cycles_option()
@accept_tp_option
@json_option(what="analysis")
@click.option("--report", "report_dir", metavar="DIR", type=click.Path(file_okay=False),
              help="Write an HTML report with plots to DIR (created if missing).")
@click.option("--mcap-out", "mcap_out", metavar="FILE", type=click.Path(dir_okay=False),
              help="Write an MCAP with the tests, the model's predicted output and residual and the parameters, "
                   "on the log's clock, to open beside the log in Foxglove Studio or PlotJuggler (a binary file; "
                   "not '-').")
@click.option("--paper-only", is_flag=True,
              help="Identify from the UFM slices alone (the paper's method), without the weighted phase and "
                   "amplitude constraints.")
@click.option("--diagnose", "run_diagnose", is_flag=True,
              help="Also locate model mismatch and name the missing physics (mrftcli.diagnose.selection).")
@cascade_options
@quiet_option()
def analyze(log, Tp, model_name, params, ranges, windows, relay_kind, eps, min_cycles, accept_tp, json_target,
            report_dir, mcap_out, paper_only, run_diagnose, quiet, **read_options):
    """Find the MRFT tests in LOG, identify Td, tau and K of the loop, and report.

    LOG is a log file or a ROS 2 bag folder. With --model fopdt|sopdt|ipdt|foipdt (a process plant under
    an MRFT, ideal, hysteresis or biased relay) see docs/process-plants.md; the rest of this text is
    the default, --model soiptd (eq. (2)). Each test's stable limit cycles are measured (frequency,
    amplitude, and the beta the relay actually achieved); two or more betas give Td and tau from the
    intersection of the unit frequency manifolds at the known Tp (paper Fig. 5), K from the
    amplitudes. Each test's fundamental-harmonic phase and the amplitude ratios join the UFM slices as
    weighted constraints (--paper-only: not). Times shown are seconds from the log start; the JSON
    also keeps the absolute ones.

    Each test's output must be a limit cycle of its relay (oscillating at the relay's frequency
    above the noise, in a steady phase that matches the measured beta, with the nominal beta and the
    same loop-gain sign as the other tests); tests that are not are rejected with the reason.

    Exit codes: 0 ok, 2 bad option, 3 unreadable log, 4 no usable relay test (none, too short, or
    the output does not follow the relay), 5 no plant fits, or the recording rejects --tp (it names
    the Tp it fits; --accept-tp keeps yours), 6 a single usable beta or not enough data (the partial
    result is printed, and written by --json).

    Example: mrft-ident analyze flight.mcap --tp 0.0422 --loop altitude --report out/
    """
    from ..analyze import AnalyzeOptions, log_start
    from ..analyze.options import TRY_DIAGNOSE, RelayOptions
    from ..io import ReadOptions, read_flight

    # a process model's operating point: a number, or a topic of the log
    baseline = parse_baseline(read_options.pop("baseline", None))
    baseline_topic = read_options.pop("baseline_topic", None)
    if baseline is not None and baseline_topic is not None:
        raise click.UsageError("give the operating point once: --baseline Y0[:STD] or --baseline-topic TOPIC[:FIELD]")
    cascade = pop_cascade_options(read_options)  # --inner-model: the outer loop through its inner loop
    model, cascade_opts = _model(Tp, model_name, params, ranges, relay_kind, eps, paper_only, run_diagnose, windows,
                                 cascade, read_options, baseline is not None or baseline_topic is not None)
    to_stdout = json_target == "-"
    # every output is checked before the work starts, all in the same way (parents created)
    check_output_file(json_target, "--json")
    check_output_dir(report_dir, "--report")
    if mcap_out:
        from ..io.overlay import check_overlay_path

        check_output_file(mcap_out, "--mcap-out")  # as --json: its folder created, writable
        check_overlay_path(mcap_out)  # and only an MCAP replaced (never '-': binary)
    with read_progress(not quiet) as progress:  # a bar only for a read that takes seconds (a large CSV)
        # a process plant runs on any time scale: the clock is not checked against vehicle loops' rates
        flight = read_flight(log, ReadOptions(**read_options, any_time_scale=model.family not in ("soiptd", "cascade")),
                             echo_warnings=False, progress=progress)  # its warnings: once, below
    if isinstance(baseline_topic, str):  # --baseline-topic: the operating point as logged
        baseline = (_baseline_signal(log, baseline_topic, read_options), 0.0)
    options = AnalyzeOptions(min_stable_cycles=min_cycles, **({"constraints": ()} if paper_only else {}),
                             relay=RelayOptions(relay_kind, None, eps), windows=parse_windows(windows, log_start(flight)),
                             baseline=baseline, **({"cascade": cascade_opts} if cascade_opts is not None else {}),
                             diagnose_hint="" if run_diagnose else TRY_DIAGNOSE)  # with --diagnose: given below
    weights = {"identify": 6.0, **({"diagnose": 25.0} if run_diagnose else {}), **({"report": 4.0} if report_dir else {})}
    # a bar (stderr, terminal only) when the run is long enough to wait for: a diagnosis or a report
    with tqdm_progress("analyze", unit="s", enabled=len(weights) > 1 and not quiet) as progress:
        stage = _stages(progress, weights)
        stage("identify")(0, 1, "segmenting and identifying")
        result = _identify(flight, model, options, accept_tp, json_target)
        diagnosis = None
        if run_diagnose:
            from ..diagnose.selection import diagnose as run_diagnosis

            if result.kind == "soiptd":
                diagnosis = run_diagnosis(flight, model, analysis=result, progress=stage("diagnose"))
            else:  # the analysis made above, with the same options, instead of a second one
                diagnosis = run_diagnosis(flight, model, analysis=result, progress=stage("diagnose"),
                                          relay=options.relay, windows=options.windows, min_stable_cycles=min_cycles,
                                          baseline=options.baseline)
        index = None
        if report_dir:
            from ..report.analysis import write_analysis_report

            links, extra = [], []
            if diagnosis is not None and result.kind == "soiptd":
                from ..report.diagnosis import write_diagnosis_report

                stage("report")(0, 1, "diagnosis page")
                page = write_diagnosis_report(diagnosis, report_dir)
                links.append((page.name, "Model-mismatch diagnosis"))
            elif diagnosis is not None:  # a family's diagnosis draws no figures yet: its verdict on the page
                from ..report._common import esc

                extra.append(f"<h2>Model-mismatch diagnosis</h2><p>{esc(diagnosis.summary)}</p>")
            index = write_analysis_report(result, report_dir, links=links, progress=stage("report"), extra=extra)
    if json_target:
        data = result.to_json()
        if diagnosis is not None:
            data["diagnosis"] = diagnosis.to_dict()
        dump_json(data, json_target)
    ident = result.identification if result.kind == "family" else None
    if not to_stdout:  # nothing determined: the exit-6 line below gives the advice, once
        click.echo(format_analysis(result, advice=ident is None or not ident.nothing_determined))
        if diagnosis is not None:
            click.echo(f"diagnosis: {diagnosis.summary}")
    if mcap_out:
        from ..analyze import analysis_overlay
        from ..io.overlay import write_overlay

        click.echo(f"mcap: {write_overlay(mcap_out, **analysis_overlay(result))}", err=to_stdout)
    echo_warnings(result.warnings)
    if index is not None:
        click.echo(f"report: {index}", err=to_stdout)
    if ident is not None:
        refuse_nothing_determined(ident)  # exit 6 after the output, as identify's


#: why --paper-only has no meaning beyond eq. (2) (the paper's method is eq. (2)'s UFM slices)
_NO_PAPER_ONLY = {
    "family": "the paper's method is eq. (2)'s UFM slices; a {family} model is fitted directly to its cycles' "
              "response points, which have no paper-only subset: leave --paper-only out",
    "cascade": "the paper's method is eq. (2)'s UFM slices; the cascade is fitted to the exact sampled orbits "
               "through the inner loop, which have no paper-only subset: leave --paper-only out",
}


def _model(Tp, model_name, params, ranges, relay_kind, eps, paper_only, run_diagnose, windows, cascade, read_options,
           baseline: bool):
    """The model object to identify (and the cascade's options): eq. (2), a process family or the cascade;
    one-line errors naming the options that do not apply to it."""
    if cascade is not None:
        model, options = cascade_setup(cascade, str(read_options.get("loop")),
                                       {"--diagnose": run_diagnose, "--window": windows,
                                        "--model": model_name != "soiptd"})
    elif model_name == "soiptd":
        model = soiptd_or_process(Tp, model_name, params, ranges, relay_kind, eps)
        if baseline:
            raise click.UsageError("--baseline and --baseline-topic take a process model (--model fopdt or sopdt, "
                                   "or --model-file); eq. (2) integrates (no static gain)")
        return model, None
    else:
        model, options = soiptd_or_process(Tp, model_name, params, ranges, relay_kind, eps), None  # --tp refused
    if paper_only:
        raise click.UsageError("--paper-only: " + _NO_PAPER_ONLY["cascade" if cascade is not None else "family"]
                               .format(family=model.family))
    return model, options


def _identify(flight, model, options, accept_tp: bool, json_target):
    """:func:`~mrftcli.analyze.analyze_flight` (a Tp the recording rejects refused unless ``accept_tp``); on a
    refusal the JSON says what was found and the reader's warnings are shown, then the error propagates."""
    from ..analyze import analyze_flight, refuse_rejected_tp

    try:
        return refuse_rejected_tp(analyze_flight(flight, model, options=options), accept_tp)
    except MrftError as err:
        if isinstance(err, TpRejectedError) and json_target and err.result is not None:
            dump_json(cast(Any, err.result).to_json(), json_target)  # the JSON says which: tp_check.verdict "rejected"
        elif isinstance(err, InsufficientDataError):
            report_partial(err, json_target)
        elif isinstance(err, SegmentationError) and json_target and err.rejected_tests is not None:
            # tests found but none usable: the JSON still says what was found and why each was rejected
            dump_json({"error": str(err), "exit_code": err.exit_code, "tests": [],
                       "rejected_tests": err.rejected_tests}, json_target)
        echo_warnings(flight.warnings)
        raise


def _baseline_signal(log, spec: str, read_options):
    """The ``--baseline-topic`` signal [s, output units] from the log (the reader's clock and time unit)."""
    import numpy as np

    from ..io import open_log
    from ..io.logtypes import Signal
    from ..io.source import parse_spec

    ts = parse_spec(spec)
    with open_log(log, read_options.get("fmt"), echo_warnings=False, time_unit=read_options.get("time_unit")) as src:
        topic = src.resolve_topic(ts.topic)
        if topic is None:
            raise src.missing_topic(ts.topic)
        t, leaves, values = src.values(topic, ts.field)
    scale = read_options.get("output_scale") or 1.0  # the output's units
    return Signal(np.asarray(t, float), scale * np.asarray(values[leaves[0]], float))
