"""Held-out predictions: each test's cycle predicted by the model identified from the other tests.

One record (:class:`HeldOut`, ``tests[i].held_out`` in every analysis JSON) and its wording
(:func:`held_out_cells`, :func:`held_out_notes`, :meth:`HeldOut.describe`) for every model: the
families' (``analyze --model``, :func:`mrftcli.analyze.general.held_out`) and eq. (2)'s
(:func:`held_out_eq2`).

eq. (2) (``analyze`` without ``--model``): the other tests' mean frequencies, effective betas and
mean amplitudes are identified by the paper's UFM/UGM point solve (:func:`mrftcli.mrft.identify.identify`,
no bootstrap), and the test's cycle is that model's exact limit cycle (LPRS closed form) under the
test's own beta and relay height. The prediction's standard deviation is the other tests' standard
errors of their means propagated linearly (two more point solves per beta among them); ``*_sigma`` is
that and the test's own standard error in quadrature, the scale of ``measured - predicted``, and
``*_z`` the error in those standard deviations.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import IdentificationError, InputError
from ..mrft.identify import TestMeasurement, identify
from ..mrft.lprs import mrft_limit_cycle
from ..mrft.model import LoopModel
from ..segment.records import MrftTest
from .screen import group_betas

__all__ = ["HeldOut", "held_out_eq2", "held_out_cells", "held_out_notes", "NOTHING_HELD_OUT"]

_ONE_OTHER = ("the other test alone does not determine Td and tau (eq. (2) needs two betas): a third test would "
              "check each test against the others")
_ONE_BETA = "the other tests share one beta and do not determine Td and tau (eq. (2) needs two betas)"
#: the note of a flight with one usable test
NOTHING_HELD_OUT = "the only test: nothing is held out (no other test to predict it from)"


def _opt(x: Any) -> float | None:
    return None if x is None else float(x)


@dataclass(frozen=True)
class HeldOut:
    """A test's cycle predicted by the model identified from the other tests.

    Attributes
    ----------
    frequency_hz, amplitude : float or None
        Predicted frequency [Hz] and amplitude [output units]; None when the other tests do not
        determine the model (``note`` says why).
    note : str
        Why there is no prediction (or what qualifies it), or ``""``.
    frequency_sigma_hz, amplitude_sigma : float or None
        Standard deviation of ``measured - predicted`` [Hz], [output units]: the prediction's own
        (the other tests' standard errors propagated) and the measured mean's in quadrature; None
        where the route does not state one (the families' ``analyze --model`` today).
    frequency_z, amplitude_z : float or None
        ``(measured - predicted) / sigma`` [-]; None without a sigma.
    """

    frequency_hz: float | None
    amplitude: float | None
    note: str = ""
    frequency_sigma_hz: float | None = None
    amplitude_sigma: float | None = None
    frequency_z: float | None = None
    amplitude_z: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {"frequency_hz": self.frequency_hz, "amplitude": self.amplitude, "note": self.note,
                "frequency_sigma_hz": self.frequency_sigma_hz, "amplitude_sigma": self.amplitude_sigma,
                "frequency_z": self.frequency_z, "amplitude_z": self.amplitude_z}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> HeldOut:
        """The record of a ``held_out`` object (the sigma and z keys may be absent: older records)."""
        return cls(_opt(data.get("frequency_hz")), _opt(data.get("amplitude")), str(data.get("note", "")),
                   *(_opt(data.get(k)) for k in ("frequency_sigma_hz", "amplitude_sigma", "frequency_z",
                                                 "amplitude_z")))

    @classmethod
    def against(cls, frequency_hz: float, amplitude: float, measured: tuple[float, float, float, float],
                spread: tuple[float, float], note: str = "") -> HeldOut:
        """A prediction with its sigma and z against the measured means.

        ``measured``: frequency [Hz], its standard error [Hz], amplitude, its standard error [output
        units]; ``spread``: the prediction's standard deviation in frequency [Hz] and amplitude.
        """
        f_m, f_se, a_m, a_se = measured
        sf, sa = math.hypot(f_se, spread[0]), math.hypot(a_se, spread[1])
        return cls(frequency_hz, amplitude, note, sf, sa, (f_m - frequency_hz) / sf if sf > 0 else None,
                   (a_m - amplitude) / sa if sa > 0 else None)

    def describe(self, frequency_hz: float, amplitude: float, unit: str) -> str:
        """One line beside the measured values, e.g. ``f 0.7732 ± 0.0022 Hz (measured 0.8417, +30.6 std),
        amplitude 0.1038 ± 0.00054 m (measured 0.08687, -31.6 std)``; the note where there is no prediction."""
        if self.frequency_hz is None or self.amplitude is None:
            return self.note or "none"

        def part(value: str, sigma: float | None, z: float | None, measured: str) -> tuple[str, str]:
            spread = "" if sigma is None else f" ± {_num(sigma, 2)}"
            return f"{value}{spread}", f"(measured {measured}" + ("" if z is None else f", {z:+.1f} std") + ")"

        f, f_m = part(f"{self.frequency_hz:.4f}", self.frequency_sigma_hz, self.frequency_z, f"{frequency_hz:.4f}")
        a, a_m = part(f"{self.amplitude:.4g}", self.amplitude_sigma, self.amplitude_z, f"{amplitude:.4g}")
        return f"f {f} Hz {f_m}, amplitude {a} {unit} {a_m}" + (f"; {self.note}" if self.note else "")


def _num(x: float | None, digits: int = 4) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x:#.{digits}g}".rstrip(".")


def held_out_cells(ho: HeldOut | None) -> tuple[str, str]:
    """The table's held-out frequency and amplitude cells: the prediction, ``± sigma`` and the error in
    std where there is one (``0.7731 ± 0.0042 (+0.2)``), ``-`` where there is no prediction."""
    if ho is None:
        return "-", "-"

    def cell(value: float | None, sigma: float | None, z: float | None, digits: int) -> str:
        if value is None:
            return "-"
        text = _num(value, digits)
        if sigma is not None:
            text += f" ± {_num(sigma, 2)}"
        return text + (f" ({z:+.1f})" if z is not None else "")

    return (cell(ho.frequency_hz, ho.frequency_sigma_hz, ho.frequency_z, 4),
            cell(ho.amplitude, ho.amplitude_sigma, ho.amplitude_z, 3))


def held_out_notes(held: Sequence[HeldOut | None]) -> list[str]:
    """One line per distinct note, naming the tests (1-based, in ``held``'s order) it applies to."""
    by_note: dict[str, list[str]] = {}
    for k, ho in enumerate(held):
        if ho is not None and ho.note:
            by_note.setdefault(ho.note, []).append(str(k + 1))
    return [f"held-out test{'s' if len(ix) > 1 else ''} {', '.join(ix)}: {note}" for note, ix in by_note.items()]


# ----------------------------------------------------------------------------------------------
# eq. (2)
# ----------------------------------------------------------------------------------------------
def _measurement(test: MrftTest, beta: float) -> TestMeasurement:
    return TestMeasurement(beta=beta, frequency_hz=test.frequency_hz_mean, amplitude=test.amplitude_mean, h=test.h)


def _sem(x: Any) -> float:
    return float(x.std(ddof=1) / math.sqrt(x.size)) if x.size > 1 else 0.0


def _predict(Tp: float, others: Sequence[TestMeasurement], beta: float, h: float) -> tuple[float, float]:
    """The eq. (2) model of ``others`` (point solve) and its exact cycle under ``beta``, ``h``: (f [Hz], a)."""
    ident = identify(others, Tp, rate_hz=None)
    if ident.K is None:
        raise IdentificationError("no amplitude in the other tests")
    model = LoopModel(Tp, ident.Td.mean, max(ident.tau.mean, 0.0), ident.K.mean)
    lc = mrft_limit_cycle(model, beta, h)
    return float(lc.frequency_hz), float(lc.amplitude)


def _spread(Tp: float, others: list[TestMeasurement], tests: list[MrftTest], beta: float, h: float,
            centre: tuple[float, float]) -> tuple[float, float]:
    """The prediction's std [Hz], [output units]: the other tests' standard errors propagated linearly.

    The tests at one beta play one role in the fit (their derivatives are alike), so each beta group's
    frequencies (then amplitudes) move together, each by its standard error, in one point solve: with
    equal derivatives d, the shift is d * sum(se) and the group's variance d^2 * sum(se^2). Two solves
    per beta group, not per test, keep a 20-test log's cost small.
    """
    var_f = var_a = 0.0
    for group in group_betas(tests):
        for which in ("frequency", "amplitude"):
            se = np.array([_sem(tests[j].frequency_hz if which == "frequency" else tests[j].amplitude)
                           for j in group])
            if not np.any(se > 0):
                continue
            moved = list(others)
            for j, e in zip(group, se):
                m = others[j]
                f, a = m.frequency_mean + (e if which == "frequency" else 0.0), m.amplitude_mean or 0.0
                moved[j] = TestMeasurement(m.beta, f, a + (e if which == "amplitude" else 0.0), m.h)
            try:
                f, a = _predict(Tp, moved, beta, h)
            except (IdentificationError, InputError):
                continue  # the point solve fails one std away: that group's share is left out
            scale = float(np.sum(se ** 2) / np.sum(se) ** 2)
            var_f += (f - centre[0]) ** 2 * scale
            var_a += (a - centre[1]) ** 2 * scale
    return math.sqrt(var_f), math.sqrt(var_a)


def held_out_eq2(Tp: float, tests: Sequence[MrftTest], betas: Sequence[float]) -> tuple[HeldOut, ...]:
    """Each test's cycle predicted by eq. (2) identified from the other tests (module docstring).

    Parameters
    ----------
    Tp : float
        Known propulsion time constant [s].
    tests : sequence of MrftTest
        The usable tests.
    betas : sequence of float
        The beta each test is identified with (:func:`mrftcli.analyze.estimate.beta_used`).

    Returns
    -------
    tuple of HeldOut
        One per test, in ``tests``' order.
    """
    tests = list(tests)
    if len(tests) < 2:
        return tuple(HeldOut(None, None, NOTHING_HELD_OUT) for _ in tests)
    meas = [_measurement(t, b) for t, b in zip(tests, betas)]
    out = []
    for i, (test, beta) in enumerate(zip(tests, betas)):
        others = meas[:i] + meas[i + 1:]
        if len(group_betas(tests[:i] + tests[i + 1:])) < 2:
            out.append(HeldOut(None, None, _ONE_BETA if len(others) > 1 else _ONE_OTHER))
            continue
        try:
            centre = _predict(Tp, others, beta, test.h)
        except (IdentificationError, InputError) as err:
            out.append(HeldOut(None, None, f"the other tests give no eq. (2) model: {err}"))
            continue
        spread = _spread(Tp, others, [*tests[:i], *tests[i + 1:]], beta, test.h, centre)
        measured = (test.frequency_hz_mean, _sem(test.frequency_hz), test.amplitude_mean, _sem(test.amplitude))
        out.append(HeldOut.against(*centre, measured, spread))
    return tuple(out)
