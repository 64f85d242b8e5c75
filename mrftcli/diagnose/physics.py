"""diagnose's one library of physics: what a model leaves out, for every family (issue 36).

Each effect has a JSON name, a plain-language explanation, the augmentation of the model it stands
for and its own parameter (name, unit). How an effect changes a model's limit cycle is the family's
strategy:

* eq. (2) (:mod:`mrftcli.diagnose.selection` with a ``soiptd`` model) simulates the cycle of the
  augmented plant (:class:`mrftcli.diagnose.limit_cycles.AugmentedPlant`, keyed by the effect's name)
  and fits the effect with Td and tau to the cycle features; its library is :data:`CANDIDATES`, which
  holds the physics of the propulsion it models (quadratic drag, thrust rectification);
* every other family (the second part of this module) writes the effect as what it does to one test's
  response points, mean balance and period scatter (:class:`OnTests`: an :class:`Action` per test, a
  grid of values to profile over); its library is :data:`EFFECTS`.

Parameterisation used by eq. (2)'s fit (all O(1) so finite differences behave): the base vector is
``[ln Td, 10 tau]``; K is eliminated in closed form (Lemma 2 of the paper: frequency and waveform
shape are invariant to K, the amplitude scales with it). Quadratic drag replaces the linear drag, so
its vector is ``[ln q, 10 tau]`` with q = c K (the limit cycle depends on c and K only through c K up
to the amplitude scale), then c = q / K.

**The families' strategy** of the library: every family but eq. (2), each effect judged held out,
on the model object.

A relay test's stable cycle is periodic, so for any linear plant each output harmonic is the plant's
response to the same harmonic of the plant's input: ``Y_k = G(j k Omega) W_k``. An effect the linear
model leaves out changes what the plant receives (``W``) or what the sensor reports, and each effect
of the library is written as what it does to one test (:class:`Action`, the effect's
:class:`OnTests`):

* ``gain``: the factor on the relay's square wave the plant receives (``(f(+h) - f(-h)) / 2h`` for a
  static input nonlinearity ``f``: a dead zone ``1 - delta / h``, a saturation ``(min(h, U) + h) / 2h``,
  a gain drifting between tests ``1 + g (t - t_mid)``);
* ``ramp``: the time ``2 h / R`` a rate-limited actuator takes between the levels (the trapezoid is
  the square wave through a box of that width: ``sinc(w D / 2) e^{-j w D / 2}`` on every harmonic);
* ``lag``: a first-order lag ``1 / (T s + 1)`` on the output (a sensor lag, or a second lag of the
  plant: the loop sees only their product, so the two are one candidate);
* ``dc``: what the nonlinearity adds to the plant input's mean over a cycle [command units] (an
  input bias, an asymmetric gain, a bias drifting between tests);
* ``jitter``: a switch-instant jitter [s] (the cycles' period scatter; their mean blurred by it,
  ``e^{-(w sigma)^2 / 2}`` on every harmonic).

Three views of a test compare the model with the recording, each exactly for a linear plant:

* the response points ``G(j k Omega) = Y_k / U_k`` (:func:`mrftcli.analyze.general.response_points`)
  divided by the action's factor, fitted by the family's identification (:func:`identify_points`):
  its chi^2, and the held-out cycle (frequency and amplitude of the model of the other tests, the
  exact LPRS limit cycle with the effect added: the relay's levels scaled by ``gain``, the ramp's
  half width added to the delay, the lag in the state space);
* the mean balance: over a periodic cycle the output's mean is ``G(0)`` times the plant input's mean
  (zero for an integrating plant), so ``mean(y) / G(0) - h (2 D - 1) - dc = 0`` with ``D`` the
  high-time fraction, a relay's bias balanced by the operating point (the analysis's assumption);
* the period scatter: a switch decided on noisy samples moves by the noise over the waveform's slope
  and by the sample time, and the period's variance is twice that; a jitter sigma in the delay
  moves each half period by ``s sigma / 2``, ``s = dP / dtau`` of the model's cycle under the
  test's relay (4 for an integrator under a hysteresis relay: the output runs on for the delay and
  must come back), so it adds ``(s sigma)^2 / 2``; the variance's likelihood on its degrees of
  freedom (as eq. (2)'s ``variance_deviance_z``) is the evidence.

Each candidate's parameter is fitted on all tests (a grid, then refined) and on every set of all but
one test; it is named only when its evidence is strong (delta BIC > :data:`BIC_THRESHOLD` over the
three views) **and** each test predicted from the others with it is closer than without
(:attr:`EffectFit.held_out_after` < :attr:`EffectFit.held_out_before`). The same code serves every
family: it uses the model object's frequency response, realisation and identification only.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import numpy as np
from scipy.optimize import minimize_scalar

from ..analyze.general import MeasuredTest, identify_points
from ..errors import IdentificationError, InputError
from ..io.logtypes import FlightLog, output_unit
from ..jsonable import finite_or_none, json_float
from ..mrft.identify_lti import LtiIdentification, ResponsePoint
from ..mrft.lprs import lti_limit_cycle
from ..mrft.model import PlantModel
from ..mrft.relays import RelayLaw

if TYPE_CHECKING:
    from .locate import MeasuredWaveform

__all__ = ["Effect", "Action", "OnTests", "LIBRARY", "CANDIDATES", "EFFECTS", "BY_NAME", "BIC_THRESHOLD", "Z_LIMIT",
           "unit_in_loop", "EffectFit", "Selection", "TestData", "as_test_data",
           "select"]

#: evidence needed to name an effect, every family: delta BIC above it ("very strong" on Kass-Raftery's scale)
BIC_THRESHOLD = 10.0
#: a difference beyond this many standard deviations (or standard errors) is a disagreement, every family
Z_LIMIT = 3.0


@dataclass(frozen=True)
class Action:
    """What an effect does to one test, the families' strategy (the module
    docstring). The defaults are no effect.

    Attributes
    ----------
    gain : float
        The factor on the relay's square wave the plant receives [-].
    ramp : float
        The time a rate-limited actuator takes between the levels [s].
    lag : float
        A first-order lag on the output [s].
    dc : float
        What the effect adds to the plant input's mean over a cycle [command units].
    jitter : float
        A switch-instant jitter [s].
    """

    gain: float = 1.0
    ramp: float = 0.0
    lag: float = 0.0
    dc: float = 0.0
    jitter: float = 0.0


@dataclass(frozen=True)
class OnTests:
    """An effect as the families' strategy fits it (this module's second part).

    Attributes
    ----------
    views : tuple of str
        Which views it changes: ``"points"``, ``"balance"``, ``"scatter"``.
    action : callable
        ``action(test, value, t_ref) -> Action``.
    grid : callable
        ``grid(tests) -> array`` of values to profile over (its no-effect value first).
    """

    views: tuple[str, ...]
    action: Callable[[TestData, float, float], Action]
    grid: Callable[[Sequence[TestData]], np.ndarray]


@dataclass(frozen=True)
class Effect:
    """One physical effect of the library.

    Attributes
    ----------
    name : str
        JSON name.
    explanation : str
        What it is and how it shows in an MRFT test, in plain words.
    augmentation : str
        The model change it stands for.
    parameter : str
        Name of its parameter in the JSON ``parameters`` object.
    unit : str
        Unit of the parameter.
    replaces_drag : bool
        The candidate replaces Td by its own parameter (quadratic drag) instead of adding one.
    stochastic : bool
        Acts on the cycle-to-cycle scatter only (delay jitter).
    on_tests : OnTests or None
        The families' strategy; None: eq. (2)'s only (the physics of its propulsion).
    """

    name: str
    explanation: str
    augmentation: str
    parameter: str
    unit: str
    replaces_drag: bool = False
    stochastic: bool = False
    on_tests: OnTests | None = None


def _static(f: Callable[[float], float]) -> Callable[[TestData], Action]:
    """A static input nonlinearity on the relay's deviation from its bias: the square wave's factor
    and the added mean (the module docstring)."""
    def act(t: TestData) -> Action:
        hi, lo = f(t.h), f(-t.h)
        return Action(gain=(hi - lo) / (2 * t.h), dc=t.duty * hi + (1 - t.duty) * lo - t.h * (2 * t.duty - 1))
    return act


def _span(tests: Sequence[TestData]) -> float:
    return max(max(t.t_mid for t in tests) - min(t.t_mid for t in tests), 1e-9)


def _w(tests: Sequence[TestData]) -> float:
    return 2 * math.pi * min(t.frequency_hz for t in tests)


def _h_max(tests: Sequence[TestData]) -> float:
    return max(t.h for t in tests)


LIBRARY: tuple[Effect, ...] = (
    Effect(
        "input_bias",
        "A constant disturbance adds to the command at the plant input (hover-thrust trim error, "
        "centre-of-gravity offset). The relay then pushes harder one way than the other: the high and "
        "low half-periods become unequal and the oscillation centre shifts.",
        "plant input = command - hover trim + d",
        "d",
        "command units",
        on_tests=OnTests(("balance",), lambda t, v, _: Action(dc=v), lambda ts: np.linspace(-0.5, 0.5, 21) * _h_max(ts)),
    ),
    Effect(
        "gain_drift",
        "The loop gain changes steadily over the flight (battery sag: the same command gives less "
        "thrust as the voltage drops). At a constant frequency the amplitude drifts with time, and "
        "since the battery scales the hover command too, the trim and the half-period balance drift.",
        "K(t) = K (1 + g t) multiplying the whole command, t from the start of the log",
        "g",
        "1/s",
        on_tests=OnTests(("points", "balance"), lambda t, v, tr: _static(lambda u: (1 + v * (t.t_mid - tr)) * u)(t),
                         lambda ts: np.linspace(-0.8, 0.8, 17) / _span(ts)),
    ),
    Effect(
        "sensor_lag",
        "The measurement passes through an extra first-order lag (a filter or state estimator). It "
        "adds phase that grows like arctan(w T) rather than linearly with frequency as a delay does, "
        "and attenuates the higher harmonics, so one delay cannot absorb it at every beta and harmonic.",
        "y_measured = y / (T_lag s + 1)",
        "T_lag",
        "s",
        on_tests=OnTests(("points",), lambda t, v, _: Action(lag=v),
                         lambda ts: np.concatenate([[0.0], np.geomspace(0.02, 3.0, 14) / _w(ts)])),
    ),
    Effect(
        "quadratic_drag",
        "Drag grows with the square of the speed instead of linearly. The damping then depends on the "
        "oscillation's speed, so the amplitude stops scaling with h, the frequency moves with h and "
        "the waveform is distorted.",
        "y'' = -c y'|y'| + K p in place of y'' = -y'/Td + K p",
        "c",
        "1/output unit",
        replaces_drag=True,
    ),
    Effect(
        "actuator_rate_limit",
        "The actuator slews at a finite rate instead of stepping: the plant sees ramps rather than "
        "relay steps. That is an extra lag of about h/R that grows with the relay height, so the "
        "frequency drops as h grows (a linear loop's frequency does not depend on h).",
        "plant input follows the delayed command at |da/dt| <= R",
        "R",
        "command units/s",
        on_tests=OnTests(("points",), lambda t, v, _: Action(ramp=2 * t.h / v if v > 0 else 0.0),
                         lambda ts: np.concatenate([[math.inf], 2 * _h_max(ts) * _w(ts) / np.geomspace(0.02, 2.0, 14)])),
    ),
    Effect(
        "asymmetric_gain",
        "The plant responds more strongly to the relay's +h than to its -h (or the reverse): thrust goes "
        "with rotor speed squared, ESC curves are not straight. The relay's two half-periods then differ "
        "by an amount that grows with h (a trim error shifts them by the same amount at every h), and "
        "the oscillation centre moves.",
        "plant input = (1 + a) u for u > 0, (1 - a) u for u < 0 (u = command - trim)",
        "a",
        "1",
        on_tests=OnTests(("balance",), lambda t, v, _: _static(lambda u: (1 + v * math.copysign(1.0, u)) * u)(t),
                         lambda ts: np.linspace(-0.5, 0.5, 21)),
    ),
    Effect(
        "actuator_saturation",
        "Trim + u is clipped at an upper limit (throttle or ESC limit), so a large relay step upwards "
        "is cut short. Only the tests whose trim + h reaches the limit change: their upper half-period "
        "lengthens and the centre drops, while the small-h tests follow the linear model.",
        "plant input = min(trim + u, U_max) - trim",
        "U_max",
        "command units",
        on_tests=OnTests(("points", "balance"), lambda t, v, _: _static(lambda u: min(u, v))(t),
                         lambda ts: np.concatenate([[_h_max(ts)], np.linspace(0.98, 0.2, 14) * _h_max(ts)])),
    ),
    Effect(
        "dead_zone",
        "A band of command around the trim gives no response (ESC dead band, stiction): the plant sees "
        "a relay of height h - delta instead of h. The amplitude then grows faster than h (it is "
        "proportional to h - delta), while the period and waveform keep the linear model's.",
        "plant input = sign(u) max(|u| - delta, 0)",
        "delta",
        "command units",
        on_tests=OnTests(("points", "balance"), lambda t, v, _: _static(lambda u: math.copysign(max(abs(u) - v, 0.0), u))(t),
                         lambda ts: np.linspace(0.0, 0.9, 15) * min(t.h for t in ts)),
    ),
    Effect(
        "thrust_rectification",
        "The propulsion lag acts on rotor speed while thrust goes with speed squared. Over a relay "
        "swing of +-h the mean thrust falls short of the mean command by an amount growing with h^2, "
        "and the thrust rises and falls along different curves. The relay makes up the deficit by "
        "staying longer at +h: the half-period balance grows in proportion to h (a trim error's "
        "falls like 1/h, an asymmetric gain's is the same at every h) and the waveform loses its symmetry.",
        "rotor speed q' = (sqrt(1 + w/F) - 1 - q)/Tp, thrust = F ((1 + q)^2 - 1) in place of p' = (w - p)/Tp",
        "F",
        "command units",
    ),
    Effect(
        "bias_drift",
        "The offset of the plant input drifts between the tests (a trim or a disturbance that changes over "
        "the recording). The relay's half-period balance and the output's mean then move from one test to "
        "the next in proportion to the time between them, while each test's cycle keeps its shape.",
        "plant input = command + b (t - t_mid), t_mid the middle of the tests",
        "b",
        "command units/s",
        on_tests=OnTests(("balance",), lambda t, v, tr: Action(dc=v * (t.t_mid - tr)),
                         lambda ts: np.linspace(-0.5, 0.5, 21) * _h_max(ts) / _span(ts)),
    ),
    Effect(
        "delay_jitter",
        "The transport delay varies randomly from one command to the next (scheduling, a "
        "non-real-time link). Each switch then lands early or late: the cycle-to-cycle period "
        "scatter exceeds what the sensor noise and the controller's sampling explain.",
        "tau_k = tau + d_k, d_k Gauss-Markov with std sigma (correlation 0.05 s)",
        "sigma",
        "s",
        stochastic=True,
        on_tests=OnTests(("points", "scatter"), lambda t, v, _: Action(jitter=v),
                         lambda ts: np.concatenate([[0.0], np.geomspace(1e-3, 0.1, 14)
                                                    / (2 * math.pi * max(t.frequency_hz for t in ts))])),
    ),
)

BY_NAME: dict[str, Effect] = {e.name: e for e in LIBRARY}
#: eq. (2)'s library, in its fitting order (the drift of a bias between tests is the families' only)
CANDIDATES: tuple[Effect, ...] = tuple(BY_NAME[n] for n in (
    "input_bias", "gain_drift", "sensor_lag", "quadratic_drag", "actuator_rate_limit", "asymmetric_gain",
    "actuator_saturation", "dead_zone", "thrust_rectification", "delay_jitter"))
#: the families' library, in its fitting order: every effect with a strategy on the tests
EFFECTS: tuple[Effect, ...] = tuple(BY_NAME[n] for n in (
    "sensor_lag", "actuator_rate_limit", "dead_zone", "actuator_saturation", "asymmetric_gain", "input_bias",
    "gain_drift", "bias_drift", "delay_jitter"))


def df_quadratic_drag(Td: float, velocity_amplitude: float) -> float:
    """Describing-function equivalent: c with the same first-harmonic damping as 1/Td at speed V.

    The first harmonic of c v|v| for v = V sin(wt) is (8 / (3 pi)) c V v, so 1/Td = 8 c V / (3 pi).
    """
    return 3.0 * math.pi / (8.0 * Td * velocity_amplitude)


def unit_in_loop(unit: str | None, loop: str) -> str | None:
    """A candidate parameter's unit with the loop's output unit spelt out, as the terminal shows it.

    Examples
    --------
    >>> unit_in_loop("1/output unit", "altitude"), unit_in_loop("command units/s", "roll")
    ('1/m', 'command units/s')
    """
    return None if unit is None else unit.replace("output unit", output_unit(loop))


# ==================================================================================================
# the families' strategy: each effect on the tests, judged held out
# ==================================================================================================
#: a named effect's held-out error must fall below this fraction of the linear model's: a small gain on
#: a few noisy tests is what a free parameter buys anyway
HELD_OUT_GAIN = 0.9
#: on top of a first effect the second must cut the held-out error by a quarter: it is the best of
#: eight tried, and a free parameter absorbs some of what the first one leaves
HELD_OUT_GAIN_SECOND = 0.75
#: the noise-only period scatter (the noise over the waveform's slope, the tick) is a reference known
#: within about a factor 2 (a sampled relay's periods follow tick patterns; measured on clean
#: recordings of bench_diagnose_families): its spread on the log scale [-]
SCATTER_MODEL_LN = math.log(2.0)


# ----------------------------------------------------------------------------------------------
# one test as the library sees it
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TestData:
    """What the library compares per test (measured from its stable cycles).

    Attributes
    ----------
    index : int
        The analysis's test number (0-based).
    t_mid : float
        The test's middle [s, log clock].
    h : float
        Half the relay's level difference [command units].
    relay : RelayLaw
        The relay a model's cycle is computed under (the effective one where there is one).
    rate_hz : float
        The relay's rate [Hz].
    points : tuple of ResponsePoint
        The test's response points.
    frequency_hz, amplitude : float
        The mean cycle's frequency [Hz] and amplitude (half its peak-to-peak) [output units].
    duty, duty_se : float
        High-time fraction D and its standard error [-].
    mean, mean_se : float
        The output's mean over the cycles (from the setpoint) and its standard error [output units].
    period_var, period_dof : float, int
        The periods' variance [s^2] and its degrees of freedom.
    noise_var : float
        The period variance the sensor noise and the sampled relay explain [s^2].
    precision : float
        The mean cycle's relative standard error, frequency and amplitude together [-].
    delay_gain : float
        dP / dtau of the model's cycle under this test's relay [-]: a switch reaching the plant late
        by d lengthens the period by about half of it times d (set by :func:`select`).
    """

    __test__ = False

    index: int
    t_mid: float
    h: float
    relay: RelayLaw
    rate_hz: float
    points: tuple[ResponsePoint, ...]
    frequency_hz: float
    amplitude: float
    duty: float
    duty_se: float
    mean: float
    mean_se: float
    period_var: float
    period_dof: int
    noise_var: float
    precision: float = 0.0
    delay_gain: float = 2.0


def _noise_std(t: np.ndarray, y: np.ndarray, t0: float, P: float, Y: np.ndarray) -> float:
    """The output's noise over one cycle: what its harmonics and a line leave [output units]."""
    k = np.arange(1, Y.size + 1)
    smooth = np.real(np.exp(1j * 2 * math.pi / P * np.outer(t - t0, k)) @ Y)
    r = y - smooth
    if r.size < 4:
        return 0.0
    r = r - np.polyval(np.polyfit(t - t0, r, 1), t - t0)
    return float(np.std(r, ddof=2))


