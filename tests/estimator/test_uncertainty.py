"""The drift covariance (rodo.estimator.uncertainty): relative covariance from a joint one, the absolute
recursion and the span covariance against Monte Carlo on SE(3), and the odometry's covariances end to end."""

import numpy as np
import pytest
from hypothesis import given, settings
from scipy.stats import chi2

from rodo.estimator.config import OdometryConfig
from rodo.estimator.lie import se3
from rodo.estimator.odometry import RadarOdometry
from rodo.estimator.uncertainty import DriftCovariance, relative_pose_covariance, revision_covariance, span_covariance
from tests.estimator import scene
from tests.strategies import twists

N_MC = 4000


def _mean_nees_in_bounds(e: np.ndarray, P: np.ndarray, dof: int = 6, level: float = 0.999):
    v = np.einsum("ni,ij,nj->n", e, np.linalg.inv(P), e)
    lo, hi = chi2.ppf([(1 - level) / 2, (1 + level) / 2], len(e) * dof) / len(e)
    return lo <= v.mean() <= hi, (v.mean(), lo, hi)


def _random_cov(rng, scale):
    A = rng.normal(size=(6, 6)) * scale
    return A @ A.T + np.eye(6) * scale**2 * 0.1


@given(a=twists("vehicle", 5.0), b=twists("vehicle", 5.0))
@settings(max_examples=10)
def test_relative_covariance_of_a_known_joint_gaussian(a, b):
    """Perturb two poses with a correlated joint Gaussian on the left; the relative pose's perturbation
    log(R' R^-1) has the covariance `relative_pose_covariance` gives (mean NEES in the 99.9 % bounds)."""
    rng = np.random.default_rng(np.random.SeedSequence(11))
    T_prev, T_new = se3.exp(a), se3.exp(b)
    L = rng.normal(size=(12, 12)) * 2e-3
    P_pair = L @ L.T + 1e-7 * np.eye(12)
    dim = 6
    xi = rng.multivariate_normal(np.zeros(12), P_pair, size=N_MC)
    R = T_new @ se3.inverse(T_prev)
    Rp = se3.exp(xi[:, 6:]) @ T_new @ se3.inverse(se3.exp(xi[:, :6]) @ T_prev)
    delta = se3.log(Rp @ se3.inverse(R))
    ok, info = _mean_nees_in_bounds(delta, relative_pose_covariance(P_pair, T_prev, T_new, dim))
    assert ok, info


@given(a=twists("vehicle", 5.0), b=twists("vehicle", 5.0))
@settings(max_examples=10)
def test_relative_covariance_between_emitted_poses_counts_the_revision(a, b):
    """A linear Gaussian window: the previous pose was emitted at its prior mean with covariance P0; a new
    scan's measurement z = H xi + v (informative about both poses) gives the posterior P_pair and revises the
    previous pose. The relative pose between the emitted poses (the previous one as emitted, the new one as
    solved) has the covariance `relative_pose_covariance` gives plus `revision_covariance` of P0 (mean NEES in
    the 99.9 % bounds), and not the first alone; a revision that lost information (P0 smaller than the
    posterior's, a forgetting prior) adds nothing."""
    rng = np.random.default_rng(np.random.SeedSequence(12))
    T_prev, T_new = se3.exp(a), se3.exp(b)
    L = rng.normal(size=(12, 12)) * 2e-3
    P_prior = L @ L.T + 1e-7 * np.eye(12)
    H = rng.normal(size=(9, 12))
    R_noise = np.eye(9) * 1e-6
    K = P_prior @ H.T @ np.linalg.inv(H @ P_prior @ H.T + R_noise)
    P_pair = P_prior - K @ H @ P_prior
    xi = rng.multivariate_normal(np.zeros(12), P_prior, size=N_MC)
    z = xi @ H.T + rng.multivariate_normal(np.zeros(9), R_noise, size=N_MC)
    m_new = (z @ K.T)[:, 6:]
    R_true = se3.exp(xi[:, 6:]) @ T_new @ se3.inverse(se3.exp(xi[:, :6]) @ T_prev)
    R_emitted = se3.exp(m_new) @ T_new @ se3.inverse(T_prev)
    delta = se3.log(R_true @ se3.inverse(R_emitted))
    S = relative_pose_covariance(P_pair, T_prev, T_new, 6)
    ok, info = _mean_nees_in_bounds(delta, S + revision_covariance(P_prior, P_pair, T_prev, T_new))
    assert ok, info
    ok, info = _mean_nees_in_bounds(delta, S)
    assert not ok and info[0] > info[2], info
    np.testing.assert_array_equal(revision_covariance(0.5 * P_pair[:6, :6], P_pair, T_prev, T_new), np.zeros((6, 6)))


