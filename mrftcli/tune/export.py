"""Gains in the form a user pastes into a flight stack: generic JSON/table, HEAR PID JSON, PX4 parameters.

These are the design's own forms (its first-order Tf, its rate), kept for ``tune --json``'s ``export``
block; ``tune --export`` designs with the rate and filter each stack really runs and writes the file
it loads, checked against its ranges (:mod:`mrftcli.tune.stacks`).

* **generic**: Kp, Ki, Kd (parallel form), Tf [s] (first-order derivative filter), rate [Hz], with the
  derivative on the measurement (:class:`mrftcli.mrft.controller.Controller`).
* **HEAR** (the HEAR flight stack's ``PID_parameters`` JSON: ``id``, ``kp``, ``ki``, ``kd``, ``kdd``,
  ``anti_windup``, ``en_pv_derivation``, ``dt``): ``en_pv_derivation = 1`` makes the D term act on the
  process variable's derivative (derivative on the measurement); HEAR has no derivative-filter field,
  so the rate signal fed to ``PV_DOT`` must be filtered with Tf (stated in ``note``).
* **PX4** attitude (roll, pitch): the angle P / rate PID cascade, with the rate loop's I and D at zero,
  u = P_rate (P_att (r - y) - y') = P_rate P_att e - P_rate y', is exactly a PD on the angle with the
  derivative on the measurement: ``MC_ROLL_P = Kp / Kd``, ``MC_ROLLRATE_P = Kd`` (likewise PITCH).
  It holds when (:func:`px4_params` checks it): the design is a PD (a rate-loop I acts on y' and so on the
  measurement, which a parallel PID on the error is not); the loop is roll or pitch; the MRFT command
  was PX4's normalised torque setpoint (|u| <= 1, so each test's relay height h <= 1) and the output
  in radians (rate in rad/s); MC_*RATE_K = 1, MC_*RATE_FF = 0; both loops run at the design rate;
  the gyro rate is filtered like the design's derivative (IMU_GYRO_CUTOFF ~ 1 / (2 pi Tf)).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from ..errors import InputError
from ..io.logtypes import gain_unit, output_unit, sig
from .closed_loop import Controller

if TYPE_CHECKING:
    from .design import TuneResult

__all__ = ["generic_export", "generic_units", "hear_json", "hear_params", "px4_params", "unit_reasons",
           "format_table", "HEAR_PID_ID"]

#: HEAR's PID_ID enum (PID_X, PID_Y, PID_Z, PID_ROLL, PID_PITCH, PID_YAW, PID_YAW_RATE).
HEAR_PID_ID = {"x": 0, "y": 1, "altitude": 2, "roll": 3, "pitch": 4, "yaw": 5}


def generic_units(loop: str) -> dict[str, str]:
    """The units of the generic export's numbers for ``loop`` (the command's unit is the log's).

    Examples
    --------
    >>> generic_units("roll")["Kp"]
    'command unit per rad'
    """
    y = output_unit(loop)
    return {"Kp": f"command unit per {y}", "Ki": f"command unit per ({y} s)", "Kd": f"command unit s per {y}",
            "Tf": "s", "rate_hz": "Hz", "cutoff_hz": "Hz", "command": "the log's command unit (the relay's)",
            "output": y}


def generic_export(result: "TuneResult", design: str, kind: str) -> str:
    """``tune --export generic``'s file (JSON text) for any family, as written and as ``tune --report`` shows it:
    eq. (2)'s with its loop and the units of its numbers (:func:`generic_units`); a cascade's outer PD; another
    family's with ``reverse_acting`` (the gains act on -e)."""
    import json

    from ..mrft.cascade import CascadeModel
    from ..mrft.model import LoopModel

    c = result.get(design, kind).controller
    if isinstance(result.model, LoopModel):
        data = {"design": design, "kind": kind, "loop": result.loop, **c.to_dict(), "units": generic_units(result.loop)}
    elif isinstance(result.model, CascadeModel):
        data = {"design": design, "kind": kind, **c.to_dict()}
    else:
        data = {"design": design, "kind": kind, "reverse_acting": result.reverse_acting, **c.to_dict()}
    return json.dumps(data, indent=2) + "\n"


def hear_params(c: Controller, loop: str, scale: float = 1.0) -> dict[str, float]:
    """The fields of HEAR's ``PID_param`` message for ``c`` on ``loop`` (the gains times ``scale``: a unit change)."""
    return {"id": float(HEAR_PID_ID.get(loop, -1)), "kp": scale * c.Kp, "ki": scale * c.Ki, "kd": scale * c.Kd,
            "kdd": 0.0, "anti_windup": 0.0, "en_pv_derivation": 1.0, "dt": c.Ts}


