"""Plain JSON values from the library's records (numpy scalars and arrays, NaN), for every writer.

The CLI's ``--json`` output and the batch's per-log records both go through :func:`to_jsonable`, so a
record reads the same whichever wrote it.

Examples
--------
>>> import numpy as np
>>> to_jsonable({"f": np.float64(1.5), "nan": float("nan"), "v": np.arange(2), 3: (np.bool_(True),)})
{'f': 1.5, 'nan': None, 'v': [0, 1], '3': [True]}
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Collection, Mapping
from typing import Any

import numpy as np

from .errors import InputError

__all__ = ["to_jsonable", "check_schema_version", "json_float", "json_opt_float", "finite_or_none", "load_json_text", "load_toml_text", "load_yaml_text",
           "MAX_JSON_DEPTH", "MAX_YAML_NODES"]


#: deepest nesting of objects and arrays a JSON (or TOML) file the tool reads may have; the records
#: nest a dozen levels, and Python's parsers recurse (a file nested 100,000 deep would exhaust the stack)
MAX_JSON_DEPTH = 64

#: a JSON string (brackets inside strings do not nest)
_JSON_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"')


def json_depth(text: str) -> int:
    """The deepest nesting of ``[``/``{`` in JSON ``text`` (brackets in strings not counted), in one
    vectorised pass: the check runs before the parser, whose recursion a deep file would exhaust.

    Examples
    --------
    >>> json_depth('{"a": [[1, "]]]"], {}]}')
    3
    """
    codes = np.frombuffer(_JSON_STRING.sub('""', text).encode("utf-8", "replace"), dtype=np.uint8)
    if not codes.size:
        return 0
    steps = ((codes == ord("[")) | (codes == ord("{"))).astype(np.int32)
    steps -= ((codes == ord("]")) | (codes == ord("}"))).astype(np.int32)
    return int(np.cumsum(steps).max())


def load_json_text(text: str, what: str) -> Any:
    """The parsed JSON ``text``; one-line :class:`~mrftcli.errors.InputError` naming ``what`` when it is
    not JSON or is nested deeper than :data:`MAX_JSON_DEPTH` (the one JSON reader of the tool's inputs).

    Examples
    --------
    >>> load_json_text('{"a": [1, 2]}', "demo")
    {'a': [1, 2]}
    >>> load_json_text("[" * 100000, "demo")
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: demo: JSON nested 100000 deep, more than the 64 levels any file mrft-ident reads has; is it the right file?
    """
    return _parsed(text, what, "JSON", json.loads)


def _check_depth(text: str, what: str, kind: str) -> None:
    """InputError when ``text`` nests deeper than :data:`MAX_JSON_DEPTH` (JSON, and TOML's arrays and inline
    tables and YAML's flow collections, which use JSON's brackets): the parsers recurse."""
    depth = json_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise InputError(f"{what}: {kind} nested {depth} deep, more than the {MAX_JSON_DEPTH} levels any file "
                         "mrft-ident reads has; is it the right file?")


def _parsed(text: str, what: str, kind: str, parse: Any) -> Any:
    """``parse(text)`` after :func:`_check_depth`; its errors (ValueError, as tomllib's) as one-line InputErrors."""
    _check_depth(text, what, kind)
    try:
        return parse(text)
    except RecursionError:
        raise InputError(f"{what}: {kind} nested too deep to read") from None
    except ValueError as err:
        raise InputError(f"{what}: not valid {kind} ({str(err).splitlines()[0]})") from None


def load_toml_text(text: str, what: str) -> Any:
    """The parsed TOML ``text``; one-line InputError when it is not TOML or nests arrays or inline tables
    deeper than :data:`MAX_JSON_DEPTH` (``tomllib`` recurses on them)."""
    import tomllib

    return _parsed(text, what, "TOML", tomllib.loads)


#: most values a YAML file may expand to, aliases counted at every use (a settings file holds hundreds;
#: a 341-byte "billion laughs" file of nested aliases expands to 10**9)
MAX_YAML_NODES = 100_000


def load_yaml_text(text: str, what: str) -> Any:
    r"""The parsed YAML ``text`` through PyYAML's safe loader (plain values only: no Python object is
    ever constructed), after checking on the composed node graph that it expands to at most
    :data:`MAX_YAML_NODES` values nested at most :data:`MAX_JSON_DEPTH` deep, with no recursive alias.

    Examples
    --------
    >>> load_yaml_text("a: &x [1, 2]\nb: *x", "demo")
    {'a': [1, 2], 'b': [1, 2]}
    >>> load_yaml_text("a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
    ...     f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 10)}]\n" for i in range(5)), "demo")
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: demo: its aliases expand to more than 100000 values (a settings file holds hundreds); is it the right file?
    """
    import yaml  # PyYAML, only needed for YAML configs

    _check_depth(text, what, "YAML")  # PyYAML's composer recurses
    # the pure-Python safe loader: libyaml's (CSafeLoader) crashes the process on deeply nested input
    loader = yaml.SafeLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_yaml_graph(node, what)
        return loader.construct_document(node)
    except yaml.YAMLError as err:
        raise InputError(f"{what}: not valid YAML: {' '.join(str(err).split())}") from None
    except RecursionError:
        raise InputError(f"{what}: YAML nested too deep to read") from None
    finally:
        loader.dispose()


def _check_yaml_graph(root: Any, what: str) -> None:
    """Expanded size and depth of a composed YAML node graph (aliases share nodes), without recursion."""
    size: dict[int, int] = {}
    depth: dict[int, int] = {}
    open_nodes: set[int] = set()
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        node, finished = stack.pop()
        key = id(node)
        children = [c for pair in node.value for c in (pair if isinstance(pair, tuple) else (pair,))] \
            if isinstance(node.value, list) else []
        if finished:
            open_nodes.discard(key)
            size[key] = 1 + sum(size[id(c)] for c in children)
            depth[key] = 1 + max((depth[id(c)] for c in children), default=0)
            if size[key] > MAX_YAML_NODES:
                raise InputError(f"{what}: its aliases expand to more than {MAX_YAML_NODES} values (a settings "
                                 "file holds hundreds); is it the right file?")
            if depth[key] > MAX_JSON_DEPTH:
                raise InputError(f"{what}: YAML nested more than {MAX_JSON_DEPTH} deep; is it the right file?")
            continue
        if key in size:
            continue
        if key in open_nodes:
            raise InputError(f"{what}: a recursive YAML alias (a value that contains itself)")
        open_nodes.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in children if id(c) not in size)


def to_jsonable(obj: Any, nonfinite: Callable[[float], Any] = lambda v: None) -> Any:
    """Convert numpy scalars/arrays, dataclasses' dicts and NaN into plain JSON values (NaN -> None).

    Dict keys become strings, tuples and arrays become lists, non-finite floats become None (JSON has
    no NaN; ``nonfinite=str``: the strings "inf", "-inf", "nan" of the tune records); anything else is
    returned unchanged.
    """
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v, nonfinite) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v, nonfinite) for v in obj]
    if isinstance(obj, np.ndarray):
        return [to_jsonable(v, nonfinite) for v in obj.tolist()]
    if isinstance(obj, (np.floating, float)):
        value = float(obj)
        return value if math.isfinite(value) else nonfinite(value)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def json_float(x: object, what: str = "a number") -> float:
    """A JSON number as a float (null, which the writers make of NaN: NaN); TypeError on anything else."""
    if x is None:
        return float("nan")
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise TypeError(f"expected {what}, got {x!r}")
    return float(x)


