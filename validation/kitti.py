"""The KITTI odometry metric, computed exactly as the devkit's `calcSequenceErrors` does (Geiger et al. 2012).

For every first frame f = 0, step, 2 step, ... and every length L (default 100, 200, ..., 800 m): the last frame
l is the first one whose ground-truth path distance exceeds dist[f] + L (strictly); the error pose is
E = inv(inv(est_f) est_l) (inv(gt_f) gt_l); the translational error is |t(E)| / L and the rotational error
angle(E) / L with angle = acos(clip((trace(R) - 1) / 2)). The reported numbers are the plain means over all
(f, L) pairs pooled: translational in %, rotational in deg/m.

Poses are T_world_vehicle (4x4), ground truth and estimate at the same frames.

Checked by: tests/validation/test_kitti.py (a hand-checked case and an independent brute-force implementation)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rodo.estimator.errors import InputError

LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


@dataclass
class KittiResult:
    t_err_pct: float  # mean translational error, %
    r_err_deg_per_m: float  # mean rotational error, deg/m
    segments: np.ndarray  # (k, 4): first frame, length, t_err (fraction), r_err (rad/m)

    @property
    def n_segments(self) -> int:
        return len(self.segments)

    def per_length(self) -> dict[float, tuple[float, float, int]]:
        """length -> (t_err %, r_err deg/m, count)."""
        out = {}
        for L in np.unique(self.segments[:, 1]):
            s = self.segments[self.segments[:, 1] == L]
            out[float(L)] = (float(s[:, 2].mean() * 100), float(np.rad2deg(s[:, 3].mean())), len(s))
        return out


def trajectory_distances(T_world_vehicle: np.ndarray) -> np.ndarray:
    """Cumulative path length along the positions (the devkit's trajectoryDistances)."""
    p = T_world_vehicle[:, :3, 3]
    return np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]


def _rotation_angle(R: np.ndarray) -> np.ndarray:
    d = 0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0)
    return np.arccos(np.clip(d, -1.0, 1.0))


def kitti_errors(gt: np.ndarray, est: np.ndarray, lengths=LENGTHS, step: int = 10) -> KittiResult:
    """Devkit-exact KITTI errors of `est` against `gt`, both (N, 4, 4) T_world_vehicle at the same frames.

    Returns a KittiResult; when the trajectory is shorter than every length, the means are NaN and
    `segments` is empty (the caller decides what to report).
    """
    gt = np.asarray(gt, dtype=float)
    est = np.asarray(est, dtype=float)
    if gt.shape != est.shape or gt.ndim != 3 or gt.shape[1:] != (4, 4):
        raise InputError(f"gt, est: expected matching (N, 4, 4) poses, got {gt.shape} and {est.shape}")
    if not (np.all(np.isfinite(gt)) and np.all(np.isfinite(est))):
        raise InputError("gt, est: poses contain NaN or infinity")
    if step < 1:
        raise InputError(f"step: must be >= 1, got {step}")
    dist = trajectory_distances(gt)
    firsts = np.arange(0, len(gt), step)
    rows = []
    inv = np.linalg.inv
    for L in lengths:
        # last = first index with dist > dist[first] + L (strict), vectorised over first frames
        last = np.searchsorted(dist, dist[firsts] + L, side="right")
        ok = last < len(gt)
        f, l = firsts[ok], last[ok]
        if len(f) == 0:
            continue
        d_gt = inv(gt[f]) @ gt[l]
        d_est = inv(est[f]) @ est[l]
        E = inv(d_est) @ d_gt
        t_err = np.linalg.norm(E[:, :3, 3], axis=1) / L
        r_err = _rotation_angle(E[:, :3, :3]) / L
        rows.append(np.c_[f, np.full(len(f), L), t_err, r_err])
    if not rows:
        return KittiResult(float("nan"), float("nan"), np.zeros((0, 4)))
    seg = np.concatenate(rows)
    seg = seg[np.lexsort((seg[:, 1], seg[:, 0]))]  # the devkit's order: by first frame, then length
    return KittiResult(float(seg[:, 2].mean() * 100), float(np.rad2deg(seg[:, 3].mean())), seg)
