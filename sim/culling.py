"""Culling for the radar model: which patches and points a scan can see at all (in range, facing the sensor,
near the field of view), so that the per-scan work is about what is around the sensor, not the whole scene.

`PatchGeometry` holds what does not change from scan to scan (computed once per static scene): the patches'
centres, half diagonals, unit normals and areas, and a KD-tree over the centres. A scan first takes the patches
whose centre is within max_range + the largest half diagonal (+ 1 m) of the sensor (a superset of those in
range), then applies the exact tests to those only; the kept patches, and every value computed for them, are
the same as when all patches are tested (per-row arithmetic; matrix products of at least two rows, see
`transform`).

Checked by: tests/sim/test_radar.py, tests/sim/test_occlusion.py
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .objects import Patches

MARGIN = 1.0  # m added to the pre-selection radius (the exact tests then decide)


def transform(p: np.ndarray, C: np.ndarray, t: np.ndarray, n_all: int) -> np.ndarray:
    """p @ C.T + t for rows p selected from a set of n_all rows, with each row's bits as in the product of
    the whole set: numpy computes a one-row product as a vector product (other rounding than the matrix
    product of several rows), so a single row selected from several is computed in a two-row product."""
    if len(p) == 1 and n_all > 1:
        return (np.concatenate([p, p]) @ C.T + t)[:1]
    return p @ C.T + t


class PatchGeometry:
    """The culling geometry of a set of patches that does not depend on the sensor pose.

    Args:
        patches: the patches (world frame).
        indexed: build a KD-tree over the centres (for a static scene used over many scans).
    """

    def __init__(self, patches: Patches, indexed: bool):
        self.patches = patches
        self.center = patches.center
        self.half_diagonal = patches.half_diagonal
        self.normal = patches.normal
        self.area = patches.area
        self._tree = cKDTree(self.center) if indexed and len(patches) > 1 else None
        self._radius = float(self.half_diagonal.max()) + MARGIN if len(patches) else 0.0

    def near(self, p_world: np.ndarray, max_range: float) -> np.ndarray | None:
        """Sorted indices of the patches that may be within max_range of p_world, or None for all of them
        (no index, or fewer than two near: then all are tested, as one product)."""
        if self._tree is None:
            return None
        idx = self._tree.query_ball_point(p_world, max_range + self._radius, return_sorted=True)
        return np.asarray(idx, dtype=np.intp) if len(idx) >= 2 else None


class Cull:
    """Patches visible from the sensor: in range, facing it, near the field of view.

    Attributes:
        idx: (k,) indices of the kept patches.
        d: (k,) range of their centres; cos: (k,) |cos| of the incidence angle at the centre.
        origin, u, v: (k, 3) the kept patches in the world frame; object_id: (k,).
        sensor: the kept `Patches` in the sensor frame.
    """

    def __init__(self, geometry: PatchGeometry, T_sensor_world: np.ndarray, cfg):
        patches = geometry.patches
        C, t = T_sensor_world[:3, :3], T_sensor_world[:3, 3]
        near = geometry.near(-(C.T @ t), cfg.max_range)

        def sel(a):
            return a if near is None else a[near]

        c = sel(geometry.center) @ C.T + t
        d = np.linalg.norm(c, axis=-1)
        hd = sel(geometry.half_diagonal)
        n = sel(geometry.normal) @ C.T
        facing = np.einsum("ij,ij->i", n, -c)  # > 0: the sensor is on the normal's side
        ang = np.where(d > hd, np.arcsin(np.clip(hd / np.maximum(d, 1e-9), 0, 1)), np.pi)
        az = np.arctan2(c[:, 1], c[:, 0])
        el = np.arcsin(np.clip(c[:, 2] / np.maximum(d, 1e-9), -1, 1))
        keep = np.flatnonzero((d - hd < cfg.max_range) & (d + hd > cfg.min_range)
                              & (sel(patches.two_sided) | (facing > 0))
                              & (az > cfg.azimuth_fov[0] - ang) & (az < cfg.azimuth_fov[1] + ang)
                              & (el > cfg.elevation_fov[0] - ang) & (el < cfg.elevation_fov[1] + ang))
        self.idx = keep if near is None else near[keep]
        self.d = d[keep]
        self.cos = np.abs(facing[keep]) / np.maximum(self.d, 1e-9)
        self._geometry = geometry
        self.origin, self.u, self.v = patches.origin[self.idx], patches.u[self.idx], patches.v[self.idx]
        self.object_id = patches.object_id[self.idx]
        self.sensor = Patches(self.origin @ C.T + t, self.u @ C.T, self.v @ C.T, self.object_id,
                              patches.reflectivity[self.idx], patches.opaque[self.idx], patches.two_sided[self.idx])

    def counts(self, cfg, rng: np.random.Generator) -> np.ndarray:
        """Poisson numbers of surface samples per kept patch: mean surface_fill * reflectivity * area * cos /
        (max(d, min_density_range)^2 * cell solid angle)."""
        cell = cfg.cell_azimuth * cfg.cell_elevation
        lam = (cfg.surface_fill * self.sensor.reflectivity * self._geometry.area[self.idx] * self.cos
               / (np.maximum(self.d, cfg.min_density_range) ** 2 * cell))
        return rng.poisson(lam)

    def sample(self, cfg, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Random points on the kept patches (Poisson counts, then uniform positions, world frame): (m, 3) and
        the index of their patch among the kept ones."""
        k = np.repeat(np.arange(len(self.idx)), self.counts(cfg, rng))
        ab = rng.random((k.size, 2))
        return self.origin[k] + ab[:, :1] * self.u[k] + ab[:, 1:] * self.v[k], k


class PointIndex:
    """A KD-tree over point scatterers (world frame): the points that may be within range of the sensor."""

    def __init__(self, p: np.ndarray):
        self.p = p
        self._tree = cKDTree(p) if len(p) > 1 else None

    def near(self, p_world: np.ndarray, max_range: float) -> np.ndarray | None:
        """Sorted indices of the points within max_range + MARGIN of p_world, or None for all."""
        if self._tree is None:
            return None
        return np.asarray(self._tree.query_ball_point(p_world, max_range + MARGIN, return_sorted=True),
                          dtype=np.intp)
