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
