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
from rodo.sim.convert import radarscenes, raflow, ti_mmwave, vod
from rodo.sim.sequence import read_sequence
from tests.sim.test_convert import _rng, _run, _vod_frame, _write_radarscenes, _write_ti, _write_vod
from tests.sim.test_convert_raflow import _pc, _synthetic, _write


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


def test_radarscenes_several_radars_check_every_target_first(tmp_path, capsys):
    """Finding 11: out/radar3 a file left out/radar2 written (a partial output)."""
    for r in (2, 3):
        _write_radarscenes(tmp_path / "src", r, _rng(28 + r), n_scans=5, per_scan=30)
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "radar3").write_text("")
    _fails(["convert", "radarscenes", tmp_path / "src", "--out", tmp_path / "o", "--radars", "2,3"], capsys,
           "--out", "radar3")
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["radar3"]


# ---------------------------------------------------------------- VoD: file order, dtype, empty, --rate

def test_vod_unpadded_names_are_taken_in_numeric_order(tmp_path):
    """Finding 3: 0.bin, 1.bin, 10.bin, 2.bin was the scan order."""
    rng = _rng(29)
    frames = [_vod_frame(rng, 3 + k, np.array([5.0, 0, 0])) for k in range(12)]
    tmp_path.joinpath("src").mkdir()
    for k, f in enumerate(frames):
        (tmp_path / "src" / f"{k}.bin").write_bytes(np.asarray(f, dtype="<f4").tobytes())
    conv = vod.convert(tmp_path / "src")
    assert [len(s.range) for s in conv.sequence.scans] == [3 + k for k in range(12)]
    assert conv.report.info["files"] == [f"{k}.bin" for k in range(12)]


@pytest.mark.parametrize("dtype", ["<f8", ">f4", "<f8 round"])
def test_vod_float64_or_big_endian_files_are_refused(tmp_path, capsys, dtype):
    """Finding 4: 56-byte float64 rows are two 28-byte float32 rows; both decoded as garbage and were kept."""
    frame = _vod_frame(_rng(30), 10, np.array([5.0, 0, 0]))
    if dtype == "<f8 round":  # float32 values stored as float64 (the reviewer's case: 10, 1, 0, 0, -1, 0, 0)
        frame, dtype = frame.astype(np.float32).astype(np.float64), "<f8"
    _write_vod(tmp_path / "src", [frame[:0] + 0, frame])
    (tmp_path / "src" / "00001.bin").write_bytes(np.asarray(frame, dtype=dtype).tobytes())
    _fails(["convert", "vod", tmp_path / "src", "--out", tmp_path / "o"], capsys, "00001.bin",
           "wrong dtype or byte order? (expected little-endian float32 x, y, z, rcs, v_r, v_r_compensated, time)")


def test_vod_float32_upcast_round_values_are_refused(tmp_path, capsys):
    rows = np.tile([10.0, 1.0, 0.0, 0.0, -1.0, 0.0, 0.0], (5, 1))
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "00000.bin").write_bytes(rows.astype("<f8").tobytes())
    _fails(["convert", "vod", tmp_path / "src", "--out", tmp_path / "o"], capsys, "00000.bin", "float64")


def test_vod_empty_files_name_the_source(tmp_path, capsys):
    """Finding 6: only 0-byte files gave an empty sequence with exit 0."""
    _write_vod(tmp_path / "src", [np.zeros((0, 7))] * 3)
    _fails(["convert", "vod", tmp_path / "src", "--out", tmp_path / "o"], capsys, "src: no detections")


def test_vod_rate_outside_scan_rates_names_the_option(tmp_path, capsys):
    _write_vod(tmp_path / "src", [_vod_frame(_rng(31), 5, np.ones(3))] * 2)
    _fails(["convert", "vod", tmp_path / "src", "--out", tmp_path / "o", "--rate", "0.01"], capsys,
           "--rate: ", "0.1 to 1000 Hz")


