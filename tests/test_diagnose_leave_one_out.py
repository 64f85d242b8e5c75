"""Issue 39: two effects are named together only if each earns its place (leave-one-out on the pair)."""

from __future__ import annotations

from mrftcli.diagnose.pairs import _first_earns_place
from mrftcli.diagnose.rows import CandidateFit, HeldOut, PairFit


def _held(nrmse: float, chi2: float) -> HeldOut:
    return HeldOut(kind="waveform", nrmse=nrmse, nrmse_timed=nrmse, feature_chi2=chi2)


def _rows(pair_bic: float, pair_chi2: float, pair_nrmse: float):
    # drag found first (BIC 300), the rate limit alone (BIC 200) explains the held-out cycles to chi^2 60
    first = CandidateFit(name="quadratic_drag", bic=300.0, held_out_after=_held(0.20, 400.0), significant=True)
    alone = CandidateFit(name="actuator_rate_limit", bic=200.0, held_out_after=_held(0.05, 60.0), significant=True)
    pair = PairFit(name="actuator_rate_limit", with_="quadratic_drag", bic=pair_bic, delta_bic=300.0 - pair_bic,
                   held_out_before=first.held_out_after, held_out_after=_held(pair_nrmse, pair_chi2), significant=True)
    return first, pair, [first, alone]


def test_a_first_effect_that_adds_nothing_to_the_second_alone_is_dropped():
    # the pair's BIC is 4 below the rate limit alone and its held-out chi^2 5 lower: chance
    first, pair, rows = _rows(pair_bic=196.0, pair_chi2=55.0, pair_nrmse=0.048)
    fits = {"quadratic_drag": None, "actuator_rate_limit": None}
    kept, second, said = _first_earns_place(first, pair, rows, fits)
    assert second is None and kept.name == "actuator_rate_limit"
    assert said and said[0].startswith("quadratic_drag not reported beside actuator_rate_limit")


def test_a_first_effect_that_earns_its_place_is_kept():
    # against the rate limit alone the pair gains 40 in BIC and 30 in held-out chi^2, with a lower error
    first, pair, rows = _rows(pair_bic=160.0, pair_chi2=30.0, pair_nrmse=0.02)
    fits = {"quadratic_drag": None, "actuator_rate_limit": None}
    kept, second, said = _first_earns_place(first, pair, rows, fits)
    assert (kept, second, said) == (first, pair, [])


def test_without_a_significant_second_alone_the_pair_stands():
    # a rate limit that only helps beside the drag (alone not significant): nothing to leave out
    first, pair, rows = _rows(pair_bic=196.0, pair_chi2=55.0, pair_nrmse=0.048)
    rows[1] = CandidateFit(name="actuator_rate_limit", bic=290.0, held_out_after=_held(0.3, 500.0), significant=False)
    kept, second, said = _first_earns_place(first, pair, rows, {"quadratic_drag": None, "actuator_rate_limit": None})
    assert (kept, second, said) == (first, pair, [])


def test_a_held_out_nrmse_rise_within_the_cycle_scatter_is_chance():
    # oracle: recorded cycles = a true cycle + each cycle's own smooth scatter (three random harmonics);
    # two models with the same true error (so neither is worse) scored as held_out_score does, the
    # scatter's share (common to both) taken out. The rule must call "worse" rarely (its bound is twice
    # the cross term's largest standard deviation), and must call a model with five times the error worse.
    import math

    import numpy as np

    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 2 * np.pi, 200, endpoint=False)
    truth = np.sin(t) + 0.2 * np.sin(3 * t)
    n, s_scatter = 15, 0.08
    false_alarms, misses, trials = 0, 0, 400
    for _ in range(trials):
        eps = sum(s_scatter * rng.standard_normal((n, 1)) * np.sin(k * t + rng.uniform(0, 6.3, (n, 1)))
                  for k in (1, 2, 3)) / math.sqrt(1.5)
        y = truth + eps
        sst = float(np.sum(np.var(y, axis=1)))
        floor = float(np.sum((eps - eps.mean(axis=0)) ** 2) / t.size) * n / (n - 1)
        err = 0.03 * np.std(truth)

        def score(model, y, floor, sst):
            sse = float(np.sum((y - model) ** 2) / t.size)
            return HeldOut("waveform", nrmse=math.sqrt(max(sse - floor, 0.0) / sst),
                           scatter_nrmse=math.sqrt(floor / sst), cycles=n)

        phase = rng.uniform(0, 6.3)
        a, b, worse = (score(truth + f * err * math.sqrt(2) * np.sin(2 * t + phase + shift), y, floor, sst)
                       for f, shift in ((1, 0.0), (1, 2.0), (5, 0.0)))
        false_alarms += a.worse_beyond_chance(b)
        misses += not worse.worse_beyond_chance(b)
    assert false_alarms / trials < 0.05
    assert misses / trials < 0.05
    # the RotorPy sensor lag of the docstring: within chance; the rule without a scatter share: any rise
    before = HeldOut("waveform", nrmse=0.0302, scatter_nrmse=0.082, cycles=15)
    assert not HeldOut("waveform", nrmse=0.0322, scatter_nrmse=0.082, cycles=15).worse_beyond_chance(before)
    assert HeldOut("waveform", nrmse=0.0322).worse_beyond_chance(HeldOut("waveform", nrmse=0.0302))
