"""The loop model as an object: named parameters, frequency response, state space, normalisation.

The paper (Section II) writes the plant as W(s, p) with a parameter vector p (time constants, gain,
delay) and two sets of constraints on its estimate: E, the parameters known beforehand (Tp from a
bench test), and I, the ranges the unknown ones may take. A :class:`PlantModel` carries exactly
that: its :attr:`~PlantModel.parameters` are :class:`Parameter` records (name, unit, value, known,
bounds), and it exposes what the maths needs from a structure:

* :meth:`~PlantModel.frequency_response` G(j omega), delay included;
* :meth:`~PlantModel.realisation` (A, B, C, D) of the delay-free part and :attr:`~PlantModel.delay`
  [s], for the exact propagation of the LPRS and of the simulators;
* :meth:`~PlantModel.unit_normalisation`, the scaling of Lemmas 1-4 to the unit frequency / unit
  gain manifolds (UFM/UGM), where the structure has one (None otherwise);
* :meth:`~PlantModel.with_parameters`, a copy with some values changed.

:class:`LoopModel` is the paper's eq. (2),

    G(s) = K Td e^{-tau s} / (s (Tp s + 1) (Td s + 1)),

Tp the propulsion time constant [s] (known from a bench test), Td the drag time constant [s], tau
the loop's transport delay [s] and K the gain [output units / (command unit * s^2)], so that K Td
is the static gain from command to output rate. :data:`MODEL_FAMILIES` names the structures by
family; new structures (first order plus delay, integrator plus delay, ...) register there and
callers that take a :class:`PlantModel` need no change.

Eq. (2) admits a small lead, tau down to :func:`lead_floor` = -min(Tp / 2, 6 ms): a loop with a little less
lag than eq. (2) without delay, as an estimator's lead makes it (PX4 SIH's rate loops on EKF2's attitude
-2.9 to -4.4 ms, ArduPilot SITL's altitude on EKF3 -3.1 ms). The 6 ms cap (:data:`LEAD_CAP_S`) is there
because a Tp given too large also reads as a lead, of tens of ms on the same logs, and those logs cannot
check Tp on the waveform: beyond the cap ``analyze`` (and the model itself) refuses, naming --tp; within it,
``analyze`` refuses a lead whose tests held out disagree (docs/method.md section 4). ``delay`` fits its
delays down to the same floor.
"""

from __future__ import annotations

import math
import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Iterable, Mapping, Protocol, Self, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..jsonable import check_schema_version
from ..errors import InputError
from ..validate import MAX_TIME_S

if TYPE_CHECKING:
    from .lprs import LimitCycle

__all__ = ["LEAD_MAX", "LEAD_CAP_S", "lead_floor", "Parameter", "StateSpace", "UnitNormalisation", "PlantModel", "LoopModel", "MODEL_FAMILIES",
           "model_family", "model_from_json", "SampledPlantModel", "MODEL_SCHEMA_VERSION", "model_json", "model_json_parameters",
           "json_bounds", "soiptd_model", "ParameterSpec", "SpecModel", "check_parameter_names", "spec_parameters",
           "K_UNIT"]

_INF = math.inf
#: version of the JSON form of a model (``to_json`` / ``from_json``)
MODEL_SCHEMA_VERSION = 1


@dataclass(frozen=True)
class Parameter:
    """One named parameter of a plant model.

    Attributes
    ----------
    name : str
        The paper's symbol (``"Tp"``, ``"Td"``, ``"tau"``, ``"K"``).
    unit : str
        Its unit (``"s"`` for times; gains are in output units per command unit and time power).
    value : float
        Its value in ``unit``.
    known : bool
        True for the paper's set E (given, e.g. from a bench test), False for a parameter to identify.
    bounds : tuple of float
        The admissible range (low, high) in ``unit``: the paper's set I for an unknown parameter,
        the physical range otherwise. Inclusive; infinite ends are open.
    description : str
        What it is, in words.
    """

    name: str
    unit: str
    value: float
    known: bool
    bounds: tuple[float, float] = (-_INF, _INF)
    description: str = ""

    def contains(self, value: float) -> bool:
        """Is ``value`` within :attr:`bounds`?"""
        return self.bounds[0] <= value <= self.bounds[1]


