"""The sliding window's compiled kernels against NumPy: the pairs' linearisation (`measurement_kernels.
state_pairs`), the motion-prior residuals, their SE(3) logarithm and Jacobians and their normal equations
(`motion_kernels`), and the batched state update. The assembly of them all, and the solver, are in
test_window.py."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rodo.estimator import measurement_kernels as kernel
from rodo.estimator import measurements
from rodo.estimator.lie import se3
from rodo.estimator.motion import motion_prior
from rodo.estimator.state import State
from tests.estimator import scene
from tests.strategies import hypothesis_rngs


def _random_sets(rng, K, m, model):
    T = np.stack([se3.exp(rng.normal(size=6) * np.array([3, 3, 0.5, 0.05, 0.05, 0.3])) for _ in range(K)])
    varpi = rng.normal(size=(K, 6)) * np.array([10, 1, 0.5, 0.05, 0.05, 0.3])
    sets = []
    for k in range(K):
        p_sensor = np.c_[rng.uniform(5, 80, m), rng.uniform(-30, 30, m), rng.uniform(-3, 5, m)]
        p_world = se3.transform_points(se3.inverse(T[k]) @ scene.T_VEHICLE_SENSOR, p_sensor)
        z = measurements.predict(model, T[k], varpi[k], p_world, scene.T_VEHICLE_SENSOR).z
        z = z + rng.normal(size=z.shape) * np.array([0.05, 0.01, 0.01, 0.02])
        A = rng.normal(size=(4, 4)) * rng.uniform(0.5, 2.0, size=(m, 1, 1))  # one shape per set, scaled per pair
        W = A @ np.swapaxes(A, 1, 2) + np.eye(4)
        sets.append((p_world, z, W))
    return T, varpi, sets


@pytest.mark.parametrize("model", measurements.MODELS)
@given(rng=hypothesis_rngs())
@settings(max_examples=10, suppress_health_check=[HealthCheck.large_base_example])  # 3 states x 8 pairs
def test_kernel_matches_numpy_linearisation(model, rng):
    """The fused kernel's H = sum w J^T W J and b = -sum w J^T W e equal those from measurements.predict
    (states, points, noise and weights drawn through hypothesis, so a failure shrinks)."""
    K, m = 3, 8
    T, varpi, sets = _random_sets(rng, K, m, model)
    offsets = np.arange(K + 1, dtype=np.int64) * m
    p = np.concatenate([s[0] for s in sets])
    z = np.concatenate([s[1] for s in sets])
    W = np.concatenate([s[2] for s in sets])
    w = rng.uniform(0.2, 1.0, K * m)
    d2 = np.empty(K * m)
    # state 0 seen by the scene's radar, the others by radars mounted elsewhere (multi-radar odometry)
    mounting = np.array([1.0, 0.5, 0.3, 0.05, 0.05, 1.0])
    Tvs = np.stack([scene.T_VEHICLE_SENSOR] + [se3.exp(rng.normal(size=6) * mounting) @ scene.T_VEHICLE_SENSOR
                                                 for _ in range(K - 1)])
    H, b = np.zeros((K, 12, 12)), np.zeros((K, 12))
    code = kernel.POLAR if model == "polar" else kernel.CARTESIAN
    cost = sum(kernel.state_pairs(code, T[k], varpi[k], offsets[k], offsets[k + 1], p, z, W, Tvs[k], w, d2, 3.0,
                                  H[k], b[k]) for k in range(K))
    total = 0.0
    for k in range(K):
        sl = slice(k * m, (k + 1) * m)
        pred = measurements.predict(model, T[k], varpi[k], p[sl], Tvs[k])
        e = measurements.residual(model, z[sl], pred.z)
        J = np.concatenate([pred.J_z_xi, pred.J_z_varpi], axis=2)
        WJ = W[sl] @ J * w[sl, None, None]
        np.testing.assert_allclose(H[k], np.einsum("mai,maj->ij", J, WJ), rtol=1e-9, atol=1e-8)
        np.testing.assert_allclose(b[k], -np.einsum("mai,ma->i", WJ, e), rtol=1e-9, atol=1e-8)
        d2k = np.einsum("ma,mab,mb->m", e, W[sl], e)
        # absolute floor: e is a difference of ~100 m quantities, so d2 carries ~1e-14 m rounding in e
        np.testing.assert_allclose(d2[sl], d2k, rtol=1e-10, atol=1e-15)
        total += 0.5 * np.sum(w[sl] * d2k)
    assert cost == pytest.approx(total, rel=1e-10, abs=1e-14)


def _reference_terms(model, T, varpi, p, z, W, Tvs, w):
    """H = sum w J^T W J, b = -sum w J^T W e and d2 of one state's pairs, from measurements.predict."""
    pred = measurements.predict(model, T, varpi, p, Tvs)
    e = measurements.residual(model, z, pred.z)
    J = np.concatenate([pred.J_z_xi, pred.J_z_varpi], axis=2)
    WJ = W @ J * w[:, None, None]
    return np.einsum("mai,maj->ij", J, WJ), -np.einsum("mai,ma->i", WJ, e), np.einsum("ma,mab,mb->m", e, W, e)


