"""``mrft-ident topics``: table, --fields, --json, --format; errors (exit codes via subprocess in
test_readers_broken.py)."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from mrftcli.cli.main import cli
from mrftcli.io import log_filename, write_log
from test_readers import synthetic_flight


@pytest.fixture(scope="module")
def bag_and_csv(tmp_path_factory):
    base = tmp_path_factory.mktemp("topics")
    topics, truth = synthetic_flight(n=201)
    return {fmt: write_log(topics, log_filename(base / "t", fmt), fmt) for fmt in ("ros2-mcap", "csv")}


def test_table_and_fields(bag_and_csv):
    result = CliRunner().invoke(cli, ["topics", str(bag_and_csv["ros2-mcap"]), "--fields"])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert "(ros2-mcap, 6 topics)" in lines[0]
    assert lines[1] == "layout: reference (auto-detected: /mrft/command)"
    assert lines[2].split() == ["topic", "type", "count", "rate_hz"]
    row = next(line for line in lines if line.startswith("/imu/data"))
    assert row.split() == ["/imu/data", "sensor_msgs/msg/Imu", "201", "200.0"]
    beta = next(line for line in lines if line.startswith("/mrft/beta"))
    # two messages, at samples 10 and n // 2 = 100 of a 200 Hz clock: (2 - 1) / 0.45 s
    assert beta.split()[-2:] == ["2", f"{200 / 90:.1f}"]
    assert any("fields:" in line and "pose.position.z" in line for line in lines)


def test_json(bag_and_csv):
    result = CliRunner().invoke(cli, ["topics", str(bag_and_csv["csv"]), "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.output)
    assert doc["format"] == "csv" and doc["warnings"] == []
    cols = {t["name"]: t for t in doc["topics"]}
    assert cols["/mocap/pose/pose/position/z"]["count"] == 201
    assert cols["/mocap/pose/pose/position/z"]["rate_hz"] == pytest.approx(200.0)
    assert cols["/mrft/setpoint/data"]["count"] == 5


def test_explicit_format_and_unknown_format(bag_and_csv, tmp_path):
    result = CliRunner().invoke(cli, ["topics", str(bag_and_csv["csv"]), "--format", "csv"])
    assert result.exit_code == 0
    result = CliRunner().invoke(cli, ["topics", str(bag_and_csv["csv"]), "--format", "hdf5"])
    assert result.exit_code != 0 and "unknown log format" in str(result.exception)
