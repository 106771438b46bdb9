"""Rigs (several radars on one vehicle): round trip, merge by time, refusals naming file and field."""

from __future__ import annotations

import numpy as np
import pytest

from rodo.estimator.errors import InputError
from rodo.sim.rig import RIG_TOML, Rig, is_rig, merged_groundtruth, read_rig, write_rig
from rodo.sim.sequence import NoiseSigmas, RadarScan, SensorConfig, Sequence, Trajectory, read_sequence


def _radar(yaw: float, times, gt: bool = True) -> Sequence:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[:3, 3] = [3.5 * np.cos(yaw), 0.8 * np.sin(yaw), 0.5]
    cfg = SensorConfig(13.0, T, NoiseSigmas(0.1, 0.01, 0.02, 0.1), (-1.0, 1.0), (-0.2, 0.2), 100.0)
    scans = [RadarScan(k, float(t), [10.0 + k, 20.0], [0.1, -0.2], [0.0, 0.05], [-1.0, 2.0])
             for k, t in enumerate(times)]
    poses = np.tile(np.eye(4), (len(times), 1, 1))
    poses[:, 0, 3] = 10.0 * np.asarray(times)
    return Sequence(cfg, scans, Trajectory(np.asarray(times, float), poses) if gt else None)


def test_round_trip_and_merge(tmp_path):
    front, left = _radar(0.0, [0.0, 0.1, 0.2]), _radar(np.pi / 2, [0.05, 0.15])
    gt = Trajectory(np.array([0.0, 0.25]), np.tile(np.eye(4), (2, 1, 1)))
    write_rig(tmp_path / "rig", Rig(["front", "left"], [front, left], gt))
    assert is_rig(tmp_path / "rig") and not is_rig(tmp_path / "rig" / "front")
    back = read_rig(tmp_path / "rig", use_cache=False)
    assert back.names == ["front", "left"]
    np.testing.assert_allclose(back.sequences[1].sensor.T_vehicle_sensor, left.sensor.T_vehicle_sensor, atol=1e-15)
    np.testing.assert_array_equal(back.groundtruth.t, gt.t)
    assert [(t, i) for t, i, _ in back.scans()] == [(0.0, 0), (0.05, 1), (0.1, 0), (0.15, 1), (0.2, 0)]
    # every radar stays a sequence of its own
    assert len(read_sequence(tmp_path / "rig" / "left").scans) == 2
    # without the rig's ground truth: the radars' own, merged by time
    back.groundtruth = None
    np.testing.assert_array_equal(merged_groundtruth(back).t, [0.0, 0.05, 0.1, 0.15, 0.2])


def test_two_radars_at_one_instant_are_refused(tmp_path):
    rig = Rig(["a", "b"], [_radar(0.0, [0.0, 0.1]), _radar(1.0, [0.1, 0.2])])
    with pytest.raises(InputError, match="radars 'a' and 'b' both have a scan at t = 0.1"):
        rig.scans()


@pytest.mark.parametrize("text, message", [
    ("sensors = [", "not valid TOML"),
    ("radars = ['a']", "unknown key"),
    ("sensors = []", "field 'sensors'"),
    ("sensors = ['/abs']", "not a sub-directory name"),
    ("sensors = ['" + "/".join(["..", "a"]) + "']", "not a sub-directory name"),  # a parent path
    ("sensors = ['a', 'a']", "listed twice"),
    ("sensors = ['missing']", "not a sequence directory"),
])
def test_bad_rig_toml_names_the_file(tmp_path, text, message):
    write_rig(tmp_path, Rig(["a"], [_radar(0.0, [0.0])]))
    (tmp_path / RIG_TOML).write_text(text)
    with pytest.raises(InputError, match=message) as err:
        read_rig(tmp_path)
    assert str(tmp_path) in str(err.value)


def test_not_a_rig(tmp_path):
    with pytest.raises(InputError, match="not a rig directory"):
        read_rig(tmp_path)
