"""The outer loop of a cascade (x, y through the closed attitude loop): model, exact sampled limit cycle, identification.

The lateral plant of a multirotor is the inner attitude loop, closed by the controller it flies,
followed by the translational dynamics (issue 23; the paper's Section V leaves it as future work)::

    G_outer(s) = K T_inner(s) Td e^{-tau s} / (s (Td s + 1))

with T_inner the inner loop closed by its *sampled* controller, K known (1 for a commanded
acceleration, g = 9.80665 m/s^2 for a commanded attitude in rad) or identified, and Td [s], tau [s] the
outer loop's drag time constant and delay. The inner loop is sampled, so the exact object is
discrete-time: :meth:`CascadeModel.discrete_realisation` is its exact zero-order-hold realisation
at the controller rate, from the outer relay's command (held over a tick) to the outer output
sampled at the ticks:

* the inner plant (any :class:`~mrftcli.mrft.model.PlantModel`, usually eq. (2)) with its delay on
  its command (tau_i = d_i T + eps_i: the command of tick k - d_i - 1 acts for the first eps_i of a
  period, that of tick k - d_i for the rest);
* the inner controller in tune's generic form (:class:`~mrftcli.mrft.controller.Controller`: parallel PID, derivative on
  the measurement through a first-order filter Tf, backward differences, at ``rate_hz``)::

      e_k = r_k - phi_k,  I_k = I_{k-1} + Ki T e_k,  D_k = (Tf D_{k-1} - Kd (phi_k - phi_{k-1})) / (Tf + T)
      c_k = Kp e_k + I_k + D_k

  where r_k is the outer relay's command of the same tick (the outer relay runs first);
* the translational dynamics p'' = K phi - p' / Td driven by the continuous inner output phi(t);
* the outer delay on the measurement: y_k = p(k T - tau).

The MRFT's limit cycle of this system is found exactly (:func:`discrete_limit_cycle`): for each
half period of N ticks the symmetric periodic orbit of the discrete system is solved in closed form
and the sampled MRFT rule (``checks.md`` section 2) checked sample by sample, as
:func:`mrftcli.mrft.lprs.sampled_limit_cycle` does for a continuous plant; the band of admissible
orbits and its centre are returned in a :class:`~mrftcli.mrft.lprs.LimitCycle`, so
:func:`~mrftcli.mrft.lprs.mrft_limit_cycle` (``rate_hz`` given) takes a :class:`CascadeModel`.

:func:`mrftcli.mrft.identify.identify` (the strategy :func:`mrftcli.mrft.cascade_identify.fit_cascade_cycles`) finds Td and tau (and K when not known) from the outer tests' mean
frequencies and amplitudes through that exact cycle; the inner model's uncertainty enters as draws
of the inner loop, each solved again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar, Mapping, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError
from ..jsonable import check_schema_version
from ..validate import check_beta, check_positive
from .controller import Controller
from .propagate import phi_gamma
from .model import ParameterSpec, PlantModel, SpecModel, StateSpace, json_parameter_values, model_from_json, model_json, \
    model_json_parameters

__all__ = ["InnerLoop", "CascadeModel", "DiscreteStateSpace", "discrete_limit_cycle", "STANDARD_GRAVITY",
           "INNER_LOOP_SCHEMA_VERSION", "INNER_LOOP_OF", "CASCADE_PARAMETERS", "SwitchedOrbit", "delayed_discrete", "fraction_discrete",
           "orbits", "split_interval", "whole_and_fraction"]

if TYPE_CHECKING:
    from .lprs import LimitCycle

FloatArray = NDArray[np.float64]
_INF = math.inf
#: standard gravity g [m/s^2] (CGPM's, PX4's CONSTANTS_ONE_G): the package's one g (the stacks' thrust scaling in
#: tune, the simulator's y'' = g phi, the cascade's K of a commanded attitude [rad]: the lateral acceleration per
#: radian of tilt)
STANDARD_GRAVITY = 9.80665
#: version of :meth:`InnerLoop.to_json`
INNER_LOOP_SCHEMA_VERSION = 1
#: the inner (attitude) loop each outer loop goes through: a y displacement needs a roll, x a pitch
INNER_LOOP_OF = {"y": "roll", "x": "pitch"}

#: the outer loop's parameters: unit, description, physical bounds
CASCADE_PARAMETERS: dict[str, tuple[str, str, tuple[float, float]]] = {
    "Td": ("s", "drag (translational) time constant", (0.0, _INF)),
    "tau": ("s", "outer transport delay (on the measured output)", (0.0, _INF)),
    "K": ("output / (inner output s^2)", "gain from the inner loop's output to the acceleration", (0.0, _INF)),
}


# ----------------------------------------------------------------------------------------------
# the inner loop
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class InnerLoop:
    """The inner loop an outer loop goes through: its identified plant and the controller flying it.

    Attributes
    ----------
    plant : PlantModel
        The inner loop's plant (usually eq. (2), :class:`~mrftcli.mrft.model.LoopModel`), from its
        command [command units] to its output [rad for attitude]; its delay acts on the command.
    controller : Controller
        The inner controller in use during the outer tests (its gains not all zero: the loop is closed).
    loop : str
        Its name (``"roll"``, ``"pitch"``), for messages; may be empty.
    std : tuple of (str, float)
        The standard deviations of the plant's identified parameters, ``(name, std [unit])`` (the
        inner analysis' uncertainty, for draws of the inner loop); empty: taken as exact.
    lead_s : float
        A lead [s] (< 0) the inner analysis identified and the plant takes as tau = 0 (the sampled inner loop
        holds delays only; :func:`mrftcli.analyze.cascade.inner_loop_of` sets it and the assumptions say so); 0.
    """

    plant: PlantModel
    controller: Controller
    loop: str = ""
    std: tuple[tuple[str, float], ...] = field(default=(), compare=False)
    lead_s: float = field(default=0.0, compare=False)

    def __post_init__(self) -> None:
        c = self.controller
        if c.Kp == 0 and c.Ki == 0 and c.Kd == 0:
            raise InputError("inner controller gains are all zero: the inner loop is not closed")
        if self.plant.delay < 0:  # eq. (2) admits a lead; the inner loop's sampled realisation holds delays only
            raise InputError(f"the inner loop's model leads (tau = {self.plant.delay * 1e3:.3g} ms < 0): the cascade "
                             "samples the inner loop with a delay line, which cannot hold a lead; give an inner model "
                             "with tau >= 0 (analyze.cascade.inner_loop_of takes a lead as 0 and says so)")

    def draw(self, rng: np.random.Generator) -> InnerLoop:
        """One draw of the inner loop over :attr:`std`: times and gains log-normal, the delay normal about the
        identified one (with :attr:`lead_s`: about the lead, not about the 0 the plant holds it at), then held >= 0."""
        values = {}
        for name, sd in self.std:
            value = self.plant.parameters[name].value
            if not (math.isfinite(sd) and sd > 0):
                continue
            if name == "tau":
                values[name] = max(0.0, value + self.lead_s + rng.normal(0.0, sd))
            elif value != 0:
                values[name] = value * math.exp(rng.normal(0.0, sd / abs(value)))
        return InnerLoop(self.plant.with_parameters(**values), self.controller, self.loop, self.std, self.lead_s)

    def closed_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """T_inner(j omega): the continuous inner output over a held reference, fundamental only; rad/s.

        C_ref(z) G_i(j omega) / (1 + C_fb(z) G_id(z)), z = e^{j omega T}: C_ref = Kp + Ki T z / (z - 1)
        acts on the reference, C_fb adds the derivative on the measurement, G_id is the exact
        zero-order-hold equivalent of the plant with its delay (the hold's factors of reference and
        command cancel).
        """
        w = np.asarray(omega, dtype=float)
        ctrl = self.controller
        T = ctrl.Ts
        z = np.exp(1j * w * T)
        c_ref = ctrl.Kp + ctrl.Ki * T * z / (z - 1.0)
        # Tf's first-order filter, as the discrete realisation below has it (a stack's rate filter is not modelled)
        c_fb = replace(ctrl, rate_filter=None).feedback_at(z)
        out: NDArray[np.complex128] = c_ref * self.plant.frequency_response(w) / (
            1.0 + c_fb * delayed_discrete(self.plant.realisation(), self.plant.delay, ctrl.rate_hz).frequency_response(w))
        return out

    def to_json(self) -> dict[str, Any]:
        """``{"schema_version", "loop", "plant": <model JSON>, "gains": <generic form>}``."""
        return {"schema_version": INNER_LOOP_SCHEMA_VERSION, "loop": self.loop, "plant": self.plant.to_json(),
                "gains": self.controller.to_json(), "std": dict(self.std)}

    @classmethod
    def from_json(cls, data: Any) -> InnerLoop:
        """The inner loop of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input."""
        d = check_schema_version(data, "inner loop JSON", INNER_LOOP_SCHEMA_VERSION)
        if "plant" not in d or "gains" not in d:
            raise InputError("inner loop JSON needs 'plant' and 'gains'")
        std = d.get("std") or {}
        if not isinstance(std, Mapping) or not all(isinstance(v, (int, float)) for v in std.values()):
            raise InputError("inner loop JSON: 'std' must map parameter names to numbers")
        plant = model_from_json(d["plant"])
        unknown = set(std) - set(plant.parameters)
        if unknown:
            raise InputError(f"inner loop JSON: 'std' names {sorted(unknown)}, not parameters of the plant")
        return cls(plant, Controller.from_json(d["gains"], "inner gains"), str(d.get("loop", "")),
                   tuple((str(k), float(v)) for k, v in std.items()))


# ----------------------------------------------------------------------------------------------
# the exact discrete realisation
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class DiscreteStateSpace:
    """x_{k+1} = Phi x_k + Gamma u_k,  y_k = C x_k, at ``rate_hz`` (u held over a tick).

    Attributes
    ----------
    Phi : numpy.ndarray
        (n, n) state transition over one tick.
    Gamma : numpy.ndarray
        (n,) input vector.
    C : numpy.ndarray
        (n,) output vector (strictly proper: the output of tick k does not see u_k).
    rate_hz : float
        The tick rate [Hz].
    """

    Phi: FloatArray
    Gamma: FloatArray
    C: FloatArray
    rate_hz: float

    @property
    def order(self) -> int:
        """Number of states."""
        return int(self.Phi.shape[0])

    def lifted(self, m: int) -> DiscreteStateSpace:
        """The system seen every ``m`` ticks with its input held over the ``m`` ticks (rate / m)."""
        P = np.eye(self.order)
        S = np.zeros(self.order)
        for _ in range(m):
            S = self.Phi @ S + self.Gamma
            P = self.Phi @ P
        return DiscreteStateSpace(P, S, self.C.copy(), self.rate_hz / m)

    def frequency_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """C (z I - Phi)^-1 Gamma at z = e^{j omega T}; ``omega`` in rad/s."""
        w = np.atleast_1d(np.asarray(omega, dtype=float))
        z = np.exp(1j * w / self.rate_hz)
        M = z[:, None, None] * np.eye(self.order)[None] - self.Phi[None]
        rhs = np.broadcast_to(self.Gamma.astype(complex), (z.size, self.order))[..., None]
        out: NDArray[np.complex128] = np.asarray(np.linalg.solve(M, rhs)[..., 0] @ self.C, dtype=complex)
        return out.reshape(np.shape(omega))


def split_interval(A: FloatArray, B: FloatArray, t: float,
                   eps: float | FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(e^{A t}, old-input and new-input vectors) over [0, t) [s] with the held input changing at ``eps`` [s].

    A stack of plants at once: ``A`` (M, n, n), ``B`` (M, n) and ``eps`` (M,) give (M, n, n), (M, n) and
    (M, n) (:func:`~mrftcli.mrft.propagate.phi_gamma` over the stack).
    """
    E, G = phi_gamma(A, B, t)
    if np.ndim(eps) == 0:
        if t <= eps:
            return E, G, np.zeros_like(B)
        _, G_old = phi_gamma(A, B, eps)
        E_rest, G_new = phi_gamma(A, B, t - eps)
        return E, E_rest @ G_old, G_new
    eps = np.minimum(eps, t)  # an input changing at or after t: the old one over the whole interval
    _, G_old = phi_gamma(A, B, eps)
    E_rest, G_new = phi_gamma(A, B, t - eps)
    return E, np.einsum("...ij,...j->...i", E_rest, G_old), G_new


