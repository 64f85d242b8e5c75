"""The analysis record: :class:`AnalysisResult`, what ``analyze --json`` writes and every reader reads back.

One record for every model family: the model object chose the strategy (eq. (2) through its
manifolds, a process family's response points, an outer loop through its closed inner loop) and
the record holds what that strategy found. :meth:`AnalysisResult.to_json` gives the JSON object
(``schema_version`` first, then the strategy's layout documented in ``docs/records.md``);
:meth:`AnalysisResult.from_json` validates a JSON object of any of them and rebuilds the typed record
(without the :class:`~mrftcli.io.logtypes.FlightLog`, which the JSON does not hold). Readers of a
RESULT.json (``tune``, ``plan``, ``batch``, ``report``) go through :meth:`~AnalysisResult.from_json`
only, so they read one set of typed fields, not keys by hand.

Times are seconds; ``t_start``/``t_end`` are log times (epoch seconds in real logs) and
``*_rel`` the same as seconds since the log's first sample (``t0``).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from ..io.logtypes import FlightLog, output_unit
from ..jsonable import check_schema_version, json_float, json_opt_float
from ..mrft.cascade import CascadeModel
from ..mrft.cascade_identify import CascadeIdentification
from ..mrft.identification import spelt_unit
from ..mrft.identify import IdentificationResult, ParameterEstimate
from ..mrft.identify_lti import LtiIdentification
from ..mrft.model import K_UNIT, LoopModel
from ..mrft.refine import Refinement
from ..mrft.relays import RelayLaw
from ..mrft.sem import mean_sem
from ..segment import MrftTest
from .held_out import HeldOut
from .mrfttest_json import mrft_test_from_json
from .smooth_cycle import SwitchingLevel
from .static_gain import StaticGain

__all__ = ["AnalysisResult", "TestSummary", "LogInfo", "TpCheck",
           "TP_VERDICTS", "SCHEMA_VERSION", "FAMILY_SCHEMA_VERSION", "CASCADE_SCHEMA_VERSION",
           "analysis_controller_rate", "command_rate_of_result", "measured_noise_std"]

#: Version of eq. (2)'s JSON layout of :meth:`AnalysisResult.to_json` (docs/records.md). 2 added ``noise``
#: (the measured sensor noise) and ``tp_check`` (the recording's verdict on the given Tp); 3 added
#: ``tests[i].held_out`` (:class:`~mrftcli.analyze.held_out.HeldOut`, the families' record); 4 writes
#: every parameter as the one record (:class:`~mrftcli.mrft.parameter.ParameterEstimate`: ``value``,
#: ``std``, ``ci95_low``, ``ci95_high``, ``unit``, ``determined``, ``known``, ``method``) where 1-3 wrote
#: ``mean``. Versions 1-3 are read as before (no noise, no verdict; no held-out prediction: ``held_out``
#: None) and written back in version 4's layout.
SCHEMA_VERSION = 4
#: Version of a process family's layout; 2 gave ``tests[i].held_out`` the shared record's sigma and z keys
#: (null here: :class:`~mrftcli.analyze.held_out.HeldOut`); 3 writes each parameter as the one record
#: (``method`` in place of ``one_sided``); versions 1-2 still read
FAMILY_SCHEMA_VERSION = 3
#: Version of the cascade's layout; 2: each parameter the one record (with ``method``); version 1 still
#: reads and is written back in this layout
CASCADE_SCHEMA_VERSION = 2

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
        return {**dataclasses.asdict(self), "unit": "s"}  # the fields in their order

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
#: K's unit as the JSON stated it before it took the model's spelling (:data:`~mrftcli.mrft.model.K_UNIT`)
_OLD_K_UNIT = "output units / (command unit s^2)"
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
        """The keys of the JSON's ``input`` section, in its order (the fields')."""
        return {**dataclasses.asdict(self), "reader_warnings": list(self.reader_warnings)}

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


@dataclass(frozen=True)
class TestSummary:
    """One relay test of a process family as measured, with its relay and its held-out prediction.

    Attributes
    ----------
    index : int
        Test number (0-based, in time order over the windows).
    t_start, t_end : float
        Its span [s, log clock].
    relay : RelayLaw
        Its relay.
    frequency_hz, amplitude : float
        Mean over the stable cycles [Hz], [output units].
    n_stable, n_cycles : int
        Stable and all cycles.
    rate_hz : float
        The relay's (controller's) rate [Hz].
    beta_effective : float
        The switching level measured, over the amplitude [-].
    notes : tuple of str
        E.g. why a noisy test was kept.
    held_out : HeldOut or None
        The prediction from the other tests.
    switching : SwitchingLevel or None
        The smooth waveform's level at the switches and its amplitude
        (:func:`~mrftcli.analyze.smooth_cycle.switching_level`).
    effective_relay : RelayLaw or None
        ``relay`` at that level (``source "effective"``): what the held-out prediction uses; None for
        an ideal relay or without a measured level.
    """

    __test__ = False

    index: int
    t_start: float
    t_end: float
    relay: RelayLaw
    frequency_hz: float
    amplitude: float
    n_stable: int
    n_cycles: int
    rate_hz: float
    beta_effective: float
    notes: tuple[str, ...] = ()
    held_out: HeldOut | None = None
    switching: SwitchingLevel | None = None
    effective_relay: RelayLaw | None = None

    @property
    def bias(self) -> float:
        """The relay's bias [command units] (the level the plant is in equilibrium at, for a prediction)."""
        return self.relay.bias

    @property
    def predicting_relay(self) -> RelayLaw:
        """The relay a model's limit cycle is computed under: the effective one where there is one."""
        return self.effective_relay or self.relay

    def describe_relay(self) -> str:
        """The relay without its ``relay: `` prefix, with the effective level where there is one.

        E.g. ``hysteresis eps 3.76e-06 (effective, on the cycle's smooth waveform: 3.48e-06), levels
        +1200 / -720, bias +240``.
        """
        text = self.relay.describe()[len("relay: "):]
        eff = self.effective_relay
        if eff is None:
            return text
        value = f"{eff.eps:.3g}" if eff.kind == "hysteresis" else f"{eff.beta:+.3g}"
        head, sep, rest = text.partition(", levels")
        return f"{head} (effective, on the cycle's smooth waveform: {value}){sep}{rest}"

    def to_json(self) -> _JSONDict:
        return {"index": self.index, "t_start": self.t_start, "t_end": self.t_end, "relay": self.relay.to_json(),
                "frequency_hz": self.frequency_hz, "amplitude": self.amplitude, "n_stable": self.n_stable,
                "n_cycles": self.n_cycles, "rate_hz": self.rate_hz,
                "beta_effective": self.beta_effective, "notes": list(self.notes),
                "held_out": None if self.held_out is None else self.held_out.to_json(),
                "switching": None if self.switching is None else self.switching.to_json(),
                "effective_relay": None if self.effective_relay is None else self.effective_relay.to_json()}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> TestSummary:
        try:
            ho, sw, eff = d.get("held_out"), d.get("switching"), d.get("effective_relay")
            return cls(int(d["index"]), float(d["t_start"]), float(d["t_end"]), RelayLaw.from_json(d["relay"]),
                       float(d["frequency_hz"]), float(d["amplitude"]), int(d["n_stable"]), int(d["n_cycles"]),
                       float(d["rate_hz"]), float(d["beta_effective"]), tuple(str(n) for n in d.get("notes", [])),
                       None if ho is None else HeldOut.from_json(ho),
                       None if sw is None else SwitchingLevel.from_json(sw),
                       None if eff is None else RelayLaw.from_json(eff))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"analysis JSON: bad test entry ({err})") from None