# ---------------------------------------------------------------- RaFlow: layout, reflected pose, JSON types

def test_raflow_single_chain_goes_to_its_subdirectory(tmp_path):
    """Finding 8: with one chain the sequence went straight into --out; the layout is SEQ_DIR/SPLIT_seqS_K."""
    _synthetic(tmp_path / "src")
    assert _run(["convert", "raflow", str(tmp_path / "src"), "--out", str(tmp_path / "o"), "--min-scans", "3"]) == 0
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["train_seq0_1"]
    assert len(read_sequence(tmp_path / "o" / "train_seq0_1").scans) == 4


@pytest.mark.parametrize("pose, needles", [
    (np.diag([1.0, 1.0, -1.0, 1.0]), ["'pc1.pose'", "determinant -1", "reflection"]),
    (np.diag([1.0, 1.0, 1.1, 1.0]), ["'pc1.pose'", "|C C^T - I| = 0.21"]),
])
def test_raflow_reflected_pose_names_file_and_key(tmp_path, pose, needles):
    """Finding 9: 'Trajectory.T_world_vehicle: ... not a proper rotation (|C C^T - I| = 2.22e-16)'."""
    path = _write(tmp_path, "val", 0, 10, dict(_pc(1, 0.0), pose=pose.tolist()), _pc(2, 1.0))
    with pytest.raises(InputError) as err:
        raflow.convert(tmp_path, min_scans=2)
    for needle in [str(path), *needles]:
        assert needle in str(err.value), (needle, str(err.value))


@pytest.mark.parametrize("value", ["1.5", True, None])
def test_raflow_strings_and_booleans_are_not_numbers(tmp_path, value):
    pc = _pc(1, 0.0)
    pc["rcs"][3] = value
    path = _write(tmp_path, "val", 0, 10, pc, _pc(2, 1.0))
    with pytest.raises(InputError, match=r"field 'pc1.rcs': every entry must be a number") as err:
        raflow.convert(tmp_path, min_scans=2)
    assert str(path) in str(err.value)


def test_raflow_chain_without_detections_names_its_file(tmp_path):
    """Finding 6 (frames without points are one raw scan, dropped as repeats: no points left means NaN ones)."""
    pc1, pc2 = _pc(1, 0.0), _pc(2, 1.0)
    for pc in (pc1, pc2):
        pc["car_loc_x"] = [float("nan")] * len(pc["car_loc_x"])
    path = _write(tmp_path, "val", 0, 10, pc1, pc2)
    with pytest.raises(InputError, match="no detections") as err:
        raflow.convert(tmp_path, min_scans=2)
    assert str(path) in str(err.value)


def test_raflow_interval_below_a_millisecond_is_refused(tmp_path):
    path = _write(tmp_path, "val", 0, 10, _pc(1, 0.0), _pc(2, 1.0), interval=1e-7)
    with pytest.raises(InputError, match=r"field 'interval': expected seconds in \[0.001, 10\)") as err:
        raflow.convert(tmp_path, min_scans=2)
    assert str(path) in str(err.value)


def test_raflow_chain_slower_than_any_radar_names_its_first_file(tmp_path):
    """Intervals of 9 s with the middle scan a repeat (dropped): 2 scans 18 s apart, 0.056 Hz."""
    a, b = _pc(1, 0.0), _pc(2, 1.0)
    first = _write(tmp_path, "val", 0, 10, a, dict(a, pose=_pc(3, 2.0)["pose"]), interval=9.0)
    _write(tmp_path, "val", 0, 11, dict(a, pose=_pc(3, 2.0)["pose"]), b, interval=9.0)
    with pytest.raises(InputError, match=r"field 'interval': the chain's 2 scans span 18 s, 0.0556 Hz") as err:
        raflow.convert(tmp_path, min_scans=2)
    assert str(first) in str(err.value)
