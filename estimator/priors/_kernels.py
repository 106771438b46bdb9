"""Numba kernels of the motion priors: Magnus pose term, F_k and Q_k fused, batched forms.

No validation here (the public methods in `constant_acceleration` / `constant_velocity` do it once).
Derivations: docs/priors.md. Notation: a 6x6 matrix of the form [[A, B], [0, A]] (A, B 3x3) is an
"upper-block" (ub) matrix, stored as an array (2, 3, 3) = (A, B). curlyhat(x), every polynomial in
curlyhats, the left Jacobian J and H of curlyhat(sigma) are all of this form, and ub products cost
three 3x3 products instead of one 6x6 product.

Functions f(S) = sum_n a_n S^n of S = curlyhat(xi) are evaluated as c_0 I + ... + c_4 S^4 (paper eq. 70),
c_i from closed forms at |phi| >= 1 rad and from the exact Taylor tables of `estimator.lie._series` below,
as `estimator.lie.se3` does.

Checked by: tests/estimator/test_priors_ca.py, tests/estimator/test_priors_cv.py
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from rodo.estimator.lie._series import SE3_EXP, SE3_H, SE3_JAC, SO3_EXP, SO3_JAC
from rodo.estimator.lie.so3 import TAYLOR_BELOW

# kind 0: exp (Ad), 1: left Jacobian J, 2: H = sum S^n/(n+2)!
_SE3_TAB = np.ascontiguousarray(np.stack([SE3_EXP, SE3_JAC, SE3_H]))
_SO3_TAB = np.ascontiguousarray(np.stack([SO3_EXP, SO3_JAC]))
_TB = float(TAYLOR_BELOW)
# IEEE-safe fast-math subset (no nnan/ninf: finiteness checks must survive)
_FM = {"nsz", "arcp", "contract", "afn", "reassoc"}


def gauss_legendre_01(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, 1] (exact for polynomials of degree <= 2n - 1)."""
    x, w = np.polynomial.legendre.leggauss(n)
    return np.ascontiguousarray(0.5 * (x + 1.0)), np.ascontiguousarray(0.5 * w)


# Quadrature rules over u in [0, 1] for Q_k. The integrand is entire in u; with S = curlyhat(sigma), rotation
# angle a and translation norm r, |S^n| <~ a^n + n r a^(n-1), so the rule is chosen by b = a + sqrt(a r).
# Thresholds calibrated so that Q_k matches expm of the 36x36 S_M to ~1e-13 relative (vehicle motion at
# 13 Hz has b ~ 0.3: 6 nodes); checked by
# tests/estimator/test_priors_ca.py::test_process_noise_matches_van_loan_of_full_magnus_block.
QUAD_SIZES = (4, 6, 8, 12, 24, 32)
QUAD_BELOW = np.array([0.08, 1.2, 4.0, 15.0, 50.0, np.inf])
QUAD_NODES = np.zeros((len(QUAD_SIZES), max(QUAD_SIZES)))
QUAD_WEIGHTS = np.zeros_like(QUAD_NODES)
for _i, _n in enumerate(QUAD_SIZES):
    QUAD_NODES[_i, :_n], QUAD_WEIGHTS[_i, :_n] = gauss_legendre_01(_n)
QUAD_COUNT = np.array(QUAD_SIZES, dtype=np.int64)


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _quad_set(sig):
    a = math.sqrt(sig[3] * sig[3] + sig[4] * sig[4] + sig[5] * sig[5])
    r = math.sqrt(sig[0] * sig[0] + sig[1] * sig[1] + sig[2] * sig[2])
    b = a + math.sqrt(a * r)
    for i in range(QUAD_BELOW.shape[0]):
        if b < QUAD_BELOW[i]:
            return i
    return QUAD_BELOW.shape[0] - 1


