"""Dense symmetric positive-definite algebra of the sliding window (`estimator.window`): its solves, the trailing
block of an inverse from a Cholesky factor (the newest states' covariances), and inverses of noise covariances.
LAPACK through scipy: at the window's sizes (up to 90 x 90) faster than NumPy's general solvers.

Checked by: tests/estimator/test_window.py
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.linalg as sla


def solve_spd(H: np.ndarray, rhs: np.ndarray, factor: bool = False):
    """Solve H x = rhs for symmetric positive (semi-)definite H (LAPACK dposv; the fastest here for the
    window's sizes), with a tiny relative jitter if the Cholesky factorisation fails. With factor, returns
    (x, the factor of H as dposv leaves it, its lower triangle L with H = L L^T; None when H needed the jitter
    or the least-squares fallback)."""
    jitter = 0.0
    for _ in range(6):
        c, x, info = sla.lapack.dposv(H + jitter * np.eye(len(H)) if jitter else H, rhs, lower=1)
        if info == 0:
            return (x, c if jitter == 0.0 else None) if factor else x
        jitter = max(np.max(np.abs(np.diag(H))), 1e-300) * 1e-12 if jitter == 0 else jitter * 100
    x = np.linalg.lstsq(H, rhs, rcond=None)[0]
    return (x, None) if factor else x


def trailing_inverse(H: np.ndarray, k: int, factor: np.ndarray | None = None) -> np.ndarray:
    """The trailing k x k block of H^-1 (H symmetric positive definite), from the trailing block of its Cholesky
    factor: with H = L L^T, H^-1 = L^-T L^-1 and L^-1 lower triangular, so (H^-1)_BB = (L_BB L_BB^T)^-1 for the
    last block B (LAPACK dpotri on L_BB). factor: H's factor if known (`solve_spd`), else H is factored here.
    Falls back to solving for the block's columns when H is not numerically positive definite.

    Checked by: tests/estimator/test_window.py::test_trailing_inverse_is_the_block_of_the_inverse
    """
    if factor is None:
        c, info = sla.lapack.dpotrf(H, lower=1)
        factor = c if info == 0 else None
    if factor is not None:
        X, info = sla.lapack.dpotri(factor[-k:, -k:], lower=1)
        if info == 0:
            upper, lower = _triangles(k)
            X[upper] = X[lower]  # dpotri leaves the lower triangle
            return X
    E = np.zeros((len(H), k))
    E[-k:, :] = np.eye(k)
    X = solve_spd(H, E)[-k:, :]
    return 0.5 * (X + X.T)


@functools.lru_cache(maxsize=8)
def _triangles(k: int) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """The indices of the strict upper triangle of a k x k matrix and of its mirror image in the lower one."""
    i, j = np.triu_indices(k, 1)
    return (i, j), (j, i)


def inv_spd(P: np.ndarray) -> np.ndarray:
    W = solve_spd(P, np.eye(len(P)))
    return 0.5 * (W + W.T)
