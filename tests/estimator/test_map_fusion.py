"""Map-point fusion (map.fuse) end to end on the hand-built scene: persistent landmarks seen with the paper's
sensor noise, so a map point observed again really is the same point and fusing must bring it closer to it."""

import numpy as np

from rodo.estimator.config import OdometryConfig
from rodo.estimator.odometry import RadarOdometry
from tests.estimator import scene


def _run(fuse: bool, seed: int = 2, n_scans: int = 50):
    rng = np.random.default_rng(seed)
    t, T, varpi, vd = scene.trajectory(n_scans, accel=0.3, yaw_rate=0.05, yaw_acc=0.0, pitch_acc=0.0)
    L = scene.landmarks(rng)
    cfg = OdometryConfig.from_dict({"model": "ca-polar", "map": {"fuse": fuse}})
    odo = RadarOdometry(cfg, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    for k in range(len(t)):
        est = odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L, rng))
    # the estimator's world is its first vehicle frame, the trajectory starts at the identity
    seen = odo.map.hits >= 10
    p = odo.map.points[seen]
    err = np.min(np.linalg.norm(p[:, None] - L[None], axis=2), axis=1)
    return est, err, odo.map.covariances[seen]


def test_fused_map_points_approach_the_landmarks():
    est0, err0, cov0 = _run(False)
    est1, err1, cov1 = _run(True)
    assert len(err0) > 50 and len(err1) > 50
    # a map point seen 10+ times averages its detections: closer to its landmark than a single detection
    assert np.median(err1) < 0.6 * np.median(err0)
    # and its covariance says so (vertical variance, the elevation noise, shrinks the most)
    assert np.median(cov1[:, 2, 2]) < 0.3 * np.median(cov0[:, 2, 2])
    assert est1.n_associated > 0.8 * est1.n_static


def test_fuse_options_are_checked():
    import pytest

    from rodo.estimator.errors import InputError
    assert OdometryConfig().map.fuse is False                                  # off by default
    assert OdometryConfig.from_dict({"map": {"fuse": True, "max_fused": 0}}).map.max_fused == 0
    with pytest.raises(InputError, match="fuse"):
        OdometryConfig.from_dict({"map": {"fuse": 1}})
    with pytest.raises(InputError, match="max_fused"):
        OdometryConfig.from_dict({"map": {"max_fused": 1}})
    cfg = OdometryConfig.from_dict({"map": {"fuse": True}})
    assert OdometryConfig.from_dict(cfg.to_dict()) == cfg