def _model_monte_carlo(rng, T, t, Sigma_rel, P_varpi, tau, P0, drift_rate_sigma=np.zeros(6), restart=None):
    """Samples of the drift model on SE(3): true poses exp(dt b_k + s_k beta + delta_k) R_k T_{k-1} with the
    velocity error b a Gauss-Markov process and the drift rate beta constant per sample (s_k = |t(R_k)|); at the
    scan `restart` a re-initialisation, exp(delta_k) R_k T_{k-1} with b zero from there; returns the pose
    perturbations log(T_true T^-1) at the last scan."""
    n = len(t)
    T_true = se3.exp(rng.multivariate_normal(np.zeros(6), P0, size=N_MC)) @ T[0]
    b = rng.multivariate_normal(np.zeros(6), P_varpi[0], size=N_MC)
    beta = rng.normal(size=(N_MC, 6)) * drift_rate_sigma
    for k in range(1, n):
        if k == restart:
            b = np.zeros_like(b)
            d = rng.multivariate_normal(np.zeros(6), Sigma_rel[k], size=N_MC)
            T_true = se3.exp(d) @ T[k] @ se3.inverse(T[k - 1]) @ T_true
            continue
        dt = t[k] - t[k - 1]
        phi = np.exp(-dt / tau) if tau > 0 else 0.0
        w = rng.multivariate_normal(np.zeros(6), (1 - phi**2) * P_varpi[k], size=N_MC)
        b = phi * b + w if tau > 0 else np.zeros_like(b)
        d = rng.multivariate_normal(np.zeros(6), Sigma_rel[k], size=N_MC)
        R = T[k] @ se3.inverse(T[k - 1])
        T_true = se3.exp(dt * b + np.linalg.norm(R[:3, 3]) * beta + d) @ R @ T_true
    return se3.log(T_true @ se3.inverse(T[-1]))


DRIFT_RATE = np.array([2e-3, 1e-3, 3e-3, 2e-4, 3e-4, 1e-4])  # per metre: large, so that it shows in 20 scans


@pytest.mark.parametrize("tau, drift_rate_sigma", [(0.0, None), (0.3, None), (2.0, None), (0.3, DRIFT_RATE)])
def test_drift_covariance_matches_monte_carlo_of_the_model(tau, drift_rate_sigma):
    """The absolute recursion against samples of the model it linearises, over 20 turning, accelerating scans."""
    rng = np.random.default_rng(np.random.SeedSequence(12))
    t = np.cumsum(np.r_[0.0, rng.uniform(0.05, 0.1, 19)])
    T = np.stack([se3.exp(np.array([-8.0 * s, 0.3 * s, 0.0, 0.01, -0.02, 0.4 * s])) for s in t])
    Sigma_rel = np.stack([_random_cov(rng, 3e-3) for _ in t])
    P_varpi = np.stack([_random_cov(rng, 2e-2) for _ in t])
    P0 = _random_cov(rng, 1e-3)
    drift = DriftCovariance(P0, P_varpi[0], tau, drift_rate_sigma)
    for k in range(1, len(t)):
        P = drift.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k])
    xi = _model_monte_carlo(rng, T, t, Sigma_rel, P_varpi, tau, P0,
                            np.zeros(6) if drift_rate_sigma is None else drift_rate_sigma)
    ok, info = _mean_nees_in_bounds(xi, P)
    assert ok, info
    if drift_rate_sigma is not None:  # the drift rate matters here: without it the covariance is too small
        without = DriftCovariance(P0, P_varpi[0], tau)
        for k in range(1, len(t)):
            P_without = without.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k])
        assert not _mean_nees_in_bounds(xi, P_without)[0]
    # and the velocity part matters when tau > 0: without it the covariance is too small
    if tau >= 2.0:
        small = DriftCovariance(P0, P_varpi[0], 0.0)
        for k in range(1, len(t)):
            P0_only = small.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k])
        assert not _mean_nees_in_bounds(xi, P0_only)[0]


