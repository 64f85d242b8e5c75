"""Readers: reference layout, topic options, quaternions, vectorised CDR decoding, third-party logs.

Oracles: the values written (round trips, see also test_writers.py), scipy's Rotation for the Euler
angles, rosbags' and mcap_ros2's own per-message decoders for the vectorised CDR walk, and the dump
files shipped with the third-party logs.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mrftcli.errors import InputError, LogReadError
from mrftcli.io.logtypes import TopicData
from mrftcli.io import (FORMATS, log_filename, open_log, read_flight, roll_pitch, write_log)
from mrftcli.io import ReadOptions, cdr
from mrftcli.io.msgtypes import typestore_for

SAMPLE = Path(__file__).resolve().parents[1] / "sample_logs"


def quaternion(roll, pitch, yaw):
    """(x, y, z, w) of R = Rz(yaw) Ry(pitch) Rx(roll), via scipy (independent of the reader)."""
    q = Rotation.from_euler("ZYX", np.c_[yaw, pitch, roll]).as_quat()  # scalar-last
    return q[:, 0], q[:, 1], q[:, 2], q[:, 3]


def synthetic_flight(n=300, rate=200.0, t0=50.0, seed=3, names=None, with_optional=True):
    """A small reference-layout flight and its true signals (a dict)."""
    names = names or {}
    rng = np.random.default_rng(seed)
    t = t0 + np.arange(n) / rate
    cmd = 0.45 + 0.08 * np.sign(np.sin(2 * np.pi * 1.7 * t)) + 1e-3 * rng.standard_normal(n)
    z = 1.2 + 0.03 * np.sin(2 * np.pi * 1.7 * t - 1.0) + 1e-3 * rng.standard_normal(n)
    roll = 0.2 * np.sin(2 * np.pi * 2.3 * t)
    pitch = -0.15 * np.cos(2 * np.pi * 1.1 * t)
    yaw = 0.7 + 0.1 * t / t[-1]
    x, y, zq, w = quaternion(roll, pitch, yaw)
    t_pose = t + 0.0013
    t_imu = t + 0.0021
    tb = t[::25]
    volt = 16.4 - 0.01 * np.arange(len(tb))
    topics = [
        TopicData(names.get("command", "/mrft/command"), "std_msgs/msg/Float64", t, {"data": cmd}),
        TopicData(names.get("pose", "/mocap/pose"), "geometry_msgs/msg/PoseStamped", t_pose,
                  {"pose.position.z": z, "pose.position.x": -z}),
        TopicData(names.get("imu", "/imu/data"), "sensor_msgs/msg/Imu", t_imu,
                  {"orientation.x": x, "orientation.y": y, "orientation.z": zq, "orientation.w": w}),
    ]
    if with_optional:
        topics += [
            TopicData("/mrft/beta", "std_msgs/msg/Float64", t[[10, n // 2]], {"data": np.array([-0.3, 0.2])}),
            TopicData("/mrft/setpoint", "std_msgs/msg/Float64", t[::50], {"data": np.full(len(t[::50]), 1.2)}),
            TopicData("/battery", "sensor_msgs/msg/BatteryState", tb, {"voltage": volt}),
        ]
    truth = dict(t=t, cmd=cmd, t_pose=t_pose, z=z, t_imu=t_imu, roll=roll, pitch=pitch, tb=tb, volt=volt)
    return topics, truth


# CSV keeps 10 significant digits; the binary formats are exact
TOL = {"csv": 1e-8}


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """The synthetic flight written once in every format."""
    base = tmp_path_factory.mktemp("logs")
    topics, truth = synthetic_flight()
    paths = {fmt: write_log(topics, log_filename(base / "flight", fmt), fmt) for fmt in FORMATS}
    return paths, truth


@pytest.mark.parametrize("fmt", FORMATS)
def test_reference_layout_every_format(logs, fmt):
    paths, truth = logs
    tol = TOL.get(fmt, 1e-12)
    alt = read_flight(paths[fmt], ReadOptions(loop="altitude"))
    np.testing.assert_allclose(alt.command.t, truth["t"], atol=1e-6)
    np.testing.assert_allclose(alt.command.values, truth["cmd"], atol=tol)
    np.testing.assert_allclose(alt.output.t, truth["t_pose"], atol=1e-6)
    np.testing.assert_allclose(alt.output.values, truth["z"], atol=tol)
    np.testing.assert_allclose(alt.beta.values, [-0.3, 0.2], atol=tol)
    np.testing.assert_allclose(alt.setpoint.values, 1.2, atol=tol)
    # BatteryState.voltage is float32 in ROS; ULog/CSV keep what was given
    np.testing.assert_allclose(alt.battery_voltage.values, truth["volt"], rtol=1e-6)
    assert alt.warnings == ()
    for loop in ("roll", "pitch"):
        fl = read_flight(paths[fmt], ReadOptions(loop=loop))
        np.testing.assert_allclose(fl.output.t, truth["t_imu"], atol=1e-6)
        np.testing.assert_allclose(fl.output.values, truth[loop], atol=max(tol, 1e-12) * 10)
        assert np.all(np.diff(fl.output.t) >= 0)
        assert fl.output.t.dtype == fl.output.values.dtype == np.float64


def test_roll_pitch_matches_scipy():
    rng = np.random.default_rng(7)
    q = Rotation.random(500, random_state=rng).as_quat()
    scale = rng.uniform(0.5, 2.0, size=500)  # not normalised on purpose
    roll, pitch = roll_pitch(*(q.T * scale))
    yaw_ref, pitch_ref, roll_ref = Rotation.from_quat(q).as_euler("ZYX").T
    np.testing.assert_allclose(pitch, pitch_ref, atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (roll - roll_ref))), 0.0, atol=1e-9)
    with pytest.raises(LogReadError, match="zero"):
        roll_pitch(np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2))


def test_topic_options_other_layout(tmp_path):
    """Other topic names, fields and rates: everything reachable through TOPIC[:FIELD] options."""
    rng = np.random.default_rng(11)
    t_cmd = 10 + np.arange(200) / 100.0  # 100 Hz
    t_od = 10 + np.arange(120) / 60.0    # 60 Hz
    cmd = rng.normal(size=200)
    alt = rng.normal(size=120)
    roll = 0.1 * rng.normal(size=120)
    x, y, z, w = quaternion(roll, 0 * roll, 0 * roll + 2.0)
    topics = [
        TopicData("/uav1/thrust", "std_msgs/msg/Float64", t_cmd, {"data": cmd}),
        TopicData("/uav1/odom", "geometry_msgs/msg/PoseStamped", t_od,
                  {"pose.position.z": alt, "pose.orientation.x": x, "pose.orientation.y": y,
                   "pose.orientation.z": z, "pose.orientation.w": w}),
        TopicData("/uav1/test_beta", "std_msgs/msg/Float64", t_cmd[:1], {"data": np.array([0.4])}),
    ]
    for fmt in ("mcap", "bag", "ulog", "csv"):
        path = write_log(topics, log_filename(tmp_path / "other", fmt), fmt)
        fl = read_flight(path, ReadOptions(loop="altitude", command_topic="/uav1/thrust", output_topic="/uav1/odom:pose.position.z", beta_topic="/uav1/test_beta:data", output_scale=-1.0))
        np.testing.assert_allclose(fl.command.values, cmd, atol=1e-8)
        np.testing.assert_allclose(fl.output.values, -alt, atol=1e-8)
        np.testing.assert_allclose(fl.output.t, t_od, atol=1e-6)
        assert fl.beta.values[0] == pytest.approx(0.4)
        assert fl.setpoint is None and fl.battery_voltage is None  # defaults absent: no error
        rl = read_flight(path, ReadOptions(loop="roll", command_topic="/uav1/thrust:data", output_topic="/uav1/odom:pose.orientation"))
        np.testing.assert_allclose(rl.output.values, roll, atol=1e-8)
        with pytest.raises(LogReadError, match="orientation quaternion"):
            read_flight(path, ReadOptions(loop="altitude", command_topic="/uav1/thrust", output_topic="/uav1/odom:pose.orientation"))


def test_default_optional_topic_of_another_type_is_skipped(tmp_path):
    t = np.arange(50) * 0.01
    topics = [TopicData("/mrft/command", "std_msgs/msg/Float64", t, {"data": np.ones(50)}),
              TopicData("/mocap/pose", "geometry_msgs/msg/PoseStamped", t, {"pose.position.z": t}),
              TopicData("/battery", "std_msgs/msg/Float64", t, {"data": np.full(50, 15.0)})]
    path = write_log(topics, tmp_path / "b.mcap")
    fl = read_flight(path)
    assert fl.battery_voltage is None
    assert len(fl.warnings) == 1 and "ignored /battery:voltage" in fl.warnings[0]
    fl = read_flight(path, ReadOptions(battery_topic="/battery"))  # named: read as asked
    assert fl.battery_voltage.values[0] == 15.0 and fl.warnings == ()
    with pytest.raises(InputError, match="output scale"):
        read_flight(path, ReadOptions(output_scale=0.0))


def test_missing_topics_and_fields(logs):
    paths, _ = logs
    mcap = paths["mcap"]
    with pytest.raises(LogReadError, match=r"no topic '/mrft/comand'.*did you mean /mrft/command\?") as err:
        read_flight(mcap, ReadOptions(command_topic="/mrft/comand"))
    assert str(mcap) in str(err.value) and "/imu/data" in str(err.value)
    with pytest.raises(LogReadError, match=r"no field 'pose\.position\.q'.*fields there: x, y, z"):
        read_flight(mcap, ReadOptions(output_topic="/mocap/pose:pose.position.q"))
    with pytest.raises(LogReadError, match="no topic '/beta2'"):  # a named optional topic must exist
        read_flight(mcap, ReadOptions(beta_topic="/beta2"))
    with pytest.raises(InputError, match="unknown loop"):
        read_flight(mcap, ReadOptions(loop="yaw"))
    with pytest.raises(LogReadError, match="pose.position"):
        read_flight(mcap, ReadOptions(output_topic="/mocap/pose:pose.position"))  # a struct, not a number
    with pytest.raises(LogReadError, match="no column"):
        read_flight(paths["csv"], ReadOptions(output_topic="/mocap/pose:pose.position.q"))
    with pytest.raises(LogReadError, match="no field 'zz'"):
        read_flight(paths["ulog"], ReadOptions(output_topic="/mocap/pose:zz"))


def test_series_and_topics_api(logs, tmp_path):
    paths, truth = logs
    with open_log(paths["bag"]) as log:
        assert log.format == "bag"
        info = {i.name: i for i in log.topics()}
        assert info["/imu/data"].msgtype == "sensor_msgs/msg/Imu"
        assert info["/imu/data"].count == len(truth["t"])
        assert info["/imu/data"].rate_hz == pytest.approx(200.0, rel=1e-6)
        assert "pose.position.z" in info["/mocap/pose"].fields
        s = log.series("/mocap/pose", "pose.position.x")
        np.testing.assert_allclose(s.values, -truth["z"])
        with pytest.raises(LogReadError, match="quaternion"):
            log.series("/imu/data", "orientation")
    for fmt in FORMATS:
        with open_log(paths[fmt]) as log:
            assert log.format == fmt
    # a ROS 2 bag's storage file on its own (the sqlite3 one is written zstd-compressed)
    import zstandard

    packed = next(paths["ros2-sqlite3"].glob("*.db3.zstd"))
    plain = tmp_path / "alone.db3"
    plain.write_bytes(zstandard.ZstdDecompressor().decompress(packed.read_bytes(),
                                                               max_output_size=1 << 30))
    for storage, expect in ((plain, "ros2-sqlite3"), (next(paths["ros2-mcap"].glob("*.mcap")), "mcap")):
        fl = read_flight(storage, ReadOptions(loop="pitch"))
        assert fl.source["format"] == expect
        np.testing.assert_allclose(fl.output.values, truth["pitch"], atol=1e-12)


def test_cdr_walk_matches_library_decoders():
    """The vectorised walk against rosbags' (both encodings) and mcap_ros2's decoders."""
    from mcap_ros2._dynamic import generate_dynamic

    rng = np.random.default_rng(5)
    for ros1 in (False, True):
        ts = typestore_for(ros1=ros1)
        raw, expect = [], []
        for i in range(40):
            msg = cdr.default_message(ts, "sensor_msgs/msg/BatteryState", "f" * int(rng.integers(0, 11)))
            msg.voltage = float(rng.normal())
            msg.cell_voltage = rng.normal(size=int(rng.integers(0, 5))).astype(np.float32)
            msg.location = "x" * int(rng.integers(0, 7))
            msg.header.stamp.sec = i
            little = bool(ros1 or i % 3)
            data = (ts.serialize_ros1(msg, "sensor_msgs/msg/BatteryState") if ros1 else
                    ts.serialize_cdr(msg, "sensor_msgs/msg/BatteryState", little_endian=little))
            raw.append(bytes(data))
            cells = list(msg.cell_voltage) + [np.nan] * 5
            expect.append([np.float32(msg.voltage), i, cells[1]])
        lengths = np.array([len(r) for r in raw])
        starts = np.r_[0, np.cumsum(lengths)[:-1]]
        got = cdr.extract(ts, "sensor_msgs/msg/BatteryState", np.frombuffer(b"".join(raw), np.uint8),
                           starts, lengths, ["voltage", "header.stamp.sec", "cell_voltage[1]"], ros1=ros1)
        np.testing.assert_array_equal(np.c_[got["voltage"], got["header.stamp.sec"], got["cell_voltage[1]"]],
                                      np.array(expect, dtype=np.float64))
    # mcap_ros2's own decoder on what serialize_many writes (odd frame_id lengths shift the alignment)
    ts = typestore_for()
    t = np.arange(7) * 0.01
    z = rng.normal(size=7)
    text = ts.generate_msgdef("geometry_msgs/msg/PoseStamped", ros_version=2)[0]
    decode = generate_dynamic("geometry_msgs/msg/PoseStamped", text)["geometry_msgs/msg/PoseStamped"]
    for frame in ("", "a", "abc", "abcdefg"):
        for k, data in enumerate(cdr.serialize_many(ts, "geometry_msgs/msg/PoseStamped", t,
                                                     {"pose.position.z": z}, frame_id=frame)):
            msg = decode(data)
            assert msg.pose.position.z == z[k] and msg.pose.orientation.w == 1.0
            assert msg.header.frame_id == frame and msg.header.stamp.nanosec == round(t[k] * 1e9) % 10**9


def test_px4_ulog(shared_dir):
    path = shared_dir / "data" / "third_party_logs" / "px4_sample_log_small.ulg"
    with open_log(path) as log:
        assert log.format == "ulog"
        names = {i.name: i for i in log.topics()}
        assert {"vehicle_attitude", "actuator_controls_0", "battery_status.1"} <= set(names)
        assert names["vehicle_attitude"].count == 1298
        # the text messages the autopilot logged, as listed in the file beside the log
        listed = (shared_dir / "data" / "third_party_logs" / "px4_sample_log_small_messages.txt")
        expect = [re.match(r"(\d+):(\d\d):(\d\d) (\w+): (.*)", line).groups()
                  for line in listed.read_text().splitlines() if line.strip()]
        got = log.logged_messages()
        assert len(got) == len(expect)
        for (t, level, text), (h, m, s, level_ref, text_ref) in zip(got, expect):
            assert int(t) == int(h) * 3600 + int(m) * 60 + int(s)
            assert (level, text) == (level_ref, text_ref)
    # PX4 stores q as (w, x, y, z): roll from the reader equals scipy's on the raw array
    from pyulog import ULog

    raw = ULog(str(path), ["vehicle_attitude"]).get_dataset("vehicle_attitude").data
    q = np.c_[raw["q[1]"], raw["q[2]"], raw["q[3]"], raw["q[0]"]]
    fl = read_flight(path, ReadOptions(loop="pitch", command_topic="actuator_controls_0:control[1]", output_topic="vehicle_attitude:q"))
    np.testing.assert_allclose(fl.output.values, Rotation.from_quat(q).as_euler("ZYX")[:, 1], atol=1e-6)
    np.testing.assert_allclose(fl.output.t, raw["timestamp"] / 1e6)
    assert fl.beta is None and fl.battery_voltage is None
    assert fl.warnings == ()  # a whole PX4 log is not flagged as damaged


def test_ardupilot_dataflash(shared_dir):
    path = shared_dir / "data" / "third_party_logs" / "ardupilot_plane_test.BIN"
    dump = (path.parent / (path.name + ".dumped")).read_text()
    with open_log(path) as log:
        assert log.format == "dataflash"
        names = {i.name: i for i in log.topics()}
        for name in ("ATT", "BAT", "CTUN", "IMU", "AHR2"):
            assert names[name].count == len(re.findall(rf": {name} {{", dump))
        for topic, column in (("ATT", "Roll"), ("BAT", "Volt"), ("CTUN", "ThrOut"), ("AHR2", "Alt")):
            rows = re.findall(rf": {topic} {{TimeUS : (\d+),.*? {column} : ([-\d.e]+)", dump)
            ref = np.array(rows, dtype=float)
            s = log.series(topic, column)
            np.testing.assert_allclose(s.t, ref[:, 0] / 1e6, rtol=0, atol=1e-9)
            np.testing.assert_allclose(s.values, ref[:, 1], rtol=1e-6)
    fl = read_flight(path, ReadOptions(loop="roll", command_topic="RCOU:C1", output_topic="ATT:Roll", output_scale=math.pi / 180))
    assert np.abs(fl.output.values).max() < math.pi


def test_every_third_party_file_is_read(shared_dir):
    """Whatever lies in third_party_logs (apart from the dumps/listings beside the logs) opens and
    lists topics with messages."""
    folder = shared_dir / "data" / "third_party_logs"
    logs = [p for p in sorted(folder.iterdir()) if p.suffix not in (".txt", ".dumped")]
    assert len(logs) >= 2
    for path in logs:
        with open_log(path) as log:
            infos = log.topics()
            assert infos and sum(i.count for i in infos) > 100, path
            busiest = max(infos, key=lambda i: i.count)
            assert busiest.rate_hz is not None and busiest.rate_hz > 0


def test_custom_message_type_from_the_mcap_schema(tmp_path):
    """A type the standard definitions do not know is decoded from the schema the file carries,
    with a string and a sequence of structs before the wanted fields (checked with mcap_ros2)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from mcap_ros2.writer import Writer as Ros2Writer

    text = ("string note\ngeometry_msgs/Point[] waypoints\nfloat32 thrust\nfloat64 alt\n"
            "================================================================================\n"
            "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n")
    rng = np.random.default_rng(2)
    path = tmp_path / "custom.mcap"
    with open(path, "wb") as f:
        writer = Ros2Writer(f)
        schema = writer.register_msgdef("my_pkg/msg/Drone", text)
        for i in range(60):
            msg = {"note": "n" * int(rng.integers(0, 6)),
                   "waypoints": [{"x": 1.0, "y": 2.0, "z": float(k)} for k in range(int(rng.integers(0, 4)))],
                   "thrust": float(i) * 0.25, "alt": float(rng.normal())}
            writer.write_message("/drone", schema, msg, log_time=10**9 + i * 10**7)
        writer.finish()
    with open(path, "rb") as f:
        ref = [(m.log_time, d.thrust, d.alt) for _, _, m, d in
               make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]
    ref = np.array(ref, dtype=float)
    fl = read_flight(path, ReadOptions(command_topic="/drone:thrust", output_topic="/drone:alt"))
    np.testing.assert_array_equal(fl.command.values, ref[:, 1])
    np.testing.assert_array_equal(fl.output.values, ref[:, 2])
    np.testing.assert_allclose(fl.output.t, ref[:, 0] / 1e9)
    with open_log(path) as log:
        (info,) = log.topics()
        assert info.msgtype == "my_pkg/msg/Drone" and "thrust" in info.fields
        z1 = log.series("/drone", "waypoints[1].z")  # element of a sequence of structs
    with open(path, "rb") as f:
        expect = [d.waypoints[1].z if len(d.waypoints) > 1 else np.nan for _, _, _, d in
                  make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]
    np.testing.assert_array_equal(z1.values, expect)
    assert np.isnan(expect).any() and not np.isnan(expect).all()


