"""The span covariances of a whole run at once: `estimator.uncertainty.span_covariance` for every span of n scans
ending at scans n .. N-1, bit for bit, in batched matrix products instead of one Python recursion per span.

The odometry consistency measures (`validation.odometry_consistency`, relative_scan and relative_span) need the
covariance of T_k T_{k-n}^-1 for every scan k: N - n recursions of n steps each, C <- A_j C A_j^T + Q_j
(`uncertainty._step`), about 13,000 small steps for a 60 s run with a 1 s span, the costliest part of a
campaign trial's evaluation (0.7-1.4 s per model). The step matrices A_j, Q_j depend on the scan j only, not on
the span, so they are built once per scan (with the same arithmetic as `_step`, scan by scan), and the N - n
recursions advance together: step i applies A_{start+i} to every span at once. Each span's products are the
same BLAS calls on the same operands as in the loop, so the result is identical, not merely close.

Checked by: tests/validation/test_span_covariances.py::test_equals_span_covariance_bit_for_bit,
    ::test_equals_span_covariance_bit_for_bit_across_restarts,
    tests/estimator/test_heading_reversion.py::test_span_covariances_equal_span_covariance_with_the_reversion
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.lie import se3
from rodo.estimator.heading_reversion import heading_reversion_matrix, state_size
from rodo.estimator.uncertainty import DriftCovariance, drift_rate_sigma_array, fresh_starts, restart_matrices

BLOCK = 2048  # spans advanced together (bounds the memory: 2 x BLOCK x 19 x 19 floats at most, ~12 MB)


def step_matrices(T: np.ndarray, t: np.ndarray, Sigma_rel: np.ndarray, P_varpi: np.ndarray, tau: float,
                  scans: np.ndarray, restarts=None, heading=None) -> tuple[np.ndarray, np.ndarray]:
    """A_j, Q_j (len(scans), 18, 18) of the recursion's step from scan j - 1 to scan j, for j in `scans` (>= 1):
    the matrices `uncertainty._step` builds, x <- A x + w, Cov(w) = Q (NaN rows of Sigma_rel count as 0), or
    `uncertainty.restart_matrices` at a scan flagged in `restarts` (a re-initialisation); (19, 19) with the
    heading's reversion on (`heading`, [T_r, T_a])."""
    n = state_size(heading)
    A = np.zeros((len(scans), n, n))
    Q = np.zeros((len(scans), n, n))
    eye = np.eye(6)
    for i, j in enumerate(scans):
        if restarts is not None and restarts[j]:
            S = Sigma_rel[j] if np.all(np.isfinite(Sigma_rel[j])) else np.zeros((6, 6))
            A[i], Q[i] = restart_matrices(T[j - 1], T[j], S, heading)
            continue
        dt = t[j] - t[j - 1]
        phi = np.exp(-dt / tau) if tau > 0 else 0.0
        R = T[j] @ se3.inverse(T[j - 1])
        A[i, :6, :6] = se3.adjoint(R)
        A[i, :6, 6:12] = dt * phi * eye
        A[i, 6:12, 6:12] = phi * eye
        A[i, :6, 12:18] = np.linalg.norm(R[:3, 3]) * eye
        A[i, 12:, 12:] = np.eye(n - 12)
        if n > 18:
            A[i] = A[i] @ heading_reversion_matrix(dt, heading)
        S = Sigma_rel[j] if np.all(np.isfinite(Sigma_rel[j])) else np.zeros((6, 6))
        W = (1.0 - phi**2) * P_varpi[j] if tau > 0 else np.zeros((6, 6))
        Q[i, :6, :6] = dt * dt * W + S
        Q[i, :6, 6:12] = Q[i, 6:12, :6] = dt * W
        Q[i, 6:12, 6:12] = W
    return A, Q


