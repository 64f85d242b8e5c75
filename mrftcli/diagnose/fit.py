"""The models diagnose fits to the recorded cycles: per-test data, the candidate models' limit cycles,
and the least-squares fits (used by :mod:`mrftcli.diagnose.selection`).

* :func:`prepare_tests` turns the segmenter's MRFT tests into :class:`DiagnosedTest`: the stable cycles
  measured by :func:`mrftcli.diagnose.features.cycle_table`, split into a fitting (even) and a
  held-out (odd) half, plus the sample behind the period-scatter statistic.
* :class:`CandidateModel` evaluates the linear model with zero, one or two candidate effects at the
  tests' MRFT settings (the exact limit cycle of :mod:`mrftcli.diagnose.limit_cycles`) and returns the same
  features as the recording's (:class:`PredictedCycle`).
* :func:`fit_model` fits a model's parameters to the features (residuals in units of the
  recording's standard errors, K in closed form); :func:`fit_base` starts the linear model along the
  Td-tau valley; :func:`candidate_starts` gives each candidate its starting points.

Units: times in seconds, the output in its own units (m or rad), the command in command units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Callable

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from .features import FEATURE_NAMES, N_HARM, CycleTable, cycle_features, cycle_table, relay_harmonics
from .physics import Effect, df_quadratic_drag
from .scatter import scatter_sample
from .limit_cycles import AugmentedPlant, quasi_static_plant
from .periodic import CyclePlant, PeriodicSolution, cycle_at_period, periodic_solution
from ..io.logtypes import FlightLog
from ..segment import MrftTest, segment

if TYPE_CHECKING:
    from ..analyze import AnalysisResult

__all__ = ["MIN_CYCLES", "FEATURE_FLOOR", "PERIOD_RTOL", "DiagnosedTest", "segments_of", "prepare_tests", "PredictedCycle",
           "CandidateModel", "cycle_plant", "model_cycle", "feature_mask", "feature_sigma", "Fit", "residuals", "fit_model", "initial_base", "tau_on_valley",
           "bound_reason", "TD_RANGE_S", "fit_base", "theta_bounds", "candidate_starts", "plant_params", "param_std", "effect_value"]

#: the fits' relative finite-difference step (least_squares' diff_step)
_STEP = 1e-3
_EPS_STEP = float(np.sqrt(np.finfo(float).eps))  # its step where the relative one vanishes (theta = 0)
#: fewest stable cycles per test for a diagnosis
MIN_CYCLES = 4
#: the period's relative tolerance of each limit cycle: the features' floors are 1e-3 and a Jacobian
#: column's cycle (one Newton step) is 1e-6 off, so 1e-8 is ample; 1e-10 took one series evaluation
#: more per cycle (of four or five; issue 39)
PERIOD_RTOL = 1e-8
#: the relative step in the period of a Jacobian column's feature derivative (:meth:`CandidateModel._column`)
_PERIOD_STEP = 1e-6
#: a limit cycle is started from the last one found only when that was found within this distance of
#: theta (largest component; theta's entries are O(1)): the steps inside one fit
WARM_RADIUS = 0.1


# Floors added (in quadrature) to each feature's standard error: the continuous-relay model of a
# sampled, noisy relay (``diagnose_sim``) is not exact to better than about this.
FEATURE_FLOOR = {
    "period": 1.5e-3,  # relative
    "balance": 1.5e-3,
    "log_amplitude": 4e-3,
    "centre": 8e-3,
    "h3_re": 1.5e-3,
    "h3_im": 1.5e-3,
    "h5_re": 1e-3,
    "h5_im": 1e-3,
    "h2_re": 1.5e-3,
    "h2_im": 1.5e-3,
    "amplitude_trend": 2e-4,  # 1/s
    "balance_trend": 1e-4,  # 1/s
}


@dataclass
class DiagnosedTest:
    """One MRFT test as the diagnosis sees it: its settings, its stable cycles and their split.

    Built by :func:`prepare_tests` from the segmenter's :class:`~mrftcli.segment.MrftTest` (the
    test as found in the log); not to be confused with the simulator's
    :class:`~mrftcli.sim.flight.TestSpec` (a test to fly) or identify's ``TestMeasurement``.

    ``beta`` is the effective switching level per direction (up, down); ``tab`` the measured stable
    cycles; ``fit`` / ``hold`` boolean masks over them (even / odd cycles); ``bias`` the hover
    command [command units]; times in log seconds.
    """

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
    #: periods [s] of the cycles behind the scatter statistic (``diagnose_scatter.scatter_sample``)
    scatter_periods: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: regular cycles the segmenter found in the test (the window the scatter model reproduces)
    n_window: int = 0
    #: the relay centre of the flight's earliest test flown, diagnosed or not [command units] (the hover
    #: command a gain drift's trim error is taken against; None: the earliest of the tests given)
    first_centre: float | None = None

    def scatter_var(self, sel: str) -> tuple[float, int]:
        """Sample variance [s^2] of the scatter periods ('fit': even, 'hold': odd, else all) and their count."""
        p = self.scatter_periods
        if sel in ("fit", "hold"):
            p = p[(np.arange(p.size) % 2 == 0) == (sel == "fit")]
        return (float(np.var(p, ddof=1)) if p.size >= 3 else float("nan")), int(p.size)


def segments_of(flight: FlightLog, analysis: AnalysisResult | None) -> list[MrftTest]:
    """The MRFT tests to diagnose: the analysis' tests when it used any (its segmentation is
    reused), else :func:`mrftcli.segment.segment` of ``flight``."""
    if analysis is not None and analysis.tests:
        return list(analysis.tests)
    return list(segment(flight))


def prepare_tests(flight: FlightLog, segs: list[MrftTest]) -> tuple[list[DiagnosedTest], float, list[str]]:
    """The tests with at least :data:`MIN_CYCLES` stable cycles as :class:`DiagnosedTest`, the sensor
    noise std estimated from the cycle projections' residual [output units], and warnings."""
    warnings: list[str] = []
    t_y, y = flight.output.t, flight.output.values
    ok = np.isfinite(t_y) & np.isfinite(y)
    t_y, y = t_y[ok], y[ok]
    t0_log = float(min(np.nanmin(flight.command.t), np.nanmin(flight.output.t)))
    tests: list[DiagnosedTest] = []
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
        tab, sparse = tab.subset(good), int(np.sum(tab.n_samples < 2 * N_HARM + 4))
        if len(tab) < MIN_CYCLES:  # a cycle with fewer output samples than the harmonic fit's unknowns is not measured
            warnings.append(
                f"test {s.index + 1} (beta {s.beta:.2f}): {len(tab)} of its {len(st)} stable cycles can be measured "
                f"({sparse} have fewer than the {2 * N_HARM + 4} output samples a cycle the waveform fit needs"
                + ("; log the output faster" if sparse else "") + f"); the diagnosis needs {MIN_CYCLES}, so it is left out"
            )
            continue
        idx = np.arange(len(tab))
        b_up = float(np.nanmedian(tab.beta_up))
        b_dn = float(np.nanmedian(tab.beta_dn))
        if not (-1 < b_up < 1 and -1 < b_dn < 1):
            b_up = b_dn = float(s.beta)
        rss += float(tab.resid_ss.sum())
        nsamp += int(tab.n_samples.sum()) - len(tab) * (2 * N_HARM + 2)
        P_all = np.array([c.period for c in s.cycles], float)
        A_all = np.array([c.amplitude for c in s.cycles], float)
        reg_all = np.array([c.regular for c in s.cycles], bool)
        keep = scatter_sample(P_all, A_all, reg_all, 1.0 / float(s.rate_hz))
        tests.append(
            DiagnosedTest(
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
                scatter_periods=P_all[keep],
                n_window=int(reg_all.sum()),
            )
        )
    noise = math.sqrt(rss / nsamp) if nsamp > 0 else 0.0
    return tests, noise, warnings


