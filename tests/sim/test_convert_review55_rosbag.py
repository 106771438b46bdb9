"""`rodo convert rosbag` input a review found accepted silently or refused without naming the bag (review 55,
findings 5, 6 and 10): polar azimuths in degrees, messages without points, duplicate record times, stamps
that give no radar's scan rate. Exit 2 with one line naming the bag, topic, message or field."""

from __future__ import annotations

import numpy as np
import pytest

from tests.sim.test_convert import _rng
from tests.sim.test_convert_review55 import _fails

pytest.importorskip("rosbags", reason="the rosbag converter needs rosbags (pip install rosbags)")
from tests.sim.test_convert_rosbag import _static_scene, _write_bag  # noqa: E402


def test_duplicate_record_times_name_bag_topic_message_and_time(tmp_path, capsys):
    """Finding 10: 'seq.scans[2]: scan index and time must strictly increase', naming no bag or message."""
    scenes = [(_static_scene(_rng(40 + k), 5, np.ones(3)), 0) for k in range(4)]
    record = [10**18, 10**18 + 10**8, 10**18 + 10**8, 10**18 + 3 * 10**8]
    bag = _write_bag(tmp_path / "bag", "sqlite3", scenes, record_ns=record)
    _fails(["convert", "rosbag", bag, "--topic", "/radar", "--out", tmp_path / "o"], capsys,
           f"{bag}, topic /radar, message 2", "record time", str(10**18 + 10**8), "--time")
    assert not (tmp_path / "o").exists()


def test_header_stamps_in_another_unit_name_the_bag(tmp_path, capsys):
    """Stamps 100 ns apart (a driver writing ms into nanosec): refused naming the bag, not SensorConfig."""
    scenes = [(_static_scene(_rng(45 + k), 5, np.ones(3)), 10**18 + 100 * k) for k in range(4)]
    bag = _write_bag(tmp_path / "bag", "mcap", scenes)
    err = _fails(["convert", "rosbag", bag, "--topic", "/radar", "--out", tmp_path / "o"], capsys,
                 f"{bag}, topic /radar", "header stamp", "median step 100 ns", "milliseconds?")
    assert "SensorConfig" not in err


def test_polar_azimuths_in_degrees_are_refused(tmp_path, capsys):
    """Finding 5 (--polar): most rows dropped as out of range, the rest (degrees read as radians) kept."""
    rng = _rng(50)
    clouds = []
    for k in range(3):
        n = 20
        f = {"range": rng.uniform(1, 50, n), "azimuth": np.rad2deg(rng.uniform(-1, 1, n)),
             "elevation": rng.uniform(-0.2, 0.2, n), "velocity": rng.uniform(-5, 5, n)}
        clouds.append((f, 10**18 + 10**8 * k))
    bag = _write_bag(tmp_path / "bag", "sqlite3", clouds)
    _fails(["convert", "rosbag", bag, "--topic", "/radar", "--polar", "range,azimuth,elevation",
            "--out", tmp_path / "o"], capsys, f"{bag}, topic /radar, message ", "field 'azimuth'", "degrees")
    assert not (tmp_path / "o").exists()


def test_messages_without_points_name_the_bag(tmp_path, capsys):
    """Finding 6: every message empty gave an empty sequence with exit 0."""
    empty = {k: v[:0] for k, v in _static_scene(_rng(51), 3, np.ones(3)).items()}
    bag = _write_bag(tmp_path / "bag", "sqlite3", [(empty, 10**18 + 10**8 * k) for k in range(3)])
    _fails(["convert", "rosbag", bag, "--topic", "/radar", "--out", tmp_path / "o"], capsys,
           f"{bag}, topic /radar: no detections")
