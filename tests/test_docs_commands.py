"""A user's slips with the documented commands: one line naming the option and the fix, no traceback.

Found by running the docs' commands and their bad-input variants as a user would (the user's-workflow
check); each case here failed before its fix. The docs' own examples are run by test_docs_examples.py.
"""

from __future__ import annotations

import pytest

from cli_helpers import run_main


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