@dataclass(frozen=True, eq=False)
class StateSpace:
    """A delay-free single-input single-output realisation x' = A x + B u, y = C x + D u.

    Attributes
    ----------
    A : numpy.ndarray
        (n, n) state matrix [1/s].
    B, C : numpy.ndarray
        (n,) input and output vectors.
    D : float
        Direct feedthrough (0 for the strictly proper plants of relay tests).
    """

    A: NDArray[np.float64]
    B: NDArray[np.float64]
    C: NDArray[np.float64]
    D: float = 0.0

    @property
    def order(self) -> int:
        """Number of states."""
        return int(self.A.shape[0])


@dataclass(frozen=True)
class UnitNormalisation:
    """A plant oscillating at ``omega`` mapped onto the UFM/UGM (Lemmas 1-4).

    Scaling time by ``omega`` makes every plant of a structure oscillate at 1 rad/s: its
    normalised time constants are the UFM's coordinates and ``theta = tau * omega`` the UFM's value.
    The amplitude scales as ``a_y = h * amplitude_scale * a_unit`` with ``a_unit`` the UGM's value.

    Attributes
    ----------
    omega : float
        The oscillation frequency [rad/s].
    coordinates : mapping of str to float
        The normalised time constants (dimensionless), e.g. ``{"tp_n": Tp*omega, "td_n": Td*omega}``.
    theta : float
        The normalised delay ``tau * omega`` [rad].
    amplitude_scale : float
        Static gain over frequency, ``K Td / omega`` for eq. (2) [output units per command unit].
    """

    omega: float
    coordinates: Mapping[str, float] = field(hash=False)
    theta: float
    amplitude_scale: float


@runtime_checkable
class PlantModel(Protocol):
    """What the MRFT maths needs from a plant structure (see the module docstring).

    Every structure has a transport delay ``tau`` [s] and a gain ``K``; its other parameters are
    its own. Implementations are immutable (frozen dataclasses).
    """

    #: the structure's name in :data:`MODEL_FAMILIES`
    family: ClassVar[str]
    #: the transfer function in words, e.g. ``"K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1))"``
    structure: ClassVar[str]

    @property
    def parameters(self) -> Mapping[str, Parameter]:
        """The named parameters, in the structure's order."""
        ...

    @property
    def delay(self) -> float:
        """The transport delay tau [s]."""
        ...

    def frequency_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """G(j omega), delay included; ``omega`` in rad/s."""
        ...

    def realisation(self) -> StateSpace:
        """The delay-free part as a :class:`StateSpace`."""
        ...

    def unit_normalisation(self, omega: float) -> UnitNormalisation | None:
        """The UFM/UGM coordinates of this plant oscillating at ``omega`` [rad/s]; None without them."""
        ...

    def with_parameters(self, **values: float) -> PlantModel:
        """A copy with the named parameters set to new values."""
        ...

    def to_json(self) -> dict[str, Any]:
        """The JSON form: ``schema_version``, ``family`` and the parameters (see :meth:`LoopModel.to_json`)."""
        ...

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> PlantModel:
        """The model of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input."""
        ...


@runtime_checkable
class SampledPlantModel(Protocol):
    """A plant whose exact object is sampled (a controller inside it, as the cascade of an outer loop).

    :func:`~mrftcli.mrft.lprs.mrft_limit_cycle` hands its MRFT cycle at a relay rate to the model.
    """

    def sampled_limit_cycle(self, beta: float, h: float, rate_hz: float,
                            n_guess: float | None = None) -> LimitCycle:
        """The exact MRFT limit cycle with the relay at ``rate_hz`` [Hz] (``n_guess``: a half period [ticks] near it)."""
        ...


#: a structure's parameters by name: (unit, description, physical bounds)
ParameterSpec = Mapping[str, tuple[str, str, tuple[float, float]]]


def check_parameter_names(names: Iterable[str], spec: ParameterSpec, family: str) -> None:
    """InputError naming any of ``names`` that is not a parameter of the structure ``spec``."""
    bad = set(names) - set(spec)
    if bad:
        raise InputError(f"unknown parameter(s) {sorted(bad)} of {family}; it has {list(spec)}")


