"""Frequency-domain figures of the sampled loop: gain, phase and delay margins, sensitivity peak Ms.

The loop is L(z) = C_fb(z) Gd(z) (broken at the plant input), with Gd the exact zero-order-hold
equivalent of the plant and its delay (:meth:`mrftcli.tune.closed_loop.PlantStack.transfer`: the delay is
the phase term z^{-d} and its fractional part is in the hold, no Pade approximant, no delay states)
and C_fb the controller from -y to u. One computation, :func:`loop_margins`, gives every figure for
any number of loops at once, the nominal model and the posterior's draws alike (:func:`margins` is
its one-loop case), so the nominal figure is always one of the draws' figures:

* the crossings are bracketed on a frequency grid (log-spaced, plus a linear part fine enough that
  the delay's phase turns by less than 0.25 rad between points, so its size grows linearly with the
  delay) and refined by bisection on the exact response;
* gain and phase margins are chosen as :func:`control.stability_margins` does (the phase margin of
  smallest magnitude, the gain margin closest to 1 in log);
* stability is the Nyquist criterion on the unit circle, indented around the integrators at z = 1;
* the delay margin is exact for the sampled loop: an extra delay of whole ticks j T turns L by
  e^{-j omega j T} and leaves |L| alone, so the tick in which the phase margin runs out is known in
  closed form and the fraction of a tick is bisected on the loop rediscretised with that delay.

The python-control model of the plant (:func:`plant_system`) is kept as the tests' check.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..jsonable import check_schema_version, to_jsonable
from ..errors import InputError
from ..mrft.model import LoopModel, PlantModel
from .closed_loop import Controller, DiscretePlant, PlantStack, as_discrete, augmented, discrete_plants, plants_of_parameters

__all__ = ["Margins", "MARGINS_SCHEMA_VERSION", "LoopMargins", "plant_system", "margins", "loop_margins", "stack_margins",
           "stack_sensitivity", "margin_response", "sensitivity_peaks",
           "frequency_grid", "margin_grid", "plant_response", "nyquist_stable",
           "phase_margins", "gain_margins", "largest_holding"]


@dataclass(frozen=True)
class Margins:
    """Stability margins of one sampled loop.

    Attributes
    ----------
    gain_margin : float
        Factor by which the loop gain may grow before instability [-] (inf if the phase never crosses -180 deg).
    phase_margin_deg : float
        Phase margin [deg] at the gain crossover ``w_gc``.
    delay_margin_s : float
        Extra transport delay the loop survives [s] (exact, sampled loop).
    Ms : float
        Sensitivity peak max |1 / (1 + L)| [-].
    w_gc, w_pc : float
        Gain and phase crossover frequencies [rad/s].
    stable : bool
        Whether the nominal sampled closed loop is stable.
    """

    gain_margin: float
    phase_margin_deg: float
    delay_margin_s: float
    Ms: float
    w_gc: float
    w_pc: float
    stable: bool

    def to_json(self) -> dict[str, Any]:
        """The versioned JSON object (:data:`MARGINS_SCHEMA_VERSION`): the fields in their units, a
        non-finite figure (no crossing: inf; unstable: Ms inf) as the string "inf", "-inf" or "nan".

        Examples
        --------
        >>> m = Margins(3.8, 48.3, 1.24, 1.59, 0.68, 2.11, True)
        >>> Margins.from_json(m.to_json()) == m
        True
        """
        return {"schema_version": MARGINS_SCHEMA_VERSION,
                **to_jsonable({name: float(getattr(self, name)) for name in _MARGIN_FIELDS}, nonfinite=str),
                "stable": self.stable}

    @classmethod
    def from_json(cls, data: Any) -> "Margins":
        """The record of :meth:`to_json`.

        Raises
        ------
        InputError
            Not a JSON object, another ``schema_version``, or a missing or malformed field.
        """
        check_schema_version(data, "tune margins", MARGINS_SCHEMA_VERSION)
        try:
            values = [float(data[name]) for name in _MARGIN_FIELDS]
            stable = data["stable"]
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"tune margins: missing or malformed field ({err})") from err
        if not isinstance(stable, bool):
            raise InputError(f"tune margins: 'stable' must be true or false, got {stable!r}")
        gm, pm, dm, Ms, w_gc, w_pc = values
        return cls(gm, pm, dm, Ms, w_gc, w_pc, stable)


#: Version of :meth:`Margins.to_json`'s object.
MARGINS_SCHEMA_VERSION = 1
_MARGIN_FIELDS = ("gain_margin", "phase_margin_deg", "delay_margin_s", "Ms", "w_gc", "w_pc")


def plant_system(model: LoopModel, rate_hz: float):
    """Gd as a discrete python-control state space (input u_k, output y_k, time step 1/rate_hz).

    States: the plant's three, then the commands still in flight u_{k-1} ... u_{k-d-1} (:func:`augmented`).
    """
    import control

    ss = augmented(discrete_plants([model], rate_hz)[0])
    return control.ss(ss.Phi, ss.Gamma[:, None], ss.C[None, :], np.zeros((1, 1)), 1.0 / rate_hz)


def frequency_grid(rate_hz: float, n: int = 600) -> np.ndarray:
    """Log-spaced frequencies [rad/s] from 1e-3 of Nyquist up to just below Nyquist."""
    w_nyq = math.pi * rate_hz
    return np.geomspace(w_nyq * 1e-4, w_nyq * 0.999, n)


def margin_grid(rate_hz: float, d_max: int) -> np.ndarray:
    """Frequencies [rad/s] that bracket every crossing of a loop with a delay of up to ``d_max`` ticks.

    1200 log-spaced points from 1e-6 of Nyquist, and a linear grid on which z^{-(d_max + 4)} turns by
    at most 0.25 rad per step (so it grows linearly with the delay); the last point is just below
    Nyquist.
    """
    w_nyq = math.pi * rate_hz
    n_lin = int(math.ceil(math.pi * (d_max + 4) / 0.25))
    w = np.union1d(np.geomspace(w_nyq * 1e-6, w_nyq, 1200), np.linspace(0.0, w_nyq, n_lin + 1)[1:])
    return np.append(w[w < w_nyq * (1 - 1e-9)], w_nyq * (1 - 1e-9))


def plant_response(models: Sequence[PlantModel | DiscretePlant], rate_hz: float, omega: np.ndarray) -> np.ndarray:
    """Gd(e^{j omega T}) of each model (any family's, or a DiscretePlant), shape (M, len(omega)), omega in rad/s.

    :meth:`mrftcli.tune.closed_loop.PlantStack.transfer` on the unit circle (the same system as
    :func:`plant_system`, whose python-control frequency response the tests compare it with).
    """
    plants = as_discrete(models, rate_hz)
    if not plants:
        return np.empty((0, np.size(omega)), complex)
    return PlantStack.of(plants).transfer(np.exp(1j * np.asarray(omega, float) / rate_hz))


@dataclass(frozen=True, eq=False)
class LoopMargins:
    """The figures of :class:`Margins` for M loops (arrays of shape (M,)); ``[i]`` is loop i's Margins."""

    gain_margin: np.ndarray
    phase_margin_deg: np.ndarray
    delay_margin_s: np.ndarray
    Ms: np.ndarray
    w_gc: np.ndarray
    w_pc: np.ndarray
    stable: np.ndarray

    def __len__(self) -> int:
        return int(self.stable.size)

    def __getitem__(self, i: int) -> Margins:
        return Margins(float(self.gain_margin[i]), float(self.phase_margin_deg[i]), float(self.delay_margin_s[i]),
                       float(self.Ms[i]), float(self.w_gc[i]), float(self.w_pc[i]), bool(self.stable[i]))


def margins(model: LoopModel, controller: Controller) -> Margins:
    """Gain, phase and delay margins and Ms of the sampled loop on ``model`` (:func:`loop_margins` of one loop)."""
    return loop_margins(controller, [model])[0]


#: Regula falsi steps (:func:`_root`): on log frequency within a grid interval, and on the fraction
#: of a tick of the delay margin.
_ROOT_STEPS = 16


def _root(f: Callable[[np.ndarray], np.ndarray], lo: np.ndarray, hi: np.ndarray, n: int,
          f_lo: np.ndarray | None = None, f_hi: np.ndarray | None = None) -> np.ndarray:
    """A root of each f in [lo, hi] (vectorised over the brackets, a sign change in each).

    Regula falsi with the Illinois modification (superlinear; a bracket of 1 % shrinks below 1e-13
    in about a dozen steps), so a refinement costs a few evaluations of the loop, whatever the delay.
    """
    f_lo = f(lo) if f_lo is None else f_lo
    f_hi = f(hi) if f_hi is None else f_hi
    side = np.zeros(lo.shape)
    for _ in range(n):
        den = f_hi - f_lo
        x = np.where(den != 0.0, (lo * f_hi - hi * f_lo) / np.where(den != 0.0, den, 1.0), 0.5 * (lo + hi))
        fx = f(x)
        left = np.sign(fx) == np.sign(f_lo)  # the root is in [x, hi]
        lo, hi = np.where(left, x, lo), np.where(left, hi, x)
        f_lo, f_hi = np.where(left, fx, f_lo), np.where(left, f_hi, fx)
        # Illinois: an end kept twice running has its value halved (no one-sided creeping)
        f_hi = np.where(left & (side > 0), 0.5 * f_hi, f_hi)
        f_lo = np.where(~left & (side < 0), 0.5 * f_lo, f_lo)
        side = np.where(left, 1.0, -1.0)
    den = f_hi - f_lo
    return np.where(den != 0.0, (lo * f_hi - hi * f_lo) / np.where(den != 0.0, den, 1.0), 0.5 * (lo + hi))


def largest_holding(ok: Callable[[float], bool], scan: Sequence[float] | np.ndarray, ratio: float | None = None, *,
                    halvings: int | None = None) -> float | None:
    """The largest value at which ``ok`` holds (None: none of ``scan``): the first of ``scan`` (descending) that
    holds (the test need not be monotone: a scan, not a bisection from the top), then bisected on its log
    between it and the scan point above, until they are within a factor ``ratio`` (> 1) or ``halvings``
    times (give one of the two)."""
    if (ratio is None) == (halvings is None):
        raise ValueError("largest_holding takes a ratio or a number of halvings, one of the two")
    for i, v in enumerate(scan):
        if ok(float(v)):
            break
    else:
        return None
    if i == 0:
        return float(scan[0])
    lo, hi = math.log(scan[i]), math.log(scan[i - 1])
    if halvings is not None:
        for _ in range(halvings):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ok(math.exp(mid)) else (lo, mid)
        return math.exp(lo)
    while hi - lo > math.log(ratio):  # type: ignore[arg-type]  # (ratio is given when halvings is not)
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(math.exp(mid)) else (lo, mid)
    return math.exp(lo)


def _golden_min(f: Callable[[np.ndarray], np.ndarray], lo: np.ndarray, hi: np.ndarray, n: int = 40) -> np.ndarray:
    """The minimiser of each unimodal f on [lo, hi] by golden section (vectorised over the brackets).

    ``f`` takes both probes of every bracket stacked (2K points: the K first probes, then the K second) and
    is evaluated elementwise. Why: one call of twice the size instead of two halves the loop evaluations'
    per-call overhead, which dominates at tens of brackets (the same values: each point is computed alone;
    ``benchmarks/bench_tune_ranges.py`` prints the ratio)."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = lo.copy(), hi.copy()
    k = a.size
    for _ in range(n):
        c, d = b - g * (b - a), a + g * (b - a)
        fcd = f(np.concatenate([c, d]))
        left = fcd[:k] < fcd[k:]
        a, b = np.where(left, a, c), np.where(left, d, b)
    return 0.5 * (a + b)


def _first_per_row(rows: np.ndarray, key: np.ndarray, M: int) -> np.ndarray:
    """Per row, the index (into rows/key) of the smallest key; -1 for a row with none."""
    out = np.full(M, -1)
    if rows.size:
        order = np.lexsort((key, rows))
        first = np.ones(order.size, bool)
        first[1:] = rows[order][1:] != rows[order][:-1]
        out[rows[order[first]]] = order[first]
    return out


class _Loop:
    """L(e^{j omega T}) of M loops at a frequency per bracket (row index ``rows``), for the refinements."""

    def __init__(self, controller: Controller, stack: PlantStack) -> None:
        self.c, self.stack, self.T = controller, stack, controller.Ts
        self._rows: np.ndarray | None = None  # the last rows taken, and their plants (a refinement's steps reuse them)
        self._taken = stack

    def at(self, rows: np.ndarray, log_w: np.ndarray, stack: PlantStack | None = None) -> np.ndarray:
        w = np.exp(log_w)
        if stack is None:
            if rows is not self._rows:  # by identity: callers never mutate rows in place
                self._rows, self._taken = rows, self.stack.take(rows)
            stack = self._taken
        return self.c.feedback_response(w) * stack.transfer(np.exp(1j * w * self.T)[:, None])[:, 0]


def _crossings(sign_of: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, k) where a row of values changes sign between grid points k and k + 1."""
    s = np.sign(sign_of)
    rows, k = np.nonzero((s[:, :-1] * s[:, 1:] < 0) | ((s[:, 1:] == 0) & (s[:, :-1] != 0)))
    return rows, k


def nyquist_stable(m: Any, L: np.ndarray, unstable: Any = 0) -> np.ndarray:
    """Nyquist criterion on the unit circle (open loop: ``m`` integrators at z = 1 indented, ``unstable`` poles
    outside the circle, the others inside; each a number or one per row), per row of the loop ``L`` on
    :func:`margin_grid`-like frequencies up to Nyquist.

    Going round the circle from z = 1+ to 1- and round z = 1 outside, the winding of 1 + L about 0 is
    (2 Delta arg_{(0, pi)} (1 + L) - m pi) / 2 pi (L is real on the real axis and conjugate-symmetric;
    the arc about z = 1, where L ~ c / (z - 1)^m, turns it by -m pi). 1 + L has as many zeros as poles
    (L strictly proper), so the closed-loop poles outside number ``unstable`` minus the winding. Stable:
    the winding is ``unstable`` (none for every plant but a declared unstable one).
    """
    ph = np.unwrap(np.angle(1.0 + L), axis=-1)
    winding = (2.0 * (ph[:, -1] - ph[:, 0]) - m * math.pi) / (2.0 * math.pi)
    return np.asarray(np.rint(winding) == unstable)


def loop_margins(controller: Controller, models: Sequence[LoopModel],
                 plants: Sequence[DiscretePlant] | None = None) -> LoopMargins:
    """Gain, phase and delay margins, Ms and stability of the sampled loop on each of ``models``.

    Parameters
    ----------
    controller : Controller
    models : sequence of LoopModel
        The plants (the nominal model, or the posterior's draws).
    plants : sequence of DiscretePlant, optional
        ``models`` already discretised at the controller rate (saves that step).

    Returns
    -------
    LoopMargins
        Per loop: gain margin [-] (inf without a -180 deg crossing), phase margin [deg] (inf without a
        gain crossover), delay margin [s] (0 when unstable), Ms [-] (inf when unstable), the
        crossover frequencies [rad/s] and the stability flag (module docstring for the method).
    """
    models = list(models)
    plants = as_discrete(plants if plants is not None else models, controller.rate_hz)
    return stack_margins(controller, PlantStack.of(plants), models)


def stack_margins(controller: Controller, stack: PlantStack, models: Sequence[LoopModel] = (), integrators: Any = 1,
                  unstable: Any = 0, response: np.ndarray | None = None, search: bool = False) -> LoopMargins:
    """:func:`loop_margins` of the loops on the discrete plants ``stack`` of any family (eq. (2)'s or another's).

    ``integrators`` and ``unstable``: the plants' poles at z = 1 and outside the unit circle (a number, or one per
    plant: :func:`nyquist_stable`); eq. (2)'s plant has one integrator. ``models``: eq. (2)'s models of the plants,
    for the delay margin (empty: NaN, another family's). ``response``: the plants' transfer on :func:`margin_grid`
    (a search that tries many controllers on the same plants computes it once). ``search``: a search's
    constraints only (stability, the phase margin, Ms on the grid; no gain margin: inf).
    """
    M = int(stack.d.size)
    lw, L, loop = _on_grid(controller, stack, response)
    Ms, stable = _stable_ms(controller, L, lw, loop, integrators, unstable, refine=not search)
    pm, wgc, cand = phase_margins(loop.at, L, lw, M)
    if search:
        inf = np.full(M, np.inf)
        return LoopMargins(inf, pm, inf, Ms, wgc, inf, stable)
    gm, wpc = gain_margins(loop.at, L, lw, M)
    dm = _delay_margins(loop, models, cand, stable, M) if models else np.full(M, np.nan)
    return LoopMargins(gm, pm, dm, Ms, wgc, wpc, stable)


def margin_response(stack: PlantStack, rate_hz: float) -> np.ndarray:
    """The plants' transfer on :func:`margin_grid` at ``rate_hz`` [Hz] (M, W): the ``response`` of
    :func:`stack_margins` and :func:`stack_sensitivity`, computed once for a scan of many controllers."""
    w = margin_grid(rate_hz, int(stack.d.max()))
    return stack.transfer(np.exp(1j * w / rate_hz))


def stack_sensitivity(controller: Controller, stack: PlantStack, response: np.ndarray | None = None,
                      integrators: Any = 1, unstable: Any = 0) -> tuple[np.ndarray, np.ndarray]:
    """(Ms [-], stable) of each loop on ``stack``: :func:`stack_margins`' Ms (inf when unstable) and stability,
    the same computation bit for bit, without the crossings and the delay margin.

    Why: a scan that reads only Ms (:func:`mrftcli.tune.stacks._inside_ranges`) spent four fifths of its time on
    the figures it drops (``benchmarks/bench_tune_ranges.py`` prints the ratio)."""
    lw, L, loop = _on_grid(controller, stack, response)
    return _stable_ms(controller, L, lw, loop, integrators, unstable)


def _stable_ms(controller: Controller, L: np.ndarray, lw: np.ndarray, loop: "_Loop", integrators: Any, unstable: Any,
               refine: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(Ms [-], inf when unstable; stable) of the loops ``L`` on the log frequencies ``lw``: Ms refined on the
    exact response (:func:`sensitivity_peaks`), or with ``refine`` False the grid's peak (a search's constraint)."""
    stable = nyquist_stable(integrators + (controller.Ki > 0), L, unstable)  # the plant's integrators and the controller's
    Ms = sensitivity_peaks(loop.at, L, lw) if refine else np.max(1.0 / np.abs(1.0 + L), axis=-1)
    return np.where(stable, Ms, np.inf), stable


def _on_grid(controller: Controller, stack: PlantStack,
             response: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, "_Loop"]:
    """(log w on :func:`margin_grid`, the loops L on it (M, W), the loops' exact response for the refinements)."""
    w = margin_grid(controller.rate_hz, int(stack.d.max()))
    if response is None:
        response = stack.transfer(np.exp(1j * w / controller.rate_hz))
    return np.log(w), controller.feedback_response(w)[None, :] * response, _Loop(controller, stack)


At = Callable[[np.ndarray, np.ndarray], np.ndarray]


def phase_margins(at: At, L: np.ndarray, lw: np.ndarray, M: int):
    """Phase margin [deg] of smallest magnitude per row of ``L`` (on the log frequencies ``lw``) and its crossover
    [rad/s]; all the crossovers found (rows, log w, PM [deg]). Each crossing of |L| = 1 is refined (:func:`_root`)
    on ``at(rows, log w)``, the loop's exact response."""
    rows, k = _crossings(np.log(np.abs(L)))
    x = _root(lambda x: np.log(np.abs(at(rows, x))), lw[k], lw[k + 1], _ROOT_STEPS)
    pm_all = np.remainder(np.degrees(np.angle(at(rows, x))), 360.0) - 180.0
    pick = _first_per_row(rows, np.abs(pm_all), M)
    if not rows.size:  # no loop crosses |L| = 1 (a low gain of a search)
        return np.full(M, np.inf), np.full(M, np.nan), (rows, x, pm_all)
    has = pick >= 0
    pm = np.where(has, pm_all[pick], np.inf)
    wgc = np.where(has, np.exp(x[pick]), np.nan)
    return pm, wgc, (rows, x, pm_all)


def gain_margins(at: At, L: np.ndarray, lw: np.ndarray, M: int):
    """Gain margin closest to 1 (in log) over the crossings of the negative real axis, and its frequency
    [rad/s] (refined as :func:`phase_margins`)."""
    rows, k = _crossings(L.imag)
    near = (L.real[rows, k] < 0) | (L.real[rows, k + 1] < 0)
    rows, k = rows[near], k[near]
    x = _root(lambda x: at(rows, x).imag, lw[k], lw[k + 1], _ROOT_STEPS)
    Lx = at(rows, x)
    neg = Lx.real <= 0
    rows, x = rows[neg], x[neg]
    with np.errstate(divide="ignore"):
        gm_all = 1.0 / np.abs(Lx[neg])
        pick = _first_per_row(rows, np.abs(np.log(gm_all)), M)
    if not rows.size:  # no loop crosses the negative real axis
        return np.full(M, np.inf), np.full(M, np.nan)
    has = pick >= 0
    return np.where(has, gm_all[pick], np.inf), np.where(has, np.exp(x[pick]), np.nan)


def sensitivity_peaks(at: Callable[[np.ndarray, np.ndarray], np.ndarray], L: np.ndarray, lw: np.ndarray,
                      n: int = 40) -> np.ndarray:
    """max |1 / (1 + L)| per row of ``L`` (on the log frequencies ``lw``): the grid's peak refined between its
    neighbours by golden section (``n`` steps) on ``at(rows, log w)``, the loop's exact response."""
    dist = np.abs(1.0 + L)
    k = np.argmin(dist, axis=-1)
    rows = np.arange(L.shape[0])
    lo, hi = lw[np.maximum(k - 1, 0)], lw[np.minimum(k + 1, lw.size - 1)]
    both = np.concatenate([rows, rows])  # the two golden-section probes of each row in one evaluation
    x = _golden_min(lambda x: np.abs(1.0 + at(both, x)), lo, hi, n)
    return np.asarray(1.0 / np.minimum(dist[rows, k], np.abs(1.0 + at(rows, x))), float)


def _delay_margins(loop: _Loop, models: Sequence[LoopModel], cand, stable: np.ndarray, M: int) -> np.ndarray:
    """The extra delay [s] at which each stable loop loses stability (module docstring): the smallest
    over its gain crossovers of positive phase margin; inf with none, 0 when unstable."""
    rows, x, pm_all = cand
    keep = (pm_all > 0) & stable[rows]
    rows, x, pm_all = rows[keep], x[keep], pm_all[keep]
    out = np.where(stable, np.inf, 0.0)
    if not rows.size:
        return out
    T = loop.T
    w = np.exp(x)
    ticks = np.floor(np.radians(pm_all) / w / T)  # the last whole tick of delay the crossover survives
    par = {k: np.array([getattr(models[r], k) for r in rows], float) for k in ("Tp", "Td", "tau", "K")}
    rate = loop.c.rate_hz
    span = math.log(1.1)  # the crossover moves little with the hold's fraction: track it within 10 %

    def margin_left(frac: np.ndarray) -> np.ndarray:
        stack = PlantStack.of(plants_of_parameters(par["Tp"], par["Td"], par["tau"] + ticks * T + frac, par["K"],
                                                   rate))

        def log_gain(y: np.ndarray) -> np.ndarray:
            return np.log(np.abs(loop.at(rows, y, stack)))

        lo, hi = x - span, x + span
        g_lo, g_hi = log_gain(lo), log_gain(hi)
        ok = np.sign(g_lo) != np.sign(g_hi)
        xc = np.where(ok, _root(log_gain, lo, hi, _ROOT_STEPS, g_lo, g_hi), x)
        return np.remainder(np.degrees(np.angle(loop.at(rows, xc, stack))), 360.0) - 180.0

    # whole ticks turn the phase by omega j T exactly: the margin left at 0 and at one more tick
    left_0 = pm_all - np.degrees(w * ticks * T)
    left_1 = left_0 - np.degrees(w * T)
    frac = _root(margin_left, np.zeros(rows.size), np.full(rows.size, T), _ROOT_STEPS // 2, left_0, left_1)
    dm = ticks * T + np.clip(frac, 0.0, T)
    np.minimum.at(out, rows, dm)
    return out