@dataclass
class PredictedCycle:
    """A :class:`CandidateModel`'s limit cycle for one test (at K = 1 unless noted)."""

    features: np.ndarray  # FEATURE_NAMES order, log amplitude at K = 1
    solution: PeriodicSolution  # the cycle's series, K = 1
    h: float  # the relay's height [command units]
    gain: float  # battery gain g at the test's reference time (1 unless gain drift)

    @property
    def cycle(self) -> CycleTable:
        """The model's periodic cycle as a one-row table (K = 1): built when asked for (the fits read
        only the features; issue 39)."""
        return model_cycle(self.solution, self.h)


class CandidateModel:
    """Evaluates the limit cycles of the linear model with zero, one or several candidate effects
    for every test, with warm starts (each evaluation simulates an
    :class:`~mrftcli.diagnose.limit_cycles.AugmentedPlant`; the identified linear model alone is
    :class:`~mrftcli.mrft.model.LoopModel`).

    theta layout: [ln Td (ln q with quadratic drag, whose q replaces 1/Td), 10 tau, then one scaled
    parameter per other deterministic effect, in the order given].
    """

    def __init__(self, cand: Effect | tuple | None, tests: list[DiagnosedTest], Tp: float) -> None:
        cands = () if cand is None else (tuple(cand) if isinstance(cand, (tuple, list)) else (cand,))
        self.cands = tuple(c for c in cands if not c.stochastic)
        self.cand = cands[0] if cands else None
        self.names = tuple(c.name for c in self.cands)
        self.tests = tests
        self.Tp = Tp
        # last (theta, (period [s], residual slope, nonlinear fixed point)) found, per evaluation key
        self.warm: dict[int, tuple[np.ndarray, tuple]] = {}
        # the same, per test, whatever the key: the start of a key's first cycle near a point solved under
        # another (a held-out score or a refit at a fit's own point; issue 39)
        self._by_test: dict[int, tuple[np.ndarray, tuple]] = {}
        # per test, the features' derivative in the period at the last point a Jacobian stepped from
        self._slopes: dict[int, tuple[tuple, np.ndarray]] = {}
        # every cycle solved, by (test, reference time, theta): the fits, their starts' scores, the
        # held-out scores and the refits ask for the same points again (a fifth of the evaluations of a
        # diagnosis; issue 39), and a point evaluated twice is one cycle, not two warm-started ones
        self._solved: dict[tuple, tuple[PredictedCycle | None, tuple | None]] = {}
        self.name = "+".join(c.name for c in cands) if cands else "base"
        self.hs = float(np.mean([t.h for t in tests]))
        self.bias_mean = float(np.mean([t.bias for t in tests]))
        # the hover command at the log's start under a gain drift: the first test's relay centre (a relay
        # centred on the trim of its own start, as a hold hands over, or on one fixed trim: then every test's),
        # of the tests flown (screen.flown, as trim_spread takes them) when the screen says
        given = [c for c in (getattr(t, "first_centre", None) for t in tests) if c is not None]
        self.bias_first = (float(given[0]) if given else
                           float(min(tests, key=lambda t: t.t_start).bias) if tests else 0.0)

    def extra_index(self, name: str) -> int | None:
        """Index in theta of the effect's own parameter (None for quadratic drag, which uses theta[0])."""
        j = 2
        for c in self.cands:
            if c.replaces_drag:
                if c.name == name:
                    return None
                continue
            if c.name == name:
                return j
            j += 1
        raise KeyError(name)

    def unpack(self, theta: np.ndarray) -> dict:
        """Physical parameters: Td [s], tau [s], ``extras`` {effect: value}, ``extra`` the first one's."""
        p = {"Td": math.exp(theta[0]), "tau": theta[1] / 10.0, "extra": None, "extras": {}}
        hs = self.hs
        for c in self.cands:
            j = self.extra_index(c.name)
            x = theta[j] if j is not None and j < len(theta) else None
            if c.name == "quadratic_drag":
                p["q"] = math.exp(theta[0])
                p["Td"] = None
                continue
            if x is None:
                continue
            value = {"input_bias": x * hs, "gain_drift": x / 100.0, "sensor_lag": x / 10.0,
                     "actuator_rate_limit": x / (10.0 * hs),  # rate limit: rho = 1/R [s per unit]
                     "asymmetric_gain": x / 10.0,
                     "actuator_saturation": x * hs,  # headroom above the mean trim [command units]
                     "dead_zone": x * hs / 10.0,
                     "thrust_rectification": x / (10.0 * hs),  # 1/F [1/command unit]
                     }[c.name]
            p["extras"][c.name] = value
        if self.cand is not None and self.cand.name in p["extras"]:
            p["extra"] = p["extras"][self.cand.name]
        return p

    def _solve(self, cp: CyclePlant, test_i: int, k: int, theta: np.ndarray) -> PeriodicSolution | None:
        """:meth:`evaluate`'s periodic solution (``k``: the key of its warm start)."""
        test = self.tests[test_i]
        # the recorded period, with the slope of the switching residual of the test's last cycle as the
        # first step's (the slope changes slowly with theta; one series evaluation fewer of five)
        last = self._by_test.get(test_i)
        cold = (float(np.mean(test.tab.period)), None if last is None else last[1][1], None)
        # the last period found is the start when it was found close by (inside a fit); from a distant
        # theta it can lead the solver to another periodic solution of the relay's switching equations
        # (a pair fit's nested start once scored chi^2 9e4 instead of its 2e3), so the recorded period
        # is the start there, and the fallback when the close one fails
        guesses = [cold]
        near = self._near(test_i, k, theta)
        if near is not None:
            guesses.insert(0, near[1])
        for guess in guesses:
            sol = _periodic(cp, test, guess)
            if sol is not None:
                self.warm[k] = self._by_test[test_i] = (np.array(theta, float), (sol.period, sol.slope or None,
                                                                                  sol.state))
                return sol
        return None

    def plant(self, p: dict, test: DiagnosedTest, t_ref: float) -> tuple[AugmentedPlant, float]:
        """The augmented plant (K = 1) for a test at reference time t_ref [s, log time]; returns (plant, gain)."""
        ex = p["extras"]
        rho = ex.get("actuator_rate_limit", 0.0)
        inv_f = ex.get("thrust_rectification", 0.0)
        kw = {
            "input_bias": ex.get("input_bias", 0.0),
            "sensor_lag": max(ex["sensor_lag"], 1e-4) if "sensor_lag" in ex else 0.0,
            "rate_limit": (1.0 / rho) if rho > 1e-9 else 0.0,
            "asymmetric_gain": ex.get("asymmetric_gain", 0.0),
            # the saturation's parameter is the absolute limit: the headroom is the limit above this test's trim
            "headroom": (max(self.bias_mean + ex["actuator_saturation"] - test.bias, 1e-6)
                         if "actuator_saturation" in ex else 0.0),
            "dead_zone": ex.get("dead_zone", 0.0),
            "hover_thrust": (1.0 / inv_f) if inv_f > 1e-9 else 0.0,
        }
        if "quadratic_drag" in self.names:
            plant = AugmentedPlant(self.Tp, 1.0, p["tau"], 1.0, quadratic_drag=p["q"], **kw)
        else:
            plant = AugmentedPlant(self.Tp, p["Td"], p["tau"], 1.0, **kw)
        if "gain_drift" in ex:
            g = max(1.0 + ex["gain_drift"] * (t_ref - test.t0_log), 0.05)
            # g (b + u) - b0 + d: the hover command b0 is the flight's, so a test whose relay a hold re-centred
            # on the drifted trim (b = b0 / g(start)) starts trimmed and drifts off within it (issue 39: the
            # test's own b taken as b0 put every later test off trim by (g - 1) b / g)
            plant = replace(plant, input_bias=plant.input_bias + test.bias - self.bias_first)
            return quasi_static_plant(plant, g, test.bias), g
        return plant, 1.0

    def evaluate(self, theta: np.ndarray, test_i: int, t_ref: float, *, key: int | None = None,
                 newton: bool = False) -> PredictedCycle | None:
        """The model's periodic cycle for test ``test_i`` at log time ``t_ref`` [s] (K = 1), or None.

        The cycle is the exact periodic solution of :func:`mrftcli.diagnose.periodic.periodic_solution`
        (its Fourier series), started from the last period found for ``key`` (default: the test).
        ``newton``: a finite-difference Jacobian's column (:func:`fit_model`): the cycle at the period of
        the last one solved close by, moved by one Newton step on the period (:meth:`_column`).
        """
        # (the cycle depends on the reference time only through a gain drift, on the key not at all)
        when = float(t_ref) if "gain_drift" in self.names else None
        memo = None if newton else (test_i, when, np.asarray(theta, float).tobytes())
        k = test_i if key is None else key
        if memo is not None and memo in self._solved:
            got, start = self._solved[memo]
            if start is not None:  # the last point evaluated is the next one's start, as when solved
                self.warm[k] = self._by_test[test_i] = start
            return got
        before = self.warm.get(k)
        got = self._evaluate(theta, test_i, t_ref, k, newton)
        if memo is not None:
            after = self.warm.get(k)
            self._solved[memo] = (got, after if after is not before else None)
        return got

    def _evaluate(self, theta: np.ndarray, test_i: int, t_ref: float, k: int,
                  newton: bool) -> PredictedCycle | None:
        """:meth:`evaluate` of a point not solved before (or a Newton column, which depends on its start;
        ``k``: the key of the warm start)."""
        test = self.tests[test_i]
        p = self.unpack(theta)
        plant, g = self.plant(p, test, t_ref)
        cp = cycle_plant(plant, test.h)
        if newton:
            col = self._column(cp, theta, test_i, t_ref, k, p, g)
            if col is not None:
                return col
        sol = self._solve(cp, test_i, k, theta)
        return None if sol is None else self._predicted(sol, test, p, g)

    def _near(self, test_i: int, k: int, theta: np.ndarray) -> tuple[np.ndarray, tuple] | None:
        """The last cycle solved for key ``k`` (or else for the test) when it was solved close to ``theta``."""
        return next((w for w in (self.warm.get(k), self._by_test.get(test_i))
                     if w is not None and np.max(np.abs(w[0] - theta)) <= WARM_RADIUS), None)

    def _column(self, cp: CyclePlant, theta: np.ndarray, test_i: int, t_ref: float, k: int, p: dict,
                g: float) -> PredictedCycle | None:
        """A finite-difference Jacobian's column: the cycle of ``theta`` at the period P0 of the point it
        steps from (solved just before, the start of key ``k``) and the period's Newton step dP = -f / f'
        (f the switching residual there, f' its slope at P0), its features moved by dP times their
        derivative in the period at that point. The error is of the order of the square of the step, as
        a cycle solved at P0 + dP was (its period's error), at one series evaluation instead of two per
        column and one per point (issue 39). None when no close point was solved with a slope."""
        near = self._near(test_i, k, theta)
        if near is None or not near[1][1]:
            return None
        P0, slope, state = near[1]
        test = self.tests[test_i]
        got = _at_period(cp, test, P0, state)
        if got is None:
            return None
        dP = -got[0] / slope
        if not -0.5 * P0 < dP < P0:  # (the Newton step's bounds of periodic_solution)
            return None
        col = self._predicted(got[1], test, p, g)
        slope_f = self._feature_slope(test_i, t_ref, near)
        if col is None or slope_f is None:
            return None
        return PredictedCycle(features=col.features + slope_f * dP, solution=col.solution, h=col.h, gain=g)

    def _feature_slope(self, test_i: int, t_ref: float, near: tuple[np.ndarray, tuple]) -> np.ndarray | None:
        """d(features)/d(period) [1/s] of the cycle solved at ``near`` (its theta and period), at fixed theta:
        one cycle a millionth of the period away; kept for the next columns of the same point."""
        theta, (P0, _, state) = near
        when = float(t_ref) if "gain_drift" in self.names else None
        key = (test_i, when, theta.tobytes())
        if test_i not in self._slopes or self._slopes[test_i][0] != key:
            test = self.tests[test_i]
            p = self.unpack(theta)
            plant, g = self.plant(p, test, t_ref)
            cp = cycle_plant(plant, test.h)
            here = self._solved.get(key, (None, None))[0]  # the point's own cycle, when it was solved here
            if here is None or here.features[0] != P0:
                got = _at_period(cp, test, P0, state)
                here = None if got is None else self._predicted(got[1], test, p, g)
            got = _at_period(cp, test, P0 * (1.0 + _PERIOD_STEP), state)
            there = None if got is None else self._predicted(got[1], test, p, g)
            if here is None or there is None:
                return None
            self._slopes[test_i] = (key, (there.features - here.features) / (P0 * _PERIOD_STEP))
        return self._slopes[test_i][1]

    def _predicted(self, sol: PeriodicSolution, test: DiagnosedTest, p: dict, g: float) -> PredictedCycle | None:
        """The features of a cycle (None when its amplitude is not positive)."""
        amplitude, centre = _extent(sol)
        if not np.isfinite(amplitude) or amplitude <= 0:
            return None
        f = cycle_features(sol.period, sol.high / sol.period - 0.5, amplitude, centre, sol.Y)
        f[np.isnan(f)] = 0.0
        # analytic trends of the quasi-static gain drift
        if "gain_drift" in p["extras"]:
            gd = p["extras"]["gain_drift"]
            f[FEATURE_NAMES.index("amplitude_trend")] = gd / g
            # balance D = -d_eff / (2 h), d_eff = ((g - 1) b) / g  ->  dD/dt = -b gd / (2 h g^2)
            f[FEATURE_NAMES.index("balance_trend")] = -test.bias * gd / (2.0 * test.h * g * g)
        else:
            f[FEATURE_NAMES.index("amplitude_trend")] = 0.0
            f[FEATURE_NAMES.index("balance_trend")] = 0.0
        return PredictedCycle(features=f, solution=sol, h=test.h, gain=g)