@dataclass(frozen=True, eq=False)
class AnalysisResult:
    """Everything ``mrft-ident analyze`` found in one log, for one loop: the one analysis record of every family.

    The model object chose the strategy (:func:`mrftcli.analyze.analyze_flight`) and the record says
    which it was (:attr:`kind`): ``"soiptd"`` (eq. (2) through its manifolds), ``"family"`` (a process
    family's response points) or ``"cascade"`` (an outer loop through its closed inner loop). What only
    one strategy finds sits in that strategy's fields below (empty for the others); the JSON
    (:meth:`to_json`) is the strategy's layout, each with its own version (:data:`SCHEMA_VERSION`,
    :data:`FAMILY_SCHEMA_VERSION`, :data:`CASCADE_SCHEMA_VERSION`; docs/records.md), and
    :meth:`from_json` reads any of them. The model, test and identification records are the strategy's
    (eq. (2): LoopModel, MrftTest, IdentificationResult; a family: PlantModel, TestSummary,
    LtiIdentification; the cascade: CascadeModel, MrftTest, CascadeIdentification).

    Attributes
    ----------
    path, loop : str
        The log and the loop analysed.
    model : LoopModel, PlantModel or CascadeModel
        The identified model (the point estimate).
    tests : tuple of MrftTest (eq. (2), cascade) or TestSummary (process family)
        The tests used for identification (eq. (2) and the cascade: with their per-cycle data).
    identification : IdentificationRecord or None
        The one identification record of the strategy (:mod:`mrftcli.mrft.identification`): eq. (2)'s point
        identification from
        :func:`mrftcli.mrft.identify.identify` (None in a record read from JSON: the JSON keeps its
        summary only), the family's fit, or the cascade's.
    parameters : mapping of str to ParameterEstimate
        The estimates by name (eq. (2): Td, tau, K; Td, tau in seconds, K in output units / (command
        unit s^2), K Td the static gain from command to output rate), with std and 95 % interval.
    rejected : tuple of MrftTest
        Tests found but left out (eq. (2), cascade), with the reason in ``rejection_reasons``.
    rejection_reasons : dict
        ``MrftTest.index`` of each rejected test -> why it was left out (one sentence).
    warnings : tuple of str
        Identifiability and data-quality warnings (times in them are seconds from ``t0``).
    notes : tuple of str
        Information that needs no action (e.g. Td*Omega > 5 on an altitude loop, where it is usual).
    t0 : float
        The log's first sample time [s] (epoch seconds in real logs): everything a person reads
        shows times relative to it; the JSON keeps the absolute times too.
    flight : FlightLog or None
        The signals analysed (for plots; not serialised, None in a record read from JSON).
    controller_rate_hz : float or None
        The rate the loop's controller runs at [Hz] (:func:`analysis_controller_rate`): what ``tune``
        designs for.
    recorded : Mapping or None
        The JSON object an eq. (2) or cascade record was read from (:meth:`from_json`); None for a
        fresh analysis.
    held_out : tuple of HeldOut or None
        Eq. (2): per test, its cycle predicted by eq. (2) identified from the other tests
        (:func:`~mrftcli.analyze.held_out.held_out_eq2`; a family's are in its tests:
        :meth:`held_out_of` reads both).
    segments : tuple of MrftTest
        A process family's usable tests as segmented (a fresh analysis only: for the report's plots
        and the overlay; the JSON holds ``tests``).
    combinations, bootstrap : dict
        Eq. (2): per-combination estimates (paper Table III: ``n`` and ``Td``/``tau``/``K`` arrays) and
        the bootstrap draws.
    constraints : dict
        Eq. (2): the extra weighted constraints of the point estimate beyond the UFM slices and their
        residuals; empty when none were used.
    method : {"waveform", "mrft"}
        Eq. (2): which estimate ``parameters`` and ``model`` hold: the output-error refinement on the
        waveform (:func:`mrftcli.mrft.refine.refine`, when the data accept it) or the MRFT consensus.
    parameters_mrft : dict
        Eq. (2): ``"Td"``, ``"tau"``, ``"K"`` -> the MRFT estimate, whichever is used.
    refinement : Refinement or None
        Eq. (2): the waveform refinement; None when not run (and in a record read from JSON).
    log_info : LogInfo or None
        The ``input`` section's account of the log (None: taken from ``flight``).
    tp_check : TpCheck or None
        Eq. (2): the recording's verdict on the given Tp; None when the waveform refinement did not run.
    windows : tuple of (float, float)
        A process family: the parts of the log used [s, log clock]; empty: all of it.
    static_gain : StaticGain or None
        A process family: K measured from a biased relay's mean levels and the given operating point.
    rejected_spans : tuple of (int, float, float, str)
        A process family's tests left out: index, span [s], reason.
    assumptions : tuple of str
        The cascade: what the numbers rest on (K, the inner model and gains), printed first.
    """

    path: str
    loop: str
    model: Any
    tests: tuple[Any, ...]
    identification: Any  # an Identification (or None); typed Any so each kind's readers reach their strategy's fields
    parameters: Mapping[str, ParameterEstimate]
    rejected: tuple[MrftTest, ...] = ()
    rejection_reasons: Mapping[int, str] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    t0: float = 0.0
    flight: FlightLog | None = field(default=None, repr=False)
    controller_rate_hz: float | None = None
    recorded: Mapping[str, Any] | None = field(default=None, repr=False)
    held_out: tuple[HeldOut | None, ...] = ()
    segments: tuple[MrftTest, ...] = field(default=(), repr=False)
    # eq. (2)'s
    combinations: Mapping[str, Any] = field(default_factory=dict)
    bootstrap: Mapping[str, Any] = field(default_factory=dict)
    constraints: Mapping[str, Any] = field(default_factory=dict)
    method: str = "mrft"
    parameters_mrft: Mapping[str, ParameterEstimate] = field(default_factory=dict)
    refinement: Refinement | None = None
    log_info: LogInfo | None = None
    tp_check: TpCheck | None = None
    # a process family's
    windows: tuple[tuple[float, float], ...] = ()
    static_gain: StaticGain | None = None
    rejected_spans: tuple[tuple[int, float, float, str], ...] = ()
    # the cascade's
    assumptions: tuple[str, ...] = ()

    @property
    def kind(self) -> str:
        """Which strategy made the record: ``"soiptd"`` (eq. (2)), ``"cascade"`` or ``"family"``."""
        return _kind_of(self.model)

    def _eq2(self, name: str) -> ParameterEstimate:
        try:
            return self.parameters[name]
        except KeyError:
            raise InputError(f"a {self.kind} analysis has no {name}: this needs an analysis of eq. (2) "
                             "(--model soiptd)") from None

    @property
    def Td(self) -> ParameterEstimate:
        """Eq. (2)'s (and the cascade's) drag time constant [s] (InputError for a process family)."""
        return self._eq2("Td")

    @property
    def tau(self) -> ParameterEstimate:
        """Eq. (2)'s (and the cascade's) delay [s]."""
        return self._eq2("tau")

    @property
    def K(self) -> ParameterEstimate:
        """Eq. (2)'s (and the cascade's) gain."""
        return self._eq2("K")

    @property
    def Tp(self) -> float:
        """Eq. (2)'s known propulsion time constant [s]."""
        if not isinstance(self.model, LoopModel):
            raise InputError(f"a {self.kind} analysis has no Tp: this needs an analysis of eq. (2) (--model soiptd)")
        return float(self.model.Tp)

    @property
    def output_unit(self) -> str:
        """The output's unit as people read it: the vehicle loop's (m, rad), a process plant's "output units"."""
        return "output units" if self.kind == "family" else output_unit(self.loop)

    @property
    def segmented(self) -> tuple[MrftTest, ...]:
        """The usable tests as segmented, with their cycles (eq. (2), cascade: ``tests``; a process family:
        ``segments``, in a fresh analysis only): what the report's plots and the overlay draw."""
        return self.segments if self.kind == "family" else tuple(self.tests)

    def parameters_json(self) -> _JSONDict:
        """Every parameter as the one record's JSON by name, the known ones too (eq. (2): Tp first)."""
        given = {"Tp": ParameterEstimate.given(self.Tp, "s")} if self.kind == "soiptd" else {}
        return {name: est.to_json() for name, est in {**given, **self.parameters}.items()}

    def held_out_of(self, k: int) -> HeldOut | None:
        """The held-out prediction of ``tests[k]`` (None where the record has none)."""
        if k < len(self.held_out):
            return self.held_out[k]
        ho = getattr(self.tests[k], "held_out", None) if k < len(self.tests) else None
        return ho if isinstance(ho, HeldOut) else None

    @property
    def estimate_method(self) -> str:
        """How eq. (2)'s MRFT point estimate was found: identify's method, or the weighted least squares with its constraints."""
        if self.constraints:
            return "weighted least squares: UFM slices + " + " + ".join(self.constraints.get("used", ["ufm"])[1:])
        if isinstance(self.identification, IdentificationResult):
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

    def to_dict(self, cycles: bool = True) -> _JSONDict:
        """The JSON object of ``mrft-ident analyze --json`` without ``schema_version`` (:meth:`to_json`)."""
        return {k: v for k, v in self.to_json(cycles).items() if k != "schema_version"}

    def to_json(self, cycles: bool = True) -> _JSONDict:
        """The versioned JSON object of the strategy's layout (docs/records.md), ``schema_version`` first.

        Eq. (2): ``parameters`` (Td, tau, K, Tp; each the one parameter record: ``value``, ``std``,
        ``ci95_low``, ``ci95_high``, ``unit``, ``determined``, ``known``, ``method``), ``combinations``
        (Table III mean/std), ``tests`` (per test: ``beta`` (the effective beta used), ``beta_nominal``,
        ``beta_effective``, ``h``, ``frequency_hz``, ``amplitude``, ``cycles``, ``t_start``, ``t_end``
        (absolute log times [s]), ``t_start_rel``, ``t_end_rel``, ``held_out``, ... and per-cycle data
        unless ``cycles`` is False), ``rejected_tests``, ``model``, ``identification``, ``warnings``,
        ``input``. A process family: ``model`` (the family), ``parameters`` by name, ``identification``,
        ``tests`` (each with its relay and held-out prediction), ``windows``, ``static_gain``. The
        cascade: ``kind``, ``input``, ``assumptions``, ``model``, ``parameters``, ``identification``,
        ``tests``, ``rejected_tests``. Values may still be numpy scalars or NaN:
        :func:`mrftcli.jsonable.to_jsonable` makes them plain JSON (NaN -> null) as every writer does.
        An eq. (2) or cascade record read by :meth:`from_json` writes back the object it was read from.
        """
        if self.kind == "cascade":
            return _cascade_json(self)
        if self.kind == "family":
            return _family_json(self)
        return {"schema_version": SCHEMA_VERSION, **_eq2_json(self, cycles)}

    @classmethod
    def from_json(cls, data: object) -> AnalysisResult:
        """The typed record of an ``analyze --json`` object of any strategy (any ``schema_version`` up to its own).

        Eq. (2): the tests are rebuilt with their cycles (rejected tests, written without cycles, have
        none); the draws behind the bootstrap and Table III, the identification record and the
        refinement fit are not in the JSON (``identification`` and ``refinement`` are None,
        ``bootstrap`` and ``combinations`` empty; their JSON summaries stay in ``recorded``). A JSON
        object without ``schema_version`` is read as eq. (2)'s version 1 (written before the key existed).

        Raises
        ------
        InputError
            Not an analyze result, or a ``schema_version`` newer than this version reads.
        """
        if isinstance(data, Mapping) and data.get("kind") == "cascade":
            return _cascade_from_json(data)
        if isinstance(data, Mapping) and (isinstance(data.get("model"), str) or ("path" in data and "input" not in data)):
            return _family_from_json(data)
        other = _other_record(data)
        if other:
            raise InputError(f"not an analyze RESULT.json but {other}; give what 'mrft-ident analyze LOG --json FILE' "
                             "writes")
        data = check_schema_version(data, "analyze RESULT.json", range(1, SCHEMA_VERSION + 1), missing=1,
                                    fix="update mrft-ident")
        try:
            return _eq2_from_json(data)
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise InputError(f"not an analyze RESULT.json ({type(err).__name__}: {err}); "
                             "needs parameters.Td/tau/K, model, tests and input") from err