@overload
def whole_and_fraction(delay: float, T: float) -> tuple[int, float]: ...
@overload
def whole_and_fraction(delay: FloatArray, T: float) -> tuple[NDArray[np.int_], FloatArray]: ...
def whole_and_fraction(delay: float | FloatArray, T: float) -> tuple[Any, Any]:
    """delay = d T + eps with 0 <= eps < T [s]; ``delay`` a scalar, or an array giving arrays of d and eps."""
    if np.ndim(delay) == 0:
        d = int(math.floor(float(delay) / T + 1e-12))
        return d, max(float(delay) - d * T, 0.0)
    delay = np.asarray(delay, float)
    ds = np.floor(delay / T + 1e-12).astype(int)
    return ds, np.maximum(delay - ds * T, 0.0)


def _cascade_discrete(plant: StateSpace, delay_i: float, c: Controller, K: float, Td: float,
                      tau: float) -> DiscreteStateSpace:
    """The exact discrete realisation at the inner controller's rate (the module docstring's equations).

    State X_k = [x_k (inner plant, p, v), c_{k-1} .. c_{k-d_i-1}, I_{k-1}, D_{k-1}, phi_{k-1},
    z_{k-1} .. z_{k-d_o-1}] with z_j = p(j T + T - eps_o), so that y_k = p(k T - tau) = z_{k-d_o-1}.
    """
    T = c.Ts
    ni = plant.order
    n_x = ni + 2
    A = np.zeros((n_x, n_x))
    A[:ni, :ni] = plant.A
    A[ni, ni + 1] = 1.0  # p' = v
    A[ni + 1, :ni] = K * plant.C  # v' = K phi - v / Td
    A[ni + 1, ni + 1] = -1.0 / Td
    B = np.zeros(n_x)
    B[:ni] = plant.B
    d_i, eps_i = whole_and_fraction(delay_i, T)
    d_o, eps_o = whole_and_fraction(tau, T)
    Phi, Ga, Gb = split_interval(A, B, T, eps_i)
    Pz, Gaz, Gbz = split_interval(A, B, T - eps_o, eps_i)
    ib = n_x
    iI, iD, iy = ib + d_i + 1, ib + d_i + 2, ib + d_i + 3
    iz = iy + 1
    n = iz + d_o + 1
    unit = np.eye(n)  # unit[i]: the row picking state i of X_k
    phi = np.zeros(n)
    phi[:ni] = plant.C
    # the controller of tick k: a row over X_k and the coefficient of the relay command r_k
    I_row, I_r = (unit[iI] - c.Ki * T * phi, c.Ki * T) if c.Ki > 0 else (np.zeros(n), 0.0)
    D_row = (c.Tf * unit[iD] - c.Kd * (phi - unit[iy])) / (c.Tf + T)
    c_row, c_r = -c.Kp * phi + I_row + D_row, c.Kp + I_r
    old_row, old_r = unit[ib + d_i], 0.0
    new_row, new_r = (c_row, c_r) if d_i == 0 else (unit[ib + d_i - 1], 0.0)
    Ad = np.zeros((n, n))
    Bd = np.zeros(n)
    Ad[:n_x] = Phi @ np.eye(n_x, n) + np.outer(Ga, old_row) + np.outer(Gb, new_row)
    Bd[:n_x] = Ga * old_r + Gb * new_r
    Ad[ib], Bd[ib] = c_row, c_r
    for j in range(1, d_i + 1):
        Ad[ib + j, ib + j - 1] = 1.0
    Ad[iI], Bd[iI] = I_row, I_r
    Ad[iD] = D_row
    Ad[iy] = phi
    p = np.zeros(n_x)
    p[ni] = 1.0
    Ad[iz] = p @ (Pz @ np.eye(n_x, n) + np.outer(Gaz, old_row) + np.outer(Gbz, new_row))
    Bd[iz] = p @ (Gaz * old_r + Gbz * new_r)
    for j in range(1, d_o + 1):
        Ad[iz + j, iz + j - 1] = 1.0
    C = np.zeros(n)
    C[iz + d_o] = 1.0
    return DiscreteStateSpace(Ad, Bd, C, c.rate_hz)


