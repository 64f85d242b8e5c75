"""One flight log in, the loop's model out: read -> segment -> identify, with uncertainty.

:func:`analyze_flight` takes a :class:`~mrftcli.io.logtypes.FlightLog`; :func:`analyze_path` reads the
log first. Both are pure (no printing, no files written) and return an :class:`AnalysisResult`.

How the figures are obtained
----------------------------
* Every MRFT test comes from :func:`mrftcli.segment.core.segment` with its stable cycles, the measured
  frequency and amplitude per cycle and the *effective* beta (the switching level the relay actually
  achieved, measured from the output at the switch instants). Identification uses the effective
  beta with ``rate_hz=None``: at the actual switch instants the sampled, noisy relay *is* a
  continuous relay switching at that level, so no sampling correction applies.
* **Point estimate** (``parameters.*.mean``): the paper's method at its core - each test's UFM
  slice at the known Tp scaled to real units (Lemma 3, exact LPRS, the test's mean effective beta
  and mean frequency) - with two more measured constraints per test in one weighted least squares
  (*Beyond the paper*; ``constraints=()`` leaves them out):

  - **phase**: the fundamental harmonic of the output relative to that of the relay's square wave
    (``RelayCycle.phase_h1``) is arg G(j Omega) of the plant, whatever level the relay switched at;
    it puts the plant on the curve :func:`phase_tau`. It averages the output noise over whole
    cycles, where the effective beta carries the switching jitter of a noisy sampled relay: on the
    30-plant sweep its standard error in tau is 1.2-4.9 times (median 2.2) smaller than the UFM
    slice's, and the tau RMS error drops from 0.59 to 0.16 ms (docs/benchmarks/analyze.md).
  - **amplitude**: ln K_i(Td) from each test's amplitude through the UGM must agree between tests
    (the ratio (a_i/h_i)/(a_j/h_j) does not depend on K; Lemmas 2, 4).

  Weights are inverse variances from each test's per-cycle scatter plus a systematic floor
  (:func:`_constraint_weights`); the solution minimises the chi-square of all constraints
  (:func:`_consensus_objective`), K follows through the UGM. ``identification`` keeps the
  UFM-only result of :func:`mrftcli.mrft.identify.identify` (the paper's estimate) and ``constraints``
  the constraints used with their residuals at the estimate and the chi-square; a chi-square with
  p < 1e-3 raises a warning (the constraints disagree: the plant may not follow eq. (2)).
* **Uncertainty** (``std``, ``ci95_low/high``): a bootstrap over cycles. Each draw resamples the
  stable cycles of every test with replacement, recomputes each test's mean beta, frequency and
  amplitude (and phase) together (so their cycle-to-cycle correlation is kept), adds a systematic
  beta error of standard deviation ``_BETA_SYSTEMATIC`` (and phase error ``_PHASE_SYSTEMATIC``) per
  test, and re-identifies with the vectorised consensus solver (:func:`_consensus_solve`). This propagates the scatter of the
  frequencies *and* of the measured switching levels, the larger error source at small amplitudes.
  ``n_bootstrap`` draws (400), fewer for logs with many tests (draws x tests <= 4000, >= 100).
* **Per-combination spread** (``combinations``, the paper's Table III): one stable cycle from each
  test, identified with that cycle's own beta and frequency, over all combinations (a seeded random
  subset when there are more than ``max_combinations``); mean and standard deviation.

The consensus solver: each test i gives the curve tau_i(Td) (the UFM slice at the known Tp scaled
to real units, Lemma 3) and, with the constraints, its phase curve. Td minimises the weighted
scatter of all curves about their weighted mean taubar(Td) (for two UFM slices alone this is their
intersection) plus the weighted scatter of ln K_i(Td), found by a coarse scan and a golden-section
search in ln Td vectorised over draws; tau = taubar(Td).

Times: people read times relative to the log's first sample (``AnalysisResult.t0``, epoch seconds
in real logs); the JSON keeps the absolute ``t_start``/``t_end`` and adds ``t_start_rel``/``t_end_rel``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from .errors import InsufficientDataError, SegmentationError
from .mrft.identify import IdentificationResult, ParameterEstimate, TestMeasurement, identify, ufm_slice
from .io.logtypes import FlightLog
from .mrft.lprs import unit_cycle
from .mrft.model import LoopModel
from .segment.core import MrftTest, StabilityCriterion, ValidityCriterion, segment
from .validate import check_time

__all__ = ["AnalysisResult", "analyze_flight", "analyze_path", "log_start", "describe_t0", "phase_tau", "CONSTRAINTS",
           "ASSUMED_TD_RANGE"]

_TWO_PI = 2.0 * math.pi
#: Td range [s] assumed for the partial result of a single-beta log (multirotor drag time constants).
ASSUMED_TD_RANGE = (0.1, 10.0)
#: Two tests whose betas differ by less than this measure the same UFM slice.
_SAME_BETA = 0.05
#: Td * Omega above which Td is called poorly identifiable (the issue's accuracy boundary).
_TD_OMEGA_LIMIT = 5.0
#: Standard deviation [-] of the systematic error of a test's effective beta (see analyze_flight).
_BETA_SYSTEMATIC = 1e-3
#: Systematic floor [rad] of a test's fundamental-harmonic phase (harmonic truncation, cycle
#: non-periodicity; see :func:`_constraint_weights`).
_PHASE_SYSTEMATIC = 3e-4
#: Systematic floor [-] of a test's ln(amplitude) (harmonic truncation of the cycle fit ~5e-4).
_GAIN_SYSTEMATIC = 1e-3
#: The constraints beyond the UFM slices that analyze_flight can add (see :func:`analyze_flight`).
CONSTRAINTS = ("phase", "amplitude")


@dataclass(frozen=True, eq=False)
class AnalysisResult:
    """Everything ``mrft-ident analyze`` found in one log, for one loop.

    Attributes
    ----------
    path, loop : str
        The log and the loop analysed.
    Tp : float
        The known propulsion time constant [s].
    tests : tuple of MrftTest
        The tests used for identification (with their per-cycle data).
    rejected : tuple of MrftTest
        Tests found in the command but left out (too few stable cycles, or the output is not a limit
        cycle of this relay: ``MrftTest.validity``), with the reason in ``rejection_reasons`` and
        ``warnings``.
    Td, tau, K : ParameterEstimate
        Point estimate (``mean``) with bootstrap ``std`` and 95 % interval; Td, tau in seconds, K in
        output units / (command unit s^2) (K Td is the static gain from command to output rate).
    model : LoopModel
        The identified model (the point estimate).
    identification : IdentificationResult
        The point identification from :func:`mrftcli.mrft.identify.identify`.
    combinations : dict
        Per-combination estimates (paper Table III): ``n`` and ``Td``/``tau``/``K`` arrays [s].
    bootstrap : dict
        Bootstrap draws ``Td``/``tau``/``K`` (arrays).
    warnings : tuple of str
        Identifiability and data-quality warnings (times in them are seconds from ``t0``).
    flight : FlightLog
        The signals analysed (for plots; not serialised).
    t0 : float
        The log's first sample time [s] (epoch seconds in real logs): everything a person reads
        (table, plots, warnings) shows times relative to it; the JSON keeps the absolute times too.
    constraints : dict
        The extra weighted constraints of the point estimate beyond the UFM slices and their
        residuals (see :func:`analyze_flight`); empty when none were used.
    rejection_reasons : dict
        ``MrftTest.index`` of each rejected test -> why it was left out (one sentence).
    """

    path: str
    loop: str
    Tp: float
    tests: tuple[MrftTest, ...]
    rejected: tuple[MrftTest, ...]
    Td: ParameterEstimate
    tau: ParameterEstimate
    K: ParameterEstimate
    model: LoopModel
    identification: IdentificationResult
    combinations: dict
    bootstrap: dict
    warnings: tuple[str, ...]
    flight: FlightLog | None = field(default=None, repr=False)
    t0: float = 0.0
    constraints: dict = field(default_factory=dict)
    rejection_reasons: dict = field(default_factory=dict)

    def rel(self, t: float) -> float:
        """A log time [s] as seconds since the log's first sample."""
        return float(t) - self.t0

    def combination_stats(self) -> dict:
        """Mean and std over the per-combination estimates (paper Table III)."""
        out = {"n": int(self.combinations.get("n", 0))}
        for name in ("Td", "tau", "K"):
            v = np.asarray(self.combinations.get(name, []), float)
            v = v[np.isfinite(v)]
            out[name] = {"mean": float(v.mean()) if v.size else None,
                         "std": float(v.std(ddof=1)) if v.size > 1 else None,
                         "unit": "s" if name != "K" else ""}
        return out

    def _ident_tests(self, rows: list) -> list:
        # identify() saw each test's means only; give the cycle counts and standard errors behind them
        out = []
        for row, t in zip(rows, self.tests):
            row = dict(row)
            f = t.frequency_hz
            row["n_cycles"] = int(f.size)
            row["frequency_sem_hz"] = float(f.std(ddof=1) / math.sqrt(f.size)) if f.size > 1 else None
            out.append(row)
        return out

    def _with_rel(self, d: dict) -> dict:
        # absolute times stay (the keys); relative ones next to them for people and plots
        out = {}
        for k, v in d.items():
            out[k] = v
            if k in ("t_start", "t_end"):
                out[k + "_rel"] = self.rel(v)
        return out

    def to_dict(self, cycles: bool = True) -> dict:
        """The JSON object of ``mrft-ident analyze --json``.

        Keys: ``parameters`` (Td, tau, K, Tp; each ``mean``, ``std``, ``ci95_low``, ``ci95_high``,
        ``unit``), ``combinations`` (Table III mean/std), ``tests`` (per test: ``beta`` (the
        effective beta used), ``beta_nominal``, ``beta_effective``, ``h``, ``frequency_hz``,
        ``amplitude``, ``cycles``, ``t_start``, ``t_end`` (absolute log times [s]), ``t_start_rel``,
        ``t_end_rel`` (seconds since the log's first sample, ``input.t0``), ... and per-cycle data),
        ``rejected_tests``, ``model``, ``identification`` (method, per-test sensitivities, the extra
        constraints and their residuals), ``warnings``, ``input``.
        """
        params = {"Td": self.Td.to_dict(), "tau": self.tau.to_dict(), "K": self.K.to_dict(),
                  "Tp": {"mean": self.Tp, "std": 0.0, "ci95_low": self.Tp, "ci95_high": self.Tp, "unit": "s",
                         "known": True}}
        params["K"]["unit"] = "output units / (command unit s^2)"
        ident = self.identification.to_dict()
        flight = self.flight
        inp: dict = {"path": self.path, "loop": self.loop, "Tp": self.Tp, "t0": self.t0}
        if flight is not None:
            tc = flight.command.t
            inp.update(
                source=flight.source,
                command_samples=int(tc.size),
                output_samples=int(len(flight.output)),
                t_first=float(tc[0]) if tc.size else None,
                t_last=float(tc[-1]) if tc.size else None,
                beta_topic=flight.beta is not None,
                setpoint_topic=flight.setpoint is not None,
                reader_warnings=list(flight.warnings),
            )
        return {
            "parameters": params,
            "model": {"Tp": self.model.Tp, "Td": self.model.Td, "tau": self.model.tau, "K": self.model.K},
            "combinations": self.combination_stats(),
            "tests": [self._with_rel(t.to_dict(cycles=cycles)) for t in self.tests],
            "rejected_tests": [{**self._with_rel(t.to_dict(cycles=False)),
                                "reason": self.rejection_reasons.get(t.index, "")} for t in self.rejected],
            "identification": {"method": ident["method"] if not self.constraints else
                               "weighted least squares: UFM slices + " + " + ".join(self.constraints["used"][1:]),
                               "residual": ident["residual"],
                               "tests": self._ident_tests(ident["tests"]), "beta_used": "effective",
                               "rate_correction": None,
                               "constraints": self.constraints or {"used": ["ufm"]}},
            "uncertainty": {"method": "bootstrap over stable cycles",
                            "draws": int(np.isfinite(np.asarray(self.bootstrap.get("Td", []), float)).sum())},
            "warnings": list(self.warnings),
            "input": inp,
        }


