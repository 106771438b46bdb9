"""sim.occlusion: the shortcuts of the depth buffer give exactly (bit for bit) what the plain computations give:
pairs only at needed cells, hits beyond a per-cell limit dropped, a scatter-min for the nearest per cell."""

import numpy as np
import pytest

from rodo.estimator.lie import se3
from rodo.sim import trajectory as tr
from rodo.sim import world as w
from rodo.sim.culling import Cull, PatchGeometry
from rodo.sim.occlusion import box_pairs, cell_boxes, cell_directions, cross, depth_buffer, nearest_per_cell
from rodo.sim.radar import RadarConfig

CFG = RadarConfig()


@pytest.fixture(scope="module")
def opaque():
    """The opaque patches (sensor frame) of a city scan."""
    profile = tr.city(np.random.default_rng(0), 20.0)
    world = w.build_world(np.random.default_rng(1), tr.route_of(profile), w.CITY)
    m = profile.sample(np.array([8.0]))
    T_sensor_world = se3.inverse(m.T_world_vehicle[0] @ CFG.T_vehicle_sensor)
    p = Cull(PatchGeometry(world.patches, indexed=True), T_sensor_world, CFG).sensor(opaque_only=True)
    assert len(p) > 50
    return p


def _all_pairs(boxes, n_el):
    """Every (patch, cell) pair of the boxes, patch by patch, azimuth-major: the plain enumeration."""
    pid, cell = [], []
    for i, (a0, a1, e0, e1) in enumerate(zip(*boxes)):
        c = (np.arange(a0, a1 + 1)[:, None] * n_el + np.arange(e0, e1 + 1)[None, :]).ravel()
        pid.append(np.full(c.size, i))
        cell.append(c)
    return np.concatenate(pid), np.concatenate(cell)


def test_box_pairs_at_needed_cells_are_the_plain_pairs_filtered(opaque):
    boxes = cell_boxes(opaque, CFG)
    n_el = CFG.grid_shape[1]
    pid, cell = _all_pairs(boxes, n_el)
    need = np.random.default_rng(3).random(np.prod(CFG.grid_shape)) < 0.2
    got_pid, got_cell = box_pairs(*boxes, need, n_el)
    np.testing.assert_array_equal(got_pid, pid[need[cell]])
    np.testing.assert_array_equal(got_cell, cell[need[cell]])
    all_pid, all_cell = box_pairs(*boxes, np.ones_like(need), n_el)
    np.testing.assert_array_equal(all_pid, pid)
    np.testing.assert_array_equal(all_cell, cell)


def test_nearest_per_cell_is_lexsort_then_first():
    rng = np.random.default_rng(4)
    for n in (0, 1, 7, 500):
        cell = rng.integers(0, 40, n)
        key = rng.integers(0, 5, n).astype(float)  # many ties: the first index must win
        order = np.lexsort((key, cell))
        first = order[np.r_[True, cell[order][1:] != cell[order][:-1]]] if n else order
        np.testing.assert_array_equal(nearest_per_cell(cell, key, 40), first)


def test_limited_depth_buffer_agrees_below_the_limit(opaque):
    """Where the full buffer is nearer than the limit, the limited one has the same depth and owner (bits);
    elsewhere it has none, so `depth < limit` is the same decision."""
    dirs = cell_directions(CFG)
    full_depth, full_owner = depth_buffer(opaque, CFG, dirs)
    assert np.isfinite(full_depth).sum() > 500
    rng = np.random.default_rng(5)
    limit = np.where(rng.random(len(dirs)) < 0.3, -np.inf, rng.uniform(0.0, 80.0, len(dirs)))
    limit[rng.random(len(dirs)) < 0.1] = np.inf
    depth, owner = depth_buffer(opaque, CFG, dirs, limit)
    below = full_depth < limit
    assert 100 < below.sum() < np.isfinite(full_depth).sum()
    np.testing.assert_array_equal(depth[below], full_depth[below])
    np.testing.assert_array_equal(owner[below], full_owner[below])
    assert np.all(np.isinf(depth[~below])) and np.all(owner[~below] == -1)
    np.testing.assert_array_equal(depth < limit, below)


def test_cross_is_np_cross_bit_for_bit():
    rng = np.random.default_rng(6)
    a, b = rng.normal(size=(2, 1000, 3)) * rng.uniform(1e-3, 1e3, (2, 1000, 1))
    np.testing.assert_array_equal(cross(a, b), np.cross(a, b))
    np.testing.assert_array_equal(cross(a[0], b), np.cross(a[0], b))
