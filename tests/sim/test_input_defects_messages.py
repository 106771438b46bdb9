"""Messages of `rodo export` and of commands that read one sequence: plain numbers (no numpy reprs) when a scan
has no pose, and a rig directory named as a rig with its radars (not "sensor.toml: file not found")."""

from __future__ import annotations

import numpy as np
import pytest

from rodo import scenarios
from rodo.estimator.errors import InputError
from rodo.sim.export import poses_at_scans
from rodo.sim.sequence import Trajectory, read_sequence, write_tum
from tests.cli.helpers import fails


@pytest.fixture(scope="module")
def city(tmp_path_factory):
    d = tmp_path_factory.mktemp("city")
    scenarios.simulate_to("city", 1, d, duration=1.2)  # scans at k / 13 s, k = 0..15
    return d


def test_no_pose_message_prints_plain_numbers(city, tmp_path, capsys):
    seq = read_sequence(city)
    short = Trajectory(np.array([0.0, 0.5, 1.0]), np.tile(np.eye(4), (3, 1, 1)))
    with pytest.raises(InputError) as err:
        poses_at_scans(seq, short, "estimate.txt")
    assert str(err.value) == ("estimate.txt: no pose at the time of scan 1 (t = 0.07692307692307693 s; poses cover "
                              "0.0 .. 1.0 s)")
    # through `rodo export ply --run` with an estimate that ends early
    run = tmp_path / "run"
    run.mkdir()
    gt = seq.groundtruth
    write_tum(run / "estimate.txt", Trajectory(gt.t[:14], gt.T_world_vehicle[:14]))
    message = fails(capsys, ["export", "ply", city, "--out", tmp_path / "x", "--run", run],
                    "no pose at the time of scan 14 (t = 1.0769230769230769 s; poses cover 0.0 .. 1.0 s)")
    assert "np." not in message


@pytest.mark.parametrize("argv", [["ego-velocity", "{rig}", "--out", "{tmp}/e.csv"],
                                  ["export", "ply", "{rig}", "--out", "{tmp}/x"],
                                  ["export", "kitti-bin", "{rig}", "--out", "{tmp}/k"]])
def test_a_rig_given_for_one_sequence_is_named_as_a_rig(tmp_path, capsys, argv):
    rig = tmp_path / "rig"
    scenarios.simulate_rig_to("city", 1, rig, "corners", 0.3)
    argv = [a.format(rig=rig, tmp=tmp_path) for a in argv]
    message = fails(capsys, argv, f"{rig}: holds a rig (rig.toml", f"e.g. {rig / 'front_left'}",
                    "radars: front_left, front_right")
    assert "file not found" not in message
    assert not (tmp_path / "e.csv").exists() and not (tmp_path / "x").exists()


def test_a_truth_file_that_is_not_an_archive_is_named_without_pickle_advice(tmp_path):
    """A text file in place of truth.npz: named as not an archive; numpy's own message took it for pickled data and
    suggested loading it unsafely."""
    from rodo.sim.simulate import load_truth

    (tmp_path / "truth.npz").write_text("0.0 1 2 3 0 0 0 1\n")
    with pytest.raises(InputError) as err:
        load_truth(tmp_path)
    assert str(err.value) == (f"{tmp_path / 'truth.npz'}: not a readable .npz archive "
                              "(expected the truth.npz `rodo simulate` writes)")