@pytest.mark.parametrize("model", measurements.MODELS)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(kernel.BLOCK, 2 * kernel.BLOCK + 3),  # two or three blocks
       lo=st.integers(0, 5), c=st.sampled_from([0.0, 2.0]))
@settings(max_examples=10, deadline=None)
def test_kernel_over_blocks_with_cauchy_weights_and_a_point_at_the_sensor(model, seed, m, lo, c):
    """Over two or three blocks of pairs lo:hi inside a longer pack (a few pairs: the test above): the Cauchy
    weights of the pairs whose weight is negative are set from their d2 (1 when robust_c is 0), and H, b, d2
    equal the reference with those weights; the pack's other pairs are left as they were. A map point at the
    sensor adds no term to H and b, keeps its weight, and makes its d2 and the cost NaN."""
    rng = np.random.default_rng(np.random.SeedSequence(seed))  # ~10 draws a pair: too many to draw through hypothesis
    n = lo + m + 1 + 3  # 3 pairs after hi
    T, varpi, sets = _random_sets(rng, 1, n, model)
    p, z, W = (np.array(x) for x in sets[0])
    hi = lo + m + 1
    at_sensor = int(rng.integers(lo, hi))
    p[at_sensor] = se3.transform_points(se3.inverse(T[0]) @ scene.T_VEHICLE_SENSOR, np.zeros((1, 3)))[0]
    w = np.where(rng.uniform(size=n) < 0.5, -1.0, rng.uniform(0.2, 1.0, n))
    w_before, d2 = w.copy(), np.full(n, 7.0)
    H, b = np.zeros((12, 12)), np.zeros(12)
    code = kernel.POLAR if model == "polar" else kernel.CARTESIAN
    cost = kernel.state_pairs(code, T[0], varpi[0], lo, hi, p, z, W, scene.T_VEHICLE_SENSOR, w, d2, c, H, b)
    outside = np.r_[0:lo, hi:n]
    np.testing.assert_array_equal(w[outside], w_before[outside])
    np.testing.assert_array_equal(d2[outside], 7.0)
    keep = np.setdiff1d(np.arange(lo, hi), [at_sensor])
    H_ref, b_ref, d2_ref = _reference_terms(model, T[0], varpi[0], p[keep], z[keep], W[keep],
                                            scene.T_VEHICLE_SENSOR, np.ones(m))
    cauchy = 1.0 / (1.0 + d2_ref / c**2) if c > 0 else np.ones(m)
    assert np.isnan(cost) and np.isnan(d2[at_sensor]) and w[at_sensor] == w_before[at_sensor]
    np.testing.assert_allclose(d2[keep], d2_ref, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(w[keep], np.where(w_before[keep] < 0, cauchy, w_before[keep]), rtol=1e-10)
    H_ref, b_ref, _ = _reference_terms(model, T[0], varpi[0], p[keep], z[keep], W[keep], scene.T_VEHICLE_SENSOR,
                                       w[keep])
    np.testing.assert_allclose(H, H_ref, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(b, b_ref, rtol=1e-9, atol=1e-8)


@pytest.mark.parametrize("kind", ["ca", "cv"])
def test_batched_motion_residuals_equal_the_priors_residual(kind):
    """MotionModel.residuals (the window's single path) = the prior's own residual, pair by pair."""
    rng = np.random.default_rng(4)
    motion = motion_prior(kind, (2.0, 0.05, 0.05, 1e-3, 1e-3, 0.05))
    states = [State(0.1 * k + 0.01 * k**2, se3.exp(rng.normal(size=6) * 0.5), rng.normal(size=6),
                    rng.normal(size=6) if kind == "ca" else None) for k in range(4)]
    E, J1, J2 = motion.residuals(states)
    for k, (a, b) in enumerate(zip(states[:-1], states[1:])):
        args = (a.T_vehicle_world, a.varpi, a.varpi_dot, b.T_vehicle_world, b.varpi, b.varpi_dot) if kind == "ca" \
            else (a.T_vehicle_world, a.varpi, b.T_vehicle_world, b.varpi)
        e, j1, j2 = motion.prior.residual(*args, b.t - a.t)
        np.testing.assert_allclose(E[k], e, atol=1e-12)
        np.testing.assert_allclose(J1[k], j1, atol=1e-10)
        np.testing.assert_allclose(J2[k], j2, atol=1e-12)


@pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-4, 0.3, 1.5, 3.1])
def test_motion_kernel_log_and_jacobians_match_lie(scale):
    """The compiled SE(3) logarithm and inverse left Jacobians = estimator.lie's, from the identity through
    the Taylor range (< 1 rad) and the closed forms up to near pi."""
    from rodo.estimator.lie import kernels as lie_kernels

    rng = np.random.default_rng(int(scale * 1e3) + 1)
    for _ in range(20):
        xi = rng.normal(size=6)
        xi[3:] *= scale / np.linalg.norm(xi[3:])
        T = se3.exp(xi)
        out, Jp, Jm = np.empty(6), np.empty((6, 6)), np.empty((6, 6))
        lie_kernels.se3_log_and_jac_inv(T, out, Jp, Jm)
        ref = se3.log(T)
        np.testing.assert_allclose(out, ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(Jp, se3.left_jacobian_inv(ref), rtol=1e-9, atol=1e-11)
        np.testing.assert_allclose(Jm, se3.left_jacobian_inv(-ref), rtol=1e-9, atol=1e-11)


@pytest.mark.parametrize("kind", ["ca", "cv"])
def test_window_update_equals_state_oplus(kind):
    """The solver's compiled batched update = State.oplus state by state (small and large steps), and the
    arrays it returns (the window's stacked states) are those states'."""
    from rodo.estimator.state import stacked
    from rodo.estimator.window import _oplus_all

    rng = np.random.default_rng(5)
    motion = motion_prior(kind, (2.0, 0.05, 0.05, 1e-3, 1e-3, 0.05))
    states = [State(0.1 * k, se3.exp(rng.normal(size=6)), rng.normal(size=6),
                    rng.normal(size=6) if kind == "ca" else None) for k in range(4)]
    d = rng.normal(size=(4, motion.dim)) * np.array([1e-9, 1e-3, 0.5, 2.0])[:, None]
    new, T, tail = _oplus_all(states, *stacked(states)[:2], d)
    np.testing.assert_array_equal(T, stacked(new)[0])
    np.testing.assert_array_equal(tail, stacked(new)[1])
    for got, x, dk in zip(new, states, d):
        want = x.oplus(dk)
        np.testing.assert_allclose(got.T_vehicle_world, want.T_vehicle_world, rtol=1e-13, atol=1e-13)
        np.testing.assert_array_equal(got.varpi, want.varpi)
        if kind == "ca":
            np.testing.assert_array_equal(got.varpi_dot, want.varpi_dot)


@pytest.mark.parametrize("kind", ["ca", "cv"])
@pytest.mark.parametrize("jacobians", ["residuals", "dense", "holes"])
def test_motion_terms_in_the_normal_equations(kind, jacobians):
    """The compiled accumulation of the motion terms = J^T W J, J^T W e, 1/2 e^T W e summed in NumPy: with the
    Jacobians the residuals give (J1 sparse below its pose rows), with J1 and J2's pose block dense, and with
    exact zeros scattered through them (the kernel skips zeros; it must skip nothing else)."""
    from rodo.estimator import motion_kernels

    rng = np.random.default_rng(6)
    motion = motion_prior(kind, (2.0, 0.05, 0.05, 1e-3, 1e-3, 0.05))
    d = motion.dim
    states = [State(0.08 * k, se3.exp(rng.normal(size=6)), rng.normal(size=6),
                    rng.normal(size=6) if kind == "ca" else None) for k in range(4)]
    E, J1, J2 = motion.residuals(states)
    if jacobians != "residuals":
        J1 = rng.normal(size=J1.shape)
        J2[:, :6, :6] = rng.normal(size=(3, 6, 6))
    if jacobians == "holes":
        J1[rng.random(J1.shape) < 0.3] = 0.0
        J2[:, :6, :6][rng.random((3, 6, 6)) < 0.3] = 0.0
        J1[1, :, 4] = 0.0  # a column without nonzeros
    W = np.stack([(lambda A: A @ A.T + np.eye(d))(rng.normal(size=(d, d))) for _ in range(3)])
    H, b = np.zeros((4 * d, 4 * d)), np.zeros(4 * d)
    cost = motion_kernels.accumulate(H, b, E, J1, J2, W)
    H_ref, b_ref, cost_ref = np.zeros_like(H), np.zeros_like(b), 0.0
    for k in range(3):
        J = np.concatenate([J1[k], J2[k]], axis=1)
        sl = slice(k * d, (k + 2) * d)
        H_ref[sl, sl] += J.T @ W[k] @ J
        b_ref[sl] += J.T @ W[k] @ E[k]
        cost_ref += 0.5 * E[k] @ W[k] @ E[k]
    np.testing.assert_allclose(H, H_ref, rtol=1e-10, atol=1e-10 * np.abs(H_ref).max())
    np.testing.assert_allclose(b, b_ref, rtol=1e-10, atol=1e-10 * np.abs(b_ref).max())
    assert cost == pytest.approx(cost_ref, rel=1e-12)
