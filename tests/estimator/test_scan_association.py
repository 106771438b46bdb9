"""The odometry's compiled association of the map with a scan (`rodo.estimator.scan_association`): the
prepared per-map-point quantities and pairs against the readable reference, and the field-of-view window on
both sides."""

import functools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.estimator import measurements
from rodo.estimator.config import OdometryConfig
from rodo.estimator.lie import se3
from rodo.estimator.odometry import RadarOdometry
from tests.estimator import scene


@functools.lru_cache(maxsize=4)
def _scene_association(model, seed=5):
    """An odometry seven scans into `scene`'s drive, the eighth scan and its association at the prediction."""
    from rodo.estimator.scan_association import ScanMeasurements

    rng = np.random.default_rng(seed)
    t, T, varpi, vd = scene.trajectory(8)
    L = scene.landmarks(rng)
    D = np.pi / 180
    odo = RadarOdometry(OdometryConfig.for_model(model), scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0,
                        fov=((-60 * D, 60 * D), (-15 * D, 15 * D)))
    for k in range(7):
        odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L, rng))
    x = odo.motion.predict(odo.window.newest, t[7])
    P = odo.P + np.diag(np.r_[np.full(6, 1e-4), np.full(6, 1e-2), np.zeros(odo.motion.dim - 12)])
    scan = ScanMeasurements.of(scene.measure(T[7], varpi[7], vd[7], L, rng), odo.measurement)
    W, pairs = odo.associator.associate(x, P, odo.map, scan)
    return odo, x, P, scan, W, pairs


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_prepared_association_equals_the_reference(model):
    """The odometry's compiled association (`prepare_kernels.prepare`, the candidates on one grid per scan,
    their one-to-one choice) gives the pairs, distances and solve information of the readable reference:
    `measurements.predict`, `association.innovation_covariance` plus the map-point term, `association.associate`."""
    from rodo.estimator import association
    from rodo.estimator import prepare_kernels as pkernel

    odo, x, P, scan, W_pairs, got = _scene_association(model, 3)
    polar = scan.polar
    z = measurements.to_model_space(odo.config.measurement, polar)
    pts = measurements.polar_to_cartesian(polar)
    assoc = odo.associator

    pred = measurements.predict(odo.config.measurement, x.T_vehicle_world, x.varpi, odo.map.points,
                                odo.T_vehicle_sensor)
    cov = odo.map.covariances + odo.map_sigma**2 * np.eye(3)
    Smap = assoc.R + pred.J_z_p @ cov @ np.swapaxes(pred.J_z_p, 1, 2)
    S = association.innovation_covariance(pred, P[:12, :12], Smap, 0.0)
    m_in, d_in = assoc.window_masks(pred.p_sensor, polar)
    mi, di = np.flatnonzero(m_in), np.flatnonzero(d_in)
    sub = measurements.Prediction(z=pred.z[mi], J_z_xi=pred.J_z_xi[mi], J_z_varpi=pred.J_z_varpi[mi],
                                  J_z_p=pred.J_z_p[mi], p_sensor=pred.p_sensor[mi])
    ref = association.associate(odo.config.measurement, z[di], pts[di], sub, S[mi], assoc.gate,
                                odo.config.association.max_radius)
    assert len(ref.map_idx) > 100
    np.testing.assert_array_equal(got.map_idx, mi[ref.map_idx])
    np.testing.assert_array_equal(got.det_idx, di[ref.det_idx])
    np.testing.assert_allclose(got.d2, ref.d2, rtol=1e-9)
    assert got.n_candidates == ref.n_candidates
    W_ref = np.linalg.inv(Smap)[got.map_idx]  # each pair's information, in the order of the pairs
    np.testing.assert_allclose(W_pairs, W_ref, rtol=1e-8, atol=1e-8 * np.abs(W_ref).max())
    # the kernel's own outputs, point by point
    m = len(odo.map)
    out = [np.empty((m, 4)), np.empty((m, 3)), np.empty((m, 4, 4)), np.empty((m, 4, 4)), np.empty((m, 4, 4)),
           np.empty(m)]
    assert pkernel.prepare(odo.measurement.is_polar, x.T_vehicle_world, x.varpi, odo.map.points,
                           odo.map.covariances, np.arange(m), odo.map_sigma**2, P[:12, :12].copy(), assoc.R,
                           odo.T_vehicle_sensor, assoc.gate, *out) == -1
    np.testing.assert_allclose(out[0], pred.z, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out[2], S, rtol=1e-10, atol=1e-14)
    W_all = np.linalg.inv(Smap)
    scale = np.sqrt(np.abs(np.einsum("mii->mi", W_all)))  # each entry against its rows' and columns' scales
    np.testing.assert_allclose(out[4] / (scale[:, :, None] * scale[:, None, :]),
                               W_all / (scale[:, :, None] * scale[:, None, :]), rtol=0, atol=1e-9)
    radius = odo.measurement.search_radius(pred.z, S, assoc.gate)
    assert np.all(out[5] >= radius) and np.allclose(out[5], radius, rtol=1e-7)


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
@pytest.mark.parametrize("first", ["at the sensor", "not positive definite"])
def test_preparation_reports_a_point_at_the_sensor_and_an_s_not_positive_definite(model, first):
    """`prepare` returns the index (in rows) of the first map point at the sensor, or m + the index of the first
    whose S is not positive definite, whichever comes first, also past its first block of points; so does
    `pair_information` for R + map term."""
    from rodo.estimator import prepare_kernels as pkernel

    odo, x, P, _, _, _ = _scene_association(model, 3)
    m = len(odo.map)
    assert m > pkernel.BLOCK + 40
    points, covariances = odo.map.points.copy(), odo.map.covariances.copy()
    at_sensor, indefinite = (pkernel.BLOCK + 5, pkernel.BLOCK + 30)[::1 if first == "at the sensor" else -1]
    T_world_sensor = se3.inverse(x.T_vehicle_world) @ odo.T_vehicle_sensor
    points[at_sensor] = T_world_sensor[:3, 3]
    covariances[indefinite] = -1e6 * np.eye(3)  # S far from positive definite
    out = [np.empty((m, 4)), np.empty((m, 3)), np.empty((m, 4, 4)), np.empty((m, 4, 4)), np.empty((m, 4, 4)),
           np.empty(m)]
    got = pkernel.prepare(odo.measurement.is_polar, x.T_vehicle_world, x.varpi, points, covariances, np.arange(m),
                          odo.map_sigma**2, P[:12, :12].copy(), odo.associator.R, odo.T_vehicle_sensor,
                          odo.associator.gate, *out)
    assert got == (at_sensor if first == "at the sensor" else m + indefinite)
    W = np.empty((m, 4, 4))
    got = pkernel.pair_information(odo.measurement.is_polar, x.T_vehicle_world, x.varpi, points, covariances,
                                   np.arange(m), odo.map_sigma**2, odo.associator.R, odo.T_vehicle_sensor, W)
    assert got == (at_sensor if first == "at the sensor" else m + indefinite)


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_preparation_marks_a_pair_covariance_not_positive_definite_with_nan(model):
    """A map point whose R + map term is not positive definite (its S is, with a wide P) gets NaN for its pair
    information (an error only if it is paired); every other point's is finite."""
    from rodo.estimator import prepare_kernels as pkernel

    odo, x, _, _, _, _ = _scene_association(model, 3)
    m = len(odo.map)
    covariances = odo.map.covariances.copy()
    covariances[pkernel.BLOCK + 7] = -1.0 * np.eye(3)  # -1 m^2: R + J_z_p cov J_z_p^T indefinite
    out = [np.empty((m, 4)), np.empty((m, 3)), np.empty((m, 4, 4)), np.empty((m, 4, 4)), np.empty((m, 4, 4)),
           np.empty(m)]
    got = pkernel.prepare(odo.measurement.is_polar, x.T_vehicle_world, x.varpi, odo.map.points, covariances,
                          np.arange(m), odo.map_sigma**2, 1e6 * np.eye(12), odo.associator.R, odo.T_vehicle_sensor,
                          odo.associator.gate, *out)
    assert got == -1
    nan = np.isnan(out[4]).any(axis=(1, 2))
    np.testing.assert_array_equal(np.flatnonzero(nan), [pkernel.BLOCK + 7])
    assert np.isnan(out[4][pkernel.BLOCK + 7]).all()


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_association_refuses_a_paired_point_whose_pair_covariance_is_not_positive_definite(model):
    """`MapAssociation.associate` raises a clear error, naming the map point, when a point it pairs has an
    R + map term that is not positive definite (its S positive definite, with a wide P)."""
    import copy

    odo, x, P, scan, _, pairs = _scene_association(model, 3)
    bad = int(pairs.map_idx[0])
    local_map = copy.deepcopy(odo.map)  # the scene is cached: a copy to spoil
    local_map._cov[bad] = -1.0 * np.eye(3)  # its public view is read-only
    P_wide = P.copy()
    P_wide[:12, :12] += 100.0 * np.eye(12)
    with pytest.raises(FloatingPointError, match=f"map point {bad} has a non positive definite R \\+ map term"):
        odo.associator.associate(x, P_wide, local_map, copy.deepcopy(scan))


