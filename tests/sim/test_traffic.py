"""Traffic that never passes through traffic (sim.traffic): footprints, the separating-axis overlap test against
the area of one rectangle clipped to the other, the collision filter, and every traffic scenario's movers clear
of each other and of the parked cars at every instant."""

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from rodo.estimator.lie import se3, so3
from rodo.scenarios import registry
from rodo.sim import trajectory as tr
from rodo.sim import world as w
from rodo.sim.traffic import collision_free, footprints, overlap
from rodo.validation import realism
from tests.sim.test_world import lateral


def _rect(x, y, yaw, length, width):
    T = se3.from_rotation_translation(so3.exp(np.array([0.0, 0.0, yaw])), np.array([x, y, 0.0]))
    return footprints(T[None], (length, width, 1.5))[0]


def _clip(subject, quad):
    """The convex polygon `subject` clipped to the counter-clockwise convex `quad` (Sutherland-Hodgman)."""
    out = list(subject)
    for i in range(len(quad)):
        a, b = quad[i], quad[(i + 1) % len(quad)]
        inside = [((b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])) >= 0.0 for p in out]
        clipped = []
        for j, p in enumerate(out):
            q, q_in = out[j - 1], inside[j - 1]
            if inside[j] != q_in:  # the edge q -> p crosses the line a b
                d, e = q - p, b - a
                t = ((a[0] - p[0]) * e[1] - (a[1] - p[1]) * e[0]) / (d[0] * e[1] - d[1] * e[0])
                clipped.append(p + t * d)
            if inside[j]:
                clipped.append(p)
        out = clipped
        if not out:
            break
    return np.array(out).reshape(-1, 2)


def _reference(a, b):
    """Overlap as the area of a clipped to b (Sutherland-Hodgman, shoelace): positive iff they intersect."""
    c = _clip(a, b)
    if len(c) < 3:
        return False
    x, y = c[:, 0], c[:, 1]
    return bool(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) > 1e-9)


def test_footprint_is_the_box_bottom_under_its_pose():
    T = se3.from_rotation_translation(so3.exp(np.array([0.0, 0.0, 0.7])), np.array([3.0, -2.0, 0.4]))
    quad = footprints(T[None], (4.0, 2.0, 1.5))[0]
    local = np.array([[-2.0, -1.0, 0.0], [2.0, -1.0, 0.0], [2.0, 1.0, 0.0], [-2.0, 1.0, 0.0]])
    np.testing.assert_allclose(quad, se3.transform_points(T, local)[:, :2], atol=1e-12)
    e = np.roll(quad, -1, axis=0) - quad
    assert np.all(e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0] > 0)  # CCW


coord = st.floats(-6.0, 6.0)
yaw = st.floats(-np.pi, np.pi)
side = st.floats(0.3, 6.0)


@given(coord, coord, yaw, side, side, coord, coord, yaw, side, side)
def test_overlap_agrees_with_the_clipped_area(x1, y1, a1, l1, w1, x2, y2, a2, l2, w2):
    grown = _reference(_rect(x1, y1, a1, l1 + 0.02, w1 + 0.02), _rect(x2, y2, a2, l2 + 0.02, w2 + 0.02))
    shrunk = _reference(_rect(x1, y1, a1, l1 - 0.02, w1 - 0.02), _rect(x2, y2, a2, l2 - 0.02, w2 - 0.02))
    assume(grown == shrunk)  # not within a centimetre of touching
    a, b = _rect(x1, y1, a1, l1, w1), _rect(x2, y2, a2, l2, w2)
    assert overlap(a[None], b[None])[0] == shrunk
    assert overlap(b[None], a[None])[0] == shrunk


def test_overlap_margin_and_batches():
    a = _rect(0.0, 0.0, 0.0, 4.0, 2.0)
    b = _rect(5.0, 0.0, 0.0, 4.0, 2.0)  # 1 m apart, end to end
    assert not overlap(a[None], b[None])[0]
    assert not overlap(a[None], b[None], margin=0.9)[0] and overlap(a[None], b[None], margin=1.1)[0]
    many = np.stack([_rect(x, 0.0, 0.0, 4.0, 2.0) for x in (0.0, 3.9, 4.1, 10.0)])
    np.testing.assert_array_equal(overlap(many, a[None]), [True, True, False, False])


@pytest.fixture(scope="module")
def straight():
    """60 s straight at 10 m/s."""
    return tr.ProfileBuilder(10.0).add(60.0).build()


