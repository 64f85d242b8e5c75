"""The delay a change added to a loop: two recordings of one plant identified together (``mrft-ident delay``).

A user changes something between two MRFT flights of one vehicle (a filter, a firmware's scheduling, a
delay inserted on purpose) and asks how much delay it added. Analysed apart, each flight's Td trades
against its tau (at Td Omega of 10-60 Td barely moves a relay's frequency), so the difference of two
separate analyses carries both flights' Td-tau trade. Here both flights are one plant: eq. (2) with the
known Tp, **one** Td and **one** K, and **a delay per flight**, fitted to every test's measured
frequency (weighted least squares on log frequency). The delay added is ``tau_after - tau_before``.
A delay may be negative (down to -Tp / 2 or -6 ms, whichever is less: analyze's one rule, mrft.model.lead_floor;
on that bound it is refused naming --tp): a loop that leads eq. (2) without delay, as an estimator's lead
makes it (EKF2's attitude in PX4 SIH leads by 2-3 ms), as ``analyze`` admits alone; a lead both
recordings share cancels in the difference, where a bound at 0 would bend the shared Td instead.

The frequency of a test is eq. (2)'s continuous limit cycle under the beta ``analyze`` identifies it
with (the effective beta, measured at the relay's switches, which holds where a sampled relay actually
switched) and its relay height; tau is then what ``analyze``'s tau is. A recording whose command is
logged below the controller's rate (switch instants known to a logging period only) is taken, as
``analyze`` takes it, at the nominal beta, at the centre of the sampled relay's band of orbits (the
continuous cycle with half a controller tick more delay). K moves no frequency: with Td and the delays fixed,
each test's amplitude gives K, and K is their mean, its standard error their spread over the root of their number
and its interval Student's t on their number less one (Td's and the delays' errors are not in it).

Each test's weight is its mean frequency's standard error from its stable cycles, taken as an AR(1)
sequence (:func:`mrftcli.mrft.sem.mean_sem`), at least the sampled relay's orbit quantisation
(:func:`_frequency_se`: a test locked onto one orbit does not average its offset away).
When the tests scatter about the joint fit more than those errors say (chi^2 above its degrees of
freedom), every test's frequency is given a common model error on top of its own, sized so that chi^2
matches (:func:`_fit_with_scatter`), and the intervals are Student's t on the degrees of freedom: a
plant that is not quite eq. (2) (an estimator's lead, a relay locked off its band's centre) widens the
interval, and no single steady test dominates the fit.

Checked against the simulator flying a known added delay (tests/test_delay_increment.py) and used by
benchmarks/bench_sitl.py for ArduPilot SITL's +20 ms flights (docs/benchmarks/sitl.md).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..analyze.estimate import beta_used
from ..analyze.record import analysis_controller_rate
from ..analyze.screen import group_betas, low_rate_period, prefixed_notes, screen_usable
from ..errors import (IdentificationError, InputError, InsufficientDataError, LogReadError, MrftError,
                      SegmentationError)
from ..io import LogSource, ReadOptions, open_log, read_loop
from ..jsonable import check_schema_version, json_float, json_opt_float
from ..mrft.lprs import lead_cycle, mrft_limit_cycle
from ..mrft.model import K_UNIT, LEAD_CAP_S, LoopModel, lead_floor
from ..mrft.parameter import ParameterEstimate
from ..mrft.sem import mean_sem
from ..progress import Progress
from ..segment import MrftTest, segment
from ..validate import check_tp

__all__ = ["DELAY_SCHEMA_VERSION", "PairTest", "DelayIncrement", "identify_pair", "delay_increment"]

#: Version of the ``delay --json`` record; bump when its layout changes.
DELAY_SCHEMA_VERSION = 3  # 2: warnings, controller_rate_hz, controller_rate_assumed; 3: output_latency_s (1, 2 read)

_FLIGHTS = ("before", "after")
_TAU_MAX = 0.5  # [s]: the delays' upper bound in the fit (eq. (2)'s multirotor range and more)


@dataclass(frozen=True)
class PairTest:
    """One test of either flight, as the joint fit uses it.

    Attributes
    ----------
    flight : {"before", "after"}
        Which recording.
    t_start : float
        Start of the test [s, the log's clock].
    beta, h : float
        The beta the fit uses (the one ``analyze`` identifies the test with) and the relay height [command units].
    rate_hz : float
        The relay's decision rate [Hz]: the controller's when known, else the logged rate.
    n_cycles : int
        Stable cycles.
    frequency_hz, frequency_se_hz : float
        Measured limit-cycle frequency [Hz] and its standard error [Hz] (the fit's weight).
    fitted_hz : float
        The joint model's frequency for the test [Hz].
    amplitude : float
        Measured amplitude [output units].
    K : float
        The K this test's amplitude gives with the joint Td and its flight's delay [``K_UNIT``].
    """

    flight: str
    t_start: float
    beta: float
    h: float
    rate_hz: float
    n_cycles: int
    frequency_hz: float
    frequency_se_hz: float
    fitted_hz: float
    amplitude: float
    K: float

    @property
    def error(self) -> float:
        """fitted / measured - 1 [-]."""
        return self.fitted_hz / self.frequency_hz - 1.0

    def to_json(self) -> dict[str, Any]:
        return {"flight": self.flight, "t_start": self.t_start, "beta": self.beta, "h": self.h,
                "rate_hz": self.rate_hz, "n_cycles": self.n_cycles, "frequency_hz": self.frequency_hz,
                "frequency_se_hz": self.frequency_se_hz, "fitted_hz": self.fitted_hz, "amplitude": self.amplitude,
                "K": self.K}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> PairTest:
        flight = str(data["flight"])
        if flight not in _FLIGHTS:
            raise InputError(f"delay JSON: a test's flight is {flight!r}, not one of {', '.join(_FLIGHTS)}")
        def num(k: str) -> float:
            return json_float(data[k], f"delay JSON test {k}")

        return cls(flight, num("t_start"), num("beta"), num("h"), num("rate_hz"), int(data["n_cycles"]),
                   num("frequency_hz"), num("frequency_se_hz"), num("fitted_hz"), num("amplitude"), num("K"))


@dataclass(frozen=True)
class DelayIncrement:
    """Two recordings of one loop identified together: one Td and K, a delay each (``delay --json``).

    Attributes
    ----------
    before, after : str
        The recordings' paths.
    loop : str
        The loop.
    Tp : float
        The known Tp [s].
    Td, K : ParameterEstimate
        The plant's, shared by both flights [s], [``K_UNIT``].
    tau_before, tau_after : ParameterEstimate
        Each flight's delay [s].
    increment : ParameterEstimate
        ``tau_after - tau_before`` [s]: the delay the change added (negative: removed).
    tests : tuple of PairTest
        Every test used, before's first.
    chi2 : float
        Sum of the squared residuals over the cycles' errors alone, at the final fit's first pass [-].
    dof : int
        Tests less the three fitted parameters.
    model_scatter : float
        The relative error each test's frequency is given beyond its cycles' so that chi2 matches dof (0 when
        the cycles' errors explain the scatter) [-].
    notes : tuple of str
        What qualifies the figures (a delay at its bound, an exactly determined fit, the model's scatter).
    warnings : tuple of str
        Each recording's warnings as ``analyze`` gives them: the reader's (an assumed controller rate), the tests
        left out and why, the tests' own notes (none in a schema 1 record).
    controller_rate_hz : tuple of (float or None)
        Each recording's controller rate [Hz] (before, after): the relay's decision rate, whose half tick is added
        to the delay of a command logged below it (None: unknown, or a schema 1 record).
    controller_rate_assumed : tuple of bool
        Whether the layout assumed that rate (the log did not show it and ``--controller-rate`` was not given).
    output_latency_s : tuple of (float or None)
        How long after its sample each recording's output was published [s] (the median of its topic's
        ``timestamp - timestamp_sample``, PX4's estimates' two stamps; None without them, or a schema 1-2 record):
        a change between the recordings is in the delay added (the reader and the relay go by publication).
    """

    before: str
    after: str
    loop: str
    Tp: float
    Td: ParameterEstimate
    K: ParameterEstimate
    tau_before: ParameterEstimate
    tau_after: ParameterEstimate
    increment: ParameterEstimate
    tests: tuple[PairTest, ...]
    chi2: float
    dof: int
    model_scatter: float
    notes: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    controller_rate_hz: tuple[float | None, float | None] = (None, None)
    controller_rate_assumed: tuple[bool, bool] = (False, False)
    output_latency_s: tuple[float | None, float | None] = (None, None)

    #: What the figures rest on (first line of the text output and the JSON's ``method``).
    METHOD = ("eq. (2) at the known Tp, one Td and K for both recordings and a delay each, fitted to every test's "
              "frequency under the beta analyze identifies it with (weighted by each mean's standard error)")

    def parameters(self) -> dict[str, ParameterEstimate]:
        """The figures by name, in display order."""
        return {"Td": self.Td, "K": self.K, "tau_before": self.tau_before, "tau_after": self.tau_after,
                "delay_added": self.increment}

    def to_json(self) -> dict[str, Any]:
        return {"schema_version": DELAY_SCHEMA_VERSION, "kind": "delay-increment", "before": self.before,
                "after": self.after, "loop": self.loop, "Tp": self.Tp, "method": self.METHOD,
                "parameters": {k: v.to_json() for k, v in self.parameters().items()},
                "tests": [t.to_json() for t in self.tests], "chi2": self.chi2, "dof": self.dof,
                "model_scatter": self.model_scatter, "notes": list(self.notes), "warnings": list(self.warnings),
                "controller_rate_hz": dict(zip(_FLIGHTS, self.controller_rate_hz)),
                "controller_rate_assumed": dict(zip(_FLIGHTS, self.controller_rate_assumed)),
                "output_latency_s": dict(zip(_FLIGHTS, self.output_latency_s))}

    @classmethod
    def from_json(cls, data: Any) -> DelayIncrement:
        """The record of a :meth:`to_json` object.

        Raises
        ------
        InputError
            Not this record, a newer schema, or a missing or malformed field (one line).
        """
        d = check_schema_version(data, "delay", (1, 2, DELAY_SCHEMA_VERSION))
        if d.get("kind") != "delay-increment":  # another record that happens to carry a schema version
            raise InputError(f"delay JSON: kind {d.get('kind')!r} is not a delay increment (mrft-ident delay --json "
                             "writes kind 'delay-increment')")
        try:
            rates = d.get("controller_rate_hz") or {}
            assumed = d.get("controller_rate_assumed") or {}
            latency = d.get("output_latency_s") or {}
            p = d["parameters"]
            est = {k: ParameterEstimate.from_json(k, p[k]) for k in ("Td", "K", "tau_before", "tau_after",
                                                                     "delay_added")}
            return cls(str(d["before"]), str(d["after"]), str(d["loop"]), json_float(d["Tp"], "delay JSON Tp"),
                       est["Td"], est["K"], est["tau_before"], est["tau_after"], est["delay_added"],
                       tuple(PairTest.from_json(t) for t in d["tests"]), json_float(d["chi2"], "delay JSON chi2"),
                       int(d["dof"]), json_float(d["model_scatter"], "delay JSON model_scatter"), tuple(str(n) for n in d["notes"]),
                       tuple(str(w) for w in d.get("warnings", ())),
                       (json_opt_float(rates.get("before"), "delay JSON controller_rate_hz"),
                        json_opt_float(rates.get("after"), "delay JSON controller_rate_hz")),
                       (bool(assumed.get("before", False)), bool(assumed.get("after", False))),
                       (json_opt_float(latency.get("before"), "delay JSON output_latency_s"),
                        json_opt_float(latency.get("after"), "delay JSON output_latency_s")))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"delay JSON: missing or malformed field ({err})") from None


# ----------------------------------------------------------------------------------------------
def _frequency_se(test: MrftTest) -> float:
    """The test's mean frequency's standard error [Hz]: its cycles as an AR(1) sequence (:func:`mean_sem`), and
    at least the sampled relay's orbit quantisation.

    A relay deciding at its controller's rate (:attr:`MrftTest.decision_rate_hz`, not the logger's) switches on ticks, so its
    half period is a whole number N = rate / (2 f) of them: a test that locks onto one of those orbits repeats its frequency cycle after cycle (a tiny
    scatter) while sitting anywhere within half a tick per half period of the continuous cycle, an offset
    its cycles cannot average away: uniform, relative std 1 / (N sqrt(12)), f^2 / (rate sqrt(3)) [Hz]. A
    test hopping among orbits shows that spread in its cycles instead.
    """
    f = test.frequency_hz_mean
    return max(mean_sem(test.frequency_hz), f * f / (test.decision_rate_hz * math.sqrt(3.0)))


@dataclass(frozen=True)
class _Rows:
    flight: np.ndarray  # 0 before, 1 after
    beta: np.ndarray
    hold: np.ndarray  # [s] half the controller's period for a low-rate recording (the band centre), else 0
    h: np.ndarray
    rate: np.ndarray
    f: np.ndarray
    se: np.ndarray
    amp: np.ndarray


def _rows(before: Sequence[MrftTest], after: Sequence[MrftTest]) -> _Rows:
    """Each test's figures; the beta ``analyze`` identifies it with (:func:`mrftcli.analyze.estimate.beta_used`:
    the effective one, measured at the switches, or the nominal one for a recording whose command is logged
    below the controller's rate, which is then taken at the sampled relay's band centre)."""
    tests = [*before, *after]
    ts = [low_rate_period(list(flight)) for flight in (before, after)]
    ts_each = [ts[0]] * len(before) + [ts[1]] * len(after)
    return _Rows(np.array([0] * len(before) + [1] * len(after)),
                 np.array([beta_used(t, s) for t, s in zip(tests, ts_each)]), 0.5 * np.array(ts_each),
                 np.array([t.h for t in tests]),
                 np.array([t.decision_rate_hz for t in tests]), np.array([t.frequency_hz_mean for t in tests]),
                 np.array([_frequency_se(t) for t in tests]), np.array([t.amplitude_mean for t in tests]))


def _cycle(Tp: float, Td: float, tau: float, rows: _Rows, i: int) -> tuple[float, float]:
    """Eq. (2)'s cycle (K = 1) for row ``i``: frequency [Hz], amplitude [output units per unit K]; a negative
    delay (a lead) through :func:`~mrftcli.mrft.lprs.lead_cycle`."""
    delay, beta, h = tau + float(rows.hold[i]), float(rows.beta[i]), float(rows.h[i])
    if delay < 0.0:
        omega, a_unit = lead_cycle(Tp, Td, delay, beta)
        return omega / (2.0 * math.pi), h * Td * a_unit / omega  # Lemmas 2 and 4 at K = 1
    lc = mrft_limit_cycle(LoopModel(Tp, Td, delay, 1.0), beta, h)
    return float(lc.frequency_hz), float(lc.amplitude)


def _fit(Tp: float, rows: _Rows, var: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """[ln Td, tau_before, tau_after], their covariance and the log-frequency residuals, each test's residual
    weighted by ``var`` (its relative variance)."""
    from scipy.optimize import least_squares

    sd = np.sqrt(var)

    def log_misses(p: np.ndarray) -> np.ndarray:
        Td = math.exp(p[0])
        return np.array([math.log(_cycle(Tp, Td, float(p[1 + rows.flight[i]]), rows, i)[0] / rows.f[i])
                         for i in range(rows.f.size)])

    try:
        fit = least_squares(lambda p: log_misses(p) / sd, [math.log(0.5), 0.005, 0.005],
                            bounds=([math.log(0.01), lead_floor(Tp), lead_floor(Tp)],  # analyze's one rule
                                    [math.log(100.0), _TAU_MAX, _TAU_MAX]),
                            x_scale=[0.1, 0.001, 0.001])
    except (InputError, ValueError) as err:
        raise IdentificationError(f"the joint fit of the two recordings failed: {err}") from None
    jac = np.asarray(fit.jac, float)
    try:
        cov = np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        cov = np.full((3, 3), np.inf)
    return np.asarray(fit.x, float), cov, np.asarray(fit.fun, float) * sd


def _model_variance(misses: np.ndarray, var: np.ndarray, dof: int) -> float:
    """The relative variance s^2 a test's frequency has about eq. (2) beyond its cycles' error: the s^2 >= 0 with
    sum(miss^2 / (var + s^2)) = dof (0 when the cycles' errors explain the scatter, or dof is 0)."""
    from scipy.optimize import brentq

    def excess(s2: float) -> float:
        return float(np.sum(misses ** 2 / (var + s2))) - dof

    if dof <= 0 or excess(0.0) <= 0.0:
        return 0.0
    return float(brentq(excess, 0.0, float(np.sum(misses ** 2))))


def _fit_with_scatter(Tp: float, rows: _Rows) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The fit, its covariance, chi^2 with the cycles' errors alone, and the model's relative variance s^2.

    A plant that is not quite eq. (2) (an estimator's lead, a relay locked off its band's centre) scatters
    the tests about any joint fit more than their cycles say; weighted by the cycles alone the fit would
    then lean on the steadiest tests and state an interval that ignores the misfit. So each test's
    variance is its own plus a common s^2 found so that chi^2 equals its degrees of freedom (a random
    effect, as a meta-analysis treats studies that disagree), refitted until s^2 settles.
    """
    var0 = (rows.se / rows.f) ** 2
    dof = rows.f.size - 3
    s2 = 0.0
    x, cov, misses = _fit(Tp, rows, var0)
    chi2 = float(np.sum(misses ** 2 / var0))
    for _ in range(6):
        new = _model_variance(misses, var0, dof)
        if abs(new - s2) <= 0.02 * max(new, 1e-12):
            break
        s2 = new
        x, cov, misses = _fit(Tp, rows, var0 + s2)
    return x, cov, chi2, s2


def _estimate(value: float, std: float, q: float, unit: str, *, log: bool = False) -> ParameterEstimate:
    determined = math.isfinite(std)
    if log:  # Td: its interval on the log scale of the fit (std from the delta method)
        return ParameterEstimate(value, value * std, value * math.exp(-q * std), value * math.exp(q * std), unit,
                                 determined)
    return ParameterEstimate(value, std, value - q * std, value + q * std, unit, determined)


def identify_pair(before: Sequence[MrftTest], after: Sequence[MrftTest], Tp: float, *,
                  names: tuple[str, str] = ("before", "after"), loop: str = "") -> DelayIncrement:
    """Identify two flights of one plant together: one Td and K, a delay each (module docstring).

    Parameters
    ----------
    before, after : sequence of MrftTest
        The usable tests of each recording (at least one each; together two betas in one recording).
    Tp : float
        The known Tp [s].
    names : tuple of str
        The recordings' names (paths) for the record.
    loop : str
        The loop's name for the record.

    Returns
    -------
    DelayIncrement

    Raises
    ------
    InsufficientDataError
        A recording without a test, or neither with two betas (Td is then not determined).
    IdentificationError
        The fit fails.
    """
    Tp = check_tp(Tp)
    for tests, name in zip((before, after), names):
        if not tests:
            raise InsufficientDataError(f"{name}: no usable MRFT test; the delay needs at least one test in each "
                                        "recording")
    if max(len(group_betas(list(before))), len(group_betas(list(after)))) < 2:
        raise InsufficientDataError(
            "neither recording has two betas: Td (shared by both) needs two tests with different betas in one "
            "of them (e.g. -0.4 and -0.7)")
    rows = _rows(before, after)
    x, cov, chi2, s2 = _fit_with_scatter(Tp, rows)
    dof = rows.f.size - 3
    q = _quantile(dof if s2 > 0.0 else 0)
    Td, tau_b, tau_a = math.exp(x[0]), float(x[1]), float(x[2])
    std = np.sqrt(np.clip(np.diag(cov), 0.0, np.inf))
    with np.errstate(invalid="ignore"):  # a singular fit's infinite covariance: refused below, no numpy warning
        inc_var = float(cov[1, 1] + cov[2, 2] - 2 * cov[1, 2])
    cycles = [_cycle(Tp, Td, (tau_b, tau_a)[rows.flight[i]], rows, i) for i in range(rows.f.size)]
    if not math.isfinite(inc_var):
        worst = max(abs(c[0] / f - 1.0) for c, f in zip(cycles, rows.f))
        raise IdentificationError(
            f"the joint fit does not determine the delay added (Td {Td:.3g} s, tau before {tau_b * 1e3:.3g} ms, after "
            f"{tau_a * 1e3:.3g} ms, none bounded; its tests off the fit by up to {worst * 100:.0f} %): check Tp "
            f"({Tp:g} s given) and that both recordings are of one loop")
    for name, tau in (("before", tau_b), ("after", tau_a)):
        if tau <= lead_floor(Tp) + 1e-6:  # the fit wants more lead than eq. (2) admits: analyze's one rule refuses
            worst = max(abs(c[0] / f - 1.0) for c, f in zip(cycles, rows.f))
            raise IdentificationError(
                f"the {name} recording's loop leads eq. (2) by more than the {-lead_floor(Tp) * 1e3:.3g} ms it admits "
                f"(an estimator's lead is a few ms: at most {LEAD_CAP_S * 1e3:g} ms or Tp/2; its delay sits on that "
                f"bound, tests off the fit by up to {worst * 100:.0f} %): a Tp given too large reads as a lead; check "
                f"--tp ({Tp:g} s given)")
    inc_std = math.sqrt(max(inc_var, 0.0))
    K_each = rows.amp / np.array([a for _, a in cycles])
    # K's error is its tests' spread alone (no frequency moves it): its interval is Student's t on their number less 1
    K_std = float(np.std(K_each, ddof=1) / math.sqrt(K_each.size)) if K_each.size > 1 else math.nan
    q_K = _quantile(K_each.size - 1) if K_each.size > 1 else q
    pairs = tuple(PairTest(_FLIGHTS[rows.flight[i]], t.t_start, float(rows.beta[i]), float(rows.h[i]),
                           float(rows.rate[i]), t.n_stable, float(rows.f[i]), float(rows.se[i]), cycles[i][0],
                           float(rows.amp[i]), float(K_each[i]))
                  for i, t in enumerate([*before, *after]))
    return DelayIncrement(
        names[0], names[1], loop, Tp, _estimate(Td, float(std[0]), q, "s", log=True),
        _estimate(float(np.mean(K_each)), K_std, q_K, K_UNIT), _estimate(tau_b, float(std[1]), q, "s"),
        _estimate(tau_a, float(std[2]), q, "s"), _estimate(tau_a - tau_b, inc_std, q, "s"),
        pairs, chi2, dof, math.sqrt(s2),
        _notes(Tp, ((tau_b, float(std[1])), (tau_a, float(std[2]))), dof, chi2, math.sqrt(s2)))


def _quantile(dof: int) -> float:
    """The two-sided 95 % quantile: normal, or Student's t on ``dof`` when the model's scatter was estimated."""
    from scipy.stats import norm, t

    return float(t.ppf(0.975, dof)) if dof > 0 else float(norm.ppf(0.975))


def _notes(Tp: float, taus: tuple[tuple[float, float], tuple[float, float]], dof: int, chi2: float,
           scatter: float) -> tuple[str, ...]:
    """What qualifies the figures; ``taus``: (value, std) [s] of the before and after recordings' delays."""
    notes = []
    for name, tau, std in (("before", *taus[0]), ("after", *taus[1])):
        if tau < -1e-5:  # a lead within lead_floor (one on its bound is refused)
            notes.append(f"the {name} recording's delay is negative ({tau * 1e3:.3g} ± {std * 1e3:.2g} ms): its loop "
                         "has less lag than eq. (2) with no delay (an estimator's lead?), as analyze states "
                         "alone; a lead both recordings share cancels in the delay added")
    if dof == 0:
        notes.append("three tests for three parameters: the fit is exact, and the interval is the tests' own "
                     "scatter only (a fourth test would check the joint model)")
    elif scatter > 0.0:
        notes.append(f"the tests scatter about the joint model more than their cycles say (chi^2 {chi2:.3g} on {dof} "
                     f"degrees of freedom): each test's frequency is given a further {scatter * 100:.2g} % of error (the "
                     "model's scatter) and the intervals are Student's t")
    return tuple(notes)


@dataclass(frozen=True)
class _Recording:
    """One recording's usable tests, its warnings, its controller's rate and its output's publication latency."""

    tests: list[MrftTest]
    warnings: tuple[str, ...]
    controller_rate_hz: float | None
    rate_assumed: bool
    output_latency_s: float | None = None


def _usable(path: str | Path, read: ReadOptions, min_stable_cycles: int) -> _Recording:
    """The tests of one recording that ``analyze`` would use (its screening, :func:`screen_tests`), with the
    warnings ``analyze`` gives it (the reader's, the tests left out and why, the tests' own notes) and the
    controller's rate (and whether the layout assumed it: then it sets the half tick added to the delay)."""
    with open_log(path, read.fmt, echo_warnings=False, time_unit=read.time_unit) as src:
        flight = dataclasses.replace(read_loop(src, read, loop_hint=True), path=str(path))  # as read_flight
        latency = _output_latency(src, flight.source)  # from the same open log
    found = segment(flight, controller_rate_hz=read.controller_rate_hz)
    try:
        usable, _, _, t0, left_out = screen_usable(flight, found, min_stable_cycles)
    except SegmentationError as err:
        err.warnings = tuple(flight.warnings)  # the reader's (an assumed rate): shown above the error
        raise
    notes = prefixed_notes(usable, t0)
    rate = read.controller_rate_hz or analysis_controller_rate(flight.timing.controller_rate_hz,
                                                               [t.rate_hz for t in usable])
    assumed = flight.timing.controller_rate_assumed  # never with --controller-rate (io.flight.read_loop)
    warnings = tuple(dict.fromkeys([*flight.warnings, *(f"{flight.path}: {w}" for w in [*left_out, *notes])]))
    return _Recording(usable, warnings, rate, assumed, latency)


def _output_latency(src: LogSource, source: Mapping[str, Any]) -> float | None:
    """The median of the output topic's ``timestamp - timestamp_sample`` [s] in the open log ``src`` (PX4's
    estimates carry both, in us: how long after the IMU sample the estimate was published); None for a log that
    is not a ULog (the two stamps are PX4's there) or a topic without the two fields."""
    topic = str(source.get("output", "")).split(":", 1)[0]
    if not topic or source.get("format") != "ulog":
        return None
    try:
        _, data = src.read(topic, ["timestamp", "timestamp_sample"])
    except (LogReadError, KeyError):  # the topic has no timestamp_sample
        return None
    lag = (np.asarray(data["timestamp"], float) - np.asarray(data["timestamp_sample"], float)) * 1e-6
    lag = lag[np.isfinite(lag)]
    return float(np.median(lag)) if lag.size and 0.0 <= float(np.median(lag)) < 1.0 else None


def delay_increment(before: str | Path, after: str | Path, Tp: float, *, read: ReadOptions | None = None,
                    min_stable_cycles: int = 3, progress: Progress | None = None) -> DelayIncrement:
    """The delay the change between two recordings of one loop added (:func:`identify_pair` on their tests).

    Parameters
    ----------
    before, after : str or Path
        The two recordings (any log format ``analyze`` reads); both read with ``read``.
    Tp : float
        The known Tp [s].
    read : ReadOptions, optional
        How to read the loop (the loop, topics, layout, rate); default: altitude, the layout recognised.
    min_stable_cycles : int
        Fewest stable cycles for a test to be used (``analyze``'s rule).
    progress : Progress, optional
        Called as ``progress(done, 3, stage)`` after each recording is read and after the fit.

    Raises
    ------
    LogReadError, SegmentationError, InsufficientDataError, IdentificationError
        One line each, naming the recording; its ``warnings`` those of the recordings read before it.
    """
    read = read or ReadOptions()
    tests: list[_Recording] = []
    try:
        for k, path in enumerate((before, after)):
            if progress:
                progress(k, 3, f"reading {Path(path).name}")
            tests.append(_usable(path, read, min_stable_cycles))
        if progress:
            progress(2, 3, "fitting")
        result = identify_pair(tests[0].tests, tests[1].tests, Tp, names=(str(before), str(after)), loop=read.loop)
    except MrftError as err:  # what was warned of before it (each recording read), for the CLI to show first
        err.warnings = (*(w for r in tests for w in r.warnings), *err.warnings)
        raise
    if progress:
        progress(3, 3, "done")
    latency = (tests[0].output_latency_s, tests[1].output_latency_s)
    return dataclasses.replace(
        result, warnings=(*tests[0].warnings, *tests[1].warnings),
        controller_rate_hz=(tests[0].controller_rate_hz, tests[1].controller_rate_hz),
        controller_rate_assumed=(tests[0].rate_assumed, tests[1].rate_assumed), output_latency_s=latency,
        notes=(*result.notes, *_latency_note(latency, result.increment)))


def _latency_note(latency: tuple[float | None, float | None], added: ParameterEstimate) -> tuple[str, ...]:
    """A note when the output's publication latency differs between the recordings (by 0.1 ms or more): that
    part of the delay added (read from the stamps, not fitted) and the rest, with the delay added's std."""
    before, after = latency
    if before is None or after is None or abs(after - before) < 1e-4:
        return ()
    moved = after - before
    return (f"the output was published {before * 1e3:.3g} ms after its sample in the before recording and "
            f"{after * 1e3:.3g} ms in the after one (its topic's timestamp - timestamp_sample): {moved * 1e3:+.3g} ms of "
            "the delay added is that publication latency (the estimator's scheduling, e.g. PX4's EKF2), part of the "
            "loop's change (tune for the whole delay added); the rest, a delay inserted elsewhere (e.g. in the "
            f"firmware's command path), is {(added.value - moved) * 1e3:.3g} ms ± {added.std * 1e3:.3g} ms (the "
            "delay added's std; the latency is read, not fitted)",)
