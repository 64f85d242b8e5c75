"""A user's slips with the documented commands: one line naming the option and the fix, no traceback.

Found by running the docs' commands and their bad-input variants as a user would (the user's-workflow
check); each case here failed before its fix. The docs' own examples are run by test_docs_examples.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cli_helpers import run_main

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs"


@pytest.mark.parametrize("argv, option", [
    (["identify", "--tp", "0.1", "--test", "1.2:0.7", "--test", "-0.7:1.0"], "--test '1.2:0.7'"),
    (["identify", "--tp", "0.1", "--test", "-0.4:0.7:0.08:-1", "--test", "-0.7:1.0:0.04:1"], "--test '-0.4:0.7:0.08:-1'"),
])
def test_identify_bad_test_names_the_option(argv: list[str], option: str) -> None:
    """A --test whose beta (or h) is out of range names that --test, as simulate's --test does."""
    done = run_main(*argv)
    assert done.returncode == 2
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ")
    assert option in lines[0]
    assert "Traceback" not in done.stderr


def _no_relay_csv(path: Path) -> Path:
    """A log whose command never switches: the analysis fails (exit 4) once it has read the log."""
    t = np.arange(0.0, 20.0, 0.01)
    rows = "\n".join(f"{a:.2f},0.5,{b:.5f}" for a, b in zip(t, 0.01 * np.sin(7 * t)))
    path.write_text("time,u_relay,y_output\n" + rows + "\n")
    return path


@pytest.mark.parametrize("option", ["--json", "--mcap-out"])
def test_unwritable_output_refused_before_the_work(tmp_path: Path, option: str) -> None:
    """An output folder the tool cannot write in (/proc: no file can be created there, even by root, whom
    os.access calls it writable) is refused before the log is analysed (exit 2, naming the option), not
    after it, and not as a temporary file's name."""
    log = _no_relay_csv(tmp_path / "flat.csv")
    done = run_main("analyze", str(log), "--tp", "0.0422", "--command-topic", "u_relay", "--output-topic", "y_output",
                    option, "/proc/out.file")
    assert done.returncode == 2, done.stderr
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"error: {option} /proc/out.file")


def test_mcap_out_creates_its_folder_as_json_does(tmp_path: Path) -> None:
    """--mcap-out into a folder not yet there: created, as --json's and --report's are (one rule for outputs)."""
    from mrftcli.samples import sample_log

    target = tmp_path / "new" / "fit.mcap"
    done = run_main("analyze", str(sample_log("design1_altitude.mcap")), "--tp", "0.0422", "-q",
                    "--mcap-out", str(target))
    assert done.returncode == 0, done.stderr
    assert target.read_bytes()[:5] == b"\x89MCAP"


@pytest.mark.parametrize("log, loop", [("design1_roll.mcap", None), ("design1_altitude.mcap", "roll")])
def test_wrong_loop_names_the_fix(log: str, loop: str | None) -> None:
    """A roll log read as the default altitude loop (or the other way round): the layout's output topic is
    missing, and the one line says to give --loop (or --output-topic), not only which topics exist."""
    done = run_main("analyze", str(SAMPLES / log), "--tp", "0.0422", *(["--loop", loop] if loop else []))
    assert done.returncode == 3
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ")
    assert "--loop" in lines[0] and "--output-topic" in lines[0]


def test_given_topic_missing_is_not_blamed_on_the_loop() -> None:
    """An --output-topic the user gave and the log lacks: the error names it (no --loop advice)."""
    from mrftcli.samples import sample_log

    done = run_main("analyze", str(sample_log("design1_altitude.mcap")), "--tp", "0.0422", "--output-topic", "/nope")
    assert done.returncode == 3 and "'/nope'" in done.stderr and "--loop" not in done.stderr


def test_help_has_no_doubled_words() -> None:
    """Every command's --help reads cleanly (a 'Holds the the tune record' slipped through)."""
    import re

    top = run_main("--help").stdout
    names = re.findall(r"^  ([a-z][\w-]+)  ", top.split("Commands:")[1], flags=re.M)
    assert len(names) >= 13
    for name in names:
        done = run_main(name, "--help")
        assert done.returncode == 0
        doubled = re.findall(r"\b(\w+)\s+\1\b", " ".join(done.stdout.split()))
        assert not [w for w in doubled if not w.isdigit()], (name, doubled)


