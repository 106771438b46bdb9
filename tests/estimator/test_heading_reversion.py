"""The heading's reversion in the drift recursion (rodo.estimator.heading_reversion): the reversion's closed form
against its differential equation, the recursion against Monte Carlo on SE(3) of the model it linearises, the
long-run growth it leaves, and every replay equal to the odometry's recursion."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.estimator.heading_reversion import ANCHOR, YAW, heading_reversion_matrix, state_size
from rodo.estimator.lie import se3
from rodo.estimator.uncertainty import DriftCovariance, _initial, _step, span_covariance
from rodo.validation.span_covariances import heading_deviations, span_covariances
from tests.estimator.test_uncertainty import N_MC, _mean_nees_in_bounds, _random_cov

HEADING = (0.4, 3.0)  # s: short, so that it shows within 20 scans


def _rng(*key):
    return np.random.default_rng(np.random.SeedSequence([2026, 30, *key]))


def _euler(yaw, a, dt, T_r, T_a, n=400):
    """The reversion's differential equation, d yaw = -(yaw - a) / T_r dt, d a = (yaw - a) / T_a dt, by n
    explicit Euler steps (an independent reference for the closed form)."""
    h = dt / n
    for _ in range(n):
        d = yaw - a
        yaw, a = yaw - h * d / T_r, a + h * d / T_a
    return yaw, a


@given(dt=st.floats(0.01, 2.0), T_r=st.floats(0.1, 20.0), T_a=st.floats(1.0, 500.0),
       yaw=st.floats(-1.0, 1.0), a=st.floats(-1.0, 1.0))
@settings(max_examples=40, deadline=None)
def test_the_closed_form_is_the_differential_equation(dt, T_r, T_a, yaw, a):
    """`heading_reversion_matrix` moves (yaw, anchor) as the reversion's ODE integrated finely does, keeps the
    weighted mean T_r yaw + T_a a, and leaves every other state alone."""
    M = heading_reversion_matrix(dt, (T_r, T_a))
    x = np.zeros(19)
    x[YAW], x[ANCHOR], x[0], x[11] = yaw, a, 0.3, -0.2
    y = M @ x
    want = _euler(yaw, a, dt, T_r, T_a, n=4000)
    assert y[YAW] == pytest.approx(want[0], abs=1e-4 * (abs(yaw) + abs(a)) + 1e-12)
    assert y[ANCHOR] == pytest.approx(want[1], abs=1e-4 * (abs(yaw) + abs(a)) + 1e-12)
    assert T_r * y[YAW] + T_a * y[ANCHOR] == pytest.approx(T_r * yaw + T_a * a, abs=1e-12 * (T_r + T_a))
    assert (y[0], y[11]) == (0.3, -0.2)


def _drive(rng, n=20):
    t = np.cumsum(np.r_[0.0, rng.uniform(0.05, 0.1, n - 1)])
    T = np.stack([se3.exp(np.array([-8.0 * s, 0.3 * s, 0.0, 0.01, -0.02, 0.4 * s])) for s in t])
    return t, T


def _monte_carlo(rng, T, t, Sigma_rel, P_varpi, tau, P0, heading):
    """Samples of the drift model with the heading's reversion on SE(3): before each step the sample's yaw error
    (of log(T_true T^-1)) and its anchor follow the reversion's ODE (`_euler`), then the true pose is
    exp(dt b_k + delta_k) R_k T_{k-1} as in test_uncertainty's model; the anchor starts at the yaw error."""
    T_r, T_a = heading
    T_true = se3.exp(rng.multivariate_normal(np.zeros(6), P0, size=N_MC)) @ T[0]
    anchor = se3.log(T_true @ se3.inverse(T[0]))[:, YAW]
    b = rng.multivariate_normal(np.zeros(6), P_varpi[0], size=N_MC)
    for k in range(1, len(t)):
        dt = t[k] - t[k - 1]
        xi = se3.log(T_true @ se3.inverse(T[k - 1]))
        xi[:, YAW], anchor = _euler(xi[:, YAW], anchor, dt, T_r, T_a, n=50)
        T_true = se3.exp(xi) @ T[k - 1]
        phi = np.exp(-dt / tau)
        b = phi * b + rng.multivariate_normal(np.zeros(6), (1 - phi**2) * P_varpi[k], size=N_MC)
        d = rng.multivariate_normal(np.zeros(6), Sigma_rel[k], size=N_MC)
        T_true = se3.exp(dt * b + d) @ T[k] @ se3.inverse(T[k - 1]) @ T_true
    return se3.log(T_true @ se3.inverse(T[-1]))