def test_head_on_in_one_lane_leaves_the_later_mover_out(straight):
    oncoming = w.oncoming_vehicle(straight, 1, 30.0, lane=3.5)
    passing = w.overtaking_vehicle(straight, 2, 20.0, lane=3.5, speed_ratio=1.4)
    kept, out = collision_free([oncoming, passing])
    assert kept == [oncoming] and out == [passing]
    passing_right = w.overtaking_vehicle(straight, 3, 20.0, lane=-3.5, speed_ratio=1.4)
    assert collision_free([oncoming, passing_right]) == ([oncoming, passing_right], [])


def test_a_mover_through_a_parked_car_is_left_out(straight):
    oncoming = w.oncoming_vehicle(straight, 1, 30.0, lane=3.5)
    in_lane = _rect(200.0, 3.5, 0.0, 4.5, 1.8)[None]
    beside = _rect(200.0, 6.5, 0.0, 4.5, 1.8)[None]
    assert collision_free([oncoming], in_lane) == ([], [oncoming])
    assert collision_free([oncoming], beside) == ([oncoming], [])


def _movers_overlap(world, step=0.013, duration=30.0):
    """Any two movers, or a mover and a parked car, overlapping at an instant of a grid other than the filter's."""
    times = np.arange(0.0, duration, step)
    quads = []
    for m in world.movers:
        s = m.states(times)
        q = np.full((times.size, 4, 2), np.nan)
        q[s.present] = footprints(s.T_world_object[s.present], m.size)
        quads.append(q)
    for i in range(len(quads)):
        for j in range(i + 1, len(quads)):
            both = ~np.isnan(quads[i][:, 0, 0]) & ~np.isnan(quads[j][:, 0, 0])
            if both.any() and overlap(quads[i][both], quads[j][both]).any():
                return f"movers {world.movers[i].object_id} and {world.movers[j].object_id}"
        present = ~np.isnan(quads[i][:, 0, 0])
        for solid in world.solids:
            if overlap(quads[i][present], solid[None]).any():
                return f"mover {world.movers[i].object_id} and a parked car"
    return None


@pytest.mark.parametrize("name,seed", [("city", 204), ("city", 3), ("stop_and_go", 5), ("blockage", 1),
                                       ("highway", 2), ("hills", 4)])
def test_scenario_traffic_never_overlaps(name, seed):
    world = registry.get(name).build(seed, 30.0).world
    assert world.movers
    assert _movers_overlap(world) is None


def _sides(world, profile):
    """Distances of the parked cars' corners from the route, on its left and on its right."""
    y = lateral(tr.route_of(profile), world.solids.reshape(-1, 2))
    return y[y > 0], -y[y < 0]


def _parked_sides(name, seed):
    parts = registry.get(name).build(seed, 30.0)
    return (parts.world, *_sides(parts.world, parts.profile))


def test_city_passes_on_the_right_and_parks_beyond_the_traffic():
    world, left, right = _parked_sides("city", 204)
    lanes = {(round(m.rate, 1) > 0, round(float(m.T_carrier_object[1, 3]), 1)) for m in world.movers}
    assert (True, -3.5) in lanes and (False, 3.5) in lanes  # passing to the right, oncoming to the left
    assert left.size > 8 and right.size > 8
    beyond = 3.5 + w.TRUCK_SIZE[1] / 2  # every corner beyond a truck in the lanes beside the ego's
    assert left.min() > beyond and right.min() > beyond


def test_stop_and_go_parks_at_the_kerb_and_beyond_the_oncoming_lane():
    _, left, right = _parked_sides("stop_and_go", 5)
    assert left.size > 8 and right.size > 8
    assert left.min() > 3.5 + w.TRUCK_SIZE[1] / 2
    assert right.max() < 4.4 + 2.5  # the kerb: centres 3.6-4.4 m out, corners within half a diagonal
    assert np.median(right) < 4.5 < np.median(left)


@pytest.mark.parametrize("motion,seed", [(tr.city, 0), (tr.city, 5), (tr.hills, 2)])
def test_the_realism_boulevard_parks_beyond_its_oncoming_lanes(motion, seed):
    """validation.realism's boulevard: oncoming cars and trucks in the lanes 7 and 10.5 m to the left, parked cars
    beyond them on the left and at the kerb on the right, and no mover through another or a parked car."""
    profile, world, _ = realism.boulevard(seed, 20.0, motion)
    lanes = {round(float(m.T_carrier_object[1, 3]), 1) for m in world.movers}
    assert {7.0, 10.5, -3.5} <= lanes
    assert _movers_overlap(world, duration=20.0) is None
    left, right = _sides(world, profile)
    assert left.size > 8 and right.size > 8
    assert left.min() > 10.5 + w.TRUCK_SIZE[1] / 2 and right.max() < 9.0 + 2.5
