"""The compiled loops of the radar model (`sim.radar`): the pre-selection and the samples of the culling
(`sim.culling`), the occlusion and the gates (`sim.occlusion`), the noise and the order of the detections: what
numpy did in a few dozen calls per scan, each loop in one pass, with numpy's arithmetic element for element, so
that the simulator's output stays bit for bit what it was.

How the bits are kept: no fast-math (numba's default: no contraction into fused multiply-adds, no
reassociation); every product, sum and quotient in the order numpy evaluated it; 3-vector dot products in the
order of numpy's einsum("ij,ij->i") (`dot3`); transcendental functions (arctan2, arcsin, cos, sin) and matrix
products are left to numpy (their implementations differ between libraries), so the kernels take angles as
inputs; integer and comparison logic (floors, clips, scatter-min and -max, first index of ties) is exact.
Division by zero gives inf or NaN as in numpy (error_model="numpy").

Checked by: tests/sim/test_occlusion.py, tests/sim/test_culling.py, tests/sim/test_radar.py (each kernel against the
numpy computation it replaces, bit for bit)
"""

from __future__ import annotations

import os

import numpy as np

from rodo.estimator.jit import njit, register_kernel_root

# the simulator's kernels: cache keyed on their sources' digest, and the first-run compile notice on stderr
register_kernel_root(os.path.dirname(os.path.abspath(__file__)), "rodo.sim")

@njit(cache=True, error_model="numpy")
def dot3(a0, a1, a2, b0, b1, b2):
    """a . b as numpy's einsum("ij,ij->i") sums a row of 3 (SIMD lanes: (a0 b0 + a2 b2) + a1 b1, then + 0.0,
    which turns a -0 into +0), so the kernel's results are numpy's bit for bit (no fast-math: no contraction)."""
    return ((a0 * b0 + a2 * b2) + a1 * b1) + 0.0


@njit(cache=True, error_model="numpy")
def depth_pairs(origin, u, v, object_id, ia0, ia1, ie0, ie1, limit, dirs, n_el, depth, owner):
    """The depth buffer's loop over (patch, needed cell) pairs (`depth_buffer`), writing depth and owner in place.

    Per patch: n = u x v (as `cross`), n . o, u . u, v . v; per pair with limit > -inf: s = (n . o) / (n . d),
    kept if 0 < s < limit; q = s d - o, a = (q . u) / (u . u), b = (q . v) / (v . v); a hit (a, b in [0, 1])
    nearer than the cell's depth so far replaces it. Division by zero gives inf or NaN as in numpy (both fail
    the tests)."""
    for k in range(origin.shape[0]):
        o0, o1, o2 = origin[k, 0], origin[k, 1], origin[k, 2]
        u0, u1, u2 = u[k, 0], u[k, 1], u[k, 2]
        v0, v1, v2 = v[k, 0], v[k, 1], v[k, 2]
        n0, n1, n2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
        no = dot3(n0, n1, n2, o0, o1, o2)
        uu = dot3(u0, u1, u2, u0, u1, u2)
        vv = dot3(v0, v1, v2, v0, v1, v2)
        for ia in range(ia0[k], ia1[k] + 1):
            for ie in range(ie0[k], ie1[k] + 1):
                c = ia * n_el + ie
                lim = limit[c]
                if not lim > -np.inf:
                    continue
                d0, d1, d2 = dirs[c, 0], dirs[c, 1], dirs[c, 2]
                s = no / dot3(n0, n1, n2, d0, d1, d2)
                if not (s > 0 and s < lim):  # (excludes NaN and inf)
                    continue
                q0, q1, q2 = s * d0 - o0, s * d1 - o1, s * d2 - o2
                a = dot3(q0, q1, q2, u0, u1, u2) / uu
                b = dot3(q0, q1, q2, v0, v1, v2) / vv
                if a >= 0 and a <= 1 and b >= 0 and b <= 1 and s < depth[c]:
                    depth[c] = s
                    owner[c] = object_id[k]


