"""The search: eq. (2)'s beta grid (each beta a candidate test: its h, cycle and admissibility, and the
greedy choice of the next test(s) by the expected posterior covariance, guarded by the conventional
beta), and a process plant's candidate relays ranked (:func:`candidate_relays`, :func:`forecast_relay`,
:func:`rank`).

Candidates: h the largest that keeps the largest predicted amplitude over the draws within the
limit, the duration the time available (split equally between the tests asked for). Admissible: at
least 8 controller samples per period and 3 stable cycles; the output moving 4 noise std per tick
at the zero crossing (:func:`mrftcli.sim.noise_margin`); the typical amplitude 10 noise std; and,
when any beta allows it, the switch at least 16 noise std below the extremum
(:func:`~mrftcli.plan.noise.switch_gap`).

A process plant's candidates: an ideal relay, hystereses and MRFTs at the recorded levels (or
``max_h``), each forecast with the current model (:func:`forecast_relay`) and ranked (:func:`rank`).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError
from ..mrft.identify_lti import ResponsePoint
from ..mrft.lprs import mrft_limit_cycle
from ..mrft.model import LoopModel, PlantModel
from ..mrft.relays import RelayLaw
from .fisher import (FloatArray, PredictedCycle, design_cost, planned_information, point_jacobian, point_stds,
                     posterior_covariance, posterior_stds, predict_cycle, undetermined_parameters, unknown_parameters)
from .forecast import std_median
from .noise import LOST_CYCLES, MAX_EPS, MIN_CYCLES, MIN_NOISE_MARGIN, MIN_SWITCH_GAP, switch_gap
from .records import OVER_LIMIT, CandidateTest, FlownTest, PlanLimits, TestPlan, relay_candidate

__all__ = [
    "DesignSpace",
    "Information",
    "Choice",
    "design_space",
    "assess",
    "admissible_betas",
    "conventional_information",
    "choose_tests",
    "recommended_test",
    "with_first_round",
    "CONVENTIONAL_BETAS",
    "candidate_relays",
    "relay_noise",
    "forecast_relay",
    "forecast_relays",
    "rank",
    "EPS_FRACTIONS",
    "CANDIDATE_BETAS",
]

#: The conventional MRFT betas a plan is compared with (the paper's recipe).
CONVENTIONAL_BETAS = (-0.4, -0.7)

Cycles = tuple[PredictedCycle | None, ...]


@dataclass(frozen=True)
class DesignSpace:
    """What every candidate test is evaluated on.

    Attributes
    ----------
    model : LoopModel
        Eq. (2), its known Tp [s] the plants share.
    plants : ndarray, shape (n, 3)
        The draws (Td [s], tau [s], K).
    limits : PlanLimits
        The flight's limits.
    duration_s : float
        Relay time of each next test [s].
    cycles : mapping of float to tuple
        Per beta, each draw's predicted cycle for h = 1 (None: no limit cycle).
    """

    model: LoopModel
    plants: np.ndarray
    limits: PlanLimits
    duration_s: float
    cycles: Mapping[float, Cycles]

    def predict(self, beta: float) -> Cycles:
        """Each draw's cycle at ``beta`` (from :attr:`cycles` when already predicted)."""
        if beta in self.cycles:
            return self.cycles[beta]
        return tuple(predict_cycle(self.model.Tp, p, beta, self.limits.rate_hz) for p in self.plants)

    def information(self, beta: float, h: float) -> list[np.ndarray]:
        """Each draw's Fisher information of the test (beta, h, :attr:`duration_s`)."""
        lim = self.limits
        return [planned_information(self.model.Tp, p, beta, h, self.duration_s, lim.rate_hz, lim.noise_std, cycle=c)
                for p, c in zip(self.plants, self.predict(beta))]


@dataclass(frozen=True)
class Information:
    """Fisher information on (Td, tau, ln K) per draw: with the prior's, and of the tests alone."""

    total: tuple[np.ndarray, ...]
    data: tuple[np.ndarray, ...]

    def plus(self, infos: Sequence[np.ndarray]) -> Information:
        """The information after one more test (``infos``: per draw)."""
        return Information(tuple(A + I for A, I in zip(self.total, infos)),
                           tuple(A + I for A, I in zip(self.data, infos)))


