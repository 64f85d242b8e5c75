"""The consensus of a log's MRFT tests: weighted constraints, a vectorised solver and the bootstrap.

:func:`mrftcli.mrft.identify.identify` finds (Td, tau) from the tests' mean frequencies (the paper's
method). With the per-cycle data of a real log this module adds, *Beyond the paper*:

* **Constraints** beyond the UFM slices, in one weighted least squares (``CONSTRAINTS``):

  - **phase**: the fundamental harmonic of the output relative to that of the relay's square wave
    is arg G(j Omega) of the plant, whatever level the relay switched at; it puts the plant on the
    curve :func:`phase_tau` in the (Td, tau) plane, next to its UFM slice.
  - **amplitude**: ln K_i(Td) from each test's amplitude through the UGM must agree between tests
    (the ratio (a_i/h_i)/(a_j/h_j) does not depend on K; Lemmas 2, 4).

  Weights are inverse variances from each test's per-cycle scatter plus a systematic floor
  (:func:`constraint_weights`), so the objective (:func:`consensus_objective`) is a chi-square;
  :func:`constraint_report` gives the residuals at the estimate and the p-value.
* **The solver** (:func:`consensus_solve`): each test i gives the curve tau_i(Td) (its UFM slice at
  the known Tp scaled to real units, Lemma 3) and, with the constraints, its phase curve. Td
  minimises the weighted scatter of all curves about their weighted mean taubar(Td) (for two UFM
  slices alone this is their intersection) plus the weighted scatter of ln K_i(Td); a coarse scan and
  a golden-section search in ln Td, vectorised over M sets of tests; tau = taubar(Td).
* **Uncertainty** (:func:`bootstrap`): each draw resamples the stable cycles of every test with
  replacement, recomputes each test's mean beta, frequency, amplitude and phase together (their
  cycle-to-cycle correlation is kept), adds a systematic beta error (``BETA_SYSTEMATIC``) and phase
  error (``PHASE_SYSTEMATIC``) per test and solves all draws at once.
* **Per-combination spread** (:func:`combinations`, the paper's Table III): one stable cycle from each
  test, identified with that cycle's own beta and frequency.

Units: Tp, Td, tau in seconds, omega in rad/s, phases in rad. Arrays of shape (M, n) hold M sets of
n tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .identify import ParameterEstimate
from .lprs import unit_cycle

__all__ = [
    "upper_bound_open",
    "UnboundedTd",
    "unbounded_td",
    "SAME_BETA",
    "CONSTRAINTS",
    "BETA_SYSTEMATIC",
    "PHASE_SYSTEMATIC",
    "GAIN_SYSTEMATIC",
    "StableCycles",
    "ExtraConstraints",
    "Bootstrap",
    "phase_tau",
    "consensus_objective",
    "consensus_solve",
    "constraint_weights",
    "constraint_report",
    "ugm_gain",
    "bootstrap",
    "bootstrap_estimate",
    "combinations",
]

_TWO_PI = 2.0 * math.pi
#: The constraints beyond the UFM slices that the consensus can add.
CONSTRAINTS = ("phase", "amplitude")
#: Standard deviation [-] of the systematic error of a test's effective beta: harmonic truncation of
#: the cycle model and cycle-to-cycle non-periodicity of a noisy sampled relay give up to ~5e-4 on
#: noise-free simulations; 1e-3 keeps the interval from resting on the random scatter alone (it
#: matters when Td * Omega is large and the slices nearly parallel).
BETA_SYSTEMATIC = 1e-3
#: Systematic floor [rad] of a test's fundamental-harmonic phase (harmonic truncation, cycle
#: non-periodicity; see :func:`constraint_weights`).
PHASE_SYSTEMATIC = 3e-4
#: Systematic floor [-] of a test's ln(amplitude) (harmonic truncation of the cycle fit ~5e-4).
GAIN_SYSTEMATIC = 1e-3
#: Two tests whose betas differ by less than this measure the same UFM slice.
SAME_BETA = 0.05


@dataclass(frozen=True, eq=False)
class StableCycles:
    """The stable cycles of one MRFT test as arrays (one entry per cycle), what the consensus reads.

    Attributes
    ----------
    beta : ndarray
        Effective beta of each cycle [-] (the level the relay actually switched at).
    period : ndarray
        Period of each cycle [s].
    amplitude : ndarray
        Output amplitude of each cycle [output units].
    phase : ndarray
        Phase of the output's fundamental relative to the relay's [rad]; NaN where unknown.
    h : float
        Relay height [command units].
    index : int
        The test's position in the log (for the report).
    """

    beta: np.ndarray
    period: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray
    h: float
    index: int = 0


@dataclass(frozen=True)
class ExtraConstraints:
    """The weighted constraints beyond the UFM slices for M sets of n tests (arrays (M, n)).

    ``phases`` [rad] with weights ``w_phase`` [1/s^2] (zero where a test has no phase); ``ln_amp``
    = ln(a_i / h_i) with weights ``w_gain`` [-] on the UGM consensus of ln K.
    """

    phases: np.ndarray
    w_phase: np.ndarray
    ln_amp: np.ndarray
    w_gain: np.ndarray

    @classmethod
    def of(cls, phases: np.ndarray, ln_amp: np.ndarray, cw: dict[str, np.ndarray]) -> ExtraConstraints:
        """The constraints of test means (``phases`` [rad], NaN where unknown, and ``ln_amp``: (M, n)) with
        the weights ``cw`` of :func:`constraint_weights`."""
        return cls(np.nan_to_num(phases), np.where(np.isfinite(phases), np.asarray(cw["w_phase"], float)[None, :], 0.0),
                   ln_amp, np.broadcast_to(np.asarray(cw["w_gain"], float), ln_amp.shape))


@dataclass(frozen=True, eq=False)
class Bootstrap:
    """Outcome of :func:`bootstrap`: row 0 is the data themselves, rows 1.. the draws.

    Attributes
    ----------
    Td, tau : ndarray, shape (B + 1,)
        Consensus estimates [s]; NaN where the search found no minimum inside its range.
    K : ndarray, shape (B + 1,)
        Gain through the UGM (:func:`ugm_gain`).
    betas, omegas, phases, ln_amp : ndarray, shape (B + 1, n)
        Each draw's test means: beta [-], Omega [rad/s], phase [rad] (NaN where unknown) and
        ln(a / h).
    weights : dict or None
        :func:`constraint_weights` at the reference Td (None without constraints).
    """

    Td: np.ndarray
    tau: np.ndarray
    K: np.ndarray
    betas: np.ndarray
    omegas: np.ndarray
    phases: np.ndarray
    ln_amp: np.ndarray
    weights: dict[str, np.ndarray] | None


def phase_tau(Tp: float, omegas: np.ndarray | float, phases: np.ndarray | float,
              Td: np.ndarray | float) -> np.ndarray:
    """The delay [s] that gives the plant of eq. (2) the measured phase at Omega (Beyond the paper).

    arg G(j Omega) = -pi/2 - atan(Tp Omega) - atan(Td Omega) - tau Omega, solved for tau: each test's
    fundamental harmonic (``RelayCycle.phase_h1``) puts the plant on this curve in the (Td, tau)
    plane, next to its UFM slice. Broadcasts ``omegas`` [rad/s], ``phases`` [rad] and ``Td`` [s].

    Examples
    --------
    The phase of the paper's example plant at 4 rad/s gives back its delay:

    >>> from mrftcli.mrft.model import LoopModel
    >>> G = LoopModel(0.1, 0.7042, 0.06)
    >>> phase = -math.pi / 2 - math.atan(0.1 * 4) - math.atan(0.7042 * 4) - 0.06 * 4
    >>> round(float(phase_tau(0.1, 4.0, phase, 0.7042)), 12)
    0.06
    """
    omegas = np.asarray(omegas, float)
    tau: np.ndarray = (-np.asarray(phases, float) - 0.5 * math.pi - np.arctan(Tp * omegas)
                       - np.arctan(np.asarray(Td, float) * omegas)) / omegas
    return tau


def consensus_objective(Tp: float, betas: np.ndarray, omegas: np.ndarray, w: np.ndarray, x: np.ndarray,
                        extra: ExtraConstraints | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Weighted scatter of the tests' constraints at Td = exp(x); returns (J, tau, lnK).

    Without ``extra``: the UFM slices only, J = sum_i w_i (tau_i(Td) - taubar)^2. With it, every test
    adds its phase curve :func:`phase_tau` to the same weighted consensus for tau, and the UGM adds
    sum_i wk_i (ln K_i(Td) - ln Kbar)^2, ln K_i = ln(a_i Omega_i / (h_i Td a_unit(Tp Omega_i,
    Td Omega_i))) (Lemmas 2, 4; independent of beta): the amplitude ratios between tests, which do not
    depend on K, constrain Td. Weights are inverse variances, so J is a chi-square.

    Parameters
    ----------
    Tp : float
        Propulsion time constant [s].
    betas, omegas, w : ndarray, shape (M, n)
        Beta, frequency [rad/s] and UFM weight [1/s^2] of each test in each set.
    x : ndarray, shape (M,)
        ln Td [ln s].
    extra : ExtraConstraints, optional
        The phase and amplitude constraints.
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


def consensus_solve(Tp: float, betas: np.ndarray, omegas: np.ndarray, weights: np.ndarray,
                    Td_ref: float, span: float = 10.0, iters: int = 30,
                    extra: ExtraConstraints | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised (Td, tau) for M sets of n tests (see the module docstring).

    Parameters
    ----------
    Tp : float
        Propulsion time constant [s].
    betas, omegas, weights : numpy.ndarray
        Shape (M, n): beta, frequency [rad/s] and weight of each test's UFM slice in each set.
    Td_ref : float
        Centre of the search [s]; the search covers Td_ref / span .. Td_ref * span.
    span : float
        Ratio of the search range's ends to ``Td_ref``.
    iters : int
        Golden-section iterations after the coarse scan.
    extra : ExtraConstraints, optional
        Phase and amplitude constraints (:func:`consensus_objective`); None: the UFM slices only.

    Returns
    -------
    (Td, tau) : arrays of shape (M,) [s]; NaN where the search ended on its boundary (no
    intersection inside the range).

    Examples
    --------
    Two tests of the paper's example (exact frequencies 0.70564 and 1.01884 Hz at beta -0.4 and
    -0.7, Tp = 0.1 s) intersect at its Td and tau:

    >>> w = 2 * np.pi * np.array([[0.705643, 1.018843]])
    >>> Td, tau = consensus_solve(0.1, np.array([[-0.4, -0.7]]), w, np.ones((1, 2)), 0.5)
    >>> round(float(Td[0]), 3), round(float(tau[0]), 4)
    (0.704, 0.06)
    """
    M = betas.shape[0]
    lo_x, hi_x = math.log(Td_ref / span), math.log(Td_ref * span)
    # coarse scan first, so that the golden section starts in the basin of the global minimum
    grid = np.linspace(lo_x, hi_x, 13)
    Jg = np.stack([consensus_objective(Tp, betas, omegas, weights, np.full(M, g), extra)[0] for g in grid], axis=1)
    Jg = np.where(np.isfinite(Jg), Jg, np.inf)
    k = np.clip(np.argmin(Jg, axis=1), 1, grid.size - 2)
    a = grid[k - 1]
    b = grid[k + 1]
    g = (math.sqrt(5.0) - 1.0) / 2.0
    c = b - g * (b - a)
    d = a + g * (b - a)
    fc = consensus_objective(Tp, betas, omegas, weights, c, extra)[0]
    fd = consensus_objective(Tp, betas, omegas, weights, d, extra)[0]
    for _ in range(iters):
        left = fc < fd  # minimum in [a, d]
        b = np.where(left, d, b)
        a = np.where(left, a, c)
        new = np.where(left, b - g * (b - a), a + g * (b - a))
        fnew = consensus_objective(Tp, betas, omegas, weights, new, extra)[0]
        d_new = np.where(left, c, new)
        fd_new = np.where(left, fc, fnew)
        c_new = np.where(left, new, d)
        fc_new = np.where(left, fnew, fd)
        c, d, fc, fd = c_new, d_new, fc_new, fd_new
    x = 0.5 * (a + b)
    _, tau, _ = consensus_objective(Tp, betas, omegas, weights, x, extra)
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


