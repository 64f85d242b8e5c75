"""The loop model's output driven by a recorded command: exact zero-order-hold simulation.

:func:`predict_output` answers "what would the identified model have done with the command that was
actually sent?". It is what ``analyze --mcap-out`` overlays on the recording, and the forward model
an output-error refinement can reuse.

Method
------
The plant is G(s) = K Td e^{-tau s} / (s (Tp s + 1)(Td s + 1)) in the delay-free realisation of
:meth:`~mrftcli.mrft.model.LoopModel.state_space` (x = [y, y', propulsion state]). The command is put
on a uniform grid t_k = t_0 + k dt at its own rate (the sample in force at each grid instant: a
zero-order hold, dropped messages hold the previous value) and reaches the plant ``tau`` later. With
tau = (d + f) dt, d an integer and 0 <= f < 1, the plant input over [t_k, t_{k+1}) is u_{k-d-1} for
the first f dt and u_{k-d} after it, so the exact discretisation (no delay rounding) is

    x_{k+1} = Phi x_k + Gamma_a u_{k-d-1} + Gamma_b u_{k-d},
    Phi = e^{A dt},  Gamma_b = int_0^{(1-f) dt} e^{A s} ds B,  Gamma_a = e^{A (1-f) dt} int_0^{f dt} e^{A s} ds B,

in closed form in the modal coordinates of A (:func:`response_basis`; eq. (2) has the distinct
eigenvalues 0, -1/Td, -1/Tp): each mode is a first-order recursion (one :func:`scipy.signal.lfilter`
call, C speed), and the output at an arbitrary output time t_k + s is propagated exactly from x_k over
s with the same closed forms. The gridded command (:class:`CommandWindow`) does not depend on the
model, so a fit that evaluates many models grids it once. (The first version summed 15 transfer
functions from ``ss2tf``: the same output to 1e-9 relative, 12x slower: 33 against 2.8 ms for 10 s at
200 Hz.)

The initial state is not known (the loop was flying before the test), and neither is the exact hover
trim that the relay's centre level departs from: both enter the output linearly, so they are fitted by
linear least squares to the recorded output (``fit_initial``): the three initial states and a constant
input offset (added to ``command - bias``), four numbers against thousands of samples. The command is
taken relative to ``bias`` (the relay's centre level, :attr:`mrftcli.segment.MrftTest.bias`), the
equilibrium of the linear model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal

from ..errors import InputError
from .model import PlantModel

__all__ = ["PredictedOutput", "predict_output", "predict_tests", "CommandWindow", "ResponseBasis", "response_basis",
           "TestSpan"]

FloatArray = NDArray[np.float64]


class TestSpan(Protocol):
    """What :func:`predict_tests` needs of a test (:class:`mrftcli.segment.MrftTest` has it)."""

    @property
    def index(self) -> int:
        """The test's number in its log."""
        ...

    @property
    def t_start(self) -> float:
        """Its first relay sample [s]."""
        ...

    @property
    def t_end(self) -> float:
        """Its last relay sample [s]."""
        ...

    @property
    def bias(self) -> float:
        """The relay's centre level [command units]."""
        ...


@dataclass(frozen=True, eq=False)
class PredictedOutput:
    """The model's output over the recording's output times.

    Attributes
    ----------
    t : numpy.ndarray
        Output times [s] (the ``t_output`` given, in the log's time base).
    y : numpy.ndarray
        Predicted output [output units].
    residual : numpy.ndarray
        Recorded minus predicted output [output units] (NaN where no recording was given).
    x0 : numpy.ndarray
        Initial state [y, y', propulsion state] at the first command grid instant (fitted or given).
    input_offset : float
        Constant added to ``command - bias`` (fitted trim error) [command units].
    rms : float
        Root mean square of the residual [output units] (NaN without a recording).
    """

    t: np.ndarray
    y: np.ndarray
    residual: np.ndarray
    x0: np.ndarray
    input_offset: float
    rms: float


