"""MCAP reading in bounded memory (issue 24.1) and decompression bombs (issue 29.2).

The files are assembled here byte by byte (as rosbags' MCAP tests do), sharing no code with the
reader: a few messages of a Float64 command beside a "camera" channel of large messages, in zstd
chunks, with or without a summary; bombs are zstd frames built from RLE blocks (a 4 GiB frame is
128 KiB), so nothing here ever holds the sizes it claims. The oracle for the values is what was
written.
"""

from __future__ import annotations

import resource
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
import zstandard

from mrftcli.errors import LogReadError
from mrftcli.io import ReadOptions, open_log
from mrftcli.io.mcap_stream import MAX_CHUNK_BYTES, ChunkHeader, OversizeChunkError, decompress_chunk

MAGIC = b"\x89MCAP0\r\n"
GIB = 1 << 30
FLOAT64 = b"float64 data\n"
CAMERA_BYTES = 20_000


# -- writing MCAP by hand ---------------------------------------------------------------------------
def record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def string(s: str) -> bytes:
    return struct.pack("<I", len(s)) + s.encode()


def message(channel: int, seq: int, t_ns: int, data: bytes) -> bytes:
    return record(0x05, struct.pack("<HIQQ", channel, seq, t_ns, t_ns) + data)


def schema_and_channels() -> bytes:
    return (record(0x03, struct.pack("<H", 1) + string("std_msgs/msg/Float64") + string("ros2msg")
                   + struct.pack("<I", len(FLOAT64)) + FLOAT64)
            + record(0x04, struct.pack("<HH", 1, 1) + string("/mrft/command") + string("cdr") + struct.pack("<I", 0))
            + record(0x04, struct.pack("<HH", 2, 0) + string("/camera/image/compressed") + string("cdr")
                     + struct.pack("<I", 0)))


def chunk(records: bytes, *, declared: int | None = None, payload: bytes | None = None,
          crc: int | None = None) -> bytes:
    """A zstd Chunk record of ``records`` (or of a given compressed ``payload`` declaring ``declared``)."""
    payload = zstandard.ZstdCompressor().compress(records) if payload is None else payload
    size = len(records) if declared is None else declared
    crc = zlib.crc32(records) if crc is None else crc
    return record(0x06, struct.pack("<QQQI", 0, 10**12, size, crc) + string("zstd")
                  + struct.pack("<Q", len(payload)) + payload)


def rle_zstd_frame(total: int) -> bytes:
    """A valid zstd frame of ``total`` zero bytes, written as RLE blocks of 128 KiB (4 bytes each)."""
    block = 1 << 17
    out = [struct.pack("<IBBQ", 0xFD2FB528, 0xC0, (17 - 10) << 3, total)]  # 8-byte content size, 128 KiB window
    left = total
    while left > 0:
        n = min(block, left)
        left -= n
        out.append(int((n << 3) | (1 << 1) | (left == 0)).to_bytes(3, "little") + b"\0")
    return b"".join(out)


def flight(n: int = 400, rate: float = 200.0, camera_every: int = 7) -> tuple[list[bytes], np.ndarray, np.ndarray]:
    """Chunk-sized groups of records: the command (known values and times) interleaved with camera frames."""
    rng = np.random.default_rng(7)
    t_ns = (1_700_000_000 * 10**9 + np.arange(n) * (10**9 / rate)).astype(np.int64)
    values = 0.5 + 0.05 * np.sign(np.sin(np.arange(n) / 9.0))
    groups, current = [], b""
    for i in range(n):
        current += message(1, i, int(t_ns[i]), b"\0\x01\0\0" + struct.pack("<d", values[i]))
        if i % camera_every == 0:
            current += message(2, i, int(t_ns[i]) + 1, rng.bytes(CAMERA_BYTES))
        if len(current) > 100_000:
            groups.append(current)
            current = b""
    groups.append(current)
    return groups, t_ns, values


def write_file(path: Path, chunks: list[bytes], *, summary: bool, extra: bytes = b"",
               extra_index: tuple[int, int] | None = None) -> int:
    """Header, schema and channels, the chunks (``extra`` after them); with ``summary`` a summary
    whose Chunk Index records list every chunk without Message Index records (so a reader has to
    open each). Returns the data section's end (where the summary starts)."""
    head = MAGIC + record(0x01, string("ros2") + string("hand")) + schema_and_channels()
    body, indexes, pos = b"", [], len(head)
    for c in chunks + ([extra] if extra else []):
        indexes.append(record(0x08, struct.pack("<QQQQ", 0, 10**12, pos, len(c)) + struct.pack("<I", 0)
                              + struct.pack("<Q", 0) + string("zstd") + struct.pack("<QQ", len(c), 0)))
        body += c
        pos += len(c)
    data_end = record(0x0F, struct.pack("<I", 0))
    summary_start = pos + len(data_end)
    tail = schema_and_channels() + b"".join(indexes) if summary else b""
    footer = record(0x02, struct.pack("<QQI", summary_start if summary else 0, 0, 0)) + MAGIC
    path.write_bytes(head + body + data_end + tail + footer)
    return summary_start


