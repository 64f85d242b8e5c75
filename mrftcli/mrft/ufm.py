"""Unit frequency and unit gain manifolds (UFM / UGM) of the paper's model, eq. (2).

By Lemmas 1-4 of the paper every plant ``G(s) = K Td e^{-tau s} / (s (Tp s+1)(Td s+1))`` that the
MRFT (parameter beta) makes oscillate at ``Omega`` [rad/s] maps to the normalised plant

    G_n(s) = e^{-theta s} / (s (tp_n s + 1)(td_n s + 1)),  tp_n = Tp Omega, td_n = Td Omega, theta = tau Omega

which oscillates at exactly 1 rad/s.  For each beta the **UFM** is the surface ``theta(tp_n, td_n)``
(our convention: unit frequency = 1 rad/s, not the paper's 1 Hz) and the **UGM** the amplitude
``a_unit(tp_n, td_n)`` of G_n for relay height h = 1 (so that ``a = h K Td a_unit / Omega``).  Both come
from the exact closed form in :mod:`mrftcli.mrft.lprs`.

File format (``FORMAT_VERSION`` 1), one pair of files per beta in a directory:

* ``ufm_beta{beta:+.3f}.npz`` with float64 ``tp`` (n_tp,), ``td`` (n_td,) log-spaced grids of
  ``tp_n = Tp Omega`` and ``td_n = Td Omega`` (:attr:`Manifold.tp_n`, :attr:`Manifold.td_n`), float32
  ``theta`` and ``amplitude`` (n_tp, n_td), and ``metadata`` (0-d string: the JSON below);
* ``ufm_beta{beta:+.3f}.json`` with ``format``: "mrft-ident-ufm", ``format_version``, ``beta``,
  ``model``, ``unit_frequency_rad_s``: 1.0, ``gain_normalisation``: "K*Td = 1, h = 1", ``grid``
  (ranges, sizes, spacing), ``build`` (method, tolerances, time), ``package_version``, ``created``.

``theta`` is stored *signed*: a negative value is the delay a plant would need to oscillate at unit
frequency if delays could be negative (the delay-free plant already lags too much).  No physical plant
lies there; :meth:`Manifold.theta_physical` masks it with NaN.  Keeping the signed values makes the
surface smooth across the boundary, which the identifier's bracketing relies on.
"""

from __future__ import annotations

import datetime as _dt
import functools
import importlib.resources
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from importlib.resources.abc import Traversable
from typing import Any, Iterable

import numpy as np
from numpy.typing import ArrayLike

from .._version import __version__
from ..errors import InputError
from ..jsonable import load_json_text
from ..io.atomic import atomic_path, write_text_atomic
from ..progress import Progress, report
from ..validate import check_beta
from .lprs import unit_crossing, unit_cycle, unit_extremum

__all__ = [
    "FORMAT_VERSION",
    "DEFAULT_TP",
    "DEFAULT_TD",
    "SHIPPED_BETAS",
    "Manifold",
    "ManifoldSet",
    "build_manifold",
    "build_manifolds",
    "save_manifold",
    "load_manifold",
    "load_manifolds",
]

FORMAT_VERSION = 1
#: normalised propulsion time constant grid, Tp * Omega (Omega in rad/s)
DEFAULT_TP = np.logspace(-3.0, 2.0, 201)
#: normalised drag time constant grid, Td * Omega
DEFAULT_TD = np.logspace(-2.0, 3.0, 201)
#: the betas shipped in mrftcli._manifolds (manifolds/ in the source tree)
SHIPPED_BETAS = tuple(np.round(np.arange(-0.9, -0.1 + 1e-9, 0.05), 3))
MODEL = "G(s) = K Td exp(-tau s) / (s (Tp s + 1) (Td s + 1))  (paper eq. 2)"


def _file_stem(beta: float) -> str:
    return f"ufm_beta{beta:+.3f}"


