"""The stationary pose error beside the drift recursion (`estimator.stationary_error`)."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, strategies as st

from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.estimator.lie import se3
from rodo.estimator.stationary_error import KEEP, one_scan_change, span_term, stationary_error_array, taken_out
from rodo.validation import replayed_states as rs
from rodo.validation.driver import run_sequence
from rodo.validation.error_growth import error_growth
from rodo.validation.odometry_consistency import matched_run, matched_span_terms

ON = np.array([[4e-4, 9e-4, 1e-4, 2e-7, 3e-7, 5e-6], [0.5, 1.0, 2.0, 5.0, 1.0, 0.5]])


def _rng(*key):
    return np.random.default_rng(np.random.SeedSequence([2026, 12, 6, *key]))


def test_span_term_is_the_covariance_of_a_sampled_stationary_error():
    """Exponentially correlated errors sampled exactly at a span's two ends (an Ornstein-Uhlenbeck step per axis),
    s_k - Ad(T_k T_j^-1) s_j: their sample covariance is span_term's, the lever arm's lateral-yaw term too."""
    rng = _rng(1)
    T_j = se3.exp(np.array([1.0, -2.0, 0.3, 0.02, -0.01, 0.4]))
    T_k = se3.exp(np.array([12.0, 0.5, 0.1, -0.01, 0.02, 0.5])) @ T_j  # 12 m forward: a lever arm
    L, V, T = 0.7, ON[0], ON[1]
    n = 200_000
    s_j = rng.standard_normal((n, 6)) * np.sqrt(V)
    rho = np.exp(-L / T)
    s_k = rho * s_j + rng.standard_normal((n, 6)) * np.sqrt(V * (1 - rho**2))
    e = s_k - s_j @ se3.adjoint(T_k @ se3.inverse(T_j)).T
    C = span_term(T_k, T_j, L, ON)
    sample = np.cov(e.T)
    sd = np.sqrt(np.outer(np.diag(C), np.diag(C)))
    assert np.all(np.abs(sample - C) < 0.02 * sd)  # ~4.5 standard errors of a correlation at n = 2e5
    assert C[1, 5] < 0 and abs(C[1, 5]) > 0.3 * sd[1, 5]  # the yaw at the start moves the lateral position
    np.testing.assert_allclose(span_term(T_j, T_j, 0.0, ON), np.zeros((6, 6)), atol=1e-18)


def test_span_term_tends_to_twice_the_variance_without_motion():
    """Without motion the change over L per axis is 2 V (1 - exp(-L / T)): the one-scan change over dt, 2 V over
    long spans."""
    eye = np.eye(4)
    for L in (0.077, 1.0, 100.0):
        np.testing.assert_allclose(np.diag(span_term(eye, eye, L, ON)), 2 * ON[0] * (1 - np.exp(-L / ON[1])))
    np.testing.assert_allclose(one_scan_change(0.077, ON), 2 * ON[0] * (1 - np.exp(-0.077 / ON[1])))


@st.composite
def _covariances(draw):
    seed = draw(st.integers(0, 2**32 - 1))
    scale = draw(st.floats(1e-8, 1e-2))
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((6, 6)) * scale ** 0.5
    return A @ A.T + 1e-12 * np.eye(6)


@given(_covariances(), st.floats(0.01, 0.2))
def test_taken_out_keeps_a_covariance_and_lowers_each_variance_by_the_change(P, dt):
    """Each variance falls by the one-scan change, or to KEEP of itself where it holds less; the result stays
    positive semi-definite with the same correlations."""
    out = taken_out(P, dt, ON)
    d = one_scan_change(dt, ON)
    v = np.diag(P)
    np.testing.assert_allclose(np.diag(out), v - np.minimum(d, (1 - KEEP) * v), rtol=1e-9)
    assert np.linalg.eigvalsh(out).min() >= -1e-12 * np.abs(v).max()
    corr = lambda M: M / np.sqrt(np.outer(np.diag(M), np.diag(M)))  # noqa: E731
    np.testing.assert_allclose(corr(out), corr(P), atol=1e-9)
    assert taken_out(P, dt, None) is P


def test_a_bad_stationary_error_is_refused():
    for bad in ([[1.0] * 6, [0.0] * 6], [[-1.0] * 6, [1.0] * 6], [[np.nan] * 6, [1.0] * 6]):
        with pytest.raises(ValueError, match="stationary error"):
            stationary_error_array(bad)
    np.testing.assert_array_equal(stationary_error_array(None), [[0.0] * 6, [1.0] * 6])


@pytest.fixture(scope="module")
def runs():
    """A short city run with the stationary error off and on (the estimate is the same: reported covariances
    only)."""
    seq, truth = scenarios.get("city").simulate(3, 6.0)
    base = OdometryConfig.for_model("ca-polar")
    unc = dataclasses.replace(base.uncertainty, velocity_correlation_time=0.4, registration_correlation=0.5,
                              stationary_variance=tuple(ON[0]), stationary_time=tuple(ON[1]))
    off = run_sequence(seq, base.replace(uncertainty=dataclasses.replace(unc, stationary_variance=(0.0,) * 6)))
    on = run_sequence(seq, base.replace(uncertainty=unc))
    return off.state_arrays(), on.state_arrays(), truth


def test_a_replay_equals_the_run_with_the_stationary_error(runs):
    """The run's absolute covariances, the stationary error's change since its first scan added, are the
    replay's, and replayed without it they are the run's without it; the estimate is the same."""
    off, on, _ = runs
    np.testing.assert_array_equal(on["T_vehicle_world"], off["T_vehicle_world"])
    np.testing.assert_array_equal(on["stationary_error"], ON)
    tau, drift = 0.4, on["drift_rate_sigma"]
    np.testing.assert_allclose(rs.absolute_covariances(on, tau, drift, stationary=ON), on["P_pose_absolute"],
                               rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(rs.absolute_covariances(on, tau, drift), off["P_pose_absolute"], rtol=1e-9,
                               atol=1e-15)
    np.testing.assert_array_equal(on["P_pose_absolute"][0], off["P_pose_absolute"][0])
    assert not np.allclose(on["P_pose_absolute"][-1], off["P_pose_absolute"][-1], rtol=1e-3)


def test_the_one_scan_span_is_the_runs_own_and_longer_spans_change(runs):
    """Over one scan the measures compose the unreduced inputs: bit for bit the run without the model; over a
    second the covariance changes, and the error growth reads the run's own stationary error."""
    off, on, truth = runs
    m_off, m_on = (matched_run(s, truth, 1e-6, 0.4, None, None) for s in (off, on))
    e0, C0, _, _ = matched_span_terms(m_off, 1)
    e1, C1, _, _ = matched_span_terms(m_on, 1)
    np.testing.assert_array_equal(C1, C0)
    np.testing.assert_array_equal(e1, e0)
    _, C0, _, _ = matched_span_terms(m_off, 13)
    _, C1, _, _ = matched_span_terms(m_on, 13)
    assert not np.allclose(C1, C0, rtol=1e-3)
    g_off, g_on = error_growth(off, truth), error_growth(on, truth)
    np.testing.assert_array_equal(g_on["z2"][0], g_off["z2"][0])
    assert not np.allclose(g_on["z2"][2], g_off["z2"][2], rtol=1e-3)
    longer = error_growth(on, truth, spans=(0.5, 1.0))  # matched without the one-scan inputs: the same rows
    np.testing.assert_array_equal(longer["z2"][:2], g_on["z2"][1:3])
    with pytest.raises(ValueError, match="one-scan inputs"):
        matched_span_terms(matched_run(on, truth, 1e-6, 0.4, None, None, one_scan=False), 1)
