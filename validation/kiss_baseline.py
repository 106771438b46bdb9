"""KISS-ICP (Vizzo et al., RA-L 2023; the `kiss-icp` package) as a radar odometry baseline, driven in-process.

The package's own loop (`kiss_icp.pipeline.OdometryPipeline._run_pipeline`) is: per frame, `KissICP.register_frame
(points, timestamps)` then read `.last_pose`. We do the same, frame by frame, without its dataset classes and
result files, so the timing covers exactly `register_frame` (the pipeline times the same call):

1. Source: the scan's detections in the sensor frame (`scan.points_sensor`), all of them (KISS-ICP has no
   Doppler; its robust kernel and adaptive threshold are what rejects movers and clutter).
2. `KissICP.register_frame(p_sensor, [])`: range crop, voxelisation (0.5 and 1.5 voxel), the constant-velocity
   guess `last_pose @ last_delta`, point-to-point ICP against the voxel-hash local map with a Geman-McClure kernel
   and the adaptive threshold, map update. Its pose is T_sensor0_sensork.
3. The vehicle pose, as `validation.icp_baseline.run_icp` reports it (world = vehicle frame at the first scan):
   T_world_vehicle_k = T_vehicle_sensor @ T_sensor0_sensork @ T_vehicle_sensor^-1.

A scan with fewer than MIN_POINTS detections (blackouts, empty scans known from the ground truth) is not
registered: the pose is KISS-ICP's own prediction `last_pose @ last_delta` and its state advances to it, as it
would with a frame that matched the prediction exactly.

Settings (`radar_config`, the reasons in docs/benchmarks.md): KISS-ICP's defaults are for a 64-beam lidar
(max_range 100 m, voxel max_range / 100, deskew on). For this radar: max_range and min_range the sensor's, deskew
off (a radar scan is one timestamp), voxel RADAR_VOXEL (sparse clouds: a few hundred detections per scan),
`max_num_threads=1` (single-threaded, as every method of the bench). Everything else is the package's default.

`kiss_icp` is imported inside the functions only; it is optional (`pip install 'rodo[icp]'`) and its absence raises
ModuleNotFoundError naming that extra.

Checked by: tests/validation/test_kiss_baseline.py
"""

from __future__ import annotations

import time

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.sim.sequence import Sequence, Trajectory

MIN_POINTS = 10       # fewer detections: keep KISS-ICP's constant-velocity prediction
RADAR_VOXEL = 1.5     # m: the tuned voxel of the bench (sensitivity 0.5-2 m in docs/benchmarks.md)


def _import_kiss():
    try:
        from kiss_icp.config import KISSConfig
        from kiss_icp.kiss_icp import KissICP
    except ModuleNotFoundError as exc:  # an optional dependency: rodo[icp]
        if exc.name is None or not exc.name.startswith("kiss_icp"):
            raise
        raise ModuleNotFoundError("run_kiss needs kiss-icp, an optional dependency of rodo[icp]: "
                                  "pip install 'rodo[icp]'", name="kiss_icp") from None
    return KISSConfig, KissICP


def radar_config(seq: Sequence, voxel: float = RADAR_VOXEL, **overrides) -> dict:
    """The KISS-ICP settings for `seq`'s radar as a nested dict (KISSConfig's sections), before `overrides`.

    Args:
        seq: gives the sensor's max_range and min_range.
        voxel: mapping.voxel_size, metres.
        overrides: section -> {field: value}, e.g. adaptive_threshold={"initial_threshold": 1.0}.

    Returns:
        {"data": {...}, "mapping": {...}, "registration": {...}, "adaptive_threshold": {...}}; the fields not named
        keep KISS-ICP's defaults (kiss_icp/config/config.py).
    """
    cfg = {"data": {"max_range": float(seq.sensor.max_range), "min_range": float(seq.sensor.min_range),
                    "deskew": False},
           "mapping": {"voxel_size": float(voxel)},
           "registration": {"max_num_threads": 1},
           "adaptive_threshold": {}}
    for section, values in overrides.items():
        if section not in cfg or not isinstance(values, dict):
            raise InputError(f"{section}: expected one of {sorted(cfg)} with a dict of fields, got {values!r}")
        cfg[section] = {**cfg[section], **values}
    return cfg


def run_kiss(seq: Sequence, voxel: float = RADAR_VOXEL, *, progress=None,
             **overrides) -> tuple[Trajectory, np.ndarray]:
    """KISS-ICP odometry over every scan of `seq` (see the module docstring).

    Args:
        seq: the radar sequence (scans in the sensor frame, `seq.sensor.T_vehicle_sensor`).
        voxel: KISS-ICP's mapping.voxel_size, metres (> 0).
        progress: optional object with update(), called once per scan.
        overrides: KISSConfig sections to change, as in `radar_config`.

    Returns:
        (Trajectory of T_world_vehicle (N, 4, 4) at every scan time of `validation.driver.scan_times`, identity
        first; ms_per_scan (N,), the time of register_frame plus the frame conversions).

    Raises:
        InputError naming the argument: voxel not a finite size > 0, unknown config section, not a Sequence, no scans.

    Checked by: tests/validation/test_kiss_baseline.py::test_pure_translation_through_a_rotated_mount
    """
    try:
        vx = float(voxel)
    except (TypeError, ValueError):
        raise InputError(f"voxel: expected a number, got {voxel!r}") from None
    if isinstance(voxel, bool) or not (np.isfinite(vx) and vx > 0):
        raise InputError(f"voxel: must be a finite size > 0 m, got {voxel!r}")
    if not isinstance(seq, Sequence):
        raise InputError(f"seq: expected a sim.sequence.Sequence, got {type(seq).__name__}")
    from threadpoolctl import threadpool_limits

    from rodo.validation.driver import scan_times

    times = scan_times(seq)
    if len(times) == 0:
        raise InputError("seq: no scans (radar.csv has no rows and there is no groundtruth.txt)")
    settings = radar_config(seq, vx, **overrides)
    KISSConfig, KissICP = _import_kiss()
    odometry = KissICP(KISSConfig(**settings))
    with threadpool_limits(limits=1, user_api="blas"):
        return _run(odometry, seq, times, progress)


def _run(odometry, seq, times, progress):
    T_vehicle_sensor = np.asarray(seq.sensor.T_vehicle_sensor, dtype=float)
    T_sensor_vehicle = se3.inverse(T_vehicle_sensor)
    no_stamps = np.zeros(0)
    by_t = {s.t: s for s in seq.scans}
    poses = np.empty((len(times), 4, 4))
    wall = np.empty(len(times))
    for k, t in enumerate(times):
        tic = time.perf_counter()
        scan = by_t.get(t)
        if scan is not None and len(scan) >= MIN_POINTS:
            odometry.register_frame(np.ascontiguousarray(scan.points_sensor, dtype=np.float64), no_stamps)
        else:  # nothing to register: advance by the prediction
            odometry.last_pose = odometry.last_pose @ odometry.last_delta
        poses[k] = T_vehicle_sensor @ odometry.last_pose @ T_sensor_vehicle
        wall[k] = (time.perf_counter() - tic) * 1e3
        if progress is not None:
            progress.update()
    poses[0] = np.eye(4)  # T_vehicle_sensor @ I @ T_sensor_vehicle, exactly
    return Trajectory(times, poses), wall
