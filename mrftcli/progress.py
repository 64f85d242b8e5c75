"""The one progress protocol of the library.

Long-running library functions take ``progress: Progress | None`` and call it as
``progress(done, total, stage)``: ``done`` out of ``total`` units of work (ticks, logs, candidates:
the function's docstring says which) and a short text naming the current stage. Drawing a bar is the
CLI's job (:mod:`mrftcli.cli`, the only place that imports tqdm); the library never prints.

Examples
--------
>>> seen = []
>>> def record(done: float, total: float, stage: str = "") -> None:
...     seen.append((done, total, stage))
>>> report(record, 1, 4, "fitting")
>>> report(None, 2, 4, "ignored")
>>> seen
[(1, 4, 'fitting')]
"""

from __future__ import annotations

from typing import Protocol

__all__ = ["Progress", "report"]


class Progress(Protocol):
    """Called as ``progress(done, total, stage)``; must return quickly and never raise."""

    def __call__(self, done: float, total: float, stage: str = "") -> None: ...


def report(progress: Progress | None, done: float, total: float, stage: str = "") -> None:
    """Call ``progress`` if one was given (so callers need no ``if progress is not None``)."""
    if progress is not None:
        progress(done, total, stage)