def as_test_data(flight: FlightLog, measured: MeasuredTest, wave: MeasuredWaveform) -> TestData:
    """One usable test of :func:`mrftcli.analyze.general.measure_tests` as :class:`TestData`, its mean
    cycle ``wave`` (:func:`mrftcli.diagnose.locate.measured_waveform`) measured from the same fits.

    Raises
    ------
    InputError
        Fewer than two fitted cycles.
    """
    s, test, fits = measured.summary, measured.test, measured.fits
    if s is None or test is None or len(fits) < 2:
        raise InputError("a test needs two fitted stable cycles")
    t, y = flight.output.t, flight.output.values * test.loop_sign
    if flight.setpoint is not None:  # the error's reference: the relay decides on setpoint - output
        y = y - np.interp(t, flight.setpoint.t, flight.setpoint.values * test.loop_sign)
    P = np.array([f.period for f in fits])
    D = np.array([f.t_high / f.period for f in fits])
    means, noise, slopes = [], [], []
    for f in fits:
        i0, i1 = np.searchsorted(t, [f.t_start, f.t_start + f.period])
        means.append(float(np.mean(y[i0:i1])) if i1 > i0 else math.nan)
        noise.append(_noise_std(t[i0:i1], y[i0:i1], f.t_start, f.period, f.harmonics))
        k = np.arange(1, f.harmonics.size + 1)
        slopes.append(abs(float(np.real(np.sum(1j * k * 2 * math.pi / f.period * f.harmonics)))))
    n = len(fits)
    m = np.array(means)
    Ts = 1.0 / float(s.rate_hz)
    slope = float(np.median(slopes))
    sigma_n = float(np.median(noise))
    switch_var = (sigma_n / slope) ** 2 if slope > 0 else math.inf
    precision = math.hypot(wave.frequency_se_hz / wave.frequency_hz, wave.amplitude_se / wave.amplitude)
    return TestData(s.index, 0.5 * (s.t_start + s.t_end), s.relay.h, s.predicting_relay, float(s.rate_hz),
                    wave.points, wave.frequency_hz, wave.amplitude,
                    float(D.mean()), float(D.std(ddof=1) / math.sqrt(n)), float(np.nanmean(m)),
                    float(np.nanstd(m, ddof=1) / math.sqrt(n)), float(P.var(ddof=1)), n - 1,
                    2.0 * (switch_var + Ts * Ts / 12.0), precision)