def hear_json(c: Controller, loop: str) -> dict[str, Any]:
    """The HEAR ``PID_parameters`` JSON object of ``c`` for ``loop``.

    Examples
    --------
    >>> hear_json(Controller(2.0, 0.5, 0.3, 0.01, 200.0), "roll")["id"]
    3
    """
    return {**hear_params(c, loop), "id": HEAR_PID_ID.get(loop, -1), "en_pv_derivation": 1,
            "note": "HEAR computes u += kd * PV_DOT: feed PV_DOT with the NEGATED output rate (HEAR_FC's Gain(-1) "
                    f"block), filtered by a first-order lag of {c.Tf * 1e3:.1f} ms as designed (HEAR_FC's own filter is "
                    "a 2nd-order Butterworth at 50 Hz: tune --export hear designs with it); anti_windup 0 = off"}


def unit_reasons(loop: str, heights: Sequence[float], amplitudes: Sequence[float]) -> list[str]:
    """Reasons the log's units are not a flight stack's (normalised command, radians); empty: they are.

    ``heights`` [command units] are the relay heights flown (over 1: not the stack's normalised command),
    ``amplitudes`` [output units] the tests' amplitudes (over 1 on roll or pitch: not radians)."""
    why = []
    if any(h > 1.0 for h in heights):
        why.append(f"the MRFT relay height ({max(heights):.3g}) exceeds 1: the command was not the stack's "
                   "normalised torque/thrust setpoint")
    if loop in ("roll", "pitch") and any(a > 1.0 for a in amplitudes):
        why.append(f"the oscillation amplitude ({max(amplitudes):.3g}) is not an angle in radians (degrees? "
                   "use --output-scale 0.0174533)")
    return why


def px4_params(c: Controller, loop: str, relay_heights: Sequence[float] = (),
               amplitudes: Sequence[float] = ()) -> dict[str, Any]:
    """PX4 parameters ``MC_<AXIS>_P`` = Kp / Kd and ``MC_<AXIS>RATE_P`` = Kd (the export's mapping,
    :func:`mrftcli.tune.stacks.cascade_params`) with the design's own filter as ``IMU_GYRO_CUTOFF``, or
    InputError with the reasons the mapping does not hold.

    ``relay_heights`` and ``amplitudes`` are the MRFT tests' h [command units] and output amplitudes
    (when known): PX4's torque setpoint is normalised to [-1, 1], and an attitude in radians of an
    MRFT test stays well below 1 rad.
    """
    from .stacks import cascade_params

    why = []
    if loop not in ("roll", "pitch"):
        why.append(f"PX4's {loop} loop is not an angle-P / rate-PID cascade on the command tested (only roll and pitch map)")
    if c.Ki > 0:
        why.append("the design has integral action: PX4's rate-loop I acts on the measured rate, so a PID on the "
                   "angle error does not map exactly (use the PD design)")
    why += unit_reasons(loop, relay_heights, amplitudes)
    if why:
        raise InputError("cannot export to PX4: " + "; ".join(why))
    if c.Kd <= 0:
        raise InputError("cannot export to PX4: the design has no derivative gain (MC_*RATE_P would be 0)")
    return {**cascade_params(c, loop, "px4", None),
            "IMU_GYRO_CUTOFF": 1.0 / (2.0 * math.pi * c.Tf) if c.Tf > 0 else None,
            "rate_hz": c.rate_hz,
            "conditions": "command = PX4 normalised torque setpoint, output in rad; attitude and rate loops at rate_hz"}


