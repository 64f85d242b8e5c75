"""``plan_tests``: the one planner, taking the model object; a strategy per model kind.

Eq. (2) (a :class:`~mrftcli.mrft.model.LoopModel`, Tp known): draws -> information of the flown tests ->
candidates -> greedy search -> forecast -> notes. Any other family (a process plant, a declared
model): the recorded tests' information -> candidate relays forecast with the identified model ->
ranking -> why.

Design: Fisher information ``I = sum_tests J^T W J`` plus the prior's (each range read as +/- 2
standard deviations), the expected posterior covariance its inverse. It is averaged over a few draws
from the prior (for flown tests: draws on the flown tests' UFM slice), and the candidate that
minimises the mean of ``var(ln Td) + var(ln tau) + var(ln K)`` wins, among those predicted no worse
than the conventional beta (-0.4, then -0.7) for Td and tau when there are any. The frequencies on
the grid are the exact continuous LPRS with half a controller period added to the delay, which is
the centre of the sampled relay's band (:func:`mrftcli.mrft.lprs.mrft_limit_cycle`); the recommended
tests are then predicted with the sampled relay itself.

Forecast: the predicted stds are the median over the draws (the typical plant's), with the 10-90 %
range over them: after one test, Td is often still uncertain by a factor of several, and the Td std
grows about as Td^2, so the forecast for the actual plant lies in that range. They forecast the
bootstrap std of ``analyze``'s MRFT estimate (``parameters_mrft``).

A process plant (docs/process-plants.md, "Planning the next test"): the information of the recorded
response points (widened by the fit's chi2/dof as the identification does), each candidate relay's
exact limit cycle on the current model and the stds after adding its points
(:func:`~mrftcli.plan.search.forecast_relays`), ranked by :func:`~mrftcli.plan.search.rank`. Why a test
helps: one relay type puts every cycle at one phase of G, so one test gives one point of G (two
figures) plus weak harmonics, and a three-parameter model trades K against T along them; a relay that
moves the cycle to another phase (a hysteresis, or an MRFT beta) adds an independent point.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import math
import statistics

import numpy as np
from scipy import stats

from ..analyze.record import AnalysisResult
from ..errors import InputError
from ..mrft.model import LoopModel, PlantModel
from ..mrft.relays import RelayLaw
from ..progress import Progress, report
from ..validate import check_beta, check_time
from .draws import conditioned_draws
from .fisher import (flown_information, point_information, point_stds, posterior_covariance, undetermined_parameters,
                     unknown_parameters)
from .forecast import SimulatedForecast, simulated_forecast, std_median, std_range
from .noise import MIN_SWITCH_GAP
from .records import (CandidateTest, Conventional, FlownTest, PlanLimits, PlanResult, Prior, Stds,
                      TestPlan)
from .search import (Choice, DesignSpace, Information, admissible_betas, assess, candidate_relays, choose_tests,
                     conventional_information, design_space, forecast_relays, rank, recommended_test, relay_noise,
                     with_first_round)

__all__ = ["PlanOptions", "plan_tests", "plan_notes", "DEFAULT_BETAS", "TD_OMEGA_LIMIT"]

#: beta grid searched by default (the issue's admissible range (-0.9, -0.1)).
DEFAULT_BETAS = tuple(float(b) for b in np.round(np.linspace(-0.9, -0.1, 17), 3))
#: Td * Omega above which the frequencies hardly depend on Td (the tool's identifiability boundary).
TD_OMEGA_LIMIT = 5.0


@dataclass(frozen=True)
class PlanOptions:
    """How :func:`plan_tests` searches.

    Attributes
    ----------
    n_tests : int, optional
        How many next tests to recommend (sharing ``limits.time_s`` equally); default 2 with no
        flown test, else 1.
    betas : tuple of float
        The beta grid searched.
    n_draws : int
        Plant draws from the prior the design is averaged over.
    n_simulated : int
        When > 0, the recommended tests are also flown in simulation on this many of the draws
        (:func:`~mrftcli.plan.forecast.simulated_flights`, about 0.1 s each): ``PlanResult.simulated_std``
        and its range.
    seed : int
        Seed of the draws.
    """

    n_tests: int | None = None
    betas: Sequence[float] = DEFAULT_BETAS
    n_draws: int = 8
    n_simulated: int = 0
    seed: int = 0


def plan_tests(model: PlantModel, limits: PlanLimits, *, prior: Prior | None = None,
               flown: Sequence[FlownTest] = (), recorded: AnalysisResult | None = None,
               options: PlanOptions = PlanOptions(), progress: Progress | None = None) -> PlanResult:
    """Recommend the next test(s) for ``model`` (docs/plan.md, docs/process-plants.md; module docstring).

    Parameters
    ----------
    model : PlantModel
        The model object: eq. (2) (``soiptd_model(Tp)``, Tp [s] known) plans MRFT tests from ``prior``
        and ``flown``; any other family plans the next relay test from ``recorded``.
    limits : PlanLimits
        Eq. (2): amplitude, relay height, time, rate and noise of the flight. A process plant: the
        largest amplitude and the relay half-height (both optional).
    prior : Prior
        Eq. (2): ranges for Td, tau and K.
    flown : sequence of FlownTest
        Eq. (2): tests already flown (their information is counted, and the draws follow their UFM slice).
    recorded : AnalysisResult
        A process plant: its recorded relay tests analysed (``analyze --model``), of ``model``'s family.
    options : PlanOptions
        Eq. (2): number of tests, beta grid, draws, simulated flights and seed.
    progress : Progress, optional
        Eq. (2): called as ``progress(done, total, "planning")`` per beta and test.

    Returns
    -------
    PlanResult

    Raises
    ------
    InputError
        Bad arguments, or limits that admit no test (the message says which limit to relax); a process
        plant without an identified model, or every parameter known.

    Examples
    --------
    >>> from mrftcli.mrft.model import soiptd_model
    >>> from mrftcli.plan import PlanLimits, PlanOptions, Prior, plan_tests
    >>> prior = Prior(Td=(0.3, 3.0), tau=(0.01, 0.08), K=(1.0, 10.0))
    >>> limits = PlanLimits(max_amplitude=0.05, max_h=2.0, time_s=30.0, rate_hz=200.0, noise_std=0.0005)
    >>> p = plan_tests(soiptd_model(0.04), limits, prior=prior,
    ...                options=PlanOptions(n_tests=2, n_draws=3, betas=(-0.2, -0.5, -0.8)))
    >>> len(p.tests), all(-0.9 <= t.beta <= -0.1 for t in p.tests), p.Tp
    (2, True, 0.04)
    """
    if isinstance(model, LoopModel):
        if not limits.flight or prior is None:
            raise InputError("eq. (2) plans from a Prior and a flight's PlanLimits (amplitude, height, time, rate, "
                             "noise)")
        return _plan_mrft(model, prior, limits, flown, options, progress)
    if limits.flight:
        raise InputError(f"a {model.family} plan takes the largest amplitude and the relay half-height (the time, "
                         "rate and noise are the recorded tests')")
    return _plan_relays(model, recorded, limits)


def _plan_mrft(model: LoopModel, prior: Prior, limits: PlanLimits, flown: Sequence[FlownTest],
               options: PlanOptions, progress: Progress | None) -> PlanResult:
    """Eq. (2)'s strategy: the next MRFT test(s) over the prior's draws at ``model``'s known Tp."""
    check_time("Tp", model.Tp)
    if model.known != frozenset({"Tp"}) or model.ranges:  # what the draws, the search and analyze identify
        raise InputError("eq. (2) is planned with Tp known and Td, tau, K free: give soiptd_model(Tp)")
    betas, n_tests = _resolve(options, flown)
    rng = np.random.default_rng(options.seed)
    lead_notes: list[str] = []
    plants = conditioned_draws(model, prior, flown, max(int(options.n_draws), 1), rng, limits.rate_hz, limits.noise_std,
                               lead_notes)
    total = len(betas) * (n_tests + 1)
    space = design_space(model, plants, limits, limits.time_s / n_tests, betas,
                         lambda i: report(progress, i, total, "planning"))
    start = _flown_information(space, prior, flown)
    candidates = {b: assess(space, b) for b in betas}
    admissible, early_only = admissible_betas(candidates, betas)
    infos = {b: space.information(b, _height(candidates[b])) for b in admissible}
    conventional = conventional_information(space, flown, n_tests)
    conv_infos = None if conventional is None else [inf for _, inf in conventional]
    conv_betas = () if conventional is None else tuple(b for b, _ in conventional)

    def choose(pool: Sequence[float]) -> tuple[Choice, tuple[TestPlan, ...]]:
        c = choose_tests(space, pool, {b: infos[b] for b in pool}, start, conv_infos, n_tests,
                         lambda j: report(progress, len(betas) * (j + 2), total, "planning"), conv_betas)
        return c, tuple(recommended_test(space, b, candidates[b]) for b in c.betas)

    choice, tests, sim, dropped = _flown_choice(choose, admissible, space, prior, flown, options, rng, progress)
    prior_std = _prior_std(prior, plants)
    post = std_median(choice.information.total, plants)
    centre = dict(zip(("Td", "tau", "K"), map(float, np.exp(np.mean(np.log(plants), axis=0)))))
    notes = plan_notes(tests, _lowest_frequency(candidates[b] for b in admissible), post, prior_std, limits,
                       centre=centre, post_data=std_median(choice.information.data, plants))
    notes[:0] = lead_notes  # what the forecasts leave out, read first
    if early_only:
        notes.append(f"at every admissible beta the relay switches fewer than {MIN_SWITCH_GAP:g} noise stds below "
                     "the extremum for the typical plant: noise may trigger switches early; allow a larger amplitude "
                     "(--max-amplitude) or narrow the K range")
    conv = _conventional(space, start, conventional)
    worse = _worse_than_conventional(post, conv)
    if worse and conv is not None:
        notes.append(_worse_note(worse, conv.betas, admissible, dropped))
    if dropped:
        notes.append(f"beta {', '.join(f'{b:g}' for b in dropped)} not recommended: analyze lost the test in some "
                     "of its simulated flights")
    _refuse_failing(sim, options)
    if sim.note:
        notes.append(sim.note + ("" if not any(sim.lost) else
                                 "; no admissible beta flew cleanly on every plant: this is the least-failing "
                                 "choice (allow a larger amplitude, or measure the sensor noise: --noise)"))
    return PlanResult(model=model.with_parameters(**centre), tests=tests, predicted_std=post, predicted_std_data=std_median(choice.information.data,
                                                                                              plants),
                      simulated_std=sim.std, simulated_std_range=sim.std_range, n_simulated=sim.n_used,
                      predicted_std_data_range=std_range(choice.information.data, plants),
                      prior_std=prior_std, conventional=conv,
                      candidates=tuple(with_first_round(candidates[b], choice.first_round) for b in betas),
                      notes=tuple(notes), flown=tuple(flown), limits=limits, rate_hz=limits.rate_hz)


