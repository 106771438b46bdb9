"""Constant-acceleration prior: Magnus mean vs the exact ODE, F_k and Q_k vs expm / FD / exact integrals,
residual Jacobians vs finite differences, bad input."""

import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.estimator.priors import ConstantAccelerationPrior
from rodo.estimator.priors import exact as ex
from tests.helpers import numerical_jacobian
from tests.strategies import twists, vectors, vehicle_motion

DT = 1.0 / 13.0
QC = np.diag([1.0, 0.5, 0.2, 0.01, 0.01, 0.05])
_A = np.random.default_rng(np.random.SeedSequence(7)).normal(size=(6, 6))
QC_FULL = _A @ _A.T + 0.5 * np.eye(6)  # a dense SPD Qc, so no block structure hides mistakes
T0 = se3.exp(np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]))
# an aggressive motion so the truncation errors stay far above the ODE's rounding while dt is halved
VARPI = np.array([-10.0, 0.5, 0.2, 0.3, -0.2, 0.8])
VD = np.array([2.0, -1.0, 0.5, 0.4, 0.3, -0.5])


def _pose_err(Ta, Tb):
    return np.linalg.norm(se3.log(Ta @ se3.inverse(Tb)))


def _rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


def _close_to_rounding(a, b):
    assert np.abs(a - b).max() <= 1e-14 * np.abs(b).max()


def _whitened(Q, Qex):
    Li = np.linalg.inv(np.linalg.cholesky(Qex))
    return np.abs(np.linalg.eigvalsh(Li @ (Q - Qex) @ Li.T)).max()


# ---------------------------------------------------------------------------------------------- mean
@given(motion=vehicle_motion(), xi0=twists("any"))
def test_magnus_pose_matches_exact_ode(motion, xi0):
    """Order 3 at 13 Hz: typically a few 1e-10; the worst corner of vehicle_motion() (30 m/s with 1 m/s lateral
    and vertical slip, rates 0.1 / 0.1 / 0.5 rad/s, 3 m/s^2 and 0.5 rad/s^2 about every axis, all 2^11 sign
    combinations) measures 3.3e-8, hence 5e-8 here (an earlier bound from a 13 m/s corner was too tight: hypothesis
    found 1.53e-8 at 20 m/s). Order 4 adds the omitted dt^5 term: 2.4e-9 there, hence 3.5e-9."""
    varpi, vd = motion
    T = se3.exp(xi0)
    prior = ConstantAccelerationPrior(QC, magnus_order=3)
    T_k, varpi_k, vd_k = prior.predict(T, varpi, vd, DT)
    T_ex, varpi_ex, vd_ex = ex.exact_predict(T, varpi, vd, DT)
    assert _pose_err(T_k, T_ex) < 5e-8
    assert _pose_err(ConstantAccelerationPrior(QC, magnus_order=4).predict(T, varpi, vd, DT)[0], T_ex) < 3.5e-9
    np.testing.assert_allclose(varpi_k, varpi_ex, atol=1e-14)
    np.testing.assert_array_equal(vd_k, vd_ex)
    # stays on SE(3)
    C = T_k[:3, :3]
    np.testing.assert_allclose(C.T @ C, np.eye(3), atol=1e-13)
    assert abs(np.linalg.det(C) - 1.0) < 1e-13
    np.testing.assert_array_equal(T_k[3], [0.0, 0.0, 0.0, 1.0])


def _slopes(order, varpi, dts=(0.8, 0.4, 0.2, 0.1)):
    prior = ConstantAccelerationPrior(QC, magnus_order=order)
    errs = np.array([_pose_err(prior.predict(T0, varpi, VD, dt)[0], ex.exact_predict(T0, varpi, VD, dt)[0])
                     for dt in dts])
    return np.log2(errs[:-1] / errs[1:]), errs


@pytest.mark.parametrize("order, rotating, slope", [(1, True, 3), (2, True, 5), (3, True, 5), (4, True, 6),
                                                    (1, False, 3), (2, False, 5), (3, False, 7)])
