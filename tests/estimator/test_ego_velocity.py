"""Doppler ego-velocity: exact on noise-free data, robust to moving objects, standstill, failure modes."""

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from rodo.estimator.ego_velocity import doppler_inliers, estimate_ego_velocity, least_squares_velocity
from rodo.estimator.errors import InputError
from tests.estimator.strategies import directions
from tests.strategies import vectors


def _rng(seed):
    return np.random.default_rng(np.random.SeedSequence(seed))


def _scene(rng, v, n=200, planar=False, sigma=0.0, az_fov=np.deg2rad(60), el_fov=np.deg2rad(15)):
    az = rng.uniform(-az_fov, az_fov, n)
    el = np.zeros(n) if planar else rng.uniform(-el_fov, el_fov, n)
    u = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    vr = -u @ v + sigma * rng.normal(size=n)
    return az, el, vr


def _noise_free(v, az_el):
    az, el = az_el[:, 0], az_el[:, 1]
    u = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    return az, el, -u @ v


@given(v=vectors(3, 30.0), az_el=directions(50), seed=st.integers(0, 2**32 - 1))
def test_exact_on_noise_free_data_3d(v, az_el, seed):
    az, el, vr = _noise_free(v, az_el)
    est = estimate_ego_velocity(az, el, vr, _rng(seed))
    assert est.ok and not est.planar and est.inliers.all()
    np.testing.assert_allclose(est.v_sensor, v, atol=1e-9)


@given(v=vectors(2, 30.0), az_el=directions(30, planar=True), seed=st.integers(0, 2**32 - 1))
def test_exact_on_noise_free_data_planar(v, az_el, seed):
    v3 = np.r_[v, 0.0]
    az, el, vr = _noise_free(v3, az_el)
    est = estimate_ego_velocity(az, el, vr, _rng(seed))
    assert est.ok and est.planar and est.inliers.all()
    np.testing.assert_allclose(est.v_sensor, v3, atol=1e-9)
    assert np.all(est.covariance[2] == 0) and np.all(est.covariance[:, 2] == 0)


@pytest.mark.parametrize("outlier_fraction", [0.3, 0.4])
@pytest.mark.parametrize("seed", range(5))
def test_robust_to_moving_objects(outlier_fraction, seed):
    """Static world plus several moving objects (each a cluster with its own velocity)."""
    rng = _rng(seed)
    v = np.array([12.0, -0.5, 0.1])
    n = 300
    n_out = int(outlier_fraction * n)
    az, el, vr = _scene(rng, v, n=n, sigma=0.01)
    # three moving objects: clusters of detections whose targets move with random velocities
    labels = rng.integers(0, 3, n_out)
    centres = rng.uniform(-1.0, 1.0, 3)
    az[:n_out] = centres[labels] + rng.normal(0, 0.03, n_out)
    v_obj = rng.normal(0, 10, (3, 3))
    u = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    vr[:n_out] = np.einsum("ij,ij->i", u[:n_out], v_obj[labels] - v) + 0.01 * rng.normal(size=n_out)
    est = estimate_ego_velocity(az, el, vr, rng, sigma_vr=0.01)
    assert est.ok
    np.testing.assert_allclose(est.v_sensor, v, atol=0.05)
    assert est.inliers[n_out:].mean() > 0.97
    assert est.inliers[:n_out].mean() < 0.05
    # the covariance matches the actual error scale: the whitened error is plausible (chi2_3 99.9 % = 16.3)
    e = est.v_sensor - v
    assert e @ np.linalg.solve(est.covariance, e) < 16.3


def test_covariance_matches_monte_carlo():
    v = np.array([8.0, 1.0, -0.3])
    geo = _rng(100)
    az = geo.uniform(-1, 1, 80)
    el = geo.uniform(-0.25, 0.25, 80)
    u = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    rng = _rng(101)
    errs, covs = [], []
    for _ in range(300):
        vr = -u @ v + 0.01 * rng.normal(size=80)
        est = estimate_ego_velocity(az, el, vr, rng, sigma_vr=0.01)
        errs.append(est.v_sensor - v)
        covs.append(est.covariance)
    emp = np.cov(np.array(errs).T)
    mean_cov = np.mean(covs, axis=0)
    Linv = np.linalg.inv(np.linalg.cholesky(mean_cov))
    np.testing.assert_allclose(Linv @ emp @ Linv.T, np.eye(3), atol=0.25)  # 300 samples: ~ +-0.08 per entry


