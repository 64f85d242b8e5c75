"""Build a corpus of broken and hostile flight logs (tracker issue 29), deterministically.

Every file is built from a shipped sample log (``sample_logs/``) or from scratch, into ``OUT``, with
``OUT/manifest.json`` saying for each case what a correct tool does with it:

* ``refuse``: a one-line error with exit code 2-7 (never 1, an internal error);
* ``right``: exit 0 with numbers that match the truth (Td, tau, K within the tolerances of
  ``benchmarks/bench_hostile.py``), or a refusal;
* ``either``: a refusal, or exit 0 with the truth's numbers (a salvaged or damaged file may still
  hold enough of the flight).

``benchmarks/bench_hostile.py`` runs ``analyze``, ``topics`` and ``diagnose`` on every case under a
memory cap; ``tests/test_hostile.py`` runs the fast cases.

Usage::

    python scripts/make_hostile_corpus.py OUT [--big-rows N] [--only REGEX]
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import struct
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_logs"

__all__ = ["Case", "build_corpus", "CASES"]


@dataclass(frozen=True)
class Case:
    """One hostile file: its name in the corpus, how to build it, what a correct tool does with it."""

    name: str
    build: Callable[[Path], None] = field(repr=False, compare=False)
    expect: str  # refuse | right | either
    truth: str | None = None  # the sample log whose .truth.json holds the right numbers
    args: tuple[str, ...] = ()  # extra options for analyze/diagnose (e.g. --time-unit ms)
    fast: bool = True  # small and quick: run by tests/test_hostile.py
    loop: str = "altitude"
    why: str = ""


# -- byte surgery ---------------------------------------------------------------------------------
def _copy(src: Path) -> Callable[[Path], None]:
    def build(dst: Path) -> None:
        if src.is_dir():
            shutil.copytree(src, dst)
        else:
            shutil.copyfile(src, dst)
    return build


def _cut(src: Path, fraction: float) -> Callable[[Path], None]:
    def build(dst: Path) -> None:
        data = src.read_bytes()
        dst.write_bytes(data[:max(1, int(len(data) * fraction))])
    return build


def _flip(src: Path, fraction: float, n: int = 64) -> Callable[[Path], None]:
    def build(dst: Path) -> None:
        data = bytearray(src.read_bytes())
        i = int(len(data) * fraction)
        data[i:i + n] = bytes(255 - b for b in data[i:i + n])
        dst.write_bytes(bytes(data))
    return build


def _bytes(payload: bytes) -> Callable[[Path], None]:
    def build(dst: Path) -> None:
        dst.write_bytes(payload)
    return build


def _noise(size: int, seed: int) -> Callable[[Path], None]:
    def build(dst: Path) -> None:
        dst.write_bytes(np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8).tobytes())
    return build


# -- CSV ------------------------------------------------------------------------------------------
def _csv_rewrite(edit: Callable[[list[str]], list[str]]) -> Callable[[Path], None]:
    def build(dst: Path) -> None:
        lines = (SAMPLES / "design1_altitude.csv").read_text().splitlines()
        dst.write_text("\n".join(edit(lines)) + "\n")
    return build


def _time_scaled(lines: list[str], factor: float) -> list[str]:
    out = [lines[0]]
    for line in lines[1:]:
        t, rest = line.split(",", 1)
        out.append(f"{float(t) * factor:.6f},{rest}")
    return out


def _one_value(lines: list[str], row: int, col: int, text: str) -> list[str]:
    cells = lines[row].split(",")
    cells[col] = text
    return lines[:row] + [",".join(cells)] + lines[row + 1:]


def _column_nan(lines: list[str], col: int) -> list[str]:
    out = [lines[0]]
    for line in lines[1:]:
        cells = line.split(",")
        if cells[col]:
            cells[col] = "nan"
        out.append(",".join(cells))
    return out


def _big_csv(rows: int) -> Callable[[Path], None]:
    """``rows`` rows of a 200 Hz flight with 10 columns (about 40 bytes a row), written in blocks."""
    def build(dst: Path) -> None:
        rng = np.random.default_rng(29)
        with open(dst, "w") as handle:
            handle.write("__time,/mrft/command/data,/mocap/pose/pose/position/z," +
                         ",".join(f"/extra/c{i}" for i in range(3)) + "\n")
            for start in range(0, rows, 200_000):
                n = min(200_000, rows - start)
                t = 1700000000.0 + (start + np.arange(n)) / 200.0
                u = 0.5 + 0.05 * np.sign(np.sin(2 * np.pi * 1.0 * t))
                y = 1.0 + 0.05 * np.sin(2 * np.pi * 1.0 * t - 2.0) + 1e-4 * rng.standard_normal(n)
                block = np.column_stack([t, u, y, rng.standard_normal((n, 3))])
                np.savetxt(handle, block, fmt=["%.3f", "%.4g", "%.6g", "%.3g", "%.3g", "%.3g"], delimiter=",")
    return build


# -- MATLAB ---------------------------------------------------------------------------------------
def _mat(edit: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]]) -> Callable[[Path], None]:
    def build(dst: Path) -> None:
        from scipy.io import loadmat, savemat

        raw = {k: v for k, v in loadmat(str(SAMPLES / "dnn_altitude.mat")).items() if not k.startswith("__")}
        with open(dst, "wb") as handle:
            savemat(handle, edit(raw))
    return build


def _mat_ms(d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: v * 1000.0 if k.endswith("_t") else v for k, v in d.items()}


def _mat_nx2(d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    d = dict(d)
    d["z"] = np.column_stack([d["z"].ravel(), d["z"].ravel()])
    return d


def _mat_complex(d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    d = dict(d)
    d["z"] = d["z"] + 0.5j
    return d


def _mat_length(d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    d = dict(d)
    d["z"] = d["z"][:-7]
    return d


# -- MCAP -----------------------------------------------------------------------------------------
def _mcap_messages(src: Path) -> tuple[dict[int, tuple[str, str, bytes]], dict[int, tuple[str, int, str]],
                                       list[tuple[int, int, int, bytes]]]:
    from mcap.reader import make_reader

    with open(src, "rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert summary is not None
        schemas = {sid: (s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
        channels = {cid: (c.topic, c.schema_id, c.message_encoding) for cid, c in summary.channels.items()}
        msgs = [(m.channel_id, m.log_time, m.publish_time, m.data)
                for _s, _c, m in reader.iter_messages(log_time_order=False)]
    return schemas, channels, msgs


def _mcap_write(dst: Path, schemas: dict[int, tuple[str, str, bytes]],
                channels: dict[int, tuple[str, int, str]], msgs: list[tuple[int, int, int, bytes]]) -> None:
    from mcap.writer import Writer

    with open(dst, "wb") as handle:
        writer = Writer(handle)
        writer.start("ros2", "mrft-ident hostile corpus")
        new_sid = {sid: writer.register_schema(name, enc, data) for sid, (name, enc, data) in schemas.items()}
        new_cid = {cid: writer.register_channel(topic, enc, new_sid.get(sid, sid + 100))
                   for cid, (topic, sid, enc) in channels.items()}
        for cid, log_time, pub, data in msgs:
            writer.add_message(new_cid[cid], log_time, data, pub)
        writer.finish()


def _mcap_edit(edit: Callable[[dict, dict, list], tuple[dict, dict, list]]) -> Callable[[Path], None]:
    def build(dst: Path) -> None:
        _mcap_write(dst, *edit(*_mcap_messages(SAMPLES / "design1_altitude.mcap")))
    return build


def _self_schema(schemas: dict, channels: dict, msgs: list) -> tuple[dict, dict, list]:
    schemas = dict(schemas)
    schemas[1] = ("std_msgs/msg/Float64", "ros2msg", b"float64 data\nstd_msgs/Float64 next\n")
    return schemas, channels, msgs


def _mutual_schema(schemas: dict, channels: dict, msgs: list) -> tuple[dict, dict, list]:
    schemas = dict(schemas)
    text = (b"float64 data\nhostile_msgs/B b\n" + b"=" * 80 + b"\nMSG: hostile_msgs/B\nhostile_msgs/A a\n"
            + b"=" * 80 + b"\nMSG: hostile_msgs/A\nhostile_msgs/B b\n")
    schemas[1] = ("hostile_msgs/msg/A", "ros2msg", text)
    return schemas, channels, msgs


def _unknown_type(schemas: dict, channels: dict, msgs: list) -> tuple[dict, dict, list]:
    schemas = dict(schemas)
    schemas[1] = ("std_msgs/msg/Float64", "ros2msg", b"float64 data\nnowhere_msgs/Ghost ghost\n")
    return schemas, channels, msgs


def _zero_times(schemas: dict, channels: dict, msgs: list) -> tuple[dict, dict, list]:
    return schemas, channels, [(c, 0, 0, d) for c, _lt, _pt, d in msgs]


def _no_schema(schemas: dict, channels: dict, msgs: list) -> tuple[dict, dict, list]:
    schemas = {sid: s for sid, s in schemas.items() if sid != 1}  # the Float64 channels point at nothing
    return schemas, channels, msgs


def _float32(schemas: dict, channels: dict, msgs: list) -> tuple[dict, dict, list]:
    """The command as std_msgs/Float32 holding values beyond float32's range (inf after the cast)."""
    schemas = dict(schemas)
    schemas[9] = ("std_msgs/msg/Float32", "ros2msg", b"float32 data\n")
    channels = dict(channels)
    cmd = next(cid for cid, (topic, _s, _e) in channels.items() if topic == "/mrft/command")
    channels[cmd] = ("/mrft/command", 9, "cdr")
    out = []
    for i, (c, lt, pt, d) in enumerate(msgs):
        if c == cmd:
            value = struct.unpack_from("<d", d, 4)[0]
            f32 = np.float32(value) if i % 50 else np.float32(np.nan)
            d = d[:4] + struct.pack("<f", f32)
        out.append((c, lt, pt, d))
    return schemas, channels, out


