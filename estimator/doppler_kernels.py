"""Compiled Doppler RANSAC and least-squares fit (`ego_velocity.ransac_velocity`, `least_squares_velocity`):
the hypotheses from the minimal sets, their scoring, the refits and the fit's covariance, in one pass per scan.

Also the Doppler front end's per-detection gates (`thresholds`), a scan's voxels (`voxel_index`) and the
moving-group test (`moving_voxels`). The readable references are the NumPy versions these replaced, kept in the
tests (`_reference_ransac`, `_reference_moving_voxels`): the same steps, with the 2x2 and 3x3 systems solved in
closed form (Cramer's rule for a minimal set, the adjugate for the normal equations U^T U v = U^T b) instead of
LAPACK's LU and SVD, so results agree to rounding.

Checked by: tests/estimator/test_ego_velocity.py (::test_inlier_counts_equal_the_numpy_expression,
    ::test_compiled_ransac_equals_the_numpy_reference and the estimator's properties),
    tests/estimator/test_moving_groups.py (::test_compiled_moving_voxels_equal_the_numpy_reference,
    ::test_compiled_doppler_thresholds_equal_the_numpy_expressions)
"""

from __future__ import annotations

import math

import numpy as np

from .association_kernels import lambda_max_sym3
from .jit import njit

MIN_DET = 1e-6  # |det| of a minimal set of unit directions below which the set is skipped


@njit(cache=True)
def count_inliers(U, b, hyps, threshold):
    """Per hypothesis v = hyps[h] (m, dof), the number of rows i of U (n, dof) with |U[i] . v - b[i]| <=
    threshold[i] (n,): (m,) int64. Without the (n, m) temporaries of the NumPy expression."""
    counts = np.zeros(hyps.shape[0], np.int64)
    for h in range(hyps.shape[0]):
        counts[h] = _count(U, b, hyps[h], threshold)
    return counts


@njit(cache=True, inline="always")
def _residual(U, b, v, i):
    """U[i] . v - b[i]: detection i's Doppler residual under the hypothesis v, in the order `_count` sums it, so a
    hypothesis's count and its inlier mask agree to the last bit."""
    if U.shape[1] == 3:
        return U[i, 0] * v[0] + U[i, 1] * v[1] + U[i, 2] * v[2] - b[i]
    return U[i, 0] * v[0] + U[i, 1] * v[1] - b[i]


@njit(cache=True, inline="always")
def _count(U, b, v, threshold):
    """The number of detections with |`_residual`| <= threshold, with the same expression written out per dof
    (the RANSAC's hot loop: one branch outside it)."""
    n, dof = U.shape
    v0, v1 = v[0], v[1]
    v2 = v[2] if dof == 3 else 0.0
    c = 0
    if dof == 3:
        for i in range(n):
            if abs(U[i, 0] * v0 + U[i, 1] * v1 + U[i, 2] * v2 - b[i]) <= threshold[i]:
                c += 1
    else:
        for i in range(n):
            if abs(U[i, 0] * v0 + U[i, 1] * v1 - b[i]) <= threshold[i]:
                c += 1
    return c


