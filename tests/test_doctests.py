"""The Examples in the package's docstrings run: each module's doctests, one test per module."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import mrftcli

MODULES = ["mrftcli"] + sorted(
    m.name for m in pkgutil.walk_packages(mrftcli.__path__, prefix="mrftcli.")
    if not m.name.endswith("__main__") and not m.name.startswith("mrftcli._manifolds")
)


#: exported names whose docstrings live in other areas' modules; the package docstring's Examples use them
_EXAMPLES_ELSEWHERE = {"read_flight"}


def test_the_public_api_is_reached_lazily_and_documented():
    """``import mrftcli`` loads none of the pipeline; each exported name has an annotated signature."""
    import inspect
    import subprocess
    import sys

    code = "import sys, mrftcli; print(sorted(m for m in sys.modules if m.startswith('mrftcli.')))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "['mrftcli._version']"  # the version leaf only
    for name in mrftcli.__all__:
        if name == "__version__":
            continue
        obj = getattr(mrftcli, name)
        assert obj.__doc__, name
        if name not in _EXAMPLES_ELSEWHERE:
            assert "Examples" in obj.__doc__, f"{name} has no Examples section"
        target = obj.__init__ if inspect.isclass(obj) else obj
        for p in inspect.signature(target).parameters.values():
            if p.name in ("self", "args", "kwargs") or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                continue
            assert p.annotation is not p.empty, f"{name}: parameter {p.name} has no annotation"


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in finder.find(module, name):
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
