"""ArduPilot SITL DataFlash logs (sample_logs/sitl/*.BIN, flown by scripts/sitl/, issue 41), read without SITL.

The logs are ArduCopter's own DataFlash files: the MRFT relay ran in the firmware (Lua), the physics
is SITL's quad model. Each has a sidecar ``*.BIN.json`` saying how it was flown (loop, Tp's filter,
beta and h of each test, the delay added inside the firmware). What is asserted is what the data
show (docs/benchmarks/sitl.md): the layout is recognised, every flown test is located with its beta
and h, and the delay added inside the firmware is in the log (the switches of what was sent follow the
relay's decisions by the added delay plus at most about two script ticks). Identification is *not* asserted: in SITL the
Lua thread samples at irregular simulated instants (5.8 ms apart, gaps to 12 ms), the segmenter
drops most cycles as having command samples missing at a switch, and ``analyze`` refuses these logs
(docs/sitl.md, "Where it stops"); the last test pins that refusal and its reason.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).parents[1]
LOGS = ROOT / "sample_logs" / "sitl"
SIDECARS = sorted(LOGS.glob("*.BIN.json"))
pytestmark = pytest.mark.skipif(not SIDECARS, reason="no SITL sample logs")


def _names() -> list[str]:
    return [p.name[: -len(".BIN.json")] for p in SIDECARS]


def _side(name: str) -> dict:
    return json.loads((LOGS / f"{name}.BIN.json").read_text())


def _read(name: str):
    from mrftcli.io import ReadOptions, read_flight

    return read_flight(LOGS / f"{name}.BIN", ReadOptions(loop=_side(name)["loop"]))


@pytest.mark.parametrize("name", _names())
def test_every_flown_test_is_located_with_its_beta_and_h(name: str) -> None:
    from mrftcli.segment import segment

    flight = _read(name)
    assert flight.source["layout"].startswith("ardupilot-mrft (auto-detected")
    flown = [(t["beta"], t["h"]) for t in _side(name)["tests"]]
    found = [(t.beta_nominal, t.h) for t in segment(flight)]
    assert len(found) == len(flown)
    for (b0, h0), (b1, h1) in zip(flown, found):
        assert b1 == pytest.approx(b0, abs=1e-6)
        assert h1 == pytest.approx(h0, rel=0.02)  # h read from the command's levels


@pytest.mark.parametrize("name", _names())
def test_the_added_delay_is_in_the_log(name: str) -> None:
    from mrftcli.io import open_log

    with open_log(LOGS / f"{name}.BIN", echo_warnings=False) as src:
        t, m = src.read("MRFT", ["Cmd", "Snt"])
    t_cmd = t[1:][np.diff(m["Cmd"]) != 0]
    t_snt = t[1:][np.diff(m["Snt"]) != 0]
    lags = np.array([t_snt[t_snt >= x][0] - x for x in t_cmd[:-1] if (t_snt >= x).any()])
    delay = _side(name)["added_delay_ms"] * 1e-3
    assert lags.size >= 30
    # each switch leaves at the first tick at least the delay later; the stamps are the logger's, taken
    # when the script writes (a tick may straddle a simulation step: about 1 ms), and a test's first and
    # last samples carry no delay
    assert np.mean(lags >= delay - 0.001) >= 0.9
    assert delay <= np.median(lags) < delay + 0.0125  # at most about two script ticks late


def test_analyze_refuses_the_sitl_altitude_log_for_too_few_stable_cycles() -> None:
    from mrftcli.analyze import AnalyzeOptions, analyze_flight
    from mrftcli.errors import InsufficientDataError

    name = "altitude"
    with pytest.raises(InsufficientDataError, match=r"only one beta was tested.*stable cycles \(need 3\)"):
        analyze_flight(_read(name), _side(name)["tp_s"], options=AnalyzeOptions(n_bootstrap=20))
