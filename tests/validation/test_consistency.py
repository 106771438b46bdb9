"""NEES/NIS: error convention, Gaussian samples with known covariance, chi-square bounds by Monte Carlo."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.stats import chi2

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.validation.alignment import truth_in_estimator_frame
from rodo.validation.consistency import (average_nees, chi2_bounds, fraction_within, gated_mean, nees,
                                         nees_sequence, nis_summary, pose_error, state_error)
from tests.strategies import covariances, twists


def _rng(seed):
    return np.random.default_rng(np.random.SeedSequence(seed))


def _spd(rng, d, scale=1.0):
    A = rng.normal(0, 1, (d, d))
    return scale * (A @ A.T / d + 0.1 * np.eye(d))


@given(twists("vehicle", 5.0), twists("any", 20.0))
def test_state_error_is_left_perturbation(xi, base):
    T_est = se3.exp(base)
    T_true = se3.exp(xi) @ T_est
    e = state_error(T_true, np.arange(6.0), T_est, np.zeros(6), np.ones(6), np.zeros(6))
    np.testing.assert_allclose(e[:6], xi, atol=1e-9)
    np.testing.assert_allclose(e[6:], np.r_[np.arange(6.0), np.ones(6)])
    np.testing.assert_allclose(pose_error(T_true, T_est), e[:6])
    assert state_error(T_true, np.zeros(6), T_est, np.zeros(6)).shape == (12,)


@pytest.mark.parametrize("d", [12, 18])
def test_gaussian_nees_within_bounds_and_wrong_covariance_outside(d):
    rng = _rng(d)
    runs, scans = 40, 100
    P = _spd(rng, d)
    L = np.linalg.cholesky(P)
    e = rng.normal(0, 1, (runs, scans, d)) @ L.T
    Pb = np.broadcast_to(P, (runs, scans, d, d))
    lo, hi = chi2_bounds(runs, d)
    avg = nees(e, Pb).mean(axis=0)
    inside = np.mean((avg >= lo) & (avg <= hi))
    assert 0.88 <= inside <= 1.0  # 95 % bounds: binomial(100, 0.95) is above 88 % with probability > 0.99
    assert abs(avg.mean() - d) < 0.05 * d
    for wrong, off in ((2.0, "low"), (0.5, "high")):  # over- and under-confident covariances
        bad = nees(e, Pb * wrong).mean(axis=0)
        assert np.mean(bad < lo if off == "low" else bad > hi) > 0.99


def test_nees_matches_direct_formula_and_flags_singular_p():
    rng = _rng(1)
    P = _spd(rng, 12)
    e = rng.normal(0, 1, 12)
    assert nees(e, P) == pytest.approx(e @ np.linalg.solve(P, e), rel=1e-10)
    Ps = np.stack([P, np.zeros((12, 12)), P])
    out = nees(np.stack([e, e, e * np.nan]), Ps)
    assert out[0] == pytest.approx(e @ np.linalg.solve(P, e)) and np.isnan(out[1]) and np.isnan(out[2])
    with pytest.raises(InputError, match="e, P"):
        nees(e, P[:6, :6])


@pytest.mark.parametrize("n, d", [(1, 1), (1, 18), (25, 12), (200, 4)])
def test_chi2_bounds_cover_the_average_of_chi2_samples(n, d):
    rng = _rng(n * 100 + d)
    lo, hi = chi2_bounds(n, d, alpha=0.1)
    avg = rng.chisquare(d, (20000, n)).mean(axis=1)
    assert np.mean(avg < lo) == pytest.approx(0.05, abs=0.008)
    assert np.mean(avg > hi) == pytest.approx(0.05, abs=0.008)
    if n == 1:
        assert (lo, hi) == pytest.approx(tuple(chi2.ppf([0.05, 0.95], d)))


def test_chi2_bounds_vectorised_over_counts():
    b = chi2_bounds(np.array([0, 1, 10]), 6)
    assert np.all(np.isnan(b[0])) and b[2] == pytest.approx(chi2_bounds(10, 6))
    for kwargs, name in ((dict(alpha=1.5), "alpha"), (dict(alpha=0.0), "alpha"), (dict(dim=0), "dim"),
                         (dict(dim=2.5), "dim"), (dict(n_runs=-1), "n_runs"), (dict(n_runs=np.nan), "n_runs")):
        with pytest.raises(InputError, match=name):
            chi2_bounds(**{"n_runs": 3, "dim": 6, **kwargs})


@given(dim=st.integers(1, 12), n_runs=st.integers(1, 40))
def test_chi2_bounds_match_chi_square_quantiles(dim, n_runs):
    """The default alpha = 0.05: the 2.5 % and 97.5 % quantiles of chi2(n d) / n, which the mean of n chi2(d)
    draws falls between 95 % of the time; the array form gives the same numbers per entry."""
    lo, hi = chi2_bounds(n_runs, dim)
    assert lo == pytest.approx(chi2.ppf(0.025, dim * n_runs) / n_runs, rel=1e-12)
    assert hi == pytest.approx(chi2.ppf(0.975, dim * n_runs) / n_runs, rel=1e-12)
    b = chi2_bounds([n_runs, 0], dim)
    assert np.allclose(b[0], (lo, hi), rtol=1e-12) and np.isnan(b[1]).all()
    mean = _rng([dim, n_runs]).chisquare(dim, size=(4000, n_runs)).mean(axis=1)
    assert abs(np.mean((mean >= lo) & (mean <= hi)) - 0.95) < 0.02


def test_fraction_within_skips_missing_values():
    v = np.array([1.0, 5.0, np.nan, 2.0, 3.0])
    assert fraction_within(v, (1.5, 4.0)) == pytest.approx(2 / 4)  # the NaN value is left out, not outside
    b = np.array([[0.0, 2.0], [0.0, 2.0], [0.0, 2.0], [np.nan, np.nan], [2.5, 3.5]])
    assert fraction_within(v, b) == pytest.approx(2 / 3)  # NaN bounds (a count of 0) too
    assert np.isnan(fraction_within([np.nan], (0.0, 1.0))) and np.isnan(fraction_within([], (0.0, 1.0)))


def test_nees_is_chi_square_for_sampled_errors():
    rng = _rng(11)
    Q, _ = np.linalg.qr(rng.standard_normal((6, 6)))
    P = (Q * np.array([0.1, 0.5, 2.0, 0.01, 0.02, 0.05]) ** 2) @ Q.T
    err = rng.multivariate_normal(np.zeros(6), P, size=20000)
    v = nees(err, np.broadcast_to(P, (len(err), 6, 6)))
    assert v.mean() == pytest.approx(6.0, abs=0.1)   # chi2(6): mean 6, sd of the mean 0.024
    assert v.var() == pytest.approx(12.0, rel=0.06)
    err[3] = np.nan
    assert np.isnan(nees(err[:5], np.broadcast_to(P, (5, 6, 6)))[3])


@given(covariances(18, 0.05, 2.0), twists("vehicle", 3.0), twists("any", 3.0))
def test_pose_window_and_velocity_use_the_diagonal_blocks(P, xi, varpi_error):
    """odometry_nees's `pose_window` and `velocity` are NEES against the window's diagonal blocks P[:6, :6] and
    P[6:12, 6:12]; a block that is not positive definite gives NaN."""
    from rodo.validation.odometry_consistency import odometry_nees

    T1 = se3.exp(np.array([-5.0, 0.2, 0.0, 0.0, 0.0, 0.1]))
    truth = {"t": np.array([0.0, 0.1]), "T_vehicle_world": np.stack([np.eye(4), se3.exp(xi) @ T1]),
             "varpi": np.stack([np.zeros(6), varpi_error])}
    states = {"t": truth["t"], "T_vehicle_world": np.stack([np.eye(4), T1]), "varpi": np.zeros((2, 6)),
              "P": np.stack([P, P])}
    out = odometry_nees(states, truth)
    assert out["pose_window"][1] == pytest.approx(xi @ np.linalg.solve(P[:6, :6], xi), rel=1e-8)
    assert out["velocity"][1] == pytest.approx(varpi_error @ np.linalg.solve(P[6:12, 6:12], varpi_error), rel=1e-8)
    states["P"] = np.zeros((2, 12, 12))
    assert np.isnan(odometry_nees(states, truth)["pose_window"][1])  # not positive definite


@pytest.mark.parametrize("d", [12, 18])
def test_nees_sequence_uses_truth_relative_to_first_pose(d):
    rng = _rng(d + 7)
    K = 30
    t_true = np.arange(2 * K) * 0.05  # truth at twice the scan rate
    T_world_true = se3.exp(rng.normal(0, [20, 20, 2, 0.1, 0.1, 3], (2 * K, 6)))  # arbitrary world frame
    varpi_true = rng.normal(0, 2, (2 * K, 6))
    vd_true = rng.normal(0, 1, (2 * K, 6))
    truth = {"t": t_true, "T_vehicle_world": T_world_true, "varpi": varpi_true, "varpi_dot": vd_true}
    rel = truth_in_estimator_frame(T_world_true)[::2]
    np.testing.assert_allclose(rel[0], np.eye(4), atol=1e-12)
    P = np.stack([_spd(rng, d, 0.01) for _ in range(K)])
    e = np.einsum("kij,kj->ki", np.linalg.cholesky(P), rng.normal(0, 1, (K, d)))
    states = {"t": t_true[::2] + 1e-4, "T_vehicle_world": se3.exp(-e[:, :6]) @ rel,
              "varpi": varpi_true[::2] - e[:, 6:12], "P": P,
              "varpi_dot": vd_true[::2] - (e[:, 12:] if d == 18 else 0.0)}
    out = nees_sequence(states, truth)
    want = np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])
    np.testing.assert_allclose(out["nees"], want, rtol=1e-6)
    assert out["dim"] == d and len(out["t"]) == K
    states["T_vehicle_world"] = states["T_vehicle_world"].copy()
    states["T_vehicle_world"][3] = np.nan
    assert np.isnan(nees_sequence(states, truth)["nees"][3])
    with pytest.raises(InputError, match="P must be"):
        nees_sequence({**states, "P": P[:, :6, :6]}, truth)
    with pytest.raises(InputError, match="missing array 'varpi'"):
        nees_sequence(states, {k: v for k, v in truth.items() if k != "varpi"})


def test_average_nees_handles_ragged_runs_and_nan():
    mean, count = average_nees([np.array([1.0, 2.0, 3.0]), np.array([3.0, np.nan]), np.array([5.0])])
    np.testing.assert_allclose(mean, [3.0, 2.0, 3.0])
    np.testing.assert_array_equal(count, [3, 1, 1])


def test_nis_summary_of_chi2_pairs():
    rng = _rng(3)
    n = rng.integers(20, 80, 300)
    nis = np.array([rng.chisquare(4, k).mean() for k in n])
    s = nis_summary(nis, n)
    lo, hi = s["bounds"]
    assert lo <= s["mean"] <= hi and s["pairs"] == n.sum()
    assert 0.9 <= s["fraction_scans_within"] <= 0.99
    s2 = nis_summary(2 * nis, n)
    assert s2["mean"] > s2["bounds"][1] and s2["fraction_scans_within"] < 0.1
    empty = nis_summary(np.array([np.nan, 1.0]), np.array([5, 0]))
    assert empty["pairs"] == 0 and np.isnan(empty["mean"])


def test_gated_mean_matches_truncated_samples():
    x = _rng(9).chisquare(4, 400000)
    g = chi2.ppf(0.95, 4)
    assert gated_mean(4, 0.95) == pytest.approx(x[x < g].mean(), rel=5e-3)
