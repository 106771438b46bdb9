"""Compiled (numba) SO(3) / SE(3) and small block-matrix kernels shared by the priors and the solver.

The NumPy reference is `estimator.lie.se3` / `so3`; these are the same formulas, written into preallocated
outputs for the hot loops of `estimator.priors.kernels` and `estimator.motion_kernels`. No validation here.

Notation: a 6x6 matrix of the form [[A, B], [0, A]] (A, B 3x3) is an "upper-block" (ub) matrix, stored as an
array (2, 3, 3) = (A, B). curlyhat(x), every polynomial in curlyhats, the left Jacobian J and H of
curlyhat(sigma) are all of this form, and ub products cost three 3x3 products instead of one 6x6 product.
Functions f(S) = sum_n a_n S^n of S = curlyhat(xi) are evaluated as c_0 I + ... + c_4 S^4 (paper eq. 70),
c_i from closed forms at |phi| >= 1 rad and from the exact Taylor tables of `estimator.lie._series` below,
as `estimator.lie.se3` does. Derivations: docs/priors.md.

Checked by: tests/estimator/test_priors_ca.py, tests/estimator/test_priors_cv.py,
    tests/estimator/test_window_kernels.py::test_motion_kernel_log_and_jacobians_match_lie
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import FASTMATH, njit
from ._series import SE3_EXP, SE3_H, SE3_JAC, SO3_EXP, SO3_JAC
from .so3 import TAYLOR_BELOW

__all__ = ["ad_vec", "hat3", "inv3", "jac_inv_into", "matmul_into", "se3_coeffs", "se3_exp_into",
           "se3_log_and_jac_inv", "so3_coeffs", "so3_log", "ub_axpby", "ub_curly", "ub_mul", "ub_poly",
           "ub_powers", "ub_to_dense"]

# kind 0: exp (Ad), 1: left Jacobian J, 2: H = sum S^n/(n+2)!
_SE3_TAB = np.ascontiguousarray(np.stack([SE3_EXP, SE3_JAC, SE3_H]))
_SO3_TAB = np.ascontiguousarray(np.stack([SO3_EXP, SO3_JAC]))
_TB = float(TAYLOR_BELOW)


# ----------------------------------------------------------------------------------------------
# scalar coefficients
@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def se3_coeffs(kind, a, out):
    """c_0..c_4 of f(curlyhat(xi)) = sum_i c_i curlyhat(xi)^i (paper eq. 70) for |phi| = a.

    Args:
        kind: 0 exp (Ad), 1 left Jacobian J, 2 H = sum S^n/(n+2)!.
        a: rotation angle |phi| >= 0.
        out: (5,) written.

    Checked by: tests/estimator/test_priors_ca.py::test_transition_closed_form_matches_expm,
        tests/estimator/test_priors_cv.py::test_cv_matches_exact
    """
    if a < _TB:
        x = a * a
        for i in range(5):
            acc = 0.0
            for k in range(_SE3_TAB.shape[2] - 1, -1, -1):
                acc = acc * x + _SE3_TAB[kind, i, k]
            out[i] = acc
        return
    s = math.sin(a)
    c = math.cos(a)
    a2 = a * a
    if kind == 0:
        out[0] = 1.0
        out[1] = (3.0 * s - a * c) / (2.0 * a)
        out[2] = (4.0 - a * s - 4.0 * c) / (2.0 * a2)
        out[3] = (s - a * c) / (2.0 * a2 * a)
        out[4] = (2.0 - a * s - 2.0 * c) / (2.0 * a2 * a2)
    elif kind == 1:
        out[0] = 1.0
        out[1] = (4.0 - a * s - 4.0 * c) / (2.0 * a2)
        out[2] = (4.0 * a - 5.0 * s + a * c) / (2.0 * a2 * a)
        out[3] = (2.0 - a * s - 2.0 * c) / (2.0 * a2 * a2)
        out[4] = (2.0 * a - 3.0 * s + a * c) / (2.0 * a2 * a2 * a)
    else:
        out[0] = 0.5
        out[1] = (4.0 * a + a * c - 5.0 * s) / (2.0 * a2 * a)
        out[2] = (2.0 * a2 + a * s + 6.0 * c - 6.0) / (2.0 * a2 * a2)
        out[3] = (2.0 * a + a * c - 3.0 * s) / (2.0 * a2 * a2 * a)
        out[4] = (a2 + a * s + 4.0 * c - 4.0) / (2.0 * a2 * a2 * a2)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def so3_coeffs(kind, a, out):
    """c_0..c_2 of f(phi^) = c_0 I + c_1 phi^ + c_2 phi^2 for |phi| = a (kind 0 exp, 1 J); out (3,).

    Checked by: tests/estimator/test_window_kernels.py::test_window_update_equals_state_oplus (through `se3_exp_into`)
    """
    if a < _TB:
        x = a * a
        for i in range(3):
            acc = 0.0
            for k in range(_SO3_TAB.shape[2] - 1, -1, -1):
                acc = acc * x + _SO3_TAB[kind, i, k]
            out[i] = acc
        return
    out[0] = 1.0
    if kind == 0:
        out[1] = math.sin(a) / a
        out[2] = (1.0 - math.cos(a)) / (a * a)
    else:
        out[1] = (1.0 - math.cos(a)) / (a * a)
        out[2] = (a - math.sin(a)) / (a * a * a)


# ----------------------------------------------------------------------------------------------
# small linear algebra and ub (upper-block) matrices
@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def ad_vec(a, b, out):
    """out (6,) = curlyhat(a) b = [phi_a x rho_b + rho_a x phi_b; phi_a x phi_b] for a, b (6,).

    Checked by: tests/estimator/test_priors_ca.py::test_magnus_pose_matches_exact_ode (the Magnus commutators)
    """
    r0 = a[4] * b[2] - a[5] * b[1] + a[1] * b[5] - a[2] * b[4]
    r1 = a[5] * b[0] - a[3] * b[2] + a[2] * b[3] - a[0] * b[5]
    r2 = a[3] * b[1] - a[4] * b[0] + a[0] * b[4] - a[1] * b[3]
    p0 = a[4] * b[5] - a[5] * b[4]
    p1 = a[5] * b[3] - a[3] * b[5]
    p2 = a[3] * b[4] - a[4] * b[3]
    out[0] = r0
    out[1] = r1
    out[2] = r2
    out[3] = p0
    out[4] = p1
    out[5] = p2


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def hat3(v, o, out):
    """out (3, 3) = v[o:o+3]^ (skew-symmetric).

    Checked by: tests/estimator/test_priors_ca.py::test_transition_closed_form_matches_expm
    """
    x = v[o]
    y = v[o + 1]
    z = v[o + 2]
    out[0, 0] = 0.0
    out[0, 1] = -z
    out[0, 2] = y
    out[1, 0] = z
    out[1, 1] = 0.0
    out[1, 2] = -x
    out[2, 0] = -y
    out[2, 1] = x
    out[2, 2] = 0.0


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def ub_curly(v, out):
    """out (2, 3, 3) = curlyhat(v) as ub: A = phi^, B = rho^, for v = [rho; phi] (6,).

    Checked by: tests/estimator/test_priors_ca.py::test_transition_closed_form_matches_expm
    """
    hat3(v, 3, out[0])
    hat3(v, 0, out[1])


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def ub_mul(P, Q, out):
    """out = P Q for ub arrays P, Q (2, 3, 3): (A_P A_Q, A_P B_Q + B_P A_Q); out must not alias P or Q.

    Checked by: tests/estimator/test_priors_ca.py::test_transition_closed_form_matches_expm
    """
    for i in range(3):
        for j in range(3):
            s0 = 0.0
            s1 = 0.0
            for k in range(3):
                s0 += P[0, i, k] * Q[0, k, j]
                s1 += P[0, i, k] * Q[1, k, j] + P[1, i, k] * Q[0, k, j]
            out[0, i, j] = s0
            out[1, i, j] = s1


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def ub_poly(c, scale, Sp, out):
    """out (2, 3, 3) = sum_i c[i] scale^i Sp[i], i = 0..4 (Sp (5, 2, 3, 3) the powers, Sp[0] = I).

    Checked by: tests/estimator/test_priors_ca.py::test_process_noise_matches_van_loan_of_full_magnus_block
    """
    f = 1.0
    out[:] = 0.0
    for i in range(5):
        ci = c[i] * f
        for j in range(2):
            for k in range(3):
                for m in range(3):
                    out[j, k, m] += ci * Sp[i, j, k, m]
        f *= scale


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def ub_axpby(alpha, X, beta, out):
    """out = alpha X + beta out (ub arrays); beta == 0 overwrites (out may hold garbage).

    Checked by: tests/estimator/test_priors_ca.py::test_transition_closed_form_matches_expm (order 4)
    """
    for j in range(2):
        for k in range(3):
            for m in range(3):
                if beta == 0.0:
                    out[j, k, m] = alpha * X[j, k, m]
                else:
                    out[j, k, m] = alpha * X[j, k, m] + beta * out[j, k, m]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def ub_to_dense(U, M, r0, c0, alpha):
    """M[r0:r0+6, c0:c0+6] += alpha U, the ub array U written as a dense 6x6 block.

    Checked by: tests/estimator/test_priors_ca.py::test_transition_closed_form_matches_expm
    """
    for i in range(3):
        for j in range(3):
            M[r0 + i, c0 + j] += alpha * U[0, i, j]
            M[r0 + i, c0 + 3 + j] += alpha * U[1, i, j]
            M[r0 + 3 + i, c0 + 3 + j] += alpha * U[0, i, j]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def ub_powers(S, Sp):
    """Sp[i] = S^i, i = 0..4, for a ub array S (2, 3, 3); Sp (5, 2, 3, 3).

    Checked by: tests/estimator/test_priors_ca.py::test_transition_closed_form_matches_expm
    """
    Sp[0] = 0.0
    for i in range(3):
        Sp[0, 0, i, i] = 1.0
    Sp[1] = S
    ub_mul(S, S, Sp[2])
    ub_mul(Sp[2], S, Sp[3])
    ub_mul(Sp[2], Sp[2], Sp[4])


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def matmul_into(A, B, out):
    """out = A B for small dense matrices (3x3 A^2, 4x4 poses); out must not alias A or B.

    Checked by: tests/estimator/test_window_kernels.py::test_window_update_equals_state_oplus
    """
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            s = 0.0
            for k in range(A.shape[1]):
                s += A[i, k] * B[k, j]
            out[i, j] = s


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def se3_exp_into(xi, E, c3, A, A2):
    """E (4, 4) = exp(xi^) for xi = [rho; phi] (6,); c3 (3,), A, A2 (3, 3) are scratch.

    Checked by: tests/estimator/test_window_kernels.py::test_window_update_equals_state_oplus,
        tests/estimator/test_priors_ca.py::test_magnus_pose_matches_exact_ode
    """
    a = math.sqrt(xi[3] * xi[3] + xi[4] * xi[4] + xi[5] * xi[5])
    hat3(xi, 3, A)
    matmul_into(A, A, A2)
    so3_coeffs(0, a, c3)
    for i in range(3):
        for j in range(3):
            E[i, j] = c3[1] * A[i, j] + c3[2] * A2[i, j]
        E[i, i] += c3[0]
    so3_coeffs(1, a, c3)
    for i in range(3):
        s = c3[0] * xi[i]
        for k in range(3):
            s += (c3[1] * A[i, k] + c3[2] * A2[i, k]) * xi[k]
        E[i, 3] = s
        E[3, i] = 0.0
    E[3, 3] = 1.0


# ----------------------------------------------------------------------------------------------
# SE(3) logarithm and inverse left Jacobians
@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def so3_log(C, out):
    """out (3,) = log(C)^vee via the unit quaternion (Shepperd), |phi| <= pi; as `lie.so3.log`.

    Checked by: tests/estimator/test_window_kernels.py::test_motion_kernel_log_and_jacobians_match_lie
    """
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def inv3(A, out):
    """out = A^-1 for a 3x3 matrix (cofactors; J_so3 is well conditioned below 2 pi).

    Checked by: tests/estimator/test_window_kernels.py::test_motion_kernel_log_and_jacobians_match_lie
    """
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def jac_inv_into(Sp, c, sign, Ai, out, r0, c0):
    """out[r0:r0+6, c0:c0+6] = J(sign xi)^-1 from the curlyhat powers Sp of xi and J's coefficients c.

    J = [[A, B], [0, A]] -> J^-1 = [[A^-1, -A^-1 B A^-1], [0, A^-1]]; Ai (3, 3) receives A^-1.

    Checked by: tests/estimator/test_window_kernels.py::test_motion_kernel_log_and_jacobians_match_lie
    """
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
    inv3(A, Ai)
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def se3_log_and_jac_inv(T, xi, Jinv, Jinv_neg):
    """xi = ln(T)^vee (6,), Jinv = J(xi)^-1 and Jinv_neg = J(-xi)^-1 (6, 6) for one pose T (4, 4).

    Checked by: tests/estimator/test_window_kernels.py::test_motion_kernel_log_and_jacobians_match_lie
    """
    phi = np.empty(3)
    so3_log(T[:3, :3], phi)
    a = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    c = np.empty(5)
    se3_coeffs(1, a, c)
    # rho = J_so3(phi)^-1 r: the SO(3) Jacobian is the upper-left block of the SE(3) one (same coefficients
    # on the rotation-only curlyhat), so build J with rho = 0 first
    x0 = np.zeros(6)
    x0[3:] = phi
    S = np.empty((2, 3, 3))
    Sp = np.empty((5, 2, 3, 3))
    ub_curly(x0, S)
    ub_powers(S, Sp)
    A = np.zeros((3, 3))
    for i in range(5):
        for k in range(3):
            for m in range(3):
                A[k, m] += c[i] * Sp[i, 0, k, m]
    Ai = np.empty((3, 3))
    inv3(A, Ai)
    for k in range(3):
        xi[k] = Ai[k, 0] * T[0, 3] + Ai[k, 1] * T[1, 3] + Ai[k, 2] * T[2, 3]
        xi[3 + k] = phi[k]
    ub_curly(xi, S)
    ub_powers(S, Sp)
    jac_inv_into(Sp, c, 1.0, Ai, Jinv, 0, 0)
    jac_inv_into(Sp, c, -1.0, Ai, Jinv_neg, 0, 0)