def cycle_plant(plant: AugmentedPlant, h: float) -> CyclePlant:
    """The periodic solver's view of an :class:`AugmentedPlant` under a relay of height ``h``."""
    # the static command nonlinearities act on the relay's two levels (command_shaper's order)
    up, dn = max(h - plant.dead_zone, 0.0), -max(h - plant.dead_zone, 0.0)
    up, dn = up * (1.0 + plant.asymmetric_gain), dn * (1.0 - plant.asymmetric_gain)
    if plant.headroom > 0:
        up = min(up, plant.headroom)
    return CyclePlant(Tp=plant.Tp, Td=plant.Td, tau=plant.tau, K=plant.K, level_high=up + plant.input_bias,
                      level_low=dn + plant.input_bias, rate_limit=plant.rate_limit, sensor_lag=plant.sensor_lag,
                      quadratic_drag=plant.quadratic_drag, hover_thrust=plant.hover_thrust)


def _at_period(cp: CyclePlant, test: DiagnosedTest, P: float, state: tuple | None
               ) -> tuple[float, PeriodicSolution] | None:
    """:func:`~mrftcli.diagnose.periodic.cycle_at_period` at the test's effective betas, or None (none, or
    not finite)."""
    with np.errstate(all="ignore"):
        try:
            got = cycle_at_period(cp, P, test.beta[0], test.beta[1], state)
        except (FloatingPointError, ValueError, OverflowError, ZeroDivisionError):
            return None
    return got if got is not None and math.isfinite(got[0]) and np.all(np.isfinite(got[1].Y)) else None