def json_opt_float(x: object, what: str = "a number or null") -> float | None:
    """A JSON number or null as a float or None (TypeError, naming ``what``, on anything else)."""
    return None if x is None else json_float(x, what)


def finite_or_none(x: float | None) -> float | None:
    """``x`` as a float, or None when it is None or not finite (JSON has no inf or NaN: an undetermined std is null)."""
    return float(x) if x is not None and math.isfinite(x) else None


def check_schema_version(data: Any, what: str, supported: int | Collection[int], *, missing: int | None = None,
                         fix: str = "write it again with this version of mrft-ident") -> Mapping[str, Any]:
    """``data`` as a mapping after checking it is a JSON object whose ``schema_version`` this version reads.

    The one check every record's ``from_json`` starts with.

    Parameters
    ----------
    data : Any
        The parsed JSON.
    what : str
        The record's name for the message, e.g. ``"tune margins"``.
    supported : int or collection of int
        The schema version(s) this version of mrft-ident reads.
    missing : int or None
        The version a JSON without ``schema_version`` is taken to have (records written before the field
        existed); None: such a JSON is refused.
    fix : str
        What the user should do, ending the one-line message.

    Raises
    ------
    InputError
        ``data`` is not a JSON object, or its version is not supported (one line, naming the fix).

    Examples
    --------
    >>> check_schema_version({"schema_version": 2, "x": 1}, "demo", 2)["x"]
    1
    >>> check_schema_version({"schema_version": 3}, "demo", (1, 2))
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: demo: schema_version 3 is not supported (this version reads 1, 2); update mrft-ident (a newer version wrote it)
    >>> check_schema_version({"schema_version": 0}, "demo", (1, 2))
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: demo: schema_version 0 is not supported (this version reads 1, 2); write it again with this version of mrft-ident
    """
    if not isinstance(data, Mapping):
        raise InputError(f"{what}: expected a JSON object, got {type(data).__name__}")
    versions = (supported,) if isinstance(supported, int) else tuple(supported)
    version = data.get("schema_version", missing)
    if version is None:
        raise InputError(f"{what}: no schema_version (is this a {what}?); {fix}")
    if isinstance(version, bool) or version not in versions:
        readable = ", ".join(str(v) for v in versions)
        if isinstance(version, int) and versions and version > max(versions):  # rewriting it cannot help
            fix = "update mrft-ident (a newer version wrote it)"
        raise InputError(f"{what}: schema_version {version!r} is not supported (this version reads {readable}); "
                         f"{fix}")
    return data
