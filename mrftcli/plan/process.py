"""Plan the next relay test on a process plant (``plan LOG --model NAME``): which relay pins the model down.

The recorded tests (analysed as ``analyze --model`` does, :func:`mrftcli.analyze.general.analyze_general`)
give the current model and its response points ``G(j k Omega)``. Stages, each a short function:

1. information now (:func:`point_information`): the Fisher information of the recorded points on
   the unknown parameters (ln p for a gain or a time constant, tau in seconds), weighted by each
   point's standard error and widened by the fit's chi2/dof as the identification does;
2. candidates (:func:`candidate_relays`): the relays the user can run at the recorded levels (or
   ``max_h``): an ideal relay, a hysteresis at a few fractions of the ideal relay's amplitude, MRFTs
   at a few betas;
3. forecast (:func:`forecast_candidate`): each candidate's exact limit cycle of the current model
   (LPRS, sampled at the controller rate), the response points it yields (fundamental and the
   harmonics the recorded tests measured), their standard errors scaled from the recorded tests'
   own scatter by the amplitude, and the parameters' std after adding them (Gauss-Newton update);
4. ranking (:func:`rank`): fewest parameters left undetermined, then the smallest product of the
   relative stds (D-optimality on ln p); a candidate over ``max_amplitude`` is never first.

Why a test helps: one relay type puts every cycle at one phase of G, so one test gives one
point of G (two figures) plus weak harmonics, and a three-parameter model trades K against T along
them. A relay that moves the cycle to another phase (a hysteresis or an MRFT beta lowers the
frequency) adds an independent point.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from ..analyze.general import GeneralAnalysis
from ..errors import InputError
from ..mrft.identify_lti import DETERMINED_LOG_WIDTH, LtiIdentification, ResponsePoint
from ..mrft.model import PlantModel
from ..mrft.relays import RelayLaw
from .process_records import ProcessCandidate, ProcessPlan

__all__ = ["plan_process", "point_information", "candidate_relays", "forecast_candidate", "rank",
           "EPS_FRACTIONS", "CANDIDATE_BETAS"]

#: hysteresis candidates, as fractions of the ideal relay's predicted amplitude
EPS_FRACTIONS = (0.25, 0.5, 0.75)
#: MRFT candidates' beta
CANDIDATE_BETAS = (-0.5, -0.2, 0.2, 0.5)
#: the identification's floors (mrft/identify_lti.py, analyze/general.py): fundamentals' and harmonics'
#: standard errors, and a parameter's relative std
_SE_FLOOR, _HARMONIC_SE, _PARAM_FLOOR = 5e-3, 0.03, 5e-3
_STEP = 1e-5  # finite-difference step of the Jacobian (relative, or times tau's scale)

FloatArray = NDArray[np.float64]


def _unknown(model: PlantModel) -> list[str]:
    return [n for n, p in model.parameters.items() if not p.known]


def _is_log(name: str, value: float) -> bool:
    """A gain or time constant is varied as ln|p| (its std relative); the delay and a zero value in seconds."""
    return name != "tau" and value != 0


def _point_jacobian(model: PlantModel, omega: float, names: Sequence[str]) -> FloatArray:
    """(2, n) derivatives of (ln |G|, arg G) at ``omega`` [rad/s] w.r.t. the coordinates of ``names``."""
    G0 = complex(model.frequency_response(np.array([omega]))[0])
    J = np.zeros((2, len(names)))
    for i, name in enumerate(names):
        v = model.parameters[name].value
        step = _STEP * (abs(v) if _is_log(name, v) else max(abs(v), 1.0 / omega))
        G1 = complex(model.with_parameters(**{name: v + step}).frequency_response(np.array([omega]))[0])
        ratio = G1 / G0
        scale = step / abs(v) if _is_log(name, v) else step
        J[:, i] = [math.log(abs(ratio)) / scale, math.atan2(ratio.imag, ratio.real) / scale]
    return J


def point_information(model: PlantModel, points: Sequence[ResponsePoint], names: Sequence[str]) -> FloatArray:
    """Fisher information of ``points`` on the coordinates of ``names`` (ln p, or tau [s])."""
    F = np.zeros((len(names), len(names)))
    for p in points:
        J = _point_jacobian(model, p.omega, names)
        W = np.diag([1.0 / p.se_log_gain ** 2, 1.0 / p.se_phase ** 2])
        F += J.T @ W @ J
    return F


def _stds(model: PlantModel, names: Sequence[str], F: FloatArray, w_ref: float) -> dict[str, float]:
    """Each parameter's std [its unit] from the information ``F`` (inf along a direction it does not see)."""
    scale = np.sqrt(np.diag(F))
    scale = np.where(scale > 0, scale, 1.0)
    Fs = F / np.outer(scale, scale)  # scaled: the verdict must not depend on units
    vals, vecs = np.linalg.eigh(Fs)
    out = {}
    for i, name in enumerate(names):
        v = model.parameters[name].value
        # a direction the points hardly see (eigenvalue below 1e-8 of the largest) has no std worth the name
        flat = any(abs(vecs[i, k]) > 0.1 for k in range(len(vals)) if vals[k] < 1e-8 * vals[-1])
        if flat or np.diag(F)[i] <= 0:
            out[name] = math.inf
            continue
        cov = vecs @ np.diag(1.0 / np.maximum(vals, 1e-300)) @ vecs.T
        s = math.sqrt(max(float(cov[i, i]), 0.0)) / scale[i]
        if _is_log(name, v):
            out[name] = float(abs(v) * max(s, _PARAM_FLOOR))
        else:
            out[name] = float(max(s, _PARAM_FLOOR / w_ref if name == "tau" else 0.0))
    return out