def _worse_than_conventional(post: Mapping[str, float], conv: Conventional | None) -> str:
    """``Td``, ``tau`` or ``Td and tau`` where the predicted std exceeds the conventional tests' ("": none)."""
    if conv is None:
        return ""
    worse = [p for p in ("Td", "tau") if post[p] > conv.predicted_std[p] * (1 + 1e-6)]
    return " and ".join(worse)


def _worse_note(worse: str, conv_betas: Sequence[float], admissible: Sequence[float],
                dropped: Sequence[float]) -> str:
    """Why the recommendation is predicted worse than the conventional betas (which the choice prefers
    whenever they are all still candidates: :func:`~mrftcli.plan.search.choose_tests`)."""
    why = []
    outside = [b for b in conv_betas if b not in admissible]
    lost = [b for b in conv_betas if b in dropped]
    if outside:
        why.append(f"beta {', '.join(f'{b:g}' for b in outside)} is not a candidate here (inadmissible, or its relay "
                   "switches too near the extremum for the noise)")
    if lost:
        why.append(f"analyze lost beta {', '.join(f'{b:g}' for b in lost)} in the simulated flights")
    return (f"the recommended tests are predicted worse than the conventional beta {' / '.join(f'{b:g}' for b in conv_betas)} "
            f"for {worse}: " + ("; ".join(why) or "the simulated flights dropped the betas that did as well"))


