"""Compiled inner loops of the association (the per-scan hot path; the per-map-point preparation is
`prepare_kernels.prepare`): the candidate search on a grid over the detections with the Mahalanobis distances of
the candidates (the greedy one-to-one selection is in `matching_kernels`), and the re-association's scoring of
those candidates at the solution with the chosen pairs' information there. `association.associate` is the
public entry and documents the method; `scan_association.MapAssociation` is the odometry's.

Checked by: tests/estimator/test_association.py (greedy against an all-pairs loop; gate statistics),
    tests/estimator/test_scan_association.py (the preparation and the re-association against the references)
"""

from __future__ import annotations

import math

import numpy as np

from .jit import njit
from .measurement_kernels import frame_values, point_prediction, residual_d2


@njit(cache=True)
def lambda_max_sym3(M):
    """Largest eigenvalue of a symmetric 3x3 matrix (trigonometric closed form, Smith 1961)."""
    return lambda_max_upper(M[0, 0], M[0, 1], M[0, 2], M[1, 1], M[1, 2], M[2, 2])


@njit(cache=True, inline="always")
def lambda_max_upper(m00, m01, m02, m11, m12, m22):
    """`lambda_max_sym3` of the symmetric matrix with upper triangle m00, m01, m02, m11, m12, m22."""
    p1 = m01 * m01 + m02 * m02 + m12 * m12
    q = (m00 + m11 + m22) / 3.0
    p2 = (m00 - q) ** 2 + (m11 - q) ** 2 + (m22 - q) ** 2 + 2.0 * p1
    if p2 <= 0.0:
        return q
    p = math.sqrt(p2 / 6.0)
    b00, b11, b22 = (m00 - q) / p, (m11 - q) / p, (m22 - q) / p
    b01, b02, b12 = m01 / p, m02 / p, m12 / p
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    phi = math.acos(min(1.0, max(-1.0, r))) / 3.0
    return q + 2.0 * p * math.cos(phi)


@njit(cache=True, inline="always")
def sensor_from_world(Cvs, C):
    """B (3, 3) = C_vs^T C: a map point's sensor-frame position's derivative by its world position."""
    B = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            B[i, j] = Cvs[0, i] * C[0, j] + Cvs[1, i] * C[1, j] + Cvs[2, i] * C[2, j]
    return B


@njit(cache=True)
def rescore(polar, T, varpi, p_world, rows, Tvs, z_meas, S_inv, j, i, d2):
    """An association's candidate pairs (map point p_world[rows[j[q]]], detection z_meas[i[q]]; j ascending)
    scored again at the state (T, varpi) with the S_inv they were gated with: d2[q] = e^T S_inv[j[q]] e, e the
    detection minus the map point's prediction (`point_prediction`, the azimuth wrapped). Returns -1, or j[q] for the
    first map point at the sensor origin.

    Checked by: tests/estimator/test_scan_association.py::test_reassociation_rescores_the_candidates_at_the_new_state
    """
    F = frame_values(T, varpi, Tvs)
    zp, e = np.empty(4), np.empty(4)
    last = -1
    for q in range(j.shape[0]):
        a = j[q]
        if a != last:  # the candidates come map point by map point: one prediction each
            if point_prediction(polar, F, p_world[rows[a]], zp) == 0.0:
                return a
            last = a
        d2[q] = residual_d2(polar, z_meas[i[q]], zp, S_inv[a], e)
    return -1


@njit(cache=True)
def build_grid(points, cell):
    """A uniform grid over the x-y plane of points (n, 3), in compressed rows: the detections of cell
    c = ix * ny + iy are order[start[c]:start[c + 1]]. Returns (x0, y0, nx, ny, start, order).

    Checked by: tests/estimator/test_association.py::test_grid_candidates_are_the_k_nearest_in_the_radius
    """
    n = len(points)
    x0, y0 = np.inf, np.inf
    x1, y1 = -np.inf, -np.inf
    for i in range(n):
        x0, x1 = min(x0, points[i, 0]), max(x1, points[i, 0])
        y0, y1 = min(y0, points[i, 1]), max(y1, points[i, 1])
    if n == 0:
        x0, y0, x1, y1 = 0.0, 0.0, 0.0, 0.0
    nx = int((x1 - x0) / cell) + 1
    ny = int((y1 - y0) / cell) + 1
    cells = np.empty(n, np.int64)
    start = np.zeros(nx * ny + 1, np.int64)
    for i in range(n):
        c = int((points[i, 0] - x0) / cell) * ny + int((points[i, 1] - y0) / cell)
        cells[i] = c
        start[c + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):  # ascending detection index within a cell
        order[fill[cells[i]]] = i
        fill[cells[i]] += 1
    return x0, y0, nx, ny, start, order


