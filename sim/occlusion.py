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

from . import radar_kernels as kern
from .objects import Patches


def cell_directions(cfg) -> np.ndarray:
    """Unit directions (sensor frame) of the cell centres, (n_az * n_el, 3), azimuth-major."""
    n_az, n_el = cfg.grid_shape
    az = cfg.azimuth_fov[0] + (np.arange(n_az) + 0.5) * cfg.cell_azimuth
    el = cfg.elevation_fov[0] + (np.arange(n_el) + 0.5) * cfg.cell_elevation
    A, E = np.meshgrid(az, el, indexing="ij")
    A, E = A.ravel(), E.ravel()
    return np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis (3): np.cross's arithmetic (a1 b2 - a2 b1, ...: the same bits) without its
    per-call overhead, which dominates on the few-row arrays of a scan."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def nearest_per_cell(cell: np.ndarray, key: np.ndarray, n_cells: int) -> np.ndarray:
    """Indices of the smallest key in each cell (ties: the first index), in ascending cell order.

    The same as `order = np.lexsort((key, cell))` then the first of each cell, without sorting: one pass keeps
    per cell the first index of the smallest key so far (`radar_kernels.nearest_first`). Keys must not be NaN."""
    if not cell.size:
        return np.zeros(0, dtype=np.intp)
    return kern.nearest_first(np.ascontiguousarray(cell, dtype=np.int64), np.ascontiguousarray(key, dtype=np.float64),
                              n_cells)


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
    s d - o = a u + b v has a, b in [0, 1]. The (patch, cell) pairs are visited patch by patch, each box
    azimuth-major, and a hit replaces a cell's depth only if strictly nearer (ties: the first pair), in one
    compiled loop (`radar_kernels.depth_pairs`, numpy's arithmetic bit for bit).

    `limit` (cells,) restricts the work to what a caller comparing `depth < limit` needs: hits at s >= limit are
    dropped (cells with limit -inf are not computed at all). Where the full buffer's depth is below the limit,
    depth and owner are the same as without it (the same pairs, the same arithmetic, the same order); elsewhere
    they are inf and -1. The radar passes per cell the farthest candidate's range minus the occlusion tolerance:
    a surface that hides nothing there need not be known, and most pairs (surfaces behind others, surfaces at
    the candidates' own depth) are dropped before their intersection is tested.

    Checked by: tests/sim/test_occlusion.py::test_limited_depth_buffer_agrees_below_the_limit,
    tests/sim/test_occlusion.py::test_depth_buffer_is_the_numpy_computation_bit_for_bit
    """
    n_az, n_el = cfg.grid_shape
    depth = np.full(n_az * n_el, np.inf)
    owner = np.full(n_az * n_el, -1, dtype=np.int64)
    if not len(p):
        return depth, owner
    if limit is None:
        limit = np.full(n_az * n_el, np.inf)
    f64 = [np.ascontiguousarray(a, dtype=np.float64) for a in (p.origin, p.u, p.v, limit, dirs)]
    kern.depth_pairs(*f64[:3], np.ascontiguousarray(p.object_id, dtype=np.int64),
                     *(np.ascontiguousarray(b, dtype=np.int64) for b in cell_boxes(p, cfg)), *f64[3:], n_el, depth,
                     owner)
    return depth, owner


def cell_boxes(p: Patches, cfg) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each patch's box of cells (first and last azimuth and elevation cell, inclusive), from 9 points on the
    patch, padded by one cell and clipped to the grid.

    The 9 points origin + a u + b v (a, b in {0, 0.5, 1}) and their horizontal distance are computed by
    `radar_kernels.box_points`, their azimuth and elevation by numpy (np.arctan2, as ever), the boxes by
    `radar_kernels.box_cells`.

    Checked by: tests/sim/test_occlusion.py::test_cell_boxes_are_the_numpy_computation_bit_for_bit"""
    n_az, n_el = cfg.grid_shape
    x, y, z, h = kern.box_points(*(np.ascontiguousarray(a, dtype=np.float64) for a in (p.origin, p.u, p.v)))
    az = np.arctan2(y, x)  # (9, P)
    el = np.arctan2(z, h)
    return kern.box_cells(az, el, x, float(cfg.azimuth_fov[0]), float(cfg.azimuth_fov[1]), float(cfg.cell_azimuth),
                          float(cfg.elevation_fov[0]), float(cfg.cell_elevation), n_az, n_el)


def gate_cells(r: np.ndarray, az: np.ndarray, el: np.ndarray, cfg) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                          np.ndarray]:
    """The targets within the range gates and the field of view (`RadarConfig.in_view`) and their cells.

    Returns:
        idx (m,) indices of the targets in view, ascending; cell (m,) the cell of each (floor((angle - fov_min) /
        cell size), clipped to the grid, azimuth-major); r_hidden (m,) = r - occlusion_tolerance (a target is
        hidden behind an opaque surface nearer than this); limit (cells,) per cell the largest r_hidden, -inf
        where no target is (the `depth_buffer` limit). One pass (`radar_kernels.gate_cells`).

    Checked by: tests/sim/test_occlusion.py::test_gates_cells_and_limit_are_the_numpy_computation_bit_for_bit
    """
    n_az, n_el = cfg.grid_shape
    f = [np.ascontiguousarray(a, dtype=np.float64) for a in (r, az, el)]
    return kern.gate_cells(*f, float(cfg.min_range), float(cfg.max_range), float(cfg.azimuth_fov[0]),
                           float(cfg.azimuth_fov[1]), float(cfg.elevation_fov[0]), float(cfg.elevation_fov[1]),
                           float(cfg.cell_azimuth), float(cfg.cell_elevation), n_az, n_el,
                           float(cfg.occlusion_tolerance))


def nearest_visible(idx: np.ndarray, cell: np.ndarray, r_hidden: np.ndarray, r: np.ndarray, object_id: np.ndarray,
                    depth: np.ndarray, owner: np.ndarray) -> np.ndarray:
    """Of the gated targets (`gate_cells`: idx, cell, r_hidden), those not hidden (depth[cell] < r_hidden with an
    owner other than the target's object), then the nearest per cell (by r[idx], ties: the first): their indices
    idx[...], in ascending cell order (`radar_kernels.nearest_visible`; the same as filtering, then
    `nearest_per_cell`).

    Checked by: tests/sim/test_occlusion.py::test_nearest_visible_is_the_numpy_computation
    """
    return kern.nearest_visible(idx, cell, r_hidden, np.ascontiguousarray(r, dtype=np.float64),
                                np.ascontiguousarray(object_id, dtype=np.int64), depth, owner)
