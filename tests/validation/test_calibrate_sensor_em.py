"""The measurement noise without ground truth (validation/calibrate_sensor_em.py): the pair model's Jacobians
against finite differences, the fits against Monte Carlo draws of their own models, and `rodo calibrate
--no-truth --sensor-noise`'s pipeline recovering the simulator's sigmas (and the observed Qc components) on a
sequence of persistent point scatterers."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.estimator.lie import se3
from rodo.estimator.radar_geometry import cartesian_to_polar_jacobian, polar_to_cartesian
from rodo.sim.sequence import read_sequence
from rodo.sim.simulate import load_truth
from rodo.validation import calibrate_sensor_em as em
from rodo.validation.calibrate import COMPONENTS
from rodo.validation.calibrate_config import calibrate_without_truth

T_VS = se3.from_rotation_translation(se3.exp(np.array([0, 0, 0, 0.01, -0.02, 0.03]))[:3, :3], np.array([3.5, 0, 0.5]))


def _rng(*key):
    return np.random.default_rng(np.random.SeedSequence([20261205, *key]))


def _polar(rng, n, r=(5.0, 80.0)):
    return np.stack([rng.uniform(*r, n), rng.uniform(-1.0, 1.0, n), rng.uniform(-0.2, 0.2, n), np.zeros(n)], axis=1)


def _polar_of(p):
    s, _ = cartesian_to_polar_jacobian(p)
    return np.column_stack([s, np.zeros(len(p))])


motions = st.tuples(st.floats(-3.0, 3.0), st.floats(-0.3, 0.3), st.floats(-0.1, 0.1),
                    st.floats(-0.02, 0.02), st.floats(-0.02, 0.02), st.floats(-0.1, 0.1))


@given(motion=motions, seed=st.integers(0, 2**16))
def test_pair_jacobian_matches_finite_differences(motion, seed):
    """G = d s(M p(z_{k-1})) / d z_{k-1} of each pair, against central differences of that map."""
    rng = _rng(1, seed)
    T_rel = se3.exp(np.array(motion))
    prev = _polar(rng, 40)
    M = se3.inverse(T_VS) @ T_rel @ T_VS
    cur = _polar_of(polar_to_cartesian(prev) @ M[:3, :3].T + M[:3, 3])  # the same scatterers, noise-free

    def image(z):
        return cartesian_to_polar_jacobian(polar_to_cartesian(z) @ M[:3, :3].T + M[:3, 3])[0]

    d, G, pose, r = em.pair_terms(prev, cur, T_rel, T_VS, None)
    assert len(d) >= 30 and np.allclose(d, 0.0, atol=1e-9) and np.all(pose == 0.0)
    ip = np.flatnonzero(np.isin(cur[:, 0], r))  # cur[i] is prev[i]'s image; the pairs come in that order
    h = np.array([1e-6, 1e-7, 1e-7])
    fd = np.stack([(image(prev[ip] + np.eye(4)[j] * h[j]) - image(prev[ip] - np.eye(4)[j] * h[j])) / (2 * h[j])
                   for j in range(3)], axis=2)
    np.testing.assert_allclose(G, fd, rtol=1e-5, atol=1e-6)  # G is O(1); central differences at h ~ 1e-7


@given(seed=st.integers(0, 2**16))
def test_pose_jacobian_matches_finite_differences(seed):
    """d s / d delta for a left perturbation of the relative vehicle pose, against central differences."""
    p = polar_to_cartesian(_polar(_rng(2, seed), 20))

    def s_of(delta):
        return cartesian_to_polar_jacobian(se3.transform_points(se3.inverse(T_VS) @ se3.exp(delta) @ T_VS, p))[0]

    h = 1e-7
    fd = np.stack([(s_of(h * e) - s_of(-h * e)) / (2 * h) for e in np.eye(6)], axis=2)
    np.testing.assert_allclose(em.pose_jacobian(p, T_VS), fd, rtol=1e-5, atol=1e-6)


def test_only_isolated_mutual_neighbours_are_paired():
    """A scatterer seen 3 cm off with a second return 5 cm away on the other side (nearer than twice the first)
    is left out; the isolated ones are paired."""
    prev = np.array([[20.0, 0.0, 0.0, 0], [40.0, 0.5, 0.0, 0], [30.0, -0.5, 0.05, 0]])
    cur = np.vstack([prev + [[0.03, 0, 0, 0], [0.03, 0, 0, 0], [0.03, 0, 0, 0]], [[19.95, 0.0, 0.0, 0]]])
    d, G, pose, r = em.pair_terms(prev, cur, np.eye(4), T_VS, None)
    assert sorted(r.tolist()) == [30.03, 40.03]
    cur[3, 0] = 19.9  # 10 cm away: more than twice the 3 cm
    assert sorted(em.pair_terms(prev, cur, np.eye(4), T_VS, None)[3].tolist()) == [20.03, 30.03, 40.03]


@given(sig=st.tuples(st.floats(0.01, 0.3), st.floats(5e-4, 0.02), st.floats(5e-4, 0.03)), seed=st.integers(0, 999))
def test_position_sigmas_recover_the_variances_of_their_model(sig, seed):
    """Pairs drawn from the model d = n_k - G n_{k-1} - J delta (G near the identity: the angles scaled by the
    ratio of ranges, each channel taking 5 % of the others' noise in units of their sigmas, as a rigid motion of a
    few metres does; a known pose term) plus 1 % gross outliers: the fitted sigmas within 5 %."""
    rng = _rng(3, seed)
    m = 20000
    s = np.array(sig) ** 2
    G = np.eye(3)[None] + 0.05 * rng.standard_normal((m, 3, 3)) * np.sqrt(s)[:, None] / np.sqrt(s)[None, :]
    G[:, 1, 1] = G[:, 2, 2] = rng.uniform(0.8, 1.2, m)
    pose = np.abs(rng.normal(0, 0.2, (m, 3))) * s  # up to about half the noise
    d = rng.standard_normal((m, 3)) * np.sqrt(s) - np.einsum("mab,mb->ma", G, rng.standard_normal((m, 3)) * np.sqrt(s))
    d += rng.standard_normal((m, 3)) * np.sqrt(pose)
    bad = rng.random(m) < 0.01
    d[bad] += rng.uniform(-30, 30, (bad.sum(), 3)) * np.sqrt(s)
    fit = em.position_sigmas(d, G, pose, 4 * s * rng.uniform(0.3, 3.0, 3), planar=False)
    np.testing.assert_allclose(np.sqrt(fit["variances"]), sig, rtol=0.05)
    assert 0.97 * m < fit["pairs"] < 0.995 * m


@given(sigma_vr=st.floats(0.01, 0.2), angles=st.floats(0.0, 1.0), speed=st.floats(0.0, 15.0),
       seed=st.integers(0, 999))
def test_doppler_sigma_recovers_the_radial_velocity_noise_under_angle_noise(sigma_vr, angles, speed, seed):
    """Static detections of a moving sensor (30 scans of 150), radial velocities from the true directions plus
    sigma_vr, the reported angles noisy (angles x 2.6 and 5.2 mrad: their share of the residual grows with the
    speed, up to four times sigma_vr here), 5 % movers: sigma_vr within 15 % (the spread over draws is 1 % without
    angle noise, 3.5 % at the share's top, the largest of 30 draws there 8.5 %; docs/calibration.md gives it at
    highway speed)."""
    rng = _rng(4, seed)
    s_ang = angles * np.array([2.6e-3, 5.2e-3])
    scans = []
    for _ in range(30):
        n = 150
        true = _polar(rng, n)
        v = np.array([speed, rng.normal(0, 0.5), rng.normal(0, 0.2)])
        ce = np.cos(true[:, 2])
        u = np.stack([ce * np.cos(true[:, 1]), ce * np.sin(true[:, 1]), np.sin(true[:, 2])], axis=1)
        meas = true.copy()
        meas[:, 3] = -u @ v + sigma_vr * rng.standard_normal(n)
        meas[:, 1:3] += s_ang * rng.standard_normal((n, 2))
        movers = rng.random(n) < 0.05
        meas[movers, 3] += rng.choice([-1, 1], movers.sum()) * rng.uniform(1.0, 5.0, movers.sum())
        scans.append(meas)
    fit = em.doppler_sigma(scans, planar=False, angle_variances=s_ang**2)
    assert fit["sigma"] == pytest.approx(sigma_vr, rel=0.15)
    assert fit["scans"] == 30


@pytest.fixture(scope="module")
def point_drive(tmp_path_factory):
    """20 s of persistent point scatterers with the CA prior's motion at a known Qc (x and yaw excited)."""
    d = tmp_path_factory.mktemp("em") / "pts"
    scenarios.simulate_to("prior_ca_points", 11, d, duration=20.0, qc=[5e-3, 1e-6, 5e-7, 2e-11, 2e-11, 1e-4])
    return d


