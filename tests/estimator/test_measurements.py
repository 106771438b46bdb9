"""Measurement models: Jacobians against finite differences, a hand-built scene, conversions, noise, residuals."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator import measurements
from rodo.estimator import measurements as ms
from rodo.estimator.measurements import MODELS
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3, so3
from tests.estimator.strategies import cartesian_points
from tests.helpers import left_perturbation_jacobian, numerical_jacobian
from tests.strategies import twists, vectors, vehicle_motion

# a typical front-mounted radar: 3.5 m ahead of the rear axle, 0.5 m up, pitched down 2 deg, yawed 1 deg
T_VS = se3.from_rotation_translation(so3.exp(np.array([0.0, np.deg2rad(2.0), np.deg2rad(1.0)])),
                                     np.array([3.5, 0.1, 0.5]))


def _points_in_front(rng, T, m=5):
    """World points 5..60 m in front of the sensor (so they are well-conditioned for the polar model)."""
    p_s = np.stack([rng.uniform(5, 60, m), rng.uniform(-20, 20, m), rng.uniform(-3, 5, m)], axis=1)
    p_v = se3.transform_points(T_VS, p_s)
    return se3.transform_points(se3.inverse(T), p_v)


@pytest.mark.parametrize("model", ms.MODELS)
@given(xi=twists("vehicle", 50.0), motion=vehicle_motion(),
       front=cartesian_points(5, 5, 1.0).map(lambda u: (u + 1.0) / 2.0))
def test_jacobians_match_finite_differences(model, xi, motion, front):
    T = se3.exp(xi)
    varpi, _ = motion
    # world points 5..60 m in front of the sensor (well-conditioned for the polar model)
    p_s = np.c_[5 + 55 * front[:, 0], -20 + 40 * front[:, 1], -3 + 8 * front[:, 2]]
    p = se3.transform_points(se3.inverse(T), se3.transform_points(T_VS, p_s))
    pred = ms.predict(model, T, varpi, p, T_VS)

    def z_of_T(Tp):
        return ms.predict(model, Tp, varpi, p, T_VS).z

    J_xi = left_perturbation_jacobian(z_of_T, T)  # (m, 4, 6)
    # azimuth never wraps here (points in front), so plain differences are fine
    np.testing.assert_allclose(pred.J_z_xi, J_xi, rtol=1e-5, atol=1e-6)
    J_varpi = numerical_jacobian(lambda w: ms.predict(model, T, w, p, T_VS).z, varpi)
    np.testing.assert_allclose(pred.J_z_varpi, J_varpi, rtol=1e-6, atol=1e-8)
    for j in range(len(p)):
        def z_of_p(pj, j=j):
            q = p.copy()
            q[j] = pj
            return ms.predict(model, T, varpi, q, T_VS).z[j]
        np.testing.assert_allclose(pred.J_z_p[j], numerical_jacobian(z_of_p, p[j]), rtol=1e-5, atol=1e-7)


@given(p=vectors(3, 100.0).filter(lambda v: v[0] > 0.1))  # x > 0: no azimuth wrap in the differences
def test_polar_jacobian_matches_finite_differences(p):
    s, J = ms.cartesian_to_polar_jacobian(p[None])
    num = numerical_jacobian(lambda x: ms.cartesian_to_polar_jacobian(x[None])[0][0], p, eps=1e-7)
    np.testing.assert_allclose(J[0], num, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ms.polar_to_cartesian(s), p[None], atol=1e-10)


def test_hand_built_scene():
    """Independent check: integrate the true motion a tiny step and difference the range for v_r."""
    speed, yaw_rate = 12.0, 0.3                           # forward, turning left
    heading, pos = 0.4, np.array([10.0, -5.0, 0.2])       # vehicle pose in the world
    C_wv = so3.exp(np.array([0.0, 0.0, heading]))
    lever = np.array([3.5, 0.5, 0.8])                     # sensor not at the rear axle; sensor axes = vehicle axes
    T_vs = se3.from_rotation_translation(np.eye(3), lever)
    T = se3.inverse(se3.from_rotation_translation(C_wv, pos))   # T_vehicle_world
    varpi = np.array([-speed, 0, 0, 0, 0, -yaw_rate])      # convention: nu = -v, omega = -w
    # points given by hand in the sensor frame, placed in the world
    p_s_true = np.array([[20.0, 0.0, 0.0], [10.0, 10.0, 0.0], [30.0, -5.0, 3.0], [5.0, 1.0, -1.0]])
    p_w = C_wv @ (p_s_true + lever).T
    p_w = p_w.T + pos

    def sensor_position(t):
        """World position of the sensor origin at time t along the true circular-arc motion."""
        h = heading + yaw_rate * t
        R = speed / yaw_rate
        centre = pos + R * np.array([-np.sin(heading), np.cos(heading), 0.0])
        p_veh = centre + R * np.array([np.sin(h), -np.cos(h), 0.0])
        return p_veh + so3.exp(np.array([0.0, 0.0, h])) @ lever

    dt = 1e-6
    ranges = lambda t: np.linalg.norm(p_w - sensor_position(t), axis=1)
    vr_fd = (ranges(dt) - ranges(-dt)) / (2 * dt)
    expected = np.stack([np.linalg.norm(p_s_true, axis=1), np.arctan2(p_s_true[:, 1], p_s_true[:, 0]),
                         np.arcsin(p_s_true[:, 2] / np.linalg.norm(p_s_true, axis=1)), vr_fd], axis=1)
    pred = ms.predict("polar", T, varpi, p_w, T_vs)
    np.testing.assert_allclose(pred.p_sensor, p_s_true, atol=1e-12)
    np.testing.assert_allclose(pred.z, expected, atol=1e-7)
    # the first point is straight ahead: the sensor's lateral velocity yaw_rate * 3.5 is orthogonal to the line
    # of sight, but the lateral lever arm 0.5 m slows the sensor's forward velocity to speed - yaw_rate * 0.5
    assert pred.z[0, 3] == pytest.approx(-(speed - yaw_rate * 0.5), abs=1e-9)
    # second point at 45 deg left: v_r = -u . v_sensor, v_sensor = [speed - w*0.5, w*3.5, 0]
    v_sensor = np.array([speed - yaw_rate * 0.5, yaw_rate * 3.5, 0.0])
    assert pred.z[1, 3] == pytest.approx(-np.array([1, 1, 0]) @ v_sensor / np.sqrt(2), abs=1e-9)
    cart = ms.predict("cartesian", T, varpi, p_w, T_vs)
    np.testing.assert_allclose(cart.z[:, :3], p_s_true, atol=1e-12)
    np.testing.assert_allclose(cart.z[:, 3], vr_fd, atol=1e-7)


def test_polar_cartesian_round_trip():
    rng = np.random.default_rng(np.random.SeedSequence(1))
    polar = np.stack([rng.uniform(1, 100, 50), rng.uniform(-np.pi, np.pi, 50), rng.uniform(-1.4, 1.4, 50),
                      rng.normal(size=50)], axis=1)
    p = ms.polar_to_cartesian(polar)
    s, _ = ms.cartesian_to_polar_jacobian(p)
    np.testing.assert_allclose(s, polar[:, :3], atol=1e-12)


@pytest.mark.parametrize("model", ms.MODELS)
def test_to_model_space_matches_prediction(model):
    rng = np.random.default_rng(np.random.SeedSequence(2))
    T = se3.exp(np.array([1.0, 2.0, 0.1, 0.01, 0.02, 0.3]))
    varpi = np.array([-10.0, 0.2, 0.0, 0.01, 0.0, -0.2])
    pred_polar = ms.predict("polar", T, varpi, _points_in_front(rng, T, 20), T_VS)
    rng = np.random.default_rng(np.random.SeedSequence(2))
    pred = ms.predict(model, T, varpi, _points_in_front(rng, T, 20), T_VS)
    np.testing.assert_allclose(ms.to_model_space(model, pred_polar.z), pred.z, atol=1e-10)


def test_cartesian_position_covariance_monte_carlo():
    rng = np.random.default_rng(np.random.SeedSequence(3))
    polar = np.array([[40.0, 0.5, 0.1, 0.0], [3.0, -1.0, -0.2, 0.0]])
    sig = np.array([0.02, np.deg2rad(0.15), np.deg2rad(0.3), 0.01])
    P = ms.cartesian_position_covariance(polar, sig)
    N = 200_000
    for k in range(2):
        samples = polar[k, :3] + rng.normal(size=(N, 3)) * sig[:3]
        cov = np.cov(ms.polar_to_cartesian(samples).T)
        # whitened: L^-1 cov L^-T = I up to sampling error (~ sqrt(2 / N) = 0.003) and second-order terms
        Linv = np.linalg.inv(np.linalg.cholesky(P[k]))
        np.testing.assert_allclose(Linv @ cov @ Linv.T, np.eye(3), atol=0.02)
    # far away the polar ellipse is much wider than near (what the fixed Cartesian R ignores)
    assert np.linalg.eigvalsh(P[0]).max() > 50 * np.linalg.eigvalsh(P[1]).max()


def test_noise_covariance():
    polar = np.array([[10.0, 0.1, 0.0, 1.0], [80.0, -0.3, 0.05, -2.0]])
    sig = np.array([0.02, 0.003, 0.005, 0.01])
    R = ms.noise_covariance("polar", polar, sig, 0.3)
    assert R.shape == (2, 4, 4)
    np.testing.assert_allclose(R[1], np.diag(sig**2))
    Rc = ms.noise_covariance("cartesian", polar, sig, 0.3)
    np.testing.assert_allclose(Rc[0], np.diag([0.09, 0.09, 0.09, 1e-4]))
    np.testing.assert_allclose(Rc[0], Rc[1])  # fixed, range-independent (the CV/C baseline)


def test_residual_wraps_azimuth():
    zm = np.array([[10.0, np.pi - 0.01, 0.0, 1.0]])
    zp = np.array([[9.0, -np.pi + 0.01, 0.1, 0.5]])
    e = ms.residual("polar", zm, zp)
    np.testing.assert_allclose(e, [[1.0, -0.02, -0.1, 0.5]], atol=1e-12)
    assert ms.residual("polar", [[0, np.pi, 0, 0]], [[0, 0, 0, 0]])[0, 1] == pytest.approx(np.pi)
    assert ms.residual("polar", [[0, -np.pi, 0, 0]], [[0, 0, 0, 0]])[0, 1] == pytest.approx(np.pi)
    np.testing.assert_allclose(ms.residual("cartesian", zm, zp)[0, 1], 2 * np.pi - 0.02)


def test_bad_input_names_the_argument():
    T = np.eye(4)
    with pytest.raises(InputError, match="model"):
        ms.predict("spherical", T, np.zeros(6), np.ones((1, 3)), T)
    with pytest.raises(InputError, match="varpi"):
        ms.predict("polar", T, np.zeros(5), np.ones((1, 3)), T)
    with pytest.raises(InputError, match="p_world"):
        ms.predict("polar", T, np.zeros(6), np.array([[0.0, 0, 0]]), T)
    with pytest.raises(InputError, match="p_world"):
        ms.predict("polar", T, np.zeros(6), np.array([[np.nan, 0, 0]]), T)
    with pytest.raises(InputError, match="T_vehicle_sensor"):
        ms.predict("polar", T, np.zeros(6), np.ones((1, 3)), 2 * T)
    with pytest.raises(InputError, match="sigmas"):
        ms.noise_covariance("polar", np.ones((1, 4)), [1, 1, 1], 0.1)
    with pytest.raises(InputError, match="polar"):
        ms.to_model_space("polar", np.ones((3, 2)))


@pytest.mark.parametrize("model", MODELS)
def test_predict_batch_matches_predict(model):
    """One state per point (the window's batched linearisation) equals per-state calls."""
    rng = np.random.default_rng(7)
    Tvs = se3.exp(np.r_[3.5, 0.1, 0.5, 0.01, 0.02, 0.03])
    poses = [se3.exp(rng.normal(size=6) * [5, 5, 1, 0.1, 0.1, 0.5]) for _ in range(3)]
    varpis = [rng.normal(size=6) * [10, 1, 1, 0.1, 0.1, 0.3] for _ in range(3)]
    pts = [rng.uniform(-50, 50, size=(20, 3)) + [60, 0, 0] for _ in range(3)]
    # keep points in front of each sensor so ranges are well defined
    singles = [measurements.predict(model, T, w, p, Tvs) for T, w, p in zip(poses, varpis, pts)]
    batch = measurements.predict_batch(model, np.repeat(np.stack(poses), 20, axis=0),
                                       np.repeat(np.stack(varpis), 20, axis=0), np.concatenate(pts), Tvs)
    for field in ("z", "J_z_xi", "J_z_varpi", "J_z_p", "p_sensor"):
        np.testing.assert_allclose(getattr(batch, field), np.concatenate([getattr(s, field) for s in singles]),
                                   rtol=1e-13, atol=1e-12)


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 40))
def test_world_position_covariance_is_the_rotated_reference(seed, n):
    """What a new map point inherits: the compiled polar propagation rotated into the world
    (`measurement_kernels.position_covariances`) = C (J diag(s^2) J^T) C^T from the NumPy reference; the
    Cartesian model's C (sigma^2 I) C^T."""
    from rodo.estimator.measurement_models import CartesianModel, PolarModel

    rng = np.random.default_rng(seed)
    polar = np.c_[rng.uniform(0.5, 120, n), rng.uniform(-1.5, 1.5, n), rng.uniform(-0.5, 0.5, n), rng.normal(0, 5, n)]
    sig = np.array([0.1, 0.01, 0.02, 0.05])
    C = se3.exp(rng.normal(size=6))[:3, :3]
    want = C @ ms.cartesian_position_covariance(polar, sig) @ C.T
    got = PolarModel().world_position_covariance(polar, sig, 0.3, C)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12 * max(np.abs(want).max(initial=0.0), 1e-300))
    np.testing.assert_array_equal(got, np.swapaxes(got, 1, 2))
    np.testing.assert_allclose(CartesianModel().world_position_covariance(polar, sig, 0.3, C),
                               np.broadcast_to(0.09 * C @ C.T, (n, 3, 3)), rtol=1e-12, atol=1e-16)
