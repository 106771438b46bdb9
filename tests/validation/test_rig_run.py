"""`run_rig` and `rodo run RIG_DIR`: every radar of a rig in one estimator, scan by scan in time order."""

from __future__ import annotations

import re

import numpy as np
import pytest
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


@pytest.mark.slow
def test_radarscenes_front_radars_fused_with_the_common_doppler_error(realdata_dir, tmp_path, capsys):
    """Radars 2 and 3 of RadarScenes over the whole drive (3,224 scans, some of the two radars' 0.06 ms apart)
    in one CA/P estimator, with the common Doppler error measured on the drive (`noise.doppler_common_sigma`
    0.05 m/s): it runs to the end (before `noise.min_prior_dt` it diverged 9 s in), stays planar, and beats
    either radar alone (measured: fused 1.58 %, radar 2 alone 2.21 %, radar 3 alone 2.73 %;
    docs/estimator.md, "Several radars")."""
    from rodo.cli import main

    src = realdata_dir / "radarscenes_seq105_2d"
    assert main(["convert", "radarscenes", str(src), "--out", str(tmp_path / "rig"), "--radars", "2,3"]) == 0
    (tmp_path / "c.toml").write_text("[noise]\ndoppler_common_sigma = 0.05\n")
    capsys.readouterr()
    assert main(["run", str(tmp_path / "rig"), "--model", "ca-polar", "--config", str(tmp_path / "c.toml"),
                 "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    t_err = float(re.search(r"KITTI t_err ([0-9.]+) %", out).group(1))
    assert t_err < 2.0
    est = np.loadtxt(tmp_path / "out" / "estimate.txt")
    assert np.all(np.isfinite(est)) and np.max(np.abs(est[:, 3])) == 0.0  # z: a 2D rig stays in its plane