# ----------------------------------------------------------------------------------------------
# the model object
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CascadeModel(SpecModel):
    """G_outer(s) = K T_inner(s) Td e^{-tau s} / (s (Td s + 1)): an outer loop through its closed inner loop.

    Implements :class:`~mrftcli.mrft.model.PlantModel` (family ``"cascade"``); the exact object is
    discrete (:meth:`discrete_realisation`); :meth:`realisation` raises (no continuous one exists).

    Attributes
    ----------
    inner : InnerLoop
        The inner loop's plant and controller.
    Td : float
        Drag time constant of the translational dynamics [s], > 0.
    tau : float
        Outer transport delay [s] (on the measured output), >= 0.
    K : float
        Gain from the inner output to the acceleration [output / (inner output s^2)]: 1 for a
        commanded acceleration, :data:`STANDARD_GRAVITY` = g = 9.80665 for a commanded attitude in rad.
    known : frozenset of str
        The set E (default: K).
    ranges : tuple of (str, float, float)
        The set I: ``(name, low, high)``.

    Examples
    --------
    >>> from mrftcli.mrft.model import LoopModel
    >>> inner = InnerLoop(LoopModel(Tp=0.03, Td=0.3, tau=0.01, K=50.0), Controller(0.4, 0.0, 0.05, 0.005, 200.0))
    >>> m = CascadeModel(inner, Td=1.5, tau=0.05, K=STANDARD_GRAVITY)
    >>> m.family, [p.name for p in m.parameters.values()], m.parameters["K"].known
    ('cascade', ['Td', 'tau', 'K'], True)
    >>> m.discrete_realisation(200.0).order > 5
    True
    """

    family: ClassVar[str] = "cascade"
    structure: ClassVar[str] = "K T_inner(s) Td e^{-tau s} / (s (Td s + 1))"
    #: the family's strategy in :func:`mrftcli.mrft.identify.identify`: the exact sampled cycle of the cascade
    identification: ClassVar[str] = "cascade-cycles"

    inner: InnerLoop
    Td: float
    tau: float
    K: float = 1.0
    known: frozenset[str] = field(default=frozenset({"K"}), repr=False, compare=False)
    ranges: tuple[tuple[str, float, float], ...] = field(default=(), repr=False, compare=False)

    _spec: ClassVar[ParameterSpec] = CASCADE_PARAMETERS

    def __post_init__(self) -> None:
        self._check()
        if self.K < 0:
            raise InputError(f"K must be a positive gain, got {self.K!r}")

    def with_inner(self, inner: InnerLoop) -> CascadeModel:
        """The same outer loop through another inner loop (a draw of the inner model)."""
        return CascadeModel(inner, self.Td, self.tau, self.K, known=self.known, ranges=self.ranges)

    def realisation(self) -> StateSpace:
        """Not defined: the inner loop is sampled. Raises :class:`~mrftcli.errors.InputError`."""
        raise InputError("the cascade model has no continuous realisation (its inner loop is sampled): "
                         "give the controller rate (discrete_realisation, mrft_limit_cycle rate_hz=...)")

    def unit_normalisation(self, omega: float) -> None:
        """None: the cascade has no unit-frequency manifold."""
        return None

    def discrete_realisation(self, rate_hz: float | None = None) -> DiscreteStateSpace:
        """The exact discrete realisation from the outer relay's held command to the sampled output.

        Parameters
        ----------
        rate_hz : float, optional
            The outer relay's rate [Hz]: the inner controller's rate (default) or a whole divisor of
            it (the outer loop ticking every m inner ticks, its command held over them).

        Raises
        ------
        InputError
            A rate that does not divide the inner controller's rate.
        """
        c = self.inner.controller
        ss = self.inner.plant.realisation()
        base = _cascade_discrete(ss, self.inner.plant.delay, c, self.K, self.Td, self.tau)
        if rate_hz is None:
            return base
        check_positive("rate_hz", rate_hz)
        m = c.rate_hz / rate_hz
        if abs(m - round(m)) > 1e-6 * m or round(m) < 1:
            raise InputError(f"the outer loop's rate {rate_hz:g} Hz must be the inner controller's rate "
                             f"{c.rate_hz:g} Hz or a whole divisor of it (check --controller-rate and the inner gains' rate_hz)")
        return base if round(m) == 1 else base.lifted(int(round(m)))

    def frequency_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """G_outer(j omega): the translational part times T_inner(j omega), delay included; rad/s.

        T_inner is the response of the continuous inner output to a held reference through the
        sampled inner loop, fundamental only (the hold's factors of reference and command cancel):
        C_ref(z) G_i(j omega) / (1 + C_fb(z) G_id(z)), z = e^{j omega T}, with G_id the exact
        zero-order-hold equivalent of the inner plant and its delay. It is what ``tune``'s
        continuous margins would read; the limit cycle goes through :meth:`discrete_realisation`.
        """
        w = np.asarray(omega, dtype=float)
        s = 1j * w
        response: NDArray[np.complex128] = (self.K * self.Td * np.exp(-self.tau * s) * self.inner.closed_response(w)
                                            / (s * (self.Td * s + 1)))
        return response

    def to_json(self) -> dict[str, Any]:
        """The shared model JSON (:func:`~mrftcli.mrft.model.model_json`) plus ``"inner"`` (:meth:`InnerLoop.to_json`)."""
        return {**model_json(self.family, self.parameters.values()), "inner": self.inner.to_json()}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> CascadeModel:
        """The model of a :meth:`to_json` dict.

        Raises
        ------
        InputError
            Not of this version and family, a parameter missing, or no valid ``inner`` loop.
        """
        values, known, ranges = json_parameter_values(model_json_parameters(data, cls.family), CASCADE_PARAMETERS)
        if "inner" not in data:
            raise InputError("cascade model JSON needs its 'inner' loop")
        return cls(InnerLoop.from_json(data["inner"]), values["Td"], values["tau"], values["K"], known=known,
                   ranges=ranges)

    def sampled_limit_cycle(self, beta: float, h: float, rate_hz: float, n_guess: float | None = None) -> LimitCycle:
        """The exact MRFT cycle at the outer relay's ``rate_hz`` [Hz] (:func:`discrete_limit_cycle`).

        ``n_guess``: a half period [ticks] near the answer, to skip the first guess (a search's last).
        """
        return discrete_limit_cycle(self.discrete_realisation(rate_hz), beta, h, self.frequency_response, self.tau,
                                    n_guess)

    def orbit_at(self, half_period: float, h: float, rate_hz: float) -> SwitchedOrbit:
        """The symmetric orbit of a measured half period [ticks]: its amplitude and its level at the switch.

        The orbit of a whole half period N does not depend on beta (beta only decides which N the
        relay admits): the measured half period names the orbit the loop is on, whose amplitude and
        output at the switching sample are smooth functions of Td and tau. A half period between
        whole ticks (the loop alternating between neighbouring orbits, or the mean over cycles) is
        interpolated linearly between them.

        Parameters
        ----------
        half_period : float
            The measured half period [ticks of ``rate_hz``], >= 2.
        h : float
            Relay amplitude [command units], > 0.
        rate_hz : float
            The outer relay's rate [Hz].

        Returns
        -------
        SwitchedOrbit
        """
        h = check_positive("h", h)
        if not (math.isfinite(half_period) and half_period >= 2):
            raise InputError(f"half period must be at least 2 ticks, got {half_period!r}")
        n0 = int(math.floor(half_period))
        # beta is not used by the orbits' samples (only by their admissibility, not read here)
        orb = orbits(self.discrete_realisation(rate_hz), 0.0, h, n0, n0 + 1)
        amp = orb.amplitude
        level = np.array([orb.samples[i, orb.N[i]] / amp[i] for i in range(2)])
        frac = half_period - n0
        return SwitchedOrbit(float((1 - frac) * amp[0] + frac * amp[1]),
                             float((1 - frac) * level[0] + frac * level[1]))


