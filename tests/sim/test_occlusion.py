"""sim.occlusion and sim.radar_kernels: the shortcuts of the depth buffer give exactly (bit for bit) what the
plain computations give: pairs only at needed cells, hits beyond a per-cell limit dropped, the nearest per cell
without sorting; and each compiled loop gives what the numpy computation it replaced gives, bit for bit (those
computations are kept here as the references)."""

import numpy as np
import pytest

from rodo.estimator.lie import se3
from rodo.sim import trajectory as tr
from rodo.sim import world as w
from rodo.sim.culling import Cull, PatchGeometry
from rodo.sim.objects import Patches
from rodo.sim.occlusion import cell_boxes, cell_directions, cross, depth_buffer, gate_cells, nearest_per_cell, \
    nearest_visible
from rodo.sim.radar_kernels import dot3
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


@pytest.fixture(scope="module")
def scattered():
    """Random patches all around the sensor (behind, beside, above, far, near, large, tiny), some of them
    degenerate (a zero edge), with the object ids of 40 objects."""
    rng = np.random.default_rng(7)
    n = 400
    origin = rng.uniform(-60, 60, (n, 3)) * [1, 1, 0.2]
    u = rng.normal(size=(n, 3)) * rng.uniform(0.01, 8.0, (n, 1))
    v = cross(u, rng.normal(size=(n, 3)))
    v *= rng.uniform(0.01, 8.0, (n, 1)) / np.linalg.norm(v, axis=1, keepdims=True)
    u[:5] = 0.0
    return Patches(origin, u, v, rng.integers(0, 40, n), np.ones(n), np.ones(n, bool), np.zeros(n, bool))


def _all_pairs(boxes, n_el):
    """Every (patch, cell) pair of the boxes, patch by patch, azimuth-major: the plain enumeration."""
    pid, cell = [], []
    for i, (a0, a1, e0, e1) in enumerate(zip(*boxes)):
        c = (np.arange(a0, a1 + 1)[:, None] * n_el + np.arange(e0, e1 + 1)[None, :]).ravel()
        pid.append(np.full(c.size, i))
        cell.append(c)
    return np.concatenate(pid), np.concatenate(cell)


def _numpy_cell_boxes(p, cfg):
    """The cell boxes as numpy computed them (the reference of the compiled `cell_boxes`)."""
    n_az, n_el = cfg.grid_shape
    box_a, box_b = np.array([[a, b] for a in (0, 0.5, 1) for b in (0, 0.5, 1)]).T[:, None, :, None]
    x, y, z = (p.origin.T[:, None, :] + box_a * p.u.T[:, None, :]) + box_b * p.v.T[:, None, :]
    az = np.arctan2(y, x)
    el = np.arctan2(z, np.sqrt(x * x + y * y))
    az_lo, az_hi = az.min(axis=0), az.max(axis=0)
    wraps = (az_hi - az_lo > np.pi) | ((x <= 0).any(axis=0) & (az_hi - az_lo > np.pi / 2))
    az_lo_hi = np.where(wraps, np.array(cfg.azimuth_fov, dtype=float)[:, None], np.stack([az_lo, az_hi]))
    el_lo_hi = np.stack([el.min(axis=0), el.max(axis=0)])
    pad = np.array([[-1], [1]])
    ia0, ia1 = np.clip(np.floor((az_lo_hi - cfg.azimuth_fov[0]) / cfg.cell_azimuth).astype(int) + pad, 0, n_az - 1)
    ie0, ie1 = np.clip(np.floor((el_lo_hi - cfg.elevation_fov[0]) / cfg.cell_elevation).astype(int) + pad, 0,
                       n_el - 1)
    return ia0, ia1, ie0, ie1


