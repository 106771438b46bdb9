"""What the odometry returns per scan: the newest estimate (`ScanEstimate`) and, for visual debugging, the
association detail behind it (`ScanDetail`). Typed end to end: `RadarOdometry.process` builds them, the
driver keeps them, `rodo.viz.recording.record_run` draws them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rodo.estimator.errors import InputError, check_finite
from rodo.estimator.lie import se3


@dataclass
class ScanDetail:
    """Per-scan association detail (kept when the odometry runs with `record_detail=True`).

    Attributes:
        polar: (n, 4) detections [range, azimuth, elevation, radial_velocity] in the sensor frame, as the
            estimator used them (after its range filter).
        static: (n,) bool, True where the Doppler test kept the detection as static.
        det_idx: (k,) int, associated detections, indices into `polar` (not into polar[static]).
        map_idx: (k,) int, their map points, indices into `map_points`.
        map_points: (m, 3) the local map in the estimator's world frame at association time (before the
            map update of this scan).
        rows: (n,) int indices of the detections in the scan's rows (radar.csv order), used to look up the
            truth labels; None means polar is the whole scan in its original order.

    Checked by: tests/viz/test_recording.py::test_scan_detail_rejects_inconsistent_input
    """

    polar: np.ndarray
    static: np.ndarray
    det_idx: np.ndarray
    map_idx: np.ndarray
    map_points: np.ndarray
    rows: np.ndarray | None = None

    def __post_init__(self):
        self.polar = check_finite("ScanDetail.polar", self.polar, (4,)).reshape(-1, 4)
        n = len(self.polar)
        self.static = np.asarray(self.static, dtype=bool).reshape(-1)
        if len(self.static) != n:
            raise InputError(f"ScanDetail.static: expected {n} flags, got {len(self.static)}")
        self.map_points = check_finite("ScanDetail.map_points", self.map_points, (3,)).reshape(-1, 3)
        self.det_idx = np.asarray(self.det_idx, dtype=np.int64).reshape(-1)
        self.map_idx = np.asarray(self.map_idx, dtype=np.int64).reshape(-1)
        if len(self.det_idx) != len(self.map_idx):
            raise InputError(f"ScanDetail.det_idx, map_idx: lengths differ ({len(self.det_idx)} vs "
                             f"{len(self.map_idx)})")
        for name, idx, size in (("det_idx", self.det_idx, n), ("map_idx", self.map_idx, len(self.map_points))):
            if len(idx) and (idx.min() < 0 or idx.max() >= size):
                raise InputError(f"ScanDetail.{name}: indices must lie in [0, {size}), got {idx.min()}..{idx.max()}")
        if self.rows is not None:
            self.rows = np.asarray(self.rows, dtype=np.int64).reshape(-1)
            if len(self.rows) != n:
                raise InputError(f"ScanDetail.rows: expected {n} indices, got {len(self.rows)}")


@dataclass
class ScanEstimate:
    """The newest estimate after one scan.

    Attributes:
        t: scan time (s).
        T_vehicle_world: (4, 4) pose.
        varpi: (6,) body velocity [nu; omega].
        varpi_dot: (6,) body acceleration, or None for the constant-velocity prior.
        P: (18, 18) CA or (12, 12) CV posterior covariance of the newest state (left perturbation, order
            [pose; velocity; acceleration]).
        n_detections, n_static, n_associated: counts of this scan (after the range filter).
        nis: mean normalised innovation squared of the accepted associations (per pair, dof 4).
        timings: seconds per stage (predict, associate, solve, map).
        events: what happened besides the ordinary step (initialisation, Doppler fallbacks, ...).
        detail: the association detail, with `record_detail`.
        standstill: the zero-velocity term was applied (the Doppler says the sensor is at rest).
        P_relative: (6, 6) covariance of the relative pose since the previous scan, delta = xi_k - Ad(R_k)
            xi_{k-1} (`rodo.estimator.uncertainty.relative_pose_covariance`, the window's two newest states),
            times `uncertainty.inflation`.
        P_revision: (6, 6) what this scan's revision of the previous pose adds to P_relative for the relative
            pose between the two EMITTED poses (`uncertainty.revision_covariance`), times the same factor.
        P_pose_absolute: (6, 6) pose covariance in the estimator's world (its first frame), composed from the
            relative ones: it grows as the drift does (P's pose block is relative to the local map).
        map_reuse: mean number of scans the associated map points have been associated in (NaN: none).
        doppler_nis: the scan's Doppler velocity against the prediction, NIS per dof (`DopplerFrontEnd.correct`;
            NaN without a prediction or a Doppler fit).
        pose_pull: the scan's pull on its solved pose, per dof (`rodo.estimator.pull`; NaN with fewer than
            six pairs): how far its pairs alone would move the pose, in their own information.
        velocity_lag: (6,) the velocity's bias behind a manoeuvre b = L a (`rodo.estimator.velocity_lag`), whose
            b b^T P's velocity block holds; zeros without `uncertainty.velocity_lag_*`.
        restarted: the odometry re-initialised at this scan (after an outage, or on the consensus switch):
            P_relative is the dead-reckoned step from the last estimate (`uncertainty.restart_matrices`).
    """

    t: float
    T_vehicle_world: np.ndarray
    varpi: np.ndarray
    varpi_dot: np.ndarray | None
    P: np.ndarray
    n_detections: int
    n_static: int
    n_associated: int
    nis: float
    timings: dict = field(default_factory=dict)
    events: list = field(default_factory=list)
    detail: ScanDetail | None = None
    standstill: bool = False
    P_relative: np.ndarray | None = None
    P_revision: np.ndarray | None = None
    P_pose_absolute: np.ndarray | None = None
    map_reuse: float = float("nan")
    doppler_nis: float = float("nan")
    pose_pull: float = float("nan")
    restarted: bool = False
    velocity_lag: np.ndarray = field(default_factory=lambda: np.zeros(6))

    @property
    def T_world_vehicle(self) -> np.ndarray:
        return se3.inverse(self.T_vehicle_world)
