"""``compare`` on process-family analyses (issue 36: one parameter record everywhere, compare included).

The recordings come from tests/process_sim.py (independent of mrftcli); the oracle is the simulated
plants' truth: the same FOPDT recorded twice is unchanged, a FOPDT whose delay grew from 0.3 s to 0.4 s
has its tau flagged (and only tau), and a FOPDT analysis is not compared with a SOPDT one.
"""

from __future__ import annotations

import json
import os
import sys

import pytest
from cli_helpers import run_main

sys.path.insert(0, os.path.dirname(__file__))
from process_sim import Window, simulate, write_csv  # noqa: E402

from mrftcli.analyze import analyze_path  # noqa: E402
from mrftcli.compare import CompareOptions, compare  # noqa: E402
from mrftcli.io import ReadOptions  # noqa: E402
from mrftcli.mrft.families import family_model  # noqa: E402

_READ = ReadOptions(command_topic="u_relay", output_topic="y_output")
_WINDOWS = [Window("hysteresis", 1.0, -1.0, eps=0.05, duration=25.0),
            Window("hysteresis", 1.5, -0.5, eps=0.3, duration=25.0)]


@pytest.fixture(scope="module")
def analyses(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    folder = tmp_path_factory.mktemp("families")
    out = {}
    for name, family, truth in (("before", "fopdt", {"tau": 0.3}), ("after", "fopdt", {"tau": 0.4}),
                                ("before_sopdt", "sopdt", {"tau": 0.3})):
        t, u, y = simulate("fopdt", dict(K=2.0, T=1.0, **truth), _WINDOWS, 100.0, 0.01, seed=1)
        log = folder / f"{name}.csv"
        write_csv(str(log), t, u, y)
        result = analyze_path(log, family_model(family), read=_READ)
        path = folder / f"{name}.json"
        path.write_text(json.dumps(result.to_json()))
        out[name] = str(path)
    return out


def test_a_family_compared_with_itself_is_unchanged_by_name(analyses):
    result = compare(analyses["before"], analyses["before"], CompareOptions())
    assert [c.parameter for c in result.changes] == ["tau", "K", "T"]  # eq. (2)'s names first, then the family's
    assert all(c.verdict == "unchanged" and c.change == 0 for c in result.changes) and not result.missing


def test_a_grown_delay_is_flagged_and_nothing_else(analyses):
    result = compare(analyses["before"], analyses["after"], CompareOptions())
    by_name = {c.parameter: c for c in result.changes}
    assert by_name["tau"].significant and by_name["tau"].change == pytest.approx(0.1, abs=0.01)
    assert not by_name["K"].significant and not by_name["T"].significant
    run = run_main("compare", analyses["before"], analyses["after"], "--fail-on", "tau:+50ms")
    assert run.returncode == 9 and "tau" in run.stderr and "T s" in run.stdout


def test_a_familys_k_is_shown_in_its_records_unit(analyses):
    """A family's K is output / command (eq. (2)'s is output / (command s^2)): the table says so below its rows,
    from the analyses' parameter record, not a table of its own."""
    result = compare(analyses["before"], analyses["after"], CompareOptions())
    assert {c.parameter: c.unit for c in result.changes} == {"tau": "s", "K": "output / command", "T": "s"}
    out = run_main("compare", analyses["before"], analyses["after"]).stdout.splitlines()
    assert "K in output / command" in out and max(map(len, out)) <= 100


def test_two_families_are_not_compared(analyses):
    result = compare(analyses["before"], analyses["before_sopdt"], CompareOptions())
    assert not result.changes
    (gap,) = result.missing
    assert gap.side == "both" and "different models (fopdt, sopdt)" in gap.reason


def test_a_process_plants_loop_is_the_one_named_or_process(analyses, tmp_path):
    """A process plant's analysis said loop 'altitude' (the vehicle default of --loop), so compare printed KSTAR's
    rows as altitude: without --loop its record says 'process', with --loop the loop named; eq. (2) keeps altitude."""
    csv = analyses["before"].replace(".json", ".csv")
    topics = ("--model", "fopdt", "--command-topic", "u_relay", "--output-topic", "y_output")
    loops = {}
    for extra in ((), ("--loop", "roll")):
        out = tmp_path / f"r{len(extra)}.json"
        done = run_main("analyze", csv, *topics, *extra, "--json", str(out))
        assert done.returncode == 0, done.stderr
        loops[extra] = json.loads(out.read_text())["loop"]
    assert loops == {(): "process", ("--loop", "roll"): "roll"}
    rows = run_main("compare", str(tmp_path / "r0.json"), str(tmp_path / "r0.json")).stdout.splitlines()
    assert any(r.split()[:2] == ["process", "K"] for r in rows) and not any("altitude" in r for r in rows)


def test_a_familys_tau_is_shown_in_seconds_as_analyze_shows_it(analyses):
    """compare showed a process family's tau in ms (300 ms) where analyze shows s (0.3 s): one rule now
    (mrft.parameter.display_scale), recorded per change as the model compared; eq. (2)'s tau stays in ms."""
    from mrftcli.compare import Comparison
    from mrftcli.compare.export import format_change, format_value, to_markdown

    result = compare(analyses["before"], analyses["after"], CompareOptions())
    tau = next(c for c in result.changes if c.parameter == "tau")
    assert tau.model == "fopdt" and tau.process
    assert format_value("tau", tau.baseline, tau.unit, tau.process) == f"{tau.baseline:.4g} s"
    assert format_change(tau, 0.95).startswith(f"{tau.change:+.4g} s [")
    assert f"| tau | {tau.baseline:.4g} s |" in to_markdown(result)
    rows = run_main("compare", analyses["before"], analyses["after"]).stdout.splitlines()
    (row,) = [r for r in rows if r.split()[1:3] == ["tau", "s"]]
    assert f"{tau.baseline:.4g}" in row.split() and "ms" not in row
    assert Comparison.from_json(json.loads(json.dumps(result.to_json()))).changes == result.changes
    # eq. (2)'s (a vehicle loop's) in ms, as analyze shows it
    assert format_value("tau", 0.0464) == "46.4 ms" and format_value("tau", 0.0464, "s", False) == "46.4 ms"