@dataclass(frozen=True)
class Choice:
    """The greedy search's result.

    Attributes
    ----------
    betas : tuple of float
        The chosen tests' betas, in flying order.
    information : Information
        After them.
    first_round : dict
        Per admissible beta: (median predicted std, score) as the first test.
    """

    betas: tuple[float, ...]
    information: Information
    first_round: dict[float, tuple[dict[str, float], float]]


def design_space(model: LoopModel, plants: np.ndarray, limits: PlanLimits, duration_s: float,
                 betas: Sequence[float], on_beta: Callable[[int], None]) -> DesignSpace:
    """The draws' cycles at every beta of the grid (``on_beta(i)`` after the i-th, from 1)."""
    cycles: dict[float, Cycles] = {}
    for i, b in enumerate(betas):
        cycles[b] = tuple(predict_cycle(model.Tp, p, b, limits.rate_hz) for p in plants)
        on_beta(i + 1)
    return DesignSpace(model, plants, limits, duration_s, cycles)


def assess(space: DesignSpace, beta: float) -> CandidateTest:
    """The candidate test at ``beta``: its h, predicted cycles over the draws and admissibility."""
    cs = space.predict(beta)
    if any(c is None for c in cs):
        return CandidateTest(beta, False, "no limit cycle for some plants of the prior")
    known = [c for c in cs if c is not None]
    lim = space.limits
    rate, noise_std = lim.rate_hz, lim.noise_std
    max_amplitude, max_h = lim.bounds()
    h = min(max_h, max_amplitude / max(c.amp1 for c in known))
    periods = np.array([math.tau / c.omega for c in known])
    n_cyc = np.floor(space.duration_s / periods) - LOST_CYCLES
    amps = np.array([h * c.amp1 for c in known])
    motion = amps * np.array([c.omega for c in known]) / (rate * noise_std)  # noise stds per tick at the switch
    typical = float(np.exp(np.mean(np.log(amps))))  # the typical plant of the prior, not the smallest
    gap = switch_gap(typical, beta, noise_std)
    reason = _refusal(rate * float(periods.min()), float(n_cyc.min()), float(np.max(motion)), noise_std / typical,
                      typical, space.duration_s, lim)
    early = not reason and gap < MIN_SWITCH_GAP
    if early:
        # not refused outright: with a broad prior every beta may fall short for the typical plant
        reason = (f"the relay would switch {gap:.3g} noise stds below the extremum (< 16: noise may "
                  "trigger it early)")
    admissible = not reason or early
    if admissible and float(np.min(motion)) < MIN_NOISE_MARGIN:
        # the prior's spread of K makes the amplitude of some plants too small for the noise
        reason = "some plants of the prior may lock up on noise (amplitude too small): narrow the K range"
    return CandidateTest(beta, admissible, reason, h=h,
                         frequency_hz=(float(1 / periods.max()), float(1 / periods.min())),
                         amplitude=(float(amps.min()), float(amps.max())), n_cycles=int(n_cyc.min()),
                         samples_per_period=float(rate * periods.min()), switch_gap=gap, early_switch=early)


def _refusal(samples_per_period: float, n_cycles: float, max_motion: float, eps: float, typical: float,
             duration_s: float, lim: PlanLimits) -> str:
    """Why the limits refuse a candidate ("" when they do not)."""
    if samples_per_period < 8:
        return f"fewer than 8 controller samples per period at {lim.rate_hz:g} Hz"
    if n_cycles < MIN_CYCLES:
        return f"fewer than {MIN_CYCLES} stable cycles in {duration_s:.3g} s"
    if max_motion < MIN_NOISE_MARGIN:
        return (f"the output moves less than {MIN_NOISE_MARGIN:g} noise stds per "
                "controller tick at the switch (the relay would lock up on noise)")
    if eps > MAX_EPS:
        # the typical plant of the prior, not the smallest: a wide K range would refuse every test
        return f"the typical amplitude ({typical:.3g}) is under {1 / MAX_EPS:g} x the sensor noise ({lim.noise_std:.3g})"
    return ""


