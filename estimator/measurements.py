"""Radar measurement models: polar (paper eq. 79-85) and the Cartesian baseline (CV/C), with radial velocity.

A map point p_world is seen from the state pose T = T_vehicle_world and the body velocity varpi = [nu; omega]
(paper convention dT/dt = varpi^ T) through the extrinsics T_vehicle_sensor = [C_vs, r_vs]:

    p_v = T p_world,                 dp_v/dt = nu + omega x p_v
    p_s = C_vs^T (p_v - r_vs),       q := dp_s/dt = C_vs^T (nu + omega x p_v)
    v_r = u . q,  u = p_s / |p_s|    (d(range)/dt, negative when approaching; depends on the lever arm)

The two models share v_r and differ in the position part:

    "polar":     z = [r, azimuth = atan2(y_s, x_s), elevation = asin(z_s / r), v_r]      (eq. 79-81)
    "cartesian": z = [x_s, y_s, z_s, v_r]  (detections converted from polar; fixed Cartesian covariance)

The acceleration varpi_dot does not enter a measurement at the scan time: z depends on the pose and the
velocity at t_k only, so the Jacobian w.r.t. varpi_dot is zero (the solver adds a zero block).

Jacobians (derivation in docs/measurements.md), with left perturbation T -> exp(xi^) T, xi = [rho; phi]:

    dp_v/dxi = [I, -p_v^],      dp_s/dxi = C_vs^T [I, -p_v^],      dp_s/dp_world = C_vs^T C
    dq/dp_v  = C_vs^T omega^,   dq/dvarpi = C_vs^T [I, -p_v^]
    dv_r/dp_s = (q - u (u.q))^T / r,   dv_r/dq = u^T

This module is the readable NumPy REFERENCE of the models: the tests check the compiled production path
(`rodo.estimator.measurement_kernels`, `rodo.estimator.association_kernels`) against it, and the figures use
it. The model-specific parts (measurement space, noise, residual) are `MeasurementModel` objects
(`rodo.estimator.measurement_models`); the functions here take a model object or its name.

Checked by: tests/estimator/test_measurements.py::test_jacobians_match_finite_differences,
    ::test_hand_built_scene
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError, check_finite
from .lie import so3
from .measurement_models import MODELS, MeasurementModel, measurement_model
from .radar_geometry import cartesian_position_covariance, cartesian_to_polar_jacobian, check_polar, \
    polar_to_cartesian, polar_to_cartesian_jacobian, wrap_angle

__all__ = ["MODELS", "MIN_RANGE", "Prediction", "predict", "predict_batch", "residual", "to_model_space",
           "noise_covariance", "polar_to_cartesian", "polar_to_cartesian_jacobian", "cartesian_to_polar_jacobian",
           "cartesian_position_covariance", "wrap_angle"]

MIN_RANGE = 1e-9  # m; a point closer than this to the sensor origin has no direction


@dataclass
class Prediction:
    """Predicted measurements of m map points and their Jacobians.

    Attributes:
        z: (m, 4) predicted measurement in the model's space.
        J_z_xi: (m, 4, 6) w.r.t. the left perturbation xi of T (T -> exp(xi^) T).
        J_z_varpi: (m, 4, 6) w.r.t. varpi (varpi -> varpi + eta).
        J_z_p: (m, 4, 3) w.r.t. p_world.
        p_sensor: (m, 3) the points in the sensor frame.
    """

    z: np.ndarray
    J_z_xi: np.ndarray
    J_z_varpi: np.ndarray
    J_z_p: np.ndarray
    p_sensor: np.ndarray


def _check_pose(name: str, T) -> np.ndarray:
    T = check_finite(name, T, (4, 4))
    if T.ndim != 2:
        raise InputError(f"{name}: expected a single (4, 4) pose, got shape {T.shape}")
    C = T[:3, :3]
    if not np.allclose(C.T @ C, np.eye(3), atol=1e-6) or abs(np.linalg.det(C) - 1.0) > 1e-6 \
            or not np.allclose(T[3], [0, 0, 0, 1]):
        raise InputError(f"{name}: not a rigid transform (rotation block not orthonormal or last row not 0 0 0 1)")
    return T


def predict(model: str | MeasurementModel, T_vehicle_world, varpi, p_world, T_vehicle_sensor) -> Prediction:
    """Predicted measurements and Jacobians of map points (paper eq. 76-85; [1] eq. 53 for v_r).

    Args:
        model: "polar" or "cartesian".
        T_vehicle_world: (4, 4) state pose T.
        varpi: (6,) body velocity [nu; omega] at the scan time (acceleration does not enter).
        p_world: (m, 3) map points in world coordinates.
        T_vehicle_sensor: (4, 4) extrinsics.

    Returns:
        Prediction with z (m, 4), J_z_xi (m, 4, 6), J_z_varpi (m, 4, 6), J_z_p (m, 4, 3), p_sensor (m, 3).

    Raises:
        InputError: unknown model, misshaped or non-finite input, a point at the sensor origin.

    Checked by: tests/estimator/test_measurements.py::test_jacobians_match_finite_differences,
        ::test_hand_built_scene
    """
    model = measurement_model(model)
    T = _check_pose("T_vehicle_world", T_vehicle_world)
    T_vehicle_sensor = _check_pose("T_vehicle_sensor", T_vehicle_sensor)
    varpi = check_finite("varpi", varpi, (6,))
    if varpi.shape != (6,):
        raise InputError(f"varpi: expected shape (6,), got {varpi.shape}")
    p_world = check_finite("p_world", p_world, (3,))
    if p_world.ndim != 2:
        raise InputError(f"p_world: expected shape (m, 3), got {p_world.shape}")
    return _predict(model, T[None], varpi[None], p_world, T_vehicle_sensor)


def predict_batch(model: str | MeasurementModel, T_vehicle_world, varpi, p_world, T_vehicle_sensor) -> Prediction:
    """`predict` with one state per point: T_vehicle_world (m, 4, 4), varpi (m, 6), p_world (m, 3).

    The sliding window linearises the measurements of all its states in one call with this. Inputs are
    checked for shape and finiteness only (the poses come from the estimator itself).

    Checked by: tests/estimator/test_measurements.py::test_predict_batch_matches_predict
    """
    model = measurement_model(model)
    T = check_finite("T_vehicle_world", T_vehicle_world, (4, 4))
    varpi = check_finite("varpi", varpi, (6,))
    p_world = check_finite("p_world", p_world, (3,))
    m = len(p_world)
    if T.shape != (m, 4, 4) or varpi.shape != (m, 6) or p_world.shape != (m, 3):
        raise InputError(f"T_vehicle_world, varpi, p_world: expected (m,4,4), (m,6), (m,3) with one m, "
                         f"got {T.shape}, {varpi.shape}, {p_world.shape}")
    return _predict(model, T, varpi, p_world, _check_pose("T_vehicle_sensor", T_vehicle_sensor))


def _predict(model: MeasurementModel, T: np.ndarray, varpi: np.ndarray, p_world: np.ndarray,
             T_vehicle_sensor: np.ndarray) -> Prediction:
    """Shared core; T (1 or m, 4, 4) and varpi (1 or m, 6) broadcast against p_world (m, 3)."""
    m = len(p_world)
    C, Cvs, r_vs = T[:, :3, :3], T_vehicle_sensor[:3, :3], T_vehicle_sensor[:3, 3]
    nu, omega = varpi[:, :3], varpi[:, 3:]
    CvsT = Cvs.T

    p_v = np.matmul(C, p_world[:, :, None])[:, :, 0] + T[:, :3, 3]
    p_s = (p_v - r_vs) @ Cvs                      # rows: C_vs^T (p_v - r_vs)
    r = np.sqrt(np.sum(p_s * p_s, axis=1))
    if np.any(r < MIN_RANGE):
        raise InputError(f"p_world: point {int(np.argmax(r < MIN_RANGE))} is at the sensor origin (range 0)")
    u = p_s / r[:, None]
    q = (nu + np.cross(omega, p_v)) @ Cvs         # dp_s/dt in the sensor frame
    v_r = np.sum(u * q, axis=1)

    # dp_s/dxi = C_vs^T [I, -p_v^]  (m, 3, 6); the same matrix is dq/dvarpi
    J_ps_xi = np.empty((m, 3, 6))
    J_ps_xi[:, :, :3] = CvsT
    J_ps_xi[:, :, 3:] = -(CvsT @ so3.hat(p_v))
    J_ps_p = np.broadcast_to(CvsT @ C, (m, 3, 3))
    J_vr_ps = (q - u * v_r[:, None]) / r[:, None]  # (m, 3)
    # dv_r/dp_v through q: u^T C_vs^T omega^  (m, 3)
    J_vr_pv = np.matmul((u @ CvsT)[:, None, :], so3.hat(omega))[:, 0, :]
    J_vr_varpi = np.matmul(u[:, None, :], J_ps_xi)[:, 0, :]
    J_vr_xi = np.matmul(J_vr_ps[:, None, :], J_ps_xi)[:, 0, :]
    J_vr_xi[:, :3] += J_vr_pv
    J_vr_xi[:, 3:] += np.cross(p_v, J_vr_pv)  # J_vr_pv (-p_v^) = (p_v x J_vr_pv)^T
    J_vr_p = np.matmul(J_vr_ps[:, None, :], J_ps_p)[:, 0, :] + np.matmul(J_vr_pv[:, None, :], C)[:, 0, :]

    z = np.empty((m, 4))
    J_z_xi = np.zeros((m, 4, 6))
    J_z_varpi = np.zeros((m, 4, 6))
    J_z_p = np.empty((m, 4, 3))
    s, J_s_ps = model.position_part(p_s)
    z[:, :3] = s
    J_z_xi[:, :3] = J_ps_xi if J_s_ps is None else J_s_ps @ J_ps_xi
    J_z_p[:, :3] = J_ps_p if J_s_ps is None else J_s_ps @ J_ps_p
    z[:, 3] = v_r
    J_z_xi[:, 3] = J_vr_xi
    J_z_varpi[:, 3] = J_vr_varpi
    J_z_p[:, 3] = J_vr_p
    return Prediction(z=z, J_z_xi=J_z_xi, J_z_varpi=J_z_varpi, J_z_p=J_z_p, p_sensor=p_s)


def to_model_space(model: str | MeasurementModel, polar) -> np.ndarray:
    """Detections (n, 4) [r, az, el, v_r] -> (n, 4) in the model's space (polar: a copy; cartesian: [x, y, z, v_r]).

    Checked by: tests/estimator/test_measurements.py::test_to_model_space_matches_prediction
    """
    return measurement_model(model).to_model_space(polar)


def noise_covariance(model: str | MeasurementModel, polar, sigmas, cartesian_sigma: float) -> np.ndarray:
    """Measurement noise R per detection, (n, 4, 4) (paper eq. 78, 82).

    polar: diag(sigma_r^2, sigma_az^2, sigma_el^2, sigma_vr^2), the same for every detection.
    cartesian (the CV/C baseline): a FIXED diag(c^2, c^2, c^2, sigma_vr^2), c = cartesian_sigma, whatever the
    range; this is what makes the baseline over-confident far away and under-confident close (paper Fig. 2).

    Args:
        model: "polar" or "cartesian".
        polar: (n, 4) detections (only n is used; kept so a range-dependent R can be added).
        sigmas: (4,) 1-sigma of [range (m), azimuth (rad), elevation (rad), radial velocity (m/s)].
        cartesian_sigma: 1-sigma (m) of each Cartesian coordinate (cartesian model only).

    Checked by: tests/estimator/test_measurements.py::test_noise_covariance
    """
    model = measurement_model(model)
    polar = check_polar("polar", polar, 4)
    R = model.noise_covariance(sigmas, cartesian_sigma)
    return np.broadcast_to(R, (len(polar), 4, 4)).copy()


def residual(model: str | MeasurementModel, z_meas, z_pred) -> np.ndarray:
    """e = z_meas - z_pred (paper eq. 83), (n, 4); the polar azimuth difference wrapped to (-pi, pi].

    Checked by: tests/estimator/test_measurements.py::test_residual_wraps_azimuth
    """
    model = measurement_model(model)
    z_meas = check_finite("z_meas", z_meas, (4,))
    z_pred = check_finite("z_pred", z_pred, (4,))
    try:
        e = z_meas - z_pred
    except ValueError:
        raise InputError(f"z_meas, z_pred: shapes {z_meas.shape} and {z_pred.shape} do not broadcast") from None
    return model.residual(e)