def _kind_of(model: object) -> str:
    if isinstance(model, LoopModel):
        return "soiptd"
    return "cascade" if isinstance(model, CascadeModel) else "family"


# ----------------------------------------------------------------------------------------------
# eq. (2)'s layout
# ----------------------------------------------------------------------------------------------
def _eq2_json(r: AnalysisResult, cycles: bool) -> _JSONDict:
    if r.recorded is not None:
        return _recorded_dict(r.recorded, cycles, r)
    if not isinstance(r.identification, IdentificationResult):
        raise InputError("an analysis without its identification record cannot be written as JSON")
    m = r.model
    params = _group({k: r.parameters[k] for k in ("Td", "tau", "K")}, r.method, m)
    params["Tp"] = ParameterEstimate.given(r.Tp, "s").to_json()
    return {
        "parameters": params,
        **_estimates(r),
        "model": {"Tp": m.Tp, "Td": m.Td, "tau": m.tau, "K": m.K},
        "combinations": r.combination_stats(),
        "tests": [{**_with_rel(r, t.to_dict(cycles=cycles)),
                   "held_out": None if (ho := r.held_out_of(k)) is None else ho.to_json()}
                  for k, t in enumerate(r.tests)],
        "rejected_tests": [{**_with_rel(r, t.to_dict(cycles=False)),
                            "reason": r.rejection_reasons.get(t.index, "")} for t in r.rejected],
        "identification": _identification(r, r.identification),
        "uncertainty": {"method": "bootstrap over stable cycles",
                        "draws": int(np.isfinite(np.asarray(r.bootstrap.get("Td", []), float)).sum())},
        "noise": {"std": measured_noise_std(r.tests), "unit": "output units",
                  "source": "median residual of the used tests' stable cycle fits"},
        "tp_check": r.tp_check.to_dict() if r.tp_check is not None else None,
        "warnings": list(r.warnings),
        "notes": list(r.notes),
        "input": _input(r),
    }