def test_magnus_convergence_slopes(order, rotating, slope):
    """Halving dt: order 1 ~ dt^3, orders 2-3 ~ dt^5, order 3 ~ dt^7 without rotation, order 4 ~ dt^6."""
    varpi = VARPI if rotating else np.r_[VARPI[:3], 0.0, 0.0, 0.0]
    slopes, _ = _slopes(order, varpi)
    np.testing.assert_allclose(slopes, slope, atol=0.15)


def test_order_four_beats_order_three():
    _, e3 = _slopes(3, VARPI)
    _, e4 = _slopes(4, VARPI)
    assert np.all(e4 < 0.1 * e3)


def test_fourth_order_term_sign():
    """sigma_4 = +dt^5/720 ad(varpi)^3 vd: the opposite sign is worse than leaving the term out."""
    dt = 0.4
    p3, p4 = ConstantAccelerationPrior(QC, 3), ConstantAccelerationPrior(QC, 4)
    s3, s4 = p3.magnus_sigma(VARPI, VD, dt), p4.magnus_sigma(VARPI, VD, dt)
    X = se3.curlyhat(VARPI)
    np.testing.assert_allclose(s4 - s3, dt**5 / 720 * X @ X @ X @ VD, rtol=0, atol=1e-15)
    T_ex = ex.exact_predict(T0, VARPI, VD, dt)[0]
    errs = [_pose_err(se3.exp(s) @ T0, T_ex) for s in (s4, s3, 2 * s3 - s4)]
    assert errs[0] < 0.1 * errs[1] < 0.1 * errs[2]


def test_predict_batches_broadcast():
    prior = ConstantAccelerationPrior(QC)
    rng = np.random.default_rng(np.random.SeedSequence(1))
    T = se3.exp(rng.normal(size=(2, 3, 6)))
    varpi = rng.normal(size=(3, 6))
    dt = np.array([[0.1], [0.2]])
    T_k, w_k, v_k = prior.predict(T, varpi, VD, dt)
    assert T_k.shape == (2, 3, 4, 4) and w_k.shape == (2, 3, 6) and v_k.shape == (2, 3, 6)
    for i in range(2):
        for j in range(3):
            Ts, ws, _ = prior.predict(T[i, j], varpi[j], VD, dt[i, 0])
            np.testing.assert_allclose(T_k[i, j], Ts, rtol=0, atol=1e-14)
            np.testing.assert_allclose(w_k[i, j], ws, rtol=0, atol=1e-15)


# ---------------------------------------------------------------------------------------------- F_k
@pytest.mark.parametrize("order", [1, 2, 3, 4])
@settings(max_examples=30)  # x4 orders
@given(motion=vehicle_motion(), dt=st.floats(0.01, 1.0), big=twists("any", 30.0))
def test_transition_closed_form_matches_expm(order, motion, dt, big):
    """F_k = exp(S_A) (eq. 59-69) equals scipy's expm of the 18x18 Magnus block, vehicle and wild motion."""
    prior = ConstantAccelerationPrior(QC_FULL, magnus_order=order)
    for varpi, vd in (motion, (big, 0.3 * big[::-1])):
        F_ref = sla.expm(ex.magnus_block(varpi, vd, dt, order))
        assert _rel(prior.transition(varpi, vd, dt), F_ref) < 1e-12


@given(motion=vehicle_motion())
def test_transition_matches_fd_of_mean_flow(motion):
    """F_k vs the finite-difference Jacobian of the (order-3) Magnus mean flow under left perturbations.

    F11, F12 are the exact derivative (S12 = d sigma / d varpi); F13 = dt H S12 differs at O(dt^5 |vd| ...):
    measured <= ~1e-7 at dt = 1/13 s for vehicle motion."""
    varpi, vd = motion
    prior = ConstantAccelerationPrior(QC)
    T_ref, w_ref, v_ref = prior.predict(T0, varpi, vd, DT)

    def flow(d):
        T, w, v = prior.predict(se3.exp(d[:6]) @ T0, varpi + d[6:12], vd + d[12:], DT)
        return np.r_[se3.log(T @ se3.inverse(T_ref)), w - w_ref, v - v_ref]

    J = numerical_jacobian(flow, np.zeros(18), eps=1e-5)
    F = prior.transition(varpi, vd, DT)
    assert np.abs(F[:, :12] - J[:, :12]).max() < 1e-8
    assert np.abs(F - J).max() < 2e-7