@dataclass(frozen=True)
class SwitchedOrbit:
    """One symmetric orbit of the sampled relay (:meth:`CascadeModel.orbit_at`).

    Attributes
    ----------
    amplitude : float
        max |y| over the orbit's samples [output units].
    switch_level : float
        The output at the sample the relay switches on (+h -> -h), over the amplitude [-]: what the
        log's ``beta_down`` measures (about beta less the rise over the sampling lag).
    """

    amplitude: float
    switch_level: float


def delayed_discrete(ss: StateSpace, delay: float, rate_hz: float) -> DiscreteStateSpace:
    """A continuous plant ``ss`` with its input delay [s], from its command held over a tick at ``rate_hz``
    [Hz] to its sampled output: exact (zero-order hold, the delay's fraction of a tick split off; the
    inner plant of a cascade, the plant of a sampled relay, :func:`mrftcli.mrft.lprs.sampled_limit_cycle`)."""
    T = 1.0 / rate_hz
    d, eps = whole_and_fraction(delay, T)
    Phi, Ga, Gb = split_interval(ss.A, ss.B, T, eps)
    n = ss.order
    # state [x, u_{k-1} .. u_{k-d-1}]: the command buffer carries the delay
    N = n + d + 1
    Ad = np.zeros((N, N))
    Bd = np.zeros(N)
    Ad[:n, :n] = Phi
    Ad[:n, n + d] += Ga
    if d == 0:
        Bd[:n] = Gb
    else:
        Ad[:n, n + d - 1] += Gb
    Bd[n] = 1.0
    for j in range(1, d + 1):
        Ad[n + j, n + j - 1] = 1.0
    C = np.zeros(N)
    C[:n] = ss.C
    return DiscreteStateSpace(Ad, Bd, C, rate_hz)


