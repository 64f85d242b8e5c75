"""Diagnose where the identified linear model and a flight log disagree, and which physics explains it.

Pipeline (``docs/diagnose.md`` walks through a case):

1. **Measure.** The MRFT tests and their stable cycles come from :func:`mrftcli.segment.segment`
   (or from an :class:`~mrftcli.analyze.AnalysisResult` already computed). Every cycle is measured by
   :func:`mrftcli.diagnose_features.cycle_table`: period, half-period balance, the noise-free
   waveform (harmonics 1..7 of the cycle), amplitude, centre, per-harmonic response Y_k/U_k and the
   switching levels the relay actually achieved (effective beta, per switch direction).
2. **Split.** Even-numbered stable cycles of each test are the fitting set, odd ones are held out.
3. **Base model.** Td and tau (K in closed form, Lemma 2) are fitted to the fitting set's features:
   per test the mean period, balance, log amplitude, centre, shape (Y3/Y1, Y5/Y1), amplitude and
   balance trends. The model's features come from its exact limit cycle under the same MRFT
   settings (effective betas, h, rate) computed by :mod:`mrftcli.diagnose_sim`. Each residual is
   weighted by its standard error (cycle-to-cycle spread / sqrt(n), with a small floor for the
   modelling approximations), so chi^2 is in units of what the noise explains. The cycle-to-cycle
   period scatter is compared with what the base model plus sensor noise produces on a sampled relay.
4. **Candidates** (:mod:`mrftcli.diagnose_physics`): each augments the model with one parameter and is
   refitted together with Td and tau. Evidence: BIC = chi^2 + k ln n over the same features;
   ``delta_bic`` = BIC(base) - BIC(candidate). An effect is reported when delta_bic >= 10 ("very
   strong" on Kass-Raftery's scale) *and* it improves the held-out cycles (feature chi^2 and
   waveform NRMSE); otherwise nothing is reported.
5. **Locate.** The base model's residuals say which test, which feature (period, a half-period,
   amplitude, a harmonic, a trend, the scatter), which time segment and by how much.

Everything here is pure computation on a :class:`~mrftcli.logtypes.FlightLog`; I/O is limited to
reading the log when a path is given.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
from scipy.optimize import least_squares

from .diagnose_features import FEATURE_NAMES, N_HARM, CycleTable, cycle_table, summarize_features
from .diagnose_physics import BY_NAME, CANDIDATES, Candidate, df_quadratic_drag
from .diagnose_sim import Plant, periodic_cycle, quasi_static_plant, run_relay
from .errors import DiagnoseError, InputError
from .logtypes import FlightLog
from .segment import stable_cycles

__all__ = ["diagnose", "DiagnosisResult", "EffectFinding", "BIC_THRESHOLD"]

#: delta BIC above which an effect counts as found (Kass & Raftery: > 10 is very strong evidence)
BIC_THRESHOLD = 10.0
#: fewest stable cycles per test for a diagnosis
MIN_CYCLES = 6

# Floors added (in quadrature) to each feature's standard error: the continuous-relay model of a
# sampled, noisy relay (``diagnose_sim``) is not exact to better than about this.
_FLOOR = {
    "period": 1.5e-3,  # relative
    "balance": 1.5e-3,
    "log_amplitude": 4e-3,
    "centre": 8e-3,
    "h3_re": 1.5e-3,
    "h3_im": 1.5e-3,
    "h5_re": 1e-3,
    "h5_im": 1e-3,
    "amplitude_trend": 2e-4,  # 1/s
    "balance_trend": 1e-4,  # 1/s
}
_FEATURE_TEXT = {
    "period": "oscillation period",
    "balance": "half-period balance (time at +h vs -h)",
    "log_amplitude": "amplitude",
    "centre": "oscillation centre relative to the setpoint",
    "h3_re": "3rd-harmonic content of the waveform",
    "h3_im": "3rd-harmonic content of the waveform",
    "h5_re": "5th-harmonic content of the waveform",
    "h5_im": "5th-harmonic content of the waveform",
    "amplitude_trend": "amplitude trend over time",
    "balance_trend": "half-period balance trend over time",
    "period_scatter": "cycle-to-cycle period scatter",
}


# --------------------------------------------------------------------------------------------------
# result types


@dataclass
class EffectFinding:
    """A candidate effect with its fit and evidence (``to_dict`` gives the JSON item)."""

    name: str
    explanation: str
    augmentation: str
    parameters: dict
    evidence: dict
    fit_before: dict
    fit_after: dict
    identification: dict
    harmonics: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "explanation": self.explanation,
            "augmentation": self.augmentation,
            "parameters": self.parameters,
            "evidence": self.evidence,
            "fit_before": self.fit_before,
            "fit_after": self.fit_after,
            "identification": self.identification,
            "harmonics": self.harmonics,
        }


@dataclass
class DiagnosisResult:
    """What :func:`diagnose` found.

    Attributes
    ----------
    path, loop : str
        The log and loop.
    Tp : float
        The propulsion time constant used [s].
    effects : list of EffectFinding
        Effects the evidence supports (empty when the linear model explains the log).
    candidates : list of dict
        Every candidate's evidence and held-out scores (including the rejected ones).
    located : list of dict
        Where the base model disagrees with the recording, largest first.
    identification : dict
        The base (linear) fit and, per found effect, the refit that accounts for it; the analysis'
        own identification when one was given.
    tests : list of dict
        Per test: beta (nominal, effective up/down), h, bias, cycles used, times.
    noise_std : float
        Sensor noise estimated from the residual of the cycle projections [output units].
    summary : str
        One sentence.
    """

    path: str
    loop: str
    Tp: float
    effects: list
    candidates: list
    located: list
    identification: dict
    tests: list
    noise_std: float
    summary: str
    warnings: list = field(default_factory=list)
    _plot: dict = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict:
        return {
            "path": self.path,
            "loop": self.loop,
            "Tp": self.Tp,
            "summary": self.summary,
            "effects": [e.to_dict() for e in self.effects],
            "located": self.located,
            "identification": self.identification,
            "candidates": self.candidates,
            "tests": self.tests,
            "noise_std": self.noise_std,
            "nrmse_definition": (
                "held-out (odd) stable cycles; waveform NRMSE = RMS(recorded - model) / RMS(recorded - its "
                "cycle mean), recorded waveform projected on harmonics 1-7 of each cycle (sensor noise "
                "removed), recorded and model cycles both aligned at the -h -> +h switch and put on the mean "
                "held-out period of the test (phase-normalised: the period is judged by the feature z-scores, "
                "whose standard errors account for the few-cycle sampling error of the mean period); the "
                "cycle-to-cycle scatter of the recording that no deterministic model can predict (residual of a "
                "per-phase linear trend over the held-out cycles of each test, dof-corrected; reported as "
                "scatter_nrmse) is subtracted from the mean square error (nrmse_raw keeps it; nrmse_timed also "
                "keeps the model's own period, and is what confirms a candidate); for "
                "delay_jitter the nrmse is the relative error of the predicted cycle-to-cycle period scatter"
            ),
            "warnings": self.warnings,
        }


# --------------------------------------------------------------------------------------------------
# per-test data


@dataclass
class _Test:
    index: int
    h: float
    bias: float
    rate_hz: float
    beta_nominal: float | None
    beta: tuple[float, float]  # effective (up, down)
    t_start: float
    t_end: float
    tab: CycleTable
    fit: np.ndarray
    hold: np.ndarray
    has_setpoint: bool
    t0_log: float


def _get_tests(flight: FlightLog, analysis: Any) -> list:
    segs = None
    if analysis is not None:
        segs = getattr(analysis, "segments", None) or getattr(analysis, "mrft_tests", None)
        if segs is None:
            cand = getattr(analysis, "tests", None)
            if cand and all(hasattr(t, "cycles") and hasattr(t, "loop_sign") for t in cand):
                segs = cand
    if segs is None:
        from .segment import segment

        segs = segment(flight)
    return list(segs)


def _prepare(flight: FlightLog, segs: list) -> tuple[list[_Test], float, list[str]]:
    warnings: list[str] = []
    t_y = flight.output.index.to_numpy(dtype=float)
    y = flight.output.to_numpy(dtype=float)
    ok = np.isfinite(t_y) & np.isfinite(y)
    t_y, y = t_y[ok], y[ok]
    t0_log = float(min(flight.command.index.min(), flight.output.index.min()))
    tests: list[_Test] = []
    rss = 0.0
    nsamp = 0
    for s in segs:
        st = [c for c in s.cycles if c.stable]
        if len(st) < MIN_CYCLES:
            warnings.append(
                f"test {s.index + 1} (beta {s.beta:.2f}) has {len(st)} stable cycles; the diagnosis needs "
                f"{MIN_CYCLES}, so it is left out"
            )
            continue
        r = s.setpoint if s.setpoint is not None else None
        has_sp = r is not None
        if r is None:
            # without a setpoint the relay's reference is unknown: take the oscillation centre
            r = float(np.median([c.centre for c in st]))
        yy = s.loop_sign * (y - r) if s.setpoint is not None else s.loop_sign * (y - r)
        tab = cycle_table(t_y, yy, s.h, [c.t_start for c in st], [c.t_switch for c in st], [c.t_end for c in st])
        good = np.isfinite(tab.amplitude) & (tab.amplitude > 0)
        tab = tab.subset(good)
        if len(tab) < MIN_CYCLES:
            continue
        idx = np.arange(len(tab))
        b_up = float(np.nanmedian(tab.beta_up))
        b_dn = float(np.nanmedian(tab.beta_dn))
        if not (-1 < b_up < 1 and -1 < b_dn < 1):
            b_up = b_dn = float(s.beta)
        rss += float(tab.resid_ss.sum())
        nsamp += int(tab.n_samples.sum()) - len(tab) * (2 * N_HARM + 2)
        tests.append(
            _Test(
                index=s.index,
                h=float(s.h),
                bias=float(s.bias),
                rate_hz=float(s.rate_hz),
                beta_nominal=None if s.beta_nominal is None else float(s.beta_nominal),
                beta=(b_up, b_dn),
                t_start=float(tab.start[0]),
                t_end=float(tab.end[-1]),
                tab=tab,
                fit=idx % 2 == 0,
                hold=idx % 2 == 1,
                has_setpoint=has_sp,
                t0_log=t0_log,
            )
        )
    noise = math.sqrt(rss / nsamp) if nsamp > 0 else 0.0
    return tests, noise, warnings


# --------------------------------------------------------------------------------------------------
# model evaluation


@dataclass
class _Eval:
    """A candidate's prediction for one test (at K = 1 unless noted)."""

    features: np.ndarray  # FEATURE_NAMES order, log amplitude at K = 1
    cycle: CycleTable  # the model's periodic cycle (one row), K = 1
    gain: float  # battery gain g at the test's reference time (1 unless gain drift)


