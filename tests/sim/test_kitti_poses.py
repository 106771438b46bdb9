"""KITTI pose files: 12 numbers per line (3x4, row-major), exact round trip, errors naming file and line."""

import numpy as np
import pytest

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.sim.kitti_poses import format_kitti_poses, read_kitti_poses, write_kitti_poses


def _poses(n=20, seed=0):
    rng = np.random.default_rng(seed)
    return se3.exp(rng.normal(scale=[5, 5, 1, 0.3, 0.3, 2], size=(n, 6)))


def test_round_trip(tmp_path):
    T = _poses()
    write_kitti_poses(tmp_path / "p.txt", T)
    back = read_kitti_poses(tmp_path / "p.txt")
    np.testing.assert_array_equal(back, T)  # shortest round-trip text: exact
    first = np.array((tmp_path / "p.txt").read_text().splitlines()[0].split(), dtype=float)
    np.testing.assert_array_equal(first, T[0][:3, :].ravel())  # row-major 3x4 as written


def test_same_poses_same_bytes_and_no_negative_zero():
    T = np.repeat(np.eye(4)[None], 2, axis=0)
    T[1, 0, 3] = -0.0
    text = format_kitti_poses(T)
    assert text == format_kitti_poses(T.copy()) and "-0.0" not in text and text.endswith("\n")
    assert text.splitlines()[1].split()[3] == "0.0"


@pytest.mark.parametrize("content, line, what", [
    ("1 0 0 0 0 1 0 0 0 0 1\n", 1, "expected 12 numbers"),
    ("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 x 0 1 0 0 0 0 1 0\n", 2, "expected 12 numbers"),
    ("1 0 0 0 0 1 0 0 0 0 1 nan\n", 1, "not finite"),
    ("2 0 0 0 0 1 0 0 0 0 1 0\n", 1, "not a rotation"),
    ("-1 0 0 0 0 1 0 0 0 0 1 0\n", 1, "not a rotation"),
])
def test_bad_files_name_file_and_line(tmp_path, content, line, what):
    path = tmp_path / "bad.txt"
    path.write_text(content)
    with pytest.raises(InputError, match=f"bad.txt, line {line}.*{what}"):
        read_kitti_poses(path)


def test_bad_poses_are_refused():
    with pytest.raises(InputError, match="expected \\(N, 4, 4\\)"):
        format_kitti_poses(np.eye(4))
    with pytest.raises(InputError, match="NaN"):
        format_kitti_poses(np.full((1, 4, 4), np.nan))
