"""TUM trajectory I/O: round trip, comments, malformed rows, unsorted/duplicate times, non-unit quaternions."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.sim.sequence import Trajectory, read_tum, write_tum
from tests.strategies import rotation_vectors, vectors

FIELDS = ("t", "tx", "ty", "tz", "qx", "qy", "qz", "qw")


@st.composite
def trajectories(draw, min_size=1, max_size=8):
    n = draw(st.integers(min_size, max_size))
    t = draw(st.floats(-1e4, 1e6)) + np.cumsum([draw(st.floats(1e-3, 5.0)) for _ in range(n)])
    xi = np.array([np.r_[draw(vectors(3, 1e3)), draw(rotation_vectors("any"))] for _ in range(n)])
    return Trajectory(t=t, T_world_vehicle=se3.exp(xi).reshape(n, 4, 4))


def write_read(traj):
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp, "gt.txt")
        write_tum(p, traj)
        return read_tum(p), p.read_bytes()


@given(trajectories())
def test_tum_round_trip(traj):
    back, data = write_read(traj)
    # %.9f: times and positions to 0.5 ns / 0.5 nm (plus the float64 spacing at 1e6), rotations to ~1e-9
    np.testing.assert_allclose(back.t, traj.t, rtol=0, atol=6e-10)
    np.testing.assert_allclose(back.T_world_vehicle[:, :3, 3], traj.T_world_vehicle[:, :3, 3], rtol=0, atol=6e-10)
    np.testing.assert_allclose(back.T_world_vehicle[:, :3, :3], traj.T_world_vehicle[:, :3, :3], rtol=0, atol=1e-8)
    assert write_read(traj)[1] == data  # deterministic bytes
    rows = np.array([ln.split() for ln in data.decode().splitlines()], dtype=float)
    assert rows.shape == (len(traj), 8) and np.all(rows[:, 7] >= 0)  # qw >= 0
    assert b"-0.000000000" not in data and b"\r" not in data


def test_tum_convention_is_T_world_vehicle_with_xyzw_quaternion(tmp_path):
    """A vehicle at (1, 2, 3) yawed +90 deg: its x axis points along world y; quaternion [0, 0, s, s]."""
    T = se3.exp(np.array([0, 0, 0, 0, 0, np.pi / 2]))
    T[:3, 3] = [1.0, 2.0, 3.0]
    write_tum(tmp_path / "gt.txt", Trajectory(np.array([5.0]), T[None]))
    s = f"{np.sqrt(0.5):.9f}"
    assert (tmp_path / "gt.txt").read_text() == f"5.000000000 1.000000000 2.000000000 3.000000000 " \
                                                f"0.000000000 0.000000000 {s} {s}\n"
    back = read_tum(tmp_path / "gt.txt").T_world_vehicle[0]
    np.testing.assert_allclose(back @ [1.0, 0, 0, 1.0], [1.0, 3.0, 3.0, 1.0], atol=1e-9)


def test_comments_blank_lines_whitespace_bom_crlf(tmp_path):
    p = tmp_path / "gt.txt"
    p.write_bytes(b"\xef\xbb\xbf# timestamp tx ty tz qx qy qz qw\r\n\r\n"
                  b"1.0 0 0 0 0 0 0 1\r\n  # a comment\r\n2.5\t1  2 3 0 0 0 -1\r\n\r\n")
    traj = read_tum(p)
    assert np.array_equal(traj.t, [1.0, 2.5])
    expected = [[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]]
    np.testing.assert_array_equal(traj.T_world_vehicle[1], expected)
    # the line numbers count comments and blank lines
    p.write_text("# c\n\n1.0 0 0 0 0 0 0 1\n# c\n2.0 0 0 0 0 0 0 nan\n")
    with pytest.raises(InputError, match=r"gt\.txt, line 5, field 'qw': value nan is not finite"):
        read_tum(p)


@given(trajectories(min_size=2), st.sampled_from(["drop", "add", "text", "nan", "inf"]), st.data())
def test_malformed_rows_name_line_and_field(traj, kind, data):
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp, "gt.txt")
        write_tum(p, traj)
        lines = ["# header comment"] + p.read_text().splitlines()
        k = data.draw(st.integers(1, len(lines) - 1))
        fields = lines[k].split()
        c = data.draw(st.integers(0, 7))
        if kind == "drop":
            del fields[c]
            field, words = "qw", "got 7"
        elif kind == "add":
            fields.insert(c, "0.5")
            field, words = None, "got 9"
        else:
            fields[c] = {"text": data.draw(st.sampled_from(["x", "1.0.0", "--2", "1e", "0x3"])),
                         "nan": "nan", "inf": "-inf"}[kind]
            field, words = FIELDS[c], ("expected a number" if kind == "text" else "not finite")
        lines[k] = " ".join(fields)
        p.write_text("\n".join(lines) + "\n")
        with pytest.raises(InputError) as info:
            read_tum(p)
        msg = str(info.value)
        assert str(p) in msg and f"line {k + 1}" in msg and words in msg, msg
        if field:
            assert f"field '{field}'" in msg, msg


@given(trajectories(min_size=3), st.data())
def test_unsorted_and_duplicate_times(traj, data):
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp, "gt.txt")
        write_tum(p, traj)
        lines = p.read_text().splitlines()
        i = data.draw(st.integers(1, len(lines) - 1))
        duplicate = data.draw(st.booleans())
        if duplicate:
            fields = lines[i].split()
            fields[0] = lines[i - 1].split()[0]
            lines[i] = " ".join(fields)
        else:
            lines[i - 1], lines[i] = lines[i], lines[i - 1]
        p.write_text("\n".join(lines) + "\n")
        with pytest.raises(InputError) as info:
            read_tum(p)
        msg = str(info.value)
        assert f"line {i + 1}" in msg and "field 't'" in msg, msg
        assert ("duplicate time" if duplicate else "not sorted") in msg, msg


@given(eps=st.floats(1e-5, 0.5), sign=st.sampled_from([1.0, -0.9]))
def test_non_unit_quaternion_is_an_error_not_normalised(eps, sign, tmp_path_factory):
    p = tmp_path_factory.mktemp("q") / "gt.txt"
    q = np.array([0.1, -0.2, 0.3, 0.9])
    q = q / np.linalg.norm(q)
    good = q * (1 + 5e-7)  # inside the 1e-6 tolerance: accepted, rotation normalised
    bad = q * (1 + sign * eps)
    good_text, bad_text = (" ".join(map(repr, q_.tolist())) for q_ in (good, bad))
    p.write_text(f"0.0 0 0 0 {good_text}\n1.0 0 0 0 {bad_text}\n")
    with pytest.raises(InputError, match=r"line 2, field 'qx qy qz qw': not a unit quaternion"):
        read_tum(p)
    p.write_text(f"0.0 0 0 0 {good_text}\n")
    C = read_tum(p).T_world_vehicle[0, :3, :3]
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-14)


def test_empty_and_comment_only_files(tmp_path):
    p = tmp_path / "gt.txt"
    for content, message in [(b"", "empty"), (b"\n \n", "empty"), (b"# only a comment\n", "no poses")]:
        p.write_bytes(content)
        with pytest.raises(InputError, match=message):
            read_tum(p)
    with pytest.raises(InputError, match="file not found"):
        read_tum(tmp_path / "missing.txt")


def test_trajectory_rejects_bad_input(tmp_path):
    I2 = np.stack([np.eye(4)] * 2)
    with pytest.raises(InputError, match="strictly increasing"):
        Trajectory(np.array([1.0, 1.0]), I2)
    with pytest.raises(InputError, match="shape"):
        Trajectory(np.array([1.0, 2.0, 3.0]), I2)
    bad = I2.copy()
    bad[1, 0, 1] = 0.5
    with pytest.raises(InputError, match="rotation"):
        Trajectory(np.array([1.0, 2.0]), bad)
    with pytest.raises(InputError, match="no poses"):
        write_tum(tmp_path / "x.txt", Trajectory(np.zeros(0), np.zeros((0, 4, 4))))
