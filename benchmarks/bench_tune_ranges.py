"""Benchmark: ``tune --export``'s design inside the stack's ranges (issue 37's scan), against the path it replaces.

:func:`mrftcli.tune.stacks._inside_ranges` scans 48 gains of the stack's range, each loop on the nominal model and
up to 40 posterior draws, and reads only the worst Ms and the stability. It used to call
:func:`~mrftcli.tune.margins.loop_margins` per gain (the plants discretised again, every margin refined, the delay
margin's rediscretised plants); it now discretises once and calls
:func:`~mrftcli.tune.margins.stack_sensitivity` (Ms and stability only, the same computation). Ms's golden section
(:func:`~mrftcli.tune.margins.sensitivity_peaks`, every margin computation's) now evaluates its two probes in one
call of the loop's response; the old path below runs the previous golden section (a copy: two calls per step).

Cases: the paper's four platforms (checks.md Table III, Td and tau with the reported standard deviations as the
posterior, ``--draws`` draws on a fresh ``--seed``), robust PD designed at each stack's rate and filter
(:func:`~mrftcli.tune.stacks.stack_setting`), exported to PX4 (altitude, x, roll) and ArduPilot (roll, pitch) with
the hover thrust 0.5 (K = g / 0.5 for the thrust loops). Per case, both paths run in this process: the exported
values, margins and notes must be equal (printed: ``same``), and the CPU of ``export_design`` for each.

Run: ``python benchmarks/bench_tune_ranges.py [--seed 7] [--draws 80]`` (about a minute on a busy core).
"""

from __future__ import annotations

import argparse
import importlib
import math
import statistics
import time
from collections.abc import Iterator
from contextlib import contextmanager

import mrftcli.cli  # noqa: F401  (first: BLAS single-threaded, as the command line runs it)
import numpy as np

from mrftcli.mrft.cascade import STANDARD_GRAVITY
from mrftcli.mrft.model import LoopModel
from mrftcli.tune import stacks
from mrftcli.tune.design import DesignOptions, Posterior, tune
from mrftcli.tune.margins import loop_margins

_MARGINS = importlib.import_module("mrftcli.tune.margins")  # (the package re-exports a function of that name)

HOVER = 0.5
TABLE_III = [  # platform, loop, Tp, Td mean, Td std, tau mean, tau std (checks.md section 4)
    ("Design I", "roll", 0.0422, 1.301, 0.8395, 0.0297, 0.0042),
    ("Design I", "altitude", 0.0422, 2.669, 0.6612, 0.0464, 0.0012),
    ("Design II", "roll", 0.0499, 0.887, 0.4574, 0.0228, 0.0053),
    ("Design II", "altitude", 0.0499, 1.8345, 0.1754, 0.0498, 0.0017),
]
#: (stack, loop) exported from a roll row and from an altitude row (x: the altitude plant as a position loop)
EXPORTS = {"roll": (("px4", "roll"), ("ardupilot", "roll"), ("ardupilot", "pitch")),
           "altitude": (("px4", "altitude"), ("px4", "x"))}


@contextmanager
def old_scan(models_of: list) -> Iterator[None]:
    """The path before: every gain's loop through :func:`loop_margins` on the models (discretised each call)."""
    new = stacks.stack_sensitivity

    def full(ctrl, plants, response):  # noqa: ARG001  (the old path recomputes both)
        lm = loop_margins(ctrl, models_of[0])
        return lm.Ms, lm.stable

    peaks = _MARGINS.sensitivity_peaks
    stacks.stack_sensitivity, _MARGINS.sensitivity_peaks = full, old_peaks
    try:
        yield
    finally:
        stacks.stack_sensitivity, _MARGINS.sensitivity_peaks = new, peaks


def old_peaks(at, L, lw, n=40):
    """The previous :func:`~mrftcli.tune.margins.sensitivity_peaks` (its golden section: two calls per step)."""
    dist = np.abs(1.0 + L)
    k = np.argmin(dist, axis=-1)
    rows = np.arange(L.shape[0])
    a, b = lw[np.maximum(k - 1, 0)], lw[np.minimum(k + 1, lw.size - 1)]
    g = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(n):
        c, d = b - g * (b - a), a + g * (b - a)
        left = np.abs(1.0 + at(rows, c)) < np.abs(1.0 + at(rows, d))
        a, b = np.where(left, a, c), np.where(left, d, b)
    x = 0.5 * (a + b)
    return np.asarray(1.0 / np.minimum(dist[rows, k], np.abs(1.0 + at(rows, x))), float)


