"""The declared structures of the SITL held-out routes (scripts/sitl/held_out_routes.py, issue 41) and the one
docs/sitl.md gives users.

Oracles: eq. (2)'s frequency response written out here, K e^{-tau jw} / (jw (Td jw + 1)(Tp jw + 1)); a lead-lag
with a = b is 1; the lead zero's phase is atan(a w).
"""

from __future__ import annotations

import cmath
import math
import re
import sys
import tomllib
from pathlib import Path

import pytest

from mrftcli.mrft.model_file import declared_model, load_model_file

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts" / "sitl"))

from held_out_routes import MODEL_FILES  # noqa: E402

TP = 0.03307
P = {"K": 27.0, "Td": 4.1, "tau": 0.0213, "Tp": TP}


def _eq2(w: float) -> complex:
    s = 1j * w
    return P["K"] * cmath.exp(-P["tau"] * s) / (s * (P["Td"] * s + 1) * (P["Tp"] * s + 1))


def _spec(route: str) -> dict:
    return tomllib.loads(MODEL_FILES[route].replace("@TP@", repr(TP)))


@pytest.mark.parametrize("route", sorted(MODEL_FILES))
def test_every_route_file_loads(route: str, tmp_path: Path) -> None:
    path = tmp_path / f"{route}.toml"
    path.write_text(MODEL_FILES[route].replace("@TP@", repr(TP)))
    model = load_model_file(path)
    assert {n for n, _, _ in model.ranges} >= {"K", "tau"}
    assert all(lo > 0 or n == "tau" for n, lo, _ in model.ranges)  # a range from 0 is log-scaled (issue noted)


@pytest.mark.parametrize("w", [2.0, 7.5, 19.0])
def test_declared_eq2_is_eq2_and_the_lead_lag_reduces_to_it(w: float) -> None:
    eq2 = declared_model(_spec("eq2_declared")["transfer_function"], P)
    assert complex(eq2.frequency_response(w)) == pytest.approx(_eq2(w), rel=1e-9)
    same = declared_model(_spec("lead_lag")["transfer_function"], {**P, "a": 0.05, "b": 0.05})
    assert complex(same.frequency_response(w)) == pytest.approx(_eq2(w), rel=1e-9)
    lead = declared_model(_spec("lead")["transfer_function"], {**P, "a": 0.01})
    ratio = complex(lead.frequency_response(w)) / _eq2(w)
    assert cmath.phase(ratio) == pytest.approx(math.atan(0.01 * w), rel=1e-9)


def test_the_docs_model_file_is_the_benchmarks_lead_lag() -> None:
    text = (ROOT / "docs" / "sitl.md").read_text()
    block = re.search(r"```toml\n(# eq2_lead_lag\.toml.*?)```", text, re.S)
    assert block is not None
    docs, bench = tomllib.loads(block.group(1)), _spec("lead_lag")
    assert docs["transfer_function"] == bench["transfer_function"]
    assert {k: v for k, v in docs["parameters"].items() if k != "Tp"} == \
        {k: v for k, v in bench["parameters"].items() if k != "Tp"}
