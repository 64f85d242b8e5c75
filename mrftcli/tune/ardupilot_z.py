"""ArduPilot's altitude cascade (``AC_PosControl::update_z_controller``) designed for every split of tau.

**The cascade** (ArduPilot/ardupilot ``libraries/AC_AttitudeControl/AC_PosControl.cpp`` @46d6887e, Copter 4.x;
``AC_PID.cpp``, ``AC_PID_Basic.cpp``, ``AP_MotorsMulticopter.cpp``), run every main-loop tick T:

* velocity target [cm/s] = ``PSC_POSZ_P`` x (altitude target - the EKF's altitude) (``AC_P_1D``: linear for
  small errors);
* acceleration target [cm/s^2] = the ``AC_PID_Basic`` ``PSC_VELZ_P``/``_I`` of the velocity error (the EKF's
  vertical velocity), the error through ``PSC_VELZ_FLTE``; ``_D`` and ``_FF`` 0;
* throttle = ``MOT_THST_HOVER`` + 0.001 x the ``AC_PID`` ``PSC_ACCZ_P``/``_I`` of (the target through
  ``PSC_ACCZ_FLTT`` - ``get_z_accel_cmss()``, the IMU's earth-frame vertical acceleration through
  ``INS_ACCEL_FILTER``), the error through ``PSC_ACCZ_FLTE``; ``_D`` and ``_FF`` 0;
* the throttle reaches the motors through a 2 Hz first-order low-pass (``set_throttle_out(...,
  POSCONTROL_THROTTLE_CUTOFF_FREQ_HZ)``, ``AP_MotorsMulticopter::update_throttle_filter``).

ArduPilot's first-order filters are y_k = y_{k-1} + alpha (x_k - y_{k-1}), alpha = T / (T + 1 / (2 pi f))
(f = 0: off); its integrators add Ki e_k T before the output. Broken at the throttle, with eq. (2)'s states
x = [z, v, thrust] giving the altitude z, the velocity v and the acceleration a = -v / Td + K x3, each measured
with its own delay, the loop is (SI units: 0.001 x 100 cm/m = 0.1)

    L = 0.1 F_thr E_a (P_a + I_a T z/(z-1)) [F_acc G_a + F_T E_v (P_v + I_v T z/(z-1)) (G_v + P_z G_z)]

with G_a, G_v, G_z the exact zero-order-hold transfers of the three outputs (their delays in the hold and
z^-d, :class:`mrftcli.tune.closed_loop.PlantStack`), F_acc ``INS_ACCEL_FILTER``'s 2nd-order Butterworth at the
loop rate (as the gyro filter is modelled), F_thr, F_T, E_a, E_v the first-order filters above.

**The split of tau.** One altitude MRFT identifies one delay tau, from the throttle to the measured altitude:
the actuator's part and the altitude measurement's, lumped. The accelerometer sees the actuator's part alone;
the EKF's velocity and altitude some of the rest each. The split is not identifiable from one altitude test,
so every figure is the worst over a grid of splits (:func:`split_grid`): the actuator's delay tau_a at 0, 1/4,
1/2, 3/4 and all of tau, and the velocity's and the altitude's measurement delays each at 0, half and all of
tau - tau_a (37 splits).

**The design** (:func:`design_z_cascade`), from tune's PD u = Kp e - Kd v: P_z = Kp / Kd; the acceleration
feedback 0.1 P_a a divides the low-frequency loop gain by 1 + 0.1 P_a K, so P_v = g (1 + 0.1 P_a K) Kd /
(0.1 P_a) keeps the PD's loop at g = 1. ``PSC_ACCZ_I`` must be > 0 (``AC_PosControl::pre_arm_checks``: "PSC_ACCZ_I
must be > 0"), so the acceleration loop is a PI, I_a = r P_a (ArduPilot's default r = 2: P 0.5, I 1.0). For each
``PSC_ACCZ_P`` candidate the largest g <= 1 at which every loop is stable with Ms at most the PD's own is found
(a scan down over the g that keep ``PSC_VELZ_P`` in its range, then bisection); "every loop" is every split of
tau of the nominal model and of the posterior's 95 % set's extreme draws (:func:`robust_models`: the smallest
and largest tau, K, Td and Tp, each over its own splits), and the PD's Ms is its worst over the same models,
so the cascade is robust as tune's robust design is. The candidates are tried in increasing P_a until one
keeps less than the best so far; r is tried from the smallest (0.1) up, and the largest r that keeps at
least 95 % of the smallest r's g is exported (a stronger integral costs phase at the crossover). The
ranges are the chosen version's (:func:`mrftcli.tune.ardupilot_versions.z_bounds`). ``PSC_VELZ_I`` is set at
0.02 (4.6's documented minimum), in the margins.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError
from ..mrft.model import LoopModel
from .closed_loop import Controller, PlantStack, RateFilter, plants_of_parameters
from .margins import (Margins, gain_margins, largest_holding, margin_grid, nyquist_stable, phase_margins,
                      sensitivity_peaks)
from .ardupilot_versions import z_bounds

__all__ = ["DelaySplit", "ZCascadeGains", "ZCascadeFigures", "ZCascadeDesign", "split_grid", "cascade_loop",
           "cascade_figures", "design_z_cascade", "split_assumption", "THROTTLE_CUTOFF_HZ", "ACCZ_P_CANDIDATES",
           "ACCZ_I_RATIOS", "robust_models", "margins_qualifier"]

#: ``POSCONTROL_THROTTLE_CUTOFF_FREQ_HZ`` [Hz] (AC_PosControl.h): the motors' first-order throttle filter in the z loop.
THROTTLE_CUTOFF_HZ = 2.0
#: ``PSC_ACCZ_P`` values tried [(throttle/1000)/(cm/s^2)], within ArduPilot's 0.2-1.5.
ACCZ_P_CANDIDATES = (0.2, 0.25, 0.3, 0.4, 0.5, 0.6, 0.75, 1.0, 1.5)
#: ``PSC_ACCZ_I`` / ``PSC_ACCZ_P`` ratios tried [1/s], from the smallest (ArduPilot's default is 2).
ACCZ_I_RATIOS = (0.1, 0.2, 0.5, 1.0, 2.0)
#: A larger integral is kept while g stays within this fraction of the smallest ratio's.
_I_KEEP = 0.95
#: VELZ_I written [(cm/s^2)/cm]: 4.6's documented minimum (4.7's is 0).
_VELZ_I = 0.02
#: Bisection steps on log g between two scan points (to 0.15 %).
_STEPS = 8
#: Points of the downward scan of g over its range.
_SCAN = 10
_G_MIN = 0.05


@dataclass(frozen=True)
class DelaySplit:
    """One split of the identified tau [s]: the actuator's part and each measurement's beyond it.

    Attributes
    ----------
    actuator_s : float
        Throttle -> thrust delay [s]: the acceleration loop's (the IMU's own is taken as 0).
    velocity_s, altitude_s : float
        The EKF velocity's and altitude's delays beyond the actuator's [s].
    """

    actuator_s: float
    velocity_s: float
    altitude_s: float

    def describe(self) -> str:
        return (f"actuator {self.actuator_s * 1e3:.1f} ms, velocity +{self.velocity_s * 1e3:.1f} ms, altitude "
                f"+{self.altitude_s * 1e3:.1f} ms")


def split_grid(tau: float, n: int = 4) -> tuple[DelaySplit, ...]:
    """The splits of ``tau`` [s] the figures are the worst over: tau_a = tau i / n, i = 0..n; each measurement's
    delay at 0, half and all of tau - tau_a (one split at tau_a = tau): 9 n + 1 splits."""
    out = []
    for i in range(n + 1):
        ta = tau * i / n
        rest = max(tau - ta, 0.0)
        fractions = (0.0, 0.5, 1.0) if rest > 0 else (0.0,)
        out += [DelaySplit(ta, fv * rest, fz * rest) for fv in fractions for fz in fractions]
    return tuple(out)


@dataclass(frozen=True)
class ZCascadeGains:
    """The AC_PosControl z gains and filters of one design, in ArduPilot's units.

    Attributes
    ----------
    pos_p : float
        ``PSC_POSZ_P`` [(cm/s)/cm].
    vel_p, vel_i : float
        ``PSC_VELZ_P`` [(cm/s^2)/(cm/s)], ``PSC_VELZ_I`` [(cm/s^2)/cm].
    vel_flte_hz : float
        ``PSC_VELZ_FLTE`` [Hz] (0: off).
    acc_p, acc_i : float
        ``PSC_ACCZ_P`` [(throttle/1000)/(cm/s^2)], ``PSC_ACCZ_I`` [(throttle/1000)/(cm/s)].
    acc_flte_hz, acc_fltt_hz : float
        ``PSC_ACCZ_FLTE``, ``PSC_ACCZ_FLTT`` [Hz] (0: off).
    accel_filter_hz : float
        ``INS_ACCEL_FILTER`` [Hz].
    rate_hz : float
        The loop rate (``SCHED_LOOP_RATE``) [Hz].
    """

    pos_p: float
    vel_p: float
    vel_i: float
    vel_flte_hz: float
    acc_p: float
    acc_i: float
    acc_flte_hz: float
    acc_fltt_hz: float
    accel_filter_hz: float
    rate_hz: float

    def params(self) -> dict[str, float]:
        """The values the ``.param`` file sets (``PSC_ACCZ_FLTT`` is not written: 0, ArduPilot's default, is
        below its documented range; the design runs with it off)."""
        return {"PSC_POSZ_P": self.pos_p, "PSC_VELZ_P": self.vel_p, "PSC_VELZ_I": self.vel_i, "PSC_VELZ_D": 0.0,
                "PSC_VELZ_FF": 0.0, "PSC_VELZ_FLTE": self.vel_flte_hz, "PSC_ACCZ_P": self.acc_p,
                "PSC_ACCZ_I": self.acc_i, "PSC_ACCZ_D": 0.0, "PSC_ACCZ_FF": 0.0, "PSC_ACCZ_FLTE": self.acc_flte_hz,
                "INS_ACCEL_FILTER": self.accel_filter_hz}

    @classmethod
    def from_params(cls, p: dict[str, float], rate_hz: float) -> "ZCascadeGains":
        """The gains of a ``.param`` mapping (``PSC_ACCZ_FLTT`` absent: off)."""
        return cls(p["PSC_POSZ_P"], p["PSC_VELZ_P"], p["PSC_VELZ_I"], p["PSC_VELZ_FLTE"], p["PSC_ACCZ_P"],
                   p["PSC_ACCZ_I"], p["PSC_ACCZ_FLTE"], p.get("PSC_ACCZ_FLTT", 0.0), p["INS_ACCEL_FILTER"], rate_hz)

    @property
    def integrators(self) -> int:
        """Integrators of the loop at z = 1: the plant's and each nonzero integral gain's."""
        return 1 + (self.vel_i > 0) + (self.acc_i > 0)


def _first_order(cutoff_hz: float, rate_hz: float, z: np.ndarray) -> np.ndarray:
    """ArduPilot's first-order low-pass alpha / (1 - (1 - alpha) z^-1) at ``z`` (cutoff 0: 1)."""
    if cutoff_hz <= 0:
        return np.ones_like(z)
    T = 1.0 / rate_hz
    alpha = T / (T + 1.0 / (2.0 * math.pi * cutoff_hz))
    return alpha / (1.0 - (1.0 - alpha) / z)


