"""The model object (mrftcli.mrft.model): parameters, realisation, normalisation, JSON, and a structure
that is not eq. (2) going through the same callers."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import numpy as np
import pytest

from mrftcli.errors import InputError
from mrftcli.mrft.lprs import mrft_limit_cycle
from mrftcli.mrft.model import (
    MODEL_FAMILIES,
    LoopModel,
    Parameter,
    PlantModel,
    StateSpace,
    UnitNormalisation,
    model_family,
    model_from_json,
)
from mrftcli.mrft.waveform import predict_output

PAPER = LoopModel(Tp=0.1, Td=1 / 1.42, tau=0.06, K=1.42)  # checks.md section 1


def test_loop_model_is_a_plant_model_with_named_parameters():
    assert isinstance(PAPER, PlantModel)
    p = PAPER.parameters
    assert list(p) == ["Tp", "Td", "tau", "K"]
    assert p["Tp"] == Parameter("Tp", "s", 0.1, True, (0.0, math.inf), "propulsion time constant")
    assert [q.known for q in p.values()] == [True, False, False, False]  # the paper's set E: Tp
    assert PAPER.delay == 0.06
    assert MODEL_FAMILIES["soiptd"] is LoopModel and model_family("soiptd") is LoopModel
    assert all(isinstance(name, str) and hasattr(cls, "realisation") for name, cls in MODEL_FAMILIES.items())


def test_ranges_are_the_bounds_of_the_unknown_parameters():
    m = LoopModel(0.05, 1.0, 0.03, 2.0, known=frozenset({"Tp", "K"}), ranges=(("Td", 0.2, 5.0),))
    p = m.parameters
    assert p["Td"].bounds == (0.2, 5.0) and p["Td"].contains(1.0) and not p["Td"].contains(6.0)
    assert p["K"].known and p["tau"].bounds == (0.0, math.inf)
    # known and ranges do not change what the model is
    assert m == LoopModel(0.05, 1.0, 0.03, 2.0) and repr(m) == repr(LoopModel(0.05, 1.0, 0.03, 2.0))
    with pytest.raises(InputError, match=r"unknown parameter\(s\) \['Tq'\] of soiptd"):
        LoopModel(0.05, 1.0, 0.03, known=frozenset({"Tq"}))


def test_with_parameters_validates_and_keeps_the_constraints():
    m = LoopModel(0.05, 1.0, 0.03, 2.0, ranges=(("tau", 0.0, 0.2),))
    m2 = m.with_parameters(tau=0.05, K=3.0)
    assert (m2.Tp, m2.Td, m2.tau, m2.K) == (0.05, 1.0, 0.05, 3.0)
    assert m2.ranges == m.ranges and m2.known == m.known
    with pytest.raises(InputError, match=r"unknown parameter\(s\) \['T'\]"):
        m.with_parameters(T=1.0)
    with pytest.raises(InputError, match="tau must be a non-negative time"):
        m.with_parameters(tau=-1.0)


def test_realisation_and_frequency_response_agree():
    """C (j w I - A)^-1 B e^{-j w tau}, from the realisation, against the closed form of eq. (2)."""
    ss = PAPER.realisation()
    assert isinstance(ss, StateSpace) and ss.order == 3 and ss.D == 0.0
    for w in (0.3, 4.4337, 60.0):
        g = ss.C @ np.linalg.solve(1j * w * np.eye(3) - ss.A, ss.B) * np.exp(-1j * w * PAPER.delay)
        assert g == pytest.approx(complex(PAPER.frequency_response(w)), rel=1e-12)


def test_unit_normalisation_maps_the_paper_example_onto_its_unit_cycle():
    """Lemmas 1-4 on the paper's example (checks.md: 0.70564 Hz, amplitude 0.078530 at beta -0.4)."""
    lc = mrft_limit_cycle(PAPER, -0.4)
    n = PAPER.unit_normalisation(lc.omega)
    assert isinstance(n, UnitNormalisation)
    assert lc.frequency_hz == pytest.approx(0.70564, abs=5e-6)
    assert n.coordinates == {"tp_n": pytest.approx(0.1 * lc.omega), "td_n": pytest.approx(lc.omega / 1.42)}
    assert n.theta == pytest.approx(0.06 * lc.omega)
    from mrftcli.mrft.lprs import unit_cycle

    theta, a_unit = unit_cycle(n.coordinates["tp_n"], n.coordinates["td_n"], -0.4)
    assert float(theta) == pytest.approx(n.theta, abs=1e-9)
    assert n.amplitude_scale * float(a_unit) == pytest.approx(0.078530, abs=5e-7)


