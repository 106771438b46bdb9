"""KITTI odometry pose files: one line per pose, the 12 numbers of the top 3x4 block of a 4x4 pose, row-major
(`r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz`), no time stamps (line i is frame i). kiss-icp, evo
(`evo_ape kitti`) and the KITTI devkit read them.

rodo writes T_world_vehicle, the poses of its TUM files in the same order (`rodo run` writes estimate.kitti.txt
beside estimate.txt; the estimator's world is its first vehicle frame, so the first pose is the identity, as
in KITTI). Values are written as the shortest text that reads back to the same float64, so a file round-trips
exactly.

Checked by: tests/sim/test_kitti_poses.py
"""

from __future__ import annotations

import numpy as np

from ._seqio import SequenceFormatError, atomic_write_bytes, float_text, read_text

ORTHONORMAL_TOL = 1e-6  # |R^T R - I| allowed when reading


def format_kitti_poses(T_world_vehicle) -> str:
    """Text of a KITTI pose file for (N, 4, 4) poses, N >= 1."""
    T = np.asarray(T_world_vehicle, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) == 0:
        raise SequenceFormatError("poses", f"expected (N, 4, 4) poses with N >= 1, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise SequenceFormatError("poses", "contains NaN or infinity")
    rows = T[:, :3, :].reshape(len(T), 12) + 0.0  # + 0.0: no negative zeros
    return "".join(" ".join(float_text(v) for v in row) + "\n" for row in rows.tolist())


def write_kitti_poses(path, T_world_vehicle) -> None:
    """Write a KITTI pose file atomically (see `format_kitti_poses`)."""
    atomic_write_bytes(path, format_kitti_poses(T_world_vehicle).encode("ascii"))


def read_kitti_poses(path) -> np.ndarray:
    """Read a KITTI pose file into (N, 4, 4) poses.

    Raises:
        SequenceFormatError (InputError) naming the file, the 1-based line and the problem: not 12 numbers,
        a non-finite value, a rotation block that is not orthonormal with determinant +1.
    """
    text = read_text(path)
    poses = []
    for number, line in enumerate(text.split("\n"), start=1):
        if not line.strip():
            continue
        fields = line.split()
        if len(fields) != 12:
            raise SequenceFormatError(path, f"expected 12 numbers (a 3x4 pose, row-major), got {len(fields)}",
                                      line=number)
        try:
            values = np.array([float(f) for f in fields])
        except ValueError:
            raise SequenceFormatError(path, "expected 12 numbers (a 3x4 pose, row-major)", line=number) from None
        if not np.all(np.isfinite(values)):
            raise SequenceFormatError(path, "value is not finite", line=number)
        T = np.eye(4)
        T[:3, :] = values.reshape(3, 4)
        R = T[:3, :3]
        if np.abs(R.T @ R - np.eye(3)).max() > ORTHONORMAL_TOL or np.linalg.det(R) < 0:
            raise SequenceFormatError(path, f"the rotation block is not a rotation (tolerance {ORTHONORMAL_TOL:g})",
                                      line=number)
        poses.append(T)
    return np.array(poses)