def _periodic(cp: CyclePlant, test: DiagnosedTest, guess: tuple) -> PeriodicSolution | None:
    """:func:`~mrftcli.diagnose.periodic.periodic_solution` of ``cp`` at the test's effective betas from
    ``guess`` (period [s], slope, fixed point), or None (none found, or not finite)."""
    period, slope, state = guess
    with np.errstate(all="ignore"):
        try:
            sol = periodic_solution(cp, test.beta[0], test.beta[1], period, rtol=PERIOD_RTOL, slope_guess=slope,
                                    state_guess=state)
        except (FloatingPointError, ValueError, OverflowError, ZeroDivisionError):
            return None
    return sol if sol is not None and np.all(np.isfinite(sol.Y)) else None


def model_cycle(sol: PeriodicSolution, h: float) -> CycleTable:
    """A periodic solution as a one-row :class:`CycleTable` (measured like a recorded cycle: the
    amplitude and centre of its harmonics 1..N_HARM)."""
    P, H = sol.period, sol.high
    Y = sol.Y[: N_HARM + 1].copy()
    amplitude, centre = _extent(sol)
    one = lambda v: np.array([v], float)  # noqa: E731 - one-row columns
    return CycleTable(start=one(0.0), end=one(P), switch=one(H), period=one(P), high=one(H), balance=one(H / P - 0.5),
                      amplitude=one(amplitude), centre=one(centre), Y=Y[None, :], U=relay_harmonics(h, one(H), one(P)),
                      trend=one(0.0), beta_up=one(np.nan), beta_dn=one(np.nan), resid_ss=one(0.0),
                      n_samples=np.array([400]))


