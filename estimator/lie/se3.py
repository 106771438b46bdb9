"""SE(3) in the paper's conventions (Barfoot, State Estimation, ch. 7; paper eq. 19, 62-75).

Tangent vectors are xi = [rho; phi] (translation first), flat (..., 6). Left perturbations:
T = exp(xi^) T_bar. `curlyhat` is the 6x6 adjoint-algebra matrix of eq. 19,
curlyhat([rho; phi]) = [[phi^, rho^], [0, phi^]], so curlyhat(a) b = [a^, b^]^vee.

Functions of S = curlyhat(xi) (the left Jacobian J, H = sum S^n/(n+2)!) are evaluated as
c_0 I + c_1 S + ... + c_4 S^4 (identity eq. 70), the coefficients from closed forms above
phi = 1 rad and from exact Taylor series below (see `_series`).

Checked by: tests/estimator/test_lie.py
"""

from __future__ import annotations

import numpy as np

from . import so3
from ._series import SE3_H, SE3_JAC, horner

TAYLOR_BELOW = so3.TAYLOR_BELOW


def hat(xi: np.ndarray) -> np.ndarray:
    """xi^ in se(3), (..., 6) -> (..., 4, 4)."""
    xi = np.asarray(xi, dtype=float)
    out = np.zeros(xi.shape[:-1] + (4, 4))
    out[..., :3, :3] = so3.hat(xi[..., 3:])
    out[..., :3, 3] = xi[..., :3]
    return out


def vee(X: np.ndarray) -> np.ndarray:
    """Inverse of hat, (..., 4, 4) -> (..., 6)."""
    X = np.asarray(X, dtype=float)
    return np.concatenate([X[..., :3, 3], so3.vee(X[..., :3, :3])], axis=-1)


def curlyhat(xi: np.ndarray) -> np.ndarray:
    """Paper eq. 19: [[phi^, rho^], [0, phi^]], (..., 6) -> (..., 6, 6)."""
    xi = np.asarray(xi, dtype=float)
    out = np.zeros(xi.shape[:-1] + (6, 6))
    Phi = so3.hat(xi[..., 3:])
    out[..., :3, :3] = Phi
    out[..., 3:, 3:] = Phi
    out[..., :3, 3:] = so3.hat(xi[..., :3])
    return out


