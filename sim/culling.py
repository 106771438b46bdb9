"""Culling for the radar model: which patches and points a scan can see at all (in range, facing the sensor,
near the field of view), so that the per-scan work is about what is around the sensor, not the whole scene.

`PatchGeometry` holds what does not change from scan to scan (computed once per static scene): the patches'
centres, half diagonals, unit normals and areas, and contiguous copies of the patches. A scan first
pre-selects the patches whose centre is within max_range + the largest half diagonal (+ 1 m) of the sensor and
not wholly behind it (a superset of those the exact tests keep), then applies the exact tests to those only;
the kept patches, and every value computed for them, are the same as when all patches are tested (per-row
arithmetic; matrix products of at least two rows, see `transform`). Likewise for the point scatterers.

Speed notes (the output is bit-identical to computing on whole (n, 3) arrays): row gathers use `take`, and
element-wise work on (n, 3) arrays is done column by column, as numpy loops over a last axis of 3 elements once
per row; the pre-selection's distance tests and the surface samples are compiled loops (`sim.radar_kernels`,
numpy's arithmetic element for element).

Checked by: tests/sim/test_culling.py, tests/sim/test_radar.py
"""

from __future__ import annotations

import numpy as np

from . import radar_kernels as kern
from .objects import Patches
from .occlusion import cross

MARGIN = 1.0  # m added to the pre-selection distances (the exact tests then decide)
SMALL = 4000  # up to this many points the pre-selection tests them all, beyond it only the tiles near the sensor
FEW_POINTS = 1000  # up to this many point scatterers none are pre-selected (all are gated exactly)


def transform(p: np.ndarray, C: np.ndarray, t: np.ndarray | None = None, n_all: int | None = None) -> np.ndarray:
    """p @ C.T (+ t), (n, 3), for rows p selected from a set of n_all rows (default: p is the set), with each
    row's bits as in the product of the whole set: numpy computes a one-row product as a vector product (other
    rounding than the matrix product of several rows), so a single row selected from several is computed in a
    two-row product."""
    if len(p) == 1 and (n_all or 1) > 1:
        out = np.concatenate([p, p]) @ C.T
        out = out[:1]
    else:
        out = p @ C.T
    if t is not None:
        for j in range(3):  # + t column by column (a broadcast add loops once per row)
            out[:, j] += t[j]
    return out