def _on(effect: Effect) -> OnTests:
    """The effect's strategy on the tests (every effect of :data:`EFFECTS` has one)."""
    assert effect.on_tests is not None, effect.name
    return effect.on_tests


def _combine(actions: Sequence[Action]) -> Action:
    return Action(gain=float(np.prod([a.gain for a in actions])), ramp=sum(a.ramp for a in actions),
                  lag=sum(a.lag for a in actions), dc=sum(a.dc for a in actions),
                  jitter=math.sqrt(sum(a.jitter ** 2 for a in actions)))


# ----------------------------------------------------------------------------------------------
# the three views
# ----------------------------------------------------------------------------------------------
def _factor(p: ResponsePoint, a: Action) -> complex:
    """The action's factor on the plant's response at the point's frequency."""
    f = complex(a.gain)
    if a.lag > 0:
        f /= 1 + 1j * p.omega * a.lag
    if a.ramp > 0:
        x = 0.5 * p.omega * a.ramp
        f *= (math.sin(x) / x if x > 0 else 1.0) * np.exp(-1j * x)
    if a.jitter > 0:  # the cycles' mean: the plant input's transitions spread by the jitter (a Gaussian blur)
        f *= math.exp(-0.5 * (p.omega * a.jitter) ** 2)
    return f


