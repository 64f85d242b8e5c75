"""Reader speed: ``read_flight``/``open_log`` against plain per-message decoding, container and CDR apart.

Generates a reference-layout MCAP (``/mrft/command`` Float64, ``/mocap/pose`` PoseStamped,
``/imu/data`` Imu at 200 Hz; 10 minutes = 360 000 messages by default) in a temporary directory, then
extracts the same series (command, altitude, orientation quaternion, each with its log times) three
ways in the same run and checks that they agree exactly:

* **mcap + mcap_ros2**: ``mcap.reader.make_reader(f).iter_messages`` over the three topics, in file
  order (``log_time_order=False``, no CRC check: the library's quickest settings) (container), then ``mcap_ros2.decoder.DecoderFactory``'s decoder on every message (CDR);
* **mcap + rosbags**: the same raw messages (container), decoded with rosbags'
  ``Typestore.deserialize_cdr`` per message (CDR): the quickest per-message path the libraries offer;
* **ours**: ``open_log`` + ``prefetch`` of the three topics + one vectorised read per topic. Its CDR
  time is the time spent in :func:`mrftcli.io.cdr.extract` (timed by wrapping it), its container time
  is the rest (locating, decompressing and indexing the chunks' message records).

Also ``read_flight(loop="roll")`` end to end (two of the three topics, quaternion -> roll).

Heavy bags (issue 24.1, ``--heavy 1,3``): the 40 s MRFT flight of ``sample_logs/design1_altitude.mcap``
recorded as ``ros2 bag record -a`` writes it beside a camera (``sensor_msgs/msg/CompressedImage`` at
30 Hz, incompressible frames sized so the file is the given GB), a point cloud (10 Hz, 200 KB) and a
raw IMU (400 Hz), in 768 KiB zstd chunks with message indexes (rosbag2's mcap defaults), written to
/tmp and deleted after. Each run is a fresh subprocess whose CPU time (user + system) and peak
resident memory come from ``os.wait4``: ``mrft-ident analyze`` on the heavy bag, against the baseline
(the ``mcap`` library's ``iter_messages(topics=[the flight's topics])`` on the heavy bag, plus
``mrft-ident analyze`` on the light bag, the same flight written the same way without the heavy
topics). The heavy bag's analysis must equal the light one's, and so must the analysis of the heavy
bag cut before its summary (a recording stopped short: the salvage pass), measured the same way.

Run: ``python benchmarks/bench_readers.py [--minutes 10] [--repeat 2] [--seed N] [--heavy GB,...]
[--skip-light]``. Prints best-of-N times per stage and the ratios against the mcap + rosbags
baseline; with ``--heavy``, CPU, peak memory and the ratio per heavy bag.
"""

from __future__ import annotations

import argparse
import difflib
import os
import resource
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from mrftcli.io import ReadOptions, cdr, open_log, read_flight, write_log
from mrftcli.io.logtypes import TopicData

TOPICS = ["/mrft/command", "/mocap/pose", "/imu/data"]


def make_log(path: Path, minutes: float, seed: int, rate: float = 200.0) -> int:
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * rate)
    t = 1_700_000_000.0 + np.arange(n) / rate
    f1, f2 = rng.uniform(0.8, 2.5, 2)
    cmd = 0.5 + 0.05 * np.sign(np.sin(2 * np.pi * f1 * t))
    z = 1.0 + 0.02 * np.sin(2 * np.pi * f1 * t) + 1e-3 * rng.standard_normal(n)
    roll = 0.05 * np.sin(2 * np.pi * f2 * t)
    topics = [
        TopicData("/mrft/command", "std_msgs/msg/Float64", t, {"data": cmd}),
        TopicData("/mocap/pose", "geometry_msgs/msg/PoseStamped", t + 1e-4, {"pose.position.z": z}),
        TopicData("/imu/data", "sensor_msgs/msg/Imu", t + 2e-4,
                  {"orientation.x": np.sin(roll / 2), "orientation.w": np.cos(roll / 2)}),
    ]
    write_log(topics, path, "mcap")
    return 3 * n


