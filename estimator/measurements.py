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

Checked by: tests/estimator/test_measurements.py (finite differences, a hand-built scene)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rodo.estimator.errors import InputError, check_finite
from rodo.estimator.lie import so3

MODELS = ("polar", "cartesian")
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


def _check_model(model: str) -> str:
    if model not in MODELS:
        raise InputError(f"model: expected one of {MODELS}, got {model!r}")
    return model


def _check_pose(name: str, T) -> np.ndarray:
    T = check_finite(name, T, (4, 4))
    if T.ndim != 2:
        raise InputError(f"{name}: expected a single (4, 4) pose, got shape {T.shape}")
    C = T[:3, :3]
    if not np.allclose(C.T @ C, np.eye(3), atol=1e-6) or abs(np.linalg.det(C) - 1.0) > 1e-6 \
            or not np.allclose(T[3], [0, 0, 0, 1]):
        raise InputError(f"{name}: not a rigid transform (rotation block not orthonormal or last row not 0 0 0 1)")
    return T


def _check_polar(name: str, polar, min_cols: int = 4) -> np.ndarray:
    polar = check_finite(name, polar)
    if polar.ndim != 2 or polar.shape[1] < min_cols:
        raise InputError(f"{name}: expected shape (n, {min_cols}) [range, azimuth, elevation, ...], got {polar.shape}")
    if np.any(polar[:, 0] < 0):
        raise InputError(f"{name}: negative range in row {int(np.argmax(polar[:, 0] < 0))}")
    return polar


