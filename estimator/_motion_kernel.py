"""Numba kernel of the motion-prior residuals of a window (the solver's hot path besides the measurements).

For consecutive states the residual is e = x2 (-) f(x1) = [ln(T2 Tp^-1)^vee; tail2 - tail_pred] with
J_e_x2 = diag(J(e_xi)^-1, I) and J_e_x1 = -diag(J(-e_xi)^-1, I) F_k (the priors' `residual`, docs/priors.md).
`MotionModel.residuals` passes the predicted means and F_k from the priors' kernels; this kernel adds the SE(3)
logarithm and the inverse left Jacobians, which in NumPy cost about 0.6 ms per window (many tiny array calls)
and here a few microseconds. The same formulas as `estimator.lie` (quaternion-based SO(3) logarithm, J from its
degree-four curlyhat polynomial with Taylor coefficients below 1 rad), so the two agree to round-off.

Checked by: tests/estimator/test_window.py::test_batched_motion_residuals_equal_the_priors_residual,
    ::test_motion_kernel_log_and_jacobians_match_lie
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .priors._kernels import _FM, _se3_coeffs, _se3_exp_into, _ub_curly, _ub_powers, matmul_into


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _so3_log(C, out):
    """out = log(C)^vee (3,), via the unit quaternion (Shepperd), |phi| <= pi; as `lie.so3.log`."""
    tr = C[0, 0] + C[1, 1] + C[2, 2]
    if tr >= C[0, 0] and tr >= C[1, 1] and tr >= C[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + tr, 1e-300))
        qx, qy, qz, qw = (C[2, 1] - C[1, 2]) / s, (C[0, 2] - C[2, 0]) / s, (C[1, 0] - C[0, 1]) / s, 0.25 * s
    elif C[0, 0] >= C[1, 1] and C[0, 0] >= C[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + 2.0 * C[0, 0] - tr, 1e-300))
        qx, qy, qz, qw = 0.25 * s, (C[0, 1] + C[1, 0]) / s, (C[0, 2] + C[2, 0]) / s, (C[2, 1] - C[1, 2]) / s
    elif C[1, 1] >= C[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + 2.0 * C[1, 1] - tr, 1e-300))
        qx, qy, qz, qw = (C[0, 1] + C[1, 0]) / s, 0.25 * s, (C[1, 2] + C[2, 1]) / s, (C[0, 2] - C[2, 0]) / s
    else:
        s = 2.0 * math.sqrt(max(1.0 + 2.0 * C[2, 2] - tr, 1e-300))
        qx, qy, qz, qw = (C[0, 2] + C[2, 0]) / s, (C[1, 2] + C[2, 1]) / s, 0.25 * s, (C[1, 0] - C[0, 1]) / s
    norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    if qw < 0.0:
        norm = -norm
    qx, qy, qz, qw = qx / norm, qy / norm, qz / norm, qw / norm
    sv = math.sqrt(qx * qx + qy * qy + qz * qz)
    ratio = 2.0 * math.atan2(sv, qw) / sv if sv > 0.0 else 2.0
    out[0] = qx * ratio
    out[1] = qy * ratio
    out[2] = qz * ratio


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _inv3(A, out):
    """out = A^-1 for a 3x3 matrix (cofactors; J_so3 is well conditioned below 2 pi)."""
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    inv_det = 1.0 / (A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02)
    out[0, 0] = c00 * inv_det
    out[1, 0] = c01 * inv_det
    out[2, 0] = c02 * inv_det
    out[0, 1] = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) * inv_det
    out[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) * inv_det
    out[2, 1] = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) * inv_det
    out[0, 2] = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) * inv_det
    out[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) * inv_det
    out[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) * inv_det


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _jac_inv_into(Sp, c, sign, Ai, out, r0, c0):
    """out[r0:r0+6, c0:c0+6] = J(sign * xi)^-1 from the curlyhat powers Sp of xi and J's coefficients c:
    J = [[A, B], [0, A]] -> J^-1 = [[A^-1, -A^-1 B A^-1], [0, A^-1]]."""
    A = np.zeros((3, 3))
    B = np.zeros((3, 3))
    f = 1.0
    for i in range(5):
        ci = c[i] * f
        for k in range(3):
            for m in range(3):
                A[k, m] += ci * Sp[i, 0, k, m]
                B[k, m] += ci * Sp[i, 1, k, m]
        f *= sign
    _inv3(A, Ai)
    for k in range(3):
        for m in range(3):
            s = 0.0
            for p in range(3):
                for q in range(3):
                    s += Ai[k, p] * B[p, q] * Ai[q, m]
            out[r0 + k, c0 + m] = Ai[k, m]
            out[r0 + 3 + k, c0 + 3 + m] = Ai[k, m]
            out[r0 + k, c0 + 3 + m] = -s
            out[r0 + 3 + k, c0 + m] = 0.0


@njit(cache=True, fastmath=_FM, error_model="numpy")
def se3_log_and_jac_inv(T, xi, Jinv, Jinv_neg):
    """xi = ln(T)^vee (6,), Jinv = J(xi)^-1 and Jinv_neg = J(-xi)^-1 (6, 6) for one pose T (4, 4)."""
    phi = np.empty(3)
    _so3_log(T[:3, :3], phi)
    a = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    c = np.empty(5)
    _se3_coeffs(1, a, c)
    # rho = J_so3(phi)^-1 r: the SO(3) Jacobian is the upper-left block of the SE(3) one (same coefficients
    # on the rotation-only curlyhat), so build J with rho = 0 first
    x0 = np.zeros(6)
    x0[3:] = phi
    S = np.empty((2, 3, 3))
    Sp = np.empty((5, 2, 3, 3))
    _ub_curly(x0, S)
    _ub_powers(S, Sp)
    A = np.zeros((3, 3))
    for i in range(5):
        for k in range(3):
            for m in range(3):
                A[k, m] += c[i] * Sp[i, 0, k, m]
    Ai = np.empty((3, 3))
    _inv3(A, Ai)
    for k in range(3):
        xi[k] = Ai[k, 0] * T[0, 3] + Ai[k, 1] * T[1, 3] + Ai[k, 2] * T[2, 3]
        xi[3 + k] = phi[k]
    _ub_curly(xi, S)
    _ub_powers(S, Sp)
    _jac_inv_into(Sp, c, 1.0, Ai, Jinv, 0, 0)
    _jac_inv_into(Sp, c, -1.0, Ai, Jinv_neg, 0, 0)


@njit(cache=True, fastmath=_FM, error_model="numpy")
def residuals(T_pred, tail_pred, T2, tail2, F, e, J1, J2):
    """Motion residuals of n intervals: T_pred, T2 (n, 4, 4), tail_pred, tail2 (n, d - 6), F (n, d, d) ->
    e (n, d), J1 = J_e_x1, J2 = J_e_x2 (n, d, d), written in place."""
    n, d = F.shape[0], F.shape[1]
    D = np.empty((4, 4))
    xi = np.empty(6)
    Jp = np.empty((6, 6))
    Jm = np.empty((6, 6))
    for s in range(n):
        # D = T2 Tp^-1 with Tp^-1 = [C^T, -C^T r]
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for k in range(3):
                    acc += T2[s, i, k] * T_pred[s, j, k]
                D[i, j] = acc
            acc = T2[s, i, 3]
            for j in range(3):
                acc -= D[i, j] * T_pred[s, j, 3]
            D[i, 3] = acc
        se3_log_and_jac_inv(D, xi, Jp, Jm)
        for i in range(6):
            e[s, i] = xi[i]
        for i in range(d - 6):
            e[s, 6 + i] = tail2[s, i] - tail_pred[s, i]
        J2[s] = 0.0
        for i in range(d):
            J2[s, i, i] = 1.0
        for i in range(6):
            for j in range(6):
                J2[s, i, j] = Jp[i, j]
        # J1 = -diag(Jm, I) F
        for i in range(6):
            for j in range(d):
                acc = 0.0
                for k in range(6):
                    acc += Jm[i, k] * F[s, k, j]
                J1[s, i, j] = -acc
        for i in range(6, d):
            for j in range(d):
                J1[s, i, j] = -F[s, i, j]


@njit(cache=True, fastmath=_FM, error_model="numpy")
def exp_times(xi, T, out):
    """out[n] = exp(xi[n]^) T[n] for n poses: the solver's state update (left perturbation)."""
    E = np.empty((4, 4))
    c3 = np.empty(3)
    A = np.empty((3, 3))
    A2 = np.empty((3, 3))
    for n in range(T.shape[0]):
        _se3_exp_into(xi[n], E, c3, A, A2)
        matmul_into(E, T[n], out[n])


