"""Point-cloud export of a sequence for other tools: `.ply` (open3d, CloudCompare) and the KITTI odometry layout
(velodyne `.bin`, times.txt, calib.txt, poses/00.txt) that kiss-icp reads unchanged. Docs: docs/export.md.

Our own small writers (binary little-endian PLY, float32 `.bin`): no dependency beyond numpy.

Checked by: tests/sim/test_export.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError, out_of_space
from rodo.estimator.lie import se3
from rodo.sim.kitti_poses import format_kitti_poses
from rodo.sim.sequence import RadarScan, Sequence, Trajectory, atomic_write_bytes
from rodo.sim.simulate import read_npz

PLY_TYPES = {"f4": "float", "f8": "double", "i4": "int", "u4": "uint", "i2": "short", "u2": "ushort",
             "i1": "char", "u1": "uchar"}
TIME_MATCH_S = 1e-6  # a pose within 1 us of a scan time is that scan's pose (TUM files keep 9 decimals)
KITTI_SEQUENCE = "00"


def _atomic_write(path: Path, data: bytes) -> None:
    try:
        atomic_write_bytes(path, data)  # a uniquely named temporary file, fsync, rename; removed on failure
    except OSError as exc:
        if out_of_space(exc):  # the machine's: the CLI's one line and exit 1 (atomic_write_bytes named the file)
            raise
        raise InputError(f"{path}: cannot write ({exc.strerror or exc})") from None


def _mkdir(path: Path) -> Path:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        if out_of_space(exc):  # mkdir's error names its directory
            raise
        raise InputError(f"{path}: cannot create the directory ({exc.strerror or exc})") from None
    return path


def _remove_stale(directory: Path, suffix: str, written: set[str]) -> None:
    """Remove the files of an earlier export in `directory` (NNNNNN`suffix`, six digits) that this one did not
    write: a scan directory holds one drive, not the tail of another."""
    for path in directory.glob(f"*{suffix}"):
        stem = path.name[:-len(suffix)]
        if len(stem) == 6 and stem.isdigit() and path.name not in written:
            _unlink(path)


def _unlink(path: Path) -> None:
    try:
        path.unlink(missing_ok=True)
    except OSError as exc:
        raise InputError(f"{path}: cannot remove the earlier export's file ({exc.strerror or exc})") from None


def ply_bytes(columns: dict[str, np.ndarray]) -> bytes:
    """A binary little-endian PLY with one `vertex` element whose properties are `columns` (name -> (n,)
    array, in order; x, y, z first for point-cloud readers). Types follow the arrays' dtypes (PLY_TYPES)."""
    names = list(columns)
    arrays = [np.asarray(columns[k]) for k in names]
    n = len(arrays[0]) if arrays else 0
    formats = []
    for name, a in zip(names, arrays):
        if a.shape != (n,) or a.dtype.kind + str(a.dtype.itemsize) not in PLY_TYPES:
            raise InputError(f"PLY property {name!r}: expected ({n},) of {sorted(PLY_TYPES)}, got {a.shape} "
                             f"{a.dtype}")
        formats.append("<" + a.dtype.kind + str(a.dtype.itemsize))
    record = np.zeros(n, dtype=np.dtype({"names": names, "formats": formats}))
    for name, a in zip(names, arrays):
        record[name] = a
    header = ["ply", "format binary_little_endian 1.0", "comment written by rodo", f"element vertex {n}"]
    header += [f"property {PLY_TYPES[f[1:]]} {name}" for name, f in zip(names, formats)]
    header.append("end_header")
    return ("\n".join(header) + "\n").encode("ascii") + record.tobytes()


