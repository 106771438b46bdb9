"""Alignment by the first pose: a trajectory re-expressed in another world frame so that both start at the same
pose. (ATE's least-squares alignment, Umeyama, is `validation.metrics.umeyama_se3`.)

Frames (docs/conventions.md): the estimator's world frame `e` is its own first frame (T_vehicle_world = I at the
first scan); the ground truth lives in the simulator's world frame `g`. Poses in TUM files and in
`Trajectory.T_world_vehicle` are T_world_vehicle; the state pose is T_vehicle_world.

Checked by: tests/validation/test_alignment.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.errors import check_finite
from rodo.estimator.lie import se3


def align_to_first(T_a_vehicle, T_b_vehicle0) -> np.ndarray:
    """Poses T_a_vehicle (N, 4, 4) of a trajectory in world frame a, expressed in world frame b so that the
    first aligned pose equals T_b_vehicle0:

        T_b_vehicle,k = T_b_a T_a_vehicle,k,    T_b_a = T_b_vehicle0 T_a_vehicle,0^-1.

    Uses: the recording maps the truth into the estimator's frame (T_b_vehicle0 = the first estimate), Fig. 4
    maps the estimates into the truth's, `metrics.drift` expresses both relative to their first pose
    (T_b_vehicle0 = I).

    Args:
        T_a_vehicle: (N, 4, 4) T_world_vehicle poses, finite.
        T_b_vehicle0: (4, 4) the pose the first one is mapped to.

    Returns:
        (N, 4, 4) aligned poses.

    Checked by: tests/validation/test_alignment.py::test_align_to_first_starts_together_and_keeps_relative_poses
    """
    T_a = check_finite("T_a_vehicle", T_a_vehicle, (4, 4)).reshape(-1, 4, 4)
    T_b0 = check_finite("T_b_vehicle0", T_b_vehicle0, (4, 4))
    return (T_b0 @ se3.inverse(T_a[0])) @ T_a


def truth_in_estimator_frame(T_vehicle_world_true) -> np.ndarray:
    """The true state poses in the frame in which the estimator starts at the identity: T_true,k T_true,0^-1.

    This is `align_to_first` written for state poses T = T_vehicle_world, which carry the world frame on the
    right: T_v_e,k = T_v_g,k T_g_e with T_g_e = T_v_g,0^-1 (the estimator's first pose is I), i.e.
    inverse(align_to_first(T^-1, I)). It is kept in this form, without the two inversions, so the reported NEES
    is exactly what it was.

    Args:
        T_vehicle_world_true: (N, 4, 4) true state poses in the simulator's world frame.

    Returns:
        (N, 4, 4) true state poses in the estimator's world frame (the first one is I).

    Checked by: tests/validation/test_alignment.py::test_truth_in_estimator_frame_is_align_to_first_of_state_poses
    """
    T = np.asarray(T_vehicle_world_true, dtype=float)
    return T @ se3.inverse(T[0])
