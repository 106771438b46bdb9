"""The velocity's lag behind a manoeuvre (rodo.estimator.velocity_lag, `[uncertainty] velocity_lag_*`): the smoothed
acceleration it reads, the bias's b b^T on the reported velocity covariance, and the states a run writes with it,
which a replay of a run without it reproduces and from which the window's covariance comes back."""

import dataclasses
from types import SimpleNamespace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.estimator.config import OdometryConfig
from rodo.estimator.odometry import RadarOdometry
from rodo.estimator.uncertainty import fresh_starts
from rodo.estimator.velocity_lag import VelocityLag, lag_accelerations, with_lag
from rodo.validation.odometry_consistency import drift_velocity_covariances
from rodo.validation.replayed_states import velocity_inflated_states
from tests.estimator import scene

LAG = np.array([[0.002, -0.004], [0.0, -0.09], [0.0, -0.006], [0.0, 0.02], [0.0, -0.003], [0.001, 0.03]])


@given(accel=st.floats(-4.0, 4.0), yaw_accel=st.floats(-0.3, 0.3), dt=st.floats(0.02, 0.2),
       smoothing=st.sampled_from([0.0, 0.1, 0.3, 1.0]), restart=st.integers(2, 30))
@settings(max_examples=30, deadline=None)
def test_the_acceleration_follows_a_ramp_and_starts_again_at_a_restart(accel, yaw_accel, dt, smoothing, restart):
    """Under a constant forward and yaw acceleration the smoothed change of the velocity after k scans is the
    acceleration times 1 - phi^k (phi = exp(-dt / T); the acceleration itself at T = 0), from zero at the first
    scan and again from a re-initialisation; scan by scan (`VelocityLag`, as the odometry runs it) the same, bit
    for bit, and its b is L a."""
    n = 40
    t = dt * np.arange(n)
    varpi = np.zeros((n, 6))
    varpi[:, 0], varpi[:, 5] = 5.0 + accel * t, 0.1 + yaw_accel * t
    fresh = fresh_starts(np.arange(n) == restart, n)
    a = lag_accelerations(varpi, t, fresh, smoothing)
    phi = np.exp(-dt / smoothing) if smoothing > 0 else 0.0
    since = np.where(np.arange(n) < restart, np.arange(n), np.arange(n) - restart)
    np.testing.assert_allclose(a, (1.0 - phi**since)[:, None] * [accel, yaw_accel], rtol=1e-9, atol=1e-9)
    config = SimpleNamespace(velocity_lag_per_acceleration=LAG[:, 0], velocity_lag_per_yaw_acceleration=LAG[:, 1],
                             velocity_lag_time=smoothing)
    lag, P = VelocityLag(config), np.eye(12)
    for k in range(n):
        est = SimpleNamespace(varpi=varpi[k], P=P, velocity_lag=np.zeros(6))
        lag.annotate(est, None if fresh[k] else (varpi[k - 1], t[k] - t[k - 1]))
        np.testing.assert_array_equal(lag.acceleration, a[k])
        np.testing.assert_array_equal(est.velocity_lag, LAG @ a[k])
        np.testing.assert_allclose(est.P - P, with_lag(P, LAG @ a[k]) - P, atol=0)


@given(seed=st.integers(0, 2**16))
@settings(max_examples=10, deadline=None)
def test_the_bias_adds_to_the_velocity_block_only(seed):
    """with_lag: P's velocity block + b b^T (one state or a stack), the rest unchanged; sign -1 takes it off
    again; b = 0 returns P itself."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(3, 18, 18))
    P = A @ np.swapaxes(A, 1, 2)
    b = rng.normal(size=(3, 6))
    out = with_lag(P, b)
    want = P.copy()
    want[:, 6:12, 6:12] += b[:, :, None] * b[:, None, :]
    np.testing.assert_array_equal(out, want)
    np.testing.assert_allclose(with_lag(out, b, -1.0), P, atol=1e-12)
    np.testing.assert_array_equal(with_lag(P[0], b[0]), want[0])
    assert with_lag(P, np.zeros((3, 6))) is P


def _run(config, n=26):
    t, T, varpi, vd = scene.trajectory(n, accel=2.0, yaw_acc=0.2)
    landmarks = scene.landmarks(np.random.default_rng(3))
    odometry = RadarOdometry(config, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    est = [odometry.process(t[k], scene.measure(T[k], varpi[k], vd[k], landmarks, np.random.default_rng(k)))
           for k in range(n)]
    return {"t": t, "varpi": np.stack([e.varpi for e in est]), "P": np.stack([e.P for e in est]),
            "T": np.stack([e.T_vehicle_world for e in est]), "velocity_lag": np.stack([e.velocity_lag for e in est]),
            "P_absolute": np.stack([e.P_pose_absolute for e in est]), "restarted": np.array([e.restarted for e in est])}


def test_the_run_adds_the_lag_the_states_replay():
    """A CV/C run with a lag has the same estimates and absolute covariances as one without, its reported velocity
    covariance is the plain run's + b b^T with b = L a of its own emitted velocities; the states of the plain run
    replayed at the lag (`velocity_inflated_states`) are that run's, and the window's velocity covariance comes
    back from them (`drift_velocity_covariances`). Under a 0.2 rad/s^2 yaw acceleration b is not small."""
    config = OdometryConfig.for_model("cv-cartesian")
    plain = _run(config)
    u = dataclasses.replace(config.uncertainty, velocity_lag_per_acceleration=tuple(LAG[:, 0]),
                            velocity_lag_per_yaw_acceleration=tuple(LAG[:, 1]))
    lagged = _run(config.replace(uncertainty=u))
    for key in ("varpi", "T", "P_absolute"):
        np.testing.assert_array_equal(lagged[key], plain[key])
    a = lag_accelerations(plain["varpi"], plain["t"], fresh_starts(plain["restarted"], len(plain["t"])), 0.3)
    np.testing.assert_allclose(lagged["velocity_lag"], a @ LAG.T, rtol=1e-12, atol=1e-15)
    assert np.abs(lagged["velocity_lag"][-1, 5]) > 0.003, lagged["velocity_lag"][-1]  # 0.03 s x 0.2 rad/s^2
    np.testing.assert_allclose(lagged["P"], with_lag(plain["P"], lagged["velocity_lag"]), rtol=1e-12, atol=1e-18)
    replay = velocity_inflated_states(plain, 1.0, 0.0, lag=LAG, lag_time=0.3)
    np.testing.assert_allclose(replay["P"], lagged["P"], rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(replay["velocity_lag"], lagged["velocity_lag"], rtol=1e-12, atol=1e-15)
    window = drift_velocity_covariances(lagged["P"], lagged["varpi"], lag=lagged["velocity_lag"])
    np.testing.assert_allclose(window, plain["P"][:, 6:12, 6:12], rtol=1e-9, atol=1e-15)


def test_a_lag_without_smoothing_or_with_a_bad_lag_is_refused():
    """velocity_lag_time must be positive (the raw change over dt is unbounded for scans close in time), and the
    lag vectors need six finite numbers: each refused naming the key."""
    import pytest

    from rodo.estimator.config import UncertaintyConfig
    from rodo.estimator.errors import InputError

    for bad in ({"velocity_lag_time": 0.0}, {"velocity_lag_per_acceleration": (0.0,) * 5},
                {"velocity_lag_per_yaw_acceleration": (0.0,) * 5 + (float("nan"),)}):
        with pytest.raises(InputError, match=next(iter(bad))):
            OdometryConfig.for_model("cv-cartesian").replace(uncertainty=UncertaintyConfig(**bad))
