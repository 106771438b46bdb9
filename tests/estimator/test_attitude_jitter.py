"""The roll and pitch jitter beside the drift recursion (rodo.estimator.attitude_jitter): a span's variance
against Monte Carlo of the stationary process it models, its limits, the covariances it changes (roll and pitch
only), and the odometry reporting it in the absolute pose and replaying it."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator.attitude_jitter import (AXES, AbsoluteJitter, absolute_excess, attitude_jitter_array,
                                            attitude_jitter_of, span_excess, span_variance, with_roll_pitch_variance)


def _rng(*key):
    return np.random.default_rng(np.random.SeedSequence([2026, 31, *key]))


@pytest.mark.parametrize("T", [0.3, 1.0, 2.5])
def test_a_spans_variance_is_that_of_the_stationary_process(T):
    """Paths of a stationary Gaussian process with covariance V exp(-(dt / T)^2), drawn on a 0.05 s grid: the
    sample variance of j(s + L) - j(s) equals `span_variance(L)` at every lag, within Monte Carlo error (4000
    paths: relative standard error 2.2 %), at lags short and long against T."""
    V, dt, n, paths = 3e-6, 0.05, 120, 4000
    t = dt * np.arange(n)
    K = V * np.exp(-np.square((t[:, None] - t[None, :]) / T))
    w, U = np.linalg.eigh(K)
    root = U * np.sqrt(np.clip(w, 0.0, None))  # K = root root^T; eigh, as K is numerically semi-definite
    j = _rng(1, int(10 * T)).standard_normal((paths, n)) @ root.T
    for lag in (1, 3, 10, 30, 100):
        sample = np.var(j[:, lag:] - j[:, :-lag], axis=0, ddof=1).mean()  # averaged over the start s
        assert sample == pytest.approx(float(span_variance(lag * dt, (V, T))), rel=0.08), lag


@given(V=st.floats(1e-9, 1e-3), T=st.floats(0.05, 10.0), L=st.floats(0.0, 100.0), k=st.floats(1.0, 10.0))
def test_the_span_variance_grows_from_zero_to_twice_the_variance(V, T, L, k):
    """0 at L = 0, never decreasing with L, never above 2 V, 2 V for L >> T, and linear in V."""
    assert span_variance(0.0, (V, T)) == 0.0
    assert 0.0 <= span_variance(L, (V, T)) <= span_variance(L * k, (V, T)) <= 2 * V
    assert span_variance(10 * T, (V, T)) == pytest.approx(2 * V, rel=1e-12)
    assert span_variance(L, (k * V, T)) == pytest.approx(k * span_variance(L, (V, T)), rel=1e-12, abs=1e-300)


def test_the_excess_is_the_covariance_between_the_one_scan_changes():
    """On jitter paths at 13 scans per second (T 1 s), the variance of the change over n scans less the sum of
    the n one-scan changes' variances (what composing one-scan covariances counts), by Monte Carlo, equals
    `span_excess` where it is positive (n up to 40 scans); over one scan it is 0, exactly."""
    V, T, dt, n_scans, paths = 3e-6, 1.0, 1 / 13, 60, 4000
    t = dt * np.arange(n_scans)
    K = V * np.exp(-np.square((t[:, None] - t[None, :]) / T))
    w, U = np.linalg.eigh(K)
    j = _rng(3).standard_normal((paths, n_scans)) @ (U * np.sqrt(np.clip(w, 0.0, None))).T
    changes = np.diff(j, axis=1)
    for n in (3, 13, 40):
        total = np.var(j[:, n:] - j[:, :-n], axis=0, ddof=1).mean()
        composed = n * np.var(changes, axis=0, ddof=1).mean()
        assert total - composed == pytest.approx(span_excess(t, n, (V, T)).mean(), rel=0.1), n
    assert np.all(span_excess(t, 1, (V, T)) == 0.0)


def test_the_excess_at_thirteen_scans_per_second():
    """At T = 1 s and 13 scans per second, what the docs quote: about 1.11 V over 1 s, 0 over one scan, and the
    absolute pose's excess positive until about 13 s ((T / dt)^2 scans) and 0 after it."""
    t = np.arange(400) / 13
    assert span_excess(t, 13, (1.0, 1.0)) == pytest.approx(1.11, abs=0.01)
    absolute = absolute_excess(t, (1.0, 1.0))
    assert absolute[1] == 0 and np.all(absolute[2:int(12.9 * 13)] > 0) and np.all(absolute[int(13.1 * 13):] == 0)


