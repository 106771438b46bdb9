"""World generation: clearance from the route, ground following the road, movers' exact rigid motion,
reproducibility, box geometry."""

from dataclasses import replace

import numpy as np
import pytest

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.sim import objects as ob
from rodo.sim import trajectory as tr
from rodo.sim import world as w


@pytest.fixture(scope="module")
def city():
    profile = tr.city(np.random.default_rng(0), 40.0)
    route = tr.route_of(profile)
    return profile, route, w.build_world(np.random.default_rng(1), route, w.CITY)


def test_static_scene_keeps_clear_of_the_route(city):
    _, route, world = city
    from scipy.spatial import cKDTree

    tree = cKDTree(route.p_world[:, :2])
    assert len(world.points) > 100
    assert tree.query(world.points.p[:, :2])[0].min() >= w.CITY.clearance - 1e-9
    assert world.patches.opaque.sum() > 50


def _min_box_distance(patches, route):
    """Distance from route points to sampled points on the patches (a check not limited to corners)."""
    pts, _ = patches.sample(np.full(len(patches), 20), np.random.default_rng(0))
    from scipy.spatial import cKDTree

    return cKDTree(pts[:, :2]).query(route.p_world[:, :2])[0].min()


def test_every_opaque_surface_leaves_the_road_free(city):
    _, route, world = city
    opaque = world.patches.subset(world.patches.opaque)
    assert _min_box_distance(opaque, route) > 1.5


def test_ground_follows_the_road_height_on_hills():
    profile = tr.hills(np.random.default_rng(0), 60.0)
    route = tr.route_of(profile)
    world = w.build_world(np.random.default_rng(0), route, w.RURAL)
    ground = world.patches.subset(world.patches.object_id == world.patches.object_id.max())
    assert np.ptp(route.p_world[:, 2]) > 5.0
    # the ground tile centred under the road has its height at the route height minus GROUND_BELOW
    c = ground.center
    from scipy.spatial import cKDTree

    d, i = cKDTree(c[:, :2]).query(route.p_world[::10, :2])
    dz = c[i, 2] - (route.p_world[::10, 2] - w.GROUND_BELOW)
    assert np.abs(dz).max() < 0.6  # tiles are 5 m long on grades up to 8 %
    assert np.all(ground.normal[:, 2] > 0.99)


def test_same_rng_same_world(city):
    profile, route, world = city
    again = w.build_world(np.random.default_rng(1), route, w.CITY)
    for f in ("origin", "u", "v", "object_id", "reflectivity", "opaque"):
        np.testing.assert_array_equal(getattr(world.patches, f), getattr(again.patches, f))
    np.testing.assert_array_equal(world.points.p, again.points.p)
    other = w.build_world(np.random.default_rng(2), route, w.CITY)
    assert len(other.points) != len(world.points) or not np.array_equal(other.points.p, world.points.p)


def lateral(route, p):
    """Signed distance of points p (N, 2 or 3) from the route, positive to its left (also test_traffic's)."""
    from scipy.spatial import cKDTree

    d, i = cKDTree(route.p_world[:, :2]).query(p[:, :2])
    return d * np.sign(np.einsum("ij,ij->i", p[:, :2] - route.p_world[i, :2], route.left()[i, :2]))


def test_a_left_side_of_its_own_moves_only_the_left(city):
    """SceneParams.left: the same draws in the same order, so the same side params give the same world bit for
    bit; other offsets on the left move the left's poles and trees and leave the right's where they were."""
    _, route, world = city
    same = w.build_world(np.random.default_rng(1), route, w.SceneParams(left=w.SceneParams()))
    np.testing.assert_array_equal(same.points.p, world.points.p)
    np.testing.assert_array_equal(same.patches.origin, world.patches.origin)
    np.testing.assert_array_equal(same.solids, world.solids)
    bare = w.SceneParams(building_prob=0.0, parked_car_spacing=0.0, clutter_per_100m=0.0)
    far = replace(bare, left=replace(bare, pole_offset=(20.0, 21.0), tree_offset=(20.0, 21.0)))
    y_bare, y_far = (lateral(route, w.build_world(np.random.default_rng(3), route, p).points.p) for p in (bare, far))
    np.testing.assert_array_equal(np.sort(y_far[y_far < 0]), np.sort(y_bare[y_bare < 0]))
    assert y_far[y_far > 0].size > 20
    assert np.all(y_far[y_far > 0] > 14.0) and np.any(y_bare[(y_bare > 0)] < 9.0)


