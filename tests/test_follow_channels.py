"""The MCAP follower keeps only the loop's channels: a camera beside them costs its log times, not its bytes.

Oracle: the flight read from the same recording without the camera (``read_flight`` on the sample
log), and the bytes the unfiltered follower holds (every camera frame, undecoded).
"""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from mrftcli.errors import LogReadError
from mrftcli.io import read_flight
from mrftcli.io.flight import ReadOptions
from mrftcli.io.follow import McapFollower, follow_log

#: one fake camera frame [bytes] (compresses to little: the test file stays small, what it decompresses to does not)
_FRAME = 64 * 1024


def _with_camera(src, dst, every: int = 20) -> int:
    """``src`` rewritten with a /camera channel of ``_FRAME``-byte messages after every ``every``-th
    message; returns the camera's total bytes."""
    frame = np.tile(np.random.default_rng(0).integers(0, 256, 1024, dtype=np.uint8), _FRAME // 1024).tobytes()
    total = 0
    with open(src, "rb") as fin, open(dst, "wb") as fout:
        reader = make_reader(fin)
        w = Writer(fout, compression=CompressionType.ZSTD, chunk_size=1 << 18)
        w.start(profile="ros2", library="test")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        cam_schema = w.register_schema("sensor_msgs/msg/CompressedImage", "ros2msg", b"")
        cam = w.register_channel("/camera/image/compressed", "cdr", cam_schema)
        for k, (schema, channel, msg) in enumerate(reader.iter_messages(log_time_order=False)):
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding, schemas[schema.id])
            w.add_message(channels[channel.id], msg.log_time, msg.data, msg.publish_time)
            if k % every == 0:
                w.add_message(cam, msg.log_time, frame, msg.log_time)
                total += len(frame)
        w.finish()
    return total


@pytest.fixture(scope="module")
def camera_bag(repo_root, tmp_path_factory):
    src = repo_root / "sample_logs" / "design1_altitude.mcap"
    dst = tmp_path_factory.mktemp("cam") / "with_camera.mcap"
    return src, dst, _with_camera(src, dst)


def test_a_follower_of_a_camera_bag_holds_only_the_loop_channels(camera_bag):
    src, bag, camera_bytes = camera_bag
    assert camera_bytes > 40e6  # the unwanted channel dwarfs the loop's (16815 small messages)
    everything = McapFollower(bag)
    everything.poll()
    assert everything.kept_bytes() >= camera_bytes  # what the follower held before: every frame
    log = follow_log(bag, ReadOptions())
    snap = log.poll()
    assert snap.closed and snap.flight is not None
    follower = log.follower
    assert follower is not None and "/camera/image/compressed" in follower.topics()
    # the loop's messages are decoded (and released) by the flight; the camera's were never held
    assert follower.kept_bytes() < 1e6
    ref = read_flight(src, echo_warnings=False)
    np.testing.assert_array_equal(snap.flight.command.values, ref.command.values)
    np.testing.assert_array_equal(snap.flight.output.t, ref.output.t)
    np.testing.assert_array_equal(snap.flight.output.values, ref.output.values)


def test_asking_a_filtered_follower_for_a_dropped_topic_is_an_error(camera_bag):
    _, bag, _ = camera_bag
    f = McapFollower(bag, topics={"/mrft/command"})
    f.poll()
    with pytest.raises(LogReadError, match="not one this follower keeps"):
        f.values("/camera/image/compressed", ["data"])
    t, v = f.values("/mrft/command", ["data"])
    assert t.size > 100 and np.isfinite(v["data"]).all()


@pytest.mark.parametrize("name", ["design1_altitude.mcap", "design1_altitude.json.mcap"])
def test_a_followed_log_decodes_as_the_reader_does(name):
    """The follower decodes each channel (CDR and JSON) through the MCAP reader's own decoding
    (io/format_mcap.channel_values): the finished log followed gives the flight the reader gives."""
    from pathlib import Path

    log = Path(__file__).parents[1] / "sample_logs" / name
    whole = read_flight(log, ReadOptions(loop="altitude"), echo_warnings=False)
    follower = follow_log(log, ReadOptions(loop="altitude"))
    snap = follower.poll()
    assert snap.flight is not None
    for role in ("command", "output", "setpoint"):
        ours, theirs = getattr(snap.flight, role), getattr(whole, role)
        np.testing.assert_array_equal(ours.t, theirs.t)
        np.testing.assert_array_equal(ours.values, theirs.values)