# --------------------------------------------------------------------------------------------------
# vectorised consensus solver
# --------------------------------------------------------------------------------------------------


def _tau_curves(Tp: float, betas: np.ndarray, omegas: np.ndarray, Td: np.ndarray) -> np.ndarray:
    """tau_i(Td) [s] for arrays of shape (M, n) (betas, omegas) and Td of shape (M,)."""
    th, _ = unit_cycle(Tp * omegas, Td[:, None] * omegas, betas)
    return th / omegas


def phase_tau(Tp: float, omegas, phases, Td) -> np.ndarray:
    """The delay [s] that gives the plant of eq. (2) the measured phase at Omega (Beyond the paper).

    arg G(j Omega) = -pi/2 - atan(Tp Omega) - atan(Td Omega) - tau Omega, solved for tau: each test's
    fundamental harmonic (``RelayCycle.phase_h1``) puts the plant on this curve in the (Td, tau)
    plane, next to its UFM slice. Broadcasts ``omegas`` [rad/s], ``phases`` [rad] and ``Td`` [s].
    """
    omegas = np.asarray(omegas, float)
    return (-np.asarray(phases, float) - 0.5 * math.pi - np.arctan(Tp * omegas)
            - np.arctan(np.asarray(Td, float) * omegas)) / omegas