class _Model:
    """Evaluates one candidate's limit cycles for every test, with warm starts."""

    def __init__(self, cand: Candidate | None, tests: list[_Test], Tp: float) -> None:
        self.cand = cand
        self.tests = tests
        self.Tp = Tp
        self.warm: dict[int, dict] = {}
        self.name = cand.name if cand else "base"

    # theta layout: [ln Td (or ln q), 10 tau, (effect parameter scaled)]
    def unpack(self, theta: np.ndarray) -> dict:
        c = self.cand
        p = {"Td": math.exp(theta[0]), "tau": theta[1] / 10.0, "extra": None}
        if c is None or c.stochastic:
            return p
        hs = np.mean([t.h for t in self.tests])
        x = theta[2] if len(theta) > 2 else None
        if c.name == "input_bias":
            p["extra"] = x * hs
        elif c.name == "gain_drift":
            p["extra"] = x / 100.0
        elif c.name == "sensor_lag":
            p["extra"] = x / 10.0
        elif c.name == "actuator_rate_limit":
            p["extra"] = x / (10.0 * hs)  # rho = 1/R [s per command unit]
        elif c.name == "quadratic_drag":
            p["q"] = math.exp(theta[0])
            p["Td"] = None
        return p

    def plant(self, p: dict, test: _Test, t_ref: float) -> tuple[Plant, float]:
        """Plant (K = 1) for a test at reference time t_ref [s, log time]; returns (plant, gain)."""
        name = self.cand.name if self.cand else "base"
        if name == "quadratic_drag":
            return Plant(self.Tp, 1.0, p["tau"], 1.0, quadratic_drag=p["q"]), 1.0
        base = Plant(self.Tp, p["Td"], p["tau"], 1.0)
        if name == "input_bias":
            return Plant(self.Tp, p["Td"], p["tau"], 1.0, input_bias=p["extra"]), 1.0
        if name == "sensor_lag":
            return Plant(self.Tp, p["Td"], p["tau"], 1.0, sensor_lag=max(p["extra"], 1e-4)), 1.0
        if name == "actuator_rate_limit":
            rho = p["extra"]
            return Plant(self.Tp, p["Td"], p["tau"], 1.0, rate_limit=(1.0 / rho) if rho > 1e-9 else 0.0), 1.0
        if name == "gain_drift":
            g = 1.0 + p["extra"] * (t_ref - test.t0_log)
            g = max(g, 0.05)
            return quasi_static_plant(base, g, test.bias), g
        return base, 1.0

    def evaluate(self, theta: np.ndarray, test_i: int, t_ref: float, *, key: int | None = None) -> _Eval | None:
        test = self.tests[test_i]
        p = self.unpack(theta)
        plant, g = self.plant(p, test, t_ref)
        k = test_i if key is None else key
        try:
            # the continuous relay does not need the log's tick: ~100 samples per period suffice for
            # the harmonic projection and keep the cubic interpolation of the switches exact to 1e-8
            rate = min(test.rate_hz, 100.0 / float(np.mean(test.tab.period)))
            run = periodic_cycle(plant, test.beta, test.h, rate, warm=self.warm.get(k), tol=3e-7)
        except (FloatingPointError, ValueError, OverflowError, ZeroDivisionError):
            return None
        if run is None or run.up.size < 2:
            return None
        self.warm[k] = run.state_at_up[-1]
        u0, u1 = run.up[-2], run.up[-1]
        dn = run.down[(run.down > u0) & (run.down < u1)]
        if dn.size != 1:
            return None
        cyc = cycle_table(run.t, run.y, test.h, [u0], dn[:1], [u1])
        if not np.isfinite(cyc.amplitude[0]) or cyc.amplitude[0] <= 0:
            return None
        f = summarize_features(cyc).values.copy()
        f[np.isnan(f)] = 0.0
        # analytic trends of the quasi-static gain drift
        if self.cand is not None and self.cand.name == "gain_drift":
            gd = p["extra"]
            f[FEATURE_NAMES.index("amplitude_trend")] = gd / g
            # balance D = -d_eff / (2 h), d_eff = ((g - 1) b) / g  ->  dD/dt = -b gd / (2 h g^2)
            f[FEATURE_NAMES.index("balance_trend")] = -test.bias * gd / (2.0 * test.h * g * g)
        else:
            f[FEATURE_NAMES.index("amplitude_trend")] = 0.0
            f[FEATURE_NAMES.index("balance_trend")] = 0.0
        return _Eval(features=f, cycle=cyc, gain=g)