def _mcap_bomb(declared: int | None, inflated: int) -> Callable[[Path], None]:
    """A valid MCAP header and one zstd chunk inflating to ``inflated`` bytes of zeros (declaring
    ``declared``, default the truth), then a footer: a decompression bomb."""
    def build(dst: Path) -> None:
        import zstandard

        def record(op: int, body: bytes) -> bytes:
            return struct.pack("<BQ", op, len(body)) + body

        def string(s: str) -> bytes:
            return struct.pack("<I", len(s)) + s.encode()

        cctx = zstandard.ZstdCompressor(level=3)
        comp = cctx.compressobj()
        parts = []
        block = bytes(1 << 24)
        for _ in range(inflated >> 24):
            parts.append(comp.compress(block))
        parts.append(comp.flush())
        payload = b"".join(parts)
        size = inflated if declared is None else declared
        chunk = struct.pack("<QQQI", 0, 10**9, size, 0) + string("zstd") + struct.pack("<Q", len(payload)) + payload
        with open(dst, "wb") as handle:
            handle.write(b"\x89MCAP0\r\n")
            handle.write(record(0x01, string("ros2") + string("bomb")))
            handle.write(record(0x06, chunk))
            handle.write(record(0x0F, b""))  # data end
            handle.write(record(0x02, struct.pack("<QQI", 0, 0, 0)))
            handle.write(b"\x89MCAP0\r\n")
    return build


