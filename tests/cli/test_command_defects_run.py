"""`rodo run` with a groundtruth.txt too sparse for the accuracy (one pose, or poses off the scan times): the run
succeeds, writes its outputs and says on stderr, naming the file, that the accuracy was not computed; the same for a
rig. Sizing: a 1 s city sequence and a 1 s three-radar rig, a few runs of each; about 5 s."""

import shutil

import pytest

from rodo import scenarios
from rodo.cli import main
from rodo.commands import run as run_cmd
from rodo.commands import simulate as simulate_cmd
from rodo.commands.run import RUN_FILES


def _run(capsys, seq, out):
    capsys.readouterr()
    rc = main(["run", str(seq), "--out", str(out)], commands=[run_cmd])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


@pytest.fixture(scope="module")
def city(tmp_path_factory):
    d = tmp_path_factory.mktemp("city") / "seq"
    scenarios.simulate_to("city", 0, d, duration=1.0)
    return d


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    d = tmp_path_factory.mktemp("rig") / "rig"
    assert main(["simulate", "city", "--duration", "1", "--rig", "front-corners", "--out", str(d)],
                commands=[simulate_cmd]) == 0
    return d


def _with_groundtruth(src, dst, lines):
    shutil.copytree(src, dst)
    (dst / "groundtruth.txt").write_text("".join(lines))
    return dst


def test_one_ground_truth_pose_runs_and_says_the_accuracy_was_not_computed(city, tmp_path, capsys):
    lines = (city / "groundtruth.txt").read_text().splitlines(keepends=True)
    seq = _with_groundtruth(city, tmp_path / "one", lines[:1])
    rc, out, err = _run(capsys, seq, tmp_path / "out")
    assert rc == 0, err
    assert all((tmp_path / "out" / name).is_file() for name in RUN_FILES)
    assert err.startswith("rodo run: warning: ") and err.count("\n") == 1, err
    assert f"{seq / 'groundtruth.txt'}: accuracy not computed: 1 of its 1 poses" in err
    assert "t_a, t_b" not in err and "Traceback" not in err
    assert "KITTI" not in out and "ATE" not in out
    # the same sequence with two poses: the accuracy line (the control)
    seq2 = _with_groundtruth(city, tmp_path / "two", lines[:1] + lines[-1:])
    rc, out, err = _run(capsys, seq2, tmp_path / "out2")
    assert rc == 0 and err == "" and f"against {seq2 / 'groundtruth.txt'} (2 poses)" in out


def test_a_rig_ground_truth_of_one_pose_runs_and_says_so(rig, tmp_path, capsys):
    first = (rig / "front" / "groundtruth.txt").read_text().splitlines(keepends=True)[:1]
    seq = _with_groundtruth(rig, tmp_path / "rig1", first)
    rc, out, err = _run(capsys, seq, tmp_path / "out")
    assert rc == 0, err
    assert all((tmp_path / "out" / name).is_file() for name in RUN_FILES)
    assert err.startswith("rodo run: warning: ") and err.count("\n") == 1, err
    assert f"{seq / 'groundtruth.txt'}: accuracy not computed: 1 of its 1 poses" in err and "t_a, t_b" not in err
    assert "KITTI" not in out
    rc, out, err = _run(capsys, rig, tmp_path / "out_all")  # the radars' own ground truths, merged: the control
    assert rc == 0 and "against " in out and "KITTI" in out and "accuracy not computed" not in err