def _corrected(test: TestData, a: Action) -> list[ResponsePoint]:
    out = []
    for p in test.points:
        f = _factor(p, a)
        if not abs(f) > 0:
            return []
        out.append(dataclasses.replace(p, gain=p.gain / abs(f), phase=p.phase - float(np.angle(f))))
    return out


def _identify(model: PlantModel, tests: Sequence[TestData], actions: Sequence[Action]) -> LtiIdentification | None:
    points = [p for t, a in zip(tests, actions) for p in _corrected(t, a)]
    try:
        return identify_points(model, points)
    except (IdentificationError, InputError, ArithmeticError):  # an interval's end beyond floats: no fit here
        return None


def _points_chi2(ident: LtiIdentification | None) -> float:
    if ident is None:
        return math.inf
    dof = 2 * len(ident.points) - sum(not e.known for e in ident.estimates)
    return 0.0 if ident.chi2_dof is None or dof < 1 else float(ident.chi2_dof) * dof


def _static_gain(model: PlantModel) -> float:
    """G(0) of the identified model [output / command]; inf for an integrating plant (its response
    doubles when the frequency halves, far below the tests')."""
    g1, g2 = np.abs(model.frequency_response(np.array([1e-9, 2e-9])))
    return math.inf if g1 > 1.5 * g2 else float(g1)