def test_the_recursion_matches_monte_carlo_of_the_reverting_model():
    """The absolute covariance with the reversion against samples of the model (yaw-heavy noise over 20 turning
    scans, T_r 0.4 s): inside the 99.9 % bounds; the recursion without the reversion is not (it lets the yaw
    random-walk)."""
    rng = _rng(1)
    t, T = _drive(rng)
    yaw_heavy = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, 30.0])
    Sigma_rel = np.stack([yaw_heavy @ _random_cov(rng, 2e-4) @ yaw_heavy for _ in t])
    P_varpi = np.stack([yaw_heavy @ _random_cov(rng, 1e-3) @ yaw_heavy for _ in t])
    P0, tau = _random_cov(rng, 1e-4), 0.3
    on, off = DriftCovariance(P0, P_varpi[0], tau, heading=HEADING), DriftCovariance(P0, P_varpi[0], tau)
    for k in range(1, len(t)):
        P_on = on.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k])
        P_off = off.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k])
    xi = _monte_carlo(rng, T, t, Sigma_rel, P_varpi, tau, P0, HEADING)
    ok, info = _mean_nees_in_bounds(xi, P_on)
    assert ok, info
    assert not _mean_nees_in_bounds(xi, P_off)[0]
    assert P_on[YAW, YAW] < 0.5 * P_off[YAW, YAW]


@given(T_r=st.floats(0.5, 5.0), ratio=st.floats(5.0, 50.0))
@settings(max_examples=10, deadline=None)
def test_the_yaw_still_random_walks_at_the_reduced_rate(T_r, ratio):
    """Yaw noise q per scan alone, standing still: the yaw variance grows, over spans much longer than T_r, at
    r^2 q per scan, r = T_r / (T_r + T_a) (the weighted mean's random walk), not at q."""
    T_a, dt, q = ratio * T_r, 0.1, 1e-6
    Sigma = np.zeros((6, 6))
    Sigma[YAW, YAW] = q
    C = _initial(np.zeros((6, 6)), np.zeros((6, 6)), 0.0, None, (T_r, T_a))
    var = []
    for k in range(int(40 * (T_r + T_a) / dt)):
        C = _step(C, np.eye(4), np.eye(4), dt, Sigma, np.zeros((6, 6)), 0.0, (T_r, T_a))
        var.append(C[YAW, YAW])
    n = len(var) // 2
    r = T_r / (T_r + T_a)
    assert (var[-1] - var[n - 1]) / (len(var) - n) == pytest.approx(r * r * q, rel=0.05)


def _step_without_reversion(C, T_prev, T_new, dt, Sigma_rel, P_varpi, tau):
    """`uncertainty._step` as it was before the heading's reversion (session 29), verbatim: the reference the
    18-state path must still equal bit for bit."""
    phi = np.exp(-dt / tau) if tau > 0 else 0.0
    R = T_new @ se3.inverse(T_prev)
    A = np.zeros((18, 18))
    A[:6, :6] = se3.adjoint(R)
    A[:6, 6:12] = dt * phi * np.eye(6)
    A[6:12, 6:12] = phi * np.eye(6)
    A[:6, 12:] = np.linalg.norm(R[:3, 3]) * np.eye(6)
    A[12:, 12:] = np.eye(6)
    W = (1.0 - phi**2) * P_varpi if tau > 0 else np.zeros((6, 6))
    Q = np.zeros((18, 18))
    Q[:6, :6] = dt * dt * W + Sigma_rel
    Q[:6, 6:12] = Q[6:12, :6] = dt * W
    Q[6:12, 6:12] = W
    C = A @ C @ A.T + Q
    return 0.5 * (C + C.T)


def test_off_is_the_recursion_as_it_was_bit_for_bit():
    """Without the reversion the step is the 18-state one as it was before the reversion existed, bit for bit
    (`_step_without_reversion`), over a turning drive."""
    rng = _rng(5)
    t, T = _drive(rng, 60)
    Sigma_rel, P_varpi = _random_cov(rng, 2e-3), _random_cov(rng, 1e-2)
    C = _initial(_random_cov(rng, 1e-3), P_varpi, 0.3, [1e-4] * 6)
    want = C.copy()
    for k in range(1, len(t)):
        C = _step(C, T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel, P_varpi, 0.3, None)
        want = _step_without_reversion(want, T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel, P_varpi, 0.3)
    assert C.shape == (18, 18)
    np.testing.assert_array_equal(C, want)


