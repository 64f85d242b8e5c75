"""Every file the tool writes appears whole or not at all (tracker issue 29, item 3).

Each writer is made to fail (or is killed) half-way through its output; the target must then be
absent (or still the previous file) and no half-written file may carry the target's name.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from mrftcli.io.atomic import atomic_path, write_text_atomic


class Boom(RuntimeError):
    """The failure injected half-way through a write."""


def _half_then_fail(target_arg: int | str = 0):
    """A stand-in writer: writes some bytes to the file it was given, then raises."""
    def write(*args, **kwargs):
        dest = kwargs[target_arg] if isinstance(target_arg, str) else args[target_arg]
        if hasattr(dest, "write"):
            dest.write(b"partial")
        else:
            Path(dest).write_bytes(b"partial")
        raise Boom("killed mid-write")
    return write


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "result.json"
    target.write_text("old, whole\n")
    with pytest.raises(Boom):
        with atomic_path(target) as tmp:
            tmp.write_text("new but cut")
            raise Boom("killed mid-write")
    assert target.read_text() == "old, whole\n"
    assert _names(tmp_path) == ["result.json"]


def test_killed_process_leaves_no_file_under_the_target_name(tmp_path: Path) -> None:
    """SIGKILL between the first and the last byte: the target does not exist; what is left is a hidden
    ``.NAME.*.tmp`` that no reader takes for the output."""
    target = tmp_path / "report.html"
    code = textwrap.dedent(f"""
        import sys, time
        from mrftcli.io.atomic import atomic_path
        with atomic_path({str(target)!r}) as tmp, open(tmp, "w") as handle:
            handle.write("<html>" + "x" * 100000)
            handle.flush()
            print("half", flush=True)
            time.sleep(60)
            handle.write("</html>")
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "half"
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert not target.exists()
    left = _names(tmp_path)
    assert len(left) == 1 and left[0].startswith(".report.html.") and left[0].endswith(".tmp")


def test_report_figure_and_page(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from matplotlib.figure import Figure

    from mrftcli.report._common import new_figure, save_figure, write_page

    fig, ax = new_figure()
    ax.plot([0, 1], [0, 1])
    monkeypatch.setattr(Figure, "savefig", _half_then_fail(1))  # (self, fname, ...)
    with pytest.raises(Boom):
        save_figure(fig, tmp_path / "fit.png")
    monkeypatch.undo()
    assert _names(tmp_path) == []
    fig, ax = new_figure()
    ax.plot([0, 1], [0, 1])
    png = save_figure(fig, tmp_path / "fit.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # the format from the target's suffix
    write_page(tmp_path / "index.html", "<html>whole</html>")
    assert _names(tmp_path) == ["fit.png", "index.html"]


def test_ufm_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mrftcli.mrft import ufm

    [manifold] = ufm.build_manifolds([-0.5], np.geomspace(1e-3, 1e2, 8), np.geomspace(1e-2, 1e3, 8))
    monkeypatch.setattr(ufm.np, "savez_compressed", _half_then_fail(0))
    with pytest.raises(Boom):
        ufm.save_manifold(manifold, tmp_path)
    monkeypatch.undo()
    assert _names(tmp_path) == []
    path = ufm.save_manifold(manifold, tmp_path)
    assert np.allclose(ufm.load_manifold(path).theta, manifold.theta)
    assert _names(tmp_path) == ["ufm_beta-0.500.json", "ufm_beta-0.500.npz"]


def test_written_logs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import pandas as pd

    from mrftcli.io import write_log
    from mrftcli.io.logtypes import TopicData

    topics = [TopicData("/mrft/command", "std_msgs/msg/Float64", np.arange(5) * 0.01, {"data": np.ones(5)})]
    monkeypatch.setattr(pd.DataFrame, "to_csv", lambda self, dest, **kw: _half_then_fail(0)(dest))
    with pytest.raises(Boom):
        write_log(topics, tmp_path / "flight.csv")
    monkeypatch.undo()
    assert _names(tmp_path) == []
    write_log(topics, tmp_path / "flight.csv")
    write_log(topics, tmp_path / "flight.mcap")
    assert _names(tmp_path) == ["flight.csv", "flight.mcap"]


def test_compare_output(tmp_path: Path) -> None:
    from mrftcli.cli.compare import _write

    (tmp_path / "cmp.md").write_text("old")
    _write(str(tmp_path / "cmp.md"), "| new |\n")
    assert (tmp_path / "cmp.md").read_text() == "| new |\n" and _names(tmp_path) == ["cmp.md"]


def test_write_text_atomic_keeps_umask_permissions(tmp_path: Path) -> None:
    path = write_text_atomic(tmp_path / "a.txt", "x")
    mask = os.umask(0)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask


def _bag_size(bag: Path) -> int:
    from mrftcli.io import open_log

    with open_log(bag) as src:
        return int(src.read("/mrft/command", ["data"])[0].size)


def test_ros2_bag_folder_replaced_whole_or_not_at_all(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A ROS 2 bag is a folder: a write that fails half-way leaves the old bag readable under its name and
    no hidden staging folder; a write that ends replaces it whole."""
    import mrftcli.sim.sidecar as sidecar
    from mrftcli.io.logtypes import TopicData

    def topics(n: int) -> list[TopicData]:
        return [TopicData("/mrft/command", "std_msgs/msg/Float64", np.arange(n) * 0.01, {"data": np.ones(n)})]

    bag = tmp_path / "flight"
    sidecar.write_log_atomic(topics(5), bag, "ros2-mcap")

    import mrftcli.io

    real_write = mrftcli.io.write_log

    def cut(topic_list, folder, fmt):  # the real writer, then a failure before it returns
        real_write(topic_list, folder, fmt)
        raise Boom("killed mid-write")

    monkeypatch.setattr("mrftcli.io.write_log", cut)
    with pytest.raises(Boom):
        sidecar.write_log_atomic(topics(9), bag, "ros2-mcap")
    monkeypatch.undo()
    assert _names(tmp_path) == ["flight"]
    assert _bag_size(bag) == 5
    sidecar.write_log_atomic(topics(9), bag, "ros2-mcap")
    assert _names(tmp_path) == ["flight"]
    assert _bag_size(bag) == 9
