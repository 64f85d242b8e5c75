"""Cycle-to-cycle period scatter of a sampled MRFT: what noise explains, and the delay jitter beyond it.

A relay that decides at controller ticks on noisy samples does not repeat its cycle exactly: every
switch lands a tick early or late and the period scatters. A transport delay that varies from one
command to the next (``delay_jitter``) adds to that scatter. No deterministic model predicts the
scatter cycle by cycle, so the diagnosis compares its *size*: the sample variance of the recorded
periods against the variance the model produces under the same conditions.

"The same conditions" matters. Delay jitter perturbs a lightly damped closed loop, so the
period deviations are large (5-7 times the jitter std) and correlated from cycle to cycle, and the
cycles that survive a stability filter are a truncated sample. Both make the variance of a short
recorded test smaller than the loop's long-run variance (about 25 % smaller for a 12 ms jitter on the
paper's platforms, measured with the project simulator). The model's variance is therefore
computed exactly as the recorded one is:

* the sampled relay (:func:`mrftcli.diagnose.limit_cycles.run_relay`, sampled mode) runs several windows of
  as many cycles as the recorded test had,
* every window goes through the same cycle filter as the recorded test
  (:func:`mrftcli.segment.stable_cycles` with :data:`SCATTER_CRITERION`),
* the variance is the dof-weighted mean of the windows' sample variances.

The jitter std sigma [s] is then the value whose predicted variances match the recorded ones, in
the least-squares sense on log variance (each test weighted by its degrees of freedom, since
var(log s^2) = 2 / (n - 1)). The prediction is calibrated by simulation at the estimate and the
estimate refined, a few times: the variance is close to s0^2 + c^2 sigma^2 (s0 the noise-only
scatter) but the filter makes c fall slowly as sigma grows. All simulations of one test use the same
random numbers (common random numbers), so the calibration is smooth in sigma.

The diagnosis' side (:func:`scatter_reference`, :func:`scatter_z`, :func:`jitter_candidate`): per test,
the sampled-relay setting of a fitted model and the period variance noise alone explains; the
recorded scatter's deviance against it; and the delay jitter as a candidate judged on the scatter alone.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import minimize_scalar

from .limit_cycles import AugmentedPlant, SampledRelay, periodic_cycle, run_relay
from .physics import BIC_THRESHOLD, Effect
from .records import CandidateFit, HeldOut
from ..segment import StabilityCriterion, stable_cycles

if TYPE_CHECKING:
    from .fit import Fit
    from .prepared import DiagnosedTest
    from .candidate_model import CandidateModel

__all__ = ["SCATTER_CRITERION", "ScatterSetting", "scatter_sample", "expected_period_variance",
           "fit_jitter", "JitterFit", "pooled_scatter_error", "REFERENCE_WINDOWS", "scatter_reference",
           "variance_deviance_z", "scatter_z", "jitter_candidate"]

#: The cycle filter of the scatter statistic. Same robust rule as the segmenter's (4 robust sigma
#: about the median of the test's second half, a floor of 3 ticks / 6 % of the period and 12 % of the
#: amplitude), but with wide caps: the segmenter caps the tolerances at 15 % / 25 % to keep only
#: clean limit cycles for identification, which under a large jitter throws away most cycles and
#: truncates the very scatter that measures it. In a clean log the floors bind and both agree.
SCATTER_CRITERION = StabilityCriterion(period_cap_rel=0.35, amplitude_cap_rel=0.6)

#: windows simulated per scatter prediction (each as long as the recorded test)
N_WINDOWS = 8
#: the delays a scatter prediction's windows run on, spread over one controller tick (expected_period_variance)
DITHER = 4


@dataclass(frozen=True)
class ScatterSetting:
    """What the sampled relay of one test needs to reproduce its scatter.

    Attributes
    ----------
    plant : AugmentedPlant
        The loop model (deviation coordinates).
    beta : float
        Nominal beta of the log's relay (it decides on noisy samples with this level).
    h : float
        Relay half-height [command units].
    rate_hz : float
        Controller rate [Hz].
    noise_std : float
        Sensor noise std [output units].
    n_window : int
        Regular cycles in the recorded test: each simulated window has as many.
    period : float
        Recorded mean period [s] (a simulated relay silent for 5 periods has locked up: stop).
    warm : dict or None
        Loop state on the limit cycle (from :func:`mrftcli.diagnose.limit_cycles.run_relay`), so windows start
        in steady oscillation.
    """

    plant: AugmentedPlant
    beta: float
    h: float
    rate_hz: float
    noise_std: float
    n_window: int
    period: float
    warm: dict | None = None


def scatter_sample(period: np.ndarray, amplitude: np.ndarray, regular: np.ndarray, dt: float) -> np.ndarray:
    """Mask of the cycles whose periods make the scatter statistic (:data:`SCATTER_CRITERION`).

    Parameters
    ----------
    period, amplitude : numpy.ndarray
        Per-cycle period [s] and amplitude [output units] of one test, in order.
    regular : numpy.ndarray of bool
        Cycles without gaps or glitches.
    dt : float
        Controller tick [s].
    """
    keep, _, _ = stable_cycles(period, amplitude, regular, dt, SCATTER_CRITERION)
    return keep


def expected_period_variance(setting: ScatterSetting, jitter_std: float, *, n_windows: int = N_WINDOWS,
                             seed: int = 1, memo: dict | None = None) -> tuple[float, int]:
    """Expected sample variance of a recorded test's filtered periods [s^2], and its degrees of freedom.

    The sampled relay runs ``n_windows`` windows of ``setting.n_window`` cycles with sensor noise and
    a Gauss-Markov delay jitter of std ``jitter_std`` [s]; each window's cycles are filtered by
    :func:`scatter_sample` and their sample variance taken; the result is the dof-weighted mean.
    Returns ``(nan, 0)`` when the relay breaks down (no usable window).

    Each window runs on the plant's delay moved by a fraction of a tick (:data:`DITHER`, spread
    over one tick): a sampled relay's cycle is a whole number of ticks, and whether it locks on one
    such orbit (no scatter at all) or hops between two depends on where the cycle falls between the
    ticks, i.e. on the delay to a fraction of a tick, which no fit determines (issue 39: a RotorPy
    flight's 2h test was called unexplained at z = 7 against a locked orbit's zero scatter, while
    the same model a quarter tick later hops as the recording does).

    ``memo``, when given, keeps each window's term by ``(jitter_std, seed, window)`` for this
    ``setting`` only (the caller keeps one per setting: :func:`scatter_reference` puts it beside the
    setting as ``"windows"``): the jitter's calibration reruns the reference's windows on the same
    random numbers (issue 39's CPU).
    """
    s = setting
    memo = {} if memo is None else memo
    n_w = max(int(s.n_window), 4)
    skip = 1 if s.warm is not None else 6  # past the start-up (a warm run starts on the limit cycle)
    num = 0.0
    dof = 0
    for w in range(n_windows):
        key = (float(jitter_std), seed, w)
        if key not in memo:
            memo[key] = _window_term(s, jitter_std, seed, w, n_w, skip)
        term = memo[key]
        if term is not None:
            num += term[0]
            dof += term[1]
    if dof == 0:
        return float("nan"), 0
    return num / dof, dof


def _window_term(s: ScatterSetting, jitter_std: float, seed: int, w: int, n_w: int, skip: int
                 ) -> tuple[float, int] | None:
    """Window ``w`` of :func:`expected_period_variance`: (n - 1) times the sample variance [s^2] of its
    filtered periods and n - 1, or None (fewer than 3 cycles kept, or the relay never ran the window)."""
    dt = 1.0 / s.rate_hz
    shift = ((w % DITHER) + 0.5) / DITHER - 0.5
    plant = replace(s.plant, tau=max(s.plant.tau + shift * dt, 0.0))
    # the plain MRFT rule can lock up on a noise-triggered false switch (docs/simulator.md); the log's
    # relay evidently did not, so a run that locks up is restarted from the limit cycle with fresh
    # random numbers (a fixed sequence of seeds: still common random numbers)
    for attempt in range(4):
        relay = SampledRelay(noise_std=s.noise_std, jitter_std=jitter_std,
                             seed=seed + 7919 * attempt + 104729 * w, max_gap=5.0 * s.period)
        run = run_relay(plant, s.beta, s.h, s.rate_hz, n_w + skip + 1, warm=s.warm, sampled=relay,
                        max_time=(n_w + skip + 5) * 3.0 * s.period)
        up = run.up[skip:]
        if up.size < n_w + 1:
            continue
        P = np.diff(up)[:n_w]
        k = np.searchsorted(run.t, up)
        A = np.array([0.5 * (run.y[a:b].max() - run.y[a:b].min()) if b > a else np.nan
                      for a, b in zip(k[:-1], k[1:])])[:n_w]
        keep = scatter_sample(P, A, np.isfinite(A), dt)
        n = int(keep.sum())
        return ((n - 1) * float(np.var(P[keep], ddof=1)), n - 1) if n >= 3 else None
    return None


@dataclass(frozen=True)
class JitterFit:
    """Delay-jitter std fitted to recorded period variances.

    Attributes
    ----------
    sigma : float
        Jitter std [s] (0 when the recorded scatter is what noise explains).
    noise_var : numpy.ndarray
        Per test, the predicted period variance without jitter [s^2].
    slope : numpy.ndarray
        Per test, c^2 in var = noise_var + c^2 sigma^2, calibrated at ``sigma`` [1].
    iterations : int
        Calibration simulations run.
    """

    sigma: float
    noise_var: np.ndarray
    slope: np.ndarray
    iterations: int

    def predicted_var(self, sigma: float | None = None) -> np.ndarray:
        """Per-test period variance [s^2] at jitter ``sigma`` (default: the fitted one)."""
        s = self.sigma if sigma is None else sigma
        return self.noise_var + self.slope * s * s


def _ls_sigma(v_rec: np.ndarray, w: np.ndarray, v0: np.ndarray, c2: np.ndarray, upper: float) -> float:
    """sigma minimising sum w (log v_rec - log(v0 + c2 sigma^2))^2 on [0, upper]."""
    ok = np.isfinite(v_rec) & (v_rec > 0) & np.isfinite(v0) & (v0 > 0) & np.isfinite(c2) & (w > 0)
    if not ok.any():
        return 0.0
    v_rec, w, v0, c2 = v_rec[ok], w[ok], v0[ok], c2[ok]

    def cost(sig: float) -> float:
        r = np.log(v_rec) - np.log(v0 + c2 * sig * sig)
        return float(np.sum(w * r * r))

    # the cost is smooth and unimodal in sigma^2 >= 0; a bounded scalar search on sigma suffices
    res = minimize_scalar(cost, bounds=(0.0, upper), method="bounded", options={"xatol": upper * 1e-5})
    return float(res.x) if cost(res.x) < cost(0.0) else 0.0


def fit_jitter(v_rec: np.ndarray, n_rec: np.ndarray, noise_var: np.ndarray,
               calibrate: Callable[[float], np.ndarray], *, trial: float = 0.005, upper: float = 0.2,
               max_iter: int = 4, rtol: float = 0.03) -> JitterFit:
    """Fit the delay-jitter std to the recorded per-test period variances.

    Parameters
    ----------
    v_rec : numpy.ndarray
        Recorded sample variance of each test's periods [s^2].
    n_rec : numpy.ndarray
        Cycles behind each variance (weights n - 1).
    noise_var : numpy.ndarray
        Predicted variance without jitter [s^2] (nan where the prediction failed: that test is
        left out).
    calibrate : callable
        ``calibrate(sigma)`` -> predicted per-test variance at jitter ``sigma`` [s^2] (same random
        numbers at every call).
    trial : float
        First calibration point [s].
    upper : float
        Largest sigma considered [s].
    """
    v_rec = np.asarray(v_rec, float)
    w = np.maximum(np.asarray(n_rec, float) - 1.0, 0.0)
    v0 = np.asarray(noise_var, float)
    f = np.asarray(calibrate(trial), float)
    c2 = np.maximum(f - v0, 1e-14) / trial**2
    it = 1
    sigma = _ls_sigma(v_rec, w, v0, c2, upper)
    for _ in range(max_iter):
        if sigma <= 0.1 * trial:
            break  # nothing beyond the noise: no need to calibrate closer
        f = np.asarray(calibrate(sigma), float)
        it += 1
        good = np.isfinite(f)
        c2 = np.where(good, np.maximum(f - v0, 1e-14) / sigma**2, c2)
        new = _ls_sigma(v_rec, w, v0, c2, upper)
        done = abs(new - sigma) <= rtol * sigma
        sigma = new
        if done:
            break
    return JitterFit(sigma=sigma, noise_var=v0, slope=c2, iterations=it)


def refit_sigma(fit: JitterFit, v_rec: np.ndarray, n_rec: np.ndarray, upper: float = 0.2) -> float:
    """sigma [s] for other recorded variances (e.g. the fitting half of the cycles) with ``fit``'s calibration."""
    w = np.maximum(np.asarray(n_rec, float) - 1.0, 0.0)
    return _ls_sigma(np.asarray(v_rec, float), w, fit.noise_var, fit.slope, upper)


def pooled_scatter_error(v_rec: np.ndarray, n_rec: np.ndarray, v_pred: np.ndarray) -> float | None:
    """Relative error of a predicted period scatter, pooled over tests: |s_rec - s_pred| / s_rec.

    With r = sum (n - 1) v_rec / v_pred / sum (n - 1) the pooled ratio of recorded to predicted
    variance, the error is |1 - 1 / sqrt(r)|: 0 when the prediction is right, near 1 when the
    prediction is far too small. Pooling the tests' degrees of freedom (rather than averaging
    per-test errors) keeps the sampling error of a handful of held-out cycles per test small:
    about 1/sqrt(2 sum (n - 1)).
    """
    v_rec = np.asarray(v_rec, float)
    v_pred = np.asarray(v_pred, float)
    w = np.maximum(np.asarray(n_rec, float) - 1.0, 0.0)
    ok = np.isfinite(v_rec) & np.isfinite(v_pred) & (v_pred > 0) & (w > 0)
    if not ok.any():
        return None
    r = float(np.sum(w[ok] * v_rec[ok] / v_pred[ok]) / np.sum(w[ok]))
    return abs(1.0 - 1.0 / math.sqrt(r)) if r > 0 else 1.0


#: sampled-relay windows behind the noise-only period scatter of each test
REFERENCE_WINDOWS = 4


def scatter_reference(tests: list[DiagnosedTest], model: CandidateModel, fit: Fit, noise: float) -> list[dict]:
    """Per test: the sampled-relay setting of a fitted model (the linear one, or with a found effect)
    and the period variance that noise alone explains (``"setting"``, ``"v0"`` [s^2], ``"s0"`` [s],
    ``"dof"``; ``"windows"``: the setting's memo of window terms for :func:`expected_period_variance`)."""
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
        windows: dict = {}  # the windows' terms of this setting, reused by the jitter's calibration
        v0, dof = expected_period_variance(setting, 0.0, n_windows=REFERENCE_WINDOWS, memo=windows)
        if not (np.isfinite(v0) and math.sqrt(v0) < 0.2 * float(np.mean(t.tab.period))):
            v0, dof = float("nan"), 0  # the sampled relay broke down (false switches): no scatter reference
        out.append({"setting": setting, "windows": windows, "v0": v0, "s0": math.sqrt(v0) if np.isfinite(v0) else float("nan"), "dof": dof})
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
    """Fit the delay-jitter std to the recorded period scatter (:func:`fit_jitter`)."""
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
    scatter = [dict(sc, v0=expected_period_variance(sc["setting"], 0.0, memo=sc["windows"])[0]) if np.isfinite(sc["v0"]) else sc
               for sc in scatter]
    v0 = np.array([sc["v0"] for sc in scatter])

    def calibrate(sigma: float) -> np.ndarray:
        return np.array([expected_period_variance(sc["setting"], sigma, memo=sc["windows"])[0] if np.isfinite(sc["v0"]) else np.nan
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
