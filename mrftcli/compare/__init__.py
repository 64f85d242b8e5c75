"""Compare identified loops against a baseline (``mrft-ident compare``).

Read two sides (:mod:`.inputs`: analysis results, batch folders, reference files), test every matched
loop's parameter changes (:mod:`.changes`), report them (:mod:`.export`: terminal, Markdown, JUnit
XML) in a versioned record (:mod:`.records`). docs/compare.md is the user's guide.
"""

from __future__ import annotations

from .changes import CompareOptions, compare_sides, critical_z
from .export import format_table, to_junit_xml, to_markdown
from .inputs import Side, read_side
from .records import (EXIT_CHANGED, EXIT_INCOMPLETE, SCHEMA_VERSION, Comparison, LoopEstimates,
                      MissingResult, ParameterChange, Tolerance)
from .tolerance import parse_fail_on

__all__ = ["compare", "CompareOptions", "compare_sides", "critical_z", "format_table", "to_junit_xml", "to_markdown",
           "Side", "read_side", "EXIT_CHANGED", "EXIT_INCOMPLETE", "SCHEMA_VERSION", "Comparison",
           "LoopEstimates", "MissingResult", "ParameterChange", "Tolerance", "parse_fail_on"]


def compare(baseline: str, new: str, options: CompareOptions | None = None, *, by: str = "log") -> Comparison:
    """Compare two sides given by path (analysis JSON, batch folder, reference .toml).

    Parameters
    ----------
    baseline, new : str
        Paths (see :func:`read_side`).
    options : CompareOptions, optional
        Confidence, correction, tolerances, loops.
    by : {"log", "vehicle"}
        How batch folders are matched.

    Raises
    ------
    InputError
        A side that cannot be read.
    """
    return compare_sides(read_side(baseline, by), read_side(new, by), options)
