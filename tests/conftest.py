"""Shared pytest fixtures."""

from __future__ import annotations

import os
from pathlib import Path

# One BLAS thread per test process, as the CLI runs (mrftcli/cli/__init__.py): with -n 2 on 2 cores, two
# workers each spinning a BLAS pool over small matrices only contend. Set before numpy loads (matplotlib).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import matplotlib  # noqa: E402 - after the thread settings above
import pytest  # noqa: E402

matplotlib.use("Agg")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The team's ``../shared/`` folder (real third-party logs and recordings, never copied into the repo)."""
    if not SHARED.is_dir():
        pytest.skip(f"needs the team's shared data in {SHARED} (data/third_party_logs/: a PX4 ULog from pyulog's "
                    "tests and an ArduPilot DataFlash log from pymavlink's tests; data/real_relay/: real relay "
                    "recordings). Check out the shared folder beside this checkout to run it")
    return SHARED


#: Environment variable that runs the slow accuracy sweeps at their full size (benchmarks, release).
FULL_SWEEPS_ENV = "MRFT_FULL_SWEEPS"


def pytest_addoption(parser):
    parser.addoption("--full-sweeps", action="store_true", default=False,
                     help=f"run the slow accuracy sweeps at full size (also {FULL_SWEEPS_ENV}=1); "
                          "the default is the CI size, a few draws of each")


@pytest.fixture(scope="session")
def sweep_size(request):
    """``sweep_size(full, ci)``: how many draws a slow sweep takes: ``ci`` by default, ``full`` on request.

    The slow tier (``-m slow``) always runs; the CI size keeps the suite under 5 minutes on 2 cores,
    and ``--full-sweeps`` (or MRFT_FULL_SWEEPS=1) restores the acceptance size.
    """
    full = request.config.getoption("--full-sweeps") or os.environ.get(FULL_SWEEPS_ENV, "") not in ("", "0")

    def size(full_n: int, ci_n: int) -> int:
        return full_n if full else ci_n

    return size


@pytest.fixture
def mplcleanup():
    """Close every figure a test opened (python-control's pattern)."""
    import matplotlib.pyplot as plt

    yield
    plt.close("all")


def pytest_report_header(config):
    return f"CI={os.environ.get('CI', '')}"
