"""One analyze route (issue 36): ``analyze_flight(flight, model, options=)`` runs eq. (2)'s strategy for
a :class:`~mrftcli.mrft.model.LoopModel` and the direct fit for every other family, the relay, windows
and operating point in :class:`~mrftcli.analyze.AnalyzeOptions`; ``identify`` takes Tp inside the model.

The flights come from tests/process_sim.py (an exact ZOH loop with the checks.md MRFT rule, sharing no
code with mrftcli); the figures are checked against the plants that flew them.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from mrftcli.analyze import AnalysisResult, AnalyzeOptions, RelayOptions, analyze_flight, analyze_path
from mrftcli.errors import InputError, InsufficientDataError
from mrftcli.io import ReadOptions, read_flight
from mrftcli.mrft.families import family_model
from mrftcli.mrft.identify import TestMeasurement, identify
from mrftcli.mrft.model import LoopModel, soiptd_model

sys.path.insert(0, str(Path(__file__).parent))
from process_sim import Window, simulate, write_csv  # noqa: E402

#: checks.md section 1: Tp 0.1 s, Td 1/1.42 s, tau 0.06 s, K Td = 1
PLANT = {"Tp": 0.1, "Td": 1 / 1.42, "tau": 0.06, "K": 1.42}
FOPDT = {"K": 2.0, "T": 1.5, "tau": 0.3}
READ = ReadOptions(command_topic="u_relay", output_topic="y_output")


def _log(tmp_path: Path, family: str, params: dict[str, float], windows: list[Window], name: str) -> Path:
    """One CSV log of the windows flown one after the other, each from rest (h = 1, 500 Hz, noise 2e-4)."""
    parts, off = [], 0.0
    for k, w in enumerate(windows):
        t, u, y = simulate(family, params, [w], 500.0, 2e-4, seed=k, start=0.01)
        parts.append((t + off, u, y))
        off += t[-1] + 0.002
    t, u, y = (np.concatenate(z) for z in zip(*parts))
    path = tmp_path / name
    write_csv(str(path), t, u, y)
    return path


@pytest.fixture(scope="module")
def eq2_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _log(tmp_path_factory.mktemp("route"), "eq2", PLANT,
                [Window("mrft", 1.0, -1.0, beta=b, duration=14.0) for b in (-0.4, -0.7)], "eq2.csv")


def test_eq2_through_the_model_object_finds_the_plant(eq2_log: Path) -> None:
    result = analyze_path(eq2_log, soiptd_model(PLANT["Tp"]), read=READ,
                          options=AnalyzeOptions(n_bootstrap=50, refine_waveform=False))
    assert isinstance(result, AnalysisResult) and result.kind == "soiptd" and result.Tp == PLANT["Tp"]
    assert result.model.Td == pytest.approx(PLANT["Td"], rel=0.05)
    assert result.model.tau == pytest.approx(PLANT["tau"], abs=2e-3)


def test_eq2_windows_in_the_options_keep_only_their_tests(eq2_log: Path) -> None:
    """A window around the first test leaves one beta: the partial result, not a silent fit."""
    flight = read_flight(eq2_log, READ, echo_warnings=False)
    first_end = float(flight.command.t[0]) + 14.0
    with pytest.raises(InsufficientDataError, match="one beta"):
        analyze_flight(flight, soiptd_model(PLANT["Tp"]),
                       options=AnalyzeOptions(n_bootstrap=50, windows=((float(flight.command.t[0]), first_end),)))


@pytest.mark.parametrize("options, words", [
    (AnalyzeOptions(relay=RelayOptions("hysteresis", None, 0.01)), "--relay"),
    (AnalyzeOptions(baseline=(0.0, 0.1)), "--baseline"),
])
def test_eq2_refuses_a_process_models_options(eq2_log: Path, options: AnalyzeOptions, words: str) -> None:
    flight = read_flight(eq2_log, READ, echo_warnings=False)
    with pytest.raises(InputError, match=words):
        analyze_flight(flight, soiptd_model(PLANT["Tp"]), options=options)


def test_a_family_model_takes_the_direct_fit_with_the_relay_stated(tmp_path: Path) -> None:
    log = _log(tmp_path, "fopdt", FOPDT, [Window("mrft", 1.0, -1.0, beta=b, duration=40.0) for b in (-0.2, -0.5)],
               "fopdt.csv")
    result = analyze_path(log, family_model("fopdt"), read=READ,
                          options=AnalyzeOptions(relay=RelayOptions("mrft")))
    assert result.kind == "family" and len(result.tests) == 2
    assert all(t.relay.kind == "mrft" for t in result.tests)
    assert result.identification is not None
    values = {e.name: e.value for e in result.identification.estimates}
    assert values["T"] == pytest.approx(FOPDT["T"], rel=0.05)
    assert values["tau"] == pytest.approx(FOPDT["tau"], rel=0.05)


def test_unknown_relay_kind_is_refused_on_creation() -> None:
    with pytest.raises(InputError, match="unknown relay"):
        AnalyzeOptions(relay=RelayOptions("bang-bang"))


def test_identify_takes_tp_and_k_inside_the_model() -> None:
    """checks.md section 1: the paper's two tests give Td, tau; one test with K known gives them too."""
    tests = [TestMeasurement(-0.4, 0.705643, amplitude=0.078530, h=1.0),
             TestMeasurement(-0.7, 1.018843, amplitude=0.035602, h=1.0)]
    r = identify(tests, soiptd_model(0.1))
    assert r.model.Td == pytest.approx(PLANT["Td"], rel=1e-3) and r.model.tau == pytest.approx(0.06, abs=1e-4)
    one = identify(tests[1:], soiptd_model(0.1, K=PLANT["K"]))
    assert one.model.Td == pytest.approx(PLANT["Td"], rel=1e-2) and one.model.tau == pytest.approx(0.06, abs=1e-3)
    with pytest.raises(InputError, match="Tp known"):
        identify(tests, LoopModel(0.1, 1.0, 0.0, known=frozenset()))
    with pytest.raises(InputError, match="fopdt model is identified from ResponsePoint"):
        identify(tests, family_model("fopdt"))  # type: ignore[arg-type]