# -- ULog -----------------------------------------------------------------------------------------
def _ulog_param(name: bytes, value: float) -> Callable[[Path], None]:
    def build(dst: Path) -> None:
        data = bytearray((SAMPLES / "px4_altitude_50hz.ulg").read_bytes())
        key = b"float " + name
        for m in re.finditer(re.escape(key), bytes(data)):
            i = m.end()
            data[i:i + 4] = struct.pack("<f", value)
        dst.write_bytes(bytes(data))
    return build


# -- issue 35: small files that declare huge sizes, damage, stale samples -------------------------
def ulog_nested(dst: Path) -> None:
    """A 168-byte ULog whose format nests ``inner[65535]`` of ``uint8_t[65535]`` (3.9 GB per message)."""
    def msg(kind: str, payload: bytes) -> bytes:
        return struct.pack("<HB", len(payload), ord(kind)) + payload

    head = b"ULog\x01\x12\x35" + b"\x01" + struct.pack("<Q", 0)
    fmts = msg("F", b"inner:uint8_t[65535] a;") + msg("F", b"outer:uint64_t timestamp;inner[65535] b;")
    add = msg("A", struct.pack("<BH", 0, 1) + b"outer")
    data = msg("D", struct.pack("<H", 1) + struct.pack("<Q", 1000) + bytes(16))
    dst.write_bytes(head + msg("B", bytes(40)) + fmts + add + data)


