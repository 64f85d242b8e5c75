"""Messages name options that exist: in the command that prints them, and anywhere in the package."""

from __future__ import annotations

import contextlib
import re
import subprocess
from pathlib import Path

import click
import pytest
from cli_helpers import run_main

from mrftcli.cli.main import cli

ROOT = Path(__file__).resolve().parents[1]
#: options of other tools that messages and docstrings name on purpose (rosbag, the benchmarks)
OTHER_TOOLS = {"--lz4", "--max-bag-size", "--calibrate", "--admissibility"}


def _options() -> set[str]:
    ctx = click.Context(cli)
    found = {"--help", "--version", "--debug"}

    def walk(cmd: click.Command) -> None:
        if isinstance(cmd, click.Group):
            for name in cmd.list_commands(ctx):
                walk(cmd.get_command(ctx, name))
            return
        for p in cmd.params:
            found.update(getattr(p, "opts", ()), getattr(p, "secondary_opts", ()))

    walk(cli)
    return found


def test_every_option_named_in_the_package_exists():
    options = _options() | OTHER_TOOLS
    unknown = []
    for path in sorted((ROOT / "mrftcli").rglob("*.py")):
        for i, line in enumerate(path.read_text().splitlines(), 1):
            for name in re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", line):
                if name not in options:
                    unknown.append(f"{path.relative_to(ROOT)}:{i}: {name}")
    assert not unknown, unknown


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``mrft-ident ARGS`` in ``cwd`` through main() in this process (cli_helpers.run_main)."""
    with contextlib.chdir(cwd):
        return run_main(*args)


@pytest.mark.parametrize(("command", "option"), [(("analyze",), "--format"), (("tune", "--loop", "altitude"),
                                                                               "--format")])
def test_an_unknown_log_format_names_the_commands_own_option(tmp_path: Path, command, option):
    """The readers' advice names --format, the log format's option in every command (tune's was --log-format,
    now its hidden alias)."""
    (tmp_path / "flight.log").write_bytes(b"\x00\x01 not a log")
    p = _run(command[0], "flight.log", "--tp", "0.04", *command[1:], cwd=tmp_path)
    assert p.returncode == 3, p.stderr
    assert f"pass {option} (" in p.stderr, p.stderr
    if option != "--format":
        assert "--format" not in p.stderr.replace(option, ""), p.stderr