@dataclass(frozen=True)
class _Extra:
    """The weighted constraints beyond the UFM slices for M sets of n tests (arrays (M, n)).

    ``phases`` [rad] with weights ``w_phase`` [1/s^2] (zero where a test has no phase); ``ln_amp``
    = ln(a_i / h_i) with weights ``w_gain`` [-] on the UGM consensus of ln K.
    """

    phases: np.ndarray
    w_phase: np.ndarray
    ln_amp: np.ndarray
    w_gain: np.ndarray


def _consensus_objective(Tp, betas, omegas, w, x, extra: _Extra | None = None):
    """Weighted scatter of the tests' constraints at Td = exp(x); returns (J, tau, lnK).

    Without ``extra``: the UFM slices only, J = sum_i w_i (tau_i(Td) - taubar)^2. With it, every test
    adds its phase curve :func:`phase_tau` to the same weighted consensus for tau, and the UGM adds
    sum_i wk_i (ln K_i(Td) - ln Kbar)^2, ln K_i = ln(a_i Omega_i / (h_i Td a_unit(Tp Omega_i,
    Td Omega_i))) (Lemmas 2, 4; independent of beta): the amplitude ratios between tests, which do not
    depend on K, constrain Td. Weights are inverse variances, so J is a chi-square.
    """
    Td = np.exp(x)
    th, a_unit = unit_cycle(Tp * omegas, Td[:, None] * omegas, betas)
    tau = th / omegas
    if extra is None:
        tbar = np.sum(w * tau, axis=1) / np.sum(w, axis=1)
        return np.sum(w * (tau - tbar[:, None]) ** 2, axis=1), tbar, None
    tph = phase_tau(Tp, omegas, extra.phases, Td[:, None])
    wp = extra.w_phase
    tph = np.where(wp > 0, tph, 0.0)
    tbar = (np.sum(w * tau, axis=1) + np.sum(wp * tph, axis=1)) / (np.sum(w, axis=1) + np.sum(wp, axis=1))
    J = np.sum(w * (tau - tbar[:, None]) ** 2, axis=1) + np.sum(wp * (tph - tbar[:, None]) ** 2, axis=1)
    wk = extra.w_gain
    lnK = extra.ln_amp + np.log(omegas) - x[:, None] - np.log(a_unit)
    sk = np.sum(wk, axis=1)
    kbar = np.sum(wk * lnK, axis=1) / np.where(sk > 0, sk, 1.0)
    J = J + np.sum(wk * (lnK - kbar[:, None]) ** 2, axis=1)
    return J, tbar, kbar


