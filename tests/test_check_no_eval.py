"""scripts/check_no_eval.py (CI): the package has no call that evaluates text or unpickles, and the check
finds each kind of such call when one is there (a module written here)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "check_no_eval.py"

HOSTILE = '''
import pickle
import yaml
from sympy import sympify
from sympy.parsing.sympy_parser import parse_expr
import numpy as np

def f(text, path):
    eval(text)
    exec(text)
    compile(text, "x", "eval")
    __import__(text)
    sympify(text)
    parse_expr(text)
    yaml.load(text)
    yaml.unsafe_load(text)
    pickle.loads(text)
    np.load(path, allow_pickle=True)
    import sympy
    sympy.lambdify([], text)
    sympy.S(text)
'''

HARMLESS = '''
import re
import yaml
import numpy as np

class Model:
    def eval(self, t):
        return t

def f(text, path, m: Model):
    re.compile(text)
    m.eval(1.0)
    yaml.safe_load(text)
    np.load(path, allow_pickle=False)
'''


def _run(root: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), str(root)], capture_output=True, text=True, timeout=120)


def test_the_package_evaluates_no_text():
    done = _run(SCRIPT.parent.parent / "mrftcli")
    assert done.returncode == 0, done.stdout


def test_every_kind_of_evaluation_is_found(tmp_path):
    pkg = tmp_path / "mrftcli"
    pkg.mkdir()
    (pkg / "bad.py").write_text(HOSTILE)
    (pkg / "good.py").write_text(HARMLESS)
    done = _run(pkg)
    assert done.returncode == 1
    lines = done.stdout.splitlines()
    assert all(line.startswith("mrftcli/bad.py:") for line in lines), lines
    found = " ".join(lines)
    for what in ("import pickle", "from sympy import sympify", "import parse_expr", "call of eval", "call of exec",
                 "call of compile", "call of __import__", "call of sympify", "call of parse_expr", "call of yaml.load",
                 "call of yaml.unsafe_load", "call of pickle.loads", "allow_pickle", "call of sympy.lambdify",
                 "call of sympy.S"):
        assert what in found, what
