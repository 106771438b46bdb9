"""EM's check without ground truth (validation/velocity_growth.py): the growth kernel against the exact covariance of
the prior's linear velocity SDE, the estimate and its interval against Monte Carlo tracks drawn from that SDE with a
bounded, correlated estimation error added, and the check flagging an EM that books that error as motion."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo.validation.calibrate import StateTrack
from rodo.validation.velocity_growth import growth_check, growth_kernel, velocity_growth

DT = 0.077
QC_CA = np.array([0.05, 0.01, 0.005, 1e-4, 1e-4, 1e-3])
QC_CV = np.array([0.2, 0.02, 0.01, 1e-4, 1e-4, 1e-3])


def _rng(*key):
    return np.random.default_rng(np.random.SeedSequence([20261207, *key]))


def _transition(kind, dt, q):
    """F, Q of one component's (velocity[, acceleration]) over dt: the exact integrals of white jerk (CA) or
    white acceleration (CV) of PSD q."""
    if kind == "ca":
        return np.array([[1.0, dt], [0.0, 1.0]]), q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    return np.eye(1), q * dt * np.eye(1)


@pytest.mark.parametrize("kind", ["ca", "cv"])
@given(m=st.integers(1, 80), dt=st.floats(0.01, 0.2), q=st.floats(1e-6, 10.0))
def test_growth_kernel_is_the_exact_variance_of_the_second_difference(kind, m, dt, q):
    """Var(v_{k+2m} - 2 v_{k+m} + v_k) propagated exactly through m steps twice (from any state: the second
    difference does not depend on it) equals q g(m dt)."""
    F, Q = _transition(kind, dt, q)
    n = len(F)
    A = np.zeros((3 * n, n))  # [x_k; x_{k+m}; x_{k+2m}] = A x_k + noise of covariance C
    C = np.zeros((3 * n, 3 * n))
    Fm, Qm = np.eye(n), np.zeros((n, n))
    for _ in range(m):
        Fm, Qm = F @ Fm, F @ Qm @ F.T + Q
    A[:n], A[n:2 * n], A[2 * n:] = np.eye(n), Fm, Fm @ Fm
    C[n:2 * n, n:2 * n] = Qm
    C[2 * n:, n:2 * n] = Fm @ Qm
    C[n:2 * n, 2 * n:] = Qm @ Fm.T
    C[2 * n:, 2 * n:] = Fm @ Qm @ Fm.T + Qm
    w = np.zeros(3 * n)
    w[[0, n, 2 * n]] = [1.0, -2.0, 1.0]
    assert np.allclose(w @ A, 0.0, atol=1e-9 * max(1.0, np.abs(A).max()))
    assert w @ C @ w == pytest.approx(q * float(growth_kernel(kind, m * dt)), rel=1e-9)


def _track(rng, kind, qc, seconds, sigma_e, tau_e=0.5):
    """Velocity tracks drawn exactly from the prior's SDE at Qc, plus a bounded Gauss-Markov error per component
    (sigma_e (6,), correlation time tau_e): what an estimator's velocity looks like."""
    n = int(seconds / DT)
    v = np.zeros((n, 6))
    for i in range(6):
        F, Q = _transition(kind, DT, qc[i])
        L = np.linalg.cholesky(Q)
        x = np.zeros(len(F))
        for k in range(n):
            v[k, i] = x[0]
            x = F @ x + L @ rng.normal(size=len(F))
    phi = np.exp(-DT / tau_e)
    e = np.zeros((n, 6))
    e[0] = rng.normal(size=6) * sigma_e
    for k in range(1, n):
        e[k] = phi * e[k - 1] + np.sqrt(1 - phi**2) * sigma_e * rng.normal(size=6)
    t = np.arange(n) * DT
    return StateTrack(t, np.tile(np.eye(4), (n, 1, 1)), v + e, np.zeros((n, 6)))


