"""The planner's records, for every model family: what is known (:class:`Prior`, :class:`FlownTest`; a
process plant's recorded tests are its analysis), what the next test may do (:class:`PlanLimits`), and what it recommends (:class:`TestPlan`,
:class:`CandidateTest`, :class:`PlanResult`, the versioned JSON of ``mrft-ident plan --json``).

Units: times in seconds, frequencies in Hz, amplitudes in output units, h in command units, phases in
degrees, each parameter's standard deviation in its own unit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np

from ..errors import InputError
from ..jsonable import check_schema_version, finite_or_none, json_opt_float
from ..mrft.identify_lti import LtiIdentification
from ..mrft.model import LoopModel, PlantModel, soiptd_model
from ..mrft.relays import RelayLaw
from ..validate import check_beta, check_positive, check_time

__all__ = [
    "Prior",
    "PlanLimits",
    "FlownTest",
    "TestPlan",
    "CandidateTest",
    "Conventional",
    "PlanResult",
    "PARAMS",
    "SCHEMA_VERSION",
]

#: The identified parameters, in the order of every (Td, tau, K) array of the planner.
PARAMS = ("Td", "tau", "K")
#: Version of :meth:`PlanResult.to_json` (2: one record for every family, the model object instead of ``Tp``;
#: :meth:`PlanResult.from_json` still reads version 1, eq. (2)'s plan and a process plan, for one release).
SCHEMA_VERSION = 2

Stds = dict[str, float]
StdRanges = dict[str, tuple[float, float]]


def _check_range(name: str, rng: Sequence[float], unit: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in rng)
    except (TypeError, ValueError) as err:
        raise InputError(f"the {name} range must be two numbers LOW HIGH{unit}, got {rng!r}") from err
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise InputError(f"the {name} range must satisfy 0 < LOW <= HIGH{unit}, got {lo:g} {hi:g}")
    return lo, hi


@dataclass(frozen=True)
class Prior:
    """What is known before the next test: a range for each parameter.

    Attributes
    ----------
    Td : (float, float)
        Drag time constant range [s].
    tau : (float, float)
        Loop delay range [s].
    K : (float, float)
        Gain range [output units / (command unit s^2)].

    Each range is read as the mean +/- 2 standard deviations (of Td, tau and ln K) for the prior
    information, and drawn from uniformly (log-uniformly for Td and K).
    """

    Td: tuple[float, float] = (0.2, 3.0)
    tau: tuple[float, float] = (0.01, 0.1)
    K: tuple[float, float] = (0.5, 20.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "Td", _check_range("Td", self.Td, " [s]"))
        object.__setattr__(self, "tau", _check_range("tau", self.tau, " [s]"))
        object.__setattr__(self, "K", _check_range("K", self.K, ""))

    def information(self) -> np.ndarray:
        """Prior Fisher information on (Td, tau, ln K): diag(1 / sigma^2), sigma = width / 4."""
        sig = np.array([(self.Td[1] - self.Td[0]) / 4, (self.tau[1] - self.tau[0]) / 4,
                        math.log(self.K[1] / self.K[0]) / 4])
        return np.diag(np.where(sig > 0, 1.0 / np.maximum(sig, 1e-300) ** 2, 1e30))

    def draws(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` plants (rows Td, tau, K) from the ranges, stratified so few draws cover them."""
        u = (np.arange(n)[None, :] + rng.uniform(size=(3, n))) / n
        u = np.array([rng.permutation(row) for row in u])
        Td = self.Td[0] * (self.Td[1] / self.Td[0]) ** u[0]
        tau = self.tau[0] + (self.tau[1] - self.tau[0]) * u[1]
        K = self.K[0] * (self.K[1] / self.K[0]) ** u[2]
        return np.stack([Td, tau, K], axis=1)


