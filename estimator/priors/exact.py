"""Exact references of the motion priors (truth over speed) and the literal matrix-exponential recipes.

- `exact_predict`: the nominal flow dT/dt = varpi(t)^ T, varpi(t) = varpi + t varpi_dot (paper eq. 15, 20-21),
  integrated with DOP853 at tight tolerances.
- `exact_transition`: dPhi/dt = A(t) Phi, A(t) = [[curlyhat(varpi(t)), I, 0], [0, 0, I], [0, 0, 0]] (eq. 17, 40).
- `exact_process_noise`: the Lyapunov ODE dP/dt = A P + P A^T + L Qc L^T from P = 0 (eq. 36, 42).
- `magnus_van_loan`: the paper's recipe taken literally (eq. 44-48, 51-57): scipy expm of the 36x36 S_M;
  the fast closed forms in `constant_acceleration` must equal it to rounding.
- `van_loan_midpoint`: the naive baseline (A frozen at the mid-interval velocity, one 36x36 expm).
- CV counterparts (A constant, so matrix exponentials are exact).
- `ExactConstantAccelerationPrior`: the `ConstantAccelerationPrior` API backed by these references
  (about 10-100 ms per call): for users who want truth over speed.

Checked by: tests/estimator/test_priors_exact.py
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from scipy.integrate import solve_ivp

from rodo.estimator.errors import InputError, check_finite
from rodo.estimator.lie import se3

from .constant_acceleration import ConstantAccelerationPrior, check_dt
from .kernels import magnus_sigma

_ATOL = 1e-15


def _a_matrix(w: np.ndarray) -> np.ndarray:
    A = np.zeros((18, 18))
    A[:6, :6] = se3.curlyhat(w)
    A[:6, 6:12] = np.eye(6)
    A[6:12, 12:] = np.eye(6)
    return A


def _l_matrix(n_blocks: int) -> np.ndarray:
    L = np.zeros((6 * n_blocks, 6))
    L[-6:] = np.eye(6)
    return L


def _inputs(varpi, varpi_dot, dt):
    varpi = check_finite("varpi", varpi, (6,)).reshape(6)
    varpi_dot = check_finite("varpi_dot", varpi_dot, (6,)).reshape(6)
    return varpi, varpi_dot, check_dt(dt)


def exact_predict(T, varpi, varpi_dot, dt, rtol: float = 1e-13):
    """Exact mean transition (eq. 15, 20-21) by DOP853; returns (T_k (4,4), varpi_k (6,), varpi_dot_k (6,))."""
    T = check_finite("T", T, (4, 4)).reshape(4, 4)
    varpi, varpi_dot, dt = _inputs(varpi, varpi_dot, dt)
    # components below 1e-100 act far below double precision on the pose, but their squares underflow inside
    # DOP853's error norm (0/0, found by hypothesis with a 1e-160 angular acceleration): integrate them as 0
    w0, w1 = (np.where(np.abs(v) < 1e-100, 0.0, v) for v in (varpi, varpi_dot))

    def rhs(t, y):
        w = w0 + t * w1
        M = y.reshape(3, 4)  # [C, r]: d/dt [C, r] = omega^ [C, r] + [0, nu]
        out = se3.hat(w)[:3, :3] @ M
        out[:, 3] += w[:3]
        return out.ravel()

    sol = solve_ivp(rhs, (0.0, dt), T[:3].ravel(), method="DOP853", rtol=rtol, atol=_ATOL)
    T_k = np.eye(4)
    T_k[:3] = sol.y[:, -1].reshape(3, 4)
    U, _, Vt = np.linalg.svd(T_k[:3, :3])  # remove the integrator's ~1e-14 drift off SO(3)
    T_k[:3, :3] = U @ Vt
    return T_k, varpi + dt * varpi_dot, varpi_dot.copy()


def exact_transition(varpi, varpi_dot, dt, rtol: float = 1e-12) -> np.ndarray:
    """Exact F_k = Phi(dt, 0) of dPhi/dt = A(t) Phi (eq. 40-41), (18, 18)."""
    varpi, varpi_dot, dt = _inputs(varpi, varpi_dot, dt)
    sol = solve_ivp(lambda t, y: (_a_matrix(varpi + t * varpi_dot) @ y.reshape(18, 18)).ravel(),
                    (0.0, dt), np.eye(18).ravel(), method="DOP853", rtol=rtol, atol=_ATOL)
    return sol.y[:, -1].reshape(18, 18)


def exact_process_noise(varpi, varpi_dot, dt, Qc, rtol: float = 1e-12) -> np.ndarray:
    """Exact Q_k = P(dt) of dP/dt = A P + P A^T + L Qc L^T, P(0) = 0 (eq. 36, 42), (18, 18)."""
    varpi, varpi_dot, dt = _inputs(varpi, varpi_dot, dt)
    Qc = check_finite("Qc", Qc, (6, 6)).reshape(6, 6)
    L = _l_matrix(3)
    W = L @ Qc @ L.T

    def rhs(t, y):
        A = _a_matrix(varpi + t * varpi_dot)
        P = y.reshape(18, 18)
        AP = A @ P
        return (AP + AP.T + W).ravel()

    sol = solve_ivp(rhs, (0.0, dt), np.zeros(18 * 18), method="DOP853", rtol=rtol, atol=1e-20)
    P = sol.y[:, -1].reshape(18, 18)
    return 0.5 * (P + P.T)


def magnus_block(varpi, varpi_dot, dt, magnus_order: int = 3) -> np.ndarray:
    """S_A (18, 18) of eq. 51-57 (orders 1-3) plus the fourth-order terms of docs/priors.md (order 4)."""
    varpi, varpi_dot, dt = _inputs(varpi, varpi_dot, dt)
    sig = np.empty(6)
    magnus_sigma(varpi, varpi_dot, dt, int(magnus_order), sig, np.empty(6), np.empty(6))
    X, Y = se3.curlyhat(varpi), se3.curlyhat(varpi_dot)
    S12 = dt * np.eye(6)
    S13 = np.zeros((6, 6))
    if magnus_order >= 2:
        S12 = S12 + dt**3 / 12 * Y
    if magnus_order >= 3:
        S12 = S12 + dt**5 / 240 * Y @ Y
    if magnus_order >= 4:
        c = dt**5 / 720
        S12 = S12 + c * (-3 * X @ X @ Y + 3 * X @ Y @ X - Y @ X @ X)
        S13 = c * (3 * X @ Y - Y @ X)
    S = np.zeros((18, 18))
    S[:6, :6] = se3.curlyhat(sig)
    S[:6, 6:12] = S12
    S[:6, 12:] = S13
    S[6:12, 12:] = dt * np.eye(6)
    return S


def _van_loan(S: np.ndarray, W_dt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = S.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = S
    M[:n, n:] = W_dt
    M[n:, n:] = -S.T
    E = sla.expm(M)
    F = E[:n, :n]
    Q = E[:n, n:] @ F.T
    return F, 0.5 * (Q + Q.T)


def magnus_van_loan(varpi, varpi_dot, dt, Qc, magnus_order: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """The paper's recipe literally (eq. 44-48): F = exp(S_A), Q = G F^T, G from scipy expm of the 36x36 S_M."""
    varpi, varpi_dot, dt = _inputs(varpi, varpi_dot, dt)
    L = _l_matrix(3)
    return _van_loan(magnus_block(varpi, varpi_dot, dt, magnus_order), L @ Qc @ L.T * dt)