@dataclass(frozen=True, eq=False)
class _Paths:
    """The plant's three measured outputs for every (model, split) row: acceleration, velocity, altitude."""

    acc: PlantStack
    vel: PlantStack
    alt: PlantStack

    def take(self, rows: np.ndarray) -> "_Paths":
        return _Paths(self.acc.take(rows), self.vel.take(rows), self.alt.take(rows))


def _paths(models: Sequence[LoopModel], splits: Sequence[DelaySplit], rate_hz: float) -> _Paths:
    return _paths_of([(m, s) for m in models for s in splits], rate_hz)


def _paths_of(rows: Sequence[tuple[LoopModel, DelaySplit]], rate_hz: float) -> _Paths:
    """The three outputs of each (model, split) row."""
    Tp, Td, K = (np.array([getattr(m, k) for m, _ in rows], float) for k in ("Tp", "Td", "K"))
    ta = np.array([s.actuator_s for _, s in rows])

    def stack(delay: np.ndarray, C: np.ndarray) -> PlantStack:
        st = PlantStack.of(plants_of_parameters(Tp, Td, delay, K, rate_hz))
        return replace(st, C=C)

    zero = np.zeros(len(rows))
    return _Paths(stack(ta, np.column_stack([zero, -1.0 / Td, K])),
                  stack(ta + np.array([s.velocity_s for _, s in rows]), np.column_stack([zero, 1.0 + zero, zero])),
                  stack(ta + np.array([s.altitude_s for _, s in rows]), np.column_stack([1.0 + zero, zero, zero])))


