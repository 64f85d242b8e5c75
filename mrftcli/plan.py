"""Plan the next MRFT test(s): the beta, relay height and duration that pin (Td, tau, K) down best.

What is known enters as a :class:`Prior` (ranges for Td, tau and K) and, optionally, as tests
already flown (:class:`FlownTest`, from a log or an ``analyze --json`` result). What the flight
allows enters as :class:`FlightLimits` (largest output amplitude, largest relay height, time
available, controller rate, sensor noise). :func:`plan_tests` returns the recommended test(s) with
their predicted limit cycle and the predicted standard deviations of Td, tau and K after them.

Method (docs/plan.md)
---------------------
*Measurement model.* ``mrft-ident analyze`` identifies from three constraints per test
(:mod:`mrftcli.analyze`): the test's UFM slice ``tau_i(Td) = theta_beta(Tp Omega, Td Omega) / Omega``
(paper Lemma 3, at the effective beta and measured Omega), the phase of its fundamental harmonic
``arg G(j Omega)`` and its amplitude through the UGM ``ln a = ln(h K Td a_unit / Omega)`` (Lemmas 2,
4). Each constraint is a row of the Jacobian J with respect to ``theta = (Td, tau, ln K)`` at the
test's frequency, evaluated with the exact closed form (:func:`mrftcli.mrft.lprs.unit_cycle`).

*Noise.* The per-cycle scatter of each constraint is modelled from three sources: the sensor
noise relative to the amplitude (``eps = noise / a``), the sampling of the relay (a switch comes up
to one controller period ``Ts`` after the crossing) and the switch-timing jitter that the noise
causes (``noise / |dy/dt|`` at the switch, from the exact waveform). The coefficients
(:data:`NOISE_MODEL`) were fitted once on simulated flights of random plants (fresh seeds, rates
100-400 Hz, noise 0.5-4 x default; ``benchmarks/bench_plan.py --calibrate`` re-fits them); the
standard error of a test's constraint is that scatter over sqrt(stable cycles), with the same
systematic floors that ``analyze`` adds (1e-3 of beta, 3e-4 rad of phase, 1e-3 of ln a).

*Design.* Fisher information ``I = sum_tests J^T W J`` plus the prior's (each range read as
+/- 2 standard deviations), the expected posterior covariance its inverse. It is averaged over a
few draws from the prior (for flown tests: draws on the flown tests' UFM slice), and the candidate
that minimises the mean of ``var(ln Td) + var(ln tau) + var(ln K)`` wins, among those predicted
no worse than the conventional beta (-0.4, then -0.7) for Td and tau when there are any. Candidates: beta on a grid
in ``(-0.9, -0.1)``, h the largest that keeps the largest predicted amplitude over the draws within
the limit, the duration the time available (split equally between the tests asked for). The
frequencies on the grid are the exact continuous LPRS with half a controller period added to the
delay, which is the centre of the sampled relay's band (:func:`mrftcli.mrft.lprs.mrft_limit_cycle`);
the recommended tests are then predicted with the sampled relay itself.

*Admissible.* At least 8 controller samples per period and 3 stable cycles; the output moving 4
noise std per tick at the zero crossing (:func:`mrftcli.sim.noise_margin`); and, when any beta
allows it, the switch at least 16 noise std below the extremum (:func:`switch_gap`): nearer
beta = -1 a noise dip triggers it early and ``analyze`` loses the test.

*Forecast.* The predicted stds are the median over the draws (the typical plant's), with the
10-90 % range over them: after one test, Td is often still uncertain by a factor of several, and
the Td std grows about as Td^2, so the forecast for the actual plant lies in that range. They
forecast the bootstrap std of ``analyze``'s MRFT estimate (``parameters_mrft``).

Units: times in seconds, frequencies in Hz, amplitudes in output units, h in command units.

Examples
--------
>>> from mrftcli.plan import FlightLimits, Prior, plan_tests
>>> prior = Prior(Td=(0.3, 3.0), tau=(0.01, 0.08), K=(1.0, 10.0))
>>> limits = FlightLimits(max_amplitude=0.05, max_h=2.0, time_s=30.0, rate_hz=200.0, noise_std=0.0005)
>>> p = plan_tests(0.04, prior, limits, n_tests=2, n_draws=3, betas=(-0.2, -0.5, -0.8))
>>> len(p.tests), all(-0.9 <= t.beta <= -0.1 for t in p.tests)
(2, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .errors import InputError
from .mrft.consensus import BETA_SYSTEMATIC, GAIN_SYSTEMATIC, PHASE_SYSTEMATIC
from .mrft.lprs import mrft_limit_cycle, unit_cycle
from .mrft.model import LoopModel
from .progress import Progress, report
from .validate import check_beta, check_positive, check_time

__all__ = [
    "Prior",
    "FlightLimits",
    "FlownTest",
    "flown_from_segments",
    "flown_from_result",
    "prior_range",
    "TestPlan",
    "PlanResult",
    "NOISE_MODEL",
    "cycle_noise",
    "switch_gap",
    "fisher_information",
    "planned_information",
    "flown_information",
    "plan_tests",
    "simulated_std",
    "DEFAULT_BETAS",
    "TD_OMEGA_LIMIT",
]

_TWO_PI = 2.0 * math.pi
#: beta grid searched by default (the issue's admissible range (-0.9, -0.1)).
DEFAULT_BETAS = tuple(np.round(np.linspace(-0.9, -0.1, 17), 3))
#: Td * Omega above which the frequencies hardly depend on Td (the tool's identifiability boundary).
TD_OMEGA_LIMIT = 5.0
#: Per-cycle noise model (see :func:`cycle_noise`): coefficients of (eps, sampling, switch jitter)
#: for the UFM slice, the fundamental's phase and ln(amplitude). Fitted on simulated flights by
#: ``benchmarks/bench_plan.py --calibrate`` (docs/benchmarks/plan.md).
NOISE_MODEL = {
    "ufm": (0.0, 0.072, 0.596),
    "phase": (0.003, 0.0, 0.719),
    "ln_amplitude": (0.0, 0.0, 1.536),
}
# Systematic floors analyze adds to every test (mrftcli.analyze: effective beta, phase, ln a).
_FLOOR_BETA, _FLOOR_PHASE, _FLOOR_LN_A = BETA_SYSTEMATIC, PHASE_SYSTEMATIC, GAIN_SYSTEMATIC
#: Cycles the segmenter typically drops at the start of a test (the transient) and at its end.
_LOST_CYCLES = 3
#: Fewest stable cycles analyze accepts in a test (its min_stable_cycles).
_MIN_CYCLES = 3
#: Largest sensor noise relative to the amplitude for a usable test (the MRFT rule locks up on noise).
_MAX_EPS = 0.1
#: Least a * Omega / (rate * noise) for the MRFT rule not to lock up on noise (measured over 486
#: simulated tests: none locked at >= 4; mrftcli.sim.noise_margin).
_MIN_NOISE_MARGIN = 4.0
#: Least switch gap (1 + beta) a / noise for analyze to use the test (see :func:`switch_gap`).
_MIN_SWITCH_GAP = 16.0
_PARAMS = ("Td", "tau", "K")


# ----------------------------------------------------------------------------------------------
# inputs
# ----------------------------------------------------------------------------------------------
def _check_range(name: str, rng: Sequence[float], unit: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in rng)
    except (TypeError, ValueError) as err:
        raise InputError(f"the {name} range must be two numbers LOW HIGH{unit}, got {rng!r}") from err
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise InputError(f"the {name} range must satisfy 0 < LOW <= HIGH{unit}, got {lo:g} {hi:g}")
    return lo, hi


@dataclass(frozen=True)
class Prior:
    """What is known before the next test: a range for each parameter.

    Attributes
    ----------
    Td : (float, float)
        Drag time constant range [s].
    tau : (float, float)
        Loop delay range [s].
    K : (float, float)
        Gain range [output units / (command unit s^2)].

    Each range is read as the mean +/- 2 standard deviations (of Td, tau and ln K) for the prior
    information, and drawn from uniformly (log-uniformly for Td and K).
    """

    Td: tuple[float, float] = (0.2, 3.0)
    tau: tuple[float, float] = (0.01, 0.1)
    K: tuple[float, float] = (0.5, 20.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "Td", _check_range("Td", self.Td, " [s]"))
        object.__setattr__(self, "tau", _check_range("tau", self.tau, " [s]"))
        object.__setattr__(self, "K", _check_range("K", self.K, ""))

    def information(self) -> np.ndarray:
        """Prior Fisher information on (Td, tau, ln K): diag(1 / sigma^2), sigma = width / 4."""
        sig = np.array([(self.Td[1] - self.Td[0]) / 4, (self.tau[1] - self.tau[0]) / 4,
                        math.log(self.K[1] / self.K[0]) / 4])
        return np.diag(np.where(sig > 0, 1.0 / np.maximum(sig, 1e-300) ** 2, 1e30))

    def draws(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` plants (rows Td, tau, K) from the ranges, stratified so few draws cover them."""
        u = (np.arange(n)[None, :] + rng.uniform(size=(3, n))) / n
        u = np.array([rng.permutation(row) for row in u])
        Td = self.Td[0] * (self.Td[1] / self.Td[0]) ** u[0]
        tau = self.tau[0] + (self.tau[1] - self.tau[0]) * u[1]
        K = self.K[0] * (self.K[1] / self.K[0]) ** u[2]
        return np.stack([Td, tau, K], axis=1)