@njit(cache=True, error_model="numpy")
def _minimal_solution(U, b, rows, out):
    """Solve U[rows] x = b[rows] (dof x dof) by Cramer's rule into out; False when |det| <= MIN_DET."""
    if U.shape[1] == 2:
        a, c = U[rows[0], 0], U[rows[0], 1]
        d, e = U[rows[1], 0], U[rows[1], 1]
        det = a * e - c * d
        if not abs(det) > MIN_DET:
            return False
        y0, y1 = b[rows[0]], b[rows[1]]
        out[0] = (y0 * e - c * y1) / det
        out[1] = (a * y1 - y0 * d) / det
        return True
    r0, r1, r2 = rows[0], rows[1], rows[2]
    c0 = U[r1, 1] * U[r2, 2] - U[r1, 2] * U[r2, 1]
    c1 = U[r1, 2] * U[r2, 0] - U[r1, 0] * U[r2, 2]
    c2 = U[r1, 0] * U[r2, 1] - U[r1, 1] * U[r2, 0]
    det = U[r0, 0] * c0 + U[r0, 1] * c1 + U[r0, 2] * c2
    if not abs(det) > MIN_DET:
        return False
    for k in range(3):  # x_k = det(A with column k replaced by b) / det, expanded along that column
        j1, j2 = (k + 1) % 3, (k + 2) % 3
        s = 0.0
        for i in range(3):
            i1, i2 = rows[(i + 1) % 3], rows[(i + 2) % 3]
            s += b[rows[i]] * (U[i1, j1] * U[i2, j2] - U[i1, j2] * U[i2, j1])
        out[k] = s / det
    return True


@njit(cache=True, error_model="numpy")
def _normal_equations(U, b, inliers, info, rhs):
    """info = U_in^T U_in, rhs = U_in^T b_in over the rows in `inliers`."""
    dof = U.shape[1]
    info[:] = 0.0
    rhs[:] = 0.0
    for i in range(U.shape[0]):
        if inliers[i]:
            for p in range(dof):
                rhs[p] += U[i, p] * b[i]
                for q in range(p + 1):
                    info[p, q] += U[i, p] * U[i, q]
    for p in range(dof):
        for q in range(p):
            info[q, p] = info[p, q]


@njit(cache=True, error_model="numpy")
def _inverse_spd(A, out):
    """out = A^-1 for a symmetric 2x2 or 3x3 A by its adjugate; its determinant (<= 0: A is not positive
    definite, out not written)."""
    if A.shape[0] == 2:
        det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
        if not det > 0.0:
            return det
        out[0, 0], out[1, 1] = A[1, 1] / det, A[0, 0] / det
        out[0, 1] = out[1, 0] = -A[0, 1] / det
        return det
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    if not det > 0.0:
        return det
    out[0, 0], out[0, 1], out[0, 2] = c00 / det, c01 / det, c02 / det
    out[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) / det
    out[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) / det
    out[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) / det
    out[1, 0], out[2, 0], out[2, 1] = out[0, 1], out[0, 2], out[1, 2]
    return det


@njit(cache=True, error_model="numpy")
def _lambda_max(A):
    """Largest eigenvalue of a symmetric 2x2 or 3x3 matrix."""
    M = np.zeros((3, 3))
    M[:A.shape[0], :A.shape[0]] = A
    return lambda_max_sym3(M)


@njit(cache=True, error_model="numpy")
def _solve_normal(U, b, inliers, v, cov, max_cond):
    """v = argmin |U_in v - b_in| by the normal equations, cov = (U_in^T U_in)^-1; False when U_in^T U_in is not
    positive definite or its condition number (lambda_max lambda_max(inverse)) is above max_cond."""
    dof = U.shape[1]
    info, rhs = np.empty((dof, dof)), np.empty(dof)
    _normal_equations(U, b, inliers, info, rhs)
    if not _inverse_spd(info, cov) > 0.0:
        return False
    if _lambda_max(info) * _lambda_max(cov) > max_cond:
        return False
    for p in range(dof):
        s = 0.0
        for q in range(dof):
            s += cov[p, q] * rhs[q]
        v[p] = s
    return True


@njit(cache=True, error_model="numpy")
def fit_velocity(U, b, inliers, variance_floor, default_variance, max_cond, v, cov):
    """`ego_velocity._fit` over the rows in `inliers`: v (dof,) and its covariance s^2 (U^T U)^-1 written,
    s^2 the residual variance (default_variance without redundancy), at least variance_floor. False when
    U^T U is singular or worse conditioned than max_cond (nothing meaningful written then)."""
    n, dof = U.shape
    if not _solve_normal(U, b, inliers, v, cov, max_cond):
        return False
    k, ss = 0, 0.0
    for i in range(n):
        if inliers[i]:
            k += 1
            ss += _residual(U, b, v, i) ** 2
    s2 = max(ss / (k - dof) if k > dof else default_variance, variance_floor)
    for p in range(dof):
        for q in range(dof):
            cov[p, q] *= s2
    return True