def _grid(t_command: np.ndarray, command: np.ndarray, t_end: float
          ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """The command on a uniform grid at its median rate up to ``t_end`` (zero-order hold), and the
    grid instants whose command is not known (:func:`_unknown_ticks`)."""
    dt = float(np.median(np.diff(t_command)))
    if not (math.isfinite(dt) and dt > 0):
        raise InputError("command times must increase")
    # Epoch stamps (1.7e9 s) are rounded to 2.4e-7 s, so single intervals miss dt by up to 5e-5 of
    # it, and over a 3000-sample test the grid would drift by a fraction of a millisecond (a bias in
    # tau): the period is the slope of the stamps against their tick counts instead.
    ticks = np.round((t_command - t_command[0]) / dt)
    if ticks[-1] > 0:
        tt = t_command - t_command[0]
        dt = float(np.dot(ticks - ticks.mean(), tt - tt.mean()) / np.dot(ticks - ticks.mean(), ticks - ticks.mean()))
    n = int(math.floor((max(t_end, t_command[-1]) - t_command[0]) / dt + 1e-9)) + 2
    grid = t_command[0] + dt * np.arange(n)
    # the sample in force at each grid instant (a half-sample tolerance absorbs receive jitter)
    idx = np.clip(np.searchsorted(t_command, grid + 0.5 * dt, side="right") - 1, 0, command.size - 1)
    ug = command[idx]
    free = _unknown_ticks(idx, command)
    if free.size:
        # the switch is at one of the missing ticks or at the next message: the middle of the two
        # levels stands for it in a prediction (a fit leaves these ticks free)
        ug = ug.copy()
        ug[free] = 0.5 * (command[idx[free]] + command[np.minimum(idx[free] + 1, command.size - 1)])
    return grid, ug, dt, free


#: a jump between the messages either side of a gap larger than this share of the window's largest
#: jump between messages is a switch that may sit in the gap (a PID command's steps are far smaller)
_SWITCH_SHARE = 0.25


def _unknown_ticks(idx: np.ndarray, command: np.ndarray) -> NDArray[np.intp]:
    """Grid instants without a message of their own (``idx``: the message in force at each, held
    from an earlier one) where the messages either side of the gap differ by a switch: the switch
    may sit at any of them, so their command is not known."""
    held = np.flatnonzero(np.diff(idx) == 0) + 1
    if held.size == 0 or command.size < 2:
        return held
    jump = np.abs(np.diff(command))
    nxt = idx[held]
    step = jump[np.minimum(nxt, jump.size - 1)]
    out: NDArray[np.intp] = held[(nxt < jump.size) & (step > _SWITCH_SHARE * float(jump.max()))]
    return out


def _phi(mu: ArrayLike, s: ArrayLike) -> NDArray[np.complex128]:
    """int_0^s e^{mu r} dr elementwise ((e^{mu s} - 1) / mu, and s where mu = 0)."""
    mu, s = np.asarray(mu), np.asarray(s)
    ms = mu * s
    small = np.abs(ms) < 1e-8
    with np.errstate(divide="ignore", invalid="ignore"):
        out: NDArray[np.complex128] = np.where(small, s * (1.0 + 0.5 * ms), np.expm1(ms) / np.where(mu == 0, 1.0, mu))
    return out


@dataclass(frozen=True, eq=False)
class CommandWindow:
    """A stretch of recorded command and output put on the controller's grid (model-independent).

    Built once per test by :meth:`from_arrays` and reused for every model evaluated on it (the
    output-error refinement evaluates dozens).

    Attributes
    ----------
    dt : float
        Controller period [s] (median command interval).
    u : numpy.ndarray
        Command minus ``bias`` at each grid instant t_0 + j dt (zero-order hold) [command units].
    k : numpy.ndarray
        Index of the grid instant at or before each output time.
    s : numpy.ndarray
        Output time minus that grid instant [s], in [0, dt).
    t_output : numpy.ndarray
        Output times [s].
    output : numpy.ndarray or None
        Recorded output at ``t_output`` [output units].
    bias : float
        The command level subtracted (the relay's centre level) [command units].
    free : numpy.ndarray
        Grid instants whose command is not known: no message was logged for them and the messages
        either side of the gap differ by a switch, which may sit at any of them (one tick of
        uncertainty in that switch's time). ``u`` holds the middle of the two levels there; a fit
        leaves them free (:attr:`ResponseBasis.pulses`).
    """

    dt: float
    u: np.ndarray
    k: np.ndarray
    s: np.ndarray
    t_output: np.ndarray
    output: np.ndarray | None
    bias: float
    free: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))

    @classmethod
    def from_arrays(cls, t_command: ArrayLike, command: ArrayLike, t_output: ArrayLike, output: ArrayLike | None = None,
                    bias: float = 0.0) -> "CommandWindow":
        """Grid a recorded command (times [s], values) and the output times [s] it drives.

        Raises :class:`~mrftcli.errors.InputError` when the command has fewer than two samples,
        its times do not increase, the output starts before it or ``output`` has another length.
        """
        tc = np.asarray(t_command, float)
        uc = np.asarray(command, float)
        to = np.asarray(t_output, float)
        if tc.ndim != 1 or tc.size < 2 or tc.size != uc.size:
            raise InputError("the command needs at least two samples with one time each")
        if to.size and to[0] < tc[0] - 1e-9:
            raise InputError("output times must not start before the first command sample")
        yrec = None if output is None else np.asarray(output, float)
        if yrec is not None and yrec.shape != to.shape:
            raise InputError("output and t_output must have the same length")
        grid, ug, dt, free = _grid(tc, uc - bias, float(to[-1]) if to.size else float(tc[-1]))
        k = np.clip(np.searchsorted(grid, to + 1e-12, side="right") - 1, 0, grid.size - 1)
        if to.size:
            # a tick after the last output's moves no output: its unknown command is no nuisance (a gap
            # after the test, a masked log's, gave thousands of zero columns to each fit's least squares)
            free = free[free <= k[-1]]
        return cls(dt=dt, u=ug, k=k, s=to - grid[k], t_output=to, output=yrec, bias=float(bias), free=free)


    @classmethod
    def between(cls, t_start: float, t_end: float, t_command: ArrayLike, command: ArrayLike, t_output: ArrayLike,
                output: ArrayLike | None, bias: float = 0.0, history: float = 0.0) -> "CommandWindow | None":
        """The window of a whole recording from ``t_start`` to ``t_end`` [s] (a test's relay span):
        command samples from the first at or after ``t_start - history`` to the first after
        ``t_end``, outputs from ``t_start`` on. None when it holds fewer than 2 command or 8 output
        samples.

        ``history`` [s] should cover the largest transport delay a model evaluated on the window
        may have: the outputs at the start of the test are driven by the commands sent up to tau
        before it (the hold controller's), which the free initial state cannot stand in for;
        without them the grid's first command is held backwards. (Leaving them out biased the
        refinement on plants with tau of 40-100 ms by up to 5 Cramer-Rao std and pushed the
        residual of clean logs to 1.1-1.3x the noise: docs/benchmarks/analyze.md.)

        Examples
        --------
        >>> import numpy as np
        >>> t = np.arange(0.0, 4.0, 0.01)
        >>> w = CommandWindow.between(2.0, 3.0, t, np.sin(t), t, np.cos(t), history=0.5)
        >>> float(w.t_output[0]), round(float(w.dt * w.k[0]), 6)
        (2.0, 0.5)
        """
        tc = np.asarray(t_command, float)
        ty = np.asarray(t_output, float)
        if not (math.isfinite(history) and history >= 0):
            raise InputError(f"the command history must be >= 0 s, got {history!r}")
        a = int(np.searchsorted(tc, t_start - history - 1e-9, side="left"))
        b = int(np.searchsorted(tc, t_end, side="left"))
        b = min(b + 1, tc.size)
        ya, yb = np.searchsorted(ty, [t_start, t_end], side="left")
        if b - a < 2 or yb - ya < 8:
            return None
        ya = max(ya, int(np.searchsorted(ty, tc[a] - 1e-9, side="left")))
        return cls.from_arrays(tc[a:b], np.asarray(command, float)[a:b], ty[ya:yb],
                               None if output is None else np.asarray(output, float)[ya:yb], bias)


