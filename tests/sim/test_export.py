"""Point-cloud export (sim/export.py, `rodo export`): .ply read back with open3d, KITTI .bin with numpy, the
map placed by a `rodo run` estimate, and the bad-input paths."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rodo import cli, scenarios
from rodo.commands import export as export_cmd
from rodo.commands import run as run_cmd
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.sim.export import export_ply, ply_bytes
from rodo.sim.sequence import Trajectory, read_sequence, read_tum, write_sequence, write_tum

o3d = pytest.importorskip("open3d", reason="reading .ply back needs open3d")


def _rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed))


def _run(argv) -> int:
    return cli.main([str(a) for a in argv], commands=[export_cmd, run_cmd])


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    """A 0.5 s city sequence with ground truth, plus an extra column `snr` (seeded values)."""
    d = tmp_path_factory.mktemp("seq")
    scenarios.simulate_to("city", 0, d, duration=0.5)
    seq = read_sequence(d, use_cache=False)
    rng = _rng(7)
    seq.scans = [dataclasses.replace(s, extra={**s.extra, "snr": rng.uniform(5, 30, len(s))}) for s in seq.scans]
    write_sequence(d, seq)
    return d


def _read_ply(path):
    pcd = o3d.t.io.read_point_cloud(str(path))
    return pcd.point.positions.numpy(), {k: pcd.point[k].numpy().ravel() for k in
                                         ("radial_velocity", "scan_time", "scan", "range", "snr")}


def test_ply_scans_read_back_with_open3d(seq_dir, tmp_path):
    """One file per scan; open3d reads the sensor-frame points bit-exactly (doubles) and the Doppler, time,
    scan index and extra columns as properties; the legacy reader sees the same points."""
    seq = read_sequence(seq_dir)
    assert _run(["export", "ply", seq_dir, "--out", tmp_path]) == 0
    files = sorted((tmp_path / "scans").glob("*.ply"))
    assert [f.stem for f in files] == [f"{s.scan:06d}" for s in seq.scans]
    assert files[0].read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    for k in (0, len(seq.scans) // 2, len(seq.scans) - 1):
        scan = seq.scans[k]
        xyz, props = _read_ply(files[k])
        np.testing.assert_array_equal(xyz, scan.points_sensor)
        np.testing.assert_array_equal(props["radial_velocity"], scan.radial_velocity)
        np.testing.assert_array_equal(props["range"], scan.range)
        np.testing.assert_array_equal(props["snr"], scan.extra["snr"])
        assert np.all(props["scan_time"] == scan.t) and np.all(props["scan"] == scan.scan)
        np.testing.assert_array_equal(np.asarray(o3d.io.read_point_cloud(str(files[k])).points), xyz)
    assert not (tmp_path / "map.ply").exists()  # no --run, no map


def test_ply_map_is_the_scans_in_the_world_frame(seq_dir, tmp_path):
    """`rodo run` then `export ply --run`: map.ply holds every detection at T_world_vehicle(t_k) T_vehicle_sensor
    p_sensor with the estimated poses, so its distance to the sensor's estimated position is the range."""
    seq = read_sequence(seq_dir)
    assert _run(["run", seq_dir, "--out", tmp_path / "run"]) == 0
    assert _run(["export", "ply", seq_dir, "--out", tmp_path / "exp", "--run", tmp_path / "run"]) == 0
    est = read_tum(tmp_path / "run" / "estimate.txt")
    xyz, props = _read_ply(tmp_path / "exp" / "map.ply")
    assert len(xyz) == sum(len(s) for s in seq.scans)
    for scan in (seq.scans[1], seq.scans[-1]):
        rows = props["scan"] == scan.scan
        T_world_sensor = est.T_world_vehicle[np.argmin(np.abs(est.t - scan.t))] @ seq.sensor.T_vehicle_sensor
        np.testing.assert_allclose(xyz[rows], se3.transform_points(T_world_sensor, scan.points_sensor),
                                   rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(xyz[rows] - T_world_sensor[:3, 3], axis=1), scan.range,
                                   rtol=1e-12, atol=1e-9)
        np.testing.assert_array_equal(props["radial_velocity"][rows], scan.radial_velocity)


