"""Helpers the CLI and watch tests share (not tests themselves).

* :func:`run_cli`: the CLI in this process; a subprocess costs seconds of imports, so only a test that
  needs a process of its own (Ctrl-C, exit on a signal) starts one.
* :func:`run_main`: the same, returned as ``subprocess.run`` would (returncode, stdout, stderr).
* :class:`LiveWriter`: a recorder stand-in for ``watch``: appends the next slice of a log at every
  poll (the watch's ``sleep``), with a fake clock.
"""

from __future__ import annotations

import contextlib
import io
import subprocess
import warnings
from pathlib import Path

import pytest


def run_main(*argv: str) -> subprocess.CompletedProcess[str]:
    """``mrft-ident ARGV`` through main() in this process, shaped as ``subprocess.run``'s result (returncode,
    stdout, stderr) for tests written against a subprocess; a warning that would reach the terminal is
    appended to stderr (pytest would otherwise keep it from the test)."""
    from mrftcli.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings(record=True) as seen:
        # the filters of a plain ``python -m mrftcli`` (pytest's own would show, or hide, other warnings)
        warnings.resetwarnings()
        warnings.simplefilter("default")
        for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
            warnings.filterwarnings("ignore", category=category)
        warnings.filterwarnings("default", category=DeprecationWarning, module="__main__")
        try:
            main(list(argv))
            code = 0
        except SystemExit as done:
            code = int(done.code or 0)
    shown = "".join(warnings.formatwarning(w.message, w.category, w.filename, w.lineno) for w in seen)
    return subprocess.CompletedProcess(list(argv), code, out.getvalue(), err.getvalue() + shown)


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    """Run ``mrft-ident ARGV`` in this process: (exit code, stdout, stderr)."""
    from mrftcli.cli.main import main

    try:
        main(list(argv))
        code = 0
    except SystemExit as done:
        code = int(done.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


class LiveWriter:
    """Writes ``data`` into ``dst`` ``step`` bytes per poll; ``sleep`` and ``clock`` are watch's hooks."""

    def __init__(self, data: bytes, dst: Path, step: int) -> None:
        self.data, self.dst, self.step, self.pos, self.now = data, dst, step, 0, 0.0
        dst.write_bytes(b"")

    def sleep(self, dt: float) -> None:
        self.now += dt
        if self.pos < len(self.data):
            with open(self.dst, "ab") as fh:
                fh.write(self.data[self.pos:self.pos + self.step])
            self.pos += self.step

    def clock(self) -> float:
        return self.now