def _resolve(options: PlanOptions, flown: Sequence[FlownTest]) -> tuple[tuple[float, ...], int]:
    """The checked beta grid and number of tests (default 2 with no flown test, else 1)."""
    betas = tuple(check_beta(b) for b in options.betas)
    if not betas:
        raise InputError("give at least one beta to search")
    n_tests = options.n_tests
    if n_tests is None:
        n_tests = 1 if flown else 2
    if int(n_tests) < 1:
        raise InputError(f"the number of tests must be at least 1, got {n_tests!r}")
    return betas, int(n_tests)


def _height(candidate: CandidateTest) -> float:
    """The relay height of an admissible candidate (which always has one)."""
    if candidate.h is None:
        raise ValueError(f"candidate beta {candidate.beta:g} has no relay height")
    return candidate.h


def _lowest_frequency(candidates: Iterable[CandidateTest]) -> float:
    """The lowest predicted frequency over the candidates [Hz]."""
    return min(c.frequency_hz[0] for c in candidates if c.frequency_hz is not None)


def _flown_information(space: DesignSpace, prior: Prior, flown: Sequence[FlownTest]) -> Information:
    """Each draw's information before the next tests: the prior's plus the flown tests'."""
    prior_info = prior.information()
    lim = space.limits
    start = Information(tuple(prior_info.copy() for _ in space.plants), tuple(np.zeros((3, 3)) for _ in space.plants))
    for f in flown:
        start = start.plus([flown_information(space.model.Tp, p, f, lim.rate_hz, lim.noise_std) for p in space.plants])
    return start