@dataclass(frozen=True)
class PlanLimits:
    """What the next test may do, for every model family.

    Eq. (2)'s flight gives all five; a process plant's relay test (``plan LOG --model NAME``) the
    amplitude and the half-height, each optional (its rate and noise are the recorded tests').

    Attributes
    ----------
    max_amplitude : float or None
        Largest output amplitude allowed [output units] (e.g. 0.05 m, 5 deg in rad). A process plant's
        candidate over it is listed, never recommended; None: no limit.
    max_h : float or None
        Largest relay height the motors give [command units]; a process plant's candidates' half-height
        about the recorded bias (None: the recorded tests' largest).
    time_s : float
        Relay time available for the next test(s) together [s] (eq. (2); NaN: not given).
    rate_hz : float
        Controller (relay) rate [Hz] (eq. (2); NaN: not given).
    noise_std : float
        Sensor noise standard deviation of the output [output units] (eq. (2); NaN: not given).
    """

    max_amplitude: float | None = None
    max_h: float | None = None
    time_s: float = math.nan
    rate_hz: float = math.nan
    noise_std: float = math.nan

    def __post_init__(self) -> None:
        if self.max_amplitude is not None:
            check_positive("the largest amplitude (--max-amplitude)", self.max_amplitude)
        if self.max_h is not None:
            check_positive("the largest relay height (--max-h)" if self.flight else "the relay half-height (--max-h)",
                           self.max_h)
        if self.flight:
            if self.max_amplitude is None or self.max_h is None:
                raise InputError("an MRFT flight's limits need the largest amplitude (--max-amplitude) and relay "
                                 "height (--max-h)")
            check_time("the time available (--time)", self.time_s)
            check_positive("the controller rate (--controller-rate)", self.rate_hz)
            check_positive("the sensor noise (--noise)", self.noise_std)

    @property
    def flight(self) -> bool:
        """Whether these are an MRFT flight's limits (eq. (2)): the time, rate or noise given."""
        return not (math.isnan(self.time_s) and math.isnan(self.rate_hz) and math.isnan(self.noise_std))

    def bounds(self) -> tuple[float, float]:
        """(largest amplitude [output units], largest relay height [command units]) of an MRFT flight."""
        if self.max_amplitude is None or self.max_h is None:
            raise InputError("an MRFT flight's limits need --max-amplitude and --max-h")
        return self.max_amplitude, self.max_h

    def to_json(self) -> dict[str, float | None]:
        """The ``limits`` object of the plan's JSON (a relay plan's: the amplitude and the half-height)."""
        out = {"max_amplitude": self.max_amplitude, "max_h": self.max_h}
        if self.flight:
            out.update(time_s=self.time_s, rate_hz=self.rate_hz, noise_std=self.noise_std)
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> PlanLimits:
        """The ``limits`` object of :meth:`to_json`."""
        if "time_s" not in data:
            return cls(json_opt_float(data.get("max_amplitude")), json_opt_float(data.get("max_h")))
        return cls(**{k: float(data[k]) for k in ("max_amplitude", "max_h", "time_s", "rate_hz", "noise_std")})


@dataclass(frozen=True)
class FlownTest:
    """A test already flown, as measured (from a log or an ``analyze --json`` result).

    Attributes
    ----------
    beta : float
        Effective beta of the test.
    h : float
        Relay height [command units].
    frequency_hz : float
        Mean limit-cycle frequency [Hz].
    amplitude : float
        Mean output amplitude [output units].
    n_cycles : int
        Stable cycles used.
    phase : float, optional
        Mean phase of the output's fundamental relative to the relay's [rad] (``RelayCycle.phase_h1``);
        with it the draws are weighted by how well each plant explains it.
    """

    __test__ = False  # not a pytest class

    beta: float
    h: float
    frequency_hz: float
    amplitude: float
    n_cycles: int
    phase: float | None = None

    def __post_init__(self) -> None:
        check_beta(self.beta)
        check_positive("h", self.h)
        check_positive("frequency_hz", self.frequency_hz)
        check_positive("amplitude", self.amplitude)
        if int(self.n_cycles) < 1:
            raise InputError(f"a flown test needs at least one cycle, got {self.n_cycles!r}")

    def to_json(self) -> dict[str, float | int]:
        """One of the plan's ``flown_tests`` (the phase is not written)."""
        return {"beta": self.beta, "h": self.h, "frequency_hz": self.frequency_hz, "amplitude": self.amplitude,
                "n_cycles": self.n_cycles}