@dataclass(frozen=True, eq=False)
class ResponseBasis:
    """The output over a :class:`CommandWindow` as a linear combination of known columns.

    y = columns[:, 0] + offset * columns[:, 1] + columns[:, 2:] @ z0, where ``offset`` is a constant
    added to the command and z0 the initial state in modal coordinates (x0 = ``modes`` @ z0).
    ``pulses[:, j]`` is the output's change per unit of command at the window's unknown tick
    ``free[j]`` (:attr:`CommandWindow.free`; ``u`` holds the middle of the two levels there).
    """

    columns: np.ndarray
    modes: np.ndarray
    pulses: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))


def response_basis(A: ArrayLike, B: ArrayLike, C: ArrayLike, tau: float, window: CommandWindow) -> ResponseBasis:
    """Exact zero-order-hold response of x' = A x + B u(t - tau), y = C x over a window.

    Diagonalises A (distinct eigenvalues: eq. (2) has 0, -1/Td, -1/Tp; an effect such as a sensor
    lag adds one more) so that each mode is a first-order recursion (one
    :func:`scipy.signal.lfilter` call) and the intra-sample propagation to each output time is closed
    form. Coincident eigenvalues are split by a relative 1e-7 (an output change far below noise).

    Parameters
    ----------
    A, B, C : array_like
        Delay-free state-space matrices (n x n, n, n).
    tau : float
        Transport delay [s], >= 0 (any fraction of the controller period).
    window : CommandWindow
        The gridded command and output times.

    Returns
    -------
    ResponseBasis
    """
    A_ = np.asarray(A, float)
    mu, V = np.linalg.eig(A_)
    if np.linalg.cond(V) > 1e8:  # (near-)coincident eigenvalues: split them by a relative 1e-7
        scale = max(float(np.max(np.abs(mu))), 1e-12)
        mu, V = np.linalg.eig(A_ + np.diag(1e-7 * scale * np.arange(A_.shape[0])))
    if np.iscomplexobj(mu) and np.any(np.abs(mu.imag) > 0):
        raise InputError("the plant has oscillatory modes; response_basis handles real eigenvalues only")
    # real eigenvalues: eig's arrays are real, and so is every product below. Why real accumulators, the window's
    # indexing hoisted out of the modes' loop and lam^k taken at the output ticks only: the refinement calls this
    # thousands of times per analysis (37 % of analyze's CPU on a PX4 SITL log); the same values, 1.15x faster
    # (benchmarks/bench_response_basis.py prints the ratio)
    mu, V = mu.real, V.real
    Vinv = np.linalg.inv(V)
    beta = Vinv @ np.asarray(B, float)
    c = np.asarray(C, float) @ V
    dt = window.dt
    d = int(math.floor(tau / dt + 1e-12))
    f = min(max(tau / dt - d, 0.0), 1.0)
    n = window.u.size
    # the command, and a unit pulse at each unknown tick: the forced response of each (one filter)
    U = np.zeros((n, 1 + window.free.size))
    U[:, 0] = window.u
    U[window.free, 1 + np.arange(window.free.size)] = 1.0
    pad = np.zeros((d + 1, U.shape[1]))
    pad[:, 0] = window.u[0]
    ua = np.concatenate([pad, U])[:n]  # u_{j-d-1}: in force over [t_j, t_j + f dt)
    ub = np.concatenate([pad[1:], U])[:n]  # u_{j-d}: in force over [t_j + f dt, t_{j+1})
    lam = np.exp(mu * dt)
    phi_f = _phi(mu, f * dt)
    gb = beta * _phi(mu, (1.0 - f) * dt)
    ga = beta * np.exp(mu * (1.0 - f) * dt) * phi_f
    k, s = window.k, window.s
    m = k.size
    first = s <= f * dt
    s2 = np.where(first, 0.0, s - f * dt)
    # intra-sample factors per output time and mode
    es = np.exp(np.outer(s, mu))
    pa = np.where(first[:, None], _phi(mu[None, :], s[:, None]), np.exp(np.outer(s2, mu)) * phi_f[None, :])
    pb = np.where(first[:, None], 0.0, _phi(mu[None, :], s2[:, None]))
    cols = np.zeros((m, 2 + mu.size))
    forced = np.zeros((m, U.shape[1]))
    ua_k, ub_k = ua[k], ub[k]
    for i in range(mu.size):
        # z_{j+1} = lam z_j + ga a_j + gb b_j, z_0 = 0: strictly causal first-order filter
        zf = signal.lfilter([0.0, 1.0], [1.0, -lam[i]], ga[i] * ua + gb[i] * ub, axis=0)
        lam_k = lam[i] ** k
        if abs(lam[i] - 1.0) < 1e-12:
            zs_k = (ga[i] + gb[i]) * k
        else:
            zs_k = (ga[i] + gb[i]) * (1.0 - lam_k) / (1.0 - lam[i])
        forced += c[i] * (es[:, i, None] * zf[k] + beta[i] * (pa[:, i, None] * ua_k + pb[:, i, None] * ub_k))
        cols[:, 1] += c[i] * (es[:, i] * zs_k + beta[i] * (pa[:, i] + pb[:, i]))
        cols[:, 2 + i] = c[i] * es[:, i] * lam_k
    cols[:, 0] = forced[:, 0]
    return ResponseBasis(columns=cols, modes=V, pulses=forced[:, 1:])


