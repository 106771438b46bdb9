"""One set of value rules for a radar's description and detections, whichever way they come in: a sequence's
files, an in-memory SensorConfig, or `RadarOdometry`'s Python arguments. Before session 55 the Python API ran none
of them: azimuths in degrees gave an estimate 2.5 m off (ATE) without a word."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator.config import OdometryConfig
from rodo.estimator.errors import InputError
from rodo.estimator.odometry import RadarOdometry
from rodo.estimator.sensor_values import check_polar_bounds
from rodo.sim.sequence import NoiseSigmas, SensorConfig
from tests.estimator import scene

CONFIG = OdometryConfig.for_model("ca-polar")
FOV = ((-1.0, 1.0), (-0.2, 0.2))


def _odometry(**changes):
    args = dict(T_vehicle_sensor=scene.T_VEHICLE_SENSOR, sensor_sigmas=scene.SIGMAS, max_range=120.0, fov=FOV)
    args.update(changes)
    return RadarOdometry(CONFIG, args["T_vehicle_sensor"], args["sensor_sigmas"], args["max_range"], fov=args["fov"])


def _scan(n=40, seed=0):
    t, T, varpi, vd = scene.trajectory(2)
    return scene.measure(T[0], varpi[0], vd[0], scene.landmarks(np.random.default_rng(seed)))[:n]


@pytest.mark.parametrize("column, unit, needle", [
    (1, np.rad2deg, r"polar\[\d+, 1\] \(azimuth\): value .* outside \[-3.14159265, 3.14159265\]; looks like degrees"),
    (2, np.rad2deg, r"polar\[\d+, 2\] \(elevation\): value .* outside \[-1.57079633, 1.57079633\]; looks like degrees"),
    (0, np.negative, r"polar\[0, 0\] \(range\): negative value"),
])
def test_a_scan_in_other_units_is_refused_naming_its_column(column, unit, needle):
    polar = _scan()
    polar[:, column] = unit(polar[:, column])
    polar[np.abs(polar[:, column]) < 1e-3, column] = -5.0  # every row, even those near 0, is out of bounds
    with pytest.raises(InputError, match=needle):
        _odometry().process(0.0, polar)


def test_an_azimuth_in_0_to_2pi_is_refused_with_its_own_hint():
    polar = _scan()
    polar[:, 1] = np.mod(polar[:, 1], 2 * np.pi)
    with pytest.raises(InputError, match=r"\(azimuth\): .*a \[0, 2pi\) convention"):
        _odometry().process(0.0, polar)


@given(st.lists(st.tuples(st.floats(0.0, 300.0), st.floats(-np.pi, np.pi), st.floats(-np.pi / 2, np.pi / 2),
                          st.floats(-50.0, 50.0)), max_size=20),
       st.integers(0, 19), st.sampled_from([(0, -1e-9), (1, np.pi + 1e-9), (1, -4.0), (2, np.pi / 2 + 1e-9)]))
def test_check_polar_bounds_accepts_every_value_in_bounds_and_names_the_first_row_out(rows, at, bad):
    polar = np.array(rows, dtype=float).reshape(-1, 4)
    check_polar_bounds("polar", polar)  # the bounds themselves are in
    if len(polar) == 0:
        return
    at = at % len(polar)
    col, value = bad
    polar[at:, col] = value  # every row from `at` on is out: the message names `at`
    with pytest.raises(InputError, match=rf"^polar\[{at}, {col}\] "):
        check_polar_bounds("polar", polar)


def _rigid_but_scaled():
    T = scene.T_VEHICLE_SENSOR.copy()
    T[:3, :3] *= 1.01
    return T


def _reflected():
    T = scene.T_VEHICLE_SENSOR.copy()
    T[:3, 1] *= -1.0
    return T


def _mounted_in_mm():
    T = scene.T_VEHICLE_SENSOR.copy()
    T[:3, 3] *= 1000.0
    return T


# (the argument changed, its bad value, the message, and the same mistake in a SensorConfig's arguments)
CASES = [
    ("T_vehicle_sensor", _rigid_but_scaled(), r"T_vehicle_sensor: rotation block is not a proper rotation",
     lambda: dict(T_vehicle_sensor=_rigid_but_scaled())),
    ("T_vehicle_sensor", _reflected(), r"T_vehicle_sensor: .* proper rotation \(determinant -1: a reflection\)",
     lambda: dict(T_vehicle_sensor=_reflected())),
    ("T_vehicle_sensor", _mounted_in_mm(), r"T_vehicle_sensor\[:3, 3\]: .* millimetres\? it is in metres",
     lambda: dict(T_vehicle_sensor=_mounted_in_mm())),
    ("sensor_sigmas", np.r_[0.02, 5.0, 0.005, 0.01], r"sensor_sigmas\[1\] \(azimuth\): 5.0 rad is implausibly large",
     lambda: dict(noise=NoiseSigmas(0.02, 5.0, 0.005, 0.01))),
    ("sensor_sigmas", np.r_[0.02, 0.003, 2.0, 0.01], r"sensor_sigmas\[2\] \(elevation\): 2.0 rad is implausibly",
     lambda: dict(noise=NoiseSigmas(0.02, 0.003, 2.0, 0.01))),
    ("sensor_sigmas", np.r_[0.02, 0.003, 0.005, 72.0], r"sensor_sigmas\[3\] \(radial_velocity\): .* km/h\?",
     lambda: dict(noise=NoiseSigmas(0.02, 0.003, 0.005, 72.0))),
    ("sensor_sigmas", np.r_[0.02, 0.0, 0.005, 0.01], r"sensor_sigmas\[1\] \(azimuth\): 1-sigma must be > 0",
     lambda: dict(noise=NoiseSigmas(0.02, 0.0, 0.005, 0.01))),
    ("fov", ((-60.0, 60.0), (-10.0, 10.0)), r"fov\[0\] \(azimuth\): .* \(looks like degrees",
     lambda: dict(azimuth_fov=(-60.0, 60.0))),
    ("fov", ((0.5, -0.5), (-0.2, 0.2)), r"fov\[0\] \(azimuth\): need -3.14159 <= min < max",
     lambda: dict(azimuth_fov=(0.5, -0.5))),
    ("max_range", 0.01, r"max_range: must be > 0 and above the range sigma", lambda: dict(max_range=0.01)),
]


@pytest.mark.parametrize("argument, value, needle, sensor_config", CASES, ids=[c[2][:30] for c in CASES])
def test_the_sensor_arguments_meet_the_rules_of_sensor_toml(argument, value, needle, sensor_config):
    """The Python API refuses what a SensorConfig (and so sensor.toml) refuses, naming its own argument."""
    with pytest.raises(InputError, match=needle):
        _odometry(**{argument: value})
    odo = _odometry()
    with pytest.raises(InputError, match=needle):
        odo.add_sensor(**dict(T_vehicle_sensor=scene.T_VEHICLE_SENSOR, sensor_sigmas=scene.SIGMAS) | {argument: value})
    good = dict(rate_hz=13.0, T_vehicle_sensor=scene.T_VEHICLE_SENSOR, noise=NoiseSigmas(*scene.SIGMAS),
                azimuth_fov=FOV[0], elevation_fov=FOV[1], max_range=120.0)
    SensorConfig(**good)
    with pytest.raises(InputError, match="^(SensorConfig|NoiseSigmas)"):
        SensorConfig(**good | sensor_config())


def test_good_arguments_are_kept_as_given():
    odo = _odometry()
    np.testing.assert_array_equal(odo.T_vehicle_sensor, scene.T_VEHICLE_SENSOR)
    assert odo.max_range == 120.0 and isinstance(odo.max_range, float)
    np.testing.assert_array_equal(odo.associator.fov, np.asarray(FOV))
    assert _odometry(fov=None).associator.fov is None
    est = odo.process(0.0, _scan())
    assert np.isfinite(est.T_vehicle_world).all()
