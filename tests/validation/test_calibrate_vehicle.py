"""validation/calibrate_vehicle.py: the road-vehicle terms on the roll and pitch rates from the true motion."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.estimator.config import OdometryConfig
from rodo.validation import calibrate as cal
from rodo.validation.calibrate_vehicle import RATE_FLOOR, fit_vehicle_rates


def _track(rng, n, speed, roll_sigma, pitch_sigma):
    """A StateTrack whose body velocity moves forward at `speed` (m/s, each scan; varpi's sign as T_vehicle_world's)
    with Gaussian roll and pitch rates of these sigmas."""
    varpi = np.zeros((n, 6))
    varpi[:, 0] = -np.asarray(speed, dtype=float)
    varpi[:, 3] = rng.normal(0.0, roll_sigma, n)
    varpi[:, 4] = rng.normal(0.0, pitch_sigma, n)
    return cal.StateTrack(0.1 * np.arange(n), np.tile(np.eye(4), (n, 1, 1)), varpi, np.zeros((n, 6)))


@settings(max_examples=20, deadline=None)
@given(roll=st.floats(2e-3, 0.05), pitch=st.floats(2e-3, 0.05), seed=st.integers(0, 2**32 - 1))
def test_the_sigmas_are_the_true_rates_rms_over_the_moving_scans(roll, pitch, seed):
    """Two drives pooled, each standing for its first 200 scans with rates ten times larger (the term does not
    apply at a standstill, so they are left out): the report's RMS is the moving scans' (within 10 % of the drawn
    sigmas over 4000 scans: its relative standard error is 1.1 %), the sigmas sqrt(window) times it (the window's
    states each carry the term), and the report says how many scans."""
    rng = np.random.default_rng(np.random.SeedSequence([50, seed]))
    speed = np.r_[np.zeros(200), np.full(2000, 8.0)]
    tracks = [_track(rng, 2200, speed, roll, pitch) for _ in range(2)]
    for k in tracks:
        k.varpi[:200, 3:5] *= 10.0
    config, report = fit_vehicle_rates(tracks, OdometryConfig.for_model("ca-polar"))
    moving = np.concatenate([k.varpi[200:, 3:5] for k in tracks])
    np.testing.assert_allclose(report["rms"], np.sqrt(np.mean(moving**2, axis=0)), rtol=1e-12)
    assert report["moving_scans"] == 4000
    got = (config.vehicle.sigma_roll_rate, config.vehicle.sigma_pitch_rate)
    np.testing.assert_allclose(report["rms"], [roll, pitch], rtol=0.1)
    np.testing.assert_allclose(got, np.sqrt(config.window) * np.asarray(report["rms"]), rtol=1e-12)
    assert list(got) == report["sigma"] and report["before"] == [0.01, 0.015]


def test_a_drive_that_never_rolls_gets_the_floor_and_a_term_that_is_off_stays_off():
    """No roll rate at all: the floor, not 0 (which would switch the term off); a base config with the pitch term
    off (0) keeps it off whatever the truth; a drive that never moves keeps the config's."""
    rng = np.random.default_rng(np.random.SeedSequence([50, 1]))
    track = _track(rng, 500, np.full(500, 10.0), 0.0, 0.01)
    base = OdometryConfig.for_model("cv-cartesian")
    base = base.replace(vehicle=type(base.vehicle)(sigma_roll_rate=0.01, sigma_pitch_rate=0.0))
    config, report = fit_vehicle_rates([track], base)
    assert config.vehicle.sigma_roll_rate == RATE_FLOOR and report["rms"][0] == 0.0
    assert config.vehicle.sigma_pitch_rate == 0.0
    standing = _track(rng, 100, np.zeros(100), 0.01, 0.01)
    kept, report = fit_vehicle_rates([standing], base)
    assert kept.vehicle == base.vehicle and report["moving_scans"] == 0


def test_the_config_keeps_its_other_vehicle_terms():
    """The lateral and vertical velocity terms are not the rates' fit's."""
    rng = np.random.default_rng(np.random.SeedSequence([50, 2]))
    base = OdometryConfig.for_model("ca-polar")
    base = base.replace(vehicle=type(base.vehicle)(sigma_lateral_velocity=0.02, sigma_vertical_velocity=0.03))
    config, _ = fit_vehicle_rates([_track(rng, 300, np.full(300, 5.0), 0.004, 0.006)], base)
    assert (config.vehicle.sigma_lateral_velocity, config.vehicle.sigma_vertical_velocity) == (0.02, 0.03)
    assert config.vehicle.sigma_roll_rate == pytest.approx(0.004 * np.sqrt(config.window), rel=0.2)
