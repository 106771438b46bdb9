"""`rodo export ply SEQ --run RUN_DIR` refuses a run of another sequence: simulated sequences share their scan
times, so the run's states.npz detection counts decide (sim/export.py, `check_run_of_sequence`)."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

from rodo import cli, scenarios
from rodo.commands import export as export_cmd
from rodo.commands import run as run_cmd
from rodo.sim.sequence import read_sequence, write_sequence


def _main(argv) -> int:
    return cli.main([str(a) for a in argv], commands=[export_cmd, run_cmd])


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """0.5 s of city and of hills (the same scan times) and a `rodo run` of city."""
    root = tmp_path_factory.mktemp("drives")
    for name in ("city", "hills"):
        scenarios.simulate_to(name, 0, root / name, duration=0.5)
    assert _main(["run", root / "city", "--out", root / "run_city"]) == 0
    return root


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("rodo export: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    return err


def test_a_run_of_another_sequence_with_the_same_times_is_refused(drives, tmp_path, capsys):
    """hills with city's run: the times match scan for scan (so the time check alone passed it), the counts do
    not; refused with both directories and the first scan, given as the directory or as its estimate.txt, before
    anything is written."""
    city, hills = read_sequence(drives / "city"), read_sequence(drives / "hills")
    assert [s.t for s in city.scans] == [s.t for s in hills.scans]
    for run in (drives / "run_city", drives / "run_city" / "estimate.txt"):
        assert _main(["export", "ply", drives / "hills", "--run", run, "--out", tmp_path / "x"]) == 2
        err = _one_line_error(capsys)
        first = hills.scans[0]
        for needle in (f"--run: {run} is not a run of {drives / 'hills'}", f"scan {first.scan} (t = 0.0 s)",
                       f"the run took {len(city.scans[0])} detections", f"the sequence has {len(first)} in range"):
            assert needle in err, (needle, err)
        assert not (tmp_path / "x").exists()


def test_the_run_of_the_same_sequence_passes(drives, tmp_path):
    seq = read_sequence(drives / "city")
    assert _main(["export", "ply", drives / "city", "--run", drives / "run_city", "--out", tmp_path / "ok"]) == 0
    assert (tmp_path / "ok" / "map.ply").is_file()
    assert len(list((tmp_path / "ok" / "scans").glob("*.ply"))) == len(seq.scans)


def test_the_run_of_a_sequence_with_filtered_detections_passes(drives, tmp_path, capsys):
    """Detections the estimator drops (beyond max_range; elevation exactly 0 under
    association.missing_elevation_zero) are not counted as a mismatch; the counts still are compared (one changed
    scan is refused)."""
    seq = read_sequence(drives / "city", use_cache=False)
    scans = []
    for k, s in enumerate(seq.scans):
        rng, el = s.range.copy(), s.elevation.copy()
        rng[:k] = seq.sensor.max_range + 1.0  # k detections out of range in scan k
        el[-2:] = 0.0  # two without an elevation
        scans.append(dataclasses.replace(s, range=rng, elevation=el))
    write_sequence(tmp_path / "seq", dataclasses.replace(seq, scans=scans))
    (tmp_path / "cfg.toml").write_text("[association]\nmissing_elevation_zero = true\n")
    assert _main(["run", tmp_path / "seq", "--config", tmp_path / "cfg.toml", "--out", tmp_path / "run"]) == 0
    n = np.load(tmp_path / "run" / "states.npz")["n_detections"]
    assert list(n) == [len(s) - k - 2 for k, s in enumerate(seq.scans)]  # the run did drop them
    assert _main(["export", "ply", tmp_path / "seq", "--run", tmp_path / "run", "--out", tmp_path / "ok"]) == 0
    scans[3] = dataclasses.replace(scans[3], range=scans[3].range.copy())
    scans[3].range[-3] = seq.sensor.max_range + 1.0  # one more out of range (it has an elevation)
    write_sequence(tmp_path / "seq", dataclasses.replace(seq, scans=scans))
    capsys.readouterr()
    assert _main(["export", "ply", tmp_path / "seq", "--run", tmp_path / "run", "--out", tmp_path / "no"]) == 2
    assert f"at scan {scans[3].scan} " in _one_line_error(capsys)


def test_without_states_npz_only_the_times_are_checked_and_said(drives, tmp_path, capsys):
    """A run directory without states.npz (or another TUM file) passes the time check with a warning saying that
    only the times were checked; an unreadable states.npz is refused, naming it."""
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(drives / "run_city" / "estimate.txt", run / "estimate.txt")
    assert _main(["export", "ply", drives / "hills", "--run", run, "--out", tmp_path / "o"]) == 0
    err = capsys.readouterr().err
    assert "warning" in err and "no states.npz" in err and "only its times were checked" in err, err
    (run / "states.npz").write_bytes(b"PK\x03\x04 not a zip")
    assert _main(["export", "ply", drives / "hills", "--run", run, "--out", tmp_path / "o2"]) == 2
    assert "states.npz: cannot read" in _one_line_error(capsys)
    np.savez(run / "states.npz", t=np.zeros(3))
    assert _main(["export", "ply", drives / "hills", "--run", run, "--out", tmp_path / "o2"]) == 2
    err = _one_line_error(capsys)
    assert "states.npz: no array 'n_detections' (not a `rodo run` states.npz)" in err and "cannot read" not in err
