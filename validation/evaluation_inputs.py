"""Checks that a run's states and a simulator's truth belong to the trajectories being evaluated, made once by
`validation.metrics.evaluate` (naming its arguments, or `rodo evaluate`'s files through its labels): the
states.npz of another run, or the truth.npz of another drive, would otherwise give a wrong NEES, NIS and timing
without a word.

Checked by: tests/cli/test_command_defects_demo_evaluate.py, tests/validation/test_review3_python_api.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.errors import InputError
from rodo.validation.association import associate
from rodo.validation.metrics import rotation_angle

TUM_ROUNDING = 1e-9  # s: a TUM file keeps 9 decimals, states.npz and truth.npz the exact times
POSE_TOLERANCE = (1e-3, 1e-4)  # m, rad: the truth's pose against groundtruth.txt's at the same time (beyond the
# motion over their time difference): the same poses written to 9 decimals differ by 1e-9


def check_states_times(states: dict, est, tolerance: float, where: str) -> None:
    """InputError naming `where` (both files) unless the states' times are the estimate's, one per pose within
    `tolerance` (plus TUM's rounding): the states.npz of another run would report that run's NIS, timing, NEES.

    Checked by: tests/cli/test_command_defects_demo_evaluate.py::test_states_off_by_more_than_the_tolerance_are_refused
    """
    ts, te = np.asarray(states["t"], dtype=float), np.asarray(est.t, dtype=float)
    off = np.abs(ts - te) > tolerance + TUM_ROUNDING if ts.shape == te.shape else None
    if off is None or off.any():
        first = "" if off is None else (f"; first at pose {int(np.argmax(off))}: {ts[np.argmax(off)]:.6f} s "
                                        f"against {te[np.argmax(off)]:.6f} s")
        raise InputError(f"{where}: the states' times are not the estimate's within {tolerance:g} s "
                         f"({len(ts)} states over {_span(ts)}, {len(te)} poses over {_span(te)}{first}): give the "
                         "states.npz that `rodo run` wrote with this estimate")


STATES_POSE_TOLERANCE = 1e-6  # m and rad: the run's states and its estimate.txt are one pose each, 9 decimals apart


def check_states_poses(states: dict, est, where: str) -> None:
    """InputError naming `where` unless every state's pose is the estimate's at that scan (within
    STATES_POSE_TOLERANCE): the states of another run on the same scan times (the other model, another scenario
    of the same duration) would otherwise give that run's NEES, NIS and timing as this estimate's.

    Checked by: tests/cli/test_command_defects_demo_evaluate.py::test_states_of_another_run_on_the_same_times_are_refused
    """
    dp, angle = _pose_gaps(est.T_world_vehicle, states["T_vehicle_world"])
    bad = (dp > STATES_POSE_TOLERANCE) | (angle > STATES_POSE_TOLERANCE)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"{where}: the states' poses are not the estimate's ({int(bad.sum())} of {len(bad)} differ; "
                         f"first at t = {est.t[k]:.6f} s by {dp[k]:.3g} m): give the states.npz that `rodo run` "
                         "wrote with this estimate")


def _pose_gaps(T_world_vehicle, T_vehicle_world) -> tuple[np.ndarray, np.ndarray]:
    """(position distance (m), rotation angle (rad)) between two stacks of one pose each, given as a TUM file's
    T_world_vehicle and an npz's T_vehicle_world."""
    from rodo.estimator.lie import se3

    A, B = np.asarray(T_world_vehicle, dtype=float), se3.inverse(np.asarray(T_vehicle_world, dtype=float))
    return (np.linalg.norm(A[:, :3, 3] - B[:, :3, 3], axis=1),
            rotation_angle(np.swapaxes(A[:, :3, :3], 1, 2) @ B[:, :3, :3]))


def _span(t: np.ndarray) -> str:
    return f"[{t[0]:.6f}, {t[-1]:.6f}] s" if len(t) else "no times"


def check_truth_poses(truth: dict, gt, tolerance: float, where: str) -> None:
    """InputError naming `where` (both files) unless truth.npz's poses are groundtruth.txt's: the times associate
    and, at every matched time, position and attitude agree within POSE_TOLERANCE plus the truth's motion over
    the two times' difference (a truth.npz of another sequence on the same clock would give a wrong NEES).

    Checked by: tests/cli/test_command_defects_demo_evaluate.py::test_the_truth_pose_tolerance_is_a_millimetre
    """
    try:
        ig, it = associate(gt.t, truth["t"], tolerance)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    dt = np.abs(gt.t[ig] - np.asarray(truth["t"], dtype=float)[it])
    varpi = np.asarray(truth["varpi"], dtype=float)[it]
    dp, angle = _pose_gaps(gt.T_world_vehicle[ig], np.asarray(truth["T_vehicle_world"], dtype=float)[it])
    bad = ((dp > POSE_TOLERANCE[0] + np.linalg.norm(varpi[:, :3], axis=1) * dt)
           | (angle > POSE_TOLERANCE[1] + np.linalg.norm(varpi[:, 3:], axis=1) * dt))
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"{where}: the truth's poses are not the ground truth's ({int(bad.sum())} of {len(bad)} "
                         f"matched poses differ by more than {POSE_TOLERANCE[0]:g} m or {POSE_TOLERANCE[1]:g} rad; "
                         f"first at t = {gt.t[ig[k]]:.6f} s: {dp[k]:.4g} m, {np.rad2deg(angle[k]):.4g} deg): give "
                         "the truth.npz of the sequence whose groundtruth.txt this is")