def _prior_std(prior: Prior, plants: np.ndarray) -> dict[str, float]:
    """The prior's standard deviations (range / 4; K's at the draws' central K)."""
    centre = np.exp(np.mean(np.log(plants), axis=0))
    sd = np.sqrt(np.diag(posterior_covariance(prior.information())))
    return {"Td": float(sd[0]), "tau": float(sd[1]), "K": float(sd[2] * centre[2])}


def _conventional(space: DesignSpace, start: Information,
                  conventional: Sequence[tuple[float, list[np.ndarray]]] | None) -> Conventional | None:
    """The forecast after the conventional beta(s) instead of the recommended ones."""
    if conventional is None:
        return None
    acc = start
    for _, inf in conventional:
        acc = acc.plus(inf)
    return Conventional(betas=tuple(b for b, _ in conventional), predicted_std=std_median(acc.total, space.plants),
                        predicted_std_tests_only=std_median(acc.data, space.plants))


#: Rounds of :func:`_flown_choice`: each drops the betas the simulated flights lost and chooses again.
SIMULATED_ROUNDS = 3
#: Share of the simulated flights (at least one) a planned beta must be lost on to be dropped: one flight of
#: the default 8, so that more simulated plants (``--simulate 64``) sharpen the forecast instead of dropping
#: every beta that one plant of 64 happens to lose.
DROP_LOST_SHARE = 1.0 / 8.0


def _lost_too_often(lost: int, n: int) -> bool:
    """A planned beta lost on ``lost`` of ``n`` simulated flights is dropped (:data:`DROP_LOST_SHARE`)."""
    return lost > 0 and lost >= max(1.0, DROP_LOST_SHARE * n) * (1 - 1e-9)


def _flown_choice(choose: Callable[[Sequence[float]], tuple[Choice, tuple[TestPlan, ...]]],
                  admissible: Sequence[float], space: DesignSpace, prior: Prior, flown: Sequence[FlownTest],
                  options: PlanOptions, rng: np.random.Generator, progress: Progress | None
                  ) -> tuple[Choice, tuple[TestPlan, ...], SimulatedForecast, tuple[float, ...]]:
    """The recommendation that its own simulated forecast does not fail (issue 26).

    The chosen tests are flown in simulation (``options.n_simulated`` plants); a planned beta that
    analyze lost on any plant is dropped from the pool and the choice is made again, for at most
    :data:`SIMULATED_ROUNDS` rounds. The round with the fewest lost tests is kept (the first on a tie).
    Returns the choice, its tests, their simulated forecast and the betas dropped.
    """
    pool = list(admissible)
    dropped: list[float] = []
    best: tuple[Choice, tuple[TestPlan, ...], SimulatedForecast] | None = None
    for _ in range(SIMULATED_ROUNDS):
        choice, tests = choose(pool)
        sim = _simulate(space, prior, flown, tests, options, rng, progress)
        if best is None or sum(sim.lost) < sum(best[2].lost):
            best = (choice, tests, sim)
        bad = {t.beta for t, n in zip(tests, sim.lost) if _lost_too_often(n, int(options.n_simulated))}
        if not bad or not [b for b in pool if b not in bad]:
            break
        dropped += sorted(bad)
        pool = [b for b in pool if b not in bad]
    assert best is not None
    kept = {t.beta for t in best[1]}
    return best[0], best[1], best[2], tuple(b for b in dropped if b not in kept)


