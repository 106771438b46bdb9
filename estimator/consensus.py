"""Which Doppler consensus is the world: the one that fills space (the odometry's consensus switch).

A truck may fill the radar's view and outnumber the static world for seconds, but it is one compact object;
the world is spread over the scene. The space a set of detections covers is its support: the number of
voxels (edge `association.consensus_voxel`, 2 m) it occupies. Measured on the simulator's labels, a blockage
truck covers 4-6 voxels against 50-170 for the world, and the lead truck on `highway` at most 8 % of the world.

- `ConsensusSwitch.outvoted`: when the estimate has locked onto a co-moving object (nothing else in view for a
  while), the world comes back as a consensus far from the prediction; when the largest consensus among the
  detections called moving has covered `association.consensus_switch_ratio` (3) times the space of ours for
  `association.consensus_switch_after` (0.5 s) of scans, the odometry re-initialises on it.
- `ConsensusSwitch.widest`: the fit to start from (initialisation, the free-RANSAC fallback): the largest
  consensus, or a wider one.
- `moving_voxels`: the same voxels against the opposite mistake, a dense group that starts to move inside every
  detection's gate (a queue of cars moving off, more detections than the world): the world's velocity fitted
  with each voxel counted once, and the voxels whose mean radial velocity disagrees with it as a group.

Counting detections instead (the first version) took a lead truck that outnumbered the guard rails 1.5:1 on
`highway`. The fits of this module draw from their own random stream.

Checked by: tests/estimator/test_odometry.py::test_locked_onto_a_co_moving_object_the_world_is_taken_back,
    ::test_a_compact_object_outnumbering_the_world_is_not_taken, ::test_support_counts_the_occupied_voxels,
    tests/estimator/test_moving_groups.py
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import doppler_kernels
from .config import AssociationConfig
from .ego_velocity import PLANAR_ELEVATION, EgoVelocity, estimate_ego_velocity
from .measurements import polar_to_cartesian

MIN_STATIC = 8  # fewest detections a consensus needs; fewer static detections: the odometry's Doppler
# classification falls back to RANSAC


def voxel_keys(p: np.ndarray, voxel: float) -> np.ndarray:
    """(n,) int64 key of each point's voxel (edge `voxel` m)."""
    k = np.clip(np.floor(p / voxel).astype(np.int64), -(1 << 20), (1 << 20) - 1) + (1 << 20)  # 21 bits each
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


def support(p: np.ndarray, voxel: float) -> int:
    """The space a set of points covers: the number of distinct voxels (edge `voxel` m) they occupy."""
    return len(np.unique(voxel_keys(p, voxel))) if len(p) else 0


@dataclasses.dataclass(frozen=True)
class Voxels:
    """A scan's points by voxel (edge `voxel` m), found once per scan for every check of the scan: `index` (n,)
    numbers each point's voxel 0..K-1, `counts` (K,) the points in each.

    Checked by: tests/estimator/test_moving_groups.py::test_voxels_of_a_scan_give_the_support_of_any_subset
    """

    index: np.ndarray
    counts: np.ndarray

    @classmethod
    def of(cls, p: np.ndarray, voxel: float) -> "Voxels":
        return cls(*doppler_kernels.voxel_index(np.ascontiguousarray(p, dtype=float).reshape(-1, 3), float(voxel)))

    def support(self, rows: np.ndarray) -> int:
        """`support` of the points p[rows] (a mask or indices), counted from the voxels found already."""
        return int(np.count_nonzero(np.bincount(self.index[rows], minlength=len(self.counts))))


def moving_voxels(pts, u, vr, var, gated, voxel: float, z: float, margin: float, max_residual: float,
                  min_points: int = 5, voxels: Voxels | None = None) -> np.ndarray:
    """(n,) mask of the detections in voxels that move slowly against the world: as a group their Doppler
    disagrees with it, though each detection alone may be inside its gate. An object that starts to move (a
    queue of cars moving off) stays inside every detection's gate for a few scans, and as one dense group
    outweighs the world in a fit that counts detections.

    The world's sensor velocity is fitted to the `gated` detections (those near the prediction) with each voxel
    (edge `voxel`) weighted as one, so a dense object counts as much as one voxel of the world. Per voxel of all
    detections, the mean residual r against that fit, with variance sum(var) / n^2 (var: each detection's
    radial-velocity variance, angle noise seen through the velocity included); flagged when
    z sqrt(variance) + margin < |r| <= max_residual and the voxel holds min_points. Nothing is flagged when the
    flagged voxels would be half the gated voxels or more, or when the world's fit is degenerate. u: (n, 3)
    directions, vr: (n,) radial velocities; voxels: `Voxels.of(pts, voxel)` when the caller has it. Compiled
    (`doppler_kernels.moving_voxels`: the weighted fit by its normal equations).
    """
    out = np.empty(len(vr), bool)
    voxels = Voxels.of(pts, voxel) if voxels is None else voxels
    doppler_kernels.moving_voxels(np.ascontiguousarray(u, dtype=float), np.ascontiguousarray(vr, dtype=float),
                                  np.ascontiguousarray(var, dtype=float), np.ascontiguousarray(gated, dtype=bool),
                                  voxels.index, voxels.counts, float(z), float(margin), float(max_residual),
                                  int(min_points), float(np.sin(PLANAR_ELEVATION)), out)
    return out