def old_transfer(st, z: np.ndarray) -> np.ndarray:
    """The previous :meth:`~mrftcli.tune.closed_loop.PlantStack.transfer` of eq. (2)'s plants: the two inputs'
    resolvents in two passes."""
    z = np.atleast_2d(np.asarray(z, complex))
    Phi, C = st.Phi, st.C

    def resolvent(b):
        x2 = b[:, 2, None] / (z - Phi[:, 2, 2, None])
        x1 = (b[:, 1, None] + Phi[:, 1, 2, None] * x2) / (z - Phi[:, 1, 1, None])
        x0 = (b[:, 0, None] + Phi[:, 0, 1, None] * x1 + Phi[:, 0, 2, None] * x2) / (z - Phi[:, 0, 0, None])
        return C[:, 0, None] * x0 + C[:, 1, None] * x1 + C[:, 2, None] * x2

    xa, xb = resolvent(st.Gamma[:, 0]), resolvent(st.Gamma[:, 1])
    return (xb + xa / z) * np.exp(-st.d[:, None] * np.log(z))


def transfer_ratio(seed: int) -> None:
    """PlantStack.transfer at one point per plant (the refinements' call), new against old, 1 to 200 plants."""
    from mrftcli.tune.closed_loop import PlantStack, discrete_plants

    rng = np.random.default_rng(seed)
    for m in (1, 41, 200):
        models = [LoopModel(0.0422, float(np.exp(rng.uniform(-1, 1.5))), float(rng.uniform(0, 0.06)), 1.0)
                  for _ in range(m)]
        st = PlantStack.of(discrete_plants(models, 250.0))
        z = np.exp(1j * rng.uniform(0.01, 3.0, (m, 1)))
        same = np.array_equal(st.transfer(z), old_transfer(st, z))
        reps = 3000
        t = time.process_time()
        for _ in range(reps):
            st.transfer(z)
        t_new = time.process_time() - t
        t = time.process_time()
        for _ in range(reps):
            old_transfer(st, z)
        t_old = time.process_time() - t
        print(f"PlantStack.transfer, {m:3d} plants x 1 point: new {t_new / reps * 1e6:5.1f} us, old "
              f"{t_old / reps * 1e6:5.1f} us (ratio {t_old / t_new:.2f}x); values {'same' if same else 'DIFFER'}")


def old_xy_ticks(params: dict, model: LoopModel, rate_hz: float, hover: float, seconds: float):
    """The previous :func:`~mrftcli.tune.px4_xy.px4_xy_ticks`' loop, verbatim (np.outer per tick)."""
    from mrftcli.mrft.controller import PX4VelocityPath
    from mrftcli.tune.closed_loop import discrete_plants

    Phi, G, C, d = discrete_plants([model], rate_hz)[0]
    n, T = int(round(seconds * rate_hz)) + 1, 1.0 / rate_hz
    alpha = PX4VelocityPath(params["MPC_VELD_LP"], "MPC_VELD_LP").alpha(rate_hz)
    pz, pv, iv, dv = (params[k] for k in ("MPC_XY_P", "MPC_XY_VEL_P_ACC", "MPC_XY_VEL_I_ACC", "MPC_XY_VEL_D_ACC"))
    r, load = np.array([1.0, 0.0]), np.array([0.0, 1.0 / model.K])
    u = np.zeros((n + d + 1, 2))
    x, y_prev, v_prev, acc_f, integral = np.zeros((2, 3)), np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2)
    y = np.empty((2, n))
    for k in range(n):
        y[:, k] = x @ C
        v = (y[:, k] - y_prev) / T
        acc_f += alpha * ((v - v_prev) / T - acc_f)
        err = pz * (r - y[:, k]) - v
        u[k + d + 1] = (pv * err + integral - dv * acc_f) * hover / STANDARD_GRAVITY
        integral += iv * err * T
        x = x @ Phi.T + np.outer(u[k], G[0]) + np.outer(u[k + 1], G[1]) + np.outer(load, G[0] + G[1])
        y_prev, v_prev = y[:, k], v
    return np.arange(n) * T, y


