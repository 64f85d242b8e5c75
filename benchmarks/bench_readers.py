"""Reader speed: ``read_flight``/``open_log`` against a plain ``mcap`` decoding loop.

Generates a 10-minute, 200 Hz reference-layout MCAP (``/mrft/command`` Float64, ``/mocap/pose``
PoseStamped, ``/imu/data`` Imu: 360 000 messages) in a temporary directory, then extracts the same
series (command, altitude, orientation quaternion) two ways, in the same run:

* baseline: ``mcap.reader.make_reader(..., decoder_factories=[mcap_ros2.decoder.DecoderFactory()])``
  and ``iter_decoded_messages`` over the three topics, appending the fields to lists;
* ours: ``open_log`` + one vectorised read per topic (and, separately, ``read_flight`` for the roll
  loop, which also turns the quaternion into roll).

Run: ``python benchmarks/bench_readers.py [--minutes 10] [--repeat 3]``. Prints best-of-N times and
the ratio.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from mrftcli.io.logtypes import TopicData
from mrftcli.io import open_log, read_flight, write_log


def make_log(path: Path, minutes: float, rate: float = 200.0) -> int:
    rng = np.random.default_rng(0)
    n = int(minutes * 60 * rate)
    t = 1_700_000_000.0 + np.arange(n) / rate
    cmd = 0.5 + 0.05 * np.sign(np.sin(2 * np.pi * 1.3 * t))
    z = 1.0 + 0.02 * np.sin(2 * np.pi * 1.3 * t) + 1e-3 * rng.standard_normal(n)
    roll = 0.05 * np.sin(2 * np.pi * 2.1 * t)
    topics = [
        TopicData("/mrft/command", "std_msgs/msg/Float64", t, {"data": cmd}),
        TopicData("/mocap/pose", "geometry_msgs/msg/PoseStamped", t + 1e-4, {"pose.position.z": z}),
        TopicData("/imu/data", "sensor_msgs/msg/Imu", t + 2e-4,
                  {"orientation.x": np.sin(roll / 2), "orientation.w": np.cos(roll / 2)}),
    ]
    write_log(topics, path, "mcap")
    return 3 * n


def baseline(path: Path) -> dict[str, np.ndarray]:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out = {"cmd_t": [], "cmd": [], "z_t": [], "z": [], "q_t": [], "qx": [], "qy": [], "qz": [], "qw": []}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, msg in reader.iter_decoded_messages(
                topics=["/mrft/command", "/mocap/pose", "/imu/data"]):
            if channel.topic == "/mrft/command":
                out["cmd_t"].append(message.log_time)
                out["cmd"].append(msg.data)
            elif channel.topic == "/mocap/pose":
                out["z_t"].append(message.log_time)
                out["z"].append(msg.pose.position.z)
            else:
                q = msg.orientation
                out["q_t"].append(message.log_time)
                out["qx"].append(q.x)
                out["qy"].append(q.y)
                out["qz"].append(q.z)
                out["qw"].append(q.w)
    return {k: np.asarray(v) / (1e9 if k.endswith("_t") else 1.0) for k, v in out.items()}


def ours(path: Path) -> dict[str, np.ndarray]:
    with open_log(path) as log:
        log.prefetch(["/mrft/command", "/mocap/pose", "/imu/data"])  # one pass, as read_flight does
        t_c, _, c = log.values("/mrft/command", "data")
        t_z, _, z = log.values("/mocap/pose", "pose.position.z")
        t_q, leaves, q = log.values("/imu/data", "orientation")
    return {"cmd_t": t_c, "cmd": c["data"], "z_t": t_z, "z": z["pose.position.z"], "q_t": t_q,
            **{f"q{k}": q[f"orientation.{k}"] for k in "xyzw"}}


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
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        start = time.perf_counter()
        count = make_log(path, args.minutes)
        print(f"wrote {count} messages ({path.stat().st_size / 1e6:.1f} MB) in "
              f"{time.perf_counter() - start:.2f} s")
        t_base, ref = best(lambda: baseline(path), args.repeat)
        t_ours, got = best(lambda: ours(path), args.repeat)
        for key in ref:
            if not np.array_equal(ref[key], got[key]):
                raise SystemExit(f"MISMATCH in {key}")
        t_flight, _ = best(lambda: read_flight(path, loop="roll"), args.repeat)
        print(f"baseline mcap iter_decoded_messages (3 topics): {t_base:8.3f} s")
        print(f"open_log + prefetch + 3 reads (same series):   {t_ours:8.3f} s   "
              f"ratio {t_base / t_ours:5.1f}x")
        print(f"read_flight(loop='roll') (command + imu->roll): {t_flight:8.3f} s   "
              f"ratio {t_base / t_flight:5.1f}x (vs the 3-topic baseline)")


if __name__ == "__main__":
    main()
