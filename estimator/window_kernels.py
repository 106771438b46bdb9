"""The sliding window's normal equations in one compiled call (`SlidingWindow.linearize`, the solver's hot path),
and the Gauss-Newton loop around them (`gauss_newton`, `SlidingWindow.optimize`).

Per linearisation the window adds, in this order: the prior on its oldest state (e = x0 (-) mean, cost
1/2 e^T Lam e + g^T e, de/dx0 = diag(J(e_xi)^-1, I)), the motion-prior terms between consecutive states (the
priors' batched means and F_k, `motion_kernels.residuals` and `accumulate`), the measurement terms of every state
with associated pairs (`measurement_kernels.state_pairs`, or the quadratic model of the set's last linearisation
where the window lags it: `SlidingWindow._arguments`), and the rate terms with the measurement blocks
(`motion_kernels.add_blocks`). Assembled in Python, the same took about a millisecond of array calls per CA/P
scan on city (three linearisations) around the pair kernel's 0.8 ms. The references it is checked against: the
priors' `residual` (through `MotionPrior.residuals`), `measurements.predict` and `lie.se3`.

IEEE arithmetic here (no fast-math flags; its callees keep theirs): with the fast-math subset on these helpers a
freshly compiled `normal_equations` and the same one loaded from numba's cache gave results that differed by
rounding (the flags let the compiler reorder sums; the mechanism was not isolated further), so a run right after
an edit or an install was not bit for bit the runs after it. Without them the two agree bit for bit (20 s of five
scenarios x two models, each run after a fresh compilation and after a load from the cache).

Checked by: tests/estimator/test_window.py::test_compiled_normal_equations_equal_the_python_assembly,
    tests/estimator/test_window_solve.py::test_compiled_gauss_newton_equals_the_python_loop,
    ::test_the_solve_s_schur_complement_is_the_marginalisation_s
"""

from __future__ import annotations

import numpy as np

from .jit import njit
from .lie.kernels import matmul_into, se3_log_and_jac_inv
from .measurement_kernels import state_pairs
from .motion_kernels import accumulate, add_blocks, exp_times, residuals
from .priors.kernels import ca_batch, cv_batch, predict_batch


@njit(cache=True, error_model="numpy")
def _log_from(T, T0_inverse, xi):
    """xi = ln(T T0^-1)^vee (6,); returns J(xi)^-1 (6, 6)."""
    D = np.empty((4, 4))
    matmul_into(T, T0_inverse, D)
    Jp, Jm = np.empty((6, 6)), np.empty((6, 6))
    se3_log_and_jac_inv(D, xi, Jp, Jm)
    return Jp


@njit(cache=True, error_model="numpy")
def _prior_terms(T0, tail0, mean_T_inverse, mean_tail, info, grad, H, b):
    """The prior on the oldest state added to H[:d, :d], b[:d]; returns its cost."""
    d = info.shape[0]
    e = np.empty(d)
    Jp = _log_from(T0, mean_T_inverse, e[:6])
    for i in range(d - 6):
        e[6 + i] = tail0[i] - mean_tail[i]
    r = np.empty(d)  # Lam e + g
    cost = 0.0
    for i in range(d):
        s = 0.0
        for j in range(d):
            s += info[i, j] * e[j]
        r[i] = s + grad[i]
        cost += e[i] * (0.5 * s + grad[i])
    JL = np.empty((d, d))  # J^T Lam, J = diag(Jp, I)
    for i in range(d):
        for j in range(d):
            if i < 6:
                s = 0.0
                for k in range(6):
                    s += Jp[k, i] * info[k, j]
                JL[i, j] = s
            else:
                JL[i, j] = info[i, j]
    for i in range(d):
        if i < 6:
            s = 0.0
            for k in range(6):
                s += Jp[k, i] * r[k]
            b[i] += s
        else:
            b[i] += r[i]
        for j in range(d):
            if j < 6:
                s = 0.0
                for k in range(6):
                    s += JL[i, k] * Jp[k, j]
                H[i, j] += s
            else:
                H[i, j] += JL[i, j]
    return cost


