"""Shared pytest fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib
import pytest

matplotlib.use("Agg")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.skip("../shared/ is not beside this checkout")
    return SHARED


@pytest.fixture
def mplcleanup():
    """Close every figure a test opened (python-control's pattern)."""
    import matplotlib.pyplot as plt

    yield
    plt.close("all")


def pytest_report_header(config):
    return f"CI={os.environ.get('CI', '')}"