# ----------------------------------------------------------------------------------------------
# scalar coefficients
@njit(cache=True, fastmath=_FM, error_model="numpy")
def _se3_coeffs(kind, a, out):
    """c_0..c_4 of f(curlyhat(xi)) for |phi| = a (kind 0 exp, 1 J, 2 H)."""
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


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _so3_coeffs(kind, a, out):
    """c_0..c_2 of f(phi^) (kind 0 exp, 1 J)."""
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
# small linear algebra
@njit(cache=True, fastmath=_FM, error_model="numpy")
def _ad_vec(a, b, out):
    """out = curlyhat(a) b = [phi_a x rho_b + rho_a x phi_b; phi_a x phi_b]."""
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


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _hat3(v, o, out):
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


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _ub_curly(v, out):
    """curlyhat(v) as ub: A = phi^, B = rho^."""
    _hat3(v, 3, out[0])
    _hat3(v, 0, out[1])


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _ub_mul(P, Q, out):
    for i in range(3):
        for j in range(3):
            s0 = 0.0
            s1 = 0.0
            for k in range(3):
                s0 += P[0, i, k] * Q[0, k, j]
                s1 += P[0, i, k] * Q[1, k, j] + P[1, i, k] * Q[0, k, j]
            out[0, i, j] = s0
            out[1, i, j] = s1


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _ub_poly(c, scale, Sp, out):
    """out = sum_i c[i] scale^i Sp[i] (Sp[0] = I)."""
    f = 1.0
    out[:] = 0.0
    for i in range(5):
        ci = c[i] * f
        for j in range(2):
            for k in range(3):
                for m in range(3):
                    out[j, k, m] += ci * Sp[i, j, k, m]
        f *= scale


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _ub_axpby(alpha, X, beta, out):
    """out = alpha X + beta out (ub arrays); beta == 0 overwrites (out may hold garbage)."""
    for j in range(2):
        for k in range(3):
            for m in range(3):
                if beta == 0.0:
                    out[j, k, m] = alpha * X[j, k, m]
                else:
                    out[j, k, m] = alpha * X[j, k, m] + beta * out[j, k, m]


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _sandwich_acc(N, Qc, Nd, NQ, Q, c11, c12, c13):
    """With NQ = N Qc (N ub): Q[:6,:6] += c11 N Qc N^T (upper triangle), Q[:6,6:12] += c12 NQ,
    Q[:6,12:18] += c13 NQ (skipped when c13 == 0)."""
    Nd[:] = 0.0
    _ub_to_dense(N, Nd, 0, 0, 1.0)
    for i in range(6):
        k0 = 0 if i < 3 else 3  # zero lower-left block of N
        for j in range(6):
            s = 0.0
            for k in range(k0, 6):
                s += Nd[i, k] * Qc[k, j]
            NQ[i, j] = s
    for i in range(6):
        for j in range(i, 6):
            k0 = 0 if j < 3 else 3
            s = 0.0
            for k in range(k0, 6):
                s += NQ[i, k] * Nd[j, k]
            Q[i, j] += c11 * s
        if c12 != 0.0:
            for j in range(6):
                Q[i, 6 + j] += c12 * NQ[i, j]
        if c13 != 0.0:
            for j in range(6):
                Q[i, 12 + j] += c13 * NQ[i, j]


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _ub_to_dense(U, M, r0, c0, alpha):
    """M[r0:r0+6, c0:c0+6] += alpha * U (dense)."""
    for i in range(3):
        for j in range(3):
            M[r0 + i, c0 + j] += alpha * U[0, i, j]
            M[r0 + i, c0 + 3 + j] += alpha * U[1, i, j]
            M[r0 + 3 + i, c0 + 3 + j] += alpha * U[0, i, j]


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _ub_powers(S, Sp):
    """Sp[i] = S^i, i = 0..4."""
    Sp[0] = 0.0
    for i in range(3):
        Sp[0, 0, i, i] = 1.0
    Sp[1] = S
    _ub_mul(S, S, Sp[2])
    _ub_mul(Sp[2], S, Sp[3])
    _ub_mul(Sp[2], Sp[2], Sp[4])