#: Largest share of the simulated flights (at least one) that may lose a planned test for the plan still to
#: recommend it.
MAX_LOST_SHARE = 0.25


def _refuse_failing(sim: SimulatedForecast, options: PlanOptions) -> None:
    """Refuse a recommendation its own simulated forecast fails (more than :data:`MAX_LOST_SHARE` lost).

    Raises
    ------
    InputError
        Naming the share lost and the options that make the tests robust.
    """
    n = int(options.n_simulated)
    lost = max(sim.lost, default=0)
    if n > 0 and lost > max(1.0, MAX_LOST_SHARE * n):  # one lost flight is noise, not a pattern
        raise InputError(f"no test within the limits flies reliably: analyze lost the best planned test on {lost} of "
                         f"{n} simulated plausible plants (plants of the prior whose cycle is too small for the "
                         "noise): narrow the gain prior (--k-range), give the measured sensor noise (--noise) or "
                         "allow a larger amplitude (--max-amplitude, --max-h)")


def _simulate(space: DesignSpace, prior: Prior, flown: Sequence[FlownTest], tests: Sequence[TestPlan],
              options: PlanOptions, rng: np.random.Generator, progress: Progress | None) -> SimulatedForecast:
    """The simulated forecast on the draws (more from the same generator when too few)."""
    n = int(options.n_simulated)
    if n <= 0:
        return SimulatedForecast({}, {}, 0)
    plants = space.plants
    lim = space.limits
    if n > len(plants):
        plants = np.vstack([plants, conditioned_draws(space.model, prior, flown, n - len(plants), rng, lim.rate_hz,
                                                      lim.noise_std)])
    return simulated_forecast(space.model, plants, flown, tests, lim, n, seed=options.seed, progress=progress)


#: A parameter is poorly determined when its predicted std exceeds this share of its value (and half the
#: prior's std): a std of a few per cent is a parameter pinned down, whatever the prior was.
POORLY_DETERMINED = 0.1


def plan_notes(tests: Sequence[TestPlan], lowest_f: float, post: dict[str, float], prior_std: dict[str, float],
               limits: PlanLimits, *, centre: Mapping[str, float] | None = None,
               post_data: Mapping[str, float] | None = None) -> list[str]:
    """Which parameters no admissible test pins down, and what would help.

    ``lowest_f`` is the lowest frequency an admissible test reaches [Hz]; ``post`` and ``prior_std``
    the stds after the tests and of the prior; ``centre`` the typical plant's Td, tau [s] and K (a
    parameter whose predicted std is within :data:`POORLY_DETERMINED` of it is not named);
    ``post_data`` the stds from the tests alone (Td is "not pinned down by any test" only when the tests
    leave it loose, whatever the prior says).
    """
    notes = []
    loose = {p: centre is None or post[p] > POORLY_DETERMINED * abs(centre[p]) for p in ("Td", "tau", "K")}
    td_tests_loose = centre is None or post_data is None or post_data["Td"] > POORLY_DETERMINED * abs(centre["Td"])
    best_tdw = min(min(t.td_omega) for t in tests)
    helps = (f"What would help: a lower test frequency (a beta nearer 0 or positive; the lowest here is "
             f"{lowest_f:.3g} Hz), a larger amplitude or more time (more cycles), or a Td from elsewhere (a step "
             "response, a drag model)")
    if td_tests_loose and best_tdw > TD_OMEGA_LIMIT:
        notes.append(f"Td cannot be pinned down by any admissible test: Td*Omega stays above {best_tdw:.1f} (the "
                     f"frequencies hardly depend on Td above {TD_OMEGA_LIMIT:g}). " + helps)
    elif loose["Td"] and post["Td"] > 0.5 * prior_std["Td"]:
        notes.append(f"Td stays poorly determined: its predicted std is {post['Td'] / prior_std['Td']:.0%} of the "
                     f"prior's (Td*Omega up to {max(max(t.td_omega) for t in tests):.1f} over the prior). " + helps)
    if loose["tau"] and post["tau"] > 0.5 * prior_std["tau"]:
        notes.append("tau stays poorly determined: allow a larger amplitude (--max-amplitude) or more time (--time)")
    if loose["K"] and post["K"] > 0.5 * prior_std["K"]:
        notes.append("K stays poorly determined: allow a larger amplitude or relay height")
    max_h = limits.bounds()[1]
    capped = [t for t in tests if t.h >= max_h * (1 - 1e-9)]
    if capped:
        notes.append(f"the relay height is at its limit ({max_h:g}) for beta "
                     f"{', '.join(f'{t.beta:g}' for t in capped)}: the amplitude is below the allowed one")
    return notes


