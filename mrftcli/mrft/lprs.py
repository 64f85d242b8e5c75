"""Exact MRFT limit cycles of LTI loops with delay (LPRS), continuous and sampled relay.

The modified relay feedback test (MRFT, paper eq. 3) drives the loop with a symmetric square wave
of height ``h``.  Its periodic solution is computed *exactly* here, the way the locus of a perturbed
relay system (LPRS, Boiko) does it: the periodic response of the linear part to the square wave is
written in closed form (matrix exponentials, or partial fractions for the paper's model eq. 2) and
the switching condition of the MRFT is imposed on it.  No describing-function approximation and no
long time-domain simulation is involved (the sampled relay is the exception, see
:func:`sampled_limit_cycle`).

Frame and conditions (see ``docs/method.md``)
---------------------------------------------
The relay output is ``+h`` on ``[0, T/2)`` and ``-h`` on ``[T/2, T)``; ``t = 0`` is the ``-h -> +h``
switch.  ``y0(t)`` is the periodic response of the delay-free plant to that square wave; it is
antisymmetric, ``y0(t + T/2) = -y0(t)``, and the delayed output is ``y(t) = y0(t - tau)``.  With
``e = -y`` and the switching rule of ``checks.md`` section 2, the output at the ``+h -> -h`` switch is
``y(T/2) = beta * a_y`` on the ascending branch (equivalently ``y(0) = -beta * a_y`` on the
descending one), ``a_y = max |y0|``.  Writing ``u`` for the instant in ``(t_min, t_min + T/2)`` at
which the delay-free output crosses ``beta * a_y`` upwards, the condition is

    tau = T/2 - u(Omega)                                              (LPRS frequency condition)

which has exactly one root in ``Omega`` on the branch that starts at low frequency (Lemma 3 makes
this a one-dimensional problem in normalised time).  ``y0`` does not depend on beta: only the level
does.

Units: times in seconds, ``omega`` in rad/s, ``frequency_hz`` in Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize

from ..errors import IdentificationError, InputError
from ..jsonable import json_float, json_opt_float
from ..validate import check_beta, check_positive
from .describing import df_crossing, df_frequency
from .propagate import phi_gamma
from .cascade import fraction_discrete, orbits
from .model import LoopModel, PlantModel, SampledPlantModel, StateSpace

__all__ = [
    "LimitCycle",
    "mrft_limit_cycle",
    "lead_cycle",
    "lti_limit_cycle",
    "sampled_limit_cycle",
    "SquareWaveResponse",
    "unit_cycle",
    "unit_cycle_scalar",
    "unit_extremum",
    "unit_crossing",
]

_TWO_PI = 2.0 * math.pi
#: relative separation used when Tp and Td (nearly) coincide: the partial-fraction form is a divided
#: difference, evaluated at Tm (1 +- _SPLIT/2); the error is O(_SPLIT**2) = 1e-8 relative.
_SPLIT = 2e-4

FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------------------------
# the limit-cycle record
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class LimitCycle:
    """The MRFT periodic solution of one loop.

    Attributes
    ----------
    omega : float
        Oscillation frequency [rad/s].
    frequency_hz : float
        Oscillation frequency [Hz].
    period : float
        Period [s].
    amplitude : float
        Output amplitude a_y = max |y| [output units] (paper eq. 10).
    beta, h : float
        MRFT parameters (paper eq. 3).
    rate_hz : float or None
        Relay (controller) rate [Hz]; None for the continuous relay.
    t, y : ndarray
        One period of the output, ``t`` in [0, period) from the ``-h -> +h`` switch of the relay.
        For the sampled relay these are the samples of one representative cycle.
    delay_phase : float
        ``tau * omega`` [rad], the normalised delay (the UFM value of the loop).
    method : str
        ``"lprs"`` (exact closed form), ``"lprs-state-space"`` (exact, matrix exponentials),
        or ``"sampled-mean"`` (sampled relay: centre of the band of admissible orbits).
    orbits_hz, orbits_amplitude : tuple of float
        Sampled relay only: frequency [Hz] and amplitude of every admissible periodic orbit (a whole
        number of samples per half period), see :func:`sampled_limit_cycle`.
    """

    omega: float
    frequency_hz: float
    period: float
    amplitude: float
    beta: float
    h: float
    rate_hz: float | None
    t: FloatArray = field(repr=False)
    y: FloatArray = field(repr=False)
    delay_phase: float = float("nan")
    method: str = "lprs"
    orbits_hz: tuple[float, ...] = ()
    orbits_amplitude: tuple[float, ...] = ()

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary (no waveform)."""
        return {
            "frequency_hz": self.frequency_hz,
            "omega": self.omega,
            "period": self.period,
            "amplitude": self.amplitude,
            "beta": self.beta,
            "h": self.h,
            "rate_hz": self.rate_hz,
            "delay_phase": self.delay_phase,
            "method": self.method,
            "orbits_hz": list(self.orbits_hz),
            "orbits_amplitude": list(self.orbits_amplitude),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LimitCycle:
        """The cycle of a :meth:`to_dict` summary, without its waveform (``t``, ``y`` empty); KeyError or
        TypeError on a missing or non-numeric field."""
        empty = np.zeros(0)
        return cls(json_float(data["omega"]), json_float(data["frequency_hz"]), json_float(data["period"]),
                   json_float(data["amplitude"]), json_float(data["beta"]), json_float(data["h"]),
                   json_opt_float(data["rate_hz"]), empty, empty, json_float(data["delay_phase"]),
                   str(data["method"]), tuple(json_float(f) for f in data["orbits_hz"]),
                   tuple(json_float(a) for a in data["orbits_amplitude"]))


# ----------------------------------------------------------------------------------------------
# closed-form periodic response of G_n(s) = 1/(s (tp_n s + 1)(td_n s + 1)) at Omega = 1 rad/s, h = 1
# ----------------------------------------------------------------------------------------------
class SquareWaveResponse:
    """Periodic response y0 of the normalised plant ``1/(s (tp_n s+1)(td_n s+1))`` to the unit square wave.

    The square wave is +1 on ``[0, P)`` and -1 on ``[P, 2P)``, ``P = pi`` (period 2 pi, Omega = 1
    rad/s); ``tp_n = Tp Omega`` and ``td_n = Td Omega`` are the dimensionless time constants.

    Partial fractions (checks.md section 3):
    ``1/(s(T1 s+1)(T2 s+1)) = 1/s - T1^2/((T1-T2)(T1 s+1)) + T2^2/((T1-T2)(T2 s+1))``.
    The integrator answers with the zero-mean triangle ``t - P/2`` on ``[0, P]``, a first-order lag
    with ``f(t; T) = 1 - 2 e^{-t/T} / (1 + e^{-P/T})`` (its symmetric periodic solution), written
    with ``expm1`` so that large T keep their digits.  Arrays broadcast.
    """

    P = math.pi

    def __init__(self, tp_n: ArrayLike, td_n: ArrayLike) -> None:
        tp_n = np.asarray(tp_n, dtype=float)
        td_n = np.asarray(td_n, dtype=float)
        tp_n, td_n = np.broadcast_arrays(tp_n, td_n)
        mid = 0.5 * (tp_n + td_n)
        close = np.abs(tp_n - td_n) < _SPLIT * mid
        if np.any(close):  # double pole: divided difference at a symmetric split (see _SPLIT)
            tp_n = np.where(close, mid * (1 + 0.5 * _SPLIT), tp_n)
            td_n = np.where(close, mid * (1 - 0.5 * _SPLIT), td_n)
        self.tp_n, self.td_n = tp_n, td_n
        diff = tp_n - td_n
        self.cp = -(tp_n * tp_n) / diff
        self.cd = (td_n * td_n) / diff
        self.em1p = np.expm1(-self.P / tp_n)  # E - 1, E = exp(-P/T)
        self.em1d = np.expm1(-self.P / td_n)
        self.onep = 2.0 + self.em1p  # 1 + E
        self.oned = 2.0 + self.em1d

    def _half(self, s: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """y0, y0' and y0'' for s in [0, P] (the +h half period)."""
        s = np.asarray(s, dtype=float)
        P = self.P
        ep = np.exp(-s / self.tp_n)
        ed = np.exp(-s / self.td_n)
        fp = (-2.0 * np.expm1(-s / self.tp_n) + self.em1p) / self.onep
        fd = (-2.0 * np.expm1(-s / self.td_n) + self.em1d) / self.oned
        y = (s - 0.5 * P) + self.cp * fp + self.cd * fd
        dfp = 2.0 * ep / (self.tp_n * self.onep)
        dfd = 2.0 * ed / (self.td_n * self.oned)
        dy = 1.0 + self.cp * dfp + self.cd * dfd
        ddy = -self.cp * dfp / self.tp_n - self.cd * dfd / self.td_n
        return y, dy, ddy

    def slope(self, s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """y0' and y0'' for s in [0, P]: the pair whose root is the extremum of y0."""
        _, dy, ddy = self._half(s)
        return dy, ddy

    def eval(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """y0, y0', y0'' at any t (antisymmetry y0(t + P) = -y0(t))."""
        t = np.asarray(t, dtype=float)
        k = np.floor(t / self.P)
        s = t - k * self.P
        sign = np.where(np.mod(k, 2.0) == 0.0, 1.0, -1.0)
        y, dy, ddy = self._half(s)
        return sign * y, sign * dy, sign * ddy


def _bracketed_newton(fun: Callable[[FloatArray], tuple[FloatArray, FloatArray]], lo: ArrayLike, hi: ArrayLike,
                      x: ArrayLike, xtol: float, maxiter: int = 100) -> FloatArray:
    """Vectorised safeguarded Newton for an increasing function with fun(lo) <= 0 <= fun(hi)."""
    lo = np.array(lo, dtype=float, copy=True)
    hi = np.array(hi, dtype=float, copy=True)
    x = np.array(x, dtype=float, copy=True)
    for _ in range(maxiter):
        f, df = fun(x)
        lo = np.where(f < 0, x, lo)
        hi = np.where(f > 0, x, hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = x - f / df
        bad = ~((xn >= lo) & (xn <= hi))
        xn = np.where(bad, 0.5 * (lo + hi), xn)
        xn = np.where(f == 0, x, xn)
        step = np.abs(xn - x)
        x = xn
        if np.all((step <= xtol) | ~np.isfinite(step)):
            break
    return x


def unit_cycle(tp_n: ArrayLike, td_n: ArrayLike, beta: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Normalised MRFT solution of G_n(s) = e^{-theta s} / (s (tp_n s+1)(td_n s+1)) at Omega = 1 rad/s.

    Lemmas 1-4 of the paper reduce every plant of eq. (2) to this one: a plant (Tp, Td, tau, K)
    oscillating at Omega has ``tp_n = Tp Omega``, ``td_n = Td Omega``, ``theta = tau Omega`` and amplitude
    ``a = h K Td a_unit / Omega``.

    Parameters
    ----------
    tp_n, td_n : array_like
        Normalised time constants Tp * Omega and Td * Omega (dimensionless), > 0; broadcast together
        with beta.
    beta : array_like
        MRFT parameter(s) in (-1, 1).

    Returns
    -------
    theta : ndarray
        The normalised delay tau*Omega [rad] that makes the loop oscillate at exactly Omega = 1 rad/s
        (the UFM value).  Negative where even tau = 0 lags too much (no physical plant).
    a_unit : ndarray
        Amplitude of y for h = 1, K Td = 1 at Omega = 1 (the UGM value); independent of beta.

    Examples
    --------
    The paper's example (Tp = 0.1 s, Td = 0.7042 s, tau = 0.06 s) oscillates at 4.4337 rad/s under
    beta = -0.4, so its normalised delay there is tau * Omega:

    >>> theta, a_unit = unit_cycle(0.1 * 4.433739, 0.7042 * 4.433739, -0.4)
    >>> round(float(theta), 4), round(0.06 * 4.433739, 4)
    (0.266, 0.266)
    """
    sys_, s0, a = unit_extremum(tp_n, td_n)
    return unit_crossing(sys_, s0, a, beta), a


def unit_extremum(tp_n: ArrayLike, td_n: ArrayLike) -> tuple[SquareWaveResponse, FloatArray, FloatArray]:
    """The beta-independent half of :func:`unit_cycle`: y0, the instant of its minimum and a_unit.

    Returns the :class:`SquareWaveResponse` of ``(tp_n, td_n)`` (broadcast), the instant ``s0`` in
    [0, pi] of the minimum of y0 and the amplitude ``a_unit = -y0(s0)``; :func:`unit_crossing` adds
    beta. Building the manifolds of many betas calls this once and the crossing once per beta.
    """
    sys_ = SquareWaveResponse(tp_n, td_n)
    P = sys_.P
    zeros = np.zeros(sys_.tp_n.shape)
    # y0' = r crosses 0 upwards exactly once in the +h half period (r(P) = -r(0) and a sum of three
    # exponentials has at most two zeros), so the bracket [0, P] is always valid.
    s0 = _bracketed_newton(lambda s: sys_.slope(s), zeros, zeros + P, zeros + 0.25 * P, 1e-13 * P)
    a = -sys_._half(s0)[0]
    return sys_, s0, a


def unit_crossing(sys_: SquareWaveResponse, s0: FloatArray, a: FloatArray, beta: ArrayLike) -> FloatArray:
    """The UFM value theta [rad] for beta from the output of :func:`unit_extremum`.

    theta = P - u, u the ascending crossing of the level beta * a in (s0, s0 + P) (the LPRS
    frequency condition of the module docstring at Omega = 1 rad/s).
    """
    beta = np.asarray(beta, dtype=float)
    P = sys_.P
    shape = np.broadcast_shapes(sys_.tp_n.shape, beta.shape)
    if sys_.tp_n.shape != shape:
        sys_ = SquareWaveResponse(np.broadcast_to(sys_.tp_n, shape), np.broadcast_to(sys_.td_n, shape))
    s0b = np.broadcast_to(s0, shape)
    ab = np.broadcast_to(a, shape)
    betab = np.broadcast_to(beta, shape)

    def fun(u: FloatArray) -> tuple[FloatArray, FloatArray]:
        y, dy, _ = sys_.eval(u)
        return y - betab * ab, dy

    u = _bracketed_newton(fun, s0b, s0b + P, s0b + 0.5 * P * (1.0 + betab), 1e-10 * P)
    theta: FloatArray = P - u
    return theta


def unit_cycle_scalar(tp_n: float, td_n: float, beta: float, warm: list[float] | None = None) -> tuple[float, float]:
    """Scalar :func:`unit_cycle` in plain Python, for root finders that call it one point at a time.

    Same closed form and the same safeguarded Newton iterations as :func:`unit_cycle` (equal to
    ~1e-12); numpy's per-call overhead on 0-d arrays makes the vectorised form several times slower
    per point (``benchmarks/bench_engine.py``, docs/benchmarks/engine.md). ``warm`` (a list
    ``[s0, u]`` or ``[]``) carries the previous solution as starting values for the next call and is
    updated in place (root finders call this with slowly changing arguments).

    Examples
    --------
    >>> theta, a = unit_cycle_scalar(0.5, 3.0, -0.4)
    >>> t_vec, a_vec = unit_cycle(0.5, 3.0, -0.4)
    >>> abs(theta - float(t_vec)) < 1e-12 and abs(a - float(a_vec)) < 1e-12
    True
    """
    P = math.pi
    mid = 0.5 * (tp_n + td_n)
    if abs(tp_n - td_n) < _SPLIT * mid:
        tp_n, td_n = mid * (1 + 0.5 * _SPLIT), mid * (1 - 0.5 * _SPLIT)
    diff = tp_n - td_n
    cp, cd = -(tp_n * tp_n) / diff, (td_n * td_n) / diff
    em1p, em1d = math.expm1(-P / tp_n), math.expm1(-P / td_n)
    onep, oned = 2.0 + em1p, 2.0 + em1d
    kp, kd = 2.0 / (tp_n * onep), 2.0 / (td_n * oned)

    def half(s: float) -> tuple[float, float, float]:
        ep, ed = math.exp(-s / tp_n), math.exp(-s / td_n)
        y = (s - 0.5 * P) + cp * (-2.0 * math.expm1(-s / tp_n) + em1p) / onep + cd * (-2.0 * math.expm1(-s / td_n) + em1d) / oned
        return y, 1.0 + cp * kp * ep + cd * kd * ed, -cp * kp * ep / tp_n - cd * kd * ed / td_n

    def newton(fun: Callable[[float], tuple[float, float]], lo: float, hi: float, x: float) -> float:
        for _ in range(100):
            f, df = fun(x)
            if f < 0:
                lo = x
            elif f > 0:
                hi = x
            else:
                return x
            xn = x - f / df if df != 0 else 0.5 * (lo + hi)
            if not lo < xn < hi:
                xn = 0.5 * (lo + hi)
            if abs(xn - x) <= 1e-13 * P:
                return xn
            x = xn
        return x

    s_start, u_start = (warm[0], warm[1] - warm[0]) if warm else (0.25 * P, None)
    s0 = newton(lambda s: half(s)[1:], 0.0, P, s_start)
    a = -half(s0)[0]
    level = beta * a

    def cross(u: float) -> tuple[float, float]:
        if u <= P:
            y, dy, _ = half(u)
        else:
            y, dy, _ = half(u - P)
            y, dy = -y, -dy
        return y - level, dy

    du = u_start if u_start is not None and 0 < u_start < P else 0.5 * P * (1.0 + beta)
    u = newton(cross, s0, s0 + P, s0 + du)
    if warm is not None:
        warm[:] = [s0, u]
    return P - u, a


# ----------------------------------------------------------------------------------------------
# the paper's model: exact continuous limit cycle
# ----------------------------------------------------------------------------------------------
def _exact_omega(model: LoopModel, beta: float) -> tuple[float, float]:
    """Exact MRFT frequency [rad/s] of eq. (2) and the normalised unit amplitude at that frequency."""
    Tp, Td, tau = model.Tp, model.Td, model.tau
    if tau < 0.0:  # a lead: the bracket below holds for tau >= 0 only
        return lead_cycle(Tp, Td, tau, beta, strict=True)

    warm: list[float] = []

    def g(logw: float) -> float:
        w = math.exp(logw)
        theta, _ = unit_cycle_scalar(Tp * w, Td * w, beta, warm)
        return theta - tau * w

    w0 = df_frequency(model, beta)  # the describing function's root starts the bracket
    if not np.isfinite(w0):
        w0 = 1.0 / max(Tp, Td, tau)
    lo, hi = math.log(w0) - 0.3, math.log(w0) + 0.3
    for _ in range(200):
        if g(lo) > 0:
            break
        lo -= 1.0
    for _ in range(200):
        if g(hi) < 0:
            break
        hi += 1.0
    logw = optimize.brentq(g, lo, hi, xtol=1e-15, rtol=4 * np.finfo(float).eps)
    w = math.exp(logw)
    _, a = unit_cycle_scalar(Tp * w, Td * w, beta)
    return w, float(a)


def lead_cycle(Tp: float, Td: float, tau: float, beta: float, strict: bool = False) -> tuple[float, float]:
    """Eq. (2)'s MRFT frequency [rad/s] and unit amplitude (:func:`unit_cycle`) with a negative ``tau`` [s]: a
    loop that leads eq. (2) without delay, as an estimator's lead makes it (``compare.delay``'s pair fit).
    :func:`_exact_omega`'s bracket about the describing function's frequency (one sign change for ``tau >= 0``)
    does not hold for a lead: the delay a cycle needs falls, then rises, with w (below).

    Along the frequency, the delay a cycle needs is ``theta(Tp w, Td w) / w`` (the UFM over w): 0 at the
    no-delay cycle's w0, falling with w to a least value (about -0.16 Tp at beta -0.7, -0.05 Tp at -0.9) and
    rising after it. A lead within reach has its one root on the falling branch; a larger one, which no cycle
    of this beta holds, is given the branch's end (the residual stays continuous and the fit moves back), or,
    ``strict``, an :class:`~mrftcli.errors.IdentificationError` naming it (a model's cycle: no such cycle exists).
    """
    def needed(logw: float) -> float:
        w = math.exp(logw)
        return unit_cycle_scalar(Tp * w, Td * w, beta)[0] / w

    lo, prev, step = math.log(_exact_omega(LoopModel(Tp, Td, 0.0, 1.0), beta)[0]), 0.0, 0.02  # the no-delay cycle
    for _ in range(2000):
        hi = lo + step
        now = needed(hi)
        if now <= tau:
            logw = optimize.brentq(lambda x: needed(x) - tau, lo, hi, xtol=1e-13)
            break
        if now >= prev:  # past the least delay: the lead is out of this beta's reach
            if strict:
                raise IdentificationError(f"no MRFT cycle of eq. (2) with a lead of {-tau * 1e3:.3g} ms (tau < 0) at "
                                          f"beta {beta:g}: the least delay a cycle of this beta holds is "
                                          f"{prev * 1e3:.3g} ms at Tp = {Tp:g} s; a beta nearer 0 holds more lead: "
                                          "use one nearer 0, or check --tau and --tp")
            logw = float(optimize.minimize_scalar(needed, bounds=(lo - step, hi), method="bounded",
                                                  options={"xatol": 1e-10}).x)
            break
        lo, prev = hi, now
    else:  # pragma: no cover - the least delay is reached within a few decades of w0
        raise IdentificationError(f"no MRFT cycle of eq. (2) with a lead of {-tau * 1e3:.3g} ms at beta {beta:g}")
    omega = math.exp(logw)
    return omega, unit_cycle_scalar(Tp * omega, Td * omega, beta)[1]


def mrft_limit_cycle(model: PlantModel, beta: float, h: float = 1.0, rate_hz: float | None = None,
                     n_points: int = 512, eps: float = 0.0) -> LimitCycle:
    """Exact MRFT limit cycle of a plant model; eq. (2) in closed form.

    A :class:`~mrftcli.mrft.model.LoopModel` (G(s) = K Td e^{-tau s}/(s (Tp s+1)(Td s+1)), paper
    eq. 2) is solved with the closed form of :func:`unit_cycle`; any other
    :class:`~mrftcli.mrft.model.PlantModel` through its state space (:func:`lti_limit_cycle`).

    Parameters
    ----------
    model : PlantModel
        The plant.
    beta : float
        MRFT parameter in (-1, 1) (paper eq. 3).
    h : float
        Relay amplitude [command units], > 0.
    rate_hz : float, optional
        Controller rate [Hz].  None: continuous relay (exact closed form).  Otherwise the relay
        decides at sample instants on sampled y and holds its output (see :func:`sampled_limit_cycle`).
    n_points : int
        Number of waveform samples over one period (continuous relay).
    eps : float
        Relay hysteresis [output units] (see :func:`lti_limit_cycle`); 0 for the MRFT.

    Returns
    -------
    LimitCycle

    Raises
    ------
    InputError
        beta outside (-1, 1), non-positive h or rate, invalid model parameters.

    Examples
    --------
    The paper's example (checks.md section 1), continuous relay and a 200 Hz controller:

    >>> plant = LoopModel(Tp=0.1, Td=1 / 1.42, tau=0.06, K=1.42)
    >>> lc = mrft_limit_cycle(plant, beta=-0.4)
    >>> print(f"{lc.frequency_hz:.5f} Hz, amplitude {lc.amplitude:.6f}")
    0.70564 Hz, amplitude 0.078530
    >>> sampled = mrft_limit_cycle(plant, beta=-0.4, rate_hz=200.0)
    >>> [round(f, 4) for f in sampled.orbits_hz]
    [0.6897, 0.6944, 0.6993, 0.7042]
    """
    beta = check_beta(beta)
    h = check_positive("h", h)
    rate_hz = None if rate_hz is None else check_positive("rate_hz", rate_hz)
    if not isinstance(model, PlantModel):
        raise InputError("model must be a plant model (e.g. a LoopModel)")
    if model.parameters["K"].value < 0:
        raise InputError("K must be positive for a negative-feedback MRFT loop (invert the command sign)")
    if isinstance(model, SampledPlantModel):  # a controller inside the plant: exact only at the relay's rate
        if rate_hz is None or eps != 0.0:
            raise InputError(f"the {model.family} model's cycle needs the relay's rate (rate_hz) and the MRFT (eps 0)")
        return model.sampled_limit_cycle(beta, h, rate_hz)
    if rate_hz is not None:
        # the centre of the sampled relay's band (a lead too: a periodic orbit is a shift of the command, whose
        # sign the anti-periodic orbit's algebra does not need; as the rate rises it tends to the lead's cycle): the continuous cycle with half a sample more delay
        centre = mrft_limit_cycle(model.with_parameters(tau=model.delay + 0.5 / rate_hz), beta, h, None, n_points,
                                  eps=eps)
        ss = model.realisation()
        return sampled_limit_cycle(ss.A, ss.B, ss.C, model.delay, beta, h, rate_hz, _centre=centre, eps=eps)
    if not isinstance(model, LoopModel) or eps != 0.0:
        ss = model.realisation()
        return lti_limit_cycle(ss.A, ss.B, ss.C, model.delay, beta, h, None, n_points, eps=eps)
    return _closed_form_cycle(model, beta, h, n_points)


def _closed_form_cycle(model: LoopModel, beta: float, h: float, n_points: int) -> LimitCycle:
    """The continuous relay's cycle of eq. (2) from the unit cycle (Lemmas 1-4)."""
    w, a_unit = _exact_omega(model, beta)
    unit = model.unit_normalisation(w)
    scale = h * model.K * model.Td / w  # Lemmas 2 and 4: y = h K Td y_n(Omega t) / Omega
    theta = unit.theta
    tn = np.linspace(0.0, _TWO_PI, n_points, endpoint=False)
    # delayed output y(t) = y0(t - tau) in normalised time, t = 0 at the -h -> +h switch
    y = SquareWaveResponse(np.array(unit.coordinates["tp_n"]), np.array(unit.coordinates["td_n"])).eval(tn - theta)[0]
    T = _TWO_PI / w
    return LimitCycle(
        omega=w,
        frequency_hz=w / _TWO_PI,
        period=T,
        amplitude=scale * a_unit,
        beta=beta,
        h=h,
        rate_hz=None,
        t=tn / w,
        y=scale * y,
        delay_phase=theta,
        method="lprs",
    )


# ----------------------------------------------------------------------------------------------
# general state space (integrators allowed)
# ----------------------------------------------------------------------------------------------
class _StateSpaceCycle:
    """Periodic solution of x' = A x + B u for the square wave of half period P (h = 1).

    The state is exact at ``n`` samples per half period (matrix exponentials); between samples the
    output is the cubic Hermite interpolant of the exact y and y' = C (A x + B u), whose error is
    O((P/n)^4) -- below 1e-12 relative with the default n -- so extrema and crossings are located
    in continuous time without further matrix exponentials.
    """

    def __init__(self, A: FloatArray, B: FloatArray, C: FloatArray, P: float, n: int = 512) -> None:
        from scipy.interpolate import CubicHermiteSpline

        self.A, self.B, self.C, self.P = A, B, C, P
        Phi, Gam = phi_gamma(A, B, P)
        # symmetric periodic state at the -h -> +h switch: x(P) = -x(0)  =>  (I + Phi) x0 = -Gamma
        self.x0 = -np.linalg.solve(np.eye(A.shape[0]) + Phi, Gam)
        Pd, Gd = phi_gamma(A, B, P / n)
        xs = np.empty((n + 1, A.shape[0]))
        xs[0] = self.x0
        for k in range(n):
            xs[k + 1] = Pd @ xs[k] + Gd
        self.ts = np.linspace(0.0, P, n + 1)
        ys = xs @ C
        dys = (xs @ A.T + B) @ C  # u = +1 on the first half period
        # two periods (0 .. 4P) so that any half-period window starting in [0, 2P) is covered
        t4 = np.concatenate([self.ts[:-1] + k * P for k in range(4)] + [[4 * P]])
        sgn = [1.0, -1.0, 1.0, -1.0]
        y4 = np.concatenate([s * ys[:-1] for s in sgn] + [[ys[0]]])
        # y' is continuous when C B = 0; at the switches use the one-sided value of the new half
        dy4 = np.concatenate([s * dys[:-1] for s in sgn] + [[dys[0]]])
        self.ys, self.y4 = ys, y4
        self.spline = CubicHermiteSpline(t4, y4, dy4)

    def y(self, t: ArrayLike) -> FloatArray:
        """The delay-free output y0 at times ``t`` (periodic, h = 1)."""
        y: FloatArray = self.spline(np.mod(t, 2 * self.P))
        return y

    def condition(self, beta: float, offset: float = 0.0) -> tuple[float, float, float]:
        """(u, a_y, t_min): ascending crossing instant of beta*a_y + offset, amplitude and minimum instant.

        ``offset`` is a relay's hysteresis in this cycle's units (h = 1): the level a hysteresis relay
        switches at does not scale with the amplitude.
        """
        P = self.P
        sp = self.spline
        t4, y4 = sp.x, self.y4
        n2 = (t4.size - 1) // 2  # samples over one period
        i = int(np.argmin(y4[:n2]))
        lo, hi = t4[max(i - 1, 0)], t4[i + 1]
        dsp = sp.derivative()
        if i > 0 and dsp(lo) < 0 < dsp(hi):
            t_min = optimize.brentq(dsp, lo, hi, xtol=1e-15 * P)
        else:
            t_min = float(t4[i])
        a = -float(sp(t_min))
        level = beta * a + offset
        j0 = int(np.searchsorted(t4, t_min))
        seg = y4[j0 : j0 + n2 // 2 + 2] - level
        k = int(np.argmax(seg >= 0))
        if seg[k] < 0:
            raise InputError("no MRFT switching point on the periodic solution (check the plant)")
        t_lo = max(t4[j0 + k - 1], t_min) if k > 0 else t_min
        u = optimize.brentq(lambda t: float(sp(t)) - level, t_lo, t4[j0 + k], xtol=1e-15 * P)
        return u, a, t_min


def _as_state_space(A: ArrayLike, B: ArrayLike, C: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(A, B, C) as float arrays of matching shapes ((n, n), (n,), (n,)), finite."""
    A_ = np.atleast_2d(np.asarray(A, dtype=float))
    B_ = np.asarray(B, dtype=float).reshape(-1)
    C_ = np.asarray(C, dtype=float).reshape(-1)
    n = A_.shape[0]
    if A_.shape != (n, n) or B_.size != n or C_.size != n:
        raise InputError(f"state space shapes do not match: A {A_.shape}, B {B_.shape}, C {C_.shape}")
    if not (np.all(np.isfinite(A_)) and np.all(np.isfinite(B_)) and np.all(np.isfinite(C_))):
        raise InputError("state-space matrices must be finite")
    return A_, B_, C_


def lti_limit_cycle(A: ArrayLike, B: ArrayLike, C: ArrayLike, tau: float, beta: float, h: float = 1.0,
                    rate_hz: float | None = None, n_points: int = 512, eps: float = 0.0) -> LimitCycle:
    """Exact MRFT limit cycle of x' = A x + B u(t - tau), y = C x (integrators allowed).

    The symmetric periodic state at the ``-h -> +h`` switch solves ``(I + Phi) x0 = -Gamma h`` with
    ``Phi = e^{A T/2}`` and ``Gamma = int_0^{T/2} e^{As} ds B`` (an eigenvalue 1 of Phi from an
    integrator becomes 2 in ``I + Phi``, so the system stays solvable).  The frequency is the root of
    ``T/2 - u(Omega) - tau`` (module docstring) found by bracketing and Brent's method.

    Parameters
    ----------
    A, B, C : array_like
        Single-input single-output state space of the delay-free plant.
    tau : float
        Transport delay [s], >= 0.
    beta, h, rate_hz, n_points
        As in :func:`mrft_limit_cycle`.
    eps : float
        Hysteresis [output units]: the relay switches at ``beta a_y + eps`` (0 for the MRFT; beta = 0
        and eps > 0 for a relay with hysteresis, both 0 for the ideal relay).

    Raises
    ------
    InputError
        Bad beta, h, tau or shapes.
    """
    beta = check_beta(beta)
    h = check_positive("h", h)
    rate_hz = None if rate_hz is None else check_positive("rate_hz", rate_hz)
    A, B, C = _as_state_space(A, B, C)
    tau = float(tau)
    if not math.isfinite(tau) or tau < 0:
        raise InputError(f"tau must be a non-negative time in seconds, got {tau}")
    if rate_hz is not None:
        return sampled_limit_cycle(A, B, C, tau, beta, h, rate_hz, eps=eps)
    offset = float(eps) / h

    def g(logw: float) -> float:
        P = math.pi / math.exp(logw)
        try:
            u, _, _ = _StateSpaceCycle(A, B, C, P).condition(beta, offset)
        except InputError:
            # the level is beyond the cycle: no switch at this frequency. The crossing tends to the
            # peak as the level nears it, where the condition is negative (-t_min - tau): negative
            # here too, so a cycle just below this frequency is bracketed (a hysteresis near the
            # amplitude put it within one grid step of this region and NaN hid it)
            return -(P + tau)
        return (P - u) - tau

    ev = np.abs(np.linalg.eigvals(A))
    ev = ev[ev > 1e-12]
    scales = list(ev) + ([1.0 / tau] if tau > 0 else [])
    w_ref = float(np.exp(np.mean(np.log(scales)))) if scales else 1.0
    # first a narrow bracket around the describing function's frequency (a few matrix exponentials),
    # then, if it holds no root, the wide grid
    hint = _df_hint(A, B, C, tau, beta, w_ref)
    for grid in ([] if hint is None else [np.log(hint) + np.linspace(-1.0, 1.0, 9)],
                 [np.log(w_ref) + np.linspace(-6, 6, 37)]):
        if not grid:
            continue
        vals = np.array([g(x) for x in grid[0]])
        idx = np.nonzero((vals[:-1] > 0) & (vals[1:] <= 0))[0]
        if idx.size:
            grid = grid[0]
            break
    else:
        raise InputError("no MRFT limit cycle found for this loop (check the plant and beta)")
    # the highest-frequency sign change: at very low frequency the dense sampling of a fast,
    # non-integrating plant cannot resolve its step-like response and may fake a crossing
    i = idx[-1]
    logw = optimize.brentq(g, grid[i], grid[i + 1], xtol=1e-14, rtol=4 * np.finfo(float).eps)
    w = math.exp(logw)
    P = math.pi / w
    cyc = _StateSpaceCycle(A, B, C, P)
    _, a, _ = cyc.condition(beta, offset)
    t = np.linspace(0.0, 2 * P, n_points, endpoint=False)
    y = cyc.y(t - tau) * h
    return LimitCycle(omega=w, frequency_hz=w / _TWO_PI, period=2 * P, amplitude=abs(h) * a, beta=beta,
                      h=h, rate_hz=None, t=t, y=y, delay_phase=tau * w, method="lprs-state-space")


def _df_hint(A: FloatArray, B: FloatArray, C: FloatArray, tau: float, beta: float, w_ref: float) -> float | None:
    """Where arg G(j omega) = -pi + arcsin(beta) (the describing function's frequency), or None."""
    w = w_ref * np.logspace(-4, 4, 161)
    n = A.shape[0]
    G = np.array([C @ np.linalg.solve(1j * wk * np.eye(n) - A, B) for wk in w]) * np.exp(-1j * w * tau)
    return df_crossing(w, G, beta)


# ----------------------------------------------------------------------------------------------
# sampled relay
# ----------------------------------------------------------------------------------------------
def _band(valid: NDArray[np.bool_], i0: int, i1: int) -> NDArray[np.bool_]:
    """The admissible orbits of the first window ``valid[i0:i1 + 1]`` and, beyond it, those that continue
    its admissible edge without a gap (what a search widening one orbit at a time finds)."""
    band = np.zeros_like(valid)
    band[i0:i1 + 1] = valid[i0:i1 + 1]
    j = i0 - 1
    while j >= 0 and valid[j] and band[j + 1]:
        band[j] = True
        j -= 1
    j = i1 + 1
    while j < valid.size and valid[j] and band[j - 1]:
        band[j] = True
        j += 1
    return band


def sampled_limit_cycle(A: ArrayLike, B: ArrayLike, C: ArrayLike, tau: float, beta: float, h: float,
                        rate_hz: float, _centre: LimitCycle | None = None, eps: float = 0.0) -> LimitCycle:
    """Limit cycle of the MRFT run at ``rate_hz``: the switch is decided on sampled y, then held (ZOH).

    Switching can only happen at samples, so the sampled loop locks onto periodic orbits whose half
    period is a whole number N of samples (frequency ``rate_hz / (2 N)``).  With the MRFT's adaptive
    level (beta times the tracked extremum) *several consecutive N are admissible at once* (2-6 for
    100-500 Hz relays on multirotor loops): which one the loop settles in depends on its history,
    and it may also run patterns mixing neighbouring orbits.  This function therefore returns

    * ``orbits_hz`` / ``orbits_amplitude``: every admissible orbit, found exactly -- for each
      candidate N the symmetric periodic orbit of the exactly discretised loop (zero-order hold, the
      fractional part of the delay handled by splitting the sample interval, its whole ticks by shifting the
      orbit: :func:`~mrftcli.mrft.cascade.fraction_discrete`) is solved in closed form and the MRFT rule of
      checks.md section 2 is checked sample by sample (:func:`~mrftcli.mrft.cascade.orbits`, as for a
      cascade);
    * ``frequency_hz`` / ``amplitude``: the centre of that band, the exact continuous cycle with the
      mean switching lag of half a sample added to the delay (the switch comes uniformly 0..Ts after
      the continuous crossing when the phase of the sample grid is random).  ``docs/method.md``
      compares it with the orbits and with simulations.

    Note that the orbits are not equally likely and noise does not average them to the centre, so no
    single sampled-relay frequency can be predicted to better than the band width.
    """
    beta = check_beta(beta)
    h = check_positive("h", h)
    rate_hz = check_positive("rate_hz", rate_hz)
    A, B, C = _as_state_space(A, B, C)
    Ts = 1.0 / rate_hz
    cont = _centre if _centre is not None else lti_limit_cycle(A, B, C, tau + 0.5 * Ts, beta, h, None, eps=eps)
    P = cont.period / 2
    if P / Ts < 4:
        raise InputError(f"rate {rate_hz} Hz is too slow for a limit cycle near {cont.frequency_hz:.3g} Hz "
                         "(fewer than 8 samples per period)")
    ss, shift = fraction_discrete(StateSpace(A, B, C), tau, rate_hz)  # the delay's whole ticks as a shift
    n_mid = P / Ts
    first, last = max(2, int(math.floor(n_mid)) - 6), int(math.ceil(n_mid)) + 6
    lo_n, hi_n = first, last
    while True:  # widen the window while the band runs on past its edges (wide bands at high rates)
        orb = orbits(ss, beta, h, lo_n, hi_n, eps, shift)
        band = _band(orb.valid, first - lo_n, last - lo_n)
        if band[0] and lo_n > 2:
            lo_n = max(2, lo_n - 8)
        elif band[-1]:
            hi_n += 8
        else:
            break
    freqs = [rate_hz / (2 * int(N)) for N in orb.N[band][::-1]]  # increasing frequency
    amps = [float(a) for a in orb.amplitude[band][::-1]]
    return LimitCycle(omega=cont.omega, frequency_hz=cont.frequency_hz, period=cont.period,
                      amplitude=cont.amplitude, beta=beta, h=h, rate_hz=rate_hz, t=cont.t, y=cont.y,
                      delay_phase=tau * cont.omega, method="sampled-mean", orbits_hz=tuple(freqs),
                      orbits_amplitude=tuple(amps))
