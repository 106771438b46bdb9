"""Constant-acceleration (white-noise-on-jerk) motion prior on SE(3) x R^12 (paper sec. IV).

State x = {T, varpi, varpi_dot}, T = T_vehicle_world, left perturbation x = {exp(xi^) T, varpi + eta,
varpi_dot + zeta}. SDE (eq. 13-14): dT/dt = varpi^ T, d varpi/dt = varpi_dot, d varpi_dot/dt = w, w ~ GP(0, Qc).

- Mean (eq. 31-34): T_k = exp(sigma^) T, varpi_k = varpi + dt varpi_dot, varpi_dot_k = varpi_dot, with the
  Magnus pose term sigma = dt varpi + dt^2/2 vd + dt^3/12 ad(vd) varpi + dt^5/240 ad(vd)^2 varpi (orders 1-3,
  eq. 28-30) + dt^5/720 ad(varpi)^3 vd (order 4, the term the paper omits; docs/priors.md).
- Transition (eq. 59-69): F_k = exp(S_A) = [[Ad(exp sigma), J(sigma) S12, dt H(sigma) S12 (+ J S13)], [0, I, dt I],
  [0, 0, I]], S12 = dt I + dt^3/12 ad(vd) + dt^5/240 ad(vd)^2 (eq. 55-57).
- Process noise (eq. 43-48): Q_k = G F_k^T = dt int_0^1 E(u) L Qc L^T E(u)^T du, E(u) = exp(u S_A), evaluated
  with Gauss-Legendre quadrature over u of the closed-form E(u) L (docs/priors.md); equals scipy expm of the
  36x36 S_M to ~1e-13 relative.

Everything heavy runs in the numba kernels of `kernels` (F_k and Q_k fused); this module validates inputs once.

Checked by: tests/estimator/test_priors_ca.py
"""

from __future__ import annotations

import math

import numpy as np

from rodo.estimator.errors import InputError, check_finite
from rodo.estimator.jit import njit
from rodo.estimator.lie import se3

from . import kernels as K


# ---------------------------------------------------------------------------------------------- validation
@njit(cache=True)
def first_nonfinite(a, b):
    """0 if all of a and b are finite, 1 if a is not, 2 if b is not (cheap input check)."""
    for x in a.ravel():
        if not math.isfinite(x):
            return 1
    for x in b.ravel():
        if not math.isfinite(x):
            return 2
    return 0


@njit(cache=True)
def pose_problem(T):
    """0 if T (4,4) is finite with bottom row [0, 0, 0, 1]; 1 if non-finite; 2 if the bottom row is wrong."""
    for i in range(4):
        for j in range(4):
            if not math.isfinite(T[i, j]):
                return 1
    if abs(T[3, 0]) > 1e-9 or abs(T[3, 1]) > 1e-9 or abs(T[3, 2]) > 1e-9 or abs(T[3, 3] - 1.0) > 1e-9:
        return 2
    return 0


def check_dt(dt) -> float:
    """dt as a float; InputError unless it is a finite scalar > 0 seconds."""
    if np.ndim(dt) != 0:
        raise InputError(f"dt: expected a scalar number of seconds, got shape {np.shape(dt)}")
    try:
        value = float(dt)
    except (TypeError, ValueError):
        raise InputError(f"dt: expected a positive number of seconds, got {dt!r}") from None
    if not (value > 0.0 and math.isfinite(value)):
        raise InputError(f"dt: must be finite and > 0 seconds, got {value!r}")
    return value


def vec6(name: str, x) -> np.ndarray:
    """x as a contiguous float64 (6,) array; InputError (naming `name`) otherwise. Finiteness not checked."""
    try:
        a = np.ascontiguousarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: not a numeric array ({exc})") from None
    if a.shape != (6,):
        raise InputError(f"{name}: expected shape (6,), got {a.shape}")
    return a


def _check_pair(names, a, b) -> None:
    bad = first_nonfinite(a, b)
    if bad:
        raise InputError(f"{names[bad - 1]}: contains NaN or infinity")


def check_qc(Qc) -> np.ndarray:
    """Qc as a read-only contiguous (6, 6) float array; InputError unless symmetric positive definite."""
    Qc = check_finite("Qc", Qc, (6, 6))
    if Qc.shape != (6, 6):
        raise InputError(f"Qc: expected shape (6, 6), got {Qc.shape}")
    scale = max(float(np.abs(Qc).max()), np.finfo(float).tiny)
    if np.abs(Qc - Qc.T).max() > 1e-12 * scale:
        raise InputError("Qc: not symmetric")
    try:
        np.linalg.cholesky(Qc)
    except np.linalg.LinAlgError:
        raise InputError("Qc: not positive definite") from None
    Qc = np.ascontiguousarray(0.5 * (Qc + Qc.T))
    Qc.setflags(write=False)
    return Qc


