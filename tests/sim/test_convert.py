"""Converters of real radar data (sim/convert, rodo convert): geometry, times, noise estimates, input errors.

Synthetic sources are written here in each format's layout; the real samples are used where they exist.
"""

from __future__ import annotations

import gzip
import json
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator.ego_velocity import estimate_ego_velocity
from rodo.estimator.errors import InputError
from rodo import cli
from rodo.commands import convert as convert_cmd
from rodo.sim.convert import CONVERSION_JSON, radarscenes, ti_mmwave, vod, write_conversion
from rodo.sim.sequence import polar_to_cartesian, read_sequence


def _rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed))


def _run(argv) -> int:
    return cli.main(argv, commands=[convert_cmd])


# ---------------------------------------------------------------- VoD (.bin frames)

def _write_vod(folder: Path, frames: list[np.ndarray]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for k, f in enumerate(frames):
        (folder / f"{k:05d}.bin").write_bytes(np.asarray(f, dtype="<f4").tobytes())


def _vod_frame(rng, n: int, v_sensor: np.ndarray) -> np.ndarray:
    """n static points ahead of the sensor with v_r = -u . v (sensor frame), columns as the VoD layout."""
    p = np.c_[rng.uniform(2, 50, n), rng.uniform(-20, 20, n), rng.uniform(-2, 3, n)]
    u = p / np.linalg.norm(p, axis=1, keepdims=True)
    vr = -u @ v_sensor
    return np.c_[p, rng.normal(0, 5, n), vr, np.zeros(n), rng.uniform(0, 0.05, n)]


def _normal(lo: float, hi: float):
    """Floats without the tiny ones that make a subnormal float32 value (angles: their sines; refused by `vod`)."""
    return st.floats(lo, hi).filter(lambda a: a == 0 or abs(a) > 1e-30)


@given(st.lists(st.tuples(st.floats(0.5, 80), _normal(-3.1, 3.1), _normal(-1.2, 1.2), _normal(-30, 30)),
                min_size=1, max_size=20))
def test_vod_polar_matches_cartesian_points(points):
    """range, azimuth, elevation of the converted scan give back the float32 x, y, z (paper eq. 80)."""
    r, az, el, vr = np.array(points).T
    xyz = polar_to_cartesian(r, az, el).astype(np.float32)
    frame = np.c_[xyz, np.zeros_like(r), vr, vr, np.zeros_like(r)]
    with tempfile.TemporaryDirectory() as d:
        _write_vod(Path(d), [frame])
        conv = vod.convert(d)
    (scan,) = conv.sequence.scans
    back = polar_to_cartesian(scan.range, scan.azimuth, scan.elevation)
    np.testing.assert_allclose(back, xyz.astype(float), atol=1e-9 + 1e-12 * r.max())
    np.testing.assert_array_equal(scan.radial_velocity, vr.astype(np.float32).astype(float))
    assert np.all(np.abs(scan.azimuth) <= np.pi) and np.all(np.abs(scan.elevation) <= np.pi / 2)


def test_vod_round_trip_times_extras_and_ego_velocity(tmp_path):
    """File-name order, t = k / rate, extra columns kept; Doppler ego-velocity recovers the sensor velocity."""
    rng = _rng(1)
    v = np.array([8.0, -0.7, 0.2])
    frames = [_vod_frame(rng, 60, v) for _ in range(3)]
    _write_vod(tmp_path / "src", frames)
    assert _run(["convert", "vod", str(tmp_path / "src"), "--out", str(tmp_path / "seq"), "--rate", "12.5"]) == 0
    seq = read_sequence(tmp_path / "seq")
    assert [s.scan for s in seq.scans] == [0, 1, 2]
    np.testing.assert_allclose([s.t for s in seq.scans], [0.0, 0.08, 0.16], atol=1e-15)
    assert seq.sensor.rate_hz == 12.5 and seq.groundtruth is None
    f32 = frames[1].astype(np.float32).astype(float)
    np.testing.assert_array_equal(seq.scans[1].extra["rcs"], f32[:, 3])
    np.testing.assert_array_equal(seq.scans[1].extra["point_time"], f32[:, 6])
    est = estimate_ego_velocity(seq.scans[1].azimuth, seq.scans[1].elevation, seq.scans[1].radial_velocity,
                                _rng(2), sigma_vr=0.01, planar=False)
    assert est.ok and np.allclose(est.v_sensor, v, atol=1e-4)
    report = json.loads((tmp_path / "seq" / CONVERSION_JSON).read_text())
    assert report["kept_detections"] == 180 and report["dropped"] == {}


def test_vod_drops_nan_and_zero_range_and_counts_them(tmp_path):
    frame = _vod_frame(_rng(3), 10, np.array([5.0, 0, 0]))
    frame[2, 0] = np.nan
    frame[4, :3] = 0.0
    frame[6, 4] = np.inf
    _write_vod(tmp_path, [frame, frame[:0], frame])  # an empty scan in the middle
    conv = vod.convert(tmp_path)
    assert conv.report.dropped == {"detections with NaN or infinity in x, y, z or v_r": 4,
                                   "detections at zero range": 2}
    assert [s.scan for s in conv.sequence.scans] == [0, 2]
    assert conv.report.kept_detections == 14
    assert any("without detections" in n for n in conv.report.notes)


def test_vod_bad_inputs(tmp_path, capsys):
    (tmp_path / "a.bin").write_bytes(b"\0" * 30)
    with pytest.raises(InputError, match=r"a\.bin: size 30 bytes is not a multiple of 28"):
        vod.convert(tmp_path)
    (tmp_path / "empty").mkdir()
    assert _run(["convert", "vod", str(tmp_path / "empty"), "--out", str(tmp_path / "o")]) == 2
    assert "no *.bin files" in capsys.readouterr().err
    _write_vod(tmp_path / "ok", [_vod_frame(_rng(4), 5, np.ones(3))])
    assert _run(["convert", "vod", str(tmp_path / "ok"), "--out", str(tmp_path / "o"), "--rate", "0"]) == 2
    assert "--rate: must be > 0" in capsys.readouterr().err
    assert _run(["convert", "vod", str(tmp_path / "ok"), "--out", str(tmp_path / "o"), "--radars", "2"]) == 2
    assert "--radars: only for the radarscenes format" in capsys.readouterr().err
    assert _run(["convert", "vod", str(tmp_path / "ok"), "--out", str(tmp_path / "o"), "--sigma", "1,2"]) == 2
    assert "--sigma: expected 4 numbers" in capsys.readouterr().err
    assert _run(["convert", "vod", str(tmp_path / "ok"), "--out", str(tmp_path / "o"),
                 "--sigma", "0.2,0.01,0.02,0.05"]) == 0
    assert read_sequence(tmp_path / "o").sensor.noise.radial_velocity == 0.05


# ---------------------------------------------------------------- RadarScenes (synthetic export)

def _write_radarscenes(folder: Path, radar: int, rng, n_scans=40, per_scan=80, sigma_vr=0.05, sigma_az=0.01,
                       speed=15.0, yaw_rate=0.05):
    """A synthetic export: straight-line odometry (x = speed t_odom), static detections with known noise."""
    folder.mkdir(parents=True, exist_ok=True)
    t = 0.05 + np.arange(n_scans) / 13.0
    t_odom = t + rng.uniform(-0.005, 0.005, n_scans)
    vx = np.full(n_scans, speed)
    w = np.full(n_scans, yaw_rate)
    odom = np.c_[t, t_odom, speed * t_odom, np.zeros(n_scans), np.zeros(n_scans), vx, w]
    lines = ["timestamp_rad,timestamp_odom,x_loc,y_loc,yaw_loc,vx_ego,yaw_rate_ego"]
    lines += [",".join(repr(float(v)) for v in row) for row in odom]
    (folder / f"radar{radar}_timestamp_and_odom.csv").write_text("\n".join(lines) + "\n")
    v_sensor = radarscenes.sensor_velocity(radar, vx, w)
    scan = np.repeat(np.arange(n_scans), per_scan)
    az_true = rng.uniform(-1.2, 1.2, len(scan))
    vr = (-(np.cos(az_true) * v_sensor[scan, 0] + np.sin(az_true) * v_sensor[scan, 1])
          + rng.normal(0, sigma_vr, len(scan)))
    az = az_true + rng.normal(0, sigma_az, len(scan))
    rows = np.c_[scan + 1, rng.uniform(1, 90, len(scan)), az, vr, rng.normal(-5, 5, len(scan)),
                 np.zeros(len(scan)), np.full(len(scan), 11)]
    text = "scan_idx,range_m,azimuth_rad,vr_mps,rcs_dbsm,vr_comp_mps,label_id\n"
    text += "\n".join(f"{int(r[0])},{float(r[1])!r},{float(r[2])!r},{float(r[3])!r},{float(r[4])!r},0.0,"
                      f"{int(r[6])}" for r in rows) + "\n"
    with gzip.open(folder / f"radar{radar}_detections.csv.gz", "wt") as f:
        f.write(text)
    return t, speed


def test_radarscenes_noise_estimate_recovers_known_sigmas(tmp_path):
    """Doppler-residual regression gives back sigma_vr and sigma_az of synthetic static detections (~10 %)."""
    _write_radarscenes(tmp_path, 2, _rng(5), n_scans=60, per_scan=150, sigma_vr=0.05, sigma_az=0.01)
    info = radarscenes.convert_radar(tmp_path, 2).report.info
    assert info["sigma_radial_velocity_mps"] == pytest.approx(0.05, rel=0.15)
    assert info["sigma_azimuth_rad"] == pytest.approx(0.01, rel=0.15)


def test_radarscenes_groundtruth_mounting_and_odom(tmp_path):
    """Pose moved from odometry to scan time (x = speed t exactly on a straight line); extrinsics; odom.csv."""
    t, speed = _write_radarscenes(tmp_path / "src", 3, _rng(6))
    assert _run(["convert", "radarscenes", str(tmp_path / "src"), "--out", str(tmp_path / "seq"),
                 "--radars", "3"]) == 0
    seq = read_sequence(tmp_path / "seq")
    np.testing.assert_allclose(seq.groundtruth.t, t, atol=1e-9)
    np.testing.assert_allclose(seq.groundtruth.T_world_vehicle[:, 0, 3], speed * t, atol=2e-9)
    x, y, yaw = radarscenes.MOUNTING[3]
    T = seq.sensor.T_vehicle_sensor
    np.testing.assert_allclose(T[:3, 3], [x, y, 0.0])
    np.testing.assert_allclose(T[:3, 0], [np.cos(yaw), np.sin(yaw), 0.0], atol=1e-12)
    assert seq.sensor.noise.elevation == pytest.approx(np.deg2rad(10))
    assert all(np.all(s.elevation == 0) for s in seq.scans)
    assert set(seq.scans[0].extra) == {"label", "rcs"}
    odom = radarscenes.read_odom_csv(tmp_path / "seq" / "odom.csv")
    np.testing.assert_array_equal(odom["t"], t)
    assert np.all(odom["vx"] == speed)


@given(st.sampled_from([1, 2, 3, 4]), st.floats(0, 40), st.floats(-0.5, 0.5))
def test_radarscenes_sensor_velocity_is_rigid_body_velocity(radar, speed, w):
    """v_sensor = C_vs^T (v + omega x r_vs) with v = (speed, 0, 0), omega = (0, 0, w) at the mounting."""
    T = radarscenes.T_vehicle_sensor(radar)
    v = np.array([speed, 0.0, 0.0]) + np.cross([0.0, 0.0, w], T[:3, 3])
    expect = T[:3, :3].T @ v
    got = radarscenes.sensor_velocity(radar, np.array([speed]), np.array([w]))[0]
    np.testing.assert_allclose(got, expect[:2], atol=1e-12)
    assert abs(expect[2]) < 1e-12


def test_radarscenes_bad_inputs(tmp_path, capsys):
    _write_radarscenes(tmp_path / "src", 2, _rng(7), n_scans=5, per_scan=30)
    out = str(tmp_path / "o")
    for radars, msg in (("5", "radar numbers must be in 1-4"), ("a", "expected radar numbers"),
                        ("2,2", "duplicate radar")):
        assert _run(["convert", "radarscenes", str(tmp_path / "src"), "--out", out, "--radars", radars]) == 2
        assert "--radars: " in (err := capsys.readouterr().err) and msg in err
    # radar 3 has no files
    with pytest.raises(InputError, match=r"radar3_timestamp_and_odom\.csv: file not found"):
        radarscenes.convert_radar(tmp_path / "src", 3)
    with pytest.raises(InputError, match="not a directory"):
        radarscenes.convert_radar(tmp_path / "nope", 2)
    det = tmp_path / "src" / "radar2_detections.csv.gz"
    lines = gzip.open(det, "rt").read().splitlines()
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "radar2_timestamp_and_odom.csv").write_text((tmp_path / "src" / "radar2_timestamp_and_odom.csv").read_text())

    def write_with(edits: dict[int, tuple[int, str]], header: str | None = None):
        """The detections file with field edits {line index: (column, value)} and an optional new header."""
        rows = [header or lines[0]]
        for i, line in enumerate(lines[1:], start=1):
            if i in edits:
                parts = line.split(",")
                parts[edits[i][0]] = edits[i][1]
                line = ",".join(parts)
            rows.append(line)
        with gzip.open(bad / "radar2_detections.csv.gz", "wt") as f:
            f.write("\n".join(rows) + "\n")

    write_with({}, header=lines[0].replace("vr_mps", "doppler"))
    with pytest.raises(InputError, match=r"line 1: missing column\(s\) vr_mps"):
        radarscenes.convert_radar(bad, 2)
    write_with({4: (2, "abc")})
    with pytest.raises(InputError, match=r"line 5, field 'azimuth_rad': not a number: 'abc'"):
        radarscenes.convert_radar(bad, 2)
    write_with({3: (0, "2.5")})
    with pytest.raises(InputError, match=r"line 4, field 'scan_idx': must be an integer, got '2.5'"):
        radarscenes.convert_radar(bad, 2)
    # NaN value, zero range and a scan_idx without odometry: dropped and counted
    write_with({2: (3, "nan"), 3: (1, "0.0"), 6: (0, "99")})
    assert _run(["convert", "radarscenes", str(bad), "--out", out, "--radars", "2"]) == 0
    dropped = json.loads((Path(out) / CONVERSION_JSON).read_text())["dropped"]
    assert dropped == {"detections with NaN or infinity": 1, "detections with range <= 0": 1,
                       "detections whose scan_idx has no row in the odometry file": 1}
    assert "dropped 1 detections with NaN or infinity" in capsys.readouterr().out


