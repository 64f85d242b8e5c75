"""A transfer function's text -> a sympy expression, built from Python's ``ast`` tree: no text is evaluated.

A model file (``--model-file``), an analysis JSON of a declared model, a batch record: every transfer
function the tool reads back is text someone else wrote. The text is parsed by :func:`ast.parse`
(``mode="eval"``: a parse tree, nothing run) and walked node by node; only these nodes build the
expression:

- numbers (finite, at most :data:`MAX_LITERAL` in size), the declared parameter names and ``s``;
- ``+ - * /``, unary minus and plus, parentheses;
- ``**`` (or ``^``) with a whole-number exponent 0..:data:`MAX_EXPONENT` written as a literal;
- ``exp(...)`` with one argument (the delay, ``exp(-tau*s)``; the caller checks its form).

Anything else (a string, an attribute, a call of any other name, a lambda, a comprehension, a
subscript, a comparison ...) is an :class:`~mrftcli.errors.InputError` naming the token and its
column. The expression is built with sympy's constructors from the checked tree (``sympy.Symbol``,
``sympy.Integer``, ``sympy.Float``, ``+``, ``*``, ``sympy.Pow``, ``sympy.exp``), never from a string.

The limits (:data:`MAX_TEXT`, :data:`MAX_NESTING`, :data:`MAX_NODES`, :data:`MAX_EXPONENT`,
:data:`MAX_ORDER`, :data:`MAX_TERMS`) are checked on the text and on the tree *before* sympy does any
algebra, so ``K/(s**10**10 + 1)`` or ``K/((T*s + 1)**100000)`` are refused in microseconds.

Examples
--------
>>> parse_transfer_function("K*exp(-tau*s)/(T*s + 1)**2", ("K", "T", "tau"))
K*exp(-s*tau)/(T*s + 1)**2
>>> parse_transfer_function("K.func(s)", ("K",))
Traceback (most recent call last):
...
mrftcli.errors.InputError: transfer_function 'K.func(s)': attribute '.func' at column 2 is not allowed; a transfer function may hold only numbers, its declared parameters, s, + - * / ** and exp(-tau*s)
"""

from __future__ import annotations

import ast
import math
from dataclasses import dataclass
from typing import Any, Sequence

from ..errors import InputError

__all__ = ["parse_transfer_function", "check_transfer_text", "MAX_TEXT", "MAX_NESTING", "MAX_DEPTH", "MAX_NODES",
           "MAX_EXPONENT", "MAX_ORDER", "MAX_TERMS", "MAX_LITERAL", "ALLOWED"]

#: longest transfer-function text [characters] (a 20th-order model written out is a few hundred)
MAX_TEXT = 4000
#: deepest nesting of parentheses
MAX_NESTING = 40
#: deepest parse tree (a sum of n terms is n deep)
MAX_DEPTH = 200
#: most nodes of the parse tree (numbers, names, operators)
MAX_NODES = 1000
#: largest exponent of ``**``
MAX_EXPONENT = 20
#: highest power of s the numerator or denominator may reach (the model order)
MAX_ORDER = 20
#: most monomials the expanded numerator or denominator may hold (in s and the parameters): sympy
#: cancels 256 (a product of eight distinct lags) in about two seconds
MAX_TERMS = 256
#: largest magnitude of a number written in the text
MAX_LITERAL = 1e12
#: what the refusals say a transfer function may hold
ALLOWED = "a transfer function may hold only numbers, its declared parameters, s, + - * / ** and exp(-tau*s)"

_BINARY = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**", ast.BitXor: "^"}
_OPEN, _CLOSE = "([{", ")]}"


@dataclass(frozen=True)
class _Bound:
    """Upper bounds of the expression as a ratio of expanded polynomials: powers of s and monomials."""

    num_order: int
    den_order: int
    num_terms: int
    den_terms: int


def _refuse(what: str, text: str, problem: str) -> InputError:
    shown = text if len(text) <= 80 else text[:77] + "..."
    return InputError(f"{what} {shown!r}: {problem}")


def check_transfer_text(text: Any, what: str = "transfer_function") -> str:
    """``text`` if it is a non-empty string within :data:`MAX_TEXT` and :data:`MAX_NESTING`; else InputError.

    A cheap scan before the parser: Python's own parser recurses on nesting.
    """
    if not isinstance(text, str) or not text.strip():
        raise InputError(f"{what} must be a non-empty expression in s, e.g. \"K*exp(-tau*s)/(T*s + 1)\"")
    if len(text) > MAX_TEXT:
        raise InputError(f"{what}: {len(text)} characters, more than the {MAX_TEXT} a transfer function may "
                         "have; write it with fewer terms (a product of factors)")
    depth = 0
    for column, char in enumerate(text, start=1):
        if char < " " and char not in "\t\n\r":
            raise _refuse(what, text, f"control character U+{ord(char):04X} at column {column} is not allowed")
        depth += (char in _OPEN) - (char in _CLOSE)
        if depth > MAX_NESTING:
            raise _refuse(what, text, f"parentheses nested deeper than {MAX_NESTING} at column {column}")
    return text


