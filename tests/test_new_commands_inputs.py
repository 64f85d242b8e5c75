"""A user's slips with this stop's new commands (``delay``, ``tune --export px4 --loop x|y``) and the outputs
they share with ``vehicle``: one line naming the problem and the fix, a non-zero exit, no traceback, inputs
never written over. Found by running the docs' commands and their bad-input variants as a user would."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest

from cli_helpers import run_main

SITL = Path(__file__).resolve().parents[1] / "sample_logs" / "sitl"
ROLL, ROLL_20 = SITL / "roll.BIN", SITL / "roll_20ms.BIN"


def _one_error_line(done, code: int) -> str:
    """The one ``error:`` line of a refused command (exit ``code``), no traceback, no library warning."""
    assert done.returncode == code, (done.returncode, done.stderr)
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    assert "Traceback" not in done.stderr and "Warning" not in done.stderr
    return lines[0]


def _md5(path: Path) -> str:
    return hashlib.md5(path.read_bytes()).hexdigest()


def test_vehicle_out_onto_its_log_is_refused(tmp_path: Path) -> None:
    """vehicle --out LOG (or --json LOG) would write the export over the flight it reads: refused before the
    work (exit 2, naming the option), the log unchanged."""
    log = tmp_path / "x.ulg"
    shutil.copy(SITL / "px4_x.ulg", log)
    before = _md5(log)
    for option in ("--out", "--json"):
        done = run_main("vehicle", str(log), "--tp", "0.05", "--export", "px4", option, str(log), "-q")
        line = _one_error_line(done, 2)
        assert f"{option} {log}" in line and "input" in line
    assert _md5(log) == before


@pytest.mark.parametrize("argv, words", [
    ([str(ROLL)], ["Missing argument 'AFTER'"]),
    ([str(ROLL), str(ROLL_20), "--json", "/proc/delay.json"], ["--json /proc/delay.json", "writable"]),
    ([str(ROLL), str(ROLL_20), "--json", "{tmp}"], ["--json", "is a folder", "file name"]),
    ([str(ROLL), str(ROLL_20), "--json", str(ROLL_20)], ["is an input", "another path"]),
    ([str(ROLL), str(ROLL_20), "--min-cycles", "1"], ["--min-cycles"]),
    ([str(ROLL), str(SITL / "." / "roll.BIN")], ["BEFORE and AFTER are the same recording", "before the change"]),
])
def test_delay_bad_input_one_line(tmp_path: Path, argv: list[str], words: list[str]) -> None:
    """delay's slips that need no fit: exit 2 before either log is analysed, one line naming the problem."""
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    done = run_main("delay", *argv, "--tp", "0.00915", "--loop", "roll", "-q")
    line = _one_error_line(done, 2)
    for w in words:
        assert w in line, line


