"""Constant-velocity (white-noise-on-acceleration) prior on SE(3) x R^6 with absolute variables.

State x = {T, varpi}; SDE dT/dt = varpi^ T, d varpi/dt = w, w ~ GP(0, Qc) (Barfoot, State Estimation,
sec. 11.3; the paper's ref. [1]). Perturbation dynamics A = [[curlyhat(varpi), I], [0, 0]] is constant over an
interval, so F_k and Q_k are exact:

    F_k = exp(dt A) = [[Ad(exp(dt varpi)), dt J(dt varpi)], [0, I]],
    Q_k = int_0^dt Phi(s) L Qc L^T Phi(s)^T ds
        = [[dt^3 int_0^1 u^2 J(u sigma) Qc J(u sigma)^T du, dt^2 H(sigma) Qc], [sym, dt Qc]],  sigma = dt varpi,

the remaining integral by Gauss-Legendre quadrature (docs/priors.md). At zero velocity
Q_k = [[dt^3/3, dt^2/2], [dt^2/2, dt]] (x) Qc.

Checked by: tests/estimator/test_priors_cv.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.errors import InputError, check_finite
from rodo.estimator.lie import se3

from . import kernels as K
from .constant_acceleration import (batch_input, batch_outputs, block_diag3, check_batch, check_dt, check_pose,
                                    check_qc, first_nonfinite, single_pose, vec6)

_ZERO6 = np.zeros(6)


class ConstantVelocityPrior:
    """Constant-velocity prior (WNOA, absolute variables).

    Args:
        Qc: (6, 6) symmetric positive-definite power spectral density of the acceleration noise.

    Checked by: tests/estimator/test_priors_cv.py
    """

    state_dim = 12

    def __init__(self, Qc):
        self.Qc = check_qc(Qc)

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"

    def predict(self, T, varpi, dt):
        """Mean: T_k = exp(dt varpi^) T, varpi_k = varpi; T (..., 4, 4), varpi (..., 6), dt broadcastable."""
        fast = single_pose(T)
        if fast is not None and np.shape(varpi) == (6,) and np.ndim(dt) == 0:
            varpi = vec6("varpi", varpi)
            if first_nonfinite(varpi, _ZERO6):
                raise InputError("varpi: contains NaN or infinity")
            T_k, w_k, _ = K.predict_single(fast, varpi, _ZERO6, check_dt(dt), 1)
            return T_k, w_k
        T = check_pose("T", T)
        varpi = check_finite("varpi", varpi, (6,))
        dt_arr = check_finite("dt", dt)
        if np.any(dt_arr <= 0):
            raise InputError("dt: must be > 0 seconds")
        try:
            shape = np.broadcast_shapes(T.shape[:-2], varpi.shape[:-1], dt_arr.shape)
        except ValueError:
            raise InputError(f"T, varpi, dt: batch shapes {T.shape[:-2]}, {varpi.shape[:-1]}, {dt_arr.shape} "
                             "do not broadcast") from None
        n = int(np.prod(shape))
        Tb, wb, db = batch_input(T, shape, (4, 4)), batch_input(varpi, shape, (6,)), batch_input(dt_arr, shape, ())
        T_out = np.empty((n, 4, 4))
        w_out = np.empty((n, 6))
        K.predict_batch(Tb, wb, np.zeros((n, 6)), db, 1, T_out, w_out, np.empty((n, 6)))
        return T_out.reshape(shape + (4, 4)), w_out.reshape(shape + (6,))

    def _single(self, varpi, dt, want_q):
        varpi = vec6("varpi", varpi)
        dt = check_dt(dt)
        out = np.empty((2, 12, 12))
        if K.cv_into(varpi, dt, self.Qc, want_q, out):
            raise InputError("varpi: contains NaN or infinity")
        return out[0], out[1]

    def transition(self, varpi, dt) -> np.ndarray:
        """F_k (12, 12) = [[Ad(exp(dt varpi)), dt J(dt varpi)], [0, I]].

        Checked by: tests/estimator/test_priors_cv.py::test_cv_matches_exact
        """
        return self._single(varpi, dt, False)[0]

    def process_noise(self, varpi, dt) -> np.ndarray:
        """Q_k (12, 12), exact integral (see the module docstring).

        Checked by: tests/estimator/test_priors_cv.py::test_cv_matches_exact
        """
        return self._single(varpi, dt, True)[1]

    def transition_and_noise(self, varpi, dt) -> tuple[np.ndarray, np.ndarray]:
        """(F_k, Q_k) from one kernel call."""
        return self._single(varpi, dt, True)

    def _batch(self, varpi, dt, want_q, out):
        varpi, dt = check_batch(("varpi",), 1, (varpi,), dt)
        F, Q = batch_outputs(out, varpi.shape[0], 12, want_q)
        K.cv_batch(varpi, dt, self.Qc, F, Q, want_q)
        return F, Q

    def transition_batch(self, varpi, dt, out=None) -> np.ndarray:
        """varpi (N, 6), dt (N,) or scalar -> F (N, 12, 12); `out` an optional (N, 12, 12) buffer."""
        return self._batch(varpi, dt, False, None if out is None else (out, None))[0]

    def process_noise_batch(self, varpi, dt) -> np.ndarray:
        """varpi (N, 6), dt (N,) or scalar -> Q (N, 12, 12)."""
        return self._batch(varpi, dt, True, None)[1]

    def transition_and_noise_batch(self, varpi, dt, out=None) -> tuple[np.ndarray, np.ndarray]:
        """(F, Q) (N, 12, 12) each; `out` an optional (F, Q) pair of buffers to write into."""
        return self._batch(varpi, dt, True, out)

    def residual(self, T1, varpi1, T2, varpi2, dt):
        """e = [ln(T2 Tpred^-1)^vee; varpi2 - varpi1] and (J_e_x1, J_e_x2), left perturbations.

        J_e_x2 = diag(J(e_xi)^-1, I), J_e_x1 = -diag(J(-e_xi)^-1, I) F_k (exact: F_k is the Jacobian of the
        CV mean flow). Returns (e (12,), J_e_x1 (12, 12), J_e_x2 (12, 12)).

        Checked by: tests/estimator/test_priors_cv.py::test_cv_residual_jacobians
        """
        T1 = check_pose("T1", T1)
        T2 = check_pose("T2", T2)
        for name, T in (("T1", T1), ("T2", T2)):
            if T.shape != (4, 4):
                raise InputError(f"{name}: expected shape (4, 4), got {T.shape}")
        varpi2 = vec6("varpi2", varpi2)
        if first_nonfinite(varpi2, _ZERO6):
            raise InputError("varpi2: contains NaN or infinity")
        dt = check_dt(dt)
        F = self.transition(varpi1, dt)
        varpi1 = vec6("varpi1", varpi1)
        T_pred, _ = self.predict(T1, varpi1, dt)
        e_xi = se3.log(T2 @ se3.inverse(T_pred))
        e = np.concatenate([e_xi, varpi2 - varpi1])
        J_e_x2 = block_diag3(se3.left_jacobian_inv(e_xi), 2)
        J_e_x1 = -block_diag3(se3.left_jacobian_inv(-e_xi), 2) @ F
        return e, J_e_x1, J_e_x2