def _with_rel(r: AnalysisResult, d: _JSONDict) -> _JSONDict:
    # absolute times stay (the keys); relative ones next to them for people and plots
    out = {}
    for k, v in d.items():
        out[k] = v
        if k in ("t_start", "t_end"):
            out[k + "_rel"] = r.rel(v)
    return out


def _estimates(r: AnalysisResult) -> _JSONDict:
    """``parameters_mrft``, and with a refinement ``parameters_waveform`` and ``refinement``."""
    extra: _JSONDict = {}
    if r.parameters_mrft:
        extra["parameters_mrft"] = _group(r.parameters_mrft, "mrft", r.model)
    if r.refinement is not None:
        ref = r.refinement
        extra["parameters_waveform"] = _group({"Td": ref.Td, "tau": ref.tau, "K": ref.K}, "waveform", r.model)
        extra["refinement"] = {"method": "output error on the tests' windows (exact ZOH, fractional delay)",
                               **ref.to_dict()}
    return extra


def _identification(r: AnalysisResult, ident: IdentificationResult) -> _JSONDict:
    rows = []
    # identify() saw each test's means only; give the cycle counts and standard errors behind them
    for row, t in zip(ident.tests, r.tests):
        f = t.frequency_hz
        rows.append({**row, "n_cycles": int(f.size),
                     "frequency_sem_hz": mean_sem(f) if f.size > 1 else None})
    return {"method": r.estimate_method, "residual": ident.residual, "tests": rows, "beta_used": "effective",
            "rate_correction": None, "constraints": dict(r.constraints) or {"used": ["ufm"]}}


