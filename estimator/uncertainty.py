"""Pose uncertainty that grows as odometry drift does.

The sliding window holds the local map as constants, so its marginal pose covariance says how well the newest
pose is known RELATIVE TO THE MAP, which was built from earlier estimates: it stays flat while the error
against the world grows (pose NEES of hundreds on the simulated city). Odometry's honest uncertainty is that
of its relative motion, accumulated. These parts make it up (docs/consistency.md has the measurements):

1. the registration of each scan: delta_k = xi_k - Ad(R_k) xi_{k-1}, R_k = T_k T_{k-1}^-1 (left perturbations,
   T = T_vehicle_world), Sigma_rel,k = A P_pair A^T with A = [-Ad(R_k), I] on the pose blocks of the window's
   joint covariance of its two newest states (`relative_pose_covariance`); the one-scan relative pose between
   the EMITTED poses adds the new scan's revision of the previous one (`revision_covariance`), which the
   composition below does not carry;
2. the velocity error, which the motion prior keeps correlated from scan to scan, so that it integrates into
   pose: a first-order Gauss-Markov process b with the window's velocity covariance P_varpi,k as its variance
   and correlation time tau, b_k = phi b_{k-1} + w_k, phi = exp(-dt / tau), Var(w_k) = (1 - phi^2) P_varpi,k,
   from b_0 = 0 at a run's first scan (`DriftCovariance.at_first_scan`: that scan's velocity covariance is the
   initial prior's);
3. a drift rate beta (per metre travelled, vehicle frame), unknown but constant over a run, beta ~ N(0,
   diag(drift_rate_sigma^2)): the registration's systematic error (scan-to-map association on resampled
   surfaces makes every scan's relative pose err the same way; KITTI-style drift is its visible part), which
   grows the error in proportion to the distance s_k = |t(R_k)| driven, not its square root.

    xi_k = Ad(R_k) xi_{k-1} + dt phi b_{k-1} + dt w_k + s_k beta + delta_k

4. optionally, the heading's reversion (`heading_reversion_matrix`; off by default): the yaw error reverts, with
   time constant T_r, to an anchor a that follows it with time constant T_a >> T_r (the far scene, seen for tens
   of scans, holds the heading: on hills and highway the yaw error over 20 s is a fraction of the composed
   steps', docs/consistency.md, "The heading reverts"). Before each step, d yaw = -(yaw - a) / T_r dt,
   d a = (yaw - a) / T_a dt, exactly over dt; the weighted mean (T_r yaw + T_a a) / (T_r + T_a) keeps random
   walking, so the yaw's variance still grows without bound, (T_r / (T_r + T_a))^2 as fast over long spans.

`DriftCovariance` runs this recursion over [xi; b; beta] (18 x 18; [xi; b; beta; a], 19 x 19, with the heading's
reversion) from scan to scan (the absolute pose covariance) and `span_covariance` over any span (the covariance
of a relative pose over, e.g., 1 s). tau = 0 drops the second part (the per-scan relative errors composed as
independent), drift_rate_sigma = 0 the third, a reversion time of 0 the fourth. Beside the recursion, not in it,
a smooth roll and pitch jitter adds to the reported covariances (`attitude_jitter`; off by default), and a bounded
error per axis, whose one-scan change the recursion's inputs leave out, adds its change over a span with its lever
arm (`stationary_error`; off by default). `reported_covariances.ReportedCovariances` puts them together per scan.
Across a re-initialisation (`restart_matrices`) the step is the dead-reckoned relative pose alone: no
registration ran over the outage, so neither the velocity error nor the drift rate adds to it, and b starts
again at zero as at a run's first scan (the fresh window's velocity covariance is the initial prior's, and the
next scan is registered against the fresh map).
The velocity covariance the recursion uses is the window's times `[uncertainty] velocity_error_share` g (1 by
default; the registration pins each pose to the map, so less of the window's velocity error reaches the relative
pose than dead reckoning would carry; + `velocity_error_share_per_speed` times the speed, 0 by default: less at
rest than at speed), plus `registration_correlation` alpha (0 by default) of the scan's relative
pose covariance over dt^2, which then composes the rest, (1 - alpha) Sigma_rel,k, as independent: the registration's
errors are correlated over a few scans (`recursion_inputs`; per axis with `registration_axis_correlation`,
`registration_shares`); the reported one has its variance scaled with the
speed where calibrated (`velocity_inflation.velocity_inflated`).

Checked by: tests/estimator/test_uncertainty.py::test_relative_covariance_of_a_known_joint_gaussian,
    ::test_drift_covariance_matches_monte_carlo_of_the_model, ::test_span_covariance_equals_the_recursion,
    ::test_the_drift_recursion_starts_without_the_first_scans_velocity_error,
    ::test_the_restart_adds_the_prediction_not_the_last_states_own_covariance,
    ::test_a_blackout_is_not_counted_twice_at_the_restart,
    ::test_the_restart_starts_the_velocity_error_again,
    ::test_the_restart_is_flagged_and_adds_the_dead_reckoned_step_alone,
    tests/estimator/test_heading_reversion.py,
    tests/estimator/test_uncertainty_inflation.py::test_velocity_inflation_scales_the_velocity_variance_only
"""