class _Source:
    """The text as given and as parsed (``^`` read as ``**``, as sympy's parser did: ``K*s^2`` is K s^2);
    :meth:`column` maps a node's offset in the parsed text back to a column of the given one (from 1)."""

    def __init__(self, text: str) -> None:
        self.text = text
        stripped = text.lstrip()
        self.lead = len(text) - len(stripped)
        self.parsed = stripped.rstrip().replace("^", "**")
        #: offsets in the parsed text just after each inserted "*"
        self.inserted = [i + 2 + k for k, i in enumerate(j for j, c in enumerate(stripped) if c == "^")]

    def column(self, offset: int) -> int:
        return offset + 1 + self.lead - sum(1 for i in self.inserted if i <= offset)


def _parse_tree(src: _Source, what: str) -> ast.expr:
    text = src.text
    try:
        tree = ast.parse(src.parsed, mode="eval")
    except SyntaxError as err:
        offset = (err.offset or 0) - 1
        near = src.parsed[offset:offset + 1] if offset >= 0 else ""
        where = (f" at column {src.column(offset)}" if offset >= 0 else "") + (f" ({near!r})" if near.strip() else "")
        raise _refuse(what, text, f"not an expression{where}: {err.msg}; {ALLOWED}") from None
    except (ValueError, RecursionError, MemoryError):
        raise _refuse(what, text, f"cannot be parsed; {ALLOWED}") from None
    _check_size(tree.body, src, what)
    return tree.body


def _check_size(root: ast.expr, src: _Source, what: str) -> None:
    """Node count and nesting depth, walked without recursion (the walk that builds comes after)."""
    stack: list[tuple[ast.AST, int]] = [(root, 1)]
    count = 0
    while stack:
        node, depth = stack.pop()
        count += 1
        if count > MAX_NODES:
            raise _refuse(what, src.text, f"more than {MAX_NODES} numbers, names and operators; write it with "
                                          "fewer terms")
        if depth > MAX_DEPTH:
            raise _refuse(what, src.text, f"nested deeper than {MAX_DEPTH} operations at column "
                                          f"{src.column(getattr(node, 'col_offset', 0))}; write it with fewer terms")
        stack.extend((child, depth + 1) for child in ast.iter_child_nodes(node))


def _column(node: ast.AST, src: _Source) -> int:
    return src.column(getattr(node, "col_offset", 0))


def _not_allowed(node: ast.AST, src: _Source, what: str) -> InputError:
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
        node = node.func  # name the attribute: K.func(s) is refused for its '.func'
    if isinstance(node, ast.Attribute):
        column = src.column((getattr(node, "end_col_offset", None) or 0) - len(node.attr) - 1)
        token = f"attribute '.{node.attr}' at column {column}"
    elif isinstance(node, ast.Call):
        name = node.func.id if isinstance(node.func, ast.Name) else ast.unparse(node.func)[:30]
        token = f"call of {name!r} at column {_column(node, src)}"
    elif isinstance(node, ast.Constant):
        token = f"{type(node.value).__name__} {str(node.value)[:30]!r} at column {_column(node, src)}"
    elif isinstance(node, (ast.BinOp, ast.UnaryOp)):
        token = f"operator {type(node.op).__name__} at column {_column(node, src)}"
    else:
        token = f"{type(node).__name__.lower()} at column {_column(node, src)}"
    return _refuse(what, src.text, f"{token} is not allowed; {ALLOWED}")


def _exponent(node: ast.expr, src: _Source, what: str) -> int:
    value = node.value if isinstance(node, ast.Constant) else None
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= MAX_EXPONENT:
        return value
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        raise _refuse(what, src.text, f"exponent {str(value)[:30]} at column {_column(node, src)} is not a whole "
                                  f"number from 0 to {MAX_EXPONENT}; write the factor as a product")
    raise _refuse(what, src.text, f"the exponent at column {_column(node, src)} must be a whole number from 0 to "
                              f"{MAX_EXPONENT} written as a number, e.g. (T*s + 1)**2")


def _multisets(terms: int, power: int) -> int:
    """Monomials of a sum of ``terms`` monomials raised to ``power`` (an upper bound)."""
    return math.comb(min(terms, MAX_TERMS + 1) + power - 1, power) if power else 1