def cascade_loop(g: ZCascadeGains, paths: _Paths, z: np.ndarray) -> np.ndarray:
    """L at the points ``z`` ((1, W) for all rows, or (R, 1) with ``paths`` taken to R rows): shape (rows, W)."""
    parts = _Parts(z, g.rate_hz, paths.acc.transfer(z), paths.vel.transfer(z), paths.alt.transfer(z))
    return np.asarray(_loop_of(g, parts), complex)


class _Parts:
    """The loop's factors at ``z``: the plant's three responses (G_a, G_v, G_z) and the filters, by
    ``part(key, value)`` (kept across gains: the search's cache)."""

    def __init__(self, z: np.ndarray, rate_hz: float, Ga: np.ndarray, Gv: np.ndarray, Gz: np.ndarray) -> None:
        self.z, self.rate_hz, self.Ga, self.Gv, self.Gz = z, rate_hz, Ga, Gv, Gz
        self._cache: dict[tuple[str, float], np.ndarray] = {}

    def part(self, key: str, value: float) -> np.ndarray:
        """``pz``: G_v + P_z G_z; ``ins``: INS_ACCEL_FILTER times G_a; ``f``: a first-order filter at ``value`` Hz."""
        k = (key, value)
        if k in self._cache:
            return self._cache[k]
        r, z = self.rate_hz, self.z
        if key == "pz":
            out = self.Gv + value * self.Gz
        elif key == "ins":
            out = RateFilter(value).response(z, r) * self.Ga
        else:
            out = _first_order(value, r, z)
        self._cache[k] = out
        return out