def admissible_betas(candidates: Mapping[float, CandidateTest], betas: Sequence[float]) -> tuple[list[float], bool]:
    """The betas to search and whether they all risk an early switch.

    Those whose switch sits far enough below the extremum, when there are any: nearer -1 the noise
    triggers the switch early and analyze loses the test (docs/benchmarks/plan.md).

    Raises
    ------
    InputError
        No beta is admissible (the message names the limits' reasons and what to relax).
    """
    admissible = [b for b in betas if candidates[b].admissible]
    if not admissible:
        reasons = sorted({candidates[b].reason for b in betas})
        raise InputError(f"the limits admit no MRFT test ({'; '.join(reasons)}): {_remedies(reasons)}")
    clear = [b for b in admissible if not candidates[b].early_switch]
    return clear or admissible, not clear


#: What relaxes each refusal of :func:`_refusal` (its message's start -> the options that help).
_REMEDIES = (
    ("fewer than 8 controller", "a faster controller (--controller-rate)"),
    ("fewer than", "more time (--time)"),
    ("the output moves less", "a smaller sensor noise (--noise: measure it on a hover), a larger amplitude "
                              "(--max-amplitude) or a narrower gain prior (--k-range: h is set by its highest-gain "
                              "plant, so the others cycle smaller)"),
    ("the typical amplitude", "a smaller sensor noise (--noise), a larger amplitude (--max-amplitude, --max-h) or a "
                              "narrower gain prior (--k-range)"),
    ("no limit cycle", "a narrower prior (--td-range, --tau-range)"),
)


def _remedies(reasons: Sequence[str]) -> str:
    """The options that relax ``reasons`` (in the order of :data:`_REMEDIES`, each once)."""
    helps: list[str] = []
    for reason in reasons:
        for start, remedy in _REMEDIES:
            if reason.startswith(start):
                if remedy not in helps:
                    helps.append(remedy)
                break
    return "allow " + "; or ".join(helps) if helps else "relax the limits"


def conventional_information(space: DesignSpace, flown: Sequence[FlownTest],
                             n_tests: int) -> tuple[tuple[float, list[np.ndarray]], ...] | None:
    """The conventional beta(s) not yet flown (at most ``n_tests``; -0.7 if both were) with each
    draw's information; None when the limits refuse one of them."""
    betas = [b for b in CONVENTIONAL_BETAS if not any(abs(f.beta - b) < 0.05 for f in flown)][:n_tests] or [-0.7]
    out = []
    for b in betas:
        c = assess(space, b)
        if not c.admissible or c.h is None:
            return None
        out.append((b, space.information(b, c.h)))
    return tuple(out)


def choose_tests(space: DesignSpace, admissible: Sequence[float], infos: Mapping[float, list[np.ndarray]],
                 start: Information, conventional: Sequence[list[np.ndarray]] | None, n_tests: int,
                 on_test: Callable[[int], None], conventional_betas: Sequence[float] = ()) -> Choice:
    """The next ``n_tests`` tests, one at a time, each the admissible beta of the least mean design
    cost (:func:`~mrftcli.plan.fisher.design_cost`) after the tests before it.

    Guard: among the candidates predicted no worse than the conventional beta for Td and tau (if any
    is), the one with the smallest total relative variance: a user who replaces the -0.4/-0.7 recipe
    should not lose on the delay or the drag by the plan's own model. ``on_test(j)`` after the j-th.
    The guard holds for the tests together too: when the greedy tests are predicted worse than the
    conventional ones (``conventional_betas``, all in ``admissible``) for Td or tau (median std over the
    draws, as reported), the conventional tests are chosen.
    """
    plants = space.plants
    chosen: list[float] = []
    acc = start
    first: dict[float, tuple[dict[str, float], float]] = {}
    for j in range(n_tests):
        scores, rms = {}, {}
        for b in admissible:
            covs = [posterior_covariance(A + I) for A, I in zip(acc.total, infos[b])]
            scores[b] = float(np.mean([design_cost(c, p) for c, p in zip(covs, plants)]))
            rms[b] = _rms_stds(covs, plants)
            if j == 0:
                first[b] = (std_median([A + I for A, I in zip(acc.total, infos[b])], plants), scores[b])
        pool = list(admissible)
        if conventional is not None and j < len(conventional):
            ref = _rms_stds([posterior_covariance(A + I) for A, I in zip(acc.total, conventional[j])], plants)
            pool = [b for b in admissible if np.all(rms[b][:2] <= ref[:2] * (1 + 1e-9))] or pool
        best = _least(pool, scores, chosen)
        chosen.append(best)
        acc = acc.plus(infos[best])
        on_test(j)
    if conventional is not None and conventional_betas and len(conventional) == n_tests \
            and all(b in admissible for b in conventional_betas):
        conv = start
        for inf in conventional:
            conv = conv.plus(inf)
        now, instead = std_median(acc.total, plants), std_median(conv.total, plants)
        if any(now[k] > instead[k] * (1 + 1e-9) for k in ("Td", "tau")):
            return Choice(tuple(conventional_betas), conv, first)
    return Choice(tuple(chosen), acc, first)


