"""SO(3)/SE(3): group axioms, exp/log round trips in every regime, closed forms against series, Jacobians."""

from math import factorial

import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator.lie import se3, so3
from rodo.estimator.lie import _series
from tests.helpers import numerical_jacobian
from tests.strategies import rotation_vectors, twists

REGIMES = ["tiny", "vehicle", "near_pi", "any"]


def _series_sum(S, shift, terms=80):
    out = np.zeros_like(S)
    P = np.eye(S.shape[-1])
    for n in range(terms):
        out = out + P / float(factorial(n + shift))  # a float: numpy 1.x makes 81! an object array
        P = P @ S
    return out


@pytest.mark.parametrize("regime", REGIMES)
@given(data=st.data())
def test_so3_exp_matches_expm_and_log_inverts(regime, data):
    phi = data.draw(rotation_vectors(regime))
    C = so3.exp(phi)
    np.testing.assert_allclose(C, sla.expm(so3.hat(phi)), atol=1e-14)
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(C) == pytest.approx(1.0, abs=1e-14)
    # near pi the axis of log(C) is determined up to 1e-16 / sin(phi) (the problem's own conditioning)
    tol = 1e-12 if regime != "near_pi" else 1e-7
    np.testing.assert_allclose(so3.log(C), phi, atol=tol)


@pytest.mark.parametrize("regime", REGIMES)
@given(data=st.data())
def test_se3_exp_log_round_trip(regime, data):
    xi = data.draw(twists(regime))
    T = se3.exp(xi)
    np.testing.assert_allclose(T, sla.expm(se3.hat(xi)), atol=1e-12 * max(1, np.abs(xi).max()))
    tol = 1e-11 if regime != "near_pi" else 1e-6
    np.testing.assert_allclose(se3.log(T), xi, atol=tol)


