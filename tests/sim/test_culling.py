"""sim.culling: the per-scene geometry and the pre-selection near the sensor change nothing (bit for bit) in
what a scan keeps and computes; the helpers reproduce numpy's own arithmetic."""

import numpy as np
import pytest

from rodo.estimator.lie import se3, so3
from rodo.sim import trajectory as tr
from rodo.sim import world as w
from rodo.sim.culling import Cull, PatchGeometry, PointIndex, norm3, transform
from rodo.sim.radar import RadarConfig, polar

CFG = RadarConfig()


@pytest.fixture(scope="module")
def scene():
    profile = tr.city(np.random.default_rng(0), 40.0)
    world = w.build_world(np.random.default_rng(1), tr.route_of(profile), w.CITY)
    m = profile.sample(np.linspace(1.0, 39.0, 7))
    return world, [se3.inverse(T @ CFG.T_vehicle_sensor) for T in m.T_world_vehicle]


def test_patch_geometry_is_the_patches_properties(scene):
    world, _ = scene
    p = world.patches
    g = PatchGeometry(p, indexed=True)
    for name in ("center", "half_diagonal", "normal", "area"):
        np.testing.assert_array_equal(getattr(g, name), getattr(p, name), err_msg=name)


def _sampled(cull, seed):
    return cull.sample(CFG, np.random.default_rng(seed))