def scan_columns(scan: RadarScan, T_out_sensor: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The PLY properties of one scan: x, y, z (sensor frame, or T_out_sensor @ p_sensor), radial_velocity
    (the Doppler, m/s, negative when approaching), scan_time (s), scan, range, azimuth, elevation, then the
    scan's extra columns. Doubles except the scan index (int).

    The time is named `scan_time`, not `time` or `t`: kiss-icp reads those as per-point deskew stamps.
    """
    p = scan.points_sensor
    if T_out_sensor is not None:
        p = se3.transform_points(T_out_sensor, p)
    n = len(scan)
    cols = {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "radial_velocity": scan.radial_velocity,
            "scan_time": np.full(n, scan.t), "scan": np.full(n, scan.scan, dtype=np.int32),
            "range": scan.range, "azimuth": scan.azimuth, "elevation": scan.elevation}
    for name, values in scan.extra.items():
        if name not in cols:
            cols[name] = values
    return {k: np.ascontiguousarray(v, dtype=np.int32 if k == "scan" else np.float64) for k, v in cols.items()}


def poses_at_scans(seq: Sequence, trajectory: Trajectory, where: str) -> np.ndarray:
    """(S, 4, 4) T_world_vehicle of every scan, taken from `trajectory` at the scan times (within 1 us).

    Raises:
        InputError naming `where` and the first scan without a pose.
    """
    t_scan = np.array([s.t for s in seq.scans])
    t_traj = trajectory.t
    if len(t_traj) == 0:
        raise InputError(f"{where}: no poses")
    j = np.searchsorted(t_traj, t_scan)
    lo, hi = np.clip(j - 1, 0, len(t_traj) - 1), np.clip(j, 0, len(t_traj) - 1)
    idx = np.where(np.abs(t_traj[lo] - t_scan) <= np.abs(t_traj[hi] - t_scan), lo, hi)  # the nearest pose
    bad = np.abs(t_traj[idx] - t_scan) > TIME_MATCH_S
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"{where}: no pose at the time of scan {seq.scans[k].scan} (t = {float(t_scan[k])!r} s; "
                         f"poses cover {float(t_traj[0])!r} .. {float(t_traj[-1])!r} s)")  # plain numbers
    return trajectory.T_world_vehicle[idx]


def _read_states(states_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(t, n_detections) of a run's states.npz, or an InputError naming it."""
    data = read_npz(states_path, f"--run: {states_path}: cannot read", "the states.npz `rodo run` writes")
    missing = [k for k in ("t", "n_detections") if k not in data]
    if missing:
        raise InputError(f"--run: {states_path}: no array {missing[0]!r} (not a `rodo run` states.npz)")
    t, n = np.asarray(data["t"], dtype=float), np.asarray(data["n_detections"])
    if t.ndim != 1 or n.shape != t.shape or n.dtype.kind not in "iu":
        raise InputError(f"--run: {states_path}: t {t.shape} and n_detections {n.shape} {n.dtype} are not one "
                         "count per scan (not a `rodo run` states.npz)")
    return t, n


def check_run_of_sequence(seq: Sequence, states_path, run_name: str, seq_name: str) -> None:
    """Refuse a run of another sequence: simulated sequences share their scan times, so matching times do not
    tell. The run's states.npz counts the detections the estimator took from every scan (n_detections: range
    in (0, max_range], and without those of elevation exactly 0 under `association.missing_elevation_zero`); each
    scan of `seq` must have a state at its time with its count, one of those two.

    Raises:
        InputError naming both directories and the first scan that differs.

    Checked by: tests/sim/test_review2_export_run.py::test_a_run_of_another_sequence_with_the_same_times_is_refused
    """
    states_path = Path(states_path)
    t_run, n_run = _read_states(states_path)
    order = np.argsort(t_run, kind="stable")
    t_run, n_run = t_run[order], n_run[order]
    max_range = seq.sensor.max_range
    for scan in seq.scans:
        j = int(np.searchsorted(t_run, scan.t))
        near = [k for k in (j - 1, j) if 0 <= k < len(t_run) and abs(t_run[k] - scan.t) <= TIME_MATCH_S]
        where = f"scan {scan.scan} (t = {float(scan.t)!r} s)"
        if not near:
            raise InputError(f"--run: {run_name} is not a run of {seq_name}: its {states_path.name} has no state at "
                             f"{where}")
        inside = (scan.range > 0) & (scan.range <= max_range)
        n_in, n_elevation = int(inside.sum()), int((inside & (scan.elevation != 0)).sum())
        if int(n_run[near[0]]) not in (n_in, n_elevation):
            also = "" if n_elevation == n_in else f", {n_elevation} of them with an elevation"
            raise InputError(f"--run: {run_name} is not a run of {seq_name}: at {where} the run took "
                             f"{int(n_run[near[0]])} detections ({states_path.name} n_detections), the sequence "
                             f"has {n_in} in range (0, {max_range:g}] m{also}; give the run of this sequence")


def export_ply(seq: Sequence, out_dir, trajectory: Trajectory | None = None, where: str = "trajectory") -> dict:
    """Write OUT/scans/<scan:06d>.ply (sensor frame, one per scan) and, given a trajectory, OUT/map.ply: every
    scan in the world frame, p_world = T_world_vehicle(t_k) T_vehicle_sensor p_sensor (the aggregated map).

    Returns:
        {"scans": number of scan files, "points": total points, "map": path of map.ply or None}.

    Checked by: tests/sim/test_export.py::test_ply_scans_read_back_with_open3d,
        ::test_ply_map_is_the_scans_in_the_world_frame
    """
    if not seq.scans:
        raise InputError("SEQ_DIR: the sequence has no scans with detections: nothing to export")
    T_world_vehicle = None if trajectory is None else poses_at_scans(seq, trajectory, where)  # fail early
    out = _mkdir(Path(out_dir))
    scans_dir = _mkdir(out / "scans")
    for scan in seq.scans:
        _atomic_write(scans_dir / f"{scan.scan:06d}.ply", ply_bytes(scan_columns(scan)))
    _remove_stale(scans_dir, ".ply", {f"{scan.scan:06d}.ply" for scan in seq.scans})
    map_path = None
    if T_world_vehicle is None:
        _unlink(out / "map.ply")  # an earlier export's map is not this drive's
    else:
        T_world_sensor = T_world_vehicle @ seq.sensor.T_vehicle_sensor
        parts = [scan_columns(s, T) for s, T in zip(seq.scans, T_world_sensor)]
        names = [k for k in parts[0] if all(k in p for p in parts)]
        map_path = out / "map.ply"
        _atomic_write(map_path, ply_bytes({k: np.concatenate([p[k] for p in parts]) for k in names}))
    return {"scans": len(seq.scans), "points": sum(len(s) for s in seq.scans), "map": map_path}


def kitti_pose_rows(T_world_sensor: np.ndarray) -> str:
    """KITTI poses text (`kitti_poses.format_kitti_poses`) of T_0_k = T_world_sensor[0]^-1 T_world_sensor[k],
    the sensor's pose in its first frame."""
    return format_kitti_poses(se3.inverse(T_world_sensor[0]) @ T_world_sensor)


def _check_intensity(seq: Sequence, values: list, intensity: str | None, extras: set) -> None:
    """KITTI's .bin holds float32 intensities that its readers take as numbers: a column with NaN or infinity
    (allowed in a sequence's extra columns) is refused before anything is written, naming its first such row."""
    for scan, i in zip(seq.scans, values):
        bad = ~np.isfinite(i.astype("<f4"))  # a finite float64 beyond float32's range is infinite in the file
        if bad.any():
            others = ", ".join(c for c in ["radial_velocity", *sorted(extras)] if c != intensity)
            raise InputError(f"--intensity: column {intensity!r} is {float(i[bad][0])!r} in scan {scan.scan} "
                             f"(t = {scan.t} s), row {int(np.argmax(bad))} of the scan; KITTI's .bin needs finite "
                             f"intensities: choose another column with --intensity ({others})")


def export_kitti(seq: Sequence, out_dir, intensity: str | None = None) -> dict:
    """Write the KITTI odometry layout for sequence 00 (sensor frame = KITTI's velodyne = camera, Tr identity):

        OUT/sequences/00/velodyne/<k:06d>.bin  float32 x, y, z, intensity (one file per scan, k = 0, 1, ...)
        OUT/sequences/00/times.txt            scan time in s, one per line
        OUT/sequences/00/calib.txt            `Tr:` identity (3 x 4)
        OUT/poses/00.txt                      ground-truth sensor poses in the first sensor frame (3 x 4 per
                                              line), when groundtruth.txt has a pose at every scan time

    Args:
        intensity: the column written as intensity: 'radial_velocity', an extra column (e.g. 'snr'), or None
            for 'snr' when the sequence has it, else zeros.

    Returns:
        {"scans": S, "points": total, "poses": path of poses/00.txt or None, "intensity": the column or None}.

    Checked by: tests/sim/test_export.py::test_kitti_bin_times_and_poses
    """
    if not seq.scans:
        raise InputError("SEQ_DIR: the sequence has no scans with detections: nothing to export")
    extras = set(seq.scans[0].extra)
    if intensity is None and "snr" in extras:
        intensity = "snr"
    if intensity is not None and intensity != "radial_velocity" and intensity not in extras:
        raise InputError(f"--intensity: no column {intensity!r} in the sequence (radial_velocity"
                         f"{''.join(', ' + e for e in sorted(extras))})")
    values = [np.zeros(len(scan)) if intensity is None else (
        scan.radial_velocity if intensity == "radial_velocity" else scan.extra[intensity]) for scan in seq.scans]
    _check_intensity(seq, values, intensity, extras)
    seq_dir = _mkdir(Path(out_dir) / "sequences" / KITTI_SEQUENCE)
    velodyne = _mkdir(seq_dir / "velodyne")
    for k, (scan, i) in enumerate(zip(seq.scans, values)):
        _atomic_write(velodyne / f"{k:06d}.bin", np.c_[scan.points_sensor, i].astype("<f4").tobytes())
    _remove_stale(velodyne, ".bin", {f"{k:06d}.bin" for k in range(len(seq.scans))})
    _atomic_write(seq_dir / "times.txt", "".join(f"{s.t:.9e}\n" for s in seq.scans).encode("ascii"))
    _atomic_write(seq_dir / "calib.txt", b"Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    poses = None
    if seq.groundtruth is not None:
        try:
            T_world_vehicle = poses_at_scans(seq, seq.groundtruth, "groundtruth.txt")
        except InputError:
            T_world_vehicle = None  # ground truth not at every scan time: no poses file (reported)
        if T_world_vehicle is not None:
            poses = _mkdir(Path(out_dir) / "poses") / f"{KITTI_SEQUENCE}.txt"
            rows = kitti_pose_rows(T_world_vehicle @ seq.sensor.T_vehicle_sensor)
            _atomic_write(poses, rows.encode("ascii"))
    if poses is None:
        _unlink(Path(out_dir) / "poses" / f"{KITTI_SEQUENCE}.txt")  # an earlier export's poses are not this drive's
    return {"scans": len(seq.scans), "points": sum(len(s) for s in seq.scans), "poses": poses,
            "intensity": intensity}