@dataclass(frozen=True)
class FlightLimits:
    """What the flight allows.

    Attributes
    ----------
    max_amplitude : float
        Largest output amplitude allowed [output units] (e.g. 0.05 m, 5 deg in rad).
    max_h : float
        Largest relay height the motors give [command units].
    time_s : float
        Relay time available for the next test(s) together [s].
    rate_hz : float
        Controller (relay) rate [Hz].
    noise_std : float
        Sensor noise standard deviation of the output [output units].
    """

    max_amplitude: float
    max_h: float
    time_s: float
    rate_hz: float
    noise_std: float

    def __post_init__(self) -> None:
        check_positive("the largest amplitude (--max-amplitude)", self.max_amplitude)
        check_positive("the largest relay height (--max-h)", self.max_h)
        check_time("the time available (--time)", self.time_s)
        check_positive("the controller rate (--rate)", self.rate_hz)
        check_positive("the sensor noise (--noise)", self.noise_std)


@dataclass(frozen=True)
class FlownTest:
    """A test already flown, as measured (from a log or an ``analyze --json`` result).

    Attributes
    ----------
    beta : float
        Effective beta of the test.
    h : float
        Relay height [command units].
    frequency_hz : float
        Mean limit-cycle frequency [Hz].
    amplitude : float
        Mean output amplitude [output units].
    n_cycles : int
        Stable cycles used.
    phase : float, optional
        Mean phase of the output's fundamental relative to the relay's [rad] (``RelayCycle.phase_h1``);
        with it the draws are weighted by how well each plant explains it.
    """

    __test__ = False  # not a pytest class

    beta: float
    h: float
    frequency_hz: float
    amplitude: float
    n_cycles: int
    phase: float | None = None

    def __post_init__(self) -> None:
        check_beta(self.beta)
        check_positive("h", self.h)
        check_positive("frequency_hz", self.frequency_hz)
        check_positive("amplitude", self.amplitude)
        if int(self.n_cycles) < 1:
            raise InputError(f"a flown test needs at least one cycle, got {self.n_cycles!r}")


def flown_from_segments(tests: Sequence) -> tuple[tuple[FlownTest, ...], float | None]:
    """The flown tests of :func:`mrftcli.segment.segment` (``MrftTest`` records) and their sensor noise.

    Tests with fewer than 3 stable cycles are left out. Returns the tests and the median per-cycle
    residual noise of the segmenter's cycle fits [output units] (None when none was measured).
    """
    out, noise = [], []
    for t in tests:
        if t.n_stable < _MIN_CYCLES or not np.isfinite(t.beta_effective):
            continue
        ph = np.array([c.phase_h1 for c in t.stable], float)
        ph = ph[np.isfinite(ph)]
        out.append(FlownTest(beta=float(t.beta_effective), h=float(t.h), frequency_hz=float(t.frequency_hz_mean),
                             amplitude=float(t.amplitude_mean), n_cycles=int(t.n_stable),
                             phase=float(ph.mean()) if ph.size >= 2 else None))
        noise.extend(c.noise_std for c in t.stable if np.isfinite(c.noise_std))
    return tuple(out), (float(np.median(noise)) if noise else None)


