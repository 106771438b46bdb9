"""The association's per-map-point preparation, compiled (the per-scan hot path): each map point's prediction,
innovation covariance S and its inverse, the pair's information (R + map term)^-1 (the inverse of the pair's
covariance without the state's part) and the search radius (`prepare`, for
`scan_association.MapAssociation.associate`); the chosen pairs' information at the re-association's state
(`pair_information`, for `MapAssociation.reassociate`). Both go in blocks of points held in rows, through the same
passes.

Checked by: tests/estimator/test_scan_association.py::test_prepared_association_equals_the_reference,
    ::test_preparation_reports_a_point_at_the_sensor_and_an_s_not_positive_definite,
    ::test_preparation_marks_a_pair_covariance_not_positive_definite_with_nan,
    ::test_reassociation_rescores_the_candidates_at_the_new_state
"""

from __future__ import annotations

import math

import numpy as np

from .association_kernels import lambda_max_upper, sensor_from_world
from .jit import njit
from .measurement_kernels import frame_values, frames, geometry_rows, polar_jacobian, predicted_z

BLOCK = 64  # map points per block of `prepare`: its scratch rows stay in the L1 cache


@njit(cache=True, error_model="numpy")
def prepare(polar, T, varpi, p_world, cov_world, rows, map_var, P, R, Tvs, gate, z, p_s, S, S_inv, W_pair, radius):
    """Everything the association needs per map point (the same model as `measurements.predict`,
    `association.innovation_covariance` and `association._search_radius`):

    for the m map points p_world[rows], cov_world[rows] (rows (m,) indices into the map's arrays):
    z (m, 4) predicted measurement, p_s (m, 3) sensor-frame position,
    S = G P G^T + R + J_z_p (cov_world_j + map_var I) J_z_p^T and S_inv (m, 4, 4),
    W_pair = S_pair^-1 (m, 4, 4), S_pair = R + J_z_p (cov_world_j + map_var I) J_z_p^T: the pair's information
    in the solve, NaN where S_pair is not positive definite (an error only for a point that is paired),
    radius (m,) the search radius that holds every detection with d2 <= gate.
    Returns -1 when all is well, else the index of the first point at the sensor origin (range < 1e-9) or
    with an S that is not positive definite (then m + index).

    G = dz/d[xi, varpi] has zeros in the velocity columns of its position rows, so G P G^T is formed from the
    pose block of P for all rows and the velocity blocks for row 3 only.

    The points go in blocks of BLOCK, each pass over a block a loop over its points with their quantities in
    rows, so that the passes without a transcendental function compile to SIMD code over the points. IEEE
    arithmetic, each quantity summed in the order a point at a time sums it: the results are those of a point
    at a time, bit for bit.

    Checked by: tests/estimator/test_scan_association.py::test_prepared_association_equals_the_reference,
        ::test_preparation_reports_a_point_at_the_sensor_and_an_s_not_positive_definite,
        ::test_preparation_marks_a_pair_covariance_not_positive_definite_with_nan
    """
    m = rows.shape[0]
    C, _, Cvs, _, _, _ = frames(T, varpi, Tvs)
    F = frame_values(T, varpi, Tvs)
    B = sensor_from_world(Cvs, C)  # dp_s/dp_world
    C, P, R = C.copy(), np.ascontiguousarray(P).copy(), R.copy()  # local: the passes need not check for overlaps
    X, G, Y = np.empty((12, BLOCK)), np.empty((30, BLOCK)), np.empty((20, BLOCK))  # `_block_geometry`'s rows
    Q = np.empty((42, BLOCK))  # upper triangles of S_pair, S, S^-1 (10 each), S pos. def., S_pair^-1, S_pair p.d.
    Z, Lr = np.empty((69, BLOCK)), np.empty((20, BLOCK))  # the passes' rows
    for s in range(0, m, BLOCK):
        n = min(BLOCK, m - s)
        _block_geometry(polar, F, p_world, cov_world, rows, s, n, X, G, Y)
        _pair_rows(Y, X, n, B, C, map_var, R, Z, Q)
        _innovation_rows(G, n, P, Z, Q)
        for i in range(n):
            _inv_spd4_rows(Q, 10, 20, 30, i, Lr)
            _inv_spd4_rows(Q, 0, 31, 41, i, Lr)
        _radius_blocks(polar, Y, Q, n, gate, Z)
        for i in range(n):  # outputs, the search radius (scalar: its eigenvalue's trigonometry)
            a = s + i
            if Y[3, i] < 1e-9:
                return a
            if Q[30, i] == 0.0:
                return m + a
            r = Y[3, i]
            for k in range(3):
                p_s[a, k] = Y[k, i]
            predicted_z(polar, Y[0, i], Y[1, i], Y[2, i], r, Y[4, i], z[a])
            q = 0
            for u in range(4):
                for v in range(u, 4):
                    w = Q[31 + q, i] if Q[41, i] == 1.0 else np.nan
                    W_pair[a, u, v], W_pair[a, v, u] = w, w
                    S[a, u, v], S[a, v, u] = Q[10 + q, i], Q[10 + q, i]
                    S_inv[a, u, v], S_inv[a, v, u] = Q[20 + q, i], Q[20 + q, i]
                    q += 1
            lam = lambda_max_upper(Z[0, i], Z[1, i], Z[2, i], Z[3, i], Z[4, i], Z[5, i])
            radius[a] = math.sqrt(gate * max(lam, 0.0) * Z[6, i]) * (1.0 + 1e-9)
    return -1