def _consensus_solve(Tp: float, betas: np.ndarray, omegas: np.ndarray, weights: np.ndarray,
                     Td_ref: float, span: float = 10.0, iters: int = 30,
                     extra: _Extra | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised (Td, tau) for M sets of n tests (see the module docstring).

    Parameters
    ----------
    Tp : float
        Propulsion time constant [s].
    betas, omegas, weights : numpy.ndarray
        Shape (M, n): beta, frequency [rad/s] and weight of each test's UFM slice in each set.
    Td_ref : float
        Centre of the search [s]; the search covers Td_ref / span .. Td_ref * span.
    extra : _Extra, optional
        Phase and amplitude constraints (:func:`_consensus_objective`); None: the UFM slices only.

    Returns
    -------
    (Td, tau) : arrays of shape (M,) [s]; NaN where the search ended on its boundary (no
    intersection inside the range).
    """
    M = betas.shape[0]
    lo_x, hi_x = math.log(Td_ref / span), math.log(Td_ref * span)
    # coarse scan first, so that the golden section starts in the basin of the global minimum
    grid = np.linspace(lo_x, hi_x, 13)
    Jg = np.stack([_consensus_objective(Tp, betas, omegas, weights, np.full(M, g), extra)[0] for g in grid], axis=1)
    Jg = np.where(np.isfinite(Jg), Jg, np.inf)
    k = np.clip(np.argmin(Jg, axis=1), 1, grid.size - 2)
    a = grid[k - 1]
    b = grid[k + 1]
    g = (math.sqrt(5.0) - 1.0) / 2.0
    c = b - g * (b - a)
    d = a + g * (b - a)
    fc = _consensus_objective(Tp, betas, omegas, weights, c, extra)[0]
    fd = _consensus_objective(Tp, betas, omegas, weights, d, extra)[0]
    for _ in range(iters):
        left = fc < fd  # minimum in [a, d]
        b = np.where(left, d, b)
        a = np.where(left, a, c)
        new = np.where(left, b - g * (b - a), a + g * (b - a))
        fnew = _consensus_objective(Tp, betas, omegas, weights, new, extra)[0]
        d_new = np.where(left, c, new)
        fd_new = np.where(left, fc, fnew)
        c_new = np.where(left, new, d)
        fc_new = np.where(left, fnew, fd)
        c, d, fc, fd = c_new, d_new, fc_new, fd_new
    x = 0.5 * (a + b)
    _, tau, _ = _consensus_objective(Tp, betas, omegas, weights, x, extra)
    Td = np.exp(x)
    edge = (x <= lo_x + 1e-3) | (x >= hi_x - 1e-3)
    Td = np.where(edge, np.nan, Td)
    tau = np.where(edge | ~np.isfinite(tau), np.nan, tau)
    return Td, tau


def _nanmean_rows(x: np.ndarray, axis: int = 1) -> np.ndarray:
    """Mean ignoring NaN; NaN (without a warning) where a row has no finite value."""
    ok = np.isfinite(x)
    cnt = ok.sum(axis=axis)
    tot = np.where(ok, x, 0.0).sum(axis=axis)
    return np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)


def _constraint_weights(Tp: float, tests: Sequence[MrftTest], Td_ref: float, constraints: Sequence[str]) -> dict:
    """Inverse-variance weights of each test's constraints, from the measured per-cycle scatter.

    Each stable cycle c of test i is evaluated at ``Td_ref`` on its own: its UFM value
    tau_ic = theta(Tp W_c, Td W_c, beta_c) / W_c, its phase value (:func:`phase_tau` with the cycle's
    phase), and its ln K_ic from the UGM. The variance of a test's constraint is the scatter of these
    values over its n_i cycles divided by n_i (the standard error of the mean), plus a systematic
    floor: ``_BETA_SYSTEMATIC`` of beta (through d tau / d beta), ``_PHASE_SYSTEMATIC`` rad of phase
    (through 1 / Omega) and ``_GAIN_SYSTEMATIC`` of ln a. A test with fewer than two finite phases
    gets no phase constraint.

    Returns
    -------
    dict
        ``w_ufm`` [1/s^2], ``w_phase`` [1/s^2], ``w_gain`` [-] (arrays of shape (n,)) and the standard
        deviations behind them (``sigma_ufm_s``, ``sigma_phase_s``, ``sigma_ln_gain``).
    """
    n = len(tests)
    sig_u, sig_p, sig_k = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    for i, t in enumerate(tests):
        st = t.stable
        b = np.array([c.beta_effective for c in st])
        W = _TWO_PI / np.array([c.period for c in st])
        m = b.size
        th, a_unit = unit_cycle(Tp * W, Td_ref * W, b)
        tu = th / W
        Wm, bm = float(W.mean()), float(np.nanmean(b))
        db = 1e-4
        th2, _ = unit_cycle(Tp * Wm, Td_ref * Wm, np.array([bm - db, bm + db]))
        dtau_dbeta = float(th2[1] - th2[0]) / (2 * db) / Wm
        var = np.nanvar(tu, ddof=1) / m if m > 1 else 0.0
        sig_u[i] = math.sqrt(var + (dtau_dbeta * _BETA_SYSTEMATIC) ** 2)
        if "phase" in constraints:
            ph = np.array([c.phase_h1 for c in st])
            ok = np.isfinite(ph)
            if ok.sum() >= 2:
                tp_ = phase_tau(Tp, W[ok], ph[ok], Td_ref)
                sig_p[i] = math.sqrt(np.var(tp_, ddof=1) / ok.sum() + (_PHASE_SYSTEMATIC / Wm) ** 2)
        if "amplitude" in constraints:
            a = np.array([c.amplitude for c in st])
            lnk = np.log(a * W / (t.h * Td_ref * a_unit))
            var = np.var(lnk, ddof=1) / m if m > 1 else 0.0
            sig_k[i] = math.sqrt(var + _GAIN_SYSTEMATIC**2)
    inv = (lambda sg: np.where(np.isfinite(sg) & (sg > 0), 1.0 / np.where(sg > 0, sg, 1.0) ** 2, 0.0))
    return {"w_ufm": inv(sig_u), "w_phase": inv(sig_p), "w_gain": inv(sig_k),
            "sigma_ufm_s": sig_u, "sigma_phase_s": sig_p, "sigma_ln_gain": sig_k}


def _constraint_report(Tp: float, tests: Sequence[MrftTest], Td: float, tau: float, betas, omegas, phases,
                       ln_amp, cw: dict, constraints: Sequence[str]) -> dict:
    """The constraints used and their residuals at the estimate (for the JSON and the warnings)."""
    from scipy import stats

    x = np.array([math.log(Td)])
    th, a_unit = unit_cycle(Tp * omegas, Td * omegas, betas)
    tau_u = th / omegas
    tau_p = phase_tau(Tp, omegas, phases, Td)
    lnK = ln_amp + np.log(omegas) - x[0] - np.log(a_unit)
    wk = cw["w_gain"]
    kbar = float(np.sum(wk * lnK) / np.sum(wk)) if np.sum(wk) > 0 else float("nan")
    per, chi2, m = [], 0.0, 0
    for i, t in enumerate(tests):
        row = {"index": t.index, "beta": float(betas[i]), "omega_rad_s": float(omegas[i])}
        r = float(tau_u[i] - tau)
        row["ufm"] = {"tau_s": float(tau_u[i]), "sigma_s": float(cw["sigma_ufm_s"][i]), "residual_s": r,
                      "normalised": r / float(cw["sigma_ufm_s"][i])}
        chi2 += (r / cw["sigma_ufm_s"][i]) ** 2
        m += 1
        if cw["w_phase"][i] > 0:
            r = float(tau_p[i] - tau)
            row["phase"] = {"phase_rad": float(phases[i]), "tau_s": float(tau_p[i]),
                            "sigma_s": float(cw["sigma_phase_s"][i]), "residual_s": r,
                            "residual_rad": float(-r * omegas[i]), "normalised": r / float(cw["sigma_phase_s"][i])}
            chi2 += (r / cw["sigma_phase_s"][i]) ** 2
            m += 1
        if wk[i] > 0:
            r = float(lnK[i] - kbar)
            row["amplitude"] = {"ln_K": float(lnK[i]), "sigma": float(cw["sigma_ln_gain"][i]), "residual": r,
                                "normalised": r / float(cw["sigma_ln_gain"][i])}
            chi2 += (r / cw["sigma_ln_gain"][i]) ** 2
            m += 1
        per.append(row)
    n_par = 2 + (1 if np.sum(wk) > 0 else 0)  # Td, tau (and K through ln Kbar)
    dof = m - n_par
    used = ["ufm"] + [c for c, key in (("phase", "w_phase"), ("amplitude", "w_gain")) if np.any(cw[key] > 0)]
    return {"used": used, "requested": list(constraints), "tests": per, "chi2": float(chi2), "dof": int(dof),
            "p_value": float(stats.chi2.sf(chi2, dof)) if dof > 0 else None}


def _gain(Tp: float, Td: np.ndarray, omegas: np.ndarray, amps: np.ndarray, hs: np.ndarray) -> np.ndarray:
    """K from the UGM (Lemmas 2, 4): a = h K Td a_unit(Tp w, Td w) / w, averaged over the tests."""
    _, a_unit = unit_cycle(Tp * omegas, Td[:, None] * omegas, np.zeros_like(omegas))
    return np.mean(amps * omegas / (hs * Td[:, None] * a_unit), axis=1)


def _estimate(point: float, draws: np.ndarray, centre: float, unit: str) -> ParameterEstimate:
    """Point estimate with bootstrap std and a 95 % interval (percentiles shifted to the point)."""
    v = np.asarray(draws, float)
    v = v[np.isfinite(v)]
    if v.size < 10 or not np.isfinite(centre):
        return ParameterEstimate(float(point), float("nan"), float("nan"), float("nan"), unit)
    lo, hi = np.percentile(v, [2.5, 97.5])
    shift = point - centre
    return ParameterEstimate(float(point), float(v.std(ddof=1)), float(lo + shift), float(hi + shift), unit)


# --------------------------------------------------------------------------------------------------
# analysis
# --------------------------------------------------------------------------------------------------


def _group_betas(tests: Sequence[MrftTest]) -> list[list[int]]:
    """Indices of tests grouped by beta (nominal when logged, else effective)."""
    groups: list[list[int]] = []
    keys: list[float] = []
    for i, t in enumerate(tests):
        key = t.beta_nominal if t.beta_nominal is not None else t.beta_effective
        for g, k in zip(groups, keys):
            if abs(k - key) < _SAME_BETA:
                g.append(i)
                break
        else:
            groups.append([i])
            keys.append(key)
    return groups


def log_start(flight: FlightLog) -> float:
    """The log's first sample time [s]: the earliest timestamp of any series of the flight.

    Real logs carry epoch timestamps (1.7e9 s); people read times relative to this.
    """
    firsts = []
    for s in (flight.command, flight.output, flight.beta, flight.setpoint, flight.battery_voltage):
        if s is not None and len(s):
            idx = s.t
            idx = idx[np.isfinite(idx)]
            if idx.size:
                firsts.append(float(idx.min()))
    return min(firsts) if firsts else 0.0


def describe_t0(t0: float) -> str:
    """The log start for people: a UTC date when it looks like an epoch time, else seconds."""
    if 1e9 <= t0 <= 4e9:  # 2001 .. 2096: an epoch timestamp
        from datetime import datetime, timezone

        return datetime.fromtimestamp(t0, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC"
    return f"{t0:.3f} s"


def _span(t: MrftTest, t0: float) -> str:
    """A test's time span for people: seconds from the log start."""
    return f"{t.t_start - t0:.1f}-{t.t_end - t0:.1f} s"


def _describe(tests: Sequence[MrftTest], t0: float = 0.0) -> str:
    parts = []
    for t in tests:
        b = f"beta {t.beta_nominal:g}" if t.beta_nominal is not None else f"beta~{t.beta_effective:.2f}"
        parts.append(f"{b} at {_span(t, t0)} ({t.n_stable} stable of {len(t.cycles)} cycles)")
    return "; ".join(parts)


def _screen_tests(found: Sequence[MrftTest], min_stable_cycles: int) -> dict:
    """Which tests cannot be used, and why: {MrftTest.index: reason}.

    In order: an output with no oscillation at the relay frequency (SNR or variance share of
    ``MrftTest.validity``, robust even on start-up cycles); too few stable cycles; any other failed
    validity criterion (phase, beta); then the loop-gain sign, which must be the same in every test
    of one log (one plant, one sign): the tests of the minority sign are rejected, and all of them
    when the signs split evenly (nothing tells which is right).
    """
    reasons: dict = {}
    for t in found:
        v = t.validity
        if v is not None and not v.follows_relay:
            reasons[t.index] = "the output does not follow this relay: " + "; ".join(v.reasons)
        elif t.n_stable < min_stable_cycles or not np.isfinite(t.beta_effective):
            reasons[t.index] = f"{t.n_stable} stable cycles (need {min_stable_cycles})"
        elif v is not None and not v.ok:
            reasons[t.index] = "not an MRFT limit cycle of this output: " + "; ".join(v.reasons)
    kept = [t for t in found if t.index not in reasons]
    signs = np.array([t.loop_sign for t in kept])
    if signs.size and np.unique(signs).size > 1:
        n_pos, n_neg = int((signs > 0).sum()), int((signs < 0).sum())
        keep = 1 if n_pos > n_neg else -1 if n_neg > n_pos else 0
        for t in kept:
            if t.loop_sign != keep:
                reasons[t.index] = (
                    f"the loop gain is {'positive' if t.loop_sign > 0 else 'negative'} here but "
                    f"{'negative' if t.loop_sign > 0 else 'positive'} in {n_neg if t.loop_sign > 0 else n_pos} "
                    "other test(s) of the log: one plant has one sign, so the output is not the relayed signal "
                    "in all of them")
    return reasons


def _topic(flight: FlightLog, key: str, default: str) -> str:
    src = flight.source.get(key) if isinstance(flight.source, dict) else None
    return str(src).split(":")[0] if src else default


def _amp_text(x: float, loop: str) -> str:
    """An output amplitude for people: mm for altitude [m], mrad for the attitude loops [rad]."""
    if not np.isfinite(x):
        return "-"
    return f"{x * 1e3:.2g} {'mm' if loop == 'altitude' else 'mrad'}"


def _no_usable_message(flight: FlightLog, found: Sequence[MrftTest], reasons: dict, min_stable_cycles: int,
                       t0: float) -> str:
    """The one-line SegmentationError when no test survives :func:`_screen_tests`."""
    n = len(found)
    cmd = _topic(flight, "command", "the command")
    out = f"{_topic(flight, 'output', 'the output')} {flight.loop}"
    head = f"{flight.path}: {n} relay test(s) found on {cmd}, but "
    lost = [t for t in found if t.validity is not None and not t.validity.follows_relay]
    if lost and len(lost) * 2 >= n:
        v = [t.validity for t in lost]
        amp = float(np.nanmedian([x.amplitude for x in v]))
        snr = float(np.nanmedian([x.snr for x in v]))
        frac = float(np.nanmedian([x.h1_fraction for x in v]))
        return (head + f"{out} does not follow them (output amplitude {_amp_text(amp, flight.loop)}, "
                f"{snr:.2g}x the noise at the relay frequency; fraction of variance at the relay frequency "
                f"{frac:.2f}): is --loop/--output-topic right?")
    bad = [t for t in found if t.validity is not None and not t.validity.ok and t.index in reasons
           and "stable cycles" not in reasons[t.index]]
    if bad:
        why = "; ".join(f"test at {_span(t, t0)}: {reasons[t.index]}" for t in bad)
        return (head + f"{out} is not a limit cycle of them ({why}): is --loop/--output-topic/--command-topic "
                "right?")
    signs = [t for t in found if "loop gain" in reasons.get(t.index, "")]
    if signs:
        return (head + f"the loop gain of {out} has opposite signs in them "
                f"({', '.join(f'{_span(t, t0)}: {t.loop_sign:+d}' for t in found)}): the output is not the "
                "signal the relay controls in all of them; is --output-topic right?")
    return (f"{flight.path}: found {n} relay test(s) but none with {min_stable_cycles} or more stable "
            f"cycles ({_describe(found, t0)}; times from the log start); record longer tests or check for "
            "noise/dropouts")


def _partial_single_beta(Tp: float, tests: Sequence[MrftTest], t0: float = 0.0) -> dict:
    """What one beta can say: tau(Td) over the assumed Td range, per test."""
    Td = np.geomspace(ASSUMED_TD_RANGE[0], ASSUMED_TD_RANGE[1], 9)
    rows = []
    for t in tests:
        d = t.to_dict(cycles=False)
        d.update(t_start_rel=t.t_start - t0, t_end_rel=t.t_end - t0)
        rows.append(d)
    out = {"assumed_Td_range_s": list(ASSUMED_TD_RANGE), "t0": t0, "tests": rows, "tau_for_assumed_Td": []}
    for t in tests:
        try:
            tau = ufm_slice(Tp, t.beta, t.frequency_hz_mean, Td)
        except Exception:  # noqa: BLE001 - a partial result is best effort; never invent a number
            tau = np.full(Td.size, np.nan)
        fin = tau[np.isfinite(tau)]
        out["tau_for_assumed_Td"].append({
            "beta": t.beta, "frequency_hz": t.frequency_hz_mean, "Td_s": Td.tolist(),
            "tau_s": [float(x) if np.isfinite(x) else None for x in tau],
            "tau_range_s": [float(fin.min()), float(fin.max())] if fin.size else None,
        })
    return out


def analyze_flight(
    flight: FlightLog,
    Tp: float,
    *,
    min_stable_cycles: int = 3,
    criterion: StabilityCriterion | None = None,
    n_bootstrap: int = 400,
    max_combinations: int = 400,
    seed: int = 0,
    constraints: Sequence[str] = CONSTRAINTS,
    validity: ValidityCriterion | None = None,
) -> AnalysisResult:
    """Segment the MRFT tests of a flight and identify Td, tau and K (see the module docstring).

    Parameters
    ----------
    flight : FlightLog
        Command and output (and optional beta/setpoint) of one loop.
    Tp : float
        Known propulsion time constant [s] (bench test).
    min_stable_cycles : int
        Fewest stable cycles for a test to be used.
    criterion : StabilityCriterion, optional
        Stable-limit-cycle criterion for the segmenter.
    n_bootstrap : int
        Bootstrap draws for the uncertainty.
    max_combinations : int
        Cap on the per-combination identifications (a seeded random subset above it).
    seed : int
        Seed of the bootstrap and of the combination subset.
    constraints : sequence of {"phase", "amplitude"}
        Weighted constraints added to the UFM slices for the point estimate and the bootstrap
        (Beyond the paper, see the module docstring); ``()`` gives the paper's method alone.
    validity : ValidityCriterion, optional
        Thresholds of the limit-cycle validity check (:func:`mrftcli.segment.core.check_limit_cycle`):
        a test whose output does not follow its relay as an MRFT limit cycle is rejected, and so are
        the tests whose loop-gain sign disagrees with the others' (:func:`_screen_tests`).

    Returns
    -------
    AnalysisResult

    Raises
    ------
    SegmentationError
        No relay test in the log, or no test with ``min_stable_cycles`` stable cycles whose output
        is a limit cycle of its relay (the message says what was found and why it is not usable).
    InsufficientDataError
        Usable tests at a single beta only (``.partial`` gives tau over an assumed Td range).
    IdentificationError
        The measured cycles admit no plant of eq. (2) with this Tp.
    """
    Tp = check_time("Tp", Tp)
    constraints = tuple(constraints)
    bad = [c for c in constraints if c not in CONSTRAINTS]
    if bad:
        from .errors import InputError

        raise InputError(f"unknown constraint(s) {bad}; choose from {list(CONSTRAINTS)}")
    crit = criterion or StabilityCriterion()
    found = segment(flight, criterion=crit, validity=validity or ValidityCriterion())
    t0 = log_start(flight)
    reasons = _screen_tests(found, min_stable_cycles)
    usable = [t for t in found if t.index not in reasons]
    rejected = [t for t in found if t.index in reasons]
    warnings: list[str] = []
    for t in rejected:
        warnings.append(f"test at {_span(t, t0)} left out: {reasons[t.index]}")
    if not usable:
        err = SegmentationError(_no_usable_message(flight, found, reasons, min_stable_cycles, t0))
        # for ``--json``: what was found and why each test was rejected (read by commands/analyze.py)
        err.rejected_tests = [{**t.to_dict(cycles=False), "t_start_rel": t.t_start - t0, "t_end_rel": t.t_end - t0,
                               "reason": reasons[t.index]} for t in found]
        raise err
    groups = _group_betas(usable)
    if len(groups) < 2:
        raise InsufficientDataError(
            f"{flight.path}: only one beta was tested ({_describe(usable, t0)}; times from the log start); "
            f"Td and tau need two tests with "
            f"different betas (e.g. -0.4 and -0.7). Partial result: tau for an assumed Td range "
            f"{ASSUMED_TD_RANGE[0]:g}-{ASSUMED_TD_RANGE[1]:g} s"
            + (f" ({len(rejected)} other test(s) rejected: {'; '.join(reasons[t.index] for t in rejected)})"
               if rejected else ""),
            partial={**_partial_single_beta(Tp, usable, t0),
                     "rejected_tests": [{**t.to_dict(cycles=False), "t_start_rel": t.t_start - t0,
                                         "t_end_rel": t.t_end - t0, "reason": reasons[t.index]}
                                        for t in rejected]},
        )
    for t in usable:
        warnings.extend(f"test at {t.t_start - t0:.1f} s: {n}" for n in t.notes)
        if t.beta_nominal is not None and abs(t.beta_effective - t.beta_nominal) > 0.02:
            warnings.append(
                f"test at {t.t_start - t0:.1f} s: the relay switched at beta {t.beta_effective:.3f}, not the nominal "
                f"{t.beta_nominal:g} (sampling and noise); identified with the effective value"
            )
    warnings.extend(flight.warnings)

    # ---- point estimate through the identification core ---------------------------------------
    meas = [TestMeasurement(beta=t.beta_effective, frequency_hz=t.frequency_hz_mean, amplitude=t.amplitude_mean,
                            h=t.h) for t in usable]
    ident = identify(meas, Tp, rate_hz=None)
    warnings.extend(ident.warnings)
    model = ident.model
    Td_hat, tau_hat = model.Td, model.tau
    K_hat = ident.K.mean if ident.K is not None else float("nan")

    # ---- bootstrap over cycles ----------------------------------------------------------------
    rng = np.random.default_rng(seed)
    n = len(usable)
    per_b = [np.array([c.beta_effective for c in t.stable]) for t in usable]
    per_P = [t.period for t in usable]
    per_a = [t.amplitude for t in usable]
    per_ph = [np.array([c.phase_h1 for c in t.stable]) for t in usable]
    hs = np.array([t.h for t in usable])
    ncyc = np.array([t.n_stable for t in usable], float)
    # Many tests: fewer draws keep the cost (draws x tests) bounded; a few hundred draws suffice
    # for a std and percentile interval.
    B = int(min(n_bootstrap, max(100, 4000 // n)))
    bb = np.empty((B + 1, n))
    ww = np.empty((B + 1, n))
    aa = np.empty((B + 1, n))
    pp = np.empty((B + 1, n))
    for i in range(n):
        m = per_P[i].size
        idx = rng.integers(0, m, size=(B, m))
        idx = np.vstack([np.arange(m)[None, :], idx])  # row 0: the data themselves (the centre)
        bb[:, i] = per_b[i][idx].mean(axis=1)
        ww[:, i] = _TWO_PI / per_P[i][idx].mean(axis=1)
        aa[:, i] = per_a[i][idx].mean(axis=1)
        pp[:, i] = _nanmean_rows(per_ph[i][idx])
    # Systematic floor of the effective-beta measurement (harmonic truncation of the cycle model,
    # cycle-to-cycle non-periodicity of a noisy sampled relay): up to ~5e-4 on noise-free
    # simulations, taken as a 1e-3 standard deviation per test so the interval does not rest on
    # the random scatter alone (it matters when Td * Omega is large and the slices nearly parallel).
    bb[1:] += _BETA_SYSTEMATIC * rng.standard_normal((B, n))
    extra = None
    constraint_info: dict = {}
    if constraints:
        # Beyond the paper: the phase of each test's fundamental and the amplitude ratios join the
        # UFM slices in one weighted least squares, with inverse-variance weights from the measured
        # per-cycle scatter (the paper's weights: the cycle counts).
        cw = _constraint_weights(Tp, usable, Td_hat, constraints)
        pp[1:] += _PHASE_SYSTEMATIC * rng.standard_normal((B, n))
        weights = np.broadcast_to(cw["w_ufm"], bb.shape)
        wp = np.where(np.isfinite(pp), cw["w_phase"][None, :], 0.0)
        extra = _Extra(phases=np.nan_to_num(pp), w_phase=wp, ln_amp=np.log(aa / hs[None, :]),
                       w_gain=np.broadcast_to(cw["w_gain"], aa.shape))
    else:
        weights = np.broadcast_to(ncyc, bb.shape)
    Td_d, tau_d = _consensus_solve(Tp, bb, ww, weights, Td_hat, extra=extra)
    K_d = np.full(B + 1, np.nan)
    ok = np.isfinite(Td_d)
    if ok.any():
        K_d[ok] = _gain(Tp, Td_d[ok], ww[ok], aa[ok], np.broadcast_to(hs, aa[ok].shape))
    if constraints and np.isfinite(Td_d[0]):
        # the weighted estimate on the data themselves (bootstrap row 0) is the point estimate; the
        # paper's UFM-only estimate stays in ``identification`` for comparison
        Td_hat, tau_hat, K_hat = float(Td_d[0]), float(tau_d[0]), float(K_d[0])
        model = LoopModel(Tp, Td_hat, max(tau_hat, 0.0), K_hat if np.isfinite(K_hat) else model.K)
        constraint_info = _constraint_report(Tp, usable, Td_hat, tau_hat, bb[0], ww[0], pp[0],
                                             np.log(aa[0] / hs), cw, constraints)
        constraint_info["paper_estimate"] = {"Td": ident.model.Td, "tau": ident.model.tau,
                                             "K": ident.K.mean if ident.K is not None else None,
                                             "method": "UFM slices only (identify)"}
        pv = constraint_info["p_value"]
        if pv is not None and pv < 1e-3:
            warnings.append(
                f"the tests' constraints disagree (chi2 {constraint_info['chi2']:.1f} for {constraint_info['dof']} "
                f"degrees of freedom): the plant may not follow eq. (2); the UFM-only estimate is Td "
                f"{ident.model.Td:.4g} s, tau {ident.model.tau * 1e3:.4g} ms (try --diagnose)")
    elif constraints:
        warnings.append("the weighted estimate found no minimum in the search range; the UFM-only estimate is used")
    Td_est = _estimate(Td_hat, Td_d[1:], Td_d[0], "s")
    tau_est = _estimate(tau_hat, tau_d[1:], tau_d[0], "s")
    K_est = _estimate(K_hat, K_d[1:], K_d[0], "")
    n_fail = int((~np.isfinite(Td_d[1:])).sum())
    if n_fail > 0.05 * B:
        warnings.append(f"{n_fail} of {B} bootstrap draws found no intersection of the UFM slices within "
                        f"{Td_hat / 10:.3g}-{Td_hat * 10:.3g} s: Td is poorly determined")

    # ---- per-combination identification (paper Table III) -------------------------------------
    sizes = [p.size for p in per_P]
    total = int(np.prod(sizes, dtype=float)) if np.prod(sizes, dtype=float) < 1e9 else int(1e9)
    max_combinations = int(min(max_combinations, max(50, 4000 // n)))
    if total <= max_combinations:
        grids = np.meshgrid(*[np.arange(s) for s in sizes], indexing="ij")
        combo = np.stack([g.ravel() for g in grids], axis=1)
    else:
        combo = np.stack([rng.integers(0, s, size=max_combinations) for s in sizes], axis=1)
    cb = np.stack([per_b[i][combo[:, i]] for i in range(n)], axis=1)
    cw = np.stack([_TWO_PI / per_P[i][combo[:, i]] for i in range(n)], axis=1)
    ca = np.stack([per_a[i][combo[:, i]] for i in range(n)], axis=1)
    cTd, ctau = _consensus_solve(Tp, cb, cw, np.ones_like(cb), Td_hat)
    cK = np.full(cTd.size, np.nan)
    okc = np.isfinite(cTd)
    if okc.any():
        cK[okc] = _gain(Tp, cTd[okc], cw[okc], ca[okc], np.broadcast_to(hs, ca[okc].shape))
    combinations = {"n": int(cTd.size), "Td": cTd, "tau": ctau, "K": cK, "index": combo}

    # ---- identifiability ----------------------------------------------------------------------
    td_omega = max(Td_hat * _TWO_PI * t.frequency_hz_mean for t in usable)
    if td_omega > _TD_OMEGA_LIMIT:
        warnings.append(
            f"Td*Omega = {td_omega:.1f} > {_TD_OMEGA_LIMIT:g}: the frequencies depend weakly on Td, so Td is known "
            f"only to its interval ({Td_est.ci95_low:.3g}-{Td_est.ci95_high:.3g} s); tau and K are not affected as much"
        )
    warnings = list(dict.fromkeys(warnings))  # unique, in order
    return AnalysisResult(
        path=str(flight.path), loop=flight.loop, Tp=Tp, tests=tuple(usable), rejected=tuple(rejected),
        Td=Td_est, tau=tau_est, K=K_est, model=model, identification=ident, combinations=combinations,
        bootstrap={"Td": Td_d[1:], "tau": tau_d[1:], "K": K_d[1:]}, warnings=tuple(warnings), flight=flight,
        t0=t0, constraints=constraint_info, rejection_reasons={t.index: reasons[t.index] for t in rejected},
    )


def analyze_path(
    path: str | Path,
    Tp: float,
    loop: str = "altitude",
    *,
    command_topic: str | None = None,
    output_topic: str | None = None,
    beta_topic: str | None = None,
    setpoint_topic: str | None = None,
    battery_topic: str | None = None,
    output_scale: float | None = 1.0,
    fmt: str | None = None,
    **kwargs,
) -> AnalysisResult:
    """Read one log with :func:`mrftcli.io.read_flight` and run :func:`analyze_flight`.

    Parameters
    ----------
    path : str or Path
        The flight log (any supported format).
    Tp : float
        Known propulsion time constant [s].
    loop : {"altitude", "roll", "pitch"}
        The loop to analyse.
    command_topic, output_topic, beta_topic, setpoint_topic, battery_topic : str, optional
        ``TOPIC[:FIELD]`` overrides of the reference layout.
    output_scale : float
        Factor applied to the output and setpoint (e.g. -1 for NED z).
    fmt : str, optional
        Log format (detected when omitted).
    **kwargs
        Passed to :func:`analyze_flight` (``min_stable_cycles``, ``n_bootstrap``, ...).

    Returns
    -------
    AnalysisResult
    """
    from .io import read_flight

    flight = read_flight(path, loop=loop, command_topic=command_topic, output_topic=output_topic,
                         beta_topic=beta_topic, setpoint_topic=setpoint_topic, battery_topic=battery_topic,
                         output_scale=1.0 if output_scale is None else output_scale, fmt=fmt)
    return analyze_flight(flight, Tp, **kwargs)
