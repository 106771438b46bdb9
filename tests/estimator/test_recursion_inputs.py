"""estimator/uncertainty.py's `recursion_inputs`: what the drift recursion composes for a registered scan, with the
registration's correlation (one share, or one per axis) and the velocity error's share (with its growth with the
speed), checked against the closed-form AR(1) sum of a vehicle at rest."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.estimator.uncertainty import recursion_inputs, registration_shares, span_covariance
from tests.estimator.test_uncertainty import _random_cov


@settings(max_examples=10, deadline=None)
@given(alpha=st.floats(0.0, 1.0), g=st.floats(0.05, 1.0), tau=st.floats(0.05, 2.0), n=st.integers(2, 20),
       seed=st.integers(0, 2**32 - 1))
def test_a_correlated_registration_keeps_one_scan_and_grows_a_span(alpha, g, tau, n, seed):
    """`recursion_inputs` at the registration's correlation alpha and the velocity error's share g, for a vehicle
    at rest (every Ad the identity) with constant Sigma_rel and P_varpi: one scan composes Sigma_rel + g dt^2
    P_varpi whatever alpha, and a span of n scans the AR(1) sum n (1 - alpha) Sigma_rel + dt^2 P' (n + 2 sum_k
    (n - k) phi^k), P' = g P_varpi + alpha Sigma_rel / dt^2, phi = exp(-dt / tau); at alpha 0 and g 1 the inputs
    themselves, bit for bit."""
    rng = np.random.default_rng(np.random.SeedSequence([39, seed]))
    dt, m = 0.077, n + 3
    t = dt * np.arange(m)
    T = np.stack([np.eye(4)] * m)
    Sigma, P = _random_cov(rng, 1e-3), _random_cov(rng, 1e-2)
    S_k, P_k = recursion_inputs(np.stack([Sigma] * m), np.stack([P] * m), np.full(m, dt), alpha, g)
    one = span_covariance(T, t, S_k, P_k, 1, 2, tau)
    np.testing.assert_allclose(one, Sigma + g * dt**2 * P, rtol=1e-9, atol=1e-15)
    phi = np.exp(-dt / tau)
    P_prime = g * P + alpha * Sigma / dt**2
    expected = n * (1 - alpha) * Sigma + dt**2 * P_prime * (n + 2 * sum((n - k) * phi**k for k in range(1, n)))
    np.testing.assert_allclose(span_covariance(T, t, S_k, P_k, 1, 1 + n, tau), expected, rtol=1e-9, atol=1e-15)
    same = recursion_inputs(Sigma, P, dt, 0.0, 1.0)
    assert same[0] is Sigma and same[1] is P


@settings(max_examples=10, deadline=None)
@given(alpha=st.floats(0.0, 1.0), a=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6), g=st.floats(0.05, 1.0),
       tau=st.floats(0.05, 2.0), n=st.integers(2, 20), seed=st.integers(0, 2**32 - 1))
def test_a_registration_correlation_per_axis_grows_its_axis_alone(alpha, a, g, tau, n, seed):
    """`recursion_inputs` with a share per axis (`registration_shares`: alpha + (1 - alpha) a_i): at rest (every
    Ad the identity) a span of n scans is the AR(1) sum n B Sigma_rel B + dt^2 P' (n + 2 sum_k (n - k) phi^k),
    P' = g P_varpi + A Sigma_rel A / dt^2, A = diag(sqrt(alpha_i)), B = diag(sqrt(1 - alpha_i)); one scan keeps
    every axis's variance Sigma_rel,ii + g dt^2 P_varpi,ii; equal shares are the scalar alpha's (to rounding);
    per-axis shares of 0 are alpha itself, a float (the scalar's path, bit for bit)."""
    rng = np.random.default_rng(np.random.SeedSequence([50, seed]))
    dt, m = 0.077, n + 3
    t = dt * np.arange(m)
    T = np.stack([np.eye(4)] * m)
    Sigma, P = _random_cov(rng, 1e-3), _random_cov(rng, 1e-2)
    shares = registration_shares(alpha, a)
    if not any(a):
        assert shares == alpha and isinstance(shares, float)
        return
    np.testing.assert_allclose(shares, alpha + (1 - alpha) * np.asarray(a), rtol=0, atol=1e-15)
    S_k, P_k = recursion_inputs(np.stack([Sigma] * m), np.stack([P] * m), np.full(m, dt), shares, g)
    one = span_covariance(T, t, S_k, P_k, 1, 2, tau)
    np.testing.assert_allclose(np.diag(one), np.diag(Sigma + g * dt**2 * P), rtol=1e-9, atol=1e-15)
    A, B = np.diag(np.sqrt(shares)), np.diag(np.sqrt(1 - shares))
    phi = np.exp(-dt / tau)
    P_prime = g * P + A @ Sigma @ A / dt**2
    expected = n * B @ Sigma @ B + dt**2 * P_prime * (n + 2 * sum((n - k) * phi**k for k in range(1, n)))
    np.testing.assert_allclose(span_covariance(T, t, S_k, P_k, 1, 1 + n, tau), expected, rtol=1e-9, atol=1e-15)
    equal = recursion_inputs(Sigma, P, dt, np.full(6, shares[0]), g)
    scalar = recursion_inputs(Sigma, P, dt, float(shares[0]), g)
    for x, y in zip(equal, scalar):
        np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-18)


