"""Fuzzing the CSV/YAML converters' input: whatever the rows of a TI mmWave export (radar_scans.csv,
radar_detections.csv, the calibration yaml) or of a RadarScenes export (radar{N}_detections.csv(.gz),
radar{N}_timestamp_and_odom.csv), `convert ti-mmwave` / `convert radarscenes` give a sequence that writes and
reads back with only finite detections, or an InputError naming a file of the source folder (or an option);
never another exception. Generated rows hold NaN, infinity, huge, negative and duplicate values; some lines are
damaged (a field replaced by junk, a field missing, a blank line, a truncated file). Sizes follow the hypothesis
profile of tests/conftest.py (nightly: 1000 cases). The `convert vod` fuzzer is tests/sim/test_convert_fuzz.py.
"""

import gzip
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo.sim.convert import radarscenes, ti_mmwave
from rodo.sim.sequence import read_sequence, write_sequence

specials = st.sampled_from([0.0, -0.0, np.nan, np.inf, -np.inf, 1e308, -1e308, 1e-320, 1.0, -3.0, 0.125, 5.0])
plausible = st.floats(-50, 50)


def mostly(usual, rare, n: int):
    """`usual` in n of n + 1 draws, else `rare` (so that many conversions go through)."""
    return st.integers(0, n).flatmap(lambda k: rare if k == 0 else usual)


values = mostly(plausible, st.one_of(specials, st.floats(allow_nan=True, allow_infinity=True)), 3)
indices = mostly(st.integers(0, 5), st.one_of(st.integers(-2, 8), st.sampled_from([10**12, 2**62, -(2**62)])), 3)
ns = st.one_of(st.integers(0, 10**9), st.sampled_from([0, 1, 2**62, 2**63 - 1, -(2**63), 1631895354018503000]))
junk = st.sampled_from(["", "abc", "1e", "nan", "inf", "1.5", " ", "0x10", "1,2", "--1"])


def _field(v) -> str:
    return repr(float(v)) if isinstance(v, float) else str(v)


@st.composite
def csv_text(draw, header: list[str], cells: list) -> str:
    """A header and 0-8 rows drawn from `cells` (one strategy per column), some lines damaged."""
    lines = [",".join(header)]
    for _ in range(draw(st.integers(0, 8))):
        row = [_field(draw(c)) for c in cells]
        damage = draw(st.sampled_from(["none"] * 30 + ["junk", "short", "blank"]))
        if damage == "junk":
            row[draw(st.integers(0, len(row) - 1))] = draw(junk)
        elif damage == "short":
            row = row[:-1]
        lines.append("" if damage == "blank" else ",".join(row))
    text = "\n".join(lines) + "\n"
    if draw(st.integers(0, 19)) == 0:  # a truncated file
        text = text[: draw(st.integers(0, len(text)))]
    return text


def calib_yaml(draw) -> str:
    q = np.array([draw(st.one_of(values, st.just(0.5))) for _ in range(4)])
    with np.errstate(all="ignore"):
        norm = np.linalg.norm(q)
    if draw(mostly(st.just(True), st.just(False), 4)) and np.isfinite(norm) and norm > 1e-100:
        q = q / norm  # a unit quaternion mostly, so that conversions go through
    entries = dict(zip(ti_mmwave.CALIB_KEYS, [draw(values) for _ in range(3)] + list(q) + [draw(values)]))
    if draw(st.booleans()):
        entries["radar_frame_ms"] = 18.5
    drop = draw(mostly(st.just(set()), st.sets(st.sampled_from(ti_mmwave.CALIB_KEYS), min_size=1, max_size=1), 5))
    spell = {np.inf: ".inf", -np.inf: "-.inf"}
    return "".join(f"{k}: {spell.get(v, 'nan' if v != v else repr(float(v)))}\n"
                   for k, v in entries.items() if k not in drop)


@st.composite
def ti_exports(draw) -> dict[str, str]:
    return {
        ti_mmwave.CALIB_YAML: calib_yaml(draw),
        ti_mmwave.SCANS_CSV: draw(csv_text(["scan_idx", "t_trigger_ns", "n_points"], [indices, ns, indices])),
        ti_mmwave.DETECTIONS_CSV: draw(csv_text(["scan_idx", "x_m", "y_m", "z_m", "intensity", "v_radial_mps"],
                                                [indices] + [values] * 5)),
    }


