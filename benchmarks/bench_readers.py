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

Run: ``python benchmarks/bench_readers.py [--minutes 10] [--repeat 2] [--seed N]``. Prints best-of-N
times per stage and the ratios against the mcap + rosbags baseline.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from mrftcli.io import cdr, open_log, read_flight, write_log
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--seed", type=int, default=None, help="log content seed (default: fresh)")
    args = parser.parse_args()
    seed = int(np.random.SeedSequence().entropy % 2**32) if args.seed is None else args.seed
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
        t_flight, _ = best(lambda: read_flight(path, loop="roll"), args.repeat)

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