def flown_from_result(data: object) -> tuple[list[FlownTest], dict]:
    """The flown tests and the identified parameters (``{}`` if none) of an ``analyze --json`` result.

    ``data`` is the parsed JSON; the tests of a partial (single-beta) result count too.

    Raises
    ------
    InputError
        Not a JSON object, a test without beta, h, frequency_hz, amplitude or cycles, or no test.
    """
    if not isinstance(data, dict):
        raise InputError("not an analyze --json result (expected a JSON object)")
    tests = data.get("tests") or (data.get("partial") or {}).get("tests") or []
    flown = []
    for t in tests:
        try:
            flown.append(FlownTest(beta=float(t["beta"]), h=float(t["h"]), frequency_hz=float(t["frequency_hz"]),
                                   amplitude=float(t["amplitude"]), n_cycles=int(t["cycles"])))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"a test lacks beta, h, frequency_hz, amplitude or cycles ({err})") from err
    if not flown:
        raise InputError("no MRFT test in this JSON (give the output of 'mrft-ident analyze --json')")
    return flown, data.get("parameters") or {}


def prior_range(estimate: dict | None, default: tuple[float, float]) -> tuple[float, float]:
    """A prior range from an identified parameter (``{"mean", "std"}``): mean +/- 2 std, its low end
    kept above mean / 10 (a range must stay positive); ``default`` without a usable estimate.

    Examples
    --------
    >>> prior_range({"mean": 1.0, "std": 0.1}, (0.2, 3.0))
    (0.8, 1.2)
    >>> prior_range(None, (0.2, 3.0))
    (0.2, 3.0)
    """
    if estimate and estimate.get("mean") is not None and estimate.get("std") is not None \
            and math.isfinite(estimate["std"]) and estimate["std"] > 0 and estimate["mean"] > 0:
        m, s = float(estimate["mean"]), float(estimate["std"])
        return (max(m - 2 * s, m / 10), m + 2 * s)
    return default


# ----------------------------------------------------------------------------------------------
# the measurement model
# ----------------------------------------------------------------------------------------------
def cycle_noise(amplitude: float, omega: float, switch_slope: float, rate_hz: float,
                noise_std: float) -> dict[str, float]:
    """Per-cycle standard deviations of a test's three constraints (the measurement noise model).

    Parameters
    ----------
    amplitude : float
        Output amplitude a [output units].
    omega : float
        Limit-cycle frequency [rad/s].
    switch_slope : float
        |dy/dt| of the output at the relay switch [output units / s].
    rate_hz : float
        Controller rate [Hz].
    noise_std : float
        Sensor noise std [output units].

    Returns
    -------
    dict
        ``ufm`` [s] (scatter of a cycle's UFM value tau_c), ``phase`` [rad] (of the fundamental's
        phase), ``ln_amplitude`` [-]: each ``sqrt(sum (c_k x_k)^2)`` over the sources
        ``x = (eps, Ts, noise / slope)`` scaled to the quantity (:data:`NOISE_MODEL`), with
        ``eps = noise / a`` and ``Ts = 1 / rate``.

    Examples
    --------
    >>> s = cycle_noise(0.05, 6.0, 0.3, 200.0, 0.0)   # no sensor noise: sampling alone
    >>> round(s["ufm"] * 1e3, 3)   # 0.072 Ts [ms]
    0.36
    """
    eps = noise_std / amplitude
    Ts = 1.0 / rate_hz
    jit = noise_std / max(switch_slope, 1e-300)
    n_per_cycle = rate_hz * _TWO_PI / omega

    def comb(c: tuple[float, float, float], x: tuple[float, float, float]) -> float:
        return math.sqrt(sum((ci * xi) ** 2 for ci, xi in zip(c, x)))

    return {
        "ufm": comb(NOISE_MODEL["ufm"], (eps / omega, Ts, jit)),
        "phase": comb(NOISE_MODEL["phase"], (eps / math.sqrt(n_per_cycle), omega * Ts, omega * jit)),
        "ln_amplitude": comb(NOISE_MODEL["ln_amplitude"], (eps, omega * Ts, omega * jit)),
    }


def switch_gap(amplitude: float, beta: float, noise_std: float) -> float:
    """How far below the extremum the MRFT rule switches, in sensor noise std: ``(1 + beta) a / noise``.

    The rule switches once the error has fallen back by the share ``1 + beta`` of its extremum. Near
    beta = -1 that is a small drop, which a noise dip right after the extremum triggers early (the
    switch level then wanders and the relay hops between orbits or locks up), although the output
    moves fast enough at the zero crossing (:func:`mrftcli.sim.noise_margin`). ``analyze`` could
    use every simulated test with a gap of 16 or more (``benchmarks/bench_plan.py --admissibility``,
    docs/benchmarks/plan.md). Returns inf without noise.

    Examples
    --------
    >>> round(switch_gap(0.05, -0.9, 0.0005), 3)   # a 5 cm cycle at beta -0.9 under 0.5 mm of noise
    10.0
    """
    if noise_std <= 0:
        return math.inf
    return (1.0 + beta) * amplitude / noise_std


def _slice_derivatives(Tp: float, Td: float, omega: float, beta: float) -> tuple[float, float]:
    """d tau_i / d Td [-] of the UFM slice at Omega, and d tau / d beta [s] (central differences)."""
    d = 1e-4
    th, _ = unit_cycle(Tp * omega, np.array([Td * (1 - d), Td * (1 + d)]) * omega, beta)
    dtau_dTd = float(th[1] - th[0]) / (2 * d * Td) / omega
    tb, _ = unit_cycle(Tp * omega, Td * omega, np.array([beta - d, beta + d]))
    dtau_dbeta = float(tb[1] - tb[0]) / (2 * d) / omega
    return dtau_dTd, dtau_dbeta