def _loop_of(g: ZCascadeGains, parts: _Parts) -> np.ndarray:
    """L from the loop's factors (:class:`_Parts`, the search keeps them across gains)."""
    integ = (1.0 / parts.rate_hz) * parts.z / (parts.z - 1.0)
    Cv = parts.part("f", g.vel_flte_hz) * (g.vel_p + g.vel_i * integ)
    Ca = parts.part("f", g.acc_flte_hz) * (g.acc_p + g.acc_i * integ)
    inner = parts.part("ins", g.accel_filter_hz) + parts.part("f", g.acc_fltt_hz) * Cv * parts.part("pz", g.pos_p)
    L: np.ndarray = 0.1 * parts.part("f", THROTTLE_CUTOFF_HZ) * Ca * inner
    return L


@dataclass(frozen=True)
class ZCascadeFigures:
    """Per (model, split) row: the margins of the cascade's loop, and the worst over the rows."""

    per_row: tuple[Margins, ...]
    splits: tuple[DelaySplit, ...]

    def worst(self) -> Margins:
        """Smallest GM, PM and delay margin, largest Ms (its row's crossovers), stable only if every row is."""
        return _worst(self.per_row)

    def worst_split(self) -> DelaySplit:
        """The split of the largest Ms (rows cycle through the splits per model)."""
        i = max(range(len(self.per_row)), key=lambda k: self.per_row[k].Ms)
        return self.splits[i % len(self.splits)]