def _input(r: AnalysisResult) -> _JSONDict:
    inp: _JSONDict = {"path": r.path, "loop": r.loop, "Tp": r.Tp, "t0": r.t0}
    info = r.log_info
    if info is None and r.flight is not None:
        info = LogInfo.from_flight(r.flight)
    if info is not None:
        inp.update(info.to_dict())
    return inp


def _other_record(data: Any) -> str:
    """What another command's JSON record is, when a user gives it where an analysis is read (else "")."""
    if not isinstance(data, Mapping):
        return ""
    if "strategy" in data and "parameters" in data:
        return "an identification record ('mrft-ident identify --json')"
    kinds = {"delay-increment": "a delay record ('mrft-ident delay --json')",
             "diagnosis": "a diagnosis record ('mrft-ident diagnose --json')"}
    if data.get("kind") in kinds:
        return kinds[str(data["kind"])]
    if ("designs" in data and "ms_max" in data) or "tune_results" in data:
        return "a tune record ('mrft-ident tune --json')"
    if "rows" in data and "counts" in data:
        return "a batch summary ('mrft-ident batch --json'; its logs/*.json are analyses)"
    return ""


def _eq2_from_json(data: Mapping[str, Any]) -> AnalysisResult:
    """Eq. (2)'s record after the version check (KeyError etc. on bad input).

    Required: ``parameters`` Td, tau, K (``value``; ``mean`` before version 4) and Tp; a hand-written
    result may leave out the rest (no tests, the model from the parameters, an empty path and loop).
    """
    p = data["parameters"]
    inp = data.get("input") or {}
    Tp = _estimate("Tp", p["Tp"]).value
    Td, tau, K = _estimate("Td", p["Td"]), _estimate("tau", p["tau"]), _estimate("K", p["K"])
    m = data.get("model") or {"Tp": Tp, "Td": Td.value, "tau": tau.value, "K": K.value}
    info = LogInfo.from_dict(inp) if "command_samples" in inp else None
    constraints = (data.get("identification") or {}).get("constraints") or {}
    return AnalysisResult(
        model=LoopModel(json_float(m["Tp"]), json_float(m["Td"]), json_float(m["tau"]), json_float(m["K"])),
        identification=None, parameters={"Td": Td, "tau": tau, "K": K}, **_logged(data),
        # the JSON writes {"used": ["ufm"]} when no constraint was used; the record holds {} then
        constraints={} if dict(constraints) == {"used": ["ufm"]} else dict(constraints),
        method=str(p["Td"].get("method", "mrft")),
        parameters_mrft={k: _estimate(k, v) for k, v in (data.get("parameters_mrft") or {}).items()},
        notes=tuple(str(n) for n in data.get("notes") or ()),
        controller_rate_hz=_recorded_rate(data, info), log_info=info,
        recorded=copy.deepcopy(dict(data)),
        tp_check=TpCheck.from_dict(data["tp_check"]) if isinstance(data.get("tp_check"), Mapping) else None,
        held_out=tuple(HeldOut.from_json(t["held_out"]) if isinstance(t.get("held_out"), Mapping) else None
                       for t in data.get("tests") or ()),
    )