def test_association_window_is_the_same_for_map_points_and_detections():
    """Both sides cut at the field of view shrunk by 3 sigma; a 2D radar's elevation is not windowed."""
    from rodo.estimator.errors import InputError

    D = np.pi / 180
    sig = np.array([0.02, 0.15 * D, 0.3 * D, 0.01])
    odo = RadarOdometry(OdometryConfig(), np.eye(4), sig, 100.0, fov=((-60 * D, 60 * D), (-15 * D, 15 * D)))
    el = np.array([-14.5, -14.0, 0.0, 14.0, 14.5]) * D
    az = np.array([0.0, 59.0, 59.7, -59.0, 0.0]) * D
    polar = np.c_[np.full(5, 20.0), az, el, np.zeros(5)]
    p_sensor = measurements.polar_to_cartesian(polar)
    m_in, d_in = odo.associator.window_masks(p_sensor, polar)
    np.testing.assert_array_equal(m_in, [False, True, False, True, False])
    np.testing.assert_array_equal(d_in, m_in)
    planar = RadarOdometry(OdometryConfig(), np.eye(4), [0.1, 0.01, 0.17, 0.1], 100.0,
                           fov=((-60 * D, 60 * D), (-1e-4, 1e-4)))
    flat = np.c_[np.full(3, 20.0), np.array([-50.0, 0.0, 50.0]) * D, np.zeros(3), np.zeros(3)]
    m_in, d_in = planar.associator.window_masks(measurements.polar_to_cartesian(flat) + [0, 0, 0.5], flat)
    assert m_in.all() and d_in.all()
    with pytest.raises(InputError, match="fov"):
        RadarOdometry(OdometryConfig(), np.eye(4), sig, 100.0, fov=((1.0, -1.0), (-0.1, 0.1)))


