"""The factors on the covariances (rodo.estimator.uncertainty, [uncertainty]): the pairs' information in the
solve (measurement_inflation), the reported velocity's variance (velocity_inflation and its speed, Doppler and
per-axis terms) and the Doppler innovation NIS it reads, which is chi-square when the prediction is right."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from rodo.estimator.config import OdometryConfig
from rodo.estimator.lie import se3
from rodo.estimator.odometry import RadarOdometry
from rodo.estimator.velocity_inflation import velocity_inflated
from tests.estimator import scene


def test_measurement_inflation_scales_the_information_of_the_pairs():
    """uncertainty.measurement_inflation kappa divides every pair's information in the solve: the
    relative pose covariance grows by up to kappa (the prior keeps its share), the estimate stays close, and a
    kappa below 1 is refused."""
    from rodo.estimator.config import UncertaintyConfig
    from rodo.estimator.errors import InputError

    rng_scene = np.random.default_rng(5)
    t, T, varpi, vd = scene.trajectory(12)
    L = scene.landmarks(rng_scene)
    scans = [scene.measure(T[k], varpi[k], vd[k], L, np.random.default_rng(k)) for k in range(len(t))]
    out = {}
    for kappa in (1.0, 4.0):
        cfg = OdometryConfig.for_model("ca-polar").replace(uncertainty=UncertaintyConfig(measurement_inflation=kappa))
        odo = RadarOdometry(cfg, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
        out[kappa] = [odo.process(t[k], scans[k]) for k in range(len(t))][-1]
    ratio = np.trace(out[4.0].P_relative) / np.trace(out[1.0].P_relative)
    assert 2.0 < ratio < 4.5, ratio  # measured 2.46: the motion prior and the rate terms keep some information
    assert np.abs(se3.log(out[4.0].T_vehicle_world @ se3.inverse(out[1.0].T_vehicle_world))).max() < 0.05
    with pytest.raises(InputError, match="measurement_inflation"):
        OdometryConfig.for_model("ca-polar").replace(uncertainty=UncertaintyConfig(measurement_inflation=0.5))


@given(inflation=st.floats(0.05, 20.0), per_speed=st.floats(0.0, 1.0), speed=st.floats(0.0, 40.0),
       per_doppler=st.floats(0.0, 2.0), nis=st.one_of(st.just(float("nan")), st.floats(0.0, 1e4)),
       seed=st.integers(0, 2**16))
@settings(max_examples=40)
def test_velocity_inflation_scales_the_velocity_variance_only(inflation, per_speed, speed, per_doppler, nis, seed):
    """`velocity_inflated`: the velocity block times c = inflation + per_speed |nu| + per_doppler ln(1 + nis)
    (no Doppler term for a scan without one, NaN), its cross blocks times sqrt(c) (the covariance of the state
    with its velocity error scaled by sqrt(c)), everything else as it was; a stack of states as one at a time;
    no factor returns P itself; per-axis factors scale each velocity element's variance, and ones change
    nothing, bit for bit."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(18, 18))
    P = A @ A.T + 0.1 * np.eye(18)
    u = rng.normal(size=3)
    varpi = np.r_[speed * u / np.linalg.norm(u), rng.normal(size=3)]
    c = inflation + per_speed * speed + (per_doppler * np.log1p(nis) if np.isfinite(nis) else 0.0)
    out = velocity_inflated(P, varpi, inflation, per_speed, per_doppler, nis)
    D = np.diag(np.r_[np.ones(6), np.full(6, np.sqrt(c)), np.ones(6)])
    np.testing.assert_allclose(out, D @ P @ D, rtol=1e-12)
    np.testing.assert_allclose(out[6:12, 6:12], c * P[6:12, 6:12], rtol=1e-12)
    rest = np.r_[0:6, 12:18]
    np.testing.assert_array_equal(out[np.ix_(rest, rest)], P[np.ix_(rest, rest)])
    stack = velocity_inflated(np.stack([P, P[::-1, ::-1]]), np.stack([varpi, 2 * varpi]), inflation, per_speed,
                              per_doppler, np.array([nis, 2 * nis]))
    np.testing.assert_allclose(stack[1], velocity_inflated(P[::-1, ::-1], 2 * varpi, inflation, per_speed,
                                                           per_doppler, 2 * nis), rtol=1e-12)
    np.testing.assert_allclose(stack[0], out, rtol=1e-12)
    assert velocity_inflated(P, varpi, 1.0, 0.0, 0.0, nis) is P
    assert velocity_inflated(P, varpi, 1.0, 0.0) is P
    # per-axis factors g: velocity element i's variance times c g_i, its cross terms by the square roots
    g = np.exp(rng.uniform(-2.0, 2.0, 6))
    axes = velocity_inflated(P, varpi, inflation, per_speed, per_doppler, nis, g)
    D = np.diag(np.r_[np.ones(6), np.sqrt(c * g), np.ones(6)])
    np.testing.assert_allclose(axes, D @ P @ D, rtol=1e-12)
    np.testing.assert_allclose(np.diag(axes)[6:12], c * g * np.diag(P)[6:12], rtol=1e-12)
    assert velocity_inflated(P, varpi, inflation, per_speed, per_doppler, nis, np.ones(6)).tobytes() == out.tobytes()
    assert velocity_inflated(P, varpi, 1.0, 0.0, 0.0, nis, np.ones(6)) is P


