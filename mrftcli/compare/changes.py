"""The comparison itself: match the two sides' loops, then test each parameter's change.

The change of a parameter is the difference of two **independent** estimates (two flights, two
analyses), d = new - baseline. Its uncertainty combines the two sides' standard deviations in
quadrature. Where a side's interval is asymmetric, each side of it gives its own standard deviation
(half-width / z of the interval's confidence), and the side facing the other estimate is used:

    sigma_down = sqrt(s_new,below^2 + s_base,above^2)     (how far d may really be lower)
    sigma_up   = sqrt(s_new,above^2 + s_base,below^2)
    interval   = [d - z_c sigma_down, d + z_c sigma_up],  z_c = Phi^-1(1 - (1 - c) / 2)

The change is **significant** when that interval excludes zero (a two-sided test at confidence c per
parameter; with ``correction="bonferroni"`` each of a loop's m tested parameters is tested at
1 - (1 - c) / m, so the chance of any false alarm in a loop stays below 1 - c). A side that cannot
determine a parameter (no estimate, or an open interval such as Td without an upper bound) makes it
**undetermined**: reported as such, never as a change.

The change **fails** the comparison (verdict ``changed``) when it is significant **and** its point
estimate is beyond the tolerance that applies (:class:`Tolerance`); when no tolerance is given
anywhere (no ``--fail-on``, no ``tol`` in a reference file), every significant change fails.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from statistics import NormalDist

from ..errors import InputError
from .inputs import Side
from ..jsonable import finite_or_none
from ..mrft.parameter import ParameterEstimate
from .records import PARAMETERS, Comparison, LoopEstimates, MissingResult, ParameterChange, Tolerance

__all__ = ["CompareOptions", "compare_sides", "compare_estimates", "critical_z", "side_sigmas",
           "comparable", "CORRECTIONS"]

#: Multiple-comparison corrections: none (per parameter) or Bonferroni over a loop's parameters.
CORRECTIONS: tuple[str, ...] = ("none", "bonferroni")


@dataclass(frozen=True)
class CompareOptions:
    """How to compare.

    Parameters
    ----------
    confidence : float
        Confidence of the change intervals, in (0, 1) (0.95).
    correction : {"none", "bonferroni"}
        Per-parameter test, or Bonferroni over each loop's tested parameters.
    fail_on : tuple of Tolerance
        ``--fail-on`` tolerances; they override a reference file's for the same loop and parameter.
    loops : tuple of str
        Compare only these loops (empty: all).
    """

    confidence: float = 0.95
    correction: str = "none"
    fail_on: tuple[Tolerance, ...] = ()
    loops: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not 0.5 <= self.confidence < 1.0:
            raise InputError(f"confidence {self.confidence}: give a value in [0.5, 1), e.g. 0.95")
        if self.correction not in CORRECTIONS:
            raise InputError(f"correction {self.correction!r}: use one of {', '.join(CORRECTIONS)}")


def critical_z(confidence: float) -> float:
    """z_c of a two-sided interval at ``confidence`` (1.96 at 0.95).

    >>> round(critical_z(0.95), 3)
    1.96
    """
    return NormalDist().inv_cdf(0.5 + confidence / 2.0)


def comparable(e: ParameterEstimate) -> bool:
    """A finite estimate with both ends of its 95 % interval finite, or (a reference's) no interval and a finite
    std: a change can be tested (an open end, as Td bounded from below only, cannot)."""
    ends = [math.isfinite(e.ci95_low), math.isfinite(e.ci95_high)]
    return math.isfinite(e.value) and (all(ends) or (not any(ends) and math.isfinite(e.std)))


def side_sigmas(e: ParameterEstimate) -> tuple[float, float]:
    """(below, above) standard deviations of a :func:`comparable` estimate [SI units].

    From the 95 % interval's half-widths when it has one (asymmetric intervals keep their shape), else the
    std on both sides.
    """
    if math.isfinite(e.ci95_low) and math.isfinite(e.ci95_high):
        z = critical_z(0.95)
        return max(e.value - e.ci95_low, 0.0) / z, max(e.ci95_high - e.value, 0.0) / z
    return e.std, e.std


def _undetermined_note(base: ParameterEstimate, new: ParameterEstimate) -> str:
    def why(e: ParameterEstimate, side: str) -> str | None:
        if comparable(e):
            return None
        if not math.isfinite(e.value):
            return f"no {side} estimate"
        if math.isfinite(e.ci95_low):
            return f"{side} bounded below only (> {e.ci95_low:.4g})"
        return f"{side} interval open"

    return "; ".join(w for w in (why(base, "baseline"), why(new, "new")) if w)


def compare_estimates(base: ParameterEstimate, new: ParameterEstimate, *, z_crit: float,
                      tolerance: Tolerance | None, fail_without_tolerance: bool,
                      where: tuple[str | None, str, str], model: str | None = None) -> ParameterChange:
    """Test one parameter's change (module docstring) with the critical value ``z_crit``; ``where``: the
    change's log or vehicle name, loop and parameter; ``model``: the model the sides identified (None: unstated)."""
    row = ParameterChange(*where, finite_or_none(base.value), finite_or_none(new.value), None, None, None, None,
                          False, tolerance.text if tolerance is not None else None, False, "undetermined",
                          unit=base.unit or new.unit, model=model)
    if not (comparable(base) and comparable(new)):
        return dataclasses.replace(row, note=_undetermined_note(base, new))
    b_below, b_above = side_sigmas(base)
    n_below, n_above = side_sigmas(new)
    d = new.value - base.value
    sigma_down, sigma_up = math.hypot(n_below, b_above), math.hypot(n_above, b_below)
    low, high = d - z_crit * sigma_down, d + z_crit * sigma_up
    towards_zero = sigma_down if d > 0 else sigma_up
    z = d / towards_zero if towards_zero > 0 else (0.0 if d == 0 else math.copysign(math.inf, d))
    significant = low > 0.0 or high < 0.0
    beyond = tolerance is not None and tolerance.exceeded_by(d, base.value)
    if not significant:
        verdict = "unchanged"
    elif beyond or (tolerance is None and fail_without_tolerance):
        verdict = "changed"
    else:
        verdict = "significant"
    return dataclasses.replace(row, change=d, low=low, high=high, z=z, significant=significant,
                               beyond_tolerance=beyond, verdict=verdict)


def _tolerance_for(loop: str, param: str, fail_on: tuple[Tolerance, ...],
                   pair: tuple[LoopEstimates, LoopEstimates]) -> Tolerance | None:
    """--fail-on for this loop, then --fail-on for every loop, then the sides' own (reference) tolerances."""
    for wanted in (loop, None):
        for tol in fail_on:
            if tol.parameter == param and tol.loop == wanted:
                return tol
    for side in pair:
        for tol in side.tolerances:
            if tol.parameter == param and tol.loop in (loop, None):
                return tol
    return None


def _compare_loop(b: LoopEstimates, n: LoopEstimates, name: str | None, options: CompareOptions,
                  fail_without_tolerance: bool, skip_absent: bool) -> list[ParameterChange]:
    # eq. (2)'s in their order, then a process family's others in the order the sides name them
    params = [p for p in dict.fromkeys((*PARAMETERS, *b.parameters, *n.parameters))
              if p in b.parameters or p in n.parameters]
    if skip_absent:  # a reference states only the parameters it checks
        params = [p for p in params if p in b.parameters and p in n.parameters]
    missing = ParameterEstimate(math.nan, math.nan, math.nan, math.nan, "")
    pairs = {p: (b.parameters.get(p, missing), n.parameters.get(p, missing)) for p in params}
    tested = sum(1 for be, ne in pairs.values() if comparable(be) and comparable(ne))
    alpha = 1.0 - options.confidence
    if options.correction == "bonferroni" and tested > 1:
        alpha /= tested
    z_crit = critical_z(1.0 - alpha)
    out = []
    for p, (be, ne) in pairs.items():
        tol = _tolerance_for(n.loop, p, options.fail_on, (b, n))
        out.append(compare_estimates(be, ne, z_crit=z_crit, tolerance=tol, fail_without_tolerance=fail_without_tolerance,
                                     where=(name, n.loop, p), model=b.model or n.model))
    return out


_Row = tuple[str | None, str, LoopEstimates | None, LoopEstimates | None]


def _merged(named: LoopEstimates | None, plain: LoopEstimates | None, kind: str) -> LoopEstimates | None:
    """A named entry over its side's plain entry for the loop.

    For a reference both apply: the named table's parameters and tolerances win, the plain table's
    fill in the rest (``[vehicle7.altitude] tau`` overrides ``[altitude] tau`` for vehicle7 only).
    """
    if named is None or plain is None or kind != "reference":
        return named if named is not None else plain
    params = {**plain.parameters, **named.parameters}
    own = {t.parameter for t in named.tolerances}
    tols = (*named.tolerances, *(t for t in plain.tolerances if t.parameter not in own))
    return LoopEstimates(loop=named.loop, name=named.name, source=named.source, parameters=params,
                         tolerances=tols)


def _present(e: LoopEstimates | None) -> bool:
    """The entry stands for a loop the log holds (identified, or failed), not an absent one."""
    return e is not None and not e.absent


def _match(base: Side, new: Side) -> tuple[list[_Row], list[str]]:
    """(name, loop, baseline loop, new loop) for every key on either side, and notes on what matched nothing.

    Named entries (batch logs or vehicles, named reference tables) match by (name, loop); an unnamed
    entry (a single analysis, a reference's [loop] table) stands for its loop on every name. A
    reference's entry applies only where the other side holds the loop; one that applies nowhere is
    a note (a named reference table whose name the other side does not have at all, too).
    """
    sides = (base, new)
    named = [{e.key: e for e in s.loops if e.name is not None} for s in sides]
    plain = [{e.loop: e for e in s.loops if e.name is None} for s in sides]
    names = [{e.name for e in s.loops if e.name is not None} for s in sides]
    refs = [s.kind == "reference" for s in sides]
    used: set[tuple[int, str]] = set()
    rows: list[_Row] = []
    for name, loop in dict.fromkeys([*named[0], *named[1]]):
        if any(refs[i] and (name, loop) in named[i] and name not in names[1 - i] for i in (0, 1)):
            continue  # a reference table for a name the other side does not have: noted below
        own = [named[i].get((name, loop)) for i in (0, 1)]
        pair = [_merged(own[i], plain[i].get(loop), sides[i].kind) for i in (0, 1)]
        for i in (0, 1):
            if own[i] is None and pair[i] is not None:
                if refs[i] and not _present(pair[1 - i]):
                    pair[i] = None  # a plain reference table does not apply to a loop the log does not hold
                else:
                    used.add((i, loop))
        rows.append((name, loop, pair[0], pair[1]))
    notes = []
    for loop in dict.fromkeys([*plain[0], *plain[1]]):
        pair = [plain[0].get(loop), plain[1].get(loop)]
        unused = [pair[i] is not None and (i, loop) not in used for i in (0, 1)]
        if not any(unused):
            continue
        for i in (0, 1):
            entry = pair[i]
            if unused[i] and refs[i] and pair[1 - i] is None and entry is not None:
                notes.append(f"{entry.source}: [{loop}] matches no {loop} loop in {sides[1 - i].path}")
                pair[i] = None
        if pair[0] is not None or pair[1] is not None:
            rows.append((None, loop, pair[0], pair[1]))
    for i in (0, 1):
        if refs[i]:
            notes += [f"{e.source}: [{e.name}.{e.loop}] matches nothing in {sides[1 - i].path} (no {e.name})"
                      for e in named[i].values() if e.name not in names[1 - i]]
    return rows, notes


def _missing(name: str | None, loop: str, b: LoopEstimates | None, n: LoopEstimates | None) -> MissingResult | None:
    """The loop cannot be compared: it is on one side only (absent, or failed, on the other), or the two
    sides identified different model families."""
    if b is None or n is None or not b.usable or not n.usable:
        side = "baseline" if b is None or not b.usable else "new"
        other = n if side == "baseline" else b
        gone = b if side == "baseline" else n
        reason = (gone.error or "").strip() if gone is not None else f"no {side} result for this loop"
        assert other is not None
        return MissingResult(name=name, loop=loop, side=side, reason=reason or f"no {side} result for this loop")
    if b.model is not None and n.model is not None and b.model != n.model:  # a K of fopdt is not eq. (2)'s
        return MissingResult(name=name, loop=loop, side="both",
                             reason=f"the analyses identified different models ({b.model}, {n.model}): their "
                                    "parameters are not comparable; analyse both with the same --model")
    return None


def _neither(name: str | None, loop: str, b: LoopEstimates | None, n: LoopEstimates | None) -> str | None:
    """None when some side has a result for the loop; else a note when it failed (not merely absent) on both."""
    if (b is not None and b.usable) or (n is not None and n.usable):
        return None
    if _present(b) or _present(n):
        return f"{name + ' ' if name else ''}{loop}: not compared, no result on either side"
    return ""


def _asked_on_neither(asked: tuple[str, ...], rows: list[_Row], sides: tuple[Side, Side]) -> list[MissingResult]:
    """The loops asked for (``--loop``) when neither side records any of them: each missing on both (exit 10),
    never "no change beyond tolerance in 0 parameters" (exit 0). When some asked loop is recorded, one that is
    not stays unsaid, as a loop absent or failed on both sides (issue 40: a fleet CI job asks for altitude, roll
    and pitch of every folder, an altitude-only one included). A loop that failed on both sides is not held."""
    held = {loop for _, loop, b, n in rows if (b is not None and b.usable) or (n is not None and n.usable)}
    if not asked or held & set(asked):
        return []

    def holds(s: Side) -> str:
        loops = sorted({e.loop for e in s.loops if e.usable})
        return f"{s.path} holds {', '.join(loops)}" if loops else f"{s.path} holds no usable loop"

    return [MissingResult(name=None, loop=loop, side="both",
                          reason=f"no {loop} result on either side ({holds(sides[0])}; {holds(sides[1])})")
            for loop in dict.fromkeys(asked) if loop not in held]


def compare_sides(base: Side, new: Side, options: CompareOptions | None = None) -> Comparison:
    """Compare every matched loop and parameter of two sides.

    Parameters
    ----------
    base, new : Side
        From :func:`mrftcli.compare.inputs.read_side`.
    options : CompareOptions, optional
        Confidence, correction, tolerances, loops.

    Returns
    -------
    Comparison
        One :class:`ParameterChange` per matched loop and parameter; loops absent or unusable on a side
        as :class:`MissingResult`; its ``exit_code`` is 0, 9 (changed) or 10 (incomplete).
    """
    options = options or CompareOptions()
    fail_without_tolerance = not options.fail_on and not any(e.tolerances for e in (*base.loops, *new.loops))
    skip_absent = "reference" in (base.kind, new.kind)
    changes: list[ParameterChange] = []
    missing: list[MissingResult] = []
    notes = [*base.notes, *new.notes]
    rows, unmatched = _match(base, new)
    notes += unmatched
    missing += _asked_on_neither(options.loops, rows, (base, new))
    for name, loop, b, n in rows:
        if options.loops and loop not in options.loops:
            continue
        neither = _neither(name, loop, b, n)
        if neither is not None:  # absent or failed on both sides: not a change
            if neither:
                notes.append(neither)
            continue
        gap = _missing(name, loop, b, n)
        if gap is not None:
            missing.append(gap)
            continue
        assert b is not None and n is not None
        if b.tp is not None and n.tp is not None and not math.isclose(b.tp, n.tp, rel_tol=1e-9):
            notes.append(f"{name + ' ' if name else ''}{loop}: the analyses assumed different Tp "
                         f"({b.tp:.4g} s, {n.tp:.4g} s); Td, tau and K depend on it")
        changes.extend(_compare_loop(b, n, name, options, fail_without_tolerance, skip_absent))
    return Comparison(baseline=base.path, new=new.path, confidence=options.confidence, correction=options.correction,
                      fail_on=tuple(t.text for t in options.fail_on), changes=tuple(changes),
                      missing=tuple(missing), notes=tuple(dict.fromkeys(notes)))