def fisher_information(Tp: float, Td: float, K: float, beta: float, omega: float, amplitude: float,
                     n_cycles: float, noise: dict[str, float]) -> np.ndarray:
    """Fisher information of one test on ``(Td, tau, ln K)`` (3 x 3), as ``analyze`` measures it.

    Rows of J (residuals of :mod:`mrftcli.analyze`'s weighted least squares, at the measured Omega):
    UFM slice ``tau - tau_i(Td)``: ``(-d tau_i/d Td, 1, 0)``; phase ``tau - tau_phi(Td)`` with
    ``tau_phi = (-phi - pi/2 - atan(Tp W) - atan(Td W)) / W``: ``(1 / (1 + (Td W)^2), 1, 0)``; UGM
    ``ln K - ln K_i(Td)``, ``ln K_i = ln(a W / (h Td a_unit))``: ``(1/Td + W d ln a_unit / d td, 0,
    1)``. Their variances are the per-cycle ``noise`` over ``n_cycles`` plus analyze's floors.

    Examples
    --------
    The phase constraint alone for a plant with Td W = 1 (closed form: J = (1/2, 1, 0)):

    >>> import numpy as np
    >>> I = fisher_information(0.04, 1.0, 1.0, -0.5, 1.0, 1.0, 1, {"ufm": np.inf, "phase": 1.0,
    ...                      "ln_amplitude": np.inf})
    >>> np.round(I / I[1, 1] * 1.0, 3).tolist()[0]
    [0.25, 0.5, 0.0]
    """
    n = max(float(n_cycles), 1.0)
    dtau_dTd, dtau_dbeta = _slice_derivatives(Tp, Td, omega, beta)
    d = 1e-4
    _, au = unit_cycle(Tp * omega, np.array([Td * (1 - d), Td * (1 + d)]) * omega, 0.0)
    dln_au_dTd = float(np.log(au[1] / au[0])) / (2 * d * Td)
    var_u = noise["ufm"] ** 2 / n + (dtau_dbeta * _FLOOR_BETA) ** 2
    var_p = (noise["phase"] ** 2 / n + _FLOOR_PHASE ** 2) / omega**2
    var_k = noise["ln_amplitude"] ** 2 / n + _FLOOR_LN_A**2
    rows = np.array([[-dtau_dTd, 1.0, 0.0], [1.0 / (1.0 + (Td * omega) ** 2), 1.0, 0.0],
                     [1.0 / Td + dln_au_dTd, 0.0, 1.0]])
    w = np.array([1.0 / var_u, 1.0 / var_p, 1.0 / var_k])
    w = np.where(np.isfinite(w), w, 0.0)
    return rows.T @ (w[:, None] * rows)


# ----------------------------------------------------------------------------------------------
# results
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TestPlan:
    """One recommended test and its predicted limit cycle (for the prior's central plant).

    Attributes
    ----------
    beta, h, duration_s : float
        The test: MRFT beta, relay height [command units], relay duration [s].
    frequency_hz, amplitude : float
        Predicted limit cycle at the controller rate (centre of the sampled relay's band) [Hz],
        [output units], for the central plant.
    frequency_range_hz, amplitude_range : (float, float)
        Range of the prediction over the prior's draws.
    orbits_hz : tuple of float
        The sampled relay's admissible periodic orbits for the central plant [Hz].
    n_cycles : int
        Predicted stable cycles (``duration / period`` less the transient).
    td_omega : (float, float)
        Range of Td * Omega over the draws (above 5 the test says little about Td).
    """

    __test__ = False

    beta: float
    h: float
    duration_s: float
    frequency_hz: float
    amplitude: float
    frequency_range_hz: tuple[float, float]
    amplitude_range: tuple[float, float]
    orbits_hz: tuple[float, ...]
    n_cycles: int
    td_omega: tuple[float, float]

    def to_dict(self) -> dict:
        return {"beta": self.beta, "h": self.h, "duration_s": self.duration_s, "frequency_hz": self.frequency_hz,
                "amplitude": self.amplitude, "frequency_range_hz": list(self.frequency_range_hz),
                "amplitude_range": list(self.amplitude_range), "orbits_hz": list(self.orbits_hz),
                "n_cycles": self.n_cycles, "td_omega": list(self.td_omega)}


@dataclass(frozen=True)
class PlanResult:
    """What :func:`plan_tests` recommends.

    Attributes
    ----------
    Tp : float
        Known propulsion time constant [s].
    tests : tuple of TestPlan
        The recommended next test(s), in flying order.
    predicted_std : dict
        Td, tau [s], K: predicted standard deviation after the recommended tests, prior included
        (the median over the draws: the typical plant's).
    predicted_std_data : dict
        The same from the tests alone (flown and recommended): the bootstrap std of ``analyze``'s
        MRFT estimate (``parameters_mrft``; the waveform refinement, when accepted, is tighter).
    predicted_std_data_range : dict
        Td, tau, K -> (low, high): the 10-90 % range of ``predicted_std_data`` over the draws (how
        much the forecast depends on where in the remaining uncertainty the plant lies).
    prior_std : dict
        The prior's standard deviations (range / 4).
    conventional : dict or None
        For comparison, the same figures for the conventional beta -0.4 / -0.7 (the one(s) of
        them not yet flown), with the same h rule and durations.
    candidates : tuple of dict
        Per beta on the grid (for the first recommended test): h, predicted frequency, amplitude,
        cycles and stds, and whether the limits admit it.
    notes : tuple of str
        Parameters no admissible test pins down, and what would help.
    simulated_std, simulated_std_range : dict
        With ``n_simulated``: the median and the 10-90 % range over the simulated plants of the
        bootstrap std ``analyze`` measured on their simulated flights (:func:`simulated_std`); empty
        otherwise.
    n_simulated : int
        Simulated flights that ``analyze`` could use.
    """

    Tp: float
    tests: tuple[TestPlan, ...]
    predicted_std: dict
    predicted_std_data: dict
    prior_std: dict
    conventional: dict | None
    candidates: tuple = ()
    notes: tuple[str, ...] = ()
    predicted_std_data_range: dict = field(default_factory=dict)
    flown: tuple[FlownTest, ...] = ()
    limits: FlightLimits | None = field(default=None, repr=False)
    simulated_std: dict = field(default_factory=dict)
    simulated_std_range: dict = field(default_factory=dict)
    n_simulated: int = 0

    def to_dict(self) -> dict:
        """JSON object of ``mrft-ident plan --json``."""
        lim = self.limits
        return {
            "Tp": self.Tp,
            "tests": [t.to_dict() for t in self.tests],
            "predicted_std": self.predicted_std,
            "predicted_std_tests_only": self.predicted_std_data,
            "predicted_std_tests_only_range": {k: list(v) for k, v in self.predicted_std_data_range.items()},
            "simulated_std": self.simulated_std,
            "simulated_std_range": {k: list(v) for k, v in self.simulated_std_range.items()},
            "n_simulated": self.n_simulated,
            "prior_std": self.prior_std,
            "conventional": self.conventional,
            "candidates": list(self.candidates),
            "notes": list(self.notes),
            "flown_tests": [{"beta": f.beta, "h": f.h, "frequency_hz": f.frequency_hz, "amplitude": f.amplitude,
                             "n_cycles": f.n_cycles} for f in self.flown],
            "limits": None if lim is None else {"max_amplitude": lim.max_amplitude, "max_h": lim.max_h,
                                                "time_s": lim.time_s, "rate_hz": lim.rate_hz,
                                                "noise_std": lim.noise_std},
        }


