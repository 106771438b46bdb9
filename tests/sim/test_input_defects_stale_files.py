"""Writing a sequence into a directory that holds another one leaves none of the earlier writer's files
(docs/sequence_format.md, "Writing"): a conversion over a simulation drops its truth.npz
(sim.convert.write_conversion), a simulation over a conversion its conversion.json and odom.csv
(sim.sequence.write_sequence, CONVERTER_FILES)."""

from __future__ import annotations

import numpy as np
import pytest

from rodo import scenarios
from rodo.cli import main
from rodo.estimator.errors import InputError
from rodo.sim.convert import CONVERSION_JSON, radarscenes
from rodo.sim.rig import Rig, write_rig
from rodo.sim.sequence import CONVERTER_FILES, Trajectory, read_sequence, write_sequence
from rodo.sim.simulate import TRUTH_NPZ
from tests.sim.test_convert import _rng, _write_radarscenes, _write_ti


def test_conversion_over_a_simulation_keeps_no_simulator_file(tmp_path):
    seq = tmp_path / "mine"
    assert main(["simulate", "city", "--seed", "3", "--duration", "1", "--out", str(seq)]) == 0
    assert (seq / TRUTH_NPZ).is_file() and (seq / "groundtruth.txt").is_file()
    _write_ti(tmp_path / "ti", _rng(8))
    assert main(["convert", "ti-mmwave", str(tmp_path / "ti"), "--out", str(seq)]) == 0
    names = sorted(p.name for p in seq.iterdir() if not p.name.startswith("."))
    assert names == [CONVERSION_JSON, "radar.csv", "sensor.toml"]  # TI has no ground truth: no groundtruth.txt


def test_simulation_over_a_conversion_keeps_no_converter_file(tmp_path):
    _write_radarscenes(tmp_path / "rs", 2, _rng(3), n_scans=8, per_scan=30)
    seq = tmp_path / "mine"
    assert main(["convert", "radarscenes", str(tmp_path / "rs"), "--radars", "2", "--out", str(seq)]) == 0
    assert (seq / CONVERSION_JSON).is_file() and (seq / "odom.csv").is_file()
    assert main(["simulate", "city", "--seed", "3", "--duration", "1", "--out", str(seq)]) == 0
    names = sorted(p.name for p in seq.iterdir() if not p.name.startswith("."))
    assert names == ["groundtruth.txt", "radar.csv", "sensor.toml", TRUTH_NPZ]


def test_converter_files_are_the_files_the_converters_write(tmp_path):
    """CONVERTER_FILES names every file a converter adds, so a renamed one cannot silently stay behind;
    `write_sequence` removes them and leaves the simulator's truth.npz and any other file alone."""
    assert CONVERSION_JSON in CONVERTER_FILES
    _write_radarscenes(tmp_path / "rs", 1, _rng(4), n_scans=5, per_scan=30)
    conv = radarscenes.convert(tmp_path / "rs", radars=(1,))[0]
    assert set(conv.extra_files) <= set(CONVERTER_FILES)
    seq, _ = scenarios.get("city").simulate(1, 0.3)
    d = tmp_path / "d"
    d.mkdir()
    for name in CONVERTER_FILES + (TRUTH_NPZ, "notes.txt"):
        (d / name).write_text("earlier")
    write_sequence(d, seq)
    assert sorted(p.name for p in d.iterdir()) == ["groundtruth.txt", "notes.txt", "radar.csv", "sensor.toml",
                                                   TRUTH_NPZ]


def test_a_stale_file_that_cannot_be_removed_is_named(tmp_path):
    seq, _ = scenarios.get("city").simulate(1, 0.3)
    (tmp_path / CONVERSION_JSON).mkdir()  # a directory where conversion.json would be: not removable as a file
    with pytest.raises(InputError, match="conversion.json: cannot remove this stale file"):
        write_sequence(tmp_path, seq)


def test_a_rig_written_without_groundtruth_drops_the_earlier_one(tmp_path):
    seq, _ = scenarios.get("city").simulate(1, 0.3)
    gt = Trajectory(np.array([0.0, 0.3]), np.tile(np.eye(4), (2, 1, 1)))
    write_rig(tmp_path, Rig(["a"], [seq], gt))
    assert (tmp_path / "groundtruth.txt").is_file()
    write_rig(tmp_path, Rig(["a"], [seq]))
    assert not (tmp_path / "groundtruth.txt").exists() and len(read_sequence(tmp_path / "a").scans) == 4
