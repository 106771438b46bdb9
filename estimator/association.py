"""Maximum-likelihood data association of map points to radar detections (paper eq. 86-88).

For map point j and detection i, e_ij = residual(z_i, z_pred_j) and

    S_j = G_j P G_j^T + R + map_sigma^2 J_z_p,j J_z_p,j^T,   G_j = [J_z_xi, J_z_varpi]_j      (eq. 87)
    d2_ij = e_ij^T S_j^-1 e_ij                                                                  (eq. 88)

The map-point term models that a map built from detections does not hold the exact points the next scan
samples on extended surfaces (isotropic world-frame covariance map_sigma^2 I). R is per scan (4, 4) or per
map point (m, 4, 4); a per-pair R (depending on detection i) is NOT used: with the polar model R is the same
for every detection, and for the Cartesian baseline it is fixed by construction.

Pairs are gated at d2 <= gate (chi-square quantile, 4 dof, default 95 %). Candidates come from a cKDTree over
the detections' Cartesian sensor-frame positions, queried around each map point's predicted position with the
radius sqrt(gate * lambda_max(Sigma_pos,j)), capped at max_radius, where Sigma_pos,j is the position block of
S_j expressed in Cartesian coordinates (for the polar model A S_j[:3, :3] A^T, A = d(cartesian)/d(polar) at the
prediction, times a curvature factor k >= 1, see `MeasurementModel.search_radius`). Since the 3-D marginal Mahalanobis distance
never exceeds the 4-D one, this radius loses no gated pair unless the cap max_radius cuts it.

One-to-one by greedy smallest d2: equivalent to repeatedly accepting every pair that is the best remaining pair
of both its map point and its detection (locally dominant pairs), which vectorises into a few rounds.

Checked by: tests/estimator/test_association.py
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import chi2

from .errors import InputError, check_finite
from .measurement_models import MeasurementModel, measurement_model
from .measurements import Prediction

from . import association_kernels as _kernel


@dataclass
class Association:
    """Accepted one-to-one pairs, sorted by map index.

    Attributes:
        map_idx: (k,) int map-point indices.
        det_idx: (k,) int detection indices.
        d2: (k,) squared Mahalanobis distances (all <= gate).
        n_candidates: number of (map point, detection) pairs the KD-tree proposed before gating.
    """

    map_idx: np.ndarray
    det_idx: np.ndarray
    d2: np.ndarray
    n_candidates: int


def gate_threshold(prob: float = 0.95, dof: int = 4) -> float:
    """Chi-square quantile for gating d2 (paper sec. VII: 95 %, 4-D measurements -> 9.488).

    Checked by: tests/estimator/test_association.py::test_gate_probability_with_true_covariance
    """
    prob = float(check_finite("prob", prob))
    if not 0.0 < prob < 1.0:
        raise InputError(f"prob: must be in (0, 1), got {prob}")
    if int(dof) != dof or dof < 1:
        raise InputError(f"dof: must be a positive integer, got {dof}")
    return float(chi2.ppf(prob, int(dof)))


def innovation_covariance(pred: Prediction, P_pose_vel, R, map_sigma: float = 0.0) -> np.ndarray:
    """S = G P G^T + R + map_sigma^2 J_z_p J_z_p^T per map point (paper eq. 87), (m, 4, 4).

    Args:
        pred: Prediction of m map points.
        P_pose_vel: (12, 12) covariance of [xi; varpi] (left pose perturbation, then velocity).
        R: (4, 4) measurement noise for all, or (m, 4, 4) per map point.
        map_sigma: isotropic 1-sigma (m) of the map points' world positions.

    Checked by: tests/estimator/test_association.py::test_innovation_covariance_monte_carlo
    """
    P = check_finite("P_pose_vel", P_pose_vel, (12, 12))
    if P.shape != (12, 12):
        raise InputError(f"P_pose_vel: expected shape (12, 12), got {P.shape}")
    m = len(pred.z)
    R = check_finite("R", R, (4, 4))
    if R.shape not in ((4, 4), (m, 4, 4)):
        raise InputError(f"R: expected shape (4, 4) or ({m}, 4, 4), got {R.shape}")
    map_sigma = float(check_finite("map_sigma", map_sigma))
    if map_sigma < 0:
        raise InputError(f"map_sigma: must be >= 0, got {map_sigma}")
    G = np.concatenate([pred.J_z_xi, pred.J_z_varpi], axis=2)   # (m, 4, 12)
    S = (G @ P) @ np.swapaxes(G, 1, 2) + R
    if map_sigma > 0:
        S = S + map_sigma**2 * (pred.J_z_p @ np.swapaxes(pred.J_z_p, 1, 2))
    return 0.5 * (S + np.swapaxes(S, 1, 2))


def _greedy_one_to_one(j: np.ndarray, i: np.ndarray, d2: np.ndarray, m: int, n: int) -> np.ndarray:
    """Mask of pairs chosen greedily by smallest d2 (ties: smaller j, then i), each j and i used at most once."""
    return _kernel.greedy_one_to_one(_kernel.order_by_d2(j, i, d2, n), j, i, m, n)


def associate(model: str | MeasurementModel, z_meas, det_points_sensor, pred: Prediction, S, gate: float,
              max_radius: float = 5.0, max_candidates: int = 16) -> Association:
    """Gated, one-to-one nearest-neighbour association in the Mahalanobis metric (paper eq. 86-88).

    Args:
        model: "polar" or "cartesian" (the space of z_meas and pred.z).
        z_meas: (n, 4) detections in model space (`measurements.to_model_space`).
        det_points_sensor: (n, 3) the detections' Cartesian sensor-frame positions (KD-tree).
        pred: Prediction of the m map points.
        S: (m, 4, 4) innovation covariances (`innovation_covariance`).
        gate: d2 threshold (`gate_threshold`).
        max_radius: cap (m) of the KD-tree search radius.
        max_candidates: at most this many nearest detections (inside the radius) are scored per map point.

    Returns:
        Association (pairs sorted by map index).

    Checked by: tests/estimator/test_association.py
    """
    model = measurement_model(model)
    z_meas = check_finite("z_meas", z_meas, (4,))
    pts = check_finite("det_points_sensor", det_points_sensor, (3,))
    if z_meas.ndim != 2 or pts.ndim != 2 or len(pts) != len(z_meas):
        raise InputError(f"z_meas, det_points_sensor: expected (n, 4) and (n, 3) with the same n, "
                         f"got {z_meas.shape} and {pts.shape}")
    m, n = len(pred.z), len(z_meas)
    S = check_finite("S", S, (4, 4))
    if S.shape != (m, 4, 4):
        raise InputError(f"S: expected shape ({m}, 4, 4), got {S.shape}")
    gate = float(check_finite("gate", gate))
    max_radius = float(check_finite("max_radius", max_radius))
    if gate <= 0 or max_radius <= 0:
        raise InputError(f"gate, max_radius: must be > 0, got {gate}, {max_radius}")
    empty = Association(np.zeros(0, int), np.zeros(0, int), np.zeros(0), 0)
    if m == 0 or n == 0:
        return empty
    try:
        np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise InputError("S: not positive definite for every map point") from None
    S_inv = np.linalg.inv(S)

    radius = np.minimum(model.search_radius(pred.z, S, gate), max_radius)
    return match(model, z_meas, cKDTree(pts), pred.z, pred.p_sensor, S_inv, radius, gate, max_candidates)[0]


@dataclass
class Search:
    """The KD-tree's answer for m predicted positions, kept so a re-association at nearby positions can reuse it.

    Attributes:
        keys: (m,) sorted ids of the points (the caller's map indices).
        p: (m, 3) the positions the distances are measured from.
        bound: (m,) a row that is not full lists every detection within bound[j] of p[j].
        idx: (m, k) detection indices, tree.n in unused places (queried rows: nearest first).
        dist: (m, k) their distances from p (inf where idx is tree.n).
        full: (m,) the query found k detections (more may lie within bound).
    """

    keys: np.ndarray
    p: np.ndarray
    bound: np.ndarray
    idx: np.ndarray
    dist: np.ndarray
    full: np.ndarray


def search(tree: cKDTree, p_sensor: np.ndarray, radius: np.ndarray, k: int, keys: np.ndarray,
           previous: Search | None = None) -> Search:
    """The k nearest detections of each position inside its radius (the candidates of `match`).

    Without `previous`: KD-tree queries in four groups of similar radius (a tighter distance bound per group,
    fewer nodes visited). With `previous` (the same tree, positions moved by a solve): a point whose previous row
    was not full (so it lists every detection within the previous bound) and whose new radius plus the distance
    its position moved stays inside that bound takes that row, re-measured from the new position; it holds
    every detection within the new radius, fewer than k, which is what a new query would give. The other points
    are queried.

    Checked by: tests/estimator/test_association.py::test_reused_search_equals_a_new_query
    """
    m, n = len(p_sensor), tree.n
    idx, dist = np.full((m, k), n, np.int64), np.full((m, k), np.inf)
    bound, full = np.zeros(m), np.zeros(m, bool)
    todo = np.ones(m, bool)
    if previous is not None and m:
        todo = _kernel.reuse_search(keys, p_sensor, radius, previous.keys, previous.p, previous.bound,
                                    previous.idx, previous.full, tree.data, idx, dist, bound, full)
    rows = np.flatnonzero(todo)
    if len(rows):
        by_radius = rows[np.argsort(radius[rows], kind="stable")]
        for g in np.array_split(by_radius, min(4, len(rows))):
            bound[g] = float(radius[g].max())
            d_g, i_g = tree.query(p_sensor[g], k=k, distance_upper_bound=bound[g[0]])
            dist[g], idx[g] = d_g.reshape(len(g), k), i_g.reshape(len(g), k)
        full[rows] = idx[rows, -1] < n
    return Search(keys, p_sensor, bound, idx, dist, full)


def match(model: MeasurementModel, z_meas: np.ndarray, tree: cKDTree, z_pred: np.ndarray, p_sensor: np.ndarray,
          S_inv: np.ndarray, radius: np.ndarray, gate: float, max_candidates: int = 16,
          keys: np.ndarray | None = None, previous: Search | None = None) -> tuple[Association, Search]:
    """The candidate search, gating and one-to-one choice of `associate`, from prepared inputs (no checks):
    a KD-tree over the detections' sensor-frame positions (one per scan, reused when re-associating), the m
    map points' predictions z_pred (m, 4) and p_sensor (m, 3), S_inv (m, 4, 4) and search radii (m,) (capped).
    keys (m,) sorted ids of the map points (default 0..m-1) and `previous`, the Search of an earlier call with
    the same tree, let the search reuse that call's candidates (`search`). Returns the association and the
    Search to pass on.

    Checked by: tests/estimator/test_association.py (through `associate`),
        tests/estimator/test_odometry.py::test_prepared_association_equals_the_reference
    """
    m, n = len(z_pred), tree.n
    empty = Association(np.zeros(0, int), np.zeros(0, int), np.zeros(0), 0)
    keys = np.arange(m) if keys is None else keys
    if m == 0 or n == 0:
        # no rows to reuse: every point "full", so a later call queries it
        return empty, Search(keys, p_sensor, np.zeros(m), np.zeros((m, 0), np.int64), np.zeros((m, 0)),
                             np.ones(m, bool))
    # candidates: the k nearest detections inside each map point's own radius (bounded work per point)
    found = search(tree, p_sensor, radius, min(max_candidates, n), keys, previous)
    valid = (found.idx < n) & (found.dist <= radius[:, None])
    n_candidates = int(valid.sum())
    if n_candidates == 0:
        return empty, found
    j = np.nonzero(valid)[0].astype(np.int64)
    i = found.idx[valid].astype(np.int64)
    d2 = _kernel.pair_d2(model.is_polar, j, i, z_meas, z_pred, S_inv)  # e^T S^-1 e, azimuth wrapped
    keep = d2 <= gate
    j, i, d2 = j[keep], i[keep], d2[keep]
    chosen = _greedy_one_to_one(j, i, d2, m, n)
    j, i, d2 = j[chosen], i[chosen], d2[chosen]
    order = np.argsort(j, kind="stable")
    return Association(j[order], i[order], d2[order], n_candidates), found
