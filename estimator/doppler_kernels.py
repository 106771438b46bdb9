"""Compiled inner loop of the Doppler RANSAC (`ego_velocity.estimate_ego_velocity`): scoring its hypotheses.

Checked by: tests/estimator/test_ego_velocity.py::test_inlier_counts_equal_the_numpy_expression
"""

from __future__ import annotations

import numpy as np

from .jit import njit


@njit(cache=True)
def count_inliers(U, b, hyps, threshold):
    """Per hypothesis v = hyps[h] (m, dof), the number of rows i of U (n, dof) with |U[i] . v - b[i]| <=
    threshold[i] (n,): (m,) int64. Without the (n, m) temporaries of the NumPy expression."""
    n, dof = U.shape
    counts = np.zeros(hyps.shape[0], np.int64)
    for h in range(hyps.shape[0]):
        v0, v1 = hyps[h, 0], hyps[h, 1]
        v2 = hyps[h, 2] if dof == 3 else 0.0
        c = 0
        if dof == 3:
            for i in range(n):
                if abs(U[i, 0] * v0 + U[i, 1] * v1 + U[i, 2] * v2 - b[i]) <= threshold[i]:
                    c += 1
        else:
            for i in range(n):
                if abs(U[i, 0] * v0 + U[i, 1] * v1 - b[i]) <= threshold[i]:
                    c += 1
        counts[h] = c
    return counts