def predict_output(model: PlantModel, t_command: ArrayLike, command: ArrayLike, t_output: ArrayLike, *,
                   bias: float = 0.0, output: ArrayLike | None = None, fit_initial: bool = True,
                   x0: ArrayLike | None = None) -> PredictedOutput:
    """Simulate ``model`` driven by a recorded command, at the recording's output times.

    Parameters
    ----------
    model : PlantModel
        The plant (e.g. a :class:`~mrftcli.mrft.model.LoopModel`: Tp, Td, tau [s] and K of eq. (2)).
    t_command, command : array_like
        Command sample times [s] (increasing) and values [command units], as logged.
    t_output : array_like
        Times [s] at which to predict the output, within ``[t_command[0], ...)``; later than the last
        command sample the last command is held.
    bias : float
        The command level at which the linear model is in equilibrium (relay centre) [command units].
    output : array_like, optional
        The recorded output at ``t_output`` [output units]: needed to fit the initial state and for
        the residual.
    fit_initial : bool
        Fit the initial state and a constant input offset to ``output`` by linear least squares
        (see the module docstring). Otherwise ``x0`` (default: the first recorded output at rest).
    x0 : array_like, optional
        Initial state [y, y', propulsion state] at ``t_command[0]`` when not fitted.

    Returns
    -------
    PredictedOutput

    Examples
    --------
    At the bias the model is in equilibrium, so a hover stays where it started:

    >>> import numpy as np
    >>> from mrftcli.mrft.model import LoopModel
    >>> m = LoopModel(Tp=0.05, Td=2.0, tau=0.0123, K=19.6)
    >>> t = np.arange(0.0, 1.0, 0.005)
    >>> p = predict_output(m, t, np.full(t.size, 0.5), t, bias=0.5, fit_initial=False, x0=[1.0, 0, 0])
    >>> bool(np.allclose(p.y, 1.0))
    True
    """
    if fit_initial and output is None:
        raise InputError("fitting the initial state needs the recorded output")
    return _predict(model, CommandWindow.from_arrays(t_command, command, t_output, output, bias), fit_initial, x0)


