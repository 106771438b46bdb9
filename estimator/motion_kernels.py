"""Numba kernel of the motion-prior residuals of a window (the solver's hot path besides the measurements).

For consecutive states the residual is e = x2 (-) f(x1) = [ln(T2 Tp^-1)^vee; tail2 - tail_pred] with
J_e_x2 = diag(J(e_xi)^-1, I) and J_e_x1 = -diag(J(-e_xi)^-1, I) F_k (the priors' `residual`, docs/priors.md).
`MotionModel.residuals` passes the predicted means and F_k from `estimator.priors.kernels`; this kernel adds the
SE(3) logarithm and the inverse left Jacobians (`estimator.lie.kernels.se3_log_and_jac_inv`), which in NumPy cost
about 0.6 ms per window (many tiny array calls) and here a few microseconds. The same formulas as
`estimator.lie` (quaternion-based SO(3) logarithm, J from its degree-four curlyhat polynomial with Taylor
coefficients below 1 rad), so the two agree to round-off.

Checked by: tests/estimator/test_window_kernels.py::test_batched_motion_residuals_equal_the_priors_residual,
    ::test_window_update_equals_state_oplus, ::test_motion_terms_in_the_normal_equations
"""

from __future__ import annotations

import numpy as np

from .jit import FASTMATH, njit
from .lie.kernels import matmul_into, se3_exp_into, se3_log_and_jac_inv


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def residuals(T_pred, tail_pred, T2, tail2, F, e, J1, J2):
    """Motion residuals of n intervals: T_pred, T2 (n, 4, 4), tail_pred, tail2 (n, d - 6), F (n, d, d) ->
    e (n, d), J1 = J_e_x1, J2 = J_e_x2 (n, d, d), written in place.

    Checked by: tests/estimator/test_window_kernels.py::test_batched_motion_residuals_equal_the_priors_residual
    """
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


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def exp_times(xi, T, out):
    """out[n] = exp(xi[n]^) T[n] for n poses: the solver's state update (left perturbation).

    Checked by: tests/estimator/test_window_kernels.py::test_window_update_equals_state_oplus
    """
    E = np.empty((4, 4))
    c3 = np.empty(3)
    A = np.empty((3, 3))
    A2 = np.empty((3, 3))
    for n in range(T.shape[0]):
        se3_exp_into(xi[n], E, c3, A, A2)
        matmul_into(E, T[n], out[n])


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def accumulate(H, b, e, J1, J2, W):
    """Adds the motion terms of consecutive states k, k+1 to the window's normal equations: with
    J = [J1_k, J2_k] (d x 2d), H[kd:(k+2)d, kd:(k+2)d] += J^T W_k J, b[...] += J^T W_k e_k; returns
    sum_k 1/2 e_k^T W_k e_k. J2 has the structure `residuals` gives it, diag(J2[:6, :6], I): only its pose block
    is read.

    J is sparse: below its pose rows, J1 = -F_k holds the identity and the dt blocks of the rates (a CA column
    has at most 8 nonzeros of 18, `_nonzeros`), so each column's nonzeros are listed once per interval and
    both products, J^T W and J^T (W J), run over them alone, a row of the result at a time over contiguous
    rows of the right factor (the innermost loops vectorise): 22 -> 12 us for a CA window of five states, 10.5 ->
    6 for CV. A skipped term is an exact zero times a finite W or e, so no sum loses anything but its order of
    evaluation. W_k must be symmetric (Q_k^-1, `spd.inv_spd`): a row of W stands for its column.

    Checked by: tests/estimator/test_window_kernels.py::test_motion_terms_in_the_normal_equations
    """
    n, d = e.shape[0], e.shape[1]
    JW = np.empty((2 * d, d))  # J^T W_k
    WJ = np.empty((d, 2 * d))  # its transpose, W_k J
    We = np.empty(d)
    rows, vals, count = np.empty((2 * d, d), np.int64), np.empty((2 * d, d)), np.empty(2 * d, np.int64)
    row = np.empty(2 * d)
    cost = 0.0
    for k in range(n):
        Wk = W[k]
        for i in range(d):
            s = 0.0
            for l in range(d):
                s += Wk[i, l] * e[k, l]
            We[i] = s
            cost += 0.5 * e[k, i] * s
        _nonzeros(J1[k], J2[k], rows, vals, count)
        o = k * d
        for r in range(2 * d):
            s = 0.0
            JW[r] = 0.0
            for m in range(count[r]):
                l, a = rows[r, m], vals[r, m]
                s += a * We[l]
                for c in range(d):
                    JW[r, c] += a * Wk[l, c]
            b[o + r] += s
        for r in range(2 * d):
            for c in range(d):
                WJ[c, r] = JW[r, c]
        for r in range(2 * d):
            row[:] = 0.0
            for m in range(count[r]):
                l, a = rows[r, m], vals[r, m]
                for c in range(2 * d):
                    row[c] += a * WJ[l, c]
            for c in range(2 * d):
                H[o + r, o + c] += row[c]
    return cost


@njit(cache=True, error_model="numpy")
def _nonzeros(J1, J2, rows, vals, count):
    """The nonzeros of each column r of J = [J1, diag(J2[:6, :6], I)] (d x 2d): rows[r, :count[r]] and
    vals[r, :count[r]], in the order of their rows."""
    d = J1.shape[0]
    for r in range(2 * d):
        m = 0
        if r < d + 6:
            for l in range(d if r < d else 6):
                a = J1[l, r] if r < d else J2[l, r - d]
                if a != 0.0:
                    rows[r, m] = l
                    vals[r, m] = a
                    m += 1
        else:
            rows[r, 0] = r - d
            vals[r, 0] = 1.0
            m = 1
        count[r] = m


@njit(cache=True, error_model="numpy")
def add_blocks(H, b, d, rate_info, rate_on, tail, ks, Hm, bm):
    """The window's per-state terms added to its normal equations (d: the state's dimension):

    the zero-mean rate terms of the states k with rate_on[k] (cost 1/2 t^T rate_info[k] t, t = tail[k], on the
    state's Euclidean part, indices 6 to d), and the measurement blocks Hm[q] (12, 12), bm[q] (12,) of state
    ks[q] on its pose and velocity. Returns the rate terms' cost.

    Checked by: tests/estimator/test_window.py::test_rate_prior_is_a_zero_mean_gaussian_term,
        ::test_compiled_normal_equations_equal_the_python_assembly (through `SlidingWindow.linearize`)
    """
    cost = 0.0
    m = d - 6
    for k in range(len(rate_on)):
        if not rate_on[k]:
            continue
        o = k * d + 6
        for i in range(m):
            s = 0.0
            for j in range(m):
                H[o + i, o + j] += rate_info[k, i, j]
                s += rate_info[k, i, j] * tail[k, j]
            b[o + i] += s
            cost += 0.5 * tail[k, i] * s
    for q in range(len(ks)):
        o = ks[q] * d
        for i in range(12):
            for j in range(12):
                H[o + i, o + j] += Hm[q, i, j]
            b[o + i] += bm[q, i]
    return cost