@njit(cache=True)
def grid_candidates(polar, cell_points, x0, y0, cell, nx, ny, start, order, p, radius, k, z_meas, z_pred, S_inv,
                    gate, j_out, i_out, d2_out):
    """For each position p[a] (m, 3): the k nearest detections within radius[a] (Euclidean, sensor frame),
    their d2 = e^T S_inv[a] e with e = z_meas[i] - z_pred[a] (azimuth wrapped), and the pairs with d2 <= gate
    written to j_out, i_out, d2_out (capacity m * k). Returns (pairs written, candidates before gating).
    cell_points are the detections' positions in the grid's order (points[order]): a row of cells is one run
    of them, read in sequence.

    Checked by: tests/estimator/test_association.py::test_grid_candidates_are_the_k_nearest_in_the_radius
    """
    m = len(p)
    dist = np.empty(len(cell_points))
    idx = np.empty(len(cell_points), np.int64)
    e = np.empty(4)
    written, proposed = 0, 0
    for a in range(m):
        r = radius[a]
        r2 = r * r
        p0, p1, p2 = p[a, 0], p[a, 1], p[a, 2]
        ix0, ix1 = int(max(0.0, (p0 - r - x0) / cell)), int(min(nx - 1.0, (p0 + r - x0) / cell))
        iy0, iy1 = int(max(0.0, (p1 - r - y0) / cell)), int(min(ny - 1.0, (p1 + r - y0) / cell))
        if iy0 > iy1:  # no cell of the grid in p's square: no row to read (start[ix * ny + iy1 + 1] is not its row)
            continue
        found = 0
        for ix in range(ix0, ix1 + 1):  # cells iy0..iy1 of row ix: one run of cell_points, in the grid's order
            for q in range(start[ix * ny + iy0], start[ix * ny + iy1 + 1]):
                dx, dy, dz = cell_points[q, 0] - p0, cell_points[q, 1] - p1, cell_points[q, 2] - p2
                d = dx * dx + dy * dy + dz * dz  # squared: the same order, no root per detection
                # written always, kept when inside: no branch to mispredict; in bounds because every
                # detection sits in one cell, so found < the detections examined <= len(cell_points)
                dist[found] = d
                idx[found] = order[q]
                found += d <= r2
        if found > k:  # the k nearest, by selection (equidistant detections: the first found in the grid)
            for q in range(k):
                best = q
                for u in range(q + 1, found):
                    if dist[u] < dist[best]:
                        best = u
                dist[q], dist[best] = dist[best], dist[q]
                idx[q], idx[best] = idx[best], idx[q]
            found = k
        proposed += found
        for q in range(found):
            i = idx[q]
            s = residual_d2(polar, z_meas[i], z_pred[a], S_inv[a], e)
            if s <= gate:
                j_out[written] = a
                i_out[written] = i
                d2_out[written] = s
                written += 1
    return written, proposed


@njit(cache=True)
def window_points(points, T_sensor_world, limits, inside):
    """inside[a] = whether map point points[a] (world frame), seen from the sensor at T_sensor_world, has its
    azimuth in [limits[0], limits[1]] and its elevation in [limits[2], limits[3]] (infinite limits: that angle
    is not windowed): the map side of `MapAssociation.window_masks` in one pass, without the sensor-frame
    positions it does not need.

    Checked by: tests/estimator/test_scan_association.py::test_compiled_map_window_equals_the_reference
    """
    C, t = T_sensor_world[:3, :3], T_sensor_world[:3, 3]
    use_az = limits[0] > -np.inf or limits[1] < np.inf
    use_el = limits[2] > -np.inf or limits[3] < np.inf
    for a in range(points.shape[0]):
        p0, p1, p2 = points[a, 0], points[a, 1], points[a, 2]
        x = C[0, 0] * p0 + C[0, 1] * p1 + C[0, 2] * p2 + t[0]
        y = C[1, 0] * p0 + C[1, 1] * p1 + C[1, 2] * p2 + t[1]
        z = C[2, 0] * p0 + C[2, 1] * p1 + C[2, 2] * p2 + t[2]
        ok = True
        if use_az:
            az = math.atan2(y, x)
            ok = limits[0] <= az <= limits[1]
        if ok and use_el:
            r = max(math.sqrt(x * x + y * y + z * z), 1e-12)
            el = math.asin(min(1.0, max(-1.0, z / r)))
            ok = limits[2] <= el <= limits[3]
        inside[a] = ok
