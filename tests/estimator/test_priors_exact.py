"""The exact references themselves: consistent with closed forms where those are exact, and with each other."""

import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import given, settings

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.estimator.priors import exact as ex
from tests.helpers import numerical_jacobian
from tests.strategies import twists, vehicle_motion

DT = 1.0 / 13.0
QC = np.diag([1.0, 0.5, 0.2, 0.01, 0.01, 0.05])


@given(varpi=twists("any", 20.0), xi=twists("any"))
def test_exact_predict_constant_velocity_is_exponential(varpi, xi):
    T = se3.exp(xi)
    T_k, w_k, v_k = ex.exact_predict(T, varpi, np.zeros(6), DT)
    assert np.linalg.norm(se3.log(T_k @ se3.inverse(sla.expm(DT * se3.hat(varpi)) @ T))) < 1e-11
    np.testing.assert_array_equal(w_k, varpi)
    np.testing.assert_array_equal(v_k, np.zeros(6))


@settings(max_examples=10)
@given(motion=vehicle_motion())
def test_exact_transition_is_jacobian_of_exact_flow(motion):
    varpi, vd = motion
    T0 = np.eye(4)
    T_ref = ex.exact_predict(T0, varpi, vd, DT)[0]

    def flow(d):
        T, w, v = ex.exact_predict(se3.exp(d[:6]) @ T0, varpi + d[6:12], vd + d[12:], DT)
        return np.r_[se3.log(T @ se3.inverse(T_ref)), w, v]

    J = numerical_jacobian(flow, np.zeros(18), eps=1e-5)
    assert np.abs(ex.exact_transition(varpi, vd, DT) - J).max() < 1e-8


@pytest.mark.parametrize("dt", [DT, 1.0])
def test_exact_forms_at_zero_motion(dt):
    z = np.zeros(6)
    F_ref = np.kron(np.array([[1, dt, dt**2 / 2], [0, 1, dt], [0, 0, 1]]), np.eye(6))
    Q_ref = np.kron(np.array([[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                              [dt**3 / 6, dt**2 / 2, dt]]), QC)
    np.testing.assert_allclose(ex.exact_transition(z, z, dt), F_ref, atol=1e-13)
    np.testing.assert_allclose(ex.exact_process_noise(z, z, dt, QC), Q_ref, rtol=1e-10, atol=1e-15)
    F, Q = ex.van_loan_midpoint(z, z, dt, QC)
    np.testing.assert_allclose(F, F_ref, atol=1e-13)
    np.testing.assert_allclose(Q, Q_ref, rtol=1e-10, atol=1e-15)


def test_exact_process_noise_equals_quadrature_of_exact_transitions():
    """Q = int_0^dt Phi(dt, s) L Qc L^T Phi(dt, s)^T ds with Phi(dt, s) from the ODE started at s."""
    varpi = np.array([-10.0, 0.5, 0.2, 0.3, -0.2, 0.8])
    vd = np.array([2.0, -1.0, 0.5, 0.4, 0.3, -0.5])
    dt = 0.3
    x, w = np.polynomial.legendre.leggauss(10)
    s_nodes, weights = 0.5 * dt * (x + 1), 0.5 * dt * w
    Q = np.zeros((18, 18))
    for s, wk in zip(s_nodes, weights):
        Phi = ex.exact_transition(varpi + s * vd, vd, dt - s)
        Q += wk * Phi[:, 12:] @ QC @ Phi[:, 12:].T
    Qex = ex.exact_process_noise(varpi, vd, dt, QC)
    assert np.abs(Q - Qex).max() < 1e-9 * np.abs(Qex).max()


def test_exact_bad_input():
    with pytest.raises(InputError, match="varpi"):
        ex.exact_transition(np.zeros(5), np.zeros(6), DT)
    with pytest.raises(InputError, match="dt"):
        ex.exact_process_noise(np.zeros(6), np.zeros(6), -1.0, QC)
    with pytest.raises(InputError, match="T"):
        ex.exact_predict(np.eye(3), np.zeros(6), np.zeros(6), DT)
    with pytest.raises(InputError, match="varpi"):
        ex.exact_cv_transition(np.r_[np.nan, np.zeros(5)], DT)