@pytest.mark.parametrize("order, tol", [(3, 2e-7), (4, 5e-9)])
@given(motion=vehicle_motion())
def test_transition_matches_exact_ode(order, tol, motion):
    varpi, vd = motion
    F = ConstantAccelerationPrior(QC, magnus_order=order).transition(varpi, vd, DT)
    assert _rel(F, ex.exact_transition(varpi, vd, DT)) < tol


# ---------------------------------------------------------------------------------------------- Q_k
@pytest.mark.parametrize("order", [1, 2, 3, 4])
@settings(max_examples=30)  # x4 orders
@given(motion=vehicle_motion(), dt=st.floats(0.01, 1.0), big=twists("any", 30.0))
def test_process_noise_matches_van_loan_of_full_magnus_block(order, motion, dt, big):
    """Q_k (quadrature of the closed-form E(u) L) = G F^T from scipy expm of the 36x36 S_M (eq. 44-48)."""
    prior = ConstantAccelerationPrior(QC_FULL, magnus_order=order)
    for varpi, vd in (motion, (big, 0.3 * big[::-1])):
        F, Q = prior.transition_and_noise(varpi, vd, dt)
        F_ref, Q_ref = ex.magnus_van_loan(varpi, vd, dt, QC_FULL, order)
        assert _rel(Q, Q_ref) < 1e-12
        assert _rel(F, F_ref) < 1e-12
        np.testing.assert_array_equal(Q, Q.T)
        assert np.linalg.eigvalsh(Q)[0] > 0
        # the velocity/acceleration block is exactly the WNOJ lower block
        lower = np.kron(np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]), QC_FULL)
        np.testing.assert_allclose(Q[6:, 6:], lower, rtol=1e-14, atol=0)


@settings(max_examples=15)
@given(motion=vehicle_motion())
def test_process_noise_whitened_error_against_exact_integral(motion):
    """The paper's Q_k (G truncated at the coupling L Qc L^T dt) vs the exact integral: <= 1e-3 whitened at
    13 Hz for a vehicle-like Qc (measured max 4.3e-4; the value grows with Qc's condition number: ~1.1e-3 for
    Qc = I, ~4e-3 for the dense QC_FULL, because whitening amplifies the small directions)."""
    varpi, vd = motion
    Q = ConstantAccelerationPrior(QC).process_noise(varpi, vd, DT)
    assert _whitened(Q, ex.exact_process_noise(varpi, vd, DT, QC)) <= 1e-3


@settings(max_examples=15)
@given(motion=vehicle_motion())
def test_subinterval_noise_is_closer_to_exact_integral(motion):
    """noise="subinterval" (docs/priors.md sec. 4b): measured ~3e-5 (order 3) and ~5e-7 (order 4) whitened at
    13 Hz for this Qc, against ~4e-4 for the paper's G F^T; F_k is unchanged."""
    varpi, vd = motion
    Qex = ex.exact_process_noise(varpi, vd, DT, QC)
    for order, tol in ((3, 1e-4), (4, 3e-6)):
        prior = ConstantAccelerationPrior(QC, magnus_order=order, noise="subinterval")
        F, Q = prior.transition_and_noise(varpi, vd, DT)
        assert _whitened(Q, Qex) <= tol
        np.testing.assert_array_equal(F, ConstantAccelerationPrior(QC, order).transition(varpi, vd, DT))
        np.testing.assert_array_equal(Q, Q.T)
        np.testing.assert_allclose(Q[6:, 6:], ConstantAccelerationPrior(QC, order).process_noise(varpi, vd, DT)[6:, 6:],
                                   rtol=1e-14, atol=0)


