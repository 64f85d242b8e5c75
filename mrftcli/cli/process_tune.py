"""``tune`` on a process plant: ``tune RESULT.json`` of ``analyze --model NAME``, or ``tune --model NAME --param ..``.

The designs are :func:`mrftcli.tune.process.tune_process`'s; this module reads the source, checks the
options that do not apply, and prints the table or the generic export.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from typing import Any, Mapping

import click

from ..errors import InputError
from ..jsonable import load_json_text
from .model_options import meta_model
from .options import check_output_file, dump_json

__all__ = ["ProcessTuneRequest", "process_tune_asked", "run_process_tune", "format_process_tune"]

#: the flight stacks ``--export`` knows besides generic: UAV autopilots, not process controllers
_UAV_STACKS = ("hear", "px4", "ardupilot")


@dataclass(frozen=True)
class ProcessTuneRequest:
    """What ``tune`` was asked for, as far as the process path uses it.

    Attributes
    ----------
    source : str or None
        The process analysis RESULT.json (None: the model from ``--model``/``--param``).
    rate_hz : float or None
        ``--controller-rate`` [Hz] (None: the analysis' tests' rate).
    json_target : str or None
        ``--json`` target.
    ms_max : float
        ``--ms-max`` [-].
    design, kind : str or None
        ``--design`` and ``--kind`` (None: robust else model-based; PI).
    export, out : str or None
        ``--export`` and ``--out``.
    unsupported : mapping of str to Any
        Options given that the process path does not take (a usage error names them).
    """

    source: str | None
    rate_hz: float | None
    json_target: str | None
    ms_max: float
    design: str | None
    kind: str | None
    export: str | None
    out: str | None
    unsupported: Mapping[str, Any]


def _read_json(path: str) -> Any:
    try:
        with open(path, encoding="utf-8") as fh:
            return load_json_text(fh.read(), path)
    except (OSError, ValueError):  # InputError too: the caller's own reader then says why
        return None


def process_tune_asked(ctx: click.Context, source: str | None) -> bool:
    """Is this ``tune`` for a process plant: ``--model NAME``/``--model-file`` given, or SOURCE an
    ``analyze --model NAME --json`` result (its ``model`` a family other than soiptd)?"""
    if meta_model(ctx) is not None:
        return True
    if source is None or not str(source).lower().endswith(".json"):
        return False
    data = _read_json(source)
    return isinstance(data, dict) and isinstance(data.get("model"), str) and data["model"] != "soiptd" \
        and "identification" in data


def _from_result(path: str) -> tuple[Any, list[Any], float | None, str, list[str]]:
    """(analysis, estimates, the tests' controller rate or None when they differ, loop, notes)."""
    from ..analyze.general import GeneralAnalysis

    data = _read_json(path) if str(path).lower().endswith(".json") else None
    if data is None:
        raise InputError(f"{path}: tune on a process plant takes the RESULT.json of analyze LOG --model NAME "
                         "--json RESULT.json (or --model NAME with every --param)")
    analysis = GeneralAnalysis.from_json(data)
    ident = analysis.identification
    if ident is None:
        raise InputError(f"{path}: the analysis identified no model (no usable test): nothing to tune")
    rates = sorted({round(t.rate_hz, 6) for t in analysis.tests})
    rate = rates[0] if len(rates) == 1 else None
    return ident.model, list(ident.estimates), rate, analysis.loop, []


def _from_params(ctx: click.Context) -> Any:
    model = meta_model(ctx)
    missing = [p.name for p in model.parameters.values() if not p.known]
    if missing:
        raise InputError(f"give every parameter of {model.family} with --param NAME=VALUE: missing "
                         f"{', '.join(missing)} (or tune an analyze --model {model.family} RESULT.json)")
    return model


def _check(req: ProcessTuneRequest) -> None:
    used = [name for name, value in req.unsupported.items() if value]
    if used:
        raise click.UsageError(f"{', '.join(used)}: not for a process plant (tune designs PI/PID/PD on it with "
                               "--controller-rate, --ms-max, --design, --kind, --json, --export generic)")
    if req.export in _UAV_STACKS:
        raise InputError(f"--export {req.export}: {req.export} is a UAV flight stack, not a process controller; "
                         "a process plant's gains export as --export generic")
    if req.design == "mrft-rule":
        raise InputError("--design mrft-rule is the DNN-MRFT rule for eq. (2) loops; a process plant has "
                         "model-based and robust designs")
    if req.out and req.export is None:
        raise InputError("--out needs --export generic")
    if req.export == "generic" and not req.out and req.json_target == "-":
        raise InputError("--json - and the export would both go to stdout: give --out FILE (or --json FILE)")
    check_output_file(req.json_target, "--json")


def run_process_tune(ctx: click.Context, req: ProcessTuneRequest) -> None:
    """``tune`` for a process plant: robust PI/PID (PD on integrating plants) on the exact sampled loop."""
    from ..tune.process import ProcessTuneOptions, process_draws, tune_process

    if ctx.get_parameter_source("kind") is not click.core.ParameterSource.COMMANDLINE:
        req = dataclasses.replace(req, kind=None)  # tune's default PD is eq. (2)'s: a process plant's is PI
    _check(req)
    notes: list[str] = []
    if req.source is not None:
        if meta_model(ctx) is not None:
            raise InputError("give a RESULT.json or --model with --param, not both (the file holds its model)")
        model, estimates, rate, loop, notes = _from_result(req.source)
        rate_note = f"controller rate {rate:g} Hz: the analysis' tests' rate" if rate else ""
    else:
        model, estimates, rate, loop = _from_params(ctx), [], None, ""
        rate_note = ""
    if req.rate_hz is not None:
        rate, rate_note = req.rate_hz, f"controller rate {req.rate_hz:g} Hz: --controller-rate"
    if rate is None:
        raise InputError("give --controller-rate HZ, the rate the controller runs at: the gains are designed for "
                         "the sampled loop and " + ("the tests' rates differ" if req.source else "no log gives it"))
    options = ProcessTuneOptions(ms_max=req.ms_max)
    draws, draw_notes = process_draws(model, estimates, options.n_draws, options.seed)
    res = tune_process(model, rate, draws=draws, loop=loop, options=options)
    res = dataclasses.replace(res, notes=(rate_note, *notes, *draw_notes, *res.notes))
    _output(res, req)


def _output(res: Any, req: ProcessTuneRequest) -> None:
    name = req.design or ("robust" if any(d.name == "robust" for d in res.designs) else "model-based")
    kind = req.kind or "PI"
    chosen = res.get(name, kind)
    generic = {"design": name, "kind": kind, "reverse_acting": res.reverse_acting, **chosen.controller.to_dict()}
    if req.json_target:
        dump_json({**res.to_json(), "export": generic}, req.json_target)
    if req.export == "generic":
        text = json.dumps(generic, indent=2) + "\n"
        if req.out:
            from ..io.atomic import write_text_atomic

            write_text_atomic(req.out, text)
            click.echo(f"export generic ({name} {kind}) written: {req.out}", err=req.json_target == "-")
        else:
            click.echo(text, nl=False)
        return
    if req.json_target != "-":
        click.echo(format_process_tune(res))
        c = chosen.controller
        click.echo(f"export ({name} {kind}): Kp {c.Kp:.5g}  Ki {c.Ki:.5g}  Kd {c.Kd:.5g}  Tf {c.Tf:.5g} s  "
                   f"rate {res.rate_hz:g} Hz")


def _g(x: float, digits: int = 4) -> str:
    return f"{x:.{digits}g}" if math.isfinite(x) else "-"


def format_process_tune(res: Any) -> str:
    """The terminal table of a :class:`~mrftcli.tune.process.ProcessTuneResult`."""
    m = res.model
    params = "  ".join(f"{p.name} {p.value:.4g} {p.unit}" for p in m.parameters.values())
    lines = [f"{m.family}: G(s) = {getattr(m, 'transfer_function', m.structure)}; {params}",
             f"ultimate period of the sampled loop {res.ultimate_period_s * 1e3:.4g} ms; rate {res.rate_hz:g} Hz",
             "gains: Kp [command per output unit], Ki [command per output unit s], Kd [command s per output unit], "
             "Tf [s]; IAE [output unit s]"]
    lines += [f"note: {n}" for n in res.notes if n]
    head = ("design", "kind", "Kp", "Ki", "Kd", "Tf", "PM [deg]", "GM", "Ms", "crossover [Hz]",
            "worst PM [deg]", "worst Ms", "IAE", "criterion")
    rows = [head]
    for d in res.designs:
        c, n, w = d.controller, d.nominal, d.worst
        rows.append((d.name, d.kind, _g(c.Kp), _g(c.Ki), _g(c.Kd), _g(c.Tf, 3), _g(n.phase_margin_deg, 3),
                     _g(n.gain_margin, 3), _g(n.Ms, 3), _g(n.crossover_hz, 3),
                     "-" if w is None else _g(w.phase_margin_deg, 3), "-" if w is None else _g(w.Ms, 3),
                     _g(d.iae, 3), d.criterion))
    widths = [max(len(r[k]) for r in rows) for k in range(len(head))]
    lines += ["  ".join(c.ljust(wd) for c, wd in zip(r, widths)).rstrip() for r in rows]
    return "\n".join(lines)
