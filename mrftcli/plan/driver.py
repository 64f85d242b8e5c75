"""``plan_tests``: the driver over the planner's stages (draws -> information of the flown tests ->
candidates -> greedy search -> forecast -> notes).

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
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..progress import Progress, report
from ..validate import check_beta, check_time
from .draws import conditioned_draws
from .fisher import flown_information, posterior_covariance
from .forecast import SimulatedForecast, simulated_forecast, std_median, std_range
from .noise import MIN_SWITCH_GAP
from .records import CandidateTest, Conventional, FlightLimits, FlownTest, PlanResult, Prior, TestPlan
from .search import (Choice, DesignSpace, Information, admissible_betas, assess, choose_tests, conventional_information,
                     design_space, recommended_test, with_first_round)

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
        (:func:`~mrftcli.plan.forecast.simulated_std`, about 0.1 s each): ``PlanResult.simulated_std``
        and its range.
    seed : int
        Seed of the draws.
    """

    n_tests: int | None = None
    betas: Sequence[float] = DEFAULT_BETAS
    n_draws: int = 8
    n_simulated: int = 0
    seed: int = 0


def plan_tests(Tp: float, prior: Prior, limits: FlightLimits, *, flown: Sequence[FlownTest] = (),
               options: PlanOptions = PlanOptions(), progress: Progress | None = None) -> PlanResult:
    """Recommend the next MRFT test(s) (docs/plan.md; the stages are this package's modules).

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
    options : PlanOptions
        Number of tests, beta grid, draws, simulated flights and seed.
    progress : Progress, optional
        Called as ``progress(done, total, "planning")`` per beta and test.

    Returns
    -------
    PlanResult

    Raises
    ------
    InputError
        Bad arguments, or limits that admit no test (the message says which limit to relax).

    Examples
    --------
    >>> from mrftcli.plan import FlightLimits, PlanOptions, Prior, plan_tests
    >>> prior = Prior(Td=(0.3, 3.0), tau=(0.01, 0.08), K=(1.0, 10.0))
    >>> limits = FlightLimits(max_amplitude=0.05, max_h=2.0, time_s=30.0, rate_hz=200.0, noise_std=0.0005)
    >>> p = plan_tests(0.04, prior, limits, options=PlanOptions(n_tests=2, n_draws=3, betas=(-0.2, -0.5, -0.8)))
    >>> len(p.tests), all(-0.9 <= t.beta <= -0.1 for t in p.tests)
    (2, True)
    """
    Tp = check_time("Tp", Tp)
    betas, n_tests = _resolve(options, flown)
    rng = np.random.default_rng(options.seed)
    plants = conditioned_draws(Tp, prior, flown, max(int(options.n_draws), 1), rng, limits.rate_hz, limits.noise_std)
    total = len(betas) * (n_tests + 1)
    space = design_space(Tp, plants, limits, limits.time_s / n_tests, betas,
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
    return PlanResult(Tp=Tp, tests=tests, predicted_std=post, predicted_std_data=std_median(choice.information.data,
                                                                                              plants),
                      simulated_std=sim.std, simulated_std_range=sim.std_range, n_simulated=sim.n_used,
                      predicted_std_data_range=std_range(choice.information.data, plants),
                      prior_std=prior_std, conventional=conv,
                      candidates=tuple(with_first_round(candidates[b], choice.first_round) for b in betas),
                      notes=tuple(notes), flown=tuple(flown), limits=limits)


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
        start = start.plus([flown_information(space.Tp, p, f, lim.rate_hz, lim.noise_std) for p in space.plants])
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
        plants = np.vstack([plants, conditioned_draws(space.Tp, prior, flown, n - len(plants), rng, lim.rate_hz,
                                                      lim.noise_std)])
    return simulated_forecast(space.Tp, plants, flown, tests, lim, n, seed=options.seed, progress=progress)


#: A parameter is poorly determined when its predicted std exceeds this share of its value (and half the
#: prior's std): a std of a few per cent is a parameter pinned down, whatever the prior was.
POORLY_DETERMINED = 0.1


def plan_notes(tests: Sequence[TestPlan], lowest_f: float, post: dict[str, float], prior_std: dict[str, float],
               limits: FlightLimits, *, centre: Mapping[str, float] | None = None,
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
    capped = [t for t in tests if t.h >= limits.max_h * (1 - 1e-9)]
    if capped:
        notes.append(f"the relay height is at its limit ({limits.max_h:g}) for beta "
                     f"{', '.join(f'{t.beta:g}' for t in capped)}: the amplitude is below the allowed one")
    return notes