def spec_parameters(model: Any, spec: ParameterSpec) -> dict[str, Parameter]:
    """The :class:`Parameter` records of a model whose parameters are its attributes named in ``spec``
    (its ``known`` set and ``ranges``, the set I, where given; else the physical bounds)."""
    ranges = {name: (lo, hi) for name, lo, hi in model.ranges}
    return {name: Parameter(name, unit, float(getattr(model, name)), name in model.known,
                            ranges.get(name, bounds), description)
            for name, (unit, description, bounds) in spec.items()}


class SpecModel:
    """What the structures with named parameters share (eq. (2), the process families, the cascade).

    A subclass is a frozen dataclass whose parameters are its fields named in :attr:`_spec` (name ->
    unit, description, physical bounds; ``K`` and ``tau`` always among them), with the fields
    ``known`` (the set E) and ``ranges`` (the set I). It gets the :class:`PlantModel` protocol's
    :attr:`parameters`, :attr:`delay`, :meth:`with_parameters` and JSON, and the checks of its values
    (:meth:`_check`, called by its ``__post_init__``).
    """

    family: ClassVar[str]
    _spec: ClassVar[ParameterSpec]
    known: frozenset[str]
    ranges: tuple[tuple[str, float, float], ...]

    def __post_init__(self) -> None:
        self._check()

    def _check(self) -> None:
        """InputError naming a value out of its domain (times positive, tau >= 0, K finite and non-zero;
        every time at most a week, :data:`~mrftcli.validate.MAX_TIME_S`) or an unknown name in E or I."""
        for name, (unit, _, _) in self._spec.items():
            value = float(getattr(self, name))
            if name == "K":
                if not math.isfinite(value) or value == 0:
                    raise InputError(f"K must be finite and non-zero, got {value!r}")
            elif name == "tau":
                if not math.isfinite(value) or value < self._tau_floor():
                    lead = f" (or a lead down to {self._tau_floor():.4g} s)" if self._tau_floor() < 0 else ""
                    raise InputError(f"tau must be a non-negative time in seconds{lead}, got {value!r}")
            elif unit == "s" and (not math.isfinite(value) or value <= 0):
                raise InputError(f"{name} must be a positive time in seconds, got {value!r}")
        for name, (unit, _, _) in self._spec.items():  # the shared bound of every time (a week): 1e300 broke the root finders
            if unit == "s" and float(getattr(self, name)) > MAX_TIME_S:
                raise InputError(f"{name} = {float(getattr(self, name)):g} s is longer than a week ({MAX_TIME_S:g} s); "
                                 "give it in seconds")
        check_parameter_names(set(self.known).union(r[0] for r in self.ranges), self._spec, self.family)

    def _tau_floor(self) -> float:
        """The least tau [s] the family admits: 0 (a transport delay); eq. (2) admits a small lead."""
        return 0.0

    @property
    def parameters(self) -> dict[str, Parameter]:
        """The named parameters as :class:`Parameter` records (bounds: the set I where given)."""
        return spec_parameters(self, self._spec)

    @property
    def delay(self) -> float:
        """The transport delay tau [s]."""
        return float(getattr(self, "tau"))

    def with_parameters(self, **values: float) -> Self:
        """A copy with some parameters replaced (validated as in the constructor)."""
        check_parameter_names(values, self._spec, self.family)
        return dataclasses.replace(self, **{k: float(v) for k, v in values.items()})  # type: ignore[type-var]

    def to_json(self) -> dict[str, Any]:
        """``{"schema_version", "family", "parameters": {name: {"value", "unit", "known", "bounds"}}}``
        (infinite bounds written as null: JSON has no infinity)."""
        return model_json(self.family, self.parameters.values())

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Self:
        """The model of a :meth:`to_json` dict.

        Raises
        ------
        InputError
            Not a dict of this schema version and family, or a parameter missing or out of range.
        """
        values, known, ranges = json_parameter_values(model_json_parameters(data, cls.family), cls._spec)
        return cls(**values, known=known, ranges=ranges)  # type: ignore[call-arg]