# -- fixtures -------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def light(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray, np.ndarray]:
    groups, t_ns, values = flight()
    path = tmp_path_factory.mktemp("mcap") / "light.mcap"
    write_file(path, [chunk(g) for g in groups], summary=True)
    return path, t_ns, values


def _read(path: Path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    with open_log(path, echo_warnings=False) as log:
        t, _, vals = log.values("/mrft/command", "data")
        return t, vals["data"], list(log.warnings)


# -- light files: the values written, and only the wanted channel's bytes held ----------------------
def test_indexed_read_gives_what_was_written_and_holds_no_camera_bytes(light):
    path, t_ns, values = light
    t, v, warnings = _read(path)
    np.testing.assert_array_equal(t, t_ns / 1e9)
    np.testing.assert_array_equal(v, values)
    assert warnings == []
    with open_log(path) as log:
        log.prefetch(["/mrft/command"])
        buffers = [raw[1] for raw in log._raw_cache.values()]  # noqa: SLF001 - what the reader holds
    assert sum(b.nbytes for b in buffers) == len(values) * 12  # 4-byte CDR header + float64 each


def test_salvage_without_summary_reads_the_same(light, tmp_path):
    path, t_ns, values = light
    data = path.read_bytes()
    cut = tmp_path / "nosummary.mcap"
    cut.write_bytes(data[:data.rindex(record(0x0F, struct.pack("<I", 0)))])  # summary and footer gone
    t, v, warnings = _read(cut)
    np.testing.assert_array_equal(t, t_ns / 1e9)
    np.testing.assert_array_equal(v, values)
    assert len(warnings) == 1 and "salvaged 458 messages" in warnings[0]  # 400 commands, 58 frames
    with open_log(cut, echo_warnings=False) as log:
        info = {i.name: i for i in log.topics()}
        log.prefetch(["/mrft/command"])
        # what the reader holds: the command's bytes, none of the camera's
        held = [d for ch in log._records.channels.values() for d in ch.datas]  # noqa: SLF001
        buffers = [raw[1] for raw in log._raw_cache.values()]  # noqa: SLF001
    assert held == [] and sum(b.nbytes for b in buffers) == 400 * 12
    assert info["/mrft/command"].count == 400 and info["/camera/image/compressed"].count == 58


# -- bombs ----------------------------------------------------------------------------------------
def test_rle_frame_is_the_zeros_it_claims():
    frame = rle_zstd_frame(3 * (1 << 17) + 5)
    assert zstandard.frame_content_size(frame) == 3 * (1 << 17) + 5
    assert zstandard.ZstdDecompressor().decompress(frame) == bytes(3 * (1 << 17) + 5)


def test_declared_size_over_the_limit_is_refused_before_decompressing():
    header = ChunkHeader(0, 0, 4 * GIB, 0, "zstd", 0, 0)
    with pytest.raises(OversizeChunkError, match=r"chunk X declares 4096 MiB uncompressed, over the 256 MiB"):
        decompress_chunk(header, rle_zstd_frame(4 * GIB), "chunk X")


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_a_chunk_inflating_past_its_declaration_is_refused(compression):
    import lz4.frame

    inflated = 64 << 20
    packed = (rle_zstd_frame(inflated) if compression == "zstd"
              else lz4.frame.compress(bytes(inflated)))
    header = ChunkHeader(0, 0, 1 << 20, 0, compression, 0, len(packed))
    with pytest.raises(OversizeChunkError, match="decompresses to more than the 1 MiB it declares"):
        decompress_chunk(header, packed, "chunk Y")


def test_a_frame_without_content_size_is_capped_by_the_declaration():
    packed = zstandard.ZstdCompressor(write_content_size=False).compress(bytes(8 << 20))
    header = ChunkHeader(0, 0, 1 << 20, 0, "zstd", 0, len(packed))
    with pytest.raises(OversizeChunkError):
        decompress_chunk(header, packed, "chunk Z")
    assert len(decompress_chunk(ChunkHeader(0, 0, 8 << 20, 0, "zstd", 0, len(packed)), packed, "ok")) == 8 << 20


def _cli(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """The CLI in a subprocess limited to 1.5 GB of address space (a 4 GiB allocation fails)."""
    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (3 * GIB // 2, 3 * GIB // 2))

    return subprocess.run([sys.executable, "-m", "mrftcli", *args], capture_output=True, text=True,
                          timeout=timeout, preexec_fn=cap, check=False)


@pytest.fixture(scope="module")
def bombs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    groups, _, _ = flight()
    good = [chunk(g) for g in groups]
    frame = rle_zstd_frame(4 * GIB)
    bomb = chunk(b"", declared=4 * GIB, payload=frame, crc=0)  # crc 0: "not written", nothing checks it
    liar = chunk(b"", declared=4096, payload=frame, crc=0)  # declares 4 KiB, frame says 4 GiB
    d = tmp_path_factory.mktemp("bombs")
    out = {}
    for name, extra, summary in (("indexed", bomb, True), ("salvage", bomb, False),
                                 ("liar_indexed", liar, True), ("liar_salvage", liar, False)):
        out[name] = d / f"{name}.mcap"
        end = write_file(out[name], good[:3], summary=summary, extra=extra)
        if not summary:  # summary and footer cut off
            out[name].write_bytes(out[name].read_bytes()[:end - 13])
    # the bomb chunk cut mid-way by the end of the file
    data = out["salvage"].read_bytes()
    out["cut"] = d / "cut.mcap"
    out["cut"].write_bytes(data[:data.index(frame) + len(frame) // 2])
    # a recording whose tail is zero-filled (a crash with preallocated blocks)
    out["zeros"] = d / "zeros.mcap"
    out["zeros"].write_bytes(data[:data.index(frame) - (9 + 28 + 8 + 8)] + bytes(8 << 20))  # from the bomb on
    return out


@pytest.mark.parametrize("name", ["indexed", "liar_indexed"])
def test_bomb_with_its_index_is_refused_in_one_line(bombs, name):
    for command in ("topics", "analyze"):
        run = _cli(command, str(bombs[name]), *(["--tp", "0.02"] if command == "analyze" else []))
        assert run.returncode == 3, run.stderr
        assert "Traceback" not in run.stderr and len(run.stderr.strip().splitlines()) == 1
        assert "chunk at byte" in run.stderr and "refused" in run.stderr


@pytest.mark.parametrize("name", ["salvage", "liar_salvage", "cut", "zeros"])
def test_salvage_skips_the_bomb_and_keeps_the_rest(bombs, name):
    run = _cli("topics", str(bombs[name]))
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr
    assert "salvaged" in run.stderr
    # the three good chunks before the bomb: their command messages, counted independently
    groups, _, _ = flight()
    expected = sum(g.count(b"\x05" + struct.pack("<Q", 22 + 12)) for g in groups[:3])
    line = next(row for row in run.stdout.splitlines() if row.split()[:1] == ["/mrft/command"])
    assert str(expected) in line.split()


def test_in_process_salvage_names_what_was_skipped(bombs):
    with open_log(bombs["salvage"], echo_warnings=False) as log:
        (warning,) = log.warnings
    assert f"declares 4096 MiB uncompressed, over the {MAX_CHUNK_BYTES >> 20} MiB" in warning
    with pytest.raises(LogReadError, match="refused"):
        _read(bombs["indexed"])


# -- ROS 2 bags split over several mcap files ------------------------------------------------------
def test_split_ros2_bag_reads_as_the_whole(tmp_path):
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    from mrftcli.io import read_flight

    whole = Path(__file__).resolve().parents[1] / "sample_logs" / "design1_altitude_ros2_mcap"
    bag = tmp_path / "split_bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text((whole / "metadata.yaml").read_text())
    with open(next(whole.glob("*.mcap")), "rb") as f:
        msgs = list(make_reader(f).iter_messages())
    cut = len(msgs) // 3
    # the second file's name sorts first: the reader must order by time, not by name
    for name, part in (("b_0.mcap", msgs[:cut]), ("a_1.mcap", msgs[cut:])):
        with open(bag / name, "wb") as stream:
            writer = Writer(stream, compression=CompressionType.ZSTD, chunk_size=1 << 16)
            writer.start(profile="ros2", library="test")
            ids: dict[str, int] = {}
            for s, c, m in part:
                if c.topic not in ids:
                    ids[c.topic] = writer.register_channel(c.topic, c.message_encoding,
                                                           writer.register_schema(s.name, s.encoding, s.data))
                writer.add_message(ids[c.topic], m.log_time, m.data, m.publish_time)
            writer.finish()
    a, b = read_flight(whole, ReadOptions(loop="altitude")), read_flight(bag, ReadOptions(loop="altitude"))
    for name in ("command", "output", "setpoint"):
        np.testing.assert_array_equal(getattr(a, name).t, getattr(b, name).t)
        np.testing.assert_array_equal(getattr(a, name).values, getattr(b, name).values)
    with open_log(bag) as log:
        assert type(log).__name__ == "McapBagSource"
        counts = {i.name: i.count for i in log.topics()}
    with open_log(whole) as log:
        assert counts == {i.name: i.count for i in log.topics()}