def _extent(sol: PeriodicSolution) -> tuple[float, float]:
    """The amplitude and centre of a cycle's harmonics 1..N_HARM [output units], from 400 points of the
    period: an inverse real FFT, which is sol.waveform on that grid to rounding (1e-16) at a tenth of
    its CPU (issue 39)."""
    X = np.zeros(201, complex)
    X[1:N_HARM + 1] = sol.Y[1:N_HARM + 1]
    yg = sol.Y[0].real + np.fft.irfft(X, 400) * 200.0
    hi, lo = yg.max(), yg.min()
    return 0.5 * (hi - lo), 0.5 * (hi + lo)


def feature_mask(test: DiagnosedTest) -> np.ndarray:
    m = np.ones(len(FEATURE_NAMES), bool)
    if not test.has_setpoint:
        m[FEATURE_NAMES.index("centre")] = False
    return m


def feature_sigma(rec_sigma: np.ndarray, rec_values: np.ndarray) -> np.ndarray:
    floor = np.array([FEATURE_FLOOR[n] for n in FEATURE_NAMES])
    floor = floor.copy()
    floor[0] *= rec_values[0]  # period floor is relative
    rs = np.nan_to_num(np.asarray(rec_sigma, float), nan=0.0, posinf=np.inf)
    with np.errstate(over="ignore"):
        s = np.sqrt(np.where(np.isfinite(rs), rs, np.inf) ** 2 + floor**2)
    return s


@dataclass
class Fit:
    theta: np.ndarray
    K: float
    chi2: float
    n: int
    k: int
    resid: np.ndarray
    evals: list
    cov: np.ndarray | None
    ok: bool


def residuals(model: CandidateModel, theta: np.ndarray, recs: list, with_K: bool = False, newton: bool = False):
    """Stacked z residuals over tests; K eliminated in closed form (weighted mean of ln A); ``newton``:
    a Jacobian's column (:meth:`CandidateModel.evaluate`)."""
    evals = []
    ia = FEATURE_NAMES.index("log_amplitude")
    num = den = 0.0
    for i, (f_rec, s) in enumerate(recs):
        ev = model.evaluate(theta, i, f_rec.t_mean, newton=newton)
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
        out.append(z[feature_mask(test)])
    r = np.concatenate(out)
    if with_K:
        return r, math.exp(lnK), evals
    return r


