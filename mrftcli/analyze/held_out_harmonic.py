"""eq. (2)'s held-out route on response points: each test predicted from the other tests' fundamentals and 3rd harmonics.

``analyze --tp`` identifies the reported model from the tests' mean frequencies and amplitudes (the paper's
UFM/UGM, :mod:`mrftcli.analyze.estimate`). Its held-out check (``tests[i].held_out``) is this route (issue 41):
for each test, eq. (2) at the known Tp is fitted to the *other* tests' response points, the fundamental and
the 3rd harmonic of every stable cycle, ``G(j k Omega) = Y_k / U_k`` (:func:`mrftcli.analyze.general.
response_points`, the harmonics' standard errors floored at 3 % as :func:`~mrftcli.analyze.general.
identify_points` floors them), and the test's cycle is that model's exact limit cycle under its effective relay
(:func:`~mrftcli.analyze.smooth_cycle.predicted_cycle`, sampled at the test's rate). The 3rd harmonic is a
second frequency per test: the other tests then pin Td and tau without extrapolating from two fundamentals
(ArduPilot SITL's roll and pitch: 27 -> 42 of 78 within 5 %, docs/benchmarks/sitl.md). The 5th is left out:
an estimator's lag bends it (EKF3's altitude) and it is the most precise point there.

The prediction's standard deviation is the fit's own: the Gauss-Newton covariance of its parameters
(:func:`~mrftcli.mrft.identify_lti.fit_covariance`, inflated by the reduced chi-square where the points disagree)
propagated linearly through the predicted cycle (forward differences of the continuous relay's cycle, in
log terms); ``*_sigma`` is that and the test's own
standard error of its mean in quadrature, as for the fundamentals' route (:class:`~mrftcli.analyze.held_out.
HeldOut`). The harmonics are used only where the other tests' points are one eq. (2) plant: where their fit's
chi-square exceeds its 99th percentile, a harmonic carries what eq. (2) leaves out (an estimator's lag: EKF2's
altitude on PX4 SIH, where the fitted harmonics moved 7 of 63 held-out tests beyond 5 %), and the fundamentals'
route is kept. A parameter the points determine only loosely (e.g. Td where Td Omega >> 1) widens it as much as
it moves the cycle. Where the fit is flat along some direction, ends on a bound of a parameter's range (where its
covariance does not hold), or the test has no measured relay, the fundamentals' point solve
(:func:`~mrftcli.analyze.held_out.held_out_eq2`) is kept, and its note says so. The fit admits the lead the reported
tau does (down to :func:`~mrftcli.mrft.model.lead_floor`): held at tau >= 0 it ended on tau = 0 on PX4 SIH's
EKF2 attitude (a -3 to -4 ms lead) and predicted those cycles up to 11 % off.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from scipy.stats import chi2

from ..errors import IdentificationError, InputError
from ..io.logtypes import FlightLog
from ..mrft.identify_lti import ResponsePoint, fit_covariance
from ..mrft.model import LoopModel, PlantModel, lead_floor
from ..mrft.sem import mean_sem
from ..segment.records import MrftTest
from .general import identify_points, measure_test
from .held_out import ROUTE_POINTS, HeldOut
from .options import RelayOptions
from .record import TestSummary
from .smooth_cycle import predicted_cycle

__all__ = ["held_out_harmonic", "HELD_OUT_HARMONICS", "ROUTE_NOTE", "route_note", "FALLBACK_WORDS", "FEW_DOF_WORDS", "SCALED_FEW_DOF_WORDS"]

#: the harmonics each other test contributes to the held-out fit
HELD_OUT_HARMONICS = (1, 3)
#: the analysis note naming the held-out route, ``{source}`` where the reported parameters come from
_ROUTE_TEMPLATE = ("held out: each test predicted by eq. (2) fitted to the other tests' fundamental and 3rd-harmonic "
                   "response points (its std from that fit's covariance); the reported model is identified from "
                   "{source}, so the held-out checks the structure and the tests, not that exact procedure")
#: the note when the reported model is the UFM's (the tests' fundamentals)
ROUTE_NOTE = _ROUTE_TEMPLATE.format(source="the tests' fundamentals (UFM/UGM)")


def route_note(refined: bool) -> str:
    """The analysis note naming the held-out route, worded from where the reported parameters come from:
    ``refined`` True when they are the waveform refinement's (:data:`ROUTE_NOTE` otherwise)."""
    if not refined:
        return ROUTE_NOTE
    return _ROUTE_TEMPLATE.format(source="the waveform refinement (output error on the tests' windows)")