def test_velocity_inflation_changes_the_report_not_the_estimate():
    """The odometry with velocity factors: the same estimates bit for bit (the solve and the gates use the
    window's own covariance), the reported velocity variance scaled by a + b |nu| of each scan, the relative and
    absolute pose covariances as they were (the drift recursion keeps the window's velocity covariance, with
    which its tau and drift rate are calibrated)."""
    from rodo.estimator.config import UncertaintyConfig

    rng_scene = np.random.default_rng(5)
    t, T, varpi, vd = scene.trajectory(15)
    L = scene.landmarks(rng_scene)
    scans = [scene.measure(T[k], varpi[k], vd[k], L, np.random.default_rng(k)) for k in range(len(t))]
    out = {}
    for factors in ((1.0, 0.0, 0.0), (0.5, 0.3, 0.7)):
        unc = UncertaintyConfig(velocity_inflation=factors[0], velocity_inflation_per_speed=factors[1],
                                velocity_inflation_per_doppler=factors[2])
        odo = RadarOdometry(OdometryConfig.for_model("ca-polar").replace(uncertainty=unc), scene.T_VEHICLE_SENSOR,
                            scene.SIGMAS, 120.0)
        out[factors] = [odo.process(t[k], scans[k]) for k in range(len(t))]
    assert np.isnan(out[(1.0, 0.0, 0.0)][0].doppler_nis)  # the first scan has no prediction
    assert np.all(np.isfinite([e.doppler_nis for e in out[(1.0, 0.0, 0.0)][1:]]))
    for a, b in zip(out[(1.0, 0.0, 0.0)], out[(0.5, 0.3, 0.7)]):
        np.testing.assert_array_equal(a.T_vehicle_world, b.T_vehicle_world)
        np.testing.assert_array_equal(a.varpi, b.varpi)
        np.testing.assert_array_equal(a.doppler_nis, b.doppler_nis)
        c = 0.5 + 0.3 * np.linalg.norm(a.varpi[:3]) + (0.7 * np.log1p(a.doppler_nis) if a.t > t[0] else 0.0)
        np.testing.assert_allclose(b.P[6:12, 6:12], c * a.P[6:12, 6:12], rtol=1e-12)
        np.testing.assert_array_equal(b.P[:6, :6], a.P[:6, :6])
        np.testing.assert_array_equal(b.P_relative, a.P_relative)
        np.testing.assert_array_equal(b.P_pose_absolute, a.P_pose_absolute)


