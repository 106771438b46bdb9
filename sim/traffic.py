"""Traffic that never passes through traffic: ground footprints of boxes and a collision filter for movers.

The scenarios place their moving vehicles by rule (oncoming cars drive the ego's path backwards in the lane to
the left, overtaking cars drive it faster, a lead vehicle ahead), and rules that do not see each other can put
two vehicles in the same place: on `city` an overtaking car and an oncoming car shared the lane 3.5 m to the
left and met head on, or stood in each other at a stop (version 2; docs/simulator.md, "Traffic"). Two boxes
in one place with opposite velocities are not a scene a radar meets: their returns, mixed in space, average to
the world's Doppler and so hid both from the estimator's moving-group test. `collision_free` keeps the movers
in order and leaves out each one whose footprint would overlap one already kept, or a parked car, at any time
both are present.

Footprints are the boxes' ground rectangles in the world's x-y plane; the overlap test is the separating-axis
test of two convex quadrilaterals. Tests: tests/sim/test_traffic.py.
"""

from __future__ import annotations

import numpy as np

from .objects import MovingBox

STEP = 0.02  # s between the instants tested: well under a car length at any closing speed the scenes reach


def footprints(T_world_box: np.ndarray, size) -> np.ndarray:
    """(M, 4, 2) ground rectangles (x-y corners, counter-clockwise) of a box of `size` (length, width, height;
    origin at the centre of its bottom face, as `objects.box`) at the poses T_world_box (M, 4, 4)."""
    T = np.asarray(T_world_box, dtype=float).reshape(-1, 4, 4)
    half_l, half_w = 0.5 * float(size[0]), 0.5 * float(size[1])
    corners = np.array([[-half_l, -half_w], [half_l, -half_w], [half_l, half_w], [-half_l, half_w]])
    return np.einsum("mij,kj->mki", T[:, :2, :2], corners) + T[:, None, :2, 3]


def overlap(a: np.ndarray, b: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """(M,) whether the convex quadrilaterals a[m] and b[m] ((M, 4, 2) each, or broadcastable) come closer than
    `margin` along every axis normal to one of their edges (the separating-axis test; margin 0: they
    intersect, touching counts as apart)."""
    a, b = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    a, b = a.reshape(-1, 4, 2), b.reshape(-1, 4, 2)
    hit = np.ones(len(a), bool)
    for quad in (a, b):
        edges = np.roll(quad, -1, axis=1) - quad
        normals = np.stack([-edges[..., 1], edges[..., 0]], axis=-1)
        normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
        pa, pb = np.einsum("mki,mji->mkj", normals, a), np.einsum("mki,mji->mkj", normals, b)
        gap = np.maximum(pb.min(-1) - pa.max(-1), pa.min(-1) - pb.max(-1))  # (M, 4): > 0 where apart
        hit &= np.all(gap < margin, axis=-1)
    return hit


def _track(mover: MovingBox, step: float) -> tuple[np.ndarray, np.ndarray]:
    """The instants of a grid `step` apart at which `mover` is present, and its footprints there."""
    k0, k1 = int(np.ceil(mover.t_on / step - 1e-9)), int(np.floor(mover.t_off / step + 1e-9))
    ticks = np.arange(k0, k1 + 1)
    if ticks.size == 0:
        return ticks, np.zeros((0, 4, 2))
    states = mover.states(ticks * step)
    return ticks, footprints(states.T_world_object, mover.size)


def collision_free(movers, solids: np.ndarray | None = None, step: float = STEP,
                   margin: float = 0.0) -> tuple[list, list]:
    """(kept, left out): the movers in order, each left out when its footprint overlaps (closer than `margin`)
    a kept mover's at an instant of a common grid `step` seconds apart where both are present, or one of the
    static footprints `solids` (K, 4, 2) (parked cars) at any instant. No random draws: the scene's other
    contents, and so its random stream, do not change."""
    solids = np.zeros((0, 4, 2)) if solids is None else np.asarray(solids, dtype=float).reshape(-1, 4, 2)
    kept, left_out, tracks = [], [], []
    for mover in movers:
        ticks, quads = _track(mover, step)
        if _hits(ticks, quads, tracks, solids, margin):
            left_out.append(mover)
            continue
        kept.append(mover)
        tracks.append((ticks, quads))
    return kept, left_out


def _hits(ticks, quads, tracks, solids, margin: float) -> bool:
    for other_ticks, other_quads in tracks:
        common, i, j = np.intersect1d(ticks, other_ticks, assume_unique=True, return_indices=True)
        if common.size and overlap(quads[i], other_quads[j], margin).any():
            return True
    if len(solids) == 0 or len(quads) == 0:
        return False
    m, k = _near(quads, solids, margin)
    return bool(m.size) and bool(overlap(quads[m], solids[k], margin).any())


def _near(quads: np.ndarray, solids: np.ndarray, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """The (instant, solid) index pairs whose centres are within the sum of their half diagonals plus
    `margin`: the only ones that can overlap."""
    c_q, c_s = quads.mean(1), solids.mean(1)
    r_q = np.linalg.norm(quads - c_q[:, None], axis=-1).max(1)
    r_s = np.linalg.norm(solids - c_s[:, None], axis=-1).max(1)
    d = np.linalg.norm(c_q[:, None] - c_s[None], axis=-1)
    return np.nonzero(d <= r_q[:, None] + r_s[None] + max(margin, 0.0))