class _Builder:
    """The checked walk: one sympy expression and its size bound per node."""

    def __init__(self, src: _Source, names: Sequence[str], what: str) -> None:
        import sympy  # type: ignore[import-untyped]  # sympy ships no type information

        self.sympy = sympy
        self.src, self.text, self.what = src, src.text, what
        self.symbols: dict[str, Any] = {n: sympy.Symbol(n, real=True) for n in names}
        self.symbols["s"] = sympy.Symbol("s")

    def build(self, node: ast.expr) -> tuple[Any, _Bound]:
        if isinstance(node, ast.Constant):
            return self._number(node)
        if isinstance(node, ast.Name):
            return self._name(node)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            expr, bound = self.build(node.operand)
            return (-expr if isinstance(node.op, ast.USub) else expr), bound
        if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
            return self._binary(node)
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "exp"
                and len(node.args) == 1 and not node.keywords and not isinstance(node.args[0], ast.Starred)):
            argument, _ = self.build(node.args[0])
            return self.sympy.exp(argument), _Bound(0, 0, 1, 1)
        raise _not_allowed(node, self.src, self.what)

    def _number(self, node: ast.Constant) -> tuple[Any, _Bound]:
        value = node.value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _not_allowed(node, self.src, self.what)
        try:
            size = abs(float(value))
        except OverflowError:
            size = math.inf
        if not size <= MAX_LITERAL:
            raise _refuse(self.what, self.text, f"the number at column {_column(node, self.src)} is larger than "
                                                f"{MAX_LITERAL:g} (or not finite)")
        number = self.sympy.Integer(value) if isinstance(value, int) else self.sympy.Float(value)
        return number, _Bound(0, 0, 1, 1)

    def _name(self, node: ast.Name) -> tuple[Any, _Bound]:
        if node.id not in self.symbols:
            raise InputError(f"unknown symbol {node.id} at column {_column(node, self.src)} in {self.text!r}: "
                             "declare it under [parameters] with a value (known) or a range (to identify); "
                             "s and exp are built in")
        return self.symbols[node.id], _Bound(int(node.id == "s"), 0, 1, 1)

    def _binary(self, node: ast.BinOp) -> tuple[Any, _Bound]:
        left, a = self.build(node.left)
        if isinstance(node.op, (ast.Pow, ast.BitXor)):
            n = _exponent(node.right, self.src, self.what)
            bound = _Bound(a.num_order * n, a.den_order * n, _multisets(a.num_terms, n), _multisets(a.den_terms, n))
            self._check_bound(bound, node)
            return self.sympy.Pow(left, n), bound
        right, b = self.build(node.right)
        if isinstance(node.op, (ast.Add, ast.Sub)):
            bound = _Bound(max(a.num_order + b.den_order, b.num_order + a.den_order), a.den_order + b.den_order,
                           a.num_terms * b.den_terms + b.num_terms * a.den_terms, a.den_terms * b.den_terms)
            expr = left + right if isinstance(node.op, ast.Add) else left - right
        elif isinstance(node.op, ast.Mult):
            bound = _Bound(a.num_order + b.num_order, a.den_order + b.den_order,
                           a.num_terms * b.num_terms, a.den_terms * b.den_terms)
            expr = left * right
        else:
            bound = _Bound(a.num_order + b.den_order, a.den_order + b.num_order,
                           a.num_terms * b.den_terms, a.den_terms * b.num_terms)
            expr = left / right
        self._check_bound(bound, node)
        return expr, bound

    def _check_bound(self, bound: _Bound, node: ast.AST) -> None:
        order = max(bound.num_order, bound.den_order)
        if order > MAX_ORDER:
            raise _refuse(self.what, self.text, f"reaches s**{order} at column {_column(node, self.src)}, above the "
                                                f"model order limit of {MAX_ORDER}")
        if max(bound.num_terms, bound.den_terms) > MAX_TERMS:
            raise _refuse(self.what, self.text, f"would expand to more than {MAX_TERMS} terms at column "
                                                f"{_column(node, self.src)}; write it with fewer parameters "
                                                "or a lower order")


def parse_transfer_function(text: str, names: Sequence[str], what: str = "transfer_function") -> Any:
    """The sympy expression of ``text``, a transfer function in ``s`` of the parameters ``names``.

    Parameters
    ----------
    text : str
        The transfer function, e.g. ``"K*exp(-tau*s)/(T*s + 1)**2"`` (``^`` is read as ``**``).
    names : sequence of str
        The declared parameter names (real symbols); ``s`` is the Laplace variable.
    what : str
        How messages name the text.

    Returns
    -------
    sympy.Expr
        Built from the checked parse tree (module docstring); no text is evaluated.

    Raises
    ------
    InputError
        One line naming the token and its column, or the limit exceeded.
    """
    text = check_transfer_text(text, what)
    src = _Source(text)
    expr, _ = _Builder(src, names, what).build(_parse_tree(src, what))
    return expr
