"""`rodo run`'s accuracy line and KITTI poses: on a sequence with ground truth it prints the KITTI drift and ATE
that `rodo evaluate` reports for the same files, and estimate.kitti.txt holds the poses of estimate.txt.

Sizing: one 8 s highway sequence (105 scans, 249 m: every KITTI length up to 200 m has segments), one CV/C
run (about 10 s).
"""

import json
import re

import numpy as np
import pytest

from rodo import scenarios
from rodo.cli import main
from rodo.commands import evaluate as evaluate_cmd
from rodo.commands import run as run_cmd
from rodo.sim.kitti_poses import read_kitti_poses
from rodo.sim.sequence import read_tum


@pytest.fixture(scope="module")
def highway_run(tmp_path_factory):
    """(seq_dir, out_dir, what `rodo run` printed) for CV/C on 8 s of highway, seed 1."""
    seq = tmp_path_factory.mktemp("highway8")
    scenarios.simulate_to("highway", 1, seq, duration=8.0)
    out = tmp_path_factory.mktemp("run")
    capture = pytest.MonkeyPatch()
    import io
    import sys

    buf = io.StringIO()
    capture.setattr(sys, "stdout", buf)
    try:
        assert main(["run", str(seq), "--model", "cv-cartesian", "--out", str(out)], commands=[run_cmd]) == 0
    finally:
        capture.undo()
    return seq, out, buf.getvalue()


def _number(pattern: str, text: str) -> str:
    m = re.search(pattern, text)
    assert m, f"{pattern!r} not in\n{text}"
    return m.group(1)


def test_run_prints_the_numbers_of_rodo_evaluate(highway_run, capsys):
    seq, out, printed = highway_run
    assert main(["evaluate", "--gt", str(seq / "groundtruth.txt"), "--est", str(out / "estimate.txt")],
                commands=[evaluate_cmd]) == 0
    table = capsys.readouterr().out
    line = next(x for x in printed.splitlines() if x.startswith("against "))
    t_run = _number(r"KITTI t_err (\S+) %", line)
    r_run = _number(r"r_err (\S+) deg/m", line)
    ate_run = _number(r"ATE rmse (\S+) m", line)
    assert t_run == _number(r"KITTI t_err\s+(\S+) %", table)
    assert r_run == _number(r"KITTI r_err\s+(\S+) deg/m", table)
    assert ate_run == _number(r"ATE rmse / max\s+(\S+) /", table)
    assert _number(r"\((\d+) segments\)", line) == _number(r"\((\d+) segments\)", table)
    # and they are real numbers for this 249 m drive: below 2 % / 0.02 deg/m, ATE under a metre
    assert 0 < float(t_run) < 2 and 0 < float(r_run) < 0.02 and 0 < float(ate_run) < 1


def test_evaluate_prints_the_runs_error_growth_per_axis(highway_run, capsys):
    """With the run's states and the truth, `rodo evaluate` tables E[e^2 / sigma^2] per axis over each span that
    fits the 8 s drive, over the drive and of the velocity: the report's rows (`error_growth.growth_table`), rounded,
    printed."""
    seq, out, _ = highway_run
    report = out.parent / f"{out.name}_growth.json"
    assert main(["evaluate", "--gt", str(seq / "groundtruth.txt"), "--est", str(out / "estimate.txt"), "--states",
                 str(out / "states.npz"), "--truth", str(seq / "truth.npz"), "--json", str(report)],
                commands=[evaluate_cmd]) == 0
    text = capsys.readouterr().out
    rows = json.loads(report.read_text())["error_growth"]
    assert [r["label"] for r in rows] == ["1 scan", "0.5 s", "1 s", "2 s", "5 s", "10 s", "20 s", "drive", "velocity",
                                          "acceleration"]
    counted = [r for r in rows if r["count"]]
    assert [r["label"] for r in counted] == ["1 scan", "0.5 s", "1 s", "2 s", "5 s", "drive",  # 8 s: no 10 s span
                                             "velocity"]  # a CV run: no acceleration
    assert "error growth E[e^2/sigma^2]" in text
    for r in counted:
        assert all(x > 0 for x in r["ratio"])
        line = next(x for x in text.split("error growth E[e^2/sigma^2]")[1].splitlines()
                    if x.split()[:len(r["label"].split())] == r["label"].split())
        assert line.split()[len(r["label"].split()):-1] == [f"{x:.2f}" for x in r["ratio"]], line


def test_kitti_poses_round_trip_to_the_tum_poses(highway_run):
    _, out, printed = highway_run
    assert "estimate.kitti.txt" in printed
    lines = (out / "estimate.kitti.txt").read_text().splitlines()
    tum = read_tum(out / "estimate.txt")
    assert len(lines) == len(tum.t) and all(len(x.split()) == 12 for x in lines)
    T = read_kitti_poses(out / "estimate.kitti.txt")
    np.testing.assert_allclose(T, tum.T_world_vehicle, atol=2e-9)  # TUM's 9 decimals
    np.testing.assert_array_equal(T[0], np.eye(4))  # the estimator's world is its first vehicle frame
    row = np.array(lines[-1].split(), dtype=float).reshape(3, 4)  # 3x4, row-major: rotation | translation
    np.testing.assert_allclose(row[:, 3], tum.T_world_vehicle[-1][:3, 3], atol=2e-9)


def test_run_without_ground_truth_prints_no_accuracy(tmp_path, capsys):
    seq = tmp_path / "seq"
    scenarios.simulate_to("city", 0, seq, duration=0.5)
    (seq / "groundtruth.txt").unlink()
    assert main(["run", str(seq), "--out", str(tmp_path / "out")], commands=[run_cmd]) == 0
    printed = capsys.readouterr().out
    assert "KITTI" not in printed and (tmp_path / "out" / "estimate.kitti.txt").is_file()


def test_short_path_says_why_there_is_no_kitti_number(tmp_path, capsys):
    seq = tmp_path / "seq"
    scenarios.simulate_to("city", 0, seq, duration=1.0)
    assert main(["run", str(seq), "--out", str(tmp_path / "out")], commands=[run_cmd]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("against "))
    assert "is shorter than 100 m" in line and float(_number(r"ATE rmse (\S+) m", line)) >= 0
