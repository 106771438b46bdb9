"""The Cramér-Rao bound of Qc without ground truth (validation.qc_information): the Monte Carlo score variance
against the exact Fisher information of a Gaussian model written out whole, and the information a Kalman filter's
covariances give against its measurement's."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.validation import calibrate as cal
from rodo.validation import em_surrogate as ems
from rodo.validation import qc_information as qi
from tests.validation.test_calibrate import QC, _rng, draw_ca_tracks
from tests.validation.test_em_surrogate import SIG, kalman_filter, measure

DT, K = 0.1, 30


def _axes_model(q, sigmas):
    """Two constant-acceleration axes (position, velocity, acceleration each), white jerk of PSD q_i; each
    interval's noise basis B (K, 2, 6, 6), transitions F (K, 6, 6); the first velocity and the sum of the two
    velocities measured with sigmas (a coupling: the information matrix is not diagonal)."""
    f = np.array([[1, DT, DT**2 / 2], [0, 1, DT], [0, 0, 1]])
    b = np.array([[DT**5 / 20, DT**4 / 8, DT**3 / 6], [DT**4 / 8, DT**3 / 3, DT**2 / 2], [DT**3 / 6, DT**2 / 2, DT]])
    F = np.broadcast_to(np.kron(np.eye(2), f), (K, 6, 6)).copy()
    B = np.zeros((K, 2, 6, 6))
    B[:, 0, :3, :3], B[:, 1, 3:, 3:] = b, b
    H = np.zeros((2, 6))
    H[0, 1], H[1, 1], H[1, 4] = 1.0, 1.0, 1.0
    R = np.diag(np.asarray(sigmas) ** 2)
    return F, B, H, R


def _exact_fisher(F, B, q, H, R, P0):
    """I_ij = 1/2 tr(C^-1 dC/dq_i C^-1 dC/dq_j) q_i q_j of the stacked measurements y_k = H x_k + v_k, k >= 1,
    whose covariance C is written out whole (x = A [x_0; w_1 ... w_K])."""
    d = F.shape[-1]
    A = np.zeros(((K + 1) * d, (K + 1) * d))
    for k in range(K + 1):
        block = np.eye(d)
        for j in range(k, -1, -1):
            A[k * d:(k + 1) * d, j * d:(j + 1) * d] = block
            block = block @ F[j - 1] if j > 0 else block
    Hs = np.kron(np.eye(K + 1), H)[H.shape[0]:]  # no measurement of x_0

    def cov(S_blocks):
        S = np.zeros_like(A)
        for k, blk in enumerate(S_blocks):
            S[k * d:(k + 1) * d, k * d:(k + 1) * d] = blk
        return Hs @ A @ S @ A.T @ Hs.T

    Q = np.einsum("i,kiab->kab", q, B)
    C = cov([P0, *Q]) + np.kron(np.eye(K), R)
    dC = [cov([np.zeros((d, d)), *B[:, i]]) for i in range(len(q))]
    Ci = np.linalg.inv(C)
    info = np.array([[0.5 * np.trace(Ci @ a @ Ci @ b) for b in dC] for a in dC])
    return info * np.outer(q, q)


@settings(max_examples=6)
@given(q=st.tuples(*[st.floats(-2.0, 1.0)] * 2).map(lambda t: 10.0 ** np.array(t)),
       sigmas=st.tuples(*[st.floats(-2.0, 0.0)] * 2).map(lambda t: 10.0 ** np.array(t)))
def test_the_score_variance_is_the_exact_fisher_information(q, sigmas):
    """Within the Monte Carlo's own error (20000 datasets; a component the data say little about has a heavy-tailed
    score, whose variance 4000 datasets gave only to about 10 %)."""
    F, B, H, R = _axes_model(q, sigmas)
    P0 = np.diag([1.0, 0.1, 0.1, 1.0, 0.1, 0.1])
    info = np.concatenate([np.zeros((1, 6, 6)), np.broadcast_to(H.T @ np.linalg.inv(R) @ H, (K, 6, 6))])
    exact = _exact_fisher(F, B, q, H, R, P0)
    mc = qi.fisher_information(F, B, q, info, P0, samples=20000, rng=_rng(31))
    scale = np.sqrt(np.outer(np.diag(exact), np.diag(exact)))
    np.testing.assert_allclose(mc / scale, exact / scale, atol=0.1)


def test_a_kalman_filters_scan_information_is_its_measurement():
    """For a Kalman filter P_k^-1 = (F P_{k-1} F^T + Q)^-1 + H^T R^-1 H: the information the stand-in reads back from
    its covariances (one per scan after the first) is its measurement's (pose and velocity, test_calibrate's
    filter)."""
    track = draw_ca_tracks(QC, 1, 20, _rng(32))[0]
    filtered = kalman_filter(track, measure(track, _rng(33)), QC)
    (part,) = ems.surrogates("ca", filtered, QC)
    info = part.info
    H, R = np.eye(12, 18), np.diag(SIG**2)
    expected = H.T @ np.linalg.inv(R) @ H
    assert info.shape == (20, 18, 18)
    np.testing.assert_allclose(info / np.sqrt(np.outer(np.diag(expected) + 1, np.diag(expected) + 1)),
                               np.broadcast_to(expected, info.shape)
                               / np.sqrt(np.outer(np.diag(expected) + 1, np.diag(expected) + 1)), atol=1e-6)


@pytest.fixture(scope="module")
def filtered_drive():
    track = draw_ca_tracks(QC, 1, 60, _rng(34))[0]
    return kalman_filter(track, measure(track, _rng(35)), QC)


def test_the_bound_of_a_drive(filtered_drive):
    """Rows per component; a component not learned has no bound and leaves the others' bound at most as
    tight (it is known there); a drive broken by a re-initialisation holds less information than the whole; the
    same seed gives the same bound, bit for bit."""
    rows = qi.qc_bound("ca", filtered_drive, QC, QC, samples=600)
    assert [r["component"] for r in rows] == list(cal.COMPONENTS)
    sd = np.array([r["sd_log"] for r in rows])
    assert np.all(np.isfinite(sd) & (sd > 0))
    assert [r["within_95"] for r in rows] == list(sd <= qi.SD_FOR_WITHIN)
    assert rows == qi.qc_bound("ca", filtered_drive, QC, QC, samples=600)
    learned = np.array([True, False, False, False, False, True])
    some = qi.qc_bound("ca", filtered_drive, QC, QC, learned=learned, samples=600)
    assert [r["sd_log"] is None for r in some] == list(~learned)
    assert all(s["sd_log"] <= r["sd_log"] * 1.05 for s, r in zip(some, rows) if s["learned"])
    valid = np.ones(60, bool)
    valid[30] = False
    broken = qi.qc_bound("ca", dataclasses.replace(filtered_drive, valid=valid), QC, QC, samples=600)
    assert [s.stop - s.start for s in ems.segments(dataclasses.replace(filtered_drive, valid=valid))] == [31, 30]
    assert np.mean([b["sd_log"] / r["sd_log"] for b, r in zip(broken, rows)]) > 1.0
