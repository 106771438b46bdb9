"""The scan's pull on its solved pose: how far, in its own information, the scan's pairs would move the pose they
were solved at, as a rigid body.

At the solved pose each pair i has the point-to-point residual e_i = T_world_sensor p_i - m_i (the detection
placed in the world against its map point) with covariance C_i (the detection's and the map point's, as the
association counts them). A rigid perturbation of the scan (left, world frame, about the sensor's position c:
p -> p + rho + phi x (p - c)) moves it by J_i = [I, -[p_i - c]x]. The pairs' summed score g = sum J_i^T C_i^-1 e_i
and information H = sum J_i^T C_i^-1 J_i give

    pull = g^T H^-1 g / 6,

the Gauss-Newton step the pairs alone would take, measured in their own information, per degree of freedom. At
the true pose, with independent pair errors drawn from C_i, 6 pull is chi-square with 6 dof (mean 1 per dof). A
window solve stops where the scan's pull is balanced by the motion prior and the older scans; where the scan and
its map disagree as a rigid body (the map placed with a drifted pose, a surface resampled), the balance leaves a
large pull, and the solved relative pose's error is larger than its covariance says (docs/consistency.md, "The
scan's pull"). `[uncertainty] inflation_per_pull` turns it into the one-scan relative pose covariance's factor.

The model is point-to-point in Cartesian coordinates whatever the estimator's measurement model (the polar one's
Doppler rows do not constrain the pose): a statistic of the scan, its map and the estimate, not the solve's own
gradient.

Checked by: tests/estimator/test_pull.py
"""

from __future__ import annotations

import numpy as np

from .uncertainty_kernels import pull_quadratic
from .velocity_inflation import velocity_factor

MIN_PAIRS = 6  # fewer pairs cannot hold six degrees of freedom


def pose_pull(T_world_sensor: np.ndarray, points_sensor: np.ndarray, map_points: np.ndarray,
              covariances: np.ndarray, variance: float = 0.0) -> float:
    """g^T H^-1 g / 6 of the pairs (module docstring): T_world_sensor (4, 4) the solved pose of the sensor,
    points_sensor (n, 3) the detections in the sensor frame, map_points (n, 3) their map points, covariances
    (n, 3, 3) of the pairs' differences in the world frame, plus `variance` (m^2) on each diagonal (the map's
    own sigma squared). NaN with fewer than MIN_PAIRS pairs, a covariance or an information matrix that is not
    positive definite (the pairs in a line)."""
    if len(points_sensor) < MIN_PAIRS:
        return float("nan")
    arrays = [np.ascontiguousarray(a, dtype=float) for a in (T_world_sensor, points_sensor, map_points, covariances)]
    return pull_quadratic(*arrays, float(variance)) / 6.0


NEUTRAL_PULL = 1.0  # per dof: chi-square's mean, for a scan whose pull cannot be measured


def pull_term(pull):
    """The pull per dof (a float or an array) as a factor's regressor; NEUTRAL_PULL where it is NaN (too few
    pairs to measure it): such a scan counts as a consistent one, never as one the pairs hold exactly, which with
    f near 0 (docs/consistency.md, "The scan's pull") would leave its relative pose a vanishing covariance."""
    pull = np.asarray(pull, dtype=float)
    return np.where(np.isfinite(pull), np.maximum(pull, 0.0), NEUTRAL_PULL)


def relative_factor(varpi, inflation: float, per_rate=None, per_doppler: float = 0.0, doppler_nis=None,
                    per_pull: float = 0.0, pull=None):
    """The one-scan relative pose covariance's factor f + r . |omega| + d ln(1 + nis) + p pull of one scan (a
    float) or of a stack (N, 6) of varpi ((N,)): `[uncertainty] inflation`, `inflation_per_rate`,
    `inflation_per_doppler` and `inflation_per_pull` (pull None: no term; a NaN pull counts as NEUTRAL_PULL).
    Bit for bit the factor without the pull when per_pull is 0.

    Checked by: tests/estimator/test_pull.py::test_the_relative_factor_adds_the_pull
    """
    c = velocity_factor(varpi, inflation, 0.0, per_doppler, doppler_nis, per_rate)
    if per_pull == 0.0 or pull is None:
        return c
    return c + per_pull * pull_term(pull)
