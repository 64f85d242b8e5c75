"""The CI workflow of docs/compare.md, run as a script on the sample logs (issue 40).

The workflow's ``run:`` steps (bar ``pip install``) and its ``fleet.toml`` and ``expected.toml`` are read
from the page itself, so the page is what is tested. Oracles: the sample logs' simulation truth (the
reference values are the design1 plant's) and design1_altitude_20ms, the same plant with tau + 20 ms.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

DOC = Path(__file__).resolve().parents[1] / "docs" / "compare.md"


def _blocks(text: str) -> dict[str, str]:
    """Fenced blocks of the page whose first line is ``# <file name>``, by that name."""
    out = {}
    for body in re.findall(r"```(?:toml|yaml)\n(.*?)```", text, flags=re.S):
        first = body.splitlines()[0]
        if first.startswith("# "):
            out[first[2:].strip()] = body
    return out


def _run_steps(workflow: str) -> list[str]:
    steps = yaml.safe_load(workflow)["jobs"]["compare"]["steps"]
    runs = [s["run"] for s in steps if "run" in s]
    assert runs[0].startswith("pip install")
    return runs[1:]


def _ci(workspace: Path, steps: list[str]) -> int:
    """Run the steps as GitHub Actions does (bash -e each; stop at the first failing step); its exit code."""
    bindir = Path(sys.executable).parent
    env = {"PATH": f"{bindir}:/usr/bin:/bin", "HOME": str(Path.home()), "LANG": "C.UTF-8"}
    for step in steps:
        done = subprocess.run(["bash", "-e", "-c", step], cwd=workspace, env=env, capture_output=True, text=True,
                              timeout=600)
        if done.returncode:
            print(step, done.stdout, done.stderr, sep="\n")  # shown when the test fails
            return done.returncode
    return 0


@pytest.fixture(scope="module")
def page() -> dict[str, str]:
    blocks = _blocks(DOC.read_text())
    assert {".github/workflows/loop-check.yml", "fleet.toml", "expected.toml"} <= set(blocks)
    return blocks


def test_documented_ci_workflow(page, tmp_path, repo_root):
    steps = _run_steps(page[".github/workflows/loop-check.yml"])
    for name in ("fleet.toml", "expected.toml"):
        (tmp_path / name).write_text(page[name])
    vehicle = tmp_path / "flights" / "new" / "vehicle7"
    vehicle.mkdir(parents=True)
    for log in ("design1_altitude.mcap", "design1_roll.mcap"):
        shutil.copy(repo_root / "sample_logs" / log, vehicle / log)

    # the baseline flights: every loop as expected (x, y and pitch, without tests, are not failures)
    assert _ci(tmp_path, steps) == 0
    root = ET.parse(tmp_path / "compare.xml").getroot()
    assert (root.get("tests"), root.get("failures"), root.get("errors")) == ("6", "0", "0")

    # the altitude log replaced by its +20 ms twin: exit 9, a JUnit failure naming the loop and parameter
    shutil.copy(repo_root / "sample_logs" / "design1_altitude_20ms.mcap", vehicle / "design1_altitude.mcap")
    assert _ci(tmp_path, steps) == 9
    failures = [(c.get("classname"), c.get("name")) for c in ET.parse(tmp_path / "compare.xml").iter("testcase")
                if c.find("failure") is not None]
    assert failures == [("vehicle7.altitude", "tau")]
    assert ":x: changed" in (tmp_path / "compare.md").read_text()

    # the reference's tolerance covers +20 ms: passes again
    expected = tmp_path / "expected.toml"
    text = expected.read_text()
    assert text.count('tol = "+5ms"') == 2
    expected.write_text(text.replace('tau = { value = 0.0464, tol = "+5ms" }', 'tau = { value = 0.0464, tol = "+25ms" }'))
    # only the compare step again: the flights are those the batch step just analysed into results/ (the same
    # inputs give the same rows), so re-running batch would redo ~1/3 of the test's work for no new claim
    compare = [s for s in steps if s.lstrip().startswith("mrft-ident compare")]
    assert len(compare) == 1
    assert _ci(tmp_path, compare) == 0
    root = ET.parse(tmp_path / "compare.xml").getroot()
    assert root.get("failures") == "0"