def fit_model(model: CandidateModel, theta0: np.ndarray, lo: np.ndarray, hi: np.ndarray, recs: list, max_nfev: int = 60,
         free: np.ndarray | None = None) -> Fit:
    """Least-squares fit of the candidate's parameters (``free`` selects the ones that move)."""
    big = 1e3
    theta0 = np.clip(np.asarray(theta0, float), lo + 1e-9, hi - 1e-9)
    free = np.ones(theta0.size, bool) if free is None else np.asarray(free, bool)
    full0 = theta0.copy()

    def expand(x):
        th = full0.copy()
        th[free] = x
        return th

    # the best point evaluated is kept: a limit cycle solved from a warm start (the last one found)
    # can land on another periodic solution when evaluated again, so the final x of least_squares,
    # evaluated once more, is not always the point it scored (a pair fit once "ended" at delta BIC -1e5)
    best: list = [np.inf, None, None]  # chi^2, theta, (r, K, evals)
    last: list = [None, None]  # the last point evaluated and its residuals
    calls = [0]  # least_squares' own evaluations

    def fun(x):
        th = expand(x)
        got = residuals(model, th, recs, with_K=True)
        if got is None or not np.all(np.isfinite(got[0])):
            n = sum(int(feature_mask(t).sum()) for t in model.tests)
            last[:] = [np.array(x), np.full(n, big)]
            return last[1]
        r = got[0]
        chi2 = float(r @ r)
        if chi2 < best[0]:
            best[:] = [chi2, th, got]
        last[:] = [np.array(x), r]
        return r

    def counted(x):
        calls[0] += 1
        return fun(x)

    def jac(x):
        """Forward differences as least_squares' '2-point' with ``diff_step`` (its steps, their sign
        at the bounds), each column's cycles one Newton step on the period from the point's own."""
        r0 = last[1] if last[0] is not None and np.array_equal(last[0], x) else fun(x)
        if calls[0] >= max_nfev and not free.all():
            # least_squares asks for the Jacobian of its last point before it stops at max_nfev: with
            # parameters held, no covariance is taken from it, so it is never read (a profile's fit)
            return np.zeros((r0.size, x.size))
        sign = np.where(x >= 0, 1.0, -1.0)
        h = _STEP * sign * np.abs(x)
        h = np.where((x + h) - x == 0, _EPS_STEP * sign * np.maximum(1.0, np.abs(x)), h)
        lb, ub = lo[free], hi[free]
        flip = ((x + h < lb) | (x + h > ub)) & (np.abs(h) <= np.maximum(x - lb, ub - x))
        h[flip] = -h[flip]
        cols = []
        for j in range(x.size):
            xj = x.copy()
            xj[j] += h[j]
            r = residuals(model, expand(xj), recs, newton=True)
            if r is None or not np.all(np.isfinite(r)):
                r = np.full(r0.size, big)
            cols.append((r - r0) / (xj[j] - x[j]))
        return np.column_stack(cols)

    try:
        # chi^2 to 1e-5 relative is far finer than the evidence needs (thresholds of 10 in chi^2)
        sol = least_squares(counted, theta0[free], jac=jac, bounds=(lo[free], hi[free]), max_nfev=max_nfev,
                            x_scale=1.0, ftol=1e-5, xtol=1e-6)
        theta = expand(sol.x)
        J = sol.jac if free.all() else None
    except (ValueError, np.linalg.LinAlgError):
        theta, J = theta0, None
    got = residuals(model, theta, recs, with_K=True)
    if best[1] is not None and (got is None or float(got[0] @ got[0]) > best[0]):
        theta, got = best[1], best[2]
    if got is None:
        return Fit(theta, float("nan"), float("inf"), 0, len(theta) + 1, np.array([]), [], None, False)
    r, K, evals = got
    cov = None
    if J is not None:
        try:
            cov = np.linalg.pinv(J.T @ J)
        except np.linalg.LinAlgError:
            cov = None
    return Fit(theta, K, float(r @ r), int(r.size), len(theta) + 1, r, evals, cov, bool(np.all(np.abs(r) < big)))


#: Td's range in the fits [s] (:func:`theta_bounds`) and in the phase-condition start (:func:`initial_base`)
TD_RANGE_S = (0.02, 100.0)
#: tau's upper end in the phase-condition start [s]
_TAU_START_MAX_S = 0.5
#: log-Td grid of the phase-condition start (refined around its best point)
_LOG_TD_GRID = np.linspace(math.log(TD_RANGE_S[0]), math.log(TD_RANGE_S[1]), 49)
#: phase residuals [rad^2] this close to the best are rounding: the valley is flat there
_FLAT_COST = 1e-12