from __future__ import annotations

import numpy as np

from .heading_reversion import (ANCHOR, YAW, anchored_at_yaw, heading_reversion_array,
                               heading_reversion_matrix, reversion_coefficients, state_size)
from .lie import se3
from .stationary_error import taken_out
from .uncertainty_kernels import drift_step, relative_covariances

NO_REVERSION = np.zeros(4)  # drift_step's coefficients without the heading's reversion (unused there)


def relative_pose_covariance(P_pair: np.ndarray, T_prev: np.ndarray, T_new: np.ndarray, dim: int) -> np.ndarray:
    """Sigma_rel (6, 6) of delta = xi_new - Ad(T_new T_prev^-1) xi_prev from the joint covariance P_pair
    (2 dim, 2 dim) of two consecutive states [x_prev; x_new] (pose first in each block of `dim`)."""
    A = np.hstack([-se3.adjoint(T_new @ se3.inverse(T_prev)), np.eye(6)])
    idx = np.r_[0:6, dim:dim + 6]
    S = A @ P_pair[np.ix_(idx, idx)] @ A.T
    return 0.5 * (S + S.T)


def predicted_relative_covariance(P: np.ndarray, F: np.ndarray, Q: np.ndarray, T_prev: np.ndarray,
                                  T_new: np.ndarray) -> np.ndarray:
    """Sigma_rel (6, 6) of a state predicted by the motion prior (Jacobian F, noise Q) relative to the state it
    was predicted from (covariance P, dim x dim): `relative_pose_covariance` of their joint covariance [[P, P F^T],
    [F P, F P F^T + Q]]. What dead reckoning across an outage adds to the absolute pose covariance; the covariance
    of the state it starts from (relative to the map, grown over the outage) is in that already."""
    FP = F @ P
    joint = np.block([[P, FP.T], [FP, FP @ F.T + Q]])
    return relative_pose_covariance(joint, T_prev, T_new, P.shape[0])