@njit(cache=True, error_model="numpy")
def pair_information(polar, T, varpi, p_world, cov_world, rows, map_var, R, Tvs, W):
    """W[q] = (R + map term)^-1 of the map point p_world[rows[q]], cov_world[rows[q]] at the state (T, varpi):
    each associated pair's information in the solve, as `prepare` gives it (bit for bit: the same passes), for
    the pairs of a re-association (`association_kernels.rescore`). Returns -1, or q for the first point at the
    sensor origin, or len(rows) + q for the first whose R + map term is not positive definite.

    Checked by: tests/estimator/test_scan_association.py::test_reassociation_rescores_the_candidates_at_the_new_state,
        ::test_preparation_reports_a_point_at_the_sensor_and_an_s_not_positive_definite
    """
    m = rows.shape[0]
    C, _, Cvs, _, _, _ = frames(T, varpi, Tvs)
    F = frame_values(T, varpi, Tvs)
    B = sensor_from_world(Cvs, C)
    C, R = C.copy(), R.copy()
    X, G, Y = np.empty((12, BLOCK)), np.empty((30, BLOCK)), np.empty((20, BLOCK))
    Q, Z, Lr = np.empty((21, BLOCK)), np.empty((33, BLOCK)), np.empty((20, BLOCK))
    for s in range(0, m, BLOCK):
        n = min(BLOCK, m - s)
        _block_geometry(polar, F, p_world, cov_world, rows, s, n, X, G, Y)
        _pair_rows(Y, X, n, B, C, map_var, R, Z, Q)
        for i in range(n):
            _inv_spd4_rows(Q, 0, 10, 20, i, Lr)
        for i in range(n):
            if Y[3, i] < 1e-9:
                return s + i
            if Q[20, i] == 0.0:
                return m + s + i
            q = 0
            for u in range(4):
                for v in range(u, 4):
                    W[s + i, u, v], W[s + i, v, u] = Q[10 + q, i], Q[10 + q, i]
                    q += 1
    return -1


