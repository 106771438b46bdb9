"""The odometry end to end on hand-built scenes: noise-free accuracy, robustness (empty scans, time gaps,
clutter, hard braking, a co-moving object) and the road-vehicle roll and pitch rate terms (at rest and between
rest and motion: test_standstill.py). The window's own math is in test_window.py, the compiled association
against its reference in test_scan_association.py, several radars in test_multi_radar.py, which pairs and terms
each scan's solve uses in test_odometry_solve.py, where a run starts or starts again without a velocity in
test_odometry_starts.py."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.estimator.config import OdometryConfig
from rodo.estimator.lie import se3
from rodo.estimator.odometry import RadarOdometry
from tests.estimator import scene
from tests.estimator.strategies import cartesian_points
from tests.strategies import vectors


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
@pytest.mark.parametrize("pitch_acc, vehicle", [(0.02, "off"), (0.0, "default")])
def test_noise_free_scene_gives_near_exact_odometry(model, pitch_acc, vehicle):
    """Exact on any SE(3) motion (a pitch acceleration: the road-vehicle roll and pitch rate terms off), and with
    those terms on (the default) on a motion that has no roll or pitch rate: they pull towards the truth there."""
    rng = np.random.default_rng(0)
    t, T, varpi, vd = scene.trajectory(30, pitch_acc=pitch_acc)
    L = scene.landmarks(rng)
    cfg = OdometryConfig.from_dict({"model": model} | ({"vehicle": {"sigma_roll_rate": 0.0, "sigma_pitch_rate": 0.0}}
                                                       if vehicle == "off" else {}))
    odo = RadarOdometry(cfg, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    for k in range(len(t)):
        est = odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L))
    Tgt = T[-1] @ se3.inverse(T[0])  # the estimator's world is its first vehicle frame
    err = se3.log(est.T_vehicle_world @ se3.inverse(Tgt))
    path = np.linalg.norm(se3.inverse(T[-1])[:3, 3] - se3.inverse(T[0])[:3, 3])
    assert np.linalg.norm(err[:3]) < 1e-3 * path and np.linalg.norm(err[3:]) < 1e-4
    # CV cannot represent the trajectory's acceleration: its velocity lags by a few mm/s, CA is exact
    np.testing.assert_allclose(est.varpi, varpi[-1], atol=2e-3 if model.startswith("ca") else 1e-2)
    assert est.n_associated > 0.9 * est.n_static


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_survives_empty_scans_gaps_and_clutter(model):
    """Blockage (empty scans for 3 s), a 1 s time gap and a scan of pure clutter: finite, PD, and it recovers."""
    rng = np.random.default_rng(1)
    t, T, varpi, vd = scene.trajectory(110, accel=0.2, yaw_rate=0.02, yaw_acc=0.0, pitch_acc=0.0)
    L = scene.landmarks(rng)
    odo = RadarOdometry(OdometryConfig.for_model(model), scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    for k in range(len(t)):
        if 20 <= k < 59 or 70 <= k < 83:  # total blockage, then a gap with no scans at all
            if k >= 70:
                continue
            z = np.zeros((0, 4))
        elif k == 90:
            z = np.c_[rng.uniform(1, 100, 500), rng.uniform(-1, 1, 500), rng.uniform(-0.2, 0.2, 500),
                      rng.uniform(-30, 30, 500)]
        else:
            z = scene.measure(T[k], varpi[k], vd[k], L, rng)
        est = odo.process(t[k], z)
        assert np.all(np.isfinite(est.T_vehicle_world)) and np.all(np.isfinite(est.P))
        assert np.linalg.eigvalsh(est.P).min() > 0
    assert est.n_associated > 100  # recovered: associating again
    np.testing.assert_allclose(est.varpi, varpi[-1], atol=0.3)  # and tracking the velocity again
    # The pose error of the 4 s without data (about 45 m) is dead reckoning and stays; after the outage the
    # estimator re-initialises (velocity from Doppler, fresh window and map) instead of matching a stale map.
    Tgt = T[-1] @ se3.inverse(T[0])
    err = se3.log(est.T_vehicle_world @ se3.inverse(Tgt))
    path = np.sum(np.linalg.norm(np.diff(se3.inverse(T)[:, :3, 3], axis=0), axis=1))
    assert np.linalg.norm(err[:3]) < 0.08 * path and np.linalg.norm(err[3:]) < 0.15


def test_bad_input_is_rejected_with_a_clear_error():
    from rodo.estimator.errors import InputError

    odo = RadarOdometry(OdometryConfig(), scene.T_VEHICLE_SENSOR, scene.SIGMAS)
    odo.process(0.0, np.zeros((0, 4)))
    with pytest.raises(InputError, match="t: scan times must increase"):
        odo.process(0.0, np.zeros((0, 4)))
    with pytest.raises(InputError, match="polar"):
        odo.process(0.1, np.full((3, 4), np.nan))
    with pytest.raises(InputError, match="model"):
        OdometryConfig(model="ca-spherical")


def _two_segments(n1: int, n2: int, speed: float, brake: float, rate: float = 13.0):
    """Constant speed for n1 scans, then braking at `brake` m/s^2 (a step in acceleration: the jerk no prior
    expects) for n2 scans. Times, T_vehicle_world, varpi, varpi_dot."""
    from rodo.estimator.priors.exact import exact_predict

    t1, T1, w1, a1 = scene.trajectory(n1, rate, speed, 0.0, 0.0, 0.0, 0.0)
    vd = np.array([brake, 0, 0, 0, 0, 0])  # nu = -speed: braking makes nu_x grow towards 0
    t2 = np.arange(1, n2 + 1) / rate
    T2 = np.stack([exact_predict(T1[-1], w1[-1], vd, s)[0] for s in t2])
    w2 = w1[-1] + t2[:, None] * vd
    return (np.r_[t1, t1[-1] + t2], np.concatenate([T1, T2]), np.concatenate([w1, w2]),
            np.concatenate([a1, np.tile(vd, (n2, 1))]))


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_hard_braking_is_followed(model):
    """4 m/s^2 braking from 12 m/s, unannounced: the Doppler correction before association keeps the pairs
    (the radial velocity gate is a few cm/s, the prediction is off by 0.3 m/s at the first braking scan)."""
    rng = np.random.default_rng(5)
    t, T, varpi, vd = _two_segments(25, 30, 12.0, 4.0)
    L = scene.landmarks(rng)
    odo = RadarOdometry(OdometryConfig.for_model(model), scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    for k in range(len(t)):
        est = odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L, rng))
        if k >= 25:
            assert np.abs(est.varpi[:3] - varpi[k][:3]).max() < 0.05, k
            assert est.n_associated > 0.8 * est.n_detections, k
    Tgt = T[-1] @ se3.inverse(T[0])
    err = se3.log(est.T_vehicle_world @ se3.inverse(Tgt))
    assert np.linalg.norm(err[:3]) < 0.1 and np.linalg.norm(err[3:]) < 5e-3


@pytest.mark.parametrize("accel", [3.7, 3.85, -3.95])
def test_a_departure_from_rest_at_the_start_is_followed(accel):
    """Moving off at about 4 sigma of the initial acceleration (`solver.init_accel_sigma` 1 m/s^2) from the second
    scan of a drive. Without the start's acceleration jump (`standstill.sigma_accel_jump` 0) the predicted
    velocity's error and its sigma grow together, so its Doppler check stays just below its 99.9 % at every scan
    while the pairs' 95 % gates reject every pair; CA/P coasted at zero velocity (errors 0.3-2.4 m/s). The
    re-centring at the pairs' level (`RadarOdometry._recentre`) follows it from the first moving scan; without a
    departure it never fires. With the jump (the default) the prediction's own covariance holds the start and
    every scan is followed as well."""
    import dataclasses

    rng = np.random.default_rng(5)
    t, T, varpi, vd = _two_segments(1, 20, 0.0, accel)
    L = scene.landmarks(rng)
    default = OdometryConfig.for_model("ca-polar")
    no_jump = default.replace(standstill=dataclasses.replace(default.standstill, sigma_accel_jump=0.0))
    for config in (no_jump, default):
        odo = RadarOdometry(config, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
        recentred = []
        for k in range(len(t)):
            est = odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L, rng))
            recentred.append("doppler-recentred" in est.events)
            if k >= 1:
                assert np.abs(est.varpi[:3] - varpi[k][:3]).max() < 0.05, k
                assert est.n_associated > 0.8 * est.n_detections, k
        assert recentred[1] or config is default
    t, T, varpi, vd = _two_segments(20, 1, 0.0, 0.0)  # the same scene at rest
    odo = RadarOdometry(no_jump, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    for k in range(len(t)):
        assert "doppler-recentred" not in odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L, rng)).events


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_elevations_reported_as_zero_are_not_taken_as_measured(model):
    """A quarter of the detections come without an elevation estimate, reported as exactly 0 (as the LRR30-F
    does): taken as measured they tilt the estimate; `association.missing_elevation_zero` leaves them out."""
    t, T, varpi, vd = scene.trajectory(40)
    errors, counts = {}, {}
    for missing in (False, True):
        rng = np.random.default_rng(11)
        L = scene.landmarks(rng)
        config = OdometryConfig.from_dict({"model": model, "association": {"missing_elevation_zero": missing}})
        odo = RadarOdometry(config, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
        n = 0
        for k in range(len(t)):
            z = scene.measure(T[k], varpi[k], vd[k], L, rng)
            z[rng.random(len(z)) < 0.25, 2] = 0.0
            est = odo.process(t[k], z)
            n += est.n_detections
        err = se3.log(est.T_vehicle_world @ se3.inverse(T[-1] @ se3.inverse(T[0])))
        errors[missing], counts[missing] = np.linalg.norm(err[3:]) + np.linalg.norm(err[:3]) / 10.0, n
    assert counts[True] < 0.8 * counts[False]
    assert errors[True] < 0.5 * errors[False], errors


def test_locked_onto_a_co_moving_object_the_world_is_taken_back():
    """The first 2 s see only a truck moving with the vehicle (Doppler 0: the estimate says standstill); then
    the world comes into view, spread over far more space than the truck: after consensus_switch_after (1 s)
    the estimator re-initialises on it and tracks the true 10 m/s. Without the switch it stays at rest."""
    rng = np.random.default_rng(11)
    t, T, varpi, vd = scene.trajectory(65, speed=10.0, accel=0.0, yaw_rate=0.0, yaw_acc=0.0, pitch_acc=0.0)
    L = scene.landmarks(rng, n=1500, extent=400.0)
    truck = np.c_[rng.uniform(4, 8, 150), rng.uniform(-1.2, 1.2, 150), rng.uniform(-0.5, 1.5, 150)]
    r = np.linalg.norm(truck, axis=1)
    truck_polar = np.c_[r, np.arctan2(truck[:, 1], truck[:, 0]), np.arcsin(truck[:, 2] / r), np.zeros(150)]
    for after, expect_speed in ((1.0, 10.0), (0.0, 0.0)):
        cfg = OdometryConfig.from_dict({"model": "ca-polar", "association": {"consensus_switch_after": after}})
        odo = RadarOdometry(cfg, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
        events = []
        for k in range(len(t)):
            world = scene.measure(T[k], varpi[k], vd[k], L, rng) if k >= 26 else np.zeros((0, 4))
            est = odo.process(t[k], np.r_[truck_polar + rng.normal(size=truck_polar.shape) * scene.SIGMAS, world])
            events += est.events
        assert est.varpi[0] == pytest.approx(-expect_speed, abs=0.1), (after, events)
        assert ("doppler-consensus-switch" in events) == (after > 0)


def test_an_oncoming_car_filling_the_view_is_not_taken():
    """For 6 scans an oncoming car (-8 m/s, 300 detections 6-10 m ahead) hides all but 4 of the world's
    detections: with a confident prediction those few stay the static set (event doppler-few-static) and the
    prior carries the scans (velocity error at most 0.054 m/s). The free RANSAC fit that decided before took
    the car: 8 m/s off at the second scan (stop_and_go, one trial of 20: 2.9 m/s, NEES/dof 604 over it)."""
    rng = np.random.default_rng(13)
    t, T, varpi, vd = scene.trajectory(40, speed=10.0, accel=0.0, yaw_rate=0.0, yaw_acc=0.0, pitch_acc=0.0)
    L = scene.landmarks(rng)
    car = np.c_[rng.uniform(6, 10, 300), rng.uniform(-1.5, 1.5, 300), rng.uniform(-0.5, 1.0, 300)]  # sensor frame
    r = np.linalg.norm(car, axis=1)
    v_rel = np.array([-8.0, 0.0, 0.0]) - se3.inverse(scene.T_VEHICLE_SENSOR)[:3, :3] @ -varpi[0][:3]
    car_polar = np.c_[r, np.arctan2(car[:, 1], car[:, 0]), np.arcsin(car[:, 2] / r), car @ v_rel / r]
    odo = RadarOdometry(OdometryConfig.for_model("ca-polar"), scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    events = []
    for k in range(len(t)):
        world = scene.measure(T[k], varpi[k], vd[k], L, rng)
        scan = np.r_[car_polar + rng.normal(size=car_polar.shape) * scene.SIGMAS, world[:4]] \
            if 26 <= k < 32 else world
        est = odo.process(t[k], scan)
        events += est.events
        assert np.abs(est.varpi[:3] - varpi[k][:3]).max() < 0.1, (k, est.events)
    assert "doppler-few-static" in events and "doppler-ransac-fallback" not in events


def test_a_compact_object_outnumbering_the_world_is_not_taken():
    """A co-moving truck with four times the world's detections (the lead truck on `highway`): the world
    covers more space, so the estimate stays on it, no consensus switch, 10 m/s tracked throughout."""
    rng = np.random.default_rng(12)
    t, T, varpi, vd = scene.trajectory(40, speed=10.0, accel=0.0, yaw_rate=0.0, yaw_acc=0.0, pitch_acc=0.0)
    L = scene.landmarks(rng, n=250, extent=400.0)
    n_truck = 4 * len(scene.measure(T[0], varpi[0], vd[0], L))
    truck = np.c_[rng.uniform(15, 19, n_truck), rng.uniform(-1.3, 1.3, n_truck), rng.uniform(-0.5, 3.0, n_truck)]
    r = np.linalg.norm(truck, axis=1)
    truck_polar = np.c_[r, np.arctan2(truck[:, 1], truck[:, 0]), np.arcsin(truck[:, 2] / r), np.zeros(n_truck)]
    odo = RadarOdometry(OdometryConfig.for_model("ca-polar"), scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    events = []
    for k in range(len(t)):
        world = scene.measure(T[k], varpi[k], vd[k], L, rng)
        est = odo.process(t[k], np.r_[truck_polar + rng.normal(size=truck_polar.shape) * scene.SIGMAS, world])
        events += est.events
        assert est.varpi[0] == pytest.approx(-10.0, abs=0.1), (k, events)
    assert "doppler-consensus-switch" not in events
    # the starting fit picks the world's detections (rows after the truck's), not the truck's
    scan = np.r_[truck_polar, scene.measure(T[0], varpi[0], vd[0], L, rng)]
    ego = odo.doppler.widest_consensus(scan)
    assert ego.inliers.shape == (len(scan),) and not ego.inliers[:n_truck].any()
    assert ego.inliers[n_truck:].mean() > 0.9


@given(unit=cartesian_points(0, 80, 1.0), voxel=st.floats(0.3, 5.0), extent=st.floats(1.0, 500.0))
@settings(max_examples=30)
def test_support_counts_the_occupied_voxels(unit, voxel, extent):
    """The space a consensus covers (`consensus.support`) = the number of distinct voxel rows, also for
    negative coordinates and points on voxel faces."""
    from rodo.estimator.consensus import support as _support

    n = len(unit)
    p = unit * extent
    p[: n // 4] = np.round(p[: n // 4] / voxel) * voxel  # exactly on faces
    want = len(np.unique(np.floor(p / voxel).astype(np.int64), axis=0)) if n else 0
    assert _support(p, voxel) == want


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_vehicle_rate_terms_hold_roll_and_pitch(model):
    """20 s of level driving past noisy landmarks: without the zero-mean roll and pitch rate terms the rates
    are free as long as they stay constant (the motion prior penalises changes only) and the attitude drifts by
    tenths of a radian; with them (the default) it stays within 0.02 rad. Measured, seed 0: CA/P 0.0014 vs
    0.37 rad, CV/C 0.0065 vs 0.27 rad (seeds 1-3: with the terms 0.005-0.029, without 0.08-0.34)."""
    out = {}
    for vehicle in ("default", "off"):
        rng = np.random.default_rng(0)
        t, T, varpi, vd = scene.trajectory(260, accel=0.0, yaw_rate=0.05, yaw_acc=0.0, pitch_acc=0.0)
        L = scene.landmarks(rng, extent=400.0)
        off = {"vehicle": {"sigma_roll_rate": 0.0, "sigma_pitch_rate": 0.0}} if vehicle == "off" else {}
        odo = RadarOdometry(OdometryConfig.from_dict({"model": model} | off), scene.T_VEHICLE_SENSOR,
                            scene.SIGMAS, 120.0)
        for k in range(len(t)):
            est = odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L, rng))
        out[vehicle] = np.abs(se3.log(est.T_vehicle_world @ se3.inverse(T[-1] @ se3.inverse(T[0])))[3:5]).max()
    assert out["default"] < 0.02 and out["off"] > 10 * out["default"]


@given(varpi=vectors(6, 5.0), xi=vectors(6, 2.0))
def test_sensor_velocity_jacobian_matches_finite_differences(varpi, xi):
    """v_s = -C_vs^T (nu + omega x r_vs) is linear in varpi: J_v_varpi by central differences, and
    `body_velocity` inverts it for the given omega."""
    from rodo.estimator.doppler import body_velocity, sensor_velocity

    T_vehicle_sensor = se3.exp(xi)
    v, J = sensor_velocity(varpi, T_vehicle_sensor)
    h = 1e-6
    J_fd = np.stack([(sensor_velocity(varpi + h * e, T_vehicle_sensor)[0]
                      - sensor_velocity(varpi - h * e, T_vehicle_sensor)[0]) / (2 * h) for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(J, J_fd, atol=1e-8)
    np.testing.assert_allclose(J @ varpi, v, atol=1e-12)
    np.testing.assert_allclose(body_velocity(v, varpi[3:], T_vehicle_sensor), varpi[:3], atol=1e-9)


def test_non_holonomic_terms_hold_the_lateral_and_vertical_velocity():
    """The scene's vehicle does not slip (nu = [-speed, 0, 0]): with `vehicle.sigma_lateral_velocity` and
    `sigma_vertical_velocity` the estimated y and z velocities stay near 0; off (the default), one radar's
    Doppler leaves the lateral velocity and the yaw rate free to trade against each other through the lever arm.
    Measured, seed 1: RMS y, z velocity error 0.0044 m/s with the terms, 0.019 without."""
    out = {}
    for case, sigma in (("on", 0.02), ("off", 0.0)):
        rng = np.random.default_rng(1)
        t, T, varpi, vd = scene.trajectory(130, accel=0.3, yaw_rate=0.05, yaw_acc=0.0, pitch_acc=0.0)
        L = scene.landmarks(rng, extent=250.0)
        cfg = OdometryConfig.from_dict({"model": "ca-polar", "vehicle": {"sigma_lateral_velocity": sigma,
                                                                         "sigma_vertical_velocity": sigma}})
        odo = RadarOdometry(cfg, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
        lateral = [odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L, rng)).varpi[1:3]
                   for k in range(len(t))]
        out[case] = float(np.sqrt(np.mean(np.square(lateral[20:]))))
    assert out["on"] < 0.5 * out["off"]


def test_a_blocked_view_is_not_recentred(monkeypatch):
    """A truck filling the view (blockage, seed 3411976877185804603 of the campaign seeds `--seed 7`): the pairs
    are lost and the few static detections' Doppler fit contradicts the prediction, but re-centred on that fit
    the prediction pairs far less than a quarter of the scan, so it stays: the run is the one without
    re-centring, bit for bit. Without the recovery test (a recovery of 0 accepted) it re-centres. (Before
    session 25's re-association the drive left the truck with fewer pairs, and a 5 % recovery re-centred.)"""
    from rodo import scenarios
    from rodo.estimator import odometry
    from rodo.validation.driver import run_sequence

    seq, _ = scenarios.get("blockage").simulate(3411976877185804603, 30.0)

    def run():
        out = run_sequence(seq, OdometryConfig.for_model("ca-polar")).estimates
        return np.stack([e.T_vehicle_world for e in out]), [e for est in out for e in est.events]

    T, events = run()
    assert "doppler-recentred" not in events
    monkeypatch.setattr(odometry, "LOST_PAIRS", 0.0)
    np.testing.assert_array_equal(run()[0], T)
    monkeypatch.setattr(odometry, "LOST_PAIRS", 0.1)
    monkeypatch.setattr(odometry, "RECOVERED_PAIRS", 0.0)
    assert "doppler-recentred" in run()[1]