# ----------------------------------------------------------------------------------------------
# Magnus pose term (paper eq. 28-30 + the fourth-order term, docs/priors.md)
@njit(cache=True, fastmath=_FM, error_model="numpy")
def magnus_sigma(varpi, vd, dt, order, out, tmp1, tmp2):
    """out = sigma (6,) with exp(sigma^) the Magnus approximation of the pose flow over dt."""
    h2 = dt * dt
    for i in range(6):
        out[i] = dt * varpi[i] + 0.5 * h2 * vd[i]
    if order >= 2:
        _ad_vec(vd, varpi, tmp1)  # [vd^, varpi^]
        c = h2 * dt / 12.0
        for i in range(6):
            out[i] += c * tmp1[i]
        if order >= 3:
            _ad_vec(vd, tmp1, tmp2)  # [vd^, [vd^, varpi^]]
            c = h2 * h2 * dt / 240.0
            for i in range(6):
                out[i] += c * tmp2[i]
        if order >= 4:
            _ad_vec(varpi, vd, tmp1)
            _ad_vec(varpi, tmp1, tmp2)
            _ad_vec(varpi, tmp2, tmp1)  # ad(varpi)^3 vd
            c = h2 * h2 * dt / 720.0
            for i in range(6):
                out[i] += c * tmp1[i]


@njit(cache=True, fastmath=_FM, error_model="numpy")
def matmul_into(A, B, out):
    """out = A B for small matrices (3x3 A^2, 4x4 poses; out must not alias A or B)."""
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            s = 0.0
            for k in range(A.shape[1]):
                s += A[i, k] * B[k, j]
            out[i, j] = s


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _se3_exp_into(xi, E, c3, A, A2):
    """E (4, 4) = exp(xi^)."""
    a = math.sqrt(xi[3] * xi[3] + xi[4] * xi[4] + xi[5] * xi[5])
    _hat3(xi, 3, A)
    matmul_into(A, A, A2)
    _so3_coeffs(0, a, c3)
    for i in range(3):
        for j in range(3):
            E[i, j] = c3[1] * A[i, j] + c3[2] * A2[i, j]
        E[i, i] += c3[0]
    _so3_coeffs(1, a, c3)
    for i in range(3):
        s = c3[0] * xi[i]
        for k in range(3):
            s += (c3[1] * A[i, k] + c3[2] * A2[i, k]) * xi[k]
        E[i, 3] = s
        E[3, i] = 0.0
    E[3, 3] = 1.0




@njit(cache=True, fastmath=_FM, error_model="numpy")
def predict_batch(T, varpi, vd, dt, order, T_out, varpi_out, vd_out):
    """Mean transition eq. 31-34 for N intervals: T (N,4,4), varpi/vd (N,6), dt (N,)."""
    sig = np.empty(6)
    t1 = np.empty(6)
    t2 = np.empty(6)
    E = np.empty((4, 4))
    c3 = np.empty(3)
    A = np.empty((3, 3))
    A2 = np.empty((3, 3))
    for n in range(T.shape[0]):
        magnus_sigma(varpi[n], vd[n], dt[n], order, sig, t1, t2)
        _se3_exp_into(sig, E, c3, A, A2)
        matmul_into(E, T[n], T_out[n])
        for i in range(6):
            varpi_out[n, i] = varpi[n, i] + dt[n] * vd[n, i]
            vd_out[n, i] = vd[n, i]