@njit(cache=True, error_model="numpy")
def _inliers(U, b, v, threshold, out):
    """out (n,) = |U v - b| <= threshold, as `_count` counts them; returns their number."""
    k = 0
    for i in range(U.shape[0]):
        out[i] = abs(_residual(U, b, v, i)) <= threshold[i]
        k += out[i]
    return k


@njit(cache=True, error_model="numpy")
def ransac(U, b, draws, threshold, ref, radius, sigma_vr2, v, cov, inliers):
    """`ego_velocity.ransac_velocity` from its minimal sets `draws` (k, dof) (rows of U (n, dof), b (n,)): the
    hypothesis with the most inliers |U v - b| <= threshold (ties: the closest to ref, then the first drawn;
    ref itself competes first), among those within `radius` of ref (radius inf: all), then two refits on the
    inliers, each kept only if it leaves dof inliers, and `fit_velocity` (max condition 1e12) with the noise
    variance sigma_vr2 as the default. Writes v, cov (dof, dof), inliers (n,); returns False on failure (fewer
    than dof inliers, or a degenerate fit)."""
    n, dof = U.shape
    best = ref.copy()
    best_count, best_dist = _count(U, b, ref, threshold), 0.0
    h = np.empty(dof)
    for k in range(draws.shape[0]):
        if not _minimal_solution(U, b, draws[k], h):
            continue
        d = 0.0
        for p in range(dof):
            d += (h[p] - ref[p]) ** 2
        d = math.sqrt(d)
        if d > radius:
            continue
        c = _count(U, b, h, threshold)
        if c > best_count or (c == best_count and d < best_dist):
            best[:] = h
            best_count, best_dist = c, d
    if _inliers(U, b, best, threshold, inliers) < dof:
        return False
    refit, refit_cov = np.empty(dof), np.empty((dof, dof))
    trial = np.empty(n, np.bool_)
    for _ in range(2):
        if not _solve_normal(U, b, inliers, refit, refit_cov, np.inf):
            break
        if _inliers(U, b, refit, threshold, trial) < dof:  # the refit lost the consensus: keep the one before
            break
        inliers[:] = trial
    return fit_velocity(U, b, inliers, 1e-12, sigma_vr2, 1e12, v, cov)


@njit(cache=True, error_model="numpy")
def voxel_index(p, voxel):
    """(index (n,), counts (K,)): each point's voxel (edge `voxel`) numbered 0..K-1 in the order of the voxels'
    keys (`consensus.voxel_keys`), and the points in each; np.unique(keys, return_inverse, return_counts)."""
    n = p.shape[0]
    keys = np.empty(n, np.int64)
    lim = (1 << 20) - 1
    for i in range(n):
        key = 0
        for a in range(3):
            k = min(max(int(math.floor(p[i, a] / voxel)), -(1 << 20)), lim) + (1 << 20)  # 21 bits each
            key = (key << 21) | k
        keys[i] = key
    order = np.argsort(keys)
    index = np.empty(n, np.int64)
    counts = np.zeros(n, np.int64)
    K = 0
    for q in range(n):
        if q == 0 or keys[order[q]] != keys[order[q - 1]]:
            K += 1
        index[order[q]] = K - 1
        counts[K - 1] += 1
    return index, counts[:K]