@given(a=twists("any"), b=twists("any"), c=twists("vehicle"))
def test_group_axioms(a, b, c):
    A, B, Cm = se3.exp(a), se3.exp(b), se3.exp(c)
    np.testing.assert_allclose((A @ B) @ Cm, A @ (B @ Cm), atol=1e-10)
    np.testing.assert_allclose(A @ se3.inverse(A), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(se3.inverse(A), np.linalg.inv(A), atol=1e-11)
    # adjoint: T exp(x^) T^-1 = exp((Ad(T) x)^); Ad is a homomorphism
    np.testing.assert_allclose(A @ se3.exp(c) @ se3.inverse(A), se3.exp(se3.adjoint(A) @ c), atol=1e-9)
    np.testing.assert_allclose(se3.adjoint(A @ B), se3.adjoint(A) @ se3.adjoint(B), atol=1e-10)


@given(a=twists("any"), b=twists("any"))
def test_curlyhat_is_the_lie_bracket(a, b):
    bracket = se3.hat(a) @ se3.hat(b) - se3.hat(b) @ se3.hat(a)
    np.testing.assert_allclose(se3.hat(se3.curlyhat(a) @ b), bracket, atol=1e-12)
    np.testing.assert_allclose(se3.adjoint(se3.exp(a)), sla.expm(se3.curlyhat(a)), atol=1e-10)


@given(a=twists("any"), scale=st.floats(1e-3, 1e3), zero=st.booleans())
def test_inverse_of_one_pose_is_the_batched_inverse_bit_for_bit(a, scale, zero):
    """`se3.inverse`'s path for one (4, 4) pose computes the batched path's sums in its order: equal bits, the
    signs of zeros too (a translation of -0), whatever the memory layout."""
    T = se3.exp(a * np.r_[np.full(3, scale), np.ones(3)])
    if zero:
        T[:3, 3] = -0.0
    one = se3.inverse(T)
    for other in (se3.inverse(T[None])[0], se3.inverse(np.asfortranarray(T)), se3.inverse(np.stack([T, T]))[1]):
        assert np.array_equal(one, other) and np.array_equal(np.signbit(one), np.signbit(other))
    np.testing.assert_allclose(one, np.linalg.inv(T), atol=1e-9 * max(1.0, scale))


@pytest.mark.parametrize("shape", [(), (5,), (2, 3)])
def test_batched_inputs_match_single(shape):
    rng = np.random.default_rng(1)
    xi = rng.normal(size=shape + (6,))
    flat = xi.reshape(-1, 6)
    for fn in (se3.exp, se3.curlyhat, se3.left_jacobian, se3.left_jacobian_inv, se3.h_matrix):
        batched = fn(xi)
        single = np.stack([fn(x) for x in flat]).reshape(batched.shape)
        np.testing.assert_allclose(batched, single, atol=1e-15)
    np.testing.assert_allclose(se3.log(se3.exp(xi)), xi, atol=1e-12)


@pytest.mark.parametrize("phi", np.r_[1e-6, np.geomspace(1e-5, 7.0, 40)])
def test_h_and_j_against_their_series(phi):
    """H = sum S^n/(n+2)! and J = sum S^n/(n+1)! to 1e-12 for phi in [1e-6, 7] (issue 2)."""
    rng = np.random.default_rng(int(phi * 1e6) % 2**32)
    axis = rng.normal(size=3)
    xi = np.r_[rng.normal(size=3) * 2.0, axis / np.linalg.norm(axis) * phi]
    S = se3.curlyhat(xi)
    np.testing.assert_allclose(se3.h_matrix(xi), _series_sum(S, 2), atol=1e-12)
    np.testing.assert_allclose(se3.left_jacobian(xi), _series_sum(S, 1), atol=1e-12)
    np.testing.assert_allclose(se3.left_jacobian_inv(xi) @ se3.left_jacobian(xi), np.eye(6), atol=1e-11)


def test_h_alpha_reference_values_at_phi_one():
    """docs/paper_notes.md reference: alpha(phi=1) = [0.16647369091, 0.04164241001, 0.00794467572, 0.00134010414]."""
    alpha_closed = se3._h_closed(np.array(1.0))[1:]
    alpha_taylor = _series.horner(_series.SE3_H, np.array(1.0))[1:]
    ref = [0.16647369091, 0.04164241001, 0.00794467572, 0.00134010414]
    np.testing.assert_allclose(alpha_closed, ref, atol=1e-11)
    np.testing.assert_allclose(alpha_taylor, ref, atol=1e-11)


@pytest.mark.parametrize("angle", [0.9, 1.0, 1.2, 1.5])
def test_taylor_coefficients_match_closed_forms(angle):
    """Where both branches are accurate they must agree: the Taylor series are derived, not typed.

    (Below ~0.9 rad the closed forms themselves lose digits: alpha_4 is 1e-11 off at 0.5 rad.)
    """
    a = np.array(angle)
    pairs = [(_series.SE3_H, se3._h_closed), (_series.SE3_JAC, se3._jac_closed),
             (_series.SO3_EXP, so3._exp_closed), (_series.SO3_JAC, so3._jac_closed),
             (_series.SO3_JAC_INV, so3._jac_inv_closed)]
    for taylor, closed in pairs:
        np.testing.assert_allclose(_series.horner(taylor, a**2), closed(a), rtol=1e-12, atol=1e-15)


@given(xi=twists("vehicle"))
def test_left_jacobian_relates_exp_of_sum(xi):
    """exp((xi + d)^) = exp((J(xi) d)^) exp(xi^) to first order: J by finite differences on the manifold."""
    T = se3.exp(xi)
    f = lambda d: se3.log(se3.exp(xi + d) @ se3.inverse(T))
    np.testing.assert_allclose(numerical_jacobian(f, np.zeros(6)), se3.left_jacobian(xi), atol=1e-7)
    g = lambda d: se3.log(se3.exp(d) @ T)
    np.testing.assert_allclose(numerical_jacobian(g, np.zeros(6)), se3.left_jacobian_inv(xi), atol=1e-7)
    np.testing.assert_allclose(se3.right_jacobian(xi), se3.adjoint(se3.inverse(T)) @ se3.left_jacobian(xi),
                               atol=1e-12)


@given(phi=rotation_vectors("any"))
def test_quaternion_round_trip(phi):
    C = so3.exp(phi)
    q = so3.to_quaternion(C)
    assert np.linalg.norm(q) == pytest.approx(1.0) and q[3] >= 0
    np.testing.assert_allclose(so3.from_quaternion(q), C, atol=1e-14)


def test_transform_points_frame_indices_cancel():
    rng = np.random.default_rng(3)
    T_a_b, T_b_c = se3.exp(rng.normal(size=6)), se3.exp(rng.normal(size=6))
    p_c = rng.normal(size=(10, 3))
    p_a = se3.transform_points(T_a_b, se3.transform_points(T_b_c, p_c))
    np.testing.assert_allclose(p_a, se3.transform_points(T_a_b @ T_b_c, p_c), atol=1e-13)


@pytest.mark.parametrize("shape", [(), (5,), (2, 3)])
def test_quaternion_agrees_with_scipy(shape):
    """so3's quaternions are scipy's (Hamilton, [qx, qy, qz, qw], qw >= 0): scipy appears here only as the
    reference; rodo itself has one implementation. Samples: random, near identity, near a half turn."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(11)
    axis = rng.normal(size=shape + (3,))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    for angle in (rng.uniform(0, np.pi, size=shape), np.full(shape, 1e-9), np.full(shape, np.pi - 1e-6)):
        phi = axis * angle[..., None]
        C = so3.exp(phi)
        q = so3.to_quaternion(C)
        assert q.shape == shape + (4,)
        ref = Rotation.from_rotvec(phi.reshape(-1, 3)).as_quat().reshape(shape + (4,))
        ref = np.where(ref[..., 3:4] < 0, -ref, ref)
        np.testing.assert_allclose(q, ref, atol=1e-12)
        np.testing.assert_allclose(so3.from_quaternion(ref), Rotation.from_quat(ref.reshape(-1, 4)).as_matrix()
                                   .reshape(shape + (3, 3)), atol=1e-14)
        np.testing.assert_allclose(so3.from_quaternion(-q), C, atol=1e-14)  # q and -q: one rotation


def test_one_quaternion_implementation():
    """Outside the tests, no module converts quaternions with scipy's Rotation: everything goes through
    estimator.lie.so3 (to_quaternion / from_quaternion)."""
    import re
    from pathlib import Path

    scipy_quat = re.compile(r"\b(as_quat|from_quat)\(|spatial\.transform|\bRotation\.")
    root = Path(__file__).resolve().parents[2]
    offenders = [str(p.relative_to(root)) for pkg in ("estimator", "sim", "scenarios", "validation", "viz", "rodo")
                 for p in (root / pkg).rglob("*.py")
                 if scipy_quat.search(p.read_text())]
    assert offenders == []