def raw_messages(path: Path) -> list[tuple]:
    """Container only: (topic, schema, log_time [ns], CDR bytes) of every wanted message."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return [(channel.topic, schema, message.log_time, message.data)
                for schema, channel, message in make_reader(f).iter_messages(topics=TOPICS, log_time_order=False)]


def collect(decoded) -> dict[str, np.ndarray]:
    """The series from (topic, log_time, message object) triples."""
    out = {"cmd_t": [], "cmd": [], "z_t": [], "z": [], "q_t": [], "qx": [], "qy": [], "qz": [], "qw": []}
    for topic, log_time, msg in decoded:
        if topic == "/mrft/command":
            out["cmd_t"].append(log_time)
            out["cmd"].append(msg.data)
        elif topic == "/mocap/pose":
            out["z_t"].append(log_time)
            out["z"].append(msg.pose.position.z)
        else:
            q = msg.orientation
            out["q_t"].append(log_time)
            out["qx"].append(q.x)
            out["qy"].append(q.y)
            out["qz"].append(q.z)
            out["qw"].append(q.w)
    return {k: np.asarray(v) / (1e9 if k.endswith("_t") else 1.0) for k, v in out.items()}


def decode_mcap_ros2(raw: list[tuple]) -> dict[str, np.ndarray]:
    from mcap_ros2.decoder import DecoderFactory

    factory, decoders = DecoderFactory(), {}

    def decode(schema, data):
        if schema.id not in decoders:
            decoders[schema.id] = factory.decoder_for("cdr", schema)
        return decoders[schema.id](data)

    return collect((topic, t, decode(schema, data)) for topic, schema, t, data in raw)


def decode_rosbags(raw: list[tuple]) -> dict[str, np.ndarray]:
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    return collect((topic, t, ts.deserialize_cdr(data, schema.name)) for topic, schema, t, data in raw)


def ours(path: Path) -> dict[str, np.ndarray]:
    with open_log(path) as log:
        log.prefetch(TOPICS)  # one pass over the chunks, as read_flight does
        t_c, _, c = log.values("/mrft/command", "data")
        t_z, _, z = log.values("/mocap/pose", "pose.position.z")
        t_q, _, q = log.values("/imu/data", "orientation")
    return {"cmd_t": t_c, "cmd": c["data"], "z_t": t_z, "z": z["pose.position.z"], "q_t": t_q,
            **{f"q{k}": q[f"orientation.{k}"] for k in "xyzw"}}


class _TimedExtract:
    """Wraps :func:`mrftcli.io.cdr.extract` to add up the time spent in it (our CDR stage)."""

    def __init__(self) -> None:
        self.inner = cdr.extract
        self.seconds = 0.0

    def __call__(self, *args, **kwargs):
        start = time.perf_counter()
        try:
            return self.inner(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - start


def best(fn, repeat: int) -> tuple[float, object]:
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return min(times), result


# -- heavy bags (issue 24.1) ----------------------------------------------------------------------
FLIGHT = Path(__file__).resolve().parents[1] / "sample_logs" / "design1_altitude.mcap"
FLIGHT_TP = "0.0422"  # its Tp [s] (the .truth.json)
CHUNK_BYTES = 768 * 1024  # rosbag2's mcap storage default chunk size


def _msgdef(msgtype: str) -> bytes:
    from mrftcli.io.msgtypes import typestore_for

    return typestore_for(ros1=False).generate_msgdef(msgtype, ros_version=2)[0].encode()


def write_bag(path: Path, gigabytes: float, seed: int) -> None:
    """The sample flight's messages, and (``gigabytes`` > 0) a camera, a point cloud and a raw IMU
    beside them, interleaved in log-time order, as rosbag2 writes an MCAP."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(FLIGHT, "rb") as f:
        flight = [(s, c, m.log_time, m.publish_time, bytes(m.data))
                  for s, c, m in make_reader(f).iter_messages(log_time_order=True)]
    t0, t1 = flight[0][2], flight[-1][2]
    rng = np.random.default_rng(seed)
    heavy: list[tuple[str, str, float, int]] = []
    if gigabytes > 0:
        seconds = (t1 - t0) / 1e9
        # the camera takes what the other two leave of the file's size
        frame = int((gigabytes * 1e9 - seconds * (10 * 200_000 + 400 * 324)) / (seconds * 30))
        heavy = [("/camera/image_raw/compressed", "sensor_msgs/msg/CompressedImage", 30.0, frame),
                 ("/points", "sensor_msgs/msg/PointCloud2", 10.0, 200_000),
                 ("/imu/data_raw", "sensor_msgs/msg/Imu", 400.0, 324)]
    # a few distinct incompressible payloads per topic (JPEG frames do not compress)
    payloads = {name: [rng.bytes(size) for _ in range(4)] for name, _, _, size in heavy}
    events = [(t, 0, i) for i, (_, _, t, _, _) in enumerate(flight)]
    for k, (name, _, rate, _) in enumerate(heavy, start=1):
        events += [(int(t), k, i) for i, t in enumerate(np.arange(t0, t1, 1e9 / rate))]
    events.sort()
    with open(path, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.ZSTD, chunk_size=CHUNK_BYTES)
        writer.start(profile="ros2", library="bench_readers")
        channels: dict[str, int] = {}
        for s, c, *_ in flight:
            if c.topic not in channels:
                sid = writer.register_schema(s.name, s.encoding, s.data)
                channels[c.topic] = writer.register_channel(c.topic, c.message_encoding, sid)
        for name, msgtype, _, _ in heavy:
            sid = writer.register_schema(msgtype, "ros2msg", _msgdef(msgtype))
            channels[name] = writer.register_channel(name, "cdr", sid)
        for t, k, i in events:
            if k == 0:
                _, c, log_time, publish_time, data = flight[i]
                writer.add_message(channels[c.topic], log_time, data, publish_time)
            else:
                name = heavy[k - 1][0]
                writer.add_message(channels[name], t, payloads[name][i % 4], t)
        writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer.finish has no annotations


