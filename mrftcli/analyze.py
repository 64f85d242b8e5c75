"""One flight log in, the loop's model out: read -> segment -> identify, with uncertainty.

:func:`analyze_flight` takes a :class:`~mrftcli.logtypes.FlightLog`; :func:`analyze_path` reads the
log first. Both are pure (no printing, no files written) and return an :class:`AnalysisResult`.

How the figures are obtained
----------------------------
* Every MRFT test comes from :func:`mrftcli.segment.segment` with its stable cycles, the measured
  frequency and amplitude per cycle and the *effective* beta (the switching level the relay actually
  achieved, measured from the output at the switch instants). Identification uses the effective
  beta with ``rate_hz=None``: at the actual switch instants the sampled, noisy relay *is* a
  continuous relay switching at that level, so no sampling correction applies.
* **Point estimate** (``parameters.*.mean``): :func:`mrftcli.identify.identify` on the tests' mean
  effective beta and mean frequency (two tests: the intersection of the UFM slices, paper Fig. 5;
  three or more: least squares), K from the mean amplitudes through the UGM.
* **Uncertainty** (``std``, ``ci95_low/high``): a bootstrap over cycles. Each draw resamples the
  stable cycles of every test with replacement, recomputes each test's mean beta, frequency and
  amplitude together (so their cycle-to-cycle correlation is kept), adds a systematic beta error
  of standard deviation ``_BETA_SYSTEMATIC`` per test, and re-identifies with a
  vectorised consensus solver (:func:`_consensus_solve`). This propagates the scatter of the
  frequencies *and* of the measured switching levels, the larger error source at small amplitudes.
  ``n_bootstrap`` draws (400), fewer for logs with many tests (draws x tests <= 4000, >= 100).
* **Per-combination spread** (``combinations``, the paper's Table III): one stable cycle from each
  test, identified with that cycle's own beta and frequency, over all combinations (a seeded random
  subset when there are more than ``max_combinations``); mean and standard deviation.

The consensus solver: each test i gives the curve tau_i(Td) (the UFM slice at the known Tp scaled
to real units, Lemma 3). Td minimises sum_i w_i (tau_i(Td) - taubar(Td))^2 with taubar the weighted
mean (for two tests this is their intersection), found by a golden-section search in ln Td
vectorised over draws; tau = taubar(Td).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from .errors import InsufficientDataError, SegmentationError
from .identify import IdentificationResult, ParameterEstimate, TestMeasurement, identify, ufm_slice
from .logtypes import FlightLog
from .lprs import unit_cycle
from .model import LoopModel
from .segment import MrftTest, StabilityCriterion, segment

__all__ = ["AnalysisResult", "analyze_flight", "analyze_path", "ASSUMED_TD_RANGE"]

_TWO_PI = 2.0 * math.pi
#: Td range [s] assumed for the partial result of a single-beta log (multirotor drag time constants).
ASSUMED_TD_RANGE = (0.1, 10.0)
#: Two tests whose betas differ by less than this measure the same UFM slice.
_SAME_BETA = 0.05
#: Td * Omega above which Td is called poorly identifiable (the issue's accuracy boundary).
_TD_OMEGA_LIMIT = 5.0
#: Standard deviation [-] of the systematic error of a test's effective beta (see analyze_flight).
_BETA_SYSTEMATIC = 1e-3


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
        Tests found in the command but left out (too few stable cycles), with the reason in
        ``warnings``.
    Td, tau, K : ParameterEstimate
        Point estimate (``mean``) with bootstrap ``std`` and 95 % interval; Td, tau in seconds, K in
        output units / (command unit s^2) (K Td is the static gain from command to output rate).
    model : LoopModel
        The identified model (the point estimate).
    identification : IdentificationResult
        The point identification from :func:`mrftcli.identify.identify`.
    combinations : dict
        Per-combination estimates (paper Table III): ``n`` and ``Td``/``tau``/``K`` arrays [s].
    bootstrap : dict
        Bootstrap draws ``Td``/``tau``/``K`` (arrays).
    warnings : tuple of str
        Identifiability and data-quality warnings.
    flight : FlightLog
        The signals analysed (for plots; not serialised).
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

    def to_dict(self, cycles: bool = True) -> dict:
        """The JSON object of ``mrft-ident analyze --json``.

        Keys: ``parameters`` (Td, tau, K, Tp; each ``mean``, ``std``, ``ci95_low``, ``ci95_high``,
        ``unit``), ``combinations`` (Table III mean/std), ``tests`` (per test: ``beta`` (the
        effective beta used), ``beta_nominal``, ``beta_effective``, ``h``, ``frequency_hz``,
        ``amplitude``, ``cycles``, ``t_start``, ``t_end``, ... and per-cycle data), ``rejected_tests``,
        ``model``, ``identification`` (method, per-test sensitivities), ``warnings``, ``input``.
        """
        params = {"Td": self.Td.to_dict(), "tau": self.tau.to_dict(), "K": self.K.to_dict(),
                  "Tp": {"mean": self.Tp, "std": 0.0, "ci95_low": self.Tp, "ci95_high": self.Tp, "unit": "s",
                         "known": True}}
        params["K"]["unit"] = "output units / (command unit s^2)"
        ident = self.identification.to_dict()
        flight = self.flight
        inp: dict = {"path": self.path, "loop": self.loop, "Tp": self.Tp}
        if flight is not None:
            tc = np.asarray(flight.command.index, float)
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
            "tests": [t.to_dict(cycles=cycles) for t in self.tests],
            "rejected_tests": [t.to_dict(cycles=False) for t in self.rejected],
            "identification": {"method": ident["method"], "residual": ident["residual"],
                               "tests": self._ident_tests(ident["tests"]), "beta_used": "effective",
                               "rate_correction": None},
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


def _consensus_objective(Tp, betas, omegas, w, x):
    tau = _tau_curves(Tp, betas, omegas, np.exp(x))
    tbar = np.sum(w * tau, axis=1) / np.sum(w, axis=1)
    return np.sum(w * (tau - tbar[:, None]) ** 2, axis=1), tbar


def _consensus_solve(Tp: float, betas: np.ndarray, omegas: np.ndarray, weights: np.ndarray,
                     Td_ref: float, span: float = 10.0, iters: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised (Td, tau) for M sets of n tests (see the module docstring).

    Parameters
    ----------
    Tp : float
        Propulsion time constant [s].
    betas, omegas, weights : numpy.ndarray
        Shape (M, n): beta, frequency [rad/s] and weight of each test in each set.
    Td_ref : float
        Centre of the search [s]; the search covers Td_ref / span .. Td_ref * span.

    Returns
    -------
    (Td, tau) : arrays of shape (M,) [s]; NaN where the search ended on its boundary (no
    intersection inside the range).
    """
    M = betas.shape[0]
    a = np.full(M, math.log(Td_ref / span))
    b = np.full(M, math.log(Td_ref * span))
    g = (math.sqrt(5.0) - 1.0) / 2.0
    c = b - g * (b - a)
    d = a + g * (b - a)
    fc, _ = _consensus_objective(Tp, betas, omegas, weights, c)
    fd, _ = _consensus_objective(Tp, betas, omegas, weights, d)
    for _ in range(iters):
        left = fc < fd  # minimum in [a, d]
        b = np.where(left, d, b)
        a = np.where(left, a, c)
        new = np.where(left, b - g * (b - a), a + g * (b - a))
        fnew, _ = _consensus_objective(Tp, betas, omegas, weights, new)
        d_new = np.where(left, c, new)
        fd_new = np.where(left, fc, fnew)
        c_new = np.where(left, new, d)
        fc_new = np.where(left, fnew, fd)
        c, d, fc, fd = c_new, d_new, fc_new, fd_new
    x = 0.5 * (a + b)
    _, tau = _consensus_objective(Tp, betas, omegas, weights, x)
    Td = np.exp(x)
    edge = (x <= math.log(Td_ref / span) + 1e-3) | (x >= math.log(Td_ref * span) - 1e-3)
    Td = np.where(edge, np.nan, Td)
    tau = np.where(edge | ~np.isfinite(tau), np.nan, tau)
    return Td, tau


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