class ConsensusSwitch:
    """The consensus checks of one odometry run: its configuration, radial-velocity sigma and random stream,
    and the count of consecutive scans in which a wider consensus than ours was seen."""

    def __init__(self, config: AssociationConfig, sigma_vr: float, rng: np.random.Generator):
        self.config = config
        self.sigma_vr = float(sigma_vr)
        self.rng = rng
        self.outvoted_scans = 0

    def wider(self, az, el, vr, threshold, taken: np.ndarray, pts: np.ndarray,
              voxels: Voxels | None = None) -> np.ndarray | None:
        """The largest Doppler consensus among the detections outside `taken` (a mask), if it covers
        `consensus_switch_ratio` times the space `taken` covers; else None. pts: the detections' positions;
        voxels: `Voxels.of(pts, consensus_voxel)` when the caller has it."""
        cfg = self.config
        rest = np.flatnonzero(~taken)
        if len(rest) < MIN_STATIC:
            return None
        voxels = Voxels.of(pts, cfg.consensus_voxel) if voxels is None else voxels
        need = cfg.consensus_switch_ratio * max(voxels.support(taken), 1)
        if voxels.support(rest) < need:  # no subset of the rest can cover enough
            return None
        free = estimate_ego_velocity(az[rest], el[rest], vr[rest], self.rng, sigma_vr=self.sigma_vr,
                                     threshold=None if np.ndim(threshold) == 0 else threshold[rest])
        if not free.ok or free.inliers.sum() < MIN_STATIC \
                or voxels.support(rest[free.inliers]) < need:
            return None
        mask = np.zeros(len(vr), bool)
        mask[rest[free.inliers]] = True
        return mask

    def outvoted(self, az, el, vr, threshold, ours: np.ndarray, pts: np.ndarray, scan_dt: float,
                 voxels: Voxels | None = None):
        """The wider consensus (a mask) once one has been seen for `consensus_switch_after` seconds of scans in
        a row (scan_dt: the time between scans), else None. Disabled when that time is 0."""
        after = self.config.consensus_switch_after
        mask = None if after <= 0 else self.wider(az, el, vr, threshold, ours, pts, voxels)
        self.outvoted_scans = 0 if mask is None else self.outvoted_scans + 1
        if mask is not None and self.outvoted_scans >= max(int(np.ceil(after / max(scan_dt, 1e-3))), 1):
            self.outvoted_scans = 0
            return mask
        return None

    def widest(self, polar: np.ndarray, rng: np.random.Generator, threshold=None) -> EgoVelocity:
        """The largest consensus of a scan (polar (n, 4); its RANSAC draws from `rng`), or a `wider` one than
        it, refitted. With the switch disabled, simply the largest."""
        az, el, vr = polar[:, 1], polar[:, 2], polar[:, 3]
        ego = estimate_ego_velocity(az, el, vr, rng, sigma_vr=self.sigma_vr, threshold=threshold)
        if not ego.ok or self.config.consensus_switch_after <= 0:
            return ego
        mask = self.wider(az, el, vr, threshold, ego.inliers, polar_to_cartesian(polar))
        if mask is None:
            return ego
        fit = estimate_ego_velocity(az[mask], el[mask], vr[mask], self.rng, sigma_vr=self.sigma_vr,
                                    threshold=None if np.ndim(threshold) == 0 else threshold[mask])
        if not fit.ok:
            return ego
        inliers = np.zeros(len(polar), bool)
        inliers[np.flatnonzero(mask)[fit.inliers]] = True
        return dataclasses.replace(fit, inliers=inliers)
