"""The analysis record: :class:`AnalysisResult`, what ``analyze --json`` writes and every reader reads back.

:meth:`AnalysisResult.to_json` gives the JSON object (``schema_version`` first, then the layout
documented in ``docs/records.md``); :meth:`AnalysisResult.from_json` validates a JSON object and
rebuilds the typed record from it (without the :class:`~mrftcli.io.logtypes.FlightLog`, which the
JSON does not hold). Readers of a RESULT.json (``tune``, ``plan``, ``batch``, ``report``) go through
:meth:`~AnalysisResult.from_json` only, so they read one set of typed fields, not keys by hand.

Times are seconds; ``t_start``/``t_end`` are log times (epoch seconds in real logs) and
``*_rel`` the same as seconds since the log's first sample (``t0``).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from ..jsonable import check_schema_version
from ..errors import InputError
from ..io.logtypes import FlightLog
from ..mrft.identify import IdentificationResult, ParameterEstimate
from ..mrft.model import LoopModel
from ..mrft.refine import Refinement
from ..segment import MrftTest
from .held_out import HeldOut
from .mrfttest_json import json_float, json_opt_float, mrft_test_from_json

__all__ = ["AnalysisResult", "LogInfo", "TpCheck", "TP_VERDICTS", "SCHEMA_VERSION", "K_UNIT",
           "analysis_controller_rate", "command_rate_of_result", "measured_noise_std"]

#: Version of the JSON layout of :meth:`AnalysisResult.to_json` (docs/records.md). 2 added ``noise``
#: (the measured sensor noise) and ``tp_check`` (the recording's verdict on the given Tp); 3 added
#: ``tests[i].held_out`` (:class:`~mrftcli.analyze.held_out.HeldOut`, the families' record); 4 writes
#: every parameter as the one record (:class:`~mrftcli.mrft.parameter.ParameterEstimate`: ``value``,
#: ``std``, ``ci95_low``, ``ci95_high``, ``unit``, ``determined``, ``known``, ``method``) where 1-3 wrote
#: ``mean``. Versions 1-3 are read as before (no noise, no verdict; no held-out prediction: ``held_out``
#: None) and written back in version 4's layout.
SCHEMA_VERSION = 4

#: What the recording says about the given Tp: ``consistent`` (the waveform accepts it), ``rejected``
#: (it fits another Tp clearly better), ``accepted`` (rejected, kept by the user's ``--accept-tp``),
#: ``not-checkable`` (the log cannot tell; the warning says why).
TP_VERDICTS = ("consistent", "rejected", "accepted", "not-checkable")


@dataclass(frozen=True)
class TpCheck:
    """The recording's verdict on the given Tp (:data:`TP_VERDICTS`), with the profile's figures when run.

    ``given``, ``best``, ``low``, ``high`` in seconds (``best`` in [``low``, ``high``], its 95 %
    profile interval); ``residual_ratio_given`` / ``_best``: the waveform residual RMS over the sensor
    noise at the given and at the best Tp. None where the profile did not run.
    """

    verdict: str
    given: float
    best: float | None = None
    low: float | None = None
    high: float | None = None
    residual_ratio_given: float | None = None
    residual_ratio_best: float | None = None

    def to_dict(self) -> _JSONDict:
        return {"verdict": self.verdict, "given": self.given, "best": self.best, "low": self.low, "high": self.high,
                "residual_ratio_given": self.residual_ratio_given, "residual_ratio_best": self.residual_ratio_best,
                "unit": "s"}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> TpCheck:
        verdict = str(d["verdict"])
        if verdict not in TP_VERDICTS:
            raise ValueError(f"unknown tp_check verdict {verdict!r}")
        return cls(verdict, json_float(d["given"]), *(json_opt_float(d.get(k)) for k in
                                                       ("best", "low", "high", "residual_ratio_given",
                                                        "residual_ratio_best")))


def measured_noise_std(tests: Sequence[MrftTest]) -> float | None:
    """The sensor noise std [output units] the tests measured: the median residual of their stable
    cycles' fits (None when none was measured). What ``plan`` plans with, from a log or its JSON."""
    noise = [c.noise_std for t in tests for c in t.stable if np.isfinite(c.noise_std)]
    return float(np.median(noise)) if noise else None
#: K's unit as the JSON states it.
K_UNIT = "output units / (command unit s^2)"
_JSONDict = dict[str, Any]


