"""ArduPilot SITL DataFlash logs (sample_logs/sitl/, flown by scripts/sitl/, issue 41), analysed without SITL.

The logs are ArduCopter's own DataFlash files: the MRFT relay ran in the firmware (Lua), the physics
is SITL's quad model. Each has a sidecar ``*.BIN.json`` saying how it was flown (loop, Tp's filter,
beta and h of each test, the delay added inside the firmware). What is asserted is what the data
show (docs/benchmarks/sitl.md): every flown test is found with its beta, the layout is recognised
from the log, each test's frequency is predicted from the other tests' model within 5 %, and the
added delay comes back as the tau increment between the two flights of a loop.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
LOGS = ROOT / "sample_logs" / "sitl"
sys.path.insert(0, str(ROOT / "scripts" / "sitl"))

from sitl_analysis import analyze_log, held_out  # noqa: E402

SIDECARS = sorted(LOGS.glob("*.BIN.json"))
pytestmark = pytest.mark.skipif(not SIDECARS, reason="no SITL sample logs")
_CACHE: dict[str, object] = {}


def _flight(name: str):
    if name not in _CACHE:
        side = json.loads((LOGS / f"{name}.BIN.json").read_text())
        _CACHE[name] = (side, analyze_log(LOGS / f"{name}.BIN", side["tp_s"], side["loop"]))
    return _CACHE[name]


def _names() -> list[str]:
    return [p.name[: -len(".BIN.json")] for p in SIDECARS]


@pytest.mark.parametrize("name", _names())
def test_every_flown_test_is_found_with_its_beta(name: str) -> None:
    from mrftcli.io import read_flight
    from mrftcli.io.flight import ReadOptions

    side, res = _flight(name)
    flight = read_flight(LOGS / f"{name}.BIN", ReadOptions(loop=side["loop"]))
    assert flight.source["layout"].startswith("ardupilot-mrft (auto-detected")
    flown = [(t["beta"], t["h"]) for t in side["tests"]]
    found = [(t.beta_nominal, t.h) for t in res.tests]
    assert len(found) == len(flown)
    for (b0, h0), (b1, h1) in zip(flown, found):
        assert b1 == pytest.approx(b0, abs=1e-6)
        assert h1 == pytest.approx(h0, rel=0.02)  # h read from the command's levels
