"""Numerical Jacobians on the manifold (central differences), used to check every analytic Jacobian."""

import numpy as np

from rodo.estimator.lie import se3


def numerical_jacobian(f, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """d f(x) / d x for vector x and vector-valued f (central differences)."""
    x = np.asarray(x, dtype=float)
    f0 = np.asarray(f(x))
    J = np.zeros(f0.shape + x.shape)
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx.flat[i] = eps
        J[..., i] = (np.asarray(f(x + dx)) - np.asarray(f(x - dx))) / (2 * eps)
    return J


def left_perturbation_jacobian(f, T: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """d f(exp(d^) T) / d d at d = 0, f of a 4x4 pose returning a vector."""
    return numerical_jacobian(lambda d: f(se3.exp(d) @ T), np.zeros(6), eps)
