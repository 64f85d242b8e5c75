"""The candidate models' limit cycles: :class:`CandidateModel` evaluates the linear model with zero, one
or several candidate effects at the tests' MRFT settings (the exact limit cycle of
:mod:`mrftcli.diagnose.limit_cycles` and :mod:`mrftcli.diagnose.periodic`, warm-started and memoised)
and returns the same features as the recording's (:class:`PredictedCycle`); fitted by
:mod:`mrftcli.diagnose.fit`.

Units: times in seconds, the output in its own units (m or rad), the command in command units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .features import FEATURE_NAMES, N_HARM, CycleTable, cycle_features, relay_harmonics
from .physics import Effect
from .limit_cycles import AugmentedPlant, quasi_static_plant
from .periodic import CyclePlant, PeriodicSolution, cycle_at_period, periodic_solution
from .prepared import DiagnosedTest

__all__ = ["PERIOD_RTOL", "WARM_RADIUS", "PredictedCycle", "CandidateModel", "cycle_plant", "model_cycle"]

#: the period's relative tolerance of each limit cycle: the features' floors are 1e-3 and a Jacobian
#: column's cycle (one Newton step) is 1e-6 off, so 1e-8 is ample; 1e-10 took one series evaluation
#: more per cycle (of four or five; issue 39)
PERIOD_RTOL = 1e-8
#: the relative step in the period of a Jacobian column's feature derivative (:meth:`CandidateModel._column`)
_PERIOD_STEP = 1e-6
#: a limit cycle is started from the last one found only when that was found within this distance of
#: theta (largest component; theta's entries are O(1)): the steps inside one fit
WARM_RADIUS = 0.1


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