def fraction_discrete(ss: StateSpace, delay: float, rate_hz: float) -> tuple[DiscreteStateSpace, int]:
    """:func:`delayed_discrete` with only the delay's fraction of a tick, and the whole ticks d left out: a periodic
    orbit of the delayed plant is the undelayed one's shifted by d ticks (:func:`orbits`'s ``shift``), so its
    state need not carry a d-long command buffer (604 states for 60 ms at 10 kHz)."""
    d, eps = whole_and_fraction(delay, 1.0 / rate_hz)
    return delayed_discrete(ss, eps, rate_hz), d


# ----------------------------------------------------------------------------------------------
# the exact sampled limit cycle of a discrete system
# ----------------------------------------------------------------------------------------------
def _first_guess_half_period(response: Any, beta: float, rate_hz: float) -> float:
    """Half period [ticks] where arg G = asin(beta) - pi (a start for the exact search, not the answer)."""
    from .describing import df_crossing  # here: describing imports the model module, which registers this one

    w = np.geomspace(1e-2, math.pi * rate_hz * 0.99, 600)
    w0 = df_crossing(w, response(w), beta)
    if w0 is None:
        raise InputError("the cascade has no MRFT phase crossing below the Nyquist frequency: check the inner "
                         "gains (an unstable or unclosed inner loop?)")
    return float(math.pi * rate_hz / w0)