def revision_covariance(P_prev_emitted: np.ndarray, P_prev_now: np.ndarray, T_prev: np.ndarray,
                        T_new: np.ndarray) -> np.ndarray:
    """(6, 6) what the new scan's revision of the previous pose adds to the covariance of the relative pose
    between the EMITTED poses (the previous one as emitted one scan earlier, the new one as solved), in the frame
    of `relative_pose_covariance`'s delta: Ad (P_prev_emitted - P_prev_now) Ad^T, Ad = Ad(T_new T_prev^-1), on
    the pose blocks (>= 6 x 6, pose first) of the previous state's covariance when emitted and now.

    The revision r (the previous pose's estimate now minus the one emitted) is a function of the new data,
    uncorrelated with the smoothed pair's error, with covariance P_prev_emitted - P_prev_now (the information
    the new scan added about the previous pose; clipped to positive semi-definite where a forgetting prior lost
    some). Exact for a linear Gaussian window. It matters most at the start of a drive (the second scan's
    relative pose had NEES/dof up to 170 without it on `hills`), but not only there: on hills the revisions are
    about as large as the smoothed pair's sigmas (docs/consistency.md, "The emitted relative pose").

    A relative pose over a span from an emitted pose j carries the revision of pose j alone (the later poses'
    revisions telescope), and an absolute pose none: the drift recursion composes the smoothed pairs'
    covariances, and the span measures add the revision at their first scan.
    """
    Ad = se3.adjoint(T_new @ se3.inverse(T_prev))
    D = np.asarray(P_prev_emitted, dtype=float)[:6, :6] - np.asarray(P_prev_now, dtype=float)[:6, :6]
    w, V = np.linalg.eigh(0.5 * (D + D.T))
    R = Ad @ ((V * np.maximum(w, 0.0)) @ V.T) @ Ad.T
    return 0.5 * (R + R.T)


def scan_relative_covariances(P_pair: np.ndarray, P_emitted: np.ndarray | None, T_prev: np.ndarray,
                              T_new: np.ndarray, dim: int, solved: bool) -> tuple[np.ndarray, np.ndarray]:
    """(`relative_pose_covariance`, `revision_covariance` if the previous pose was emitted as solved, else zeros) of
    one scan from one compiled call (`uncertainty_kernels.relative_covariances`; equal to the two to rounding):
    the odometry's per-scan pair."""
    rel, rev = np.empty((6, 6)), np.empty((6, 6))
    P_pair = _matrix(P_pair, 2 * dim)
    relative_covariances(P_pair, P_pair if P_emitted is None else np.ascontiguousarray(P_emitted, dtype=float),
                         _pose(T_prev), _pose(T_new), int(dim), bool(solved), rel, rev)
    return rel, rev


def _initial(P_pose: np.ndarray, P_varpi: np.ndarray, tau: float, drift_rate_sigma, heading=None) -> np.ndarray:
    """C = Cov([xi; b; beta]) (18, 18) at a start: the pose's, the velocity error at its stationary variance
    (when tau > 0), the drift rate at its prior; with the heading's reversion on (`heading`, [T_r, T_a]) (19, 19),
    the anchor at the yaw error (`heading_reversion.anchored_at_yaw`)."""
    C = np.zeros((state_size(heading),) * 2)
    C[:6, :6] = P_pose
    if tau > 0:
        C[6:12, 6:12] = P_varpi
    C[12:18, 12:18] = np.diag(np.square(drift_rate_sigma_array(drift_rate_sigma)))
    return anchored_at_yaw(C) if len(C) > 18 else C


def drift_rate_sigma_array(drift_rate_sigma) -> np.ndarray:
    """(6,) sigma of the drift rate: [x, y, z] in m/m, [roll, pitch, yaw] in rad/m; None means zero."""
    return np.zeros(6) if drift_rate_sigma is None else np.asarray(drift_rate_sigma, dtype=float).reshape(6)


def _step(C: np.ndarray, T_prev, T_new, dt: float, Sigma_rel, P_varpi, tau: float, heading=None) -> np.ndarray:
    """One scan of the recursion over C = Cov([xi; b; beta]) (18, 18), or (19, 19) with the heading's anchor
    (reverted first: `heading_reversion_matrix`)."""
    n = len(C)
    phi = np.exp(-dt / tau) if tau > 0 else 0.0
    R = T_new @ se3.inverse(T_prev)
    A = np.zeros((n, n))
    A[:6, :6] = se3.adjoint(R)
    A[:6, 6:12] = dt * phi * np.eye(6)
    A[6:12, 6:12] = phi * np.eye(6)
    A[:6, 12:18] = np.linalg.norm(R[:3, 3]) * np.eye(6)
    A[12:, 12:] = np.eye(n - 12)
    if n > 18:
        A = A @ heading_reversion_matrix(dt, heading)
    W = (1.0 - phi**2) * P_varpi if tau > 0 else np.zeros((6, 6))
    Q = np.zeros((n, n))
    Q[:6, :6] = dt * dt * W + Sigma_rel
    Q[:6, 6:12] = Q[6:12, :6] = dt * W
    Q[6:12, 6:12] = W
    C = A @ C @ A.T + Q
    return 0.5 * (C + C.T)


