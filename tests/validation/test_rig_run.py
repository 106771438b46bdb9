"""`run_rig` and `rodo run RIG_DIR`: every radar of a rig in one estimator, scan by scan in time order."""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_limits

from rodo.estimator.config import OdometryConfig
from rodo.estimator.odometry import RadarOdometry
from rodo.sim.rig import Rig, read_rig, write_rig
from rodo.sim.sequence import NoiseSigmas, RadarScan, SensorConfig, Sequence
from rodo.validation.driver import run_rig
from tests.estimator import scene
from tests.estimator.test_multi_radar import REAR

FOV = ((-np.deg2rad(60), np.deg2rad(60)), (-np.deg2rad(15), np.deg2rad(15)))


def _rig() -> Rig:
    """The estimator tests' front radar and a rear radar, scans alternating at 26 Hz (noise-free)."""
    rng = np.random.default_rng(4)
    t, T, varpi, vd = scene.trajectory(30, rate=26.0, pitch_acc=0.0)
    L = np.r_[scene.landmarks(rng), scene.landmarks(rng) * [-1, 1, 1]]
    seqs = []
    for first, mount in ((0, scene.T_VEHICLE_SENSOR), (1, REAR)):
        scans = []
        for k in range(first, len(t), 2):
            z = scene.measure(T[k], varpi[k], vd[k], L, T_vehicle_sensor=mount)
            scans.append(RadarScan(k, float(t[k]), *z.T))
        sensor = SensorConfig(13.0, mount, NoiseSigmas(*scene.SIGMAS), FOV[0], FOV[1], 120.0)
        seqs.append(Sequence(sensor, scans))
    return Rig(["front", "rear"], seqs)


def test_run_rig_is_the_estimator_with_one_sensor_per_radar(tmp_path):
    """run_rig on a rig written and read back gives, bit for bit, what RadarOdometry with add_sensor gives
    fed the same scans by hand."""
    rig = _rig()
    write_rig(tmp_path, rig)
    cfg = OdometryConfig.for_model("ca-polar")
    back = read_rig(tmp_path, use_cache=False)
    result = run_rig(back, cfg)
    front, rear = (s.sensor for s in back.sequences)  # as read back (sensor.toml keeps a quaternion)
    odo = RadarOdometry(cfg, front.T_vehicle_sensor, front.noise.as_array(), 120.0, fov=FOV)
    odo.add_sensor(rear.T_vehicle_sensor, rear.noise.as_array(), 120.0, fov=FOV)
    with threadpool_limits(limits=1, user_api="blas"):  # as the driver runs
        poses = [odo.process(t, scan.polar, i).T_vehicle_world for t, i, scan in sorted(
            ((s.t, i, s) for i, seq in enumerate(back.sequences) for s in seq.scans), key=lambda x: x[0])]
    assert result.n_scans == 30
    np.testing.assert_array_equal(result.columns["T_vehicle_world"], np.stack(poses))


def test_rodo_run_fuses_a_radarscenes_rig(realdata_dir, tmp_path, capsys):
    """`rodo convert radarscenes --radars 2,3` writes a rig; `rodo run` on it takes both radars' scans and
    reports the KITTI drift against their merged ground truth; the recording flags are refused for a rig."""
    from rodo.cli import main

    src = realdata_dir / "radarscenes_seq105_2d"
    assert main(["convert", "radarscenes", str(src), "--out", str(tmp_path / "rig"), "--radars", "2,3",
                 "--t-max", "8"]) == 0
    rig = read_rig(tmp_path / "rig")
    n = sum(len(s.scans) for s in rig.sequences)
    assert main(["run", str(tmp_path / "rig"), "--model", "cv-cartesian", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert '"radars": ["radar2", "radar3"]' in out and f'"scans": {n}' in out and "ATE rmse" in out
    assert main(["run", str(tmp_path / "rig"), "--out", str(tmp_path / "o2"), "--rerun", str(tmp_path / "x.rrd")]) == 2
    assert "not available for a rig" in capsys.readouterr().err
