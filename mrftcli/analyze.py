"""One flight log in, the loop's model out: read -> segment -> identify, with uncertainty.

:func:`analyze_flight` takes a :class:`~mrftcli.io.logtypes.FlightLog`; :func:`analyze_path` reads the
log first. Both are pure (no printing, no files written) and return an :class:`AnalysisResult`.

How the figures are obtained
----------------------------
* Every MRFT test comes from :func:`mrftcli.segment.segment` with its stable cycles, the measured
  frequency and amplitude per cycle and the *effective* beta (the switching level the relay actually
  achieved, measured from the output at the switch instants). Identification uses the effective
  beta with ``rate_hz=None``: at the actual switch instants the sampled, noisy relay *is* a
  continuous relay switching at that level, so no sampling correction applies.
* **Point estimate** (``parameters.*.mean``): the paper's method at its core - each test's UFM
  slice at the known Tp scaled to real units (Lemma 3, exact LPRS, the test's mean effective beta
  and mean frequency) - with two more measured constraints per test in one weighted least squares
  (*Beyond the paper*, :mod:`mrftcli.mrft.consensus`; ``constraints=()`` leaves them out): the
  **phase** of each test's fundamental harmonic (``RelayCycle.phase_h1``; on the 30-plant sweep its
  standard error in tau is 1.2-4.9 times (median 2.2) smaller than the UFM slice's, and the tau RMS
  error drops from 0.59 to 0.16 ms, docs/benchmarks/analyze.md) and the **amplitude** ratios between
  tests through the UGM. ``identification`` keeps the UFM-only result of
  :func:`mrftcli.mrft.identify.identify` (the paper's estimate) and ``constraints`` the constraints
  used with their residuals at the estimate and the chi-square; a chi-square with p < 1e-3 raises a
  warning (the constraints disagree: the plant may not follow eq. (2)).
* **Uncertainty** (``std``, ``ci95_low/high``): a bootstrap over cycles
  (:func:`mrftcli.mrft.consensus.bootstrap`): ``n_bootstrap`` draws (400), fewer for logs with many
  tests (draws x tests <= 4000, >= 100).
* **Per-combination spread** (``combinations``, the paper's Table III): one stable cycle from each
  test, identified with that cycle's own beta and frequency, over all combinations (a seeded random
  subset when there are more than ``max_combinations``; :func:`mrftcli.mrft.consensus.combinations`).

Times: people read times relative to the log's first sample (``AnalysisResult.t0``, epoch seconds
in real logs); the JSON keeps the absolute ``t_start``/``t_end`` and adds ``t_start_rel``/``t_end_rel``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from .errors import IdentificationError, InputError, InsufficientDataError, SegmentationError
from .io.logtypes import FlightLog
from .mrft.consensus import (CONSTRAINTS, SAME_BETA, Bootstrap, StableCycles, UnboundedTd, bootstrap,
                             bootstrap_estimate, combinations, constraint_report, unbounded_td, upper_bound_open)
from .mrft.identify import IdentificationResult, ParameterEstimate, TestMeasurement, identify, ufm_slice
from .mrft.model import LoopModel
from .mrft.refine import Refinement, refine, refinement_windows
from .segment import MrftTest, StabilityCriterion, ValidityCriterion, segment
from .validate import check_tp

__all__ = ["AnalysisResult", "analyze_flight", "analyze_path", "analysis_overlay", "command_rate_of_result", "log_start", "describe_t0",
           "CONSTRAINTS", "ASSUMED_TD_RANGE"]

_TWO_PI = 2.0 * math.pi
#: Td range [s] assumed for the partial result of a single-beta log (multirotor drag time constants).
ASSUMED_TD_RANGE = (0.1, 10.0)
#: Td * Omega above which Td is called poorly identifiable (the issue's accuracy boundary).
_TD_OMEGA_LIMIT = 5.0


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
    method : {"waveform", "mrft"}
        Which estimate ``Td``, ``tau``, ``K`` and ``model`` hold: the output-error refinement on the
        waveform (:func:`mrftcli.mrft.refine.refine`, when the data accept it) or the MRFT consensus.
    parameters_mrft : dict
        ``"Td"``, ``"tau"``, ``"K"`` -> the MRFT estimate (bootstrap std and interval), whichever is used.
    refinement : Refinement or None
        The waveform refinement (estimate, std, acceptance and reasons); None when not run.
    notes : tuple of str
        Information that needs no action (e.g. Td*Omega > 5 on an altitude loop, where it is usual);
        ``warnings`` hold what the user should act on.
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
    method: str = "mrft"
    parameters_mrft: dict = field(default_factory=dict)
    refinement: Refinement | None = None
    notes: tuple[str, ...] = ()

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
        for name in ("Td", "tau", "K"):
            params[name]["method"] = self.method
        ident = self.identification.to_dict()
        k_unit = params["K"]["unit"]

        def group(est: dict) -> dict:
            out = {k: v.to_dict() for k, v in est.items()}
            if "K" in out:
                out["K"]["unit"] = k_unit
            return out

        extra: dict = {}
        if self.parameters_mrft:
            extra["parameters_mrft"] = group(self.parameters_mrft)
        if self.refinement is not None:
            ref = self.refinement
            extra["parameters_waveform"] = group({"Td": ref.Td, "tau": ref.tau, "K": ref.K})
            extra["refinement"] = {"method": "output error on the tests' windows (exact ZOH, fractional delay)",
                                   **ref.to_dict()}
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
            **extra,
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
            "notes": list(self.notes),
            "input": inp,
        }


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
            if abs(k - key) < SAME_BETA:
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
    refine_waveform: bool = True,
    controller_rate_hz: float | None = None,
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
        Thresholds of the limit-cycle validity check (:func:`mrftcli.segment.check_limit_cycle`):
        a test whose output does not follow its relay as an MRFT limit cycle is rejected, and so are
        the tests whose loop-gain sign disagrees with the others' (:func:`_screen_tests`).
    refine_waveform : bool
        Refine the MRFT estimate by output error on the tests' windows and report it when the data
        accept it (:func:`mrftcli.mrft.refine.refine`); False: the MRFT estimate alone.
    controller_rate_hz : float, optional
        Rate the relay decides at [Hz] when the log sub-samples it (PX4 logs its 50 Hz position
        controller at 10 Hz by default); None: the flight's ``source["controller_rate_hz"]``.
        A log below the controller's rate is identified as a sampled relay at the nominal beta
        (:func:`_low_rate_period`).

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
        The measured cycles admit no plant of eq. (2) with this Tp. (Slices that do not cross but
        fit a plant without linear damping are not an error: Td is then bounded from below only,
        ``identification.method == "unbounded-Td"``.)

    Examples
    --------
    A shipped sample log (simulated Design I altitude loop: Td 2.669 s, tau 46.4 ms, K 19.62):

    >>> from pathlib import Path
    >>> from mrftcli.io import read_flight
    >>> log = Path(__file__).parents[1] / "sample_logs" / "design1_altitude.mcap"
    >>> result = analyze_flight(read_flight(log, loop="altitude"), Tp=0.0422, n_bootstrap=100)
    >>> print(f"Td {result.Td.mean:.2f} s ({result.Td.ci95_low:.2f}-{result.Td.ci95_high:.2f}), "
    ...       f"tau {result.tau.mean * 1e3:.1f} ms")
    Td 2.66 s (2.65-2.67), tau 46.4 ms
    """
    Tp = check_tp(Tp)
    constraints = tuple(constraints)
    bad = [c for c in constraints if c not in CONSTRAINTS]
    if bad:
        raise InputError(f"unknown constraint(s) {bad}; choose from {list(CONSTRAINTS)}")
    crit = criterion or StabilityCriterion()
    found = segment(flight, criterion=crit, validity=validity or ValidityCriterion(),
                    controller_rate_hz=controller_rate_hz)
    t0 = log_start(flight)
    reasons = _screen_tests(found, min_stable_cycles)
    usable = [t for t in found if t.index not in reasons]
    rejected = [t for t in found if t.index in reasons]
    warnings: list[str] = []
    for t in rejected:
        warnings.append(f"test at {_span(t, t0)} left out: {reasons[t.index]}")
    if not usable:
        err = SegmentationError(_no_usable_message(flight, found, reasons, min_stable_cycles, t0))
        # for ``--json``: what was found and why each test was rejected (read by cli/analyze.py)
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
    ts_ctrl = _low_rate_period(usable)
    for t in usable:
        warnings.extend(f"test at {t.t_start - t0:.1f} s: {n}" for n in t.notes)
        # a low-rate log is identified at the nominal beta: its coarse effective beta is expected to differ
        if t.beta_nominal is not None and abs(t.beta_effective - t.beta_nominal) > 0.02 and not ts_ctrl:
            warnings.append(
                f"test at {t.t_start - t0:.1f} s: the relay switched at beta {t.beta_effective:.3f}, not the nominal "
                f"{t.beta_nominal:g} (sampling and noise); identified with the effective value"
            )
    warnings.extend(flight.warnings)

    # ---- point estimate through the identification core ---------------------------------------
    meas = [TestMeasurement(beta=_beta_used(t, ts_ctrl), frequency_hz=t.frequency_hz_mean, amplitude=t.amplitude_mean,
                            h=t.h) for t in usable]
    rng = np.random.default_rng(seed)
    n = len(usable)
    cycles = [_stable_cycles(t, ts_ctrl) for t in usable]
    # Many tests: fewer draws keep the cost (draws x tests) bounded; a few hundred draws suffice
    # for a std and percentile interval.
    B = int(min(n_bootstrap, max(100, 4000 // n)))
    limit = None
    try:
        ident = identify(meas, Tp, rate_hz=None)
    except IdentificationError as exc:
        # The slices may not cross because the plant has no linear damping (Td -> infinity: they run
        # side by side and noise decides); the consensus says whether the tests agree in that limit.
        ident, limit = _unbounded_td_or_raise(exc, Tp, meas, cycles, constraints, B, rng)
    warnings.extend(ident.warnings)
    model = ident.model
    Td_hat, tau_hat = model.Td, model.tau
    K_hat = ident.K.mean if ident.K is not None else float("nan")

    # ---- the consensus of the tests and its bootstrap over cycles ---------------------------------
    if limit is None:
        boot = bootstrap(Tp, cycles, Td_hat, constraints, B, rng)
        Td_d, tau_d, K_d = boot.Td, boot.tau, boot.K
    else:
        boot, limit = limit
        Td_d, tau_d, K_d = np.full(B + 1, Td_hat), limit.tau, limit.K
    constraint_info: dict = {}
    if constraints and np.isfinite(Td_d[0]):
        # the weighted estimate on the data themselves (bootstrap row 0) is the point estimate; the
        # paper's UFM-only estimate stays in ``identification`` for comparison
        Td_hat, tau_hat, K_hat = float(Td_d[0]), float(tau_d[0]), float(K_d[0])
        model = LoopModel(Tp, Td_hat, max(tau_hat, 0.0), K_hat if np.isfinite(K_hat) else model.K)
        constraint_info = constraint_report(Tp, cycles, Td_hat, tau_hat, boot.betas[0], boot.omegas[0],
                                            boot.phases[0], boot.ln_amp[0], boot.weights, constraints)
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
    if ts_ctrl:
        # the sampled relay's continuous equivalent has the delay tau + Ts / 2 (it switches 0..Ts
        # after the crossing of its level); remove that lag from every tau
        lag = 0.5 * ts_ctrl
        tau_hat, tau_d = tau_hat - lag, tau_d - lag
        model = LoopModel(Tp, model.Td, max(model.tau - lag, 0.0), model.K)
    Td_est = bootstrap_estimate(Td_hat, Td_d[1:], Td_d[0], "s")
    tau_est = bootstrap_estimate(tau_hat, tau_d[1:], tau_d[0], "s")
    K_est = bootstrap_estimate(K_hat, K_d[1:], K_d[0], "")
    if limit is not None:
        Td_est = ParameterEstimate(Td_hat, float("nan"), limit.Td_low, float("nan"), "s")
    n_fail = int((~np.isfinite(Td_d[1:])).sum())
    if n_fail > 0.05 * B:
        warnings.append(f"{n_fail} of {B} bootstrap draws found no intersection of the UFM slices within "
                        f"{Td_hat / 10:.3g}-{Td_hat * 10:.3g} s: Td is poorly determined")

    # ---- per-combination identification (paper Table III) -------------------------------------
    combos = combinations(Tp, cycles, Td_hat, int(min(max_combinations, max(50, 4000 // n))), rng)

    # ---- identifiability ----------------------------------------------------------------------
    notes: list[str] = []  # what is expected and needs no action (shown as information)
    td_omega = max(Td_hat * _TWO_PI * t.frequency_hz_mean for t in usable)
    td_open = limit is not None or (bool(constraints) and upper_bound_open(Tp, boot, Td_hat))
    if td_open:
        # the likelihood does not close as Td -> infinity: a lower bound only (the upper end of the
        # bootstrap interval would come from the search range, not from the data)
        Td_est = ParameterEstimate(Td_est.mean, Td_est.std, Td_est.ci95_low, float("nan"), "s")
        low = f"Td > {Td_est.ci95_low:.3g} s" if np.isfinite(Td_est.ci95_low) else "Td"
        warnings.append(f"{low}: these tests cannot bound it from above (a plant without "
                        "linear damping fits them as well); tau and K are determined")
    elif td_omega > _TD_OMEGA_LIMIT:
        # usual for an altitude loop (slow drag, fast loop): information, not a warning, unless the
        # interval is too wide to use (then the user should act: another test, 'mrft-ident plan')
        text = (f"Td*Omega = {td_omega:.1f} > {_TD_OMEGA_LIMIT:g}: the test frequencies depend weakly on Td, so Td "
                f"is less closely determined than tau and K (MRFT interval {Td_est.ci95_low:.3g}-{Td_est.ci95_high:.3g} s)")
        if Td_est.ci95_high > 2.0 * Td_est.ci95_low:
            warnings.append(text + "; a test at another beta narrows it (see 'mrft-ident plan')")
        else:
            notes.append(text)

    if ts_ctrl and limit is None:
        Td_est, tau_est, K_est = _widen_for_orbits(Tp, cycles, Td_hat, constraints, ts_ctrl,
                                                   (Td_est, tau_est, K_est), rng)
        rate = min(t.rate_hz for t in usable)
        notes.append(f"command logged at {rate:.0f} Hz below the {1 / ts_ctrl:.0f} Hz controller: identified as "
                     "a sampled relay at the nominal beta (the logged switch instants and output levels are too "
                     f"coarse), with +-{0.5e3 * ts_ctrl:.0f} ms of switching lag per test in the intervals")

    # ---- refinement on the waveform (output error from the MRFT estimate) -------------------------
    mrft_params = {"Td": Td_est, "tau": tau_est, "K": K_est}
    refinement = None
    method = "mrft"
    if refine_waveform and ts_ctrl:
        # the waveform needs the command as the plant received it; logged below the controller's
        # rate, its switch instants are off by up to a logging period
        notes.append("the waveform refinement was not run: the command is logged below the controller's rate")
    elif refine_waveform and np.isfinite(K_hat):
        windows = refinement_windows(usable, flight.command.t, flight.command.values, flight.output.t,
                               flight.output.values)
        if windows:
            # Td bounded from below only: the cost is flat along ln Td, and the fit takes longer
            refinement = refine(windows, model, mrft_params, loop_sign=usable[0].loop_sign,
                                max_evaluations=80 if td_open else 30)
            if refinement.accepted:
                method = "waveform"
                model = refinement.model
                Td_est, tau_est, K_est = refinement.Td, refinement.tau, refinement.K
                if td_open:
                    # the waveform does not close it either: keep the one-sided statement, with the
                    # consensus's profile lower bound (the Gauss-Newton interval of ln Td is a local
                    # linearisation, meaningless where the cost is flat in Td: it gave 1e-5 s)
                    Td_est = ParameterEstimate(Td_est.mean, Td_est.std, mrft_params["Td"].ci95_low, float("nan"), "s")
            else:
                warnings.append("the waveform refinement was not used (" + "; ".join(refinement.reasons)
                                + "): the MRFT estimate is reported (try --diagnose)")
    jitter = float(flight.source.get("timing_jitter_s") or 0.0)
    if jitter >= 1e-4 and np.isfinite(tau_est.std):  # below 0.1 ms: stamp rounding, not transport
        # receive-time stamps: the command's and the output's transport delays differ by an unknown
        # offset of the order of their jitter, which moves every switch against the output alike
        # (no averaging over cycles): added to tau's spread in quadrature
        std = float(np.hypot(tau_est.std, jitter))
        widen = 1.96 * std - 1.96 * tau_est.std
        tau_est = ParameterEstimate(tau_est.mean, std, tau_est.ci95_low - widen, tau_est.ci95_high + widen, "s")
        notes.append(f"receive-time stamps: {jitter * 1e3:.1f} ms of timing jitter between topics is folded "
                     "into tau's interval")
    warnings = list(dict.fromkeys(warnings))  # unique, in order
    return AnalysisResult(notes=tuple(notes),
        path=str(flight.path), loop=flight.loop, Tp=Tp, tests=tuple(usable), rejected=tuple(rejected),
        Td=Td_est, tau=tau_est, K=K_est, model=model, identification=ident, combinations=combos,
        bootstrap={"Td": Td_d[1:], "tau": tau_d[1:], "K": K_d[1:]}, warnings=tuple(warnings), flight=flight,
        t0=t0, constraints=constraint_info, rejection_reasons={t.index: reasons[t.index] for t in rejected},
        method=method, parameters_mrft=mrft_params, refinement=refinement,
    )


def _unbounded_td_or_raise(exc: IdentificationError, Tp: float, meas: list[TestMeasurement],
                           cycles: list[StableCycles], constraints: Sequence[str], B: int,
                           rng: np.random.Generator) -> tuple[IdentificationResult, tuple[Bootstrap, UnboundedTd]]:
    """The Td -> infinity result when the tests fit a plant without linear damping, else ``exc``.

    Returns the identification record of the limit (method ``"unbounded-Td"``) and the bootstrap
    with :func:`mrftcli.mrft.consensus.unbounded_td`'s result.
    """
    if not constraints:
        raise exc
    Td_ref = 1e4 / (_TWO_PI * min(m.frequency_hz for m in meas))
    boot = bootstrap(Tp, cycles, Td_ref, constraints, B, rng)
    limit = unbounded_td(Tp, boot)
    if limit is None or not limit.tau[0] >= 0:  # a finite Td fits better, or no plant of eq. (2) does
        raise exc
    tau = bootstrap_estimate(float(limit.tau[0]), limit.tau[1:], float(limit.tau[0]), "s")
    K = bootstrap_estimate(float(limit.K[0]), limit.K[1:], float(limit.K[0]), "")
    Td = ParameterEstimate(limit.Td_limit, float("nan"), limit.Td_low, float("nan"), "s")
    ident = IdentificationResult(
        Td=Td, tau=tau, K=K, model=LoopModel(Tp, limit.Td_limit, max(tau.mean, 0.0), K.mean), Tp=Tp,
        residual=None, tests=(), method="unbounded-Td", uncertainty="bootstrap", n_draws=B,
        warnings=(f"the UFM slices do not intersect: identified in the limit Td -> infinity, which the tests "
                  f"fit (chi2 {limit.chi2:.1f} for {limit.dof} degrees of freedom)",))
    return ident, (boot, limit)


def _low_rate_period(tests: Sequence[MrftTest]) -> float:
    """The controller's period [s] when every test's command is logged below it with a nominal beta, else 0.

    Then the logged switch instants are known to a logging period only, and with them the output
    at the switch (the effective beta) and the phase of the fundamental: the tests are identified
    from the nominal beta as a relay sampled at the controller's rate (exact LPRS band centre: the
    continuous cycle with the delay tau + Ts / 2, :func:`mrftcli.mrft.lprs.sampled_limit_cycle`)
    and their frequencies (a mean over many switches, unbiased) and amplitudes.
    """
    if not tests or any(t.controller_rate_hz is None or t.beta_nominal is None for t in tests):
        return 0.0
    return 1.0 / max(t.controller_rate_hz for t in tests)


def _beta_used(test: MrftTest, ts_ctrl: float) -> float:
    """The beta a test is identified with: nominal for a low-rate log (:func:`_low_rate_period`), else effective."""
    return float(test.beta_nominal) if ts_ctrl and test.beta_nominal is not None else test.beta_effective


def _stable_cycles(test: MrftTest, ts_ctrl: float = 0.0) -> StableCycles:
    """The per-cycle arrays of a test's stable cycles that the consensus reads.

    For a low-rate log (``ts_ctrl`` > 0): the nominal beta and no phase (the switch instants are
    too coarse for it, and the error they share over a test's cycles does not average out).
    """
    st = test.stable
    if ts_ctrl:
        return StableCycles(beta=np.full(len(st), _beta_used(test, ts_ctrl)), period=test.period,
                            amplitude=test.amplitude, phase=np.full(len(st), np.nan), h=test.h, index=test.index)
    return StableCycles(beta=np.array([c.beta_effective for c in st]), period=test.period,
                        amplitude=test.amplitude, phase=np.array([c.phase_h1 for c in st]), h=test.h,
                        index=test.index)


def _widen_for_orbits(Tp: float, cycles: list[StableCycles], Td: float, constraints: Sequence[str],
                      ts_ctrl: float, estimates: tuple[ParameterEstimate, ...],
                      rng: np.random.Generator) -> tuple[ParameterEstimate, ...]:
    """Td, tau, K with the sampled relay's switching lag per test added to their spread.

    A relay sampled at period Ts switches 0..Ts after the crossing of its level; the band centre
    takes Ts / 2, and where in that band a test's cycles settled (its orbits) is common to all its
    cycles and cannot be seen at a lower logging rate: a lag uniform over Ts, std Ts / sqrt(12),
    independent between tests. A lag d moves the continuous equivalent's switching level by
    Omega sqrt(1 - beta^2) d (the output's slope at the switch over the amplitude); each test's
    effect on the estimate is found by re-solving with its beta moved by one std, and the effects
    are added in quadrature to the bootstrap std (the 95 % interval widened by 1.96 times the increase).
    """
    sd = ts_ctrl / math.sqrt(12.0)
    base = bootstrap(Tp, cycles, Td, constraints, 0, rng)
    p0 = np.array([base.Td[0], base.tau[0], base.K[0]])
    var = np.zeros(3)
    for i, c in enumerate(cycles):
        w = _TWO_PI / c.period
        moved = StableCycles(beta=c.beta + w * np.sqrt(1.0 - c.beta ** 2) * sd, period=c.period,
                             amplitude=c.amplitude, phase=c.phase, h=c.h, index=c.index)
        b = bootstrap(Tp, [moved if j == i else cc for j, cc in enumerate(cycles)], Td, constraints, 0, rng)
        d = np.array([b.Td[0], b.tau[0], b.K[0]]) - p0
        var += np.where(np.isfinite(d), d, 0.0) ** 2
    out = []
    for est, v in zip(estimates, var):
        if not np.isfinite(est.std):
            out.append(est)
            continue
        std = float(math.sqrt(est.std ** 2 + v))
        widen = 1.96 * (std - est.std)
        out.append(ParameterEstimate(est.mean, std, est.ci95_low - widen, est.ci95_high + widen, est.unit))
    return tuple(out)


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
    output_scale: float | None = None,
    fmt: str | None = None,
    layout: str | None = None,
    command_scale: float | None = None,
    controller_rate_hz: float | None = None,
    min_stable_cycles: int = 3,
    criterion: StabilityCriterion | None = None,
    n_bootstrap: int = 400,
    max_combinations: int = 400,
    seed: int = 0,
    constraints: Sequence[str] = CONSTRAINTS,
    validity: ValidityCriterion | None = None,
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
    output_scale, command_scale : float, optional
        Factors applied to the output and setpoint, and to the command (default: the layout's).
    fmt : str, optional
        Log format (detected when omitted).
    layout : str, optional
        One of :data:`mrftcli.io.LAYOUT_NAMES` (recognised from the topics when omitted).
    controller_rate_hz : float, optional
        Rate [Hz] at which the relay decided (default: the layout's; see :func:`mrftcli.io.read_flight`).
    min_stable_cycles, criterion, n_bootstrap, max_combinations, seed, constraints, validity
        As in :func:`analyze_flight`.

    Returns
    -------
    AnalysisResult

    Examples
    --------
    >>> from pathlib import Path
    >>> log = Path(__file__).parents[1] / "sample_logs" / "design1_altitude.csv"
    >>> result = analyze_path(log, Tp=0.0422, loop="altitude", n_bootstrap=100)
    >>> [round(t.beta_nominal, 1) for t in result.tests], f"{result.K.mean:.1f}"
    ([-0.4, -0.7], '19.6')
    """
    from .io import read_flight

    flight = read_flight(path, loop=loop, command_topic=command_topic, output_topic=output_topic,
                         beta_topic=beta_topic, setpoint_topic=setpoint_topic, battery_topic=battery_topic,
                         output_scale=output_scale, fmt=fmt, layout=layout, command_scale=command_scale,
                         controller_rate_hz=controller_rate_hz, echo_warnings=False)  # the reader's warnings come once, in the result's
    return analyze_flight(flight, Tp, min_stable_cycles=min_stable_cycles, criterion=criterion,
                          n_bootstrap=n_bootstrap, max_combinations=max_combinations, seed=seed,
                          constraints=constraints, validity=validity)


def analysis_overlay(result: AnalysisResult) -> dict:
    """What the results MCAP of an analysis shows, as the keyword arguments of
    :func:`mrftcli.io.overlay.write_overlay`: its tests, the identified model's prediction over each
    test (:func:`mrftcli.mrft.waveform.predict_tests`, driven by the recorded command), the
    parameters [s; K in output units / (command unit s^2)] and metadata strings.

    Raises
    ------
    InputError
        The result carries no flight signals (``result.flight`` is None).
    """
    from ._version import __version__
    from .io.overlay import OverlayFit, OverlayTest
    from .mrft.waveform import predict_tests

    flight = result.flight
    if flight is None:
        raise InputError("the analysis carries no flight signals to overlay")
    preds = predict_tests(result.model, result.tests, flight.command.t, flight.command.values,
                          flight.output.t, flight.output.values)
    tests = [OverlayTest(number=t.index + 1, t_start=t.t_start, t_end=t.t_end, beta=t.beta_effective,
                         beta_nominal=t.beta_nominal, h=t.h, bias=t.bias, frequency_hz=t.frequency_hz_mean,
                         amplitude=t.amplitude_mean, cycles=t.n_stable,
                         rms_residual=preds[t.index].rms if t.index in preds else float("nan"))
             for t in result.tests]
    fits = [OverlayFit(number=i + 1, t=p.t, output=p.y + p.residual, predicted=p.y) for i, p in preds.items()]
    params = {name: {"mean": est.mean, "std": est.std, "ci95_low": est.ci95_low, "ci95_high": est.ci95_high}
              for name, est in (("Td", result.Td), ("tau", result.tau), ("K", result.K))}
    params = {"Tp": {"mean": result.Tp, "std": 0.0, "ci95_low": result.Tp, "ci95_high": result.Tp}, **params}
    meta = {"log": str(result.path), "loop": result.loop, "mrft_ident_version": __version__,
            "time_base": "the original log's time [s] (MCAP log_time = seconds * 1e9)"}
    return {"tests": tests, "fits": fits, "parameters": params, "metadata": meta}


def command_rate_of_result(data: dict) -> float | None:
    """The mean command rate [Hz] an ``analyze --json`` result records (its ``input`` section:
    ``command_samples`` over ``t_first`` .. ``t_last``); None when it does not say.

    Examples
    --------
    >>> command_rate_of_result({"input": {"command_samples": 201, "t_first": 0.0, "t_last": 1.0}})
    200.0
    """
    inp = data.get("input", {})
    if inp.get("command_samples") and inp.get("t_first") is not None and inp.get("t_last") is not None:
        span = float(inp["t_last"]) - float(inp["t_first"])
        return (int(inp["command_samples"]) - 1) / span if span > 0 else None
    return None