@st.composite
def radarscenes_exports(draw) -> tuple[dict[str, bytes], float | None]:
    rare = mostly(plausible, values, 12)  # an odometry row with one bad value is refused as a whole
    t = st.one_of(rare, st.floats(0, 10))
    odom = draw(csv_text(list(radarscenes.ODOM_COLUMNS), [t, t] + [rare] * 5))
    if draw(st.booleans()):  # increasing scan times (the odometry file's first column) half of the time
        lines = odom.split("\n")
        times = np.cumsum([draw(st.floats(1e-3, 1.0)) for _ in lines])
        odom = "\n".join([lines[0]] + [f"{float(t)!r}," + line.partition(",")[2] if line else line
                                       for t, line in zip(times, lines[1:])])
    det = draw(csv_text(list(radarscenes.DET_COLUMNS), [indices] + [values] * 6))
    name = "radar2_detections.csv"
    if draw(st.booleans()):
        return {"radar2_timestamp_and_odom.csv": odom.encode(), name + ".gz": gzip.compress(det.encode())}, None
    t_max = draw(st.one_of(st.none(), values))
    return {"radar2_timestamp_and_odom.csv": odom.encode(), name: det.encode()}, t_max


def _check_round_trip(conv, d: Path) -> None:
    """Finite detections with range > 0; the sequence writes and reads back unchanged."""
    for scan in conv.sequence.scans:
        assert np.all(np.isfinite(scan.polar)) and np.all(scan.polar[:, 0] > 0)
    out = d / "seq"
    write_sequence(out, conv.sequence)
    back = read_sequence(out)
    assert len(back.scans) == len(conv.sequence.scans)
    for a, b in zip(back.scans, conv.sequence.scans):
        np.testing.assert_allclose(a.polar, b.polar, rtol=1e-12, atol=0)
        assert a.t == b.t


def _assert_names_the_input(exc: InputError, src: Path) -> None:
    msg = str(exc)
    assert "\n" not in msg, msg
    assert str(src) in msg or msg.startswith(("t_max:", "--t-max:")), msg


def _convert(folder: str, files: dict[str, str | bytes], convert) -> None:
    """Write `files` into a fresh source folder and convert it: a round trip or an InputError naming the input."""
    with tempfile.TemporaryDirectory() as d:
        src = Path(d) / folder
        src.mkdir()
        for name, content in files.items():
            (src / name).write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))
        try:
            conv = convert(src)
        except InputError as exc:
            _assert_names_the_input(exc, src)
            return
        _check_round_trip(conv, Path(d))


def convert_ti(files: dict[str, str]) -> None:
    _convert("ti", files, ti_mmwave.convert)


def convert_radarscenes(files: dict[str, bytes], t_max) -> None:
    _convert("rs", files, lambda src: radarscenes.convert_radar(src, 2, t_max))


@given(ti_exports())
@settings(suppress_health_check=[HealthCheck.too_slow], deadline=None)
def test_ti_mmwave_rows_convert_to_a_finite_sequence_or_a_named_input_error(files):
    convert_ti(files)


@given(radarscenes_exports())
@settings(suppress_health_check=[HealthCheck.too_slow], deadline=None)
def test_radarscenes_rows_convert_to_a_finite_sequence_or_a_named_input_error(export):
    convert_radarscenes(*export)


# ---------------------------------------------------------------- failing examples the fuzzers found, kept

UNIT_Q = "l_b_r_x: 0.0\nl_b_r_y: 0.0\nl_b_r_z: 0.0\nq_b_r_x: 0.0\nq_b_r_y: 0.0\nq_b_r_z: 0.0\nq_b_r_w: 1.0\n"
DET_HEADER = "scan_idx,x_m,y_m,z_m,intensity,v_radial_mps\n"


def _ti(tmp_path, scans: str, dets: str, calib: str = UNIT_Q + "radar_frame_ms: 0.0\n"):
    (tmp_path / ti_mmwave.CALIB_YAML).write_text(calib)
    (tmp_path / ti_mmwave.SCANS_CSV).write_text("scan_idx,t_trigger_ns\n" + scans)
    (tmp_path / ti_mmwave.DETECTIONS_CSV).write_text(DET_HEADER + dets)
    return ti_mmwave.convert(tmp_path)