@pytest.mark.parametrize("tau_e", [0.3, 1.0])
def test_the_estimate_is_unbiased_and_its_interval_covers_the_truth(tau_e):
    """40 drives of 60 s from the CA prior's SDE, each with an estimation error correlated over tau_e whose second
    difference is 0.2-1 times the motion's over 1 s (hundreds of times a scan's change: EM would book it as
    motion): the median estimate within 20 % of the truth, and the 99 % intervals hold the truth in at least 90 %
    of the 240 cases (a jackknife over 8 blocks is rough)."""
    rng = _rng(1, int(10 * tau_e))
    ratios, covered = [], []
    for _ in range(40):
        sigma_e = np.sqrt(rng.uniform(0.2, 1.0) * QC_CA * growth_kernel("ca", 1.0) / 6)
        g = velocity_growth(_track(rng, "ca", QC_CA, 60.0, sigma_e, tau_e), "ca")
        ratios.append(g.qc / QC_CA)
        covered.append((g.lo <= QC_CA) & (QC_CA <= g.hi))
    assert np.all(np.abs(np.median(ratios, axis=0) - 1.0) < 0.2), np.median(ratios, axis=0)
    assert np.mean(covered) >= 0.9, np.mean(covered, axis=0)


def test_the_check_flags_an_em_that_books_the_error_as_motion():
    """30 drives whose estimation error's second difference equals the motion's over 1 s: EM's Qc at the truth is
    flagged (in any component) on at most 15 % of them, at 10 x the truth in four or more components on at least
    90 %."""
    rng = _rng(2)
    right, runaway = [], []
    for _ in range(30):
        g = velocity_growth(_track(rng, "ca", QC_CA, 60.0, np.sqrt(QC_CA * growth_kernel("ca", 1.0) / 6)), "ca")
        right.append(any(r["outside"] for r in growth_check(QC_CA, g)))
        runaway.append(sum(r["outside"] for r in growth_check(10 * QC_CA, g)) >= 4)
    assert np.mean(right) <= 0.15 and np.mean(runaway) >= 0.9, (np.mean(right), np.mean(runaway))


def test_a_reinitialisation_is_not_motion():
    """A jump of the velocity at a re-initialisation (the interval marked invalid) leaves the estimate as it is
    without the jump; taken as motion (not marked), it inflates it."""
    rng = _rng(3)
    tr = _track(rng, "ca", QC_CA, 60.0, np.sqrt(0.2 * QC_CA * growth_kernel("ca", 1.0) / 6))
    valid = np.ones(len(tr.t) - 1, bool)
    valid[400] = False
    jumped = tr.varpi.copy()
    jumped[401:] += 3 * np.sqrt(QC_CA * growth_kernel("ca", 5.0))
    base = velocity_growth(StateTrack(tr.t, tr.T_vehicle_world, tr.varpi, tr.varpi_dot, valid=valid), "ca")
    marked = velocity_growth(StateTrack(tr.t, tr.T_vehicle_world, jumped, tr.varpi_dot, valid=valid), "ca")
    unmarked = velocity_growth(StateTrack(tr.t, tr.T_vehicle_world, jumped, tr.varpi_dot), "ca")
    np.testing.assert_allclose(marked.qc, base.qc, rtol=1e-12)
    assert np.all(unmarked.qc > 1.5 * base.qc), unmarked.qc / base.qc


def test_an_axis_without_motion_a_short_drive_and_the_cv_prior():
    """A planar radar's z, roll and pitch never move: not estimated (NaN, no verdict). A drive too short for lags
    over a factor of two from 0.5 s, and the CV prior (whose linear growth a correlated error imitates), are
    refused with the reason."""
    rng = _rng(4)
    tr = _track(rng, "ca", QC_CA, 30.0, np.full(6, 1e-3))
    planar = tr.varpi.copy()
    planar[:, 2:5] = 0.0
    g = velocity_growth(StateTrack(tr.t, tr.T_vehicle_world, planar, tr.varpi_dot), "ca")
    assert np.all(np.isnan(g.qc[2:5])) and np.all(np.isfinite(g.qc[[0, 1, 5]]))
    assert [r["outside"] for r in growth_check(QC_CA, g)][2:5] == [None] * 3
    n = int(5.0 / DT)
    with pytest.raises(InputError, match="spans"):
        velocity_growth(StateTrack(tr.t[:n], tr.T_vehicle_world[:n], tr.varpi[:n], tr.varpi_dot[:n]), "ca")
    with pytest.raises(InputError, match="CA prior"):
        velocity_growth(tr, "cv")