@njit(cache=True)
def nearest_first(cell, key, n_cells):
    """Per cell the first index of its smallest key (a later entry replaces it only if strictly smaller), then
    the cells that hold one, in ascending order."""
    arg = np.full(n_cells, -1, dtype=np.int64)
    for i in range(cell.size):
        j = arg[cell[i]]
        if j < 0 or key[i] < key[j]:
            arg[cell[i]] = i
    return arg[arg >= 0]


@njit(cache=True)
def box_points(origin, u, v):
    """x, y, z (9, P) of the points (origin + a u) + b v, a, b in {0, 0.5, 1} (a-major), and h = sqrt(x^2 + y^2)
    (the bits of np.linalg.norm of (x, y))."""
    P = origin.shape[0]
    x, y, z, h = np.empty((9, P)), np.empty((9, P)), np.empty((9, P)), np.empty((9, P))
    for i in range(9):
        a, b = 0.5 * (i // 3), 0.5 * (i % 3)
        for k in range(P):
            x[i, k] = (origin[k, 0] + a * u[k, 0]) + b * v[k, 0]
            y[i, k] = (origin[k, 1] + a * u[k, 1]) + b * v[k, 1]
            z[i, k] = (origin[k, 2] + a * u[k, 2]) + b * v[k, 2]
            h[i, k] = np.sqrt(x[i, k] * x[i, k] + y[i, k] * y[i, k])
    return x, y, z, h


@njit(cache=True)
def box_cells(az, el, x, az_min, az_max, cell_az, el_min, cell_el, n_az, n_el):
    """The cell boxes from the 9 points' angles: azimuth from the smallest to the largest (the whole field of
    view where the points' azimuths may not bound the patch: a spread over pi, or over pi / 2 with a point at
    x <= 0, behind or beside the sensor), elevation likewise; floor((angle - fov_min) / cell), one cell of
    padding, clipped to the grid."""
    P = az.shape[1]
    ia0, ia1 = np.empty(P, dtype=np.int64), np.empty(P, dtype=np.int64)
    ie0, ie1 = np.empty(P, dtype=np.int64), np.empty(P, dtype=np.int64)
    for k in range(P):
        a_lo, a_hi, e_lo, e_hi, behind = az[0, k], az[0, k], el[0, k], el[0, k], x[0, k] <= 0
        for i in range(1, 9):
            a_lo, a_hi = min(a_lo, az[i, k]), max(a_hi, az[i, k])
            e_lo, e_hi = min(e_lo, el[i, k]), max(e_hi, el[i, k])
            behind = behind or x[i, k] <= 0
        if a_hi - a_lo > np.pi or (behind and a_hi - a_lo > np.pi / 2):
            a_lo, a_hi = az_min, az_max
        ia0[k] = min(max(int(np.floor((a_lo - az_min) / cell_az)) - 1, 0), n_az - 1)
        ia1[k] = min(max(int(np.floor((a_hi - az_min) / cell_az)) + 1, 0), n_az - 1)
        ie0[k] = min(max(int(np.floor((e_lo - el_min) / cell_el)) - 1, 0), n_el - 1)
        ie1[k] = min(max(int(np.floor((e_hi - el_min) / cell_el)) + 1, 0), n_el - 1)
    return ia0, ia1, ie0, ie1


@njit(cache=True)
def gate_cells(r, az, el, min_range, max_range, az_min, az_max, el_min, el_max, cell_az, cell_el, n_az, n_el,
               tolerance):
    """`occlusion.gate_cells`: the in-view test of `RadarConfig.in_view`, the cell index, r - tolerance and its
    maximum per cell (np.maximum.at), in one pass."""
    idx = np.empty(r.size, dtype=np.int64)
    m = 0
    for i in range(r.size):
        if (r[i] >= min_range and r[i] <= max_range and az[i] >= az_min and az[i] <= az_max and el[i] >= el_min
                and el[i] <= el_max):
            idx[m] = i
            m += 1
    idx = idx[:m].copy()
    cell, r_hidden = np.empty(m, dtype=np.int64), np.empty(m)
    limit = np.full(n_az * n_el, -np.inf)
    for j in range(m):
        i = idx[j]
        ia = min(max(int(np.floor((az[i] - az_min) / cell_az)), 0), n_az - 1)
        ie = min(max(int(np.floor((el[i] - el_min) / cell_el)), 0), n_el - 1)
        c = ia * n_el + ie
        cell[j] = c
        r_hidden[j] = r[i] - tolerance
        if r_hidden[j] > limit[c]:
            limit[c] = r_hidden[j]
    return idx, cell, r_hidden, limit


@njit(cache=True)
def nearest_visible(idx, cell, r_hidden, r, object_id, depth, owner):
    """`occlusion.nearest_visible`: per cell the first visible entry of the smallest r[idx] (a later one replaces
    it only if strictly nearer), then the cells that hold one, in ascending order: idx of those entries."""
    arg = np.full(depth.size, -1, dtype=np.int64)
    for j in range(idx.size):
        c = cell[j]
        if depth[c] < r_hidden[j] and owner[c] != object_id[idx[j]]:
            continue  # hidden by an opaque surface of another object
        b = arg[c]
        if b < 0 or r[idx[j]] < r[idx[b]]:
            arg[c] = j
    return idx[arg[arg >= 0]]


@njit(cache=True)
def near_points(xyz, idx, p, r2, b, behind, per_point, gate_behind):
    """`culling.NearIndex.near`'s exact tests of the points xyz[idx]: d = xyz - p, kept if (dx^2 + dy^2) + dz^2
    <= r2 and (with gate_behind) (b0 dx + b1 dy) + b2 dz > -behind (behind[idx] if per_point, else behind[0]);
    the kept idx, in order."""
    out = np.empty(idx.size, dtype=np.int64)
    m = 0
    for j in range(idx.size):
        i = idx[j]
        dx, dy, dz = xyz[i, 0] - p[0], xyz[i, 1] - p[1], xyz[i, 2] - p[2]
        if not dx * dx + dy * dy + dz * dz <= r2:
            continue
        if gate_behind and not b[0] * dx + b[1] * dy + b[2] * dz > -(behind[i] if per_point else behind[0]):
            continue
        out[m] = i
        m += 1
    return out[:m].copy()


@njit(cache=True)
def patch_samples(origin, u, v, g, ab):
    """`culling.Cull.sample`'s points (origin + a u) + b v on patches g with (a, b) = ab, (m, 3)."""
    out = np.empty((g.size, 3))
    for i in range(g.size):
        for j in range(3):
            out[i, j] = (origin[g[i], j] + ab[i, 0] * u[g[i], j]) + ab[i, 1] * v[g[i], j]
    return out


@njit(cache=True)
def noisy_in_order(true, z, sigmas, fa, perm, idx, label, object_id, landmark_id, p_world, clutter):
    """`radar._noisy_with_clutter`'s detections: the n targets' measurements true (4, n) + z.T * sigmas (z (n, 4)
    the standard normal draws), then the false alarms fa (4, n_fa), all put in the order perm; truth from the
    candidates idx (label, object_id, landmark_id, p_world), for false alarms `clutter`, -1, -1, NaN.

    Returns range, azimuth, elevation, radial_velocity (N,), label, object_id, landmark_id (N,), p_world (N, 3),
    true_polar (N, 4)."""
    n, N = true.shape[1], perm.size
    meas = np.empty((4, N))
    lab, oid, lid = np.empty(N, dtype=np.int64), np.empty(N, dtype=np.int64), np.empty(N, dtype=np.int64)
    pw, tp = np.empty((N, 3)), np.empty((N, 4))
    for i in range(N):
        j = perm[i]
        if j < n:
            for q in range(4):
                tp[i, q] = true[q, j]
                meas[q, i] = true[q, j] + z[j, q] * sigmas[q]
            c = idx[j]
            lab[i], oid[i], lid[i] = label[c], object_id[c], landmark_id[c]
            for q in range(3):
                pw[i, q] = p_world[c, q]
        else:
            for q in range(4):
                tp[i, q] = fa[q, j - n]
                meas[q, i] = fa[q, j - n]
            lab[i], oid[i], lid[i] = clutter, -1, -1
            for q in range(3):
                pw[i, q] = np.nan
    return meas[0].copy(), meas[1].copy(), meas[2].copy(), meas[3].copy(), lab, oid, lid, pw, tp
