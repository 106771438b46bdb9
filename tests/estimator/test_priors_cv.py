"""Constant-velocity prior: F_k, Q_k against their exact forms (A constant), mean, residual Jacobians, bad input."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.estimator.priors import ConstantVelocityPrior
from rodo.estimator.priors import exact as ex
from tests.helpers import numerical_jacobian
from tests.strategies import twists, vectors, vehicle_motion

DT = 1.0 / 13.0
_A = np.random.default_rng(np.random.SeedSequence(11)).normal(size=(6, 6))
QC = _A @ _A.T + 0.5 * np.eye(6)


def _rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


@given(motion=vehicle_motion(), big=twists("any", 30.0), dt=st.floats(0.01, 1.0))
def test_cv_matches_exact(motion, big, dt):
    prior = ConstantVelocityPrior(QC)
    for varpi in (motion[0], big):
        F, Q = prior.transition_and_noise(varpi, dt)
        assert _rel(F, ex.exact_cv_transition(varpi, dt)) < 1e-12
        assert _rel(Q, ex.exact_cv_process_noise(varpi, dt, QC)) < 1e-11
        np.testing.assert_array_equal(Q, Q.T)
        assert np.linalg.eigvalsh(Q)[0] > 0
        np.testing.assert_allclose(Q[6:, 6:], dt * QC, rtol=1e-15)
        np.testing.assert_array_equal(prior.transition(varpi, dt), F)
        np.testing.assert_array_equal(prior.process_noise(varpi, dt), Q)


@given(motion=vehicle_motion())
def test_cv_process_noise_matches_lyapunov_ode(motion):
    """Independent check through the Lyapunov ODE of the CA module's generic machinery: a CV interval is a
    CA interval whose acceleration block is frozen; here simply integrate dP = A P + P A^T + L Qc L^T."""
    from scipy.integrate import solve_ivp

    varpi = motion[0]
    A = np.zeros((12, 12))
    A[:6, :6] = se3.curlyhat(varpi)
    A[:6, 6:] = np.eye(6)
    W = np.zeros((12, 12))
    W[6:, 6:] = QC
    sol = solve_ivp(lambda t, y: (A @ y.reshape(12, 12) + y.reshape(12, 12) @ A.T + W).ravel(), (0, DT),
                    np.zeros(144), method="DOP853", rtol=1e-12, atol=1e-20)
    assert _rel(ConstantVelocityPrior(QC).process_noise(varpi, DT), sol.y[:, -1].reshape(12, 12)) < 1e-10


@pytest.mark.parametrize("dt", [DT, 1.0, 3.0])
def test_cv_zero_motion_classic_forms(dt):
    F, Q = ConstantVelocityPrior(QC).transition_and_noise(np.zeros(6), dt)
    F_ref = np.kron(np.array([[1.0, dt], [0.0, 1.0]]), np.eye(6))
    Q_ref = np.kron(np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]), QC)
    assert np.abs(F - F_ref).max() <= 1e-15 * np.abs(F_ref).max()
    assert np.abs(Q - Q_ref).max() <= 1e-15 * np.abs(Q_ref).max()


@given(motion=vehicle_motion(), xi=twists("any"))
def test_cv_predict_and_batches(motion, xi):
    prior = ConstantVelocityPrior(QC)
    varpi = motion[0]
    T = se3.exp(xi)
    T_k, w_k = prior.predict(T, varpi, DT)
    T_ex, _ = ex.exact_cv_predict(T, varpi, DT)
    assert np.linalg.norm(se3.log(T_k @ se3.inverse(T_ex))) < 1e-12
    np.testing.assert_array_equal(w_k, varpi)
    Tb, wb = prior.predict(np.stack([T, T]), np.stack([varpi, -varpi]), np.array([DT, 2 * DT]))
    np.testing.assert_allclose(Tb[0], T_k, atol=1e-14)
    np.testing.assert_allclose(Tb[1], prior.predict(T, -varpi, 2 * DT)[0], atol=1e-14)
    W = np.stack([varpi, np.zeros(6)])
    F, Q = prior.transition_and_noise_batch(W, np.array([DT, 0.5]))
    np.testing.assert_array_equal(F[0], prior.transition(varpi, DT))
    np.testing.assert_array_equal(Q[1], prior.process_noise(np.zeros(6), 0.5))
    np.testing.assert_array_equal(prior.transition_batch(W, DT)[1], prior.transition(np.zeros(6), DT))
    np.testing.assert_array_equal(prior.process_noise_batch(W, DT)[0], prior.process_noise(varpi, DT))


@settings(max_examples=25)  # each example is ~40 finite-difference residual evaluations
@given(motion=vehicle_motion(), d2=vectors(12, 0.05), xi1=twists("vehicle"))
def test_cv_residual_jacobians(motion, d2, xi1):
    """F_k is the exact Jacobian of the CV mean flow, so both residual Jacobians match FD to ~1e-9."""
    prior = ConstantVelocityPrior(QC)
    varpi = motion[0]
    T1 = se3.exp(xi1)
    Tp, wp = prior.predict(T1, varpi, DT)
    T2, w2 = se3.exp(d2[:6]) @ Tp, wp + d2[6:]
    e, J1, J2 = prior.residual(T1, varpi, T2, w2, DT)
    np.testing.assert_allclose(e, d2, atol=1e-9)
    J1_fd = numerical_jacobian(lambda d: prior.residual(se3.exp(d[:6]) @ T1, varpi + d[6:], T2, w2, DT)[0],
                               np.zeros(12), eps=1e-5)
    J2_fd = numerical_jacobian(lambda d: prior.residual(T1, varpi, se3.exp(d[:6]) @ T2, w2 + d[6:], DT)[0],
                               np.zeros(12), eps=1e-5)
    assert np.abs(J1 - J1_fd).max() < 1e-8
    assert np.abs(J2 - J2_fd).max() < 1e-8


NAN6 = np.r_[np.nan, np.zeros(5)]


@pytest.mark.parametrize("call, name", [
    (lambda p: p.transition(NAN6, DT), "varpi"),
    (lambda p: p.process_noise(np.zeros(5), DT), "varpi"),
    (lambda p: p.transition_and_noise(np.zeros(6), 0.0), "dt"),
    (lambda p: p.process_noise(np.zeros(6), np.inf), "dt"),
    (lambda p: p.predict(np.eye(4), NAN6, DT), "varpi"),
    (lambda p: p.predict(np.eye(4), np.zeros(6), -1.0), "dt"),
    (lambda p: p.predict(np.ones((4, 4)), np.zeros(6), DT), "T.*bottom row"),
    (lambda p: p.transition_batch(np.zeros((2, 6)), np.array([0.1, -0.1])), "dt"),
    (lambda p: p.process_noise_batch(np.zeros(6), 0.1), "varpi"),
    (lambda p: p.residual(np.eye(4), np.zeros(6), np.eye(4), NAN6, DT), "varpi2"),
    (lambda p: p.residual(np.eye(4), NAN6, np.eye(4), np.zeros(6), DT), "varpi"),
    (lambda p: p.residual(np.eye(4), np.zeros(6), np.full((4, 4), np.nan), np.zeros(6), DT), "T2"),
    (lambda p: p.residual(np.eye(4), np.zeros(6), np.eye(4), np.zeros(6), 0), "dt"),
])
def test_cv_bad_input(call, name):
    with pytest.raises(InputError, match=name):
        call(ConstantVelocityPrior(QC))


def test_cv_bad_qc():
    with pytest.raises(InputError, match="Qc.*positive definite"):
        ConstantVelocityPrior(-np.eye(6))