# ----------------------------------------------------------------------------------------------
# a process family's layout
# ----------------------------------------------------------------------------------------------
def _family_json(r: AnalysisResult) -> _JSONDict:
    """``schema_version``, ``model`` (the family), ``parameters`` by name, ``identification``, ``tests``."""
    ident = r.identification
    return {"schema_version": FAMILY_SCHEMA_VERSION, "path": r.path, "loop": r.loop, "t0": r.t0,
            "windows": [list(w) for w in r.windows], "model": ident.model.family,
            "parameters": {e.name: e.to_json() for e in ident.estimates}, "identification": ident.to_json(),
            "tests": [t.to_json() for t in r.tests],
            "rejected_tests": [{"index": i, "t_start": a, "t_end": b, "reason": w} for i, a, b, w in r.rejected_spans],
            "notes": list(r.notes), "warnings": list(r.warnings),
            "static_gain": None if r.static_gain is None else r.static_gain.to_json()}


def _family_from_json(data: Mapping[str, Any]) -> AnalysisResult:
    data = check_schema_version(data, "analysis JSON", range(1, FAMILY_SCHEMA_VERSION + 1))
    try:
        sg = data.get("static_gain")
        ident = LtiIdentification.from_json(data["identification"])
        return AnalysisResult(
            str(data["path"]), str(data["loop"]), ident.model, tuple(TestSummary.from_json(t) for t in data["tests"]),
            ident, ident.parameters, t0=float(data["t0"]),
            windows=tuple((float(a), float(b)) for a, b in data.get("windows", [])),
            rejected_spans=tuple((int(r["index"]), float(r["t_start"]), float(r["t_end"]), str(r["reason"]))
                                 for r in data.get("rejected_tests", [])),
            notes=tuple(str(n) for n in data.get("notes", [])), warnings=tuple(str(w) for w in data.get("warnings", [])),
            static_gain=None if sg is None else StaticGain.from_json(sg))
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise InputError(f"analysis JSON: bad or missing field ({err})") from None