def xy_ticks_ratio() -> None:
    """px4_xy_ticks (PX4's x/y law, 40 s at 125 Hz with and without the integral), new against old."""
    from mrftcli.tune.px4_xy import XY_HORIZON_S, px4_xy_ticks

    model = LoopModel(0.0422, 2.669, 0.0464, STANDARD_GRAVITY / HOVER)
    t_new = t_old = 0.0
    same = True
    for iv in (0.0, 0.4):
        p = {"MPC_XY_P": 0.95, "MPC_XY_VEL_P_ACC": 1.8, "MPC_XY_VEL_I_ACC": iv, "MPC_XY_VEL_D_ACC": 0.2,
             "MPC_VELD_LP": 5.0}
        t = time.process_time()
        a = px4_xy_ticks(p, model, 125.0, HOVER, XY_HORIZON_S)
        t_new += time.process_time() - t
        t = time.process_time()
        b = old_xy_ticks(p, model, 125.0, HOVER, XY_HORIZON_S)
        t_old += time.process_time() - t
        same &= np.array_equal(a[1], b[1]) and np.array_equal(a[0], b[0])
    print(f"px4_xy_ticks, 2 x {XY_HORIZON_S:g} s at 125 Hz: new {t_new:.3f} s, old {t_old:.3f} s "
          f"(ratio {t_old / t_new:.2f}x); values {'same' if same else 'DIFFER'}")


def _case(row: tuple, stack: str, loop: str, seed: int, draws: int):
    _, kind, Tp, Td, Td_std, tau, tau_std = row
    K = STANDARD_GRAVITY / HOVER if kind == "altitude" else 1.0
    model = LoopModel(Tp, Td, tau, K)
    post = Posterior.from_spread(model, Td_std, tau_std, 0.0, n=draws, seed=seed, source="bench")
    st = stacks.stack_setting(stack, loop, None, 250.0, None)
    res = tune(model, st.rate_hz, posterior=post, loop=loop,
               options=DesignOptions(kinds=("PD",), rate_filter=st.rate_filter))
    c = res.get("robust", "PD").controller
    kept = post.models(np.flatnonzero(post.in_set()))
    return model, c, tuple(kept)


def _export(stack: str, loop: str, model: LoopModel, c, kept) -> tuple[object, float]:
    t = time.process_time()
    e = stacks.export_design(stack, c, model, loop, "robust PD", hover_thrust=HOVER,
                             evidence=stacks.ExportEvidence(posterior_models=kept))
    return e, time.process_time() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--draws", type=int, default=80)
    a = ap.parse_args()
    ratios, new_total, old_total, same_all = [], 0.0, 0.0, True
    print(f"{'case':34s} {'scanned':>7s} {'new s':>7s} {'old s':>7s} {'ratio':>6s}  outputs")
    for row in TABLE_III:
        for stack, loop in EXPORTS[row[1]]:
            model, c, kept = _case(row, stack, loop, a.seed, a.draws)
            e_new, t_new = _export(stack, loop, model, c, kept)
            models = [model, *kept[:: max(1, len(kept) // 40)]]
            with old_scan([models]):
                e_old, t_old = _export(stack, loop, model, c, kept)
            same = (e_new.params == e_old.params and e_new.margins == e_old.margins and e_new.notes == e_old.notes)
            same_all &= same
            scanned = any("designed inside them" in n or "designed with it" in n for n in e_new.notes)
            new_total, old_total = new_total + t_new, old_total + t_old
            if scanned:
                ratios.append(t_old / t_new)
            name = f"{row[0]} {row[1]} -> {stack} {loop}"
            print(f"{name:34s} {str(scanned):>7s} {t_new:7.2f} {t_old:7.2f} {t_old / t_new:6.2f}  "
                  f"{'same' if same else 'DIFFER'}")
    med = statistics.median(ratios) if ratios else math.nan
    print(f"CPU of export_design, all cases: new {new_total:.2f} s, old {old_total:.2f} s "
          f"(ratio {old_total / new_total:.2f}x; median {med:.2f}x over the {len(ratios)} scanned cases); "
          f"outputs {'identical' if same_all else 'DIFFER'}")
    transfer_ratio(a.seed)
    xy_ticks_ratio()


if __name__ == "__main__":
    main()
