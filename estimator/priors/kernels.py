"""Compiled (numba) kernels of the motion priors: Magnus mean, F_k and Q_k fused, batched forms (CA and CV).

No validation here (the public methods of `constant_acceleration` / `constant_velocity` do it once). Built from
the SE(3) and upper-block (ub) kernels of `estimator.lie.kernels` (notation there). Derivations: docs/priors.md.

Checked by: tests/estimator/test_priors_ca.py, tests/estimator/test_priors_cv.py
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import FASTMATH, njit
from ..lie.kernels import (ad_vec, matmul_into, se3_coeffs, se3_exp_into, ub_axpby, ub_curly, ub_mul, ub_poly,
                           ub_powers, ub_to_dense)

__all__ = ["QUAD_BELOW", "QUAD_COUNT", "QUAD_NODES", "QUAD_SIZES", "QUAD_WEIGHTS", "ca_batch", "ca_into",
           "cv_batch", "cv_into", "gauss_legendre_01", "magnus_sigma", "predict_batch", "predict_single"]


def gauss_legendre_01(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, 1] (exact for polynomials of degree <= 2n - 1).

    Checked by: tests/estimator/test_priors_ca.py::test_process_noise_matches_van_loan_of_full_magnus_block
    """
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _quad_set(sig):
    a = math.sqrt(sig[3] * sig[3] + sig[4] * sig[4] + sig[5] * sig[5])
    r = math.sqrt(sig[0] * sig[0] + sig[1] * sig[1] + sig[2] * sig[2])
    b = a + math.sqrt(a * r)
    for i in range(QUAD_BELOW.shape[0]):
        if b < QUAD_BELOW[i]:
            return i
    return QUAD_BELOW.shape[0] - 1


# ----------------------------------------------------------------------------------------------
# Magnus pose term and mean (paper eq. 28-34 + the fourth-order term, docs/priors.md)
@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def magnus_sigma(varpi, vd, dt, order, out, tmp1, tmp2):
    """out = sigma (6,) with exp(sigma^) the Magnus approximation of the pose flow over dt (orders 1-4).

    Checked by: tests/estimator/test_priors_ca.py::test_magnus_pose_matches_exact_ode, ::test_fourth_order_term_sign
    """
    h2 = dt * dt
    for i in range(6):
        out[i] = dt * varpi[i] + 0.5 * h2 * vd[i]
    if order >= 2:
        ad_vec(vd, varpi, tmp1)  # [vd^, varpi^]
        c = h2 * dt / 12.0
        for i in range(6):
            out[i] += c * tmp1[i]
        if order >= 3:
            ad_vec(vd, tmp1, tmp2)  # [vd^, [vd^, varpi^]]
            c = h2 * h2 * dt / 240.0
            for i in range(6):
                out[i] += c * tmp2[i]
        if order >= 4:
            ad_vec(varpi, vd, tmp1)
            ad_vec(varpi, tmp1, tmp2)
            ad_vec(varpi, tmp2, tmp1)  # ad(varpi)^3 vd
            c = h2 * h2 * dt / 720.0
            for i in range(6):
                out[i] += c * tmp1[i]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def predict_batch(T, varpi, vd, dt, order, T_out, varpi_out, vd_out):
    """Mean transition eq. 31-34 for N intervals: T (N,4,4), varpi/vd (N,6), dt (N,) -> the *_out arrays.

    Checked by: tests/estimator/test_priors_ca.py::test_predict_batches_broadcast
    """
    sig = np.empty(6)
    t1 = np.empty(6)
    t2 = np.empty(6)
    E = np.empty((4, 4))
    c3 = np.empty(3)
    A = np.empty((3, 3))
    A2 = np.empty((3, 3))
    for n in range(T.shape[0]):
        magnus_sigma(varpi[n], vd[n], dt[n], order, sig, t1, t2)
        se3_exp_into(sig, E, c3, A, A2)
        matmul_into(E, T[n], T_out[n])
        for i in range(6):
            varpi_out[n, i] = varpi[n, i] + dt[n] * vd[n, i]
            vd_out[n, i] = vd[n, i]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def predict_single(T, varpi, vd, dt, order):
    """(T_k (4,4), varpi_k (6,), vd_k (6,)) for one interval (eq. 31-34).

    Checked by: tests/estimator/test_priors_ca.py::test_magnus_pose_matches_exact_ode
    """
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