@dataclass(frozen=True)
class _Orbits:
    """The symmetric orbits for half periods ``N`` [ticks]: switch margins and amplitudes."""

    N: NDArray[np.int64]
    at_end: FloatArray  # e_N + beta e_max: <= 0 once the switch level is reached at the last sample
    before_end: FloatArray  # the same at sample N - 1
    valid: NDArray[np.bool_]
    amplitude: FloatArray
    samples: FloatArray  # (len N, max N + 1): row i holds orbit i's y_0 .. y_N (then unused)


def _matrix_powers(Phi: FloatArray, count: int) -> FloatArray:
    """Phi^0 .. Phi^(count-1), stacked, by doubling (log2(count) batched products, not count small ones)."""
    out = np.empty((count, *Phi.shape))
    out[0] = np.eye(Phi.shape[0])
    step, have = Phi.copy(), 1
    while have < count:
        take = min(have, count - have)
        out[have:have + take] = np.einsum("nij,jk->nik", out[:take], step)
        have += take
        step = step @ step
    return out


def _powers(ss: DiscreteStateSpace, count: int) -> tuple[FloatArray, FloatArray]:
    """C Phi^k and sum_{j<k} Phi^j Gamma for k < count, by doubling.

    With M = Phi^m: C Phi^(k+m) = (C Phi^k) M and S_(k+m) = M S_k + S_m.
    """
    CP = np.empty((count, ss.order))
    S = np.empty((count, ss.order))
    CP[0], S[0] = ss.C, 0.0
    step, have = ss.Phi.copy(), 1  # step = Phi^have
    while have < count:
        take = min(have, count - have)
        s_m = ss.Phi @ S[have - 1] + ss.Gamma  # S_have
        CP[have:have + take] = np.einsum("ni,ij->nj", CP[:take], step)
        S[have:have + take] = np.einsum("ij,nj->ni", step, S[:take]) + s_m
        have += take
        step = step @ step
    return CP, S