def test_the_restart_starts_the_velocity_error_again():
    """Across a re-initialisation the recursion adds the dead-reckoned relative pose alone and starts the velocity
    error b again at zero: the absolute covariance matches Monte Carlo of that model, and what b was before the
    restart (its variance) changes nothing after it but through the pose it left, at the restart and 8 scans
    later. (An ordinary update at the restart, as before session 29, adds the velocity error over the 2 s outage
    that the dead-reckoned step holds already: the closed form at the restart fails then.)"""
    rng = np.random.default_rng(np.random.SeedSequence(14))
    t = np.cumsum(np.r_[0.0, rng.uniform(0.05, 0.1, 19)])
    t[10:] += 2.0  # a 2 s outage before scan 10
    T = np.stack([se3.exp(np.array([-8.0 * s, 0.3 * s, 0.0, 0.01, -0.02, 0.4 * s])) for s in t])
    Sigma_rel = np.stack([_random_cov(rng, 3e-3) for _ in t])
    Sigma_rel[10] = _random_cov(rng, 1e-2)  # the dead-reckoned step
    P_varpi = np.stack([_random_cov(rng, 2e-2) for _ in t])
    P0, tau = _random_cov(rng, 1e-3), 0.5

    def run(big_b: bool, restart: bool):
        drift = DriftCovariance(P0, (100.0 if big_b else 1.0) * P_varpi[0], tau, DRIFT_RATE)
        out = []
        for k in range(1, len(t)):
            if k == 10 and restart:
                out.append(drift.restart(T[k - 1], T[k], Sigma_rel[k]))
            else:
                out.append(drift.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k]))
        return np.stack(out)

    P = run(False, True)
    xi = _model_monte_carlo(rng, T, t, Sigma_rel, P_varpi, tau, P0, DRIFT_RATE, restart=10)
    ok, info = _mean_nees_in_bounds(xi, P[-1])
    assert ok, info
    A = se3.adjoint(T[10] @ se3.inverse(T[9]))  # at the restart: the pose carried, plus the dead-reckoned step
    np.testing.assert_allclose(P[9], A @ P[8] @ A.T + Sigma_rel[10], rtol=1e-12, atol=1e-18)
    big = run(True, True)
    assert not np.allclose(big[8], P[8], rtol=1e-3)  # b mattered before the restart
    for k in (9, 17):  # after it, only through the pose it left
        A = np.eye(6)
        for j in range(10, k + 2):
            A = se3.adjoint(T[j] @ se3.inverse(T[j - 1])) @ A
        np.testing.assert_allclose(big[k] - P[k], A @ (big[8] - P[8]) @ A.T, rtol=1e-9, atol=1e-15)


