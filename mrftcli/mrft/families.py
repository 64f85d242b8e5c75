"""Process-plant structures beside eq. (2): FOPDT, SOPDT, IPDT, FOIPDT (Astrom-Hagglund's relay plants).

Each family is a frozen dataclass implementing :class:`~mrftcli.mrft.model.PlantModel`, so every
caller that takes a plant model (the exact limit cycle :func:`~mrftcli.mrft.lprs.mrft_limit_cycle`,
the direct identification :mod:`mrftcli.mrft.identify_lti`) takes them unchanged. In every family
the gain is ``K`` and the transport delay ``tau`` [s]; the JSON ``parameters`` are keyed by these
names:

========  ===========================================  ==========================
family    G(s)                                         parameters
========  ===========================================  ==========================
fopdt     K e^{-tau s} / (T s + 1)                     K, T, tau
sopdt     K e^{-tau s} / ((T1 s + 1)(T2 s + 1))        K, T1, T2, tau
ipdt      K e^{-tau s} / s                             K, tau
foipdt    K e^{-tau s} / (s (T s + 1))                 K, T, tau
========  ===========================================  ==========================

K is in output units per command unit (per second for the integrating families). By default no
parameter is known (the paper's set E is empty) and the ranges (set I) are the physical ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError
from .model import SpecModel, StateSpace, UnitNormalisation

__all__ = ["FOPDT", "SOPDT", "IPDT", "FOIPDT", "PROCESS_FAMILIES", "family_model"]

_INF = math.inf
_TIME = ("s", (0.0, _INF))


@dataclass(frozen=True)
class _Family(SpecModel):
    """What the four families share: a chain of lags behind integrators (subclasses are frozen dataclasses).

    A subclass declares its parameters as fields, :attr:`_spec` (name -> unit, description, physical
    bounds; K and tau always present) and the number of integrators :attr:`_integrators`; parameters,
    validation and JSON are :class:`~mrftcli.mrft.model.SpecModel`'s. ``known`` (the set E) and
    ``ranges`` (the set I) are keyword-only.
    """

    family: ClassVar[str]
    structure: ClassVar[str]
    #: the families' strategy in :func:`mrftcli.mrft.identify.identify`: a direct fit to response points
    identification: ClassVar[str] = "response-points"
    _spec: ClassVar[dict[str, tuple[str, str, tuple[float, float]]]]
    _integrators: ClassVar[int]
    known: frozenset[str] = field(default=frozenset(), repr=False, compare=False, kw_only=True)
    ranges: tuple[tuple[str, float, float], ...] = field(default=(), repr=False, compare=False, kw_only=True)

    @property
    def lags(self) -> tuple[str, ...]:
        """The names of the time constants T_i of the first-order lags (T_i s + 1) in G's denominator."""
        return tuple(n for n in self._spec if n not in ("K", "tau"))

    @property
    def integrators(self) -> int:
        """n: the power of s in G's denominator (1 for the integrating families)."""
        return self._integrators

    def _time_constants(self) -> list[float]:
        return [float(getattr(self, n)) for n in self._spec if n not in ("K", "tau")]

    def frequency_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """G(j omega) including the delay; ``omega`` in rad/s."""
        s = 1j * np.asarray(omega, dtype=float)
        den = s ** self._integrators
        for T in self._time_constants():
            den = den * (T * s + 1)
        response: NDArray[np.complex128] = float(getattr(self, "K")) * np.exp(-self.delay * s) / den
        return response

    def realisation(self) -> StateSpace:
        """Delay-free realisation: a chain of first-order lags, then the integrator (if any); y = K x_last."""
        lags = self._time_constants()
        n = len(lags) + self._integrators
        A = np.zeros((n, n))
        B = np.zeros(n)
        C = np.zeros(n)
        for i, T in enumerate(lags):  # x_i' = (x_{i-1} - x_i) / T, x_{-1} = u
            A[i, i] = -1.0 / T
            if i > 0:
                A[i, i - 1] = 1.0 / T
            else:
                B[0] = 1.0 / T
        if self._integrators:
            if lags:
                A[n - 1, n - 2] = 1.0
            else:
                B[0] = 1.0
        C[n - 1] = float(getattr(self, "K"))
        return StateSpace(A, B, C, 0.0)

    def unit_normalisation(self, omega: float) -> UnitNormalisation:
        """Lemmas 1-4 for this structure: time constants times ``omega``, scale ``K / omega^integrators``."""
        coords = {f"{n.lower()}_n": float(getattr(self, n)) * omega for n in self._spec if n not in ("K", "tau")}
        return UnitNormalisation(omega=omega, coordinates=coords, theta=self.delay * omega,
                                 amplitude_scale=float(getattr(self, "K")) / omega ** self._integrators)


_K = ("output / command", "static gain", (-_INF, _INF))
_KI = ("output / (command s)", "integrating gain (output rate per command unit)", (-_INF, _INF))
_TAU = ("s", "transport delay", (0.0, _INF))