def test_lead_truck_dominating_the_scan():
    """A truck ahead fills 45 % of the detections; the static world is still the largest consistent set."""
    rng = _rng(7)
    v = np.array([15.0, 0.0, 0.0])
    az, el, vr = _scene(rng, v, n=200, sigma=0.01)
    n_truck = 90
    az[:n_truck] = rng.normal(0, 0.05, n_truck)
    el[:n_truck] = rng.uniform(-0.05, 0.1, n_truck)
    u = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    vr[:n_truck] = u[:n_truck] @ (np.array([14.0, 0, 0]) - v) + 0.01 * rng.normal(size=n_truck)  # truck at 14 m/s
    est = estimate_ego_velocity(az, el, vr, rng)
    assert est.ok
    np.testing.assert_allclose(est.v_sensor, v, atol=0.05)
    assert not est.inliers[:n_truck].any()


def test_near_keeps_the_consensus_next_to_the_prediction():
    """A truck with more detections than the static world wins a free RANSAC; gated near the predicted
    velocity (off by 0.3 m/s: hard braking) the static world wins and is refitted exactly."""
    rng = _rng(11)
    v = np.array([8.0, 0.2, 0.0])
    az, el, vr = _scene(rng, v, n=100, sigma=0.005)
    n_truck = 150
    az_t, el_t = rng.normal(0, 0.1, n_truck), rng.uniform(-0.05, 0.1, n_truck)
    u_t = np.stack([np.cos(el_t) * np.cos(az_t), np.cos(el_t) * np.sin(az_t), np.sin(el_t)], axis=1)
    vr_t = u_t @ (np.array([7.0, 0, 0]) - v) + 0.005 * rng.normal(size=n_truck)  # truck at 7 m/s
    az, el, vr = np.r_[az_t, az], np.r_[el_t, el], np.r_[vr_t, vr]
    free = estimate_ego_velocity(az, el, vr, _rng(1), sigma_vr=0.005)
    assert free.inliers[:n_truck].all()  # the larger, wrong consensus
    gated = estimate_ego_velocity(az, el, vr, _rng(1), sigma_vr=0.005, near=(v + [0.3, 0, 0], 0.5))
    assert gated.ok and not gated.inliers[:n_truck].any() and gated.inliers[n_truck:].all()
    np.testing.assert_allclose(gated.v_sensor, v, atol=0.01)
    # nothing near the prediction: not ok, never the far consensus
    far = estimate_ego_velocity(az, el, vr, _rng(1), sigma_vr=0.005, near=(v + [3.0, 0, 0], 0.5))
    assert not far.ok and not far.inliers.any()


def test_per_detection_threshold():
    """One threshold per detection: a detection whose own threshold is tight becomes an outlier."""
    rng = _rng(12)
    v = np.array([5.0, 0.0, 0.0])
    az, el, vr = _scene(rng, v, n=40)
    vr[0] += 0.1
    loose = estimate_ego_velocity(az, el, vr, _rng(2), threshold=np.full(40, 0.2))
    tight = np.full(40, 0.2)
    tight[0] = 0.05
    strict = estimate_ego_velocity(az, el, vr, _rng(2), threshold=tight)
    assert loose.inliers[0] and not strict.inliers[0] and strict.inliers[1:].all()
    with pytest.raises(InputError, match="threshold"):
        estimate_ego_velocity(az, el, vr, _rng(2), threshold=np.full(39, 0.2))
    with pytest.raises(InputError, match="near radius"):
        estimate_ego_velocity(az, el, vr, _rng(2), near=(v, 0.0))


@pytest.mark.parametrize("dof", [2, 3])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 60), m=st.integers(1, 12))
def test_inlier_counts_equal_the_numpy_expression(dof, seed, n, m):
    """The RANSAC's compiled scoring counts, per hypothesis, the detections the NumPy expression
    |U v - b| <= threshold counts (planar and 3-D, random hypotheses and the zero one, per-detection
    thresholds, empty scans)."""
    from rodo.estimator.doppler_kernels import count_inliers

    rng = _rng(seed)
    az, el, vr = _scene(rng, rng.normal(size=3) * 10, n=n, planar=dof == 2, sigma=0.05)
    U = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)[:, :dof]
    hyps = np.vstack([np.zeros(dof), rng.normal(size=(m - 1, dof)) * 10])
    threshold = rng.uniform(0.01, 0.2, n)
    want = (np.abs(U @ hyps.T + vr[:, None]) <= threshold[:, None]).sum(axis=0)
    np.testing.assert_array_equal(count_inliers(np.ascontiguousarray(U), -vr, hyps, threshold), want)