def _run(args: list[str], *, tree: Path | None = None, timeout: float | None = None,
         address_space: int | None = None) -> tuple[int | None, float, float, str, str]:
    """Run ``args`` in a fresh process: (exit code, None if killed at ``timeout`` [s]; CPU [s]; peak
    resident memory [MB]; stdout; stderr). The child is reaped with ``os.wait4``, which gives its own
    resource usage. ``tree``: run another checkout's ``mrftcli`` (the code before a change);
    ``address_space``: an ``RLIMIT_AS`` cap [bytes]."""
    def limit() -> None:
        if address_space is not None:
            resource.setrlimit(resource.RLIMIT_AS, (address_space, address_space))

    env = dict(os.environ, PYTHONPATH=str(tree)) if tree is not None else None
    killed: list[bool] = []

    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        # (``python -m`` puts the working directory first on the path: run in the tree)
        proc = subprocess.Popen(args, stdout=out, stderr=err, env=env, cwd=tree, preexec_fn=limit)
        timer = threading.Timer(timeout or 1e9, lambda: (killed.append(True), proc.kill()))
        timer.start()
        _, status, usage = os.wait4(proc.pid, 0)
        timer.cancel()
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        texts = out.read().decode(errors="replace"), err.read().decode(errors="replace")
    code = None if killed else proc.returncode
    return code, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, *texts


def _measured(args: list[str], tree: Path | None = None) -> tuple[float, float, str]:
    """(CPU [s], peak resident memory [MB], stdout) of a run that must succeed."""
    code, cpu, peak, out, err = _run(args, tree=tree)
    if code != 0:
        raise SystemExit(f"{' '.join(args)} failed ({code}): {err.strip()}")
    return cpu, peak, out


def _cut_summary(path: Path) -> None:
    """Truncate an MCAP in place before its Data End record (summary and footer gone)."""
    with open(path, "rb") as f:
        f.seek(-8 - 29, os.SEEK_END)
        footer = f.read(29)
    summary_start = struct.unpack_from("<Q", footer, 9)[0]
    os.truncate(path, summary_start - 13)