def restart_matrices(T_prev, T_new, Sigma_rel: np.ndarray, heading=None) -> tuple[np.ndarray, np.ndarray]:
    """A, Q (18, 18) of the recursion's step across a re-initialisation, x <- A x + w, Cov(w) = Q: the pose carried
    by Ad(T_new T_prev^-1) plus the dead-reckoned relative pose (covariance Sigma_rel,
    `predicted_relative_covariance`), the velocity error b set to zero (its row of A zero, no noise: the fresh
    window starts from the initial prior's velocity and the next scan is registered against the fresh map, as
    at a run's first scan), the drift rate kept and not applied over the outage (no registration ran). With the
    heading's reversion (19, 19): the anchor set to the new yaw error (the map is new).

    An approximation: the dead-reckoned step starts from the last window's velocity, whose error b was, so the
    step's error is correlated with the pose's (by about dt C[xi, b]); zeroing b drops that. Small where the
    outage's empty scans were processed (dt one scan interval), larger where a gap had none.

    Checked by: tests/estimator/test_uncertainty.py::test_the_restart_starts_the_velocity_error_again
    """
    n = state_size(heading)
    A = np.zeros((n, n))
    A[:6, :6] = se3.adjoint(T_new @ se3.inverse(T_prev))
    A[12:18, 12:18] = np.eye(6)
    Q = np.zeros((n, n))
    Q[:6, :6] = Sigma_rel
    if n > 18:
        A[ANCHOR] = A[YAW]
        anchored_at_yaw(Q)
    return A, Q


def _restart_step(C: np.ndarray, T_prev, T_new, Sigma_rel, heading=None) -> np.ndarray:
    """One scan of the recursion across a re-initialisation (`restart_matrices`)."""
    A, Q = restart_matrices(T_prev, T_new, Sigma_rel, heading)
    C = A @ C @ A.T + Q
    return 0.5 * (C + C.T)


class DriftCovariance:
    """The absolute pose covariance of one run, scan by scan (the recursion of the module docstring).

    Args:
        P_pose0: (6, 6) covariance of the first pose.
        P_varpi0: (6, 6) covariance of the first velocity.
        tau: correlation time (s) of the velocity error; 0: none.
        drift_rate_sigma: (6,) sigma of the constant drift rate per metre (m/m, rad/m); None: none.
        heading: [T_r, T_a] (s) of the heading's reversion (`heading_reversion`); None or T_r = 0: off.
    """

    def __init__(self, P_pose0: np.ndarray, P_varpi0: np.ndarray, tau: float, drift_rate_sigma=None, heading=None):
        self.tau = float(tau)
        self.heading = heading_reversion_array(heading)
        self.C = _initial(P_pose0, P_varpi0, self.tau, drift_rate_sigma, self.heading)

    @classmethod
    def at_first_scan(cls, P_pose0: np.ndarray, tau: float, drift_rate_sigma=None, heading=None) -> "DriftCovariance":
        """The recursion of a run from its first scan: the velocity error b starts at zero. The first scan's
        velocity covariance is the initial prior's (a yaw rate of 0.2 rad/s with the defaults: one scan's
        Doppler does not see it), and the next scan's pose is registered against the first scan's map, not
        dead-reckoned with that velocity. Taken as b's variance it put 9 mrad of yaw into the first step where
        the registration allowed 0.6 (hills), and that yaw times the distance into the lateral position for
        the rest of the drive. b reaches its stationary variance within a few tau."""
        return cls(P_pose0, np.zeros((6, 6)), tau, drift_rate_sigma, heading)

    def update(self, T_prev, T_new, dt: float, Sigma_rel: np.ndarray, P_varpi: np.ndarray) -> np.ndarray:
        """Advance by one scan (`_step`, compiled: `uncertainty_kernels.drift_step`); returns the new absolute
        pose covariance (6, 6)."""
        C = np.empty_like(self.C)
        reversion = reversion_coefficients(float(dt), self.heading) if len(C) > ANCHOR else NO_REVERSION
        drift_step(self.C, _pose(T_prev), _pose(T_new), float(dt), _matrix(Sigma_rel, 6), _matrix(P_varpi, 6),
                   self.tau, reversion, C)
        self.C = C
        return C[:6, :6].copy()

    def restart(self, T_prev, T_new, Sigma_rel: np.ndarray) -> np.ndarray:
        """Advance across a re-initialisation (`restart_matrices`); returns the new absolute pose covariance."""
        self.C = _restart_step(self.C, _pose(T_prev), _pose(T_new), _matrix(Sigma_rel, 6), self.heading)
        return self.C[:6, :6].copy()

    @property
    def deviation(self) -> float:
        """Var(yaw - a), the variance of the yaw error's deviation from its anchor (0 without the heading's
        reversion): what a span starting here carries (`span_covariance`'s `deviation`)."""
        C = self.C
        return float(C[YAW, YAW] + C[ANCHOR, ANCHOR] - 2.0 * C[YAW, ANCHOR]) if len(C) > ANCHOR else 0.0


