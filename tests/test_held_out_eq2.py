"""Held-out predictions for eq. (2) (``analyze`` without ``--model``, issue 36): each test's cycle
predicted by the model identified from the other tests, against an independent oracle.

The oracle is written here from the series definition (it imports nothing of mrftcli): the periodic
output of eq. (2) under a square wave of frequency w is the sum over odd harmonics of
``(4 h / (pi k)) |W(j k w)| sin(k w t + arg W(j k w))``, and the MRFT's cycle is the w at which the
output at the switch from -h to +h is ``-beta`` times its maximum (checks.md section 2). It is first
checked against the exact figures of checks.md section 1. The flights are simulated by
tests/process_sim.py (an exact ZOH loop with the checks.md MRFT rule, sharing no code with mrftcli).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import optimize

from mrftcli.mrft.model import soiptd_model
from mrftcli.analyze import AnalysisResult, AnalyzeOptions, analyze_flight
from mrftcli.analyze.estimate import beta_used
from mrftcli.analyze.held_out import NOTHING_HELD_OUT, ROUTE_FUNDAMENTALS, ROUTE_POINTS, HeldOut, held_out_eq2
from mrftcli.analyze.held_out_harmonic import FALLBACK_WORDS, FEW_DOF_WORDS, ROUTE_NOTE
from mrftcli.cli.analyze import format_analysis
from mrftcli.io import ReadOptions, read_flight
from mrftcli.jsonable import to_jsonable

sys.path.insert(0, str(Path(__file__).parent))
from process_sim import Window, simulate, write_csv  # noqa: E402

#: checks.md section 1: Tp 0.1 s, Td 1/1.42 s, tau 0.06 s, K Td = 1
PLANT = {"Tp": 0.1, "Td": 1 / 1.42, "tau": 0.06, "K": 1.42}


def _output(w: float, p: dict[str, float], n: int, grid: int) -> np.ndarray:
    """One period of the output under a unit square wave (+1 on the first half), on ``grid`` points."""
    k = np.arange(1, 2 * n, 2)
    s = 1j * k * w
    g = p["K"] * p["Td"] * np.exp(-p["tau"] * s) / (s * (p["Tp"] * s + 1) * (p["Td"] * s + 1))
    th = np.linspace(0, 2 * np.pi, grid, endpoint=False)
    return (4 / np.pi) * (np.sin(np.outer(th, k) + np.angle(g)) * (np.abs(g) / k)).sum(axis=1)


def exact_cycle(beta: float, p: dict[str, float]) -> tuple[float, float]:
    """The MRFT cycle of eq. (2) at ``beta`` (h = 1): frequency [Hz] and amplitude (module docstring)."""
    def crossing(lw: float) -> float:
        y = _output(math.exp(lw), p, 400, 1024)
        return float(y[0] + beta * y.max())

    # the describing function's frequency brackets the root
    w0 = optimize.brentq(lambda w: math.atan(p["Tp"] * w) + math.atan(p["Td"] * w) + p["tau"] * w
                         - (math.pi / 2 - math.asin(beta)), 1e-3, 1e4)
    w = math.exp(optimize.brentq(crossing, math.log(w0) - 0.5, math.log(w0) + 0.5, xtol=1e-12))
    return w / (2 * math.pi), float(_output(w, p, 4000, 4096).max())


def test_the_oracle_gives_the_exact_figures_of_checks_md() -> None:
    f, a = exact_cycle(-0.4, PLANT)
    assert f == pytest.approx(0.70564, rel=5e-5) and a == pytest.approx(0.078530, rel=5e-5)
    f, a = exact_cycle(-0.7, PLANT)
    assert f == pytest.approx(1.01884, rel=5e-5) and a == pytest.approx(0.035602, rel=5e-5)


def _flight(tmp_path: Path, betas: tuple[float, ...], seed: int = 0):
    """One log of MRFT tests at ``betas`` (h = 1, 500 Hz, noise 2e-4), each from rest (an integrating
    plant keeps its offset between tests, which can lock an MRFT up at its start)."""
    parts, off = [], 0.0
    for k, beta in enumerate(betas):
        t, u, y = simulate("eq2", PLANT, [Window("mrft", 1.0, -1.0, beta=beta, duration=14.0)], 500.0, 2e-4,
                           seed=seed + k, start=0.01)
        parts.append((t + off, u, y))
        off += t[-1] + 0.002
    t, u, y = (np.concatenate(z) for z in zip(*parts))
    path = tmp_path / "eq2.csv"
    write_csv(str(path), t, u, y)
    return read_flight(path, ReadOptions(command_topic="u_relay", output_topic="y_output"), echo_warnings=False)


@pytest.fixture(scope="module")
def three(tmp_path_factory: pytest.TempPathFactory) -> AnalysisResult:
    flight = _flight(tmp_path_factory.mktemp("ho3"), (-0.4, -0.7, -0.55))
    return analyze_flight(flight, soiptd_model(PLANT["Tp"]), options=AnalyzeOptions(n_bootstrap=100, refine_waveform=False))


def test_each_held_out_cycle_is_the_plants_exact_cycle_within_the_stated_sigma(three: AnalysisResult) -> None:
    assert len(three.tests) == 3 and len(three.held_out) == 3
    for test, ho in zip(three.tests, three.held_out):
        assert ho is not None and ho.frequency_hz is not None and ho.amplitude is not None, ho
        assert ho.frequency_sigma_hz is not None and ho.amplitude_sigma is not None
        assert not ho.note.startswith(FALLBACK_WORDS) and ho.route == ROUTE_POINTS, ho  # not its fallback
        f, a = exact_cycle(beta_used(test, 0.0), PLANT)  # the plant's cycle at the level the relay switched
        assert abs(ho.frequency_hz - f) < 3 * ho.frequency_sigma_hz, (ho, f)
        assert abs(ho.amplitude - a) < 3 * ho.amplitude_sigma, (ho, a)
        # the stated sigma is an interval, not a blanket: within 1 % of the plant's cycle
        assert ho.frequency_sigma_hz < 0.01 * f and ho.amplitude_sigma < 0.02 * a
        assert ho.frequency_z is not None and abs(ho.frequency_z) < 3
        assert ho.frequency_z == pytest.approx((test.frequency_hz_mean - ho.frequency_hz) / ho.frequency_sigma_hz)


def test_a_wrong_plant_misses_its_held_out_cycle(three: AnalysisResult) -> None:
    """The check can fail: the tests of one plant predicted from another's (Td doubled) miss by many sigma."""
    wrong = dict(PLANT, Td=2 * PLANT["Td"])
    f, _ = exact_cycle(beta_used(three.tests[2], 0.0), wrong)
    ho = three.held_out[2]
    assert ho is not None and ho.frequency_hz is not None and ho.frequency_sigma_hz is not None
    assert abs(ho.frequency_hz - f) > 5 * ho.frequency_sigma_hz