def _phase_terms(tests: list[DiagnosedTest], Tp: float, extra_phase: Callable | None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Each test's frequency W [rad/s] and the part of its describing-function phase condition that
    depends on neither Td nor tau [rad]: the condition is ``c - atan(W Td) - W tau = 0``."""
    W = np.array([2 * np.pi / np.mean(t.tab.period[t.fit]) for t in tests])
    # an effective beta measured beyond +-1 (a relay that switched late on a noisy or lagging output)
    # has no describing-function phase: the edge's (was a NaN and a RuntimeWarning on the terminal)
    B = np.clip([np.mean(t.beta) for t in tests], -1.0, 1.0)
    fs = np.array([t.rate_hz for t in tests])
    extra = np.zeros(len(tests)) if extra_phase is None else np.array([extra_phase(w, t) for w, t in zip(W, tests)])
    return W, np.pi / 2 - np.arctan(W * Tp) - W * 0.5 / fs + extra - np.arcsin(B)


def initial_base(tests: list[DiagnosedTest], Tp: float, extra_phase: Callable | None = None) -> np.ndarray:
    """Td, tau from the describing-function phase condition at each test's frequency (theta's layout).

    arg G(jW) - W/(2 f_s) + extra = -pi + asin(beta), with arg G = -pi/2 - atan(W Tp) - atan(W Td) - W tau;
    ``extra_phase(W, test)`` adds a candidate's own phase [rad] (e.g. -atan(W T_lag)). The condition
    is linear in tau, so tau is solved in closed form at each Td (in [0, 0.5] s) and the least-squares
    Td is found on a log grid over :data:`TD_RANGE_S` refined by a bounded scalar search. (A 2-D
    least-squares fit wandered the Td-tau valley for 40-120 ms a start when the tests share one
    frequency, where the condition cannot separate Td from tau: issue 39.) Tests at one frequency
    leave the valley (nearly) flat: its least-squares point is then as arbitrary as the noise, often a
    bound of the range, and the fits from it say so (:func:`bound_reason`); one test leaves it exactly
    flat, and the start is the valley's point nearest Td = 1 s.
    """
    W, c = _phase_terms(tests, Tp, extra_phase)
    ww = float(W @ W)

    def profile(u: float) -> tuple[float, float]:
        a = c - np.arctan(W * math.exp(u))
        tau = min(max(float(W @ a) / ww, 0.0), _TAU_START_MAX_S)
        r = a - W * tau
        return float(r @ r), tau

    costs = np.array([profile(u)[0] for u in _LOG_TD_GRID])
    flat = np.flatnonzero(costs <= costs.min() + _FLAT_COST)
    if flat.size > 1:  # one frequency: every Td of the valley meets the condition; the one nearest 1 s
        u = float(_LOG_TD_GRID[flat[np.argmin(np.abs(_LOG_TD_GRID[flat]))]])
        return np.array([u, 10 * profile(u)[1]])
    i = int(np.argmin(costs))
    lo, hi = _LOG_TD_GRID[max(i - 1, 0)], _LOG_TD_GRID[min(i + 1, _LOG_TD_GRID.size - 1)]
    ref = minimize_scalar(lambda u: profile(u)[0], bounds=(lo, hi), method="bounded", options={"xatol": 1e-9})
    u = float(ref.x) if ref.fun <= costs[i] else float(_LOG_TD_GRID[i])
    return np.array([u, 10 * profile(u)[1]])


def bound_reason(Td: float | None) -> str | None:
    """Why a fitted Td [s] is no estimate of the plant, or None: it ended on an end of :data:`TD_RANGE_S`.

    There the tests did not bound Td (nor so tau and K, which trade off against it along the valley of
    the phase condition): their frequencies fix the phase, not how Td and tau share it.
    """
    if Td is None or not math.isfinite(Td):
        return None
    lo, hi = TD_RANGE_S
    if Td >= hi * (1.0 - 1e-3):
        end = f"upper bound ({hi:g} s)"
    elif Td <= lo * (1.0 + 1e-3):
        end = f"lower bound ({lo:g} s)"
    else:
        return None
    return (f"its Td ended on the fit's {end}: these tests do not determine Td, nor so tau and K (their "
            "frequencies fix the phase, not how Td and tau share it; a test at another beta would)")


def tau_on_valley(tests: list[DiagnosedTest], Tp: float, Td: float) -> float:
    """tau [s] that satisfies the describing-function phase condition best for a given Td (closed form)."""
    W = np.array([2 * np.pi / np.mean(t.tab.period[t.fit]) for t in tests])
    B = np.clip([np.mean(t.beta) for t in tests], -1.0, 1.0)  # as _phase_terms
    fs = np.array([t.rate_hz for t in tests])
    # -pi/2 - atan(W Tp) - atan(W Td) - W (tau + 1/(2 fs)) = -pi + asin(B), linear in tau
    rhs = np.pi / 2 - np.arctan(W * Tp) - np.arctan(W * Td) - W * 0.5 / fs - np.arcsin(B)
    return max(float(W @ rhs / (W @ W)), 0.0)


def fit_base(model: CandidateModel, tests: list[DiagnosedTest], Tp: float, lo: np.ndarray, hi: np.ndarray, recs: list) -> Fit:
    """The linear model's fit, started along the Td-tau valley.

    The features pin the phase at each test's frequency well but Td and tau trade off along a curved
    valley, and a noisy log (large cycle-to-cycle scatter) can leave the describing-function start on
    the wrong side of a shallow local minimum. Td is therefore profiled over a decade-wide grid (tau
    fitted alone at each point, from the phase condition), and the two best points are refined freely.
    """
    th0 = initial_base(tests, Tp)
    starts = [th0] + [np.array([math.log(td), 10 * tau_on_valley(tests, Tp, td)])
                      for td in math.exp(th0[0]) * np.array([0.25, 0.5, 2.0, 4.0])]
    free = np.array([False, True])
    prof = []
    for th in starts:
        pf = fit_model(model, th, lo, hi, recs, max_nfev=6, free=free)
        if np.isfinite(pf.chi2):
            prof.append(pf)
    prof.sort(key=lambda f: f.chi2)
    best: Fit | None = None
    tries: list[Fit | None] = list(prof[:2]) or [None]
    for trial in tries:
        f = fit_model(model, trial.theta if trial is not None else th0, lo, hi, recs)
        if best is None or (f.ok and (not best.ok or f.chi2 < best.chi2)):
            best = f
    assert best is not None  # (one try at least)
    return best


def theta_bounds(cand: Effect | tuple | None, tests: list[DiagnosedTest]) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of theta (layout of :class:`CandidateModel`) for the base model, one candidate or a combination."""
    cands = () if cand is None else (tuple(cand) if isinstance(cand, (tuple, list)) else (cand,))
    lo = [math.log(TD_RANGE_S[0]), 0.0]
    hi = [math.log(TD_RANGE_S[1]), 5.0]
    hmin = min(t.h for t in tests)
    hmax = max(t.h for t in tests)
    hs = float(np.mean([t.h for t in tests]))
    extra: dict[str, tuple[float, float]] = {
        "input_bias": (-0.9 * hmin / hs, 0.9 * hmin / hs),
        "gain_drift": (-5.0, 5.0),
        "sensor_lag": (0.002, 3.0),
        "actuator_rate_limit": (0.0, 10.0),
        "asymmetric_gain": (-5.0, 5.0),
        "actuator_saturation": (0.2 * hmin / hs, 3.0 * hmax / hs),
        "dead_zone": (0.0, 9.0 * hmin / hs),
        "thrust_rectification": (0.0, 9.5 * hs / hmax),
    }
    for c in cands:
        if c.stochastic:
            continue
        if c.replaces_drag:
            lo[0], hi[0] = math.log(1e-4), math.log(1e6)
            continue
        lo.append(extra[c.name][0])
        hi.append(extra[c.name][1])
    return np.array(lo), np.array(hi)