def _predict(model: PlantModel, window: CommandWindow, fit_initial: bool = True,
             x0: ArrayLike | None = None) -> PredictedOutput:
    """:func:`predict_output` over a gridded window."""
    to, yrec = window.t_output, window.output
    ss = model.realisation()
    basis = response_basis(ss.A, ss.B, ss.C, model.delay, window)
    cols = basis.columns
    if fit_initial and yrec is not None:  # (checked above: fitting needs the recording)
        ok = np.isfinite(yrec)
        coef, *_ = np.linalg.lstsq(cols[ok, 1:], yrec[ok] - cols[ok, 0], rcond=None)
        offset, z_init = float(coef[0]), coef[1:]
        x_init = basis.modes @ z_init
    else:
        offset = 0.0
        if x0 is None:
            # at rest at the first recorded output: the least-norm state with C x = y (for eq. (2)
            # [y, 0, 0])
            y_first = yrec[0] if yrec is not None and yrec.size else 0.0
            x_init = ss.C * y_first / float(ss.C @ ss.C)
        else:
            x_init = np.asarray(x0, float).reshape(ss.order)
        z_init = np.linalg.solve(basis.modes, x_init)
    y = cols[:, 0] + offset * cols[:, 1] + cols[:, 2:] @ z_init
    if yrec is None:
        resid = np.full(to.size, np.nan)
        rms = float("nan")
    else:
        resid = yrec - y
        fin = resid[np.isfinite(resid)]
        rms = float(np.sqrt(np.mean(fin ** 2))) if fin.size else float("nan")
    return PredictedOutput(t=to, y=y, residual=resid, x0=np.asarray(x_init, float), input_offset=offset, rms=rms)


def predict_tests(model: PlantModel, tests: Sequence[TestSpan], t_command: ArrayLike, command: ArrayLike,
                  t_output: ArrayLike, output: ArrayLike, *, history: float = 1.0) -> dict[int, PredictedOutput]:
    """:func:`predict_output` over each MRFT test's outputs, driven by its commands from ``history``
    [s] before its first relay sample (the commands sent within tau before a test drive its first
    outputs; :meth:`CommandWindow.between`) to its last.

    Parameters
    ----------
    model : PlantModel
        The identified model.
    tests : sequence of mrftcli.segment.MrftTest
        The tests (their ``t_start``, ``t_end`` [s] and ``bias`` [command units] are used).
    t_command, command, t_output, output : array_like
        The whole recording (times [s] in the log's time base).
    history : float
        Command before each test used [s] (1 s covers any delay up to 1 s).

    Returns
    -------
    dict
        ``MrftTest.index`` -> the prediction over that test (initial state and trim fitted per test).
    """
    out = {}
    for test in tests:
        w = CommandWindow.between(test.t_start, test.t_end, t_command, command, t_output, output, test.bias, history)
        if w is not None:
            out[test.index] = _predict(model, w)
    return out