def test_subinterval_noise_converges_faster():
    """Whitened error vs dt: paper ~dt^2, subinterval ~dt^3 (order 3) and ~dt^4 (order 4)."""
    dts = (2 * DT, DT, DT / 2)
    for order, noise, slope in ((3, "paper", 2.0), (3, "subinterval", 3.0), (4, "subinterval", 4.0)):
        prior = ConstantAccelerationPrior(QC, magnus_order=order, noise=noise)
        errs = [_whitened(prior.process_noise(VARPI, VD, dt), ex.exact_process_noise(VARPI, VD, dt, QC))
                for dt in dts]
        np.testing.assert_allclose(np.log2(np.array(errs[:-1]) / errs[1:]), slope, atol=0.3)


def test_process_noise_error_shrinks_like_dt_squared():
    prior = ConstantAccelerationPrior(QC)
    errs = [_whitened(prior.process_noise(VARPI, VD, dt), ex.exact_process_noise(VARPI, VD, dt, QC))
            for dt in (2 * DT, DT, DT / 2)]
    np.testing.assert_allclose(np.log2(np.array(errs[:-1]) / errs[1:]), 2.0, atol=0.15)
    assert errs[1] < 1e-3


@pytest.mark.parametrize("order", [1, 2, 3])
def test_noise_cross_blocks_match_series(order):
    """Orders <= 3 (S13 = 0): Q13 = dt^2 H3(sigma) S12 Qc, Q12 = dt^3 sum (n+3) S^n/(n+4)! S12 Qc (docs/priors.md)."""
    from math import factorial

    dt = 0.3
    prior = ConstantAccelerationPrior(QC_FULL, order)
    Q = prior.process_noise(VARPI, VD, dt)
    S = se3.curlyhat(prior.magnus_sigma(VARPI, VD, dt))
    S12 = ex.magnus_block(VARPI, VD, dt, order)[:6, 6:12]
    P = [np.linalg.matrix_power(S, n) for n in range(40)]
    H3 = sum(P[n] / factorial(n + 3) for n in range(40))
    K4 = sum((n + 3) * P[n] / factorial(n + 4) for n in range(40))
    assert _rel(Q[:6, 12:], dt**2 * H3 @ S12 @ QC_FULL) < 1e-14
    assert _rel(Q[:6, 6:12], dt**3 * K4 @ S12 @ QC_FULL) < 1e-14


