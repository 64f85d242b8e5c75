"""Held-out predictions: each test's cycle predicted by the model identified from the other tests.

One record (:class:`HeldOut`, ``tests[i].held_out`` in every analysis JSON) and its wording
(:func:`held_out_cells`, :func:`held_out_notes`, :meth:`HeldOut.describe`) for every model: the
families' (``analyze --model``, :func:`mrftcli.analyze.general.held_out`) and eq. (2)'s
(:func:`held_out_eq2`).

eq. (2) (``analyze`` without ``--model``): the other tests' mean frequencies, betas and mean
amplitudes are identified by the paper's UFM/UGM point solve (their UFM slices weighted by their
cycle counts, Td where they meet, K the mean of their UGM gains; no bootstrap), and the test's cycle
is that model's exact limit cycle (LPRS closed form) under the test's own beta and relay height. The
prediction's standard deviation is the other tests' standard errors of their means (:func:`mean_sem`:
neighbouring cycles are correlated, so an effective sample size from their lag-1 autocorrelation) propagated
linearly: one more point solve per beta among them (its tests' frequencies moved together), the
amplitudes through K in closed form; ``*_sigma`` is that and the test's own standard error in
quadrature, the scale of ``measured - predicted``, and ``*_z`` the error in those standard
deviations. All the held-out point solves of a log are one vectorised call of
:func:`mrftcli.mrft.consensus.consensus_solve` (a left-out test has weight 0).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import IdentificationError, InputError
from ..mrft.consensus import consensus_solve
from ..mrft.identify import TestMeasurement, identify
from ..mrft.lprs import mrft_limit_cycle, unit_cycle
from ..mrft.model import LoopModel, lead_floor
from ..mrft.sem import mean_sem
from ..segment.records import MrftTest
from .screen import group_betas

__all__ = ["HeldOut", "held_out_eq2", "held_out_cells", "held_out_notes", "mean_sem", "NOTHING_HELD_OUT",
           "lead_held_out_refusal", "LEAD_MISS_Z", "MISS_WORDS", "ROUTE_POINTS", "ROUTE_FUNDAMENTALS"]

#: :attr:`HeldOut.route` of eq. (2)'s prediction from the other tests' fundamental and 3rd-harmonic response points
ROUTE_POINTS = "response_points"
#: :attr:`HeldOut.route` of eq. (2)'s prediction from the other tests' fundamentals (the UFM/UGM point solve)
ROUTE_FUNDAMENTALS = "fundamentals"

_ONE_OTHER = ("the other test alone does not determine Td and tau (eq. (2) needs two betas): a third test would "
              "check each test against the others")
_ONE_BETA = "the other tests share one beta and do not determine Td and tau (eq. (2) needs two betas)"
#: the note of a flight with one usable test
NOTHING_HELD_OUT = "the only test: nothing is held out (no other test to predict it from)"


def _opt(x: Any) -> float | None:
    return None if x is None else float(x)


@dataclass(frozen=True)
class HeldOut:
    """A test's cycle predicted by the model identified from the other tests.

    Attributes
    ----------
    frequency_hz, amplitude : float or None
        Predicted frequency [Hz] and amplitude [output units]; None when the other tests do not
        determine the model (``note`` says why).
    note : str
        Why there is no prediction (or what qualifies it), or ``""``.
    frequency_sigma_hz, amplitude_sigma : float or None
        Standard deviation of ``measured - predicted`` [Hz], [output units]: the prediction's own
        (the other tests' standard errors propagated) and the measured mean's in quadrature; None
        where the route does not state one (the families' ``analyze --model`` today).
    frequency_z, amplitude_z : float or None
        ``(measured - predicted) / sigma`` [-]; None without a sigma.
    route : str
        Which route made eq. (2)'s prediction: :data:`ROUTE_POINTS` (the other tests' fundamental and 3rd-harmonic
        response points, :mod:`~mrftcli.analyze.held_out_harmonic`) or :data:`ROUTE_FUNDAMENTALS` (their
        fundamentals' UFM/UGM point solve, :func:`held_out_eq2`); ``""`` without a prediction, for the families
        (one route) and in records written before the key (JSON ``route``, written only when set).
    """

    frequency_hz: float | None
    amplitude: float | None
    note: str = ""
    frequency_sigma_hz: float | None = None
    amplitude_sigma: float | None = None
    frequency_z: float | None = None
    amplitude_z: float | None = None
    route: str = ""

    def to_json(self) -> dict[str, Any]:
        out = {"frequency_hz": self.frequency_hz, "amplitude": self.amplitude, "note": self.note,
               "frequency_sigma_hz": self.frequency_sigma_hz, "amplitude_sigma": self.amplitude_sigma,
               "frequency_z": self.frequency_z, "amplitude_z": self.amplitude_z}
        # additive: a record without a route (older, or the families') keeps its keys as they were written
        return {**out, "route": self.route} if self.route else out

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> HeldOut:
        """The record of a ``held_out`` object (the sigma, z and route keys may be absent: older records)."""
        sf, sa, zf, za = (_opt(data.get(k)) for k in ("frequency_sigma_hz", "amplitude_sigma", "frequency_z",
                                                      "amplitude_z"))
        return cls(_opt(data.get("frequency_hz")), _opt(data.get("amplitude")), str(data.get("note", "")),
                   sf, sa, zf, za, str(data.get("route") or ""))

    @classmethod
    def against(cls, frequency_hz: float, amplitude: float, measured: tuple[float, float, float, float],
                spread: tuple[float, float], note: str = "", route: str = "") -> HeldOut:
        """A prediction with its sigma and z against the measured means.

        ``measured``: frequency [Hz], its standard error [Hz], amplitude, its standard error [output
        units]; ``spread``: the prediction's standard deviation in frequency [Hz] and amplitude.
        """
        f_m, f_se, a_m, a_se = measured
        sf, sa = math.hypot(f_se, spread[0]), math.hypot(a_se, spread[1])
        return cls(frequency_hz, amplitude, note, sf, sa, (f_m - frequency_hz) / sf if sf > 0 else None,
                   (a_m - amplitude) / sa if sa > 0 else None, route)

    def describe(self, frequency_hz: float, amplitude: float, unit: str) -> str:
        """One line beside the measured values, e.g. ``f 0.7732 ± 0.0022 Hz (measured 0.8417, +30.6 std),
        amplitude 0.1038 ± 0.00054 m (measured 0.08687, -31.6 std)``; the note where there is no prediction."""
        if self.frequency_hz is None or self.amplitude is None:
            return self.note or "none"

        def part(value: str, sigma: float | None, z: float | None, measured: str) -> tuple[str, str]:
            spread = "" if sigma is None else f" ± {_num(sigma, 2)}"
            return f"{value}{spread}", f"(measured {measured}" + ("" if z is None else f", {z:+.1f} std") + ")"

        f, f_m = part(f"{self.frequency_hz:.4f}", self.frequency_sigma_hz, self.frequency_z, f"{frequency_hz:.4f}")
        a, a_m = part(f"{self.amplitude:.4g}", self.amplitude_sigma, self.amplitude_z, f"{amplitude:.4g}")
        return f"f {f} Hz {f_m}, amplitude {a} {unit} {a_m}" + (f"; {self.note}" if self.note else "")


def _num(x: float | None, digits: int = 4) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x:#.{digits}g}".rstrip(".")


def held_out_cells(ho: HeldOut | None) -> tuple[str, str]:
    """The table's held-out frequency and amplitude cells: the prediction, ``± sigma`` and the error in
    std where there is one (``0.7731 ± 0.0042 (+0.2)``), ``-`` where there is no prediction."""
    if ho is None:
        return "-", "-"

    def cell(value: float | None, sigma: float | None, z: float | None, digits: int) -> str:
        if value is None:
            return "-"
        text = _num(value, digits)
        if sigma is not None:
            text += f" ± {_num(sigma, 2)}"
        return text + (f" ({z:+.1f})" if z is not None else "")

    return (cell(ho.frequency_hz, ho.frequency_sigma_hz, ho.frequency_z, 4),
            cell(ho.amplitude, ho.amplitude_sigma, ho.amplitude_z, 3))


def held_out_notes(held: Sequence[HeldOut | None], numbers: Sequence[int] | None = None) -> list[str]:
    """One line per distinct note, naming the tests it applies to: by ``numbers`` (the test numbers the
    table shows, one per entry of ``held``) or, without them, 1-based in ``held``'s order."""
    labels = [k + 1 for k in range(len(held))] if numbers is None else list(numbers)
    by_note: dict[str, list[str]] = {}
    for label, ho in zip(labels, held):
        if ho is not None and ho.note:
            by_note.setdefault(ho.note, []).append(str(label))
    return [f"held-out test{'s' if len(ix) > 1 else ''} {', '.join(ix)}: {note}" for note, ix in by_note.items()]


# ----------------------------------------------------------------------------------------------
# eq. (2)
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Sets:
    """The point solves of every held-out fit in one vectorised call: row r leaves out test ``left[r]``
    (weight 0) and moves the frequencies of the tests ``moved[r]`` (the others at one beta) by their
    standard errors (empty: none, the prediction itself)."""

    left: np.ndarray
    moved: list[list[int]]
    omegas: np.ndarray
    weights: np.ndarray


def _sets(tests: list[MrftTest], groups: list[list[int]], usable: list[int]) -> _Sets:
    n = len(tests)
    w0 = 2 * math.pi * np.array([t.frequency_hz_mean for t in tests])
    se = 2 * math.pi * np.array([mean_sem(t.frequency_hz) for t in tests])
    ncyc = np.array([float(t.n_stable) for t in tests])  # the paper's weights: the cycle counts
    left: list[int] = []
    moved: list[list[int]] = []
    omegas, weights = [], []
    for i in usable:
        moves = [m for g in groups if (m := [j for j in g if j != i]) and np.any(se[m] > 0)]
        for members in [[], *moves]:
            w = w0.copy()
            w[members] += se[members]
            left.append(i)
            moved.append(members)
            omegas.append(w)
            weights.append(np.where(np.arange(n) == i, 0.0, ncyc))
    return _Sets(np.array(left, int), moved, np.array(omegas).reshape(-1, n), np.array(weights).reshape(-1, n))


def _gains(Tp: float, Td: np.ndarray, sets: _Sets, amps: np.ndarray, hs: np.ndarray) -> np.ndarray:
    """K of every test in every row (UGM, Lemmas 2 and 4: a = h K Td a_unit(Tp w, Td w) / w)."""
    _, a_unit = unit_cycle(Tp * sets.omegas, Td[:, None] * sets.omegas, np.zeros_like(sets.omegas))
    return np.asarray(amps[None, :] * sets.omegas / (hs[None, :] * Td[:, None] * a_unit))


def _prediction(model: LoopModel, Td: float, tau: float, K: float, beta: float, h: float) -> tuple[float, float] | str | None:
    """The cycle [Hz], [output units] of ``model`` (eq. (2), its known Tp) at Td, tau, K; None where the others give
    no model; a note (containing :data:`MISS_WORDS`) where their model has no cycle at ``beta``, where one was flown."""
    if not (math.isfinite(Td) and math.isfinite(tau) and math.isfinite(K) and K > 0):
        return None
    if tau < lead_floor(model.Tp):
        return (f"the other tests give a lead of {-tau * 1e3:.3g} ms, beyond the {-lead_floor(model.Tp) * 1e3:.3g} ms "
                f"eq. (2) admits: {MISS_WORDS}")
    try:
        lc = mrft_limit_cycle(model.with_parameters(Td=Td, tau=tau, K=K), beta, h)
    except IdentificationError:
        if tau >= 0:
            return None
        return (f"eq. (2) from the other tests (tau {tau * 1e3:.3g} ms, a lead) has no cycle at beta {beta:.3g}, "
                f"where one was flown: {MISS_WORDS}")
    except (InputError, ValueError):
        return None
    return float(lc.frequency_hz), float(lc.amplitude)


#: how a held-out note that counts as a miss ends (the others' model predicts no cycle where one was flown)
MISS_WORDS = "a held-out miss"
#: a lead whose held-out tests miss by more than this many stated std is refused (:func:`lead_held_out_refusal`)
LEAD_MISS_Z = 5.0


def lead_held_out_refusal(held: Sequence[HeldOut], tau: float) -> str | None:
    """The one-line refusal of a lead (``tau`` [s] < 0) whose held-out tests miss, or None.

    A Tp given too large reads as a lead within :func:`~mrftcli.mrft.model.lead_floor` on some logs; the tests
    then disagree with each other: a test predicted from the others misses by more than :data:`LEAD_MISS_Z` of its
    stated std (on PX4 SIH's pitch at Tp 10x too large, 10 std), or the others' model has no cycle where one was
    flown. An estimator's lead at the right Tp held out within 2 std on every lead log measured (docs/method.md 4).
    """
    if not tau < 0:
        return None
    zs = [abs(z) for h in held for z in (h.frequency_z, h.amplitude_z) if z is not None and math.isfinite(z)]
    misses = sum(MISS_WORDS in h.note for h in held)
    worst = max(zs, default=0.0)
    if worst <= LEAD_MISS_Z and not misses:
        return None
    why = (f"a test held out misses by {worst:.3g} std" if worst > LEAD_MISS_Z else
           f"{misses} test(s) held out have no cycle in the others' model")
    return (f"the lead tau = {tau * 1e3:.3g} ms comes with tests that disagree ({why}; an estimator's lead holds "
            f"them within {LEAD_MISS_Z:g}): a Tp given too large reads as a lead; check --tp")


def held_out_eq2(model: LoopModel, tests: Sequence[MrftTest], betas: Sequence[float],
                 Td_ref: float | None = None) -> tuple[HeldOut, ...]:
    """Each test's cycle predicted by eq. (2) identified from the other tests (module docstring).

    Parameters
    ----------
    model : LoopModel
        Eq. (2) with its known Tp [s] (``soiptd_model(Tp)``).
    tests : sequence of MrftTest
        The usable tests.
    betas : sequence of float
        The beta each test is identified with (:func:`mrftcli.analyze.estimate.beta_used`).
    Td_ref : float or None
        Centre of the point solves' search [s] (0.1-10 times it), e.g. the estimate from all tests;
        None: their UFM estimate (:func:`mrftcli.mrft.identify.identify`).

    Returns
    -------
    tuple of HeldOut
        One per test, in ``tests``' order.
    """
    tests = list(tests)
    if len(tests) < 2:
        return tuple(HeldOut(None, None, NOTHING_HELD_OUT) for _ in tests)
    groups = group_betas(tests)
    out: list[HeldOut | None] = [None] * len(tests)
    usable = []
    for i in range(len(tests)):
        if sum(1 for g in groups if set(g) - {i}) < 2:
            out[i] = HeldOut(None, None, _ONE_BETA if len(tests) > 2 else _ONE_OTHER)
        else:
            usable.append(i)
    if usable:
        for i, ho in zip(usable, _solve(model, tests, np.asarray(betas, float), groups, usable, Td_ref)):
            out[i] = ho
    return tuple(o for o in out if o is not None)


def _solve(model: LoopModel, tests: list[MrftTest], betas: np.ndarray, groups: list[list[int]], usable: list[int],
           Td_ref: float | None) -> list[HeldOut]:
    """The held-out predictions of the ``usable`` tests: one vectorised UFM consensus for all their fits."""
    Tp = model.Tp
    if Td_ref is None:
        Td_ref = identify([TestMeasurement(b, t.frequency_hz_mean) for t, b in zip(tests, betas)], model).Td.value
    sets = _sets(tests, groups, usable)
    Td, tau = consensus_solve(Tp, np.broadcast_to(betas, sets.omegas.shape), sets.omegas, sets.weights, Td_ref)
    amps = np.array([t.amplitude_mean for t in tests])
    hs = np.array([t.h for t in tests])
    K_each = _gains(Tp, Td, sets, amps, hs)
    a_se = np.array([mean_sem(t.amplitude) for t in tests])
    results = []
    for i in usable:
        rows = np.flatnonzero(sets.left == i)
        others = sets.weights[rows[0]] > 0
        base = rows[0]  # the first row of a test moves nothing
        K = float(np.mean(K_each[base][others]))
        centre = _prediction(model, float(Td[base]), float(tau[base]), K, float(betas[i]), tests[i].h)
        if not isinstance(centre, tuple):
            results.append(HeldOut(None, None, centre or "the other tests give no eq. (2) model: their UFM slices "
                                                         f"do not meet within 0.1-10 x Td {Td_ref:.3g} s"))
            continue
        var_f = var_a = 0.0
        lost = 0
        for r in rows[1:]:
            se = _freq_se(tests, sets.moved[r])
            scale = float(np.sum(se ** 2) / np.sum(se) ** 2)
            moved = _prediction(model, float(Td[r]), float(tau[r]), float(np.mean(K_each[r][others])),
                                float(betas[i]), tests[i].h)
            if isinstance(moved, tuple):
                var_f += (moved[0] - centre[0]) ** 2 * scale
                var_a += (moved[1] - centre[1]) ** 2 * scale
            else:  # the solve one std away gives no cycle: its share is not in the std, which the note says
                lost += 1
        # the amplitudes move K only (K is the mean of the others' UGM gains): linear, no solve
        dK = K_each[base][others] * a_se[others] / amps[others] / others.sum()
        var_a += float(np.sum(dK ** 2)) * (centre[1] / K) ** 2
        t = tests[i]
        measured = (t.frequency_hz_mean, mean_sem(t.frequency_hz), t.amplitude_mean, mean_sem(t.amplitude))
        note = (f"{lost} of {len(rows) - 1} solves one std away give no cycle: the std leaves them out, "
                "so it is understated" if lost else "")
        results.append(HeldOut.against(*centre, measured, (math.sqrt(var_f), math.sqrt(var_a)), note,
                                       ROUTE_FUNDAMENTALS))
    return results


def _freq_se(tests: list[MrftTest], group: list[int]) -> np.ndarray:
    return np.array([mean_sem(tests[j].frequency_hz) for j in group])
