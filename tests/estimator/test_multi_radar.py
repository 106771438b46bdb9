"""Several radars in one estimator (`RadarOdometry.add_sensor`): each scan through its own radar's extrinsics into
one window and one map, a map that keeps its time span as radars are added, almost simultaneous scans, and the
common Doppler error that several radars' Doppler disagreeing exposes (`noise.doppler_common_sigma`)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.estimator.config import OdometryConfig
from rodo.estimator.doppler import common_doppler_error
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3, so3
from rodo.estimator.odometry import RadarOdometry
from rodo.estimator.priors.exact import exact_predict
from tests.estimator import scene


REAR = se3.from_rotation_translation(so3.exp(np.array([0.0, 0.01, np.pi - 0.05])), np.array([-1.0, -0.3, 0.5]))


def test_each_radar_added_keeps_the_map_as_long_in_time():
    """Every radar's scan ages the map by one: with N radars the map keeps N x capacity points for N x max_age
    scans, the time span and density one radar has."""
    config = OdometryConfig.from_dict({"model": "ca-polar", "map": {"capacity": 700, "max_age": 12}})
    odo = RadarOdometry(config, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    assert (odo.map.capacity, odo.map.max_age) == (700, 12)
    for n in (2, 3):
        odo.add_sensor(scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
        assert (odo.map.capacity, odo.map.max_age) == (700 * n, 12 * n)


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_two_radars_in_one_window(model):
    """A front and a rear-facing radar (`add_sensor`), noise-free, their scans alternating at 26 Hz once the
    start-up transient is over (scan 12: the rear radar's map is then placed as exactly as the front's; a radar
    joining during the transient maps the world with the transient's error, inconsistent with the other's map by
    a centimetre, which washes out over seconds): every rear scan is associated through its own extrinsics and
    the estimate is as exact as with one radar. The control, the rear scans given as the front radar's, loses
    the pose: the extrinsics of each scan are what is used."""
    rng = np.random.default_rng(4)
    t, T, varpi, vd = scene.trajectory(60, rate=26.0, pitch_acc=0.0)
    L = np.r_[scene.landmarks(rng), scene.landmarks(rng) * [-1, 1, 1]]  # landmarks ahead and behind
    cfg = OdometryConfig.for_model(model)
    errors, rear_associated = {}, {}
    for case in ("two radars", "control"):
        odo = RadarOdometry(cfg, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
        assert odo.add_sensor(REAR, scene.SIGMAS, 120.0) == 1
        ratios = []
        for k in range(len(t)):
            rear = k % 2 == 1
            if rear and k < 12:
                continue
            z = scene.measure(T[k], varpi[k], vd[k], L, T_vehicle_sensor=REAR if rear else scene.T_VEHICLE_SENSOR)
            est = odo.process(t[k], z, 1 if rear and case == "two radars" else 0)
            if rear and k > 14:  # from the second rear scan on: the first saw no map behind the vehicle
                ratios.append(est.n_associated / len(z))
        err = se3.log(est.T_vehicle_world @ se3.inverse(T[-1] @ se3.inverse(T[0])))
        errors[case], rear_associated[case] = np.linalg.norm(err[:3]), (min(ratios), float(np.median(ratios)))
    path = np.linalg.norm(se3.inverse(T[-1])[:3, 3] - se3.inverse(T[0])[:3, 3])
    # measured: 7e-6 (CA/P) and 1.3e-4 (CV/C) of the path
    assert errors["two radars"] < 1e-3 * path
    assert rear_associated["two radars"][0] > 0.9
    # with the front radar's extrinsics the rear scans match far fewer map points (median measured: 0 for
    # CA/P; 0.56 for CV/C, whose Cartesian gates are wide; 0.97-0.99 with their own)
    assert rear_associated["control"][1] < rear_associated["two radars"][0] - 0.3
    odo = RadarOdometry(cfg, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    for bad in (1, -1, True, 0.0):
        with pytest.raises(InputError, match="sensor"):
            odo.process(0.0, np.zeros((0, 4)), bad)


LEFT = se3.from_rotation_translation(so3.exp(np.array([0.0, 0.0, 0.6])), np.array([3.4, 0.7, 0.5]))


def _rig_error(min_prior_dt: float, delta: float, n: int = 60) -> float:
    """Rotation error (rad) after n noise-free scans of the front radar, a left radar (from scan 12) scanning
    delta s after each front scan, CA/P."""
    rng = np.random.default_rng(3)
    t, T, varpi, vd = scene.trajectory(n, rate=13.0, pitch_acc=0.0)
    L = scene.landmarks(rng, n=900)
    cfg = OdometryConfig.from_dict({"model": "ca-polar", "noise": {"min_prior_dt": min_prior_dt}})
    odo = RadarOdometry(cfg, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    odo.add_sensor(LEFT, scene.SIGMAS, 120.0)
    for k in range(n):
        est = odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L), 0)
        if k >= 12:
            Tk, vk, _ = exact_predict(T[k], varpi[k], vd[k], delta)
            est = odo.process(t[k] + delta, scene.measure(Tk, vk, vd[k], L, T_vehicle_sensor=LEFT), 1)
    T_end = exact_predict(T[-1], varpi[-1], vd[-1], delta)[0]
    return float(np.linalg.norm(se3.log(est.T_vehicle_world @ se3.inverse(T_end @ se3.inverse(T[0])))[3:]))


def test_almost_simultaneous_scans_of_two_radars():
    """Two radars' scans 0.06 ms apart (as on RadarScenes): the CA prior's Q_k ~ dt^5 between them would carry
    an information of ~1e22 that swamps the normal equations in double precision; with `noise.min_prior_dt`
    (default 10 ms) the prior between them gets the noise of 10 ms and the estimate is as exact as with the
    scans 30 ms apart. The control, min_prior_dt = 0, loses the rotation (measured: 1.4e-6 rad with it, 1.6e-6 at
    30 ms, 2.6e-4 without it)."""
    with_floor = _rig_error(0.01, 6e-5)
    apart = _rig_error(0.01, 0.03)
    assert with_floor < 2 * apart < 1e-5
    assert _rig_error(0.0, 6e-5) > 20 * with_floor


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 40), sigma_c=st.floats(1e-3, 1.0), planar=st.booleans(), seed=st.integers(0, 2**32 - 1))
def test_common_doppler_error_inflates_the_radial_velocity(n, sigma_c, planar, seed):
    """`common_doppler_error` is (W^-1 + c e3 e3^T)^-1 with c = sigma_c^2 lambda_max(sum u u^T) (Sherman-Morrison
    checked against the inverse of the inflated covariance)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, 4, 4))
    cov = A @ A.transpose(0, 2, 1) + 0.1 * np.eye(4)
    az, el = rng.uniform(-1.2, 1.2, n), np.zeros(n) if planar else rng.uniform(-0.3, 0.3, n)
    u = np.c_[np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]
    c = sigma_c**2 * np.linalg.eigvalsh(u.T @ u)[-1]
    want = np.linalg.inv(cov + c * np.diag([0.0, 0.0, 0.0, 1.0]))
    got = common_doppler_error(np.linalg.inv(cov), az, el, sigma_c)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9 * np.abs(want).max())