def _numpy_depth_buffer(p, cfg, dirs, limit):
    """The depth buffer as numpy computed it: every pair of the boxes at the needed cells, the ray-rectangle test
    with einsum dot products, then the nearest hit per cell by lexsort (the reference of `depth_buffer`)."""
    n_cells = len(dirs)
    depth, owner = np.full(n_cells, np.inf), np.full(n_cells, -1)
    pid, cell = _all_pairs(_numpy_cell_boxes(p, cfg), cfg.grid_shape[1])
    pid, cell = pid[limit[cell] > -np.inf], cell[limit[cell] > -np.inf]
    normal = cross(p.u, p.v)
    d = dirs[cell]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.einsum("ij,ij->i", normal, p.origin)[pid] / np.einsum("ij,ij->i", normal[pid], d)
        keep = (s > 0) & (s < limit[cell])
        pid, cell, s, d = pid[keep], cell[keep], s[keep], d[keep]
        q = s[:, None] * d - p.origin[pid]
        a = np.einsum("ij,ij->i", q, p.u[pid]) / np.einsum("ij,ij->i", p.u, p.u)[pid]
        b = np.einsum("ij,ij->i", q, p.v[pid]) / np.einsum("ij,ij->i", p.v, p.v)[pid]
    hit = (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
    cell, s, pid = cell[hit], s[hit], pid[hit]
    order = np.lexsort((s, cell))
    first = order[np.r_[True, cell[order][1:] != cell[order][:-1]]] if len(order) else order
    depth[cell[first]], owner[cell[first]] = s[first], p.object_id[pid[first]]
    return depth, owner


def _same_bits(a, b):
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("which", ["opaque", "scattered"])
def test_cell_boxes_are_the_numpy_computation_bit_for_bit(which, request):
    p = request.getfixturevalue(which)
    got, ref = cell_boxes(p, CFG), _numpy_cell_boxes(p, CFG)
    for g, r in zip(got, ref):
        np.testing.assert_array_equal(g, r)
    if which == "scattered":  # the cases the boxes distinguish are all there
        assert np.any(got[0] == 0) and np.any(got[1] == CFG.grid_shape[0] - 1) and np.any(got[0] > 0)


@pytest.mark.parametrize("which", ["opaque", "scattered"])
def test_depth_buffer_is_the_numpy_computation_bit_for_bit(which, request):
    p = request.getfixturevalue(which)
    dirs = cell_directions(CFG)
    rng = np.random.default_rng(8)
    limits = [np.full(len(dirs), np.inf), np.where(rng.random(len(dirs)) < 0.5, -np.inf, rng.uniform(0, 60, len(dirs)))]
    for limit in limits:
        depth, owner = depth_buffer(p, CFG, dirs, limit)
        ref_depth, ref_owner = _numpy_depth_buffer(p, CFG, dirs, limit)
        assert _same_bits(depth, ref_depth) and _same_bits(owner, ref_owner)
        assert np.isfinite(depth).sum() > 200


def test_dot3_is_numpys_einsum_bit_for_bit():
    """The kernels' 3-vector dot product sums as numpy's einsum("ij,ij->i") does on rows (not left to right:
    that differs on about a fifth of random rows), signed zeros included."""
    rng = np.random.default_rng(9)
    a, b = rng.normal(size=(2, 20000, 3)) * np.exp(rng.normal(size=(2, 20000, 3)) * 4)
    a[rng.random(a.shape) < 0.1] = -0.0
    b[:100] = a[:100]
    got = np.array([dot3(*x, *y) for x, y in zip(a, b)])
    assert _same_bits(got, np.einsum("ij,ij->i", a, b))
    assert not np.array_equal(got, ((a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]) + a[:, 2] * b[:, 2]))


def test_gates_cells_and_limit_are_the_numpy_computation_bit_for_bit():
    rng = np.random.default_rng(10)
    n = 5000
    r = rng.uniform(-1.0, 160.0, n)
    az, el = rng.uniform(-1.2, 1.2, n), rng.uniform(-0.3, 0.3, n)
    r[:9], az[:9], el[:9] = 50.0, 0.0, 0.0
    az[:3], el[3:6], r[6:9] = CFG.azimuth_fov[1], CFG.elevation_fov[0], CFG.max_range  # on the edges: in view
    idx, cell, r_hidden, limit = gate_cells(r, az, el, CFG)
    ref_idx = np.flatnonzero(CFG.in_view(r, az, el))
    n_az, n_el = CFG.grid_shape
    ia = np.clip(np.floor((az[ref_idx] - CFG.azimuth_fov[0]) / CFG.cell_azimuth).astype(int), 0, n_az - 1)
    ie = np.clip(np.floor((el[ref_idx] - CFG.elevation_fov[0]) / CFG.cell_elevation).astype(int), 0, n_el - 1)
    ref_limit = np.full(n_az * n_el, -np.inf)
    np.maximum.at(ref_limit, ia * n_el + ie, r[ref_idx] - CFG.occlusion_tolerance)
    np.testing.assert_array_equal(idx, ref_idx)
    np.testing.assert_array_equal(cell, ia * n_el + ie)
    assert _same_bits(r_hidden, r[ref_idx] - CFG.occlusion_tolerance) and _same_bits(limit, ref_limit)
    assert set(range(9)) <= set(idx.tolist()) and 0.2 < len(idx) / n < 0.9


def test_nearest_visible_is_the_numpy_computation():
    """Filter the hidden entries, then the nearest per cell (ties: the first)."""
    rng = np.random.default_rng(11)
    n, n_cells = 3000, 200
    idx = np.sort(rng.choice(10000, n, replace=False))
    cell = rng.integers(0, n_cells, n)
    r = rng.integers(1, 30, 10000).astype(float)  # ties
    object_id = rng.integers(0, 5, 10000)
    r_hidden = r[idx] - 0.3
    depth = np.where(rng.random(n_cells) < 0.5, rng.uniform(0, 30, n_cells), np.inf)
    owner = np.where(np.isfinite(depth), rng.integers(0, 5, n_cells), -1)
    visible = ~((depth[cell] < r_hidden) & (owner[cell] != object_id[idx]))
    assert 0.2 < visible.mean() < 0.9
    ref = idx[visible][nearest_per_cell(cell[visible], r[idx][visible], n_cells)]
    np.testing.assert_array_equal(nearest_visible(idx, cell, r_hidden, r, object_id, depth, owner), ref)


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