# ----------------------------------------------------------------------------------------------
# the cascade's layout
# ----------------------------------------------------------------------------------------------
def _cascade_json(r: AnalysisResult) -> _JSONDict:
    """``{"schema_version", "kind": "cascade", "input", "assumptions", "model", "parameters", "identification",
    "tests", "rejected_tests", "warnings"}`` (docs/cascade.md)."""
    if r.recorded is not None:
        return dict(r.recorded)
    ident = r.identification
    return {"schema_version": CASCADE_SCHEMA_VERSION, "kind": "cascade",
            "input": {"path": r.path, "loop": r.loop, "t0": r.t0, "controller_rate_hz": r.controller_rate_hz or 0.0},
            "assumptions": list(r.assumptions), "model": ident.model.to_json(),
            "parameters": {e.name: e.to_json() for e in ident.estimates}, "identification": ident.to_json(),
            "tests": [t.to_dict(cycles=True) for t in r.tests],
            "rejected_tests": [{**t.to_dict(cycles=False), "reason": r.rejection_reasons.get(t.index, "")}
                               for t in r.rejected],
            "warnings": list(r.warnings)}


def _cascade_from_json(data: Any) -> AnalysisResult:
    d = check_schema_version(data, "cascade analysis JSON", range(1, CASCADE_SCHEMA_VERSION + 1))
    if d.get("kind") != "cascade" or "identification" not in d:
        raise InputError("not a cascade analysis JSON (needs kind 'cascade' and 'identification')")
    try:
        ident = CascadeIdentification.from_json(d["identification"])
        recorded = dict(d) if d.get("schema_version") == CASCADE_SCHEMA_VERSION else \
            {**d, "schema_version": CASCADE_SCHEMA_VERSION,  # version 1's parameters as the one record
             "parameters": {e.name: e.to_json() for e in ident.estimates}, "identification": ident.to_json()}
        return AnalysisResult(
            model=ident.model, identification=ident, parameters=ident.parameters, **_logged(d),
            controller_rate_hz=float((d.get("input") or {}).get("controller_rate_hz") or 0.0),
            assumptions=tuple(str(a) for a in d.get("assumptions") or ()), recorded=recorded)
    except (KeyError, TypeError, ValueError) as err:
        raise InputError(f"cascade analysis JSON: bad tests ({type(err).__name__}: {err})") from err