def _balance(test: TestData, a: Action, k0: float) -> tuple[float, float]:
    """The mean balance's residual and its standard error [command units] (module docstring)."""
    pred = test.h * (2 * test.duty - 1) + a.dc
    r = (test.mean / k0 if math.isfinite(k0) and k0 > 0 else 0.0) - pred
    se = math.hypot(test.mean_se / k0 if math.isfinite(k0) and k0 > 0 else 0.0, 2 * test.h * test.duty_se)
    return r, max(se, 1e-3 * test.h)


def _scatter(test: TestData, a: Action) -> float:
    """ln(recorded / predicted period variance) [-]: two independent switch delays a period, each
    moving it by half the cycle's delay gain; both floored at a tick's quantisation (Ts^2 / 12: a
    sampled relay's periods can repeat to the tick)."""
    floor = 1.0 / (12.0 * test.rate_hz ** 2)
    pred = test.noise_var + 0.5 * (test.delay_gain * a.jitter) ** 2
    return math.log((test.period_var + floor) / (pred + floor)) if math.isfinite(pred) else 0.0


def _deviance(test: TestData, a: Action) -> float:
    """The scatter's chi^2 term: ln of the variance ratio over its spread, the sample variance's (2 / dof)
    and the noise reference's own (:data:`SCATTER_MODEL_LN`)."""
    r = _scatter(test, a)
    return r * r / (2.0 / max(test.period_dof, 1) + SCATTER_MODEL_LN ** 2)


