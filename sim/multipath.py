"""Multipath ghosts: the mirror image of a target across a large flat reflector (a facade, a parked car's side,
a guard rail), as a radar sees it after the path sensor -> reflector -> target -> reflector -> sensor (or the
two single-bounce paths, which have the same mean length). All in the sensor frame, sensor at the origin.

For a reflector plane through o with unit normal n (the sensor and the target on the same side):
    p' = p - 2 ((p - o) . n) n                      (the target's mirror image, M = I - 2 n n^T)
    the ghost is seen along u' = p' / |p'| at range |p'|, if the line of sight to p' crosses the plane inside the
    reflector's rectangle (at b = t p', t = s / (s + d), s = -o . n, d = (p - o) . n);
    v_r' = u' . (M v_target - v_sensor)             (d|p'|/dt of the mirrored geometry; static reflector).

Checked by: tests/sim/test_multipath.py
"""

from __future__ import annotations

import numpy as np

from .objects import Patches


def reflectors(patches: Patches, min_area: float) -> Patches:
    """The patches (sensor frame) large and reflective enough to mirror: area >= min_area and not ground
    (reflectivity >= 0.5)."""
    keep = (patches.area >= min_area) & (patches.reflectivity >= 0.5)
    return patches.subset(np.flatnonzero(keep))


def mirror(p: np.ndarray, v: np.ndarray, v_sensor: np.ndarray, refl: Patches, j: np.ndarray):
    """Mirror images of targets p (m, 3) with velocities v (m, 3) (sensor frame, relative to the world) across
    reflectors j (m,) of `refl` (sensor frame).

    Returns:
        (p_ghost (m, 3), v_r_ghost (m,), valid (m,) bool): valid when the sensor and the target are on the same
        side of the plane and the bounce point lies on the reflector rectangle.

    Checked by: tests/sim/test_multipath.py::test_ghost_is_the_mirror_image_with_the_mirrored_doppler
    """
    o, a, b = refl.origin[j], refl.u[j], refl.v[j]
    n = refl.normal[j]
    d = np.einsum("ij,ij->i", p - o, n)
    s = -np.einsum("ij,ij->i", o, n)
    p_ghost = p - 2.0 * d[:, None] * n
    v_ghost = v - 2.0 * np.einsum("ij,ij->i", v, n)[:, None] * n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = s / (s + d)
        bounce = t[:, None] * p_ghost - o
        alpha = np.einsum("ij,ij->i", bounce, a) / np.einsum("ij,ij->i", a, a)
        beta = np.einsum("ij,ij->i", bounce, b) / np.einsum("ij,ij->i", b, b)
    valid = (d * s > 0) & (alpha >= 0) & (alpha <= 1) & (beta >= 0) & (beta <= 1)
    r = np.linalg.norm(p_ghost, axis=1)
    u = p_ghost / np.maximum(r, 1e-12)[:, None]
    vr = np.einsum("ij,ij->i", u, v_ghost - v_sensor)
    return p_ghost, vr, valid


def valid_pairs(p: np.ndarray, refl: Patches) -> np.ndarray:
    """(m, k) bool: target i (sensor frame) has a mirror ghost via reflector j (`mirror`'s validity for every
    pair). With d = p . n + s and s = -o . n, and since n . u = n . v = 0, the bounce point's coordinates on the
    rectangle are alpha = (t p . u - o . u) / |u|^2 and beta likewise, t = s / (s + d): matrix products only.

    Checked by: tests/sim/test_multipath.py::test_valid_pairs_agree_with_mirror"""
    n = refl.normal
    s = -np.einsum("ij,ij->i", refl.origin, n)
    d = p @ n.T + s
    with np.errstate(divide="ignore", invalid="ignore"):
        t = s / (s + d)
        alpha = (t * (p @ refl.u.T) - np.einsum("ij,ij->i", refl.origin, refl.u)) / np.einsum("ij,ij->i", refl.u,
                                                                                             refl.u)
        beta = (t * (p @ refl.v.T) - np.einsum("ij,ij->i", refl.origin, refl.v)) / np.einsum("ij,ij->i", refl.v,
                                                                                            refl.v)
    return (d * s > 0) & (alpha >= 0) & (alpha <= 1) & (beta >= 0) & (beta <= 1)


def ghost_candidates(p: np.ndarray, v: np.ndarray, v_sensor: np.ndarray, refl: Patches, prob: float,
                     rng: np.random.Generator):
    """Each target tries one ghost with probability `prob`: via a reflector drawn uniformly from those whose
    rectangle the mirrored line of sight crosses (none: no ghost).

    Returns (source index (g,), p_ghost (g, 3), v_r_ghost (g,)) of the ghosts."""
    m, k = len(p), len(refl)
    if m == 0 or k == 0 or prob <= 0:
        return np.zeros(0, int), np.zeros((0, 3)), np.zeros(0)
    src = np.flatnonzero(rng.random(m) < prob)
    if len(src) == 0:
        return np.zeros(0, int), np.zeros((0, 3)), np.zeros(0)
    valid = valid_pairs(p[src], refl)
    # one valid reflector per source, uniformly: the valid one with the smallest random key
    key = np.where(valid, rng.random(valid.shape), np.inf)
    j = np.argmin(key, axis=1)
    has = np.isfinite(key[np.arange(len(src)), j])
    src, j = src[has], j[has]
    p_ghost, vr, _ = mirror(p[src], v[src], v_sensor, refl, j)
    return src, p_ghost, vr


__all__ = ["ghost_candidates", "mirror", "reflectors", "valid_pairs"]