#: how the note of a test predicted by the fundamentals' point solve begins
FALLBACK_WORDS = "from the other tests' fundamentals only"
#: the note of a prediction whose fit has too few degrees of freedom to check its std against the points' scatter
#: (worded without a pronoun for the prediction: held_out_notes joins one test's note and several tests')
FEW_DOF_WORDS = ("std from the other tests' stated errors alone: their fit has too few figures beyond its "
                 "parameters to scale the std by their scatter")
#: the note of such a prediction whose fit misses its points by more than their stated errors: the std is scaled by
#: a scatter seen on too few figures to estimate it
SCALED_FEW_DOF_WORDS = ("std scaled by the other tests' scatter seen on too few figures beyond their fit's "
                        "parameters to estimate it")

_Prediction = tuple[float, float]
#: the points' fit is used only where they are one eq. (2) plant at this significance (chi-square test)
_CONSISTENT_P = 0.01


def held_out_harmonic(flight: FlightLog, model: LoopModel, tests: Sequence[MrftTest],
                      fundamentals: Sequence[HeldOut], min_stable_cycles: int = 3) -> tuple[HeldOut, ...]:
    """Each test's cycle predicted by eq. (2) fitted to the other tests' response points (module docstring).

    Parameters
    ----------
    flight : FlightLog
        The log the tests were segmented from (their output samples).
    model : LoopModel
        Eq. (2) with its known Tp [s].
    tests : sequence of MrftTest
        The usable tests.
    fundamentals : sequence of HeldOut
        The fundamentals' route (:func:`~mrftcli.analyze.held_out.held_out_eq2`), one per test: kept where this
        route has no prediction.
    min_stable_cycles : int
        As the screening's (a test is measured as :func:`~mrftcli.analyze.general.measure_test` does).

    Returns
    -------
    tuple of HeldOut
        One per test, in ``tests``' order.
    """
    if len(tests) < 2:
        return tuple(fundamentals)
    measured = [measure_test(flight, t, RelayOptions(), min_stable_cycles) for t in tests]
    points = [p for m in measured for p in m.points if p.harmonic in HELD_OUT_HARMONICS]
    out = []
    for t, m, fallback in zip(tests, measured, fundamentals):
        got = None
        if m.summary is not None and m.fits:
            got = _predict(model, m.summary, [p for p in points if p.test != t.index],
                           min(f.harmonics.size for f in m.fits))
        if isinstance(got, tuple):
            centre, spread, note = got
            measured_t = (t.frequency_hz_mean, mean_sem(t.frequency_hz), t.amplitude_mean, mean_sem(t.amplitude))
            out.append(HeldOut.against(*centre, measured_t, spread, note, ROUTE_POINTS))
        else:
            why = got or "this test's relay was not measured on its cycles"
            out.append(_fallback(fallback, why))
    return tuple(out)


def _fallback(ho: HeldOut, why: str) -> HeldOut:
    """The fundamentals' prediction, its note saying why the response points gave none."""
    if ho.frequency_hz is None:
        return ho
    note = f"{FALLBACK_WORDS} ({why})"
    return dataclasses.replace(ho, note="; ".join(filter(None, [note, ho.note])))


