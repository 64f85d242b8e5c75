"""One gyro cutoff for roll and pitch, designed from both loops (PX4 ``IMU_GYRO_CUTOFF``, ArduPilot ``INS_GYRO_FILTER``).

PX4 and ArduPilot filter the gyro with ONE 2nd-order Butterworth for all three axes, so roll and
pitch fly with the same cutoff. Each axis is designed with it (:func:`mrftcli.tune.design.tune` with
the stack's :class:`~mrftcli.tune.closed_loop.RateFilter`), and the cutoff is chosen from both:

**The criterion.** A lower cutoff passes less gyro noise to the motors (the controller's largest
gain |C| over frequency, the noise gain, falls roughly in proportion to the cutoff) but adds phase
lag, so the robust PD must back off. The joint cutoff is the LOWEST cutoff f of the candidate list
(:data:`JOINT_CUTOFFS_HZ`, below the filter's bypass at half the controller rate) such that, at f
and at every candidate above f, BOTH axes' robust PDs

1. hold tune's robust constraints: Ms <= ``ms_max`` on every draw of the 95 % set and the noise
   gain within tune's limit (``Design.constraints["feasible"]``), and
2. lose at most ``max_loss`` (default :data:`JOINT_MAX_LOSS`, 10 %) of their performance: the
   expected criterion (IAE of a unit step, mean over the posterior draws) is at most
   (1 + max_loss) times that of the same axis's robust PD with the filter bypassed (cutoff 0,
   the stack's "off").

"Every candidate above" makes the choice a band (no isolated passing cutoff among failing ones) and
lets the search stop at the first failure going down; :func:`joint_gyro_cutoff` tries the
candidates from the top. The designs at the chosen cutoff are the ones exported; their margins are
those of the loop with the stack's Butterworth.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from ..analyze import AnalysisResult
from ..errors import InputError
from ..jsonable import check_schema_version
from ..mrft.model import LoopModel
from ..progress import Progress, report
from .closed_loop import RateFilter
from .design import DesignOptions, Posterior, TuneResult, tune
from .stacks import ExportEvidence, StackExport, export_design

__all__ = ["AxisModel", "AxisSource", "merge_exports", "CutoffTrial", "JointCutoff", "JointExport", "joint_gyro_cutoff", "design_axes",
           "export_axes", "joint_cutoff_of_analyses", "JOINT_CUTOFFS_HZ",
           "JOINT_MAX_LOSS", "JOINT_SCHEMA_VERSION", "GYRO_FILTER_PARAM"]

#: Candidate cutoffs [Hz] (round values a user would set); those at or above half the rate are left out.
JOINT_CUTOFFS_HZ = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0, 60.0, 80.0, 100.0)
#: Fraction of the expected criterion an axis may lose to the filter against the filter bypassed.
JOINT_MAX_LOSS = 0.10
#: Version of :meth:`JointCutoff.to_json`'s object.
JOINT_SCHEMA_VERSION = 1
#: The parameter that sets the vehicle-wide gyro filter, per stack.
GYRO_FILTER_PARAM = {"px4": "IMU_GYRO_CUTOFF", "ardupilot": "INS_GYRO_FILTER"}


@dataclass(frozen=True)
class AxisModel:
    """One axis to design: its loop (``roll`` or ``pitch``), identified model and posterior draws."""

    loop: str
    model: LoopModel
    posterior: Posterior


@dataclass(frozen=True)
class CutoffTrial:
    """Both axes' robust PDs at one cutoff.

    Attributes
    ----------
    cutoff_hz : float
        The gyro cutoff [Hz] (0: filter bypassed, the reference).
    worst_ms : tuple of float
        Per axis (in the order given), the largest Ms over the 95 % set [-].
    criterion : tuple of float
        Per axis, the expected criterion (mean over the draws) [output unit s].
    noise_gain : tuple of float
        Per axis, the controller's largest |C| over frequency [command / output unit].
    feasible : tuple of bool
        Per axis, whether tune's robust constraints hold.
    passed : bool
        Both axes feasible and within the allowed loss of their reference (False for the reference).
    """

    cutoff_hz: float
    worst_ms: tuple[float, ...]
    criterion: tuple[float, ...]
    noise_gain: tuple[float, ...]
    feasible: tuple[bool, ...]
    passed: bool

    def to_json(self) -> dict[str, Any]:
        return {"cutoff_hz": self.cutoff_hz, "worst_ms": list(self.worst_ms), "criterion": list(self.criterion),
                "noise_gain": list(self.noise_gain), "feasible": list(self.feasible), "passed": self.passed}

    @classmethod
    def from_json(cls, data: Any) -> "CutoffTrial":
        try:
            return cls(float(data["cutoff_hz"]), tuple(float(v) for v in data["worst_ms"]),
                       tuple(float(v) for v in data["criterion"]), tuple(float(v) for v in data["noise_gain"]),
                       tuple(bool(v) for v in data["feasible"]), bool(data["passed"]))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"joint cutoff: malformed trial ({err})") from err


@dataclass(frozen=True)
class JointCutoff:
    """The cutoff chosen for both axes, every trial that led to it, and the axes' designs with it.

    Attributes
    ----------
    stack : str
        ``px4`` or ``ardupilot``.
    parameter : str
        ``IMU_GYRO_CUTOFF`` or ``INS_GYRO_FILTER``.
    cutoff_hz : float
        The chosen cutoff [Hz].
    rate_hz : float
        Controller rate the axes were designed at [Hz].
    loops : tuple of str
        The axes, in the order of every per-axis tuple.
    max_loss : float
        Allowed loss of the expected criterion against the filter bypassed [-].
    reference : CutoffTrial
        The axes' robust PDs with the filter bypassed.
    trials : tuple of CutoffTrial
        The candidates tried, from the highest down (the last one failed, unless the list ran out).
    results : tuple of TuneResult
        Per axis, the designs at ``cutoff_hz`` (model-based and robust PD); not in the JSON (each
        axis's ``TuneResult.to_json`` is written beside it).
    """

    stack: str
    parameter: str
    cutoff_hz: float
    rate_hz: float
    loops: tuple[str, ...]
    max_loss: float
    reference: CutoffTrial
    trials: tuple[CutoffTrial, ...]
    results: tuple[TuneResult, ...] = ()

    def chosen(self) -> CutoffTrial:
        """The trial at :attr:`cutoff_hz`."""
        return next(t for t in self.trials if t.cutoff_hz == self.cutoff_hz)

    def note(self) -> str:
        """One sentence stating the choice and its cost, for the output's first lines."""
        c, r = self.chosen(), self.reference
        loss = ", ".join(f"{lp} {100 * (j / j0 - 1):+.1f} %" for lp, j, j0 in zip(self.loops, c.criterion,
                                                                                   r.criterion))
        noise = ", ".join(f"{lp} {g:.3g}" for lp, g in zip(self.loops, c.noise_gain))
        return (f"{self.parameter} = {self.cutoff_hz:g} Hz designed for {' and '.join(self.loops)} together: the "
                f"lowest cutoff at which both robust PDs hold Ms <= their limit on the 95 % set and lose at most "
                f"{100 * self.max_loss:g} % of their expected IAE against the filter off ({loss}); noise gain "
                f"{noise}")

    def to_json(self) -> dict[str, Any]:
        """The versioned JSON object (:data:`JOINT_SCHEMA_VERSION`)."""
        return {"schema_version": JOINT_SCHEMA_VERSION, "stack": self.stack, "parameter": self.parameter,
                "cutoff_hz": self.cutoff_hz, "rate_hz": self.rate_hz, "loops": list(self.loops),
                "max_loss": self.max_loss, "reference": self.reference.to_json(),
                "trials": [t.to_json() for t in self.trials]}

    @classmethod
    def from_json(cls, data: Any) -> "JointCutoff":
        """The record of :meth:`to_json` (without the designs); InputError (one line) on a bad version or field."""
        d = check_schema_version(data, "joint cutoff", JOINT_SCHEMA_VERSION)
        try:
            head = (str(d["stack"]), str(d["parameter"]), float(d["cutoff_hz"]), float(d["rate_hz"]),
                    tuple(str(v) for v in d["loops"]), float(d["max_loss"]))
            trials = tuple(CutoffTrial.from_json(t) for t in d["trials"])
            reference = CutoffTrial.from_json(d["reference"])
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"joint cutoff: missing or malformed field ({err})") from err
        return cls(*head, reference, trials)