def constraint_weights(Tp: float, tests: Sequence[StableCycles], Td_ref: float,
                       constraints: Sequence[str]) -> dict[str, np.ndarray]:
    """Inverse-variance weights of each test's constraints, from the measured per-cycle scatter.

    Each stable cycle c of test i is evaluated at ``Td_ref`` on its own: its UFM value
    tau_ic = theta(Tp W_c, Td W_c, beta_c) / W_c, its phase value (:func:`phase_tau` with the cycle's
    phase), and its ln K_ic from the UGM. The variance of a test's constraint is the scatter of these
    values over its n_i cycles divided by n_i (the standard error of the mean), plus a systematic
    floor: ``BETA_SYSTEMATIC`` of beta (through d tau / d beta), ``PHASE_SYSTEMATIC`` rad of phase
    (through 1 / Omega) and ``GAIN_SYSTEMATIC`` of ln a. A test with fewer than two finite phases
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
        b = t.beta
        W = _TWO_PI / t.period
        m = b.size
        th, a_unit = unit_cycle(Tp * W, Td_ref * W, b)
        tu = th / W
        Wm, bm = float(W.mean()), float(np.nanmean(b))
        db = 1e-4
        th2, _ = unit_cycle(Tp * Wm, Td_ref * Wm, np.array([bm - db, bm + db]))
        dtau_dbeta = float(th2[1] - th2[0]) / (2 * db) / Wm
        var = np.nanvar(tu, ddof=1) / m if m > 1 else 0.0
        sig_u[i] = math.sqrt(var + (dtau_dbeta * BETA_SYSTEMATIC) ** 2)
        if "phase" in constraints:
            ph = t.phase
            ok = np.isfinite(ph)
            if ok.sum() >= 2:
                tp_ = phase_tau(Tp, W[ok], ph[ok], Td_ref)
                sig_p[i] = math.sqrt(np.var(tp_, ddof=1) / ok.sum() + (PHASE_SYSTEMATIC / Wm) ** 2)
        if "amplitude" in constraints:
            lnk = np.log(t.amplitude * W / (t.h * Td_ref * a_unit))
            var = np.var(lnk, ddof=1) / m if m > 1 else 0.0
            sig_k[i] = math.sqrt(var + GAIN_SYSTEMATIC**2)

    def inv(sg: np.ndarray) -> np.ndarray:
        return np.where(np.isfinite(sg) & (sg > 0), 1.0 / np.where(sg > 0, sg, 1.0) ** 2, 0.0)

    return {"w_ufm": inv(sig_u), "w_phase": inv(sig_p), "w_gain": inv(sig_k),
            "sigma_ufm_s": sig_u, "sigma_phase_s": sig_p, "sigma_ln_gain": sig_k}


def constraint_report(Tp: float, tests: Sequence[StableCycles], Td: float, tau: float, betas: np.ndarray,
                      omegas: np.ndarray, phases: np.ndarray, ln_amp: np.ndarray, cw: dict[str, np.ndarray],
                      constraints: Sequence[str]) -> dict[str, Any]:
    """The constraints used and their residuals at the estimate (Td, tau) [s] (for the JSON and the warnings).

    ``betas``, ``omegas`` [rad/s], ``phases`` [rad] and ``ln_amp`` = ln(a/h) are the tests' means (n,);
    ``cw`` the weights of :func:`constraint_weights`. Returns ``used``, ``requested``, per-test
    residuals (``tests``), ``chi2``, ``dof`` and ``p_value``.
    """
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
        row: dict[str, Any] = {"index": t.index, "beta": float(betas[i]), "omega_rad_s": float(omegas[i])}
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


def ugm_gain(Tp: float, Td: np.ndarray, omegas: np.ndarray, amps: np.ndarray, hs: np.ndarray) -> np.ndarray:
    """K from the UGM (Lemmas 2, 4): a = h K Td a_unit(Tp w, Td w) / w, averaged over the tests.

    ``Td`` (M,) [s]; ``omegas`` [rad/s], ``amps`` [output units] and ``hs`` [command units] (M, n).
    """
    _, a_unit = unit_cycle(Tp * omegas, Td[:, None] * omegas, np.zeros_like(omegas))
    K: np.ndarray = np.mean(amps * omegas / (hs * Td[:, None] * a_unit), axis=1)
    return K


def bootstrap(Tp: float, tests: Sequence[StableCycles], Td_ref: float, constraints: Sequence[str],
              n_draws: int, rng: np.random.Generator) -> Bootstrap:
    """The consensus on the data (row 0) and on ``n_draws`` bootstrap resamples of the stable cycles.

    Parameters
    ----------
    Tp : float
        Propulsion time constant [s].
    tests : sequence of StableCycles
        Two or more tests.
    Td_ref : float
        Centre of the search and the Td at which the constraint weights are evaluated [s].
    constraints : sequence of {"phase", "amplitude"}
        Constraints beyond the UFM slices; ``()``: the UFM slices weighted by the cycle counts.
    n_draws : int
        Bootstrap draws B.
    rng : numpy.random.Generator
        Source of the resamples and systematic errors (used in a fixed order, so a seed reproduces).
    """
    n = len(tests)
    B = int(n_draws)
    hs = np.array([t.h for t in tests])
    ncyc = np.array([t.period.size for t in tests], float)
    bb = np.empty((B + 1, n))
    ww = np.empty((B + 1, n))
    aa = np.empty((B + 1, n))
    pp = np.empty((B + 1, n))
    for i, t in enumerate(tests):
        m = t.period.size
        idx = rng.integers(0, m, size=(B, m))
        idx = np.vstack([np.arange(m)[None, :], idx])  # row 0: the data themselves (the centre)
        bb[:, i] = t.beta[idx].mean(axis=1)
        ww[:, i] = _TWO_PI / t.period[idx].mean(axis=1)
        aa[:, i] = t.amplitude[idx].mean(axis=1)
        pp[:, i] = _nanmean_rows(t.phase[idx])
    bb[1:] += BETA_SYSTEMATIC * rng.standard_normal((B, n))
    ln_amp = np.log(aa / hs[None, :])
    extra = None
    cw = None
    if constraints:
        # the paper weights the slices by the cycle counts; here inverse variances from the measured
        # per-cycle scatter, so the phase and amplitude constraints join on the same footing
        cw = constraint_weights(Tp, tests, Td_ref, constraints)
        pp[1:] += PHASE_SYSTEMATIC * rng.standard_normal((B, n))
        weights = np.broadcast_to(cw["w_ufm"], bb.shape)
        extra = ExtraConstraints.of(pp, ln_amp, cw)
    else:
        weights = np.broadcast_to(ncyc, bb.shape)
    Td_d, tau_d = consensus_solve(Tp, bb, ww, weights, Td_ref, extra=extra)
    K_d = np.full(B + 1, np.nan)
    ok = np.isfinite(Td_d)
    if ok.any():
        K_d[ok] = ugm_gain(Tp, Td_d[ok], ww[ok], aa[ok], np.broadcast_to(hs, aa[ok].shape))
    return Bootstrap(Td=Td_d, tau=tau_d, K=K_d, betas=bb, omegas=ww, phases=pp, ln_amp=ln_amp, weights=cw)


def bootstrap_estimate(point: float, draws: np.ndarray, centre: float, unit: str) -> ParameterEstimate:
    """Point estimate with bootstrap std and a 95 % interval (percentiles shifted to the point).

    ``centre`` is the consensus on the data themselves (bootstrap row 0); fewer than 10 finite
    draws or no centre give NaN spread.
    """
    v = np.asarray(draws, float)
    v = v[np.isfinite(v)]
    if v.size < 10 or not np.isfinite(centre):
        return ParameterEstimate(float(point), float("nan"), float("nan"), float("nan"), unit, method="mrft")
    lo, hi = np.percentile(v, [2.5, 97.5])
    shift = point - centre
    return ParameterEstimate(float(point), float(v.std(ddof=1)), float(lo + shift), float(hi + shift), unit,
                             method="mrft")


def combinations(Tp: float, tests: Sequence[StableCycles], Td_ref: float, max_combinations: int,
                 rng: np.random.Generator) -> dict[str, Any]:
    """Per-combination estimates (paper Table III): one stable cycle from each test.

    Every combination when there are at most ``max_combinations``, else a random subset of that
    size drawn from ``rng``. Returns ``n`` and arrays ``Td``, ``tau`` [s], ``K`` and ``index`` (the
    cycle of each test in each combination).
    """
    n = len(tests)
    sizes = [t.period.size for t in tests]
    total = int(np.prod(sizes, dtype=float)) if np.prod(sizes, dtype=float) < 1e9 else int(1e9)
    if total <= max_combinations:
        grids = np.meshgrid(*[np.arange(s) for s in sizes], indexing="ij")
        combo = np.stack([g.ravel() for g in grids], axis=1)
    else:
        combo = np.stack([rng.integers(0, s, size=max_combinations) for s in sizes], axis=1)
    hs = np.array([t.h for t in tests])
    cb = np.stack([tests[i].beta[combo[:, i]] for i in range(n)], axis=1)
    cw = np.stack([_TWO_PI / tests[i].period[combo[:, i]] for i in range(n)], axis=1)
    ca = np.stack([tests[i].amplitude[combo[:, i]] for i in range(n)], axis=1)
    cTd, ctau = consensus_solve(Tp, cb, cw, np.ones_like(cb), Td_ref)
    cK = np.full(cTd.size, np.nan)
    okc = np.isfinite(cTd)
    if okc.any():
        cK[okc] = ugm_gain(Tp, cTd[okc], cw[okc], ca[okc], np.broadcast_to(hs, ca[okc].shape))
    return {"n": int(cTd.size), "Td": cTd, "tau": ctau, "K": cK, "index": combo}


def upper_bound_open(Tp: float, boot: Bootstrap, Td: float, delta_chi2: float = 3.84) -> bool:
    """Whether the tests cannot bound Td from above (the likelihood does not close as Td -> infinity).

    Evaluates the consensus chi-square (:func:`consensus_objective` on the data themselves, bootstrap
    row 0, with the phase and amplitude constraints) at ``Td`` and at 1e4 ``Td`` (Td Omega >> 1: the
    double-integrator limit, where every curve has flattened): when the rise is below ``delta_chi2``
    (3.84: 95 % for one parameter) a plant without linear damping explains the tests as well, and
    only a lower bound on Td is supported. Needs the constraint weights (``boot.weights``); without
    them (the paper's UFM-only weighting is not a chi-square) returns False.
    """
    cw = boot.weights
    if cw is None or not math.isfinite(Td) or Td <= 0:
        return False
    extra = ExtraConstraints.of(boot.phases[:1], boot.ln_amp[:1], cw)
    x = np.log(np.array([Td, Td * 1e4]))
    J = np.array([consensus_objective(Tp, boot.betas[:1], boot.omegas[:1], np.asarray(cw["w_ufm"], float)[None, :],
                                      x[i:i + 1], extra)[0][0] for i in range(2)])
    return bool(np.all(np.isfinite(J)) and J[1] - J[0] < delta_chi2)


@dataclass(frozen=True, eq=False)
class UnboundedTd:
    """The consensus in the limit Td -> infinity (no linear damping): outcome of :func:`unbounded_td`.

    Attributes
    ----------
    Td_low : float
        95 % lower bound on Td [s] (profile chi-square).
    Td_limit : float
        The Td standing for infinity [s] (Td Omega = 1e4 at the slowest test): the model's Td.
    tau, K : ndarray, shape (B + 1,)
        Delay [s] and gain in the limit for the data (row 0) and each bootstrap draw.
    chi2 : float
        The consensus chi-square of the data in the limit.
    dof : int
        Its degrees of freedom (constraints minus tau, and minus ln K with the amplitude constraint).
    p_value : float
        Chi-square tail probability of ``chi2``.
    """

    Td_low: float
    Td_limit: float
    tau: np.ndarray
    K: np.ndarray
    chi2: float
    dof: int
    p_value: float


def unbounded_td(Tp: float, boot: Bootstrap, delta_chi2: float = 3.84, p_min: float = 1e-3) -> UnboundedTd | None:
    """The one-sided result when the tests fit a plant without linear damping (issue 12 item 8).

    For a double integrator with motor lag and delay (Td -> infinity) the UFM slices of two tests run
    side by side towards large Td, and measurement noise decides whether they cross at all: when
    they do not, :func:`mrftcli.mrft.identify.identify` has no intersection to report, yet the tests
    do determine tau and K, and bound Td from below. Here the consensus chi-square of the data
    (:func:`consensus_objective`, bootstrap row 0, all constraints) is profiled over Td: the limit is
    accepted when no finite Td beats it by ``delta_chi2`` (3.84: 95 % for one parameter) and the
    tests agree in it (chi-square tail probability >= ``p_min``). Td's lower bound is where the
    profile first comes within ``delta_chi2`` of its minimum; tau and K are the consensus in the
    limit, for every bootstrap draw (their spread is the interval).

    Parameters
    ----------
    Tp : float
        Propulsion time constant [s].
    boot : Bootstrap
        :func:`bootstrap` with constraints (its weights evaluated at a large reference Td).
    delta_chi2, p_min : float
        The thresholds above.

    Returns
    -------
    UnboundedTd or None
        None when a finite Td fits better, the tests disagree in the limit, or ``boot`` has no
        constraint weights (the paper's UFM-only weighting is not a chi-square).
    """
    from scipy import stats

    cw = boot.weights
    if cw is None:
        return None
    M, n = boot.betas.shape
    w_ufm = np.broadcast_to(np.asarray(cw["w_ufm"], float), (M, n))
    extra = ExtraConstraints.of(boot.phases, boot.ln_amp, cw)
    wp, w_gain = extra.w_phase, extra.w_gain
    w0 = boot.omegas[0]
    Td_limit = 1e4 / float(np.min(w0))
    # profile of the data (row 0) from Td Omega = 0.1 at the fastest test up to the limit
    x = np.linspace(math.log(0.1 / float(np.max(w0))), math.log(Td_limit), 161)
    e0 = ExtraConstraints(phases=extra.phases[:1].repeat(x.size, 0), w_phase=wp[:1].repeat(x.size, 0),
                          ln_amp=boot.ln_amp[:1].repeat(x.size, 0), w_gain=w_gain[:1].repeat(x.size, 0))
    J = consensus_objective(Tp, boot.betas[:1].repeat(x.size, 0), boot.omegas[:1].repeat(x.size, 0),
                            w_ufm[:1].repeat(x.size, 0), x, e0)[0]
    J = np.where(np.isfinite(J), J, np.inf)
    J_inf = float(J[-1])
    if not math.isfinite(J_inf) or J_inf - float(J.min()) > delta_chi2:
        return None
    m = n + int(np.sum(wp[0] > 0)) + int(np.sum(w_gain[0] > 0))
    dof = m - 1 - (1 if np.sum(w_gain[0]) > 0 else 0)
    p = float(stats.chi2.sf(J_inf, dof)) if dof > 0 else 1.0
    if p < p_min:
        return None
    # the lower bound: below the last grid point whose chi-square rises by delta_chi2 or more
    above = np.nonzero(J - J.min() >= delta_chi2)[0]
    if above.size:
        i = int(above[-1])
        d0, d1 = J[i] - J.min() - delta_chi2, J[i + 1] - J.min() - delta_chi2
        f = d0 / (d0 - d1) if np.isfinite(d0) and d0 != d1 else 0.0
        Td_low = float(np.exp(x[i] + f * (x[i + 1] - x[i])))
    else:
        Td_low = float(np.exp(x[0]))
    J_all, tau, _ = consensus_objective(Tp, boot.betas, boot.omegas, w_ufm, np.full(M, math.log(Td_limit)), extra)
    K = ugm_gain(Tp, np.full(M, Td_limit), boot.omegas, np.exp(boot.ln_amp), np.ones((M, n)))
    return UnboundedTd(Td_low=Td_low, Td_limit=Td_limit, tau=np.asarray(tau, float), K=np.asarray(K, float),
                       chi2=J_inf, dof=int(dof), p_value=p)
