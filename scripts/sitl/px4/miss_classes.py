"""The PX4 campaign's held-out misses by class (issue 42): which loop and relay height, refused, not found or
over 5 %, and whether each lies inside the std analyze states for its own held-out prediction.

A class is set by how the flight was flown (its loop and relay height), never by its outcome:

* altitude at h <= 0.15 (cycles of 1-15 cm, where EKF2's altitude error is a large part of the cycle);
* altitude at h > 0.15 (the campaign flies 0.25);
* x / y (eq. (2) holds the attitude loop in its delay);
* roll / pitch (on EKF2's attitude).

Each test's own mean frequency has a standard error (the spread of its cycles over their count): a test whose
mean is uncertain by a few percent cannot be predicted within 5 % by any model; the class line prints the
median of that standard error for its misses and for its hits.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["miss_class", "classify", "totals", "report_classes"]


def miss_class(loop: str, h_max: float) -> str:
    """The class of a flight's tests from its loop and its largest relay height [command units]."""
    if loop == "altitude":
        if not math.isfinite(h_max):
            raise ValueError(f"an altitude flight's relay height is {h_max}: its class needs a finite h")
        return "altitude, h <= 0.15" if h_max <= 0.15 + 1e-9 else "altitude, h > 0.15"
    return "x / y" if loop in ("x", "y") else "roll / pitch"


def _outcomes(r: dict[str, Any]) -> list[tuple[str, dict[str, Any] | None]]:
    """One (outcome, the test's jitter row or None) per flown test: 'refused', 'not found', 'not predicted',
    'over' (more than 5 % off) or 'within'."""
    if "refused" in r:
        return [("refused", None)] * r["flown"]
    jitter = r.get("jitter", [])
    if "held_rate" in r:  # the rate loops: analyze's own held-out (``held_out_jitter``'s error, per test)
        errs = {k: row["error"] for k, row in enumerate(jitter) if row["error"] is not None}
    else:
        errs = {h.index: h.error for h in r["held"]}
    out = [("not found", None)] * max(0, r["flown"] - r["found"])
    for k in range(r["found"]):
        row = jitter[k] if k < len(jitter) else None
        e = errs.get(k)
        out.append(("not predicted", row) if e is None else ("over" if abs(e) > 0.05 else "within", row))
    return out


def classify(results: dict[str, dict[str, Any]], h_max: dict[str, float]) -> dict[str, dict[str, Any]]:
    """Per class: the count of each outcome, the over-5 % tests' |z| (analyze's stated std) and the
    standard errors of their own mean frequencies [-], beside the hits' (the tests held out within 5 %; a test
    found but not predicted is neither). ``h_max``: each flight's largest h; a flight missing from it is an error
    (its class would be a guess)."""
    classes: dict[str, dict[str, Any]] = {}
    for name, r in results.items():
        if name not in h_max:
            raise KeyError(f"no relay height for flight {name!r}: its class is set by the h it flew")
        c = classes.setdefault(miss_class(r["loop"], h_max[name]),
                               {"flights": [], "counts": {}, "z": [], "sem_miss": [], "sem_hit": [], "band": []})
        c["flights"].append(name)
        for outcome, row in _outcomes(r):
            c["counts"][outcome] = c["counts"].get(outcome, 0) + 1
            if row is None:
                continue
            if outcome in ("over", "within"):
                (c["sem_miss"] if outcome == "over" else c["sem_hit"]).append(row["sem"])
            if outcome == "over" and row.get("z") is not None:
                c["z"].append(abs(row["z"]))
            if outcome == "over" and "ekf" in row:
                c["band"].append(row["ekf"]["band"])
    return classes


def totals(classes: dict[str, dict[str, Any]]) -> dict[str, int]:
    """Every class's outcome counts summed: the campaign's refused, not found, not predicted, over and within."""
    out: dict[str, int] = {}
    for c in classes.values():
        for outcome, n in c["counts"].items():
            out[outcome] = out.get(outcome, 0) + n
    return out


def _pct(values: list[float]) -> str:
    vals = [v for v in values if np.isfinite(v)]
    return f"{np.median(vals) * 100:.1f} %" if vals else "-"


def report_classes(classes: dict[str, dict[str, Any]]) -> None:
    """Print one line per class of :func:`classify` (the benchmark's classification of the misses)."""
    print("  the misses by class (set by the loop and relay height flown):")
    for name, c in classes.items():
        n = sum(c["counts"].values())
        misses = n - c["counts"].get("within", 0)
        parts = ", ".join(f"{v} {k}" for k, v in c["counts"].items() if k != "within")
        z = c["z"]
        print(f"    {name}: {misses} missed of {n} ({parts or 'none'}); the over-5 % within 2.5 of analyze's stated "
              f"std {sum(v <= 2.5 for v in z)}/{len(z)} (max |z| {max(z, default=math.nan):.2f}); their own mean "
              f"frequency's standard error, median {_pct(c['sem_miss'])} (the hits' {_pct(c['sem_hit'])})"
              + (f"; EKF2's error in the cycle band, median {_pct(c['band'])} of the amplitude (where SIH's is logged)"
                 if c["band"] else "") + f" [{', '.join(c['flights'])}]")
