"""simulate(): sequence + truth consistency, empty scans kept, deterministic bytes, read-back."""

from dataclasses import replace

import numpy as np
import pytest

from rodo.estimator.lie import se3
from rodo.sim import trajectory as tr
from rodo.sim import world as w
from rodo.sim.radar import RadarConfig
from rodo.sim.sequence import polar_to_cartesian, read_sequence, read_tum
from rodo.sim.simulate import load_truth, save_npz, scan_times, simulate, write_simulation


@pytest.fixture(scope="module")
def small():
    profile = tr.city(np.random.default_rng(0), 12.0)
    world = w.build_world(np.random.default_rng(1), tr.route_of(profile), w.CITY)
    world = world.with_movers([w.oncoming_vehicle(profile, 10**6, 4.0)]).with_blackouts([(2.0, 2.5)])
    return profile, world


def _run(small, seed, cfg=None, duration=4.0):
    profile, world = small
    return simulate(world, profile, cfg or RadarConfig(), np.random.default_rng(seed), duration)


def test_truth_is_consistent_with_the_sequence(small):
    cfg = RadarConfig().noise_free()
    seq, truth = _run(small, 0, cfg)
    K = len(scan_times(4.0, 13.0))
    assert len(seq.scans) == K == len(truth["t"]) == len(seq.groundtruth.t)
    np.testing.assert_allclose(se3.inverse(truth["T_vehicle_world"]), seq.groundtruth.T_world_vehicle, atol=1e-12)
    off = truth["scan_offsets"]
    assert off[-1] == len(truth["det_label"]) == sum(len(s.range) for s in seq.scans)
    # noise-free: every detection maps back to its true scatterer through the true pose
    for k in (0, K // 2, K - 1):
        sc = seq.scans[k]
        T_world_sensor = seq.groundtruth.T_world_vehicle[k] @ cfg.T_vehicle_sensor
        p = se3.transform_points(T_world_sensor, polar_to_cartesian(sc.range, sc.azimuth, sc.elevation))
        np.testing.assert_allclose(p, truth["det_p_world"][off[k]:off[k + 1]], atol=1e-9)
    assert set(np.unique(truth["det_label"])) <= {0, 1, 2}
    assert (truth["det_label"] == 2).any()  # the oncoming car is seen


def test_blackout_scans_are_empty_but_present(small, tmp_path):
    seq, truth = _run(small, 0)
    t = truth["t"]
    blocked = (t >= 2.0) & (t <= 2.5)
    assert blocked.sum() >= 6
    counts = np.diff(truth["scan_offsets"])
    assert np.all(counts[blocked] == 0) and np.all(counts[~blocked] > 100)
    write_simulation(tmp_path / "seq", seq, truth)
    gt = read_tum(tmp_path / "seq" / "groundtruth.txt")
    assert len(gt.t) == len(t)
    back = read_sequence(tmp_path / "seq", use_cache=False)
    assert len(back.scans) == (~blocked).sum()
    k = np.flatnonzero(~blocked)[3]
    np.testing.assert_array_equal(back.scans[3].range, seq.scans[k].range)
    loaded = load_truth(tmp_path / "seq")
    assert set(loaded) == set(truth)
    np.testing.assert_array_equal(loaded["det_object_id"], truth["det_object_id"])


def test_same_seed_same_bytes_other_seed_differs(small, tmp_path):
    a, b, c = (tmp_path / n for n in "abc")
    for d, seed in ((a, 5), (b, 5), (c, 6)):
        write_simulation(d, *_run(small, seed, duration=1.0))
    for name in ("radar.csv", "sensor.toml", "groundtruth.txt", "truth.npz"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert (a / "radar.csv").read_bytes() != (c / "radar.csv").read_bytes()


def test_save_npz_is_deterministic(tmp_path):
    arrays = {"x": np.arange(5.0), "y": np.eye(3, dtype=np.int8)}
    save_npz(tmp_path / "1.npz", arrays)
    save_npz(tmp_path / "2.npz", dict(reversed(list(arrays.items()))))
    assert (tmp_path / "1.npz").read_bytes() == (tmp_path / "2.npz").read_bytes()


def test_noise_free_sensor_file_has_positive_sigmas(small):
    cfg = replace(RadarConfig(), sigmas=(0.0, 0.0, 0.0, 0.0))
    assert np.all(cfg.sensor_config().noise.as_array() > 0)


def test_truth_twist_explains_static_radial_velocities(small):
    """Per docs/conventions.md: p_vehicle = T p_world, dp_vehicle/dt = nu + omega x p_vehicle,
    v_r = u . C_vehicle_sensor^T dp_vehicle/dt."""
    cfg = RadarConfig().noise_free()
    seq, truth = _run(small, 1, cfg, duration=3.0)
    C_vehicle_sensor = cfg.T_vehicle_sensor[:3, :3]
    off = truth["scan_offsets"]
    checked = 0
    for k in range(0, len(truth["t"]), 5):
        sl = slice(off[k], off[k + 1])
        static = truth["det_label"][sl] < 2
        p_vehicle = se3.transform_points(truth["T_vehicle_world"][k], truth["det_p_world"][sl][static])
        varpi = truth["varpi"][k]
        dps = (varpi[:3] + np.cross(varpi[3:], p_vehicle)) @ C_vehicle_sensor
        sc = seq.scans[k]
        u = polar_to_cartesian(1.0, sc.azimuth[static], sc.elevation[static])
        np.testing.assert_allclose(sc.radial_velocity[static], np.einsum("ij,ij->i", u, dps), atol=1e-9)
        checked += static.sum()
    assert checked > 500


def test_moving_detections_radial_velocity_is_range_rate(small):
    """End to end: for detections on the oncoming car, v_r equals the finite-difference rate of the range of
    the same body point, with both the ego and the car moving along their trajectories."""
    profile, world = small
    cfg = RadarConfig().noise_free()
    seq, truth = _run(small, 2, cfg, duration=4.0)
    mover = world.movers[0]
    off = truth["scan_offsets"]
    h = 1e-4
    checked = 0
    for k in range(1, len(truth["t"])):
        sl = slice(off[k], off[k + 1])
        moving = truth["det_label"][sl] == 2
        if not moving.any():
            continue
        t = truth["t"][k]
        T_world_object = mover.states(np.array([t - h, t, t + h])).T_world_object
        q = se3.transform_points(se3.inverse(T_world_object[1]), truth["det_p_world"][sl][moving])
        T_world_vehicle = profile.sample(np.array([t - h, t + h])).T_world_vehicle
        T_sensor_object = [se3.inverse(T_world_vehicle[i] @ cfg.T_vehicle_sensor) @ T_world_object[2 * i]
                           for i in (0, 1)]
        r = [np.linalg.norm(se3.transform_points(T, q), axis=1) for T in T_sensor_object]
        np.testing.assert_allclose(seq.scans[k].radial_velocity[moving], (r[1] - r[0]) / (2 * h), atol=1e-5)
        checked += moving.sum()
    assert checked > 20
