"""validation/calibrate_axis_correlation.py: the registration's correlation per axis recovered from drives whose
pose error carries one on one axis, and none where the error is a random walk."""

import numpy as np
import pytest

from rodo.estimator.lie import se3
from rodo.validation import replayed_states as rs
from rodo.validation.calibrate_axis_correlation import SHARES, fit_axis_correlation, growth_at
from tests.validation.synthetic_drives import stated_run, straight_drive

DT, N, RUNS, TAU = 0.1, 300, 4, 0.5
SIGMA = np.array([3e-3, 3e-3, 3e-3, 2e-4, 2e-4, 5e-4])  # per scan, as the states say
X, SHARE = 0, 0.5  # the forward position: half its registration covariance correlated over TAU


def _run(seed: int):
    """(states, truth) of a drive whose errors follow the drift recursion's own model (`estimator.uncertainty`) with
    the share SHARE on the forward axis and 0 on the others: xi_k = Ad xi_{k-1} + dt phi b_{k-1} + dt w_k + delta_k,
    delta_k ~ N(0, B Sigma B), b_k = phi b_{k-1} + w_k, w_k ~ N(0, (1 - phi^2) A Sigma A / dt^2), b_0 = 0
    (the window's velocity covariance is nil here)."""
    rng = np.random.default_rng(np.random.SeedSequence([2026, 50, seed]))
    T_true = straight_drive(rng, N, step_range=(0.06, 0.1))
    a = np.zeros(6)
    a[X] = SHARE
    phi = np.exp(-DT / TAU)
    independent, correlated = SIGMA * np.sqrt(1 - a), SIGMA * np.sqrt(a) / DT
    x, b, errors = np.zeros(6), np.zeros(6), [np.zeros(6)]
    for k in range(1, N):
        w = rng.normal(size=6) * correlated * np.sqrt(1 - phi**2)
        x = se3.adjoint(T_true[k] @ se3.inverse(T_true[k - 1])) @ x + DT * (phi * b + w) \
            + rng.normal(size=6) * independent
        b = phi * b + w
        errors.append(x.copy())
    states, truth = stated_run(DT, T_true, errors, np.diag(SIGMA**2))
    return rs.replayed(states, TAU, None), truth


@pytest.fixture(scope="module")
def runs():
    return [_run(seed) for seed in range(RUNS)]


def test_the_fit_finds_the_forward_correlation_and_none_in_a_random_walk(runs):
    """The forward position: the grid's share at the truth (0.5) or next to it, its growth's cost well below the
    one without; the lateral position and the yaw, random walks of their stated variance: 0; the axes not fitted
    stay 0."""
    shares, report = fit_axis_correlation([r[0] for r in runs], [r[1] for r in runs], axes=(5, 0, 1))
    x = report["axes"]["x"]
    assert x["share"] in (0.25, 0.5, 1.0) and x["cost"] < 0.5 * x["cost_without"], x
    assert report["axes"]["y"]["share"] == 0.0 and report["axes"]["yaw"]["share"] == 0.0, report
    assert shares[X] == x["share"] and np.all(shares[[1, 2, 3, 4, 5]] == 0.0)
    assert report["fitted"] is True and set(SHARES) >= {x["share"]}


def test_the_growth_at_the_true_share_is_consistent_and_cautious_beyond_it(runs):
    """`growth_at`: at the true share the forward position's E[e^2 / sigma^2] over 0.5-5 s is near 1 on every
    span (within 35 %: four drives of 30 s, a few independent spans of 5 s each; over 10-20 s too few to test:
    24 drives read 0.89 and 0.65 there), at no share over-confident (above 1.5 from 1 s on), at share 1 cautious
    (below the true share's)."""
    spans = (0.5, 1.0, 2.0, 5.0)
    at = lambda a: growth_at(runs, np.r_[a, np.zeros(5)], spans)[:, X]  # noqa: E731
    truth, none, full = at(SHARE), at(0.0), at(1.0)
    assert np.all(np.abs(np.log(truth)) < np.log(1.35)), truth
    assert np.all(none[1:] > 1.5), none
    assert np.all(full < truth), (full, truth)
