"""SO(3): hat/vee, exp/log, left Jacobian and its inverse, quaternions (Barfoot, State Estimation, ch. 7).

All functions accept single inputs ((3,) or (3, 3)) and batches ((..., 3) or (..., 3, 3)).
Small angles use exact Taylor series (see `_series`), so results are accurate at phi -> 0; `log`
goes through a quaternion (Shepperd's method), so it is accurate near pi as well.
Quaternions are [qx, qy, qz, qw] (TUM, Rerun and scipy order; Hamilton convention, so q and the matrix
C = from_quaternion(q) rotate vectors the same way), written with qw >= 0. These two functions are rodo's only
quaternion implementation: the TUM and sensor.toml readers and writers, the covariance ellipsoids and the
Rerun recording all use them (docs/conventions.md).

Checked by: tests/estimator/test_lie.py
"""

from __future__ import annotations

import numpy as np

from ._series import SO3_EXP, SO3_JAC, SO3_JAC_INV, horner

TAYLOR_BELOW = 1.0  # rad; below it coefficients come from Taylor series (exact to double precision)


def hat(phi: np.ndarray) -> np.ndarray:
    """phi^ (skew-symmetric), (..., 3) -> (..., 3, 3)."""
    phi = np.asarray(phi, dtype=float)
    out = np.zeros(phi.shape[:-1] + (3, 3))
    out[..., 0, 1] = -phi[..., 2]
    out[..., 0, 2] = phi[..., 1]
    out[..., 1, 0] = phi[..., 2]
    out[..., 1, 2] = -phi[..., 0]
    out[..., 2, 0] = -phi[..., 1]
    out[..., 2, 1] = phi[..., 0]
    return out


def vee(Phi: np.ndarray) -> np.ndarray:
    """Inverse of hat, (..., 3, 3) -> (..., 3)."""
    Phi = np.asarray(Phi, dtype=float)
    return np.stack([Phi[..., 2, 1], Phi[..., 0, 2], Phi[..., 1, 0]], axis=-1)


def _coefficients(phi: np.ndarray, taylor: np.ndarray, closed) -> np.ndarray:
    """Coefficients c_0..c_2 of f(phi^) = c0 I + c1 phi^ + c2 phi^2, shape (3, ...)."""
    angle = np.linalg.norm(phi, axis=-1)
    if angle.ndim == 0:  # single input: evaluate only the branch that applies
        return horner(taylor, angle**2) if angle < TAYLOR_BELOW else closed(angle)
    small = angle < TAYLOR_BELOW
    safe = np.where(small, TAYLOR_BELOW, angle)  # closed forms never see the small angles
    return np.where(small, horner(taylor, angle**2), closed(safe))


def _poly(phi: np.ndarray, c: np.ndarray) -> np.ndarray:
    A = hat(phi)
    eye = np.broadcast_to(np.eye(3), A.shape)
    return c[0][..., None, None] * eye + c[1][..., None, None] * A + c[2][..., None, None] * (A @ A)


def _exp_closed(a):
    return np.stack([np.ones_like(a), np.sin(a) / a, (1 - np.cos(a)) / a**2])


def _jac_closed(a):
    return np.stack([np.ones_like(a), (1 - np.cos(a)) / a**2, (a - np.sin(a)) / a**3])


def _jac_inv_closed(a):
    half = 0.5 * a
    return np.stack([np.ones_like(a), -0.5 * np.ones_like(a), 1 / a**2 - np.cos(half) / (2 * a * np.sin(half))])


def exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix C = exp(phi^), (..., 3) -> (..., 3, 3)."""
    phi = np.asarray(phi, dtype=float)
    return _poly(phi, _coefficients(phi, SO3_EXP, _exp_closed))


def left_jacobian(phi: np.ndarray) -> np.ndarray:
    """J(phi) = sum_n (phi^)^n / (n+1)!, (..., 3) -> (..., 3, 3)."""
    phi = np.asarray(phi, dtype=float)
    return _poly(phi, _coefficients(phi, SO3_JAC, _jac_closed))


def left_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """J(phi)^-1 in closed form; singular only at |phi| = 2 pi k, k >= 1."""
    phi = np.asarray(phi, dtype=float)
    return _poly(phi, _coefficients(phi, SO3_JAC_INV, _jac_inv_closed))


def to_quaternion(C: np.ndarray) -> np.ndarray:
    """Rotation matrix -> unit quaternion [qx, qy, qz, qw] with qw >= 0 (Shepperd's method).

    (..., 3, 3) -> (..., 4). Of the two quaternions of a rotation, the one with qw >= 0 (for a half turn,
    qw = 0, either sign may come out).

    Checked by: tests/estimator/test_lie.py::test_quaternion_round_trip, ::test_quaternion_agrees_with_scipy
    """
    C = np.asarray(C, dtype=float)
    tr = C[..., 0, 0] + C[..., 1, 1] + C[..., 2, 2]
    diag = np.stack([C[..., 0, 0], C[..., 1, 1], C[..., 2, 2], tr], axis=-1)
    k = np.argmax(diag, axis=-1)
    # four candidate solutions, each well conditioned when its pivot is the largest
    s0 = np.sqrt(np.maximum(1 + 2 * C[..., 0, 0] - tr, 1e-300)) * 2
    s1 = np.sqrt(np.maximum(1 + 2 * C[..., 1, 1] - tr, 1e-300)) * 2
    s2 = np.sqrt(np.maximum(1 + 2 * C[..., 2, 2] - tr, 1e-300)) * 2
    s3 = np.sqrt(np.maximum(1 + tr, 1e-300)) * 2
    cands = np.stack(
        [
            np.stack([0.25 * s0, (C[..., 0, 1] + C[..., 1, 0]) / s0, (C[..., 0, 2] + C[..., 2, 0]) / s0,
                      (C[..., 2, 1] - C[..., 1, 2]) / s0], -1),
            np.stack([(C[..., 0, 1] + C[..., 1, 0]) / s1, 0.25 * s1, (C[..., 1, 2] + C[..., 2, 1]) / s1,
                      (C[..., 0, 2] - C[..., 2, 0]) / s1], -1),
            np.stack([(C[..., 0, 2] + C[..., 2, 0]) / s2, (C[..., 1, 2] + C[..., 2, 1]) / s2, 0.25 * s2,
                      (C[..., 1, 0] - C[..., 0, 1]) / s2], -1),
            np.stack([(C[..., 2, 1] - C[..., 1, 2]) / s3, (C[..., 0, 2] - C[..., 2, 0]) / s3,
                      (C[..., 1, 0] - C[..., 0, 1]) / s3, 0.25 * s3], -1),
        ],
        axis=-2,
    )
    q = np.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def from_quaternion(q: np.ndarray) -> np.ndarray:
    """Unit quaternion [qx, qy, qz, qw] -> rotation matrix (the quaternion is normalised first).

    (..., 4) -> (..., 3, 3); q and -q give the same matrix.

    Checked by: tests/estimator/test_lie.py::test_quaternion_agrees_with_scipy
    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def log(C: np.ndarray) -> np.ndarray:
    """phi = log(C)^vee with |phi| <= pi, (..., 3, 3) -> (..., 3); accurate near 0 and near pi."""
    q = to_quaternion(C)
    v = q[..., :3]
    s = np.linalg.norm(v, axis=-1)
    w = q[..., 3]
    angle = 2 * np.arctan2(s, w)
    # atan2 and the norm are both accurate for tiny s, so angle / s has no cancellation; s == 0 is identity
    ratio = np.where(s > 0, angle / np.where(s > 0, s, 1), 2.0)
    return v * ratio[..., None]