def test_radarscenes_several_radars_go_to_subdirectories(tmp_path):
    for r in (1, 4):
        _write_radarscenes(tmp_path / "src", r, _rng(10 + r), n_scans=5, per_scan=30)
    assert _run(["convert", "radarscenes", str(tmp_path / "src"), "--out", str(tmp_path / "o"),
                 "--radars", "4,1"]) == 0
    for r in (1, 4):
        seq = read_sequence(tmp_path / "o" / f"radar{r}")
        assert seq.sensor.T_vehicle_sensor[0, 3] == radarscenes.MOUNTING[r][0]
        assert (tmp_path / "o" / f"radar{r}" / "odom.csv").exists()


# ---------------------------------------------------------------- TI mmWave (synthetic export + real sample)

CALIB = """# calib
l_b_r_x: 0.03
l_b_r_y: 0.03
l_b_r_z: -0.06
q_b_r_x: 0.923218461092
q_b_r_y: 0.375992995522
q_b_r_z: -0.0267831268675
q_b_r_w: -0.0746967504749
radar_frame_ms: 18.5
"""


def _write_ti(folder: Path, rng, calib: str = CALIB, n_scans: int = 4):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / ti_mmwave.CALIB_YAML).write_text(calib)
    trig = 1631895354018503000 + np.arange(n_scans, dtype=np.int64) * 97_700_000
    (folder / ti_mmwave.SCANS_CSV).write_text(
        "scan_idx,t_trigger_ns,t_bag_ns,n_points\n" + "".join(f"{k},{t},{t + 5},9\n" for k, t in enumerate(trig)))
    rows = ["scan_idx,x_m,y_m,z_m,intensity,v_radial_mps,range_m,azimuth_rad,elevation_rad"]
    for k in range(n_scans):
        for _ in range(9):
            p = rng.uniform(-3, 3, 3) + [5, 0, 0]
            vr = 0.125 * rng.integers(-8, 8)
            rows.append(f"{k},{p[0]:.9g},{p[1]:.9g},{p[2]:.9g},10,{float(vr)!r},0,0,0")
    rows.append("0,0.0,0.0,0.0,10,0.0,0,0,0")  # zero range
    (folder / ti_mmwave.DETECTIONS_CSV).write_text("\n".join(rows) + "\n")
    return trig


