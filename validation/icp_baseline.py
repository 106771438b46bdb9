"""The baseline a user might pick instead of the paper's estimator: open3d ICP odometry, scan to local map.

Per scan k (times from `validation.driver.scan_times`, so the output lines up with `run_sequence`):

1. Source: the scan's detections in the vehicle frame, p_vehicle = T_vehicle_sensor @ p_sensor (all detections:
   ICP has no Doppler; with `doppler_filter=True` only the inliers of
   `estimator.ego_velocity.estimate_ego_velocity`, i.e. the static world as seen through the radial velocities).
2. Initial guess, constant velocity: T_k^0 = T_{k-1} exp(dt_k / dt_{k-1} log(T_{k-2}^-1 T_{k-1})), with
   T = T_world_vehicle (the last relative motion applied again, scaled to the interval). At the second scan there
   is no motion yet: T_1^0 = T_0, or with `doppler_init=True` T_0 translated by dt_1 v_vehicle, the first scan's
   Doppler ego velocity (`estimate_ego_velocity`, v_vehicle = R_vehicle_sensor v_sensor): the estimator's own
   initialisation uses the same. Without it a vehicle already at 30 m/s (2.3 m per scan) never locks on with
   a correspondence distance below that: ICP registers "no motion" against the along-track structure.
3. Target: the local map, the registered scans k-map_scans..k-1 in the world frame (`map_scans=1`: the previous
   scan, i.e. scan-to-scan ICP), voxel-downsampled (`voxel` metres; None: every point kept) and, for
   point-to-plane, with normals from a hybrid KNN search (radius 3 voxel, or NORMAL_RADIUS without a voxel
   filter; 20 neighbours).
4. `o3d.pipelines.registration.registration_icp(source, target, max_correspondence, T_k^0, ...)` gives
   T_k = T_world_vehicle (the transform mapping vehicle into world coordinates). Scans with fewer than
   MIN_POINTS points (or fewer correspondences) keep the prediction.

The first estimate is the identity, as the estimator's. Timing per scan covers steps 1-4 and the map update.
BLAS and open3d's thread pool are limited to one thread for the run, as in `validation.driver.run_sequence`,
so the timings compare like with like on a shared machine.

`open3d` is imported inside `run_icp` only (importing it takes about 2 s); it is optional (`pip install 'rodo[icp]'`)
and its absence raises ModuleNotFoundError naming that extra.

Checked by: tests/validation/test_icp_baseline.py
"""

from __future__ import annotations

import time
from collections import deque

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.sim.sequence import Sequence, Trajectory

METHODS = ("point_to_point", "point_to_plane")
MIN_POINTS = 10       # fewer source or map points: keep the constant-velocity prediction
MAX_ITERATIONS = 30   # ICP iterations per scan
NORMAL_NEIGHBOURS = 20
NORMAL_RADIUS = 1.0   # m: normal search radius when the map is not voxel-filtered (3 x the usual 0.3 m voxel)


def _check_args(method, max_correspondence, voxel, map_scans, doppler_filter,
                doppler_init=False) -> tuple[float, float | None, int]:
    if method not in METHODS:
        raise InputError(f"method: expected one of {METHODS}, got {method!r}")
    try:
        mc = float(max_correspondence)
        vx = None if voxel is None else float(voxel)
    except (TypeError, ValueError):
        raise InputError(f"max_correspondence, voxel: expected numbers, got {max_correspondence!r}, {voxel!r}") \
            from None
    if not (np.isfinite(mc) and mc > 0):
        raise InputError(f"max_correspondence: must be a finite distance > 0 m, got {max_correspondence!r}")
    if vx is not None and (isinstance(voxel, (bool, np.bool_)) or not (np.isfinite(vx) and vx > 0)):
        raise InputError(f"voxel: must be a finite size > 0 m or None (no filter), got {voxel!r}")
    if isinstance(map_scans, (bool, np.bool_)) or not isinstance(map_scans, (int, np.integer)) or map_scans < 1:
        raise InputError(f"map_scans: expected an integer >= 1, got {map_scans!r}")
    for name, flag in (("doppler_filter", doppler_filter), ("doppler_init", doppler_init)):
        if not isinstance(flag, (bool, np.bool_)):
            raise InputError(f"{name}: expected True or False, got {flag!r}")
    return mc, vx, int(map_scans)


def _predict(poses: list[np.ndarray], times: np.ndarray, k: int) -> np.ndarray:
    """Constant-velocity guess of T_world_vehicle at scan k from the two previous estimates."""
    if k < 2:
        return poses[-1].copy()
    delta = se3.inverse(poses[-2]) @ poses[-1]
    ratio = (times[k] - times[k - 1]) / (times[k - 1] - times[k - 2])
    return poses[-1] @ se3.exp(ratio * se3.log(delta))


