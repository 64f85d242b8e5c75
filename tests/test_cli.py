"""The CLI layer itself: command registry, one-line errors, exit codes (subprocess, as a user runs it)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mrftcli.cli.main import COMMANDS, cli


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", "from mrftcli.cli.main import main; main()", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_registered_command_imports_and_has_help(name):
    command = cli.get_command(None, name)
    assert command is not None, name
    assert command.help and len(command.help.strip()) > 20, f"{name} has no real --help text"


def test_top_level_help_lists_every_command():
    proc = _run("--help")
    assert proc.returncode == 0
    for name in COMMANDS:
        assert name in proc.stdout


@pytest.mark.parametrize(
    "args, needle",
    [
        (("predict", "--tp", "0.1", "--td", "0.7", "--tau", "0.06", "--beta", "1.2"), "beta must lie in the open interval"),
        (("predict", "--tp", "0.1"), "Missing option"),
        (("no-such-command",), "no command 'no-such-command'"),
        (("analyse", "x.mcap"), "did you mean 'analyze'?"),
    ],
)
def test_usage_errors_are_one_line_with_exit_2(args, needle):
    proc = _run(*args)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("error: ") and needle in lines[0]
    assert "Traceback" not in proc.stderr


def test_unwritable_output_path_is_a_one_line_error(repo_root, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    log = repo_root / "sample_logs" / "design1_altitude.mcap"
    proc = _run("analyze", str(log), "--tp", "0.0422", "--report", str(blocker / "report"))
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("error: ")
    assert "Traceback" not in proc.stderr


def _imports(path):
    """(module imported, names imported) for every import statement of a source file, resolved to
    absolute ``mrftcli`` names for relative imports."""
    import ast

    from mrftcli import __file__ as pkg_init
    from pathlib import Path

    root = Path(pkg_init).parent
    package = ".".join(("mrftcli", *path.relative_to(root).with_suffix("").parts[:-1]))
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(a.name, ()) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - node.level + 1]
                base = ".".join(parts + ([node.module] if node.module else []))
            out.append((base, tuple(a.name for a in node.names)))
    return out


# Which layers may import what (click/tqdm only in cli/, matplotlib only in report/ and above, the pipeline's
# order) is import-linter's contract in pyproject.toml, checked by .ci/run.


def test_no_module_imports_another_modules_private_name():
    from pathlib import Path

    from mrftcli import __file__ as pkg_init

    root = Path(pkg_init).parent
    private = [f"{path.relative_to(root)}: {module}.{name}"
               for path in sorted(root.rglob("*.py")) for module, names in _imports(path)
               if module.startswith("mrftcli") for name in names if name.startswith("_") and not name.startswith("__")]
    assert not private, private


def test_every_subpackage_is_in_the_wheel():
    # pyproject lists the packages by hand (manifolds/ is installed as mrftcli._manifolds): a new
    # subpackage missing there would install without it (a non-editable install fails at import)
    import tomllib

    root = Path(__file__).resolve().parents[1]
    listed = set(tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(root).parts) for p in (root / "mrftcli").rglob("__init__.py")}
    assert found <= listed, sorted(found - listed)
    # folders installed under another name (manifolds/ -> mrftcli._manifolds, sample_logs/ -> mrftcli._samples)
    mapped = set(tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"])
    assert mapped <= listed, sorted(mapped - listed)
