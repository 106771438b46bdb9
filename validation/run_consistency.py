"""The consistency of one run (a `validation.driver.RunResult`) scan by scan: what a campaign trial stores and
what the Rerun recording draws (docs/evaluation.md, "Consistency in campaigns"; docs/visualisation.md).

- `run_states`: the states.npz arrays of a run, in memory (the inputs of `odometry_consistency.odometry_nees`);
- `scan_measures`: `odometry_nees` laid out per estimate (NaN where a scan has no truth);
- `ellipsoid_coverage`: whether the true position lies inside the n-sigma ellipsoid of the world position
  covariance (`covariance.position_covariance_world` of `P_pose_absolute`), and the running fraction of scans
  where it does, against the fraction the ellipsoid claims, chi2.cdf(n^2, 3) (97.1 % for 3 sigma);
- `truth_coverage`: that of a run's states against its truth.npz (a campaign trial's `ellipsoid_3sigma_pct`).

Checked by: tests/validation/test_campaign_consistency.py::test_run_consistency_per_scan_and_ellipsoid_coverage,
    tests/viz/test_recording.py::test_recording_has_every_consistency_measure
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from rodo.estimator.lie import se3

from .association import DEFAULT_TOLERANCE, match_index
from .consistency import nees
from .covariance import position_covariance_world
from .odometry_consistency import MEASURES, matched_poses, odometry_nees

DEFAULT_TAU = 0.25  # s, the estimator's default velocity_correlation_time (older runs did not record theirs)


def run_states(result) -> dict:
    """The arrays `validation.driver.write_run` writes to states.npz, of a RunResult in memory
    (`RunResult.state_arrays`): the inputs of `odometry_consistency.odometry_nees`."""
    return result.state_arrays()


def scan_measures(states: dict, truth: dict, span: float = 1.0, tolerance: float = DEFAULT_TOLERANCE) -> dict:
    """`odometry_nees` of every measure (MEASURES) for every state row: (N,) arrays, NaN where the scan has no
    truth; plus t (N,), dof and span. The velocity correlation time is the run's own (states'
    velocity_correlation_time, DEFAULT_TAU when absent)."""
    tau = float(states["velocity_correlation_time"]) if "velocity_correlation_time" in states else DEFAULT_TAU
    m = odometry_nees(states, truth, span=span, tau=tau, tolerance=tolerance)
    t = np.asarray(states["t"], dtype=float)
    idx = match_index(t, m["t"], tolerance)
    ok = idx >= 0
    out = {"t": t, "dof": m["dof"], "span": m["span"]}
    for name in MEASURES:
        v = np.full(len(t), np.nan)
        v[ok] = np.asarray(m[name], dtype=float)[idx[ok]]
        out[name] = v
    return out


def ellipsoid_coverage(p_world_est, p_world_true, T_vehicle_world, P_pose, n_sigma: float = 3.0) -> dict:
    """Is the true position inside the n-sigma ellipsoid of the estimated one, scan by scan?

    The ellipsoid is that of Sigma_w = C^T P_pose[:3, :3] C (`position_covariance_world`, left perturbation of
    T_vehicle_world = [C, r]) centred on the estimated world position; the truth is inside when the squared
    Mahalanobis distance d2 = e^T Sigma_w^-1 e, e = p_true - p_est, is <= n_sigma^2. A consistent estimate has
    it inside with probability chi2.cdf(n_sigma^2, 3).

    Args:
        p_world_est, p_world_true: (N, 3) positions in the same world frame (NaN rows: no truth).
        T_vehicle_world: (N, 4, 4) estimated state poses.
        P_pose: (N, 6, 6) pose covariances (e.g. P_pose_absolute; a singular one gives NaN).
        n_sigma: the ellipsoid's scale.

    Returns:
        dict: d2 (N,), inside (N,) 1.0 / 0.0 / NaN (undefined), running_fraction (N,) the fraction of the scans
        so far (defined ones) with the truth inside (NaN before the first), fraction (float, NaN when none),
        claimed (float).
    """
    e = np.asarray(p_world_true, dtype=float) - np.asarray(p_world_est, dtype=float)
    Sigma_w = position_covariance_world(T_vehicle_world, np.asarray(P_pose, dtype=float)[:, :3, :3])
    d2 = nees(e, Sigma_w)
    fin = np.isfinite(d2)
    inside = np.where(fin, (d2 <= n_sigma**2).astype(float), np.nan)
    count = np.cumsum(fin)
    with np.errstate(invalid="ignore", divide="ignore"):
        running = np.where(count > 0, np.cumsum(np.where(fin, inside, 0.0)) / np.maximum(count, 1), np.nan)
    return {"d2": d2, "inside": inside, "running_fraction": running,
            "fraction": float(np.mean(inside[fin])) if fin.any() else float("nan"),
            "claimed": float(chi2.cdf(n_sigma**2, 3))}


def runs_of(states, truth) -> list[tuple[dict, dict]]:
    """[(states, truth), ...]: one run (two dicts) or several (two lists of the same length)."""
    if isinstance(states, dict):
        return [(states, truth)]
    states, truth = list(states), list(truth)
    if len(states) != len(truth) or not states:
        raise ValueError(f"runs: {len(states)} states for {len(truth)} truths")
    return list(zip(states, truth))


def truth_coverage(states: dict, truth: dict, n_sigma: float = 3.0, tolerance: float = DEFAULT_TOLERANCE) -> dict:
    """`ellipsoid_coverage` of a run's states (`P_pose_absolute`) against its truth at the scans that have one, the
    true poses in the estimator's world as `odometry_nees` aligns them (the first matched true pose on the first
    matched estimate). A run without P_pose_absolute or without matched scans: fraction NaN.

    Checked by: tests/validation/test_campaign_consistency.py::test_campaign_trials_report_the_ellipsoid_coverage
    """
    ia, _, T_est, T_true = matched_poses(states, truth, tolerance)
    if "P_pose_absolute" not in states or not len(ia):
        return {"fraction": float("nan"), "claimed": float(chi2.cdf(n_sigma**2, 3))}
    return ellipsoid_coverage(se3.inverse(T_est)[:, :3, 3], se3.inverse(T_true)[:, :3, 3], T_est,
                              np.nan_to_num(np.asarray(states["P_pose_absolute"], dtype=float)[ia]), n_sigma)
