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


def test_a_directory_that_is_a_rig_and_a_sequence_is_refused(tmp_path):
    """rig.toml beside a radar.csv: `is_rig` and `read_sequence` refuse it alike, naming the directory, instead of
    each command picking one (a run of the rig scored against the single sequence's ground truth)."""
    from rodo.sim.sequence import write_sequence

    write_rig(tmp_path, Rig(["a"], [_radar(0.0, [0.0, 0.1])]))
    write_sequence(tmp_path, _radar(0.5, [0.0, 0.1, 0.2]))
    for call in (is_rig, read_sequence):
        with pytest.raises(InputError, match="both a rig .rig.toml. and a single sequence .radar.csv.") as err:
            call(tmp_path)
        assert str(tmp_path) in str(err.value)
    assert is_rig(tmp_path / "a") is False and len(read_sequence(tmp_path / "a").scans) == 2


def test_a_simulated_rig_is_one_drive_seen_by_radars_taking_turns(tmp_path):
    """`scenarios.simulate_rig_to`: the front radar is the single-radar simulation bit for bit, the corner radars
    have their layout's mounts and scan i / (n rate) s later, and the rig reads back and merges without two
    scans at one instant; each radar's ground truth is the same drive."""
    from rodo import scenarios
    from rodo.sim.rig import LAYOUTS

    radars = scenarios.simulate_rig_to("highway", 3, tmp_path / "rig", "front-corners", 2.0)
    scenarios.simulate_to("highway", 3, tmp_path / "single", 2.0)
    assert (tmp_path / "rig" / "front" / "radar.csv").read_bytes() == (tmp_path / "single" / "radar.csv").read_bytes()
    rig = read_rig(tmp_path / "rig", use_cache=False)
    assert rig.names == [name for name, _ in LAYOUTS["front-corners"]] == [r[0] for r in radars]
    n, rate = len(rig.names), rig.sequences[0].sensor.rate_hz
    for i, (seq, (_, mount)) in enumerate(zip(rig.sequences, LAYOUTS["front-corners"])):
        t = np.array([s.t for s in seq.scans])
        np.testing.assert_allclose(t[:3], i / (n * rate) + np.arange(3) / rate, atol=1e-12)
        if mount is not None:
            np.testing.assert_allclose(seq.sensor.T_vehicle_sensor, mount, atol=1e-12)
        assert len(seq.scans[1].range) > 50  # each radar sees the scene
    merged = rig.scans()
    assert len({t for t, _, _ in merged}) == len(merged) == sum(len(s.scans) for s in rig.sequences)
    gt = merged_groundtruth(rig)
    single = read_sequence(tmp_path / "single", use_cache=False).groundtruth
    np.testing.assert_array_equal(gt.T_world_vehicle[::n], single.T_world_vehicle[:len(gt.t[::n])])


def test_unknown_layout_is_refused_listing_the_known_ones():
    from rodo import scenarios

    with pytest.raises(InputError, match="unknown layout 'rear'; known layouts: front-corners"):
        scenarios.get("city").simulate_rig(0, "rear", 1.0)


def test_faults_on_a_rig_draw_per_radar(tmp_path):
    """Faults apply to every radar of a simulated rig: the front radar's is the single-radar simulation with the
    same faults, bit for bit; the corner radars draw their own (their common Doppler errors differ)."""
    from rodo import scenarios
    from rodo.sim.faults import parse_faults

    faults = parse_faults(["doppler_common=0.05:0.9", "dropped=0.1"])
    radars = scenarios.simulate_rig_to("highway", 3, tmp_path / "rig", "front-corners", 2.0, faults=faults)
    scenarios.simulate_to("highway", 3, tmp_path / "single", 2.0, faults=faults)
    clean = scenarios.simulate_to("highway", 3, tmp_path / "clean", 2.0)[1]
    assert (tmp_path / "rig" / "front" / "radar.csv").read_bytes() == (tmp_path / "single" / "radar.csv").read_bytes()
    assert (tmp_path / "single" / "radar.csv").read_bytes() != (tmp_path / "clean" / "radar.csv").read_bytes()
    drops = [truth["fault_dropped"] for _, _, truth in radars]
    assert not np.array_equal(drops[1], drops[2]) and clean["t"].shape == radars[0][2]["t"].shape