def _library_read(path: Path) -> list[str]:
    topics = ["/mrft/command", "/mocap/pose", "/mrft/setpoint", "/mrft/beta", "/battery"]
    code = ("import sys; from mcap.reader import make_reader\n"
            "with open(sys.argv[1], 'rb') as f:\n"
            f"    n = sum(1 for _ in make_reader(f).iter_messages(topics={topics!r}))\n"
            "print(n)")
    return [sys.executable, "-c", code, str(path)]


def _analyze(path: Path) -> list[str]:
    return [sys.executable, "-m", "mrftcli", "analyze", str(path), "--tp", FLIGHT_TP, "--loop", "altitude"]


def heavy_bags(sizes: list[float], seed: int, before: Path | None = None) -> None:
    """Issue 24.1's figures: peak memory and CPU of analyze on heavy bags against the baseline (and,
    with ``before``, of the analyze of another checkout)."""
    with tempfile.TemporaryDirectory(dir="/tmp") as tmp:
        light = Path(tmp) / "light.mcap"
        write_bag(light, 0, seed)
        cpu_light, mem_light, out_light = _measured(_analyze(light))
        print(f"light bag {light.stat().st_size / 1e6:.2f} MB: analyze {cpu_light:.2f} s CPU, "
              f"{mem_light:.0f} MB peak")
        print(f"{'bag':>8s} {'analyze CPU [s]':>15s} {'peak [MB]':>9s} {'mcap read CPU [s]':>17s} "
              f"{'peak [MB]':>9s} {'baseline CPU [s]':>16s} {'ratio':>6s}")
        for gb in sizes:
            path = Path(tmp) / f"heavy_{gb:g}gb.mcap"
            try:
                write_bag(path, gb, seed)
                cpu, mem, out = _measured(_analyze(path))
                cpu_lib, mem_lib, _ = _measured(_library_read(path))
                old = _measured(_analyze(path), before) if before is not None else None
                _cut_summary(path)  # the recording stopped before its summary: the salvage pass
                cpu_cut, mem_cut, out_cut = _measured(_analyze(path))
            finally:
                size = path.stat().st_size / 1e9 if path.exists() else float("nan")
                path.unlink(missing_ok=True)
            for what, got in (("", out), (" cut before its summary", out_cut)):
                if got.replace(str(path), "LOG") != out_light.replace(str(light), "LOG"):
                    diff = difflib.unified_diff(out_light.replace(str(light), "LOG").splitlines(),
                                                got.replace(str(path), "LOG").splitlines(), lineterm="")
                    raise SystemExit(f"MISMATCH: analyze on the {gb:g} GB bag{what} differs from the light "
                                     "bag:\n" + "\n".join(diff))
            base = cpu_lib + cpu_light
            print(f"{size:7.2f}G {cpu:15.2f} {mem:9.0f} {cpu_lib:17.2f} {mem_lib:9.0f} {base:16.2f} "
                  f"{cpu / base:5.2f}x   summary cut: {cpu_cut:.2f} s CPU, {mem_cut:.0f} MB peak"
                  + (f"   before: {old[0]:.2f} s CPU, {old[1]:.0f} MB peak" if old else ""))


# -- decompression bombs (issue 29.2) -------------------------------------------------------------
GIB = 1 << 30


def _record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _string(text: str) -> bytes:
    return struct.pack("<I", len(text)) + text.encode()


def _rle_zstd(total: int) -> bytes:
    """A valid zstd frame of ``total`` zeros as 128 KiB RLE blocks (4 bytes each: 4 GiB in 128 KiB)."""
    out = [struct.pack("<IBBQ", 0xFD2FB528, 0xC0, 7 << 3, total)]
    left = total
    while left > 0:
        n = min(1 << 17, left)
        left -= n
        out.append(int((n << 3) | 2 | (left == 0)).to_bytes(3, "little") + b"\0")
    return b"".join(out)