# ----------------------------------------------------------------------------------------------
# CA prior: F_k and Q_k fused (paper eq. 43-69, docs/priors.md)
@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _sandwich_acc(N, Qc, Nd, NQ, Q, c11, c12, c13):
    """(CA and CV) With NQ = N Qc (N ub): Q[:6,:6] += c11 N Qc N^T (upper triangle), Q[:6,6:12] += c12 NQ,
    Q[:6,12:18] += c13 NQ (skipped when c13 == 0)."""
    Nd[:] = 0.0
    ub_to_dense(N, Nd, 0, 0, 1.0)
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _s_blocks(varpi, dt, order, X, Y, S12, S13, U1, U2, N):
    """S12 = dt I + dt^3/12 Y + dt^5/240 Y^2 (+ order 4), S13 = 0 (order 4: dt^5/720 (3XY - YX)); Y = curlyhat(vd)
    given, X = curlyhat(varpi) written here (order 4 only). U1, U2, N are scratch."""
    S12[:] = 0.0
    S13[:] = 0.0
    for i in range(3):
        S12[0, i, i] = dt
    h5 = dt * dt * dt * dt * dt
    if order >= 2:
        ub_axpby(dt * dt * dt / 12.0, Y, 1.0, S12)
    if order >= 3:
        ub_mul(Y, Y, U1)
        ub_axpby(h5 / 240.0, U1, 1.0, S12)
    if order >= 4:
        ub_curly(varpi, X)
        c = h5 / 720.0
        ub_mul(X, Y, U1)  # XY
        ub_mul(Y, X, U2)  # YX
        ub_axpby(3.0 * c, U1, 0.0, S13)
        ub_axpby(-c, U2, 1.0, S13)  # S13 = c (3 XY - YX)
        # S12 += c (-3 X^2 Y + 3 X Y X - Y X^2) = c (X (3 (YX - XY)) - (YX) X)
        ub_axpby(3.0, U2, 0.0, N)
        ub_axpby(-3.0, U1, 1.0, N)
        ub_mul(X, N, U1)  # 3 X (YX - XY)
        ub_mul(U2, X, N)  # Y X^2
        ub_axpby(c, U1, 1.0, S12)
        ub_axpby(-c, N, 1.0, S12)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _last_column(sig, Sp, cf, S12, S13, h, scale, order, Hs, Js, U1, N):
    """N = h H(scale sigma) S12 + J(scale sigma) S13 (the pose row of exp(scale S_A) L, up to the factor)."""
    a = math.sqrt(sig[3] * sig[3] + sig[4] * sig[4] + sig[5] * sig[5])
    se3_coeffs(2, scale * a, cf)
    ub_poly(cf, scale, Sp, Hs)
    ub_mul(Hs, S12, U1)
    ub_axpby(h, U1, 0.0, N)
    if order >= 4:
        se3_coeffs(1, scale * a, cf)
        ub_poly(cf, scale, Sp, Js)
        ub_mul(Js, S13, U1)
        ub_axpby(1.0, U1, 1.0, N)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
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
    ub_curly(sig, S)
    ub_powers(S, Sp[0])
    a = math.sqrt(sig[3] * sig[3] + sig[4] * sig[4] + sig[5] * sig[5])
    ub_curly(vd, Y)
    _s_blocks(varpi, dt, order, X, Y, S12, S13, U1, U2, N)
    # F: [[Ad(exp sigma), J S12, J S13 + dt H S12], [0, I, dt I], [0, 0, I]]
    se3_coeffs(0, a, cf)
    ub_poly(cf, 1.0, Sp[0], U1)
    ub_to_dense(U1, F, 0, 0, 1.0)
    se3_coeffs(1, a, cf)
    ub_poly(cf, 1.0, Sp[0], Js)
    ub_mul(Js, S12, U1)
    ub_to_dense(U1, F, 0, 6, 1.0)
    _last_column(sig, Sp[0], cf, S12, S13, dt, 1.0, order, Hs, Js, U1, N)
    ub_to_dense(N, F, 0, 12, 1.0)
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
            ub_curly(sq, U1)
            ub_powers(U1, Sp[1])
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def ca_batch(varpi, vd, dt, Qc, order, noise, F, Q, want_q):
    """CA F (N,18,18) and, if want_q, Q (N,18,18) for N intervals (written in place, zeroed here).

    Checked by: tests/estimator/test_priors_ca.py::test_batched_forms_equal_single_calls
    """
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def ca_into(varpi, vd, dt, Qc, order, noise, want_q, out):
    """One CA interval into out (2, 18, 18) = (F, Q); returns 0, or 1 / 2 if varpi / vd is not finite
    (a status for the public method to raise on; nothing is computed then).

    Checked by: tests/estimator/test_priors_ca.py::test_bad_input_names_the_argument
    """
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