def _predict(model: LoopModel, test: TestSummary, points: Sequence[ResponsePoint],
             n_h: int) -> tuple[_Prediction, _Prediction, str] | str:
    """The test's (frequency [Hz], amplitude), their std from the fit to ``points`` and a note qualifying the std
    (``""``, :data:`FEW_DOF_WORDS` or :data:`SCALED_FEW_DOF_WORDS`), or why there is none."""
    if not points:
        return "no other test's response points"
    try:
        # the lead the reported model admits (estimate.py, down to lead_floor(Tp)): a fit held at tau >= 0 ends
        # on that bound on a leading loop (PX4 SIH's EKF2 attitude) and predicts its cycles up to 11 % off
        fit = identify_points(_with_lead(model), points)
    except (IdentificationError, InputError, ValueError, ArithmeticError) as err:  # no fit: the fallback says why
        return str(err) or type(err).__name__
    dof = 2 * len(fit.points) - len([e for e in fit.estimates if not e.known])
    if fit.chi2_dof is not None and dof > 0 and chi2.sf(fit.chi2_dof * dof, dof) < _CONSISTENT_P:
        return (f"their points disagree with one eq. (2) plant (chi² {fit.chi2_dof * dof:.3g} for {dof} degrees of "
                "freedom: a harmonic carries what eq. (2) leaves out, e.g. an estimator's lag)")
    names, z, cov = fit_covariance(fit)
    if len(fit.points) * 2 < len(names) or not np.all(np.isfinite(cov)) or np.linalg.matrix_rank(cov) < len(names):
        # a flat direction has no variance in the covariance: the std would be understated
        return f"their response points do not determine {', '.join(fit.undetermined) or 'the model'}"
    on_bound = _on_bound(fit.model, names)
    if on_bound:  # the covariance of an unconstrained minimum does not hold there: no std to state
        return f"their fit ends on the bound of {on_bound}"

    def cycle(zk: np.ndarray, rate_hz: float | None) -> _Prediction:
        values = {n: (math.exp(v) if n != "tau" else float(v)) for n, v in zip(names, zk)}
        if "K" in values and fit.model.parameters["K"].value < 0:
            values["K"] = -values["K"]
        lc = predicted_cycle(test.predicting_relay, _with(fit.model, values), rate_hz, n_h)
        return float(lc.frequency_hz), float(lc.amplitude)

    try:
        centre = cycle(z, test.rate_hz)
        # the sensitivities in log terms from the continuous relay's cycle (smooth in the parameters, where the
        # sampled relay's orbits step; a quarter of the sampled cycles' CPU), scaled to the sampled prediction
        base = np.log(cycle(z, None))
        grad = np.empty((2, z.size))
        for i in range(z.size):
            dz = 1e-4 * max(1.0, abs(float(z[i]))) if names[i] != "tau" else 1e-6
            grad[:, i] = np.asarray(centre) * (np.log(cycle(z + np.eye(z.size)[i] * dz, None)) - base) / dz
    except (IdentificationError, InputError, ValueError, ArithmeticError):
        return "the fitted model has no limit cycle under this test's relay"
    var = np.einsum("ki,ij,kj->k", grad, cov, grad)
    # a chi-square on 1-2 degrees of freedom (a two-test flight: 4 figures for Td, tau, K) is one or two samples
    # of the points' scatter: below 1 the covariance is not scaled by it (fit_covariance), so the std rests on
    # their stated errors alone; above 1 it is scaled by that one or two samples
    note = ""
    if dof <= 2:
        scaled = fit.chi2_dof is not None and fit.chi2_dof > 1.0
        note = (f"{SCALED_FEW_DOF_WORDS if scaled else FEW_DOF_WORDS} ({dof} degree{'s' if dof > 1 else ''} "
                "of freedom)")
    return centre, (math.sqrt(max(float(var[0]), 0.0)), math.sqrt(max(float(var[1]), 0.0))), note


def _with(model: PlantModel, values: dict[str, float]) -> PlantModel:
    return model.with_parameters(**values)


def _with_lead(model: LoopModel) -> LoopModel:
    """Eq. (2) with tau free down to :func:`~mrftcli.mrft.model.lead_floor` (the set I), as the reported tau is."""
    return dataclasses.replace(model, ranges=(("tau", lead_floor(float(model.Tp)), math.inf),))


def _on_bound(model: PlantModel, names: Sequence[str]) -> str:
    """The fitted parameters among ``names`` that sit on a finite bound of their range (``tau = -6 ms``), or ``""``."""
    hits = []
    for name in names:
        p = model.parameters[name]
        for b in p.bounds:
            log = name != "tau" and b > 0 and p.value > 0  # a positive parameter is fitted in log terms
            if math.isfinite(b) and abs((math.log(p.value / b)) if log else p.value - b) <= 1e-6 * (1 + abs(b)):
                hits.append(f"{name} = {p.value * 1e3:.3g} ms" if p.unit == "s" else f"{name} = {p.value:.4g}")
    return ", ".join(hits)
