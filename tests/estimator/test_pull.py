"""The scan's pull on its solved pose (rodo.estimator.pull, its compiled sums in uncertainty_kernels):
chi-square with 6 dof at the true pose for pair errors drawn from their covariances, the rigid offset's quadratic
form in the pairs' information (H built here in NumPy), the same in any world frame; and the relative pose
factor's pull term."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2, kstest

from rodo.estimator.lie import se3
from rodo.estimator.pull import MIN_PAIRS, NEUTRAL_PULL, pose_pull, pull_term, relative_factor
from rodo.estimator.velocity_inflation import velocity_factor


def _rng(*key):
    return np.random.default_rng(np.random.SeedSequence([2026, 37, *key]))


def _scene(rng, n):
    """A sensor pose T (world from sensor), n points 5-60 m from it in the world, with anisotropic pair
    covariances (radar-like: long along the line of sight or across it)."""
    T = se3.exp(np.r_[rng.normal(size=3) * 10.0, rng.normal(size=3)])
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    m = se3.transform_points(T, d * rng.uniform(5.0, 60.0, size=(n, 1)))
    B = rng.normal(size=(n, 3, 3))
    C = B @ np.swapaxes(B, 1, 2) * 0.01 + 1e-4 * np.eye(3)
    return m, C, T


def _in_sensor(T, p):
    return se3.transform_points(se3.inverse(T), p)


def _draw(rng, C):
    return (np.linalg.cholesky(C) @ rng.normal(size=(len(C), 3, 1)))[..., 0]


@settings(max_examples=4, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(20, 200))
def test_at_the_true_pose_six_times_the_pull_is_chi_square_with_six_dof(seed, n):
    """Pair errors drawn from their covariances at the true pose: g ~ N(0, H), so 6 pull ~ chi2(6): 600 scenes'
    mean within 4 standard errors of 6, and a Kolmogorov-Smirnov test against chi2(6) not rejected at 1e-4."""
    rng = _rng(seed)
    values = []
    for _ in range(600):
        m, C, T = _scene(rng, n)
        values.append(6.0 * pose_pull(T, _in_sensor(T, m + _draw(rng, C)), m, C))
    values = np.array(values)
    assert abs(values.mean() - 6.0) < 4.0 * np.sqrt(12.0 / len(values))
    assert kstest(values, chi2(6).cdf).pvalue > 1e-4


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rho=st.tuples(*[st.floats(-0.5, 0.5)] * 3),
       phi=st.tuples(*[st.floats(-0.01, 0.01)] * 3))
def test_a_rigid_offset_pulls_by_its_quadratic_form(seed, rho, phi):
    """The scan displaced from its map by delta = (rho, phi), m = p - rho - phi x (p - c), without noise: the pairs'
    residuals are J delta exactly (J at the scan's points), so the pull is delta^T H delta / 6, H = sum J^T C^-1
    J."""
    rng = _rng(seed)
    p, C, T = _scene(rng, 50)
    c = T[:3, 3]
    rho, phi = np.array(rho), np.array(phi)
    m = p - rho - np.cross(phi, p - c)
    q = p - c
    J = np.zeros((len(m), 3, 6))
    J[:, :, :3] = np.eye(3)
    J[:, :, 3:] = -np.array([[np.zeros(len(q)), -q[:, 2], q[:, 1]],
                             [q[:, 2], np.zeros(len(q)), -q[:, 0]],
                             [-q[:, 1], q[:, 0], np.zeros(len(q))]]).transpose(2, 0, 1)
    H = np.einsum("nij,nik->jk", J, np.linalg.solve(C, J))
    delta = np.r_[rho, phi]
    assert pose_pull(T, _in_sensor(T, p), m, C) == pytest.approx(delta @ H @ delta / 6.0, rel=1e-8, abs=1e-12)
    shared = 0.02  # a variance on every pair's diagonal (the map's sigma squared) is the same as in C
    H = np.einsum("nij,nik->jk", J, np.linalg.solve(C + shared * np.eye(3), J))
    assert pose_pull(T, _in_sensor(T, p), m, C, shared) == pytest.approx(delta @ H @ delta / 6.0, rel=1e-8,
                                                                         abs=1e-12)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), xi=st.tuples(*[st.floats(-50.0, 50.0)] * 3, *[st.floats(-3.0, 3.0)] * 3))
def test_the_pull_is_the_same_in_any_world_frame(seed, xi):
    """The world moved by one rigid transform M (the map points, the covariances and the sensor's pose with it; the
    detections stay in the sensor frame): the same pull."""
    rng = _rng(seed)
    m, C, T = _scene(rng, 40)
    p = _in_sensor(T, m + _draw(rng, C) + 0.05)
    M = se3.exp(np.array(xi))
    R = M[:3, :3]
    moved = pose_pull(M @ T, p, se3.transform_points(M, m), R @ C @ R.T)
    assert moved == pytest.approx(pose_pull(T, p, m, C), rel=1e-7)


def test_too_few_pairs_or_pairs_in_a_line_have_no_pull():
    rng = _rng(1)
    m, C, T = _scene(rng, MIN_PAIRS)
    p = _in_sensor(T, m + 0.01)
    assert np.isfinite(pose_pull(T, p, m, C))
    assert np.isnan(pose_pull(T, p[:-1], m[:-1], C[:-1]))
    assert np.isnan(pose_pull(T, p, m, -C))  # not a covariance
    line = np.outer(np.linspace(5.0, 40.0, 20), [1.0, 0.0, 0.0])  # through the sensor: the roll about it is free
    assert np.isnan(pose_pull(np.eye(4), line + [0.01, 0.0, 0.0], line, np.broadcast_to(0.01 * np.eye(3), (20, 3, 3))))


def test_the_relative_factor_adds_the_pull():
    """f + r . |omega| + d ln(1 + nis) + p pull: bit for bit the factor without the pull at p 0 or without pulls;
    a NaN pull (too few pairs) counts as the neutral 1 per dof, so a factor with f near 0 does not vanish there."""
    rng = _rng(2)
    varpi = rng.normal(size=(50, 6))
    nis, pull = rng.uniform(0.0, 3.0, 50), rng.uniform(0.0, 4.0, 50)
    pull[:5] = np.nan
    base = velocity_factor(varpi, 0.3, 0.0, 0.2, nis, (10.0, 20.0, 0.0))
    np.testing.assert_array_equal(relative_factor(varpi, 0.3, (10.0, 20.0, 0.0), 0.2, nis), base)
    np.testing.assert_array_equal(relative_factor(varpi, 0.3, (10.0, 20.0, 0.0), 0.2, nis, 0.0, pull), base)
    with_pull = relative_factor(varpi, 0.3, (10.0, 20.0, 0.0), 0.2, nis, 0.5, pull)
    np.testing.assert_allclose(with_pull, base + 0.5 * np.where(np.isnan(pull), NEUTRAL_PULL, pull), rtol=1e-15)
    np.testing.assert_array_equal(pull_term(pull)[:5], NEUTRAL_PULL)
    assert NEUTRAL_PULL == pytest.approx(chi2(6).mean() / 6)
    tiny = relative_factor(np.zeros((1, 6)), 1e-6, (10.0, 20.0, 0.0), 0.2, [np.nan], 0.3, [np.nan])
    assert tiny[0] == pytest.approx(0.3 + 1e-6)


def test_a_shared_variance_is_the_same_as_adding_it_and_the_cartesian_one_needs_no_rotation():
    """`pose_pull`'s variance (the map's sigma squared) is the same as adding it to every pair's covariance; the
    Cartesian model's detections have sigma^2 I in any frame, exactly, and equal to its rotated reference C (sigma^2
    I) C^T, while the polar model's differ from detection to detection."""
    from rodo.estimator.measurement_models import measurement_model

    rng = _rng(3)
    polar = np.column_stack([rng.uniform(5.0, 80.0, 30), rng.uniform(-0.6, 0.6, 30), rng.uniform(-0.2, 0.2, 30),
                             rng.normal(size=30)])
    R = se3.exp(np.r_[np.zeros(3), rng.normal(size=3)])[:3, :3]
    sigmas = np.array([0.1, 0.01, 0.02, 0.1])
    cartesian = measurement_model("cartesian").world_position_covariance(polar, sigmas, 0.3, R)
    np.testing.assert_array_equal(cartesian, np.broadcast_to(0.09 * np.eye(3), (30, 3, 3)))
    np.testing.assert_allclose(cartesian, np.broadcast_to(R @ (0.09 * np.eye(3)) @ R.T, (30, 3, 3)), atol=1e-15)
    polar_cov = measurement_model("polar").world_position_covariance(polar, sigmas, 0.3, R)
    assert np.ptp(np.linalg.eigvalsh(polar_cov)[:, -1]) > 0.1 * np.median(np.linalg.eigvalsh(polar_cov)[:, -1])
    m, C, T = _scene(rng, 30)
    p = _in_sensor(T, m + _draw(rng, C))
    assert pose_pull(T, p, m, C, 0.09) == pytest.approx(pose_pull(T, p, m, C + 0.09 * np.eye(3)), rel=1e-12)
