"""What a set of relay tests determines when it does not determine every parameter (issue 38, item 3).

One relay setting puts its response points at one frequency and its odd harmonics. Where the slope
of the plant's response there is all they see, some parameters trade off: on a slow SOPDT well
above its corner ``|G| ~ K / (omega T1)``, so K and T1 move together and only ``K/T1`` (with the
phase: T2 and tau) is pinned down. :func:`~mrftcli.mrft.identify_lti.fit_response_points` (the families' strategy of ``identify``) names the
parameters the fit does not determine (the Jacobian's rank and each interval's width); this module
finds the product of their powers that the points **do** determine: the direction, in the
log-parameters, of the largest information left once the determined parameters are profiled out
(the Schur complement of the Fisher information ``J^T J``, so their uncertainty is included). The
exponents are rounded to halves where that costs little precision or keeps the 95 % interval within a
factor e (``K/T1`` rather than ``K^1 T1^-0.93``); the combination is reported only if its 95 % interval is within a factor of e^2
(a single parameter is called determined only within a factor 1.25,
:data:`~mrftcli.mrft.parameter.DETERMINED_LOG_WIDTH`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from .parameter import Z95

__all__ = ["DeterminedCombination", "determined_combination"]

#: a combination is determined when its 95 % interval is within this factor (log width 2: e^2)
_LOG_WIDTH = 2.0


@dataclass(frozen=True)
class DeterminedCombination:
    """A product of powers of parameters the tests determine, though each factor alone is not.

    Attributes
    ----------
    exponents : tuple of (str, float)
        Parameter name and its power, e.g. ``(("K", 1.0), ("T1", -1.0))`` for K/T1.
    value : float
        Its value at the estimate [the product of the units' powers, :attr:`unit`].
    ci95_low, ci95_high : float
        95 % interval (log-normal: the log-parameters' covariance).
    unit : str
        The unit, e.g. ``output / command / s``.
    """

    exponents: tuple[tuple[str, float], ...]
    value: float
    ci95_low: float
    ci95_high: float
    unit: str

    @property
    def name(self) -> str:
        """``K/T1``, ``K T1^0.5``: the powers as written by hand."""
        num = [_power(n, e) for n, e in self.exponents if e > 0]
        den = [_power(n, -e) for n, e in self.exponents if e < 0]
        top = " ".join(num) or "1"
        return top + "".join(f"/{d}" for d in den)

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "exponents": dict(self.exponents), "value": self.value,
                "ci95_low": self.ci95_low, "ci95_high": self.ci95_high, "unit": self.unit}

    @classmethod
    def from_json(cls, data: Any) -> DeterminedCombination:
        try:
            exps = tuple((str(n), float(e)) for n, e in data["exponents"].items())
            return cls(exps, float(data["value"]), float(data["ci95_low"]), float(data["ci95_high"]),
                       str(data.get("unit", "")))
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise InputError(f"identification JSON: bad determined combination ({err})") from None


def _power(name: str, e: float) -> str:
    return name if e == 1 else f"{name}^{e:g}"


def _unit(exponents: Sequence[tuple[str, float]], units: Mapping[str, str]) -> str:
    parts = []
    for n, e in exponents:
        u = units.get(n, "")
        if not u or u == "-":
            continue
        u = f"({u})" if " " in u else u
        parts.append(u if e == 1 else f"{u}^{e:g}")
    return " ".join(parts) or "-"


def _schur_information(F: NDArray[np.float64], sel: list[int]) -> NDArray[np.float64]:
    """The information on the selected log-parameters with the others profiled out."""
    rest = [i for i in range(F.shape[0]) if i not in sel]
    F_uu = F[np.ix_(sel, sel)]
    if not rest:
        return F_uu
    F_ur, F_rr = F[np.ix_(sel, rest)], F[np.ix_(rest, rest)]
    out: NDArray[np.float64] = F_uu - F_ur @ np.linalg.pinv(F_rr, rcond=1e-12) @ F_ur.T
    return 0.5 * (out + out.T)


def _variance(S: NDArray[np.float64], e: NDArray[np.float64]) -> float:
    """Variance of ``e . z`` from the information ``S`` (infinite along a direction S does not see)."""
    w, V = np.linalg.eigh(S)
    c = V.T @ e
    top = float(w[-1]) if w.size else 0.0
    if top <= 0:
        return math.inf
    blind = w <= 1e-12 * top
    if np.any(np.abs(c[blind]) > 1e-9 * float(np.linalg.norm(e))):
        return math.inf
    return float(np.sum(c[~blind] ** 2 / w[~blind]))


def _best_direction(F: NDArray[np.float64], sel: list[int]) -> tuple[float, NDArray[np.float64]] | None:
    """(std, exponents) of the best-determined power product of the parameters ``sel``, or None."""
    S = _schur_information(F, sel)
    w, V = np.linalg.eigh(S)
    if not w.size or w[-1] <= 0:
        return None
    v = V[:, -1]
    e = v / v[int(np.argmax(np.abs(v)))]  # the strongest factor at power 1
    rounded = np.round(2 * e) / 2
    var_exact = _variance(S, e)
    var_round = _variance(S, rounded) if np.any(rounded != 0) else math.inf
    if var_round <= 4 * var_exact or 2 * Z95 * math.sqrt(var_round) < 0.5 * _LOG_WIDTH:
        # halves, as written by hand, where they cost at most a factor 2 in the std or stay within a factor e
        e, var = rounded, var_round
    else:
        e = np.round(e, 2)
        var = _variance(S, e)
    return (math.sqrt(var), e) if math.isfinite(var) else None


def determined_combination(names: Sequence[str], z: NDArray[np.float64], F: NDArray[np.float64],
                           undetermined: Sequence[str], units: Mapping[str, str],
                           signs: Mapping[str, float] | None = None,
                           log_width: float = _LOG_WIDTH,
                           region: Sequence[NDArray[np.float64]] = ()) -> DeterminedCombination | None:
    """The best-determined power product of the undetermined log-scaled parameters, or None.

    Parameters
    ----------
    names : sequence of str
        The unknowns, in the order of ``z`` and ``F``.
    z : ndarray
        The estimate, log of each parameter's modulus.
    F : ndarray
        Fisher information on ``z`` (``J^T J`` of the weighted residuals, scaled by the misfit).
    undetermined : sequence of str
        The parameters the fit leaves undetermined (only those in ``names`` take part).
    units : mapping
        Unit of each parameter.
    signs : mapping, optional
        Sign of each parameter's value (K may be negative); default positive.
    log_width : float
        The widest 95 % interval, in log units, of a determined combination (default a factor e^2).
        Of the combinations within it, the one with the fewest factors, then the least uncertain.
    region : sequence of ndarray
        Points of ``z`` inside the 95 % confidence region (the profile likelihood's, where the fit is
        not linear): the combination's interval is widened to hold its value at each of them, so a
        curved valley (SOPDT's two lags) cannot make it overconfident.

    Examples
    --------
    K and T seen only through K/T (log-information along (1, -1)):

    >>> F = 1e4 * np.array([[1.0, -1.0], [-1.0, 1.0]]) + 1e-3 * np.eye(2)
    >>> c = determined_combination(["K", "T"], np.log([2.0, 4.0]), F, ["K", "T"], {"K": "-", "T": "s"})
    >>> c.name, round(c.value, 3)
    ('K/T', 0.5)
    """
    sel = [i for i, n in enumerate(names) if n in undetermined]
    if len(sel) < 2:
        return None
    best: tuple[float, list[int], NDArray[np.float64], float, float] | None = None
    for size in range(2, len(sel) + 1):  # the fewest factors first: K/T1 before K T2^0.5/T1
        for sub in itertools.combinations(sel, size):
            found = _best_direction(np.asarray(F, dtype=np.float64), list(sub))
            if found is None or np.count_nonzero(found[1]) < 2:
                continue
            c0 = float(sum(ei * z[i] for i, ei in zip(sub, found[1].tolist())))
            c_region = [float(sum(ei * zr[i] for i, ei in zip(sub, found[1].tolist()))) for zr in region]
            a = min([c0 - Z95 * found[0], *c_region])
            b = max([c0 + Z95 * found[0], *c_region])
            if b - a < log_width and (best is None or b - a < best[3] - best[4]):
                best = (found[0], list(sub), found[1], b, a)
        if best is not None:
            break
    if best is None:
        return None
    _, sel, e, hi_log, lo_log = best
    pick = [(names[i], float(ei)) for i, ei in zip(sel, e.tolist()) if ei != 0]
    log_value = float(sum(ei * z[i] for i, ei in zip(sel, e.tolist())))
    sign = 1.0
    for n, ei in pick:
        if (signs or {}).get(n, 1.0) < 0 and float(ei).is_integer() and int(ei) % 2:
            sign = -sign
    ends = sorted([sign * math.exp(lo_log), sign * math.exp(hi_log)])
    pick.sort(key=lambda ne: -ne[1])
    return DeterminedCombination(tuple(pick), sign * math.exp(log_value), ends[0], ends[1], _unit(pick, units))