def test_ti_huge_quaternion_component_is_a_named_error_not_an_overflow(tmp_path):
    calib = UNIT_Q.replace("q_b_r_x: 0.0", "q_b_r_x: 0.5").replace("q_b_r_w: 1.0", "q_b_r_w: 1.3407807929942597e+154")
    with pytest.raises(InputError, match=r"calib_ti_mmwave_rospkg_dataset\.yaml, line 4, field 'q_b_r': not a unit"):
        _ti(tmp_path, "0,0\n", "", calib + "radar_frame_ms: 0.0\n")


def test_ti_detections_straight_up_keep_the_field_of_view_inside_its_limits(tmp_path):
    conv = _ti(tmp_path, "1,0\n", "1,0.0,0.0,1.0,0.0,0.0\n")
    lo, hi = conv.sequence.sensor.elevation_fov
    assert lo < hi <= np.pi / 2 and hi == pytest.approx(np.pi / 2)
    _check_round_trip(conv, tmp_path)


def test_ti_overflowing_range_is_dropped_and_counted(tmp_path):
    """One detection at 1e308 m among 101 is dropped (up to 1 % are; more are refused: millimetres?)."""
    conv = _ti(tmp_path, "0,0\n", "0,1e308,1e308,0.0,0.0,0.0\n" + "0,5.0,0.0,0.0,0.0,0.0\n" * 100)
    assert conv.report.dropped == {"detections farther than 2000 m": 1}
    assert conv.report.kept_detections == 100


S = 10**8  # ns: 10 Hz (the median step must be a scan rate, 0.1-1000 Hz)


@pytest.mark.parametrize("trig, kept", [
    ([0, 10 * S, 5 * S, 7 * S, 11 * S], [0, 10 * S, 11 * S]),  # only the previous row was compared: 7 > 5 was kept
    # 1 ns after 1e8 s is lost in float64
    ([0, S, 2 * S, 10**17, 10**17 + 1, 10**17 + S, 10**17 + 2 * S],
     [0, S, 2 * S, 10**17, 10**17 + S, 10**17 + 2 * S]),
])
def test_ti_scan_times_strictly_increase(tmp_path, trig, kept):
    scans = "".join(f"{k},{t}\n" for k, t in enumerate(trig))
    conv = _ti(tmp_path, scans, "".join(f"{k},5.0,0.0,0.0,0.0,0.0\n" for k in range(len(trig))))
    t = np.array([s.t for s in conv.sequence.scans])
    assert np.all(np.diff(t) > 0) and conv.sequence.sensor.rate_hz > 0
    np.testing.assert_allclose(t, (np.array(kept) - trig[0]) * 1e-9, atol=1e-6)


def test_ti_trigger_times_spanning_centuries_are_refused(tmp_path):
    with pytest.raises(InputError, match=r"radar_scans\.csv, field 't_trigger_ns': trigger times span more than"):
        _ti(tmp_path, f"0,{-(2**63)}\n1,{2**63 - 1}\n", "")


def _radarscenes_odometry(tmp_path, rows: str):
    """Convert radar 2 of a RadarScenes folder with these odometry rows and no detections."""
    (tmp_path / "radar2_timestamp_and_odom.csv").write_text(",".join(radarscenes.ODOM_COLUMNS) + "\n" + rows)
    (tmp_path / "radar2_detections.csv").write_text(",".join(radarscenes.DET_COLUMNS) + "\n")
    return radarscenes.convert_radar(tmp_path, 2)


def test_radarscenes_huge_odometry_value_is_a_named_error_not_an_overflow(tmp_path):
    with pytest.raises(InputError, match=r"odom\.csv, line 3, field 'yaw_rate_ego': \|value\| > 1e\+09"):
        _radarscenes_odometry(tmp_path, "-1.0,0,0,0,0,0,0\n0.0,0,0,0,0,0,4.657236100679575e+307\n")


def test_ti_blank_line_inside_the_scans_is_named_not_an_index_error(tmp_path):
    """np.loadtxt skipped the blank line, so a bad value's row no longer matched its line."""
    with pytest.raises(InputError, match=r"radar_scans\.csv, line 2: blank line"):
        _ti(tmp_path, "\n0,nan\n", "")


def test_radarscenes_scan_times_closer_than_groundtruth_precision_are_refused(tmp_path):
    """0 and 1.16e-131 s are distinct, but one time in groundtruth.txt (1 ns): the sequence did not read back."""
    with pytest.raises(InputError, match=r"line 3, field 'timestamp_rad': times must increase by at least 1e-06 s"):
        _radarscenes_odometry(tmp_path, "0.0,0,0,0,0,0,0\n1.1618033020708705e-131,0,0,0,0,0,0\n")
