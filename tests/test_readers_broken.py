"""Broken input: truncated, corrupt, empty, unknown, backwards time. Built here from good files.

Library-level checks use pytest.raises(match=...); the CLI contract (exit code 3, one line on stderr,
no traceback) runs ``mrft-ident topics`` in a subprocess, since the error mapping lives in cli.main.
"""

from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pytest

from mrftcli.mrft.model import soiptd_model
from mrftcli.errors import LogReadError
from mrftcli.io.logtypes import TopicData
from mrftcli.io import ReadOptions, log_filename, open_log, read_flight, write_log
from mrftcli.io.cdr import serialize_many
from mrftcli.io.msgtypes import typestore_for
from test_readers import synthetic_flight


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A flight long enough that the MCAP has several chunks (salvage needs whole chunks)."""
    base = tmp_path_factory.mktemp("good")
    topics, truth = synthetic_flight(n=3000)
    paths = {fmt: write_log(topics, log_filename(base / "g", fmt), fmt)
             for fmt in ("mcap", "mcap-json", "bag", "ulog", "csv", "ros2-sqlite3")}
    return paths, truth


def _cut(src, dst, fraction):
    data = src.read_bytes()
    dst.write_bytes(data[:int(len(data) * fraction)])
    return dst


def _flip(src, dst, fraction, n=16):
    data = bytearray(src.read_bytes())
    i = int(len(data) * fraction)
    data[i:i + n] = bytes(255 - b for b in data[i:i + n])
    dst.write_bytes(bytes(data))
    return dst


@pytest.mark.parametrize("fmt", ["mcap", "mcap-json"])
def test_truncated_mcap_is_salvaged_with_a_warning(good, tmp_path, fmt, capsys):
    paths, truth = good
    cut = _cut(paths[fmt], tmp_path / paths[fmt].name, 0.6)
    fl = read_flight(cut, ReadOptions(loop="roll"))
    assert len(fl.warnings) == 1 and "salvaged" in fl.warnings[0] and str(cut) in fl.warnings[0]
    assert "warning:" in capsys.readouterr().err
    n = len(fl.command)
    assert 0.3 * 3000 < n < 3000
    # what is salvaged is exact: a prefix of the true series
    np.testing.assert_allclose(fl.command.values, truth["cmd"][:n], atol=1e-12)
    np.testing.assert_allclose(fl.output.values, truth["roll"][:len(fl.output)], atol=1e-12)


@pytest.mark.parametrize("fraction", [0.99, 0.6])
def test_truncated_ros1_bag_is_reindexed_from_its_complete_chunks(good, tmp_path, fraction, capsys):
    # a ROS 1 bag is indexed at its end: cut at 99 % it has lost its index (rosbags refuses it);
    # its complete chunks are read back as `rosbag reindex` would, with the MCAP salvage warning
    paths, truth = good
    cut = _cut(paths["bag"], tmp_path / "cut.bag", fraction)
    fl = read_flight(cut, ReadOptions(loop="roll"))
    assert len(fl.warnings) == 1 and "salvaged" in fl.warnings[0] and str(cut) in fl.warnings[0]
    assert "rosbag reindex" in fl.warnings[0] and "warning:" in capsys.readouterr().err
    n = len(fl.command)
    assert (n == 3000) if fraction == 0.99 else (0.2 * 3000 < n < 3000)
    # what is salvaged is exact: a prefix of the true series, at the true times
    np.testing.assert_allclose(fl.command.values, truth["cmd"][:n], atol=1e-12)
    np.testing.assert_allclose(fl.output.values, truth["roll"][:len(fl.output)], atol=1e-12)
    with open_log(paths["bag"]) as whole:
        t_all, _ = whole.read("/mrft/command", ["data"])
    np.testing.assert_array_equal(fl.command.t, t_all[:n])


def test_mcap_cut_inside_a_chunk_keeps_its_complete_messages(good, tmp_path):
    """Cut inside the first chunk: the zstd blocks that arrived whole still give messages."""
    paths, truth = good
    from mcap.reader import make_reader

    with open(paths["mcap"], "rb") as f:
        first = min(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    data = paths["mcap"].read_bytes()
    cut = tmp_path / "in_chunk.mcap"
    cut.write_bytes(data[:first.chunk_start_offset + int(first.chunk_length * 0.9)])
    fl = read_flight(cut)
    assert "from the cut-off chunk" in fl.warnings[0]
    n = len(fl.command)
    assert 0 < n < 3000
    np.testing.assert_allclose(fl.command.values, truth["cmd"][:n], atol=1e-12)
    np.testing.assert_allclose(fl.output.values, truth["z"][:len(fl.output)], atol=1e-12)


def test_corrupt_mcap_chunk_is_skipped_not_misread(good, tmp_path):
    paths, truth = good
    from mcap.reader import make_reader

    with open(paths["mcap"], "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    last = max(chunks, key=lambda c: c.chunk_start_offset)
    data = bytearray(paths["mcap"].read_bytes())
    mid = last.chunk_start_offset + last.chunk_length // 2  # inside the compressed chunk data
    data[mid:mid + 8] = bytes(255 - b for b in data[mid:mid + 8])
    bad = tmp_path / "flip.mcap"
    bad.write_bytes(bytes(data))
    fl = read_flight(bad, ReadOptions(loop="altitude"))
    assert any("corrupt" in w for w in fl.warnings)
    t = fl.output.t
    keep = np.isin(np.round(truth["t_pose"], 6), np.round(t, 6))
    assert 0 < keep.sum() < 3000
    np.testing.assert_allclose(fl.output.values, truth["z"][keep], atol=1e-12)


def test_corrupt_message_index_falls_back_to_the_chunk(good, tmp_path):
    paths, truth = good
    from mcap.reader import make_reader

    with open(paths["mcap"], "rb") as f:
        summary = make_reader(f).get_summary()
    cid = next(c.id for c in summary.channels.values() if c.topic == "/mrft/command")
    chunk = summary.chunk_indexes[0]
    data = bytearray(paths["mcap"].read_bytes())
    pos = chunk.message_index_offsets[cid] + 15 + 16  # second (log_time, offset) pair
    data[pos:pos + 16] = bytes(255 - b for b in data[pos:pos + 16])
    bad = tmp_path / "index.mcap"
    bad.write_bytes(bytes(data))
    fl = read_flight(bad)
    assert any("message index" in w for w in fl.warnings)
    np.testing.assert_allclose(fl.command.values, truth["cmd"], atol=1e-12)


def test_backwards_time_is_an_error(tmp_path):
    from mcap.writer import Writer

    ts = typestore_for()
    t = np.array([1.0, 1.1, 1.2, 0.9, 1.3])
    datas = serialize_many(ts, "std_msgs/msg/Float64", t, {"data": np.arange(5.0)})
    path = tmp_path / "back.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        cid = w.register_channel("/mrft/command", "cdr", sid)
        for k, d in enumerate(datas):  # recorded in this order: the clock jumped back
            w.add_message(cid, log_time=int(t[k] * 1e9), publish_time=int(t[k] * 1e9), data=d)
        w.finish()
    with open_log(path) as log, pytest.raises(LogReadError, match=r"back\.mcap: /mrft/command: "
                                                                  r"timestamps go backwards"):
        log.series("/mrft/command")
    csv = tmp_path / "back.csv"
    csv.write_text("time,cmd\n0.0,1\n0.1,2\n0.05,3\n")
    with open_log(csv) as log, pytest.raises(LogReadError, match="timestamps go backwards"):
        log.series("cmd")
    dup = tmp_path / "dup.csv"
    dup.write_text("time,cmd\n0.0,1\n0.1,2\n0.1,3\n0.2,4\n")
    with open_log(dup) as log:
        s = log.series("cmd")
        # no message dropped: the shared stamp's batch is spread back at the rate (0.075 s here)
        assert list(s.values) == [1.0, 2.0, 3.0, 4.0] and "stamps batches on arrival" in log.warnings[0]
        np.testing.assert_allclose(s.t, [0.0, 0.025, 0.1, 0.2])


def test_truncated_csv_drops_the_partial_row(good, tmp_path):
    paths, truth = good
    data = paths["csv"].read_bytes()
    cut = tmp_path / "cut.csv"
    cut.write_bytes(data[:len(data) // 2 + 7])  # mid-row
    fl = read_flight(cut)
    assert any("partial row" in w for w in fl.warnings)
    n = len(fl.command)
    assert 0 < n < 3000
    np.testing.assert_allclose(fl.command.values, truth["cmd"][:n], rtol=1e-9)


def test_empty_logs(tmp_path):
    topics = [TopicData("/mrft/command", "std_msgs/msg/Float64", np.zeros(0), {"data": np.zeros(0)})]
    for fmt in ("mcap", "bag", "csv"):
        path = write_log(topics, log_filename(tmp_path / "e", fmt), fmt)
        with pytest.raises(LogReadError, match=r"(no messages|no rows|no topic)"):
            read_flight(path)
    header_only = tmp_path / "h.csv"
    header_only.write_text("time,a\n")
    with pytest.raises(LogReadError, match="no rows"):
        open_log(header_only)
    no_time = tmp_path / "n.csv"
    no_time.write_text("x,a\n1,2\n")
    with pytest.raises(LogReadError, match="no time column"):
        open_log(no_time)


def test_cut_ulog_is_read_with_a_warning(good, tmp_path):
    paths, truth = good
    cut = _cut(paths["ulog"], tmp_path / "cut.ulg", 0.6)
    fl = read_flight(cut, ReadOptions(loop="roll"))
    assert any("ends inside a message" in w for w in fl.warnings)
    n = len(fl.output)
    assert 0 < n < 3000
    np.testing.assert_allclose(fl.output.values, truth["roll"][:n], atol=1e-12)
    whole = read_flight(paths["ulog"])
    assert whole.warnings == ()


def test_ulog_damage_keeps_what_pyulog_reads(good, tmp_path, capsys):
    paths, truth = good
    bad = _flip(paths["ulog"], tmp_path / "flip.ulg", 0.5)
    fl = read_flight(bad, ReadOptions(loop="altitude"))
    captured = capsys.readouterr()
    assert captured.out == ""  # pyulog's own prints are captured and summarised
    assert any("corrupt" in w for w in fl.warnings)
    good_rows = np.isin(np.round(truth["t_pose"], 6), np.round(fl.output.t, 6))
    np.testing.assert_allclose(fl.output.values, truth["z"][good_rows], atol=1e-12)


def _cli(*args):
    return subprocess.run([sys.executable, "-c", "from mrftcli.cli.main import main; main()", *args],
                          capture_output=True, text=True, timeout=120)


def test_cli_broken_files_one_line_exit_3(good, tmp_path):
    paths, _ = good
    cases = {
        "empty.mcap": b"",
        "unknown.log": np.random.default_rng(0).bytes(2000),
    }
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
    broken = [tmp_path / n for n in cases]
    broken.append(_cut(paths["bag"], tmp_path / "cut.bag", 0.05))  # inside its first chunk: nothing to salvage
    broken.append(_cut(paths["mcap"], tmp_path / "cut.mcap", 0.01))
    broken.append(_flip(paths["csv"], tmp_path / "flip.csv", 0.5))
    broken.append(_cut(paths["ulog"], tmp_path / "cut.ulg", 0.0005))
    bag_dir = tmp_path / "cut_ros2"
    shutil.copytree(paths["ros2-sqlite3"], bag_dir)
    db = next(bag_dir.glob("*.db3*"))  # the (zstd-compressed) sqlite3 database
    db.write_bytes(db.read_bytes()[:5000])
    broken.append(bag_dir)
    broken.append(tmp_path / "does_not_exist.mcap")
    # one interpreter for all cases keeps the test cheap; each case still goes through cli.main
    script = (
        "import sys, io, contextlib\n"
        "from mrftcli.cli.main import main\n"
        "for path in sys.argv[1:]:\n"
        "    err = io.StringIO()\n"
        "    with contextlib.redirect_stderr(err):\n"
        "        try:\n"
        "            main(['topics', path])\n"
        "        except SystemExit as exc:\n"
        "            code = exc.code\n"
        "    print(repr((path, code, err.getvalue())))\n")
    run = subprocess.run([sys.executable, "-c", script, *map(str, broken)], capture_output=True,
                         text=True, timeout=300)
    results = [eval(line) for line in run.stdout.splitlines() if line.startswith("(")]  # noqa: S307
    assert len(results) == len(broken), run.stderr
    for path, code, err in results:
        lines = err.strip().splitlines()
        assert code == 3, (path, code, err)
        assert len(lines) == 1 and lines[0].startswith("error: ") and path in lines[0], (path, err)
        assert "Traceback" not in err


def test_cli_subprocess_no_traceback(tmp_path):
    """The real console entry point, once: exit code 3 and a single stderr line."""
    (tmp_path / "x.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)
    proc = _cli("topics", str(tmp_path / "x.mcap"))
    assert proc.returncode == 3
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("error: ")
    assert "Traceback" not in proc.stderr


def test_batch_stamped_csv_rebuilds_the_times_and_tau_keeps_the_truth(repo_root, tmp_path):
    """A logger that stamps on batch arrival (4 samples of a 200 Hz loop per 50 Hz stamp, 3 ms late).

    Dropping the repeated stamps gave tau 42.64 [41.14, 44.38] ms for a truth of 46.4 ms; the rebuilt
    times must give an interval that holds the truth (the sidecar's), with a warning that says what
    was done.
    """
    import json

    from mrftcli.analyze import analyze_path

    src = repo_root / "sample_logs" / "design1_altitude.csv"
    truth = json.loads((repo_root / "sample_logs" / "design1_altitude.csv.truth.json").read_text())
    lines = src.read_text().splitlines()
    t = np.array([float(line.split(",", 1)[0]) for line in lines[1:]])
    t0 = t[0]
    stamps = t0 + np.ceil((t - t0) / 0.02 - 1e-6) * 0.02 + 0.003
    out = [lines[0]] + [f"{s:.9f}," + line.split(",", 1)[1] for s, line in zip(stamps, lines[1:])]
    batched = tmp_path / "batched.csv"
    batched.write_text("\n".join(out) + "\n")
    res = analyze_path(batched, soiptd_model(truth["Tp"]))
    tau = truth["tau"]
    assert res.tau.ci95_low <= tau <= res.tau.ci95_high, (res.tau.value, res.tau.ci95_low, res.tau.ci95_high)
    assert abs(res.tau.value - tau) < 1.5e-3
    assert any("stamps batches on arrival" in w and "rebuilt" in w for w in res.flight.warnings)


def test_nan_and_inf_in_the_relay_column_are_said_and_left_out(repo_root, tmp_path):
    lines = (repo_root / "sample_logs" / "design1_altitude.csv").read_text().splitlines()
    out = [lines[0]]
    for i, line in enumerate(lines[1:]):
        parts = line.split(",")
        if i in (3000, 3004, 3008, 3012):
            parts[1] = ("nan", "inf", "-inf", "NaN")[(i - 3000) // 4]
        out.append(",".join(parts))
    path = tmp_path / "nan.csv"
    path.write_text("\n".join(out) + "\n")
    fl = read_flight(path, echo_warnings=False)
    assert len(fl.command) == len(lines) - 1 - 4 and np.isfinite(fl.command.values).all()
    text = " ".join(fl.warnings)
    assert "2 blank or NaN cell(s)" in text and "2 value(s) are NaN or infinite" in text
    all_bad = tmp_path / "allnan.csv"
    all_bad.write_text("time,cmd,y\n" + "".join(f"{k * 0.01},inf,{k}\n" for k in range(50)))
    with pytest.raises(LogReadError, match="every value is NaN or infinite"):
        read_flight(all_bad, ReadOptions(command_topic="cmd", output_topic="y"), echo_warnings=False)


@pytest.mark.parametrize("name", ["design1_altitude.mcap", "design1_altitude.ulg"])
def test_topics_format_csv_on_a_binary_log_never_echoes_its_bytes(repo_root, name):
    proc = subprocess.run([sys.executable, "-m", "mrftcli.cli", "topics", str(repo_root / "sample_logs" / name),
                           "--format", "csv"], capture_output=True, text=True, errors="replace", timeout=120)
    assert proc.returncode == 3
    line = proc.stderr.strip()
    assert line.count("\n") == 0 and "a binary file, not a CSV" in line
    assert all(ch.isprintable() for ch in line) and "\ufffd" not in line