@pytest.mark.parametrize("kind", ["lead", "oncoming", "overtaking"])
def test_movers_velocity_is_the_derivative_of_their_pose(city, kind):
    profile = city[0]
    mover = {"lead": lambda: w.lead_vehicle(profile, 5, 2.0, 0.0, 30.0),
             "oncoming": lambda: w.oncoming_vehicle(profile, 5, 15.0, speed_ratio=0.9),
             "overtaking": lambda: w.overtaking_vehicle(profile, 5, 15.0)}[kind]()
    t = np.array([12.0, 12.0 + 1e-4, 12.0 - 1e-4, 15.0])
    s = mover.states(t)
    assert s.present.all()
    q = np.array([2.0, 0.8, 1.2, 1.0])  # a point fixed on the body
    p = np.einsum("mij,j->mi", s.T_world_object, q)[:, :3]
    fd = (p[1] - p[2]) / 2e-4
    np.testing.assert_allclose(s.v_world[0] + np.cross(s.w_world[0], p[0] - s.T_world_object[0, :3, 3]), fd,
                               atol=1e-6)
    if kind == "oncoming":  # level with the ego at t_meet, one lane to the left, facing the other way
        T_world_vehicle = profile.sample(np.array([15.0])).T_world_vehicle[0]
        rel = se3.inverse(T_world_vehicle) @ s.T_world_object[3]
        np.testing.assert_allclose(rel[:3, 3], [1.25, 3.5, -w.GROUND_BELOW], atol=1e-9)
        assert rel[0, 0] == pytest.approx(-1.0)


def test_mover_outside_its_carrier_time_is_rejected(city):
    profile = city[0]
    with pytest.raises(InputError, match="carrier time"):
        ob.MovingBox(1, w.CAR_SIZE, profile, 0.0, 1.0, 0.0, profile.duration + 10.0)


def test_box_faces_point_outwards():
    b = ob.box(se3.from_rotation_translation(np.eye(3), np.array([1.0, 2.0, 0.0])), (4.0, 2.0, 1.5), 0)
    outward = b.center - np.array([1.0, 2.0, 0.75])
    assert np.all(np.einsum("ij,ij->i", b.normal, outward) > 0)
    assert b.area.sum() == pytest.approx(2 * (2.0 * 1.5) + 2 * (4.0 * 1.5) + 4.0 * 2.0)


def test_a_side_a_whole_number_of_tiles_long_does_not_hang_on_round_off():
    """Buildings span route points 1 m apart, so a facade is often a whole number of 4 m tiles long; its last
    bit (which a trajectory's round-off decides) must not add a tile and, through the draws after it, change
    the world."""
    counts = {len(ob.rectangle([0, 0, 0], [36.0 * (1 + e), 0, 0], [0, 0, 8.0 * (1 - e)], 0))
              for e in (-4e-16, 0.0, 4e-16, 1e-14)}
    assert counts == {9 * 2}
    assert len(ob.rectangle([0, 0, 0], [36.001, 0, 0], [0, 0, 8.0], 0)) == 10 * 2  # a real excess does


def test_landmark_world_is_persistent_points_only(city):
    """`landmark_world`: no surfaces, points clear of the route, at the asked heights above the road, about
    `per_100m` per 100 m and spread along the whole route (none piled up at its ends), and the same rng state
    gives the same points."""
    _, route, _ = city
    world = w.landmark_world(np.random.default_rng(5), route, per_100m=200.0, height=(0.5, 4.0))
    again = w.landmark_world(np.random.default_rng(5), route, per_100m=200.0, height=(0.5, 4.0))
    assert len(world.patches) == 0 and world.movers == ()
    np.testing.assert_array_equal(world.points.p, again.points.p)
    np.testing.assert_array_equal(world.points.pd, again.points.pd)
    expected = 200.0 * route.length / 100.0
    assert 0.8 * expected < len(world.points) <= 1.1 * expected  # a few fall too near the route
    nearest = np.argmin(np.linalg.norm(world.points.p[:, None, :2] - route.p_world[None, :, :2], axis=-1), axis=1)
    per_metre = np.bincount(nearest, minlength=len(route.s))  # the route is sampled every metre
    assert per_metre.max() <= 12 and per_metre[[0, -1]].max() <= 12  # 2 a metre on average
    d = np.min(np.linalg.norm(world.points.p[:, None, :2] - route.p_world[None, :, :2], axis=-1), axis=1)
    assert d.min() >= w.SceneParams().clearance
    assert np.all((world.points.pd >= 0.6) & (world.points.pd <= 0.95))
    assert np.array_equal(world.points.landmark_id, np.arange(len(world.points)))
    near = route.p_world[np.argmin(np.linalg.norm(world.points.p[:, None, :2] - route.p_world[None, :, :2],
                                                  axis=-1), axis=1)]
    above = world.points.p[:, 2] - (near[:, 2] - w.GROUND_BELOW)
    assert above.min() >= 0.5 - 1e-9 and above.max() <= 4.0 + 0.5  # the road's height varies within a step