# ----------------------------------------------------------------------------------------------
# CV prior: F_k and Q_k fused (docs/priors.md sec. 5)
@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _cv_core(varpi, dt, Qc, F, Q, want_q, sig, U, Sp, cf, Nd, NQ):
    """F (12,12) and, if want_q, Q (12,12) for one interval (F, Q zeroed by the caller)."""
    for i in range(6):
        sig[i] = dt * varpi[i]
    ub_curly(sig, U[0])
    ub_powers(U[0], Sp)
    a = math.sqrt(sig[3] * sig[3] + sig[4] * sig[4] + sig[5] * sig[5])
    se3_coeffs(0, a, cf)
    ub_poly(cf, 1.0, Sp, U[1])
    ub_to_dense(U[1], F, 0, 0, 1.0)
    se3_coeffs(1, a, cf)
    ub_poly(cf, 1.0, Sp, U[1])
    ub_to_dense(U[1], F, 0, 6, dt)
    for i in range(6, 12):
        F[i, i] = 1.0
    if not want_q:
        return
    # Q11 = dt^3 int u^2 J(u sigma) Qc J^T du (quadrature), Q12 = dt^2 H(sigma) Qc, Q22 = dt Qc
    qs = _quad_set(sig)
    for q in range(QUAD_COUNT[qs]):
        v = QUAD_NODES[qs, q]
        se3_coeffs(1, v * a, cf)
        ub_poly(cf, v, Sp, U[1])
        _sandwich_acc(U[1], Qc, Nd, NQ, Q, dt * dt * dt * QUAD_WEIGHTS[qs, q] * v * v, 0.0, 0.0)
    se3_coeffs(2, a, cf)
    ub_poly(cf, 1.0, Sp, U[1])
    Nd[:] = 0.0
    ub_to_dense(U[1], Nd, 0, 0, 1.0)
    for i in range(6):
        for j in range(6):
            acc = 0.0
            for k in range(6):
                acc += Nd[i, k] * Qc[k, j]
            Q[i, 6 + j] = dt * dt * acc
            Q[6 + i, 6 + j] = dt * Qc[i, j]
    for i in range(12):  # mirror the upper triangle
        for j in range(i):
            Q[i, j] = Q[j, i]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def cv_batch(varpi, dt, Qc, F, Q, want_q):
    """CV F (N,12,12) and, if want_q, Q (N,12,12) for N intervals (written in place, zeroed here).

    Checked by: tests/estimator/test_priors_cv.py::test_cv_predict_and_batches
    """
    sig = np.empty(6)
    U = np.empty((2, 2, 3, 3))
    Sp = np.empty((5, 2, 3, 3))
    cf = np.empty(5)
    Nd = np.empty((6, 6))
    NQ = np.empty((6, 6))
    for n in range(varpi.shape[0]):
        F[n] = 0.0
        if want_q:
            Q[n] = 0.0
        _cv_core(varpi[n], dt[n], Qc, F[n], Q[n], want_q, sig, U, Sp, cf, Nd, NQ)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def cv_into(varpi, dt, Qc, want_q, out):
    """One CV interval into out (2, 12, 12) = (F, Q); returns 0, or 1 if varpi is not finite (nothing computed).

    Checked by: tests/estimator/test_priors_cv.py::test_cv_matches_exact, ::test_cv_bad_input
    """
    for i in range(6):
        if not math.isfinite(varpi[i]):
            return 1
    out[0] = 0.0
    if want_q:
        out[1] = 0.0
    _cv_core(varpi, dt, Qc, out[0], out[1], want_q, np.empty(6), np.empty((2, 2, 3, 3)), np.empty((5, 2, 3, 3)),
             np.empty(5), np.empty((6, 6)), np.empty((6, 6)))
    return 0