#: the largest lead (negative tau) eq. (2) admits, in units of Tp: a loop with a little less lag than eq. (2)
#: without delay (an estimator's lead: EKF2's attitude leads PX4 SIH's by 2-4 ms at Tp 50 ms, EKF3's altitude
#: ArduPilot SITL's by ~3 ms), well inside what a cycle holds at low |beta|; ``analyze`` and ``delay`` fit down to it
#: or to :data:`LEAD_CAP_S`, whichever is less (:func:`lead_floor`)
LEAD_MAX = 0.5
#: the largest lead eq. (2) admits in seconds, whatever Tp: an estimator's lead is a few ms (about one of its
#: update steps). Measured: PX4 SIH's rate loops on EKF2's attitude -2.9 to -4.4 ms (std 0.2-0.6 ms), ArduPilot
#: SITL's altitude on EKF3 -3.1 ms; 6 ms admits these with ~3 std to spare. A Tp given 1.5-10x too large reads
#: as a larger lead (-6 to -42 ms on the same logs), which -Tp/2 alone (25-250 ms there) let through
LEAD_CAP_S = 0.006
#: eq. (2)'s K unit, the one spelling of every record (the model's, analyze's parameters, watch's lines)
K_UNIT = "output / (command s^2)"


def lead_floor(Tp: float) -> float:
    """The least tau [s] eq. (2) admits at Tp [s]: ``-min(LEAD_MAX Tp, LEAD_CAP_S)``, 0 for a Tp not positive.

    The one rule of a lead (``analyze``, ``delay``, a model given with tau < 0): an estimator's lead is a few
    ms whatever the plant, so beyond :data:`LEAD_CAP_S` (6 ms) a lead is not an estimator's but a Tp given too
    large (or another lag structure): refused, naming --tp; below it, -Tp/2 is what a cycle at low |beta| holds.
    """
    return -min(LEAD_MAX * Tp, LEAD_CAP_S) if math.isfinite(Tp) and Tp > 0 else 0.0
#: eq. (2)'s parameters: unit, description, physical bounds
_LOOP_PARAMETERS: dict[str, tuple[str, str, tuple[float, float]]] = {
    "Tp": ("s", "propulsion time constant", (0.0, _INF)),
    "Td": ("s", "drag (aerodynamic) time constant", (0.0, _INF)),
    "tau": ("s", "transport delay", (0.0, _INF)),
    "K": (K_UNIT, "gain; K Td is the static gain from command to output rate", (-_INF, _INF)),
}


