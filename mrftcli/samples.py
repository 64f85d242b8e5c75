"""The sample logs that ship inside the package, so examples run from any install.

A ``pip install .`` (not editable) copies no ``sample_logs/`` folder next to the package; the few logs the
documentation's examples use are installed as package data (``mrftcli._samples``) and found here.

Examples
--------
>>> from mrftcli.samples import sample_log
>>> sample_log("design1_altitude.mcap").name
'design1_altitude.mcap'
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

from .errors import InputError

#: The logs installed with the package (the rest of ``sample_logs/`` lives only in the source tree).
PACKAGED = ("design1_altitude.mcap", "design1_altitude.csv", "concealed/flight_02.mcap")

__all__ = ["PACKAGED", "sample_log"]


def sample_log(name: str = "design1_altitude.mcap") -> Path:
    """Path of a sample log shipped with the package.

    Parameters
    ----------
    name : str
        One of :data:`PACKAGED` (a path relative to ``sample_logs/``); its ground truth is beside it as
        ``<name>.truth.json``.

    Returns
    -------
    pathlib.Path
        The installed file (read-only; never modify it).

    Raises
    ------
    InputError
        ``name`` is not a packaged sample, or the install lacks it.

    Examples
    --------
    >>> path = sample_log("design1_altitude.csv")
    >>> path.exists(), path.with_name(path.name + ".truth.json").exists()
    (True, True)
    """
    if name not in PACKAGED:
        raise InputError(f"no packaged sample log {name!r}: choose one of {', '.join(PACKAGED)}")
    candidates = [Path(__file__).resolve().parents[1] / "sample_logs" / name]  # a source checkout
    try:
        candidates.insert(0, Path(str(importlib.resources.files("mrftcli._samples").joinpath(name))))
    except ModuleNotFoundError:  # a source checkout that was never installed
        pass
    for path in candidates:
        if path.exists():
            return path
    raise InputError(f"the packaged sample log {name!r} is missing from this install (reinstall mrft-ident)")
