"""The cycle-to-cycle period scatter: what sensor noise explains on a sampled relay, and the delay
jitter beyond it (a candidate judged on the scatter alone; the calibration is
:mod:`mrftcli.diagnose.scatter`'s).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from .fit import CandidateModel, DiagnosedTest, Fit
from .heldout import BIC_THRESHOLD
from .limit_cycles import AugmentedPlant, periodic_cycle
from .physics import Effect
from .records import CandidateFit, HeldOut
from .scatter import ScatterSetting, expected_period_variance, fit_jitter, pooled_scatter_error, refit_sigma

__all__ = ["REFERENCE_WINDOWS", "scatter_reference", "variance_deviance_z", "scatter_z", "jitter_candidate"]

#: sampled-relay windows behind the noise-only period scatter of each test
REFERENCE_WINDOWS = 4


def scatter_reference(tests: list[DiagnosedTest], model: CandidateModel, fit: Fit, noise: float) -> list[dict]:
    """Per test: the sampled-relay setting of a fitted model (the linear one, or with a found effect)
    and the period variance that noise alone explains."""
    p = model.unpack(fit.theta)
    out = []
    for i, t in enumerate(tests):
        plant, gain = model.plant(p, t, float(np.mean(t.tab.t_mid)))
        K = fit.K * gain
        # the model plant is at K = 1: the output scales with K, so a drag per output unit divides by it
        plant = replace(plant, K=K, quadratic_drag=plant.quadratic_drag / K)
        setting = ScatterSetting(plant=plant, beta=t.beta_nominal if t.beta_nominal is not None else float(np.mean(t.beta)),
                                 h=t.h, rate_hz=t.rate_hz, noise_std=noise, n_window=max(t.n_window, len(t.tab)),
                                 period=float(np.mean(t.tab.period)), warm=_limit_cycle_state(plant, t))
        # the noise-only reference: 4 windows (its standard error then adds ~5 % to the comparison's;
        # the jitter's calibration reruns it with the full N_WINDOWS on the same random numbers)
        v0, dof = expected_period_variance(setting, 0.0, n_windows=REFERENCE_WINDOWS)
        if not (np.isfinite(v0) and math.sqrt(v0) < 0.2 * float(np.mean(t.tab.period))):
            v0, dof = float("nan"), 0  # the sampled relay broke down (false switches): no scatter reference
        out.append({"setting": setting, "v0": v0, "s0": math.sqrt(v0) if np.isfinite(v0) else float("nan"), "dof": dof})
    return out


def _limit_cycle_state(plant: AugmentedPlant, test: DiagnosedTest) -> dict | None:
    """The loop state on its continuous-relay limit cycle (a warm start for the sampled relay)."""
    try:
        run = periodic_cycle(plant, test.beta, test.h, test.rate_hz, tol=1e-5)
    except (FloatingPointError, ValueError, OverflowError, ZeroDivisionError):
        return None
    return run.state_at_up[-1] if run is not None and run.state_at_up else None


def variance_deviance_z(ratio: float, dof: float) -> float:
    """Signed root of the chi^2 deviance of a sample variance ``ratio`` times the model's, on ``dof``.

    A sample variance s^2 of ``dof`` degrees of freedom about a model variance v has dof s^2 / v
    ~ chi^2(dof) (Gaussian periods); -2 ln of its likelihood ratio against v = s^2 is
    dof (r - 1 - ln r) with r = s^2 / v. Near r = 1 this is the normal approximation on log
    variance, (ln r)^2 / (2 / dof); far from 1 the normal one understates what a few cycles say (a
    5-fold variance on 7 degrees of freedom: 9.1 for the exact 16.7), and below 1 it overstates it. The sign is
    that of ln r.
    """
    d = dof * (ratio - 1.0 - math.log(ratio))
    return math.copysign(math.sqrt(max(d, 0.0)), math.log(ratio))


def scatter_z(tests: list[DiagnosedTest], scatter: list[dict], sel: str, v_pred: Sequence[float]) -> np.ndarray:
    """Per test, the signed deviance z of the recorded period scatter against the predicted one
    (:func:`variance_deviance_z`), for the 'fit', 'hold' or all cycles.

    The recorded variance has n - 1 degrees of freedom, the simulated reference its own ``dof``; the
    deviance is taken on the pooled 1 / (1 / (n - 1) + 1 / dof), which keeps the normal limit's
    variance of ln r, 2 / (n - 1) + 2 / dof.
    """
    out = []
    for t, sc, vp in zip(tests, scatter, v_pred):
        v_rec, n = t.scatter_var(sel)
        if not (np.isfinite(vp) and np.isfinite(sc["v0"]) and np.isfinite(v_rec)) or sc["dof"] == 0:
            out.append(0.0)
            continue
        v_floor = (0.5 / t.rate_hz) ** 2 / 3.0  # never compare below the tick quantisation
        dof = 1.0 / (1.0 / (n - 1) + 1.0 / sc["dof"])
        out.append(variance_deviance_z(max(v_rec, v_floor) / max(vp, v_floor), dof))
    return np.array(out)


def jitter_candidate(cand: Effect, tests: list[DiagnosedTest], scatter: list[dict],
                     scatter_z: Callable[[str, Sequence[float]], np.ndarray], base: Fit, n_all: int) -> CandidateFit:
    """Fit the delay-jitter std to the recorded period scatter (:func:`mrftcli.diagnose.scatter.fit_jitter`)."""
    v0 = np.array([sc["v0"] for sc in scatter])
    if not np.isfinite(v0).any():
        return CandidateFit(cand.name, "failed", status="no scatter reference (the sampled relay broke down)")

    z_all = np.clip(scatter_z("all", list(v0)), 0.0, None)
    if float(z_all @ z_all) < BIC_THRESHOLD + math.log(n_all):
        # a jitter only raises the predicted scatter, so its chi^2 gain is at most the sum of the
        # positive z^2: below the threshold its calibration runs (most of a diagnosis' cost) are skipped
        return CandidateFit(cand.name, "jitter_below", parameter=cand.parameter, unit=cand.unit,
                            status="period scatter within what sensor noise explains (no jitter could reach the "
                                   "evidence threshold)")

    # the calibration runs below use N_WINDOWS windows: the noise-only variance is recomputed on the
    # same random numbers, so that the calibrated slope is not biased by the reference's sampling
    scatter = [dict(sc, v0=expected_period_variance(sc["setting"], 0.0)[0]) if np.isfinite(sc["v0"]) else sc
               for sc in scatter]
    v0 = np.array([sc["v0"] for sc in scatter])

    def calibrate(sigma: float) -> np.ndarray:
        return np.array([expected_period_variance(sc["setting"], sigma)[0] if np.isfinite(sc["v0"]) else np.nan
                         for sc in scatter])

    v_all, n_all_c = (np.array(x) for x in zip(*(t.scatter_var("all") for t in tests)))
    v_fit, n_fit = (np.array(x) for x in zip(*(t.scatter_var("fit") for t in tests)))
    v_hold, n_hold = (np.array(x) for x in zip(*(t.scatter_var("hold") for t in tests)))
    # the reported value uses every cycle of the scatter sample (calibrated at that value); the
    # evidence and the held-out scores use the fit from the even cycles only
    jf = fit_jitter(v_all, n_all_c, v0, calibrate)
    sigma_fit = refit_sigma(jf, v_fit, n_fit)
    v_pred = jf.predicted_var(sigma_fit)
    z = scatter_z("fit", list(v_pred))
    chi2 = base.chi2 + float(z @ z)
    bic = chi2 + (base.k + 1) * math.log(n_all)
    z_base = scatter_z("fit", list(v0))
    bic_b = base.chi2 + float(z_base @ z_base) + base.k * math.log(n_all)
    zh_b = scatter_z("hold", list(v0))
    zh_a = scatter_z("hold", list(v_pred))
    # standard error of sigma: var(log s^2) = 2/(n - 1) per test, pooled; d log v / d log sigma = 2 c^2 s^2 / v
    ok = np.isfinite(v0) & np.isfinite(v_all) & (n_all_c > 1)
    if jf.sigma > 0 and ok.any():
        vp = jf.predicted_var()[ok]
        g = 2.0 * jf.slope[ok] * jf.sigma**2 / vp
        info = float(np.sum((n_all_c[ok] - 1) / 2.0 * g * g))
        s_std = jf.sigma / math.sqrt(info) if info > 0 else float("nan")
    else:
        s_std = float("nan")
    metric = "pooled relative error of the held-out cycle-to-cycle period scatter, |s_rec - s_model| / s_rec"
    cycles = int(n_hold.sum())
    return CandidateFit(
        cand.name, "jitter",
        min_value=0.5 / min(t.rate_hz for t in tests),
        parameter=cand.parameter,
        value=jf.sigma,
        value_fit_cycles=sigma_fit,
        std=s_std,
        unit=cand.unit,
        chi2=chi2,
        bic=bic,
        delta_bic=bic_b - bic,
        held_out_before=HeldOut("scatter", nrmse=pooled_scatter_error(v_hold, n_hold, v0),
                                feature_rms_z=float(np.sqrt(np.mean(zh_b**2))), metric=metric, cycles=cycles),
        held_out_after=HeldOut("scatter", nrmse=pooled_scatter_error(v_hold, n_hold, v_pred),
                               feature_rms_z=float(np.sqrt(np.mean(zh_a**2))), metric=metric, cycles=cycles),
        fit_params=None,
        calibration_runs=jf.iterations,
        period_scatter={"recorded": [math.sqrt(v) if np.isfinite(v) else None for v in v_all],
                        "noise_only": [math.sqrt(v) if np.isfinite(v) else None for v in v0],
                        "with_jitter": [math.sqrt(v) if np.isfinite(v) else None for v in jf.predicted_var()]},
    )
