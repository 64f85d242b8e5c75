"""Every ``mrft-ident ...`` command in a fenced block of docs/*.md and README.md runs (issue 26 item 3).

The commands are extracted from the documents, so a new example is run by default. Synopses (lines
with ``LOG``, ``[...]``, ``|``) are not commands; an example that needs what a test cannot have (a
user's own log with its own topics, a growing log, a Dask cluster) or is slow is skipped with the
reason, listed in :data:`SKIP`. Placeholder files are the shipped sample logs and their analyses.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from cli_helpers import run_main

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_logs"

#: (pattern, reason): examples that are not run.
SKIP = (
    (r"^mrft-ident watch ", "follows a log while a recorder writes it (tests/test_watch.py)"),
    (r"--scheduler tcp://", "needs a Dask cluster"),
    (r"^mrft-ident batch logs/", "a folder of the user's logs (tests/test_batch_cli.py)"),
    (r"flight\.(ulg|csv)", "a user's own log with its own topics"),
    (r"^mrft-ident simulate \.\.\.", "an elided command"),
    (r"--report ", "slow (plots); the report is tested in tests/test_report_analysis.py and test_tune.py"),
    (r"^mrft-ident (diagnose|build-ufm|simulate) ", "slow (> 10 s of CPU); tested in their own test files"),
    (r"^mrft-ident compare ", "needs two analysed batches (tests/test_compare.py)"),
    (r"heater\.csv", "the slow thermal example's log is written by scripts/make_thermal_example.py "
     "(the same flow on a shorter recording: tests/test_slow_process.py)"),
    (r"flight\.bag --tp 0\.0499", "a user's roll log with another Tp"),
    (r"--inner-model roll\.json|^mrft-ident tune y\.json", "the cascade chain reads the files the example before "
     "it writes (the workers of pytest -n do not share them); run end to end in tests/test_cascade.py"),
)


def doc_commands() -> list[tuple[str, str]]:
    """(document:line, command) of every ``mrft-ident`` line in a fenced block, continuations joined."""
    found = []
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        fenced = False
        lines = doc.read_text().splitlines()
        i = 0
        while i < len(lines):
            line = lines[i]
            if line.startswith("```"):
                fenced = not fenced
            elif fenced and line.startswith("mrft-ident "):
                start = i
                while line.rstrip().endswith("\\") and i + 1 < len(lines):
                    i += 1
                    line = line.rstrip()[:-1] + " " + lines[i].strip()
                command = re.sub(r"\s+#.*$", "", line).strip()
                if not re.search(r"\bLOG\b|\[|\||BASELINE", command):  # a synopsis, not a command
                    found.append((f"{doc.relative_to(ROOT)}:{start + 1}", command))
            i += 1
    return found


COMMANDS = doc_commands()


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding the names the examples use: the sample logs and analyses of them."""
    d = tmp_path_factory.mktemp("docs")
    (d / "sample_logs").symlink_to(SAMPLES)
    shared = ROOT.parent / "shared"  # ../shared/data: real relay recordings, read in place
    if shared.is_dir() and not (d.parent / "shared").exists():
        (d.parent / "shared").symlink_to(shared)
    for name in ("flight.mcap", "first.mcap"):
        (d / name).symlink_to(SAMPLES / "design1_altitude.mcap")
    for name, log, loop in (("first.json", "design1_altitude.mcap", "altitude"),
                            ("result.json", "design1_roll.mcap", "roll")):
        # main() in this process, as the examples run (a fresh interpreter costs ~1.4 CPU-s of imports)
        done = run_main("analyze", str(SAMPLES / log), "--tp", "0.0422", "--loop", loop, "--json", str(d / name))
        assert done.returncode == 0, done.stderr
    return d


@pytest.mark.parametrize("where, command", COMMANDS, ids=[w for w, _ in COMMANDS])
def test_documented_example_runs(where: str, command: str, workdir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for pattern, reason in SKIP:
        if re.search(pattern, command):
            pytest.skip(reason)
    if "../shared/" in command and not (ROOT.parent / "shared").is_dir():
        pytest.skip("the real relay recordings (../shared/data) are not on this machine")
    args = shlex.split(command)[1:]
    # in this process (a separate interpreter per example cost ~1.5 CPU-s of imports each): main() as the
    # console script calls it, in the examples' folder
    monkeypatch.chdir(workdir)
    proc = run_main(*args)
    assert proc.returncode == 0, f"{where}: {command}\n{proc.stderr}"


def test_the_examples_are_found() -> None:
    # the extraction itself: the plan page's three examples, the tune synopsis left out
    plan = [c for w, c in COMMANDS if w.startswith("docs/plan.md")]
    assert len(plan) == 3 and all(c.startswith("mrft-ident plan --tp 0.0422") for c in plan)
    assert not any(w.startswith("docs/tune.md:4") for w, _ in COMMANDS)