def van_loan_midpoint(varpi, varpi_dot, dt, Qc) -> tuple[np.ndarray, np.ndarray]:
    """Naive baseline: A frozen at varpi + dt/2 varpi_dot, F and Q from one 36x36 expm (Van Loan 1978)."""
    varpi, varpi_dot, dt = _inputs(varpi, varpi_dot, dt)
    L = _l_matrix(3)
    return _van_loan(_a_matrix(varpi + 0.5 * dt * varpi_dot) * dt, L @ Qc @ L.T * dt)


# ---------------------------------------------------------------------------------------------- CV
def _cv_a(varpi):
    A = np.zeros((12, 12))
    A[:6, :6] = se3.curlyhat(varpi)
    A[:6, 6:] = np.eye(6)
    return A


def exact_cv_predict(T, varpi, dt):
    """T_k = expm(dt varpi^) T (scipy expm of the 4x4), varpi_k = varpi."""
    T = check_finite("T", T, (4, 4)).reshape(4, 4)
    varpi = check_finite("varpi", varpi, (6,)).reshape(6)
    dt = check_dt(dt)
    return sla.expm(dt * se3.hat(varpi)) @ T, varpi.copy()


def exact_cv_transition(varpi, dt) -> np.ndarray:
    """F_k = expm(dt A), A = [[curlyhat(varpi), I], [0, 0]] (exact: A is constant), (12, 12)."""
    varpi = check_finite("varpi", varpi, (6,)).reshape(6)
    return sla.expm(check_dt(dt) * _cv_a(varpi))


def exact_cv_process_noise(varpi, dt, Qc) -> np.ndarray:
    """Q_k = int_0^dt Phi(s) L Qc L^T Phi(s)^T ds via Van Loan (exact for constant A), (12, 12)."""
    varpi = check_finite("varpi", varpi, (6,)).reshape(6)
    dt = check_dt(dt)
    Qc = check_finite("Qc", Qc, (6, 6)).reshape(6, 6)
    L = _l_matrix(2)
    return _van_loan(_cv_a(varpi) * dt, L @ Qc @ L.T * dt)[1]


class ExactConstantAccelerationPrior(ConstantAccelerationPrior):
    """`ConstantAccelerationPrior` whose predict, F_k and Q_k come from the exact ODE references.

    Same constructor (magnus_order is ignored) and methods; slow (tens of ms per interval), for
    validation and for users who want truth over speed. `residual` uses the exact F_k, which is then
    exactly the Jacobian of the exact mean flow.
    """

    def predict(self, T, varpi, varpi_dot, dt):
        T = np.asarray(T, dtype=float)
        if T.ndim != 2:
            raise InputError("T: ExactConstantAccelerationPrior.predict takes a single (4, 4) pose")
        return exact_predict(T, varpi, varpi_dot, dt)

    def transition(self, varpi, varpi_dot, dt):
        return exact_transition(varpi, varpi_dot, dt)

    def process_noise(self, varpi, varpi_dot, dt):
        return exact_process_noise(varpi, varpi_dot, dt, self.Qc)

    def transition_and_noise(self, varpi, varpi_dot, dt):
        return self.transition(varpi, varpi_dot, dt), self.process_noise(varpi, varpi_dot, dt)

    def transition_batch(self, varpi, varpi_dot, dt):
        varpi, varpi_dot, dt = self._check_batch(varpi, varpi_dot, dt)
        return np.stack([self.transition(a, b, c) for a, b, c in zip(varpi, varpi_dot, dt)])

    def process_noise_batch(self, varpi, varpi_dot, dt):
        varpi, varpi_dot, dt = self._check_batch(varpi, varpi_dot, dt)
        return np.stack([self.process_noise(a, b, c) for a, b, c in zip(varpi, varpi_dot, dt)])

    def transition_and_noise_batch(self, varpi, varpi_dot, dt):
        return self.transition_batch(varpi, varpi_dot, dt), self.process_noise_batch(varpi, varpi_dot, dt)