@settings(max_examples=10, deadline=None)
@given(alpha=st.floats(0.0, 1.0), g=st.floats(0.01, 1.0), g_v=st.floats(0.0, 0.2), n=st.integers(2, 12),
       seed=st.integers(0, 2**32 - 1))
def test_the_velocity_error_share_grows_with_the_speed(alpha, g, g_v, n, seed):
    """`recursion_inputs` with the share's growth g_v per m/s: each scan's velocity error variance is (g + g_v
    v_k) P_varpi,k (+ alpha Sigma_rel / dt^2), so one scan composes Sigma_rel + (g + g_v v_k) dt^2 P_varpi at its
    own speed, a scan at rest g dt^2 P_varpi; a stack is the scans one by one; g_v 0 is the share alone, bit for
    bit."""
    rng = np.random.default_rng(np.random.SeedSequence([40, seed]))
    dt, m = 0.077, n + 3
    t = dt * np.arange(m)
    T = np.stack([np.eye(4)] * m)
    Sigma, P = _random_cov(rng, 1e-3), _random_cov(rng, 1e-2)
    speed = rng.uniform(0.0, 20.0, size=m)
    speed[2] = 0.0
    S_k, P_k = recursion_inputs(np.stack([Sigma] * m), np.stack([P] * m), np.full(m, dt), alpha, g, g_v, speed)
    for k in range(m):
        one = recursion_inputs(Sigma, P, dt, alpha, g, g_v, speed[k])
        np.testing.assert_array_equal(S_k[k], one[0])
        np.testing.assert_array_equal(P_k[k], one[1])
        np.testing.assert_allclose(one[1], (g + g_v * speed[k]) * P + alpha * Sigma / dt**2, rtol=1e-12)
    tau = 1e-9  # no memory: one scan's velocity error is its own
    for k in (2, m - 1):
        np.testing.assert_allclose(span_covariance(T, t, S_k, P_k, k - 1, k, tau),
                                   (1 - alpha) * Sigma + dt**2 * P_k[k], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(P_k[2], g * P + alpha * Sigma / dt**2, rtol=1e-12)  # at rest
    alone = recursion_inputs(np.stack([Sigma] * m), np.stack([P] * m), np.full(m, dt), alpha, g)
    zero = recursion_inputs(np.stack([Sigma] * m), np.stack([P] * m), np.full(m, dt), alpha, g, 0.0, speed)
    np.testing.assert_array_equal(alone[1], zero[1])
