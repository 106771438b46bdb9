"""The estimator's state and a uniform interface to the CV and CA motion priors.

A `State` is x = {T, varpi, varpi_dot} (paper eq. 3) with T = T_vehicle_world; the CV prior simply has no
varpi_dot (`vd is None`). Perturbations are left ones: x (+) d = {exp(d_xi^) T, varpi + d_eta, vd + d_zeta}.
`MotionModel` gives the solver one interface for both priors: dimension, prediction, the prior residual with
its Jacobians, and F_k / Q_k.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import motion_kernels
from .lie import se3
from .priors import ConstantAccelerationPrior, ConstantVelocityPrior
from .priors import kernels as prior_kernels


@dataclass
class State:
    t: float
    T: np.ndarray  # (4, 4) T_vehicle_world
    varpi: np.ndarray  # (6,)
    vd: np.ndarray | None = None  # (6,) or None for the CV prior

    def copy(self) -> "State":
        return State(self.t, self.T.copy(), self.varpi.copy(), None if self.vd is None else self.vd.copy())

    def vector_tail(self) -> np.ndarray:
        """[varpi; vd] (the Euclidean part of the state)."""
        return self.varpi if self.vd is None else np.concatenate((self.varpi, self.vd))

    def oplus(self, d: np.ndarray) -> "State":
        """x (+) d with a left perturbation of the pose."""
        vd = None if self.vd is None else self.vd + d[12:18]
        return State(self.t, se3.exp(d[:6]) @ self.T, self.varpi + d[6:12], vd)

    def ominus(self, other: "State") -> np.ndarray:
        """x (-) other (paper eq. 12)."""
        xi = se3.log(self.T @ se3.inverse(other.T))
        return np.concatenate((xi, self.vector_tail() - other.vector_tail()))


class MotionModel:
    """The CA (dim 18) or CV (dim 12) prior behind one interface."""

    def __init__(self, kind: str, qc_diag):
        Qc = np.diag(np.asarray(qc_diag, dtype=float))
        self.kind = kind
        if kind == "ca":
            self.prior = ConstantAccelerationPrior(Qc)
            self.dim = 18
        elif kind == "cv":
            self.prior = ConstantVelocityPrior(Qc)
            self.dim = 12
        else:
            raise ValueError(f"unknown prior kind {kind!r}")

    def initial_state(self, t: float, T: np.ndarray, varpi: np.ndarray) -> State:
        return State(t, T, varpi, np.zeros(6) if self.kind == "ca" else None)

    def predict(self, x: State, t: float) -> State:
        dt = t - x.t
        if self.kind == "ca":
            T, varpi, vd = self.prior.predict(x.T, x.varpi, x.vd, dt)
            return State(t, T, varpi, vd)
        T, varpi = self.prior.predict(x.T, x.varpi, dt)
        return State(t, T, varpi, None)

    def transition_and_noise(self, x: State, dt: float) -> tuple[np.ndarray, np.ndarray]:
        if self.kind == "ca":
            return self.prior.transition_and_noise(x.varpi, x.vd, dt)
        return self.prior.transition_and_noise(x.varpi, dt)

    def residuals(self, states: list[State]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The priors' `residual` for all consecutive pairs of `states`: e (n-1, d), J_e_x1, J_e_x2 (n-1, d, d).

        Same formulas as the priors' `residual` (e = x2 (-) f(x1), J_e_x2 = diag(J(e_xi)^-1, I..),
        J_e_x1 = -diag(J(-e_xi)^-1, I..) F_k): means and F_k from the priors' batched kernels, the SE(3)
        logarithm and Jacobians from `motion_kernels`, one pass for the whole window.
        """
        T1 = np.stack([x.T for x in states[:-1]])
        T2 = np.stack([x.T for x in states[1:]])
        tail1 = np.stack([x.vector_tail() for x in states[:-1]])
        tail2 = np.stack([x.vector_tail() for x in states[1:]])
        dt = np.array([b.t - a.t for a, b in zip(states[:-1], states[1:])])
        n = len(dt)
        # the priors' kernels directly: the window's states are the estimator's own (finite, times increasing)
        w1 = np.ascontiguousarray(tail1[:, :6])
        vd1 = np.ascontiguousarray(tail1[:, 6:]) if self.kind == "ca" else np.zeros((n, 6))
        Tp, wp, vp = np.empty((n, 4, 4)), np.empty((n, 6)), np.empty((n, 6))
        order = self.prior.magnus_order if self.kind == "ca" else 1
        prior_kernels.predict_batch(T1, w1, vd1, dt, order, Tp, wp, vp)
        F = np.empty((n, self.dim, self.dim))
        if self.kind == "ca":
            prior_kernels.ca_batch(w1, vd1, dt, self.prior.Qc, order, self.prior.noise_code, F,
                                   np.empty((n, 0, 0)), False)
            tail_pred = np.concatenate([wp, vp], axis=1)
        else:
            prior_kernels.cv_batch(w1, dt, self.prior.Qc, F, np.empty((n, 0, 0)), False)
            tail_pred = wp
        d = self.dim
        e, J1, J2 = np.empty((n, d)), np.empty((n, d, d)), np.empty((n, d, d))
        motion_kernels.residuals(Tp, tail_pred, T2, np.ascontiguousarray(tail2), F, e, J1, J2)
        return e, J1, J2