def _chi2(model: PlantModel, tests: Sequence[TestData], actions: Sequence[Action], k0: float,
          views: Sequence[str]) -> float:
    total = _points_chi2(_identify(model, tests, actions)) if "points" in views else 0.0
    if "balance" in views:
        total += sum((lambda r: (r[0] / r[1]) ** 2)(_balance(t, a, k0)) for t, a in zip(tests, actions))
    if "scatter" in views:
        total += sum(_deviance(t, a) for t, a in zip(tests, actions))
    return total


# ----------------------------------------------------------------------------------------------
# fitting and holding out
# ----------------------------------------------------------------------------------------------
def _actions(effects: Sequence[tuple[Effect, float]], tests: Sequence[TestData], t_ref: float) -> list[Action]:
    return [_combine([_on(e).action(t, v, t_ref) for e, v in effects]) for t in tests]


def _views(effects: Sequence[Effect]) -> tuple[str, ...]:
    return tuple(sorted({v for e in effects for v in _on(e).views}))


def _profile(model: PlantModel, tests: Sequence[TestData], fixed: Sequence[tuple[Effect, float]], effect: Effect,
             k0: float, t_ref: float) -> tuple[float, float]:
    """The effect's value that minimises chi^2 over ``tests`` (a grid, then refined) and that chi^2."""
    views = _views([e for e, _ in fixed] + [effect])
    grid = _on(effect).grid(tests)

    def cost(v: float) -> float:
        return _chi2(model, tests, _actions([*fixed, (effect, v)], tests, t_ref), k0, views)

    costs = np.array([cost(float(v)) for v in grid])
    i = int(np.nanargmin(np.where(np.isfinite(costs), costs, np.inf)))
    best, value = float(costs[i]), float(grid[i])
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    if i > 0 and math.isfinite(lo) and math.isfinite(hi) and lo != hi:
        r = minimize_scalar(cost, bounds=(min(lo, hi), max(lo, hi)), method="bounded",
                            options={"xatol": 1e-3 * abs(hi - lo)})
        if r.success and float(r.fun) < best:
            best, value = float(r.fun), float(r.x)
    return value, best


