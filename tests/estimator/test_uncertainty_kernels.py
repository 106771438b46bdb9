"""The compiled per-scan uncertainty (rodo.estimator.uncertainty_kernels) against the readable references of
rodo.estimator.uncertainty: equal to rounding, on random poses and covariances."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.estimator.lie import se3
from rodo.estimator.uncertainty import (DriftCovariance, _initial, _step, relative_pose_covariance,
                                        revision_covariance, scan_relative_covariances)
from tests.strategies import covariances, twists


def _close(got: np.ndarray, want: np.ndarray, scale: float) -> None:
    """Equal to rounding: the references' entries come from sums of terms up to `scale`."""
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13 * scale)


def _pair_scale(P: np.ndarray, T_prev: np.ndarray, T_new: np.ndarray) -> float:
    Ad = se3.adjoint(T_new @ se3.inverse(T_prev))
    return float(np.abs(P).max() * max(1.0, np.abs(Ad).max()) ** 2 * 36)


@given(a=twists("vehicle", 30.0), b=twists("any", 30.0), dim=st.sampled_from([6, 12, 18]),
       pair=covariances(36, 1e-4, 0.3), change=covariances(6, 1e-4, 0.3), lost=covariances(6, 1e-4, 0.3),
       solved=st.booleans())
@settings(max_examples=25)
def test_relative_covariances_equal_the_references(a, b, dim, pair, change, lost, solved):
    """The scan's relative pose covariance and its revision, one compiled call, against
    `relative_pose_covariance` and `revision_covariance`: with a revision that added information in some
    directions and lost it in others (the clipping to positive semi-definite matters), and zeros when the
    previous pose was not emitted as solved."""
    T_prev, T_new = se3.exp(a), se3.exp(b)
    P_pair = np.ascontiguousarray(pair[:2 * dim, :2 * dim])
    P_emitted = P_pair[:dim, :dim].copy()
    P_emitted[:6, :6] += change - lost  # indefinite in general
    rel, rev = scan_relative_covariances(P_pair, P_emitted, T_prev, T_new, dim, solved)
    scale = _pair_scale(P_pair + np.pad(change + lost, (0, 2 * dim - 6)), T_prev, T_new)
    _close(rel, relative_pose_covariance(P_pair, T_prev, T_new, dim), scale)
    want = revision_covariance(P_emitted, P_pair, T_prev, T_new) if solved else np.zeros((6, 6))
    _close(rev, want, scale)
    assert np.array_equal(rel, rel.T) and np.array_equal(rev, rev.T)
    if not solved:
        assert not rev.any()


@given(a=twists("vehicle", 30.0), b=twists("vehicle", 30.0), C=covariances(18, 1e-4, 1.0),
       Sigma_rel=covariances(6, 1e-4, 0.1), P_varpi=covariances(6, 1e-4, 0.5),
       tau=st.sampled_from([0.0, 0.05, 0.35, 3.0]), dt=st.floats(0.01, 0.5))
@settings(max_examples=25)
def test_drift_step_equals_the_reference(a, b, C, Sigma_rel, P_varpi, tau, dt):
    """One scan of the drift recursion (`DriftCovariance.update`, compiled) against `_step`: with and without the
    velocity error's correlation (tau 0), the absolute covariance it returns and the state it keeps."""
    T_prev, T_new = se3.exp(a), se3.exp(b)
    drift = DriftCovariance(np.eye(6), np.eye(6), tau)
    drift.C = C.copy()
    P_abs = drift.update(T_prev, T_new, dt, Sigma_rel, P_varpi)
    want = _step(C, T_prev, T_new, dt, Sigma_rel, P_varpi, tau)
    R = T_new @ se3.inverse(T_prev)
    largest = max(1.0, np.abs(se3.adjoint(R)).max(), np.linalg.norm(R[:3, 3]))  # of the recursion's matrix A
    scale = float(np.abs(C).max() * largest**2 * 18 + np.abs(Sigma_rel).max() + np.abs(P_varpi).max())
    _close(drift.C, want, scale)
    _close(P_abs, want[:6, :6], scale)
    assert np.array_equal(drift.C, drift.C.T)


def test_a_drive_of_drift_steps_stays_the_recursion():
    """Two hundred scans of a turning drive: the compiled recursion stays within rounding of `_step`'s (the
    errors do not grow), as the validation's replays of a run assume."""
    rng = np.random.default_rng(np.random.SeedSequence(31))
    T = [se3.exp(np.array([-10.0 * k / 13, 0, 0, 0, 0, 0.2 * k / 13])) for k in range(201)]
    drift = DriftCovariance(1e-6 * np.eye(6), 1e-4 * np.eye(6), 0.35, [1e-4, 1e-5, 3e-4, 2e-5, 2e-5, 4e-6])
    C = drift.C.copy()
    assert np.array_equal(C, _initial(1e-6 * np.eye(6), 1e-4 * np.eye(6), 0.35, [1e-4, 1e-5, 3e-4, 2e-5, 2e-5, 4e-6]))
    for k in range(1, 201):
        A = rng.normal(size=(6, 6)) * 1e-3
        Sigma_rel, P_varpi = A @ A.T, 1e-4 * np.eye(6) + 10 * A @ A.T
        drift.update(T[k - 1], T[k], 1 / 13, Sigma_rel, P_varpi)
        C = _step(C, T[k - 1], T[k], 1 / 13, Sigma_rel, P_varpi, 0.35)
    np.testing.assert_allclose(drift.C, C, rtol=1e-11, atol=1e-13 * np.abs(C).max())