def test_ti_times_extrinsics_and_quantisation(tmp_path):
    trig = _write_ti(tmp_path / "src", _rng(8))
    assert _run(["convert", "ti-mmwave", str(tmp_path / "src"), "--out", str(tmp_path / "seq")]) == 0
    seq = read_sequence(tmp_path / "seq")
    np.testing.assert_allclose([s.t for s in seq.scans], (trig - trig[0]) * 1e-9 + 0.00925, atol=1e-12)
    # the TI boresight (x_ti) is RIO's y_r axis: in the body frame it is C_b_r e_y
    from rodo.estimator.lie import so3
    C_b_r = so3.from_quaternion(np.array([0.923218461092, 0.375992995522, -0.0267831268675, -0.0746967504749]))
    T = seq.sensor.T_vehicle_sensor
    np.testing.assert_allclose(T[:3, 0], C_b_r[:, 1], atol=1e-9)
    np.testing.assert_allclose(T[:3, 1], -C_b_r[:, 0], atol=1e-9)
    np.testing.assert_allclose(T[:3, 3], [0.03, 0.03, -0.06])
    assert not (tmp_path / "seq" / "groundtruth.txt").exists()
    rep = json.loads((tmp_path / "seq" / CONVERSION_JSON).read_text())
    assert rep["dropped"] == {"detections at zero range": 1}
    assert rep["info"]["doppler_quantisation"]["step_mps"] == pytest.approx(0.125)
    assert rep["info"]["doppler_quantisation"]["fraction_on_grid"] == 1.0
    assert "snr" in seq.scans[0].extra