def _cycle(model: PlantModel, test: TestData, a: Action) -> tuple[float, float] | None:
    """The (frequency [Hz], amplitude [output units]) of ``model`` with the action under the test's relay.

    The continuous cycle with half a sample more delay (the centre of a sampled relay's band, as
    :func:`mrftcli.mrft.lprs.mrft_limit_cycle` starts from); a lag extends the realisation. A ramp
    of width D is the box filter ``(1 - e^{-sD}) / (sD)``: its phase is a delay D / 2, its gain
    ``sinc(w D / 2)``, here a lag ``D / sqrt(12)`` (the same gain to second order in w D) with the
    delay shortened by it (the same phase to first order).
    """
    ss = model.realisation()
    A, B, C = np.asarray(ss.A, float), np.asarray(ss.B, float).ravel(), np.asarray(ss.C, float).ravel()
    ramp_lag = a.ramp / math.sqrt(12.0)
    for T in (a.lag, ramp_lag):
        if T > 0:
            n = A.shape[0]
            A = np.block([[A, np.zeros((n, 1))], [C[None, :] / T, -np.ones((1, 1)) / T]])
            B, C = np.append(B, 0.0), np.append(np.zeros(n), 1.0)
    relay = test.relay
    tau = model.delay + 0.5 / test.rate_hz + 0.5 * a.ramp - ramp_lag
    h = relay.h * a.gain
    gain = model.parameters.get("K")  # a declared structure may hold its gain in the expression
    if not h > 0 or (gain is not None and gain.value <= 0):
        return None
    try:
        lc = lti_limit_cycle(A, B, C, tau, relay.beta, h, None, eps=relay.eps)
    except (InputError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None
    return lc.frequency_hz, lc.amplitude


def _ac_error(test: TestData, cycle: tuple[float, float] | None) -> float:
    """The held-out cycle's relative error: sqrt(frequency^2 + amplitude^2) [-]; 1 without a cycle."""
    if cycle is None:
        return 1.0
    return math.hypot(test.frequency_hz / cycle[0] - 1.0, test.amplitude / cycle[1] - 1.0)


def _held_out_errors(model: PlantModel, tests: Sequence[TestData], effects: Sequence[tuple[Effect, float]],
                     free: Sequence[Effect], k0: float, t_ref: float, views: Sequence[str]) -> list[float]:
    """Each test predicted from the others (the ``free`` effects refitted on them): its error over the
    views (points: the cycle's relative error; balance: the residual over h; scatter: ln of the
    variance ratio), RMS over the views."""
    out = []
    for i, test in enumerate(tests):
        others = [t for j, t in enumerate(tests) if j != i]
        fitted = [(e, v) for e, v in effects if e not in free]
        for e in free:
            v, _ = _profile(model, others, fitted, e, k0, t_ref) if others else (_on(e).grid(tests)[0], 0.0)
            fitted.append((e, v))
        a_i = _actions(fitted, [test], t_ref)[0]
        errs = []
        if "points" in views:
            ident = _identify(model, others, _actions(fitted, others, t_ref)) if others else None
            errs.append(_ac_error(test, None if ident is None else _cycle(ident.model, test, a_i)))
        if "balance" in views:
            errs.append(_balance(test, a_i, k0)[0] / test.h)
        if "scatter" in views:
            errs.append(_scatter(test, a_i))
        out.append(math.sqrt(sum(e * e for e in errs) / max(len(errs), 1)))
    return out


# ----------------------------------------------------------------------------------------------
# the candidates' rows and the selection
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class EffectFit:
    """One candidate (or a second one on top of ``with_``) fitted and held out.

    Attributes
    ----------
    name, parameter, unit : str
        The effect and its parameter.
    value : float
        Fitted on all tests [unit].
    delta_bic : float
        BIC without it minus with it (one parameter more).
    held_out_before, held_out_after : float
        RMS over the tests of each test's error predicted from the others, without and with the
        effect (refitted on the others) [-], over the views it changes.
    per_test_before, per_test_after : tuple of float
        The same per test.
    views : tuple of str
        The views it changes.
    with_ : str
        The effect already kept it was fitted on top of, or ``""``.
    floor : float
        The smallest value told from the recording's own limits (a jitter: half the slowest relay's
        tick, below which the tick's quantisation makes the same scatter) [unit].
    refit : mapping of str to float
        The family's parameters identified from all tests' response points with the effect (and
        ``with_``) taken out [their units]; empty when the effect leaves the points alone.
    """

    name: str
    parameter: str
    unit: str
    value: float
    delta_bic: float
    held_out_before: float
    held_out_after: float
    per_test_before: tuple[float, ...]
    per_test_after: tuple[float, ...]
    views: tuple[str, ...]
    with_: str = ""
    floor: float = 0.0
    refit: Mapping[str, float] = dataclasses.field(default_factory=dict)

    @property
    def found(self) -> bool:
        """Strong evidence and a clearly better held-out prediction (by :data:`HELD_OUT_GAIN` at least;
        :data:`HELD_OUT_GAIN_SECOND` on top of a first effect)."""
        gain = HELD_OUT_GAIN_SECOND if self.with_ else HELD_OUT_GAIN
        return (self.delta_bic > BIC_THRESHOLD and self.held_out_after < gain * self.held_out_before
                and abs(self.value) >= self.floor)

    @property
    def held_out_errors(self) -> tuple[float, float]:
        """:attr:`held_out_before`, :attr:`held_out_after` (as eq. (2)'s rows show theirs)."""
        return self.held_out_before, self.held_out_after

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "parameter": self.parameter, "unit": self.unit, "value": finite_or_none(self.value),
                "delta_bic": finite_or_none(self.delta_bic), "held_out_before": finite_or_none(self.held_out_before),
                "held_out_after": finite_or_none(self.held_out_after),
                "per_test_before": [finite_or_none(x) for x in self.per_test_before],
                "per_test_after": [finite_or_none(x) for x in self.per_test_after], "views": list(self.views),
                "with": self.with_, "found": self.found, "floor": self.floor, "refit": {k: finite_or_none(v) for k, v in self.refit.items()}}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> EffectFit:
        num = json_float  # null (a NaN written out): NaN
        return cls(str(d["name"]), str(d["parameter"]), str(d["unit"]), num(d["value"]), num(d["delta_bic"]),
                   num(d["held_out_before"]), num(d["held_out_after"]),
                   tuple(num(x) for x in d.get("per_test_before", [])),
                   tuple(num(x) for x in d.get("per_test_after", [])), tuple(str(v) for v in d.get("views", [])),
                   str(d.get("with", "")), float(d.get("floor", 0.0)),
                   {str(k): num(v) for k, v in d.get("refit", {}).items()})


