"""Which loops a flight recorded, and in which order a vehicle's loops are identified and tuned.

One implementation of "the loops of a log" (``batch --loop auto`` and ``mrft-ident vehicle`` both
use it): the loops of the log's layout (named, or recognised from its topics) whose command and
output topics the log holds. Whether a loop's relay *moved* (it holds MRFT tests) is the segmenter's
question, asked when the loop is analysed.

The cascade of a multirotor: the attitude loops (roll, pitch) and the altitude loop are *inner*
loops, identified with eq. (2) at the known Tp; the lateral loops x and y are *outer* loops, whose
plant is the closed inner attitude loop followed by the translational dynamics (y rides on roll,
x on pitch).
"""

from __future__ import annotations

from pathlib import Path

from ..io import LogSource, log_layout, open_log
from ..io.layouts import Layout
from ..io.logtypes import LOOPS

__all__ = ["INNER_LOOPS", "OUTER_LOOPS", "INNER_OF", "VEHICLE_ORDER", "loops_in_log", "absent_topics", "layout_absent"]

#: Loops identified first, with eq. (2) at the known Tp.
INNER_LOOPS = ("altitude", "roll", "pitch")
#: Loops whose plant holds a closed inner loop.
OUTER_LOOPS = ("x", "y")
#: The inner (attitude) loop each outer loop commands through: a roll angle moves the vehicle along y,
#: a pitch angle along x.
INNER_OF: dict[str, str] = {"x": "pitch", "y": "roll"}
#: Every loop, inner loops first (the order of identification and tuning).
VEHICLE_ORDER = tuple(loop for loop in (*INNER_LOOPS, *OUTER_LOOPS) if loop in LOOPS)


def loops_in_log(path: str | Path, layout: str | None = None) -> tuple[str, ...]:
    """The loops of the log's layout whose command and output topics the log holds.

    Parameters
    ----------
    path : str or Path
        The log (any format :func:`mrftcli.io.open_log` reads).
    layout : str, optional
        A layout name; None: recognised from the topics (:func:`mrftcli.io.log_layout`).

    Returns
    -------
    tuple of str
        In the layout's order; empty when the layout records none of its loops.
    """
    with open_log(path) as source:
        lay = log_layout(source, layout).layout
        return tuple(loop for loop in lay.loops if not layout_absent(source, lay, loop))


def absent_topics(path: str | Path, loop: str, layout: str | None = None) -> tuple[str, ...]:
    """The topics of ``loop`` (command, output) that the log's layout names and the log does not hold.

    The layout is the one :func:`mrftcli.io.log_layout` reads the log with (named, or recognised from
    the topics). A layout without the loop gives its name as the one absent topic. Empty: the loop's
    topics are there (whether its tests are is the analysis's question).
    """
    with open_log(path) as source:
        return layout_absent(source, log_layout(source, layout).layout, loop)


def layout_absent(source: LogSource, layout: Layout, loop: str) -> tuple[str, ...]:
    """:func:`absent_topics` on a log that is open already, read with ``layout``."""
    topics = layout.loops.get(loop)
    if topics is None:
        return (f"{layout.name} layout has no {loop} loop",)
    specs = (topics.command, topics.output)
    return tuple(spec for spec in specs if source.resolve_topic(spec.split(":", 1)[0]) is None)
