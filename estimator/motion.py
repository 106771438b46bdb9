"""The two motion priors behind one interface (navlie's ProcessModel is the anchor).

A `MotionPrior` owns the state layout (dimension, whether there is an acceleration), the prediction of the
mean, F_k and Q_k for the covariance, the batched prior residuals of the sliding window with their
Jacobians (compiled kernels), and which of the configured sigmas belong to its state. The odometry and the
window hold one and never branch on its kind.

    ConstantAccelerationMotion  x = {T, varpi, varpi_dot}, dim 18, white-noise jerk (paper sec. IV-B, Magnus)
    ConstantVelocityMotion      x = {T, varpi},            dim 12, white-noise acceleration (the CV baseline)

The array-level priors (`rodo.estimator.priors`) hold the mathematics; this is the estimator's view of them.

Checked by: tests/estimator/test_window_kernels.py::test_batched_motion_residuals_equal_the_priors_residual,
    ::test_motion_terms_in_the_normal_equations
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from . import motion_kernels
from .errors import InputError
from .priors import ConstantAccelerationPrior, ConstantVelocityPrior
from .priors import kernels as prior_kernels
from .state import State, stacked


class MotionPrior(ABC):
    """A motion prior as the estimator uses it. `dim` is the state's tangent dimension (6 pose + the rest)."""

    name: str
    dim: int
    qc_field: str

    @abstractmethod
    def initial_state(self, t: float, T_vehicle_world: np.ndarray, varpi: np.ndarray) -> State:
        """A state of this layout (zero acceleration where there is one)."""

    @abstractmethod
    def predict(self, x: State, t: float) -> State:
        """The prior's mean at time t >= x.t."""

    @abstractmethod
    def transition_and_noise(self, x: State, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """F_k and Q_k (dim, dim) of the interval dt after x."""

    @abstractmethod
    def _batch_means(self, T1, tail1, dt, F) -> tuple[np.ndarray, np.ndarray]:
        """Compiled kernels: the means of n intervals from states (T1 (n, 4, 4), tail1 (n, dim - 6)) and F_k
        (into F); returns the predicted poses (n, 4, 4) and Euclidean tails (n, dim - 6)."""

    def with_jump(self, Q: np.ndarray, P: np.ndarray, x: State, t: float, sigma: float):
        """(Q, P) of the interval from x to t with the prior noise of a linear acceleration jump of 1-sigma
        `sigma` (m/s^2) at an unknown time within it added (`config.StandstillConfig.sigma_accel_jump`); as they
        are for a prior without acceleration or sigma 0.

        Checked by: tests/estimator/test_standstill.py::test_the_jump_noise_is_an_acceleration_jump
        """
        return Q, P

    def tail_sigmas(self, velocity, rate, accel, angular_accel) -> list[float]:
        """1-sigmas of the Euclidean part of a state in the layout of `State.vector_tail`: [velocity (3);
        rate (3)], and [accel (3); angular accel (3)] where the state has an acceleration."""
        return list(velocity) + list(rate)

    @abstractmethod
    def predict_batch(self, T_vehicle_world, varpi, varpi_dot, dt) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The mean of the prior for arrays of states (calibration, analysis): (T, varpi, varpi_dot) after dt,
        varpi_dot zeros for a state without acceleration."""

    @abstractmethod
    def transition_and_noise_batch(self, varpi, varpi_dot, dt) -> tuple[np.ndarray, np.ndarray]:
        """F_k and Q_k (n, dim, dim) of n intervals from arrays of states (varpi_dot ignored without one)."""

    def tail(self, varpi, varpi_dot) -> np.ndarray:
        """The Euclidean part of states in this layout, (..., dim - 6): `State.vector_tail` for arrays."""
        return np.asarray(varpi, dtype=float)

    def residuals(self, states: list[State]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The prior residual of all consecutive pairs of `states`: e (n-1, d), J_e_x1, J_e_x2 (n-1, d, d).

        e = x2 (-) f(x1), J_e_x2 = diag(J(e_xi)^-1, I..), J_e_x1 = -diag(J(-e_xi)^-1, I..) F_k (the priors'
        `residual`): means and F_k from the priors' batched kernels, the SE(3) logarithm and Jacobians from
        `motion_kernels`, one pass for the whole window (the states are the estimator's own: finite, times
        increasing, so nothing is re-checked).
        """
        return self.stacked_residuals(*stacked(states))

    def stacked_residuals(self, T: np.ndarray, tail: np.ndarray, t: np.ndarray):
        """`residuals` of states given as arrays (`state.stacked`): T (n, 4, 4), tail (n, d - 6), t (n,)."""
        dt = t[1:] - t[:-1]
        n, d = len(dt), self.dim
        F = np.empty((n, d, d))
        Tp, tail_pred = self._batch_means(T[:-1], tail[:-1], dt, F)
        e, J1, J2 = np.empty((n, d)), np.empty((n, d, d)), np.empty((n, d, d))
        motion_kernels.residuals(Tp, tail_pred, T[1:], np.ascontiguousarray(tail[1:]), F, e, J1, J2)
        return e, J1, J2


class ConstantAccelerationMotion(MotionPrior):
    """White-noise-on-jerk prior (paper sec. IV-B): Magnus mean of order 3, closed-form F_k, Q_k."""

    name = "ca"
    dim = 18
    qc_field = "qc_ca"  # the NoiseConfig field of its power spectral density (jerk)

    def __init__(self, qc_diag):
        self.prior = ConstantAccelerationPrior(np.diag(np.asarray(qc_diag, dtype=float)))
        # (CA?, Magnus order, noise code, Qc): the prior as `window_kernels.normal_equations` takes it
        self.kernel_args = (True, self.prior.magnus_order, self.prior.noise_code, self.prior.Qc)

    def initial_state(self, t, T_vehicle_world, varpi):
        return State(t, T_vehicle_world, varpi, np.zeros(6))

    def with_jump(self, Q, P, x, t, sigma):
        if sigma <= 0:
            return Q, P
        dt = t - x.t
        Qc = np.diag([sigma**2 / dt] * 3 + [0.0] * 3)  # the jerk PSD of the jump: Var(a) grows by sigma^2 over dt
        F, J = np.empty((1, 18, 18)), np.empty((1, 18, 18))  # the kernel is linear in Qc, semi-definite or not
        prior_kernels.ca_batch(x.varpi[None], x.varpi_dot[None], np.array([dt]), Qc, self.prior.magnus_order,
                               self.prior.noise_code, F, J, True)
        return Q + J[0], P + J[0]

    def predict(self, x, t):
        T, varpi, varpi_dot = self.prior.predict(x.T_vehicle_world, x.varpi, x.varpi_dot, t - x.t)
        return State(t, T, varpi, varpi_dot)

    def transition_and_noise(self, x, dt):
        return self.prior.transition_and_noise(x.varpi, x.varpi_dot, dt)

    def tail_sigmas(self, velocity, rate, accel, angular_accel):
        return list(velocity) + list(rate) + list(accel) + list(angular_accel)

    def tail(self, varpi, varpi_dot):
        return np.concatenate([np.asarray(varpi, dtype=float), np.asarray(varpi_dot, dtype=float)], axis=-1)

    def predict_batch(self, T_vehicle_world, varpi, varpi_dot, dt):
        return self.prior.predict(T_vehicle_world, varpi, varpi_dot, dt)

    def transition_and_noise_batch(self, varpi, varpi_dot, dt):
        return self.prior.transition_and_noise_batch(varpi, varpi_dot, dt)

    def _batch_means(self, T1, tail1, dt, F):
        n, order = len(dt), self.prior.magnus_order
        varpi1, varpi_dot1 = np.ascontiguousarray(tail1[:, :6]), np.ascontiguousarray(tail1[:, 6:])
        Tp, varpi_p, varpi_dot_p = np.empty((n, 4, 4)), np.empty((n, 6)), np.empty((n, 6))
        prior_kernels.predict_batch(T1, varpi1, varpi_dot1, dt, order, Tp, varpi_p, varpi_dot_p)
        prior_kernels.ca_batch(varpi1, varpi_dot1, dt, self.prior.Qc, order, self.prior.noise_code, F,
                               np.empty((n, 0, 0)), False)
        return Tp, np.concatenate([varpi_p, varpi_dot_p], axis=1)


class ConstantVelocityMotion(MotionPrior):
    """White-noise-on-acceleration prior (the CV/C baseline)."""

    name = "cv"
    dim = 12
    qc_field = "qc_cv"  # the NoiseConfig field of its power spectral density (acceleration)

    def __init__(self, qc_diag):
        self.prior = ConstantVelocityPrior(np.diag(np.asarray(qc_diag, dtype=float)))
        self.kernel_args = (False, 1, 0, self.prior.Qc)  # as `ConstantAccelerationMotion.kernel_args`

    def initial_state(self, t, T_vehicle_world, varpi):
        return State(t, T_vehicle_world, varpi, None)

    def predict(self, x, t):
        T, varpi = self.prior.predict(x.T_vehicle_world, x.varpi, t - x.t)
        return State(t, T, varpi, None)

    def transition_and_noise(self, x, dt):
        return self.prior.transition_and_noise(x.varpi, dt)

    def predict_batch(self, T_vehicle_world, varpi, varpi_dot, dt):
        T, varpi = self.prior.predict(T_vehicle_world, varpi, dt)
        return T, varpi, np.zeros_like(varpi)

    def transition_and_noise_batch(self, varpi, varpi_dot, dt):
        return self.prior.transition_and_noise_batch(varpi, dt)

    def _batch_means(self, T1, tail1, dt, F):
        n = len(dt)
        varpi1 = np.ascontiguousarray(tail1[:, :6])
        Tp, varpi_p, varpi_dot_p = np.empty((n, 4, 4)), np.empty((n, 6)), np.empty((n, 6))
        prior_kernels.predict_batch(T1, varpi1, np.zeros((n, 6)), dt, 1, Tp, varpi_p, varpi_dot_p)
        prior_kernels.cv_batch(varpi1, dt, self.prior.Qc, F, np.empty((n, 0, 0)), False)
        return Tp, varpi_p


MOTION_PRIORS = {"ca": ConstantAccelerationMotion, "cv": ConstantVelocityMotion}


def motion_prior(name: str, qc_diag) -> MotionPrior:
    """The motion prior "ca" or "cv" with the diagonal power spectral density qc_diag (6,).

    Checked by: tests/estimator/test_window_kernels.py::test_motion_terms_in_the_normal_equations
    """
    try:
        kind = MOTION_PRIORS[name]
    except (KeyError, TypeError):
        raise InputError(f"prior: expected one of {tuple(MOTION_PRIORS)}, got {name!r}") from None
    return kind(qc_diag)


def motion_prior_for(config) -> MotionPrior:
    """The motion prior of an `OdometryConfig` (its model's prior, with that prior's Qc from the noise section).

    Checked by: tests/estimator/test_window_kernels.py::test_motion_terms_in_the_normal_equations
    """
    kind = MOTION_PRIORS[config.prior]
    return kind(getattr(config.noise, kind.qc_field))