@given(seed=st.integers(0, 2**16), planar=st.booleans())
@settings(max_examples=10, deadline=None)
def test_the_doppler_nis_is_chi_square_when_the_prediction_is_right(seed, planar):
    """`DopplerFrontEnd.correct`'s NIS per dof (what `velocity_inflation_per_doppler` reads): with the true
    velocity drawn from the prediction's own N(varpi, P) and the scan's Doppler fit from N(v_s, fit.cov), over
    2000 scans its mean is 1 within 5 standard errors of chi-square(dof) / dof, and 5 % of the scans lie above
    chi-square's 95 % quantile (within 2.2 points, 4.5 sigma); a prediction 2 sigma off in every velocity
    component raises it. (The bounds hold the false alarms of 10 random draws a run near 1 in 10,000 runs; at 4
    and 3.3 sigma, as before, about 1 in 100.)"""
    from rodo.estimator.doppler import DopplerFit, sensor_velocity
    from rodo.estimator.state import State

    rng = np.random.default_rng(seed)
    odo = RadarOdometry(OdometryConfig.for_model("ca-polar"), scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    dof = 2 if planar else 3
    A = rng.normal(size=(18, 18)) * 0.1
    P = A @ A.T + 1e-3 * np.eye(18)
    x = State(0.0, np.eye(4), np.r_[10.0, 0.5, 0.0, 0.0, 0.0, 0.1], np.zeros(6))
    _, J = sensor_velocity(x.varpi, scene.T_VEHICLE_SENSOR)
    B = rng.normal(size=(dof, dof)) * 0.05
    cov = B @ B.T + 1e-3 * np.eye(dof)
    L_v, L_fit = np.linalg.cholesky(P[6:12, 6:12]), np.linalg.cholesky(cov)
    nis, off = [], []
    for _ in range(2000):
        varpi = x.varpi + L_v @ rng.normal(size=6)
        v = (J @ varpi)[:dof] + L_fit @ rng.normal(size=dof)
        nis.append(odo.doppler.correct(x, P, DopplerFit(v, cov, np.zeros(10)))[1])
        v_off = v + (J @ (2 * np.sqrt(np.diag(P[6:12, 6:12]))))[:dof]
        off.append(odo.doppler.correct(x, P, DopplerFit(v_off, cov, np.zeros(10)))[1])
    nis = np.array(nis)
    assert abs(nis.mean() - 1.0) < 5 * np.sqrt(2.0 / dof / len(nis)), nis.mean()
    assert abs(np.mean(nis * dof > chi2.ppf(0.95, dof)) - 0.05) < 0.022
    assert np.mean(off) > 1.5 * nis.mean()
    assert np.isnan(odo.doppler.correct(x, P, None)[1])


@given(rates=st.tuples(*[st.floats(0.0, 50.0)] * 3), seed=st.integers(0, 2**16))
def test_velocity_factor_with_rates(rates, seed):
    """The rate terms add r . |omega| to the factor, for one varpi and for a stack alike; with r = 0 the factor
    is the one without them, bit for bit."""
    from rodo.estimator.velocity_inflation import velocity_factor

    rng = np.random.default_rng(np.random.SeedSequence([35, seed]))
    varpi = rng.normal(size=(20, 6))
    nis = rng.chisquare(3, 20) / 3
    base = velocity_factor(varpi, 0.8, 0.05, 0.3, nis)
    with_rates = velocity_factor(varpi, 0.8, 0.05, 0.3, nis, rates)
    np.testing.assert_allclose(with_rates, base + np.abs(varpi[:, 3:]) @ np.array(rates), rtol=1e-12)
    assert velocity_factor(varpi[3], 0.8, 0.05, 0.3, nis[3], rates) == pytest.approx(with_rates[3], rel=1e-12)
    np.testing.assert_array_equal(velocity_factor(varpi, 0.8, 0.05, 0.3, nis, (0.0, 0.0, 0.0)), base)


def test_velocity_inflation_array_round_trips():
    """states.npz velocity_inflation: [a, b, d] without rate terms (as runs before them wrote it), six numbers with
    them; read back to the same terms, [a, b] as d = 0; any other length refused."""
    from rodo.estimator.config import OdometryConfig
    from rodo.estimator.velocity_inflation import velocity_inflation_array, velocity_inflation_terms

    u = OdometryConfig().uncertainty
    plain = velocity_inflation_array(u.velocity_inflation, u.velocity_inflation_per_speed,
                                     u.velocity_inflation_per_doppler, u.velocity_inflation_per_rate)
    assert plain.shape == (3,)
    six = velocity_inflation_array(0.7, 0.0, 0.0, (1.0, 2.0, 0.0))
    assert six.tolist() == [0.7, 0.0, 0.0, 1.0, 2.0, 0.0]
    a, b, d, r = velocity_inflation_terms(six)
    assert (a, b, d) == (0.7, 0.0, 0.0) and r.tolist() == [1.0, 2.0, 0.0]
    assert velocity_inflation_terms([1.2, 0.1])[:3] == (1.2, 0.1, 0.0)
    with pytest.raises(ValueError, match="2, 3 or 6"):
        velocity_inflation_terms([1.0, 0.0, 0.0, 1.0])
