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

import math
from collections.abc import Collection, Mapping
from typing import Any

import numpy as np

from .errors import InputError

__all__ = ["to_jsonable", "check_schema_version"]


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays, dataclasses' dicts and NaN into plain JSON values (NaN -> None).

    Dict keys become strings, tuples and arrays become lists, non-finite floats become None (JSON has
    no NaN); anything else is returned unchanged.
    """
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [to_jsonable(v) for v in obj.tolist()]
    if isinstance(obj, (np.floating, float)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


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
    mrftcli.errors.InputError: demo: schema_version 3 is not supported (this version reads 1, 2); write it again with this version of mrft-ident
    """
    if not isinstance(data, Mapping):
        raise InputError(f"{what}: expected a JSON object, got {type(data).__name__}")
    versions = (supported,) if isinstance(supported, int) else tuple(supported)
    version = data.get("schema_version", missing)
    if version is None:
        raise InputError(f"{what}: no schema_version (is this a {what}?); {fix}")
    if isinstance(version, bool) or version not in versions:
        readable = ", ".join(str(v) for v in versions)
        raise InputError(f"{what}: schema_version {version!r} is not supported (this version reads {readable}); "
                         f"{fix}")
    return data