def dataflash_short_fmt(length: int) -> Callable[[Path], None]:
    """A DataFlash log whose FMT declares a message type ``length`` bytes long (0: pymavlink's scan hung)."""
    def fmt(t: int, n: int, name: bytes, form: bytes, cols: bytes) -> bytes:
        return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", t, n, name, form, cols)

    def build(dst: Path) -> None:
        head = fmt(128, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns") + fmt(129, 15, b"ATT", b"Qf",
                                                                                           b"TimeUS,Roll")
        att = b"".join(b"\xa3\x95\x81" + struct.pack("<Qf", 1000 * i, 0.1) for i in range(20))
        bad = fmt(200, length, b"BAD", b"Q", b"TimeUS") + b"\xa3\x95\xc8" + struct.pack("<Q", 5)
        dst.write_bytes(head + att + bad + att)
    return build


def mat_v5_zeros(n: int) -> Callable[[Path], None]:
    """A v5 .mat holding one compressed vector ``z`` of ``n`` zeros (200 M: 1.5 MB declaring 1.6 GB).

    Deflate restarts after a full flush, so one 16 MB block's compressed bytes are written over and over:
    the file is built in well under a second without ever holding the zeros."""
    import zlib

    def build(dst: Path) -> None:
        def tag(kind: int, nbytes: int) -> bytes:
            return struct.pack("<II", kind, nbytes)

        head = (tag(6, 8) + struct.pack("<II", 6, 0) + tag(5, 8) + struct.pack("<ii", n, 1)
                + tag(1, 1) + b"z" + bytes(7) + tag(9, 8 * n))
        comp = zlib.compressobj(9)
        parts = [comp.compress(tag(14, len(head) + 8 * n) + head), comp.flush(zlib.Z_FULL_FLUSH)]
        block = 1 << 24
        whole, rest = divmod(8 * n, block)
        if whole:
            parts.append((comp.compress(bytes(block)) + comp.flush(zlib.Z_FULL_FLUSH)) * whole)
        parts.append(comp.compress(bytes(rest)) + comp.flush())
        payload = b"".join(parts)
        text = b"MATLAB 5.0 MAT-file, hostile corpus".ljust(116, b" ")
        dst.write_bytes(text + bytes(8) + struct.pack("<H", 0x0100) + b"IM" + tag(15, len(payload)) + payload)
    return build