def design_axes(axes: Sequence[AxisModel], rate_hz: float, rate_filter: RateFilter, *, objective: str = "iae",
                ms_max: float = 1.6) -> tuple[TuneResult, ...]:
    """Each axis's model-based and robust PD at ``rate_hz`` with ``rate_filter`` (tune's designs, PD only)."""
    options = DesignOptions(objective=objective, ms_max=ms_max, designs=("model-based", "robust"), kinds=("PD",),
                            rate_filter=rate_filter)
    return tuple(tune(a.model, rate_hz, posterior=a.posterior, options=options, loop=a.loop) for a in axes)


def _trial(cutoff_hz: float, results: Sequence[TuneResult], reference: CutoffTrial | None,
           max_loss: float) -> CutoffTrial:
    ds = [r.get("robust", "PD") for r in results]
    J = tuple(float(d.criterion_expected) for d in ds)
    feasible = tuple(bool(d.constraints.get("feasible", False)) for d in ds)
    within = reference is not None and all(j <= (1 + max_loss) * j0 for j, j0 in zip(J, reference.criterion))
    return CutoffTrial(cutoff_hz, tuple(float(d.posterior["worst"]["Ms"]) for d in ds), J,
                       tuple(float(d.controller.noise_gain()) for d in ds), feasible, bool(within and all(feasible)))