def orbits(ss: DiscreteStateSpace, beta: float, h: float, n_lo: int, n_hi: int, eps: float = 0.0,
           shift: int = 0) -> _Orbits:
    """Orbits x_N = -x_0 of the relay +h over ticks 0..N-1 for N in [n_lo, n_hi], in closed form; each
    ``valid`` where the sampled MRFT rule (``checks.md`` section 2, level ``beta e_max + eps``, ``eps``
    a hysteresis [output units]) first switches at its sample N. ``shift``: whole ticks of input delay
    outside ``ss`` (:func:`fraction_discrete`): the relay sees y_k = y0_(k - shift), y0 the orbit of ``ss``
    (anti-periodic: y0_(k + N) = -y0_k)."""
    CP, S = _powers(ss, n_hi + 1)
    CS = S @ ss.C
    Ns = np.arange(n_lo, n_hi + 1)
    P = np.einsum("ij,njk->nik", np.linalg.matrix_power(ss.Phi, int(n_lo)), _matrix_powers(ss.Phi, Ns.size))
    with np.errstate(all="ignore"):
        x0 = -np.linalg.solve(np.eye(ss.order)[None] + P, (S[Ns] * h)[..., None])[..., 0]  # (len N, n)
    k = np.arange(n_hi + 1)
    # einsum, not @: a BLAS call per product thrashes its threads on a busy machine for these sizes
    Y = np.einsum("ij,kj->ik", x0, CP) + h * CS[None, :]  # (len N, k): the orbit's samples y_k, meaningful for k <= N
    if shift:
        m = (k[None, :] - shift) % (2 * Ns[:, None])  # where in the period of y0 each sample falls
        upper = m >= Ns[:, None]  # the half with the relay at -h: -y0 of the half at +h
        Y = np.where(upper, -1.0, 1.0) * np.take_along_axis(Y, np.where(upper, m - Ns[:, None], m), axis=1)
    inside = k[None, :] <= Ns[:, None]
    e = np.where(inside, -Y, -_INF)
    e_max = np.maximum.accumulate(e, axis=1)
    margin = e + beta * e_max + eps
    switched = inside & (e_max > 0) & (margin <= 0)
    switched[:, 0] = False
    first = np.where(switched.any(axis=1), np.argmax(switched, axis=1), -1)
    rows = np.arange(Ns.size)

    def margin_at(j: NDArray[np.int64]) -> FloatArray:
        out: FloatArray = np.where(e_max[rows, j] > 0, margin[rows, j], _INF)
        return out

    amplitude = np.max(np.where(inside, np.abs(Y), 0.0), axis=1)
    return _Orbits(Ns, margin_at(Ns), margin_at(np.maximum(Ns - 1, 1)), first == Ns, amplitude, Y)