def cartesian_to_polar_jacobian(p_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """s(p) = [r, atan2(y, x), asin(z / r)] and ds/dp (paper eq. 80, 85), (m, 3) -> (m, 3), (m, 3, 3).

    dr/dp = p^T / r,  daz/dp = [-y, x, 0] / rho^2,  del/dp = [-x z, -y z, rho^2] / (r^2 rho), rho = |[x, y]|.
    Straight above/below the sensor (rho = 0) the azimuth is undefined; rho is floored at 1e-12 r there.

    Checked by: tests/estimator/test_measurements.py::test_polar_jacobian_matches_finite_differences
    """
    x, y, zc = p_sensor[:, 0], p_sensor[:, 1], p_sensor[:, 2]
    r = np.linalg.norm(p_sensor, axis=1)
    rho = np.maximum(np.hypot(x, y), 1e-12 * r)
    s = np.stack([r, np.arctan2(y, x), np.arcsin(np.clip(zc / r, -1.0, 1.0))], axis=1)
    J = np.zeros((len(r), 3, 3))
    J[:, 0, :] = p_sensor / r[:, None]
    J[:, 1, 0] = -y / rho**2
    J[:, 1, 1] = x / rho**2
    d = (r**2 * rho)
    J[:, 2, 0] = -x * zc / d
    J[:, 2, 1] = -y * zc / d
    J[:, 2, 2] = rho**2 / d
    return s, J


def predict(model: str, T_vehicle_world, varpi, p_world, T_vehicle_sensor) -> Prediction:
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
    _check_model(model)
    T = _check_pose("T_vehicle_world", T_vehicle_world)
    Tvs = _check_pose("T_vehicle_sensor", T_vehicle_sensor)
    varpi = check_finite("varpi", varpi, (6,))
    if varpi.shape != (6,):
        raise InputError(f"varpi: expected shape (6,), got {varpi.shape}")
    p_world = check_finite("p_world", p_world, (3,))
    if p_world.ndim != 2:
        raise InputError(f"p_world: expected shape (m, 3), got {p_world.shape}")
    return _predict(model, T[None], varpi[None], p_world, Tvs)


def predict_batch(model: str, T_vehicle_world, varpi, p_world, T_vehicle_sensor) -> Prediction:
    """`predict` with one state per point: T_vehicle_world (m, 4, 4), varpi (m, 6), p_world (m, 3).

    The sliding window linearises the measurements of all its states in one call with this. Inputs are
    checked for shape and finiteness only (the poses come from the estimator itself).

    Checked by: tests/estimator/test_measurements.py::test_predict_batch_matches_predict
    """
    _check_model(model)
    T = check_finite("T_vehicle_world", T_vehicle_world, (4, 4))
    varpi = check_finite("varpi", varpi, (6,))
    p_world = check_finite("p_world", p_world, (3,))
    m = len(p_world)
    if T.shape != (m, 4, 4) or varpi.shape != (m, 6) or p_world.shape != (m, 3):
        raise InputError(f"T_vehicle_world, varpi, p_world: expected (m,4,4), (m,6), (m,3) with one m, "
                         f"got {T.shape}, {varpi.shape}, {p_world.shape}")
    return _predict(model, T, varpi, p_world, _check_pose("T_vehicle_sensor", T_vehicle_sensor))


def _predict(model: str, T: np.ndarray, varpi: np.ndarray, p_world: np.ndarray, Tvs: np.ndarray) -> Prediction:
    """Shared core; T (1 or m, 4, 4) and varpi (1 or m, 6) broadcast against p_world (m, 3)."""
    m = len(p_world)
    C, Cvs, r_vs = T[:, :3, :3], Tvs[:3, :3], Tvs[:3, 3]
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
    if model == "polar":
        s, J_s_ps = cartesian_to_polar_jacobian(p_s)
        z[:, :3] = s
        J_z_xi[:, :3] = J_s_ps @ J_ps_xi
        J_z_p[:, :3] = J_s_ps @ J_ps_p
    else:
        z[:, :3] = p_s
        J_z_xi[:, :3] = J_ps_xi
        J_z_p[:, :3] = J_ps_p
    z[:, 3] = v_r
    J_z_xi[:, 3] = J_vr_xi
    J_z_varpi[:, 3] = J_vr_varpi
    J_z_p[:, 3] = J_vr_p
    return Prediction(z=z, J_z_xi=J_z_xi, J_z_varpi=J_z_varpi, J_z_p=J_z_p, p_sensor=p_s)


def polar_to_cartesian(polar) -> np.ndarray:
    """x = r cos(el) cos(az), y = r cos(el) sin(az), z = r sin(el); (n, >=3) -> (n, 3) sensor frame.

    Checked by: tests/estimator/test_measurements.py::test_polar_cartesian_round_trip
    """
    polar = _check_polar("polar", polar, 3)
    r, az, el = polar[:, 0], polar[:, 1], polar[:, 2]
    ce = np.cos(el)
    return np.stack([r * ce * np.cos(az), r * ce * np.sin(az), r * np.sin(el)], axis=1)


def polar_to_cartesian_jacobian(polar) -> np.ndarray:
    """d[x, y, z]/d[r, az, el] of `polar_to_cartesian`, (n, >=3) -> (n, 3, 3).

    Checked by: tests/estimator/test_measurements.py::test_cartesian_position_covariance_monte_carlo
    """
    polar = _check_polar("polar", polar, 3)
    r, az, el = polar[:, 0], polar[:, 1], polar[:, 2]
    ca, sa, ce, se = np.cos(az), np.sin(az), np.cos(el), np.sin(el)
    J = np.empty((len(r), 3, 3))
    J[:, :, 0] = np.stack([ce * ca, ce * sa, se], axis=1)
    J[:, :, 1] = np.stack([-r * ce * sa, r * ce * ca, np.zeros_like(r)], axis=1)
    J[:, :, 2] = np.stack([-r * se * ca, -r * se * sa, r * ce], axis=1)
    return J


def to_model_space(model: str, polar) -> np.ndarray:
    """Detections (n, 4) [r, az, el, v_r] -> (n, 4) in the model's space (polar: a copy; cartesian: [x, y, z, v_r]).

    Checked by: tests/estimator/test_measurements.py::test_to_model_space_matches_prediction
    """
    _check_model(model)
    polar = _check_polar("polar", polar, 4)
    if model == "polar":
        return polar[:, :4].copy()
    return np.concatenate([polar_to_cartesian(polar), polar[:, 3:4]], axis=1)


def _check_sigmas(sigmas) -> np.ndarray:
    sigmas = check_finite("sigmas", sigmas, (4,))
    if sigmas.shape != (4,) or np.any(sigmas <= 0):
        raise InputError(f"sigmas: expected 4 positive values [range, azimuth, elevation, radial_velocity], "
                         f"got {sigmas.tolist()}")
    return sigmas


def noise_covariance(model: str, polar, sigmas, cartesian_sigma: float) -> np.ndarray:
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
    _check_model(model)
    polar = _check_polar("polar", polar, 4)
    sigmas = _check_sigmas(sigmas)
    if model == "polar":
        d = sigmas**2
    else:
        c = float(check_finite("cartesian_sigma", cartesian_sigma))
        if not c > 0:
            raise InputError(f"cartesian_sigma: must be > 0, got {c}")
        d = np.array([c * c, c * c, c * c, sigmas[3] ** 2])
    return np.broadcast_to(np.diag(d), (len(polar), 4, 4)).copy()


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles to (-pi, pi]."""
    return np.pi - np.mod(np.pi - a, 2 * np.pi)


def residual(model: str, z_meas, z_pred) -> np.ndarray:
    """e = z_meas - z_pred (paper eq. 83), (n, 4); the polar azimuth difference wrapped to (-pi, pi].

    Checked by: tests/estimator/test_measurements.py::test_residual_wraps_azimuth
    """
    _check_model(model)
    z_meas = check_finite("z_meas", z_meas, (4,))
    z_pred = check_finite("z_pred", z_pred, (4,))
    try:
        e = z_meas - z_pred
    except ValueError:
        raise InputError(f"z_meas, z_pred: shapes {z_meas.shape} and {z_pred.shape} do not broadcast") from None
    if model == "polar":
        e[..., 1] = wrap_angle(e[..., 1])
    return e


def cartesian_position_covariance(polar, sigmas) -> np.ndarray:
    """Polar detection noise propagated to Cartesian sensor coordinates, J diag(s_r^2, s_az^2, s_el^2) J^T.

    Args:
        polar: (n, >=3) detections [r, az, el, ...].
        sigmas: (>=3,) 1-sigma of [range, azimuth, elevation, ...] (extra entries ignored).

    Returns:
        (n, 3, 3) first-order covariance of [x, y, z] (used for KD-tree radii and figures).

    Checked by: tests/estimator/test_measurements.py::test_cartesian_position_covariance_monte_carlo
    """
    polar = _check_polar("polar", polar, 3)
    sigmas = check_finite("sigmas", sigmas)
    if sigmas.ndim != 1 or len(sigmas) < 3 or np.any(sigmas[:3] < 0):
        raise InputError(f"sigmas: expected >= 3 non-negative values [range, azimuth, elevation], got {sigmas}")
    J = polar_to_cartesian_jacobian(polar)
    return np.einsum("nij,j,nkj->nik", J, sigmas[:3] ** 2, J)
