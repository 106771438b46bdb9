"""Trajectory metrics: ATE (Umeyama SE(3) alignment), RPE, per-axis drift, velocity errors.

All trajectories are T_world_vehicle (N, 4, 4) as in TUM files; the estimate's world frame is its own (the
estimator starts at the identity), the ground truth's the simulator's. Metrics that need a common frame either
align (ATE) or express both trajectories relative to their first pose (drift), or are relative by nature
(RPE, KITTI in `validation.kitti`). Times are matched by `validation.association`, the state's NEES and NIS
come from `validation.consistency`. Definitions and formulas: docs/evaluation.md.

Checked by: tests/validation/test_metrics.py
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3

from .alignment import align_to_first
from .association import DEFAULT_TOLERANCE, associate
from .consistency import chi2_bounds, fraction_within, nees_sequence, nis_summary, pose_error
from .error_growth import error_growth, growth_table
from .odometry_consistency import odometry_nees, summarise
from .kitti import LENGTHS, kitti_errors, trajectory_distances


def umeyama_se3(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rigid transform T (4, 4) minimising sum |dst_i - (C src_i + r)|^2 (Umeyama 1991, no scale).

    C = U diag(1, 1, det(U V^T)) V^T from the SVD U S V^T of the cross-covariance sum (dst_i - mu_d)(src_i - mu_s)^T,
    r = mu_d - C mu_s. Needs (N, 3) point sets with N >= 3 not all collinear for a unique C (with fewer, one of
    the minimisers is returned).

    Checked by: tests/validation/test_metrics.py::test_umeyama_recovers_transform
    """
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 1:
        raise InputError(f"src, dst: expected matching (N, 3) points, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    cov = (dst - mu_d).T @ (src - mu_s) / len(src)
    U, _, Vt = np.linalg.svd(cov)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    C = U @ D @ Vt
    return se3.from_rotation_translation(C, mu_d - C @ mu_s)


def _stats(x: np.ndarray, prefix: str, unit: str) -> dict:
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return {f"{prefix}_{k}_{unit}": float("nan") for k in ("rmse", "mean", "median", "max")}
    return {f"{prefix}_rmse_{unit}": float(np.sqrt(np.mean(x ** 2))), f"{prefix}_mean_{unit}": float(np.mean(x)),
            f"{prefix}_median_{unit}": float(np.median(x)), f"{prefix}_max_{unit}": float(np.max(x))}


def _poses(name: str, T) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise InputError(f"{name}: expected (N, 4, 4) poses, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise InputError(f"{name}: poses contain NaN or infinity")
    return T


def _pair(gt, est):
    gt, est = _poses("gt", gt), _poses("est", est)
    if gt.shape != est.shape:
        raise InputError(f"gt, est: need the same number of poses (associate first), got {len(gt)} and {len(est)}")
    return gt, est


def ate(gt: np.ndarray, est: np.ndarray, align: bool = True) -> dict:
    """Absolute trajectory error of positions after SE(3) alignment (Sturm et al. 2012; Umeyama, no scale).

    e_i = |p_gt,i - (C p_est,i + r)| with (C, r) = umeyama_se3(p_est, p_gt).

    Args:
        gt, est: (N, 4, 4) T_world_vehicle at matched times.
        align: False compares positions as they are.

    Returns:
        dict: ate_rmse_m, ate_mean_m, ate_median_m, ate_max_m, and `T_align` (4, 4, list) mapping est into gt.

    Checked by: tests/validation/test_metrics.py::test_ate_*
    """
    gt, est = _pair(gt, est)
    p_gt, p_est = gt[:, :3, 3], est[:, :3, 3]
    T = umeyama_se3(p_est, p_gt) if align else np.eye(4)
    err = np.linalg.norm(p_gt - (p_est @ T[:3, :3].T + T[:3, 3]), axis=1)
    return {**_stats(err, "ate", "m"), "T_align": T.tolist()}


def rotation_angle(C: np.ndarray) -> np.ndarray:
    """Angle of rotation matrices, accurate near 0 too: atan2(|axial(C - C^T)| / 2, (tr C - 1) / 2)."""
    axial = np.stack([C[..., 2, 1] - C[..., 1, 2], C[..., 0, 2] - C[..., 2, 0], C[..., 1, 0] - C[..., 0, 1]], -1)
    return np.arctan2(0.5 * np.linalg.norm(axial, axis=-1), 0.5 * (np.trace(C, axis1=-2, axis2=-1) - 1.0))


path_distances = trajectory_distances  # cumulative path length (N,) in metres: one implementation, the devkit's


def rpe(gt: np.ndarray, est: np.ndarray, delta_frames: int = 1, delta_m: float = 10.0) -> dict:
    """Relative pose error per frame and per metre (Sturm et al. 2012; Geiger et al. 2012 for the per-metre form).

    E_ij = (est_i^-1 est_j)^-1 (gt_i^-1 gt_j); translational error |r(E)|, rotational angle(E).
    Per frame: pairs (i, i + delta_frames), errors in m and deg per pair.
    Per metre: for every i, j = the first frame whose ground-truth path distance exceeds dist_i + delta_m;
    errors divided by the travelled distance dist_j - dist_i (m/m as %, deg/m).

    Returns:
        dict with rpe_trans_{rmse,mean,median,max}_m, rpe_rot_{...}_deg (per frame), rpe_trans_pct and
        rpe_rot_deg_per_m (means per metre, NaN when the path is shorter than delta_m), and the deltas.

    Checked by: tests/validation/test_metrics.py::test_rpe_*
    """
    gt, est = _pair(gt, est)
    if int(delta_frames) < 1:
        raise InputError(f"delta_frames: must be >= 1, got {delta_frames!r}")
    if not (np.isfinite(delta_m) and delta_m > 0):
        raise InputError(f"delta_m: must be > 0, got {delta_m!r}")
    d = int(delta_frames)

    def errors(i, j):
        E = se3.inverse(se3.inverse(est[i]) @ est[j]) @ (se3.inverse(gt[i]) @ gt[j])
        return np.linalg.norm(E[:, :3, 3], axis=1), rotation_angle(E[:, :3, :3])

    i = np.arange(max(len(gt) - d, 0))
    te, re = errors(i, i + d)
    out = {"rpe_delta_frames": d, **_stats(te, "rpe_trans", "m"), **_stats(np.rad2deg(re), "rpe_rot", "deg")}
    dist = path_distances(gt)
    j = np.searchsorted(dist, dist + delta_m, side="right")
    ok = j < len(gt)
    i, j = np.arange(len(gt))[ok], j[ok]
    te, re = errors(i, j)
    travelled = dist[j] - dist[i]
    out["rpe_delta_m"] = float(delta_m)
    out["rpe_trans_pct"] = float(np.mean(te / travelled) * 100) if len(i) else float("nan")
    out["rpe_rot_deg_per_m"] = float(np.rad2deg(np.mean(re / travelled))) if len(i) else float("nan")
    return out


def euler_zyx(C: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) of C = Rz(yaw) Ry(pitch) Rx(roll), (..., 3, 3) -> (..., 3), radians."""
    roll = np.arctan2(C[..., 2, 1], C[..., 2, 2])
    pitch = np.arcsin(np.clip(-C[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(C[..., 1, 0], C[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


DRIFT_AXES = ("x", "y", "z", "roll", "pitch", "yaw")


def drift(gt: np.ndarray, est: np.ndarray) -> dict:
    """Per-axis drift, both trajectories expressed relative to their first pose.

    G_k = gt_0^-1 gt_k and E_k = est_0^-1 est_k (both T_first_vehicle_k). Position drift r(E_k) - r(G_k) in the
    first vehicle frame (x forward, y left, z up); attitude drift the wrapped difference of the ZYX Euler angles
    (roll, pitch, yaw) of C(E_k) and C(G_k). A planar estimate of a hilly drive shows up in z, roll and pitch.

    Returns:
        dict: `final` {x, y, z (m), roll, pitch, yaw (deg)} at the last pose, `max_abs` {z, roll, pitch} over
        time, and `series` arrays (N, 6) (not JSON: the caller drops or converts it).

    Checked by: tests/validation/test_metrics.py::test_drift_*
    """
    gt, est = _pair(gt, est)
    G = align_to_first(gt, np.eye(4))
    E = align_to_first(est, np.eye(4))
    dp = E[:, :3, 3] - G[:, :3, 3]
    da = np.rad2deg(_wrap(euler_zyx(E[:, :3, :3]) - euler_zyx(G[:, :3, :3])))
    series = np.c_[dp, da]
    final = {axis: float(v) for axis, v in zip(DRIFT_AXES, series[-1])}
    max_abs = {axis: float(np.max(np.abs(series[:, k]))) for k, axis in enumerate(DRIFT_AXES) if k in (2, 3, 4)}
    return {"final": final, "max_abs": max_abs, "units": "m for x, y, z; deg for roll, pitch, yaw",
            "series": series}


@dataclass
class PoseErrors:
    """Per-scan errors of an estimate against the truth in the same world frame (rows without truth are NaN).

    Attributes:
        translation: (N,) |p_est - p_true| in metres.
        rotation_deg: (N,) angle of C_est^T C_true in degrees.
        drift: (N, 3) p_est - p_true per world axis x, y, z in metres.
        xi: (N, 6) `consistency.pose_error` of the state poses T_vehicle_world: ln(T_true T_est^-1)^vee, the
            error the pose covariance P describes.
    """

    translation: np.ndarray
    rotation_deg: np.ndarray
    drift: np.ndarray
    xi: np.ndarray


def pose_errors(T_world_vehicle_est, T_world_vehicle_true) -> PoseErrors:
    """Errors of (N, 4, 4) estimates against (N, 4, 4) truth already expressed in the same world frame (e.g.
    by `alignment.align_to_first`); rows of the truth that are not finite (no truth at that scan) give NaN.

    Checked by: tests/validation/test_metrics.py::test_pose_errors_of_a_known_perturbation
    """
    T_est = np.asarray(T_world_vehicle_est, dtype=float)
    T_true = np.asarray(T_world_vehicle_true, dtype=float)
    if T_est.shape != T_true.shape or T_est.shape[1:] != (4, 4):
        raise InputError(f"est, true: expected matching (N, 4, 4) poses, got {T_est.shape} and {T_true.shape}")
    n = len(T_est)
    ok = np.all(np.isfinite(T_true.reshape(n, -1)), axis=1)
    drift_xyz = np.full((n, 3), np.nan)
    rot = np.full(n, np.nan)
    xi = np.full((n, 6), np.nan)
    if ok.any():
        drift_xyz[ok] = T_est[ok, :3, 3] - T_true[ok, :3, 3]
        rot[ok] = np.rad2deg(rotation_angle(np.swapaxes(T_est[ok, :3, :3], 1, 2) @ T_true[ok, :3, :3]))
        xi[ok] = pose_error(se3.inverse(T_true[ok]), se3.inverse(T_est[ok]))
    return PoseErrors(np.linalg.norm(drift_xyz, axis=1), rot, drift_xyz, xi)


def velocity_errors(t_est, varpi_est, t_true, varpi_true, varpi_dot_est=None, varpi_dot_true=None,
                    tolerance: float = DEFAULT_TOLERANCE) -> dict:
    """Errors of the estimated body velocity varpi = [nu; omega] (paper convention) against the truth.

    Times are matched with `associate`; e = varpi_est - varpi_true per matched scan. Reports the RMSE of the
    linear part (m/s, overall and per axis) and of the angular part (deg/s); the same for varpi_dot when both
    are given and the estimate's is not all zeros (the CV model has none).

    Checked by: tests/validation/test_metrics.py::test_velocity_errors_*
    """
    ia, ib = associate(t_est, t_true, tolerance)
    ve = np.asarray(varpi_est, dtype=float)
    vt = np.asarray(varpi_true, dtype=float)
    if ve.shape != (len(t_est), 6) or vt.shape != (len(t_true), 6):
        raise InputError(f"varpi: expected (N, 6) arrays matching the times, got {ve.shape} and {vt.shape}")
    e = ve[ia] - vt[ib]
    ok = np.all(np.isfinite(e), axis=1)
    e = e[ok]
    rms = lambda x: float(np.sqrt(np.mean(x ** 2))) if x.size else float("nan")  # noqa: E731
    out = {"matched": int(len(ia)), "finite": int(ok.sum()),
           "nu_rmse_mps": rms(e[:, :3]) * np.sqrt(3) if e.size else float("nan"),
           "nu_rmse_per_axis_mps": [rms(e[:, k]) for k in range(3)],
           "omega_rmse_degps": float(np.rad2deg(rms(e[:, 3:]) * np.sqrt(3))) if e.size else float("nan")}
    if varpi_dot_est is not None and varpi_dot_true is not None:
        ae = np.asarray(varpi_dot_est, dtype=float)[ia]
        at = np.asarray(varpi_dot_true, dtype=float)[ib]
        if np.any(ae != 0):
            ea = (ae - at)[np.all(np.isfinite(ae - at), axis=1)]
            out["a_rmse_mps2"] = rms(ea[:, :3]) * np.sqrt(3) if ea.size else float("nan")
            out["alpha_rmse_degps2"] = float(np.rad2deg(rms(ea[:, 3:]) * np.sqrt(3))) if ea.size else float("nan")
    return out


def _check_inputs(gt, est, lengths, states, truth, tolerance: float, labels: dict | None) -> tuple:
    """`evaluate`'s arguments checked (InputError naming each by its label, default its name): the trajectories,
    the KITTI lengths (default LENGTHS), and states and a truth that belong to `est` and `gt`."""
    from .evaluation_inputs import check_states_poses, check_states_times, check_truth_poses  # they use this module

    name = {"gt": "gt", "est": "est", "states": "states", "truth": "truth", **(labels or {})}
    for key, traj in (("gt", gt), ("est", est)):
        if not (hasattr(traj, "t") and hasattr(traj, "T_world_vehicle")):
            raise InputError(f"{name[key]}: expected a trajectory with t and T_world_vehicle (sim.sequence.Trajectory, "
                             f"e.g. RunResult.trajectory()), got {type(traj).__name__}")
    try:
        lengths = LENGTHS if lengths is None else tuple(float(L) for L in np.atleast_1d(np.asarray(lengths, float)))
    except (TypeError, ValueError):
        raise InputError(f"lengths: need positive finite KITTI segment lengths (m), got {lengths!r}") from None
    if not lengths or not all(np.isfinite(L) and L > 0 for L in lengths):
        raise InputError(f"lengths: need positive finite KITTI segment lengths (m), got {list(lengths)}")
    for key, arrays in (("states", states), ("truth", truth)):
        missing = [] if arrays is None else [k for k in ("t", "T_vehicle_world", "varpi") if k not in arrays]
        if missing:
            raise InputError(f"{name[key]}: missing array(s) {', '.join(missing)}")
    if states is not None:
        check_states_times(states, est, tolerance, f"{name['states']} and {name['est']}")
        check_states_poses(states, est, f"{name['states']} and {name['est']}")  # the same times: another run's
    if truth is not None:
        check_truth_poses(truth, gt, tolerance, f"{name['truth']} and {name['gt']}")
    return lengths


def evaluate(gt, est, lengths=None, step: int = 10, states: dict | None = None, truth: dict | None = None,
             tolerance: float = DEFAULT_TOLERANCE, alpha: float = 0.05, *, labels: dict | None = None) -> dict:
    """All metrics of one run, as the JSON report of `rodo evaluate` (docs/evaluation.md lists the keys).

    Args:
        gt, est: `sim.sequence.Trajectory`-like objects with `t` (N,) and `T_world_vehicle` (N, 4, 4); their
            times are matched with `associate` (mutual nearest within `tolerance`).
        lengths, step: KITTI segment lengths (m; default validation.kitti.LENGTHS) and first-frame step.
        states: optional states.npz arrays (t, T_vehicle_world, varpi, varpi_dot, P, nis, n_associated,
            ms_per_scan); truth: optional truth.npz arrays (t, T_vehicle_world, varpi, varpi_dot). The states
            must be `est`'s run and the truth `gt`'s drive (validation/evaluation_inputs.py), else InputError.
        labels: what the errors call gt, est, states and truth (default those names; `rodo evaluate` its files).

    Returns:
        dict with kitti_t_err_pct, kitti_r_err_deg_per_m, kitti_segments, segments (per length), ate_*,
        rpe, drift (final, max_abs), matched, and `nees`, `nis`, `velocity`, `consistency` (the odometry
        measures of `odometry_consistency`, 1 s span), `ms_per_scan` when available.
        Values that cannot be computed (path shorter than every KITTI length) are NaN.

    Checked by:
        tests/validation/test_metrics.py::test_evaluate_report_has_the_documented_keys_and_zero_errors_for_truth,
        tests/cli/test_evaluate_cli.py
    """
    lengths = _check_inputs(gt, est, lengths, states, truth, tolerance, labels)
    ig, ie = associate(gt.t, est.t, tolerance)
    G, E = gt.T_world_vehicle[ig], est.T_world_vehicle[ie]
    k = kitti_errors(G, E, lengths, step)
    out = {"matched": int(len(ig)), "gt_poses": int(len(gt.t)), "est_poses": int(len(est.t)),
           "path_length_m": float(path_distances(G)[-1]),
           "kitti_t_err_pct": k.t_err_pct, "kitti_r_err_deg_per_m": k.r_err_deg_per_m,
           "kitti_segments": k.n_segments,
           "segments": [{"length_m": L, "t_err_pct": t, "r_err_deg_per_m": r, "count": n}
                        for L, (t, r, n) in k.per_length().items()]}
    out.update({key: v for key, v in ate(G, E).items()})
    out["rpe"] = rpe(G, E)
    dr = drift(G, E)
    out["drift"] = {"final": dr["final"], "max_abs": dr["max_abs"], "units": dr["units"]}
    if states is not None and "ms_per_scan" in states:
        ms = np.asarray(states["ms_per_scan"], dtype=float)
        out["ms_per_scan"] = {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95))} if ms.size else {}
    if states is not None and "nis" in states and "n_associated" in states:
        out["nis"] = nis_summary(states["nis"], states["n_associated"], alpha)
    if states is not None and truth is not None:
        out["velocity"] = velocity_errors(states["t"], states["varpi"], truth["t"], truth["varpi"],
                                          states.get("varpi_dot"), truth.get("varpi_dot"), tolerance)
        ns = nees_sequence(states, truth, tolerance)
        v = ns["nees"][np.isfinite(ns["nees"])]
        d = ns["dim"]
        per_scan = chi2_bounds(1, d, alpha)
        out["nees"] = {"dim": d, "scans": int(len(ns["nees"])), "finite": int(v.size),
                       "mean": float(v.mean()) if v.size else float("nan"),
                       "median": float(np.median(v)) if v.size else float("nan"),
                       "per_scan_bounds": per_scan.tolist(),
                       "fraction_within": fraction_within(v, per_scan),
                       "time_average_bounds": chi2_bounds(max(v.size, 1), d, alpha).tolist()}
        tau = float(states["velocity_correlation_time"]) if "velocity_correlation_time" in states else 0.25
        out["consistency"] = summarise(odometry_nees(states, truth, span=1.0, tau=tau, tolerance=tolerance), alpha)
        out["error_growth"] = growth_table(error_growth(states, truth, tolerance=tolerance))
    return out


def jsonable(obj):
    """Replace non-finite floats by None and numpy scalars/arrays by Python objects (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    return obj