@njit(cache=True, inline="always")
def _block_geometry(polar, F, p_world, cov_world, rows, s, n, X, G, Y):
    """Points rows[s:s + n] of a block: their positions and covariances gathered into X (p (3), cov (9)), and
    `geometry_rows` of them into G and Y (with the point Jacobian), F the state's `frame_values`."""
    for i in range(n):
        row = rows[s + i]
        X[0, i], X[1, i], X[2, i] = p_world[row, 0], p_world[row, 1], p_world[row, 2]
        for k in range(9):
            X[3 + k, i] = cov_world[row, k // 3, k % 3]
    geometry_rows(polar, F, X, n, G, Y, True)


@njit(cache=True, inline="always")
def _pair_rows(Y, X, n, B, C, map_var, R, Z, Q):
    """Points 0:n of a block: S_pair = R + J_z_p (cov + map_var I) J_z_p^T, J_z_p = [Js; a^T] B + [0; m^T C]
    (B = C_vs^T C, C the pose's rotation), its upper triangle row by row into Q[0:10]. Z's rows hold J_z_p
    (0-11), cov + map_var I (12-20) and J_z_p times it (21-32). One loop over the points per step, each reading
    few arrays (so that the compiler's checks that they do not overlap stay few enough for it to vectorise)."""
    for i in range(n):
        for j in range(3):
            for u in range(3):
                Z[3 * u + j, i] = Y[5 + 3 * u, i] * B[0, j] + Y[6 + 3 * u, i] * B[1, j] + Y[7 + 3 * u, i] * B[2, j]
            Z[9 + j, i] = Y[14, i] * B[0, j] + Y[15, i] * B[1, j] + Y[16, i] * B[2, j] \
                + Y[17, i] * C[0, j] + Y[18, i] * C[1, j] + Y[19, i] * C[2, j]
    for i in range(n):
        for u in range(3):
            for j in range(3):
                Z[12 + 3 * u + j, i] = X[3 + 3 * u + j, i] + map_var if u == j else X[3 + 3 * u + j, i]
    for i in range(n):
        for u in range(4):
            for j in range(3):
                Z[21 + 3 * u + j, i] = (Z[3 * u, i] * Z[12 + j, i] + Z[3 * u + 1, i] * Z[15 + j, i]
                                        + Z[3 * u + 2, i] * Z[18 + j, i])
    for i in range(n):
        q = 0
        for u in range(4):
            for v in range(u, 4):
                Q[q, i] = R[u, v] + Z[21 + 3 * u, i] * Z[3 * v, i] + Z[22 + 3 * u, i] * Z[3 * v + 1, i] \
                    + Z[23 + 3 * u, i] * Z[3 * v + 2, i]
                q += 1


@njit(cache=True, inline="always")
def _innovation_rows(G, n, P, Z, Q):
    """Points 0:n of a block: S = S_pair + G P G^T (S_pair in Q[0:10]) into Q[10:20], upper triangles row by
    row, each entry summed in the order of a point at a time (the pose block of P for every row of G, the
    velocity blocks for its Doppler row). Z's rows hold G P (33-56) and P[:, 6:] g_v (57-68), g_v = G[3, 6:]."""
    for i in range(n):
        for u in range(4):
            for j in range(6):
                sm = 0.0
                for k in range(6):
                    sm += G[6 * u + k, i] * P[k, j]
                Z[33 + 6 * u + j, i] = sm
    for i in range(n):
        for j in range(12):
            sm = 0.0
            for k in range(6):
                sm += P[j, 6 + k] * G[24 + k, i]
            Z[57 + j, i] = sm
    for i in range(n):
        q = 0
        for u in range(4):
            for v in range(u, 4):
                sg = 0.0
                for k in range(6):
                    sg += Z[33 + 6 * u + k, i] * G[6 * v + k, i]
                if v == 3:  # + Gp_u P_pv g_v
                    sm = 0.0
                    for k in range(6):
                        sm += G[6 * u + k, i] * Z[57 + k, i]
                    sg += sm
                if u == 3:  # + g_v P_vp Gp_3^T + g_v P_vv g_v
                    sm, vv = 0.0, 0.0
                    for k in range(6):
                        sm += Z[57 + k, i] * G[18 + k, i]
                        vv += G[24 + k, i] * Z[63 + k, i]
                    sg += sm + vv
                Q[10 + q, i] = Q[q, i] + sg
                q += 1


_UPPER = np.array([[0, 1, 2, 3], [1, 4, 5, 6], [2, 5, 7, 8], [3, 6, 8, 9]], np.int64)  # (u, v) -> upper index


@njit(cache=True, inline="always")
def _inv_spd4_rows(Q, src, dst, ok, i, Lr):
    """The inverse of the symmetric 4x4 matrix whose upper triangle is Q[src:src + 10, i] (row by row), into
    Q[dst:dst + 10, i], by Cholesky: S = L L^T, then L^-1, then S^-1 = L^-T L^-1; Q[ok, i] = 1.0 if S is
    positive definite, else 0.0 (and the inverse is not meaningful). Lr's rows hold L's lower triangle (0-9)
    and L^-1's (10-19), entry (u, j), j <= u, in row _UPPER[j, u] (and 10 + it)."""
    good = True
    for u in range(4):
        for j in range(u + 1):
            sm = Q[src + _UPPER[j, u], i]
            for k in range(j):
                sm -= Lr[_UPPER[k, u], i] * Lr[_UPPER[k, j], i]
            if u == j:
                good = good and sm > 0.0
                Lr[_UPPER[u, u], i] = math.sqrt(sm)
            else:
                Lr[_UPPER[j, u], i] = sm / Lr[_UPPER[j, j], i]
    for u in range(4):
        Lr[10 + _UPPER[u, u], i] = 1.0 / Lr[_UPPER[u, u], i]
        for j in range(u):
            sm = 0.0
            for k in range(j, u):
                sm -= Lr[_UPPER[k, u], i] * Lr[10 + _UPPER[j, k], i]
            Lr[10 + _UPPER[j, u], i] = sm / Lr[_UPPER[u, u], i]
    for u in range(4):
        for j in range(u, 4):
            sm = 0.0
            for k in range(j, 4):
                sm += Lr[10 + _UPPER[u, k], i] * Lr[10 + _UPPER[j, k], i]
            Q[dst + _UPPER[u, j], i] = sm
    Q[ok, i] = 1.0 if good else 0.0


@njit(cache=True, inline="always")
def _radius_blocks(polar, Y, Q, n, gate, Z):
    """The position block of S in Cartesian coordinates (upper triangle) and the factor k2 of points 0:n of a
    `prepare` block, into Z[0:7] (Y: the block's ps and r, Q[10:20]: its S), for the search radius, which
    holds every detection with d2 <= gate: sqrt(gate lambda_max k2). Z[7:16] holds the polar Jacobian."""
    for i in range(n):
        if polar:
            ps0, ps1, ps2, r = Y[0, i], Y[1, i], Y[2, i], Y[3, i]
            rho = math.sqrt(ps0 * ps0 + ps1 * ps1)
            # cos and sin of the elevation and the azimuth from the position (as the predicted z); straight
            # above the sensor the azimuth is arbitrary and the elevation's cosine as small as polar_rows'
            ce, se = max(rho, 1e-12 * r) / r, ps2 / r
            ca, sa = (ps0 / rho, ps1 / rho) if rho > 0.0 else (1.0, 0.0)
            Ac = polar_jacobian(r, ca, sa, ce, se)
            for k in range(9):
                Z[7 + k, i] = Ac[k]
            q = 0
            for u in range(3):
                pc0 = Z[7 + 3 * u, i] * Q[10, i] + Z[8 + 3 * u, i] * Q[11, i] + Z[9 + 3 * u, i] * Q[12, i]
                pc1 = Z[7 + 3 * u, i] * Q[11, i] + Z[8 + 3 * u, i] * Q[14, i] + Z[9 + 3 * u, i] * Q[15, i]
                pc2 = Z[7 + 3 * u, i] * Q[12, i] + Z[8 + 3 * u, i] * Q[15, i] + Z[9 + 3 * u, i] * Q[17, i]
                for j in range(u, 3):
                    Z[q, i] = pc0 * Z[7 + 3 * j, i] + pc1 * Z[8 + 3 * j, i] + pc2 * Z[9 + 3 * j, i]
                    q += 1
            Z[6, i] = max(1.0, (r + math.sqrt(gate * Q[10, i])) / (r * ce))
        else:
            Z[0, i], Z[1, i], Z[2, i] = Q[10, i], Q[11, i], Q[12, i]
            Z[3, i], Z[4, i], Z[5, i] = Q[14, i], Q[15, i], Q[17, i]
            Z[6, i] = 1.0
