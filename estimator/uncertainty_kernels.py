"""Compiled per-scan uncertainty of `RadarOdometry`: the scan's relative pose covariance and its revision
(`uncertainty.relative_pose_covariance`, `uncertainty.revision_covariance`) in one call, one step of the
drift recursion (`uncertainty._step`, which `DriftCovariance.update` runs through `drift_step`), with the heading's
reversion where it is on, and the scan's pull on its solved pose (`pose_pull`; its NumPy reference is in the
tests: about 0.1 ms a scan in NumPy, 40 us compiled).

The readable references stay in `uncertainty` (the validation's replays use them); these equal them to rounding:
they sum in their own order and skip the zero blocks. They feed only the reported covariances (P_relative,
P_revision, P_pose_absolute), never the estimate. Why compiled: the references take about 100 and 90 us a call
(a few dozen small NumPy calls each), these 6 and 5 us, on a scan of 4-5 ms (docs/estimator.md, "Speed").

Checked by: tests/estimator/test_uncertainty_kernels.py
"""

from __future__ import annotations

import numpy as np

from .jit import njit


@njit(cache=True)
def relative_adjoint(T_prev, T_new, Ad):
    """Ad (6, 6) out = Ad(R) of R = T_new T_prev^-1 (`se3.adjoint`: [[C, r^ C], [0, C]]); returns |r|, the
    distance between the two poses."""
    C = np.empty((3, 3))
    r = np.empty(3)
    for i in range(3):
        for j in range(3):
            C[i, j] = T_new[i, 0] * T_prev[j, 0] + T_new[i, 1] * T_prev[j, 1] + T_new[i, 2] * T_prev[j, 2]
    for i in range(3):
        r[i] = T_new[i, 3] - (C[i, 0] * T_prev[0, 3] + C[i, 1] * T_prev[1, 3] + C[i, 2] * T_prev[2, 3])
    for i in range(3):
        for j in range(3):
            Ad[i, j] = C[i, j]
            Ad[3 + i, 3 + j] = C[i, j]
            Ad[3 + i, j] = 0.0
    for j in range(3):  # r^ C, r^ = [[0, -r2, r1], [r2, 0, -r0], [-r1, r0, 0]]
        Ad[0, 3 + j] = r[1] * C[2, j] - r[2] * C[1, j]
        Ad[1, 3 + j] = r[2] * C[0, j] - r[0] * C[2, j]
        Ad[2, 3 + j] = r[0] * C[1, j] - r[1] * C[0, j]
    return np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])


@njit(cache=True)
def _sandwich(A, B, out):
    """out = A B A^T, symmetrised, for (m, m) A and B."""
    m = A.shape[0]
    AB = np.zeros((m, m))
    for i in range(m):
        for k in range(m):
            a = A[i, k]
            if a != 0.0:
                for j in range(m):
                    AB[i, j] += a * B[k, j]
    for i in range(m):
        for j in range(i, m):
            s = 0.0
            for k in range(m):
                s += AB[i, k] * A[j, k]
            out[i, j] = s
    for i in range(m):
        for j in range(i + 1, m):
            out[j, i] = out[i, j]


@njit(cache=True)
def relative_covariances(P_pair, P_emitted, T_prev, T_new, dim, solved, rel, rev):
    """The scan's relative pose covariance rel (6, 6) out and its revision rev (6, 6) out (zeros unless solved)
    from the window's joint covariance P_pair (2 dim, 2 dim) of its two newest states and the previous state's
    covariance P_emitted as emitted (>= (6, 6), pose first): `uncertainty.relative_pose_covariance` and
    `uncertainty.revision_covariance`."""
    Ad = np.empty((6, 6))
    relative_adjoint(T_prev, T_new, Ad)
    S = np.empty((6, 6))
    _sandwich(Ad, P_pair[:6, :6], S)
    # rel = Ad B11 Ad^T - Ad B12 - (Ad B12)^T + B22 with A = [-Ad, I] on the pose blocks
    AB12 = np.empty((6, 6))
    for i in range(6):
        for j in range(6):
            s = 0.0
            for k in range(6):
                s += Ad[i, k] * P_pair[k, dim + j]
            AB12[i, j] = s
    for i in range(6):
        for j in range(6):
            S[i, j] += P_pair[dim + i, dim + j] - AB12[i, j] - AB12[j, i]
    for i in range(6):
        for j in range(6):
            rel[i, j] = 0.5 * (S[i, j] + S[j, i])
    rev[:, :] = 0.0
    if not solved:
        return
    D = np.empty((6, 6))
    for i in range(6):
        for j in range(6):
            D[i, j] = 0.5 * ((P_emitted[i, j] - P_pair[i, j]) + (P_emitted[j, i] - P_pair[j, i]))
    w, V = np.linalg.eigh(D)
    M = np.zeros((6, 6))
    for k in range(6):
        if w[k] > 0.0:
            for i in range(6):
                c = V[i, k] * w[k]
                for j in range(6):
                    M[i, j] += c * V[j, k]
    _sandwich(Ad, M, rev)


