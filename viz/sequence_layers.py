"""What a recording of a simulated sequence shows besides its labelled scans (`rodo simulate --rerun`,
`viz.recording.record_sequence`): the scans coloured by radial velocity, the world's moving objects as boxes
with their velocities, and a default layout.

- `doppler_colours(vr, limit)`: a diverging map, blue approaching (v_r < 0), white at rest, red receding,
  saturated at +-limit (`doppler_limit`: one limit for the whole sequence);
- `mover_tracks(truth, T_gt_truth)`: per moving object its present frames, world poses, velocity (finite
  differences of the scan poses) and a box fitted to its detections (in the object frame: the detections'
  extent, or a car's size when it was never seen), from truth.npz (`mover_T_world_object`, `det_*`);
- `log_sequence_layers(rec, rr, ...)` logs both; `sequence_blueprint(positions)` is the layout.

rerun is passed in, never imported here at module level (viz is the only package importing it).

Checked by: tests/viz/test_sequence_recording.py::test_sequence_recording_layers
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rodo.estimator.lie import se3, so3

CAR_HALF_SIZE = np.array([2.25, 0.9, 0.75])  # m, for a mover with no detection
MOVING = 2  # sim label of a detection on a moving object


def doppler_limit(vr: np.ndarray) -> float:
    """The default saturation of `doppler_colours`: the 95th percentile of |v_r|, at least 0.5 m/s."""
    vr = np.asarray(vr, dtype=float)
    return max(float(np.percentile(np.abs(vr), 95)) if vr.size else 0.0, 0.5)


def doppler_colours(vr: np.ndarray, limit: float | None = None) -> np.ndarray:
    """(n, 3) uint8: blue (approaching) - white (0) - red (receding), saturated at +-limit (default
    `doppler_limit(vr)`)."""
    vr = np.asarray(vr, dtype=float)
    limit = doppler_limit(vr) if limit is None else limit
    x = np.clip(np.nan_to_num(vr) / limit, -1.0, 1.0)
    white = np.array([255.0, 255.0, 255.0])
    blue, red = np.array([30.0, 80.0, 230.0]), np.array([220.0, 40.0, 30.0])
    ends = np.where(x[:, None] < 0, blue, red)
    return np.rint(white + np.abs(x)[:, None] * (ends - white)).astype(np.uint8)


@dataclass(frozen=True)
class MoverTrack:
    """One moving object over the frames where it is present."""

    object_id: int
    frames: np.ndarray  # (m,) scan indices
    T_world_object: np.ndarray  # (m, 4, 4) in the recording's world
    centres: np.ndarray  # (m, 3) the box centre in the recording's world
    velocity: np.ndarray  # (m, 3) of the box centre, world frame, m/s
    centre: np.ndarray  # (3,) box centre in the object frame
    half_size: np.ndarray  # (3,)


def _box_of(truth: dict, object_id: int, T_world_object: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Box (centre, half size) in the object frame spanned by the object's moving detections."""
    mask = (np.asarray(truth["det_object_id"]) == object_id) & (np.asarray(truth["det_label"]) == MOVING)
    scan = np.asarray(truth["det_scan"])[mask]
    p = np.asarray(truth["det_p_world"], dtype=float)[mask]
    ok = np.all(np.isfinite(T_world_object[scan]), axis=(1, 2)) if len(scan) else np.zeros(0, bool)
    if not ok.any():
        return np.zeros(3), CAR_HALF_SIZE.copy()
    T_obj_world = se3.inverse(T_world_object[scan[ok]])
    q = np.einsum("nij,nj->ni", T_obj_world[:, :3, :3], p[ok]) + T_obj_world[:, :3, 3]
    lo, hi = q.min(axis=0), q.max(axis=0)
    return 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), 0.1)


def mover_tracks(truth: dict, T_gt_truth: np.ndarray) -> list[MoverTrack]:
    """The moving objects of truth.npz in the recording's world (T_gt_truth maps the simulator's world into it)."""
    ids = np.asarray(truth.get("mover_ids", np.zeros(0)), dtype=np.int64)
    if ids.size == 0:
        return []
    T_all = np.asarray(truth["mover_T_world_object"], dtype=float)
    t = np.asarray(truth["t"], dtype=float)
    tracks = []
    for j, object_id in enumerate(ids):
        frames = np.flatnonzero(np.all(np.isfinite(T_all[:, j]), axis=(1, 2)))
        if frames.size == 0:
            continue
        centre, half = _box_of(truth, int(object_id), T_all[:, j])
        T = T_gt_truth @ T_all[frames, j]
        p = T[:, :3, 3] + np.einsum("nij,j->ni", T[:, :3, :3], centre)
        v = np.gradient(p, t[frames], axis=0) if frames.size > 1 else np.zeros_like(p)
        tracks.append(MoverTrack(int(object_id), frames, T, p, v, centre, half))
    return tracks


def log_sequence_layers(rec, rr, scans_by_frame, truth: dict | None, T_gt_truth: np.ndarray, times) -> None:
    """`world/vehicle/sensor/scan_doppler` (each scan coloured by radial velocity) and, with the truth,
    `world/movers/<id>` (a box per frame where the object is present) and `world/movers/<id>/velocity` (an
    arrow of one second's travel). scans_by_frame: [(frame, scan)]; times: (K,) the frames' times."""
    limit = doppler_limit(np.concatenate([s.polar[:, 3] for _, s in scans_by_frame] + [np.zeros(0)]))
    for k, scan in scans_by_frame:
        rec.set_time("frame", sequence=int(k))
        rec.set_time("time", duration=float(scan.t))
        rec.log("world/vehicle/sensor/scan_doppler",
                rr.Points3D(scan.points_sensor, colors=doppler_colours(scan.polar[:, 3], limit), radii=0.15))
    for track in mover_tracks(truth, T_gt_truth) if truth is not None else []:
        path = f"world/movers/{track.object_id}"
        quats = so3.to_quaternion(track.T_world_object[:, :3, :3])
        for i, k in enumerate(track.frames):
            if k >= len(times):
                break
            rec.set_time("frame", sequence=int(k))
            rec.set_time("time", duration=float(times[k]))
            rec.log(path, rr.Boxes3D(centers=[track.centres[i]], half_sizes=[track.half_size],
                                     quaternions=[quats[i]], colors=[(255, 120, 0)],
                                     labels=[f"object {track.object_id}"]))
            rec.log(f"{path}/velocity", rr.Arrows3D(origins=[track.centres[i]], vectors=[track.velocity[i]],
                                                    colors=[(255, 120, 0)]))


def sequence_blueprint(positions: np.ndarray):
    """The layout of a sequence recording: the labelled scans in 3D, the Doppler-coloured scans from above."""
    import rerun.blueprint as rrb

    from .blueprint import birds_eye_eye

    eye = birds_eye_eye(positions)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="3D (truth labels)",
                              contents=["+ /**", "- /world/vehicle/sensor/scan_doppler"]),
            rrb.Spatial3DView(origin="world", name="bird's-eye, Doppler (blue approaching, red receding)",
                              contents=["+ /**", "- /world/vehicle/sensor/scan"],
                              eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, **eye)),
        ),
        collapse_panels=False,
    )