def cascade_figures(g: ZCascadeGains, models: Sequence[LoopModel], splits: Sequence[DelaySplit]) -> ZCascadeFigures:
    """GM, PM, delay margin, Ms and stability of the cascade on every (model, split).

    Stability is the Nyquist criterion on the unit circle (open loop: poles inside, :attr:`integrators` at
    z = 1 indented); crossings are bracketed on :func:`mrftcli.tune.margins.margin_grid` and refined as eq. (2)'s; Ms is
    the grid's peak refined by golden section; the delay margin is PM / w_gc at each gain crossover of positive
    margin (exact for an extra delay of whole ticks, the hold's fraction aside).
    """
    r = g.rate_hz
    T = 1.0 / r
    d_max = int(max(s.actuator_s + max(s.velocity_s, s.altitude_s) for s in splits) * r) + 1
    w = margin_grid(r, d_max)
    lw = np.log(w)
    paths = _paths(models, splits, r)
    L = cascade_loop(g, paths, np.exp(1j * w * T)[None, :])
    M = L.shape[0]

    def at(rows: np.ndarray, x: np.ndarray) -> np.ndarray:
        return cascade_loop(g, paths.take(rows), np.exp(1j * np.exp(x) * T)[:, None])[:, 0]

    stable = nyquist_stable(g.integrators, L)
    pm, wgc, (rows, x, pm_all) = phase_margins(at, L, lw, M)
    gm, wpc = gain_margins(at, L, lw, M)
    dm = np.where(stable, np.inf, 0.0)
    for i, xi, p in zip(rows, x, pm_all):  # PM / w_gc at each gain crossover of positive margin
        if p > 0 and stable[i]:
            dm[i] = min(dm[i], math.radians(p) / math.exp(xi))
    Ms = sensitivity_peaks(at, L, lw, 30)
    out = tuple(Margins(float(gm[i]), float(pm[i]), float(dm[i]), float(Ms[i]) if stable[i] else math.inf,
                        float(wgc[i]), float(wpc[i]), bool(stable[i])) for i in range(M))
    return ZCascadeFigures(out, tuple(splits))


@dataclass(frozen=True)
class ZCascadeDesign:
    """The exported cascade, how it was chosen, and its worst figures over the splits.

    Attributes
    ----------
    gains : ZCascadeGains
    kept : float
        g: the fraction of the PD's loop gain the cascade keeps (1: the PD's low-frequency loop).
    ms_target : float
        The Ms every loop is held to: the PD's own worst over the nominal model and :attr:`models` [-].
    figures : ZCascadeFigures
        Per split, on the nominal model.
    tau : float
        The identified delay that was split [s].
    tried : tuple of (float, float, float)
        Per (``PSC_ACCZ_I`` / ``PSC_ACCZ_P`` ratio, ``PSC_ACCZ_P``) tried, the largest g found (0: none holds).
    robust : Margins
        The worst over the nominal model and :attr:`models`, each over its own splits of tau.
    models : tuple of LoopModel
        The posterior draws the design holds the Ms on besides the nominal model (empty: none given).
    """

    gains: ZCascadeGains
    kept: float
    ms_target: float
    figures: ZCascadeFigures
    tau: float
    tried: tuple[tuple[float, float, float], ...]
    robust: Margins
    models: tuple[LoopModel, ...] = ()


def split_assumption(tau: float, n_splits: int) -> str:
    """The stated assumption (first lines of the output and the JSON)."""
    return (f"the split of tau {tau * 1e3:.0f} ms between the motors and the sensors is not identifiable from one "
            f"altitude test: the margins hold for every split ({n_splits} on a grid: the actuator's delay, which the "
            "accelerometer loop sees, from 0 to tau; the EKF velocity's and altitude's each from 0 to the rest)")