@dataclass(frozen=True)
class TestPlan:
    """One recommended test and its predicted limit cycle (for the prior's central plant).

    Attributes
    ----------
    beta, h, duration_s : float
        The test: MRFT beta, relay height [command units], relay duration [s].
    frequency_hz, amplitude : float
        Predicted limit cycle at the controller rate (centre of the sampled relay's band) [Hz],
        [output units], for the central plant.
    frequency_range_hz, amplitude_range : (float, float)
        Range of the prediction over the prior's draws.
    orbits_hz : tuple of float
        The sampled relay's admissible periodic orbits for the central plant [Hz].
    n_cycles : int
        Predicted stable cycles (``duration / period`` less the transient).
    td_omega : (float, float)
        Range of Td * Omega over the draws (above 5 the test says little about Td).
    """

    __test__ = False

    beta: float
    h: float
    duration_s: float
    frequency_hz: float
    amplitude: float
    frequency_range_hz: tuple[float, float]
    amplitude_range: tuple[float, float]
    orbits_hz: tuple[float, ...]
    n_cycles: int
    td_omega: tuple[float, float]

    def to_json(self) -> dict[str, Any]:
        """One of the plan's ``tests``."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


@dataclass(frozen=True)
class CandidateTest:
    """One candidate next test: a beta of eq. (2)'s grid, or a relay for a process plant.

    Attributes
    ----------
    beta : float or None
        MRFT beta (None: a relay candidate of another kind, see ``relay``).
    admissible : bool
        Whether the limits admit it (a relay candidate: its amplitude within ``--max-amplitude``);
        ``reason`` says why not (or what to watch).
    reason : str
        Empty, or the limit it breaks / the risk it runs.
    h : float or None
        Eq. (2): the largest relay height within the amplitude and height limits [command units]; a
        relay candidate: its half-height. None when some plant of the prior has no limit cycle at
        this beta (then so are the fields below).
    frequency_hz, amplitude : (float, float) or None
        Range of the predicted frequency [Hz] and amplitude [output units] over the draws (a relay
        candidate: the current model's exact cycle, both ends equal).
    n_cycles : int or None
        Fewest predicted stable cycles over the draws (eq. (2)).
    samples_per_period : float or None
        Controller samples in the shortest period (eq. (2)).
    switch_gap : float or None
        :func:`~mrftcli.plan.noise.switch_gap` for the typical plant [noise std] (eq. (2)).
    early_switch : bool
        The switch gap is under the admissible line: used only if no beta clears it (eq. (2)).
    predicted_std : dict or None
        Each unknown parameter's std [its unit] after this test: eq. (2), the median over the draws
        (admissible candidates only); a relay candidate, the Fisher update of the recorded tests
        (``inf``: still not determined).
    score : float or None
        Eq. (2)'s design criterion, mean of var(ln Td) + var(ln tau) + var(ln K) over the draws.
    relay : RelayLaw or None
        A relay candidate's law (kind, levels, beta or eps [output units]); None for eq. (2)'s grid.
    gain, phase_deg : float or None
        A relay candidate's response point: |G(j Omega)| [output units per command unit] and
        arg G(j Omega) [deg] at its frequency.
    undetermined : tuple of str
        A relay candidate: the parameters still not determined after it.
    """

    beta: float | None
    admissible: bool
    reason: str
    h: float | None = None
    frequency_hz: tuple[float, float] | None = None
    amplitude: tuple[float, float] | None = None
    n_cycles: int | None = None
    samples_per_period: float | None = None
    switch_gap: float | None = None
    early_switch: bool = False
    predicted_std: Stds | None = None
    score: float | None = None
    relay: RelayLaw | None = None
    gain: float | None = None
    phase_deg: float | None = None
    undetermined: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """One of the plan's ``candidates`` (only the fields that apply; an undetermined std is null)."""
        if self.h is None or self.frequency_hz is None or self.amplitude is None:
            return {"beta": self.beta, "admissible": self.admissible, "reason": self.reason}
        out: dict[str, Any] = {"beta": self.beta, "h": self.h, "frequency_hz": list(self.frequency_hz),
                               "amplitude": list(self.amplitude)}
        if self.relay is None:
            out.update(n_cycles=self.n_cycles, samples_per_period=self.samples_per_period)
        out.update(admissible=self.admissible, reason=self.reason)
        if self.relay is None:
            out["switch_gap"] = self.switch_gap
        if self.early_switch:
            out["early_switch"] = True
        if self.predicted_std is not None:
            out["predicted_std"] = {k: finite_or_none(v) for k, v in self.predicted_std.items()}
        if self.score is not None:
            out["score"] = self.score
        if self.relay is not None:
            out.update(relay=self.relay.to_json(), gain=self.gain, phase_deg=self.phase_deg,
                       undetermined=list(self.undetermined))
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> CandidateTest:
        """The record of :meth:`to_json`'s object (``KeyError``/``TypeError`` on a bad one)."""
        rng = {k: (float(data[k][0]), float(data[k][1])) for k in ("frequency_hz", "amplitude") if k in data}
        std = data.get("predicted_std")
        relay = data.get("relay")
        return cls(beta=json_opt_float(data.get("beta")), admissible=bool(data["admissible"]), reason=str(data["reason"]),
                   h=json_opt_float(data.get("h")), frequency_hz=rng.get("frequency_hz"), amplitude=rng.get("amplitude"),
                   n_cycles=None if data.get("n_cycles") is None else int(data["n_cycles"]),
                   samples_per_period=json_opt_float(data.get("samples_per_period")),
                   switch_gap=json_opt_float(data.get("switch_gap")), early_switch=bool(data.get("early_switch", False)),
                   predicted_std=None if std is None else _stds(std), score=json_opt_float(data.get("score")),
                   relay=None if relay is None else RelayLaw.from_json(relay), gain=json_opt_float(data.get("gain")),
                   phase_deg=json_opt_float(data.get("phase_deg")),
                   undetermined=tuple(str(n) for n in data.get("undetermined", ())))

    @classmethod
    def from_relay_v1(cls, data: Mapping[str, Any]) -> CandidateTest:
        """A candidate of a version-1 process plan (``plan --model NAME --json`` before issue 36)."""
        relay = RelayLaw.from_json(data["relay"])
        f, a = float(data["frequency_hz"]), float(data["amplitude"])
        within = bool(data.get("within_limit", True))
        return relay_candidate(relay, f, a, float(data["gain"]), float(data["phase_deg"]),
                               _stds(data["std_after"]), tuple(str(n) for n in data.get("undetermined_after", [])),
                               within)


def relay_candidate(relay: RelayLaw, frequency_hz: float, amplitude: float, gain: float, phase_deg: float,
                    std_after: Stds, undetermined: tuple[str, ...], within_limit: bool = True) -> CandidateTest:
    """A process plant's candidate relay test predicted with the current model (frequency [Hz], amplitude
    [output units], |G| and arg G [deg] at its frequency, each unknown parameter's std after it)."""
    return CandidateTest(beta=relay.beta if relay.kind == "mrft" else None, admissible=within_limit,
                         reason="" if within_limit else OVER_LIMIT, h=relay.h,
                         frequency_hz=(frequency_hz, frequency_hz), amplitude=(amplitude, amplitude),
                         predicted_std=std_after, relay=relay, gain=gain, phase_deg=phase_deg,
                         undetermined=undetermined)


#: The reason a relay candidate is not admissible.
OVER_LIMIT = "amplitude over --max-amplitude"


@dataclass(frozen=True)
class Conventional:
    """The forecast of the conventional beta -0.4 / -0.7 (the one(s) not yet flown), for comparison.

    Attributes
    ----------
    betas : tuple of float
        The conventional betas flown instead of the recommended ones.
    predicted_std, predicted_std_tests_only : dict
        Td, tau [s], K: median std over the draws, with the prior and from the tests alone.
    """

    betas: tuple[float, ...]
    predicted_std: Stds
    predicted_std_tests_only: Stds

    def to_json(self) -> dict[str, Any]:
        """The plan's ``conventional`` object."""
        return {**asdict(self), "betas": list(self.betas)}


@dataclass(frozen=True)
class PlanResult:
    """What :func:`~mrftcli.plan.plan_tests` recommends, for every family (``schema_version`` 2 as JSON).

    Eq. (2) (``soiptd``) plans the next MRFT test(s) from a prior and the tests flown: ``tests`` holds
    them with their forecast and ``candidates`` the beta grid. A process plant's plan ranks relay
    tests for the model its recorded tests identified: ``candidates`` best first (the first is
    :attr:`recommended`), ``tests`` empty, ``identification`` the current model.

    Attributes
    ----------
    model : PlantModel
        The model planned for: eq. (2), ``soiptd`` with Tp known and Td, tau, K the draws' central
        plant (the one the tests are predicted for); a process plant, the identified model.
    tests : tuple of TestPlan
        Eq. (2): the recommended next test(s), in flying order.
    predicted_std : dict
        Each unknown parameter's predicted standard deviation after the recommended test(s) [its
        unit], what is known before included (eq. (2): the median over the draws, the typical plant's).
    predicted_std_data : dict
        Eq. (2): the same from the tests alone (flown and recommended): the bootstrap std of
        ``analyze``'s MRFT estimate (``parameters_mrft``; the waveform refinement, when accepted, is tighter).
    prior_std : dict
        The standard deviations before the next test: the prior's (eq. (2): range / 4), or those the
        recorded tests leave (a process plant; ``inf``: not determined).
    conventional : Conventional or None
        Eq. (2), for comparison: the same figures for the conventional beta -0.4 / -0.7 (the one(s)
        of them not yet flown), with the same h rule and durations.
    candidates : tuple of CandidateTest
        Eq. (2): per beta on the grid (for the first recommended test). A process plant: the relay
        tests ranked, the recommended one first.
    notes : tuple of str
        Parameters no admissible test pins down, and what would help.
    predicted_std_data_range : dict
        Eq. (2): Td, tau, K -> (low, high), the 10-90 % range of ``predicted_std_data`` over the draws.
    flown : tuple of FlownTest
        Eq. (2): the tests already flown that the plan counted.
    limits : PlanLimits or None
        The limits planned within.
    simulated_std, simulated_std_range : dict
        Eq. (2) with ``n_simulated``: the median and the 10-90 % range over the simulated plants of the
        bootstrap std ``analyze`` measured on their simulated flights
        (:func:`~mrftcli.plan.forecast.simulated_flights`); empty otherwise.
    n_simulated : int
        Simulated flights that ``analyze`` could use.
    assumptions : tuple of str
        What the plan assumed rather than was given (a default sensor noise, a default prior range,
        the next relay test's cycles and noise), each naming the option that gives it; shown first.
    rate_hz : float or None
        The controller rate the tests are predicted at [Hz].
    identification : LtiIdentification or None
        A process plant: the current model from the recorded tests (as ``analyze --model`` identifies it).
    undetermined : tuple of str
        A process plant: the parameters the recorded tests do not pin down.
    why : str
        A process plant: one sentence, why the first candidate is recommended.
    """

    model: PlantModel
    tests: tuple[TestPlan, ...]
    predicted_std: Stds
    predicted_std_data: Stds
    prior_std: Stds
    conventional: Conventional | None
    candidates: tuple[CandidateTest, ...] = ()
    notes: tuple[str, ...] = ()
    predicted_std_data_range: StdRanges = field(default_factory=dict)
    flown: tuple[FlownTest, ...] = ()
    limits: PlanLimits | None = field(default=None, repr=False)
    simulated_std: Stds = field(default_factory=dict)
    simulated_std_range: StdRanges = field(default_factory=dict)
    n_simulated: int = 0
    assumptions: tuple[str, ...] = ()
    rate_hz: float | None = None
    identification: LtiIdentification | None = None
    undetermined: tuple[str, ...] = ()
    why: str = ""

    @property
    def Tp(self) -> float:
        """Eq. (2)'s known propulsion time constant [s] (read from :attr:`model`)."""
        if not isinstance(self.model, LoopModel):
            raise TypeError(f"a {self.model.family} plan has no Tp")
        return self.model.Tp

    @property
    def recommended(self) -> CandidateTest:
        """A process plant's recommended relay test (the first candidate; eq. (2)'s are :attr:`tests`)."""
        if self.identification is None:
            raise TypeError("an eq. (2) plan's recommended tests are its tests, its candidates the beta grid")
        return self.candidates[0]

    def to_json(self) -> dict[str, Any]:
        """JSON object of ``mrft-ident plan --json`` (``schema_version`` first)."""
        out = {
            "schema_version": SCHEMA_VERSION,
            "assumptions": list(self.assumptions),
            "model": self.model.to_json(),
            "rate_hz": self.rate_hz,
            "tests": [t.to_json() for t in self.tests],
            "predicted_std": {k: finite_or_none(v) for k, v in self.predicted_std.items()},
            "predicted_std_tests_only": self.predicted_std_data,
            "predicted_std_tests_only_range": {k: list(v) for k, v in self.predicted_std_data_range.items()},
            "simulated_std": self.simulated_std,
            "simulated_std_range": {k: list(v) for k, v in self.simulated_std_range.items()},
            "n_simulated": self.n_simulated,
            "prior_std": {k: finite_or_none(v) for k, v in self.prior_std.items()},
            "conventional": None if self.conventional is None else self.conventional.to_json(),
            "candidates": [c.to_json() for c in self.candidates],
            "notes": list(self.notes),
            "flown_tests": [f.to_json() for f in self.flown],
            "limits": None if self.limits is None else self.limits.to_json(),
        }
        if self.identification is not None:
            out.update(identification=self.identification.to_json(), undetermined=list(self.undetermined),
                       why=self.why, recommended=0)
        return out

    @classmethod
    def from_json(cls, data: object) -> PlanResult:
        """The plan of a :meth:`to_json` object (e.g. a ``plan --json`` file, parsed); version 1 too (eq. (2)'s
        plan and ``plan --model NAME``'s process plan), for one release.

        Raises
        ------
        InputError
            Not a JSON object, another ``schema_version``, or a missing or malformed field.
        """
        data = check_schema_version(data, "plan --json result", (1, SCHEMA_VERSION),
                                    fix="run plan again with this version")
        try:
            if data["schema_version"] == 1:
                return _process_v1(data) if data.get("kind") == "process" else cls._parse(data, v1=True)
            return cls._parse(data)
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise InputError(f"not a valid plan --json result ({type(err).__name__}: {err})") from err

    @classmethod
    def _parse(cls, data: Mapping[str, Any], v1: bool = False) -> PlanResult:
        conv = data["conventional"]
        ident = None if data.get("identification") is None else LtiIdentification.from_json(data["identification"])
        limits = None if data["limits"] is None else PlanLimits.from_json(data["limits"])
        if v1:  # eq. (2)'s plan before issue 36: Tp, no model, the rate in the limits
            model: PlantModel = soiptd_model(float(data["Tp"]))
        else:
            model = ident.model if ident is not None else LoopModel.from_json(data["model"])
        candidates = tuple(CandidateTest.from_json(c) for c in data["candidates"])
        if ident is not None and not candidates:
            raise InputError("not a valid plan --json result: a relay plan without a candidate")
        rate = data.get("rate_hz", limits.rate_hz if limits is not None and limits.flight else None)
        return cls(
            model=model,
            tests=tuple(_test_plan(t) for t in data["tests"]),
            predicted_std=_stds(data["predicted_std"]),
            predicted_std_data=_stds(data["predicted_std_tests_only"]),
            prior_std=_stds(data["prior_std"]),
            conventional=None if conv is None else Conventional(
                betas=tuple(float(b) for b in conv["betas"]), predicted_std=_stds(conv["predicted_std"]),
                predicted_std_tests_only=_stds(conv["predicted_std_tests_only"])),
            candidates=candidates,
            notes=tuple(str(n) for n in data["notes"]),
            predicted_std_data_range=_ranges(data["predicted_std_tests_only_range"]),
            flown=tuple(FlownTest(beta=float(f["beta"]), h=float(f["h"]), frequency_hz=float(f["frequency_hz"]),
                                  amplitude=float(f["amplitude"]), n_cycles=int(f["n_cycles"]))
                        for f in data["flown_tests"]),
            limits=limits,
            simulated_std=_stds(data["simulated_std"]),
            simulated_std_range=_ranges(data["simulated_std_range"]),
            n_simulated=int(data["n_simulated"]),
            # absent from plans written before issue 26 (nothing was stated then)
            assumptions=tuple(str(a) for a in data.get("assumptions", ())),
            rate_hz=None if rate is None else float(rate),
            identification=ident,
            undetermined=tuple(str(n) for n in data.get("undetermined", ())),
            why=str(data.get("why", "")),
        )


def _process_v1(data: Mapping[str, Any]) -> PlanResult:
    """A version-1 process plan (``plan --model NAME --json`` before issue 36: ``kind "process"``)."""
    ident = LtiIdentification.from_json(data["identification"])
    candidates = tuple(CandidateTest.from_relay_v1(c) for c in data["candidates"])
    if not candidates:
        raise InputError("not a valid plan --json result: a relay plan without a candidate")
    first = candidates[0].predicted_std
    return PlanResult(model=ident.model, tests=(), predicted_std=dict(first or {}), predicted_std_data={},
                      prior_std=_stds(data["std_now"]), conventional=None, candidates=candidates,
                      notes=tuple(str(n) for n in data.get("notes", [])),
                      assumptions=tuple(str(a) for a in data.get("assumptions", [])),
                      rate_hz=float(data["rate_hz"]), identification=ident,
                      undetermined=tuple(str(n) for n in data.get("undetermined", [])), why=str(data["why"]))


def _stds(data: Mapping[str, Any]) -> Stds:
    """{name: std} from JSON (null: not determined, infinity)."""
    return {str(k): math.inf if v is None else float(v) for k, v in data.items()}


def _ranges(data: Mapping[str, Any]) -> StdRanges:
    return {str(k): (float(v[0]), float(v[1])) for k, v in data.items()}


def _test_plan(data: Mapping[str, Any]) -> TestPlan:
    """The record of :meth:`TestPlan.to_json` (its lists as tuples of floats, ``n_cycles`` an int)."""
    def value(name: str, v: Any) -> Any:
        return tuple(float(x) for x in v) if isinstance(v, list) else int(v) if name == "n_cycles" else float(v)

    return TestPlan(**{f.name: value(f.name, data[f.name]) for f in fields(TestPlan)})