def _undetermined(model: PlantModel, stds: Mapping[str, float], w_ref: float) -> tuple[str, ...]:
    """identify_lti's verdict: a 95 % interval wider than :data:`DETERMINED_LOG_WIDTH` (a factor 1.25 either
    way), or (tau) than a radian at w_ref."""
    out = []
    for name, s in stds.items():
        v = model.parameters[name].value
        wide = 2 * 1.959964 * (s / abs(v) if _is_log(name, v) else s * w_ref) >= (
            DETERMINED_LOG_WIDTH if _is_log(name, v) else 1.0)
        if not math.isfinite(s) or wide:
            out.append(name)
    return tuple(out)


def candidate_relays(levels: tuple[float, float], ideal_amplitude: float) -> list[RelayLaw]:
    """The relays the user can run: ideal, hysteresis at :data:`EPS_FRACTIONS` of ``ideal_amplitude``
    [output units], MRFT at :data:`CANDIDATE_BETAS`; all at ``levels`` (high, low) [command units]."""
    high, low = levels
    relays = [RelayLaw("ideal", high, low, source="stated")]
    relays += [RelayLaw("hysteresis", high, low, eps=float(f"{f * ideal_amplitude:.3g}"), source="stated")
               for f in EPS_FRACTIONS]
    relays += [RelayLaw("mrft", high, low, beta=b, source="stated") for b in CANDIDATE_BETAS]
    return relays


def _noise(points: Sequence[ResponsePoint], amplitude: float) -> dict[int, tuple[float, float]]:
    """{k: (se, amplitude)}: per harmonic k, the recorded points' median standard error (ln gain and phase
    [rad] pooled) and the recorded tests' amplitude [output units] it was measured at."""
    out = {}
    for k in sorted({p.harmonic for p in points}):
        ses = [math.hypot(p.se_log_gain, p.se_phase) / math.sqrt(2) for p in points if p.harmonic == k]
        out[k] = (statistics.median(ses), amplitude)
    return out