def robust_models(models: Sequence[LoopModel]) -> tuple[LoopModel, ...]:
    """The draws the cascade is held on: the smallest and the largest tau, K, Td and Tp of ``models`` (the
    posterior's 95 % set), without repeats (at most 8)."""
    if not models:
        return ()
    idx: list[int] = []
    for key in ("tau", "K", "Td", "Tp"):
        v = [getattr(m, key) for m in models]
        for i in (int(np.argmin(v)), int(np.argmax(v))):
            if i not in idx:
                idx.append(i)
    return tuple(models[i] for i in idx)


def robust_figures(g: ZCascadeGains, models: Sequence[LoopModel]) -> Margins:
    """The worst margins of ``g`` over ``models``, each over its own splits of tau."""
    return _worst([cascade_figures(g, [m], split_grid(m.tau)).worst() for m in models])


def _worst(rows: Sequence[Margins]) -> Margins:
    """Smallest GM, PM and delay margin, largest Ms (its row's crossovers), stable only if every row is."""
    w = max(rows, key=lambda m: m.Ms)
    return Margins(min(m.gain_margin for m in rows), min(m.phase_margin_deg for m in rows),
                   min(m.delay_margin_s for m in rows), w.Ms, w.w_gc, w.w_pc, all(m.stable for m in rows))


def _gains(pz: float, pv: float, pa: float, ai: float, rate_hz: float) -> ZCascadeGains:
    """The gains with ArduPilot's filter defaults (``PSC_VELZ_FLTE`` 5 Hz, ``PSC_ACCZ_FLTE`` 20 Hz,
    ``INS_ACCEL_FILTER`` 20 Hz), ``PSC_VELZ_I`` 0.02 and ``PSC_ACCZ_I`` ``ai``."""
    return ZCascadeGains(pz, pv, _VELZ_I, 5.0, pa, ai, 20.0, 0.0, 20.0, rate_hz)


class _Check:
    """Whether gains hold: every (model, split) row's loop stable with its grid Ms at most the target (the
    search's test; the reported figures are :func:`cascade_figures`'s, refined). The plant's and the fixed
    filters' responses are kept (:class:`_Parts`); the loop is :func:`_loop_of`'s."""

    def __init__(self, models: Sequence[LoopModel], rate_hz: float, ms_target: float) -> None:
        # the nominal model (first) over the full grid of splits, the draws over a coarser one (n = 2: 19)
        rows = [(m, s) for i, m in enumerate(models) for s in split_grid(m.tau, 4 if i == 0 else 2)]
        d_max = int(max(s.actuator_s + max(s.velocity_s, s.altitude_s) for _, s in rows) * rate_hz) + 1
        # the search's grid: margin_grid's linear part (the delays' phase) and 300 log points from 1e-6 of
        # Nyquist (the reported figures use margin_grid itself and are refined)
        full = margin_grid(rate_hz, d_max)
        w = np.union1d(full[full >= 0.05 * math.pi * rate_hz][::2],
                       np.geomspace(1e-6 * math.pi * rate_hz, 0.05 * math.pi * rate_hz, 300))
        z = np.exp(1j * w / rate_hz)[None, :]
        paths = _paths_of(rows, rate_hz)
        self.parts = _Parts(z, rate_hz, paths.acc.transfer(z), paths.vel.transfer(z), paths.alt.transfer(z))
        self.ms_target, self.rate_hz = ms_target, rate_hz

    def holds(self, g: ZCascadeGains) -> bool:
        L = _loop_of(g, self.parts)
        if np.max(1.0 / np.abs(1.0 + L)) > self.ms_target:
            return False
        return bool(np.all(nyquist_stable(g.integrators, L)))


