"""Issue 39: each test's relay centre (the hold's trim when the test began) is a per-test nuisance of the
diagnosis, sized by how far the tests' centres scatter (:func:`mrftcli.diagnose.screen.with_trim_nuisance`)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mrftcli.diagnose.candidates import fit_linear
from mrftcli.diagnose.features import FEATURE_NAMES
from mrftcli.diagnose.fit import fit_base
from mrftcli.diagnose.candidate_model import CandidateModel
from mrftcli.diagnose.starts import theta_bounds
from mrftcli.diagnose.screen import screen_log, trim_spread, with_trim_nuisance
from mrftcli.io import ReadOptions, read_flight
from mrftcli.mrft.model import soiptd_model

ROOT = Path(__file__).resolve().parents[1]
LOG = ROOT / "sample_logs" / "concealed" / "flight_03.mcap"  # clean, our simulator: one trim throughout
QUIET = lambda *a, **k: None  # noqa: E731 - no progress


@pytest.fixture(scope="module")
def flown():
    truth = json.loads(Path(str(LOG) + ".truth.json").read_text())
    assert truth["concealed_effect"] is None
    model = soiptd_model(truth["Tp"])
    return model, screen_log(read_flight(LOG, ReadOptions(loop="altitude")), model, None, QUIET)


def test_one_trim_throughout_leaves_the_screen_alone(flown) -> None:
    model, screen = flown
    assert len(screen.tests) >= 2 and trim_spread(list(screen.flown)) == 0.0
    linear = fit_linear(screen, model, str(LOG), QUIET)
    assert linear.screen is screen


def test_the_balance_widens_by_the_closed_form_of_an_offset(flown) -> None:
    """The oracle: on eq. (2) (an integrator) the mean command over a limit cycle is the trim, so relay
    levels offset by d give a half-period balance of exactly -d / (2 h), whatever Td and tau are."""
    model, screen = flown
    offsets = np.array([0.004, -0.002, 0.001])[: len(screen.tests)]
    tests = [replace(t, bias=t.bias + d) for t, d in zip(screen.tests, offsets)]
    assert [s.index for s in screen.flown] == [t.index for t in screen.tests]
    moved = replace(screen, tests=tests, flown=tuple(replace(s, bias=s.bias + d) for s, d in zip(screen.flown, offsets)))
    spread = trim_spread(list(moved.flown))
    assert spread == pytest.approx(float(np.std(offsets, ddof=1)), rel=1e-9)
    lin = CandidateModel(None, tests, model.Tp)
    lo, hi = theta_bounds(None, tests)
    base = fit_base(lin, tests, model.Tp, lo, hi, moved.recs_fit)
    widened = with_trim_nuisance(moved, lin, base)
    ib = FEATURE_NAMES.index("balance")
    for t, (_, s0), (_, s1) in zip(tests, moved.recs_fit, widened.recs_fit):
        added = np.sqrt(s1[ib] ** 2 - s0[ib] ** 2)
        assert added == pytest.approx(spread / (2.0 * t.h), rel=2e-3)
        # the period and the amplitude move only at second order in the offset
        for name in ("period", "log_amplitude"):
            k = FEATURE_NAMES.index(name)
            assert s1[k] == pytest.approx(s0[k], rel=0.02)
    for a, b in ((moved.recs_hold, widened.recs_hold), (moved.recs_all, widened.recs_all)):
        assert all(np.all(s1 >= s0) for (_, s0), (_, s1) in zip(a, b))