def _feature_mask(test: _Test) -> np.ndarray:
    m = np.ones(len(FEATURE_NAMES), bool)
    if not test.has_setpoint:
        m[FEATURE_NAMES.index("centre")] = False
    return m


def _sigma(rec_sigma: np.ndarray, rec_values: np.ndarray) -> np.ndarray:
    floor = np.array([_FLOOR[n] for n in FEATURE_NAMES])
    floor = floor.copy()
    floor[0] *= rec_values[0]  # period floor is relative
    rs = np.nan_to_num(np.asarray(rec_sigma, float), nan=0.0, posinf=np.inf)
    with np.errstate(over="ignore"):
        s = np.sqrt(np.where(np.isfinite(rs), rs, np.inf) ** 2 + floor**2)
    return s


@dataclass
class _Fit:
    theta: np.ndarray
    K: float
    chi2: float
    n: int
    k: int
    resid: np.ndarray
    evals: list
    cov: np.ndarray | None
    ok: bool


def _residuals(model: _Model, theta: np.ndarray, recs: list, with_K: bool = False):
    """Stacked z residuals over tests; K eliminated in closed form (weighted mean of ln A)."""
    evals = []
    ia = FEATURE_NAMES.index("log_amplitude")
    num = den = 0.0
    for i, (f_rec, s) in enumerate(recs):
        ev = model.evaluate(theta, i, f_rec.t_mean)
        if ev is None:
            return None
        evals.append(ev)
        w = 1.0 / s[ia] ** 2
        num += w * (f_rec.values[ia] - ev.features[ia])
        den += w
    lnK = num / den
    out = []
    for (f_rec, s), ev, test in zip(recs, evals, model.tests):
        fm = ev.features.copy()
        fm[ia] += lnK
        z = (f_rec.values - fm) / s
        out.append(z[_feature_mask(test)])
    r = np.concatenate(out)
    if with_K:
        return r, math.exp(lnK), evals
    return r


def _fit(model: _Model, theta0: np.ndarray, lo: np.ndarray, hi: np.ndarray, recs: list, max_nfev: int = 60,
         free: np.ndarray | None = None) -> _Fit:
    """Least-squares fit of the candidate's parameters (``free`` selects the ones that move)."""
    big = 1e3
    theta0 = np.clip(np.asarray(theta0, float), lo + 1e-9, hi - 1e-9)
    free = np.ones(theta0.size, bool) if free is None else np.asarray(free, bool)
    full0 = theta0.copy()

    def expand(x):
        th = full0.copy()
        th[free] = x
        return th

    def fun(x):
        th = expand(x)
        r = _residuals(model, th, recs)
        if r is None or not np.all(np.isfinite(r)):
            n = sum(int(_feature_mask(t).sum()) for t in model.tests)
            return np.full(n, big)
        return r

    try:
        sol = least_squares(fun, theta0[free], bounds=(lo[free], hi[free]), diff_step=1e-3, max_nfev=max_nfev,
                            x_scale=1.0)
        theta = expand(sol.x)
        J = sol.jac if free.all() else None
    except (ValueError, np.linalg.LinAlgError):
        theta, J = theta0, None
    got = _residuals(model, theta, recs, with_K=True)
    if got is None:
        return _Fit(theta, float("nan"), float("inf"), 0, len(theta) + 1, np.array([]), [], None, False)
    r, K, evals = got
    cov = None
    if J is not None:
        try:
            cov = np.linalg.pinv(J.T @ J)
        except np.linalg.LinAlgError:
            cov = None
    return _Fit(theta, K, float(r @ r), int(r.size), len(theta) + 1, r, evals, cov, bool(np.all(np.abs(r) < big)))


# --------------------------------------------------------------------------------------------------
# scatter (sampled relay with noise and jitter)


def _sim_scatter(plant: Plant, beta: float, test: _Test, noise: float, jitter: float, warm: dict | None,
                 n_cycles: int = 50, seed: int = 0) -> float:
    """Cycle-to-cycle period std of the sampled, noisy relay on ``plant`` [s]."""
    run = run_relay(plant, beta, test.h, test.rate_hz, n_cycles + 3, warm=warm, sampled=True,
                    noise_std=noise, jitter_std=jitter, seed=seed, max_time=(n_cycles + 4) * 20.0)
    up = run.up[2:]
    if up.size < 6:
        return float("nan")
    per = np.diff(up)
    # the recorded scatter is measured on the segmenter's stable cycles, which drops cycles whose
    # period *or amplitude* is inconsistent (a jitter-hit cycle often is): the simulated cycles go
    # through the very same criterion, so model and measurement see the same cycles
    k = np.searchsorted(run.t, up)
    amp = np.array([0.5 * (run.y[a:b].max() - run.y[a:b].min()) if b > a else np.nan for a, b in zip(k[:-1], k[1:])])
    stable, _, _ = stable_cycles(per, amp, np.isfinite(amp), 1.0 / test.rate_hz)
    per = per[stable]
    if per.size < 5:
        return float("nan")
    return float(np.std(per, ddof=1))


# --------------------------------------------------------------------------------------------------
# waveform NRMSE and harmonics


def _model_wave(ev: _Eval, K: float, t_rel: np.ndarray, period: float | None = None) -> np.ndarray:
    """The model cycle at times ``t_rel`` after its -h -> +h switch; with ``period`` [s] it is put on
    that period (phase-normalised) instead of its own."""
    c = ev.cycle
    if period is not None:
        t_rel = t_rel * (c.period[0] / period)
    return K * c.waveform(0, c.start[0] + t_rel, trend=False)