def _check_axes(axes: Sequence[AxisModel], stack: str) -> None:
    if stack not in GYRO_FILTER_PARAM:
        raise InputError(f"a joint gyro cutoff is for --export px4|ardupilot (one gyro filter on all axes), "
                         f"not {stack}")
    loops = [a.loop for a in axes]
    if sorted(loops) != ["pitch", "roll"]:
        raise InputError(f"the joint gyro cutoff needs one roll and one pitch analysis, got {' and '.join(loops)}")
    for a in axes:
        if a.posterior.n < 2:
            raise InputError(f"the {a.loop} analysis has no posterior draws: the robust designs the cutoff is "
                             "chosen from need them")


def joint_gyro_cutoff(axes: Sequence[AxisModel], stack: str, rate_hz: float, *, objective: str = "iae",
                      ms_max: float = 1.6, max_loss: float = JOINT_MAX_LOSS,
                      candidates: Sequence[float] = JOINT_CUTOFFS_HZ, progress: Progress | None = None) -> JointCutoff:
    """The stack's one gyro cutoff for roll and pitch, chosen from both axes (criterion: module docstring).

    Parameters
    ----------
    axes : sequence of AxisModel
        One roll and one pitch axis, each with posterior draws.
    stack : {"px4", "ardupilot"}
    rate_hz : float
        The rate the stack's rate loop runs at [Hz] (PX4: an ``IMU_GYRO_RATEMAX`` choice).
    objective : {"iae", "itae"}
    ms_max : float
        Limit on Ms over the 95 % set [-].
    max_loss : float
        Allowed loss of each axis's expected criterion against the filter bypassed [-], in (0, 1).
    candidates : sequence of float
        Cutoffs to choose from [Hz]; those at or above half ``rate_hz`` (where the filter is bypassed)
        are left out.
    progress : Progress, optional
        Called as ``progress(done, total, stage)`` per cutoff tried (total: the most it may try).

    Returns
    -------
    JointCutoff
        With ``results``: each axis's designs at the chosen cutoff.

    Raises
    ------
    InputError
        Not one roll and one pitch axis with draws; no candidate below half the rate; or even the
        highest candidate fails (the message names the axis and why).
    """
    _check_axes(axes, stack)
    if not (0.0 < max_loss < 1.0):
        raise InputError(f"the allowed performance loss must be a fraction in (0, 1), got {max_loss}")
    cands = sorted((float(f) for f in candidates if 0 < f < rate_hz / 2), reverse=True)
    if not cands:
        raise InputError(f"no candidate gyro cutoff below half the rate ({rate_hz / 2:g} Hz)")
    name = GYRO_FILTER_PARAM[stack]
    report(progress, 0, len(cands) + 1, f"{name} off (the reference)")
    ref_results = design_axes(axes, rate_hz, RateFilter(0.0, name), objective=objective, ms_max=ms_max)
    reference = _trial(0.0, ref_results, None, max_loss)
    trials: list[CutoffTrial] = []
    chosen: tuple[float, tuple[TuneResult, ...]] | None = None
    for i, f in enumerate(cands):
        report(progress, i + 1, len(cands) + 1, f"{name} {f:g} Hz")
        results = design_axes(axes, rate_hz, RateFilter(f, name), objective=objective, ms_max=ms_max)
        trials.append(_trial(f, results, reference, max_loss))
        if not trials[-1].passed:
            break
        chosen = (f, results)
    report(progress, len(cands) + 1, len(cands) + 1, "done")
    if chosen is None:
        raise InputError(_why_none(trials[0], reference, [a.loop for a in axes], name, max_loss, ms_max))
    return JointCutoff(stack, name, chosen[0], rate_hz, tuple(a.loop for a in axes), max_loss, reference,
                       tuple(trials), chosen[1])


