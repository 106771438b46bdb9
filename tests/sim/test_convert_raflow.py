"""`rodo convert raflow`: frame pairs chained into scans, repeated raw scans dropped, bad files refused.

Synthetic sample files check the chaining exactly; the real demo data (skipped when absent, docs/realdata.md) checks the
chains its README describes and that the ground truth reproduces every pair's `trans`.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.sim.convert import raflow, write_conversion
from rodo.sim.sequence import read_sequence

RAFLOW = "raflow_lrr30_demo"


def _pose(x: float) -> list:
    T = np.eye(4)
    T[0, 3] = x
    return T.tolist()


def _pc(seed: int, x: float, n: int = 12) -> dict:
    """A frame: n points ahead of the sensor, Doppler and RCS lists that identify the raw scan (seed)."""
    rng = np.random.default_rng(seed)
    p = rng.uniform([5, -5, -1], [30, 5, 1], (n, 3))
    return {"car_loc_x": p[:, 0].tolist(), "car_loc_y": p[:, 1].tolist(), "car_loc_z": p[:, 2].tolist(),
            "car_vel_r": rng.normal(-5, 1, n).tolist(), "rcs": rng.normal(0, 5, n).tolist(),
            "power": rng.normal(60, 5, n).tolist(), "pose": _pose(x)}


def _write(root, split, seq, k, pc1, pc2, interval=0.1):
    (root / split).mkdir(parents=True, exist_ok=True)
    path = root / split / f"radar_seqs-{seq}_samples-{k}.json"
    path.write_text(json.dumps({"pc1": pc1, "pc2": pc2, "interval": interval, "trans": _pose(0)}))
    return path


def _synthetic(root):
    """Sequence 0: samples 1-4 chained (frames 1..5), sample 3's pc2 repeats its pc1's raw scan (moved points),
    then sample 7 (frames 7, 8: not chained, sample numbers skip). Frame f has raw scan seed f, pose x = f."""
    frame = {f: _pc(f, float(f)) for f in range(1, 9)}
    repeat = dict(frame[3], car_loc_x=[v + 0.5 for v in frame[3]["car_loc_x"]], pose=_pose(4.0))
    for k, (a, b) in {1: (frame[1], frame[2]), 2: (frame[2], frame[3]), 3: (frame[3], repeat),
                      4: (repeat, frame[5])}.items():
        _write(root, "train", 0, k, a, b)
    _write(root, "train", 0, 7, frame[7], frame[8], interval=0.099)
    return frame


def test_chains_drop_repeats_and_keep_times(tmp_path):
    frame = _synthetic(tmp_path)
    convs = raflow.convert(tmp_path, min_scans=2)
    assert [c.name for c in convs] == ["train_seq0_1", "train_seq0_7"]
    first, second = (c.sequence for c in convs)
    # frames 1, 2, 3, (repeat of 3 dropped), 5: times add the pairs' intervals, a 0.2 s step at the repeat
    np.testing.assert_allclose([s.t for s in first.scans], [0.0, 0.1, 0.2, 0.4])
    np.testing.assert_allclose([s.t for s in second.scans], [0.0, 0.099])
    for scan, f in zip(first.scans, (1, 2, 3, 5)):
        np.testing.assert_array_equal(scan.radial_velocity, frame[f]["car_vel_r"])
        np.testing.assert_array_equal(scan.extra["rcs"], frame[f]["rcs"])
        p = np.c_[frame[f]["car_loc_x"], frame[f]["car_loc_y"], frame[f]["car_loc_z"]]
        q = np.c_[scan.range * np.cos(scan.elevation) * np.cos(scan.azimuth),
                  scan.range * np.cos(scan.elevation) * np.sin(scan.azimuth), scan.range * np.sin(scan.elevation)]
        np.testing.assert_allclose(q, p, atol=1e-12)
    # ground truth relative to the chain's first pose: x = frame - 1
    np.testing.assert_allclose(first.groundtruth.T_world_vehicle[:, 0, 3], [0, 1, 2, 4])
    assert convs[0].report.dropped == {raflow.REPEATED: 1}
    assert [c.name for c in raflow.convert(tmp_path, min_scans=3)] == ["train_seq0_1"]


def test_cli_writes_one_sequence_per_chain(tmp_path):
    from rodo.cli import main

    _synthetic(tmp_path / "src")
    assert main(["convert", "raflow", str(tmp_path / "src"), "--out", str(tmp_path / "out"), "--min-scans", "2"]) == 0
    seq = read_sequence(tmp_path / "out" / "train_seq0_1")
    assert len(seq.scans) == 4 and seq.groundtruth is not None
    assert main(["convert", "vod", str(tmp_path / "src"), "--out", str(tmp_path / "o2"), "--min-scans", "2"]) == 2


@pytest.mark.parametrize("edit, message", [
    (lambda d: "{not json", "not valid JSON"),
    (lambda d: json.dumps({k: v for k, v in d.items() if k != "pc2"}), "pc1, pc2 and interval"),
    (lambda d: json.dumps(dict(d, interval=-1)), "field 'interval'"),
    (lambda d: json.dumps(dict(d, pc1={k: v for k, v in d["pc1"].items() if k != "rcs"})), "'pc1' lacks rcs"),
    (lambda d: json.dumps(dict(d, pc1=dict(d["pc1"], car_vel_r=[1.0]))), "'pc1.car_vel_r': expected 12"),
    (lambda d: json.dumps(dict(d, pc2=dict(d["pc2"], car_loc_x=["a"] * 12))), "every entry must be a number"),
    (lambda d: json.dumps(dict(d, pc2=dict(d["pc2"], pose=(2 * np.eye(4)).tolist()))), "rigid transform"),
])
def test_bad_sample_files_name_file_and_field(tmp_path, edit, message):
    path = _write(tmp_path, "test", 0, 1, _pc(1, 0.0), _pc(2, 1.0))
    path.write_text(edit(json.loads(path.read_text())))
    with pytest.raises(InputError, match=message) as err:
        raflow.convert(tmp_path, min_scans=2)
    assert str(path) in str(err.value)


def test_empty_source_and_bad_options(tmp_path):
    with pytest.raises(InputError, match="no radar_seqs"):
        raflow.convert(tmp_path)
    with pytest.raises(InputError, match="not a directory"):
        raflow.convert(tmp_path / "missing")
    _synthetic(tmp_path)
    with pytest.raises(InputError, match="--min-scans"):
        raflow.convert(tmp_path, min_scans=1)
    with pytest.raises(InputError, match="no chain of at least 9"):
        raflow.convert(tmp_path, min_scans=9)


def test_demo_data_chains_as_its_readme_says(realdata_dir, tmp_path):
    """The demo data's chains (test seq0: 13 + 9 scans around a missing frame; train seq0 6-17 less its two
    repeats), no raw scan twice in a chain, and the written ground truth reproducing every kept pair's trans."""
    source = realdata_dir / RAFLOW / "demo_data"
    convs = raflow.convert(source)
    scans = {c.name: len(c.sequence.scans) for c in convs}
    assert scans == {"test_seq0_1": 13, "test_seq0_13": 9, "train_seq0_6": 11, "train_seq1_622": 5,
                     "train_seq2_1986": 6, "val_seq0_10": 10}
    for conv in convs:
        seq = conv.sequence
        vr = [s.radial_velocity for s in seq.scans]
        assert not any(np.array_equal(a, b) for i, a in enumerate(vr) for b in vr[i + 1:]), conv.name
        steps = np.diff([s.t for s in seq.scans])
        assert np.all((steps > 0.098) & (steps < 0.21)), conv.name
        np.testing.assert_allclose(seq.groundtruth.T_world_vehicle[0], np.eye(4), atol=1e-12)
    # each kept consecutive pair of test seq0's first chain is one sample file: its trans is inv(pose1) pose2
    conv = next(c for c in convs if c.name == "test_seq0_1")
    G = conv.sequence.groundtruth.T_world_vehicle
    for k in range(1, 13):
        trans = np.array(json.loads((source / "test" / f"radar_seqs-0_samples-{k}.json").read_text())["trans"])
        np.testing.assert_allclose(se3.inverse(G[k - 1]) @ G[k], trans, atol=1e-9)
    out = write_conversion(tmp_path / conv.name, conv)
    back = read_sequence(out)
    assert len(back.scans) == 13 and set(back.scans[0].extra) == {"rcs", "power"}