def _rms_stds(covs: Sequence[np.ndarray], plants: np.ndarray) -> np.ndarray:
    """RMS over the draws of (std Td, std tau, std K)."""
    rms: np.ndarray = np.sqrt(np.mean([posterior_stds(c, p) ** 2 for c, p in zip(covs, plants)], axis=0))
    return rms


def _least(pool: Sequence[float], scores: Mapping[float, float], chosen: Sequence[float]) -> float:
    """The least score in ``pool``; on a tie, a beta not yet chosen."""
    return min(pool, key=lambda b: (scores[b], b in chosen))


def recommended_test(space: DesignSpace, beta: float, candidate: CandidateTest) -> TestPlan:
    """The recommended test, predicted with the sampled relay for the central plant of the draws
    (the geometric mean; the centre of the sampled relay's band when the sampled relay fails)."""
    assert candidate.h is not None and candidate.frequency_hz is not None and candidate.amplitude is not None
    Tp, rate, duration = space.model.Tp, space.limits.rate_hz, space.duration_s
    centre = np.exp(np.mean(np.log(space.plants), axis=0))
    h = float(candidate.h)
    try:
        lc = mrft_limit_cycle(LoopModel(Tp, centre[0], centre[1], centre[2]), beta, h, rate)
        f, a, orbits = lc.frequency_hz, lc.amplitude, tuple(lc.orbits_hz)
    except InputError:
        c = predict_cycle(Tp, centre, beta, rate)
        if c is None:
            raise
        f, a, orbits = c.omega / math.tau, h * c.amp1, ()
    cs = space.predict(beta)
    tdw = np.array([p[0] * c.omega for p, c in zip(space.plants, cs) if c is not None])
    n_c = max(int(math.floor(duration * f)) - LOST_CYCLES, 0)
    return TestPlan(beta=float(beta), h=h, duration_s=float(duration), frequency_hz=float(f), amplitude=float(a),
                    frequency_range_hz=candidate.frequency_hz, amplitude_range=candidate.amplitude,
                    orbits_hz=orbits, n_cycles=n_c, td_omega=(float(tdw.min()), float(tdw.max())))


def with_first_round(candidate: CandidateTest, first: Mapping[float, tuple[dict[str, float], float]]) -> CandidateTest:
    """``candidate`` with its predicted std and score as the first test, when it was searched."""
    if candidate.beta is None or candidate.beta not in first:
        return candidate
    std, score = first[candidate.beta]
    return replace(candidate, predicted_std=std, score=score)


# -- a process plant: the candidate relays, forecast with the current model --------------------------

#: hysteresis candidates, as fractions of the ideal relay's predicted amplitude
EPS_FRACTIONS = (0.25, 0.5, 0.75)
#: MRFT candidates' beta
CANDIDATE_BETAS = (-0.5, -0.2, 0.2, 0.5)
#: the identification's floors on the fundamentals' and harmonics' standard errors (mrft/identify_lti.py)
_SE_FLOOR, _HARMONIC_SE = 5e-3, 0.03