@pytest.mark.slow
def test_calibrate_without_truth_recovers_the_sensor_noise_and_the_observed_qc(point_drive):
    """From a base config whose sigmas are 2x / 0.5x off (and the road-vehicle terms off: this motion rolls and
    pitches): the four sigmas within 10 % of the simulator's, the Cartesian sigma within 10 % of the one ground
    truth gives, and the jerk PSD of the components the drive determines (x, yaw: a Cramer-Rao bound of 0.35 or
    less on SD(log q)) within 2.5 bounds of the simulator's, x within 25 %. y, z, roll and pitch are left out: the
    estimator's own velocity error is larger than their motion (docs/calibration.md, "What a drive can tell")."""
    from rodo.validation import calibrate_sensor as cs

    seq, truth = read_sequence(point_drive), load_truth(point_drive)
    base = OdometryConfig.for_model("ca-polar")
    base = base.replace(vehicle=dataclasses.replace(base.vehicle, sigma_roll_rate=0.0, sigma_pitch_rate=0.0),
                        noise=dataclasses.replace(base.noise, sensor_sigma_scales=(2.0, 0.5, 2.0, 0.5)))
    config, report = calibrate_without_truth(seq, base, iterations=20, tolerance=0.01, sensor_noise=True)
    np.testing.assert_allclose(config.noise.sensor_sigma_scales, 1.0, rtol=0.10)  # sensor.toml is the truth
    res, r = cs.detection_residuals(seq, truth)
    assert config.noise.cartesian_sigma == pytest.approx(cs.cartesian_sigma(res, r), rel=0.10)
    qc = np.asarray(config.noise.qc_ca)
    true_qc = np.asarray(truth["prior_qc"])
    assert qc[0] == pytest.approx(true_qc[0], rel=0.25)  # the forward jerk: its bound 0.17 on SD(log q)
    bound = {r["component"]: r["sd_log"] for r in report["information"]["rows"]}
    determined = [i for i, c in enumerate(COMPONENTS) if bound[c] is not None and bound[c] <= 0.35]
    assert determined == [0, 5]  # x and yaw; y's bound is 0.6 on 20 s of this drive, the others' wider
    off = np.abs(np.log(qc / true_qc))[determined] / np.array([bound[COMPONENTS[i]] for i in determined])
    assert np.all(off <= 2.5), off  # measured: 0.6 and 1.6 bounds (yaw 0.68 of the truth)
    assert report["measurement"]["learned"] == [True] * 4 and report["measurement"]["pairs"] > 10000
    rows = {r["component"]: r for r in report["velocity_growth"]}  # EM's check: x and yaw agree with it
    assert rows["x"]["outside"] is False and rows["yaw"]["outside"] is False