def test_the_anchor_starts_at_the_yaw_error():
    """At a start the anchor is the yaw error itself (its row and column the yaw's): no deviation to revert."""
    rng = _rng(6)
    C = _initial(_random_cov(rng, 1e-2), _random_cov(rng, 1e-2), 0.3, [1e-4] * 6, HEADING)
    np.testing.assert_array_equal(C[ANCHOR, :ANCHOR], C[YAW, :ANCHOR])
    np.testing.assert_array_equal(C[:ANCHOR, ANCHOR], C[:ANCHOR, YAW])
    assert C[ANCHOR, ANCHOR] == C[YAW, YAW] > 0
    assert DriftCovariance(_random_cov(rng, 1e-2), np.eye(6), 0.3, None, HEADING).deviation == pytest.approx(0.0,
                                                                                                              abs=1e-18)


def test_a_span_carries_the_deviation_it_starts_with():
    """Yaw noise alone, standing still: the relative yaw over a span from scan k0 of a running recursion has the
    variance of the exact joint (yaw, anchor, the yaw at k0) propagated by the ODE's own flow (`_euler`), when the
    span starts with the run's deviation; without it (a span from an anchor at the start pose) it is smaller."""
    T_r, T_a, dt, q = 1.5, 20.0, 0.1, 1e-6
    m = np.array([_euler(1.0, 0.0, dt, T_r, T_a), _euler(0.0, 1.0, dt, T_r, T_a)]).T  # columns: images of e_yaw, e_a
    Sigma = np.zeros((6, 6))
    Sigma[YAW, YAW] = q
    zeros, eye4 = np.zeros((6, 6)), np.eye(4)
    k0, n = 300, 40
    drift = DriftCovariance.at_first_scan(zeros, 0.0, None, (T_r, T_a))
    J = np.zeros((3, 3))  # Cov of (yaw, a, yaw at k0), exact for the linear model
    for k in range(1, k0 + n + 1):
        if k == k0 + 1:
            J[2, :2] = J[:2, 0]
            J[:2, 2] = J[0, :2]
            J[2, 2] = J[0, 0]
        if k <= k0:
            drift.update(eye4, eye4, dt, Sigma, zeros)
        A = np.eye(3)
        A[:2, :2] = m
        J = A @ J @ A.T
        J[0, 0] += q
    exact = J[0, 0] + J[2, 2] - 2 * J[0, 2]
    T = np.tile(eye4, (k0 + n + 1, 1, 1))
    t = dt * np.arange(k0 + n + 1)
    S = np.tile(Sigma, (len(t), 1, 1))
    span = span_covariance(T, t, S, np.zeros_like(S), k0, k0 + n, 0.0, None, None, (T_r, T_a), drift.deviation)
    assert span[YAW, YAW] == pytest.approx(exact, rel=2e-3)
    without = span_covariance(T, t, S, np.zeros_like(S), k0, k0 + n, 0.0, None, None, (T_r, T_a))
    assert without[YAW, YAW] < 0.9 * exact


def test_off_is_the_recursion_without_it_bit_for_bit():
    """A reversion time of 0 (or none) is the 18-state recursion, whatever the anchor time: the same arrays."""
    rng = _rng(2)
    t, T = _drive(rng)
    Sigma_rel = np.stack([_random_cov(rng, 2e-3) for _ in t])
    P_varpi = np.stack([_random_cov(rng, 1e-2) for _ in t])
    assert state_size(None) == state_size((0.0, 50.0)) == 18 and state_size(HEADING) == 19
    runs = [DriftCovariance.at_first_scan(P_varpi[0], 0.3, None, h) for h in (None, (0.0, 50.0))]
    for k in range(1, len(t)):
        a, b = (d.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k]) for d in runs)
        np.testing.assert_array_equal(a, b)