def _waveform_errors(test: _Test, mask: np.ndarray, evs: list, K: float, t_refs: np.ndarray | None = None,
                     flight_t: np.ndarray | None = None, phase: bool = False
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per selected cycle: sum of squared error, sum of squares about the mean, and per half (high, low).

    ``phase=True`` puts the model cycle on the same reference period as the recorded ones (the
    held-out NRMSE: a 0.3 % period error, the sampling error of the mean of a few periods, would
    otherwise make 2-3 % of waveform error; the period is judged by the feature z-scores).
    """
    tab = test.tab
    idx = np.flatnonzero(mask)
    sse = np.zeros(idx.size)
    sst = np.zeros(idx.size)
    sse_hi = np.zeros(idx.size)
    sse_lo = np.zeros(idx.size)
    # Each recorded cycle is put on the mean period of the selected cycles (phase-normalised): the
    # cycle-to-cycle timing scatter of a sampled, noisy relay (a tick or two) is not a model error,
    # a systematic period error still is unless ``phase`` (the model cycle keeps its own period).
    P_ref = float(np.mean(tab.period[idx])) if idx.size else 1.0
    for j, i in enumerate(idx):
        P = P_ref
        tt = np.linspace(0.0, P, 200, endpoint=False)
        y_rec = tab.waveform(i, tab.start[i] + tt * tab.period[i] / P_ref)
        Pm = P_ref if phase else None
        if len(evs) == 1:
            y_mod = _model_wave(evs[0], K, tt, Pm)
        else:  # quasi-static models at several times: interpolate linearly in time
            tm = tab.start[i] + 0.5 * P
            w = np.interp(tm, t_refs, np.arange(len(evs)))
            a = int(min(math.floor(w), len(evs) - 2))
            lam = w - a
            y_mod = (1 - lam) * _model_wave(evs[a], K, tt, Pm) + lam * _model_wave(evs[a + 1], K, tt, Pm)
        err = y_rec - y_mod
        sse[j] = float(err @ err) / tt.size
        sst[j] = float(np.var(y_rec))
        hi = tt < tab.high[i] * P_ref / tab.period[i]
        sse_hi[j] = float(np.mean(err[hi] ** 2)) if hi.any() else 0.0
        sse_lo[j] = float(np.mean(err[~hi] ** 2)) if (~hi).any() else 0.0
    return sse, sst, sse_hi, sse_lo


def _cycle_scatter(test: _Test, mask: np.ndarray) -> float:
    """Sum over the selected recorded cycles of their cycle-to-cycle scatter [output units^2 x cycles].

    The sampled relay decides on noisy samples, so every cycle's switch instants and centre move
    by a tick or a fraction of a millimetre: the recorded cycles scatter about the waveform the
    plant would repeat, and no deterministic model can predict that part. For the n selected
    cycles y_i (on the same phase grid as in :func:`_waveform_errors`) and any model m_i,
    E sum_i |y_i - m_i|^2 = sum_i |mu_i - m_i|^2 + n s^2, mu_i the scatter-free waveform. With
    mu_i = a + b t_i (a slow drift such as a battery sag is not scatter) the residual sum of squares
    of the per-phase least-squares line is (n - 2) s^2, so n s^2 = RSS n / (n - 2) (for n = 3 a
    constant a: RSS n / (n - 1)). Subtracting it leaves an unbiased estimate of the systematic error.
    """
    tab = test.tab
    idx = np.flatnonzero(mask)
    n = idx.size
    if n < 3:
        return 0.0
    P_ref = float(np.mean(tab.period[idx]))
    tt = np.linspace(0.0, P_ref, 200, endpoint=False)
    Y = np.array([tab.waveform(i, tab.start[i] + tt * tab.period[i] / P_ref) for i in idx])
    tm = tab.start[idx] - tab.start[idx].mean()
    X = np.column_stack([np.ones(n), tm]) if n >= 4 else np.ones((n, 1))
    coef, *_ = np.linalg.lstsq(X, Y, rcond=None)
    rss = float(np.sum((Y - X @ coef) ** 2)) / tt.size
    return rss * n / (n - X.shape[1])


def _harmonic_errors(test: _Test, mask: np.ndarray, ev: _Eval, K: float) -> dict:
    """Relative error of the measured G(j k Omega) = Y_k/U_k against the model's, odd k."""
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        G_rec = np.nanmean(test.tab.G[mask], axis=0)
    G_mod = K * ev.cycle.G[0]
    out = {}
    for k in (1, 3, 5, 7):
        if np.isfinite(G_rec[k]) and np.isfinite(G_mod[k]) and abs(G_mod[k]) > 0:
            out[str(k)] = float(abs(G_rec[k] - G_mod[k]) / abs(G_mod[k]))
    return out


# --------------------------------------------------------------------------------------------------
# the diagnosis


def _initial_base(tests: list[_Test], Tp: float, extra_phase: Callable | None = None) -> np.ndarray:
    """Td, tau from the describing-function phase condition at each test's frequency.

    arg G(jW) - W/(2 f_s) + extra = -pi + asin(beta), with arg G = -pi/2 - atan(W Tp) - atan(W Td) - W tau;
    ``extra_phase(W, test)`` adds a candidate's own phase [rad] (e.g. -atan(W T_lag)).
    """
    W = np.array([2 * np.pi / np.mean(t.tab.period[t.fit]) for t in tests])
    B = np.array([np.mean(t.beta) for t in tests])
    fs = np.array([t.rate_hz for t in tests])
    extra = np.zeros(len(tests)) if extra_phase is None else np.array([extra_phase(w, t) for w, t in zip(W, tests)])

    def res(x):
        Td, tau = math.exp(x[0]), x[1]
        ph = -np.pi / 2 - np.arctan(W * Tp) - np.arctan(W * Td) - W * (tau + 0.5 / fs) + extra
        return ph - (-np.pi + np.arcsin(B))

    best = None
    for td0 in (0.3, 1.0, 3.0):
        try:
            s = least_squares(res, [math.log(td0), 0.03], bounds=([math.log(0.02), 0.0], [math.log(100.0), 0.5]))
        except ValueError:
            continue
        if best is None or s.cost < best.cost:
            best = s
    x = best.x if best is not None else np.array([0.0, 0.03])
    return np.array([x[0], 10 * x[1]])


def _bounds(cand: Candidate | None, tests: list[_Test]) -> tuple[np.ndarray, np.ndarray]:
    lo = [math.log(0.02), 0.0]
    hi = [math.log(100.0), 5.0]
    if cand is not None and cand.replaces_drag:
        lo[0], hi[0] = math.log(1e-4), math.log(1e6)
    if cand is None or cand.stochastic or cand.replaces_drag:
        return np.array(lo), np.array(hi)
    hmin = min(t.h for t in tests)
    hs = np.mean([t.h for t in tests])
    extra = {
        "input_bias": (-0.9 * hmin / hs, 0.9 * hmin / hs),
        "gain_drift": (-5.0, 5.0),
        "sensor_lag": (0.002, 3.0),
        "actuator_rate_limit": (0.0, 10.0),
    }[cand.name]
    return np.array(lo + [extra[0]]), np.array(hi + [extra[1]])


def _start(cand: Candidate, base: _Fit, tests: list[_Test], recs: list, Tp: float) -> list[np.ndarray]:
    th = base.theta
    hs = np.mean([t.h for t in tests])
    if cand.name == "input_bias":
        d = np.mean([-2.0 * t.h * f.values[FEATURE_NAMES.index("balance")] for t, (f, _) in zip(tests, recs)])
        return [np.array([th[0], th[1], d / hs])]
    if cand.name == "gain_drift":
        # amplitude trend ~ g; where the hover command b is non-zero the battery also shifts the trim:
        # balance trend dD/dt ~ -b g / (2 h)
        ga = float(np.mean([f.values[FEATURE_NAMES.index("amplitude_trend")] for f, _ in recs]))
        starts = [np.array([th[0], th[1], 100 * ga])]
        gb = [-2.0 * t.h * f.values[FEATURE_NAMES.index("balance_trend")] / t.bias for t, (f, _) in zip(tests, recs)
              if abs(t.bias) > 0.2 * t.h]
        if gb:
            starts.insert(0, np.array([th[0], th[1], 100 * float(np.median(gb))]))
        return starts
    if cand.name == "sensor_lag":
        # profile over a grid of lags: Td and tau from the describing function with the lag's phase
        out = []
        for tl in (0.01, 0.03, 0.06, 0.1, 0.16):
            b = _initial_base(tests, Tp, lambda w, t, tl=tl: -math.atan(w * tl))
            out.append(np.array([b[0], b[1], 10 * tl]))
        return out
    if cand.name == "actuator_rate_limit":
        # a ramp of 2h/R delays the relay's first harmonic by h/R: profile over that extra delay
        out = []
        for ex in (0.005, 0.012, 0.025, 0.045, 0.07):
            rho = ex / hs
            b = _initial_base(tests, Tp, lambda w, t, rho=rho: -w * t.h * rho)
            out.append(np.array([b[0], b[1], 10 * hs * rho]))
        return out
    if cand.name == "quadratic_drag":
        # describing-function equivalent at the middle test's velocity amplitude (K = 1 units)
        Td = math.exp(th[0])
        f, _ = recs[len(recs) // 2]
        a1 = math.exp(f.values[FEATURE_NAMES.index("log_amplitude")]) / base.K
        V = a1 * 2 * np.pi / f.values[0]
        q = df_quadratic_drag(Td, V)
        return [np.array([math.log(q), th[1]])]
    raise ValueError(cand.name)


def _held_out(model: _Model, fit: _Fit, tests: list[_Test], recs_hold: list, gain_times: bool) -> dict:
    """Score a fitted model on the held-out cycles: feature z RMS and waveform NRMSE."""
    zs = []
    sse = sst = floor = sse_timed = 0.0
    per_test = []
    per_test_raw = []
    ia = FEATURE_NAMES.index("log_amplitude")
    for i, (test, (f_rec, s)) in enumerate(zip(tests, recs_hold)):
        ev = model.evaluate(fit.theta, i, f_rec.t_mean, key=1000 + i)
        if ev is None:
            return {"nrmse": None, "feature_rms_z": None}
        fm = ev.features.copy()
        fm[ia] += math.log(fit.K)
        z = ((f_rec.values - fm) / s)[_feature_mask(test)]
        zs.append(z)
        if gain_times:
            t_refs = np.array([test.t_start, 0.5 * (test.t_start + test.t_end), test.t_end])
            evs = [model.evaluate(fit.theta, i, tr, key=2000 + 10 * i + j) for j, tr in enumerate(t_refs)]
            if any(e is None for e in evs):
                return {"nrmse": None, "feature_rms_z": None}
        else:
            t_refs, evs = None, [ev]
        e, v, _, _ = _waveform_errors(test, test.hold, evs, fit.K, t_refs, phase=True)
        sse_timed += float(_waveform_errors(test, test.hold, evs, fit.K, t_refs)[0].sum())
        # the cycle-to-cycle scatter of the recording (relay ticks on noisy samples) is the same for
        # every model: it is taken out, so the NRMSE measures the systematic (model) error
        fl = _cycle_scatter(test, test.hold)
        sse += float(e.sum())
        sst += float(v.sum())
        floor += fl
        per_test.append(math.sqrt(max(e.sum() - fl, 0.0) / v.sum()) if v.sum() > 0 else None)
        per_test_raw.append(math.sqrt(e.sum() / v.sum()) if v.sum() > 0 else None)
    z = np.concatenate(zs)
    return {
        "nrmse": math.sqrt(max(sse - floor, 0.0) / sst) if sst > 0 else None,
        "nrmse_raw": math.sqrt(sse / sst) if sst > 0 else None,
        "nrmse_timed": math.sqrt(sse_timed / sst) if sst > 0 else None,
        "scatter_nrmse": math.sqrt(floor / sst) if sst > 0 else None,
        "nrmse_per_test": per_test,
        "nrmse_raw_per_test": per_test_raw,
        "feature_rms_z": float(np.sqrt(np.mean(z**2))),
        "cycles": int(sum(int(t.hold.sum()) for t in tests)),
    }


def _params_out(model: _Model, fit: _Fit) -> dict:
    p = model.unpack(fit.theta)
    out = {"tau": p["tau"], "K": fit.K}
    if p.get("Td") is not None:
        out["Td"] = p["Td"]
    return out


def _std_of(fit: _Fit, j: int) -> float:
    if fit.cov is None or j >= fit.cov.shape[0]:
        return float("nan")
    v = fit.cov[j, j]
    return float(math.sqrt(v)) if v >= 0 else float("nan")


def diagnose(
    flight: FlightLog | str | Path | None = None,
    Tp: float | None = None,
    analysis: Any = None,
    *,
    path: str | Path | None = None,
    tp: float | None = None,
    loop: str | None = None,
    command_topic: str | None = None,
    output_topic: str | None = None,
    beta_topic: str | None = None,
    setpoint_topic: str | None = None,
    output_scale: float | None = None,
    candidates: tuple[str, ...] | None = None,
    progress: Callable[[str], None] | None = None,
) -> DiagnosisResult:
    """Locate model mismatch in an MRFT flight log, name the missing physics, fit it, compare.

    Parameters
    ----------
    flight : FlightLog or path
        The log (already read), or a path that is read with :func:`mrftcli.readers.read_flight`
        using ``loop`` and the topic options. ``path=`` is accepted as an alias.
    Tp : float
        Propulsion time constant [s] (known from a bench test, as for ``analyze``). ``tp=`` alias.
    analysis : AnalysisResult, optional
        An analysis of the same log already computed (its segmentation is reused and its
        identification is reported beside the diagnosis' own fits).
    loop, command_topic, output_topic, beta_topic, setpoint_topic, output_scale
        Passed to the reader when ``flight`` is a path.
    candidates : tuple of str, optional
        Restrict the candidate library (JSON names); default all.
    progress : callable, optional
        Called with a short text before each stage (for a progress bar).

    Returns
    -------
    DiagnosisResult

    Raises
    ------
    InputError
        Tp missing or not positive, unknown candidate name.
    SegmentationError, LogReadError
        From reading/segmenting the log.
    DiagnoseError
        No test with enough stable cycles, or the base model cannot reproduce any limit cycle.
    """
    Tp = Tp if Tp is not None else tp
    if Tp is None or not (isinstance(Tp, (int, float)) and math.isfinite(Tp) and Tp > 0):
        raise InputError(f"Tp must be a positive time in seconds (the bench-measured propulsion time constant), got {Tp!r}")
    if flight is None:
        flight = path
    if flight is None and analysis is not None:
        flight = getattr(analysis, "flight", None)
    if flight is None:
        raise InputError("give the flight log (a FlightLog or a path)")
    if not isinstance(flight, FlightLog):
        from .readers import read_flight

        kw = {}
        for name, value in (("command_topic", command_topic), ("output_topic", output_topic),
                            ("beta_topic", beta_topic), ("setpoint_topic", setpoint_topic),
                            ("output_scale", output_scale)):
            if value is not None:
                kw[name] = value
        flight = read_flight(str(flight), loop or "altitude", **kw)
    names = [c.name for c in CANDIDATES] if candidates is None else list(candidates)
    for n in names:
        if n not in BY_NAME:
            raise InputError(f"unknown candidate effect {n!r}; choose from {', '.join(BY_NAME)}")
    say = progress or (lambda _msg: None)

    say("segmenting")
    segs = _get_tests(flight, analysis)
    tests, noise, warnings = _prepare(flight, segs)
    if not tests:
        raise DiagnoseError(
            f"{flight.path}: no MRFT test with at least {MIN_CYCLES} stable cycles; the diagnosis compares "
            "cycles, so record longer tests"
        )
    if len({round(np.mean(t.beta), 2) for t in tests}) < 2:
        warnings.append("all tests share one beta: Td and tau are fitted from the waveform shape alone (weakly identified)")

    recs_fit = []
    recs_hold = []
    recs_all = []
    for t in tests:
        for mask, store in ((t.fit, recs_fit), (t.hold, recs_hold), (np.ones(len(t.tab), bool), recs_all)):
            f = summarize_features(t.tab.subset(mask))
            store.append((f, _sigma(f.sigma, f.values)))

    # ---- base model
    say("fitting the linear model")
    base_model = _Model(None, tests, Tp)
    lo, hi = _bounds(None, tests)
    th0 = _initial_base(tests, Tp)
    base = _fit(base_model, th0, lo, hi, recs_fit)
    if not base.ok:
        raise DiagnoseError(f"{flight.path}: the linear model reproduces no limit cycle close to the recorded ones")
    n_data = base.n

    # ---- scatter predicted by noise on a sampled relay (base model)
    say("simulating the noise-driven scatter")
    pb = base_model.unpack(base.theta)
    scatter = []
    for i, t in enumerate(tests):
        plant = Plant(Tp, pb["Td"], pb["tau"], base.K)
        beta_s = t.beta_nominal if t.beta_nominal is not None else float(np.mean(t.beta))
        warm = base_model.warm.get(i)
        if warm is not None:
            # the warm state was computed at K = 1: output and rate scale with K, the propulsion state not
            x = np.asarray(warm["x"], float).copy()
            x[:2] *= base.K
            x[3:] *= base.K
            warm = dict(warm, x=x)
            warm["e_prev"] *= base.K
            warm["de_prev"] *= base.K
            warm["e_ext"] *= base.K
        s0 = _sim_scatter(plant, beta_s, t, noise, 0.0, warm, seed=1)
        if not (np.isfinite(s0) and s0 < 0.2 * float(np.mean(t.tab.period))):
            s0 = float("nan")  # the sampled relay broke down (false switches): no scatter reference
        scatter.append({"plant": plant, "beta": beta_s, "warm": warm, "s0": s0})

    def scatter_z(sel: str, s_pred: list[float]) -> np.ndarray:
        out = []
        for t, sc, sp in zip(tests, scatter, s_pred):
            if not (np.isfinite(sp) and np.isfinite(sc["s0"])):
                out.append(0.0)
                continue
            mask = t.fit if sel == "fit" else (t.hold if sel == "hold" else np.ones(len(t.tab), bool))
            per = t.tab.period[mask]
            n = per.size
            s_rec = float(np.std(per, ddof=1))
            s_floor = 0.5 / t.rate_hz / math.sqrt(3.0)  # never compare below the tick quantisation
            a, b = max(s_rec, s_floor), max(sp, s_floor)
            se = math.sqrt(1.0 / (2 * (n - 1)) + 1.0 / (2 * 49))
            out.append(math.log(a / b) / se)
        return np.array(out)

    z_sc_base = scatter_z("fit", [sc["s0"] for sc in scatter])
    chi2_base = base.chi2 + float(z_sc_base @ z_sc_base)
    n_all = n_data + len(tests)
    bic_base = chi2_base + base.k * math.log(n_all)

    before = _held_out(base_model, base, tests, recs_hold, gain_times=False)

    # ---- candidates
    cand_rows = []
    fits: dict[str, tuple[_Model, _Fit]] = {}
    for cand in CANDIDATES:
        if cand.name not in names:
            continue
        say(f"fitting {cand.name}")
        if cand.stochastic:
            row = _jitter_candidate(cand, tests, scatter, noise, scatter_z, base, bic_base, n_all)
            cand_rows.append(row)
            continue
        model = _Model(cand, tests, Tp)
        lo, hi = _bounds(cand, tests)
        best = None
        starts = _start(cand, base, tests, recs_fit, Tp)
        if len(starts) > 2:
            # profile over the grid: at each grid value fit Td and tau with the effect held (the effect
            # and the delay trade off along a curved valley), then refine the two best freely
            prof = []
            free = np.ones(len(starts[0]), bool)
            free[2:] = False
            for th in starts:
                pf = _fit(model, th, lo, hi, recs_fit, max_nfev=16, free=free)
                if pf.ok and np.isfinite(pf.chi2):
                    prof.append(pf)
            prof.sort(key=lambda f: f.chi2)
            starts = [pf.theta for pf in prof[:2]]
        for th in starts:
            f = _fit(model, th, lo, hi, recs_fit)
            if f.ok and (best is None or f.chi2 < best.chi2):
                best = f
        if best is None:
            cand_rows.append({"name": cand.name, "delta_bic": None, "status": "fit failed"})
            continue
        chi2 = best.chi2 + float(z_sc_base @ z_sc_base)
        bic = chi2 + best.k * math.log(n_all)
        after = _held_out(model, best, tests, recs_hold, gain_times=cand.name == "gain_drift")
        p = model.unpack(best.theta)
        value, std = _effect_value(cand, model, best, p)
        fits[cand.name] = (model, best)
        cand_rows.append(
            {
                "name": cand.name,
                "parameter": cand.parameter,
                "value": value,
                "std": std,
                "unit": cand.unit,
                "chi2": chi2,
                "bic": bic,
                "delta_bic": bic_base - bic,
                "held_out_before": before,
                "held_out_after": after,
                "fit_params": _params_out(model, best),
            }
        )

    # ---- selection: strong evidence and confirmed on the held-out cycles
    for row in cand_rows:
        row["significant"] = _significant(row)
    chosen = [r for r in cand_rows if r["significant"]]
    chosen.sort(key=lambda r: -r["delta_bic"])
    effects = []
    base_params = _params_out(base_model, base)
    for row in chosen[:1]:
        cand = BY_NAME[row["name"]]
        ident = {"linear": base_params, "with_effect": row.get("fit_params") or base_params}
        harm = {}
        if row["name"] in fits:
            model, fit = fits[row["name"]]
            harm = _harmonics_before_after(tests, base_model, base, model, fit)
        effects.append(
            EffectFinding(
                name=cand.name,
                explanation=cand.explanation,
                augmentation=cand.augmentation,
                parameters={cand.parameter: row["value"], f"{cand.parameter}_std": row["std"], "unit": cand.unit,
                            **{f"{k}": v for k, v in (row.get("fit_params") or {}).items()}},
                evidence={"delta_bic": row["delta_bic"], "bic_base": bic_base, "bic": row["bic"],
                          "n_features": n_all, "threshold": BIC_THRESHOLD},
                fit_before=_fit_summary(row["held_out_before"]),
                fit_after=_fit_summary(row["held_out_after"]),
                identification=ident,
                harmonics=harm,
            )
        )

    # ---- locate (base model against all cycles)
    say("locating")
    located, plot = _locate(tests, base_model, base, recs_all, scatter)
    identification = {"linear": {**base_params, "Tp": Tp}}
    for e in effects:
        identification[f"with_{e.name}"] = {**e.identification["with_effect"], "Tp": Tp}
    if analysis is not None:
        identification["analyze"] = _analysis_params(analysis)
    if effects:
        e = effects[0]
        summary = (
            f"{e.name} explains the mismatch ({e.parameters.get(BY_NAME[e.name].parameter):.4g} {BY_NAME[e.name].unit}; "
            f"delta BIC {e.evidence['delta_bic']:.0f}); held-out NRMSE {_fmt(e.fit_before.get('nrmse'))} -> "
            f"{_fmt(e.fit_after.get('nrmse'))}"
        )
    else:
        summary = "the linear model explains the log: no candidate effect has strong evidence confirmed on held-out cycles"
    test_rows = [
        {
            "index": t.index,
            "beta_nominal": t.beta_nominal,
            "beta_effective_up": t.beta[0],
            "beta_effective_down": t.beta[1],
            "h": t.h,
            "bias": t.bias,
            "rate_hz": t.rate_hz,
            "t_start": t.t_start,
            "t_end": t.t_end,
            "cycles": len(t.tab),
            "cycles_fit": int(t.fit.sum()),
            "cycles_held_out": int(t.hold.sum()),
            "period_scatter": float(np.std(t.tab.period, ddof=1)),
            "period_scatter_noise_model": sc["s0"],
        }
        for t, sc in zip(tests, scatter)
    ]
    plot.update({"tests": tests, "base_model": base_model, "base": base, "fits": fits, "flight": flight,
                 "effects": [e.name for e in effects]})
    return DiagnosisResult(
        path=str(flight.path),
        loop=flight.loop,
        Tp=float(Tp),
        effects=effects,
        candidates=cand_rows,
        located=located,
        identification=identification,
        tests=test_rows,
        noise_std=noise,
        summary=summary,
        warnings=warnings,
        _plot=plot,
    )


def _fmt(x) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def _fit_summary(h: dict) -> dict:
    return {k: h.get(k) for k in ("nrmse", "nrmse_raw", "nrmse_timed", "scatter_nrmse", "feature_rms_z", "cycles",
                                  "nrmse_per_test",
                                  "metric") if k in h}


def _significant(row: dict) -> bool:
    db = row.get("delta_bic")
    if db is None or not np.isfinite(db) or db < BIC_THRESHOLD:
        return False
    b, a = row.get("held_out_before") or {}, row.get("held_out_after") or {}
    if b.get("nrmse") is None or a.get("nrmse") is None:
        return False
    if row["name"] == "delay_jitter":
        # a jitter below half a controller tick cannot be told from the tick quantisation itself
        return a["nrmse"] < b["nrmse"] and row.get("value", 0.0) >= row.get("min_value", 0.0)
    # confirmation on the held-out cycles: the whole waveform error as timed (the model cycle on its own
    # period, so the period counts; the recording's scatter is common to both sides) and the features
    key = "nrmse_timed" if a.get("nrmse_timed") is not None and b.get("nrmse_timed") is not None else "nrmse"
    return a[key] < b[key] and (a.get("feature_rms_z") or 0) < (b.get("feature_rms_z") or 0)


def _effect_value(cand: Candidate, model: _Model, fit: _Fit, p: dict) -> tuple[float, float]:
    hs = np.mean([t.h for t in model.tests])
    if cand.name == "input_bias":
        return p["extra"], _std_of(fit, 2) * hs
    if cand.name == "gain_drift":
        return p["extra"], _std_of(fit, 2) / 100.0
    if cand.name == "sensor_lag":
        return p["extra"], _std_of(fit, 2) / 10.0
    if cand.name == "actuator_rate_limit":
        rho = p["extra"]
        R = 1.0 / rho if rho > 1e-9 else float("inf")
        s_rho = _std_of(fit, 2) / (10.0 * hs)
        return R, (s_rho / rho**2 if rho > 1e-9 else float("nan"))
    if cand.name == "quadratic_drag":
        c = p["q"] / fit.K
        return c, c * _std_of(fit, 0)
    raise ValueError(cand.name)


def _jitter_candidate(cand, tests, scatter, noise, scatter_z, base, bic_base, n_all) -> dict:
    """Fit the delay-jitter std to the period scatter: s^2 = s0^2 + c^2 sigma^2 per test."""
    trial = 0.005
    cs = []
    s_rec_fit = []
    for t, sc in zip(tests, scatter):
        s1 = _sim_scatter(sc["plant"], sc["beta"], t, noise, trial, sc["warm"], seed=1)
        c2 = max(s1**2 - sc["s0"] ** 2, 1e-12) / trial**2
        cs.append(c2)
        s_rec_fit.append(float(np.std(t.tab.period[t.fit], ddof=1)))
    cs = np.array(cs)
    s0 = np.array([sc["s0"] for sc in scatter])
    okj = np.isfinite(cs) & np.isfinite(s0)
    if not okj.any():
        return {"name": cand.name, "delta_bic": None, "status": "no scatter reference (the sampled relay broke down)"}
    cs = np.where(okj, cs, 0.0)
    s0 = np.where(okj, s0, np.nan)
    s_rec = np.array(s_rec_fit)
    ex = s_rec**2 - s0**2
    sig2 = max(float(np.nansum(cs * ex) / np.sum(cs * cs)), 0.0)
    if sig2 > 0:
        # the scatter is not exactly quadratic in sigma (first-in-first-out delays): recalibrate the
        # slope once at the estimate
        trial2 = math.sqrt(sig2)
        for j, (t, sc) in enumerate(zip(tests, scatter)):
            if okj[j]:
                s1 = _sim_scatter(sc["plant"], sc["beta"], t, noise, trial2, sc["warm"], seed=2, n_cycles=80)
                if np.isfinite(s1):
                    cs[j] = max(s1**2 - sc["s0"] ** 2, 1e-12) / trial2**2
        sig2 = max(float(np.nansum(cs * ex) / np.sum(cs * cs)), 0.0)
    sigma = math.sqrt(sig2)
    s_pred = np.sqrt(s0**2 + cs * sig2)
    # the reported value uses every stable cycle (the held-out scores below use the even-cycle fit):
    # a sample std over a handful of cycles of a skewed (first-in-first-out) delay is low more often
    # than not, so the more cycles the better
    s_all = np.array([float(np.std(t.tab.period, ddof=1)) for t in tests])
    sigma_all = math.sqrt(max(float(np.nansum(cs * (s_all**2 - s0**2)) / np.sum(cs * cs)), 0.0))
    z = scatter_z("fit", list(s_pred))
    chi2 = base.chi2 + float(z @ z)
    bic = chi2 + (base.k + 1) * math.log(n_all)
    z_base = scatter_z("fit", list(s0))
    bic_b = base.chi2 + float(z_base @ z_base) + base.k * math.log(n_all)

    def hold_err(pred):
        errs = []
        for t, sp in zip(tests, pred):
            if not np.isfinite(sp):
                continue
            sr = float(np.std(t.tab.period[t.hold], ddof=1))
            errs.append((sr - sp) / sr if sr > 0 else 0.0)
        return float(np.sqrt(np.mean(np.square(errs)))) if errs else None

    zh_b = scatter_z("hold", list(s0))
    zh_a = scatter_z("hold", list(s_pred))
    # standard error of sigma from the per-test spread of the implied sigma^2
    with np.errstate(all="ignore"):
        implied = np.sqrt(np.clip(ex / cs, 0, None))[okj]
    s_std = float(np.std(implied, ddof=1) / math.sqrt(implied.size)) if implied.size > 1 else float("nan")
    metric = "relative error of the held-out cycle-to-cycle period scatter"
    return {
        "min_value": 0.5 / min(t.rate_hz for t in tests),
        "name": cand.name,
        "parameter": cand.parameter,
        "value": sigma_all,
        "value_fit_cycles": sigma,
        "std": s_std,
        "unit": cand.unit,
        "chi2": chi2,
        "bic": bic,
        "delta_bic": bic_b - bic,
        "held_out_before": {"nrmse": hold_err(s0), "feature_rms_z": float(np.sqrt(np.mean(zh_b**2))), "metric": metric,
                            "cycles": int(sum(int(t.hold.sum()) for t in tests))},
        "held_out_after": {"nrmse": hold_err(s_pred), "feature_rms_z": float(np.sqrt(np.mean(zh_a**2))), "metric": metric,
                           "cycles": int(sum(int(t.hold.sum()) for t in tests))},
        "fit_params": None,
        "period_scatter": {"recorded": list(s_rec), "noise_only": list(s0), "with_jitter": list(s_pred)},
    }


def _harmonics_before_after(tests, base_model, base, model, fit) -> dict:
    out = {}
    for i, t in enumerate(tests):
        ev_b = base_model.evaluate(base.theta, i, t.tab.t_mid[t.hold].mean(), key=3000 + i)
        ev_a = model.evaluate(fit.theta, i, t.tab.t_mid[t.hold].mean(), key=3000 + i)
        if ev_b is None or ev_a is None:
            continue
        out[str(t.index)] = {
            "before": _harmonic_errors(t, t.hold, ev_b, base.K),
            "after": _harmonic_errors(t, t.hold, ev_a, fit.K),
        }
    return out


def _analysis_params(analysis: Any) -> dict:
    """Td, tau, K (means) of an AnalysisResult-like object, whatever its exact shape."""
    out = {}
    params = getattr(analysis, "parameters", None)
    for k in ("Td", "tau", "K"):
        v = None
        if isinstance(params, dict):
            v = params.get(k)
        elif params is not None:
            v = getattr(params, k, None)
        if v is None:
            v = getattr(analysis, k, None)
        if isinstance(v, dict):
            v = v.get("mean")
        v = getattr(v, "mean", v)
        if isinstance(v, (int, float, np.floating)) and math.isfinite(float(v)):
            out[k] = float(v)
    return out


def _locate(tests, base_model, base, recs_all, scatter) -> tuple[list, dict]:
    """Where the base model and the recording disagree: features, cycles/halves, harmonics."""
    located = []
    ia = FEATURE_NAMES.index("log_amplitude")
    plot = {"cycle_errors": [], "harmonics": []}
    errs_all = []
    for i, (t, (f, s)) in enumerate(zip(tests, recs_all)):
        ev = base_model.evaluate(base.theta, i, f.t_mean, key=4000 + i)
        if ev is None:
            continue
        fm = ev.features.copy()
        fm[ia] += math.log(base.K)
        z = (f.values - fm) / s
        for j, name in enumerate(FEATURE_NAMES):
            if not _feature_mask(t)[j] or abs(z[j]) < 3.0:
                continue
            rec, mod = float(f.values[j]), float(fm[j])
            item = {
                "kind": "feature",
                "test": t.index,
                "beta": float(np.mean(t.beta)),
                "h": t.h,
                "t_start": t.t_start,
                "t_end": t.t_end,
                "feature": name,
                "what": _FEATURE_TEXT[name],
                "recorded": rec,
                "model": mod,
                "difference": rec - mod,
                "z": float(z[j]),
            }
            if name == "log_amplitude":
                item.update(recorded=math.exp(rec), model=math.exp(mod), difference=math.exp(rec) - math.exp(mod),
                            relative=math.exp(rec - mod) - 1.0)
            if name == "period":
                item["relative"] = rec / mod - 1.0
                item["unit"] = "s"
            if name == "centre":
                a_rec = math.exp(float(f.values[ia]))
                item.update(recorded=rec * a_rec, model=mod * math.exp(float(fm[ia])),
                            difference=rec * a_rec - mod * math.exp(float(fm[ia])), unit="output units")
            if name in ("amplitude_trend", "balance_trend"):
                item["unit"] = "relative change per second" if name == "amplitude_trend" else "per second"
            if name == "balance":
                P = float(f.values[0])
                item["half_periods_recorded"] = {"high": P * (0.5 + rec), "low": P * (0.5 - rec)}
                item["half_periods_model"] = {"high": P * (0.5 + mod), "low": P * (0.5 - mod)}
            located.append(item)
        # period scatter
        sc = scatter[i]
        s_rec = float(np.std(t.tab.period, ddof=1))
        n = len(t.tab)
        se = math.sqrt(1.0 / (2 * (n - 1)) + 1.0 / (2 * 49))
        zs = math.log(max(s_rec, 1e-9) / max(sc["s0"], 1e-9)) / se
        if abs(zs) >= 3.0:
            located.append({"kind": "feature", "test": t.index, "beta": float(np.mean(t.beta)), "h": t.h,
                            "t_start": t.t_start, "t_end": t.t_end, "feature": "period_scatter",
                            "what": _FEATURE_TEXT["period_scatter"], "recorded": s_rec, "model": sc["s0"],
                            "difference": s_rec - sc["s0"], "z": zs})
        # per cycle and half-cycle waveform errors
        allm = np.ones(len(t.tab), bool)
        e, v, e_hi, e_lo = _waveform_errors(t, allm, [ev], base.K)
        cyc_nrmse = np.sqrt(e / np.where(v > 0, v, np.nan))
        errs_all.append(cyc_nrmse)
        plot["cycle_errors"].append({"t": t.tab.t_mid, "nrmse": cyc_nrmse, "hi": np.sqrt(e_hi / v), "lo": np.sqrt(e_lo / v),
                                     "start": t.tab.start, "end": t.tab.end})
        harm = _harmonic_errors(t, allm, ev, base.K)
        plot["harmonics"].append(harm)
        # only the fundamental and the 3rd harmonic are well above the noise at realistic amplitudes
        strong = {k: v for k, v in harm.items() if k in ("1", "3")}
        if strong:
            kmax = max(strong, key=lambda k: strong[k])
            if strong[kmax] > 0.05:
                located.append({"kind": "harmonic", "test": t.index, "beta": float(np.mean(t.beta)), "h": t.h,
                                "t_start": t.t_start, "t_end": t.t_end, "harmonic": int(kmax),
                                "what": f"G(j{kmax}Omega) measured from harmonic {kmax} of output/command",
                                "relative_error": harm[kmax], "all": harm})
    # time segments: runs of cycles whose waveform error stands out from the log's typical cycle
    # (only when some feature disagrees beyond the noise at all: otherwise they would flag noise)
    mismatch = any(d["kind"] == "feature" for d in located)
    if not mismatch:
        located = []
    if errs_all and mismatch:
        pooled = np.concatenate(errs_all)
        med = float(np.nanmedian(pooled))
        for t, ce in zip(tests, plot["cycle_errors"]):
            bad = ce["nrmse"] > max(1.5 * med, 0.02)
            if not bad.any():
                continue
            idx = np.flatnonzero(bad)
            runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
            for rr in runs:
                hi_err = float(np.nanmean(ce["hi"][rr]))
                lo_err = float(np.nanmean(ce["lo"][rr]))
                located.append({
                    "kind": "segment", "test": t.index, "beta": float(np.mean(t.beta)), "h": t.h,
                    "t_start": float(ce["start"][rr[0]]), "t_end": float(ce["end"][rr[-1]]),
                    "cycles": [int(x) for x in rr],
                    "nrmse": float(np.nanmean(ce["nrmse"][rr])),
                    "typical_nrmse": med,
                    "worse_half": "high (+h)" if hi_err > lo_err else "low (-h)",
                    "half_nrmse": {"high": hi_err, "low": lo_err},
                })
    located.sort(key=lambda d: -abs(d.get("z", 0.0)) if d["kind"] == "feature" else (0 if d["kind"] == "harmonic" else 1))
    return located, plot