def test_json_and_table_hold_the_families_record(three: AnalysisResult) -> None:
    d = to_jsonable(three.to_json())
    assert d["schema_version"] == 4
    for row, ho in zip(d["tests"], three.held_out):
        assert ho is not None and row["held_out"] == to_jsonable(ho.to_json())
        assert set(row["held_out"]) == {*HeldOut(None, None).to_json(), "route"}  # the families' keys and the route
        assert row["held_out"]["route"] == ROUTE_POINTS
    back = AnalysisResult.from_json(d)
    assert back.held_out == three.held_out and to_jsonable(back.to_json()) == d
    text = format_analysis(three)
    assert "held-out f" in text and f"{three.held_out[0].frequency_hz:.4f}" in text


def test_a_version_2_record_reads_without_held_out(three: AnalysisResult) -> None:
    d = to_jsonable(three.to_json())
    old = {**d, "schema_version": 2, "tests": [{k: v for k, v in t.items() if k != "held_out"} for t in d["tests"]]}
    back = AnalysisResult.from_json(old)
    assert back.held_out == (None, None, None) and back.tau == three.tau
    assert [t["held_out"] for t in to_jsonable(back.to_json())["tests"]] == [None] * 3
    assert "held-out f" not in format_analysis(back)


def test_two_tests_each_predicted_from_the_others_fundamental_and_3rd_harmonic(tmp_path: Path) -> None:
    """Issue 41: the other test's 3rd harmonic is a second frequency, so one other test determines eq. (2) (its
    fundamental and 3rd harmonic: four figures for Td, tau, K): the plant's exact cycle (the series oracle above)
    within the fit's own sigma, which is an interval (under 2 %), not a blanket; one test holds nothing out."""
    flight = _flight(tmp_path, (-0.4, -0.7))
    result = analyze_flight(flight, soiptd_model(PLANT["Tp"]), options=AnalyzeOptions(n_bootstrap=100, refine_waveform=False))
    for test, ho in zip(result.tests, result.held_out):
        assert ho is not None and ho.frequency_hz is not None and ho.frequency_sigma_hz is not None, ho
        f, a = exact_cycle(beta_used(test, 0.0), PLANT)
        assert abs(ho.frequency_hz - f) < 3 * ho.frequency_sigma_hz and ho.frequency_sigma_hz < 0.02 * f, (ho, f)
        assert ho.amplitude is not None and ho.amplitude_sigma is not None
        assert abs(ho.amplitude - a) < 3 * ho.amplitude_sigma and ho.amplitude_sigma < 0.04 * a, (ho, a)
    assert ROUTE_NOTE in result.notes and f"note: {ROUTE_NOTE}" in format_analysis(result)
    # one other test: 4 figures for Td, tau and K, one degree of freedom, so the std is not scaled by the scatter
    assert all(ho.note == f"{FEW_DOF_WORDS} (1 degree of freedom)" for ho in result.held_out), result.held_out
    assert f"held-out tests 1, 2: {FEW_DOF_WORDS} (1 degree of freedom)" in format_analysis(result)
    # the fundamentals alone (the UFM's route) cannot: one beta's slice does not give Td and tau
    ufm = held_out_eq2(soiptd_model(PLANT["Tp"]), result.tests, [beta_used(t, 0.0) for t in result.tests])
    assert all(ho.frequency_hz is None and "does not determine Td and tau" in ho.note for ho in ufm)
    (only,) = held_out_eq2(soiptd_model(PLANT["Tp"]), result.tests[:1], [result.tests[0].beta_effective])
    assert only.frequency_hz is None and only.note == NOTHING_HELD_OUT


