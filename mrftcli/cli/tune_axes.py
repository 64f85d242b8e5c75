"""``mrft-ident tune ROLL.json PITCH.json --export px4|ardupilot``: both axes with one gyro cutoff, one file.

PX4's ``IMU_GYRO_CUTOFF`` and ArduPilot's ``INS_GYRO_FILTER`` are one Butterworth on all axes, so the
roll and pitch designs share it: chosen from both loops (``--gyro-cutoff auto``, the default here:
:func:`mrftcli.tune.joint.joint_gyro_cutoff`) or given (``--gyro-cutoff HZ``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import click

from ..errors import InputError
from ..validate import TP_MISSING
from .options import check_export_paths, dump_json, tqdm_progress

if TYPE_CHECKING:
    from ..mrft.model import LoopModel
    from .tune import ExportOptions

__all__ = ["AxesRequest", "tune_axes"]


@dataclass(frozen=True)
class AxesRequest:
    """What ``tune ROLL.json PITCH.json`` was asked for.

    Attributes
    ----------
    sources : tuple of str
        The two analyze RESULT.json files.
    model : LoopModel or None
        Eq. (2) with the bench test's Tp known (``soiptd_model(--tp)``), the same for both axes (None: no --tp).
    ex : ExportOptions
        ``--export``, ``--out``, ``--gyro-cutoff HZ`` (``gyro_cutoff_hz``), ``--clamp``.
    auto : bool
        Choose the cutoff from both axes (else ``ex.gyro_cutoff_hz``).
    rate_hz : float or None
        ``--controller-rate``.
    objective : str
    ms_max : float
    design : str
        ``robust`` or ``model-based``.
    kind : str
    json_target : str or None
    quiet : bool
    """

    sources: tuple[str, ...]
    model: LoopModel | None
    ex: ExportOptions
    auto: bool
    rate_hz: float | None
    objective: str
    ms_max: float
    design: str
    kind: str
    json_target: str | None
    quiet: bool


def _check_request(req: AxesRequest) -> str:
    """The stack, after the checks that need no file (one-line errors)."""
    if req.model is None:
        raise click.UsageError(f"missing --tp: {TP_MISSING}")
    if req.ex.stack not in ("px4", "ardupilot"):
        raise InputError("two results are designed together only with --export px4|ardupilot (their one gyro "
                         "filter on all axes); tune each result alone otherwise")
    if req.kind != "PD":
        raise InputError(f"cannot export a PID to {req.ex.stack}: its rate-loop I acts on the measured rate; "
                         "export the PD (--kind PD)")
    for s in req.sources:
        if not (s.lower().endswith(".json") and Path(s).is_file()):
            raise InputError(f"{s}: with two sources give analyze RESULT.json files (analyze each log with "
                             "--json FILE first)")
    check_export_paths(req.json_target, req.ex.out, True)
    return req.ex.stack


def _axes(req: AxesRequest) -> tuple[list, list, float | None]:
    """The two axes (roll first) with their sources, and the rate both records share."""
    from ..mrft.model import LoopModel
    from ..tune.design import Posterior
    from ..tune.joint import AxisModel, AxisSource
    from .tune import from_result_json

    assert req.model is not None
    srcs = [(path, from_result_json(Path(path), req.model, None)) for path in req.sources]
    (pa, a), (pb, b) = srcs
    if a.loop == b.loop:
        raise InputError(f"{pa} and {pb} are both for the {a.loop} loop: give one roll and one pitch result")
    for path, s in srcs:
        if s.loop not in ("roll", "pitch"):
            alone = ("PX4's x and y share one MPC_XY_* set: tune one of them alone, its export sets both"
                     if s.loop in ("x", "y") else "tune it alone")
            raise InputError(f"{path} is for the {s.loop} loop: the joint gyro cutoff is for roll and pitch; {alone}")
        if s.posterior is None:
            raise InputError(f"{path} has no spreads: the robust designs need the posterior")
    if req.rate_hz is None and a.rate_hz != b.rate_hz:
        raise InputError(f"{pa} records {a.rate_hz} Hz and {pb} {b.rate_hz} Hz: one rate loop runs both axes; "
                         "analyse logs of one controller rate or give --controller-rate HZ")
    srcs.sort(key=lambda ps: ps[1].loop != "roll")
    axes = [AxisModel(str(s.loop), s.model, s.posterior) for _, s in srcs  # eq. (2)'s, as from_result_json reads
            if isinstance(s.model, LoopModel) and isinstance(s.posterior, Posterior)]
    return axes, [(AxisSource(s.heights, s.amplitudes), s.notes) for _, s in srcs], a.rate_hz


def tune_axes(req: AxesRequest) -> None:
    """Design roll and pitch with one gyro cutoff and write the one file the stack loads."""
    from ..tune.closed_loop import RateFilter
    from ..tune.joint import GYRO_FILTER_PARAM, design_axes, export_axes, joint_gyro_cutoff
    from ..tune.stacks import stack_setting
    from .tune import stack_summary, write_export

    stack = _check_request(req)
    axes, extra, rate_source = _axes(req)
    # the rate the stack runs (PX4: an IMU_GYRO_RATEMAX choice), stated; its cutoff note is replaced below
    setting = stack_setting(stack, "roll", req.rate_hz, rate_source, req.ex.gyro_cutoff_hz)
    rate, name = setting.rate_hz, GYRO_FILTER_PARAM[stack]
    joint = None
    with tqdm_progress("tune", unit="cutoff", enabled=not req.quiet) as progress:
        progress(0, 1, "designing roll and pitch with one gyro cutoff")
        if req.auto:
            joint = joint_gyro_cutoff(axes, stack, rate, objective=req.objective, ms_max=req.ms_max,
                                      progress=progress)
            results, said = joint.results, joint.note()
        else:
            assert req.ex.gyro_cutoff_hz is not None
            results = design_axes(axes, rate, RateFilter(req.ex.gyro_cutoff_hz, name), objective=req.objective,
                                  ms_max=req.ms_max)
            said = f"{name} = {req.ex.gyro_cutoff_hz:g} Hz (--gyro-cutoff) for roll and pitch: one filter on all axes"
    results = tuple(dataclasses.replace(r, notes=(*notes, setting.notes[0], said, *r.notes))
                    for r, (_, notes) in zip(results, extra))
    export = export_axes(stack, results, req.design, [src for src, _ in extra], clamp=req.ex.clamp, cutoff=joint)
    if req.json_target:
        dump_json({"export": {"joint": export.to_json()},
                   "tune_results": {r.loop: r.to_json() for r in results}}, req.json_target)
    summary = [f"{name} = {export.params()[name]:g} Hz for both axes ({'auto' if req.auto else '--gyro-cutoff'})"]
    for e in export.exports:
        summary += stack_summary(e, console=False)
    summary += export.console_lines()
    write_export(export.file_text(), summary, req.ex.out, req.json_target)
