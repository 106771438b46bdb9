"""Culling for the radar model: which patches and points a scan can see at all (in range, facing the sensor,
near the field of view), so that the per-scan work is about what is around the sensor, not the whole scene.

`PatchGeometry` holds what does not change from scan to scan (computed once per static scene): the patches'
centres, half diagonals, unit normals and areas, and coordinate-major copies of the patches. A scan first
pre-selects the patches whose centre is within max_range + the largest half diagonal (+ 1 m) of the sensor and
not wholly behind it (a superset of those the exact tests keep), then applies the exact tests to those only;
the kept patches, and every value computed for them, are the same as when all patches are tested (per-row
arithmetic; matrix products of at least two rows, see `transform`). Likewise for the point scatterers.

Speed notes (the output is bit-identical to computing on whole (n, 3) arrays): row gathers use `take`, and
element-wise work on (n, 3) arrays is done column by column or on (3, n) copies, as numpy loops over a last axis
of 3 elements once per row.

Checked by: tests/sim/test_culling.py, tests/sim/test_radar.py
"""

from __future__ import annotations

import numpy as np

from .objects import Patches
from .occlusion import cross

MARGIN = 1.0  # m added to the pre-selection distances (the exact tests then decide)


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


def _ahead(xyz_T: np.ndarray, T_sensor_world: np.ndarray, cfg, max_range: float, behind: np.ndarray | float):
    """(n,) mask of the world points (3, n) within max_range of the sensor and, when the azimuth field of view
    lies within +-90 deg, with a sensor-frame x above -behind (what is wholly behind the sensor plane is outside
    such a field of view)."""
    p = sensor_position(T_sensor_world)
    dx, dy, dz = xyz_T[0] - p[0], xyz_T[1] - p[1], xyz_T[2] - p[2]
    m = dx * dx + dy * dy + dz * dz <= max_range * max_range
    if -np.pi / 2 <= cfg.azimuth_fov[0] and cfg.azimuth_fov[1] <= np.pi / 2:
        b = T_sensor_world[0, :3]  # the sensor's x axis in the world frame
        m &= b[0] * dx + b[1] * dy + b[2] * dz > -behind
    return m


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
            self.center_T = np.ascontiguousarray(self.center.T)
            self._reach = float(self.half_diagonal.max()) + MARGIN
        self.origin_T, self.u_T, self.v_T = (np.ascontiguousarray(a.T) for a in (patches.origin, patches.u,
                                                                                  patches.v))

    def near(self, T_sensor_world: np.ndarray, cfg) -> np.ndarray | None:
        """Sorted indices of the patches the exact tests may keep, or None for all of them (not indexed, all
        near, or fewer than two near: then all are tested, as one product)."""
        if not self.indexed:
            return None
        m = _ahead(self.center_T, T_sensor_world, cfg, cfg.max_range + self._reach, self.half_diagonal + MARGIN)
        idx = np.flatnonzero(m)
        return idx if 2 <= len(idx) < len(m) else None


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

    def sensor(self, opaque_only: bool = False) -> Patches:
        """The kept patches (or only the opaque ones) in the sensor frame."""
        patches = self._geometry.patches
        idx = self.idx.take(np.flatnonzero(patches.opaque.take(self.idx))) if opaque_only else self.idx
        C, t, n_all = self._C, self._t, len(self.idx)
        return Patches(transform(patches.origin.take(idx, axis=0), C, t, n_all),
                       transform(patches.u.take(idx, axis=0), C, None, n_all),
                       transform(patches.v.take(idx, axis=0), C, None, n_all), patches.object_id.take(idx),
                       patches.reflectivity.take(idx), patches.opaque.take(idx), patches.two_sided.take(idx))

    def counts(self, cfg, rng: np.random.Generator) -> np.ndarray:
        """Poisson numbers of surface samples per kept patch: mean surface_fill * reflectivity * area * cos /
        (max(d, min_density_range)^2 * cell solid angle)."""
        cell = cfg.cell_azimuth * cfg.cell_elevation
        lam = (cfg.surface_fill * self._geometry.patches.reflectivity.take(self.idx)
               * self._geometry.area.take(self.idx) * self.cos
               / (np.maximum(self.d, cfg.min_density_range) ** 2 * cell))
        return rng.poisson(lam)

    def sample(self, cfg, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Random points on the kept patches (Poisson counts, then uniform positions origin + a u + b v, world
        frame): (m, 3) and the index of their patch among the kept ones."""
        k = np.repeat(np.arange(len(self.idx)), self.counts(cfg, rng))
        ab = rng.random((k.size, 2))
        g = self.idx.take(k)
        p_T = ((self._geometry.origin_T.take(g, axis=1) + ab[:, 0] * self._geometry.u_T.take(g, axis=1))
               + ab[:, 1] * self._geometry.v_T.take(g, axis=1))
        return p_T.T, k


class PointIndex:
    """Point scatterers (world frame), pre-selected per scan like the patches: those that may pass the gates."""

    def __init__(self, p: np.ndarray):
        self.p_T = np.ascontiguousarray(p.T)

    def near(self, T_sensor_world: np.ndarray, cfg) -> np.ndarray | None:
        """Sorted indices of the points within max_range + MARGIN of the sensor and not behind it, or None
        for all of them."""
        m = _ahead(self.p_T, T_sensor_world, cfg, cfg.max_range + MARGIN, MARGIN)
        idx = np.flatnonzero(m)
        return idx if len(idx) < len(m) else None