def test_the_families_read_a_version_1_held_out() -> None:
    """A family's analysis record version 1 wrote ``held_out`` without the sigma and z keys: they read as None."""
    ho = HeldOut.from_json({"frequency_hz": 0.5, "amplitude": 2.0, "note": "x"})
    assert ho == HeldOut(0.5, 2.0, "x") and ho.frequency_sigma_hz is None and ho.amplitude_z is None
    assert ho.describe(0.51, 2.1, "K") == "f 0.5000 Hz (measured 0.5100), amplitude 2 K (measured 2.1); x"


def test_a_version_1_family_analysis_reads_with_its_held_out(tmp_path: Path) -> None:
    """A family's analysis record schema 2 gave ``held_out`` the shared record's sigma and z keys (null for the families);
    a version-1 JSON (without them) reads to the same analysis."""
    from mrftcli.analyze import analyze_flight
    from mrftcli.analyze.record import AnalysisResult
    from mrftcli.mrft.families import family_model

    windows = [Window("hysteresis", 1.5, -0.5, eps=e, duration=30.0) for e in (0.05, 0.3)]
    t, u, y = simulate("fopdt", {"K": 2.0, "T": 1.0, "tau": 0.3}, windows, 100.0, 0.01, seed=1)
    write_csv(str(tmp_path / "fopdt.csv"), t, u, y)
    flight = read_flight(tmp_path / "fopdt.csv", ReadOptions(command_topic="u_relay", output_topic="y_output"),
                         echo_warnings=False)
    result = analyze_flight(flight, family_model("fopdt"))
    d = to_jsonable(result.to_json())
    assert d["schema_version"] == 3 and all(set(r["held_out"]) == set(HeldOut(None, None).to_json())
                                            for r in d["tests"])
    v1 = {**d, "schema_version": 1,
          "tests": [{**r, "held_out": {k: r["held_out"][k] for k in ("frequency_hz", "amplitude", "note")}}
                    for r in d["tests"]]}
    assert to_jsonable(AnalysisResult.from_json(v1).to_json()) == d