@pytest.mark.parametrize("argv", [
    ["analyze", "{missing}", "--tp", "0.04"],
    ["diagnose", "{missing}", "--tp", "0.04"],
    ["topics", "{missing}"],
    ["vehicle", "{missing}", "--tp", "0.04"],
    ["tune", "{missing}", "--tp", "0.04", "--loop", "roll"],
    ["plan", "{missing}", "--tp", "0.04"],
    ["plan", "--from", "{missing}", "--tp", "0.04"],
    ["delay", "{missing}", str(ROLL_20), "--tp", "0.00915", "--loop", "roll"],
    ["delay", str(ROLL), "{missing}", "--tp", "0.00915", "--loop", "roll"],
    ["batch", "{missing}", "--tp", "0.04", "--out", "{tmp}/out"],
    ["batch", str(ROLL), "--tp", "0.04", "--out", "{tmp}/out", "--against", "{missing}"],
    ["compare", "{missing}", str(ROLL)],
], ids=lambda argv: " ".join(a for a in argv if not a.startswith(("{", "/", "0", "-")))[:40])
def test_missing_input_is_one_rule(tmp_path: Path, argv: list[str]) -> None:
    """A missing input (a log, a folder of logs, an analysis): exit 3 (docs/usage.md: the log cannot be read)
    and one wording, '<path>: no such file or directory', from every command (plan, delay and batch said
    click's 'Path ... does not exist' or 'no such file or folder', exit 2)."""
    missing = tmp_path / "missing.BIN"
    argv = [a.replace("{missing}", str(missing)).replace("{tmp}", str(tmp_path)) for a in argv]
    quiet = ["-q"] if argv[0] not in ("topics", "compare") else []  # no progress bar where there is one
    line = _one_error_line(run_main(*argv, *quiet), 3)
    assert line == f"error: {missing}: no such file or directory"
    assert not (tmp_path / "out").exists()


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation but '-' and '_' dropped, spaces '-'."""
    import re

    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_docs_named_in_help_and_messages_exist() -> None:
    """Every ``docs/NAME.md[#anchor]`` the package names (help texts, errors, notes) is a page we ship, and
    its anchor one of the page's headings (delay's help pointed at a '#delay' no heading makes)."""
    import re

    root = Path(__file__).resolve().parents[1]
    named = {m for p in (root / "mrftcli").rglob("*.py")
             for m in re.findall(r"docs/[\w/.-]+?\.md(?:#[\w-]+)?", p.read_text(encoding="utf-8"))}
    assert named
    for ref in sorted(named):
        page, _, anchor = ref.partition("#")
        assert (root / page).is_file(), ref
        if anchor:
            headings = [ln.lstrip("#") for ln in (root / page).read_text(encoding="utf-8").splitlines()
                        if ln.startswith("#")]
            assert anchor in {_slug(h) for h in headings}, ref


def test_docs_links_resolve() -> None:
    """Every relative link of README.md, sample_logs/README.md and docs/ names a file we ship and, with an
    anchor, one of its headings (GitHub's slug) or an ``<a id>`` (a ``{#id}`` heading suffix is not one on
    GitHub: it showed as text and the link landed at the page's top)."""
    import re

    root = Path(__file__).resolve().parents[1]
    pages = [root / "README.md", root / "sample_logs" / "README.md", *sorted((root / "docs").rglob("*.md"))]
    broken = []
    for md in pages:
        for link in re.findall(r"\]\(([^)\s]+)\)", md.read_text(encoding="utf-8")):
            if link.startswith(("http:", "https:", "mailto:")):
                continue
            page, _, anchor = link.partition("#")
            target = (md.parent / page) if page else md
            if not target.exists():
                broken.append(f"{md.relative_to(root)}: {link}")
            elif anchor and target.suffix == ".md":
                text = target.read_text(encoding="utf-8")
                ids = {_slug(ln.lstrip("#")) for ln in text.splitlines() if ln.startswith("#")}
                ids |= set(re.findall(r"<a id=\"([\w-]+)\"", text))
                if anchor not in ids:
                    broken.append(f"{md.relative_to(root)}: {link}")
    assert not broken, broken


@pytest.mark.parametrize("other, loop", [("pitch.BIN", "pitch"), ("altitude.BIN", "altitude")])
def test_delay_two_loops_refused(other: str, loop: str) -> None:
    """delay BEFORE AFTER where AFTER is another loop's recording (ArduPilot's MRFB:Ax says which): refused
    with one line naming that log and its loop, not a delay between two loops (it gave 23 ms for roll vs
    altitude)."""
    done = run_main("delay", str(ROLL), str(SITL / other), "--tp", "0.00915", "--loop", "roll", "-q")
    line = _one_error_line(done, 4)  # no usable test on the loop asked (docs/usage.md's exit codes)
    assert other in line and f"{loop} loop" in line and f"--loop {loop}" in line


def test_tune_out_never_replaces_a_file_it_did_not_write(tmp_path: Path) -> None:
    """tune --out over someone's file (another flight's ULog, a ground station's own parameter file) is
    refused before the work, the file unchanged; over its own earlier export it is replaced (before, a
    ULog given as --out was overwritten by the parameter file)."""
    flight = tmp_path / "flight.ulg"
    shutil.copy(SITL / "px4_y.ulg", flight)
    qgc = tmp_path / "qgc.params"
    qgc.write_text("# Onboard parameters for Vehicle 1\n1\t1\tMPC_ROLL_P\t6.5\t9\n")
    args = ["tune", "--tp", "0.05", "--td", "0.7", "--tau", "0.12", "--k", "27", "--loop", "roll", "--export", "px4",
            "-q", "--out"]
    for theirs in (flight, qgc):
        before = _md5(theirs)
        line = _one_error_line(run_main(*args, str(theirs)), 2)
        assert f"--out {theirs}" in line and "not an export" in line
        assert _md5(theirs) == before
    ours = tmp_path / "roll.params"
    for _ in range(2):  # written, then replaced
        done = run_main(*args, str(ours))
        assert done.returncode == 0, done.stderr
    assert "mrft-ident tune" in ours.read_text()


def test_logged_beta_outside_the_relays_range_is_named(tmp_path: Path) -> None:
    """A log whose beta topic holds +1.6 and +2.8 (a scaled or wrong topic; the relay flew -0.4 and -0.7): a
    warning names the values outside (-1, 1) and --beta-topic, and the tests are read by their effective
    beta, as with a NaN beta. Before, the analysis refused both tests as 'not the nominal +1.6' (exit 4)."""
    import csv

    rows = list(csv.reader((SITL.parent / "design1_altitude.csv").open()))
    col = rows[0].index("/mrft/beta/data")
    for r in rows[1:]:
        if r[col]:
            r[col] = f"{float(r[col]) * -4:g}"
    log = tmp_path / "scaled_beta.csv"
    with log.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    done = run_main("analyze", str(log), "--tp", "0.0422", "-q")
    assert done.returncode == 0, done.stderr
    warned = [ln for ln in done.stderr.splitlines() if "outside (-1, 1)" in ln]
    assert len(warned) == 1 and "+1.6" in warned[0] and "--beta-topic" in warned[0]
    assert "Traceback" not in done.stderr


def test_delay_prints_what_usage_md_says() -> None:
    """docs/usage.md's delay example prints the table it describes (units on each column and figure) and
    the very 'delay added' line the page quotes (rerun the command and update the page if this moves)."""
    done = run_main("delay", str(ROLL), str(ROLL_20), "--tp", "0.00915", "--loop", "roll", "-q")
    assert done.returncode == 0, done.stderr
    out = done.stdout.splitlines()
    for name, unit in (("Td", "s"), ("K", "rad/s² per command unit"), ("tau_before", "ms"), ("tau_after", "ms"),
                       ("delay_added", "ms")):
        assert any(ln.split()[:1] == [name] and f" {unit} " in ln for ln in out), (name, unit)
    assert any("[Hz]" in ln and "[%]" in ln for ln in out)
    line = next(ln for ln in out if ln.startswith("delay added: "))
    usage = (SITL.parents[1] / "docs" / "usage.md").read_text(encoding="utf-8")
    assert f"`{line}`" in usage, line


@pytest.mark.parametrize("command, loop, logged", [
    ("analyze", None, "y"),  # the default --loop altitude on PX4's y MRFT
    ("tune", "x", "y"),
    ("delay", "altitude", "x"),
])
def test_px4_log_of_another_loop_names_the_loop(tmp_path: Path, command: str, loop: str | None, logged: str) -> None:
    """A PX4 ULog's MRFT_<AXIS>_ENABLE changes say which loop its tests excite: reading it as another loop is
    one line naming the loop and --loop (before: 'no MRFT relay test ... check --command-topic', exit 4)."""
    log = str(SITL / f"px4_{logged}.ulg")
    again = tmp_path / "again.ulg"  # delay's AFTER: another file (the same one twice is its own refusal)
    shutil.copy(log, again)
    argv = [command, log] + ([str(again)] if command == "delay" else []) + ["--tp", "0.05", "-q"]
    argv += ["--loop", loop] if loop else []
    argv += ["--export", "px4", "--hover-thrust", "0.49"] if command == "tune" else []
    line = _one_error_line(run_main(*argv), 4)  # exit 4 (it was 2 for a while): no usable test on the loop asked
    assert f"excite the {logged} loop" in line and f"give --loop {logged}" in line


def test_tune_x_and_y_results_together_say_px4_shares_the_parameters(tmp_path: Path) -> None:
    """tune X.json Y.json --export px4: the two-result route is roll and pitch's joint gyro cutoff; for x and y
    the one line says PX4 has one MPC_XY_* set for both and to tune one alone."""
    import json

    x = tmp_path / "x.json"
    done = run_main("analyze", str(SITL / "px4_x.ulg"), "--tp", "0.05", "--loop", "x", "-q", "--json", str(x))
    assert done.returncode == 0, done.stderr
    y = tmp_path / "y.json"
    data = json.loads(x.read_text())
    data["input"]["loop"] = "y"  # the same record as a y analysis: the loop is what the check reads
    y.write_text(json.dumps(data))
    line = _one_error_line(run_main("tune", str(x), str(y), "--tp", "0.05", "--export", "px4", "-q"), 2)
    assert "x loop" in line and "one MPC_XY_* set" in line and "tune one of them alone" in line


def test_min_cycles_above_every_test_names_the_option() -> None:
    """--min-cycles raised above what the tests hold: the one line names --min-cycles beside 'record longer
    tests' (the user set the bar; before, only the flight was blamed)."""
    done = run_main("delay", str(ROLL), str(ROLL_20), "--tp", "0.00915", "--loop", "roll", "--min-cycles", "100", "-q")
    line = _one_error_line(done, 4)
    assert "none with 100 or more stable cycles" in line and "(or lower --min-cycles from 100)" in line