def from_rotation_translation(C: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Assemble T = [[C, r], [0, 1]], (..., 3, 3) and (..., 3) -> (..., 4, 4)."""
    C = np.asarray(C, dtype=float)
    r = np.asarray(r, dtype=float)
    shape = np.broadcast_shapes(C.shape[:-2], r.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = C
    T[..., :3, 3] = r
    T[..., 3, 3] = 1.0
    return T


def exp(xi: np.ndarray) -> np.ndarray:
    """T = exp(xi^), (..., 6) -> (..., 4, 4)."""
    xi = np.asarray(xi, dtype=float)
    C = so3.exp(xi[..., 3:])
    r = np.einsum("...ij,...j->...i", so3.left_jacobian(xi[..., 3:]), xi[..., :3])
    return from_rotation_translation(C, r)


def log(T: np.ndarray) -> np.ndarray:
    """xi = log(T)^vee with |phi| <= pi, (..., 4, 4) -> (..., 6)."""
    T = np.asarray(T, dtype=float)
    phi = so3.log(T[..., :3, :3])
    rho = np.einsum("...ij,...j->...i", so3.left_jacobian_inv(phi), T[..., :3, 3])
    return np.concatenate([rho, phi], axis=-1)


def inverse(T: np.ndarray) -> np.ndarray:
    """T^-1 using the group structure, (..., 4, 4)."""
    T = np.asarray(T, dtype=float)
    # -C^T r as three products summed in the order j = 0, 1, 2, each rounded on its own (NumPy never fuses a
    # multiply and an add), so a pose gives the same bits alone or in a stack, on any machine and memory layout
    if T.shape == (4, 4):  # one pose (the per-scan case), from its floats: without the arrays' set-up
        (c00, c01, c02, r0), (c10, c11, c12, r1), (c20, c21, c22, r2), _ = T.tolist()
        return np.array([[c00, c10, c20, -(c00 * r0 + c10 * r1 + c20 * r2)],
                         [c01, c11, c21, -(c01 * r0 + c11 * r1 + c21 * r2)],
                         [c02, c12, c22, -(c02 * r0 + c12 * r1 + c22 * r2)],
                         [0.0, 0.0, 0.0, 1.0]])
    C, r = T[..., :3, :3], T[..., :3, 3:]
    return from_rotation_translation(np.swapaxes(C, -1, -2),
                                     -(C[..., 0, :] * r[..., 0, :] + C[..., 1, :] * r[..., 1, :]
                                       + C[..., 2, :] * r[..., 2, :]))


def adjoint(T: np.ndarray) -> np.ndarray:
    """Ad(T) = [[C, r^ C], [0, C]], so that T exp(xi^) T^-1 = exp((Ad(T) xi)^)."""
    T = np.asarray(T, dtype=float)
    C = T[..., :3, :3]
    out = np.zeros(T.shape[:-2] + (6, 6))
    out[..., :3, :3] = C
    out[..., 3:, 3:] = C
    out[..., :3, 3:] = so3.hat(T[..., :3, 3]) @ C
    return out


def transform_points(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """p_a = T_a_b p_b for points (..., 3); T (4, 4) or broadcastable (..., 4, 4)."""
    T = np.asarray(T, dtype=float)
    p = np.asarray(p, dtype=float)
    return np.einsum("...ij,...j->...i", T[..., :3, :3], p) + T[..., :3, 3]


def _curly_poly(xi: np.ndarray, taylor: np.ndarray, closed) -> np.ndarray:
    xi = np.asarray(xi, dtype=float)
    angle = np.linalg.norm(xi[..., 3:], axis=-1)
    if angle.ndim == 0:  # single input: evaluate only the branch that applies
        c = horner(taylor, angle**2) if angle < TAYLOR_BELOW else closed(angle)
    else:
        small = angle < TAYLOR_BELOW
        safe = np.where(small, TAYLOR_BELOW, angle)
        c = np.where(small, horner(taylor, angle**2), closed(safe))
    S = curlyhat(xi)
    S2 = S @ S
    S3 = S2 @ S
    S4 = S2 @ S2
    eye = np.broadcast_to(np.eye(6), S.shape)
    w = [ci[..., None, None] for ci in c]
    return w[0] * eye + w[1] * S + w[2] * S2 + w[3] * S3 + w[4] * S4


def _jac_closed(a):
    s, c = np.sin(a), np.cos(a)
    return np.stack([
        np.ones_like(a),
        (4 - a * s - 4 * c) / (2 * a**2),
        (4 * a - 5 * s + a * c) / (2 * a**3),
        (2 - a * s - 2 * c) / (2 * a**4),
        (2 * a - 3 * s + a * c) / (2 * a**5),
    ])


def _h_closed(a):
    """Paper eq. 72-75 (eq. 71 corrected: H = 1/2 I + sum_i alpha_i S^i, see docs/paper_notes.md)."""
    s, c = np.sin(a), np.cos(a)
    return np.stack([
        0.5 * np.ones_like(a),
        (4 * a + a * c - 5 * s) / (2 * a**3),
        (2 * a**2 + a * s + 6 * c - 6) / (2 * a**4),
        (2 * a + a * c - 3 * s) / (2 * a**5),
        (a**2 + a * s + 4 * c - 4) / (2 * a**6),
    ])


def left_jacobian(xi: np.ndarray) -> np.ndarray:
    """J(xi) = sum_n curlyhat(xi)^n / (n+1)! = [[J_so3, Q], [0, J_so3]], (..., 6) -> (..., 6, 6)."""
    return _curly_poly(xi, SE3_JAC, _jac_closed)


def q_block(xi: np.ndarray) -> np.ndarray:
    """Barfoot's Q(xi): the upper-right 3x3 block of the left Jacobian, (..., 6) -> (..., 3, 3)."""
    return left_jacobian(xi)[..., :3, 3:]


def left_jacobian_inv(xi: np.ndarray) -> np.ndarray:
    """J(xi)^-1 = [[Ji, -Ji Q Ji], [0, Ji]] with Ji = J_so3(phi)^-1, (..., 6) -> (..., 6, 6)."""
    xi = np.asarray(xi, dtype=float)
    Ji = so3.left_jacobian_inv(xi[..., 3:])
    Q = q_block(xi)
    out = np.zeros(xi.shape[:-1] + (6, 6))
    out[..., :3, :3] = Ji
    out[..., 3:, 3:] = Ji
    out[..., :3, 3:] = -Ji @ Q @ Ji
    return out


def h_matrix(xi: np.ndarray) -> np.ndarray:
    """H(xi) = sum_n curlyhat(xi)^n / (n+2)! (paper eq. 68-75), (..., 6) -> (..., 6, 6)."""
    return _curly_poly(xi, SE3_H, _h_closed)


def right_jacobian(xi: np.ndarray) -> np.ndarray:
    """J_r(xi) = J(-xi)."""
    return left_jacobian(-np.asarray(xi, dtype=float))


def right_jacobian_inv(xi: np.ndarray) -> np.ndarray:
    """J_r(xi)^-1 = J(-xi)^-1."""
    return left_jacobian_inv(-np.asarray(xi, dtype=float))
