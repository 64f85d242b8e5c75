"""Writers, checked with *other* readers than ours: mcap_ros2, rosbags' AnyReader, pyulog, pandas."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from mrftcli.errors import InputError
from mrftcli.io.logtypes import TopicData
from mrftcli.io import FORMAT_SUFFIX, FORMATS, log_filename, write_log
from test_readers import synthetic_flight


@pytest.fixture(scope="module")
def flight():
    return synthetic_flight(n=120)


def test_mcap_cdr_decodes_with_mcap_ros2(tmp_path, flight):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    topics, truth = flight
    path = write_log(topics, tmp_path / "f.mcap")
    got = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, msg in reader.iter_decoded_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            got.setdefault(channel.topic, []).append((message.log_time, msg))
    stamps = np.array([m[0] for m in got["/mocap/pose"]]) / 1e9
    np.testing.assert_allclose(stamps, truth["t_pose"], atol=1e-9)
    np.testing.assert_array_equal([m.pose.position.z for _, m in got["/mocap/pose"]], truth["z"])
    header = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for _, m in got["/mocap/pose"]])
    np.testing.assert_allclose(header, truth["t_pose"], atol=1e-9)
    assert all(m.header.frame_id == "map" for _, m in got["/imu/data"])
    np.testing.assert_array_equal([m.data for _, m in got["/mrft/command"]], truth["cmd"])
    np.testing.assert_allclose([m.voltage for _, m in got["/battery"]], truth["volt"], rtol=1e-6)


def test_mcap_json_is_plain_json(tmp_path, flight):
    from mcap.reader import make_reader

    topics, truth = flight
    path = write_log(topics, tmp_path / "f.json.mcap")  # suffix selects mcap-json
    z = []
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=["/mocap/pose"]):
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            assert json.loads(schema.data)["properties"]["pose"]["type"] == "object"
            z.append(json.loads(message.data)["pose"]["position"]["z"])
    np.testing.assert_array_equal(z, truth["z"])


@pytest.mark.parametrize("fmt", ["bag", "ros2-sqlite3", "ros2-mcap"])
def test_bags_decode_with_rosbags_anyreader(tmp_path, flight, fmt):
    from rosbags.highlevel import AnyReader

    topics, truth = flight
    path = write_log(topics, log_filename(tmp_path / "f", fmt), fmt)
    assert path.is_dir() == (fmt != "bag")
    with AnyReader([path]) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert conns["/imu/data"].msgtype == "sensor_msgs/msg/Imu"
        q = [reader.deserialize(raw, c.msgtype).orientation
             for c, _, raw in reader.messages(connections=[conns["/imu/data"]])]
        stamps = [s for _, s, _ in reader.messages(connections=[conns["/mrft/command"]])]
        cmd = [reader.deserialize(raw, c.msgtype).data
               for c, _, raw in reader.messages(connections=[conns["/mrft/command"]])]
    from scipy.spatial.transform import Rotation

    euler = Rotation.from_quat([[o.x, o.y, o.z, o.w] for o in q]).as_euler("ZYX")
    np.testing.assert_allclose(euler[:, 2], truth["roll"], atol=1e-12)
    np.testing.assert_array_equal(cmd, truth["cmd"])
    np.testing.assert_allclose(np.array(stamps) / 1e9, truth["t"], atol=1e-9)


def test_ros1_bag_uses_ros1_type_names(tmp_path, flight):
    topics, _ = flight
    path = write_log(topics, tmp_path / "f.bag")
    raw = path.read_bytes()
    assert b"type=std_msgs/Float64" in raw and b"type=sensor_msgs/Imu" in raw
    assert b"/msg/" not in raw.split(b"type=sensor_msgs/Imu")[1][:5]


def test_ulog_reads_with_pyulog(tmp_path, flight):
    from pyulog import ULog

    topics, truth = flight
    path = write_log(topics, tmp_path / "f.ulg")
    ulog = ULog(str(path))
    assert not ulog.file_corruption
    pose = ulog.get_dataset("mocap_pose").data
    np.testing.assert_array_equal(pose["pose.position.z"], truth["z"])
    np.testing.assert_array_equal(pose["timestamp"], np.round(truth["t_pose"] * 1e6).astype(np.uint64))
    imu = ulog.get_dataset("imu_data").data
    assert set(imu) == {"timestamp", "orientation.x", "orientation.y", "orientation.z", "orientation.w"}
    np.testing.assert_array_equal(ulog.get_dataset("mrft_command").data["data"], truth["cmd"])
    assert ulog.msg_info_dict["sys_name"] == "mrft-ident"


def test_csv_layout_with_pandas(tmp_path, flight):
    topics, truth = flight
    path = write_log(topics, tmp_path / "f.csv")
    frame = pd.read_csv(path)
    assert frame.columns[0] == "__time"
    assert "/mocap/pose/pose/position/z" in frame.columns and "/imu/data/orientation/w" in frame.columns
    rows = frame["/mocap/pose/pose/position/z"].notna()
    np.testing.assert_allclose(frame.loc[rows, "__time"], truth["t_pose"], atol=1e-9)
    np.testing.assert_allclose(frame.loc[rows, "/mocap/pose/pose/position/z"], truth["z"], rtol=1e-9)
    assert len(frame) == len(np.unique(np.r_[truth["t"], truth["t_pose"], truth["t_imu"]]))


def test_quaternion_completion_and_defaults(tmp_path):
    """Fields not given are zero, quaternion w one (ROS writers) / completed (ULog, CSV)."""
    from mrftcli.io import open_log

    t = np.arange(5) * 0.1
    topics = [TopicData("/imu/data", "sensor_msgs/msg/Imu", t, {"orientation.x": np.zeros(5)})]
    for fmt in FORMATS:
        path = write_log(topics, log_filename(tmp_path / "q", fmt), fmt)
        with open_log(path) as log:
            _, leaves, vals = log.values("/imu/data", "orientation")
            assert len(leaves) == 4
            np.testing.assert_array_equal(vals[leaves[3]], 1.0)


def test_write_log_errors(tmp_path, flight):
    topics, _ = flight
    with pytest.raises(InputError, match="cannot tell the log format"):
        write_log(topics, tmp_path / "f.xyz")
    with pytest.raises(InputError, match="unknown log format"):
        write_log(topics, tmp_path / "f.mcap", fmt="hdf5")
    backwards = [TopicData("/a", "std_msgs/msg/Float64", np.array([1.0, 0.5]), {"data": np.zeros(2)})]
    with pytest.raises(InputError, match="non-decreasing"):
        write_log(backwards, tmp_path / "b.mcap")
    (tmp_path / "plain_dir").mkdir()
    with pytest.raises(InputError, match="not a ROS 2 bag"):
        write_log(topics, tmp_path / "plain_dir", fmt="ros2-sqlite3")
    path = write_log(topics, tmp_path / "again", fmt="ros2-mcap")
    write_log(topics, path, fmt="ros2-mcap")  # replacing an existing bag is allowed
    with pytest.raises(InputError, match="exists"):
        write_log(topics, path, fmt="ros2-mcap", overwrite=False)
    assert set(FORMAT_SUFFIX) == set(FORMATS)