@dataclass(frozen=True)
class LoopModel(SpecModel):
    """Parameters of G(s) = K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1)) (paper eq. (2)).

    Attributes
    ----------
    Tp : float
        Propulsion time constant [s], > 0.
    Td : float
        Drag (aerodynamic) time constant [s], > 0.
    tau : float
        Transport delay [s], >= 0.
    K : float
        Gain; K * Td is the static gain from command to output rate. Default 1.
    known : frozenset of str
        The paper's set E: parameters given rather than identified (default: Tp, from a bench test).
    ranges : tuple of (str, float, float)
        The paper's set I: ``(name, low, high)`` ranges narrowing the physical bounds of unknown
        parameters (default: none).

    Examples
    --------
    >>> G = LoopModel(Tp=0.1, Td=0.7042, tau=0.06, K=1.42)
    >>> round(abs(complex(G.frequency_response(4.4337))), 4)
    0.0629
    >>> [(p.name, p.unit, p.known) for p in G.parameters.values()][:3]
    [('Tp', 's', True), ('Td', 's', False), ('tau', 's', False)]
    >>> G.with_parameters(tau=0.07).tau
    0.07
    >>> d = G.to_json()
    >>> d["family"], d["parameters"]["tau"]
    ('soiptd', {'value': 0.06, 'unit': 's', 'known': False, 'bounds': [0.0, None]})
    >>> LoopModel.from_json(d) == G
    True
    >>> n = G.unit_normalisation(4.4337)
    >>> round(n.coordinates["td_n"], 4), round(n.theta, 4)
    (3.1222, 0.266)
    >>> G.realisation().order
    3
    >>> LoopModel(Tp=0.1, Td=-1.0, tau=0.06)
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: Td must be a positive time in seconds, got -1.0
    """

    family: ClassVar[str] = "soiptd"
    structure: ClassVar[str] = "K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1))"
    #: the family's strategy in :func:`mrftcli.mrft.identify.identify`: the tests' means through the unit manifolds
    identification: ClassVar[str] = "unit-manifolds"
    _spec: ClassVar[ParameterSpec] = _LOOP_PARAMETERS

    Tp: float
    Td: float
    tau: float
    K: float = 1.0
    known: frozenset[str] = field(default=frozenset({"Tp"}), repr=False, compare=False)
    ranges: tuple[tuple[str, float, float], ...] = field(default=(), repr=False, compare=False)

    def _tau_floor(self) -> float:
        """A lead down to :func:`lead_floor` (-Tp / 2 or -6 ms): less lag than eq. (2) without delay."""
        return lead_floor(float(self.Tp))

    @property
    def lead(self) -> bool:
        """tau < 0: the loop leads eq. (2) without delay (an estimator's lead); no causal delay line holds it."""
        return float(self.tau) < 0.0

    # -- the PlantModel protocol (parameters, delay, with_parameters and the JSON: SpecModel's) --------
    def realisation(self) -> StateSpace:
        """Delay-free realisation with states [y, y', propulsion output] (see :meth:`state_space`)."""
        A, B, C = self.state_space()
        return StateSpace(A, B, C, 0.0)

    def state_space(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Delay-free realisation (A, B, C) with states [y, y', thrust/moment state].

        x1 = y, x2 = y' (rate), x3 = propulsion output; u enters x3 (delayed by tau, handled by the
        caller):  x1' = x2;  x2' = (-x2 + K Td x3) / Td;  x3' = (-x3 + u) / Tp.
        """
        A = np.array(
            [
                [0.0, 1.0, 0.0],
                [0.0, -1.0 / self.Td, self.K],
                [0.0, 0.0, -1.0 / self.Tp],
            ]
        )
        B = np.array([0.0, 0.0, 1.0 / self.Tp])
        C = np.array([1.0, 0.0, 0.0])
        return A, B, C

    def frequency_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """G(j omega) including the delay; omega in rad/s."""
        s = 1j * np.asarray(omega, dtype=float)
        response: NDArray[np.complex128] = (
            self.K * self.Td * np.exp(-self.tau * s) / (s * (self.Tp * s + 1) * (self.Td * s + 1))
        )
        return response

    def unit_normalisation(self, omega: float) -> UnitNormalisation:
        """Lemmas 1-4: ``tp_n = Tp omega``, ``td_n = Td omega``, ``theta = tau omega``, scale ``K Td / omega``."""
        return UnitNormalisation(omega=omega, coordinates={"tp_n": self.Tp * omega, "td_n": self.Td * omega},
                                 theta=self.tau * omega, amplitude_scale=self.K * self.Td / omega)


def soiptd_model(Tp: float, K: float | None = None) -> LoopModel:
    """Eq. (2) to identify: Tp known (the bench test's propulsion time constant [s], the paper's set E).

    ``K`` given: known too (the single-test amplitude route of :func:`mrftcli.mrft.identify.identify`).

    Td, tau and K get placeholder values (1 s, 0 s, 1) that identification ignores, as the process
    families' do (:func:`mrftcli.mrft.families.family_model`): this is the model object every use
    case (analyze, identify, simulate, watch, plan, tune, diagnose) takes for eq. (2), so Tp travels
    inside it.

    Raises
    ------
    InputError
        Tp not a positive time in seconds.

    Examples
    --------
    >>> m = soiptd_model(0.0422)
    >>> m.family, m.Tp, sorted(m.known)
    ('soiptd', 0.0422, ['Tp'])
    """
    if K is None:
        return LoopModel(Tp=float(Tp), Td=1.0, tau=0.0, K=1.0)
    return LoopModel(Tp=float(Tp), Td=1.0, tau=0.0, K=float(K), known=frozenset({"Tp", "K"}))


def model_json(family: str, parameters: Iterable[Parameter]) -> dict[str, Any]:
    """The JSON form every family shares (infinite bounds written as null: JSON has no infinity)."""
    def bound(x: float) -> float | None:
        return x if math.isfinite(x) else None

    return {"schema_version": MODEL_SCHEMA_VERSION, "family": family,
            "parameters": {p.name: {"value": p.value, "unit": p.unit, "known": p.known,
                                    "bounds": [bound(p.bounds[0]), bound(p.bounds[1])]}
                           for p in parameters}}


def model_json_parameters(data: Mapping[str, Any], family: str) -> Mapping[str, Any]:
    """The ``parameters`` of a model's JSON after checking its version and family."""
    data = check_schema_version(data, "model JSON", MODEL_SCHEMA_VERSION)
    if data.get("family") != family:
        raise InputError(f"model JSON family {data.get('family')!r} is not {family!r}")
    params = data.get("parameters")
    if not isinstance(params, Mapping):
        raise InputError("model JSON needs a 'parameters' object")
    return params


def json_parameter_values(
    params: Mapping[str, Any], spec: Mapping[str, tuple[str, str, tuple[float, float]]]
) -> tuple[dict[str, float], frozenset[str], tuple[tuple[str, float, float], ...]]:
    """Values, the known set (E) and the ranges narrower than physical (I) of a model JSON's parameters.

    ``spec`` maps each parameter of the structure to ``(unit, description, physical range)``; every one
    must be present with a numeric ``value``. Raises :class:`~mrftcli.errors.InputError` otherwise.
    """
    values: dict[str, float] = {}
    known: set[str] = set()
    ranges: list[tuple[str, float, float]] = []
    for name, (_, _, physical) in spec.items():
        entry = params.get(name)
        if not isinstance(entry, Mapping) or not isinstance(entry.get("value"), (int, float)):
            raise InputError(f"model JSON: parameter {name!r} needs a numeric 'value'")
        values[name] = float(entry["value"])
        if entry.get("known"):
            known.add(name)
        lo, hi = json_bounds(name, entry.get("bounds"), physical)
        if (lo, hi) != physical:
            ranges.append((name, lo, hi))
    return values, frozenset(known), tuple(ranges)


def json_bounds(name: str, bounds: Any, physical: tuple[float, float]) -> tuple[float, float]:
    """(low, high) from a JSON ``[low, high]`` with null for an infinite end (``physical`` when absent)."""
    if bounds is None:
        return physical
    if not (isinstance(bounds, (list, tuple)) and len(bounds) == 2
            and all(b is None or isinstance(b, (int, float)) for b in bounds)):
        raise InputError(f"model JSON: bounds of {name!r} must be [low, high] (null for no bound)")
    lo = -_INF if bounds[0] is None else float(bounds[0])
    hi = _INF if bounds[1] is None else float(bounds[1])
    return lo, hi


# the process families (families.py) import this module's records, so they are registered last
from .families import PROCESS_FAMILIES  # noqa: E402
from .model_file import DeclaredModel  # noqa: E402

#: the plant structures by family name: eq. (2), the process plants of :mod:`mrftcli.mrft.families`
#: and a structure declared in a model file (:mod:`mrftcli.mrft.model_file`)
MODEL_FAMILIES: dict[str, type[PlantModel]] = {"soiptd": LoopModel, **PROCESS_FAMILIES, "declared": DeclaredModel}


def model_family(name: str) -> type[PlantModel]:
    """The model class of a family name.

    Raises
    ------
    InputError
        An unknown family (the message lists the known ones).

    Examples
    --------
    >>> model_family("soiptd").__name__
    'LoopModel'
    """
    try:
        return MODEL_FAMILIES[name]
    except KeyError:
        raise InputError(f"unknown model family {name!r}; known: {', '.join(sorted(MODEL_FAMILIES))}") from None


def model_from_json(data: Mapping[str, Any]) -> PlantModel:
    """A model of any registered family from its ``to_json`` dict.

    Raises
    ------
    InputError
        Not an object, an unknown family, or bad parameters (one-line message).

    Examples
    --------
    >>> model_from_json(LoopModel(0.1, 0.7, 0.06).to_json())
    LoopModel(Tp=0.1, Td=0.7, tau=0.06, K=1.0)
    """
    if not isinstance(data, Mapping):
        raise InputError(f"model JSON: expected a JSON object, got {type(data).__name__}")
    return model_family(str(data.get("family"))).from_json(data)


# the cascade of an outer loop (cascade.py) is built on this module's records and on the limit cycles
# that import it, so it is registered after everything here is defined
from .cascade import CascadeModel  # noqa: E402

MODEL_FAMILIES["cascade"] = CascadeModel
