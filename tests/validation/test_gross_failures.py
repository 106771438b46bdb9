"""Gross failures left out of the calibration's likelihood fits (rodo.validation.gross_failures): the scans whose
NEES per dof under the fit exceeds 100, at most 1 % of them, refitted until the set repeats."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from rodo.validation import gross_failures as gf


def _rng(*key):
    return np.random.default_rng(np.random.SeedSequence([2026, 42, *key]))


def test_the_failures_are_100_per_dof_at_the_median_scans_level_and_at_most_the_cap():
    typical = chi2.median(6)  # the median scan of a consistent fit
    limit = gf.GROSS_NEES_PER_DOF * 6
    nees = np.r_[np.full(500, typical), limit * 0.999, limit * 1.001, np.nan, 1e6]
    np.testing.assert_array_equal(np.flatnonzero(gf.gross_failures(nees, 6)), [501, 503])
    for scale in (1e-3, 7.0, 1e4):  # at any level of the fit: the failures are judged against its median scan
        np.testing.assert_array_equal(np.flatnonzero(gf.gross_failures(scale * nees, 6)), [501, 503])
    assert not gf.gross_failures(np.full(1000, 1e3), 6).any()  # wrong by the same factor everywhere: no failure
    # more than 1 % beyond it is not a few failures: at most 1 % of the scans go, the largest first
    many = np.r_[np.full(950, typical), 1e6 + np.arange(50.0)]
    failed = gf.gross_failures(many, 6)
    assert failed.sum() == 10 and failed[-10:].all()
    assert not gf.gross_failures(np.r_[np.full(98, typical), 1e9], 6).any()  # under 100 scans: none may go
    assert not gf.gross_failures(np.full(5, np.nan), 6).any()
    assert not gf.gross_failures(np.r_[np.zeros(150), np.full(50, 1e-12), 1.0], 6).any()  # no level: none


@settings(max_examples=10, deadline=None)
@given(n_bad=st.integers(0, 30), scale=st.floats(0.01, 100.0), seed=st.integers(0, 2**32 - 1))
def test_a_fit_without_its_gross_failures_is_the_fit_of_the_clean_scans(n_bad, scale, seed):
    """Errors e_k ~ N(0, s I6) on 3000 scans, n_bad of them (up to the 1 % cap) replaced by errors 100 times as
    large (an estimator's outright failure): the maximum likelihood s refitted without the failures is the clean
    scans' own within 5 %, the scans left out are exactly the replaced ones, and the plain fit is off by more
    than the failures' share (with them every scan's NEES would be judged against a covariance 1.3 to 4 times
    too large)."""
    rng = _rng(seed)
    n = 3000
    e = rng.normal(0.0, np.sqrt(scale), (n, 6))
    bad = rng.choice(n, n_bad, replace=False)
    e[bad] *= 100.0

    def fit(keep):
        return float(np.mean(e[keep] ** 2))

    s, failed, nees = gf.fit_without_gross_failures(fit, lambda s: np.sum(e**2, axis=1) / s, n, 6)
    np.testing.assert_array_equal(np.flatnonzero(failed), np.sort(bad))
    np.testing.assert_array_equal(nees, np.sum(e**2, axis=1) / s)  # the NEES returned are the returned fit's
    assert s == pytest.approx(scale, rel=0.05)
    if n_bad >= 2:  # (one bad scan's chi-square draw may be small: 0.3 % odds of a plain fit under 1.3 s)
        assert fit(np.ones(n, bool)) > 1.3 * scale