@njit(cache=True, fastmath=_FM, error_model="numpy")
def accumulate(H, b, e, J1, J2, W):
    """Adds the motion terms of consecutive states k, k+1 to the window's normal equations: with
    J = [J1_k, J2_k] (d x 2d), H[kd:(k+2)d, kd:(k+2)d] += J^T W_k J, b[...] += J^T W_k e_k; returns
    sum_k 1/2 e_k^T W_k e_k."""
    n, d = e.shape[0], e.shape[1]
    JW = np.empty((2 * d, d))
    We = np.empty(d)
    cost = 0.0
    for k in range(n):
        for i in range(d):
            s = 0.0
            for l in range(d):
                s += W[k, i, l] * e[k, l]
            We[i] = s
            cost += 0.5 * e[k, i] * s
        for r in range(2 * d):  # JW = J^T W
            for c in range(d):
                s = 0.0
                if r < d:
                    for l in range(d):
                        s += J1[k, l, r] * W[k, l, c]
                else:
                    for l in range(d):
                        s += J2[k, l, r - d] * W[k, l, c]
                JW[r, c] = s
        o = k * d
        for r in range(2 * d):
            s = 0.0
            for l in range(d):
                s += (J1[k, l, r] if r < d else J2[k, l, r - d]) * We[l]
            b[o + r] += s
            for c in range(2 * d):
                s = 0.0
                if c < d:
                    for l in range(d):
                        s += JW[r, l] * J1[k, l, c]
                else:
                    for l in range(d):
                        s += JW[r, l] * J2[k, l, c - d]
                H[o + r, o + c] += s
    return cost