def mat_v73_unwritten(n: int) -> Callable[[Path], None]:
    """A v7.3 .mat (HDF5) with gzip datasets ``z`` and ``z_t`` of ``n`` doubles never written (4 kB)."""
    def build(dst: Path) -> None:
        import h5py

        with h5py.File(dst, "w", userblock_size=512) as f:
            for name in ("z", "z_t"):
                f.create_dataset(name, shape=(n, 1), dtype="f8", chunks=(1 << 16, 1), compression="gzip")
        with open(dst, "r+b") as fh:
            fh.write(b"MATLAB 7.3 MAT-file, hostile corpus".ljust(116, b" ") + bytes(8)
                     + struct.pack("<H", 0x0200) + b"IM")
    return build


def mcap_uncompressed_damaged(dst: Path) -> None:
    """design1_altitude.mcap in uncompressed chunks without CRCs, one message record's length garbled in the
    middle of the first chunk: neither a CRC nor the message index can vouch for what follows."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(SAMPLES / "design1_altitude.mcap", "rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert summary is not None
        msgs = [m for _s, _c, m in reader.iter_messages(log_time_order=False)]
    with open(dst, "wb") as out:
        writer = Writer(out, compression=CompressionType.NONE, enable_crcs=False)
        writer.start("ros2", "mrft-ident hostile corpus")
        sid = {k: writer.register_schema(v.name, v.encoding, v.data) for k, v in summary.schemas.items()}
        cid = {k: writer.register_channel(v.topic, v.message_encoding, sid[v.schema_id])
               for k, v in summary.channels.items()}
        for m in msgs:
            writer.add_message(cid[m.channel_id], m.log_time, m.data, m.publish_time)
        writer.finish()
    data = bytearray(dst.read_bytes())
    pos = 8  # magic; walk top-level records to the first chunk
    while data[pos] != 0x06:
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    body = pos + 9
    records = body + 8 + 8 + 8 + 4 + 4 + struct.unpack_from("<I", data, body + 28)[0] + 8
    end = records + struct.unpack_from("<Q", data, records - 8)[0]
    rec, count = records, 0
    while rec < end:  # the records of the chunk; garble the length of the 200th message
        length = struct.unpack_from("<Q", data, rec + 1)[0]
        if data[rec] == 0x05:
            count += 1
            if count == 200:
                struct.pack_into("<Q", data, rec + 1, length + 0x1234567)
                break
        rec += 9 + length
    dst.write_bytes(bytes(data))


def csv_stale(lag: int = 4) -> Callable[[Path], None]:
    """design1_altitude.csv whose every second output sample is the measurement ``lag`` samples (20 ms)
    older: a stale, sample-and-hold sensor (tau read 10 ms long)."""
    def build(dst: Path) -> None:
        lines = (SAMPLES / "design1_altitude.csv").read_text().splitlines()
        values = [line.split(",")[4] for line in lines[1:]]
        out = [lines[0]]
        for i, line in enumerate(lines[1:]):
            cells = line.split(",")
            if i % 2 == 1 and i >= lag:
                cells[4] = values[i - lag]
            out.append(",".join(cells))
        dst.write_text("\n".join(out) + "\n")
    return build


def _issue35_cases() -> list[Case]:
    """The files issue 35 names (items 3-5)."""
    d1 = "design1_altitude.csv"
    return [
        Case("ulog_nested.ulg", ulog_nested, "refuse", why="format nesting inner[65535] of uint8_t[65535]"),
        Case("dataflash_fmt0.bin", dataflash_short_fmt(0), "refuse", why="FMT of length 0 (pymavlink hung)"),
        Case("dataflash_fmt1.bin", dataflash_short_fmt(1), "refuse", why="FMT of length 1 (numpy warning)"),
        Case("mat_v5_zeros.mat", mat_v5_zeros(200_000_000), "refuse", why="1.5 MB declaring 200 M compressed zeros"),
        Case("mat_v73_unwritten.mat", mat_v73_unwritten(190_000_000), "refuse",
             why="v7.3 gzip datasets of 190 M doubles never written"),
        Case("mcap_uncompressed_damaged.mcap", mcap_uncompressed_damaged, "either", "design1_altitude.mcap",
             why="uncompressed chunk without CRC, a record's length garbled"),
        Case("csv_stale.csv", csv_stale(), "right", d1, why="every second output sample 20 ms old"),
    ]


# -- the cases ------------------------------------------------------------------------------------
def _format_cases() -> list[Case]:
    """Each shipped format cut, flipped, emptied, zeroed and replaced by noise."""
    out: list[Case] = []
    for src_name in ("design1_altitude.mcap", "design1_altitude.json.mcap", "design1_altitude.bag",
                     "design1_altitude.ulg", "design1_altitude.csv", "dnn_altitude.mat",
                     "px4_altitude_50hz.ulg", "hear_x.bag"):
        src = SAMPLES / src_name
        stem, dot, ext = src_name.partition(".")
        size = src.stat().st_size
        loop = "x" if stem == "hear_x" else "altitude"
        out += [
            Case(f"{stem}_cut50.{ext}", _cut(src, 0.5), "either", src_name, why="truncated at half"),
            Case(f"{stem}_cut97.{ext}", _cut(src, 0.97), "either", src_name, why="truncated near the end"),
            Case(f"{stem}_head.{ext}", _cut(src, 64 / size), "refuse", why="only the first 64 bytes"),
            Case(f"{stem}_flip40.{ext}", _flip(src, 0.4), "either", src_name, why="64 bytes inverted at 40 %"),
            Case(f"{stem}_flip03.{ext}", _flip(src, 0.03), "either", src_name, why="64 bytes inverted at 3 %"),
            Case(f"{stem}_empty.{ext}", _bytes(b""), "refuse", why="zero bytes"),
            Case(f"{stem}_zeros.{ext}", _bytes(bytes(min(size, 1 << 20))), "refuse", why="zeros"),
            Case(f"{stem}_noise.{ext}", _noise(min(size, 1 << 20), len(out)), "refuse", why="random bytes"),
        ]
        out[-8:] = [replace(c, loop=loop) for c in out[-8:]]
    ros2 = SAMPLES / "design1_altitude_ros2_sqlite3"
    out.append(Case("ros2_no_metadata", lambda d: (shutil.copytree(ros2, d), (d / "metadata.yaml").unlink()),
                    "refuse", why="a ROS 2 bag folder without metadata.yaml"))
    out.append(Case("folder_of_logs", lambda d: (d.mkdir(), shutil.copyfile(SAMPLES / "design1_altitude.mcap",
                                                                             d / "a.mcap")),
                    "refuse", why="a folder of logs (batch's input) given to a one-log command"))
    return out


def _issue_cases(big_rows: int) -> list[Case]:
    """The cases issue 29 names."""
    d1 = "design1_altitude.csv"
    return [
        # 1. times in milliseconds
        Case("csv_time_ms.csv", _csv_rewrite(lambda ls: _time_scaled(ls, 1e3)), "refuse",
             why="time column in ms under a seconds name"),
        Case("csv_time_ms_declared.csv", _csv_rewrite(lambda ls: _time_scaled(ls, 1e3)), "right", d1,
             args=("--time-unit", "ms"), fast=False, why="the same with --time-unit ms"),
        Case("csv_time_us.csv", _csv_rewrite(lambda ls: _time_scaled(ls, 1e6)), "refuse",
             why="time column in us under a seconds name"),
        Case("csv_time_min.csv", _csv_rewrite(lambda ls: _time_scaled(ls, 1 / 60)), "refuse",
             why="time column in minutes"),
        Case("mat_time_ms.mat", _mat(_mat_ms), "refuse", why=".mat times in ms"),
        # 3. internal errors
        # the standard std_msgs/Float64 decodes these (io/format_mcap falls back to it): either
        Case("mcap_self_schema.mcap", _mcap_edit(_self_schema), "either", "design1_altitude.mcap",
             why="a message type containing itself"),
        Case("mcap_mutual_schema.mcap", _mcap_edit(_mutual_schema), "refuse", why="two types containing each other"),
        Case("mcap_unknown_type.mcap", _mcap_edit(_unknown_type), "either", "design1_altitude.mcap",
             why="a field of a type never defined"),
        Case("mcap_zero_times.mcap", _mcap_edit(_zero_times), "refuse", why="every log time 0"),
        Case("csv_1e308.csv", _csv_rewrite(lambda ls: _one_value(ls, 2000, 4, "1e308")), "either", d1,
             why="one output sample of 1e308"),
        Case("csv_inf.csv", _csv_rewrite(lambda ls: _one_value(ls, 2000, 1, "inf")), "either", d1,
             why="one command sample of inf"),
        Case("px4_beta_nan.ulg", _ulog_param(b"MRFT_Z_BETA", float("nan")), "either", "px4_altitude_50hz.ulg",
             why="MRFT beta parameter NaN"),
        Case("px4_beta_inf.ulg", _ulog_param(b"MRFT_Z_BETA", float("inf")), "either", "px4_altitude_50hz.ulg",
             why="MRFT beta parameter inf"),
        # 4. size
        Case("csv_big.csv", _big_csv(big_rows), "either", fast=False,
             why=f"{big_rows} rows (about {big_rows * 40 / 1e6:.0f} MB)"),
        # 6. numpy warnings
        Case("mcap_float32_nan.mcap", _mcap_edit(_float32), "either", "design1_altitude.mcap",
             why="float32 command with NaN samples"),
        Case("csv_output_nan.csv", _csv_rewrite(lambda ls: _column_nan(ls, 4)), "refuse",
             why="output column all NaN"),
        Case("csv_command_nan.csv", _csv_rewrite(lambda ls: _column_nan(ls, 1)), "refuse",
             why="command column all NaN"),
        # 7. silent drops and unclear messages
        Case("mat_nx2.mat", _mat(_mat_nx2), "refuse", why=".mat output N x 2"),
        Case("mat_complex.mat", _mat(_mat_complex), "refuse", why=".mat output complex"),
        Case("mat_length.mat", _mat(_mat_length), "refuse", why=".mat output shorter than its _t"),
        Case("mcap_no_schema.mcap", _mcap_edit(_no_schema), "refuse", why="channels whose schema is missing"),
        # 2. decompression bombs (io/format_mcap.py, another engineer)
        Case("mcap_bomb_zstd.mcap", _mcap_bomb(None, 2 << 30), "refuse", fast=False,
             why="one zstd chunk inflating to 2 GiB"),
        Case("mcap_bomb_lie.mcap", _mcap_bomb(1 << 62, 1 << 24), "refuse", why="a chunk declaring 4 EiB"),
    ]


def cases(big_rows: int = 1_000_000) -> list[Case]:
    """Every case, in a fixed order."""
    return _format_cases() + _issue_cases(big_rows) + _issue35_cases()


CASES = cases


def build_corpus(out: Path, *, big_rows: int = 1_000_000, only: str | None = None) -> list[dict[str, object]]:
    """Write the corpus and its manifest into ``out`` (emptied first); the manifest's entries."""
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    manifest = []
    for case in cases(big_rows):
        if only and not re.search(only, case.name):
            continue
        case.build(out / case.name)
        entry = {k: v for k, v in asdict(case).items() if k != "build"}
        entry["args"] = list(case.args)
        manifest.append(entry)
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return manifest


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--big-rows", type=int, default=1_000_000,
                        help="rows of the big CSV (the issue's case: 10000000)")
    parser.add_argument("--only", help="build only the cases whose name matches this regex")
    args = parser.parse_args(argv)
    manifest = build_corpus(args.out, big_rows=args.big_rows, only=args.only)
    print(f"{len(manifest)} cases in {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
