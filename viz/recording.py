"""Rerun recordings of an odometry run: `record_run(path, seq, result, truth=None, detail=None)`.

Every recording is written through its own `rr.RecordingStream` (never the global stream), so Monte Carlo
workers can each write a file. rerun is imported inside the functions only: `rodo run` without `--rerun`
never loads it. Entity paths, colours and what each plot means: docs/visualisation.md.

Timelines: `frame` (scan index k of the run) and `time` (scan time, a duration in seconds).

viz only draws: the truth's time association and alignment, the errors, NEES and bounds, and the covariance
ellipsoids are computed by `rodo.validation` (association, alignment, metrics, consistency, covariance).

Checked by: tests/viz/test_recording.py (recordings read back with rerun.chunk.RrdReader)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError, check_finite
from rodo.estimator.lie import se3, so3
from rodo.estimator.measurements import polar_to_cartesian
from rodo.estimator.scan import ScanDetail
from rodo.validation.alignment import align_to_first
from rodo.validation.association import match_index
from rodo.validation.consistency import NIS_DOF, chi2_bounds
from rodo.validation.covariance import covariance_ellipsoid, position_covariance_world
from rodo.validation.metrics import pose_errors
from rodo.validation.run_consistency import run_states

from .recording_metrics import ELLIPSOID_SIGMA, log_consistency, send_series
from .rrd_file import recording_file
from .sequence_layers import log_sequence_layers, sequence_blueprint

# class ids of detections (AnnotationContext on `world`): label, RGB
DETECTION_CLASSES = {
    0: ("associated", (40, 200, 60)),
    1: ("static, not associated (gated out)", (240, 180, 0)),
    2: ("rejected as moving", (230, 40, 40)),
    3: ("clutter (truth)", (160, 80, 220)),
    4: ("detection (no association detail)", (120, 170, 255)),
    5: ("static (truth)", (200, 200, 200)),
    6: ("moving (truth)", (255, 120, 0)),
}
TRUTH_CLUTTER = 3  # sim label of a false alarm (0 static surface, 1 static point, 2 moving, 3 clutter)
TRUTH_MOVING = 2
ESTIMATE_COLOUR = (40, 120, 255)
TRUTH_COLOUR = (20, 20, 20)
VELOCITY_NAMES = ("nu_x (m/s)", "nu_y (m/s)", "nu_z (m/s)", "omega_x (rad/s)", "omega_y (rad/s)",
                  "omega_z (rad/s)")
ACCEL_NAMES = ("nu_dot_x (m/s^2)", "nu_dot_y (m/s^2)", "nu_dot_z (m/s^2)", "omega_dot_x (rad/s^2)",
               "omega_dot_y (rad/s^2)", "omega_dot_z (rad/s^2)")


def detection_classes(detail: ScanDetail, labels: np.ndarray | None = None) -> np.ndarray:
    """Class id per detection (DETECTION_CLASSES): associated 0, gated out 1, moving 2; clutter 3 when the
    truth labels (n,) are given (it overrides the status)."""
    cls = np.where(detail.static, 1, 2).astype(np.uint16)
    cls[detail.det_idx] = 0
    if labels is not None:
        cls[np.asarray(labels) == TRUTH_CLUTTER] = 3
    return cls


class _Truth:
    """Ground truth matched to the estimates (`validation.association.match_index`) and aligned to the first
    matched estimate (`validation.alignment.align_to_first`): poses T_world_vehicle (N, 4, 4; NaN where
    missing), varpi and varpi_dot (N, 6), and per-scan detection labels when the simulator's truth dict is
    given."""

    def __init__(self, seq, result, truth: dict | None):
        n = len(result.t)
        self.T_world_vehicle = None
        self.varpi = self.varpi_dot = None
        self.labels = None
        if truth is not None:
            for key in ("t", "T_vehicle_world"):
                if key not in truth:
                    raise InputError(f"truth: missing key {key!r} (expected the dict of sim.simulate)")
            t_truth = np.asarray(truth["t"], dtype=float)
            T_world_vehicle = se3.inverse(check_finite("truth['T_vehicle_world']", truth["T_vehicle_world"], (4, 4)))
        elif seq.groundtruth is not None and len(seq.groundtruth.t):
            t_truth = np.asarray(seq.groundtruth.t, float)
            T_world_vehicle = np.asarray(seq.groundtruth.T_world_vehicle, float)
        else:
            return
        idx = match_index(result.t, t_truth)
        self.index = idx
        ok = idx >= 0
        if not ok.any():
            return
        first = int(np.argmax(ok))
        self.T_world_vehicle = np.full((n, 4, 4), np.nan)
        self.T_world_vehicle[ok] = align_to_first(T_world_vehicle[idx[ok]], result.estimates[first].T_world_vehicle)
        if truth is not None:
            self.varpi = self._matched(truth, "varpi", idx)
            self.varpi_dot = self._matched(truth, "varpi_dot", idx)
            if "det_label" in truth and "scan_offsets" in truth:
                self._labels = np.asarray(truth["det_label"])
                self._offsets = np.asarray(truth["scan_offsets"], dtype=np.int64)
                self.labels = True

    @staticmethod
    def _matched(truth: dict, key: str, idx: np.ndarray) -> np.ndarray | None:
        """truth[key] (M, 6) at the matched rows, NaN where a scan has no truth; None when the key is absent."""
        if key not in truth:
            return None
        out = np.full((len(idx), 6), np.nan)
        out[idx >= 0] = np.asarray(truth[key], float)[idx[idx >= 0]]
        return out

    def truth_dict(self, t: np.ndarray, ok: np.ndarray) -> dict:
        """The matched truth at the scans `ok` as a truth.npz-like dict (t, T_vehicle_world; varpi and
        varpi_dot when known, else NaN velocities), for `validation.run_consistency.scan_measures`."""
        out = {"t": np.asarray(t, dtype=float)[ok], "T_vehicle_world": se3.inverse(self.T_world_vehicle[ok])}
        out["varpi"] = self.varpi[ok] if self.varpi is not None else np.full((int(ok.sum()), 6), np.nan)
        if self.varpi_dot is not None:
            out["varpi_dot"] = self.varpi_dot[ok]
        return out

    def scan_labels(self, k: int, n_rows: int) -> np.ndarray | None:
        """Truth labels of the rows of scan k (radar.csv order), None when unknown or inconsistent."""
        if not self.labels or self.index[k] < 0:
            return None
        j = self.index[k]
        lab = self._labels[self._offsets[j]:self._offsets[j + 1]]
        return lab if len(lab) == n_rows else None


def _log_world(rec, rr) -> None:
    """`world`: RIGHT_HAND_Z_UP and the detection classes (static)."""
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log("world", rr.AnnotationContext([(i, label, colour) for i, (label, colour) in DETECTION_CLASSES.items()]),
            static=True)


def _log_frames(rec, rr, seq) -> None:
    """The extrinsic T_vehicle_sensor under `world/vehicle/sensor` (static, logged once) and the axes of
    `world/vehicle`."""
    T_vehicle_sensor = np.asarray(seq.sensor.T_vehicle_sensor, dtype=float)
    rec.log("world/vehicle/sensor", rr.Transform3D(translation=T_vehicle_sensor[:3, 3],
                                                   quaternion=so3.to_quaternion(T_vehicle_sensor[:3, :3])),
            rr.TransformAxes3D(axis_length=0.8), static=True)
    rec.log("world/vehicle", rr.TransformAxes3D(axis_length=2.0), static=True)


def _log_series(rec, rr, result, truth: _Truth, frames, times) -> set[str]:
    """All the time series; returns the tab origins that got data."""
    est = result.estimates
    n = len(est)
    logged = set()

    def send(tab, path, values, names, colours=None):
        if send_series(rec, rr, path, frames, times, values, names, colours):
            logged.add(tab)

    grey, blue, black = (150, 150, 150), ESTIMATE_COLOUR, TRUTH_COLOUR
    varpi = np.stack([e.varpi for e in est])
    if truth.T_world_vehicle is not None:
        err = pose_errors(np.stack([e.T_world_vehicle for e in est]), truth.T_world_vehicle)
        send("metrics/error", "metrics/error/translation", err.translation[:, None], ["translation error (m)"])
        send("metrics/error", "metrics/error/rotation", err.rotation_deg[:, None], ["rotation error (deg)"])
        send("metrics/drift", "metrics/drift", err.drift, ["x drift (m)", "y drift (m)", "z drift (m)"],
             [(220, 50, 50), (40, 170, 40), (40, 90, 230)])
        ok = np.all(np.isfinite(truth.T_world_vehicle.reshape(n, -1)), axis=1)
        if ok.sum() >= 2:  # odometry_nees needs two matched scans
            logged |= log_consistency(rec, rr, run_states(result), truth.truth_dict(result.t, ok), frames, times,
                                      truth.T_world_vehicle[:, :3, 3])
    nis = np.array([e.nis for e in est], dtype=float)
    n_assoc = np.array([e.n_associated for e in est])
    bounds = chi2_bounds(n_assoc, NIS_DOF)
    send("metrics/nis", "metrics/nis", np.c_[nis, bounds], ["mean NIS per pair (4 dof)", "2.5 % bound",
                                                            "97.5 % bound"], [blue, grey, grey])
    # the scan's Doppler velocity against the prediction (`DopplerFrontEnd.correct`): high where the prior's
    # model is wrong (a start, a turn's onset), which `velocity_inflation_per_doppler` turns into velocity variance
    send("metrics/nis", "metrics/nis/doppler", np.array([e.doppler_nis for e in est], dtype=float),
         ["Doppler velocity against the prediction, NIS per dof"], [(220, 120, 0)])
    # the scan's pull on its solved pose (`pose_pull`): high where scan and map disagree as a rigid body, which
    # `inflation_per_pull` turns into relative pose variance
    send("metrics/nis", "metrics/nis/pull", np.array([e.pose_pull for e in est], dtype=float),
         ["the scan's pull on its solved pose, per dof"], [(150, 60, 200)])
    counts = np.array([[e.n_detections, e.n_static, e.n_associated] for e in est], dtype=float)
    send("metrics/counts", "metrics/counts", counts, ["detections", "static (Doppler)", "associated"])
    stages = ("predict", "associate", "solve", "map")
    ms = np.c_[result.wall_ms, np.array([[e.timings.get(s, np.nan) * 1e3 for s in stages] for e in est])]
    send("metrics/timing", "metrics/timing", ms, ["total (ms)"] + [f"{s} (ms)" for s in stages])
    varpi_dot = np.stack([e.varpi_dot for e in est]) if all(e.varpi_dot is not None for e in est) else None
    for group, names, e_val, t_val in (("velocity", VELOCITY_NAMES, varpi, truth.varpi),
                                       ("acceleration", ACCEL_NAMES, varpi_dot, truth.varpi_dot)):
        for i, name in enumerate(names):
            cols, labels, colours = [], [], []
            if e_val is not None:
                cols.append(e_val[:, i]), labels.append(f"estimate {name}"), colours.append(blue)
            if t_val is not None:
                cols.append(t_val[:, i]), labels.append(f"truth {name}"), colours.append(black)
            if cols:
                send(group, f"{group}/{name.split(' ')[0]}", np.stack(cols, axis=1), labels, colours)
    return logged


def _log_scans(rec, rr, seq, result, truth: _Truth, detail) -> None:
    """Per frame: the scan in the sensor frame (class ids), the local map, association lines."""
    scans = {float(s.t): s for s in seq.scans}
    for k, e in enumerate(result.estimates):
        rec.set_time("frame", sequence=k)
        rec.set_time("time", duration=float(e.t))
        scan = scans.get(float(e.t))
        d = detail[k] if detail is not None else None
        if d is not None:
            labels = None
            if scan is not None:
                all_labels = truth.scan_labels(k, len(scan))
                if all_labels is not None:
                    rows = d.rows if d.rows is not None else (np.arange(len(d.polar)) if len(d.polar) == len(scan)
                                                                else None)
                    labels = all_labels[rows] if rows is not None else None
            p_sensor = polar_to_cartesian(d.polar)
            rec.log("world/vehicle/sensor/scan",
                    rr.Points3D(p_sensor, class_ids=detection_classes(d, labels), radii=0.15))
            rec.log("world/map", rr.Points3D(d.map_points, colors=[(90, 90, 90)], radii=0.1))
            T_world_sensor = e.T_world_vehicle @ seq.sensor.T_vehicle_sensor
            a = se3.transform_points(T_world_sensor, p_sensor[d.det_idx]) if len(d.det_idx) else np.zeros((0, 3))
            strips = np.stack([a, d.map_points[d.map_idx]], axis=1)
            rec.log("world/associations", rr.LineStrips3D(strips, colors=[(40, 200, 60)], radii=0.03))
        elif scan is not None:
            labels = truth.scan_labels(k, len(scan))
            if labels is None:
                cls = np.full(len(scan), 4, dtype=np.uint16)
            else:
                cls = np.where(labels == TRUTH_CLUTTER, 3, np.where(labels == TRUTH_MOVING, 6, 5)).astype(np.uint16)
            rec.log("world/vehicle/sensor/scan", rr.Points3D(scan.points_sensor, class_ids=cls, radii=0.15))
        if e.events:
            rec.log("events", rr.TextLog("; ".join(e.events), level="INFO"))


def record_run(path, seq, result, truth: dict | None = None, detail: list | None = None,
               recording_id: str | None = None) -> Path:
    """Write a Rerun recording (.rrd) of one odometry run.

    Contents (entity paths; docs/visualisation.md): `world` (RIGHT_HAND_Z_UP, the estimator's world frame),
    `world/estimate/trajectory` and `world/truth/trajectory` (line strips; the truth aligned to the estimate
    by its first pose), `world/vehicle` (estimated T_world_vehicle per frame), `world/vehicle/sensor` (the
    extrinsic, static, logged once), `world/vehicle/sensor/scan` (detections in the sensor frame, class ids of
    DETECTION_CLASSES), `world/map`, `world/associations`, `world/estimate/covariance` (3-sigma ellipsoid of
    the vehicle's world position, Sigma_w = C^T P_rho C with P_rho the position block of the estimate's
    `P_pose_absolute`, the covariance that grows with the drift, see
    `validation.covariance.position_covariance_world`; a point where the estimator gave none),
    `world/truth/vehicle`; time series under `metrics/...` (`metrics/nees/<measure>` for every
    measure of `validation.odometry_consistency`, `metrics/ellipsoid/...`: `viz.recording_metrics`), `velocity/...`, `acceleration/...`; `events`.

    Args:
        path: output .rrd file (parent directories are created).
        seq: the `sim.sequence.Sequence` that was run.
        result: its `validation.driver.RunResult`.
        truth: the simulator's truth dict (t, T_vehicle_world, varpi, varpi_dot, det_label, scan_offsets), or
            None (then seq.groundtruth, if any, gives the truth trajectory).
        detail: per-frame `ScanDetail` (or None entries), len == len(result.estimates), or None.
        recording_id: Rerun recording id (default: a fresh one).

    Returns:
        The path written.

    Raises:
        InputError: empty result, detail of the wrong length, malformed truth.

    Checked by: tests/viz/test_recording.py::test_recording_has_every_entity_and_a_blueprint (and the tests after it)
    """
    import rerun as rr

    est = result.estimates
    if not est:
        raise InputError("result: no estimates to record")
    if detail is not None and len(detail) != len(est):
        raise InputError(f"detail: expected {len(est)} entries (one per estimate), got {len(detail)}")
    truth_m = _Truth(seq, result, truth)
    with recording_file(rr, path, recording_id) as rec:
        _write(rec, rr, seq, result, truth_m, detail)
    return Path(path)


def record_sequence(path, seq, truth: dict | None = None, recording_id: str | None = None) -> Path:
    """Write a Rerun recording of a sequence on its own (`rodo simulate --rerun`): no estimator involved.

    Entities: `world` (RIGHT_HAND_Z_UP, the sequence's world frame), `world/truth/trajectory`,
    `world/vehicle` (T_world_vehicle per frame from groundtruth.txt), `world/vehicle/sensor` (the extrinsic,
    static) and `world/vehicle/sensor/scan` (detections in the sensor frame; class ids 5 static, 6 moving,
    3 clutter when the simulator's truth labels are given, else 4); `.../scan_doppler` (coloured by radial
    velocity) and, with the truth, `world/movers/<id>` boxes with their velocities (`viz.sequence_layers`);
    timelines `frame` and `time`; a blueprint.

    Checked by: tests/viz/test_sequence_recording.py::test_sequence_recording
    """
    import rerun as rr

    if seq.groundtruth is None or len(seq.groundtruth.t) == 0:
        raise InputError("sequence: a recording of a sequence needs its groundtruth.txt")
    gt = seq.groundtruth
    with recording_file(rr, path, recording_id) as rec:
        _log_world(rec, rr)
        _log_frames(rec, rr, seq)
        pos = gt.T_world_vehicle[:, :3, 3]
        rec.log("world/truth/trajectory", rr.LineStrips3D([pos], colors=[TRUTH_COLOUR], radii=0.08), static=True)
        frames = np.arange(len(gt.t))
        rec.send_columns("world/vehicle",
                         indexes=[rr.TimeColumn("frame", sequence=frames), rr.TimeColumn("time", duration=gt.t)],
                         columns=rr.Transform3D.columns(translation=pos,
                                                        quaternion=so3.to_quaternion(gt.T_world_vehicle[:, :3, :3])))
        offsets = None if truth is None else np.asarray(truth["scan_offsets"])
        frame_of = match_index([s.t for s in seq.scans], gt.t) if seq.scans else []
        by_frame = [(k, scan) for scan, k in zip(seq.scans, frame_of) if k >= 0]
        for k, scan in by_frame:
            rec.set_time("frame", sequence=k)
            rec.set_time("time", duration=float(scan.t))
            if offsets is not None and offsets[k + 1] - offsets[k] == len(scan):
                labels = np.asarray(truth["det_label"])[offsets[k]:offsets[k + 1]]
                cls = np.where(labels == TRUTH_CLUTTER, 3, np.where(labels == TRUTH_MOVING, 6, 5)).astype(np.uint16)
            else:
                cls = np.full(len(scan), 4, dtype=np.uint16)
            rec.log("world/vehicle/sensor/scan", rr.Points3D(scan.points_sensor, class_ids=cls, radii=0.15))
        T_gt_truth = None if truth is None else gt.T_world_vehicle[0] @ np.asarray(truth["T_vehicle_world"])[0]
        log_sequence_layers(rec, rr, by_frame, truth, T_gt_truth, gt.t)
        rec.send_blueprint(sequence_blueprint(pos))
    return Path(path)


def _write(rec, rr, seq, result, truth_m: _Truth, detail) -> None:
    from .blueprint import build_blueprint

    est = result.estimates
    n = len(est)
    frames = np.arange(n)
    times = result.t.astype(float)
    T_world_vehicle = np.stack([e.T_world_vehicle for e in est])
    positions = T_world_vehicle[:, :3, 3]
    _log_world(rec, rr)
    _log_frames(rec, rr, seq)
    rec.log("world/estimate/trajectory", rr.LineStrips3D([positions], colors=[ESTIMATE_COLOUR], radii=0.08,
                                                         labels=[f"estimate ({result.config.model})"],
                                                         show_labels=False), static=True)
    index = [rr.TimeColumn("frame", sequence=frames), rr.TimeColumn("time", duration=times)]
    rec.send_columns("world/vehicle", indexes=index,
                     columns=rr.Transform3D.columns(translation=positions,
                                                    quaternion=so3.to_quaternion(T_world_vehicle[:, :3, :3])))
    P_abs = np.stack([e.P_pose_absolute[:3, :3] if e.P_pose_absolute is not None else np.zeros((3, 3)) for e in est])
    Sigma = position_covariance_world(np.stack([e.T_vehicle_world for e in est]), np.nan_to_num(P_abs))
    half, quat = covariance_ellipsoid(Sigma, ELLIPSOID_SIGMA)
    rec.log("world/estimate/covariance", rr.Ellipsoids3D.from_fields(
        colors=[(40, 120, 255)], fill_mode=rr.components.FillMode.MajorWireframe), static=True)
    rec.send_columns("world/estimate/covariance", indexes=index,
                     columns=rr.Ellipsoids3D.columns(centers=positions, half_sizes=half, quaternions=quat))
    if truth_m.T_world_vehicle is not None:
        ok = np.all(np.isfinite(truth_m.T_world_vehicle.reshape(n, -1)), axis=1)
        Tt = truth_m.T_world_vehicle[ok]
        rec.log("world/truth/trajectory", rr.LineStrips3D([Tt[:, :3, 3]], colors=[TRUTH_COLOUR], radii=0.08,
                                                          labels=["ground truth (aligned at the first pose)"],
                                                          show_labels=False),
                static=True)
        rec.log("world/truth/vehicle", rr.TransformAxes3D(axis_length=1.5), static=True)
        rec.send_columns("world/truth/vehicle",
                         indexes=[rr.TimeColumn("frame", sequence=frames[ok]),
                                  rr.TimeColumn("time", duration=times[ok])],
                         columns=rr.Transform3D.columns(translation=Tt[:, :3, 3],
                                                        quaternion=so3.to_quaternion(Tt[:, :3, :3])))
    logged = _log_series(rec, rr, result, truth_m, frames, times)
    _log_scans(rec, rr, seq, result, truth_m, detail)
    pts = positions if truth_m.T_world_vehicle is None else np.r_[positions, truth_m.T_world_vehicle[:, :3, 3]]
    rec.send_blueprint(build_blueprint(pts, logged))
