"""Fail when a module of the package can run text as code (issue 35; CI runs this next to the module-size check).

An AST scan of every module under ``mrftcli/`` for a call of, or an import of, anything that evaluates
text or unpickles: ``eval``, ``exec``, ``compile``, ``__import__``, sympy's ``sympify``/``S``/
``parse_expr``/``lambdify``/``parse_latex``, ``pickle.load(s)``/``Unpickler`` (and ``dill``,
``cloudpickle``, ``marshal``, ``shelve``), ``yaml.load``/``unsafe_load``/``full_load`` (``safe_load`` and
``SafeLoader`` are fine), ``numpy.load(..., allow_pickle=True)`` and ``pandas.read_pickle``. A
transfer function from a file is parsed by ``mrftcli/mrft/tf_parse.py`` from Python's ``ast`` tree
(docs/security.md).

An exception would be listed in :data:`ALLOWED` as ``"path/to/module.py:name"`` with the reason next to
it; there is none.

Usage: ``python scripts/check_no_eval.py [ROOT]`` (default: the package next to this script). Prints one
line per finding and exits 1 when there is any.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

#: builtins that run text: refused as a plain call, or as ``builtins.NAME``
FORBIDDEN_BUILTINS = frozenset({"eval", "exec", "compile", "__import__"})
#: names whose call (or import) evaluates text or unpickles, whatever object or module they come from
FORBIDDEN_CALLS = frozenset({"sympify", "parse_expr", "lambdify", "parse_latex", "read_pickle", "unsafe_load",
                             "full_load", "Unpickler", "load_module", "exec_module"})
#: modules any use of which is refused (they load code or pickles)
FORBIDDEN_MODULES = frozenset({"pickle", "cPickle", "_pickle", "dill", "cloudpickle", "marshal", "shelve",
                               "joblib"})
#: attribute calls refused on these module names: yaml.load(...) (the unsafe default loader), sympy.S(...)
FORBIDDEN_ATTRIBUTES = {("yaml", "load"), ("yaml", "load_all"), ("sympy", "S")} | {
    ("builtins", name) for name in FORBIDDEN_BUILTINS}
#: "relative/path.py:name" -> why it is safe (none so far)
ALLOWED: dict[str, str] = {}


def _call_name(func: ast.expr) -> tuple[str | None, str]:
    """(the module-ish name before the dot or None, the called name)."""
    if isinstance(func, ast.Name):
        return None, func.id
    if isinstance(func, ast.Attribute):
        base = func.value
        return (base.id if isinstance(base, ast.Name) else None), func.attr
    return None, ""


def _pickle_flag(node: ast.Call) -> bool:
    """``np.load(..., allow_pickle=True)`` (anything but a literal False)."""
    for kw in node.keywords:
        if kw.arg == "allow_pickle" and not (isinstance(kw.value, ast.Constant) and kw.value.value is False):
            return True
    return False


def _findings(tree: ast.AST) -> list[tuple[int, str, str]]:
    """(line, name, what) for every forbidden call or import in ``tree``."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            base, name = _call_name(node.func)
            bare = isinstance(node.func, ast.Name)
            if name in FORBIDDEN_CALLS or (bare and name in FORBIDDEN_BUILTINS) or (base, name) in FORBIDDEN_ATTRIBUTES:
                out.append((node.lineno, name, f"call of {'.'.join(filter(None, (base, name)))}"))
            elif base in FORBIDDEN_MODULES:
                out.append((node.lineno, name, f"call of {base}.{name}"))
            elif _pickle_flag(node):
                out.append((node.lineno, name, f"{name}(..., allow_pickle=...) not False"))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] in FORBIDDEN_MODULES:
                    out.append((node.lineno, alias.name, f"import {alias.name}"))
        elif isinstance(node, ast.ImportFrom):
            module = (node.module or "").split(".")[0]
            for alias in node.names:
                if (module in FORBIDDEN_MODULES or alias.name in FORBIDDEN_CALLS | FORBIDDEN_BUILTINS
                        or (module, alias.name) in FORBIDDEN_ATTRIBUTES):
                    out.append((node.lineno, alias.name, f"from {node.module} import {alias.name}"))
    return out


def scan(root: Path) -> list[str]:
    """One message per forbidden call or import in the modules under ``root``."""
    messages = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root.parent).as_posix()
        try:
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=rel)
        except SyntaxError as err:
            messages.append(f"{rel}:{err.lineno}: cannot be parsed ({err.msg})")
            continue
        for line, name, what in _findings(tree):
            if f"{rel}:{name}" not in ALLOWED:
                messages.append(f"{rel}:{line}: {what}: no input may run as code (parse it; docs/security.md)")
    return messages


def main(argv: list[str]) -> int:
    root = Path(argv[0]) if argv else Path(__file__).resolve().parent.parent / "mrftcli"
    messages = scan(root)
    for message in messages:
        print(message)
    return 1 if messages else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
