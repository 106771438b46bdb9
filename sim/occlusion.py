"""Occlusion for the radar model: the angular cell grid, a depth buffer of opaque patches over it, and the
nearest entry per cell (used by `sim.radar.Radar`; docs/simulator.md).

The grid: `n_az x n_el` cells of the field of view (`RadarConfig.grid_shape`), indexed azimuth-major
(`cell = i_az * n_el + i_el`). The depth buffer casts the ray through each cell centre against the opaque patches
(sensor frame) and keeps the nearest hit. Only what the scan needs is computed: the cells that hold a candidate
scatterer, and per patch only the cells of its angular box; the arithmetic per (patch, cell) pair is the same
whichever cells are computed, so the depth at a needed cell does not depend on the others.

Checked by: tests/sim/test_radar.py (occlusion against brute-force ray casting), tests/sim/test_occlusion.py
"""

from __future__ import annotations

import numpy as np

from .objects import Patches

# the 9 points of a patch whose angles bound its cell box: origin + a u + b v, a, b in {0, 0.5, 1}, as (1, 9, 1)
_BOX_A, _BOX_B = np.array([[a, b] for a in (0, 0.5, 1) for b in (0, 0.5, 1)]).T[:, None, :, None]
_PAD = np.array([[-1], [1]])  # a box's first and last cell padded by one cell


def cell_directions(cfg) -> np.ndarray:
    """Unit directions (sensor frame) of the cell centres, (n_az * n_el, 3), azimuth-major."""
    n_az, n_el = cfg.grid_shape
    az = cfg.azimuth_fov[0] + (np.arange(n_az) + 0.5) * cfg.cell_azimuth
    el = cfg.elevation_fov[0] + (np.arange(n_el) + 0.5) * cfg.cell_elevation
    A, E = np.meshgrid(az, el, indexing="ij")
    A, E = A.ravel(), E.ravel()
    return np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1)


def cell_index(az: np.ndarray, el: np.ndarray, cfg) -> np.ndarray:
    """The cell of each direction (azimuth, elevation in radians), clipped to the grid."""
    n_az, n_el = cfg.grid_shape
    ia = _clip(np.floor((az - cfg.azimuth_fov[0]) / cfg.cell_azimuth).astype(int), 0, n_az - 1)
    ie = _clip(np.floor((el - cfg.elevation_fov[0]) / cfg.cell_elevation).astype(int), 0, n_el - 1)
    return ia * n_el + ie