def test_preselection_keeps_the_same_patches_and_samples(scene):
    """Indexed (pre-selected near the sensor) and plain culling keep the same patches with the same values, draw
    the same samples and map the same patches into the sensor frame."""
    world, poses = scene
    indexed, plain = PatchGeometry(world.patches, indexed=True), PatchGeometry(world.patches, indexed=False)
    for k, T_sensor_world in enumerate(poses):
        near = indexed.near(T_sensor_world, CFG)
        assert near is not None and len(near) < len(world.patches)  # the pre-selection does something
        a, b = Cull(indexed, T_sensor_world, CFG), Cull(plain, T_sensor_world, CFG)
        assert len(a.idx) > 100
        for name in ("idx", "d", "cos", "object_id"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        for x, y in zip(_sampled(a, k), _sampled(b, k)):
            np.testing.assert_array_equal(x, y)
        for opaque_only in (False, True):
            pa, pb = a.sensor(opaque_only), b.sensor(opaque_only)
            for name in ("origin", "u", "v", "object_id", "opaque"):
                np.testing.assert_array_equal(getattr(pa, name), getattr(pb, name), err_msg=name)


def test_point_preselection_keeps_every_point_in_the_field_of_view(scene, monkeypatch):
    from rodo.sim import culling

    monkeypatch.setattr(culling, "FEW_POINTS", 0)  # select even among few points
    world, poses = scene
    index = PointIndex(world.points.p)
    for T_sensor_world in poses:
        near = index.near(T_sensor_world, CFG)
        r, az, el = polar(transform(world.points.p, T_sensor_world[:3, :3], T_sensor_world[:3, 3]))
        seen = np.flatnonzero((r <= CFG.max_range) & (az >= CFG.azimuth_fov[0]) & (az <= CFG.azimuth_fov[1]))
        assert len(seen) > 10 and near is not None and len(near) < len(r)
        assert np.isin(seen, near).all()


def test_transform_rows_do_not_depend_on_the_other_rows():
    """A row's product is the same in any set of rows, a single row included (numpy computes that one as a
    vector product: `transform` keeps it a matrix product)."""
    rng = np.random.default_rng(2)
    C, t = so3.exp(rng.normal(size=3)), rng.normal(size=3) * 50
    p = rng.uniform(-200, 200, (500, 3))
    full = p @ C.T + t
    np.testing.assert_array_equal(transform(p, C, t), full)
    for n in (1, 2, 3, 17):
        idx = np.sort(rng.choice(len(p), n, replace=False))
        np.testing.assert_array_equal(transform(p[idx], C, t, len(p)), full[idx])
    np.testing.assert_array_equal(transform(p[:1], C, t), p[:1] @ C.T + t)  # a one-row set stays as numpy has it


def test_norm3_is_np_linalg_norm_bit_for_bit():
    p = np.random.default_rng(3).normal(size=(10000, 3)) * 30
    np.testing.assert_array_equal(norm3(p), np.linalg.norm(p, axis=-1))


def test_a_radar_reused_across_worlds_scans_as_a_fresh_one(scene):
    """The radar keeps the culling geometry of the last world it scanned: switching worlds must not reuse it."""
    from rodo.sim.radar import Radar

    world, poses = scene
    other = w.build_world(np.random.default_rng(9), tr.route_of(tr.city(np.random.default_rng(8), 40.0)), w.CITY)
    T_world_vehicle = se3.inverse(poses[3]) @ se3.inverse(CFG.T_vehicle_sensor)
    varpi = np.array([-10.0, 0, 0, 0, 0, 0.1])
    reused = Radar(CFG)
    for wd in (world, other, world):
        got = reused.scan(wd, T_world_vehicle, varpi, np.random.default_rng(4))
        want = Radar(CFG).scan(wd, T_world_vehicle, varpi, np.random.default_rng(4))
        assert len(got) > 50
        for name in ("range", "azimuth", "elevation", "radial_velocity", "label", "p_world"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


def test_movers_culled_together_as_one_by_one():
    """Moving boxes culled as one set give each box's kept patches, samples and sensor-frame patches as culling
    it alone (a box with a single kept patch included: its one-row product is kept as numpy computes it)."""
    from rodo.sim.objects import Patches, box

    T_sensor_world = se3.inverse(CFG.T_vehicle_sensor)
    T_side = se3.from_rotation_translation(so3.exp(np.array([0, 0, 0.7])), np.array([15.0, -6.0, -0.35]))
    for x in (12.0, 20.0, 35.0, 60.0, 90.0):  # a car straight ahead: only its rear is seen
        T_ahead = se3.from_rotation_translation(so3.exp(np.array([0, 0, 0.003])), np.array([x, 0.1, -0.35]))
        bodies = [box(T_ahead, (4.5, 1.8, 1.5), 7), box(T_side, (8.0, 2.5, 3.6), 8)]
        together = Cull(PatchGeometry(Patches.concat(bodies), indexed=False), T_sensor_world, CFG)
        groups = np.searchsorted(together.idx, np.cumsum([0] + [len(b) for b in bodies]))
        alone = [Cull(PatchGeometry(b, indexed=False), T_sensor_world, CFG) for b in bodies]
        assert list(np.diff(groups)) == [len(a.idx) for a in alone] and np.diff(groups)[0] == 1
        rng_a, rng_b = np.random.default_rng(1), np.random.default_rng(1)
        for g, a in enumerate(alone):
            np.testing.assert_array_equal(together.sample(CFG, rng_a, slice(groups[g], groups[g + 1]))[0],
                                          a.sample(CFG, rng_b)[0])
        got = together.sensor(groups=groups)
        want = Patches.concat([a.sensor() for a in alone])
        for name in ("origin", "u", "v", "object_id"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


def test_near_index_tiles_select_as_testing_every_point(monkeypatch):
    """Large scenes go through the grid of tiles: the same indices as testing every point."""
    from rodo.sim import culling

    rng = np.random.default_rng(11)
    xyz = rng.uniform([-1500, -400, -5], [1500, 400, 20], (20000, 3))
    behind = rng.uniform(1.0, 10.0, len(xyz))
    big, small = culling.NearIndex(xyz), culling.NearIndex(xyz)
    for _ in range(20):
        T_sensor_world = se3.inverse(se3.from_rotation_translation(so3.exp(np.array([0, 0, rng.uniform(-3, 3)])),
                                                                   rng.uniform([-1600, -500, 0], [1600, 500, 2])))
        monkeypatch.setattr(culling, "SMALL", 0)
        got = big.near(T_sensor_world, CFG, 160.0, behind)
        monkeypatch.setattr(culling, "SMALL", len(xyz))
        want = small.near(T_sensor_world, CFG, 160.0, behind)
        np.testing.assert_array_equal(got, want)


def test_near_points_kernel_is_the_numpy_test(scene):
    """The pre-selection's compiled distance and behind-the-sensor tests keep what numpy's did (scalar and
    per-point margins, and without the behind test for a field of view wider than +-90 deg)."""
    from dataclasses import replace

    from rodo.sim import culling

    world, poses = scene
    xyz = world.patches.origin + 0.5 * (world.patches.u + world.patches.v)
    index = culling.NearIndex(xyz)
    behind = np.random.default_rng(12).uniform(0.0, 5.0, len(xyz))
    for cfg in (CFG, replace(CFG, azimuth_fov=(-2.0, 2.0))):
        for T_sensor_world in poses:
            for margin in (1.0, behind):
                p = culling.sensor_position(T_sensor_world)
                dx, dy, dz = xyz[:, 0] - p[0], xyz[:, 1] - p[1], xyz[:, 2] - p[2]
                m = dx * dx + dy * dy + dz * dz <= 80.0 * 80.0
                if cfg is CFG:
                    b = T_sensor_world[0, :3]
                    m &= b[0] * dx + b[1] * dy + b[2] * dz > -margin
                got = index.near(T_sensor_world, cfg, 80.0, margin)
                np.testing.assert_array_equal(got, np.flatnonzero(m))
                assert 0 < len(got) < len(xyz)


def test_samples_kernel_is_the_numpy_arithmetic(scene):
    """Cull.sample's compiled points are (origin + a u) + b v as numpy computed them, bit for bit."""
    world, poses = scene
    cull = Cull(PatchGeometry(world.patches, indexed=True), poses[2], CFG)
    pts, k = _sampled(cull, 5)
    rng = np.random.default_rng(5)
    cull.counts(CFG, rng)
    ab = rng.random((k.size, 2))
    g = cull.idx[k]
    p = world.patches
    want = (p.origin[g] + ab[:, :1] * p.u[g]) + ab[:, 1:] * p.v[g]
    assert pts.shape == want.shape and pts.tobytes() == want.tobytes() and len(pts) > 500