def _largest_g(pz: float, v_full: float, pa: float, ai: float, check: _Check, g_range: tuple[float, float]) -> float:
    """The largest g in ``g_range`` at which the cascade holds (0: none): scanned down from the top (the
    test is not monotone in g: a small g leaves the acceleration loop alone, whose Ms may exceed the target),
    then bisected on log g, :data:`_STEPS` times, between the first that holds and the one above it."""
    lo_g, hi_g = g_range
    if not (0.0 < lo_g <= hi_g):
        return 0.0
    scan = np.geomspace(hi_g, lo_g, _SCAN) if hi_g > lo_g else np.array([hi_g])
    g = largest_holding(lambda g: check.holds(_gains(pz, g * v_full, pa, ai, check.rate_hz)), scan,
                        halvings=_STEPS)
    return 0.0 if g is None else g


_Bounds = dict[str, tuple[float, float]]


def _search(pz: float, kd: float, K: float, ratio: float, check: _Check,
            bounds: _Bounds) -> tuple[list[tuple[float, float, float]], tuple[float, float, float] | None]:
    """For one ``PSC_ACCZ_I`` / ``_P`` ratio: per ``PSC_ACCZ_P`` candidate in range, the largest g; the best
    (P_a, g, P_v) or None."""
    lo_v, hi_v = bounds["PSC_VELZ_P"]
    lo_a, hi_a = bounds["PSC_ACCZ_P"]
    tried: list[tuple[float, float, float]] = []
    best: tuple[float, float, float] | None = None
    for pa in (p for p in ACCZ_P_CANDIDATES if lo_a <= p <= hi_a):
        ai = min(ratio * pa, bounds["PSC_ACCZ_I"][1])
        v_full = (1.0 + 0.1 * pa * K) * kd / (0.1 * pa)
        # g is searched where PSC_VELZ_P = g v_full is in its range
        g = _largest_g(pz, v_full, pa, ai, check, (max(_G_MIN, lo_v / v_full), min(1.0, hi_v / v_full)))
        tried.append((ratio, pa, g))
        if g > 0 and (best is None or g > best[1] * 1.001):
            best = (pa, g, g * v_full)
        elif best is not None and g <= best[1]:
            break  # past the best: a stronger acceleration feedback only holds less (its own loop's Ms)
    return tried, best


def design_z_cascade(pd: Controller, model: LoopModel, *, clamp: bool = False, models: Sequence[LoopModel] = (),
                     bounds: _Bounds | None = None
                     ) -> tuple[ZCascadeDesign, tuple[tuple[str, float, float], ...]]:
    """The cascade for tune's PD ``pd`` (module docstring), and the values set to ArduPilot's bounds.

    ``models``: posterior draws (:func:`robust_models`) the cascade must hold on besides ``model``;
    ``bounds``: the ranges in 4.6's names and units (default 4.6's; :func:`mrftcli.tune.ardupilot_versions.z_bounds`).

    Returns
    -------
    design : ZCascadeDesign
    clamped : tuple of (name, value designed, value exported)
        Empty unless ``clamp`` let a value out of range be exported at its bound.

    Raises
    ------
    InputError
        ``PSC_POSZ_P`` = Kp / Kd is outside its range, or no ``PSC_ACCZ_P`` candidate gives a loop that holds the
        Ms with ``PSC_VELZ_P`` in its range, and ``clamp`` is off (the message names the closest and its
        margins; ``--clamp`` exports it at the bounds).
    """
    from .margins import margins as pd_margins

    b = bounds or z_bounds("4.6")
    rate = pd.rate_hz
    every = (model, *models)
    ms_target = max(pd_margins(m, pd).Ms for m in every)
    pz_designed = pd.Kp / pd.Kd
    lo_z, hi_z = b["PSC_POSZ_P"]
    pz = min(max(pz_designed, lo_z), hi_z)
    clamped: list[tuple[str, float, float]] = []
    if pz != pz_designed:
        if not clamp:
            raise InputError(f"cannot export to ardupilot: PSC_POSZ_P = Kp / Kd = {pz_designed:.4g} is outside its "
                             f"range {lo_z:g}-{hi_z:g} [(cm/s)/cm] (AC_PosControl.cpp) (--clamp to "
                             "export it at the bound, with the margins that result)")
        clamped.append(("PSC_POSZ_P", pz_designed, pz))
    check = _Check(every, rate, ms_target)
    tried, first = _search(pz, pd.Kd, model.K, ACCZ_I_RATIOS[0], check, b)
    chosen = (ACCZ_I_RATIOS[0], first) if first is not None else None
    g_first = first[1] if first is not None else 0.0
    for ratio in ACCZ_I_RATIOS[1:] if first is not None else ():
        t, best = _search(pz, pd.Kd, model.K, ratio, check, b)
        tried += t
        if best is None or best[1] < _I_KEEP * g_first:
            break
        chosen = (ratio, best)
    if chosen is None:
        pa, ai, v_designed, v = _closest(pz, model, pd.Kd, rate, clamp, b)
        clamped.append(("PSC_VELZ_P", v_designed, v))
        ratio, g = ai / pa, 0.0
    else:
        ratio, (pa, g, v) = chosen
        ai = min(ratio * pa, b["PSC_ACCZ_I"][1])
    gains = _gains(pz, v, pa, ai, rate)
    nominal = cascade_figures(gains, [model], split_grid(model.tau))
    design = ZCascadeDesign(gains, g, ms_target, nominal, model.tau, tuple(tried),
                            robust_figures(gains, every), tuple(models))
    return design, tuple(clamped)