def run_icp(seq: Sequence, method: str = "point_to_plane", max_correspondence: float = 1.0,
            voxel: float | None = 0.3,
            map_scans: int = 10, doppler_filter: bool = False, doppler_init: bool = False, *, seed: int = 0,
            progress=None) -> tuple[Trajectory, np.ndarray]:
    """ICP odometry over every scan of `seq` (see the module docstring for the algorithm).

    Args:
        seq: the radar sequence (scans in the sensor frame, `seq.sensor.T_vehicle_sensor`).
        method: "point_to_plane" (normals estimated on the map) or "point_to_point".
        max_correspondence: largest point-to-point distance of a correspondence, metres.
        voxel: voxel size of the map downsampling, metres; None keeps every point.
        map_scans: number of most recent registered scans in the local map (1: scan-to-scan).
        doppler_filter: register only the Doppler inliers (static world) instead of all detections.
        doppler_init: the second scan's guess moves by the first scan's Doppler ego velocity (step 2).
        seed: seeds the RANSAC of the Doppler filter (`SeedSequence(seed)`); unused without it.
        progress: optional object with update(), called once per scan.

    Returns:
        (Trajectory of T_world_vehicle (N, 4, 4) at every scan time, identity first; ms_per_scan (N,)).

    Raises:
        InputError naming the argument: unknown method, non-positive distances, bad map_scans, empty sequence.

    Checked by: tests/validation/test_icp_baseline.py
    """
    mc, vx, n_map = _check_args(method, max_correspondence, voxel, map_scans, doppler_filter, doppler_init)
    if not isinstance(seq, Sequence):
        raise InputError(f"seq: expected a sim.sequence.Sequence, got {type(seq).__name__}")
    from threadpoolctl import threadpool_limits

    from rodo.validation.driver import scan_times

    times = scan_times(seq)
    if len(times) == 0:
        raise InputError("seq: no scans (radar.csv has no rows and there is no groundtruth.txt)")
    try:
        import open3d as o3d
    except ModuleNotFoundError as exc:  # an optional dependency: rodo[icp]
        if exc.name != "open3d":
            raise
        raise ModuleNotFoundError("run_icp needs open3d, the optional dependency of rodo[icp]: "
                                  "pip install 'rodo[icp]'", name="open3d") from None

    before = o3d.utility.get_max_threads() if hasattr(o3d.utility, "get_max_threads") else None
    try:
        if before is not None:
            o3d.utility.set_max_threads(1)
        with threadpool_limits(limits=1, user_api="blas"):
            return _run(o3d, seq, times, method, mc, vx, n_map, (bool(doppler_filter), bool(doppler_init)), seed,
                        progress)
    finally:
        if before is not None:
            o3d.utility.set_max_threads(before)


def _static_mask(scan, sigma_vr: float, rng: np.random.Generator) -> np.ndarray:
    from rodo.estimator.ego_velocity import estimate_ego_velocity

    ego = estimate_ego_velocity(scan.azimuth, scan.elevation, scan.radial_velocity, rng, sigma_vr=sigma_vr)
    return ego.inliers if ego.ok else np.ones(len(scan), dtype=bool)


def _first_guess(scan, T_vehicle_sensor, dt, sigma_vr, rng) -> np.ndarray:
    """T_world_vehicle at the second scan from the first scan's Doppler ego velocity (identity if it fails)."""
    from rodo.estimator.ego_velocity import estimate_ego_velocity

    T = np.eye(4)
    if scan is not None and len(scan):
        ego = estimate_ego_velocity(scan.azimuth, scan.elevation, scan.radial_velocity, rng, sigma_vr=sigma_vr)
        if ego.ok:
            T[:3, 3] = dt * (T_vehicle_sensor[:3, :3] @ ego.v_sensor)
    return T


def _run(o3d, seq, times, method, mc, vx, n_map, doppler, seed, progress):
    reg = o3d.pipelines.registration
    estimation = (reg.TransformationEstimationPointToPlane() if method == "point_to_plane"
                  else reg.TransformationEstimationPointToPoint())
    doppler_filter, doppler_init = doppler
    criteria = reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=MAX_ITERATIONS)
    normal_search = o3d.geometry.KDTreeSearchParamHybrid(radius=3.0 * vx if vx else NORMAL_RADIUS,
                                                         max_nn=NORMAL_NEIGHBOURS)
    Vec = o3d.utility.Vector3dVector
    T_vehicle_sensor = np.asarray(seq.sensor.T_vehicle_sensor)
    sigma_vr = float(seq.sensor.noise.radial_velocity)
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    by_t = {s.t: s for s in seq.scans}
    history: deque[np.ndarray] = deque(maxlen=n_map)   # registered scans, world frame
    target = None
    poses: list[np.ndarray] = []
    wall = np.empty(len(times))
    for k, t in enumerate(times):
        tic = time.perf_counter()
        scan = by_t.get(t)
        if scan is not None and len(scan):
            p_sensor = scan.points_sensor
            if doppler_filter:
                p_sensor = p_sensor[_static_mask(scan, sigma_vr, rng)]
            p_vehicle = p_sensor @ T_vehicle_sensor[:3, :3].T + T_vehicle_sensor[:3, 3]
        else:
            p_vehicle = np.zeros((0, 3))
        if k == 0:
            T = np.eye(4)
            first = _first_guess(scan, T_vehicle_sensor, times[1] - t, sigma_vr, rng) \
                if doppler_init and len(times) > 1 else T
        else:
            T = _predict(poses, times, k) if k > 1 else first
            if target is not None and len(p_vehicle) >= MIN_POINTS:
                source = o3d.geometry.PointCloud(Vec(p_vehicle))
                result = reg.registration_icp(source, target, mc, T, estimation, criteria)
                if len(result.correspondence_set) >= MIN_POINTS:
                    T = np.array(result.transformation)
        poses.append(T)
        if len(p_vehicle):
            history.append(p_vehicle @ T[:3, :3].T + T[:3, 3])
            cloud = o3d.geometry.PointCloud(Vec(np.concatenate(list(history))))
            if vx is not None:
                cloud = cloud.voxel_down_sample(vx)
            if len(cloud.points) >= MIN_POINTS:
                if method == "point_to_plane":
                    cloud.estimate_normals(normal_search)
                target = cloud
        wall[k] = (time.perf_counter() - tic) * 1e3
        if progress is not None:
            progress.update()
    return Trajectory(times, np.stack(poses)), wall