@given(dts=st.lists(st.floats(0.01, 0.5), min_size=2, max_size=60), V=st.floats(1e-8, 1e-4),
       T=st.floats(0.2, 5.0))
def test_the_absolute_excess_scan_by_scan_is_the_batch_one(dts, V, T):
    """`AbsoluteJitter`, as the odometry runs it, equals `absolute_excess` bit for bit on any scan times; both are
    0 at the first scan, never negative, and span_excess from the first scan is the same."""
    t = 10.0 + np.r_[0.0, np.cumsum(dts)]
    batch = absolute_excess(t, (V, T))
    running = AbsoluteJitter((V, T))
    running.start(t[0])
    np.testing.assert_array_equal([running.at(x) for x in t], batch)
    assert batch[0] == 0.0 and np.all(batch >= 0.0)
    assert span_excess(t, len(t) - 1, (V, T))[0] == pytest.approx(batch[-1], rel=1e-9, abs=1e-300)


def test_only_the_roll_and_pitch_variances_change():
    """A stack of covariances: the roll and pitch variances gain the given variances, every other element is
    unchanged; all zeros (the jitter off) return the covariances themselves."""
    rng = _rng(2)
    A = rng.standard_normal((5, 6, 6))
    P = A @ np.swapaxes(A, 1, 2)
    add = np.array([0.0, 1e-7, 5e-7, 1e-6, 3e-6])
    diff = with_roll_pitch_variance(P, add) - P
    for a in AXES:
        np.testing.assert_allclose(diff[:, a, a], add, rtol=1e-9, atol=1e-14)  # P ~ 1
        diff[:, a, a] = 0.0
    assert np.all(diff == 0.0) and AXES == (3, 4)
    assert with_roll_pitch_variance(P, np.zeros(5)) is P
    assert with_roll_pitch_variance(P, 0.0) is P


@pytest.mark.parametrize("bad", [(-1e-6, 1.0), (1e-6, 0.0), (1e-6, -1.0), (np.nan, 1.0), (1e-6, np.inf)])
def test_an_invalid_jitter_is_refused(bad):
    with pytest.raises(ValueError, match="attitude jitter"):
        attitude_jitter_array(bad)


def test_a_run_with_the_jitter_reports_and_replays_it():
    """The odometry with the jitter on: the same estimates and relative covariances as without it, the absolute
    pose covariance the one without it plus the jitter's excess since the first scan (roll and pitch only), the
    jitter in its states; replaying the stored covariances with it gives the reported absolute covariances, and
    the span measures read the run's own jitter."""
    from rodo import scenarios
    from rodo.estimator.config import OdometryConfig
    from rodo.validation import replayed_states as rs
    from rodo.validation.driver import run_sequence
    from rodo.validation.odometry_consistency import odometry_nees
    from rodo.validation.run_consistency import run_states

    seq, truth = scenarios.get("hills").simulate(3, duration=3.0)
    base = OdometryConfig.for_model("ca-polar")
    jitter = (4e-6, 0.5)
    config = base.replace(uncertainty=dataclasses.replace(base.uncertainty, attitude_jitter_variance=jitter[0],
                                                          attitude_jitter_time=jitter[1]))
    assert np.array_equal(attitude_jitter_of(config.uncertainty), jitter)
    on, off = (run_states(run_sequence(seq, c)) for c in (config, base))
    np.testing.assert_array_equal(on["attitude_jitter"], jitter)
    np.testing.assert_array_equal(off["attitude_jitter"], [0.0, 1.0])
    for key in ("T_vehicle_world", "P", "P_relative", "P_revision"):
        np.testing.assert_array_equal(on[key], off[key])
    expected = with_roll_pitch_variance(off["P_pose_absolute"], absolute_excess(on["t"], jitter))
    np.testing.assert_array_equal(on["P_pose_absolute"], expected)
    assert np.all(on["P_pose_absolute"][-1, 3:5, 3:5].diagonal() > off["P_pose_absolute"][-1, 3:5, 3:5].diagonal())

    tau = float(on["velocity_correlation_time"])
    replay = rs.absolute_covariances(on, tau, on["drift_rate_sigma"], jitter=on["attitude_jitter"])
    np.testing.assert_allclose(replay, on["P_pose_absolute"], rtol=1e-9, atol=1e-15)
    own, given_, none = (odometry_nees(on, truth, tau=tau, jitter=j)["relative_span"]
                         for j in (None, jitter, (0.0, 1.0)))
    np.testing.assert_array_equal(own, given_)
    finite = np.isfinite(own)
    assert finite.sum() > 10 and np.all(own[finite] < none[finite])  # more variance: every NEES smaller