def recursion_inputs(P_relative, P_varpi, dt, correlation=0.0, share: float = 1.0,
                     share_per_speed: float = 0.0, speed=None, stationary=None):
    """(Sigma_rel, the velocity error's variance) the drift recursion composes for a registered scan (one, or a
    stack with dt (N,)): (1 - alpha) P_relative and g P_varpi + alpha P_relative / dt^2, alpha = `[uncertainty]
    registration_correlation` (the share of the registration's covariance carried correlated over tau, with the
    velocity error), g = `velocity_error_share` + `velocity_error_share_per_speed` x `speed` (the scan's |nu|, m/s;
    (N,) with a stack); (P_relative, P_varpi) themselves, bit for bit, at alpha 0, g 1 and no speed term.
    One scan then still composes P_relative + g dt^2 P_varpi (the correlated part's one-scan share is alpha
    P_relative, smoothed over tau where it varies); a span adds the correlation. With a stationary error
    ([V; T], `estimator.stationary_error`; None: off) its one-scan change is taken out of P_relative first
    (`stationary_error.taken_out`). `correlation` may be (6,), a share per axis (`registration_shares`): then
    B P_relative B and A P_relative A / dt^2, A = diag(sqrt(alpha)), B = diag(sqrt(1 - alpha)) (the registration's
    error the sum of a correlated and an independent part, per axis; the same as the scalar's where all are equal).

    Checked by:
        tests/estimator/test_recursion_inputs.py::test_a_correlated_registration_keeps_one_scan_and_grows_a_span,
        ::test_the_velocity_error_share_grows_with_the_speed,
        ::test_a_registration_correlation_per_axis_grows_its_axis_alone
    """
    P_relative = taken_out(P_relative, dt, stationary)
    per_axis = np.ndim(correlation) > 0
    if not per_axis and correlation == 0.0 and share == 1.0 and share_per_speed == 0.0:
        return P_relative, P_varpi
    P_relative = np.asarray(P_relative, dtype=float)
    dt = np.asarray(dt, dtype=float)[..., None, None]
    g = share if share_per_speed == 0.0 else share + share_per_speed * np.asarray(speed, dtype=float)[..., None, None]
    if not per_axis:
        return (1.0 - correlation) * P_relative, g * np.asarray(P_varpi, dtype=float) + correlation * P_relative / dt**2
    a = np.asarray(correlation, dtype=float).reshape(6)
    A, B = np.sqrt(a), np.sqrt(1.0 - a)
    return (B[:, None] * P_relative * B[None, :],
            g * np.asarray(P_varpi, dtype=float) + A[:, None] * P_relative * A[None, :] / dt**2)