@pytest.mark.slow
def test_a_planar_radar_keeps_the_configured_elevation(tmp_path):
    """A 2D radar (no elevation): the elevation is not learned, its factor stays the base config's."""
    d = tmp_path / "planar"
    scenarios.simulate_to("prior_ca_points", 3, d, duration=4.0, sensor_profile="corner2d")
    base = OdometryConfig.for_model("ca-polar")
    base = base.replace(noise=dataclasses.replace(base.noise, sensor_sigma_scales=(1.0, 1.0, 1.7, 1.0)))
    config, report = calibrate_without_truth(read_sequence(d), base, iterations=1, sensor_noise=True)
    assert report["measurement"]["learned"] == [True, True, False, True] and report["measurement"]["planar"]
    assert config.noise.sensor_sigma_scales[2] == 1.7
    assert report["measurement"]["cartesian_sigma"] is None
    assert report["velocity_growth"].startswith("not checked")  # 4 s are too short for the check
    assert config.noise.cartesian_sigma == base.noise.cartesian_sigma
    assert report["measurement"]["sigmas"]["elevation"] == pytest.approx(1.7 * read_sequence(d).sensor.noise.elevation)


@pytest.mark.slow
def test_the_ti_demo_radial_velocity_noise_is_its_quantisation(realdata_dir):
    """The TI demo (../shared/realdata, no ground truth) reports its Doppler in steps of 0.12492 m/s
    (docs/realdata.md): a uniform quantisation error of step / sqrt(12) = 0.036 m/s, which dominates its noise.
    The learned sigma_vr is within 25 % of it, from the moving scans only: at standstill (scans 0-139 and 342-411)
    the demo repeats its detections bit for bit and its Doppler reads exactly 0, which would learn nothing."""
    from rodo.sim.convert import ti_mmwave

    seq = ti_mmwave.convert(realdata_dir / "rio_ti_mmwave_demo").sequence
    config, report = calibrate_without_truth(seq, OdometryConfig.for_model("ca-polar"), iterations=1,
                                             sensor_noise=True)
    m = report["measurement"]
    assert m["sigmas"]["radial_velocity"] == pytest.approx(0.12492 / np.sqrt(12), rel=0.25)
    assert 150 <= m["doppler_scans"] <= 270 and m["pairs"] >= 100  # the moving part, 412 scans in all