@pytest.mark.parametrize("fov", [((-1.05, 1.05), (-0.26, 0.26)), ((-1.05, 1.05), (-1e-4, 1e-4)), None])
@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=20)
def test_compiled_map_window_equals_the_reference(fov, seed):
    """The association's compiled map-point window (`association_kernels.window_points`, from world points and
    the pose) keeps the map points `window_masks` keeps from their sensor-frame positions: a 3-D and a 2D
    radar's field of view, and none."""
    from rodo.estimator import association_kernels as akernel

    rng = np.random.default_rng(seed)
    T_vs = se3.exp(rng.normal(size=6) * [1, 0.5, 0.3, 0.05, 0.05, 0.5])
    odo = RadarOdometry(OdometryConfig(), T_vs, [0.1, 0.01, 0.02, 0.1], 100.0, fov=fov)
    T_vw = se3.exp(rng.normal(size=6) * [20, 20, 1, 0.1, 0.1, 3])
    points = rng.normal(size=(300, 3)) * [40, 40, 5]
    T_sw = se3.inverse(T_vs) @ T_vw
    m_ref, _ = odo.associator.window_masks(se3.transform_points(T_sw, points), np.zeros((0, 4)))
    inside = np.empty(len(points), bool)
    akernel.window_points(points, T_sw, odo.associator.limits, inside)
    np.testing.assert_array_equal(inside, m_ref)
    assert fov is not None or inside.all()


