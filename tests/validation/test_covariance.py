"""World-frame position covariance of the state pose and its n-sigma ellipsoid (validation.covariance)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rodo.estimator.lie import se3
from rodo.validation.covariance import covariance_axes, covariance_ellipsoid, position_covariance_world
from tests.strategies import covariances, twists

# pose covariance scales: metres for rho, rotation sd of mrad so that the first-order result holds
POSE_SD = np.array([0.3, 0.5, 0.2, 3e-3, 3e-3, 5e-3])


@settings(deadline=None, max_examples=30)
@given(xi=twists("vehicle", translation_scale=50.0), shape=covariances(6, 0.3, 1.0))
def test_position_covariance_world_monte_carlo(xi, shape):
    """Sigma_w = C^T P_rho C against samples of T' = exp(gamma^) T, gamma ~ N(0, P) (first order)."""
    T = se3.exp(np.asarray(xi))
    P = POSE_SD[:, None] * shape * POSE_SD[None, :] + np.diag([1e-4] * 3 + [1e-8] * 3)
    rng = np.random.default_rng(np.random.SeedSequence(7))  # the Monte Carlo sampler; the data is drawn above
    gamma = rng.multivariate_normal(np.zeros(6), P, size=4000)
    r_w = se3.inverse(se3.exp(gamma) @ T)[:, :3, 3]
    S_mc = np.cov(r_w.T)
    S = position_covariance_world(T, P[:3, :3])
    # same shape: whiten the sample covariance by S (4000 samples: entries within ~0.1 of I)
    L = np.linalg.cholesky(S)
    W = np.linalg.solve(L, np.linalg.solve(L, S_mc).T)
    assert np.abs(W - np.eye(3)).max() < 0.15


@given(S=st.lists(covariances(3, 0.01, 3.0), min_size=1, max_size=5).map(np.stack), n_sigma=st.floats(0.5, 5.0))
def test_covariance_ellipsoid_reconstructs_sigma(S, n_sigma):
    half, q = covariance_ellipsoid(S, n_sigma)
    R = Rotation.from_quat(q).as_matrix()
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.all(q[:, 3] >= 0)
    rebuilt = R @ (((half / n_sigma) ** 2)[:, :, None] * np.swapaxes(R, 1, 2))
    assert np.allclose(rebuilt, S, atol=1e-10 * np.abs(S).max())


@given(S=covariances(2, 0.01, 3.0), n_sigma=st.floats(0.5, 5.0))
def test_covariance_axes_of_a_2d_covariance(S, n_sigma):
    """Points m + V diag(half) [cos a, sin a] lie on the n-sigma ellipse (x - m)^T S^-1 (x - m) = n^2; V proper."""
    half, V = covariance_axes(S, n_sigma)
    assert np.linalg.det(V) == pytest.approx(1.0)
    a = np.linspace(0, 2 * np.pi, 7)
    x = (np.c_[np.cos(a), np.sin(a)] * half) @ V.T
    np.testing.assert_allclose(np.einsum("ni,ij,nj->n", x, np.linalg.inv(S), x), n_sigma**2, rtol=1e-6)
