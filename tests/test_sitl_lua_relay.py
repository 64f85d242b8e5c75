"""The Lua MRFT relay flown in ArduPilot SITL (scripts/sitl/mrft_relay.lua) follows the switching rule.

Its ``relay_step`` is cut out of the script and run by a Lua 5.3 interpreter on random error
sequences; the signs it gives must be those of the independent transcription in ``relay_rule.py``
(started the same way: the first error's sign, held until the error passes the start threshold on
the other side). Skipped where no ``lua5.3`` / ``lua`` is installed (``apt-get install lua5.3``).
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from relay_rule import relay_signs

SCRIPT = Path(__file__).parents[1] / "scripts" / "sitl" / "mrft_relay.lua"
LUA = shutil.which("lua5.3") or shutil.which("lua")
pytestmark = pytest.mark.skipif(LUA is None, reason="no Lua interpreter (apt-get install lua5.3)")


def _lua_signs(errors: np.ndarray, beta: float, eth: float) -> list[float]:
    text = SCRIPT.read_text()
    body = re.search(r"local function relay_step\(t, e\)\n.*?\nend\n", text, re.S)
    assert body is not None, "relay_step not found in mrft_relay.lua"
    values = ", ".join(repr(float(e)) for e in errors)
    driver = (body.group(0) + f"local t = {{beta = {beta!r}, eth = {eth!r}, relay = 1, e_ext = 0, "
              "first_half = true, started = false}\n"
              f"for _, e in ipairs({{{values}}}) do print(relay_step(t, e)) end\n")
    out = subprocess.run([LUA, "-"], input=driver, capture_output=True, text=True, check=True).stdout
    return [float(x) for x in out.split()]



@pytest.mark.parametrize("beta,eth,seed", [(-0.2, 0.0, 1), (-0.5, 0.05, 2), (-0.8, 0.0, 3), (0.3, 0.02, 4)])
def test_lua_relay_matches_rule(beta: float, eth: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    t = np.arange(600) * 0.005
    errors = np.sin(2 * np.pi * 1.3 * t) * (1 + 0.3 * np.sin(0.7 * t)) + 0.1 * rng.standard_normal(t.size)
    lua, oracle = _lua_signs(errors, beta, eth), relay_signs(errors, beta, eth)
    assert lua == oracle
    assert sum(a != b for a, b in zip(oracle, oracle[1:])) >= 6  # the sequence does switch