@dataclass(frozen=True)
class FOPDT(_Family):
    """First order plus dead time, G(s) = K e^{-tau s} / (T s + 1).

    Examples
    --------
    >>> G = FOPDT(K=2.0, T=0.5, tau=0.1)
    >>> round(abs(complex(G.frequency_response(2.0))), 4)
    1.4142
    >>> G.realisation().order, sorted(G.to_json()["parameters"])
    (1, ['K', 'T', 'tau'])
    """

    family: ClassVar[str] = "fopdt"
    structure: ClassVar[str] = "K e^{-tau s} / (T s + 1)"
    _spec: ClassVar[dict[str, tuple[str, str, tuple[float, float]]]] = {
        "K": _K, "T": ("s", "time constant", _TIME[1]), "tau": _TAU}
    _integrators: ClassVar[int] = 0

    K: float
    T: float
    tau: float

@dataclass(frozen=True)
class SOPDT(_Family):
    """Second order plus dead time, G(s) = K e^{-tau s} / ((T1 s + 1)(T2 s + 1)).

    T1 and T2 are interchangeable in G; the identification reports them with T1 >= T2.

    Examples
    --------
    >>> G = SOPDT(K=1.0, T1=1.0, T2=0.25, tau=0.1)
    >>> round(abs(complex(G.frequency_response(1.0))), 4)
    0.686
    """

    family: ClassVar[str] = "sopdt"
    structure: ClassVar[str] = "K e^{-tau s} / ((T1 s + 1)(T2 s + 1))"
    _spec: ClassVar[dict[str, tuple[str, str, tuple[float, float]]]] = {
        "K": _K, "T1": ("s", "first time constant", _TIME[1]),
        "T2": ("s", "second time constant", _TIME[1]), "tau": _TAU}
    _integrators: ClassVar[int] = 0

    K: float
    T1: float
    T2: float
    tau: float

@dataclass(frozen=True)
class IPDT(_Family):
    """Integrator plus dead time, G(s) = K e^{-tau s} / s.

    Examples
    --------
    >>> round(abs(complex(IPDT(K=3.0, tau=0.2).frequency_response(1.5))), 4)
    2.0
    """

    family: ClassVar[str] = "ipdt"
    structure: ClassVar[str] = "K e^{-tau s} / s"
    _spec: ClassVar[dict[str, tuple[str, str, tuple[float, float]]]] = {"K": _KI, "tau": _TAU}
    _integrators: ClassVar[int] = 1

    K: float
    tau: float

@dataclass(frozen=True)
class FOIPDT(_Family):
    """First order, integrator plus dead time, G(s) = K e^{-tau s} / (s (T s + 1)).

    Examples
    --------
    >>> G = FOIPDT(K=1.0, T=1.0, tau=0.0)
    >>> round(abs(complex(G.frequency_response(1.0))), 4)
    0.7071
    """

    family: ClassVar[str] = "foipdt"
    structure: ClassVar[str] = "K e^{-tau s} / (s (T s + 1))"
    _spec: ClassVar[dict[str, tuple[str, str, tuple[float, float]]]] = {
        "K": _KI, "T": ("s", "time constant", _TIME[1]), "tau": _TAU}
    _integrators: ClassVar[int] = 1

    K: float
    T: float
    tau: float

#: the process families by name (registered in :data:`mrftcli.mrft.model.MODEL_FAMILIES`)
PROCESS_FAMILIES: dict[str, type[Any]] = {c.family: c for c in (FOPDT, SOPDT, IPDT, FOIPDT)}


def family_model(family: str, known: Mapping[str, float] | None = None,
                 ranges: Mapping[str, tuple[float, float]] | None = None) -> Any:
    """A process-family model to identify: the known parameters (set E) at their values, ranges (set I).

    The unknown parameters get placeholder values (1 for K and time constants, 0 for tau) that the
    identification ignores.

    Raises
    ------
    InputError
        An unknown family or parameter name, or a bad value.

    Examples
    --------
    >>> m = family_model("fopdt", known={"tau": 0.05}, ranges={"T": (0.01, 10.0)})
    >>> [(p.name, p.known, p.bounds) for p in m.parameters.values()][1:]
    [('T', False, (0.01, 10.0)), ('tau', True, (0.0, inf))]
    """
    if family not in PROCESS_FAMILIES:
        raise InputError(f"unknown process family {family!r}; known: {', '.join(PROCESS_FAMILIES)}")
    cls = PROCESS_FAMILIES[family]
    known, ranges = dict(known or {}), dict(ranges or {})
    bad = (set(known) | set(ranges)) - set(cls._spec)
    if bad:
        raise InputError(f"unknown parameter(s) {sorted(bad)} of {family}; it has {', '.join(cls._spec)}")
    values = {n: (0.0 if n == "tau" else 1.0) for n in cls._spec}
    values.update(known)
    for name, (lo, hi) in ranges.items():
        if not lo < hi:
            raise InputError(f"range of {name}: low {lo:g} must be below high {hi:g}")
    return cls(**values, known=frozenset(known),
               ranges=tuple((n, float(lo), float(hi)) for n, (lo, hi) in ranges.items()))
