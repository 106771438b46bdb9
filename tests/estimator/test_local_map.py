"""Local map policy: capacity, stalest first, refresh, pruning, stable ids, thinning, determinism."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3, so3
from rodo.estimator.local_map import LocalMap
from tests.estimator.strategies import scans_of_points


def _rng(seed):
    return np.random.default_rng(np.random.SeedSequence(seed))


def test_capacity_and_stalest_dropped_first():
    m = LocalMap(capacity=10, max_age=100, max_new_fraction=1.0)
    m.add(np.arange(18.0).reshape(6, 3), scan=0)          # ids 0..5 at scan 0
    m.refresh(np.array([0, 1]), scan=3)                    # ids 0, 1 seen again
    m.add(np.arange(18.0).reshape(6, 3) + 100, scan=5)    # ids 6..11 at scan 5: 12 > 10
    assert len(m) == 10
    # the stalest are ids 2..5 (last seen 0); of them the oldest ids 2, 3 go first
    assert sorted(m.ids.tolist()) == [0, 1, 4, 5, 6, 7, 8, 9, 10, 11]
    # ties on last_seen broken by hits: id 0 and 1 have 2 hits, new points 1
    m.refresh(np.flatnonzero(np.isin(m.ids, [4, 5, 6, 7, 8, 9, 10, 11])), scan=5)
    m.add(np.zeros((2, 3)) + 500, scan=5)
    assert len(m) == 10
    assert set(m.ids.tolist()) == {4, 5, 6, 7, 8, 9, 10, 11, 12, 13}


@given(data=st.data(), scans=scans_of_points(12, 400), seed=st.integers(0, 1000), capacity=st.integers(1, 300))
def test_capacity_never_exceeded_and_ids_stable(data, scans, seed, capacity):
    m = LocalMap(capacity=capacity, max_age=3, voxel=0.0, rng=_rng(seed))
    id_to_point = {}
    for scan, points in enumerate(scans):
        m.add(points, scan)
        assert len(m) <= capacity
        if len(m):
            seen = data.draw(st.lists(st.integers(0, len(m) - 1), min_size=1, max_size=5, unique=True))
            m.refresh(np.array(seen), scan)
        for i, p in zip(m.ids.tolist(), m.points):
            assert np.array_equal(id_to_point.setdefault(i, p.copy()), p)   # an id keeps its point
        assert len(np.unique(m.ids)) == len(m)
        assert np.all(np.diff(m.ids) > 0)                                    # order kept, ids never reused


def test_one_scan_cannot_flush_the_map():
    m = LocalMap(capacity=100, max_age=10, rng=_rng(1))
    m.add(_rng(2).uniform(0, 10, (40, 3)), scan=0)
    m.add(_rng(12).uniform(0, 10, (40, 3)), scan=0)
    assert len(m) == 80
    m.refresh(np.arange(80), scan=1)
    m.add(_rng(3).uniform(0, 10, (1000, 3)), scan=1)
    # at most 50 new points per add; the 80 refreshed ones have more hits, so the new ones go first
    assert len(m) == 100
    assert np.sum(m.ids < 80) == 80


def test_refresh_keeps_points():
    m = LocalMap(capacity=50, max_age=2)
    p = _rng(4).uniform(1, 20, (10, 3))
    m.add(p, scan=0)
    before = m.points.copy()
    m.refresh(np.array([2, 7]), scan=4)
    np.testing.assert_array_equal(m.points, before)            # positions never move
    assert m.last_seen.tolist() == [0, 0, 4, 0, 0, 0, 0, 4, 0, 0]
    assert m.hits.tolist() == [1, 1, 2, 1, 1, 1, 1, 2, 1, 1]
    m.prune(4, np.eye(4), np.eye(4), 100.0)                     # age 4 > max_age 2 except the refreshed ones
    assert m.ids.tolist() == [2, 7]
    with pytest.raises(ValueError):
        m.points[0, 0] = 1.0                                    # read-only views


def test_prune():
    T_wv = se3.from_rotation_translation(so3.exp(np.array([0, 0, np.pi / 2])), np.array([10.0, 0.0, 0.0]))
    T = se3.inverse(T_wv)                                       # vehicle at (10, 0) facing +y (world)
    T_vs = se3.from_rotation_translation(np.eye(3), np.array([2.0, 0.0, 0.0]))   # sensor 2 m ahead
    # sensor at world (10, 2) looking along +y
    pts = np.array([[10.0, 10.0, 0.0],    # 8 m ahead: kept
                    [10.0, 1.0, 0.0],     # 1 m behind the sensor (but ahead of the vehicle origin): dropped
                    [10.0, -5.0, 0.0],    # behind: dropped
                    [10.0, 90.0, 0.0],    # 88 m ahead, beyond 80 m: dropped
                    [30.0, 3.0, 0.0]])    # 1 m ahead, 20 m to the side: kept
    m = LocalMap(capacity=10, max_age=5)
    m.add(pts, scan=0)
    m.prune(1, T, T_vs, max_range=80.0)
    np.testing.assert_array_equal(m.points, pts[[0, 4]])
    assert m.ids.tolist() == [0, 4]
    m.prune(6, T, T_vs, max_range=80.0)                         # age 6 > 5: everything goes
    assert len(m) == 0
    m.add(np.array([[0.0, 5.0, 0.0], [1e-9, 5.0, 0.0]]), scan=6)
    m.prune(6, np.eye(4), np.eye(4), max_range=80.0)            # on the sensor's plane (x_s = 0): behind
    assert m.ids.tolist() == [6]


def test_voxel_thinning():
    m = LocalMap(capacity=1000, voxel=1.0, rng=_rng(5))
    p = np.array([[0.1, 0.1, 0.1], [0.9, 0.5, 0.2], [1.5, 0.5, 0.5], [5.2, 5.1, 5.0]])
    m.add(p, scan=0)
    assert len(m) == 3                                          # two points share the voxel [0, 1)^3
    m.add(np.array([[0.5, 0.5, 0.5], [7.5, 0.0, 0.0]]), scan=1)   # first voxel already occupied
    assert len(m) == 4
    np.testing.assert_array_equal(m.points[-1], [7.5, 0.0, 0.0])


def test_deterministic_given_the_generator():
    pts = _rng(6).uniform(0, 30, (3000, 3))
    a = LocalMap(capacity=500, voxel=0.5, rng=_rng(7))
    b = LocalMap(capacity=500, voxel=0.5, rng=_rng(7))
    a.add(pts, 0)
    b.add(pts, 0)
    assert a.points.tobytes() == b.points.tobytes()


def test_bad_input_names_the_argument():
    m = LocalMap(capacity=5)
    with pytest.raises(InputError, match="p_world"):
        m.add(np.zeros((2, 2)), 0)
    m.add(np.ones((2, 3)), 0)
    with pytest.raises(InputError, match="idx"):
        m.refresh(np.array([0, 5]), 1)
    with pytest.raises(InputError, match="distinct"):
        m.refresh(np.array([1, 1]), 1)
    assert m.hits.tolist() == [1, 1] and m.last_seen.tolist() == [0, 0]  # nothing refreshed by a rejected call
    with pytest.raises(InputError, match="max_range"):
        m.prune(1, np.eye(4), np.eye(4), -1.0)
    with pytest.raises(InputError, match="capacity"):
        LocalMap(capacity=0)
    with pytest.raises(InputError, match="rng"):
        LocalMap(rng=42)


def test_covariances_follow_their_points_through_thinning_and_pruning():
    rng = np.random.default_rng(3)
    m = LocalMap(capacity=50, max_age=5, voxel=1.0, rng=np.random.default_rng(0))
    p = rng.uniform(0, 20, size=(200, 3))
    cov = np.einsum("k,ij->kij", np.arange(200.0), np.eye(3))  # cov k tagged by its point index k
    m.add(p, 0, covariances=cov)
    assert 0 < len(m) <= 25  # max_new_fraction 0.5 of the capacity per scan
    # each kept point carries the covariance it came with
    idx = [int(np.flatnonzero(np.all(p == q, axis=1))[0]) for q in m.points]
    np.testing.assert_array_equal(m.covariances[:, 0, 0], np.array(idx, dtype=float))
    m.add(rng.uniform(0, 20, size=(5, 3)), 1)  # no covariances given: zeros
    assert m.covariances.shape == (len(m), 3, 3)


def _elevation_like_covariance(rng, r):
    """World covariance of a detection at range r: 2 cm range, 0.15 deg azimuth, 0.3 deg elevation, in a
    randomly rotated sensor frame (x along the line of sight)."""
    s = np.array([0.02, r * np.deg2rad(0.15), r * np.deg2rad(0.3)])
    C = so3.exp(rng.normal(size=3) * 0.3)
    return C @ np.diag(s**2) @ C.T


def test_fuse_averages_noise_and_shrinks_covariance():
    """Repeated noisy observations of a fixed point: without fading the fused point is the information-weighted
    mean, its covariance (sum R^-1)^-1, and it converges to the truth (error consistent with that covariance)."""
    rng = _rng(8)
    truth = np.array([30.0, -4.0, 1.5])
    errs, single = [], []
    for trial in range(200):
        Rs = [_elevation_like_covariance(rng, r) for r in rng.uniform(10, 80, 25)]
        zs = [truth + rng.multivariate_normal(np.zeros(3), R) for R in Rs]
        m = LocalMap(capacity=10, max_age=100)
        m.add(zs[0][None], 0, covariances=Rs[0][None])
        for k in range(1, len(zs)):
            m.fuse(np.array([0]), zs[k][None], Rs[k][None], k, max_fused=0)
        info = sum(np.linalg.inv(R) for R in Rs)
        np.testing.assert_allclose(m.covariances[0], np.linalg.inv(info), rtol=1e-8, atol=1e-12)
        mean = np.linalg.solve(info, sum(np.linalg.solve(R, z) for R, z in zip(Rs, zs)))
        np.testing.assert_allclose(m.points[0], mean, atol=1e-9)
        assert m.hits[0] == 25 and m.last_seen[0] == 24
        e = m.points[0] - truth
        errs.append(e @ info @ e)                      # chi-square, 3 dof if the covariance is right
        single.append(np.linalg.norm(zs[0] - truth))
        final = np.linalg.norm(e)
        if trial == 0:
            assert np.all(np.linalg.eigvalsh(Rs[0] - m.covariances[0]) > 0)   # shrank in every direction
    assert 2.5 < np.mean(errs) < 3.5
    assert np.mean(final) < 0.5 * np.mean(single)


def test_fuse_fading_memory_bounds_information():
    """With max_fused = N and equal R the information stays at most N R^-1, and the point follows a surface
    that moved (an old position is forgotten)."""
    R = np.diag([0.04, 0.01, 0.09])
    m = LocalMap(capacity=10, max_age=1000)
    m.add(np.zeros((1, 3)), 0, covariances=R[None])
    for k in range(1, 200):
        m.fuse(np.array([0]), np.zeros((1, 3)), R[None], k, max_fused=10)
        assert np.all(np.linalg.eigvalsh(m.covariances[0] - R / 10) > -1e-12)   # never above N R^-1
    np.testing.assert_allclose(m.covariances[0], R / 10, rtol=1e-6)
    for k in range(200, 260):                                   # the surface moves 1 m: the point follows
        m.fuse(np.array([0]), np.ones((1, 3)), R[None], k, max_fused=10)
    np.testing.assert_allclose(m.points[0], np.ones(3), atol=0.01)
    m0 = LocalMap(capacity=10, max_age=1000)                    # without fading it would stay near the middle
    m0.add(np.zeros((1, 3)), 0, covariances=R[None])
    for k in range(1, 260):
        m0.fuse(np.array([0]), np.ones((1, 3)) * (k >= 200), R[None], k, max_fused=0)
    assert np.all(m0.points[0] < 0.3)


def test_fuse_moves_only_the_fused_points_and_exact_points_stay():
    m = LocalMap(capacity=10, max_age=100)
    p = np.arange(9.0).reshape(3, 3)
    cov = np.stack([np.eye(3), np.zeros((3, 3)), np.eye(3)])   # point 1 was added without a covariance
    m.add(p, 0, covariances=cov)
    m.fuse(np.array([0, 1]), p[:2] + 1.0, np.stack([np.eye(3)] * 2), 1)
    np.testing.assert_allclose(m.points, [p[0] + 0.5, p[1], p[2]])
    np.testing.assert_allclose(m.covariances[0], 0.5 * np.eye(3))
    assert m.hits.tolist() == [2, 2, 1]
    with pytest.raises(InputError, match="z_world"):
        m.fuse(np.array([0]), np.zeros((2, 3)), np.stack([np.eye(3)] * 2), 2)
    with pytest.raises(InputError, match="max_fused"):
        m.fuse(np.array([0]), np.zeros((1, 3)), np.eye(3)[None], 2, max_fused=1)


def test_cleared_map_continues_the_random_stream():
    """A re-initialised map is empty, keeps the settings and draws on from the same random stream (the
    odometry's runs stay reproducible through a re-initialisation)."""
    rng_a, rng_b = np.random.default_rng(5), np.random.default_rng(5)
    a = LocalMap(40, 7, 0.5, rng=rng_a, max_new_fraction=0.25)
    a.add(np.random.default_rng(1).normal(size=(100, 3)) * 10, 0)
    b = a.cleared()
    assert len(b) == 0 and (b.capacity, b.max_age, b.voxel, b.max_new_fraction) == (40, 7, 0.5, 0.25)
    reference = LocalMap(40, 7, 0.5, rng=rng_b, max_new_fraction=0.25)
    reference.add(np.random.default_rng(1).normal(size=(100, 3)) * 10, 0)
    fresh = LocalMap(40, 7, 0.5, rng=rng_b, max_new_fraction=0.25)  # a new map on the same stream position
    new = np.random.default_rng(2).normal(size=(100, 3)) * 10
    b.add(new, 1)
    fresh.add(new, 1)
    np.testing.assert_array_equal(b.points, fresh.points)
    assert rng_a.random() == rng_b.random()


class _ReferenceMap:
    """The NumPy bookkeeping `map_kernels` replaced (no voxel thinning, which runs before it): new points
    concatenated, the stalest over capacity found by a lexsort, pruning by a matrix product and a mask."""

    def __init__(self, capacity, max_age):
        self.capacity, self.max_age = capacity, max_age
        self.points, self.cov = np.zeros((0, 3)), np.zeros((0, 3, 3))
        self.last_seen, self.hits, self.ids = (np.zeros(0, np.int64) for _ in range(3))

    def _keep(self, mask):
        for name in ("points", "cov", "last_seen", "hits", "ids"):
            setattr(self, name, getattr(self, name)[mask])

    def add(self, p, cov, scan):  # p already at most max_new points
        k, first = len(p), self.next_id  # the map's id counter (ids are never reused)
        self.points, self.cov = np.concatenate([self.points, p]), np.concatenate([self.cov, cov])
        self.last_seen = np.concatenate([self.last_seen, np.full(k, scan, np.int64)])
        self.hits = np.concatenate([self.hits, np.ones(k, np.int64)])
        self.ids = np.concatenate([self.ids, first + np.arange(k)])
        excess = len(self.ids) - self.capacity
        if excess > 0:
            mask = np.ones(len(self.ids), bool)
            mask[np.lexsort((self.ids, self.hits, self.last_seen))[:excess]] = False
            self._keep(mask)

    def prune(self, scan, T, T_vs, max_range, behind):
        # p_s = C_vs^T (T p - r_vs) summed in the kernel's order: a matrix product may round differently, which
        # decides a point within rounding of x_s = 0 or of max_range the other way
        p_s = np.array([[sum(T_vs[i, j] * (T[i, 0] * p[0] + T[i, 1] * p[1] + T[i, 2] * p[2] + T[i, 3] - T_vs[i, 3])
                             for i in range(3)) for j in range(3)] for p in self.points.tolist()]).reshape(-1, 3)
        keep = ((scan - self.last_seen) <= self.max_age) & (np.sqrt(np.sum(p_s**2, axis=1)) <= max_range)
        self._keep(keep & (p_s[:, 0] > 0) if behind else keep)


@given(data=st.data(), scans=scans_of_points(15, 60, extent=30.0), capacity=st.integers(1, 80),
       max_age=st.integers(0, 4))
def test_compiled_map_equals_the_numpy_reference(data, scans, capacity, max_age):
    """Adds (over capacity: the stalest by last seen, hits, id; also an add of nothing after the capacity was
    lowered), refreshes, prunes from random poses, changes of capacity and scan numbers far apart leave the
    compiled map's arrays equal, bit for bit, to the NumPy reference's."""
    m = LocalMap(capacity=capacity, max_age=max_age, max_new_fraction=1.0)
    ref = _ReferenceMap(capacity, max_age)
    step = data.draw(st.sampled_from([1, 2**58]))  # scan numbers far apart: the kernel's key would overflow
    for scan, p in enumerate(scans):
        scan *= step
        if data.draw(st.integers(0, 4)) == 0:  # a new capacity (as `RadarOdometry.add_sensor` sets one)
            m.capacity = ref.capacity = data.draw(st.integers(1, 120))
        p = p[:m.capacity]  # at most max_new (the capacity here) per scan: no random subset
        cov = np.arange(len(p) * 9.0).reshape(-1, 3, 3) + len(ref.ids)
        ref.next_id = m._next_id
        m.add(p, scan, covariances=cov)
        ref.add(p, cov, scan)
        if len(m):
            seen = data.draw(st.lists(st.integers(0, len(m) - 1), max_size=len(m), unique=True))
            m.refresh(np.array(seen, np.int64), scan)
            ref.last_seen[seen] = scan
            ref.hits[seen] += 1
        if data.draw(st.booleans()):
            T = se3.exp(np.array(data.draw(st.lists(st.floats(-3, 3), min_size=6, max_size=6))))
            T_vs = se3.exp(np.array(data.draw(st.lists(st.floats(-1, 1), min_size=6, max_size=6))))
            behind = data.draw(st.booleans())
            m.prune(scan, T, T_vs, 40.0, behind=behind)
            ref.prune(scan, T, T_vs, 40.0, behind)
        for name, mine in (("points", m.points), ("cov", m.covariances), ("last_seen", m.last_seen),
                           ("hits", m.hits), ("ids", m.ids)):
            np.testing.assert_array_equal(mine, getattr(ref, name), err_msg=name)
