"""The numbers a run recording plots: truth alignment, pose errors, NEES with chi-square bounds, and the
world-frame position covariance with its 3-sigma ellipsoid. Plain numpy/scipy (no rerun, no matplotlib).

Frames: the estimator's world frame `e` is its own first frame (T_vehicle_world = I at the first scan); the
ground truth lives in its own world frame `g`. `align_to_first` finds T_e_g with T_e_g T_g_v(0) = T_e_v(0) and
maps the whole truth into `e`, so both trajectories start at the same pose (docs/visualisation.md).

Checked by: tests/viz/test_recording.py
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from rodo.estimator.errors import InputError, check_finite
from rodo.estimator.lie import se3, so3


def nees_bounds(dof: int, n_runs: int = 1, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided chi-square bounds of the NEES averaged over `n_runs` independent runs.

    n_runs * mean NEES ~ chi2(n_runs * dof) for a consistent estimator, so the bounds are
    chi2.ppf((1 -+ prob) / 2, n_runs * dof) / n_runs (navlie's convention; Bar-Shalom sec. 5.4.2).

    Args:
        dof: dimension of the error (6 for a pose, 4 for a radar measurement).
        n_runs: number of runs (or of terms) averaged, >= 1.
        prob: two-sided probability mass between the bounds, in (0, 1).

    Returns:
        (lower, upper).

    Checked by: tests/viz/test_recording.py::test_nees_bounds_match_chi_square_quantiles
    """
    if int(dof) != dof or dof < 1:
        raise InputError(f"dof: must be a positive integer, got {dof!r}")
    if int(n_runs) != n_runs or n_runs < 1:
        raise InputError(f"n_runs: must be a positive integer, got {n_runs!r}")
    if not 0.0 < float(prob) < 1.0:
        raise InputError(f"prob: must be in (0, 1), got {prob!r}")
    k = int(n_runs) * int(dof)
    a = 0.5 * (1.0 - float(prob))
    return float(chi2.ppf(a, k) / n_runs), float(chi2.ppf(1.0 - a, k) / n_runs)


def nees_bounds_array(dof: int, n_terms, prob: float = 0.95) -> np.ndarray:
    """`nees_bounds(dof, n)` for an array of term counts n (N,) -> (N, 2); rows with n <= 0 are NaN.

    Checked by: tests/viz/test_recording.py::test_nees_bounds_match_chi_square_quantiles
    """
    n = np.asarray(n_terms, dtype=float).reshape(-1)
    out = np.full((len(n), 2), np.nan)
    ok = n > 0
    if ok.any():
        nees_bounds(dof, 1, prob)  # validates dof and prob
        a = 0.5 * (1.0 - float(prob))
        out[ok, 0] = chi2.ppf(a, n[ok] * dof) / n[ok]
        out[ok, 1] = chi2.ppf(1.0 - a, n[ok] * dof) / n[ok]
    return out


def align_to_first(T_a_vehicle, T_b_vehicle0) -> np.ndarray:
    """Poses (N, 4, 4) T_a_v of a trajectory expressed in another world frame b, aligned by the first pose:
    T_b_a T_a_v with T_b_a = T_b_v(0) T_a_v(0)^-1, so the first aligned pose equals T_b_vehicle0.

    (The recording maps the truth into the estimator's frame; Fig. 4 maps the estimates into the truth's.)
    """
    Ta = check_finite("T_a_vehicle", T_a_vehicle, (4, 4)).reshape(-1, 4, 4)
    Tb0 = check_finite("T_b_vehicle0", T_b_vehicle0, (4, 4))
    return (Tb0 @ se3.inverse(Ta[0])) @ Ta


def match_times(t_est, t_truth, tol: float = 1e-6) -> np.ndarray:
    """Index into t_truth of each t_est (nearest), or -1 where no truth time lies within tol seconds."""
    t_est = np.asarray(t_est, dtype=float)
    t_truth = np.asarray(t_truth, dtype=float)
    if len(t_truth) == 0:
        return np.full(len(t_est), -1, dtype=np.int64)
    order = np.argsort(t_truth)
    ts = t_truth[order]
    hi = np.clip(np.searchsorted(ts, t_est), 0, len(ts) - 1)
    lo = np.maximum(hi - 1, 0)
    pick = np.where(np.abs(ts[lo] - t_est) <= np.abs(ts[hi] - t_est), lo, hi)
    ok = np.abs(ts[pick] - t_est) <= tol
    return np.where(ok, order[pick], -1).astype(np.int64)