def test_common_doppler_error_bounds_what_a_scan_says_about_the_velocity():
    """However many detections, a scan's radial velocities (independent sigma_vr each) claim the sensor velocity
    along no axis better than the common error sigma_c allows: the information sum_i w_i u_i u_i^T stays below
    1 / sigma_c^2 and approaches it along the best observed axis as n grows (the control: without the term it
    grows as n / sigma_vr^2); for a 4D and a 2D radar."""
    rng = np.random.default_rng(0)
    sigma_vr, sigma_c = 0.1, 0.05
    for el_max in (0.2, 0.0):
        for n in (10, 100, 10000):
            az, el = rng.uniform(-1, 1, n), rng.uniform(-el_max, el_max, n)
            u = np.c_[np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]
            W = np.zeros((n, 4, 4))
            W[:, 3, 3] = sigma_vr**-2
            w = common_doppler_error(W, az, el, sigma_c)[:, 3, 3]
            info = np.linalg.eigvalsh((u * w[:, None]).T @ u)
            assert info.max() < 1.0 / sigma_c**2
            assert np.linalg.eigvalsh(u.T @ u / sigma_vr**2).max() > n / 2 / sigma_vr**2
        assert info.max() > 0.95 / sigma_c**2  # n = 10000: along its best axis all the common error allows


def test_the_doppler_check_counts_the_common_error():
    """The Doppler fit that checks the prediction carries sigma_c^2 more variance per axis (the same scan's
    common error); the default (0) leaves it as the least-squares fit's own."""
    rng = np.random.default_rng(5)
    z = scene.measure(np.eye(4), np.array([-10.0, 0, 0, 0, 0, -0.1]), np.zeros(6), scene.landmarks(rng), rng)
    fits = [RadarOdometry(OdometryConfig.from_dict({"noise": {"doppler_common_sigma": s}}), scene.T_VEHICLE_SENSOR,
                          scene.SIGMAS, 120.0).sensor.doppler.fit(z) for s in (0.0, 0.05)]
    np.testing.assert_array_equal(fits[0].v, fits[1].v)
    np.testing.assert_allclose(fits[1].cov - fits[0].cov, 0.05**2 * np.eye(3), atol=1e-15)