def _fit_one(model: PlantModel, tests: Sequence[TestData], kept: Sequence[tuple[Effect, float]], effect: Effect,
             k0: float, t_ref: float, with_: str) -> EffectFit:
    views = _views([effect])
    base_views = _views([e for e, _ in kept] + [effect])
    base = _chi2(model, tests, _actions(kept, tests, t_ref), k0, base_views)
    value, chi2 = _profile(model, tests, kept, effect, k0, t_ref)
    n_obs = sum(2 * len(t.points) for t in tests) if "points" in base_views else 0
    n_obs += len(tests) * (("balance" in base_views) + ("scatter" in base_views))
    dbic = base - chi2 - math.log(max(n_obs, 2))
    before = _held_out_errors(model, tests, kept, [], k0, t_ref, views)
    after = _held_out_errors(model, tests, [*kept, (effect, value)], [effect], k0, t_ref, views)
    ident = _identify(model, tests, _actions([*kept, (effect, value)], tests, t_ref))
    refit = {} if ident is None or "points" not in base_views else {e.name: e.value for e in ident.estimates}
    floor = max(0.5 / t.rate_hz for t in tests) if effect.name == "delay_jitter" else 0.0
    unit = "-" if effect.unit == "1" else effect.unit  # a ratio, as the terminal spells it
    return EffectFit(effect.name, effect.parameter, unit, value, dbic, _rms(before), _rms(after),
                     tuple(before), tuple(after), views, with_, floor, refit)


def _rms(xs: Sequence[float]) -> float:
    return math.sqrt(sum(x * x for x in xs) / len(xs))


@dataclass(frozen=True)
class _Prepared:
    tests: list[TestData]  # with their delay gains
    k0: float  # G(0) of the model of all tests [output / command]
    t_ref: float  # the tests' middle [s, log clock]


def _prepare(model: PlantModel, tests: Sequence[TestData]) -> _Prepared:
    base = _identify(model, tests, [Action()] * len(tests))
    k0 = _static_gain(base.model) if base is not None else math.inf
    if base is not None:
        tests = [dataclasses.replace(t, delay_gain=_delay_gain(base.model, t)) for t in tests]
    return _Prepared(list(tests), k0, 0.5 * (min(t.t_mid for t in tests) + max(t.t_mid for t in tests)))


def _rows(model: PlantModel, prep: _Prepared, kept: Sequence[tuple[Effect, float]]) -> list[EffectFit]:
    with_ = "+".join(e.name for e, _ in kept)
    return [_fit_one(model, prep.tests, kept, e, prep.k0, prep.t_ref, with_) for e in EFFECTS
            if e not in [k for k, _ in kept]]


def _delay_gain(model: PlantModel, test: TestData) -> float:
    """dP / dtau of the model's cycle under the test's relay [-] (central difference; 2 without a cycle)."""
    step = 0.02 / (2 * math.pi * test.frequency_hz)
    if "tau" not in model.parameters:  # a declared structure without a delay: its cycle's gain is not needed
        return 2.0
    lo = _cycle(model.with_parameters(tau=max(model.delay - step, 0.0)), test, Action())
    hi = _cycle(model.with_parameters(tau=model.delay + step), test, Action())
    if lo is None or hi is None:
        return 2.0
    return float((1 / hi[0] - 1 / lo[0]) / (model.delay + step - max(model.delay - step, 0.0)))


@dataclass(frozen=True)
class Selection:
    """The library's outcome on one recording (:func:`select`).

    Attributes
    ----------
    rows : list of EffectFit
        Every candidate alone, then on top of the first one found.
    found : list of EffectFit
        The effects named, in order.
    cycle_error_left : float
        RMS over the tests of each test's cycle (frequency, amplitude) predicted from the others with
        the effects named, relative [-] (NaN when none was named: nothing reads it then).
    cycle_precision : float
        RMS over the tests of the cycles' own relative standard error (frequency, amplitude) [-]: what
        the recording's scatter explains of the error left.
    """

    rows: list[EffectFit]
    found: list[EffectFit]
    cycle_error_left: float
    cycle_precision: float


def select(model: PlantModel, tests: Sequence[TestData]) -> Selection:
    """The candidates alone, then a second on top of the best one found (forward selection), and the
    held-out cycle error the effects found leave."""
    precision = math.sqrt(sum(t.precision ** 2 for t in tests) / max(len(tests), 1))
    if len(tests) < 2:
        return Selection([], [], math.nan, precision)
    prep = _prepare(model, tests)
    rows = _rows(model, prep, [])
    found = sorted((r for r in rows if r.found), key=lambda r: -r.delta_bic)[:1]
    if found:
        second = _rows(model, prep, [(BY_NAME[found[0].name], found[0].value)])
        rows += second
        found += sorted((r for r in second if r.found), key=lambda r: -r.delta_bic)[:1]
    if not found:  # what the effects found leave is read only when they found something
        return Selection(rows, found, math.nan, precision)
    kept = [(BY_NAME[f.name], f.value) for f in found]
    left = _held_out_errors(model, prep.tests, kept, [], prep.k0, prep.t_ref, ("points",))
    return Selection(rows, found, _rms(left), precision)