def test_json_that_is_not_an_analysis_names_file_and_option(tmp_path: Path) -> None:
    """A JSON file that is not an analysis, given where one is read: one line naming the option (or the
    file) once, without 'not an analyze RESULT.json (not an analyze RESULT.json (...'."""
    other = tmp_path / "other.json"
    other.write_text('{"foo": 1}\n')
    done = run_main("tune", str(other), "--tp", "0.0422", "--loop", "roll")
    assert done.returncode == 2
    assert done.stderr.count("not an analyze RESULT.json") == 1 and done.stderr.startswith(f"error: {other}:")
    done = run_main("analyze", str(SAMPLES / "hear_cascade_y.bag"), "--loop", "y", "--inner-model", str(other),
                    "--inner-gains", str(SAMPLES / "hear_cascade_y.gains.json"))
    assert done.returncode == 2
    assert done.stderr.startswith(f"error: --inner-model {other}: not an analyze RESULT.json")


@pytest.mark.parametrize("relay, fix", [([], "--relay hysteresis"), (["--relay", "ideal"], "--relay hysteresis"),
                                        (["--relay", "hysteresis", "--eps", "-1"], "non-negative")])
def test_eps_without_a_hysteresis_relay_is_refused(tmp_path: Path, relay: list[str], fix: str) -> None:
    """--eps is the hysteresis of --relay hysteresis: given without it, it was silently ignored; negative, it
    was called 'not below the output amplitude'. One line naming the fix (exit 2), before the analysis."""
    log = _no_relay_csv(tmp_path / "flat.csv")
    args = relay if "--eps" in relay else [*relay, "--eps", "0.01"]
    done = run_main("analyze", str(log), "--model", "fopdt", "--command-topic", "u_relay", "--output-topic",
                    "y_output", *args)
    assert done.returncode == 2, done.stderr
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: --eps") and fix in lines[0]


def test_simulate_cascade_bad_inner_test_names_inner_test(tmp_path: Path) -> None:
    """A cascade's --inner-test out of range names --inner-test (it said --test, the outer loop's option)."""
    done = run_main("simulate", "--cascade", "y", "--inner-tp", "0.0422", "--inner-td", "1.301", "--inner-tau", "0.0297",
                    "--inner-k", "30", "--inner-test", "-0.4", "--inner-test", "1.7", "--td", "2", "--tau", "0.03",
                    "--test", "-0.4", "--out", str(tmp_path / "c.bag"))
    assert done.returncode == 2
    assert done.stderr.startswith("error: --inner-test '1.7': beta must lie in the open interval (-1, 1)")


def test_watch_of_a_log_with_no_messages_names_it_and_the_fix(tmp_path: Path) -> None:
    """watch on a recording that stops before any message (an MCAP cut after its header) said only
    'error: no data in the log': the line names the file and what to check."""
    cut = tmp_path / "cut.mcap"
    cut.write_bytes((SAMPLES / "design1_altitude.mcap").read_bytes()[:300])
    done = run_main("watch", str(cut), "--tp", "0.0422", "--idle", "0.3", "--poll", "0.05")
    assert done.returncode == 3
    error = [ln for ln in done.stderr.splitlines() if ln.startswith("error:")]
    assert len(error) == 1 and str(cut) in error[0] and "mrft-ident topics" in error[0]


def test_csv_of_another_layout_names_command_topic(tmp_path: Path) -> None:
    """A process plant's CSV read without --command-topic (the first try of a new user): the layout's command
    column is missing, and the line says to name the log's own with --command-topic and --output-topic."""
    log = _no_relay_csv(tmp_path / "plant.csv")
    done = run_main("analyze", str(log), "--model", "fopdt")
    assert done.returncode == 3
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "'/mrft/command'" in lines[0]
    assert "--command-topic" in lines[0] and "--output-topic" in lines[0]


@pytest.mark.parametrize("argv", [["predict", "--tp", "0.1", "--td", "0.7042", "--tau", "0.06", "--beta", "-0.4"],
                                  ["identify", "--tp", "0.1", "--test", "-0.4:0.70564", "--test", "-0.7:1.01884"],
                                  ["topics", str(SAMPLES / "design1_altitude.csv")]])
def test_json_into_a_new_folder_as_every_command(tmp_path: Path, argv: list[str]) -> None:
    """predict, identify and topics --json into a folder not yet there: created, as analyze's, tune's, plan's...
    (they said 'cannot write (No such file or directory)')."""
    target = tmp_path / "new" / "out.json"
    done = run_main(*argv, "--json", str(target))
    assert done.returncode == 0, done.stderr
    assert target.read_text().lstrip().startswith("{")
