"""Covariances in the world frame: the vehicle position's covariance from the pose covariance of the state
(left perturbation of T_vehicle_world, docs/conventions.md), and the axes of n-sigma ellipses and ellipsoids.
The recording draws the ellipsoids, the figures the ellipses (docs/visualisation.md, "What the covariance
ellipsoid shows").

Checked by: tests/validation/test_covariance.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.lie import so3


def position_covariance_world(T_vehicle_world, P_rho) -> np.ndarray:
    """Covariance of the vehicle's world position from the left-perturbation covariance of T_vehicle_world.

    With T = T_vehicle_world = [C, r] and T_true = exp(xi^) T, xi = [rho; phi], the vehicle's world position
    r_w = -C^T r becomes r_w' = -C^T exp(-phi^) (exp(phi^) r + J(phi) rho) = r_w - C^T J_r(phi) rho, so to
    first order dr_w = -C^T rho (phi drops out) and

        Sigma_w = C^T P_rho C,    P_rho = P[:3, :3].

    Args:
        T_vehicle_world: (..., 4, 4) state poses.
        P_rho: (..., 3, 3) translational block of the pose covariance.

    Returns:
        (..., 3, 3) world-frame covariance of the vehicle position.

    Checked by: tests/validation/test_covariance.py::test_position_covariance_world_monte_carlo
    """
    T = np.asarray(T_vehicle_world, dtype=float)
    C = T[..., :3, :3]
    return np.swapaxes(C, -1, -2) @ np.asarray(P_rho, dtype=float) @ C


def covariance_axes(Sigma, n_sigma: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Half sizes and axes of the n-sigma ellipse or ellipsoid of (..., d, d) covariances.

    Sigma = V diag(lambda) V^T (of the symmetrised Sigma) with det V = +1 (the first column flipped if needed);
    the ellipsoid {x : x^T Sigma^-1 x <= n^2} has half sizes n sqrt(lambda) along V's columns (negative
    eigenvalues of a rounding-level indefinite Sigma count as 0).

    Args:
        Sigma: (..., d, d) symmetric positive semi-definite.
        n_sigma: scale (3 for the 3-sigma ellipsoid).

    Returns:
        (half_sizes (..., d), V (..., d, d) with det V = 1).

    Checked by: tests/validation/test_covariance.py::test_covariance_ellipsoid_reconstructs_sigma,
        tests/validation/test_covariance.py::test_covariance_axes_of_a_2d_covariance
    """
    S = np.asarray(Sigma, dtype=float)
    S = 0.5 * (S + np.swapaxes(S, -1, -2))
    lam, V = np.linalg.eigh(S)
    flip = np.linalg.det(V) < 0
    V[..., :, 0] = np.where(flip[..., None], -V[..., :, 0], V[..., :, 0])
    return float(n_sigma) * np.sqrt(np.maximum(lam, 0.0)), V


def covariance_ellipsoid(Sigma, n_sigma: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Half sizes and rotation (as a quaternion) of the n-sigma ellipsoid of 3x3 covariances (`covariance_axes`).

    Args:
        Sigma: (..., 3, 3) symmetric positive semi-definite.
        n_sigma: scale (3 for the 3-sigma ellipsoid).

    Returns:
        (half_sizes (..., 3), quaternions (..., 4) [qx, qy, qz, qw] with qw >= 0).

    Checked by: tests/validation/test_covariance.py::test_covariance_ellipsoid_reconstructs_sigma
    """
    half, V = covariance_axes(Sigma, n_sigma)
    return half, so3.to_quaternion(V)  # V is a rotation: covariance_axes makes det(V) = +1