def test_span_covariance_equals_the_recursion():
    """A span from scan s to e is the recursion started at s with a known pose (from scan 0, the run's start, or
    from a re-initialisation: the velocity error at zero, as the absolute recursion starts), with the restart's
    step into a scan flagged as one."""
    rng = np.random.default_rng(np.random.SeedSequence(13))
    t = np.cumsum(np.r_[0.0, rng.uniform(0.05, 0.1, 14)])
    T = np.stack([se3.exp(np.array([-8.0 * s, 0.0, 0.0, 0.0, 0.0, 0.3 * s])) for s in t])
    Sigma_rel = np.stack([_random_cov(rng, 1e-3) for _ in t])
    Sigma_rel[0] = np.nan
    P_varpi = np.stack([_random_cov(rng, 1e-2) for _ in t])
    for drift_rate_sigma in (None, DRIFT_RATE):
        drift = DriftCovariance(np.zeros((6, 6)), P_varpi[4], 0.5, drift_rate_sigma)
        for k in range(5, 12):
            P = drift.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k])
        np.testing.assert_allclose(span_covariance(T, t, Sigma_rel, P_varpi, 4, 11, 0.5, drift_rate_sigma), P,
                                   rtol=1e-12, atol=1e-18)
        first = DriftCovariance.at_first_scan(np.zeros((6, 6)), 0.5, drift_rate_sigma)  # a span from scan 0
        for k in range(1, 8):
            P = first.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k])
        np.testing.assert_allclose(span_covariance(T, t, Sigma_rel, P_varpi, 0, 7, 0.5, drift_rate_sigma), P,
                                   rtol=1e-12, atol=1e-18)
        restarts = np.zeros(len(t), bool)
        restarts[[7, 9]] = True  # across a re-initialisation the restart's step; from one, b at zero
        drift = DriftCovariance(np.zeros((6, 6)), P_varpi[4], 0.5, drift_rate_sigma)
        for k in range(5, 12):
            P = (drift.restart(T[k - 1], T[k], Sigma_rel[k]) if restarts[k]
                 else drift.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k]))
        np.testing.assert_allclose(span_covariance(T, t, Sigma_rel, P_varpi, 4, 11, 0.5, drift_rate_sigma, restarts),
                                   P, rtol=1e-12, atol=1e-18)
        after = DriftCovariance.at_first_scan(np.zeros((6, 6)), 0.5, drift_rate_sigma)
        for k in range(8, 12):
            P = (after.restart(T[k - 1], T[k], Sigma_rel[k]) if restarts[k]
                 else after.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k]))
        np.testing.assert_allclose(span_covariance(T, t, Sigma_rel, P_varpi, 7, 11, 0.5, drift_rate_sigma, restarts),
                                   P, rtol=1e-12, atol=1e-18)


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_absolute_covariance_grows_while_the_windows_stays_flat(model):
    """Odometry end to end: the window's pose covariance is relative to the map and stays flat; the absolute
    one grows with the distance driven (drift), and each scan reports a positive definite relative one."""
    rng = np.random.default_rng(5)
    t, T, varpi, vd = scene.trajectory(40)
    L = scene.landmarks(rng)
    odo = RadarOdometry(OdometryConfig.for_model(model), scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    est = [odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L, rng)) for k in range(len(t))]
    assert np.isnan(est[0].P_relative).all()
    for e in est[1:]:
        assert np.all(np.linalg.eigvalsh(e.P_relative) > 0)
    window = [np.trace(e.P[:6, :6]) for e in est]
    absolute = [np.trace(e.P_pose_absolute) for e in est]
    assert absolute[-1] > 10 * absolute[5] and absolute[-1] > 10 * window[-1]
    assert np.all(np.diff(absolute[1:]) > 0)


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_the_drift_recursion_starts_without_the_first_scans_velocity_error(model):
    """At a run's first scan the window's velocity covariance is the initial prior's (the yaw rate unseen), and the
    second scan is registered against the first one's map: the absolute covariance of the second scan is the first
    pose's carried over plus that step's registration, velocity (b_0 = 0: only w_1, (1 - phi^2) P_varpi,1) and
    drift rate terms, none of the first velocity covariance, whatever the initial yaw rate sigma."""
    from rodo.estimator.config import SolverConfig, UncertaintyConfig

    rng = np.random.default_rng(5)
    t, T, varpi, vd = scene.trajectory(6)
    L = scene.landmarks(rng)
    scans = [scene.measure(T[k], varpi[k], vd[k], L, np.random.default_rng(k)) for k in range(3)]
    tau, beta = 0.3, np.array([1e-3, 1e-4, 2e-3, 1e-5, 2e-5, 3e-5])
    for yaw_rate_sigma in (0.2, 2.0):
        cfg = OdometryConfig.for_model(model).replace(
            uncertainty=UncertaintyConfig(velocity_correlation_time=tau, drift_rate_sigma=tuple(beta)),
            solver=SolverConfig(init_rate_sigma=(0.02, 0.02, yaw_rate_sigma)))
        odo = RadarOdometry(cfg, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
        e0, e1 = (odo.process(t[k], scans[k]) for k in range(2))
        assert e0.P[11, 11] > 0.5 * yaw_rate_sigma ** 2  # the first scan's yaw rate is the prior's
        R = e1.T_vehicle_world @ se3.inverse(e0.T_vehicle_world)
        dt = e1.t - e0.t
        A = se3.adjoint(R)
        w1 = (1 - np.exp(-2 * dt / tau)) * e1.P[6:12, 6:12]  # Var(w_1) = (1 - phi^2) P_varpi,1
        expected = (A @ e0.P_pose_absolute @ A.T + e1.P_relative + dt ** 2 * w1
                    + np.linalg.norm(R[:3, 3]) ** 2 * np.diag(beta ** 2))
        np.testing.assert_allclose(e1.P_pose_absolute, expected, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_the_restart_adds_the_prediction_not_the_last_states_own_covariance(model):
    """Across a re-initialisation the odometry dead-reckons from its last state; the relative pose of the
    prediction is what it adds to the absolute covariance. The last state's own pose covariance (relative to the
    map, grown over the outage, and composed into the absolute covariance scan by scan already) cancels: inflated
    10^4 times, it moves the result by rounding; with no covariance at all the result is the prior's Q."""
    from rodo.estimator.uncertainty import predicted_relative_covariance

    rng = np.random.default_rng(7)
    t, T, varpi, vd = scene.trajectory(8)
    L = scene.landmarks(rng)
    odo = RadarOdometry(OdometryConfig.for_model(model), scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    for k in range(6):
        odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L, rng))
    last, dt = odo.window.newest, 0.9
    T_new = odo.motion.predict(last, last.t + dt).T_vehicle_world
    F, Q = odo.motion.transition_and_noise(last, dt)
    P = odo.P.copy()
    got = predicted_relative_covariance(P, F, Q, last.T_vehicle_world, T_new)
    inflated = P.copy()
    inflated[:6, :6] += 1e4 * P[:6, :6]
    after = predicted_relative_covariance(inflated, F, Q, last.T_vehicle_world, T_new)
    np.testing.assert_allclose(after, got, rtol=1e-5, atol=1e-12 * np.abs(got).max())
    old = (F @ inflated @ F.T + Q)[:6, :6]  # what the restart carried before: the inflation too
    assert np.trace(old) - np.trace(after) > 0.5e4 * np.trace(P[:6, :6])
    np.testing.assert_allclose(predicted_relative_covariance(np.zeros_like(P), F, Q, last.T_vehicle_world, T_new),
                               Q[:6, :6], rtol=1e-9, atol=1e-15)
    assert np.all(np.linalg.eigvalsh(got) > 0)


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_a_blackout_is_not_counted_twice_at_the_restart(model):
    """3 s of empty scans, then a re-initialisation: the window's pose covariance has grown over the blackout
    (and the absolute covariance with it, scan by scan); the relative covariance the restart reports is one
    prediction step's, not that grown covariance again."""
    rng = np.random.default_rng(1)
    t, T, varpi, vd = scene.trajectory(62, accel=0.2, yaw_rate=0.02, yaw_acc=0.0, pitch_acc=0.0)
    L = scene.landmarks(rng)
    odo = RadarOdometry(OdometryConfig.for_model(model), scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    est = []
    for k in range(len(t)):
        z = np.zeros((0, 4)) if 20 <= k < 59 else scene.measure(T[k], varpi[k], vd[k], L, rng)
        est.append(odo.process(t[k], z))
    restart = next(k for k, e in enumerate(est) if any("re-initialised" in m for m in e.events))
    before = est[restart - 1]
    assert np.trace(before.P[:6, :6]) > 10.0  # grown over the blackout
    assert np.trace(est[restart].P_relative) < 0.01 * np.trace(before.P[:6, :6])
    assert np.all(np.linalg.eigvalsh(est[restart].P_relative) > 0)


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_the_restart_is_flagged_and_adds_the_dead_reckoned_step_alone(model):
    """The re-initialisation's scan is flagged (`restarted`) and its absolute covariance is the
    last one carried over plus the dead-reckoned relative pose, no velocity error or drift rate over the outage
    (`uncertainty.restart_matrices`); that relative pose is the prior's, not a registration's, so the factor on
    the registrations' relative covariance (`uncertainty.inflation`) leaves it as it is."""
    from rodo.estimator.config import UncertaintyConfig

    rng = np.random.default_rng(1)
    t, T, varpi, vd = scene.trajectory(66, accel=0.2, yaw_rate=0.02, yaw_acc=0.0, pitch_acc=0.0)
    L = scene.landmarks(rng)
    scans = [np.zeros((0, 4)) if 20 <= k < 59 else scene.measure(T[k], varpi[k], vd[k], L, rng) for k in range(66)]
    runs = {}
    for f in (1.0, 0.5):
        cfg = OdometryConfig.for_model(model).replace(uncertainty=UncertaintyConfig(
            velocity_correlation_time=0.3, drift_rate_sigma=(1e-3, 1e-4, 2e-3, 1e-5, 2e-5, 3e-5), inflation=f))
        odo = RadarOdometry(cfg, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
        runs[f] = [odo.process(t[k], scans[k]) for k in range(len(t))]
    est = runs[0.5]
    r = next(k for k, e in enumerate(est) if any("re-initialised" in m for m in e.events))
    assert [k for k, e in enumerate(est) if e.restarted] == [r]
    A = se3.adjoint(est[r].T_vehicle_world @ se3.inverse(est[r - 1].T_vehicle_world))
    np.testing.assert_allclose(est[r].P_pose_absolute, A @ est[r - 1].P_pose_absolute @ A.T + est[r].P_relative,
                               rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(est[r].P_relative, runs[1.0][r].P_relative)  # not scaled by inflation
    np.testing.assert_allclose(est[r + 3].P_relative, 0.5 * runs[1.0][r + 3].P_relative, rtol=1e-12)