def _clip(i: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """np.clip of integers without its per-call overhead."""
    return np.minimum(np.maximum(i, lo), hi)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis (3): np.cross's arithmetic (a1 b2 - a2 b1, ...: the same bits) without its
    per-call overhead, which dominates on the few-row arrays of a scan."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def nearest_per_cell(cell: np.ndarray, key: np.ndarray, n_cells: int) -> np.ndarray:
    """Indices of the smallest key in each cell (ties: the first index), in ascending cell order.

    The same as `order = np.lexsort((key, cell))` then the first of each cell, without sorting every entry:
    a scatter-min per cell, then only the entries at their cell's minimum are sorted by cell (stable). Keys
    must not be NaN."""
    if not cell.size:
        return np.zeros(0, dtype=np.intp)
    best = np.full(n_cells, np.inf)
    np.minimum.at(best, cell, key)
    at_min = np.flatnonzero(key == best[cell])
    c = cell[at_min]
    order = np.argsort(c, kind="stable")
    c = c[order]
    return at_min[order[np.r_[True, c[1:] != c[:-1]]]]


def nearest_per_bin(cell: np.ndarray, r: np.ndarray, range_cell: float, max_range: float) -> np.ndarray:
    """Indices of the nearest entry in each (angular cell, range bin of `range_cell` m) that holds one: the
    pairs are numbered (np.unique), then `nearest_per_cell` over them."""
    key = cell * (int(max_range / range_cell) + 2) + (r // range_cell).astype(np.int64)
    bins, pair = np.unique(key, return_inverse=True)
    return nearest_per_cell(pair.ravel(), r, len(bins))


def depth_buffer(p: Patches, cfg, dirs: np.ndarray, limit: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Nearest opaque surface along each cell-centre ray: depth (cells,) (inf if none) and its object id (-1).

    Each patch (sensor frame) is tested only against the cells of its angular box (`cell_boxes`); the test is
    an exact ray-rectangle intersection: s = (n . o) / (n . d) along the ray d, hit if s > 0 and the point
    s d - o = a u + b v has a, b in [0, 1].

    `limit` (cells,) restricts the work to what a caller comparing `depth < limit` needs: hits at s >= limit are
    dropped (cells with limit -inf are not computed at all). Where the full buffer's depth is below the limit,
    depth and owner are the same as without it (the same pairs, the same arithmetic, the same order); elsewhere
    they are inf and -1. The radar passes per cell the farthest candidate's range minus the occlusion tolerance:
    a surface that hides nothing there need not be known, and most pairs (surfaces behind others, surfaces at
    the candidates' own depth) are dropped before their intersection is tested.

    Checked by: tests/sim/test_occlusion.py::test_limited_depth_buffer_agrees_below_the_limit
    """
    n_az, n_el = cfg.grid_shape
    depth = np.full(n_az * n_el, np.inf)
    owner = np.full(n_az * n_el, -1)
    if not len(p):
        return depth, owner
    if limit is None:
        limit = np.full(n_az * n_el, np.inf)
    pid, cell = box_pairs(*cell_boxes(p, cfg), limit > -np.inf, n_el)
    normal = cross(p.u, p.v)
    d = dirs.take(cell, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.einsum("ij,ij->i", normal, p.origin).take(pid) / np.einsum("ij,ij->i", normal.take(pid, axis=0), d)
        keep = np.flatnonzero((s > 0) & (s < limit.take(cell)))  # (s < limit excludes NaN and inf)
        pid, cell, s, d = pid.take(keep), cell.take(keep), s.take(keep), d.take(keep, axis=0)
        q = np.repeat(s, 3).reshape(-1, 3) * d - p.origin.take(pid, axis=0)  # = s[:, None] * d - o, no row loop
        a = np.einsum("ij,ij->i", q, p.u.take(pid, axis=0)) / np.einsum("ij,ij->i", p.u, p.u).take(pid)
        b = np.einsum("ij,ij->i", q, p.v.take(pid, axis=0)) / np.einsum("ij,ij->i", p.v, p.v).take(pid)
    hit = (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
    cell, s, pid = cell[hit], s[hit], pid[hit]
    first = nearest_per_cell(cell, s, n_az * n_el)
    depth[cell[first]] = s[first]
    owner[cell[first]] = p.object_id[pid[first]]
    return depth, owner


def cell_boxes(p: Patches, cfg) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each patch's box of cells (first and last azimuth and elevation cell, inclusive), from 9 points on the
    patch, padded by one cell and clipped to the grid."""
    n_az, n_el = cfg.grid_shape
    # the 9 points, coordinate-major: (3, 9, P)
    x, y, z = (p.origin.T[:, None, :] + _BOX_A * p.u.T[:, None, :]) + _BOX_B * p.v.T[:, None, :]
    az = np.arctan2(y, x)  # (9, P)
    el = np.arctan2(z, np.sqrt(x * x + y * y))  # the same bits as np.linalg.norm of (x, y)
    az_lo, az_hi = az.min(axis=0), az.max(axis=0)
    # behind or beside the sensor the corner azimuths may not bound the patch: take the whole field of view
    wraps = (az_hi - az_lo > np.pi) | ((x <= 0).any(axis=0) & (az_hi - az_lo > np.pi / 2))
    az_lo_hi = np.where(wraps, np.array(cfg.azimuth_fov, dtype=float)[:, None], np.stack([az_lo, az_hi]))
    el_lo_hi = np.stack([el.min(axis=0), el.max(axis=0)])
    # floor((angle - fov_min) / cell), one cell of padding, clipped (lo and hi rows together)
    ia0, ia1 = _clip(np.floor((az_lo_hi - cfg.azimuth_fov[0]) / cfg.cell_azimuth).astype(int) + _PAD, 0, n_az - 1)
    ie0, ie1 = _clip(np.floor((el_lo_hi - cfg.elevation_fov[0]) / cfg.cell_elevation).astype(int) + _PAD, 0,
                     n_el - 1)
    return ia0, ia1, ie0, ie1


def box_pairs(ia0, ia1, ie0, ie1, need: np.ndarray, n_el: int) -> tuple[np.ndarray, np.ndarray]:
    """The (patch, cell) pairs of the boxes at the needed cells: (pairs,) patch indices and cell indices, patch
    by patch, each box azimuth-major (its cells in increasing index order).

    A box's azimuth column is the contiguous cell range [i_az n_el + ie0, i_az n_el + ie1]; its needed cells are
    a contiguous run of the sorted needed cells, found from the count of needed cells before each cell."""
    na = ia1 - ia0 + 1
    row = np.repeat(np.arange(len(na)), na)  # one row per (patch, azimuth column)
    col = np.arange(row.size) + np.repeat(ia0 - (np.cumsum(na) - na), na)
    before = np.concatenate([[0], np.cumsum(need)])  # needed cells with a smaller index
    lo = before[col * n_el + ie0[row]]
    cnt = before[col * n_el + ie1[row] + 1] - lo
    pid = np.repeat(row, cnt)
    j = np.arange(pid.size) + np.repeat(lo - (np.cumsum(cnt) - cnt), cnt)
    return pid, np.flatnonzero(need)[j]