@njit(cache=True, error_model="numpy")
def _motion_terms(ca, order, noise, Qc, T, tail, t, motion_info, H, b):
    """The motion-prior terms of consecutive states added to H, b; returns their cost."""
    n, d = T.shape[0] - 1, tail.shape[1] + 6
    dt = np.empty(n)
    for k in range(n):
        dt[k] = t[k + 1] - t[k]
    T1, T2 = np.ascontiguousarray(T[:-1]), np.ascontiguousarray(T[1:])
    varpi1 = np.ascontiguousarray(tail[:-1, :6])
    vd1 = np.ascontiguousarray(tail[:-1, 6:]) if ca else np.zeros((n, 6))
    Tp, varpi_p, vd_p = np.empty((n, 4, 4)), np.empty((n, 6)), np.empty((n, 6))
    predict_batch(T1, varpi1, vd1, dt, order if ca else 1, Tp, varpi_p, vd_p)
    F = np.empty((n, d, d))
    if ca:
        ca_batch(varpi1, vd1, dt, Qc, order, noise, F, np.empty((n, 0, 0)), False)
    else:
        cv_batch(varpi1, dt, Qc, F, np.empty((n, 0, 0)), False)
    tail_pred = np.empty((n, d - 6))
    tail_pred[:, :6] = varpi_p
    if ca:
        tail_pred[:, 6:] = vd_p
    e, J1, J2 = np.empty((n, d)), np.empty((n, d, d)), np.empty((n, d, d))
    residuals(Tp, tail_pred, T2, np.ascontiguousarray(tail[1:]), F, e, J1, J2)
    return accumulate(H, b, e, J1, J2, motion_info)


@njit(cache=True, error_model="numpy")
def normal_equations(ca, order, noise, Qc, T, tail, t, mean_T_inverse, mean_tail, info, grad, motion_info,
                     rate_info, rate_on, model, ks, slot, offsets, p, z, W, Tvs, weights, robust_c, d2,
                     T0_inverse, varpi0, H0, b0, c0, H, b, Hm, bm, cm):
    """The window's normal equations H d = -b (H, b zeroed by the caller) at the states T (n, 4, 4), tail
    (n, d - 6), t (n,); returns the cost.

    Args:
        ca, order, noise, Qc: the motion prior (CA with its Magnus order and noise code, or CV) and its PSD.
        mean_T_inverse, mean_tail, info, grad: the prior on the oldest state (its mean's T^-1 and tail, Lam, g).
        motion_info: (n - 1, d, d) Q_k^-1. rate_info, rate_on: the rate terms (`motion_kernels.add_blocks`).
        model, ks, slot: the measurement model's kernel code; the K states with pairs, and for each the slot of
            its pairs in the pack (offsets, p, z, W, Tvs, weights: `measurement_kernels.state_pairs`; d2 the
            pairs' d2 out), or -1: its terms from the quadratic model of its last linearisation at T0 (its
            inverse T0_inverse[q]), varpi0[q]: H0[q], b0[q] + H0[q] d, c0[q] + b0[q]^T d + 1/2 d^T H0[q] d
            with d = [ln(T T0^-1)^vee; varpi - varpi0].
        Hm, bm, cm: (K, 12, 12), (K, 12), (K,) out: each state's measurement block and cost; for a state
            linearised afresh also T0_inverse[q], varpi0[q] (the point of that linearisation).

    Checked by: tests/estimator/test_window.py::test_compiled_normal_equations_equal_the_python_assembly
    """
    n, d = T.shape[0], tail.shape[1] + 6
    cost = _prior_terms(T[0], tail[0], mean_T_inverse, mean_tail, info, grad, H, b)
    if n > 1:
        cost += _motion_terms(ca, order, noise, Qc, T, tail, t, motion_info, H, b)
    dq = np.empty(12)
    measured = 0.0
    for q in range(len(ks)):
        k = ks[q]
        s = slot[q]
        if s >= 0:
            Hm[q] = 0.0
            bm[q] = 0.0
            cm[q] = state_pairs(model, T[k], tail[k, :6], offsets[s], offsets[s + 1], p, z, W, Tvs[s], weights,
                                d2, robust_c, Hm[q], bm[q])
            C = T[k, :3, :3]  # T0^-1 = [C^T, -C^T r]
            for i in range(3):
                for j in range(3):
                    T0_inverse[q, i, j] = C[j, i]
                T0_inverse[q, i, 3] = -(C[0, i] * T[k, 0, 3] + C[1, i] * T[k, 1, 3] + C[2, i] * T[k, 2, 3])
                T0_inverse[q, 3, i] = 0.0
            T0_inverse[q, 3, 3] = 1.0
            varpi0[q] = tail[k, :6]
        else:
            _log_from(T[k], T0_inverse[q], dq[:6])
            for i in range(6):
                dq[6 + i] = tail[k, i] - varpi0[q, i]
            c = c0[q]
            for i in range(12):
                s_ = 0.0
                for j in range(12):
                    s_ += H0[q, i, j] * dq[j]
                Hm[q, i] = H0[q, i]
                bm[q, i] = b0[q, i] + s_
                c += dq[i] * (b0[q, i] + 0.5 * s_)
            cm[q] = c
        measured += cm[q]
    cost += measured
    cost += add_blocks(H, b, d, rate_info, rate_on, tail, ks, Hm, bm)
    return cost