def _greedy_reference(j, i, d2):
    """The one-to-one choice by a plain loop: pairs by (d2, j, i), each taken while both ends are free."""
    used_j, used_i, chosen = set(), set(), np.zeros(len(j), bool)
    for q in sorted(range(len(j)), key=lambda q: (d2[q], j[q], i[q])):
        if j[q] not in used_j and i[q] not in used_i:
            used_j.add(j[q]), used_i.add(i[q])
            chosen[q] = True
    return chosen


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
@given(step=st.lists(st.floats(-1.0, 1.0), min_size=12, max_size=12))
@settings(max_examples=10)
def test_reassociation_rescores_the_candidates_at_the_new_state(model, step):
    """`MapAssociation.reassociate` at a state moved by up to 0.2 m, 10 mrad, 0.5 m/s and 0.1 rad/s (a solve
    moves it less; this much moves candidates across the gate): every candidate the first association scored
    (its pairs among them, and candidates outside the gate) scored with `measurements.predict` at the new state
    and the S^-1 of the readable reference at the first, gated, chosen one to one by a plain greedy loop, and
    each chosen pair's information (R + map term)^-1 at the new state; at the first state, the first association
    itself, bit for bit; pairs of another scan refused."""
    from rodo.estimator import association
    from rodo.estimator.radar_geometry import wrap_angle

    odo, x, P, scan, W0, a0 = _scene_association(model)
    assoc = odo.associator
    W_same, same = assoc.reassociate(x, odo.map, scan, a0)
    for got, ref in ((W_same, W0), (same.map_idx, a0.map_idx), (same.det_idx, a0.det_idx), (same.d2, a0.d2)):
        np.testing.assert_array_equal(got, ref)
    assert len(a0.map_idx) > 100

    d = np.r_[np.full(3, 0.2), np.full(3, 0.01), np.full(3, 0.5), np.full(3, 0.1)] * np.array(step)
    y = x.oplus(np.r_[d, np.zeros(odo.motion.dim - 12)])
    W, got = assoc.reassociate(y, odo.map, scan, a0)

    c = a0.candidates
    pred_x = measurements.predict(odo.config.measurement, x.T_vehicle_world, x.varpi, odo.map.points,
                                  odo.T_vehicle_sensor)
    cov = odo.map.covariances + odo.map_sigma**2 * np.eye(3)
    Smap_x = assoc.R + pred_x.J_z_p @ cov @ np.swapaxes(pred_x.J_z_p, 1, 2)
    S_inv = np.linalg.inv(association.innovation_covariance(pred_x, P[:12, :12], Smap_x, 0.0))[c.rows]
    np.testing.assert_allclose(c.S_inv, S_inv, rtol=1e-8, atol=1e-10 * np.abs(S_inv).max())
    di = scan.cache["di"]
    e_x = scan.z[di[c.i]] - pred_x.z[c.rows[c.j]]
    if odo.measurement.is_polar:
        e_x[:, 1] = wrap_angle(e_x[:, 1])
    assert (np.einsum("ni,nij,nj->n", e_x, S_inv[c.j], e_x) > assoc.gate).any()  # not only the gated ones
    assert set(zip(a0.map_idx, a0.det_idx)) <= set(zip(c.rows[c.j], di[c.i]))
    pred = measurements.predict(odo.config.measurement, y.T_vehicle_world, y.varpi, odo.map.points,
                                odo.T_vehicle_sensor)
    e = scan.z[di[c.i]] - pred.z[c.rows[c.j]]
    if odo.measurement.is_polar:
        e[:, 1] = wrap_angle(e[:, 1])
    d2 = np.einsum("ni,nij,nj->n", e, S_inv[c.j], e)
    inside = d2 <= assoc.gate
    chosen = _greedy_reference(c.j[inside], c.i[inside], d2[inside])
    np.testing.assert_array_equal(got.map_idx, c.rows[c.j[inside][chosen]])
    np.testing.assert_array_equal(got.det_idx, di[c.i[inside][chosen]])
    np.testing.assert_allclose(got.d2, d2[inside][chosen], rtol=1e-7, atol=1e-9)
    Smap = assoc.R + pred.J_z_p @ cov @ np.swapaxes(pred.J_z_p, 1, 2)
    W_ref = np.linalg.inv(Smap[got.map_idx])
    np.testing.assert_allclose(W, W_ref, rtol=1e-8, atol=1e-8 * np.abs(W_ref).max())
    assert got.n_candidates == len(c.j) and got.candidates is c
    from rodo.estimator.scan_association import ScanMeasurements

    with pytest.raises(ValueError, match="this scan"):
        assoc.reassociate(y, odo.map, ScanMeasurements.of(scan.polar[:-1], odo.measurement), a0)
