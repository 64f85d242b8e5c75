"""A large CSV: read block by block in bounded memory, with its progress told (tracker issue 29).

The reader's block path (files over ``LARGE_CSV_BYTES``) is forced on small files here by lowering the
threshold and the block size; the oracle is the same file read whole (pyarrow, every column at once).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mrftcli.errors import LogReadError
from mrftcli.io import format_csv, list_topics, read_flight
from mrftcli.io.flight import ReadOptions

SAMPLE = Path(__file__).resolve().parents[1] / "sample_logs" / "design1_altitude.csv"


@pytest.fixture
def blocks(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(format_csv, "LARGE_CSV_BYTES", 1000)  # every file is "large"
    monkeypatch.setattr(format_csv, "_BLOCK_ROWS", 997)  # several blocks, a partial last one


def test_blocks_give_the_whole_read_and_progress_reaches_the_file_size(blocks: None, monkeypatch) -> None:
    seen: list[tuple[float, float, str]] = []
    lazy = read_flight(SAMPLE, ReadOptions(), echo_warnings=False, progress=lambda d, t, s="": seen.append((d, t, s)))
    monkeypatch.undo()
    whole = read_flight(SAMPLE, ReadOptions(), echo_warnings=False)
    for role in ("command", "output", "beta", "setpoint"):
        a, b = getattr(whole, role), getattr(lazy, role)
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_array_equal(a.values, b.values)
    size = SAMPLE.stat().st_size
    assert len(seen) > 4 and {t for _, t, _ in seen} == {size}
    passes = [s for _, _, s in seen]
    assert passes[0] == "reading 1 column(s)" and passes[-1].startswith("reading ")  # the time column, then the rest
    done = [d for d, _, _ in seen]
    assert done[-1] == size and all(0 < d <= size for d in done)


def test_topics_of_a_large_csv_in_one_pass(blocks: None, monkeypatch) -> None:
    seen: list[str] = []
    fmt, lazy = list_topics(SAMPLE, progress=lambda d, t, s="": seen.append(s))
    monkeypatch.undo()
    _, whole = list_topics(SAMPLE)
    assert [(i.name, i.count) for i in lazy] == [(i.name, i.count) for i in whole]
    for a, b in zip(lazy, whole):
        assert (a.rate_hz is None and b.rate_hz is None) or a.rate_hz == pytest.approx(b.rate_hz, rel=1e-9)
    assert "listing the columns" in seen


def test_a_non_number_in_a_large_csv_is_one_line(blocks: None, tmp_path: Path) -> None:
    lines = SAMPLE.read_text().splitlines()
    head = lines[0].split(",")
    row = lines[2500].split(",")
    col = next(k for k, name in enumerate(head) if name == "/mrft/command/data")
    row[col] = "oops"
    lines[2500] = ",".join(row)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(LogReadError, match=r"column\(s\) .*not numbers .*oops") as err:
        read_flight(bad, ReadOptions(), echo_warnings=False)
    assert "\n" not in str(err.value)