@njit(cache=True, error_model="numpy")
def gauss_newton(ca, order, noise, Qc, T, tail, t, mean_T_inverse, mean_tail, info, grad, motion_info, rate_info,
                 rate_on, model, ks, slot, offsets, p, z, W, Tvs, weights, robust_c, d2, T0_inverse, varpi0, H0, b0,
                 c0, relinearize, iterations, tol, sigma_tol, check_last, T_out, tail_out, H, b, L, Hm, bm, cm, result,
                 marginal, Lam, g):
    """`SlidingWindow.optimize`'s Gauss-Newton loop in one call, from the window's states T, tail (n, ...) and the
    first linearisation's arguments (those of `normal_equations` up to c0).

    The first linearisation's measurement blocks go to Hm, bm, cm (and T0_inverse, varpi0 for the states it
    linearised afresh), for the window's lag bookkeeping. Each later one takes the older states' measurement terms
    from the quadratic models of their last linearisation (the first, or the window's kept one where the first
    lagged them; all afresh with `relinearize`), the newest state's afresh from the same pack, its weights as the
    first left them (a copy when the older states lag: the Python loop packs the newest set alone then). Each
    step solves H d = -b by Cholesky (`np.linalg.cholesky`, LAPACK's potrf; it raises LinAlgError when H is not
    positive definite, and the caller falls back to the Python loop with its jitter) and the two triangular
    systems. Out: the states T_out, tail_out; H, b of the last accepted linearisation; L the factor of the last
    step's H; result = [iterations, cost, step, 1 if L is H's factor else 0]; with `marginal` (and n > 1) the
    Schur complement of the oldest state at the states out (`_marginal`), Lam and g (its Cholesky raising too,
    so that the caller redoes the whole solve in Python).

    Checked by: tests/estimator/test_window_solve.py::test_compiled_gauss_newton_equals_the_python_loop,
        ::test_the_solve_s_schur_complement_is_the_marginalisation_s
    """
    n, d = T.shape[0], tail.shape[1] + 6
    K = len(ks)
    H[:] = 0.0
    b[:] = 0.0
    cost = normal_equations(ca, order, noise, Qc, T, tail, t, mean_T_inverse, mean_tail, info, grad, motion_info,
                            rate_info, rate_on, model, ks, slot, offsets, p, z, W, Tvs, weights, robust_c, d2,
                            T0_inverse, varpi0, H0, b0, c0, H, b, Hm, bm, cm)
    later = slot.copy()  # the later linearisations' plan: the older states' terms lag, the newest's afresh
    T0l, v0l, H0l, b0l, c0l = T0_inverse.copy(), varpi0.copy(), H0.copy(), b0.copy(), c0.copy()
    for q in range(K):
        if slot[q] >= 0:
            H0l[q] = Hm[q]
            b0l[q] = bm[q]
            c0l[q] = cm[q]
            if not relinearize and ks[q] != n - 1:
                later[q] = -1
    w_later = weights if relinearize else np.empty_like(weights)
    Hm2, bm2, cm2 = np.empty_like(Hm), np.empty_like(bm), np.empty_like(cm)
    H2, b2, delta, xi = np.empty_like(H), np.empty_like(b), np.empty_like(b), np.empty((n, 6))
    T_try, tail_try = np.empty_like(T), np.empty_like(tail)
    T_out[:] = T
    tail_out[:] = tail
    step, it, factored = 1.0, 0, False
    for it in range(1, iterations + 1):
        L[:] = np.linalg.cholesky(H)
        factored = True
        size = _cholesky_solve(L, b, delta)
        if not np.isfinite(size):
            break
        s = 0.0
        for i in range(len(b)):
            s -= delta[i] * b[i]
        full = step == 1.0 and (size < tol or s < sigma_tol * sigma_tol)
        scale = 1.0 if full else step
        for k in range(n):
            for i in range(6):
                xi[k, i] = scale * delta[k * d + i]
            for i in range(d - 6):
                tail_try[k, i] = tail_out[k, i] + scale * delta[k * d + 6 + i]
        exp_times(xi, T_out, T_try)
        if full or (it == iterations and not check_last):
            T_out[:] = T_try
            tail_out[:] = tail_try
            break
        H2[:] = 0.0
        b2[:] = 0.0
        if not relinearize:
            w_later[:] = weights
        cost2 = normal_equations(ca, order, noise, Qc, T_try, tail_try, t, mean_T_inverse, mean_tail, info, grad,
                                 motion_info, rate_info, rate_on, model, ks, later, offsets, p, z, W, Tvs, w_later,
                                 robust_c, d2, T0l, v0l, H0l, b0l, c0l, H2, b2, Hm2, bm2, cm2)
        if np.isfinite(cost2) and cost2 <= cost * (1 + 1e-12) + 1e-12:
            H[:] = H2
            b[:] = b2
            cost = cost2
            T_out[:] = T_try
            tail_out[:] = tail_try
            factored = False
            if step * size < tol:
                break
            step = 1.0
        else:
            step *= 0.5
            if step < 1e-3:
                break
    result[0], result[1], result[2], result[3] = it, cost, step, 1.0 if factored else 0.0
    if marginal and n > 1:  # the oldest state's terms: lagged (so no weights read), or afresh with the pack's
        on = np.zeros(2, np.bool_)
        on[0] = rate_on[0]
        first = 1 if K > 0 and ks[0] == 0 else 0
        _marginal(ca, order, noise, Qc, T_out[:2], tail_out[:2], t[:2], mean_T_inverse, mean_tail, info, grad,
                  motion_info[:1], rate_info[:2], on, model, ks[:first], later[:first], offsets, p, z, W, Tvs,
                  w_later, robust_c, d2, T0l[:first], v0l[:first], H0l[:first], b0l[:first], c0l[:first], Lam, g)