def _why_none(t: CutoffTrial, ref: CutoffTrial, loops: Sequence[str], name: str, max_loss: float,
              ms_max: float) -> str:
    why = []
    for lp, ok, ms, j, j0 in zip(loops, t.feasible, t.worst_ms, t.criterion, ref.criterion):
        if not ok:
            why.append(f"the {lp} robust PD misses its constraints (worst Ms {ms:.3g}, limit {ms_max:g})")
        elif not (j <= (1 + max_loss) * j0) or not math.isfinite(j):
            why.append(f"the {lp} robust PD loses {100 * (j / j0 - 1):.0f} % of its IAE")
    return (f"no {name} at or below {t.cutoff_hz:g} Hz suits both axes: at {t.cutoff_hz:g} Hz " + "; ".join(why)
            + " (give --gyro-cutoff HZ to design both axes with a cutoff you choose)")


@dataclass(frozen=True)
class AxisSource:
    """What one axis's export checks besides its design: the tests' relay heights and output amplitudes."""

    heights: tuple[float, ...] = ()
    amplitudes: tuple[float, ...] = ()


def merge_exports(exports: Sequence[StackExport], loop: str) -> StackExport:
    """Several loops' exports to one stack as the one file it loads, for ``loop`` (their names): every parameter
    once, in their order, each loop's assumptions prefixed with its loop.

    Raises
    ------
    InputError
        A parameter the loops share (the gyro rate, its filter) with two values.
    """
    params: dict[str, float] = {}
    for e in exports:
        for n, v in e.params.items():
            if n in params and params[n] != v:
                raise InputError(f"{n} differs between the loops ({params[n]:g} and {v:g}): not one file; export "
                                 "them one at a time with tune")
            params[n] = v
    return replace(exports[0], loop=loop, params=params,
                   assumptions=tuple(f"{e.loop}: {a}" for e in exports for a in e.assumptions))


