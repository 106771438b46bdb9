"""Local map of world points for scan-to-map association (paper sec. VII: 1500 points).

Policy (docs/measurements.md, "Local map"):
- add: after the solve, the caller passes the scan's static (Doppler-inlier) detections that were NOT associated,
  placed in the world with the estimate. They are thinned before insertion: with voxel > 0 one randomly chosen
  detection per voxel is kept, and none in a voxel that already holds a map point; then at most
  max_new_fraction * capacity of them are kept (random subset), so one scan cannot flush the map.
  New points get a new stable id, hits = 1, last_seen = scan.
- refresh: associated points get last_seen = scan and hits += 1. Their positions are NOT moved (a map that
  follows the estimate would absorb the drift it is meant to measure).
- fuse (optional, the caller decides: MapConfig.fuse): instead of `refresh`, an associated point is refined
  with the detection placed by the solved estimate, information-weighted (Kalman form
  p += K (z - p), P = (I - K) P, K = P (P + R)^-1), so repeated observations average the detection noise
  (elevation noise at long range above all) while close, precise observations dominate. With max_fused = N the
  point's prior information is multiplied by (N - 1) / N once it holds N observations, so with equal R its
  information stays at most N R^-1 (a fading memory of about N observations): the surface under a point is
  resampled every scan and the estimate that places the detections drifts, so a point must not become certain.
- drop: `prune` removes points not seen for more than max_age scans, points behind the sensor (x_sensor <= 0)
  and points farther than max_range. Whenever the map is over capacity (after `add`), the stalest points go
  first: smallest last_seen, then fewest hits, then oldest id.

All randomness comes from the Generator given at construction (default: SeedSequence(0)), so the same inputs
give the same map. The arrays exposed (points, covariances, last_seen, hits, ids) are read-only views of the
map's own preallocated arrays (capacity plus one scan's most new points), valid with the indices into them until
the next add/prune, which move points within those arrays (copy what must outlive them). The bookkeeping of
add and prune is compiled (`map_kernels`).

Checked by: tests/estimator/test_local_map.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator import map_kernels
from rodo.estimator.errors import InputError, check_finite


def _int_arg(name: str, value) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise InputError(f"{name}: expected an integer, got {value!r}")
    return int(value)


def _voxel_keys(p: np.ndarray, voxel: float) -> np.ndarray:
    return np.floor(p / voxel).astype(np.int64)


class LocalMap:
    """A bounded set of world points with last-seen scan, hit count and stable ids."""

    def __init__(self, capacity: int = 1500, max_age: int = 30, voxel: float = 0.0,
                 rng: np.random.Generator | None = None, *, max_new_fraction: float = 0.5):
        """Args:
            capacity: maximum number of points (paper: 1500).
            max_age: a point not seen for more than this many scans is dropped by `prune`.
            voxel: edge (m) of the voxels used to thin new points; 0 disables voxel thinning.
            rng: Generator for the random choices (default seeded from SeedSequence(0)).
            max_new_fraction: at most this fraction of `capacity` is added per scan.
        """
        self.max_age = _int_arg("max_age", max_age)
        if self.max_age < 0:
            raise InputError(f"max_age: must be >= 0, got {max_age}")
        self.voxel = float(check_finite("voxel", voxel))
        if self.voxel < 0:
            raise InputError(f"voxel: must be >= 0, got {voxel}")
        self._max_new_fraction = float(check_finite("max_new_fraction", max_new_fraction))
        if not 0.0 < self._max_new_fraction <= 1.0:
            raise InputError(f"max_new_fraction: must be in (0, 1], got {max_new_fraction}")
        if rng is None:
            rng = np.random.default_rng(np.random.SeedSequence(0))
        if not isinstance(rng, np.random.Generator):
            raise InputError(f"rng: expected a numpy.random.Generator or None, got {type(rng).__name__}")
        self._rng = rng
        self._points = np.zeros((0, 3))
        self._cov = np.zeros((0, 3, 3))
        self._last_seen = np.zeros(0, dtype=np.int64)
        self._hits = np.zeros(0, dtype=np.int64)
        self._ids = np.zeros(0, dtype=np.int64)
        self._n = 0  # the points are the first _n rows
        self._next_id = 0
        self.capacity = capacity  # sizes the arrays

    @property
    def max_new_fraction(self) -> float:
        """At most this fraction of the capacity is added per scan (fixed at construction)."""
        return self._max_new_fraction

    @property
    def capacity(self) -> int:
        return self._capacity

    @capacity.setter
    def capacity(self, value: int) -> None:
        """A new capacity, also after points were added (a multi-radar rig scales it with its radars): the arrays
        grow to hold it and one scan's most new points; over a smaller one the stalest go at the next add.

        Checked by: tests/estimator/test_local_map.py::test_compiled_map_equals_the_numpy_reference
        """
        value = _int_arg("capacity", value)
        if value < 1:
            raise InputError(f"capacity: must be >= 1, got {value}")
        self._capacity = value
        self._max_new = max(1, int(self.max_new_fraction * value))
        rows = value + self._max_new  # the most an add holds before it drops the excess (the kernel relies on it)
        if rows > len(self._points):
            for name in ("_points", "_cov", "_last_seen", "_hits", "_ids"):
                old = getattr(self, name)
                new = np.zeros((rows,) + old.shape[1:], old.dtype)
                new[:self._n] = old[:self._n]
                setattr(self, name, new)

    def cleared(self) -> "LocalMap":
        """An empty map with the same settings that continues this map's random stream (a re-initialisation).

        Checked by: tests/estimator/test_local_map.py::test_cleared_map_continues_the_random_stream
        """
        return LocalMap(self.capacity, self.max_age, self.voxel, rng=self._rng,
                        max_new_fraction=self.max_new_fraction)

    def _view(self, a: np.ndarray) -> np.ndarray:
        v = a[:self._n]
        v.flags.writeable = False
        return v

    @property
    def points(self) -> np.ndarray:
        """(m, 3) world coordinates."""
        return self._view(self._points)

    @property
    def last_seen(self) -> np.ndarray:
        """(m,) scan index at which each point was last added or associated."""
        return self._view(self._last_seen)

    @property
    def hits(self) -> np.ndarray:
        """(m,) number of scans that added or associated each point."""
        return self._view(self._hits)

    @property
    def ids(self) -> np.ndarray:
        """(m,) stable ids (never reused), e.g. for visualisation."""
        return self._view(self._ids)

    def __len__(self) -> int:
        return self._n

    @property
    def covariances(self) -> np.ndarray:
        """(m, 3, 3) world-frame covariance of each point at insertion (zeros when none was given)."""
        return self._view(self._cov)

    def add(self, p_world, scan: int, covariances=None) -> None:
        """Insert new world points (thinned as in the module docstring), then enforce the capacity.

        Args:
            p_world: (k, 3) new points in world coordinates (the caller's array is not modified).
            scan: the current scan index.
            covariances: optional (k, 3, 3) world-frame covariances of the points (kept with them).

        Checked by: tests/estimator/test_local_map.py::test_capacity_and_stalest_dropped_first,
            ::test_one_scan_cannot_flush_the_map, ::test_voxel_thinning
        """
        p = check_finite("p_world", p_world, (3,))
        if p.ndim != 2:
            raise InputError(f"p_world: expected shape (k, 3), got {p.shape}")
        scan = _int_arg("scan", scan)
        if len(p) == 0:
            if self._n > self.capacity:  # over a lowered capacity: the stalest go now
                self._append(p, np.zeros((0, 3, 3)), scan)
            return
        cov = np.zeros((len(p), 3, 3)) if covariances is None else check_finite("covariances", covariances, (3, 3))
        if cov.shape != (len(p), 3, 3):
            raise InputError(f"covariances: expected shape ({len(p)}, 3, 3), got {cov.shape}")
        if self.voxel > 0:
            order = self._rng.permutation(len(p))          # random representative per voxel
            keys = _voxel_keys(p[order], self.voxel)
            _, first = np.unique(keys, axis=0, return_index=True)
            sel = order[np.sort(first)]
            if len(self):
                occupied = _voxel_keys(self._points[:self._n], self.voxel)
                both = np.concatenate([occupied, _voxel_keys(p[sel], self.voxel)])
                _, inv = np.unique(both, axis=0, return_inverse=True)
                inv = inv.ravel()
                taken = np.zeros(inv.max() + 1, dtype=bool)
                taken[inv[:len(occupied)]] = True
                sel = sel[~taken[inv[len(occupied):]]]
            p, cov = p[sel], cov[sel]
        if len(p) > self._max_new:
            sel = np.sort(self._rng.choice(len(p), size=self._max_new, replace=False))
            p, cov = p[sel], cov[sel]
        self._append(p, cov, scan)

    def _append(self, p: np.ndarray, cov: np.ndarray, scan: int) -> None:
        """The compiled append of (k, 3) points and their covariances, then the stalest over capacity dropped."""
        if self._n + len(p) > len(self._points):  # the kernel writes without bounds checks: never past the arrays
            raise RuntimeError(f"LocalMap: {self._n} + {len(p)} points exceed its {len(self._points)} rows")
        self._n = map_kernels.append(self._points, self._cov, self._last_seen, self._hits, self._ids, self._n,
                                     np.ascontiguousarray(p, dtype=float), np.ascontiguousarray(cov, dtype=float),
                                     scan, self._next_id, self.capacity)
        self._next_id += len(p)

    def refresh(self, idx, scan: int) -> None:
        """Mark map points as seen in `scan` (last_seen = scan, hits += 1); positions stay fixed.

        Args:
            idx: (k,) distinct indices into the current map (e.g. Association.map_idx).
            scan: the current scan index.

        Checked by: tests/estimator/test_local_map.py::test_refresh_keeps_points
        """
        scan = _int_arg("scan", scan)
        idx = np.asarray(idx)
        if idx.size == 0:
            return
        if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
            raise InputError(f"idx: expected a 1-D integer array, got dtype {idx.dtype} shape {idx.shape}")
        if idx.min() < 0 or idx.max() >= len(self):
            raise InputError(f"idx: indices must be in [0, {len(self)}), got range [{idx.min()}, {idx.max()}]")
        seen = np.zeros(len(self), bool)
        seen[idx] = True  # distinct: as many points marked as indices given (a mark, not a sort)
        if np.count_nonzero(seen) != len(idx):
            raise InputError("idx: indices must be distinct")
        self._last_seen[idx] = scan
        self._hits[idx] += 1

    def fuse(self, idx, z_world, R_world, scan: int, max_fused: int = 0) -> None:
        """Refresh map points (as `refresh`) and refine their positions with new observations of them.

        Args:
            idx: (k,) distinct indices into the current map.
            z_world: (k, 3) the associated detections in world coordinates (placed with the estimate).
            R_world: (k, 3, 3) their world-frame covariances (positive definite).
            scan: the current scan index.
            max_fused: N > 1: fading memory of about N observations (module docstring); 0: no fading.

        A point added without a covariance (zeros) is treated as exact and does not move.

        Checked by: tests/estimator/test_local_map.py::test_fuse_averages_noise_and_shrinks_covariance,
            ::test_fuse_fading_memory_bounds_information
        """
        idx = np.asarray(idx)
        if idx.size == 0:
            return
        z = check_finite("z_world", z_world, (3,))
        R = check_finite("R_world", R_world, (3, 3))
        if z.shape != (len(idx), 3) or R.shape != (len(idx), 3, 3):
            raise InputError(f"z_world, R_world: expected shapes ({len(idx)}, 3), ({len(idx)}, 3, 3), "
                             f"got {z.shape}, {R.shape}")
        max_fused = _int_arg("max_fused", max_fused)
        if max_fused < 0 or max_fused == 1:
            raise InputError(f"max_fused: must be 0 (no fading) or >= 2, got {max_fused}")
        self.refresh(idx, scan)  # checks idx and scan; hits now counts this observation too
        P = self._cov[idx]
        if max_fused:
            n = self._hits[idx] - 1  # observations already in the point
            fade = np.where(n >= max_fused, (max_fused - 1) / max_fused, 1.0)
            P = P / fade[:, None, None]
        K = P @ np.linalg.inv(P + R)
        self._points[idx] = self._points[idx] + np.einsum("kij,kj->ki", K, z - self._points[idx])
        P = P - K @ P
        self._cov[idx] = 0.5 * (P + np.swapaxes(P, 1, 2))

    def prune(self, scan: int, T_vehicle_world, T_vehicle_sensor, max_range: float, behind: bool = True) -> None:
        """Drop points unseen for more than max_age scans, behind the sensor (x_s <= 0; unless behind=False: a
        vehicle with several radars), or beyond max_range.

        Args:
            scan: the current scan index.
            T_vehicle_world: (4, 4) current pose estimate.
            T_vehicle_sensor: (4, 4) extrinsics.
            max_range: m, > 0.

        Checked by: tests/estimator/test_local_map.py::test_prune
        """
        scan = _int_arg("scan", scan)
        T_vehicle_world = check_finite("T_vehicle_world", T_vehicle_world, (4, 4))
        T_vehicle_sensor = check_finite("T_vehicle_sensor", T_vehicle_sensor, (4, 4))
        if T_vehicle_world.shape != (4, 4) or T_vehicle_sensor.shape != (4, 4):
            raise InputError("T_vehicle_world, T_vehicle_sensor: expected single (4, 4) poses")
        max_range = float(check_finite("max_range", max_range))
        if max_range <= 0:
            raise InputError(f"max_range: must be > 0, got {max_range}")
        if len(self) == 0:
            return
        # p_v = T_vehicle_world p, p_s = C_vs^T (p_v - r_vs): kept when seen within max_age, |p_s| <= max_range
        # and (behind) x_s > 0
        self._n = map_kernels.prune(self._points, self._cov, self._last_seen, self._hits, self._ids, self._n, scan,
                                    self.max_age, np.ascontiguousarray(T_vehicle_world),
                                    np.ascontiguousarray(T_vehicle_sensor), max_range, behind)