@dataclass(frozen=True)
class LogInfo:
    """What the analysis says of the log it read: the ``input`` section of the JSON beyond path, loop, Tp, t0.

    Attributes
    ----------
    source : Mapping
        The reader's description: format, layout, topics, scales, and the timing it knows
        (``controller_rate_hz`` [Hz], ``timing_jitter_s`` [s]) when it knows it.
    command_samples, output_samples : int
        Samples of the command and of the output.
    t_first, t_last : float or None
        The first and last command sample time [s] (log time); None without command samples.
    beta_topic, setpoint_topic : bool
        Whether beta and the setpoint were logged.
    reader_warnings : tuple of str
        The reader's warnings.
    """

    source: Mapping[str, Any]
    command_samples: int
    output_samples: int
    t_first: float | None
    t_last: float | None
    beta_topic: bool
    setpoint_topic: bool
    reader_warnings: tuple[str, ...]

    @classmethod
    def from_flight(cls, flight: FlightLog) -> LogInfo:
        """The record of a flight's signals and source."""
        tc = flight.command.t
        return cls(source=flight.source_json(), command_samples=int(tc.size), output_samples=int(len(flight.output)),
                   t_first=float(tc[0]) if tc.size else None, t_last=float(tc[-1]) if tc.size else None,
                   beta_topic=flight.beta is not None, setpoint_topic=flight.setpoint is not None,
                   reader_warnings=tuple(flight.warnings))

    def to_dict(self) -> _JSONDict:
        """The keys of the JSON's ``input`` section, in its order."""
        return {"source": self.source, "command_samples": self.command_samples,
                "output_samples": self.output_samples, "t_first": self.t_first, "t_last": self.t_last,
                "beta_topic": self.beta_topic, "setpoint_topic": self.setpoint_topic,
                "reader_warnings": list(self.reader_warnings)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> LogInfo:
        """The record of a JSON ``input`` section (KeyError/TypeError/ValueError on a bad one)."""
        src = d.get("source") or {}
        if not isinstance(src, Mapping):
            raise TypeError("input.source is not an object")
        return cls(source=dict(src), command_samples=int(d["command_samples"]),
                   output_samples=int(d["output_samples"]), t_first=json_opt_float(d.get("t_first")),
                   t_last=json_opt_float(d.get("t_last")), beta_topic=bool(d.get("beta_topic")),
                   setpoint_topic=bool(d.get("setpoint_topic")),
                   reader_warnings=tuple(str(w) for w in d.get("reader_warnings") or ()))


@dataclass(frozen=True, eq=False)
class AnalysisResult:
    """Everything ``mrft-ident analyze`` found in one log, for one loop.

    Attributes
    ----------
    path, loop : str
        The log and the loop analysed.
    Tp : float
        The known propulsion time constant [s].
    tests : tuple of MrftTest
        The tests used for identification (with their per-cycle data).
    rejected : tuple of MrftTest
        Tests found in the command but left out (too few stable cycles, or the output is not a limit
        cycle of this relay: ``MrftTest.validity``), with the reason in ``rejection_reasons`` and
        ``warnings``.
    Td, tau, K : ParameterEstimate
        Point estimate (``value``) with bootstrap ``std`` and 95 % interval; Td, tau in seconds, K in
        output units / (command unit s^2) (K Td is the static gain from command to output rate).
    model : LoopModel
        The identified model (the point estimate).
    identification : IdentificationResult or None
        The point identification from :func:`mrftcli.mrft.identify.identify`; None in a record
        read from JSON (the JSON keeps its summary only).
    combinations : dict
        Per-combination estimates (paper Table III): ``n`` and ``Td``/``tau``/``K`` arrays [s].
    bootstrap : dict
        Bootstrap draws ``Td``/``tau``/``K`` (arrays).
    warnings : tuple of str
        Identifiability and data-quality warnings (times in them are seconds from ``t0``).
    flight : FlightLog or None
        The signals analysed (for plots; not serialised, None in a record read from JSON).
    t0 : float
        The log's first sample time [s] (epoch seconds in real logs): everything a person reads
        (table, plots, warnings) shows times relative to it; the JSON keeps the absolute times too.
    constraints : dict
        The extra weighted constraints of the point estimate beyond the UFM slices and their
        residuals (see :func:`mrftcli.analyze.analyze_flight`); empty when none were used.
    rejection_reasons : dict
        ``MrftTest.index`` of each rejected test -> why it was left out (one sentence).
    method : {"waveform", "mrft"}
        Which estimate ``Td``, ``tau``, ``K`` and ``model`` hold: the output-error refinement on the
        waveform (:func:`mrftcli.mrft.refine.refine`, when the data accept it) or the MRFT consensus.
    parameters_mrft : dict
        ``"Td"``, ``"tau"``, ``"K"`` -> the MRFT estimate (bootstrap std and interval), whichever is used.
    refinement : Refinement or None
        The waveform refinement (estimate, std, acceptance and reasons); None when not run (and in
        a record read from JSON).
    notes : tuple of str
        Information that needs no action (e.g. Td*Omega > 5 on an altitude loop, where it is usual);
        ``warnings`` hold what the user should act on.
    controller_rate_hz : float or None
        The rate the loop's controller runs at [Hz] (:func:`analysis_controller_rate`):
        what ``tune`` designs for, whether given the log or this record's JSON.
    log_info : LogInfo or None
        The ``input`` section's account of the log (None: taken from ``flight``).
    recorded : Mapping or None
        The JSON object a record was read from (:meth:`from_json`); None for a fresh analysis.
    tp_check : TpCheck or None
        The recording's verdict on the given Tp; None when the waveform refinement did not run.
    held_out : tuple of HeldOut or None
        Per test (in ``tests``' order), its cycle predicted by eq. (2) identified from the other tests
        (:func:`~mrftcli.analyze.held_out.held_out_eq2`); empty, or None per test, in a record that
        does not hold them (read from a JSON before version 3).
    """

    schema_version: ClassVar[int] = SCHEMA_VERSION

    path: str
    loop: str
    Tp: float
    tests: tuple[MrftTest, ...]
    rejected: tuple[MrftTest, ...]
    Td: ParameterEstimate
    tau: ParameterEstimate
    K: ParameterEstimate
    model: LoopModel
    identification: IdentificationResult | None
    combinations: Mapping[str, Any]
    bootstrap: Mapping[str, Any]
    warnings: tuple[str, ...]
    flight: FlightLog | None = field(default=None, repr=False)
    t0: float = 0.0
    constraints: Mapping[str, Any] = field(default_factory=dict)
    rejection_reasons: Mapping[int, str] = field(default_factory=dict)
    method: str = "mrft"
    parameters_mrft: Mapping[str, ParameterEstimate] = field(default_factory=dict)
    refinement: Refinement | None = None
    notes: tuple[str, ...] = ()
    controller_rate_hz: float | None = None
    log_info: LogInfo | None = None
    recorded: Mapping[str, Any] | None = field(default=None, repr=False)
    tp_check: TpCheck | None = None
    held_out: tuple[HeldOut | None, ...] = ()

    def held_out_of(self, k: int) -> HeldOut | None:
        """The held-out prediction of ``tests[k]`` (None where the record has none)."""
        return self.held_out[k] if k < len(self.held_out) else None

    def _test_rows(self, cycles: bool) -> list[_JSONDict]:
        return [{**self._with_rel(t.to_dict(cycles=cycles)),
                 "held_out": None if (ho := self.held_out_of(k)) is None else ho.to_json()}
                for k, t in enumerate(self.tests)]

    @property
    def estimate_method(self) -> str:
        """How the MRFT point estimate was found: identify's method, or the weighted least squares with its constraints."""
        if self.constraints:
            return "weighted least squares: UFM slices + " + " + ".join(self.constraints.get("used", ["ufm"])[1:])
        if self.identification is not None:
            return self.identification.method
        return str((self.recorded or {}).get("identification", {}).get("method", ""))

    def rel(self, t: float) -> float:
        """A log time [s] as seconds since the log's first sample."""
        return float(t) - self.t0

    def combination_stats(self) -> _JSONDict:
        """Mean and std over the per-combination estimates (paper Table III); a record read from JSON gives
        the JSON's figures (the draws are not in it)."""
        if self.recorded is not None and "combinations" in self.recorded:
            return dict(self.recorded["combinations"])
        out: _JSONDict = {"n": int(self.combinations.get("n", 0))}
        for name in ("Td", "tau", "K"):
            v = np.asarray(self.combinations.get(name, []), float)
            v = v[np.isfinite(v)]
            out[name] = {"mean": float(v.mean()) if v.size else None,
                         "std": float(v.std(ddof=1)) if v.size > 1 else None,
                         "unit": "s" if name != "K" else ""}
        return out

    def _ident_tests(self, rows: list[_JSONDict]) -> list[_JSONDict]:
        # identify() saw each test's means only; give the cycle counts and standard errors behind them
        out = []
        for row, t in zip(rows, self.tests):
            row = dict(row)
            f = t.frequency_hz
            row["n_cycles"] = int(f.size)
            row["frequency_sem_hz"] = float(f.std(ddof=1) / math.sqrt(f.size)) if f.size > 1 else None
            out.append(row)
        return out

    def _with_rel(self, d: _JSONDict) -> _JSONDict:
        # absolute times stay (the keys); relative ones next to them for people and plots
        out = {}
        for k, v in d.items():
            out[k] = v
            if k in ("t_start", "t_end"):
                out[k + "_rel"] = self.rel(v)
        return out

    def _parameters(self) -> _JSONDict:
        params = _group({"Td": self.Td, "tau": self.tau, "K": self.K}, self.method)
        params["Tp"] = ParameterEstimate.given(self.Tp, "s").to_json()
        return params

    def _estimates(self) -> _JSONDict:
        """``parameters_mrft``, and with a refinement ``parameters_waveform`` and ``refinement``."""

        extra: _JSONDict = {}
        if self.parameters_mrft:
            extra["parameters_mrft"] = _group(self.parameters_mrft, "mrft")
        if self.refinement is not None:
            ref = self.refinement
            extra["parameters_waveform"] = _group({"Td": ref.Td, "tau": ref.tau, "K": ref.K}, "waveform")
            extra["refinement"] = {"method": "output error on the tests' windows (exact ZOH, fractional delay)",
                                   **ref.to_dict()}
        return extra

    def _identification(self, ident: IdentificationResult) -> _JSONDict:
        d = ident.to_dict()
        return {"method": self.estimate_method,
                "residual": d["residual"],
                "tests": self._ident_tests(d["tests"]), "beta_used": "effective",
                "rate_correction": None,
                "constraints": dict(self.constraints) or {"used": ["ufm"]}}

    def _input(self) -> _JSONDict:
        inp: _JSONDict = {"path": self.path, "loop": self.loop, "Tp": self.Tp, "t0": self.t0}
        info = self.log_info
        if info is None and self.flight is not None:
            info = LogInfo.from_flight(self.flight)
        if info is not None:
            inp.update(info.to_dict())
        return inp

    def to_dict(self, cycles: bool = True) -> _JSONDict:
        """The JSON object of ``mrft-ident analyze --json`` without ``schema_version`` (:meth:`to_json`).

        Keys: ``parameters`` (Td, tau, K, Tp; each the one parameter record: ``value``, ``std``,
        ``ci95_low``, ``ci95_high``, ``unit``, ``determined``, ``known``, ``method``), ``combinations`` (Table III mean/std), ``tests`` (per test: ``beta`` (the
        effective beta used), ``beta_nominal``, ``beta_effective``, ``h``, ``frequency_hz``,
        ``amplitude``, ``cycles``, ``t_start``, ``t_end`` (absolute log times [s]), ``t_start_rel``,
        ``t_end_rel`` (seconds since the log's first sample, ``input.t0``), ... and per-cycle data),
        ``rejected_tests``, ``model``, ``identification`` (method, per-test sensitivities, the extra
        constraints and their residuals), ``warnings``, ``input`` (docs/records.md).
        """
        if self.recorded is not None:
            return _recorded_dict(self.recorded, cycles, self)
        if self.identification is None:
            raise InputError("an analysis without its identification record cannot be written as JSON")
        return {
            "parameters": self._parameters(),
            **self._estimates(),
            "model": {"Tp": self.model.Tp, "Td": self.model.Td, "tau": self.model.tau, "K": self.model.K},
            "combinations": self.combination_stats(),
            "tests": self._test_rows(cycles),
            "rejected_tests": [{**self._with_rel(t.to_dict(cycles=False)),
                                "reason": self.rejection_reasons.get(t.index, "")} for t in self.rejected],
            "identification": self._identification(self.identification),
            "uncertainty": {"method": "bootstrap over stable cycles",
                            "draws": int(np.isfinite(np.asarray(self.bootstrap.get("Td", []), float)).sum())},
            "noise": {"std": measured_noise_std(self.tests), "unit": "output units",
                      "source": "median residual of the used tests' stable cycle fits"},
            "tp_check": self.tp_check.to_dict() if self.tp_check is not None else None,
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "input": self._input(),
        }

    def to_json(self, cycles: bool = True) -> _JSONDict:
        """The versioned JSON object (``schema_version``, then :meth:`to_dict`'s keys; docs/records.md).

        Values may still be numpy scalars or NaN: :func:`mrftcli.jsonable.to_jsonable` makes them
        plain JSON (NaN -> null) as every writer does. A record read by :meth:`from_json` writes
        back the object it was read from.
        """
        return {"schema_version": SCHEMA_VERSION, **self.to_dict(cycles=cycles)}

    @classmethod
    def from_json(cls, data: object) -> AnalysisResult:
        """The typed record of an ``analyze --json`` object (any ``schema_version`` up to this one).

        The tests are rebuilt with their cycles (rejected tests, written without cycles, have none);
        the draws behind the bootstrap and Table III, the identification record and the refinement
        fit are not in the JSON (``identification`` and ``refinement`` are None, ``bootstrap`` and
        ``combinations`` empty; their JSON summaries stay in ``recorded``). A JSON object without
        ``schema_version`` is read as version 1 (written before the key existed).

        Raises
        ------
        InputError
            Not an analyze result, or a ``schema_version`` newer than this version reads.
        """
        data = check_schema_version(data, "analyze RESULT.json", range(1, SCHEMA_VERSION + 1), missing=1,
                                    fix="update mrft-ident")
        try:
            return _from_json(cls, data)
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise InputError(f"not an analyze RESULT.json ({type(err).__name__}: {err}); "
                             "needs parameters.Td/tau/K, model, tests and input") from err


def _from_json(cls: type[AnalysisResult], data: Mapping[str, Any]) -> AnalysisResult:
    """:meth:`AnalysisResult.from_json` after the version check (KeyError etc. on bad input).

    Required: ``parameters`` Td, tau, K (``value``; ``mean`` before version 4) and Tp; a hand-written
    result may leave out the rest (no tests, the model from the parameters, an empty path and loop).
    """
    p = data["parameters"]
    inp = data.get("input") or {}
    Tp = _estimate("Tp", p["Tp"]).value
    Td, tau, K = _estimate("Td", p["Td"]), _estimate("tau", p["tau"]), _estimate("K", p["K"])
    m = data.get("model") or {"Tp": Tp, "Td": Td.value, "tau": tau.value, "K": K.value}
    rejected_rows = data.get("rejected_tests") or ()
    info = LogInfo.from_dict(inp) if "command_samples" in inp else None
    constraints = (data.get("identification") or {}).get("constraints") or {}
    return cls(
        path=str(inp.get("path", "")), loop=str(inp.get("loop", "")), Tp=Tp,
        tests=tuple(mrft_test_from_json(t) for t in data.get("tests") or ()),
        rejected=tuple(mrft_test_from_json(t) for t in rejected_rows),
        Td=Td, tau=tau, K=K,
        model=LoopModel(json_float(m["Tp"]), json_float(m["Td"]), json_float(m["tau"]), json_float(m["K"])),
        identification=None, combinations={}, bootstrap={},
        warnings=tuple(str(w) for w in data.get("warnings") or ()), flight=None,
        t0=json_float(inp.get("t0") or 0.0),
        # the JSON writes {"used": ["ufm"]} when no constraint was used; the record holds {} then
        constraints={} if dict(constraints) == {"used": ["ufm"]} else dict(constraints),
        rejection_reasons={int(t["index"]): str(t.get("reason", "")) for t in rejected_rows},
        method=str(p["Td"].get("method", "mrft")),
        parameters_mrft={k: _estimate(k, v) for k, v in (data.get("parameters_mrft") or {}).items()},
        refinement=None, notes=tuple(str(n) for n in data.get("notes") or ()),
        controller_rate_hz=_recorded_rate(data, info), log_info=info,
        recorded=copy.deepcopy(dict(data)),
        tp_check=TpCheck.from_dict(data["tp_check"]) if isinstance(data.get("tp_check"), Mapping) else None,
        held_out=tuple(HeldOut.from_json(t["held_out"]) if isinstance(t.get("held_out"), Mapping) else None
                       for t in data.get("tests") or ()),
    )


def _recorded_rate(data: Mapping[str, Any], info: LogInfo | None) -> float | None:
    """The controller rate [Hz] a JSON records: :func:`analysis_controller_rate` of its declared rate and tests."""
    declared = info.source.get("controller_rate_hz") if info is not None else None
    rates = [float(t["rate_hz"]) for t in data.get("tests") or () if t.get("rate_hz")]
    rate = analysis_controller_rate(float(declared) if declared else None, rates)
    return rate if rate is not None else command_rate_of_result(data)


def analysis_controller_rate(declared_hz: float | None, test_rates_hz: Sequence[float]) -> float | None:
    """The rate [Hz] the loop's controller runs at, as an analysis records it (``controller_rate_hz``).

    The rate the layout or the user declared (``FlightLog.timing.controller_rate_hz``: PX4 logs
    its 50 Hz position controller at 10 Hz), else the rate the tests' commands were logged at: the
    median of the tests' rates (each 1 / the median interval of its samples,
    :func:`mrftcli.io.timing.median_rate_hz`) to 0.1 Hz. Both are in the JSON (``input.source`` and
    ``tests[].rate_hz``), so a record read back gives the same figure as the analysis of the log.

    Parameters
    ----------
    declared_hz : float or None
        The declared controller rate [Hz].
    test_rates_hz : sequence of float
        The usable tests' command rates [Hz].

    Returns
    -------
    float or None
        The rate [Hz]; None when neither is known.

    Examples
    --------
    >>> analysis_controller_rate(50.0, [10.0, 10.0])
    50.0
    >>> analysis_controller_rate(None, [199.98, 200.01, 200.02])
    200.0
    """
    if declared_hz:
        return float(declared_hz)
    rates = [r for r in test_rates_hz if math.isfinite(r) and r > 0]
    return round(float(np.median(rates)), 1) if rates else None


def _recorded_dict(recorded: Mapping[str, Any], cycles: bool, result: AnalysisResult) -> _JSONDict:
    """The JSON a record was read from, in this version's layout (an older one's tests get ``held_out`` null,
    its parameters the one record's keys)."""
    out = {k: copy.deepcopy(v) for k, v in recorded.items() if k != "schema_version"}
    for key, method in (("parameters", result.method), ("parameters_mrft", "mrft"),
                        ("parameters_waveform", "waveform")):
        if isinstance(out.get(key), Mapping):
            group = {k: _estimate(k, v) for k, v in out[key].items()}
            out[key] = _group({k: v for k, v in group.items() if k != "Tp"}, method)
            if "Tp" in group:
                out[key]["Tp"] = ParameterEstimate.given(group["Tp"].value, "s").to_json()
    if "tests" in out:
        out["tests"] = [{**({k: v for k, v in t.items() if k != "per_cycle"} if not cycles else t),
                         "held_out": None if (ho := result.held_out_of(i)) is None else ho.to_json()}
                        for i, t in enumerate(out["tests"])]
    return out


def _estimate(name: str, d: Mapping[str, Any]) -> ParameterEstimate:
    """One parameter of the JSON (this version's record, or ``mean`` before version 4)."""
    est = ParameterEstimate.from_json(name, d)
    # the record keeps K's unit as identify gives it (""); the JSON spells it out (K_UNIT)
    return dataclasses.replace(est, unit="") if est.unit == K_UNIT else est


def _group(estimates: Mapping[str, ParameterEstimate], method: str) -> _JSONDict:
    """Parameters by name as JSON (K's unit spelt out), each with its method (``method`` where it has none)."""
    return {k: v.to_json(unit=K_UNIT if k == "K" else None, method=v.method or method) for k, v in estimates.items()}


def command_rate_of_result(data: Mapping[str, Any]) -> float | None:
    """The mean command rate [Hz] an ``analyze --json`` result records (its ``input`` section:
    ``command_samples`` over ``t_first`` .. ``t_last``); None when it does not say.

    This is the logging rate, not the controller's: ``tune`` reads
    :attr:`AnalysisResult.controller_rate_hz` instead.

    Examples
    --------
    >>> command_rate_of_result({"input": {"command_samples": 201, "t_first": 0.0, "t_last": 1.0}})
    200.0
    """
    inp = data.get("input", {})
    if inp.get("command_samples") and inp.get("t_first") is not None and inp.get("t_last") is not None:
        span = float(inp["t_last"]) - float(inp["t_first"])
        return (int(inp["command_samples"]) - 1) / span if span > 0 else None
    return None