def registration_shares(alpha: float, axis_correlation=None):
    """The registration's correlated share for `recursion_inputs`: alpha itself (a float) where the per-axis shares
    a (`[uncertainty] registration_axis_correlation`; None: none) are all 0, else (6,) alpha + (1 - alpha) a."""
    a = np.zeros(6) if axis_correlation is None else np.asarray(axis_correlation, dtype=float).reshape(6)
    return float(alpha) if not a.any() else float(alpha) + (1.0 - float(alpha)) * a


def fresh_starts(restarts, n: int) -> np.ndarray:
    """(n,) bool: the scans from which the velocity error b starts at zero, a run's first
    (`DriftCovariance.at_first_scan`) and every re-initialisation (`restarts` (n,), states.npz `restarted`; None:
    none); a span from any other scan starts b at its stationary variance."""
    starts = np.zeros(n, bool) if restarts is None else np.array(restarts, dtype=bool)
    starts[:1] = True
    return starts


def _pose(T) -> np.ndarray:
    return np.ascontiguousarray(T, dtype=float).reshape(4, 4)


def _matrix(A, n: int) -> np.ndarray:
    return np.ascontiguousarray(A, dtype=float).reshape(n, n)


def span_covariance(T: np.ndarray, t: np.ndarray, Sigma_rel: np.ndarray, P_varpi: np.ndarray, start: int,
                    end: int, tau: float, drift_rate_sigma=None, restarts=None, heading=None,
                    deviation: float = 0.0) -> np.ndarray:
    """Covariance (6, 6) of the relative pose T_end T_start^-1 of a run: the recursion from a known pose at
    scan `start` (the velocity error at its stationary variance P_varpi[start], at zero from the run's first scan
    as in `DriftCovariance.at_first_scan` or from a re-initialisation; the drift rate at its prior; the heading's
    anchor, where on, off the start pose by the yaw's deviation from it, variance `deviation` (the run's
    `DriftCovariance.deviation` at `start`), which reverts over the span) to scan `end`; the step into a scan
    flagged in `restarts` is the re-initialisation's (`restart_matrices`).

    Args:
        T: (N, 4, 4) estimated T_vehicle_world; t: (N,) times.
        Sigma_rel: (N, 6, 6) per-scan relative covariances (row j: from scan j-1 to j; NaN rows count as 0).
        P_varpi: (N, 6, 6) the velocity covariances.
        start, end: scan indices, start < end.
        tau: the velocity error's correlation time (s).
        drift_rate_sigma: (6,) sigma of the drift rate per metre; None: none.
        restarts: (N,) bool, the scans at which the run re-initialised (states.npz `restarted`); None: none.
        heading: [T_r, T_a] (s) of the heading's reversion; None: off.
        deviation: Var(yaw - anchor) at `start` (with the heading's reversion; taken as uncorrelated with the
            rest of the state).
    """
    restarts = np.zeros(len(t), bool) if restarts is None else np.asarray(restarts, dtype=bool)
    C = _initial(np.zeros((6, 6)), np.zeros((6, 6)) if fresh_starts(restarts, len(t))[start] else P_varpi[start], tau,
                 drift_rate_sigma, heading)
    if len(C) > ANCHOR:
        C[ANCHOR, ANCHOR] = deviation  # the anchor at -(yaw - a) from the start pose
    for j in range(start + 1, end + 1):
        S = Sigma_rel[j] if np.isfinite(Sigma_rel[j]).all() else np.zeros((6, 6))
        if restarts[j]:
            C = _restart_step(C, T[j - 1], T[j], S, heading)
        else:
            C = _step(C, T[j - 1], T[j], t[j] - t[j - 1], S, P_varpi[j], tau, heading)
    return C[:6, :6]
