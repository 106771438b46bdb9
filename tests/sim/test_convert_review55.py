"""Converter input a review found accepted silently or refused without naming the input (findings 1-14 of
review 55): times in another unit, an odometry clock offset, angles in degrees, positions in millimetres, empty
detection files, VoD files in another dtype or named without padding, a reflected RaFlow pose, duplicate bag
times, a multi-radar target that is a file. Each case: exit 2 (InputError) with a message naming the file and
field, nothing written; or, where the input is valid, the documented layout.
"""

from __future__ import annotations

import gzip

import numpy as np
import pytest

from rodo.estimator.errors import InputError
from rodo.sim.convert import radarscenes, ti_mmwave
from tests.sim.test_convert import _rng, _run, _write_radarscenes, _write_ti


def _fails(argv, capsys, *needles) -> str:
    """`rodo convert ...` exits 2 with one line naming every needle."""
    assert _run([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rodo convert: error: ") and err.count("\n") == 1, err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


# ---------------------------------------------------------------- TI mmWave: time and position units, empty

def _edit_csv(path, column: str, edit) -> None:
    """Rewrite one column of a CSV file with `edit(text) -> text`."""
    lines = path.read_text().splitlines()
    j = lines[0].split(",").index(column)
    rows = [lines[0]]
    for line in lines[1:]:
        parts = line.split(",")
        parts[j] = edit(parts[j])
        rows.append(",".join(parts))
    path.write_text("\n".join(rows) + "\n")


def test_ti_trigger_times_in_milliseconds_name_file_and_field(tmp_path, capsys):
    """Finding 1: t_trigger_ns in ms made 98 ns steps, a 1e7 Hz sensor; refused before SensorConfig's check."""
    _write_ti(tmp_path / "src", _rng(20), n_scans=6)
    _edit_csv(tmp_path / "src" / ti_mmwave.SCANS_CSV, "t_trigger_ns", lambda s: str(int(s) // 1_000_000))
    err = _fails(["convert", "ti-mmwave", tmp_path / "src", "--out", tmp_path / "o"], capsys,
                 "radar_scans.csv", "field 't_trigger_ns'", "median step 98 ns between scans", "milliseconds?")
    assert "SensorConfig" not in err and not (tmp_path / "o").exists()


def test_ti_positions_in_millimetres_name_file_line_and_field(tmp_path, capsys):
    """Finding 14: x, y, z in mm gave a 19 km max range; refused beyond 2 km with a millimetres hint."""
    _write_ti(tmp_path / "src", _rng(21))
    for c in ("x_m", "y_m", "z_m"):
        _edit_csv(tmp_path / "src" / ti_mmwave.DETECTIONS_CSV, c, lambda s: repr(1000 * float(s)))
    _fails(["convert", "ti-mmwave", tmp_path / "src", "--out", tmp_path / "o"], capsys,
           "radar_detections.csv, line 2, field 'x_m'", "millimetres?")
    assert not (tmp_path / "o").exists()


def test_ti_header_only_detections_name_the_file(tmp_path, capsys):
    """Finding 6: no detections gave an empty sequence with exit 0."""
    _write_ti(tmp_path / "src", _rng(22))
    det = tmp_path / "src" / ti_mmwave.DETECTIONS_CSV
    det.write_text(det.read_text().splitlines()[0] + "\n")
    _fails(["convert", "ti-mmwave", tmp_path / "src", "--out", tmp_path / "o"], capsys,
           "radar_detections.csv: no detections")


def test_ti_directory_for_a_csv_says_so(tmp_path):
    _write_ti(tmp_path / "src", _rng(23))
    (tmp_path / "src" / ti_mmwave.DETECTIONS_CSV).unlink()
    (tmp_path / "src" / ti_mmwave.DETECTIONS_CSV).mkdir()
    with pytest.raises(InputError, match=r"radar_detections\.csv: is a directory, expected a file"):
        ti_mmwave.convert(tmp_path / "src")


# ---------------------------------------------------------------- RadarScenes: odometry time, angles, empty

def _edit_odom(folder, edit) -> None:
    """Rewrite radar2's odometry times: edit(t_rad, t_odom) -> (t_rad, t_odom)."""
    path = folder / "radar2_timestamp_and_odom.csv"
    lines = path.read_text().splitlines()
    rows = [lines[0]]
    for line in lines[1:]:
        a, b, rest = line.split(",", 2)
        a, b = edit(float(a), float(b))
        rows.append(f"{a!r},{b!r},{rest}")
    path.write_text("\n".join(rows) + "\n")


def _edit_azimuth(folder, edit) -> None:
    path = folder / "radar2_detections.csv.gz"
    lines = gzip.open(path, "rt").read().splitlines()
    rows = [lines[0]]
    for line in lines[1:]:
        parts = line.split(",")
        parts[2] = repr(edit(float(parts[2])))
        rows.append(",".join(parts))
    with gzip.open(path, "wt") as f:
        f.write("\n".join(rows) + "\n")


@pytest.mark.parametrize("edit, needles", [
    (lambda a, b: (a, b + 5.0), ["line 2, field 'timestamp_odom'", "5.0", "from timestamp_rad"]),
    (lambda a, b: (1e3 * a, 1e3 * b), ["field 'timestamp_rad'", "milliseconds?"]),
    (lambda a, b: (1e6 * a, 1e6 * b), ["field 'timestamp_rad'", "microseconds?"]),
])
def test_radarscenes_odometry_time_offset_or_unit_is_refused(tmp_path, capsys, edit, needles):
    """Finding 2: an offset or a unit in the odometry times moved groundtruth.txt 100 m to tens of km."""
    _write_radarscenes(tmp_path / "src", 2, _rng(24), n_scans=20, per_scan=30)
    _edit_odom(tmp_path / "src", edit)
    _fails(["convert", "radarscenes", tmp_path / "src", "--out", tmp_path / "o", "--radars", "2"], capsys,
           "radar2_timestamp_and_odom.csv", *needles)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("edit, hint", [(lambda a: float(np.rad2deg(a)), "degrees"),
                                        (lambda a: a % (2 * np.pi), "[0, 2pi)")])
def test_radarscenes_azimuths_in_degrees_or_0_2pi_are_refused(tmp_path, capsys, edit, hint):
    """Finding 5: most rows were dropped as 'outside [-pi, pi]' and the rest written, exit 0."""
    _write_radarscenes(tmp_path / "src", 2, _rng(25), n_scans=20, per_scan=30)
    _edit_azimuth(tmp_path / "src", edit)
    _fails(["convert", "radarscenes", tmp_path / "src", "--out", tmp_path / "o", "--radars", "2"], capsys,
           "radar2_detections.csv.gz, line ", "field 'azimuth_rad'", hint)
    assert not (tmp_path / "o").exists()


def test_radarscenes_a_few_azimuths_out_of_range_are_still_dropped(tmp_path):
    _write_radarscenes(tmp_path, 2, _rng(26), n_scans=20, per_scan=30)
    _edit_azimuth(tmp_path, lambda a: 4.0 if a > 1.19 else a)
    conv = radarscenes.convert_radar(tmp_path, 2)
    n = conv.report.dropped["detections with azimuth outside [-pi, pi]"]
    assert 0 < n <= 6 and conv.report.kept_detections == 600 - n


def test_radarscenes_header_only_detections_name_the_file(tmp_path, capsys):
    """Finding 6."""
    _write_radarscenes(tmp_path / "src", 2, _rng(27), n_scans=5, per_scan=3)
    with gzip.open(tmp_path / "src" / "radar2_detections.csv.gz", "wt") as f:
        f.write(",".join(radarscenes.DET_COLUMNS) + "\n")
    _fails(["convert", "radarscenes", tmp_path / "src", "--out", tmp_path / "o", "--radars", "2"], capsys,
           "radar2_detections.csv.gz: no detections")