# -- a process plant (any family but eq. (2)): the next relay test for the identified model --------------

def _plan_relays(structure: PlantModel, recorded: AnalysisResult | None, limits: PlanLimits) -> PlanResult:
    """The relay strategy: rank the next relay tests for the model ``recorded`` identified (module docstring).

    Raises
    ------
    InputError
        No identification, another family than ``structure``'s, every parameter known, or no candidate
        relay with a limit cycle on the current model.
    """
    ident = None if recorded is None else recorded.identification
    if recorded is None or ident is None or not recorded.tests:
        raise InputError("no identified model to plan from: the log needs a usable relay test")
    if ident.model.family != structure.family:
        raise InputError(f"the recorded tests were analysed as {ident.model.family}, not {structure.family}: "
                         f"give --model {ident.model.family}")
    model, points = ident.model, ident.points
    names = unknown_parameters(model)
    if not names:
        raise InputError("every parameter is known (--param): there is nothing for a next test to determine")
    tests = recorded.tests
    rate = statistics.median(t.rate_hz for t in tests)
    w_ref = 2 * math.pi * statistics.median(t.frequency_hz for t in tests)
    widen = max(1.0, ident.chi2_dof or 1.0)
    F_now = point_information(model, points, names) / widen
    std_now = point_stds(model, names, F_now, w_ref)
    first = max(tests, key=lambda t: t.relay.h)
    h = limits.max_h if limits.max_h is not None else first.relay.h
    levels = (first.relay.bias + h, first.relay.bias - h)
    a_rec = statistics.median(t.amplitude for t in tests) * h / first.relay.h
    try:
        a_ideal = RelayLaw("ideal", *levels).limit_cycle(model, rate).amplitude
    except InputError:
        a_ideal = a_rec
    noise = {k: (se * math.sqrt(widen), a) for k, (se, a) in relay_noise(points, a_rec).items()}
    out, skipped = forecast_relays(model, candidate_relays(levels, a_ideal), rate, F_now, noise, w_ref,
                                   limits.max_amplitude)
    if not out:
        raise InputError(f"no candidate relay has a limit cycle on the current model: {'; '.join(skipped)}")
    ranked = rank(model, out)
    undetermined = undetermined_parameters(model, std_now, w_ref)
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
    if limits.max_amplitude is not None and not ranked[0].admissible:
        notes += (f"no candidate stays within --max-amplitude {limits.max_amplitude:g}: the first is the least "
                  "over it",)
    return PlanResult(model=model, tests=(), predicted_std=dict(ranked[0].predicted_std or {}), predicted_std_data={},
                      prior_std=std_now, conventional=None, candidates=tuple(ranked), notes=notes, limits=limits,
                      assumptions=assumptions, rate_hz=float(rate), identification=ident, undetermined=undetermined,
                      why=_why(ranked[0], std_now, undetermined, phases))


def _why(best: CandidateTest, std_now: Stds, undetermined: Sequence[str], phases_now: Sequence[float]) -> str:
    """One sentence: what the recommended relay test determines or narrows, and at which phase."""
    after = best.predicted_std or {}
    gains = {n: std_now[n] / s for n, s in after.items() if math.isfinite(s) and s > 0}
    fixed = [n for n in undetermined if n not in best.undetermined]
    f = best.frequency_hz[0] if best.frequency_hz is not None else math.nan
    phase = f"its cycle at {f:.4g} Hz puts a response point at {best.phase_deg:.0f} deg"
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
            f"{after[best_name]:.3g}).")
