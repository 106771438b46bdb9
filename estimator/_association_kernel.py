"""Compiled inner loops of the association (the per-scan hot path): Mahalanobis distances of candidate pairs
and the greedy one-to-one selection. `association.associate` is the public entry and documents the method.

Checked by: tests/estimator/test_association.py (greedy against an all-pairs loop; gate statistics)
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def pair_d2(polar, j, i, z_meas, z_pred, S_inv):
    """d2_k = e^T S_j^-1 e for candidate pairs (j[k], i[k]), e = z_meas[i] - z_pred[j] (azimuth wrapped)."""
    out = np.empty(len(j))
    e = np.empty(4)
    for k in range(len(j)):
        a, b = j[k], i[k]
        for c in range(4):
            e[c] = z_meas[b, c] - z_pred[a, c]
        if polar:
            e[1] = e[1] - 2.0 * math.pi * math.floor((e[1] + math.pi) / (2.0 * math.pi))
        s = 0.0
        for r in range(4):
            t = 0.0
            for c in range(4):
                t += S_inv[a, r, c] * e[c]
            s += e[r] * t
        out[k] = s
    return out


@njit(cache=True)
def greedy_one_to_one(order, j, i, m, n):
    """Walk the pairs in `order` (ascending d2, ties by j then i) and take each whose map point and detection
    are both still free: the global greedy matching by smallest d2."""
    used_j = np.zeros(m, dtype=np.bool_)
    used_i = np.zeros(n, dtype=np.bool_)
    chosen = np.zeros(len(j), dtype=np.bool_)
    for k in order:
        if not used_j[j[k]] and not used_i[i[k]]:
            used_j[j[k]] = True
            used_i[i[k]] = True
            chosen[k] = True
    return chosen