# ----------------------------------------------------------------------------------------------
# the planner
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Cycle:
    """The predicted cycle of one plant draw at one beta, for h = 1."""

    omega: float
    amp1: float  # amplitude for h = 1
    slope1: float  # |dy/dt| at the switch for h = 1


def _predict(Tp: float, Td: float, tau: float, K: float, beta: float, rate_hz: float) -> _Cycle | None:
    """Exact LPRS with the sampled relay's mean lag (half a period) added to the delay, h = 1."""
    try:
        lc = mrft_limit_cycle(LoopModel(Tp, Td, tau + 0.5 / rate_hz, K), beta, 1.0, None, n_points=256)
    except (InputError, ValueError, RuntimeError):
        return None
    if not (np.isfinite(lc.omega) and lc.omega > 0):
        return None
    # the +h -> -h switch is at t = T/2 in the LimitCycle frame
    dy = np.gradient(lc.y, lc.t)
    i = int(np.argmin(np.abs(lc.t - 0.5 * lc.period)))
    return _Cycle(lc.omega, lc.amplitude, float(abs(dy[i])))


def planned_information(Tp: float, plant: Sequence[float], beta: float, h: float, duration_s: float,
                        rate_hz: float, noise_std: float, *, cycle: _Cycle | None = None) -> np.ndarray:
    """Fisher information on ``(Td, tau, ln K)`` of a test not yet flown, for one plant (3 x 3).

    Parameters
    ----------
    Tp : float
        Propulsion time constant [s].
    plant : (float, float, float)
        Td [s], tau [s], K of the plant.
    beta, h, duration_s : float
        The test: MRFT beta, relay height [command units], relay duration [s].
    rate_hz, noise_std : float
        Controller rate [Hz] and sensor noise std [output units].

    Its cycle is the exact LPRS with half a controller period added to the delay; the stable cycles
    are those of ``duration_s`` less the transient; the noise is :func:`cycle_noise`. Returns zeros
    when the plant has no limit cycle at this beta.
    """
    Td, tau, K = (float(v) for v in plant)
    c = cycle if cycle is not None else _predict(Tp, Td, tau, K, beta, rate_hz)
    if c is None:
        return np.zeros((3, 3))
    a = h * c.amp1
    n_c = max(math.floor(duration_s * c.omega / _TWO_PI) - _LOST_CYCLES, 1)
    noise = cycle_noise(a, c.omega, h * c.slope1, rate_hz, noise_std)
    return fisher_information(Tp, Td, K, beta, c.omega, a, n_c, noise)


def flown_information(Tp: float, plant: Sequence[float], f: FlownTest, rate_hz: float, noise_std: float) -> np.ndarray:
    """Fisher information on ``(Td, tau, ln K)`` of a flown test (as measured) for one plant (3 x 3)."""
    omega = _TWO_PI * f.frequency_hz
    slope = f.amplitude * omega * 1.5  # a triangle-like cycle; used only for the jitter term
    noise = cycle_noise(f.amplitude, omega, slope, rate_hz, noise_std)
    return fisher_information(Tp, plant[0], plant[2], f.beta, omega, f.amplitude, f.n_cycles, noise)