def test_the_compiled_step_equals_the_reference():
    """Two hundred scans of a turning drive with the reversion: `DriftCovariance.update` (compiled) within
    rounding of `_step`."""
    rng = _rng(3)
    t, T = _drive(rng, 200)
    Sigma_rel, P_varpi = _random_cov(rng, 2e-3), _random_cov(rng, 1e-2)
    drift = DriftCovariance.at_first_scan(_random_cov(rng, 1e-3), 0.35, [1e-4] * 6, HEADING)
    C = drift.C.copy()
    for k in range(1, len(t)):
        drift.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel, P_varpi)
        C = _step(C, T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel, P_varpi, 0.35, HEADING)
    np.testing.assert_allclose(drift.C, C, rtol=1e-9, atol=1e-18)


def test_span_covariances_equal_span_covariance_with_the_reversion():
    """The batched spans equal `span_covariance` with the reversion and each start's deviation, across a restart
    too, and the restart sets the anchor to the new yaw error: to rounding (1e-12; bit for bit on the Intel CPUs
    this was written on, while an AMD EPYC's OpenBLAS kernels round a product's rows and batches differently, by
    an ulp)."""
    rng = _rng(4)
    t, T = _drive(rng, 40)
    Sigma_rel = np.stack([_random_cov(rng, 2e-3) for _ in t])
    P_varpi = np.stack([_random_cov(rng, 1e-2) for _ in t])
    restarts = np.zeros(len(t), bool)
    restarts[17] = True
    drift = DriftCovariance.at_first_scan(P_varpi[0], 0.3, [1e-4] * 6, HEADING)
    for k in range(1, len(t)):
        if restarts[k]:
            drift.restart(T[k - 1], T[k], Sigma_rel[k])
            np.testing.assert_allclose(drift.C[ANCHOR, :ANCHOR], drift.C[YAW, :ANCHOR], rtol=1e-12, atol=0)
            assert drift.C[ANCHOR, ANCHOR] == pytest.approx(drift.C[YAW, YAW], rel=1e-12, abs=0)
        else:
            drift.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k])
    deviations = heading_deviations(T, t, Sigma_rel, P_varpi, 0.3, [1e-4] * 6, restarts, HEADING)
    assert deviations[0] == deviations[17] == 0.0 and np.all(deviations[1:17] > 0)  # zero at each (re)start
    for n in (1, 5, 13):
        batched = span_covariances(T, t, Sigma_rel, P_varpi, n, 0.3, [1e-4] * 6, restarts, HEADING, deviations)
        for k in range(n, len(t)):
            want = span_covariance(T, t, Sigma_rel, P_varpi, k - n, k, 0.3, [1e-4] * 6, restarts, HEADING,
                                   deviations[k - n])
            np.testing.assert_allclose(batched[k - n], want, rtol=1e-12, atol=1e-15 * np.abs(want).max())
    # from the run's first scan the span is the absolute recursion from a known pose
    whole = span_covariance(T, t, Sigma_rel, P_varpi, 0, 16, 0.3, [1e-4] * 6, restarts, HEADING)
    drift = DriftCovariance.at_first_scan(np.zeros((6, 6)), 0.3, [1e-4] * 6, HEADING)
    for k in range(1, 17):
        P = drift.update(T[k - 1], T[k], t[k] - t[k - 1], Sigma_rel[k], P_varpi[k])
    np.testing.assert_allclose(whole, P, rtol=1e-9, atol=1e-18)


def test_a_run_with_the_reversion_reports_and_replays_it():
    """The odometry with the reversion on writes it to its states, and replaying the run's stored covariances
    with it gives the absolute covariances the run reported (and without it others)."""
    import dataclasses

    from rodo import scenarios
    from rodo.estimator.config import OdometryConfig
    from rodo.validation import replayed_states as rs
    from rodo.validation.driver import run_sequence
    from rodo.validation.run_consistency import run_states

    seq, _ = scenarios.get("hills").simulate(3, duration=4.0)
    config = OdometryConfig.for_model("ca-polar")
    config = config.replace(uncertainty=dataclasses.replace(config.uncertainty, heading_reversion_time=1.0,
                                                            heading_anchor_time=20.0))
    states = run_states(run_sequence(seq, config))
    np.testing.assert_array_equal(states["heading_reversion"], [1.0, 20.0])
    tau = float(states["velocity_correlation_time"])
    replay = rs.absolute_covariances(states, tau, states["drift_rate_sigma"], states["heading_reversion"])
    np.testing.assert_allclose(replay, states["P_pose_absolute"], rtol=1e-9, atol=1e-15)
    off = rs.absolute_covariances(states, tau, states["drift_rate_sigma"])
    assert not np.allclose(off[-1], states["P_pose_absolute"][-1], rtol=1e-3)