@dataclass(frozen=True)
class _Lagged:
    """A structure that is not a LoopModel: eq. (2) written as a first-order lag in series with
    K Td / (s (Td s + 1)), its own state order [propulsion, rate, y], no unit normalisation."""

    family: ClassVar[str] = "test-lagged"
    structure: ClassVar[str] = "K Td e^{-tau s} / ((Tp s + 1) s (Td s + 1))"
    Tp: float
    Td: float
    tau: float
    K: float

    @property
    def parameters(self) -> dict[str, Parameter]:
        return {n: Parameter(n, "", float(getattr(self, n)), n == "Tp") for n in ("Tp", "Td", "tau", "K")}

    @property
    def delay(self) -> float:
        return self.tau

    def frequency_response(self, omega: Any) -> Any:
        s = 1j * np.asarray(omega, float)
        return self.K * self.Td * np.exp(-self.tau * s) / ((self.Tp * s + 1) * s * (self.Td * s + 1))

    def realisation(self) -> StateSpace:
        A = np.array([[-1 / self.Tp, 0.0, 0.0], [self.K, -1 / self.Td, 0.0], [0.0, 1.0, 0.0]])
        return StateSpace(A, np.array([1 / self.Tp, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))

    def unit_normalisation(self, omega: float) -> None:
        return None

    def with_parameters(self, **values: float) -> _Lagged:
        return _Lagged(**{**{n: getattr(self, n) for n in ("Tp", "Td", "tau", "K")}, **values})

    def to_json(self) -> dict[str, Any]:
        return {"schema_version": 1, "family": self.family}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> _Lagged:
        raise NotImplementedError


def test_another_structure_goes_through_the_same_callers():
    """The limit cycle (state-space LPRS) and the predicted output of a structure the callers do not
    know match eq. (2)'s closed forms for the same transfer function."""
    other = _Lagged(PAPER.Tp, PAPER.Td, PAPER.tau, PAPER.K)
    assert isinstance(other, PlantModel)
    exact, general = mrft_limit_cycle(PAPER, -0.4), mrft_limit_cycle(other, -0.4)
    assert general.method == "lprs-state-space"
    assert general.frequency_hz == pytest.approx(exact.frequency_hz, rel=1e-8)
    assert general.amplitude == pytest.approx(exact.amplitude, rel=1e-6)
    sampled = mrft_limit_cycle(other, -0.4, rate_hz=200.0)
    assert sampled.orbits_hz == pytest.approx(mrft_limit_cycle(PAPER, -0.4, rate_hz=200.0).orbits_hz)
    t = np.arange(0.0, 3.0, 0.005)
    u = np.sign(np.sin(2 * np.pi * 0.7 * t))
    ty = np.arange(0.01, 2.9, 0.0031)
    y = 0.05 * np.sin(2 * np.pi * 0.7 * ty - 2.0)
    a, b = predict_output(PAPER, t, u, ty, output=y), predict_output(other, t, u, ty, output=y)
    assert np.allclose(a.y, b.y, rtol=1e-7, atol=1e-9)


def test_json_round_trip():
    m = LoopModel(0.05, 1.0, 0.03, -2.0, known=frozenset({"Tp", "tau"}), ranges=(("Td", 0.2, 5.0),))
    d = json.loads(json.dumps(m.to_json()))  # plain JSON: no infinities
    back = model_from_json(d)
    assert back == m and back.known == m.known and back.ranges == m.ranges
    assert LoopModel.from_json(PAPER.to_json()).parameters == PAPER.parameters


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.update(schema_version=2), r"schema_version 2 is not supported \(this version reads 1\)"),
        (lambda d: d.pop("schema_version"), "no schema_version"),
        (lambda d: d.update(family="pidtd"), "unknown model family 'pidtd'; known: .*soiptd"),
        (lambda d: d.pop("parameters"), "needs a 'parameters' object"),
        (lambda d: d["parameters"].pop("Td"), "parameter 'Td' needs a numeric 'value'"),
        (lambda d: d["parameters"]["tau"].update(value="x"), "parameter 'tau' needs a numeric 'value'"),
        (lambda d: d["parameters"]["Td"].update(bounds=[1.0]), r"bounds of 'Td' must be \[low, high\]"),
        (lambda d: d["parameters"]["Td"].update(value=-1.0), "Td must be a positive time"),
    ],
)
def test_json_errors_are_one_line_input_errors(change, message):
    d = json.loads(json.dumps(PAPER.to_json()))
    change(d)
    with pytest.raises(InputError, match=message) as err:
        model_from_json(d)
    assert "\n" not in str(err.value)


def test_json_must_be_an_object():
    with pytest.raises(InputError, match="model JSON: expected a JSON object, got list"):
        model_from_json([1, 2])  # type: ignore[arg-type]  # the bad input under test
    with pytest.raises(InputError, match="family None is not 'soiptd'"):
        LoopModel.from_json({"schema_version": 1})