# ----------------------------------------------------------------------------------------------
# CA prior: F_k and Q_k fused (paper eq. 43-69, docs/priors.md)
@njit(cache=True, fastmath=_FM, error_model="numpy")
def _s_blocks(varpi, dt, order, X, Y, S12, S13, U1, U2, N):
    """S12 = dt I + dt^3/12 Y + dt^5/240 Y^2 (+ order 4), S13 = 0 (order 4: dt^5/720 (3XY - YX)); Y = curlyhat(vd)
    given, X = curlyhat(varpi) written here (order 4 only). U1, U2, N are scratch."""
    S12[:] = 0.0
    S13[:] = 0.0
    for i in range(3):
        S12[0, i, i] = dt
    h5 = dt * dt * dt * dt * dt
    if order >= 2:
        _ub_axpby(dt * dt * dt / 12.0, Y, 1.0, S12)
    if order >= 3:
        _ub_mul(Y, Y, U1)
        _ub_axpby(h5 / 240.0, U1, 1.0, S12)
    if order >= 4:
        _ub_curly(varpi, X)
        c = h5 / 720.0
        _ub_mul(X, Y, U1)  # XY
        _ub_mul(Y, X, U2)  # YX
        _ub_axpby(3.0 * c, U1, 0.0, S13)
        _ub_axpby(-c, U2, 1.0, S13)  # S13 = c (3 XY - YX)
        # S12 += c (-3 X^2 Y + 3 X Y X - Y X^2) = c (X (3 (YX - XY)) - (YX) X)
        _ub_axpby(3.0, U2, 0.0, N)
        _ub_axpby(-3.0, U1, 1.0, N)
        _ub_mul(X, N, U1)  # 3 X (YX - XY)
        _ub_mul(U2, X, N)  # Y X^2
        _ub_axpby(c, U1, 1.0, S12)
        _ub_axpby(-c, N, 1.0, S12)


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _last_column(sig, Sp, cf, S12, S13, h, scale, order, Hs, Js, U1, N):
    """N = h H(scale sigma) S12 + J(scale sigma) S13 (the pose row of exp(scale S_A) L, up to the factor)."""
    a = math.sqrt(sig[3] * sig[3] + sig[4] * sig[4] + sig[5] * sig[5])
    _se3_coeffs(2, scale * a, cf)
    _ub_poly(cf, scale, Sp, Hs)
    _ub_mul(Hs, S12, U1)
    _ub_axpby(h, U1, 0.0, N)
    if order >= 4:
        _se3_coeffs(1, scale * a, cf)
        _ub_poly(cf, scale, Sp, Js)
        _ub_mul(Js, S13, U1)
        _ub_axpby(1.0, U1, 1.0, N)


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _ca_core(varpi, vd, dt, Qc, order, noise, F, Q, want_q, ws6, ws33, ws66, Sp, cf):
    """Write F_k (18,18) and, if want_q, Q_k (18,18) for one interval (F, Q zeroed by the caller).

    noise 0: the paper's Q = G F^T (eq. 43-48); 1: quadrature over s of Phi(dt, s) L Qc L^T Phi(dt, s)^T with
    Phi(dt, s) the Magnus transition of the sub-interval [s, dt] (docs/priors.md sec. 4b)."""
    sig = ws6[0]
    t1 = ws6[1]
    t2 = ws6[2]
    w0 = ws6[3]
    sq = ws6[4]
    S = ws33[0]
    X = ws33[1]
    Y = ws33[2]
    S12 = ws33[3]
    S13 = ws33[4]
    U1 = ws33[5]
    U2 = ws33[6]
    Hs = ws33[7]
    Js = ws33[8]
    N = ws33[9]
    S12q = ws33[10]
    S13q = ws33[11]
    magnus_sigma(varpi, vd, dt, order, sig, t1, t2)
    _ub_curly(sig, S)
    _ub_powers(S, Sp[0])
    a = math.sqrt(sig[3] * sig[3] + sig[4] * sig[4] + sig[5] * sig[5])
    _ub_curly(vd, Y)
    _s_blocks(varpi, dt, order, X, Y, S12, S13, U1, U2, N)
    # F: [[Ad(exp sigma), J S12, J S13 + dt H S12], [0, I, dt I], [0, 0, I]]
    _se3_coeffs(0, a, cf)
    _ub_poly(cf, 1.0, Sp[0], U1)
    _ub_to_dense(U1, F, 0, 0, 1.0)
    _se3_coeffs(1, a, cf)
    _ub_poly(cf, 1.0, Sp[0], Js)
    _ub_mul(Js, S12, U1)
    _ub_to_dense(U1, F, 0, 6, 1.0)
    _last_column(sig, Sp[0], cf, S12, S13, dt, 1.0, order, Hs, Js, U1, N)
    _ub_to_dense(N, F, 0, 12, 1.0)
    for i in range(6, 18):
        F[i, i] = 1.0
    for i in range(6):
        F[6 + i, 12 + i] = dt
    if not want_q:
        return
    # Q = dt int_0^1 E(u) L Qc L^T E(u)^T du with E(u) L = [K(u); u dt I; I]:
    #   noise 0: E(u) = exp(u S_A), K = u N(u), N(u) = u dt H(u sigma) S12 + J(u sigma) S13;
    #   noise 1: E(u) = Magnus transition over the last u dt of the interval, K = N of that sub-interval.
    NQ = ws66[0]
    Nd = ws66[1]
    qs = _quad_set(sig)
    for q in range(QUAD_COUNT[qs]):
        v = QUAD_NODES[qs, q]
        w = QUAD_WEIGHTS[qs, q]
        if noise == 0:
            _last_column(sig, Sp[0], cf, S12, S13, v * dt, v, order, Hs, Js, U1, N)
            _sandwich_acc(N, Qc, Nd, NQ, Q, dt * w * v * v, dt * dt * w * v * v, dt * w * v)
        else:
            h = v * dt
            for i in range(6):
                w0[i] = varpi[i] + (dt - h) * vd[i]
            magnus_sigma(w0, vd, h, order, sq, t1, t2)
            _ub_curly(sq, U1)
            _ub_powers(U1, Sp[1])
            _s_blocks(w0, h, order, X, Y, S12q, S13q, U1, U2, N)
            _last_column(sq, Sp[1], cf, S12q, S13q, h, 1.0, order, Hs, Js, U1, N)
            _sandwich_acc(N, Qc, Nd, NQ, Q, dt * w, dt * w * h, dt * w)
    h2 = dt * dt
    for i in range(6):
        for j in range(6):
            qc = Qc[i, j]
            Q[6 + i, 6 + j] = h2 * dt / 3.0 * qc
            Q[6 + i, 12 + j] = 0.5 * h2 * qc
            Q[12 + i, 12 + j] = dt * qc
    for i in range(18):  # mirror the upper triangle
        for j in range(i):
            Q[i, j] = Q[j, i]