def forecast_candidate(model: PlantModel, relay: RelayLaw, rate_hz: float, F_now: FloatArray,
                       noise: Mapping[int, tuple[float, float]], w_ref: float) -> ProcessCandidate:
    """The candidate's limit cycle (exact LPRS) and the stds after adding its response points.

    A point's standard error is the recorded one at harmonic k scaled by the recorded amplitude over
    the predicted one (the noise is the same sensor's; the signal scales with the cycle), floored as
    the identification floors it.

    Raises
    ------
    InputError
        The model has no limit cycle under this relay.
    """
    lc = relay.limit_cycle(model, rate_hz)
    names = _unknown(model)
    F = F_now.copy()
    for k, (se, at_amplitude) in noise.items():
        floor = _SE_FLOOR if k == 1 else _HARMONIC_SE
        se_k = max(se * at_amplitude / max(lc.amplitude, 1e-300), floor)
        J = _point_jacobian(model, k * lc.omega, names)
        F += J.T @ J / se_k ** 2
    G = complex(model.frequency_response(np.array([lc.omega]))[0])
    stds = _stds(model, names, F, w_ref)
    return ProcessCandidate(relay, lc.frequency_hz, lc.amplitude, abs(G), math.degrees(math.atan2(G.imag, G.real)),
                            stds, _undetermined(model, stds, w_ref))


def _score(model: PlantModel, c: ProcessCandidate) -> tuple[bool, int, float]:
    """Sort key: within the limit first, then fewest undetermined, then sum of ln(relative std)."""
    total = 0.0
    for name, s in c.std_after.items():
        v = model.parameters[name].value
        total += math.log(s / abs(v)) if math.isfinite(s) and v != 0 else 50.0
    return (not c.within_limit, len(c.undetermined_after), total)


def rank(model: PlantModel, candidates: Sequence[ProcessCandidate]) -> list[ProcessCandidate]:
    """The candidates best first (:func:`_score`): the ones within the amplitude limit, fewest parameters left
    undetermined, then the smallest product of relative stds."""
    return sorted(candidates, key=lambda c: _score(model, c))


def _why(best: ProcessCandidate, std_now: Mapping[str, float], undetermined: Sequence[str],
         phases_now: Sequence[float]) -> str:
    """One sentence: what the recommended test determines or narrows, and at which phase."""
    gains = {n: std_now[n] / s for n, s in best.std_after.items() if math.isfinite(s) and s > 0}
    fixed = [n for n in undetermined if n not in best.undetermined_after]
    phase = f"its cycle at {best.frequency_hz:.4g} Hz puts a response point at {best.phase_deg:.0f} deg"
    listed = (", ".join(f"{p:.0f}" for p in phases_now) if len(phases_now) <= 3
              else f"{min(phases_now):.0f} to {max(phases_now):.0f}")
    where = f"where the recorded tests sit at {listed} deg"
    if fixed:
        return f"{phase}, {where}: it determines {', '.join(fixed)} (not determined by the recorded tests)."
    if not gains:
        return f"{phase}, {where}; no candidate determines {', '.join(undetermined)}."
    if not undetermined and max(gains.values()) < 1.1:
        return ("no candidate narrows any parameter by 10 % or more: the recorded tests already pin the model down "
                "(to the identification's floor of 0.5 %, or their own scatter); a next test is not needed.")
    best_name = max((n for n in gains if math.isfinite(gains[n])), key=lambda n: gains[n], default=None)
    if best_name is None:
        return f"{phase}, {where}: it narrows every parameter the recorded tests left undetermined."
    return (f"{phase}, {where}: it narrows {best_name} the most (std {std_now[best_name]:.3g} -> "
            f"{best.std_after[best_name]:.3g}).")


def _forecast_all(model: PlantModel, relays: Sequence[RelayLaw], rate_hz: float, F_now: FloatArray,
                  noise: Mapping[int, tuple[float, float]], w_ref: float,
                  max_amplitude: float | None) -> tuple[list[ProcessCandidate], list[str]]:
    """Every relay forecast (:func:`forecast_candidate`), marked over ``max_amplitude`` [output units]; and the
    relays without a limit cycle on the model, described."""
    out, skipped = [], []
    for relay in relays:
        try:
            c = forecast_candidate(model, relay, rate_hz, F_now, noise, w_ref)
        except InputError:
            skipped.append(relay.describe()[len("relay: "):])
            continue
        if max_amplitude is not None and c.amplitude > max_amplitude:
            c = dataclasses.replace(c, within_limit=False)
        out.append(c)
    return out, skipped