def _describe(tests: Sequence[MrftTest]) -> str:
    parts = []
    for t in tests:
        b = f"beta {t.beta_nominal:g}" if t.beta_nominal is not None else f"beta~{t.beta_effective:.2f}"
        parts.append(f"{b} at {t.t_start:.1f}-{t.t_end:.1f} s ({t.n_stable} stable of {len(t.cycles)} cycles)")
    return "; ".join(parts)


def _partial_single_beta(Tp: float, tests: Sequence[MrftTest]) -> dict:
    """What one beta can say: tau(Td) over the assumed Td range, per test."""
    Td = np.geomspace(ASSUMED_TD_RANGE[0], ASSUMED_TD_RANGE[1], 9)
    out = {"assumed_Td_range_s": list(ASSUMED_TD_RANGE), "tests": [t.to_dict(cycles=False) for t in tests],
           "tau_for_assumed_Td": []}
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

    Returns
    -------
    AnalysisResult

    Raises
    ------
    SegmentationError
        No relay test in the log, or no test with ``min_stable_cycles`` stable cycles.
    InsufficientDataError
        Usable tests at a single beta only (``.partial`` gives tau over an assumed Td range).
    IdentificationError
        The measured cycles admit no plant of eq. (2) with this Tp.
    """
    from .identify import _check_time  # the identify module's validation of a time argument

    Tp = _check_time("Tp", Tp)
    crit = criterion or StabilityCriterion()
    found = segment(flight, criterion=crit)
    usable = [t for t in found if t.n_stable >= min_stable_cycles and np.isfinite(t.beta_effective)]
    rejected = [t for t in found if t not in usable]
    warnings: list[str] = []
    for t in rejected:
        warnings.append(f"test at {t.t_start:.1f}-{t.t_end:.1f} s left out: {t.n_stable} stable cycles "
                        f"(need {min_stable_cycles})")
    if not usable:
        raise SegmentationError(
            f"{flight.path}: found {len(found)} relay test(s) but none with {min_stable_cycles} or more stable "
            f"cycles ({_describe(found)}); record longer tests or check for noise/dropouts"
        )
    groups = _group_betas(usable)
    if len(groups) < 2:
        raise InsufficientDataError(
            f"{flight.path}: only one beta was tested ({_describe(usable)}); Td and tau need two tests with "
            f"different betas (e.g. -0.4 and -0.7). Partial result: tau for an assumed Td range "
            f"{ASSUMED_TD_RANGE[0]:g}-{ASSUMED_TD_RANGE[1]:g} s",
            partial=_partial_single_beta(Tp, usable),
        )
    for t in usable:
        warnings.extend(f"test at {t.t_start:.1f} s: {n}" for n in t.notes)
        if t.beta_nominal is not None and abs(t.beta_effective - t.beta_nominal) > 0.02:
            warnings.append(
                f"test at {t.t_start:.1f} s: the relay switched at beta {t.beta_effective:.3f}, not the nominal "
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
    hs = np.array([t.h for t in usable])
    ncyc = np.array([t.n_stable for t in usable], float)
    # Many tests: fewer draws keep the cost (draws x tests) bounded; a few hundred draws suffice
    # for a std and percentile interval.
    B = int(min(n_bootstrap, max(100, 4000 // n)))
    bb = np.empty((B + 1, n))
    ww = np.empty((B + 1, n))
    aa = np.empty((B + 1, n))
    for i in range(n):
        m = per_P[i].size
        idx = rng.integers(0, m, size=(B, m))
        idx = np.vstack([np.arange(m)[None, :], idx])  # row 0: the data themselves (the centre)
        bb[:, i] = per_b[i][idx].mean(axis=1)
        ww[:, i] = _TWO_PI / per_P[i][idx].mean(axis=1)
        aa[:, i] = per_a[i][idx].mean(axis=1)
    # Systematic floor of the effective-beta measurement (harmonic truncation of the cycle model,
    # cycle-to-cycle non-periodicity of a noisy sampled relay): up to ~5e-4 on noise-free
    # simulations, taken as a 1e-3 standard deviation per test so the interval does not rest on
    # the random scatter alone (it matters when Td * Omega is large and the slices nearly parallel).
    bb[1:] += _BETA_SYSTEMATIC * rng.standard_normal((B, n))
    weights = np.broadcast_to(ncyc, bb.shape)
    Td_d, tau_d = _consensus_solve(Tp, bb, ww, weights, Td_hat)
    K_d = np.full(B + 1, np.nan)
    ok = np.isfinite(Td_d)
    if ok.any():
        K_d[ok] = _gain(Tp, Td_d[ok], ww[ok], aa[ok], np.broadcast_to(hs, aa[ok].shape))
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
    """Read one log with :func:`mrftcli.readers.read_flight` and run :func:`analyze_flight`.

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
    from .readers import read_flight

    flight = read_flight(path, loop=loop, command_topic=command_topic, output_topic=output_topic,
                         beta_topic=beta_topic, setpoint_topic=setpoint_topic, battery_topic=battery_topic,
                         output_scale=1.0 if output_scale is None else output_scale, fmt=fmt)
    return analyze_flight(flight, Tp, **kwargs)
