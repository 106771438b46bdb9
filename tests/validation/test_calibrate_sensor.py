"""`validation.calibrate_sensor`: the measurement noise learned from the static detections against the
simulator's truth (per channel, range dependence, the Cartesian sigma, the scans' common Doppler error) and what
`calibrate_with_truth` writes of it into the config."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.estimator.radar_geometry import polar_to_cartesian
from rodo.sim.faults import parse_faults
from rodo.validation import calibrate_sensor as cs
from rodo.validation.calibrate_config import calibrate_with_truth


@pytest.fixture(scope="module")
def city():
    return scenarios.get("city").simulate(1, duration=3.0)


def test_measurement_noise_recovered_on_city(city):
    seq, truth = city
    res, r = cs.detection_residuals(seq, truth)
    channels = cs.channel_noise(res, r)
    sensor = seq.sensor.noise.as_array()
    for name, sigma in zip(cs.CHANNELS, sensor):
        assert channels[name]["sigma"] == pytest.approx(sigma, rel=0.10)  # measured: within 0.5 %
        assert not channels[name]["range_dependent"]
    assert cs.sigma_scale(res, sensor) == pytest.approx(1.0, rel=0.10)
    assert cs.sigma_scale(res, 2 * sensor) == pytest.approx(0.5, rel=0.10)


def test_calibrate_with_truth_sets_the_noise(city):
    seq, truth = city
    config, report = calibrate_with_truth(seq, truth, OdometryConfig.for_model("cv-polar"), duration=2.0)
    assert config.model == "cv-polar"
    assert config.noise.qc_ca == tuple(report["qc_ca"]["qc"]) and config.noise.qc_cv == tuple(report["qc_cv"]["qc"])
    assert config.noise.sensor_sigma_scale == 1.0
    np.testing.assert_allclose(config.noise.sensor_sigma_scales, 1.0, rtol=0.10)  # sensor.toml is the truth
    assert report["scans"] == int(np.sum(truth["t"] <= truth["t"][0] + 2.0))


def test_cartesian_sigma_is_the_ml_isotropic_sigma(city):
    """The learned Cartesian sigma equals the RMS of the detections' true Cartesian position errors per axis
    (computed directly from radar.csv and the truth's noise-free polar), within 2 %."""
    seq, truth = city
    measured = np.concatenate([s.polar for s in seq.scans])
    true = np.asarray(truth["det_true_polar"])
    static = np.isin(np.asarray(truth["det_label"]), cs.STATIC_LABELS)
    d = polar_to_cartesian(measured[static]) - polar_to_cartesian(true[static])
    want = np.sqrt(np.mean(d**2))
    res, r = cs.detection_residuals(seq, truth)
    assert cs.cartesian_sigma(res, r) == pytest.approx(want, rel=0.02)
    assert cs.cartesian_sigma(2 * res, r) == pytest.approx(2 * want, rel=0.02)


@settings(max_examples=10)
@given(a=st.floats(0.005, 0.05), b=st.floats(0.0, 1e-3), seed=st.integers(0, 2**32 - 1))
def test_range_dependence_is_detected(a, b, seed):
    """sigma(r) = a + b r on 20 000 detections in 1-100 m: the line is recovered, and a dependence is reported
    exactly when b (r_max - r_min) is well above the noise of the fit."""
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    r = rng.uniform(1, 100, 20000)
    res = rng.standard_normal((20000, 4)) * (a + b * r)[:, None]
    line = cs.channel_noise(res, r)["range"]
    assert line["line"]["b_per_m"] == pytest.approx(b, abs=5 * line["line"]["b_stderr"])
    if b * 99 > 0.3 * a:
        assert line["range_dependent"]
    if b == 0:
        assert not line["range_dependent"] or abs(line["line"]["b_per_m"]) > 4 * line["line"]["b_stderr"]


def test_common_doppler_error_of_a_drive_with_planar_scans():
    """A 3D radar's drive in which two scans have every detection in the sensor plane (elevation 0): those scans'
    fits have 2 axes, the others 3, and every one counts (it raised a ValueError from deep inside numpy); with
    the common error injected it is still recovered."""
    for faults, expected in (([], 0.0), (["doppler_common=0.02:0.5"], 0.02)):
        seq, truth = scenarios.get("city").simulate(1, duration=4.0, faults=parse_faults(faults))
        true, offsets, scans = truth["det_true_polar"].copy(), truth["scan_offsets"], list(seq.scans)
        for k in (3, 10):
            true[offsets[k]:offsets[k + 1], 2] = 0.0
            scans[k] = dataclasses.replace(scans[k], elevation=np.zeros_like(scans[k].elevation))
        got = cs.common_doppler_error(dataclasses.replace(seq, scans=scans), dict(truth, det_true_polar=true))
        assert got["scans"] == len(scans) and len(got["lag1"]) == 3
        assert got["sigma_c"] == pytest.approx(expected, rel=0.25, abs=1e-12), got


def test_common_doppler_error_recovered_from_truth():
    """`calibrate_sensor.common_doppler_error` on 8 s of city: 0 (not significant) on the clean simulation; with
    the `doppler_common` fault it recovers SIGMA (measured: 0.0186 for 0.02, rho 0.5; 0.0459 for 0.05, rho 0.9,
    whose correlated errors give fewer independent scans) and the detections' own radial-velocity sigma, and
    `calibrate_with_truth` writes both into the config."""
    clean = scenarios.get("city").simulate(1, duration=8.0)
    faulted = scenarios.get("city").simulate(1, duration=8.0, faults=parse_faults(["doppler_common=0.02:0.5"]))
    sigma_vr = clean[0].sensor.noise.as_array()[3]
    got = cs.common_doppler_error(*clean)
    assert got["sigma_c"] == 0.0 and not got["significant"]
    got = cs.common_doppler_error(*faulted)
    assert got["significant"] and got["sigma_c"] == pytest.approx(0.02, rel=0.15)
    assert got["sigma_vr_independent"] == pytest.approx(sigma_vr, rel=0.05)
    assert np.mean(got["lag1"]) == pytest.approx(0.5, abs=0.2)
    config, report = calibrate_with_truth(*faulted, OdometryConfig.for_model("ca-polar"), consistency=False)
    assert config.noise.doppler_common_sigma == report["measurement"]["doppler_common"]["sigma_c"] == got["sigma_c"]
    assert config.noise.sensor_sigma_scales[3] == pytest.approx(1.0, rel=0.05)  # the common part taken out
