"""Issue 39: two effects are named together only if the pair predicts each test from the others
better than each effect alone (leave one test out, :mod:`mrftcli.diagnose.testout`)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from mrftcli.diagnose import pairs as pairs_mod
from mrftcli.diagnose.candidates import fit_linear, search_candidates
from mrftcli.diagnose.heldout import HOLDOUT_THRESHOLD
from mrftcli.diagnose.rows import CandidateFit, PairFit
from mrftcli.diagnose.screen import screen_log
from mrftcli.diagnose.testout import left_out_chi2
from mrftcli.io import ReadOptions, read_flight
from mrftcli.mrft.model import soiptd_model

ROOT = Path(__file__).resolve().parents[1]


def test_the_concealed_drag_predicts_the_left_out_tests_better_than_the_linear_model() -> None:
    """The oracle is the log's concealed truth (quadratic drag, flown by our simulator): the drag
    model fitted on two tests predicts the third far better than the linear model does."""
    path = ROOT / "sample_logs" / "concealed" / "flight_01.mcap"
    truth = json.loads(Path(str(path) + ".truth.json").read_text())
    assert truth["concealed_effect"] == "quadratic_drag"
    model = soiptd_model(truth["Tp"])
    quiet = lambda *a, **k: None  # noqa: E731 - no progress
    screen = screen_log(read_flight(path, ReadOptions(loop="altitude")), model, None, quiet)
    assert len(screen.tests) >= 3
    linear = fit_linear(screen, model, str(path), quiet)
    screen = linear.screen  # the errors the fits were scored on (each test's relay centre a nuisance)
    search = search_candidates(linear, ["quadratic_drag"], model, quiet)
    m, f = search.fits["quadratic_drag"]
    with_drag = left_out_chi2(m, f, screen.tests, screen.recs_fit, screen.recs_all)
    without = left_out_chi2(linear.model, linear.fit, screen.tests, screen.recs_fit, screen.recs_all)
    assert with_drag is not None and without is not None
    assert with_drag < 0.5 * without and without - with_drag > HOLDOUT_THRESHOLD
    # one test alone cannot be left out
    assert left_out_chi2(m, f, screen.tests[:1], screen.recs_fit[:1], screen.recs_all[:1]) is None


def _case(monkeypatch: pytest.MonkeyPatch, chi2: dict[str, float]):
    first = CandidateFit(name="quadratic_drag", bic=300.0, significant=True)
    alone = CandidateFit(name="gain_drift", bic=320.0, significant=True)
    pair = PairFit(name="gain_drift", with_="quadratic_drag", bic=250.0, delta_bic=50.0, significant=True)
    fits = {"quadratic_drag": ("drag", None), "gain_drift": ("drift", None)}
    stub = SimpleNamespace(screen=SimpleNamespace(tests=[], recs_fit=[], recs_all=[]), fits=fits,
                           joint=lambda row: ("pair", None))
    monkeypatch.setattr(pairs_mod, "left_out_chi2", lambda m, f, *a: chi2[m])
    return pairs_mod._pair_predicts_tests(first, pair, [first, alone], stub, [])


def test_a_pair_that_predicts_the_left_out_tests_no_better_gives_the_best_single(monkeypatch) -> None:
    kept, second, said = _case(monkeypatch, {"pair": 95.0, "drag": 100.0, "drift": 400.0})
    assert second is None and kept.name == "quadratic_drag"
    assert said[0].startswith("gain_drift not reported beside quadratic_drag")


def test_a_pair_that_predicts_them_better_than_each_alone_stands(monkeypatch) -> None:
    kept, second, said = _case(monkeypatch, {"pair": 60.0, "drag": 100.0, "drift": 400.0})
    assert kept.name == "quadratic_drag" and second is not None and said == []


def test_the_refits_keep_the_flights_hover_command(monkeypatch: pytest.MonkeyPatch) -> None:
    """A gain drift's trim is the flight's hover command (the first test's relay centre): the refit that
    leaves the first test out must keep it, not take the second test's centre (review R2 of issue 39)."""
    from mrftcli.diagnose import testout
    from mrftcli.diagnose.candidate_model import CandidateModel
    from mrftcli.diagnose.physics import BY_NAME

    made: list = []

    class Recorded(CandidateModel):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            made.append(self)

    monkeypatch.setattr(testout, "CandidateModel", Recorded)
    monkeypatch.setattr(testout, "fit_model", lambda *a, **k: SimpleNamespace(ok=False, chi2=float("nan")))
    tests = [SimpleNamespace(h=0.2, bias=b, t_start=t0) for b, t0 in ((1.00, 5.0), (1.01, 20.0), (1.03, 35.0))]
    model = CandidateModel((BY_NAME["gain_drift"],), tests, 0.05)
    assert model.bias_first == 1.00
    assert testout.left_out_chi2(model, SimpleNamespace(theta=None), tests, [None] * 3, [None] * 3) is None
    assert made and made[0].bias_first == 1.00 and made[0].bias_mean == model.bias_mean