def test_a_one_test_flight_says_nothing_is_held_out(tmp_path: Path) -> None:
    """One test is a partial result (exit 6): its row says nothing is held out, in the JSON and the text."""
    from mrftcli.cli.analyze import format_partial
    from mrftcli.errors import InsufficientDataError

    with pytest.raises(InsufficientDataError) as err:
        analyze_flight(_flight(tmp_path, (-0.4,)), soiptd_model(PLANT["Tp"]), options=AnalyzeOptions(n_bootstrap=100))
    (row,) = err.value.partial["tests"]
    assert row["held_out"]["frequency_hz"] is None and row["held_out"]["note"] == NOTHING_HELD_OUT
    assert f"held-out test 1: {NOTHING_HELD_OUT}" in format_partial(err.value)


def test_held_out_notes_name_the_tests_by_the_tables_numbers():
    # a test left out before the fit (0 stable cycles) keeps its number in the table: the notes of the
    # tests used must name them by those numbers (2 and 3), not by their rank among the used tests
    from mrftcli.analyze.held_out import HeldOut, held_out_notes

    why = "the other test alone does not determine Td and tau"
    held = [HeldOut(None, None, why), HeldOut(None, None, why)]
    assert held_out_notes(held, [2, 3]) == [f"held-out tests 2, 3: {why}"]
    assert held_out_notes(held) == [f"held-out tests 1, 2: {why}"]


def test_the_few_dof_note_reads_right_for_one_test_and_several() -> None:
    # the line joins one note over several tests: no singular pronoun for "the prediction" ("its std" read
    # wrong on a two-test log's "held-out tests 1, 2: ...")
    from mrftcli.analyze.held_out import held_out_notes

    note = f"{FEW_DOF_WORDS} (1 degree of freedom)"
    two = held_out_notes([HeldOut(0.78, 0.058, note), HeldOut(1.38, 0.055, note)])
    one = held_out_notes([HeldOut(0.78, 0.058, note), None])
    assert two == [f"held-out tests 1, 2: {note}"] and one == [f"held-out test 1: {note}"]
    assert not any(line.split(": ", 1)[1].startswith(("its ", "their ")) for line in two + one), (two, one)
    assert "std from the other tests' stated errors alone" in two[0]


def test_a_held_out_record_without_a_route_reads_and_writes_as_it_was() -> None:
    """The ``route`` key is additive: a record written before it (or a family's, one route) reads with route ""
    and writes back without the key; a route read back is kept; the fallback keeps the fundamentals' route."""
    from mrftcli.analyze.held_out_harmonic import _fallback

    old = {"frequency_hz": 0.5, "amplitude": 2.0, "note": "", "frequency_sigma_hz": 0.01, "amplitude_sigma": 0.1,
           "frequency_z": 1.0, "amplitude_z": -1.0}
    ho = HeldOut.from_json(old)
    assert ho.route == "" and ho.to_json() == old
    new = HeldOut.from_json({**old, "route": ROUTE_POINTS})
    assert new.route == ROUTE_POINTS and HeldOut.from_json(new.to_json()) == new
    back = _fallback(HeldOut.against(0.5, 2.0, (0.51, 0.01, 2.1, 0.1), (0.01, 0.1), route=ROUTE_FUNDAMENTALS), "why")
    assert back.route == ROUTE_FUNDAMENTALS and back.note.startswith(FALLBACK_WORDS)
