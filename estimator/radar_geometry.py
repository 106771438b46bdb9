"""Radar geometry shared by the measurement models, the Doppler front end and the simulator's checks: polar
<-> Cartesian sensor coordinates with their Jacobians, the propagated position covariance, angle wrapping.

Checked by: tests/estimator/test_measurements.py::test_polar_cartesian_round_trip,
    ::test_polar_jacobian_matches_finite_differences, ::test_cartesian_position_covariance_monte_carlo
"""

from __future__ import annotations

import numpy as np

from .errors import InputError, check_finite


def check_polar(name: str, polar, min_cols: int = 4) -> np.ndarray:
    """polar as a finite (n, >= min_cols) float array with ranges >= 0, or InputError naming `name`."""
    polar = check_finite(name, polar)
    if polar.ndim != 2 or polar.shape[1] < min_cols:
        raise InputError(f"{name}: expected shape (n, {min_cols}) [range, azimuth, elevation, ...], got {polar.shape}")
    if (polar[:, 0] < 0).any():
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


def polar_to_cartesian(polar) -> np.ndarray:
    """x = r cos(el) cos(az), y = r cos(el) sin(az), z = r sin(el); (n, >=3) -> (n, 3) sensor frame.

    Checked by: tests/estimator/test_measurements.py::test_polar_cartesian_round_trip
    """
    polar = check_polar("polar", polar, 3)
    r, az, el = polar[:, 0], polar[:, 1], polar[:, 2]
    ce = np.cos(el)
    return np.stack([r * ce * np.cos(az), r * ce * np.sin(az), r * np.sin(el)], axis=1)


def polar_to_cartesian_jacobian(polar) -> np.ndarray:
    """d[x, y, z]/d[r, az, el] of `polar_to_cartesian`, (n, >=3) -> (n, 3, 3).

    Checked by: tests/estimator/test_measurements.py::test_cartesian_position_covariance_monte_carlo
    """
    polar = check_polar("polar", polar, 3)
    r, az, el = polar[:, 0], polar[:, 1], polar[:, 2]
    ca, sa, ce, se = np.cos(az), np.sin(az), np.cos(el), np.sin(el)
    J = np.empty((len(r), 3, 3))
    J[:, :, 0] = np.stack([ce * ca, ce * sa, se], axis=1)
    J[:, :, 1] = np.stack([-r * ce * sa, r * ce * ca, np.zeros_like(r)], axis=1)
    J[:, :, 2] = np.stack([-r * se * ca, -r * se * sa, r * ce], axis=1)
    return J


def cartesian_position_covariance(polar, sigmas) -> np.ndarray:
    """Polar detection noise propagated to Cartesian sensor coordinates, J diag(s_r^2, s_az^2, s_el^2) J^T.

    Args:
        polar: (n, >=3) detections [r, az, el, ...].
        sigmas: (>=3,) 1-sigma of [range, azimuth, elevation, ...] (extra entries ignored).

    Returns:
        (n, 3, 3) first-order covariance of [x, y, z] (used for search radii and figures).

    Checked by: tests/estimator/test_measurements.py::test_cartesian_position_covariance_monte_carlo
    """
    polar = check_polar("polar", polar, 3)
    sigmas = check_finite("sigmas", sigmas)
    if sigmas.ndim != 1 or len(sigmas) < 3 or np.any(sigmas[:3] < 0):
        raise InputError(f"sigmas: expected >= 3 non-negative values [range, azimuth, elevation], got {sigmas}")
    J = polar_to_cartesian_jacobian(polar)
    return (J * sigmas[:3] ** 2) @ np.swapaxes(J, 1, 2)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles to (-pi, pi].

    Checked by: tests/estimator/test_measurements.py::test_residual_wraps_azimuth
    """
    return np.pi - np.mod(np.pi - a, 2 * np.pi)