def _conditioned_draws(Tp: float, prior: Prior, flown: Sequence[FlownTest], n: int,
                       rng: np.random.Generator, rate_hz: float, noise_std: float) -> np.ndarray:
    """Plant draws consistent with the flown tests: Td from the prior, tau from the first test's
    UFM slice (Lemma 3), K from its amplitude (UGM); with two betas flown, least squares of them all.
    When the flown tests carry their phase, many candidates on the slice are weighted by the
    likelihood of the measured phases (Gaussian, the noise model's standard error) and ``n`` drawn
    from them by systematic resampling: the posterior of the flown tests, not the whole slice."""
    if not flown:
        return prior.draws(n, rng)
    phased = [t for t in flown if t.phase is not None]
    m = 64 * n if phased else n
    draws = prior.draws(m, rng)
    f = flown[0]
    omega = _TWO_PI * f.frequency_hz
    Td = draws[:, 0]
    if len({round(t.beta, 2) for t in flown}) >= 2:
        from .mrft.identify import TestMeasurement, identify

        res = identify([TestMeasurement(beta=t.beta, frequency_hz=t.frequency_hz, amplitude=t.amplitude, h=t.h)
                        for t in flown], Tp)
        Td = np.full(n, res.model.Td)
    th, a_unit = unit_cycle(Tp * omega, Td * omega, f.beta)
    tau = th / omega
    K = f.amplitude * omega / (f.h * Td * a_unit)
    ok = np.isfinite(tau) & (tau >= 0) & (K > 0)
    inside = ok & (tau >= prior.tau[0]) & (tau <= prior.tau[1])
    keep = inside if inside.sum() >= max(2, n // 3) else ok
    if not keep.any():
        raise InputError("the flown test admits no plant with Td in the prior range and a non-negative delay; "
                         "check --tp and the Td range")
    out = np.stack([Td, tau, K], axis=1)[keep]
    if not phased or out.shape[0] <= n:
        return out
    loglik = np.zeros(out.shape[0])
    for t in phased:
        w = _TWO_PI * t.frequency_hz
        pred = -0.5 * math.pi - np.arctan(Tp * w) - np.arctan(out[:, 0] * w) - out[:, 1] * w
        # the noise model's per-cycle phase scatter at this test (slope of a triangle-like cycle)
        sd = cycle_noise(t.amplitude, w, 1.5 * t.amplitude * w, rate_hz, noise_std)["phase"]
        sd = math.sqrt(sd**2 / t.n_cycles + _FLOOR_PHASE**2)
        r = np.angle(np.exp(1j * (t.phase - pred)))
        loglik += -0.5 * (r / sd) ** 2
    wts = np.exp(loglik - loglik.max())
    cdf = np.cumsum(wts) / wts.sum()
    idx = np.searchsorted(cdf, (np.arange(n) + rng.uniform()) / n)
    return out[np.minimum(idx, out.shape[0] - 1)]


def simulated_std(Tp: float, plants: np.ndarray, flown: Sequence[FlownTest], tests: Sequence[TestPlan],
                  limits: FlightLimits, *, n_bootstrap: int = 100, seed: int = 0,
                  progress: Progress | None = None) -> np.ndarray:
    """Forecast by simulation: fly the flown and planned tests on each plant and measure analyze's std.

    For each plant (rows Td [s], tau [s], K) the project's simulator (:func:`mrftcli.sim.simulate_flight`,
    exact sampled MRFT rule at ``limits.rate_hz``, white sensor noise ``limits.noise_std``) flies the
    flown tests (their beta and h, their stable cycles plus the transient) and then ``tests``; the
    flight is analysed as ``analyze`` does without the waveform refinement, and the bootstrap std
    of its MRFT estimate is kept. Everything the analytic noise model approximates (the sampled
    relay hopping between orbits, switch jitter, the segmenter's choices) is then in the forecast.

    Parameters
    ----------
    Tp : float
        Propulsion time constant [s].
    plants : ndarray, shape (n, 3)
        The plants to fly (Td, tau, K), e.g. draws from what the flown tests leave.
    flown, tests : sequences of FlownTest and TestPlan
        The tests flown so far and the planned ones, in flying order.
    limits : FlightLimits
        Controller rate and sensor noise of the flight.
    n_bootstrap : int
        Bootstrap draws per analysis.
    seed : int
        Seed of the noise and of the bootstrap.
    progress : Progress, optional
        Called as ``progress(done, n, "simulating")`` per plant.

    Returns
    -------
    ndarray, shape (n, 3)
        std of Td [s], tau [s], K per plant; NaN where ``analyze`` could not use the simulated flight
        (it locked up on noise, or a test was lost).
    """
    from .analyze import analyze_flight
    from .errors import MrftError
    from .io.logtypes import FlightLog, Signal
    from .sim import FlightSpec, TestSpec, simulate_flight

    specs = [TestSpec(f.beta, f.h, (f.n_cycles + _LOST_CYCLES) / f.frequency_hz) for f in flown]
    specs += [TestSpec(t.beta, t.h, t.duration_s) for t in tests]
    rng = np.random.default_rng(seed)
    out = np.full((len(plants), 3), np.nan)
    for k, p in enumerate(plants):
        model = LoopModel(Tp, float(p[0]), float(p[1]), float(p[2]))
        try:
            sf = simulate_flight(FlightSpec(model=model, tests=tuple(specs), rate_hz=limits.rate_hz,
                                            noise_std=limits.noise_std, seed=int(rng.integers(1 << 30)),
                                            hover_s=2.0, hold_s=2.0))
            flight = FlightLog(path="<simulated>", loop=sf.spec.loop, command=Signal(sf.t, sf.command),
                               output=Signal(sf.t, sf.output_measured), setpoint=Signal(sf.t, sf.setpoint))
            with np.errstate(all="ignore"):
                res = analyze_flight(flight, Tp, n_bootstrap=n_bootstrap, refine_waveform=False,
                                     seed=int(rng.integers(1 << 30)))
            # a planned test analyze lost counts as no forecast (its std would be the flown tests')
            if all(any(abs(m.beta_effective - t.beta) < 0.1 for m in res.tests) for t in tests):
                out[k] = (res.Td.std, res.tau.std, res.K.std)
        except MrftError:
            pass
        report(progress, k + 1, len(plants), "simulating")
    return out


def _stds(cov: np.ndarray, plant: np.ndarray) -> np.ndarray:
    """(std Td [s], std tau [s], std K) from the covariance on (Td, tau, ln K)."""
    d = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return np.array([d[0], d[1], d[2] * plant[2]])


def _cost(cov: np.ndarray, plant: np.ndarray) -> float:
    """var(ln Td) + var(ln tau) + var(ln K)."""
    return float(cov[0, 0] / plant[0] ** 2 + cov[1, 1] / max(plant[1], 1e-4) ** 2 + cov[2, 2])


def _inv(info: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(info)


def plan_tests(
    Tp: float,
    prior: Prior,
    limits: FlightLimits,
    *,
    flown: Sequence[FlownTest] = (),
    n_tests: int | None = None,
    betas: Sequence[float] = DEFAULT_BETAS,
    n_draws: int = 8,
    n_simulated: int = 0,
    seed: int = 0,
    progress: Progress | None = None,
) -> PlanResult:
    """Recommend the next MRFT test(s) (see the module docstring for the method).

    Parameters
    ----------
    Tp : float
        Known propulsion time constant [s].
    prior : Prior
        Ranges for Td, tau and K.
    limits : FlightLimits
        Amplitude, relay height, time, rate and noise of the flight.
    flown : sequence of FlownTest
        Tests already flown (their information is counted, and the draws follow their UFM slice).
    n_tests : int, optional
        How many next tests to recommend (sharing ``limits.time_s`` equally); default 2 with no
        flown test, else 1.
    betas : sequence of float
        The beta grid searched.
    n_draws : int
        Plant draws from the prior the design is averaged over.
    n_simulated : int
        When > 0, the recommended tests are also flown in simulation on this many of the draws
        (:func:`simulated_std`, about 0.1 s each): ``PlanResult.simulated_std`` and its range.
    seed : int
        Seed of the draws.
    progress : Progress, optional
        Called as ``progress(done, total, "planning")`` per beta and test.

    Returns
    -------
    PlanResult

    Raises
    ------
    InputError
        Bad arguments, or limits that admit no test (the message says which limit to relax).
    """
    Tp = check_time("Tp", Tp)
    betas = tuple(check_beta(b) for b in betas)
    if not betas:
        raise InputError("give at least one beta to search")
    if n_tests is None:
        n_tests = 1 if flown else 2
    if int(n_tests) < 1:
        raise InputError(f"the number of tests must be at least 1, got {n_tests!r}")
    n_tests = int(n_tests)
    rng = np.random.default_rng(seed)
    rate, noise_std = limits.rate_hz, limits.noise_std
    plants = _conditioned_draws(Tp, prior, flown, max(int(n_draws), 1), rng, rate, noise_std)
    duration = limits.time_s / n_tests
    prior_info = prior.information()
    base = [prior_info.copy() for _ in plants]
    base_data = [np.zeros((3, 3)) for _ in plants]
    for f in flown:
        for k, p in enumerate(plants):
            J = flown_information(Tp, p, f, rate, noise_std)
            base[k] = base[k] + J
            base_data[k] = base_data[k] + J

    # predicted cycles per (beta, draw), h = 1
    cycles: dict[float, list[_Cycle | None]] = {}
    total = len(betas) * (n_tests + 1)
    for i, b in enumerate(betas):
        cycles[b] = [_predict(Tp, p[0], p[1], p[2], b, rate) for p in plants]
        report(progress, i + 1, total, "planning")

    def candidate(b: float) -> dict:
        cs = cycles[b]
        if any(c is None for c in cs):
            return {"beta": b, "admissible": False, "reason": "no limit cycle for some plants of the prior"}
        h = min(limits.max_h, limits.max_amplitude / max(c.amp1 for c in cs))
        periods = np.array([_TWO_PI / c.omega for c in cs])
        n_cyc = np.floor(duration / periods) - _LOST_CYCLES
        amps = np.array([h * c.amp1 for c in cs])
        omegas = np.array([c.omega for c in cs])
        row = {"beta": b, "h": h, "frequency_hz": [float(1 / periods.max()), float(1 / periods.min())],
               "amplitude": [float(amps.min()), float(amps.max())], "n_cycles": int(n_cyc.min()),
               "samples_per_period": float(rate * periods.min()), "admissible": True, "reason": ""}
        if rate * periods.min() < 8:
            row.update(admissible=False, reason=f"fewer than 8 controller samples per period at {rate:g} Hz")
        elif n_cyc.min() < _MIN_CYCLES:
            row.update(admissible=False, reason=f"fewer than {_MIN_CYCLES} stable cycles in {duration:.3g} s")
        elif float(np.max(amps * omegas)) / (rate * noise_std) < _MIN_NOISE_MARGIN:
            row.update(admissible=False, reason=f"the output moves less than {_MIN_NOISE_MARGIN:g} noise stds per "
                                                "controller tick at the switch (the relay would lock up on noise)")
        elif noise_std / float(np.exp(np.mean(np.log(amps)))) > _MAX_EPS:
            # the typical plant of the prior, not the smallest: a wide K range would refuse every test
            row.update(admissible=False, reason=f"the typical amplitude ({np.exp(np.mean(np.log(amps))):.3g}) is "
                                                f"under {1 / _MAX_EPS:g} x the sensor noise ({noise_std:.3g})")
        row["switch_gap"] = switch_gap(float(np.exp(np.mean(np.log(amps)))), b, noise_std)
        if row["admissible"] and row["switch_gap"] < _MIN_SWITCH_GAP:
            # not refused outright: with a broad prior every beta may fall short for the typical plant
            row.update(early_switch=True, reason=f"the relay would switch {row['switch_gap']:.3g} noise stds below "
                                                 "the extremum (< 16: noise may trigger it early)")
        if row["admissible"] and float(np.min(amps * omegas)) / (rate * noise_std) < _MIN_NOISE_MARGIN:
            # the prior's spread of K makes the amplitude of some plants too small for the noise
            row["reason"] = "some plants of the prior may lock up on noise (amplitude too small): narrow the K range"
        return row

    def info_of(b: float, row: dict) -> list[np.ndarray]:
        return [planned_information(Tp, p, b, row["h"], duration, rate, noise_std, cycle=c)
                for p, c in zip(plants, cycles[b])]

    rows = {b: candidate(b) for b in betas}
    admissible = [b for b in betas if rows[b]["admissible"]]
    if not admissible:
        reasons = "; ".join(sorted({rows[b]["reason"] for b in betas}))
        raise InputError(f"the limits admit no MRFT test ({reasons}): allow a larger amplitude "
                         "(--max-amplitude, --max-h) or more time (--time)")
    # Betas whose switch sits far enough below the extremum, when there are any: nearer -1 the
    # noise triggers the switch early and analyze loses the test (docs/benchmarks/plan.md)
    clear = [b for b in admissible if not rows[b].get("early_switch")]
    early_only = not clear
    admissible = clear or admissible
    infos = {b: info_of(b, rows[b]) for b in admissible}

    conv_betas = [b for b in (-0.4, -0.7) if not any(abs(f.beta - b) < 0.05 for f in flown)][:n_tests] or [-0.7]
    conv = []
    for b in conv_betas:
        cycles.setdefault(b, [_predict(Tp, p[0], p[1], p[2], b, rate) for p in plants])
        r = candidate(b)
        if r["admissible"]:
            conv.append((b, info_of(b, r)))
    conv_infos = [inf for _, inf in conv] if len(conv) == len(conv_betas) else None

    chosen: list[float] = []
    acc = list(base)
    acc_data = list(base_data)
    candidate_rows = []
    for j in range(n_tests):
        scores, std_of = {}, {}
        for b in admissible:
            covs = [_inv(A + I) for A, I in zip(acc, infos[b])]
            scores[b] = float(np.mean([_cost(c, p) for c, p in zip(covs, plants)]))
            std_of[b] = np.sqrt(np.mean([_stds(c, p) ** 2 for c, p in zip(covs, plants)], axis=0))
            if j == 0:
                s = np.median([_stds(c, p) for c, p in zip(covs, plants)], axis=0)
                rows[b]["predicted_std"] = dict(zip(_PARAMS, map(float, s)))
                rows[b]["score"] = scores[b]
        # Guard: among the candidates predicted no worse than the conventional beta for Td and tau
        # (if any is), the one with the smallest total relative variance: a user who replaces the
        # -0.4/-0.7 recipe should not lose on the delay or the drag by the plan's own model.
        pool = admissible
        if conv_infos is not None and j < len(conv_infos):
            ref = [_inv(A + I) for A, I in zip(acc, conv_infos[j])]
            ref_s = np.sqrt(np.mean([_stds(c, p) ** 2 for c, p in zip(ref, plants)], axis=0))
            safe = [b for b in admissible if np.all(std_of[b][:2] <= ref_s[:2] * (1 + 1e-9))]
            pool = safe or admissible
        best = min(pool, key=lambda b: (scores[b], b in chosen))
        chosen.append(best)
        acc = [A + I for A, I in zip(acc, infos[best])]
        acc_data = [A + I for A, I in zip(acc_data, infos[best])]
        report(progress, len(betas) * (j + 2), total, "planning")
    candidate_rows = [rows[b] for b in betas]

    def summary(accs: list[np.ndarray], q: float | tuple[float, float] = 50.0) -> dict:
        # the median over the draws: the typical plant's std. The mean (or RMS) is pulled up by the
        # draws with the slowest drag, whose Td std grows about as Td^2, so it over-forecasts most plants
        s = np.percentile([_stds(_inv(A), p) for A, p in zip(accs, plants)], q, axis=0)
        if np.ndim(q):
            return {k: (float(lo), float(hi)) for k, lo, hi in zip(_PARAMS, s[0], s[1])}
        return dict(zip(_PARAMS, map(float, s)))

    centre = np.exp(np.mean(np.log(plants), axis=0))
    tests = tuple(_test_plan(Tp, centre, b, rows[b], cycles[b], plants, duration, rate) for b in chosen)

    conventional = None
    if conv and len(conv) == len(conv_betas):
        cacc = list(base)
        cdata = list(base_data)
        for _, inf in conv:
            cacc = [A + I for A, I in zip(cacc, inf)]
            cdata = [A + I for A, I in zip(cdata, inf)]
        conventional = {"betas": [b for b, _ in conv], "predicted_std": summary(cacc),
                        "predicted_std_tests_only": summary(cdata)}

    prior_sd = np.sqrt(np.diag(_inv(prior_info)))
    prior_std = {"Td": float(prior_sd[0]), "tau": float(prior_sd[1]), "K": float(prior_sd[2] * centre[2])}
    post = summary(acc)
    notes = _notes(tests, rows, admissible, post, prior_std, limits)
    if early_only:
        notes.append(f"at every admissible beta the relay switches fewer than {_MIN_SWITCH_GAP:g} noise stds below "
                     "the extremum for the typical plant: noise may trigger switches early; allow a larger amplitude "
                     "(--max-amplitude) or narrow the K range")
    sim_std, sim_range, n_sim = {}, {}, 0
    if n_simulated > 0:
        extra = int(n_simulated) - len(plants)
        sims = plants if extra <= 0 else np.vstack(
            [plants, _conditioned_draws(Tp, prior, flown, extra, rng, rate, noise_std)])
        s = simulated_std(Tp, sims[:int(n_simulated)], flown, tests, limits, seed=seed, progress=progress)
        s = s[np.all(np.isfinite(s), axis=1)]
        n_sim = int(s.shape[0])
        if n_sim:
            sim_std = dict(zip(_PARAMS, map(float, np.median(s, axis=0))))
            lo, hi = np.percentile(s, [10.0, 90.0], axis=0)
            sim_range = {k: (float(a), float(b)) for k, a, b in zip(_PARAMS, lo, hi)}
        if n_sim < int(n_simulated):
            notes.append(f"analyze could not use the simulated flight of {int(n_simulated) - n_sim} of "
                         f"{int(n_simulated)} plants (lost or locked-up tests): the test may fail on noise")
    return PlanResult(Tp=Tp, tests=tests, predicted_std=post, predicted_std_data=summary(acc_data),
                      simulated_std=sim_std, simulated_std_range=sim_range, n_simulated=n_sim,
                      predicted_std_data_range=summary(acc_data, (10.0, 90.0)),
                      prior_std=prior_std, conventional=conventional, candidates=tuple(candidate_rows),
                      notes=tuple(notes), flown=tuple(flown), limits=limits)


def _test_plan(Tp: float, centre: np.ndarray, beta: float, row: dict, cs: list, plants: np.ndarray,
               duration: float, rate: float) -> TestPlan:
    """The recommended test, predicted with the sampled relay for the central plant."""
    h = float(row["h"])
    try:
        lc = mrft_limit_cycle(LoopModel(Tp, centre[0], centre[1], centre[2]), beta, h, rate)
        f, a, orbits = lc.frequency_hz, lc.amplitude, tuple(lc.orbits_hz)
    except InputError:
        c = _predict(Tp, centre[0], centre[1], centre[2], beta, rate)
        f, a, orbits = c.omega / _TWO_PI, h * c.amp1, ()
    tdw = np.array([p[0] * c.omega for p, c in zip(plants, cs)])
    n_c = max(int(math.floor(duration * f)) - _LOST_CYCLES, 0)
    return TestPlan(beta=float(beta), h=h, duration_s=float(duration), frequency_hz=float(f), amplitude=float(a),
                    frequency_range_hz=tuple(row["frequency_hz"]), amplitude_range=tuple(row["amplitude"]),
                    orbits_hz=orbits, n_cycles=n_c, td_omega=(float(tdw.min()), float(tdw.max())))


def _notes(tests: Sequence[TestPlan], rows: dict, admissible: Sequence[float], post: dict, prior_std: dict,
           limits: FlightLimits) -> list[str]:
    """Which parameters no admissible test pins down, and what would help."""
    notes = []
    best_tdw = min(min(t.td_omega) for t in tests)
    lowest_f = min(rows[b]["frequency_hz"][0] for b in admissible)
    helps = (f"What would help: a lower test frequency (a beta nearer 0 or positive; the lowest here is "
             f"{lowest_f:.3g} Hz), a larger amplitude or more time (more cycles), or a Td from elsewhere (a step "
             "response, a drag model)")
    if best_tdw > TD_OMEGA_LIMIT:
        notes.append(f"Td cannot be pinned down by any admissible test: Td*Omega stays above {best_tdw:.1f} (the "
                     f"frequencies hardly depend on Td above {TD_OMEGA_LIMIT:g}). " + helps)
    elif post["Td"] > 0.5 * prior_std["Td"]:
        notes.append(f"Td stays poorly determined: its predicted std is {post['Td'] / prior_std['Td']:.0%} of the "
                     f"prior's (Td*Omega up to {max(max(t.td_omega) for t in tests):.1f} over the prior). " + helps)
    if post["tau"] > 0.5 * prior_std["tau"]:
        notes.append("tau stays poorly determined: allow a larger amplitude (--max-amplitude) or more time (--time)")
    if post["K"] > 0.5 * prior_std["K"]:
        notes.append("K stays poorly determined: allow a larger amplitude or relay height")
    capped = [t for t in tests if t.h >= limits.max_h * (1 - 1e-9)]
    if capped:
        notes.append(f"the relay height is at its limit ({limits.max_h:g}) for beta "
                     f"{', '.join(f'{t.beta:g}' for t in capped)}: the amplitude is below the allowed one")
    return notes