def candidate_relays(levels: tuple[float, float], ideal_amplitude: float) -> list[RelayLaw]:
    """The relays the user can run: ideal, hysteresis at :data:`EPS_FRACTIONS` of ``ideal_amplitude``
    [output units], MRFT at :data:`CANDIDATE_BETAS`; all at ``levels`` (high, low) [command units]."""
    high, low = levels
    relays = [RelayLaw("ideal", high, low, source="stated")]
    relays += [RelayLaw("hysteresis", high, low, eps=float(f"{f * ideal_amplitude:.3g}"), source="stated")
               for f in EPS_FRACTIONS]
    relays += [RelayLaw("mrft", high, low, beta=b, source="stated") for b in CANDIDATE_BETAS]
    return relays


def relay_noise(points: Sequence[ResponsePoint], amplitude: float) -> dict[int, tuple[float, float]]:
    """{k: (se, amplitude)}: per harmonic k, the recorded points' median standard error (ln gain and phase
    [rad] pooled) and the recorded tests' amplitude [output units] it was measured at."""
    out = {}
    for k in sorted({p.harmonic for p in points}):
        ses = [math.hypot(p.se_log_gain, p.se_phase) / math.sqrt(2) for p in points if p.harmonic == k]
        out[k] = (statistics.median(ses), amplitude)
    return out


def forecast_relay(model: PlantModel, relay: RelayLaw, rate_hz: float, F_now: FloatArray,
                   noise: Mapping[int, tuple[float, float]], w_ref: float) -> CandidateTest:
    """The relay's limit cycle on ``model`` (exact LPRS at ``rate_hz`` [Hz]) and the stds after adding its
    response points to the information ``F_now``.

    A point's standard error is the recorded one at harmonic k scaled by the recorded amplitude over
    the predicted one (the noise is the same sensor's; the signal scales with the cycle), floored as
    the identification floors it.

    Raises
    ------
    InputError
        The model has no limit cycle under this relay.
    """
    lc = relay.limit_cycle(model, rate_hz)
    names = unknown_parameters(model)
    F = F_now.copy()
    for k, (se, at_amplitude) in noise.items():
        floor = _SE_FLOOR if k == 1 else _HARMONIC_SE
        se_k = max(se * at_amplitude / max(lc.amplitude, 1e-300), floor)
        J = point_jacobian(model, k * lc.omega, names)
        F += J.T @ J / se_k ** 2
    G = complex(model.frequency_response(np.array([lc.omega]))[0])
    stds = point_stds(model, names, F, w_ref)
    return relay_candidate(relay, lc.frequency_hz, lc.amplitude, abs(G), math.degrees(math.atan2(G.imag, G.real)),
                           stds, undetermined_parameters(model, stds, w_ref))


def forecast_relays(model: PlantModel, relays: Sequence[RelayLaw], rate_hz: float, F_now: FloatArray,
                    noise: Mapping[int, tuple[float, float]], w_ref: float,
                    max_amplitude: float | None) -> tuple[list[CandidateTest], list[str]]:
    """Every relay forecast (:func:`forecast_relay`), marked over ``max_amplitude`` [output units]; and the
    relays without a limit cycle on the model, described."""
    out, skipped = [], []
    for relay in relays:
        try:
            c = forecast_relay(model, relay, rate_hz, F_now, noise, w_ref)
        except InputError:
            skipped.append(relay.describe()[len("relay: "):])
            continue
        if max_amplitude is not None and c.amplitude is not None and c.amplitude[0] > max_amplitude:
            c = replace(c, admissible=False, reason=OVER_LIMIT)
        out.append(c)
    return out, skipped


def _score(model: PlantModel, c: CandidateTest) -> tuple[bool, int, float]:
    """Sort key: within the limit first, then fewest undetermined, then sum of ln(relative std)."""
    total = 0.0
    for name, s in (c.predicted_std or {}).items():
        v = model.parameters[name].value
        total += math.log(s / abs(v)) if math.isfinite(s) and v != 0 else 50.0
    return (not c.admissible, len(c.undetermined), total)


def rank(model: PlantModel, candidates: Sequence[CandidateTest]) -> list[CandidateTest]:
    """The relay candidates best first (:func:`_score`): the ones within the amplitude limit, fewest parameters
    left undetermined, then the smallest product of relative stds."""
    return sorted(candidates, key=lambda c: _score(model, c))
