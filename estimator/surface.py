"""Surface-shaped covariances of new map points (the map's optional surface model, `MapConfig.surface_*`).

A map point and the detection later associated with it are two different samples of the same surface: the
simulator (and a real radar) draws a new scatterer each scan. Their offset lies in the surface, so a point-to-point
residual carries no information along the surface, only across it. The paper's model adds an isotropic
`map_sigma` to every map point, which counts the along-surface offsets as information in every direction: on a
road between facades, the roll (and pitch) the ground and the facades cannot tell are then "known" to a fraction
of a milliradian while the estimate wanders by tens of milliradians (docs/consistency.md, "Roll and pitch on
resampled surfaces").

With the surface model, each new point's neighbourhood (the other new points and the map, within `radius`, at
most `neighbours` of them) is fitted with a plane (principal axes of the neighbours' scatter). Where it is a plane
(smallest eigenvalue below `planarity` times the middle one, the middle one at least `planarity` times the
largest, at least five neighbours) the point gets

    sigma_tangent^2 (I - n n^T) + sigma_normal^2 n n^T           (n: the plane's unit normal)

on top of its detection covariance: loose along the surface, tight across it, as point-to-plane registration
(generalised ICP) treats it. Elsewhere (edges, poles, sparse or isolated returns) it gets the isotropic
`sigma_iso^2 I`, the paper's term.

Checked by: tests/estimator/test_surface.py
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

MIN_NEIGHBOURS = 5  # a plane through fewer points is not a surface


def surface_covariances(p_new: np.ndarray, p_map: np.ndarray, sigma_normal: float, sigma_tangent: float,
                        sigma_iso: float, neighbours: int = 10, radius: float = 2.0,
                        planarity: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """The resampling covariance of each new point: (k, 3, 3) world-frame matrices and the (k,) planar mask.

    Args:
        p_new: (k, 3) the new points (world frame); each is one of its own neighbours.
        p_map: (m, 3) the map's points (world frame), neighbours too.
        sigma_normal, sigma_tangent: 1-sigma (m) across and along a planar neighbourhood's surface.
        sigma_iso: isotropic 1-sigma (m) where the neighbourhood is not a plane.
        neighbours: most neighbours per point (itself included); radius: farthest neighbour (m).
        planarity: largest ratio of the smallest to the middle eigenvalue of the neighbours' scatter.
    """
    p_new = np.asarray(p_new, dtype=float).reshape(-1, 3)
    k = len(p_new)
    iso = sigma_iso**2 * np.eye(3)
    if k == 0:
        return np.zeros((0, 3, 3)), np.zeros(0, bool)
    ref = np.concatenate([p_new, np.asarray(p_map, dtype=float).reshape(-1, 3)])
    n_query = min(int(neighbours), len(ref))
    dist, idx = cKDTree(ref).query(p_new, k=n_query, distance_upper_bound=radius)
    dist, idx = dist.reshape(k, n_query), idx.reshape(k, n_query)
    valid = np.isfinite(dist)
    count = valid.sum(axis=1)
    nb = ref[np.where(valid, idx, 0)]                       # (k, n, 3); invalid rows masked below
    mean = np.einsum("kn,kni->ki", valid, nb) / np.maximum(count, 1)[:, None]
    q = (nb - mean[:, None, :]) * valid[..., None]
    scatter = np.einsum("kni,knj->kij", q, q)
    w, V = np.linalg.eigh(scatter)                           # ascending eigenvalues
    # a plane: thin across (smallest << middle) but not a line (middle not << largest: a pole, an edge)
    planar = (count >= MIN_NEIGHBOURS) & (w[:, 0] < planarity * w[:, 1]) & (w[:, 1] >= planarity * w[:, 2])
    normal = V[:, :, 0]
    nn = normal[:, :, None] * normal[:, None, :]
    aniso = sigma_tangent**2 * (np.eye(3) - nn) + sigma_normal**2 * nn
    return np.where(planar[:, None, None], aniso, iso), planar