@njit(cache=True, error_model="numpy")
def moving_voxels(u, vr, var, gated, index, counts, z, margin, max_residual, min_points, planar_sin, out):
    """`consensus.moving_voxels` from the voxels (index, counts) found: out (n,) set where a voxel moves slowly
    against the world's fit (weighted by 1 / its gated detections, by the normal equations); nothing when too
    few gated detections or voxels, when that fit is degenerate, or when the flagged voxels would be half the
    gated ones or more. planar_sin: |u_z| below it on every detection fits (vx, vy) only."""
    n, K = len(vr), len(counts)
    out[:] = False
    n_gated = np.zeros(K, np.int64)
    g = 0
    for i in range(n):
        if gated[i]:
            n_gated[index[i]] += 1
            g += 1
    occupied = 0
    for c in range(K):
        occupied += n_gated[c] > 0
    if g < 2 * min_points or occupied < 4:
        return
    dof = 2
    for i in range(n):
        if not abs(u[i, 2]) < planar_sin:
            dof = 3
            break
    info, rhs = np.zeros((dof, dof)), np.zeros(dof)
    for i in range(n):
        if gated[i]:
            w2 = 1.0 / n_gated[index[i]]
            for p in range(dof):
                rhs[p] -= w2 * u[i, p] * vr[i]
                for q in range(dof):
                    info[p, q] += w2 * u[i, p] * u[i, q]
    inverse = np.empty((dof, dof))
    if not _inverse_spd(info, inverse) > 0.0:
        return
    v = inverse @ rhs
    r, s = np.zeros(K), np.zeros(K)
    for i in range(n):
        res = vr[i]
        for p in range(dof):
            res += u[i, p] * v[p]
        r[index[i]] += res
        s[index[i]] += var[i]
    flagged = np.zeros(K, np.bool_)
    any_flagged, flagged_gated = False, 0
    for c in range(K):
        rc, sd = r[c] / counts[c], math.sqrt(s[c]) / counts[c]
        flagged[c] = counts[c] >= min_points and abs(rc) > z * sd + margin and abs(rc) <= max_residual
        any_flagged |= flagged[c]
        flagged_gated += flagged[c] and n_gated[c] > 0
    if not any_flagged or 2 * flagged_gated >= occupied:
        return
    for i in range(n):
        out[i] = flagged[index[i]]


@njit(cache=True, error_model="numpy")
def thresholds(polar, ca, sa, ce, se, v, Sv, sigmas, floor, u, pts, var_fit, mask, fit_threshold):
    """`doppler.DopplerFrontEnd._thresholds` and the masks built on it, per detection (ca, sa, ce, se: cos and
    sin of its azimuth and elevation): u the unit direction, pts = u r, var_fit = sigma_vr^2 + (sigma_az v .
    du/daz)^2 + (sigma_el v . du/del)^2, mask = |v_r + u . v| <= 3 sqrt(var_fit + u^T Sv u) + floor (the
    prediction's gate), fit_threshold = 3 sqrt(var_fit) + floor."""
    for i in range(polar.shape[0]):
        u0, u1, u2 = ce[i] * ca[i], ce[i] * sa[i], se[i]
        u[i, 0], u[i, 1], u[i, 2] = u0, u1, u2
        r = polar[i, 0]
        pts[i, 0], pts[i, 1], pts[i, 2] = u0 * r, u1 * r, u2 * r
        d_az = -ce[i] * sa[i] * v[0] + ce[i] * ca[i] * v[1]
        d_el = -se[i] * ca[i] * v[0] - se[i] * sa[i] * v[1] + ce[i] * v[2]
        vf = sigmas[3] ** 2 + (sigmas[1] * d_az) ** 2 + (sigmas[2] * d_el) ** 2
        var_fit[i] = vf
        q = 0.0
        for a in range(3):
            q += (Sv[a, 0] * u0 + Sv[a, 1] * u1 + Sv[a, 2] * u2) * u[i, a]
        mask[i] = abs(polar[i, 3] + u0 * v[0] + u1 * v[1] + u2 * v[2]) <= 3.0 * math.sqrt(vf + q) + floor
        fit_threshold[i] = 3.0 * math.sqrt(vf) + floor
