"""Helpers shared by the report modules: Agg figures, saving, and a minimal HTML page."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any, Iterable

import matplotlib

matplotlib.use("Agg")  # never needs a display; set before pyplot is imported

import matplotlib.pyplot as plt  # noqa: E402

from ..io.atomic import (atomic_path, check_output_path, looks_like_figure, looks_like_page,  # noqa: E402
                         write_text_atomic)

__all__ = ["plt", "new_figure", "save_figure", "savefig_atomic", "write_page", "html_page", "html_table", "esc",
           "ensure_dir"]

#: Colours for tests (colour-blind-safe Okabe-Ito order).
TEST_COLOURS = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442", "#000000")

# keys typed loosely: matplotlib's stubs type rc_context's keys as a Literal of every rc name
_STYLE: dict[Any, Any] = {
    "figure.dpi": 100,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.titlesize": 12,
    "axes.labelsize": 10,
    "legend.fontsize": 9,
    "xtick.labelsize": 9,
    "ytick.labelsize": 9,
}


def esc(text: object) -> str:
    """HTML-escape any value's text."""
    return html.escape(str(text))


def ensure_dir(path: str | Path) -> Path:
    """Create the report directory (and parents) and return it."""
    p = Path(path)
    p.mkdir(parents=True, exist_ok=True)
    return p


def new_figure(nrows: int = 1, ncols: int = 1, *, width: float = 10.0, height: float = 4.0, **kw):
    """A figure with the report style (grid, font sizes); returns (fig, axes)."""
    with plt.rc_context(_STYLE):
        fig, axes = plt.subplots(nrows, ncols, figsize=(width, height), **kw)
    return fig, axes


def save_figure(fig, path: str | Path, dpi: int = 110) -> Path:
    """Save as PNG with a tight layout (unless the figure has its own) and close the figure (reports never keep figures open)."""
    path = Path(path)
    try:
        with plt.rc_context(_STYLE):
            if fig.get_layout_engine() is None:  # a figure laid out as constrained keeps its own layout
                fig.tight_layout()
            savefig_atomic(fig, path, dpi=dpi)
    finally:
        plt.close(fig)  # also when the path is refused
    return path


def savefig_atomic(fig, path: str | Path, *, dpi: int = 110) -> Path:
    """``fig.savefig`` into a temporary file renamed onto ``path`` (:mod:`mrftcli.io.atomic`): a run
    killed mid-report never leaves a cut PNG; the format is the path's suffix (PNG without one)."""
    path = Path(path)
    check_output_path(path, "--report", ours=looks_like_figure, what="a figure")  # never someone's file (issue 35)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".").lower() or "png")
    return path


def write_page(path: str | Path, page: str) -> Path:
    """Write an HTML page (:func:`html_page`) atomically: a reader never sees half a page; an existing file
    that is not a page (or a link) is not replaced (:func:`mrftcli.io.atomic.check_output_path`)."""
    check_output_path(path, "--report", ours=looks_like_page, what="an HTML page")
    return write_text_atomic(path, page)


def html_table(header: Iterable[str], rows: Iterable[Iterable[object]]) -> str:
    """A plain HTML table (cells escaped)."""
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{esc(c)}</td>" for c in row) + "</tr>" for row in rows)
    # the wrapper scrolls a table wider than the page instead of letting it run past the page's edge
    return f"<div class='table-wrap'><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>"


_CSS = """
body { font-family: -apple-system, Segoe UI, Helvetica, Arial, sans-serif; margin: 2em auto; max-width: 1100px;
       color: #222; line-height: 1.4; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }
th { background: #f3f3f3; } td:first-child, th:first-child { text-align: left; }
img { max-width: 100%; border: 1px solid #eee; }
.table-wrap { max-width: 100%; overflow-x: auto; }
td:first-child { overflow-wrap: anywhere; min-width: 10em; }
pre { background: #f7f7f7; padding: 0.6em; overflow-x: auto; }
.warn { color: #8a4b00; } .muted { color: #666; font-size: 0.9em; }
"""


def html_page(title: str, body: str) -> str:
    """A self-contained HTML page (inline CSS) around ``body`` (already HTML)."""
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>{esc(title)}</title><style>{_CSS}</style></head>\n<body>\n<h1>{esc(title)}</h1>\n{body}\n"
        "</body></html>\n"
    )