def _lz4_zeros(total: int) -> bytes:
    import lz4.frame

    comp = lz4.frame.LZ4FrameCompressor()
    parts, block = [comp.begin()], bytes(64 << 20)
    for _ in range(total // len(block)):
        parts.append(comp.compress(block))
    parts.append(comp.flush())
    return b"".join(parts)


def _bomb_chunk(compression: str, declared: int, payload: bytes) -> bytes:
    # crc 0 means "not written": nothing checks the inflated bytes
    return _record(0x06, struct.pack("<QQQI", 0, 10**18, declared, 0) + _string(compression)
                   + struct.pack("<Q", len(payload)) + payload)


def bomb_files(folder: Path) -> dict[str, tuple[Path, bool]]:
    """The sample flight with a bomb chunk after its chunks: name -> (file, whether a correct reader
    may give the flight's numbers: the bomb cannot be in its index)."""
    flight = FLIGHT.read_bytes()
    data_end = flight.rindex(_record(0x0F, struct.pack("<I", 0)), 0, len(flight) - 8 - 29)
    summary_start = data_end + 13
    summary = flight[summary_start:len(flight) - 8 - 29]  # up to the footer (29 bytes) and magic
    bombs = {"zstd_4gib": _bomb_chunk("zstd", 4 * GIB, _rle_zstd(4 * GIB)),
             "lz4_2gib": _bomb_chunk("lz4", 2 * GIB, _lz4_zeros(2 * GIB)),
             "zstd_liar": _bomb_chunk("zstd", 1 << 20, _rle_zstd(4 * GIB))}
    out: dict[str, tuple[Path, bool]] = {}
    for name, chunk in bombs.items():
        head = flight[:data_end] + chunk
        index = _record(0x08, struct.pack("<QQQQ", 0, 10**18, data_end, len(chunk)) + struct.pack("<IQ", 0, 0)
                        + _string("x") + struct.pack("<QQ", len(chunk), 0))
        rest = _record(0x0F, struct.pack("<I", 0)) + summary + index
        footer = _record(0x02, struct.pack("<QQI", len(head) + 13, 0, 0)) + flight[:8]
        out[f"{name}.mcap"] = (folder / f"{name}.mcap", False)
        out[f"{name}.mcap"][0].write_bytes(head + rest + footer)
        if name != "zstd_liar":  # summary and footer cut off: the salvage pass
            out[f"{name}_nosummary.mcap"] = (folder / f"{name}_nosummary.mcap", True)
            out[f"{name}_nosummary.mcap"][0].write_bytes(head)
            out[f"{name}_cut.mcap"] = (folder / f"{name}_cut.mcap", True)
            out[f"{name}_cut.mcap"][0].write_bytes(head[:len(head) - len(chunk) // 2])
    return out


def bombs(timeout: float) -> None:
    """Issue 29.2: every bomb through topics, analyze and diagnose (internal errors, hangs, runs over
    1 GB, exit 0 with numbers other than the clean flight's)."""
    commands = {"topics": [], "analyze": ["--tp", FLIGHT_TP, "--loop", "altitude"],
                "diagnose": ["--tp", FLIGHT_TP, "--loop", "altitude", "--json", "-"]}
    clean: dict[str, str] = {}
    for command, extra in commands.items():
        if command != "topics":
            _, _, out = _measured([sys.executable, "-m", "mrftcli", command, str(FLIGHT), *extra])
            clean[command] = out.replace(str(FLIGHT), "LOG")
    totals = {"runs": 0, "internal": 0, "hangs": 0, "over_1gb": 0, "wrong_exit_0": 0}
    with tempfile.TemporaryDirectory(dir="/tmp") as tmp:
        print(f"{'file':28s} {'command':9s} {'exit':>4s} {'peak [MB]':>9s}  first line of stderr")
        for name, (path, may_succeed) in bomb_files(Path(tmp)).items():
            for command, extra in commands.items():
                code, _, peak, out, err = _run([sys.executable, "-m", "mrftcli", command, str(path), *extra],
                                               timeout=timeout, address_space=3 * GIB)
                totals["runs"] += 1
                totals["hangs"] += code is None
                totals["internal"] += code is not None and (code not in (0, 2, 3, 4, 5, 6, 7) or "Traceback" in err)
                totals["over_1gb"] += peak > 1024
                same = command == "topics" or out.replace(str(path), "LOG") == clean[command]
                totals["wrong_exit_0"] += code == 0 and not (may_succeed and same)
                print(f"{name:28s} {command:9s} {code if code is not None else 'hang':>4} {peak:9.0f}  "
                      f"{(err.strip().splitlines() or [''])[0][:110]}")
    print("totals: " + ", ".join(f"{k} {v}" for k, v in totals.items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--seed", type=int, default=None, help="log content seed (default: fresh)")
    parser.add_argument("--heavy", default="", help="heavy bag sizes [GB], comma-separated (issue 24.1)")
    parser.add_argument("--skip-light", action="store_true", help="only the heavy bags (or bombs)")
    parser.add_argument("--bombs", action="store_true", help="decompression bombs through the CLI (issue 29.2)")
    parser.add_argument("--timeout", type=float, default=120.0, help="per bomb run [s]")
    parser.add_argument("--before", type=Path, default=None,
                        help="a checkout of the code before the change: its analyze on the heavy bags too")
    args = parser.parse_args()
    seed = int(np.random.SeedSequence().entropy % 2**32) if args.seed is None else args.seed
    if not args.skip_light:
        light_log(args.minutes, args.repeat, seed)
    if args.heavy:
        heavy_bags([float(x) for x in args.heavy.split(",")], seed, args.before)
    if args.bombs:
        bombs(args.timeout)


def light_log(minutes: float, repeat: int, seed: int) -> None:
    """The reference-layout log: our reader against the libraries' per-message decoding."""
    args = argparse.Namespace(minutes=minutes, repeat=repeat)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        start = time.perf_counter()
        count = make_log(path, args.minutes, seed)
        print(f"wrote {count} messages ({path.stat().st_size / 1e6:.1f} MB, seed {seed}) in "
              f"{time.perf_counter() - start:.2f} s; best of {args.repeat}")

        t_raw, raw = best(lambda: raw_messages(path), args.repeat)
        t_mr2, ref = best(lambda: decode_mcap_ros2(raw), args.repeat)  # noqa: F821 (deleted below)
        t_rb, got_rb = best(lambda: decode_rosbags(raw), args.repeat)  # noqa: F821 (deleted below)
        del raw

        timed = _TimedExtract()
        cdr.extract = timed
        try:
            runs = []
            for _ in range(args.repeat):
                timed.seconds = 0.0
                start = time.perf_counter()
                got = ours(path)
                runs.append((time.perf_counter() - start, timed.seconds))
        finally:
            cdr.extract = timed.inner
        t_ours, t_ours_cdr = min(runs)
        t_ours_box = t_ours - t_ours_cdr
        for name, result in (("mcap + rosbags", got_rb), ("ours", got)):
            for key in ref:
                if not np.array_equal(ref[key], result[key]):
                    raise SystemExit(f"MISMATCH in {key} ({name} vs mcap + mcap_ros2)")
        t_flight, _ = best(lambda: read_flight(path, ReadOptions(loop="roll")), args.repeat)

        base = t_raw + t_rb
        print(f"{'path':46s} {'container [s]':>13s} {'CDR [s]':>9s} {'total [s]':>10s} {'vs mcap+rosbags':>16s}")
        rows = (("mcap iter_messages + mcap_ros2 decoder", t_raw, t_mr2),
                ("mcap iter_messages + rosbags deserialize_cdr", t_raw, t_rb),
                ("ours: open_log + prefetch + 3 reads", t_ours_box, t_ours_cdr))
        for name, box, dec in rows:
            print(f"{name:46s} {box:13.3f} {dec:9.3f} {box + dec:10.3f} {base / (box + dec):15.1f}x")
        print(f"{'ours: read_flight(loop=roll), 2 topics':46s} {'':13s} {'':9s} {t_flight:10.3f} "
              f"{base / t_flight:15.1f}x")
        print(f"stage ratios, mcap + rosbags / ours: container {t_raw / t_ours_box:.1f}x, "
              f"CDR {t_rb / t_ours_cdr:.1f}x")


if __name__ == "__main__":
    main()