def test_kitti_bin_times_and_poses(seq_dir, tmp_path):
    """velodyne/<k>.bin is float32 N x 4 (x, y, z, intensity = snr by default or the Doppler on request),
    times.txt the scan times, poses/00.txt the ground-truth sensor poses in the first sensor frame (identity
    first, T_0_k = T_world_sensor_0^-1 T_world_sensor_k)."""
    seq = read_sequence(seq_dir)
    assert _run(["export", "kitti-bin", seq_dir, "--out", tmp_path]) == 0
    root = tmp_path / "sequences" / "00"
    bins = sorted((root / "velodyne").glob("*.bin"))
    assert [b.name for b in bins] == [f"{k:06d}.bin" for k in range(len(seq.scans))]
    for k in (0, len(seq.scans) - 1):
        data = np.fromfile(bins[k], dtype="<f4").reshape(-1, 4)
        np.testing.assert_array_equal(data[:, :3], seq.scans[k].points_sensor.astype(np.float32))
        np.testing.assert_array_equal(data[:, 3], seq.scans[k].extra["snr"].astype(np.float32))
    np.testing.assert_allclose(np.loadtxt(root / "times.txt"), [s.t for s in seq.scans], rtol=1e-9, atol=1e-12)
    assert (root / "calib.txt").read_text() == "Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n"
    poses = np.loadtxt(tmp_path / "poses" / "00.txt").reshape(-1, 3, 4)
    gt = seq.groundtruth
    T_ws = np.stack([gt.T_world_vehicle[np.argmin(np.abs(gt.t - s.t))] for s in seq.scans]) @ seq.sensor.T_vehicle_sensor
    np.testing.assert_allclose(poses[0], np.eye(4)[:3], atol=1e-12)
    np.testing.assert_allclose(poses, (se3.inverse(T_ws[0]) @ T_ws)[:, :3], atol=1e-10)
    assert _run(["export", "kitti-bin", seq_dir, "--out", tmp_path / "dop", "--intensity", "radial_velocity"]) == 0
    data = np.fromfile(tmp_path / "dop" / "sequences" / "00" / "velodyne" / "000001.bin", dtype="<f4")
    np.testing.assert_array_equal(data.reshape(-1, 4)[:, 3], seq.scans[1].radial_velocity.astype(np.float32))


