"""Output-error refinement of Td, tau and K on the recorded waveform, guarded by the MRFT estimate.

The MRFT route (:mod:`~mrftcli.mrft.identify`, :mod:`~mrftcli.mrft.consensus`) uses what the limit
cycle says: period, amplitude, phase of the fundamental, effective beta. The waveform says more. Here
the recorded command drives the exactly discretised model (:func:`~mrftcli.mrft.waveform.response_basis`:
zero-order hold at the controller rate, the fractional delay exact) over each test's window, and the
parameters are fitted by output error, starting from the MRFT estimate.

Method
------
For parameters p (for eq. (2): ln Td, tau, K) the prediction over window w is

    y_w(p) = c0_w(p) + offset_w c1_w(p) + Z_w(p) z_w,

with c0 the forced response, c1 the response to a unit command offset (the trim the relay centre
misses) and Z the free responses of the initial state z_w. The nuisance parameters (offset_w, z_w:
four per test) enter linearly, so they are eliminated by linear least squares inside the residual
(variable projection): r_w(p) = (I - P_w) (y_w - c0_w), P_w the projector on [c1_w, Z_w]. The
Gauss-Newton fit of p (:func:`scipy.optimize.least_squares`, forward-difference Jacobian, 3-8
iterations from the MRFT start) minimises sum_w |r_w|^2. The covariance is the Gauss-Newton one
scaled by the residual variance, s^2 (J^T J)^{-1}, s^2 = |r|^2 / (N - n_p - 4 n_tests): for white
sensor noise and a model that holds it is the Cramer-Rao bound at the estimate (the projected
Jacobian gives the bound with the nuisance parameters unknown).

A command message that was not logged where the messages either side differ by a switch
(:attr:`~mrftcli.mrft.waveform.CommandWindow.free`: the switch may sit at that tick or at the next
message, one tick of uncertainty in its time) leaves that tick's command unknown: it enters the
output linearly too, so it is one more nuisance parameter of the projection (its pulse response,
:attr:`~mrftcli.mrft.waveform.ResponseBasis.pulses`), and the output decides where the switch sat
as far as it can, its uncertainty in the parameters' covariance (and one degree of freedom fewer).

Acceptance (:func:`refine`)
---------------------------
The refined estimate is used only when the data say the model holds:

1. the residual RMS is within ``RESIDUAL_FACTOR`` (1.15) of the sensor noise estimated from the
   same windows (:func:`sensor_noise`: third differences, robust scale): on clean simulated logs the
   ratio is 1.00-1.02; a sensor lag gives 1.3-1.9, gain drift about 5, delay jitter 13-33;
2. each refined parameter lies inside the MRFT estimate's 95 % interval widened by
   ``INTERVAL_FACTOR`` (2) about the MRFT point (an open side of a one-sided interval does not bound);
3. the fit converged and its covariance is finite;
4. the waveform bounds Td: its 95 % interval ends within the windows' total length (over a time
   much shorter than Td eq. (2) is an integrator of gain K, and a longer Td is not told apart).

Otherwise the MRFT estimate stands and :attr:`Refinement.reasons` says why.

Windows (:func:`refinement_windows`)
------------------------------
Each test's window holds the outputs of the test and the commands from ``COMMAND_HISTORY`` (1 s,
the fit's largest tau) before it: the first outputs of a test are driven by the hold controller's
last commands, which no initial state can stand in for.

Reuse: a refit with an effect modelled
--------------------------------------
A refit with one more physical effect is the same problem with one more parameter:
:func:`fit_output_error` takes any ``plant(p) -> (A, B, C, tau)`` with real, distinct eigenvalues,
and :func:`with_sensor_lag` appends a first-order measurement lag to any plant (one more parameter,
ln T_lag). An input bias needs no new parameter: the fitted command offset of each window
(:attr:`OutputErrorFit.offsets`, with :attr:`OutputErrorFit.offset_std`) is the bias at the plant
input relative to the relay's centre. :func:`refit_with_effect` does either from a model:

>>> import numpy as np
>>> from mrftcli.mrft.model import LoopModel
>>> truth = LoopModel(Tp=0.05, Td=1.0, tau=0.03, K=5.0)
>>> A, B, C = truth.state_space()
>>> lag = 0.02  # s: the sensor the recording went through
>>> A4 = np.block([[A, np.zeros((3, 1))], [C[None, :] / lag, -np.ones((1, 1)) / lag]])
>>> t = np.arange(0.0, 6.0, 0.005)
>>> u = 0.1 * np.sign(np.sin(2 * np.pi * 1.3 * t))
>>> w = CommandWindow.from_arrays(t, u, t)
>>> y = response_basis(A4, np.append(B, 0.0), np.eye(4)[3], truth.tau, w).columns[:, 0]
>>> w = CommandWindow.from_arrays(t, u, t, y + 1e-5 * np.random.default_rng(0).standard_normal(t.size))
>>> r = refit_with_effect([w], LoopModel(0.05, 1.1, 0.04, 5.2), "sensor_lag", 0.01)
>>> round(r.value * 1e3), round(r.model.tau * 1e3)  # T_lag [ms] and tau [ms] recovered
(20, 30)
>>> bool(abs(r.value - lag) < 3 * r.value_std)
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize

from ..errors import InputError
from ..validate import MAX_TIME_S
from .identify import ParameterEstimate
from .model import LoopModel
from .waveform import CommandWindow, TestSpan, response_basis

__all__ = ["RESIDUAL_FACTOR", "INTERVAL_FACTOR", "TAU_MAX", "COMMAND_HISTORY", "sensor_noise", "OutputErrorFit",
           "fit_output_error", "Refinement", "refine", "loop_model_plant", "loop_model_bounds", "refinement_windows",
           "with_sensor_lag", "EFFECTS", "EffectRefit", "refit_with_effect"]

#: Largest accepted ratio of the residual RMS to the estimated sensor noise.
RESIDUAL_FACTOR = 1.15
#: The MRFT 95 % interval is widened by this factor (about its point) for the acceptance check.
INTERVAL_FACTOR = 2.0
_Z95 = 1.959963984540054
#: the fits' upper bound on ln Td [ln s]: a week, the longest time a model takes (the cost is flat in
#: ln Td where the damping is not seen; past it eq. (2) refuses Td as a unit mistake)
_LN_TD_MAX = math.log(MAX_TIME_S * (1.0 - 1e-9))
#: Largest transport delay the refinement considers [s] (its upper bound on tau).
TAU_MAX = 1.0
#: Command recorded before each test that the windows carry [s]: covers any tau up to TAU_MAX.
COMMAND_HISTORY = TAU_MAX

Plant = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray, float]]


def sensor_noise(outputs: Sequence[np.ndarray]) -> float:
    """White sensor-noise std estimated from recorded outputs [output units].

    Third differences of a sampled output remove a smooth signal (the loop's output changes little
    in three samples; its third derivative jumps only at relay switches) and multiply white noise's
    variance by 20; the scale is the median absolute deviation (robust to the switches), pooled over
    the series.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> t = np.arange(0, 20, 0.005)
    >>> y = 0.05 * np.sin(2 * np.pi * t) + 0.0005 * rng.standard_normal(t.size)
    >>> bool(abs(sensor_noise([y]) / 0.0005 - 1) < 0.05)
    True
    """
    d = np.concatenate([np.diff(np.asarray(y, float)[np.isfinite(y)], 3) for y in outputs])
    if d.size < 8:
        raise InputError("estimating the sensor noise needs at least 8 output samples per test")
    return float(1.482602218505602 * np.median(np.abs(d - np.median(d))) / math.sqrt(20.0))


@dataclass(frozen=True, eq=False)
class OutputErrorFit:
    """Outcome of :func:`fit_output_error`.

    Attributes
    ----------
    p : numpy.ndarray
        Fitted parameters (the plant's own parametrisation).
    covariance : numpy.ndarray
        Gauss-Newton covariance of ``p`` scaled by the residual variance.
    std : numpy.ndarray
        Square roots of its diagonal.
    residual_rms : float
        RMS of the residual over all windows [output units].
    window_rms : tuple of float
        RMS of the residual per window [output units].
    n_samples : int
        Output samples fitted.
    n_evaluations : int
        Residual evaluations (each one simulation of every window).
    converged : bool
        The optimiser met a tolerance.
    offsets : tuple of float
        Fitted command offset per window [command units]: the plant input's bias relative to the
        window's ``bias`` (an input bias, or a trim the relay centre misses).
    offset_std : tuple of float
        Their std at the fitted ``p`` (linear least squares, residual variance) [command units].
    """

    p: np.ndarray
    covariance: np.ndarray
    std: np.ndarray
    residual_rms: float
    window_rms: tuple[float, ...]
    n_samples: int
    n_evaluations: int
    converged: bool
    offsets: tuple[float, ...]
    offset_std: tuple[float, ...] = ()


def _projected(plant: Plant, windows: Sequence[CommandWindow], p: np.ndarray,
               keep: list[tuple[float, float]] | None = None) -> np.ndarray:
    A, B, C, tau = plant(p)
    out = []
    for w in windows:
        basis = response_basis(A, B, C, tau, w)
        cols = basis.columns
        if w.output is None:  # (fit_output_error checks every window has its recording)
            raise InputError("the output-error fit needs every window's recorded output")
        ok = np.isfinite(w.output)
        y = w.output[ok] - cols[ok, 0]
        # an unknown tick's command (a switch that may sit in a gap) is one more linear nuisance
        X = np.hstack([cols[ok, 1:], basis.pulses[ok]]) if w.free.size else cols[ok, 1:]
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        out.append(y - X @ coef)
        if keep is not None:  # the offset and its unscaled variance (X^T X)^-1 [0, 0]
            keep.append((float(coef[0]), float(np.linalg.pinv(X.T @ X)[0, 0])))
    return np.concatenate(out)


def fit_output_error(windows: Sequence[CommandWindow], plant: Plant, p0: ArrayLike, *, lower: ArrayLike | None = None,
                     upper: ArrayLike | None = None, max_evaluations: int = 30) -> OutputErrorFit:
    """Fit a plant's parameters to recorded windows by output error (see the module docstring).

    Parameters
    ----------
    windows : sequence of CommandWindow
        The tests' gridded commands with their recorded outputs (``output`` must be given).
    plant : callable
        ``plant(p) -> (A, B, C, tau)``: the delay-free state space (real, distinct eigenvalues) and
        the transport delay [s] for parameters ``p``.
    p0 : array_like
        Start (the MRFT estimate in the plant's parametrisation).
    lower, upper : array_like, optional
        Bounds on ``p`` (default unbounded).
    max_evaluations : int
        Cap on residual evaluations.

    Returns
    -------
    OutputErrorFit
    """
    if not windows or any(w.output is None for w in windows):
        raise InputError("the output-error fit needs at least one window with its recorded output")
    p0 = np.asarray(p0, float)
    lo = np.full(p0.size, -np.inf) if lower is None else np.asarray(lower, float)
    hi = np.full(p0.size, np.inf) if upper is None else np.asarray(upper, float)
    p0 = np.clip(p0, lo, hi)
    p0 = np.where(np.isfinite(lo) & (p0 <= lo), lo + 1e-9 * (1.0 + np.abs(np.where(np.isfinite(lo), lo, 0.0))), p0)
    res = optimize.least_squares(lambda p: _projected(plant, windows, p), p0, bounds=(lo, hi), method="trf",
                                 x_scale="jac", jac="2-point", diff_step=1e-6, max_nfev=max_evaluations,
                                 xtol=1e-8, ftol=1e-10)
    offsets: list[tuple[float, float]] = []
    r = _projected(plant, windows, res.x, offsets)
    n = r.size
    dof = max(n - p0.size - sum(4 + w.free.size for w in windows), 1)
    s2 = float(r @ r) / dof
    J = res.jac
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        cov = np.full((p0.size, p0.size), np.nan)
    sizes = np.cumsum([int(np.isfinite(w.output).sum()) for w in windows if w.output is not None])[:-1]
    per = tuple(float(np.sqrt(np.mean(x ** 2))) for x in np.split(r, sizes))
    return OutputErrorFit(p=res.x, covariance=cov, std=np.sqrt(np.abs(np.diag(cov))),
                          residual_rms=float(np.sqrt(np.mean(r ** 2))), window_rms=per, n_samples=int(n),
                          n_evaluations=int(res.nfev), converged=bool(res.status > 0),
                          offsets=tuple(o for o, _ in offsets),
                          offset_std=tuple(math.sqrt(max(s2 * v, 0.0)) for _, v in offsets))


def loop_model_bounds(Tp: float) -> tuple[list[float], list[float]]:
    """The output-error fits' bounds on eq. (2)'s p = (ln Td, tau [s], K) at a known Tp [s]:
    Td from Tp/100 to a week, tau from 0 to ``TAU_MAX``, K free."""
    return [math.log(Tp * 1e-2), 0.0, -np.inf], [_LN_TD_MAX, TAU_MAX, np.inf]


def loop_model_plant(Tp: float) -> Plant:
    """eq. (2) at a known Tp [s] in the parametrisation p = (ln Td, tau [s], K)."""

    def plant(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        ss = LoopModel(Tp, math.exp(p[0]), max(p[1], 0.0), p[2]).realisation()
        return ss.A, ss.B, ss.C, max(float(p[1]), 0.0)

    return plant


def refinement_windows(tests: Sequence[TestSpan], t_command: ArrayLike, command: ArrayLike, t_output: ArrayLike,
                       output: ArrayLike, *, history: float = COMMAND_HISTORY) -> list[CommandWindow]:
    """Each test's :class:`CommandWindow` for the refinement: its outputs, and its commands from
    ``history`` [s] before it (see the module docstring).

    Parameters
    ----------
    tests : sequence of mrftcli.segment.MrftTest
        The tests (their ``t_start``, ``t_end`` [s] and ``bias`` [command units] are used).
    t_command, command, t_output, output : array_like
        The whole recording (times [s]).
    history : float
        Command before each test carried by its window [s].

    Returns
    -------
    list of CommandWindow
        In the tests' order; a test with fewer than 2 commands or 8 outputs is left out.
    """
    windows = [CommandWindow.between(t.t_start, t.t_end, t_command, command, t_output, output, t.bias, history)
               for t in tests]
    return [w for w in windows if w is not None]


def with_sensor_lag(plant: Plant) -> Plant:
    """``plant`` measured through a first-order lag 1 / (T_lag s + 1): one more parameter, ln T_lag.

    The augmented plant takes ``p = (*p_plant, ln T_lag [s])``; its state is the plant's plus the
    lagged output, which is what it outputs (the initial lagged output is fitted as well).

    Examples
    --------
    >>> import numpy as np
    >>> A, B, C, tau = with_sensor_lag(loop_model_plant(0.05))(np.array([0.0, 0.03, 2.0, np.log(0.02)]))
    >>> A.shape, C.tolist(), tau
    ((4, 4), [0.0, 0.0, 0.0, 1.0], 0.03)
    """

    def lagged(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        p = np.asarray(p, float)
        A, B, C, tau = plant(p[:-1])
        n = A.shape[0]
        inv = math.exp(-float(p[-1]))
        A4 = np.zeros((n + 1, n + 1))
        A4[:n, :n] = A
        A4[n, :n] = inv * np.asarray(C, float)
        A4[n, n] = -inv
        return A4, np.append(B, 0.0), np.eye(n + 1)[n], tau

    return lagged


#: The effects :func:`refit_with_effect` models (names as in :mod:`mrftcli.diagnose.physics`).
EFFECTS = ("sensor_lag", "input_bias")


@dataclass(frozen=True, eq=False)
class EffectRefit:
    """Outcome of :func:`refit_with_effect`.

    Attributes
    ----------
    effect : str
        ``"sensor_lag"`` or ``"input_bias"``.
    model : LoopModel
        Td, tau, K refitted with the effect modelled (Tp the start's).
    value, value_std : float
        The effect's parameter and its std: T_lag [s] (std by the delta method from ln T_lag), or
        the input bias d [command units] (the windows' offsets pooled by inverse variance).
    fit : OutputErrorFit
        The fit (p = (ln Td, tau, K) and, for a sensor lag, ln T_lag).
    """

    effect: str
    model: LoopModel
    value: float
    value_std: float
    fit: OutputErrorFit = field(repr=False)


def refit_with_effect(windows: Sequence[CommandWindow], start: LoopModel, effect: str, value0: float | None = None,
                      *, loop_sign: int = 1, max_evaluations: int = 60) -> EffectRefit:
    """Refit eq. (2) by output error with one physical effect modelled.

    Parameters
    ----------
    windows : sequence of CommandWindow
        Each test's window (:func:`refinement_windows`).
    start : LoopModel
        Start of the fit (the MRFT or the refined estimate; its Tp is kept).
    effect : {"sensor_lag", "input_bias"}
        ``"sensor_lag"``: y_measured = y / (T_lag s + 1), T_lag fitted (one more parameter).
        ``"input_bias"``: a constant at the plant input; the per-window command offset already models
        it, so the fit is the plain one and the value is the pooled offset.
    value0 : float, optional
        Start of T_lag [s] (default 0.01 s); unused for an input bias.
    loop_sign : {1, -1}
        Sign of the loop gain (as for :func:`refine`).
    max_evaluations : int
        Cap on residual evaluations.

    Returns
    -------
    EffectRefit

    Raises
    ------
    InputError
        An unknown effect or a non-positive T_lag start.
    """
    if effect not in EFFECTS:
        raise InputError(f"unknown effect {effect!r}: choose one of {', '.join(EFFECTS)}")
    sign = -1.0 if loop_sign < 0 else 1.0
    p0 = [math.log(start.Td), start.tau, sign * start.K]
    lower, upper = loop_model_bounds(start.Tp)
    plant = loop_model_plant(start.Tp)
    if effect == "sensor_lag":
        lag0 = 0.01 if value0 is None else float(value0)
        if not (math.isfinite(lag0) and lag0 > 0):
            raise InputError(f"the sensor-lag start must be a positive time in seconds, got {value0!r}")
        plant = with_sensor_lag(plant)
        p0, lower, upper = p0 + [math.log(lag0)], lower + [math.log(1e-4)], upper + [math.log(10.0)]
    fit = fit_output_error(windows, plant, p0, lower=lower, upper=upper, max_evaluations=max_evaluations)
    model = LoopModel(start.Tp, math.exp(float(fit.p[0])), max(float(fit.p[1]), 0.0), sign * float(fit.p[2]))
    if effect == "sensor_lag":
        value = math.exp(float(fit.p[3]))
        std = value * float(fit.std[3])
    else:
        w = np.array([1.0 / s ** 2 if s > 0 else 0.0 for s in fit.offset_std])
        o = np.asarray(fit.offsets)
        value = float(np.sum(w * o) / np.sum(w)) if w.sum() > 0 else float(np.mean(o))
        std = float(1.0 / math.sqrt(w.sum())) if w.sum() > 0 else float("nan")
    return EffectRefit(effect=effect, model=model, value=value, value_std=std, fit=fit)


@dataclass(frozen=True, eq=False)
class Refinement:
    """Outcome of :func:`refine`: the waveform estimate and whether it is used.

    Attributes
    ----------
    Td, tau, K : ParameterEstimate
        The output-error estimate with its Gauss-Newton std and mean +- 1.96 std interval [s], [s], [-].
    model : LoopModel
        The refined model.
    accepted : bool
        Use it instead of the MRFT estimate.
    reasons : tuple of str
        Why it was refused (empty when accepted).
    noise_std : float
        Sensor noise estimated from the windows [output units].
    residual_rms : float
        Residual RMS of the fit [output units].
    residual_ratio : float
        ``residual_rms / noise_std`` (accepted up to ``RESIDUAL_FACTOR``).
    fit : OutputErrorFit
        The fit itself (parameters in the (ln Td, tau, K) parametrisation).
    """

    Td: ParameterEstimate
    tau: ParameterEstimate
    K: ParameterEstimate
    model: LoopModel
    accepted: bool
    reasons: tuple[str, ...]
    noise_std: float
    residual_rms: float
    residual_ratio: float
    fit: OutputErrorFit = field(repr=False)

    def to_dict(self) -> dict[str, object]:
        """The ``refinement`` object of ``analyze --json``."""
        return {"accepted": self.accepted, "reasons": list(self.reasons), "noise_std": self.noise_std,
                "residual_rms": self.residual_rms, "residual_ratio": self.residual_ratio,
                "residual_factor": RESIDUAL_FACTOR, "interval_factor": INTERVAL_FACTOR,
                "evaluations": self.fit.n_evaluations, "samples": self.fit.n_samples,
                "window_rms": list(self.fit.window_rms)}


def _gaussian(mean: float, std: float, unit: str) -> ParameterEstimate:
    return ParameterEstimate(float(mean), float(std), float(mean - _Z95 * std), float(mean + _Z95 * std), unit,
                             method="waveform")


def _outside(name: str, value: float, est: ParameterEstimate, factor: float, scale: float, unit: str) -> str | None:
    lo = est.value - factor * (est.value - est.ci95_low) if np.isfinite(est.ci95_low) else -np.inf
    hi = est.value + factor * (est.ci95_high - est.value) if est.ci95_high is not None and np.isfinite(est.ci95_high) \
        else np.inf
    if lo <= value <= hi:
        return None
    return (f"{name} {value * scale:.4g}{unit} is outside the MRFT interval widened {factor:g}x "
            f"({lo * scale:.4g}-{hi * scale:.4g}{unit})")


def _td_not_bounded(Td_est: ParameterEstimate, windows: Sequence[CommandWindow]) -> str | None:
    """Why the waveform does not bound Td (None when it does): its 95 % interval runs past the record.

    Over times t << Td, K Td / (Td s + 1) = (K / s) (1 - 1 / (Td s) + ...): eq. (2) is then
    K e^{-tau s} / (s^2 (Tp s + 1)), an integrator of gain K behind the propulsion, and Td is left only in a
    correction of relative size t / Td. A Td far longer than the windows record is told from any longer one
    only by that vanishing correction, so an interval reaching past the record (the windows' total length,
    the most generous reading) is open above, and where the fit stopped on the flat cost is no value: an
    undamped loop's windows gave 151 s [2.95, 7.7e3] s from starts of 3 s to 1e4 s, 5.6e5 s or the week's
    bound from 1e5 s. The fit at the week's bound is the same case (its interval reaches past a week).
    """
    record = sum(float(w.t_output[-1] - w.t_output[0]) for w in windows if w.t_output.size)
    high, what = Td_est.ci95_high, "its 95 % interval reaches"
    if high is None or math.isnan(high):  # no covariance (the fit's own reason says so): the point alone
        high, what = Td_est.value, "its fit reaches"
    if high <= record:
        return None
    reach = f"{high:.3g} s" if math.isfinite(high) else "beyond a week"
    return (f"the waveform does not bound Td ({what} {reach}, more than the {record:.3g} s these windows "
            "record: a damping that slow is not seen in them)")


def refine(windows: Sequence[CommandWindow], start: LoopModel, mrft: Mapping[str, ParameterEstimate], *,
           noise_std: float | None = None, loop_sign: int = 1, residual_factor: float = RESIDUAL_FACTOR,
           interval_factor: float = INTERVAL_FACTOR, max_evaluations: int = 30) -> Refinement:
    """Refine Td, tau, K by output error from the MRFT estimate, and decide whether to use it.

    Parameters
    ----------
    windows : sequence of CommandWindow
        Each test's recorded command and output (times [s]; command relative to the test's bias),
        as :func:`refinement_windows` builds them.
    start : LoopModel
        The MRFT estimate (start of the fit; its Tp is the known one).
    mrft : mapping
        ``"Td"``, ``"tau"``, ``"K"`` -> the MRFT :class:`ParameterEstimate` (its 95 % interval, an
        open side given as NaN or None, bounds the acceptance).
    noise_std : float, optional
        Sensor noise [output units]; estimated by :func:`sensor_noise` when omitted.
    loop_sign : {1, -1}
        Sign of the loop gain (:attr:`mrftcli.segment.MrftTest.loop_sign`): the output moves with
        ``loop_sign * K`` times the command; K itself is reported positive, as the MRFT's is.
    residual_factor, interval_factor : float
        The acceptance thresholds (module docstring).
    max_evaluations : int
        Cap on residual evaluations (clean logs need 4-8; a Td the data bound from below only leaves
        a flat direction that takes 30-40).

    Returns
    -------
    Refinement
    """
    if noise_std is None:
        noise_std = sensor_noise([w.output for w in windows if w.output is not None])
    plant = loop_model_plant(start.Tp)
    sign = -1.0 if loop_sign < 0 else 1.0
    lower, upper = loop_model_bounds(start.Tp)
    fit = fit_output_error(windows, plant, [math.log(start.Td), start.tau, sign * start.K], lower=lower, upper=upper,
                           max_evaluations=max_evaluations)
    lnTd, tau, K = float(fit.p[0]), float(fit.p[1]), sign * float(fit.p[2])
    s = fit.std
    Td = math.exp(lnTd)
    # Td's interval is symmetric in ln Td (the fitted coordinate); std by the delta method
    # (a fit that leaves ln Td free has a huge std: the interval saturates instead of math.exp overflowing)
    half = min(_Z95 * float(s[0]), 700.0)
    Td_est = ParameterEstimate(Td, Td * float(s[0]), Td * math.exp(-half), Td * math.exp(half), "s", method="waveform")
    est = {"Td": Td_est, "tau": _gaussian(tau, s[1], "s"), "K": _gaussian(K, s[2], "")}
    ratio = fit.residual_rms / noise_std if noise_std > 0 else float("inf")
    reasons = []
    if not fit.converged or not np.all(np.isfinite(s)):
        reasons.append("the waveform fit did not converge")
    if not ratio <= residual_factor:
        reasons.append(f"the waveform residual is {ratio:.2f}x the sensor noise (accepted up to "
                       f"{residual_factor:g}x): the recording holds dynamics eq. (2) leaves out")
    unbounded = _td_not_bounded(Td_est, windows)
    if unbounded:
        reasons.append(unbounded)
    for name, scale, unit in (("Td", 1.0, " s"), ("tau", 1e3, " ms"), ("K", 1.0, "")):
        why = _outside(name, est[name].value, mrft[name], interval_factor, scale, unit)
        if why:
            reasons.append(why)
    model = LoopModel(start.Tp, Td, max(tau, 0.0), K if K != 0 else start.K)
    return Refinement(Td=est["Td"], tau=est["tau"], K=est["K"], model=model, accepted=not reasons,
                      reasons=tuple(reasons), noise_std=float(noise_std), residual_rms=fit.residual_rms,
                      residual_ratio=float(ratio), fit=fit)