def plan_process(analysis: GeneralAnalysis, *, max_amplitude: float | None = None,
                 max_h: float | None = None) -> ProcessPlan:
    """Rank the next relay tests for the model of ``analysis`` (module docstring).

    Parameters
    ----------
    analysis : GeneralAnalysis
        The recorded tests analysed (``analyze --model``).
    max_amplitude : float, optional
        Largest output amplitude allowed [output units]; a candidate over it is listed, never recommended.
    max_h : float, optional
        Relay half-height for the candidates [command units] (default: the recorded tests' largest),
        about the recorded bias.

    Raises
    ------
    InputError
        No identification, or no candidate relay has a limit cycle on the current model.
    """
    ident: LtiIdentification | None = analysis.identification
    if ident is None or not analysis.tests:
        raise InputError("no identified model to plan from: the log needs a usable relay test")
    model, points = ident.model, ident.points
    names = _unknown(model)
    if not names:
        raise InputError("every parameter is known (--param): there is nothing for a next test to determine")
    tests = analysis.tests
    rate = statistics.median(t.rate_hz for t in tests)
    w_ref = 2 * math.pi * statistics.median(t.frequency_hz for t in tests)
    widen = max(1.0, ident.chi2_dof or 1.0)
    F_now = point_information(model, points, names) / widen
    std_now = _stds(model, names, F_now, w_ref)
    first = max(tests, key=lambda t: t.relay.h)
    h = max_h if max_h is not None else first.relay.h
    levels = (first.relay.bias + h, first.relay.bias - h)
    a_rec = statistics.median(t.amplitude for t in tests) * h / first.relay.h
    try:
        a_ideal = RelayLaw("ideal", *levels).limit_cycle(model, rate).amplitude
    except InputError:
        a_ideal = a_rec
    noise = {k: (se * math.sqrt(widen), a) for k, (se, a) in _noise(points, a_rec).items()}
    out, skipped = _forecast_all(model, candidate_relays(levels, a_ideal), rate, F_now, noise, w_ref, max_amplitude)
    if not out:
        raise InputError("no candidate relay has a limit cycle on the current model: "
                         f"{'; '.join(skipped)}")
    ranked = rank(model, out)
    undetermined = _undetermined(model, std_now, w_ref)
    phases = sorted({round(math.degrees(p.phase)) for p in points if p.harmonic == 1})
    n_cycles = int(statistics.median(t.n_stable for t in tests))
    assumptions = (f"the next test runs about {n_cycles} stable cycles at levels {levels[0]:+.4g} / {levels[1]:+.4g} "
                   "[command units] with the recorded tests' noise (their points' scatter, scaled by the "
                   "amplitude)",)
    notes = tuple(f"no limit cycle on the current model: {s}" for s in skipped)
    dof = 2 * len(points) - len(names)
    # beyond chance at 0.1 % (chi2 with the fit's degrees of freedom): a misfit the structure must answer for
    if dof > 0 and widen > float(stats.chi2.ppf(0.999, dof)) / dof:
        notes += (f"the recorded points disagree with {model.family} beyond their scatter (chi2/dof {widen:.3g}): the "
                  "forecast widens their errors by it, and no next test fixes a structure that does not fit (compare "
                  "another --model, and the held-out predictions of analyze --model)",)
    if max_amplitude is not None and not ranked[0].within_limit:
        notes += (f"no candidate stays within --max-amplitude {max_amplitude:g}: the first is the least over it",)
    return ProcessPlan(ident, float(rate), std_now, undetermined, tuple(ranked),
                       _why(ranked[0], std_now, undetermined, phases), assumptions, notes)