def test_kitti_without_groundtruth_at_every_scan_writes_no_poses(seq_dir, tmp_path, capsys):
    seq = read_sequence(seq_dir)
    d = tmp_path / "seq"
    keep = slice(0, len(seq.groundtruth) // 2)
    seq.groundtruth = Trajectory(seq.groundtruth.t[keep], seq.groundtruth.T_world_vehicle[keep])
    write_sequence(d, seq)
    assert _run(["export", "kitti-bin", d, "--out", tmp_path / "out"]) == 0
    assert "no poses/00.txt" in capsys.readouterr().out
    assert not (tmp_path / "out" / "poses").exists()


def test_an_export_over_an_earlier_one_leaves_only_its_own_drive(seq_dir, tmp_path, capsys):
    """Exporting a shorter drive into the directory of a longer one's export leaves that drive's files only: its
    scans (no tail of the other's), and no poses or map of the other drive where it has none."""
    seq = read_sequence(seq_dir)
    short = tmp_path / "short"
    seq.scans = seq.scans[:3]
    late = seq.groundtruth.t > seq.scans[1].t  # ground truth at the first two scans only: no poses to export
    seq.groundtruth = Trajectory(seq.groundtruth.t[~late], seq.groundtruth.T_world_vehicle[~late])
    write_sequence(short, seq)
    est = tmp_path / "run"
    assert _run(["run", seq_dir, "--out", est]) == 0
    out = tmp_path / "out"
    assert _run(["export", "kitti-bin", seq_dir, "--out", out]) == 0
    assert _run(["export", "ply", seq_dir, "--out", out, "--run", est]) == 0
    mine = out / "sequences" / "00" / "velodyne" / "notes.bin"
    mine.write_bytes(b"x")  # not an export's name: kept
    assert _run(["export", "kitti-bin", short, "--out", out]) == 0
    assert _run(["export", "ply", short, "--out", out]) == 0
    capsys.readouterr()
    velodyne = sorted(p.name for p in (out / "sequences" / "00" / "velodyne").iterdir())
    assert velodyne == ["000000.bin", "000001.bin", "000002.bin", "notes.bin"]
    assert len(np.loadtxt(out / "sequences" / "00" / "times.txt")) == 3
    assert not (out / "poses" / "00.txt").exists() and not (out / "map.ply").exists()
    assert sorted(p.name for p in (out / "scans").iterdir()) == [f"{s.scan:06d}.ply" for s in seq.scans]


def test_export_bad_inputs(seq_dir, tmp_path, capsys):
    """Missing sequence, missing or short estimate, an option of the other format, an unknown intensity
    column, an --out that is a file: exit 2 with one line naming the file, option or scan."""
    seq = read_sequence(seq_dir)
    est = tmp_path / "short.txt"
    write_tum(est, Trajectory(seq.groundtruth.t[:2], seq.groundtruth.T_world_vehicle[:2]))
    a_file = tmp_path / "a_file"
    a_file.write_text("x\n")
    cases = [
        (["ply", tmp_path / "nope", "--out", tmp_path / "o"], ["nope", "not a sequence directory"]),
        (["ply", seq_dir, "--out", tmp_path / "o", "--run", tmp_path / "norun"], ["--run:", "estimate.txt"]),
        (["ply", seq_dir, "--out", tmp_path / "o", "--run", est], ["short.txt: no pose at the time of scan 2"]),
        (["kitti-bin", seq_dir, "--out", tmp_path / "o", "--run", est], ["--run: only for the ply format"]),
        (["ply", seq_dir, "--out", tmp_path / "o", "--intensity", "snr"], ["--intensity: only for the kitti-bin"]),
        (["kitti-bin", seq_dir, "--out", tmp_path / "o", "--intensity", "rcs"],
         ["--intensity: no column 'rcs'", "snr"]),
        (["ply", seq_dir, "--out", a_file], ["a_file", "cannot create the directory"]),
    ]
    for args, needles in cases:
        assert _run(["export", *args]) == 2, args
        err = capsys.readouterr().err
        assert err.startswith("rodo export: error: ") and err.count("\n") == 1, err
        for needle in needles:
            assert needle in err, (needle, err)
    with pytest.raises(InputError, match="PLY property 'c'"):
        ply_bytes({"x": np.zeros(2), "c": np.zeros(2, dtype=complex)})
    with pytest.raises(InputError, match="no scans"):
        export_ply(dataclasses.replace(seq, scans=[]), tmp_path / "e")


def test_kitti_bin_refuses_an_intensity_that_is_not_finite(seq_dir, tmp_path, capsys):
    """NaN is allowed in a sequence's extra columns, but KITTI's .bin readers take intensities as numbers: the
    column is refused, naming its first such row and the others to choose, before anything is written (review
    55: NaN was written without a word)."""
    seq = read_sequence(seq_dir, use_cache=False)
    scans = list(seq.scans)
    snr = scans[2].extra["snr"].copy()
    snr[[4, 7]] = [np.nan, np.inf]
    scans[2] = dataclasses.replace(scans[2], extra={**scans[2].extra, "snr": snr})
    bad = tmp_path / "bad"
    write_sequence(bad, dataclasses.replace(seq, scans=scans))
    out = tmp_path / "o"
    assert _run(["export", "kitti-bin", bad, "--out", out]) == 2  # snr is the default intensity
    err = capsys.readouterr().err
    assert f"--intensity: column 'snr' is nan in scan {scans[2].scan} (t = {scans[2].t} s), row 4" in err, err
    assert "choose another column with --intensity (radial_velocity)" in err and not out.exists()
    assert _run(["export", "kitti-bin", bad, "--out", out, "--intensity", "radial_velocity"]) == 0
    assert len(list((out / "sequences" / "00" / "velodyne").glob("*.bin"))) == len(scans)