def _logged(data: Mapping[str, Any]) -> dict[str, Any]:
    """What eq. (2)'s and the cascade's layouts hold alike: ``input``'s path, loop and t0, the tests, the rejected
    tests (without their cycles) with their reasons, the warnings."""
    inp, rows = data.get("input") or {}, data.get("rejected_tests") or ()
    return {"path": str(inp.get("path", "")), "loop": str(inp.get("loop", "")), "t0": json_float(inp.get("t0") or 0.0),
            "tests": tuple(mrft_test_from_json(t) for t in data.get("tests") or ()),
            "rejected": tuple(mrft_test_from_json(t) for t in rows),
            "rejection_reasons": {int(t["index"]): str(t.get("reason", "")) for t in rows},
            "warnings": tuple(str(w) for w in data.get("warnings") or ())}


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
            out[key] = _group({k: v for k, v in group.items() if k != "Tp"}, method, result.model)
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
    return dataclasses.replace(est, unit="") if est.unit in (K_UNIT, _OLD_K_UNIT) else est


def _group(estimates: Mapping[str, ParameterEstimate], method: str, model: Any) -> _JSONDict:
    """Parameters by name as JSON (K's unit spelt out from ``model``'s, :func:`~mrftcli.mrft.identification.spelt_unit`),
    each with its method (``method`` where it has none)."""
    return {k: v.to_json(unit=spelt_unit(k, v.unit, model), method=v.method or method) for k, v in estimates.items()}


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