@njit(cache=True)
def drift_step(C, T_prev, T_new, dt, Sigma_rel, P_varpi, tau, reversion, out):
    """One scan of the drift recursion over C = Cov([xi; b; beta]) (18, 18) into out (18, 18): A C A^T + Q,
    symmetrised (`uncertainty._step`); over Cov([xi; b; beta; a]) (19, 19) the heading's reversion comes first,
    `reversion` (4,) its coefficients on (yaw, a) (`heading_reversion.reversion_coefficients`; unused at 18)."""
    n = C.shape[0]
    if n > 18:
        M = np.eye(n)
        M[5, 5], M[5, 18], M[18, 5], M[18, 18] = reversion[0], reversion[1], reversion[2], reversion[3]
        reverted = np.empty((n, n))
        _sandwich(M, C, reverted)
        C = reverted
    phi = np.exp(-dt / tau) if tau > 0 else 0.0
    A = np.zeros((n, n))
    if n > 18:
        A[18, 18] = 1.0  # the anchor is carried as it is
    Ad = np.empty((6, 6))
    s = relative_adjoint(T_prev, T_new, Ad)
    for i in range(6):
        for j in range(6):
            A[i, j] = Ad[i, j]
        A[i, 6 + i] = dt * phi
        A[6 + i, 6 + i] = phi
        A[i, 12 + i] = s
        A[12 + i, 12 + i] = 1.0
    _sandwich(A, C, out)
    if tau > 0:
        g = 1.0 - phi * phi
        for i in range(6):
            for j in range(6):
                W = g * 0.5 * (P_varpi[i, j] + P_varpi[j, i])
                out[i, j] += dt * dt * W
                out[i, 6 + j] += dt * W
                out[6 + i, j] += dt * W
                out[6 + i, 6 + j] += W
    for i in range(6):
        for j in range(6):
            out[i, j] += 0.5 * (Sigma_rel[i, j] + Sigma_rel[j, i])


@njit(cache=True)
def pull_quadratic(T_world_sensor, points_sensor, map_points, covariances, variance):
    """g^T H^-1 g of the pairs (`pose_pull`: H = sum J_i^T C_i^-1 J_i, g = sum J_i^T C_i^-1 (p_i - m_i), p_i the
    detection placed in the world, J_i = [I, -[p_i - c]x], c the sensor's position, C_i covariances[i] + variance
    I, inverted by its cofactors); NaN where a C_i or H is not positive definite."""
    H = np.zeros((6, 6))
    g = np.zeros(6)
    if not _pull_sums(T_world_sensor, points_sensor, map_points, covariances, variance, H, g):
        return np.nan
    for j in range(6):  # H = L L^T in place (lower triangle), then |L^-1 g|^2
        for k in range(j + 1):
            s = H[j, k]
            for m in range(k):
                s -= H[j, m] * H[k, m]
            if j == k:
                if not s > 0.0:
                    return np.nan
                H[j, j] = np.sqrt(s)
            else:
                H[j, k] = s / H[k, k]
    total = 0.0
    for j in range(6):
        s = g[j]
        for m in range(j):
            s -= H[j, m] * g[m]
        g[j] = s / H[j, j]
        total += g[j] * g[j]
    return total


@njit(cache=True)
def _pull_sums(T_world_sensor, points_sensor, map_points, covariances, variance, H, g):
    """H and g of `pull_quadratic` accumulated into H (6, 6) and g (6,); False where a C_i is not positive
    definite."""
    J = np.zeros((3, 6))
    Ci = np.empty((3, 3))
    CiJ = np.empty((3, 6))
    q = np.empty(3)
    e = np.empty(3)
    for i in range(3):
        J[i, i] = 1.0
    for n in range(points_sensor.shape[0]):
        C = covariances[n]
        c00, c11, c22 = C[0, 0] + variance, C[1, 1] + variance, C[2, 2] + variance
        Ci[0, 0] = c11 * c22 - C[1, 2] * C[2, 1]
        Ci[0, 1] = C[0, 2] * C[2, 1] - C[0, 1] * c22
        Ci[0, 2] = C[0, 1] * C[1, 2] - C[0, 2] * c11
        Ci[1, 1] = c00 * c22 - C[0, 2] * C[2, 0]
        Ci[1, 2] = C[0, 2] * C[1, 0] - c00 * C[1, 2]
        Ci[2, 2] = c00 * c11 - C[0, 1] * C[1, 0]
        det = (c00 * Ci[0, 0] + C[0, 1] * (C[1, 2] * C[2, 0] - C[1, 0] * c22)
               + C[0, 2] * (C[1, 0] * C[2, 1] - c11 * C[2, 0]))
        if not (c00 > 0.0 and Ci[2, 2] > 0.0 and det > 0.0):  # the leading minors (Sylvester)
            return False
        for a in range(3):
            for b in range(a, 3):
                Ci[a, b] /= det
                Ci[b, a] = Ci[a, b]
        for a in range(3):  # q = R p (the detection relative to the sensor, in world axes)
            q[a] = (T_world_sensor[a, 0] * points_sensor[n, 0] + T_world_sensor[a, 1] * points_sensor[n, 1]
                    + T_world_sensor[a, 2] * points_sensor[n, 2])
            e[a] = q[a] + T_world_sensor[a, 3] - map_points[n, a]
        J[0, 4], J[0, 5] = q[2], -q[1]  # -[q]x
        J[1, 3], J[1, 5] = -q[2], q[0]
        J[2, 3], J[2, 4] = q[1], -q[0]
        for a in range(3):
            for k in range(6):
                CiJ[a, k] = Ci[a, 0] * J[0, k] + Ci[a, 1] * J[1, k] + Ci[a, 2] * J[2, k]
        for j in range(6):
            g[j] += CiJ[0, j] * e[0] + CiJ[1, j] * e[1] + CiJ[2, j] * e[2]
            for k in range(j, 6):
                H[j, k] += J[0, j] * CiJ[0, k] + J[1, j] * CiJ[1, k] + J[2, j] * CiJ[2, k]
    for j in range(6):
        for k in range(j):
            H[j, k] = H[k, j]
    return True