def format_table(result: "TuneResult") -> str:
    """The terminal table of a :class:`~mrftcli.tune.design.TuneResult` (any family)."""
    from ..mrft.model import LoopModel

    m = result.model
    if not isinstance(m, LoopModel):
        return _grid_table(result)
    from .design import assumptions_first, tau_line

    first = [n for n in assumptions_first(result.notes) if n.startswith("assumed:")]
    lines = [f"note: {n}" for n in first]  # what the designs rest on (a lead taken as tau 0), before the model
    lines += [f"model: Tp {m.Tp:g} s  Td {m.Td:.4g} s  {tau_line(result)}  K {m.K:.4g}   rate {result.rate_hz:g} Hz  "
             f"objective {result.objective.upper()}  Ms <= {result.ms_max:g}  noise gain <= {result.effort_max:.4g}"]
    lines.append(f"{'design':<12}{'kind':<5}{'Kp':>10}{'Ki':>10}{'Kd':>10}{'Tf [ms]':>8}{'GM':>7}{'PM[deg]':>8}"
                 f"{'DM[ms]':>8}{'Ms':>6}{'OS[%]':>7}{'rise[s]':>8}{'set[s]':>7}{'J':>8}"
                 f"  {'worst of 95 %: PM':>17}{'Ms':>6}{'OS[%]':>7}")

    y = output_unit(result.loop)
    lines.insert(len(first) + 1, f"gains: Kp [command per {y}], Ki [command per {y} s], Kd [command s per {y}]; "
                    f"K [{gain_unit(result.loop)}]")
    for d in result.designs:
        c, g, s = d.controller, d.margins, d.step
        w = d.posterior.get("worst", {}) if d.posterior else {}

        lines.append(f"{d.name:<12}{d.kind:<5}{c.Kp:>10.4g}{c.Ki:>10.4g}{c.Kd:>10.4g}{c.Tf * 1e3:>8.2f}"
                     f"{sig(g.gain_margin, '.2f'):>7}{sig(g.phase_margin_deg, '.1f'):>8}{sig(g.delay_margin_s * 1e3, '.1f'):>8}"
                     f"{sig(g.Ms, '.2f'):>6}{sig(s.overshoot_pct, '.1f'):>7}{sig(s.rise_s, '.3f'):>8}{sig(s.settling_s, '.2f'):>7}"
                     f"{sig(d.criterion, '.4g'):>8}  {sig(w.get('phase_margin_deg'), '.1f'):>17}{sig(w.get('Ms'), '.2f'):>6}"
                     f"{sig(w.get('overshoot_pct'), '.1f'):>7}")
    if any(d.load for d in result.designs):
        rec = ", ".join(f"{d.name} {sig(d.load.get('recovery_s'), '.2f')} s" for d in result.designs if d.load)
        lines.append(f"J: {result.objective.upper()} of a unit setpoint step; a PID's adds the {result.objective.upper()} "
                     f"of a load step at the plant input (size: its PD's Kp). PID load recovery (2 %): {rec}")
    for n in result.notes:
        if n not in first:
            lines.append(f"note: {n}")
    return "\n".join(lines)


def _grid_table(res: "TuneResult") -> str:
    """The table of :mod:`mrftcli.tune.grid`'s designs (a process family's, or an outer loop's PD on the
    cascade): the model's lines, the notes, then every design's gains, nominal margins and the worst over
    the draws (no step figures)."""
    from ..mrft.cascade import CascadeModel

    m = res.model
    if isinstance(m, CascadeModel):
        y = output_unit(res.loop)
        lines = [f"loop {res.loop} on the cascade: Td {m.Td:.4g} s  tau {m.tau * 1e3:.4g} ms  K {m.K:.4g}  through "
                 f"{m.inner.loop or 'the inner loop'}; rate {res.rate_hz:g} Hz"]
    else:
        y = "output unit"
        params = "  ".join(f"{p.name} {p.value:.4g} {p.unit}" for p in m.parameters.values())
        tu = res.rule_cycle.get("ultimate_period_s", math.nan)
        lines = [f"{m.family}: G(s) = {getattr(m, 'transfer_function', m.structure)}; {params}",
                 f"ultimate period of the sampled loop {tu * 1e3:.4g} ms; rate {res.rate_hz:g} Hz"]
    lines.append(f"gains: Kp [command per {y}], Ki [command per {y} s], Kd [command s per {y}]; "
                 f"IAE [{y} s]")
    lines += [f"note: {n}" for n in res.notes if n]
    head = ("design", "kind", "Kp", "Ki", "Kd", "Tf [ms]", "PM [deg]", "GM", "Ms", "crossover [Hz]",
            "worst PM [deg]", "worst Ms", "IAE", "criterion")
    rows = [head]
    for d in res.designs:
        c, n, w = d.controller, d.margins, d.posterior.get("worst")
        rows.append((d.name, d.kind, sig(c.Kp), sig(c.Ki), sig(c.Kd), sig(c.Tf * 1e3), sig(n.phase_margin_deg, '.3g'),
                     sig(n.gain_margin, '.3g'), sig(n.Ms, '.3g'), sig(n.w_gc / (2 * math.pi), '.3g'),
                     "-" if w is None else sig(w["phase_margin_deg"], '.3g'), "-" if w is None else sig(w["Ms"], '.3g'),
                     sig(d.criterion, '.3g'), d.criterion_definition))
    widths = [max(len(r[k]) for r in rows) for k in range(len(head))]
    lines += ["  ".join(c.ljust(wd) for c, wd in zip(r, widths)).rstrip() for r in rows]
    return "\n".join(lines)