def span_covariances(T: np.ndarray, t: np.ndarray, Sigma_rel: np.ndarray, P_varpi: np.ndarray, n: int, tau: float,
                     drift_rate_sigma=None, restarts=None, heading=None, deviations=None, starts=None,
                     steps=None) -> np.ndarray:
    """Covariances (N - n, 6, 6) of T_k T_{k-n}^-1 for k = n .. N-1: row k - n equals
    `span_covariance(T, t, Sigma_rel, P_varpi, k - n, k, tau, drift_rate_sigma, restarts, heading,
    deviations[k - n])` bit for bit; with `starts`, the rows of those spans' first scans alone (len(starts), 6, 6).

    Args: as `uncertainty.span_covariance`; n >= 1 scans per span; deviations (N,) each scan's Var(yaw - anchor)
    (`heading_deviations`; None: zeros); starts: increasing first scans, each below N - n (None: all); steps:
    `step_matrices` of scans 1 .. N-1 (row j - 1: the step into scan j) at these arguments, for a caller that
    composes several span lengths (None: each block builds its own).
    """
    N = len(t)
    fresh = fresh_starts(restarts, N)
    first = np.arange(max(N - n, 0)) if starts is None else np.asarray(starts, dtype=int)
    out = np.zeros((len(first), 6, 6))
    prior = np.diag(np.square(drift_rate_sigma_array(drift_rate_sigma)))
    for b in range(0, len(first), BLOCK):  # spans starting at scans s = first[b:b + BLOCK]
        s = first[b:b + BLOCK]
        first_step = s[0] + 1 if steps is None else 1  # the scan A_all[0] steps into
        A_all, Q_all = steps if steps is not None else step_matrices(
            T, t, Sigma_rel, P_varpi, tau, np.arange(s[0] + 1, s[-1] + n + 1), restarts, heading)
        C = np.zeros((len(s),) + A_all.shape[1:])  # uncertainty._initial with a known start pose
        if tau > 0:
            C[:, 6:12, 6:12] = P_varpi[s]
            C[fresh[s], 6:12, 6:12] = 0.0  # from the run's first scan or a re-initialisation: at zero
        C[:, 12:18, 12:18] = prior
        if C.shape[-1] > 18 and deviations is not None:
            C[:, 18, 18] = deviations[s]  # the anchor at -(yaw - a) from each span's start pose
        rows = s + 1 - first_step
        for i in range(n):  # step into scan start + i + 1 of every span
            A, Q = A_all[rows + i], Q_all[rows + i]
            C = A @ C @ np.swapaxes(A, -1, -2) + Q
            C = 0.5 * (C + np.swapaxes(C, -1, -2))
        out[b:b + len(s)] = C[:, :6, :6]
    return out


def drift_replay(T: np.ndarray, t: np.ndarray, Sigma_rel: np.ndarray, P_varpi: np.ndarray, P_pose0: np.ndarray,
                 tau: float, drift_rate_sigma=None, restarts=None, heading=None):
    """The run's absolute recursion replayed from its stored covariances, as the odometry ran it (`DriftCovariance`
    from its first scan, the re-initialisations' step where `restarts` flags them; NaN rows of Sigma_rel count as
    0): yields the recursion after each scan k = 1 .. N-1."""
    drift = DriftCovariance.at_first_scan(P_pose0, tau, drift_rate_sigma, heading)
    for k in range(1, len(t)):
        S = Sigma_rel[k] if np.all(np.isfinite(Sigma_rel[k])) else np.zeros((6, 6))
        if restarts is not None and restarts[k]:
            drift.restart(T[k - 1], T[k], S)
        else:
            drift.update(T[k - 1], T[k], t[k] - t[k - 1], S, P_varpi[k])
        yield drift


def heading_deviations(T: np.ndarray, t: np.ndarray, Sigma_rel: np.ndarray, P_varpi: np.ndarray, tau: float,
                       drift_rate_sigma=None, restarts=None, heading=None) -> np.ndarray | None:
    """(N,) Var(yaw - anchor) of the run's absolute recursion at each scan (`DriftCovariance.deviation`: zero at
    its first scan and at each re-initialisation), the deviation a span starting there carries; None without the
    heading's reversion. The first pose is taken as known: the deviation starts at zero whatever its covariance."""
    if state_size(heading) == 18:
        return None
    steps = drift_replay(T, t, Sigma_rel, P_varpi, np.zeros((6, 6)), tau, drift_rate_sigma, restarts, heading)
    return np.r_[0.0, [drift.deviation for drift in steps]]