def _reference_ransac(U, b, draws, threshold, ref, radius, sigma_vr2):
    """The RANSAC in NumPy as it was before it was compiled (LAPACK's LU for the minimal sets, its SVD for the
    least squares and the condition number): (v, cov, inliers) or None."""
    dof = U.shape[1]
    A = U[draws]
    good = np.abs(np.linalg.det(A)) > 1e-6
    hyps = np.concatenate([ref[None], np.linalg.solve(A[good], b[draws[good]][..., None])[..., 0]])
    hyps = hyps[np.linalg.norm(hyps - ref, axis=1) <= radius]
    counts = (np.abs(U @ hyps.T - b[:, None]) <= threshold[:, None]).sum(axis=0)
    v = hyps[np.lexsort((np.linalg.norm(hyps - ref, axis=1), -counts))[0]]
    inl = np.abs(U @ v - b) <= threshold
    if inl.sum() < dof:
        return None
    for _ in range(2):
        v_new = np.linalg.lstsq(U[inl], b[inl], rcond=None)[0]
        inl_new = np.abs(U @ v_new - b) <= threshold
        if inl_new.sum() < dof:
            break
        v, inl = v_new, inl_new
    info = U[inl].T @ U[inl]
    if np.linalg.cond(info) > 1e12:
        return None
    v = np.linalg.solve(info, U[inl].T @ b[inl])
    res = U[inl] @ v - b[inl]
    s2 = res @ res / (inl.sum() - dof) if inl.sum() > dof else sigma_vr2
    return v, max(s2, 1e-12) * np.linalg.inv(info), inl


@pytest.mark.parametrize("dof", [2, 3])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 80), near=st.booleans(),
       outliers=st.floats(0.0, 0.45))
@example(seed=365, n=3, near=False, outliers=0.0)  # condition number 1e11 (a clean clone's CI, session 51)
def test_compiled_ransac_equals_the_numpy_reference(dof, seed, n, near, outliers):
    """The compiled RANSAC (`doppler_kernels.ransac`: Cramer's rule, normal equations) picks the hypothesis,
    the inliers and the fit the NumPy reference does (LAPACK), to rounding: a static world with a moving
    group, noise, per-detection thresholds, free or gated near a prediction, planar or 3-D, empty scans.
    Ill-conditioned fits (a few detections in nearly one plane) agree to their condition number times eps."""
    from rodo.estimator.doppler_kernels import ransac

    rng = _rng(seed)
    v = rng.normal(size=3) * 8 * ([1, 1, 0] if dof == 2 else 1)
    az, el, vr = _scene(rng, v, n=n, planar=dof == 2, sigma=0.02)
    k = int(outliers * n)
    vr[:k] += rng.normal(3.0, 0.01, k)  # one object moving at about 3 m/s radially
    U = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)[:, :dof]
    threshold = rng.uniform(0.04, 0.08, n)
    draws = rng.integers(0, max(n, 1), size=(100, dof)) if n else np.zeros((100, dof), np.int64)
    ref = v[:dof] + rng.normal(0, 0.1, dof) if near else np.zeros(dof)
    radius = 0.5 if near else np.inf
    if n < dof:
        return
    want = _reference_ransac(U, -vr, draws, threshold, ref, radius, 0.02**2)
    got_v, got_cov, got_inl = np.empty(dof), np.empty((dof, dof)), np.empty(n, bool)
    ok = ransac(np.ascontiguousarray(U), -vr, draws, threshold, ref, radius, 0.02**2, got_v, got_cov, got_inl)
    assert ok == (want is not None)
    if ok:
        np.testing.assert_array_equal(got_inl, want[2])
        # rounding grows with the fit's condition number (accepted up to 1e12: three nearly coplanar directions,
        # seed 365, n 3, read 1e11 and agree to 1.6e-6)
        rounding = 10 * np.finfo(float).eps * np.linalg.cond(U[want[2]].T @ U[want[2]])
        np.testing.assert_allclose(got_v, want[0], rtol=1e-9 + rounding, atol=1e-9)
        np.testing.assert_allclose(got_cov, want[1], rtol=1e-7 + rounding, atol=1e-15)


