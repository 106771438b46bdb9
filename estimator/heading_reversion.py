"""The heading's reversion in the drift recursion (`uncertainty`, part 4; off by default).

Odometry's yaw error does not random-walk as the composed per-scan errors say: over a second it is correlated,
over ten it comes back. The far scene, seen for tens of scans, holds the heading, and it was itself placed with
an earlier heading: so the yaw error reverts, with time constant T_r, to an anchor a, which follows the yaw with
a much longer time constant T_a. Between scans, exactly over dt,

    d yaw / dt = -(yaw - a) / T_r,    d a / dt = (yaw - a) / T_a:

the deviation yaw - a decays by e = exp(-dt (1 / T_r + 1 / T_a)), and the weighted mean
r yaw + (1 - r) a, r = T_r / (T_r + T_a), stays. The registration's errors still enter the yaw, and the mean
still random-walks, at (r)^2 the rate over spans much longer than T_r. On hills and highway (CA/P at learned
noise, held-out drives) the composed yaw variance was 12-16 times the yaw error's over 15-30 s and about 2 times
over 1 s; roll and pitch do not revert so (docs/consistency.md, "The heading reverts").

The recursion's state gains the anchor, [xi; b; beta; a] (19): `heading_reversion_matrix` is applied before each
step (x <- A M x + w), the anchor is carried unchanged by the step, and it starts at the yaw error (a run's
first scan, a re-initialisation: no deviation to revert, the map is new); a span starts with the anchor off its
start pose by the deviation the run's recursion has there (`DriftCovariance.deviation`).

Checked by: tests/estimator/test_heading_reversion.py
"""

from __future__ import annotations

import numpy as np

BASE = 18  # [xi; b; beta]
YAW, ANCHOR = 5, 18


def heading_reversion_array(heading) -> np.ndarray:
    """(2,) [T_r, T_a] (s), the reversion's and the anchor's time constants; None, or T_r = 0: [0, 0], off.
    ValueError unless both are finite, T_r >= 0 and, with T_r > 0, T_a > 0."""
    if heading is None:
        return np.zeros(2)
    h = np.asarray(heading, dtype=float).reshape(2)
    if not (np.all(np.isfinite(h)) and h[0] >= 0):
        raise ValueError(f"heading reversion [T_r, T_a]: finite, T_r >= 0 expected, got {h.tolist()}")
    if h[0] == 0:
        return np.zeros(2)
    if h[1] <= 0:
        raise ValueError(f"heading reversion [T_r, T_a]: T_a > 0 expected with T_r > 0, got {h.tolist()}")
    return h


def state_size(heading) -> int:
    """The recursion's state size: 18, or 19 with the heading's reversion on."""
    return BASE + 1 if heading_reversion_array(heading)[0] > 0 else BASE


def reversion_coefficients(dt: float, heading) -> np.ndarray:
    """(4,) the reversion over dt (module docstring) on (yaw, a): [m_yy, m_ya, m_ay, m_aa] with
    yaw <- (r + (1 - r) e) yaw + (1 - r)(1 - e) a, a <- r (1 - e) yaw + (1 - r + r e) a. ValueError when the
    reversion is off (there is no anchor)."""
    T_r, T_a = heading_reversion_array(heading)
    if T_r == 0:
        raise ValueError("heading reversion: it is off (T_r = 0): no anchor to revert to")
    r = T_r / (T_r + T_a)
    e = np.exp(-dt * (1.0 / T_r + 1.0 / T_a))
    return np.array([r + (1.0 - r) * e, (1.0 - r) * (1.0 - e), r * (1.0 - e), 1.0 - r + r * e])


def heading_reversion_matrix(dt: float, heading) -> np.ndarray:
    """M (19, 19), the reversion over dt: the identity but for the yaw (index 5) and its anchor (index 18), the
    2 x 2 block `reversion_coefficients`. ValueError when the reversion is off."""
    m = reversion_coefficients(dt, heading)
    M = np.eye(BASE + 1)
    M[YAW, YAW], M[YAW, ANCHOR], M[ANCHOR, YAW], M[ANCHOR, ANCHOR] = m
    return M


def anchored_at_yaw(C: np.ndarray) -> np.ndarray:
    """C (19, 19) with the anchor set to the yaw error (its row and column the yaw's; in place, returned): where
    the recursion starts or restarts, so there is no deviation to revert."""
    C[ANCHOR, :ANCHOR] = C[YAW, :ANCHOR]
    C[:ANCHOR, ANCHOR] = C[:ANCHOR, YAW]
    C[ANCHOR, ANCHOR] = C[YAW, YAW]
    return C


def heading_of(config) -> np.ndarray:
    """[T_r, T_a] (s) of an `UncertaintyConfig`'s heading reversion ([0, 0]: off)."""
    return heading_reversion_array((config.heading_reversion_time, config.heading_anchor_time))