def candidate_starts(cand: Effect, base: Fit, tests: list[DiagnosedTest], recs: list, Tp: float) -> list[np.ndarray]:
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
            b = initial_base(tests, Tp, lambda w, t, tl=tl: -math.atan(w * tl))
            out.append(np.array([b[0], b[1], 10 * tl]))
        return out
    if cand.name == "actuator_rate_limit":
        # a ramp of 2h/R delays the relay's first harmonic by h/R: profile over that extra delay
        out = []
        for ex in (0.005, 0.012, 0.025, 0.045, 0.07):
            rho = ex / hs
            b = initial_base(tests, Tp, lambda w, t, rho=rho: -w * t.h * rho)
            out.append(np.array([b[0], b[1], 10 * hs * rho]))
        return out
    if cand.name == "asymmetric_gain":
        # the balance of a test ~ -(a h) / (2 h) beyond the trim error's: start from both signs
        return [np.array([th[0], th[1], x]) for x in (-1.0, -0.3, 0.3, 1.0)]
    if cand.name == "actuator_saturation":
        # the limit just inside the largest test's trim + h, or a little further in
        hmax = max(t.h for t in tests)
        return [np.array([th[0], th[1], f * hmax / hs]) for f in (0.5, 0.7, 0.9, 1.2)]
    if cand.name == "dead_zone":
        hmin = min(t.h for t in tests)
        return [np.array([th[0], th[1], 10.0 * f * hmin / hs]) for f in (0.05, 0.2, 0.4)]
    if cand.name == "thrust_rectification":
        hmax = max(t.h for t in tests)
        return [np.array([th[0], th[1], 10.0 * f * hs / hmax]) for f in (0.15, 0.4, 0.7)]
    if cand.name == "quadratic_drag":
        # describing-function equivalent at the middle test's velocity amplitude (K = 1 units)
        Td = math.exp(th[0])
        f, _ = recs[len(recs) // 2]
        a1 = math.exp(f.values[FEATURE_NAMES.index("log_amplitude")]) / base.K
        V = a1 * 2 * np.pi / f.values[0]
        q = df_quadratic_drag(Td, V)
        return [np.array([math.log(q), th[1]])]
    raise ValueError(cand.name)


def plant_params(model: CandidateModel, fit: Fit) -> dict:
    p = model.unpack(fit.theta)
    out = {"tau": p["tau"], "K": fit.K}
    if p.get("Td") is not None:
        out["Td"] = p["Td"]
    return out


def param_std(fit: Fit, j: int | None) -> float:
    """Standard error of theta[j] from the fit's covariance (NaN without one, or no such parameter)."""
    if fit.cov is None or j is None or j >= fit.cov.shape[0]:
        return float("nan")
    v = fit.cov[j, j]
    return float(math.sqrt(v)) if v >= 0 else float("nan")


def effect_value(cand: Effect, model: CandidateModel, fit: Fit, p: dict) -> tuple[float, float]:
    """The effect's parameter in its own units and its standard error, from a fit of ``model``."""
    hs = model.hs
    j = model.extra_index(cand.name)
    if cand.name == "quadratic_drag":
        c = p["q"] / fit.K
        return c, c * param_std(fit, 0)
    x = p["extras"][cand.name]
    if cand.name == "input_bias":
        return x, param_std(fit, j) * hs
    if cand.name == "gain_drift":
        return x, param_std(fit, j) / 100.0
    if cand.name == "sensor_lag":
        return x, param_std(fit, j) / 10.0
    if cand.name == "asymmetric_gain":
        return x, param_std(fit, j) / 10.0
    if cand.name == "actuator_saturation":
        return model.bias_mean + x, param_std(fit, j) * hs
    if cand.name == "dead_zone":
        return x, param_std(fit, j) * hs / 10.0
    if cand.name == "thrust_rectification":
        F = 1.0 / x if x > 1e-9 else float("inf")
        s_inv = param_std(fit, j) / (10.0 * hs)
        return F, (s_inv / x**2 if x > 1e-9 else float("nan"))
    if cand.name == "actuator_rate_limit":
        rho = x
        R = 1.0 / rho if rho > 1e-9 else float("inf")
        s_rho = param_std(fit, j) / (10.0 * hs)
        return R, (s_rho / rho**2 if rho > 1e-9 else float("nan"))
    raise ValueError(cand.name)