def _closest(pz: float, model: LoopModel, kd: float, rate: float, clamp: bool,
             b: _Bounds) -> tuple[float, float, float, float]:
    """With no candidate holding the Ms in range: the PD itself (g = 1) per ``PSC_ACCZ_P``, with the smallest
    integral ratio, its PSC_VELZ_P set to the range; the one of smallest worst Ms, as (PSC_ACCZ_P, PSC_ACCZ_I,
    PSC_VELZ_P designed, exported); refused without ``clamp``."""
    best: tuple[float, float, float, float, Margins] | None = None
    splits = split_grid(model.tau)
    lo_v, hi_v = b["PSC_VELZ_P"]
    for pa in (p for p in ACCZ_P_CANDIDATES if b["PSC_ACCZ_P"][0] <= p <= b["PSC_ACCZ_P"][1]):
        ai = ACCZ_I_RATIOS[0] * pa
        v_designed = (1.0 + 0.1 * pa * model.K) * kd / (0.1 * pa)
        v = min(max(v_designed, lo_v), hi_v)
        w = cascade_figures(_gains(pz, v, pa, ai, rate), [model], splits).worst()
        if best is None or w.Ms < best[4].Ms:
            best = (pa, ai, v_designed, v, w)
    assert best is not None
    pa, ai, v_designed, v, w = best
    if not clamp:
        raise InputError(f"cannot export to ardupilot: no PSC_ACCZ_P in {b['PSC_ACCZ_P'][0]:g}-{b['PSC_ACCZ_P'][1]:g} "
                         f"holds the PD's Ms on every split of tau with PSC_VELZ_P in its range {lo_v:g}-{hi_v:g} "
                         f"(AC_PosControl.cpp); the closest, PSC_ACCZ_P {pa:g} with PSC_VELZ_P {v_designed:.4g} set to "
                         f"{v:g}, has Ms {w.Ms:.3g}, GM {w.gain_margin:.3g}, PM {w.phase_margin_deg:.1f} deg on its "
                         "worst split (--clamp to export that)")
    return pa, ai, v_designed, v


def margins_qualifier(stack: str, loop: str) -> str:
    """What an export's stated margins are, after "margins with the stack's filter and rate": only ArduPilot's
    altitude export holds them over the splits of tau (:func:`design_z_cascade`); another export's assumptions (a
    hover thrust read from the log, HEAR's command scale) are no splits."""
    return " (the worst over the splits of tau)" if (stack, loop) == ("ardupilot", "altitude") else ""