@dataclass
class PoseErrors:
    """Per-scan errors of the estimate against the aligned truth (rows without truth are NaN).

    Attributes:
        translation: (N,) |p_est - p_true| in metres (world frame e).
        rotation_deg: (N,) angle of C_est^T C_true in degrees.
        drift: (N, 3) p_est - p_true per world axis x, y, z in metres.
        xi: (N, 6) left-perturbation error xi = ln(T_true T_est^-1)^vee of the state pose T_vehicle_world
            (the error the covariance P describes: T_true = exp(xi^) T_est).
    """

    translation: np.ndarray
    rotation_deg: np.ndarray
    drift: np.ndarray
    xi: np.ndarray


def pose_errors(T_world_vehicle_est, T_world_vehicle_true) -> PoseErrors:
    """Errors of (N, 4, 4) estimates against (N, 4, 4) truth in the same world frame (NaN rows allowed in
    the truth: they give NaN errors)."""
    Te = np.asarray(T_world_vehicle_est, dtype=float)
    Tt = np.asarray(T_world_vehicle_true, dtype=float)
    n = len(Te)
    ok = np.all(np.isfinite(Tt.reshape(n, -1)), axis=1)
    drift = np.full((n, 3), np.nan)
    rot = np.full(n, np.nan)
    xi = np.full((n, 6), np.nan)
    if ok.any():
        drift[ok] = Te[ok, :3, 3] - Tt[ok, :3, 3]
        dC = np.swapaxes(Te[ok, :3, :3], 1, 2) @ Tt[ok, :3, :3]
        rot[ok] = np.degrees(np.linalg.norm(so3.log(dC), axis=1))
        # state poses T = T_vehicle_world: xi = ln(T_true T_est^-1) = ln(T_v_w,true T_w_v,est)
        xi[ok] = se3.log(se3.inverse(Tt[ok]) @ Te[ok])
    return PoseErrors(np.linalg.norm(drift, axis=1), rot, drift, xi)


def nees(err, P) -> np.ndarray:
    """Normalised estimation error squared e^T P^-1 e per row: err (N, d), P (N, d, d) -> (N,) (NaN rows stay
    NaN).

    Checked by: tests/viz/test_recording.py::test_nees_is_chi_square_for_sampled_errors
    """
    err = np.asarray(err, dtype=float)
    P = np.asarray(P, dtype=float)
    out = np.full(len(err), np.nan)
    ok = np.all(np.isfinite(err), axis=1)
    if ok.any():
        sol = np.linalg.solve(P[ok], err[ok][..., None])[..., 0]
        out[ok] = np.einsum("ni,ni->n", err[ok], sol)
    return out


def position_covariance_world(T_vehicle_world, P_rho) -> np.ndarray:
    """Covariance of the vehicle's world position from the left-perturbation covariance of T_vehicle_world.

    With T = T_vehicle_world = [C, r] and T_true = exp(xi^) T, xi = [rho; phi], the vehicle's world position
    r_w = -C^T r becomes r_w' = -C^T exp(-phi^) (exp(phi^) r + J(phi) rho) = r_w - C^T J_r(phi) rho, so to
    first order dr_w = -C^T rho (phi drops out) and

        Sigma_w = C^T P_rho C,    P_rho = P[:3, :3].

    Args:
        T_vehicle_world: (..., 4, 4) state poses.
        P_rho: (..., 3, 3) translational block of the pose covariance.

    Returns:
        (..., 3, 3) world-frame covariance of the vehicle position.

    Checked by: tests/viz/test_recording.py::test_position_covariance_world_monte_carlo
    """
    T = np.asarray(T_vehicle_world, dtype=float)
    C = T[..., :3, :3]
    return np.swapaxes(C, -1, -2) @ np.asarray(P_rho, dtype=float) @ C


def covariance_ellipsoid(Sigma, n_sigma: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Half sizes and rotation of the n-sigma ellipsoid of 3x3 covariances.

    Sigma = V diag(lambda) V^T with V a proper rotation (a column flipped if det V = -1); the ellipsoid
    {x : x^T Sigma^-1 x <= n^2} has half sizes n sqrt(lambda) along V's columns.

    Args:
        Sigma: (..., 3, 3) symmetric positive semi-definite.
        n_sigma: scale (3 for the 3-sigma ellipsoid).

    Returns:
        (half_sizes (..., 3), quaternions (..., 4) [qx, qy, qz, qw] with qw >= 0).

    Checked by: tests/viz/test_recording.py::test_covariance_ellipsoid_reconstructs_sigma
    """
    S = np.asarray(Sigma, dtype=float)
    S = 0.5 * (S + np.swapaxes(S, -1, -2))
    lam, V = np.linalg.eigh(S)
    flip = np.linalg.det(V) < 0
    V[..., :, 0] = np.where(flip[..., None], -V[..., :, 0], V[..., :, 0])
    half = float(n_sigma) * np.sqrt(np.maximum(lam, 0.0))
    q = Rotation.from_matrix(V.reshape(-1, 3, 3)).as_quat().reshape(S.shape[:-2] + (4,))
    q = np.where(q[..., 3:4] < 0, -q, q)
    return half, q
