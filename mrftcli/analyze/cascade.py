"""One outer loop (x, y) through its closed inner loop: ``analyze LOG --loop x|y --inner-model R --inner-gains G``.

Stages, each returning a frozen record:

1. the inner loop (:func:`inner_loop_of`): the inner analysis' eq. (2) model and the controller
   flying it (the gains file's entry for the inner loop: roll for y, pitch for x), and draws of it
   over the inner analysis' uncertainty (:func:`inner_draws`);
2. screen (:func:`mrftcli.analyze.screen.screen_tests`, ``eq2=False``): the outer tests found in the log, those with too few stable
   cycles or whose output does not follow the relay left out (the eq. (2)-specific phase checks do
   not apply to the cascade);
3. the measurements (:func:`outer_levels`): each test's frequencies and amplitudes, and its output
   at the relay's switches (which places the fractional delay between ticks, and needs no beta);
4. identification (:func:`mrftcli.mrft.identify.identify`, the cascade's strategy) through the exact sampled
   orbits of the cascade.

The result is the one analysis record (:class:`~mrftcli.analyze.record.AnalysisResult`, kind
``"cascade"``), versioned JSON (``analyze --json``) with the cascade model (family ``"cascade"``, read
back by :func:`mrftcli.mrft.model.model_from_json`).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import InputError, SegmentationError
from ..io.logtypes import FlightLog
from ..mrft.cascade import STANDARD_GRAVITY, CascadeModel, InnerLoop
from ..mrft.controller import Controller
from ..mrft.cascade_identify import CascadeIdentification
from ..mrft.identify import TestMeasurement, identify
from ..segment import segment
from ..segment.records import MrftTest
from ..segment.relay_type import infer_relay
from .options import AnalyzeOptions, CascadeOptions
from .record import AnalysisResult, analysis_controller_rate
from .screen import log_start, screen_tests

__all__ = ["analyze_cascade", "cascade_model", "inner_loop_of", "inner_draws", "inner_gains_of", "outer_levels",
           "OUTER_COMMANDS"]

#: what the outer relay commands -> K of the cascade (None: identified)
OUTER_COMMANDS: dict[str, float | None] = {"acceleration": 1.0, "attitude": STANDARD_GRAVITY, "identify": None}


# ----------------------------------------------------------------------------------------------
# stage 1: the inner loop
# ----------------------------------------------------------------------------------------------
def inner_gains_of(data: Any, inner_name: str) -> Controller:
    """The inner loop's controller from a gains file's JSON.

    Accepted: ``{"roll": {"Kp", "Ki", "Kd", "Tf", "rate_hz"}, ...}`` (a map of loop names); the
    output of ``tune --export generic`` (one controller, ``Kp`` ... at the top); ``tune --json``
    (its ``export.generic``, checked against its ``loop``); a vehicle record (``loops.<name>.gains.generic``).

    Raises
    ------
    InputError
        Not an object, no gains for ``inner_name``, or a stack's rate filter that runs at the gains'
        rate (the cascade closes the inner loop with Tf's first-order filter only: the filter would be
        a silent default; the message names --inner-gains).
    """
    what = f"--inner-gains ({inner_name})"
    c = Controller.from_json(_gains_entry(data, inner_name), what)
    if c.rate_filter is not None and c.rate_filter.active(c.rate_hz):
        f = c.rate_filter
        raise InputError(f"{what}: the cascade does not model a stack's rate filter (rate_filter {f.parameter or 'cutoff'} "
                         f"{f.cutoff_hz:g} Hz at {c.rate_hz:g} Hz; its inner derivative runs through Tf only): remove "
                         "'rate_filter' and give Tf [s] for the derivative's filter, or a cutoff of 0 if it is off")
    return c


def _gains_entry(data: Any, inner_name: str) -> Any:
    """The JSON of ``inner_name``'s controller in a gains file (:func:`inner_gains_of`'s forms)."""
    if not isinstance(data, Mapping):
        raise InputError(f"--inner-gains: expected a JSON object, got {type(data).__name__}")
    if "Kp" in data:  # tune --export generic: one controller
        return data
    export = data.get("export")
    if isinstance(export, Mapping) and "generic" in export:  # tune --json
        loop = data.get("loop")
        if loop and loop != inner_name:
            raise InputError(f"--inner-gains holds gains of the {loop} loop; the outer loop goes through {inner_name}")
        return export["generic"]
    loops = data.get("loops")
    if isinstance(loops, Mapping):  # a vehicle record
        entry = loops.get(inner_name)
        gains = entry.get("gains") if isinstance(entry, Mapping) else None
        if isinstance(gains, Mapping) and "generic" in gains:
            return gains["generic"]
    if inner_name not in data:
        raise InputError(f"--inner-gains has no gains for the {inner_name} loop (found: "
                         f"{', '.join(map(str, data)) or 'nothing'}); give {{\"{inner_name}\": {{\"Kp\": ..., \"Ki\": ..., "
                         "\"Kd\": ..., \"Tf\": ..., \"rate_hz\": ...}}")
    return data[inner_name]


def inner_loop_of(result: AnalysisResult, controller: Controller, inner_name: str) -> InnerLoop:
    """The inner loop of an inner analysis (its eq. (2) point estimate) and its controller.

    Raises
    ------
    InputError
        The analysis is of another loop than ``inner_name`` (the message names --inner-model).
    """
    if result.loop and result.loop != inner_name:
        raise InputError(f"--inner-model is an analysis of the {result.loop} loop; the outer loop goes through "
                         f"{inner_name} (analyze the {inner_name} tests and pass that result)")
    std = tuple((name, float(est.std)) for name, est in (("Td", result.Td), ("tau", result.tau), ("K", result.K))
                if math.isfinite(est.std) and est.std > 0)
    lead = min(float(result.model.tau), 0.0)  # eq. (2)'s lead: the sampled inner loop takes it as 0 (stated)
    return InnerLoop(result.model.with_parameters(tau=max(result.model.tau, 0.0)), controller, inner_name, std, lead)


def inner_draws(result: AnalysisResult, inner: InnerLoop, n: int, seed: int = 0) -> list[InnerLoop]:
    """``n`` draws of the inner loop over its std (:meth:`~mrftcli.mrft.cascade.InnerLoop.draw`; Tp known).

    Td and K are drawn log-normal, tau normal (kept >= 0), independently: the analysis JSON keeps
    their spreads, not their correlation. ``result`` is the inner analysis (its std, when ``inner``
    carries none).
    """
    if n <= 0:
        return []
    if not inner.std:
        inner = inner_loop_of(result, inner.controller, inner.loop or result.loop)
    rng = np.random.default_rng(seed)
    return [inner.draw(rng) for _ in range(n)]


# ----------------------------------------------------------------------------------------------
# stage 2: the outer tests
# ----------------------------------------------------------------------------------------------
def _measurement(t: MrftTest) -> TestMeasurement:
    """The test's per-cycle frequencies and amplitudes at its nominal beta.

    The exact sampled cycle holds the sampling lag itself, so the effective beta (measured at the
    switches, lag included) would count it twice (a bias of about half a tick in tau): without a
    logged beta, the measured level less the sampling lag's
    (:func:`mrftcli.segment.relay_type.infer_relay`).
    """
    beta = t.beta_nominal if t.beta_nominal is not None else infer_relay(t, kind="mrft").beta
    st = t.stable
    return TestMeasurement(beta=float(beta),
                           frequency_hz=[c.frequency_hz for c in st], amplitude=[c.amplitude for c in st], h=float(t.h))


def outer_levels(tests: Sequence[MrftTest], rate_hz: float) -> list[tuple[float, float]] | None:
    """Each test's output at the relay's switches over its amplitude [-] and its standard error.

    The level at the switches places the orbit's switching sample against the delay continuously,
    where the band of orbits moves by whole ticks (half a tick is 5 ms at 100 Hz); and it needs no
    beta, which a log without one (HEAR's) would give only as the level less an average half tick
    of sampling lag, a few thousandths off on a locked orbit (5-9 ms of tau at beta -0.7). None
    when a test has no level or its command is logged below the relay's rate (its switch
    instants are then off by up to a logging period).
    """
    out = []
    for t in tests:
        # the mean over the cycles, as the frequency's: a loop wandering between orbits has a level per orbit
        levels = np.array([c.beta_effective for c in t.stable], dtype=float)
        levels = levels[np.isfinite(levels)]
        if not (levels.size and t.rate_hz >= 0.9 * rate_hz):
            return None
        se = float(np.std(levels, ddof=1) / math.sqrt(levels.size)) if levels.size > 1 else math.nan
        out.append((float(np.mean(levels)), se))
    return out


# ----------------------------------------------------------------------------------------------
# the driver
# ----------------------------------------------------------------------------------------------
def cascade_model(inner: InnerLoop, commanded: str = "acceleration") -> CascadeModel:
    """The cascade to identify: ``inner`` closed, K known from what the outer relay commands (set E).

    ``commanded`` is ``"acceleration"`` (K = 1), ``"attitude"`` (K = g) or ``"identify"`` (K unknown);
    Td and tau get placeholders that identification ignores; their set I is
    :data:`~mrftcli.mrft.cascade_identify.TD_BOUNDS`, :data:`~mrftcli.mrft.cascade_identify.TAU_BOUNDS` unless the model's ``ranges`` narrow them.

    Raises
    ------
    InputError
        An unknown ``commanded`` (naming ``--outer-command``).
    """
    if commanded not in OUTER_COMMANDS:
        raise InputError(f"--outer-command must be one of {', '.join(OUTER_COMMANDS)}, got {commanded!r}")
    K = OUTER_COMMANDS[commanded]
    return CascadeModel(inner, 1.0, 0.0, 1.0 if K is None else K,
                        known=frozenset() if K is None else frozenset({"K"}))


def analyze_cascade(flight: FlightLog, model: CascadeModel, options: AnalyzeOptions) -> AnalysisResult:
    """The outer loop of ``flight`` identified through ``model.inner`` (the module docstring's stages): the
    cascade family's strategy of :func:`mrftcli.analyze.analyze_flight`.

    Parameters
    ----------
    flight : FlightLog
        The outer loop's signals (command: the outer relay's output; output: the position [m]).
    model : CascadeModel
        The inner loop's model and controller (:func:`inner_loop_of`) and the outer set E (K known or
        not: :func:`cascade_model`) and set I (``ranges`` of Td, tau).
    options : AnalyzeOptions
        ``min_stable_cycles`` and ``cascade``: the inner loop's draws (:func:`inner_draws`; empty: the
        inner model taken as exact), the caller's assumptions (stated first) and the sources' wording.

    Raises
    ------
    SegmentationError
        No usable outer test.
    IdentificationError
        The tests do not determine the unknowns.
    InputError
        The outer rate does not divide the inner controller's rate.
    """
    c, inner = options.cascade, model.inner
    t0 = log_start(flight)
    found = segment(flight, controller_rate_hz=flight.timing.controller_rate_hz)
    reasons = screen_tests(found, options.min_stable_cycles, eq2=False)
    usable = tuple(t for t in found if t.index not in reasons)
    rejected = tuple(t for t in found if t.index in reasons)
    if not usable:
        why = "; ".join(f"test {i + 1}: {r}" for i, r in reasons.items())
        raise SegmentationError(f"{flight.path}: no usable {flight.loop} relay test for the cascade"
                                + (f" ({why})" if why else " (no relay switching found on the command)"))
    rate = analysis_controller_rate(flight.timing.controller_rate_hz, [t.rate_hz for t in usable])
    if rate is None:
        raise InputError("the outer loop's controller rate is unknown: give --controller-rate HZ")
    rate = _snap_rate(rate, inner.controller.rate_hz)
    jitter = float(flight.timing.timing_jitter_s or 0.0) if flight.timing.stamps == "receive" else 0.0
    ident = identify([_measurement(t) for t in usable], model, rate_hz=rate, inner_draws=c.draws,
                     switch_levels=outer_levels(usable, rate), tau_timing_std=jitter)
    stated = list(c.assumptions) + _assumptions(model, c, rate, ident)
    if jitter >= 1e-4:
        stated.append(f"receive-time stamps: {jitter * 1e3:.1f} ms of timing jitter between topics is folded into "
                      "tau's interval")
    warnings = [f"test {t.index + 1} left out: {reasons[t.index]}" for t in rejected]
    warnings += _fit_warnings(ident)
    warnings += list(flight.warnings)
    return AnalysisResult(flight.path, flight.loop, ident.model, usable, ident, ident.parameters,
                          rejected=rejected, rejection_reasons=reasons, warnings=tuple(warnings),
                          t0=t0, flight=flight, controller_rate_hz=rate, assumptions=tuple(stated))


def _snap_rate(rate: float, inner_rate: float) -> float:
    """The outer rate as the inner rate over a whole number when the log's rate is within 2 % of one.

    A rate measured from stamps (199.7 Hz) is the controller's 200 Hz; a rate that is not close to a
    divisor of the inner controller's is a mismatch (one-line error naming both options).
    """
    m = inner_rate / rate
    if round(m) >= 1 and abs(m - round(m)) < 0.02 * round(m):
        return inner_rate / round(m)
    raise InputError(f"the outer loop runs at {rate:g} Hz but the inner gains' rate_hz is {inner_rate:g} Hz: the outer "
                     "rate must equal it or divide it (check --inner-gains rate_hz and --controller-rate)")


def _assumptions(model: CascadeModel, options: CascadeOptions, rate: float,
                 ident: CascadeIdentification) -> list[str]:
    if "K" not in model.known:
        what = "K identified from the tests (--outer-command identify)"
    elif model.K == STANDARD_GRAVITY:
        what = f"the outer relay commands an attitude [rad]: K = g = {STANDARD_GRAVITY} m/s^2 per rad (--outer-command)"
    else:
        what = f"the outer relay commands an acceleration [m/s^2]: K = {model.K:g} (--outer-command)"
    inner = model.inner
    c = inner.controller
    p = inner.plant.parameters
    plant = ", ".join(f"{n} {q.value:.4g}{' ' + q.unit if q.unit == 's' else ''}" for n, q in p.items())
    out = [what,
           f"inner loop {inner.loop}: {inner.plant.family} {plant} ({options.inner_source}), flown by Kp {c.Kp:.4g}, "
           f"Ki {c.Ki:.4g}, Kd {c.Kd:.4g}, Tf {c.Tf * 1e3:.3g} ms at {c.rate_hz:g} Hz ({options.gains_source})",
           f"outer relay at {rate:g} Hz"]
    if inner.lead_s < 0:
        out.append(f"the inner analysis identified a lead (tau = {inner.lead_s * 1e3:.3g} ms < 0), taken as tau = 0: the "
                   "cascade samples the inner loop through a delay line, which holds no lead (a little more lag)")
    if ident.inner_draws:
        out.append(f"the inner model's uncertainty: {ident.inner_draws} draws solved and added to the intervals")
    else:
        out.append("the inner model taken as exact (no draws): the intervals hold the outer tests' scatter only")
    return out


def _fit_warnings(ident: CascadeIdentification) -> list[str]:
    out = []
    for i, t in enumerate(ident.tests):
        lo, hi = t.band_hz
        if math.isfinite(lo) and not (0.97 * lo <= t.frequency_hz <= 1.03 * hi):
            out.append(f"test {i + 1}: measured {t.frequency_hz:.4g} Hz, outside the identified cascade's band of "
                       f"sampled orbits {lo:.4g}-{hi:.4g} Hz: the inner model or gains may not be those flown")
    for name, e in ident.parameters.items():
        if not e.known and not e.determined:
            out.append(f"{name} is not determined by these tests (95 % interval {e.ci95_low:.4g}-{e.ci95_high:.4g} "
                       f"{e.unit}): add a test at another beta")
    return out