@dataclass(frozen=True)
class JointExport:
    """Both axes' exports with one gyro cutoff: one file for the stack.

    Attributes
    ----------
    stack : str
    exports : tuple of StackExport
        Per axis (roll, pitch), each with its margins under the stack's filter at the common cutoff.
    cutoff : JointCutoff or None
        How the cutoff was chosen (None: given with ``--gyro-cutoff HZ``).
    """

    stack: str
    exports: tuple[StackExport, ...]
    cutoff: JointCutoff | None = None

    def params(self) -> dict[str, float]:
        """Every parameter once, in the axes' order (the shared ones, equal by construction, once)."""
        return self._merged().params

    def _merged(self) -> StackExport:
        return merge_exports(self.exports, " and ".join(e.loop for e in self.exports))

    def file_text(self) -> str:
        """The one file the stack loads (PX4 ``.params``, ArduPilot ``.param``)."""
        return self._merged().file_text()

    def console_lines(self) -> list[str]:
        """PX4's ``param set`` lines for both axes."""
        return self._merged().console_lines()

    def to_json(self) -> dict[str, Any]:
        """The versioned object (:data:`JOINT_SCHEMA_VERSION`): each axis's export record and the cutoff's."""
        return {"schema_version": JOINT_SCHEMA_VERSION, "stack": self.stack, "params": self.params(),
                "axes": [e.to_json() for e in self.exports],
                "cutoff": None if self.cutoff is None else self.cutoff.to_json()}

    @classmethod
    def from_json(cls, data: Any) -> "JointExport":
        """The record of :meth:`to_json`; InputError (one line) on another version or a malformed field."""
        d = check_schema_version(data, "joint export", JOINT_SCHEMA_VERSION)
        try:
            exports = tuple(StackExport.from_json(e) for e in d["axes"])
            cutoff = None if d["cutoff"] is None else JointCutoff.from_json(d["cutoff"])
            return cls(str(d["stack"]), exports, cutoff)
        except (KeyError, TypeError) as err:
            raise InputError(f"joint export: missing or malformed field ({err})") from err


def export_axes(stack: str, results: Sequence[TuneResult], design: str, sources: Sequence[AxisSource], *,
                clamp: bool = False, cutoff: JointCutoff | None = None) -> JointExport:
    """Each axis's ``design`` PD (designed with the common cutoff) as ``stack`` loads it, in one record.

    Raises
    ------
    InputError
        An axis's values do not map or are out of the stack's range (:func:`export_design`'s reasons,
        prefixed with the axis).
    """
    exports = []
    for res, src in zip(results, sources):
        d = res.get(design, "PD")
        try:
            evidence = ExportEvidence(tuple(src.heights), tuple(src.amplitudes), tuple(res.notes))
            exports.append(export_design(stack, d.controller, res.loop_model, res.loop, f"{design} PD", clamp=clamp,
                                         evidence=evidence))
        except InputError as err:
            raise InputError(f"{res.loop}: {err}") from err
    out = JointExport(stack, tuple(exports), cutoff)
    out.params()  # one value per shared parameter, checked before anything is written
    return out


def joint_cutoff_of_analyses(analyses: Sequence[AnalysisResult], stack: str, rate_hz: float, *,
                             objective: str = "iae", ms_max: float = 1.6) -> JointCutoff:
    """:func:`joint_gyro_cutoff` of a roll and a pitch analysis (their posteriors as ``tune LOG`` draws them).

    The hook the ``vehicle`` command calls once both loops are identified.
    """
    from .analysis import posterior_from_analysis

    axes = [AxisModel(a.loop, a.model, posterior_from_analysis(a)) for a in analyses]
    return joint_gyro_cutoff(sorted(axes, key=lambda x: x.loop != "roll"), stack, rate_hz, objective=objective,
                             ms_max=ms_max)