@dataclass(frozen=True, eq=False)
class Manifold:
    """UFM and UGM of eq. (2) for one beta, on a log grid of (tp_n, td_n) = (Tp, Td) * Omega.

    Attributes
    ----------
    beta : float
        MRFT parameter.
    tp_n, td_n : ndarray
        Normalised grids Tp * Omega and Td * Omega (dimensionless), increasing, log-spaced.
    theta : ndarray, shape (tp_n.size, td_n.size)
        Signed normalised delay tau * Omega [rad] giving unit frequency (UFM).
    amplitude : ndarray, shape (tp_n.size, td_n.size)
        Output amplitude for h = 1, K Td = 1 at Omega = 1 rad/s (UGM).
    metadata : dict
        Build information (see the module docstring).
    """

    beta: float
    tp_n: np.ndarray
    td_n: np.ndarray
    theta: np.ndarray = field(repr=False)
    amplitude: np.ndarray = field(repr=False)
    metadata: dict[str, Any] = field(default_factory=dict, repr=False)

    def theta_physical(self) -> np.ndarray:
        """UFM with NaN where no non-negative delay gives unit frequency."""
        th = np.asarray(self.theta, dtype=float)
        return np.where(th >= 0, th, np.nan)

    def interpolate(self, tp_n: ArrayLike, td_n: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Bilinear interpolation in (log tp_n, log td_n) of (theta, amplitude); NaN outside the grid."""
        ltp, ltd = np.log(self.tp_n), np.log(self.td_n)
        x = np.log(np.asarray(tp_n, dtype=float))
        y = np.log(np.asarray(td_n, dtype=float))
        x, y = np.broadcast_arrays(x, y)
        dx = ltp[1] - ltp[0]
        dy = ltd[1] - ltd[0]
        fx = (x - ltp[0]) / dx
        fy = (y - ltd[0]) / dy
        inside = (fx >= 0) & (fx <= ltp.size - 1) & (fy >= 0) & (fy <= ltd.size - 1)
        i = np.clip(np.floor(fx).astype(int), 0, ltp.size - 2)
        j = np.clip(np.floor(fy).astype(int), 0, ltd.size - 2)
        wx = np.clip(fx - i, 0.0, 1.0)
        wy = np.clip(fy - j, 0.0, 1.0)
        out = []
        for arr in (self.theta, self.amplitude):
            v = (
                arr[i, j] * (1 - wx) * (1 - wy)
                + arr[i + 1, j] * wx * (1 - wy)
                + arr[i, j + 1] * (1 - wx) * wy
                + arr[i + 1, j + 1] * wx * wy
            )
            out.append(np.where(inside, v.astype(float), np.nan))
        return out[0], out[1]


def build_manifolds(betas: Iterable[float], tp_n: np.ndarray | None = None, td_n: np.ndarray | None = None,
                    progress: Progress | None = None) -> list[Manifold]:
    """Build the UFM/UGM for several betas, sharing the beta-independent part.

    The delay-free periodic response y0 and its amplitude do not depend on beta; only the switching
    level beta * a_y does.  So the closed form, the instant of the minimum and the UGM are computed
    once, and each beta only costs the crossing search.

    Parameters
    ----------
    betas : iterable of float
        MRFT parameters in (-1, 1).
    tp_n, td_n : ndarray, optional
        Increasing log-spaced normalised grids Tp * Omega and Td * Omega; default :data:`DEFAULT_TP`,
        :data:`DEFAULT_TD`.
    progress : Progress, optional
        Called as ``progress(done, total, "UFM")`` after each beta (``done`` betas of ``total``).

    Raises
    ------
    InputError
        beta outside (-1, 1) or grids that are not positive, increasing and log-spaced.
    """
    betas = [check_beta(b) for b in betas]
    if not betas:
        raise InputError("give at least one beta")
    tp_n = DEFAULT_TP if tp_n is None else np.asarray(tp_n, dtype=float)
    td_n = DEFAULT_TD if td_n is None else np.asarray(td_n, dtype=float)
    for name, g in (("tp", tp_n), ("td", td_n)):
        if g.ndim != 1 or g.size < 2 or np.any(g <= 0) or np.any(np.diff(g) <= 0):
            raise InputError(f"{name} grid must be positive and strictly increasing")
        steps = np.diff(np.log(g))
        if np.ptp(steps) > 1e-9 * max(1.0, abs(steps.mean())):
            raise InputError(f"{name} grid must be log-spaced (interpolation is done in log coordinates)")
    t0 = time.perf_counter()
    sys_, s0, a = unit_extremum(tp_n[:, None], td_n[None, :])
    t_shared = time.perf_counter() - t0
    out = []
    report(progress, 0, len(betas), "UFM")
    for beta in betas:
        t1 = time.perf_counter()
        theta = unit_crossing(sys_, s0, a, beta)
        meta = {
            "format": "mrft-ident-ufm",
            "format_version": FORMAT_VERSION,
            "beta": beta,
            "model": MODEL,
            "unit_frequency_rad_s": 1.0,
            "gain_normalisation": "K*Td = 1, h = 1",
            "theta": "signed tau*Omega [rad]; < 0 where no physical plant (see docs/method.md)",
            "grid": {
                "tp": {"min": float(tp_n[0]), "max": float(tp_n[-1]), "n": int(tp_n.size), "spacing": "log"},
                "td": {"min": float(td_n[0]), "max": float(td_n[-1]), "n": int(td_n.size), "spacing": "log"},
                "axes": ["tp", "td"],
            },
            "build": {
                "method": "closed-form periodic solution (LPRS), safeguarded Newton, xtol 3e-10 rad",
                "dtype": "float32",
                "seconds": round(time.perf_counter() - t1 + t_shared / len(betas), 4),
            },
            "package_version": __version__,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        }
        out.append(Manifold(beta, tp_n.copy(), td_n.copy(), theta.astype(np.float32), a.astype(np.float32), meta))
        report(progress, len(out), len(betas), "UFM")
    return out


def build_manifold(beta: float, tp_n: np.ndarray | None = None, td_n: np.ndarray | None = None) -> Manifold:
    """Build the UFM/UGM for one beta (see :func:`build_manifolds`)."""
    return build_manifolds([beta], tp_n, td_n)[0]


def save_manifold(manifold: Manifold, directory: str | Path) -> Path:
    """Write ``ufm_beta±b.npz`` and its ``.json`` metadata into ``directory``; return the npz path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    stem = _file_stem(manifold.beta)
    meta_text = json.dumps(manifold.metadata, indent=2, sort_keys=True)
    path = directory / f"{stem}.npz"
    # each file through a temporary one renamed when whole: a killed build-ufm leaves no cut manifold
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        np.savez_compressed(
            handle,
            tp=manifold.tp_n,
            td=manifold.td_n,
            theta=np.asarray(manifold.theta, dtype=np.float32),
            amplitude=np.asarray(manifold.amplitude, dtype=np.float32),
            metadata=np.array(meta_text),
        )
    write_text_atomic(directory / f"{stem}.json", meta_text + "\n")
    return path


def load_manifold(path: str | Path | Traversable) -> Manifold:
    """Read one manifold file (``.npz``; a Traversable from importlib.resources is accepted).

    Raises
    ------
    InputError
        Not a manifold file, or a format version this package cannot read.
    """
    try:
        fh_ctx = open(path, "rb") if isinstance(path, (str, Path)) else path.open("rb")
        with fh_ctx as fh:
            with np.load(fh, allow_pickle=False) as data:
                meta = load_json_text(str(data["metadata"]), f"manifold file {path}: metadata")
                tp, td = np.array(data["tp"]), np.array(data["td"])
                theta, amp = np.array(data["theta"]), np.array(data["amplitude"])
    except (OSError, KeyError, ValueError) as err:
        raise InputError(f"cannot read manifold file {path}: {err}") from err
    if not isinstance(meta, dict) or meta.get("format") != "mrft-ident-ufm" or int(meta.get("format_version", -1)) != FORMAT_VERSION:
        raise InputError(f"{path} is not a mrft-ident manifold of format version {FORMAT_VERSION}")
    return Manifold(float(meta["beta"]), tp, td, theta, amp, meta)


class ManifoldSet:
    """Manifolds for several betas, with slices at any beta.

    Inside the range of stored betas a slice is the linear interpolation (in beta) of the two
    neighbouring manifolds; outside it, or with ``exact=True``, the slice is computed exactly from
    the closed form (any beta in (-1, 1)).  The identifier only uses slices to bracket the solution
    and then polishes with the exact LPRS, so interpolation never limits its accuracy.
    """

    def __init__(self, manifolds: Iterable[Manifold]) -> None:
        ms = sorted(manifolds, key=lambda m: m.beta)
        if not ms:
            raise InputError("no manifolds given")
        self.manifolds = tuple(ms)
        self.betas = np.array([m.beta for m in ms])

    def __len__(self) -> int:
        return len(self.manifolds)

    @property
    def td_n(self) -> np.ndarray:
        """The normalised Td * Omega grid shared by the manifolds."""
        return self.manifolds[0].td_n

    @property
    def tp_n(self) -> np.ndarray:
        """The normalised Tp * Omega grid shared by the manifolds."""
        return self.manifolds[0].tp_n

    def covers(self, beta: float) -> bool:
        return bool(self.betas[0] - 1e-9 <= beta <= self.betas[-1] + 1e-9)

    def evaluate(self, beta: float, tp_n: ArrayLike, td_n: ArrayLike,
                 exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(theta, a_unit) at normalised (tp_n, td_n) = (Tp, Td) * Omega for this beta (interpolated or exact)."""
        beta = check_beta(beta)
        if exact or not self.covers(beta):
            return unit_cycle(tp_n, td_n, beta)
        k = int(np.searchsorted(self.betas, beta))
        if k < len(self.betas) and abs(self.betas[k] - beta) < 1e-9:
            return self.manifolds[k].interpolate(tp_n, td_n)
        lo, hi = self.manifolds[k - 1], self.manifolds[k]
        w = (beta - lo.beta) / (hi.beta - lo.beta)
        th0, a0 = lo.interpolate(tp_n, td_n)
        th1, a1 = hi.interpolate(tp_n, td_n)
        return (1 - w) * th0 + w * th1, (1 - w) * a0 + w * a1


@functools.lru_cache(maxsize=8)
def _load_dir(directory: str | None) -> ManifoldSet:
    if directory is None:
        root = importlib.resources.files("mrftcli._manifolds")
        files: list[Traversable] | list[Path] = [
            p for p in root.iterdir() if p.name.startswith("ufm_beta") and p.name.endswith(".npz")]
    else:
        d = Path(directory)
        if not d.is_dir():
            raise InputError(f"manifold directory {directory} does not exist")
        files = sorted(d.glob("ufm_beta*.npz"))
    if not files:
        where = directory or "the installed package (run: mrft-ident build-ufm --shipped --out manifolds)"
        raise InputError(f"no manifold files found in {where}")
    return ManifoldSet(load_manifold(f) for f in files)


def load_manifolds(directory: str | Path | None = None) -> ManifoldSet:
    """Load every ``ufm_beta*.npz`` of ``directory`` (default: the shipped set), cached."""
    return _load_dir(None if directory is None else str(Path(directory).resolve()))
