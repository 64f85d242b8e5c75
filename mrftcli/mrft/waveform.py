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

each from one matrix exponential of the augmented matrix [[A, B], [0, 0]]. The recursion runs as
two IIR filters (:func:`scipy.signal.lfilter`, C speed); the output at an arbitrary output time
t_k + s is propagated exactly from x_k over s (s rounded to dt/1000 so that few matrix exponentials
are needed; the error is below 1e-3 dt times the output's rate).

The initial state is not known (the loop was flying before the test), and neither is the exact hover
trim that the relay's centre level departs from: both enter the output linearly, so they are fitted by
linear least squares to the recorded output (``fit_initial``): the three initial states and a constant
input offset (added to ``command - bias``), four numbers against thousands of samples. The command is
taken relative to ``bias`` (the relay's centre level, :attr:`mrftcli.segment.MrftTest.bias`), the
equilibrium of the linear model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg, signal

from ..errors import InputError
from .model import LoopModel

__all__ = ["PredictedOutput", "predict_output", "predict_tests"]


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


def _augmented(A: np.ndarray, B: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{A s}, int_0^s e^{A r} dr B) from one matrix exponential."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A * s
    M[:n, n] = B * s
    E = linalg.expm(M)
    return E[:n, :n], E[:n, n]


def _augmented_many(A: np.ndarray, B: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_augmented` for many short times at once (s within one sample): a Taylor series of
    the augmented exponential, exact to rounding while |A| s stays below 1 (else per-time expm)."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A
    M[:n, n] = B
    s = np.asarray(s, float)
    if s.size == 0 or np.abs(M).sum(axis=1).max() * s.max() > 1.0:
        pairs = [_augmented(A, B, float(v)) for v in s]
        return (np.array([p[0] for p in pairs]).reshape(-1, n, n), np.array([p[1] for p in pairs]).reshape(-1, n))
    # Horner: E(s) = I + Ms (I + Ms/2 (I + Ms/3 (...))); 18 terms reach rounding for |M s| <= 1
    eye = np.eye(n + 1)
    E = np.broadcast_to(eye, (s.size, n + 1, n + 1)).copy()
    Ms = M[None, :, :] * s[:, None, None]
    for j in range(18, 0, -1):
        E = eye + (Ms @ E) / j
    return E[:, :n, :n], E[:, :n, n]


def _grid(t_command: np.ndarray, command: np.ndarray, t_end: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The command on a uniform grid at its median rate up to ``t_end`` (zero-order hold)."""
    dt = float(np.median(np.diff(t_command)))
    if not (math.isfinite(dt) and dt > 0):
        raise InputError("command times must increase")
    n = int(math.floor((max(t_end, t_command[-1]) - t_command[0]) / dt + 1e-9)) + 2
    grid = t_command[0] + dt * np.arange(n)
    # the sample in force at each grid instant (a half-sample tolerance absorbs receive jitter)
    idx = np.searchsorted(t_command, grid + 0.5 * dt, side="right") - 1
    return grid, command[np.clip(idx, 0, command.size - 1)], dt


def predict_output(model: LoopModel, t_command, command, t_output, *, bias: float = 0.0,
                   output=None, fit_initial: bool = True, x0=None) -> PredictedOutput:
    """Simulate ``model`` driven by a recorded command, at the recording's output times.

    Parameters
    ----------
    model : LoopModel
        Tp, Td, tau [s] and K of eq. (2).
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
    tc = np.asarray(t_command, float)
    u = np.asarray(command, float)
    to = np.asarray(t_output, float)
    if tc.ndim != 1 or tc.size < 2 or tc.size != u.size:
        raise InputError("the command needs at least two samples with one time each")
    if to.size and to[0] < tc[0] - 1e-9:
        raise InputError("output times must not start before the first command sample")
    if fit_initial and output is None:
        raise InputError("fitting the initial state needs the recorded output")
    yrec = None if output is None else np.asarray(output, float)
    if yrec is not None and yrec.shape != to.shape:
        raise InputError("output and t_output must have the same length")
    A, B, C = model.state_space()
    grid, ug, dt = _grid(tc, u - bias, float(to[-1]) if to.size else float(tc[-1]))
    d = int(math.floor(model.tau / dt + 1e-12))
    f = model.tau / dt - d
    Phi, Gb = _augmented(A, B, (1.0 - f) * dt)
    Ef, Sf = _augmented(A, B, f * dt)
    Phi_full = Phi @ Ef
    Ga = Phi @ Sf
    n = grid.size
    # u_{k-d-1} and u_{k-d}: before the first sample the command was at its first value
    pad = np.full(d + 1, ug[0])
    ua = np.concatenate([pad, ug])[:n]
    ub = np.concatenate([pad[:-1] if d else pad[:0], ug])[:n]

    def states(inp_a: np.ndarray, inp_b: np.ndarray) -> np.ndarray:
        # x_{k+1} = Phi x_k + Ga a_k + Gb b_k, x_0 = 0, every state component by an IIR filter
        den = np.poly(Phi_full)
        out = np.zeros((n, 3))
        for g, inp in ((Ga, inp_a), (Gb, inp_b)):
            for i in range(3):
                e = np.zeros(3)
                e[i] = 1.0
                num, _ = signal.ss2tf(Phi_full, g[:, None], e[None, :], np.zeros((1, 1)))
                # strictly proper (leading zero): x_k depends on the inputs up to k - 1
                out[:, i] += signal.lfilter(num[0], den, inp)
        return out

    forced = states(ua, ub)
    ones = np.ones(n)
    step = states(ones, ones)
    # free responses Phi^k e_i: impulse responses of (zI - Phi)^{-1} shifted by one
    free = np.zeros((n, 3, 3))  # [k, state, initial component]
    den = np.poly(Phi_full)
    imp = np.zeros(n + 1)
    imp[0] = 1.0
    for j in range(3):
        for i in range(3):
            e_i, e_j = np.zeros(3), np.zeros(3)
            e_i[i], e_j[j] = 1.0, 1.0
            num, _ = signal.ss2tf(Phi_full, e_j[:, None], e_i[None, :], np.zeros((1, 1)))
            free[:, i, j] = signal.lfilter(num[0], den, imp)[1:]

    # output times: exact propagation from the grid instant before each one over s in [0, dt)
    k = np.clip(np.searchsorted(grid, to + 1e-12, side="right") - 1, 0, n - 1)
    s = to - grid[k]
    first = s <= f * dt  # still under u_{k-d-1}
    # a regular output grid has few distinct offsets: one exponential per distinct one
    s_u, inv = np.unique(np.round(s / dt, 9), return_inverse=True)
    s2_u, inv2 = np.unique(np.round(np.where(first, 0.0, s - f * dt) / dt, 9), return_inverse=True)
    Es, Ss = (v[inv] for v in _augmented_many(A, B, s_u * dt))
    E2, S2 = (v[inv2] for v in _augmented_many(A, B, s2_u * dt))
    M_a = np.where(first[:, None], Ss, E2 @ Sf)
    M_b = np.where(first[:, None], 0.0, S2)
    cE = np.einsum("j,mjl->ml", C, Es)  # C e^{A s}, shape (m, 3)
    basis = np.zeros((to.size, 5))  # columns: forced, unit input offset, x0[0..2]
    basis[:, 0] = np.einsum("ml,ml->m", forced[k], cE) + (M_a @ C) * ua[k] + (M_b @ C) * ub[k]
    basis[:, 1] = np.einsum("ml,ml->m", step[k], cE) + M_a @ C + M_b @ C
    basis[:, 2:] = np.einsum("ml,mlj->mj", cE, free[k])
    if fit_initial:
        ok = np.isfinite(yrec)
        coef, *_ = np.linalg.lstsq(basis[ok, 1:], yrec[ok] - basis[ok, 0], rcond=None)
        offset, x_init = float(coef[0]), coef[1:]
    else:
        offset = 0.0
        if x0 is None:
            x_init = np.array([yrec[0] if yrec is not None and yrec.size else 0.0, 0.0, 0.0])
        else:
            x_init = np.asarray(x0, float).reshape(3)
    y = basis[:, 0] + offset * basis[:, 1] + basis[:, 2:] @ x_init
    if yrec is None:
        resid = np.full(to.size, np.nan)
        rms = float("nan")
    else:
        resid = yrec - y
        fin = resid[np.isfinite(resid)]
        rms = float(np.sqrt(np.mean(fin ** 2))) if fin.size else float("nan")
    return PredictedOutput(t=to, y=y, residual=resid, x0=np.asarray(x_init, float), input_offset=offset, rms=rms)


def predict_tests(model: LoopModel, tests, t_command, command, t_output, output) -> dict[int, PredictedOutput]:
    """:func:`predict_output` over each MRFT test, from its relay's first to its last command sample.

    Parameters
    ----------
    model : LoopModel
        The identified model.
    tests : sequence of mrftcli.segment.MrftTest
        The tests (their ``t_start``, ``t_end`` [s] and ``bias`` [command units] are used).
    t_command, command, t_output, output : array_like
        The whole recording (times [s] in the log's time base).

    Returns
    -------
    dict
        ``MrftTest.index`` -> the prediction over that test (initial state and trim fitted per test).
    """
    tc = np.asarray(t_command, float)
    u = np.asarray(command, float)
    ty = np.asarray(t_output, float)
    y = np.asarray(output, float)
    out = {}
    for test in tests:
        a, b = np.searchsorted(tc, [test.t_start, test.t_end], side="left")
        b = min(b + 1, tc.size)
        ya, yb = np.searchsorted(ty, [test.t_start, test.t_end], side="left")
        if b - a < 2 or yb - ya < 8:
            continue
        out[test.index] = predict_output(model, tc[a:b], u[a:b], ty[ya:yb], bias=test.bias, output=y[ya:yb])
    return out