def check_batch(names, n_vec, vecs, dt):
    """Validate batched (N, 6) arrays (n_vec of them) and dt (N,) or scalar; returns contiguous arrays."""
    out = []
    for name, v in zip(names, vecs):
        a = check_finite(name, v, (6,))
        if a.ndim != 2:
            raise InputError(f"{name}: expected shape (N, 6), got {a.shape}")
        out.append(np.ascontiguousarray(a))
    n = out[0].shape[0]
    for name, a in zip(names, out):
        if a.shape[0] != n:
            raise InputError(f"{name}: expected {n} rows like {names[0]}, got {a.shape[0]}")
    d = check_finite("dt", dt)
    if d.ndim == 0:
        d = np.full(n, float(d))
    if d.shape != (n,):
        raise InputError(f"dt: expected a scalar or shape ({n},), got {d.shape}")
    if np.any(d <= 0):
        raise InputError("dt: every interval must be > 0 seconds")
    return (*out, np.ascontiguousarray(d))


def check_pose(name: str, T) -> np.ndarray:
    """(..., 4, 4) finite poses with bottom row [0, 0, 0, 1]."""
    T = check_finite(name, T, (4, 4))
    if T.ndim < 2:
        raise InputError(f"{name}: expected shape (..., 4, 4), got {T.shape}")
    if np.abs(T[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-9:
        raise InputError(f"{name}: bottom row must be [0, 0, 0, 1]")
    return T


def single_pose(T, name: str = "T"):
    """A contiguous (4, 4) pose after a cheap check, or None if T is not a single (4, 4) array."""
    if np.shape(T) != (4, 4):
        return None
    try:
        a = np.ascontiguousarray(T, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: not a numeric array ({exc})") from None
    bad = pose_problem(a)
    if bad == 1:
        raise InputError(f"{name}: contains NaN or infinity")
    if bad == 2:
        raise InputError(f"{name}: bottom row must be [0, 0, 0, 1]")
    return a


def batch_outputs(out, n: int, d: int, want_q: bool):
    """(F, Q) output arrays (n, d, d): the caller's (checked) or fresh ones (Q a dummy when not wanted)."""
    if out is None:
        return np.empty((n, d, d)), np.empty((n, d, d) if want_q else (n, 0, 0))
    F, Q = out
    if Q is None and not want_q:
        Q = np.empty((n, 0, 0))
    for name, a, shape in (("out[0]", F, (n, d, d)), ("out[1]", Q, (n, d, d) if want_q else (n, 0, 0))):
        if not (isinstance(a, np.ndarray) and a.dtype == np.float64 and a.shape == shape
                and a.flags.c_contiguous and a.flags.writeable):
            raise InputError(f"{name}: expected a writeable C-contiguous float64 array of shape {shape}")
    return F, Q


def batch_input(a, shape: tuple, tail: tuple) -> np.ndarray:
    """`a` broadcast to shape + tail as an (n,) + tail array, C-contiguous and writable: the one array type the
    batch kernels are compiled for (a read-only view, e.g. of an input already of that shape, would be another
    numba specialisation, compiled again on its first use: `make demo` did so after the warm-up)."""
    n = int(np.prod(shape))
    return np.require(np.broadcast_to(a, shape + tail).reshape((n,) + tail), dtype=float, requirements=("C", "W"))


def block_diag3(J: np.ndarray, n_blocks: int) -> np.ndarray:
    out = np.eye(6 * n_blocks)
    out[:6, :6] = J
    return out


class ConstantAccelerationPrior:
    """Constant-acceleration prior; see the module docstring for the model and docs/priors.md for derivations.

    Args:
        Qc: (6, 6) symmetric positive-definite power spectral density of the jerk, [linear; angular].
        magnus_order: 1, 2, 3 (paper eq. 28-30) or 4 (3 plus the leading fourth-order term).
        noise: "paper" (default): Q_k = G F_k^T of eq. 43-48 (whitened error vs the exact integral ~4e-4 at
            13 Hz, growing as dt^2); "subinterval": Q_k = int Phi(dt, s) L Qc L^T Phi(dt, s)^T ds with each
            Phi(dt, s) the Magnus transition of [s, dt] (~1e-7 at 13 Hz, ~1.5x the cost; docs/priors.md sec. 4b).

    Checked by: tests/estimator/test_priors_ca.py
    """

    state_dim = 18

    NOISE_MODELS = ("paper", "subinterval")

    def __init__(self, Qc, magnus_order: int = 3, noise: str = "paper"):
        if isinstance(magnus_order, bool) or not isinstance(magnus_order, (int, np.integer)) \
                or not 1 <= int(magnus_order) <= 4:
            raise InputError(f"magnus_order: must be one of 1, 2, 3, 4, got {magnus_order!r}")
        if noise not in self.NOISE_MODELS:
            raise InputError(f"noise: must be one of {self.NOISE_MODELS}, got {noise!r}")
        self.Qc = check_qc(Qc)
        self.magnus_order = int(magnus_order)
        self.noise = noise
        self.noise_code = self.NOISE_MODELS.index(noise)  # the kernels' code of `noise`

    def __repr__(self) -> str:
        return f"{type(self).__name__}(magnus_order={self.magnus_order}, noise={self.noise!r})"

    # ------------------------------------------------------------------------------------------ mean
    def predict(self, T, varpi, varpi_dot, dt):
        """Mean transition f(x) (eq. 31-34): T_k = exp(sigma^) T, varpi_k = varpi + dt vd, vd_k = vd.

        Args:
            T: (4, 4) or (..., 4, 4) pose T_vehicle_world.
            varpi, varpi_dot: (6,) or (..., 6), broadcast against T's batch shape.
            dt: seconds > 0, scalar or broadcastable to the batch shape.

        Returns:
            (T_k, varpi_k, varpi_dot_k) with the broadcast batch shape.

        Checked by: tests/estimator/test_priors_ca.py::test_magnus_pose_matches_exact_ode
        """
        fast = single_pose(T)
        if fast is not None and np.shape(varpi) == (6,) and np.shape(varpi_dot) == (6,) and np.ndim(dt) == 0:
            varpi, varpi_dot = vec6("varpi", varpi), vec6("varpi_dot", varpi_dot)
            _check_pair(("varpi", "varpi_dot"), varpi, varpi_dot)
            return K.predict_single(fast, varpi, varpi_dot, check_dt(dt), self.magnus_order)
        T = check_pose("T", T)
        varpi = check_finite("varpi", varpi, (6,))
        varpi_dot = check_finite("varpi_dot", varpi_dot, (6,))
        dt_arr = check_finite("dt", dt)
        if np.any(dt_arr <= 0):
            raise InputError("dt: must be > 0 seconds")
        try:
            shape = np.broadcast_shapes(T.shape[:-2], varpi.shape[:-1], varpi_dot.shape[:-1], dt_arr.shape)
        except ValueError:
            raise InputError(f"T, varpi, varpi_dot, dt: batch shapes {T.shape[:-2]}, {varpi.shape[:-1]}, "
                             f"{varpi_dot.shape[:-1]}, {dt_arr.shape} do not broadcast") from None
        n = int(np.prod(shape))
        Tb, wb, vb = batch_input(T, shape, (4, 4)), batch_input(varpi, shape, (6,)), batch_input(varpi_dot, shape, (6,))
        db = batch_input(dt_arr, shape, ())
        T_out = np.empty((n, 4, 4))
        w_out = np.empty((n, 6))
        v_out = np.empty((n, 6))
        K.predict_batch(Tb, wb, vb, db, self.magnus_order, T_out, w_out, v_out)
        return T_out.reshape(shape + (4, 4)), w_out.reshape(shape + (6,)), v_out.reshape(shape + (6,))

    def magnus_sigma(self, varpi, varpi_dot, dt) -> np.ndarray:
        """The Magnus pose term sigma (6,) with T_k = exp(sigma^) T (eq. 28-30, docs/priors.md)."""
        varpi, varpi_dot = vec6("varpi", varpi), vec6("varpi_dot", varpi_dot)
        _check_pair(("varpi", "varpi_dot"), varpi, varpi_dot)
        out = np.empty(6)
        K.magnus_sigma(varpi, varpi_dot, check_dt(dt), self.magnus_order, out, np.empty(6), np.empty(6))
        return out

    # ------------------------------------------------------------------------------------------ F_k, Q_k
    def _single(self, varpi, varpi_dot, dt, want_q):
        varpi, varpi_dot = vec6("varpi", varpi), vec6("varpi_dot", varpi_dot)
        dt = check_dt(dt)
        out = np.empty((2, 18, 18))
        bad = K.ca_into(varpi, varpi_dot, dt, self.Qc, self.magnus_order, self.noise_code, want_q, out)
        if bad:
            raise InputError(f"{('varpi', 'varpi_dot')[bad - 1]}: contains NaN or infinity")
        return out[0], out[1]

    def transition(self, varpi, varpi_dot, dt) -> np.ndarray:
        """F_k (18, 18) = exp(S_A) in closed form (eq. 59-69).

        Checked by: tests/estimator/test_priors_ca.py::test_transition_closed_form_matches_expm,
        ::test_transition_matches_fd_of_mean_flow, ::test_transition_matches_exact_ode
        """
        return self._single(varpi, varpi_dot, dt, False)[0]

    def process_noise(self, varpi, varpi_dot, dt) -> np.ndarray:
        """Q_k (18, 18) = G F_k^T (eq. 43-48), symmetric positive definite.

        Checked by: tests/estimator/test_priors_ca.py::test_process_noise_matches_van_loan_of_full_magnus_block,
        ::test_process_noise_whitened_error_against_exact_integral
        """
        return self._single(varpi, varpi_dot, dt, True)[1]

    def transition_and_noise(self, varpi, varpi_dot, dt) -> tuple[np.ndarray, np.ndarray]:
        """(F_k, Q_k) from one fused kernel call (cheaper than two calls)."""
        return self._single(varpi, varpi_dot, dt, True)

    def _check_batch(self, varpi, varpi_dot, dt):
        return check_batch(("varpi", "varpi_dot"), 2, (varpi, varpi_dot), dt)

    def _batch(self, varpi, varpi_dot, dt, want_q, out):
        varpi, varpi_dot, dt = self._check_batch(varpi, varpi_dot, dt)
        F, Q = batch_outputs(out, varpi.shape[0], 18, want_q)
        K.ca_batch(varpi, varpi_dot, dt, self.Qc, self.magnus_order, self.noise_code, F, Q, want_q)
        return F, Q

    def transition_batch(self, varpi, varpi_dot, dt, out=None) -> np.ndarray:
        """F_k for N intervals: varpi, varpi_dot (N, 6), dt (N,) or scalar -> (N, 18, 18).

        `out`: optional C-contiguous float64 (N, 18, 18) array to write into (saves the allocation)."""
        return self._batch(varpi, varpi_dot, dt, False, None if out is None else (out, None))[0]

    def process_noise_batch(self, varpi, varpi_dot, dt) -> np.ndarray:
        """Q_k for N intervals -> (N, 18, 18)."""
        return self._batch(varpi, varpi_dot, dt, True, None)[1]

    def transition_and_noise_batch(self, varpi, varpi_dot, dt, out=None) -> tuple[np.ndarray, np.ndarray]:
        """(F (N, 18, 18), Q (N, 18, 18)) from one fused batched kernel call.

        `out`: optional (F, Q) pair of C-contiguous float64 (N, 18, 18) arrays to write into; reusing buffers
        avoids fresh-memory page faults, which cost about as much as the computation for large N."""
        return self._batch(varpi, varpi_dot, dt, True, out)

    # ------------------------------------------------------------------------------------------ residual
    def residual(self, T1, varpi1, varpi_dot1, T2, varpi2, varpi_dot2, dt):
        """Prior residual e = x2 (-) f(x1) (eq. 12, 31-34) and its Jacobians under left perturbations.

        e = [ln(T2 Tpred^-1)^vee; varpi2 - varpi_pred; vd2 - vd_pred],
        J_e_x2 = diag(J(e_xi)^-1, I, I), J_e_x1 = -diag(J(-e_xi)^-1, I, I) F_k.

        Returns:
            (e (18,), J_e_x1 (18, 18), J_e_x2 (18, 18)).

        Checked by: tests/estimator/test_priors_ca.py::test_residual_jacobians_match_finite_differences
        """
        T1 = check_pose("T1", T1)
        T2 = check_pose("T2", T2)
        for name, T in (("T1", T1), ("T2", T2)):
            if T.shape != (4, 4):
                raise InputError(f"{name}: expected shape (4, 4), got {T.shape}")
        varpi2, varpi_dot2 = vec6("varpi2", varpi2), vec6("varpi_dot2", varpi_dot2)
        _check_pair(("varpi2", "varpi_dot2"), varpi2, varpi_dot2)
        varpi1, varpi_dot1 = vec6("varpi1", varpi1), vec6("varpi_dot1", varpi_dot1)
        _check_pair(("varpi1", "varpi_dot1"), varpi1, varpi_dot1)
        dt = check_dt(dt)
        T_pred, w_pred, v_pred = self.predict(T1, varpi1, varpi_dot1, dt)
        F = self.transition(varpi1, varpi_dot1, dt)
        e_xi = se3.log(T2 @ se3.inverse(T_pred))
        e = np.concatenate([e_xi, varpi2 - w_pred, varpi_dot2 - v_pred])
        J_e_x2 = block_diag3(se3.left_jacobian_inv(e_xi), 3)
        J_e_x1 = -block_diag3(se3.left_jacobian_inv(-e_xi), 3) @ F
        return e, J_e_x1, J_e_x2
