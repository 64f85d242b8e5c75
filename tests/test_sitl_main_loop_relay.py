"""The main-loop MRFT relay patched into ArduCopter (scripts/sitl/ardupilot_patch) follows the rule.

``MRFT_relay.h`` (the rule and the delay line the firmware task uses, free of ArduPilot headers) is
compiled alone with a small driver and run on random error sequences: the signs must be those of the
independent transcription in ``relay_rule.py``, and the delay line must give back each value exactly
the asked number of ticks later. Skipped where no C++ compiler is installed.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from relay_rule import relay_signs

PATCH = Path(__file__).parents[1] / "scripts" / "sitl" / "ardupilot_patch"
CXX = shutil.which("g++") or shutil.which("c++") or shutil.which("clang++")
pytestmark = pytest.mark.skipif(CXX is None, reason="no C++ compiler (apt-get install g++)")

DRIVER = r"""
#include <cstdio>
#include "MRFT_relay.h"
int main(int argc, char **argv) {
    float beta, eth; int ticks; int n;
    if (std::scanf("%f %f %d %d", &beta, &eth, &ticks, &n) != 4) return 1;
    mrft::Relay relay; relay.reset(beta, eth);
    mrft::DelayLine<128> line; line.reset(ticks, 0.5f);
    for (int i = 0; i < n; i++) {
        float e; if (std::scanf("%f", &e) != 1) return 1;
        int s = relay.step(e);
        std::printf("%d %.6f\n", s, line.push(float(i)));
    }
    return 0;
}
"""


@pytest.fixture(scope="module")
def driver(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("mrft_relay")
    (folder / "driver.cpp").write_text(DRIVER)
    exe = folder / "driver"
    subprocess.run([CXX, "-std=c++11", "-O1", f"-I{PATCH}", str(folder / "driver.cpp"), "-o", str(exe)],
                   check=True, capture_output=True)
    return exe


def _run(exe: Path, errors: np.ndarray, beta: float, eth: float, ticks: int) -> tuple[list[float], list[float]]:
    text = f"{beta} {eth} {ticks} {errors.size}\n" + "\n".join(f"{e:.9g}" for e in errors) + "\n"
    out = subprocess.run([str(exe)], input=text, capture_output=True, text=True, check=True).stdout.split()
    return [float(x) for x in out[0::2]], [float(x) for x in out[1::2]]



@pytest.mark.parametrize("beta,eth,ticks,seed", [(-0.2, 0.0, 0, 1), (-0.5, 0.05, 8, 2), (-0.8, 0.0, 127, 3),
                                                 (0.3, 0.02, 3, 4)])
def test_main_loop_relay_matches_rule(driver: Path, beta: float, eth: float, ticks: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    t = np.arange(600) * 0.0025
    # float32 values, so that the C++ float rule and the oracle see the same numbers
    errors = (np.sin(2 * np.pi * 1.3 * t) * (1 + 0.3 * np.sin(0.7 * t)) +
              0.1 * rng.standard_normal(t.size)).astype(np.float32).astype(float)
    signs, delayed = _run(driver, errors, beta, eth, ticks)
    oracle = relay_signs(errors, beta, eth)
    assert signs == oracle
    assert sum(a != b for a, b in zip(oracle, oracle[1:])) >= 6  # the sequence does switch
    # the delay line: value i comes back at call i + ticks; before that, the idle value
    expected = [0.5] * ticks + [float(i) for i in range(t.size - ticks)]
    assert delayed == pytest.approx(expected)