def test_ti_bad_calibration_and_missing_files(tmp_path):
    _write_ti(tmp_path / "a", _rng(9), calib=CALIB.replace("q_b_r_w: -0.0746967504749\n", ""))
    with pytest.raises(InputError, match=r"calib_ti_mmwave_rospkg_dataset\.yaml: missing key\(s\) q_b_r_w"):
        ti_mmwave.convert(tmp_path / "a")
    _write_ti(tmp_path / "b", _rng(9), calib=CALIB.replace("q_b_r_x: 0.923218461092", "q_b_r_x: 0.5"))
    with pytest.raises(InputError, match=r"line 5, field 'q_b_r': not a unit quaternion"):
        ti_mmwave.convert(tmp_path / "b")
    _write_ti(tmp_path / "c", _rng(9))
    (tmp_path / "c" / ti_mmwave.SCANS_CSV).unlink()
    with pytest.raises(InputError, match=r"radar_scans\.csv: file not found"):
        ti_mmwave.convert(tmp_path / "c")


def test_ti_real_demo_converts(realdata_dir, tmp_path):
    """The real demo: 412 scans, 17,872 detections, ~10.2 Hz, Doppler on a 0.12492 m/s grid (nominal 0.125)."""
    conv = ti_mmwave.convert(realdata_dir / "rio_ti_mmwave_demo")
    write_conversion(tmp_path, conv)
    seq = read_sequence(tmp_path, use_cache=False)
    assert len(seq.scans) == 412 and sum(len(s.range) for s in seq.scans) == 17872
    assert seq.sensor.rate_hz == pytest.approx(10.24, abs=0.05)
    q = conv.report.info["doppler_quantisation"]
    assert q["step_mps"] == pytest.approx(0.12492, abs=2e-5) and q["fraction_on_grid"] == 1.0
    assert q["distinct_values"] == 34
