"""Sizes are bounded before anything is allocated (a clear error, never a MemoryError) and a sequence whose
radar and ground-truth clocks do not overlap is refused, naming both files."""

import shutil

import numpy as np
import pytest

from rodo import scenarios
from rodo.estimator.errors import InputError
from rodo.scenarios.registry import MAX_DURATION
from rodo.sim.convert import ti_mmwave
from rodo.sim.sequence import read_sequence
from tests.cli.helpers import fails
from tests.sim.test_convert import _write_ti


@pytest.mark.parametrize("duration", ["1e9", "3600.5"])
def test_simulation_length_is_bounded_before_allocation(tmp_path, capsys, duration):
    fails(capsys, ["simulate", "city", "--duration", duration, "--out", tmp_path / "s"], "duration",
           f"at most {MAX_DURATION:g} s")
    assert not (tmp_path / "s").exists()
    fails(capsys, ["montecarlo", "city", "--runs", "1", "--duration", duration, "--out", tmp_path / "m"],
           "--duration", f"at most {MAX_DURATION:g} s")
    assert not (tmp_path / "m").exists()
    with pytest.raises(InputError, match="at most 3600 s"):
        scenarios.get("highway").build(0, duration=float(duration))


def test_ti_scan_index_of_1e12_converts_without_a_table_that_long(tmp_path):
    """The scan index only orders scans: 10**12 costs no more memory than 3 (the same sequence, shifted)."""
    for name, offset in (("small", 0), ("huge", 10**12)):
        _write_ti(tmp_path / name, np.random.default_rng(np.random.SeedSequence(3)))
        for f in (ti_mmwave.SCANS_CSV, ti_mmwave.DETECTIONS_CSV):
            p = tmp_path / name / f
            lines = p.read_text().splitlines()
            p.write_text("\n".join([lines[0]] + [f"{int(r.split(',')[0]) + offset},{r.split(',', 1)[1]}"
                                                 for r in lines[1:]]) + "\n")
    small, huge = ti_mmwave.convert(tmp_path / "small"), ti_mmwave.convert(tmp_path / "huge")
    assert len(huge.sequence.scans) == len(small.sequence.scans) == 4
    for a, b in zip(small.sequence.scans, huge.sequence.scans):
        assert a.t == b.t and np.array_equal(a.range, b.range) and np.array_equal(a.radial_velocity, b.radial_velocity)
    assert huge.report.dropped == small.report.dropped == {"detections at zero range": 1}


def test_detections_of_unknown_scans_are_dropped_and_counted(tmp_path):
    _write_ti(tmp_path / "src", np.random.default_rng(1))
    p = tmp_path / "src" / ti_mmwave.DETECTIONS_CSV
    p.write_text(p.read_text() + "999999999999,5.0,0.0,0.0,10,0.0,0,0,0\n-5,5.0,0.0,0.0,10,0.0,0,0,0\n")
    conv = ti_mmwave.convert(tmp_path / "src")
    assert conv.report.dropped["detections whose scan has no (valid) trigger time"] == 2


def test_radar_and_groundtruth_on_different_clocks_are_refused(seq, tmp_path, capsys):
    bad = tmp_path / "offset"
    shutil.copytree(seq, bad)
    gt = bad / "groundtruth.txt"
    rows = [r.split() for r in gt.read_text().splitlines() if r and not r.startswith("#")]
    gt.write_text("".join(" ".join([repr(float(r[0]) + 100.0)] + r[1:]) + "\n" for r in rows))
    with pytest.raises(InputError, match=r"radar.csv \(scans at .*\) and .*groundtruth.txt \(poses at 100.* do not "
                                         "overlap in time"):
        read_sequence(bad)
    fails(capsys, ["run", bad, "--out", tmp_path / "o"], str(bad / "radar.csv"), str(gt), "do not overlap")
    assert not (tmp_path / "o").exists()
    # overlapping clocks are accepted, even when the truth covers only part of the scans
    gt.write_text("".join(" ".join(r) + "\n" for r in rows[len(rows) // 2:]))
    assert read_sequence(bad).groundtruth is not None