@pytest.mark.parametrize("index", ["CHUNK", "NONE"])
def test_mcap_without_message_index_records(tmp_path, index):
    # Message Index records (and, with NONE, the whole summary's indexes) are optional in MCAP; a
    # file written without them must read the same as the shipped one
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, IndexType, Writer

    src = SAMPLE / "design1_altitude.mcap"
    out = tmp_path / "no_index.mcap"
    with open(src, "rb") as f_in, open(out, "wb") as f_out:
        reader = make_reader(f_in)
        summary = reader.get_summary()
        w = Writer(f_out, index_types=getattr(IndexType, index), compression=CompressionType.ZSTD)
        w.start(profile=reader.get_header().profile, library="test")
        sids = {sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
        cids = {cid: w.register_channel(c.topic, c.message_encoding, sids.get(c.schema_id, 0), c.metadata)
                for cid, c in summary.channels.items()}
        for _, ch, m in reader.iter_messages():
            w.add_message(cids[ch.id], m.log_time, m.data, m.publish_time, m.sequence)
        w.finish()
    a, b = read_flight(src, ReadOptions(loop="altitude")), read_flight(out, ReadOptions(loop="altitude"))
    for x, y in ((a.command, b.command), (a.output, b.output)):
        assert np.array_equal(x.t, y.t)
        assert np.array_equal(x.values, y.values)
    counts = {t.name: t.count for t in open_log(out).topics()}
    assert counts == {t.name: t.count for t in open_log(src).topics()}


def test_signal_holds_float_arrays_of_one_length():
    from mrftcli.io import Signal

    s = Signal([0, 1, 2], np.array([1, 2, 3], dtype=np.int32))
    assert s.t.dtype == s.values.dtype == np.float64 and len(s) == 3
    with pytest.raises(InputError, match="one length"):
        Signal([0.0, 1.0], [1.0])