@njit(cache=True, error_model="numpy")
def _marginal(ca, order, noise, Qc, T, tail, t, mean_T_inverse, mean_tail, info, grad, motion_info, rate_info,
              rate_on, model, ks, slot, offsets, p, z, W, Tvs, weights, robust_c, d2, T0_inverse, varpi0, H0, b0, c0,
              Lam, g):
    """The Schur complement of the oldest of two states (`SlidingWindow.marginalize_oldest`): their normal
    equations with the oldest state's terms only (the arguments of `normal_equations` for them), then
    Lam = H11 - H10 H00^-1 H01 and g = b1 - H10 H00^-1 b0 (H00 by Cholesky; LinAlgError if not positive
    definite).

    Checked by: tests/estimator/test_window_solve.py::test_the_solve_s_schur_complement_is_the_marginalisation_s
    """
    d = tail.shape[1] + 6
    H, b = np.zeros((2 * d, 2 * d)), np.zeros(2 * d)
    K = len(ks)
    normal_equations(ca, order, noise, Qc, T, tail, t, mean_T_inverse, mean_tail, info, grad, motion_info, rate_info,
                     rate_on, model, ks, slot, offsets, p, z, W, Tvs, weights, robust_c, d2, T0_inverse, varpi0, H0,
                     b0, c0, H, b, np.empty((K, 12, 12)), np.empty((K, 12)), np.empty(K))
    L0 = np.linalg.cholesky(H[:d, :d].copy())
    X, col, x = np.empty((d, d + 1)), np.empty(d), np.empty(d)
    for j in range(d + 1):  # X = H00^-1 [H01, b0], a column at a time (`_cholesky_solve` returns -H^-1 rhs)
        for i in range(d):
            col[i] = -(H[i, d + j] if j < d else b[i])
        _cholesky_solve(L0, col, x)
        X[:, j] = x
    for i in range(d):
        s = 0.0
        for k in range(d):
            s += H[k, d + i] * X[k, d]
        g[i] = b[d + i] - s
        for j in range(d):
            s = 0.0
            for k in range(d):
                s += H[k, d + i] * X[k, j]
            Lam[i, j] = H[d + i, d + j] - s


@njit(cache=True, error_model="numpy")
def _cholesky_solve(L, b, x):
    """x = -(L L^T)^-1 b (L lower triangular); returns max |x_i| (NaN if x holds one)."""
    N = len(b)
    for i in range(N):
        s = -b[i]
        for j in range(i):
            s -= L[i, j] * x[j]
        x[i] = s / L[i, i]
    for i in range(N - 1, -1, -1):
        x[i] /= L[i, i]
        v = x[i]
        for j in range(i):
            x[j] -= L[i, j] * v
    size = 0.0
    for i in range(N):
        a = abs(x[i])
        if a != a:
            return a
        size = max(size, a)
    return size