@njit(cache=True, fastmath=_FM, error_model="numpy")
def ca_batch(varpi, vd, dt, Qc, order, noise, F, Q, want_q):
    """F (N,18,18), Q (N,18,18) for N intervals (written in place, zeroed here)."""
    ws6 = np.empty((5, 6))
    ws33 = np.empty((12, 2, 3, 3))
    ws66 = np.empty((2, 6, 6))
    Sp = np.empty((2, 5, 2, 3, 3))
    cf = np.empty(5)
    for n in range(varpi.shape[0]):
        F[n] = 0.0
        if want_q:
            Q[n] = 0.0
        _ca_core(varpi[n], vd[n], dt[n], Qc, order, noise, F[n], Q[n], want_q, ws6, ws33, ws66, Sp, cf)


@njit(cache=True, fastmath=_FM, error_model="numpy")
def ca_into(varpi, vd, dt, Qc, order, noise, want_q, out):
    """One interval into out (2, 18, 18) = (F, Q); returns 0, or 1 / 2 if varpi / vd is not finite
    (a status for the public method to raise on; nothing is computed then)."""
    for i in range(6):
        if not math.isfinite(varpi[i]):
            return 1
    for i in range(6):
        if not math.isfinite(vd[i]):
            return 2
    out[0] = 0.0
    if want_q:
        out[1] = 0.0
    _ca_core(varpi, vd, dt, Qc, order, noise, out[0], out[1], want_q, np.empty((5, 6)), np.empty((12, 2, 3, 3)),
             np.empty((2, 6, 6)), np.empty((2, 5, 2, 3, 3)), np.empty(5))
    return 0


@njit(cache=True, fastmath=_FM, error_model="numpy")
def predict_single(T, varpi, vd, dt, order):
    """(T_k (4,4), varpi_k (6,), vd_k (6,)) for one interval (eq. 31-34)."""
    T_out = np.empty((1, 4, 4))
    w_out = np.empty((1, 6))
    v_out = np.empty((1, 6))
    Tb = np.empty((1, 4, 4))
    Tb[0] = T
    wb = np.empty((1, 6))
    wb[0] = varpi
    vb = np.empty((1, 6))
    vb[0] = vd
    db = np.empty(1)
    db[0] = dt
    predict_batch(Tb, wb, vb, db, order, T_out, w_out, v_out)
    return T_out[0], w_out[0], v_out[0]
