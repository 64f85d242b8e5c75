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
from typing import Any

import numpy as np

__all__ = ["to_jsonable"]


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
