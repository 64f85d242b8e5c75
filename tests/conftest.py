"""Shared pytest fixtures."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

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


_T = TypeVar("_T")
@contextlib.contextmanager
def _exclusive(lock: Path):
    """One xdist worker at a time: a lock file created exclusively (another worker waits for the result instead
    of computing it again; a lock older than 10 min is a dead worker's)."""
    while True:
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            break
        except FileExistsError:
            try:
                if time.time() - lock.stat().st_mtime > 600:
                    lock.unlink(missing_ok=True)
            except FileNotFoundError:
                pass
            time.sleep(0.1)
    try:
        yield
    finally:
        os.close(fd)
        lock.unlink(missing_ok=True)


class SharedResults:
    """Expensive results computed once per test session and shared by every test file and xdist worker.

    A result is stored as its record's JSON (``to_json``) in one file per key, written by an atomic rename
    under a lock (:func:`_exclusive`: two workers do not compute it twice); every caller, the one that
    computed it included, gets a fresh ``from_json`` object, so no test can mutate another's. Use it only where a
    test asserts on the result's content; a test of the CLI path keeps its own CLI call.
    """

    def __init__(self, root: Path) -> None:
        self.root = root
        root.mkdir(parents=True, exist_ok=True)

    @staticmethod
    def log_key(path: str | Path) -> tuple[str, int, int]:
        """A committed log's identity in a cache key: its resolved path, size [bytes] and mtime [ns]."""
        p = Path(path).resolve()
        st = p.stat()
        return str(p), st.st_size, st.st_mtime_ns

    def get(self, kind: str, key: tuple[Any, ...], compute: Callable[[], Any], to_json: Callable[[Any], Any],
            from_json: Callable[[Any], _T]) -> _T:
        """``from_json`` of ``to_json(compute())``, computed once per (kind, key) in the session.

        ``key`` holds everything the result depends on besides the code (which a session does not change: the
        cache's folder is the session's own, :func:`shared_results`): the logs' :meth:`log_key` and the exact
        options (their ``repr``).
        """
        from mrftcli.jsonable import to_jsonable

        digest = hashlib.sha256(repr((kind, key)).encode()).hexdigest()[:24]
        path = self.root / f"{kind}-{digest}.json"
        if path.exists():  # the common case: no lock needed (the file appears whole, by a rename)
            return from_json(json.loads(path.read_text()))
        with _exclusive(Path(str(path) + ".lock")):
            return from_json(self._load_or_compute(path, compute, to_json, to_jsonable))

    def analysis(self, log: str | Path, model: Any, read: Any = None, options: Any = None) -> Any:
        """``analyze_path(log, model, read=read, options=options)`` (an AnalysisResult) through :meth:`get`: one
        analysis of a committed log per (log, model, read options, analyze options) in the session."""
        from mrftcli.analyze import AnalysisResult, analyze_path

        key = (self.log_key(log), repr(model), repr(read), repr(options))
        return self.get("analyze_path", key, lambda: analyze_path(log, model, read=read, options=options),
                        AnalysisResult.to_json, AnalysisResult.from_json)

    @staticmethod
    def _load_or_compute(path: Path, compute, to_json, to_jsonable) -> Any:
        if path.exists():
            return json.loads(path.read_text())
        data = json.loads(json.dumps(to_jsonable(to_json(compute()))))
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            json.dump(data, f)
        os.replace(tmp, path)
        return data


@pytest.fixture(scope="session")
def shared_results(tmp_path_factory) -> SharedResults:
    """The session's :class:`SharedResults`: under xdist in the folder all workers share (the base temp's parent),
    else in this session's own base temp."""
    base = tmp_path_factory.getbasetemp()
    return SharedResults((base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "shared_results")


def pytest_report_header(config):
    return f"CI={os.environ.get('CI', '')}"