def test_least_squares_velocity():
    """Exact on noise-free data (3D and planar), the covariance floor, and None where it cannot fit."""
    rng = _rng(13)
    v = np.array([6.0, -0.4, 0.2])
    az, el, vr = _scene(rng, v, n=30)
    fit = least_squares_velocity(az, el, vr, variance_floor=1e-4)
    np.testing.assert_allclose(fit[0], v, atol=1e-10)
    U = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    np.testing.assert_allclose(fit[1], 1e-4 * np.linalg.inv(U.T @ U), rtol=1e-10)  # no residual: the floor
    az, el, vr = _scene(rng, v * [1, 1, 0], n=30, planar=True)
    fit = least_squares_velocity(az, el, vr, variance_floor=1e-6)
    np.testing.assert_allclose(fit[0], v[:2], atol=1e-10)
    assert least_squares_velocity(az[:2], el[:2], vr[:2], variance_floor=1e-6) is None  # no redundancy
    assert least_squares_velocity(np.zeros(5), np.zeros(5), np.ones(5), variance_floor=1e-6) is None  # one direction


def test_standstill_moving_object_does_not_win():
    rng = _rng(8)
    az, el, vr = _scene(rng, np.zeros(3), n=60, sigma=0.005)
    # a pedestrian crossing with 20 detections (fewer than the static world)
    az[:20] = 0.3 + rng.normal(0, 0.02, 20)
    vr[:20] = -1.4 * np.sin(az[:20]) + 0.005 * rng.normal(size=20)
    est = estimate_ego_velocity(az, el, vr, rng, sigma_vr=0.005)
    assert est.ok
    assert np.linalg.norm(est.v_sensor) < 0.02
    assert est.inliers[20:].all() and not est.inliers[:20].any()


def test_standstill_tie_goes_to_the_smaller_velocity():
    """Two equally large consistent sets: the standstill one wins (ties to the smaller velocity)."""
    az = np.deg2rad(np.array([-40.0, -10.0, 20.0, 45.0]))
    el = np.zeros(4)
    v_moving = np.array([3.0, 1.0, 0.0])
    vr = np.r_[0.0, 0.0, -np.cos(az[2:]) * 3.0 - np.sin(az[2:]) * 1.0]
    for seed in range(5):
        est = estimate_ego_velocity(az, el, vr, _rng(seed), threshold=0.05)
        assert est.ok and est.planar
        np.testing.assert_allclose(est.v_sensor, 0.0, atol=1e-12)
        np.testing.assert_array_equal(est.inliers, [True, True, False, False])
    assert np.abs(vr[2:] + np.stack([np.cos(az[2:]), np.sin(az[2:])], 1) @ v_moving[:2]).max() < 1e-12


def test_quantised_doppler():
    rng = _rng(9)
    v = np.array([10.0, 0.3, 0.0])
    step = 0.05
    az, el, vr = _scene(rng, v, n=150)
    vr = np.round(vr / step) * step
    est = estimate_ego_velocity(az, el, vr, rng, sigma_vr=step / np.sqrt(12))
    assert est.ok and est.inliers.all()
    np.testing.assert_allclose(est.v_sensor, v, atol=0.03)


def test_too_few_points_is_not_ok():
    rng = _rng(10)
    for n, planar in [(0, None), (1, True), (2, False)]:
        az, el, vr = _scene(rng, np.array([5.0, 0, 0]), n=n)
        est = estimate_ego_velocity(az, el, vr, rng, planar=planar)
        assert not est.ok
        assert np.all(np.isfinite(est.v_sensor)) and np.all(np.isfinite(est.covariance))
        assert est.inliers.shape == (n,)
    # collinear detections: all from one direction, no 3-D solution
    est = estimate_ego_velocity(np.zeros(5), np.zeros(5) + 0.1, -np.ones(5), rng, planar=False)
    assert not est.ok and np.all(np.isfinite(est.v_sensor))