def _root(N: NDArray[np.int64], f: FloatArray) -> float | None:
    """The real N where ``f`` (sampled at whole N) first crosses from > 0 to <= 0, linearly interpolated."""
    k = np.nonzero((f[:-1] > 0) & (f[1:] <= 0))[0]
    if not k.size:
        return None
    i = int(k[0])
    f0, f1 = f[i], f[i + 1]
    if not math.isfinite(f0):
        return float(N[i + 1])
    return float(N[i] + f0 / (f0 - f1))


def discrete_limit_cycle(ss: DiscreteStateSpace, beta: float, h: float, response: Any = None,
                         delay: float = float("nan"), n_guess: float | None = None) -> LimitCycle:
    """Exact MRFT limit cycle of a discrete system run at its rate (the relay decides at the ticks).

    For every half period N [ticks] the symmetric periodic orbit (relay +h over ticks 0..N-1,
    x_N = -x_0) is solved in closed form, x_0 = -(I + Phi^N)^-1 sum_{j<N} Phi^j Gamma h, and the
    sampled MRFT rule of ``checks.md`` section 2 is checked sample by sample: the orbit is
    admissible when the rule first switches at sample N (as
    :func:`mrftcli.mrft.lprs.sampled_limit_cycle` does for a continuous plant). The admissible
    orbits are a band of neighbouring N; its centre, reported as ``frequency_hz`` and
    ``amplitude``, is the midpoint between the real N at which the switch level is first reached at
    the orbit's last sample and the real N at which it is reached one sample earlier (both linearly
    interpolated between whole N): a smooth function of the parameters, which the identification
    needs, in the middle of the band of orbits the loop may lock onto.

    Parameters
    ----------
    ss : DiscreteStateSpace
        The loop's plant as seen by the relay (e.g. :meth:`CascadeModel.discrete_realisation`).
    beta : float
        MRFT parameter in (-1, 1).
    h : float
        Relay amplitude [command units], > 0.
    response : callable, optional
        omega [rad/s] -> G(j omega), for the first guess of the half period (default: the discrete
        system's own response).
    delay : float
        The loop's delay [s], for ``delay_phase`` only.
    n_guess : float, optional
        A half period [ticks] near the answer (e.g. the last one of a search); skips the first guess.

    Returns
    -------
    LimitCycle
        ``method="sampled-mean"``; ``orbits_hz``, ``orbits_amplitude`` the admissible orbits.

    Raises
    ------
    InputError
        Bad beta or h; no admissible orbit (the loop does not oscillate under this relay).
    """
    # imported here: lprs imports the model module, which registers this one (a cycle at import time)
    from .lprs import LimitCycle

    beta = check_beta(beta)
    h = check_positive("h", h)
    rate = ss.rate_hz
    if n_guess is not None and n_guess > 2:
        n0, width = float(n_guess), 0.03 * n_guess + 3
    else:
        n0 = _first_guess_half_period(response if response is not None else ss.frequency_response, beta, rate)
        width = 0.08 * n0 + 4
    for _ in range(6):
        lo, hi = max(2, int(n0 - width)), int(n0 + width) + 1
        orb = orbits(ss, beta, h, lo, hi)
        n_first, n_last = _root(orb.N, orb.at_end), _root(orb.N, orb.before_end)
        if n_first is not None and n_last is not None and orb.valid.any():
            break
        width *= 2.5
    else:
        raise InputError(f"no MRFT limit cycle of this loop at beta {beta:g} at {rate:g} Hz (no admissible orbit)")
    if n_first is None or n_last is None:  # for mypy: the loop above breaks only with both
        raise InputError("no MRFT limit cycle")
    n_c = 0.5 * (n_first + n_last)
    i = int(np.clip(math.floor(n_c) - orb.N[0], 0, orb.N.size - 2))
    frac = float(np.clip(n_c - orb.N[i], 0.0, 1.0))
    amplitude = float((1 - frac) * orb.amplitude[i] + frac * orb.amplitude[i + 1])
    j = int(np.argmin(np.abs(orb.N - round(n_c))))
    half = orb.samples[j, :orb.N[j]]
    Ns = orb.N[orb.valid][::-1]  # increasing frequency
    T = 1.0 / rate
    period = 2.0 * n_c * T
    omega = 2.0 * math.pi / period
    return LimitCycle(omega=omega, frequency_hz=1.0 / period, period=period, amplitude=amplitude, beta=beta, h=h,
                      rate_hz=rate, t=np.arange(2 * half.size, dtype=float) * T, y=np.concatenate([half, -half]),
                      delay_phase=delay * omega, method="sampled-mean",
                      orbits_hz=tuple(float(rate / (2 * N)) for N in Ns),
                      orbits_amplitude=tuple(float(a) for a in orb.amplitude[orb.valid][::-1]))