@pytest.mark.parametrize("noise", ["paper", "subinterval"])
@pytest.mark.parametrize("order", [1, 2, 3, 4])
@pytest.mark.parametrize("dt", [DT, 0.5, 2.0])
def test_zero_motion_gives_classic_wnoj_forms(order, dt, noise):
    F, Q = ConstantAccelerationPrior(QC_FULL, order, noise).transition_and_noise(np.zeros(6), np.zeros(6), dt)
    F_ref = np.kron(np.array([[1, dt, dt**2 / 2], [0, 1, dt], [0, 0, 1]]), np.eye(6))
    Q_ref = np.kron(np.array([[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                              [dt**3 / 6, dt**2 / 2, dt]]), QC_FULL)
    assert np.abs(F - F_ref).max() <= 1e-15 * np.abs(F_ref).max()
    assert np.abs(Q - Q_ref).max() <= 1e-15 * np.abs(Q_ref).max()


@pytest.mark.parametrize("noise", ["paper", "subinterval"])
@given(motion=vehicle_motion(), extra=vehicle_motion(), dt=st.floats(0.01, 0.5))
def test_batched_forms_equal_single_calls(motion, extra, dt, noise):
    prior = ConstantAccelerationPrior(QC_FULL, magnus_order=4, noise=noise)
    varpi = np.stack([motion[0], extra[0], np.zeros(6)])
    vd = np.stack([motion[1], extra[1], np.zeros(6)])
    dts = np.array([dt, DT, 1.0])
    F, Q = prior.transition_and_noise_batch(varpi, vd, dts)
    same = _close_to_rounding  # the kernels are compiled separately (fast-math contraction may differ)
    for i in range(3):
        Fi, Qi = prior.transition_and_noise(varpi[i], vd[i], dts[i])
        same(F[i], Fi)
        same(Q[i], Qi)
        same(prior.transition(varpi[i], vd[i], dts[i]), Fi)
        same(prior.process_noise(varpi[i], vd[i], dts[i]), Qi)
    same(prior.transition_batch(varpi, vd, dts), F)
    same(prior.process_noise_batch(varpi, vd, dt), prior.process_noise_batch(varpi, vd, np.full(3, dt)))
    bufs = (np.empty((3, 18, 18)), np.empty((3, 18, 18)))
    F2, Q2 = prior.transition_and_noise_batch(varpi, vd, dts, out=bufs)
    assert F2 is bufs[0] and Q2 is bufs[1]
    same(F2, F)
    same(Q2, Q)


def test_exact_prior_class_matches_references():
    prior = ex.ExactConstantAccelerationPrior(QC)
    F, Q = prior.transition_and_noise(VARPI, VD, DT)
    np.testing.assert_array_equal(F, ex.exact_transition(VARPI, VD, DT))
    np.testing.assert_array_equal(Q, ex.exact_process_noise(VARPI, VD, DT, QC))
    assert _rel(F, ConstantAccelerationPrior(QC).transition(VARPI, VD, DT)) < 1e-6
    # with the exact F the residual Jacobian is the exact derivative: FD of the exact flow agrees closely
    T2 = se3.exp(np.full(6, 0.01)) @ ex.exact_predict(T0, VARPI, VD, DT)[0]
    e, J1, _ = prior.residual(T0, VARPI, VD, T2, VARPI, VD, DT)
    Jfd = numerical_jacobian(lambda d: prior.residual(se3.exp(d[:6]) @ T0, VARPI + d[6:12], VD + d[12:],
                                                      T2, VARPI, VD, DT)[0], np.zeros(18), eps=1e-5)
    assert np.abs(J1 - Jfd).max() < 1e-7


# ---------------------------------------------------------------------------------------------- residual
@pytest.mark.parametrize("order", [3, 4])
@settings(max_examples=25)  # each example is ~40 finite-difference residual evaluations
@given(motion=vehicle_motion(), d2=vectors(18, 0.05), xi1=twists("vehicle"))
def test_residual_jacobians_match_finite_differences(order, motion, d2, xi1):
    """J_e_x2 is exact (FD to ~1e-9); J_e_x1 = -diag(J(-e)^-1, I, I) F_k matches FD to ~2e-7 (measured
    <= ~1e-7 at dt = 1/13 s: F13 is the paper's approximation of the Magnus-mean derivative)."""
    varpi, vd = motion
    prior = ConstantAccelerationPrior(QC, magnus_order=order)
    T1 = se3.exp(xi1)
    Tp, wp, vp = prior.predict(T1, varpi, vd, DT)
    T2, w2, v2 = se3.exp(d2[:6]) @ Tp, wp + d2[6:12], vp + d2[12:]
    e, J1, J2 = prior.residual(T1, varpi, vd, T2, w2, v2, DT)
    np.testing.assert_allclose(e, d2, atol=1e-9)

    def res1(d):
        return prior.residual(se3.exp(d[:6]) @ T1, varpi + d[6:12], vd + d[12:], T2, w2, v2, DT)[0]

    def res2(d):
        return prior.residual(T1, varpi, vd, se3.exp(d[:6]) @ T2, w2 + d[6:12], v2 + d[12:], DT)[0]

    assert np.abs(J2 - numerical_jacobian(res2, np.zeros(18), eps=1e-5)).max() < 1e-8
    assert np.abs(J1 - numerical_jacobian(res1, np.zeros(18), eps=1e-5)).max() < 2e-7


# ---------------------------------------------------------------------------------------------- bad input
def _calls(prior):
    T, w, v = np.eye(4), VARPI, VD
    return {
        "predict": lambda T=T, w=w, v=v, dt=DT: prior.predict(T, w, v, dt),
        "transition": lambda T=T, w=w, v=v, dt=DT: prior.transition(w, v, dt),
        "process_noise": lambda T=T, w=w, v=v, dt=DT: prior.process_noise(w, v, dt),
        "transition_and_noise": lambda T=T, w=w, v=v, dt=DT: prior.transition_and_noise(w, v, dt),
        "transition_batch": lambda T=T, w=w, v=v, dt=DT: prior.transition_batch(np.atleast_2d(w),
                                                                                 np.atleast_2d(v), dt),
        "process_noise_batch": lambda T=T, w=w, v=v, dt=DT: prior.process_noise_batch(np.atleast_2d(w),
                                                                                       np.atleast_2d(v), dt),
        "residual": lambda T=T, w=w, v=v, dt=DT: prior.residual(T, w, v, np.eye(4), VARPI, VD, dt),
        "magnus_sigma": lambda T=T, w=w, v=v, dt=DT: prior.magnus_sigma(w, v, dt),
    }


NAN6 = np.r_[np.nan, np.zeros(5)]
BAD = [("varpi", dict(w=NAN6)), ("varpi", dict(w=np.zeros(5))), ("varpi_dot", dict(v=np.r_[np.inf, np.zeros(5)])),
       ("varpi_dot", dict(v=np.zeros((6, 2)))), ("dt", dict(dt=0.0)), ("dt", dict(dt=-1.0)),
       ("dt", dict(dt=np.nan)), ("dt", dict(dt="soon"))]


@pytest.mark.parametrize("method", list(_calls(ConstantAccelerationPrior(QC))))
@pytest.mark.parametrize("name, kwargs", BAD)
def test_bad_input_names_the_argument(method, name, kwargs):
    call = _calls(ConstantAccelerationPrior(QC))[method]
    with pytest.raises(InputError, match=name):
        call(**kwargs)


@pytest.mark.parametrize("method", ["predict", "residual"])
@pytest.mark.parametrize("T, why", [(np.full((4, 4), np.nan), "NaN"), (np.zeros((3, 4)), "shape"),
                                    (np.ones((4, 4)), "bottom row")])
def test_bad_pose(method, T, why):
    with pytest.raises(InputError, match=f"T.*{why}|{why}"):
        _calls(ConstantAccelerationPrior(QC))[method](T=T)


@pytest.mark.parametrize("Qc, why", [(np.eye(5), "shape"), (np.diag([1, 1, 1, 1, 1, -1.0]), "positive definite"),
                                     (np.eye(6) + np.triu(np.ones((6, 6)), 1), "symmetric"),
                                     (np.full((6, 6), np.nan), "NaN")])
def test_bad_qc(Qc, why):
    with pytest.raises(InputError, match=f"Qc.*{why}"):
        ConstantAccelerationPrior(Qc)


@pytest.mark.parametrize("order", [0, 5, 2.5, "3", True])
def test_bad_magnus_order(order):
    with pytest.raises(InputError, match="magnus_order"):
        ConstantAccelerationPrior(QC, magnus_order=order)


@pytest.mark.parametrize("noise", ["exact", None, "Paper"])
def test_bad_noise_model(noise):
    with pytest.raises(InputError, match="noise"):
        ConstantAccelerationPrior(QC, noise=noise)


def test_bad_batches():
    prior = ConstantAccelerationPrior(QC)
    w = np.zeros((3, 6))
    with pytest.raises(InputError, match="varpi_dot.*3 rows"):
        prior.transition_batch(w, np.zeros((2, 6)), 0.1)
    with pytest.raises(InputError, match="dt"):
        prior.process_noise_batch(w, w, np.array([0.1, 0.1, 0.0]))
    with pytest.raises(InputError, match="dt.*shape"):
        prior.process_noise_batch(w, w, np.ones(2))
    with pytest.raises(InputError, match="varpi.*N, 6"):
        prior.transition_and_noise_batch(np.zeros(6), np.zeros(6), 0.1)
    with pytest.raises(InputError, match="out"):
        prior.transition_and_noise_batch(w, w, 0.1, out=(np.empty((3, 18, 18)), np.empty((3, 18, 18), np.float32)))
    with pytest.raises(InputError, match="out"):
        prior.transition_batch(w, w, 0.1, out=np.empty((2, 18, 18)))
    with pytest.raises(InputError, match="broadcast"):
        prior.predict(np.stack([np.eye(4)] * 2), np.zeros((3, 6)), VD, 0.1)