def test_deterministic_given_the_generator():
    az, el, vr = _scene(_rng(11), np.array([7.0, 1.0, 0.2]), n=100, sigma=0.02)
    vr[:30] += 3.0
    a = estimate_ego_velocity(az, el, vr, _rng(12))
    b = estimate_ego_velocity(az, el, vr, _rng(12))
    assert a.v_sensor.tobytes() == b.v_sensor.tobytes()
    np.testing.assert_array_equal(a.inliers, b.inliers)


def test_doppler_inliers():
    az = np.array([0.0, 0.5, -0.5])
    el = np.zeros(3)
    v = np.array([10.0, 0.0, 0.0])
    vr = -10.0 * np.cos(az) + np.array([0.0, 0.04, 0.2])
    np.testing.assert_array_equal(doppler_inliers(az, el, vr, v, 0.05), [True, True, False])


def test_bad_input_names_the_argument():
    rng = _rng(0)
    with pytest.raises(InputError, match="elevation"):
        estimate_ego_velocity(np.zeros(3), np.zeros(2), np.zeros(3), rng)
    with pytest.raises(InputError, match="radial_velocity"):
        estimate_ego_velocity(np.zeros(3), np.zeros(3), [0, np.nan, 0], rng)
    with pytest.raises(InputError, match="rng"):
        estimate_ego_velocity(np.zeros(3), np.zeros(3), np.zeros(3), 0)
    with pytest.raises(InputError, match="v_sensor"):
        doppler_inliers(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(2), 0.1)


def test_cli_ego_velocity(tmp_path):
    """End to end: a hand-made sequence (3-D scan with a moving object, planar scan, too-few scan) -> CSV."""
    seq_mod = pytest.importorskip("rodo.sim.sequence")
    from rodo.cli import main
    from rodo.commands import ego_velocity as cmd

    rng = _rng(20)
    v1 = np.array([10.0, 0.5, -0.2])
    az, el, vr = _scan_with_object(rng, v1)
    v2 = np.array([5.0, -1.0, 0.0])
    az2, el2, vr2 = _scene(rng, v2, n=40, planar=True, sigma=0.01)
    scans = [seq_mod.RadarScan(0, 0.0, np.full(len(az), 20.0), az, el, vr),
             seq_mod.RadarScan(1, 1 / 13, np.full(40, 20.0), az2, el2, vr2),
             seq_mod.RadarScan(2, 2 / 13, np.full(2, 20.0), az[:2], el[:2], vr[:2])]
    sensor = seq_mod.SensorConfig(rate_hz=13.0, T_vehicle_sensor=np.eye(4),
                                  noise=seq_mod.NoiseSigmas(0.02, 0.003, 0.005, 0.01),
                                  azimuth_fov=(-1.2, 1.2), elevation_fov=(-0.3, 0.3), max_range=100.0)
    seq_mod.write_sequence(tmp_path / "seq", seq_mod.Sequence(sensor=sensor, scans=scans))
    out = tmp_path / "ego.csv"
    assert main([ "ego-velocity", str(tmp_path / "seq"), "--out", str(out), "--seed", "3"], commands=[cmd]) == 0
    lines = out.read_text().splitlines()
    assert lines[0] == "scan,t,vx,vy,vz,inliers"
    rows = [line.split(",") for line in lines[1:]]
    assert [r[0] for r in rows] == ["0", "1", "2"]
    np.testing.assert_allclose([float(x) for x in rows[0][2:5]], v1, atol=0.05)
    assert int(rows[0][5]) == 140
    np.testing.assert_allclose([float(x) for x in rows[1][2:5]], v2, atol=0.05)
    assert rows[1][4] == "0"                                             # planar scan: vz = 0
    assert rows[2][2:] == ["nan", "nan", "nan", "0"]                     # fit failed
    first = out.read_bytes()
    assert main(["ego-velocity", str(tmp_path / "seq"), "--out", str(out), "--seed", "3"], commands=[cmd]) == 0
    assert out.read_bytes() == first                                     # deterministic
    assert main(["ego-velocity", str(tmp_path / "nope"), "--out", str(out)], commands=[cmd]) == 2


def _scan_with_object(rng, v, n=200, n_obj=60):
    """Static world (n - n_obj detections, the last ones) plus one moving object (the first n_obj)."""
    az, el, vr = _scene(rng, v, n=n, sigma=0.01)
    u = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    vr[:n_obj] = u[:n_obj] @ (np.array([-8.0, 2.0, 0.0]) - v)
    return az, el, vr