def norm3(p: np.ndarray) -> np.ndarray:
    """np.linalg.norm(p, axis=-1) of (n, 3) rows, the same bits: sqrt((x^2 + y^2) + z^2)."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    return np.sqrt((x * x + y * y) + z * z)


def sensor_position(T_sensor_world: np.ndarray) -> np.ndarray:
    """The sensor origin in the world frame (to the rounding of the pre-selection)."""
    return -(T_sensor_world[:3, :3].T @ T_sensor_world[:3, 3])


class NearIndex:
    """World points (centres of patches, point scatterers) bucketed on a horizontal grid of `tile` metres, for
    the per-scan pre-selection: only the tiles around the sensor are tested, so its cost does not grow with the
    length of the drive.

    Args:
        xyz: (n, 3) world points.
        tile: grid spacing, m.
    """

    def __init__(self, xyz: np.ndarray, tile: float = 50.0):
        self.xyz = np.ascontiguousarray(xyz, dtype=float)
        self.tile = tile
        ij = np.floor(self.xyz[:, :2] / tile).astype(np.int64) if len(xyz) else np.zeros((0, 2), np.int64)
        self._lo = ij.min(axis=0) if len(xyz) else np.zeros(2, np.int64)
        self._shape = (ij.max(axis=0) - self._lo + 1) if len(xyz) else np.ones(2, np.int64)
        key = (ij[:, 0] - self._lo[0]) * self._shape[1] + (ij[:, 1] - self._lo[1])
        self._order = np.argsort(key, kind="stable")  # by tile, then by index
        self._start = np.searchsorted(key[self._order], np.arange(self._shape[0] * self._shape[1] + 1))

    def __len__(self) -> int:
        return len(self.xyz)

    def near(self, T_sensor_world: np.ndarray, cfg, max_range: float, behind: np.ndarray | float) -> np.ndarray:
        """Sorted indices of the points within max_range of the sensor and, when the azimuth field of view lies
        within +-90 deg, with a sensor-frame x above -behind (what is wholly behind the sensor plane is outside
        such a field of view). `behind` is a scalar or (n,) per point."""
        p = sensor_position(T_sensor_world)
        if len(self.xyz) <= SMALL:  # testing all is cheaper than gathering the tiles
            idx = np.arange(len(self.xyz))
        else:
            i0, j0 = np.maximum(np.floor((p[:2] - max_range) / self.tile).astype(np.int64) - self._lo, 0)
            i1, j1 = np.minimum(np.floor((p[:2] + max_range) / self.tile).astype(np.int64) - self._lo,
                                self._shape - 1)
            if i0 > i1 or j0 > j1:
                return np.zeros(0, dtype=np.intp)
            rows = np.arange(i0, i1 + 1) * self._shape[1]
            idx = np.sort(np.concatenate([self._order[self._start[r + j0]:self._start[r + j1 + 1]] for r in rows]))
        per_point = np.ndim(behind) != 0
        return kern.near_points(self.xyz, idx, p, max_range * max_range, np.ascontiguousarray(T_sensor_world[0, :3]),
                                np.ascontiguousarray(behind if per_point else [behind], dtype=np.float64), per_point,
                                -np.pi / 2 <= cfg.azimuth_fov[0] and cfg.azimuth_fov[1] <= np.pi / 2)


class PatchGeometry:
    """The culling geometry of a set of patches that does not depend on the sensor pose.

    Args:
        patches: the patches (world frame).
        indexed: pre-select the patches near the sensor each scan (for a static scene: many patches, many scans).
    """

    def __init__(self, patches: Patches, indexed: bool):
        self.patches = patches
        # the Patches properties (center, half_diagonal, normal, area), the same arithmetic
        diagonal = patches.u + patches.v
        self.center = patches.origin + 0.5 * diagonal
        self.half_diagonal = 0.5 * norm3(diagonal)
        n = cross(patches.u, patches.v)
        self.area = norm3(n)
        self.normal = n / self.area[:, None]
        self.indexed = indexed and len(patches) > 1
        if self.indexed:
            self._index = NearIndex(self.center)
            self._reach = float(self.half_diagonal.max()) + MARGIN
            self._behind = self.half_diagonal + MARGIN  # a patch is wholly behind the sensor beyond this
        self.origin, self.u, self.v = (np.ascontiguousarray(a, dtype=np.float64) for a in (patches.origin, patches.u,
                                                                                            patches.v))

    def near(self, T_sensor_world: np.ndarray, cfg) -> np.ndarray | None:
        """Sorted indices of the patches the exact tests may keep, or None for all of them (not indexed, all
        near, or fewer than two near: then all are tested, as one product)."""
        if not self.indexed:
            return None
        idx = self._index.near(T_sensor_world, cfg, cfg.max_range + self._reach, self._behind)
        return idx if 2 <= len(idx) < len(self.center) else None


class Cull:
    """Patches visible from the sensor: in range, facing it, near the field of view.

    Attributes:
        idx: (k,) indices of the kept patches.
        d: (k,) range of their centres; cos: (k,) |cos| of the incidence angle at the centre.
        object_id: (k,).
    """

    def __init__(self, geometry: PatchGeometry, T_sensor_world: np.ndarray, cfg):
        patches = geometry.patches
        C, t = T_sensor_world[:3, :3], T_sensor_world[:3, 3]
        near = geometry.near(T_sensor_world, cfg)

        def sel(a):
            return a if near is None else a.take(near, axis=0)

        c = transform(sel(geometry.center), C, t)
        d = norm3(c)
        hd = sel(geometry.half_diagonal)
        facing = np.einsum("ij,ij->i", sel(geometry.normal) @ C.T, -c)  # > 0: the sensor is on the normal's side
        # (clip as minimum(maximum()): these angles are only compared, the sign of a zero does not matter)
        ang = np.where(d > hd, np.arcsin(np.minimum(np.maximum(hd / np.maximum(d, 1e-9), 0), 1)), np.pi)
        az = np.arctan2(c[:, 1], c[:, 0])
        el = np.arcsin(np.minimum(np.maximum(c[:, 2] / np.maximum(d, 1e-9), -1), 1))
        keep = np.flatnonzero((d - hd < cfg.max_range) & (d + hd > cfg.min_range)
                              & (sel(patches.two_sided) | (facing > 0))
                              & (az > cfg.azimuth_fov[0] - ang) & (az < cfg.azimuth_fov[1] + ang)
                              & (el > cfg.elevation_fov[0] - ang) & (el < cfg.elevation_fov[1] + ang))
        self.idx = keep if near is None else near.take(keep)
        self.d = d.take(keep)
        self.cos = np.abs(facing.take(keep)) / np.maximum(self.d, 1e-9)
        self._geometry = geometry
        self.object_id = patches.object_id.take(self.idx)
        self._C, self._t = C, t

    def sensor(self, opaque_only: bool = False, groups: np.ndarray | None = None) -> Patches:
        """The kept patches (or only the opaque ones) in the sensor frame.

        groups: offsets (g + 1,) into the kept patches of groups that were culled one by one before (the moving
        vehicles, now culled together): a group of one patch is mapped as its own one-row product, as then."""
        patches = self._geometry.patches
        idx = self.idx.take(np.flatnonzero(patches.opaque.take(self.idx))) if opaque_only else self.idx
        C, t, n_all = self._C, self._t, len(self.idx)
        out = [transform(patches.origin.take(idx, axis=0), C, t, n_all),
               transform(patches.u.take(idx, axis=0), C, None, n_all),
               transform(patches.v.take(idx, axis=0), C, None, n_all)]
        if groups is not None and not opaque_only:
            for j in [int(a) for a, b in zip(groups[:-1], groups[1:]) if b - a == 1]:  # (a few movers)
                out[0][j] = transform(patches.origin.take(idx[j:j + 1], axis=0), C, t)[0]
                out[1][j] = transform(patches.u.take(idx[j:j + 1], axis=0), C)[0]
                out[2][j] = transform(patches.v.take(idx[j:j + 1], axis=0), C)[0]
        return Patches(*out, patches.object_id.take(idx), patches.reflectivity.take(idx), patches.opaque.take(idx),
                       patches.two_sided.take(idx))

    def counts(self, cfg, rng: np.random.Generator, rows: slice = slice(None)) -> np.ndarray:
        """Poisson numbers of surface samples per kept patch (of `rows` of them): mean surface_fill *
        reflectivity * area * cos / (max(d, min_density_range)^2 * cell solid angle)."""
        cell = cfg.cell_azimuth * cfg.cell_elevation
        idx = self.idx[rows]
        lam = (cfg.surface_fill * self._geometry.patches.reflectivity.take(idx)
               * self._geometry.area.take(idx) * self.cos[rows]
               / (np.maximum(self.d[rows], cfg.min_density_range) ** 2 * cell))
        return rng.poisson(lam)

    def sample(self, cfg, rng: np.random.Generator, rows: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """Random points on the kept patches (or on `rows` of them: a slice): Poisson counts, then uniform
        positions origin + a u + b v, world frame. Returns (m, 3) and the index of their patch among the kept."""
        k = np.arange(len(self.idx))[rows]
        k = np.repeat(k, self.counts(cfg, rng, rows))
        ab = rng.random((k.size, 2))
        g = self.idx.take(k)
        geometry = self._geometry
        return kern.patch_samples(geometry.origin, geometry.u, geometry.v, g, ab), k


class PointIndex:
    """Point scatterers (world frame), pre-selected per scan like the patches: those that may pass the gates."""

    def __init__(self, p: np.ndarray):
        self._index = NearIndex(p)

    def near(self, T_sensor_world: np.ndarray, cfg) -> np.ndarray | None:
        """Sorted indices of the points within max_range + MARGIN of the sensor and not behind it, or None
        for all of them."""
        if len(self._index) <= FEW_POINTS:  # gating them all costs less than selecting
            return None
        idx = self._index.near(T_sensor_world, cfg, cfg.max_range + MARGIN, MARGIN)
        return idx if len(idx) < len(self._index) else None
